//! The co-rotational ("shape matching") triangle membrane of the lecture (P39–P42), with its exact Hessian.
//!
//! Per triangle with rest area `Ā` and `F = Ds Dm⁻¹ = Σ_v x_v b_vᵀ` (3×2, as in [`crate::membrane`]):
//!
//! ```text
//! energy = ½ k Ā ‖F − R‖²,   R = F (FᵀF)^(-1/2)  (the rotation of the polar decomposition F = R S),
//! ```
//!
//! so `‖F − R‖² = (σ₁ − 1)² + (σ₂ − 1)²` with `σᵢ` the singular values of `F`: the energy penalises `S − I`
//! (stretch and compression) and nothing else. `k` is a stiffness per unit rest area (N/m); the
//! co-rotated linear material with `λ = 0` gives `k = 2μh = Y h / (1 + ν)` ([`CorotationalMembrane::from_material`]).
//!
//! **Gradient** (exact): `∂E/∂F = k Ā (F − R)`, so `∇_v E = k Ā (F − R) b_v`.
//!
//! **Hessian: exact, R is not held constant.** The lecture treats `R` as constant, which makes the energy
//! quadratic with the constant Hessian `k Ā (b_v·b_w) I` — a Newton model that is not the energy's. Here the
//! differential of `R` is kept. Write the deformed triangle's unit normal `n`, `F = U Σ Vᵀ` (U 3×2),
//! `Q = U [[0, −1], [1, 0]] Vᵀ`. An in-plane perturbation turns `R` by `dR = Q ⟨Q, dF⟩ / (σ₁ + σ₂)`; a
//! perturbation along the normal, `dF = n bᵀ`, leaves `S` unchanged to first order, so `dR = n bᵀ S⁻¹`.
//! Hence, with `q_v = Q b_v`,
//!
//! ```text
//! ∂²E/∂x_v∂x_w = k Ā [ (b_v·b_w) I − q_v q_wᵀ / (σ₁ + σ₂) − (b_vᵀ S⁻¹ b_w) n nᵀ ].
//! ```
//!
//! In `F`-space this Hessian has the eigenvectors `Q` (eigenvalue `1 − 2/(σ₁ + σ₂)`), `n v_iᵀ`
//! (`1 − 1/σᵢ`) and three with eigenvalue 1: it is indefinite under compression. A
//! [`Request::definite`](hinge_core::bending::Request::definite) evaluation clamps those eigenvalues at zero
//! (the exact projection of the per-triangle `F`-space Hessian, in closed form), which gives a positive
//! semi-definite 9×9 block per triangle and equals the exact Hessian for triangles in tension.
//!
//! **Degenerate triangles.** `R` is undefined where the deformed triangle has no normal (collapsed onto a
//! line or a point; numerically, edges whose angle has a sine below [`DEGENERATE_SIN`]): evaluation then fails with [`EvalError::Element`] naming the triangle (index and
//! vertices in the caller's numbering).

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy};
use hinge_core::nalgebra::{Matrix2, Matrix3, Matrix3x2, Vector3};
use hinge_core::{ElementRef, EvalError, TriMesh};

/// The co-rotational membrane over every triangle of a mesh.
#[derive(Debug, Clone)]
pub struct CorotationalMembrane {
    stiffness: f64,
    triangles: crate::util::Triangles,
}

/// The polar decomposition of one triangle's `F` and what the derivatives need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Polar {
    /// The rotation of `F = R S` (3×2, orthonormal columns).
    pub r: Matrix3x2<f64>,
    /// The symmetric stretch `S` (2×2, positive definite).
    pub s: Matrix2<f64>,
    /// The deformed triangle's unit normal (`f₁ × f₂` direction, `f_k` the columns of `F`).
    pub normal: Vector3<f64>,
    /// `Q = R [[0, −1], [1, 0]]`: the in-plane rotation direction (‖Q‖² = 2).
    pub q: Matrix3x2<f64>,
    /// `σ₁ + σ₂ = tr S`.
    pub trace: f64,
}

