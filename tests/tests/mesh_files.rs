//! Mesh files: OBJ, OFF and PLY (ASCII, binary little and big endian) read back what was written, polygons
//! are fan-triangulated, and bad files are typed errors that name the file and count as the file does —
//! never a panic, whatever the bytes.

use std::io::Cursor;

use hinge_core::TriMesh;
use hinge_core::meshio::{
    MeshFileError, MeshFormat, PlyEncoding, read_mesh, read_mesh_from, write_mesh, write_off_to,
    write_ply_to,
};
use hinge_core::nalgebra::Vector3;
use hinge_core::shapes::{icosphere, irregular_sheet, random_permutation, renumber, torus};
use hinge_tests::Scratch;

fn meshes() -> Vec<(&'static str, TriMesh)> {
    let ico = icosphere(2, 0.7).unwrap();
    let perm = random_permutation(ico.n_vertices(), 11);
    vec![
        ("renumbered icosphere", renumber(&ico, &perm).unwrap()),
        ("torus", torus(12, 7, 1.0, 0.3).unwrap()),
        ("irregular sheet", irregular_sheet(9, 7, 5).unwrap()),
    ]
}

fn tmp(name: &str) -> Scratch {
    Scratch::new(&format!("tests-mesh-files-{name}"))
}

fn read(bytes: &[u8], format: MeshFormat) -> Result<hinge_core::meshio::MeshFile, MeshFileError> {
    read_mesh_from(Cursor::new(bytes), format, "test")
}

#[test]
fn every_format_reads_back_what_it_wrote_bitwise() {
    let dir = tmp("roundtrip");
    for (name, mesh) in meshes() {
        let (x, t) = (mesh.positions(), mesh.triangles());
        // Through files, by extension.
        for ext in ["obj", "off", "ply", "OFF", "Ply"] {
            let path = dir.join(format!("m.{ext}"));
            write_mesh(&path, x, t).unwrap();
            let back = read_mesh(&path).unwrap();
            assert_eq!(back.mesh.positions(), x, "{name} .{ext}");
            assert_eq!(back.mesh.triangles(), t, "{name} .{ext}");
            assert_eq!(back.polygons_split, 0);
        }
        // Every PLY encoding, and OFF, through readers.
        for enc in [
            PlyEncoding::Ascii,
            PlyEncoding::BinaryLittleEndian,
            PlyEncoding::BinaryBigEndian,
        ] {
            let mut bytes = Vec::new();
            write_ply_to(&mut bytes, x, t, enc).unwrap();
            let back = read(&bytes, MeshFormat::Ply).unwrap();
            assert_eq!(back.mesh.positions(), x, "{name} {enc:?}");
            assert_eq!(back.mesh.triangles(), t, "{name} {enc:?}");
        }
        let mut bytes = Vec::new();
        write_off_to(&mut bytes, x, t).unwrap();
        assert_eq!(read(&bytes, MeshFormat::Off).unwrap().mesh.positions(), x);
    }
}

#[test]
fn ply_type_spellings_extra_properties_and_elements() {
    // Both spellings of the types, properties hinge does not use, an element it does not know, vertex
    // indices as uint8 lists of uint32: read as the same mesh.
    let ascii = "ply\nformat ascii 1.0\ncomment a quad and a triangle\nelement vertex 5\n\
        property float32 x\nproperty float y\nproperty double z\nproperty uchar red\nproperty float32 confidence\n\
        element face 2\nproperty list uint8 uint32 vertex_indices\nproperty int flags\n\
        element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n\
        0 0 0 255 0.5\n1 0 0 0 0.5\n1 1 0 0 0.5\n0 1 0 0 0.5\n2 0.5 0.25 7 1\n\
        4 0 1 2 3 9\n3 1 4 2 0\n0 1\n";
    let m = read(ascii.as_bytes(), MeshFormat::Ply).unwrap();
    assert_eq!(m.mesh.n_vertices(), 5);
    assert_eq!(m.mesh.triangles(), &[[0, 1, 2], [0, 2, 3], [1, 4, 2]]);
    assert_eq!(m.polygons_split, 1);
    assert_eq!(m.face_of_triangle, [0, 0, 1]);
    assert_eq!(m.mesh.positions()[4], Vector3::new(2.0, 0.5, 0.25));
    // The same in binary big endian with float32 coordinates and an int16 list type.
    let mut bin = b"ply\nformat binary_big_endian 1.0\nelement vertex 5\nproperty float32 x\n\
        property float32 y\nproperty float32 z\nproperty uint8 alpha\nelement face 2\n\
        property list uchar int16 vertex_index\nend_header\n"
        .to_vec();
    for p in m.mesh.positions() {
        for c in [p.x, p.y, p.z] {
            bin.extend_from_slice(&(c as f32).to_be_bytes());
        }
        bin.push(200);
    }
    for face in [&[0i16, 1, 2, 3][..], &[1, 4, 2]] {
        bin.push(face.len() as u8);
        for &i in face {
            bin.extend_from_slice(&i.to_be_bytes());
        }
    }
    let b = read(&bin, MeshFormat::Ply).unwrap();
    assert_eq!(b.mesh.positions(), m.mesh.positions());
    assert_eq!(b.mesh.triangles(), m.mesh.triangles());
}

