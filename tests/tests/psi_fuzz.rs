//! Generated ψ strings: the parser, the compiler and every evaluation method either succeed with finite
//! outputs or return an error — never a panic and never a silent NaN or infinity.

use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::psi::runtime::RuntimePsi;
use hinge_core::shapes;
use hinge_tests::*;

const ATOMS: &[&str] = &[
    "theta",
    "theta_bar",
    "a",
    "k",
    "dt",
    "theta_prev",
    "rest_length",
    "rest_area",
    "PI",
    "E",
    "0.0",
    "1.0",
    "2.5",
    "1e308",
    "1e-320",
    "3.0",
    "1e-300",
    "0.5",
];
const FUNCS: &[&str] = &[
    "sin", "cos", "tan", "exp", "ln", "sqrt", "abs", "sinh", "cosh", "tanh", "atan", "asin",
    "acos", "log", "cbrt", "exp_m1", "ln_1p", "recip", "asinh", "acosh", "atanh",
];

/// A random expression of the grammar (and some names it does not have) of at most `depth` levels.
fn expression(rng: &mut SplitMix64, depth: u32) -> String {
    let pick = |rng: &mut SplitMix64, n: usize| (rng.next_u64() % n as u64) as usize;
    if depth == 0 || rng.next_u64().is_multiple_of(4) {
        return ATOMS[pick(rng, ATOMS.len())].to_string();
    }
    let d = depth - 1;
    match pick(rng, 9) {
        0 => format!("-{}", expression(rng, d)),
        1 => {
            let op = ["+", "-", "*", "/"][pick(rng, 4)];
            format!("({} {op} {})", expression(rng, d), expression(rng, d))
        }
        2 | 3 => format!("{}({})", FUNCS[pick(rng, FUNCS.len())], expression(rng, d)),
        4 => {
            let n = [0, 1, 2, 3, -1, -2, 7, 100, -100][pick(rng, 9)];
            format!("({}).powi({n})", expression(rng, d))
        }
        5 => format!(
            "({}).powf({})",
            expression(rng, d),
            ATOMS[pick(rng, ATOMS.len())]
        ),
        6 => {
            let c = ["<", ">", "<=", ">="][pick(rng, 4)];
            let (l, r) = (expression(rng, d), expression(rng, d));
            let (a, b) = (expression(rng, d), expression(rng, d));
            format!("if {l} {c} {r} {{ {a} }} else {{ {b} }}")
        }
        7 => {
            let (v, w) = (expression(rng, d), expression(rng, d));
            format!("{{ let u = {v}; u * {w} }}")
        }
        _ => {
            let f = ["min", "max", "atan2"][pick(rng, 3)];
            let (v, w) = (expression(rng, d), expression(rng, d));
            format!("{f}({v}, {w})")
        }
    }
}

/// 4 000 seeded strings (a third of them with one character deleted or inserted) on a renumbered irregular
/// sheet bent at random: every string either fails to compile with a message, or gives a model whose three
/// methods either evaluate to finite energy, gradient and Hessian or return an error. (Found: a ψ finite
/// per hinge whose derivatives or sum overflow returned infinities; see
/// `overflowing_outputs_are_errors_naming_the_lowest_vertex`.)
#[test]
fn generated_psi_strings_compile_or_fail_and_never_evaluate_to_non_finite_values() {
    let mesh = shapes::renumber(
        &shapes::irregular_sheet(4, 4, 3).expect("mesh"),
        &shapes::random_permutation(16, 4),
    )
    .expect("renumbered");
    let mut rng = SplitMix64(12345);
    let (mut compiled, mut evaluated, mut failed) = (0, 0, 0);
    for case in 0..4000 {
        let depth = 1 + (rng.next_u64() % 5) as u32;
        let mut s = expression(&mut rng, depth);
        if !s.contains('k') || rng.next_u64().is_multiple_of(2) {
            s = format!("k * {s}");
        }
        if rng.next_u64().is_multiple_of(3) {
            let mut chars: Vec<char> = s.chars().collect();
            let i = (rng.next_u64() % chars.len() as u64) as usize;
            if rng.next_u64().is_multiple_of(2) {
                chars.remove(i);
            } else {
                let c = ['(', ')', 'θ', '.', ',', '{', '}', ';', 'é', '9']
                    [(rng.next_u64() % 10) as usize];
                chars.insert(i, c);
            }
            s = chars.into_iter().collect();
        }
        let psi = match RuntimePsi::new(&s, [("k", 1.5.into())]) {
            Ok(p) => p,
            Err(e) => {
                assert!(!e.to_string().is_empty(), "case {case}: `{s}`");
                continue;
            }
        };
        compiled += 1;
        let Ok(m) = BendingModel::new(&mesh, psi) else {
            continue;
        };
        let x: Vec<_> = mesh
            .positions()
            .iter()
            .map(|p| p + nalgebra::Vector3::new(0.0, 0.0, rng.range(-0.3, 0.3)))
            .collect();
        for method in Method::ALL {
            match m.evaluate(&x, Request::ALL, method, Parallelism::Sequential) {
                Ok(e) => {
                    evaluated += 1;
                    assert!(
                        e.energy.is_finite()
                            && e.gradient.iter().all(|v| v.is_finite())
                            && e.hessian.iter().all(|v| v.is_finite()),
                        "case {case}: non-finite output without an error for `{s}` ({method:?})"
                    );
                }
                Err(_) => failed += 1,
            }
        }
    }
    println!("compiled {compiled} of 4000, evaluated {evaluated}, errors {failed}");
    // The generator must reach the evaluation often enough for the test to mean something.
    assert!(
        compiled > 1000 && evaluated > 1000 && failed > 100,
        "{compiled} {evaluated} {failed}"
    );
}
