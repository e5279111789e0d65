//! A small symbolic engine: a hash-consed expression arena (so equal subexpressions are one node — common
//! subexpression elimination for free), simplifying constructors, and differentiation with respect to θ or to
//! any input variable (parameter derivatives).
//!
//! Non-smooth nodes (`Select`, which `abs`, `min`, `max` and `if` lower to) differentiate branch-wise: the
//! derivative at a switch point is the derivative of the branch the condition selects there (for `abs(x)`
//! at `x = 0` that of `x`, for `min(a, b)` and `max(a, b)` at `a = b` that of `a`).

use std::collections::HashMap;

use crate::ast::Cmp;

/// Index of a node in the arena.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Debug, PartialOrd, Ord)]
pub struct Id(pub u32);

/// Unary functions of the grammar.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Debug)]
#[allow(missing_docs)]
pub enum Func {
    Sqrt,
    Sin,
    Cos,
    Tan,
    Exp,
    Ln,
    Atan,
    Tanh,
    Sinh,
    Cosh,
}

/// Every unary function, in the order the documentation lists them.
pub const FUNCS: [Func; 10] = [
    Func::Sqrt,
    Func::Sin,
    Func::Cos,
    Func::Tan,
    Func::Exp,
    Func::Ln,
    Func::Atan,
    Func::Tanh,
    Func::Sinh,
    Func::Cosh,
];

impl Func {
    /// The function's name (the method Rust calls).
    pub fn name(self) -> &'static str {
        match self {
            Func::Sqrt => "sqrt",
            Func::Sin => "sin",
            Func::Cos => "cos",
            Func::Tan => "tan",
            Func::Exp => "exp",
            Func::Ln => "ln",
            Func::Atan => "atan",
            Func::Tanh => "tanh",
            Func::Sinh => "sinh",
            Func::Cosh => "cosh",
        }
    }

    /// The function called `s`.
    pub fn from_name(s: &str) -> Option<Self> {
        FUNCS.into_iter().find(|f| f.name() == s)
    }

    /// The function applied to `x` (what generated code and the run-time program compute).
    pub fn apply(self, x: f64) -> f64 {
        match self {
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
        }
    }
}

/// A node. `Var(i)` is a θ-free input (struct field or provided quantity) numbered by the caller.
/// `Atan2(y, x)` is `y.atan2(x)` (θ-free operands only); `Select(cmp, l, r, a, b)` is `a` when `l cmp r`
/// holds, else `b`.
#[derive(Clone, Copy, PartialEq, Debug)]
#[allow(missing_docs)]
pub enum Node {
    Const(f64),
    Theta,
    Var(usize),
    Add(Id, Id),
    Sub(Id, Id),
    Mul(Id, Id),
    Div(Id, Id),
    Neg(Id),
    Powi(Id, i32),
    Powf(Id, Id),
    Call(Func, Id),
    Atan2(Id, Id),
    Select(Cmp, Id, Id, Id, Id),
}

#[derive(Clone, Copy, PartialEq, Eq, Hash, Debug)]
enum Key {
    Const(u64),
    Theta,
    Var(usize),
    Add(Id, Id),
    Sub(Id, Id),
    Mul(Id, Id),
    Div(Id, Id),
    Neg(Id),
    Powi(Id, i32),
    Powf(Id, Id),
    Call(Func, Id),
    Atan2(Id, Id),
    Select(Cmp, Id, Id, Id, Id),
}

fn key(n: &Node) -> Key {
    match *n {
        Node::Const(c) => Key::Const(c.to_bits()),
        Node::Theta => Key::Theta,
        Node::Var(i) => Key::Var(i),
        Node::Add(a, b) => Key::Add(a, b),
        Node::Sub(a, b) => Key::Sub(a, b),
        Node::Mul(a, b) => Key::Mul(a, b),
        Node::Div(a, b) => Key::Div(a, b),
        Node::Neg(a) => Key::Neg(a),
        Node::Powi(a, n) => Key::Powi(a, n),
        Node::Powf(a, b) => Key::Powf(a, b),
        Node::Call(f, a) => Key::Call(f, a),
        Node::Atan2(a, b) => Key::Atan2(a, b),
        Node::Select(c, l, r, a, b) => Key::Select(c, l, r, a, b),
    }
}

