//! Meshes as users bring them: closed surfaces, boundaries, slivers, random numbering and every corner
//! rotation of a face. Each comparison is against something computed independently (another method, the
//! double-double reference, the same mesh numbered otherwise, or values from outside implementations).

use std::collections::HashMap;

use hinge_core::bending::{BendingModel, Evaluation, Method, Parallelism, Request};
use hinge_core::export::full_csr;
use hinge_core::grid::{reference_jitter, unit_grid};
use hinge_core::pattern::SymmetricPattern;
use hinge_core::precise::{Dd, Jet, reference_hessian};
use hinge_core::psi::{DiscreteShells, HingePsi, TanBending};
use hinge_core::shapes::{
    bend, icosphere, irregular_sheet, random_permutation, renumber, renumber_positions,
    sliver_sheet, torus,
};
use hinge_core::{EvalError, MeshError, TriMesh};
use hinge_tests::{SplitMix64, on_threads, rel_error};
use nalgebra::Vector3;

const SEQ: Parallelism = Parallelism::Sequential;

fn eval<P: HingePsi>(m: &BendingModel<P>, x: &[Vector3<f64>], method: Method) -> Evaluation {
    m.evaluate(x, Request::ALL, method, SEQ).unwrap()
}

/// Positions rounded to multiples of 2⁻⁴⁰, so that every coordinate difference is exact: the errors measured
/// are those of the formulas, not of representing a sliver's inputs.
fn quantize(x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let s = (40f64).exp2();
    x.iter().map(|p| p.map(|c| (c * s).round() / s)).collect()
}

/// The mesh with face `t`'s corners rotated left by `rot(t)` (the same triangles, listed from another corner).
fn rotate_faces(mesh: &TriMesh, rot: impl Fn(usize) -> usize) -> TriMesh {
    let tris = mesh
        .triangles()
        .iter()
        .enumerate()
        .map(|(t, f)| {
            let mut f = *f;
            f.rotate_left(rot(t) % 3);
            f
        })
        .collect();
    TriMesh::new(mesh.positions().to_vec(), tris).unwrap()
}

/// Σ k·a·(θ − θ̄)² assembled in double-double into `model`'s pattern.
fn dd_reference(model: &BendingModel<DiscreteShells>, x: &[Vector3<f64>]) -> Vec<Dd> {
    let k = model.psi().k;
    let rest = model.rest_hinges();
    reference_hessian(model, x, |h, t| {
        let d = t - Jet::constant(Dd::from(rest[h].theta_bar));
        (d * d) * (Dd::from(k) * Dd::from(rest[h].a))
    })
}

/// Normwise error of the full symmetric matrix in ulps (off-diagonal stored entries count twice).
fn hessian_ulps(p: &SymmetricPattern, values: &[f64], reference: &[Dd]) -> f64 {
    hinge_core::precise::hessian_ulps(p, values, reference)
}

/// The meshes of the double-double comparison, quantized (rest and deformed).
fn reference_meshes() -> Vec<(String, TriMesh, Vec<Vector3<f64>>)> {
    let mut out = Vec::new();
    for seed in [1u64, 2, 3] {
        let rest = sliver_sheet(10, seed).unwrap();
        out.push((
            format!("sliver sheet {seed}"),
            rest.clone(),
            bend(rest.positions()),
        ));
    }
    let wobble = |m: &TriMesh| -> Vec<Vector3<f64>> {
        m.positions()
            .iter()
            .map(|p| p * (1.0 + 0.08 * (3.0 * p.x).sin() * (2.0 * p.y + p.z).cos()))
            .collect()
    };
    let ico = icosphere(2, 1.0).unwrap();
    let tor = torus(16, 10, 1.0, 0.35).unwrap();
    let irr = irregular_sheet(14, 12, 21).unwrap();
    out.push(("icosphere".into(), ico.clone(), wobble(&ico)));
    out.push(("torus".into(), tor.clone(), wobble(&tor)));
    out.push(("irregular".into(), irr.clone(), bend(irr.positions())));
    out.into_iter()
        .map(|(name, rest, x)| {
            let rest = TriMesh::new(quantize(rest.positions()), rest.triangles().to_vec()).unwrap();
            (name, rest, quantize(&x))
        })
        .collect()
}

