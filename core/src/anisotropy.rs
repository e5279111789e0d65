//! Anisotropic (warp/weft) bending: a per-hinge factor on any ψ from the angle between the hinge's rest
//! edge and a material direction.
//!
//! Woven textiles bend differently along their two thread directions. With φ the angle between a hinge's
//! rest edge and the warp direction (the material direction, measured in the hinge's tangent plane), every
//! hinge energy ψ is multiplied by
//!
//! ```text
//! s(φ) = (k_bend + k_warp sin²φ + k_weft cos²φ) / k_bend = 1 + warp·sin²φ + weft·cos²φ,
//! ```
//!
//! with `warp = k_warp / k_bend` and `weft = k_weft / k_bend` ([`Anisotropy`]), so `k_bend` stays the
//! material's own stiffness (the ψ's `k`). The law is that of the ppf contact solver's cloth model.
//!
//! **Which fold each term stiffens.** A fold bends the threads that cross its line and leaves those along it
//! straight. A hinge whose edge runs along the warp (φ = 0) is a fold line along the warp: it bends the weft
//! threads, and `weft` stiffens it (cos²φ = 1). A hinge across the warp (φ = 90°) bends the warp threads,
//! and `warp` stiffens it. A strip cut along the warp bends about lines across it: it is stiffened by
//! `warp` (and by `weft` on its diagonal hinges, by cos² of their angle).
//!
//! The material direction is a constant vector ([`MaterialDirection::Constant`], for flat sheets: it is
//! projected onto each hinge's tangent plane) or comes from texture coordinates
//! ([`MaterialDirection::Uv`]): the direction of increasing u, `∂x/∂u`, of each triangle's map from UV to
//! space (its UV Jacobian), averaged over the hinge's two triangles.
//!
//! [`Anisotropic`] applies the factors to any [`HingePsi`] — built-in, derived or run-time — as a
//! per-hinge parameter; with `warp = weft = 0` every factor is exactly 1 and the results are bitwise those
//! of the isotropic energy.

use nalgebra::{Matrix2, Vector3};
use num_dual::DualNum;
use thiserror::Error;

use crate::mesh::TriMesh;
use crate::psi::{HingePsi, HingeQuantities, PsiError};
use crate::topology::Topology;

/// Texture coordinates of one triangle's three corners (in the triangle's corner order).
pub type TriangleUv = [[f64; 2]; 3];

/// The warp and weft stiffness of [`s(φ)`](Anisotropy::factor), relative to the material's `k_bend`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Anisotropy {
    /// `k_warp / k_bend`: extra stiffness of folds across the warp (sin²φ).
    pub warp: f64,
    /// `k_weft / k_bend`: extra stiffness of folds along the warp (cos²φ).
    pub weft: f64,
}

/// Why anisotropy factors could not be computed.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum AnisotropyError {
    /// A ratio that is not finite or would make a factor non-positive.
    #[error(
        "`{name}` = {value}: must be finite and greater than -1 (the factor 1 + warp·sin²φ + weft·cos²φ must stay positive)"
    )]
    Ratio {
        /// `warp` or `weft`.
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// The constant direction is zero or not finite.
    #[error("material direction {direction:?} is zero or not finite")]
    Direction {
        /// The direction given.
        direction: [f64; 3],
    },
    /// The constant direction is normal to a hinge's surface: it has no tangent part there.
    #[error(
        "material direction is normal to the surface at hinge {hinge} (vertices {vertices:?}): it defines no direction in the surface there"
    )]
    NormalToSurface {
        /// Hinge index (hinge order).
        hinge: usize,
        /// Its stencil vertices x0..x3.
        vertices: [usize; 4],
    },
    /// The UV list does not have one entry per triangle.
    #[error("{given} triangles with texture coordinates for a mesh of {triangles} triangles")]
    UvCount {
        /// Entries given.
        given: usize,
        /// Triangles of the mesh.
        triangles: usize,
    },
    /// A triangle next to a hinge has no texture coordinates.
    #[error(
        "triangle {triangle} has no texture coordinates (the material direction is taken from UVs)"
    )]
    MissingUv {
        /// Triangle index (mesh order, from 0).
        triangle: usize,
    },
    /// A triangle's texture coordinates are collinear (or not finite): its UV Jacobian is singular.
    #[error(
        "triangle {triangle} has degenerate texture coordinates {uv:?} (zero UV area): no direction of increasing u"
    )]
    DegenerateUv {
        /// Triangle index (mesh order, from 0).
        triangle: usize,
        /// Its corners' UVs.
        uv: TriangleUv,
    },
    /// The mesh is invalid.
    #[error("{0}")]
    Mesh(#[from] crate::error::MeshError),
}

