//! # hinge-core
//!
//! Mesh topology and the hinge-angle kernels of **hinge**, a framework for bending energies ψ(θ) of the
//! signed hinge (dihedral) angle on triangle meshes, after Tamstorf & Grinspun, *Discrete bending forces and
//! their Jacobians* (2013).
//!
//! - [`TriMesh`], [`Topology`]: validated meshes; edges, σ flags and hinges built once by sorting edge
//!   triples ([`topology`] documents the hinge labelling).
//! - [`geometry`]: the per-triangle quantities of the paper's Algorithm 2.
//! - [`hinge`]: θ, tan(θ/2), ∇θ (Eq. 4) and Hess θ (Eqs. 5–6, corrected) of one stencil, with the formulas.
//! - [`autodiff`]: the same θ, ∇θ, Hess θ by num-dual, the oracle and slow baseline.
//! - [`grid`], [`obj`]: grid generator, OBJ input and output.
//! - [`psi`]: the ψ(θ) interface ([`psi::HingePsi`]) and the built-in discrete-shells and tan energies.
//! - [`bending`]: the assembly engine — energy, forces and the exact sparse Hessian by the
//!   triangle-refactored (`refactored`), per-hinge (`per_hinge`) or num-dual (`autodiff`) method.
//! - [`pattern`], [`export`]: the lower-triangle CSC sparsity pattern; full CSR, faer and Matrix Market.
//!
//! # Declaring your own energy
//!
//! `#[derive(HingeEnergy)]` turns a struct of constants and a ψ expression into a [`psi::HingePsi`]; ψ′ and
//! ψ″ are derived symbolically at compile time, θ-free parts are computed once per hinge.
//!
//! ```
//! use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
//! use hinge_core::{grid, HingeEnergy};
//!
//! /// A bending energy that grows like θ⁴ for large angles.
//! #[derive(HingeEnergy)]
//! #[psi(k * a * ((theta - theta_bar).powi(2) + c * (theta - theta_bar).powi(4)))]
//! struct Stiffening {
//!     k: f64,
//!     c: f64,
//! }
//!
//! let rest = grid::unit_grid(8).unwrap();
//! let bent = grid::wave(rest.positions());
//! let model = BendingModel::new(&rest, Stiffening { k: 1.0, c: 10.0 }).unwrap();
//! let e = model.evaluate(&bent, Request::ALL, Method::Refactored, Parallelism::Sequential).unwrap();
//! assert!(e.energy > 0.0);
//! // Forces are −gradient; the Hessian is in `model.pattern()`'s lower-triangle CSC order.
//! assert_eq!(e.hessian.len(), model.pattern().nnz());
//! let flat = model.evaluate(rest.positions(), Request::ALL, Method::Refactored, Parallelism::Sequential).unwrap();
//! assert_eq!(flat.energy, 0.0);
//! ```
//!
//! The expression language (the same at compile time and at run time, defined once in `hinge-symbolic`):
//! `theta`; the struct's `f64` fields (a field marked `#[per_hinge]` is a `Vec<f64>` with one value per
//! hinge, in the hinge order of [`topology`]); the provided per-hinge names `theta_bar`, `a` (= 3|ē|²/Ā),
//! `rest_length`, `rest_area`, and for damping `theta_prev` (θ at the end of the previous step, see
//! [`bending::BendingModel::set_step`]) and `dt`; the constants `PI`, `E` (also `std::f64::consts::PI`);
//! literals, `+ - * /`, unary `-`, parentheses; `sqrt sin cos tan exp ln atan tanh sinh cosh abs` as
//! `f(x)` or `x.f()`; `min(a, b)`, `max(a, b)`; `powi(x, INT)`, `powf(x, θ-free)`, `pow(x, y)`;
//! `atan2(θ-free, θ-free)`; `if A < B { … } else { … }` (also `<=`, `>`, `>=`, `else if`); and
//! `{ let x = …; … }` blocks. Anything else is a compile error pointing at the offending token (with a
//! "did you mean" for near misses). A field named like a provided name or a constant is an error.
//!
//! Non-smooth points: `abs`, `min`, `max` and `if` differentiate branch-wise, and at a switch point ψ′ and
//! ψ″ are those of the branch the condition selects: `abs(x)` at `x = 0` takes `x`'s, `min(a, b)` and
//! `max(a, b)` at `a = b` take `a`'s, `if l < r { A } else { B }` at `l = r` takes `B`'s.
//!
//! At run time the same text becomes a [`psi::runtime::RuntimePsi`] (no compiler, no rebuild): it
//! implements [`psi::HingePsi`] like a derived energy and gives bitwise the same values.
//!
//! ```
//! use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
//! use hinge_core::psi::runtime::{ParamValue, RuntimePsi};
//! use hinge_core::grid;
//!
//! let psi = RuntimePsi::new(
//!     "k * a * if theta < theta_bar { (theta - theta_bar).powi(2) } else { 2.0 * (theta - theta_bar).powi(2) }",
//!     [("k", ParamValue::Scalar(1.0))],
//! )
//! .unwrap();
//! let rest = grid::unit_grid(8).unwrap();
//! let model = BendingModel::new(&rest, psi).unwrap();
//! let e = model.evaluate(&grid::wave(rest.positions()), Request::ALL, Method::Refactored, Parallelism::Sequential).unwrap();
//! assert!(e.energy > 0.0);
//! ```
//!
//! For a ψ the language cannot express, `#[psi(autodiff)]` takes an inherent method
//! `fn psi<D: DualNum<Primitive = f64> + Copy>(&self, q: &HingeQuantities, theta: D) -> D` and obtains ψ′, ψ″
//! with num-dual.
//!
//! # On your own arrays
//!
//! Positions as a flat `[f64]` (or `[[f64; 3]]`) are viewed without copying; the Hessian goes into your CSR
//! arrays through a layout built once ([`layout`], [`export::CsrLayout`]).
//!
//! ```
//! use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
//! use hinge_core::export::CsrLayout;
//! use hinge_core::layout::Positions;
//! use hinge_core::psi::TanBending;
//! use hinge_core::TriMesh;
//!
//! // Two triangles folded along the edge 1–2.
//! let rest = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0];
//! let mine = [0.0, 1.0, 0.2, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0];
//! let tris: [[u32; 3]; 2] = [[0, 1, 2], [3, 2, 1]];
//! let mesh = TriMesh::from_arrays(&rest[..], &tris[..]).unwrap();
//! let model = BendingModel::new(&mesh, TanBending { k: 1.0 }).unwrap();
//! let (mut out, mut scratch) = (model.new_output(), model.new_scratch());
//! model
//!     .evaluate_into(mine.as_vectors().unwrap(), Request::ALL, Method::Refactored,
//!                    Parallelism::Sequential, &mut scratch, &mut out)
//!     .unwrap();
//! let layout = CsrLayout::new(model.pattern());
//! let mut csr_values = vec![0.0; layout.nnz()];
//! layout.scatter(&out.hessian, &mut csr_values).unwrap();
//! assert!(out.energy > 0.0 && csr_values.iter().any(|v| *v != 0.0));
//! ```
//!
//! # Topology and one hinge
//!
//! ```
//! use hinge_core::{grid::unit_grid, Topology, hinge::hinge_angle_hessian};
//!
//! let mesh = unit_grid(4).unwrap();
//! let topo = Topology::new(mesh.n_vertices(), mesh.triangles()).unwrap();
//! assert_eq!(topo.hinges().len(), 40); // 3·16 edges per cell pattern minus 16 boundary edges
//! let h = &topo.hinges()[0];
//! let x = h.vertices.map(|v| mesh.positions()[v]);
//! let d = hinge_angle_hessian(&x).unwrap();
//! assert_eq!(d.theta, 0.0); // flat
//! ```
#![cfg_attr(not(test), warn(clippy::unwrap_used, clippy::expect_used))]
#![deny(missing_docs)]

