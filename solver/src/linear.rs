//! Linear solvers for symmetric sparse systems given as a lower-triangle CSC pattern plus values
//! ([`hinge_core::pattern::SymmetricPattern`]'s layout): analyze once per pattern, factor per Newton
//! iteration, solve per right-hand side.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::perm::PermRef;
use faer::sparse::linalg::LuError as FaerLuError;
use faer::sparse::linalg::cholesky::{
    LltRef, SymbolicCholesky, SymmetricOrdering, factorize_symbolic_cholesky,
};
use faer::sparse::linalg::lu::{LuRef, NumericLu, SymbolicLu, factorize_symbolic_lu};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Side};
use hinge_core::export::CsrLayout;

use crate::ordering::{FillOrdering, nested_dissection};

/// A symmetric sparse matrix pattern in lower-triangle CSC form (rows sorted within each column).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LowerCsc {
    /// Dimension.
    pub n: usize,
    /// Column pointers (`n + 1`).
    pub col_ptr: Vec<usize>,
    /// Row indices (≥ the column), sorted per column.
    pub row_idx: Vec<usize>,
}

impl LowerCsc {
    /// Checks the structure every backend relies on: `n + 1` column pointers from 0 to the number of row
    /// indices, never decreasing, and in each column row indices strictly increasing, from the column's own
    /// index (lower triangle) to below `n`.
    ///
    /// # Errors
    /// [`LinearError::Usage`] naming the first column that breaks it.
    pub fn check(&self) -> Result<(), LinearError> {
        let cp = &self.col_ptr;
        if cp.len() != self.n + 1
            || cp.first() != Some(&0)
            || cp.last() != Some(&self.row_idx.len())
        {
            let got = match (cp.first(), cp.last()) {
                (Some(a), Some(b)) => format!("{} from {a} to {b}", cp.len()),
                _ => "none".into(),
            };
            return Err(LinearError::Usage(format!(
                "a pattern of dimension {} needs {} column pointers from 0 to its {} row indices, got {got}",
                self.n,
                self.n + 1,
                self.row_idx.len(),
            )));
        }
        for c in 0..self.n {
            if cp[c] > cp[c + 1] {
                return Err(LinearError::Usage(format!(
                    "column {c}'s pointers decrease ({} > {})",
                    cp[c],
                    cp[c + 1]
                )));
            }
            let rows = &self.row_idx[cp[c]..cp[c + 1]];
            let mut below = c;
            for (k, &r) in rows.iter().enumerate() {
                if r < below || (k > 0 && r == below) || r >= self.n {
                    return Err(LinearError::Usage(format!(
                        "column {c}: row {r} is not in increasing order within {c}..{} (lower triangle)",
                        self.n
                    )));
                }
                below = r;
            }
        }
        Ok(())
    }

    /// Position of each column's diagonal entry (every column must store its diagonal).
    pub fn diagonal_positions(&self) -> Option<Vec<usize>> {
        (0..self.n)
            .map(|c| {
                let k = self.col_ptr[c];
                (k < self.col_ptr[c + 1] && self.row_idx[k] == c).then_some(k)
            })
            .collect()
    }

    /// `y = A x` for the symmetric matrix with lower-triangle `values`.
    pub fn mul(&self, values: &[f64], x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        for c in 0..self.n {
            for k in self.col_ptr[c]..self.col_ptr[c + 1] {
                let r = self.row_idx[k];
                y[r] += values[k] * x[c];
                if r != c {
                    y[c] += values[k] * x[r];
                }
            }
        }
    }
}

/// Why a linear solve failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LinearError {
    /// The matrix is not positive definite (a Cholesky pivot was not positive).
    #[error("matrix is not positive definite (non-positive pivot at permuted index {index})")]
    NotPositiveDefinite {
        /// Pivot index in the factorization's (permuted) order.
        index: usize,
    },
    /// The matrix is (numerically) singular.
    #[error("matrix is singular or the solution is not finite")]
    Singular,
    /// An iterative method did not reach its tolerance.
    #[error(
        "{method} did not converge: relative residual {residual:e} after {iterations} iterations"
    )]
    NotConverged {
        /// The method.
        method: &'static str,
        /// Iterations done.
        iterations: usize,
        /// Final relative residual.
        residual: f64,
    },
    /// `factor` or `solve` before `analyze`, or sizes that do not match.
    #[error("solver used out of order or with mismatched sizes: {0}")]
    Usage(String),
    /// An error inside faer.
    #[error("faer: {0}")]
    Faer(String),
}

