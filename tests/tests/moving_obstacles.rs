//! Moving obstacles: a contact obstacle on a prescribed rigid motion is where the motion puts it (against
//! positions computed by hand), the time steppers place it at each (sub)step's end (implicit Euler) or
//! start (symplectic Euler) whether or not the frame took substeps, a failed frame leaves it at the frame's
//! start, and a rising plane lifts an irregular, renumbered sheet with it.

use hinge_core::TriMesh;
use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Energy, System};
use hinge_core::grid::SplitMix64;
use hinge_core::nalgebra::Vector3;
use hinge_core::shapes::{irregular_sheet, random_permutation, renumber};
use hinge_energies::contact::{Contact, Obstacle};
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::motion::Motion;
use hinge_energies::pins::Pins;
use hinge_energies::spring::MassSpring;
use hinge_solver::explicit::SymplecticEuler;
use hinge_solver::linear::default_solver;
use hinge_solver::newton::{ImplicitEuler, NewtonParams, SubstepPolicy};
use hinge_tests::{StepGate, Times};

/// Rotates `d` about the unit `axis` by `angle` (Rodrigues' formula, written out).
fn rodrigues(d: Vector3<f64>, axis: Vector3<f64>, angle: f64) -> Vector3<f64> {
    let (s, c) = angle.sin_cos();
    d * c + axis.cross(&d) * s + axis * (axis.dot(&d) * (1.0 - c))
}

#[test]
fn obstacles_are_where_their_motion_puts_them() {
    let axis = Vector3::new(2.0, -1.0, 2.0) / 3.0;
    let pivot = Vector3::new(0.2, 0.1, -0.3);
    let w = 0.8;
    let (centre, radius) = (Vector3::new(0.5, 0.4, -0.6), 0.7);
    let (point, normal) = (Vector3::new(0.0, 0.1, 0.2), Vector3::new(0.0, 0.6, 0.8));
    let motions = [
        Motion::Translation(Vector3::new(0.3, -0.2, 0.5)),
        Motion::Rotation {
            center: pivot,
            axis,
            angular_velocity: w,
        },
        Motion::Keyframes(vec![
            (0.5, Vector3::new(0.0, 0.0, 0.4)),
            (1.5, Vector3::new(1.0, 0.0, 0.4)),
        ]),
    ];
    // By hand: translation c + v t; rotation pivot + Rodrigues(c − pivot); keyframes linear in pieces.
    let by_hand = |k: usize, p: Vector3<f64>, t: f64| -> Vector3<f64> {
        match k {
            0 => p + Vector3::new(0.3, -0.2, 0.5) * t,
            1 => pivot + rodrigues(p - pivot, axis, w * t),
            _ if t <= 0.5 => p + Vector3::new(0.0, 0.0, 0.4) * (t / 0.5),
            _ if t <= 1.5 => p + Vector3::new(t - 0.5, 0.0, 0.4),
            _ => p + Vector3::new(1.0, 0.0, 0.4),
        }
    };
    let mut rng = SplitMix64(3);
    let probes: Vec<Vector3<f64>> = (0..40)
        .map(|_| Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 1.5)
        .collect();
    for (k, m) in motions.iter().enumerate() {
        let mut sphere = Contact::new(
            1,
            Obstacle::Sphere {
                center: centre,
                radius,
            },
            10.0,
            0.0,
        )
        .unwrap()
        .with_motion(m.clone())
        .unwrap();
        let mut plane = Contact::new(1, Obstacle::Plane { point, normal }, 10.0, 0.0)
            .unwrap()
            .with_motion(m.clone())
            .unwrap();
        for t in [0.0, 0.3, 0.9, 2.0] {
            sphere.set_time(t).unwrap();
            plane.set_time(t).unwrap();
            let c = by_hand(k, centre, t);
            // The plane's normal turns like the difference of two points on the body.
            let n = (by_hand(k, point + normal, t) - by_hand(k, point, t)).normalize();
            let q = by_hand(k, point, t);
            for p in &probes {
                let (ds, dp) = (sphere.distance(p), plane.distance(p));
                assert!(
                    (ds - ((p - c).norm() - radius)).abs() < 1e-14,
                    "{m:?} t {t}: {ds}"
                );
                assert!((dp - n.dot(&(p - q))).abs() < 1e-14, "{m:?} t {t}: {dp}");
            }
        }
        // A non-finite time is an error and leaves the obstacle where it was.
        let before = sphere.obstacle();
        assert!(sphere.set_time(f64::NAN).is_err());
        assert_eq!(sphere.obstacle(), before);
    }
    // Bad motions are typed errors.
    let c = || {
        Contact::new(
            1,
            Obstacle::Sphere {
                center: centre,
                radius,
            },
            1.0,
            0.0,
        )
        .unwrap()
    };
    assert!(
        c().with_motion(Motion::Translation(Vector3::new(f64::NAN, 0.0, 0.0)))
            .is_err()
    );
    assert!(
        c().with_motion(Motion::Rotation {
            center: pivot,
            axis: Vector3::new(1.0, 1.0, 0.0),
            angular_velocity: 1.0
        })
        .is_err()
    );
    assert!(
        c().with_motion(Motion::Keyframes(vec![
            (1.0, Vector3::zeros()),
            (0.5, Vector3::zeros())
        ]))
        .is_err()
    );
    assert!(c().with_motion(Motion::Keyframes(Vec::new())).is_err());
}

