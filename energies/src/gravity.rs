//! Gravity with lumped masses: `E = −Σ_i m_i g · x_i`. Linear in `x`: constant gradient, zero Hessian (it
//! adds no coupling to the pattern).

use std::sync::Arc;

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{
    Accumulator, Energy, Parameter, ParameterOutput, check_parameter_output, unknown_parameter,
};
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
    /// `g`, the acceleration vector (3 values, m/s²): `E = −Σ m_i g·x_i`, so `∂E/∂g = −Σ m_i x_i` and
    /// `∂∇_i E/∂g = −m_i I`.
    fn parameters(&self) -> Vec<Parameter> {
        vec![Parameter {
            name: "g".into(),
            len: 3,
        }]
    }

    fn parameter(&self, name: &str) -> Result<Vec<f64>, EvalError> {
        match name {
            "g" => Ok(self.g.iter().copied().collect()),
            _ => Err(unknown_parameter(name, &self.parameters())),
        }
    }

    fn set_parameter(&mut self, name: &str, values: &[f64]) -> Result<(), EvalError> {
        let p = &self.parameters()[0];
        if name != p.name {
            return Err(unknown_parameter(name, &self.parameters()));
        }
        hinge_core::energy::check_parameter_values(p, values)?;
        self.g = Vector3::new(values[0], values[1], values[2]);
        Ok(())
    }

    fn add_parameter_derivatives(
        &mut self,
        x: &[Vector3<f64>],
        name: &str,
        out: &mut ParameterOutput,
    ) -> Result<(), EvalError> {
        if name != "g" {
            return Err(unknown_parameter(name, &self.parameters()));
        }
        let n = self.masses.len();
        hinge_core::mesh::check_same_vertex_count(n, x.len())?;
        check_parameter_output(name, 3, n, out)?;
        for (i, (&m, p)) in self.masses.iter().zip(x).enumerate() {
            for c in 0..3 {
                if !out.energy.is_empty() {
                    out.energy[c] -= m * p[c];
                }
                if !out.lambda.is_empty() {
                    out.contracted[c] -= m * out.lambda[3 * i + c];
                }
                if !out.direction.is_empty() {
                    out.gradient[3 * i + c] -= m * out.direction[c];
                }
            }
        }
        Ok(())
    }

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