/// An OBJ file of `mesh` as other tools write them: a byte-order mark, CRLF line ends, objects, groups,
/// materials and smoothing groups, texture coordinates and normals on every corner, comments after
/// statements, negative (relative) indices on every third face and a face continued over two lines.
fn obj_as_tools_write_it(mesh: &TriMesh) -> String {
    let mut s = String::from("\u{feff}# exported\r\nmtllib cloth.mtl\r\no sheet\r\n");
    for (i, p) in mesh.positions().iter().enumerate() {
        s += &format!("v {:?} {:?} {:?} # vertex {}\r\n", p.x, p.y, p.z, i + 1);
        s += &format!("vt {} 0.5\r\nvn 0 0 1\r\n", i as f64 / 100.0);
    }
    s += "g cloth\r\nusemtl fabric\r\ns 1\r\n";
    let n = mesh.n_vertices() as i64;
    for (k, t) in mesh.triangles().iter().enumerate() {
        let idx = |v: usize| {
            let i = v as i64 + 1;
            if k % 3 == 2 { i - n - 1 } else { i }
        };
        let c: Vec<String> = t
            .iter()
            .map(|&v| format!("{}/{}/{}", idx(v), idx(v), idx(v)))
            .collect();
        if k % 5 == 1 {
            s += &format!("f {} {} \\\r\n  {}\r\n", c[0], c[1], c[2]);
        } else {
            s += &format!("f {} {} {} # face {}\r\n", c[0], c[1], c[2], k + 1);
        }
    }
    s
}

#[test]
fn obj_files_as_other_tools_write_them_read_as_the_same_mesh() {
    for (name, mesh) in meshes() {
        let text = obj_as_tools_write_it(&mesh);
        let back = read(text.as_bytes(), MeshFormat::Obj).unwrap();
        assert_eq!(back.mesh.positions(), mesh.positions(), "{name}");
        assert_eq!(back.mesh.triangles(), mesh.triangles(), "{name}");
        // Before the byte-order mark was dropped, the first vertex was skipped as an unknown statement and
        // every face named the wrong vertices.
        assert!(text.starts_with('\u{feff}'));
    }
    // An error after a continued face names the physical line it is on, and the face by its number.
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n 3\nf 1 3 7 # broken\n";
    let e = message(obj.as_bytes(), MeshFormat::Obj);
    assert!(
        e.contains("face 2 (line 6)") && e.contains("vertex 7"),
        "{e}"
    );
    // A continuation on the last line ends the file's last statement.
    let m = read(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 \\", MeshFormat::Obj).unwrap();
    assert_eq!(m.mesh.triangles(), &[[0, 1, 2]]);
    // OFF with a byte-order mark and CRLF.
    let off = "\u{feff}OFF\r\n3 1 0\r\n0 0 0\r\n1 0 0\r\n0 1 0\r\n3 0 1 2\r\n";
    let m = read(off.as_bytes(), MeshFormat::Off).unwrap();
    assert_eq!(m.mesh.triangles(), &[[0, 1, 2]]);
}

/// `sheet` cut along its middle as an exporter splits vertices along a UV seam: the faces right of x = 0.5
/// get copies (numbered after the others) of the vertices they share with the faces on the left. Returns
/// the cut mesh and the (copy, original) pairs.
fn seam_cut(sheet: &TriMesh) -> (TriMesh, Vec<(usize, usize)>) {
    let x = sheet.positions();
    let right = |t: &[usize; 3]| t.iter().map(|&v| x[v].x).sum::<f64>() / 3.0 > 0.5;
    let mut on_left = vec![false; x.len()];
    for t in sheet.triangles().iter().filter(|t| !right(t)) {
        t.iter().for_each(|&v| on_left[v] = true);
    }
    let mut positions = x.to_vec();
    let mut copy = vec![usize::MAX; x.len()];
    let mut pairs = Vec::new();
    let mut triangles = Vec::new();
    for t in sheet.triangles() {
        if !right(t) {
            triangles.push(*t);
            continue;
        }
        triangles.push(t.map(|v| {
            if !on_left[v] {
                return v;
            }
            if copy[v] == usize::MAX {
                copy[v] = positions.len();
                pairs.push((positions.len(), v));
                positions.push(x[v]);
            }
            copy[v]
        }));
    }
    (TriMesh::new(positions, triangles).unwrap(), pairs)
}

#[test]
fn vertices_split_along_a_seam_are_found() {
    let sheet = irregular_sheet(9, 8, 4).unwrap();
    assert!(sheet.coincident_vertices().is_empty());
    let (cut, pairs) = seam_cut(&sheet);
    assert!(pairs.len() >= 8, "a seam across the sheet: {}", pairs.len());
    assert_eq!(cut.coincident_vertices(), pairs);
    // Through an OBJ file: the same pairs (the written digits round-trip).
    let mut bytes = Vec::new();
    hinge_core::obj::write_obj_to(&mut bytes, cut.positions(), cut.triangles()).unwrap();
    assert_eq!(
        read(&bytes, MeshFormat::Obj)
            .unwrap()
            .mesh
            .coincident_vertices(),
        pairs
    );
    // Renumbered at random: the pairs follow the numbering, each copy paired with the lowest of its group.
    let perm = random_permutation(cut.n_vertices(), 5);
    let renumbered = renumber(&cut, &perm).unwrap();
    let mut expected: Vec<(usize, usize)> = pairs
        .iter()
        .map(|&(a, b)| {
            let (a, b) = (perm[a], perm[b]);
            (a.max(b), a.min(b))
        })
        .collect();
    expected.sort_unstable();
    assert_eq!(renumbered.coincident_vertices(), expected);
    // -0.0 and +0.0 are one position; a vertex in no face does not count; a closed mesh has none.
    let m = TriMesh::new(
        vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(-0.0, 0.0, -0.0),
            Vector3::new(1.0, 0.0, 0.0),
        ],
        vec![[0, 1, 2], [3, 2, 1]],
    )
    .unwrap();
    assert_eq!(m.coincident_vertices(), vec![(3, 0)]);
    assert!(icosphere(3, 1.0).unwrap().coincident_vertices().is_empty());
    assert!(
        torus(16, 9, 1.0, 0.3)
            .unwrap()
            .coincident_vertices()
            .is_empty()
    );
}

