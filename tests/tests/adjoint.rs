//! Parameter derivatives and adjoint sensitivities (issue 19): ∂ψ/∂p and ∂ψ′/∂p of derived and run-time ψ
//! against num-dual (an independent tree-walking evaluator of the unsimplified text, hyper-dual in θ and the
//! parameter) and central differences; every energy's `∂E/∂p`, `(∂∇E/∂p)ᵀλ` and `∂∇E/∂p` against central
//! differences on irregular, renumbered meshes; the adjoint `dL/dp` against central differences of
//! re-solved equilibria (scalar, material and per-hinge parameters, a cantilever and a non-grid sheet);
//! fits that recover known parameters from targets the solver made.

use hinge_core::HingeEnergy;
use hinge_core::anisotropy::Anisotropic;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::energy::{Energy, HingeTerm, ParameterOutput, System};
use hinge_core::grid::{Diagonal, SplitMix64, grid};
use hinge_core::nalgebra::{Matrix2, Vector3};
use hinge_core::psi::runtime::{ParamValue, RuntimePsi};
use hinge_core::psi::{DiscreteShells, HingePsi, HingeQuantities};
use hinge_core::shapes::{irregular_sheet, random_permutation, renumber};
use hinge_core::{EvalError, TriMesh};
use hinge_energies::bending::plate_consistent_stiffness;
use hinge_energies::contact::{Contact, Obstacle};
use hinge_energies::corotational::CorotationalMembrane;
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::StvkMembrane;
use hinge_energies::neohookean::NeoHookeanMembrane;
use hinge_energies::pins::Pins;
use hinge_energies::spring::MassSpring;
use hinge_solver::adjoint::{
    Adjoint, AdjointError, Fit, FitOptions, FitVariable, Link, TargetLoss,
};
use hinge_solver::linear::default_solver;
use hinge_solver::newton::{Newton, NewtonParams};
use hinge_tests::*;
use num_dual::{DualNum, HyperDual64};

/// Expressions with two parameters `c0`, `c1`, exercising every rule of the parameter derivative: products,
/// quotients, powers with parameter exponents, functions, `atan2` of parameters, `if`, `abs`, `let`, θ̄.
const EXPRESSIONS: [&str; 7] = [
    "c0 * a * (theta - theta_bar).powi(2) + c1 * theta",
    "c0 * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2) + c1 * theta",
    "c0 * (theta - c1 * theta_bar).powi(2) / (1.0 + c1 * c1)",
    "c0 * (1.0 + theta * theta).powf(c1) + c1.exp() * theta.sin()",
    "c1.atan2(c0) * theta.powi(2) + (c0 * theta + c1).cosh()",
    "if theta < c1 { c0 * (theta - c1).powi(2) } else { c1 * c0.sqrt() * (theta - c1).powi(3) }",
    "{ let d = theta - theta_bar; c0 * d.abs().powi(3) + (c1 * d).tanh() * rest_length }",
];

/// `[∂ψ/∂c_k, ∂ψ′/∂c_k]` for k = 0, 1 and θ̄ from the independent evaluator, hyper-dual in θ and one value.
fn reference(expr: &str, c: [f64; 2], q: &HingeQuantities, theta: f64) -> [[f64; 2]; 3] {
    let tree = hinge_symbolic::text::parse(expr).unwrap_or_else(|e| panic!("{expr}: {e:?}"));
    let mut out = [[0.0; 2]; 3];
    for (k, slot) in out.iter_mut().enumerate() {
        let seed = |i: usize, v: f64| {
            if i == k {
                HyperDual64::new(v, 0.0, 1.0, 0.0)
            } else {
                HyperDual64::from(v)
            }
        };
        let env = [
            ("c0", seed(0, c[0])),
            ("c1", seed(1, c[1])),
            ("theta_bar", seed(2, q.theta_bar)),
            ("a", HyperDual64::from(q.a)),
            ("rest_length", HyperDual64::from(q.rest_length)),
            ("rest_area", HyperDual64::from(q.rest_area)),
            ("theta_prev", HyperDual64::from(q.theta_prev)),
            ("dt", HyperDual64::from(q.dt)),
        ];
        let t = HyperDual64::new(theta, 1.0, 0.0, 0.0);
        let r = tree::eval_dual_env(&tree, t, &env);
        *slot = [r.eps2, r.eps1eps2];
    }
    out
}

fn runtime(expr: &str, c: [f64; 2]) -> RuntimePsi {
    RuntimePsi::new(expr, [("c0", c[0].into()), ("c1", c[1].into())])
        .unwrap_or_else(|e| panic!("{expr}: {e}"))
}

#[test]
fn runtime_parameter_derivatives_match_num_dual_and_finite_differences() {
    let c = [0.8, 1.3];
    let mut worst_dual = 0.0f64;
    let mut worst_fd = 0.0f64;
    let mut compared = 0;
    for (k, expr) in EXPRESSIONS.into_iter().enumerate() {
        let psi = runtime(expr, c);
        assert!(psi.has_parameter_derivatives());
        let names: Vec<String> = HingePsi::parameters(&psi)
            .into_iter()
            .map(|p| p.name)
            .collect();
        assert_eq!(names, ["c0", "c1"]);
        let mut rng = SplitMix64(900 + k as u64);
        for i in 0..200 {
            let q = random_quantities(&mut rng, i);
            let theta = rng.range(-2.0, 2.0);
            let mut d = [[0.0; 2]; 3];
            assert!(psi.parameter_derivatives(&q, theta, &mut d));
            assert!(!psi.parameter_derivatives(&q, theta, &mut [[0.0; 2]; 2]));
            let r = reference(expr, c, &q, theta);
            for j in 0..3 {
                for m in 0..2 {
                    let scale = r[j][m].abs().max(1.0);
                    worst_dual = worst_dual.max((d[j][m] - r[j][m]).abs() / scale);
                    compared += 1;
                }
            }
            // Central differences of ψ and ψ′ in each parameter (through re-built energies: c0, c1) and θ̄
            // (through the quantities).
            let h = 1e-6;
            for j in 0..3 {
                let eval_at = |delta: f64| {
                    let (mut cc, mut qq) = (c, q);
                    if j < 2 {
                        cc[j] += delta;
                    } else {
                        qq.theta_bar += delta;
                    }
                    let p = runtime(expr, cc);
                    let params = p.params(&qq);
                    p.eval(&params, theta)
                };
                let (fp, fm) = (eval_at(h), eval_at(-h));
                for m in 0..2 {
                    let fd = (fp[m] - fm[m]) / (2.0 * h);
                    let scale = fd.abs().max(d[j][m].abs()).max(1.0);
                    worst_fd = worst_fd.max((fd - d[j][m]).abs() / scale);
                }
            }
        }
    }
    println!(
        "runtime ∂ψ/∂p, ∂ψ′/∂p over {compared} values: num-dual {worst_dual:.1e}, central differences {worst_fd:.1e}"
    );
    assert!(worst_dual < 1e-12, "{worst_dual}");
    assert!(worst_fd < 1e-6, "{worst_fd}");
}

/// A derived energy with a scalar and a per-hinge field, and the same text at run time.
#[derive(Debug, Clone, PartialEq, HingeEnergy)]
#[psi(k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2) + s * (theta - theta_bar).powi(3))]
struct Graded {
    k: f64,
    #[per_hinge]
    s: Vec<f64>,
}

const GRADED: &str = "k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2) + s * (theta - theta_bar).powi(3)";

#[test]
fn derived_parameter_derivatives_equal_the_runtime_ones_and_num_dual() {
    let s: Vec<f64> = (0..10).map(|i| 0.1 + 0.05 * i as f64).collect();
    let derived = Graded {
        k: 1.7,
        s: s.clone(),
    };
    let rt = RuntimePsi::new(
        GRADED,
        [
            ("k", ParamValue::Scalar(1.7)),
            ("s", ParamValue::PerHinge(s.clone())),
        ],
    )
    .unwrap();
    let infos = HingePsi::parameters(&derived);
    assert_eq!(infos.len(), 2);
    assert_eq!((infos[0].name.as_str(), infos[0].per_hinge), ("k", false));
    assert_eq!((infos[1].name.as_str(), infos[1].per_hinge), ("s", true));
    assert_eq!(HingePsi::parameters(&rt), infos);
    let mut rng = SplitMix64(77);
    let mut worst = 0.0f64;
    let mut worst_dual = 0.0f64;
    for i in 0..500 {
        let q = random_quantities(&mut rng, i % 10);
        let theta = rng.range(-2.0, 2.0);
        let (mut a, mut b) = ([[0.0; 2]; 3], [[0.0; 2]; 3]);
        assert!(derived.parameter_derivatives(&q, theta, &mut a));
        assert!(rt.parameter_derivatives(&q, theta, &mut b));
        for j in 0..3 {
            for m in 0..2 {
                worst = worst.max((a[j][m] - b[j][m]).abs() / a[j][m].abs().max(1e-300));
            }
        }
        // num-dual on the text with k, s_h, θ̄ as the seeded values.
        let tree = hinge_symbolic::text::parse(GRADED).unwrap();
        for (j, slot) in a.iter().enumerate() {
            let seed = |idx: usize, v: f64| {
                if idx == j {
                    HyperDual64::new(v, 0.0, 1.0, 0.0)
                } else {
                    HyperDual64::from(v)
                }
            };
            let env = [
                ("k", seed(0, 1.7)),
                ("s", seed(1, s[q.hinge])),
                ("theta_bar", seed(2, q.theta_bar)),
                ("a", HyperDual64::from(q.a)),
            ];
            let r = tree::eval_dual_env(&tree, HyperDual64::new(theta, 1.0, 0.0, 0.0), &env);
            for (m, v) in [r.eps2, r.eps1eps2].into_iter().enumerate() {
                worst_dual = worst_dual.max((slot[m] - v).abs() / v.abs().max(1.0));
            }
        }
    }
    println!("derive vs run time: {worst:.1e} relative; derive vs num-dual {worst_dual:.1e}");
    assert!(worst < 1e-14, "{worst}");
    assert!(worst_dual < 1e-12, "{worst_dual}");
    // Getters and setters.
    let mut d = derived.clone();
    assert_eq!(d.parameter_values(0), Some(vec![1.7]));
    assert_eq!(d.parameter_values(1), Some(s.clone()));
    assert_eq!(d.parameter_values(2), None);
    d.set_parameter_values(0, &[2.5]).unwrap();
    assert_eq!(d.k, 2.5);
    assert!(d.set_parameter_values(0, &[1.0, 2.0]).is_err());
    assert_eq!(d.k, 2.5);
    assert!(d.set_parameter_values(5, &[1.0]).is_err());
}

