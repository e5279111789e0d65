//! Anisotropic (warp/weft) bending: the per-hinge factor s(φ) = 1 + warp·sin²φ + weft·cos²φ on every hinge
//! energy (built-in, derived and run-time ψ), checked against the law at constructed angles, against the
//! isotropic energy bitwise when warp = weft = 0, against finite differences and num-dual, and with the
//! material direction from texture coordinates (OBJ `vt`, PLY `u`,`v`) equal to the constant one.

use hinge_core::TriMesh;
use hinge_core::anisotropy::{
    Anisotropic, Anisotropy, AnisotropyError, MaterialDirection, TriangleUv, hinge_material_angles,
};
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::grid::{Diagonal, grid};
use hinge_core::meshio::{MeshFormat, read_mesh_from};
use hinge_core::psi::runtime::{ParamValue, RuntimePsi};
use hinge_core::psi::{DiscreteShells, HingePsi, TanBending};
use hinge_core::shapes::{
    bend, icosphere, irregular_sheet, random_permutation, renumber, renumber_positions,
    sliver_sheet,
};
use hinge_tests::*;
use nalgebra::Vector3;

const SEQ: Parallelism = Parallelism::Sequential;

fn eval<P: HingePsi>(
    rest: &TriMesh,
    psi: P,
    x: &[Vector3<f64>],
    method: Method,
) -> hinge_core::bending::Evaluation {
    BendingModel::new(rest, psi)
        .unwrap()
        .evaluate(x, Request::ALL, method, SEQ)
        .unwrap()
}

/// One hinge along the x axis (x1 = origin, x2 = (1, 0, 0)), flat at rest, bent by lifting x0.
fn one_hinge() -> (TriMesh, Vec<Vector3<f64>>) {
    let rest = one_hinge_mesh();
    let mut x = one_hinge_positions();
    x[0].z = 0.35;
    x[3].z = 0.1;
    (rest, x)
}

#[test]
fn the_energy_is_the_law_times_the_isotropic_energy_over_a_sweep_of_angles() {
    let (rest, x) = one_hinge();
    let law = Anisotropy::new(3.0, 0.5).unwrap();
    let iso = eval(&rest, TanBending { k: 0.8 }, &x, Method::Refactored);
    let mut worst = 0.0_f64;
    for step in 0..=48 {
        // The warp direction at angle φ to the hinge edge (the x axis), in the sheet's plane; a little
        // out-of-plane component is projected away.
        let phi = std::f64::consts::PI * step as f64 / 24.0 - std::f64::consts::PI;
        let d = Vector3::new(phi.cos(), phi.sin(), 0.3);
        let expected = 1.0 + 3.0 * phi.sin().powi(2) + 0.5 * phi.cos().powi(2);
        let factors = law
            .hinge_factors(&rest, &MaterialDirection::Constant(d))
            .unwrap();
        assert_eq!(factors.len(), 1);
        let angle = hinge_material_angles(&rest, &MaterialDirection::Constant(d)).unwrap()[0];
        // φ folded into [0, π/2]: the law depends on the line only.
        let folded = phi.cos().abs().acos();
        assert!((angle - folded).abs() < 1e-7, "{angle} vs {folded}");
        let an = eval(
            &rest,
            Anisotropic::new(TanBending { k: 0.8 }, factors),
            &x,
            Method::Refactored,
        );
        let e_ratio = an.energy / iso.energy;
        let g: Vec<f64> = iso.gradient.iter().map(|v| v * expected).collect();
        let h: Vec<f64> = iso.hessian.iter().map(|v| v * expected).collect();
        let err = ((e_ratio - expected) / expected)
            .abs()
            .max(rel_error(&an.gradient, &g))
            .max(rel_error(&an.hessian, &h));
        worst = worst.max(err);
        assert!(err < 1e-14, "φ = {phi}: ratio {e_ratio} vs law {expected}");
    }
    println!("energy / isotropic energy vs s(φ) over 49 angles: worst relative error {worst:.1e}");
}

