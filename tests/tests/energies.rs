//! Every energy of hinge-energies: gradient and Hessian against finite differences, zero energy and force at
//! rest where the model says so, rigid-motion invariance; systems compose additively; hinge terms share one
//! pass; the tan energy near ±π.

use hinge_core::TriMesh;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::grid::{Diagonal, grid};
use hinge_core::nalgebra::{Rotation3, Vector3};
use hinge_core::psi::HingePsi;
use hinge_energies::bending::{
    Bridson, DiscreteShells, TanBending, ViscousDamping, Willmore, plate_consistent_stiffness,
    stiffness_from_material,
};
use hinge_energies::contact::{Contact, Obstacle};
use hinge_energies::corotational::CorotationalMembrane;
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::StvkMembrane;
use hinge_energies::neohookean::NeoHookeanMembrane;
use hinge_energies::quadratic::QuadraticBending;
use hinge_energies::spring::MassSpring;
use hinge_tests::*;

/// A flat rest grid and a deformed state (stretched a little, bent, jittered).
fn meshes() -> (TriMesh, Vec<Vector3<f64>>) {
    let rest = grid(5, 4, 1.0, 0.8, Diagonal::Alternating).unwrap();
    let mut rng = SplitMix64(17);
    let def = rest
        .positions()
        .iter()
        .map(|p| {
            Vector3::new(
                1.05 * p.x + 0.02 * rng.symmetric(),
                0.97 * p.y + 0.02 * rng.symmetric(),
                0.15 * (2.0 * p.x).sin() + 0.03 * rng.symmetric(),
            )
        })
        .collect();
    (rest, def)
}

fn hinge<P: HingePsi + Send + 'static>(rest: &TriMesh, psi: P) -> Box<dyn Energy>
where
    P::Params: Send + Sync,
{
    Box::new(HingeTerm::new(
        "hinge",
        BendingModel::new(rest, psi).unwrap(),
        Method::Refactored,
    ))
}

fn all_energies(rest: &TriMesh) -> Vec<(&'static str, Box<dyn Energy>, bool)> {
    // (name, energy, zero energy and force at rest, rigid-motion invariant)
    let n = rest.n_vertices();
    vec![
        (
            "discrete-shells",
            hinge(rest, DiscreteShells { k: 1.3 }),
            true,
        ),
        ("tan-bending", hinge(rest, TanBending { k: 0.7 }), true),
        ("willmore", hinge(rest, Willmore { k: 0.9 }), true),
        ("bridson", hinge(rest, Bridson { k: 1.1 }), true),
        (
            "viscous-damping",
            hinge(rest, ViscousDamping { kd: 0.2 }),
            true,
        ),
        (
            "mass-spring",
            Box::new(MassSpring::new(rest, 50.0).unwrap()),
            true,
        ),
        (
            "bending-springs",
            Box::new(MassSpring::bending_springs(rest, 30.0).unwrap()),
            true,
        ),
        (
            "mass-spring-psd",
            Box::new(
                MassSpring::new(rest, 50.0)
                    .unwrap()
                    .drop_compressive_term(true),
            ),
            true,
        ),
        (
            "quadratic-bending",
            Box::new(QuadraticBending::new(rest, 0.8).unwrap()),
            true,
        ),
        (
            "membrane",
            Box::new(StvkMembrane::new(rest, 1000.0, 0.3, 0.01).unwrap()),
            true,
        ),
        (
            "corotational-membrane",
            Box::new(CorotationalMembrane::new(rest, 40.0).unwrap()),
            true,
        ),
        (
            "neo-hookean-membrane",
            Box::new(NeoHookeanMembrane::new(rest, 1000.0, 0.3, 0.01).unwrap()),
            true,
        ),
        (
            "gravity",
            Box::new(
                Gravity::new(lumped_masses(rest, 0.2), Vector3::new(0.0, 0.0, -9.81)).unwrap(),
            ),
            false,
        ),
        (
            "contact-sphere",
            Box::new(
                Contact::new(
                    n,
                    Obstacle::Sphere {
                        center: Vector3::new(0.5, 0.4, -0.8),
                        radius: 0.9,
                    },
                    300.0,
                    0.05,
                )
                .unwrap(),
            ),
            false,
        ),
        (
            "contact-plane",
            Box::new(
                Contact::new(
                    n,
                    Obstacle::Plane {
                        point: Vector3::new(0.0, 0.0, 0.05),
                        normal: Vector3::new(0.1, 0.0, 1.0),
                    },
                    300.0,
                    0.02,
                )
                .unwrap(),
            ),
            false,
        ),
        (
            "contact-sphere-smoothed",
            Box::new(
                Contact::new(
                    n,
                    Obstacle::Sphere {
                        center: Vector3::new(0.5, 0.4, -0.8),
                        radius: 0.9,
                    },
                    300.0,
                    0.05,
                )
                .and_then(|c| c.with_smoothing(0.03))
                .unwrap(),
            ),
            false,
        ),
        (
            "contact-plane-smoothed",
            Box::new(
                Contact::new(
                    n,
                    Obstacle::Plane {
                        point: Vector3::new(0.0, 0.0, 0.05),
                        normal: Vector3::new(0.1, 0.0, 1.0),
                    },
                    300.0,
                    0.02,
                )
                .and_then(|c| c.with_smoothing(0.01))
                .unwrap(),
            ),
            false,
        ),
        (
            "contact-sphere-barrier",
            Box::new(
                Contact::new(
                    n,
                    Obstacle::Sphere {
                        center: Vector3::new(0.5, 0.4, -0.8),
                        radius: 0.88,
                    },
                    300.0,
                    0.06,
                )
                .and_then(Contact::with_barrier)
                .unwrap(),
            ),
            false,
        ),
        (
            "contact-plane-barrier",
            Box::new(
                Contact::new(
                    n,
                    Obstacle::Plane {
                        point: Vector3::new(0.0, 0.0, -0.06),
                        normal: Vector3::new(0.1, 0.0, 1.0),
                    },
                    300.0,
                    0.08,
                )
                .and_then(Contact::with_barrier)
                .unwrap(),
            ),
            false,
        ),
    ]
}

