//! Energies of any stencil (vertex, edge, triangle, hinge) and their composition into a [`System`]: one
//! sparsity pattern holding exactly the couplings the energies create, one matrix they all add into, and one
//! geometric pass for all hinge terms (compose ψ terms as a tuple in one [`HingeTerm`]).
//!
//! An [`Energy`] declares its couplings, is bound once to the system's pattern (where it precomputes its
//! value slots), then adds its energy, gradient and Hessian to an [`Accumulator`] under a [`Request`]:
//! nothing unrequested is computed. Implement it for your own energies outside this crate.

use std::sync::Arc;

use nalgebra::{Matrix3, Vector3};

use crate::bending::scatter::{Orient, add_block_values};
use crate::bending::{BendingModel, HessianMode, Method, Parallelism, Request, Scratch};
use crate::error::{ElementRef, EvalError};
use crate::mesh::check_same_vertex_count;
use crate::pattern::SymmetricPattern;
use crate::psi::HingePsi;

/// Where energies add their gradient and Hessian. An empty `gradient` or `hessian` means not requested.
#[derive(Debug)]
pub struct Accumulator<'a> {
    /// The system's pattern.
    pub pattern: &'a SymmetricPattern,
    /// Gradient, `3n` entries (empty if not requested).
    pub gradient: &'a mut [f64],
    /// Hessian values in the pattern's lower-triangle CSC order (empty if not requested).
    pub hessian: &'a mut [f64],
}

impl<'a> Accumulator<'a> {
    /// An accumulator into `gradient` and `hessian` for the outputs `request` asks for (the others empty).
    pub fn of(
        pattern: &'a SymmetricPattern,
        request: Request,
        gradient: &'a mut [f64],
        hessian: &'a mut [f64],
    ) -> Self {
        Self {
            pattern,
            gradient: if request.gradient { gradient } else { &mut [] },
            hessian: if request.hessian { hessian } else { &mut [] },
        }
    }

    /// Adds `g` to vertex `v`'s gradient (no-op when the gradient is not requested).
    #[inline]
    pub fn add_gradient(&mut self, v: usize, g: &Vector3<f64>) {
        if let Some(dst) = self.gradient.get_mut(3 * v..3 * v + 3) {
            dst[0] += g.x;
            dst[1] += g.y;
            dst[2] += g.z;
        }
    }

    /// Adds block `b` = ∂²E/∂x_r∂x_c at the pattern's block `slot` (from [`SymmetricPattern::find`]); `r`
    /// and `c` are the block's row and column vertices (the caller's numbering) in either order: the
    /// transpose is stored when the slot's stored block is `(c, r)` (see [`crate::pattern::BlockSlot`]). No-op
    /// when the Hessian is not requested.
    #[inline]
    pub fn add_block(&mut self, slot: usize, r: usize, c: usize, b: &Matrix3<f64>) {
        if self.hessian.is_empty() {
            return;
        }
        let Some(s) = self.pattern.blocks().get(slot) else {
            return;
        };
        let off = s.offset.map(|o| o as usize);
        let orient = if r == c {
            Orient::Diagonal
        } else if r == s.row as usize {
            Orient::AsIs
        } else {
            Orient::Transposed
        };
        add_block_values(self.hessian, off, orient, b);
    }
}

/// A parameter of an energy that derivatives can be taken with respect to ([`Energy::parameters`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Parameter {
    /// Its name within the energy (`k`, `theta_bar`, `young`, …); a [`System`] prefixes the term name.
    pub name: String,
    /// How many values it has: 1 for a scalar, the hinge count for a per-hinge field, and so on.
    pub len: usize,
}

/// What [`Energy::add_parameter_derivatives`] adds to, for one parameter of `len` values. Empty slices are not
/// requested.
#[derive(Debug)]
pub struct ParameterOutput<'a> {
    /// `∂E/∂p` (`len` entries).
    pub energy: &'a mut [f64],
    /// The vector the gradient's derivative is contracted with (`3n` entries, or empty).
    pub lambda: &'a [f64],
    /// `(∂∇E/∂p)ᵀ λ` (`len` entries; requested when `lambda` is not empty).
    pub contracted: &'a mut [f64],
    /// The direction in parameter space (`len` entries, or empty) the gradient's derivative is taken along.
    pub direction: &'a [f64],
    /// `Σ_i direction_i ∂∇E/∂p_i` (`3n` entries; requested when `direction` is not empty): what forward
    /// sensitivities `dx*/dp·d = −H⁻¹ (∂∇E/∂p) d` need.
    pub gradient: &'a mut [f64],
}

