//! From one ψ node to everything both back ends need: ψ′ and ψ″ by [`Arena::diff`], the θ-dependent nodes in
//! evaluation order, and the θ-free nodes hoisted out of them (computed per hinge at set-up, or per step when
//! they read `theta_prev` or `dt`). The derive turns a [`Compiled`] into Rust code; [`Tape`] turns it into a
//! register program for run time. Both evaluate the same nodes with the same operations in the same order.

use std::collections::HashMap;
use std::ops::{Add, Div, Mul, Neg, Sub};

use crate::ast::Cmp;
use crate::lower::PROVIDED;
use crate::sym::{Arena, Func, Id, Node};

/// A ψ with its two derivatives, scheduled.
#[derive(Debug, Clone)]
pub struct Compiled {
    /// The arena holding ψ, ψ′, ψ″.
    pub arena: Arena,
    /// `[ψ, ψ′, ψ″]`.
    pub roots: [Id; 3],
    /// θ-dependent nodes of all three roots, operands first.
    pub order: Vec<Id>,
    /// θ-free, non-constant nodes the θ-dependent ones (or the roots) read: the per-hinge parameters.
    pub hoisted: Vec<Id>,
    /// The caller's inputs (fields or parameters); vars `n_inputs..` are [`PROVIDED`].
    pub n_inputs: usize,
}

impl Compiled {
    /// Differentiates `psi` twice and schedules it.
    pub fn new(mut arena: Arena, psi: Id, n_inputs: usize) -> Self {
        let d1 = arena.diff(psi);
        let d2 = arena.diff(d1);
        let roots = [psi, d1, d2];
        let (order, hoisted) = schedule(&arena, &roots);
        Self {
            arena,
            roots,
            order,
            hoisted,
            n_inputs,
        }
    }

    /// The θ-dependent nodes needed for `roots` alone (a subset of [`Compiled::order`], in the same relative
    /// order, so ψ and ψ′ computed alone are bitwise those of the full program).
    pub fn order_for(&self, roots: &[Id]) -> Vec<Id> {
        schedule(&self.arena, roots).0
    }

    /// Whether a node reads a step quantity (`theta_prev`, `dt`).
    pub fn reads_step(&self, id: Id) -> bool {
        let step_mask: u64 = (1u64 << (self.n_inputs + 4)) | (1u64 << (self.n_inputs + 5));
        self.arena.vars[id.0 as usize] & step_mask != 0
    }

    /// Whether any hoisted value reads a step quantity (then it is refreshed every time step).
    pub fn uses_step(&self) -> bool {
        self.hoisted.iter().any(|&h| self.reads_step(h))
    }

    /// Bit set of the vars the hoisted values read.
    pub fn used_vars(&self) -> u64 {
        self.hoisted
            .iter()
            .fold(0u64, |acc, &h| acc | self.arena.vars[h.0 as usize])
    }

    /// Whether ψ″ ≡ 0 (ψ affine in θ).
    pub fn d2_is_zero(&self) -> bool {
        self.arena.as_const(self.roots[2]) == Some(0.0)
    }

    /// Total number of vars: inputs plus the provided names.
    pub fn n_vars(&self) -> usize {
        self.n_inputs + PROVIDED.len()
    }
}

/// Parameter derivatives of a compiled ψ: for each chosen input variable v (a field, a run-time parameter or a
/// provided name such as `theta_bar`), `∂ψ/∂v` and `∂ψ′/∂v` with θ and the other variables held fixed, in an
/// extended copy of the arena, scheduled over θ and every variable (nothing hoisted: fitting evaluates them
/// once per hinge and solve, not per Newton iteration). Equal subexpressions are shared as everywhere else.
#[derive(Debug, Clone)]
pub struct ParameterDerivatives {
    /// The variables, in the order of [`ParameterDerivatives::roots`].
    pub vars: Vec<usize>,
    /// The arena: [`Compiled::arena`] plus the derivative nodes.
    pub arena: Arena,
    /// `[∂ψ/∂v, ∂ψ′/∂v]` for each of [`ParameterDerivatives::vars`].
    pub roots: Vec<[Id; 2]>,
    /// Every non-leaf node the roots need, operands first (θ, variables and constants are leaves).
    pub order: Vec<Id>,
    /// Total number of variables (inputs plus the provided names).
    pub n_vars: usize,
}

