//! Parse tree → arena: names, functions and their arity, θ-free operand rules, every error collected.

use std::collections::HashMap;

use crate::ast::{BinOp, Cmp, Expr};
use crate::sym::{Arena, FUNCS, Func, Id};

/// Names the framework provides per hinge, numbered after the caller's inputs (fields or parameters).
pub const PROVIDED: [&str; 6] = [
    "theta_bar",
    "a",
    "rest_length",
    "rest_area",
    "theta_prev",
    "dt",
];

/// The named constants, with every spelling accepted.
pub const CONSTANTS: [(&str, f64); 6] = [
    ("PI", std::f64::consts::PI),
    ("E", std::f64::consts::E),
    ("std::f64::consts::PI", std::f64::consts::PI),
    ("std::f64::consts::E", std::f64::consts::E),
    ("core::f64::consts::PI", std::f64::consts::PI),
    ("core::f64::consts::E", std::f64::consts::E),
];

/// What the language supports, listed once per expression with the errors that need it.
pub const SUPPORTED: &str = "supported: numbers, `theta`, the inputs, the provided names `theta_bar`, `a`, \
     `rest_length`, `rest_area`, `theta_prev`, `dt`, the constants `PI` and `E` (also \
     `std::f64::consts::PI`), `+ - * /`, unary `-`, parentheses, the functions `sqrt sin cos tan exp ln atan \
     tanh sinh cosh abs` (as `f(x)` or `x.f()`), `min(a, b)`, `max(a, b)`, `powi(x, INT)`, `powf(x, θ-free)`, \
     `pow(x, y)`, `atan2(θ-free, θ-free)` (or `a.min(b)`, `x.powi(2)`, `y.atan2(x)`, …), \
     `if A < B { … } else { … }` (`<`, `<=`, `>`, `>=`), and `{ let NAME = EXPR; … EXPR }` blocks";

/// Whether an input (struct field or run-time parameter) may be called `name`: not `theta`, a provided name
/// or a constant.
pub fn reserved(name: &str) -> Option<&'static str> {
    if name == "theta" {
        Some("the hinge angle `theta`")
    } else if PROVIDED.contains(&name) {
        Some("a provided per-hinge quantity")
    } else if CONSTANTS.iter().any(|(c, _)| *c == name) {
        Some("a constant")
    } else {
        None
    }
}

/// One lowering error.
#[derive(Clone, Debug, PartialEq)]
pub struct Error<S> {
    /// Where.
    pub span: S,
    /// What.
    pub message: String,
    /// Whether the supported list helps (an unknown function or method).
    pub wants_supported_list: bool,
}

/// The callable names (functions and methods), for "did you mean".
const CALLABLE: [&str; 8] = ["abs", "min", "max", "powi", "powf", "pow", "atan2", ""];

/// The closest of `candidates` to `name` when it is a plausible misspelling (ignoring case; edit distance 0
/// for names of one or two characters, 1 up to four, 2 from five characters on).
pub fn did_you_mean<'a>(
    name: &str,
    candidates: impl IntoIterator<Item = &'a str>,
) -> Option<&'a str> {
    let limit = match name.chars().count() {
        0..=2 => 0,
        3..=4 => 1,
        _ => 2,
    };
    candidates
        .into_iter()
        .filter(|c| !c.is_empty() && *c != name)
        .map(|c| (edit_distance(name, c), c))
        .filter(|(d, _)| *d <= limit)
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
}

/// Levenshtein distance, with a swap of neighbours counting as one edit.
fn edit_distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.to_lowercase().chars().collect();
    let b: Vec<char> = b.to_lowercase().chars().collect();
    let mut d = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    for (i, row) in d.iter_mut().enumerate() {
        row[0] = i;
    }
    for j in 0..=b.len() {
        d[0][j] = j;
    }
    for i in 1..=a.len() {
        for j in 1..=b.len() {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            let mut v = (d[i - 1][j] + 1)
                .min(d[i][j - 1] + 1)
                .min(d[i - 1][j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                v = v.min(d[i - 2][j - 2] + 1);
            }
            d[i][j] = v;
        }
    }
    d[a.len()][b.len()]
}

