//! Mesh files for the command line: any of the formats of [`hinge_core::meshio`], with a note on stderr when
//! polygons were fan-triangulated.

use std::path::Path;

use hinge_core::meshio::{FileNumbering, read_mesh};
use hinge_core::{ElementNames, TriMesh};

/// Reads a mesh file (OBJ, OFF, PLY or STL by extension); polygons with more than three corners are
/// fan-triangulated, and one line on stderr says how many. Every command bends the mesh, so its hinge
/// topology is checked here, where a non-manifold edge, an inconsistent orientation or a repeated face can
/// still be named as the file counts (face and line), not by the 0-based triangle numbers of the library.
///
/// # Errors
/// The reader's one-line message (it names the file and counts as the file does).
pub fn read(path: &Path) -> Result<TriMesh, String> {
    read_numbered(path).map(|(mesh, _)| mesh)
}

/// [`read`], with how the file counts vertices and faces (for errors about the mesh later on:
/// [`hinge_core::EvalError::describe`]).
///
/// # Errors
/// As [`read`].
pub fn read_numbered(path: &Path) -> Result<(TriMesh, FileNumbering), String> {
    let file = read_mesh(path).map_err(|e| e.to_string())?;
    file.topology().map_err(|e| e.to_string())?;
    if file.polygons_split > 0 {
        eprintln!(
            "hinge: warning: {}: {} faces with more than three corners fan-triangulated ({} triangles in all)",
            path.display(),
            file.polygons_split,
            file.mesh.n_triangles()
        );
    }
    let numbering = file.numbering().clone();
    let unreferenced = file.mesh.unreferenced_vertices();
    if let Some(&first) = unreferenced.first() {
        let one = unreferenced.len() == 1;
        eprintln!(
            "hinge: warning: {}: {} {} in no face (the first: {}); held where {}",
            path.display(),
            unreferenced.len(),
            if one { "vertex is" } else { "vertices are" },
            numbering.vertex(first),
            if one { "it is" } else { "they are" },
        );
    }
    let coincident = file.mesh.coincident_vertices();
    if let Some(&(v, first)) = coincident.first() {
        eprintln!(
            "hinge: warning: {}: {} {} exactly on another vertex (the first: {} on {}); nothing couples them, so the \
             surface is cut there (UV seams?): weld them if they should be one",
            path.display(),
            coincident.len(),
            if coincident.len() == 1 {
                "vertex lies"
            } else {
                "vertices lie"
            },
            numbering.vertex(v),
            numbering.vertex(first),
        );
    }
    Ok((file.mesh, numbering))
}

/// Checks that `other` (a deformed state or a target shape of `rest`, read from the file `label`) is
/// `rest`'s mesh: the same vertex count, and `rest`'s faces in any order, each with its corners in any
/// rotation (as another tool may write them back); only its positions are used. `names` is how `label`
/// counts vertices and faces (none: the mesh's own numbering, from 0).
///
/// # Errors
/// A one-line message naming the first face of `other` that is not one of `rest`'s, or the counts.
pub fn check_same_mesh(
    rest: &TriMesh,
    other: &TriMesh,
    names: Option<&FileNumbering>,
    label: &str,
) -> Result<(), String> {
    if other.n_vertices() != rest.n_vertices() {
        return Err(format!(
            "{label}: {} vertices, the rest mesh has {}",
            other.n_vertices(),
            rest.n_vertices()
        ));
    }
    if other.triangles() == rest.triangles() {
        return Ok(());
    }
    // Each oriented triangle with its smallest vertex first: the same key under any corner rotation.
    let key = |t: &[usize; 3]| {
        let k = (0..3).min_by_key(|&k| t[k]).unwrap_or(0);
        [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
    };
    let mut faces: Vec<[usize; 3]> = rest.triangles().iter().map(key).collect();
    faces.sort_unstable();
    if let Some((i, t)) = other
        .triangles()
        .iter()
        .enumerate()
        .find(|(_, t)| faces.binary_search(&key(t)).is_err())
    {
        let (face, vertices, note) = match names {
            Some(n) => (
                n.triangle(i),
                t.map(|v| n.vertex_number(v)).join(", "),
                format!(" {}", n.note()),
            ),
            None => (
                format!("triangle {i}"),
                t.map(|v| v.to_string()).join(", "),
                String::new(),
            ),
        };
        return Err(format!(
            "{label}: {face} (vertices {vertices}) is not a face of the rest mesh (the rest mesh's faces are \
             expected, in any order and corner rotation, with its vertices in its order){note}"
        ));
    }
    // Every face is one of the rest mesh's and none repeats (a repeated face is a topology error): only the
    // counts can still differ.
    if other.n_triangles() != rest.n_triangles() {
        return Err(format!(
            "{label}: {} triangles, the rest mesh has {}",
            other.n_triangles(),
            rest.n_triangles()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::check_same_mesh;
    use hinge_core::shapes::irregular_sheet;

    #[test]
    fn the_same_mesh_is_its_faces_in_any_order_and_rotation() {
        let rest = irregular_sheet(5, 4, 2).unwrap();
        let x = rest.positions().to_vec();
        // Faces reversed in order, each rotated by a face-dependent amount: the same mesh.
        let shuffled: Vec<[usize; 3]> = rest
            .triangles()
            .iter()
            .enumerate()
            .rev()
            .map(|(i, t)| [t[i % 3], t[(i + 1) % 3], t[(i + 2) % 3]])
            .collect();
        let other = hinge_core::TriMesh::new(x.clone(), shuffled.clone()).unwrap();
        assert_eq!(check_same_mesh(&rest, &other, None, "s"), Ok(()));
        // A face flipped is another face: named by its position in `other` (from 0 without a file).
        let mut flipped = shuffled.clone();
        flipped[3].swap(1, 2);
        let other = hinge_core::TriMesh::new(x.clone(), flipped.clone()).unwrap();
        let t = flipped[3];
        assert_eq!(
            check_same_mesh(&rest, &other, None, "s").unwrap_err(),
            format!(
                "s: triangle 3 (vertices {}, {}, {}) is not a face of the rest mesh (the rest mesh's \
                 faces are expected, in any order and corner rotation, with its vertices in its order)",
                t[0], t[1], t[2]
            )
        );
        // A face missing; a vertex more.
        let other = hinge_core::TriMesh::new(x.clone(), shuffled[1..].to_vec()).unwrap();
        let e = check_same_mesh(&rest, &other, None, "s").unwrap_err();
        assert!(e.contains("triangles, the rest mesh has"), "{e}");
        let mut more = x.clone();
        more.push(x[0]);
        let other = hinge_core::TriMesh::new(more, shuffled).unwrap();
        let e = check_same_mesh(&rest, &other, None, "s").unwrap_err();
        assert!(e.contains("vertices, the rest mesh has"), "{e}");
    }
}
