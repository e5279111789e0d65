//! The run-time front end: a ψ expression from a string, with the grammar of the derive (Rust expression
//! syntax: the text inside `#[psi(…)]` is accepted here unchanged) and errors that carry the column.

use std::fmt;

use crate::ast::{BinOp, Cmp, Expr, Let, MAX_DEPTH};

/// A range of character columns in the source string (0-based, end exclusive).
#[derive(Clone, Copy, PartialEq, Eq, Debug, Default)]
pub struct Span {
    /// First column.
    pub start: usize,
    /// One past the last column.
    pub end: usize,
}

impl Span {
    /// The 1-based column of the first character, as messages print it.
    pub fn column(self) -> usize {
        self.start + 1
    }
}

/// One error in a ψ string: where, and what is wrong or was expected.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Diagnostic {
    /// Where.
    pub span: Span,
    /// What.
    pub message: String,
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "column {}: {}", self.span.column(), self.message)
    }
}

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Num(f64, Option<i64>),
    Ident(String),
    Sym(&'static str),
    End,
}

impl fmt::Display for Tok {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Tok::Num(v, _) => write!(f, "the number `{v}`"),
            Tok::Ident(s) => write!(f, "`{s}`"),
            Tok::Sym(s) => write!(f, "`{s}`"),
            Tok::End => write!(f, "the end of the expression"),
        }
    }
}

const SYMBOLS: [&str; 17] = [
    "::", "<=", ">=", "+", "-", "*", "/", "(", ")", "{", "}", ",", ";", "=", ".", "<", ">",
];

fn lex(src: &str) -> Result<Vec<(Tok, Span)>, Diagnostic> {
    let chars: Vec<char> = src.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        let start = i;
        if c.is_ascii_digit() {
            let mut text = String::new();
            let mut is_int = true;
            let digits = |i: &mut usize, text: &mut String| {
                while *i < chars.len() && (chars[*i].is_ascii_digit() || chars[*i] == '_') {
                    if chars[*i] != '_' {
                        text.push(chars[*i]);
                    }
                    *i += 1;
                }
            };
            digits(&mut i, &mut text);
            // A fraction: `.` followed by a digit, or a trailing `2.` not followed by a name or a dot.
            if i < chars.len() && chars[i] == '.' {
                let next = chars.get(i + 1).copied();
                if next.is_some_and(|n| n.is_ascii_digit()) {
                    is_int = false;
                    text.push('.');
                    i += 1;
                    digits(&mut i, &mut text);
                } else if !next.is_some_and(|n| n.is_alphabetic() || n == '_' || n == '.') {
                    is_int = false;
                    i += 1;
                }
            }
            if i < chars.len() && (chars[i] == 'e' || chars[i] == 'E') {
                let mut j = i + 1;
                if j < chars.len() && (chars[j] == '+' || chars[j] == '-') {
                    j += 1;
                }
                if j < chars.len() && chars[j].is_ascii_digit() {
                    is_int = false;
                    text.push('e');
                    text.extend(&chars[i + 1..j]);
                    i = j;
                    digits(&mut i, &mut text);
                }
            }
            // Type suffixes as Rust writes them: `2.0f64`, `2.0_f64`, `2_f64`.
            let rest: String = chars[i..].iter().take(4).collect();
            if rest.starts_with("f64") || rest.starts_with("_f64") {
                i += if rest.starts_with('_') { 4 } else { 3 };
                is_int = false;
            }
            let span = Span { start, end: i };
            let value: f64 = text.parse().map_err(|_| Diagnostic {
                span,
                message: format!("`{text}` is not a number"),
            })?;
            let int = if is_int {
                text.parse::<i64>().ok()
            } else {
                None
            };
            out.push((Tok::Num(value, int), span));
            continue;
        }
        if c.is_alphabetic() || c == '_' {
            while i < chars.len() && (chars[i].is_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            let s: String = chars[start..i].iter().collect();
            out.push((Tok::Ident(s), Span { start, end: i }));
            continue;
        }
        let two: String = chars[i..(i + 2).min(chars.len())].iter().collect();
        if let Some(sym) = SYMBOLS
            .iter()
            .find(|s| (s.len() == 2 && two == **s) || (s.len() == 1 && c.to_string() == **s))
        {
            i += sym.len();
            out.push((Tok::Sym(sym), Span { start, end: i }));
            continue;
        }
        let message = match c {
            '^' => {
                "`^` is not a power in this language: write `x.powi(2)` or `pow(x, 2)`".to_string()
            }
            '=' | '!' => {
                "only `<`, `<=`, `>`, `>=` compare, and only in the condition of an `if`".into()
            }
            _ => format!("unexpected character `{c}`"),
        };
        return Err(Diagnostic {
            span: Span {
                start,
                end: start + 1,
            },
            message,
        });
    }
    out.push((
        Tok::End,
        Span {
            start: chars.len(),
            end: chars.len(),
        },
    ));
    Ok(out)
}

struct Parser {
    toks: Vec<(Tok, Span)>,
    pos: usize,
}

