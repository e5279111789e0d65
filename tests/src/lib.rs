//! Shared helpers for hinge's cross-crate tests (and the command line's): a seeded generator, random hinge
//! stencils, finite differences, error metrics and scratch directories.
#![deny(missing_docs)]

use hinge_core::hinge::Stencil;
use nalgebra::{Rotation3, Vector3};

/// Unit roundoff of f64, 2⁻⁵³: errors are reported in multiples of it ("ulps").
pub const UNIT_ROUNDOFF: f64 = f64::EPSILON / 2.0;

pub use hinge_core::grid::{SplitMix64, reference_jitter};

/// A random non-degenerate stencil whose hinge angle is `theta` (up to rounding), in a random rigid frame.
///
/// The hinge edge has length in [0.5, 2]; the wing vertices sit at along-edge positions in [−0.3, 1.3] of the
/// edge and at distances in [0.3, 1.5] from its line, so every altitude is bounded away from zero.
pub fn random_stencil(rng: &mut SplitMix64, theta: f64) -> Stencil {
    let len = rng.range(0.5, 2.0);
    let s0 = rng.range(-0.3, 1.3) * len;
    let s3 = rng.range(-0.3, 1.3) * len;
    let r0 = rng.range(0.3, 1.5);
    let r3 = rng.range(0.3, 1.5);
    // x1 at the origin, x2 on +x. The upper wing at angle φ around the x axis, the lower wing at φ + π + θ
    // (flat when θ = 0). Which sign of θ this produces is fixed by the convention; the caller only relies on
    // |θ|, so the sign is randomised too.
    let phi = rng.range(0.0, std::f64::consts::TAU);
    let psi = phi + std::f64::consts::PI + theta;
    let x1 = Vector3::zeros();
    let x2 = Vector3::new(len, 0.0, 0.0);
    let x0 = Vector3::new(s0, r0 * phi.cos(), r0 * phi.sin());
    let x3 = Vector3::new(s3, r3 * psi.cos(), r3 * psi.sin());
    let axis = Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric());
    let rot = Rotation3::new(axis * std::f64::consts::PI);
    let shift = Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 3.0;
    let mut x = [x0, x1, x2, x3].map(|p| rot * p + shift);
    // x1 → x2 must be counter-clockwise in (x0, x1, x2): if the construction produced the mirror image, swap
    // x1 and x2 (which also keeps (x3, x2, x1) counter-clockwise about its own normal).
    if rng.unit() < 0.5 {
        x.swap(1, 2);
    }
    x
}

/// ‖a − b‖ / ‖b‖ over slices (normwise relative error); 0 when both are zero.
pub fn rel_error(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt();
    let den: f64 = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    if num == 0.0 { 0.0 } else { num / den }
}

/// Central finite difference of a scalar function of 12 coordinates: the gradient, step `h`.
pub fn fd_gradient(f: impl Fn(&[f64; 12]) -> f64, x: &[f64; 12], h: f64) -> [f64; 12] {
    let mut g = [0.0; 12];
    for i in 0..12 {
        let (mut xp, mut xm) = (*x, *x);
        xp[i] += h;
        xm[i] -= h;
        g[i] = (f(&xp) - f(&xm)) / (2.0 * h);
    }
    g
}

/// Unflattens 12 coordinates into a stencil.
pub fn stencil(x: &[f64; 12]) -> Stencil {
    [0, 1, 2, 3].map(|v| Vector3::new(x[3 * v], x[3 * v + 1], x[3 * v + 2]))
}

/// Sorted copy; the `q`-quantile (0..=1) of a sample by nearest rank.
pub fn quantile(sample: &[f64], q: f64) -> f64 {
    let mut s = sample.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return f64::NAN;
    }
    let idx = ((s.len() - 1) as f64 * q).round() as usize;
    s[idx]
}

/// Frobenius norm of the full symmetric matrix from its lower-triangle CSC storage.
pub fn sym_frobenius(col_ptr: &[usize], row_idx: &[usize], values: &[f64]) -> f64 {
    let mut s = 0.0;
    for c in 0..col_ptr.len() - 1 {
        for k in col_ptr[c]..col_ptr[c + 1] {
            let w = if row_idx[k] == c { 1.0 } else { 2.0 };
            s += w * values[k] * values[k];
        }
    }
    s.sqrt()
}