/// `mesh` with its positions rounded to f32 (what STL stores).
fn single_precision(mesh: &TriMesh) -> TriMesh {
    let x = mesh
        .positions()
        .iter()
        .map(|p| p.map(|c| f64::from(c as f32)))
        .collect();
    TriMesh::new(x, mesh.triangles().to_vec()).unwrap()
}

/// `mesh` as an ASCII STL as CAD tools write it: upper-case keywords on some lines, CRLF, two solids, normals.
fn ascii_stl(mesh: &TriMesh) -> String {
    let x = mesh.positions();
    let half = mesh.n_triangles() / 2;
    let mut s = String::from("solid part_one\r\n");
    for (k, t) in mesh.triangles().iter().enumerate() {
        if k == half {
            s += "endsolid part_one\r\nsolid part_two\r\n";
        }
        let (facet, vertex) = if k % 2 == 0 {
            ("facet normal", "vertex")
        } else {
            ("FACET NORMAL", "VERTEX")
        };
        s += &format!("  {facet} 0 0 1\r\n    outer loop\r\n");
        for &v in t {
            s += &format!("      {vertex} {:?} {:?} {:?}\r\n", x[v].x, x[v].y, x[v].z);
        }
        s += "    endloop\r\n  endfacet\r\n";
    }
    s + "endsolid part_two\r\n"
}

/// The mesh an STL of `mesh` reads back as: the vertices welded in order of first appearance.
fn welded(mesh: &TriMesh) -> TriMesh {
    let mut number = vec![usize::MAX; mesh.n_vertices()];
    let mut positions = Vec::new();
    let triangles = mesh
        .triangles()
        .iter()
        .map(|t| {
            t.map(|v| {
                if number[v] == usize::MAX {
                    number[v] = positions.len();
                    positions.push(mesh.positions()[v]);
                }
                number[v]
            })
        })
        .collect();
    TriMesh::new(positions, triangles).unwrap()
}

