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
//! - [`membrane::StvkMembrane`], the St. Venant–Kirchhoff triangle membrane, and
//!   [`corotational::CorotationalMembrane`], the lecture's co-rotational ("shape matching") membrane with
//!   its exact Hessian, and [`neohookean::NeoHookeanMembrane`], a compressible neo-Hookean membrane whose
//!   energy is infinite at zero area (soft shells that fold cannot crush a triangle);
//! - [`gravity::Gravity`] with lumped masses; [`drag::Drag`], mass-proportional damping (air drag);
//!   [`contact`]: smooth one-sided penalties against a sphere or a plane; [`pins::Pins`], the constrained
//!   vertices a solver eliminates.
//!
//! # Quick start
//!
//! ```
//! use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
//! use hinge_core::energy::{Energy, HingeTerm, System};
//! use hinge_core::grid::{grid, wave, Diagonal};
//! use hinge_core::nalgebra::Vector3;
//! use hinge_energies::bending::{stiffness_from_material, TanBending};
//! use hinge_energies::gravity::{lumped_masses, Gravity};
//! use hinge_energies::membrane::StvkMembrane;
//!
//! let rest = grid(10, 10, 1.0, 1.0, Diagonal::Alternating).unwrap();
//! let k = stiffness_from_material(2e5, 5e-4, 0.3); // Eq. 11
//! let terms: Vec<Box<dyn Energy>> = vec![
//!     Box::new(HingeTerm::new("bending", BendingModel::new(&rest, TanBending { k }).unwrap(),
//!                             Method::Refactored)),
//!     Box::new(StvkMembrane::new(&rest, 2e5, 0.3, 5e-4).unwrap()),
//!     Box::new(Gravity::new(lumped_masses(&rest, 0.1), Vector3::new(0.0, 0.0, -9.81)).unwrap()),
//! ];
//! let mut system = System::new(rest.n_vertices(), terms).unwrap();
//! let e = system.evaluate(&wave(rest.positions()), Request::ALL, Parallelism::Sequential).unwrap();
//! assert_eq!(e.terms.len(), 3);
//! assert_eq!(e.hessian.len(), system.pattern().nnz()); // one pattern: the union of the couplings
//! ```
#![cfg_attr(not(test), warn(clippy::unwrap_used, clippy::expect_used))]
#![deny(missing_docs)]

/// The four parameter methods of [`hinge_core::energy::Energy`] for a plane-stress membrane (a field
/// `material: util::PlaneStress`) whose energy is proportional to Young's modulus and to the thickness and
/// linear in the Lamé constants `(μ, λ)` jointly: `young` (Pa, ≥ 0), `poisson` (−1 < ν < 0.5) and
/// `thickness` (m, > 0). Derivatives from the energy evaluated with the parameter's own factor replaced:
/// `young` and `thickness` set to 1, and for `poisson` the Lamé constants set to their derivatives
/// `(∂μ/∂ν, ∂λ/∂ν)` ([`util::PlaneStress::poisson_derivatives`]), then put back bitwise.
macro_rules! plane_stress_parameters {
    () => {
        fn parameters(&self) -> Vec<hinge_core::energy::Parameter> {
            ["young", "poisson", "thickness"]
                .map(|n| hinge_core::energy::Parameter {
                    name: n.into(),
                    len: 1,
                })
                .to_vec()
        }

        fn parameter(&self, name: &str) -> Result<Vec<f64>, hinge_core::EvalError> {
            match name {
                "young" => Ok(vec![self.material.young]),
                "poisson" => Ok(vec![self.material.poisson]),
                "thickness" => Ok(vec![self.material.thickness]),
                _ => Err(hinge_core::energy::unknown_parameter(
                    name,
                    &self.parameters(),
                )),
            }
        }

        fn parameter_bounds(&self, name: &str) -> Option<(f64, f64)> {
            (name == "poisson").then_some(crate::util::POISSON_BOUNDS)
        }

        fn set_parameter(
            &mut self,
            name: &str,
            values: &[f64],
        ) -> Result<(), hinge_core::EvalError> {
            match name {
                "young" => self
                    .material
                    .set_young(crate::util::scalar_value(name, values, 0.0)?),
                "poisson" => self
                    .material
                    .set_poisson(crate::util::poisson_value(name, values)?),
                "thickness" => {
                    self.material.thickness =
                        crate::util::scalar_value(name, values, f64::MIN_POSITIVE)?;
                }
                _ => {
                    return Err(hinge_core::energy::unknown_parameter(
                        name,
                        &self.parameters(),
                    ));
                }
            }
            Ok(())
        }

        fn add_parameter_derivatives(
            &mut self,
            x: &[hinge_core::nalgebra::Vector3<f64>],
            name: &str,
            out: &mut hinge_core::energy::ParameterOutput,
        ) -> Result<(), hinge_core::EvalError> {
            let kept = self.material;
            match name {
                "young" => self.material.set_young(1.0),
                "poisson" => {
                    (self.material.mu, self.material.lambda) = kept.poisson_derivatives();
                }
                "thickness" => self.material.thickness = 1.0,
                _ => {
                    return Err(hinge_core::energy::unknown_parameter(
                        name,
                        &self.parameters(),
                    ));
                }
            }
            let r = crate::util::add_proportional_derivatives(self, x, name, out);
            self.material = kept;
            r
        }
    };
}