/// The arena. Every node records whether it depends on θ and which vars it uses.
#[derive(Default, Debug, Clone)]
pub struct Arena {
    /// The nodes; an [`Id`] indexes them.
    pub nodes: Vec<Node>,
    /// Whether each node depends on θ.
    pub theta_dep: Vec<bool>,
    /// Bit set of the vars a node depends on (vars are few: fields + six provided names; ≤ 64 supported).
    pub vars: Vec<u64>,
    index: HashMap<Key, Id>,
    derivative: HashMap<(Id, Wrt), Id>,
}

/// What a derivative is taken with respect to.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Debug)]
enum Wrt {
    Theta,
    Var(usize),
}

impl Arena {
    /// The node `id`.
    pub fn node(&self, id: Id) -> Node {
        self.nodes[id.0 as usize]
    }

    /// Whether `id` depends on θ.
    pub fn depends_on_theta(&self, id: Id) -> bool {
        self.theta_dep[id.0 as usize]
    }

    fn intern(&mut self, n: Node) -> Id {
        let k = key(&n);
        if let Some(&id) = self.index.get(&k) {
            return id;
        }
        let children = children_of(&n);
        let dep = matches!(n, Node::Theta) || children.iter().any(|c| self.theta_dep[c.0 as usize]);
        let mut vars = children
            .iter()
            .fold(0u64, |acc, c| acc | self.vars[c.0 as usize]);
        if let Node::Var(i) = n {
            vars |= 1u64 << i.min(63);
        }
        let id = Id(self.nodes.len() as u32);
        self.nodes.push(n);
        self.theta_dep.push(dep);
        self.vars.push(vars);
        self.index.insert(k, id);
        id
    }

    /// The constant `c`.
    pub fn constant(&mut self, c: f64) -> Id {
        // Normalise −0 to 0 so that identities see one zero.
        self.intern(Node::Const(if c == 0.0 { 0.0 } else { c }))
    }

    /// θ.
    pub fn theta(&mut self) -> Id {
        self.intern(Node::Theta)
    }

    /// Input variable `i`.
    pub fn var(&mut self, i: usize) -> Id {
        self.intern(Node::Var(i))
    }

    /// The value of a constant node.
    pub fn as_const(&self, id: Id) -> Option<f64> {
        match self.node(id) {
            Node::Const(c) => Some(c),
            _ => None,
        }
    }

    /// Splits `c · x` into (c, x) (c = 1 when there is no constant factor).
    fn coeff(&mut self, id: Id) -> (f64, Id) {
        match self.node(id) {
            Node::Mul(a, b) => match self.as_const(a) {
                Some(c) => (c, b),
                None => (1.0, id),
            },
            Node::Neg(a) => {
                let (c, x) = self.coeff(a);
                (-c, x)
            }
            _ => (1.0, id),
        }
    }

    /// `a + b`, simplified.
    pub fn add(&mut self, a: Id, b: Id) -> Id {
        match (self.as_const(a), self.as_const(b)) {
            (Some(x), Some(y)) => return self.constant(x + y),
            (Some(x), None) if x == 0.0 => return b,
            (None, Some(y)) if y == 0.0 => return a,
            _ => {}
        }
        if let Node::Neg(nb) = self.node(b) {
            return self.sub(a, nb);
        }
        if let Node::Neg(na) = self.node(a) {
            return self.sub(b, na);
        }
        // Like terms: c1·x + c2·x = (c1 + c2)·x.
        let (ca, xa) = self.coeff(a);
        let (cb, xb) = self.coeff(b);
        if xa == xb && self.as_const(xa).is_none() {
            let c = self.constant(ca + cb);
            return self.mul(c, xa);
        }
        // Constants last in sums, so `x + 1` and `1 + x` are one node.
        if self.as_const(a).is_some() || (self.as_const(b).is_none() && a > b) {
            return self.intern(Node::Add(b, a));
        }
        self.intern(Node::Add(a, b))
    }