/// The error for a parameter name an energy does not have.
pub fn unknown_parameter(name: &str, known: &[Parameter]) -> EvalError {
    EvalError::Parameter {
        name: name.to_string(),
        message: if known.is_empty() {
            "unknown: this energy has no differentiable parameters".into()
        } else {
            format!(
                "unknown (known: {})",
                known
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        },
    }
}

/// Checks `values` against parameter `p` (length, finiteness).
///
/// # Errors
/// [`EvalError::Parameter`] naming the parameter (and the first non-finite entry).
pub fn check_parameter_values(p: &Parameter, values: &[f64]) -> Result<(), EvalError> {
    if values.len() != p.len {
        return Err(EvalError::Parameter {
            name: p.name.clone(),
            message: format!("has {} values, {} given", p.len, values.len()),
        });
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(EvalError::Parameter {
            name: p.name.clone(),
            message: format!("value {i} is not finite ({})", values[i]),
        });
    }
    Ok(())
}

/// An energy over the vertices of one mesh.
pub trait Energy: Send + Sync {
    /// A short name for reports (`"membrane"`, `"tan-bending"`, …).
    fn name(&self) -> &str;

    /// Number of vertices of the mesh it is defined on.
    fn n_vertices(&self) -> usize;

    /// Appends the vertex pairs whose Hessian block this energy can make non-zero (diagonal blocks are
    /// always present and need not be listed).
    fn couplings(&self, out: &mut Vec<(usize, usize)>);

    /// The largest fraction `t ∈ [0, 1]` of the straight move from `from` to `to` (all vertices at once) that
    /// this energy admits: a barrier's continuous collision bound, below which the energy stays finite.
    /// Newton starts its line search there. Default: 1 (no bound).
    fn max_step(&self, from: &[Vector3<f64>], to: &[Vector3<f64>]) -> f64 {
        let _ = (from, to);
        1.0
    }

    /// Whether the Hessian this term assembles for a plain (not [`Request::definite`]) request is its
    /// energy's exact second derivative: false for a hinge term in Gauss–Newton or projected mode
    /// ([`HessianMode`]). Newton judges convergence by a step's length only after a full step of an exact
    /// Hessian. Default: true.
    fn hessian_is_exact(&self) -> bool {
        true
    }

    /// Moves vertices of `x` (positions at time `from_time`) the way a moving part of this energy moved
    /// them by the time it is placed at now ([`Energy::set_time`]): a barrier's moving obstacle carries the
    /// vertices within its reach, so that a time step can start outside it. Returns whether it moved any
    /// vertex. Default: nothing (`false`).
    fn carry(&self, from_time: f64, x: &mut [Vector3<f64>]) -> bool {
        let _ = (from_time, x);
        false
    }

    /// Binds to the system's pattern, which holds at least [`Energy::couplings`]: precompute slots here.
    ///
    /// # Errors
    /// [`EvalError::Pattern`] when the pattern does not fit.
    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError>;

    /// Adds the requested quantities at positions `x` and returns the energy (0 if not requested).
    ///
    /// # Errors
    /// A typed [`EvalError`] naming the offending element; then `acc` holds no meaningful values.
    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        par: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError>;

    /// Starts a time step (positions at the end of the previous step, step size). Default: nothing.
    ///
    /// # Errors
    /// As the implementation says.
    fn begin_step(&mut self, x_prev: &[Vector3<f64>], dt: f64) -> Result<(), EvalError> {
        let _ = (x_prev, dt);
        Ok(())
    }

    /// Places parts of the energy that move on a prescribed path (a moving obstacle) where they are at
    /// `time` (s). The time steppers call it with the instant each (sub)step ends at, before solving the step,
    /// and with the time of the last accepted state when a step fails, so that a failed step leaves the
    /// energy as it was. Default: nothing.
    ///
    /// # Errors
    /// As the implementation says (a non-finite time); on error the implementation's state is unchanged.
    fn set_time(&mut self, time: f64) -> Result<(), EvalError> {
        let _ = time;
        Ok(())
    }

    /// An accepted (sub)step ended at `x`: update state that follows accepted motion only, such as
    /// plastic rest angles ([`HingeTerm::with_plasticity`]). The steppers never call it for a rejected
    /// attempt. Default: nothing.
    ///
    /// # Errors
    /// As the implementation says; on error the implementation's state is unchanged.
    fn end_step(&mut self, x: &[Vector3<f64>]) -> Result<(), EvalError> {
        let _ = x;
        Ok(())
    }

    /// Remembers the state [`Energy::end_step`] changes (plastic rest angles) for
    /// [`Energy::rewind_step_state`]. The time steppers call it at the start of every frame, so that a frame
    /// that fails after some of its substeps were accepted (and ended) leaves the energy as it was.
    /// Default: nothing.
    fn mark_step_state(&mut self) {}

    /// Sets the state [`Energy::end_step`] changes back to what it was at the last
    /// [`Energy::mark_step_state`] (nothing if it was never called). Default: nothing.
    ///
    /// # Errors
    /// As the implementation says; the state it restores was valid when marked.
    fn rewind_step_state(&mut self) -> Result<(), EvalError> {
        Ok(())
    }

    /// The current rest angles (hinge order) of a hinge energy whose rest angles evolve (plasticity);
    /// `None` for every other energy.
    fn evolving_rest_angles(&self) -> Option<&[f64]> {
        None
    }

    /// The largest accumulated plastic angle (rad) of an energy with plasticity; `None` otherwise.
    fn max_plastic_angle(&self) -> Option<f64> {
        None
    }

    /// The whole plastic state of an energy with plasticity, as a checkpoint must hold it to continue a run
    /// exactly: the rest angles θ̄ and the accumulated plastic angles α (both in hinge order). `None` for
    /// every other energy.
    fn plastic_state(&self) -> Option<(&[f64], &[f64])> {
        None
    }

    /// Sets the state [`Energy::plastic_state`] returns (a run resumed from a checkpoint).
    ///
    /// # Errors
    /// [`EvalError::Element`] for an energy without plasticity (the default); the implementation's errors
    /// for a wrong length or a value out of range. On error nothing changes.
    fn set_plastic_state(
        &mut self,
        theta_bar: &[f64],
        accumulated: &[f64],
    ) -> Result<(), EvalError> {
        let _ = (theta_bar, accumulated);
        Err(EvalError::Element {
            element: self.name().to_string(),
            message: "has no plastic state to set".into(),
        })
    }

    /// The parameters this energy can be differentiated with respect to (fitting, sensitivities). Default:
    /// none.
    fn parameters(&self) -> Vec<Parameter> {
        Vec::new()
    }

    /// The current values of parameter `name`.
    ///
    /// # Errors
    /// [`EvalError::Parameter`] for a name not in [`Energy::parameters`].
    fn parameter(&self, name: &str) -> Result<Vec<f64>, EvalError> {
        Err(unknown_parameter(name, &self.parameters()))
    }

    /// The open interval `(lower, upper)`, both ends finite, that every value of parameter `name` must lie
    /// in when the energy requires one (a membrane's Poisson ratio: `(−1, 0.5)`), so that a fit can keep it
    /// there (`hinge_solver::adjoint::FitVariable::range`). `None` for a
    /// parameter without one (any finite value, or a positive one) and for a name not in
    /// [`Energy::parameters`]. Default: `None`.
    fn parameter_bounds(&self, name: &str) -> Option<(f64, f64)> {
        let _ = name;
        None
    }

    /// Sets parameter `name` (as many values as [`Parameter::len`], finite; an energy may require more, such
    /// as positivity).
    ///
    /// # Errors
    /// [`EvalError::Parameter`] for an unknown name or a bad value; on error nothing changes.
    fn set_parameter(&mut self, name: &str, values: &[f64]) -> Result<(), EvalError> {
        let _ = values;
        Err(unknown_parameter(name, &self.parameters()))
    }

    /// Adds the derivatives with respect to parameter `name` at positions `x` that `out` requests: `∂E/∂p`,
    /// `(∂∇E/∂p)ᵀ λ`, and `(∂∇E/∂p) d` for a direction `d`.
    ///
    /// # Errors
    /// [`EvalError::Parameter`] for an unknown name or buffers of the wrong length; the evaluation's typed
    /// errors (a degenerate hinge, say).
    fn add_parameter_derivatives(
        &mut self,
        x: &[Vector3<f64>],
        name: &str,
        out: &mut ParameterOutput,
    ) -> Result<(), EvalError> {
        let _ = (x, out);
        Err(unknown_parameter(name, &self.parameters()))
    }
}

/// Checks the buffers of a [`ParameterOutput`] for a parameter of `len` values over `n` vertices.
///
/// # Errors
/// [`EvalError::Parameter`] naming the buffer.
pub fn check_parameter_output(
    name: &str,
    len: usize,
    n: usize,
    out: &ParameterOutput,
) -> Result<(), EvalError> {
    let bad = |what: &str, got: usize, want: usize| EvalError::Parameter {
        name: name.to_string(),
        message: format!("{what} has length {got}, expected {want}"),
    };
    if !out.energy.is_empty() && out.energy.len() != len {
        return Err(bad("the energy derivative", out.energy.len(), len));
    }
    if !out.lambda.is_empty() {
        if out.lambda.len() != 3 * n {
            return Err(bad("λ", out.lambda.len(), 3 * n));
        }
        if out.contracted.len() != len {
            return Err(bad("the contracted derivative", out.contracted.len(), len));
        }
    }
    if !out.direction.is_empty() {
        if out.direction.len() != len {
            return Err(bad("the direction", out.direction.len(), len));
        }
        if out.gradient.len() != 3 * n {
            return Err(bad("the gradient derivative", out.gradient.len(), 3 * n));
        }
    }
    Ok(())
}

/// Bending plasticity of a [`HingeTerm`]: after every accepted (sub)step, a hinge whose angle θ has moved
/// more than its yield angle from its rest angle θ̄ yields, θ̄ moving towards θ, with linear hardening:
/// the yield angle grows with the accumulated plastic angle α,
///
/// ```text
/// y = yield_angle + hardening · α,   if |θ − θ̄| > y:  Δ = sign(θ − θ̄) (|θ − θ̄| − y) / (1 + hardening),
///                                                      θ̄ ← θ̄ + Δ,  α ← α + |Δ|,
/// ```
///
/// so that afterwards `|θ − θ̄| = yield_angle + hardening · α` exactly (the return mapping of 1-D linear
/// hardening). Within a step the energy and its derivatives are those of the current θ̄.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plasticity {
    /// The initial yield angle (rad, ≥ 0).
    pub yield_angle: f64,
    /// Linear hardening modulus (dimensionless, ≥ 0): yield-angle growth per radian of plastic angle.
    pub hardening: f64,
}