/// An irregular, renumbered sheet bent and jittered (hinges at many angles).
fn sheet() -> (TriMesh, Vec<Vector3<f64>>) {
    let base = irregular_sheet(7, 6, 11).unwrap();
    let perm = random_permutation(base.n_vertices(), 5);
    let rest = renumber(&base, &perm).unwrap();
    let mut rng = SplitMix64(3);
    let x = rest
        .positions()
        .iter()
        .map(|p| {
            Vector3::new(
                1.03 * p.x + 0.01 * rng.symmetric(),
                0.98 * p.y + 0.01 * rng.symmetric(),
                0.25 * (2.5 * p.x).sin() + 0.1 * p.y * p.y + 0.01 * rng.symmetric(),
            )
        })
        .collect();
    (rest, x)
}

fn energies(rest: &TriMesh) -> Vec<Box<dyn Energy>> {
    let n_hinges = hinge_core::topology::hinges(rest).unwrap().len();
    let field: Vec<f64> = (0..n_hinges).map(|i| 0.5 + 0.01 * i as f64).collect();
    let rt = RuntimePsi::new(
        "k * a * (theta - theta_bar).powi(2) + c * (theta - theta_bar).powi(4)",
        [
            ("k", ParamValue::PerHinge(field.clone())),
            ("c", ParamValue::Scalar(0.3)),
        ],
    )
    .unwrap();
    vec![
        Box::new(HingeTerm::new(
            "graded",
            BendingModel::new(
                rest,
                Graded {
                    k: 0.9,
                    s: field.clone(),
                },
            )
            .unwrap(),
            Method::Refactored,
        )),
        Box::new(HingeTerm::new(
            "runtime",
            BendingModel::new(rest, rt).unwrap(),
            Method::Refactored,
        )),
        Box::new(HingeTerm::new(
            "aniso",
            BendingModel::new(
                rest,
                Anisotropic::new(
                    DiscreteShells { k: 0.4 },
                    (0..n_hinges).map(|i| 1.0 + 0.1 * (i % 5) as f64).collect(),
                ),
            )
            .unwrap(),
            Method::Refactored,
        )),
        Box::new(StvkMembrane::new(rest, 50.0, 0.3, 0.01).unwrap()),
        Box::new(NeoHookeanMembrane::new(rest, 40.0, 0.2, 0.02).unwrap()),
        Box::new(CorotationalMembrane::new(rest, 0.7).unwrap()),
        Box::new(MassSpring::new(rest, 3.0).unwrap()),
        Box::new(Gravity::new(lumped_masses(rest, 0.2), Vector3::new(0.1, 0.0, -9.81)).unwrap()),
        Box::new(
            Contact::new(
                rest.n_vertices(),
                Obstacle::Plane {
                    point: Vector3::new(0.0, 0.0, -0.05),
                    normal: Vector3::new(0.0, 0.1, 1.0),
                },
                40.0,
                0.2,
            )
            .unwrap(),
        ),
    ]
}

/// Energy and gradient of `system` at `x`.
fn eg(system: &mut System, x: &[Vector3<f64>]) -> (f64, Vec<f64>) {
    let r = system
        .evaluate(x, Request::GRADIENT, Parallelism::Sequential)
        .unwrap();
    (r.energy, r.gradient)
}

/// Terms of the same name get labels `NAME#k` in parameter names, so the second of two custom bending terms
/// (or of two obstacles) can be read, set and differentiated: against one-term systems of each.
#[test]
fn repeated_term_names_are_numbered_in_parameter_names() {
    let (rest, x) = sheet();
    let n = rest.n_vertices();
    let bend = |c: f64| -> Box<dyn Energy> {
        let psi = RuntimePsi::new(
            "c * a * (theta - theta_bar).powi(2)",
            [("c", ParamValue::Scalar(c))],
        )
        .unwrap();
        Box::new(HingeTerm::new(
            "custom",
            BendingModel::new(&rest, psi).unwrap(),
            Method::Refactored,
        ))
    };
    let plane = |z: f64, k: f64| -> Box<dyn Energy> {
        Box::new(
            Contact::new(
                n,
                Obstacle::Plane {
                    point: Vector3::new(0.0, 0.0, z),
                    normal: Vector3::z(),
                },
                k,
                0.01,
            )
            .unwrap(),
        )
    };
    let mut system = System::new(
        n,
        vec![bend(1.0), plane(0.1, 50.0), bend(3.0), plane(0.2, 50.0)],
    )
    .unwrap();
    assert_eq!(
        system.term_labels(),
        ["custom", "contact-plane", "custom#2", "contact-plane#2"]
    );
    let names: Vec<String> = system.parameters().into_iter().map(|p| p.name).collect();
    for want in [
        "custom.c",
        "custom#2.c",
        "custom#2.theta_bar",
        "contact-plane.stiffness",
        "contact-plane#2.stiffness",
    ] {
        assert!(names.iter().any(|m| m == want), "{want} not in {names:?}");
    }
    assert_eq!(system.parameter("custom.c").unwrap(), [1.0]);
    assert_eq!(system.parameter("custom#2.c").unwrap(), [3.0]);
    let energy = |s: &mut System| {
        s.evaluate(&x, Request::VALUE, Parallelism::Sequential)
            .unwrap()
            .energy
    };
    // Setting the second term's parameter is the system of the first term and the second at the new value.
    system.set_parameter("custom#2.c", &[5.0]).unwrap();
    system
        .set_parameter("contact-plane#2.stiffness", &[70.0])
        .unwrap();
    assert_eq!(system.parameter("custom.c").unwrap(), [1.0]);
    let parts: Vec<f64> = [bend(1.0), plane(0.1, 50.0), bend(5.0), plane(0.2, 70.0)]
        .into_iter()
        .map(|t| energy(&mut System::new(n, vec![t]).unwrap()))
        .collect();
    assert!(parts[1] > 0.0 && parts[3] > 0.0, "{parts:?}");
    let total: f64 = parts.iter().sum();
    assert!((energy(&mut system) - total).abs() <= 1e-13 * total);
    // ∂E/∂c of the second term: its energy over c (it is linear in c).
    let mut de = vec![0.0];
    system
        .add_parameter_derivatives(
            &x,
            "custom#2.c",
            &mut ParameterOutput {
                energy: &mut de,
                lambda: &[],
                contracted: &mut [],
                direction: &[],
                gradient: &mut [],
            },
        )
        .unwrap();
    assert!(
        (de[0] - parts[2] / 5.0).abs() <= 1e-13 * de[0].abs(),
        "{de:?}"
    );
    assert!(matches!(
        system.parameter("custom#3.c"),
        Err(EvalError::Parameter { .. })
    ));
}

#[test]
fn every_parameter_derivative_matches_central_differences() {
    let (rest, x) = sheet();
    let n = rest.n_vertices();
    let mut system = System::new(n, energies(&rest)).unwrap();
    let params = system.parameters();
    let names: Vec<&str> = params.iter().map(|p| p.name.as_str()).collect();
    for want in [
        "graded.k",
        "graded.s",
        "graded.theta_bar",
        "runtime.k",
        "runtime.c",
        "runtime.theta_bar",
        "aniso.k",
        "aniso.theta_bar",
        "membrane.young",
        "membrane.poisson",
        "membrane.thickness",
        "neo-hookean-membrane.young",
        "neo-hookean-membrane.poisson",
        "neo-hookean-membrane.thickness",
        "corotational-membrane.stiffness",
        "mass-spring.k",
        "gravity.g",
        "contact-plane.stiffness",
    ] {
        assert!(names.contains(&want), "{want} not in {names:?}");
    }
    let mut rng = SplitMix64(8);
    let lambda: Vec<f64> = (0..3 * n).map(|_| rng.symmetric()).collect();
    let mut worst = 0.0f64;
    // Each energy alone (the differences of one term are not drowned in the others' rounding).
    let count = energies(&rest).len();
    for term in 0..count {
        let mut one = System::new(n, vec![energies(&rest).swap_remove(term)]).unwrap();
        for p in one.parameters() {
            let mut de = vec![0.0; p.len];
            let mut dc = vec![0.0; p.len];
            // The gradient's derivative along a random direction, checked against the same combination
            // of differences below.
            let direction: Vec<f64> = (0..p.len).map(|_| rng.range(0.5, 1.5)).collect();
            let mut dg = vec![0.0; 3 * n];
            one.add_parameter_derivatives(
                &x,
                &p.name,
                &mut ParameterOutput {
                    energy: &mut de,
                    lambda: &lambda,
                    contracted: &mut dc,
                    direction: &direction,
                    gradient: &mut dg,
                },
            )
            .unwrap();

            let base = one.parameter(&p.name).unwrap();
            // Entries checked: all of a short parameter, every 7th of a field.
            for i in (0..p.len).step_by(if p.len > 3 { 7 } else { 1 }) {
                let h = 1e-3 * base[i].abs().max(1e-1);
                let mut at = |delta: f64| {
                    let mut v = base.clone();
                    v[i] += delta;
                    one.set_parameter(&p.name, &v).unwrap();
                    let r = eg(&mut one, &x);
                    one.set_parameter(&p.name, &base).unwrap();
                    r
                };
                // Central differences at h and 2h, Richardson-extrapolated (error O(h⁴)).
                let mut central = |h: f64| {
                    let ((ep, gp), (em, gm)) = (at(h), at(-h));
                    let g: Vec<f64> = gp
                        .iter()
                        .zip(&gm)
                        .map(|(a, b)| (a - b) / (2.0 * h))
                        .collect();
                    ((ep - em) / (2.0 * h), g)
                };
                let ((e1, g1), (e2, g2)) = (central(h), central(2.0 * h));
                let fd_e = (4.0 * e1 - e2) / 3.0;
                let fd_g: Vec<f64> = g1
                    .iter()
                    .zip(&g2)
                    .map(|(a, b)| (4.0 * a - b) / 3.0)
                    .collect();
                let fd_c: f64 = fd_g.iter().zip(&lambda).map(|(a, b)| a * b).sum();
                let scale_g = fd_g.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-8);
                let err_e = (fd_e - de[i]).abs() / fd_e.abs().max(1e-8);
                let err_c = (fd_c - dc[i]).abs() / fd_c.abs().max(scale_g);
                let err = err_e.max(err_c);
                assert!(
                    err < 1e-6,
                    "{} [{i}]: {err:.2e} (E {fd_e} vs {})",
                    p.name,
                    de[i]
                );
                worst = worst.max(err);
            }
            // Along the direction: every entry moves by t·d_i.
            let t = 1e-3 * base.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-1);
            let mut along = |t: f64| {
                let v: Vec<f64> = base
                    .iter()
                    .zip(&direction)
                    .map(|(b, d)| b + t * d)
                    .collect();
                one.set_parameter(&p.name, &v).unwrap();
                let r = eg(&mut one, &x).1;
                one.set_parameter(&p.name, &base).unwrap();
                r
            };
            let mut central = |t: f64| -> Vec<f64> {
                let (a, b) = (along(t), along(-t));
                a.iter().zip(&b).map(|(a, b)| (a - b) / (2.0 * t)).collect()
            };
            let (c1, c2) = (central(t), central(2.0 * t));
            let fd_dir: Vec<f64> = c1
                .iter()
                .zip(&c2)
                .map(|(a, b)| (4.0 * a - b) / 3.0)
                .collect();
            let scale = fd_dir.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-8);
            let e = fd_dir
                .iter()
                .zip(&dg)
                .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
                / scale;
            assert!(e < 1e-6, "{}: directional {e:.2e}", p.name);
            worst = worst.max(e);
        }
    }
    println!(
        "{} parameters: worst relative error against central differences {worst:.1e}",
        params.len()
    );
    // Unknown names and bad values are typed errors naming them; nothing changes on error.
    let before = system.parameter("membrane.young").unwrap();
    for (name, values) in [
        ("membrane.nope", vec![1.0]),
        ("membrane.young", vec![-1.0]),
        ("membrane.young", vec![1.0, 2.0]),
        ("membrane.poisson", vec![0.5]),
        ("membrane.poisson", vec![-1.0]),
        ("membrane.poisson", vec![f64::NAN]),
        ("neo-hookean-membrane.poisson", vec![0.7]),
        ("graded.s", vec![1.0]),
        ("graded.theta_bar", vec![f64::NAN; 3]),
    ] {
        match system.set_parameter(name, &values) {
            Err(EvalError::Parameter { name: n, .. }) => assert!(name.ends_with(n.as_str()), "{n}"),
            Err(EvalError::Psi(_)) => {}
            other => panic!("{name}: {other:?}"),
        }
    }
    assert_eq!(system.parameter("membrane.young").unwrap(), before);
    let e = system.parameter("nothing.here").unwrap_err().to_string();
    assert!(
        e.contains("nothing.here") && e.contains("membrane.young"),
        "{e}"
    );
}

