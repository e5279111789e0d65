//! The hinge angle θ of one stencil, its gradient (Eq. 4) and its Hessian (Eqs. 5–6).
//!
//! # Stencil and sign convention
//! A stencil is `[x0, x1, x2, x3]` with upper triangle `T = (x0, x1, x2)` and lower triangle
//! `T̃ = (x3, x2, x1)`, both counter-clockwise about their own normals
//! `n = unit((x1 − x0) × (x2 − x0))` and `ñ = unit((x2 − x3) × (x1 − x3))`. The hinge edge is
//! `e0 = x2 − x1`. The signed angle is
//!
//! ```text
//! θ = atan2( (n × ñ) · ê0 , n · ñ ) ∈ (−π, π]
//! ```
//!
//! so `|θ|` is the angle between the normals (0 when flat) and its sign that of `det[n, ñ, e0]`. The atan2
//! form is accurate near 0 and near ±π. Swapping the roles of the two triangles (`[x3, x2, x1, x0]`) gives
//! the same θ bit for bit. [`tan_half_angle`] evaluates `tan(θ/2)` directly by Eq. 12,
//! `tan(θ/2) = sgn(det[n, ñ, e0]) |n − ñ| / |n + ñ|`.
//!
//! # Labels
//! Per triangle, corner `k` has the opposite edge `e_k`, angle `α_k`, altitude `h_k` and outward edge normal
//! `m_k` (see [`crate::geometry`]). In `T` label `k` is `x_k`. In `T̃` (tilde quantities) label 0 is `x3`,
//! label 1 is `x1`, label 2 is `x2`.
//!
//! # Gradient (Eq. 4)
//! ```text
//! ∇x0 θ = −n / h0                       ∇x3 θ = −ñ / h̃0
//! ∇x1 θ = cos α2 / h1 · n + cos α̃2 / h̃1 · ñ
//! ∇x2 θ = cos α1 / h2 · n + cos α̃1 / h̃2 · ñ
//! ```
//!
//! # Hessian (Eqs. 5–6, corrected)
//! With `S(A) = A + Aᵀ`, `ω_ij = 1/(h_i h_j)`, `M_i = n m_iᵀ`, `N_i = M_i / l_i²`, `Q_j = ω_0j M_j` and
//!
//! ```text
//! P_ij = ω_ij cos α_o(i) M_jᵀ,   o(1) = 2, o(2) = 1
//! ```
//!
//! (the paper prints `cos α_i`; the cosine at the *other* hinge endpoint is what matches finite
//! differences — it is the cosine that multiplies `n` in `∇x_i θ`), the upper triangle contributes
//!
//! ```text
//! H00 = −S(Q0)
//! H11 = S(P11) − N0          H22 = S(P22) − N0
//! H10 = P10 − Q1             H20 = P20 − Q2
//! H12 = P12 + P21ᵀ + N0
//! ```
//!
//! and the lower triangle the same expressions in tilde quantities (its frame computed in its own
//! counter-clockwise order, so `m̃_k` points outward of `T̃`), with its label 0 (`x3`) in place of `x0`.
//! `H03 = 0`; the other blocks follow from symmetry. The returned matrix is exactly symmetric: the
//! diagonal blocks are symmetrised, the off-diagonal blocks mirrored.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use crate::error::{DegenerateTriangle, HingeSide, StencilError};
use crate::geometry::{DEGENERACY_TOLERANCE, TriangleFrame, accepts, pivot_cross};

/// A hinge stencil `[x0, x1, x2, x3]`.
pub type Stencil = [Vector3<f64>; 4];

/// The stencil-vertex pairs `(a, b)`, `a ≥ b`, of a hinge's 10 lower-triangle 3×3 blocks, in the order the
/// per-hinge kernels write them: the four diagonal blocks, then (1, 0), (2, 0), (3, 0), (2, 1), (3, 1), (3, 2).
pub const BLOCK_PAIRS: [(usize, usize); 10] = [
    (0, 0),
    (1, 1),
    (2, 2),
    (3, 3),
    (1, 0),
    (2, 0),
    (3, 0),
    (2, 1),
    (3, 1),
    (3, 2),
];

