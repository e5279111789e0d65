//! The sparsity pattern of a symmetric Hessian over 3D vertices, stored as its lower triangle in compressed
//! sparse column (CSC) form, the layout faer's sparse Cholesky takes.
//!
//! The pattern is built once from the vertex pairs (3×3 blocks) that some energy couples. Every block gets a
//! slot: the value offsets of its three columns, so adding a local block never searches. Values of block
//! column `j` (scalar columns `3j..3j+3`) are contiguous, which lets disjoint vertex ranges own disjoint
//! slices of the value array (see [`crate::bending`]).

/// A 3×3 block of the lower triangle: where its values live.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockSlot {
    /// Block row vertex (≥ `col`).
    pub row: u32,
    /// Block column vertex.
    pub col: u32,
    /// Value offset of the block's first stored entry in each of its three scalar columns.
    pub offset: [u32; 3],
}

/// Lower-triangular CSC pattern of a `3n × 3n` symmetric matrix with 3×3 block structure.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SymmetricPattern {
    n_vertices: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    blocks: Vec<BlockSlot>,
    /// For block column j, the range of `blocks` holding its blocks (diagonal first, then by row).
    block_col_ptr: Vec<usize>,
}

impl SymmetricPattern {
    /// Builds the pattern from vertex pairs (any order, duplicates allowed; `(i, j)` and `(j, i)` are the same
    /// block). Every vertex gets a diagonal block. Pairs with an out-of-range vertex are ignored.
    pub fn new(n_vertices: usize, pairs: impl IntoIterator<Item = (usize, usize)>) -> Self {
        let mut p: Vec<(u32, u32)> = pairs
            .into_iter()
            .filter(|&(a, b)| a < n_vertices && b < n_vertices && a != b)
            .map(|(a, b)| (a.min(b) as u32, a.max(b) as u32)) // (col, row)
            .chain((0..n_vertices as u32).map(|v| (v, v)))
            .collect();
        p.sort_unstable();
        p.dedup();
        let mut block_col_ptr = vec![0usize; n_vertices + 1];
        for &(c, _) in &p {
            block_col_ptr[c as usize + 1] += 1;
        }
        for j in 0..n_vertices {
            block_col_ptr[j + 1] += block_col_ptr[j];
        }
        let n = 3 * n_vertices;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut blocks = Vec::with_capacity(p.len());
        col_ptr.push(0);
        for j in 0..n_vertices {
            let col_blocks = &p[block_col_ptr[j]..block_col_ptr[j + 1]];
            let m = col_blocks.len() - 1; // off-diagonal blocks (the diagonal sorts first)
            let base = row_idx.len();
            let len0 = 3 + 3 * m;
            let col_start = [base, base + len0, base + 2 * len0 - 1];
            for k in 0..3 {
                for &(_, r) in col_blocks {
                    let r = r as usize;
                    let first = if r == j { 3 * j + k } else { 3 * r };
                    for row in first..3 * r + 3 {
                        row_idx.push(row);
                    }
                }
                col_ptr.push(row_idx.len());
            }
            for (q, &(_, r)) in col_blocks.iter().enumerate() {
                let offset = if q == 0 {
                    [col_start[0], col_start[1], col_start[2]]
                } else {
                    [
                        col_start[0] + 3 * q,
                        col_start[1] + 2 + 3 * (q - 1),
                        col_start[2] + 1 + 3 * (q - 1),
                    ]
                };
                blocks.push(BlockSlot {
                    row: r,
                    col: j as u32,
                    offset: offset.map(|o| o as u32),
                });
            }
        }
        Self {
            n_vertices,
            col_ptr,
            row_idx,
            blocks,
            block_col_ptr,
        }
    }

    /// Number of vertices (the matrix is `3n × 3n`).
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// Scalar dimension `3n`.
    pub fn dim(&self) -> usize {
        3 * self.n_vertices
    }

    /// Stored entries (lower triangle with diagonal).
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// Entries of the full symmetric matrix (both triangles).
    pub fn nnz_full(&self) -> usize {
        2 * self.nnz() - self.dim()
    }

    /// CSC column pointers (length `3n + 1`).
    pub fn col_ptr(&self) -> &[usize] {
        &self.col_ptr
    }

    /// CSC row indices, sorted within each column.
    pub fn row_idx(&self) -> &[usize] {
        &self.row_idx
    }

    /// All block slots, by block column then row.
    pub fn blocks(&self) -> &[BlockSlot] {
        &self.blocks
    }

    /// Value offset where block column `j` starts (`j ≤ n`).
    pub fn block_col_value_start(&self, j: usize) -> usize {
        self.col_ptr[3 * j]
    }

    /// The slot index of block `(a, b)` (either order), if the pattern holds it. Used at set-up only.
    pub fn find(&self, a: usize, b: usize) -> Option<usize> {
        let (col, row) = (a.min(b), a.max(b));
        if row >= self.n_vertices {
            return None;
        }
        let range = self.block_col_ptr[col]..self.block_col_ptr[col + 1];
        let rows = &self.blocks[range.clone()];
        rows.binary_search_by_key(&(row as u32), |s| s.row)
            .ok()
            .map(|q| range.start + q)
    }
}
