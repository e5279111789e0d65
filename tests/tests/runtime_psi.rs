//! The run-time ψ (issue 16): the same text as the derive gives bitwise the same ψ, ψ′, ψ″; an independent
//! tree-walking evaluator over num-dual (unsimplified parse tree, its own function table) agrees with the
//! simplified, differentiated programs; errors carry columns; a run-time ψ composes, assembles with every
//! method (against finite differences and num-dual), re-hoists after parameter and rest-angle updates.

use hinge_core::HingeEnergy;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::energy::{HingeTerm, System};
use hinge_core::psi::runtime::{ParamValue, RuntimePsi, RuntimePsiError};
use hinge_core::psi::{DiscreteShells, HingePsi, HingeQuantities};
use hinge_core::{EvalError, shapes};
use hinge_energies::bending::{BuiltinBending, PsiConsumer, ViscousDamping};
use hinge_tests::*;
use num_dual::second_derivative;

mod pairs {
    use hinge_core::psi::{HingePsi, HingeQuantities};
    include!(concat!(env!("OUT_DIR"), "/random_pairs.rs"));
}

fn quantities(rng: &mut SplitMix64, hinge: usize) -> HingeQuantities {
    random_quantities(rng, hinge)
}

fn ulps(a: f64, b: f64) -> u64 {
    if a == b || (a.is_nan() && b.is_nan()) {
        return 0;
    }
    let (x, y) = (a.to_bits() as i64, b.to_bits() as i64);
    if (x < 0) != (y < 0) {
        return u64::MAX;
    }
    x.abs_diff(y)
}

/// The 48 seeded random expressions (24 of the original grammar, 24 of the whole one): derive and run time
/// agree bitwise on ψ, ψ′, ψ″ and on the energy-only and gradient-only programs.
#[test]
fn runtime_equals_derive_bitwise_on_random_expressions() {
    let pairs = pairs::pairs();
    assert_eq!(pairs.len(), 48);
    let c = [0.8, 1.3];
    let mut worst = 0u64;
    let mut compared = 0usize;
    for (k, (expr, derived)) in pairs.iter().enumerate() {
        let rt = RuntimePsi::new(expr, [("c0", c[0].into()), ("c1", c[1].into())])
            .unwrap_or_else(|e| panic!("{expr}: {e}"));
        let mut rng = SplitMix64(100 + k as u64);
        for i in 0..500 {
            let q = quantities(&mut rng, i % 5);
            let theta = rng.range(-2.5, 2.5);
            let d = derived(c, &q, theta);
            let p = rt.params(&q);
            let [a, b, e] = rt.eval(&p, theta);
            let [f, g] = rt.eval_d1(&p, theta);
            let r = [a, b, e, rt.value(&p, theta), f, g];
            for (x, y) in d.iter().zip(&r) {
                if x.is_finite() || y.is_finite() {
                    worst = worst.max(ulps(*x, *y));
                    compared += 1;
                }
            }
        }
    }
    println!("{compared} values compared, worst {worst} ulps");
    assert_eq!(
        worst, 0,
        "derive and run time must evaluate the same operations"
    );
}

