//! Fill-reducing orderings of the Cholesky backend (`hinge_solver::ordering`): nested dissection is a
//! permutation on every kind of pattern, leaves less fill than AMD where it should, `Auto` keeps the
//! smaller factor, and every ordering solves the same systems (against a dense factorization and by the
//! residual).

use hinge_core::TriMesh;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::grid::{Diagonal, grid};
use hinge_core::nalgebra::Vector3;
use hinge_core::shapes::{icosphere, random_permutation, renumber, sliver_sheet, torus};
use hinge_energies::bending::TanBending;
use hinge_energies::spring::MassSpring;
use hinge_solver::linear::{
    ChebyshevJacobi, Dense, FaerLlt, FaerLu, LinearError, LinearSolver, LowerCsc, PcgJacobi,
};
use hinge_solver::newton::Reduced;
use hinge_solver::ordering::{FillOrdering, nested_dissection};
use hinge_tests::*;

/// The pattern and values of springs' and tan bending's Hessian on `mesh` (stretched by 10 % and waved),
/// with the diagonal raised to make it diagonally dominant.
fn system_of(mesh: &TriMesh) -> (Reduced, Vec<f64>) {
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(MassSpring::new(mesh, 200.0).unwrap()),
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(mesh, TanBending { k: 1e-3 }).unwrap(),
            Method::Refactored,
        )),
    ];
    let mut sys = System::new(mesh.n_vertices(), terms).unwrap();
    let x: Vec<_> = mesh
        .positions()
        .iter()
        .map(|p| p * 1.1 + Vector3::new(0.0, 0.0, 0.02 * (7.0 * p.x).sin()))
        .collect();
    let e = sys
        .evaluate(&x, Request::ALL, Parallelism::Sequential)
        .unwrap();
    let red = Reduced::new(sys.pattern(), &vec![true; 3 * mesh.n_vertices()]);
    let mut vals: Vec<f64> = red.source.iter().map(|&k| e.hessian[k]).collect();
    // Diagonally dominant (Gershgorin), hence positive definite even where slivers make the bending
    // Hessian strongly indefinite.
    let mut off = vec![0.0; red.csc.n];
    for j in 0..red.csc.n {
        for k in red.csc.col_ptr[j]..red.csc.col_ptr[j + 1] {
            let i = red.csc.row_idx[k];
            if i != j {
                off[i] += vals[k].abs();
                off[j] += vals[k].abs();
            }
        }
    }
    for (j, &d) in red.diag.iter().enumerate() {
        vals[d] = vals[d].abs() + off[j] + 1e3;
    }
    (red, vals)
}

/// Two closed meshes side by side in one mesh: a pattern with two components.
fn two_spheres() -> TriMesh {
    let a = icosphere(2, 0.5).unwrap();
    let b = torus(12, 8, 0.5, 0.2).unwrap();
    let mut positions = a.positions().to_vec();
    let offset = positions.len();
    positions.extend(
        b.positions()
            .iter()
            .map(|p| p + Vector3::new(3.0, 0.0, 0.0)),
    );
    let mut triangles = a.triangles().to_vec();
    triangles.extend(b.triangles().iter().map(|t| t.map(|v| v + offset)));
    renumber(
        &TriMesh::new(positions, triangles).unwrap(),
        &random_permutation(offset + b.n_vertices(), 11),
    )
    .unwrap()
}

/// A closed cylinder whose caps are fans around a centre vertex (as CAD exports write them): `ring`
/// vertices around, `rows` rings, so the caps' centres neighbour `ring` vertices each and the side's
/// triangles are long and thin; numbered at random. With `rows = 1` and no side, a bipyramid.
fn fan_capped_cylinder(ring: usize, rows: usize) -> TriMesh {
    let mut x = Vec::new();
    for r in 0..rows {
        for k in 0..ring {
            let a = std::f64::consts::TAU * k as f64 / ring as f64;
            x.push(Vector3::new(a.cos(), a.sin(), 0.5 * r as f64));
        }
    }
    let (bottom, top) = (x.len(), x.len() + 1);
    x.push(Vector3::new(0.0, 0.0, -0.3));
    x.push(Vector3::new(0.0, 0.0, 0.5 * (rows - 1) as f64 + 0.3));
    let at = |r: usize, k: usize| r * ring + k % ring;
    let mut t = Vec::new();
    for k in 0..ring {
        t.push([bottom, at(0, k + 1), at(0, k)]);
        t.push([top, at(rows - 1, k), at(rows - 1, k + 1)]);
        for r in 0..rows - 1 {
            t.push([at(r, k), at(r, k + 1), at(r + 1, k + 1)]);
            t.push([at(r, k), at(r + 1, k + 1), at(r + 1, k)]);
        }
    }
    let n = x.len();
    renumber(&TriMesh::new(x, t).unwrap(), &random_permutation(n, 5)).unwrap()
}