    /// `a − b`, simplified.
    pub fn sub(&mut self, a: Id, b: Id) -> Id {
        match (self.as_const(a), self.as_const(b)) {
            (Some(x), Some(y)) => return self.constant(x - y),
            (Some(x), None) if x == 0.0 => return self.neg(b),
            (None, Some(y)) if y == 0.0 => return a,
            _ => {}
        }
        if a == b {
            return self.constant(0.0);
        }
        if let Node::Neg(nb) = self.node(b) {
            return self.add(a, nb);
        }
        let (ca, xa) = self.coeff(a);
        let (cb, xb) = self.coeff(b);
        if xa == xb && self.as_const(xa).is_none() {
            let c = self.constant(ca - cb);
            return self.mul(c, xa);
        }
        self.intern(Node::Sub(a, b))
    }

    /// `a · b`, simplified.
    pub fn mul(&mut self, a: Id, b: Id) -> Id {
        match (self.as_const(a), self.as_const(b)) {
            (Some(x), Some(y)) => return self.constant(x * y),
            (Some(x), _) if x == 0.0 => return a,
            (_, Some(y)) if y == 0.0 => return b,
            (Some(x), _) if x == 1.0 => return b,
            (_, Some(y)) if y == 1.0 => return a,
            (Some(x), _) if x == -1.0 => return self.neg(b),
            (_, Some(y)) if y == -1.0 => return self.neg(a),
            (None, Some(_)) => return self.mul(b, a),
            _ => {}
        }
        // c1 · (c2 · x) = (c1 c2) · x
        if let (Some(c1), Node::Mul(p, q)) = (self.as_const(a), self.node(b))
            && let Some(c2) = self.as_const(p)
        {
            let c = self.constant(c1 * c2);
            return self.mul(c, q);
        }
        // Constant factors to the front, where they merge: (c·x)·y = c·(x·y), x·(c·y) = c·(x·y). Both
        // back ends evaluate the result, so they stay bitwise equal; the derivatives of products of
        // scaled factors (2 tan(θ/2)…) lose a multiplication per factor.
        if self.as_const(a).is_none() && self.as_const(b).is_none() {
            if let Node::Mul(p, x) = self.node(a)
                && let Some(c) = self.as_const(p)
            {
                let m = self.mul(x, b);
                let cc = self.constant(c);
                return self.mul(cc, m);
            }
            if let Node::Mul(p, y) = self.node(b)
                && let Some(c) = self.as_const(p)
            {
                let m = self.mul(a, y);
                let cc = self.constant(c);
                return self.mul(cc, m);
            }
        }
        if let Node::Neg(na) = self.node(a) {
            let m = self.mul(na, b);
            return self.neg(m);
        }
        if let Node::Neg(nb) = self.node(b) {
            let m = self.mul(a, nb);
            return self.neg(m);
        }
        if a == b && self.as_const(a).is_none() {
            return self.powi(a, 2);
        }
        // Canonical order for commutative products of non-constants.
        if self.as_const(a).is_none() && a > b {
            return self.intern(Node::Mul(b, a));
        }
        self.intern(Node::Mul(a, b))
    }

    /// `a / b`, simplified.
    pub fn div(&mut self, a: Id, b: Id) -> Id {
        match (self.as_const(a), self.as_const(b)) {
            (Some(x), Some(y)) if y != 0.0 => return self.constant(x / y),
            (Some(x), _) if x == 0.0 => return a,
            (_, Some(y)) if y == 1.0 => return a,
            (_, Some(y)) if y == -1.0 => return self.neg(a),
            _ => {}
        }
        if a == b {
            return self.constant(1.0);
        }
        // Division by a power of two is an exact multiplication by its reciprocal (and cheaper).
        if let Some(y) = self.as_const(b)
            && y != 0.0
            && y.is_finite()
            && (1.0 / y).is_finite()
            && (1.0 / y) * y == 1.0
            && y.abs().log2().fract() == 0.0
        {
            let r = self.constant(1.0 / y);
            return self.mul(r, a);
        }
        self.intern(Node::Div(a, b))
    }

    /// `−a`, simplified.
    pub fn neg(&mut self, a: Id) -> Id {
        match self.node(a) {
            Node::Const(c) => self.constant(-c),
            Node::Neg(x) => x,
            Node::Sub(x, y) => self.sub(y, x),
            _ => self.intern(Node::Neg(a)),
        }
    }