/// One triangle's membrane energy in an independent closed form (no rest frame, no `b_v`), hyper-dual: with
/// the rest Gram matrix `G` of the two edges from corner 0 and the deformed one `g`, `M = G⁻¹ g` is similar
/// to `C = FᵀF`, so StVK's `tr E = ½ (tr M − 2)`, `tr E² = ¼ tr (M − I)²`, and the neo-Hookean
/// `I₁ = tr M`, `J² = det M`; the Lamé constants from `ν` by the plane-stress formulas.
fn membrane_closed_form(
    neo_hookean: bool,
    (young, thickness): (f64, f64),
    nu: HyperDual64,
    rest: &[Vector3<f64>; 3],
    x: &[HyperDual64; 9],
) -> HyperDual64 {
    let mu = (nu + 1.0).recip() * (0.5 * young);
    let lambda = nu * young / (-(nu * nu) + 1.0);
    let (r1, r2) = (rest[1] - rest[0], rest[2] - rest[0]);
    let gram = Matrix2::new(r1.dot(&r1), r1.dot(&r2), r1.dot(&r2), r2.dot(&r2));
    let gi = gram.try_inverse().unwrap();
    let area = 0.5 * r1.cross(&r2).norm();
    let d = |k: usize| [0, 1, 2].map(|c| x[3 * k + c] - x[c]);
    let dot = |a: [HyperDual64; 3], b: [HyperDual64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (d1, d2) = (d(1), d(2));
    let g = [[dot(d1, d1), dot(d1, d2)], [dot(d1, d2), dot(d2, d2)]];
    let m = |i: usize, j: usize| g[0][j] * gi[(i, 0)] + g[1][j] * gi[(i, 1)];
    let w = if neo_hookean {
        let log_det = (m(0, 0) * m(1, 1) - m(0, 1) * m(1, 0)).ln();
        mu * 0.5 * (m(0, 0) + m(1, 1) - 2.0) - mu * 0.5 * log_det
            + lambda * 0.125 * log_det * log_det
    } else {
        let (a, b) = (m(0, 0) - 1.0, m(1, 1) - 1.0);
        let tr = (a + b) * 0.5;
        let tr2 = (a * a + m(0, 1) * m(1, 0) * 2.0 + b * b) * 0.25;
        mu * tr2 + lambda * 0.5 * tr * tr
    };
    w * (thickness * area)
}

/// `∂E/∂ν`, `(∂∇E/∂ν)ᵀλ` and `∂∇E/∂ν` of the StVK and neo-Hookean membranes against num-dual on an independent
/// closed form (hyper-dual: ν along the first unit, the vertices along λ or along one coordinate in the
/// second), on one triangle under random stretches, compressions and rotations, in each of its three corner
/// rotations, with ν from −0.9 to 0.49 (central differences check it on a whole mesh above).
#[test]
fn poisson_derivatives_match_num_dual_on_an_independent_closed_form() {
    let rest = [
        Vector3::new(0.1, 0.0, 0.05),
        Vector3::new(1.0, 0.2, 0.0),
        Vector3::new(0.3, 0.8, -0.1),
    ];
    let (young, thickness) = (300.0, 0.02);
    let mut rng = SplitMix64(17);
    let mut worst = 0.0f64;
    for case in 0..120 {
        let nu = [-0.9, -0.3, 0.0, 0.2, 0.3, 0.45, 0.49][case % 7];
        let a = [0, 1, 2].map(|_| Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()));
        // F ≈ s (I + 0.4 A): stretches from 0.3 (compressed) to 1.8, random tilts.
        let s = rng.range(0.3, 1.8);
        let x: Vec<Vector3<f64>> = rest
            .iter()
            .map(|p| p * s + (a[0] * p.x + a[1] * p.y + a[2] * p.z) * (0.4 * s))
            .collect();
        let lambda: Vec<f64> = (0..9).map(|_| rng.symmetric()).collect();
        for rotation in 0..3 {
            let corners = [rotation, (rotation + 1) % 3, (rotation + 2) % 3];
            let mesh = TriMesh::new(rest.to_vec(), vec![corners]).unwrap();
            for neo in [false, true] {
                let energy: Box<dyn Energy> = if neo {
                    Box::new(NeoHookeanMembrane::new(&mesh, young, nu, thickness).unwrap())
                } else {
                    Box::new(StvkMembrane::new(&mesh, young, nu, thickness).unwrap())
                };
                let mut system = System::new(3, vec![energy]).unwrap();
                let name = if neo {
                    "neo-hookean-membrane.poisson"
                } else {
                    "membrane.poisson"
                };
                let (mut de, mut dc, mut dg) = ([0.0], [0.0], vec![0.0; 9]);
                system
                    .add_parameter_derivatives(
                        &x,
                        name,
                        &mut ParameterOutput {
                            energy: &mut de,
                            lambda: &lambda,
                            contracted: &mut dc,
                            direction: &[1.0],
                            gradient: &mut dg,
                        },
                    )
                    .unwrap();
                // The closed form in the mesh's own corner order is the same triangle: the energy does
                // not depend on which corner comes first.
                let rest_c = corners.map(|c| rest[c]);
                let along = |dir: &[f64]| {
                    let xs: [HyperDual64; 9] = std::array::from_fn(|k| {
                        let (v, c) = (corners[k / 3], k % 3);
                        HyperDual64::new(x[v][c], 0.0, dir[3 * v + c], 0.0)
                    });
                    membrane_closed_form(
                        neo,
                        (young, thickness),
                        HyperDual64::new(nu, 1.0, 0.0, 0.0),
                        &rest_c,
                        &xs,
                    )
                };
                let r = along(&lambda);
                let tol = |v: f64, scale: f64| 1e-12 * v.abs().max(scale);
                assert!(
                    (de[0] - r.eps1).abs() <= tol(r.eps1, 1e-6),
                    "{case} {name}: {} {}",
                    de[0],
                    r.eps1
                );
                assert!(
                    (dc[0] - r.eps1eps2).abs() <= tol(r.eps1eps2, 1e-6),
                    "{case} {name}: {} {}",
                    dc[0],
                    r.eps1eps2
                );
                let reference: Vec<f64> = (0..9)
                    .map(|k| {
                        let mut unit = vec![0.0; 9];
                        unit[k] = 1.0;
                        along(&unit).eps1eps2
                    })
                    .collect();
                let scale = reference.iter().fold(1e-6f64, |m, v| m.max(v.abs()));
                for k in 0..9 {
                    assert!(
                        (dg[k] - reference[k]).abs() <= 1e-12 * scale,
                        "{case} {name} [{k}]: {} {}",
                        dg[k],
                        reference[k]
                    );
                }
                worst = worst
                    .max((de[0] - r.eps1).abs() / r.eps1.abs().max(1e-6))
                    .max(rel_error(&dg, &reference));
            }
        }
    }
    println!(
        "membrane Poisson-ratio derivatives against num-dual: worst relative error {worst:.1e}"
    );
}

/// A cantilever: a strip clamped at x = 0 (its first two vertex columns), discrete-shells bending with the
/// plate-consistent stiffness of the material, StVK membrane, gravity.
struct Cantilever {
    rest: TriMesh,
    pins: Pins,
    young: f64,
    thickness: f64,
    poisson: f64,
}

fn cantilever(rest: TriMesh, spacing: f64, young: f64) -> Cantilever {
    let n = rest.n_vertices();
    let pinned: Vec<usize> = (0..n)
        .filter(|&v| rest.positions()[v].x < 1.35 * spacing)
        .collect();
    Cantilever {
        pins: Pins::new(n, pinned).unwrap(),
        rest,
        young,
        thickness: 1e-3,
        poisson: 0.3,
    }
}

