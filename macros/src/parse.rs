//! ψ expression (a `syn::Expr`) → arena nodes, collecting every error with its span.

use std::collections::HashMap;

use proc_macro2::Span;
use syn::spanned::Spanned;
use syn::{BinOp, Expr, Lit, Stmt, UnOp};

use crate::sym::{Arena, Func, Id};

/// Names the framework provides per hinge, in var order after the struct fields.
pub const PROVIDED: [&str; 6] = [
    "theta_bar",
    "a",
    "rest_length",
    "rest_area",
    "theta_prev",
    "dt",
];

pub const SUPPORTED: &str = "supported: float and integer literals, `theta`, struct fields, the provided names \
     `theta_bar`, `a`, `rest_length`, `rest_area`, `theta_prev`, `dt`, `+ - * /`, unary `-`, parentheses, \
     `.powi(INT)`, `.powf(θ-free)`, `.sqrt()`, `.sin()`, `.cos()`, `.tan()`, `.exp()`, `.ln()`, `.atan()`, \
     `.tanh()`, and `{ let NAME = EXPR; … EXPR }` blocks";

pub struct Parser<'a> {
    pub arena: &'a mut Arena,
    /// Struct field names in var order (vars 0..fields.len()).
    pub fields: &'a [String],
    pub errors: Vec<syn::Error>,
    scopes: Vec<HashMap<String, Id>>,
}

impl<'a> Parser<'a> {
    pub fn new(arena: &'a mut Arena, fields: &'a [String]) -> Self {
        Self {
            arena,
            fields,
            errors: Vec::new(),
            scopes: Vec::new(),
        }
    }

    fn error(&mut self, span: Span, msg: impl std::fmt::Display) -> Id {
        self.errors.push(syn::Error::new(span, msg));
        // A placeholder that keeps parsing going so every error is reported at once.
        self.arena.constant(0.0)
    }

    pub fn expr(&mut self, e: &Expr) -> Id {
        match e {
            Expr::Lit(l) => match &l.lit {
                Lit::Float(f) => match f.base10_parse::<f64>() {
                    Ok(v) => self.arena.constant(v),
                    Err(err) => self.error(f.span(), err),
                },
                Lit::Int(i) => match i.base10_parse::<i64>() {
                    Ok(v) => self.arena.constant(v as f64),
                    Err(err) => self.error(i.span(), err),
                },
                other => self.error(
                    other.span(),
                    format!("unsupported literal in a ψ expression; {SUPPORTED}"),
                ),
            },
            Expr::Paren(p) => self.expr(&p.expr),
            Expr::Group(g) => self.expr(&g.expr),
            Expr::Path(p) => {
                let Some(ident) = p.path.get_ident().filter(|_| p.qself.is_none()) else {
                    return self.error(
                        p.span(),
                        format!("unsupported path in a ψ expression; {SUPPORTED}"),
                    );
                };
                let name = ident.to_string();
                self.name(&name, ident.span())
            }
            Expr::Unary(u) => match u.op {
                UnOp::Neg(_) => {
                    let a = self.expr(&u.expr);
                    self.arena.neg(a)
                }
                _ => {
                    let _ = self.expr(&u.expr);
                    self.error(
                        u.op.span(),
                        format!("unsupported unary operator; {SUPPORTED}"),
                    )
                }
            },
            Expr::Binary(b) => {
                let l = self.expr(&b.left);
                let r = self.expr(&b.right);
                match b.op {
                    BinOp::Add(_) => self.arena.add(l, r),
                    BinOp::Sub(_) => self.arena.sub(l, r),
                    BinOp::Mul(_) => self.arena.mul(l, r),
                    BinOp::Div(_) => self.arena.div(l, r),
                    _ => self.error(b.op.span(), format!("unsupported operator; {SUPPORTED}")),
                }
            }
            Expr::MethodCall(m) => {
                let recv = self.expr(&m.receiver);
                let name = m.method.to_string();
                if m.turbofish.is_some() {
                    return self.error(m.method.span(), "generic arguments are not supported here");
                }
                let args: Vec<&Expr> = m.args.iter().collect();
                match (name.as_str(), args.len()) {
                    ("powi", 1) => match int_literal(args[0]) {
                        Some(n) => self.arena.powi(recv, n),
                        None => self.error(
                            args[0].span(),
                            "`powi` takes an integer literal exponent (for example `.powi(2)`)",
                        ),
                    },
                    ("powf", 1) => {
                        let ex = self.expr(args[0]);
                        if self.arena.depends_on_theta(ex) {
                            return self.error(
                                args[0].span(),
                                "the exponent of `powf` must not depend on `theta` (write the power with `exp` and `ln` if you need it)",
                            );
                        }
                        self.arena.powf(recv, ex)
                    }
                    (f, 0) if Func::from_name(f).is_some() => {
                        let func = Func::from_name(f).unwrap_or(Func::Sqrt);
                        self.arena.call(func, recv)
                    }
                    (f, n) if Func::from_name(f).is_some() || f == "powi" || f == "powf" => self
                        .error(
                            m.method.span(),
                            format!("`{f}` does not take {n} argument(s) here; {SUPPORTED}"),
                        ),
                    (f, _) => self.error(
                        m.method.span(),
                        format!("unsupported method `{f}`; {SUPPORTED}"),
                    ),
                }
            }
            Expr::Block(b) if b.label.is_none() => self.block(&b.block),
            other => self.error(
                other.span(),
                format!("unsupported expression in a ψ expression; {SUPPORTED}"),
            ),
        }
    }

