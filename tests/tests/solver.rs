//! The solver layer: linear backends, Newton (quadratic convergence, one step on a quadratic, inertia
//! correction), implicit Euler (energy never increases without damping) and failure handling.

use hinge_core::TriMesh;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::grid::{Diagonal, grid};
use hinge_core::nalgebra::{Matrix3, Vector3};
use hinge_energies::bending::{DiscreteShells, ViscousDamping};
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::pins::Pins;
use hinge_energies::quadratic::QuadraticBending;
use hinge_energies::spring::MassSpring;
use hinge_solver::linear::{
    ChebyshevJacobi, Dense, FaerLlt, FaerLu, LinearError, LinearSolver, PcgJacobi, default_solver,
};
use hinge_solver::newton::{
    ImplicitEuler, Inertia, Newton, NewtonParams, Reduced, SolverError, SubstepPolicy,
};
use hinge_tests::*;

fn cloth(n: usize) -> TriMesh {
    grid(n, n, 1.0, 1.0, Diagonal::Alternating).unwrap()
}

fn spring_system(rest: &TriMesh, with_bending: bool) -> System {
    let mut terms: Vec<Box<dyn Energy>> = vec![Box::new(MassSpring::new(rest, 200.0).unwrap())];
    if with_bending {
        let m = BendingModel::new(rest, DiscreteShells { k: 0.01 }).unwrap();
        terms.push(Box::new(HingeTerm::new("bending", m, Method::Refactored)));
    }
    System::new(rest.n_vertices(), terms).unwrap()
}

/// M/Δt² + H of a stretched spring network: symmetric positive definite.
fn spd_system() -> (Reduced, Vec<f64>) {
    spd_system_of(8, false)
}

/// A mass-spring (and bending) Hessian plus inertia on a `cells × cells` cloth (with bending, 40 cells
/// factor supernodally).
fn spd_system_of(cells: usize, with_bending: bool) -> (Reduced, Vec<f64>) {
    let rest = cloth(cells);
    let mut sys = spring_system(&rest, with_bending);
    let x: Vec<_> = rest.positions().iter().map(|p| p * 1.1).collect();
    let e = sys
        .evaluate(&x, Request::ALL, Parallelism::Sequential)
        .unwrap();
    let free = vec![true; 3 * rest.n_vertices()];
    let red = Reduced::new(sys.pattern(), &free);
    let mut vals: Vec<f64> = red.source.iter().map(|&k| e.hessian[k]).collect();
    for &d in &red.diag {
        vals[d] += 0.01 / (0.01 * 0.01) / 50.0;
    }
    (red, vals)
}

#[test]
fn backends_agree_on_spd_systems() {
    let (red, vals) = spd_system();
    let n = red.csc.n;
    let mut rng = SplitMix64(5);
    let b: Vec<f64> = (0..n).map(|_| rng.symmetric()).collect();
    let mut reference = b.clone();
    let mut dense = Dense::default();
    dense.analyze(&red.csc).unwrap();
    dense.factor(&vals).unwrap();
    dense.solve(&mut reference).unwrap();
    let mut backends: Vec<Box<dyn LinearSolver>> = vec![
        Box::new(FaerLlt::default()),
        Box::new(FaerLlt::parallel()),
        Box::new(FaerLu::default()),
        Box::new(PcgJacobi::new(1e-12, 10_000)),
        Box::new(ChebyshevJacobi::new(1e-12, 100_000)),
    ];
    for s in &mut backends {
        s.analyze(&red.csc).unwrap();
        s.factor(&vals).unwrap();
        let mut x = b.clone();
        s.solve(&mut x).unwrap();
        let err = rel_error(&x, &reference);
        println!("{}: relative difference to dense {err:.2e}", s.name());
        assert!(err < 1e-9, "{}: {err}", s.name());
        // Residual check independent of the oracle.
        let mut ax = vec![0.0; n];
        red.csc.mul(&vals, &x, &mut ax);
        assert!(rel_error(&ax, &b) < 1e-10);
    }
}

/// Every backend refuses, with [`LinearError::Usage`] and without panicking, a solve before a factorization,
/// a factorization before an analysis, values and right-hand sides of the wrong length, and a solve after a
/// refused or failed factorization (no older one is used); and solves correctly afterwards.
#[test]
fn every_backend_refuses_misuse_and_wrong_lengths_with_a_usage_error() {
    let (red, vals) = spd_system();
    let n = red.csc.n;
    let backends: Vec<fn() -> Box<dyn LinearSolver>> = vec![
        || Box::new(FaerLlt::default()),
        || Box::new(FaerLu::default()),
        || Box::new(PcgJacobi::new(1e-12, 10_000)),
        || Box::new(ChebyshevJacobi::new(1e-12, 100_000)),
        || Box::new(Dense::default()),
    ];
    let usage = |r: Result<(), LinearError>| matches!(r, Err(LinearError::Usage(_)));
    for make in backends {
        let mut s = make();
        let name = s.name();
        assert!(usage(s.factor(&vals)), "{name}: factor before analyze");
        assert!(
            usage(s.solve(&mut vec![1.0; n])),
            "{name}: solve before analyze"
        );
        s.analyze(&red.csc).unwrap();
        assert!(
            usage(s.solve(&mut vec![1.0; n])),
            "{name}: solve before factor"
        );
        let longer = [vals.as_slice(), &[1.0]].concat();
        for values in [&[][..], &vals[..vals.len() - 1], &longer] {
            // After a good factorization, so that the refusal is seen to discard it.
            s.factor(&vals).unwrap();
            assert!(usage(s.factor(values)), "{name}: {} values", values.len());
            assert!(
                usage(s.solve(&mut vec![1.0; n])),
                "{name}: solve after a refused factor"
            );
        }
        // An indefinite matrix: the Cholesky and Jacobi backends refuse it (LU factors it), and a solve
        // after a refused factorization does not use an older one.
        let mut indefinite = vals.clone();
        indefinite[red.diag[5]] = -1e6;
        s.factor(&vals).unwrap();
        if s.factor(&indefinite).is_err() {
            assert!(
                usage(s.solve(&mut vec![1.0; n])),
                "{name}: solve after a failed factor"
            );
        } else {
            assert_eq!(name, "faer-lu");
        }
        s.factor(&vals).unwrap();
        for len in [0, n - 1, n + 1] {
            let mut b = vec![1.0; len];
            assert!(
                usage(s.solve(&mut b)),
                "{name}: right-hand side of length {len}"
            );
            assert_eq!(
                b,
                vec![1.0; len],
                "{name}: a refused right-hand side is left as it was"
            );
        }
        let b: Vec<f64> = (0..n).map(|i| (i % 7) as f64 - 3.0).collect();
        let mut x = b.clone();
        s.solve(&mut x).unwrap();
        let mut ax = vec![0.0; n];
        red.csc.mul(&vals, &x, &mut ax);
        assert!(rel_error(&ax, &b) < 1e-9, "{name}: {}", rel_error(&ax, &b));
    }
}

#[test]
fn cholesky_detects_indefinite_matrices_and_lu_solves_them() {
    let (red, mut vals) = spd_system();
    // Make one diagonal entry negative: indefinite.
    vals[red.diag[5]] = -1e6;
    let mut llt = FaerLlt::default();
    llt.analyze(&red.csc).unwrap();
    assert!(matches!(
        llt.factor(&vals),
        Err(LinearError::NotPositiveDefinite { .. })
    ));
    let mut dense = Dense::default();
    dense.analyze(&red.csc).unwrap();
    assert!(dense.factor(&vals).is_err());
    let mut lu = FaerLu::default();
    lu.analyze(&red.csc).unwrap();
    lu.factor(&vals).unwrap();
    let b = vec![1.0; red.csc.n];
    let mut x = b.clone();
    lu.solve(&mut x).unwrap();
    let mut ax = vec![0.0; red.csc.n];
    red.csc.mul(&vals, &x, &mut ax);
    assert!(rel_error(&ax, &b) < 1e-10);
}

/// LU on an indefinite system large enough for faer's supernodal path gives the same bits in pools of
/// one, two and three threads, and solves it (residual, computed here from the matrix).
#[test]
fn lu_gives_the_same_bits_on_any_thread_count() {
    let (red, mut vals) = spd_system_of(40, true);
    let largest = red.diag.iter().map(|&d| vals[d]).fold(0.0, f64::max);
    for (i, &d) in red.diag.iter().enumerate() {
        if i % 5 == 0 {
            vals[d] -= 1.5 * largest;
        }
    }
    let mut llt = FaerLlt::default();
    llt.analyze(&red.csc).unwrap();
    assert!(llt.factor(&vals).is_err(), "the system is indefinite");
    let mut rng = SplitMix64(17);
    let b: Vec<f64> = (0..red.csc.n).map(|_| rng.symmetric()).collect();
    let solve = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let mut lu = FaerLu::default();
                lu.analyze(&red.csc).unwrap();
                lu.factor(&vals).unwrap();
                let mut x = b.clone();
                lu.solve(&mut x).unwrap();
                x
            })
    };
    let one = solve(1);
    let mut ax = vec![0.0; red.csc.n];
    red.csc.mul(&vals, &one, &mut ax);
    assert!(rel_error(&ax, &b) < 1e-10, "{}", rel_error(&ax, &b));
    for threads in [2, 3] {
        let x = solve(threads);
        let differing = x
            .iter()
            .zip(&one)
            .filter(|(a, b)| a.to_bits() != b.to_bits())
            .count();
        assert_eq!(
            differing, 0,
            "{threads} threads: {differing} entries differ"
        );
    }
}

/// A static solve of gravity alone (nothing holds the cloth, F is linear): the typed `ZeroHessian` error
/// with the gradient norm, after one factorization attempt at most, positions untouched. Before, the shift
/// ladder scaled by the smallest normal number (shifts of 2e-316) and the error said "matrix is singular".
/// With inertia the same cloth solves in one step.
#[test]
fn a_zero_hessian_is_named_not_shifted_by_denormals() {
    let rest = cloth(4);
    let n = rest.n_vertices();
    let gravity = Gravity::new(lumped_masses(&rest, 0.1), Vector3::new(0.0, 0.0, -9.81)).unwrap();
    let mut sys = System::new(n, vec![Box::new(gravity)]).unwrap();
    let mut newton = Newton::new(
        &sys,
        &Pins::default(),
        default_solver(),
        NewtonParams::default(),
    )
    .unwrap();
    let mut x = rest.positions().to_vec();
    let x0 = x.clone();
    let err = newton.minimize(&mut sys, &mut x, None).unwrap_err();
    assert!(matches!(err, SolverError::ZeroHessian { .. }), "{err}");
    let stats = err.stats();
    assert_eq!(stats.iterations, 0);
    assert!(stats.factorizations <= 1, "{stats:?}");
    assert_eq!(stats.max_shift, 0.0);
    // ∇F is the vertices' weights along z: its norm is that of the lumped weights.
    let weight: f64 = lumped_masses(&rest, 0.1)
        .iter()
        .map(|m| (m * 9.81).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!((stats.gradient_norms[0] - weight).abs() <= 1e-12 * weight);
    // The norm in four significant digits, as every solver error gives it.
    assert!(
        err.to_string().starts_with(&format!(
            "the Hessian is zero on every free dof at iteration 0 while the gradient is not (norm {weight:.3e}):"
        )),
        "{err}"
    );
    assert_eq!(x, x0);
    // With inertia the Hessian is m/Δt² on the diagonal: one exact step.
    let inertia = Inertia {
        masses: lumped_masses(&rest, 0.1),
        x_hat: x0.clone(),
        dt: 0.01,
    };
    let stats = newton.minimize(&mut sys, &mut x, Some(&inertia)).unwrap();
    assert_eq!(stats.iterations, 1);
}

/// One vertex with `E = c x y`: its Hessian block has a zero diagonal and off-diagonal entries `c`
/// (eigenvalues ±c), so the exact matrix fails to factor and the shift ladder needs a scale. It takes the
/// largest entry when the diagonal is zero: the ladder climbs from 1e-8 c by factors of 4 and factors at
/// the first rung above c. With the diagonal's scale alone (zero, floored at the smallest normal number) its 40
/// rungs ended near 1e-292 and the solve failed with "not positive definite".
fn saddle(c: f64) -> OnVertex0 {
    OnVertex0::new("saddle", move |p| {
        let mut h = Matrix3::zeros();
        h[(0, 1)] = c;
        h[(1, 0)] = c;
        Ok((c * p.x * p.y, Vector3::new(c * p.y, c * p.x, 0.0), h))
    })
}

#[test]
fn a_zero_diagonal_scales_the_shifts_by_the_largest_entry() {
    for c in [1e-3, 1.0, 1e6] {
        let mut sys = System::new(1, vec![Box::new(saddle(c))]).unwrap();
        let params = NewtonParams {
            max_iterations: 1,
            ..NewtonParams::default()
        };
        let pins = Pins::new(1, Vec::new()).unwrap();
        let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
        let energies = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let seen = std::sync::Arc::clone(&energies);
        newton.set_observer(Some(Box::new(move |r| seen.lock().unwrap().push(r.energy))));
        let mut x = vec![Vector3::new(1.0, 0.5, 0.0)];
        let f0 = c * 0.5;
        let err = newton.minimize(&mut sys, &mut x, None).unwrap_err();
        // One iteration taken (the budget), not a factorization failure.
        assert!(
            matches!(err, SolverError::NotConverged { .. }),
            "c = {c}: {err}"
        );
        let stats = err.stats();
        assert_eq!(stats.iterations, 1, "c = {c}");
        // The first shift that factors is the first rung above c: in (c, 4c].
        assert!(
            stats.max_shift > c && stats.max_shift <= 4.0 * c,
            "c = {c}: shift {:e}",
            stats.max_shift
        );
        // The exact attempt, then the rungs 1e-8 c · 4^k for k = 0 … 14 (the first above c), each one
        // factorization.
        assert_eq!(stats.factorizations, 16, "c = {c}");
        // The step lowered E (unbounded below along x = −y); the failed solve left x where it was.
        let energies = energies.lock().unwrap();
        assert!(
            energies.len() == 1 && energies[0] < f0,
            "c = {c}: {energies:?} against {f0}"
        );
        assert_eq!(x, vec![Vector3::new(1.0, 0.5, 0.0)]);
    }
}

#[test]
fn newton_solves_a_quadratic_in_one_step() {
    let rest = cloth(6);
    let mut sys = System::new(
        rest.n_vertices(),
        vec![Box::new(QuadraticBending::new(&rest, 1.0).unwrap())],
    )
    .unwrap();
    let masses = lumped_masses(&rest, 1.0);
    let mut rng = SplitMix64(2);
    let x_hat: Vec<_> = rest
        .positions()
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.0, 0.1 * rng.symmetric()))
        .collect();
    let inertia = Inertia {
        masses,
        x_hat,
        dt: 0.01,
    };
    let mut newton = Newton::new(
        &sys,
        &Pins::default(),
        Box::new(FaerLlt::default()),
        NewtonParams::default(),
    )
    .unwrap();
    let mut x = rest.positions().to_vec();
    let stats = newton.minimize(&mut sys, &mut x, Some(&inertia)).unwrap();
    println!("quadratic: {:?}", stats.gradient_norms);
    assert_eq!(stats.iterations, 1);
    assert!(stats.gradient_norms[1] < 1e-9 * stats.gradient_norms[0]);
}