#[test]
fn every_test_mesh_under_every_corner_rotation_meets_the_double_double_bound() {
    for (name, rest, x) in reference_meshes() {
        let mut rng = SplitMix64(rest.n_triangles() as u64);
        let random: Vec<usize> = (0..rest.n_triangles())
            .map(|_| (rng.next_u64() % 3) as usize)
            .collect();
        let mut first: Option<Vec<f64>> = None;
        for rot in 0..4 {
            let mesh = if rot < 3 {
                rotate_faces(&rest, |_| rot)
            } else {
                rotate_faces(&rest, |t| random[t])
            };
            let model = BendingModel::new(&mesh, DiscreteShells { k: 1.0 }).unwrap();
            let reference = dd_reference(&model, &x);
            let r = eval(&model, &x, Method::Refactored);
            let ph = eval(&model, &x, Method::PerHinge);
            let (ur, up) = (
                hessian_ulps(model.pattern(), &r.hessian, &reference),
                hessian_ulps(model.pattern(), &ph.hessian, &reference),
            );
            println!(
                "{name}, rotation {}: {} triangles, refactored {ur:.2} ulps, per_hinge {up:.2} ulps",
                if rot < 3 {
                    rot.to_string()
                } else {
                    "random".into()
                },
                mesh.n_triangles()
            );
            assert!(
                ur <= (1.25 * up).max(4.0),
                "{name}: refactored {ur} vs per_hinge {up}"
            );
            // The rounding does not depend on which corner a face lists first: bit for bit.
            match &first {
                None => first = Some(r.hessian.clone()),
                Some(h) => assert!(
                    h == &r.hessian,
                    "{name}: refactored changed under rotation {rot}"
                ),
            }
        }
    }
}

#[test]
fn every_stencil_of_a_sliver_sheet_under_all_nine_rotations() {
    // Each hinge as its own two-triangle mesh, both faces in each of their three corner orders.
    let rest = sliver_sheet(8, 7).unwrap();
    let x = quantize(&bend(rest.positions()));
    let rest_q = quantize(rest.positions());
    let topo = hinge_core::Topology::new(rest.n_vertices(), rest.triangles()).unwrap();
    let (mut worst_ratio, mut n) = (0.0f64, 0);
    let mut over = Vec::new();
    for h in topo.hinges() {
        let [x0, x1, x2, x3] = h.vertices;
        let pos = |p: &[Vector3<f64>]| vec![p[x0], p[x1], p[x2], p[x3]];
        let base = [[0, 1, 2], [3, 2, 1]];
        let mut first: Option<Vec<f64>> = None;
        for ra in 0..3 {
            for rb in 0..3 {
                let mut f = base;
                f[0].rotate_left(ra);
                f[1].rotate_left(rb);
                let mesh = TriMesh::new(pos(&rest_q), f.to_vec()).unwrap();
                let model = BendingModel::new(&mesh, DiscreteShells { k: 1.0 }).unwrap();
                let xs = pos(&x);
                let reference = dd_reference(&model, &xs);
                let r = eval(&model, &xs, Method::Refactored);
                let ph = eval(&model, &xs, Method::PerHinge);
                let ur = hessian_ulps(model.pattern(), &r.hessian, &reference);
                let up = hessian_ulps(model.pattern(), &ph.hessian, &reference);
                worst_ratio = worst_ratio.max(ur / up.max(4.0 / 1.25));
                if ur > (1.25 * up).max(4.0) {
                    over.push((ur, up));
                }
                n += 1;
                match &first {
                    None => first = Some(r.hessian.clone()),
                    Some(v) => assert!(v == &r.hessian, "rotation changed the refactored Hessian"),
                }
            }
        }
    }
    let worst = over.iter().map(|o| o.0).fold(0.0f64, f64::max);
    println!(
        "{n} stencil orderings ({} stencils × 9): worst refactored / max(per_hinge, 3.2 ulps) = {worst_ratio:.3}; {} orderings over max(4 ulps, 1.25 × per_hinge), the worst at {worst:.2} ulps: {:?}",
        n / 9,
        over.len(),
        over.iter().step_by(9).collect::<Vec<_>>()
    );
    // Measured: a few stencils (4 of 235) exceed the per-mesh bound on their own, at 4.4–6.1 ulps against
    // per_hinge's 1.5–3.3 (the ψ″ outer product uses the hinge pass's unnormalised ∇θ, which is 2–3 ulps less
    // accurate there than the frames' ∇θ per_hinge uses, though more accurate on average over all stencils);
    // every whole mesh meets it (test above).
    assert!(
        worst_ratio < 2.0 && over.iter().all(|o| o.0 < 8.0),
        "{over:?}"
    );
    assert!(
        over.len() * 50 <= n,
        "more than 2% of the stencil orderings over the bound"
    );
}