fn cantilever_system(c: &Cantilever, per_hinge: bool) -> System {
    let k = plate_consistent_stiffness(c.young, c.thickness, c.poisson);
    let n_hinges = hinge_core::topology::hinges(&c.rest).unwrap().len();
    let psi = if per_hinge {
        RuntimePsi::new(
            "k * a * (theta - theta_bar).powi(2)",
            [("k", ParamValue::PerHinge(vec![k; n_hinges]))],
        )
    } else {
        RuntimePsi::new("k * a * (theta - theta_bar).powi(2)", [("k", k.into())])
    }
    .unwrap();
    System::new(
        c.rest.n_vertices(),
        vec![
            Box::new(HingeTerm::new(
                "bending",
                BendingModel::new(&c.rest, psi).unwrap(),
                Method::Refactored,
            )),
            Box::new(StvkMembrane::new(&c.rest, c.young, c.poisson, c.thickness).unwrap()),
            Box::new(
                Gravity::new(
                    lumped_masses(&c.rest, 1000.0 * c.thickness),
                    Vector3::new(0.0, 0.0, -9.81),
                )
                .unwrap(),
            ),
        ],
    )
    .unwrap()
}

fn tight_newton(system: &System, pins: &Pins) -> Newton {
    Newton::new(
        system,
        pins,
        default_solver(),
        NewtonParams {
            max_iterations: 400,
            gradient_tolerance: 1e-10,
            step_tolerance: 0.0,
            relative_gradient_tolerance: 0.0,
            relative_step_tolerance: 0.0,
            ..NewtonParams::default()
        },
    )
    .unwrap()
}

/// A tight Newton solver for `system` (the cantilever's pins), the equilibrium from the rest state, and
/// the loss of a target that is the equilibrium moved by a smooth field (not an equilibrium of anything).
fn equilibrium_and_moved_target(
    c: &Cantilever,
    system: &mut System,
) -> (Newton, Vec<Vector3<f64>>, TargetLoss) {
    let mut newton = tight_newton(system, &c.pins);
    let mut x = c.rest.positions().to_vec();
    newton.minimize(system, &mut x, None).unwrap();
    let target: Vec<Vector3<f64>> = x
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.002 * p.x, -0.01 * p.x * p.x))
        .collect();
    (newton, x, TargetLoss::all(target))
}

/// `f′(0)` by central differences at `h` and `2h`, Richardson-extrapolated (error O(h⁴)).
fn richardson(f: &mut impl FnMut(f64) -> f64, h: f64) -> f64 {
    let d1 = (f(h) - f(-h)) / (2.0 * h);
    let d2 = (f(2.0 * h) - f(-2.0 * h)) / (4.0 * h);
    (4.0 * d1 - d2) / 3.0
}

/// `checks`: parameter, entry, central-difference step.
fn check_adjoint(c: &Cantilever, per_hinge: bool, checks: &[(&str, usize, f64)]) -> f64 {
    let mut system = cantilever_system(c, per_hinge);
    let (mut newton, x, loss) = equilibrium_and_moved_target(c, &mut system);
    let mut dl = vec![0.0; 3 * x.len()];
    loss.evaluate(&x, &mut dl).unwrap();
    let mut adjoint = Adjoint::new(&system, &c.pins).unwrap();
    adjoint.factor(&mut system, &x).unwrap();
    adjoint.solve(&dl).unwrap();
    let mut worst = 0.0f64;
    for &(name, entry, h) in checks {
        let g = adjoint.parameter_gradient(&mut system, &x, name).unwrap();
        let base = system.parameter(name).unwrap();
        let mut solved = |delta: f64| {
            let mut v = base.clone();
            v[entry] += delta;
            system.set_parameter(name, &v).unwrap();
            let mut y = x.clone();
            newton.minimize(&mut system, &mut y, None).unwrap();
            system.set_parameter(name, &base).unwrap();
            loss.evaluate(&y, &mut vec![0.0; 3 * y.len()]).unwrap()
        };
        let fd = richardson(&mut solved, h);
        let err = (fd - g[entry]).abs() / fd.abs().max(g[entry].abs());
        println!(
            "  dL/d{name}[{entry}] = {:.6e}, central differences {fd:.6e}, relative {err:.1e}",
            g[entry]
        );
        worst = worst.max(err);
    }
    worst
}

#[test]
fn adjoint_gradients_match_central_differences_of_resolved_equilibria() {
    // A cantilever strip (grid) and an irregular renumbered sheet clamped the same way.
    let strip = cantilever(
        grid(12, 2, 0.3, 0.05, Diagonal::Alternating).unwrap(),
        0.025,
        2e8,
    );
    let k = plate_consistent_stiffness(2e8, strip.thickness, strip.poisson);
    let w1 = check_adjoint(
        &strip,
        false,
        &[
            ("bending.k", 0, 1e-3 * k),
            ("membrane.young", 0, 2e6),
            ("membrane.thickness", 0, 1e-6),
            ("gravity.g", 2, 1e-2),
            ("bending.theta_bar", 5, 1e-3),
        ],
    );
    let sheet = irregular_cantilever(0.3);
    let w2 = check_adjoint(
        &sheet,
        true,
        &[
            ("bending.k", 3, 1e-3 * k),
            ("bending.k", 17, 1e-3 * k),
            ("bending.theta_bar", 11, 1e-3),
            ("membrane.young", 0, 2e6),
            ("membrane.poisson", 0, 1e-3),
        ],
    );
    assert!(w1 < 1e-6 && w2 < 1e-6, "{w1:.2e} {w2:.2e}");
}

#[test]
fn an_indefinite_hessian_is_a_typed_error() {
    // A strip compressed along its length by moving pins, released from a buckled-symmetric flat state: the
    // flat state under compression is a saddle.
    let rest = grid(10, 1, 1.0, 0.1, Diagonal::Alternating).unwrap();
    let n = rest.n_vertices();
    let mut system = System::new(
        n,
        vec![
            Box::new(HingeTerm::new(
                "bending",
                BendingModel::new(
                    &rest,
                    RuntimePsi::new("k * a * (theta - theta_bar).powi(2)", [("k", 1e-4.into())])
                        .unwrap(),
                )
                .unwrap(),
                Method::Refactored,
            )),
            Box::new(StvkMembrane::new(&rest, 1e6, 0.3, 1e-3).unwrap()),
        ],
    )
    .unwrap();
    let pins = Pins::new(
        n,
        (0..n)
            .filter(|&v| rest.positions()[v].x < 1e-9 || rest.positions()[v].x > 1.0 - 1e-9)
            .collect(),
    )
    .unwrap();
    let x: Vec<Vector3<f64>> = rest
        .positions()
        .iter()
        .map(|p| Vector3::new(0.9 * p.x, p.y, 0.0))
        .collect();
    let mut adjoint = Adjoint::new(&system, &pins).unwrap();
    match adjoint.factor(&mut system, &x) {
        Err(AdjointError::NotMinimum { vertex, .. }) => assert!(vertex < n),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        adjoint.solve(&vec![0.0; 3 * n]),
        Err(AdjointError::NotFactored)
    ));
}

/// Fits `variable` of `system` (pins of `c`) to the equilibrium `target` from the rest state, and prints the
/// fit's figures under `label`.
fn fit_to(
    c: &Cantilever,
    system: &mut System,
    newton: &mut Newton,
    variable: FitVariable,
    options: FitOptions,
    target: Vec<Vector3<f64>>,
    label: &str,
) -> hinge_solver::adjoint::FitResult {
    let loss = TargetLoss::all(target);
    let mut x = c.rest.positions().to_vec();
    let mut fit = Fit::new(system, &c.pins, newton, vec![variable], options).unwrap();
    let r = fit
        .run(system, &mut x, &mut |x, g| loss.evaluate(x, g))
        .unwrap();
    println!(
        "{label}: {} iterations, {} equilibria, loss {:.2e} → {:.2e} ({})",
        r.iterations, r.equilibria, r.initial_loss, r.loss, r.stop
    );
    assert_eq!(x, r.x);
    r
}

/// The cantilever fit of Young's modulus: the equilibrium of `truth` as the target, and the cantilever,
/// its system, a Newton solver and the fit variable (linked to the bending stiffness and the membrane)
/// starting 3× too stiff.
fn young_s_modulus_fit(truth: f64) -> (Cantilever, System, Newton, FitVariable, Vec<Vector3<f64>>) {
    let c = cantilever(
        grid(16, 2, 0.3, 0.05, Diagonal::Alternating).unwrap(),
        0.3 / 16.0,
        truth,
    );
    let mut system = cantilever_system(&c, false);
    let mut newton = tight_newton(&system, &c.pins);
    let mut target = c.rest.positions().to_vec();
    newton.minimize(&mut system, &mut target, None).unwrap();
    // Young's modulus scales the bending stiffness (plate formula) and the membrane.
    let start = 3.0 * truth;
    let c = Cantilever { young: start, ..c };
    let system = cantilever_system(&c, false);
    let newton = tight_newton(&system, &c.pins);
    let variable = FitVariable {
        name: "material.young".into(),
        start: vec![start],
        positive: true,
        range: None,
        links: vec![
            Link::Power {
                parameter: "bending.k".into(),
                exponent: 1.0,
            },
            Link::Power {
                parameter: "membrane.young".into(),
                exponent: 1.0,
            },
        ],
    };
    (c, system, newton, variable, target)
}

#[test]
fn fitting_recovers_young_s_modulus_of_a_cantilever() {
    let truth = 2e8;
    let (c, mut system, mut newton, variable, target) = young_s_modulus_fit(truth);
    let r = fit_to(
        &c,
        &mut system,
        &mut newton,
        variable,
        FitOptions::default(),
        target,
        "Young's modulus",
    );
    let y = r.values[0][0];
    println!("Young's modulus {y:.6e} (truth {truth:.1e})");
    assert!((y / truth - 1.0).abs() < 0.01, "{y}");
    assert!(r.equilibria <= 25, "{}", r.equilibria);
    assert_eq!(system.parameter("membrane.young").unwrap(), vec![y]);
}