/// Columns of `F` whose angle has a sine at most this are taken as parallel (a collapsed triangle).
pub const DEGENERATE_SIN: f64 = 1e-12;

/// The polar decomposition `F = R S` of a 3×2 deformation gradient, in closed form: `F` is written in an
/// orthonormal frame of its own column plane (`F₂`, 2×2 with positive determinant), whose rotation has the
/// angle `atan2(F₂[1,0] − F₂[0,1], F₂[0,0] + F₂[1,1])`. `None` when the columns are zero, parallel (the sine
/// of their angle at most [`DEGENERATE_SIN`]: no normal) or not finite.
pub fn polar(f: &Matrix3x2<f64>) -> Option<Polar> {
    let (f1, f2) = (f.column(0).into_owned(), f.column(1).into_owned());
    let cross = f1.cross(&f2);
    let (len1, len_n) = (f1.norm(), cross.norm());
    // Columns parallel to rounding (sin of their angle ≤ 1e-12): the normal would be noise.
    if !(len1 > 0.0 && len_n > DEGENERATE_SIN * len1 * f2.norm() && len_n.is_finite()) {
        return None;
    }
    let n = cross / len_n;
    let t1 = f1 / len1;
    let t2 = n.cross(&t1);
    // F = T F₂ with T = [t1 t2]; F₂ is upper triangular with a positive diagonal.
    let (a, b, c, d) = (len1, t1.dot(&f2), 0.0, t2.dot(&f2));
    let (sum, diff) = (a + d, c - b);
    let trace = sum.hypot(diff);
    if !(trace > 0.0) {
        return None;
    }
    let (cos, sin) = (sum / trace, diff / trace);
    // R₂ = [[cos, −sin], [sin, cos]], R = T R₂, S = R₂ᵀ F₂.
    let r1 = t1 * cos + t2 * sin;
    let r2 = t2 * cos - t1 * sin;
    let r = Matrix3x2::from_columns(&[r1, r2]);
    let s01 = cos * b + sin * d;
    let s = Matrix2::new(cos * a + sin * c, s01, s01, -sin * b + cos * d);
    let q = Matrix3x2::from_columns(&[r2, -r1]);
    Some(Polar {
        r,
        s,
        normal: n,
        q,
        trace,
    })
}

impl CorotationalMembrane {
    /// A membrane of stiffness `stiffness` (k, per unit rest area, N/m) over `rest`.
    ///
    /// # Errors
    /// [`EvalError::Element`] for a negative or non-finite stiffness, or a rest triangle without area
    /// (named).
    pub fn new(rest: &TriMesh, stiffness: f64) -> Result<Self, EvalError> {
        if !(stiffness >= 0.0 && stiffness.is_finite()) {
            return Err(EvalError::Element {
                element: "corotational-membrane".into(),
                message: format!("stiffness {stiffness} must be finite and non-negative"),
            });
        }
        Ok(Self {
            stiffness,
            triangles: crate::util::Triangles::new(rest, "corotational-membrane")?,
        })
    }

    /// The stiffness of the co-rotated linear material with `λ = 0`: `k = 2μh = Y h / (1 + ν)`.
    ///
    /// # Errors
    /// As [`CorotationalMembrane::new`], and for `Y < 0`, `ν ∉ (−1, 0.5)` or `h ≤ 0`.
    pub fn from_material(
        rest: &TriMesh,
        young: f64,
        poisson: f64,
        thickness: f64,
    ) -> Result<Self, EvalError> {
        crate::util::check_material("corotational-membrane", young, poisson, thickness)?;
        Self::new(rest, young * thickness / (1.0 + poisson))
    }

    /// The stiffness k (N/m).
    pub fn stiffness(&self) -> f64 {
        self.stiffness
    }
}

fn degenerate(ti: usize, t: &[usize; 3], what: &str) -> EvalError {
    EvalError::AtElement {
        energy: "corotational-membrane".into(),
        element: ElementRef::Triangle {
            triangle: ti,
            vertices: *t,
        },
        message: format!("the triangle {what}: its rotation is undefined"),
    }
}

impl Energy for CorotationalMembrane {
    // `stiffness` (≥ 0): the energy is proportional to it.
    proportional_parameter!("stiffness", stiffness);

