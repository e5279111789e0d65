//! hinge used the way an outside crate uses it: only public items of hinge-core, hinge-energies and
//! hinge-solver. A user energy implements `Energy` and composes with built-in ones; Newton minimises the
//! sum; hinge's linear solvers solve a user matrix; evaluations run on the caller's arrays and pools.

use std::sync::Arc;

use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy, HingeTerm, System};
use hinge_core::export::{CsrLayout, faer_lower, full_csr};
use hinge_core::layout::{Positions, as_vectors_mut};
use hinge_core::nalgebra::{Matrix3, Vector3};
use hinge_core::pattern::SymmetricPattern;
use hinge_core::psi::TanBending;
use hinge_core::{EvalError, TriMesh};
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::pins::Pins;
use hinge_solver::linear::{FaerLlt, LinearSolver, LowerCsc};
use hinge_solver::newton::{Newton, NewtonParams};

/// The value slot of each vertex's diagonal block, as a user energy's `bind` finds them.
fn diagonal_blocks(pattern: &SymmetricPattern, n: usize) -> Result<Vec<usize>, EvalError> {
    (0..n)
        .map(|v| {
            pattern.find(v, v).ok_or(EvalError::Pattern {
                message: format!("no diagonal block for vertex {v}"),
            })
        })
        .collect()
}

/// A user energy: every vertex tied to an anchor by a spring, `½ c ‖x_i − a_i‖²`.
struct Anchors {
    anchors: Vec<Vector3<f64>>,
    c: f64,
    diag: Vec<usize>,
}

impl Energy for Anchors {
    fn name(&self) -> &str {
        "anchors"
    }
    fn n_vertices(&self) -> usize {
        self.anchors.len()
    }
    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}
    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError> {
        self.diag = diagonal_blocks(pattern, self.anchors.len())?;
        Ok(())
    }
    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        let mut e = 0.0;
        for (i, (p, a)) in x.iter().zip(&self.anchors).enumerate() {
            let d = p - a;
            e += 0.5 * self.c * d.norm_squared();
            acc.add_gradient(i, &(d * self.c));
            if request.hessian {
                acc.add_block(self.diag[i], i, i, &(Matrix3::identity() * self.c));
            }
        }
        Ok(e)
    }
}

/// The caller's data: flat coordinates and u32 triangles of a 6×5 grid, bent.
fn user_arrays() -> (Vec<f64>, Vec<f64>, Vec<[u32; 3]>) {
    let (nx, ny) = (6usize, 5usize);
    let (mut rest, mut bent) = (Vec::new(), Vec::new());
    for j in 0..=ny {
        for i in 0..=nx {
            let (x, y) = (i as f64 / nx as f64, j as f64 / ny as f64);
            rest.extend_from_slice(&[x, y, 0.0]);
            bent.extend_from_slice(&[x, y, 0.2 * (2.0 * x).sin() * (1.0 + y)]);
        }
    }
    let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    let mut tris = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (rest, bent, tris)
}

fn assert_send_sync<T: Send + Sync>() {}
fn assert_send<T: Send>() {}

#[test]
fn types_are_send_and_sync() {
    assert_send_sync::<TriMesh>();
    assert_send_sync::<BendingModel<TanBending>>();
    assert_send_sync::<System>();
    assert_send_sync::<CsrLayout>();
    assert_send_sync::<Pins>();
    assert_send_sync::<EvalError>();
    assert_send::<FaerLlt>();
    assert_send::<Newton>();
}

#[test]
fn caller_layouts_give_the_same_mesh_and_no_copies() {
    let (rest, _, tris) = user_arrays();
    let a = TriMesh::from_arrays(&rest[..], &tris[..]).unwrap();
    let triples: Vec<[f64; 3]> = rest.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    let tris_usize: Vec<[usize; 3]> = tris.iter().map(|t| t.map(|v| v as usize)).collect();
    let b = TriMesh::from_arrays(&triples[..], &tris_usize[..]).unwrap();
    assert_eq!(a.positions(), b.positions());
    assert_eq!(a.triangles(), b.triangles());
    // Views share memory; a length that is not a multiple of three is a typed error, not a panic.
    assert_eq!(
        rest.as_vectors().unwrap().as_ptr() as *const f64,
        rest.as_ptr()
    );
    assert!(rest[..7].as_vectors().is_err());
    let mut g = vec![0.0; 9];
    as_vectors_mut(&mut g).unwrap()[1].y = 2.0;
    assert_eq!(g[4], 2.0);
}

