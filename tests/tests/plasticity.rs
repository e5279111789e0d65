//! Bending plasticity: the rest-angle return mapping with linear hardening, applied only after accepted
//! (sub)steps, against the law computed by hand; the energy with updated rest angles against finite
//! differences.

use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::energy::{Energy, HingeTerm, Plasticity, System};
use hinge_core::psi::DiscreteShells;
use hinge_core::shapes::{irregular_sheet, random_permutation, renumber};
use hinge_core::{EvalError, TriMesh};
use hinge_energies::gravity::lumped_masses;
use hinge_energies::pins::Pins;
use hinge_solver::linear::default_solver;
use hinge_solver::newton::{ImplicitEuler, Newton, NewtonParams, SubstepPolicy};
use hinge_tests::*;
use nalgebra::Vector3;

/// One hinge along the x axis, flat at rest; `fold(θ)` turns the wing x3 about the edge by θ.
fn one_hinge() -> (TriMesh, impl Fn(f64) -> Vec<Vector3<f64>>) {
    let p = one_hinge_positions();
    let rest = one_hinge_mesh();
    let fold = move |theta: f64| {
        let mut x = p.clone();
        let (s, c) = theta.sin_cos();
        x[3] = Vector3::new(0.6, -0.9 * c, -0.9 * s);
        x
    };
    (rest, fold)
}

fn theta_of(x: &[Vector3<f64>]) -> f64 {
    hinge_core::hinge::theta_only(&[x[0], x[1], x[2], x[3]]).unwrap()
}

#[test]
fn return_mapping_with_linear_hardening_matches_the_law() {
    let (rest, fold) = one_hinge();
    let law = Plasticity {
        yield_angle: 0.1,
        hardening: 0.5,
    };
    let term = |r: &TriMesh| {
        HingeTerm::new(
            "bending",
            BendingModel::new(r, DiscreteShells { k: 1.0 }).unwrap(),
            Method::Refactored,
        )
        .with_plasticity(law)
        .unwrap()
    };
    let mut t = term(&rest);
    // Below yield: no change; the released hinge returns flat.
    let x = fold(0.08);
    t.end_step(&x).unwrap();
    assert_eq!(t.evolving_rest_angles().unwrap(), &[0.0]);
    assert_eq!(t.max_plastic_angle(), Some(0.0));
    // Above: θ̄ = sign θ (|θ| − y) / (1 + H), α = |Δ|; afterwards |θ − θ̄| = y + H α.
    let theta1 = theta_of(&fold(0.5));
    t.end_step(&fold(0.5)).unwrap();
    let expected1 = (theta1.abs() - 0.1) / 1.5 * theta1.signum();
    let tb = t.evolving_rest_angles().unwrap()[0];
    println!("fold θ = {theta1:.6}: rest angle {tb:.12} (law {expected1:.12})");
    assert!((tb - expected1).abs() < 1e-15, "{tb} vs {expected1}");
    let alpha = t.max_plastic_angle().unwrap();
    assert!(((theta1 - tb).abs() - (0.1 + 0.5 * alpha)).abs() < 1e-15);
    // Reloading below the hardened yield changes nothing; beyond it, the yield has grown by H α.
    t.end_step(&fold(theta1 - 0.1)).unwrap();
    assert_eq!(t.evolving_rest_angles().unwrap()[0], tb);
    let theta2 = theta_of(&fold(0.9));
    t.end_step(&fold(0.9)).unwrap();
    let y = 0.1 + 0.5 * alpha;
    let expected2 = tb + (theta2 - tb - y) / 1.5;
    let tb2 = t.evolving_rest_angles().unwrap()[0];
    println!("fold θ = {theta2:.6}: rest angle {tb2:.12} (law {expected2:.12}, yield {y:.6})");
    assert!((tb2 - expected2).abs() < 1e-15);
    // Folding the other way yields by the same law (the sign of θ − θ̄), with the yield hardened by the
    // plastic angle accumulated either way.
    let alpha2 = t.max_plastic_angle().unwrap();
    let theta3 = theta_of(&fold(-0.6));
    t.end_step(&fold(-0.6)).unwrap();
    let y3 = 0.1 + 0.5 * alpha2;
    let expected3 = tb2 - ((theta3 - tb2).abs() - y3) / 1.5;
    let tb3 = t.evolving_rest_angles().unwrap()[0];
    println!("fold θ = {theta3:.6}: rest angle {tb3:.12} (law {expected3:.12}, yield {y3:.6})");
    assert!((tb3 - expected3).abs() < 1e-15);
    // Released (x0, x1, x2 pinned; no load), the hinge rests at its current θ̄: the residual angle.
    let mut sys = System::new(4, vec![Box::new(term(&rest))]).unwrap();
    sys.end_step(&fold(0.5)).unwrap();
    let pins = Pins::new(4, vec![0, 1, 2]).unwrap();
    let mut newton = Newton::new(&sys, &pins, default_solver(), params_tight()).unwrap();
    let mut y = fold(0.5);
    newton.minimize(&mut sys, &mut y, None).unwrap();
    let residual = theta_of(&y);
    println!(
        "released after a fold of {theta1:.6}: residual angle {residual:.9} (law {expected1:.9})"
    );
    assert!(
        (residual - expected1).abs() < 1e-7,
        "{residual} vs {expected1}"
    );
    // Below yield the released hinge recovers fully.
    let mut sys = System::new(4, vec![Box::new(term(&rest))]).unwrap();
    sys.end_step(&fold(0.08)).unwrap();
    let mut newton = Newton::new(&sys, &pins, default_solver(), params_tight()).unwrap();
    let mut y = fold(0.08);
    newton.minimize(&mut sys, &mut y, None).unwrap();
    assert!(theta_of(&y).abs() < 1e-7, "{}", theta_of(&y));
    // Bad laws are typed errors naming the key.
    for bad in [
        Plasticity {
            yield_angle: -0.1,
            hardening: 0.0,
        },
        Plasticity {
            yield_angle: 0.1,
            hardening: f64::NAN,
        },
    ] {
        let e = HingeTerm::new(
            "bending",
            BendingModel::new(&rest, DiscreteShells { k: 1.0 }).unwrap(),
            Method::Refactored,
        )
        .with_plasticity(bad)
        .err()
        .unwrap();
        assert!(matches!(e, EvalError::Psi(_)), "{e}");
    }
}