#[test]
fn every_energy_matches_finite_differences() {
    let (rest, def) = meshes();
    for (name, e, _) in all_energies(&rest) {
        let mut sys = System::new(rest.n_vertices(), vec![e]).unwrap();
        let ev = sys
            .evaluate(&def, Request::ALL, Parallelism::Sequential)
            .unwrap();
        let (fd_g, fd_h) = fd_energy_derivatives(&def, 1e-6, |y| {
            let r = sys
                .evaluate(y, Request::GRADIENT, Parallelism::Sequential)
                .unwrap();
            (r.energy, r.gradient)
        });
        let p = sys.pattern();
        let dense = sym_dense(p, &ev.hessian);
        let (eg, eh) = (rel_error(&ev.gradient, &fd_g), rel_error(&dense, &fd_h));
        println!(
            "{name:>18}: E {:.6e}  gradient vs FD {eg:.2e}  hessian vs FD {eh:.2e}",
            ev.energy
        );
        assert!(
            ev.energy.is_finite() && ev.energy != 0.0,
            "{name}: energy {}",
            ev.energy
        );
        assert!(eg < 1e-7, "{name}: gradient {eg}");
        // The compressive-term-free spring Hessian is deliberately not exact.
        if name != "mass-spring-psd" {
            assert!(eh < 1e-6, "{name}: hessian {eh}");
        }
    }
}

#[test]
fn hinge_family_refactored_matches_autodiff_through_the_assembly() {
    let (rest, def) = meshes();
    fn both<P: HingePsi + Clone + Send + 'static>(
        rest: &TriMesh,
        def: &[Vector3<f64>],
        psi: P,
    ) -> (f64, f64)
    where
        P::Params: Send + Sync,
    {
        let mut m = BendingModel::new(rest, psi).unwrap();
        // A previous state with other hinge angles (a uniform scaling would keep θ and zero the damping).
        let prev: Vec<_> = def
            .iter()
            .map(|p| Vector3::new(p.x, p.y, 0.7 * p.z))
            .collect();
        m.set_step(&prev, 0.01).unwrap();
        let r = m
            .evaluate(
                def,
                Request::ALL,
                Method::Refactored,
                Parallelism::Sequential,
            )
            .unwrap();
        let a = m
            .evaluate(def, Request::ALL, Method::Autodiff, Parallelism::Sequential)
            .unwrap();
        (
            rel_error(&r.gradient, &a.gradient),
            rel_error(&r.hessian, &a.hessian),
        )
    }
    for (name, (g, h)) in [
        ("willmore", both(&rest, &def, Willmore { k: 0.9 })),
        ("bridson", both(&rest, &def, Bridson { k: 1.1 })),
        (
            "viscous damping",
            both(&rest, &def, ViscousDamping { kd: 0.2 }),
        ),
        (
            "tan + damping",
            both(
                &rest,
                &def,
                (TanBending { k: 0.7 }, ViscousDamping { kd: 0.2 }),
            ),
        ),
    ] {
        println!("{name}: refactored vs num-dual gradient {g:.2e}, hessian {h:.2e}");
        assert!(g < 1e-13 && h < 1e-13, "{name}: {g} {h}");
    }
}

#[test]
fn rest_state_and_rigid_motions() {
    let (rest, def) = meshes();
    let rot = Rotation3::new(Vector3::new(0.3, -0.7, 0.5));
    let shift = Vector3::new(1.0, -2.0, 0.5);
    let moved: Vec<_> = def.iter().map(|p| rot * p + shift).collect();
    let rest_moved: Vec<_> = rest.positions().iter().map(|p| rot * p + shift).collect();
    for (name, e, internal) in all_energies(&rest) {
        if !internal {
            continue;
        }
        let mut sys = System::new(rest.n_vertices(), vec![e]).unwrap();
        // Zero energy and force at rest, and at any rigid motion of the rest state.
        for x in [rest.positions().to_vec(), rest_moved.clone()] {
            let r = sys
                .evaluate(&x, Request::ALL, Parallelism::Sequential)
                .unwrap();
            let g = r.gradient.iter().map(|v| v.abs()).fold(0.0, f64::max);
            assert!(r.energy.abs() < 1e-12, "{name}: rest energy {}", r.energy);
            assert!(g < 1e-9, "{name}: rest force {g}");
        }
        // Energy invariant under a rigid motion of a deformed state.
        let a = sys
            .evaluate(&def, Request::VALUE, Parallelism::Sequential)
            .unwrap()
            .energy;
        let b = sys
            .evaluate(&moved, Request::VALUE, Parallelism::Sequential)
            .unwrap()
            .energy;
        assert!(((a - b) / a).abs() < 1e-11, "{name}: {a} vs {b}");
    }
}

#[test]
fn systems_compose_additively_and_hinge_terms_share_one_pass() {
    let (rest, def) = meshes();
    let n = rest.n_vertices();
    let parts = || -> Vec<Box<dyn Energy>> {
        vec![
            Box::new(StvkMembrane::new(&rest, 1000.0, 0.3, 0.01).unwrap()),
            hinge(&rest, TanBending { k: 0.7 }),
            Box::new(
                Gravity::new(lumped_masses(&rest, 0.2), Vector3::new(0.0, 0.0, -9.81)).unwrap(),
            ),
        ]
    };
    let mut whole = System::new(n, parts()).unwrap();
    let w = whole
        .evaluate(&def, Request::ALL, Parallelism::Rayon)
        .unwrap();
    assert_eq!(whole.term_names(), vec!["membrane", "hinge", "gravity"]);
    let mut total_g = vec![0.0; 3 * n];
    let mut total_e = 0.0;
    let wp = whole.pattern();
    let mut total_h = vec![0.0; (3 * n) * (3 * n)];
    for (k, part) in parts().into_iter().enumerate() {
        let mut s = System::new(n, vec![part]).unwrap();
        let r = s.evaluate(&def, Request::ALL, Parallelism::Rayon).unwrap();
        assert_eq!(r.energy, w.terms[k]);
        total_e += r.energy;
        for (t, g) in total_g.iter_mut().zip(&r.gradient) {
            *t += g;
        }
        let p = s.pattern();
        for (t, h) in total_h.iter_mut().zip(sym_dense(p, &r.hessian)) {
            *t += h;
        }
    }
    assert!(((w.energy - total_e) / total_e).abs() < 1e-14);
    assert!(rel_error(&w.gradient, &total_g) < 1e-14);
    assert!(rel_error(&sym_dense(wp, &w.hessian), &total_h) < 1e-14);

    // Elastic + damping in one pass (a tuple) equals two passes.
    let mut one = System::new(
        n,
        vec![hinge(
            &rest,
            (TanBending { k: 0.7 }, ViscousDamping { kd: 0.2 }),
        )],
    )
    .unwrap();
    let mut two = System::new(
        n,
        vec![
            hinge(&rest, TanBending { k: 0.7 }),
            hinge(&rest, ViscousDamping { kd: 0.2 }),
        ],
    )
    .unwrap();
    let prev: Vec<_> = def
        .iter()
        .map(|p| Vector3::new(p.x, p.y, 0.8 * p.z))
        .collect();
    one.begin_step(&prev, 0.01).unwrap();
    two.begin_step(&prev, 0.01).unwrap();
    let a = one
        .evaluate(&def, Request::ALL, Parallelism::Rayon)
        .unwrap();
    let b = two
        .evaluate(&def, Request::ALL, Parallelism::Rayon)
        .unwrap();
    assert!(((a.energy - b.energy) / b.energy).abs() < 1e-14);
    assert!(rel_error(&a.gradient, &b.gradient) < 1e-14);
    assert!(rel_error(&a.hessian, &b.hessian) < 1e-14);
}

