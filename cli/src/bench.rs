//! `hinge bench`: energy + gradient + Hessian + assembly of discrete shells per method, on three meshes
//! (every JSON row names its `mesh`):
//! - `grid`: the unit grids of 81×81 and 401×401 vertices (`--sizes`), numbered row by row;
//! - `grid-permuted`: the same grids with their vertices renumbered by a seeded random permutation;
//! - `irregular`: a 351×351-vertex irregular sheet (random diagonals, jitter, random numbering: 123 201
//!   vertices), emitted once.
//!
//! All flat at rest and deformed by z = 0.1·sin(3x)·cos(2y). Full evaluations run on 1 and on 2 threads
//! whatever the machine (and on all cores when there are more); `refactored:value` is an energy-only request.
//! Medians after a warm-up, rows interleaved so that ratios compare like with like.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use hinge_core::TriMesh;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::grid::{SplitMix64, unit_grid, wave};
use hinge_core::nalgebra::Vector3;
use hinge_core::psi::handwritten::{self, Stiffness};
use hinge_core::psi::runtime::{ParamValue, RuntimePsi};
use hinge_core::psi::{DiscreteShells, HingePsi, HingeQuantities, TanBending};
use hinge_core::shapes::{irregular_sheet, random_permutation, renumber};
use hinge_energies::bending::ViscousDamping;

/// Arguments of `hinge bench`.
#[derive(Args)]
pub struct BenchArgs {
    /// Also write the results as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Timed runs per row (at least 5).
    #[arg(long, default_value_t = 7)]
    runs: usize,
    /// Cells per side of the grids (default 80 and 400, i.e. 81×81 and 401×401 vertices).
    #[arg(long, value_delimiter = ',', default_values_t = [80usize, 400])]
    sizes: Vec<usize>,
    /// Cells per side of the cloth for the solver rows (default 80 and 200: 19 683 and 120 603 unknowns).
    #[arg(long, value_delimiter = ',', default_values_t = [80usize, 200])]
    solver_sizes: Vec<usize>,
    /// Only the rows whose method name is listed (default: all rows; `psi`, `solve`, `setup` and `adjoint`
    /// select those groups; a name that is none of these is an error listing them).
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
}