/// A small sheet on a rising plane (with gravity) plus a [`StepGate`]; the sheet's rest mesh is irregular and
/// renumbered.
fn sheet_on_a_rising_plane(max_dt: f64, speed: f64) -> (TriMesh, System, Times, Times) {
    let sheet = irregular_sheet(5, 5, 4).unwrap();
    let rest = renumber(&sheet, &random_permutation(sheet.n_vertices(), 9)).unwrap();
    let n = rest.n_vertices();
    let (ended, evaluated) = (Times::default(), Times::default());
    let plane = Contact::new(
        n,
        Obstacle::Plane {
            point: Vector3::new(0.0, 0.0, -0.01),
            normal: Vector3::z(),
        },
        1e4,
        0.005,
    )
    .unwrap()
    .with_motion(Motion::Translation(Vector3::new(0.0, 0.0, speed)))
    .unwrap();
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(MassSpring::new(&rest, 200.0).unwrap()),
        Box::new(Gravity::new(lumped_masses(&rest, 0.2), Vector3::new(0.0, 0.0, -9.81)).unwrap()),
        Box::new(plane),
        Box::new(StepGate::new(n, max_dt, &ended, &evaluated)),
    ];
    let sys = System::new(n, terms).unwrap();
    (rest, sys, ended, evaluated)
}

/// Implicit Euler with step `dt` on `sys`, lumped masses of density 0.2 on `rest`, nothing pinned, the
/// default solver and Newton parameters.
fn implicit_euler(sys: &System, rest: &TriMesh, dt: f64) -> ImplicitEuler {
    let pins = Pins::new(rest.n_vertices(), Vec::new()).unwrap();
    let masses = lumped_masses(rest, 0.2);
    ImplicitEuler::new(
        sys,
        dt,
        masses,
        pins,
        default_solver(),
        NewtonParams::default(),
    )
    .unwrap()
}