/// A raised stop flag ([`Newton::set_stop`]) ends a fit at its next equilibrium: the error is the
/// interruption (not a halved line-search step, as for a solve that does not converge), and the system
/// holds the start values again.
#[test]
fn a_stop_request_ends_a_fit_with_the_start_values_restored() {
    use hinge_solver::newton::SolverError;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let (c, mut system, mut newton, variable, target) = young_s_modulus_fit(2e8);
    let before = (
        system.parameter("bending.k").unwrap(),
        system.parameter("membrane.young").unwrap(),
    );
    let flag = Arc::new(AtomicBool::new(false));
    newton.set_stop(Some(flag.clone()));
    let loss = TargetLoss::all(target);
    let mut x = c.rest.positions().to_vec();
    let x0 = x.clone();
    let mut fit = Fit::new(
        &system,
        &c.pins,
        &mut newton,
        vec![variable],
        FitOptions::default(),
    )
    .unwrap();
    // Raised after the first accepted L-BFGS iteration (the full fit takes several).
    let raise = flag.clone();
    fit.observe(move |p| {
        if p.iteration == 1 {
            raise.store(true, Ordering::SeqCst);
        }
    });
    let err = fit
        .run(&mut system, &mut x, &mut |x, g| loss.evaluate(x, g))
        .unwrap_err();
    assert!(
        matches!(
            err,
            AdjointError::Equilibrium(SolverError::Interrupted { .. })
        ),
        "{err}"
    );
    assert_eq!(x, x0);
    assert_eq!(
        (
            system.parameter("bending.k").unwrap(),
            system.parameter("membrane.young").unwrap()
        ),
        before
    );
}

/// Non-finite inputs of the adjoint and the fit are typed errors naming the entry, never a NaN gradient
/// or a linear solver's "singular" report: a right-hand side, a target coordinate, a custom loss that is
/// not finite or whose gradient is not. A fit that fails so leaves the start values set.
#[test]
fn non_finite_adjoint_and_fit_inputs_are_named() {
    let (c, mut system, mut newton, variable, target) = young_s_modulus_fit(2e8);
    let n = c.rest.n_vertices();
    let x = target.clone();
    let mut adjoint = Adjoint::new(&system, &c.pins).unwrap();
    adjoint.factor(&mut system, &x).unwrap();
    let mut b = vec![0.0; 3 * n];
    b[3 * 9 + 1] = f64::NAN;
    let err = adjoint.solve(&b).unwrap_err();
    assert!(
        matches!(err, AdjointError::NotFinite { index: 28, .. }),
        "{err}"
    );
    assert_eq!(
        err.to_string(),
        "the right-hand side: entry 28 (vertex 9, coordinate 1) is not finite (NaN)"
    );
    b[28] = 0.5;
    assert!(adjoint.solve(&b).is_ok());
    let mut bad = target.clone();
    bad[4].z = f64::NEG_INFINITY;
    let err = TargetLoss::all(bad)
        .evaluate(&x, &mut vec![0.0; 3 * n])
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "the target positions: entry 14 (vertex 4, coordinate 2) is not finite (-inf)"
    );
    let before = system.parameter("bending.k").unwrap();
    for (nan_loss, message) in [
        (true, "the loss is not finite (NaN) at the equilibrium"),
        (
            false,
            "the loss gradient: entry 5 (vertex 1, coordinate 2) is not finite (inf)",
        ),
    ] {
        let mut fit = Fit::new(
            &system,
            &c.pins,
            &mut newton,
            vec![variable.clone()],
            FitOptions::default(),
        )
        .unwrap();
        let mut start = c.rest.positions().to_vec();
        let err = fit
            .run(&mut system, &mut start, &mut |_, g| {
                g.fill(0.0);
                if nan_loss {
                    Ok(f64::NAN)
                } else {
                    g[5] = f64::INFINITY;
                    Ok(1.0)
                }
            })
            .unwrap_err();
        assert_eq!(err.to_string(), message);
        assert_eq!(system.parameter("bending.k").unwrap(), before);
    }
}

/// Fit options out of range are refused by `Fit::new` with a setup error naming the option and its value;
/// the edges of each range are accepted.
#[test]
fn fit_options_out_of_range_are_refused_by_name() {
    use hinge_solver::newton::MAX_ITERATIONS_CEILING;
    let (c, system, mut newton, variable, _) = young_s_modulus_fit(2e8);
    let d = FitOptions::default;
    let bad: Vec<(FitOptions, &str)> = vec![
        (
            FitOptions {
                max_iterations: MAX_ITERATIONS_CEILING + 1,
                ..d()
            },
            "max_iterations must be from 0 to 1 000 000, got 1000001",
        ),
        (
            FitOptions {
                max_iterations: usize::MAX,
                ..d()
            },
            "max_iterations must be from 0 to 1 000 000",
        ),
        (
            FitOptions {
                max_line_search: 65,
                ..d()
            },
            "max_line_search must be from 0 to 64, got 65",
        ),
        (
            FitOptions {
                memory: 1_001,
                ..d()
            },
            "memory must be from 0 to 1000, got 1001",
        ),
        (
            FitOptions {
                smoothness: f64::NAN,
                ..d()
            },
            "smoothness must be non-negative and finite, got NaN",
        ),
        (
            FitOptions {
                smoothness: -1e-9,
                ..d()
            },
            "smoothness must be non-negative and finite, got -0.000000001",
        ),
        (
            FitOptions {
                loss_tolerance: f64::INFINITY,
                ..d()
            },
            "loss_tolerance must be non-negative and finite, got inf",
        ),
        (
            FitOptions {
                relative_loss_tolerance: -1.0,
                ..d()
            },
            "relative_loss_tolerance must be non-negative and finite, got -1",
        ),
        (
            FitOptions {
                relative_gradient_tolerance: f64::NAN,
                ..d()
            },
            "relative_gradient_tolerance must be non-negative and finite, got NaN",
        ),
        (
            FitOptions {
                relative_decrease_tolerance: f64::NEG_INFINITY,
                ..d()
            },
            "relative_decrease_tolerance must be non-negative and finite, got -inf",
        ),
        (
            FitOptions {
                identifiability_tolerance: f64::NAN,
                ..d()
            },
            "identifiability_tolerance must be non-negative and finite, got NaN",
        ),
        (
            FitOptions {
                max_step: 0.0,
                ..d()
            },
            "max_step must be positive and finite, got 0",
        ),
        (
            FitOptions {
                max_step: f64::INFINITY,
                ..d()
            },
            "max_step must be positive and finite, got inf",
        ),
    ];
    for (options, message) in bad {
        let err = Fit::new(
            &system,
            &c.pins,
            &mut newton,
            vec![variable.clone()],
            options,
        )
        .err()
        .unwrap_or_else(|| panic!("accepted: {message}"));
        assert!(matches!(err, AdjointError::Setup(_)), "{err}");
        assert!(
            err.to_string().contains(message),
            "{err} (expected {message})"
        );
    }
    let edges = [
        FitOptions {
            max_iterations: MAX_ITERATIONS_CEILING,
            ..d()
        },
        FitOptions {
            max_iterations: 0,
            max_line_search: 0,
            memory: 0,
            ..d()
        },
        FitOptions {
            max_line_search: FitOptions::MAX_LINE_SEARCH,
            memory: FitOptions::MAX_MEMORY,
            ..d()
        },
        FitOptions {
            loss_tolerance: 0.0,
            relative_loss_tolerance: 0.0,
            relative_gradient_tolerance: 0.0,
            relative_decrease_tolerance: 0.0,
            identifiability_tolerance: 0.0,
            smoothness: 0.0,
            max_step: f64::MIN_POSITIVE,
            ..d()
        },
    ];
    for options in edges {
        assert!(options.validate().is_ok(), "{options:?}");
        assert!(
            Fit::new(
                &system,
                &c.pins,
                &mut newton,
                vec![variable.clone()],
                options
            )
            .is_ok()
        );
    }
}

#[test]
fn young_s_modulus_and_thickness_together_are_reported_not_identifiable() {
    let c = cantilever(
        grid(16, 2, 0.3, 0.05, Diagonal::Alternating).unwrap(),
        0.3 / 16.0,
        2e8,
    );
    let mut system = cantilever_system(&c, false);
    let mut newton = tight_newton(&system, &c.pins);
    // Young's modulus scales bending (Y h³) and membrane (Y h); thickness the same with h³ and h. On an
    // inextensible cantilever only Y h³ shows in the shape.
    let young = FitVariable {
        name: "material.young".into(),
        start: vec![2e8],
        positive: true,
        range: None,
        links: vec![
            Link::Power {
                parameter: "bending.k".into(),
                exponent: 1.0,
            },
            Link::Power {
                parameter: "membrane.young".into(),
                exponent: 1.0,
            },
        ],
    };
    let thickness = FitVariable {
        name: "material.thickness".into(),
        start: vec![c.thickness],
        positive: true,
        range: None,
        links: vec![
            Link::Power {
                parameter: "bending.k".into(),
                exponent: 3.0,
            },
            Link::Power {
                parameter: "membrane.thickness".into(),
                exponent: 1.0,
            },
        ],
    };
    // The target: the same strip 20% stiffer (so the start is not already the answer).
    system
        .set_parameter(
            "bending.k",
            &[1.2 * system.parameter("bending.k").unwrap()[0]],
        )
        .unwrap();
    let mut target = c.rest.positions().to_vec();
    newton.minimize(&mut system, &mut target, None).unwrap();
    system
        .set_parameter(
            "bending.k",
            &[system.parameter("bending.k").unwrap()[0] / 1.2],
        )
        .unwrap();
    let loss = TargetLoss::all(target);
    let before = system.parameter("bending.k").unwrap();
    let mut x = c.rest.positions().to_vec();
    let mut fit = Fit::new(
        &system,
        &c.pins,
        &mut newton,
        vec![young, thickness],
        FitOptions::default(),
    )
    .unwrap();
    match fit.run(&mut system, &mut x, &mut |x, g| loss.evaluate(x, g)) {
        Err(e @ AdjointError::NotIdentifiable { .. }) => {
            let m = e.to_string();
            println!("{m}");
            assert!(
                m.contains("material.young") && m.contains("material.thickness"),
                "{m}"
            );
        }
        other => panic!("{other:?}"),
    }
    // Nothing changed.
    assert_eq!(system.parameter("bending.k").unwrap(), before);
    assert_eq!(x, c.rest.positions().to_vec());
}