#[test]
fn statics_of_a_pinned_cloth_converges_quadratically() {
    let rest = cloth(8);
    let n = rest.n_vertices();
    let mut terms: Vec<Box<dyn Energy>> = vec![
        Box::new(MassSpring::new(&rest, 500.0).unwrap()),
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&rest, DiscreteShells { k: 0.05 }).unwrap(),
            Method::Refactored,
        )),
        Box::new(Gravity::new(lumped_masses(&rest, 1.0), Vector3::new(0.0, 0.0, -9.81)).unwrap()),
    ];
    let mut sys = System::new(n, std::mem::take(&mut terms)).unwrap();
    // Pin the edge y = 0: the cloth hangs from it (a cantilever plate).
    let pinned: Vec<usize> = (0..n).filter(|&v| rest.positions()[v].y == 0.0).collect();
    let pins = Pins::new(n, pinned).unwrap();
    let params = NewtonParams {
        gradient_tolerance: 1e-10,
        max_iterations: 100,
        ..NewtonParams::default()
    };
    let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
    let mut x = rest.positions().to_vec();
    let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
    let g = &stats.gradient_norms;
    println!(
        "statics: {} iterations, {} halvings, max shift {:e}\n{g:?}",
        stats.iterations, stats.line_search_steps, stats.max_shift
    );
    // Observed order from the Newton steps (‖Δx_k‖ ≈ ‖x_k − x*‖ near the solution): the last three steps
    // above the rounding floor, p = ln(s₃/s₂) / ln(s₂/s₁).
    let s = &stats.step_norms;
    println!("steps: {s:?}");
    let tail: Vec<f64> = s.iter().copied().filter(|&v| v > 1e-12).collect();
    let k = tail.len();
    assert!(k >= 3, "too few steps to measure the order: {s:?}");
    let order = (tail[k - 1] / tail[k - 2]).ln() / (tail[k - 2] / tail[k - 3]).ln();
    println!("observed order {order:.2}");
    assert!(order > 1.7, "observed convergence order {order}");
    // The pinned edge did not move; the free edge sagged.
    assert!(pins.vertices().iter().all(|&v| x[v] == rest.positions()[v]));
    assert!(x.iter().map(|p| p.z).fold(f64::INFINITY, f64::min) < -0.01);
    assert_eq!(newton.solver().analyses(), 1);
    // The exact Hessian was indefinite on the way: the factorization failed and the shift handled it.
    assert!(
        stats.max_shift > 0.0,
        "this run exercises the inertia correction"
    );
}

/// Every Newton parameter out of its range is an input error naming it, from `Newton::new` and, after a
/// change of the public `params`, from `minimize`, which then leaves the positions as they were; the
/// ends of each range are accepted.
#[test]
fn newton_parameters_out_of_range_are_named_errors() {
    let rest = cloth(4);
    let n = rest.n_vertices();
    let mut sys = spring_system(&rest, true);
    let pinned: Vec<usize> = (0..n).filter(|&v| rest.positions()[v].y == 0.0).collect();
    let pins = Pins::new(n, pinned).unwrap();
    let d = NewtonParams::default;
    let bad: Vec<(&str, NewtonParams)> = vec![
        (
            "max_iterations",
            NewtonParams {
                max_iterations: 0,
                ..d()
            },
        ),
        ("armijo", NewtonParams { armijo: 0.0, ..d() }),
        ("armijo", NewtonParams { armijo: 0.5, ..d() }),
        (
            "armijo",
            NewtonParams {
                armijo: f64::NAN,
                ..d()
            },
        ),
        (
            "gradient_tolerance",
            NewtonParams {
                gradient_tolerance: f64::NAN,
                ..d()
            },
        ),
        (
            "gradient_tolerance",
            NewtonParams {
                gradient_tolerance: -1e-8,
                ..d()
            },
        ),
        (
            "step_tolerance",
            NewtonParams {
                step_tolerance: f64::INFINITY,
                ..d()
            },
        ),
        (
            "relative_gradient_tolerance",
            NewtonParams {
                relative_gradient_tolerance: -1.0,
                ..d()
            },
        ),
        (
            "relative_step_tolerance",
            NewtonParams {
                relative_step_tolerance: f64::NAN,
                ..d()
            },
        ),
        (
            "length_scale",
            NewtonParams {
                length_scale: -0.1,
                ..d()
            },
        ),
        (
            "initial_shift",
            NewtonParams {
                initial_shift: 0.0,
                ..d()
            },
        ),
        (
            "initial_shift",
            NewtonParams {
                initial_shift: f64::INFINITY,
                ..d()
            },
        ),
        (
            "definite_shift_ratio",
            NewtonParams {
                definite_shift_ratio: f64::NAN,
                ..d()
            },
        ),
        (
            "definite_shift_ratio",
            NewtonParams {
                definite_shift_ratio: -1.0,
                ..d()
            },
        ),
        (
            "definite_hold",
            NewtonParams {
                definite_hold: 0,
                ..d()
            },
        ),
    ];
    for (name, params) in bad {
        let err = Newton::new(&sys, &pins, default_solver(), params.clone())
            .err()
            .unwrap_or_else(|| panic!("accepted {params:?}"));
        assert!(matches!(err, SolverError::Input(_)), "{err}");
        assert!(
            err.to_string().contains(&format!("NewtonParams::{name} ")),
            "{err}"
        );
        assert_eq!(
            params.validate().err().map(|e| e.to_string()),
            Some(err.to_string())
        );
    }
    let edges = [
        NewtonParams {
            max_iterations: 1,
            armijo: f64::MIN_POSITIVE,
            gradient_tolerance: 0.0,
            step_tolerance: 0.0,
            relative_gradient_tolerance: 0.0,
            relative_step_tolerance: 0.0,
            length_scale: 0.0,
            initial_shift: f64::MIN_POSITIVE,
            definite_shift_ratio: 0.0,
            definite_hold: 1,
            max_line_search: 0,
            max_shifts: 0,
            damped_retries: 0,
            ..d()
        },
        NewtonParams {
            max_iterations: usize::MAX,
            armijo: 0.4999,
            definite_shift_ratio: f64::INFINITY,
            definite_hold: usize::MAX,
            ..d()
        },
    ];
    for params in edges {
        assert!(params.validate().is_ok(), "{params:?}");
        assert!(Newton::new(&sys, &pins, default_solver(), params).is_ok());
    }
    // A change of the public parameters after `new` is checked by the solve, which changes nothing.
    let mut newton = Newton::new(&sys, &pins, default_solver(), d()).unwrap();
    let mut x: Vec<Vector3<f64>> = rest.positions().to_vec();
    x[n - 1].z += 0.01;
    let before = x.clone();
    newton.params.gradient_tolerance = f64::NAN;
    let err = newton.minimize(&mut sys, &mut x, None).unwrap_err();
    assert!(
        err.to_string()
            .contains("NewtonParams::gradient_tolerance "),
        "{err}"
    );
    assert_eq!(err.stats().iterations, 0);
    assert_eq!(x, before);
    newton.params.gradient_tolerance = 1e-8;
    newton.params.max_iterations = 100;
    let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
    assert!(stats.iterations > 0 && x != before);
}

#[test]
fn implicit_euler_never_increases_the_energy_of_an_undamped_system() {
    let rest = cloth(6);
    let n = rest.n_vertices();
    let mut sys = spring_system(&rest, true);
    let masses = lumped_masses(&rest, 1.0);
    let pins = Pins::new(n, vec![0]).unwrap();
    let mut stepper = ImplicitEuler::new(
        &sys,
        0.01,
        masses.clone(),
        pins,
        Box::new(FaerLlt::default()),
        NewtonParams::default(),
    )
    .unwrap();
    let mut rng = SplitMix64(8);
    let mut x: Vec<_> = rest
        .positions()
        .iter()
        .map(|p| {
            p + Vector3::new(
                0.02 * rng.symmetric(),
                0.02 * rng.symmetric(),
                0.05 * rng.symmetric(),
            )
        })
        .collect();
    x[0] = rest.positions()[0];
    let mut v = vec![Vector3::zeros(); n];
    let total =
        |sys: &mut System, x: &[Vector3<f64>], v: &[Vector3<f64>]| total_energy(sys, &masses, x, v);
    let mut last = total(&mut sys, &x, &v);
    for step in 0..30 {
        let stats = stepper.step(&mut sys, &mut x, &mut v).unwrap();
        let h = total(&mut sys, &x, &v);
        assert!(
            h <= last * (1.0 + 1e-12) + 1e-15,
            "step {step}: {h} > {last} ({stats:?})"
        );
        last = h;
    }
    assert_eq!(
        stepper.newton().solver().analyses(),
        1,
        "the symbolic analysis is reused across steps"
    );
}

#[test]
fn a_step_that_cannot_converge_leaves_the_state_untouched() {
    let rest = cloth(6);
    let n = rest.n_vertices();
    let mut sys = spring_system(&rest, true);
    let params = NewtonParams {
        max_iterations: 1,
        gradient_tolerance: 0.0,
        step_tolerance: 0.0,
        ..NewtonParams::default()
    };
    let mut stepper = ImplicitEuler::new(
        &sys,
        1.0,
        lumped_masses(&rest, 1.0),
        Pins::default(),
        Box::new(FaerLlt::default()),
        params,
    )
    .unwrap();
    let mut x: Vec<_> = rest.positions().iter().map(|p| p * 1.3).collect();
    let mut v = vec![Vector3::new(0.0, 0.0, 1.0); n];
    let (x0, v0) = (x.clone(), v.clone());
    let err = stepper.step(&mut sys, &mut x, &mut v).unwrap_err();
    assert!(matches!(err, SolverError::NotConverged { .. }), "{err}");
    assert!(err.to_string().contains("no convergence"));
    assert_eq!((&x, &v), (&x0, &v0));
    // Bad input is an error too, never a panic.
    assert!(
        ImplicitEuler::new(
            &sys,
            -1.0,
            vec![1.0; n],
            Pins::default(),
            Box::new(FaerLlt::default()),
            NewtonParams::default()
        )
        .is_err()
    );
    // A mass that is negative or not finite, named by its vertex.
    for (m, shown) in [(-1.0, "-1"), (f64::NAN, "NaN"), (f64::INFINITY, "inf")] {
        let mut masses = vec![1.0; n];
        masses[5] = m;
        let err = ImplicitEuler::new(
            &sys,
            0.01,
            masses,
            Pins::default(),
            Box::new(FaerLlt::default()),
            NewtonParams::default(),
        )
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            format!("vertex 5: mass {shown} must be non-negative and finite")
        );
    }
    // A position or velocity that is not finite fails the step before anything moves, and `advance`
    // does not retry it in substeps.
    let mut stepper = ImplicitEuler::new(
        &sys,
        0.01,
        lumped_masses(&rest, 1.0),
        Pins::default(),
        Box::new(FaerLlt::default()),
        NewtonParams::default(),
    )
    .unwrap();
    for (which, c, value, message) in [
        (
            0,
            2,
            f64::NAN,
            "vertex 7: position coordinate 2 is not finite (NaN)",
        ),
        (
            1,
            0,
            f64::INFINITY,
            "vertex 7: velocity coordinate 0 is not finite (inf)",
        ),
    ] {
        let (mut x, mut v) = (x0.clone(), v0.clone());
        if which == 0 {
            x[7][c] = value;
        } else {
            v[7][c] = value;
        }
        let (xb, vb) = (x.clone(), v.clone());
        let err = stepper.step(&mut sys, &mut x, &mut v).unwrap_err();
        assert!(matches!(err, SolverError::Input(_)), "{err}");
        assert_eq!(err.to_string(), message);
        let err = stepper
            .advance(&mut sys, &mut x, &mut v, SubstepPolicy::default())
            .unwrap_err();
        assert_eq!(err.to_string(), message);
        assert_eq!(err.stats().factorizations, 0);
        // NaN != NaN: compare the bits.
        let bits = |a: &[Vector3<f64>]| -> Vec<u64> {
            a.iter()
                .flat_map(|p| p.iter().map(|c| c.to_bits()))
                .collect()
        };
        assert_eq!((bits(&x), bits(&v)), (bits(&xb), bits(&vb)));
    }
}

fn min_eigenvalue(sys: &System, hessian: &[f64]) -> (f64, f64) {
    let p = sys.pattern();
    let n = p.dim();
    let dense = sym_dense(p, hessian);
    let m = hinge_core::nalgebra::DMatrix::from_row_slice(n, n, &dense);
    let eig = m.symmetric_eigen();
    let min = eig
        .eigenvalues
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let max = eig.eigenvalues.iter().map(|v| v.abs()).fold(0.0, f64::max);
    (min, max)
}

#[test]
fn hessian_modes_gauss_newton_and_projection_are_psd() {
    use hinge_core::bending::HessianMode;
    use hinge_energies::bending::TanBending;
    let rest = cloth(4);
    let n = rest.n_vertices();
    let mut rng = SplitMix64(4);
    let x: Vec<_> = rest
        .positions()
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.0, 0.3 * rng.symmetric()))
        .collect();
    let build = |mode: HessianMode, method: Method| {
        let mut m = BendingModel::new(&rest, TanBending { k: 1.0 }).unwrap();
        m.set_hessian_mode(mode).unwrap();
        System::new(
            n,
            vec![Box::new(HingeTerm::new("tan", m, method)) as Box<dyn Energy>],
        )
        .unwrap()
    };
    let eval = |sys: &mut System| {
        sys.evaluate(&x, Request::ALL, Parallelism::Sequential)
            .unwrap()
    };
    let mut exact = build(HessianMode::Exact, Method::Refactored);
    let e = eval(&mut exact);
    let (lo, hi) = min_eigenvalue(&exact, &e.hessian);
    println!("exact: min eigenvalue {lo:.3e} (max |λ| {hi:.3e})");
    assert!(
        lo < -1e-6 * hi,
        "this bent state has an indefinite exact Hessian"
    );
    for mode in [HessianMode::GaussNewton, HessianMode::ProjectPerHinge] {
        let mut a = build(mode, Method::Refactored);
        let mut b = build(mode, Method::PerHinge);
        let (ea, eb) = (eval(&mut a), eval(&mut b));
        // Same energy and gradient as the exact mode; a PSD Hessian; both methods agree.
        assert_eq!(ea.energy, e.energy);
        assert!(rel_error(&ea.gradient, &e.gradient) < 1e-14);
        assert!(rel_error(&ea.hessian, &eb.hessian) < 1e-13, "{mode:?}");
        let (lo, hi) = min_eigenvalue(&a, &ea.hessian);
        println!("{mode:?}: min eigenvalue {lo:.3e} (max |λ| {hi:.3e})");
        assert!(lo > -1e-12 * hi, "{mode:?} must be positive semi-definite");
    }
}

#[test]
fn baraff_witkin_mode_takes_one_iteration() {
    let rest = cloth(6);
    let n = rest.n_vertices();
    let mut sys = spring_system(&rest, true);
    let params = NewtonParams {
        single_iteration: true,
        ..NewtonParams::default()
    };
    let mut stepper = ImplicitEuler::new(
        &sys,
        0.01,
        lumped_masses(&rest, 1.0),
        Pins::default(),
        Box::new(FaerLlt::default()),
        params,
    )
    .unwrap();
    let mut x: Vec<_> = rest.positions().iter().map(|p| p * 1.05).collect();
    let mut v = vec![Vector3::zeros(); n];
    let stats = stepper.step(&mut sys, &mut x, &mut v).unwrap();
    assert_eq!(stats.iterations, 1);
    assert!(stats.gradient_norms[1] < stats.gradient_norms[0]);
}