/// Lowers parse trees into an arena. Inputs `0..inputs.len()` are the caller's (fields or parameters), the
/// provided names follow.
pub struct Lowerer<'a, S> {
    /// The arena nodes go into.
    pub arena: &'a mut Arena,
    inputs: &'a [String],
    /// Errors so far.
    pub errors: Vec<Error<S>>,
    scopes: Vec<HashMap<String, Id>>,
    /// Which inputs (by var index) the expression reads.
    pub used: Vec<bool>,
    /// What the inputs are called in messages ("the struct's fields", "the parameters given").
    pub inputs_are: &'static str,
}

impl<'a, S: Copy> Lowerer<'a, S> {
    /// A lowerer over `arena` for the named inputs.
    pub fn new(arena: &'a mut Arena, inputs: &'a [String]) -> Self {
        Self {
            arena,
            inputs,
            errors: Vec::new(),
            scopes: Vec::new(),
            used: vec![false; inputs.len() + PROVIDED.len()],
            inputs_are: "the inputs",
        }
    }

    fn error(&mut self, span: S, message: impl Into<String>) -> Id {
        self.errors.push(Error {
            span,
            message: message.into(),
            wants_supported_list: false,
        });
        self.arena.constant(0.0)
    }

    fn unsupported(&mut self, span: S, message: impl Into<String>) -> Id {
        self.errors.push(Error {
            span,
            message: message.into(),
            wants_supported_list: true,
        });
        self.arena.constant(0.0)
    }

    /// Lowers `e`; errors accumulate in [`Lowerer::errors`].
    pub fn expr(&mut self, e: &Expr<S>) -> Id {
        match e {
            Expr::Num { value, .. } => self.arena.constant(*value),
            Expr::Invalid { .. } => self.arena.constant(0.0),
            Expr::Name { name, span } => self.name(name, *span),
            Expr::Neg { arg, .. } => {
                let a = self.expr(arg);
                self.arena.neg(a)
            }
            Expr::Binary { op, lhs, rhs, .. } => {
                let (l, r) = (self.expr(lhs), self.expr(rhs));
                match op {
                    BinOp::Add => self.arena.add(l, r),
                    BinOp::Sub => self.arena.sub(l, r),
                    BinOp::Mul => self.arena.mul(l, r),
                    BinOp::Div => self.arena.div(l, r),
                }
            }
            Expr::Block { lets, value } => {
                self.scopes.push(HashMap::new());
                for l in lets {
                    let v = self.expr(&l.value);
                    if let Some(scope) = self.scopes.last_mut() {
                        scope.insert(l.name.clone(), v);
                    }
                }
                let r = self.expr(value);
                self.scopes.pop();
                r
            }
            Expr::If {
                cmp,
                lhs,
                rhs,
                then,
                otherwise,
                ..
            } => {
                let (l, r) = (self.expr(lhs), self.expr(rhs));
                let (a, b) = (self.expr(then), self.expr(otherwise));
                self.arena.select(*cmp, l, r, a, b)
            }
            Expr::Call {
                func,
                func_span,
                args,
                method,
            } => self.call(func, *func_span, args, *method),
        }
    }