/// The evolving state of a [`Plasticity`].
#[derive(Debug, Clone)]
struct PlasticState {
    law: Plasticity,
    theta_bar: Vec<f64>,
    accumulated: Vec<f64>,
    /// Work vector for the angles at the end of a step.
    theta: Vec<f64>,
    /// `theta_bar` and `accumulated` at the last [`Energy::mark_step_state`].
    mark: Option<(Vec<f64>, Vec<f64>)>,
}

/// A hinge energy ψ (one ψ, or a tuple of ψ terms sharing one geometric pass) as a system [`Energy`].
pub struct HingeTerm<P: HingePsi> {
    name: String,
    model: BendingModel<P>,
    method: Method,
    scratch: Scratch,
    plastic: Option<PlasticState>,
}

impl<P: HingePsi> std::fmt::Debug for HingeTerm<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HingeTerm")
            .field("name", &self.name)
            .field("method", &self.method)
            .finish()
    }
}

impl<P: HingePsi> HingeTerm<P> {
    /// Wraps a bending model, evaluated with `method`.
    pub fn new(name: impl Into<String>, model: BendingModel<P>, method: Method) -> Self {
        let scratch = model.new_scratch();
        Self {
            name: name.into(),
            model,
            method,
            scratch,
            plastic: None,
        }
    }

