//! The assembly engine for hinge energies: energy, gradient and the exact sparse Hessian of
//! `E = Σ_hinges ψ_h(θ_h)` by one of three interchangeable [`Method`]s.
//!
//! # Methods
//! - [`Method::Refactored`] — the triangle-refactored Hessian (paper Eq. 7, §4.1–4.2). Per triangle with
//!   corners 0, 1, 2 (edge `i` opposite corner `i`, σ_i = 1 on interior edges):
//!   ```text
//!   c_i = σ_i ψ′_i,   d_i = c_{i−1} cos α_{i+1} + c_{i+1} cos α_{i−1} − c_i,   R_i = c_i N_i
//!   H^Δ_ii     = ω_ii (d_i M_iᵀ + d_i M_i) − R_{i+1} − R_{i+2}
//!   H^Δ_i,i+1  = ω_i,i+1 (d_i M_{i+1}ᵀ + d_{i+1} M_i) + R_{i+2}^†
//!   ```
//!   with `M_i = n m_iᵀ`, `N_i = M_i / l_i²`, `ω_ij = 1/(h_i h_j)`. The conditional transpose † applies in
//!   exactly one triangle of each interior edge: the lower triangle T̃ of its hinge (see [`crate::topology`]).
//!   Summed over triangles this is `Σ_h ψ′_h Hess θ_h`. Each hinge's `ψ″ ∇θ ∇θᵀ` is given to its upper
//!   triangle T, whose three corners are the hinge's x0, x1, x2: those six blocks fold into the triangle's own
//!   blocks, and only the four blocks of x3 are extra (the paper's 6F + 4E block writes).
//! - [`Method::PerHinge`] — Eqs. 4–6 per hinge: one 12×12 Hessian `ψ′ Hess θ + ψ″ ∇θ∇θᵀ` per hinge,
//!   scattered as 10 blocks. Same assembly path as `Refactored`.
//! - [`Method::Autodiff`] — num-dual's second-order duals over the 12 stencil coordinates with ψ included
//!   (`ψ(θ(x))` through [`crate::psi::HingePsi::psi_dual`]). Slow: the baseline and a cross-check.
//!
//! # Where things are
//! | phase | file |
//! |---|---|
//! | the public API: [`BendingModel`], [`Request`], [`Method`], [`HessianMode`], evaluation entry points | `bending/mod.rs` |
//! | set-up: storage order of elements and hinge states, value slots, partitions | `bending/setup.rs` |
//! | pass 1, per hinge: θ, ψ, ψ′, ψ″, ∇θ (only what the request needs) | `bending/hinge_pass.rs` |
//! | pass 2 driver: partitions, ownership, gradient and block writes | `bending/scatter.rs` |
//! | Eq. 7, the triangle-refactored kernel | `bending/triangle_pass.rs` |
//! | Eqs. 4–6 per hinge, and autodiff | `bending/per_hinge.rs` |
//! | positive semi-definite projection | `bending/projection.rs` |
//!
//! # Numbering
//! Everything the caller passes or receives is in the caller's numbering: positions and gradients by the
//! mesh's vertex numbers, hinges and every per-hinge array (parameters, rest angles, `#[per_hinge]` fields) in
//! [`crate::Topology::hinges`] order, triangles by mesh index. The Hessian values are in the order of the
//! model's [`SymmetricPattern`], whose rows and columns follow a *storage order* of the vertices (a locality
//! order by default: see [`crate::pattern`]); its exports ([`crate::export::CsrLayout`],
//! [`crate::export::dense`], Matrix Market) are in the caller's numbering. Internally the engine gathers the
//! positions into storage order once per evaluation (O(n), checking that they are finite), runs both passes
//! in storage order, and scatters the gradient back (O(n)), so the cost does not depend on how the caller
//! numbered the mesh.
//!
//! # Passes and determinism
//! 1. Per hinge (parallel, each hinge writes its own record): θ and ψ for an energy-only request; also ψ′ and
//!    ∇θ for a gradient; ψ″ too for a Hessian. Both triangles' degeneracy decisions are made here
//!    ([`crate::geometry::accepts`] on the pivot cross product, independent of the corner order) and the
//!    triangle pass repeats them bit for bit on the same positions, so a triangle is either evaluated by
//!    every pass or reported as a typed error: never skipped.
//! 2. Per partition (parallel): the vertices are split into contiguous ranges of the storage order fixed at
//!    set-up. A range owns the gradient entries of its vertices and the Hessian block columns of its
//!    vertices (contiguous in the CSC value array), zeroes them, then visits — in increasing element order —
//!    every element (triangle or hinge) touching one of its vertices, adding only what it owns.
//!
//! Every value slot thus receives its contributions in increasing element order whatever the number of
//! threads or partitions: results are bitwise identical for any thread count. Nothing allocates, sorts or
//! searches during an evaluation; unrequested outputs are not computed.