impl Compiled {
    /// `∂ψ/∂v` and `∂ψ′/∂v` for each of `vars` (see [`ParameterDerivatives`]).
    pub fn parameter_derivatives(&self, vars: &[usize]) -> ParameterDerivatives {
        let mut arena = self.arena.clone();
        let [psi, d1, _] = self.roots;
        let roots: Vec<[Id; 2]> = vars
            .iter()
            .map(|&v| [arena.diff_var(psi, v), arena.diff_var(d1, v)])
            .collect();
        let flat: Vec<Id> = roots.iter().flatten().copied().collect();
        let order = free_schedule(&arena, &flat);
        ParameterDerivatives {
            vars: vars.to_vec(),
            arena,
            roots,
            order,
            n_vars: self.n_vars(),
        }
    }
}

impl ParameterDerivatives {
    /// Bit set of the variables the derivatives read.
    pub fn used_vars(&self) -> u64 {
        self.roots
            .iter()
            .flatten()
            .fold(0u64, |acc, r| acc | self.arena.vars[r.0 as usize])
    }

    /// A register program reading `[θ, v_0, …, v_{n_vars−1}]` and writing `∂ψ/∂v, ∂ψ′/∂v` for every chosen
    /// variable in turn (`2 · vars.len()` outputs). `None` beyond [`MAX_REGISTERS`] registers.
    pub fn program(&self) -> Option<Program> {
        let mut arena = self.arena.clone();
        let mut inputs = vec![arena.theta()];
        for i in 0..self.n_vars {
            inputs.push(arena.var(i));
        }
        let flat: Vec<Id> = self.roots.iter().flatten().copied().collect();
        Program::new(&arena, &inputs, &self.order, &flat)
    }
}

/// Nodes reachable from `roots` through θ-dependent nodes, in post-order (operands first), and the θ-free
/// non-constant nodes where that walk stops.
fn schedule(arena: &Arena, roots: &[Id]) -> (Vec<Id>, Vec<Id>) {
    let mut order = Vec::new();
    let mut hoisted = Vec::new();
    let mut seen = vec![false; arena.nodes.len()];
    // Iterative post-order (expressions are depth-limited, but derivatives of deep ones are deeper still).
    for &r in roots {
        let mut stack = vec![(r, false)];
        while let Some((id, expanded)) = stack.pop() {
            let i = id.0 as usize;
            if expanded {
                order.push(id);
                continue;
            }
            if seen[i] {
                continue;
            }
            seen[i] = true;
            if !arena.depends_on_theta(id) {
                if arena.as_const(id).is_none() {
                    hoisted.push(id);
                }
                continue;
            }
            stack.push((id, true));
            for c in arena.children(id).into_iter().rev() {
                if !seen[c.0 as usize] {
                    stack.push((c, false));
                }
            }
        }
    }
    (order, hoisted)
}

