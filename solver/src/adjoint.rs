//! Derivatives of static equilibria with respect to parameters (adjoint method), and fitting parameters to a
//! measured shape.
//!
//! An equilibrium `x*(p)` satisfies `g(x*, p) = ∇ₓE(x*, p) = 0` on the free degrees of freedom (pins
//! eliminated). For a loss `L(x*)`, differentiating `g(x*(p), p) = 0` gives `H dx*/dp = −∂g/∂p`, so
//!
//! ```text
//! dL/dp = ∂L/∂x · dx*/dp = −λᵀ ∂g/∂p,    H λ = ∂L/∂x,
//! ```
//!
//! with `H` the **exact** Hessian at `x*` restricted to the free dofs (λ is zero on pinned dofs). [`Adjoint`]
//! assembles and factors `H` itself with a sparse Cholesky: Newton's last factorization may be of a projected
//! or shifted Hessian and cannot be reused. A Cholesky failure means `x*` is not a strict minimum (a
//! buckled or flat direction): [`AdjointError::NotMinimum`], never a silently wrong gradient. One adjoint
//! gradient costs one assembly, one factorization and one solve, plus a pass per parameter over its
//! energy's elements ([`hinge_core::energy::Energy::add_parameter_derivatives`]).
//!
//! [`Fit`] minimises a loss over chosen parameters with L-BFGS on `s = ln u` (positive parameters stay
//! positive), on `s = ln((u − lo)/(hi − u))` for a variable bounded to `(lo, hi)` (a Poisson ratio stays
//! in `(−1, 0.5)`), or on `u` itself; each evaluation an equilibrium solved by [`Newton`] from the
//! previous one and its gradient by the adjoint; see [`Fit::run`].

use hinge_core::EvalError;
use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{ParameterOutput, System, SystemEvaluation};
use hinge_core::nalgebra::Vector3;
use hinge_energies::pins::Pins;

use crate::linear::{FaerLlt, LinearError, LinearSolver};
use crate::newton::{
    MAX_ITERATIONS_CEILING, MAX_ITERATIONS_CEILING_TEXT, Newton, Reduced, SolverError, norm,
};

/// Why a sensitivity or a fit could not be computed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AdjointError {
    /// Evaluating the system, or a parameter derivative, failed.
    #[error(transparent)]
    Eval(#[from] EvalError),
    /// The exact Hessian at the state is not positive definite on the free dofs.
    #[error(
        "the exact Hessian at the equilibrium is not positive definite (free dof {dof}, vertex {vertex}): the state is not a strict minimum, its sensitivities are undefined"
    )]
    NotMinimum {
        /// The vertex whose dof the factorization failed at.
        vertex: usize,
        /// The dof (3·vertex + coordinate).
        dof: usize,
    },
    /// The linear solver failed otherwise.
    #[error("linear solve: {0}")]
    Linear(#[from] LinearError),
    /// An input of the wrong length.
    #[error("{what} has length {got}, expected {expected}")]
    Length {
        /// Which input.
        what: &'static str,
        /// Length given.
        got: usize,
        /// Length needed.
        expected: usize,
    },
    /// An energy refused the parameter values a fit set (a rest angle outside [−π, π], say). Within the
    /// line search such a trial counts as failed and the step is halved; at the start it is this error.
    #[error("{0}")]
    OutOfDomain(EvalError),
    /// A non-finite entry in an input or in what a loss returned.
    #[error("{what}: entry {index} (vertex {}, coordinate {}) is not finite ({value})", index / 3, index % 3)]
    NotFinite {
        /// Which input (the right-hand side, the targets, the loss gradient).
        what: &'static str,
        /// The entry (3·vertex + coordinate).
        index: usize,
        /// Its value.
        value: f64,
    },
    /// [`Adjoint::solve`] or a gradient before a successful [`Adjoint::factor`].
    #[error("the Hessian has not been factored at this state")]
    NotFactored,
    /// An equilibrium solve of a fit failed.
    #[error("equilibrium: {0}")]
    Equilibrium(#[from] SolverError),
    /// A fit set-up that cannot work (named).
    #[error("{0}")]
    Setup(String),
    /// Fitted variables whose effects on the equilibrium cannot be told apart (or a variable without
    /// effect): fitting them together would return an arbitrary combination.
    #[error(
        "{} not separately identifiable from the target: their effects on the equilibrium are proportional (smallest eigenvalue of their sensitivities' correlation matrix {smallest:.1e}); fit fewer of them",
        quoted_list(variables)
    )]
    NotIdentifiable {
        /// The variables involved (those with a weight above 0.1 in the nearly null combination).
        variables: Vec<String>,
        /// The smallest eigenvalue of the correlation matrix of their sensitivities (0: dependent).
        smallest: f64,
    },
    /// A variable whose change does not move the equilibrium at all.
    #[error("`{variable}` does not change the equilibrium: it cannot be fitted to a shape")]
    NoEffect {
        /// The variable.
        variable: String,
    },
}

fn quoted_list(v: &[String]) -> String {
    let q: Vec<String> = v.iter().map(|s| format!("`{s}`")).collect();
    match q.len() {
        0 => "the variables are".into(),
        1 => format!("{} is", q[0]),
        _ => format!("{} and {} are", q[..q.len() - 1].join(", "), q[q.len() - 1]),
    }
}

/// The exact-Hessian factorization of a system at a state, with pins eliminated, and the solves and
/// parameter gradients built on it (see the module documentation).
pub struct Adjoint {
    reduced: Reduced,
    solver: FaerLlt,
    values: Vec<f64>,
    eval: SystemEvaluation,
    rhs: Vec<f64>,
    lambda: Vec<f64>,
    n_vertices: usize,
    factored: bool,
}

impl std::fmt::Debug for Adjoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Adjoint")
            .field("free_dofs", &self.reduced.dofs.len())
            .field("factored", &self.factored)
            .finish()
    }
}

impl Adjoint {
    /// Binds to `system`'s pattern with `pins` eliminated (symbolic analysis once).
    ///
    /// # Errors
    /// [`AdjointError::Length`] when the pins are for another vertex count; [`AdjointError::Linear`].
    pub fn new(system: &System, pins: &Pins) -> Result<Self, AdjointError> {
        let n = system.n_vertices();
        let free = pins.free_dofs();
        if free.len() != 3 * n {
            return Err(AdjointError::Length {
                what: "the pins' dofs",
                got: free.len(),
                expected: 3 * n,
            });
        }
        let reduced = Reduced::new(system.pattern(), &free);
        let mut solver = FaerLlt::default();
        solver.analyze(&reduced.csc)?;
        Ok(Self {
            values: vec![0.0; reduced.source.len()],
            rhs: vec![0.0; reduced.dofs.len()],
            lambda: vec![0.0; 3 * n],
            eval: system.new_output(),
            reduced,
            solver,
            n_vertices: n,
            factored: false,
        })
    }