#[test]
fn damped_retries_rescue_a_near_singular_newton_step() {
    // A bending + membrane sheet pinned along a single row of vertices: swinging about that row costs no
    // energy at the flat start, so the exact Newton step along it is enormous and no halving of it decreases
    // F. Without Levenberg–Marquardt retries Newton fails at once; with them it converges.
    use hinge_energies::bending::TanBending;
    use hinge_energies::membrane::StvkMembrane;
    let rest = grid(8, 8, 1.0, 1.0, Diagonal::Alternating).unwrap();
    let n = rest.n_vertices();
    let make = || {
        let terms: Vec<Box<dyn Energy>> = vec![
            Box::new(HingeTerm::new(
                "bending",
                BendingModel::new(&rest, TanBending { k: 1e-2 }).unwrap(),
                Method::Refactored,
            )),
            Box::new(StvkMembrane::new(&rest, 1e4, 0.3, 1e-3).unwrap()),
            Box::new(
                Gravity::new(lumped_masses(&rest, 0.1), Vector3::new(0.0, 0.0, -9.81)).unwrap(),
            ),
        ];
        System::new(n, terms).unwrap()
    };
    let pins = Pins::new(n, (0..=8).collect()).unwrap();
    let solve = |retries: usize| {
        let mut sys = make();
        let params = NewtonParams {
            damped_retries: retries,
            max_iterations: 500,
            ..NewtonParams::default()
        };
        let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
        let mut x = rest.positions().to_vec();
        let r = newton.minimize(&mut sys, &mut x, None);
        (r, x)
    };
    let (without, x_failed) = solve(0);
    assert!(
        matches!(without, Err(SolverError::LineSearch { .. })),
        "{without:?}"
    );
    assert_eq!(
        x_failed,
        rest.positions(),
        "a failed solve leaves x untouched"
    );
    let (with, x) = solve(NewtonParams::default().damped_retries);
    let stats = with.unwrap();
    println!(
        "with damped retries: {} iterations, max shift {:.2e}, final ‖∇F‖ {:.2e}",
        stats.iterations,
        stats.max_shift,
        stats.gradient_norms.last().unwrap()
    );
    assert!(stats.max_shift > 0.0);
    // The sheet hangs below the pinned row.
    assert!(x[n - 1].z < -0.5, "{}", x[n - 1]);
}

/// A stretched, spinning cloth pinned at one corner with a Newton budget too small for a full 1 s step.
fn hard_stepper(
    max_iterations: usize,
    dt: f64,
) -> (System, ImplicitEuler, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let rest = cloth(6);
    let n = rest.n_vertices();
    let sys = spring_system(&rest, true);
    let params = NewtonParams {
        max_iterations,
        ..NewtonParams::default()
    };
    let stepper = ImplicitEuler::new(
        &sys,
        dt,
        lumped_masses(&rest, 1.0),
        Pins::new(n, vec![0]).unwrap(),
        Box::new(FaerLlt::default()),
        params,
    )
    .unwrap();
    let mut x: Vec<_> = rest.positions().iter().map(|p| p * 1.3).collect();
    x[0] = rest.positions()[0];
    let v: Vec<_> = rest
        .positions()
        .iter()
        .map(|p| Vector3::new(-p.y, p.x, 0.5) * 4.0)
        .collect();
    (sys, stepper, x, v)
}

fn total_energy(sys: &mut System, masses: &[f64], x: &[Vector3<f64>], v: &[Vector3<f64>]) -> f64 {
    let e = sys
        .evaluate(x, Request::VALUE, Parallelism::Sequential)
        .unwrap()
        .energy;
    e + v
        .iter()
        .zip(masses)
        .map(|(w, m)| 0.5 * m * w.norm_squared())
        .sum::<f64>()
}

#[test]
fn a_failed_step_is_retried_in_substeps_that_tile_the_frame() {
    // 6 Newton iterations are not enough for the 1 s step (measured: the full step fails), enough for
    // smaller ones.
    let (mut sys, mut stepper, mut x, mut v) = hard_stepper(6, 1.0);
    let masses = lumped_masses(&cloth(6), 1.0);
    let (x0, v0) = (x.clone(), v.clone());
    let e0 = total_energy(&mut sys, &masses, &x, &v);
    let err = stepper.step(&mut sys, &mut x, &mut v).unwrap_err();
    assert!(matches!(err, SolverError::NotConverged { .. }), "{err}");
    assert_eq!(
        (&x, &v),
        (&x0, &v0),
        "a failed step leaves the state untouched"
    );
    let fs = stepper
        .advance(&mut sys, &mut x, &mut v, SubstepPolicy::default())
        .unwrap();
    println!(
        "substeps {} (failed attempts {}), smallest dt/{}, {} Newton iterations, {} factorizations",
        fs.substeps,
        fs.failed_attempts,
        1.0 / fs.smallest_fraction,
        fs.newton.iterations,
        fs.newton.factorizations
    );
    assert!(fs.substeps > 1 && fs.failed_attempts >= 1);
    assert!(fs.smallest_fraction >= 1.0 / 32.0);
    assert!(fs.newton.factorizations >= fs.newton.iterations);
    assert!(fs.max_final_gradient_norm <= NewtonParams::default().gradient_tolerance);
    // Implicit Euler without damping never gains energy, whatever the step sizes.
    let e1 = total_energy(&mut sys, &masses, &x, &v);
    assert!(e1 <= e0 * (1.0 + 1e-12), "{e1} > {e0}");
    assert_eq!(x[0], x0[0], "the pin stays put");
}

#[test]
fn a_frame_that_fails_below_the_floor_leaves_everything_untouched() {
    // Two Newton iterations are too few even at dt/32 (measured).
    let (mut sys, mut stepper, mut x, mut v) = hard_stepper(2, 1.0);
    let (x0, v0) = (x.clone(), v.clone());
    let err = stepper
        .advance(&mut sys, &mut x, &mut v, SubstepPolicy::default())
        .unwrap_err();
    assert!(err.to_string().contains("no convergence"), "{err}");
    assert_eq!((x, v), (x0, v0));
}

#[test]
fn a_frame_without_failures_is_exactly_one_step() {
    let (mut sys, mut a, mut x, mut v) = hard_stepper(20, 0.25);
    let (mut sys2, mut b, mut x2, mut v2) = hard_stepper(20, 0.25);
    let fs = a
        .advance(&mut sys, &mut x, &mut v, SubstepPolicy::default())
        .unwrap();
    let s = b.step(&mut sys2, &mut x2, &mut v2).unwrap();
    assert_eq!((fs.substeps, fs.failed_attempts), (1, 0));
    assert_eq!(fs.newton.iterations, s.iterations);
    assert_eq!((x, v), (x2, v2), "bitwise the same as one step");
}

#[test]
fn a_failed_step_does_not_advance_the_damping_state() {
    let rest = cloth(5);
    let n = rest.n_vertices();
    let damped = BendingModel::new(
        &rest,
        (DiscreteShells { k: 0.01 }, ViscousDamping { kd: 0.5 }),
    )
    .unwrap();
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(MassSpring::new(&rest, 200.0).unwrap()),
        Box::new(HingeTerm::new("bending", damped, Method::Refactored)),
    ];
    let mut sys = System::new(n, terms).unwrap();
    let mut stepper = ImplicitEuler::new(
        &sys,
        0.05,
        lumped_masses(&rest, 1.0),
        Pins::new(n, vec![0]).unwrap(),
        Box::new(FaerLlt::default()),
        NewtonParams::default(),
    )
    .unwrap();
    let mut x: Vec<_> = rest
        .positions()
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.0, 0.1 * (3.0 * p.x).sin()))
        .collect();
    let mut v = vec![Vector3::new(0.0, 0.0, 0.3); n];
    v[0] = Vector3::zeros();
    stepper.step(&mut sys, &mut x, &mut v).unwrap();
    // The damping energy depends on θ_prev (the start of the last accepted step) and dt.
    let probe: Vec<_> = x.iter().map(|p| p * 1.01).collect();
    let at = |sys: &mut System| {
        sys.evaluate(&probe, Request::VALUE, Parallelism::Sequential)
            .unwrap()
            .energy
    };
    let before = at(&mut sys);
    stepper.newton_mut().params.max_iterations = 0;
    let (x1, v1) = (x.clone(), v.clone());
    assert!(stepper.step(&mut sys, &mut x, &mut v).is_err());
    assert_eq!((&x, &v), (&x1, &v1));
    assert_eq!(
        at(&mut sys).to_bits(),
        before.to_bits(),
        "the failed step's θ_prev was not kept"
    );
    assert!(
        stepper
            .advance(&mut sys, &mut x, &mut v, SubstepPolicy::default())
            .is_err()
    );
    assert_eq!(at(&mut sys).to_bits(), before.to_bits());
    // And a successful step does move it (the check above could fail).
    stepper.newton_mut().params.max_iterations = 100;
    stepper.step(&mut sys, &mut x, &mut v).unwrap();
    assert_ne!(at(&mut sys).to_bits(), before.to_bits());
}

/// ψ = k (θ − θ̄): ψ″ ≡ 0, so the exact Hessian has no wing–wing (x2–x3) blocks.
#[derive(hinge_core::HingeEnergy)]
#[psi(k * (theta - theta_bar))]
pub struct LinearInTheta {
    /// Stiffness.
    pub k: f64,
}

#[test]
fn projection_of_a_psi_second_derivative_free_energy_keeps_the_wing_blocks() {
    use hinge_core::autodiff::hinge_angle_autodiff;
    use hinge_core::bending::HessianMode;
    use hinge_core::export::dense;
    use hinge_core::nalgebra::{DMatrix, SMatrix};
    const { assert!(<LinearInTheta as hinge_core::psi::HingePsi>::D2_IS_ZERO) };
    // A closed mesh, randomly renumbered, and an irregular open sheet, both bent.
    let sphere = hinge_core::shapes::icosphere(1, 1.0).unwrap();
    let perm = hinge_core::shapes::random_permutation(sphere.n_vertices(), 5);
    let sphere = hinge_core::shapes::renumber(&sphere, &perm).unwrap();
    let sheet = hinge_core::shapes::irregular_sheet(7, 6, 3).unwrap();
    for rest in [sphere, sheet] {
        let n = rest.n_vertices();
        let mut rng = SplitMix64(11);
        let x: Vec<_> = hinge_core::shapes::bend(rest.positions())
            .iter()
            .map(|p| {
                p + Vector3::new(
                    0.05 * rng.symmetric(),
                    0.05 * rng.symmetric(),
                    0.1 * rng.symmetric(),
                )
            })
            .collect();
        let k = 0.7;
        let mut m = BendingModel::new(&rest, LinearInTheta { k }).unwrap();
        let wings = |m: &BendingModel<LinearInTheta>| {
            m.topology()
                .hinges()
                .iter()
                .filter(|h| m.pattern().find(h.vertices[2], h.vertices[3]).is_some())
                .count()
        };
        let exact_wings = wings(&m);
        m.set_hessian_mode(HessianMode::ProjectPerHinge).unwrap();
        assert_eq!(wings(&m), m.topology().hinges().len());
        for method in [Method::Refactored, Method::PerHinge, Method::Autodiff] {
            let e = m
                .evaluate(&x, Request::ALL, method, Parallelism::Sequential)
                .unwrap();
            let got = dense(m.pattern(), &e.hessian).unwrap();
            // Independent: per hinge, ψ′ Hess θ from num-dual, projected by faer's eigendecomposition.
            let mut want = DMatrix::<f64>::zeros(3 * n, 3 * n);
            for (h, rest_h) in m.topology().hinges().iter().zip(m.rest_hinges()) {
                let st = h.vertices.map(|v| x[v]);
                let d = hinge_angle_autodiff(&st).unwrap();
                let _ = rest_h;
                let local: SMatrix<f64, 12, 12> = d.hessian * k;
                let fm = faer::Mat::<f64>::from_fn(12, 12, |i, j| local[(i, j)]);
                let eig = fm.self_adjoint_eigen(faer::Side::Lower).unwrap();
                let (sv, u) = (eig.S(), eig.U());
                for a in 0..4 {
                    for b in 0..4 {
                        for i in 0..3 {
                            for j in 0..3 {
                                let (r, c) = (3 * a + i, 3 * b + j);
                                let v: f64 = (0..12)
                                    .map(|q| sv[q].max(0.0) * u[(r, q)] * u[(c, q)])
                                    .sum();
                                want[(3 * h.vertices[a] + i, 3 * h.vertices[b] + j)] += v;
                            }
                        }
                    }
                }
            }
            let rel = (&got - &want).norm() / want.norm();
            assert!(
                rel <= 1e-10,
                "{method:?}: projected Hessian off by {rel:e} (exact pattern had {exact_wings} wing pairs)"
            );
        }
    }
}

#[test]
fn definite_requests_give_psd_hessians_with_exact_energy_and_gradient() {
    use hinge_energies::contact::{Contact, Obstacle};
    use hinge_energies::membrane::StvkMembrane;
    // An irregular sheet, renumbered, compressed in-plane and bent, partly inside a sphere.
    let rest = hinge_core::shapes::irregular_sheet(6, 5, 9).unwrap();
    let perm = hinge_core::shapes::random_permutation(rest.n_vertices(), 2);
    let rest = hinge_core::shapes::renumber(&rest, &perm).unwrap();
    let n = rest.n_vertices();
    let mut rng = SplitMix64(21);
    let x: Vec<_> = rest
        .positions()
        .iter()
        .map(|p| {
            Vector3::new(0.8 * p.x, 0.85 * p.y, 0.2 * (3.0 * p.x).sin())
                + Vector3::new(
                    0.01 * rng.symmetric(),
                    0.01 * rng.symmetric(),
                    0.02 * rng.symmetric(),
                )
        })
        .collect();
    let build = || {
        let mut m = BendingModel::new(&rest, DiscreteShells { k: 0.3 }).unwrap();
        m.set_hessian_mode(hinge_core::bending::HessianMode::Exact)
            .unwrap();
        let terms: Vec<Box<dyn Energy>> = vec![
            Box::new(HingeTerm::new("bending", m, Method::Refactored)),
            Box::new(StvkMembrane::new(&rest, 50.0, 0.3, 0.01).unwrap()),
            Box::new(
                Contact::new(
                    n,
                    Obstacle::Sphere {
                        center: Vector3::new(0.4, 0.4, -0.3),
                        radius: 0.45,
                    },
                    100.0,
                    0.05,
                )
                .unwrap(),
            ),
            Box::new(MassSpring::new(&rest, 5.0).unwrap()),
        ];
        System::new(n, terms).unwrap()
    };
    let mut sys = build();
    let exact = sys
        .evaluate(&x, Request::ALL, Parallelism::Sequential)
        .unwrap();
    let definite = sys
        .evaluate(
            &x,
            Request::ALL.with_definite(true),
            Parallelism::Sequential,
        )
        .unwrap();
    assert_eq!(exact.energy, definite.energy);
    assert_eq!(exact.gradient, definite.gradient);
    let (lo, hi) = min_eigenvalue(&sys, &exact.hessian);
    assert!(
        lo < -1e-6 * hi,
        "the exact Hessian of this state is indefinite ({lo:e})"
    );
    let (lo, hi) = min_eigenvalue(&sys, &definite.hessian);
    assert!(
        lo > -1e-12 * hi,
        "definite Hessian has eigenvalue {lo:e} (max {hi:e})"
    );
    // At rest (no compression, no bending, outside the obstacle) the definite Hessian is the exact one.
    let far: Vec<_> = rest
        .positions()
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.0, 5.0))
        .collect();
    let a = sys
        .evaluate(&far, Request::ALL, Parallelism::Sequential)
        .unwrap();
    let b = sys
        .evaluate(
            &far,
            Request::ALL.with_definite(true),
            Parallelism::Sequential,
        )
        .unwrap();
    assert!(rel_error(&a.hessian, &b.hessian) <= 1e-15);
}

/// A sheet clamped along one side (x = 0), sagging under gravity from a compressed, rippled start whose
/// exact Hessian is indefinite in the first iterations: an irregular sheet (random diagonals, jitter, random
/// numbering, rotated corners) with bending, an StVK membrane and gravity. Returns the system, its pins and
/// the start.
fn compressed_clamped_sheet() -> (System, Pins, Vec<Vector3<f64>>) {
    compressed_clamped_sheet_in(hinge_core::bending::HessianMode::Exact)
}