impl Anisotropy {
    /// Checks the ratios: finite and greater than −1 (so every factor is positive).
    ///
    /// # Errors
    /// [`AnisotropyError::Ratio`] naming the ratio.
    pub fn new(warp: f64, weft: f64) -> Result<Self, AnisotropyError> {
        for (name, value) in [("warp", warp), ("weft", weft)] {
            if !(value.is_finite() && value > -1.0) {
                return Err(AnisotropyError::Ratio { name, value });
            }
        }
        Ok(Self { warp, weft })
    }

    /// `s(φ) = 1 + warp·sin²φ + weft·cos²φ`.
    pub fn factor(&self, phi: f64) -> f64 {
        let (s, c) = phi.sin_cos();
        self.factor_from_cos2(c * c, s * s)
    }

    /// With `warp = weft = 0` this is exactly 1 (so the isotropic results are reproduced bitwise).
    fn factor_from_cos2(&self, cos2: f64, sin2: f64) -> f64 {
        1.0 + self.warp * sin2 + self.weft * cos2
    }

    /// The factor of every hinge of `rest` (hinge order) for `direction`.
    ///
    /// # Errors
    /// [`AnisotropyError`] naming the hinge or triangle.
    pub fn hinge_factors(
        &self,
        rest: &TriMesh,
        direction: &MaterialDirection<'_>,
    ) -> Result<Vec<f64>, AnisotropyError> {
        let angles = hinge_cos2(rest, direction)?;
        Ok(angles
            .into_iter()
            .map(|c2| self.factor_from_cos2(c2, 1.0 - c2))
            .collect())
    }
}

/// Where the warp direction comes from.
#[derive(Debug, Clone, Copy)]
pub enum MaterialDirection<'a> {
    /// One direction in space, projected onto each hinge's tangent plane (flat sheets).
    Constant(Vector3<f64>),
    /// Per-triangle texture coordinates (one entry per triangle, `None` where a triangle has none): the
    /// warp runs along increasing u.
    Uv(&'a [Option<TriangleUv>]),
}

/// The angle φ ∈ [0, π/2] between each hinge's rest edge and the material direction (hinge order).
///
/// # Errors
/// [`AnisotropyError`] naming the hinge or triangle.
pub fn hinge_material_angles(
    rest: &TriMesh,
    direction: &MaterialDirection<'_>,
) -> Result<Vec<f64>, AnisotropyError> {
    Ok(hinge_cos2(rest, direction)?
        .into_iter()
        .map(|c2| c2.clamp(0.0, 1.0).sqrt().acos())
        .collect())
}