struct Row {
    method: String,
    /// `grid`, `grid-permuted`, `irregular`, or `none` for the ψ rows (no mesh).
    mesh: &'static str,
    threads: usize,
    n_vertices: usize,
    n_hinges: usize,
    median_ms: f64,
    /// Further named figures (solver rows: analyze, factor and solve times).
    extra: Vec<(&'static str, f64)>,
}

/// Consecutive evaluations per row and round; the first `UNTIMED` of each block are not timed.
const BLOCK: usize = 6;
const UNTIMED: usize = 2;

/// Number of (θ, hinge) samples per ψ row.
const PSI_SAMPLES: usize = 1 << 20;

/// Times (ψ, ψ′, ψ″) per θ for one ψ over fixed samples; returns the median in ms.
fn time_psi<P: HingePsi>(
    psi: &P,
    samples: &[(HingeQuantities, f64)],
    runs: usize,
    dual: bool,
) -> f64 {
    let params: Vec<(P::Params, f64)> = samples.iter().map(|(q, t)| (psi.params(q), *t)).collect();
    let mut times = Vec::with_capacity(runs);
    for round in 0..=runs {
        let start = Instant::now();
        let mut acc = 0.0;
        for (p, t) in &params {
            let [a, b, c] = if dual {
                let (a, b, c) =
                    num_dual::second_derivative(|x| psi.psi_dual(p, x), std::hint::black_box(*t));
                [a, b, c]
            } else {
                psi.eval(p, std::hint::black_box(*t))
            };
            acc += a + b + c;
        }
        std::hint::black_box(acc);
        if round > 0 {
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    median(times)
}

/// The ψ rows: macro-generated vs hand-written vs num-dual `Dual2` (of the macro's generic ψ), per energy.
fn psi_rows(runs: usize) -> Vec<Row> {
    let mut rng = SplitMix64(0x5EED);
    let mut unit = move || rng.unit();
    let samples: Vec<(HingeQuantities, f64)> = (0..PSI_SAMPLES)
        .map(|i| {
            let q = HingeQuantities {
                hinge: i,
                theta_bar: unit() - 0.5,
                a: 1.0 + unit(),
                rest_length: 1.0,
                rest_area: 1.0,
                theta_prev: 0.0,
                dt: 1.0,
            };
            (q, 2.0 * (2.0 * unit() - 1.0))
        })
        .collect();
    let row = |name: &str, ms: f64| Row {
        method: name.to_string(),
        mesh: "none",
        threads: 1,
        n_vertices: 0,
        n_hinges: PSI_SAMPLES,
        median_ms: ms,
        extra: Vec::new(),
    };
    let hk = Stiffness::Uniform(1.0);
    vec![
        row(
            "psi:macro:discrete-shells",
            time_psi(&DiscreteShells { k: 1.0 }, &samples, runs, false),
        ),
        row(
            "psi:handwritten:discrete-shells",
            time_psi(
                &handwritten::DiscreteShells { k: hk.clone() },
                &samples,
                runs,
                false,
            ),
        ),
        row(
            "psi:dual2:discrete-shells",
            time_psi(&DiscreteShells { k: 1.0 }, &samples, runs, true),
        ),
        row(
            "psi:macro:tan-bending",
            time_psi(&TanBending { k: 1.0 }, &samples, runs, false),
        ),
        row(
            "psi:handwritten:tan-bending",
            time_psi(&handwritten::TanBending { k: hk }, &samples, runs, false),
        ),
        row(
            "psi:dual2:tan-bending",
            time_psi(&TanBending { k: 1.0 }, &samples, runs, true),
        ),
        row(
            "psi:runtime:discrete-shells",
            runtime(DS_TEXT).map_or(f64::NAN, |p| time_psi(&p, &samples, runs, false)),
        ),
        row(
            "psi:runtime:tan-bending",
            runtime(TAN_TEXT).map_or(f64::NAN, |p| time_psi(&p, &samples, runs, false)),
        ),
        compile_row(runs),
    ]
}

/// An expression of about 100 parse-tree nodes exercising the grammar (`psi:compile` row).
pub fn compile_benchmark_expression() -> String {
    let terms: Vec<String> = (1..=5)
        .map(|i| {
            format!(
                "c{i} * a * (sin(theta * {i}.0 + theta_bar) - {i}.5 * cosh(theta_bar)).powi(2) * max(theta, -{i}.0)"
            )
        })
        .collect();
    terms.join(" + ")
}

/// Parsing and compiling a ψ string of about 100 nodes, milliseconds per compile (median over runs of
/// 50 compiles).
fn compile_row(runs: usize) -> Row {
    let text = compile_benchmark_expression();
    let params: Vec<(String, ParamValue)> = (1..=5)
        .map(|i| (format!("c{i}"), ParamValue::Scalar(1.0)))
        .collect();
    let nodes = hinge_symbolic::text::parse(&text).map_or(0, |e| e.node_count());
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs {
        let start = Instant::now();
        for _ in 0..50 {
            if let Err(e) =
                std::hint::black_box(RuntimePsi::<32>::with_capacity(&text, params.clone()))
            {
                eprintln!("psi:compile: {e}");
                return Row {
                    method: "psi:compile".into(),
                    mesh: "none",
                    threads: 1,
                    n_vertices: 0,
                    n_hinges: 1,
                    median_ms: f64::NAN,
                    extra: Vec::new(),
                };
            }
        }
        times.push(start.elapsed().as_secs_f64() * 1e3 / 50.0);
    }
    Row {
        method: "psi:compile".to_string(),
        mesh: "none",
        threads: 1,
        n_vertices: 0,
        n_hinges: 1,
        median_ms: median(times),
        extra: vec![("parse_tree_nodes", nodes as f64)],
    }
}

/// Solver rows: one Newton system `M/Δt² + H` of a cloth (tan bending + springs, Δt = 1/60 s, wave-deformed
/// state) per backend, with analyze / factor / solve times (medians).
/// The Newton system of one implicit-Euler step at `x` (Δt = 1/60 s, lumped masses of density 0.1, no pins):
/// `M/Δt² + H` on the reduced pattern, its values, and the right-hand side `−∇E`.
pub(crate) fn newton_system(
    sys: &mut hinge_core::energy::System,
    rest: &hinge_core::TriMesh,
    x: &[hinge_core::nalgebra::Vector3<f64>],
) -> Result<(hinge_solver::newton::Reduced, Vec<f64>, Vec<f64>), String> {
    use hinge_energies::gravity::lumped_masses;
    use hinge_solver::newton::Reduced;
    let e = sys
        .evaluate(x, Request::ALL, Parallelism::Rayon)
        .map_err(|e| e.to_string())?;
    let red = Reduced::new(sys.pattern(), &vec![true; 3 * rest.n_vertices()]);
    let masses = lumped_masses(rest, 0.1);
    let dt = 1.0 / 60.0;
    let mut values: Vec<f64> = red.source.iter().map(|&k| e.hessian[k]).collect();
    for (r, &d) in red.diag.iter().enumerate() {
        values[d] += masses[red.dofs[r] / 3] / (dt * dt);
    }
    let rhs: Vec<f64> = red.dofs.iter().map(|&d| -e.gradient[d]).collect();
    Ok((red, values, rhs))
}

fn solver_rows(n: usize, runs: usize) -> Result<Vec<Row>, String> {
    use hinge_core::energy::{Energy, HingeTerm, System};
    use hinge_core::shapes::{icosphere, random_permutation, renumber};
    use hinge_energies::spring::MassSpring;
    use hinge_solver::linear::{ChebyshevJacobi, FaerLlt, FaerLu, LinearSolver, PcgJacobi};
    use hinge_solver::ordering::FillOrdering;
    type Make = Box<dyn Fn() -> Box<dyn LinearSolver>>;
    let llt = |o: FillOrdering| -> Make {
        Box::new(move || Box::new(FaerLlt::with_ordering(o)) as Box<dyn LinearSolver>)
    };
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    // The cloth of `n` cells per side and a closed shell of about as many vertices (an icosphere, randomly
    // numbered: `shell-drop`'s kind of mesh), with the orderings of the default backend side by side.
    let sphere = icosphere(if n <= 100 { 5 } else { 6 }, 0.5).map_err(|e| e.to_string())?;
    let shell = renumber(&sphere, &random_permutation(sphere.n_vertices(), 3))
        .map_err(|e| e.to_string())?;
    let meshes = [
        ("grid", unit_grid(n).map_err(|e| e.to_string())?),
        ("icosphere", shell),
    ];
    let mut rows = Vec::new();
    for (mesh, rest) in meshes {
        // The cloth is wave-deformed; the shell is inflated by 2% (`wave` would flatten it, and a dent puts
        // springs in compression, which makes `M/Δt² + H` indefinite at the shell's small lumped masses).
        let x = if mesh == "grid" {
            wave(rest.positions())
        } else {
            rest.positions().iter().map(|p| p * 1.02).collect()
        };
        let nv = rest.n_vertices();
        let bending =
            BendingModel::new(&rest, TanBending { k: 1e-3 }).map_err(|e| e.to_string())?;
        let nh = bending.topology().hinges().len();
        let terms: Vec<Box<dyn Energy>> = vec![
            Box::new(MassSpring::new(&rest, 1e3).map_err(|e| e.to_string())?),
            Box::new(HingeTerm::new("bending", bending, Method::Refactored)),
        ];
        let mut sys = System::new(nv, terms).map_err(|e| e.to_string())?;
        let (red, values, rhs) = newton_system(&mut sys, &rest, &x)?;
        let mut backends: Vec<(&str, Make, usize)> = vec![
            ("faer-llt", llt(FillOrdering::Auto), all),
            ("faer-llt:amd", llt(FillOrdering::Amd), all),
            ("faer-llt:nd", llt(FillOrdering::NestedDissection), all),
        ];
        if mesh == "grid" {
            backends.extend([
                (
                    "faer-lu",
                    Box::new(|| Box::new(FaerLu::default()) as Box<dyn LinearSolver>) as Make,
                    all,
                ),
                (
                    "pcg-jacobi",
                    Box::new(|| Box::new(PcgJacobi::new(1e-8, 2_000)) as Box<dyn LinearSolver>),
                    1,
                ),
                (
                    "chebyshev-jacobi",
                    Box::new(|| {
                        Box::new(ChebyshevJacobi::new(1e-8, 200_000)) as Box<dyn LinearSolver>
                    }),
                    1,
                ),
            ]);
        }
        for (name, make, threads) in backends {
            let (mut ta, mut tf, mut ts) = (Vec::new(), Vec::new(), Vec::new());
            let mut failed = None;
            let mut entries = f64::NAN;
            for _ in 0..runs.max(3) {
                let mut s = make();
                let t = Instant::now();
                if let Err(e) = s.analyze(&red.csc) {
                    failed = Some(e.to_string());
                    break;
                }
                ta.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                if let Err(e) = s.factor(&values) {
                    failed = Some(e.to_string());
                    break;
                }
                tf.push(t.elapsed().as_secs_f64() * 1e3);
                let mut b = rhs.clone();
                let t = Instant::now();
                if let Err(e) = s.solve(&mut b) {
                    failed = Some(e.to_string());
                    break;
                }
                ts.push(t.elapsed().as_secs_f64() * 1e3);
                if name.starts_with("faer-llt") {
                    // The same analysis again, outside the timing, for the factor's size.
                    let o = match name {
                        "faer-llt:amd" => FillOrdering::Amd,
                        "faer-llt:nd" => FillOrdering::NestedDissection,
                        _ => FillOrdering::Auto,
                    };
                    let mut probe = FaerLlt::with_ordering(o);
                    if probe.analyze(&red.csc).is_ok() {
                        entries = probe.factor_entries().map_or(f64::NAN, |e| e as f64);
                    }
                }
            }
            if let Some(msg) = failed {
                println!("solve:{name} on the {mesh} at {nv} vertices failed: {msg}");
                continue;
            }
            let (a, f, s) = (median(ta), median(tf), median(ts));
            let mut extra = vec![
                ("analyze_ms", a),
                ("factor_ms", f),
                ("solve_ms", s),
                ("unknowns", red.csc.n as f64),
            ];
            if entries.is_finite() {
                extra.push(("factor_entries", entries));
            }
            rows.push(Row {
                method: format!("solve:{name}"),
                mesh,
                threads,
                n_vertices: nv,
                n_hinges: nh,
                median_ms: a + f + s,
                extra,
            });
        }
    }
    Ok(rows)
}

/// Adjoint rows: on beam3's static equilibrium at each resolution, one Newton iteration (`minimize` limited
/// to one iteration from a slightly perturbed equilibrium: assembly, factorization, solve, line search) and
/// one adjoint gradient (exact-Hessian assembly, factorization, solve, and `dL/dk` for the bending stiffness);
/// the symbolic analyses of both are done once beforehand. Medians; the summary prints their ratio.
fn adjoint_rows(runs: usize) -> Result<Vec<Row>, String> {
    use hinge_solver::adjoint::Adjoint;
    use hinge_solver::newton::{Newton, NewtonParams};
    let mut rows = Vec::new();
    for level in 1..=3 {
        let (mut scene, _) = hinge_cli::scene::load("beam3")?;
        scene.set_resolution(level)?;
        let rest = scene.rest_mesh(None)?;
        let b = hinge_cli::run::build(&scene, &rest, false)?;
        let mut system = b.system;
        let nv = rest.n_vertices();
        let nh = hinge_core::topology::hinges(&rest)
            .map_err(|e| e.to_string())?
            .len();
        let params = NewtonParams {
            max_iterations: 2000,
            ..b.params.clone()
        };
        let mut newton =
            Newton::new(&system, &b.pins, b.solver, params).map_err(|e| e.to_string())?;
        let mut x = rest.positions().to_vec();
        newton
            .minimize(&mut system, &mut x, None)
            .map_err(|e| format!("beam3 statics: {e}"))?;
        // One iteration from a perturbed equilibrium (the free end lifted by 1% of its deflection).
        let perturbed: Vec<_> = x
            .iter()
            .zip(rest.positions())
            .map(|(p, r)| p + (r - p) * 0.01)
            .collect();
        newton.params.max_iterations = 1;
        newton.params.gradient_tolerance = 0.0;
        newton.params.step_tolerance = 0.0;
        newton.params.relative_gradient_tolerance = 0.0;
        newton.params.relative_step_tolerance = 0.0;
        let mut adjoint = Adjoint::new(&system, &b.pins).map_err(|e| e.to_string())?;
        let target: Vec<f64> = x.iter().flat_map(|p| [p.x, p.y, p.z - 1e-3]).collect();
        let dl: Vec<f64> = x
            .iter()
            .flat_map(|p| [p.x, p.y, p.z])
            .zip(&target)
            .map(|(a, t)| 2.0 * (a - t))
            .collect();
        let (mut tn, mut ta) = (Vec::new(), Vec::new());
        for _ in 0..runs {
            let mut y = perturbed.clone();
            let t = Instant::now();
            // One iteration; "not converged" after it is expected.
            let _ = newton.minimize(&mut system, &mut y, None);
            tn.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            adjoint.factor(&mut system, &x).map_err(|e| e.to_string())?;
            adjoint.solve(&dl).map_err(|e| e.to_string())?;
            let g = adjoint
                .parameter_gradient(&mut system, &x, "bending.k")
                .map_err(|e| e.to_string())?;
            ta.push(t.elapsed().as_secs_f64() * 1e3);
            std::hint::black_box(g);
        }
        let row = |method: &str, t: Vec<f64>| Row {
            method: method.into(),
            mesh: "beam3",
            threads: rayon::current_num_threads(),
            n_vertices: nv,
            n_hinges: nh,
            median_ms: median(t),
            extra: Vec::new(),
        };
        rows.push(row("newton_iteration", tn));
        rows.push(row("adjoint", ta));
    }
    Ok(rows)
}

/// One timed row of the benchmark.
#[derive(Clone, Copy)]
enum Kind {
    /// A full evaluation (energy, gradient, Hessian, assembly) with this method and thread count.
    Full(Method, usize),
    /// An energy-only request (refactored, one thread).
    Value,
    /// Local blocks computed, nothing written into the matrix.
    Local(Method),
    /// Every value slot written once.
    WriteFloor,
    /// Tan bending + viscous damping composed as one ψ (one geometric pass).
    DampedOnePass,
    /// The same two terms as two models (two passes).
    DampedTwoPasses,
    /// The per-hinge PSD projection (`HessianMode::ProjectPerHinge`: an 8×8 eigendecomposition per hinge;
    /// there is no closed form, see `hinge_core::bending`'s projection module), one thread.
    Projected,
    /// A full refactored evaluation, one thread, of the ψ model `k` of [`psi_models`] (macro or run-time ψ
    /// of discrete shells and tan bending).
    Assembly(usize),
}

/// The whole-assembly ψ rows: (row name, which model).
const ASSEMBLY_ROWS: [&str; 4] = [
    "assembly:macro:discrete-shells",
    "assembly:runtime:discrete-shells",
    "assembly:macro:tan-bending",
    "assembly:runtime:tan-bending",
];

/// The expressions of the built-ins as run-time ψ strings (the same text as their derive attributes).
const DS_TEXT: &str = "k * a * (theta - theta_bar).powi(2)";
const TAN_TEXT: &str =
    "k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2)";

fn runtime(text: &str) -> Result<RuntimePsi, String> {
    RuntimePsi::new(text, [("k", ParamValue::Scalar(1.0))]).map_err(|e| e.to_string())
}

/// One model per [`ASSEMBLY_ROWS`] entry, each with its buffers, as an evaluation closure.
type Evaluator = Box<dyn FnMut(&[Vector3<f64>]) -> Result<(), String>>;

fn evaluator<P: HingePsi + 'static>(rest: &TriMesh, psi: P) -> Result<Evaluator, String> {
    let m = BendingModel::new(rest, psi).map_err(|e| e.to_string())?;
    let (mut out, mut scratch) = (m.new_output(), m.new_scratch());
    Ok(Box::new(move |x| {
        m.evaluate_into(
            x,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
            &mut scratch,
            &mut out,
        )
        .map_err(|e| e.to_string())?;
        std::hint::black_box(out.energy);
        Ok(())
    }))
}

fn psi_models(rest: &TriMesh) -> Result<Vec<Evaluator>, String> {
    Ok(vec![
        evaluator(rest, DiscreteShells { k: 1.0 })?,
        evaluator(rest, runtime(DS_TEXT)?)?,
        evaluator(rest, TanBending { k: 1.0 })?,
        evaluator(rest, runtime(TAN_TEXT)?)?,
    ])
}

/// The thread pools of the parallel rows.
struct Pools<'a> {
    two: &'a rayon::ThreadPool,
    many: &'a rayon::ThreadPool,
}

/// One mesh of the assembly rows, with its model, buffers and timings.
struct Case<'a> {
    mesh: &'static str,
    x: Vec<Vector3<f64>>,
    kinds: &'a [(&'a str, Kind)],
    model: BendingModel<DiscreteShells>,
    out: hinge_core::bending::Evaluation,
    scratch: hinge_core::bending::Scratch,
    damped: Option<Damped>,
    /// The same model in `HessianMode::ProjectPerHinge`, when the `projected` row is asked for.
    projected: Option<BendingModel<DiscreteShells>>,
    /// The whole-assembly ψ models, when an `assembly:*` row is asked for.
    assemblies: Vec<Evaluator>,
    times: Vec<Vec<f64>>,
    one_thread_hessian: Option<Vec<f64>>,
}