    fn name(&self) -> &str {
        "corotational-membrane"
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
        let mut energy = 0.0;
        for (ti, t) in tri.corners.iter().enumerate() {
            let (b, area) = &tri.rest[ti];
            let w = self.stiffness * area;
            let f = crate::util::deformation_gradient(x, t, b);
            let Some(p) = polar(&f) else {
                return Err(degenerate(ti, t, "is collapsed onto a line or a point"));
            };
            let diff = f - p.r;
            energy += 0.5 * w * diff.norm_squared();
            if request.gradient {
                for v in 0..3 {
                    acc.add_gradient(t[v], &(diff * b[v] * w));
                }
            }
            if !request.hessian || tri.slots.is_empty() {
                continue;
            }
            // The in-plane coefficient c_q (of q_v q_wᵀ) and the normal 2×2 form N (b_vᵀ N b_w of n nᵀ).
            let (c_q, normal_form) = if request.definite {
                // Eigenvalues 1 − 2/tr and 1 − 1/σᵢ clamped at zero: subtract min(…, 1) instead.
                let e = p.s.symmetric_eigen();
                let mut nf = Matrix2::zeros();
                for i in 0..2 {
                    let vi = e.eigenvectors.column(i).into_owned();
                    nf += vi * vi.transpose() * (1.0 / e.eigenvalues[i]).min(1.0);
                }
                (0.5 * (2.0 / p.trace).min(1.0), nf)
            } else {
                let det = p.s.determinant();
                let inv = Matrix2::new(p.s[(1, 1)], -p.s[(0, 1)], -p.s[(1, 0)], p.s[(0, 0)]) / det;
                (1.0 / p.trace, inv)
            };
            if !(normal_form.iter().all(|v| v.is_finite()) && c_q.is_finite()) {
                return Err(degenerate(ti, t, "is collapsed onto a line"));
            }
            let q: [Vector3<f64>; 3] = [0, 1, 2].map(|v| p.q * b[v]);
            let nn = p.normal * p.normal.transpose();
            let block = |v: usize, u: usize| -> Matrix3<f64> {
                (Matrix3::identity() * b[v].dot(&b[u])
                    - q[v] * q[u].transpose() * c_q
                    - nn * b[v].dot(&(normal_form * b[u])))
                    * w
            };
            crate::util::add_triangle_blocks(acc, &tri.slots[ti], t, block);
        }
        Ok(if request.value { energy } else { 0.0 })
    }
}

#[cfg(test)]
mod tests {
    use super::polar;
    use hinge_core::nalgebra::{Matrix2, Matrix3x2};

    #[test]
    fn polar_decomposition_recomposes_and_is_orthonormal() {
        for f in [
            Matrix3x2::new(1.0, 0.0, 0.0, 1.0, 0.0, 0.0),
            Matrix3x2::new(0.3, -1.2, 0.8, 0.1, -0.4, 0.7),
            Matrix3x2::new(-2.0, 0.1, 0.05, -0.3, 1.0, 1e-3),
            Matrix3x2::new(1e-6, 2e-6, -3e-6, 1e-6, 5e-7, 4e-6),
        ] {
            let p = polar(&f).unwrap();
            let scale = f.norm();
            assert!((p.r * p.s - f).norm() <= 1e-14 * scale, "{f}");
            assert!((p.r.transpose() * p.r - Matrix2::identity()).norm() <= 1e-14);
            assert!((p.s - p.s.transpose()).norm() <= 1e-15 * scale);
            // S positive definite, tr S = σ₁ + σ₂ (from the SVD).
            let sv = f.svd(false, false).singular_values;
            assert!((p.trace - (sv[0] + sv[1])).abs() <= 1e-14 * scale);
            assert!(p.s.symmetric_eigen().eigenvalues.min() > 0.0);
        }
        assert!(polar(&Matrix3x2::new(1.0, 2.0, 0.0, 0.0, 0.0, 0.0)).is_none());
        assert!(polar(&Matrix3x2::zeros()).is_none());
    }
}