    /// Assembles the exact Hessian of `system` at `x` and factors it on the free dofs.
    ///
    /// # Errors
    /// [`AdjointError::NotMinimum`] when it is not positive definite; evaluation errors.
    pub fn factor(&mut self, system: &mut System, x: &[Vector3<f64>]) -> Result<(), AdjointError> {
        self.factored = false;
        let request = Request {
            value: false,
            gradient: false,
            hessian: true,
            definite: false,
        };
        system.evaluate_into(x, request, Parallelism::Rayon, &mut self.eval)?;
        for (v, &k) in self.values.iter_mut().zip(&self.reduced.source) {
            *v = self.eval.hessian[k];
        }
        match self.solver.factor(&self.values) {
            Ok(()) => {}
            Err(LinearError::NotPositiveDefinite { index }) => {
                let dof = self.reduced.dofs.get(index).copied().unwrap_or(0);
                return Err(AdjointError::NotMinimum {
                    vertex: dof / 3,
                    dof,
                });
            }
            Err(e) => return Err(e.into()),
        }
        self.factored = true;
        Ok(())
    }

    /// Solves `H λ = b` on the free dofs (`b`: `3n` entries, its pinned entries ignored); λ is zero on pinned
    /// dofs. Needs a successful [`Adjoint::factor`].
    ///
    /// # Errors
    /// [`AdjointError::NotFactored`], [`AdjointError::Length`], [`AdjointError::NotFinite`] naming the
    /// first non-finite entry of `b`, [`AdjointError::Linear`].
    pub fn solve(&mut self, b: &[f64]) -> Result<&[f64], AdjointError> {
        if !self.factored {
            return Err(AdjointError::NotFactored);
        }
        if b.len() != 3 * self.n_vertices {
            return Err(AdjointError::Length {
                what: "the right-hand side",
                got: b.len(),
                expected: 3 * self.n_vertices,
            });
        }
        if let Some(index) = b.iter().position(|v| !v.is_finite()) {
            return Err(AdjointError::NotFinite {
                what: "the right-hand side",
                index,
                value: b[index],
            });
        }
        for (r, &d) in self.rhs.iter_mut().zip(&self.reduced.dofs) {
            *r = b[d];
        }
        self.solver.solve(&mut self.rhs)?;
        self.lambda.fill(0.0);
        for (&r, &d) in self.rhs.iter().zip(&self.reduced.dofs) {
            self.lambda[d] = r;
        }
        Ok(&self.lambda)
    }

    /// The adjoint vector of the last [`Adjoint::solve`].
    pub fn lambda(&self) -> &[f64] {
        &self.lambda
    }

    /// `dL/dp = −λᵀ ∂g/∂p` for the system parameter `name` ([`System::parameters`]) with λ from the last
    /// [`Adjoint::solve`] (whose right-hand side was `∂L/∂x`), at the same `x`: one value per parameter
    /// entry.
    ///
    /// # Errors
    /// [`AdjointError::NotFactored`]; [`EvalError::Parameter`] for an unknown name.
    pub fn parameter_gradient(
        &self,
        system: &mut System,
        x: &[Vector3<f64>],
        name: &str,
    ) -> Result<Vec<f64>, AdjointError> {
        if !self.factored {
            return Err(AdjointError::NotFactored);
        }
        let len = parameter_len(system, name)?;
        let mut contracted = vec![0.0; len];
        system.add_parameter_derivatives(
            x,
            name,
            &mut ParameterOutput {
                energy: &mut [],
                lambda: &self.lambda,
                contracted: &mut contracted,
                direction: &[],
                gradient: &mut [],
            },
        )?;
        for c in &mut contracted {
            *c = -*c;
        }
        Ok(contracted)
    }

    /// Forward sensitivity `(dx*/dp) d = −H⁻¹ (∂g/∂p) d` of system parameter `name` along the direction `d`
    /// (one entry per parameter value; `3n` entries out, zero on pinned dofs), at the state of the last
    /// [`Adjoint::factor`]. Overwrites [`Adjoint::lambda`].
    ///
    /// # Errors
    /// As [`Adjoint::solve`]; [`EvalError::Parameter`] for an unknown parameter or a direction of the wrong
    /// length.
    pub fn sensitivity(
        &mut self,
        system: &mut System,
        x: &[Vector3<f64>],
        name: &str,
        direction: &[f64],
    ) -> Result<Vec<f64>, AdjointError> {
        let dg = self.gradient_derivative(system, x, name, direction)?;
        let s = self.solve(&dg)?;
        Ok(s.iter().map(|v| -v).collect())
    }

    /// `(∂g/∂p) d` (`3n` entries).
    fn gradient_derivative(
        &self,
        system: &mut System,
        x: &[Vector3<f64>],
        name: &str,
        direction: &[f64],
    ) -> Result<Vec<f64>, AdjointError> {
        if !self.factored {
            return Err(AdjointError::NotFactored);
        }
        let mut dg = vec![0.0; 3 * self.n_vertices];
        system.add_parameter_derivatives(
            x,
            name,
            &mut ParameterOutput {
                energy: &mut [],
                lambda: &[],
                contracted: &mut [],
                direction,
                gradient: &mut dg,
            },
        )?;
        Ok(dg)
    }
}

/// The number of values of system parameter `name`.
fn parameter_len(system: &System, name: &str) -> Result<usize, EvalError> {
    system
        .parameters()
        .into_iter()
        .find(|p| p.name == name)
        .map(|p| p.len)
        .ok_or_else(|| hinge_core::energy::unknown_parameter(name, &system.parameters()))
}

/// The default loss: the sum of squared distances of chosen vertices to target positions,
/// `L = Σ_k |x_{v_k} − t_k|²`.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetLoss {
    /// The vertices compared (the caller's numbering).
    pub vertices: Vec<usize>,
    /// Their target positions.
    pub targets: Vec<Vector3<f64>>,
}

impl TargetLoss {
    /// Every vertex against `targets` (one per vertex).
    pub fn all(targets: Vec<Vector3<f64>>) -> Self {
        Self {
            vertices: (0..targets.len()).collect(),
            targets,
        }
    }