#[test]
fn stl_files_binary_and_ascii_weld_their_corners() {
    let dir = tmp("stl");
    for (name, mesh) in meshes() {
        let mesh = single_precision(&mesh);
        let expected = welded(&mesh);
        // Binary, through a file (by extension), and ASCII: the same mesh, bitwise.
        let path = dir.join("m.STL");
        write_mesh(&path, mesh.positions(), mesh.triangles()).unwrap();
        let binary = read_mesh(&path).unwrap();
        assert_eq!(binary.format, MeshFormat::Stl);
        assert_eq!(binary.mesh.positions(), expected.positions(), "{name}");
        assert_eq!(binary.mesh.triangles(), expected.triangles(), "{name}");
        assert_eq!(
            binary.mesh.n_vertices(),
            mesh.n_vertices(),
            "{name}: every vertex welded once"
        );
        assert!(binary.topology().is_ok(), "{name}");
        let ascii = read(ascii_stl(&mesh).as_bytes(), MeshFormat::Stl).unwrap();
        assert_eq!(ascii.mesh.positions(), expected.positions(), "{name}");
        assert_eq!(ascii.mesh.triangles(), expected.triangles(), "{name}");
    }
    // A binary STL whose header starts with `solid` (as many exporters write it) is binary by its size.
    let mesh = single_precision(&irregular_sheet(4, 3, 2).unwrap());
    let mut bytes = Vec::new();
    hinge_core::meshio::write_stl_to(&mut bytes, mesh.positions(), mesh.triangles()).unwrap();
    bytes[..5].copy_from_slice(b"solid");
    let m = read(&bytes, MeshFormat::Stl).unwrap();
    assert_eq!(m.mesh.triangles(), welded(&mesh).triangles());
    // Truncated binary: the sizes, one line.
    let e = message(&bytes[..bytes.len() - 7], MeshFormat::Stl);
    assert!(e.contains("(truncated?)") && e.contains("STL"), "{e}");
}

#[test]
fn stl_errors_name_facets_and_lines() {
    let facet = |a: &str, b: &str, c: &str| {
        format!(
            "facet normal 0 0 1\nouter loop\nvertex {a}\nvertex {b}\nvertex {c}\nendloop\nendfacet\n"
        )
    };
    // A facet with two corners at one position: its welded vertex twice.
    let text = format!(
        "solid t\n{}{}endsolid t\n",
        facet("0 0 0", "1 0 0", "0 1 0"),
        facet("1 0 0", "1 1 0", "1 0 0")
    );
    let e = message(text.as_bytes(), MeshFormat::Stl);
    assert!(
        e.contains("facet 2 (line 9) names vertex 2 more than once")
            && e.contains("STL numbering: from 1"),
        "{e}"
    );
    // A zero-area facet (common in CAD tessellations) names its vertices by where they first appear.
    let text = format!(
        "solid t\n{}{}endsolid t\n",
        facet("0 0 0", "1 0 0", "0 1 0"),
        facet("1 0 0", "2 0 0", "3 0 0")
    );
    let e = message(text.as_bytes(), MeshFormat::Stl);
    assert!(e.contains("facet 2 (line 9) has zero area"), "{e}");
    // A non-finite coordinate: the vertex by its facet and line.
    let text = format!(
        "solid t\n{}endsolid t\n",
        facet("0 0 0", "1 nan 0", "0 1 0")
    );
    let e = message(text.as_bytes(), MeshFormat::Stl);
    assert!(
        e.contains("vertex 2 (first in facet 1, line 5): coordinate y"),
        "{e}"
    );
    // Syntax: a bad coordinate, a facet of two vertices, an unknown keyword, a missing endfacet.
    for (text, expected) in [
        (
            "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 x\n",
            "line 4: cannot parse coordinate `x`",
        ),
        (
            "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\n",
            "line 2: the facet has 2 vertices",
        ),
        (
            "solid t\nfacet normal 0 0 1\nouterloop\n",
            "line 3: unknown keyword `outerloop`",
        ),
        (
            "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n",
            "line 2: the facet has no `endfacet`",
        ),
        (
            "solid t\nvertex 0 0 0\n",
            "line 2: `vertex` outside a facet",
        ),
    ] {
        let e = message(text.as_bytes(), MeshFormat::Stl);
        assert!(e.contains(expected), "{e}");
    }
    // Neither kind.
    let e = message(b"hello", MeshFormat::Stl);
    assert!(e.contains("neither an ASCII STL"), "{e}");
}