#[test]
fn zero_warp_and_weft_reproduce_isotropic_bending_bitwise() {
    let irr = irregular_sheet(20, 16, 3).unwrap();
    let perm = random_permutation(irr.n_vertices(), 21);
    let irr_r = renumber(&irr, &perm).unwrap();
    let x = bend(irr.positions());
    let xr = renumber_positions(&x, &perm);
    let sliv = sliver_sheet(8, 2).unwrap();
    let xs = bend(sliv.positions());
    let law = Anisotropy::new(0.0, 0.0).unwrap();
    for (name, mesh, x) in [
        ("irregular", &irr, &x),
        ("irregular renumbered", &irr_r, &xr),
        ("slivers", &sliv, &xs),
    ] {
        let f = law
            .hinge_factors(
                mesh,
                &MaterialDirection::Constant(Vector3::new(0.3, 1.0, 0.0)),
            )
            .unwrap();
        assert!(f.iter().all(|&s| s == 1.0), "{name}");
        for method in Method::ALL {
            let iso = eval(mesh, TanBending { k: 0.7 }, x, method);
            let an = eval(
                mesh,
                Anisotropic::new(TanBending { k: 0.7 }, f.clone()),
                x,
                method,
            );
            assert_eq!(iso.energy.to_bits(), an.energy.to_bits(), "{name}");
            assert!(
                iso.gradient
                    .iter()
                    .zip(&an.gradient)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{name} {}",
                method.name()
            );
            assert!(
                iso.hessian
                    .iter()
                    .zip(&an.hessian)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{name} {}",
                method.name()
            );
        }
    }
    // A closed mesh with unit factors (any per-hinge field works, not only the warp/weft law).
    let ico = icosphere(2, 1.0).unwrap();
    let xi: Vec<_> = ico
        .positions()
        .iter()
        .map(|p| p * (1.0 + 0.1 * (3.0 * p.x).sin()))
        .collect();
    let n_hinges = BendingModel::new(&ico, TanBending { k: 1.0 })
        .unwrap()
        .topology()
        .hinges()
        .len();
    let iso = eval(&ico, TanBending { k: 1.0 }, &xi, Method::Refactored);
    let an = eval(
        &ico,
        Anisotropic::new(TanBending { k: 1.0 }, vec![1.0; n_hinges]),
        &xi,
        Method::Refactored,
    );
    assert_eq!(iso.hessian, an.hessian);
}

#[test]
fn anisotropic_energies_match_finite_differences_and_num_dual() {
    // Built-in, derived (discrete shells is declared with the derive) and run-time ψ, on a bent irregular
    // sheet in random numbering.
    let irr = irregular_sheet(9, 7, 5).unwrap();
    let perm = random_permutation(irr.n_vertices(), 8);
    let rest = renumber(&irr, &perm).unwrap();
    let x = bend(rest.positions());
    let law = Anisotropy::new(4.0, 0.25).unwrap();
    let f = law
        .hinge_factors(
            &rest,
            &MaterialDirection::Constant(Vector3::new(1.0, 0.4, 0.0)),
        )
        .unwrap();
    assert!(f.iter().any(|&s| s > 2.0) && f.iter().any(|&s| s < 2.0));
    fn check<P: HingePsi>(name: &str, rest: &TriMesh, x: &[Vector3<f64>], psi: P) {
        let m = BendingModel::new(rest, psi).unwrap();
        let r = m
            .evaluate(x, Request::ALL, Method::Refactored, SEQ)
            .unwrap();
        let a = m.evaluate(x, Request::ALL, Method::Autodiff, SEQ).unwrap();
        let (fd_g, fd_h) = fd_energy_derivatives(x, 1e-6, |y| {
            let e = m
                .evaluate(y, Request::GRADIENT, Method::Refactored, SEQ)
                .unwrap();
            (e.energy, e.gradient)
        });
        let dense = sym_dense(m.pattern(), &r.hessian);
        let (eg, eh) = (rel_error(&r.gradient, &fd_g), rel_error(&dense, &fd_h));
        let (ag, ah) = (
            rel_error(&r.gradient, &a.gradient),
            rel_error(&r.hessian, &a.hessian),
        );
        println!(
            "{name}: vs FD gradient {eg:.1e} Hessian {eh:.1e}; vs num-dual gradient {ag:.1e} Hessian {ah:.1e}"
        );
        assert!(eg < 1e-7 && eh < 1e-6, "{name}: FD {eg} {eh}");
        assert!(ag < 1e-13 && ah < 1e-13, "{name}: num-dual {ag} {ah}");
    }
    check(
        "tan bending",
        &rest,
        &x,
        Anisotropic::new(TanBending { k: 0.7 }, f.clone()),
    );
    check(
        "discrete shells (derived)",
        &rest,
        &x,
        Anisotropic::new(DiscreteShells { k: 1.3 }, f.clone()),
    );
    let runtime = RuntimePsi::new(
        "k * a * (1.0 - cos(theta - theta_bar)) + c * pow(sinh(theta), 2)",
        [
            ("k", ParamValue::Scalar(0.9)),
            ("c", ParamValue::Scalar(0.05)),
        ],
    )
    .unwrap();
    check(
        "run-time ψ",
        &rest,
        &x,
        Anisotropic::new(runtime, f.clone()),
    );
}