#[test]
fn tan_energy_near_pi_is_finite_or_a_typed_error() {
    // Two triangles folded towards θ = ±π.
    let quad = vec![
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(1.0, 1.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
    ];
    let rest = TriMesh::new(quad.clone(), vec![[0, 1, 2], [0, 2, 3]]).unwrap();
    let model = BendingModel::new(&rest, TanBending { k: 1.0 }).unwrap();
    let mut last = 0.0;
    for gap in [1e-1, 1e-2, 1e-3, 1e-4, 1e-6, 1e-8, 1e-10, 0.0] {
        for sign in [1.0, -1.0] {
            // Rotate vertex 3 about the diagonal 0–2 to angle π − gap.
            let phi = std::f64::consts::PI - gap;
            let axis = Vector3::new(1.0, 1.0, 0.0).normalize();
            let rot = Rotation3::from_axis_angle(
                &hinge_core::nalgebra::Unit::new_normalize(axis),
                sign * phi,
            );
            let mut x = quad.clone();
            x[3] = rot * x[3];
            match model.evaluate(
                &x,
                Request::ALL,
                Method::Refactored,
                Parallelism::Sequential,
            ) {
                Ok(e) => {
                    assert!(
                        e.energy.is_finite()
                            && e.gradient.iter().chain(&e.hessian).all(|v| v.is_finite()),
                        "gap {gap}"
                    );
                    if sign > 0.0 {
                        assert!(e.energy >= last, "the barrier grows as the fold closes");
                        last = e.energy;
                    }
                }
                Err(err) => assert!(
                    matches!(
                        err,
                        hinge_core::EvalError::NonFiniteEnergy { .. }
                            | hinge_core::EvalError::Hinge { .. }
                    ),
                    "{err}"
                ),
            }
        }
    }
    assert!(last > 1e10, "energy near the fold: {last}");
}

#[test]
fn material_stiffness_and_bad_parameters() {
    // Eq. 11 for a 1 mm steel-like shell.
    let k = stiffness_from_material(2e11, 1e-3, 0.3);
    assert!((k - 2e11 * 1e-9 / (24.0 * 0.91)).abs() < 1e-6);
    let (rest, _) = meshes();
    assert!(MassSpring::new(&rest, f64::NAN).is_err());
    assert!(StvkMembrane::new(&rest, 1.0, 0.6, 0.1).is_err());
    assert!(
        Gravity::new(vec![1.0, -1.0], Vector3::zeros())
            .unwrap_err()
            .to_string()
            .contains("vertex 1")
    );
    assert!(
        Contact::new(
            3,
            Obstacle::Plane {
                point: Vector3::zeros(),
                normal: Vector3::zeros()
            },
            1.0,
            0.0
        )
        .is_err()
    );
    assert!(
        hinge_energies::pins::Pins::new(4, vec![1, 9])
            .unwrap_err()
            .to_string()
            .contains('9')
    );
    let pins = hinge_energies::pins::Pins::new(4, vec![2, 1, 2]).unwrap();
    assert_eq!(pins.vertices(), &[1, 2]);
    assert_eq!(pins.free_dofs().iter().filter(|f| !**f).count(), 6);
}

/// Independent generic implementations of the non-hinge energies, differentiated by num-dual: the
/// closed-form gradients and Hessians must agree with them.
mod autodiff_oracle {
    use super::*;
    use hinge_core::nalgebra::{SMatrix, SVector};
    use num_dual::{Dual2SVec64, DualNum, hessian};

    fn v3<D: Copy>(x: &[D], i: usize) -> [D; 3] {
        [x[3 * i], x[3 * i + 1], x[3 * i + 2]]
    }

    fn norm<D: DualNum<Primitive = f64> + Copy>(a: [D; 3]) -> D {
        (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
    }

    /// Dense full Hessian and gradient of a one-energy system.
    fn closed_form(e: Box<dyn Energy>, x: &[Vector3<f64>]) -> (Vec<f64>, Vec<f64>) {
        let mut s = System::new(x.len(), vec![e]).unwrap();
        let r = s
            .evaluate(x, Request::ALL, Parallelism::Sequential)
            .unwrap();
        let p = s.pattern();
        (r.gradient.clone(), sym_dense(p, &r.hessian))
    }

    fn flat<const N: usize>(x: &[Vector3<f64>]) -> SVector<f64, N> {
        SVector::from_iterator(x.iter().flat_map(|p| [p.x, p.y, p.z]))
    }

    fn compare<const N: usize>(
        name: &str,
        (g, h): (Vec<f64>, Vec<f64>),
        ad: (f64, SVector<f64, N>, SMatrix<f64, N, N>),
    ) {
        let hd: Vec<f64> = (0..N * N).map(|k| ad.2[(k / N, k % N)]).collect();
        let (eg, eh) = (rel_error(&g, ad.1.as_slice()), rel_error(&h, &hd));
        println!("{name}: gradient vs num-dual {eg:.2e}, hessian {eh:.2e}");
        assert!(eg < 1e-13 && eh < 1e-13, "{name}: {eg} {eh}");
    }

    #[test]
    fn spring_membrane_contact_quadratic_match_num_dual() {
        let tri = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.1, 0.0),
            Vector3::new(0.2, 0.9, 0.0),
        ];
        let rest = TriMesh::new(tri.clone(), vec![[0, 1, 2]]).unwrap();
        let def = vec![
            Vector3::new(0.05, -0.02, 0.1),
            Vector3::new(1.1, 0.2, -0.05),
            Vector3::new(0.1, 1.0, 0.2),
        ];
        let x = flat::<9>(&def);

        // Springs: ½k(l − L)² per edge.
        let k = 7.0;
        let lens: Vec<f64> = [[1, 2], [0, 2], [0, 1]]
            .iter()
            .map(|&[i, j]: &[usize; 2]| (tri[i] - tri[j]).norm())
            .collect();
        let ad = hessian(
            |v: SVector<Dual2SVec64<9>, 9>| {
                let s = v.as_slice();
                let mut e = Dual2SVec64::<9>::from(0.0);
                for (n, &[i, j]) in [[1usize, 2usize], [0, 2], [0, 1]].iter().enumerate() {
                    let (a, b) = (v3(s, i), v3(s, j));
                    let l = norm([a[0] - b[0], a[1] - b[1], a[2] - b[2]]);
                    let d = l - lens[n];
                    e += d * d * (0.5 * k);
                }
                e
            },
            &x,
        );
        compare(
            "mass-spring",
            closed_form(Box::new(MassSpring::new(&rest, k).unwrap()), &def),
            ad,
        );

        // StVK: h A (μ tr(E²) + λ/2 tr(E)²) with E from the metric of the deformed edges against the rest
        // metric, written without a rest frame: E = ½ (Dm⁻ᵀ Dsᵀ Ds Dm⁻¹ − I) via the rest Gram matrix.
        let (young, nu, h) = (900.0, 0.35, 0.02);
        let (mu, lambda) = (young / (2.0 * (1.0 + nu)), young * nu / (1.0 - nu * nu));
        let (r1, r2) = (tri[1] - tri[0], tri[2] - tri[0]);
        let gram =
            hinge_core::nalgebra::Matrix2::new(r1.dot(&r1), r1.dot(&r2), r1.dot(&r2), r2.dot(&r2));
        let gi = gram.try_inverse().unwrap();
        let area = 0.5 * r1.cross(&r2).norm();
        let ad = hessian(
            |v: SVector<Dual2SVec64<9>, 9>| {
                let s = v.as_slice();
                let (p0, p1, p2) = (v3(s, 0), v3(s, 1), v3(s, 2));
                let d1 = [p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]];
                let d2 = [p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]];
                let dot = |a: [Dual2SVec64<9>; 3], b: [Dual2SVec64<9>; 3]| {
                    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
                };
                // Deformed Gram matrix g; strain in the rest metric: M = G⁻¹ g − I, tr(E) = ½ tr(M),
                // tr(E²) = ¼ tr(M²).
                let g = [[dot(d1, d1), dot(d1, d2)], [dot(d1, d2), dot(d2, d2)]];
                let m = |i: usize, j: usize| {
                    g[0][j] * gi[(i, 0)] + g[1][j] * gi[(i, 1)] - if i == j { 1.0 } else { 0.0 }
                };
                let tr = (m(0, 0) + m(1, 1)) * 0.5;
                let tr2 = (m(0, 0) * m(0, 0) + m(0, 1) * m(1, 0) * 2.0 + m(1, 1) * m(1, 1)) * 0.25;
                (tr2 * mu + tr * tr * (0.5 * lambda)) * (h * area)
            },
            &x,
        );
        compare(
            "membrane",
            closed_form(
                Box::new(StvkMembrane::new(&rest, young, nu, h).unwrap()),
                &def,
            ),
            ad,
        );

        // Sphere contact: ½κ(δ − (|x − c| − r))² where active.
        let (c, r, kappa, delta) = (Vector3::new(0.3, 0.3, -0.8), 1.0, 50.0, 0.1);
        let ad = hessian(
            |v: SVector<Dual2SVec64<9>, 9>| {
                let s = v.as_slice();
                let mut e = Dual2SVec64::<9>::from(0.0);
                for i in 0..3 {
                    let p = v3(s, i);
                    let d = norm([p[0] - c.x, p[1] - c.y, p[2] - c.z]) - r;
                    if d.re < delta {
                        let sgap = -d + delta;
                        e += sgap * sgap * (0.5 * kappa);
                    }
                }
                e
            },
            &x,
        );
        let contact = Contact::new(
            3,
            Obstacle::Sphere {
                center: c,
                radius: r,
            },
            kappa,
            delta,
        )
        .unwrap();
        compare("contact-sphere", closed_form(Box::new(contact), &def), ad);
    }

    /// The C² (smoothed) contact penalty against num-dual, with one vertex in the cubic part of the margin,
    /// one past the smoothing length and one outside.
    #[test]
    fn smoothed_contact_matches_num_dual_in_both_branches() {
        let def = vec![
            Vector3::new(0.05, -0.02, 0.1),
            Vector3::new(1.1, 0.2, -0.1),
            Vector3::new(0.1, 1.0, 0.2),
        ];
        let x = flat::<9>(&def);
        let (c, r, kappa, delta, eps) = (Vector3::new(0.3, 0.3, -0.8), 1.0, 50.0, 0.1, 0.06);
        let contact = Contact::new(
            3,
            Obstacle::Sphere {
                center: c,
                radius: r,
            },
            kappa,
            delta,
        )
        .and_then(|k| k.with_smoothing(eps))
        .unwrap();
        // The penetrations s = δ − d: past ε, inside (0, ε), outside.
        let s: Vec<f64> = def.iter().map(|p| delta - contact.distance(p)).collect();
        assert!(
            s[0] > eps && s[1] > 0.0 && s[1] < eps && s[2] < 0.0,
            "{s:?}"
        );
        let ad = hessian(
            |v: SVector<Dual2SVec64<9>, 9>| {
                let sl = v.as_slice();
                let mut e = Dual2SVec64::<9>::from(0.0);
                for i in 0..3 {
                    let p = v3(sl, i);
                    let d = norm([p[0] - c.x, p[1] - c.y, p[2] - c.z]) - r;
                    let gap = -d + delta;
                    if gap.re >= eps {
                        e += (gap * gap - gap * eps + eps * eps / 3.0) * (0.5 * kappa);
                    } else if gap.re > 0.0 {
                        e += gap * gap * gap * (kappa / (6.0 * eps));
                    }
                }
                e
            },
            &x,
        );
        compare(
            "contact-sphere-smoothed",
            closed_form(Box::new(contact), &def),
            ad,
        );
    }

    /// The barrier contact against num-dual on a sphere (whose curvature enters the Hessian) and a tilted
    /// plane, with vertices deep in the barrier's reach, near its edge and outside it.
    #[test]
    fn barrier_contact_matches_num_dual() {
        let def = vec![
            Vector3::new(0.05, -0.02, 0.1),
            Vector3::new(1.1, 0.2, -0.1),
            Vector3::new(0.1, 1.0, 0.2),
        ];
        let x = flat::<9>(&def);
        let kappa = 50.0;
        // b(d) = −κ (d − δ)² ln(d/δ) for 0 < d < δ, written from the definition.
        let b = |d: Dual2SVec64<9>, delta: f64| {
            let e = d - delta;
            -(e * e * (d / delta).ln()) * kappa
        };
        let sphere = (Vector3::new(0.3, 0.3, -0.8), 0.9);
        let (point, normal) = (Vector3::new(0.2, 0.0, -0.1), Vector3::new(1.0, 0.2, 1.0));
        let unit = normal.normalize();
        let distance = |p: [Dual2SVec64<9>; 3], on_sphere: bool| {
            if on_sphere {
                let (c, r) = sphere;
                norm([p[0] - c.x, p[1] - c.y, p[2] - c.z]) - r
            } else {
                (p[0] - point.x) * unit.x + (p[1] - point.y) * unit.y + (p[2] - point.z) * unit.z
            }
        };
        for (on_sphere, delta) in [(true, 0.2), (false, 0.3)] {
            let obstacle = if on_sphere {
                Obstacle::Sphere {
                    center: sphere.0,
                    radius: sphere.1,
                }
            } else {
                Obstacle::Plane { point, normal }
            };
            let contact = Contact::new(3, obstacle, kappa, delta)
                .and_then(Contact::with_barrier)
                .unwrap();
            let d: Vec<f64> = def.iter().map(|p| contact.distance(p)).collect();
            let inside = d.iter().filter(|&&d| d > 0.0 && d < delta).count();
            assert!(d.iter().all(|&d| d > 0.0) && inside == 2, "{d:?}");
            let ad = hessian(
                |v: SVector<Dual2SVec64<9>, 9>| {
                    let sl = v.as_slice();
                    let mut e = Dual2SVec64::<9>::from(0.0);
                    for i in 0..3 {
                        let d = distance(v3(sl, i), on_sphere);
                        if d.re < delta {
                            e += b(d, delta);
                        }
                    }
                    e
                },
                &x,
            );
            let name = if on_sphere {
                "barrier-sphere"
            } else {
                "barrier-plane"
            };
            compare(name, closed_form(Box::new(contact), &def), ad);
        }
    }

    #[test]
    fn drag_matches_num_dual_and_finite_differences() {
        use hinge_energies::drag::Drag;
        let masses = vec![0.3, 0.5, 0.2];
        let x_hat = vec![
            Vector3::new(0.0, 0.1, 0.0),
            Vector3::new(1.0, 0.0, 0.2),
            Vector3::new(0.2, 0.9, -0.1),
        ];
        let def = vec![
            Vector3::new(0.05, -0.02, 0.1),
            Vector3::new(1.1, 0.2, -0.05),
            Vector3::new(0.1, 1.0, 0.2),
        ];
        let (rate, dt) = (2.5, 0.02);
        let mut drag = Drag::new(masses.clone(), rate).unwrap();
        // Before a step is known the energy is zero; bad steps are typed errors.
        let mut probe = System::new(3, vec![Box::new(drag.clone())]).unwrap();
        let r = probe
            .evaluate(&def, Request::ALL, Parallelism::Sequential)
            .unwrap();
        assert_eq!(r.energy, 0.0);
        assert!(drag.begin_step(&x_hat, 0.0).is_err());
        assert!(drag.begin_step(&x_hat[..2], dt).is_err());
        assert!(Drag::new(vec![1.0, f64::NAN], 1.0).is_err());
        assert!(Drag::new(vec![1.0], -1.0).is_err());
        drag.begin_step(&x_hat, dt).unwrap();
        let ad = hessian(
            |v: SVector<Dual2SVec64<9>, 9>| {
                let s = v.as_slice();
                let mut e = Dual2SVec64::<9>::from(0.0);
                for i in 0..3 {
                    let p = v3(s, i);
                    let d = [p[0] - x_hat[i].x, p[1] - x_hat[i].y, p[2] - x_hat[i].z];
                    e += (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) * (0.5 * rate * masses[i] / dt);
                }
                e
            },
            &flat::<9>(&def),
        );
        let (g, h) = closed_form(Box::new(drag.clone()), &def);
        let mut sys = System::new(3, vec![Box::new(drag)]).unwrap();
        let (fd_g, _) = fd_energy_derivatives(&def, 1e-6, |y| {
            let r = sys
                .evaluate(y, Request::GRADIENT, Parallelism::Sequential)
                .unwrap();
            (r.energy, r.gradient)
        });
        assert!(rel_error(&g, &fd_g) < 1e-8, "{}", rel_error(&g, &fd_g));
        // The force is −c m v with v = (x − x̂)/Δt.
        let v0 = (def[0] - x_hat[0]) / dt;
        assert!((g[0] - rate * masses[0] * v0.x).abs() < 1e-12);
        compare("drag", (g, h), ad);
    }

    #[test]
    fn quadratic_bending_matches_num_dual() {
        let quad = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(1.1, 0.9, 0.0),
            Vector3::new(-0.1, 1.0, 0.0),
        ];
        let rest = TriMesh::new(quad, vec![[0, 1, 2], [0, 2, 3]]).unwrap();
        let def = vec![
            Vector3::new(0.0, 0.0, 0.1),
            Vector3::new(1.0, 0.1, 0.0),
            Vector3::new(1.0, 1.0, -0.1),
            Vector3::new(0.0, 1.0, 0.3),
        ];
        let qb = QuadraticBending::new(&rest, 2.0).unwrap();
        let (stencil, q, c) = qb.weights().next().unwrap();
        // Flat rest: q annihilates constants and the rest positions.
        assert!(q.iter().sum::<f64>().abs() < 1e-14);
        let rp = rest.positions();
        let s: Vector3<f64> = (0..4).map(|i| rp[stencil[i]] * q[i]).sum();
        assert!(s.norm() < 1e-14);
        let ad = hessian(
            |v: SVector<Dual2SVec64<12>, 12>| {
                let sl = v.as_slice();
                let mut acc = [Dual2SVec64::<12>::from(0.0); 3];
                for i in 0..4 {
                    let p = v3(sl, stencil[i]);
                    for a in 0..3 {
                        acc[a] += p[a] * q[i];
                    }
                }
                (acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]) * (0.5 * c)
            },
            &flat::<12>(&def),
        );
        compare("quadratic-bending", closed_form(Box::new(qb), &def), ad);
    }
}

