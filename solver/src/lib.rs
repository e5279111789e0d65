//! # hinge-solver
//!
//! Pluggable linear solvers ([`linear`]: faer sparse LLᵀ with symbolic reuse — the default —, faer sparse LU
//! for indefinite systems, Jacobi-preconditioned CG, Chebyshev-accelerated Jacobi, dense nalgebra) and
//! [`newton`]: Newton's method with pins eliminated, Armijo backtracking and inertia correction, for statics
//! and implicit Euler time stepping of a [`hinge_core::energy::System`].
#![cfg_attr(not(test), warn(clippy::unwrap_used, clippy::expect_used))]
#![deny(missing_docs)]

pub mod linear;
pub mod newton;