/// [`compressed_clamped_sheet`] with its bending term assembling the Hessian `mode`.
fn compressed_clamped_sheet_in(
    mode: hinge_core::bending::HessianMode,
) -> (System, Pins, Vec<Vector3<f64>>) {
    use hinge_energies::membrane::StvkMembrane;
    let rest = hinge_core::shapes::irregular_sheet(7, 7, 4).unwrap();
    let n = rest.n_vertices();
    let pinned: Vec<usize> = (0..n).filter(|&v| rest.positions()[v].x <= 1e-12).collect();
    assert!(!pinned.is_empty());
    let start: Vec<_> = rest
        .positions()
        .iter()
        .map(|p| Vector3::new(0.9 * p.x, p.y, 0.05 * (4.0 * p.y).sin() * p.x))
        .collect();
    let mut bending = BendingModel::new(&rest, DiscreteShells { k: 1e-3 }).unwrap();
    bending.set_hessian_mode(mode).unwrap();
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(HingeTerm::new("bending", bending, Method::Refactored)),
        Box::new(StvkMembrane::new(&rest, 1e3, 0.3, 1e-3).unwrap()),
        Box::new(Gravity::new(lumped_masses(&rest, 0.1), Vector3::new(0.0, 0.0, -9.81)).unwrap()),
    ];
    (
        System::new(n, terms).unwrap(),
        Pins::new(n, pinned).unwrap(),
        start,
    )
}

#[test]
fn both_globalizations_reach_the_same_equilibrium() {
    use hinge_solver::newton::Globalization;
    let mut results = Vec::new();
    for g in [Globalization::ShiftedExact, Globalization::ProjectOnDemand] {
        let (mut sys, pins, start) = compressed_clamped_sheet();
        let params = NewtonParams {
            gradient_tolerance: 1e-9,
            max_iterations: 500,
            globalization: g,
            ..NewtonParams::default()
        };
        let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
        let mut x = start;
        let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
        println!(
            "{g:?}: {} iterations, {} factorizations, {} definite",
            stats.iterations, stats.factorizations, stats.definite_iterations
        );
        assert!(stats.gradient_norms.last().unwrap() <= &1e-9);
        if g == Globalization::ProjectOnDemand {
            assert!(
                stats.definite_iterations > 0,
                "the exact Hessian never failed: no test"
            );
        } else {
            assert_eq!(stats.definite_iterations, 0);
        }
        results.push(x);
    }
    let d = results[0]
        .iter()
        .zip(&results[1])
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(d <= 1e-6, "different equilibria: {d:e}");
    // The unit-free gradient test stops the same solve early: at a millionth of the start's gradient, with
    // the absolute tolerances switched off.
    let (mut sys, pins, start) = compressed_clamped_sheet();
    let params = NewtonParams {
        gradient_tolerance: 0.0,
        step_tolerance: 0.0,
        relative_gradient_tolerance: 1e-6,
        max_iterations: 500,
        ..NewtonParams::default()
    };
    let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
    let mut x = start;
    let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
    let g = &stats.gradient_norms;
    let (first, last) = (g[0], *g.last().unwrap());
    assert!(last <= 1e-6 * first, "{first:e} → {last:e}");
    assert!(g[g.len() - 2] > 1e-6 * first, "stopped one iteration late");
    assert!(
        last > 1e-12 * first,
        "went on past the relative test: {last:e}"
    );
}

/// [`NewtonParams::definite_hold`]: once project on demand switched to the definite Hessian, an exact
/// iteration comes only after that many full definite steps (an extrapolated step does not count), and
/// every hold reaches the same equilibrium. Read from the iteration reports of the compressed clamped
/// sheet (irregular: random diagonals, jitter, random numbering, rotated corners), whose exact Hessian
/// fails to factor on the way.
#[test]
fn definite_hold_keeps_the_definite_hessian_for_that_many_full_steps() {
    use hinge_solver::newton::{Globalization, IterationReport};
    use std::sync::{Arc, Mutex};
    let mut results = Vec::new();
    // The fewest full definite steps before an exact iteration, over the run (None: no such switch).
    let mut fewest = Vec::new();
    for hold in [1, 3, 1_000_000] {
        let (mut sys, pins, start) = compressed_clamped_sheet();
        let params = NewtonParams {
            gradient_tolerance: 1e-9,
            max_iterations: 500,
            globalization: Globalization::ProjectOnDemand,
            definite_hold: hold,
            ..NewtonParams::default()
        };
        let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
        let seen = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&seen);
        newton.set_observer(Some(Box::new(move |r: &IterationReport| {
            sink.lock().unwrap().push((r.definite, r.step_length));
        })));
        let mut x = start;
        let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
        assert!(stats.gradient_norms.last().unwrap() <= &1e-9);
        let seen = seen.lock().unwrap().clone();
        let (mut full, mut switched, mut least) = (0_usize, false, None::<usize>);
        for &(definite, alpha) in &seen {
            if definite {
                switched = true;
                if alpha == 1.0 {
                    full += 1;
                }
            } else if switched {
                least = Some(least.map_or(full, |l| l.min(full)));
                (full, switched) = (0, false);
            }
        }
        println!(
            "hold {hold}: {} iterations, {} factorizations, {} definite; fewest full definite steps \
             before an exact one {least:?}",
            stats.iterations, stats.factorizations, stats.definite_iterations
        );
        assert!(stats.definite_iterations > 0, "never switched: no test");
        assert!(least.is_none_or(|l| l >= hold), "hold {hold}: {least:?}");
        fewest.push(least);
        results.push(x);
    }
    // The test can fail: with a hold of 1 some exact iteration follows fewer than 3 full definite steps,
    // and a hold beyond the run's iterations never returns to the exact Hessian.
    assert!(fewest[0].is_some_and(|l| l < 3), "{fewest:?}");
    assert_eq!(fewest[2], None);
    for other in &results[1..] {
        let d = results[0]
            .iter()
            .zip(other)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(d <= 1e-6, "different equilibria: {d:e}");
    }
}

/// [`NewtonParams::definite_shift_ratio`]: in a time step, an iteration whose diagonal shift would exceed
/// the ratio times the largest free `m/Δt²` takes each energy's definite Hessian instead. Measured against
/// the solve that never switches: a ratio just above what its largest shift needs changes nothing
/// (bitwise), one just below it switches, and the solve still converges; without inertia (statics) the
/// ratio plays no part.
#[test]
fn a_shift_far_above_the_inertia_switches_to_the_definite_hessian() {
    let (mut sys, pins, start) = compressed_clamped_sheet();
    let n = start.len();
    // Light vertices and a long step: the inertia term (1e-5 N/m) is far below the curvature the
    // compressed start's shifts make up for.
    let (mass, dt) = (1e-7, 0.1);
    let inertia = Inertia {
        masses: vec![mass; n],
        x_hat: start.clone(),
        dt,
    };
    let top = mass / (dt * dt);
    let mut solve = |ratio: f64, inertia: Option<&Inertia>| {
        let params = NewtonParams {
            gradient_tolerance: 1e-9,
            max_iterations: 500,
            definite_shift_ratio: ratio,
            ..NewtonParams::default()
        };
        let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
        let mut x = start.clone();
        let stats = newton.minimize(&mut sys, &mut x, inertia).unwrap();
        assert!(stats.gradient_norms.last().unwrap() <= &1e-9);
        (x, stats)
    };
    let (x_never, never) = solve(f64::INFINITY, Some(&inertia));
    assert_eq!(never.definite_iterations, 0);
    assert!(
        never.max_shift > 10.0 * top,
        "no shift far above the inertia ({:e} against {top:e}): no test",
        never.max_shift
    );
    let needed = never.max_shift / top;
    let (x_above, above) = solve(1.01 * needed, Some(&inertia));
    assert_eq!(above.definite_iterations, 0);
    assert_eq!(x_above, x_never);
    assert_eq!(above.iterations, never.iterations);
    assert_eq!(above.factorizations, never.factorizations);
    let (_, below) = solve(0.99 * needed, Some(&inertia));
    println!(
        "never: {} iterations / {} factorizations (largest shift {:.3e} = {needed:.3e} m/dt²); \
         ratio 0.99 of that: {} / {}, {} definite",
        never.iterations,
        never.factorizations,
        never.max_shift,
        below.iterations,
        below.factorizations,
        below.definite_iterations
    );
    assert!(below.definite_iterations > 0, "no switch below the ratio");
    // Statics: no inertia, no switch whatever the ratio.
    let (x0, s0) = solve(0.0, None);
    let (x1, s1) = solve(f64::INFINITY, None);
    assert!(
        s0.max_shift > 0.0,
        "the static solve never shifted: no test"
    );
    assert_eq!(s0.definite_iterations, 0);
    assert_eq!((x0, s0.iterations), (x1, s1.iterations));
}

/// A step test counts only after a full step of an exact Hessian: with the bending term in Gauss–Newton or
/// projected mode no direction is an exact Newton one, so a loose step tolerance does not end the solve
/// (its gradient test does), where the exact Hessian's full steps end it early; the same equilibrium. Nor
/// is any of their steps corrected by geodesic acceleration, where the exact solve's are.
#[test]
fn a_step_test_never_ends_a_solve_whose_hessian_is_not_exact() {
    use hinge_core::bending::HessianMode;
    let mut ends = Vec::new();
    for mode in HessianMode::ALL {
        let (mut sys, pins, start) = compressed_clamped_sheet_in(mode);
        assert_eq!(sys.hessian_is_exact(), mode == HessianMode::Exact);
        let params = NewtonParams {
            gradient_tolerance: 1e-9,
            // Loose (the sheet is 1 m across): full steps of every mode fall below it while ‖∇F‖ is far
            // above 1e-9 (exact: a 1.3e-2 m step at 7e-3 N; Gauss–Newton 5.4e-2 m at 1.4e-2 N).
            step_tolerance: 0.1,
            max_iterations: 2000,
            ..NewtonParams::default()
        };
        let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
        let mut x = start;
        let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
        let last = *stats.gradient_norms.last().unwrap();
        println!(
            "{mode:?}: {} iterations, final gradient {last:e}",
            stats.iterations
        );
        if mode == HessianMode::Exact {
            assert!(
                last > 1e-9,
                "the step test never ended the exact solve: no test"
            );
            assert!(
                stats.accelerated_iterations > 0,
                "no corrected step: no test"
            );
        } else {
            assert!(last <= 1e-9, "{mode:?}: a step test ended it at {last:e}");
            // Geodesic acceleration's difference quotient needs the exact Hessian.
            assert_eq!(stats.accelerated_iterations, 0, "{mode:?}");
        }
        ends.push(x);
    }
    let d = ends[1]
        .iter()
        .zip(&ends[2])
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(d <= 1e-6, "different equilibria: {d:e}");
}

#[test]
fn unit_free_stopping_tests() {
    let p = NewtonParams {
        gradient_tolerance: 1e-12,
        step_tolerance: 0.0,
        relative_gradient_tolerance: 1e-6,
        relative_step_tolerance: 1e-8,
        length_scale: 0.01,
        ..NewtonParams::default()
    };
    // Relative to the start's gradient, whatever the units.
    assert!(p.converged(0.9e-6 * 3e4, 3e4, None));
    assert!(!p.converged(1.1e-6 * 3e4, 3e4, None));
    // Largest vertex step against the length scale.
    assert!(p.converged(1.0, 1.0, Some((1.0, 0.9e-10))));
    assert!(!p.converged(1.0, 1.0, Some((1.0, 1.1e-10))));
    // Off by default: only the absolute tests.
    let d = NewtonParams::default();
    assert!(!d.converged(1e-7, 1.0, Some((1.0, 0.0))));
    assert!(d.converged(1e-9, 1.0, None));
}

#[test]
fn refactoring_with_new_values_forgets_the_old_ones() {
    // FaerLlt keeps its factor storage between factorizations: a later factorization must not see an
    // earlier one's values, and a failed one leaves nothing to solve with.
    let (red, vals) = spd_system_of(20, true);
    let n = red.csc.n;
    // 2A + 10 I: positive definite too, other values in every slot.
    let mut other: Vec<f64> = vals.iter().map(|v| 2.0 * v).collect();
    for &k in &red.diag {
        other[k] += 10.0;
    }
    let b: Vec<f64> = (0..n).map(|i| ((i * 31) % 11) as f64 - 5.0).collect();
    let mut llt = FaerLlt::default();
    llt.analyze(&red.csc).unwrap();
    let mut ax = vec![0.0; n];
    for m in [&vals, &other, &vals, &other] {
        llt.factor(m).unwrap();
        let mut x = b.clone();
        llt.solve(&mut x).unwrap();
        red.csc.mul(m, &x, &mut ax);
        assert!(rel_error(&ax, &b) < 1e-10, "{}", rel_error(&ax, &b));
    }
    let mut ind = vals.clone();
    ind[red.diag[3]] = -1e6;
    assert!(llt.factor(&ind).is_err());
    let mut x = b.clone();
    assert!(matches!(llt.solve(&mut x), Err(LinearError::Usage(_))));
}

/// A cloth hanging from its y = 0 edge: mass-spring membrane, bending and gravity.
fn hanging_cloth(cells: usize) -> (TriMesh, System, Vec<f64>, Pins) {
    let rest = cloth(cells);
    let n = rest.n_vertices();
    let masses = lumped_masses(&rest, 0.2);
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(MassSpring::new(&rest, 300.0).unwrap()),
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&rest, DiscreteShells { k: 0.01 }).unwrap(),
            Method::Refactored,
        )),
        Box::new(Gravity::new(masses.clone(), Vector3::new(0.0, 0.0, -9.81)).unwrap()),
    ];
    let sys = System::new(n, terms).unwrap();
    let pinned: Vec<usize> = (0..n).filter(|&v| rest.positions()[v].y == 0.0).collect();
    let pins = Pins::new(n, pinned).unwrap();
    (rest, sys, masses, pins)
}

#[test]
fn symplectic_euler_matches_implicit_euler_on_small_steps_and_reports_a_blow_up() {
    use hinge_solver::explicit::{SymplecticEuler, critical_step};
    let (rest, mut sys, masses, pins) = hanging_cloth(6);
    let n = rest.n_vertices();
    let limit = critical_step(&mut sys, rest.positions(), &masses, &pins, 500).unwrap();
    println!("predicted explicit limit 2/ω_max = {limit:.4e} s");
    assert!(limit.is_finite() && limit > 0.0);
    // Far below the limit both first-order methods follow the same trajectory: after N steps their
    // displacements differ by O(1/N) relative.
    let h = 0.05 * limit;
    let steps = 400;
    let mut explicit = SymplecticEuler::new(&sys, h, 1, masses.clone(), &pins).unwrap();
    let (mut xe, mut ve) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
    for _ in 0..steps {
        explicit.advance(&mut sys, &mut xe, &mut ve).unwrap();
    }
    let (_, mut sys_i, _, _) = hanging_cloth(6);
    let params = NewtonParams {
        gradient_tolerance: 1e-12,
        ..NewtonParams::default()
    };
    let mut implicit = ImplicitEuler::new(
        &sys_i,
        h,
        masses.clone(),
        pins.clone(),
        default_solver(),
        params,
    )
    .unwrap();
    let (mut xi, mut vi) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
    for _ in 0..steps {
        implicit.step(&mut sys_i, &mut xi, &mut vi).unwrap();
    }
    let disp = |x: &[Vector3<f64>]| -> Vec<f64> {
        x.iter()
            .zip(rest.positions())
            .flat_map(|(p, r)| (p - r).iter().copied().collect::<Vec<_>>())
            .collect()
    };
    let diff = rel_error(&disp(&xe), &disp(&xi));
    println!(
        "after {steps} steps of {h:.3e} s: explicit vs implicit displacement {diff:.2e} (1/N = {:.2e})",
        1.0 / steps as f64
    );
    assert!(diff < 5.0 / steps as f64, "{diff}");
    // Pins stay put under the explicit steps too.
    assert!(
        pins.vertices()
            .iter()
            .all(|&v| xe[v] == rest.positions()[v])
    );
    // Above the limit the run blows up: detected and reported, the frame's start state kept, no NaN.
    for (factor, stable) in [(0.8, true), (1.05, false), (1.5, false)] {
        let (_, mut sys, _, _) = hanging_cloth(6);
        let h = factor * limit;
        // Frames of ten substeps of h.
        let mut stepper = SymplecticEuler::new(&sys, 10.0 * h, 10, masses.clone(), &pins).unwrap();
        assert_eq!(stepper.step_size(), h);
        let (mut x, mut v) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
        let mut outcome = Ok(());
        for _ in 0..200 {
            let (x0, v0) = (x.clone(), v.clone());
            if let Err(e) = stepper.advance(&mut sys, &mut x, &mut v) {
                assert!(x == x0 && v == v0, "state kept");
                outcome = Err(e);
                break;
            }
        }
        assert!(x.iter().all(|p| p.iter().all(|c| c.is_finite())));
        let speed = v.iter().map(|w| w.norm()).fold(0.0, f64::max);
        println!("h = {factor} × limit: {outcome:?}, largest speed {speed:.3e} m/s");
        match outcome {
            Ok(()) => assert!(stable, "h = {factor} × limit should blow up"),
            Err(SolverError::Unstable { message }) => {
                assert!(!stable, "h = {factor} × limit: {message}");
                assert!(message.contains("above the stability limit"), "{message}");
            }
            Err(e) => panic!("{e}"),
        }
    }
    // Bad input: typed errors.
    assert!(matches!(
        SymplecticEuler::new(&sys, 0.01, 0, masses.clone(), &pins),
        Err(SolverError::Input(_))
    ));
    let mut zero = masses.clone();
    zero[n - 1] = 0.0;
    assert!(matches!(
        SymplecticEuler::new(&sys, 0.01, 1, zero, &pins),
        Err(SolverError::Input(_))
    ));
}

