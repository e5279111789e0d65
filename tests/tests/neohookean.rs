//! The compressible neo-Hookean membrane with its exact Hessian: against num-dual on an independent closed
//! form of the energy (Gram matrices, no rest frame), against finite differences on closed, irregular,
//! renumbered and sliver meshes, zero energy and force at rest and under rigid motions, the same values for
//! every corner rotation of the triangles, the definite Hessian positive semi-definite and equal to the
//! exact one in moderate tension, the small-strain limit equal to the StVK membrane's, the energy growing
//! without bound as a triangle is crushed (where StVK's stays bounded), and crushed triangles named.

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Energy, System};
use hinge_core::grid::SplitMix64;
use hinge_core::nalgebra::{DMatrix, Matrix2, Rotation3, SVector, Unit, Vector3};
use hinge_core::shapes::{icosphere, irregular_sheet, random_permutation, renumber, sliver_sheet};
use hinge_core::{ElementRef, EvalError, TriMesh};
use hinge_energies::membrane::StvkMembrane;
use hinge_energies::neohookean::NeoHookeanMembrane;
use hinge_tests::*;
use num_dual::{Dual2SVec64, DualNum, hessian};

type D9 = Dual2SVec64<9>;

const YOUNG: f64 = 1000.0;
const POISSON: f64 = 0.3;
const THICKNESS: f64 = 0.01;

fn system(rest: &TriMesh) -> System {
    System::new(
        rest.n_vertices(),
        vec![
            Box::new(NeoHookeanMembrane::new(rest, YOUNG, POISSON, THICKNESS).unwrap())
                as Box<dyn Energy>,
        ],
    )
    .unwrap()
}

/// Energy, gradient and dense Hessian of the membrane on `rest` at `x`.
fn evaluate(rest: &TriMesh, x: &[Vector3<f64>], definite: bool) -> (f64, Vec<f64>, Vec<f64>) {
    let mut s = system(rest);
    let r = s
        .evaluate(
            x,
            Request::ALL.with_definite(definite),
            Parallelism::Sequential,
        )
        .unwrap();
    (
        r.energy,
        r.gradient.clone(),
        sym_dense(s.pattern(), &r.hessian),
    )
}