/// Adjacent hinge pairs (hinges sharing a triangle) of `rest`: the smoothness regularizer's graph.
fn adjacent_hinges(rest: &TriMesh) -> Vec<(usize, usize, usize)> {
    let hinges = hinge_core::topology::hinges(rest).unwrap();
    let mut by_vertex_pair = std::collections::HashMap::new();
    for (i, h) in hinges.iter().enumerate() {
        by_vertex_pair.insert(
            (
                h.vertices[1].min(h.vertices[2]),
                h.vertices[1].max(h.vertices[2]),
            ),
            i,
        );
    }
    let mut pairs = Vec::new();
    for t in rest.triangles() {
        let mut inner = Vec::new();
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if let Some(&h) = by_vertex_pair.get(&(a.min(b), a.max(b))) {
                inner.push(h);
            }
        }
        for i in 0..inner.len() {
            for j in i + 1..inner.len() {
                pairs.push((0, inner[i], inner[j]));
            }
        }
    }
    pairs
}

fn rms_relative(fit: &[f64], truth: &[f64]) -> f64 {
    let num: f64 = fit.iter().zip(truth).map(|(a, b)| (a - b) * (a - b)).sum();
    let den: f64 = truth.iter().map(|b| b * b).sum();
    (num / den).sqrt()
}

#[test]
fn fitting_recovers_a_graded_stiffness_field_along_a_strip() {
    // One cell wide, so that every hinge bends (a hinge along the strip would not, and its stiffness could
    // not show in the shape).
    let c = cantilever(
        grid(16, 1, 0.3, 0.02, Diagonal::Alternating).unwrap(),
        0.3 / 16.0,
        2e8,
    );
    let mut system = cantilever_system(&c, true);
    let hinges = hinge_core::topology::hinges(&c.rest).unwrap();
    let x0 = c.rest.positions();
    let k0 = system.parameter("bending.k").unwrap()[0];
    // Graded: twice as stiff at the clamp as at the tip.
    let truth: Vec<f64> = hinges
        .iter()
        .map(|h| {
            let mid = 0.5 * (x0[h.vertices[1]].x + x0[h.vertices[2]].x);
            k0 * (2.0 - mid / 0.3)
        })
        .collect();
    system.set_parameter("bending.k", &truth).unwrap();
    let mut newton = tight_newton(&system, &c.pins);
    let mut target = x0.to_vec();
    newton.minimize(&mut system, &mut target, None).unwrap();
    let m = truth.len();
    let variable = FitVariable {
        name: "bending.params.k".into(),
        start: vec![k0; m],
        positive: true,
        range: None,
        links: vec![Link::Power {
            parameter: "bending.k".into(),
            exponent: 1.0,
        }],
    };
    system.set_parameter("bending.k", &vec![k0; m]).unwrap();
    let options = FitOptions {
        max_iterations: 200,
        smoothness: 1e-6,
        smooth_pairs: adjacent_hinges(&c.rest),
        ..FitOptions::default()
    };
    let r = fit_to(
        &c,
        &mut system,
        &mut newton,
        variable,
        options,
        target,
        "graded stiffness",
    );
    let rms = rms_relative(&r.values[0], &truth);
    println!(
        "graded stiffness of {m} hinges: RMS error {:.2}%",
        100.0 * rms
    );
    assert!(rms < 0.05, "{rms}");
}

/// Sets the rest angles of `system` (pins of `c`) to `truth`, takes the equilibrium from the rest state as the
/// target, resets the rest angles to zero and fits them back (`fit_to` under `label`). Returns the fit and the
/// target.
fn fit_rest_angles(
    c: &Cantilever,
    system: &mut System,
    truth: &[f64],
    label: &str,
) -> (hinge_solver::adjoint::FitResult, Vec<Vector3<f64>>) {
    system.set_parameter("bending.theta_bar", truth).unwrap();
    let mut newton = tight_newton(system, &c.pins);
    let mut target = c.rest.positions().to_vec();
    newton.minimize(system, &mut target, None).unwrap();
    let m = truth.len();
    let variable = FitVariable {
        name: "bending.rest_angles".into(),
        start: vec![0.0; m],
        positive: false,
        range: None,
        links: vec![Link::Value {
            parameter: "bending.theta_bar".into(),
        }],
    };
    system
        .set_parameter("bending.theta_bar", &vec![0.0; m])
        .unwrap();
    let options = FitOptions {
        max_iterations: 400,
        max_step: 0.3,
        ..FitOptions::default()
    };
    let r = fit_to(
        c,
        system,
        &mut newton,
        variable,
        options,
        target.clone(),
        label,
    );
    (r, target)
}

/// A sheet 0.2 m × 0.15 m clamped along x = 0, its system, and a crease across it: rest angle 0.6 rad on
/// the hinges of the column of edges at x = 0.1 m, 0 elsewhere.
fn creased_sheet() -> (Cantilever, System, Vec<f64>) {
    let rest = grid(8, 6, 0.2, 0.15, Diagonal::Alternating).unwrap();
    let c = cantilever(rest, 0.2 / 8.0, 2e8);
    let system = cantilever_system(&c, false);
    let hinges = hinge_core::topology::hinges(&c.rest).unwrap();
    let x0 = c.rest.positions();
    let truth: Vec<f64> = hinges
        .iter()
        .map(|h| {
            let (a, b) = (x0[h.vertices[1]], x0[h.vertices[2]]);
            if (a.x - 0.1).abs() < 1e-9 && (b.x - 0.1).abs() < 1e-9 {
                0.6
            } else {
                0.0
            }
        })
        .collect();
    (c, system, truth)
}

#[test]
fn fitting_recovers_the_rest_angles_of_a_pre_creased_sheet() {
    // The crease's equilibrium under gravity is the target, the fit starts flat.
    let (c, mut system, truth) = creased_sheet();
    assert!(truth.iter().filter(|t| **t != 0.0).count() >= 5);
    let m = truth.len();
    let (r, _) = fit_rest_angles(&c, &mut system, &truth, "crease");
    let rms = rms_relative(&r.values[0], &truth);
    println!("rest angles of {m} hinges: RMS error {:.2}%", 100.0 * rms);
    assert!(rms < 0.05, "{rms}");
}

/// Rest angles live in [−π, π] (the range of θ; `BendingModel::set_rest_angles` refuses others). A fit of
/// them whose line search tries values beyond (a loss scaled by 1e6 and a step cap of 20 rad: the first
/// trial sets every rest angle to 20 rad) halves those trials instead of failing and lowers the loss; a
/// start beyond π is `AdjointError::OutOfDomain` at once, naming the value.
#[test]
fn a_fit_trial_with_rest_angles_beyond_pi_is_halved_not_fatal() {
    let (c, mut system, truth) = creased_sheet();
    let x0 = c.rest.positions();
    system.set_parameter("bending.theta_bar", &truth).unwrap();
    let mut newton = tight_newton(&system, &c.pins);
    let mut target = x0.to_vec();
    newton.minimize(&mut system, &mut target, None).unwrap();
    system
        .set_parameter("bending.theta_bar", &vec![0.0; truth.len()])
        .unwrap();
    // Out of range: refused by name, the angles unchanged.
    let mut beyond = vec![0.0; truth.len()];
    beyond[3] = 3.2;
    let err = system
        .set_parameter("bending.theta_bar", &beyond)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("value of hinge 3 is 3.2 rad, outside [−π, π]"),
        "{err}"
    );
    assert_eq!(
        system.parameter("bending.theta_bar").unwrap(),
        vec![0.0; truth.len()]
    );
    let pi = std::f64::consts::PI;
    for edge in [pi, -pi] {
        let mut v = vec![0.0; truth.len()];
        v[0] = edge;
        system.set_parameter("bending.theta_bar", &v).unwrap();
    }
    system
        .set_parameter("bending.theta_bar", &vec![0.0; truth.len()])
        .unwrap();
    // One scalar variable setting every hinge's rest angle (the crease target's best uniform fit).
    let variable = |start: f64| FitVariable {
        name: "crease".into(),
        start: vec![start],
        positive: false,
        range: None,
        links: vec![Link::Value {
            parameter: "bending.theta_bar".into(),
        }],
    };
    let loss = TargetLoss::all(target);
    let scaled = |x: &[Vector3<f64>], g: &mut [f64]| -> Result<f64, AdjointError> {
        let l = loss.evaluate(x, g)?;
        g.iter_mut().for_each(|v| *v *= 1e6);
        Ok(1e6 * l)
    };
    let options = FitOptions {
        max_iterations: 100,
        max_step: 20.0,
        ..FitOptions::default()
    };
    let mut x = x0.to_vec();
    let mut fit = Fit::new(
        &system,
        &c.pins,
        &mut newton,
        vec![variable(0.0)],
        options.clone(),
    )
    .unwrap();
    let r = fit
        .run(&mut system, &mut x, &mut |x, g| scaled(x, g))
        .unwrap();
    drop(fit);
    println!(
        "rest angle fit with trials beyond π: {} iterations, {} equilibria, value {} ({})",
        r.iterations, r.equilibria, r.values[0][0], r.stop
    );
    // A scalar acting on every hinge cannot make the crease alone: it fits the best uniform angle, which
    // lies well inside the range, and the loss falls.
    assert!(r.values[0][0].abs() < pi, "{:?}", r.values);
    assert!(r.loss < r.initial_loss, "{} {}", r.loss, r.initial_loss);
    let before = system.parameter("bending.theta_bar").unwrap();
    let mut fit = Fit::new(&system, &c.pins, &mut newton, vec![variable(4.0)], options).unwrap();
    let err = fit
        .run(&mut system, &mut x0.to_vec(), &mut |x, g| scaled(x, g))
        .unwrap_err();
    assert!(matches!(err, AdjointError::OutOfDomain(_)), "{err}");
    assert!(
        err.to_string().contains("is 4 rad, outside [−π, π]"),
        "{err}"
    );
    assert_eq!(system.parameter("bending.theta_bar").unwrap(), before);
}