fn params_tight() -> NewtonParams {
    NewtonParams {
        gradient_tolerance: 1e-13,
        max_iterations: 200,
        ..NewtonParams::default()
    }
}

#[test]
fn the_energy_with_updated_rest_angles_matches_finite_differences() {
    let irr = irregular_sheet(7, 6, 2).unwrap();
    let rest = renumber(&irr, &random_permutation(irr.n_vertices(), 4)).unwrap();
    let x = bend(rest.positions());
    let mut sys = System::new(
        rest.n_vertices(),
        vec![Box::new(
            HingeTerm::new(
                "bending",
                BendingModel::new(&rest, DiscreteShells { k: 0.7 }).unwrap(),
                Method::Refactored,
            )
            .with_plasticity(Plasticity {
                yield_angle: 0.05,
                hardening: 0.2,
            })
            .unwrap(),
        )],
    )
    .unwrap();
    sys.end_step(&x).unwrap();
    let moved = sys
        .evolving_rest_angles()
        .unwrap()
        .iter()
        .filter(|&&t| t != 0.0)
        .count();
    assert!(moved > 0 && sys.max_plastic_angle().unwrap() > 0.0);
    // A state off the yield surface, and the derivatives there.
    let y: Vec<_> = x
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.0, 0.02 * p.x))
        .collect();
    let ev = sys
        .evaluate(&y, Request::ALL, Parallelism::Sequential)
        .unwrap();
    let (fd_g, fd_h) = fd_energy_derivatives(&y, 1e-6, |z| {
        let r = sys
            .evaluate(z, Request::GRADIENT, Parallelism::Sequential)
            .unwrap();
        (r.energy, r.gradient)
    });
    let (eg, eh) = (
        rel_error(&ev.gradient, &fd_g),
        rel_error(&sym_dense(sys.pattern(), &ev.hessian), &fd_h),
    );
    println!(
        "{moved} hinges yielded; with the updated rest angles: gradient vs FD {eg:.1e}, Hessian {eh:.1e}"
    );
    assert!(eg < 1e-7 && eh < 1e-6);
}

fn bend(x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    hinge_core::shapes::bend(x)
}