/// Σ a θ² / (κ² A) for `rest` (flat, in the xy plane) wrapped onto a cylinder of curvature κ whose axis is
/// the in-plane direction at angle `axis` from y (κ = 0.05 / mesh unit: bend angles far below 1).
fn cylinder_ratio(rest: &TriMesh, axis: f64) -> f64 {
    let kappa = 0.05;
    let (c, s) = (axis.cos(), axis.sin());
    let x: Vec<Vector3<f64>> = rest
        .positions()
        .iter()
        .map(|p| {
            // u across the axis, w along it.
            let (u, w) = (c * p.x + s * p.y, -s * p.x + c * p.y);
            let (su, cu) = (u * kappa).sin_cos();
            let (along, z) = (su / kappa, (1.0 - cu) / kappa);
            Vector3::new(c * along - s * w, s * along + c * w, z)
        })
        .collect();
    let model = BendingModel::new(rest, DiscreteShells { k: 1.0 }).unwrap();
    let e = model
        .evaluate(
            &x,
            Request::VALUE,
            Method::Refactored,
            Parallelism::Sequential,
        )
        .unwrap()
        .energy;
    let area: f64 = rest
        .triangles()
        .iter()
        .map(|t| {
            let p = rest.positions();
            0.5 * (p[t[1]] - p[t[0]]).cross(&(p[t[2]] - p[t[0]])).norm()
        })
        .sum();
    e / (kappa * kappa * area)
}

