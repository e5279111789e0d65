//! The ψ interface: a bending energy ψ(θ) per hinge, with per-hinge parameters from the rest state.
//!
//! The energy of a mesh is `E = Σ_hinges ψ_h(θ_h)`; by the chain rule (paper Eqs. 2–3)
//!
//! ```text
//! ∇ψ = ψ′ ∇θ,        Hess ψ = ψ′ Hess θ + ψ″ ∇θ ∇θᵀ.
//! ```
//!
//! A [`HingePsi`] provides ψ, ψ′, ψ″ of θ given per-hinge parameters it computes once from the rest state
//! ([`RestHinge`]: θ̄, `a = 3|ē|²/Ā`, rest length, rest area). Parameters may differ hinge by hinge (graded or
//! anisotropic stiffness). [`HingePsi::D2_IS_ZERO`] lets the kernels drop the ψ″ outer-product pass and its
//! x0–x3 couplings from the sparsity pattern. Several terms on the same hinges compose as a tuple `(A, B)`:
//! their ψ′ and ψ″ are summed per hinge, so the geometry is evaluated once (paper §5).
//!
//! [`HingePsi::psi_dual`] is ψ written once for any num-dual scalar: the `autodiff` method and the tests
//! differentiate it, so every hand-written ψ′ and ψ″ is checked against it.

use num_dual::DualNum;

pub mod runtime;

/// Rest-state quantities of one hinge, computed once at set-up.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RestHinge {
    /// Rest hinge angle θ̄ ∈ (−π, π].
    pub theta_bar: f64,
    /// `a = 3|ē|² / Ā`, with Ā the summed rest area of the two triangles.
    pub a: f64,
    /// Rest length `|ē|` of the hinge edge.
    pub rest_length: f64,
    /// Ā: the summed rest area of the two triangles.
    pub rest_area: f64,
}

/// Everything a ψ may depend on besides θ, for one hinge: its index, its rest quantities and the current
/// step's quantities (for damping).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HingeQuantities {
    /// Hinge index (for per-hinge parameters).
    pub hinge: usize,
    /// Rest hinge angle θ̄.
    pub theta_bar: f64,
    /// `a = 3|ē|²/Ā`.
    pub a: f64,
    /// Rest length of the hinge edge.
    pub rest_length: f64,
    /// Ā, the summed rest area of the two triangles.
    pub rest_area: f64,
    /// θ at the end of the previous time step (θ̄ until a step is set).
    pub theta_prev: f64,
    /// The time step (1 until a step is set).
    pub dt: f64,
}

impl HingeQuantities {
    /// The quantities of hinge `hinge` before any time step: `theta_prev = θ̄`, `dt = 1`.
    pub fn at_rest(hinge: usize, rest: &RestHinge) -> Self {
        Self {
            hinge,
            theta_bar: rest.theta_bar,
            a: rest.a,
            rest_length: rest.rest_length,
            rest_area: rest.rest_area,
            theta_prev: rest.theta_bar,
            dt: 1.0,
        }
    }
}

/// A ψ whose parameters do not fit the mesh.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("parameter `{name}`: {message}")]
pub struct PsiError {
    /// The parameter (struct field, or run-time parameter) name.
    pub name: std::borrow::Cow<'static, str>,
    /// What is wrong.
    pub message: String,
}

/// A parameter of ψ that derivatives can be taken with respect to (fitting, sensitivities): a struct field or
/// a run-time parameter, one value for every hinge or one per hinge.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PsiParameter {
    /// The field or run-time parameter name.
    pub name: String,
    /// Whether it holds one value per hinge (hinge order) rather than one for all.
    pub per_hinge: bool,
}

/// A hinge bending energy ψ(θ).
///
/// Implement it by hand, or declare it with `#[derive(HingeEnergy)]` (see the crate docs).
pub trait HingePsi: Sync {
    /// Per-hinge parameters, computed from [`HingeQuantities`] by [`HingePsi::params`].
    type Params: Copy + Send + Sync;

