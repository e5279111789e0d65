//! Compressible neo-Hookean triangle membrane: a membrane whose energy grows without bound as a triangle's
//! area goes to zero, so a folding soft shell cannot crush a triangle flat.
//!
//! Per triangle with rest area `Ā` and `F = Ds Dm⁻¹ = Σ_v x_v b_vᵀ` (3×2, as in [`crate::membrane`]),
//! `C = FᵀF`, `I₁ = tr C`, `J = √det C` (the area ratio):
//!
//! ```text
//! W = ½ μ (I₁ − 2) − μ ln J + ½ λ (ln J)²,    energy = h Ā W,    S = 2 ∂W/∂C = μ (I − P) + λ ln J · P,
//! ```
//! with `P = C⁻¹` and the plane-stress Lamé constants of [`crate::membrane::StvkMembrane`]
//! (`μ = Y/(2(1 + ν))`, `λ = Yν/(1 − ν²)`): for small strains the two membranes agree to first order in
//! the strain. Unlike St. Venant–Kirchhoff, whose energy under compression peaks at a stretch of `1/√3` and
//! falls back to `μ/2 + λ/8` (per unit rest volume) at zero area, this energy goes to infinity as `J → 0`.
//!
//! **Gradient** `∇_v E = h Ā F S b_v`. **Hessian** (exact): with `c = μ − λ ln J`, `q_v = P b_v`,
//!
//! ```text
//! ∂²E/∂x_v∂x_w = h Ā [ (b_vᵀ S b_w) I + c (b_vᵀ P b_w) F P Fᵀ + c (F q_w)(F q_v)ᵀ + λ (F q_v)(F q_w)ᵀ ].
//! ```
//!
//! The first term is the geometric stiffness `tr(dFᵀ dF S)`, the rest the material part
//! `½ [c tr(dC P dC P) + ½ λ tr(P dC)²]` with `dC = dFᵀF + FᵀdF`: positive semi-definite when `c ≥ 0`.
//! A [`Request::definite`](hinge_core::bending::Request::definite) evaluation replaces `S` by its positive
//! part (eigenvalues clamped at zero) and `c` by `max(c, 0)`, which makes each triangle's 9×9 block
//! positive semi-definite and leaves it exact for triangles in tension with `λ ln J ≤ μ`.
//!
//! **Rounding.** The three terms of `W` are each of the order of the strain while `W` is of its square,
//! so the textbook form `½ μ (I₁ − 2) − μ ln J + …` carries an absolute rounding error of order `ε μ`: on a
//! stiff strip in bending (strains of 1e-6) that is a million times the StVK membrane's `ε μ |E|`, and it
//! stopped a static solve at ‖∇E‖ = 1.2e-7 N instead of 4e-10. Here every quantity comes from the Green
//! strain `E = ½(C − I)`: `det C = 1 + x` with `x = 2 tr E + 4 det E`, `ln J = ½ ln(1 + x)` (`ln_1p`),
//! `I₁ − 2 − 2 ln J = (x − ln(1 + x)) − 4 det E` (a power series for small `x`) and
//! `S = P (2μE + λ ln J · I)`, so the error is of order `ε μ |E|` as for StVK. For `|x| ≥ 0.5`, where
//! nothing cancels, the direct forms are used, with `det C = |f₁ × f₂|²` from the columns of `F`, which
//! stays accurate down to a crushed triangle (where `1 + x` and `c₀₀c₁₁ − c₀₁²` lose every digit).
//!
//! **Collapsed triangles.** Where `det C` is not positive (a triangle crushed onto a line or a point, or
//! with an area ratio so small that `det C` underflows) the energy is infinite: evaluation fails with
//! [`EvalError::AtElement`] naming the triangle, which Newton's line search treats as a rejected trial.

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy};
use hinge_core::nalgebra::{Matrix2, Matrix3, Vector3};
use hinge_core::{ElementRef, EvalError, TriMesh};

/// The compressible neo-Hookean membrane over every triangle of a mesh.
#[derive(Debug, Clone)]
pub struct NeoHookeanMembrane {
    material: crate::util::PlaneStress,
    triangles: crate::util::Triangles,
}

impl NeoHookeanMembrane {
    /// A membrane of Young's modulus `young`, Poisson ratio `poisson` and thickness `thickness` over `rest`.
    ///
    /// # Errors
    /// [`EvalError::Element`] for parameters out of range (`Y ≥ 0`, `−1 < ν < 0.5`, `h > 0`, all finite) or a
    /// rest triangle without area (named).
    pub fn new(
        rest: &TriMesh,
        young: f64,
        poisson: f64,
        thickness: f64,
    ) -> Result<Self, EvalError> {
        Ok(Self {
            material: crate::util::PlaneStress::new(
                "neo-hookean-membrane",
                young,
                poisson,
                thickness,
            )?,
            triangles: crate::util::Triangles::new(rest, "neo-hookean-membrane")?,
        })
    }

    /// Young's modulus (Pa).
    pub fn young(&self) -> f64 {
        self.material.young
    }