    /// `a^n`, simplified.
    pub fn powi(&mut self, a: Id, n: i32) -> Id {
        if let Some(c) = self.as_const(a) {
            return self.constant(c.powi(n));
        }
        match n {
            0 => self.constant(1.0),
            1 => a,
            _ => match self.node(a) {
                Node::Powi(x, m) if m.checked_mul(n).is_some() => self.powi(x, m * n),
                _ => self.intern(Node::Powi(a, n)),
            },
        }
    }

    /// `a^b` (b θ-free), simplified.
    pub fn powf(&mut self, a: Id, b: Id) -> Id {
        match (self.as_const(a), self.as_const(b)) {
            (Some(x), Some(y)) => return self.constant(x.powf(y)),
            (_, Some(y)) if y == 1.0 => return a,
            (_, Some(y)) if y == 0.0 => return self.constant(1.0),
            (_, Some(y)) if y.fract() == 0.0 && y.abs() <= 64.0 => return self.powi(a, y as i32),
            _ => {}
        }
        self.intern(Node::Powf(a, b))
    }

    /// `f(a)`, simplified.
    pub fn call(&mut self, f: Func, a: Id) -> Id {
        if let Some(c) = self.as_const(a) {
            return self.constant(f.apply(c));
        }
        self.intern(Node::Call(f, a))
    }

    /// dψ/dθ of node `id`, simplified and interned (recursive: the depth is bounded by the front ends).
    pub fn diff(&mut self, id: Id) -> Id {
        self.derivative(id, Wrt::Theta)
    }

    /// ∂/∂v of node `id` for input variable `v` (a field, a run-time parameter or a provided name such as
    /// `theta_bar`), θ and every other variable held fixed: what parameter derivatives (fitting) need.
    /// Simplified and interned like [`Arena::diff`]; `Select` differentiates branch-wise the same way.
    pub fn diff_var(&mut self, id: Id, v: usize) -> Id {
        self.derivative(id, Wrt::Var(v))
    }

    /// Whether `id` depends on what `wrt` names.
    fn depends_on(&self, id: Id, wrt: Wrt) -> bool {
        match wrt {
            Wrt::Theta => self.depends_on_theta(id),
            Wrt::Var(v) => v < 64 && self.vars[id.0 as usize] >> v & 1 == 1,
        }
    }

