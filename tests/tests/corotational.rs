//! The co-rotational membrane (lecture P39–P42) with its exact Hessian: against num-dual on an independent
//! closed form of the energy (no rest frame, no polar decomposition), against finite differences on closed,
//! irregular, renumbered and sliver meshes, zero energy and force at rest and under rigid motions, the
//! same values for every corner rotation of the triangles, the definite Hessian positive semi-definite and
//! equal to the exact one in tension, and degenerate triangles named in typed errors.

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Energy, System};
use hinge_core::grid::SplitMix64;
use hinge_core::nalgebra::{DMatrix, Matrix2, Rotation3, SVector, Unit, Vector3};
use hinge_core::shapes::{icosphere, irregular_sheet, random_permutation, renumber, sliver_sheet};
use hinge_core::{ElementRef, EvalError, TriMesh};
use hinge_energies::corotational::CorotationalMembrane;
use hinge_tests::*;
use num_dual::{Dual2SVec64, DualNum, hessian};

type D9 = Dual2SVec64<9>;

fn system(rest: &TriMesh, k: f64) -> System {
    System::new(
        rest.n_vertices(),
        vec![Box::new(CorotationalMembrane::new(rest, k).unwrap()) as Box<dyn Energy>],
    )
    .unwrap()
}

/// Energy, gradient and dense Hessian of the membrane on `rest` at `x`.
fn evaluate(rest: &TriMesh, x: &[Vector3<f64>], definite: bool) -> (f64, Vec<f64>, Vec<f64>) {
    let mut s = system(rest, 3.0);
    let request = if definite {
        Request::ALL.with_definite(true)
    } else {
        Request::ALL
    };
    let r = s.evaluate(x, request, Parallelism::Sequential).unwrap();
    (
        r.energy,
        r.gradient.clone(),
        sym_dense(s.pattern(), &r.hessian),
    )
}