    /// The thickness (m).
    pub fn thickness(&self) -> f64 {
        self.material.thickness
    }
}

/// `x − ln(1 + x)` without the cancellation of the direct form for small `x` (a power series below
/// `|x| = 1e-2`, accurate to rounding; the direct form above, whose relative error there is below 2e-14).
fn x_minus_ln_1p(x: f64) -> f64 {
    if x.abs() < 1e-2 {
        // x²/2 − x³/3 + x⁴/4 − … − x¹¹/11 by Horner: the next term is below 1e-19 of the first.
        let mut sum = 0.0;
        for k in (2..=11).rev() {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            sum = sum * x + sign / k as f64;
        }
        sum * x * x
    } else {
        x - x.ln_1p()
    }
}

fn collapsed(ti: usize, t: &[usize; 3], det: f64) -> EvalError {
    EvalError::AtElement {
        energy: "neo-hookean-membrane".into(),
        element: ElementRef::Triangle {
            triangle: ti,
            vertices: *t,
        },
        message: format!(
            "the triangle is crushed (det FᵀF = {det:e}): the neo-Hookean energy is infinite there"
        ),
    }
}

impl Energy for NeoHookeanMembrane {
    // `young` (Pa, ≥ 0), `poisson` and `thickness` (m, > 0): the energy is proportional to Y and h and
    // linear in (μ, λ).
    plane_stress_parameters!();

    fn name(&self) -> &str {
        "neo-hookean-membrane"
    }

    triangle_mesh_methods!();

    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        let tri = &self.triangles;
        hinge_core::mesh::check_same_vertex_count(tri.n_vertices, x.len())?;
        let (mu, lambda) = (self.material.mu, self.material.lambda);
        let mut energy = 0.0;
        for (ti, t) in tri.corners.iter().enumerate() {
            let (b, area) = &tri.rest[ti];
            let w = self.material.thickness * area;
            let f = crate::util::deformation_gradient(x, t, b);
            let c = f.transpose() * f;
            // det C = |f₁ × f₂|² (the squared area ratio): accurate relative to itself down to a crushed
            // triangle, where c₀₀c₁₁ − c₀₁² cancels.
            let det = f.column(0).cross(&f.column(1)).norm_squared();
            // Negated so that NaN is caught too.
            if !(det > 0.0 && det.is_finite()) {
                return Err(collapsed(ti, t, det));
            }
            // Small strains from the Green strain E = ½(C − I) (module docs, Rounding): det C = 1 + x.
            let e = (c - Matrix2::identity()) * 0.5;
            let det_e = e.determinant();
            let x_det = 2.0 * e.trace() + 4.0 * det_e;
            // ln J and I₁ − 2 − 2 ln J = 2 tr E − ln(1 + x) = (x − ln(1 + x)) − 4 det E.
            let (log_j, i1_term) = if x_det.abs() < 0.5 {
                (0.5 * x_det.ln_1p(), x_minus_ln_1p(x_det) - 4.0 * det_e)
            } else {
                let log_j = 0.5 * det.ln();
                (log_j, c.trace() - 2.0 - 2.0 * log_j)
            };
            energy += w * (0.5 * mu * i1_term + 0.5 * lambda * log_j * log_j);
            if !(request.gradient || request.hessian) {
                continue;
            }
            let p = Matrix2::new(c[(1, 1)], -c[(0, 1)], -c[(1, 0)], c[(0, 0)]) / det;
            // S = μ(I − P) + λ ln J P = P (2μE + λ ln J I), since I − P = P (C − I).
            let s = p * (e * (2.0 * mu) + Matrix2::identity() * (lambda * log_j));
            if request.gradient {
                let fs = f * s;
                for v in 0..3 {
                    acc.add_gradient(t[v], &(fs * b[v] * w));
                }
            }
            if request.hessian && !tri.slots.is_empty() {
                let (s, cm) = if request.definite {
                    (
                        crate::membrane::positive_part(&s),
                        (mu - lambda * log_j).max(0.0),
                    )
                } else {
                    (s, mu - lambda * log_j)
                };
                let fpf = f * p * f.transpose();
                let q = [0, 1, 2].map(|v| p * b[v]);
                let fq: [Vector3<f64>; 3] = q.map(|qv| f * qv);
                let block = |v: usize, u: usize| -> Matrix3<f64> {
                    (Matrix3::identity() * b[v].dot(&(s * b[u]))
                        + fpf * (cm * b[v].dot(&q[u]))
                        + fq[u] * fq[v].transpose() * cm
                        + fq[v] * fq[u].transpose() * lambda)
                        * w
                };
                crate::util::add_triangle_blocks(acc, &tri.slots[ti], t, block);
            }
        }
        if !energy.is_finite() {
            return Err(EvalError::Element {
                element: "neo-hookean-membrane".into(),
                message: format!("the energy is not finite ({energy})"),
            });
        }
        Ok(if request.value { energy } else { 0.0 })
    }
}