#[test]
fn polygons_are_fan_triangulated_in_every_format() {
    // A 2×1 quad strip and a pentagon: 1 + 1 + 3 … every polygon fanned from its first corner.
    let obj = "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 2 1 0\nv 1 1 0\nv 0 1 0\nv 1 2 0\nv 0 2 0\n\
        f 1 2 5 6\nf 2 3 4 5\nf 6 5 7 8\n";
    let off = "OFF\n# a comment\n8 3 0\n0 0 0\n1 0 0\n2 0 0\n2 1 0\n1 1 0\n0 1 0\n1 2 0\n0 2 0\n\
        4 0 1 4 5\n4 1 2 3 4 255 0 0\n4 5 4 6 7\n";
    let ply = "ply\nformat ascii 1.0\nelement vertex 8\nproperty double x\nproperty double y\n\
        property double z\nelement face 3\nproperty list uchar int vertex_indices\nend_header\n\
        0 0 0\n1 0 0\n2 0 0\n2 1 0\n1 1 0\n0 1 0\n1 2 0\n0 2 0\n4 0 1 4 5\n4 1 2 3 4\n4 5 4 6 7\n";
    let expect = [
        [0, 1, 4],
        [0, 4, 5],
        [1, 2, 3],
        [1, 3, 4],
        [5, 4, 6],
        [5, 6, 7],
    ];
    for (text, format) in [
        (obj, MeshFormat::Obj),
        (off, MeshFormat::Off),
        (ply, MeshFormat::Ply),
    ] {
        let m = read(text.as_bytes(), format).unwrap();
        assert_eq!(m.mesh.triangles(), &expect, "{format:?}");
        assert_eq!(m.polygons_split, 3);
        assert_eq!(m.face_of_triangle, [0, 0, 1, 1, 2, 2]);
    }
}

fn message(bytes: &[u8], format: MeshFormat) -> String {
    let e = read(bytes, format).unwrap_err().to_string();
    assert!(!e.contains('\n'), "one line: {e}");
    assert!(e.starts_with("test: "), "names the file: {e}");
    e
}

