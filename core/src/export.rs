//! Exporting an assembled Hessian: full CSR arrays, a faer sparse matrix view, Matrix Market files, and the
//! gradient as text. Values always come from [`crate::pattern::SymmetricPattern`]'s lower-triangle CSC order
//! (its storage order); every export but [`faer_lower`] is in the caller's numbering.

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
/// `Side::Lower`. The view is in the pattern's **storage order**: row/column `i` is the caller's dof
/// [`SymmetricPattern::caller_dof`]`(i)`, so permute right-hand sides with
/// [`SymmetricPattern::storage_dof`] (or build the pattern with
/// [`SymmetricPattern::with_vertex_order`] and the identity for a view in the caller's numbering).
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

/// The full symmetric matrix as a dense `3n × 3n` nalgebra matrix in the caller's numbering (for small
/// problems and tests).
///
/// # Errors
/// [`EvalError::BufferLength`] when `values` does not fit the pattern.
pub fn dense(
    pattern: &SymmetricPattern,
    values: &[f64],
) -> Result<nalgebra::DMatrix<f64>, EvalError> {
    check_len(pattern, values)?;
    let n = pattern.dim();
    let mut d = nalgebra::DMatrix::zeros(n, n);
    let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
    for c in 0..n {
        let mc = pattern.caller_dof(c);
        for k in cp[c]..cp[c + 1] {
            let mr = pattern.caller_dof(ri[k]);
            d[(mr, mc)] = values[k];
            d[(mc, mr)] = values[k];
        }
    }
    Ok(d)
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
    /// Builds the layout of `pattern`, in the caller's numbering (rows and columns are the caller's dofs
    /// whatever the pattern's storage order).
    pub fn new(pattern: &SymmetricPattern) -> Self {
        if pattern.is_identity_order() {
            Self::from_lower(pattern.dim(), pattern.col_ptr(), pattern.row_idx())
        } else {
            Self::from_lower_mapped(pattern.dim(), pattern.col_ptr(), pattern.row_idx(), |i| {
                pattern.caller_dof(i)
            })
        }
    }

    /// Builds the layout of any lower-triangle CSC structure of an `n × n` symmetric matrix (column
    /// pointers `n + 1`, row indices ≥ the column). The full symmetric CSR it describes is also the full
    /// CSC (the matrix is symmetric), which is how faer's LU takes it.
    pub fn from_lower(n: usize, cp: &[usize], ri: &[usize]) -> Self {
        Self::from_lower_mapped(n, cp, ri, |i| i)
    }

    /// [`CsrLayout::from_lower`] of the matrix renumbered by `map` (a permutation of `0..n`: row and column
    /// `i` of the lower CSC become `map(i)` in the CSR).
    pub fn from_lower_mapped(
        n: usize,
        cp: &[usize],
        ri: &[usize],
        map: impl Fn(usize) -> usize,
    ) -> Self {
        let nnz = ri.len();
        // (row, col, lower value index, whether this is the mirrored entry), both triangles.
        let mut entries: Vec<(usize, usize, usize, bool)> = Vec::with_capacity(2 * nnz);
        for c in 0..n {
            let mc = map(c);
            for k in cp[c]..cp[c + 1] {
                let mr = map(ri[k]);
                entries.push((mr, mc, k, false));
                if mr != mc {
                    entries.push((mc, mr, k, true));
                }
            }
        }
        entries.sort_unstable_by_key(|&(r, c, _, _)| (r, c));
        let mut row_ptr = vec![0usize; n + 1];
        for &(r, _, _, _) in &entries {
            row_ptr[r + 1] += 1;
        }
        for i in 0..n {
            row_ptr[i + 1] += row_ptr[i];
        }
        let (mut lower, mut upper) = (vec![0usize; nnz], vec![usize::MAX; nnz]);
        let mut col_idx = Vec::with_capacity(entries.len());
        for (q, &(_, c, k, mirrored)) in entries.iter().enumerate() {
            col_idx.push(c);
            if mirrored {
                upper[k] = q;
            } else {
                lower[k] = q;
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

/// Writes the lower triangle as Matrix Market `coordinate real symmetric`, 1-based, 17 significant digits, in
/// the caller's numbering (entries sorted by column, then row).
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
    // In the caller's numbering, each entry as (row ≥ column), sorted by column then row.
    let mut entries: Vec<(usize, usize, usize)> = Vec::with_capacity(pattern.nnz());
    for c in 0..n {
        for k in cp[c]..cp[c + 1] {
            let (a, b) = (pattern.caller_dof(ri[k]), pattern.caller_dof(c));
            entries.push((a.min(b), a.max(b), k));
        }
    }
    entries.sort_unstable();
    for (c, r, k) in entries {
        writeln!(out, "{} {} {:.16e}", r + 1, c + 1, values[k])?;
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