/// The per-triangle energy in an independent closed form, for num-dual: with the rest Gram matrix G and
/// the deformed one g of the two edges from corner 0, M = G⁻¹g has the eigenvalues σᵢ², so I₁ = tr M and
/// J² = det M: W = μ/2 (tr M − 2) − μ/2 ln det M + λ/8 (ln det M)².
fn closed_form(rest: &[Vector3<f64>; 3], x: &[D9]) -> D9 {
    let mu = YOUNG / (2.0 * (1.0 + POISSON));
    let lambda = YOUNG * POISSON / (1.0 - POISSON * POISSON);
    let (r1, r2) = (rest[1] - rest[0], rest[2] - rest[0]);
    let gram = Matrix2::new(r1.dot(&r1), r1.dot(&r2), r1.dot(&r2), r2.dot(&r2));
    let gi = gram.try_inverse().unwrap();
    let area = 0.5 * r1.cross(&r2).norm();
    let p = |i: usize| [x[3 * i], x[3 * i + 1], x[3 * i + 2]];
    let sub = |a: [D9; 3], b: [D9; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let dot = |a: [D9; 3], b: [D9; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (d1, d2) = (sub(p(1), p(0)), sub(p(2), p(0)));
    let g = [[dot(d1, d1), dot(d1, d2)], [dot(d1, d2), dot(d2, d2)]];
    let m = |i: usize, j: usize| g[0][j] * gi[(i, 0)] + g[1][j] * gi[(i, 1)];
    let tr = m(0, 0) + m(1, 1);
    let log_det = (m(0, 0) * m(1, 1) - m(0, 1) * m(1, 0)).ln();
    ((tr - 2.0) * (0.5 * mu) - log_det * (0.5 * mu) + log_det * log_det * (0.125 * lambda))
        * (THICKNESS * area)
}

#[test]
fn exact_derivatives_match_num_dual_on_an_independent_closed_form() {
    let rest = [
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.1, 0.0),
        Vector3::new(0.2, 0.9, 0.0),
    ];
    let mesh = TriMesh::new(rest.to_vec(), vec![[0, 1, 2]]).unwrap();
    let mut rng = SplitMix64(5);
    let (mut worst_g, mut worst_h, mut indefinite) = (0.0f64, 0.0f64, 0);
    for case in 0..300 {
        // Random stretches from 0.1 (strongly compressed) to 2.5, random rotations and tilts.
        let a = DMatrix::from_fn(3, 3, |_, _| 0.45 * rng.symmetric());
        let x: Vec<Vector3<f64>> = rest
            .iter()
            .map(|p| p * rng.range(0.1, 2.5) + &a * p)
            .collect();
        let flat = SVector::<f64, 9>::from_iterator(x.iter().flat_map(|p| [p.x, p.y, p.z]));
        let (e_ad, g_ad, h_ad) = hessian(
            |v: SVector<Dual2SVec64<9>, 9>| closed_form(&rest, v.as_slice()),
            &flat,
        );
        let (e, g, h) = evaluate(&mesh, &x, false);
        let hd: Vec<f64> = (0..81).map(|k| h_ad[(k / 9, k % 9)]).collect();
        let (eg, eh) = (rel_error(&g, g_ad.as_slice()), rel_error(&h, &hd));
        assert!(
            (e - e_ad).abs() <= 1e-12 * e_ad.abs().max(1e-3),
            "{case}: {e} {e_ad}"
        );
        assert!(eg < 1e-12 && eh < 1e-11, "case {case}: {eg} {eh}");
        worst_g = worst_g.max(eg);
        worst_h = worst_h.max(eh);
        let hm = DMatrix::from_row_slice(9, 9, &h);
        if hm.clone().symmetric_eigen().eigenvalues.min() < -1e-9 * hm.norm() {
            indefinite += 1;
        }
    }
    println!(
        "300 triangles: gradient vs num-dual {worst_g:.1e}, Hessian {worst_h:.1e}; {indefinite} exact Hessians indefinite"
    );
    // The cases cover compression, where the exact Hessian is indefinite.
    assert!(indefinite > 10, "{indefinite}");
}

#[test]
fn exact_derivatives_match_finite_differences_on_users_meshes() {
    let sheet = irregular_sheet(7, 6, 3).unwrap();
    let renumbered = renumber(&sheet, &random_permutation(sheet.n_vertices(), 11)).unwrap();
    let meshes = [
        ("icosphere (closed)", icosphere(1, 0.7).unwrap()),
        ("irregular sheet", sheet),
        ("renumbered irregular sheet", renumbered),
        ("slivers", sliver_sheet(6, 4).unwrap()),
    ];
    for (name, rest) in meshes {
        let x = membrane_deformation(&rest, 9);
        let (e, g, h) = evaluate(&rest, &x, false);
        let mut s = system(&rest);
        let (fd_g, fd_h) = fd_energy_derivatives(&x, 1e-6, |y| {
            let r = s
                .evaluate(y, Request::GRADIENT, Parallelism::Sequential)
                .unwrap();
            (r.energy, r.gradient)
        });
        let (eg, eh) = (rel_error(&g, &fd_g), rel_error(&h, &fd_h));
        println!("{name}: E {e:.4e}, gradient vs FD {eg:.1e}, Hessian vs FD {eh:.1e}");
        assert!(e > 0.0 && eg < 1e-7 && eh < 1e-6, "{name}: {eg} {eh}");
    }
}

#[test]
fn zero_at_rest_and_under_rigid_motions_and_the_same_for_every_corner_rotation() {
    let rest = renumber(
        &irregular_sheet(6, 5, 8).unwrap(),
        &random_permutation(30, 2),
    )
    .unwrap();
    let closed = icosphere(2, 0.5).unwrap();
    for mesh in [&rest, &closed] {
        let r = Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(1.0, -2.0, 0.5)), 2.1);
        let t = Vector3::new(0.3, -1.0, 2.0);
        for x in [
            mesh.positions().to_vec(),
            mesh.positions().iter().map(|p| r * p + t).collect(),
        ] {
            let (e, g, _) = evaluate(mesh, &x, false);
            let gmax = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(e.abs() < 1e-12 && gmax < 1e-11, "E {e}, |g| {gmax}");
        }
    }
    // Each triangle's corners rotated (a, b, c) → (b, c, a), and twice: the same energy and derivatives
    // (another rest frame, so to rounding).
    let x = membrane_deformation(&rest, 4);
    let (e0, g0, h0) = evaluate(&rest, &x, false);
    for shift in 1..3 {
        let tris: Vec<[usize; 3]> = rest
            .triangles()
            .iter()
            .map(|t| [t[shift % 3], t[(shift + 1) % 3], t[(shift + 2) % 3]])
            .collect();
        let rotated = TriMesh::new(rest.positions().to_vec(), tris).unwrap();
        let (e, g, h) = evaluate(&rotated, &x, false);
        assert!((e - e0).abs() <= 1e-13 * e0, "{e} {e0}");
        assert!(rel_error(&g, &g0) < 1e-12 && rel_error(&h, &h0) < 1e-12);
    }
}

