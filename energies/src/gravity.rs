//! Gravity with lumped masses: `E = −Σ_i m_i g · x_i`. Linear in `x`: constant gradient, zero Hessian (it
//! adds no coupling to the pattern).

use std::sync::Arc;

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy};
use hinge_core::nalgebra::Vector3;
use hinge_core::pattern::SymmetricPattern;
use hinge_core::{EvalError, TriMesh};

/// Lumped vertex masses from rest areas: each triangle gives a third of `density · area` to each corner
/// (`density` is mass per unit area).
pub fn lumped_masses(rest: &TriMesh, density: f64) -> Vec<f64> {
    let x = rest.positions();
    let mut m = vec![0.0; rest.n_vertices()];
    for t in rest.triangles() {
        let area = 0.5 * (x[t[1]] - x[t[0]]).cross(&(x[t[2]] - x[t[0]])).norm();
        for &v in t {
            m[v] += density * area / 3.0;
        }
    }
    m
}

/// Uniform gravity acting on lumped masses.
#[derive(Debug, Clone)]
pub struct Gravity {
    masses: Vec<f64>,
    g: Vector3<f64>,
}

impl Gravity {
    /// Gravity `g` (for example `(0, 0, −9.81)`) on vertices of masses `masses`.
    ///
    /// # Errors
    /// [`EvalError::Element`] naming a non-finite or negative mass, or a non-finite `g`.
    pub fn new(masses: Vec<f64>, g: Vector3<f64>) -> Result<Self, EvalError> {
        crate::util::check_masses(&masses)?;
        if !g.iter().all(|c| c.is_finite()) {
            return Err(EvalError::Element {
                element: "gravity".into(),
                message: format!("acceleration {g:?} is not finite"),
            });
        }
        Ok(Self { masses, g })
    }

    /// The masses.
    pub fn masses(&self) -> &[f64] {
        &self.masses
    }
}

impl Energy for Gravity {
    fn name(&self) -> &str {
        "gravity"
    }

    fn n_vertices(&self) -> usize {
        self.masses.len()
    }

    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}

    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError> {
        crate::util::same_size(pattern, self.masses.len())
    }

    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        hinge_core::mesh::check_same_vertex_count(self.masses.len(), x.len())?;
        let mut e = 0.0;
        for (i, (&m, p)) in self.masses.iter().zip(x).enumerate() {
            e -= m * self.g.dot(p);
            if request.gradient {
                acc.add_gradient(i, &(-self.g * m));
            }
        }
        Ok(if request.value { e } else { 0.0 })
    }
}