/// A disk made of one fan: a centre vertex and `ring` boundary vertices.
fn fan_disk(ring: usize) -> TriMesh {
    let mut x: Vec<_> = (0..ring)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / ring as f64;
            Vector3::new(a.cos(), a.sin(), 0.0)
        })
        .collect();
    x.push(Vector3::zeros());
    let t = (0..ring).map(|k| [ring, k, (k + 1) % ring]).collect();
    TriMesh::new(x, t).unwrap()
}

fn meshes() -> Vec<(&'static str, TriMesh)> {
    let sphere = icosphere(3, 0.5).unwrap();
    let n = sphere.n_vertices();
    vec![
        // Fans around one vertex put most of a set at one breadth-first level: these hung the
        // dissection before it kept its cut above the deepest level.
        ("fan disk", fan_disk(200)),
        ("bipyramid", fan_capped_cylinder(150, 1)),
        ("cylinder with fan caps", fan_capped_cylinder(100, 4)),
        (
            "icosphere, random numbering",
            renumber(&sphere, &random_permutation(n, 3)).unwrap(),
        ),
        ("torus", torus(24, 12, 0.5, 0.2).unwrap()),
        (
            "sheet with a boundary",
            grid(20, 14, 1.0, 0.7, Diagonal::Alternating).unwrap(),
        ),
        ("sliver sheet", sliver_sheet(12, 5).unwrap()),
        ("two components", two_spheres()),
        (
            "one triangle",
            TriMesh::new(
                vec![Vector3::zeros(), Vector3::x(), Vector3::y()],
                vec![[0, 1, 2]],
            )
            .unwrap(),
        ),
    ]
}

fn assert_permutation(order: &[usize], n: usize, what: &str) {
    assert_eq!(order.len(), n, "{what}");
    let mut seen = vec![false; n];
    for &i in order {
        assert!(i < n && !seen[i], "{what}: {i} out of range or repeated");
        seen[i] = true;
    }
}

/// Every vertex's three unknowns stay together and consecutive (the dissection is of the mesh graph).
#[test]
fn nested_dissection_orders_every_unknown_once_and_keeps_vertices_together() {
    for (what, mesh) in meshes() {
        let (red, _) = system_of(&mesh);
        let order = nested_dissection(&red.csc).unwrap();
        assert_permutation(&order, red.csc.n, what);
        for chunk in order.chunks(3) {
            assert_eq!(chunk[0] % 3, 0, "{what}");
            assert_eq!(chunk, [chunk[0], chunk[0] + 1, chunk[0] + 2], "{what}");
        }
    }
}

