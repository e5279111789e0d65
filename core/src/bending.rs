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
//! # Passes and determinism
//! 1. Per hinge (parallel, each hinge writes its own record): θ, ψ, ψ′, ψ″ and ∇θ.
//! 2. Per partition (parallel): the vertices are split into contiguous ranges fixed at set-up. A range owns
//!    the gradient entries of its vertices and the Hessian block columns of its vertices (contiguous in the
//!    CSC value array), zeroes them, then visits — in increasing element order — every element (triangle or
//!    hinge) touching one of its vertices, adding only what it owns.
//!
//! Every value slot thus receives its contributions in increasing element order whatever the number of
//! threads or partitions: results are bitwise identical for any thread count. Nothing allocates, sorts or
//! searches during an evaluation; unrequested outputs are not computed.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use num_dual::{Dual2SVec64, hessian};
#[cfg(feature = "rayon")]
use rayon::prelude::*;

use crate::autodiff::{flatten, hinge_angle_generic};
use crate::error::EvalError;
use crate::geometry::TriangleFrame;
use crate::hinge::{HingeFrames, Stencil, hessian_blocks, theta_and_gradient};
use crate::mesh::{TriMesh, check_same_vertex_count};
use crate::pattern::SymmetricPattern;
use crate::psi::{HingePsi, HingeQuantities, RestHinge};
use crate::topology::Topology;

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

/// What an evaluation computes; nothing else is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Request {
    /// The energy.
    pub value: bool,
    /// The gradient (forces are its negative).
    pub gradient: bool,
    /// The Hessian values (in the pattern of [`BendingModel::pattern`]).
    pub hessian: bool,
}