/// The default backend: faer's sparse LLᵀ with symbolic reuse (Newton's inertia correction handles the
/// indefinite case by shifting the diagonal).
pub fn default_solver() -> Box<dyn LinearSolver> {
    Box::new(FaerLlt::default())
}

/// Analyze / factor / solve for symmetric systems.
pub trait LinearSolver: Send {
    /// A short name for reports (`faer-llt`, `faer-lu`, `pcg-jacobi`, `chebyshev-jacobi`, `dense`).
    fn name(&self) -> &'static str;

    /// Symbolic analysis of a pattern (once per pattern).
    ///
    /// # Errors
    /// [`LinearError`].
    fn analyze(&mut self, pattern: &LowerCsc) -> Result<(), LinearError>;

    /// Numeric factorization (or preconditioner set-up) for `values` in the analyzed pattern. A failed
    /// factorization discards the one before it: `solve` then refuses until a factorization succeeds.
    ///
    /// # Errors
    /// [`LinearError::NotPositiveDefinite`] for a Cholesky backend on an indefinite matrix, and so on;
    /// [`LinearError::Usage`] before `analyze` or for values whose count is not the pattern's.
    fn factor(&mut self, values: &[f64]) -> Result<(), LinearError>;

    /// Solves in place: `rhs` becomes `A⁻¹ rhs`.
    ///
    /// # Errors
    /// [`LinearError::Usage`] before a successful `factor` or for a right-hand side whose length is not
    /// the dimension (`rhs` is then untouched); otherwise as the backend says (a non-finite solution is
    /// [`LinearError::Singular`]).
    fn solve(&mut self, rhs: &mut [f64]) -> Result<(), LinearError>;

    /// How many symbolic analyses this solver has done (to check reuse).
    fn analyses(&self) -> usize;
}

/// [`LinearError::Usage`] unless the right-hand side's length `len` is the matrix dimension `n`.
fn check_rhs(len: usize, n: usize) -> Result<(), LinearError> {
    if len == n {
        Ok(())
    } else {
        Err(LinearError::Usage(format!(
            "right-hand side of length {len} for a matrix of dimension {n}"
        )))
    }
}

/// [`LinearError::Usage`] unless there are as many `values` as the pattern `p` has entries.
fn check_values(values: &[f64], p: &LowerCsc) -> Result<(), LinearError> {
    if values.len() == p.row_idx.len() {
        Ok(())
    } else {
        Err(LinearError::Usage(format!(
            "{} values for {} entries",
            values.len(),
            p.row_idx.len()
        )))
    }
}

fn not_factored() -> LinearError {
    LinearError::Usage("solve before a successful factor".into())
}

fn check_finite(x: &[f64]) -> Result<(), LinearError> {
    if x.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(LinearError::Singular)
    }
}

/// faer's sparse supernodal/simplicial LLᵀ with the symbolic analysis reused across factorizations (the
/// default backend). The factor's storage and faer's work space are kept too: once the first
/// factorization has run, neither factoring nor solving allocates.
///
/// It factors on the calling thread ([`FaerLlt::default`]): faer's rayon-parallel factorization allocates
/// its task bookkeeping on every call (about 800 allocations per factorization of the drape's Hessian)
/// and was slower on the built-in scenes on this project's 2-core VM (drape 6.2–7.1 s against 5.6–5.7 s
/// sequential; 15 frames of `shell-drop` 15.0–15.5 s against 12.6–13.9 s; one factorization of 121 203
/// unknowns 1 576 ms against 1 378 ms). [`FaerLlt::parallel`] uses
/// faer's global parallelism (rayon's pool) instead, for large meshes on many cores. Either way the
/// results do not depend on the thread count.
///
/// The fill-reducing ordering is chosen at analysis ([`FaerLlt::with_ordering`],
/// [`crate::ordering::FillOrdering`]): by default both faer's AMD and this crate's nested dissection are
/// analysed and the one with the smaller factor is kept (AMD on a tie). Nested dissection wins on closed
/// shells and large sheets (an icosphere of 10 242 vertices: 10.8 M factor entries against 14.1 M with
/// AMD, factorization 212 ms against 339 ms), AMD on small sheets; [`FaerLlt::ordering_used`] tells which.
#[derive(Default)]
pub struct FaerLlt {
    pattern: Option<LowerCsc>,
    symbolic: Option<SymbolicCholesky<usize>>,
    factor: Vec<f64>,
    factored: bool,
    stack: Option<MemBuffer>,
    analyses: usize,
    parallel: bool,
    ordering: FillOrdering,
    used: Option<FillOrdering>,
}

