//! ψ from a string at run time: the derive's language (same grammar, derivative rules and simplifier, from
//! `hinge-symbolic`), compiled into register programs instead of Rust code.
//!
//! ```
//! use hinge_core::psi::runtime::{ParamValue, RuntimePsi};
//! let psi = RuntimePsi::new("k * a * (theta - theta_bar).powi(2)", [("k", ParamValue::Scalar(1.5))])?;
//! # Ok::<(), hinge_core::psi::runtime::RuntimePsiError>(())
//! ```
//!
//! A [`RuntimePsi`] implements [`HingePsi`] like a derived energy: the θ-free subexpressions are hoisted into
//! per-hinge parameters at set-up (refreshed per step when they read `theta_prev` or `dt`), and ψ, (ψ, ψ′)
//! and (ψ, ψ′, ψ″) each run a straight-line register program with the common subexpressions shared. Nothing
//! is allocated per evaluation (the registers live on the stack). The programs perform the same operations
//! on the same operands as the code the derive generates for the same text, so the two agree bitwise.
//!
//! Parameters are named values, each a scalar or one value per hinge (in hinge order: the order of
//! [`crate::Topology::hinges`] for the rest mesh, which [`crate::topology::hinges`] gives before a model
//! exists). A parameter the expression does not read is an error, and so is a name it reads that is neither
//! a parameter nor `theta`, a provided name or a constant.
//!
//! The per-hinge parameter array has a fixed capacity `N` (the const parameter, default 8), so that it is
//! `Copy` and stored inline like a derived energy's: an expression that hoists more θ-free values is an
//! error for that `N` ([`RuntimePsiError::TooManyHoisted`]; use, say, `RuntimePsi::<32>`). The capacity
//! is memory streamed per hinge: measured on the 401² grid (`hinge bench`), a capacity of 16 made the
//! whole discrete-shells assembly 1.26× the derived one, 8 made it 1.04×.

use std::borrow::Cow;

use std::sync::{Arc, OnceLock};

use hinge_symbolic::program::{Compiled, Program, Scalar, Tape};
use hinge_symbolic::sym::Func;
use num_dual::DualNum;

use super::{HingePsi, HingeQuantities, PsiError, PsiParameter};

pub use hinge_symbolic::{Diagnostic, ParseError, Span};

/// The default capacity of hoisted θ-free values per hinge.
pub const DEFAULT_CAPACITY: usize = 8;

/// A parameter's value: one for all hinges, or one per hinge (hinge order).
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    /// The same value at every hinge.
    Scalar(f64),
    /// One value per hinge, in hinge order.
    PerHinge(Vec<f64>),
}

impl From<f64> for ParamValue {
    fn from(v: f64) -> Self {
        ParamValue::Scalar(v)
    }
}

impl From<Vec<f64>> for ParamValue {
    fn from(v: Vec<f64>) -> Self {
        ParamValue::PerHinge(v)
    }
}

/// Why a ψ string could not become an energy.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RuntimePsiError {
    /// The expression does not parse, or names something unknown.
    #[error("ψ expression: {0}")]
    Parse(#[from] ParseError),
    /// A parameter was given that the expression does not read.
    #[error("parameter `{name}` is not used by the ψ expression")]
    UnusedParameter {
        /// The parameter.
        name: String,
    },
    /// [`RuntimePsi::set_parameter`] with a name the energy does not have.
    #[error("the ψ expression has no parameter `{name}` (its parameters: {known})")]
    UnknownParameter {
        /// The name asked for.
        name: String,
        /// The parameters it has.
        known: String,
    },
    /// More hoisted values than the capacity `N` of this `RuntimePsi<N>`.
    #[error(
        "the ψ expression needs {count} θ-free values per hinge; this RuntimePsi holds {capacity} (use a larger capacity, RuntimePsi::<32>)"
    )]
    TooManyHoisted {
        /// How many it needs.
        count: usize,
        /// The capacity.
        capacity: usize,
    },
    /// A program would need more registers than supported.
    #[error("the ψ expression is too large to compile")]
    TooLarge,
}