impl Request {
    /// Energy, gradient and Hessian.
    pub const ALL: Request = Request {
        value: true,
        gradient: true,
        hessian: true,
    };
    /// Energy only.
    pub const VALUE: Request = Request {
        value: true,
        gradient: false,
        hessian: false,
    };
    /// Energy and gradient.
    pub const GRADIENT: Request = Request {
        value: true,
        gradient: true,
        hessian: false,
    };
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

#[derive(Debug, Clone, Copy, Default)]
struct HingeState {
    psi: f64,
    dpsi: f64,
    d2psi: f64,
    grad: [Vector3<f64>; 4],
}

const NONE: u32 = u32::MAX;

/// Where a local block goes: the value offsets of its three columns (`[NONE; 3]` for a block the pattern
/// does not hold). Stored per element so that adding a block reads no other table.
type Slot = [u32; 3];
const NO_SLOT: Slot = [NONE; 3];

/// A hinge energy bound to a mesh: rest data, per-hinge parameters, the sparsity pattern, per-element slots
/// and the partition of the work, all computed once.
#[derive(Debug, Clone)]
pub struct BendingModel<P: HingePsi> {
    psi: P,
    topology: Topology,
    rest: Vec<RestHinge>,
    params: Vec<P::Params>,
    pattern: std::sync::Arc<SymmetricPattern>,
    /// Triangles with at least one interior edge (the refactored elements).
    tri_elements: Vec<u32>,
    /// Per refactored element: 6 own block slots (00, 11, 22, 01, 12, 20 by corner) and 4 x3 slots for each
    /// corner whose edge is the element's assigned hinge (x3x3, x3x0, x3x1, x3x2).
    tri_slots: Vec<[Slot; 18]>,
    /// Per refactored element: the state slot of the hinge on each of its edges (NONE on the boundary).
    tri_states: Vec<[u32; 3]>,
    /// Hinge states are stored in the order the refactored pass consumes them (each hinge right where its
    /// upper triangle T is visited), so that pass streams through them: slot → hinge.
    state_order: Vec<u32>,
    /// hinge → slot.
    state_of: Vec<u32>,
    /// Stencil vertices x0..x3 per slot.
    state_vertices: Vec<[usize; 4]>,
    /// Per hinge: 10 block slots (00, 11, 22, 33, 10, 20, 30, 21, 31, 32).
    hinge_slots: Vec<[Slot; 10]>,
    partitions: Vec<Partition>,
    hessian_mode: HessianMode,
}

#[derive(Debug, Clone)]
struct Partition {
    vertices: std::ops::Range<usize>,
    values: std::ops::Range<usize>,
    /// Indices into `tri_elements`.
    tris: Vec<u32>,
    hinges: Vec<u32>,
}

/// Below this many hinges [`Parallelism::Rayon`] runs sequentially (one hinge-pass task's worth of work).
pub const PARALLEL_MIN_HINGES: usize = 4096;

/// Hinges per parallel task of the hinge pass (large enough that task overhead is negligible).
#[cfg(feature = "rayon")]
const HINGE_CHUNK: usize = 4096;

/// Vertices per partition on large meshes. An element straddling two partitions is computed by both, so
/// partitions must be many rows of a mesh deep (8192 vertices are 20 rows of a 401² grid: ~5% repeated work).
const PARTITION_VERTICES: usize = 8192;
/// Small meshes still get this many partitions (of at least `MIN_PARTITION_VERTICES` each) so a few threads
/// have work to share.
const MIN_PARTITIONS: usize = 4;
const MIN_PARTITION_VERTICES: usize = 512;

impl<P: HingePsi> BendingModel<P> {
    /// Binds `psi` to a rest mesh: builds the topology, the rest quantities of every hinge (θ̄, a, rest length,
    /// rest area), the parameters, the pattern and the slots.
    ///
    /// # Errors
    /// [`EvalError::Mesh`] for an invalid mesh, [`EvalError::Hinge`] for a degenerate rest stencil.
    pub fn new(rest: &TriMesh, psi: P) -> Result<Self, EvalError> {
        let topology = Topology::new(rest.n_vertices(), rest.triangles())?;
        psi.validate(topology.hinges().len())?;
        let x = rest.positions();
        let mut rest_h = Vec::with_capacity(topology.hinges().len());
        for (i, h) in topology.hinges().iter().enumerate() {
            let s: Stencil = h.vertices.map(|v| x[v]);
            let f = HingeFrames::new(&s).map_err(|source| EvalError::Hinge {
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
        let params = rest_h
            .iter()
            .enumerate()
            .map(|(i, r)| psi.params(&HingeQuantities::at_rest(i, r)))
            .collect();
        let n = rest.n_vertices();
        let tris = topology.triangles();
        // The hinge on each edge, as u32 (NONE on the boundary).
        let edge_hinge = |e: usize| topology.hinge_of_edge(e).map_or(NONE, |h| h as u32);
        let tri_elements: Vec<u32> = (0..tris.len())
            .filter(|&t| {
                topology.triangle_edges()[t]
                    .iter()
                    .any(|&e| edge_hinge(e) != NONE)
            })
            .map(|t| t as u32)
            .collect();
        let bits = topology.orientation_bits();
        let mut state_order = Vec::with_capacity(topology.hinges().len());
        for &t in &tri_elements {
            for k in 0..3 {
                let hid = edge_hinge(topology.triangle_edges()[t as usize][k]);
                if hid != NONE && bits[t as usize] >> k & 1 == 1 {
                    state_order.push(hid);
                }
            }
        }
        let mut state_of = vec![NONE; topology.hinges().len()];
        for (slot, &h) in state_order.iter().enumerate() {
            state_of[h as usize] = slot as u32;
        }
        let tri_states = tri_elements
            .iter()
            .map(|&t| {
                topology.triangle_edges()[t as usize].map(|e| {
                    let h = edge_hinge(e);
                    if h == NONE {
                        NONE
                    } else {
                        state_of[h as usize]
                    }
                })
            })
            .collect();
        let state_vertices = state_order
            .iter()
            .map(|&h| topology.hinges()[h as usize].vertices)
            .collect();
        let mut model = Self {
            psi,
            topology,
            rest: rest_h,
            params,
            pattern: std::sync::Arc::new(SymmetricPattern::new(n, std::iter::empty())),
            tri_elements,
            tri_states,
            state_order,
            state_of,
            state_vertices,
            tri_slots: Vec::new(),
            hinge_slots: Vec::new(),
            partitions: Vec::new(),
            hessian_mode: HessianMode::Exact,
        };
        let own = std::sync::Arc::new(SymmetricPattern::new(n, model.couplings()));
        model.bind(own)?;
        Ok(model)
    }

    /// The vertex pairs this energy couples: the three pairs of every triangle with an interior edge, and
    /// x0–x3 of every hinge unless ψ″ ≡ 0.
    pub fn couplings(&self) -> Vec<(usize, usize)> {
        let tris = self.topology.triangles();
        let mut pairs =
            Vec::with_capacity(3 * self.tri_elements.len() + self.topology.hinges().len());
        for &t in &self.tri_elements {
            let v = tris[t as usize];
            pairs.extend([(v[0], v[1]), (v[1], v[2]), (v[2], v[0])]);
        }
        if !P::D2_IS_ZERO {
            pairs.extend(
                self.topology
                    .hinges()
                    .iter()
                    .map(|h| (h.vertices[0], h.vertices[3])),
            );
        }
        pairs
    }

    /// Binds the model to a (possibly larger, shared) pattern that holds every coupling of
    /// [`BendingModel::couplings`]: recomputes the value slots and the partition of the work. A
    /// [`crate::energy::System`] does this so that all its energies write into one matrix.
    ///
    /// # Errors
    /// [`EvalError::Pattern`] when the pattern has another size or lacks a coupling.
    pub fn bind(&mut self, pattern: std::sync::Arc<SymmetricPattern>) -> Result<(), EvalError> {
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
        let slot = |a: usize, b: usize| {
            pattern
                .find(a, b)
                .map_or(NO_SLOT, |s| pattern.blocks()[s].offset)
        };
        let topology = &self.topology;
        let tris = topology.triangles();
        let bits = topology.orientation_bits();
        let (tri_states, state_vertices) = (&self.tri_states, &self.state_vertices);
        self.tri_slots = self
            .tri_elements
            .iter()
            .zip(tri_states)
            .map(|(&t, states)| {
                let t = t as usize;
                let v = tris[t];
                let mut s = [NO_SLOT; 18];
                s[..6].copy_from_slice(&[
                    slot(v[0], v[0]),
                    slot(v[1], v[1]),
                    slot(v[2], v[2]),
                    slot(v[0], v[1]),
                    slot(v[1], v[2]),
                    slot(v[2], v[0]),
                ]);
                for k in 0..3 {
                    if states[k] != NONE && bits[t] >> k & 1 == 1 {
                        let hv = state_vertices[states[k] as usize];
                        s[6 + 4 * k..10 + 4 * k].copy_from_slice(&[
                            slot(hv[3], hv[3]),
                            slot(hv[3], hv[0]),
                            slot(hv[3], hv[1]),
                            slot(hv[3], hv[2]),
                        ]);
                    }
                }
                s
            })
            .collect();
        self.hinge_slots = topology
            .hinges()
            .iter()
            .map(|h| {
                let v = h.vertices;
                [
                    slot(v[0], v[0]),
                    slot(v[1], v[1]),
                    slot(v[2], v[2]),
                    slot(v[3], v[3]),
                    slot(v[1], v[0]),
                    slot(v[2], v[0]),
                    slot(v[3], v[0]),
                    slot(v[2], v[1]),
                    slot(v[3], v[1]),
                    slot(v[3], v[2]),
                ]
            })
            .collect();
        self.pattern = pattern;
        self.partitions = self.build_partitions();
        Ok(())
    }

    fn build_partitions(&self) -> Vec<Partition> {
        let n = self.topology.n_vertices();
        // Fixed by the mesh alone, never by the thread count (results do not depend on it anyway).
        let count = n
            .div_ceil(PARTITION_VERTICES)
            .max(MIN_PARTITIONS.min(n.div_ceil(MIN_PARTITION_VERTICES)))
            .max(1);
        let mut parts: Vec<Partition> = (0..count)
            .map(|p| {
                let vs = p * n / count..(p + 1) * n / count;
                Partition {
                    values: self.pattern.block_col_value_start(vs.start)
                        ..self.pattern.block_col_value_start(vs.end),
                    vertices: vs,
                    tris: Vec::new(),
                    hinges: Vec::new(),
                }
            })
            .collect();
        // The partition owning each vertex.
        let mut owner_of = vec![0usize; n];
        for (p, part) in parts.iter().enumerate() {
            owner_of[part.vertices.clone()].fill(p);
        }
        let owner = |v: usize| owner_of[v];
        let tris = self.topology.triangles();
        for (e, &t) in self.tri_elements.iter().enumerate() {
            let mut owners: Vec<usize> = Vec::with_capacity(6);
            let v = tris[t as usize];
            owners.extend(v.iter().map(|&x| owner(x)));
            for &st in &self.tri_states[e] {
                if st != NONE {
                    let hv = self.state_vertices[st as usize];
                    owners.push(owner(hv[3]));
                    owners.push(owner(hv[0]));
                }
            }
            owners.sort_unstable();
            owners.dedup();
            for p in owners {
                parts[p].tris.push(e as u32);
            }
        }
        for (hid, h) in self.topology.hinges().iter().enumerate() {
            let mut owners: Vec<usize> = h.vertices.iter().map(|&x| owner(x)).collect();
            owners.sort_unstable();
            owners.dedup();
            for p in owners {
                parts[p].hinges.push(hid as u32);
            }
        }
        parts
    }

    /// Chooses the Hessian the model assembles (see [`HessianMode`]).
    pub fn set_hessian_mode(&mut self, mode: HessianMode) {
        self.hessian_mode = mode;
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

    /// Rest quantities per hinge.
    pub fn rest_hinges(&self) -> &[RestHinge] {
        &self.rest
    }

    /// The Hessian's sparsity pattern (lower triangle, CSC).
    pub fn pattern(&self) -> &SymmetricPattern {
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
        if P::USES_STEP {
            for (i, (p, r)) in self.params.iter_mut().zip(&self.rest).enumerate() {
                let q = HingeQuantities {
                    theta_prev: thetas[i],
                    dt,
                    ..HingeQuantities::at_rest(i, r)
                };
                self.psi.update_step(&q, p);
            }
        }
        Ok(())
    }

    /// Per-hinge scratch space for [`BendingModel::evaluate_into`], allocated once.
    pub fn new_scratch(&self) -> Scratch {
        Scratch {
            hinges: vec![HingeState::default(); self.topology.hinges().len()],
            dpsi: vec![0.0; self.topology.hinges().len()],
        }
    }

    /// Evaluates the requested quantities at positions `x` into `out`, using `scratch`.
    ///
    /// # Errors
    /// [`crate::MeshError::VertexCountMismatch`] or [`crate::MeshError::NonFiniteCoordinate`] for bad positions;
    /// [`EvalError::Hinge`] naming the lowest-numbered degenerate hinge; [`EvalError::NonFiniteEnergy`] when ψ
    /// is not finite at some hinge (the tan energy at θ = ±π). On error `out` holds no meaningful values.
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
        if scratch.hinges.len() != self.topology.hinges().len()
            || scratch.dpsi.len() != scratch.hinges.len()
        {
            *scratch = self.new_scratch();
        }
        // Pass 1: per hinge.
        let need_grad = request.gradient || (request.hessian && !P::D2_IS_ZERO);
        let states = &mut scratch.hinges[..];
        // The lowest-numbered failing hinge of a run of states (in state order), so that the error reported
        // does not depend on the thread count.
        let first_in = |states: &mut [HingeState], order: &[u32]| {
            states
                .iter_mut()
                .zip(order)
                .filter_map(|(s, &h)| {
                    self.hinge_pass(h as usize, x, need_grad, s)
                        .err()
                        .map(|e| (h, e))
                })
                .min_by_key(|(h, _)| *h)
        };
        let first_error = match par {
            #[cfg(feature = "rayon")]
            Parallelism::Rayon => states
                .par_chunks_mut(HINGE_CHUNK)
                .zip(self.state_order.par_chunks(HINGE_CHUNK))
                .filter_map(|(states, order)| first_in(states, order))
                .min_by_key(|(h, _)| *h),
            // Sequential; without the rayon feature `Parallelism::Rayon` runs here too.
            _ => first_in(states, &self.state_order),
        }
        .map(|(_, e)| e);
        if let Some(e) = first_error {
            return Err(e);
        }
        for (d, s) in scratch.dpsi.iter_mut().zip(&scratch.hinges) {
            *d = s.dpsi;
        }
        let states = &scratch.hinges[..];
        let dpsi = &scratch.dpsi[..];
        let e: f64 = if request.value {
            states.iter().map(|s| s.psi).sum()
        } else {
            0.0
        };
        *energy = if accumulate { *energy + e } else { e };
        if !(request.gradient || request.hessian) {
            return Ok(());
        }
        // Pass 2: per partition.
        let ctx = Ctx {
            model: self,
            x,
            states,
            dpsi,
            request,
            method,
            local_only: false,
            accumulate,
        };
        let grad: &mut [f64] = if request.gradient { gradient } else { &mut [] };
        let hess: &mut [f64] = if request.hessian { hessian } else { &mut [] };
        match par {
            Parallelism::Sequential => {
                for p in &self.partitions {
                    let (g, h) = (
                        slice_of(grad, 3 * p.vertices.start, 3 * p.vertices.end),
                        slice_of(hess, p.values.start, p.values.end),
                    );
                    ctx.run_partition(p, g, h);
                }
            }
            Parallelism::Rayon => ctx.run_range(&self.partitions, grad, hess),
        }
        Ok(())
    }

    /// Benchmark instrumentation: the full single-threaded gradient + Hessian computation with every local
    /// block computed but folded into a returned checksum instead of being written into the matrix. It
    /// separates arithmetic from assembly (`hinge bench`'s `_local` rows). Gradients are written as usual.
    ///
    /// # Errors
    /// As [`BendingModel::evaluate_into`].
    pub fn local_blocks_checksum(
        &self,
        x: &[Vector3<f64>],
        method: Method,
        scratch: &mut Scratch,
        out: &mut Evaluation,
    ) -> Result<f64, EvalError> {
        check_same_vertex_count(self.n_vertices(), x.len())?;
        if scratch.hinges.len() != self.topology.hinges().len()
            || out.gradient.len() != 3 * self.n_vertices()
        {
            return Err(EvalError::BufferLength {
                buffer: "scratch or gradient",
                expected: self.topology.hinges().len(),
                got: scratch.hinges.len(),
            });
        }
        for (s, &h) in scratch.hinges.iter_mut().zip(&self.state_order) {
            self.hinge_pass(h as usize, x, true, s)?;
        }
        for (d, s) in scratch.dpsi.iter_mut().zip(&scratch.hinges) {
            *d = s.dpsi;
        }
        let ctx = Ctx {
            model: self,
            x,
            dpsi: &scratch.dpsi,
            states: &scratch.hinges,
            request: Request::ALL,
            method,
            local_only: true,
            accumulate: false,
        };
        let mut sum = 0.0;
        for p in &self.partitions {
            let g = &mut out.gradient[3 * p.vertices.start..3 * p.vertices.end];
            sum += ctx.run_partition(p, g, &mut []);
        }
        Ok(sum)
    }

    #[inline]
    fn hinge_pass(
        &self,
        i: usize,
        x: &[Vector3<f64>],
        need_grad: bool,
        s: &mut HingeState,
    ) -> Result<(), EvalError> {
        let h = &self.topology.hinges()[i];
        let st: Stencil = h.vertices.map(|v| x[v]);
        let (theta, grad) = theta_and_gradient(&st).map_err(|source| EvalError::Hinge {
            hinge: i,
            edge: h.edge,
            vertices: h.vertices,
            source,
        })?;
        let [psi, dpsi, d2psi] = self.psi.eval(&self.params[i], theta);
        if !(psi.is_finite() && dpsi.is_finite() && d2psi.is_finite()) {
            return Err(EvalError::NonFiniteEnergy {
                hinge: i,
                vertices: h.vertices,
                theta,
            });
        }
        s.psi = psi;
        s.dpsi = dpsi;
        s.d2psi = d2psi;
        if need_grad {
            s.grad = grad;
        }
        Ok(())
    }
}

/// The nearest positive semi-definite matrix (eigenvalues clamped at zero) of a symmetric 12×12 matrix.
fn project_psd(h: SMatrix<f64, 12, 12>) -> SMatrix<f64, 12, 12> {
    let eig = h.symmetric_eigen();
    let clamped = eig.eigenvalues.map(|l| l.max(0.0));
    let q = eig.eigenvectors;
    let p = q * SMatrix::<f64, 12, 12>::from_diagonal(&clamped) * q.transpose();
    // Exactly symmetric.
    (p + p.transpose()) * 0.5
}

/// Per-hinge scratch space reused across evaluations.
#[derive(Debug, Clone)]
pub struct Scratch {
    hinges: Vec<HingeState>,
    /// ψ′ per state slot, compact: the triangle pass reads it for all three edges of every triangle, and
    /// the 120-byte states would cost a cache line each.
    dpsi: Vec<f64>,
}

fn slice_of(s: &mut [f64], a: usize, b: usize) -> &mut [f64] {
    if s.is_empty() { s } else { &mut s[a..b] }
}

struct Ctx<'a, P: HingePsi> {
    model: &'a BendingModel<P>,
    x: &'a [Vector3<f64>],
    states: &'a [HingeState],
    dpsi: &'a [f64],
    request: Request,
    method: Method,
    local_only: bool,
    /// Add to the output instead of zeroing it first.
    accumulate: bool,
}

/// The part of the output one partition owns.
struct Owned<'a> {
    vertices: std::ops::Range<usize>,
    /// Owned value offsets (empty when the Hessian is not requested).
    values: std::ops::Range<usize>,
    grad: &'a mut [f64],
    hess: &'a mut [f64],
    /// Benchmark mode: blocks are folded into `checksum` instead of being written.
    local_only: bool,
    checksum: f64,
}

impl Owned<'_> {
    #[inline]
    fn add_grad(&mut self, v: usize, g: &Vector3<f64>) {
        if !self.grad.is_empty() && self.vertices.contains(&v) {
            let o = 3 * (v - self.vertices.start);
            self.grad[o] += g.x;
            self.grad[o + 1] += g.y;
            self.grad[o + 2] += g.z;
        }
    }