#[test]
fn implicit_euler_places_obstacles_at_each_substep_end_and_back_on_failure() {
    let dt = 0.04;
    // The clock rejects steps above dt/3: each frame is dt/4, dt/4, (dt/2 rejected), dt/4, dt/4.
    let (rest, mut sys, ended, evaluated) = sheet_on_a_rising_plane(dt / 3.0, 0.5);
    let n = rest.n_vertices();
    let mut stepper = implicit_euler(&sys, &rest, dt);
    let (mut x, mut v) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
    let policy = SubstepPolicy { max_halvings: 4 };
    for frame in 0..2 {
        let fs = stepper.advance(&mut sys, &mut x, &mut v, policy).unwrap();
        assert_eq!((fs.substeps, fs.failed_attempts), (4, 3));
        let t0 = frame as f64 * dt;
        let want: Vec<f64> = (1..=4).map(|k| t0 + dt * (k as f64 / 4.0)).collect();
        let got = ended.lock().unwrap().split_off(0);
        println!("frame {}: accepted substeps ended at {got:?}", frame + 1);
        assert_eq!(got, want, "each accepted substep is solved at its end time");
        assert_eq!(stepper.time(), t0 + dt);
    }
    // Every evaluation happened with the plane at some substep's end, never between.
    for t in evaluated.lock().unwrap().iter() {
        let k = t / (dt / 4.0);
        assert!((k - k.round()).abs() < 1e-9 && k.round() >= 1.0, "{t}");
    }
    // A frame that fails at every substep (the floor is dt/16 here, above the clock's limit) leaves x, v,
    // the stepper's time and the obstacles at the frame's start.
    let (rest2, mut sys2, _, evaluated2) = sheet_on_a_rising_plane(dt / 100.0, 0.5);
    let mut s2 = implicit_euler(&sys2, &rest2, dt);
    s2.set_time(&mut sys2, 0.2).unwrap();
    let (mut x2, mut v2) = (rest2.positions().to_vec(), vec![Vector3::zeros(); n]);
    let (x0, v0) = (x2.clone(), v2.clone());
    assert!(s2.advance(&mut sys2, &mut x2, &mut v2, policy).is_err());
    assert_eq!((&x2, &v2), (&x0, &v0));
    assert_eq!(s2.time(), 0.2);
    // The system's obstacles are back at the frame's start: an evaluation now sees time 0.2, and the
    // plane's contact energy equals that of a fixed plane at its t = 0.2 position.
    // (A short step lets the clock evaluate; no other term has step state.)
    sys2.begin_step(&x2, dt / 200.0).unwrap();
    let got = sys2
        .evaluate(&x2, Request::VALUE, Parallelism::Sequential)
        .unwrap()
        .terms[2];
    assert_eq!(evaluated2.lock().unwrap().last().copied(), Some(0.2));
    let fixed = Contact::new(
        n,
        Obstacle::Plane {
            point: Vector3::new(0.0, 0.0, -0.01 + 0.5 * 0.2),
            normal: Vector3::z(),
        },
        1e4,
        0.005,
    )
    .unwrap();
    let mut probe = System::new(n, vec![Box::new(fixed) as Box<dyn Energy>]).unwrap();
    let want = probe
        .evaluate(&x2, Request::VALUE, Parallelism::Sequential)
        .unwrap()
        .energy;
    assert!(
        want > 0.0 && (got - want).abs() <= 1e-12 * want,
        "{got} {want}"
    );
}

#[test]
fn symplectic_euler_evaluates_forces_with_obstacles_at_each_substep_start() {
    let dt = 0.004;
    let (rest, mut sys, _, evaluated) = sheet_on_a_rising_plane(1.0, 0.5);
    let n = rest.n_vertices();
    let mut stepper = SymplecticEuler::new(
        &sys,
        dt,
        4,
        lumped_masses(&rest, 0.2),
        &Pins::new(n, Vec::new()).unwrap(),
    )
    .unwrap();
    let (mut x, mut v) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
    stepper.advance(&mut sys, &mut x, &mut v).unwrap();
    stepper.advance(&mut sys, &mut x, &mut v).unwrap();
    let got = evaluated.lock().unwrap().clone();
    let want: Vec<f64> = (0..8)
        .map(|k| dt * (k / 4) as f64 + dt * ((k % 4) as f64 / 4.0))
        .collect();
    assert_eq!(got, want);
    assert_eq!(stepper.time(), 2.0 * dt);
}

