//! The parse tree of a ψ expression, generic over the span type of its front end (`proc_macro2::Span` in the
//! derive, [`crate::text::Span`] — byte columns — at run time). Both front ends produce this tree, and
//! [`crate::lower`] turns it into arena nodes, so the grammar's meaning is defined once.

/// A binary arithmetic operator.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum BinOp {
    /// `+`
    Add,
    /// `-`
    Sub,
    /// `*`
    Mul,
    /// `/`
    Div,
}

/// A comparison in the condition of an `if`.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Debug)]
pub enum Cmp {
    /// `<`
    Lt,
    /// `<=`
    Le,
    /// `>`
    Gt,
    /// `>=`
    Ge,
}

impl Cmp {
    /// Applies the comparison (false when either side is NaN).
    pub fn holds(self, l: f64, r: f64) -> bool {
        match self {
            Cmp::Lt => l < r,
            Cmp::Le => l <= r,
            Cmp::Gt => l > r,
            Cmp::Ge => l >= r,
        }
    }

    /// The operator as written.
    pub fn symbol(self) -> &'static str {
        match self {
            Cmp::Lt => "<",
            Cmp::Le => "<=",
            Cmp::Gt => ">",
            Cmp::Ge => ">=",
        }
    }
}

/// An expression node with its span.
#[derive(Clone, Debug, PartialEq)]
pub enum Expr<S> {
    /// A numeric literal; `int` is its value when written as an integer (`2`, `-3` after negation).
    Num {
        /// The value.
        value: f64,
        /// The integer value, when the literal is an integer.
        int: Option<i64>,
        /// Where.
        span: S,
    },
    /// An identifier (`theta`, a field or parameter, a provided name, `PI`) or a path joined with `::`
    /// (`std::f64::consts::PI`).
    Name {
        /// The name.
        name: String,
        /// Where.
        span: S,
    },
    /// Unary minus.
    Neg {
        /// The operand.
        arg: Box<Expr<S>>,
        /// Where.
        span: S,
    },
    /// `lhs op rhs`.
    Binary {
        /// The operator.
        op: BinOp,
        /// Left operand.
        lhs: Box<Expr<S>>,
        /// Right operand.
        rhs: Box<Expr<S>>,
        /// The operator's span.
        span: S,
    },
    /// A function call `f(args)`, or a method call `recv.f(args)` (then `args[0]` is the receiver).
    Call {
        /// The function or method name.
        func: String,
        /// The name's span.
        func_span: S,
        /// Arguments (the receiver first for a method call).
        args: Vec<Expr<S>>,
        /// Method spelling.
        method: bool,
    },
    /// `{ let NAME = EXPR; … EXPR }`.
    Block {
        /// The bindings, in order.
        lets: Vec<Let<S>>,
        /// The final expression.
        value: Box<Expr<S>>,
    },
    /// `if lhs CMP rhs { then } else { otherwise }`.
    If {
        /// The comparison.
        cmp: Cmp,
        /// Left side of the comparison.
        lhs: Box<Expr<S>>,
        /// Right side of the comparison.
        rhs: Box<Expr<S>>,
        /// Value when the comparison holds.
        then: Box<Expr<S>>,
        /// Value otherwise.
        otherwise: Box<Expr<S>>,
        /// The `if` keyword's span.
        span: S,
    },
    /// A construct the front end already reported as an error (lowering skips it silently).
    Invalid {
        /// Where.
        span: S,
    },
}

/// `let NAME = VALUE;`
#[derive(Clone, Debug, PartialEq)]
pub struct Let<S> {
    /// The bound name.
    pub name: String,
    /// The name's span.
    pub name_span: S,
    /// The value.
    pub value: Expr<S>,
}

impl<S: Copy> Expr<S> {
    /// A span that points at this node (the operator for binary nodes, the name for calls).
    pub fn span(&self) -> S {
        match self {
            Expr::Num { span, .. }
            | Expr::Name { span, .. }
            | Expr::Neg { span, .. }
            | Expr::Binary { span, .. }
            | Expr::If { span, .. }
            | Expr::Invalid { span } => *span,
            Expr::Call { func_span, .. } => *func_span,
            Expr::Block { value, .. } => value.span(),
        }
    }
}

impl<S> Expr<S> {
    /// Nodes of the tree (each literal, name, operator, call, block, binding and `if` counts one).
    pub fn node_count(&self) -> usize {
        match self {
            Expr::Num { .. } | Expr::Name { .. } | Expr::Invalid { .. } => 1,
            Expr::Neg { arg, .. } => 1 + arg.node_count(),
            Expr::Binary { lhs, rhs, .. } => 1 + lhs.node_count() + rhs.node_count(),
            Expr::Call { args, .. } => 1 + args.iter().map(Expr::node_count).sum::<usize>(),
            Expr::Block { lets, value } => {
                1 + value.node_count()
                    + lets.iter().map(|l| 1 + l.value.node_count()).sum::<usize>()
            }
            Expr::If {
                lhs,
                rhs,
                then,
                otherwise,
                ..
            } => {
                1 + lhs.node_count() + rhs.node_count() + then.node_count() + otherwise.node_count()
            }
        }
    }
}

/// The deepest nesting a ψ expression may have (operators, calls, blocks and `if`s each add a level). Deeper
/// input is rejected with an error rather than risking the stack of the recursive passes.
pub const MAX_DEPTH: usize = 128;
