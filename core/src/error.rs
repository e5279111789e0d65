//! Typed errors. Every variant names the offending element (vertex, triangle, edge or hinge) so a caller can
//! point at it; none of them is ever replaced by a NaN or a panic.

use thiserror::Error;

/// Invalid mesh input: raised when a [`crate::TriMesh`] or a [`crate::Topology`] is built, or when a deformed
/// state is paired with a rest mesh.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The mesh has no vertices or no triangles.
    #[error(
        "empty mesh: {vertices} vertices and {triangles} triangles (at least one triangle is needed)"
    )]
    Empty {
        /// Number of vertices given.
        vertices: usize,
        /// Number of triangles given.
        triangles: usize,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error(
        "triangle {triangle}: corner {corner} refers to vertex {index}, but the mesh has {n_vertices} vertices"
    )]
    IndexOutOfRange {
        /// Triangle index.
        triangle: usize,
        /// Corner (0, 1 or 2) of the triangle.
        corner: usize,
        /// The offending vertex index.
        index: usize,
        /// Number of vertices of the mesh.
        n_vertices: usize,
    },
    /// A triangle lists the same vertex twice.
    #[error("triangle {triangle}: vertex {vertex} appears more than once")]
    RepeatedVertex {
        /// Triangle index.
        triangle: usize,
        /// The repeated vertex.
        vertex: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("vertex {vertex}: coordinate {axis} is not finite ({value})")]
    NonFiniteCoordinate {
        /// Vertex index.
        vertex: usize,
        /// Axis 0 (x), 1 (y) or 2 (z).
        axis: usize,
        /// The offending value.
        value: f64,
    },
    /// A triangle of the rest shape has (numerically) zero area: its vertices are colinear.
    #[error("triangle {triangle} (vertices {vertices:?}) has zero area")]
    ZeroAreaTriangle {
        /// Triangle index.
        triangle: usize,
        /// Its three vertices.
        vertices: [usize; 3],
    },
    /// A triangle of the rest shape so large that its area is not representable (the cross product of its
    /// edges overflows f64: coordinates beyond about 1e77).
    #[error(
        "triangle {triangle} (vertices {vertices:?}) is too large: its area overflows f64 (rescale the mesh)"
    )]
    TriangleTooLarge {
        /// Triangle index.
        triangle: usize,
        /// Its three vertices.
        vertices: [usize; 3],
    },
    /// An edge is shared by three or more triangles.
    #[error("edge ({}, {}) is shared by {count} triangles (the first three are {triangles:?}); a manifold edge has at most two", edge[0], edge[1])]
    NonManifoldEdge {
        /// The edge's two vertices, smaller index first.
        edge: [usize; 2],
        /// How many triangles share it.
        count: usize,
        /// The first three of them.
        triangles: [usize; 3],
    },
    /// Two triangles traverse their shared edge in the same direction.
    #[error("triangles {} and {} traverse edge ({}, {}) in the same direction: the orientation is inconsistent", triangles[0], triangles[1], edge[0], edge[1])]
    InconsistentOrientation {
        /// The edge's two vertices, smaller index first.
        edge: [usize; 2],
        /// The two triangles.
        triangles: [usize; 2],
    },
    /// Two triangles have the same three vertices.
    #[error("triangles {} and {} have the same three vertices", triangles[0], triangles[1])]
    DuplicateTriangle {
        /// The two triangles.
        triangles: [usize; 2],
    },
    /// A flat coordinate array whose length is not a multiple of 3.
    #[error("a flat coordinate array has length {len}, which is not a multiple of 3")]
    FlatLength {
        /// Its length.
        len: usize,
    },
    /// A generated mesh (grid, icosphere, torus, sheet) too large to build: its vertex count exceeds the
    /// engine's 32-bit range (the Hessian pattern numbers vertices and values in 32 bits), or its
    /// vertices and triangles cannot be allocated.
    #[error(
        "a generated mesh of {vertices} vertices and {triangles} triangles is too large: {reason}"
    )]
    TooLarge {
        /// Its vertex count (saturating at `u64::MAX`).
        vertices: u64,
        /// Its triangle count (saturating at `u64::MAX`).
        triangles: u64,
        /// Why.
        reason: &'static str,
    },
    /// A deformed state does not have as many vertices as the rest mesh.
    #[error("the rest mesh has {rest} vertices but the deformed state has {deformed}")]
    VertexCountMismatch {
        /// Vertices of the rest mesh.
        rest: usize,
        /// Vertices of the deformed state.
        deformed: usize,
    },
}