/// A ψ(θ) compiled from a string, holding up to `N` hoisted values per hinge (see the module
/// documentation).
#[derive(Debug, Clone)]
pub struct RuntimePsi<const N: usize = DEFAULT_CAPACITY> {
    source: String,
    names: Vec<String>,
    values: Vec<ParamValue>,
    tape: Tape,
    d2_zero: bool,
    uses_step: bool,
    /// ψ, ψ′, ψ″ as compiled (kept for the parameter derivatives, compiled on first use).
    compiled: Arc<Compiled>,
    /// `∂ψ/∂p, ∂ψ′/∂p` for every parameter, then θ̄ (see [`HingePsi::parameter_derivatives`]); `None` inside
    /// when the program is too large.
    derivatives: OnceLock<Option<Program>>,
}

impl RuntimePsi {
    /// Compiles `expr` with the named parameters, with the default capacity of
    /// [`DEFAULT_CAPACITY`] hoisted values per hinge (see [`RuntimePsi::with_capacity`] for others).
    ///
    /// # Errors
    /// [`RuntimePsiError`]: parse errors (with columns), unused parameters, too many hoisted values.
    pub fn new<S: Into<String>>(
        expr: &str,
        params: impl IntoIterator<Item = (S, ParamValue)>,
    ) -> Result<Self, RuntimePsiError> {
        Self::with_capacity(expr, params)
    }
}

impl<const N: usize> RuntimePsi<N> {
    /// Compiles `expr` with the named parameters for a capacity of `N` hoisted values per hinge
    /// (`RuntimePsi::<32>::with_capacity(…)`).
    ///
    /// # Errors
    /// [`RuntimePsiError`]: parse errors (with columns), unused parameters, more than `N` hoisted values.
    pub fn with_capacity<S: Into<String>>(
        expr: &str,
        params: impl IntoIterator<Item = (S, ParamValue)>,
    ) -> Result<Self, RuntimePsiError> {
        let (names, values): (Vec<String>, Vec<ParamValue>) =
            params.into_iter().map(|(n, v)| (n.into(), v)).unzip();
        let src = hinge_symbolic::compile(expr, &names)?;
        if let Some(k) = src.used_inputs.iter().position(|u| !u) {
            return Err(RuntimePsiError::UnusedParameter {
                name: names[k].clone(),
            });
        }
        let c = &src.compiled;
        if c.hoisted.len() > N {
            return Err(RuntimePsiError::TooManyHoisted {
                count: c.hoisted.len(),
                capacity: N,
            });
        }
        let tape = Tape::new(c, N).ok_or(RuntimePsiError::TooLarge)?;
        Ok(Self {
            source: expr.to_string(),
            names,
            values,
            d2_zero: c.d2_is_zero(),
            uses_step: c.uses_step(),
            tape,
            compiled: Arc::new(src.compiled),
            derivatives: OnceLock::new(),
        })
    }

    /// The expression text.
    pub fn expression(&self) -> &str {
        &self.source
    }

    /// The parameters, in the order given.
    pub fn parameters(&self) -> impl Iterator<Item = (&str, &ParamValue)> {
        self.names.iter().map(String::as_str).zip(&self.values)
    }

    /// Replaces a parameter's value (a model built with this energy re-hoists through
    /// [`crate::bending::BendingModel::update_psi`]).
    ///
    /// # Errors
    /// [`RuntimePsiError::UnknownParameter`].
    pub fn set_parameter(&mut self, name: &str, value: ParamValue) -> Result<(), RuntimePsiError> {
        match self.names.iter().position(|n| n == name) {
            Some(k) => {
                self.values[k] = value;
                Ok(())
            }
            None => Err(RuntimePsiError::UnknownParameter {
                name: name.to_string(),
                known: if self.names.is_empty() {
                    "none".into()
                } else {
                    self.names.join(", ")
                },
            }),
        }
    }

    /// Hoisted θ-free values per hinge.
    pub fn hoisted(&self) -> usize {
        self.tape.n_params
    }
}