/// The four parameter methods of [`hinge_core::energy::Energy`] for an energy proportional to one
/// non-negative scalar field (`E(p) = p · E(1)`), exposed under `$name`: derivatives from the energy evaluated
/// with the field set to 1 ([`util::add_proportional_derivatives`]).
macro_rules! proportional_parameter {
    ($name:literal, $field:ident) => {
        fn parameters(&self) -> Vec<hinge_core::energy::Parameter> {
            vec![hinge_core::energy::Parameter {
                name: $name.into(),
                len: 1,
            }]
        }

        fn parameter(&self, name: &str) -> Result<Vec<f64>, hinge_core::EvalError> {
            if name == $name {
                Ok(vec![self.$field])
            } else {
                Err(hinge_core::energy::unknown_parameter(
                    name,
                    &self.parameters(),
                ))
            }
        }

        fn set_parameter(
            &mut self,
            name: &str,
            values: &[f64],
        ) -> Result<(), hinge_core::EvalError> {
            if name != $name {
                return Err(hinge_core::energy::unknown_parameter(
                    name,
                    &self.parameters(),
                ));
            }
            self.$field = crate::util::scalar_value(name, values, 0.0)?;
            Ok(())
        }

        fn add_parameter_derivatives(
            &mut self,
            x: &[hinge_core::nalgebra::Vector3<f64>],
            name: &str,
            out: &mut hinge_core::energy::ParameterOutput,
        ) -> Result<(), hinge_core::EvalError> {
            if name != $name {
                return Err(hinge_core::energy::unknown_parameter(
                    name,
                    &self.parameters(),
                ));
            }
            let kept = std::mem::replace(&mut self.$field, 1.0);
            let r = crate::util::add_proportional_derivatives(self, x, name, out);
            self.$field = kept;
            r
        }
    };
}

/// The three mesh methods of [`hinge_core::energy::Energy`] for a per-triangle energy that keeps its
/// triangles in a field `triangles: util::Triangles`: `n_vertices`, `couplings` (the triangles' edges) and
/// `bind` (each triangle's pattern slots).
macro_rules! triangle_mesh_methods {
    () => {
        fn n_vertices(&self) -> usize {
            self.triangles.n_vertices
        }

        fn couplings(&self, out: &mut Vec<(usize, usize)>) {
            crate::util::triangle_couplings(&self.triangles.corners, out);
        }

        fn bind(
            &mut self,
            pattern: &std::sync::Arc<hinge_core::pattern::SymmetricPattern>,
        ) -> Result<(), hinge_core::EvalError> {
            let t = &mut self.triangles;
            t.slots = crate::util::triangle_slots(pattern, t.n_vertices, &t.corners)?;
            Ok(())
        }
    };
}

pub mod bending;
pub mod contact;
pub mod corotational;
pub mod drag;
pub mod gravity;
pub mod membrane;
pub mod motion;
pub mod neohookean;
pub mod pins;
pub mod quadratic;
pub mod spring;

pub(crate) mod util {
    use hinge_core::bending::{Parallelism, Request};
    use hinge_core::energy::{Energy, ParameterOutput, check_parameter_output};
    use hinge_core::nalgebra::Vector3;