/// ψ, ψ′, ψ″ of the simplified run-time programs against num-dual's second derivative of the tree walk
/// (no simplifier, no symbolic derivative), on the 48 random expressions and on hand-picked ones that use
/// every grammar element, away from the kinks.
#[test]
fn simplified_programs_match_an_independent_tree_walk() {
    let mut cases: Vec<String> = pairs::pairs().iter().map(|p| p.0.to_string()).collect();
    for e in GRAMMAR {
        cases.push(format!("c0 * ({e}) + c1 * theta.powi(2)"));
    }
    let mut worst: f64 = 0.0;
    for (k, expr) in cases.iter().enumerate() {
        let tree = hinge_symbolic::text::parse(expr).expect("parses");
        let rt = RuntimePsi::new(expr, [("c0", 0.8.into()), ("c1", 1.3.into())])
            .unwrap_or_else(|e| panic!("{expr}: {e}"));
        let mut rng = SplitMix64(7 + k as u64);
        let mut w: f64 = 0.0;
        for i in 0..400 {
            let q = quantities(&mut rng, i % 3);
            let theta = rng.range(-2.5, 2.5);
            let env = [
                ("c0", 0.8),
                ("c1", 1.3),
                ("theta_bar", q.theta_bar),
                ("a", q.a),
                ("rest_length", q.rest_length),
                ("rest_area", q.rest_area),
                ("theta_prev", q.theta_prev),
                ("dt", q.dt),
            ];
            let (f, d1, d2) = second_derivative(|t| tree::eval(&tree, t, &env), theta);
            let p = rt.params(&q);
            let got = rt.eval(&p, theta);
            let scale = f.abs().max(d1.abs()).max(d2.abs()).max(1e-300);
            for (x, r) in got.iter().zip([f, d1, d2]) {
                w = w.max((x - r).abs() / scale);
            }
            // psi_dual (what the autodiff method differentiates) is the same program over duals.
            let (g, g1, g2) = second_derivative(|t| rt.psi_dual(&p, t), theta);
            for (x, r) in [g, g1, g2].iter().zip([f, d1, d2]) {
                w = w.max((x - r).abs() / scale);
            }
        }
        if w > 1e-13 {
            println!("{w:.2e}  {expr}");
        }
        worst = worst.max(w);
    }
    println!(
        "{} expressions, worst relative error {worst:.2e}",
        cases.len()
    );
    assert!(worst <= 1e-12, "{worst}");
}

/// Every element of the grammar at least once (function and method spellings, kinks, `if`, constants).
const GRAMMAR: [&str; 14] = [
    "abs(theta - 0.1).powi(3) + (theta * 0.5).abs()",
    "min(theta, theta_bar).powi(2) + theta.max(0.3 * theta_bar).powi(2)",
    "sinh(theta) + theta.cosh() - cosh(0.5 * theta).sinh()",
    "if theta < theta_bar { (theta - theta_bar).powi(2) } else { 2.0 * (theta - theta_bar).powi(2) }",
    "if theta >= 0.5 { theta } else if theta <= -0.5 { -theta } else { theta.powi(2) + 0.25 }",
    "atan2(theta_bar, a) * theta.powi(2) + a.atan2(rest_length) * theta",
    "PI * E * std::f64::consts::PI * sin(theta) + core::f64::consts::E * theta",
    "pow(theta, 2) + pow(theta, -2.0 + 4.0) + powf(a, 1.5) * sqrt(theta * theta + 1.0) + powi(theta, 4)",
    "ln(a) * exp(theta) * tanh(theta) * atan(theta) * cos(theta) * tan(theta / 3.0)",
    "{ let u = theta - theta_bar; let v = u * u; v * (1.0 + v) }",
    "(1.0 + theta.powi(2)).powf(rest_length) / (2.0 + theta.sin())",
    "c0 / dt * a * (theta - theta_prev).powi(2)",
    "max(min(theta, 1.0), -1.0).powi(2) * rest_area",
    "-theta.powi(3) - -2.0 * theta",
];

/// Evaluates a bending model of the ψ it is handed (energy, gradient, Hessian as bits).
struct Assemble<'a> {
    mesh: &'a hinge_core::TriMesh,
    x: &'a [nalgebra::Vector3<f64>],
    method: Method,
}

impl PsiConsumer for Assemble<'_> {
    type Output = (u64, Vec<u64>, Vec<u64>);
    fn consume<P>(self, psi: P) -> Self::Output
    where
        P: HingePsi + Clone + Send + Sync + std::fmt::Debug + 'static,
    {
        eval_all(
            &BendingModel::new(self.mesh, psi).expect("m"),
            self.x,
            self.method,
        )
    }
}