/// Energy, gradient and full Hessian (as a map over the caller's dofs) of a model.
fn in_caller_numbering<P: HingePsi>(
    m: &BendingModel<P>,
    e: &Evaluation,
) -> (f64, Vec<f64>, HashMap<(usize, usize), f64>) {
    let (rp, ci, v) = full_csr(m.pattern(), &e.hessian).unwrap();
    let mut h = HashMap::new();
    for r in 0..rp.len() - 1 {
        for k in rp[r]..rp[r + 1] {
            h.insert((r, ci[k]), v[k]);
        }
    }
    (e.energy, e.gradient.clone(), h)
}

fn closed_and_irregular() -> Vec<(&'static str, TriMesh, Vec<Vector3<f64>>)> {
    let wobble = |m: &TriMesh| -> Vec<Vector3<f64>> {
        m.positions()
            .iter()
            .map(|p| p * (1.0 + 0.08 * (3.0 * p.x).sin() * (2.0 * p.y + p.z).cos()))
            .collect()
    };
    let ico = icosphere(3, 1.0).unwrap();
    let tor = torus(24, 12, 1.0, 0.35).unwrap();
    let irr = irregular_sheet(24, 20, 11).unwrap();
    let sliv = sliver_sheet(10, 5).unwrap();
    let (xi, xt) = (wobble(&ico), wobble(&tor));
    let (xr, xs) = (bend(irr.positions()), bend(sliv.positions()));
    vec![
        ("icosphere", ico, xi),
        ("torus", tor, xt),
        ("irregular", irr, xr),
        ("slivers", sliv, xs),
    ]
}

fn agreement_on<P: HingePsi + Clone>(psi: P, name: &str) {
    for (mesh_name, mesh, x) in closed_and_irregular() {
        let perm = random_permutation(mesh.n_vertices(), 99);
        let renumbered = renumber(&mesh, &perm).unwrap();
        let xr = renumber_positions(&x, &perm);
        let m = BendingModel::new(&mesh, psi.clone()).unwrap();
        let mr = BendingModel::new(&renumbered, psi.clone()).unwrap();
        assert_eq!(m.topology().hinges().len(), mr.topology().hinges().len());
        let (er, gr, hr) = in_caller_numbering(&m, &eval(&m, &x, Method::Refactored));
        for (model, xx, renum) in [(&m, &x, false), (&mr, &xr, true)] {
            for method in Method::ALL {
                let (e, g, h) = in_caller_numbering(model, &eval(model, xx, method));
                // Back to the original numbering.
                let g: Vec<f64> = if renum {
                    (0..3 * perm.len())
                        .map(|d| g[3 * perm[d / 3] + d % 3])
                        .collect()
                } else {
                    g
                };
                let map = |d: usize| if renum { 3 * perm[d / 3] + d % 3 } else { d };
                let (mut num, mut den) = (0.0, 0.0);
                for (&(r, c), &v) in &hr {
                    let w = h.get(&(map(r), map(c))).copied().unwrap_or(f64::NAN);
                    num += (w - v) * (w - v);
                    den += v * v;
                }
                assert_eq!(h.len(), hr.len(), "{mesh_name}: same pattern size");
                let eh = (num / den).sqrt();
                let ee = ((e - er) / er).abs();
                let eg = rel_error(&g, &gr);
                let bound = if method == Method::Autodiff {
                    1e-11
                } else {
                    1e-12
                };
                println!(
                    "{name} {mesh_name}{}: {} vs refactored: energy {ee:.1e}, gradient {eg:.1e}, Hessian {eh:.1e}",
                    if renum { " (renumbered)" } else { "" },
                    method.name()
                );
                assert!(
                    ee < 1e-13 && eg < bound && eh < bound,
                    "{mesh_name} {}",
                    method.name()
                );
            }
        }
    }
}

#[test]
fn methods_and_numberings_agree_on_closed_irregular_and_sliver_meshes() {
    agreement_on(DiscreteShells { k: 1.0 }, "discrete shells");
    agreement_on(TanBending { k: 0.7 }, "tan bending");
}