mod eigen;
mod hinge_pass;
mod per_hinge;
mod projection;
pub(crate) mod scatter;
mod setup;
mod triangle_pass;

use std::sync::Arc;

use nalgebra::Vector3;
#[cfg(feature = "rayon")]
use rayon::prelude::*;

use crate::error::EvalError;
use crate::hinge::{Stencil, theta_and_gradient};
use crate::mesh::{TriMesh, check_same_vertex_count, validate_positions};
use crate::pattern::SymmetricPattern;
use crate::psi::{HingePsi, HingeQuantities, RestHinge};
use crate::topology::Topology;

use hinge_pass::HingeState;
use scatter::Ctx;

/// How the bending Hessian is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Triangle-refactored (paper Eq. 7): the fast default.
    Refactored,
    /// Per-hinge closed form (Eqs. 4–6).
    PerHinge,
    /// num-dual automatic differentiation over the 12 stencil coordinates.
    Autodiff,
}

impl Method {
    /// All methods.
    pub const ALL: [Method; 3] = [Method::Refactored, Method::PerHinge, Method::Autodiff];

    /// The name used on the command line: `refactored`, `per_hinge`, `autodiff`.
    pub fn name(self) -> &'static str {
        match self {
            Method::Refactored => "refactored",
            Method::PerHinge => "per_hinge",
            Method::Autodiff => "autodiff",
        }
    }

    /// Parses [`Method::name`].
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == s)
    }
}

/// Which Hessian the hinge terms contribute (the energy and gradient are always exact).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HessianMode {
    /// The exact Hessian `ψ′ Hess θ + ψ″ ∇θ∇θᵀ` (indefinite in general).
    #[default]
    Exact,
    /// Gauss–Newton: `max(ψ″, 0) ∇θ∇θᵀ` only — positive semi-definite, cheap, not exact.
    GaussNewton,
    /// The exact per-hinge 12×12 Hessian with its negative eigenvalues clamped to zero (positive
    /// semi-definite per stencil). Evaluated on the per-hinge path whatever the method (an eigen-decomposition
    /// per hinge); with `Method::Autodiff` the autodiff local Hessian is projected.
    ProjectPerHinge,
}

impl HessianMode {
    /// All modes.
    pub const ALL: [HessianMode; 3] = [
        HessianMode::Exact,
        HessianMode::GaussNewton,
        HessianMode::ProjectPerHinge,
    ];

    /// The name used on the command line and in Python: `exact`, `gauss-newton`, `projected`.
    pub fn name(self) -> &'static str {
        match self {
            HessianMode::Exact => "exact",
            HessianMode::GaussNewton => "gauss-newton",
            HessianMode::ProjectPerHinge => "projected",
        }
    }

    /// Parses [`HessianMode::name`].
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == s)
    }
}

/// What an evaluation computes; nothing else is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Request {
    /// The energy.
    pub value: bool,
    /// The gradient (forces are its negative).
    pub gradient: bool,
    /// The Hessian values (in the pattern of [`BendingModel::pattern`]).
    pub hessian: bool,
    /// Ask for a positive semi-definite Hessian instead of the exact one, from each energy's own cheap
    /// construction (documented per energy; for a hinge model in [`HessianMode::Exact`] it is
    /// [`HessianMode::GaussNewton`], other modes are already definite and stay as chosen). Newton's
    /// project-on-demand globalization asks for it only in iterations whose exact Hessian failed to factor.
    /// The energy and gradient are exact either way.
    pub definite: bool,
}

impl Request {
    /// Energy, gradient and Hessian.
    pub const ALL: Request = Request {
        value: true,
        gradient: true,
        hessian: true,
        definite: false,
    };
    /// Energy only.
    pub const VALUE: Request = Request {
        value: true,
        gradient: false,
        hessian: false,
        definite: false,
    };
    /// Energy and gradient.
    pub const GRADIENT: Request = Request {
        value: true,
        gradient: true,
        hessian: false,
        definite: false,
    };

    /// The same request with [`Request::definite`] set to `definite`.
    pub const fn with_definite(self, definite: bool) -> Request {
        Request { definite, ..self }
    }
}

/// Where the work runs. With [`Parallelism::Rayon`] the passes run on the current rayon pool: call
/// [`BendingModel::evaluate`] inside `pool.install(..)` to choose the thread count. Results are bitwise
/// identical either way. Meshes with fewer than [`PARALLEL_MIN_HINGES`] hinges run on the calling thread
/// even with `Rayon`: waking the pool costs more than such an evaluation (measured: 441 vertices, 0.16 ms
/// sequential, 0.23 ms on two threads).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parallelism {
    /// On the calling thread.
    Sequential,
    /// On the current rayon thread pool.
    Rayon,
}