impl FaerLlt {
    /// A sequential factorization in the given fill-reducing ordering (the default is
    /// [`FillOrdering::Auto`]; see [`crate::ordering`]).
    pub fn with_ordering(ordering: FillOrdering) -> Self {
        Self {
            ordering,
            ..Self::default()
        }
    }

    /// The ordering the last analysis factors in ([`FillOrdering::Amd`] or
    /// [`FillOrdering::NestedDissection`]; `None` before [`LinearSolver::analyze`]).
    pub fn ordering_used(&self) -> Option<FillOrdering> {
        self.used
    }

    /// Entries of the Cholesky factor of the analysed pattern (`None` before [`LinearSolver::analyze`]).
    pub fn factor_entries(&self) -> Option<usize> {
        self.symbolic.as_ref().map(SymbolicCholesky::len_val)
    }

    /// A factorization that runs on faer's global parallelism (`faer::get_global_parallelism`, rayon's
    /// pool by default): for large meshes on many cores. It allocates faer's task bookkeeping on every
    /// factorization.
    pub fn parallel() -> Self {
        Self {
            parallel: true,
            ..Self::default()
        }
    }

    fn par(&self) -> faer::Par {
        if self.parallel {
            faer::get_global_parallelism()
        } else {
            faer::Par::Seq
        }
    }
}

impl std::fmt::Debug for FaerLlt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FaerLlt")
            .field("n", &self.pattern.as_ref().map(|p| p.n))
            .field("factored", &self.factored)
            .field("analyses", &self.analyses)
            .field("parallel", &self.parallel)
            .field("ordering", &self.ordering)
            .field("used", &self.used)
            .finish()
    }
}

impl LinearSolver for FaerLlt {
    fn name(&self) -> &'static str {
        "faer-llt"
    }

    fn analyze(&mut self, pattern: &LowerCsc) -> Result<(), LinearError> {
        pattern.check()?;
        let sym = SymbolicSparseColMatRef::new_checked(
            pattern.n,
            pattern.n,
            &pattern.col_ptr,
            None,
            &pattern.row_idx,
        );
        let analyse = |ordering: SymmetricOrdering<'_, usize>| {
            factorize_symbolic_cholesky(sym, Side::Lower, ordering, Default::default())
                .map_err(|e| LinearError::Faer(format!("{e:?}")))
        };
        let nested = |pattern: &LowerCsc| -> Result<SymbolicCholesky<usize>, LinearError> {
            let forward = nested_dissection(pattern)?;
            let mut inverse = vec![0; forward.len()];
            for (k, &i) in forward.iter().enumerate() {
                inverse[i] = k;
            }
            let perm = PermRef::new_checked(&forward, &inverse, pattern.n);
            analyse(SymmetricOrdering::Custom(perm))
        };
        let (symbolic, used) = match self.ordering {
            FillOrdering::Amd => (analyse(SymmetricOrdering::Amd)?, FillOrdering::Amd),
            FillOrdering::NestedDissection => (nested(pattern)?, FillOrdering::NestedDissection),
            FillOrdering::Auto => {
                let amd = analyse(SymmetricOrdering::Amd)?;
                let nd = nested(pattern)?;
                if nd.len_val() < amd.len_val() {
                    (nd, FillOrdering::NestedDissection)
                } else {
                    (amd, FillOrdering::Amd)
                }
            }
        };
        self.used = Some(used);
        let par = self.par();
        self.stack = Some(MemBuffer::new(
            symbolic
                .factorize_numeric_llt_scratch::<f64>(par, Default::default())
                .or(symbolic.solve_in_place_scratch::<f64>(1, par)),
        ));
        self.symbolic = Some(symbolic);
        self.pattern = Some(pattern.clone());
        self.factored = false;
        self.analyses += 1;
        Ok(())
    }

    fn factor(&mut self, values: &[f64]) -> Result<(), LinearError> {
        let par = self.par();
        let (Some(p), Some(s), Some(stack)) = (&self.pattern, &self.symbolic, &mut self.stack)
        else {
            return Err(LinearError::Usage("factor before analyze".into()));
        };
        self.factored = false;
        check_values(values, p)?;
        self.factor.resize(s.len_val(), 0.0);
        let sym = SymbolicSparseColMatRef::new_checked(p.n, p.n, &p.col_ptr, None, &p.row_idx);
        match s.factorize_numeric_llt(
            &mut self.factor,
            SparseColMatRef::new(sym, values),
            Side::Lower,
            Default::default(),
            par,
            MemStack::new(stack),
            Default::default(),
        ) {
            Ok(_) => {
                self.factored = true;
                Ok(())
            }
            Err(faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index }) => {
                Err(LinearError::NotPositiveDefinite { index })
            }
        }
    }

    fn solve(&mut self, rhs: &mut [f64]) -> Result<(), LinearError> {
        let par = self.par();
        let (Some(s), Some(stack), true) = (&self.symbolic, &mut self.stack, self.factored) else {
            return Err(not_factored());
        };
        let n = rhs.len();
        check_rhs(n, s.nrows())?;
        LltRef::new(s, &self.factor).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(rhs, n, 1),
            par,
            MemStack::new(stack),
        );
        check_finite(rhs)
    }

    fn analyses(&self) -> usize {
        self.analyses
    }
}

