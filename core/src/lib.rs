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

pub mod autodiff;
pub mod bending;
pub mod error;
pub mod export;
pub mod geometry;
pub mod grid;
pub mod hinge;
pub mod mesh;
pub mod obj;
pub mod pattern;
pub mod psi;
pub mod topology;

pub use error::{DegenerateTriangle, EvalError, HingeSide, MeshError, ObjError, StencilError};
pub use mesh::TriMesh;
pub use topology::{Edge, Hinge, Topology};

pub use nalgebra;

/// The derive macro for hinge energies: see the crate docs and [`psi::HingePsi`].
pub use hinge_macros::HingeEnergy;

// Lets the derive's absolute `::hinge_core::…` paths resolve inside this crate too.
extern crate self as hinge_core;

/// Items the derive macro's generated code refers to. Not a public API: may change without notice.
#[doc(hidden)]
pub mod __private {
    pub use crate::psi::{HingePsi, HingeQuantities, PsiError};
    pub use num_dual::{self, DualNum};
}
