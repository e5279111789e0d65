//! `syn::Expr` → the shared parse tree ([`hinge_symbolic::ast`]), reporting the Rust syntax the ψ language
//! does not have. Names, functions and their rules are checked by [`hinge_symbolic::lower`], as at run time.

use proc_macro2::Span;
use syn::spanned::Spanned;
use syn::{BinOp, Expr as SynExpr, Lit, Stmt, UnOp};

use hinge_symbolic::ast::{self, Cmp, Expr, Let, MAX_DEPTH};

/// Syntax errors: (span, message, whether the supported list helps).
pub type Errors = Vec<(Span, String, bool)>;

/// Converts `e`, bounding the depth so that no input overflows the recursive passes.
pub fn convert(e: &SynExpr, errors: &mut Errors) -> Expr<Span> {
    let mut c = Converter {
        errors,
        too_deep: false,
    };
    c.expr(e, 0)
}

struct Converter<'a> {
    errors: &'a mut Errors,
    too_deep: bool,
}

impl Converter<'_> {
    fn invalid(&mut self, span: Span, msg: impl Into<String>, supported: bool) -> Expr<Span> {
        self.errors.push((span, msg.into(), supported));
        Expr::Invalid { span }
    }

    fn expr(&mut self, e: &SynExpr, depth: usize) -> Expr<Span> {
        if depth > MAX_DEPTH {
            if !self.too_deep {
                self.too_deep = true;
                self.errors.push((
                    e.span(),
                    format!("the ψ expression is nested more than {MAX_DEPTH} levels deep"),
                    false,
                ));
            }
            return Expr::Invalid { span: e.span() };
        }
        let d = depth + 1;
        match e {
            SynExpr::Lit(l) => match &l.lit {
                Lit::Float(f) => match f.base10_parse::<f64>() {
                    Ok(value) => Expr::Num {
                        value,
                        int: None,
                        span: f.span(),
                    },
                    Err(err) => self.invalid(f.span(), err.to_string(), false),
                },
                Lit::Int(i) => match i.base10_parse::<i64>() {
                    Ok(v) => Expr::Num {
                        value: v as f64,
                        int: Some(v),
                        span: i.span(),
                    },
                    Err(err) => self.invalid(i.span(), err.to_string(), false),
                },
                other => self.invalid(other.span(), "unsupported literal in a ψ expression", true),
            },
            SynExpr::Paren(p) => self.expr(&p.expr, d),
            SynExpr::Group(g) => self.expr(&g.expr, d),
            SynExpr::Path(p) => {
                if p.qself.is_some() || p.path.segments.iter().any(|s| !s.arguments.is_none()) {
                    return self.invalid(p.span(), "unsupported path in a ψ expression", true);
                }
                let name = p
                    .path
                    .segments
                    .iter()
                    .map(|s| s.ident.to_string())
                    .collect::<Vec<_>>()
                    .join("::");
                Expr::Name {
                    name,
                    span: p.span(),
                }
            }
            SynExpr::Unary(u) => match u.op {
                UnOp::Neg(_) => {
                    let arg = self.expr(&u.expr, d);
                    Expr::Neg {
                        arg: Box::new(arg),
                        span: u.op.span(),
                    }
                }
                _ => {
                    let _ = self.expr(&u.expr, d);
                    self.invalid(u.op.span(), "unsupported unary operator", true)
                }
            },
            SynExpr::Binary(b) => {
                let lhs = self.expr(&b.left, d);
                let rhs = self.expr(&b.right, d);
                let op = match b.op {
                    BinOp::Add(_) => ast::BinOp::Add,
                    BinOp::Sub(_) => ast::BinOp::Sub,
                    BinOp::Mul(_) => ast::BinOp::Mul,
                    BinOp::Div(_) => ast::BinOp::Div,
                    BinOp::Lt(_) | BinOp::Le(_) | BinOp::Gt(_) | BinOp::Ge(_) => {
                        return self.invalid(
                            b.op.span(),
                            "a comparison appears only in the condition of an `if`",
                            false,
                        );
                    }
                    _ => return self.invalid(b.op.span(), "unsupported operator", true),
                };
                Expr::Binary {
                    op,
                    lhs: Box::new(lhs),
                    rhs: Box::new(rhs),
                    span: b.op.span(),
                }
            }
            SynExpr::MethodCall(m) => {
                let recv = self.expr(&m.receiver, d);
                if m.turbofish.is_some() {
                    return self.invalid(
                        m.method.span(),
                        "generic arguments are not supported here",
                        false,
                    );
                }
                let mut args = vec![recv];
                args.extend(m.args.iter().map(|a| self.expr(a, d)));
                Expr::Call {
                    func: m.method.to_string(),
                    func_span: m.method.span(),
                    args,
                    method: true,
                }
            }
            SynExpr::Call(c) => {
                let args: Vec<Expr<Span>> = c.args.iter().map(|a| self.expr(a, d)).collect();
                match &*c.func {
                    SynExpr::Path(p) if p.qself.is_none() && p.path.get_ident().is_some() => {
                        let ident = p
                            .path
                            .get_ident()
                            .map(ToString::to_string)
                            .unwrap_or_default();
                        Expr::Call {
                            func: ident,
                            func_span: p.span(),
                            args,
                            method: false,
                        }
                    }
                    other => self.invalid(
                        other.span(),
                        "a function call names one function, as in `sin(x)`",
                        true,
                    ),
                }
            }
            SynExpr::Block(b) if b.label.is_none() => self.block(&b.block, d),
            SynExpr::If(i) => self.if_expr(i, d),
            other => self.invalid(
                other.span(),
                "unsupported expression in a ψ expression",
                true,
            ),
        }
    }

    fn block(&mut self, block: &syn::Block, depth: usize) -> Expr<Span> {
        let mut lets = Vec::new();
        let mut value = None;
        let n = block.stmts.len();
        for (i, stmt) in block.stmts.iter().enumerate() {
            match stmt {
                Stmt::Local(local) => {
                    let v = match &local.init {
                        Some(init) if init.diverge.is_none() => self.expr(&init.expr, depth + 1),
                        _ => self.invalid(
                            local.span(),
                            "a `let` in a ψ expression needs `= EXPR;`",
                            false,
                        ),
                    };
                    match &local.pat {
                        syn::Pat::Ident(pi) if pi.by_ref.is_none() && pi.subpat.is_none() => lets
                            .push(Let {
                                name: pi.ident.to_string(),
                                name_span: pi.ident.span(),
                                value: v,
                            }),
                        other => {
                            self.invalid(
                                other.span(),
                                "only `let NAME = EXPR;` bindings are supported",
                                false,
                            );
                        }
                    }
                }
                Stmt::Expr(e, None) if i + 1 == n => value = Some(self.expr(e, depth + 1)),
                other => {
                    self.invalid(
                        other.span(),
                        "a block in a ψ expression holds `let` bindings and ends with an expression",
                        false,
                    );
                }
            }
        }
        let value = match value {
            Some(v) => v,
            None => self.invalid(block.span(), "this block has no final expression", false),
        };
        Expr::Block {
            lets,
            value: Box::new(value),
        }
    }

    fn if_expr(&mut self, i: &syn::ExprIf, depth: usize) -> Expr<Span> {
        let span = i.if_token.span;
        let then = self.block(&i.then_branch, depth + 1);
        let otherwise = match &i.else_branch {
            Some((_, e)) => self.expr(e, depth + 1),
            None => self.invalid(span, "an `if` in ψ needs an `else` branch", false),
        };
        let (cmp, lhs, rhs) = match &*i.cond {
            SynExpr::Binary(b) => {
                let cmp = match b.op {
                    BinOp::Lt(_) => Some(Cmp::Lt),
                    BinOp::Le(_) => Some(Cmp::Le),
                    BinOp::Gt(_) => Some(Cmp::Gt),
                    BinOp::Ge(_) => Some(Cmp::Ge),
                    _ => None,
                };
                match cmp {
                    Some(c) => (
                        c,
                        self.expr(&b.left, depth + 1),
                        self.expr(&b.right, depth + 1),
                    ),
                    None => {
                        let x = self.invalid(
                            i.cond.span(),
                            "the condition of an `if` is one comparison: `<`, `<=`, `>` or `>=`",
                            false,
                        );
                        (Cmp::Lt, x.clone(), x)
                    }
                }
            }
            other => {
                let x = self.invalid(
                    other.span(),
                    "the condition of an `if` is one comparison: `<`, `<=`, `>` or `>=`",
                    false,
                );
                (Cmp::Lt, x.clone(), x)
            }
        };
        Expr::If {
            cmp,
            lhs: Box::new(lhs),
            rhs: Box::new(rhs),
            then: Box::new(then),
            otherwise: Box::new(otherwise),
            span,
        }
    }
}