/// Dense full symmetric matrix (row-major `n × n`, the caller's numbering) from a pattern's lower-triangle
/// CSC storage (its storage order).
pub fn sym_dense(pattern: &hinge_core::pattern::SymmetricPattern, values: &[f64]) -> Vec<f64> {
    let (col_ptr, row_idx) = (pattern.col_ptr(), pattern.row_idx());
    let n = col_ptr.len() - 1;
    let mut d = vec![0.0; n * n];
    for c in 0..n {
        let mc = pattern.caller_dof(c);
        for k in col_ptr[c]..col_ptr[c + 1] {
            let r = pattern.caller_dof(row_idx[k]);
            d[r * n + mc] = values[k];
            d[mc * n + r] = values[k];
        }
    }
    d
}

/// Central finite differences of a whole-mesh energy: the gradient from energy values and the dense
/// (row-major `3n × 3n`) Hessian from gradients, step `h`. `eval` returns energy and gradient at a state.
pub fn fd_energy_derivatives(
    x: &[Vector3<f64>],
    h: f64,
    mut eval: impl FnMut(&[Vector3<f64>]) -> (f64, Vec<f64>),
) -> (Vec<f64>, Vec<f64>) {
    let n = 3 * x.len();
    let (mut g, mut hess) = (vec![0.0; n], vec![0.0; n * n]);
    for i in 0..n {
        let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
        xp[i / 3][i % 3] += h;
        xm[i / 3][i % 3] -= h;
        let ((ep, gp), (em, gm)) = (eval(&xp), eval(&xm));
        g[i] = (ep - em) / (2.0 * h);
        for j in 0..n {
            hess[i * n + j] = (gp[j] - gm[j]) / (2.0 * h);
        }
    }
    (g, hess)
}

/// Random per-hinge quantities (θ̄ ∈ [−1, 1], a ∈ [0.5, 3], lengths and areas ∈ [0.1, 2], θ_prev ∈ [−1, 1],
/// dt ∈ [0.001, 0.1]) for hinge `hinge`: what the ψ tests evaluate parameters on.
pub fn random_quantities(rng: &mut SplitMix64, hinge: usize) -> hinge_core::psi::HingeQuantities {
    hinge_core::psi::HingeQuantities {
        hinge,
        theta_bar: rng.range(-1.0, 1.0),
        a: rng.range(0.5, 3.0),
        rest_length: rng.range(0.1, 2.0),
        rest_area: rng.range(0.1, 2.0),
        theta_prev: rng.range(-1.0, 1.0),
        dt: rng.range(0.001, 0.1),
    }
}

/// Runs `f` on a fresh rayon pool of `threads` threads (the thread-count tests of bitwise determinism).
pub fn on_threads<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a rayon pool")
        .install(f)
}

/// An evaluator of the ψ language that is independent of the symbolic engine: it walks the unsimplified
/// parse tree (hinge-symbolic's string parser, nothing after it) over any num-dual scalar, with its own
/// function table. What the tests compare the simplified, differentiated programs against.
pub mod tree {
    use hinge_symbolic::ast::{BinOp, Cmp, Expr};
    use hinge_symbolic::text::Span;
    use num_dual::DualNum;

    /// ψ at `theta` with the named θ-free values `env` (parameters and provided names).
    ///
    /// # Panics
    /// On a name or function outside the language (the tests only pass expressions that compile).
    pub fn eval<D: DualNum<Primitive = f64> + Copy>(
        e: &Expr<Span>,
        theta: D,
        env: &[(&str, f64)],
    ) -> D {
        let env: Vec<(&str, D)> = env.iter().map(|&(n, v)| (n, D::from(v))).collect();
        let mut lets: Vec<(String, D)> = Vec::new();
        walk(e, theta, &env, false, &mut lets)
    }

    /// ψ with dual θ-free values too (parameter derivatives): exponents and `atan2` operands are
    /// differentiated as well, where [`eval`] takes their real parts (θ never reaches them).
    pub fn eval_dual_env<D: DualNum<Primitive = f64> + Copy>(
        e: &Expr<Span>,
        theta: D,
        env: &[(&str, D)],
    ) -> D {
        let mut lets: Vec<(String, D)> = Vec::new();
        walk(e, theta, env, true, &mut lets)
    }

    fn holds(c: Cmp, l: f64, r: f64) -> bool {
        match c {
            Cmp::Lt => l < r,
            Cmp::Le => l <= r,
            Cmp::Gt => l > r,
            Cmp::Ge => l >= r,
        }
    }