#[test]
fn rest_angles_follow_accepted_substeps_only() {
    // A folded hinge springing open under implicit Euler with plasticity; the gate rejects steps above
    // dt/3: the frame's dt and dt/2 are rejected, dt/4 accepted twice, the grown-back dt/2 rejected again,
    // dt/4 accepted twice more: 4 accepted substeps, 3 rejected attempts. Each accepted substep ends once,
    // a rejected attempt never.
    let (rest, fold) = one_hinge();
    let (ended, evaluated) = (Times::default(), Times::default());
    let dt = 0.01;
    let make = |max_dt: f64| {
        let terms: Vec<Box<dyn Energy>> = vec![
            Box::new(
                HingeTerm::new(
                    "bending",
                    BendingModel::new(&rest, DiscreteShells { k: 1.0 }).unwrap(),
                    Method::Refactored,
                )
                .with_plasticity(Plasticity {
                    yield_angle: 0.05,
                    hardening: 0.0,
                })
                .unwrap(),
            ),
            Box::new(StepGate::new(4, max_dt, &ended, &evaluated)),
        ];
        System::new(4, terms).unwrap()
    };
    let mut sys = make(dt / 3.0);
    let pins = Pins::new(4, vec![0, 1, 2]).unwrap();
    let masses = lumped_masses(&rest, 1.0);
    let mut stepper = ImplicitEuler::new(
        &sys,
        dt,
        masses.clone(),
        pins.clone(),
        default_solver(),
        params_tight(),
    )
    .unwrap();
    let (mut x, mut v) = (fold(0.6), vec![Vector3::zeros(); 4]);
    let fs = stepper
        .advance(&mut sys, &mut x, &mut v, SubstepPolicy { max_halvings: 4 })
        .unwrap();
    println!(
        "frame: {} accepted substeps, {} rejected attempts, {} step ends; rest angle {:.6}",
        fs.substeps,
        fs.failed_attempts,
        ended.lock().unwrap().len(),
        sys.evolving_rest_angles().unwrap()[0]
    );
    assert_eq!(fs.substeps, 4);
    assert_eq!(fs.failed_attempts, 3);
    assert_eq!(ended.lock().unwrap().len(), 4);
    assert!(sys.evolving_rest_angles().unwrap()[0] != 0.0);
    // A frame that fails at every substep leaves the rest angles as they were.
    ended.lock().unwrap().clear();
    let mut sys = make(dt / 1000.0);
    let mut stepper =
        ImplicitEuler::new(&sys, dt, masses, pins, default_solver(), params_tight()).unwrap();
    let (mut x, mut v) = (fold(0.6), vec![Vector3::zeros(); 4]);
    assert!(
        stepper
            .advance(&mut sys, &mut x, &mut v, SubstepPolicy { max_halvings: 3 })
            .is_err()
    );
    assert_eq!(ended.lock().unwrap().len(), 0);
    assert_eq!(sys.evolving_rest_angles().unwrap(), &[0.0]);
    assert_eq!(x, fold(0.6));
}

#[test]
fn moving_pins_reach_their_targets_at_every_frame_end_under_substeps() {
    use hinge_solver::newton::PinMotion;
    // The hinge's wing x3 is pinned and carried along a line; the gate forces substeps of dt/4 (see
    // `rest_angles_follow_accepted_substeps_only`). At the end of every frame the pin is exactly at the
    // frame's target, and within a frame each substep took it to its own end's target.
    let (rest, fold) = one_hinge();
    let (ended, evaluated) = (Times::default(), Times::default());
    let dt = 0.01;
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&rest, DiscreteShells { k: 1.0 }).unwrap(),
            Method::Refactored,
        )),
        Box::new(StepGate::new(4, dt / 3.0, &ended, &evaluated)),
    ];
    let mut sys = System::new(4, terms).unwrap();
    let pins = Pins::new(4, vec![1, 2, 3]).unwrap();
    let mut stepper = ImplicitEuler::new(
        &sys,
        dt,
        lumped_masses(&rest, 1.0),
        pins,
        default_solver(),
        params_tight(),
    )
    .unwrap();
    let start = fold(0.3);
    let (mut x, mut v) = (start.clone(), vec![Vector3::zeros(); 4]);
    let velocity = Vector3::new(0.4, 0.1, -0.2);
    for frame in 0..5 {
        let t0 = frame as f64 * dt;
        let motion = |s: f64, y: &mut [Vector3<f64>]| {
            y[3] = start[3] + velocity * (t0 + s * dt);
        };
        let fs = stepper
            .advance_with(
                &mut sys,
                &mut x,
                &mut v,
                SubstepPolicy { max_halvings: 4 },
                Some(&motion as &dyn PinMotion),
            )
            .unwrap();
        assert!(fs.substeps >= 4, "{}", fs.substeps);
        let target = start[3] + velocity * (t0 + dt);
        assert_eq!(x[3], target, "frame {frame}");
        // The other pins stay put; the free vertex x0 moved with the fold.
        assert_eq!(x[1], start[1]);
        assert_eq!(x[2], start[2]);
    }
    // The pinned vertex's velocity is the one that carried it along the line (v = Δx/h of the last
    // substep, h = dt/4).
    assert!((v[3] - velocity).norm() < 1e-9, "{:?}", v[3]);
}

