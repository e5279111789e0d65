//! Mesh validation, topology construction and OBJ input/output.

use hinge_core::grid::{Diagonal, grid, unit_grid};
use hinge_core::obj::{parse_obj, read_obj, write_obj};
use hinge_core::topology::NO_TRIANGLE;
use hinge_core::{MeshError, ObjError, Topology, TriMesh};
use nalgebra::Vector3;
use proptest::prelude::*;

fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

fn quad() -> Vec<Vector3<f64>> {
    vec![v(0., 0., 0.), v(1., 0., 0.), v(1., 1., 0.), v(0., 1., 0.)]
}

#[test]
fn grid_counts_and_hinge_labels() {
    for diagonal in [Diagonal::Forward, Diagonal::Backward, Diagonal::Alternating] {
        let (nx, ny) = (5, 3);
        let mesh = grid(nx, ny, 2.0, 1.0, diagonal).unwrap();
        assert_eq!(mesh.n_vertices(), (nx + 1) * (ny + 1));
        assert_eq!(mesh.n_triangles(), 2 * nx * ny);
        let topo = Topology::new(mesh.n_vertices(), mesh.triangles()).unwrap();
        let n_edges = nx * (ny + 1) + ny * (nx + 1) + nx * ny;
        assert_eq!(topo.edges().len(), n_edges);
        assert_eq!(topo.n_boundary_edges(), 2 * (nx + ny));
        assert_eq!(topo.hinges().len(), n_edges - 2 * (nx + ny));
        let tri = mesh.triangles();
        let bits = topo.orientation_bits();
        for (hid, h) in topo.hinges().iter().enumerate() {
            let [x0, x1, x2, x3] = h.vertices;
            assert!(
                x1 < x2,
                "T runs the edge from the smaller to the larger index"
            );
            // T = (x0, x1, x2) and T̃ = (x3, x2, x1) are cyclic rotations of the stored triangles.
            let is_rotation = |t: [usize; 3], w: [usize; 3]| {
                (0..3).any(|r| [t[r], t[(r + 1) % 3], t[(r + 2) % 3]] == w)
            };
            assert!(is_rotation(tri[h.triangles[0]], [x0, x1, x2]));
            assert!(is_rotation(tri[h.triangles[1]], [x3, x2, x1]));
            assert_eq!(topo.hinge_of_edge(h.edge), Some(hid));
            assert!(topo.is_interior(h.edge));
            // Exactly one of the two triangles has the orientation bit of this edge set: T.
            let bit = |t: usize| {
                let k = topo.triangle_edges()[t]
                    .iter()
                    .position(|&e| e == h.edge)
                    .unwrap();
                bits[t] >> k & 1 == 1
            };
            assert!(bit(h.triangles[0]));
            assert!(!bit(h.triangles[1]));
            // Flat grid: θ = 0.
            let x = h.vertices.map(|i| mesh.positions()[i]);
            assert_eq!(hinge_core::hinge::hinge_angle(&x).unwrap(), 0.0);
        }
        // Every triangle's edge k is opposite corner k.
        for (t, es) in topo.triangle_edges().iter().enumerate() {
            for k in 0..3 {
                let e = topo.edges()[es[k]];
                assert!(!e.vertices.contains(&tri[t][k]));
                let on_edge = e.triangles.contains(&t);
                assert!(on_edge);
            }
        }
        for e in topo.edges() {
            assert_eq!(e.is_interior(), e.triangles[1] != NO_TRIANGLE);
        }
    }
}

#[test]
fn one_and_two_triangle_meshes() {
    let one = TriMesh::new(quad()[..3].to_vec(), vec![[0, 1, 2]]).unwrap();
    let t1 = Topology::new(one.n_vertices(), one.triangles()).unwrap();
    assert_eq!((t1.edges().len(), t1.hinges().len()), (3, 0));
    let two = TriMesh::new(quad(), vec![[0, 1, 2], [0, 2, 3]]).unwrap();
    let t2 = Topology::new(two.n_vertices(), two.triangles()).unwrap();
    assert_eq!((t2.edges().len(), t2.hinges().len()), (5, 1));
    // Edge (0, 2) runs 0 → 2 in triangle 1 = (0, 2, 3), so T is triangle 1: x0 = 3, x3 = 1.
    assert_eq!(t2.hinges()[0].vertices, [3, 0, 2, 1]);
    assert_eq!(t2.hinges()[0].triangles, [1, 0]);
}