/// Rows of equilateral triangles (odd rows shifted by half an edge), `nx` edges along x, `ny` rows.
fn equilateral(nx: usize, ny: usize) -> TriMesh {
    let h = 1.0;
    let s = h * 3f64.sqrt() / 2.0;
    let mut p = Vec::new();
    for j in 0..=ny {
        let shift = if j % 2 == 1 { 0.5 * h } else { 0.0 };
        for i in 0..=nx {
            p.push(Vector3::new(i as f64 * h + shift, j as f64 * s, 0.0));
        }
    }
    let v = |i: usize, j: usize| j * (nx + 1) + i;
    let mut t = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            if j % 2 == 0 {
                t.push([v(i, j), v(i + 1, j), v(i, j + 1)]);
                t.push([v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)]);
            } else {
                t.push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
                t.push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
            }
        }
    }
    TriMesh::new(p, t).unwrap()
}

#[test]
fn cylinder_patch_test_gives_three_times_the_plate_energy() {
    // The plate stores (D/2) κ² per area in cylindrical bending; the hinge energy with a = 3‖ē‖²/Ā stores
    // Σ a θ² → 3 κ² per area on grids bent across their columns (exactly, up to the boundary row: the column
    // edges carry θ = κ h_x, all others 0) and on equilateral meshes in every direction. Hence
    // `plate_consistent_stiffness` = Eq. 11 / 3.
    for diagonal in [Diagonal::Forward, Diagonal::Alternating] {
        for (nx, ny, w, h) in [(60, 5, 0.3 * 40.0, 0.025 * 40.0), (40, 40, 40.0, 40.0)] {
            let rest = grid(nx, ny, w, h, diagonal).unwrap();
            let r = cylinder_ratio(&rest, 0.0);
            println!("grid {nx}×{ny} {diagonal:?}: Σaθ²/(κ²A) = {r:.4}");
            assert!((r - 3.0).abs() < 0.03 * 3.0, "{r}");
        }
    }
    let eq = equilateral(40, 46);
    for axis in [0.0, 0.3, std::f64::consts::FRAC_PI_4, 1.2] {
        let r = cylinder_ratio(&eq, axis);
        println!("equilateral, axis {axis:.2}: Σaθ²/(κ²A) = {r:.4}");
        assert!((r - 3.0).abs() < 0.03 * 3.0, "{r}");
    }
    // Bent along the diagonals, a forward grid is far stiffer: the mesh dependence the docs warn about.
    let fwd = grid(40, 40, 40.0, 40.0, Diagonal::Forward).unwrap();
    assert!(cylinder_ratio(&fwd, std::f64::consts::FRAC_PI_4) > 6.0);
    let k = plate_consistent_stiffness(7e10, 2e-3, 0.3);
    assert!((3.0 * k / stiffness_from_material(7e10, 2e-3, 0.3) - 1.0).abs() < 1e-15);
}