/// faer's sparse LU with partial pivoting on the full symmetric matrix: for indefinite systems (exact Newton on
/// an indefinite Hessian). The full pattern, the symbolic analysis and faer's work space are built once at
/// analysis; the factorization runs on the calling thread, so its results do not depend on the thread count.
#[derive(Default)]
pub struct FaerLu {
    /// The full symmetric structure and where each lower value goes in it.
    full: Option<CsrLayout>,
    values: Vec<f64>,
    symbolic: Option<SymbolicLu<usize>>,
    numeric: NumericLu<usize, f64>,
    stack: Option<MemBuffer>,
    factored: bool,
    analyses: usize,
}

impl std::fmt::Debug for FaerLu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FaerLu")
            .field("n", &self.full.as_ref().map(|l| l.row_ptr().len() - 1))
            .field("factored", &self.factored)
            .field("analyses", &self.analyses)
            .finish()
    }
}

impl LinearSolver for FaerLu {
    fn name(&self) -> &'static str {
        "faer-lu"
    }

    fn analyze(&mut self, p: &LowerCsc) -> Result<(), LinearError> {
        p.check()?;
        // The full symmetric matrix: its CSR layout is its CSC layout too.
        let full = CsrLayout::from_lower(p.n, &p.col_ptr, &p.row_idx);
        let sym =
            SymbolicSparseColMatRef::new_checked(p.n, p.n, full.row_ptr(), None, full.col_idx());
        let symbolic = factorize_symbolic_lu(sym, Default::default())
            .map_err(|e| LinearError::Faer(format!("{e:?}")))?;
        self.stack = Some(MemBuffer::new(
            symbolic
                .factorize_numeric_lu_scratch::<f64>(faer::Par::Seq, Default::default())
                .or(symbolic.solve_in_place_scratch::<f64>(1, faer::Par::Seq)),
        ));
        self.symbolic = Some(symbolic);
        self.values = vec![0.0; full.nnz()];
        self.full = Some(full);
        self.factored = false;
        self.analyses += 1;
        Ok(())
    }

    fn factor(&mut self, values: &[f64]) -> Result<(), LinearError> {
        let (Some(s), Some(full), Some(stack)) = (&self.symbolic, &self.full, &mut self.stack)
        else {
            return Err(LinearError::Usage("factor before analyze".into()));
        };
        self.factored = false;
        full.scatter(values, &mut self.values)
            .map_err(|e| LinearError::Usage(e.to_string()))?;
        let n = full.row_ptr().len() - 1;
        let sym = SymbolicSparseColMatRef::new_checked(n, n, full.row_ptr(), None, full.col_idx());
        s.factorize_numeric_lu(
            &mut self.numeric,
            SparseColMatRef::new(sym, &self.values),
            faer::Par::Seq,
            MemStack::new(stack),
            Default::default(),
        )
        .map_err(|e| match e {
            FaerLuError::SymbolicSingular { .. } => LinearError::Singular,
            FaerLuError::Generic(e) => LinearError::Faer(format!("{e:?}")),
        })?;
        self.factored = true;
        Ok(())
    }

    fn solve(&mut self, rhs: &mut [f64]) -> Result<(), LinearError> {
        let (Some(s), Some(stack), true) = (&self.symbolic, &mut self.stack, self.factored) else {
            return Err(not_factored());
        };
        let n = rhs.len();
        check_rhs(n, s.nrows())?;
        LuRef::new_unchecked(s, &self.numeric).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(rhs, n, 1),
            faer::Par::Seq,
            MemStack::new(stack),
        );
        check_finite(rhs)
    }

    fn analyses(&self) -> usize {
        self.analyses
    }
}

