//! Reading and writing Wavefront OBJ meshes (`v` and `f` records).
//!
//! The reader keeps the file's vertex order (vertex `i` is the `i`-th `v` line), so outputs indexed by
//! vertex line up with the user's file. We parse OBJ ourselves rather than through tobj because tobj
//! renumbers vertices in order of first use, which would silently permute every per-vertex output, and
//! because its errors carry no line number. Supported: `v x y z [w]` (w ignored), faces `f a b c` with
//! `a`, `a/t`, `a//n` or `a/t/n` corners and negative (relative) indices; `vt`, `vn`, `g`, `o`, `s`,
//! `usemtl`, `mtllib` and comments are ignored. A face with other than three corners is an error naming its
//! line (hinge does not triangulate behind your back).

use std::io::{BufRead, BufReader, Write};
use std::path::Path;

use nalgebra::Vector3;

use crate::error::ObjError;
use crate::mesh::TriMesh;

/// Reads an OBJ file into a validated [`TriMesh`].
///
/// # Errors
/// [`ObjError::Io`], [`ObjError::Parse`] (with the line) or [`ObjError::Mesh`].
pub fn read_obj(path: impl AsRef<Path>) -> Result<TriMesh, ObjError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let file = std::fs::File::open(path).map_err(|source| ObjError::Io {
        path: name.clone(),
        source,
    })?;
    parse_obj(BufReader::new(file), &name)
}

/// Parses OBJ text from a reader; `name` is used in error messages.
///
/// # Errors
/// As [`read_obj`].
pub fn parse_obj(reader: impl BufRead, name: &str) -> Result<TriMesh, ObjError> {
    let raw = crate::meshio::parse_obj_records(reader).map_err(|e| ObjError::Parse {
        path: name.to_string(),
        line: e.line,
        message: e.message,
    })?;
    let mut triangles = Vec::with_capacity(raw.faces.len());
    for (poly, &line) in raw.faces.iter().zip(&raw.face_lines) {
        match poly[..] {
            [a, b, c] => triangles.push([a, b, c]),
            _ => {
                return Err(ObjError::Parse {
                    path: name.to_string(),
                    line,
                    message: format!(
                        "face has {} corners; only triangles are supported (hinge_core::meshio::read_mesh fan-triangulates polygons)",
                        poly.len()
                    ),
                });
            }
        }
    }
    TriMesh::new(raw.positions, triangles).map_err(|source| ObjError::Mesh {
        path: name.to_string(),
        source,
    })
}

/// Writes positions and triangles as OBJ with round-trip (17 significant digit) coordinates.
///
/// # Errors
/// The writer's I/O error.
pub fn write_obj_to(
    mut out: impl Write,
    positions: &[Vector3<f64>],
    triangles: &[[usize; 3]],
) -> std::io::Result<()> {
    for p in positions {
        writeln!(out, "v {:.17e} {:.17e} {:.17e}", p.x, p.y, p.z)?;
    }
    for t in triangles {
        writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    out.flush()
}

/// Writes a mesh (or a deformed state of it, `positions`) to an OBJ file.
///
/// # Errors
/// [`ObjError::Io`].
pub fn write_obj(
    path: impl AsRef<Path>,
    positions: &[Vector3<f64>],
    triangles: &[[usize; 3]],
) -> Result<(), ObjError> {
    let path = path.as_ref();
    let io = |source| ObjError::Io {
        path: path.display().to_string(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    write_obj_to(std::io::BufWriter::new(file), positions, triangles).map_err(io)
}
