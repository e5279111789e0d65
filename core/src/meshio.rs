//! Mesh files by extension: Wavefront OBJ, OFF, PLY (ASCII, binary little and big endian) and STL (ASCII
//! and binary).
//!
//! [`read_mesh`] picks the reader from the file's extension (`.obj`, `.off`, `.ply`, `.stl`, any case) and
//! keeps the file's vertex order in every format with vertices (vertex `i` of the mesh is the file's `i`-th
//! vertex). STL has none — each facet lists its own corners, as CAD tools export — so its corners are
//! welded where their positions are equal, vertices numbered in order of first appearance; a message names
//! a vertex by the facet (and line) it first appears in.
//! Polygons with more than three corners are fan-triangulated (corner 0 with each following pair, in the
//! file's order); [`MeshFile::polygons_split`] says how many were, so a front end can tell the user.
//!
//! Errors name the file and count as the file does: OBJ vertices and faces from 1 with the line number; OFF
//! and PLY vertices and faces from 0; STL facets from 1 (each message says which). A file whose content does not match its
//! extension, or that has no triangles, is an error saying which format it was read as.
//!
//! OBJ as exporters write it: a UTF-8 byte-order mark and CRLF line ends, `#` comments after statements,
//! lines continued with a trailing `\`, negative (relative) indices, `v/vt/vn` corners; statements other
//! than `v`, `vt` and `f` (objects, groups, materials, normals, lines) are skipped. OFF may start with a
//! byte-order mark too.
//!
//! PLY is parsed by the `ply-rs-bw` crate (both spellings of the type names, `float`/`float32`,
//! `double`/`float64`, …; extra properties and elements ignored); vertices need `x`, `y`, `z` of any numeric
//! type, faces a list property `vertex_indices` (or `vertex_index`) of any integer type.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;

use nalgebra::Vector3;
use thiserror::Error;

use crate::error::{ElementNames, MeshError};
use crate::mesh::TriMesh;
use crate::topology::Topology;

/// A mesh file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ (`v`, `f` records; 1-based indices).
    Obj,
    /// Object File Format (`OFF` header, counts, vertices, faces; 0-based indices).
    Off,
    /// Polygon File Format (ASCII or binary; 0-based indices).
    Ply,
    /// Stereolithography, as CAD tools export (ASCII or binary; facets with their own corners, welded
    /// where positions are equal; facets and the welded vertices, in order of first appearance, from 1).
    Stl,
}

impl MeshFormat {
    /// The format of a path's extension (case-insensitive), if it is one of the four.
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "obj" => Some(MeshFormat::Obj),
            "off" => Some(MeshFormat::Off),
            "ply" => Some(MeshFormat::Ply),
            "stl" => Some(MeshFormat::Stl),
            _ => None,
        }
    }

    /// `OBJ`, `OFF`, `PLY` or `STL`.
    pub fn name(self) -> &'static str {
        match self {
            MeshFormat::Obj => "OBJ",
            MeshFormat::Off => "OFF",
            MeshFormat::Ply => "PLY",
            MeshFormat::Stl => "STL",
        }
    }

    /// `obj`, `off`, `ply` or `stl`.
    pub fn extension(self) -> &'static str {
        match self {
            MeshFormat::Obj => "obj",
            MeshFormat::Off => "off",
            MeshFormat::Ply => "ply",
            MeshFormat::Stl => "stl",
        }
    }

    /// The first index of the format's vertex and face numbering (1 for OBJ and STL, 0 for OFF and PLY).
    pub fn first_index(self) -> usize {
        match self {
            MeshFormat::Obj | MeshFormat::Stl => 1,
            MeshFormat::Off | MeshFormat::Ply => 0,
        }
    }

    /// What the format calls a face: `facet` for STL, `face` otherwise.
    fn face_word(self) -> &'static str {
        match self {
            MeshFormat::Stl => "facet",
            _ => "face",
        }
    }
}

/// A mesh read from a file.
#[derive(Debug, Clone)]
pub struct MeshFile {
    /// The validated mesh (the file's vertex order; triangles in face order, polygons fanned in place).
    pub mesh: TriMesh,
    /// The format it was read as.
    pub format: MeshFormat,
    /// Faces with more than three corners, fan-triangulated.
    pub polygons_split: usize,
    /// For each triangle of [`MeshFile::mesh`], the file's face it comes from (0-based position among the
    /// faces, whatever the format's own numbering).
    pub face_of_triangle: Vec<usize>,
    /// Texture coordinates of each triangle's corners (OBJ `vt` with `f v/vt`; PLY vertex `u`,`v` —
    /// or `s`,`t`, `texture_u`,`texture_v` — or a face's `texcoord` list), `None` where the face has
    /// none; empty when the file has none at all (OFF never has).
    pub uvs: Vec<Option<crate::anisotropy::TriangleUv>>,
    /// The file's name, as given to the reader (for messages).
    name: String,
    numbering: FileNumbering,
}

impl MeshFile {
    /// A [`MeshError`] about [`MeshFile::mesh`] (0-based vertices and triangles) told in the file's own
    /// numbering: vertices and faces counted as the format counts them (OBJ from 1, OFF and PLY from 0), with
    /// their lines where the file is text, a fanned polygon named by its face.
    pub fn describe(&self, e: &MeshError) -> String {
        self.numbering
            .describe_mesh_error(e, self.mesh.n_vertices())
    }