#[test]
fn bitwise_identical_for_any_thread_count_on_renumbered_and_closed_meshes() {
    let ico = icosphere(4, 1.0).unwrap();
    let irr = irregular_sheet(70, 60, 4).unwrap();
    let perm = random_permutation(ico.n_vertices(), 5);
    let ico_r = renumber(&ico, &perm).unwrap();
    for mesh in [ico, ico_r, irr] {
        let x: Vec<Vector3<f64>> = mesh
            .positions()
            .iter()
            .map(|p| p + Vector3::new(0.0, 0.0, 0.05 * (4.0 * p.x).sin()))
            .collect();
        let model = BendingModel::new(&mesh, TanBending { k: 1.0 }).unwrap();
        assert!(model.topology().hinges().len() >= hinge_core::bending::PARALLEL_MIN_HINGES);
        let run = |threads: usize, method: Method| {
            on_threads(threads, || {
                model
                    .evaluate(&x, Request::ALL, method, Parallelism::Rayon)
                    .unwrap()
            })
        };
        for method in [Method::Refactored, Method::PerHinge] {
            let one = run(1, method);
            assert_eq!(one, run(2, method));
            assert_eq!(one, run(3, method));
            assert_eq!(one, model.evaluate(&x, Request::ALL, method, SEQ).unwrap());
        }
    }
}

#[test]
fn the_near_degenerate_pair_is_evaluated_or_rejected_alike_by_every_method() {
    // Triangles [1, 2, 0] and [3, 2, 1]; vertex 0 at distance δ from the hinge edge 1–2 in the deformed
    // state, δ swept through the degeneracy threshold (relative altitude 16ε).
    let rest = vec![
        Vector3::new(0.5, -0.4, 0.0),
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.5, 0.7, 0.3),
    ];
    let (mut ok, mut rejected) = (0, 0);
    for rot in 0..9 {
        let mut f = [[1, 2, 0], [3, 2, 1]];
        f[0].rotate_left(rot % 3);
        f[1].rotate_left(rot / 3);
        let mesh = TriMesh::new(rest.clone(), f.to_vec()).unwrap();
        let model = BendingModel::new(&mesh, DiscreteShells { k: 1.0 }).unwrap();
        for step in 0..=64 {
            let delta = f64::EPSILON * (8.0 + 0.5 * step as f64);
            let mut x = rest.clone();
            x[0] = Vector3::new(0.5, -delta, 0.0);
            let results: Vec<_> = Method::ALL
                .iter()
                .map(|&m| model.evaluate(&x, Request::ALL, m, SEQ))
                .collect();
            let all_ok = results.iter().all(|r| r.is_ok());
            let all_err = results.iter().all(|r| r.is_err());
            assert!(
                all_ok || all_err,
                "δ = {delta:e}: the methods disagree: {results:?}"
            );
            if all_err {
                rejected += 1;
                for r in &results {
                    assert!(matches!(r, Err(EvalError::Hinge { hinge: 0, .. })), "{r:?}");
                }
            } else {
                ok += 1;
                let norms: Vec<f64> = results
                    .iter()
                    .map(|r| {
                        let h = &r.as_ref().unwrap().hessian;
                        h.iter().map(|v| v * v).sum::<f64>().sqrt()
                    })
                    .collect();
                // Nothing dropped: the Hessians (≈ 1/δ²) have the same size whatever the method.
                assert!(
                    norms[0] / norms[1] > 0.5 && norms[0] / norms[1] < 2.0,
                    "δ = {delta:e}: refactored {} vs per_hinge {}",
                    norms[0],
                    norms[1]
                );
            }
        }
    }
    println!("near-degenerate sweep: {ok} evaluated, {rejected} rejected by every method");
    assert!(ok > 0 && rejected > 0, "the sweep crosses the threshold");
}

