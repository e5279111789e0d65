//! # hinge-symbolic
//!
//! The ψ expression language of hinge, shared by the `#[derive(HingeEnergy)]` macro (which turns it into
//! Rust code at compile time) and hinge-core's run-time ψ (which turns it into a register program): one
//! grammar, one set of derivative rules, one simplifier.
//!
//! - [`ast`]: the parse tree both front ends produce ([`text`] parses strings; the derive converts `syn`).
//! - [`lower`]: names, functions and the grammar's rules → a hash-consed [`sym::Arena`] (equal
//!   subexpressions are one node), every error collected with its span.
//! - [`sym`]: simplifying constructors and d/dθ.
//! - [`program`]: ψ′, ψ″, the θ-dependent schedule, the hoisted θ-free values, and the run-time [`Tape`].
//!
//! [`compile`] runs the whole chain on a string.
//!
//! ## Non-smooth points
//! `abs`, `min`, `max` and `if` differentiate branch-wise: at a switch point the derivatives are those of
//! the branch the condition selects there. `abs(x)` at `x = 0` takes `x`'s (the right derivative when `x`
//! increases with θ), `min(a, b)` and `max(a, b)` at `a = b` take `a`'s, and `if l < r { A } else { B }`
//! takes `B`'s at `l = r` (`A`'s for `<=`).

#![deny(missing_docs)]
// Float comparisons in guards (`Some(x) if x == 0.0`) read as the algebra they implement.
#![allow(clippy::redundant_guards)]

pub mod ast;
pub mod lower;
pub mod program;
pub mod sym;
pub mod text;

use std::fmt;

pub use program::{Compiled, ParameterDerivatives, Program, Scalar, Tape};
pub use text::{Diagnostic, Span};

/// A ψ string that did not compile: every error found, in source order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParseError {
    /// Problems with the parameter names themselves (shadowing, repeats): not located in the string.
    pub parameters: Vec<String>,
    /// The errors in the string (a syntax error stops at the first; name errors are all reported).
    pub diagnostics: Vec<Diagnostic>,
    /// Whether the supported list is appended (an unknown function or method was used).
    pub show_supported: bool,
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut first = true;
        for m in &self.parameters {
            write!(f, "{}{m}", if first { "" } else { "; " })?;
            first = false;
        }
        for d in &self.diagnostics {
            write!(f, "{}{d}", if first { "" } else { "; " })?;
            first = false;
        }
        if self.show_supported {
            write!(f, " ({})", lower::SUPPORTED)?;
        }
        Ok(())
    }
}

impl std::error::Error for ParseError {}

/// A compiled ψ string.
#[derive(Clone, Debug)]
pub struct Source {
    /// ψ, ψ′, ψ″, scheduled.
    pub compiled: Compiled,
    /// For each of the caller's inputs, whether the expression reads it.
    pub used_inputs: Vec<bool>,
}

/// Parses `src` with the named inputs (run-time parameters), lowers it and differentiates it.
///
/// # Errors
/// [`ParseError`] with the column of every problem.
pub fn compile(src: &str, inputs: &[String]) -> Result<Source, ParseError> {
    let mut parameters = Vec::new();
    for (k, name) in inputs.iter().enumerate() {
        if let Some(what) = lower::reserved(name) {
            parameters.push(format!("parameter `{name}` shadows {what}; rename it"));
        } else if inputs[..k].contains(name) {
            parameters.push(format!("parameter `{name}` is given twice"));
        }
    }
    if inputs.len() + lower::PROVIDED.len() > 63 {
        parameters.push(format!(
            "{} parameters: at most 57 are supported",
            inputs.len()
        ));
        return Err(ParseError {
            parameters,
            diagnostics: Vec::new(),
            show_supported: false,
        });
    }
    let expr = text::parse(src).map_err(|d| ParseError {
        parameters: parameters.clone(),
        diagnostics: vec![d],
        show_supported: false,
    })?;
    let mut arena = sym::Arena::default();
    let mut low = lower::Lowerer::new(&mut arena, inputs);
    low.inputs_are = "the parameters given";
    let psi = low.expr(&expr);
    let show_supported = low.errors.iter().any(|e| e.wants_supported_list);
    let used = low.used.clone();
    let diagnostics: Vec<Diagnostic> = low
        .errors
        .drain(..)
        .map(|e| Diagnostic {
            span: e.span,
            message: e.message,
        })
        .collect();
    if !diagnostics.is_empty() || !parameters.is_empty() {
        return Err(ParseError {
            parameters,
            diagnostics,
            show_supported,
        });
    }
    Ok(Source {
        compiled: Compiled::new(arena, psi, inputs.len()),
        used_inputs: used[..inputs.len()].to_vec(),
    })
}