    /// How the file counts vertices and faces: pass it to [`crate::EvalError::describe`] to tell an
    /// evaluation's error about this mesh in the file's numbering.
    pub fn numbering(&self) -> &FileNumbering {
        &self.numbering
    }

    /// The hinge topology of the file's mesh ([`Topology::new`]). A mesh file may hold triangles no hinge
    /// energy accepts (an edge of three faces, faces of opposite orientation across an edge, the same face
    /// twice: common in scanned and CAD meshes); here they are errors in the file's numbering.
    ///
    /// # Errors
    /// [`MeshFileError::Mesh`] naming the faces and vertices as the file counts them.
    pub fn topology(&self) -> Result<Topology, MeshFileError> {
        Topology::new(self.mesh.n_vertices(), self.mesh.triangles()).map_err(|source| {
            MeshFileError::Mesh {
                path: self.name.clone(),
                format: self.format,
                message: self.describe(&source),
                source,
            }
        })
    }
}

/// Why a mesh file could not be read or written.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum MeshFileError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The extension is not `.obj`, `.off`, `.ply` or `.stl`.
    #[error("{path}: unknown mesh file extension (expected .obj, .off, .ply or .stl)")]
    UnknownExtension {
        /// The file.
        path: String,
    },
    /// The content is not a valid file of the format its extension names.
    #[error("{path}: not a valid {} file: {message}", format.name())]
    Parse {
        /// The file.
        path: String,
        /// The format it was read as.
        format: MeshFormat,
        /// What is wrong, and where (a line, or a vertex or face in the format's numbering).
        message: String,
    },
    /// The file parsed but has no triangles.
    #[error("{path}: read as {}, it has {vertices} vertices and no faces with three or more corners", format.name())]
    NoTriangles {
        /// The file.
        path: String,
        /// The format it was read as.
        format: MeshFormat,
        /// Vertices it has.
        vertices: usize,
    },
    /// The file parsed, but the mesh is invalid; the message counts vertices and faces as the file does.
    #[error("{path}: {message} ({} numbering: from {})", format.name(), format.first_index())]
    Mesh {
        /// The file.
        path: String,
        /// The format.
        format: MeshFormat,
        /// The mesh error in the file's numbering.
        message: String,
        /// The mesh error in the mesh's own (0-based, triangle) numbering.
        source: MeshError,
    },
}

/// Faces as read: polygons of vertex indices (already 0-based), and where they came from.
#[derive(Default)]
pub(crate) struct Raw {
    pub(crate) positions: Vec<Vector3<f64>>,
    pub(crate) faces: Vec<Vec<usize>>,
    /// 1-based lines of the vertices and faces (OBJ, OFF and ASCII STL; empty for PLY and binary STL).
    pub(crate) vertex_lines: Vec<usize>,
    pub(crate) face_lines: Vec<usize>,
    /// For each vertex, the (0-based) face it first appears in (STL, whose vertices are welded corners;
    /// empty for the other formats).
    pub(crate) vertex_faces: Vec<usize>,
    /// Texture coordinates of each face's corners (parallel to `faces`; `None` for a face without them).
    pub(crate) face_uvs: Vec<Option<Vec<[f64; 2]>>>,
}

/// A parse error at a (1-based) line.
pub(crate) struct LineError {
    pub(crate) line: usize,
    pub(crate) message: String,
}

/// Reads a mesh file, the format chosen by its extension.
///
/// # Errors
/// [`MeshFileError`]: I/O, unknown extension, content that does not match it (with the line or element),
/// no triangles, or an invalid mesh in the file's numbering.
pub fn read_mesh(path: impl AsRef<Path>) -> Result<MeshFile, MeshFileError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let format = MeshFormat::from_path(path)
        .ok_or_else(|| MeshFileError::UnknownExtension { path: name.clone() })?;
    let file = std::fs::File::open(path).map_err(|source| MeshFileError::Io {
        path: name.clone(),
        source,
    })?;
    read_mesh_from(BufReader::new(file), format, &name)
}

/// Reads a mesh of `format` from a reader; `name` is used in error messages.
///
/// # Errors
/// As [`read_mesh`].
pub fn read_mesh_from(
    reader: impl BufRead,
    format: MeshFormat,
    name: &str,
) -> Result<MeshFile, MeshFileError> {
    let parse = |message: String| MeshFileError::Parse {
        path: name.to_string(),
        format,
        message,
    };
    let raw = match format {
        MeshFormat::Obj => parse_obj(reader).map_err(parse)?,
        MeshFormat::Off => parse_off(reader).map_err(parse)?,
        MeshFormat::Ply => parse_ply(reader).map_err(parse)?,
        MeshFormat::Stl => parse_stl(reader).map_err(parse)?,
    };
    let mut triangles = Vec::with_capacity(raw.faces.len());
    let mut face_of_triangle = Vec::with_capacity(raw.faces.len());
    let mut polygons_split = 0;
    let mut uvs = Vec::new();
    let any_uv = raw.face_uvs.iter().any(Option::is_some);
    for (f, poly) in raw.faces.iter().enumerate() {
        if poly.len() > 3 {
            polygons_split += 1;
        }
        let uv = raw.face_uvs.get(f).and_then(Option::as_ref);
        for k in 1..poly.len().saturating_sub(1) {
            triangles.push([poly[0], poly[k], poly[k + 1]]);
            face_of_triangle.push(f);
            if any_uv {
                uvs.push(uv.map(|uv| [uv[0], uv[k], uv[k + 1]]));
            }
        }
    }
    if triangles.is_empty() {
        return Err(MeshFileError::NoTriangles {
            path: name.to_string(),
            format,
            vertices: raw.positions.len(),
        });
    }
    let n_vertices = raw.positions.len();
    let numbering = FileNumbering {
        format,
        face_of_triangle: face_of_triangle.clone(),
        vertex_lines: raw.vertex_lines,
        face_lines: raw.face_lines,
        vertex_faces: raw.vertex_faces,
    };
    match TriMesh::new(raw.positions, triangles) {
        Ok(mesh) => Ok(MeshFile {
            mesh,
            format,
            polygons_split,
            face_of_triangle,
            uvs,
            name: name.to_string(),
            numbering,
        }),
        Err(source) => Err(MeshFileError::Mesh {
            path: name.to_string(),
            format,
            message: numbering.describe_mesh_error(&source, n_vertices),
            source,
        }),
    }
}