/// A zero energy that counts the steps ended: from the `fail_after`-th end on, every evaluation fails (a
/// step the solver cannot take), and at the `raise_at`-th end it raises a stop flag (a Ctrl-C arriving
/// between two substeps).
struct EndHook {
    ends: usize,
    fail_after: usize,
    raise_at: Option<(usize, std::sync::Arc<std::sync::atomic::AtomicBool>)>,
}

impl Energy for EndHook {
    fn name(&self) -> &str {
        "hook"
    }
    fn n_vertices(&self) -> usize {
        4
    }
    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}
    fn bind(
        &mut self,
        _: &std::sync::Arc<hinge_core::pattern::SymmetricPattern>,
    ) -> Result<(), EvalError> {
        Ok(())
    }
    fn add_to(
        &mut self,
        _: &[Vector3<f64>],
        _: Request,
        _: Parallelism,
        _: &mut hinge_core::energy::Accumulator,
    ) -> Result<f64, EvalError> {
        if self.ends >= self.fail_after {
            Err(EvalError::Step { dt: 1.0 })
        } else {
            Ok(0.0)
        }
    }
    fn end_step(&mut self, _: &[Vector3<f64>]) -> Result<(), EvalError> {
        self.ends += 1;
        if let Some((at, flag)) = &self.raise_at
            && *at == self.ends
        {
            flag.store(true, std::sync::atomic::Ordering::SeqCst);
        }
        Ok(())
    }
}

/// A plastic discrete-shells hinge term (k = 1) on `rest`, boxed for a [`System`].
fn plastic_hinges(rest: &TriMesh, law: Plasticity) -> Box<dyn Energy> {
    Box::new(
        HingeTerm::new(
            "bending",
            BendingModel::new(rest, DiscreteShells { k: 1.0 }).unwrap(),
            Method::Refactored,
        )
        .with_plasticity(law)
        .unwrap(),
    )
}