/// Tan bending + viscous damping as one model and as two.
type Damped = (
    BendingModel<(TanBending, ViscousDamping)>,
    BendingModel<TanBending>,
    BendingModel<ViscousDamping>,
    (
        hinge_core::bending::Scratch,
        hinge_core::bending::Scratch,
        hinge_core::bending::Scratch,
    ),
);

impl<'a> Case<'a> {
    fn new(
        mesh: &'static str,
        rest: &TriMesh,
        x: Vec<Vector3<f64>>,
        kinds: &'a [(&'a str, Kind)],
    ) -> Result<Self, String> {
        let model =
            BendingModel::new(rest, DiscreteShells { k: 1.0 }).map_err(|e| e.to_string())?;
        let damped = if kinds
            .iter()
            .any(|(_, k)| matches!(k, Kind::DampedOnePass | Kind::DampedTwoPasses))
        {
            let (tan, damp) = (TanBending { k: 1.0 }, ViscousDamping { kd: 0.1 });
            let mut both =
                BendingModel::new(rest, (tan.clone(), damp.clone())).map_err(|e| e.to_string())?;
            let t = BendingModel::new(rest, tan).map_err(|e| e.to_string())?;
            let mut d = BendingModel::new(rest, damp).map_err(|e| e.to_string())?;
            both.set_step(rest.positions(), 0.01)
                .map_err(|e| e.to_string())?;
            d.set_step(rest.positions(), 0.01)
                .map_err(|e| e.to_string())?;
            let scratch = (both.new_scratch(), t.new_scratch(), d.new_scratch());
            Some((both, t, d, scratch))
        } else {
            None
        };
        let projected = if kinds.iter().any(|(_, k)| matches!(k, Kind::Projected)) {
            let mut m = model.clone();
            m.set_hessian_mode(hinge_core::bending::HessianMode::ProjectPerHinge)
                .map_err(|e| e.to_string())?;
            Some(m)
        } else {
            None
        };
        let assemblies = if kinds.iter().any(|(_, k)| matches!(k, Kind::Assembly(_))) {
            psi_models(rest)?
        } else {
            Vec::new()
        };
        Ok(Self {
            mesh,
            x,
            kinds,
            projected,
            assemblies,
            out: model.new_output(),
            scratch: model.new_scratch(),
            model,
            damped,
            times: vec![Vec::new(); kinds.len()],
            one_thread_hessian: None,
        })
    }

    /// One evaluation of row `kind`.
    fn run_once(&mut self, kind: Kind, pools: &Pools) -> Result<(), String> {
        let (model, x, out, scratch) = (&self.model, &self.x[..], &mut self.out, &mut self.scratch);
        match kind {
            Kind::Full(method, threads) => {
                // One thread: the sequential path (no rayon task overhead); more: a pool.
                let eval = |scratch: &mut _, out: &mut _| {
                    model.evaluate_into(
                        x,
                        Request::ALL,
                        method,
                        if threads == 1 {
                            Parallelism::Sequential
                        } else {
                            Parallelism::Rayon
                        },
                        scratch,
                        out,
                    )
                };
                match threads {
                    1 => eval(scratch, out),
                    2 => pools.two.install(|| eval(scratch, out)),
                    _ => pools.many.install(|| eval(scratch, out)),
                }
                .map_err(|e| e.to_string())?;
            }
            Kind::Assembly(k) => {
                if let Some(f) = self.assemblies.get_mut(k) {
                    f(x)?;
                }
            }
            Kind::Projected => {
                if let Some(m) = &self.projected {
                    m.evaluate_into(
                        x,
                        Request::ALL,
                        Method::Refactored,
                        Parallelism::Sequential,
                        scratch,
                        out,
                    )
                    .map_err(|e| e.to_string())?;
                }
            }
            Kind::Value => {
                model
                    .evaluate_into(
                        x,
                        Request::VALUE,
                        Method::Refactored,
                        Parallelism::Sequential,
                        scratch,
                        out,
                    )
                    .map_err(|e| e.to_string())?;
                std::hint::black_box(out.energy);
            }
            Kind::Local(method) => {
                let sum = model
                    .local_blocks_checksum(x, method, scratch, out)
                    .map_err(|e| e.to_string())?;
                std::hint::black_box(sum);
            }
            Kind::DampedOnePass | Kind::DampedTwoPasses => {
                if let Some((both, t, d, (s1, s2, s3))) = self.damped.as_mut() {
                    let (mut e, g, h) = (0.0, &mut out.gradient, &mut out.hessian);
                    let seq = Parallelism::Sequential;
                    let r = Request::ALL;
                    let m = Method::Refactored;
                    if matches!(kind, Kind::DampedOnePass) {
                        both.evaluate_add(x, r, m, seq, s1, &mut e, g, h)
                    } else {
                        t.evaluate_add(x, r, m, seq, s2, &mut e, g, h)
                            .and_then(|()| d.evaluate_add(x, r, m, seq, s3, &mut e, g, h))
                    }
                    .map_err(|e| e.to_string())?;
                    std::hint::black_box(e);
                }
            }
            Kind::WriteFloor => {
                for v in out.hessian.iter_mut() {
                    *v = std::hint::black_box(1.0);
                }
                std::hint::black_box(&out.hessian);
            }
        }
        Ok(())
    }
}