/// Output buffers of an evaluation, allocated once by [`BendingModel::new_output`] and reused.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// The energy (0 when not requested).
    pub energy: f64,
    /// The gradient, `3n` entries `x0, y0, z0, x1, …` (untouched when not requested).
    pub gradient: Vec<f64>,
    /// Hessian values of the lower triangle in [`BendingModel::pattern`]'s CSC order (untouched when not
    /// requested).
    pub hessian: Vec<f64>,
}

/// A hinge energy bound to a mesh: rest data, per-hinge parameters, the sparsity pattern, per-element slots
/// and the partition of the work, all computed once.
#[derive(Debug, Clone)]
pub struct BendingModel<P: HingePsi> {
    psi: P,
    topology: Topology,
    rest: Vec<RestHinge>,
    /// Per-hinge parameters in hinge order (the caller's).
    params: Vec<P::Params>,
    /// The same in state-slot order (what pass 1 streams through), rebuilt whenever either changes.
    slot_params: Vec<P::Params>,
    pattern: Arc<SymmetricPattern>,
    hessian_mode: HessianMode,
    /// θ at the end of the previous step per hinge, and the step (from [`BendingModel::set_step`]): what a
    /// re-hoist after [`BendingModel::update_psi`] needs. `None` before any step.
    step: Option<(Vec<f64>, f64)>,
    /// Everything that depends on the pattern's storage order (rebuilt by [`BendingModel::bind`]).
    layout: setup::Layout,
}

/// Vertices per parallel task of the gather of positions and the scatter of the gradient.
const COPY_CHUNK: usize = 8192;

/// Below this many hinges [`Parallelism::Rayon`] runs sequentially (one hinge-pass task's worth of work).
pub const PARALLEL_MIN_HINGES: usize = 4096;

impl<P: HingePsi> BendingModel<P> {
    /// Binds `psi` to a rest mesh: builds the topology, the rest quantities of every hinge (θ̄, a, rest length,
    /// rest area), the parameters, the pattern (in a locality order, see [`crate::pattern`]) and the slots.
    ///
    /// # Errors
    /// [`EvalError::Mesh`] for an invalid mesh, [`EvalError::Hinge`] for a degenerate rest stencil,
    /// [`EvalError::Pattern`] for a mesh too large for 32-bit value slots.
    pub fn new(rest: &TriMesh, psi: P) -> Result<Self, EvalError> {
        let topology = Topology::new(rest.n_vertices(), rest.triangles())?;
        psi.validate(topology.hinges().len())?;
        let x = rest.positions();
        let mut rest_h = Vec::with_capacity(topology.hinges().len());
        for (i, h) in topology.hinges().iter().enumerate() {
            let s: Stencil = h.vertices.map(|v| x[v]);
            let f = crate::hinge::HingeFrames::new(&s).map_err(|source| EvalError::Hinge {
                hinge: i,
                edge: h.edge,
                vertices: h.vertices,
                source,
            })?;
            let area = 0.5 * (f.upper.double_area + f.lower.double_area);
            let len = f.upper.length[0];
            rest_h.push(RestHinge {
                theta_bar: f.theta(),
                a: 3.0 * len * len / area,
                rest_length: len,
                rest_area: area,
            });
        }
        let params: Vec<P::Params> = rest_h
            .iter()
            .enumerate()
            .map(|(i, r)| psi.params(&HingeQuantities::at_rest(i, r)))
            .collect();
        let n = rest.n_vertices();
        let pattern = Arc::new(SymmetricPattern::new(
            n,
            setup::couplings(&topology, psi.second_derivative_vanishes()),
        )?);
        let layout = setup::Layout::new(&topology, &pattern);
        let slot_params = layout.in_slot_order(&params);
        Ok(Self {
            psi,
            topology,
            rest: rest_h,
            params,
            slot_params,
            pattern,
            hessian_mode: HessianMode::Exact,
            step: None,
            layout,
        })
    }

    /// Changes the energy after set-up — a stiffness, a per-hinge field, a run-time parameter — and
    /// recomputes every hinge's hoisted parameters from the rest state and the current step (what fitting
    /// and plasticity need).
    ///
    /// # Errors
    /// [`EvalError::Psi`] when the changed energy does not fit the mesh; [`EvalError::Pattern`] when it
    /// gains a ψ″ the pattern has no wing couplings for (build a new model). On error nothing changes.
    pub fn update_psi(&mut self, change: impl FnOnce(&mut P)) -> Result<(), EvalError>
    where
        P: Clone,
    {
        let mut psi = self.psi.clone();
        change(&mut psi);
        self.check_changed_psi(&psi)?;
        self.psi = psi;
        self.rehoist();
        Ok(())
    }