#[test]
fn mesh_errors_count_as_the_file_does() {
    // A face naming the 9th vertex of 4 (OBJ counts from 1, OFF and PLY from 0).
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n# faces\nf 1 2 3\nf 2 4 9\n";
    let e = message(obj.as_bytes(), MeshFormat::Obj);
    assert!(
        e.contains("face 2 (line 7)") && e.contains("vertex 9") && e.contains("4 vertices"),
        "{e}"
    );
    assert!(e.contains("OBJ numbering: from 1"), "{e}");
    let off = "OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 8\n";
    let e = message(off.as_bytes(), MeshFormat::Off);
    assert!(
        e.contains("face 1 (line 8)") && e.contains("vertex 8") && e.contains("from 0"),
        "{e}"
    );
    let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
        property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n\
        0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 8\n";
    let e = message(ply.as_bytes(), MeshFormat::Ply);
    assert!(
        e.contains("face 1 names vertex 8") && e.contains("PLY numbering: from 0"),
        "{e}"
    );
    // Coordinates that are missing or not numbers, in the three text formats (one reader of x, y, z).
    for (bytes, format, expected) in [
        (
            &b"v 0 0 0\nv 1 x 0\nv 0 1 0\nf 1 2 3\n"[..],
            MeshFormat::Obj,
            "line 2: cannot parse coordinate `x`",
        ),
        (
            b"v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n",
            MeshFormat::Obj,
            "line 2: vertex has fewer than 3 coordinates (missing z)",
        ),
        (
            b"OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n",
            MeshFormat::Off,
            "line 4: vertex 1 (0-based) has fewer than 3 coordinates (missing z)",
        ),
        (
            b"OFF\n3 1 0\n0 0 0\n1 q 0\n0 1 0\n3 0 1 2\n",
            MeshFormat::Off,
            "line 4: vertex 1 (0-based): cannot parse coordinate `q`",
        ),
        (
            b"solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n",
            MeshFormat::Stl,
            "line 4: vertex has fewer than 3 coordinates (missing z)",
        ),
    ] {
        let e = message(bytes, format);
        assert!(e.contains(expected), "{e}");
    }
    // A non-finite coordinate names the vertex and its line; a repeated vertex names the face.
    let e = message(b"v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n", MeshFormat::Obj);
    assert!(
        e.contains("vertex 2 (line 2)") && e.contains("coordinate y"),
        "{e}"
    );
    let e = message(
        b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 1\n",
        MeshFormat::Off,
    );
    assert!(
        e.contains("face 0") && e.contains("vertex 1 more than once"),
        "{e}"
    );
    // A fanned polygon is named by its own number.
    let e = message(
        b"OFF\n4 1 0\n0 0 0\n1 0 0\n2 0 0\n1 1 0\n4 0 1 2 3\n",
        MeshFormat::Off,
    );
    assert!(e.contains("face 0 (line 7) has zero area"), "{e}");
    // A zero-area triangle.
    let e = message(b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", MeshFormat::Obj);
    assert!(e.contains("face 1 (line 4) has zero area"), "{e}");
    // A triangle whose area overflows is too large, not flat (it used to be reported as colinear); one
    // of 1e70 is still fine.
    let big = |s: &str| format!("v 0 0 0\nv {s} 0 0\nv 0 {s} 0\nv {s} {s} 1\nf 1 2 3\nf 2 4 3\n");
    let e = message(big("1e200").as_bytes(), MeshFormat::Obj);
    assert!(
        e.contains("face 1 (line 5) is too large: its area overflows f64")
            && !e.contains("zero area"),
        "{e}"
    );
    let m = read(big("1e70").as_bytes(), MeshFormat::Obj).unwrap();
    assert!(m.topology().is_ok());
}

/// `MeshFile::topology`'s one-line error, checked to name the file and the format's numbering.
fn topology_message(bytes: &[u8], format: MeshFormat) -> String {
    let file = read(bytes, format).unwrap();
    let e = file.topology().unwrap_err();
    let MeshFileError::Mesh {
        ref message,
        ref source,
        ..
    } = e
    else {
        panic!("not a mesh error: {e}");
    };
    assert_eq!(*message, file.describe(source));
    let e = e.to_string();
    assert!(!e.contains('\n'), "one line: {e}");
    assert!(e.starts_with("test: "), "names the file: {e}");
    e
}

#[test]
fn topology_errors_count_as_the_file_does() {
    // An edge (vertices 2–3 in OBJ numbering) shared by three faces, after a comment line.
    let square = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\n# faces\n";
    let e = topology_message(
        format!("{square}f 1 2 3\nf 2 4 3\nf 2 3 5\n").as_bytes(),
        MeshFormat::Obj,
    );
    assert!(
        e.contains(
            "the edge between vertices 2 and 3 is shared by 3 triangles (of face 1 (line 7), face 2 \
             (line 8) and face 3 (line 9))"
        ) && e.ends_with("(OBJ numbering: from 1)"),
        "{e}"
    );
    // Opposite orientations across an edge, in OFF (from 0).
    let e = topology_message(
        b"OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 2 3\n",
        MeshFormat::Off,
    );
    assert!(
        e.contains(
            "face 0 (line 7) and face 1 (line 8) traverse the edge between vertices 1 and 2 in the same \
             direction"
        ) && e.ends_with("(OFF numbering: from 0)"),
        "{e}"
    );
    // A face given twice in a binary PLY (no lines to name): the faces by number. The second copy is the
    // first face's corners rotated, so the check does not depend on the corner a face starts at.
    let positions: Vec<Vector3<f64>> = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
    ]
    .iter()
    .map(|p| Vector3::new(p[0], p[1], p[2]))
    .collect();
    let mut bytes = Vec::new();
    write_ply_to(
        &mut bytes,
        &positions,
        &[[0, 1, 2], [1, 3, 2], [2, 0, 1]],
        PlyEncoding::BinaryLittleEndian,
    )
    .unwrap();
    let e = topology_message(&bytes, MeshFormat::Ply);
    assert!(
        e.contains("face 0 and face 2 have the same three vertices")
            && e.ends_with("(PLY numbering: from 0)"),
        "{e}"
    );
    // A fanned polygon is named by its own face: the quad 1 2 4 3 fans into (1 2 4) and (1 4 3); the
    // triangle 4 3 1 repeats the second.
    let e = topology_message(
        format!("{square}f 1 2 4 3\nf 4 3 1\n").as_bytes(),
        MeshFormat::Obj,
    );
    assert!(
        e.contains("face 1 (line 7) and face 2 (line 8) have the same three vertices"),
        "{e}"
    );
    // Valid meshes: the same topology as the library builds from the mesh.
    for (name, mesh) in meshes() {
        let mut bytes = Vec::new();
        write_off_to(&mut bytes, mesh.positions(), mesh.triangles()).unwrap();
        let file = read(&bytes, MeshFormat::Off).unwrap();
        let topology = file.topology().unwrap();
        let direct = hinge_core::Topology::new(mesh.n_vertices(), mesh.triangles()).unwrap();
        assert_eq!(topology.hinges(), direct.hinges(), "{name}");
    }
}