/// The built-in energies' ψ as text (`BuiltinBending::psi_source`, which the Python package builds them
/// from) equal the derived ones bitwise through the whole assembly (energy, gradient, Hessian) on a
/// renumbered icosphere, with every method; and each name parses back to its energy.
#[test]
fn builtin_bending_sources_match_the_derive() {
    let mesh = renumbered(shapes::icosphere(2, 1.0).expect("mesh"), 11);
    let x = deform(&mesh, 3);
    let k = 1.7;
    for b in BuiltinBending::ALL {
        assert_eq!(b.name().parse::<BuiltinBending>(), Ok(b));
        let rt = RuntimePsi::new(b.psi_source(), [("k", k.into())]).expect("source compiles");
        for method in [Method::Refactored, Method::PerHinge, Method::Autodiff] {
            let a = eval_all(
                &BendingModel::new(&mesh, rt.clone()).expect("m"),
                &x,
                method,
            );
            let d = b.with_psi(
                k,
                Assemble {
                    mesh: &mesh,
                    x: &x,
                    method,
                },
            );
            assert_eq!(a, d, "{b}, {method:?}");
        }
    }
    let e = "tan".parse::<BuiltinBending>().unwrap_err().to_string();
    assert_eq!(
        e,
        "unknown `tan` (discrete-shells, tan-bending, willmore, bridson)"
    );
}

/// Viscous damping's ψ as text (`ViscousDamping::PSI_SOURCE`, which the Python package builds it from)
/// equals the derived one bitwise through the whole assembly, with the step state (θ_prev, Δt) set the same
/// way on both, on a renumbered icosphere with every method.
#[test]
fn viscous_damping_source_matches_the_derive() {
    let mesh = renumbered(shapes::icosphere(2, 1.0).expect("mesh"), 12);
    let x_prev = deform(&mesh, 4);
    let x = deform(&mesh, 5);
    let (kd, dt) = (0.37, 0.004);
    let rt = RuntimePsi::new(ViscousDamping::PSI_SOURCE, [("kd", kd.into())]).expect("compiles");
    let mut a = BendingModel::new(&mesh, rt).expect("m");
    let mut d = BendingModel::new(&mesh, ViscousDamping { kd }).expect("m");
    a.set_step(&x_prev, dt).expect("step");
    d.set_step(&x_prev, dt).expect("step");
    for method in [Method::Refactored, Method::PerHinge, Method::Autodiff] {
        let (ea, ed) = (eval_all(&a, &x, method), eval_all(&d, &x, method));
        assert_ne!(
            f64::from_bits(ea.0),
            0.0,
            "the states differ, so damping is not zero"
        );
        assert_eq!(ea, ed, "{method:?}");
    }
}

fn renumbered(mesh: hinge_core::TriMesh, seed: u64) -> hinge_core::TriMesh {
    let perm = shapes::random_permutation(mesh.n_vertices(), seed);
    shapes::renumber(&mesh, &perm).expect("renumbered")
}

fn deform(mesh: &hinge_core::TriMesh, seed: u64) -> Vec<nalgebra::Vector3<f64>> {
    let mut rng = SplitMix64(seed);
    mesh.positions()
        .iter()
        .map(|p| {
            p + nalgebra::Vector3::new(
                rng.range(-0.05, 0.05),
                rng.range(-0.05, 0.05),
                rng.range(-0.05, 0.05),
            )
        })
        .collect()
}

fn eval_all<P: HingePsi>(
    m: &BendingModel<P>,
    x: &[nalgebra::Vector3<f64>],
    method: Method,
) -> (u64, Vec<u64>, Vec<u64>) {
    let e = m
        .evaluate(x, Request::ALL, method, Parallelism::Sequential)
        .expect("evaluates");
    (
        e.energy.to_bits(),
        e.gradient.iter().map(|v| v.to_bits()).collect(),
        e.hessian.iter().map(|v| v.to_bits()).collect(),
    )
}