    fn derivative(&mut self, id: Id, wrt: Wrt) -> Id {
        if !self.depends_on(id, wrt) {
            return self.constant(0.0);
        }
        if let Some(&d) = self.derivative.get(&(id, wrt)) {
            return d;
        }
        let d = match self.node(id) {
            Node::Const(_) => self.constant(0.0),
            Node::Theta => self.constant(if wrt == Wrt::Theta { 1.0 } else { 0.0 }),
            Node::Var(i) => self.constant(if wrt == Wrt::Var(i) { 1.0 } else { 0.0 }),
            Node::Add(a, b) => {
                let (da, db) = (self.derivative(a, wrt), self.derivative(b, wrt));
                self.add(da, db)
            }
            Node::Sub(a, b) => {
                let (da, db) = (self.derivative(a, wrt), self.derivative(b, wrt));
                self.sub(da, db)
            }
            Node::Mul(a, b) => {
                let (da, db) = (self.derivative(a, wrt), self.derivative(b, wrt));
                let l = self.mul(da, b);
                let r = self.mul(a, db);
                self.add(l, r)
            }
            Node::Div(a, b) => {
                // (a/b)′ = (a′ − (a/b)·b′) / b
                let (da, db) = (self.derivative(a, wrt), self.derivative(b, wrt));
                let t = self.mul(id, db);
                let num = self.sub(da, t);
                self.div(num, b)
            }
            Node::Neg(a) => {
                let da = self.derivative(a, wrt);
                self.neg(da)
            }
            Node::Powi(a, n) => {
                // n · a^(n−1) · a′
                let da = self.derivative(a, wrt);
                let p = self.powi(a, n - 1);
                let c = self.constant(n as f64);
                let cp = self.mul(c, p);
                self.mul(cp, da)
            }
            Node::Powf(a, b) => {
                // b · a^(b−1) · a′ (+ a^b · ln(a) · b′ when the exponent depends on the variable: it never
                // does for θ, which the parser keeps out of exponents)
                let da = self.derivative(a, wrt);
                let one = self.constant(1.0);
                let bm1 = self.sub(b, one);
                let p = self.powf(a, bm1);
                let bp = self.mul(b, p);
                let base = self.mul(bp, da);
                let db = self.derivative(b, wrt);
                if self.as_const(db) == Some(0.0) {
                    base
                } else {
                    let ln = self.call(Func::Ln, a);
                    let t = self.mul(id, ln);
                    let e = self.mul(t, db);
                    self.add(base, e)
                }
            }
            Node::Call(f, a) => {
                let da = self.derivative(a, wrt);
                let outer = match f {
                    Func::Sqrt => {
                        // 1 / (2 sqrt(a))
                        let two = self.constant(2.0);
                        let den = self.mul(two, id);
                        let one = self.constant(1.0);
                        self.div(one, den)
                    }
                    Func::Sin => self.call(Func::Cos, a),
                    Func::Cos => {
                        let s = self.call(Func::Sin, a);
                        self.neg(s)
                    }
                    Func::Tan => {
                        let one = self.constant(1.0);
                        let t2 = self.powi(id, 2);
                        self.add(one, t2)
                    }
                    Func::Exp => id,
                    Func::Ln => {
                        let one = self.constant(1.0);
                        self.div(one, a)
                    }
                    Func::Atan => {
                        let one = self.constant(1.0);
                        let a2 = self.powi(a, 2);
                        let den = self.add(one, a2);
                        self.div(one, den)
                    }
                    Func::Tanh => {
                        let one = self.constant(1.0);
                        let t2 = self.powi(id, 2);
                        self.sub(one, t2)
                    }
                    Func::Sinh => self.call(Func::Cosh, a),
                    Func::Cosh => self.call(Func::Sinh, a),
                };
                self.mul(outer, da)
            }
            Node::Atan2(y, x) => match wrt {
                // θ-free by construction (the front end rejects θ in its operands): reached only if not.
                Wrt::Theta => self.constant(f64::NAN),
                // (x·y′ − y·x′) / (x² + y²)
                Wrt::Var(_) => {
                    let (dy, dx) = (self.derivative(y, wrt), self.derivative(x, wrt));
                    let l = self.mul(x, dy);
                    let r = self.mul(y, dx);
                    let num = self.sub(l, r);
                    let (x2, y2) = (self.powi(x, 2), self.powi(y, 2));
                    let den = self.add(x2, y2);
                    self.div(num, den)
                }
            },
            Node::Select(c, l, r, a, b) => {
                let (da, db) = (self.derivative(a, wrt), self.derivative(b, wrt));
                self.select(c, l, r, da, db)
            }
        };
        self.derivative.insert((id, wrt), d);
        d
    }

    /// `y.atan2(x)`, simplified (constant operands fold).
    pub fn atan2(&mut self, y: Id, x: Id) -> Id {
        if let (Some(a), Some(b)) = (self.as_const(y), self.as_const(x)) {
            return self.constant(a.atan2(b));
        }
        self.intern(Node::Atan2(y, x))
    }

    /// `if l cmp r { a } else { b }`, simplified (constant conditions and equal branches fold).
    pub fn select(&mut self, cmp: Cmp, l: Id, r: Id, a: Id, b: Id) -> Id {
        if a == b {
            return a;
        }
        if let (Some(x), Some(y)) = (self.as_const(l), self.as_const(r)) {
            return if cmp.holds(x, y) { a } else { b };
        }
        self.intern(Node::Select(cmp, l, r, a, b))
    }

    /// Children of a node.
    pub fn children(&self, id: Id) -> Vec<Id> {
        children_of(&self.node(id))
    }
}

/// The operands of a node, in the order the schedule and the programs read them.
pub fn children_of(n: &Node) -> Vec<Id> {
    match *n {
        Node::Const(_) | Node::Theta | Node::Var(_) => vec![],
        Node::Add(a, b)
        | Node::Sub(a, b)
        | Node::Mul(a, b)
        | Node::Div(a, b)
        | Node::Powf(a, b)
        | Node::Atan2(a, b) => vec![a, b],
        Node::Neg(a) | Node::Powi(a, _) | Node::Call(_, a) => vec![a],
        Node::Select(_, l, r, a, b) => vec![l, r, a, b],
    }
}