/// The assembly rows of several meshes: every (mesh, kind) timed in blocks interleaved over all meshes and
/// kinds, so that machine drift hits every row alike and the ratios between meshes are fair.
fn assembly_rows(cases: &mut [Case], runs: usize, pools: &Pools) -> Result<Vec<Row>, String> {
    for round in 0..=runs {
        for case in cases.iter_mut() {
            for i in 0..case.kinds.len() {
                let kind = case.kinds[i].1;
                // num-dual is ~10 µs per hinge: five timed runs of it are enough.
                let slow = matches!(kind, Kind::Full(Method::Autodiff, _));
                if slow && round > 5 {
                    continue;
                }
                // A block of consecutive evaluations per row: the first ones wake the row's thread pool
                // (an idle virtual CPU takes milliseconds to come back up to speed: measured here, 2-thread
                // runs right after a pool switch were no faster than 1-thread ones), the rest are timed.
                for rep in 0..if slow { 2 } else { BLOCK } {
                    let start = Instant::now();
                    case.run_once(kind, pools)?;
                    let t = start.elapsed().as_secs_f64() * 1e3;
                    if round > 0 && rep >= if slow { 1 } else { UNTIMED } {
                        case.times[i].push(t); // round 0 is the warm-up
                    }
                }
                if let Kind::Full(Method::Refactored, threads) = kind {
                    // Bitwise identity across thread counts, checked on the benchmark itself.
                    match &case.one_thread_hessian {
                        None => case.one_thread_hessian = Some(case.out.hessian.clone()),
                        Some(h)
                            if h.iter()
                                .zip(&case.out.hessian)
                                .any(|(a, b)| a.to_bits() != b.to_bits()) =>
                        {
                            return Err(format!(
                                "{}: the {threads}-thread Hessian differs from the 1-thread one",
                                case.mesh
                            ));
                        }
                        Some(_) => {}
                    }
                }
            }
        }
    }
    let mut rows = Vec::new();
    for case in cases.iter_mut() {
        let (nv, nh) = (
            case.model.n_vertices(),
            case.model.topology().hinges().len(),
        );
        for (i, &(name, kind)) in case.kinds.iter().enumerate() {
            rows.push(Row {
                method: name.to_string(),
                mesh: case.mesh,
                threads: if let Kind::Full(_, t) = kind { t } else { 1 },
                n_vertices: nv,
                n_hinges: nh,
                median_ms: median(std::mem::take(&mut case.times[i])),
                extra: Vec::new(),
            });
        }
    }
    Ok(rows)
}