/// How a mesh file counts its vertices and faces (OBJ from 1, OFF and PLY from 0; the line of each record in
/// a text file; the face a fanned polygon's triangles come from): [`MeshFile::numbering`]. As an
/// [`ElementNames`] it tells errors about the mesh in the file's terms ([`crate::EvalError::describe`]).
#[derive(Debug, Clone)]
pub struct FileNumbering {
    format: MeshFormat,
    face_of_triangle: Vec<usize>,
    vertex_lines: Vec<usize>,
    face_lines: Vec<usize>,
    vertex_faces: Vec<usize>,
}

impl ElementNames for FileNumbering {
    fn vertex(&self, v: usize) -> String {
        let n = v + self.format.first_index();
        let line = self.vertex_lines.get(v).map(|l| format!("line {l}"));
        // An STL file has no vertex list: say where the vertex first appears.
        let facet = self
            .vertex_faces
            .get(v)
            .map(|f| format!("first in facet {}", f + self.format.first_index()));
        match [facet, line].into_iter().flatten().collect::<Vec<_>>() {
            at if at.is_empty() => format!("vertex {n}"),
            at => format!("vertex {n} ({})", at.join(", ")),
        }
    }

    fn vertex_number(&self, v: usize) -> String {
        (v + self.format.first_index()).to_string()
    }

    fn triangle(&self, t: usize) -> String {
        let f = self.face_of_triangle.get(t).copied().unwrap_or(t);
        let n = f + self.format.first_index();
        let word = self.format.face_word();
        match self.face_lines.get(f) {
            Some(line) => format!("{word} {n} (line {line})"),
            None => format!("{word} {n}"),
        }
    }
}

impl FileNumbering {
    /// The format whose numbering this is.
    pub fn format(&self) -> MeshFormat {
        self.format
    }

    /// What a message in this numbering ends with: `(OBJ numbering: from 1)`.
    pub fn note(&self) -> String {
        format!(
            "({} numbering: from {})",
            self.format.name(),
            self.format.first_index()
        )
    }

    fn face(&self, t: usize) -> String {
        self.triangle(t)
    }

    /// A [`MeshError`] about the file's mesh of `n_vertices` vertices, in the file's numbering.
    pub fn describe_mesh_error(&self, e: &MeshError, n_vertices: usize) -> String {
        let xyz = |a: usize| ["x", "y", "z"].get(a).copied().unwrap_or("?");
        match e {
            MeshError::IndexOutOfRange {
                triangle, index, ..
            } => format!(
                "{} names vertex {}, but the file has {n_vertices} vertices",
                self.face(*triangle),
                self.vertex_number(*index)
            ),
            MeshError::RepeatedVertex { triangle, vertex } => format!(
                "{} names vertex {} more than once",
                self.face(*triangle),
                self.vertex_number(*vertex)
            ),
            MeshError::NonFiniteCoordinate {
                vertex,
                axis,
                value,
            } => format!(
                "{}: coordinate {} is not finite ({value})",
                self.vertex(*vertex),
                xyz(*axis)
            ),
            MeshError::ZeroAreaTriangle { triangle, vertices } => format!(
                "{} has zero area (vertices {}, {}, {} are colinear)",
                self.face(*triangle),
                self.vertex_number(vertices[0]),
                self.vertex_number(vertices[1]),
                self.vertex_number(vertices[2])
            ),
            MeshError::TriangleTooLarge { triangle, vertices } => format!(
                "{} is too large: its area overflows f64 (vertices {}, {}, {}; rescale the mesh)",
                self.face(*triangle),
                self.vertex_number(vertices[0]),
                self.vertex_number(vertices[1]),
                self.vertex_number(vertices[2])
            ),
            MeshError::NonManifoldEdge {
                edge,
                count,
                triangles,
            } => format!(
                "the edge between vertices {} and {} is shared by {count} triangles (of {}, {} and {}); a manifold edge has at most two",
                self.vertex_number(edge[0]),
                self.vertex_number(edge[1]),
                self.face(triangles[0]),
                self.face(triangles[1]),
                self.face(triangles[2])
            ),
            MeshError::InconsistentOrientation { edge, triangles } => format!(
                "{} and {} traverse the edge between vertices {} and {} in the same direction: the orientation is inconsistent",
                self.face(triangles[0]),
                self.face(triangles[1]),
                self.vertex_number(edge[0]),
                self.vertex_number(edge[1])
            ),
            MeshError::DuplicateTriangle { triangles } => format!(
                "{} and {} have the same three vertices",
                self.face(triangles[0]),
                self.face(triangles[1])
            ),
            other => other.to_string(),
        }
    }
}