#[test]
fn n400_reference_values_from_outside_implementations() {
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/grid80_reference.json"),
    )
    .unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let n400 = &json["n400"];
    let rest = unit_grid(400).unwrap();
    let x = reference_jitter(rest.positions());
    let model = BendingModel::new(&rest, DiscreteShells { k: 1.0 }).unwrap();
    assert_eq!(
        model.topology().hinges().len() as u64,
        n400["n_hinges"].as_u64().unwrap()
    );
    for method in [Method::Refactored, Method::PerHinge] {
        let e = model
            .evaluate(&x, Request::ALL, method, Parallelism::Rayon)
            .unwrap();
        let (_, _, v) = full_csr(model.pattern(), &e.hessian).unwrap();
        let frob = v.iter().map(|a| a * a).sum::<f64>().sqrt();
        let rel = |a: f64, b: f64| ((a - b) / b).abs();
        let (ee, eh) = (
            rel(e.energy, n400["energy"].as_f64().unwrap()),
            rel(frob, n400["hessian_frobenius_full"].as_f64().unwrap()),
        );
        println!(
            "N = 400 {}: energy {} (rel {ee:.1e}), Hessian Frobenius {frob} (rel {eh:.1e})",
            method.name(),
            e.energy
        );
        // The JSON records the energy to 13 significant digits and the Frobenius norm to 11
        // (3795147231500.0): allow half a unit of the last recorded digit, plus 1e-12 relative for the
        // implementations' own spread on this stress case (many hinges nearly folded).
        let half_unit =
            |v: f64, digits: i32| 0.5 * 10f64.powi(v.abs().log10().floor() as i32 - digits + 1);
        let (re, rh) = (
            n400["energy"].as_f64().unwrap(),
            n400["hessian_frobenius_full"].as_f64().unwrap(),
        );
        assert!(
            (e.energy - re).abs() <= half_unit(re, 13) + 1e-12 * re,
            "{ee}"
        );
        assert!((frob - rh).abs() <= half_unit(rh, 11) + 1e-12 * rh, "{eh}");
        assert_eq!(v.len() as u64, n400["hessian_nnz_full"].as_u64().unwrap());
    }
}

#[test]
fn non_finite_positions_are_named_even_for_a_vertex_in_no_hinge() {
    // A two-triangle hinge plus a separate triangle (vertices 4, 5, 6 are in no hinge).
    let pos = vec![
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(1.0, 1.0, 0.2),
        Vector3::new(3.0, 0.0, 0.0),
        Vector3::new(4.0, 0.0, 0.0),
        Vector3::new(3.0, 1.0, 0.0),
    ];
    let mesh = TriMesh::new(pos.clone(), vec![[0, 1, 2], [1, 3, 2], [4, 5, 6]]).unwrap();
    let mut model = BendingModel::new(&mesh, TanBending { k: 1.0 }).unwrap();
    for (v, axis, bad) in [
        (5, 1, f64::NAN),
        (0, 2, f64::INFINITY),
        (6, 0, f64::NEG_INFINITY),
    ] {
        let mut x = pos.clone();
        x[v][axis] = bad;
        for request in [Request::VALUE, Request::GRADIENT, Request::ALL] {
            for method in Method::ALL {
                let err = model.evaluate(&x, request, method, SEQ).unwrap_err();
                assert!(
                    matches!(err, EvalError::Mesh(MeshError::NonFiniteCoordinate { vertex, axis: a, .. }) if vertex == v && a == axis),
                    "{err:?}"
                );
            }
        }
        assert!(matches!(
            model.set_step(&x, 0.01),
            Err(EvalError::Mesh(MeshError::NonFiniteCoordinate { vertex, .. })) if vertex == v
        ));
    }
}

#[test]
fn energy_only_and_gradient_only_requests_equal_the_full_evaluation_bitwise() {
    for (name, mesh, x) in closed_and_irregular() {
        let model = BendingModel::new(&mesh, TanBending { k: 1.3 }).unwrap();
        let all = eval(&model, &x, Method::Refactored);
        let mut out = model.new_output();
        let mut scratch = model.new_scratch();
        for (request, check_gradient) in [(Request::VALUE, false), (Request::GRADIENT, true)] {
            out.gradient.fill(7.0);
            out.hessian.fill(7.0);
            model
                .evaluate_into(&x, request, Method::Refactored, SEQ, &mut scratch, &mut out)
                .unwrap();
            assert_eq!(out.energy.to_bits(), all.energy.to_bits(), "{name}");
            if check_gradient {
                assert_eq!(out.gradient, all.gradient, "{name}");
            } else {
                assert!(out.gradient.iter().all(|&g| g == 7.0), "untouched");
            }
            assert!(out.hessian.iter().all(|&h| h == 7.0), "untouched");
        }
    }
}