#[test]
fn definite_hessian_is_psd_and_exact_in_moderate_tension() {
    let rest = renumber(
        &irregular_sheet(6, 6, 21).unwrap(),
        &random_permutation(36, 5),
    )
    .unwrap();
    let n = 3 * rest.n_vertices();
    let min = |h: &[f64]| {
        let m = DMatrix::from_row_slice(n, n, h);
        m.clone().symmetric_eigen().eigenvalues.min() / m.norm()
    };
    // Compressed and folded: the exact Hessian is indefinite, the definite one is not. Strongly stretched
    // (λ ln J > μ, so the material part's coefficient c is negative): the same.
    let compressed: Vec<Vector3<f64>> = membrane_deformation(&rest, 1)
        .iter()
        .map(|p| Vector3::new(0.6 * p.x, p.y, p.z))
        .collect();
    let stretched: Vec<Vector3<f64>> = rest.positions().iter().map(|p| p * 2.0).collect();
    for (name, x) in [("compressed", &compressed), ("stretched 2x", &stretched)] {
        let (e, g, h) = evaluate(&rest, x, false);
        let (ed, gd, hd) = evaluate(&rest, x, true);
        assert_eq!((e, &g), (ed, &gd), "energy and gradient stay exact");
        let (exact_min, definite_min) = (min(&h), min(&hd));
        println!(
            "{name}: smallest eigenvalue / norm: exact {exact_min:.2e}, definite {definite_min:.2e}"
        );
        assert!(definite_min > -1e-14, "{name}: {definite_min}");
        if name == "compressed" {
            assert!(exact_min < -1e-3, "{exact_min}");
        }
    }
    // In moderate tension (every stress eigenvalue ≥ 0 and λ ln J ≤ μ) nothing is clamped.
    let moderate: Vec<Vector3<f64>> = rest.positions().iter().map(|p| p * 1.2).collect();
    let (_, _, h) = evaluate(&rest, &moderate, false);
    let (_, _, hd) = evaluate(&rest, &moderate, true);
    assert!(rel_error(&hd, &h) < 1e-14, "{}", rel_error(&hd, &h));
}

