//! Quadratic bending (Bergou et al. 2006; lecture P34): for each hinge, with the hinge edge `x1–x2` and the
//! wings `x0` (upper triangle) and `x3` (lower triangle) of the stencil,
//!
//! ```text
//! E = Σ_hinges 3 / (2 (A0 + A1)) · |Σ_i q_i x_i|²,
//! q = (−cot β1 − cot β2, cot β2 + cot γ2, cot β1 + cot γ1, −cot γ1 − cot γ2)   for (x0, x1, x2, x3),
//! ```
//! where `β1, β2` are the rest angles at `x1, x2` in the upper triangle and `γ1, γ2` those in the lower one,
//! and `A0, A1` the rest areas. `Σ q_i x_i` vanishes for any flat configuration of the stencil, so the energy
//! is zero at a flat rest state and invariant to rigid motions; it is quadratic in the positions, so its
//! Hessian `Σ 3/(A0 + A1) q qᵀ ⊗ I` is constant and precomputed at rest. Meant for flat rest states.

use std::sync::Arc;

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy};
use hinge_core::hinge::BLOCK_PAIRS as PAIRS;
use hinge_core::nalgebra::{Matrix3, Vector3};
use hinge_core::pattern::SymmetricPattern;
use hinge_core::{EvalError, Topology, TriMesh};

/// Bergou's quadratic bending over every hinge.
#[derive(Debug, Clone)]
pub struct QuadraticBending {
    stencils: Vec<[usize; 4]>,
    /// Per hinge: q and the factor 3 k / (A0 + A1).
    weights: Vec<([f64; 4], f64)>,
    n_vertices: usize,
    /// Per hinge: the 10 block slots of (a, b), a ≥ b in stencil order, with the Hessian value `c q_a q_b`.
    blocks: Vec<[(usize, f64); 10]>,
}

fn cot(apex: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let (u, v) = (a - apex, b - apex);
    u.dot(&v) / u.cross(&v).norm()
}

impl QuadraticBending {
    /// Quadratic bending of stiffness `k` with rest state `rest`.
    ///
    /// # Errors
    /// [`EvalError::Mesh`] for an invalid mesh, [`EvalError::Element`] for a non-finite or negative `k`.
    pub fn new(rest: &TriMesh, k: f64) -> Result<Self, EvalError> {
        if !(k >= 0.0 && k.is_finite()) {
            return Err(EvalError::Element {
                element: "quadratic bending".into(),
                message: format!("stiffness {k} must be finite and non-negative"),
            });
        }
        let topo = Topology::new(rest.n_vertices(), rest.triangles())?;
        let x = rest.positions();
        let mut stencils = Vec::new();
        let mut weights = Vec::new();
        for h in topo.hinges() {
            let [x0, x1, x2, x3] = h.vertices.map(|v| x[v]);
            let (b1, b2) = (cot(&x1, &x0, &x2), cot(&x2, &x0, &x1));
            let (g1, g2) = (cot(&x1, &x3, &x2), cot(&x2, &x3, &x1));
            let a0 = 0.5 * (x1 - x0).cross(&(x2 - x0)).norm();
            let a1 = 0.5 * (x1 - x3).cross(&(x2 - x3)).norm();
            let q = [-b1 - b2, b2 + g2, b1 + g1, -g1 - g2];
            stencils.push(h.vertices);
            weights.push((q, 3.0 * k / (a0 + a1)));
        }
        Ok(Self {
            stencils,
            weights,
            n_vertices: rest.n_vertices(),
            blocks: Vec::new(),
        })
    }

    /// Per hinge: the stencil, `q` and the factor `3k / (A0 + A1)`.
    pub fn weights(&self) -> impl Iterator<Item = ([usize; 4], [f64; 4], f64)> + '_ {
        self.stencils
            .iter()
            .zip(&self.weights)
            .map(|(s, (q, c))| (*s, *q, *c))
    }
}

impl Energy for QuadraticBending {
    fn name(&self) -> &str {
        "quadratic-bending"
    }

    fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    fn couplings(&self, out: &mut Vec<(usize, usize)>) {
        for s in &self.stencils {
            out.extend(
                PAIRS
                    .iter()
                    .filter(|(a, b)| a != b)
                    .map(|&(a, b)| (s[a], s[b])),
            );
        }
    }

    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError> {
        crate::util::same_size(pattern, self.n_vertices)?;
        self.blocks = self
            .stencils
            .iter()
            .zip(&self.weights)
            .map(|(s, (q, c))| {
                let mut out = [(0usize, 0.0); 10];
                for (i, &(a, b)) in PAIRS.iter().enumerate() {
                    out[i] = (crate::util::slot(pattern, s[a], s[b])?, c * q[a] * q[b]);
                }
                Ok(out)
            })
            .collect::<Result<_, EvalError>>()?;
        Ok(())
    }

    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        hinge_core::mesh::check_same_vertex_count(self.n_vertices, x.len())?;
        let mut e = 0.0;
        for (h, (s, (q, c))) in self.stencils.iter().zip(&self.weights).enumerate() {
            let v: Vector3<f64> = (0..4).map(|i| x[s[i]] * q[i]).sum();
            e += 0.5 * c * v.norm_squared();
            if request.gradient {
                for i in 0..4 {
                    acc.add_gradient(s[i], &(v * (c * q[i])));
                }
            }
            if request.hessian && !self.blocks.is_empty() {
                for (i, &(a, b)) in PAIRS.iter().enumerate() {
                    let (slot, value) = self.blocks[h][i];
                    acc.add_block(slot, s[a], s[b], &(Matrix3::identity() * value));
                }
            }
        }
        Ok(if request.value { e } else { 0.0 })
    }
}