    fn block(&mut self, block: &syn::Block) -> Id {
        self.scopes.push(HashMap::new());
        let mut result = None;
        let n = block.stmts.len();
        for (i, stmt) in block.stmts.iter().enumerate() {
            match stmt {
                Stmt::Local(local) => {
                    let value = match &local.init {
                        Some(init) if init.diverge.is_none() => self.expr(&init.expr),
                        _ => self.error(local.span(), "a `let` in a ψ expression needs `= EXPR;`"),
                    };
                    match &local.pat {
                        syn::Pat::Ident(pi) if pi.by_ref.is_none() && pi.subpat.is_none() => {
                            let name = pi.ident.to_string();
                            if let Some(scope) = self.scopes.last_mut() {
                                scope.insert(name, value);
                            }
                        }
                        other => {
                            self.error(
                                other.span(),
                                "only `let NAME = EXPR;` bindings are supported",
                            );
                        }
                    }
                }
                Stmt::Expr(e, None) if i + 1 == n => result = Some(self.expr(e)),
                other => {
                    self.error(other.span(), "a block in a ψ expression holds `let` bindings and ends with an expression");
                }
            }
        }
        self.scopes.pop();
        match result {
            Some(r) => r,
            None => self.error(block.span(), "this block has no final expression"),
        }
    }

    fn name(&mut self, name: &str, span: Span) -> Id {
        for scope in self.scopes.iter().rev() {
            if let Some(&id) = scope.get(name) {
                return id;
            }
        }
        if name == "theta" {
            return self.arena.theta();
        }
        if let Some(i) = self.fields.iter().position(|f| f == name) {
            return self.arena.var(i);
        }
        if let Some(i) = PROVIDED.iter().position(|p| *p == name) {
            return self.arena.var(self.fields.len() + i);
        }
        self.error(
            span,
            format!(
                "unknown identifier `{name}`: a ψ expression may use `theta`, the struct's fields ({}) and the provided \
                 names `theta_bar`, `a`, `rest_length`, `rest_area`, `theta_prev`, `dt`",
                if self.fields.is_empty() { "none".to_string() } else { self.fields.join(", ") }
            ),
        )
    }
}

fn int_literal(e: &Expr) -> Option<i32> {
    match e {
        Expr::Lit(l) => match &l.lit {
            Lit::Int(i) => i.base10_parse::<i32>().ok(),
            _ => None,
        },
        Expr::Unary(u) if matches!(u.op, UnOp::Neg(_)) => int_literal(&u.expr).map(|n| -n),
        Expr::Paren(p) => int_literal(&p.expr),
        _ => None,
    }
}