type Parsed = Result<(Expr<Span>, usize), Diagnostic>;

impl Parser {
    fn peek(&self) -> &Tok {
        &self.toks[self.pos.min(self.toks.len() - 1)].0
    }

    fn span(&self) -> Span {
        self.toks[self.pos.min(self.toks.len() - 1)].1
    }

    fn bump(&mut self) -> (Tok, Span) {
        let t = self.toks[self.pos.min(self.toks.len() - 1)].clone();
        if self.pos < self.toks.len() - 1 {
            self.pos += 1;
        }
        t
    }

    fn is(&self, sym: &str) -> bool {
        matches!(self.peek(), Tok::Sym(s) if *s == sym)
    }

    fn expect(&mut self, sym: &str, what: &str) -> Result<Span, Diagnostic> {
        if self.is(sym) {
            Ok(self.bump().1)
        } else {
            Err(self.unexpected(&format!("`{sym}` {what}")))
        }
    }

    fn unexpected(&self, expected: &str) -> Diagnostic {
        Diagnostic {
            span: self.span(),
            message: format!("expected {expected}, found {}", self.peek()),
        }
    }

    fn deep(&self, depth: usize, span: Span) -> Result<(), Diagnostic> {
        if depth > MAX_DEPTH {
            Err(Diagnostic {
                span,
                message: format!("the expression is nested more than {MAX_DEPTH} levels deep"),
            })
        } else {
            Ok(())
        }
    }

    fn expr(&mut self, depth: usize) -> Parsed {
        self.deep(depth, self.span())?;
        self.level(
            depth,
            &[("+", BinOp::Add), ("-", BinOp::Sub)],
            Self::product,
        )
    }

    fn product(&mut self, depth: usize) -> Parsed {
        self.level(depth, &[("*", BinOp::Mul), ("/", BinOp::Div)], Self::unary)
    }

    /// One left-associative precedence level: `next (op next)*` for the operators `ops`.
    fn level(
        &mut self,
        depth: usize,
        ops: &[(&str, BinOp)],
        next: fn(&mut Self, usize) -> Parsed,
    ) -> Parsed {
        let (mut lhs, mut d) = next(self, depth + 1)?;
        loop {
            let Some(&(_, op)) = ops.iter().find(|(sym, _)| self.is(sym)) else {
                return Ok((lhs, d));
            };
            let span = self.bump().1;
            let (rhs, dr) = next(self, depth + 1)?;
            d = d.max(dr) + 1;
            self.deep(d, span)?;
            lhs = Expr::Binary {
                op,
                lhs: Box::new(lhs),
                rhs: Box::new(rhs),
                span,
            };
        }
    }

    fn unary(&mut self, depth: usize) -> Parsed {
        self.deep(depth, self.span())?;
        if self.is("-") {
            let span = self.bump().1;
            let (arg, d) = self.unary(depth + 1)?;
            // `-2` stays an integer literal (for `powi(-2)`).
            if let Expr::Num {
                value,
                int,
                span: s,
            } = arg
            {
                return Ok((
                    Expr::Num {
                        value: -value,
                        int: int.map(|n| -n),
                        span: Span {
                            start: span.start,
                            end: s.end,
                        },
                    },
                    d,
                ));
            }
            return Ok((
                Expr::Neg {
                    arg: Box::new(arg),
                    span,
                },
                d + 1,
            ));
        }
        self.postfix(depth + 1)
    }

    fn postfix(&mut self, depth: usize) -> Parsed {
        let (mut recv, mut d) = self.primary(depth + 1)?;
        while self.is(".") {
            self.bump();
            let (name, func_span) = match self.bump() {
                (Tok::Ident(s), sp) => (s, sp),
                (t, sp) => {
                    return Err(Diagnostic {
                        span: sp,
                        message: format!("expected a method name after `.`, found {t}"),
                    });
                }
            };
            self.expect("(", "after a method name")?;
            let (mut args, da) = self.args(depth + 1)?;
            args.insert(0, recv);
            d = d.max(da) + 1;
            self.deep(d, func_span)?;
            recv = Expr::Call {
                func: name,
                func_span,
                args,
                method: true,
            };
        }
        Ok((recv, d))
    }

    /// Arguments after `(`, through `)`.
    fn args(&mut self, depth: usize) -> Result<(Vec<Expr<Span>>, usize), Diagnostic> {
        let mut args = Vec::new();
        let mut d = 0;
        if self.is(")") {
            self.bump();
            return Ok((args, d));
        }
        loop {
            let (a, da) = self.expr(depth + 1)?;
            d = d.max(da);
            args.push(a);
            if self.is(",") {
                self.bump();
                if self.is(")") {
                    self.bump();
                    return Ok((args, d));
                }
                continue;
            }
            self.expect(")", "or `,` in the argument list")?;
            return Ok((args, d));
        }
    }