#[test]
fn an_output_reused_with_stale_values_gets_the_fresh_evaluation_bitwise() {
    // Pass 2 zeroes the Hessian values just ahead of the elements (a frontier per partition) instead of
    // all of them first: every value must still be overwritten, whatever the output held, on meshes
    // whose elements are not in row order, on one thread and several. The randomly numbered icosphere of
    // 2 562 vertices has four partitions and enough hinges to run in parallel: the frontier crosses
    // partition boundaries.
    let big = icosphere(4, 1.0).unwrap();
    let perm = random_permutation(big.n_vertices(), 5);
    let big = renumber(&big, &perm).unwrap();
    let xb = big
        .positions()
        .iter()
        .map(|p| p * (1.0 + 0.1 * (3.0 * p.x).sin()))
        .collect();
    let mut meshes = closed_and_irregular();
    meshes.push(("icosphere 2 562, random numbering", big, xb));
    for (name, mesh, x) in meshes {
        let model = BendingModel::new(&mesh, TanBending { k: 1.3 }).unwrap();
        if mesh.n_vertices() == 2562 {
            assert!(model.topology().hinges().len() >= hinge_core::bending::PARALLEL_MIN_HINGES);
        }
        for par in [SEQ, Parallelism::Rayon] {
            let fresh = on_threads(2, || {
                model.evaluate(&x, Request::ALL, Method::Refactored, par)
            })
            .unwrap();
            let mut out = model.new_output();
            let mut scratch = model.new_scratch();
            for stale in [7.0, f64::NAN] {
                out.gradient.fill(stale);
                out.hessian.fill(stale);
                on_threads(2, || {
                    model.evaluate_into(
                        &x,
                        Request::ALL,
                        Method::Refactored,
                        par,
                        &mut scratch,
                        &mut out,
                    )
                })
                .unwrap();
                assert_eq!(out.energy.to_bits(), fresh.energy.to_bits(), "{name}");
                assert_eq!(out.gradient, fresh.gradient, "{name} {stale}");
                assert_eq!(out.hessian, fresh.hessian, "{name} {stale}");
            }
        }
    }
}

#[test]
fn value_slots_that_would_overflow_32_bits_are_a_typed_error() {
    // 716 million vertices need 6 values each on the diagonal alone: more than u32 can index.
    let err = SymmetricPattern::new(716_000_000, std::iter::empty()).unwrap_err();
    assert!(matches!(err, EvalError::Pattern { .. }), "{err}");
    assert!(err.to_string().contains("32-bit"), "{err}");
    let err = SymmetricPattern::new(u32::MAX as usize + 1, std::iter::empty()).unwrap_err();
    assert!(matches!(err, EvalError::Pattern { .. }), "{err}");
}

#[test]
fn locality_order_and_identity_order_give_the_same_matrix() {
    let mesh = irregular_sheet(15, 12, 3).unwrap();
    let x = bend(mesh.positions());
    let mut model = BendingModel::new(&mesh, TanBending { k: 1.0 }).unwrap();
    assert!(!model.pattern().is_identity_order());
    let local = eval(&model, &x, Method::Refactored);
    let (el, gl, hl) = in_caller_numbering(&model, &local);
    let order: Vec<usize> = (0..mesh.n_vertices()).collect();
    let identity =
        SymmetricPattern::with_vertex_order(mesh.n_vertices(), model.couplings(), &order).unwrap();
    assert!(identity.is_identity_order());
    model.bind(std::sync::Arc::new(identity)).unwrap();
    let (ei, gi, hi) = in_caller_numbering(&model, &eval(&model, &x, Method::Refactored));
    assert!(((ei - el) / el).abs() < 1e-14);
    assert!(rel_error(&gi, &gl) < 1e-14);
    assert_eq!(hi.len(), hl.len());
    for (k, v) in &hl {
        assert!((hi[k] - v).abs() <= 1e-12 * v.abs().max(1.0), "{k:?}");
    }
    // Not a permutation: typed errors.
    let bad = vec![0usize; mesh.n_vertices()];
    assert!(
        SymmetricPattern::with_vertex_order(mesh.n_vertices(), model.couplings(), &bad).is_err()
    );
    assert!(
        SymmetricPattern::with_vertex_order(mesh.n_vertices(), model.couplings(), &[0]).is_err()
    );
}

