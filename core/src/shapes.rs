//! Meshes that look like users' meshes, generated in code: closed surfaces (a subdivided icosahedron, a
//! torus), an irregular sheet (random diagonals, jitter), a sheet with slivers (needles and caps with aspect
//! ratios up to 10⁶), and random renumbering. Tests and benchmarks use them so that nothing is measured on
//! row-major grids alone.

use std::collections::HashMap;

use nalgebra::Vector3;

use crate::error::MeshError;
use crate::grid::SplitMix64;
use crate::mesh::TriMesh;

/// A subdivided icosahedron on a sphere of `radius`: `10·4^s + 2` vertices, closed, outward normals.
///
/// # Errors
/// [`MeshError::TooLarge`] for a level whose mesh is too large to build (beyond 15: more than 2³² vertices).
pub fn icosphere(subdivisions: usize, radius: f64) -> Result<TriMesh, MeshError> {
    let (nv, nt) = icosphere_counts(subdivisions);
    let (mut v, _) = crate::grid::reserve_generated(nv, nt)?;
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    v.extend(
        [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ]
        .iter()
        .map(|p| Vector3::new(p[0], p[1], p[2]).normalize()),
    );
    let mut f: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
        let mut next = Vec::with_capacity(4 * f.len());
        let mut midpoint = |a: usize, b: usize, v: &mut Vec<Vector3<f64>>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(((v[a] + v[b]) * 0.5).normalize());
                v.len() - 1
            })
        };
        for &[a, b, c] in &f {
            let ab = midpoint(a, b, &mut v);
            let bc = midpoint(b, c, &mut v);
            let ca = midpoint(c, a, &mut v);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = next;
    }
    TriMesh::new(v.into_iter().map(|p| p * radius).collect(), f)
}

/// The vertex and triangle counts of [`icosphere`]`(subdivisions, …)`: `10·4ˢ + 2` and `20·4ˢ`, saturating
/// beyond level 61, so a caller can check a level before building it.
pub fn icosphere_counts(subdivisions: usize) -> (u128, u128) {
    let quads = u32::try_from(subdivisions)
        .ok()
        .and_then(|s| 4u128.checked_pow(s))
        .unwrap_or(u128::MAX);
    (
        quads.saturating_mul(10).saturating_add(2),
        quads.saturating_mul(20),
    )
}

/// A torus with `nu × nv` vertices (major radius `big`, minor radius `small`), closed, outward normals.
///
/// # Errors
/// [`MeshError`] for `nu < 3` or `nv < 3` (a degenerate torus); [`MeshError::TooLarge`] for one too large to
/// build.
pub fn torus(nu: usize, nv: usize, big: f64, small: f64) -> Result<TriMesh, MeshError> {
    if nu < 3 || nv < 3 {
        return Err(MeshError::Empty {
            vertices: nu.saturating_mul(nv),
            triangles: 0,
        });
    }
    // Both below 2⁶⁴: the product fits in u128, twice it too.
    let n = nu as u128 * nv as u128;
    let (mut v, mut f) = crate::grid::reserve_generated(n, 2 * n)?;
    let tau = std::f64::consts::TAU;
    for i in 0..nu {
        let u = tau * i as f64 / nu as f64;
        for j in 0..nv {
            let w = tau * j as f64 / nv as f64;
            let r = big + small * w.cos();
            v.push(Vector3::new(r * u.cos(), r * u.sin(), small * w.sin()));
        }
    }
    let id = |i: usize, j: usize| (i % nu) * nv + (j % nv);
    for i in 0..nu {
        for j in 0..nv {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            f.push([a, b, c]);
            f.push([a, c, d]);
        }
    }
    TriMesh::new(v, f)
}

/// A seeded random permutation of `0..n` (Fisher–Yates on [`SplitMix64`]).
pub fn random_permutation(n: usize, seed: u64) -> Vec<usize> {
    let mut p: Vec<usize> = (0..n).collect();
    let mut rng = SplitMix64(seed);
    for i in (1..n).rev() {
        let j = (rng.next_u64() % (i as u64 + 1)) as usize;
        p.swap(i, j);
    }
    p
}

/// The same mesh with vertex `v` renamed `perm[v]` (triangles keep their order and corner order).
///
/// # Errors
/// [`MeshError`] if `perm` is not a permutation of the vertices (an index out of range or repeated).
pub fn renumber(mesh: &TriMesh, perm: &[usize]) -> Result<TriMesh, MeshError> {
    let n = mesh.n_vertices();
    crate::mesh::check_same_vertex_count(n, perm.len())?;
    let mut pos = vec![Vector3::new(f64::NAN, f64::NAN, f64::NAN); n];
    for (v, &p) in perm.iter().enumerate() {
        if p >= n {
            return Err(MeshError::IndexOutOfRange {
                triangle: 0,
                corner: 0,
                index: p,
                n_vertices: n,
            });
        }
        pos[p] = mesh.positions()[v];
    }
    let tris = mesh
        .triangles()
        .iter()
        .map(|t| t.map(|v| perm[v]))
        .collect();
    // A repeated entry leaves a NaN position, which `TriMesh::new` rejects.
    TriMesh::new(pos, tris)
}