/// A run-time ψ of the whole grammar on a torus with boundaries-free random numbering and on an irregular
/// sheet: gradient and Hessian against central finite differences, and the three methods against each other
/// (autodiff differentiates the program over num-dual duals).
#[test]
fn runtime_psi_assembles_against_finite_differences_and_autodiff() {
    let expr = "k * a * { let u = theta - theta_bar; if u < 0.0 { u.powi(2) + 0.1 * sinh(u).powi(2) } else { 2.0 * u.powi(2) } } + kk * rest_length * abs(theta).powi(3)";
    for (name, mesh) in [
        (
            "torus",
            renumbered(shapes::torus(12, 8, 1.0, 0.4).expect("mesh"), 5),
        ),
        (
            "irregular",
            shapes::irregular_sheet(8, 8, 21).expect("mesh"),
        ),
    ] {
        let n_h = hinge_core::topology::hinges(&mesh).expect("hinges").len();
        let kk: Vec<f64> = (0..n_h).map(|h| 0.5 + (h % 7) as f64 * 0.1).collect();
        let psi = RuntimePsi::new(expr, [("k", 1.3.into()), ("kk", ParamValue::PerHinge(kk))])
            .expect("psi");
        let m = BendingModel::new(&mesh, psi).expect("model");
        let x = deform(&mesh, 9);
        let r = m
            .evaluate(
                &x,
                Request::ALL,
                Method::Refactored,
                Parallelism::Sequential,
            )
            .expect("r");
        let p = m
            .evaluate(&x, Request::ALL, Method::PerHinge, Parallelism::Sequential)
            .expect("p");
        let a = m
            .evaluate(&x, Request::ALL, Method::Autodiff, Parallelism::Sequential)
            .expect("a");
        let g_rel = rel_error(&r.gradient, &a.gradient);
        let h_rel = rel_error(&r.hessian, &a.hessian);
        let hp_rel = rel_error(&r.hessian, &p.hessian);
        println!(
            "{name}: refactored vs autodiff gradient {g_rel:.2e}, Hessian {h_rel:.2e}; vs per_hinge {hp_rel:.2e}"
        );
        assert!(g_rel < 1e-11 && h_rel < 1e-11 && hp_rel < 1e-12);
        let (fd_g, fd_h) = fd_energy_derivatives(&x, 1e-6, |y| {
            let e = m
                .evaluate(y, Request::ALL, Method::Refactored, Parallelism::Sequential)
                .expect("fd");
            (e.energy, e.gradient)
        });
        let eg = rel_error(&r.gradient, &fd_g);
        let eh = rel_error(&sym_dense(m.pattern(), &r.hessian), &fd_h);
        println!("{name}: gradient vs FD {eg:.2e}, Hessian vs FD {eh:.2e}");
        assert!(eg < 1e-6 && eh < 1e-5, "{eg} {eh}");
    }
}

