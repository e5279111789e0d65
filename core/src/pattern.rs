//! The sparsity pattern of a symmetric Hessian over 3D vertices, stored as its lower triangle in compressed
//! sparse column (CSC) form, the layout faer's sparse Cholesky takes.
//!
//! The pattern is built once from the vertex pairs (3×3 blocks) that some energy couples. Every block gets a
//! slot: the value offsets of its three columns, so adding a local block never searches. Values of block
//! column `j` (scalar columns `3j..3j+3`) are contiguous, which lets disjoint vertex ranges own disjoint
//! slices of the value array (see [`crate::bending`]). Columns are laid out in a storage order of the
//! vertices (a locality order by default, see [`SymmetricPattern`]): a mesh numbered at random costs what
//! the same mesh numbered row by row does.

use crate::error::EvalError;

/// A 3×3 block of the lower triangle (in storage order): where its values live.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockSlot {
    /// The block's row vertex, in the caller's numbering (its storage position is ≥ the column's).
    pub row: u32,
    /// The block's column vertex, in the caller's numbering.
    pub col: u32,
    /// Value offset of the block's first stored entry in each of its three scalar columns. The stored values
    /// are those of the block `H[row][col]` (rows of `row`, columns of `col`).
    pub offset: [u32; 3],
}

/// Lower-triangular CSC pattern of a `3n × 3n` symmetric matrix with 3×3 block structure, over the vertices
/// in a *storage order*.
///
/// # Numbering
/// Vertices keep the caller's numbering in every argument and field that names a vertex ([`Self::find`],
/// [`BlockSlot::row`], [`BlockSlot::col`]). The CSC arrays ([`Self::col_ptr`], [`Self::row_idx`]) and hence the
/// value array are laid out in storage order: scalar row/column `3s + k` is coordinate `k` of vertex
/// [`Self::vertex_at`]`(s)`, and [`Self::storage_dof`] / [`Self::caller_dof`] convert scalar indices.
/// [`SymmetricPattern::new`] chooses a locality order (breadth-first, Cuthill–McKee, over the coupling graph)
/// so that evaluation cost does not depend on how the caller numbered the mesh;
/// [`SymmetricPattern::with_vertex_order`] takes any order, the identity included. The exports in
/// [`crate::export`] (CSR arrays, dense matrices, Matrix Market) map back to the caller's numbering; a
/// linear solver can work in storage order directly (permuting right-hand sides with [`Self::storage_dof`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SymmetricPattern {
    n_vertices: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    blocks: Vec<BlockSlot>,
    /// For storage block column j, the range of `blocks` holding its blocks (diagonal first, then by row).
    block_col_ptr: Vec<usize>,
    /// Storage position → caller vertex.
    order: Vec<u32>,
    /// Caller vertex → storage position.
    rank: Vec<u32>,
}

fn too_large(what: &str, n: usize) -> EvalError {
    EvalError::Pattern {
        message: format!(
            "{what} ({n}) exceeds the 32-bit index range of the value slots ({})",
            u32::MAX
        ),
    }
}

/// The number of stored values (6 per diagonal block, 9 per off-diagonal block), if value slots (`u32`) can
/// index them all.
fn check_nnz(n_vertices: usize, n_pairs: usize) -> Result<usize, EvalError> {
    let nnz = 6 * n_vertices as u128 + 9 * n_pairs as u128;
    if nnz > u32::MAX as u128 {
        return Err(too_large(
            "number of stored Hessian values",
            usize::try_from(nnz).unwrap_or(usize::MAX),
        ));
    }
    Ok(nnz as usize)
}

/// Deduplicated off-diagonal pairs `(min, max)` of in-range vertices.
fn unique_pairs(
    n_vertices: usize,
    pairs: impl IntoIterator<Item = (usize, usize)>,
) -> Vec<(u32, u32)> {
    let mut p: Vec<(u32, u32)> = pairs
        .into_iter()
        .filter(|&(a, b)| a < n_vertices && b < n_vertices && a != b)
        .map(|(a, b)| (a.min(b) as u32, a.max(b) as u32))
        .collect();
    p.sort_unstable();
    p.dedup();
    p
}