    /// Makes the rest angles plastic ([`Plasticity`]): [`Energy::end_step`] updates them after every
    /// accepted step.
    ///
    /// # Errors
    /// [`EvalError::Psi`] naming `yield_angle` or `hardening` when it is negative or not finite.
    pub fn with_plasticity(mut self, law: Plasticity) -> Result<Self, EvalError> {
        for (name, v) in [
            ("yield_angle", law.yield_angle),
            ("hardening", law.hardening),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(EvalError::Psi(crate::psi::PsiError {
                    name: name.into(),
                    message: format!(
                        "must be non-negative and finite, got {}",
                        crate::error::Num(v)
                    ),
                }));
            }
        }
        let theta_bar: Vec<f64> = self
            .model
            .rest_hinges()
            .iter()
            .map(|r| r.theta_bar)
            .collect();
        self.plastic = Some(PlasticState {
            law,
            accumulated: vec![0.0; theta_bar.len()],
            theta: Vec::with_capacity(theta_bar.len()),
            theta_bar,
            mark: None,
        });
        Ok(self)
    }

    /// The accumulated plastic angle α of every hinge (hinge order), if plastic.
    pub fn plastic_angles(&self) -> Option<&[f64]> {
        self.plastic.as_ref().map(|p| p.accumulated.as_slice())
    }

    /// The wrapped model.
    pub fn model(&self) -> &BendingModel<P> {
        &self.model
    }

    /// Changes the method.
    pub fn set_method(&mut self, method: Method) {
        self.method = method;
    }
}