/// Positions renumbered like [`renumber`]: `out[perm[v]] = x[v]`.
pub fn renumber_positions(x: &[Vector3<f64>], perm: &[usize]) -> Vec<Vector3<f64>> {
    let mut out = vec![Vector3::zeros(); x.len()];
    for (v, &p) in perm.iter().enumerate() {
        if let Some(o) = out.get_mut(p) {
            *o = x[v];
        }
    }
    out
}

/// An irregular flat sheet on `[0, 1]²` from an `nx × ny` lattice: every cell's diagonal chosen at random
/// (valences 4 to 8), positions jittered by up to 0.3 of the spacing, then vertices renumbered at random,
/// and every face's corners rotated at random. Seeded, so the same call gives the same mesh.
///
/// # Errors
/// [`MeshError`] for `nx < 2` or `ny < 2`; [`MeshError::TooLarge`] for one too large to build.
pub fn irregular_sheet(nx: usize, ny: usize, seed: u64) -> Result<TriMesh, MeshError> {
    if nx < 2 || ny < 2 {
        return Err(MeshError::Empty {
            vertices: nx.saturating_mul(ny),
            triangles: 0,
        });
    }
    let (mut v, mut f) = crate::grid::reserve_generated(
        nx as u128 * ny as u128,
        2 * (nx as u128 - 1) * (ny as u128 - 1),
    )?;
    let mut rng = SplitMix64(seed);
    let (hx, hy) = (1.0 / (nx - 1) as f64, 1.0 / (ny - 1) as f64);
    for j in 0..ny {
        for i in 0..nx {
            let jx = if i == 0 || i == nx - 1 {
                0.0
            } else {
                0.3 * hx * rng.symmetric()
            };
            let jy = if j == 0 || j == ny - 1 {
                0.0
            } else {
                0.3 * hy * rng.symmetric()
            };
            v.push(Vector3::new(i as f64 * hx + jx, j as f64 * hy + jy, 0.0));
        }
    }
    let id = |i: usize, j: usize| j * nx + i;
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if rng.next_u64() & 1 == 0 {
                f.push([a, b, c]);
                f.push([a, c, d]);
            } else {
                f.push([a, b, d]);
                f.push([b, c, d]);
            }
        }
    }
    for t in &mut f {
        t.rotate_left((rng.next_u64() % 3) as usize);
    }
    let mesh = TriMesh::new(v, f)?;
    renumber(&mesh, &random_permutation(mesh.n_vertices(), seed ^ 0xA5A5))
}

/// A flat sheet with slivers: an `n × n` lattice on `[0, 1]²` (alternating diagonals) in which about a third
/// of the triangles are split 1 → 3 at a point very close to one of their edges (a *cap*, the new triangle
/// on that edge has relative altitude `t`) or to one of their corners (two *needles*), with `t` log-uniform in
/// `[10⁻⁶, 10⁻²]`. Vertices are renumbered at random. Seeded.
///
/// # Errors
/// [`MeshError`] for `n < 2`; [`MeshError::TooLarge`] for one too large to build.
pub fn sliver_sheet(n: usize, seed: u64) -> Result<TriMesh, MeshError> {
    if n < 2 {
        return Err(MeshError::Empty {
            vertices: n.saturating_mul(n),
            triangles: 0,
        });
    }
    let base = crate::grid::grid(n - 1, n - 1, 1.0, 1.0, crate::grid::Diagonal::Alternating)?;
    let mut rng = SplitMix64(seed);
    let mut v = base.positions().to_vec();
    let mut f = Vec::with_capacity(2 * base.n_triangles());
    for &[a, b, c] in base.triangles() {
        let choice = rng.next_u64() % 9;
        let t = 10f64.powf(-rng.range(2.0, 6.0));
        let (pa, pb, pc) = (v[a], v[b], v[c]);
        match choice {
            // Cap on edge (a, b), (b, c) or (c, a): the new point sits a fraction t of the way from the
            // edge's midpoint to the opposite corner.
            0..=1 => {
                let rot = (rng.next_u64() % 3) as usize;
                let mut q = [a, b, c];
                q.rotate_left(rot);
                let (p0, p1, p2) = (v[q[0]], v[q[1]], v[q[2]]);
                let mid = (p0 + p1) * 0.5;
                v.push(mid + (p2 - mid) * t);
                let m = v.len() - 1;
                f.extend([[q[0], q[1], m], [q[1], q[2], m], [q[2], q[0], m]]);
            }
            // Needles at a corner: the new point a fraction t of the way from the corner to the opposite
            // edge's midpoint.
            2 => {
                v.push(pa + ((pb + pc) * 0.5 - pa) * t);
                let m = v.len() - 1;
                f.extend([[a, b, m], [b, c, m], [c, a, m]]);
            }
            _ => f.push([a, b, c]),
        }
    }
    let mesh = TriMesh::new(v, f)?;
    renumber(&mesh, &random_permutation(mesh.n_vertices(), seed ^ 0x5A5A))
}

/// A smooth non-flat deformation `(x, y, z) ↦ (x, y, z + 0.2 sin(2x + 1) cos(3y))` plus an in-plane shear,
/// for evaluating bending on flat generated sheets (it keeps slivers slivers: no jitter).
pub fn bend(x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    x.iter()
        .map(|p| {
            Vector3::new(
                p.x + 0.05 * p.y,
                p.y,
                p.z + 0.2 * (2.0 * p.x + 1.0).sin() * (3.0 * p.y).cos(),
            )
        })
        .collect()
}