    /// `L(x)` and `∂L/∂x` (`3n` entries) into `grad`.
    ///
    /// # Errors
    /// [`AdjointError::Setup`] naming a vertex out of range; [`AdjointError::Length`] for a mismatched target
    /// list; [`AdjointError::NotFinite`] naming a non-finite target coordinate.
    pub fn evaluate(&self, x: &[Vector3<f64>], grad: &mut [f64]) -> Result<f64, AdjointError> {
        if self.vertices.len() != self.targets.len() {
            return Err(AdjointError::Length {
                what: "the targets",
                got: self.targets.len(),
                expected: self.vertices.len(),
            });
        }
        if grad.len() != 3 * x.len() {
            return Err(AdjointError::Length {
                what: "the loss gradient",
                got: grad.len(),
                expected: 3 * x.len(),
            });
        }
        grad.fill(0.0);
        let mut l = 0.0;
        for (&v, t) in self.vertices.iter().zip(&self.targets) {
            let Some(p) = x.get(v) else {
                return Err(AdjointError::Setup(format!(
                    "target vertex {v} is beyond the mesh's {} vertices",
                    x.len()
                )));
            };
            if let Some(c) = (0..3).find(|&c| !t[c].is_finite()) {
                return Err(AdjointError::NotFinite {
                    what: "the target positions",
                    index: 3 * v + c,
                    value: t[c],
                });
            }
            let d = p - t;
            l += d.norm_squared();
            for c in 0..3 {
                grad[3 * v + c] += 2.0 * d[c];
            }
        }
        Ok(l)
    }
}

/// A loss on the equilibrium: `L(x)`, writing `∂L/∂x` (`3n` entries) into its second argument.
pub type LossFn<'a> = dyn FnMut(&[Vector3<f64>], &mut [f64]) -> Result<f64, AdjointError> + 'a;

/// How a fitted variable sets a system parameter (`TERM.NAME`, [`System::parameters`]), entry by entry: a
/// field variable has one value per parameter entry, a scalar one acts on every entry.
///
/// A parameter's value is its value when the [`Fit`] was made (`p₀`), times the factor `(u/u₀)^e` of every
/// power link and `(q(u)/q(u₀))^e` of every quadratic link to it, with `p₀` replaced by `u` when a value
/// link sets it:
///
/// ```text
/// p = (u_value or p₀) · Π_power (u / u₀)^e · Π_quadratic (q(u) / q(u₀))^e
/// ```
///
/// so Young's modulus and the thickness both scale a bending stiffness `k ∝ Y h³` (exponents 1 and 3), and
/// Poisson's ratio scales it as `1/(1 − ν²)` (a quadratic link with `q = 1 − ν²`, exponent −1).
#[derive(Debug, Clone, PartialEq)]
pub enum Link {
    /// The parameter scales as `(u/u₀)^exponent` (a positive variable).
    Power {
        /// The system parameter.
        parameter: String,
        /// The power.
        exponent: f64,
    },
    /// The parameter is the variable itself (at most one value link per parameter).
    Value {
        /// The system parameter.
        parameter: String,
    },
    /// The parameter scales as `(q(u)/q(u₀))^exponent`, `q(u) = a + b u + c u²` with `coefficients =
    /// [a, b, c]`: positive at the start value ([`Fit::new`] checks), and where it is not positive at a
    /// trial value that trial is refused as out of the domain. A plate's stiffness `∝ 1/(1 − ν²)` in
    /// Poisson's ratio is `[1, 0, −1]` with exponent −1, a stiffness `∝ 1/(1 + ν)` is `[1, 1, 0]` with −1.
    Quadratic {
        /// The system parameter.
        parameter: String,
        /// `[a, b, c]` of `q(u) = a + b u + c u²`.
        coefficients: [f64; 3],
        /// The power of `q(u)/q(u₀)`.
        exponent: f64,
    },
}

impl Link {
    /// The parameter it sets.
    pub fn parameter(&self) -> &str {
        match self {
            Link::Power { parameter, .. }
            | Link::Value { parameter }
            | Link::Quadratic { parameter, .. } => parameter,
        }
    }

    /// `q(u)` of a quadratic link (`None` for the others).
    fn quadratic(&self, u: f64) -> Option<f64> {
        match self {
            Link::Quadratic {
                coefficients: [a, b, c],
                ..
            } => Some(a + u * (b + c * u)),
            _ => None,
        }
    }
}

/// A variable the fit adjusts: a name for reports, its starting value(s) and the system parameters it sets.
#[derive(Debug, Clone, PartialEq)]
pub struct FitVariable {
    /// Its name (a scene key, say).
    pub name: String,
    /// Starting values: one for a scalar, one per entry for a field. Positive when `positive`, inside
    /// `range` when it is set.
    pub start: Vec<f64>,
    /// Fitted as `u = exp(s)` (stays positive) rather than directly.
    pub positive: bool,
    /// Fitted as `u = lo + (hi − lo)/(1 + exp(−s))` inside the open interval `(lo, hi)` (both finite,
    /// `lo < hi`; not with `positive`): a parameter an energy bounds ([`System::parameter_bounds`], a Poisson
    /// ratio) stays inside its interval. `None`: as `positive` says.
    pub range: Option<(f64, f64)>,
    /// The system parameters it sets.
    pub links: Vec<Link>,
}

impl FitVariable {
    /// The optimisation variable `s` of value `u`.
    fn s_of(&self, u: f64) -> f64 {
        match self.range {
            Some((lo, hi)) => ((u - lo) / (hi - u)).ln(),
            None if self.positive => u.ln(),
            None => u,
        }
    }

    /// The value `u` of optimisation variable `s`.
    fn value_of(&self, s: f64) -> f64 {
        match self.range {
            Some((lo, hi)) => lo + (hi - lo) / (1.0 + (-s).exp()),
            None if self.positive => s.exp(),
            None => s,
        }
    }

    /// `du/ds` at value `u`.
    fn du_ds(&self, u: f64) -> f64 {
        match self.range {
            Some((lo, hi)) => (u - lo) * (hi - u) / (hi - lo),
            None if self.positive => u,
            None => 1.0,
        }
    }
}

/// Options of a [`Fit`].
#[derive(Debug, Clone, PartialEq)]
pub struct FitOptions {
    /// L-BFGS iteration limit.
    pub max_iterations: usize,
    /// Stop when the loss is at most this.
    pub loss_tolerance: f64,
    /// Stop when the loss is at most this times its starting value (a target the model reproduces exactly
    /// is then reached to the equilibria's own accuracy).
    pub relative_loss_tolerance: f64,
    /// Line-search trials (each an equilibrium solve) before an iteration gives up.
    pub max_line_search: usize,
    /// Stop when the gradient norm (with respect to the optimisation variables) is at most this times its
    /// first value.
    pub relative_gradient_tolerance: f64,
    /// Stop when an iteration lowers the loss by less than this fraction of it.
    pub relative_decrease_tolerance: f64,
    /// L-BFGS memory.
    pub memory: usize,
    /// The largest change of an optimisation variable in one step (for `positive` variables a factor of
    /// `exp(max_step)`).
    pub max_step: f64,
    /// Scalar variables are refused as not separately identifiable when the smallest eigenvalue of the
    /// correlation matrix of their equilibrium sensitivities (at the start) is below this (0: no check).
    pub identifiability_tolerance: f64,
    /// Weight of the smoothness regularizer `w Σ_(i,j) (s_i − s_j)²` over [`FitOptions::smooth_pairs`] of
    /// field variables' entries (0: off).
    pub smoothness: f64,
    /// Pairs of entries `(variable, i, j)` the smoothness term couples (adjacent hinges, say).
    pub smooth_pairs: Vec<(usize, usize, usize)>,
}

