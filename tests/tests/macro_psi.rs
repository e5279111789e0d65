//! The derive macro: ψ′ and ψ″ from the symbolic engine against num-dual for the built-in energies and for
//! seeded random expressions; macro-declared energies against the hand-written ones through the assembly;
//! per-hinge fields, step quantities and the autodiff escape hatch.

use hinge_core::HingeEnergy;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::grid::unit_grid;
use hinge_core::psi::handwritten::{self, Stiffness};
use hinge_core::psi::{DiscreteShells, HingePsi, HingeQuantities, TanBending};
use hinge_tests::*;
use num_dual::{DualNum, second_derivative};

fn quantities(rng: &mut SplitMix64, hinge: usize) -> HingeQuantities {
    random_quantities(rng, hinge)
}

/// Max relative error of ψ, ψ′, ψ″ against num-dual's `second_derivative` of `psi_dual`, over 1000 θ in
/// [lo, hi] (each error relative to the largest of |ψ|, |ψ′|, |ψ″| there).
fn check<P: HingePsi>(psi: &P, lo: f64, hi: f64, seed: u64) -> f64 {
    let mut rng = SplitMix64(seed);
    let mut worst: f64 = 0.0;
    for i in 0..1000 {
        let q = quantities(&mut rng, i % 7);
        let p = psi.params(&q);
        let theta = rng.range(lo, hi);
        let [f, d1, d2] = psi.eval(&p, theta);
        let (rf, r1, r2) = second_derivative(|t| psi.psi_dual(&p, t), theta);
        let scale = rf.abs().max(r1.abs()).max(r2.abs()).max(f64::MIN_POSITIVE);
        for (x, r) in [(f, rf), (d1, r1), (d2, r2)] {
            worst = worst.max((x - r).abs() / scale);
        }
    }
    worst
}

mod random {
    use super::check;
    include!(concat!(env!("OUT_DIR"), "/random_energies.rs"));
}

#[test]
fn builtin_energies_match_num_dual() {
    let e = check(&DiscreteShells { k: 1.7 }, -3.1, 3.1, 1);
    println!("discrete shells: {e:.3e}");
    assert!(e <= 1e-15);
    let e = check(&TanBending { k: 0.7 }, -3.0, 3.0, 2);
    println!("tan bending: {e:.3e}");
    assert!(e <= 1e-14);
    const { assert!(!DiscreteShells::D2_IS_ZERO && !DiscreteShells::USES_STEP) };
    // The rest of the bending family (hinge-energies), declared with the same macro.
    use hinge_energies::bending::{Bridson, ViscousDamping, Willmore};
    for (name, e) in [
        ("willmore", check(&Willmore { k: 0.8 }, -3.1, 3.1, 3)),
        ("bridson", check(&Bridson { k: 1.2 }, -3.1, 3.1, 4)),
        (
            "viscous damping",
            check(&ViscousDamping { kd: 0.4 }, -3.0, 3.0, 6),
        ),
    ] {
        println!("{name}: {e:.3e}");
        assert!(e <= 1e-14, "{name}: {e}");
    }
}

/// Measured: the worst of 24 random expressions is printed with `--nocapture`; the bound is 1e-13.
#[test]
fn random_expressions_match_num_dual() {
    let cases = random::random_cases();
    assert!(cases.len() >= 20);
    let mut worst: f64 = 0.0;
    for (expr, err) in &cases {
        println!("{err:.2e}  {expr}");
        assert!(*err <= 1e-13, "{expr}: {err}");
        worst = worst.max(*err);
    }
    println!(
        "worst over {} random expressions × 1000 θ: {worst:.3e}",
        cases.len()
    );
}