/// Set-up cost on one mesh: the whole `BendingModel::new` (topology, rest quantities, pattern, slots,
/// partitions) and, inside it, the pattern with the locality order against the identity order.
fn setup_rows(mesh: &'static str, rest: &TriMesh, runs: usize) -> Result<Vec<Row>, String> {
    use hinge_core::pattern::SymmetricPattern;
    let model = BendingModel::new(rest, DiscreteShells { k: 1.0 }).map_err(|e| e.to_string())?;
    let (nv, nh) = (model.n_vertices(), model.topology().hinges().len());
    let pairs = model.couplings();
    let identity: Vec<usize> = (0..nv).collect();
    let (mut tm, mut tl, mut ti) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..runs.clamp(3, 5) {
        let t = Instant::now();
        let m = BendingModel::new(rest, DiscreteShells { k: 1.0 }).map_err(|e| e.to_string())?;
        tm.push(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(&m);
        let t = Instant::now();
        let p = SymmetricPattern::new(nv, pairs.iter().copied()).map_err(|e| e.to_string())?;
        tl.push(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(&p);
        let t = Instant::now();
        let p = SymmetricPattern::with_vertex_order(nv, pairs.iter().copied(), &identity)
            .map_err(|e| e.to_string())?;
        ti.push(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(&p);
    }
    let row = |name: &str, t: Vec<f64>| Row {
        method: name.to_string(),
        mesh,
        threads: 1,
        n_vertices: nv,
        n_hinges: nh,
        median_ms: median(t),
        extra: Vec::new(),
    };
    Ok(vec![
        row("setup:model", tm),
        row("setup:pattern:locality", tl),
        row("setup:pattern:identity", ti),
    ])
}

fn median(mut t: Vec<f64>) -> f64 {
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// Runs `hinge bench`. Rows are interleaved (one block of runs of each row per round) so that machine noise
/// hits all methods alike and the ratios printed at the end compare like with like.
pub fn run(args: BenchArgs) -> Result<(), String> {
    let runs = args.runs.max(5);
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    let pool = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .map_err(|e| format!("thread pool: {e}"))
    };
    let many = pool(all)?;
    let wanted = |name: &str| args.only.is_empty() || args.only.iter().any(|o| o == name);
    let two = pool(2)?;
    let mut kinds = vec![
        ("refactored", Kind::Full(Method::Refactored, 1)),
        ("refactored", Kind::Full(Method::Refactored, 2)),
        ("refactored:value", Kind::Value),
        ("per_hinge", Kind::Full(Method::PerHinge, 1)),
        ("projected", Kind::Projected),
        ("autodiff", Kind::Full(Method::Autodiff, 1)),
        ("refactored_local", Kind::Local(Method::Refactored)),
        ("per_hinge_local", Kind::Local(Method::PerHinge)),
        ("write_floor", Kind::WriteFloor),
        ("tan+damping:one_pass", Kind::DampedOnePass),
        ("tan+damping:two_passes", Kind::DampedTwoPasses),
        (ASSEMBLY_ROWS[0], Kind::Assembly(0)),
        (ASSEMBLY_ROWS[1], Kind::Assembly(1)),
        (ASSEMBLY_ROWS[2], Kind::Assembly(2)),
        (ASSEMBLY_ROWS[3], Kind::Assembly(3)),
    ];
    if all > 2 {
        kinds.insert(2, ("refactored", Kind::Full(Method::Refactored, all)));
    }
    // A name that selects nothing is a typo, not an empty benchmark.
    const GROUPS: [&str; 4] = ["setup", "psi", "adjoint", "solve"];
    if let Some(unknown) = args
        .only
        .iter()
        .find(|o| !GROUPS.contains(&o.as_str()) && !kinds.iter().any(|(name, _)| name == o))
    {
        let mut names: Vec<&str> = kinds.iter().map(|(name, _)| *name).collect();
        names.dedup();
        names.extend(GROUPS);
        return Err(format!(
            "--only: unknown row `{unknown}` (rows: {})",
            names.join(", ")
        ));
    }
    kinds.retain(|(name, _)| wanted(name));
    // The groups of rows beside the assembly rows, in `GROUPS`' order.
    let [setup, psi, adjoint, solve] = GROUPS.map(&wanted);
    // The other meshes get the rows that show numbering and shape independence.
    let mut other: Vec<(&str, Kind)> = kinds
        .iter()
        .copied()
        .filter(|(_, k)| {
            matches!(
                k,
                Kind::Full(Method::Refactored, _) | Kind::Full(Method::PerHinge, 1) | Kind::Value
            )
        })
        .collect();
    other.retain(|(name, _)| wanted(name));
    let pools = Pools {
        two: &two,
        many: &many,
    };
    let mut rows = Vec::new();
    // Each size's grid and permuted grid are timed together (interleaved); the irregular sheet with the
    // largest size.
    for (list, per_vertex, flag) in [
        (
            &args.sizes,
            hinge_cli::limits::BENCH_BYTES_PER_VERTEX,
            "--sizes",
        ),
        (
            &args.solver_sizes,
            hinge_cli::limits::RUN_BYTES_PER_VERTEX,
            "--solver-sizes",
        ),
    ] {
        for &n in list {
            hinge_cli::limits::memory(
                hinge_core::grid::counts(n, n).0,
                per_vertex,
                &format!("{flag} {n}"),
            )?;
        }
    }
    let largest = args.sizes.iter().copied().max();
    for &n in &args.sizes {
        let rest = unit_grid(n).map_err(|e| e.to_string())?;
        let x = wave(rest.positions());
        let mut cases = vec![Case::new("grid", &rest, x, &kinds)?];
        if !other.is_empty() {
            let perm = random_permutation(rest.n_vertices(), 0x9E37 + n as u64);
            let permuted = renumber(&rest, &perm).map_err(|e| e.to_string())?;
            let xp = wave(permuted.positions());
            cases.push(Case::new("grid-permuted", &permuted, xp, &other)?);
            if Some(n) == largest {
                let irr = irregular_sheet(351, 351, 0x1EE7).map_err(|e| e.to_string())?;
                let xi = wave(irr.positions());
                cases.push(Case::new("irregular", &irr, xi, &other)?);
            }
        }
        rows.extend(assembly_rows(&mut cases, runs, &pools)?);
        if setup {
            rows.extend(setup_rows(
                "grid-permuted",
                &renumber(&rest, &random_permutation(rest.n_vertices(), 1))
                    .map_err(|e| e.to_string())?,
                runs,
            )?);
        }
    }
    if psi {
        rows.extend(psi_rows(runs));
    }
    if adjoint {
        rows.extend(adjoint_rows(runs)?);
    }
    if solve {
        for &n in &args.solver_sizes {
            rows.extend(solver_rows(n, runs.min(7))?);
        }
    }
    println!(
        "{:<32} {:<14} {:>7} {:>10} {:>9} {:>12} {:>12}",
        "method", "mesh", "threads", "vertices", "hinges", "median_ms", "ns_per_hinge"
    );
    for r in &rows {
        let extra: Vec<String> = r.extra.iter().map(|(k, v)| format!("{k} {v:.3}")).collect();
        println!(
            "{:<32} {:<14} {:>7} {:>10} {:>9} {:>12.3} {:>12.1}  {}",
            r.method,
            r.mesh,
            r.threads,
            r.n_vertices,
            r.n_hinges,
            r.median_ms,
            r.median_ms * 1e6 / r.n_hinges as f64,
            extra.join(", ")
        );
    }
    let find = |mesh: &str, nv: usize, m: &str, t: usize| {
        rows.iter()
            .find(|r| r.mesh == mesh && r.n_vertices == nv && r.method == m && r.threads == t)
            .map(|r| r.median_ms)
    };
    for r in rows.iter().filter(|r| r.method == "adjoint") {
        if let Some(newton) = rows
            .iter()
            .find(|q| q.method == "newton_iteration" && q.n_vertices == r.n_vertices)
        {
            println!(
                "{} vertices, beam3: one adjoint gradient / one Newton iteration {:.2}x",
                r.n_vertices,
                r.median_ms / newton.median_ms
            );
        }
    }
    for &n in &args.sizes {
        let nv = (n + 1) * (n + 1);
        let get = |m: &str, t: usize| find("grid", nv, m, t);
        if let (Some(rf), Some(ph), Some(ad), Some(rl), Some(pl)) = (
            get("refactored", 1),
            get("per_hinge", 1),
            get("autodiff", 1),
            get("refactored_local", 1),
            get("per_hinge_local", 1),
        ) {
            println!(
                "{nv} vertices: per_hinge/refactored {:.2}x, per_hinge_local/refactored_local {:.2}x, refactored/refactored_local {:.2}, autodiff/refactored {:.1}x",
                ph / rf,
                pl / rl,
                rf / rl,
                ad / rf,
            );
        }
        for energy in ["discrete-shells", "tan-bending"] {
            if let (Some(m), Some(r)) = (
                get(&format!("assembly:macro:{energy}"), 1),
                get(&format!("assembly:runtime:{energy}"), 1),
            ) {
                println!(
                    "{nv} vertices: whole assembly, run-time ψ / derived ψ, {energy}: {:.3}x (1 thread)",
                    r / m
                );
            }
        }
        if let (Some(rf), Some(pr)) = (get("refactored", 1), get("projected", 1)) {
            println!(
                "{nv} vertices: projected/refactored {:.1}x (1 thread; the eigen path: no closed form exists)",
                pr / rf
            );
        }
        for mesh in ["grid", "grid-permuted"] {
            let get = |m: &str, t: usize| find(mesh, nv, m, t);
            if let (Some(r1), Some(r2)) = (get("refactored", 1), get("refactored", 2)) {
                println!(
                    "{nv} vertices, {mesh}: refactored 1 thread / 2 threads {:.2}x",
                    r1 / r2
                );
            }
            if let (Some(r1), Some(v)) = (get("refactored", 1), get("refactored:value", 1)) {
                println!(
                    "{nv} vertices, {mesh}: refactored (energy + gradient + Hessian) / energy only {:.2}x",
                    r1 / v
                );
            }
        }
        if let (Some(g), Some(p)) = (
            find("grid", nv, "refactored", 1),
            find("grid-permuted", nv, "refactored", 1),
        ) {
            println!(
                "{nv} vertices: refactored grid-permuted / grid {:.2}x (1 thread)",
                p / g
            );
        }
    }
    if let Some(r) = rows
        .iter()
        .find(|r| r.mesh == "irregular" && r.method == "refactored" && r.threads == 1)
    {
        let nv = r.n_vertices;
        if let (Some(r1), Some(r2), Some(ph)) = (
            find("irregular", nv, "refactored", 1),
            find("irregular", nv, "refactored", 2),
            find("irregular", nv, "per_hinge", 1),
        ) {
            println!(
                "irregular ({nv} vertices): per_hinge/refactored {:.2}x, 1 thread / 2 threads {:.2}x",
                ph / r1,
                r1 / r2
            );
        }
    }
    for &n in &args.sizes {
        let nv = (n + 1) * (n + 1);
        let get = |m: &str| {
            rows.iter()
                .find(|r| r.n_vertices == nv && r.method == m)
                .map(|r| r.median_ms)
        };
        if let (Some(a), Some(b)) = (get("tan+damping:one_pass"), get("tan+damping:two_passes")) {
            println!(
                "{nv} vertices: tan + damping in one pass saves {:.0}% against two passes ({:.2}x)",
                100.0 * (1.0 - a / b),
                b / a
            );
        }
    }
    for energy in ["discrete-shells", "tan-bending"] {
        let get = |kind: &str| {
            rows.iter()
                .find(|r| r.method == format!("psi:{kind}:{energy}"))
                .map(|r| r.median_ms)
        };
        if let (Some(m), Some(h), Some(d)) = (get("macro"), get("handwritten"), get("dual2")) {
            println!(
                "psi {energy}: macro/handwritten {:.2}x, dual2/macro {:.1}x",
                m / h,
                d / m
            );
        }
    }
    if let Some(path) = args.json {
        let results: Vec<_> = rows
            .iter()
            .map(|r| {
                let mut v = serde_json::json!({
                    "method": r.method,
                    "mesh": r.mesh,
                    "threads": r.threads,
                    "n_vertices": r.n_vertices,
                    "n_hinges": r.n_hinges,
                    "median_ms": r.median_ms,
                    "ns_per_hinge": r.median_ms * 1e6 / r.n_hinges as f64,
                });
                for (k, x) in &r.extra {
                    v[*k] = serde_json::json!(x);
                }
                v
            })
            .collect();
        let text = serde_json::to_string_pretty(&serde_json::json!({ "results": results }))
            .map_err(|e| e.to_string())?;
        std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}