    /// True when ψ″ ≡ 0 for every θ (ψ affine in θ): the kernels then skip the outer-product pass and the
    /// pattern omits the x0–x3 couplings.
    const D2_IS_ZERO: bool = false;

    /// True when the parameters depend on the step quantities (`theta_prev`, `dt`): the model then calls
    /// [`HingePsi::update_step`] whenever a new step is set.
    const USES_STEP: bool = false;

    /// Whether ψ″ ≡ 0 for this energy (default [`HingePsi::D2_IS_ZERO`]). A run-time ψ knows it only once its
    /// expression is parsed, so the engine asks this method; it must not change after set-up.
    fn second_derivative_vanishes(&self) -> bool {
        Self::D2_IS_ZERO
    }

    /// Whether the parameters depend on the step quantities (default [`HingePsi::USES_STEP`]); the engine
    /// asks this method, for the same reason.
    fn uses_step_quantities(&self) -> bool {
        Self::USES_STEP
    }

    /// Checks the energy against a mesh with `n_hinges` hinges (per-hinge parameter lengths, finiteness).
    ///
    /// # Errors
    /// A [`PsiError`] naming the parameter.
    fn validate(&self, n_hinges: usize) -> Result<(), PsiError> {
        let _ = n_hinges;
        Ok(())
    }

    /// Parameters of one hinge.
    fn params(&self, q: &HingeQuantities) -> Self::Params;

    /// Refreshes the step-dependent part of `p` for a new step (default: recompute everything).
    fn update_step(&self, q: &HingeQuantities, p: &mut Self::Params) {
        *p = self.params(q);
    }

    /// `[ψ, ψ′, ψ″]` at θ. A value that cannot be represented (the tan energy at θ = ±π) is returned as
    /// non-finite; the engine reports it as a typed error naming the hinge.
    fn eval(&self, p: &Self::Params, theta: f64) -> [f64; 3];

    /// ψ alone at θ (default: from [`HingePsi::eval`]): what an energy-only evaluation calls. Must equal
    /// `eval(p, theta)[0]` bitwise (the derive generates a program of ψ's nodes alone).
    fn value(&self, p: &Self::Params, theta: f64) -> f64 {
        self.eval(p, theta)[0]
    }

    /// `[ψ, ψ′]` at θ (default: from [`HingePsi::eval`]): what a gradient-only evaluation calls. Must equal
    /// the first two entries of `eval` bitwise.
    fn eval_d1(&self, p: &Self::Params, theta: f64) -> [f64; 2] {
        let [a, b, _] = self.eval(p, theta);
        [a, b]
    }

    /// ψ for any dual scalar: the reference that `autodiff` and the tests differentiate.
    fn psi_dual<D: DualNum<Primitive = f64> + Copy>(&self, p: &Self::Params, theta: D) -> D;

    /// Whether this ψ provides parameter derivatives ([`HingePsi::parameter_derivatives`]): derived and
    /// run-time energies do (generated symbolically), hand-written ones by default do not.
    fn has_parameter_derivatives(&self) -> bool {
        false
    }

    /// The parameters [`HingePsi::parameter_derivatives`] differentiates with respect to, in its order (the
    /// rest angle θ̄ comes after them and is not listed). Default: none.
    fn parameters(&self) -> Vec<PsiParameter> {
        Vec::new()
    }

    /// `parameters().len()` without building the list (what the per-hinge derivative calls ask).
    fn n_parameters(&self) -> usize {
        self.parameters().len()
    }