/// Which triangle of a hinge an error refers to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HingeSide {
    /// T = (x0, x1, x2).
    Upper,
    /// T̃ = (x3, x2, x1).
    Lower,
}

impl std::fmt::Display for HingeSide {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            HingeSide::Upper => "upper triangle (x0, x1, x2)",
            HingeSide::Lower => "lower triangle (x3, x2, x1)",
        })
    }
}

/// A stencil on which the hinge-angle formulas are undefined (they would divide by zero).
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum StencilError {
    /// A coordinate of the stencil is NaN or infinite.
    #[error("stencil coordinate {coordinate} is not finite")]
    NonFinite {
        /// Index 0..12 of the coordinate (3·vertex + axis).
        coordinate: usize,
    },
    /// The shared hinge edge x1–x2 has (numerically) zero length.
    #[error("the hinge edge x1-x2 has zero length ({length:e})")]
    ZeroLengthHingeEdge {
        /// Its length.
        length: f64,
    },
    /// The stencil's size (its largest coordinate difference) is outside
    /// [`crate::hinge::STENCIL_SIZE_RANGE`]: its squared lengths and areas would leave double precision's
    /// range, and a sound stencil would be reported as degenerate. Reported only where a check failed.
    #[error(
        "the stencil's size {size:e} (its largest coordinate difference) is outside the range the hinge formulas evaluate in double precision, 1e-60 to 1e60: rescale the mesh"
    )]
    OutOfRange {
        /// Its largest coordinate difference.
        size: f64,
    },
    /// A triangle's vertex lies on the line of its opposite edge: its altitude, and the normal, are undefined.
    #[error(
        "altitude collapse in the {side}: stencil vertex x{vertex} is colinear with its opposite edge (relative altitude {relative_altitude:e})"
    )]
    AltitudeCollapse {
        /// Which triangle.
        side: HingeSide,
        /// The stencil vertex (0..4) whose altitude collapsed.
        vertex: usize,
        /// Smallest altitude over longest edge.
        relative_altitude: f64,
    },
}

/// A triangle on which per-triangle quantities are undefined.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[error(
    "altitude collapse: corner {corner} is colinear with its opposite edge (relative altitude {relative_altitude:e})"
)]
pub struct DegenerateTriangle {
    /// The corner (0, 1 or 2) with the smallest altitude.
    pub corner: usize,
    /// Smallest altitude over longest edge.
    pub relative_altitude: f64,
}