/// A frame that fails after some of its substeps were accepted (each moving the plastic rest angle) sets the
/// rest angle and the accumulated plastic angle back to the frame's start, with the positions and
/// velocities: for implicit Euler at the substep floor and on a stop request between substeps, and for
/// symplectic Euler when a later substep cannot be evaluated. The next frame then runs as if the failed one
/// had never been tried.
#[test]
fn a_frame_that_fails_after_accepted_substeps_leaves_the_plastic_state_as_it_was() {
    use hinge_solver::explicit::SymplecticEuler;
    use hinge_solver::newton::SolverError;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let (rest, fold) = one_hinge();
    let (ended, evaluated) = (Times::default(), Times::default());
    let dt = 0.01;
    let law = Plasticity {
        yield_angle: 0.05,
        hardening: 0.3,
    };
    let make = |hook: EndHook| {
        let terms: Vec<Box<dyn Energy>> = vec![
            plastic_hinges(&rest, law),
            // Rejects dt and dt/2: the frame's first accepted substep is dt/4.
            Box::new(StepGate::new(4, dt / 3.0, &ended, &evaluated)),
            Box::new(hook),
        ];
        System::new(4, terms).unwrap()
    };
    let pins = Pins::new(4, vec![0, 1, 2]).unwrap();
    let masses = lumped_masses(&rest, 1.0);
    let plastic = |sys: &System| {
        (
            sys.evolving_rest_angles().unwrap()[0],
            sys.max_plastic_angle().unwrap(),
        )
    };
    // The wing x3 folding on at 20 rad/s: the hinge keeps yielding over the first frames.
    let folding = || {
        let mut v = vec![Vector3::zeros(); 4];
        v[3] = Vector3::new(0.0, 0.9 * 0.9f64.sin(), -0.9 * 0.9f64.cos()) * 20.0;
        v
    };
    // One good frame first (4 substeps of dt/4), so that the state to keep is not the initial one.
    let start = |hook: EndHook| {
        let mut sys = make(hook);
        let mut stepper = ImplicitEuler::new(
            &sys,
            dt,
            masses.clone(),
            pins.clone(),
            default_solver(),
            params_tight(),
        )
        .unwrap();
        let (mut x, mut v) = (fold(0.9), folding());
        stepper
            .advance(&mut sys, &mut x, &mut v, SubstepPolicy { max_halvings: 2 })
            .unwrap();
        (sys, stepper, x, v)
    };
    let flag = Arc::new(AtomicBool::new(false));
    for case in ["floor", "stop"] {
        let hook = match case {
            // The next frame's first substep is accepted, every attempt after it fails.
            "floor" => EndHook {
                ends: 0,
                fail_after: 5,
                raise_at: None,
            },
            _ => EndHook {
                ends: 0,
                fail_after: usize::MAX,
                raise_at: Some((5, flag.clone())),
            },
        };
        let (mut sys, mut stepper, mut x, mut v) = start(hook);
        let (mut twin, mut twin_stepper, mut tx, mut tv) = start(EndHook {
            ends: 0,
            fail_after: usize::MAX,
            raise_at: None,
        });
        stepper.newton_mut().set_stop(Some(flag.clone()));
        let before = plastic(&sys);
        assert!(before.1 > 0.0, "{case}: the first frame yielded");
        let (x0, v0, t0) = (x.clone(), v.clone(), stepper.time());
        let err = stepper
            .advance(&mut sys, &mut x, &mut v, SubstepPolicy { max_halvings: 2 })
            .unwrap_err();
        match case {
            "floor" => assert!(matches!(err, SolverError::Eval { .. }), "{err}"),
            _ => assert!(matches!(err, SolverError::Interrupted { .. }), "{err}"),
        }
        assert_eq!(plastic(&sys), before, "{case}: plastic state set back");
        assert_eq!((&x, &v, stepper.time()), (&x0, &v0, t0), "{case}");
        // The same frame in a run without the hook yields further (from its first substep on, which the
        // failed frame had accepted and ended): so there was something to set back.
        let twin_frame = twin_stepper
            .advance(
                &mut twin,
                &mut tx,
                &mut tv,
                SubstepPolicy { max_halvings: 2 },
            )
            .unwrap();
        assert!(plastic(&twin).1 > before.1, "{case}");
        if case == "stop" {
            // The interruption reports the frame's work: its first, accepted and undone, substep's Newton
            // iterations (the twin's frame took those and three more substeps).
            let work = err.stats();
            assert_eq!(twin_frame.substeps, 4);
            assert!(
                0 < work.iterations && work.iterations < twin_frame.newton.iterations,
                "{} of {}",
                work.iterations,
                twin_frame.newton.iterations
            );
            assert!(work.factorizations >= work.iterations);
            // The frame again, the flag down: exactly the twin's frame.
            flag.store(false, Ordering::SeqCst);
            stepper
                .advance(&mut sys, &mut x, &mut v, SubstepPolicy { max_halvings: 2 })
                .unwrap();
            assert_eq!((&x, &v), (&tx, &tv));
            assert_eq!(plastic(&sys), plastic(&twin));
        }
    }
    // Symplectic Euler, 8 substeps a frame: the hook fails the evaluation after 3 ends of the second frame
    // ("fail"), or raises the stop flag at that point ("stop": the frame ends before its fourth substep).
    let explicit_run = |hook: EndHook| {
        let terms: Vec<Box<dyn Energy>> = vec![plastic_hinges(&rest, law), Box::new(hook)];
        let mut sys = System::new(4, terms).unwrap();
        let mut explicit = SymplecticEuler::new(&sys, 1e-3, 8, masses.clone(), &pins).unwrap();
        let (mut x, mut v) = (fold(0.9), folding());
        explicit.advance(&mut sys, &mut x, &mut v).unwrap();
        (sys, explicit, x, v)
    };
    let stop = Arc::new(AtomicBool::new(false));
    for case in ["fail", "stop"] {
        let (mut sys, mut explicit, mut x, mut v) = explicit_run(EndHook {
            ends: 0,
            fail_after: if case == "fail" { 11 } else { usize::MAX },
            raise_at: (case == "stop").then(|| (11, stop.clone())),
        });
        explicit.set_stop(Some(stop.clone()));
        let before = plastic(&sys);
        assert!(before.1 > 0.0);
        let (x0, v0) = (x.clone(), v.clone());
        let err = explicit.advance(&mut sys, &mut x, &mut v).unwrap_err();
        match case {
            "fail" => {
                assert!(matches!(err, SolverError::Unstable { .. }), "{err}");
                // Substeps are numbered over the run and the failed frame's undone ones do not count:
                // the frame tried again (the hook now fails its first evaluation) fails at substep 9.
                assert!(err.to_string().contains("explicit substep 12 "), "{err}");
                let again = explicit.advance(&mut sys, &mut x, &mut v).unwrap_err();
                assert!(again.to_string().contains("explicit substep 9 "), "{again}");
            }
            _ => {
                assert!(matches!(err, SolverError::Interrupted { .. }), "{err}");
                assert_eq!(
                    err.stats().iterations,
                    0,
                    "no Newton work in an explicit frame"
                );
            }
        }
        assert_eq!(
            plastic(&sys),
            before,
            "explicit {case}: plastic state set back"
        );
        assert_eq!((&x, &v, explicit.time()), (&x0, &v0, 1e-3), "{case}");
        if case == "stop" {
            // The flag down, the frame again: bitwise the frame of a run that was never stopped (whose
            // second frame yields further, so the interrupted one had something to set back).
            stop.store(false, Ordering::SeqCst);
            explicit.advance(&mut sys, &mut x, &mut v).unwrap();
            let (mut twin, mut twin_explicit, mut tx, mut tv) = explicit_run(EndHook {
                ends: 0,
                fail_after: usize::MAX,
                raise_at: None,
            });
            twin_explicit.advance(&mut twin, &mut tx, &mut tv).unwrap();
            assert!(plastic(&twin).1 > before.1);
            assert_eq!((&x, &v), (&tx, &tv));
            assert_eq!(plastic(&sys), plastic(&twin));
            // Raised before a frame: it ends at once, nothing moved.
            stop.store(true, Ordering::SeqCst);
            let (x1, v1, p1) = (x.clone(), v.clone(), plastic(&sys));
            let err = explicit.advance(&mut sys, &mut x, &mut v).unwrap_err();
            assert!(matches!(err, SolverError::Interrupted { .. }), "{err}");
            assert_eq!((&x, &v, plastic(&sys)), (&x1, &v1, p1));
            assert_eq!(explicit.time(), 2e-3);
        }
    }
}

