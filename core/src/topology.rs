//! Mesh connectivity: edges, σ (interior) flags and hinges, built once by sorting edge triples.
//!
//! # Construction (lecture notes P9)
//! Every triangle `t = (v0, v1, v2)` contributes three triples `(min(a, b), max(a, b), t)`, one per edge
//! `k`, where edge `k` is the one **opposite** corner `k` and runs from `v[k+1]` to `v[k+2]` in the
//! triangle's counter-clockwise order. Sorting the triples brings the (one or two) triangles of each edge
//! together; a run of one triple is a boundary edge (σ = 0), a run of two an interior edge (σ = 1), and a
//! longer run a non-manifold edge, which is an error. The two triangles of an interior edge must traverse it
//! in opposite directions (consistent orientation).
//!
//! # Hinge labelling
//! Every interior edge is a hinge with four stencil vertices `x0, x1, x2, x3`:
//!
//! ```text
//!            x0
//!           /  \
//!          /  T \            T  = (x0, x1, x2), counter-clockwise about n
//!        x1 ---- x2          T̃ = (x3, x2, x1), counter-clockwise about ñ
//!          \  T̃ /            hinge edge e0 = x2 − x1
//!           \  /
//!            x3
//! ```
//!
//! `T` is the triangle in whose counter-clockwise order the edge runs from its smaller to its larger global
//! vertex index (so `x1 < x2` as global indices); `T̃` is the other one. This is also the rule for the
//! conditional transpose of the triangle-refactored Hessian: it applies in exactly one triangle of every
//! interior edge.
//!
//! # Hinge order
//! Edges are numbered in increasing `(min, max)` order of their two vertex indices (the caller's
//! numbering), and hinges in the order of their edges: hinge `h` is the `h`-th interior edge in that order.
//! Every per-hinge array — `#[per_hinge]` fields, run-time ψ parameters, rest angles — is in this order.
//! [`hinges`] gives the list from a mesh before any model is built.

use crate::error::MeshError;
use crate::mesh::validate_triangles;

/// The hinges of a mesh, in hinge order (see the module documentation): what per-hinge arrays are indexed
/// by, available before a model is built.
///
/// # Errors
/// The combinatorial [`MeshError`]s of [`Topology::new`].
pub fn hinges(mesh: &crate::mesh::TriMesh) -> Result<Vec<Hinge>, MeshError> {
    Ok(Topology::new(mesh.n_vertices(), mesh.triangles())?.hinges)
}

/// Sentinel for "no triangle" on the second side of a boundary edge.
pub const NO_TRIANGLE: usize = usize::MAX;

/// One mesh edge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Edge {
    /// Its two vertices, smaller index first.
    pub vertices: [usize; 2],
    /// The incident triangles; `triangles[1] == NO_TRIANGLE` on the boundary. For an interior edge,
    /// `triangles[0]` is the hinge's upper triangle T (the one that traverses the edge from smaller to larger
    /// index).
    pub triangles: [usize; 2],
    /// For each incident triangle, the corner opposite this edge (0, 1 or 2).
    pub opposite_corner: [u8; 2],
}

impl Edge {
    /// σ: whether the edge is interior (shared by two triangles).
    pub fn is_interior(&self) -> bool {
        self.triangles[1] != NO_TRIANGLE
    }
}

/// One hinge: an interior edge with its four stencil vertices, labelled as in the module docs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Hinge {
    /// The edge this hinge sits on.
    pub edge: usize,
    /// Global indices of x0, x1, x2, x3.
    pub vertices: [usize; 4],
    /// The upper triangle T = (x0, x1, x2) and the lower triangle T̃ = (x3, x2, x1).
    pub triangles: [usize; 2],
}

/// Connectivity of a triangle mesh, built once.
#[derive(Debug, Clone)]
pub struct Topology {
    n_vertices: usize,
    triangles: Vec<[usize; 3]>,
    edges: Vec<Edge>,
    triangle_edges: Vec<[usize; 3]>,
    forward: Vec<u8>,
    hinges: Vec<Hinge>,
    edge_hinge: Vec<usize>,
}