/// An evaluation on a whole mesh failed at a named element.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum EvalError {
    /// The deformed state is not valid for the rest mesh.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// A hinge stencil is degenerate in the deformed state.
    #[error("hinge {hinge} (edge {edge}, vertices {vertices:?}): {source}")]
    Hinge {
        /// Hinge index.
        hinge: usize,
        /// Edge index.
        edge: usize,
        /// The stencil's global vertices x0, x1, x2, x3.
        vertices: [usize; 4],
        /// What went wrong.
        source: StencilError,
    },
    /// A triangle of a hinge energy is degenerate in the deformed state (the triangle pass of the refactored
    /// Hessian and the per-hinge kernels share the hinge pass's decision, so this names the triangle a pass
    /// would otherwise have had to skip).
    #[error("triangle {triangle} (vertices {vertices:?}): {source}")]
    Triangle {
        /// Triangle index in the mesh.
        triangle: usize,
        /// Its vertices, in the mesh's corner order.
        vertices: [usize; 3],
        /// What went wrong (the corner is in the mesh's corner order).
        source: DegenerateTriangle,
    },
    /// An energy's set-up cannot be used (a negative mass, a non-finite stiffness or margin); an error at a
    /// mesh element (a vertex, an edge, a triangle) is [`EvalError::AtElement`].
    #[error("{element}: {message}")]
    Element {
        /// What is named (for example `contact`, `gravity`).
        element: String,
        /// What is wrong.
        message: String,
    },
    /// An element of some energy (a contact at a vertex, a spring on an edge, a membrane triangle) cannot be
    /// evaluated, named by its vertices and triangle in the mesh's numbering ([`EvalError::describe`] tells
    /// it in another, such as a mesh file's).
    #[error("{energy}, {element}: {message}")]
    AtElement {
        /// The energy's name (`contact`, `mass-spring`, `membrane`, …).
        energy: String,
        /// The element.
        element: ElementRef,
        /// What is wrong.
        message: String,
    },
    /// An energy's output is not finite and no single element is to blame (its total, or the sum of the
    /// terms, overflowed): [`crate::energy::System::check_finite`].
    #[error("{energy}: {message}")]
    NonFiniteTotal {
        /// The energy's name, or `the system`.
        energy: String,
        /// What is not finite.
        message: String,
    },
    /// An energy cannot be bound to a sparsity pattern.
    #[error("sparsity pattern: {message}")]
    Pattern {
        /// What does not fit.
        message: String,
    },
    /// A time step that is not positive and finite.
    #[error("time step dt = {dt} must be positive and finite")]
    Step {
        /// The offending step.
        dt: f64,
    },
    /// The energy's parameters do not fit the mesh.
    #[error(transparent)]
    Psi(#[from] crate::psi::PsiError),
    /// A parameter asked for by name (fitting, sensitivities) that the energy or system does not have, or
    /// cannot differentiate with respect to, or a value of the wrong length for it.
    #[error("parameter `{name}`: {message}")]
    Parameter {
        /// The parameter as named by the caller.
        name: String,
        /// What is wrong (for an unknown name, the names there are).
        message: String,
    },
    /// An output buffer does not have the length this model needs.
    #[error("output buffer `{buffer}` has length {got}, expected {expected}")]
    BufferLength {
        /// Which buffer.
        buffer: &'static str,
        /// Length needed.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// ψ, ψ′ or ψ″ is not finite at a hinge (for example the tan energy at θ = ±π).
    #[error("hinge {hinge} (vertices {vertices:?}): the energy is not finite at θ = {theta}")]
    NonFiniteEnergy {
        /// Hinge index.
        hinge: usize,
        /// The stencil's global vertices x0, x1, x2, x3.
        vertices: [usize; 4],
        /// The hinge angle there.
        theta: f64,
    },
}

/// A mesh element an error is about, in the mesh's own numbering (vertices and triangles from 0, in the order
/// they were given).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ElementRef {
    /// A vertex.
    Vertex(usize),
    /// An edge (a spring), by its two vertices.
    Edge([usize; 2]),
    /// A triangle.
    Triangle {
        /// Its index.
        triangle: usize,
        /// Its vertices, in its corner order.
        vertices: [usize; 3],
    },
}

impl std::fmt::Display for ElementRef {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ElementRef::Vertex(v) => write!(f, "vertex {v}"),
            ElementRef::Edge([a, b]) => write!(f, "edge ({a}, {b})"),
            ElementRef::Triangle { triangle, vertices } => write!(
                f,
                "triangle {triangle} (vertices {}, {}, {})",
                vertices[0], vertices[1], vertices[2]
            ),
        }
    }
}

