//! Exporting an assembled Hessian: full CSR arrays, a faer sparse matrix view, Matrix Market files, and the
//! gradient as text. Values always come from [`crate::pattern::SymmetricPattern`]'s lower-triangle CSC order.

use std::io::Write;

use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};

use crate::error::EvalError;
use crate::pattern::SymmetricPattern;

fn check_len(pattern: &SymmetricPattern, values: &[f64]) -> Result<(), EvalError> {
    if values.len() == pattern.nnz() {
        Ok(())
    } else {
        Err(EvalError::BufferLength {
            buffer: "hessian",
            expected: pattern.nnz(),
            got: values.len(),
        })
    }
}

/// The lower triangle as a faer sparse matrix view (no copy), the input faer's sparse Cholesky takes with
/// `Side::Lower`.
///
/// # Errors
/// [`EvalError::BufferLength`] when `values` does not fit the pattern.
pub fn faer_lower<'a>(
    pattern: &'a SymmetricPattern,
    values: &'a [f64],
) -> Result<SparseColMatRef<'a, usize, f64>, EvalError> {
    check_len(pattern, values)?;
    let n = pattern.dim();
    let symbolic =
        SymbolicSparseColMatRef::new_checked(n, n, pattern.col_ptr(), None, pattern.row_idx());
    Ok(SparseColMatRef::new(symbolic, values))
}

/// CSR arrays `(row_ptr, col_idx, values)`.
pub type CsrArrays = (Vec<usize>, Vec<usize>, Vec<f64>);

/// The full symmetric matrix (both triangles) as CSR arrays `(row_ptr, col_idx, values)`, columns sorted.
///
/// # Errors
/// [`EvalError::BufferLength`] when `values` does not fit the pattern.
pub fn full_csr(pattern: &SymmetricPattern, values: &[f64]) -> Result<CsrArrays, EvalError> {
    check_len(pattern, values)?;
    let layout = CsrLayout::new(pattern);
    let mut vals = vec![0.0; layout.nnz()];
    layout.scatter(values, &mut vals)?;
    Ok((layout.row_ptr, layout.col_idx, vals))
}

/// The full symmetric CSR structure of a pattern (both triangles, columns sorted per row), built once, and
/// where each lower-triangle value goes: [`CsrLayout::scatter`] then fills a caller's CSR value array on
/// every evaluation without allocating or searching.
///
/// ```
/// use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
/// use hinge_core::export::CsrLayout;
/// use hinge_core::grid::{grid, wave, Diagonal};
/// use hinge_core::psi::TanBending;
///
/// let rest = grid(4, 4, 1.0, 1.0, Diagonal::Alternating).unwrap();
/// let model = BendingModel::new(&rest, TanBending { k: 1.0 }).unwrap();
/// let layout = CsrLayout::new(model.pattern());
/// // The caller owns the CSR arrays (here: copies of ours).
/// let (row_ptr, col_idx) = (layout.row_ptr().to_vec(), layout.col_idx().to_vec());
/// let mut values = vec![0.0; col_idx.len()];
/// let e = model
///     .evaluate(&wave(rest.positions()), Request::ALL, Method::Refactored, Parallelism::Sequential)
///     .unwrap();
/// layout.scatter(&e.hessian, &mut values).unwrap();
/// // Symmetric: entry (r, c) equals (c, r).
/// let at = |r: usize, c: usize| {
///     (row_ptr[r]..row_ptr[r + 1]).find(|&k| col_idx[k] == c).map(|k| values[k])
/// };
/// assert_eq!(at(0, 5), at(5, 0));
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CsrLayout {
    row_ptr: Vec<usize>,
    col_idx: Vec<usize>,
    /// For lower value k: its slot in row r (entry (r, c)).
    lower: Vec<usize>,
    /// For lower value k off the diagonal: its slot in row c (entry (c, r)); `usize::MAX` on the diagonal.
    upper: Vec<usize>,
    lower_nnz: usize,
}

impl CsrLayout {
    /// Builds the layout of `pattern`.
    pub fn new(pattern: &SymmetricPattern) -> Self {
        Self::from_lower(pattern.dim(), pattern.col_ptr(), pattern.row_idx())
    }