/// Patterns that are not vertex-blocked: a dimension that is not a multiple of 3, a diagonal matrix (every
/// unknown its own component), a star, random trees, a complete graph, the empty matrix, a long chain (deep
/// dissection).
#[test]
fn nested_dissection_orders_scalar_patterns() {
    let chain = |n: usize| LowerCsc {
        n,
        col_ptr: (0..=n).map(|j| (2 * j).min(2 * n - 1)).collect(),
        row_idx: (0..n)
            .flat_map(|j| if j + 1 < n { vec![j, j + 1] } else { vec![j] })
            .collect(),
    };
    for n in [1, 2, 5, 1000, 3001] {
        let p = chain(n);
        assert_permutation(&nested_dissection(&p).unwrap(), n, "chain");
    }
    // A star: one unknown coupled to all others (a set whose breadth-first levels from a leaf are 1, 1 and
    // all the rest).
    let star = |n: usize| LowerCsc {
        n,
        col_ptr: std::iter::once(0).chain(n..=2 * n - 1).collect(),
        row_idx: (0..n).chain(1..n).collect(),
    };
    for n in [3, 66, 1000] {
        let p = star(n);
        assert_permutation(&nested_dissection(&p).unwrap(), n, "star");
    }
    // Random trees (every vertex's parent drawn among the earlier ones: wide, shallow levels) and a
    // complete graph (one level below any start).
    let lower_of = |n: usize, edges: &[(usize, usize)]| {
        let mut cols = vec![Vec::new(); n];
        for j in 0..n {
            cols[j].push(j);
        }
        for &(a, b) in edges {
            cols[a.min(b)].push(a.max(b));
        }
        let mut col_ptr = vec![0];
        let mut row_idx = Vec::new();
        for mut c in cols {
            c.sort_unstable();
            row_idx.extend(c);
            col_ptr.push(row_idx.len());
        }
        LowerCsc {
            n,
            col_ptr,
            row_idx,
        }
    };
    for (n, seed) in [(500, 1), (5000, 2), (20_000, 3)] {
        let parents = random_permutation(n, seed);
        let edges: Vec<_> = (1..n).map(|i| (parents[i] % i, i)).collect();
        assert_permutation(
            &nested_dissection(&lower_of(n, &edges)).unwrap(),
            n,
            "random tree",
        );
    }
    let complete: Vec<_> = (0..200)
        .flat_map(|a| (a + 1..200).map(move |b| (a, b)))
        .collect();
    assert_permutation(
        &nested_dissection(&lower_of(200, &complete)).unwrap(),
        200,
        "complete graph",
    );
    // Every unknown its own component: 300 001 of them (found in one pass; splitting one component off
    // at a time took quadratic time).
    let diagonal = |n: usize| LowerCsc {
        n,
        col_ptr: (0..=n).collect(),
        row_idx: (0..n).collect(),
    };
    for n in [301, 300_001] {
        assert_permutation(&nested_dissection(&diagonal(n)).unwrap(), n, "diagonal");
    }
    let empty = LowerCsc {
        n: 0,
        col_ptr: vec![0],
        row_idx: vec![],
    };
    assert!(nested_dissection(&empty).unwrap().is_empty());
    // A chain of 3001 unknowns dissected by nested dissection factors with at most one fill entry per
    // column in any order of a path: check that the factor solves it.
    let p = chain(3001);
    let vals: Vec<f64> = (0..p.n)
        .flat_map(|j| {
            if j + 1 < p.n {
                vec![4.0, -1.0]
            } else {
                vec![4.0]
            }
        })
        .collect();
    let mut llt = FaerLlt::with_ordering(FillOrdering::NestedDissection);
    llt.analyze(&p).unwrap();
    llt.factor(&vals).unwrap();
    let b: Vec<f64> = (0..p.n).map(|i| (i as f64).sin()).collect();
    let mut x = b.clone();
    llt.solve(&mut x).unwrap();
    let mut ax = vec![0.0; p.n];
    p.mul(&vals, &x, &mut ax);
    assert!(rel_error(&ax, &b) < 1e-14, "{}", rel_error(&ax, &b));
}

#[test]
fn malformed_patterns_are_errors() {
    let bad = [
        LowerCsc {
            n: 3,
            col_ptr: vec![0, 1, 2],
            row_idx: vec![0, 1],
        },
        LowerCsc {
            n: 2,
            col_ptr: vec![0, 2, 1],
            row_idx: vec![0, 1],
        },
        LowerCsc {
            n: 2,
            col_ptr: vec![0, 1, 2],
            row_idx: vec![0, 7],
        },
    ];
    // Rows out of order, repeated, or above the diagonal (upper triangle).
    let more = [
        LowerCsc {
            n: 2,
            col_ptr: vec![0, 2, 3],
            row_idx: vec![1, 0, 1],
        },
        LowerCsc {
            n: 2,
            col_ptr: vec![0, 2, 3],
            row_idx: vec![0, 0, 1],
        },
        LowerCsc {
            n: 2,
            col_ptr: vec![0, 1, 3],
            row_idx: vec![0, 0, 1],
        },
    ];
    for p in &bad {
        assert!(
            matches!(nested_dissection(p), Err(LinearError::Usage(_))),
            "{p:?}"
        );
    }
    // Every backend refuses each at analysis, with a typed error instead of a panic inside faer or an
    // index out of range, and still analyzes a good pattern afterwards.
    let good = LowerCsc {
        n: 2,
        col_ptr: vec![0, 2, 3],
        row_idx: vec![0, 1, 1],
    };
    for p in bad.iter().chain(&more) {
        // The message says what is wrong: the pointers, or the first column whose rows are.
        match p.check() {
            Err(e @ LinearError::Usage(_)) => {
                let m = e.to_string();
                assert!(m.contains("column pointers") || m.contains(": row "), "{m}");
                println!("{m}");
            }
            other => panic!("{p:?}: {other:?}"),
        }
        let backends: [Box<dyn LinearSolver>; 6] = [
            Box::new(FaerLlt::default()),
            Box::new(FaerLlt::with_ordering(FillOrdering::Amd)),
            Box::new(FaerLu::default()),
            Box::new(PcgJacobi::new(1e-12, 100)),
            Box::new(ChebyshevJacobi::new(1e-12, 100)),
            Box::new(Dense::default()),
        ];
        for mut s in backends {
            assert!(
                matches!(s.analyze(p), Err(LinearError::Usage(_))),
                "{}: {p:?}",
                s.name()
            );
            s.analyze(&good).unwrap();
            s.factor(&[2.0, -1.0, 2.0]).unwrap();
            let mut x = vec![1.0, 1.0];
            s.solve(&mut x).unwrap();
            assert!(
                (x[0] - 1.0).abs() < 1e-10 && (x[1] - 1.0).abs() < 1e-10,
                "{}: {x:?}",
                s.name()
            );
        }
    }
    good.check().unwrap();
}