#[test]
fn fitted_rest_angles_of_an_irregular_sheet_reproduce_its_shape_but_are_not_unique() {
    // An irregular sheet (random diagonals, jittered, vertices renumbered, corners rotated) 0.2 m × 0.15 m,
    // clamped along x = 0, whose rest angles are those of the sheet rolled up an eighth of a turn over its
    // length; its equilibrium under gravity is the target and the fit starts flat. The shape is matched, but
    // one static shape does not determine every hinge's rest angle: a near-flat sheet's hinge angles move
    // with the out-of-plane dofs only (here 49 free vertices for 130 hinges), so rest angles differing
    // along that null space give the same equilibrium. Asserted: the loss falls by 1e-8 and the fitted
    // equilibrium is the target; printed: how far the rest angles are from the rolled ones.
    let c = sheet_cantilever([9, 7], 31, [0.2, 0.15], 77);
    let mut system = cantilever_system(&c, false);
    let hinges = hinge_core::topology::hinges(&c.rest).unwrap();
    let x0 = c.rest.positions();
    let radius = 0.2 / std::f64::consts::FRAC_PI_4;
    let rolled: Vec<Vector3<f64>> = x0
        .iter()
        .map(|p| {
            let a = p.x / radius;
            Vector3::new(radius * a.sin(), p.y, radius * (1.0 - a.cos()))
        })
        .collect();
    let truth: Vec<f64> = hinges
        .iter()
        .map(|h| hinge_core::hinge::theta_only(&h.vertices.map(|v| rolled[v])).unwrap())
        .collect();
    assert!(truth.iter().fold(0.0f64, |m, t| m.max(t.abs())) > 0.02);
    let m = truth.len();
    let (r, target) = fit_rest_angles(&c, &mut system, &truth, "rest angles");
    let rms = rms_relative(&r.values[0], &truth);
    let worst =
        r.x.iter()
            .zip(&target)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).norm()));
    println!(
        "rest angles of {m} hinges on an irregular sheet: shape matched to {worst:.1e} m, rest angles {:.1}% RMS from the rolled ones (not unique)",
        100.0 * rms
    );
    assert!(
        r.loss <= 1e-8 * r.initial_loss,
        "{} {}",
        r.loss,
        r.initial_loss
    );
    assert!(worst < 1e-5, "{worst}");
}

#[test]
fn the_cantilever_bending_test_gives_the_plate_stiffness() {
    // ASTM D1388-like: a strip of known density overhangs under its own weight; from the measured tip
    // deflection δ the flexural rigidity is fitted. The "measurement" is the linear plate formula
    // δ = q L⁴ / (8 D) for a material whose δ/L is 2% (linear theory holds), and the fitted bending stiffness
    // k must give back D through the plate calibration within the beam tests' 10%.
    let (young, thickness, poisson, density) = (2e9, 5e-4, 0.3, 0.6);
    let (cells, length, width) = (60, 0.3, 0.0125);
    let rest = grid(cells, 5, length, width, Diagonal::Alternating).unwrap();
    let mut c = cantilever(rest, length / cells as f64, young);
    c.thickness = thickness;
    c.poisson = poisson;
    let d_true = young * thickness.powi(3) / (12.0 * (1.0 - poisson * poisson));
    let free = length * (1.0 - 1.0 / cells as f64);
    let q = density * 9.81;
    // The material whose plate deflection is δ: choose D so that δ/L = 2%, then the measurement.
    let d_measured = q * free.powi(4) / (8.0 * 0.02 * free);
    let delta = q * free.powi(4) / (8.0 * d_measured);
    let mut system = System::new(
        c.rest.n_vertices(),
        vec![
            Box::new(HingeTerm::new(
                "bending",
                BendingModel::new(
                    &c.rest,
                    RuntimePsi::new(
                        "k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2)",
                        [("k", plate_consistent_stiffness(young, thickness, poisson).into())],
                    )
                    .unwrap(),
                )
                .unwrap(),
                Method::Refactored,
            )),
            Box::new(StvkMembrane::new(&c.rest, young, poisson, thickness).unwrap()),
            Box::new(
                Gravity::new(lumped_masses(&c.rest, density), Vector3::new(0.0, 0.0, -9.81)).unwrap(),
            ),
        ],
    )
    .unwrap();
    let tip: Vec<usize> = (0..c.rest.n_vertices())
        .filter(|&v| (c.rest.positions()[v].x - length).abs() < 1e-12)
        .collect();
    let mut newton = Newton::new(
        &system,
        &c.pins,
        default_solver(),
        NewtonParams {
            max_iterations: 200,
            gradient_tolerance: 1e-9,
            ..NewtonParams::default()
        },
    )
    .unwrap();
    // k = factor · D for the plate calibration; the fitted variable is D.
    let factor = plate_consistent_stiffness(young, thickness, poisson) / d_true;
    let d_start = 2.0 * d_measured;
    system
        .set_parameter("bending.k", &[factor * d_start])
        .unwrap();
    let variable = FitVariable {
        name: "D".into(),
        start: vec![d_start],
        positive: true,
        range: None,
        links: vec![Link::Power {
            parameter: "bending.k".into(),
            exponent: 1.0,
        }],
    };
    let mut loss = |x: &[Vector3<f64>], g: &mut [f64]| -> Result<f64, AdjointError> {
        g.fill(0.0);
        let mut l = 0.0;
        for &v in &tip {
            let r = x[v].z + delta;
            l += r * r;
            g[3 * v + 2] = 2.0 * r;
        }
        Ok(l)
    };
    let mut x = c.rest.positions().to_vec();
    let mut fit = Fit::new(
        &system,
        &c.pins,
        &mut newton,
        vec![variable],
        FitOptions::default(),
    )
    .unwrap();
    let r = fit.run(&mut system, &mut x, &mut loss).unwrap();
    let d_fit = r.values[0][0];
    println!(
        "cantilever test: δ = {delta:.4e} m, fitted D = {d_fit:.4e} N·m, plate D = {d_measured:.4e} (ratio {:.4}); {} equilibria",
        d_fit / d_measured,
        r.equilibria
    );
    assert!(
        (d_fit / d_measured - 1.0).abs() < 0.10,
        "{}",
        d_fit / d_measured
    );
}

/// An irregular sheet of `n` vertices along x and y (seed `seed`) scaled to `size` metres, renumbered
/// (seed `perm`), as a cantilever clamped at x = 0 of Young's modulus 2e8 Pa.
fn sheet_cantilever(n: [usize; 2], seed: u64, size: [f64; 2], perm: u64) -> Cantilever {
    let base = irregular_sheet(n[0], n[1], seed).unwrap();
    let scaled = TriMesh::new(
        base.positions()
            .iter()
            .map(|p| Vector3::new(size[0] * p.x, size[1] * p.y, 0.0))
            .collect(),
        base.triangles().to_vec(),
    )
    .unwrap();
    let perm = random_permutation(scaled.n_vertices(), perm);
    let spacing = size[0] / (n[0] - 1) as f64;
    cantilever(renumber(&scaled, &perm).unwrap(), spacing, 2e8)
}

/// The irregular renumbered sheet 0.3 m × 0.1 m clamped at x = 0 (8 × 4 vertices) of Poisson ratio
/// `poisson`.
fn irregular_cantilever(poisson: f64) -> Cantilever {
    Cantilever {
        poisson,
        ..sheet_cantilever([8, 4], 21, [0.3, 0.1], 9)
    }
}

/// The cantilever's system with its bending stiffness from the plate formula at its Poisson ratio, and
/// the StVK membrane or (`corotational`) the co-rotational one built from the material.
fn poisson_system(c: &Cantilever, corotational: bool) -> System {
    if !corotational {
        return cantilever_system(c, false);
    }
    let k = plate_consistent_stiffness(c.young, c.thickness, c.poisson);
    let psi = RuntimePsi::new("k * a * (theta - theta_bar).powi(2)", [("k", k.into())]).unwrap();
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&c.rest, psi).unwrap(),
            Method::Refactored,
        )),
        Box::new(
            CorotationalMembrane::from_material(&c.rest, c.young, c.poisson, c.thickness).unwrap(),
        ),
        Box::new(
            Gravity::new(
                lumped_masses(&c.rest, 1000.0 * c.thickness),
                Vector3::new(0.0, 0.0, -9.81),
            )
            .unwrap(),
        ),
    ];
    System::new(c.rest.n_vertices(), terms).unwrap()
}

/// The fit variable of Poisson's ratio as `hinge fit`'s `material.poisson` links it: the plate stiffness
/// `∝ 1/(1 − ν²)`, and the StVK membrane's ν or the co-rotational stiffness `∝ 1/(1 + ν)`; bounded to
/// the membranes' interval.
fn poisson_variable(start: f64, corotational: bool) -> FitVariable {
    FitVariable {
        name: "material.poisson".into(),
        start: vec![start],
        positive: false,
        range: Some(hinge_energies::membrane::POISSON_BOUNDS),
        links: vec![
            Link::Quadratic {
                parameter: "bending.k".into(),
                coefficients: [1.0, 0.0, -1.0],
                exponent: -1.0,
            },
            if corotational {
                Link::Quadratic {
                    parameter: "corotational-membrane.stiffness".into(),
                    coefficients: [1.0, 1.0, 0.0],
                    exponent: -1.0,
                }
            } else {
                Link::Value {
                    parameter: "membrane.poisson".into(),
                }
            },
        ],
    }
}

#[test]
fn a_bounded_variable_s_gradient_through_quadratic_and_value_links_matches_rebuilt_systems() {
    // dL/dν of the fit (logistic variable, quadratic and value links, chain rule) against central
    // differences of equilibria of systems rebuilt from the material at ν ± h (the stiffnesses from their
    // formulas, nothing from the fit), on the irregular renumbered cantilever, with either membrane.
    let mut worst = 0.0f64;
    for corotational in [false, true] {
        for nu in [0.3, -0.6, 0.45] {
            let c = irregular_cantilever(nu);
            let mut system = poisson_system(&c, corotational);
            let (mut newton, x, loss) = equilibrium_and_moved_target(&c, &mut system);
            let before: Vec<Vec<f64>> = system
                .parameters()
                .iter()
                .map(|p| system.parameter(&p.name).unwrap())
                .collect();
            let mut y = x.clone();
            let mut fit = Fit::new(
                &system,
                &c.pins,
                &mut newton,
                vec![poisson_variable(nu, corotational)],
                FitOptions::default(),
            )
            .unwrap();
            let (l, g) = fit
                .loss_and_gradient(&mut system, &mut y, &mut |x, g| loss.evaluate(x, g))
                .unwrap();
            drop(fit);
            // The system holds the start values again, bitwise.
            let after: Vec<Vec<f64>> = system
                .parameters()
                .iter()
                .map(|p| system.parameter(&p.name).unwrap())
                .collect();
            assert_eq!(before, after);
            assert_eq!(l, loss.evaluate(&y, &mut vec![0.0; 3 * y.len()]).unwrap());
            let mut solved = |v: f64| {
                let mut s = poisson_system(&irregular_cantilever(v), corotational);
                let mut yv = x.clone();
                newton.minimize(&mut s, &mut yv, None).unwrap();
                loss.evaluate(&yv, &mut vec![0.0; 3 * yv.len()]).unwrap()
            };
            let fd = richardson(&mut |h| solved(nu + h), 1e-3);
            let err = (fd - g[0]).abs() / fd.abs().max(g[0].abs());
            println!(
                "dL/dnu at {nu} ({}): fit {:.6e}, central differences {fd:.6e}, relative {err:.1e}",
                if corotational {
                    "co-rotational"
                } else {
                    "StVK"
                },
                g[0]
            );
            assert!(g[0] != 0.0);
            worst = worst.max(err);
        }
    }
    assert!(worst < 1e-6, "{worst:.2e}");
}