/// In a tuple (one geometric pass) and in a `System`, a run-time ψ adds like any energy.
#[test]
fn runtime_psi_composes_in_tuples_and_systems() {
    let mesh = shapes::irregular_sheet(7, 9, 4).expect("mesh");
    let x = deform(&mesh, 2);
    let rt = RuntimePsi::new(
        "c * (theta - theta_bar).powi(4) + d * cosh(theta)",
        [("c", 0.7.into()), ("d", 0.2.into())],
    )
    .expect("psi");
    let both = BendingModel::new(&mesh, (rt.clone(), DiscreteShells { k: 1.1 })).expect("tuple");
    let one = BendingModel::new(&mesh, rt).expect("rt");
    let two = BendingModel::new(&mesh, DiscreteShells { k: 1.1 }).expect("ds");
    let eval = |m: &dyn Fn(&[nalgebra::Vector3<f64>]) -> hinge_core::bending::Evaluation| m(&x);
    let t = eval(&|x| {
        both.evaluate(x, Request::ALL, Method::Refactored, Parallelism::Rayon)
            .expect("t")
    });
    let a = eval(&|x| {
        one.evaluate(x, Request::ALL, Method::Refactored, Parallelism::Rayon)
            .expect("a")
    });
    let b = eval(&|x| {
        two.evaluate(x, Request::ALL, Method::Refactored, Parallelism::Rayon)
            .expect("b")
    });
    // The tuple shares one geometric pass; its Hessian is the sum too.
    let hsum: Vec<f64> = a
        .hessian
        .iter()
        .zip(&b.hessian)
        .map(|(p, q)| p + q)
        .collect();
    assert!(rel_error(&t.hessian, &hsum) < 1e-13);
    assert!(((a.energy + b.energy) - t.energy).abs() <= 1e-12 * t.energy.abs());
    let sum: Vec<f64> = a
        .gradient
        .iter()
        .zip(&b.gradient)
        .map(|(p, q)| p + q)
        .collect();
    assert!(rel_error(&t.gradient, &sum) < 1e-13);
    let mut sys = System::new(
        mesh.n_vertices(),
        vec![
            Box::new(HingeTerm::new("rt", one, Method::Refactored)),
            Box::new(HingeTerm::new("ds", two, Method::Refactored)),
        ],
    )
    .expect("system");
    let s = sys
        .evaluate(&x, Request::ALL, Parallelism::Rayon)
        .expect("s");
    assert!(((a.energy + b.energy) - s.energy).abs() <= 1e-12 * s.energy.abs());
    assert!(rel_error(&s.gradient, &sum) < 1e-13);
}

/// Every provided name reaches the program as the quantity of that name (the run-time input order is the
/// language's `PROVIDED` order).
#[test]
fn provided_names_are_the_hinge_quantities() {
    let mut rng = SplitMix64(3);
    let q = quantities(&mut rng, 0);
    for (name, want) in [
        ("theta_bar", q.theta_bar),
        ("a", q.a),
        ("rest_length", q.rest_length),
        ("rest_area", q.rest_area),
        ("theta_prev", q.theta_prev),
        ("dt", q.dt),
    ] {
        let psi = RuntimePsi::new(&format!("{name} * theta"), Vec::<(&str, ParamValue)>::new())
            .expect("compiles");
        let [_, d1, _] = psi.eval(&psi.params(&q), 0.3);
        assert_eq!(d1, want, "{name}");
    }
}

/// An affine run-time ψ leaves out the wing couplings, as the derive's `D2_IS_ZERO` does.
#[test]
fn affine_runtime_psi_has_no_wing_couplings() {
    let mesh = shapes::irregular_sheet(6, 6, 8).expect("mesh");
    let rt = RuntimePsi::new("k * (theta - theta_bar)", [("k", 2.0.into())]).expect("psi");
    assert!(rt.second_derivative_vanishes());
    #[derive(HingeEnergy)]
    #[psi(k * (theta - theta_bar))]
    struct Lin {
        k: f64,
    }
    let a = BendingModel::new(&mesh, rt).expect("a");
    let b = BendingModel::new(&mesh, Lin { k: 2.0 }).expect("b");
    assert_eq!(a.pattern().nnz(), b.pattern().nnz());
    let x = deform(&mesh, 1);
    assert_eq!(
        eval_all(&a, &x, Method::Refactored),
        eval_all(&b, &x, Method::Refactored)
    );
}

