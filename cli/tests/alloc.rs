//! Newton allocates nothing per iteration (issue "Newton and time stepping …", item 2), checked on the
//! scene a new user runs first: the built-in drape, with the energies, solver and parameters `hinge run`
//! builds for it.
//!
//! A counting global allocator sees every allocation of this test binary. It holds this one test only, so
//! no other test's allocations mix in (the frames are stepped on the calling thread and on rayon's
//! workers, all counted). Frames whose Newton solves take from 2 to 30 iterations must allocate the same:
//! what a frame allocates (its start and velocity copies, the solve's histories) does not grow with its
//! iterations, factorizations or line-search trials — also when every iteration that needs a shift takes
//! the definite Hessian instead (`definite_shift_ratio = 0`), with the bending term's exact Hessian and
//! with its per-hinge projection (`bending.hessian = "projected"`). The LU backend (`linear_solver = "faer-lu"`) is
//! measured on the drape's Hessian made indefinite: it does allocate on every factorization (faer's
//! supernodal LU sizes its factors from the pivots it picks), about 214 times here against 3 366 for the
//! first; the test holds it to a tenth of the first.

// A global allocator is an `unsafe impl`: the measurement is the reason (see the SAFETY comments).
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System as SystemAlloc};
use std::sync::atomic::{AtomicUsize, Ordering};

use hinge_cli::run::{Built, build};
use hinge_core::nalgebra::Vector3;
use hinge_solver::newton::{ImplicitEuler, SubstepPolicy};