    /// Builds the layout of any lower-triangle CSC structure of an `n × n` symmetric matrix (column
    /// pointers `n + 1`, row indices ≥ the column). The full symmetric CSR it describes is also the full
    /// CSC (the matrix is symmetric), which is how faer's LU takes it.
    pub fn from_lower(n: usize, cp: &[usize], ri: &[usize]) -> Self {
        let mut count = vec![0usize; n + 1];
        for c in 0..n {
            for &r in &ri[cp[c]..cp[c + 1]] {
                count[r + 1] += 1;
                if r != c {
                    count[c + 1] += 1;
                }
            }
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let row_ptr = count.clone();
        let mut next = count;
        let nnz = ri.len();
        let mut col_idx = vec![0usize; row_ptr[n]];
        let (mut lower, mut upper) = (vec![0usize; nnz], vec![usize::MAX; nnz]);
        // Row r of the full matrix = row r of the lower part plus column r of it (as the upper part). Visiting
        // entries (r, c), c ≤ r, by increasing c, row r receives its columns c < r in increasing order, then
        // row c receives (c, r') for r' > c after all its smaller columns: every row comes out sorted.
        for c in 0..n {
            for k in cp[c]..cp[c + 1] {
                let r = ri[k];
                col_idx[next[r]] = c;
                lower[k] = next[r];
                next[r] += 1;
            }
            for k in cp[c]..cp[c + 1] {
                let r = ri[k];
                if r != c {
                    col_idx[next[c]] = r;
                    upper[k] = next[c];
                    next[c] += 1;
                }
            }
        }
        Self {
            row_ptr,
            col_idx,
            lower,
            upper,
            lower_nnz: nnz,
        }
    }

    /// Row pointers (`3n + 1`).
    pub fn row_ptr(&self) -> &[usize] {
        &self.row_ptr
    }

    /// Column indices, sorted within each row.
    pub fn col_idx(&self) -> &[usize] {
        &self.col_idx
    }

    /// Number of stored entries of the full matrix.
    pub fn nnz(&self) -> usize {
        self.col_idx.len()
    }

    /// Writes the full matrix's values into `csr_values` (overwriting) from the lower-triangle `values`.
    ///
    /// # Errors
    /// [`EvalError::BufferLength`] when either buffer has the wrong length.
    pub fn scatter(&self, values: &[f64], csr_values: &mut [f64]) -> Result<(), EvalError> {
        if values.len() != self.lower_nnz {
            return Err(EvalError::BufferLength {
                buffer: "hessian",
                expected: self.lower_nnz,
                got: values.len(),
            });
        }
        if csr_values.len() != self.nnz() {
            return Err(EvalError::BufferLength {
                buffer: "csr values",
                expected: self.nnz(),
                got: csr_values.len(),
            });
        }
        for (k, &v) in values.iter().enumerate() {
            csr_values[self.lower[k]] = v;
            let u = self.upper[k];
            if u != usize::MAX {
                csr_values[u] = v;
            }
        }
        Ok(())
    }
}

/// Writes the lower triangle as Matrix Market `coordinate real symmetric`, 1-based, 17 significant digits.
///
/// # Errors
/// I/O errors of the writer; `InvalidInput` when `values` does not fit the pattern.
pub fn write_matrix_market(
    mut out: impl Write,
    pattern: &SymmetricPattern,
    values: &[f64],
) -> std::io::Result<()> {
    check_len(pattern, values)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e.to_string()))?;
    let n = pattern.dim();
    writeln!(out, "%%MatrixMarket matrix coordinate real symmetric")?;
    writeln!(out, "% hinge: lower triangle of the energy Hessian")?;
    writeln!(out, "{n} {n} {}", pattern.nnz())?;
    let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
    for c in 0..n {
        for k in cp[c]..cp[c + 1] {
            writeln!(out, "{} {} {:.16e}", ri[k] + 1, c + 1, values[k])?;
        }
    }
    out.flush()
}

/// Writes a vector one value per line with 17 significant digits.
///
/// # Errors
/// I/O errors of the writer.
pub fn write_vector(mut out: impl Write, values: &[f64]) -> std::io::Result<()> {
    for v in values {
        writeln!(out, "{v:.16e}")?;
    }
    out.flush()
}