/// Parameters and rest angles updated after set-up re-hoist: the model then equals one built fresh.
#[test]
fn updates_after_setup_rehoist() {
    let mesh = renumbered(shapes::icosphere(1, 1.0).expect("mesh"), 3);
    let x = deform(&mesh, 4);
    let expr = "k * a * (theta - theta_bar).powi(2) + c / dt * (theta - theta_prev).powi(2)";
    let make = |k: f64| RuntimePsi::new(expr, [("k", k.into()), ("c", 0.3.into())]).expect("psi");
    let mut m = BendingModel::new(&mesh, make(1.0)).expect("m");
    m.set_step(&x, 0.01).expect("step");
    m.update_psi(|p| p.set_parameter("k", ParamValue::Scalar(2.5)).expect("k"))
        .expect("update");
    let mut fresh = BendingModel::new(&mesh, make(2.5)).expect("fresh");
    fresh.set_step(&x, 0.01).expect("step");
    let y = deform(&mesh, 5);
    assert_eq!(
        eval_all(&m, &y, Method::Refactored),
        eval_all(&fresh, &y, Method::Refactored)
    );
    // An unknown parameter is an error naming it; a bad per-hinge length leaves the model as it was.
    let mut p = make(1.0);
    let err = p.set_parameter("kk", 1.0.into()).expect_err("unknown");
    assert!(err.to_string().contains("`kk`"), "{err}");
    let before = eval_all(&m, &y, Method::Refactored);
    let r = m.update_psi(|p| {
        p.set_parameter("k", ParamValue::PerHinge(vec![1.0; 3]))
            .expect("k")
    });
    assert!(matches!(r, Err(EvalError::Psi(_))), "{r:?}");
    assert_eq!(eval_all(&m, &y, Method::Refactored), before);
    // Rest angles: θ̄ set to zero everywhere equals an expression with θ̄ replaced by 0.
    let n_h = m.rest_hinges().len();
    let mut flat = BendingModel::new(&mesh, DiscreteShells { k: 1.0 }).expect("flat");
    flat.set_rest_angles(&vec![0.0; n_h]).expect("angles");
    #[derive(HingeEnergy)]
    #[psi(k * a * theta.powi(2))]
    struct Flat {
        k: f64,
    }
    let reference = BendingModel::new(&mesh, Flat { k: 1.0 }).expect("reference");
    assert_eq!(
        eval_all(&flat, &y, Method::Refactored),
        eval_all(&reference, &y, Method::Refactored)
    );
    assert!(flat.set_rest_angles(&[0.0]).is_err());
    assert!(flat.set_rest_angles(&vec![f64::NAN; n_h]).is_err());
    // The hinge list before a model: the model's order.
    let hinges = hinge_core::topology::hinges(&mesh).expect("hinges");
    assert_eq!(hinges.len(), n_h);
    assert!(
        hinges
            .iter()
            .zip(flat.topology().hinges())
            .all(|(a, b)| a.vertices == b.vertices)
    );
}