#[test]
fn user_energy_composes_and_newton_minimises_it() {
    let (rest, bent, tris) = user_arrays();
    let mesh = TriMesh::from_arrays(&rest[..], &tris[..]).unwrap();
    let n = mesh.n_vertices();
    let anchors: Vec<Vector3<f64>> = bent.as_vectors().unwrap().to_vec();
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&mesh, TanBending { k: 0.05 }).unwrap(),
            Method::Refactored,
        )),
        Box::new(Anchors {
            anchors,
            c: 3.0,
            diag: Vec::new(),
        }),
        Box::new(Gravity::new(lumped_masses(&mesh, 1.0), Vector3::new(0.0, 0.0, -1.0)).unwrap()),
    ];
    let mut system = System::new(n, terms).unwrap();
    assert_eq!(system.term_names(), ["bending", "anchors", "gravity"]);
    // Evaluate on the caller's flat buffer; the gradient matches central differences.
    let e = system
        .evaluate(
            rest.as_vectors().unwrap(),
            Request::ALL,
            Parallelism::Sequential,
        )
        .unwrap();
    let h = 1e-6;
    for d in [0, 7, 20, 3 * n - 1] {
        let mut p = rest.clone();
        p[d] += h;
        let ep = system
            .evaluate(
                p.as_vectors().unwrap(),
                Request::VALUE,
                Parallelism::Sequential,
            )
            .unwrap()
            .energy;
        p[d] -= 2.0 * h;
        let em = system
            .evaluate(
                p.as_vectors().unwrap(),
                Request::VALUE,
                Parallelism::Sequential,
            )
            .unwrap()
            .energy;
        let fd = (ep - em) / (2.0 * h);
        assert!((fd - e.gradient[d]).abs() < 1e-6 * (1.0 + fd.abs()), "{d}");
    }
    // Newton minimises bending + the user's anchors + gravity (no pins: the anchors hold the mesh).
    let pins = Pins::new(n, vec![]).unwrap();
    let mut newton = Newton::new(
        &system,
        &pins,
        Box::new(FaerLlt::default()),
        NewtonParams::default(),
    )
    .unwrap();
    let mut x = mesh.positions().to_vec();
    let stats = newton.minimize(&mut system, &mut x, None).unwrap();
    let g = system
        .evaluate(&x, Request::GRADIENT, Parallelism::Sequential)
        .unwrap()
        .gradient;
    let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
    assert!(
        norm < 1e-7,
        "‖∇E‖ = {norm} after {} iterations",
        stats.iterations
    );
}

