//! # hinge-energies
//!
//! Energies to compose into a [`hinge_core::energy::System`]:
//!
//! - [`bending`]: the hinge family, each declared with `#[derive(HingeEnergy)]` — discrete shells, the
//!   tan-based energy, Willmore-type `2 sin(θ/2)`, Bridson et al.'s, and viscous (Rayleigh) damping that
//!   shares the geometric pass with an elastic term — plus the stiffness from material (Eq. 11, and the
//!   plate-consistent Eq. 11 / 3);
//! - [`spring::MassSpring`] on edges, optionally without the compressive Hessian term;
//! - [`quadratic::QuadraticBending`] (Bergou et al. 2006) with its constant Hessian precomputed at rest;
//! - [`membrane::StvkMembrane`], the St. Venant–Kirchhoff triangle membrane;
//! - [`gravity::Gravity`] with lumped masses; [`drag::Drag`], mass-proportional damping (air drag);
//!   [`contact`]: smooth one-sided penalties against a sphere or a plane; [`pins::Pins`], the constrained
//!   vertices a solver eliminates.
#![cfg_attr(not(test), warn(clippy::unwrap_used, clippy::expect_used))]
#![deny(missing_docs)]

pub mod bending;
pub mod contact;
pub mod drag;
pub mod gravity;
pub mod membrane;
pub mod pins;
pub mod quadratic;
pub mod spring;

pub(crate) mod util {
    use hinge_core::EvalError;
    use hinge_core::pattern::SymmetricPattern;

    /// The pattern block of `(a, b)`, or a typed error naming the pair.
    pub fn slot(pattern: &SymmetricPattern, a: usize, b: usize) -> Result<usize, EvalError> {
        pattern.find(a, b).ok_or_else(|| EvalError::Pattern {
            message: format!("pattern lacks the coupling of vertices {a} and {b}"),
        })
    }

    /// Checks the vertex count of a pattern.
    pub fn same_size(pattern: &SymmetricPattern, n: usize) -> Result<(), EvalError> {
        if pattern.n_vertices() == n {
            Ok(())
        } else {
            Err(EvalError::Pattern {
                message: format!(
                    "pattern has {} vertices, the energy {n}",
                    pattern.n_vertices()
                ),
            })
        }
    }
}