/// Lines of a text reader, with a message for bytes that are not text.
fn text_lines(reader: impl BufRead) -> impl Iterator<Item = Result<(usize, String), String>> {
    reader.lines().enumerate().map(|(i, l)| {
        l.map(|s| (i + 1, without_bom(i, s))).map_err(|e| {
            if e.kind() == std::io::ErrorKind::InvalidData {
                format!("line {} is not text (a binary file?)", i + 1)
            } else {
                format!("line {}: {e}", i + 1)
            }
        })
    })
}

/// Line `index` (from 0) without the UTF-8 byte-order mark that Windows tools put before the first line.
fn without_bom(index: usize, line: String) -> String {
    match line.strip_prefix('\u{feff}') {
        Some(rest) if index == 0 => rest.to_string(),
        _ => line,
    }
}

/// The statements of an OBJ file with their first line numbers: a byte-order mark before the first line
/// dropped, a line ending in `\` joined with the next (the format's line continuation), and everything from
/// `#` to the end of the line a comment.
fn obj_statements(
    reader: impl BufRead,
) -> impl Iterator<Item = Result<(usize, String), LineError>> {
    let mut lines = reader.lines().enumerate();
    std::iter::from_fn(move || {
        let mut statement = String::new();
        let mut first = None;
        for (i, line) in lines.by_ref() {
            let line = match line {
                Ok(l) => without_bom(i, l),
                Err(e) => {
                    return Some(Err(LineError {
                        line: i + 1,
                        message: if e.kind() == std::io::ErrorKind::InvalidData {
                            "the line is not text (a binary file?)".to_string()
                        } else {
                            e.to_string()
                        },
                    }));
                }
            };
            first.get_or_insert(i + 1);
            let body = line.split('#').next().unwrap_or("");
            match body.trim_end().strip_suffix('\\') {
                Some(head) => {
                    statement.push_str(head);
                    statement.push(' ');
                }
                _ => {
                    statement.push_str(body);
                    return first.map(|n| Ok((n, statement)));
                }
            }
        }
        first.map(|n| Ok((n, statement)))
    })
}

/// Why a text vertex record has no position.
#[derive(Debug, Error)]
enum Coordinates {
    #[error("vertex has fewer than 3 coordinates (missing {0})")]
    Missing(&'static str),
    #[error("cannot parse coordinate `{0}`")]
    Unparsable(String),
}

/// The next three words as x, y, z (OBJ `v`, OFF vertex lines, STL `vertex`); further words are ignored.
fn three_coordinates<'a>(
    words: &mut impl Iterator<Item = &'a str>,
) -> Result<Vector3<f64>, Coordinates> {
    let mut c = [0.0; 3];
    for (slot, axis) in c.iter_mut().zip(["x", "y", "z"]) {
        let w = words.next().ok_or(Coordinates::Missing(axis))?;
        *slot = w
            .parse::<f64>()
            .map_err(|_| Coordinates::Unparsable(w.to_string()))?;
    }
    Ok(Vector3::new(c[0], c[1], c[2]))
}

fn parse_obj(reader: impl BufRead) -> Result<Raw, String> {
    parse_obj_records(reader).map_err(|e| format!("line {}: {}", e.line, e.message))
}

/// The `v` and `f` records of an OBJ file (faces of any corner count from 3), in file order; also what
/// [`crate::obj::parse_obj`] reads.
pub(crate) fn parse_obj_records(reader: impl BufRead) -> Result<Raw, LineError> {
    let mut raw = Raw::default();
    let mut texcoords: Vec<[f64; 2]> = Vec::new();
    for record in obj_statements(reader) {
        let (lineno, line) = record?;
        let at = |message: String| LineError {
            line: lineno,
            message,
        };
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let p = three_coordinates(&mut words).map_err(|e| at(e.to_string()))?;
                raw.positions.push(p);
                raw.vertex_lines.push(lineno);
            }
            Some("vt") => {
                let mut c = [0.0; 2];
                for (axis, slot) in c.iter_mut().enumerate() {
                    let w = words.next().ok_or_else(|| {
                        at(format!(
                            "texture coordinate has fewer than 2 components (missing {})",
                            ["u", "v"][axis]
                        ))
                    })?;
                    *slot = w
                        .parse::<f64>()
                        .map_err(|_| at(format!("cannot parse texture coordinate `{w}`")))?;
                }
                texcoords.push(c);
            }
            Some("f") => {
                let mut poly = Vec::new();
                let mut uv = Some(Vec::new());
                for corner in words {
                    let mut parts = corner.split('/');
                    let idx = parts.next().unwrap_or("");
                    let value: i64 = idx
                        .parse()
                        .map_err(|_| at(format!("cannot parse face index `{corner}`")))?;
                    let n = raw.positions.len() as i64;
                    let resolved = match value {
                        v if v > 0 => v - 1,
                        v if v < 0 => n + v,
                        _ => -1,
                    };
                    if resolved < 0 {
                        return Err(at(format!(
                            "face index {value} does not name a vertex (1-based, or negative relative to the {n} vertices so far)"
                        )));
                    }
                    poly.push(resolved as usize);
                    // `v/vt`, `v/vt/vn`; `v` and `v//vn` have no texture coordinate.
                    match parts.next().filter(|t| !t.is_empty()) {
                        Some(t) => {
                            let value: i64 = t.parse().map_err(|_| {
                                at(format!("cannot parse texture index in `{corner}`"))
                            })?;
                            let n = texcoords.len() as i64;
                            let resolved = match value {
                                v if v > 0 => v - 1,
                                v if v < 0 => n + v,
                                _ => -1,
                            };
                            if resolved < 0 || resolved >= n {
                                return Err(at(format!(
                                    "texture index {value} in `{corner}` does not name a texture coordinate (1-based, or negative relative to the {n} `vt` lines so far)"
                                )));
                            }
                            if let Some(uv) = uv.as_mut() {
                                uv.push(texcoords[resolved as usize]);
                            }
                        }
                        None => uv = None,
                    }
                }
                if poly.len() < 3 {
                    return Err(at(format!(
                        "face has {} corners (at least 3 are needed)",
                        poly.len()
                    )));
                }
                raw.faces.push(poly);
                raw.face_lines.push(lineno);
                raw.face_uvs.push(uv);
            }
            _ => {}
        }
    }
    Ok(raw)
}