/// The unit direction of increasing u on each triangle (`∂x/∂u` of the UV-to-space map, normalized).
///
/// # Errors
/// [`AnisotropyError::UvCount`], [`AnisotropyError::DegenerateUv`] (a triangle without UVs gets `None`).
pub fn uv_directions(
    rest: &TriMesh,
    uvs: &[Option<TriangleUv>],
) -> Result<Vec<Option<Vector3<f64>>>, AnisotropyError> {
    if uvs.len() != rest.n_triangles() {
        return Err(AnisotropyError::UvCount {
            given: uvs.len(),
            triangles: rest.n_triangles(),
        });
    }
    let x = rest.positions();
    rest.triangles()
        .iter()
        .zip(uvs)
        .enumerate()
        .map(|(t, (tri, uv))| {
            let Some(uv) = uv else { return Ok(None) };
            let degenerate = || AnisotropyError::DegenerateUv {
                triangle: t,
                uv: *uv,
            };
            // x(u, v) = x0 + J (uv − uv0), J = [e1 e2] · [Δuv1 Δuv2]⁻¹; ∂x/∂u is J's first column.
            let duv = Matrix2::new(
                uv[1][0] - uv[0][0],
                uv[2][0] - uv[0][0],
                uv[1][1] - uv[0][1],
                uv[2][1] - uv[0][1],
            );
            let scale = duv.abs().max();
            let det = duv.determinant();
            if !(scale.is_finite() && det.abs() > 1e-12 * scale * scale) {
                return Err(degenerate());
            }
            let inv = duv.try_inverse().ok_or_else(degenerate)?;
            let e1 = x[tri[1]] - x[tri[0]];
            let e2 = x[tri[2]] - x[tri[0]];
            let du = e1 * inv[(0, 0)] + e2 * inv[(1, 0)];
            let n = du.norm();
            if !(n > 0.0 && n.is_finite()) {
                return Err(degenerate());
            }
            Ok(Some(du / n))
        })
        .collect()
}

/// cos²φ per hinge.
fn hinge_cos2(
    rest: &TriMesh,
    direction: &MaterialDirection<'_>,
) -> Result<Vec<f64>, AnisotropyError> {
    let topology = Topology::new(rest.n_vertices(), rest.triangles())?;
    let x = rest.positions();
    enum Source {
        Constant(Vector3<f64>),
        PerTriangle(Vec<Option<Vector3<f64>>>),
    }
    let source = match direction {
        MaterialDirection::Constant(d) => {
            if !(d.iter().all(|c| c.is_finite()) && d.norm() > 0.0) {
                return Err(AnisotropyError::Direction {
                    direction: [d.x, d.y, d.z],
                });
            }
            Source::Constant(d.normalize())
        }
        MaterialDirection::Uv(uvs) => Source::PerTriangle(uv_directions(rest, uvs)?),
    };
    let unit_normal = |t: usize| {
        let [a, b, c] = rest.triangles()[t];
        (x[b] - x[a]).cross(&(x[c] - x[a])).normalize()
    };
    topology
        .hinges()
        .iter()
        .enumerate()
        .map(|(h, hinge)| {
            let [t0, t1] = hinge.triangles;
            let d = match &source {
                Source::PerTriangle(dirs) => {
                    let d0 = dirs[t0].ok_or(AnisotropyError::MissingUv { triangle: t0 })?;
                    let d1 = dirs[t1].ok_or(AnisotropyError::MissingUv { triangle: t1 })?;
                    // Two charts may run u in opposite senses across a seam: only the line matters.
                    if d0.dot(&d1) < 0.0 { d0 - d1 } else { d0 + d1 }
                }
                Source::Constant(d) => *d,
            };
            let n = (unit_normal(t0) + unit_normal(t1)).normalize();
            let tangent = d - n * d.dot(&n);
            let tn = tangent.norm();
            if !(tn > 1e-8 * d.norm()) {
                return Err(AnisotropyError::NormalToSurface {
                    hinge: h,
                    vertices: hinge.vertices,
                });
            }
            let e = (x[hinge.vertices[2]] - x[hinge.vertices[1]]).normalize();
            let c = e.dot(&tangent) / tn;
            Ok((c * c).min(1.0))
        })
        .collect()
}

/// Any hinge energy ψ with a per-hinge factor: `s_h ψ(θ)` on hinge h (with ψ′, ψ″ scaled alike). The
/// factors are in hinge order (see [`crate::topology`]); [`Anisotropy::hinge_factors`] gives the warp/weft
/// ones, but any positive per-hinge field works (graded stiffness).
#[derive(Debug, Clone, PartialEq)]
pub struct Anisotropic<P> {
    /// The energy being scaled.
    pub inner: P,
    /// One positive factor per hinge.
    pub factors: Vec<f64>,
}