    /// Adds block `b` for (row vertex `r`, column vertex `c`) at `slot`, if this partition owns it.
    #[inline(always)]
    fn add_block(&mut self, slot: &Slot, r: usize, c: usize, b: &Matrix3<f64>) {
        if self.local_only {
            self.checksum += b[(0, 0)] + b[(1, 1)] + b[(2, 2)] + b[(2, 0)];
            return;
        }
        let first = slot[0] as usize;
        // A block's three columns lie in one block column, so its first offset decides ownership. NONE
        // (a block the pattern does not hold) and an empty Hessian (not requested) fall outside too.
        if first < self.values.start || first >= self.values.end {
            return;
        }
        let base = self.values.start;
        if r == c {
            for cc in 0..3 {
                let o = slot[cc] as usize - base;
                let dst = &mut self.hess[o..o + 3 - cc];
                for (k, rr) in (cc..3).enumerate() {
                    dst[k] += b[(rr, cc)];
                }
            }
        } else if r > c {
            for cc in 0..3 {
                let o = slot[cc] as usize - base;
                let dst = &mut self.hess[o..o + 3];
                dst[0] += b[(0, cc)];
                dst[1] += b[(1, cc)];
                dst[2] += b[(2, cc)];
            }
        } else {
            // Stored block is (c, r) = bᵀ.
            for cc in 0..3 {
                let o = slot[cc] as usize - base;
                let dst = &mut self.hess[o..o + 3];
                dst[0] += b[(cc, 0)];
                dst[1] += b[(cc, 1)];
                dst[2] += b[(cc, 2)];
            }
        }
    }
}

impl<P: HingePsi> Ctx<'_, P> {
    fn run_range(&self, parts: &[Partition], grad: &mut [f64], hess: &mut [f64]) {
        match parts.len() {
            0 => {}
            1 => {
                self.run_partition(&parts[0], grad, hess);
            }
            n => {
                let (a, b) = parts.split_at(n / 2);
                let gsplit = 3 * (b[0].vertices.start - a[0].vertices.start);
                let hsplit = b[0].values.start - a[0].values.start;
                let (ga, gb) = if grad.is_empty() {
                    (&mut [][..], &mut [][..])
                } else {
                    grad.split_at_mut(gsplit)
                };
                let (ha, hb) = if hess.is_empty() {
                    (&mut [][..], &mut [][..])
                } else {
                    hess.split_at_mut(hsplit)
                };
                #[cfg(feature = "rayon")]
                rayon::join(|| self.run_range(a, ga, ha), || self.run_range(b, gb, hb));
                #[cfg(not(feature = "rayon"))]
                {
                    self.run_range(a, ga, ha);
                    self.run_range(b, gb, hb);
                }
            }
        }
    }