/// The most elements preallocated from a count in a header (a wrong count cannot exhaust memory).
const PREALLOCATE: usize = 1 << 20;

fn parse_off(reader: impl BufRead) -> Result<Raw, String> {
    // Content lines: comments (`#` to the end of the line) and blank lines skipped.
    let mut lines = text_lines(reader).filter_map(|item| match item {
        Ok((n, l)) => {
            let body = l.split('#').next().unwrap_or("").trim().to_string();
            (!body.is_empty()).then_some(Ok((n, body)))
        }
        Err(e) => Some(Err(e)),
    });
    let (first_line, header) = lines
        .next()
        .ok_or_else(|| "the file is empty (an OFF file starts with `OFF`)".to_string())??;
    let mut words = header.split_whitespace();
    let keyword = words.next().unwrap_or("");
    // OFF, with the optional colour / normal / texture prefixes of the format's variants.
    let known = [
        "OFF", "COFF", "NOFF", "CNOFF", "STOFF", "STCOFF", "STNOFF", "STCNOFF",
    ];
    if !known.contains(&keyword) {
        return Err(format!(
            "line {first_line}: the header is `{}`, not `OFF`",
            header.chars().take(40).collect::<String>()
        ));
    }
    // The counts follow on the same line or on the next content line.
    let rest: Vec<&str> = words.collect();
    let (counts_line, counts): (usize, Vec<String>) = if rest.is_empty() {
        let (n, l) = lines
            .next()
            .ok_or_else(|| "no vertex and face counts after the header".to_string())??;
        (n, l.split_whitespace().map(str::to_string).collect())
    } else {
        (first_line, rest.iter().map(|s| s.to_string()).collect())
    };
    let count = |k: usize, what: &str| -> Result<usize, String> {
        counts
            .get(k)
            .ok_or_else(|| format!("line {counts_line}: missing the {what} count"))?
            .parse::<usize>()
            .map_err(|_| {
                format!(
                    "line {counts_line}: cannot parse the {what} count `{}`",
                    counts[k]
                )
            })
    };
    let (nv, nf) = (count(0, "vertex")?, count(1, "face")?);
    let mut raw = Raw {
        positions: Vec::with_capacity(nv.min(PREALLOCATE)),
        faces: Vec::with_capacity(nf.min(PREALLOCATE)),
        vertex_lines: Vec::with_capacity(nv.min(PREALLOCATE)),
        face_lines: Vec::with_capacity(nf.min(PREALLOCATE)),
        vertex_faces: Vec::new(),
        face_uvs: Vec::with_capacity(nf.min(PREALLOCATE)),
    };
    for v in 0..nv {
        let (n, l) = lines.next().ok_or_else(|| {
            format!(
                "the file ends after {v} of its {nv} vertices (vertex {v}, 0-based, is missing)"
            )
        })??;
        let p = three_coordinates(&mut l.split_whitespace()).map_err(|e| match e {
            Coordinates::Missing(axis) => format!(
                "line {n}: vertex {v} (0-based) has fewer than 3 coordinates (missing {axis})"
            ),
            e => format!("line {n}: vertex {v} (0-based): {e}"),
        })?;
        raw.positions.push(p);
        raw.vertex_lines.push(n);
    }
    for f in 0..nf {
        let (n, l) = lines.next().ok_or_else(|| {
            format!("the file ends after {f} of its {nf} faces (face {f}, 0-based, is missing)")
        })??;
        let mut words = l.split_whitespace();
        let k: usize = words.next().and_then(|w| w.parse().ok()).ok_or_else(|| {
            format!("line {n}: face {f} (0-based) does not start with its corner count")
        })?;
        if k < 3 {
            return Err(format!(
                "line {n}: face {f} (0-based) has {k} corners (at least 3 are needed)"
            ));
        }
        let mut poly = Vec::with_capacity(k.min(64));
        for _ in 0..k {
            let w = words.next().ok_or_else(|| {
                format!("line {n}: face {f} (0-based) lists fewer than its {k} corners")
            })?;
            poly.push(w.parse::<usize>().map_err(|_| {
                format!("line {n}: face {f} (0-based): cannot parse vertex index `{w}`")
            })?);
        }
        // What follows the corners (a colour) is ignored.
        raw.faces.push(poly);
        raw.face_lines.push(n);
        raw.face_uvs.push(None);
    }
    Ok(raw)
}