/// A 0.2 m × 2 cm strip, 0.1 mm thick (Y = 1e10 Pa, tan bending at the plate stiffness), clamped by its first
/// two vertex columns, under its own weight (0.1 kg/m²): a thin shell whose membrane is 1e4 times stiffer
/// than its bending at the element scale. The mesh is irregular (random diagonals, jittered, numbered at
/// random, corners rotated), not a row-major grid.
fn thin_strip() -> (TriMesh, System, Pins) {
    thin_strip_in(1)
}

/// [`thin_strip`] with its StVK membrane split into `parts` terms of `Y / parts` each (the same energy).
fn thin_strip_in(parts: usize) -> (TriMesh, System, Pins) {
    use hinge_energies::bending::TanBending;
    use hinge_energies::membrane::StvkMembrane;
    let sheet = hinge_core::shapes::irregular_sheet(41, 4, 7).unwrap();
    let scaled = sheet
        .positions()
        .iter()
        .map(|p| Vector3::new(0.2 * p.x, 0.02 * p.y, 0.0))
        .collect();
    let rest = sheet.with_positions(scaled).unwrap();
    let n = rest.n_vertices();
    let (young, h, nu) = (1e10, 1e-4, 0.3);
    let d = young * h * h * h / (12.0 * (1.0 - nu * nu));
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&rest, TanBending { k: d }).unwrap(),
            Method::Refactored,
        )),
        Box::new(Gravity::new(lumped_masses(&rest, 0.1), Vector3::new(0.0, 0.0, -9.81)).unwrap()),
    ];
    let terms = terms
        .into_iter()
        .chain((0..parts).map(|_| -> Box<dyn Energy> {
            Box::new(StvkMembrane::new(&rest, young / parts as f64, nu, h).unwrap())
        }))
        .collect();
    let clamped: Vec<usize> = (0..n)
        .filter(|&v| rest.positions()[v].x <= 0.2 / 40.0 * 1.5)
        .collect();
    let pins = Pins::new(n, clamped).unwrap();
    let system = System::new(n, terms).unwrap();
    (rest, system, pins)
}

/// Two StVK membranes of half the Young's modulus (the same energy as one): continuing both by the same
/// stages reaches the one-membrane equilibrium in as many iterations; continuing only the first does not
/// help; a failed stage puts every parameter back bitwise.
#[test]
fn membrane_continuation_of_several_membranes_scales_them_all() {
    use hinge_solver::statics::{membrane_scales, minimize_continued, minimize_continued_all};
    let (rest, mut one, pins) = thin_strip_in(1);
    let (_, mut two, _) = thin_strip_in(2);
    assert_eq!(
        two.term_labels(),
        ["bending", "gravity", "membrane", "membrane#2"]
    );
    let params = NewtonParams {
        gradient_tolerance: 1e-8,
        step_tolerance: 1e-14,
        max_iterations: 2000,
        ..NewtonParams::default()
    };
    let scales = membrane_scales(&mut one, &rest).unwrap();
    assert!(!scales.is_empty());
    let newton = |sys: &System| Newton::new(sys, &pins, default_solver(), params.clone()).unwrap();
    let x0 = rest.positions().to_vec();
    let mut x1 = x0.clone();
    let s1 = minimize_continued(
        &mut newton(&one),
        &mut one,
        &mut x1,
        "membrane.young",
        &scales,
    )
    .unwrap();
    let both = ["membrane.young", "membrane#2.young"];
    let mut x2 = x0.clone();
    let s2 = minimize_continued_all(&mut newton(&two), &mut two, &mut x2, &both, &scales).unwrap();
    let mut x3 = x0.clone();
    let s3 = minimize_continued(
        &mut newton(&two),
        &mut two,
        &mut x3,
        "membrane.young",
        &scales,
    )
    .unwrap();
    println!(
        "Newton iterations: one membrane {}, two continued together {}, only the first {}",
        s1.iterations, s2.iterations, s3.iterations
    );
    let diff = x1
        .iter()
        .zip(&x2)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(diff <= 1e-8, "{diff}");
    assert!(s2.iterations <= s1.iterations + 2);
    assert!(2 * s2.iterations < s3.iterations);
    for p in both {
        assert_eq!(two.parameter(p).unwrap(), vec![5e9], "{p}");
    }
    // A stage the second parameter rejects (a negative modulus) after the first was set: both put back.
    let g = two.parameter("gravity.g").unwrap();
    let mut x = x0.clone();
    let r = minimize_continued_all(
        &mut newton(&two),
        &mut two,
        &mut x,
        &["gravity.g", "membrane.young"],
        &[-1.0],
    );
    assert!(matches!(r, Err(SolverError::Eval { .. })), "{r:?}");
    assert_eq!(x, x0);
    assert_eq!(two.parameter("gravity.g").unwrap(), g);
    assert_eq!(two.parameter("membrane.young").unwrap(), vec![5e9]);
}

/// Newton parameters with only a gradient tolerance (no step test) and room for 2 000 iterations.
fn gradient_only(tolerance: f64) -> NewtonParams {
    NewtonParams {
        gradient_tolerance: tolerance,
        step_tolerance: 0.0,
        max_iterations: 2000,
        ..NewtonParams::default()
    }
}

/// The stiff [`thin_strip`] at the equilibrium the membrane continuation reaches at 1e-8 N.
fn thin_strip_at_equilibrium() -> (System, Pins, Vec<Vector3<f64>>) {
    use hinge_solver::statics::{membrane_scales, minimize_continued};
    let (rest, mut sys, pins) = thin_strip();
    let scales = membrane_scales(&mut sys, &rest).unwrap();
    let mut x = rest.positions().to_vec();
    let mut newton = Newton::new(&sys, &pins, default_solver(), gradient_only(1e-8)).unwrap();
    minimize_continued(&mut newton, &mut sys, &mut x, "membrane.young", &scales).unwrap();
    (sys, pins, x)
}

/// A user's objective made of one term per dof: `F = c + Σ_d φ(t_d, b_d) + η(x)`, where `term(t, b)`
/// gives φ, φ′ and φ″ and `noise(x)` the part η of the energy that has no derivatives (a diagonal
/// Hessian; exact gradient and Hessian).
struct Separable {
    pattern: hinge_core::pattern::SymmetricPattern,
    b: Vec<f64>,
    constant: f64,
    term: fn(f64, f64) -> [f64; 3],
    noise: fn(&[Vector3<f64>]) -> f64,
}

impl Separable {
    fn new(n: usize, b: Vec<f64>, constant: f64, term: fn(f64, f64) -> [f64; 3]) -> Self {
        let pattern = hinge_core::pattern::SymmetricPattern::new(n, std::iter::empty()).unwrap();
        Self {
            pattern,
            b,
            constant,
            term,
            noise: |_| 0.0,
        }
    }
}

impl hinge_solver::newton::Objective for Separable {
    fn n_vertices(&self) -> usize {
        self.b.len() / 3
    }
    fn pattern(&self) -> &hinge_core::pattern::SymmetricPattern {
        &self.pattern
    }
    fn evaluate(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        out: &mut hinge_core::energy::SystemEvaluation,
    ) -> Result<(), hinge_core::EvalError> {
        let terms: Vec<[f64; 3]> = (0..self.b.len())
            .map(|d| (self.term)(x[d / 3][d % 3], self.b[d]))
            .collect();
        let energy = self.constant + terms.iter().map(|t| t[0]).sum::<f64>() + (self.noise)(x);
        out.energy = energy;
        out.terms = vec![energy];
        out.gradient = terms.iter().map(|t| t[1]).collect();
        if request.hessian {
            out.hessian = vec![0.0; self.pattern.nnz()];
            for v in 0..self.n_vertices() {
                let slot = self.pattern.find(v, v).expect("a diagonal block");
                let block = self.pattern.blocks()[slot];
                for c in 0..3 {
                    // The block's column c stores rows c, c+1, … from its offset: (c, c) first.
                    out.hessian[block.offset[c] as usize] = terms[3 * v + c][2];
                }
            }
        }
        Ok(())
    }
}

