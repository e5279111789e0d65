//! The assembly engine: the three methods agree, match finite differences and the outside world (shared
//! reference data), and are bitwise deterministic across thread counts.

use hinge_core::bending::{BendingModel, Evaluation, Method, Parallelism, Request};
use hinge_core::grid::{Diagonal, grid, unit_grid};
use hinge_core::obj::read_obj;
use hinge_core::psi::{DiscreteShells, HingePsi, TanBending};
use hinge_core::{TriMesh, nalgebra::Vector3};
use hinge_tests::*;

fn data(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

fn ds() -> DiscreteShells {
    DiscreteShells { k: 1.0 }
}

fn frob<P: HingePsi>(m: &BendingModel<P>, e: &Evaluation) -> f64 {
    sym_frobenius(m.pattern().col_ptr(), m.pattern().row_idx(), &e.hessian)
}

#[test]
fn reproduces_libshell_tinyad_codim_ipc_reference() {
    let rest = read_obj(data("grid80_rest.obj")).unwrap();
    let def = read_obj(data("grid80_jitter.obj")).unwrap();
    let model = BendingModel::new(&rest, ds()).unwrap();
    assert_eq!(model.topology().hinges().len(), 19040);
    assert_eq!(model.pattern().nnz_full(), 750249);
    for method in [Method::Refactored, Method::PerHinge] {
        let e = model
            .evaluate(def.positions(), Request::ALL, method, Parallelism::Rayon)
            .unwrap();
        let g: f64 = e.gradient.iter().map(|v| v * v).sum::<f64>().sqrt();
        let h = frob(&model, &e);
        println!(
            "{method:?}: E {:.16e} |g| {:.16e} |H|_F {:.16e}",
            e.energy, g, h
        );
        let rel = |a: f64, b: f64| ((a - b) / b).abs();
        assert!(
            rel(e.energy, 980.040445327099) < 1e-13,
            "energy {}",
            e.energy
        );
        assert!(rel(g, 53449.98132754365) < 1e-13, "gradient norm {g}");
        assert!(rel(h, 92530009.93375617) < 1e-13, "hessian norm {h}");
    }
}

#[test]
fn regenerated_reference_mesh_matches_the_files() {
    let rest = unit_grid(80).unwrap();
    let file = read_obj(data("grid80_rest.obj")).unwrap();
    assert_eq!(rest.triangles(), file.triangles());
    let jit = reference_jitter(rest.positions());
    let def = read_obj(data("grid80_jitter.obj")).unwrap();
    for (a, b) in jit.iter().zip(def.positions()) {
        assert!((a - b).norm() < 1e-15, "{a} vs {b}");
    }
}

/// An irregular mesh with boundary and a non-flat rest shape: an alternating grid, rest bent into a cylinder
/// patch with jitter, deformed by a wave plus jitter.
fn irregular() -> (TriMesh, Vec<Vector3<f64>>) {
    let flat = grid(9, 7, 1.3, 1.0, Diagonal::Alternating).unwrap();
    let mut rng = SplitMix64(3);
    let rest: Vec<_> = flat
        .positions()
        .iter()
        .map(|p| {
            let a = p.x * 1.2;
            Vector3::new(
                a.sin(),
                p.y + 0.02 * rng.symmetric(),
                1.0 - a.cos() + 0.02 * rng.symmetric(),
            )
        })
        .collect();
    let rest = flat.with_positions(rest).unwrap();
    let def = rest
        .positions()
        .iter()
        .map(|p| {
            p + Vector3::new(
                0.03 * rng.symmetric(),
                0.03 * rng.symmetric(),
                0.2 * (2.0 * p.y).sin(),
            )
        })
        .collect();
    (rest, def)
}

fn cases() -> Vec<(&'static str, TriMesh, Vec<Vector3<f64>>)> {
    let g = unit_grid(12).unwrap();
    let gd = reference_jitter(g.positions());
    let (r, d) = irregular();
    vec![("grid", g, gd), ("irregular", r, d)]
}

fn method_agreement<P: HingePsi + Clone>(psi: P, bound_ulps: f64) {
    for (name, rest, def) in cases() {
        let model = BendingModel::new(&rest, psi.clone()).unwrap();
        let ev = |m| {
            model
                .evaluate(&def, Request::ALL, m, Parallelism::Sequential)
                .unwrap()
        };
        let (r, p, a) = (
            ev(Method::Refactored),
            ev(Method::PerHinge),
            ev(Method::Autodiff),
        );
        let ulps = |x: &[f64], y: &[f64]| rel_error(x, y) / UNIT_ROUNDOFF;
        let (rp, ra, pa) = (
            ulps(&r.hessian, &p.hessian),
            ulps(&r.hessian, &a.hessian),
            ulps(&p.hessian, &a.hessian),
        );
        let (gp, ga) = (
            ulps(&r.gradient, &p.gradient),
            ulps(&r.gradient, &a.gradient),
        );
        println!(
            "{name}: hessian refactored~per_hinge {rp:.2} refactored~autodiff {ra:.2} per_hinge~autodiff {pa:.2} ulps; gradient {gp:.2} {ga:.2}"
        );
        assert_eq!(r.energy, p.energy);
        assert!(rp <= bound_ulps && ra <= bound_ulps && pa <= bound_ulps);
        // Same per-hinge gradients, summed per vertex in triangle order vs hinge order.
        assert!(gp <= 8.0, "gradient refactored vs per_hinge {gp} ulps");
        assert!(ga <= bound_ulps);
    }
}

#[test]
fn methods_agree_discrete_shells() {
    method_agreement(ds(), 64.0);
}

#[test]
fn methods_agree_tan_bending() {
    method_agreement(TanBending { k: 2.5 }, 64.0);
}

#[test]
fn whole_mesh_gradient_and_hessian_match_finite_differences() {
    let (rest, def) = irregular();
    let model = BendingModel::new(&rest, TanBending { k: 1.0 }).unwrap();
    let e = model
        .evaluate(
            &def,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    let dense = sym_dense(model.pattern(), &e.hessian);
    let (fd_g, fd_h) = fd_energy_derivatives(&def, 1e-6, |y| {
        let r = model
            .evaluate(
                y,
                Request::GRADIENT,
                Method::Refactored,
                Parallelism::Sequential,
            )
            .unwrap();
        (r.energy, r.gradient)
    });
    let eg = rel_error(&e.gradient, &fd_g);
    let eh = rel_error(&dense, &fd_h);
    println!("whole mesh: gradient vs FD {eg:.3e}, hessian vs FD {eh:.3e}");
    assert!(eg < 1e-7 && eh < 1e-7);
}

#[test]
fn bitwise_identical_for_any_thread_count() {
    // Large enough for several partitions.
    let rest = unit_grid(90).unwrap();
    let def = reference_jitter(rest.positions());
    let model = BendingModel::new(&rest, TanBending { k: 1.0 }).unwrap();
    // Above the size below which `Parallelism::Rayon` runs sequentially.
    assert!(model.topology().hinges().len() >= hinge_core::bending::PARALLEL_MIN_HINGES);
    for method in [Method::Refactored, Method::PerHinge] {
        let seq = model
            .evaluate(&def, Request::ALL, method, Parallelism::Sequential)
            .unwrap();
        for threads in [1, 2, 3] {
            let par = on_threads(threads, || {
                model
                    .evaluate(&def, Request::ALL, method, Parallelism::Rayon)
                    .unwrap()
            });
            assert_eq!(seq.energy.to_bits(), par.energy.to_bits());
            assert!(
                seq.gradient
                    .iter()
                    .zip(&par.gradient)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
            assert!(
                seq.hessian
                    .iter()
                    .zip(&par.hessian)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
        }
    }
}

#[test]
fn boundary_edges_contribute_nothing_and_tiny_meshes_work() {
    let quad = vec![
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(1.0, 1.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
    ];
    // One triangle: no hinge, zero everything, a diagonal-only pattern.
    let one = TriMesh::new(quad[..3].to_vec(), vec![[0, 1, 2]]).unwrap();
    let m1 = BendingModel::new(&one, ds()).unwrap();
    let mut bent = one.positions().to_vec();
    bent[2].z = 0.4;
    let e1 = m1
        .evaluate(
            &bent,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    assert_eq!(e1.energy, 0.0);
    assert!(e1.gradient.iter().chain(&e1.hessian).all(|&v| v == 0.0));
    assert_eq!(m1.pattern().nnz(), 3 * 6);
    // Two triangles: one hinge; all methods agree with the single-hinge kernel.
    let two = TriMesh::new(quad.clone(), vec![[0, 1, 2], [0, 2, 3]]).unwrap();
    let m2 = BendingModel::new(&two, ds()).unwrap();
    let mut def = quad.clone();
    def[3].z = 0.5;
    let r = m2
        .evaluate(
            &def,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    let x = m2.topology().hinges()[0].vertices.map(|v| def[v]);
    let theta = hinge_core::hinge::hinge_angle(&x).unwrap();
    let a = m2.rest_hinges()[0].a;
    assert!((r.energy - a * theta * theta).abs() < 1e-15);
    for method in [Method::PerHinge, Method::Autodiff] {
        let o = m2
            .evaluate(&def, Request::ALL, method, Parallelism::Sequential)
            .unwrap();
        assert!(rel_error(&o.hessian, &r.hessian) < 1e-14);
        assert!(rel_error(&o.gradient, &r.gradient) < 1e-14);
    }
    // A vertex in no hinge stencil (here: in no triangle at all) gets no gradient, no Hessian coupling, and
    // moving it changes nothing.
    let mut five = quad.clone();
    five.push(Vector3::new(2.0, 0.5, 0.0));
    let m3 = BendingModel::new(
        &TriMesh::new(five.clone(), vec![[0, 1, 2], [0, 2, 3]]).unwrap(),
        ds(),
    )
    .unwrap();
    let mut bent = def.clone();
    bent.push(five[4]);
    let a = m3
        .evaluate(
            &bent,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    bent[4] += Vector3::new(0.3, -0.2, 0.7);
    let b = m3
        .evaluate(
            &bent,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    assert_eq!(a, b);
    assert_eq!(&a.gradient[12..15], &[0.0; 3]);
    assert_eq!(m3.pattern().find(4, 0), None);
    assert_eq!(a.energy, r.energy);
}

#[test]
fn unrequested_outputs_are_untouched_and_errors_name_the_hinge() {
    let rest = unit_grid(6).unwrap();
    let model = BendingModel::new(&rest, TanBending { k: 1.0 }).unwrap();
    let def = reference_jitter(rest.positions());
    let mut out = model.new_output();
    out.hessian.fill(7.0);
    let mut scratch = model.new_scratch();
    model
        .evaluate_into(
            &def,
            Request::GRADIENT,
            Method::Refactored,
            Parallelism::Sequential,
            &mut scratch,
            &mut out,
        )
        .unwrap();
    assert!(out.hessian.iter().all(|&v| v == 7.0));
    // Fold hinge 5 flat onto itself (θ = π in floating point): tan(θ/2) is huge but finite in f64, so the
    // result is finite everywhere (never NaN) or a typed error.
    let h = model.topology().hinges()[5];
    let mut folded = rest.positions().to_vec();
    let mid = (folded[h.vertices[1]] + folded[h.vertices[2]]) * 0.5;
    folded[h.vertices[3]] = mid + (folded[h.vertices[0]] - mid) * 0.5;
    match model.evaluate(
        &folded,
        Request::ALL,
        Method::Refactored,
        Parallelism::Sequential,
    ) {
        Ok(e) => assert!(
            e.energy.is_finite() && e.gradient.iter().chain(&e.hessian).all(|v| v.is_finite())
        ),
        Err(e) => assert!(matches!(e, hinge_core::EvalError::NonFiniteEnergy { .. })),
    }
    // A collapsed triangle in the deformed state: a typed error naming the lowest hinge that uses it.
    let mut collapsed = rest.positions().to_vec();
    let h0 = model.topology().hinges()[0];
    collapsed[h0.vertices[0]] = (collapsed[h0.vertices[1]] + collapsed[h0.vertices[2]]) * 0.5;
    match model.evaluate(
        &collapsed,
        Request::ALL,
        Method::Refactored,
        Parallelism::Rayon,
    ) {
        Err(hinge_core::EvalError::Hinge { hinge, .. }) => assert_eq!(hinge, 0),
        other => panic!("expected a hinge error, got {:?}", other.map(|e| e.energy)),
    }
    let mut nan = def.clone();
    nan[3].x = f64::NAN;
    assert!(
        model
            .evaluate(&nan, Request::ALL, Method::Refactored, Parallelism::Rayon)
            .is_err()
    );
    assert!(
        model
            .evaluate(
                &def[1..],
                Request::ALL,
                Method::Refactored,
                Parallelism::Rayon
            )
            .is_err()
    );
}

#[test]
fn exports_agree_with_each_other() {
    let (rest, def) = irregular();
    let model = BendingModel::new(&rest, ds()).unwrap();
    let e = model
        .evaluate(
            &def,
            Request::ALL,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap();
    let p = model.pattern();
    let dense = sym_dense(p, &e.hessian);
    let n = p.dim();
    // Full CSR holds both triangles, rows sorted, and equals the dense expansion.
    let (rp, ci, v) = hinge_core::export::full_csr(p, &e.hessian).unwrap();
    assert_eq!(v.len(), p.nnz_full());
    let mut from_csr = vec![0.0; n * n];
    for r in 0..n {
        assert!(ci[rp[r]..rp[r + 1]].windows(2).all(|w| w[0] < w[1]));
        for k in rp[r]..rp[r + 1] {
            from_csr[r * n + ci[k]] = v[k];
        }
    }
    assert_eq!(from_csr, dense);
    // The faer view holds the same lower triangle.
    let m = hinge_core::export::faer_lower(p, &e.hessian).unwrap();
    assert_eq!((m.nrows(), m.ncols()), (n, n));
    assert_eq!(m.compute_nnz(), p.nnz());
    assert!(hinge_core::export::faer_lower(p, &e.hessian[1..]).is_err());
    // Matrix Market text parses back to the values.
    let mut buf = Vec::new();
    hinge_core::export::write_matrix_market(&mut buf, p, &e.hessian).unwrap();
    let text = String::from_utf8(buf).unwrap();
    assert!(text.starts_with("%%MatrixMarket matrix coordinate real symmetric"));
    // Entries (row ≥ column, 1-based, the caller's numbering) equal the dense expansion.
    let mut count = 0;
    for l in text.lines().filter(|l| !l.starts_with('%')).skip(1) {
        let w: Vec<&str> = l.split_whitespace().collect();
        let (r, c): (usize, usize) = (w[0].parse().unwrap(), w[1].parse().unwrap());
        assert!(r >= c);
        assert_eq!(w[2].parse::<f64>().unwrap(), dense[(r - 1) * n + c - 1]);
        count += 1;
    }
    assert_eq!(count, p.nnz());
}
