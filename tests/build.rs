//! Generates `random_energies.rs`: seeded random ψ expressions drawn from the derive macro's grammar, each
//! declared with `#[derive(HingeEnergy)]`, so the macro is exercised on expressions nobody hand-picked.
//! Every construct is kept well-defined for θ ∈ [−2.5, 2.5] (denominators and logarithm/sqrt arguments
//! bounded away from zero, tan arguments bounded away from its poles).

use std::fmt::Write;

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // SplitMix64 step (the generator the tests use too).
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

const LEAVES: [&str; 9] = [
    "theta",
    "theta",
    "theta",
    "theta_bar",
    "a",
    "c0",
    "c1",
    "1.5",
    "2",
];

fn random_expr(rng: &mut Rng, depth: u32) -> String {
    if depth == 0 {
        return LEAVES[rng.below(LEAVES.len() as u64) as usize].to_string();
    }
    let pick = rng.below(16);
    let mut e = || random_expr(rng, depth - 1);
    match pick {
        0 => format!("({} + {})", e(), e()),
        1 => format!("({} - {})", e(), e()),
        2 => format!("({} * {})", e(), e()),
        3 => format!("({} / (2.0 + ({}).sin()))", e(), e()),
        4 => format!("({}).sin()", e()),
        5 => format!("({}).cos()", e()),
        6 => format!("({}).atan()", e()),
        7 => format!("({}).tanh()", e()),
        8 => format!("(0.3 * ({}).sin()).tan()", e()),
        9 => format!("(0.5 * ({}).sin()).exp()", e()),
        10 => format!("(1.0 + ({}).powi(2)).sqrt()", e()),
        11 => format!("(1.0 + ({}).powi(2)).ln()", e()),
        12 => format!("({}).powi(3)", e()),
        13 => format!("(1.5 + ({}).cos()).powf(c0)", e()),
        14 => format!("{{ let u = {}; u * ({}) + u }}", e(), e()),
        _ => format!("-({})", e()),
    }
}

/// The whole grammar (issue 16): every function in both spellings, `abs`/`min`/`max`, `if`, `pow`, the
/// constants, `atan2` of θ-free values. Arguments stay where every construct is defined.
fn random_full(rng: &mut Rng, depth: u32) -> String {
    if depth == 0 {
        return LEAVES[rng.below(LEAVES.len() as u64) as usize].to_string();
    }
    let pick = rng.below(26);
    let mut e = || random_full(rng, depth - 1);
    match pick {
        0 => format!("({} + {})", e(), e()),
        1 => format!("({} - {})", e(), e()),
        2 => format!("({} * {})", e(), e()),
        3 => format!("({} / (2.0 + sin({})))", e(), e()),
        4 => format!("sin({})", e()),
        5 => format!("cos({})", e()),
        6 => format!("atan({})", e()),
        7 => format!("tanh({})", e()),
        8 => format!("tan(0.3 * sin({}))", e()),
        9 => format!("exp(0.5 * ({}).sin())", e()),
        10 => format!("sqrt(1.0 + pow({}, 2))", e()),
        11 => format!("ln(1.0 + powi({}, 2))", e()),
        12 => format!("pow({}, 3)", e()),
        13 => format!("powf(1.5 + cos({}), c0)", e()),
        14 => format!("{{ let u = {}; u * ({}) + u }}", e(), e()),
        15 => format!("abs({})", e()),
        16 => format!("({}).abs()", e()),
        17 => format!("min({}, {})", e(), e()),
        18 => format!("({}).max({})", e(), e()),
        19 => format!("sinh(0.5 * sin({}))", e()),
        20 => format!("(0.5 * cos({})).cosh()", e()),
        21 => format!("if {} < {} {{ {} }} else {{ {} }}", e(), e(), e(), e()),
        22 => format!(
            "if {} >= 0.25 {{ {} }} else if {} <= -0.5 {{ {} }} else {{ {} }}",
            e(),
            e(),
            e(),
            e(),
            e()
        ),
        23 => format!("(PI * {} + std::f64::consts::E)", e()),
        24 => format!("(atan2(theta_bar, a + c1) * {})", e()),
        _ => format!("-({})", e()),
    }
}