/// Welds STL corners into vertices: equal positions (bitwise, `-0.0` as `+0.0`) are one vertex, numbered
/// in order of first appearance.
struct Welder {
    index: std::collections::HashMap<[u64; 3], usize>,
    raw: Raw,
}

impl Welder {
    fn new() -> Self {
        Self {
            index: std::collections::HashMap::new(),
            raw: Raw::default(),
        }
    }

    /// Adds a facet of `corners` (with the line of each corner and of the facet, for ASCII files).
    fn facet(&mut self, corners: &[(Vector3<f64>, usize)], line: Option<usize>) {
        let face = self.raw.faces.len();
        let mut poly = Vec::with_capacity(corners.len());
        for &(p, corner_line) in corners {
            let key = [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits());
            let next = self.raw.positions.len();
            let v = *self.index.entry(key).or_insert(next);
            if v == next {
                self.raw.positions.push(p);
                self.raw.vertex_faces.push(face);
                if line.is_some() {
                    self.raw.vertex_lines.push(corner_line);
                }
            }
            poly.push(v);
        }
        self.raw.faces.push(poly);
        if let Some(l) = line {
            self.raw.face_lines.push(l);
        }
    }
}

/// STL, ASCII or binary. A file is binary when its length is what the facet count at bytes 80–84 says
/// (84 + 50 per facet; binary headers often start with `solid` too), else ASCII when it starts with
/// `solid`. ASCII keywords in any case; several `solid`s in one file; a loop of more than three vertices is a
/// polygon (fanned like the other formats').
fn parse_stl(mut reader: impl BufRead) -> Result<Raw, String> {
    let mut bytes = Vec::new();
    reader
        .read_to_end(&mut bytes)
        .map_err(|e| format!("cannot read: {e}"))?;
    let count = bytes
        .get(80..84)
        .and_then(|c| <[u8; 4]>::try_from(c).ok())
        .map(u32::from_le_bytes);
    let text_start = bytes.strip_prefix("\u{feff}".as_bytes()).unwrap_or(&bytes);
    let starts_solid = text_start
        .iter()
        .skip_while(|b| b.is_ascii_whitespace())
        .take(5)
        .map(u8::to_ascii_lowercase)
        .eq(*b"solid");
    // A binary header may start with `solid` too: text decides between ASCII and a damaged binary file.
    let text = starts_solid && std::str::from_utf8(text_start).is_ok();
    match count {
        Some(n) if bytes.len() as u64 == 84 + 50 * u64::from(n) => Ok(parse_stl_binary(&bytes, n)),
        _ if text => parse_stl_ascii(text_start),
        Some(n) => Err(format!(
            "a binary STL of {n} facets (the count at bytes 80-84) has {} bytes, this file has {} \
             (truncated?), and it is not ASCII STL text",
            84 + 50 * u64::from(n),
            bytes.len()
        )),
        None if starts_solid => Err("the file starts with `solid` but is not text".into()),
        None => Err(format!(
            "{} bytes: neither an ASCII STL (starting with `solid`) nor a binary one (an 84-byte header)",
            bytes.len()
        )),
    }
}

fn parse_stl_binary(bytes: &[u8], n: u32) -> Raw {
    let mut w = Welder::new();
    let f32_at = |o: usize| {
        bytes
            .get(o..o + 4)
            .and_then(|c| <[u8; 4]>::try_from(c).ok())
            .map_or(f64::NAN, |c| f64::from(f32::from_le_bytes(c)))
    };
    for i in 0..n as usize {
        // 12 bytes of normal (not used: the corners' order is the orientation), then three corners.
        let o = 84 + 50 * i + 12;
        let corners: Vec<(Vector3<f64>, usize)> = (0..3)
            .map(|k| {
                let c = o + 12 * k;
                (Vector3::new(f32_at(c), f32_at(c + 4), f32_at(c + 8)), 0)
            })
            .collect();
        w.facet(&corners, None);
    }
    w.raw
}

fn parse_stl_ascii(bytes: &[u8]) -> Result<Raw, String> {
    let text = std::str::from_utf8(bytes).map_err(|_| "the file is not text".to_string())?;
    let mut w = Welder::new();
    let mut corners: Vec<(Vector3<f64>, usize)> = Vec::new();
    let mut facet_line: Option<usize> = None;
    for (i, line) in text.lines().enumerate() {
        let lineno = i + 1;
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        match keyword.to_ascii_lowercase().as_str() {
            "facet" => {
                if facet_line.is_some() {
                    return Err(format!(
                        "line {lineno}: `facet` before the last one's `endfacet`"
                    ));
                }
                facet_line = Some(lineno);
                corners.clear();
            }
            "vertex" => {
                if facet_line.is_none() {
                    return Err(format!("line {lineno}: `vertex` outside a facet"));
                }
                let p = three_coordinates(&mut words).map_err(|e| format!("line {lineno}: {e}"))?;
                corners.push((p, lineno));
            }
            "endfacet" => {
                let Some(at) = facet_line.take() else {
                    return Err(format!("line {lineno}: `endfacet` without `facet`"));
                };
                if corners.len() < 3 {
                    return Err(format!(
                        "line {at}: the facet has {} vertices (at least 3 are needed)",
                        corners.len()
                    ));
                }
                w.facet(&corners, Some(at));
            }
            // `solid NAME`, `outer loop`, `endloop`, `endsolid NAME`: structure only.
            "solid" | "outer" | "endloop" | "endsolid" => {}
            other => {
                return Err(format!("line {lineno}: unknown keyword `{other}`"));
            }
        }
    }
    if let Some(at) = facet_line {
        return Err(format!(
            "line {at}: the facet has no `endfacet` (truncated?)"
        ));
    }
    Ok(w.raw)
}