    /// Writes `[∂ψ/∂p, ∂ψ′/∂p]` at hinge `q` and angle `theta` for every parameter of
    /// [`HingePsi::parameters`], then for the rest angle θ̄: `out` has `parameters().len() + 1` entries. For a
    /// per-hinge parameter `p` is hinge `q.hinge`'s own value. Returns false, leaving `out` untouched, when the
    /// energy has no parameter derivatives or `out` has another length.
    fn parameter_derivatives(&self, q: &HingeQuantities, theta: f64, out: &mut [[f64; 2]]) -> bool {
        let _ = (q, theta, out);
        false
    }

    /// The value of parameter `index` of [`HingePsi::parameters`]: one entry for a scalar, one per hinge for
    /// a per-hinge parameter. `None` for an index out of range.
    fn parameter_values(&self, index: usize) -> Option<Vec<f64>> {
        let _ = index;
        None
    }

    /// Sets parameter `index` of [`HingePsi::parameters`] (one value for a scalar; one per hinge for a
    /// per-hinge parameter, checked by [`HingePsi::validate`] when a model takes the energy).
    ///
    /// # Errors
    /// A [`PsiError`] for an index out of range or a scalar given another number of values than one; on
    /// error nothing changes.
    fn set_parameter_values(&mut self, index: usize, values: &[f64]) -> Result<(), PsiError> {
        let _ = values;
        Err(PsiError {
            name: format!("#{index}").into(),
            message: "this energy has no settable parameters".into(),
        })
    }
}

/// The [`PsiError`] for a scalar parameter given `n` values (shared by the derive and the run-time ψ).
#[doc(hidden)]
pub fn scalar_length_error(name: &str, n: usize) -> PsiError {
    PsiError {
        name: name.to_string().into(),
        message: format!("is one value for every hinge, got {n} values"),
    }
}

impl<A: HingePsi, B: HingePsi> HingePsi for (A, B) {
    type Params = (A::Params, B::Params);
    const D2_IS_ZERO: bool = A::D2_IS_ZERO && B::D2_IS_ZERO;
    const USES_STEP: bool = A::USES_STEP || B::USES_STEP;

    fn second_derivative_vanishes(&self) -> bool {
        self.0.second_derivative_vanishes() && self.1.second_derivative_vanishes()
    }

    fn uses_step_quantities(&self) -> bool {
        self.0.uses_step_quantities() || self.1.uses_step_quantities()
    }

    fn validate(&self, n_hinges: usize) -> Result<(), PsiError> {
        self.0.validate(n_hinges)?;
        self.1.validate(n_hinges)
    }

    fn params(&self, q: &HingeQuantities) -> Self::Params {
        (self.0.params(q), self.1.params(q))
    }

    fn update_step(&self, q: &HingeQuantities, p: &mut Self::Params) {
        self.0.update_step(q, &mut p.0);
        self.1.update_step(q, &mut p.1);
    }

    #[inline]
    fn eval(&self, p: &Self::Params, theta: f64) -> [f64; 3] {
        let a = self.0.eval(&p.0, theta);
        let b = self.1.eval(&p.1, theta);
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    }

    #[inline]
    fn value(&self, p: &Self::Params, theta: f64) -> f64 {
        self.0.value(&p.0, theta) + self.1.value(&p.1, theta)
    }

    #[inline]
    fn eval_d1(&self, p: &Self::Params, theta: f64) -> [f64; 2] {
        let a = self.0.eval_d1(&p.0, theta);
        let b = self.1.eval_d1(&p.1, theta);
        [a[0] + b[0], a[1] + b[1]]
    }

    fn psi_dual<D: DualNum<Primitive = f64> + Copy>(&self, p: &Self::Params, theta: D) -> D {
        self.0.psi_dual(&p.0, theta) + self.1.psi_dual(&p.1, theta)
    }

    fn has_parameter_derivatives(&self) -> bool {
        self.0.has_parameter_derivatives() && self.1.has_parameter_derivatives()
    }