/// The smoothed contact penalty: its closed forms against the integrals of its second derivative (trapezoid
/// rule on a fine grid, a node at ε), continuous value, slope and curvature at both ends of the smoothing
/// length, the quadratic penalty bitwise for ε = 0 and shifted by ε/2 past ε, typed errors for bad lengths.
#[test]
fn smoothed_contact_penalty_is_c2_and_reduces_to_the_quadratic() {
    let plane = Obstacle::Plane {
        point: Vector3::zeros(),
        normal: Vector3::z(),
    };
    let (kappa, delta, eps) = (40.0, 0.01, 0.004);
    let quad = Contact::new(1, plane, kappa, delta).unwrap();
    let smooth = quad.clone().with_smoothing(eps).unwrap();
    assert_eq!(smooth.smoothing(), eps);
    // φ′(s) = ∫₀ˢ φ″, φ(s) = ∫₀ˢ φ′ (nested trapezoid sums; φ″ is piecewise linear with a kink at ε,
    // which is a grid node, so the inner rule is exact up to rounding and the outer one is O(h²)).
    let n = 20_000;
    let h = 2.0 * delta / n as f64;
    let (mut d1, mut d0, mut prev2, mut prev1) = (0.0, 0.0, 0.0, 0.0);
    for k in 1..=n {
        let s = k as f64 * h;
        let (phi, dphi, ddphi) = smooth.penalty(s);
        d1 += 0.5 * h * (prev2 + ddphi);
        d0 += 0.5 * h * (prev1 + d1);
        prev2 = ddphi;
        prev1 = d1;
        if k % 1000 == 0 {
            assert!(
                (dphi - d1).abs() <= 1e-9 * kappa * delta,
                "φ′({s}) {dphi} vs {d1}"
            );
            assert!(
                (phi - d0).abs() <= 1e-6 * kappa * delta * delta,
                "φ({s}) {phi} vs {d0}"
            );
        }
    }
    // C² at ε and at 0.
    let (below, above) = (smooth.penalty(eps * (1.0 - 1e-12)), smooth.penalty(eps));
    assert!((below.0 - above.0).abs() <= 1e-12 * kappa * eps * eps);
    assert!((below.1 - above.1).abs() <= 1e-10 * kappa * eps);
    assert!((below.2 - above.2).abs() <= 1e-10 * kappa);
    let tiny = smooth.penalty(1e-12);
    assert!(tiny.0 < 1e-30 && tiny.1 < 1e-18 && tiny.2 < 1e-6);
    assert_eq!(smooth.penalty(0.0), (0.0, 0.0, 0.0));
    assert_eq!(smooth.penalty(-1e-3), (0.0, 0.0, 0.0));
    // ε = 0 is the quadratic penalty, bitwise; past ε the slope is the quadratic's at s − ε/2.
    let zero = quad.clone().with_smoothing(0.0).unwrap();
    for s in [1e-9, 1e-4, 3e-3, 0.02, 1.5] {
        assert_eq!(zero.penalty(s), quad.penalty(s));
        assert_eq!(quad.penalty(s), (0.5 * kappa * s * s, kappa * s, kappa));
        if s >= eps {
            let shifted = quad.penalty(s - 0.5 * eps);
            assert!((smooth.penalty(s).1 - shifted.1).abs() <= 1e-12 * kappa * s);
            assert_eq!(smooth.penalty(s).2, kappa);
        }
    }
    for bad in [-1e-3, f64::NAN, f64::INFINITY] {
        let err = quad.clone().with_smoothing(bad).unwrap_err().to_string();
        assert!(err.contains("smoothing"), "{err}");
    }
}