#[test]
fn files_that_do_not_match_their_extension_are_errors_naming_the_format() {
    // OBJ with no `v`/`f` records; an OFF with another header; a PNG under each extension.
    let e = message(b"# nothing here\nmtllib x.mtl\n", MeshFormat::Obj);
    assert!(e.contains("read as OBJ") && e.contains("0 vertices"), "{e}");
    let e = message(b"OFF\n0 0 0\n", MeshFormat::Off);
    assert!(e.contains("read as OFF"), "{e}");
    let e = message(b"PLY\n3 1 0\n", MeshFormat::Off);
    assert!(
        e.contains("not a valid OFF file") && e.contains("not `OFF`"),
        "{e}"
    );
    let png = b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\x01\x90\0\0\x01\x2c\x08\x02\0\0\0";
    for (format, words) in [
        (MeshFormat::Obj, "not a valid OBJ file"),
        (MeshFormat::Off, "not a valid OFF file"),
        (MeshFormat::Ply, "not a valid PLY file"),
    ] {
        let e = message(png, format);
        assert!(e.contains(words), "{e}");
    }
    // Unknown extension, missing file: named.
    let dir = tmp("ext");
    let p = dir.join("picture.png");
    std::fs::write(&p, png).unwrap();
    let e = read_mesh(&p).unwrap_err().to_string();
    assert!(
        e.contains("picture.png") && e.contains("unknown mesh file extension"),
        "{e}"
    );
    let e = read_mesh(dir.join("missing.off")).unwrap_err().to_string();
    assert!(e.contains("missing.off"), "{e}");
    // An OFF that announces more than it has: no huge allocation, the missing vertex is named.
    let e = message(b"OFF\n4000000000 4000000000 0\n0 0 0\n", MeshFormat::Off);
    assert!(e.contains("ends after 1 of its 4000000000 vertices"), "{e}");
}

#[test]
fn a_truncated_binary_ply_is_an_error_at_every_length() {
    let mesh = irregular_sheet(4, 3, 2).unwrap();
    for enc in [
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        let mut bytes = Vec::new();
        write_ply_to(&mut bytes, mesh.positions(), mesh.triangles(), enc).unwrap();
        let header = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        for len in 0..bytes.len() {
            let r = read(&bytes[..len], MeshFormat::Ply);
            let e = r.expect_err("a truncated file must not read").to_string();
            assert!(!e.contains('\n'), "{e}");
            if len > header {
                assert!(
                    e.contains("truncated") || e.contains("ends before"),
                    "{len}: {e}"
                );
            }
        }
        assert!(read(&bytes, MeshFormat::Ply).is_ok());
    }
}

#[test]
fn random_bytes_never_panic() {
    // Seeded garbage, and valid files with bytes flipped: every reader returns (Ok or Err), never panics.
    let mut rng = hinge_core::grid::SplitMix64(99);
    let mesh = irregular_sheet(4, 4, 3).unwrap();
    let mut samples: Vec<(Vec<u8>, MeshFormat)> = Vec::new();
    let mut valid = Vec::new();
    write_ply_to(
        &mut valid,
        mesh.positions(),
        mesh.triangles(),
        PlyEncoding::BinaryLittleEndian,
    )
    .unwrap();
    let mut off = Vec::new();
    write_off_to(&mut off, mesh.positions(), mesh.triangles()).unwrap();
    let mut obj = Vec::new();
    hinge_core::obj::write_obj_to(&mut obj, mesh.positions(), mesh.triangles()).unwrap();
    let mut stl = Vec::new();
    hinge_core::meshio::write_stl_to(&mut stl, mesh.positions(), mesh.triangles()).unwrap();
    let stl_text = ascii_stl(&mesh).into_bytes();
    for _ in 0..300 {
        let len = (rng.next_u64() % 400) as usize;
        let bytes: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
        for f in [
            MeshFormat::Obj,
            MeshFormat::Off,
            MeshFormat::Ply,
            MeshFormat::Stl,
        ] {
            samples.push((bytes.clone(), f));
        }
        for (base, f) in [
            (&valid, MeshFormat::Ply),
            (&off, MeshFormat::Off),
            (&obj, MeshFormat::Obj),
            (&stl, MeshFormat::Stl),
            (&stl_text, MeshFormat::Stl),
        ] {
            let mut b = base.clone();
            for _ in 0..3 {
                let i = (rng.next_u64() as usize) % b.len();
                b[i] = rng.next_u64() as u8;
            }
            samples.push((b, f));
        }
    }
    let mut errors = 0;
    for (bytes, f) in &samples {
        // The topology of what was read, with its errors in the file's numbering, is part of reading.
        let read_all = || read(bytes, *f).map(|m| (m.topology().map_err(|e| e.to_string()), m));
        match std::panic::catch_unwind(read_all) {
            Ok(Ok((topology, m))) => {
                assert!(m.mesh.n_triangles() > 0);
                if let Err(e) = topology {
                    assert!(!e.contains('\n') && e.starts_with("test: "), "{e}");
                }
            }
            Ok(Err(e)) => {
                errors += 1;
                assert!(!e.to_string().contains('\n'), "{e}");
            }
            Err(_) => panic!("a reader panicked on {f:?} input of {} bytes", bytes.len()),
        }
    }
    assert!(errors > samples.len() / 2, "{errors} of {}", samples.len());
}