impl<P: HingePsi + Send> Energy for HingeTerm<P>
where
    P::Params: Send + Sync,
{
    fn name(&self) -> &str {
        &self.name
    }

    fn n_vertices(&self) -> usize {
        self.model.n_vertices()
    }

    fn couplings(&self, out: &mut Vec<(usize, usize)>) {
        out.extend(self.model.couplings());
    }

    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError> {
        self.model.bind(Arc::clone(pattern))
    }

    fn hessian_is_exact(&self) -> bool {
        self.model.hessian_mode() == HessianMode::Exact
    }

    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        par: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        let mut e = 0.0;
        self.model.evaluate_add(
            x,
            request,
            self.method,
            par,
            &mut self.scratch,
            &mut e,
            acc.gradient,
            acc.hessian,
        )?;
        Ok(e)
    }

    fn begin_step(&mut self, x_prev: &[Vector3<f64>], dt: f64) -> Result<(), EvalError> {
        self.model.set_step(x_prev, dt)
    }

    fn end_step(&mut self, x: &[Vector3<f64>]) -> Result<(), EvalError> {
        let Some(state) = self.plastic.as_mut() else {
            return Ok(());
        };
        check_same_vertex_count(self.model.n_vertices(), x.len())?;
        // Every angle first (an error leaves the state as it was), then the return mapping.
        state.theta.clear();
        for (i, h) in self.model.topology().hinges().iter().enumerate() {
            let s = h.vertices.map(|v| x[v]);
            let theta = crate::hinge::theta_only(&s).map_err(|source| EvalError::Hinge {
                hinge: i,
                edge: h.edge,
                vertices: h.vertices,
                source,
            })?;
            state.theta.push(theta);
        }
        let Plasticity {
            yield_angle,
            hardening,
        } = state.law;
        let mut changed = false;
        for ((tb, alpha), &theta) in state
            .theta_bar
            .iter_mut()
            .zip(state.accumulated.iter_mut())
            .zip(&state.theta)
        {
            let d = theta - *tb;
            let y = yield_angle + hardening * *alpha;
            if d.abs() > y {
                let step = (d.abs() - y) / (1.0 + hardening);
                *tb += step.copysign(d);
                *alpha += step;
                changed = true;
            }
        }
        if changed {
            self.model.set_rest_angles(&state.theta_bar)?;
        }
        Ok(())
    }

    fn mark_step_state(&mut self) {
        if let Some(state) = self.plastic.as_mut() {
            match &mut state.mark {
                Some((tb, a)) => {
                    tb.clone_from(&state.theta_bar);
                    a.clone_from(&state.accumulated);
                }
                None => state.mark = Some((state.theta_bar.clone(), state.accumulated.clone())),
            }
        }
    }

    fn rewind_step_state(&mut self) -> Result<(), EvalError> {
        let Some(state) = self.plastic.as_mut() else {
            return Ok(());
        };
        let Some((tb, a)) = &state.mark else {
            return Ok(());
        };
        if *tb != state.theta_bar {
            // The marked angles were this model's rest angles then: they are accepted again.
            self.model.set_rest_angles(tb)?;
            state.theta_bar.clone_from(tb);
        }
        state.accumulated.clone_from(a);
        Ok(())
    }

    fn evolving_rest_angles(&self) -> Option<&[f64]> {
        self.plastic.as_ref().map(|p| p.theta_bar.as_slice())
    }

    fn plastic_state(&self) -> Option<(&[f64], &[f64])> {
        self.plastic
            .as_ref()
            .map(|p| (p.theta_bar.as_slice(), p.accumulated.as_slice()))
    }

    fn set_plastic_state(
        &mut self,
        theta_bar: &[f64],
        accumulated: &[f64],
    ) -> Result<(), EvalError> {
        let Some(state) = self.plastic.as_mut() else {
            return Err(EvalError::Element {
                element: self.name().to_string(),
                message: "has no plasticity, so no plastic state to set".into(),
            });
        };
        if accumulated.len() != state.accumulated.len() {
            return Err(EvalError::Psi(crate::psi::PsiError {
                name: "accumulated plastic angle".into(),
                message: format!(
                    "has {} values but the mesh has {} hinges",
                    accumulated.len(),
                    state.accumulated.len()
                ),
            }));
        }
        if let Some(i) = accumulated
            .iter()
            .position(|a| !(*a >= 0.0 && a.is_finite()))
        {
            return Err(EvalError::Psi(crate::psi::PsiError {
                name: "accumulated plastic angle".into(),
                message: format!(
                    "value of hinge {i} must be non-negative and finite, got {}",
                    crate::error::Num(accumulated[i])
                ),
            }));
        }
        // Checks θ̄ (length, range) and sets it, or changes nothing.
        self.model.set_rest_angles(theta_bar)?;
        state.theta_bar.clear();
        state.theta_bar.extend_from_slice(theta_bar);
        state.accumulated.copy_from_slice(accumulated);
        state.mark = None;
        Ok(())
    }

    /// The ψ's parameters ([`HingePsi::parameters`]; 1 value, or one per hinge) and the rest angles
    /// `theta_bar` (one per hinge), when the ψ has parameter derivatives (derived and run-time energies).
    fn parameters(&self) -> Vec<Parameter> {
        let psi = self.model.psi();
        if !psi.has_parameter_derivatives() {
            return Vec::new();
        }
        let n_hinges = self.model.rest_hinges().len();
        psi.parameters()
            .into_iter()
            .map(|p| Parameter {
                len: if p.per_hinge { n_hinges } else { 1 },
                name: p.name,
            })
            .chain(std::iter::once(Parameter {
                name: "theta_bar".into(),
                len: n_hinges,
            }))
            .collect()
    }

    fn parameter(&self, name: &str) -> Result<Vec<f64>, EvalError> {
        let params = self.parameters();
        match params.iter().position(|p| p.name == name) {
            Some(k) if k + 1 == params.len() => Ok(match &self.plastic {
                Some(state) => state.theta_bar.clone(),
                None => self
                    .model
                    .rest_hinges()
                    .iter()
                    .map(|r| r.theta_bar)
                    .collect(),
            }),
            Some(k) => self
                .model
                .psi()
                .parameter_values(k)
                .ok_or_else(|| unknown_parameter(name, &params)),
            None => Err(unknown_parameter(name, &params)),
        }
    }

    fn set_parameter(&mut self, name: &str, values: &[f64]) -> Result<(), EvalError> {
        let params = self.parameters();
        let Some(k) = params.iter().position(|p| p.name == name) else {
            return Err(unknown_parameter(name, &params));
        };
        check_parameter_values(&params[k], values)?;
        if k + 1 == params.len() {
            self.model.set_rest_angles(values)?;
            if let Some(state) = self.plastic.as_mut() {
                state.theta_bar.copy_from_slice(values);
            }
            Ok(())
        } else {
            self.model.set_psi_parameter(k, values)
        }
    }

    fn add_parameter_derivatives(
        &mut self,
        x: &[Vector3<f64>],
        name: &str,
        out: &mut ParameterOutput,
    ) -> Result<(), EvalError> {
        let params = self.parameters();
        let Some(k) = params.iter().position(|p| p.name == name) else {
            return Err(unknown_parameter(name, &params));
        };
        let n = self.model.n_vertices();
        check_same_vertex_count(n, x.len())?;
        crate::mesh::validate_positions(x)?;
        check_parameter_output(name, params[k].len, n, out)?;
        let per_hinge = params[k].len != 1 || k + 1 == params.len();
        let psi = self.model.psi();
        let mut d = vec![[0.0; 2]; params.len()];
        for (i, h) in self.model.topology().hinges().iter().enumerate() {
            let st = h.vertices.map(|v| x[v]);
            let (theta, grad) =
                crate::hinge::theta_and_gradient(&st).map_err(|source| EvalError::Hinge {
                    hinge: i,
                    edge: h.edge,
                    vertices: h.vertices,
                    source,
                })?;
            let q = self
                .model
                .hinge_quantities(i)
                .ok_or_else(|| unknown_parameter(name, &params))?;
            if !psi.parameter_derivatives(&q, theta, &mut d) {
                return Err(EvalError::Parameter {
                    name: name.to_string(),
                    message: "the ψ provides no parameter derivatives".into(),
                });
            }
            let [de, dd1] = d[k];
            if !(de.is_finite() && dd1.is_finite()) {
                return Err(EvalError::NonFiniteEnergy {
                    hinge: i,
                    vertices: h.vertices,
                    theta,
                });
            }
            let j = if per_hinge { i } else { 0 };
            if !out.energy.is_empty() {
                out.energy[j] += de;
            }
            if !out.lambda.is_empty() {
                let mut dot = 0.0;
                for (c, &v) in h.vertices.iter().enumerate() {
                    let l = &out.lambda[3 * v..3 * v + 3];
                    dot += grad[c].x * l[0] + grad[c].y * l[1] + grad[c].z * l[2];
                }
                out.contracted[j] += dd1 * dot;
            }
            if !out.direction.is_empty() {
                let w = dd1 * out.direction[j];
                for (c, &v) in h.vertices.iter().enumerate() {
                    let g = &mut out.gradient[3 * v..3 * v + 3];
                    g[0] += w * grad[c].x;
                    g[1] += w * grad[c].y;
                    g[2] += w * grad[c].z;
                }
            }
        }
        Ok(())
    }

    fn max_plastic_angle(&self) -> Option<f64> {
        self.plastic
            .as_ref()
            .map(|p| p.accumulated.iter().copied().fold(0.0, f64::max))
    }
}

/// The result of evaluating a [`System`]: total energy, energy per term, gradient and Hessian.
#[derive(Debug, Clone, PartialEq)]
pub struct SystemEvaluation {
    /// Total energy (sum of `terms`, in term order).
    pub energy: f64,
    /// Energy of each term, in the order the terms were given.
    pub terms: Vec<f64>,
    /// Gradient, `3n` entries.
    pub gradient: Vec<f64>,
    /// Hessian values in [`System::pattern`]'s lower-triangle CSC order.
    pub hessian: Vec<f64>,
}

