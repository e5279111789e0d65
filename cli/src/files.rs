//! Mesh files for the command line: any of the formats of [`hinge_core::meshio`], with a note on stderr when
//! polygons were fan-triangulated.

use std::path::Path;

use hinge_core::TriMesh;
use hinge_core::meshio::{FileNumbering, read_mesh};

/// Reads a mesh file (OBJ, OFF or PLY by extension); polygons with more than three corners are
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
            "hinge: {}: {} faces with more than three corners fan-triangulated ({} triangles in all)",
            path.display(),
            file.polygons_split,
            file.mesh.n_triangles()
        );
    }
    let numbering = file.numbering().clone();
    Ok((file.mesh, numbering))
}