    /// The first term's parameters named `0.NAME`, then the second's named `1.NAME` (nested tuples nest the
    /// prefixes).
    fn parameters(&self) -> Vec<PsiParameter> {
        let tag = |k: usize, v: Vec<PsiParameter>| {
            v.into_iter().map(move |p| PsiParameter {
                name: format!("{k}.{}", p.name),
                per_hinge: p.per_hinge,
            })
        };
        tag(0, self.0.parameters())
            .chain(tag(1, self.1.parameters()))
            .collect()
    }

    fn n_parameters(&self) -> usize {
        self.0.n_parameters() + self.1.n_parameters()
    }

    fn parameter_derivatives(&self, q: &HingeQuantities, theta: f64, out: &mut [[f64; 2]]) -> bool {
        let (na, nb) = (self.0.n_parameters(), self.1.n_parameters());
        if out.len() != na + nb + 1 || !self.has_parameter_derivatives() {
            return false;
        }
        if !self.0.parameter_derivatives(q, theta, &mut out[..na + 1]) {
            return false;
        }
        let rest_a = out[na];
        if !self.1.parameter_derivatives(q, theta, &mut out[na..]) {
            return false;
        }
        let rest = &mut out[na + nb];
        *rest = [rest[0] + rest_a[0], rest[1] + rest_a[1]];
        true
    }

    fn parameter_values(&self, index: usize) -> Option<Vec<f64>> {
        let na = self.0.n_parameters();
        if index < na {
            self.0.parameter_values(index)
        } else {
            self.1.parameter_values(index - na)
        }
    }

    fn set_parameter_values(&mut self, index: usize, values: &[f64]) -> Result<(), PsiError> {
        let na = self.0.n_parameters();
        if index < na {
            self.0.set_parameter_values(index, values)
        } else {
            self.1.set_parameter_values(index - na, values)
        }
    }
}

/// Discrete shells (Grinspun et al. 2003): `ψ = k·a·(θ − θ̄)²`, declared with the derive macro.
#[derive(Debug, Clone, PartialEq, crate::HingeEnergy)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[psi(k * a * (theta - theta_bar).powi(2))]
pub struct DiscreteShells {
    /// Bending stiffness k.
    pub k: f64,
}

/// The tan-based energy of the paper (§5): `ψ = k·a·(φ(θ) − φ(θ̄))²` with `φ(θ) = 2 tan(θ/2)`, declared with
/// the derive macro.
///
/// It grows without bound as θ → ±π (a barrier against folding through). In floating point `tan(θ/2)` stays
/// finite even at θ = π (about 1.6e16), so the values are huge but finite; the engine reports a typed error
/// if they overflow.
#[derive(Debug, Clone, PartialEq, crate::HingeEnergy)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[psi(k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2))]
pub struct TanBending {
    /// Bending stiffness k.
    pub k: f64,
}

/// Hand-written ψ implementations: the reference the macro-generated energies are tested against (they
/// give identical numbers for discrete shells) and the baseline of `hinge bench`'s ψ rows. They also show
/// how to implement [`HingePsi`] by hand, with a stiffness that may vary per hinge.
pub mod handwritten {
    use num_dual::DualNum;

    use super::{HingePsi, HingeQuantities, PsiError};

    /// Per-hinge parameters shared by the hand-written energies: `k·a` and θ̄ (or φ(θ̄)).
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct ScaledRest {
        /// Stiffness times `a`.
        pub ka: f64,
        /// The rest value the energy compares against (θ̄ or φ(θ̄)).
        pub rest: f64,
    }

    /// Stiffness: one value for every hinge, or one per hinge (graded or anisotropic materials).
    #[derive(Debug, Clone, PartialEq)]
    pub enum Stiffness {
        /// The same `k` everywhere.
        Uniform(f64),
        /// `k` per hinge, in hinge order.
        PerHinge(Vec<f64>),
    }