/// θ, ∇θ and Hess θ of one stencil; coordinates ordered `x0.x, x0.y, x0.z, x1.x, …, x3.z`.
#[derive(Debug, Clone, PartialEq)]
pub struct HingeAngleDerivatives {
    /// The signed hinge angle θ.
    pub theta: f64,
    /// ∇θ (12 entries).
    pub gradient: SVector<f64, 12>,
    /// Hess θ (12×12, symmetric).
    pub hessian: SMatrix<f64, 12, 12>,
}

/// The two triangle frames of a stencil: `upper` of `(x0, x1, x2)`, `lower` of `(x3, x2, x1)`.
///
/// In `lower`, frame corner 0 is `x3`, corner 1 is `x2` and corner 2 is `x1`; [`LOWER_LABEL`] maps tilde
/// labels to those corners.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HingeFrames {
    /// Frame of T = (x0, x1, x2).
    pub upper: TriangleFrame,
    /// Frame of T̃ = (x3, x2, x1).
    pub lower: TriangleFrame,
}

/// Frame corner of tilde label `i` in [`HingeFrames::lower`] (label 1 is `x1`, frame corner 2).
pub const LOWER_LABEL: [usize; 3] = [0, 2, 1];

impl HingeFrames {
    /// Computes both frames, checking the stencil.
    ///
    /// # Errors
    /// [`StencilError::NonFinite`], [`StencilError::ZeroLengthHingeEdge`] or
    /// [`StencilError::AltitudeCollapse`]; [`StencilError::OutOfRange`] instead of the last two when the
    /// stencil's size is outside [`STENCIL_SIZE_RANGE`].
    #[inline]
    pub fn new(x: &Stencil) -> Result<Self, StencilError> {
        for (v, p) in x.iter().enumerate() {
            for axis in 0..3 {
                if !p[axis].is_finite() {
                    return Err(StencilError::NonFinite {
                        coordinate: 3 * v + axis,
                    });
                }
            }
        }
        let hinge_len_sq = (x[2] - x[1]).norm_squared();
        let scale_sq = (x[0] - x[1])
            .norm_squared()
            .max((x[3] - x[1]).norm_squared())
            .max((x[0] - x[2]).norm_squared())
            .max((x[3] - x[2]).norm_squared());
        if !(hinge_len_sq > DEGENERACY_TOLERANCE * DEGENERACY_TOLERANCE * scale_sq) {
            return Err(
                out_of_range(x).unwrap_or(StencilError::ZeroLengthHingeEdge {
                    length: hinge_len_sq.sqrt(),
                }),
            );
        }
        let upper = TriangleFrame::new(&x[0], &x[1], &x[2])
            .map_err(|e| out_of_range(x).unwrap_or_else(|| collapse(HingeSide::Upper, e)))?;
        let lower = TriangleFrame::new(&x[3], &x[2], &x[1])
            .map_err(|e| out_of_range(x).unwrap_or_else(|| collapse(HingeSide::Lower, e)))?;
        Ok(Self { upper, lower })
    }

    /// θ from the two normals (module docs).
    #[inline]
    pub fn theta(&self) -> f64 {
        signed_angle(
            &self.upper.normal,
            &self.lower.normal,
            &self.upper.unit_edge[0],
        )
    }

    /// ∇θ by Eq. 4, as the four 3-vectors `∇x0 θ … ∇x3 θ`.
    #[inline]
    pub fn gradient(&self) -> [Vector3<f64>; 4] {
        let (u, l) = (&self.upper, &self.lower);
        let (n, nt) = (&u.normal, &l.normal);
        [
            n * -u.inv_altitude[0],
            n * (u.cos_angle[2] * u.inv_altitude[1]) + nt * (l.cos_angle[1] * l.inv_altitude[2]),
            n * (u.cos_angle[1] * u.inv_altitude[2]) + nt * (l.cos_angle[2] * l.inv_altitude[1]),
            nt * -l.inv_altitude[0],
        ]
    }
}