#[test]
fn a_rising_plane_lifts_the_sheet() {
    // The plane starts 1 cm below the sheet and rises at 0.5 m/s: after 0.6 s it is 29 cm up, and the
    // sheet rests on it (within the contact margin and the penalty's sag).
    let dt = 0.02;
    let (rest, mut sys, _, _) = sheet_on_a_rising_plane(1.0, 0.5);
    let n = rest.n_vertices();
    let mut stepper = implicit_euler(&sys, &rest, dt);
    let (mut x, mut v) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
    let mut heights = Vec::new();
    for _ in 0..30 {
        stepper
            .advance(&mut sys, &mut x, &mut v, SubstepPolicy::default())
            .unwrap();
        let plane = -0.01 + 0.5 * stepper.time();
        let (lo, hi) = x
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.z - plane), hi.max(p.z - plane))
            });
        heights.push((lo, hi));
    }
    let (lo, hi) = *heights.last().unwrap();
    println!("after 0.6 s, height of the sheet above the plane: {lo:.2e} … {hi:.2e} m");
    // Gravity 9.81 × mass against κ = 1e4 per vertex: the sag below the margin is a few tenths of a mm.
    assert!(lo > -0.001 && hi < 0.006, "{lo} {hi}");
    // It moves up with the plane: speed ≈ 0.5 m/s.
    let vz = v.iter().map(|w| w.z).sum::<f64>() / n as f64;
    assert!((vz - 0.5).abs() < 0.05, "{vz}");
}

/// The barrier with moving obstacles: a plane starting 4 mm under an irregular, renumbered sheet and
/// rising at 2 m/s (4 cm per step, ten times the gap) lifts it (with gravity) without a substep, because it
/// carries the vertices within its reach; a sphere rising at 0.5 m/s lifts a sheet lying on it (without
/// gravity). No vertex ever reaches either where it is at the end of each step, and the sheets end up
/// moving with them.
#[test]
fn moving_barrier_obstacles_carry_the_sheet_without_a_vertex_reaching_them() {
    let sheet = irregular_sheet(6, 6, 5).unwrap();
    let rest = renumber(&sheet, &random_permutation(sheet.n_vertices(), 3)).unwrap();
    let n = rest.n_vertices();
    let dt = 0.02;
    let cases = [
        (
            Obstacle::Plane {
                point: Vector3::new(0.0, 0.0, -0.004),
                normal: Vector3::z(),
            },
            Vector3::new(0.0, 0.0, -9.81),
            2.0,
        ),
        (
            Obstacle::Sphere {
                center: Vector3::new(0.5, 0.5, -0.304),
                radius: 0.3,
            },
            Vector3::zeros(),
            0.5,
        ),
    ];
    for (obstacle, g, speed) in cases {
        let contact = Contact::new(n, obstacle, 1e3, 0.005)
            .and_then(Contact::with_barrier)
            .and_then(|c| c.with_motion(Motion::Translation(Vector3::new(0.0, 0.0, speed))))
            .unwrap();
        let terms: Vec<Box<dyn Energy>> = vec![
            Box::new(MassSpring::new(&rest, 200.0).unwrap()),
            Box::new(Gravity::new(lumped_masses(&rest, 0.2), g).unwrap()),
            Box::new(contact.clone()),
        ];
        let mut sys = System::new(n, terms).unwrap();
        let mut stepper = implicit_euler(&sys, &rest, dt);
        let (mut x, mut v) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
        let mut probe = contact.clone();
        let mut closest = f64::INFINITY;
        let mut substeps = 0;
        for _ in 0..30 {
            let fs = stepper
                .advance(&mut sys, &mut x, &mut v, SubstepPolicy::default())
                .unwrap();
            substeps += fs.substeps;
            probe.set_time(stepper.time()).unwrap();
            closest = x.iter().map(|p| probe.distance(p)).fold(closest, f64::min);
        }
        let vz = v.iter().map(|w| w.z).sum::<f64>() / n as f64;
        let top = x.iter().map(|p| p.z).fold(f64::NEG_INFINITY, f64::max);
        println!(
            "{obstacle:?}: closest {closest:.3e} m, mean vz {vz:.3} m/s, top {top:.3} m, {substeps} substeps"
        );
        assert!(closest > 0.0, "{closest}");
        // Carried up: 30 steps at the obstacle's speed.
        assert!(top > 0.8 * 30.0 * dt * speed, "{top}");
        if matches!(obstacle, Obstacle::Plane { .. }) {
            assert!((vz - speed).abs() < 0.05 * speed, "{vz}");
            assert_eq!(substeps, 30);
        }
    }
}

