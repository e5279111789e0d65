//! The compiled programs of the built-in energies: their size, and that they compute what the expression
//! says (against direct f64 evaluation of the formulas).

use hinge_symbolic::{Tape, compile};

fn tape(expr: &str, inputs: &[&str]) -> Tape {
    let names: Vec<String> = inputs.iter().map(|s| s.to_string()).collect();
    let src = compile(expr, &names).expect("compiles");
    Tape::new(&src.compiled, 4).expect("tape")
}

#[test]
fn tan_bending_program_is_small_and_right() {
    let t = tape(
        "k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2)",
        &["k"],
    );
    println!(
        "tan bending: {} hoisted, programs {} / {} / {} instructions, params {}",
        t.n_params,
        t.value.len(),
        t.first.len(),
        t.full.len(),
        t.params.len()
    );
    println!("{:#?}", t.full);
    assert!(t.full.len() <= 18, "{}", t.full.len());
    // vars: k, then theta_bar, a, rest_length, rest_area, theta_prev, dt.
    let (k, tb, a) = (1.3, 0.4, 2.0);
    let mut p = [0.0; 4];
    t.params
        .run(&[k, tb, a, 1.0, 1.0, 0.0, 1.0], &mut p[..t.n_params]);
    for theta in [-2.0, -0.3, 0.0, 0.7, 2.5] {
        let mut out = [0.0; 3];
        t.full.run_theta(theta, &p, &mut out);
        let (phi, phib) = (2.0 * (theta / 2.0_f64).tan(), 2.0 * (tb / 2.0_f64).tan());
        let sec2 = 1.0 + (theta / 2.0_f64).tan().powi(2);
        let want = [
            k * a * (phi - phib).powi(2),
            2.0 * k * a * (phi - phib) * sec2,
            2.0 * k * a * (sec2 * sec2 + (phi - phib) * sec2 * (theta / 2.0_f64).tan()),
        ];
        for (g, w) in out.iter().zip(want) {
            assert!(
                (g - w).abs() <= 1e-12 * w.abs().max(1.0),
                "{theta}: {out:?} vs {want:?}"
            );
        }
    }
}

#[test]
fn parse_errors_carry_columns() {
    let e = compile("k * (theta +* 2)", &["k".into()]).expect_err("bad");
    assert_eq!(e.diagnostics[0].span.column(), 13);
    let e = compile("theta.sinn() + tehta", &[]).expect_err("bad");
    assert_eq!(e.diagnostics.len(), 2);
    assert!(e.show_supported);
    assert!(e.to_string().contains("did you mean `sin`"), "{e}");
}

#[test]
fn fused_instructions_compute_both_operations_bitwise() {
    // Every pair of binary operations, with the first result on either side of the second: the program
    // fuses them (fewer instructions than operations) and computes exactly the two f64 operations.
    type Binary = fn(f64, f64) -> f64;
    let ops: [(&str, Binary); 4] = [
        ("+", |x, y| x + y),
        ("-", |x, y| x - y),
        ("*", |x, y| x * y),
        ("/", |x, y| x / y),
    ];
    let mut fused = 0;
    for (o1, f1) in ops {
        for (o2, f2) in ops {
            for left in [true, false] {
                // θ-dependent operands, so nothing is hoisted or folded: (θ o1 u) o2 v with u, v of θ.
                let inner = format!("(theta {o1} theta.sin())");
                let expr = if left {
                    format!("{inner} {o2} theta.cos()")
                } else {
                    format!("theta.cos() {o2} {inner}")
                };
                let t = tape(&expr, &[]);
                let p = [0.0; 4];
                for theta in [-2.3, -0.4, 0.3, 1.7] {
                    let mut out = [0.0];
                    t.value.run_theta(theta, &p, &mut out);
                    let a = f1(theta, theta.sin());
                    let want = if left {
                        f2(a, theta.cos())
                    } else {
                        f2(theta.cos(), a)
                    };
                    assert_eq!(out[0].to_bits(), want.to_bits(), "{expr} at {theta}");
                }
                // sin, cos, and one fused instruction for the two operations.
                if t.value.len() == 3 {
                    fused += 1;
                } else {
                    println!("{expr}: {:?}", t.value);
                }
            }
        }
    }
    assert_eq!(fused, 32, "every pair fuses");
}