#[test]
fn each_validation_error_is_distinct_and_names_the_element() {
    assert_eq!(
        TriMesh::new(vec![], vec![]),
        Err(MeshError::Empty {
            vertices: 0,
            triangles: 0
        })
    );
    assert_eq!(
        TriMesh::new(quad(), vec![[0, 1, 2], [0, 2, 7]]),
        Err(MeshError::IndexOutOfRange {
            triangle: 1,
            corner: 2,
            index: 7,
            n_vertices: 4
        })
    );
    assert_eq!(
        TriMesh::new(quad(), vec![[0, 1, 2], [3, 2, 3]]),
        Err(MeshError::RepeatedVertex {
            triangle: 1,
            vertex: 3
        })
    );
    let mut p = quad();
    p[2].y = f64::NAN;
    assert!(matches!(
        TriMesh::new(p, vec![[0, 1, 2]]),
        Err(MeshError::NonFiniteCoordinate {
            vertex: 2,
            axis: 1,
            ..
        })
    ));
    let colinear = vec![v(0., 0., 0.), v(1., 0., 0.), v(2., 0., 0.), v(0., 1., 0.)];
    assert_eq!(
        TriMesh::new(colinear, vec![[0, 1, 3], [0, 1, 2]]),
        Err(MeshError::ZeroAreaTriangle {
            triangle: 1,
            vertices: [0, 1, 2]
        })
    );
    // Three triangles on edge (0, 1).
    let fan = vec![
        v(0., 0., 0.),
        v(1., 0., 0.),
        v(0.5, 1., 0.),
        v(0.5, -1., 0.),
        v(0.5, 0., 1.),
    ];
    let tris = vec![[0, 1, 2], [1, 0, 3], [0, 1, 4]];
    let m = TriMesh::new(fan, tris.clone()).unwrap();
    assert_eq!(
        Topology::new(m.n_vertices(), m.triangles()).unwrap_err(),
        MeshError::NonManifoldEdge {
            edge: [0, 1],
            count: 3,
            triangles: [0, 1, 2]
        }
    );
    // Second triangle flipped.
    let m = TriMesh::new(quad(), vec![[0, 1, 2], [0, 3, 2]]).unwrap();
    assert_eq!(
        Topology::new(m.n_vertices(), m.triangles()).unwrap_err(),
        MeshError::InconsistentOrientation {
            edge: [0, 2],
            triangles: [0, 1]
        }
    );
    let m = TriMesh::new(quad(), vec![[0, 1, 2], [1, 2, 0]]).unwrap();
    assert_eq!(
        Topology::new(m.n_vertices(), m.triangles()).unwrap_err(),
        MeshError::DuplicateTriangle { triangles: [0, 1] }
    );
    let rest = unit_grid(2).unwrap();
    assert_eq!(
        rest.with_positions(quad()),
        Err(MeshError::VertexCountMismatch {
            rest: 9,
            deformed: 4
        })
    );
    assert_eq!(
        TriMesh::from_flat(&[0.0; 7], &[[0, 1, 2]]),
        Err(MeshError::FlatLength { len: 7 })
    );
    // Messages name the element.
    let msg = MeshError::NonManifoldEdge {
        edge: [4, 9],
        count: 3,
        triangles: [1, 2, 3],
    }
    .to_string();
    assert!(
        msg.contains("(4, 9)") && msg.contains("3 triangles"),
        "{msg}"
    );
}

#[test]
fn obj_round_trip_keeps_vertex_order() {
    let mesh = grid(3, 2, 1.5, 1.0, Diagonal::Alternating).unwrap();
    let deformed = hinge_core::grid::wave(mesh.positions());
    let dir = hinge_tests::Scratch::new("tests-obj-round-trip");
    let path = dir.join("m.obj");
    write_obj(&path, &deformed, mesh.triangles()).unwrap();
    let back = read_obj(&path).unwrap();
    assert_eq!(
        back.positions(),
        &deformed[..],
        "bit-exact coordinates, same order"
    );
    assert_eq!(back.triangles(), mesh.triangles());
}