/// Planar texture coordinates of a flat mesh: u along `axis` (a unit vector in the xy plane), v across.
fn planar_uvs(mesh: &TriMesh, axis: Vector3<f64>) -> Vec<Option<TriangleUv>> {
    let across = Vector3::new(-axis.y, axis.x, 0.0);
    let x = mesh.positions();
    mesh.triangles()
        .iter()
        .map(|t| Some(t.map(|v| [2.0 * x[v].dot(&axis), 0.5 * x[v].dot(&across)])))
        .collect()
}

#[test]
fn uv_directions_equal_the_constant_direction_on_flat_sheets() {
    let law = Anisotropy::new(5.0, 1.5).unwrap();
    for (name, mesh) in [
        ("grid", grid(8, 6, 1.0, 0.7, Diagonal::Alternating).unwrap()),
        ("irregular", irregular_sheet(12, 9, 4).unwrap()),
    ] {
        for alpha in [0.0, 0.3, 1.2, 2.9] {
            let axis = Vector3::new(f64::cos(alpha), f64::sin(alpha), 0.0);
            let from_uv = law
                .hinge_factors(&mesh, &MaterialDirection::Uv(&planar_uvs(&mesh, axis)))
                .unwrap();
            let constant = law
                .hinge_factors(&mesh, &MaterialDirection::Constant(axis))
                .unwrap();
            let err = rel_error(&from_uv, &constant);
            assert!(err < 1e-12, "{name} α = {alpha}: {err}");
        }
    }
    // The same through the file readers: an OBJ with `vt` and `f v/vt`, a PLY with vertex `u`, `v`.
    let mesh = irregular_sheet(6, 5, 9).unwrap();
    let axis = Vector3::new(0.6, 0.8, 0.0);
    let uvs = planar_uvs(&mesh, axis);
    let across = Vector3::new(-axis.y, axis.x, 0.0);
    let vertex_uv: Vec<[f64; 2]> = mesh
        .positions()
        .iter()
        .map(|p| [2.0 * p.dot(&axis), 0.5 * p.dot(&across)])
        .collect();
    let mut obj = String::new();
    for p in mesh.positions() {
        obj += &format!("v {:e} {:e} {:e}\n", p.x, p.y, p.z);
    }
    for uv in &vertex_uv {
        obj += &format!("vt {:e} {:e}\n", uv[0], uv[1]);
    }
    for t in mesh.triangles() {
        obj += &format!(
            "f {}/{} {}/{}/1 {}/{}\n",
            t[0] + 1,
            t[0] + 1,
            t[1] + 1,
            t[1] + 1,
            t[2] + 1,
            t[2] + 1
        );
    }
    let file = read_mesh_from(obj.as_bytes(), MeshFormat::Obj, "sheet.obj").unwrap();
    assert_eq!(file.uvs, uvs);
    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nproperty float64 u\nproperty float64 v\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.n_vertices(),
        mesh.n_triangles()
    );
    for (p, uv) in mesh.positions().iter().zip(&vertex_uv) {
        ply += &format!("{:e} {:e} {:e} {:e} {:e}\n", p.x, p.y, p.z, uv[0], uv[1]);
    }
    for t in mesh.triangles() {
        ply += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    let file = read_mesh_from(ply.as_bytes(), MeshFormat::Ply, "sheet.ply").unwrap();
    assert_eq!(file.uvs, uvs);
    let from_file = law
        .hinge_factors(&file.mesh, &MaterialDirection::Uv(&file.uvs))
        .unwrap();
    let constant = law
        .hinge_factors(&mesh, &MaterialDirection::Constant(axis))
        .unwrap();
    assert!(rel_error(&from_file, &constant) < 1e-12);
    // A quad with texture coordinates, fan-triangulated: the corners follow the fan.
    let quad =
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n";
    let file = read_mesh_from(quad.as_bytes(), MeshFormat::Obj, "quad.obj").unwrap();
    assert_eq!(
        file.uvs,
        vec![
            Some([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]),
            Some([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        ]
    );
    // No texture coordinates: an empty list.
    let plain = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    assert!(
        read_mesh_from(plain.as_bytes(), MeshFormat::Obj, "p.obj")
            .unwrap()
            .uvs
            .is_empty()
    );
}

#[test]
fn bad_anisotropy_input_is_a_typed_error_naming_the_key_hinge_or_triangle() {
    let sheet = grid(3, 2, 1.0, 1.0, Diagonal::Forward).unwrap();
    for (w, v) in [(-1.0, 0.0), (0.0, f64::NAN), (f64::INFINITY, 1.0)] {
        assert!(matches!(
            Anisotropy::new(w, v),
            Err(AnisotropyError::Ratio { .. })
        ));
    }
    let law = Anisotropy::new(1.0, 0.0).unwrap();
    assert!(matches!(
        law.hinge_factors(&sheet, &MaterialDirection::Constant(Vector3::zeros())),
        Err(AnisotropyError::Direction { .. })
    ));
    // Normal to a flat sheet: no direction in the surface.
    let e = law
        .hinge_factors(&sheet, &MaterialDirection::Constant(Vector3::z()))
        .unwrap_err();
    assert!(
        matches!(e, AnisotropyError::NormalToSurface { hinge: 0, .. }),
        "{e}"
    );
    // UVs: wrong count, missing on a triangle next to a hinge, degenerate (collinear) on one.
    let mut uvs = planar_uvs(&sheet, Vector3::x());
    assert!(matches!(
        law.hinge_factors(&sheet, &MaterialDirection::Uv(&uvs[1..])),
        Err(AnisotropyError::UvCount { .. })
    ));
    uvs[4] = None;
    let e = law
        .hinge_factors(&sheet, &MaterialDirection::Uv(&uvs))
        .unwrap_err();
    assert_eq!(e, AnisotropyError::MissingUv { triangle: 4 });
    assert!(e.to_string().contains("triangle 4"), "{e}");
    uvs[4] = Some([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]);
    let e = law
        .hinge_factors(&sheet, &MaterialDirection::Uv(&uvs))
        .unwrap_err();
    assert!(
        matches!(e, AnisotropyError::DegenerateUv { triangle: 4, .. }),
        "{e}"
    );
    // Factors that do not fit the mesh: a typed error when the model is built, never a panic.
    let n_hinges = hinge_core::topology::hinges(&sheet).unwrap().len();
    for factors in [vec![1.0; n_hinges - 1], {
        let mut f = vec![1.0; n_hinges];
        f[n_hinges - 1] = -1.0;
        f
    }] {
        let e = BendingModel::new(&sheet, Anisotropic::new(TanBending { k: 1.0 }, factors))
            .err()
            .unwrap();
        assert!(e.to_string().contains("anisotropy"), "{e}");
    }
    // A texture index beyond the `vt` lines names the line.
    let bad = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n";
    let e = read_mesh_from(bad.as_bytes(), MeshFormat::Obj, "bad.obj").unwrap_err();
    assert!(
        e.to_string().contains("line 5") && e.to_string().contains("texture index 2"),
        "{e}"
    );
}