    /// The one value of scalar parameter `name`, finite and at least `min`.
    pub fn scalar_value(name: &str, values: &[f64], min: f64) -> Result<f64, EvalError> {
        match values {
            [v] if v.is_finite() && *v >= min => Ok(*v),
            [v] => Err(EvalError::Parameter {
                name: name.to_string(),
                message: format!(
                    "must be finite and at least {}, got {}",
                    hinge_core::error::Num(min),
                    hinge_core::error::Num(*v)
                ),
            }),
            _ => Err(EvalError::Parameter {
                name: name.to_string(),
                message: format!("is one value, {} given", values.len()),
            }),
        }
    }

    pub use crate::membrane::POISSON_BOUNDS;

    /// The one value of the Poisson ratio parameter `name`: finite and in [`POISSON_BOUNDS`] (−1, 0.5),
    /// where the plane-stress Lamé constants are finite and the material is stable.
    pub fn poisson_value(name: &str, values: &[f64]) -> Result<f64, EvalError> {
        let (lower, upper) = POISSON_BOUNDS;
        match values {
            [v] if *v > lower && *v < upper => Ok(*v),
            [v] => Err(EvalError::Parameter {
                name: name.to_string(),
                message: format!(
                    "must be finite and in ({lower}, {upper}), got {}",
                    hinge_core::error::Num(*v)
                ),
            }),
            _ => Err(EvalError::Parameter {
                name: name.to_string(),
                message: format!("is one value, {} given", values.len()),
            }),
        }
    }

    /// Derivatives with respect to a scalar parameter the energy is proportional to (`E(p) = p · E(1)`, so
    /// `∂E/∂p = E(1)` and `∂∇E/∂p = ∇E(1)`): `unit` is the energy with that parameter set to 1 (a gradient
    /// evaluation of it, no Hessian).
    pub fn add_proportional_derivatives(
        unit: &mut dyn Energy,
        x: &[Vector3<f64>],
        name: &str,
        out: &mut ParameterOutput,
    ) -> Result<(), EvalError> {
        let n = unit.n_vertices();
        hinge_core::mesh::check_same_vertex_count(n, x.len())?;
        check_parameter_output(name, 1, n, out)?;
        let pattern = SymmetricPattern::new(n, Vec::new())?;
        let mut g = vec![0.0; 3 * n];
        let mut acc = Accumulator {
            pattern: &pattern,
            gradient: &mut g,
            hessian: &mut [],
        };
        let e = unit.add_to(x, Request::GRADIENT, Parallelism::Sequential, &mut acc)?;
        if !out.energy.is_empty() {
            out.energy[0] += e;
        }
        if !out.lambda.is_empty() {
            out.contracted[0] += g.iter().zip(out.lambda).map(|(a, b)| a * b).sum::<f64>();
        }
        if !out.direction.is_empty() {
            let d = out.direction[0];
            for (o, v) in out.gradient.iter_mut().zip(&g) {
                *o += d * v;
            }
        }
        Ok(())
    }

    use hinge_core::energy::Accumulator;
    use hinge_core::nalgebra::{Matrix2, Matrix3, Matrix3x2, Vector2};
    use hinge_core::pattern::SymmetricPattern;
    use hinge_core::{EvalError, TriMesh};

    /// The pattern block of `(a, b)`, or a typed error naming the pair.
    pub fn slot(pattern: &SymmetricPattern, a: usize, b: usize) -> Result<usize, EvalError> {
        pattern.find(a, b).ok_or_else(|| EvalError::Pattern {
            message: format!("pattern lacks the coupling of vertices {a} and {b}"),
        })
    }

    /// The diagonal block slots of all `n` vertices, after checking the pattern's size.
    pub fn diagonal_slots(pattern: &SymmetricPattern, n: usize) -> Result<Vec<usize>, EvalError> {
        same_size(pattern, n)?;
        (0..n).map(|v| slot(pattern, v, v)).collect()
    }