    fn int(e: &Expr<Span>) -> Option<i32> {
        match e {
            Expr::Num { int: Some(n), .. } => i32::try_from(*n).ok(),
            Expr::Neg { arg, .. } => int(arg).map(|n| -n),
            _ => None,
        }
    }

    fn walk<D: DualNum<Primitive = f64> + Copy>(
        e: &Expr<Span>,
        theta: D,
        env: &[(&str, D)],
        dual_env: bool,
        lets: &mut Vec<(String, D)>,
    ) -> D {
        match e {
            Expr::Num { value, .. } => D::from(*value),
            Expr::Name { name, .. } => {
                if let Some((_, v)) = lets.iter().rev().find(|(n, _)| n == name) {
                    return *v;
                }
                if name == "theta" {
                    return theta;
                }
                if let Some((_, v)) = env.iter().find(|(n, _)| n == name) {
                    return *v;
                }
                let n = name.replace(' ', "");
                match n.rsplit("::").next() {
                    Some("PI") => D::from(std::f64::consts::PI),
                    Some("E") => D::from(std::f64::consts::E),
                    _ => panic!("unknown name {name}"),
                }
            }
            Expr::Neg { arg, .. } => -walk(arg, theta, env, dual_env, lets),
            Expr::Binary { op, lhs, rhs, .. } => {
                let (a, b) = (
                    walk(lhs, theta, env, dual_env, lets),
                    walk(rhs, theta, env, dual_env, lets),
                );
                match op {
                    BinOp::Add => a + b,
                    BinOp::Sub => a - b,
                    BinOp::Mul => a * b,
                    BinOp::Div => a / b,
                }
            }
            Expr::Block { lets: ls, value } => {
                let depth = lets.len();
                for l in ls {
                    let v = walk(&l.value, theta, env, dual_env, lets);
                    lets.push((l.name.clone(), v));
                }
                let r = walk(value, theta, env, dual_env, lets);
                lets.truncate(depth);
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
                let (l, r) = (
                    walk(lhs, theta, env, dual_env, lets),
                    walk(rhs, theta, env, dual_env, lets),
                );
                if holds(*cmp, l.re(), r.re()) {
                    walk(then, theta, env, dual_env, lets)
                } else {
                    walk(otherwise, theta, env, dual_env, lets)
                }
            }
            Expr::Call { func, args, .. } => {
                let x = walk(&args[0], theta, env, dual_env, lets);
                let y = || walk(&args[1], theta, env, dual_env, &mut lets.clone());
                match func.as_str() {
                    "sqrt" => x.sqrt(),
                    "sin" => x.sin(),
                    "cos" => x.cos(),
                    "tan" => x.tan(),
                    "exp" => x.exp(),
                    "ln" => x.ln(),
                    "atan" => x.atan(),
                    "tanh" => x.tanh(),
                    "sinh" => x.sinh(),
                    "cosh" => x.cosh(),
                    "abs" => {
                        if x.re() >= 0.0 {
                            x
                        } else {
                            -x
                        }
                    }
                    "min" => {
                        let y = y();
                        if x.re() <= y.re() { x } else { y }
                    }
                    "max" => {
                        let y = y();
                        if x.re() >= y.re() { x } else { y }
                    }
                    "powi" | "pow" if int(&args[1]).is_some() => x.powi(int(&args[1]).unwrap_or(1)),
                    "pow" | "powf" if dual_env => x.powd(y()),
                    "pow" | "powf" => x.powf(y().re()),
                    "atan2" if dual_env => {
                        // The value from atan2, the derivatives from atan(x / y) (equal off the axis).
                        let q = (x / y()).atan();
                        q - D::from(q.re()) + D::from(x.re().atan2(y().re()))
                    }
                    "atan2" => D::from(x.re().atan2(y().re())),
                    other => panic!("unknown function {other}"),
                }
            }
            Expr::Invalid { .. } => panic!("invalid node"),
        }
    }
}

/// One hinge along the x axis (x1 = origin, x2 = (1, 0, 0)), flat in the xy plane: wings x0 at y > 0 and
/// x3 at y < 0, triangles (x0, x1, x2) and (x3, x2, x1).
pub fn one_hinge_positions() -> Vec<nalgebra::Vector3<f64>> {
    vec![
        nalgebra::Vector3::new(0.45, 0.8, 0.0),
        nalgebra::Vector3::new(0.0, 0.0, 0.0),
        nalgebra::Vector3::new(1.0, 0.0, 0.0),
        nalgebra::Vector3::new(0.6, -0.9, 0.0),
    ]
}