/// How a caller counts a mesh's vertices and triangles, for [`EvalError::describe`]: a mesh file's numbering
/// (`hinge_core::meshio::FileNumbering`: OBJ from 1 with line numbers), or your own.
pub trait ElementNames {
    /// Vertex `v` (0-based in the mesh) named in full, for example `vertex 5 (line 5)`.
    fn vertex(&self, v: usize) -> String;
    /// Vertex `v`'s number alone, for lists (`vertices 5, 6, 9`).
    fn vertex_number(&self, v: usize) -> String;
    /// Triangle `t` (0-based in the mesh) named in full, for example `face 3 (line 9)`.
    fn triangle(&self, t: usize) -> String;
}

impl EvalError {
    /// The message with every vertex and triangle named by `names` instead of by the mesh's 0-based numbers
    /// (what the `Display` form says). Hinges are named by their vertices (a hinge's own index is internal
    /// to the topology): the edge x1–x2 and the wing vertices x0, x3.
    pub fn describe(&self, names: &dyn ElementNames) -> String {
        let list = |vs: &[usize]| {
            vs.iter()
                .map(|&v| names.vertex_number(v))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let hinge = |v: &[usize; 4]| {
            format!(
                "the hinge on the edge between vertices {} and {} (wing vertices {} and {})",
                names.vertex_number(v[1]),
                names.vertex_number(v[2]),
                names.vertex_number(v[0]),
                names.vertex_number(v[3])
            )
        };
        match self {
            EvalError::Mesh(MeshError::NonFiniteCoordinate {
                vertex,
                axis,
                value,
            }) => format!(
                "{}: coordinate {} is not finite ({value})",
                names.vertex(*vertex),
                ["x", "y", "z"].get(*axis).copied().unwrap_or("?")
            ),
            EvalError::Hinge {
                vertices, source, ..
            } => format!("{}: {source}", hinge(vertices)),
            EvalError::NonFiniteEnergy {
                vertices, theta, ..
            } => format!(
                "{}: the energy is not finite at θ = {theta}",
                hinge(vertices)
            ),
            EvalError::Triangle {
                triangle,
                vertices,
                source,
            } => format!(
                "{} (vertices {}): {source}",
                names.triangle(*triangle),
                list(vertices)
            ),
            EvalError::AtElement {
                energy,
                element,
                message,
            } => {
                let at = match element {
                    ElementRef::Vertex(v) => names.vertex(*v),
                    ElementRef::Edge(e) => format!(
                        "the edge between vertices {}",
                        list(e).replace(", ", " and ")
                    ),
                    ElementRef::Triangle { triangle, vertices } => format!(
                        "{} (vertices {})",
                        names.triangle(*triangle),
                        list(vertices)
                    ),
                };
                format!("{energy}, {at}: {message}")
            }
            other => other.to_string(),
        }
    }
}

/// Reading or writing a Wavefront OBJ file failed.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ObjError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line could not be parsed.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file (or `<reader>`).
        path: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The file parsed, but the mesh it describes is invalid.
    #[error("{path}: {source}")]
    Mesh {
        /// The file.
        path: String,
        /// The mesh error.
        source: MeshError,
    },
}

/// A number as messages print it: Rust's shortest round-trip form where that is short (zero, or
/// `1e-5 ≤ |v| < 1e16`), scientific notation otherwise — `1e308`, not 309 digits, and `1e-300`, not 301
/// zeros. `NaN` and `inf` as Rust prints them.
///
/// ```
/// use hinge_core::error::Num;
/// assert_eq!(Num(0.25).to_string(), "0.25");
/// assert_eq!(Num(-1e308).to_string(), "-1e308");
/// assert_eq!(Num(18446744073709551616.0).to_string(), "1.8446744073709552e19");
/// assert_eq!(Num(1e-12).to_string(), "1e-12");
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.0.abs();
        if a == 0.0 || !a.is_finite() || (1e-5..1e16).contains(&a) {
            write!(f, "{}", self.0)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}