    /// Lumped masses must be finite and non-negative: a typed error naming the first bad vertex.
    pub fn check_masses(masses: &[f64]) -> Result<(), EvalError> {
        match masses
            .iter()
            .enumerate()
            .find(|(_, m)| !(**m >= 0.0 && m.is_finite()))
        {
            Some((i, m)) => Err(EvalError::AtElement {
                energy: "masses".into(),
                element: hinge_core::ElementRef::Vertex(i),
                message: format!("mass {m} must be finite and non-negative"),
            }),
            None => Ok(()),
        }
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

    /// A triangle's `b_v` (see [`triangle_rest_shapes`]) and rest area.
    pub type RestShape = ([Vector2<f64>; 3], f64);

    /// Per triangle of `rest`: `b_v = Dm⁻ᵀ g_v` for its corners (`g_0 = (−1, −1)`, `g_1 = (1, 0)`,
    /// `g_2 = (0, 1)`, `Dm` the edges from corner 0 in a 2D frame of the triangle's plane), so that
    /// `F = Σ_v x_v b_vᵀ`, and its rest area. A triangle without area is an error naming it.
    pub fn triangle_rest_shapes(rest: &TriMesh, energy: &str) -> Result<Vec<RestShape>, EvalError> {
        let x = rest.positions();
        rest.triangles()
            .iter()
            .enumerate()
            .map(|(ti, t)| {
                let (e1, e2) = (x[t[1]] - x[t[0]], x[t[2]] - x[t[0]]);
                let n = e1.cross(&e2);
                let area = 0.5 * n.norm();
                let t1 = e1.normalize();
                let t2 = n.normalize().cross(&t1);
                let dm = Matrix2::new(e1.dot(&t1), e2.dot(&t1), 0.0, e2.dot(&t2));
                let dm_inv_t = dm
                    .try_inverse()
                    .map(|m| m.transpose())
                    .filter(|m| area > 0.0 && m.iter().all(|v| v.is_finite()))
                    .ok_or_else(|| EvalError::AtElement {
                        energy: energy.to_string(),
                        element: hinge_core::ElementRef::Triangle {
                            triangle: ti,
                            vertices: *t,
                        },
                        message: "the rest triangle has no area".into(),
                    })?;
                let b = [
                    Vector2::new(-1.0, -1.0),
                    Vector2::new(1.0, 0.0),
                    Vector2::new(0.0, 1.0),
                ]
                .map(|g| dm_inv_t * g);
                Ok((b, area))
            })
            .collect()
    }

    /// The plane-stress Lamé constants `(μ, λ) = (Y/(2(1 + ν)), Yν/(1 − ν²))` of the triangle membranes.
    pub fn plane_stress_lame(young: f64, poisson: f64) -> (f64, f64) {
        (
            young / (2.0 * (1.0 + poisson)),
            young * poisson / (1.0 - poisson * poisson),
        )
    }

    /// A plane-stress membrane material: Young's modulus, Poisson ratio, thickness and the Lamé constants
    /// [`plane_stress_lame`] derives from the first two.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct PlaneStress {
        pub young: f64,
        pub poisson: f64,
        pub thickness: f64,
        pub mu: f64,
        pub lambda: f64,
    }

    impl PlaneStress {
        /// The material after [`check_material`] (errors name `energy`).
        pub fn new(
            energy: &str,
            young: f64,
            poisson: f64,
            thickness: f64,
        ) -> Result<Self, EvalError> {
            check_material(energy, young, poisson, thickness)?;
            let (mu, lambda) = plane_stress_lame(young, poisson);
            Ok(Self {
                young,
                poisson,
                thickness,
                mu,
                lambda,
            })
        }

        /// Sets Young's modulus and recomputes the Lamé constants.
        pub fn set_young(&mut self, young: f64) {
            self.young = young;
            (self.mu, self.lambda) = plane_stress_lame(young, self.poisson);
        }

        /// Sets the Poisson ratio and recomputes the Lamé constants.
        pub fn set_poisson(&mut self, poisson: f64) {
            self.poisson = poisson;
            (self.mu, self.lambda) = plane_stress_lame(self.young, poisson);
        }

        /// `(∂μ/∂ν, ∂λ/∂ν) = (−Y / (2 (1 + ν)²), Y (1 + ν²) / (1 − ν²)²)`, the derivatives of
        /// [`plane_stress_lame`] in the Poisson ratio.
        pub fn poisson_derivatives(&self) -> (f64, f64) {
            let (y, nu) = (self.young, self.poisson);
            let one_minus_sq = 1.0 - nu * nu;
            (
                -y / (2.0 * (1.0 + nu) * (1.0 + nu)),
                y * (1.0 + nu * nu) / (one_minus_sq * one_minus_sq),
            )
        }
    }