/// The barrier of the contact: zero with zero slope and curvature at its reach (C²), convex and rising
/// without bound towards the obstacle, its derivatives the central differences of its value and slope; a
/// vertex on or inside the obstacle is a typed error naming it; bad combinations are refused.
#[test]
fn contact_barrier_is_c2_convex_and_infinite_at_the_obstacle() {
    let plane = Obstacle::Plane {
        point: Vector3::zeros(),
        normal: Vector3::z(),
    };
    let (kappa, delta) = (40.0, 0.01);
    let c = Contact::new(2, plane, kappa, delta)
        .and_then(Contact::with_barrier)
        .unwrap();
    assert!(c.is_barrier());
    assert_eq!(c.barrier(delta), Some((0.0, 0.0, 0.0)));
    assert_eq!(c.barrier(2.0 * delta), Some((0.0, 0.0, 0.0)));
    let near = c.barrier(delta * (1.0 - 1e-6)).unwrap();
    assert!(
        near.0 > 0.0
            && near.0 < 1e-15
            && near.1 < 0.0
            && near.1 > -1e-9
            && near.2 > 0.0
            && near.2 < 1e-3,
        "{near:?}"
    );
    let mut last = 0.0;
    for k in 1..200 {
        let d = delta * (1.0 - k as f64 / 200.0);
        let (v, g, h) = c.barrier(d).unwrap();
        assert!(v > last && g < 0.0 && h > 0.0, "d = {d}: {v} {g} {h}");
        last = v;
        let e = 1e-6 * d;
        let (vp, gp, _) = c.barrier(d + e).unwrap();
        let (vm, gm, _) = c.barrier(d - e).unwrap();
        assert!(
            ((vp - vm) / (2.0 * e) - g).abs() <= 1e-6 * g.abs(),
            "slope at {d}"
        );
        assert!(
            ((gp - gm) / (2.0 * e) - h).abs() <= 1e-6 * h.abs(),
            "curvature at {d}"
        );
    }
    assert!(c.barrier(1e-300).unwrap().0 > 1e-2 * kappa * delta * delta * 600.0);
    assert_eq!(c.barrier(0.0), None);
    assert_eq!(c.barrier(-1e-3), None);
    // A vertex on or below the plane: the error names it.
    let mut sys = System::new(2, vec![Box::new(c.clone())]).unwrap();
    for z in [0.0, -1e-9, -1.0] {
        let x = [Vector3::new(0.0, 0.0, 0.003), Vector3::new(1.0, 0.0, z)];
        let err = sys
            .evaluate(&x, Request::VALUE, Parallelism::Sequential)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("vertex 1") && err.contains("inside the obstacle"),
            "{err}"
        );
    }
    // Refused: no reach, a smoothing (either order). A moving obstacle is fine (either order).
    let motion = hinge_energies::motion::Motion::Translation(Vector3::new(0.0, 0.0, 1.0));
    for bad in [
        Contact::new(2, plane, kappa, 0.0).and_then(Contact::with_barrier),
        Contact::new(2, plane, kappa, delta)
            .and_then(|k| k.with_smoothing(0.002))
            .and_then(Contact::with_barrier),
        c.clone().with_smoothing(0.002),
    ] {
        assert!(bad.is_err());
    }
    assert!(c.clone().with_motion(motion.clone()).is_ok());
    assert!(
        Contact::new(2, plane, kappa, delta)
            .and_then(|k| k.with_motion(motion.clone()))
            .and_then(Contact::with_barrier)
            .is_ok()
    );
}