#[test]
fn small_strains_agree_with_stvk_and_crushing_costs_without_bound() {
    let rest = renumber(
        &irregular_sheet(5, 5, 3).unwrap(),
        &random_permutation(25, 9),
    )
    .unwrap();
    let stvk = |x: &[Vector3<f64>]| -> (f64, Vec<f64>) {
        let mut s = System::new(
            rest.n_vertices(),
            vec![
                Box::new(StvkMembrane::new(&rest, YOUNG, POISSON, THICKNESS).unwrap())
                    as Box<dyn Energy>,
            ],
        )
        .unwrap();
        let r = s
            .evaluate(x, Request::GRADIENT, Parallelism::Sequential)
            .unwrap();
        (r.energy, r.gradient)
    };
    // A strain of size s: energies agree to O(s) relative, forces to O(s).
    let mut rng = SplitMix64(4);
    let dir: Vec<Vector3<f64>> = rest
        .positions()
        .iter()
        .map(|p| {
            Vector3::new(0.7 * p.x + 0.3 * p.y, -0.4 * p.y, 0.2 * p.x)
                + 0.1 * Vector3::new(rng.symmetric(), rng.symmetric(), 0.0)
        })
        .collect();
    let mut last = f64::INFINITY;
    for s in [1e-2, 1e-3, 1e-4] {
        let x: Vec<Vector3<f64>> = rest
            .positions()
            .iter()
            .zip(&dir)
            .map(|(p, d)| p + d * s)
            .collect();
        let (e_nh, g_nh, _) = evaluate(&rest, &x, false);
        let (e_sv, g_sv) = stvk(&x);
        let (de, dg) = ((e_nh / e_sv - 1.0).abs(), rel_error(&g_nh, &g_sv));
        println!("strain ~{s:.0e}: energy ratio − 1 = {de:.2e}, force difference {dg:.2e}");
        assert!(de < 20.0 * s && dg < 20.0 * s, "{s}: {de} {dg}");
        assert!(de < last);
        last = de;
    }
    // One triangle crushed onto the line through two corners: the neo-Hookean energy grows without bound,
    // StVK's stays below its value at zero area.
    let tri = TriMesh::new(
        vec![
            Vector3::zeros(),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.4, 0.8, 0.0),
        ],
        vec![[0, 1, 2]],
    )
    .unwrap();
    let mut sv = System::new(
        3,
        vec![
            Box::new(StvkMembrane::new(&tri, YOUNG, POISSON, THICKNESS).unwrap())
                as Box<dyn Energy>,
        ],
    )
    .unwrap();
    let mut nh = system(&tri);
    let mut previous = 0.0;
    for k in 1..=12 {
        let h = 0.8 * 10f64.powi(-k);
        let x = [
            Vector3::zeros(),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.4, h, 0.0),
        ];
        let e_nh = nh
            .evaluate(&x, Request::VALUE, Parallelism::Sequential)
            .unwrap()
            .energy;
        let e_sv = sv
            .evaluate(&x, Request::VALUE, Parallelism::Sequential)
            .unwrap()
            .energy;
        assert!(e_nh > previous, "{k}: {e_nh} after {previous}");
        assert!(e_sv < 0.2 * YOUNG * THICKNESS, "{e_sv}");
        previous = e_nh;
    }
    // At an area ratio J = 1e-12, W ≥ −μ ln J − μ/2 (the λ term is positive, I₁ − 2 ≥ −1): h Ā μ (27.6 − 0.5).
    let mu = YOUNG / (2.0 * (1.0 + POISSON));
    assert!(
        previous > THICKNESS * 0.4 * mu * (12.0 * 10f64.ln() - 0.5),
        "{previous}"
    );
}

#[test]
fn crushed_triangles_are_named() {
    let rest = irregular_sheet(4, 4, 1).unwrap();
    let mut x = membrane_deformation(&rest, 2);
    let t = rest.triangles()[5];
    // Crush triangle 5 onto a line (exactly: its corners on a line parallel to x). Nearly crushed, rounded
    // onto the line through two corners, its energy is finite and huge (the cross product of its edges
    // keeps a few ulps): a barrier, not an error.
    let base = x[t[0]];
    let mut y = x.clone();
    y[t[2]] = x[t[0]] * 0.25 + x[t[1]] * 0.75;
    let mut near = system(&rest);
    let (e_ok, _, _) = evaluate(&rest, &membrane_deformation(&rest, 2), false);
    let e_near = near
        .evaluate(&y, Request::VALUE, Parallelism::Sequential)
        .map_or(f64::INFINITY, |r| r.energy);
    assert!(e_near > 10.0 * e_ok, "{e_near} {e_ok}");
    for (k, v) in t.iter().enumerate() {
        x[*v] = base + Vector3::new(0.25 * k as f64, 0.0, 0.0);
    }
    let mut s = system(&rest);
    let err = s
        .evaluate(&x, Request::VALUE, Parallelism::Sequential)
        .unwrap_err();
    println!("{err}");
    match &err {
        EvalError::AtElement {
            energy, element, ..
        } => {
            assert_eq!(energy, "neo-hookean-membrane");
            assert_eq!(
                *element,
                ElementRef::Triangle {
                    triangle: 5,
                    vertices: t
                }
            );
        }
        other => panic!("{other}"),
    }
    // NaN positions are named the same way, never a silent NaN.
    let mut y = membrane_deformation(&rest, 2);
    y[t[1]].x = f64::NAN;
    assert!(
        s.evaluate(&y, Request::ALL, Parallelism::Sequential)
            .is_err()
    );
    // Bad material and rest triangles without area are rejected at set-up.
    assert!(NeoHookeanMembrane::new(&rest, -1.0, 0.3, 1e-3).is_err());
    assert!(NeoHookeanMembrane::new(&rest, 1e3, 0.6, 1e-3).is_err());
    assert!(NeoHookeanMembrane::new(&rest, 1e3, 0.3, 0.0).is_err());
    assert!(NeoHookeanMembrane::new(&rest, f64::NAN, 0.3, 1e-3).is_err());
}