/// A user's objective whose energy carries noise above the old rounding allowance but whose gradient and
/// Hessian are exact: `F = 1 + Σ_dofs (t²/2 + t⁴/4 − b t) + η(x)`, `|η| ≤ 400ε` a deterministic hash of
/// the positions' bits (a sum of many rounded terms looks like that to the line search).
fn noisy_quartic(n: usize, b: Vec<f64>) -> Separable {
    let mut objective = Separable::new(n, b, 1.0, |t, b| {
        [
            0.5 * t.powi(2) + 0.25 * t.powi(4) - b * t,
            t + t.powi(3) - b,
            1.0 + 3.0 * t.powi(2),
        ]
    });
    objective.noise = |x| {
        let hash = x.iter().flat_map(|p| p.iter()).fold(0_u64, |h, v| {
            (h ^ v.to_bits()).wrapping_mul(0x9e37_79b9_7f4a_7c15)
        });
        400.0 * f64::EPSILON * ((hash >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0)
    };
    objective
}

/// Newton on [`noisy_quartic`] (exact derivatives, an energy whose values are noisy at 400ε, fifty times
/// the rounding allowance 8ε|F|) reaches a gradient of 1e-13 in a few iterations, at the solution found
/// independently: near it the full Newton steps change F by less than its noise, and a line search that
/// believed F's values would halve them against noise. (The line search before the slope test passes this
/// too, by luck of the noise's signs: the noise is symmetric, so half of the noisy trials look like
/// decreases; the stiff strip above is the case it failed.)
#[test]
fn newton_converges_on_an_objective_whose_energy_is_noisy_but_whose_gradient_is_exact() {
    let n = 40;
    let b: Vec<f64> = (0..3 * n)
        .map(|d| ((d * 7 % 11) as f64 - 5.0) * 0.3)
        .collect();
    let mut objective = noisy_quartic(n, b);
    let pins = Pins::new(n, Vec::new()).unwrap();
    let mut newton = Newton::new(
        &objective,
        &pins,
        hinge_solver::linear::default_solver(),
        gradient_only(1e-13),
    )
    .unwrap();
    let mut x = vec![Vector3::new(2.0, -1.5, 0.5); n];
    let stats = newton.minimize(&mut objective, &mut x, None).unwrap();
    let last = stats.gradient_norms.last().copied().unwrap();
    println!("{} iterations, ‖∇F‖ {last:e}", stats.iterations);
    assert!(last <= 1e-13 && stats.iterations <= 20, "{stats:?}");
    // The solution solves t + t³ = b dof by dof (checked by bisection, independently of Newton).
    for (d, &bd) in objective.b.iter().enumerate() {
        let (mut lo, mut hi) = (-3.0_f64, 3.0_f64);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if mid + mid.powi(3) < bd {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        assert!((x[d / 3][d % 3] - lo).abs() <= 1e-13, "dof {d}");
    }
}

/// A gradient tolerance below what F's rounding lets the gradient reach (a stiff thin strip asked for
/// 1e-15 N, no step test): the solve stops as stalled within a few iterations of reaching the floor instead
/// of crawling to the iteration limit, with the caller's positions untouched; with the tolerance the strip
/// can reach, the same solve converges.
#[test]
fn a_tolerance_below_the_rounding_floor_stalls_early() {
    use hinge_solver::newton::STALL_ITERATIONS;
    let (mut sys, pins, mut x) = thin_strip_at_equilibrium();
    let x0 = x.clone();
    let mut newton = Newton::new(&sys, &pins, default_solver(), gradient_only(1e-15)).unwrap();
    let err = newton.minimize(&mut sys, &mut x, None).unwrap_err();
    let stats = err.stats();
    println!("{err}");
    assert!(matches!(err, SolverError::Stalled { .. }), "{err}");
    assert!(err.to_string().contains("stalled after"), "{err}");
    assert!(
        stats.iterations >= STALL_ITERATIONS && stats.iterations < 100,
        "{}",
        stats.iterations
    );
    let floor = stats
        .gradient_norms
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    assert!(floor > 1e-15 && floor < 1e-7, "{floor}");
    assert_eq!(x, x0, "a failed solve leaves the positions untouched");
}

/// The line search judges trials within F's rounding by their slope (hinge_solver::newton, Rounding), so a
/// tolerance a little above the strip's rounding floor is reached: from the equilibrium at 1e-8 N, the
/// same strip as above asked for 5e-10 N converges. With F's value alone and the allowance `8ε|F|` (before
/// the slope test) the same solve stalled at 8.8e-10 N.
#[test]
fn a_tolerance_just_above_the_rounding_floor_is_reached() {
    let (mut sys, pins, mut x) = thin_strip_at_equilibrium();
    let mut newton = Newton::new(&sys, &pins, default_solver(), gradient_only(5e-10)).unwrap();
    let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
    let last = stats.gradient_norms.last().copied().unwrap();
    println!("{} iterations, ‖∇E‖ {last:e}", stats.iterations);
    assert!(last <= 5e-10, "{last}");
    // The gradient norm the solve reports is the gradient's: evaluated independently at the result.
    let mut out = sys
        .evaluate(&x, Request::GRADIENT, Parallelism::Sequential)
        .unwrap();
    for &p in pins.vertices() {
        for k in 0..3 {
            out.gradient[3 * p + k] = 0.0;
        }
    }
    let g = out.gradient.iter().map(|v| v * v).sum::<f64>().sqrt();
    assert!((g - last).abs() <= 1e-3 * last, "{g} vs {last}");
}

#[test]
fn membrane_continuation_matches_plain_newton_and_restores_the_parameter() {
    use hinge_solver::statics::{continued_start, membrane_scales, minimize_continued};
    let (rest, mut sys, pins) = thin_strip();
    let params = NewtonParams {
        gradient_tolerance: 1e-9,
        step_tolerance: 1e-14,
        max_iterations: 2000,
        ..NewtonParams::default()
    };
    let scales = membrane_scales(&mut sys, &rest).unwrap();
    assert!(!scales.is_empty(), "a thin shell gets stages");
    assert!(scales.windows(2).all(|w| w[0] < w[1]) && scales[scales.len() - 1] < 1.0);
    let solve = |sys: &mut System, scales: &[f64]| {
        let mut newton = Newton::new(sys, &pins, default_solver(), params.clone()).unwrap();
        let mut x = rest.positions().to_vec();
        let stats = minimize_continued(&mut newton, sys, &mut x, "membrane.young", scales).unwrap();
        (x, stats)
    };
    let (xc, sc) = solve(&mut sys, &scales);
    assert_eq!(
        sys.parameter("membrane.young").unwrap(),
        vec![1e10],
        "set back bitwise"
    );
    let (xp, sp) = solve(&mut sys, &[]);
    let drop = rest
        .positions()
        .iter()
        .zip(&xc)
        .map(|(a, b)| a.z - b.z)
        .fold(0.0, f64::max);
    assert!(drop > 0.02, "a large deflection: {drop}");
    let diff = xc
        .iter()
        .zip(&xp)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(diff <= 1e-8, "the same equilibrium: {diff}");
    assert!(
        2 * sc.iterations < sp.iterations,
        "{} vs {}",
        sc.iterations,
        sp.iterations
    );
    // Failures leave x and the parameter as they were: an unknown parameter, and a final solve that runs out
    // of iterations.
    let x0 = rest.positions().to_vec();
    let mut newton = Newton::new(&sys, &pins, default_solver(), params.clone()).unwrap();
    let mut x = x0.clone();
    assert!(minimize_continued(&mut newton, &mut sys, &mut x, "membrane.nope", &scales).is_err());
    assert_eq!(x, x0);
    let mut newton = Newton::new(
        &sys,
        &pins,
        default_solver(),
        NewtonParams {
            max_iterations: 2,
            ..params
        },
    )
    .unwrap();
    assert!(minimize_continued(&mut newton, &mut sys, &mut x, "membrane.young", &scales).is_err());
    assert_eq!(x, x0);
    assert_eq!(sys.parameter("membrane.young").unwrap(), vec![1e10]);
    // `continued_start`: the same failure leaves x where it was and reports the iterations it spent; no
    // scales, no work; success moves x to the continued equilibrium.
    let spent = continued_start(&mut newton, &mut sys, &mut x, "membrane.young", &scales);
    assert!(spent > 0 && x == x0, "{spent}");
    assert_eq!(
        continued_start(&mut newton, &mut sys, &mut x, "membrane.young", &[]),
        0
    );
    assert_eq!(x, x0);
    let mut newton = Newton::new(&sys, &pins, default_solver(), params.clone()).unwrap();
    assert_eq!(
        continued_start(&mut newton, &mut sys, &mut x, "membrane.young", &scales),
        sc.iterations
    );
    assert_eq!(x, xc);
    // Without stages the parameter is not needed: a system with no StVK membrane (here, the parameter name
    // is one no term has) is one plain Newton solve, bitwise the same as `Newton::minimize`.
    let mut newton = Newton::new(&sys, &pins, default_solver(), params.clone()).unwrap();
    let mut x = x0.clone();
    let st = minimize_continued(&mut newton, &mut sys, &mut x, "membrane.nope", &[]).unwrap();
    let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
    let mut y = x0.clone();
    let sp = newton.minimize(&mut sys, &mut y, None).unwrap();
    assert_eq!(x, y);
    assert_eq!(st.iterations, sp.iterations);
}

/// [`NewtonParams::remember_shift`]: a second solve of the same indefinite problem starts its shift ladder
/// near the shift the first one needed (fewer factorizations) and reaches the same equilibrium; switched
/// off, every solve repeats the first one exactly (history-independent).
#[test]
fn remembered_shift_saves_factorizations_and_off_is_history_independent() {
    let (mut sys, pins, start) = compressed_clamped_sheet();
    let mut solve_twice = |remember: bool| {
        let params = NewtonParams {
            gradient_tolerance: 1e-9,
            max_iterations: 500,
            remember_shift: remember,
            ..NewtonParams::default()
        };
        let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
        let mut runs = Vec::new();
        for _ in 0..2 {
            let mut x = start.clone();
            let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
            assert!(stats.gradient_norms.last().unwrap() <= &1e-9);
            assert!(
                stats.max_shift > 0.0,
                "the Hessian never needed a shift: no test"
            );
            runs.push((x, stats));
        }
        runs
    };
    let off = solve_twice(false);
    assert_eq!(
        off[0].0, off[1].0,
        "history-dependent without remember_shift"
    );
    assert_eq!(off[0].1.factorizations, off[1].1.factorizations);
    let on = solve_twice(true);
    // The first solve with the memory also remembers within the solve; the second starts near its shift.
    println!(
        "factorizations: off {} / {}, on {} / {}",
        off[0].1.factorizations,
        off[1].1.factorizations,
        on[0].1.factorizations,
        on[1].1.factorizations
    );
    assert!(on[1].1.factorizations < on[0].1.factorizations);
    for (x, _) in &on {
        let d = x
            .iter()
            .zip(&off[0].0)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(d <= 1e-6, "different equilibria: {d:e}");
    }
}

#[test]
fn a_step_whose_prediction_cannot_be_evaluated_starts_from_the_last_state() {
    use hinge_energies::contact::{Contact, Obstacle};
    // An irregular, renumbered sheet (z = 0) with springs and bending; one vertex moves straight down at
    // 2 m/s, so that x̂ = x + Δt v (Δt = 1/4: every number exact) lands exactly on a sphere's centre 0.5 m
    // below it, where the contact normal is undefined. The step must not fail for that: Newton starts from
    // x instead (before, the step failed and only its halves went through).
    let rest = hinge_core::shapes::irregular_sheet(7, 6, 3).unwrap();
    let n = rest.n_vertices();
    let k = (0..n)
        .min_by(|&a, &b| {
            let d = |v: usize| (rest.positions()[v] - Vector3::new(0.5, 0.5, 0.0)).norm();
            d(a).total_cmp(&d(b))
        })
        .unwrap();
    let x = rest.positions().to_vec();
    let centre = x[k] - Vector3::new(0.0, 0.0, 0.5);
    let system = || {
        let mut terms: Vec<Box<dyn Energy>> = vec![
            Box::new(MassSpring::new(&rest, 50.0).unwrap()),
            Box::new(HingeTerm::new(
                "bending",
                BendingModel::new(&rest, DiscreteShells { k: 0.01 }).unwrap(),
                Method::Refactored,
            )),
        ];
        terms.push(Box::new(
            Contact::new(
                n,
                Obstacle::Sphere {
                    center: centre,
                    radius: 0.3,
                },
                1e3,
                0.01,
            )
            .unwrap(),
        ));
        System::new(n, terms).unwrap()
    };
    let dt = 0.25;
    let mut v = vec![Vector3::zeros(); n];
    v[k] = Vector3::new(0.0, 0.0, -2.0);
    assert_eq!(x[k] + v[k] * dt, centre, "x̂ is the centre, bitwise");
    let masses = lumped_masses(&rest, 0.5);
    let pins = Pins::new(n, vec![]).unwrap();
    let mut sys = system();
    let x_hat: Vec<_> = x.iter().zip(&v).map(|(p, w)| p + w * dt).collect();
    let at_centre = sys
        .evaluate(&x_hat, Request::ALL, Parallelism::Sequential)
        .unwrap_err();
    assert!(
        at_centre.to_string().contains("sphere's centre"),
        "{at_centre}"
    );
    let mut stepper = ImplicitEuler::new(
        &sys,
        dt,
        masses.clone(),
        pins.clone(),
        Box::new(FaerLlt::default()),
        NewtonParams::default(),
    )
    .unwrap();
    let (mut x1, mut v1) = (x.clone(), v.clone());
    let fs = stepper
        .advance(&mut sys, &mut x1, &mut v1, SubstepPolicy::default())
        .unwrap();
    assert_eq!(
        (fs.substeps, fs.failed_attempts),
        (1, 0),
        "one step, no halving"
    );
    // Independently: Newton on the same incremental potential, started at x.
    let mut reference = system();
    let mut newton = Newton::new(
        &reference,
        &pins,
        Box::new(FaerLlt::default()),
        NewtonParams::default(),
    )
    .unwrap();
    let inertia = Inertia { masses, x_hat, dt };
    let mut y = x.clone();
    let stats = newton
        .minimize(&mut reference, &mut y, Some(&inertia))
        .unwrap();
    assert_eq!(x1, y, "the step from x, bitwise");
    assert_eq!(fs.newton.iterations, stats.iterations);
    assert!(fs.max_final_gradient_norm <= NewtonParams::default().gradient_tolerance);
    // The vertex moved down, held back by its springs, short of the sphere (its top is 0.2 m below);
    // v = (x1 − x)/Δt.
    let clearance = (x1[k] - centre).norm() - 0.3;
    assert!(
        x1[k].z < x[k].z - 0.01 && clearance > 0.1,
        "z {} clearance {clearance}",
        x1[k].z
    );
    for i in 0..n {
        assert_eq!(v1[i], (x1[i] - x[i]) / dt);
    }
}

/// A membrane whose Young's modulus is finite but whose Hessian overflows f64 (1e308 Pa on an irregular,
/// renumbered sheet): `System::evaluate` fails instead of returning the non-finite values, naming the
/// membrane (the second term: the bending before it is finite) and a vertex whose Hessian row holds a
/// non-finite value (checked against the membrane's own output, assembled by hand); `check_finite` says
/// the same of that output; Newton fails with that error before any factorization (before, it reached the
/// factorization and reported "linear solve failed (shift inf)").
#[test]
fn derivatives_that_overflow_are_named_by_term_and_vertex() {
    use hinge_core::EvalError;
    use hinge_core::energy::{Accumulator, SystemEvaluation};
    use hinge_core::error::ElementRef;
    use hinge_energies::membrane::StvkMembrane;
    let rest = hinge_core::shapes::irregular_sheet(8, 7, 12).unwrap();
    let x: Vec<Vector3<f64>> = rest
        .positions()
        .iter()
        .map(|p| Vector3::new(p.x, p.y, 0.05 * (4.0 * p.x).sin() * p.y))
        .collect();
    let system = |young: f64| {
        let bending = BendingModel::new(&rest, DiscreteShells { k: 0.01 }).unwrap();
        let terms: Vec<Box<dyn Energy>> = vec![
            Box::new(HingeTerm::new("bending", bending, Method::Refactored)),
            Box::new(StvkMembrane::new(&rest, young, 0.3, 5e-4).unwrap()),
        ];
        System::new(rest.n_vertices(), terms).unwrap()
    };
    // Finite: the evaluation succeeds.
    let mut fine = system(1e305);
    let out = fine
        .evaluate(&x, Request::ALL, Parallelism::Sequential)
        .unwrap();
    assert!(out.hessian.iter().all(|v| v.is_finite()));
    fine.check_finite(&x, Request::ALL, Parallelism::Sequential, &out)
        .unwrap();
    let mut sys = system(1e308);
    let e = sys
        .evaluate(&x, Request::ALL, Parallelism::Sequential)
        .unwrap_err();
    let EvalError::AtElement {
        energy,
        element: ElementRef::Vertex(v),
        ..
    } = &e
    else {
        panic!("{e}");
    };
    assert_eq!(energy, "membrane", "{e}");
    // The membrane's own output at the system's pattern, assembled outside the system.
    let pattern = std::sync::Arc::new(sys.pattern().clone());
    let mut membrane = StvkMembrane::new(&rest, 1e308, 0.3, 5e-4).unwrap();
    membrane.bind(&pattern).unwrap();
    let mut out = SystemEvaluation {
        energy: 0.0,
        terms: vec![0.0; 2],
        gradient: vec![0.0; 3 * rest.n_vertices()],
        hessian: vec![0.0; pattern.nnz()],
    };
    let mut acc = Accumulator::of(&pattern, Request::ALL, &mut out.gradient, &mut out.hessian);
    out.energy = membrane
        .add_to(&x, Request::ALL, Parallelism::Sequential, &mut acc)
        .unwrap();
    assert!(
        out.hessian.iter().any(|v| !v.is_finite()),
        "the overflow this test needs"
    );
    assert_eq!(
        sys.check_finite(&x, Request::ALL, Parallelism::Sequential, &out)
            .unwrap_err(),
        e
    );
    // The named vertex is one of the two of a non-finite stored value (column by column through the CSC).
    let p = &*pattern;
    let (cp, ri) = (p.col_ptr(), p.row_idx());
    let touches = (0..p.dim()).any(|j| {
        (cp[j]..cp[j + 1]).any(|k| {
            !out.hessian[k].is_finite()
                && (p.caller_dof(ri[k]) / 3 == *v || p.caller_dof(j) / 3 == *v)
        })
    });
    assert!(touches, "{e}");
    // Newton: the same error, no factorization.
    let pins = Pins::new(rest.n_vertices(), vec![0]).unwrap();
    let mut newton = Newton::new(
        &sys,
        &pins,
        Box::new(FaerLlt::default()),
        NewtonParams::default(),
    )
    .unwrap();
    let mut y = x.clone();
    let err = newton.minimize(&mut sys, &mut y, None).unwrap_err();
    let SolverError::Eval { source, stats } = &err else {
        panic!("{err}");
    };
    assert_eq!(source, &e);
    assert_eq!(stats.factorizations, 0);
    assert_eq!(y, x, "state untouched");
}

/// `System` as an objective that raises a stop flag when it is evaluated for the `at`-th time (a Ctrl-C
/// arriving mid-solve, deterministically).
struct RaisesStop<'a> {
    system: &'a mut System,
    flag: std::sync::Arc<std::sync::atomic::AtomicBool>,
    evaluations: usize,
    at: usize,
}

impl hinge_solver::newton::Objective for RaisesStop<'_> {
    fn n_vertices(&self) -> usize {
        self.system.n_vertices()
    }
    fn pattern(&self) -> &hinge_core::pattern::SymmetricPattern {
        self.system.pattern()
    }
    fn evaluate(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        out: &mut hinge_core::energy::SystemEvaluation,
    ) -> Result<(), hinge_core::EvalError> {
        self.evaluations += 1;
        if self.evaluations == self.at {
            self.flag.store(true, std::sync::atomic::Ordering::SeqCst);
        }
        hinge_solver::newton::Objective::evaluate(self.system, x, request, out)
    }
}