fn main() {
    let mut rng = Rng(0x5EED_F00D);
    let mut out = String::new();
    let n = 24;
    let mut calls = String::new();
    for i in 0..n {
        // Make sure θ occurs: wrap the random expression with a θ term.
        let body = random_expr(&mut rng, 3);
        let expr = format!("c0 * ({body}) + c1 * (theta - theta_bar).sin()");
        let _ = writeln!(
            out,
            "/// Random energy {i}.\n#[derive(hinge_core::HingeEnergy)]\n#[psi({expr})]\npub struct Random{i} {{\n    /// Constant.\n    pub c0: f64,\n    /// Constant.\n    pub c1: f64,\n}}\n"
        );
        let _ = writeln!(
            calls,
            "    (r#\"{expr}\"#, check(&Random{i} {{ c0: 0.8, c1: 1.3 }}, -2.5, 2.5, {i})),"
        );
    }
    let _ = writeln!(
        out,
        "/// Every random energy with its expression and measured error.\npub fn random_cases() -> Vec<(&'static str, f64)> {{\n    vec![\n{calls}    ]\n}}"
    );
    let dir = std::env::var("OUT_DIR").unwrap_or_else(|_| ".".into());
    let path = std::path::Path::new(&dir).join("random_energies.rs");
    if let Err(e) = std::fs::write(&path, out) {
        println!("cargo::error=cannot write {}: {e}", path.display());
    }
    // The same 24 expressions plus 24 of the whole grammar, each derived, for the run-time ψ tests: a
    // table of (expression text, derived evaluation).
    let mut rng = Rng(0x5EED_F00D);
    let mut exprs = Vec::new();
    for _ in 0..n {
        let body = random_expr(&mut rng, 3);
        exprs.push(format!("c0 * ({body}) + c1 * (theta - theta_bar).sin()"));
    }
    let mut rng = Rng(0xF011_6A33);
    for _ in 0..n {
        let body = random_full(&mut rng, 3);
        exprs.push(format!("c0 * ({body}) + c1 * sin(theta - theta_bar)"));
    }
    let mut out = String::new();
    let mut table = String::new();
    for (i, expr) in exprs.iter().enumerate() {
        let _ = writeln!(
            out,
            "/// Random energy {i}.\n#[derive(hinge_core::HingeEnergy)]\n#[psi({expr})]\npub struct Pair{i} {{\n    /// Constant.\n    pub c0: f64,\n    /// Constant.\n    pub c1: f64,\n}}\n\nfn derived{i}(c: [f64; 2], q: &HingeQuantities, theta: f64) -> [f64; 6] {{\n    let e = Pair{i} {{ c0: c[0], c1: c[1] }};\n    let p = e.params(q);\n    let [a, b, d] = e.eval(&p, theta);\n    let [f, g] = e.eval_d1(&p, theta);\n    [a, b, d, e.value(&p, theta), f, g]\n}}\n"
        );
        let _ = writeln!(table, "        (r#\"{expr}\"#, derived{i}),");
    }
    let _ = writeln!(
        out,
        "/// (expression, derived [ψ, ψ′, ψ″, value(), eval_d1()[0], eval_d1()[1]]) for parameters (c0, c1).\npub type Derived = fn([f64; 2], &HingeQuantities, f64) -> [f64; 6];\n\n/// Every pair; the first {n} use the original grammar, the rest the whole grammar.\npub fn pairs() -> Vec<(&'static str, Derived)> {{\n    vec![\n{table}    ]\n}}"
    );
    let path = std::path::Path::new(&dir).join("random_pairs.rs");
    if let Err(e) = std::fs::write(&path, out) {
        println!("cargo::error=cannot write {}: {e}", path.display());
    }
    println!("cargo::rerun-if-changed=build.rs");
}