/// The barrier's step bound against the distance along the path sampled densely: on random straight
/// moves near a sphere and a plane (passing through, grazing, leaving), no point before the bound is closer
/// than the kept share of the start's distance, and where the bound is below 1 the distance there is that
/// share; a move through the sphere is stopped before it; the system's bound is the smallest vertex's.
#[test]
fn barrier_step_bound_keeps_the_gap_along_the_path() {
    use hinge_energies::contact::BARRIER_GAP_KEPT;
    let mut rng = SplitMix64(99);
    let obstacles = [
        Obstacle::Sphere {
            center: Vector3::new(0.1, -0.2, 0.3),
            radius: 0.5,
        },
        Obstacle::Plane {
            point: Vector3::new(0.0, 0.0, -0.1),
            normal: Vector3::new(0.3, 0.2, 1.0),
        },
    ];
    let mut bounded = 0;
    for obstacle in obstacles {
        let c = Contact::new(1, obstacle, 10.0, 0.05)
            .and_then(Contact::with_barrier)
            .unwrap();
        for _ in 0..2000 {
            let p = Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 1.5;
            let q = Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 1.5;
            let d0 = c.distance(&p);
            if d0 <= 0.0 {
                continue;
            }
            let t = c.time_to_gap(&p, &q, BARRIER_GAP_KEPT);
            assert!((0.0..=1.0).contains(&t));
            let floor = BARRIER_GAP_KEPT * d0;
            for k in 0..=400 {
                let s = t * k as f64 / 400.0;
                let d = c.distance(&(p + (q - p) * s));
                assert!(
                    d >= floor * (1.0 - 1e-9),
                    "{obstacle:?}: {d} < {floor} at {s} of {t}"
                );
            }
            if t < 1.0 {
                bounded += 1;
                let d = c.distance(&(p + (q - p) * t));
                assert!((d - floor).abs() <= 1e-9 * d0, "{d} vs {floor}");
            }
            // The system's bound over two vertices is the smaller one's.
            let far = Vector3::new(0.0, 0.0, 50.0);
            let sys = System::new(
                2,
                vec![Box::new(
                    Contact::new(2, obstacle, 10.0, 0.05)
                        .and_then(Contact::with_barrier)
                        .unwrap(),
                )],
            )
            .unwrap();
            assert_eq!(sys.max_step(&[far, p], &[far, q]), t);
        }
    }
    assert!(bounded > 300, "{bounded}");
    // Straight through the sphere's centre from 1.5 radii out on one side to the other.
    let c = Contact::new(
        1,
        Obstacle::Sphere {
            center: Vector3::zeros(),
            radius: 1.0,
        },
        10.0,
        0.05,
    )
    .and_then(Contact::with_barrier)
    .unwrap();
    let t = c.time_to_gap(
        &Vector3::new(3.0, 0.0, 0.0),
        &Vector3::new(-3.0, 0.0, 0.0),
        0.1,
    );
    assert!((t - 0.3).abs() < 1e-15, "{t}");
    // Grazing past (closest 1.5 > 1 + 0.1 · d0) and moving away: unbounded.
    let graze = c.time_to_gap(
        &Vector3::new(3.0, 1.5, 0.0),
        &Vector3::new(-3.0, 1.5, 0.0),
        0.1,
    );
    let away = c.time_to_gap(
        &Vector3::new(1.2, 0.0, 0.0),
        &Vector3::new(9.0, 0.0, 0.0),
        0.1,
    );
    assert_eq!((graze, away), (1.0, 1.0));
    // The penalty bounds nothing.
    let penalty = Contact::new(
        1,
        Obstacle::Sphere {
            center: Vector3::zeros(),
            radius: 1.0,
        },
        10.0,
        0.05,
    )
    .unwrap();
    assert_eq!(
        penalty.max_step(
            &[Vector3::new(3.0, 0.0, 0.0)],
            &[Vector3::new(-3.0, 0.0, 0.0)]
        ),
        1.0
    );
}

/// A moving barrier obstacle carries the vertices within its reach at the earlier time to the same distance
/// from it now (a plane turning and rising, a sphere moving), and leaves the others where they are; a
/// penalty contact or a fixed barrier carries nothing.
#[test]
fn moving_barrier_obstacles_carry_vertices_within_reach_at_their_distance() {
    use hinge_energies::motion::Motion;
    let plane = Obstacle::Plane {
        point: Vector3::new(0.1, 0.0, 0.0),
        normal: Vector3::new(0.2, 0.1, 1.0),
    };
    let sphere = Obstacle::Sphere {
        center: Vector3::new(0.0, 0.3, -0.5),
        radius: 0.5,
    };
    let turn = Motion::Rotation {
        center: Vector3::new(0.3, -0.2, 0.0),
        axis: Vector3::new(1.0, 2.0, 0.5).normalize(),
        angular_velocity: 0.7,
    };
    let slide = Motion::Translation(Vector3::new(0.4, -0.1, 0.3));
    let (t0, t1, reach) = (0.2, 0.25, 0.01);
    let mut rng = SplitMix64(41);
    for (obstacle, motion) in [(plane, turn), (sphere, slide)] {
        let mut c = Contact::new(200, obstacle, 10.0, reach)
            .and_then(Contact::with_barrier)
            .and_then(|k| k.with_motion(motion.clone()))
            .unwrap();
        let mut before = c.clone();
        before.set_time(t0).unwrap();
        c.set_time(t1).unwrap();
        // Points at distances 0 … 2 reaches from the obstacle at t0.
        let x: Vec<Vector3<f64>> = (0..200)
            .map(|k| {
                let p = Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 0.6;
                let want = 2.0 * reach * k as f64 / 200.0 + 1e-6;
                let (u, d) = match before.obstacle() {
                    Obstacle::Plane { normal, .. } => (normal, before.distance(&p)),
                    Obstacle::Sphere { center, .. } => {
                        ((p - center).normalize(), before.distance(&p))
                    }
                };
                p + u * (want - d)
            })
            .collect();
        let mut moved = x.clone();
        assert!(c.carry(t0, &mut moved));
        let mut carried = 0;
        for (p, q) in x.iter().zip(&moved) {
            let d0 = before.distance(p);
            if d0 < reach {
                carried += 1;
                assert!(
                    (c.distance(q) - d0).abs() <= 1e-12,
                    "{} vs {d0}",
                    c.distance(q)
                );
            } else {
                assert_eq!(p, q);
            }
        }
        assert!(carried > 80 && carried < 120, "{carried}");
        // Not a barrier, or not moving: nothing moves.
        for other in [
            Contact::new(200, obstacle, 10.0, reach)
                .and_then(|k| k.with_motion(motion.clone()))
                .unwrap(),
            Contact::new(200, obstacle, 10.0, reach)
                .and_then(Contact::with_barrier)
                .unwrap(),
        ] {
            let mut same = x.clone();
            assert!(!other.carry(t0, &mut same));
            assert_eq!(same, x);
        }
    }
}