/// Evaluates `energy` (on its own) at `x` and returns its error.
fn eval_error(
    energy: Box<dyn hinge_core::energy::Energy>,
    x: &[Vector3<f64>],
) -> hinge_core::EvalError {
    use hinge_core::bending::{Parallelism, Request};
    let mut system = hinge_core::energy::System::new(x.len(), vec![energy]).unwrap();
    system
        .evaluate(x, Request::ALL, Parallelism::Sequential)
        .unwrap_err()
}

#[test]
fn evaluation_errors_name_elements_as_the_mesh_file_does() {
    use hinge_core::bending::{BendingModel, Method};
    use hinge_core::energy::HingeTerm;
    use hinge_core::psi::DiscreteShells;
    use hinge_energies::contact::{Contact, Obstacle};
    use hinge_energies::corotational::CorotationalMembrane;
    use hinge_energies::spring::MassSpring;
    // Two quads (fanned: face 1 → triangles 0, 1; face 2 → 2, 3) and a triangle (face 3 → triangle 4),
    // with comment lines, so that neither vertices nor faces are numbered as the mesh numbers them.
    let text = "# a strip\nv 0 0 0\nv 1 0 0\nv 2 0 0\n# row 2\nv 0 1 0\nv 1 1 0.2\nv 2 1 0\nv 1 2 0\n\
                f 1 2 5 4\nf 2 3 6 5\nf 4 5 7\n";
    let file = read(text.as_bytes(), MeshFormat::Obj).unwrap();
    let names = file.numbering();
    assert_eq!(names.note(), "(OBJ numbering: from 1)");
    let rest = file.mesh.clone();
    assert_eq!(rest.triangles()[4], [3, 4, 6]);
    let x0 = rest.positions().to_vec();
    // A contact whose sphere is centred on mesh vertex 4 (OBJ vertex 5, line 7).
    let contact = Contact::new(
        x0.len(),
        Obstacle::Sphere {
            center: x0[4],
            radius: 0.1,
        },
        10.0,
        0.01,
    )
    .unwrap();
    let e = eval_error(Box::new(contact), &x0);
    assert!(e.to_string().starts_with("contact, vertex 4: "), "{e}");
    assert!(
        e.describe(names)
            .starts_with("contact, vertex 5 (line 7): the vertex is at the sphere's centre"),
        "{}",
        e.describe(names)
    );
    // A spring of zero length: mesh vertex 6 moved onto 4.
    let mut x = x0.clone();
    x[6] = x[4];
    let e = eval_error(Box::new(MassSpring::new(&rest, 1.0).unwrap()), &x);
    let d = e.describe(names);
    assert!(
        d.contains("the edge between vertices 5 and 7")
            || d.contains("the edge between vertices 7 and 5"),
        "{d}"
    );
    // Triangle 4 (face 3, line 12) collapsed onto a line, for the co-rotational membrane; then triangle 1,
    // the second half of the quad on line 10, named by its face.
    let mut x = x0.clone();
    x[6] = x[3] * 0.3 + x[4] * 0.7;
    let e = eval_error(Box::new(CorotationalMembrane::new(&rest, 1.0).unwrap()), &x);
    assert!(
        e.to_string().contains("triangle 4 (vertices 3, 4, 6)"),
        "{e}"
    );
    let d = e.describe(names);
    assert!(
        d.starts_with(
            "corotational-membrane, face 3 (line 12) (vertices 4, 5, 7): the triangle is collapsed"
        ),
        "{d}"
    );
    let mut x = x0.clone();
    x[3] = x[0] * 0.4 + x[4] * 0.6;
    let e = eval_error(Box::new(CorotationalMembrane::new(&rest, 1.0).unwrap()), &x);
    let d = e.describe(names);
    assert!(d.contains("face 1 (line 10) (vertices 1, 5, 4)"), "{d}");
    // The same collapse for a hinge energy: the degenerate triangle or hinge, in the file's numbering.
    let bending = || {
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&rest, DiscreteShells { k: 1.0 }).unwrap(),
            Method::Refactored,
        ))
    };
    let e = eval_error(bending(), &x);
    let d = e.describe(names);
    assert!(
        d.contains("face 1 (line 10) (vertices 1, 5, 4)")
            || d.contains("the hinge on the edge between vertices"),
        "{d}"
    );
    assert_ne!(d, e.to_string());
    // A NaN coordinate names the vertex and its line (the bending model checks positions first).
    let mut x = x0.clone();
    x[4].y = f64::NAN;
    let e = eval_error(bending(), &x);
    let d = e.describe(names);
    assert!(
        d.contains("vertex 5 (line 7): coordinate y is not finite"),
        "{d} / {e}"
    );
}