    fn primary(&mut self, depth: usize) -> Parsed {
        self.deep(depth, self.span())?;
        match self.peek().clone() {
            Tok::Num(value, int) => {
                let span = self.bump().1;
                Ok((Expr::Num { value, int, span }, 1))
            }
            Tok::Ident(kw) if kw == "if" => self.if_expr(depth + 1),
            Tok::Ident(kw) if kw == "let" => Err(Diagnostic {
                span: self.span(),
                message: "a `let` binding belongs inside a block: `{ let x = …; EXPR }`".into(),
            }),
            Tok::Ident(_) => {
                let (Tok::Ident(mut name), mut span) = self.bump() else {
                    return Err(self.unexpected("a name"));
                };
                while self.is("::") {
                    self.bump();
                    match self.bump() {
                        (Tok::Ident(s), sp) => {
                            name.push_str("::");
                            name.push_str(&s);
                            span.end = sp.end;
                        }
                        (t, sp) => {
                            return Err(Diagnostic {
                                span: sp,
                                message: format!("expected a name after `::`, found {t}"),
                            });
                        }
                    }
                }
                if self.is("(") {
                    self.bump();
                    let (args, d) = self.args(depth + 1)?;
                    return Ok((
                        Expr::Call {
                            func: name,
                            func_span: span,
                            args,
                            method: false,
                        },
                        d + 1,
                    ));
                }
                Ok((Expr::Name { name, span }, 1))
            }
            Tok::Sym("(") => {
                self.bump();
                let (e, d) = self.expr(depth + 1)?;
                self.expect(")", "to close `(`")?;
                Ok((e, d))
            }
            Tok::Sym("{") => self.block(depth + 1),
            _ => Err(self.unexpected("a number, a name, `(`, `{` or `if`")),
        }
    }

    fn block(&mut self, depth: usize) -> Parsed {
        self.expect("{", "to open a block")?;
        let mut lets = Vec::new();
        let mut d = 0;
        while matches!(self.peek(), Tok::Ident(k) if k == "let") {
            self.bump();
            let (name, name_span) = match self.bump() {
                (Tok::Ident(s), sp) => (s, sp),
                (t, sp) => {
                    return Err(Diagnostic {
                        span: sp,
                        message: format!("expected a name after `let`, found {t}"),
                    });
                }
            };
            self.expect("=", "after the name of a `let` binding")?;
            let (value, dv) = self.expr(depth + 1)?;
            self.expect(";", "after a `let` binding")?;
            d = d.max(dv);
            lets.push(Let {
                name,
                name_span,
                value,
            });
        }
        let (value, dv) = self.expr(depth + 1)?;
        self.expect("}", "to close the block (a block ends with one expression)")?;
        Ok((
            Expr::Block {
                lets,
                value: Box::new(value),
            },
            d.max(dv) + 1,
        ))
    }

    fn if_expr(&mut self, depth: usize) -> Parsed {
        let span = self.bump().1;
        let (lhs, dl) = self.expr(depth + 1)?;
        let cmp = match self.peek() {
            Tok::Sym("<") => Cmp::Lt,
            Tok::Sym("<=") => Cmp::Le,
            Tok::Sym(">") => Cmp::Gt,
            Tok::Sym(">=") => Cmp::Ge,
            _ => {
                return Err(self.unexpected("a comparison (`<`, `<=`, `>`, `>=`) in the condition"));
            }
        };
        self.bump();
        let (rhs, dr) = self.expr(depth + 1)?;
        let (then, dt) = self.block(depth + 1)?;
        match self.peek() {
            Tok::Ident(k) if k == "else" => {
                self.bump();
            }
            _ => return Err(self.unexpected("`else` (an `if` in ψ needs both branches)")),
        }
        let (otherwise, de) = if matches!(self.peek(), Tok::Ident(k) if k == "if") {
            self.if_expr(depth + 1)?
        } else {
            self.block(depth + 1)?
        };
        let d = dl.max(dr).max(dt).max(de) + 1;
        self.deep(d, span)?;
        Ok((
            Expr::If {
                cmp,
                lhs: Box::new(lhs),
                rhs: Box::new(rhs),
                then: Box::new(then),
                otherwise: Box::new(otherwise),
                span,
            },
            d,
        ))
    }
}

/// Parses a ψ expression. A syntax error stops at the first problem (what follows it cannot be read
/// reliably); names and functions are checked later by [`crate::lower`], which reports all its errors.
///
/// # Errors
/// The first syntax error, with its column and what was expected.
pub fn parse(src: &str) -> Result<Expr<Span>, Diagnostic> {
    let toks = lex(src)?;
    let mut p = Parser { toks, pos: 0 };
    if matches!(p.peek(), Tok::End) {
        return Err(p.unexpected("an expression"));
    }
    let (e, _) = p.expr(0)?;
    if !matches!(p.peek(), Tok::End) {
        let what = match p.peek() {
            Tok::Sym("<" | "<=" | ">" | ">=") => {
                "an operator or the end of the expression (comparisons appear only in `if` conditions)"
            }
            _ => "an operator or the end of the expression",
        };
        return Err(p.unexpected(what));
    }
    Ok(e)
}