/// Conjugate gradients with a Jacobi (diagonal) preconditioner. For symmetric positive definite systems.
#[derive(Debug)]
pub struct PcgJacobi {
    /// Relative residual tolerance.
    pub tolerance: f64,
    /// Iteration limit.
    pub max_iterations: usize,
    jacobi: JacobiSystem,
    /// Iterations used by the last solve.
    pub last_iterations: usize,
}

impl PcgJacobi {
    /// A solver with relative tolerance `tolerance` and at most `max_iterations` iterations.
    pub fn new(tolerance: f64, max_iterations: usize) -> Self {
        Self {
            tolerance,
            max_iterations,
            jacobi: JacobiSystem::default(),
            last_iterations: 0,
        }
    }
}

/// The state the Jacobi-based iterative solvers share: the pattern, its diagonal positions, the matrix
/// values and the inverse diagonal.
#[derive(Debug, Default)]
struct JacobiSystem {
    pattern: Option<LowerCsc>,
    diag: Vec<usize>,
    values: Vec<f64>,
    inv_diag: Vec<f64>,
    /// Whether `values` and `inv_diag` hold the last successful factorization.
    factored: bool,
    analyses: usize,
}

impl JacobiSystem {
    fn analyze(&mut self, p: &LowerCsc) -> Result<(), LinearError> {
        p.check()?;
        self.diag = p
            .diagonal_positions()
            .ok_or_else(|| LinearError::Usage("every column must store its diagonal".into()))?;
        self.factored = false;
        self.pattern = Some(p.clone());
        self.analyses += 1;
        Ok(())
    }

    fn factor(&mut self, values: &[f64]) -> Result<(), LinearError> {
        self.factored = false;
        let Some(p) = &self.pattern else {
            return Err(LinearError::Usage("factor before analyze".into()));
        };
        jacobi_setup(p, &self.diag, values, &mut self.values, &mut self.inv_diag)?;
        self.factored = true;
        Ok(())
    }

    /// The pattern, values and inverse diagonal of the last successful factorization.
    fn factored(&self) -> Result<(&LowerCsc, &[f64], &[f64]), LinearError> {
        match (&self.pattern, self.factored) {
            (Some(p), true) => Ok((p, &self.values, &self.inv_diag)),
            _ => Err(not_factored()),
        }
    }
}

fn jacobi_setup(
    p: &LowerCsc,
    diag: &[usize],
    values: &[f64],
    out_values: &mut Vec<f64>,
    inv: &mut Vec<f64>,
) -> Result<(), LinearError> {
    check_values(values, p)?;
    out_values.clear();
    out_values.extend_from_slice(values);
    inv.clear();
    for (i, &k) in diag.iter().enumerate() {
        let d = values[k];
        if !(d > 0.0) || !d.is_finite() {
            return Err(LinearError::NotPositiveDefinite { index: i });
        }
        inv.push(1.0 / d);
    }
    Ok(())
}

