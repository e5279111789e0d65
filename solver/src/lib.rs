//! # hinge-solver
//!
//! Pluggable linear solvers ([`linear`]: faer sparse LLᵀ with symbolic reuse — the default —, faer sparse LU
//! for indefinite systems, Jacobi-preconditioned CG, Chebyshev-accelerated Jacobi, dense nalgebra) and
//! [`newton`]: Newton's method with pins eliminated, Armijo backtracking and inertia correction, for statics
//! and implicit Euler time stepping of a [`hinge_core::energy::System`].
//!
//! # Quick start: statics of a pinned cloth
//!
//! ```
//! use hinge_core::bending::{BendingModel, Method};
//! use hinge_core::energy::{Energy, HingeTerm, System};
//! use hinge_core::grid::{grid, Diagonal};
//! use hinge_core::nalgebra::Vector3;
//! use hinge_energies::bending::TanBending;
//! use hinge_energies::gravity::{lumped_masses, Gravity};
//! use hinge_energies::membrane::StvkMembrane;
//! use hinge_energies::pins::Pins;
//! use hinge_solver::linear::default_solver;
//! use hinge_solver::newton::{Newton, NewtonParams};
//!
//! let rest = grid(8, 8, 1.0, 1.0, Diagonal::Alternating).unwrap();
//! let n = rest.n_vertices();
//! let terms: Vec<Box<dyn Energy>> = vec![
//!     Box::new(HingeTerm::new("bending", BendingModel::new(&rest, TanBending { k: 1e-2 }).unwrap(),
//!                             Method::Refactored)),
//!     Box::new(StvkMembrane::new(&rest, 1e4, 0.3, 1e-3).unwrap()),
//!     Box::new(Gravity::new(lumped_masses(&rest, 0.1), Vector3::new(0.0, 0.0, -9.81)).unwrap()),
//! ];
//! let mut system = System::new(n, terms).unwrap();
//! // Clamp the y = 0 edge (two vertex rows: one row alone would be a hinge line the sheet swings about).
//! let pins = Pins::new(n, (0..18).collect()).unwrap();
//! let mut newton = Newton::new(&system, &pins, default_solver(), NewtonParams::default()).unwrap();
//! let mut x = rest.positions().to_vec();
//! let stats = newton.minimize(&mut system, &mut x, None).unwrap();
//! assert!(x[n - 1].z < 0.0 && stats.iterations > 0); // the free corner sags; pins stay put
//! assert_eq!(x[0], rest.positions()[0]);
//! ```
#![cfg_attr(not(test), warn(clippy::unwrap_used, clippy::expect_used))]
#![deny(missing_docs)]

pub mod adjoint;
pub mod explicit;
pub mod linear;
pub mod newton;
pub mod ordering;
pub mod statics;