/// What one instruction computes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Op {
    /// `a + b`
    Add,
    /// `a − b`
    Sub,
    /// `a · b`
    Mul,
    /// `a / b`
    Div,
    /// `−a`
    Neg,
    /// `a · a` (what `powi(2)` compiles to in both back ends)
    Square,
    /// `a.powi(n)`
    Powi(i32),
    /// `a.powf(b)`
    Powf,
    /// `f(a)`
    Call(Func),
    /// `a.atan2(b)`
    Atan2,
    /// `if a cmp b { c } else { d }`
    Select(Cmp),
    // Two binary operations in one instruction (a superinstruction: one dispatch instead of two), made by
    // `fuse` where the first result's only use is the second. The same operations on the same operands, in
    // the same order: the result is bitwise that of the two instructions. `L`: the first result is the left
    // operand of the second, `R`: the right one.
    /// `(a + b) + c`
    AddAddL,
    /// `c + (a + b)`
    AddAddR,
    /// `(a + b) - c`
    AddSubL,
    /// `c - (a + b)`
    AddSubR,
    /// `(a + b) * c`
    AddMulL,
    /// `c * (a + b)`
    AddMulR,
    /// `(a + b) / c`
    AddDivL,
    /// `c / (a + b)`
    AddDivR,
    /// `(a - b) + c`
    SubAddL,
    /// `c + (a - b)`
    SubAddR,
    /// `(a - b) - c`
    SubSubL,
    /// `c - (a - b)`
    SubSubR,
    /// `(a - b) * c`
    SubMulL,
    /// `c * (a - b)`
    SubMulR,
    /// `(a - b) / c`
    SubDivL,
    /// `c / (a - b)`
    SubDivR,
    /// `(a * b) + c`
    MulAddL,
    /// `c + (a * b)`
    MulAddR,
    /// `(a * b) - c`
    MulSubL,
    /// `c - (a * b)`
    MulSubR,
    /// `(a * b) * c`
    MulMulL,
    /// `c * (a * b)`
    MulMulR,
    /// `(a * b) / c`
    MulDivL,
    /// `c / (a * b)`
    MulDivR,
    /// `(a / b) + c`
    DivAddL,
    /// `c + (a / b)`
    DivAddR,
    /// `(a / b) - c`
    DivSubL,
    /// `c - (a / b)`
    DivSubR,
    /// `(a / b) * c`
    DivMulL,
    /// `c * (a / b)`
    DivMulR,
    /// `(a / b) / c`
    DivDivL,
    /// `c / (a / b)`
    DivDivR,
}

/// One instruction: `r[dst] = op(r[args[0]], …)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instr {
    /// The operation.
    pub op: Op,
    /// Destination register.
    pub dst: u16,
    /// Operand registers (unused ones are 0).
    pub args: [u16; 4],
}

/// The arithmetic a program runs on: `f64`, or a dual number for automatic differentiation.
pub trait Scalar:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant.
    fn from_f64(v: f64) -> Self;
    /// The real part (what a comparison compares).
    fn re(&self) -> f64;
    /// `self^n`.
    fn powi(self, n: i32) -> Self;
    /// `self^e` for a θ-free exponent.
    fn powf(self, e: Self) -> Self;
    /// `f(self)`.
    fn func(self, f: Func) -> Self;
    /// `self.atan2(x)` (θ-free operands).
    fn atan2(self, x: Self) -> Self;
}

impl Scalar for f64 {
    #[inline]
    fn from_f64(v: f64) -> Self {
        v
    }
    #[inline]
    fn re(&self) -> f64 {
        *self
    }
    #[inline]
    fn powi(self, n: i32) -> Self {
        f64::powi(self, n)
    }
    #[inline]
    fn powf(self, e: Self) -> Self {
        f64::powf(self, e)
    }
    #[inline]
    fn func(self, f: Func) -> Self {
        f.apply(self)
    }
    #[inline]
    fn atan2(self, x: Self) -> Self {
        f64::atan2(self, x)
    }
}