impl FitOptions {
    /// The largest [`FitOptions::max_line_search`]: the trial step has halved to `2⁻⁶⁴` of the first by
    /// then, below any change the loss can show.
    pub const MAX_LINE_SEARCH: usize = 64;

    /// The largest [`FitOptions::memory`]: each pair held costs two vectors of the variables' length and a
    /// pass over them per iteration.
    pub const MAX_MEMORY: usize = 1_000;

    /// Checks the options: `max_iterations` at most [`MAX_ITERATIONS_CEILING`] (0 evaluates the start
    /// only), `max_line_search` at most [`FitOptions::MAX_LINE_SEARCH`], `memory` at most
    /// [`FitOptions::MAX_MEMORY`], the tolerances, `smoothness` and `identifiability_tolerance` finite and
    /// non-negative, `max_step` finite and positive.
    ///
    /// # Errors
    /// [`AdjointError::Setup`] naming the first option out of range and its value.
    pub fn validate(&self) -> Result<(), AdjointError> {
        if self.max_iterations > MAX_ITERATIONS_CEILING {
            return Err(AdjointError::Setup(format!(
                "max_iterations must be from 0 to {MAX_ITERATIONS_CEILING_TEXT}, got {}",
                self.max_iterations
            )));
        }
        if self.max_line_search > Self::MAX_LINE_SEARCH {
            return Err(AdjointError::Setup(format!(
                "max_line_search must be from 0 to {}, got {}",
                Self::MAX_LINE_SEARCH,
                self.max_line_search
            )));
        }
        if self.memory > Self::MAX_MEMORY {
            return Err(AdjointError::Setup(format!(
                "memory must be from 0 to {}, got {}",
                Self::MAX_MEMORY,
                self.memory
            )));
        }
        for (name, value) in [
            ("loss_tolerance", self.loss_tolerance),
            ("relative_loss_tolerance", self.relative_loss_tolerance),
            (
                "relative_gradient_tolerance",
                self.relative_gradient_tolerance,
            ),
            (
                "relative_decrease_tolerance",
                self.relative_decrease_tolerance,
            ),
            ("identifiability_tolerance", self.identifiability_tolerance),
            ("smoothness", self.smoothness),
        ] {
            if !(value >= 0.0 && value.is_finite()) {
                return Err(AdjointError::Setup(format!(
                    "{name} must be non-negative and finite, got {value}"
                )));
            }
        }
        if !(self.max_step > 0.0 && self.max_step.is_finite()) {
            return Err(AdjointError::Setup(format!(
                "max_step must be positive and finite, got {}",
                self.max_step
            )));
        }
        Ok(())
    }
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            max_iterations: 50,
            loss_tolerance: 0.0,
            relative_loss_tolerance: 1e-12,
            max_line_search: 10,
            relative_gradient_tolerance: 1e-8,
            relative_decrease_tolerance: 1e-12,
            memory: 8,
            max_step: 1.0,
            identifiability_tolerance: 1e-4,
            smoothness: 0.0,
            smooth_pairs: Vec::new(),
        }
    }
}

/// The outcome of a fit.
#[derive(Debug, Clone, PartialEq)]
pub struct FitResult {
    /// The fitted values of every variable, in order.
    pub values: Vec<Vec<f64>>,
    /// The loss there (regularizer included).
    pub loss: f64,
    /// The loss before fitting.
    pub initial_loss: f64,
    /// L-BFGS iterations.
    pub iterations: usize,
    /// Equilibrium solves, line-search trials included.
    pub equilibria: usize,
    /// Newton iterations of those solves, summed (failed solves included).
    pub newton_iterations: usize,
    /// The equilibrium at the fitted values.
    pub x: Vec<Vector3<f64>>,
    /// Why it stopped.
    pub stop: &'static str,
    /// How many values of each field variable (more than one value) the loss's target can determine, at
    /// the start (see [`FieldCheck`]), in variable order.
    pub fields: Vec<FieldCheck>,
}

/// How many values of a field variable a fit can determine: one static shape often determines fewer values
/// of a per-hinge field than it has (a near-flat sheet's rest angles move its equilibrium through the
/// out-of-plane degrees of freedom only), and the fit then returns one of many fields that give the same
/// equilibrium; a smoothness term ([`FitOptions::smoothness`]) chooses among them.
///
/// Computed once, at the start: the equilibrium sensitivity `dx*/ds_i` of every value `i`, their
/// correlation matrix (each sensitivity normalised), and the count of its eigenvalues at or above
/// [`FitOptions::identifiability_tolerance`] — the number of independent combinations of values that move
/// the equilibrium. The largest-to-smallest eigenvalue gap is wide where the shape leaves values free (on
/// a near-flat clamped sheet, 2e-3 against 6e-9 between the last determined and the first free one).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FieldCheck {
    /// The variable's name.
    pub variable: String,
    /// Its number of values.
    pub entries: usize,
    /// The count, or `None` when not checked: the identifiability tolerance is 0, or the check would cost
    /// more than [`FieldCheck::MAX_WORK`] multiply-adds.
    pub rank: Option<FieldRank>,
}

impl FieldCheck {
    /// The largest `entries² · 3n` (the correlation matrix's multiply-adds, `n` the vertex count) checked:
    /// about a second.
    pub const MAX_WORK: f64 = 2e9;
}

/// The result of a [`FieldCheck`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FieldRank {
    /// Values that move nothing: their sensitivity is at most 1e-12 of the largest one's (a hinge whose four
    /// vertices are pinned moves exactly nothing).
    pub without_effect: usize,
    /// Independent combinations of the other values that move the equilibrium: the rest,
    /// `entries − without_effect − determined`, can change without changing it (to first order).
    pub determined: usize,
}

/// Fitting variables of a system to a loss on its equilibrium (see the module documentation).
pub struct Fit<'a> {
    /// The variables.
    pub variables: Vec<FitVariable>,
    /// Options.
    pub options: FitOptions,
    newton: &'a mut Newton,
    adjoint: Adjoint,
    equilibria: usize,
    newton_iterations: usize,
    grad_l: Vec<f64>,
    /// Every linked parameter and its value when the fit was made.
    linked: Vec<(String, Vec<f64>)>,
    /// Called after every accepted L-BFGS iteration (progress reports).
    observer: Option<Observer<'a>>,
    /// The field checks of the start ([`FitResult::fields`]).
    fields: Vec<FieldCheck>,
}