#[test]
fn fitting_recovers_poisson_s_ratio_inside_its_bounds() {
    // Truth ν = 0.3 on the irregular renumbered cantilever. The bending stiffness depends on ν², so the
    // shape determines |ν| through bending and its sign only through the membrane's small part: a start
    // on the truth's side recovers it, from 0.15 (where the loss is concave in ν: a first step as large as
    // the gradient barely moves) and from the upper bound's edge, and every accepted value stays inside
    // (−1, 0.5).
    let truth = irregular_cantilever(0.3);
    for corotational in [false, true] {
        let mut truth_system = poisson_system(&truth, corotational);
        let mut target = truth.rest.positions().to_vec();
        tight_newton(&truth_system, &truth.pins)
            .minimize(&mut truth_system, &mut target, None)
            .unwrap();
        for start in [0.15, 0.499] {
            let c = irregular_cantilever(start);
            let mut system = poisson_system(&c, corotational);
            let mut newton = tight_newton(&system, &c.pins);
            let seen = std::cell::RefCell::new(Vec::new());
            let loss = TargetLoss::all(target.clone());
            let mut x = c.rest.positions().to_vec();
            let mut fit = Fit::new(
                &system,
                &c.pins,
                &mut newton,
                vec![poisson_variable(start, corotational)],
                FitOptions {
                    max_iterations: 100,
                    ..FitOptions::default()
                },
            )
            .unwrap();
            fit.observe(|p| seen.borrow_mut().push(p.values[0][0]));
            let r = fit
                .run(&mut system, &mut x, &mut |x, g| loss.evaluate(x, g))
                .unwrap();
            drop(fit);
            println!(
                "Poisson ratio from {start} ({}): {:.9} in {} iterations, {} equilibria, loss {:.2e} → {:.2e} ({})",
                if corotational {
                    "co-rotational"
                } else {
                    "StVK"
                },
                r.values[0][0],
                r.iterations,
                r.equilibria,
                r.initial_loss,
                r.loss,
                r.stop
            );
            assert!((r.values[0][0] - 0.3).abs() < 1e-4, "{:?}", r.values);
            assert!(
                r.loss < 1e-10 * r.initial_loss,
                "{} {}",
                r.loss,
                r.initial_loss
            );
            assert!(seen.borrow().iter().all(|&v| v > -1.0 && v < 0.5));
            if !corotational {
                assert_eq!(system.parameter("membrane.poisson").unwrap(), r.values[0]);
            }
        }
    }
}

#[test]
fn bad_ranges_and_quadratic_links_are_refused_at_set_up() {
    let c = irregular_cantilever(0.3);
    let system = poisson_system(&c, false);
    let mut newton = tight_newton(&system, &c.pins);
    let cases: Vec<(FitVariable, &str)> = vec![
        (
            FitVariable {
                positive: true,
                ..poisson_variable(0.3, false)
            },
            "must not also be positive",
        ),
        (
            FitVariable {
                range: Some((0.5, -1.0)),
                ..poisson_variable(0.3, false)
            },
            "range (0.5, -1)",
        ),
        (
            FitVariable {
                range: Some((-1.0, f64::INFINITY)),
                ..poisson_variable(0.3, false)
            },
            "must have finite ends",
        ),
        (
            poisson_variable(0.5, false),
            "start value 0.5 must be finite and in (-1, 0.5)",
        ),
        (
            poisson_variable(-1.0, false),
            "start value -1 must be finite and in (-1, 0.5)",
        ),
        (
            FitVariable {
                range: None,
                ..poisson_variable(2.0, false)
            },
            "the quadratic link to `bending.k` is -3 at the start, not positive",
        ),
        (
            FitVariable {
                links: vec![Link::Quadratic {
                    parameter: "bending.k".into(),
                    coefficients: [1.0, 0.0, -1.0],
                    exponent: f64::NAN,
                }],
                ..poisson_variable(0.3, false)
            },
            "has exponent NaN, not finite",
        ),
    ];
    for (variable, needle) in cases {
        let err = Fit::new(
            &system,
            &c.pins,
            &mut newton,
            vec![variable],
            FitOptions::default(),
        )
        .unwrap_err();
        assert!(matches!(err, AdjointError::Setup(_)), "{err}");
        assert!(err.to_string().contains(needle), "{err} / {needle}");
        assert!(err.to_string().contains("material.poisson"), "{err}");
    }
    // The system reports the interval of its membrane's ν, and of no other parameter.
    assert_eq!(
        system.parameter_bounds("membrane.poisson").unwrap(),
        Some((-1.0, 0.5))
    );
    assert_eq!(system.parameter_bounds("membrane.young").unwrap(), None);
    assert_eq!(system.parameter_bounds("bending.k").unwrap(), None);
    assert!(system.parameter_bounds("membrane.nu").is_err());
}

/// The number of eigenvalues at or above `tol` of the correlation matrix of the non-zero columns `cols`,
/// and the number of zero columns.
fn correlation_rank(cols: &[Vec<f64>], tol: f64) -> (usize, usize) {
    let unit: Vec<Vec<f64>> = cols
        .iter()
        .filter_map(|c| {
            let n = c.iter().map(|v| v * v).sum::<f64>().sqrt();
            (n > 0.0).then(|| c.iter().map(|v| v / n).collect())
        })
        .collect();
    let m = unit.len();
    let g = hinge_core::nalgebra::DMatrix::from_fn(m, m, |i, j| {
        unit[i]
            .iter()
            .zip(&unit[j])
            .map(|(a, b)| a * b)
            .sum::<f64>()
    });
    let rank = g
        .symmetric_eigenvalues()
        .iter()
        .filter(|&&e| e >= tol)
        .count();
    (rank, cols.len() - m)
}

#[test]
fn a_field_check_counts_the_values_a_static_shape_determines() {
    // The rest angles of the irregular renumbered clamped sheet (130 hinges, 49 free vertices): at its
    // near-flat equilibrium a rest angle moves the sheet through the out-of-plane dofs only, so the shape
    // determines 49 combinations; hinges with all four vertices pinned move nothing. The fit's count (from
    // adjoint sensitivities) against the same count from central differences of re-solved equilibria, and
    // against the topology (hinges inside the clamp) and the free-vertex count.
    let c = sheet_cantilever([9, 7], 31, [0.2, 0.15], 77);
    let mut system = cantilever_system(&c, false);
    let hinges = hinge_core::topology::hinges(&c.rest).unwrap();
    let m = hinges.len();
    let pinned_hinges = hinges
        .iter()
        .filter(|h| h.vertices.iter().all(|&v| c.pins.contains(v)))
        .count();
    let free = c.rest.n_vertices() - c.pins.vertices().len();
    let mut newton = tight_newton(&system, &c.pins);
    let mut x = c.rest.positions().to_vec();
    newton.minimize(&mut system, &mut x, None).unwrap();
    let loss = TargetLoss::all(x.clone());
    let variable = FitVariable {
        name: "bending.rest_angles".into(),
        start: vec![0.0; m],
        positive: false,
        range: None,
        links: vec![Link::Value {
            parameter: "bending.theta_bar".into(),
        }],
    };
    let options = FitOptions {
        max_iterations: 0,
        ..FitOptions::default()
    };
    let mut fit = Fit::new(
        &system,
        &c.pins,
        &mut newton,
        vec![variable.clone()],
        options.clone(),
    )
    .unwrap();
    let r = fit
        .run(&mut system, &mut x.clone(), &mut |x, g| loss.evaluate(x, g))
        .unwrap();
    drop(fit);
    assert_eq!(r.fields.len(), 1);
    let rank = r.fields[0].rank.unwrap();
    // Central differences of the equilibrium in each rest angle.
    let h = 1e-4;
    let cols: Vec<Vec<f64>> = (0..m)
        .map(|i| {
            let mut solved = |delta: f64| {
                let mut t = vec![0.0; m];
                t[i] = delta;
                system.set_parameter("bending.theta_bar", &t).unwrap();
                let mut y = x.clone();
                newton.minimize(&mut system, &mut y, None).unwrap();
                y
            };
            let (a, b) = (solved(h), solved(-h));
            a.iter()
                .zip(&b)
                .flat_map(|(p, q)| ((p - q) / (2.0 * h)).iter().copied().collect::<Vec<_>>())
                .collect()
        })
        .collect();
    system
        .set_parameter("bending.theta_bar", &vec![0.0; m])
        .unwrap();
    let (fd_rank, fd_zero) = correlation_rank(&cols, options.identifiability_tolerance);
    println!(
        "rest angles of {m} hinges, {free} free vertices, {pinned_hinges} hinges inside the clamp: the fit \
         counts {} determined and {} without effect; central differences {fd_rank} and {fd_zero}",
        rank.determined, rank.without_effect
    );
    assert_eq!(rank.without_effect, pinned_hinges);
    assert_eq!(rank.determined, free);
    assert_eq!((fd_rank, fd_zero), (rank.determined, rank.without_effect));
    assert_eq!(r.fields[0].entries, m);
    // A tolerance of 0 checks nothing; a scalar variable is not a field.
    let mut fit = Fit::new(
        &system,
        &c.pins,
        &mut newton,
        vec![variable.clone()],
        FitOptions {
            identifiability_tolerance: 0.0,
            ..options.clone()
        },
    )
    .unwrap();
    let r = fit
        .run(&mut system, &mut x.clone(), &mut |x, g| loss.evaluate(x, g))
        .unwrap();
    drop(fit);
    assert_eq!(r.fields[0].rank, None);
    let mut fit = Fit::new(
        &system,
        &c.pins,
        &mut newton,
        vec![FitVariable {
            name: "uniform rest angle".into(),
            start: vec![0.0],
            ..variable
        }],
        options,
    )
    .unwrap();
    let r = fit
        .run(&mut system, &mut x, &mut |x, g| loss.evaluate(x, g))
        .unwrap();
    assert!(r.fields.is_empty());
}