/// Signed angle from unit normal `n` to unit normal `nt` about unit axis `axis`.
#[inline]
pub fn signed_angle(n: &Vector3<f64>, nt: &Vector3<f64>, axis: &Vector3<f64>) -> f64 {
    n.cross(nt).dot(axis).atan2(n.dot(nt))
}

/// The sizes (largest coordinate difference within a stencil) the hinge formulas evaluate: beyond them the
/// squared lengths and the cross products' squares (fourth powers of the size) over- or underflow double
/// precision, and a sound stencil would be reported as degenerate. A test evaluates stencils scaled to both
/// ends against the unscaled ones.
pub const STENCIL_SIZE_RANGE: (f64, f64) = (1e-60, 1e60);

/// [`StencilError::OutOfRange`] when the stencil's size is outside [`STENCIL_SIZE_RANGE`] (a stencil
/// whose vertices all coincide has size 0 and is degenerate, not out of range). Called where a check
/// failed, to say why.
#[cold]
fn out_of_range(x: &Stencil) -> Option<StencilError> {
    let size = x
        .iter()
        .flat_map(|p| (0..3).map(move |a| (p[a] - x[1][a]).abs()))
        .fold(0.0, f64::max);
    let (lo, hi) = STENCIL_SIZE_RANGE;
    (size > 0.0 && !(lo..=hi).contains(&size)).then_some(StencilError::OutOfRange { size })
}

fn collapse(side: HingeSide, e: DegenerateTriangle) -> StencilError {
    // Frame corners → stencil vertices.
    let vertex = match side {
        HingeSide::Upper => e.corner,
        HingeSide::Lower => [3, 2, 1][e.corner],
    };
    StencilError::AltitudeCollapse {
        side,
        vertex,
        relative_altitude: e.relative_altitude,
    }
}

/// The signed hinge angle θ of a stencil.
///
/// # Errors
/// As [`HingeFrames::new`].
pub fn hinge_angle(x: &Stencil) -> Result<f64, StencilError> {
    Ok(HingeFrames::new(x)?.theta())
}

/// `tan(θ/2)` by Eq. 12: `sgn(det[n, ñ, e0]) |n − ñ| / |n + ñ|` (+∞ or −∞ when the hinge is folded flat,
/// θ = ±π exactly; the sign is taken positive when the determinant is zero).
///
/// # Errors
/// As [`HingeFrames::new`].
pub fn tan_half_angle(x: &Stencil) -> Result<f64, StencilError> {
    let f = HingeFrames::new(x)?;
    let (n, nt) = (&f.upper.normal, &f.lower.normal);
    let det = n.cross(nt).dot(&f.upper.unit_edge[0]);
    let sign = if det < 0.0 { -1.0 } else { 1.0 };
    Ok(sign * (n - nt).norm() / (n + nt).norm())
}

/// θ and ∇θ by Eq. 4 rewritten without unit vectors — the fast path of the assembly engine.
///
/// With `u = (x1 − x0) × (x2 − x0)` (`|u| = 2A`), `v = (x2 − x3) × (x1 − x3)` (`|v| = 2Ã`), `e0 = x2 − x1`
/// and `l0 = |e0|`, the Eq. 4 coefficients become dot products: `1/h0 = l0/|u|`,
/// `cos α2 / h1 = (x0 − x2)·(x1 − x2) / (l0 |u|)`, `cos α1 / h2 = (x0 − x1)·(x2 − x1) / (l0 |u|)`, so
///
/// ```text
/// ∇x0 θ = −l0 u/|u|²                        ∇x3 θ = −l0 v/|v|²
/// ∇x1 θ = ((x0−x2)·(x1−x2)) u/(l0|u|²) + ((x3−x2)·(x1−x2)) v/(l0|v|²)
/// ∇x2 θ = ((x0−x1)·(x2−x1)) u/(l0|u|²) + ((x3−x1)·(x2−x1)) v/(l0|v|²)
/// ```
///
/// and `θ = atan2((u × v)·e0 / l0, u·v)`. One square root, two divisions. The stencil checks are those of
/// [`HingeFrames::new`] (the same errors, computed on the failure path by it).
///
/// # Errors
/// As [`HingeFrames::new`].
#[inline]
pub fn theta_and_gradient(x: &Stencil) -> Result<(f64, [Vector3<f64>; 4]), StencilError> {
    let k = stencil_kernel(x)?;
    let [x0, x1, x2, x3] = x;
    let (u, v, e0, l0sq) = (k.u, k.v, k.e0, k.l0sq);
    let (a1, a2) = (x0 - x1, x0 - x2);
    let (b1, b2) = (x3 - x1, x3 - x2);
    let (uu, vv) = (k.uu, k.vv);
    let l0 = l0sq.sqrt();
    let (iu, iv) = (1.0 / uu, 1.0 / vv);
    let il0 = 1.0 / l0;
    let theta = (u.cross(&v).dot(&e0) * il0).atan2(u.dot(&v));
    let su = iu * il0;
    let sv = iv * il0;
    let g = [
        u * (-l0 * iu),
        u * (a2.dot(&-e0) * su) + v * (b2.dot(&-e0) * sv),
        u * (a1.dot(&e0) * su) + v * (b1.dot(&e0) * sv),
        v * (-l0 * iv),
    ];
    Ok((theta, g))
}

