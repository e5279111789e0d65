//! St. Venant–Kirchhoff triangle membrane (plane stress).
//!
//! Per triangle with rest vertices `X0, X1, X2`, a 2D rest frame gives `Dm = [X1 − X0, X2 − X0]` (2×2);
//! deformed `Ds = [x1 − x0, x2 − x0]` (3×2), `F = Ds Dm⁻¹` (3×2), Green strain `E = ½(FᵀF − I)` and
//!
//! ```text
//! W = μ tr(E²) + ½ λ tr(E)²,    energy = h Ā W,    S = 2μE + λ tr(E) I,
//! ```
//! with `μ = Y/(2(1 + ν))`, `λ = Yν/(1 − ν²)` (plane stress), thickness `h` and rest area `Ā`. With
//! `b_v = Dm⁻ᵀ g_v`, `g_0 = (−1, −1)`, `g_1 = (1, 0)`, `g_2 = (0, 1)`, and `f_k = Fᵀ e_k` (row `k` of F):
//!
//! ```text
//! ∇_v E = h Ā F S b_v
//! ∂²E/∂x_v,k ∂x_w,l = h Ā [ μ((f_k·f_l)(b_v·b_w) + (f_k·b_w)(f_l·b_v)) + λ (f_k·b_v)(f_l·b_w) + δ_kl b_vᵀ S b_w ]
//! ```
//! (the exact Hessian; indefinite under compression). The last term is the geometric stiffness; the rest is
//! `h Ā Jᵀ C J` with `J = ∂E/∂x` and the positive semi-definite plane-stress tensor `C`. A
//! [`Request::definite`](hinge_core::bending::Request::definite) evaluation replaces `S` in the geometric
//! stiffness by its positive part `S⁺` (eigenvalues of the 2×2 `S` clamped at zero, in closed form), which
//! makes each triangle's 9×9 Hessian positive semi-definite: cheap, not the nearest PSD matrix, and exact
//! for triangles in tension.

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy};
use hinge_core::nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use hinge_core::{EvalError, TriMesh};

/// The StVK membrane over every triangle of a mesh.
#[derive(Debug, Clone)]
pub struct StvkMembrane {
    material: crate::util::PlaneStress,
    triangles: crate::util::Triangles,
}

impl StvkMembrane {
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
            material: crate::util::PlaneStress::new("membrane", young, poisson, thickness)?,
            triangles: crate::util::Triangles::new(rest, "membrane")?,
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

impl Energy for StvkMembrane {
    // `young` (Pa, ≥ 0), `poisson` and `thickness` (m, > 0): the energy is proportional to Y and h and
    // linear in (μ, λ).
    plane_stress_parameters!();

    fn name(&self) -> &str {
        "membrane"
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
            let e = (f.transpose() * f - Matrix2::identity()) * 0.5;
            let tr = e.trace();
            energy += w * (mu * (e * e).trace() + 0.5 * lambda * tr * tr);
            if !(request.gradient || request.hessian) {
                continue;
            }
            let s = e * (2.0 * mu) + Matrix2::identity() * (lambda * tr);
            if request.gradient {
                let fs = f * s;
                for v in 0..3 {
                    acc.add_gradient(t[v], &(fs * b[v] * w));
                }
            }
            if request.hessian && !tri.slots.is_empty() {
                let rows: [Vector2<f64>; 3] = [0, 1, 2].map(|k| f.row(k).transpose());
                let s = if request.definite {
                    positive_part(&s)
                } else {
                    s
                };
                let block = |v: usize, wv: usize| {
                    let (bv, bw) = (b[v], b[wv]);
                    let sb = bv.dot(&(s * bw));
                    Matrix3::from_fn(|k, l| {
                        let (fk, fl) = (rows[k], rows[l]);
                        let mut h = mu * (fk.dot(&fl) * bv.dot(&bw) + fk.dot(&bw) * fl.dot(&bv))
                            + lambda * fk.dot(&bv) * fl.dot(&bw);
                        if k == l {
                            h += sb;
                        }
                        h * w
                    })
                };
                crate::util::add_triangle_blocks(acc, &tri.slots[ti], t, block);
            }
        }
        Ok(if request.value { energy } else { 0.0 })
    }
}

/// The positive part of a symmetric 2×2 matrix (eigenvalues clamped at zero), in closed form.
pub(crate) fn positive_part(s: &Matrix2<f64>) -> Matrix2<f64> {
    let (a, b, d) = (s[(0, 0)], 0.5 * (s[(0, 1)] + s[(1, 0)]), s[(1, 1)]);
    let mean = 0.5 * (a + d);
    let radius = (0.5 * (a - d)).hypot(b);
    let (l1, l2) = (mean + radius, mean - radius);
    if l2 >= 0.0 {
        return Matrix2::new(a, b, b, d);
    }
    if l1 <= 0.0 {
        return Matrix2::zeros();
    }
    // One positive eigenvalue l1 with unit eigenvector u: S⁺ = l1 u uᵀ, and (S − l2 I) = (l1 − l2) u uᵀ.
    let m = Matrix2::new(a - l2, b, b, d - l2);
    m * (l1 / (l1 - l2))
}

#[cfg(test)]
mod tests {
    use super::positive_part;
    use hinge_core::nalgebra::Matrix2;

    #[test]
    fn positive_part_matches_the_eigendecomposition() {
        for &(a, b, d) in &[
            (1.0, 0.3, -2.0),
            (-1.0, 0.0, -3.0),
            (2.0, 0.5, 1.0),
            (0.0, 1.0, 0.0),
            (-1e-3, 2e-3, 5e-4),
            (3.0, 0.0, -1.0),
        ] {
            let s = Matrix2::new(a, b, b, d);
            let e = s.symmetric_eigen();
            let q = e.eigenvectors;
            let want =
                q * Matrix2::from_diagonal(&e.eigenvalues.map(|l: f64| l.max(0.0))) * q.transpose();
            let got = positive_part(&s);
            assert!(
                (got - want).norm() <= 1e-14 * s.norm(),
                "{s} → {got} vs {want}"
            );
        }
    }
}