/// A [`Fit`]'s progress callback.
pub type Observer<'a> = Box<dyn FnMut(&FitProgress) + 'a>;

/// What a [`Fit`]'s observer sees after every accepted iteration.
#[derive(Debug, Clone, PartialEq)]
pub struct FitProgress {
    /// Iterations so far.
    pub iteration: usize,
    /// The loss now.
    pub loss: f64,
    /// Equilibrium solves so far.
    pub equilibria: usize,
    /// The variables' values now.
    pub values: Vec<Vec<f64>>,
}

impl std::fmt::Debug for Fit<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fit")
            .field("variables", &self.variables)
            .field("options", &self.options)
            .finish()
    }
}

/// One evaluated point of the fit.
struct Point {
    s: Vec<f64>,
    loss: f64,
    grad: Vec<f64>,
    x: Vec<Vector3<f64>>,
}

impl<'a> Fit<'a> {
    /// A fit of `variables` of `system`, solving equilibria with `newton` (bound to `system` and `pins`).
    ///
    /// # Errors
    /// [`AdjointError::Setup`] naming a variable with no links, a link to an unknown parameter or of the wrong
    /// length, a non-positive start of a positive variable, a start outside a variable's range or a bad
    /// range, a quadratic link not positive at the start.
    pub fn new(
        system: &System,
        pins: &Pins,
        newton: &'a mut Newton,
        variables: Vec<FitVariable>,
        options: FitOptions,
    ) -> Result<Self, AdjointError> {
        options.validate()?;
        let known = system.parameters();
        for v in &variables {
            if v.start.is_empty() || v.links.is_empty() {
                return Err(AdjointError::Setup(format!(
                    "`{}`: a variable needs a start value and at least one parameter it sets",
                    v.name
                )));
            }
            if let Some((lo, hi)) = v.range
                && !(lo.is_finite() && hi.is_finite() && lo < hi && !v.positive)
            {
                return Err(AdjointError::Setup(format!(
                    "`{}`: range ({lo}, {hi}) must have finite ends, the lower below the upper, and the \
                     variable must not also be positive",
                    v.name
                )));
            }
            let inside = |s: f64| v.range.is_none_or(|(lo, hi)| s > lo && s < hi);
            if let Some(bad) = v
                .start
                .iter()
                .find(|s| !s.is_finite() || (v.positive && **s <= 0.0) || !inside(**s))
            {
                return Err(AdjointError::Setup(format!(
                    "`{}`: start value {bad} must be finite{}",
                    v.name,
                    match v.range {
                        Some((lo, hi)) => format!(" and in ({lo}, {hi})"),
                        None if v.positive => " and positive".into(),
                        None => String::new(),
                    }
                )));
            }
            for l in &v.links {
                let Some(p) = known.iter().find(|p| p.name == l.parameter()) else {
                    return Err(AdjointError::Eval(hinge_core::energy::unknown_parameter(
                        l.parameter(),
                        &known,
                    )));
                };
                if !(v.start.len() == 1 || v.start.len() == p.len) {
                    return Err(AdjointError::Setup(format!(
                        "`{}`: parameter `{}` has {} values, the variable {}",
                        v.name,
                        l.parameter(),
                        p.len,
                        v.start.len()
                    )));
                }
                if matches!(l, Link::Power { .. }) && !v.positive {
                    return Err(AdjointError::Setup(format!(
                        "`{}`: a power link (to `{}`) needs a positive variable",
                        v.name,
                        l.parameter()
                    )));
                }
                if let Link::Quadratic { exponent, .. } = l {
                    if !exponent.is_finite() {
                        return Err(AdjointError::Setup(format!(
                            "`{}`: the quadratic link to `{}` has exponent {exponent}, not finite",
                            v.name,
                            l.parameter()
                        )));
                    }
                    let mut q = v.start.iter().map(|&u| l.quadratic(u).unwrap_or(f64::NAN));
                    if let Some(bad) = q.find(|q| !(*q > 0.0 && q.is_finite())) {
                        return Err(AdjointError::Setup(format!(
                            "`{}`: the quadratic link to `{}` is {bad} at the start, not positive",
                            v.name,
                            l.parameter()
                        )));
                    }
                }
            }
        }
        let mut linked: Vec<(String, Vec<f64>)> = Vec::new();
        let mut value_set: Vec<&str> = Vec::new();
        for v in &variables {
            for l in &v.links {
                if !linked.iter().any(|(n, _)| n == l.parameter()) {
                    linked.push((l.parameter().to_string(), system.parameter(l.parameter())?));
                }
                if let Link::Value { parameter } = l {
                    if value_set.contains(&parameter.as_str()) {
                        return Err(AdjointError::Setup(format!(
                            "parameter `{parameter}` is set by two variables"
                        )));
                    }
                    value_set.push(parameter);
                }
            }
        }
        for &(k, i, j) in &options.smooth_pairs {
            if variables.get(k).is_none_or(|v| i.max(j) >= v.start.len()) {
                return Err(AdjointError::Setup(format!(
                    "smoothness pair ({k}, {i}, {j}) names no entry of a variable"
                )));
            }
        }
        Ok(Self {
            adjoint: Adjoint::new(system, pins)?,
            grad_l: vec![0.0; 3 * system.n_vertices()],
            linked,
            observer: None,
            fields: Vec::new(),
            variables,
            options,
            newton,
            equilibria: 0,
            newton_iterations: 0,
        })
    }

    /// Calls `observer` after every accepted iteration (to report progress).
    pub fn observe(&mut self, observer: impl FnMut(&FitProgress) + 'a) {
        self.observer = Some(Box::new(observer));
    }

    /// Equilibrium solves so far.
    pub fn equilibria(&self) -> usize {
        self.equilibria
    }

    fn to_s(&self) -> Vec<f64> {
        self.variables
            .iter()
            .flat_map(|v| v.start.iter().map(move |&u| v.s_of(u)))
            .collect()
    }

    fn unpack(&self, s: &[f64]) -> Vec<Vec<f64>> {
        let mut k = 0;
        self.variables
            .iter()
            .map(|v| {
                let u: Vec<f64> = s[k..k + v.start.len()]
                    .iter()
                    .map(|&si| v.value_of(si))
                    .collect();
                k += v.start.len();
                u
            })
            .collect()
    }