/// Writes a binary STL: an 80-byte header, the facet count, and per triangle its unit normal (zero for a
/// degenerate one) and corners as f32 — STL stores single precision, so positions are rounded to f32.
///
/// # Errors
/// The writer's I/O errors, and more than `u32::MAX` triangles.
pub fn write_stl_to(
    mut out: impl Write,
    positions: &[Vector3<f64>],
    triangles: &[[usize; 3]],
) -> std::io::Result<()> {
    let n = u32::try_from(triangles.len()).map_err(|_| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "more than 2^32 - 1 triangles",
        )
    })?;
    let mut header = [b' '; 80];
    let title = b"binary STL written by hinge";
    header[..title.len()].copy_from_slice(title);
    out.write_all(&header)?;
    out.write_all(&n.to_le_bytes())?;
    let at = |v: usize| {
        positions.get(v).copied().ok_or_else(|| {
            std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("no vertex {v}"))
        })
    };
    for t in triangles {
        let [a, b, c] = [at(t[0])?, at(t[1])?, at(t[2])?];
        let normal = (b - a).cross(&(c - a));
        let normal = normal.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
        for p in [normal, a, b, c] {
            for k in 0..3 {
                out.write_all(&(p[k] as f32).to_le_bytes())?;
            }
        }
        out.write_all(&[0, 0])?;
    }
    out.flush()
}

fn parse_ply(mut reader: impl BufRead) -> Result<Raw, String> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property};
    // A PLY file starts with the magic line `ply`: check it first, so that another file gets a clear message.
    let mut magic = [0u8; 4];
    let got = read_up_to(&mut reader, &mut magic).map_err(|e| e.to_string())?;
    if got < 3 || &magic[..3] != b"ply" || (got == 4 && !matches!(magic[3], b'\n' | b'\r')) {
        return Err("it does not start with the line `ply`".into());
    }
    let mut chained = std::io::Cursor::new(magic[..got].to_vec()).chain(reader);
    let parser = Parser::<DefaultElement>::new();
    let ply = parser.read_ply(&mut chained).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            "the file ends before the elements its header announces (truncated?)".to_string()
        } else {
            one_line(&e.to_string())
        }
    })?;
    let scalar = |p: &Property| -> Option<f64> {
        Some(match *p {
            Property::Char(v) => f64::from(v),
            Property::UChar(v) => f64::from(v),
            Property::Short(v) => f64::from(v),
            Property::UShort(v) => f64::from(v),
            Property::Int(v) => f64::from(v),
            Property::UInt(v) => f64::from(v),
            Property::Float(v) => f64::from(v),
            Property::Double(v) => v,
            _ => return None,
        })
    };
    let index_list = |p: &Property| -> Option<Vec<i64>> {
        Some(match p {
            Property::ListChar(v) => v.iter().map(|&x| i64::from(x)).collect(),
            Property::ListUChar(v) => v.iter().map(|&x| i64::from(x)).collect(),
            Property::ListShort(v) => v.iter().map(|&x| i64::from(x)).collect(),
            Property::ListUShort(v) => v.iter().map(|&x| i64::from(x)).collect(),
            Property::ListInt(v) => v.iter().map(|&x| i64::from(x)).collect(),
            Property::ListUInt(v) => v.iter().map(|&x| i64::from(x)).collect(),
            _ => return None,
        })
    };
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or_else(|| "no `vertex` element".to_string())?;
    let mut raw = Raw {
        positions: Vec::with_capacity(vertices.len()),
        ..Raw::default()
    };
    // Per-vertex texture coordinates under any of their usual names.
    let uv_names = [("u", "v"), ("s", "t"), ("texture_u", "texture_v")];
    let mut vertex_uvs: Vec<Option<[f64; 2]>> = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let mut c = [0.0; 3];
        for (slot, axis) in c.iter_mut().zip(["x", "y", "z"]) {
            *slot = v
                .get(axis)
                .and_then(scalar)
                .ok_or_else(|| format!("vertex {i} (0-based) has no numeric property `{axis}`"))?;
        }
        raw.positions.push(Vector3::new(c[0], c[1], c[2]));
        vertex_uvs.push(
            uv_names.iter().find_map(|(a, b)| {
                Some([v.get(*a).and_then(scalar)?, v.get(*b).and_then(scalar)?])
            }),
        );
    }
    let float_list = |p: &Property| -> Option<Vec<f64>> {
        Some(match p {
            Property::ListFloat(v) => v.iter().map(|&x| f64::from(x)).collect(),
            Property::ListDouble(v) => v.clone(),
            _ => return None,
        })
    };
    if let Some(faces) = ply.payload.get("face") {
        raw.faces.reserve(faces.len());
        for (f, e) in faces.iter().enumerate() {
            let list = e
                .get("vertex_indices")
                .or_else(|| e.get("vertex_index"))
                .and_then(index_list)
                .ok_or_else(|| {
                    format!("face {f} (0-based) has no integer list `vertex_indices`")
                })?;
            if list.len() < 3 {
                return Err(format!(
                    "face {f} (0-based) has {} corners (at least 3 are needed)",
                    list.len()
                ));
            }
            let mut poly = Vec::with_capacity(list.len());
            for i in list {
                poly.push(usize::try_from(i).map_err(|_| {
                    format!("face {f} (0-based) names the negative vertex index {i}")
                })?);
            }
            // Corner texture coordinates (`texcoord`, u v per corner, as MeshLab writes them), else the
            // vertices' own.
            let uv = match e.get("texcoord").and_then(float_list) {
                Some(t) if t.len() == 2 * poly.len() => {
                    Some(t.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
                }
                Some(t) => {
                    return Err(format!(
                        "face {f} (0-based) has {} `texcoord` values for {} corners (2 per corner)",
                        t.len(),
                        poly.len()
                    ));
                }
                None => poly
                    .iter()
                    .map(|&v| vertex_uvs.get(v).copied().flatten())
                    .collect::<Option<Vec<_>>>(),
            };
            raw.faces.push(poly);
            raw.face_uvs.push(uv);
        }
    }
    Ok(raw)
}

