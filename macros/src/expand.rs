//! Struct parsing, validation and code generation.

use std::collections::HashMap;

use proc_macro2::{Literal, TokenStream};
use quote::{format_ident, quote, quote_spanned};
use syn::spanned::Spanned;
use syn::{Data, DeriveInput, Fields, Type};

use hinge_symbolic::Compiled;
use hinge_symbolic::ast::Cmp;
use hinge_symbolic::lower::{Lowerer, PROVIDED, SUPPORTED, reserved};
use hinge_symbolic::sym::{Arena, Id, Node};

struct Field {
    ident: syn::Ident,
    per_hinge: bool,
}

enum Mode {
    Expr(syn::Expr),
    Autodiff,
}

pub fn derive(input: &DeriveInput) -> TokenStream {
    let mut errors: Vec<syn::Error> = Vec::new();
    let name = &input.ident;
    if !input.generics.params.is_empty() {
        errors.push(syn::Error::new(
            input.generics.span(),
            "HingeEnergy does not support generic structs",
        ));
    }
    let fields = match &input.data {
        Data::Struct(s) => match &s.fields {
            Fields::Named(named) => named.named.iter().collect::<Vec<_>>(),
            Fields::Unit => Vec::new(),
            Fields::Unnamed(u) => {
                errors.push(syn::Error::new(
                    u.span(),
                    "HingeEnergy needs named fields (or none)",
                ));
                Vec::new()
            }
        },
        _ => {
            errors.push(syn::Error::new(
                name.span(),
                "HingeEnergy can only be derived for structs",
            ));
            Vec::new()
        }
    };
    let mut parsed_fields = Vec::new();
    for f in fields {
        let per_hinge = f.attrs.iter().any(|a| a.path().is_ident("per_hinge"));
        let Some(ident) = f.ident.clone() else {
            continue;
        };
        let ok = if per_hinge {
            is_vec_f64(&f.ty)
        } else {
            is_f64(&f.ty)
        };
        if !ok {
            let want = if per_hinge {
                "`Vec<f64>` (one value per hinge)"
            } else {
                "`f64` (mark per-hinge values `#[per_hinge]` with type `Vec<f64>`)"
            };
            errors.push(syn::Error::new(
                f.ty.span(),
                format!("field `{ident}` of a HingeEnergy must have type {want}"),
            ));
        }
        if let Some(what) = reserved(&ident.to_string()) {
            errors.push(syn::Error::new(
                ident.span(),
                format!("field `{ident}` shadows {what} of the ψ expression language; rename it"),
            ));
        }
        parsed_fields.push(Field { ident, per_hinge });
    }
    let mut mode = None;
    for attr in input.attrs.iter().filter(|a| a.path().is_ident("psi")) {
        if mode.is_some() {
            errors.push(syn::Error::new(
                attr.span(),
                "only one #[psi(...)] attribute is allowed",
            ));
            continue;
        }
        match attr.parse_args::<syn::Expr>() {
            Ok(syn::Expr::Path(p)) if p.path.is_ident("autodiff") => mode = Some(Mode::Autodiff),
            Ok(e) => mode = Some(Mode::Expr(e)),
            Err(e) => errors.push(e),
        }
    }
    if mode.is_none() && errors.is_empty() {
        errors.push(syn::Error::new(
            name.span(),
            "missing #[psi(EXPR)] attribute: write the energy as an expression of `theta`, for example \
             #[psi(k * a * (theta - theta_bar).powi(2))], or #[psi(autodiff)] with a generic `psi` method",
        ));
    }
    let validate = validate_fn(&parsed_fields);
    // The expression is checked even when a field is wrong, so that every error shows at once.
    let body = match mode {
        Some(Mode::Expr(e)) => expr_impl(&e, &parsed_fields, &mut errors),
        Some(Mode::Autodiff) if errors.is_empty() => Some(autodiff_impl()),
        _ => None,
    };
    match body {
        Some(body) if errors.is_empty() => quote! {
            #[automatically_derived]
            impl ::hinge_core::__private::HingePsi for #name {
                #validate
                #body
            }
        },
        _ => fallback(name, errors),
    }
}