/// The open interval every membrane's Poisson ratio `ν` lies in, `(−1, 0.5)`: the plane-stress Lamé
/// constants are finite and the material is stable there. [`Energy::parameter_bounds`] of a membrane's
/// `poisson` parameter.
///
/// [`Energy::parameter_bounds`]: hinge_core::energy::Energy::parameter_bounds
pub const POISSON_BOUNDS: (f64, f64) = (-1.0, 0.5);

/// Which membrane model a scene or a binding asks for by name: the one place the names, the energies'
/// own names and their stiffness parameters are kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MembraneModel {
    /// [`StvkMembrane`], `"stvk"`.
    Stvk,
    /// [`CorotationalMembrane`](crate::corotational::CorotationalMembrane), `"corotational"`.
    Corotational,
    /// [`NeoHookeanMembrane`](crate::neohookean::NeoHookeanMembrane), `"neo-hookean"`.
    NeoHookean,
}

/// A membrane model's name that is not one of [`MembraneModel::NAMES`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown `{0}` (stvk, corotational, neo-hookean)")]
pub struct UnknownMembrane(pub String);

impl MembraneModel {
    /// Every model, in the order of [`MembraneModel::NAMES`].
    pub const ALL: [Self; 3] = [Self::Stvk, Self::Corotational, Self::NeoHookean];
    /// The models' names, as scene files and the Python package spell them.
    pub const NAMES: [&'static str; 3] = ["stvk", "corotational", "neo-hookean"];

    /// The model's name (`"stvk"`, `"corotational"`, `"neo-hookean"`).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Stvk => Self::NAMES[0],
            Self::Corotational => Self::NAMES[1],
            Self::NeoHookean => Self::NAMES[2],
        }
    }

    /// The name of the energy [`MembraneModel::build`] makes ([`Energy::name`]), which prefixes its
    /// parameters: `"membrane"`, `"corotational-membrane"`, `"neo-hookean-membrane"`.
    #[must_use]
    pub fn energy_name(self) -> &'static str {
        match self {
            Self::Stvk => "membrane",
            Self::Corotational => "corotational-membrane",
            Self::NeoHookean => "neo-hookean-membrane",
        }
    }

    /// The model whose [`MembraneModel::energy_name`] is `name`, if any.
    #[must_use]
    pub fn from_energy_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.energy_name() == name)
    }

    /// The parameter that scales the membrane's stiffness linearly: `membrane.young`,
    /// `corotational-membrane.stiffness` (`k = Y h / (1 + ν)`), `neo-hookean-membrane.young`.
    #[must_use]
    pub fn stiffness_parameter(self) -> &'static str {
        match self {
            Self::Stvk => "membrane.young",
            Self::Corotational => "corotational-membrane.stiffness",
            Self::NeoHookean => "neo-hookean-membrane.young",
        }
    }

    /// The membrane of this model over `rest`, from Young's modulus, Poisson ratio and thickness.
    ///
    /// # Errors
    /// The model's constructor's: [`EvalError::Element`] for material parameters out of range or a rest
    /// triangle without area (named).
    pub fn build(
        self,
        rest: &TriMesh,
        young: f64,
        poisson: f64,
        thickness: f64,
    ) -> Result<Box<dyn Energy>, EvalError> {
        Ok(match self {
            Self::Stvk => Box::new(StvkMembrane::new(rest, young, poisson, thickness)?),
            Self::Corotational => {
                Box::new(crate::corotational::CorotationalMembrane::from_material(
                    rest, young, poisson, thickness,
                )?)
            }
            Self::NeoHookean => Box::new(crate::neohookean::NeoHookeanMembrane::new(
                rest, young, poisson, thickness,
            )?),
        })
    }
}

impl std::str::FromStr for MembraneModel {
    type Err = UnknownMembrane;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| UnknownMembrane(s.to_string()))
    }
}

impl std::fmt::Display for MembraneModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod model_tests {
    use super::MembraneModel;
    use hinge_core::TriMesh;
    use hinge_core::nalgebra::Vector3;

    #[test]
    fn names_round_trip_and_build_the_energy_they_name() {
        let rest = TriMesh::new(
            vec![
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(1.0, 0.0, 0.0),
                Vector3::new(0.2, 0.9, 0.0),
            ],
            vec![[0, 1, 2]],
        )
        .unwrap();
        for (m, name) in MembraneModel::ALL.into_iter().zip(MembraneModel::NAMES) {
            assert_eq!(name.parse::<MembraneModel>(), Ok(m));
            assert_eq!(m.to_string(), name);
            let e = m.build(&rest, 1e6, 0.3, 1e-3).unwrap();
            assert_eq!(e.name(), m.energy_name());
            assert_eq!(MembraneModel::from_energy_name(e.name()), Some(m));
            let stiffness = format!("{}.{}", e.name(), e.parameters()[0].name);
            let names: Vec<String> = e
                .parameters()
                .iter()
                .map(|p| format!("{}.{}", e.name(), p.name))
                .collect();
            assert!(
                names.iter().any(|n| n == m.stiffness_parameter()),
                "{m}: {names:?} ({stiffness})"
            );
        }
        let err = "linear".parse::<MembraneModel>().unwrap_err();
        assert_eq!(
            err.to_string(),
            "unknown `linear` (stvk, corotational, neo-hookean)"
        );
        assert!(MembraneModel::Stvk.build(&rest, 1e6, 0.5, 1e-3).is_err());
    }
}