/// The plastic state a checkpoint holds (rest angles and accumulated plastic angles) reads back through
/// `System::plastic_state` and, set on a fresh system, continues the law exactly: a system given another's
/// state yields the next fold as the other does (the hardened yield included). Bad states are refused by
/// name with nothing changed; a system without plasticity has no state and refuses one.
#[test]
fn the_plastic_state_of_a_checkpoint_continues_the_law_exactly() {
    let (rest, fold) = one_hinge();
    let law = Plasticity {
        yield_angle: 0.1,
        hardening: 0.5,
    };
    let mut a = System::new(4, vec![plastic_hinges(&rest, law)]).unwrap();
    a.end_step(&fold(0.7)).unwrap();
    a.end_step(&fold(-0.4)).unwrap();
    let (theta_bar, alpha) = a
        .plastic_state()
        .map(|(t, a)| (t.to_vec(), a.to_vec()))
        .unwrap();
    assert!(
        alpha[0] > 0.3 && theta_bar[0] != 0.0,
        "{theta_bar:?} {alpha:?}"
    );
    let mut b = System::new(4, vec![plastic_hinges(&rest, law)]).unwrap();
    b.set_plastic_state(&theta_bar, &alpha).unwrap();
    assert_eq!(b.plastic_state(), a.plastic_state());
    // The next fold, beyond the hardened yield: both move the same way, bitwise.
    for s in [&mut a, &mut b] {
        s.end_step(&fold(1.1)).unwrap();
    }
    assert_eq!(b.plastic_state(), a.plastic_state());
    // With α set back to zero instead, the same fold yields further: the accumulated angle matters.
    let mut c = System::new(4, vec![plastic_hinges(&rest, law)]).unwrap();
    c.set_plastic_state(&theta_bar, &[0.0]).unwrap();
    c.end_step(&fold(1.1)).unwrap();
    assert!(c.evolving_rest_angles().unwrap()[0] > a.evolving_rest_angles().unwrap()[0]);
    // Refused, nothing changed.
    let before = b.plastic_state().map(|(t, a)| (t.to_vec(), a.to_vec()));
    for (t, al, needle) in [
        (
            vec![0.1, 0.2],
            vec![0.0],
            "has 2 values but the mesh has 1 hinges",
        ),
        (
            vec![0.1],
            vec![0.0, 0.0],
            "has 2 values but the mesh has 1 hinges",
        ),
        (
            vec![0.1],
            vec![-0.5],
            "value of hinge 0 must be non-negative and finite",
        ),
        (
            vec![0.1],
            vec![f64::NAN],
            "value of hinge 0 must be non-negative and finite",
        ),
        (vec![4.0], vec![0.0], "outside"),
    ] {
        let e = b.set_plastic_state(&t, &al).unwrap_err().to_string();
        assert!(e.contains(needle), "{e}");
        assert_eq!(
            b.plastic_state().map(|(t, a)| (t.to_vec(), a.to_vec())),
            before
        );
    }
    let mut elastic = System::new(
        4,
        vec![Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&rest, DiscreteShells { k: 1.0 }).unwrap(),
            Method::Refactored,
        ))],
    )
    .unwrap();
    assert!(elastic.plastic_state().is_none());
    let e = elastic
        .set_plastic_state(&[0.0], &[0.0])
        .unwrap_err()
        .to_string();
    assert!(e.contains("no energy has plasticity"), "{e}");
    // The shift memory a checkpoint holds: restored as given, refused when negative or not finite.
    let pins = Pins::new(4, vec![0, 1, 2]).unwrap();
    let mut newton = Newton::new(&a, &pins, default_solver(), params_tight()).unwrap();
    assert_eq!(newton.shift_memory(), 0.0);
    newton.restore_shift_memory(0.1 + 0.2).unwrap();
    assert_eq!(newton.shift_memory(), 0.1 + 0.2);
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        assert!(newton.restore_shift_memory(bad).is_err());
        assert_eq!(newton.shift_memory(), 0.1 + 0.2);
    }
}