    fn run_partition(&self, p: &Partition, grad: &mut [f64], hess: &mut [f64]) -> f64 {
        if !self.accumulate {
            grad.fill(0.0);
            hess.fill(0.0);
        }
        let mut own = Owned {
            vertices: p.vertices.clone(),
            values: if hess.is_empty() {
                0..0
            } else {
                p.values.clone()
            },
            grad,
            hess,
            local_only: self.local_only,
            checksum: 0.0,
        };
        let per_hinge_path = self.method != Method::Refactored
            || (self.request.hessian && self.model.hessian_mode == HessianMode::ProjectPerHinge);
        match per_hinge_path {
            false => {
                for &e in &p.tris {
                    self.triangle(e as usize, &mut own);
                }
            }
            true => {
                for &h in &p.hinges {
                    self.hinge(h as usize, &mut own);
                }
            }
        }
        own.checksum
    }

    /// One refactored element: H^Δ (Eq. 7) plus the assigned hinges' outer products and gradients.
    #[inline]
    fn triangle(&self, e: usize, own: &mut Owned) {
        let m = self.model;
        let t = m.tri_elements[e] as usize;
        let v = m.topology.triangles()[t];
        let slots = &m.tri_slots[e];
        let bits = m.topology.orientation_bits()[t];
        let hid = m.tri_states[e];
        let assigned = |k: usize| hid[k] != NONE && bits >> k & 1 == 1;
        if self.request.gradient {
            for k in 0..3 {
                if assigned(k) {
                    let s = &self.states[hid[k] as usize];
                    let hv = m.state_vertices[hid[k] as usize];
                    for a in 0..4 {
                        own.add_grad(hv[a], &(s.grad[a] * s.dpsi));
                    }
                }
            }
        }
        if !self.request.hessian {
            return;
        }
        // Only fails on a triangle the hinge pass already accepted if positions changed: they cannot.
        let Ok(f) = TriangleFrame::new(&self.x[v[0]], &self.x[v[1]], &self.x[v[2]]) else {
            return;
        };
        let gauss_newton = m.hessian_mode == HessianMode::GaussNewton;
        let c = hid.map(|h| {
            if h == NONE || gauss_newton {
                0.0
            } else {
                self.dpsi[h as usize]
            }
        });
        let cs = &f.cos_angle;
        let d = [0, 1, 2]
            .map(|i| c[(i + 2) % 3] * cs[(i + 1) % 3] + c[(i + 1) % 3] * cs[(i + 2) % 3] - c[i]);
        // Every term of Eq. 7 is a rank-one n ⊗ m_k or m_k ⊗ n, so each block is n pᵀ + q nᵀ for two vectors
        // p, q: M_i = n m_iᵀ, R_i = (c_i / l_i²) n m_iᵀ.
        let n = f.normal;
        let en = &f.edge_normal;
        let r = [0, 1, 2].map(|i| c[i] * f.inv_length_sq[i]);
        let ih = &f.inv_altitude;
        // Blocks 0..3: diagonal (corner i, corner i); blocks 3..6: (corner i, corner i + 1).
        let mut blk = [Matrix3::zeros(); 6];
        for i in 0..3 {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            let q = en[i] * (ih[i] * ih[i] * d[i]);
            let p = q - en[i1] * r[i1] - en[i2] * r[i2];
            blk[i] = n * p.transpose() + q * n.transpose();
            let w = ih[i] * ih[i1];
            let mut left = en[i1] * (w * d[i]);
            let mut right = en[i] * (w * d[i1]);
            // † transposes R_{i+2} in the lower triangle T̃ of edge i+2's hinge (orientation bit clear).
            if bits >> i2 & 1 == 1 {
                right += en[i2] * r[i2];
            } else {
                left += en[i2] * r[i2];
            }
            blk[3 + i] = n * right.transpose() + left * n.transpose();
        }
        // ψ″ ∇θ∇θᵀ of the assigned hinges.
        if !P::D2_IS_ZERO {
            for k in 0..3 {
                if !assigned(k) {
                    continue;
                }
                let s = &self.states[hid[k] as usize];
                let d2 = if gauss_newton {
                    s.d2psi.max(0.0)
                } else {
                    s.d2psi
                };
                let g = s.grad.map(|gv| gv * d2);
                let gr = &s.grad;
                // Hinge x0, x1, x2 are corners k, k+1, k+2; own block 3 + i is (corner i, corner i + 1), so
                // (x0, x1) → 3 + k, (x1, x2) → 3 + k1, (x2, x0) → 3 + k2.
                let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
                blk[k] += g[0] * gr[0].transpose();
                blk[k1] += g[1] * gr[1].transpose();
                blk[k2] += g[2] * gr[2].transpose();
                blk[3 + k] += g[0] * gr[1].transpose();
                blk[3 + k1] += g[1] * gr[2].transpose();
                blk[3 + k2] += g[2] * gr[0].transpose();
                let hv = m.state_vertices[hid[k] as usize];
                let x3 = hv[3];
                own.add_block(&slots[6 + 4 * k], x3, x3, &(g[3] * gr[3].transpose()));
                for a in 0..3 {
                    own.add_block(
                        &slots[7 + 4 * k + a],
                        x3,
                        hv[a],
                        &(g[3] * gr[a].transpose()),
                    );
                }
            }
        }
        for i in 0..3 {
            own.add_block(&slots[i], v[i], v[i], &blk[i]);
            let i1 = (i + 1) % 3;
            own.add_block(&slots[3 + i], v[i], v[i1], &blk[3 + i]);
        }
    }