impl Topology {
    /// Builds the topology of `triangles` over `n_vertices` vertices.
    ///
    /// # Errors
    /// The combinatorial [`MeshError`]s: empty mesh, index out of range, repeated vertex, non-manifold edge,
    /// inconsistent orientation, duplicate triangle. Never panics, whatever the input.
    pub fn new(n_vertices: usize, triangles: &[[usize; 3]]) -> Result<Self, MeshError> {
        validate_triangles(n_vertices, triangles)?;
        let n_tri = triangles.len();
        // (min, max, triangle, corner opposite the edge)
        let mut triples: Vec<(usize, usize, usize, u8)> = Vec::with_capacity(3 * n_tri);
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                let a = tri[(k + 1) % 3];
                let b = tri[(k + 2) % 3];
                triples.push((a.min(b), a.max(b), t, k as u8));
            }
        }
        triples.sort_unstable();

        let mut edges = Vec::with_capacity(3 * n_tri / 2 + 1);
        let mut triangle_edges = vec![[0usize; 3]; n_tri];
        let mut forward = vec![0u8; n_tri];
        let mut start = 0;
        while start < triples.len() {
            let (lo, hi, t0, k0) = triples[start];
            let mut end = start + 1;
            while end < triples.len() && triples[end].0 == lo && triples[end].1 == hi {
                end += 1;
            }
            let run = &triples[start..end];
            let id = edges.len();
            // Whether triangle t traverses the edge from lo to hi in its CCW order.
            let runs_forward = |t: usize, k: u8| triangles[t][(k as usize + 1) % 3] == lo;
            let edge = match run.len() {
                1 => Edge {
                    vertices: [lo, hi],
                    triangles: [t0, NO_TRIANGLE],
                    opposite_corner: [k0, 0],
                },
                2 => {
                    let (_, _, t1, k1) = run[1];
                    let f0 = runs_forward(t0, k0);
                    let f1 = runs_forward(t1, k1);
                    if f0 == f1 {
                        let opp0 = triangles[t0][k0 as usize];
                        let opp1 = triangles[t1][k1 as usize];
                        return Err(if opp0 == opp1 {
                            MeshError::DuplicateTriangle {
                                triangles: [t0, t1],
                            }
                        } else {
                            MeshError::InconsistentOrientation {
                                edge: [lo, hi],
                                triangles: [t0, t1],
                            }
                        });
                    }
                    let opp0 = triangles[t0][k0 as usize];
                    let opp1 = triangles[t1][k1 as usize];
                    if opp0 == opp1 {
                        return Err(MeshError::DuplicateTriangle {
                            triangles: [t0, t1],
                        });
                    }
                    // The upper triangle T traverses the edge forward (lo -> hi).
                    if f0 {
                        Edge {
                            vertices: [lo, hi],
                            triangles: [t0, t1],
                            opposite_corner: [k0, k1],
                        }
                    } else {
                        Edge {
                            vertices: [lo, hi],
                            triangles: [t1, t0],
                            opposite_corner: [k1, k0],
                        }
                    }
                }
                count => {
                    return Err(MeshError::NonManifoldEdge {
                        edge: [lo, hi],
                        count,
                        triangles: [run[0].2, run[1].2, run[2].2],
                    });
                }
            };
            for &(_, _, t, k) in run {
                triangle_edges[t][k as usize] = id;
                if runs_forward(t, k) {
                    forward[t] |= 1 << k;
                }
            }
            edges.push(edge);
            start = end;
        }

        let mut hinges = Vec::new();
        let mut edge_hinge = vec![usize::MAX; edges.len()];
        for (id, e) in edges.iter().enumerate() {
            if !e.is_interior() {
                continue;
            }
            let [tu, tl] = e.triangles;
            let [ku, kl] = e.opposite_corner;
            edge_hinge[id] = hinges.len();
            hinges.push(Hinge {
                edge: id,
                vertices: [
                    triangles[tu][ku as usize],
                    e.vertices[0],
                    e.vertices[1],
                    triangles[tl][kl as usize],
                ],
                triangles: [tu, tl],
            });
        }

        Ok(Self {
            n_vertices,
            triangles: triangles.to_vec(),
            edges,
            triangle_edges,
            forward,
            hinges,
            edge_hinge,
        })
    }

    /// Number of vertices the topology was built for.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// The triangles (counter-clockwise vertex triples).
    pub fn triangles(&self) -> &[[usize; 3]] {
        &self.triangles
    }

    /// All edges, sorted by (smaller vertex, larger vertex).
    pub fn edges(&self) -> &[Edge] {
        &self.edges
    }

    /// For each triangle, the ids of its three edges; entry `k` is the edge opposite corner `k`.
    pub fn triangle_edges(&self) -> &[[usize; 3]] {
        &self.triangle_edges
    }

    /// Orientation bits: bit `k` of entry `t` is set when edge `k` of triangle `t` runs from its smaller to
    /// its larger global vertex index in the triangle's counter-clockwise order. Exactly one of the two
    /// triangles of an interior edge has the bit set: it is the hinge's upper triangle T.
    pub fn orientation_bits(&self) -> &[u8] {
        &self.forward
    }

    /// σ of edge `edge` (1 interior, 0 boundary), as a bool. Returns `false` for an out-of-range id.
    pub fn is_interior(&self, edge: usize) -> bool {
        self.edges.get(edge).is_some_and(Edge::is_interior)
    }

    /// All hinges (one per interior edge), in edge order.
    pub fn hinges(&self) -> &[Hinge] {
        &self.hinges
    }

    /// The hinge on edge `edge`, if the edge is interior.
    pub fn hinge_of_edge(&self, edge: usize) -> Option<usize> {
        self.edge_hinge
            .get(edge)
            .copied()
            .filter(|&h| h != usize::MAX)
    }

    /// Number of boundary edges.
    pub fn n_boundary_edges(&self) -> usize {
        self.edges.len() - self.hinges.len()
    }
}