/// The system allocator, counting allocations and reallocations.
struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every method forwards its arguments unchanged to the system allocator, which meets
// `GlobalAlloc`'s contract; the counter is an atomic and allocates nothing.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's layout, under the caller's guarantees (non-zero size).
        unsafe { SystemAlloc.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: as for `alloc`.
        unsafe { SystemAlloc.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator (so from the system's) with this layout.
        unsafe { SystemAlloc.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: as for `dealloc`, with the caller's non-zero `new_size`.
        unsafe { SystemAlloc.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn newton_and_the_lu_backend_allocate_nothing_per_iteration_on_the_drape() {
    // One test, phases in turn: the counter is global, so they must not overlap.
    newton_on_the_drape("the default", |_| {});
    // Every iteration that needs a shift takes the definite Hessian instead (each energy's definite
    // Hessian evaluated at the iterate), with the bending term's exact and its per-hinge projected
    // Hessian.
    for hessian in ["exact", "projected"] {
        newton_on_the_drape(&format!("the definite Hessian, bending {hessian}"), |s| {
            s.solver.definite_shift_ratio = 0.0;
            s.bending.hessian = hessian.into();
        });
    }
    lu_on_the_drape_s_indefinite_hessian();
}

/// Forty frames of the drape (`edit` applied to its scene): from the third frame on, each allocates the
/// same whatever its Newton iterations.
fn newton_on_the_drape(what: &str, edit: impl Fn(&mut hinge_cli::scene::Scene)) {
    let (mut scene, _) = hinge_cli::scene::load("drape").unwrap();
    edit(&mut scene);
    let rest = scene.rest_mesh(None).unwrap();
    let Built {
        mut system,
        masses,
        pins,
        solver,
        params,
        ..
    } = build(&scene, &rest, true).unwrap();
    let mut stepper = ImplicitEuler::new(&system, scene.dt, masses, pins, solver, params).unwrap();
    let mut x = rest.positions().to_vec();
    let mut v = vec![Vector3::zeros(); x.len()];
    let policy = SubstepPolicy {
        max_halvings: scene.solver.max_substep_halvings,
    };
    // Per frame: (allocations, Newton iterations, factorizations, line-search trials, substeps).
    let mut frames = Vec::new();
    let mut definite = 0;
    for _ in 0..40 {
        let before = ALLOCATIONS.load(Ordering::SeqCst);
        let fs = stepper
            .advance(&mut system, &mut x, &mut v, policy)
            .unwrap();
        let allocations = ALLOCATIONS.load(Ordering::SeqCst) - before;
        definite += fs.newton.definite_iterations;
        frames.push((
            allocations,
            fs.newton.iterations,
            fs.newton.factorizations,
            fs.newton.line_search_steps,
            fs.substeps,
        ));
    }
    println!(
        "{what}: {definite} definite iterations; (allocations, iterations, factorizations, \
         line-search trials, substeps) per frame:"
    );
    for (k, f) in frames.iter().enumerate() {
        println!("frame {:2}: {f:?}", k + 1);
    }
    // The first frames set up the reused buffers; from the third on, every frame is one substep.
    let steady = &frames[2..];
    assert!(steady.iter().all(|f| f.4 == 1), "{steady:?}");
    let (fewest, most) = steady
        .iter()
        .fold((usize::MAX, 0), |(lo, hi), f| (lo.min(f.1), hi.max(f.1)));
    assert!(
        fewest <= 4 && most >= 15,
        "the frames span easy and hard solves: {fewest}..{most}"
    );
    let allocations = steady[0].0;
    assert!(
        steady.iter().all(|f| f.0 == allocations),
        "{what}: allocations per frame differ: {steady:?}"
    );
    if scene.solver.definite_shift_ratio == 0.0 {
        assert!(definite > 0, "{what}: no definite iteration: no test");
    }
}

/// The drape's Hessian (rest state, every vertex free) with its diagonal lowered by 1.5 × the largest
/// diagonal entry at every 7th unknown: indefinite, so LLᵀ fails and LU pivots. Ten factor-and-solve
/// rounds with different values after the first reuse the analysis and the work space: each allocates
/// less than a tenth of the first round (only faer's pivot-dependent factor storage).
fn lu_on_the_drape_s_indefinite_hessian() {
    use hinge_core::bending::{Parallelism, Request};
    use hinge_solver::linear::{FaerLlt, FaerLu, LinearError, LinearSolver};
    use hinge_solver::newton::Reduced;
    let (scene, _) = hinge_cli::scene::load("drape").unwrap();
    let rest = scene.rest_mesh(None).unwrap();
    let Built { mut system, .. } = build(&scene, &rest, true).unwrap();
    let x: Vec<_> = rest.positions().iter().map(|p| p * 1.01).collect();
    let e = system
        .evaluate(&x, Request::ALL, Parallelism::Sequential)
        .unwrap();
    let red = Reduced::new(system.pattern(), &vec![true; 3 * x.len()]);
    let base: Vec<f64> = red.source.iter().map(|&k| e.hessian[k]).collect();
    let largest = red.diag.iter().map(|&d| base[d]).fold(0.0, f64::max);
    let values = |round: usize| {
        let mut v = base.clone();
        for (i, &d) in red.diag.iter().enumerate() {
            v[d] += largest * if i % 7 == round % 7 { -1.5 } else { 0.1 };
        }
        v
    };
    let mut llt = FaerLlt::default();
    llt.analyze(&red.csc).unwrap();
    assert!(matches!(
        llt.factor(&values(0)),
        Err(LinearError::NotPositiveDefinite { .. })
    ));
    let mut lu = FaerLu::default();
    lu.analyze(&red.csc).unwrap();
    let rounds: Vec<_> = (0..11).map(values).collect();
    let rhs = vec![1.0; red.csc.n];
    let mut x = rhs.clone();
    let mut per_round = Vec::new();
    for v in &rounds {
        x.copy_from_slice(&rhs);
        let before = ALLOCATIONS.load(Ordering::SeqCst);
        lu.factor(v).unwrap();
        lu.solve(&mut x).unwrap();
        per_round.push(ALLOCATIONS.load(Ordering::SeqCst) - before);
        let mut ax = vec![0.0; red.csc.n];
        red.csc.mul(v, &x, &mut ax);
        let residual = ax
            .iter()
            .zip(&rhs)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(residual < 1e-8 * (red.csc.n as f64).sqrt(), "{residual}");
    }
    println!("LU allocations per factor and solve: {per_round:?}");
    assert!(
        per_round[1..].iter().all(|&a| 10 * a < per_round[0]),
        "{per_round:?}"
    );
}