    /// Sets parameter `index` of the energy's [`HingePsi::parameters`] (fitting) and re-hoists every hinge's
    /// parameters. Unlike [`BendingModel::update_psi`] it needs no `Clone` energy: the old value is kept to
    /// put back on error.
    ///
    /// # Errors
    /// [`EvalError::Psi`] when the energy refuses the values or no longer fits the mesh;
    /// [`EvalError::Pattern`] when it gains a ψ″ the pattern has no wing couplings for. On error nothing
    /// changes.
    pub fn set_psi_parameter(&mut self, index: usize, values: &[f64]) -> Result<(), EvalError> {
        let old = self.psi.parameter_values(index).ok_or_else(|| {
            EvalError::Psi(crate::psi::PsiError {
                name: format!("#{index}").into(),
                message: format!("the energy has {} parameters", self.psi.parameters().len()),
            })
        })?;
        self.psi.set_parameter_values(index, values)?;
        if let Err(e) = self.check_changed_psi(&self.psi) {
            // The old values were accepted before: putting them back cannot fail.
            let _ = self.psi.set_parameter_values(index, &old);
            return Err(e);
        }
        self.rehoist();
        Ok(())
    }

    /// Whether a changed energy `psi` still fits the model: its parameters fit the mesh, and it has no ψ″
    /// the pattern lacks wing couplings for.
    fn check_changed_psi(&self, psi: &P) -> Result<(), EvalError> {
        psi.validate(self.rest.len())?;
        if !psi.second_derivative_vanishes() && !self.couples_wings(self.hessian_mode) {
            return Err(EvalError::Pattern {
                message: "the changed energy has ψ″ ≠ 0 but the model was built for ψ″ ≡ 0 (no wing couplings); build a new model".into(),
            });
        }
        Ok(())
    }

    /// What ψ of hinge `hinge` is evaluated with: its rest quantities and, once a step is set, θ at the end
    /// of the previous step and the step size. `None` beyond the hinge count.
    pub fn hinge_quantities(&self, hinge: usize) -> Option<HingeQuantities> {
        let r = self.rest.get(hinge)?;
        let mut q = HingeQuantities::at_rest(hinge, r);
        if let Some((thetas, dt)) = &self.step {
            q.theta_prev = thetas[hinge];
            q.dt = *dt;
        }
        Some(q)
    }

    /// How much stiffer each hinge is at rest than the same hinge flat would be (hinge order):
    /// `ψ″(θ̄) / ψ″(0)`, both from the hinge's own parameters. The tan energy's is `1 / cos⁴(θ̄/2)`, over
    /// 10⁶ for a rest hinge folded beyond 3.09 rad; a discrete-shells hinge's is 1 everywhere. A rest state
    /// this stiff conditions Newton's systems badly (a mesh with a crease folded almost flat). `None` for a
    /// hinge whose `ψ″(0)` is not positive and finite (no flat reference); `Some(∞)` where `ψ″(θ̄)` is not
    /// finite.
    pub fn rest_stiffening(&self) -> Vec<Option<f64>> {
        self.rest
            .iter()
            .zip(&self.params)
            .map(|(r, p)| {
                let flat = self.psi.eval(p, 0.0)[2];
                if !(flat > 0.0 && flat.is_finite()) {
                    return None;
                }
                let at_rest = self.psi.eval(p, r.theta_bar)[2];
                Some(if at_rest.is_finite() {
                    at_rest / flat
                } else {
                    f64::INFINITY
                })
            })
            .collect()
    }

    /// Sets every hinge's rest angle θ̄ (hinge order) and re-hoists the parameters that depend on it (the
    /// other rest quantities stay). Bending plasticity updates θ̄ this way.
    ///
    /// # Errors
    /// [`EvalError::Psi`] (parameter `theta_bar`) for a wrong length or a value that is not finite or
    /// outside [−π, π] (the range of θ). On error nothing changes.
    pub fn set_rest_angles(&mut self, theta_bar: &[f64]) -> Result<(), EvalError> {
        let bad = |message: String| {
            EvalError::Psi(crate::psi::PsiError {
                name: "theta_bar".into(),
                message,
            })
        };
        if theta_bar.len() != self.rest.len() {
            return Err(bad(format!(
                "has {} values but the mesh has {} hinges",
                theta_bar.len(),
                self.rest.len()
            )));
        }
        if let Some(i) = theta_bar.iter().position(|t| !t.is_finite()) {
            return Err(bad(format!(
                "value of hinge {i} is not finite ({})",
                theta_bar[i]
            )));
        }
        // θ lies in (−π, π]: a rest angle beyond is no angle the hinge can take (and a tan energy would
        // wrap it around silently), most often degrees given as radians.
        if let Some(i) = theta_bar
            .iter()
            .position(|t| t.abs() > std::f64::consts::PI)
        {
            return Err(bad(format!(
                "value of hinge {i} is {} rad, outside [−π, π], the signed hinge angle's range (degrees \
                 given as radians?)",
                theta_bar[i]
            )));
        }
        for (r, &t) in self.rest.iter_mut().zip(theta_bar) {
            r.theta_bar = t;
        }
        self.rehoist();
        Ok(())
    }