/// The instruction loop on a register file `$r`, every index masked by `$mask` (for an array of
/// power-of-two length `R`, `R − 1` lets the compiler drop the bounds checks).
macro_rules! exec_loop {
    ($code:expr, $r:ident, $mask:expr) => {{
        let mask = $mask;
        let at = |i: u16| usize::from(i) & mask;
        for ins in $code {
            let [a, b, c, d] = ins.args;
            let v = match ins.op {
                Op::Add => $r[at(a)] + $r[at(b)],
                Op::Sub => $r[at(a)] - $r[at(b)],
                Op::Mul | Op::Square => $r[at(a)] * $r[at(b)],
                Op::Div => $r[at(a)] / $r[at(b)],
                Op::Neg => -$r[at(a)],
                Op::Powi(k) => $r[at(a)].powi(k),
                Op::Powf => $r[at(a)].powf($r[at(b)]),
                Op::Call(f) => $r[at(a)].func(f),
                Op::Atan2 => $r[at(a)].atan2($r[at(b)]),
                Op::AddAddL => ($r[at(a)] + $r[at(b)]) + $r[at(c)],
                Op::AddAddR => $r[at(c)] + ($r[at(a)] + $r[at(b)]),
                Op::AddSubL => ($r[at(a)] + $r[at(b)]) - $r[at(c)],
                Op::AddSubR => $r[at(c)] - ($r[at(a)] + $r[at(b)]),
                Op::AddMulL => ($r[at(a)] + $r[at(b)]) * $r[at(c)],
                Op::AddMulR => $r[at(c)] * ($r[at(a)] + $r[at(b)]),
                Op::AddDivL => ($r[at(a)] + $r[at(b)]) / $r[at(c)],
                Op::AddDivR => $r[at(c)] / ($r[at(a)] + $r[at(b)]),
                Op::SubAddL => ($r[at(a)] - $r[at(b)]) + $r[at(c)],
                Op::SubAddR => $r[at(c)] + ($r[at(a)] - $r[at(b)]),
                Op::SubSubL => ($r[at(a)] - $r[at(b)]) - $r[at(c)],
                Op::SubSubR => $r[at(c)] - ($r[at(a)] - $r[at(b)]),
                Op::SubMulL => ($r[at(a)] - $r[at(b)]) * $r[at(c)],
                Op::SubMulR => $r[at(c)] * ($r[at(a)] - $r[at(b)]),
                Op::SubDivL => ($r[at(a)] - $r[at(b)]) / $r[at(c)],
                Op::SubDivR => $r[at(c)] / ($r[at(a)] - $r[at(b)]),
                Op::MulAddL => ($r[at(a)] * $r[at(b)]) + $r[at(c)],
                Op::MulAddR => $r[at(c)] + ($r[at(a)] * $r[at(b)]),
                Op::MulSubL => ($r[at(a)] * $r[at(b)]) - $r[at(c)],
                Op::MulSubR => $r[at(c)] - ($r[at(a)] * $r[at(b)]),
                Op::MulMulL => ($r[at(a)] * $r[at(b)]) * $r[at(c)],
                Op::MulMulR => $r[at(c)] * ($r[at(a)] * $r[at(b)]),
                Op::MulDivL => ($r[at(a)] * $r[at(b)]) / $r[at(c)],
                Op::MulDivR => $r[at(c)] / ($r[at(a)] * $r[at(b)]),
                Op::DivAddL => ($r[at(a)] / $r[at(b)]) + $r[at(c)],
                Op::DivAddR => $r[at(c)] + ($r[at(a)] / $r[at(b)]),
                Op::DivSubL => ($r[at(a)] / $r[at(b)]) - $r[at(c)],
                Op::DivSubR => $r[at(c)] - ($r[at(a)] / $r[at(b)]),
                Op::DivMulL => ($r[at(a)] / $r[at(b)]) * $r[at(c)],
                Op::DivMulR => $r[at(c)] * ($r[at(a)] / $r[at(b)]),
                Op::DivDivL => ($r[at(a)] / $r[at(b)]) / $r[at(c)],
                Op::DivDivR => $r[at(c)] / ($r[at(a)] / $r[at(b)]),
                Op::Select(cmp) => {
                    if cmp.holds($r[at(a)].re(), $r[at(b)].re()) {
                        $r[at(c)]
                    } else {
                        $r[at(d)]
                    }
                }
            };
            $r[at(ins.dst)] = v;
        }
    }};
}

/// A straight-line register program. Registers `0..n_inputs` are loaded by the caller, then come the
/// constants, then temporaries (reused once their value is dead).
#[derive(Clone, Debug, PartialEq)]
pub struct Program {
    n_inputs: usize,
    /// The register file as a call starts it: the constants in place, zeros elsewhere (as long as the
    /// register tier, so that the copy has a length known at compile time).
    template: Vec<f64>,
    code: Vec<Instr>,
    outputs: Vec<u16>,
    n_regs: usize,
}

/// The largest register file a program may need (the expression is rejected beyond it).
pub const MAX_REGISTERS: usize = 1024;

impl Program {
    /// Compiles the nodes `order` (operands first) computing `outputs`, reading the nodes of `inputs` from
    /// registers `0..inputs.len()`. `None` when the program needs more than [`MAX_REGISTERS`] registers.
    pub fn new(arena: &Arena, inputs: &[Id], order: &[Id], outputs: &[Id]) -> Option<Self> {
        Self::with_input_slots(arena, inputs, inputs.len(), order, outputs)
    }