/// The mesh of [`one_hinge_positions`].
pub fn one_hinge_mesh() -> hinge_core::TriMesh {
    hinge_core::TriMesh::new(one_hinge_positions(), vec![[0, 1, 2], [3, 2, 1]])
        .expect("a valid two-triangle mesh")
}

/// Times recorded by a [`StepGate`].
pub type Times = std::sync::Arc<std::sync::Mutex<Vec<f64>>>;

/// A zero energy for stepper tests: it refuses steps longer than `max_dt` (an evaluation error, forcing
/// substeps) and records the time it was placed at ([`Energy::set_time`](hinge_core::energy::Energy::set_time))
/// whenever it is evaluated (`evaluated`) and when an accepted step ends (`ended`).
pub struct StepGate {
    n: usize,
    max_dt: f64,
    dt: f64,
    time: f64,
    ended: Times,
    evaluated: Times,
}

impl StepGate {
    /// A gate over `n` vertices refusing steps above `max_dt`, recording into `ended` and `evaluated`.
    pub fn new(n: usize, max_dt: f64, ended: &Times, evaluated: &Times) -> Self {
        Self {
            n,
            max_dt,
            dt: 0.0,
            time: f64::NAN,
            ended: std::sync::Arc::clone(ended),
            evaluated: std::sync::Arc::clone(evaluated),
        }
    }
}

impl hinge_core::energy::Energy for StepGate {
    fn name(&self) -> &str {
        "gate"
    }
    fn n_vertices(&self) -> usize {
        self.n
    }
    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}
    fn bind(
        &mut self,
        _: &std::sync::Arc<hinge_core::pattern::SymmetricPattern>,
    ) -> Result<(), hinge_core::EvalError> {
        Ok(())
    }
    fn add_to(
        &mut self,
        _: &[Vector3<f64>],
        _: hinge_core::bending::Request,
        _: hinge_core::bending::Parallelism,
        _: &mut hinge_core::energy::Accumulator,
    ) -> Result<f64, hinge_core::EvalError> {
        if let Ok(mut e) = self.evaluated.lock() {
            e.push(self.time);
        }
        if self.dt > self.max_dt {
            Err(hinge_core::EvalError::Step { dt: self.dt })
        } else {
            Ok(0.0)
        }
    }
    fn begin_step(&mut self, _: &[Vector3<f64>], dt: f64) -> Result<(), hinge_core::EvalError> {
        self.dt = dt;
        Ok(())
    }
    fn set_time(&mut self, time: f64) -> Result<(), hinge_core::EvalError> {
        self.time = time;
        Ok(())
    }
    fn end_step(&mut self, _: &[Vector3<f64>]) -> Result<(), hinge_core::EvalError> {
        if let Ok(mut e) = self.ended.lock() {
            e.push(self.time);
        }
        Ok(())
    }
}

/// A stretched, compressed, bent and jittered deformation of `rest` (seeded): some triangles in tension,
/// some compressed — the membranes' derivative tests.
pub fn membrane_deformation(rest: &hinge_core::TriMesh, seed: u64) -> Vec<Vector3<f64>> {
    let mut rng = SplitMix64(seed);
    rest.positions()
        .iter()
        .map(|p| {
            Vector3::new(
                1.08 * p.x + 0.3 * p.z + 0.02 * rng.symmetric(),
                0.9 * p.y + 0.02 * rng.symmetric(),
                0.95 * p.z + 0.2 * (2.0 * p.x).sin() + 0.02 * rng.symmetric(),
            )
        })
        .collect()
}

/// A scratch directory for a test that writes files: `hinge-{name}-{pid}` under the system's temporary
/// directory, removed with everything in it when dropped, so a test that fails (panics) leaves nothing
/// behind either.
pub struct Scratch(std::path::PathBuf);

impl Scratch {
    /// Creates the directory (emptied first if a previous run of the same process id left it).
    ///
    /// # Panics
    /// When the directory cannot be created (a test environment without a writable temporary directory).
    pub fn new(name: &str) -> Scratch {
        let d = std::env::temp_dir().join(format!("hinge-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("a writable temporary directory");
        Scratch(d)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        // Tests that remove it themselves (checking that they can) leave nothing to remove.
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

impl std::ops::Deref for Scratch {
    type Target = std::path::Path;
    fn deref(&self) -> &std::path::Path {
        &self.0
    }
}

impl AsRef<std::path::Path> for Scratch {
    fn as_ref(&self) -> &std::path::Path {
        &self.0
    }
}