    /// Recomputes all per-hinge parameters from the rest quantities and the step state.
    fn rehoist(&mut self) {
        self.params = self
            .rest
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let mut q = HingeQuantities::at_rest(i, r);
                if let Some((thetas, dt)) = &self.step {
                    q.theta_prev = thetas[i];
                    q.dt = *dt;
                }
                self.psi.params(&q)
            })
            .collect();
        self.slot_params = self.layout.in_slot_order(&self.params);
    }

    /// The vertex pairs this energy couples (the caller's numbering): the three pairs of every triangle with
    /// an interior edge, and the two wing vertices (x2–x3) of every hinge unless ψ″ ≡ 0 — or when the model
    /// projects per hinge ([`HessianMode::ProjectPerHinge`]): the projected 12×12 matrix couples the wings
    /// even where the exact one does not.
    pub fn couplings(&self) -> Vec<(usize, usize)> {
        setup::couplings(&self.topology, !self.couples_wings(self.hessian_mode))
    }

    /// Whether the Hessian in `mode` has wing–wing (x2–x3) blocks.
    fn couples_wings(&self, mode: HessianMode) -> bool {
        !self.psi.second_derivative_vanishes() || mode == HessianMode::ProjectPerHinge
    }

    /// Binds the model to a (possibly larger, shared) pattern that holds every coupling of
    /// [`BendingModel::couplings`]: recomputes the storage order of the elements, the value slots and the
    /// partition of the work. A [`crate::energy::System`] does this so that all its energies write into one
    /// matrix.
    ///
    /// # Errors
    /// [`EvalError::Pattern`] when the pattern has another size or lacks a coupling.
    pub fn bind(&mut self, pattern: Arc<SymmetricPattern>) -> Result<(), EvalError> {
        if pattern.n_vertices() != self.n_vertices() {
            return Err(EvalError::Pattern {
                message: format!(
                    "pattern has {} vertices, mesh has {}",
                    pattern.n_vertices(),
                    self.n_vertices()
                ),
            });
        }
        if let Some(&(a, b)) = self
            .couplings()
            .iter()
            .find(|&&(a, b)| pattern.find(a, b).is_none())
        {
            return Err(EvalError::Pattern {
                message: format!("pattern lacks the coupling of vertices {a} and {b}"),
            });
        }
        self.layout = setup::Layout::new(&self.topology, &pattern);
        self.slot_params = self.layout.in_slot_order(&self.params);
        self.pattern = pattern;
        Ok(())
    }

    /// Chooses the Hessian the model assembles (see [`HessianMode`]). For an energy with ψ″ ≡ 0, switching
    /// to [`HessianMode::ProjectPerHinge`] gives the model's own pattern the wing–wing couplings the
    /// projection writes (rebuilding the pattern, its storage order and the slots); a model bound into a
    /// [`crate::energy::System`] must have its mode chosen before the system is built.
    ///
    /// # Errors
    /// [`EvalError::Pattern`] when the rebuilt pattern does not fit 32-bit value slots. On error nothing
    /// changes.
    pub fn set_hessian_mode(&mut self, mode: HessianMode) -> Result<(), EvalError> {
        if self.couples_wings(mode) && !self.couples_wings(self.hessian_mode) {
            let pattern = Arc::new(SymmetricPattern::new(
                self.n_vertices(),
                setup::couplings(&self.topology, false),
            )?);
            self.layout = setup::Layout::new(&self.topology, &pattern);
            self.slot_params = self.layout.in_slot_order(&self.params);
            self.pattern = pattern;
        }
        self.hessian_mode = mode;
        Ok(())
    }

    /// The Hessian mode.
    pub fn hessian_mode(&self) -> HessianMode {
        self.hessian_mode
    }

    /// The ψ this model evaluates.
    pub fn psi(&self) -> &P {
        &self.psi
    }

    /// The mesh topology.
    pub fn topology(&self) -> &Topology {
        &self.topology
    }

    /// Rest quantities per hinge, in hinge order.
    pub fn rest_hinges(&self) -> &[RestHinge] {
        &self.rest
    }

    /// The Hessian's sparsity pattern (lower triangle, CSC, in its storage order: see [`crate::pattern`]).
    pub fn pattern(&self) -> &SymmetricPattern {
        &self.pattern
    }

    /// The pattern, shared.
    pub fn pattern_arc(&self) -> &Arc<SymmetricPattern> {
        &self.pattern
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.topology.n_vertices()
    }

    /// Output buffers sized for this model.
    pub fn new_output(&self) -> Evaluation {
        Evaluation {
            energy: 0.0,
            gradient: vec![0.0; 3 * self.n_vertices()],
            hessian: vec![0.0; self.pattern.nnz()],
        }
    }

    /// Per-hinge and per-vertex scratch space for the evaluations, allocated once.
    pub fn new_scratch(&self) -> Scratch {
        let (nh, n) = (self.topology.hinges().len(), self.n_vertices());
        Scratch {
            hinges: vec![HingeState::default(); nh],
            sums: vec![0.0; nh.div_ceil(hinge_pass::HINGE_CHUNK)],
            dpsi: vec![0.0; nh],
            positions: vec![Vector3::zeros(); n],
            gradient: vec![0.0; 3 * n],
        }
    }

    /// Evaluates into the caller's own buffers (overwriting the requested ones) and returns the energy (0 when
    /// not requested): `gradient` has `3n` entries in the layout `x0, y0, z0, x1, …` (forces are its
    /// negative), `hessian` has [`SymmetricPattern::nnz`] values in the pattern's lower-CSC order (scatter them
    /// into your CSR arrays with [`crate::export::CsrLayout`]). Unrequested buffers may be empty.
    ///
    /// # Errors
    /// As [`BendingModel::evaluate_into`], and [`EvalError::BufferLength`] for a requested buffer of the
    /// wrong length.
    #[allow(clippy::too_many_arguments)]
    pub fn evaluate_to(
        &self,
        x: &[Vector3<f64>],
        request: Request,
        method: Method,
        par: Parallelism,
        scratch: &mut Scratch,
        gradient: &mut [f64],
        hessian: &mut [f64],
    ) -> Result<f64, EvalError> {
        let mut energy = 0.0;
        self.evaluate_impl(
            x,
            request,
            method,
            par,
            scratch,
            &mut energy,
            gradient,
            hessian,
            false,
        )?;
        Ok(energy)
    }

    /// Convenience: evaluates into fresh buffers.
    ///
    /// # Errors
    /// As [`BendingModel::evaluate_into`].
    pub fn evaluate(
        &self,
        x: &[Vector3<f64>],
        request: Request,
        method: Method,
        par: Parallelism,
    ) -> Result<Evaluation, EvalError> {
        let mut out = self.new_output();
        let mut scratch = self.new_scratch();
        self.evaluate_into(x, request, method, par, &mut scratch, &mut out)?;
        Ok(out)
    }

    /// Starts a time step: θ at the end of the previous step is taken from positions `x_prev`, and `dt` is the
    /// step. Energies that use `theta_prev` or `dt` (viscous damping) refresh their step-dependent
    /// parameters; for the others this only validates the input.
    ///
    /// # Errors
    /// [`EvalError::Mesh`] for bad positions, [`EvalError::Hinge`] for a degenerate stencil,
    /// [`EvalError::Step`] for a non-positive or non-finite `dt`. On error nothing changes.
    pub fn set_step(&mut self, x_prev: &[Vector3<f64>], dt: f64) -> Result<(), EvalError> {
        check_same_vertex_count(self.n_vertices(), x_prev.len())?;
        validate_positions(x_prev)?;
        if !(dt > 0.0 && dt.is_finite()) {
            return Err(EvalError::Step { dt });
        }
        let mut thetas = Vec::with_capacity(self.topology.hinges().len());
        for (i, h) in self.topology.hinges().iter().enumerate() {
            let st: Stencil = h.vertices.map(|v| x_prev[v]);
            // The same θ as the evaluation computes, so a state equal to the previous step has θ = θ_prev.
            let (theta, _) = theta_and_gradient(&st).map_err(|source| EvalError::Hinge {
                hinge: i,
                edge: h.edge,
                vertices: h.vertices,
                source,
            })?;
            thetas.push(theta);
        }
        if self.psi.uses_step_quantities() {
            for (i, (p, r)) in self.params.iter_mut().zip(&self.rest).enumerate() {
                let q = HingeQuantities {
                    theta_prev: thetas[i],
                    dt,
                    ..HingeQuantities::at_rest(i, r)
                };
                self.psi.update_step(&q, p);
            }
            self.slot_params = self.layout.in_slot_order(&self.params);
        }
        self.step = Some((thetas, dt));
        Ok(())
    }

    /// Evaluates the requested quantities at positions `x` into `out`, using `scratch`.
    ///
    /// # Errors
    /// [`crate::MeshError::VertexCountMismatch`], or [`crate::MeshError::NonFiniteCoordinate`] naming the
    /// lowest-numbered vertex with a NaN or infinite coordinate (in a hinge or not); [`EvalError::Hinge`]
    /// naming the lowest-numbered degenerate hinge; [`EvalError::Triangle`] if a pass meets a degenerate
    /// triangle the hinge pass did not report (it cannot: both make one decision); [`EvalError::NonFiniteEnergy`]
    /// when ψ (or ψ′, ψ″ where requested) is not finite at some hinge (the tan energy at θ = ±π). On error
    /// `out` holds no meaningful values.
    pub fn evaluate_into(
        &self,
        x: &[Vector3<f64>],
        request: Request,
        method: Method,
        par: Parallelism,
        scratch: &mut Scratch,
        out: &mut Evaluation,
    ) -> Result<(), EvalError> {
        out.energy = self.evaluate_to(
            x,
            request,
            method,
            par,
            scratch,
            &mut out.gradient,
            &mut out.hessian,
        )?;
        Ok(())
    }

    /// Like [`BendingModel::evaluate_into`], but **adds** energy, gradient and Hessian values to the given
    /// buffers instead of overwriting them (how a [`crate::energy::System`] sums its terms). Empty `gradient`
    /// or `hessian` slices mean "not requested".
    ///
    /// # Errors
    /// As [`BendingModel::evaluate_into`].
    #[allow(clippy::too_many_arguments)]
    pub fn evaluate_add(
        &self,
        x: &[Vector3<f64>],
        request: Request,
        method: Method,
        par: Parallelism,
        scratch: &mut Scratch,
        energy: &mut f64,
        gradient: &mut [f64],
        hessian: &mut [f64],
    ) -> Result<(), EvalError> {
        self.evaluate_impl(
            x, request, method, par, scratch, energy, gradient, hessian, true,
        )
    }

    fn check_scratch(&self, scratch: &mut Scratch) {
        let (nh, n) = (self.topology.hinges().len(), self.n_vertices());
        if scratch.hinges.len() != nh
            || scratch.sums.len() != nh.div_ceil(hinge_pass::HINGE_CHUNK)
            || scratch.dpsi.len() != nh
            || scratch.positions.len() != n
            || scratch.gradient.len() != 3 * n
        {
            *scratch = self.new_scratch();
        }
    }

    /// Copies `x` into storage order, checking that every coordinate is finite (the lowest-numbered vertex
    /// with a bad coordinate is named).
    fn gather_positions(
        &self,
        x: &[Vector3<f64>],
        xs: &mut [Vector3<f64>],
        par: Parallelism,
    ) -> Result<(), EvalError> {
        let order = self.pattern.order();
        let gather = |(c, xs): (usize, &mut [Vector3<f64>])| {
            let mut finite = true;
            for (k, p) in xs.iter_mut().enumerate() {
                *p = x[order[c * COPY_CHUNK + k] as usize];
                finite &= p.x.is_finite() && p.y.is_finite() && p.z.is_finite();
            }
            finite
        };
        let finite = match par {
            #[cfg(feature = "rayon")]
            Parallelism::Rayon => xs.par_chunks_mut(COPY_CHUNK).enumerate().all(gather),
            _ => xs.chunks_mut(COPY_CHUNK).enumerate().all(gather),
        };
        if finite {
            Ok(())
        } else {
            validate_positions(x)?;
            Ok(())
        }
    }

    /// The Hessian mode an evaluation with `request` uses: [`HessianMode::GaussNewton`] for a
    /// [`Request::definite`] request on a model in [`HessianMode::Exact`], the model's own mode otherwise.
    fn effective_mode(&self, request: Request) -> HessianMode {
        if request.definite && self.hessian_mode == HessianMode::Exact {
            HessianMode::GaussNewton
        } else {
            self.hessian_mode
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn evaluate_impl(
        &self,
        x: &[Vector3<f64>],
        request: Request,
        method: Method,
        par: Parallelism,
        scratch: &mut Scratch,
        energy: &mut f64,
        gradient: &mut [f64],
        hessian: &mut [f64],
        accumulate: bool,
    ) -> Result<(), EvalError> {
        check_same_vertex_count(self.n_vertices(), x.len())?;
        let par = if self.topology.hinges().len() < PARALLEL_MIN_HINGES {
            Parallelism::Sequential
        } else {
            par
        };
        let request = Request {
            gradient: request.gradient && !(accumulate && gradient.is_empty()),
            hessian: request.hessian && !(accumulate && hessian.is_empty()),
            ..request
        };
        if request.gradient && gradient.len() != 3 * self.n_vertices() {
            return Err(EvalError::BufferLength {
                buffer: "gradient",
                expected: 3 * self.n_vertices(),
                got: gradient.len(),
            });
        }
        if request.hessian && hessian.len() != self.pattern.nnz() {
            return Err(EvalError::BufferLength {
                buffer: "hessian",
                expected: self.pattern.nnz(),
                got: hessian.len(),
            });
        }
        self.check_scratch(scratch);
        self.gather_positions(x, &mut scratch.positions, par)?;
        // Pass 1: per hinge.
        let need = hinge_pass::Need::of(request, self.psi.second_derivative_vanishes());
        let e = self.run_hinge_pass(
            &scratch.positions,
            need,
            par,
            &mut scratch.hinges,
            &mut scratch.dpsi,
            &mut scratch.sums,
        )?;
        let e = if request.value { e } else { 0.0 };
        if !accumulate && !e.is_finite() {
            // Every hinge's ψ is finite (the pass checked): their sum overflowed. (Summed into a system,
            // `System::check_finite` decides for the total.)
            return Err(EvalError::NonFiniteTotal {
                energy: "bending".into(),
                message: format!(
                    "every hinge's energy is finite, their sum is not ({e}): it overflows f64"
                ),
            });
        }
        *energy = if accumulate { *energy + e } else { e };
        if !(request.gradient || request.hessian) {
            return Ok(());
        }
        // Pass 2: per partition, gradient into storage-ordered scratch.
        let ctx = Ctx {
            model: self,
            x: &scratch.positions,
            states: &scratch.hinges,
            dpsi: &scratch.dpsi,
            request,
            method,
            mode: self.effective_mode(request),
            local_only: false,
            accumulate,
        };
        let grad: &mut [f64] = if request.gradient {
            &mut scratch.gradient
        } else {
            &mut []
        };
        let hess: &mut [f64] = if request.hessian { hessian } else { &mut [] };
        ctx.run(par, grad, hess)?;
        if request.gradient {
            // Back to the caller's numbering, vertex by vertex (each entry written once: any split is
            // bitwise the same).
            let (gs, p) = (&scratch.gradient, &*self.pattern);
            let scatter = |(c, g): (usize, &mut [f64])| {
                for (k, g) in g.chunks_exact_mut(3).enumerate() {
                    let o = 3 * p.storage_of(c * COPY_CHUNK + k);
                    if accumulate {
                        g[0] += gs[o];
                        g[1] += gs[o + 1];
                        g[2] += gs[o + 2];
                    } else {
                        g.copy_from_slice(&gs[o..o + 3]);
                    }
                }
            };
            match par {
                #[cfg(feature = "rayon")]
                Parallelism::Rayon => gradient
                    .par_chunks_mut(3 * COPY_CHUNK)
                    .enumerate()
                    .for_each(scatter),
                _ => gradient
                    .chunks_mut(3 * COPY_CHUNK)
                    .enumerate()
                    .for_each(scatter),
            }
        }
        Ok(())
    }

    /// Benchmark instrumentation (not a stable API: hidden from the docs): the full single-threaded
    /// gradient + Hessian computation with every local block computed but folded into a returned checksum
    /// instead of being written into the matrix. It separates arithmetic from assembly (`hinge bench`'s
    /// `_local` rows). Gradients are written as usual.
    ///
    /// # Errors
    /// As [`BendingModel::evaluate_into`].
    #[doc(hidden)]
    pub fn local_blocks_checksum(
        &self,
        x: &[Vector3<f64>],
        method: Method,
        scratch: &mut Scratch,
        out: &mut Evaluation,
    ) -> Result<f64, EvalError> {
        check_same_vertex_count(self.n_vertices(), x.len())?;
        if out.gradient.len() != 3 * self.n_vertices() {
            return Err(EvalError::BufferLength {
                buffer: "gradient",
                expected: 3 * self.n_vertices(),
                got: out.gradient.len(),
            });
        }
        self.check_scratch(scratch);
        self.gather_positions(x, &mut scratch.positions, Parallelism::Sequential)?;
        let need = hinge_pass::Need::of(Request::ALL, self.psi.second_derivative_vanishes());
        self.run_hinge_pass(
            &scratch.positions,
            need,
            Parallelism::Sequential,
            &mut scratch.hinges,
            &mut scratch.dpsi,
            &mut scratch.sums,
        )?;
        let ctx = Ctx {
            model: self,
            x: &scratch.positions,
            dpsi: &scratch.dpsi,
            states: &scratch.hinges,
            request: Request::ALL,
            method,
            mode: self.hessian_mode,
            local_only: true,
            accumulate: false,
        };
        let sum = ctx.local_checksum(&mut scratch.gradient)?;
        for (s, &v) in self.pattern.order().iter().enumerate() {
            out.gradient[3 * v as usize..3 * v as usize + 3]
                .copy_from_slice(&scratch.gradient[3 * s..3 * s + 3]);
        }
        Ok(sum)
    }
}

/// Per-hinge and per-vertex scratch space reused across evaluations (from [`BendingModel::new_scratch`]; a
/// scratch of the wrong size is replaced on first use).
#[derive(Debug, Clone)]
pub struct Scratch {
    /// Pass-1 records, in state order.
    hinges: Vec<HingeState>,
    /// ψ summed per chunk of the hinge pass.
    sums: Vec<f64>,
    /// ψ′ per state slot, compact: the triangle pass reads it for all three edges of every triangle, and
    /// the 104-byte records would cost a cache line each.
    dpsi: Vec<f64>,
    /// Positions in storage order.
    positions: Vec<Vector3<f64>>,
    /// The gradient in storage order.
    gradient: Vec<f64>,
}