    /// [`Program::new`] with registers `0..slots` reserved for inputs (`slots ≥ inputs.len()`), so that a
    /// caller may load a fixed-size block of them.
    pub fn with_input_slots(
        arena: &Arena,
        inputs: &[Id],
        slots: usize,
        order: &[Id],
        outputs: &[Id],
    ) -> Option<Self> {
        let slots = slots.max(inputs.len());
        let mut reg: HashMap<Id, u16> = HashMap::new();
        for (k, &id) in inputs.iter().enumerate() {
            reg.insert(id, u16::try_from(k).ok()?);
        }
        // Constants read by the program (operands of `order`, or outputs themselves).
        let mut consts = Vec::new();
        let const_of = |id: Id, reg: &mut HashMap<Id, u16>, consts: &mut Vec<f64>| -> Option<()> {
            if let (None, Some(c)) = (reg.get(&id), arena.as_const(id)) {
                reg.insert(id, u16::try_from(slots + consts.len()).ok()?);
                consts.push(c);
            }
            Some(())
        };
        for &id in order {
            for c in operands(arena.node(id)) {
                const_of(c, &mut reg, &mut consts)?;
            }
        }
        for &o in outputs {
            const_of(o, &mut reg, &mut consts)?;
        }
        let fixed = slots + consts.len();
        // Last use of every node's value (outputs live to the end).
        let mut last: HashMap<Id, usize> = HashMap::new();
        for (t, &id) in order.iter().enumerate() {
            for c in operands(arena.node(id)) {
                last.insert(c, t);
            }
        }
        for &o in outputs {
            last.insert(o, usize::MAX);
        }
        let mut free: Vec<u16> = Vec::new();
        let mut n_regs = fixed;
        let mut code = Vec::with_capacity(order.len());
        for (t, &id) in order.iter().enumerate() {
            if reg.contains_key(&id) {
                // θ itself (an input register), scheduled like any θ-dependent node.
                continue;
            }
            let node = arena.node(id);
            let ops: Vec<Id> = operands(node);
            let mut args = [0u16; 4];
            for (k, c) in ops.iter().enumerate() {
                args[k] = *reg.get(c)?;
            }
            // Operands dying here free their registers before the destination is chosen (it may reuse one:
            // every operand is read before the result is written).
            for c in &ops {
                if last.get(c) == Some(&t)
                    && let Some(&r) = reg.get(c)
                    && usize::from(r) >= fixed
                    && !free.contains(&r)
                {
                    free.push(r);
                }
            }
            let dst = match free.pop() {
                Some(r) => r,
                None => {
                    n_regs += 1;
                    u16::try_from(n_regs - 1).ok()?
                }
            };
            reg.insert(id, dst);
            let op = match node {
                Node::Add(..) => Op::Add,
                Node::Sub(..) => Op::Sub,
                Node::Mul(..) => Op::Mul,
                Node::Div(..) => Op::Div,
                Node::Neg(_) => Op::Neg,
                Node::Powi(_, 2) => Op::Square,
                Node::Powi(_, n) => Op::Powi(n),
                Node::Powf(..) => Op::Powf,
                Node::Call(f, _) => Op::Call(f),
                Node::Atan2(..) => Op::Atan2,
                Node::Select(c, ..) => Op::Select(c),
                // Leaves are inputs or constants, never scheduled.
                Node::Const(_) | Node::Theta | Node::Var(_) => return None,
            };
            if matches!(op, Op::Square) {
                args[1] = args[0];
            }
            code.push(Instr { op, dst, args });
        }
        let outputs = outputs
            .iter()
            .map(|o| reg.get(o).copied())
            .collect::<Option<Vec<u16>>>()?;
        let code = fuse(code, &outputs);
        if n_regs > MAX_REGISTERS {
            return None;
        }
        let mut template = vec![0.0; tier(n_regs)];
        template[slots..slots + consts.len()].copy_from_slice(&consts);
        Some(Self {
            n_inputs: slots,
            template,
            code,
            outputs,
            n_regs,
        })
    }

    /// Registers the program needs.
    pub fn registers(&self) -> usize {
        self.n_regs
    }

    /// Instructions.
    pub fn len(&self) -> usize {
        self.code.len()
    }

    /// Whether the program has no instructions (its outputs are inputs or constants).
    pub fn is_empty(&self) -> bool {
        self.code.is_empty()
    }

