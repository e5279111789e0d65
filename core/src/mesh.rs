//! Triangle meshes: positions plus counter-clockwise vertex triples, validated on construction.

use nalgebra::Vector3;

use crate::error::MeshError;

pub use crate::geometry::DEGENERACY_TOLERANCE;

/// A triangle mesh: vertex positions and triangles given as counter-clockwise vertex triples.
///
/// [`TriMesh::new`] checks everything that does not depend on connectivity (indices, repeated vertices,
/// finite coordinates, non-zero areas); [`crate::Topology::new`] checks the rest (manifold edges,
/// consistent orientation).
#[derive(Debug, Clone, PartialEq)]
pub struct TriMesh {
    positions: Vec<Vector3<f64>>,
    triangles: Vec<[usize; 3]>,
}

impl TriMesh {
    /// Builds and validates a mesh.
    ///
    /// # Errors
    /// [`MeshError::Empty`], [`MeshError::IndexOutOfRange`], [`MeshError::RepeatedVertex`],
    /// [`MeshError::NonFiniteCoordinate`] or [`MeshError::ZeroAreaTriangle`], naming the first offending
    /// element.
    pub fn new(
        positions: Vec<Vector3<f64>>,
        triangles: Vec<[usize; 3]>,
    ) -> Result<Self, MeshError> {
        validate_triangles(positions.len(), &triangles)?;
        validate_positions(&positions)?;
        for (t, tri) in triangles.iter().enumerate() {
            let p = [positions[tri[0]], positions[tri[1]], positions[tri[2]]];
            if is_degenerate(&p) {
                // Finite coordinates whose edge cross product overflows: not flat, too large.
                if !(p[1] - p[0])
                    .cross(&(p[2] - p[0]))
                    .norm_squared()
                    .is_finite()
                {
                    return Err(MeshError::TriangleTooLarge {
                        triangle: t,
                        vertices: *tri,
                    });
                }
                return Err(MeshError::ZeroAreaTriangle {
                    triangle: t,
                    vertices: *tri,
                });
            }
        }
        Ok(Self {
            positions,
            triangles,
        })
    }

    /// Builds a mesh from flat arrays: `3n` coordinates and triangles as `[u32; 3]`.
    ///
    /// # Errors
    /// As [`TriMesh::new`], and [`MeshError::FlatLength`] when the coordinate count is not a multiple of 3.
    pub fn from_flat(coordinates: &[f64], triangles: &[[u32; 3]]) -> Result<Self, MeshError> {
        if !coordinates.len().is_multiple_of(3) {
            return Err(MeshError::FlatLength {
                len: coordinates.len(),
            });
        }
        let positions = coordinates
            .chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect();
        let triangles = triangles
            .iter()
            .map(|t| [t[0] as usize, t[1] as usize, t[2] as usize])
            .collect();
        Self::new(positions, triangles)
    }

    /// Builds a mesh from the caller's arrays: positions as `&[f64]`, `&[[f64; 3]]` or `&[Vector3<f64>]`,
    /// triangles as `&[[u32; 3]]` or `&[[usize; 3]]` (see [`crate::layout`]).
    ///
    /// # Errors
    /// As [`TriMesh::new`], and [`MeshError::FlatLength`] for a flat array whose length is not a multiple
    /// of 3.
    pub fn from_arrays<P, T>(positions: &P, triangles: &T) -> Result<Self, MeshError>
    where
        P: crate::layout::Positions + ?Sized,
        T: crate::layout::Triangles + ?Sized,
    {
        Self::new(positions.as_vectors()?.to_vec(), triangles.to_usize())
    }

    /// Vertex positions.
    pub fn positions(&self) -> &[Vector3<f64>] {
        &self.positions
    }

    /// Triangles, each counter-clockwise about its normal.
    pub fn triangles(&self) -> &[[usize; 3]] {
        &self.triangles
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.positions.len()
    }

    /// The vertices that belong to no triangle, ascending (files from modelling tools often keep some
    /// after faces were deleted). No energy of the mesh acts on them and they carry no lumped mass, so the
    /// solvers of the command line and the Python package hold them where they are.
    pub fn unreferenced_vertices(&self) -> Vec<usize> {
        let used = self.vertices_in_faces();
        (0..used.len()).filter(|&v| !used[v]).collect()
    }

    /// For each vertex, whether some triangle has it as a corner.
    pub fn vertices_in_faces(&self) -> Vec<bool> {
        let mut used = vec![false; self.positions.len()];
        for t in &self.triangles {
            for &v in t {
                used[v] = true;
            }
        }
        used
    }