/// `ImplicitEuler::set_substep_observer` sees every accepted substep's end: a frame that a gate makes
/// take four substeps of dt/4 reports the times dt/4 … dt and, last, the frame's end positions; the
/// observer changes nothing (the same frame without it ends bitwise the same).
#[test]
fn the_substep_observer_sees_every_accepted_substep_end() {
    let (rest, fold) = one_hinge();
    let dt = 0.01;
    let law = Plasticity {
        yield_angle: 0.05,
        hardening: 0.3,
    };
    let run = |observe: bool| {
        let (ended, evaluated) = (Times::default(), Times::default());
        let terms: Vec<Box<dyn Energy>> = vec![
            plastic_hinges(&rest, law),
            // Rejects dt and dt/2: four substeps of dt/4.
            Box::new(StepGate::new(4, dt / 3.0, &ended, &evaluated)),
        ];
        let mut sys = System::new(4, terms).unwrap();
        let mut stepper = ImplicitEuler::new(
            &sys,
            dt,
            lumped_masses(&rest, 1.0),
            Pins::new(4, vec![0, 1, 2]).unwrap(),
            default_solver(),
            params_tight(),
        )
        .unwrap();
        let seen = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        if observe {
            let seen = std::sync::Arc::clone(&seen);
            stepper.set_substep_observer(Some(Box::new(move |x: &[Vector3<f64>], t: f64| {
                seen.lock().unwrap().push((x.to_vec(), t));
            })));
        }
        let (mut x, mut v) = (fold(0.9), vec![Vector3::zeros(); 4]);
        v[3] = Vector3::new(0.0, 1.0, -2.0);
        let fs = stepper
            .advance(&mut sys, &mut x, &mut v, SubstepPolicy { max_halvings: 2 })
            .unwrap();
        let seen = seen.lock().unwrap().clone();
        (fs.substeps, x, seen)
    };
    let (substeps, x, seen) = run(true);
    assert_eq!(substeps, 4);
    let times: Vec<f64> = seen.iter().map(|(_, t)| *t).collect();
    assert_eq!(times, vec![0.25 * dt, 0.5 * dt, 0.75 * dt, dt]);
    assert_eq!(seen.last().unwrap().0, x);
    assert_ne!(seen[0].0, x);
    let (_, unobserved, none) = run(false);
    assert!(none.is_empty());
    assert_eq!(unobserved, x);
}