/// A Newton observer sees every accepted iteration: its count, F and ‖∇F‖ at the new iterate and the step
/// (the entries the statistics record, bitwise), ending at the minimiser's energy evaluated anew; and it
/// changes nothing: the same iterates with and without it, and in an implicit Euler step F includes the
/// inertia term.
#[test]
fn a_newton_observer_sees_each_accepted_iteration_and_changes_nothing() {
    use hinge_solver::newton::IterationReport;
    use std::sync::{Arc, Mutex};
    let (rest, mut sys, pins) = thin_strip();
    let params = NewtonParams {
        gradient_tolerance: 1e-9,
        max_iterations: 2000,
        ..NewtonParams::default()
    };
    let mut plain = Newton::new(&sys, &pins, default_solver(), params.clone()).unwrap();
    let mut reference = rest.positions().to_vec();
    let full = plain.minimize(&mut sys, &mut reference, None).unwrap();
    let seen: Arc<Mutex<Vec<IterationReport>>> = Arc::default();
    let sink = seen.clone();
    let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
    newton.set_observer(Some(Box::new(move |r: &IterationReport| {
        sink.lock().unwrap().push(*r)
    })));
    let mut x = rest.positions().to_vec();
    let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
    assert_eq!((stats.iterations, &x), (full.iterations, &reference));
    let seen = seen.lock().unwrap().clone();
    assert_eq!(seen.len(), stats.iterations);
    // Damped steps on the way, full ones at the end; no shift beyond the largest the statistics record.
    assert!(seen.iter().any(|r| r.step_length < 1.0));
    assert_eq!(seen.last().unwrap().step_length, 1.0);
    assert!(seen.iter().all(|r| r.shift <= stats.max_shift));
    for (k, r) in seen.iter().enumerate() {
        assert_eq!(r.iteration, k + 1);
        assert_eq!(
            r.gradient_norm.to_bits(),
            stats.gradient_norms[k + 1].to_bits()
        );
        assert_eq!(r.step_norm.to_bits(), stats.step_norms[k].to_bits());
        assert!(r.step_length > 0.0 && !r.definite && r.stage.is_none());
    }
    let start = sys
        .evaluate(rest.positions(), Request::VALUE, Parallelism::Sequential)
        .unwrap()
        .energy;
    let end = sys
        .evaluate(&x, Request::VALUE, Parallelism::Sequential)
        .unwrap()
        .energy;
    let last = seen.last().unwrap().energy;
    assert!((last - end).abs() <= 1e-12 * end.abs(), "{last} vs {end}");
    assert!(end < start && seen.iter().all(|r| r.energy < start));
    // A time step: F = E + the inertia term ‖x − x̂‖²_M / (2Δt²) > E at the step's end.
    let (mut hs, mut stepper, mut y, mut v) = hard_stepper(20, 0.05);
    let energies: Arc<Mutex<Vec<f64>>> = Arc::default();
    let sink = energies.clone();
    stepper
        .newton_mut()
        .set_observer(Some(Box::new(move |r: &IterationReport| {
            sink.lock().unwrap().push(r.energy)
        })));
    let (mut hs2, mut twin, mut y2, mut v2) = hard_stepper(20, 0.05);
    let frame = stepper
        .advance(&mut hs, &mut y, &mut v, SubstepPolicy::default())
        .unwrap();
    twin.advance(&mut hs2, &mut y2, &mut v2, SubstepPolicy::default())
        .unwrap();
    assert_eq!((&y, &v), (&y2, &v2));
    let energies = energies.lock().unwrap().clone();
    assert_eq!(energies.len(), frame.newton.iterations);
    let e_end = hs
        .evaluate(&y, Request::VALUE, Parallelism::Sequential)
        .unwrap()
        .energy;
    assert!(*energies.last().unwrap() > e_end, "{energies:?} vs {e_end}");
}

/// A stop flag ends a solve before its next iteration with the positions untouched and the work counted
/// (raised mid-solve by the objective itself); a frame of implicit Euler is abandoned at once, without
/// smaller substeps, its state restored; a continuation ends with every stage's count and the parameter
/// set back. A huge iteration budget (any `usize`) neither aborts on its preallocation nor changes the
/// result of a solve that converges.
#[test]
fn a_raised_stop_flag_ends_solves_and_frames_with_the_state_untouched() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let (rest, mut sys, pins) = thin_strip();
    let params = NewtonParams {
        gradient_tolerance: 1e-9,
        max_iterations: 2000,
        ..NewtonParams::default()
    };
    // The reference: the same solve without a flag takes many iterations.
    let mut newton = Newton::new(&sys, &pins, default_solver(), params.clone()).unwrap();
    let mut reference = rest.positions().to_vec();
    let full = newton.minimize(&mut sys, &mut reference, None).unwrap();
    assert!(full.iterations > 10, "{}", full.iterations);
    // Raised at the fifth evaluation: the solve stops within an iteration of it.
    let flag = Arc::new(AtomicBool::new(false));
    let mut newton = Newton::new(&sys, &pins, default_solver(), params.clone()).unwrap();
    newton.set_stop(Some(flag.clone()));
    let mut x = rest.positions().to_vec();
    let mut objective = RaisesStop {
        system: &mut sys,
        flag: flag.clone(),
        evaluations: 0,
        at: 5,
    };
    let err = newton.minimize(&mut objective, &mut x, None).unwrap_err();
    let SolverError::Interrupted { stats } = &err else {
        panic!("{err}")
    };
    assert!(
        (1..=5).contains(&stats.iterations) && stats.iterations < full.iterations,
        "{}",
        stats.iterations
    );
    assert!(stats.factorizations >= stats.iterations);
    assert_eq!(err.stats().iterations, stats.iterations);
    assert!(err.to_string().starts_with("interrupted after"), "{err}");
    assert_eq!(x, rest.positions(), "positions untouched");
    // Lowered again, the same solver finishes the job exactly as a fresh one does.
    flag.store(false, Ordering::SeqCst);
    let again = newton.minimize(&mut sys, &mut x, None).unwrap();
    assert!(again.iterations > 0);
    // Continuation: a raised flag ends it at the first stage, the parameter back bitwise.
    use hinge_solver::statics::{membrane_scales, minimize_continued};
    let scales = membrane_scales(&mut sys, &rest).unwrap();
    assert!(!scales.is_empty());
    flag.store(true, Ordering::SeqCst);
    let mut y = rest.positions().to_vec();
    let err =
        minimize_continued(&mut newton, &mut sys, &mut y, "membrane.young", &scales).unwrap_err();
    assert!(matches!(err, SolverError::Interrupted { .. }), "{err}");
    assert_eq!(y, rest.positions());
    assert_eq!(sys.parameter("membrane.young").unwrap(), vec![1e10]);
    // Implicit Euler: a raised flag fails the frame at once (no substeps), state and time restored.
    let (mut hs, mut stepper, mut x, mut v) = hard_stepper(20, 0.25);
    let (x0, v0) = (x.clone(), v.clone());
    stepper.newton_mut().set_stop(Some(flag.clone()));
    let err = stepper
        .advance(&mut hs, &mut x, &mut v, SubstepPolicy::default())
        .unwrap_err();
    assert!(matches!(err, SolverError::Interrupted { .. }), "{err}");
    assert_eq!((&x, &v), (&x0, &v0));
    assert_eq!(stepper.time(), 0.0);
    // And with the flag down it takes the same frame as a stepper that never had one.
    flag.store(false, Ordering::SeqCst);
    let (mut hs2, mut plain, mut x2, mut v2) = hard_stepper(20, 0.25);
    let a = stepper
        .advance(&mut hs, &mut x, &mut v, SubstepPolicy::default())
        .unwrap();
    let b = plain
        .advance(&mut hs2, &mut x2, &mut v2, SubstepPolicy::default())
        .unwrap();
    assert_eq!(
        (a.newton.iterations, &x, &v),
        (b.newton.iterations, &x2, &v2)
    );
    // The largest budget there is: no 2⁶⁴-entry preallocation, the same result as a budget of 2000.
    let mut huge = Newton::new(
        &sys,
        &pins,
        default_solver(),
        NewtonParams {
            max_iterations: usize::MAX,
            ..params
        },
    )
    .unwrap();
    let mut z = rest.positions().to_vec();
    let st = huge.minimize(&mut sys, &mut z, None).unwrap();
    assert_eq!((st.iterations, &z), (full.iterations, &reference));
}

/// A step test that ends a time step's solve after a step that still moves the positions is accepted
/// above the gradient tolerance, as before `SolverError::Stuck` (a stiff beam's solves end that way at
/// the rounding floor of its gradient); the same step with the default tolerances converges. The stuck
/// test itself: `newton::tests::only_a_solve_that_cannot_move_and_has_not_converged_is_stuck`.
#[test]
fn a_step_test_on_a_step_that_moves_ends_a_time_step_as_before() {
    let (mut sys, mut stepper, mut x, mut v) = hard_stepper(50, 0.05);
    let tolerance = stepper.newton().params.gradient_tolerance;
    let solved = stepper.step(&mut sys, &mut x, &mut v).unwrap();
    assert!(*solved.gradient_norms.last().unwrap() <= tolerance);
    let (mut sys, mut loose, mut y, mut w) = hard_stepper(50, 0.05);
    loose.newton_mut().params.step_tolerance = 1.0;
    let early = loose.step(&mut sys, &mut y, &mut w).unwrap();
    assert!(
        *early.gradient_norms.last().unwrap() > 1e3 * tolerance
            && early.iterations < solved.iterations,
        "{early:?}"
    );
}

/// The slot of vertex 0's diagonal block (the test energies below act on vertex 0 alone).
fn vertex0_block(
    pattern: &hinge_core::pattern::SymmetricPattern,
) -> Result<usize, hinge_core::EvalError> {
    pattern.find(0, 0).ok_or(hinge_core::EvalError::Pattern {
        message: "no diagonal block".into(),
    })
}

/// The value, gradient and Hessian block of a one-vertex test energy at the vertex's position, or why it
/// cannot be evaluated there.
type VertexLocal = Result<(f64, Vector3<f64>, Matrix3<f64>), String>;

/// A test energy of vertex 0 alone (the one-vertex energies below), from a closure that gives its value,
/// gradient and Hessian block at vertex 0's position; an `Err` is returned as an evaluation error.
struct OnVertex0 {
    name: &'static str,
    local: Box<dyn Fn(Vector3<f64>) -> VertexLocal + Send + Sync>,
    diag: usize,
}

impl OnVertex0 {
    fn new(
        name: &'static str,
        local: impl Fn(Vector3<f64>) -> VertexLocal + Send + Sync + 'static,
    ) -> Self {
        OnVertex0 {
            name,
            local: Box::new(local),
            diag: 0,
        }
    }
}

impl Energy for OnVertex0 {
    fn name(&self) -> &str {
        self.name
    }
    fn n_vertices(&self) -> usize {
        1
    }
    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}
    fn bind(
        &mut self,
        pattern: &std::sync::Arc<hinge_core::pattern::SymmetricPattern>,
    ) -> Result<(), hinge_core::EvalError> {
        self.diag = vertex0_block(pattern)?;
        Ok(())
    }
    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut hinge_core::energy::Accumulator,
    ) -> Result<f64, hinge_core::EvalError> {
        let (e, g, h) =
            (self.local)(x[0]).map_err(|message| hinge_core::EvalError::Pattern { message })?;
        acc.add_gradient(0, &g);
        if request.hessian {
            acc.add_block(self.diag, 0, 0, &h);
        }
        Ok(e)
    }
}

/// One vertex on a kink with a saddle: `E = c₀ + k |x| − ½ a y²` (a gradient of k = 1e4 N that no step
/// lowers, like a triangle collapsing under a bending energy's 1/h gradient; a concave direction of
/// curvature −a = −1e16 N/m, so every factorization needs a shift above a; and a constant c₀ = 1e12 J, so
/// F's rounding allowance is 2e-3 J).
fn kink() -> OnVertex0 {
    let (k, a) = (1e4, 1e16);
    OnVertex0::new("kink", move |p| {
        Ok((
            1e12 + k * p.x.abs() - 0.5 * a * p.y * p.y,
            Vector3::new(k * p.x.signum(), -a * p.y, 0.0),
            Matrix3::from_diagonal(&Vector3::new(0.0, -a, 0.0)),
        ))
    })
}

/// A shifted direction whose predicted decrease is below F's rounding does not end a solve on the step
/// test (hinge_solver::newton, Stopping): on the [`kink`] the shift climbs above 1e16, the shifted step is
/// 1e-12 m and predicts a decrease of 1e-8 J, below F's rounding of 2e-3 J. That once returned the solve
/// as converged at ‖∇F‖ = 1e4 N (a public closed mesh accepted a frame at 4e3 N that way); it now fails
/// as stalled, leaving the positions untouched.
#[test]
fn a_shifted_step_below_the_rounding_does_not_end_a_solve() {
    let mut sys = System::new(1, vec![Box::new(kink())]).unwrap();
    let pins = Pins::new(1, Vec::new()).unwrap();
    let params = NewtonParams {
        gradient_tolerance: 1e-6,
        max_iterations: 200,
        ..NewtonParams::default()
    };
    let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
    let mut x = vec![Vector3::new(1.0, 0.0, 0.0)];
    let x0 = x.clone();
    let err = newton.minimize(&mut sys, &mut x, None).unwrap_err();
    println!("{err}");
    let stats = err.stats();
    println!(
        "max shift {:e}, steps {:?}, gradients {:?}",
        stats.max_shift,
        &stats.step_norms[..stats.step_norms.len().min(12)],
        &stats.gradient_norms[..stats.gradient_norms.len().min(12)]
    );
    assert!(stats.max_shift > 1e16, "{}", stats.max_shift);
    assert!(
        stats.step_norms.iter().all(|&s| s <= 1e-12),
        "{:?}",
        stats.step_norms
    );
    assert!(matches!(err, SolverError::Stalled { .. }), "{err}");
    assert_eq!(x, x0);
}

/// A vertex attracted by `k ln |x − c|` towards the point `c` (force `k/r`, unbounded below at `c`): the
/// incremental potential `m (r − r̂)²/(2Δt²) + k ln r` along the radius has a local minimum near the
/// prediction's distance `r̂` only when `r̂² ≥ 4 k Δt²/m`. Without it Newton follows the energy into the
/// singularity with ever shorter steps and an ever larger gradient, as on a triangle collapsing under a
/// bending energy (`docs/shells/closed_meshes.py`'s lumpy shell, frame 28).
fn attractor(centre: Vector3<f64>, k: f64) -> OnVertex0 {
    OnVertex0::new("attractor", move |p| {
        let d = p - centre;
        let r2 = d.norm_squared();
        if !(r2 > 0.0) {
            return Err("vertex 0 on the attractor".into());
        }
        let h = (Matrix3::identity() - d * d.transpose() * (2.0 / r2)) * (k / r2);
        Ok((0.5 * k * r2.ln(), d * (k / r2), h))
    })
}

/// One vertex of mass 1 passing the attractor at `b` = 2 cm (m = 1, k = 0.02, Δt = 0.1 s, speed 2 m/s, so
/// that the full step's prediction is the point of closest approach), with the stepper.
fn fly_by() -> (System, ImplicitEuler, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let centre = Vector3::new(1.0, 0.0, 0.0);
    let sys = System::new(1, vec![Box::new(attractor(centre, 0.02))]).unwrap();
    let stepper = ImplicitEuler::new(
        &sys,
        0.1,
        vec![1.0],
        Pins::new(1, Vec::new()).unwrap(),
        Box::new(FaerLlt::default()),
        NewtonParams {
            max_iterations: 200,
            ..NewtonParams::default()
        },
    )
    .unwrap();
    let x = vec![centre + Vector3::new(0.02, 0.2, 0.0)];
    let v = vec![Vector3::new(0.0, -2.0, 0.0)];
    (sys, stepper, x, v)
}

/// A time step whose solve runs into a singularity fails, leaving the state untouched (the solver's too:
/// the same step fails the same way again), and `advance` retries it in substeps, each with a local
/// minimum near its prediction: the frame is accepted, every accepted substep converged, and the vertex
/// never came near the attractor. The full step's solve crawls with shifted steps (shifts up to 4e30, steps
/// down to 4e-17 m) while ‖∇F‖ grows to 1.8e14 N and ends as [`SolverError::Stalled`]; a solve that ends
/// on the step test with exact steps there ends as [`SolverError::Stuck`] (the lumpy shell; the rule is
/// tested in `newton::tests`). Both are retried alike.
#[test]
fn a_step_collapsing_into_a_singularity_fails_and_is_retried_in_substeps() {
    let (mut sys, mut stepper, mut x, mut v) = fly_by();
    let (x0, v0) = (x.clone(), v.clone());
    let err = stepper.step(&mut sys, &mut x, &mut v).unwrap_err();
    println!("full step: {err}");
    assert!(
        matches!(err, SolverError::Stuck { .. } | SolverError::Stalled { .. }),
        "{err}"
    );
    assert_eq!((&x, &v, stepper.time()), (&x0, &v0, 0.0));
    // Nothing of the failed attempt stays behind, in the solver either (the shift its ladder climbed to):
    // the same step fails the same way.
    let again = stepper.step(&mut sys, &mut x, &mut v).unwrap_err();
    assert_eq!(again.to_string(), err.to_string());
    assert_eq!(again.stats().iterations, err.stats().iterations);
    let frame = stepper
        .advance(&mut sys, &mut x, &mut v, SubstepPolicy::default())
        .unwrap();
    println!("{frame:?}");
    assert!(
        frame.failed_attempts >= 1 && frame.substeps >= 2,
        "{frame:?}"
    );
    assert!(frame.max_final_gradient_norm <= stepper.newton().params.gradient_tolerance);
    let r = (x[0] - Vector3::new(1.0, 0.0, 0.0)).norm();
    assert!(r > 0.01, "the vertex ended {r} m from the attractor");
    assert!((stepper.time() - 0.1).abs() < 1e-15);
}