/// Two triangles on the hinge x1 = origin, x2 = (1, 0, 0), the wing x3 turned about the hinge by `fold`
/// from the flat state (|θ̄| = `fold`), numbered at random and with the corners of each face rotated by
/// `rotation`.
fn folded_pair(fold: f64, seed: u64, rotation: usize) -> TriMesh {
    let mut x = hinge_tests::one_hinge_positions();
    let (s, c) = fold.sin_cos();
    x[3] = Vector3::new(0.6, -0.9 * c, -0.9 * s);
    let faces: Vec<[usize; 3]> = [[0, 1, 2], [3, 2, 1]]
        .iter()
        .map(|f| {
            [
                f[rotation % 3],
                f[(rotation + 1) % 3],
                f[(rotation + 2) % 3],
            ]
        })
        .collect();
    let mesh = TriMesh::new(x, faces).unwrap();
    renumber(&mesh, &random_permutation(4, seed)).unwrap()
}

/// `BendingModel::rest_stiffening` (ψ″(θ̄)/ψ″(0), what `hinge run` warns about for a crease folded almost
/// flat) against the tan energy's closed form 1/cos⁴(θ̄/2) of the fold the mesh was built with, against
/// num-dual's second derivative of ψ, and against central differences of ψ′, on folded pairs numbered at
/// random under every corner rotation; discrete shells' is 1 everywhere, and a closed icosphere's is close
/// to 1.
#[test]
fn rest_stiffening_of_folded_hinges_matches_its_closed_form_and_autodiff() {
    use num_dual::second_derivative;
    let k = 0.7;
    let pi = std::f64::consts::PI;
    for (i, &fold) in [0.0, 0.4, 1.3, 2.5, 3.0, 3.09, pi - 1.6e-3, pi - 1e-4]
        .iter()
        .enumerate()
    {
        for rotation in 0..3 {
            let mesh = folded_pair(fold, 17 + i as u64, rotation);
            let tan = BendingModel::new(&mesh, TanBending { k }).unwrap();
            let ratio = tan.rest_stiffening()[0].unwrap();
            let closed = (0.5 * fold).cos().powi(-4);
            assert!(
                (ratio - closed).abs() <= 1e-9 * closed,
                "fold {fold}: {ratio} against 1/cos⁴ = {closed}"
            );
            let q = tan.hinge_quantities(0).unwrap();
            assert!((q.theta_bar.abs() - fold).abs() <= 1e-12, "{}", q.theta_bar);
            let p = tan.psi().params(&q);
            let d2 = |theta: f64| second_derivative(|t| tan.psi().psi_dual(&p, t), theta).2;
            let dual = d2(q.theta_bar) / d2(0.0);
            assert!(
                (ratio - dual).abs() <= 1e-12 * dual,
                "fold {fold}: {ratio} against num-dual {dual}"
            );
            if fold <= 3.0 {
                let h = 1e-5;
                let d1 = |theta: f64| tan.psi().eval(&p, theta)[1];
                let fd = (d1(q.theta_bar + h) - d1(q.theta_bar - h)) / (d1(h) - d1(-h));
                assert!(
                    (ratio - fd).abs() <= 1e-6 * ratio,
                    "fold {fold}: {ratio} against differences {fd}"
                );
            }
            let shells = BendingModel::new(&mesh, DiscreteShells { k }).unwrap();
            assert_eq!(shells.rest_stiffening(), vec![Some(1.0)]);
        }
    }
    // Exactly folded (both wings in one plane, on one side): tan(θ̄/2) is about 1.6e16, not infinite.
    let mut x = hinge_tests::one_hinge_positions();
    x[3] = Vector3::new(0.6, 0.5, 0.0);
    let flat = TriMesh::new(x, vec![[0, 1, 2], [3, 2, 1]]).unwrap();
    let tan = BendingModel::new(&flat, TanBending { k }).unwrap();
    let ratio = tan.rest_stiffening()[0].unwrap();
    assert!(ratio > 1e60, "{ratio}");
    // A closed icosphere: every hinge close to flat (|θ̄| ≤ 0.2 rad at 2 subdivisions: 1/cos⁴ ≤ 1.03).
    let sphere = icosphere(2, 1.0).unwrap();
    let tan = BendingModel::new(&sphere, TanBending { k }).unwrap();
    for (h, r) in tan.rest_stiffening().iter().enumerate() {
        let r = r.unwrap();
        let expected = (0.5 * tan.hinge_quantities(h).unwrap().theta_bar)
            .cos()
            .powi(-4);
        assert!(
            r > 1.0 && r < 1.03 && (r - expected).abs() <= 1e-14,
            "hinge {h}: {r}"
        );
    }
}