#[test]
fn hessian_into_caller_csr_and_faer_and_own_pool() {
    let (rest, bent, tris) = user_arrays();
    let mesh = TriMesh::from_arrays(&rest[..], &tris[..]).unwrap();
    let model = BendingModel::new(&mesh, TanBending { k: 1.0 }).unwrap();
    let x = bent.as_vectors().unwrap();
    let e = model
        .evaluate(x, Request::ALL, Method::Refactored, Parallelism::Sequential)
        .unwrap();
    // The caller's CSR values, filled without allocation, equal the one-shot export.
    let layout = CsrLayout::new(model.pattern());
    let mut values = vec![0.0; layout.nnz()];
    layout.scatter(&e.hessian, &mut values).unwrap();
    let (rp, ci, v) = full_csr(model.pattern(), &e.hessian).unwrap();
    assert_eq!((layout.row_ptr(), layout.col_idx()), (&rp[..], &ci[..]));
    assert_eq!(values, v);
    assert!(layout.scatter(&e.hessian, &mut values[1..]).is_err());
    // A faer view of the lower triangle, no copy.
    let m = faer_lower(model.pattern(), &e.hessian).unwrap();
    assert_eq!(m.nrows(), 3 * mesh.n_vertices());
    // The caller's own rayon pools: bitwise the same result for 1 and 3 threads, on a mesh large enough
    // that `Parallelism::Rayon` really runs in parallel.
    let big =
        hinge_core::grid::grid(50, 50, 1.0, 1.0, hinge_core::grid::Diagonal::Alternating).unwrap();
    let model = BendingModel::new(&big, TanBending { k: 1.0 }).unwrap();
    assert!(model.topology().hinges().len() >= hinge_core::bending::PARALLEL_MIN_HINGES);
    let bent_big = hinge_core::grid::wave(big.positions());
    let x = &bent_big[..];
    let run = |threads: usize| {
        hinge_tests::on_threads(threads, || {
            model
                .evaluate(x, Request::ALL, Method::Refactored, Parallelism::Rayon)
                .unwrap()
        })
    };
    let (one, three) = (run(1), run(3));
    assert_eq!(one.energy.to_bits(), three.energy.to_bits());
    assert!(
        one.gradient
            .iter()
            .zip(&three.gradient)
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
    assert!(
        one.hessian
            .iter()
            .zip(&three.hessian)
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
}

#[test]
fn hinge_linear_solvers_on_a_user_matrix() {
    // The user's SPD matrix: a 1D Laplacian plus the identity, lower triangle in CSC.
    let n = 50;
    let (mut col_ptr, mut row_idx, mut values) = (vec![0], Vec::new(), Vec::new());
    for c in 0..n {
        row_idx.push(c);
        values.push(3.0);
        if c + 1 < n {
            row_idx.push(c + 1);
            values.push(-1.0);
        }
        col_ptr.push(row_idx.len());
    }
    let a = LowerCsc {
        n,
        col_ptr,
        row_idx,
    };
    let b: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
    let mut solver = FaerLlt::default();
    solver.analyze(&a).unwrap();
    solver.factor(&values).unwrap();
    let mut x = b.clone();
    solver.solve(&mut x).unwrap();
    let mut ax = vec![0.0; n];
    a.mul(&values, &x, &mut ax);
    let err = ax
        .iter()
        .zip(&b)
        .map(|(p, q)| (p - q).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-13, "{err}");
    // An indefinite matrix is a typed error from LLᵀ, not a panic.
    let mut bad = values.clone();
    bad[0] = -3.0;
    assert!(solver.factor(&bad).is_err());
}

#[test]
fn energy_parameters_serialize_with_the_serde_feature() {
    use hinge_energies::bending::ViscousDamping;
    let text = serde_json::to_string(&TanBending { k: 0.25 }).unwrap();
    assert_eq!(text, r#"{"k":0.25}"#);
    let back: TanBending = serde_json::from_str(&text).unwrap();
    assert_eq!(back, TanBending { k: 0.25 });
    let d: ViscousDamping = serde_json::from_str(r#"{"kd":2.0}"#).unwrap();
    assert_eq!(d.kd, 2.0);
    assert!(serde_json::from_str::<TanBending>(r#"{"stiffness":1}"#).is_err());
}

#[test]
fn evaluate_to_fills_the_callers_buffers() {
    let (rest, bent, tris) = user_arrays();
    let mesh = TriMesh::from_arrays(&rest[..], &tris[..]).unwrap();
    let model = BendingModel::new(&mesh, TanBending { k: 1.0 }).unwrap();
    let x = bent.as_vectors().unwrap();
    let reference = model
        .evaluate(x, Request::ALL, Method::Refactored, Parallelism::Sequential)
        .unwrap();
    let mut scratch = model.new_scratch();
    // Stale values in the caller's buffers are overwritten.
    let mut grad = vec![7.0; bent.len()];
    let mut lower = vec![7.0; model.pattern().nnz()];
    let e = model
        .evaluate_to(
            x,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
            &mut scratch,
            &mut grad,
            &mut lower,
        )
        .unwrap();
    assert_eq!(e, reference.energy);
    assert_eq!(grad, reference.gradient);
    assert_eq!(lower, reference.hessian);
    // A gradient-only request may pass an empty Hessian buffer; a short buffer is a typed error.
    model
        .evaluate_to(
            x,
            Request::GRADIENT,
            Method::Refactored,
            Parallelism::Sequential,
            &mut scratch,
            &mut grad,
            &mut [],
        )
        .unwrap();
    let err = model
        .evaluate_to(
            x,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
            &mut scratch,
            &mut grad[1..],
            &mut lower,
        )
        .unwrap_err();
    assert!(err.to_string().contains("gradient"), "{err}");
}

/// A double well per vertex, `−½ a |x|² + ¼ b |x|⁴` (minimum on the sphere |x| = √(a/b)); near the origin its
/// Hessian is negative definite, so Newton needs a large diagonal shift there.
struct DoubleWell {
    n: usize,
    a: f64,
    b: f64,
    diag: Vec<usize>,
}

impl Energy for DoubleWell {
    fn name(&self) -> &str {
        "double-well"
    }
    fn n_vertices(&self) -> usize {
        self.n
    }
    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}
    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError> {
        self.diag = diagonal_blocks(pattern, self.n)?;
        Ok(())
    }
    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        let (a, b) = (self.a, self.b);
        let mut e = 0.0;
        for (i, p) in x.iter().enumerate() {
            let r2 = p.norm_squared();
            e += -0.5 * a * r2 + 0.25 * b * r2 * r2;
            acc.add_gradient(i, &(p * (-a + b * r2)));
            if request.hessian {
                let h = Matrix3::identity() * (-a + b * r2) + p * p.transpose() * (2.0 * b);
                acc.add_block(self.diag[i], i, i, &h);
            }
        }
        Ok(e)
    }
}

/// One vertex in the double well `a = b = 1e6` (minimum on |x| = 1) and a Newton bound to it with `params`.
fn double_well_newton(params: NewtonParams) -> (System, Newton) {
    let well = DoubleWell {
        n: 1,
        a: 1e6,
        b: 1e6,
        diag: Vec::new(),
    };
    let system = System::new(1, vec![Box::new(well)]).unwrap();
    let pins = Pins::new(1, Vec::new()).unwrap();
    let newton = Newton::new(&system, &pins, Box::new(FaerLlt::default()), params).unwrap();
    (system, newton)
}

#[test]
fn a_short_shifted_step_is_not_taken_for_convergence() {
    // From near the top of the well the Hessian is −a·I: the shifted steps are short (about a third of
    // |x|), far shorter than a user's absolute step tolerance of 1e-3. Newton must not stop there: it
    // continues to the minimum and says so with a small gradient.
    let (mut system, mut newton) = double_well_newton(NewtonParams {
        gradient_tolerance: 1e-6,
        step_tolerance: 1e-3,
        max_iterations: 200,
        ..NewtonParams::default()
    });
    let mut x = vec![Vector3::new(1e-3, 0.0, 0.0)];
    let stats = newton.minimize(&mut system, &mut x, None).unwrap();
    let g = stats.gradient_norms.last().copied().unwrap();
    assert!(stats.max_shift > 0.0, "the start needs a shift");
    assert!(stats.iterations > 1, "{stats:?}");
    // Stopped by the step test only after a full Newton step (≤ 1e-3) near the minimum |x| = 1, where
    // Newton converges quadratically: the error is then about 1.5 · (1e-3)², the gradient (H = 2e6) a few N
    // against 1e3 at the start.
    println!(
        "{} iterations, |x| − 1 = {:e}, gradient {g:e}",
        stats.iterations,
        x[0].norm() - 1.0
    );
    assert!((x[0].norm() - 1.0).abs() < 2e-6, "{}", x[0]);
    assert!(g < 5.0, "gradient {g}");
}

#[test]
fn extrapolation_escapes_a_saddle_in_few_iterations() {
    // From 1e-6 off the top of the well the Hessian is −a·I: a shift σ > a is needed, and each shifted
    // step multiplies |x| by σ/(σ − a), 4/3 for the ladder's σ = 4a. Without extrapolation Newton crawls
    // off the saddle (log(1e6)/log(4/3) ≈ 48 iterations); doubling the full shifted step while F
    // decreases leaves it in a few. Both must end at the minimum |x| = 1 with a small gradient.
    let run = |extrapolate: bool| {
        let (mut system, mut newton) = double_well_newton(NewtonParams {
            gradient_tolerance: 1e-6,
            max_iterations: 200,
            extrapolate,
            ..NewtonParams::default()
        });
        let mut x = vec![Vector3::new(1e-6, 0.0, 0.0)];
        let stats = newton.minimize(&mut system, &mut x, None).unwrap();
        assert!((x[0].norm() - 1.0).abs() < 1e-12, "{}", x[0]);
        assert!(*stats.gradient_norms.last().unwrap() <= 1e-6, "{stats:?}");
        stats
    };
    let (with, without) = (run(true), run(false));
    println!(
        "iterations with extrapolation {}, without {}",
        with.iterations, without.iterations
    );
    assert!(with.iterations <= 12, "{with:?}");
    assert!(without.iterations >= 3 * with.iterations, "{without:?}");
    // Extrapolation trials are energy evaluations only, counted with the line search; no factorization.
    assert!(with.factorizations < without.factorizations);
}