pub mod anisotropy;
pub mod autodiff;
pub mod bending;
pub mod energy;
pub mod error;
pub mod export;
pub mod geometry;
pub mod grid;
pub mod hinge;
pub mod layout;
pub mod mesh;
pub mod meshio;
pub mod obj;
pub mod pattern;
pub mod precise;
pub mod psi;
pub mod shapes;
pub mod topology;

pub use error::{
    DegenerateTriangle, ElementNames, ElementRef, EvalError, HingeSide, MeshError, ObjError,
    StencilError,
};
pub use mesh::TriMesh;
pub use topology::{Edge, Hinge, Topology};

pub use nalgebra;
/// num-dual, re-exported for `#[psi(autodiff)]` energies (`hinge_core::num_dual::DualNum`).
pub use num_dual;

/// The derive macro for hinge energies: see the crate docs and [`psi::HingePsi`].
pub use hinge_macros::HingeEnergy;

// Lets the derive's absolute `::hinge_core::…` paths resolve inside this crate too.
extern crate self as hinge_core;

/// Items the derive macro's generated code refers to. Not a public API: may change without notice.
#[doc(hidden)]
pub mod __private {
    pub use crate::psi::{HingePsi, HingeQuantities, PsiError, PsiParameter, scalar_length_error};
    pub use num_dual::{self, DualNum};
}