/// On error: the errors, plus an impl that keeps the rest of the user's crate from piling up follow-on errors.
fn fallback(name: &syn::Ident, errors: Vec<syn::Error>) -> TokenStream {
    let errs = errors.iter().map(syn::Error::to_compile_error);
    quote! {
        #(#errs)*
        #[automatically_derived]
        impl ::hinge_core::__private::HingePsi for #name {
            type Params = ();
            fn params(&self, _: &::hinge_core::__private::HingeQuantities) {}
            fn eval(&self, _: &(), _: f64) -> [f64; 3] { [0.0; 3] }
            fn psi_dual<D: ::hinge_core::__private::DualNum<Primitive = f64> + ::core::marker::Copy>(&self, _: &(), t: D) -> D { t }
        }
    }
}

fn is_f64(ty: &Type) -> bool {
    matches!(ty, Type::Path(p) if p.qself.is_none() && p.path.is_ident("f64"))
}

fn is_vec_f64(ty: &Type) -> bool {
    let Type::Path(p) = ty else { return false };
    let Some(seg) = p.path.segments.last() else {
        return false;
    };
    if seg.ident != "Vec" {
        return false;
    }
    match &seg.arguments {
        syn::PathArguments::AngleBracketed(a) if a.args.len() == 1 => {
            matches!(a.args.first(), Some(syn::GenericArgument::Type(t)) if is_f64(t))
        }
        _ => false,
    }
}