/// Whether `expr`, compiled with the parameters `names`, reads the parameter `name` (false when it does not
/// compile: [`RuntimePsi::new`] reports why).
pub fn reads_parameter(expr: &str, names: &[String], name: &str) -> bool {
    hinge_symbolic::compile(expr, names).is_ok_and(|s| {
        names
            .iter()
            .zip(&s.used_inputs)
            .any(|(n, &used)| used && n == name)
    })
}

/// `f64` inputs of the parameter program: the parameters at hinge `q.hinge`, then the provided names.
fn inputs(values: &[ParamValue], q: &HingeQuantities, buf: &mut [f64; 64]) -> usize {
    let mut n = 0;
    for v in values {
        buf[n] = match v {
            ParamValue::Scalar(x) => *x,
            ParamValue::PerHinge(xs) => xs.get(q.hinge).copied().unwrap_or(f64::NAN),
        };
        n += 1;
    }
    // The provided names in `hinge_symbolic::lower::PROVIDED` order (tested name by name in
    // tests/tests/runtime_psi.rs).
    for x in [
        q.theta_bar,
        q.a,
        q.rest_length,
        q.rest_area,
        q.theta_prev,
        q.dt,
    ] {
        buf[n] = x;
        n += 1;
    }
    n
}

impl<const N: usize> HingePsi for RuntimePsi<N> {
    type Params = [f64; N];
    // Known per value, through the methods below.
    const D2_IS_ZERO: bool = false;
    const USES_STEP: bool = true;

    fn second_derivative_vanishes(&self) -> bool {
        self.d2_zero
    }

    fn uses_step_quantities(&self) -> bool {
        self.uses_step
    }

    fn validate(&self, n_hinges: usize) -> Result<(), PsiError> {
        for (name, v) in self.parameters() {
            let bad = |message: String| PsiError {
                name: Cow::Owned(name.to_string()),
                message,
            };
            match v {
                ParamValue::Scalar(x) if !x.is_finite() => {
                    return Err(bad(format!("is not finite ({x})")));
                }
                ParamValue::PerHinge(xs) if xs.len() != n_hinges => {
                    return Err(bad(format!(
                        "has {} values but the mesh has {n_hinges} hinges",
                        xs.len()
                    )));
                }
                ParamValue::PerHinge(xs) => {
                    if let Some(i) = xs.iter().position(|x| !x.is_finite()) {
                        return Err(bad(format!("value of hinge {i} is not finite ({})", xs[i])));
                    }
                }
                ParamValue::Scalar(_) => {}
            }
        }
        Ok(())
    }

    fn params(&self, q: &HingeQuantities) -> Self::Params {
        let mut buf = [0.0; 64];
        let n = inputs(&self.values, q, &mut buf);
        let mut p = [0.0; N];
        self.tape
            .params
            .run(&buf[..n], &mut p[..self.tape.n_params]);
        p
    }

    #[inline]
    fn eval(&self, p: &Self::Params, theta: f64) -> [f64; 3] {
        let mut out = [0.0; 3];
        self.tape.full.run_theta(theta, p, &mut out);
        out
    }

    #[inline]
    fn value(&self, p: &Self::Params, theta: f64) -> f64 {
        let mut out = [0.0; 1];
        self.tape.value.run_theta(theta, p, &mut out);
        out[0]
    }

    #[inline]
    fn eval_d1(&self, p: &Self::Params, theta: f64) -> [f64; 2] {
        let mut out = [0.0; 2];
        self.tape.first.run_theta(theta, p, &mut out);
        out
    }

    fn has_parameter_derivatives(&self) -> bool {
        true
    }

    fn parameters(&self) -> Vec<PsiParameter> {
        self.parameters()
            .map(|(name, v)| PsiParameter {
                name: name.to_string(),
                per_hinge: matches!(v, ParamValue::PerHinge(_)),
            })
            .collect()
    }

    fn n_parameters(&self) -> usize {
        self.names.len()
    }