    /// Every linked parameter's values at the variables' values `u`, and for each the product of its power
    /// factors (what a value link's derivative is).
    fn parameter_values(&self, u: &[Vec<f64>]) -> Vec<(Vec<f64>, Vec<f64>)> {
        self.linked
            .iter()
            .map(|(name, p0)| {
                let mut value = p0.clone();
                let mut factor = vec![1.0; p0.len()];
                for (v, uv) in self.variables.iter().zip(u) {
                    for l in &v.links {
                        if l.parameter() != name {
                            continue;
                        }
                        for i in 0..p0.len() {
                            let j = if uv.len() == 1 { 0 } else { i };
                            match l {
                                Link::Power { exponent, .. } => {
                                    factor[i] *= (uv[j] / v.start[j]).powf(*exponent);
                                }
                                Link::Quadratic { exponent, .. } => {
                                    let q = |u| l.quadratic(u).unwrap_or(f64::NAN);
                                    // Not positive: NaN, which `apply` refuses.
                                    let r = q(uv[j]) / q(v.start[j]);
                                    factor[i] *= if r > 0.0 { r.powf(*exponent) } else { f64::NAN };
                                }
                                Link::Value { .. } => value[i] = uv[j],
                            }
                        }
                    }
                }
                let values = value.iter().zip(&factor).map(|(a, b)| a * b).collect();
                (values, factor)
            })
            .collect()
    }