impl LinearSolver for PcgJacobi {
    fn name(&self) -> &'static str {
        "pcg-jacobi"
    }

    fn analyze(&mut self, p: &LowerCsc) -> Result<(), LinearError> {
        self.jacobi.analyze(p)
    }

    fn factor(&mut self, values: &[f64]) -> Result<(), LinearError> {
        self.jacobi.factor(values)
    }

    fn solve(&mut self, b: &mut [f64]) -> Result<(), LinearError> {
        let (p, values, inv_diag) = self.jacobi.factored()?;
        check_rhs(b.len(), p.n)?;
        let n = p.n;
        let bnorm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut x = vec![0.0; n];
        if bnorm == 0.0 {
            b.fill(0.0);
            return Ok(());
        }
        let mut r = b.to_vec();
        let mut z: Vec<f64> = r.iter().zip(inv_diag).map(|(a, d)| a * d).collect();
        let mut d = z.clone();
        let mut q = vec![0.0; n];
        let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
        let mut res = 1.0;
        for it in 0..self.max_iterations {
            p.mul(values, &d, &mut q);
            let dq: f64 = d.iter().zip(&q).map(|(a, b)| a * b).sum();
            if !(dq > 0.0) {
                return Err(LinearError::NotPositiveDefinite { index: it });
            }
            let alpha = rz / dq;
            for i in 0..n {
                x[i] += alpha * d[i];
                r[i] -= alpha * q[i];
            }
            res = r.iter().map(|v| v * v).sum::<f64>().sqrt() / bnorm;
            if res <= self.tolerance {
                self.last_iterations = it + 1;
                b.copy_from_slice(&x);
                return check_finite(b);
            }
            for i in 0..n {
                z[i] = r[i] * inv_diag[i];
            }
            let rz_new: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..n {
                d[i] = z[i] + beta * d[i];
            }
        }
        self.last_iterations = self.max_iterations;
        Err(LinearError::NotConverged {
            method: "pcg-jacobi",
            iterations: self.max_iterations,
            residual: res,
        })
    }

    fn analyses(&self) -> usize {
        self.jacobi.analyses
    }
}

/// Jacobi iteration with Chebyshev acceleration (lecture P24–P26):
/// `x_{k+1} = ω_{k+1} (x̃_{k+1} − x_{k−1}) + x_{k−1}`, `x̃_{k+1}` the Jacobi update of `x_k`,
/// `ω_1 = 1`, `ω_2 = 2/(2 − ρ²)`, `ω_{k+1} = 4/(4 − ρ² ω_k)`, with ρ the spectral radius of the Jacobi
/// iteration matrix `I − D⁻¹A`, estimated at factorization by power iteration. Converges when ρ < 1 (for
/// example diagonally dominant systems such as `M/Δt² + H` at small steps).
#[derive(Debug)]
pub struct ChebyshevJacobi {
    /// Relative residual tolerance.
    pub tolerance: f64,
    /// Iteration limit.
    pub max_iterations: usize,
    jacobi: JacobiSystem,
    rho: f64,
    /// Iterations used by the last solve.
    pub last_iterations: usize,
}

impl ChebyshevJacobi {
    /// A solver with relative tolerance `tolerance` and at most `max_iterations` iterations.
    pub fn new(tolerance: f64, max_iterations: usize) -> Self {
        Self {
            tolerance,
            max_iterations,
            jacobi: JacobiSystem::default(),
            rho: 0.0,
            last_iterations: 0,
        }
    }

    /// The estimated spectral radius of the Jacobi iteration matrix.
    pub fn rho(&self) -> f64 {
        self.rho
    }
}