/// A message on one line: whitespace runs (newlines, tabs) collapsed, at most 200 characters.
fn one_line(message: &str) -> String {
    let joined = message.split_whitespace().collect::<Vec<_>>().join(" ");
    match joined.char_indices().nth(200) {
        Some((cut, _)) => format!("{}…", &joined[..cut]),
        None => joined,
    }
}

/// Reads up to `buf.len()` bytes (fewer only at the end of the input).
fn read_up_to(reader: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match reader.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

/// The byte order of a binary PLY file written by [`write_ply_to`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyEncoding {
    /// `format ascii 1.0`, coordinates with 17 significant digits.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
    /// `format binary_big_endian 1.0`.
    BinaryBigEndian,
}

/// Writes a PLY file: `double` x, y, z per vertex and a `uchar`/`int` list per face.
///
/// # Errors
/// The writer's I/O error.
pub fn write_ply_to(
    mut out: impl Write,
    positions: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    encoding: PlyEncoding,
) -> std::io::Result<()> {
    let format = match encoding {
        PlyEncoding::Ascii => "ascii",
        PlyEncoding::BinaryLittleEndian => "binary_little_endian",
        PlyEncoding::BinaryBigEndian => "binary_big_endian",
    };
    write!(
        out,
        "ply\nformat {format} 1.0\ncomment written by hinge\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        positions.len(),
        triangles.len()
    )?;
    let index = |i: usize| {
        i32::try_from(i).map_err(|_| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("vertex index {i} does not fit a PLY int"),
            )
        })
    };
    match encoding {
        PlyEncoding::Ascii => {
            for p in positions {
                writeln!(out, "{:.17e} {:.17e} {:.17e}", p.x, p.y, p.z)?;
            }
            for t in triangles {
                writeln!(out, "3 {} {} {}", index(t[0])?, index(t[1])?, index(t[2])?)?;
            }
        }
        PlyEncoding::BinaryLittleEndian | PlyEncoding::BinaryBigEndian => {
            let le = encoding == PlyEncoding::BinaryLittleEndian;
            let f = |v: f64| if le { v.to_le_bytes() } else { v.to_be_bytes() };
            let i = |v: i32| if le { v.to_le_bytes() } else { v.to_be_bytes() };
            for p in positions {
                out.write_all(&f(p.x))?;
                out.write_all(&f(p.y))?;
                out.write_all(&f(p.z))?;
            }
            for t in triangles {
                out.write_all(&[3])?;
                for &c in t {
                    out.write_all(&i(index(c)?))?;
                }
            }
        }
    }
    out.flush()
}

/// Writes an OFF file (coordinates with 17 significant digits).
///
/// # Errors
/// The writer's I/O error.
pub fn write_off_to(
    mut out: impl Write,
    positions: &[Vector3<f64>],
    triangles: &[[usize; 3]],
) -> std::io::Result<()> {
    writeln!(out, "OFF\n{} {} 0", positions.len(), triangles.len())?;
    for p in positions {
        writeln!(out, "{:.17e} {:.17e} {:.17e}", p.x, p.y, p.z)?;
    }
    for t in triangles {
        writeln!(out, "3 {} {} {}", t[0], t[1], t[2])?;
    }
    out.flush()
}

/// Writes a mesh (or a deformed state of it) in the format of `path`'s extension: OBJ, OFF, binary
/// little-endian PLY, or binary STL (single precision, and its vertices only as corners: read back, vertices
/// are renumbered in order of first appearance).
///
/// # Errors
/// [`MeshFileError::UnknownExtension`] or [`MeshFileError::Io`].
pub fn write_mesh(
    path: impl AsRef<Path>,
    positions: &[Vector3<f64>],
    triangles: &[[usize; 3]],
) -> Result<(), MeshFileError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let format = MeshFormat::from_path(path)
        .ok_or_else(|| MeshFileError::UnknownExtension { path: name.clone() })?;
    let io = |source| MeshFileError::Io {
        path: name.clone(),
        source,
    };
    let out = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    match format {
        MeshFormat::Obj => crate::obj::write_obj_to(out, positions, triangles),
        MeshFormat::Off => write_off_to(out, positions, triangles),
        MeshFormat::Ply => write_ply_to(out, positions, triangles, PlyEncoding::BinaryLittleEndian),
        MeshFormat::Stl => write_stl_to(out, positions, triangles),
    }
    .map_err(io)
}