    /// Vertices of faces at exactly the position of a lower-numbered vertex of a face, as `(vertex, first)`
    /// pairs ascending by `vertex` (`first` is the lowest-numbered vertex at that position). Exporters split
    /// vertices along UV seams and hard edges this way: nothing couples the two copies, so the surface is cut
    /// there (no hinge, no shared membrane edge). Vertices in no face are left out.
    pub fn coincident_vertices(&self) -> Vec<(usize, usize)> {
        let used = self.vertices_in_faces();
        let key = |v: usize| {
            let p = &self.positions[v];
            // +0.0 and -0.0 are the same position.
            [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits())
        };
        let mut order: Vec<usize> = (0..self.positions.len()).filter(|&v| used[v]).collect();
        order.sort_unstable_by_key(|&v| (key(v), v));
        let mut pairs = Vec::new();
        for group in order.chunk_by(|&a, &b| key(a) == key(b)) {
            if let Some((&first, rest)) = group.split_first() {
                pairs.extend(rest.iter().map(|&v| (v, first)));
            }
        }
        pairs.sort_unstable();
        pairs
    }

    /// Number of triangles.
    pub fn n_triangles(&self) -> usize {
        self.triangles.len()
    }

    /// The same connectivity with other positions (for example a deformed state), validated like
    /// [`TriMesh::new`] plus a vertex-count check.
    ///
    /// # Errors
    /// [`MeshError::VertexCountMismatch`] when the counts differ, otherwise as [`TriMesh::new`].
    pub fn with_positions(&self, positions: Vec<Vector3<f64>>) -> Result<Self, MeshError> {
        check_same_vertex_count(self.n_vertices(), positions.len())?;
        Self::new(positions, self.triangles.clone())
    }

    /// Consumes the mesh, returning positions and triangles.
    pub fn into_parts(self) -> (Vec<Vector3<f64>>, Vec<[usize; 3]>) {
        (self.positions, self.triangles)
    }
}

/// [`MeshError::VertexCountMismatch`] unless `deformed == rest`.
pub fn check_same_vertex_count(rest: usize, deformed: usize) -> Result<(), MeshError> {
    if rest == deformed {
        Ok(())
    } else {
        Err(MeshError::VertexCountMismatch { rest, deformed })
    }
}

/// Checks that positions are finite, naming the first offending vertex and axis.
///
/// # Errors
/// [`MeshError::NonFiniteCoordinate`].
pub fn validate_positions(positions: &[Vector3<f64>]) -> Result<(), MeshError> {
    for (v, p) in positions.iter().enumerate() {
        for axis in 0..3 {
            if !p[axis].is_finite() {
                return Err(MeshError::NonFiniteCoordinate {
                    vertex: v,
                    axis,
                    value: p[axis],
                });
            }
        }
    }
    Ok(())
}

/// Checks the purely combinatorial conditions on a triangle list: non-empty, indices in range, no repeated
/// vertex within a triangle.
///
/// # Errors
/// [`MeshError::Empty`], [`MeshError::IndexOutOfRange`] or [`MeshError::RepeatedVertex`].
pub fn validate_triangles(n_vertices: usize, triangles: &[[usize; 3]]) -> Result<(), MeshError> {
    if n_vertices == 0 || triangles.is_empty() {
        return Err(MeshError::Empty {
            vertices: n_vertices,
            triangles: triangles.len(),
        });
    }
    for (t, tri) in triangles.iter().enumerate() {
        for (corner, &index) in tri.iter().enumerate() {
            if index >= n_vertices {
                return Err(MeshError::IndexOutOfRange {
                    triangle: t,
                    corner,
                    index,
                    n_vertices,
                });
            }
        }
        for k in 0..3 {
            if tri[k] == tri[(k + 1) % 3] {
                return Err(MeshError::RepeatedVertex {
                    triangle: t,
                    vertex: tri[k],
                });
            }
        }
    }
    Ok(())
}

/// Whether a triangle's smallest altitude is below [`DEGENERACY_TOLERANCE`] times its longest edge.
/// The same test as [`crate::geometry::TriangleFrame::new`], so a mesh accepted here never fails there at rest.
pub fn is_degenerate(p: &[Vector3<f64>; 3]) -> bool {
    crate::geometry::TriangleFrame::new(&p[0], &p[1], &p[2]).is_err()
}