fn validate_fn(fields: &[Field]) -> TokenStream {
    let checks = fields.iter().map(|f| {
        let id = &f.ident;
        let lit = id.to_string();
        if f.per_hinge {
            quote! {
                if self.#id.len() != n_hinges {
                    return ::core::result::Result::Err(::hinge_core::__private::PsiError {
                        name: ::std::borrow::Cow::Borrowed(#lit),
                        message: ::std::format!("has {} values but the mesh has {} hinges", self.#id.len(), n_hinges),
                    });
                }
                if let ::core::option::Option::Some(i) = self.#id.iter().position(|v| !v.is_finite()) {
                    return ::core::result::Result::Err(::hinge_core::__private::PsiError {
                        name: ::std::borrow::Cow::Borrowed(#lit),
                        message: ::std::format!("value of hinge {} is not finite ({})", i, self.#id[i]),
                    });
                }
            }
        } else {
            quote! {
                if !self.#id.is_finite() {
                    return ::core::result::Result::Err(::hinge_core::__private::PsiError {
                        name: ::std::borrow::Cow::Borrowed(#lit),
                        message: ::std::format!("is not finite ({})", self.#id),
                    });
                }
            }
        }
    });
    quote! {
        fn validate(&self, n_hinges: usize) -> ::core::result::Result<(), ::hinge_core::__private::PsiError> {
            let _ = n_hinges;
            #(#checks)*
            ::core::result::Result::Ok(())
        }
    }
}

fn autodiff_impl() -> TokenStream {
    quote! {
        type Params = ::hinge_core::__private::HingeQuantities;
        const USES_STEP: bool = true;
        fn params(&self, q: &::hinge_core::__private::HingeQuantities) -> Self::Params {
            *q
        }
        #[inline]
        fn eval(&self, p: &Self::Params, theta: f64) -> [f64; 3] {
            let (f, d1, d2) = ::hinge_core::__private::num_dual::second_derivative(|t| self.psi(p, t), theta);
            [f, d1, d2]
        }
        fn psi_dual<D: ::hinge_core::__private::DualNum<Primitive = f64> + ::core::marker::Copy>(&self, p: &Self::Params, theta: D) -> D {
            self.psi(p, theta)
        }
    }
}

fn lit(c: f64) -> TokenStream {
    if c.is_nan() {
        quote!(f64::NAN)
    } else if c == f64::INFINITY {
        quote!(f64::INFINITY)
    } else if c == f64::NEG_INFINITY {
        quote!(f64::NEG_INFINITY)
    } else {
        let l = Literal::f64_suffixed(c);
        quote!(#l)
    }
}

fn expr_impl(e: &syn::Expr, fields: &[Field], errors: &mut Vec<syn::Error>) -> Option<TokenStream> {
    let names: Vec<String> = fields.iter().map(|f| f.ident.to_string()).collect();
    let mut found = Vec::new();
    let tree = crate::parse::convert(e, &mut found);
    let mut arena = Arena::default();
    let psi = {
        let mut low = Lowerer::new(&mut arena, &names);
        low.inputs_are = "the struct's fields";
        let id = low.expr(&tree);
        found.extend(
            low.errors
                .drain(..)
                .map(|x| (x.span, x.message, x.wants_supported_list)),
        );
        id
    };
    // The supported list once per expression, with the first error it helps.
    let mut listed = false;
    for (span, msg, wants) in found {
        let msg = if wants && !listed {
            listed = true;
            format!("{msg}; {SUPPORTED}")
        } else {
            msg
        };
        errors.push(syn::Error::new(span, msg));
    }
    if !errors.is_empty() {
        return None;
    }
    if names.len() + PROVIDED.len() > 63 {
        errors.push(syn::Error::new(
            e.span(),
            "too many fields for a HingeEnergy (at most 57)",
        ));
        return None;
    }
    let compiled = Compiled::new(arena, psi, names.len());
    let arena = &compiled.arena;
    let roots = compiled.roots;
    let [psi, d1, _] = roots;
    let (order, hoisted) = (&compiled.order, &compiled.hoisted);
    let slot: HashMap<Id, usize> = hoisted.iter().enumerate().map(|(k, &id)| (id, k)).collect();
    let uses_step = compiled.uses_step();
    let used_vars = compiled.used_vars();

    // θ-free code (params): vars as locals, nested expressions.
    fn free(arena: &Arena, id: Id) -> TokenStream {
        let node = arena.node(id);
        match node {
            Node::Const(c) => lit(c),
            Node::Var(i) => {
                let v = format_ident!("v{}", i);
                quote!(#v)
            }
            Node::Theta => quote!(0.0_f64), // unreachable: θ-free by construction
            Node::Add(a, b) => bin(free(arena, a), quote!(+), free(arena, b)),
            Node::Sub(a, b) => bin(free(arena, a), quote!(-), free(arena, b)),
            Node::Mul(a, b) => bin(free(arena, a), quote!(*), free(arena, b)),
            Node::Div(a, b) => bin(free(arena, a), quote!(/), free(arena, b)),
            Node::Neg(a) => {
                let x = free(arena, a);
                quote!((-#x))
            }
            Node::Powi(a, n) => {
                let x = free(arena, a);
                quote!((#x).powi(#n))
            }
            Node::Powf(a, b) => {
                let (x, y) = (free(arena, a), free(arena, b));
                quote!((#x).powf(#y))
            }
            Node::Call(f, a) => {
                let x = free(arena, a);
                let m = format_ident!("{}", f.name());
                quote!((#x).#m())
            }
            Node::Atan2(a, b) => {
                let (y, x) = (free(arena, a), free(arena, b));
                quote!((#y).atan2(#x))
            }
            Node::Select(c, l, r, a, b) => {
                let op = cmp_tokens(c);
                let (l, r) = (free(arena, l), free(arena, r));
                let (a, b) = (free(arena, a), free(arena, b));
                quote!((if #l #op #r { #a } else { #b }))
            }
        }
    }
    let var_lets = var_lets(fields, used_vars);
    let k = hoisted.len();
    let hoisted_exprs: Vec<TokenStream> = hoisted.iter().map(|&h| free(arena, h)).collect();
    let step_updates: Vec<TokenStream> = hoisted
        .iter()
        .enumerate()
        .filter(|(_, h)| compiled.reads_step(**h))
        .map(|(i, &h)| {
            let x = free(arena, h);
            quote!(p[#i] = #x;)
        })
        .collect();

    // θ-dependent code (eval): one `let` per node, operands by reference.
    let operand = |id: Id| -> TokenStream {
        if let Some(c) = arena.as_const(id) {
            lit(c)
        } else if let Some(&s) = slot.get(&id) {
            quote!(p[#s])
        } else {
            let t = format_ident!("t{}", id.0);
            quote!(#t)
        }
    };
    let op_code = |id: Id, operand: &dyn Fn(Id) -> TokenStream| -> TokenStream {
        node_code(arena, id, operand)
    };
    let lets: Vec<TokenStream> = order
        .iter()
        .map(|&id| {
            let t = format_ident!("t{}", id.0);
            let code = op_code(id, &operand);
            quote!(let #t: f64 = #code;)
        })
        .collect();
    let outs: Vec<TokenStream> = roots.iter().map(|&r| operand(r)).collect();
    // Energy-only and gradient-only programs: the same nodes' code, scheduled from fewer roots (their θ-free
    // nodes are a subset of the hoisted ones), so ψ and ψ′ are bitwise those of `eval`.
    let lets_for = |roots: &[Id]| -> Vec<TokenStream> {
        compiled
            .order_for(roots)
            .iter()
            .map(|&id| {
                let t = format_ident!("t{}", id.0);
                let code = op_code(id, &operand);
                quote!(let #t: f64 = #code;)
            })
            .collect()
    };
    let lets_value = lets_for(&[psi]);
    let lets_d1 = lets_for(&[psi, d1]);
    let (out_psi, out_d1) = (operand(psi), operand(d1));
    let d2_zero = compiled.d2_is_zero();
    let parameters = parameter_methods(&compiled, fields);

    // Generic ψ for num-dual (ψ root only), θ-dependent nodes as D, θ-free ones as f64.
    let dual_order = compiled.order_for(&[psi]);
    let dual_operand = |id: Id| -> (TokenStream, bool) {
        if let Some(c) = arena.as_const(id) {
            (lit(c), false)
        } else if let Some(&s) = slot.get(&id) {
            (quote!(p[#s]), false)
        } else {
            let t = format_ident!("t{}", id.0);
            (quote!(#t), true)
        }
    };
    let dual_lets: Vec<TokenStream> = dual_order
        .iter()
        .map(|&id| {
            let t = format_ident!("t{}", id.0);
            let mix = |a: Id, b: Id, op: TokenStream, commutes: bool| -> TokenStream {
                let ((x, xd), (y, yd)) = (dual_operand(a), dual_operand(b));
                match (xd, yd) {
                    (true, _) => quote!((#x #op #y)),
                    (false, true) if commutes => quote!((#y #op #x)),
                    (false, true) => quote!((D::from(#x) #op #y)),
                    (false, false) => quote!(D::from(#x #op #y)),
                }
            };
            let code = match arena.node(id) {
                Node::Theta => quote!(theta),
                Node::Add(a, b) => mix(a, b, quote!(+), true),
                Node::Sub(a, b) => mix(a, b, quote!(-), false),
                Node::Mul(a, b) => mix(a, b, quote!(*), true),
                Node::Div(a, b) => mix(a, b, quote!(/), false),
                Node::Neg(a) => {
                    let (x, _) = dual_operand(a);
                    quote!((-#x))
                }
                Node::Powi(a, n) => {
                    let (x, _) = dual_operand(a);
                    quote!((#x).powi(#n))
                }
                Node::Powf(a, b) => {
                    let ((x, _), (y, _)) = (dual_operand(a), dual_operand(b));
                    quote!((#x).powf(#y))
                }
                Node::Call(f, a) => {
                    let (x, _) = dual_operand(a);
                    let m = format_ident!("{}", f.name());
                    quote!((#x).#m())
                }
                // θ-free: hoisted, never scheduled here.
                Node::Atan2(..) => quote!(D::from(f64::NAN)),
                Node::Select(c, l, r, a, b) => {
                    let op = cmp_tokens(c);
                    let re = |id: Id| match dual_operand(id) {
                        (x, true) => quote!((#x).re()),
                        (x, false) => x,
                    };
                    let as_dual = |id: Id| match dual_operand(id) {
                        (x, true) => x,
                        (x, false) => quote!(D::from(#x)),
                    };
                    let (l, r, a, b) = (re(l), re(r), as_dual(a), as_dual(b));
                    quote!((if #l #op #r { #a } else { #b }))
                }
                Node::Const(c) => {
                    let l = lit(c);
                    quote!(D::from(#l))
                }
                Node::Var(_) => quote!(D::from(0.0)),
            };
            quote!(let #t: D = #code;)
        })
        .collect();
    let dual_result = match dual_operand(psi) {
        (x, true) => x,
        (x, false) => quote!(D::from(#x)),
    };
    let update = if uses_step {
        quote! {
            fn update_step(&self, q: &::hinge_core::__private::HingeQuantities, p: &mut Self::Params) {
                #(#var_lets)*
                #(#step_updates)*
            }
        }
    } else {
        quote!()
    };
    let span = e.span();
    Some(quote_spanned! {span=>
        type Params = [f64; #k];
        const D2_IS_ZERO: bool = #d2_zero;
        const USES_STEP: bool = #uses_step;
        #[allow(unused_variables)]
        fn params(&self, q: &::hinge_core::__private::HingeQuantities) -> Self::Params {
            #(#var_lets)*
            [#(#hoisted_exprs),*]
        }
        #update
        #[inline]
        #[allow(unused_variables, clippy::all)]
        fn eval(&self, p: &Self::Params, theta: f64) -> [f64; 3] {
            #(#lets)*
            [#(#outs),*]
        }
        #[inline]
        #[allow(unused_variables, clippy::all)]
        fn value(&self, p: &Self::Params, theta: f64) -> f64 {
            #(#lets_value)*
            #out_psi
        }
        #[inline]
        #[allow(unused_variables, clippy::all)]
        fn eval_d1(&self, p: &Self::Params, theta: f64) -> [f64; 2] {
            #(#lets_d1)*
            [#out_psi, #out_d1]
        }
        #[allow(unused_variables, clippy::all)]
        fn psi_dual<D: ::hinge_core::__private::DualNum<Primitive = f64> + ::core::marker::Copy>(&self, p: &Self::Params, theta: D) -> D {
            #(#dual_lets)*
            #dual_result
        }
        #parameters
    })
}

/// `let vI: f64 = …;` for every variable in the bit set `used`: fields (`self.f`, or hinge `q.hinge`'s entry
/// of a per-hinge field), then the provided names (`q.theta_bar`, …).
fn var_lets(fields: &[Field], used: u64) -> Vec<TokenStream> {
    let n_fields = fields.len();
    (0..n_fields + PROVIDED.len())
        .filter(|i| used >> i & 1 == 1)
        .map(|i| {
            let v = format_ident!("v{}", i);
            if i < n_fields {
                let f = &fields[i].ident;
                if fields[i].per_hinge {
                    quote!(let #v: f64 = self.#f.get(q.hinge).copied().unwrap_or(f64::NAN);)
                } else {
                    quote!(let #v: f64 = self.#f;)
                }
            } else {
                let p = format_ident!("{}", PROVIDED[i - n_fields]);
                quote!(let #v: f64 = q.#p;)
            }
        })
        .collect()
}

/// The code of one scheduled node, its operands spelled by `operand`.
fn node_code(arena: &Arena, id: Id, operand: &dyn Fn(Id) -> TokenStream) -> TokenStream {
    match arena.node(id) {
        Node::Theta => quote!(theta),
        Node::Add(a, b) => bin(operand(a), quote!(+), operand(b)),
        Node::Sub(a, b) => bin(operand(a), quote!(-), operand(b)),
        Node::Mul(a, b) => bin(operand(a), quote!(*), operand(b)),
        Node::Div(a, b) => bin(operand(a), quote!(/), operand(b)),
        Node::Neg(a) => {
            let x = operand(a);
            quote!((-#x))
        }
        Node::Powi(a, 2) => {
            let x = operand(a);
            quote!((#x * #x))
        }
        Node::Powi(a, n) => {
            let x = operand(a);
            quote!((#x).powi(#n))
        }
        Node::Powf(a, b) => {
            let (x, y) = (operand(a), operand(b));
            quote!((#x).powf(#y))
        }
        Node::Call(f, a) => {
            let x = operand(a);
            let m = format_ident!("{}", f.name());
            quote!((#x).#m())
        }
        Node::Atan2(a, b) => {
            let (y, x) = (operand(a), operand(b));
            quote!((#y).atan2(#x))
        }
        Node::Select(c, l, r, a, b) => {
            let op = cmp_tokens(c);
            let (l, r, a, b) = (operand(l), operand(r), operand(a), operand(b));
            quote!((if #l #op #r { #a } else { #b }))
        }
        Node::Const(c) => lit(c),
        Node::Var(_) => operand(id),
    }
}

/// The parameter-derivative methods of [`HingePsi`](hinge_core::psi::HingePsi): `∂ψ/∂p`, `∂ψ′/∂p` for every
/// field and for θ̄, computed from the fields and the hinge's quantities (nothing hoisted), and the field
/// getters and setters fitting uses.
fn parameter_methods(compiled: &Compiled, fields: &[Field]) -> TokenStream {
    let n_fields = fields.len();
    let vars: Vec<usize> = (0..=n_fields).collect();
    let pd = compiled.parameter_derivatives(&vars);
    let arena = &pd.arena;
    let operand = |id: Id| -> TokenStream {
        match arena.node(id) {
            Node::Const(c) => lit(c),
            Node::Theta => quote!(theta),
            Node::Var(i) => {
                let v = format_ident!("v{}", i);
                quote!(#v)
            }
            _ => {
                let t = format_ident!("t{}", id.0);
                quote!(#t)
            }
        }
    };
    let used = pd.used_vars();
    let var_lets = var_lets(fields, used);
    let lets: Vec<TokenStream> = pd
        .order
        .iter()
        .map(|&id| {
            let t = format_ident!("t{}", id.0);
            let code = node_code(arena, id, &operand);
            quote!(let #t: f64 = #code;)
        })
        .collect();
    let outs: Vec<TokenStream> = pd
        .roots
        .iter()
        .enumerate()
        .map(|(k, [a, b])| {
            let (a, b) = (operand(*a), operand(*b));
            quote!(out[#k] = [#a, #b];)
        })
        .collect();
    let len = n_fields + 1;
    let infos: Vec<TokenStream> = fields
        .iter()
        .map(|f| {
            let name = f.ident.to_string();
            let per_hinge = f.per_hinge;
            quote!(::hinge_core::__private::PsiParameter { name: #name.to_string(), per_hinge: #per_hinge })
        })
        .collect();
    let getters: Vec<TokenStream> = fields
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let id = &f.ident;
            if f.per_hinge {
                quote!(#k => ::core::option::Option::Some(self.#id.clone()),)
            } else {
                quote!(#k => ::core::option::Option::Some(::std::vec![self.#id]),)
            }
        })
        .collect();
    let setters: Vec<TokenStream> = fields
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let id = &f.ident;
            let name = id.to_string();
            if f.per_hinge {
                quote!(#k => { self.#id = values.to_vec(); ::core::result::Result::Ok(()) })
            } else {
                quote!(#k => match values {
                    [v] => { self.#id = *v; ::core::result::Result::Ok(()) }
                    _ => ::core::result::Result::Err(::hinge_core::__private::scalar_length_error(#name, values.len())),
                })
            }
        })
        .collect();
    quote! {
        fn has_parameter_derivatives(&self) -> bool {
            true
        }
        fn parameters(&self) -> ::std::vec::Vec<::hinge_core::__private::PsiParameter> {
            ::std::vec![#(#infos),*]
        }
        fn n_parameters(&self) -> usize {
            #n_fields
        }
        #[allow(unused_variables, clippy::all)]
        fn parameter_derivatives(&self, q: &::hinge_core::__private::HingeQuantities, theta: f64, out: &mut [[f64; 2]]) -> bool {
            if out.len() != #len {
                return false;
            }
            #(#var_lets)*
            #(#lets)*
            #(#outs)*
            true
        }
        fn parameter_values(&self, index: usize) -> ::core::option::Option<::std::vec::Vec<f64>> {
            match index {
                #(#getters)*
                _ => ::core::option::Option::None,
            }
        }
        fn set_parameter_values(&mut self, index: usize, values: &[f64]) -> ::core::result::Result<(), ::hinge_core::__private::PsiError> {
            match index {
                #(#setters)*
                _ => ::core::result::Result::Err(::hinge_core::__private::PsiError {
                    name: ::std::format!("#{index}").into(),
                    message: ::std::format!("the energy has {} parameters", #n_fields),
                }),
            }
        }
    }
}

fn cmp_tokens(c: Cmp) -> TokenStream {
    match c {
        Cmp::Lt => quote!(<),
        Cmp::Le => quote!(<=),
        Cmp::Gt => quote!(>),
        Cmp::Ge => quote!(>=),
    }
}

fn bin(a: TokenStream, op: TokenStream, b: TokenStream) -> TokenStream {
    quote!((#a #op #b))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn expand(src: &str) -> String {
        let input: DeriveInput = syn::parse_str(src).expect("test input parses");
        derive(&input).to_string()
    }

    #[test]
    fn tan_bending_expansion_hoists_theta_free_parts() {
        let out = expand(
            "#[psi(k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2))] struct T { k: f64 }",
        );
        println!("{out}");
        // k·a and 2 tan(θ̄/2) are θ-free: computed in params, not in eval.
        let eval = &out[out.find("fn eval").expect("eval")..out.find("fn value").expect("value")];
        // The energy-only program computes ψ alone: one tan, no ψ′ terms (tan² + 1).
        let value =
            &out[out.find("fn value").expect("value")..out.find("fn eval_d1").expect("eval_d1")];
        assert_eq!(value.matches(". tan ()").count(), 1, "{value}");
        assert!(
            !value.contains("+ 1f64"),
            "no ψ′ in the value program: {value}"
        );
        assert!(!eval.contains("v0"), "fields are not read in eval: {eval}");
        assert_eq!(
            eval.matches(". tan ()").count(),
            1,
            "one tan per evaluation: {eval}"
        );
        assert!(out.contains("const D2_IS_ZERO : bool = false"));
    }

    #[test]
    fn affine_energy_has_zero_second_derivative() {
        let out = expand("#[psi(k * (theta - theta_bar))] struct T { k: f64 }");
        assert!(out.contains("const D2_IS_ZERO : bool = true"), "{out}");
    }

    #[test]
    fn step_quantities_are_refreshed_per_step() {
        let out = expand("#[psi(c / dt * a * (theta - theta_prev).powi(2))] struct T { c: f64 }");
        assert!(out.contains("const USES_STEP : bool = true"), "{out}");
        assert!(out.contains("fn update_step"), "{out}");
    }

    #[test]
    fn all_errors_are_reported_at_once() {
        let out = expand("#[psi(foo * theta.bar() + theta.powf(theta))] struct T { k: f64 }");
        assert!(out.contains("unknown identifier `foo`"), "{out}");
        assert!(out.contains("unknown method `bar`"), "{out}");
        assert!(out.contains("must not depend on `theta`"), "{out}");
    }

    #[test]
    fn supported_list_once_and_did_you_mean() {
        let out = expand("#[psi(k * theta.sinn() + theta.cosss() + tehta)] struct T { k: f64 }");
        assert!(
            out.contains("unknown method `sinn` (did you mean `sin`?)"),
            "{out}"
        );
        assert!(
            out.contains("unknown method `cosss` (did you mean `cos`?)"),
            "{out}"
        );
        assert!(
            out.contains("unknown identifier `tehta` (did you mean `theta`?)"),
            "{out}"
        );
        assert_eq!(out.matches("supported: numbers").count(), 1, "{out}");
    }

    #[test]
    fn expression_errors_show_beside_field_type_errors() {
        let out = expand("#[psi(k * theta.sinn())] struct T { k: f32 }");
        assert!(out.contains("must have type"), "{out}");
        assert!(out.contains("unknown method `sinn`"), "{out}");
    }

    #[test]
    fn fields_may_not_shadow_constants_or_provided_names() {
        for f in ["PI", "E", "theta_bar", "theta"] {
            let out = expand(&format!("#[psi({f} * theta)] struct T {{ {f}: f64 }}"));
            assert!(out.contains(&format!("field `{f}` shadows")), "{out}");
        }
    }

    #[test]
    fn deep_nesting_is_an_error_not_a_stack_overflow() {
        // rustc runs proc macros on its 8 MiB main-thread stack; syn's own parser needs it for this input.
        let out = std::thread::Builder::new()
            .stack_size(8 << 20)
            .spawn(|| {
                let deep = format!("{}theta{}", "(1.0 + ".repeat(300), ")".repeat(300));
                expand(&format!("#[psi({deep})] struct T {{}}"))
            })
            .expect("thread")
            .join()
            .expect("no overflow");
        assert!(out.contains("nested more than"), "{out}");
    }

    #[test]
    fn the_new_grammar_generates_code() {
        let out = expand(
            "#[psi(k * if theta < 0.0 { abs(theta).powi(3) } else { max(sinh(theta), cosh(theta) - 1.0) } + atan2(theta_bar, a) * PI * std::f64::consts::E * pow(theta, 2))] struct T { k: f64 }",
        );
        assert!(!out.contains("compile_error"), "{out}");
        assert!(out.contains("atan2"), "{out}");
    }
}
