//! # hinge-macros
//!
//! `#[derive(HingeEnergy)]`: declare a hinge bending energy ψ(θ) as a struct of constants plus an expression,
//! and get an implementation of `hinge_core::psi::HingePsi` with ψ′ and ψ″ derived symbolically at compile
//! time. Use it through `hinge_core::HingeEnergy`; the documentation with examples lives in hinge-core.
//!
//! The macro parses the expression (every unsupported construct is an error with its span, all reported at
//! once) with the language of `hinge-symbolic` — the same one hinge-core's run-time ψ parses from strings —,
//! builds it in a hash-consed arena (equal subexpressions become one node), differentiates twice with
//! simplification (constant folding, 0/1 identities, like terms), hoists every θ-free subexpression into the
//! per-hinge parameters (rest-dependent ones computed at set-up, step-dependent ones once per step) and emits
//! straight-line code for ψ, ψ′, ψ″ with the common subexpressions shared. It never panics on user input.

#![deny(missing_docs)]

mod expand;
mod parse;

use proc_macro::TokenStream;

/// Derives `hinge_core::psi::HingePsi` from `#[psi(EXPR)]` (symbolic ψ′, ψ″) or `#[psi(autodiff)]` (ψ′, ψ″
/// by num-dual from a generic `psi` method you write). See hinge-core's crate documentation.
#[proc_macro_derive(HingeEnergy, attributes(psi, per_hinge))]
pub fn derive_hinge_energy(input: TokenStream) -> TokenStream {
    let input = syn::parse_macro_input!(input as syn::DeriveInput);
    expand::derive(&input).into()
}