/// What θ and ∇θ share: both triangles' pivot cross products (see [`crate::geometry`]) and the checks.
struct StencilKernel {
    u: Vector3<f64>,
    v: Vector3<f64>,
    uu: f64,
    vv: f64,
    e0: Vector3<f64>,
    l0sq: f64,
}

/// Both triangles' pivot cross products `u` (of `T`) and `v` (of `T̃`), computed from the edge vectors in
/// the triangles' own counter-clockwise order, so they are bitwise those of [`TriangleFrame::new`] for the
/// same triangle listed from any corner, and the same degeneracy decision ([`crate::geometry::accepts`]).
#[inline(always)]
fn stencil_kernel(x: &Stencil) -> Result<StencilKernel, StencilError> {
    let [x0, x1, x2, x3] = x;
    // T = (x0, x1, x2): e = [x2 − x1, x0 − x2, x1 − x0]; T̃ = (x3, x2, x1): e = [x1 − x2, x3 − x1, x2 − x3].
    let e0 = x2 - x1;
    let eu = [e0, x0 - x2, x1 - x0];
    let ev = [-e0, x3 - x1, x2 - x3];
    let lu = [
        eu[0].norm_squared(),
        eu[1].norm_squared(),
        eu[2].norm_squared(),
    ];
    let lv = [lu[0], ev[1].norm_squared(), ev[2].norm_squared()];
    let (u, lu_max) = pivot_cross([x0, x1, x2], &eu, &lu);
    let (v, lv_max) = pivot_cross([x3, x2, x1], &ev, &lv);
    let (uu, vv) = (u.norm_squared(), v.norm_squared());
    let l0sq = lu[0];
    let scale = lu[1].max(lu[2]).max(lv[1]).max(lv[2]);
    let tol2 = DEGENERACY_TOLERANCE * DEGENERACY_TOLERANCE;
    let ok = l0sq > tol2 * scale && accepts(uu, lu_max) && accepts(vv, lv_max);
    if !ok {
        // The precise error (which check, which vertex) from the reference path.
        HingeFrames::new(x)?;
        // Unreachable in practice: both paths make the same decisions. Report the upper triangle.
        return Err(StencilError::AltitudeCollapse {
            side: HingeSide::Upper,
            vertex: 0,
            relative_altitude: uu.sqrt() / lu_max,
        });
    }
    Ok(StencilKernel {
        u,
        v,
        uu,
        vv,
        e0,
        l0sq,
    })
}

/// θ alone, with the same checks and bitwise the same value as [`theta_and_gradient`]: what an energy-only
/// evaluation computes (no ∇θ).
///
/// # Errors
/// As [`HingeFrames::new`].
#[inline(always)]
pub fn theta_only(x: &Stencil) -> Result<f64, StencilError> {
    let k = stencil_kernel(x)?;
    let il0 = 1.0 / k.l0sq.sqrt();
    Ok((k.u.cross(&k.v).dot(&k.e0) * il0).atan2(k.u.dot(&k.v)))
}