/// Labels for terms named `names` (in order), as parameter names use them: a name, and for the k-th term of
/// a name that an earlier term has (k ≥ 2) the name followed by `#k` — two custom bending terms are `custom`
/// and `custom#2`, so that each one's parameters can be named (`custom#2.k`).
pub fn term_labels<'a>(names: impl IntoIterator<Item = &'a str>) -> Vec<String> {
    let mut seen: Vec<(&str, usize)> = Vec::new();
    names
        .into_iter()
        .map(|name| match seen.iter_mut().find(|(n, _)| *n == name) {
            Some((_, count)) => {
                *count += 1;
                format!("{name}#{count}")
            }
            None => {
                seen.push((name, 1));
                name.to_string()
            }
        })
        .collect()
}

/// Several energies over one mesh, assembled into one gradient and one sparse Hessian.
pub struct System {
    n_vertices: usize,
    terms: Vec<Box<dyn Energy>>,
    pattern: Arc<SymmetricPattern>,
    /// Seconds spent in each term's evaluation since the last [`System::take_timings`].
    seconds: Vec<f64>,
}

impl std::fmt::Debug for System {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("System")
            .field("n_vertices", &self.n_vertices)
            .field(
                "terms",
                &self
                    .terms
                    .iter()
                    .map(|t| t.name().to_string())
                    .collect::<Vec<_>>(),
            )
            .field("nnz", &self.pattern.nnz())
            .finish()
    }
}

impl System {
    /// Composes `terms` over `n_vertices` vertices: builds the union pattern of their couplings and binds
    /// every term to it.
    ///
    /// # Errors
    /// [`EvalError::Pattern`] when a term is defined on another number of vertices.
    pub fn new(n_vertices: usize, mut terms: Vec<Box<dyn Energy>>) -> Result<Self, EvalError> {
        let mut pairs = Vec::new();
        for t in &terms {
            if t.n_vertices() != n_vertices {
                return Err(EvalError::Pattern {
                    message: format!(
                        "term `{}` has {} vertices, the system {}",
                        t.name(),
                        t.n_vertices(),
                        n_vertices
                    ),
                });
            }
            t.couplings(&mut pairs);
        }
        let pattern = Arc::new(SymmetricPattern::new(n_vertices, pairs)?);
        for t in &mut terms {
            t.bind(&pattern)?;
        }
        let seconds = vec![0.0; terms.len()];
        Ok(Self {
            n_vertices,
            terms,
            pattern,
            seconds,
        })
    }