/// On a closed shell of `shell-drop`'s size nested dissection leaves less fill than AMD, on the drape's
/// 31×31 sheet more; `Auto` keeps the smaller factor on each, and says which.
#[test]
fn auto_keeps_the_ordering_with_the_smaller_factor() {
    let shell = renumber(&icosphere(4, 0.5).unwrap(), &random_permutation(2562, 7)).unwrap();
    let sheet = grid(30, 30, 1.0, 1.0, Diagonal::Alternating).unwrap();
    for (what, mesh, expect) in [
        ("shell", &shell, FillOrdering::NestedDissection),
        ("sheet", &sheet, FillOrdering::Amd),
    ] {
        let (red, _) = system_of(mesh);
        let entries = |o: FillOrdering| {
            let mut llt = FaerLlt::with_ordering(o);
            llt.analyze(&red.csc).unwrap();
            (llt.factor_entries().unwrap(), llt.ordering_used().unwrap())
        };
        let (amd, used_amd) = entries(FillOrdering::Amd);
        let (nd, used_nd) = entries(FillOrdering::NestedDissection);
        let (auto, used) = entries(FillOrdering::Auto);
        println!(
            "{what}: factor entries AMD {amd}, nested dissection {nd}, auto {auto} ({used:?})"
        );
        assert_eq!(
            (used_amd, used_nd),
            (FillOrdering::Amd, FillOrdering::NestedDissection)
        );
        assert_eq!(used, expect, "{what}");
        assert_eq!(auto, amd.min(nd), "{what}");
        if expect == FillOrdering::NestedDissection {
            // Not a marginal win: at least 10 % fewer entries on the closed shell.
            assert!(10 * nd <= 9 * amd, "{what}: {nd} vs {amd}");
        }
    }
    assert_eq!(FaerLlt::default().ordering_used(), None);
}

/// Every ordering solves the same systems: against a dense factorization on small meshes, by the
/// residual on each kind of mesh.
#[test]
fn every_ordering_solves_the_systems() {
    let mut rng = SplitMix64(23);
    for (what, mesh) in meshes() {
        let (red, vals) = system_of(&mesh);
        let n = red.csc.n;
        let b: Vec<f64> = (0..n).map(|_| rng.symmetric()).collect();
        let reference = (n <= 2000).then(|| {
            let mut dense = Dense::default();
            dense.analyze(&red.csc).unwrap();
            dense
                .factor(&vals)
                .unwrap_or_else(|e| panic!("{what}, dense: {e}"));
            let mut r = b.clone();
            dense.solve(&mut r).unwrap();
            r
        });
        for o in [
            FillOrdering::Auto,
            FillOrdering::Amd,
            FillOrdering::NestedDissection,
        ] {
            let mut llt = FaerLlt::with_ordering(o);
            llt.analyze(&red.csc).unwrap();
            llt.factor(&vals)
                .unwrap_or_else(|e| panic!("{what}, {o:?}: {e}"));
            let mut x = b.clone();
            llt.solve(&mut x).unwrap();
            let mut ax = vec![0.0; n];
            red.csc.mul(&vals, &x, &mut ax);
            assert!(
                rel_error(&ax, &b) < 1e-12,
                "{what}, {o:?}: residual {}",
                rel_error(&ax, &b)
            );
            if let Some(r) = &reference {
                assert!(
                    rel_error(&x, r) < 1e-10,
                    "{what}, {o:?}: {}",
                    rel_error(&x, r)
                );
            }
        }
    }
}

/// The dissection does not depend on the thread count (it runs on the calling thread; this checks that
/// nothing in it reads the pool).
#[test]
fn nested_dissection_is_the_same_on_any_thread_count() {
    let (red, _) = system_of(&two_spheres());
    let one = on_threads(1, || nested_dissection(&red.csc).unwrap());
    let three = on_threads(3, || nested_dissection(&red.csc).unwrap());
    assert_eq!(one, three);
}

#[test]
fn ordering_names_round_trip() {
    for o in [
        FillOrdering::Auto,
        FillOrdering::Amd,
        FillOrdering::NestedDissection,
    ] {
        assert_eq!(FillOrdering::from_name(o.name()), Some(o));
    }
    assert_eq!(FillOrdering::from_name("metis"), None);
}