/// θ and ∇θ (Eq. 4) of a stencil.
///
/// # Errors
/// As [`HingeFrames::new`].
pub fn hinge_angle_gradient(x: &Stencil) -> Result<(f64, [Vector3<f64>; 4]), StencilError> {
    let f = HingeFrames::new(x)?;
    Ok((f.theta(), f.gradient()))
}

/// θ, ∇θ and Hess θ of a stencil by the closed forms of the module docs.
///
/// # Errors
/// As [`HingeFrames::new`].
pub fn hinge_angle_hessian(x: &Stencil) -> Result<HingeAngleDerivatives, StencilError> {
    let f = HingeFrames::new(x)?;
    let g = f.gradient();
    let blocks = hessian_blocks(&f);
    let mut hessian = SMatrix::<f64, 12, 12>::zeros();
    for a in 0..4 {
        for b in 0..=a {
            let blk = if a == b {
                (blocks[a][a] + blocks[a][a].transpose()) * 0.5
            } else {
                blocks[a][b]
            };
            hessian.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&blk);
            if a != b {
                hessian
                    .fixed_view_mut::<3, 3>(3 * b, 3 * a)
                    .copy_from(&blk.transpose());
            }
        }
    }
    let mut gradient = SVector::<f64, 12>::zeros();
    for (a, ga) in g.iter().enumerate() {
        gradient.fixed_rows_mut::<3>(3 * a).copy_from(ga);
    }
    Ok(HingeAngleDerivatives {
        theta: f.theta(),
        gradient,
        hessian,
    })
}

/// The lower-triangle 3×3 blocks `H_ab` (a ≥ b, stencil vertex indices) of Hess θ by Eqs. 5–6; entries
/// with `a < b` are left zero. Diagonal blocks are returned as summed (symmetric only up to rounding).
pub fn hessian_blocks(f: &HingeFrames) -> [[Matrix3<f64>; 4]; 4] {
    let mut h = [[Matrix3::zeros(); 4]; 4];
    half_hinge(&f.upper, [0, 1, 2], [0, 1, 2], &mut h);
    half_hinge(&f.lower, LOWER_LABEL, [3, 1, 2], &mut h);
    h
}

/// Adds one column of Eq. 6: `label` maps labels 0, 1, 2 to frame corners, `vertex` to stencil vertices.
#[inline]
fn half_hinge(
    t: &TriangleFrame,
    label: [usize; 3],
    vertex: [usize; 3],
    h: &mut [[Matrix3<f64>; 4]; 4],
) {
    let ih = |i: usize| t.inv_altitude[label[i]];
    let omega = |i: usize, j: usize| ih(i) * ih(j);
    let m: [Matrix3<f64>; 3] = [0, 1, 2].map(|i| t.normal * t.edge_normal[label[i]].transpose());
    let cos_other = |i: usize| t.cos_angle[label[if i == 1 { 2 } else { 1 }]];
    let p = |i: usize, j: usize| m[j].transpose() * (omega(i, j) * cos_other(i));
    let q = |j: usize| m[j] * omega(0, j);
    let n0 = m[0] * t.inv_length_sq[label[0]];
    let s = |a: Matrix3<f64>| a + a.transpose();
    let [v0, v1, v2] = vertex;
    h[v0][v0] -= s(q(0));
    h[v1][v1] += s(p(1, 1)) - n0;
    h[v2][v2] += s(p(2, 2)) - n0;
    add_block(h, v1, v0, p(1, 0) - q(1));
    add_block(h, v2, v0, p(2, 0) - q(2));
    add_block(h, v1, v2, p(1, 2) + p(2, 1).transpose() + n0);
}

/// Adds block `H_ab` into the lower-triangle storage (as `H_baᵀ` when `a < b`).
#[inline]
fn add_block(h: &mut [[Matrix3<f64>; 4]; 4], a: usize, b: usize, blk: Matrix3<f64>) {
    if a >= b {
        h[a][b] += blk;
    } else {
        h[b][a] += blk.transpose();
    }
}
