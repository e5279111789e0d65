//! Rectangular grid meshes for scenes, tests and benchmarks.
//!
//! A grid of `nx × ny` cells has `(nx + 1)(ny + 1)` vertices; vertex `v = j (nx + 1) + i` (row `j` outer,
//! column `i` inner) sits at `(i·w/nx, j·h/ny, 0)`. Each cell with corners `a = (i, j)`, `b = (i+1, j)`,
//! `c = (i+1, j+1)`, `d = (i, j+1)` is split into two counter-clockwise triangles (normal +z) along the
//! diagonal chosen by [`Diagonal`].

use nalgebra::Vector3;

use crate::error::MeshError;
use crate::mesh::TriMesh;

/// How each grid cell is split into two triangles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Diagonal {
    /// Every cell split along a→c: triangles (a, b, c) and (a, c, d). This is the layout of the shared
    /// reference data and of `hinge bench`.
    #[default]
    Forward,
    /// Every cell split along b→d: triangles (a, b, d) and (b, c, d).
    Backward,
    /// Forward and backward cells alternate in a checkerboard (a "union jack" pattern): every interior
    /// vertex has valence 4 or 8.
    Alternating,
}

/// Builds a flat `nx × ny` grid of size `width × height` in the z = 0 plane.
///
/// # Errors
/// [`MeshError::Empty`] when `nx` or `ny` is zero, [`MeshError::ZeroAreaTriangle`] for a zero or non-finite
/// size, [`MeshError::TooLarge`] for a grid too large to build ([`reserve_generated`]).
pub fn grid(
    nx: usize,
    ny: usize,
    width: f64,
    height: f64,
    diagonal: Diagonal,
) -> Result<TriMesh, MeshError> {
    if nx == 0 || ny == 0 {
        return Err(MeshError::Empty {
            vertices: 0,
            triangles: 0,
        });
    }
    let (nv, nt) = counts(nx, ny);
    let (mut positions, mut triangles) = reserve_generated(nv, nt)?;
    for j in 0..=ny {
        for i in 0..=nx {
            positions.push(Vector3::new(
                i as f64 / nx as f64 * width,
                j as f64 / ny as f64 * height,
                0.0,
            ));
        }
    }
    for j in 0..ny {
        for i in 0..nx {
            let a = j * (nx + 1) + i;
            let (b, c, d) = (a + 1, a + nx + 2, a + nx + 1);
            let forward = match diagonal {
                Diagonal::Forward => true,
                Diagonal::Backward => false,
                Diagonal::Alternating => (i + j) % 2 == 0,
            };
            if forward {
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            } else {
                triangles.push([a, b, d]);
                triangles.push([b, c, d]);
            }
        }
    }
    TriMesh::new(positions, triangles)
}

/// The vertex and triangle counts of [`grid`]`(nx, ny, …)`: `(nx + 1)(ny + 1)` and `2 nx ny`, saturating at
/// `u128::MAX` (for `nx = ny = usize::MAX`), so a caller can check a size before building it.
pub fn counts(nx: usize, ny: usize) -> (u128, u128) {
    let (x, y) = (nx as u128, ny as u128);
    (
        (x + 1).saturating_mul(y + 1),
        x.saturating_mul(y).saturating_mul(2),
    )
}

/// The unit-square grid of the shared reference data and of `hinge bench`: `n × n` cells on `[0, 1]²`,
/// [`Diagonal::Forward`].
///
/// # Errors
/// As [`grid`].
pub fn unit_grid(n: usize) -> Result<TriMesh, MeshError> {
    grid(n, n, 1.0, 1.0, Diagonal::Forward)
}

/// A triangle's three vertex indices.
type Triangle = [usize; 3];

/// The most vertices a generated mesh may have: the Hessian pattern numbers vertices in 32 bits
/// ([`crate::pattern::SymmetricPattern`]).
pub const MAX_GENERATED_VERTICES: u128 = u32::MAX as u128;

/// Empty vectors with room for a generated mesh of `vertices` vertices and `triangles` triangles, or
/// [`MeshError::TooLarge`] when the vertex count exceeds [`MAX_GENERATED_VERTICES`] or the memory cannot be
/// reserved (an absurd size is an error, not an aborted process).
///
/// # Errors
/// [`MeshError::TooLarge`].
pub fn reserve_generated(
    vertices: u128,
    triangles: u128,
) -> Result<(Vec<Vector3<f64>>, Vec<Triangle>), MeshError> {
    let too_large = |reason: &'static str| MeshError::TooLarge {
        vertices: u64::try_from(vertices).unwrap_or(u64::MAX),
        triangles: u64::try_from(triangles).unwrap_or(u64::MAX),
        reason,
    };
    if vertices > MAX_GENERATED_VERTICES {
        return Err(too_large(
            "more vertices than the engine's 32-bit range (4 294 967 295)",
        ));
    }
    let (nv, nt) = (
        vertices as usize,
        usize::try_from(triangles).unwrap_or(usize::MAX),
    );
    let mut positions: Vec<Vector3<f64>> = Vec::new();
    let mut faces: Vec<Triangle> = Vec::new();
    positions
        .try_reserve_exact(nv)
        .and_then(|()| faces.try_reserve_exact(nt))
        .map_err(|_| too_large("its vertices and triangles cannot be allocated"))?;
    Ok((positions, faces))
}

/// The smooth test deformation of the reference data and of `hinge bench`: `(x, y, 0) ↦ (x, y,
/// 0.1·sin(3x)·cos(2y))`.
pub fn wave(rest: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    rest.iter()
        .map(|p| Vector3::new(p.x, p.y, 0.1 * (3.0 * p.x).sin() * (2.0 * p.y).cos()))
        .collect()
}

/// SplitMix64, the generator of the shared reference data (`shared/data/README.md`): small, seeded and
/// reproducible across platforms, for tests, benchmarks and jittered meshes.
#[derive(Debug, Clone)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [-1, 1), exactly as the reference data's jitter.
    pub fn symmetric(&mut self) -> f64 {
        self.unit() * 2.0 - 1.0
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
}

/// The jittered wave deformation of the shared reference data (`shared/data/README.md`) for a unit grid:
/// `(X + 1e-3·ux, Y + 1e-3·uy, 0.1·sin(3X)·cos(2Y) + 1e-3·uz)` with `u` drawn from [`SplitMix64`] seeded
/// `0x5EED`, three draws per vertex in index order.
pub fn reference_jitter(rest: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let mut rng = SplitMix64(0x5EED);
    rest.iter()
        .map(|p| {
            let (ux, uy, uz) = (rng.symmetric(), rng.symmetric(), rng.symmetric());
            Vector3::new(
                p.x + 1e-3 * ux,
                p.y + 1e-3 * uy,
                0.1 * (3.0 * p.x).sin() * (2.0 * p.y).cos() + 1e-3 * uz,
            )
        })
        .collect()
}