    /// The triangles a membrane runs over: their corners, rest shapes ([`triangle_rest_shapes`]) and, once
    /// bound, their pattern slots ([`triangle_slots`]; empty before).
    #[derive(Debug, Clone)]
    pub struct Triangles {
        pub corners: Vec<[usize; 3]>,
        pub rest: Vec<RestShape>,
        pub n_vertices: usize,
        pub slots: Vec<[usize; 6]>,
    }

    impl Triangles {
        /// The triangles of `rest`; a rest triangle without area is an error naming it and `energy`.
        pub fn new(rest: &TriMesh, energy: &str) -> Result<Self, EvalError> {
            Ok(Self {
                rest: triangle_rest_shapes(rest, energy)?,
                corners: rest.triangles().to_vec(),
                n_vertices: rest.n_vertices(),
                slots: Vec::new(),
            })
        }
    }

    /// A triangle's deformation gradient `F = Ds Dm⁻¹ = Σ_v x_v b_vᵀ` (3×2) from its corners `t` and rest
    /// shape `b` ([`triangle_rest_shapes`]; the `b_v` sum to zero, so translations drop out).
    pub fn deformation_gradient(
        x: &[Vector3<f64>],
        t: &[usize; 3],
        b: &[Vector2<f64>; 3],
    ) -> Matrix3x2<f64> {
        x[t[0]] * b[0].transpose() + x[t[1]] * b[1].transpose() + x[t[2]] * b[2].transpose()
    }

    /// Young's modulus `Y ≥ 0`, Poisson ratio `−1 < ν < 0.5` and thickness `h > 0`, all finite.
    pub fn check_material(
        energy: &str,
        young: f64,
        poisson: f64,
        thickness: f64,
    ) -> Result<(), EvalError> {
        if young >= 0.0
            && young.is_finite()
            && poisson > POISSON_BOUNDS.0
            && poisson < POISSON_BOUNDS.1
            && thickness > 0.0
            && thickness.is_finite()
        {
            Ok(())
        } else {
            Err(EvalError::Element {
                element: energy.into(),
                message: format!(
                    "Young's modulus {young}, Poisson ratio {poisson}, thickness {thickness} out of range"
                ),
            })
        }
    }

    /// The vertex pairs of the triangles' edges.
    pub fn triangle_couplings(triangles: &[[usize; 3]], out: &mut Vec<(usize, usize)>) {
        for t in triangles {
            out.extend([(t[0], t[1]), (t[1], t[2]), (t[2], t[0])]);
        }
    }

    /// Adds a triangle's Hessian blocks `block(v, w)` (corners v, w) at its `slots` (see
    /// [`triangle_slots`]).
    pub fn add_triangle_blocks(
        acc: &mut Accumulator,
        slots: &[usize; 6],
        t: &[usize; 3],
        block: impl Fn(usize, usize) -> Matrix3<f64>,
    ) {
        for v in 0..3 {
            acc.add_block(slots[v], t[v], t[v], &block(v, v));
            let v1 = (v + 1) % 3;
            acc.add_block(slots[3 + v], t[v], t[v1], &block(v, v1));
        }
    }

    /// Per triangle, the slots of its blocks (0,0), (1,1), (2,2), (0,1), (1,2), (2,0), after checking the
    /// pattern's size.
    pub fn triangle_slots(
        pattern: &SymmetricPattern,
        n: usize,
        triangles: &[[usize; 3]],
    ) -> Result<Vec<[usize; 6]>, EvalError> {
        same_size(pattern, n)?;
        triangles
            .iter()
            .map(|t| {
                Ok([
                    slot(pattern, t[0], t[0])?,
                    slot(pattern, t[1], t[1])?,
                    slot(pattern, t[2], t[2])?,
                    slot(pattern, t[0], t[1])?,
                    slot(pattern, t[1], t[2])?,
                    slot(pattern, t[2], t[0])?,
                ])
            })
            .collect()
    }
}