/// A breadth-first (Cuthill–McKee) order of the coupling graph: each connected component from a
/// pseudo-peripheral start vertex (George–Liu), neighbours by increasing degree, ties by vertex. Vertices at
/// the same distance from the start end up together, so a contiguous range of the order is a band of the
/// mesh whatever its numbering. Deterministic: a function of the graph and the numbering alone.
fn locality_order(n: usize, pairs: &[(u32, u32)]) -> Vec<u32> {
    let mut ptr = vec![0usize; n + 1];
    for &(a, b) in pairs {
        ptr[a as usize + 1] += 1;
        ptr[b as usize + 1] += 1;
    }
    for i in 0..n {
        ptr[i + 1] += ptr[i];
    }
    let mut adj = vec![0u32; ptr[n]];
    let mut next = ptr.clone();
    for &(a, b) in pairs {
        adj[next[a as usize]] = b;
        next[a as usize] += 1;
        adj[next[b as usize]] = a;
        next[b as usize] += 1;
    }
    let degree = |v: u32| ptr[v as usize + 1] - ptr[v as usize];
    for v in 0..n {
        adj[ptr[v]..ptr[v + 1]].sort_unstable_by_key(|&w| (degree(w), w));
    }
    let mut order: Vec<u32> = Vec::with_capacity(n);
    let mut visited = vec![false; n];
    // Scratch for the pseudo-peripheral search: BFS level per vertex, reset per search.
    let mut level = vec![u32::MAX; n];
    let mut queue: Vec<u32> = Vec::new();
    // BFS from `s` over unvisited vertices; returns (eccentricity, the min-degree vertex of the last level).
    let probe = |s: u32, visited: &[bool], level: &mut [u32], queue: &mut Vec<u32>| {
        queue.clear();
        queue.push(s);
        level[s as usize] = 0;
        let mut head = 0;
        while head < queue.len() {
            let v = queue[head];
            head += 1;
            for &w in &adj[ptr[v as usize]..ptr[v as usize + 1]] {
                if !visited[w as usize] && level[w as usize] == u32::MAX {
                    level[w as usize] = level[v as usize] + 1;
                    queue.push(w);
                }
            }
        }
        let ecc = queue.last().map_or(0, |&v| level[v as usize]);
        let far = queue
            .iter()
            .copied()
            .filter(|&v| level[v as usize] == ecc)
            .min_by_key(|&v| (degree(v), v))
            .unwrap_or(s);
        for &v in queue.iter() {
            level[v as usize] = u32::MAX;
        }
        (ecc, far)
    };
    for seed in 0..n as u32 {
        if visited[seed as usize] {
            continue;
        }
        let mut start = seed;
        let (mut ecc, mut far) = probe(start, &visited, &mut level, &mut queue);
        for _ in 0..8 {
            let (e2, f2) = probe(far, &visited, &mut level, &mut queue);
            if e2 <= ecc {
                break;
            }
            (start, ecc, far) = (far, e2, f2);
        }
        let head0 = order.len();
        order.push(start);
        visited[start as usize] = true;
        let mut head = head0;
        while head < order.len() {
            let v = order[head];
            head += 1;
            for &w in &adj[ptr[v as usize]..ptr[v as usize + 1]] {
                if !visited[w as usize] {
                    visited[w as usize] = true;
                    order.push(w);
                }
            }
        }
    }
    order
}

impl SymmetricPattern {
    /// Builds the pattern from vertex pairs (any order, duplicates allowed; `(i, j)` and `(j, i)` are the same
    /// block), in a locality order of the coupling graph (see the type's docs). Every vertex gets a diagonal
    /// block. Pairs with an out-of-range vertex are ignored. Set-up cost: a sort of the pairs and one
    /// breadth-first search per probe (a few per connected component).
    ///
    /// # Errors
    /// [`EvalError::Pattern`] when the vertex count or the number of stored values exceeds the 32-bit range
    /// of the value slots.
    pub fn new(
        n_vertices: usize,
        pairs: impl IntoIterator<Item = (usize, usize)>,
    ) -> Result<Self, EvalError> {
        if n_vertices > u32::MAX as usize {
            return Err(too_large("vertex count", n_vertices));
        }
        let p = unique_pairs(n_vertices, pairs);
        check_nnz(n_vertices, p.len())?;
        let order = locality_order(n_vertices, &p);
        Self::build(n_vertices, p, order)
    }

    /// Builds the pattern with the caller's storage order: `order[s]` is the vertex stored at position `s`
    /// (the identity `0..n` gives the classic CSC in the caller's numbering).
    ///
    /// # Errors
    /// [`EvalError::Pattern`] when `order` is not a permutation of `0..n_vertices`, or as [`Self::new`].
    pub fn with_vertex_order(
        n_vertices: usize,
        pairs: impl IntoIterator<Item = (usize, usize)>,
        order: &[usize],
    ) -> Result<Self, EvalError> {
        if n_vertices > u32::MAX as usize {
            return Err(too_large("vertex count", n_vertices));
        }
        let mut seen = vec![false; n_vertices];
        if order.len() != n_vertices {
            return Err(EvalError::Pattern {
                message: format!(
                    "vertex order has {} entries, the mesh {} vertices",
                    order.len(),
                    n_vertices
                ),
            });
        }
        for (s, &v) in order.iter().enumerate() {
            if v >= n_vertices || seen[v] {
                return Err(EvalError::Pattern {
                    message: format!(
                        "vertex order: entry {s} ({v}) is out of range or repeated; a permutation of 0..{n_vertices} is needed"
                    ),
                });
            }
            seen[v] = true;
        }
        let p = unique_pairs(n_vertices, pairs);
        Self::build(n_vertices, p, order.iter().map(|&v| v as u32).collect())
    }