    fn call(&mut self, func: &str, span: S, args: &[Expr<S>], method: bool) -> Id {
        let ids: Vec<Id> = args.iter().map(|a| self.expr(a)).collect();
        let spell = |n: usize| -> String {
            if method {
                let rest = (1..n).map(|_| "_").collect::<Vec<_>>().join(", ");
                format!("`x.{func}({rest})`")
            } else {
                let all = (0..n).map(|_| "_").collect::<Vec<_>>().join(", ");
                format!("`{func}({all})`")
            }
        };
        let arity = |want: usize| -> Option<String> {
            (ids.len() != want).then(|| {
                let given = if method { ids.len() - 1 } else { ids.len() };
                let wanted = if method { want - 1 } else { want };
                format!(
                    "`{func}` takes {wanted} argument{} here (written {}), not {given}",
                    if wanted == 1 { "" } else { "s" },
                    spell(want)
                )
            })
        };
        if let Some(f) = Func::from_name(func) {
            if let Some(m) = arity(1) {
                return self.error(span, m);
            }
            return self.arena.call(f, ids[0]);
        }
        match func {
            "abs" => {
                if let Some(m) = arity(1) {
                    return self.error(span, m);
                }
                let x = ids[0];
                let zero = self.arena.constant(0.0);
                let nx = self.arena.neg(x);
                self.arena.select(Cmp::Ge, x, zero, x, nx)
            }
            "min" | "max" => {
                if let Some(m) = arity(2) {
                    return self.error(span, m);
                }
                let (a, b) = (ids[0], ids[1]);
                let cmp = if func == "min" { Cmp::Le } else { Cmp::Ge };
                self.arena.select(cmp, a, b, a, b)
            }
            "powi" | "pow" | "powf" => {
                if let Some(m) = arity(2) {
                    return self.error(span, m);
                }
                let int = int_literal(&args[1]);
                match (func, int) {
                    ("powi" | "pow", Some(n)) => match i32::try_from(n) {
                        Ok(n) => self.arena.powi(ids[0], n),
                        Err(_) => self.error(args[1].span(), "this exponent does not fit an `i32`"),
                    },
                    ("powi", None) => self.error(
                        args[1].span(),
                        "`powi` takes an integer literal exponent (for example `x.powi(2)`); use `powf` for others",
                    ),
                    _ => {
                        if self.arena.depends_on_theta(ids[1]) {
                            return self.error(
                                args[1].span(),
                                format!(
                                    "the exponent of `{func}` must not depend on `theta` (write the power with `exp` and `ln` if you need it)"
                                ),
                            );
                        }
                        self.arena.powf(ids[0], ids[1])
                    }
                }
            }
            "atan2" => {
                if let Some(m) = arity(2) {
                    return self.error(span, m);
                }
                for (k, &id) in ids.iter().enumerate() {
                    if self.arena.depends_on_theta(id) {
                        return self.error(
                            args[k].span(),
                            "the arguments of `atan2` must not depend on `theta` (atan2 is for θ-free quantities)",
                        );
                    }
                }
                self.arena.atan2(ids[0], ids[1])
            }
            _ => {
                let names = FUNCS.iter().map(|f| f.name()).chain(CALLABLE);
                let hint = did_you_mean(func, names)
                    .map(|c| format!(" (did you mean `{c}`?)"))
                    .unwrap_or_default();
                let what = if method { "method" } else { "function" };
                self.unsupported(span, format!("unknown {what} `{func}`{hint}"))
            }
        }
    }

    fn name(&mut self, name: &str, span: S) -> Id {
        for scope in self.scopes.iter().rev() {
            if let Some(&id) = scope.get(name) {
                return id;
            }
        }
        if name == "theta" {
            return self.arena.theta();
        }
        if let Some(i) = self.inputs.iter().position(|f| f == name) {
            self.used[i] = true;
            return self.arena.var(i);
        }
        if let Some(i) = PROVIDED.iter().position(|p| *p == name) {
            let k = self.inputs.len() + i;
            self.used[k] = true;
            return self.arena.var(k);
        }
        if let Some((_, c)) = CONSTANTS.iter().find(|(n, _)| *n == name) {
            return self.arena.constant(*c);
        }
        let lets: Vec<String> = self.scopes.iter().flat_map(|s| s.keys().cloned()).collect();
        let known = std::iter::once("theta")
            .chain(self.inputs.iter().map(String::as_str))
            .chain(PROVIDED)
            .chain(["PI", "E"])
            .chain(lets.iter().map(String::as_str));
        let hint = did_you_mean(name, known)
            .map(|c| format!(" (did you mean `{c}`?)"))
            .unwrap_or_default();
        let inputs = if self.inputs.is_empty() {
            "none".to_string()
        } else {
            self.inputs.join(", ")
        };
        self.error(
            span,
            format!(
                "unknown identifier `{name}`{hint}: a ψ expression may use `theta`, {} ({inputs}), the \
                 provided names `theta_bar`, `a`, `rest_length`, `rest_area`, `theta_prev`, `dt` and the constants \
                 `PI`, `E`",
                self.inputs_are
            ),
        )
    }
}

/// The integer value of an integer literal, possibly negated or parenthesised.
fn int_literal<S>(e: &Expr<S>) -> Option<i64> {
    match e {
        Expr::Num { int, .. } => *int,
        Expr::Neg { arg, .. } => int_literal(arg).and_then(i64::checked_neg),
        _ => None,
    }
}