    /// One per-hinge element (closed form or autodiff).
    #[inline]
    fn hinge(&self, hid: usize, own: &mut Owned) {
        let m = self.model;
        let h = &m.topology.hinges()[hid];
        let s = &self.states[m.state_of[hid] as usize];
        let st: Stencil = h.vertices.map(|v| self.x[v]);
        let hv = h.vertices;
        let slots = &m.hinge_slots[hid];
        const PAIRS: [(usize, usize); 10] = [
            (0, 0),
            (1, 1),
            (2, 2),
            (3, 3),
            (1, 0),
            (2, 0),
            (3, 0),
            (2, 1),
            (3, 1),
            (3, 2),
        ];
        match self.method {
            Method::Autodiff => {
                let p = &m.params[hid];
                let coords = SVector::<f64, 12>::from(flatten(&st));
                let (_, g, hm): (f64, SVector<f64, 12>, SMatrix<f64, 12, 12>) = hessian(
                    |c: SVector<Dual2SVec64<12>, 12>| {
                        let arr: [Dual2SVec64<12>; 12] = c.into();
                        m.psi.psi_dual(p, hinge_angle_generic(&arr))
                    },
                    &coords,
                );
                if self.request.gradient {
                    for a in 0..4 {
                        own.add_grad(hv[a], &Vector3::new(g[3 * a], g[3 * a + 1], g[3 * a + 2]));
                    }
                }
                if self.request.hessian {
                    let hm = if m.hessian_mode == HessianMode::ProjectPerHinge {
                        project_psd(hm)
                    } else {
                        hm
                    };
                    for (q, &(a, b)) in PAIRS.iter().enumerate() {
                        let blk: Matrix3<f64> = hm.fixed_view::<3, 3>(3 * a, 3 * b).into_owned();
                        own.add_block(&slots[q], hv[a], hv[b], &blk);
                    }
                }
            }
            _ => {
                if self.request.gradient {
                    for a in 0..4 {
                        own.add_grad(hv[a], &(s.grad[a] * s.dpsi));
                    }
                }
                if !self.request.hessian {
                    return;
                }
                let Ok(f) = HingeFrames::new(&st) else {
                    return;
                };
                let g = f.gradient();
                let mode = m.hessian_mode;
                let (dpsi, d2psi) = match mode {
                    HessianMode::GaussNewton => (0.0, s.d2psi.max(0.0)),
                    _ => (s.dpsi, s.d2psi),
                };
                let hb = if dpsi != 0.0 {
                    hessian_blocks(&f)
                } else {
                    [[Matrix3::zeros(); 4]; 4]
                };
                let block = |a: usize, b: usize| {
                    let mut blk = if a == b {
                        (hb[a][a] + hb[a][a].transpose()) * (0.5 * dpsi)
                    } else {
                        hb[a][b] * dpsi
                    };
                    if !P::D2_IS_ZERO {
                        blk += (g[a] * d2psi) * g[b].transpose();
                    }
                    blk
                };
                if mode == HessianMode::ProjectPerHinge {
                    let mut local = SMatrix::<f64, 12, 12>::zeros();
                    for a in 0..4 {
                        for b in 0..=a {
                            let blk = block(a, b);
                            local.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&blk);
                            local
                                .fixed_view_mut::<3, 3>(3 * b, 3 * a)
                                .copy_from(&blk.transpose());
                        }
                    }
                    let projected = project_psd(local);
                    for (q, &(a, b)) in PAIRS.iter().enumerate() {
                        let blk: Matrix3<f64> =
                            projected.fixed_view::<3, 3>(3 * a, 3 * b).into_owned();
                        own.add_block(&slots[q], hv[a], hv[b], &blk);
                    }
                } else {
                    for (q, &(a, b)) in PAIRS.iter().enumerate() {
                        own.add_block(&slots[q], hv[a], hv[b], &block(a, b));
                    }
                }
            }
        }
    }
}