/// Vertex 0 in the radial double well `s (q r⁴/4 − c r²/2)` around the origin (concave near it: a solve
/// from there needs a shifted Hessian), and a switch: evaluation fails once vertex 1 (pinned, moved by a
/// `PinMotion`) is beyond `x = 0.75`, or the parameter `scale` (`s`) beyond 1.5.
struct SwitchedWell {
    c: f64,
    q: f64,
    s: f64,
    diag: usize,
}

/// The system of one [`SwitchedWell`] (c = 1000, q = 1e5: a well 0.1 m from the origin) at scale `s`.
fn switched_well(s: f64) -> System {
    let well = SwitchedWell {
        c: 1000.0,
        q: 1e5,
        s,
        diag: 0,
    };
    System::new(2, vec![Box::new(well)]).unwrap()
}

impl Energy for SwitchedWell {
    fn name(&self) -> &str {
        "switched well"
    }
    fn n_vertices(&self) -> usize {
        2
    }
    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}
    fn parameters(&self) -> Vec<hinge_core::energy::Parameter> {
        vec![hinge_core::energy::Parameter {
            name: "scale".into(),
            len: 1,
        }]
    }
    fn parameter(&self, name: &str) -> Result<Vec<f64>, hinge_core::EvalError> {
        match name {
            "scale" => Ok(vec![self.s]),
            _ => Err(hinge_core::EvalError::Pattern {
                message: format!("no parameter {name}"),
            }),
        }
    }
    fn set_parameter(&mut self, name: &str, values: &[f64]) -> Result<(), hinge_core::EvalError> {
        match (name, values) {
            ("scale", &[s]) => {
                self.s = s;
                Ok(())
            }
            _ => Err(hinge_core::EvalError::Pattern {
                message: format!("no parameter {name} of {} values", values.len()),
            }),
        }
    }
    fn bind(
        &mut self,
        pattern: &std::sync::Arc<hinge_core::pattern::SymmetricPattern>,
    ) -> Result<(), hinge_core::EvalError> {
        self.diag = vertex0_block(pattern)?;
        Ok(())
    }
    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut hinge_core::energy::Accumulator,
    ) -> Result<f64, hinge_core::EvalError> {
        if x[1].x > 0.75 || self.s > 1.5 {
            return Err(hinge_core::EvalError::Pattern {
                message: "the switch is off".into(),
            });
        }
        let (p, s) = (x[0], self.s);
        let r2 = p.norm_squared();
        acc.add_gradient(0, &(p * (s * (self.q * r2 - self.c))));
        if request.hessian {
            let h = Matrix3::identity() * (s * (self.q * r2 - self.c))
                + p * p.transpose() * (2.0 * s * self.q);
            acc.add_block(self.diag, 0, 0, &h);
        }
        Ok(s * (0.25 * self.q * r2 * r2 - 0.5 * self.c * r2))
    }
}

/// A frame that fails after an accepted substep leaves nothing behind, in the Newton solver either: its
/// first half step (from the top of the double well) needs a shifted Hessian, which the shift memory
/// ([`NewtonParams::remember_shift`]) keeps, and its second fails at the floor (`max_halvings = 1`) when the
/// switch's pin passes 0.75. After that, the stepper takes a frame exactly (positions, velocities,
/// factorizations, iterations) as a stepper that never saw the failed frame.
#[test]
fn a_frame_that_fails_after_a_shifted_substep_leaves_the_solver_as_it_was() {
    let setup = |dt: f64| {
        let sys = switched_well(1.0);
        let stepper = ImplicitEuler::new(
            &sys,
            dt,
            vec![1.0, 1.0],
            Pins::new(2, vec![1]).unwrap(),
            Box::new(FaerLlt::default()),
            NewtonParams::default(),
        )
        .unwrap();
        let x = vec![Vector3::new(0.001, 0.0002, 0.0), Vector3::zeros()];
        let v = vec![Vector3::zeros(); 2];
        (sys, stepper, x, v)
    };
    let policy = SubstepPolicy { max_halvings: 1 };
    // The switch's pin goes to x = fraction · reach.
    let motion =
        |reach: f64| move |fraction: f64, y: &mut [Vector3<f64>]| y[1].x = fraction * reach;
    let (mut sys, mut stepper, mut x, mut v) = setup(0.1);
    let (x0, v0) = (x.clone(), v.clone());
    let err = stepper
        .advance_with(&mut sys, &mut x, &mut v, policy, Some(&motion(1.0)))
        .unwrap_err();
    assert!(matches!(err, SolverError::Eval { .. }), "{err}");
    assert_eq!((&x, &v, stepper.time()), (&x0, &v0, 0.0));
    // The failed frame's first half step was accepted and shifted: the same half step on its own, in a
    // fresh stepper, factors more than once per iteration.
    let (mut sys_h, mut half, mut xh, mut vh) = setup(0.05);
    let first = half
        .advance_with(
            &mut sys_h,
            &mut xh,
            &mut vh,
            SubstepPolicy { max_halvings: 0 },
            Some(&motion(0.5)),
        )
        .unwrap();
    assert!(
        first.newton.factorizations > first.newton.iterations,
        "{first:?}"
    );
    // The next frame, with the switch staying on, against a stepper that never failed.
    let (mut sys2, mut fresh, mut x2, mut v2) = setup(0.1);
    let a = stepper
        .advance_with(&mut sys, &mut x, &mut v, policy, Some(&motion(0.7)))
        .unwrap();
    let b = fresh
        .advance_with(&mut sys2, &mut x2, &mut v2, policy, Some(&motion(0.7)))
        .unwrap();
    assert_eq!(
        (
            a.newton.iterations,
            a.newton.factorizations,
            a.substeps,
            &x,
            &v
        ),
        (
            b.newton.iterations,
            b.newton.factorizations,
            b.substeps,
            &x2,
            &v2
        )
    );
}

/// A continuation whose last solve fails after a shifted stage leaves nothing behind either: the stage at
/// half the scale (2 → 1) starts on the top of the double well (a shifted Hessian, which the shift memory
/// keeps), the final solve at the full scale fails (the switch). After that, a solve takes exactly the iterations,
/// factorizations and result of a Newton solver that never saw the failed continuation.
#[test]
fn a_continuation_that_fails_after_a_shifted_stage_leaves_the_solver_as_it_was() {
    let setup = || {
        let sys = switched_well(2.0);
        let newton = Newton::new(
            &sys,
            &Pins::new(2, vec![1]).unwrap(),
            Box::new(FaerLlt::default()),
            NewtonParams::default(),
        )
        .unwrap();
        (sys, newton)
    };
    let x0 = vec![Vector3::new(0.001, 0.0002, 0.0), Vector3::zeros()];
    let (mut sys, mut newton) = setup();
    let mut x = x0.clone();
    let err = hinge_solver::statics::minimize_continued(
        &mut newton,
        &mut sys,
        &mut x,
        "switched well.scale",
        &[0.5],
    )
    .unwrap_err();
    assert!(matches!(err, SolverError::Eval { .. }), "{err}");
    assert_eq!(x, x0);
    assert_eq!(sys.parameter("switched well.scale").unwrap(), [2.0]);
    // Its stage at half the scale, on its own in a fresh solver, is shifted.
    let (mut sys_h, mut half) = setup();
    sys_h.set_parameter("switched well.scale", &[1.0]).unwrap();
    let mut xh = x0.clone();
    let stage = half.minimize(&mut sys_h, &mut xh, None).unwrap();
    assert!(stage.factorizations > stage.iterations, "{stage:?}");
    // A solve at a scale the switch admits, against a solver that never failed.
    let (mut sys2, mut fresh) = setup();
    sys.set_parameter("switched well.scale", &[1.2]).unwrap();
    sys2.set_parameter("switched well.scale", &[1.2]).unwrap();
    let mut x2 = x0.clone();
    let a = newton.minimize(&mut sys, &mut x, None).unwrap();
    let b = fresh.minimize(&mut sys2, &mut x2, None).unwrap();
    assert_eq!(
        (a.iterations, a.factorizations, &x),
        (b.iterations, b.factorizations, &x2)
    );
}

/// A separable convex objective with a strong third derivative: `F = Σ_dofs (eᵗ − b t)`, minimum at
/// `t = ln b`; per dof `∇F = eᵗ − b`, `H = eᵗ`, `∇³F = eᵗ`.
fn exp_sum(n: usize, b: Vec<f64>) -> Separable {
    Separable::new(n, b, 0.0, |t, b| [t.exp() - b * t, t.exp() - b, t.exp()])
}

/// Geodesic acceleration ([`NewtonParams::geodesic_acceleration`]) on [`exp_sum`] from `t = 0`: the first
/// step is the Newton step `d = b − 1` corrected by `a/2`, with `a` the finite-difference formula of
/// `Newton::accelerate` in closed form, `a = −2/h² (e^{hd} − 1 − hd)` per dof (h = 0.1), which tends to
/// Chebyshev's exact `−d²` as h → 0: the reported step length matches the closed form to rounding, and
/// `a` is within O(h) of the exact third-order term. The solve ends at `ln b` (independent closed form)
/// in fewer iterations than plain Newton, whose first step is `d` itself.
#[test]
fn geodesic_acceleration_corrects_the_newton_step_by_the_third_derivative() {
    use std::sync::{Arc, Mutex};
    let n = 10;
    let b: Vec<f64> = (0..3 * n)
        .map(|d| 1.2 + 0.6 * ((d * 7 % 11) as f64 / 10.0))
        .collect();
    let h = 0.1;
    let closed_form = |accelerate: bool| {
        b.iter()
            .map(|&bd| {
                let d = bd - 1.0;
                let a = -2.0 / (h * h) * ((h * d).exp_m1() - h * d);
                // The finite-difference term is the exact one, −d², up to O(h d) relative.
                assert!(
                    (a + d * d).abs() <= 0.05 * d * d * d.abs() + 1e-15,
                    "{a} {d}"
                );
                let s = if accelerate { d + 0.5 * a } else { d };
                s * s
            })
            .sum::<f64>()
            .sqrt()
    };
    let mut counts = Vec::new();
    for accelerate in [true, false] {
        let mut objective = exp_sum(n, b.clone());
        let pins = Pins::new(n, Vec::new()).unwrap();
        let params = NewtonParams {
            geodesic_acceleration: accelerate,
            ..gradient_only(1e-12)
        };
        let mut newton = Newton::new(&objective, &pins, default_solver(), params).unwrap();
        let reports = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&reports);
        newton.set_observer(Some(Box::new(move |r| {
            sink.lock()
                .unwrap()
                .push((r.step_norm, r.step_length, r.accelerated));
        })));
        let mut x = vec![Vector3::zeros(); n];
        let stats = newton.minimize(&mut objective, &mut x, None).unwrap();
        let reports = reports.lock().unwrap();
        let (step, alpha, accelerated) = reports[0];
        let expected = closed_form(accelerate);
        assert!(
            alpha == 1.0
                && accelerated == accelerate
                && (step - expected).abs() <= 1e-12 * expected,
            "{accelerate}: first step {step} (α {alpha}, accelerated {accelerated}), closed form {expected}"
        );
        assert_eq!(
            stats.accelerated_iterations,
            reports.iter().filter(|r| r.2).count()
        );
        assert_eq!(stats.accelerated_iterations > 0, accelerate);
        for (d, &bd) in b.iter().enumerate() {
            assert!((x[d / 3][d % 3] - bd.ln()).abs() <= 1e-12, "dof {d}");
        }
        counts.push(stats.iterations);
    }
    println!("iterations with / without the acceleration: {counts:?}");
    assert!(counts[0] < counts[1], "{counts:?}");
}

/// The free vertex with the largest force ‖∂F/∂x_v‖ at `x` (pinned vertices left out), recomputed from the
/// system's gradient, and the largest force on a pinned vertex (its reaction).
fn largest_forces(sys: &mut System, pins: &Pins, x: &[Vector3<f64>]) -> ((usize, f64), f64) {
    let g = sys
        .evaluate(x, Request::GRADIENT, Parallelism::Sequential)
        .unwrap()
        .gradient;
    let force = |v: usize| Vector3::new(g[3 * v], g[3 * v + 1], g[3 * v + 2]).norm();
    let free = (0..x.len())
        .filter(|&v| !pins.contains(v))
        .map(|v| (v, force(v)))
        .fold((usize::MAX, -1.0), |b, c| if c.1 > b.1 { c } else { b });
    let pinned = pins
        .vertices()
        .iter()
        .map(|&v| force(v))
        .fold(0.0, f64::max);
    (free, pinned)
}

/// Where the residual is ([`NewtonStats::largest_residual`], the observer's `largest_residual`): after each
/// of a cantilever's first Newton iterations (a randomly numbered strip, clamped at one end), the free
/// vertex whose force is largest, recomputed from the system's gradient at the iterate: the clamped
/// vertices' reactions, larger still, are not residuals and never named. A solve that fails carries where
/// it stopped in its error, as its last iteration reported it.
#[test]
fn the_largest_residual_is_the_free_vertex_with_the_largest_force() {
    use hinge_solver::newton::IterationReport;
    use std::sync::{Arc, Mutex};
    let (rest, mut sys, pins) = thin_strip();
    let one = NewtonParams {
        single_iteration: true,
        ..NewtonParams::default()
    };
    let mut newton = Newton::new(&sys, &pins, default_solver(), one).unwrap();
    let mut x = rest.positions().to_vec();
    let mut named = Vec::new();
    let (mut reactions_larger, mut converged) = (0, false);
    // Iteration by iteration to the equilibrium (the strip converges in about fifty).
    for _ in 0..200 {
        let stats = newton.minimize(&mut sys, &mut x, None).unwrap();
        let ((v, force), reaction) = largest_forces(&mut sys, &pins, &x);
        let (sv, sf) = stats.largest_residual.unwrap();
        assert_eq!(sv, v);
        assert!((sf - force).abs() <= 1e-14 * force, "{sf} vs {force}");
        // The last entry of the gradient norms is the same residual, over every free vertex.
        let gn = *stats.gradient_norms.last().unwrap();
        assert!(sf <= gn && gn <= sf * ((x.len() - pins.vertices().len()) as f64).sqrt());
        reactions_larger += usize::from(reaction > 2.0 * force);
        named.push(v);
        if gn <= 1e-9 {
            converged = true;
            break;
        }
    }
    assert!(converged);
    // The test could tell pinned from free: the reactions were the larger forces, by far at the end.
    assert!(
        reactions_larger >= 10,
        "{reactions_larger} of {}",
        named.len()
    );
    // A solve stopped by its iteration limit: the error says where, as its last iteration reported it
    // (the same first iteration as above).
    let seen: Arc<Mutex<Vec<IterationReport>>> = Arc::default();
    let sink = seen.clone();
    let limited = NewtonParams {
        max_iterations: 1,
        ..NewtonParams::default()
    };
    let mut failing = Newton::new(&sys, &pins, default_solver(), limited).unwrap();
    failing.set_observer(Some(Box::new(move |r: &IterationReport| {
        sink.lock().unwrap().push(*r)
    })));
    let mut y = rest.positions().to_vec();
    let err = failing.minimize(&mut sys, &mut y, None).unwrap_err();
    assert!(matches!(err, SolverError::NotConverged { .. }), "{err}");
    assert_eq!(&y, rest.positions());
    let last = seen.lock().unwrap().last().unwrap().largest_residual;
    assert_eq!(err.stats().largest_residual, last);
    assert_eq!(last.map(|l| l.0), Some(named[0]));
}