    /// Runs the program on `inputs` (at least as many as it was compiled for), writing its outputs to `out`
    /// (as many as it has). No allocation: the register file lives on the stack.
    #[inline]
    pub fn run<T: Scalar>(&self, inputs: &[T], out: &mut [T]) {
        match tier(self.n_regs) {
            8 => self.run_with::<T, 8, 0>(None, inputs, &[], out),
            16 => self.run_with::<T, 16, 0>(None, inputs, &[], out),
            32 => self.run_with::<T, 32, 0>(None, inputs, &[], out),
            64 => self.run_with::<T, 64, 0>(None, inputs, &[], out),
            _ => self.run_large(None, inputs, out),
        }
    }

    /// Runs a θ program of a [`Tape`] compiled for `P` parameter slots: register 0 is `theta`, registers
    /// `1..=P` the hoisted `params` (a fixed-size block).
    #[inline]
    pub fn run_theta<T: Scalar, const P: usize>(&self, theta: T, params: &[T; P], out: &mut [T]) {
        match tier(self.n_regs) {
            8 => self.run_with::<T, 8, P>(Some(theta), &[], params, out),
            16 => self.run_with::<T, 16, P>(Some(theta), &[], params, out),
            32 => self.run_with::<T, 32, P>(Some(theta), &[], params, out),
            64 => self.run_with::<T, 64, P>(Some(theta), &[], params, out),
            _ => self.run_large(Some(theta), params, out),
        }
    }

    #[inline]
    fn run_with<T: Scalar, const R: usize, const P: usize>(
        &self,
        theta: Option<T>,
        inputs: &[T],
        params: &[T; P],
        out: &mut [T],
    ) {
        // One pass over the register file: the template (constants), then the inputs over it.
        let template = &self.template[..R];
        let mut r: [T; R] = std::array::from_fn(|i| T::from_f64(template[i]));
        match theta {
            // A θ program: the fixed block [θ, p_0, …, p_{P−1}] (its register count is at least 1 + P).
            Some(t) if P < R => {
                r[0] = t;
                r[1..=P].copy_from_slice(params);
            }
            Some(_) => return,
            None => {
                let n = self.n_inputs;
                r[..n].copy_from_slice(&inputs[..n]);
            }
        }
        // R is a power of two and every register index is below it: masking lets the compiler drop the
        // bounds checks without `unsafe`.
        exec_loop!(&self.code, r, R - 1);
        for (o, &k) in out.iter_mut().zip(&self.outputs) {
            *o = r[usize::from(k) & (R - 1)];
        }
    }

    /// Programs of more than 64 registers: the register file on the heap (one allocation per call; a
    /// stack array of 1024 dual numbers would not fit a thread's stack), never inlined.
    #[inline(never)]
    fn run_large<T: Scalar>(&self, theta: Option<T>, inputs: &[T], out: &mut [T]) {
        let mut r: Vec<T> = self.template.iter().map(|&c| T::from_f64(c)).collect();
        match theta {
            Some(t) => {
                r[0] = t;
                r[1..=inputs.len()].copy_from_slice(inputs);
            }
            None => {
                let n = self.n_inputs;
                r[..n].copy_from_slice(&inputs[..n]);
            }
        }
        exec_loop!(&self.code, r, usize::MAX);
        for (o, &k) in out.iter_mut().zip(&self.outputs) {
            *o = r[usize::from(k)];
        }
    }
}

/// The four binary operations that [`fuse`] combines.
#[derive(Clone, Copy, PartialEq)]
enum Bin {
    Add,
    Sub,
    Mul,
    Div,
}

fn bin_of(op: Op) -> Option<Bin> {
    match op {
        Op::Add => Some(Bin::Add),
        Op::Sub => Some(Bin::Sub),
        Op::Mul | Op::Square => Some(Bin::Mul),
        Op::Div => Some(Bin::Div),
        _ => None,
    }
}