/// Bad strings: one line with the column and what was expected; no input overflows the stack.
#[test]
fn errors_name_the_column_and_the_problem() {
    let err = |s: &str, params: &[(&str, f64)]| -> String {
        match RuntimePsi::new(s, params.iter().map(|(n, v)| (*n, ParamValue::Scalar(*v)))) {
            Ok(_) => panic!("`{s}` compiled"),
            Err(e) => {
                let m = e.to_string();
                assert!(!m.contains('\n'), "one line: {m}");
                m
            }
        }
    };
    assert!(err("k * (theta +* 2)", &[("k", 1.0)]).contains("column 13: expected"));
    assert!(err("k * theta ^ 2", &[("k", 1.0)]).contains("column 11: `^` is not a power"));
    let m = err("k * (tehta - theta_bar).powi(2)", &[("k", 1.0)]);
    assert!(
        m.contains("column 6: unknown identifier `tehta` (did you mean `theta`?)"),
        "{m}"
    );
    let m = err("k * theta.sinn() + theta.cosss()", &[("k", 1.0)]);
    assert!(
        m.contains("(did you mean `sin`?)") && m.contains("(did you mean `cos`?)"),
        "{m}"
    );
    assert_eq!(m.matches("supported:").count(), 1, "{m}");
    assert!(err("theta * theta", &[("k", 1.0)]).contains("parameter `k` is not used"));
    assert!(err("k * theta", &[]).contains("unknown identifier `k`"));
    let m = err("PI * theta", &[("PI", 1.0)]);
    assert!(
        m.contains("parameter `PI` shadows a constant") && !m.contains("column"),
        "{m}"
    );
    assert!(err("theta_bar * theta", &[("theta_bar", 1.0)]).contains("shadows a provided"));
    assert!(err("theta.powi(1.5)", &[]).contains("integer literal"));
    assert!(err("theta.powf(theta)", &[]).contains("must not depend on `theta`"));
    assert!(err("atan2(theta, 1.0)", &[]).contains("must not depend on `theta`"));
    assert!(err("if theta < 0.0 { theta }", &[]).contains("`else`"));
    assert!(err("if theta { theta } else { 1.0 }", &[]).contains("a comparison"));
    assert!(err("min(theta)", &[]).contains("takes 2 arguments"));
    assert!(err("", &[]).contains("column 1: expected an expression"));
    assert!(err("theta < 1.0", &[]).contains("comparisons appear only in `if`"));
    // Deep inputs: long chains, deep parentheses, deep calls — a typed error, never a stack overflow.
    for deep in [
        "theta".to_string() + &" + 1.0".repeat(100_000),
        format!("{}theta{}", "(".repeat(100_000), ")".repeat(100_000)),
        format!("{}theta{}", "sin(".repeat(50_000), ")".repeat(50_000)),
        format!("{}theta", "-".repeat(100_000)),
        format!("theta{}", ".sin()".repeat(100_000)),
    ] {
        assert!(err(&deep, &[]).contains("nested more than"));
    }
    let m = RuntimePsi::new("k * ln(theta)", [("k", 1.0.into())]).expect("compiles");
    let mesh = shapes::irregular_sheet(4, 4, 1).expect("mesh");
    let model = BendingModel::new(&mesh, m).expect("model");
    let r = model.evaluate(
        mesh.positions(),
        Request::ALL,
        Method::Refactored,
        Parallelism::Sequential,
    );
    assert!(matches!(r, Err(EvalError::NonFiniteEnergy { .. })), "{r:?}");
    assert!(RuntimePsi::new("theta", Vec::<(&str, ParamValue)>::new()).is_ok());
    let e = RuntimePsi::<1>::with_capacity(
        "a * theta + theta_bar * theta.powi(2)",
        Vec::<(&str, ParamValue)>::new(),
    );
    assert!(
        matches!(
            e,
            // a, θ̄, and ψ″ = 2θ̄ (θ-free, hoisted as it is).
            Err(RuntimePsiError::TooManyHoisted {
                count: 3,
                capacity: 1
            })
        ),
        "{e:?}"
    );
}