/// The per-triangle energy in an independent closed form, for num-dual: with the rest Gram matrix G and
/// the deformed one g of the two edges from corner 0, M = G⁻¹g has the eigenvalues σᵢ², so
/// ‖F − R‖² = Σ(σᵢ − 1)² = tr M − 2 √(tr M + 2 √det M) + 2.
fn closed_form(rest: &[Vector3<f64>; 3], x: &[D9], k: f64) -> D9 {
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
    let det = m(0, 0) * m(1, 1) - m(0, 1) * m(1, 0);
    (tr - (tr + det.sqrt() * 2.0).sqrt() * 2.0 + 2.0) * (0.5 * k * area)
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
    for case in 0..200 {
        // Random stretches from 0.3 (compressed) to 1.8, random rotations, some out-of-plane tilt.
        let a = DMatrix::from_fn(3, 3, |_, _| 0.45 * rng.symmetric());
        let mut x: Vec<Vector3<f64>> = rest
            .iter()
            .map(|p| p * rng.range(0.3, 1.8) + &a * p)
            .collect();
        if case == 0 {
            x = rest.to_vec();
            x[1].x += 0.2;
        }
        let flat = SVector::<f64, 9>::from_iterator(x.iter().flat_map(|p| [p.x, p.y, p.z]));
        let (e_ad, g_ad, h_ad) = hessian(
            |v: SVector<Dual2SVec64<9>, 9>| closed_form(&rest, v.as_slice(), 3.0),
            &flat,
        );
        let (e, g, h) = evaluate(&mesh, &x, false);
        let hd: Vec<f64> = (0..81).map(|k| h_ad[(k / 9, k % 9)]).collect();
        let (eg, eh) = (rel_error(&g, g_ad.as_slice()), rel_error(&h, &hd));
        assert!(
            (e - e_ad).abs() <= 1e-13 * e_ad.abs().max(1e-3),
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
        "200 triangles: gradient vs num-dual {worst_g:.1e}, Hessian {worst_h:.1e}; {indefinite} exact Hessians indefinite"
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
        let mut s = system(&rest, 3.0);
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
            assert!(e.abs() < 1e-26 && gmax < 1e-13, "E {e}, |g| {gmax}");
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
        assert!((e - e0).abs() <= 1e-14 * e0, "{e} {e0}");
        assert!(rel_error(&g, &g0) < 1e-13 && rel_error(&h, &h0) < 1e-13);
    }
}

#[test]
fn definite_hessian_is_psd_and_exact_in_tension() {
    let rest = renumber(
        &irregular_sheet(6, 6, 21).unwrap(),
        &random_permutation(36, 5),
    )
    .unwrap();
    // Compressed and folded: the exact Hessian is indefinite, the definite one is not.
    let x = membrane_deformation(&rest, 1)
        .iter()
        .map(|p| Vector3::new(0.6 * p.x, p.y, p.z))
        .collect::<Vec<_>>();
    let n = 3 * rest.n_vertices();
    let (e, g, h) = evaluate(&rest, &x, false);
    let (ed, gd, hd) = evaluate(&rest, &x, true);
    assert_eq!((e, &g), (ed, &gd), "energy and gradient stay exact");
    let min = |h: &[f64]| {
        let m = DMatrix::from_row_slice(n, n, h);
        m.clone().symmetric_eigen().eigenvalues.min() / m.norm()
    };
    let (exact_min, definite_min) = (min(&h), min(&hd));
    println!(
        "compressed: smallest eigenvalue / norm: exact {exact_min:.2e}, definite {definite_min:.2e}"
    );
    assert!(exact_min < -1e-3 && definite_min > -1e-14);
    // The definite Hessian is the exact one with the negative F-space eigenvalues of each triangle
    // clamped: in pure tension (every σᵢ ≥ 1) they are equal.
    let stretched: Vec<Vector3<f64>> = rest.positions().iter().map(|p| p * 1.2).collect();
    let (_, _, h) = evaluate(&rest, &stretched, false);
    let (_, _, hd) = evaluate(&rest, &stretched, true);
    assert!(rel_error(&hd, &h) < 1e-14, "{}", rel_error(&hd, &h));
    // Per triangle, the definite Hessian is k Ā Dᵀ H_F⁺ D: the Hessian of ½‖F − R‖² in F-space (num-dual on
    // the closed form in C = FᵀF) with its eigenvalues clamped at zero by a dense eigensolver, mapped by
    // D = ∂F/∂x. The exact one is k Ā Dᵀ H_F D.
    let mut rng = SplitMix64(77);
    let corners = [
        Vector3::zeros(),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.3, 0.8, 0.0),
    ];
    let tri = TriMesh::new(corners.to_vec(), vec![[0, 1, 2]]).unwrap();
    let (e1, e2) = (corners[1] - corners[0], corners[2] - corners[0]);
    let t1 = e1.normalize();
    let t2 = e1.cross(&e2).normalize().cross(&t1);
    let dm = Matrix2::new(e1.dot(&t1), e2.dot(&t1), 0.0, e2.dot(&t2));
    let dm_inv = dm.try_inverse().unwrap();
    let area = 0.5 * e1.cross(&e2).norm();
    // F_ij = Σ_v x_v,i b_v,j with b_1, b_2 the rows of Dm⁻¹ and b_0 = −b_1 − b_2.
    let b = |v: usize, j: usize| match v {
        0 => -dm_inv[(0, j)] - dm_inv[(1, j)],
        _ => dm_inv[(v - 1, j)],
    };
    let d = DMatrix::from_fn(6, 9, |r, c| {
        let (i, j, v, k) = (r / 2, r % 2, c / 3, c % 3);
        if i == k { b(v, j) } else { 0.0 }
    });
    let mut clamped = 0;
    for _ in 0..100 {
        let a = DMatrix::from_fn(3, 3, |_, _| 0.4 * rng.symmetric());
        let x: Vec<Vector3<f64>> = corners
            .iter()
            .map(|p| p * rng.range(0.3, 1.5) + &a * p)
            .collect();
        let xf = DMatrix::from_iterator(9, 1, x.iter().flat_map(|p| [p.x, p.y, p.z]));
        let f = SVector::<f64, 6>::from_iterator((&d * xf).iter().copied());
        let (_, _, hf) = hessian(
            |f: SVector<Dual2SVec64<6>, 6>| {
                let c00 = f[0] * f[0] + f[2] * f[2] + f[4] * f[4];
                let c11 = f[1] * f[1] + f[3] * f[3] + f[5] * f[5];
                let c01 = f[0] * f[1] + f[2] * f[3] + f[4] * f[5];
                let (tr, det) = (c00 + c11, c00 * c11 - c01 * c01);
                (tr - (tr + det.sqrt() * 2.0).sqrt() * 2.0 + 2.0) * 0.5
            },
            &f,
        );
        let hf = DMatrix::from_fn(6, 6, |r, c| hf[(r, c)]);
        let eig = hf.clone().symmetric_eigen();
        if eig.eigenvalues.min() < 0.0 {
            clamped += 1;
        }
        let pos = eig.eigenvalues.map(|l| l.max(0.0));
        let hf_plus =
            &eig.eigenvectors * DMatrix::from_diagonal(&pos) * eig.eigenvectors.transpose();
        let scale = 3.0 * area;
        let want_exact = (d.transpose() * &hf * &d) * scale;
        let want_definite = (d.transpose() * hf_plus * &d) * scale;
        let (_, _, h) = evaluate(&tri, &x, false);
        let (_, _, hd) = evaluate(&tri, &x, true);
        let (ee, ed) = (
            rel_error(&h, want_exact.transpose().as_slice()),
            rel_error(&hd, want_definite.transpose().as_slice()),
        );
        assert!(ee < 1e-10 && ed < 1e-10, "exact {ee}, definite {ed}");
    }
    println!(
        "one-triangle definite Hessians equal the clamped F-space Hessian; {clamped} of 100 clamped"
    );
    assert!(clamped > 10);
}

#[test]
fn degenerate_triangles_are_named() {
    let rest = irregular_sheet(4, 4, 1).unwrap();
    let mut x = membrane_deformation(&rest, 2);
    let t = rest.triangles()[5];
    // Collapse triangle 5 onto a line: its third corner on the line of the other two.
    x[t[2]] = x[t[0]] * 0.3 + x[t[1]] * 0.7;
    let mut s = system(&rest, 1.0);
    let err = s
        .evaluate(&x, Request::GRADIENT, Parallelism::Sequential)
        .unwrap_err();
    println!("{err}");
    match &err {
        EvalError::AtElement {
            energy, element, ..
        } => {
            assert_eq!(energy, "corotational-membrane");
            assert_eq!(
                *element,
                ElementRef::Triangle {
                    triangle: 5,
                    vertices: t
                }
            );
            assert!(err.to_string().contains(&format!(
                "triangle 5 (vertices {}, {}, {})",
                t[0], t[1], t[2]
            )));
        }
        other => panic!("{other}"),
    }
    // A rest triangle without area and a bad stiffness are rejected at set-up.
    assert!(CorotationalMembrane::new(&rest, -1.0).is_err());
    assert!(CorotationalMembrane::new(&rest, f64::NAN).is_err());
    assert!(CorotationalMembrane::from_material(&rest, 1e3, 0.6, 1e-3).is_err());
}