#[test]
fn obj_parser_forms_and_errors() {
    let text = "# c\no thing\nv 0 0 0\nv 1 0 0\nvt 0 0\nv 0 1 0 1.0\nvn 0 0 1\nf 1/1/1 2//1 -1\n";
    let m = parse_obj(text.as_bytes(), "t").unwrap();
    assert_eq!(m.triangles(), &[[0, 1, 2]]);
    let err = |s: &str| parse_obj(s.as_bytes(), "bad.obj").unwrap_err();
    assert!(matches!(
        err("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3 4\n"),
        ObjError::Parse { line: 5, .. }
    ));
    assert!(matches!(err("v 0 0\n"), ObjError::Parse { line: 1, .. }));
    assert!(matches!(err("v 0 0 x\n"), ObjError::Parse { line: 1, .. }));
    assert!(matches!(
        err("v 0 0 0\nf 0 1 1\n"),
        ObjError::Parse { line: 2, .. }
    ));
    assert!(matches!(
        err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"),
        ObjError::Mesh {
            source: MeshError::IndexOutOfRange { index: 8, .. },
            ..
        }
    ));
    let e = read_obj("/nonexistent/hinge.obj").unwrap_err();
    assert!(matches!(e, ObjError::Io { .. }));
    assert!(e.to_string().contains("/nonexistent/hinge.obj"));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Random index soup never panics the topology builder: it returns a topology or a typed error.
    #[test]
    fn topology_builder_never_panics(
        n_vertices in 0usize..12,
        tris in proptest::collection::vec([0usize..14, 0usize..14, 0usize..14], 0..20),
    ) {
        match Topology::new(n_vertices, &tris) {
            Ok(t) => {
                prop_assert!(t.hinges().len() <= t.edges().len());
                prop_assert_eq!(t.triangle_edges().len(), tris.len());
            }
            Err(e) => { let _ = e.to_string(); }
        }
    }

    /// Random coordinates (including non-finite and colinear ones) and indices never panic mesh
    /// construction, and whatever is accepted has a finite, non-degenerate hinge at every interior edge or a
    /// typed stencil error.
    #[test]
    fn mesh_builder_never_panics(
        coords in proptest::collection::vec(prop_oneof![
            4 => -2.0f64..2.0,
            1 => Just(0.0),
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(1e-300),
        ], 0..30),
        tris in proptest::collection::vec([0usize..10, 0usize..10, 0usize..10], 0..12),
    ) {
        let n = coords.len() / 3;
        let positions: Vec<_> = (0..n).map(|i| Vector3::new(coords[3*i], coords[3*i+1], coords[3*i+2])).collect();
        if let Ok(mesh) = TriMesh::new(positions, tris)
            && let Ok(topo) = Topology::new(mesh.n_vertices(), mesh.triangles()) {
                for h in topo.hinges() {
                    let x = h.vertices.map(|v| mesh.positions()[v]);
                    if let Ok(d) = hinge_core::hinge::hinge_angle_hessian(&x) {
                        prop_assert!(d.theta.is_finite());
                        prop_assert!(d.hessian.iter().all(|v| v.is_finite()));
                    }
                }
        }
    }
}

/// Generated meshes of absurd sizes are a typed error naming the counts, not a panic ("capacity overflow",
/// an overflowing `n - 1`) or an aborted process (an allocation of 240 GB): `hinge stats --n 100000` and
/// `--n 3037000500` did both before. Sizes just below a limit still build, with the counts the formulas
/// give.
#[test]
fn generated_meshes_too_large_to_build_are_typed_errors() {
    use hinge_core::grid::{Diagonal, MAX_GENERATED_VERTICES, grid};
    use hinge_core::shapes::{icosphere, irregular_sheet, sliver_sheet, torus};
    let too_large = |r: Result<TriMesh, MeshError>, vertices: u128| match r {
        Err(MeshError::TooLarge {
            vertices: v,
            reason,
            ..
        }) => {
            assert_eq!(v, u64::try_from(vertices).unwrap_or(u64::MAX), "{reason}");
            assert!(!reason.is_empty());
        }
        other => panic!("{vertices} vertices: {other:?}"),
    };
    let m = usize::MAX as u128;
    too_large(
        grid(100_000, 100_000, 1.0, 1.0, Diagonal::Forward),
        100_001 * 100_001,
    );
    too_large(
        grid(
            3_037_000_500,
            3_037_000_500,
            1.0,
            1.0,
            Diagonal::Alternating,
        ),
        3_037_000_501 * 3_037_000_501,
    );
    // (2⁶⁴)² overflows u128: the count saturates, still an error.
    too_large(
        grid(usize::MAX, usize::MAX, 1.0, 1.0, Diagonal::Forward),
        u128::MAX,
    );
    too_large(grid(usize::MAX - 1, 1, 1.0, 1.0, Diagonal::Forward), m * 2);
    too_large(icosphere(16, 1.0), 10 * 4u128.pow(16) + 2);
    assert!(matches!(
        icosphere(usize::MAX, 1.0),
        Err(MeshError::TooLarge { .. })
    ));
    too_large(torus(3, usize::MAX, 1.0, 0.3), 3 * m);
    too_large(irregular_sheet(2, usize::MAX, 1), 2 * m);
    assert!(matches!(
        torus(2, usize::MAX, 1.0, 0.3),
        Err(MeshError::Empty { .. })
    ));
    for n in [0, 1] {
        assert!(
            matches!(sliver_sheet(n, 1), Err(MeshError::Empty { .. })),
            "{n}"
        );
    }
    assert!(MAX_GENERATED_VERTICES == u32::MAX as u128);
    // A grid just past the 32-bit vertex range is refused; small generated meshes have the counts the
    // formulas give.
    too_large(
        grid(65_535, 65_536, 1.0, 1.0, Diagonal::Forward),
        65_536 * 65_537,
    );
    let ico = icosphere(3, 1.0).unwrap();
    assert_eq!(
        (ico.n_vertices(), ico.n_triangles()),
        (10 * 64 + 2, 20 * 64)
    );
    let t = torus(5, 4, 1.0, 0.3).unwrap();
    assert_eq!((t.n_vertices(), t.n_triangles()), (20, 40));
    let g = grid(3, 2, 1.0, 1.0, Diagonal::Alternating).unwrap();
    assert_eq!((g.n_vertices(), g.n_triangles()), (12, 12));
    let s = irregular_sheet(4, 3, 7).unwrap();
    assert_eq!((s.n_vertices(), s.n_triangles()), (12, 12));
}