    /// The shared pattern.
    pub fn pattern(&self) -> &SymmetricPattern {
        &self.pattern
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// The names of the terms, in order.
    pub fn term_names(&self) -> Vec<&str> {
        self.terms.iter().map(|t| t.name()).collect()
    }

    /// Output buffers for this system.
    pub fn new_output(&self) -> SystemEvaluation {
        SystemEvaluation {
            energy: 0.0,
            terms: vec![0.0; self.terms.len()],
            gradient: vec![0.0; 3 * self.n_vertices],
            hessian: vec![0.0; self.pattern.nnz()],
        }
    }

    /// Seconds each term spent in evaluation (energy, gradient, Hessian and assembly) since the last call,
    /// by term name; resets the counters.
    pub fn take_timings(&mut self) -> Vec<(String, f64)> {
        let out = self
            .terms
            .iter()
            .map(|t| t.name().to_string())
            .zip(self.seconds.iter().copied())
            .collect();
        self.seconds.fill(0.0);
        out
    }

    /// The smallest [`Energy::max_step`] over the terms (1 when none bounds the move; 1 as well for slices of
    /// the wrong length).
    pub fn max_step(&self, from: &[Vector3<f64>], to: &[Vector3<f64>]) -> f64 {
        if from.len() != self.n_vertices || to.len() != self.n_vertices {
            return 1.0;
        }
        self.terms
            .iter()
            .map(|t| t.max_step(from, to))
            .fold(1.0, f64::min)
    }

    /// Whether every term's Hessian is exact ([`Energy::hessian_is_exact`]).
    pub fn hessian_is_exact(&self) -> bool {
        self.terms.iter().all(|t| t.hessian_is_exact())
    }

    /// [`Energy::carry`] of every term in turn; whether any moved a vertex (nothing for a slice of the
    /// wrong length).
    pub fn carry(&self, from_time: f64, x: &mut [Vector3<f64>]) -> bool {
        if x.len() != self.n_vertices {
            return false;
        }
        let mut moved = false;
        for t in &self.terms {
            moved |= t.carry(from_time, x);
        }
        moved
    }

    /// Starts a time step for every term (see [`Energy::begin_step`]).
    ///
    /// # Errors
    /// The first term's error; terms before it have already started the step.
    pub fn begin_step(&mut self, x_prev: &[Vector3<f64>], dt: f64) -> Result<(), EvalError> {
        for t in &mut self.terms {
            t.begin_step(x_prev, dt)?;
        }
        Ok(())
    }

    /// Places every term at `time` (see [`Energy::set_time`]).
    ///
    /// # Errors
    /// The first term's error; terms before it have already moved.
    pub fn set_time(&mut self, time: f64) -> Result<(), EvalError> {
        for t in &mut self.terms {
            t.set_time(time)?;
        }
        Ok(())
    }

    /// Ends an accepted (sub)step at `x` for every term (see [`Energy::end_step`]).
    ///
    /// # Errors
    /// The first term's error; terms before it have already ended the step.
    pub fn end_step(&mut self, x: &[Vector3<f64>]) -> Result<(), EvalError> {
        check_same_vertex_count(self.n_vertices, x.len())?;
        for t in &mut self.terms {
            t.end_step(x)?;
        }
        Ok(())
    }

    /// Remembers every term's step state (see [`Energy::mark_step_state`]).
    pub fn mark_step_state(&mut self) {
        for t in &mut self.terms {
            t.mark_step_state();
        }
    }

    /// Sets every term's step state back to the last mark (see [`Energy::rewind_step_state`]).
    ///
    /// # Errors
    /// The first term's error; the other terms are rewound all the same.
    pub fn rewind_step_state(&mut self) -> Result<(), EvalError> {
        let mut first = Ok(());
        for t in &mut self.terms {
            let r = t.rewind_step_state();
            if first.is_ok() {
                first = r;
            }
        }
        first
    }

    /// The evolving rest angles of the first term that has them (see [`Energy::evolving_rest_angles`]).
    pub fn evolving_rest_angles(&self) -> Option<&[f64]> {
        self.terms.iter().find_map(|t| t.evolving_rest_angles())
    }

    /// The plastic state (rest angles, accumulated plastic angles) of the first term that has plasticity
    /// (see [`Energy::plastic_state`]).
    pub fn plastic_state(&self) -> Option<(&[f64], &[f64])> {
        self.terms.iter().find_map(|t| t.plastic_state())
    }

    /// Sets the plastic state of the first term that has plasticity (see [`Energy::set_plastic_state`]).
    ///
    /// # Errors
    /// [`EvalError::Element`] when no term has plasticity; the term's error for a state it refuses (then
    /// nothing changes).
    pub fn set_plastic_state(
        &mut self,
        theta_bar: &[f64],
        accumulated: &[f64],
    ) -> Result<(), EvalError> {
        match self.terms.iter_mut().find(|t| t.plastic_state().is_some()) {
            Some(t) => t.set_plastic_state(theta_bar, accumulated),
            None => Err(EvalError::Element {
                element: "system".into(),
                message: "no energy has plasticity, so there is no plastic state to set".into(),
            }),
        }
    }

    /// The largest accumulated plastic angle over the terms with plasticity (`None` if none has it).
    pub fn max_plastic_angle(&self) -> Option<f64> {
        self.terms
            .iter()
            .filter_map(|t| t.max_plastic_angle())
            .reduce(f64::max)
    }

    /// Evaluates every term at `x` into `out` (overwritten). Unrequested outputs are left untouched.
    ///
    /// # Errors
    /// The first failing term's error, or a length mismatch.
    pub fn evaluate_into(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        par: Parallelism,
        out: &mut SystemEvaluation,
    ) -> Result<(), EvalError> {
        check_same_vertex_count(self.n_vertices, x.len())?;
        if out.gradient.len() != 3 * self.n_vertices
            || out.hessian.len() != self.pattern.nnz()
            || out.terms.len() != self.terms.len()
        {
            *out = self.new_output();
        }
        if request.gradient {
            out.gradient.fill(0.0);
        }
        if request.hessian {
            out.hessian.fill(0.0);
        }
        let mut acc = Accumulator::of(&self.pattern, request, &mut out.gradient, &mut out.hessian);
        out.energy = 0.0;
        for ((t, e), sec) in self
            .terms
            .iter_mut()
            .zip(out.terms.iter_mut())
            .zip(self.seconds.iter_mut())
        {
            let start = std::time::Instant::now();
            *e = t.add_to(x, request, par, &mut acc)?;
            *sec += start.elapsed().as_secs_f64();
            out.energy += *e;
        }
        self.check_finite(x, request, par, out)
    }

    /// Checks an evaluation of this system at `x` (`out`, as [`System::evaluate_into`] left it for
    /// `request`): its energy, gradient and Hessian must be finite. The check is a pass over the outputs
    /// (integer operations on the exponent bits, which vectorize); only when it fails are the terms
    /// evaluated again one at a time, to name the first whose own output is not finite and the vertex of
    /// its first non-finite entry. [`System::evaluate_into`] and [`System::evaluate`] end with it, so no
    /// evaluation returns a NaN or an infinity (an energy's stiffness or a load can overflow f64 where each
    /// input is finite); it is public for outputs assembled otherwise.
    ///
    /// # Errors
    /// [`EvalError::AtElement`] naming the term and the vertex; [`EvalError::NonFiniteTotal`] when no
    /// single vertex is to blame (a term's energy alone, or the sum of finite terms, overflowed).
    pub fn check_finite(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        par: Parallelism,
        out: &SystemEvaluation,
    ) -> Result<(), EvalError> {
        let value = !request.value || out.energy.is_finite();
        let gradient = !request.gradient || all_finite(&out.gradient);
        let hessian = !request.hessian || all_finite(&out.hessian);
        if value && gradient && hessian {
            return Ok(());
        }
        let mut scratch = self.new_output();
        for t in &mut self.terms {
            scratch.gradient.fill(0.0);
            scratch.hessian.fill(0.0);
            let mut acc = Accumulator::of(
                &self.pattern,
                request,
                &mut scratch.gradient,
                &mut scratch.hessian,
            );
            let e = t.add_to(x, request, par, &mut acc)?;
            let at = |vertex: usize, what: &str, v: f64| EvalError::AtElement {
                energy: t.name().to_string(),
                element: ElementRef::Vertex(vertex),
                message: format!(
                    "its {what} is not finite here ({v}): a stiffness, load or coordinate too large for f64?"
                ),
            };
            if let Some(k) = scratch.gradient.iter().position(|v| !v.is_finite()) {
                return Err(at(k / 3, "gradient", scratch.gradient[k]));
            }
            if let Some(k) = scratch.hessian.iter().position(|v| !v.is_finite()) {
                // The value's row (in the lower triangle, the later of its two vertices in storage).
                let vertex = self.pattern.caller_dof(self.pattern.row_idx()[k]) / 3;
                return Err(at(vertex, "Hessian", scratch.hessian[k]));
            }
            if request.value && !e.is_finite() {
                return Err(EvalError::NonFiniteTotal {
                    energy: t.name().to_string(),
                    message: format!("its energy is not finite ({e})"),
                });
            }
        }
        Err(EvalError::NonFiniteTotal {
            energy: "the system".into(),
            message: "every term is finite, their sum is not (it overflows f64)".into(),
        })
    }

    /// The terms' labels in parameter names, in term order ([`term_labels`] of their [`Energy::name`]s).
    pub fn term_labels(&self) -> Vec<String> {
        term_labels(self.terms.iter().map(|t| t.name()))
    }

    /// Every term's differentiable parameters, named `TERM.NAME` (the term's label from
    /// [`System::term_labels`] — its [`Energy::name`], with `#k` for a repeated name —, a dot, the term's
    /// parameter name), in term order.
    pub fn parameters(&self) -> Vec<Parameter> {
        self.terms
            .iter()
            .zip(self.term_labels())
            .flat_map(|(t, label)| {
                t.parameters().into_iter().map(move |p| Parameter {
                    name: format!("{label}.{}", p.name),
                    len: p.len,
                })
            })
            .collect()
    }

    /// The term and the term's own parameter name of `TERM.NAME` (`TERM` a label of
    /// [`System::term_labels`]).
    fn find_parameter(&self, name: &str) -> Result<(usize, String), EvalError> {
        for (i, (t, label)) in self.terms.iter().zip(self.term_labels()).enumerate() {
            if let Some(rest) = name
                .strip_prefix(label.as_str())
                .and_then(|r| r.strip_prefix('.'))
                && t.parameters().iter().any(|p| p.name == rest)
            {
                return Ok((i, rest.to_string()));
            }
        }
        Err(unknown_parameter(name, &self.parameters()))
    }

    /// The values of parameter `TERM.NAME` (see [`System::parameters`]).
    ///
    /// # Errors
    /// [`EvalError::Parameter`] for an unknown name (the message lists the known ones).
    pub fn parameter(&self, name: &str) -> Result<Vec<f64>, EvalError> {
        let (i, own) = self.find_parameter(name)?;
        self.terms[i].parameter(&own)
    }

    /// The open interval parameter `TERM.NAME`'s values must lie in, if its term requires one (see
    /// [`Energy::parameter_bounds`]).
    ///
    /// # Errors
    /// [`EvalError::Parameter`] for an unknown name (the message lists the known ones).
    pub fn parameter_bounds(&self, name: &str) -> Result<Option<(f64, f64)>, EvalError> {
        let (i, own) = self.find_parameter(name)?;
        Ok(self.terms[i].parameter_bounds(&own))
    }

    /// Sets parameter `TERM.NAME` (see [`Energy::set_parameter`]).
    ///
    /// # Errors
    /// [`EvalError::Parameter`] for an unknown name or bad values; the term's own errors. On error nothing
    /// changes.
    pub fn set_parameter(&mut self, name: &str, values: &[f64]) -> Result<(), EvalError> {
        let (i, own) = self.find_parameter(name)?;
        self.terms[i].set_parameter(&own, values)
    }

    /// Adds the derivatives of the system's energy with respect to parameter `TERM.NAME` at `x` that `out`
    /// requests (see [`Energy::add_parameter_derivatives`]).
    ///
    /// # Errors
    /// As [`Energy::add_parameter_derivatives`].
    pub fn add_parameter_derivatives(
        &mut self,
        x: &[Vector3<f64>],
        name: &str,
        out: &mut ParameterOutput,
    ) -> Result<(), EvalError> {
        check_same_vertex_count(self.n_vertices, x.len())?;
        let (i, own) = self.find_parameter(name)?;
        self.terms[i].add_parameter_derivatives(x, &own, out)
    }

    /// Convenience: evaluates into fresh buffers.
    ///
    /// # Errors
    /// As [`System::evaluate_into`].
    pub fn evaluate(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        par: Parallelism,
    ) -> Result<SystemEvaluation, EvalError> {
        let mut out = self.new_output();
        self.evaluate_into(x, request, par, &mut out)?;
        Ok(out)
    }
}

/// Whether every value is finite. A value is NaN or infinite exactly when its exponent bits are all ones;
/// adding one to that field then carries into the sign bit, so OR-ing `(bits & EXP) + (1 << 52)` over the
/// slice and testing the sign bit decides it with integer operations only, which vectorize (a float
/// reduction such as `Σ v·0` is one dependent add per value).
pub(crate) fn all_finite(values: &[f64]) -> bool {
    const EXP: u64 = 0x7ff0_0000_0000_0000;
    let carry = values
        .iter()
        .fold(0u64, |acc, v| acc | ((v.to_bits() & EXP) + (1 << 52)));
    carry & (1 << 63) == 0
}

#[cfg(test)]
mod tests {
    use super::all_finite;

    #[test]
    fn all_finite_finds_every_non_finite_value_and_accepts_every_finite_one() {
        let finite = [
            0.0,
            -0.0,
            1.0,
            -2.5,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            f64::MIN_POSITIVE / 4.0, // subnormal
            -f64::from_bits(1),
            f64::EPSILON,
        ];
        assert!(all_finite(&finite));
        assert!(all_finite(&[]));
        let bad = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
            f64::from_bits(0x7ff0_0000_0000_0001), // signalling NaN payload
            f64::from_bits(0xfff8_dead_beef_0000),
        ];
        for len in 1..=17 {
            for at in 0..len {
                for &b in &bad {
                    let mut v: Vec<f64> = (0..len).map(|k| finite[k % finite.len()]).collect();
                    v[at] = b;
                    assert!(!all_finite(&v), "{b:e} at {at} of {len}");
                    assert_eq!(all_finite(&v), v.iter().all(|x| x.is_finite()));
                }
            }
        }
    }
}