/// Outputs that overflow f64 although every hinge's ψ, ψ′ and ψ″ is finite (k = 1.5e307 in `k θ²`, at
/// positions shrunk 100-fold so that ∇θ is large: ψ′∇θ and ψ″∇θ∇θᵀ overflow; `k · 1e308`: the sum over
/// hinges does) are errors of the bare model, not infinities
/// in its arrays (before: `hinge eval` printed `"energy": inf` and exited 0). The gradient error names the
/// lowest caller vertex whose gradient is not finite, the Hessian error the lowest caller vertex whose
/// lower-triangle row holds a non-finite value — read from the raw output, which `evaluate_add` (a
/// system's path, checked by `System::check_finite`) still returns — and that vertex has a hinge whose own
/// contribution ψ′(θ)∇θ, computed here per hinge, overflows. Same error sequentially and on 1, 2 and 3
/// threads, on a renumbered torus (every edge a hinge) and an irregular sheet above the parallel threshold;
/// k = 1e290 evaluates.
#[test]
fn overflowing_outputs_are_errors_naming_the_lowest_vertex() {
    use hinge_core::error::ElementRef;
    use hinge_core::hinge::theta_and_gradient;
    for (name, mesh) in [
        (
            "torus",
            renumbered(shapes::torus(16, 10, 1.0, 0.4).expect("mesh"), 8),
        ),
        (
            "irregular",
            renumbered(shapes::irregular_sheet(48, 48, 6).expect("mesh"), 3),
        ),
    ] {
        let x: Vec<_> = deform(&mesh, 17).iter().map(|p| p * 0.01).collect();
        let model = |expr: &str, k: f64| {
            BendingModel::new(
                &mesh,
                RuntimePsi::new(expr, [("k", k.into())]).expect("psi"),
            )
            .expect("model")
        };
        const K: f64 = 1.5e307;
        let big = model("k * theta.powi(2)", K);
        let n = mesh.n_vertices();
        // The raw output (no check on the accumulate path).
        let (mut e, mut g, mut h) = (0.0, vec![0.0; 3 * n], vec![0.0; big.pattern().nnz()]);
        big.evaluate_add(
            &x,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
            &mut big.new_scratch(),
            &mut e,
            &mut g,
            &mut h,
        )
        .expect("raw");
        let lowest_g = (0..n).find(|&v| g[3 * v..3 * v + 3].iter().any(|c| !c.is_finite()));
        let p = big.pattern();
        let lowest_h = h
            .iter()
            .enumerate()
            .filter(|(_, v)| !v.is_finite())
            .map(|(k, _)| p.caller_dof(p.row_idx()[k]) / 3)
            .min();
        let (Some(lowest_g), Some(lowest_h)) = (lowest_g, lowest_h) else {
            panic!("{name}: the overflow this test needs");
        };
        // By hand: a hinge at that vertex whose own gradient contribution 2kθ ∇θ overflows.
        let topo = hinge_core::Topology::new(n, mesh.triangles()).expect("topology");
        let own = topo.hinges().iter().any(|hg| {
            let st = hg.vertices.map(|v| x[v]);
            let (theta, grad) = theta_and_gradient(&st).expect("stencil");
            hg.vertices.iter().zip(&grad).any(|(&v, gv)| {
                v == lowest_g && (gv * (2.0 * K * theta)).iter().any(|c| !c.is_finite())
            })
        });
        assert!(own, "{name}: vertex {lowest_g}");
        let expect = |request: Request, vertex: usize, what: &str| {
            let runs = [
                big.evaluate(&x, request, Method::Refactored, Parallelism::Sequential),
                on_threads(1, || {
                    big.evaluate(&x, request, Method::Refactored, Parallelism::Rayon)
                }),
                on_threads(2, || {
                    big.evaluate(&x, request, Method::Refactored, Parallelism::Rayon)
                }),
                on_threads(3, || {
                    big.evaluate(&x, request, Method::PerHinge, Parallelism::Rayon)
                }),
            ];
            for r in runs {
                match r {
                    Err(EvalError::AtElement {
                        energy,
                        element: ElementRef::Vertex(v),
                        message,
                    }) => {
                        assert_eq!(
                            (energy.as_str(), v),
                            ("bending", vertex),
                            "{name}: {message}"
                        );
                        assert!(message.contains(what), "{name}: {message}");
                    }
                    other => panic!("{name}: {other:?}"),
                }
            }
        };
        expect(
            Request {
                value: false,
                ..Request::GRADIENT
            },
            lowest_g,
            "gradient",
        );
        expect(
            Request {
                value: false,
                gradient: false,
                ..Request::ALL
            },
            lowest_h,
            "Hessian",
        );
        // The energy of every hinge finite, the sum not.
        let total = model("k * 1e308", 1.5);
        for r in [
            total.evaluate(
                &x,
                Request::VALUE,
                Method::Refactored,
                Parallelism::Sequential,
            ),
            on_threads(2, || {
                total.evaluate(&x, Request::ALL, Method::Refactored, Parallelism::Rayon)
            }),
        ] {
            assert!(
                matches!(r, Err(EvalError::NonFiniteTotal { .. })),
                "{name}: {r:?}"
            );
        }
        let fine = model("k * theta.powi(2)", 1e290)
            .evaluate(
                &x,
                Request::ALL,
                Method::Refactored,
                Parallelism::Sequential,
            )
            .expect("k = 1e290 evaluates");
        assert!(fine.energy.is_finite() && fine.hessian.iter().all(|v| v.is_finite()));
    }
}
