//! Mass-proportional (Rayleigh) damping, "air drag", for implicit Euler: over a step of length Δt from
//! positions `x̂` (the end of the previous step),
//!
//! `E(x) = Σ_i (c m_i / (2Δt)) ‖x_i − x̂_i‖²`,
//!
//! whose force `−c m_i (x_i − x̂_i)/Δt = −c m_i v_i` damps every motion at rate `c` (1/s), rigid swinging
//! included, which bending damping cannot reach. Gradient `c m_i (x_i − x̂_i)/Δt`, Hessian `c m_i/Δt · I` on
//! the diagonal blocks only (no coupling). [`Energy::begin_step`] sets `x̂` and Δt; before the first step the
//! energy is zero (no step known yet).

use std::sync::Arc;

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy};
use hinge_core::nalgebra::{Matrix3, Vector3};
use hinge_core::pattern::SymmetricPattern;
use hinge_core::{EvalError, mesh};

/// Mass-proportional damping at rate `c` (1/s) on lumped masses.
#[derive(Debug, Clone)]
pub struct Drag {
    masses: Vec<f64>,
    rate: f64,
    /// `(x̂, Δt)` of the current step.
    step: Option<(Vec<Vector3<f64>>, f64)>,
    diag: Vec<usize>,
}

impl Drag {
    /// Damping at `rate` (1/s) on vertices of masses `masses`.
    ///
    /// # Errors
    /// [`EvalError::Element`] naming a negative or non-finite mass or rate.
    pub fn new(masses: Vec<f64>, rate: f64) -> Result<Self, EvalError> {
        crate::util::check_masses(&masses)?;
        if !(rate >= 0.0 && rate.is_finite()) {
            return Err(EvalError::Element {
                element: "drag".into(),
                message: format!("rate {rate} must be finite and non-negative"),
            });
        }
        Ok(Self {
            masses,
            rate,
            step: None,
            diag: Vec::new(),
        })
    }

    /// The damping rate `c` (1/s).
    pub fn rate(&self) -> f64 {
        self.rate
    }
}

impl Energy for Drag {
    fn name(&self) -> &str {
        "drag"
    }

    fn n_vertices(&self) -> usize {
        self.masses.len()
    }

    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}

    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError> {
        self.diag = crate::util::diagonal_slots(pattern, self.masses.len())?;
        Ok(())
    }

    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        mesh::check_same_vertex_count(self.masses.len(), x.len())?;
        let Some((x_hat, dt)) = &self.step else {
            return Ok(0.0);
        };
        let mut e = 0.0;
        for (i, ((&m, p), q)) in self.masses.iter().zip(x).zip(x_hat).enumerate() {
            let w = self.rate * m / dt;
            let d = p - q;
            e += 0.5 * w * d.norm_squared();
            if request.gradient {
                acc.add_gradient(i, &(d * w));
            }
            if request.hessian && !self.diag.is_empty() {
                acc.add_block(self.diag[i], i, i, &(Matrix3::identity() * w));
            }
        }
        Ok(if request.value { e } else { 0.0 })
    }

    fn begin_step(&mut self, x_prev: &[Vector3<f64>], dt: f64) -> Result<(), EvalError> {
        mesh::check_same_vertex_count(self.masses.len(), x_prev.len())?;
        mesh::validate_positions(x_prev)?;
        if !(dt > 0.0 && dt.is_finite()) {
            return Err(EvalError::Step { dt });
        }
        self.step = Some((x_prev.to_vec(), dt));
        Ok(())
    }
}