impl LinearSolver for ChebyshevJacobi {
    fn name(&self) -> &'static str {
        "chebyshev-jacobi"
    }

    fn analyze(&mut self, p: &LowerCsc) -> Result<(), LinearError> {
        self.jacobi.analyze(p)
    }

    fn factor(&mut self, values: &[f64]) -> Result<(), LinearError> {
        self.jacobi.factor(values)?;
        let (p, values, inv_diag) = self.jacobi.factored()?;
        // Power iteration on J = I − D⁻¹A from a fixed, non-symmetric start vector.
        let n = p.n;
        let mut v: Vec<f64> = (0..n)
            .map(|i| 1.0 + ((i * 7919) % 13) as f64 / 13.0)
            .collect();
        let mut av = vec![0.0; n];
        let mut lambda = 0.0;
        for _ in 0..60 {
            p.mul(values, &v, &mut av);
            let w: Vec<f64> = v
                .iter()
                .zip(&av)
                .zip(inv_diag)
                .map(|((vi, ai), d)| vi - d * ai)
                .collect();
            let norm = w.iter().map(|x| x * x).sum::<f64>().sqrt();
            let vnorm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm == 0.0 {
                break;
            }
            lambda = norm / vnorm;
            v = w.iter().map(|x| x / norm).collect();
        }
        // A little safety margin: Chebyshev needs an upper bound of ρ.
        self.rho = (lambda * 1.02).min(0.999_999);
        if lambda >= 1.0 {
            // No solve with a preconditioner that cannot converge.
            self.jacobi.factored = false;
            return Err(LinearError::NotConverged {
                method: "chebyshev-jacobi (Jacobi diverges: spectral radius ≥ 1)",
                iterations: 0,
                residual: lambda,
            });
        }
        Ok(())
    }

    fn solve(&mut self, b: &mut [f64]) -> Result<(), LinearError> {
        let (p, values, inv_diag) = self.jacobi.factored()?;
        check_rhs(b.len(), p.n)?;
        let n = p.n;
        let bnorm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        if bnorm == 0.0 {
            return Ok(());
        }
        let (mut prev, mut x) = (vec![0.0; n], vec![0.0; n]);
        let mut ax = vec![0.0; n];
        let mut omega = 1.0;
        let rho2 = self.rho * self.rho;
        let mut res = 1.0;
        for k in 0..self.max_iterations {
            p.mul(values, &x, &mut ax);
            res = ax
                .iter()
                .zip(b.iter())
                .map(|(a, bi)| (bi - a) * (bi - a))
                .sum::<f64>()
                .sqrt()
                / bnorm;
            if res <= self.tolerance {
                self.last_iterations = k;
                b.copy_from_slice(&x);
                return check_finite(b);
            }
            omega = match k {
                0 => 1.0,
                1 => 2.0 / (2.0 - rho2),
                _ => 4.0 / (4.0 - rho2 * omega),
            };
            for i in 0..n {
                let jacobi = x[i] + inv_diag[i] * (b[i] - ax[i]);
                let next = omega * (jacobi - prev[i]) + prev[i];
                prev[i] = x[i];
                x[i] = next;
            }
        }
        self.last_iterations = self.max_iterations;
        Err(LinearError::NotConverged {
            method: "chebyshev-jacobi",
            iterations: self.max_iterations,
            residual: res,
        })
    }

    fn analyses(&self) -> usize {
        self.jacobi.analyses
    }
}

/// Dense nalgebra Cholesky (LU fallback is not attempted: an indefinite matrix is reported): for tiny
/// systems and as a test oracle.
#[derive(Debug, Default)]
pub struct Dense {
    pattern: Option<LowerCsc>,
    chol: Option<nalgebra::Cholesky<f64, nalgebra::Dyn>>,
    analyses: usize,
}

impl LinearSolver for Dense {
    fn name(&self) -> &'static str {
        "dense"
    }

    fn analyze(&mut self, p: &LowerCsc) -> Result<(), LinearError> {
        p.check()?;
        self.chol = None;
        self.pattern = Some(p.clone());
        self.analyses += 1;
        Ok(())
    }

    fn factor(&mut self, values: &[f64]) -> Result<(), LinearError> {
        self.chol = None;
        let Some(p) = &self.pattern else {
            return Err(LinearError::Usage("factor before analyze".into()));
        };
        check_values(values, p)?;
        let mut a = nalgebra::DMatrix::zeros(p.n, p.n);
        for c in 0..p.n {
            for k in p.col_ptr[c]..p.col_ptr[c + 1] {
                let r = p.row_idx[k];
                a[(r, c)] = values[k];
                a[(c, r)] = values[k];
            }
        }
        self.chol = Some(
            a.cholesky()
                .ok_or(LinearError::NotPositiveDefinite { index: 0 })?,
        );
        Ok(())
    }

    fn solve(&mut self, rhs: &mut [f64]) -> Result<(), LinearError> {
        let (Some(p), Some(c)) = (&self.pattern, &self.chol) else {
            return Err(not_factored());
        };
        check_rhs(rhs.len(), p.n)?;
        let x = c.solve(&nalgebra::DVector::from_column_slice(rhs));
        rhs.copy_from_slice(x.as_slice());
        check_finite(rhs)
    }

    fn analyses(&self) -> usize {
        self.analyses
    }
}