/// The fused instruction of `first` then `second` (`left`: the first result is the second's left operand).
fn fused_op(first: Bin, second: Bin, left: bool) -> Op {
    match (first, second, left) {
        (Bin::Add, Bin::Add, true) => Op::AddAddL,
        (Bin::Add, Bin::Add, false) => Op::AddAddR,
        (Bin::Add, Bin::Sub, true) => Op::AddSubL,
        (Bin::Add, Bin::Sub, false) => Op::AddSubR,
        (Bin::Add, Bin::Mul, true) => Op::AddMulL,
        (Bin::Add, Bin::Mul, false) => Op::AddMulR,
        (Bin::Add, Bin::Div, true) => Op::AddDivL,
        (Bin::Add, Bin::Div, false) => Op::AddDivR,
        (Bin::Sub, Bin::Add, true) => Op::SubAddL,
        (Bin::Sub, Bin::Add, false) => Op::SubAddR,
        (Bin::Sub, Bin::Sub, true) => Op::SubSubL,
        (Bin::Sub, Bin::Sub, false) => Op::SubSubR,
        (Bin::Sub, Bin::Mul, true) => Op::SubMulL,
        (Bin::Sub, Bin::Mul, false) => Op::SubMulR,
        (Bin::Sub, Bin::Div, true) => Op::SubDivL,
        (Bin::Sub, Bin::Div, false) => Op::SubDivR,
        (Bin::Mul, Bin::Add, true) => Op::MulAddL,
        (Bin::Mul, Bin::Add, false) => Op::MulAddR,
        (Bin::Mul, Bin::Sub, true) => Op::MulSubL,
        (Bin::Mul, Bin::Sub, false) => Op::MulSubR,
        (Bin::Mul, Bin::Mul, true) => Op::MulMulL,
        (Bin::Mul, Bin::Mul, false) => Op::MulMulR,
        (Bin::Mul, Bin::Div, true) => Op::MulDivL,
        (Bin::Mul, Bin::Div, false) => Op::MulDivR,
        (Bin::Div, Bin::Add, true) => Op::DivAddL,
        (Bin::Div, Bin::Add, false) => Op::DivAddR,
        (Bin::Div, Bin::Sub, true) => Op::DivSubL,
        (Bin::Div, Bin::Sub, false) => Op::DivSubR,
        (Bin::Div, Bin::Mul, true) => Op::DivMulL,
        (Bin::Div, Bin::Mul, false) => Op::DivMulR,
        (Bin::Div, Bin::Div, true) => Op::DivDivL,
        (Bin::Div, Bin::Div, false) => Op::DivDivR,
    }
}

/// Whether register `reg` is read after instruction `j` before being overwritten (or is an output), where
/// `j` itself does not count as a reader.
fn read_after(code: &[Option<Instr>], j: usize, reg: u16, outputs: &[u16]) -> bool {
    if code[j].is_some_and(|ins| ins.dst == reg) {
        return false;
    }
    for ins in code[j + 1..].iter().flatten() {
        if operand_registers(ins).contains(&reg) {
            return true;
        }
        if ins.dst == reg {
            return false;
        }
    }
    outputs.contains(&reg)
}

/// The registers an instruction reads.
fn operand_registers(ins: &Instr) -> &[u16] {
    let n = match ins.op {
        Op::Neg | Op::Powi(_) | Op::Call(_) => 1,
        Op::Select(_) => 4,
        op if bin_of(op).is_some() || matches!(op, Op::Powf | Op::Atan2) => 2,
        // Fused instructions read three.
        _ => 3,
    };
    &ins.args[..n]
}

/// Merges each binary instruction into the binary instruction that reads its result (once, as one of its
/// two operands) when nothing else reads that result: the first instruction moves down to the second
/// (the instructions between neither read its result's register nor write any register it touches, so
/// moving it changes no value) and the two become one fused instruction (see [`Op`]), which writes only the
/// second result.
fn fuse(code: Vec<Instr>, outputs: &[u16]) -> Vec<Instr> {
    let mut slots: Vec<Option<Instr>> = code.into_iter().map(Some).collect();
    for i in 0..slots.len() {
        let Some(ins) = slots[i] else { continue };
        let Some(first) = bin_of(ins.op) else {
            continue;
        };
        let (t, [a, b, ..]) = (ins.dst, ins.args);
        for j in i + 1..slots.len() {
            let Some(next) = slots[j] else { continue };
            if !operand_registers(&next).contains(&t) {
                if [t, a, b].contains(&next.dst) {
                    break;
                }
                continue;
            }
            let [x, y, ..] = next.args;
            // Exactly one operand of `next` is the first result (not `t * t`).
            let side = match (x == t, y == t) {
                (true, false) => Some((true, y)),
                (false, true) => Some((false, x)),
                _ => None,
            };
            if let (Some(second), Some((left, other))) = (bin_of(next.op), side)
                && !read_after(&slots, j, t, outputs)
            {
                slots[j] = Some(Instr {
                    op: fused_op(first, second, left),
                    dst: next.dst,
                    args: [a, b, other, 0],
                });
                slots[i] = None;
            }
            break;
        }
    }
    slots.into_iter().flatten().collect()
}