/// Symplectic Euler with a rising barrier plane: it does not carry vertices (a carry would move a vertex
/// by the obstacle's displacement on top of its own velocity); with substeps over which the plane moves less
/// than the gap, the barrier's force throws the sheet up ahead of it, and a substep over which the plane
/// overtakes a vertex fails as unstable, with the frame's start state kept.
#[test]
fn symplectic_euler_with_a_moving_barrier_lifts_the_sheet_or_fails_cleanly() {
    let sheet = irregular_sheet(6, 6, 5).unwrap();
    let rest = renumber(&sheet, &random_permutation(sheet.n_vertices(), 3)).unwrap();
    let n = rest.n_vertices();
    let (dt, speed) = (0.02, 2.0);
    let contact = Contact::new(
        n,
        Obstacle::Plane {
            point: Vector3::new(0.0, 0.0, -0.004),
            normal: Vector3::new(0.05, 0.0, 1.0),
        },
        1e3,
        0.005,
    )
    .and_then(Contact::with_barrier)
    .and_then(|c| c.with_motion(Motion::Translation(Vector3::new(0.0, 0.0, speed))))
    .unwrap();
    let system = || {
        let terms: Vec<Box<dyn Energy>> = vec![
            Box::new(MassSpring::new(&rest, 200.0).unwrap()),
            Box::new(
                Gravity::new(lumped_masses(&rest, 0.2), Vector3::new(0.0, 0.0, -9.81)).unwrap(),
            ),
            Box::new(contact.clone()),
        ];
        System::new(n, terms).unwrap()
    };
    let mut sys = system();
    let stepper = |sys: &System, substeps| {
        SymplecticEuler::new(
            sys,
            dt,
            substeps,
            lumped_masses(&rest, 0.2),
            &Pins::new(n, Vec::new()).unwrap(),
        )
        .unwrap()
    };
    // 40 substeps a frame: the plane moves 1 mm a substep, a quarter of the first gap.
    let mut fine = stepper(&sys, 40);
    let (mut x, mut v) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
    let mut probe = contact.clone();
    let mut closest = f64::INFINITY;
    for frame in 0..30 {
        fine.advance(&mut sys, &mut x, &mut v)
            .unwrap_or_else(|e| panic!("frame {frame}: {e}"));
        probe.set_time(fine.time()).unwrap();
        closest = x.iter().map(|p| probe.distance(p)).fold(closest, f64::min);
    }
    let vz = v.iter().map(|w| w.z).sum::<f64>() / n as f64;
    let top = x.iter().map(|p| p.z).fold(f64::NEG_INFINITY, f64::max);
    println!("closest {closest:.3e} m, mean vz {vz:.3} m/s, top {top:.3} m");
    assert!(closest > 0.0, "{closest}");
    assert!(top > 0.8 * 30.0 * dt * speed, "{top}");
    assert!(vz > 0.95 * speed, "{vz}");
    // 4 substeps a frame: the plane moves 10 mm in the first, past vertices 4–9 mm above it.
    let mut sys = system();
    let mut coarse = stepper(&sys, 4);
    let (mut x, mut v) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
    let err = coarse.advance(&mut sys, &mut x, &mut v).unwrap_err();
    let message = err.to_string();
    assert!(
        message.contains("explicit substep 2") && message.contains("on or inside the obstacle"),
        "{message}"
    );
    assert_eq!(x, rest.positions());
    assert!(v.iter().all(|w| *w == Vector3::zeros()));
    assert_eq!(coarse.time(), 0.0);
}