    impl Stiffness {
        fn check(&self, n_hinges: usize) -> Result<(), PsiError> {
            match self {
                Stiffness::Uniform(k) if !k.is_finite() => Err(PsiError {
                    name: "k".into(),
                    message: format!("is not finite ({k})"),
                }),
                Stiffness::PerHinge(ks) if ks.len() != n_hinges => Err(PsiError {
                    name: "k".into(),
                    message: format!("has {} values but the mesh has {n_hinges} hinges", ks.len()),
                }),
                Stiffness::PerHinge(ks) => match ks.iter().position(|k| !k.is_finite()) {
                    Some(i) => Err(PsiError {
                        name: "k".into(),
                        message: format!("value of hinge {i} is not finite ({})", ks[i]),
                    }),
                    None => Ok(()),
                },
                Stiffness::Uniform(_) => Ok(()),
            }
        }

        /// `k` of hinge `h` (NaN beyond a too-short per-hinge list, which [`HingePsi::validate`] rejects when the
        /// energy is bound to a mesh).
        pub fn at(&self, h: usize) -> f64 {
            match self {
                Stiffness::Uniform(k) => *k,
                Stiffness::PerHinge(ks) => ks.get(h).copied().unwrap_or(f64::NAN),
            }
        }
    }

    /// Discrete shells (Grinspun et al. 2003): `ψ = k·a·(θ − θ̄)²`.
    #[derive(Debug, Clone, PartialEq)]
    pub struct DiscreteShells {
        /// Bending stiffness k.
        pub k: Stiffness,
    }

    impl HingePsi for DiscreteShells {
        type Params = ScaledRest;

        fn validate(&self, n_hinges: usize) -> Result<(), PsiError> {
            self.k.check(n_hinges)
        }

        fn params(&self, q: &HingeQuantities) -> ScaledRest {
            ScaledRest {
                ka: self.k.at(q.hinge) * q.a,
                rest: q.theta_bar,
            }
        }

        #[inline]
        fn eval(&self, p: &ScaledRest, theta: f64) -> [f64; 3] {
            let d = theta - p.rest;
            [p.ka * (d * d), p.ka * (2.0 * d), 2.0 * p.ka]
        }

        fn psi_dual<D: DualNum<Primitive = f64> + Copy>(&self, p: &ScaledRest, theta: D) -> D {
            let d = theta - p.rest;
            d * d * p.ka
        }
    }

    /// The tan-based energy of the paper (§5): `ψ = k·a·(φ(θ) − φ(θ̄))²` with `φ(θ) = 2 tan(θ/2)`.
    ///
    /// It grows without bound as θ → ±π (a barrier against folding through). At θ = ±π exactly the values are
    /// not finite and the engine reports a typed error.
    #[derive(Debug, Clone, PartialEq)]
    pub struct TanBending {
        /// Bending stiffness k.
        pub k: Stiffness,
    }

    impl HingePsi for TanBending {
        type Params = ScaledRest;

        fn validate(&self, n_hinges: usize) -> Result<(), PsiError> {
            self.k.check(n_hinges)
        }

        fn params(&self, q: &HingeQuantities) -> ScaledRest {
            ScaledRest {
                ka: self.k.at(q.hinge) * q.a,
                rest: 2.0 * (0.5 * q.theta_bar).tan(),
            }
        }

        #[inline]
        fn eval(&self, p: &ScaledRest, theta: f64) -> [f64; 3] {
            // φ = 2t, φ′ = 1 + t², φ″ = t(1 + t²) with t = tan(θ/2).
            let t = (0.5 * theta).tan();
            let s = 1.0 + t * t;
            let d = 2.0 * t - p.rest;
            [
                p.ka * d * d,
                2.0 * p.ka * d * s,
                2.0 * p.ka * (s * s + d * t * s),
            ]
        }

        fn psi_dual<D: DualNum<Primitive = f64> + Copy>(&self, p: &ScaledRest, theta: D) -> D {
            let d = (theta * 0.5).tan() * 2.0 - p.rest;
            d * d * p.ka
        }
    }
}