impl<P> Anisotropic<P> {
    /// `inner` scaled hinge by hinge by `factors` (checked against the mesh when a model is built).
    pub fn new(inner: P, factors: Vec<f64>) -> Self {
        Self { inner, factors }
    }
}

impl<P: HingePsi> HingePsi for Anisotropic<P> {
    type Params = (P::Params, f64);
    const D2_IS_ZERO: bool = P::D2_IS_ZERO;
    const USES_STEP: bool = P::USES_STEP;

    fn second_derivative_vanishes(&self) -> bool {
        self.inner.second_derivative_vanishes()
    }

    fn uses_step_quantities(&self) -> bool {
        self.inner.uses_step_quantities()
    }

    fn validate(&self, n_hinges: usize) -> Result<(), PsiError> {
        self.inner.validate(n_hinges)?;
        if self.factors.len() != n_hinges {
            return Err(PsiError {
                name: "anisotropy".into(),
                message: format!(
                    "{} factors for a mesh of {n_hinges} hinges",
                    self.factors.len()
                ),
            });
        }
        if let Some((h, s)) = self
            .factors
            .iter()
            .enumerate()
            .find(|(_, s)| !(s.is_finite() && **s > 0.0))
        {
            return Err(PsiError {
                name: "anisotropy".into(),
                message: format!("factor {s} of hinge {h} is not positive and finite"),
            });
        }
        Ok(())
    }

    fn params(&self, q: &HingeQuantities) -> Self::Params {
        // `validate` has checked the length; a missing factor would show as NaN energies (a typed error).
        let s = self.factors.get(q.hinge).copied().unwrap_or(f64::NAN);
        (self.inner.params(q), s)
    }

    fn update_step(&self, q: &HingeQuantities, p: &mut Self::Params) {
        self.inner.update_step(q, &mut p.0);
    }

    #[inline]
    fn eval(&self, p: &Self::Params, theta: f64) -> [f64; 3] {
        let [a, b, c] = self.inner.eval(&p.0, theta);
        [p.1 * a, p.1 * b, p.1 * c]
    }

    #[inline]
    fn value(&self, p: &Self::Params, theta: f64) -> f64 {
        p.1 * self.inner.value(&p.0, theta)
    }

    #[inline]
    fn eval_d1(&self, p: &Self::Params, theta: f64) -> [f64; 2] {
        let [a, b] = self.inner.eval_d1(&p.0, theta);
        [p.1 * a, p.1 * b]
    }

    fn psi_dual<D: DualNum<Primitive = f64> + Copy>(&self, p: &Self::Params, theta: D) -> D {
        self.inner.psi_dual(&p.0, theta) * p.1
    }

    fn has_parameter_derivatives(&self) -> bool {
        self.inner.has_parameter_derivatives()
    }

    /// The inner energy's parameters (the factors are fixed by the mesh's directions, not fitted).
    fn parameters(&self) -> Vec<crate::psi::PsiParameter> {
        self.inner.parameters()
    }

    fn n_parameters(&self) -> usize {
        self.inner.n_parameters()
    }

    fn parameter_derivatives(&self, q: &HingeQuantities, theta: f64, out: &mut [[f64; 2]]) -> bool {
        if !self.inner.parameter_derivatives(q, theta, out) {
            return false;
        }
        let s = self.factors.get(q.hinge).copied().unwrap_or(f64::NAN);
        for d in out.iter_mut() {
            *d = [s * d[0], s * d[1]];
        }
        true
    }

    fn parameter_values(&self, index: usize) -> Option<Vec<f64>> {
        self.inner.parameter_values(index)
    }

    fn set_parameter_values(&mut self, index: usize, values: &[f64]) -> Result<(), PsiError> {
        self.inner.set_parameter_values(index, values)
    }
}