#[test]
fn macro_discrete_shells_is_identical_to_hand_written_through_assembly() {
    let rest = unit_grid(16).unwrap();
    let def = reference_jitter(rest.positions());
    let m = BendingModel::new(&rest, DiscreteShells { k: 1.3 }).unwrap();
    let h = BendingModel::new(
        &rest,
        handwritten::DiscreteShells {
            k: Stiffness::Uniform(1.3),
        },
    )
    .unwrap();
    for method in [Method::Refactored, Method::PerHinge] {
        let a = m
            .evaluate(&def, Request::ALL, method, Parallelism::Sequential)
            .unwrap();
        let b = h
            .evaluate(&def, Request::ALL, method, Parallelism::Sequential)
            .unwrap();
        assert_eq!(a, b, "{method:?}");
    }
    // Tan bending: the macro's algebra differs from the hand-written one, so compare to rounding.
    let m = BendingModel::new(&rest, TanBending { k: 0.9 }).unwrap();
    let h = BendingModel::new(
        &rest,
        handwritten::TanBending {
            k: Stiffness::Uniform(0.9),
        },
    )
    .unwrap();
    let a = m
        .evaluate(
            &def,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    let b = h
        .evaluate(
            &def,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    assert!(((a.energy - b.energy) / b.energy).abs() < 1e-14);
    assert!(rel_error(&a.gradient, &b.gradient) < 1e-14);
    assert!(rel_error(&a.hessian, &b.hessian) < 1e-14);
}

/// Graded stiffness: one value per hinge.
#[derive(Debug, HingeEnergy)]
#[psi(k * a * (theta - theta_bar).powi(2))]
pub struct Graded {
    /// Stiffness per hinge.
    #[per_hinge]
    pub k: Vec<f64>,
}

#[test]
fn per_hinge_fields_are_indexed_and_validated() {
    let rest = unit_grid(6).unwrap();
    let def = reference_jitter(rest.positions());
    let n = hinge_core::Topology::new(rest.n_vertices(), rest.triangles())
        .unwrap()
        .hinges()
        .len();
    let ks: Vec<f64> = (0..n).map(|i| 0.5 + (i % 5) as f64).collect();
    let g = BendingModel::new(&rest, Graded { k: ks.clone() }).unwrap();
    let h = BendingModel::new(
        &rest,
        handwritten::DiscreteShells {
            k: Stiffness::PerHinge(ks.clone()),
        },
    )
    .unwrap();
    let a = g
        .evaluate(
            &def,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    let b = h
        .evaluate(
            &def,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    assert_eq!(a, b);
    let err = BendingModel::new(
        &rest,
        Graded {
            k: ks[1..].to_vec(),
        },
    )
    .unwrap_err();
    assert!(err.to_string().contains("parameter `k`"), "{err}");
    let mut bad = ks;
    bad[3] = f64::NAN;
    let err = BendingModel::new(&rest, Graded { k: bad }).unwrap_err();
    assert!(err.to_string().contains("hinge 3"), "{err}");
}

/// Viscous damping as the paper writes it, with the step quantities θ̂ (`theta_prev`) and Δt.
#[derive(HingeEnergy)]
#[psi(kd / dt * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_prev / 2.0).tan()).powi(2))]
pub struct Damping {
    /// Damping coefficient.
    pub kd: f64,
}

#[test]
fn step_quantities_refresh_per_step() {
    const { assert!(Damping::USES_STEP) };
    let e = check(&Damping { kd: 0.3 }, -3.0, 3.0, 5);
    assert!(e <= 1e-14, "{e}");
    let rest = unit_grid(5).unwrap();
    let def = reference_jitter(rest.positions());
    let mut m = BendingModel::new(&rest, Damping { kd: 0.3 }).unwrap();
    // Before a step θ_prev = θ̄: some energy at the deformed state. With θ_prev taken at the deformed state
    // itself, the damping energy there is exactly zero.
    let before = m
        .evaluate(
            &def,
            Request::VALUE,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    assert!(before.energy > 0.0);
    m.set_step(&def, 0.01).unwrap();
    let after = m
        .evaluate(
            &def,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    assert_eq!(after.energy, 0.0);
    assert!(after.gradient.iter().all(|&g| g == 0.0));
    assert!(m.set_step(&def, 0.0).is_err());
    assert!(m.set_step(&def, f64::NAN).is_err());
}

/// The escape hatch: ψ written by hand, generic over num-dual; ψ′ and ψ″ by num-dual.
#[derive(HingeEnergy)]
#[psi(autodiff)]
pub struct ByHand {
    /// Stiffness.
    pub k: f64,
}

impl ByHand {
    fn psi<D: DualNum<Primitive = f64> + Copy>(&self, q: &HingeQuantities, theta: D) -> D {
        let d = theta - q.theta_bar;
        d * d * (self.k * q.a)
    }
}

#[test]
fn autodiff_escape_hatch_matches_the_symbolic_derivation() {
    let mut rng = SplitMix64(11);
    let (a, b) = (ByHand { k: 1.1 }, DiscreteShells { k: 1.1 });
    for i in 0..1000 {
        let q = quantities(&mut rng, i);
        let theta = rng.range(-3.0, 3.0);
        let x = a.eval(&a.params(&q), theta);
        let y = b.eval(&b.params(&q), theta);
        for j in 0..3 {
            assert!((x[j] - y[j]).abs() <= 1e-14 * y[0].abs().max(y[1].abs()).max(y[2].abs()));
        }
    }
}