    fn build(
        n_vertices: usize,
        pairs: Vec<(u32, u32)>,
        order: Vec<u32>,
    ) -> Result<Self, EvalError> {
        let mut rank = vec![0u32; n_vertices];
        for (s, &v) in order.iter().enumerate() {
            rank[v as usize] = s as u32;
        }
        // (storage col, storage row) with col ≤ row.
        let mut p: Vec<(u32, u32)> = pairs
            .iter()
            .map(|&(a, b)| {
                let (ra, rb) = (rank[a as usize], rank[b as usize]);
                (ra.min(rb), ra.max(rb))
            })
            .chain((0..n_vertices as u32).map(|s| (s, s)))
            .collect();
        p.sort_unstable();
        let mut block_col_ptr = vec![0usize; n_vertices + 1];
        for &(c, _) in &p {
            block_col_ptr[c as usize + 1] += 1;
        }
        for j in 0..n_vertices {
            block_col_ptr[j + 1] += block_col_ptr[j];
        }
        let nnz = check_nnz(n_vertices, pairs.len())?;
        let n = 3 * n_vertices;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::with_capacity(nnz);
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
                    row: order[r as usize],
                    col: order[j],
                    offset: offset.map(|o| o as u32),
                });
            }
        }
        Ok(Self {
            n_vertices,
            col_ptr,
            row_idx,
            blocks,
            block_col_ptr,
            order,
            rank,
        })
    }

    /// The vertex stored at storage position `s`.
    pub fn vertex_at(&self, s: usize) -> usize {
        self.order[s] as usize
    }

    /// The storage position of vertex `v`.
    pub fn storage_of(&self, v: usize) -> usize {
        self.rank[v] as usize
    }

    /// The storage order: `order()[s]` is the vertex at storage position `s`.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Whether the storage order is the caller's numbering (`vertex_at(s) == s` for all `s`).
    pub fn is_identity_order(&self) -> bool {
        self.order.iter().enumerate().all(|(s, &v)| s == v as usize)
    }

    /// The caller's scalar dof (`3v + k`) of storage scalar index `i` (a row or column of the CSC arrays).
    pub fn caller_dof(&self, i: usize) -> usize {
        3 * self.order[i / 3] as usize + i % 3
    }

    /// The storage scalar index of the caller's scalar dof `d = 3v + k`.
    pub fn storage_dof(&self, d: usize) -> usize {
        3 * self.rank[d / 3] as usize + d % 3
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

    /// CSC column pointers (length `3n + 1`), in storage order.
    pub fn col_ptr(&self) -> &[usize] {
        &self.col_ptr
    }

    /// CSC row indices (storage scalar indices), sorted within each column.
    pub fn row_idx(&self) -> &[usize] {
        &self.row_idx
    }

    /// All block slots, by storage block column then storage row.
    pub fn blocks(&self) -> &[BlockSlot] {
        &self.blocks
    }

    /// Value offset where storage block column `j` starts (`j ≤ n`).
    pub fn block_col_value_start(&self, j: usize) -> usize {
        self.col_ptr[3 * j]
    }

    /// The slot index of block `(a, b)` (either order; the caller's vertex numbers), if the pattern holds it.
    /// Used at set-up only.
    pub fn find(&self, a: usize, b: usize) -> Option<usize> {
        if a >= self.n_vertices || b >= self.n_vertices {
            return None;
        }
        self.find_storage(self.storage_of(a), self.storage_of(b))
    }

    /// [`Self::find`] by storage positions.
    pub fn find_storage(&self, a: usize, b: usize) -> Option<usize> {
        let (col, row) = (a.min(b), a.max(b));
        if row >= self.n_vertices {
            return None;
        }
        let range = self.block_col_ptr[col]..self.block_col_ptr[col + 1];
        let rows = &self.blocks[range.clone()];
        rows.binary_search_by_key(&(row as u32), |s| self.rank[s.row as usize])
            .ok()
            .map(|q| range.start + q)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn block_offsets_follow_from_the_first_offset_and_the_column_length() {
        // A small irregular coupling set, in a non-identity order.
        let pairs = [
            (0, 1),
            (1, 2),
            (2, 0),
            (2, 3),
            (3, 4),
            (4, 0),
            (1, 4),
            (5, 2),
        ];
        for p in [
            SymmetricPattern::new(6, pairs).unwrap(),
            SymmetricPattern::with_vertex_order(6, pairs, &[3, 1, 5, 0, 2, 4]).unwrap(),
        ] {
            for s in p.blocks() {
                let col = p.storage_of(s.col as usize);
                let len0 = p.col_ptr()[3 * col + 1] - p.col_ptr()[3 * col];
                let off = crate::bending::scatter::block_offsets(
                    s.offset[0] as usize,
                    len0,
                    s.row == s.col,
                );
                assert_eq!(off, s.offset.map(|o| o as usize), "{s:?}");
            }
        }
    }
}