/// The register-file size a program of `n` registers runs with (a power of two).
fn tier(n: usize) -> usize {
    match n {
        0..=8 => 8,
        9..=16 => 16,
        17..=32 => 32,
        33..=64 => 64,
        65..=256 => 256,
        _ => MAX_REGISTERS,
    }
}

/// The operands of a node, in instruction order.
fn operands(n: Node) -> Vec<Id> {
    crate::sym::children_of(&n)
}

/// The run-time form of a [`Compiled`] ψ: a program for the hoisted parameters (from the vars), and three
/// θ programs (ψ; ψ and ψ′; all three) reading `[θ, p_0, …, p_{k−1}]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Tape {
    /// Hoisted parameters from `[v_0, …]` (inputs, then the provided names).
    pub params: Program,
    /// ψ.
    pub value: Program,
    /// ψ, ψ′.
    pub first: Program,
    /// ψ, ψ′, ψ″.
    pub full: Program,
    /// Number of hoisted parameters.
    pub n_params: usize,
}

impl Tape {
    /// Compiles `c` for a caller that passes `slots` (≥ the hoisted count) parameter values to every θ
    /// program. `None` when a program needs more than [`MAX_REGISTERS`] registers.
    pub fn new(c: &Compiled, slots: usize) -> Option<Self> {
        let a = &c.arena;
        // Vars that do not occur get no node; map positions so register i holds var i.
        let mut var_ids = Vec::with_capacity(c.n_vars());
        for i in 0..c.n_vars() {
            let id = a
                .nodes
                .iter()
                .position(|n| *n == Node::Var(i))
                .map(|k| Id(k as u32));
            // A var that never occurs: a fresh id beyond the arena, never read.
            var_ids.push(id.unwrap_or(Id(u32::MAX - i as u32)));
        }
        let free_order = free_schedule(a, &c.hoisted);
        let params = Program::new(a, &var_ids, &free_order, &c.hoisted)?;
        let theta = a
            .nodes
            .iter()
            .position(|n| *n == Node::Theta)
            .map_or(Id(u32::MAX), |k| Id(k as u32));
        let mut inputs = vec![theta];
        inputs.extend_from_slice(&c.hoisted);
        let [psi, d1, d2] = c.roots;
        let s = 1 + slots;
        let value = Program::with_input_slots(a, &inputs, s, &c.order_for(&[psi]), &[psi])?;
        let first = Program::with_input_slots(a, &inputs, s, &c.order_for(&[psi, d1]), &[psi, d1])?;
        let full = Program::with_input_slots(a, &inputs, s, &c.order, &[psi, d1, d2])?;
        Some(Self {
            params,
            value,
            first,
            full,
            n_params: c.hoisted.len(),
        })
    }
}

/// θ-free, non-leaf nodes needed for `roots`, operands first.
fn free_schedule(arena: &Arena, roots: &[Id]) -> Vec<Id> {
    let mut order = Vec::new();
    let mut seen = vec![false; arena.nodes.len()];
    for &r in roots {
        let mut stack = vec![(r, false)];
        while let Some((id, expanded)) = stack.pop() {
            if expanded {
                order.push(id);
                continue;
            }
            let i = id.0 as usize;
            if seen[i] {
                continue;
            }
            seen[i] = true;
            if matches!(arena.node(id), Node::Const(_) | Node::Var(_) | Node::Theta) {
                continue;
            }
            stack.push((id, true));
            for c in arena.children(id).into_iter().rev() {
                stack.push((c, false));
            }
        }
    }
    order
}