    fn parameter_derivatives(&self, q: &HingeQuantities, theta: f64, out: &mut [[f64; 2]]) -> bool {
        let n = self.names.len();
        if out.len() != n + 1 {
            return false;
        }
        let program = self.derivatives.get_or_init(|| {
            // The parameters are vars 0..n, θ̄ the first provided name after them.
            let vars: Vec<usize> = (0..=n).collect();
            self.compiled.parameter_derivatives(&vars).program()
        });
        let Some(program) = program else {
            return false;
        };
        let mut buf = [0.0; 65];
        buf[0] = theta;
        let mut vars = [0.0; 64];
        let k = inputs(&self.values, q, &mut vars);
        buf[1..=k].copy_from_slice(&vars[..k]);
        let mut flat = [0.0; 128];
        program.run(&buf[..=k], &mut flat[..2 * (n + 1)]);
        for (o, d) in out.iter_mut().zip(flat.chunks_exact(2)) {
            *o = [d[0], d[1]];
        }
        true
    }

    fn parameter_values(&self, index: usize) -> Option<Vec<f64>> {
        self.values.get(index).map(|v| match v {
            ParamValue::Scalar(x) => vec![*x],
            ParamValue::PerHinge(xs) => xs.clone(),
        })
    }

    fn set_parameter_values(&mut self, index: usize, values: &[f64]) -> Result<(), PsiError> {
        let Some(v) = self.values.get_mut(index) else {
            return Err(PsiError {
                name: format!("#{index}").into(),
                message: format!("the ψ expression has {} parameters", self.names.len()),
            });
        };
        match v {
            ParamValue::Scalar(x) => match values {
                [y] => *x = *y,
                _ => {
                    return Err(super::scalar_length_error(&self.names[index], values.len()));
                }
            },
            ParamValue::PerHinge(xs) => *xs = values.to_vec(),
        }
        Ok(())
    }

    fn psi_dual<D: DualNum<Primitive = f64> + Copy>(&self, p: &Self::Params, theta: D) -> D {
        let mut dp = [Dual(D::from(0.0)); N];
        for (d, &x) in dp.iter_mut().zip(p) {
            *d = Dual(D::from(x));
        }
        let mut out = [Dual(D::from(0.0)); 1];
        self.tape.value.run_theta(Dual(theta), &dp, &mut out);
        out[0].0
    }
}

/// A num-dual scalar as a program [`Scalar`].
#[derive(Clone, Copy)]
struct Dual<D>(D);

macro_rules! dual_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<D: DualNum<Primitive = f64> + Copy> std::ops::$tr for Dual<D> {
            type Output = Self;
            #[inline]
            fn $f(self, o: Self) -> Self {
                Dual(self.0 $op o.0)
            }
        }
    };
}
dual_op!(Add, add, +);
dual_op!(Sub, sub, -);
dual_op!(Mul, mul, *);
dual_op!(Div, div, /);

impl<D: DualNum<Primitive = f64> + Copy> std::ops::Neg for Dual<D> {
    type Output = Self;
    fn neg(self) -> Self {
        Dual(-self.0)
    }
}

impl<D: DualNum<Primitive = f64> + Copy> Scalar for Dual<D> {
    fn from_f64(v: f64) -> Self {
        Dual(D::from(v))
    }
    fn re(&self) -> f64 {
        self.0.re()
    }
    fn powi(self, n: i32) -> Self {
        Dual(self.0.powi(n))
    }
    fn powf(self, e: Self) -> Self {
        // θ-free exponent (the language's rule): its real part is all of it.
        Dual(self.0.powf(e.0.re()))
    }
    fn func(self, f: Func) -> Self {
        let x = self.0;
        Dual(match f {
            Func::Sqrt => x.sqrt(),
            Func::Sin => x.sin(),
            Func::Cos => x.cos(),
            Func::Tan => x.tan(),
            Func::Exp => x.exp(),
            Func::Ln => x.ln(),
            Func::Atan => x.atan(),
            Func::Tanh => x.tanh(),
            Func::Sinh => x.sinh(),
            Func::Cosh => x.cosh(),
        })
    }
    fn atan2(self, x: Self) -> Self {
        // θ-free operands only.
        Dual(D::from(self.0.re().atan2(x.0.re())))
    }
}