    /// Sets every linked parameter from the variables' values `u`.
    ///
    /// # Errors
    /// [`AdjointError::Eval`] with [`EvalError::Parameter`] for a value that is not finite (a quadratic
    /// link where `q` is not positive, an overflow), whatever the energy checks itself; the energies' own.
    fn apply(&self, system: &mut System, u: &[Vec<f64>]) -> Result<(), AdjointError> {
        for ((name, _), (values, _)) in self.linked.iter().zip(self.parameter_values(u)) {
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                return Err(AdjointError::Eval(EvalError::Parameter {
                    name: name.clone(),
                    message: format!("value {i} would be {} from the fit's links", values[i]),
                }));
            }
            system.set_parameter(name, &values)?;
        }
        Ok(())
    }

    /// `∂p_i/∂s_j` of link `l` of variable `v` (value `u`) for parameter entry `i` (`j` the variable's
    /// entry acting on it): `p e / u` for a power link, `p e q′(u)/q(u)` for a quadratic one, the factors
    /// for a value link, times `du/ds` (`u` for a positive variable, `(u − lo)(hi − u)/(hi − lo)` for a
    /// bounded one).
    fn link_derivative(l: &Link, v: &FitVariable, u: f64, value: f64, factor: f64) -> f64 {
        let d = match l {
            Link::Power { exponent, .. } => value * exponent / u,
            Link::Quadratic {
                coefficients: [_, b, c],
                exponent,
                ..
            } => value * exponent * (b + 2.0 * c * u) / l.quadratic(u).unwrap_or(f64::NAN),
            Link::Value { .. } => factor,
        };
        d * v.du_ds(u)
    }

    /// The regularizer's value and gradient (added to `grad`).
    fn regularizer(&self, s: &[f64], grad: &mut [f64]) -> f64 {
        if self.options.smoothness == 0.0 {
            return 0.0;
        }
        let offsets: Vec<usize> = self
            .variables
            .iter()
            .scan(0, |k, v| {
                let o = *k;
                *k += v.start.len();
                Some(o)
            })
            .collect();
        let w = self.options.smoothness;
        let mut r = 0.0;
        for &(k, i, j) in &self.options.smooth_pairs {
            let (a, b) = (offsets[k] + i, offsets[k] + j);
            let d = s[a] - s[b];
            r += w * d * d;
            grad[a] += 2.0 * w * d;
            grad[b] -= 2.0 * w * d;
        }
        r
    }

    /// Loss and gradient with respect to the optimisation variables at `s`, the equilibrium solved from
    /// `x` (overwritten with it). On error the system's parameters may be those of `s`.
    fn evaluate(
        &mut self,
        system: &mut System,
        s: &[f64],
        x: &mut [Vector3<f64>],
        loss: &mut LossFn,
    ) -> Result<(f64, Vec<f64>), AdjointError> {
        let u = self.unpack(s);
        self.apply(system, &u).map_err(|e| match e {
            AdjointError::Eval(e) => AdjointError::OutOfDomain(e),
            e => e,
        })?;
        self.equilibria += 1;
        match self.newton.minimize(system, x, None) {
            Ok(st) => self.newton_iterations += st.iterations,
            Err(e) => {
                self.newton_iterations += e.stats().iterations;
                return Err(e.into());
            }
        }
        let l = loss(x, &mut self.grad_l)?;
        if !l.is_finite() {
            return Err(AdjointError::Setup(format!(
                "the loss is not finite ({l}) at the equilibrium"
            )));
        }
        if let Some(index) = self.grad_l.iter().position(|v| !v.is_finite()) {
            return Err(AdjointError::NotFinite {
                what: "the loss gradient",
                index,
                value: self.grad_l[index],
            });
        }
        self.adjoint.factor(system, x)?;
        self.adjoint.solve(&self.grad_l)?;
        let mut grad = vec![0.0; s.len()];
        let values = self.parameter_values(&u);
        let mut dl_dp: Vec<Option<Vec<f64>>> = vec![None; self.linked.len()];
        let mut k = 0;
        for (v, uv) in self.variables.iter().zip(&u) {
            for l in &v.links {
                let Some(pi) = self.linked.iter().position(|(n, _)| n == l.parameter()) else {
                    continue;
                };
                if dl_dp[pi].is_none() {
                    dl_dp[pi] = Some(self.adjoint.parameter_gradient(system, x, l.parameter())?);
                }
                let (pv, factor) = &values[pi];
                if let Some(dp) = &dl_dp[pi] {
                    for (i, &g) in dp.iter().enumerate() {
                        let j = if uv.len() == 1 { 0 } else { i };
                        grad[k + j] += g * Self::link_derivative(l, v, uv[j], pv[i], factor[i]);
                    }
                }
            }
            k += uv.len();
        }
        let r = self.regularizer(s, &mut grad);
        Ok((l + r, grad))
    }

    /// The sensitivity `dx*/ds` of entry `j` of variable `k` (values `u`, parameter values `values`) at the
    /// equilibrium `x` where the adjoint is factored: every link's, summed.
    fn entry_sensitivity(
        &mut self,
        system: &mut System,
        x: &[Vector3<f64>],
        (k, j): (usize, usize),
        u: &[Vec<f64>],
        values: &[(Vec<f64>, Vec<f64>)],
    ) -> Result<Vec<f64>, AdjointError> {
        let mut col = vec![0.0; 3 * x.len()];
        let scalar = u[k].len() == 1;
        let uj = u[k][if scalar { 0 } else { j }];
        for l in &self.variables[k].links {
            let Some(pi) = self.linked.iter().position(|(n, _)| n == l.parameter()) else {
                continue;
            };
            let (pv, factor) = &values[pi];
            let v = &self.variables[k];
            let direction: Vec<f64> = if scalar {
                pv.iter()
                    .zip(factor)
                    .map(|(&p, &f)| Self::link_derivative(l, v, uj, p, f))
                    .collect()
            } else {
                let mut d = vec![0.0; pv.len()];
                d[j] = Self::link_derivative(l, v, uj, pv[j], factor[j]);
                d
            };
            let s = self
                .adjoint
                .sensitivity(system, x, l.parameter(), &direction)?;
            for (c, si) in col.iter_mut().zip(&s) {
                *c += si;
            }
        }
        Ok(col)
    }

    /// [`FieldCheck`] of every field variable at the equilibrium `x` of the start values `u` (the adjoint
    /// factored there), into `self.fields`.
    fn check_fields(
        &mut self,
        system: &mut System,
        x: &[Vector3<f64>],
        u: &[Vec<f64>],
    ) -> Result<(), AdjointError> {
        let values = self.parameter_values(u);
        let tol = self.options.identifiability_tolerance;
        let mut fields = Vec::new();
        for (k, uv) in u.iter().enumerate() {
            let m = uv.len();
            if m == 1 {
                continue;
            }
            let work = (m as f64).powi(2) * 3.0 * x.len() as f64;
            let mut check = FieldCheck {
                variable: self.variables[k].name.clone(),
                entries: m,
                rank: None,
            };
            if tol > 0.0 && work <= FieldCheck::MAX_WORK {
                let mut columns = Vec::with_capacity(m);
                for j in 0..m {
                    columns.push(self.entry_sensitivity(system, x, (k, j), u, &values)?);
                }
                // Without effect: moving the equilibrium by at most 1e-12 of what the most effective value
                // does (exactly nothing for a hinge inside a clamp; rounding's leftovers where a symmetric
                // stencil cancels).
                let norms: Vec<f64> = columns.iter().map(|c| norm(c)).collect();
                let floor = 1e-12 * norms.iter().fold(0.0f64, |a, &b| a.max(b));
                let columns: Vec<Vec<f64>> = columns
                    .into_iter()
                    .zip(&norms)
                    .filter(|&(_, &n)| n > floor)
                    .map(|(c, &n)| c.iter().map(|v| v / n).collect())
                    .collect();
                let c = columns.len();
                let gram = hinge_core::nalgebra::DMatrix::from_fn(c, c, |i, j| {
                    dot(&columns[i], &columns[j])
                });
                let determined = gram
                    .symmetric_eigenvalues()
                    .iter()
                    .filter(|&&e| e >= tol)
                    .count();
                check.rank = Some(FieldRank {
                    without_effect: m - c,
                    determined,
                });
            }
            fields.push(check);
        }
        self.fields = fields;
        Ok(())
    }

    /// Checks that the scalar variables move the equilibrium `x` (solved at the start values, with the
    /// adjoint factored there) in independent ways: the sensitivity `dx*/ds_j` of every scalar variable
    /// (`s = ln u` for positive ones), their correlation matrix, its smallest eigenvalue against
    /// [`FitOptions::identifiability_tolerance`].
    fn check_identifiable(
        &mut self,
        system: &mut System,
        x: &[Vector3<f64>],
        u: &[Vec<f64>],
    ) -> Result<(), AdjointError> {
        let mut columns: Vec<(String, Vec<f64>)> = Vec::new();
        let values = self.parameter_values(u);
        for (k, uk) in u.iter().enumerate() {
            if uk.len() != 1 {
                continue;
            }
            let col = self.entry_sensitivity(system, x, (k, 0), u, &values)?;
            let v = &self.variables[k];
            let norm = norm(&col);
            if !(norm > 0.0) {
                return Err(AdjointError::NoEffect {
                    variable: v.name.clone(),
                });
            }
            columns.push((v.name.clone(), col.iter().map(|c| c / norm).collect()));
        }
        let m = columns.len();
        if m < 2 || self.options.identifiability_tolerance <= 0.0 {
            return Ok(());
        }
        let c =
            hinge_core::nalgebra::DMatrix::from_fn(m, m, |i, j| dot(&columns[i].1, &columns[j].1));
        let eig = c.symmetric_eigen();
        let (k, &smallest) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))
            .ok_or_else(|| AdjointError::Setup("no variables".into()))?;
        if smallest < self.options.identifiability_tolerance {
            let variables = columns
                .iter()
                .enumerate()
                .filter(|(i, _)| eig.eigenvectors[(*i, k)].abs() > 0.1)
                .map(|(_, (n, _))| n.clone())
                .collect();
            return Err(AdjointError::NotIdentifiable {
                variables,
                smallest: smallest.max(0.0),
            });
        }
        Ok(())
    }

    /// The loss (regularizer included) at the variables' start values and its gradient with respect to
    /// them, `dL/du` (one entry per variable value, in order; the chain rule through every link), the
    /// equilibrium solved from `x` (overwritten with it): what each L-BFGS step uses, with respect to the
    /// values rather than the optimisation variables `s`. For a check before a fit; the system keeps the
    /// start values.
    ///
    /// # Errors
    /// As [`Fit::run`]'s first evaluation: the equilibrium fails, the Hessian there is not positive definite,
    /// evaluation errors, a loss or loss gradient that is not finite.
    pub fn loss_and_gradient(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        loss: &mut LossFn,
    ) -> Result<(f64, Vec<f64>), AdjointError> {
        let s0 = self.to_s();
        let (l, mut grad) = self.evaluate(system, &s0, x, loss)?;
        let u = self.unpack(&s0);
        for (g, (v, uv)) in grad.iter_mut().zip(
            self.variables
                .iter()
                .zip(&u)
                .flat_map(|(v, uv)| uv.iter().map(move |&u| (v, u))),
        ) {
            *g /= v.du_ds(uv);
        }
        // The exact start values (`s` round-trips to them only to rounding).
        let start: Vec<Vec<f64>> = self.variables.iter().map(|v| v.start.clone()).collect();
        self.apply(system, &start)?;
        Ok((l, grad))
    }

    /// Runs L-BFGS from the variables' start values and the state `x` (an initial guess of the first
    /// equilibrium; on success it holds the fitted equilibrium, and the system the fitted parameters).
    /// Every evaluation solves the equilibrium from the last accepted one (warm start). A trial whose
    /// equilibrium fails to converge, or whose parameter values an energy refuses
    /// ([`AdjointError::OutOfDomain`]), counts as a failed line-search step (the step is halved); a failure
    /// at the start is an error, and so is a solve stopped by the Newton solver's stop flag
    /// ([`Newton::set_stop`]): the fit ends at once.
    ///
    /// # Errors
    /// [`AdjointError`]: the first equilibrium fails, the Hessian at an equilibrium is not positive
    /// definite, evaluation errors, [`SolverError::Interrupted`] (as [`AdjointError::Equilibrium`]), a loss
    /// that is not finite ([`AdjointError::Setup`]) or a loss gradient that is not
    /// ([`AdjointError::NotFinite`]). On error the system holds the start values.
    pub fn run(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        loss: &mut LossFn,
    ) -> Result<FitResult, AdjointError> {
        let s0 = self.to_s();
        // The exact start values (exp(ln u) need not be u): what a failed run puts back.
        let start: Vec<Vec<f64>> = self.variables.iter().map(|v| v.start.clone()).collect();
        let restore = |fit: &Self, system: &mut System| {
            let _ = fit.apply(system, &start);
        };
        let mut xw = x.to_vec();
        let first = match self
            .evaluate(system, &s0, &mut xw, loss)
            .and_then(|v| self.check_identifiable(system, &xw, &start).map(|()| v))
            .and_then(|v| self.check_fields(system, &xw, &start).map(|()| v))
        {
            Ok(v) => v,
            Err(e) => {
                restore(self, system);
                return Err(e);
            }
        };
        let mut cur = Point {
            s: s0,
            loss: first.0,
            grad: first.1,
            x: xw,
        };
        let initial_loss = cur.loss;
        let g0 = norm(&cur.grad);
        let mut mem: Vec<(Vec<f64>, Vec<f64>)> = Vec::new();
        let mut iterations = 0;
        let mut stop = "iteration limit";
        while iterations < self.options.max_iterations {
            if cur.loss <= self.options.loss_tolerance
                || cur.loss <= self.options.relative_loss_tolerance * initial_loss
            {
                stop = "loss tolerance";
                break;
            }
            let gn = norm(&cur.grad);
            if gn == 0.0 || gn <= self.options.relative_gradient_tolerance * g0 {
                stop = "gradient tolerance";
                break;
            }
            let mut d = two_loop(&cur.grad, &mem);
            let mut slope = dot(&d, &cur.grad);
            if !(slope < 0.0) {
                mem.clear();
                d = cur.grad.iter().map(|g| -g).collect();
                slope = -gn * gn;
            }
            // Cap the step so no variable moves more than max_step. Without curvature pairs (the first
            // iteration, or where the loss has been concave along every step so far) the direction is the
            // gradient's, whose size says nothing about the distance to the minimum (a loss concave at the
            // start has a gradient the smaller the nearer the start is to its inflection): that step is
            // scaled to move the largest variable by max_step, and the line search halves it as needed.
            let big = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let mut t = if big > self.options.max_step || (mem.is_empty() && big > 0.0) {
                self.options.max_step / big
            } else {
                1.0
            };
            let mut accepted = None;
            for _ in 0..self.options.max_line_search.max(1) {
                let s: Vec<f64> = cur.s.iter().zip(&d).map(|(a, b)| a + t * b).collect();
                let mut xt = cur.x.clone();
                match self.evaluate(system, &s, &mut xt, loss) {
                    Ok((l, g)) if l.is_finite() && l <= cur.loss + 1e-4 * t * slope => {
                        accepted = Some(Point {
                            s,
                            loss: l,
                            grad: g,
                            x: xt,
                        });
                        break;
                    }
                    // A stop request ends the fit, not just this trial.
                    Err(e @ AdjointError::Equilibrium(SolverError::Interrupted { .. })) => {
                        restore(self, system);
                        return Err(e);
                    }
                    Ok(_)
                    | Err(AdjointError::Equilibrium(_))
                    | Err(AdjointError::NotMinimum { .. })
                    | Err(AdjointError::OutOfDomain(_)) => t *= 0.5,
                    Err(e) => {
                        restore(self, system);
                        return Err(e);
                    }
                }
            }
            iterations += 1;
            let Some(next) = accepted else {
                stop = "line search";
                break;
            };
            let sk: Vec<f64> = next.s.iter().zip(&cur.s).map(|(a, b)| a - b).collect();
            let yk: Vec<f64> = next
                .grad
                .iter()
                .zip(&cur.grad)
                .map(|(a, b)| a - b)
                .collect();
            if dot(&sk, &yk) > 1e-12 * norm(&sk) * norm(&yk) {
                mem.push((sk, yk));
                if mem.len() > self.options.memory {
                    mem.remove(0);
                }
            }
            let decrease = cur.loss - next.loss;
            cur = next;
            if self.observer.is_some() {
                let progress = FitProgress {
                    iteration: iterations,
                    loss: cur.loss,
                    equilibria: self.equilibria,
                    values: self.unpack(&cur.s),
                };
                if let Some(f) = self.observer.as_mut() {
                    f(&progress);
                }
            }
            if decrease <= self.options.relative_decrease_tolerance * cur.loss.abs() {
                stop = "loss no longer decreasing";
                break;
            }
        }
        // Leave the system at the fitted values (the last evaluation may have been a rejected trial).
        let values = self.unpack(&cur.s);
        self.apply(system, &values)?;
        x.copy_from_slice(&cur.x);
        Ok(FitResult {
            values,
            loss: cur.loss,
            initial_loss,
            iterations,
            equilibria: self.equilibria,
            newton_iterations: self.newton_iterations,
            x: cur.x,
            stop,
            fields: self.fields.clone(),
        })
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The L-BFGS direction `−H̃ g` from the pairs `(s_k, y_k)` (oldest first), scaled by `sᵀy / yᵀy` of the
/// newest pair.
fn two_loop(g: &[f64], mem: &[(Vec<f64>, Vec<f64>)]) -> Vec<f64> {
    let mut q = g.to_vec();
    let mut alpha = vec![0.0; mem.len()];
    for (k, (s, y)) in mem.iter().enumerate().rev() {
        let rho = 1.0 / dot(y, s);
        alpha[k] = rho * dot(s, &q);
        for (qi, yi) in q.iter_mut().zip(y) {
            *qi -= alpha[k] * yi;
        }
    }
    if let Some((s, y)) = mem.last() {
        let gamma = dot(s, y) / dot(y, y);
        for qi in &mut q {
            *qi *= gamma;
        }
    }
    for (k, (s, y)) in mem.iter().enumerate() {
        let rho = 1.0 / dot(y, s);
        let beta = rho * dot(y, &q);
        for (qi, si) in q.iter_mut().zip(s) {
            *qi += (alpha[k] - beta) * si;
        }
    }
    q.iter().map(|v| -v).collect()
}
