//! Per-triangle quantities (Algorithm 2, lines 1–11 of Tamstorf & Grinspun 2013).
//!
//! For a triangle `(p0, p1, p2)`, counter-clockwise about its normal, corner `k` has
//!
//! | quantity | formula |
//! |---|---|
//! | opposite edge | `e0 = p2 − p1`, `e1 = p0 − p2`, `e2 = p1 − p0` (they circulate counter-clockwise) |
//! | unit edge, inverse length | `ê_k = e_k / l_k`, `1/l_k` |
//! | normal, doubled area | `n = c / |c|`, `2A = |c|` with `c = e_{k+1} × e_{k+2}` at the pivot corner `k` (below) |
//! | interior angle | `cos α_k = −ê_{k+1} · ê_{k+2}` |
//! | inverse altitude | `1/h_k = l_k / 2A` (altitude from corner `k` onto `e_k`) |
//! | outward edge normal | `m_k = ê_k × n` (in-plane, unit, pointing away from the triangle) |
//!
//! Indices are taken mod 3. The paper writes `cos α_i = ê_j · ê_k`; here the two edges at corner `k` circulate
//! (one arrives at the corner, the other leaves it), hence the minus sign.
//!
//! # The pivot corner: rounding that does not depend on which corner a face lists first
//! `e_{k+1} × e_{k+2}` is the same vector for every corner `k` (it is `(p_{k+1} − p_k) × (p_{k+2} − p_k)`), but
//! its rounding is not: the computed cross product carries an absolute error of order `ε l_{k+1} l_{k+2}`, so
//! its relative error is about `ε l_{k+1} l_{k+2} / 2A = ε / sin α_k`. The product of the two edges at a corner
//! is smallest at the corner opposite the longest edge, so that corner (the *pivot*, [`pivot_corner`]) gives
//! the most accurate normal and area: on a needle it is one of the two right-ish angles, on a cap the obtuse
//! one whose two short edges meet there. The old choice, corner 0 in file order, lost up to `l_max / l_min`
//! digits on slivers whose corner 0 faces the short edge.
//!
//! Even at the pivot, a *cap* (an obtuse sliver: all three angles have small sines) loses digits to the
//! cancellation inside each component of the cross product; when the pivot angle's sine is below 1/8 the
//! components are recomputed with Kahan's fused difference of products ([`diff_of_products`]), which is
//! accurate to 1.5 ulps whatever the cancellation. With exactly representable edge vectors the normal is
//! then accurate to a few ulps on any triangle the degeneracy test accepts.
//!
//! The pivot is chosen from the squared edge lengths, which are computed from the same differences whatever
//! corner is listed first; ties are broken by the pivot corner's coordinates. A triangle therefore gets the
//! same normal, area and degeneracy decision bit for bit under every rotation of its corners, in every pass
//! and every method (the hinge pass's θ and ∇θ in [`crate::hinge::theta_and_gradient`], the per-hinge frames,
//! the triangle pass of the refactored Hessian, and mesh validation).

use nalgebra::Vector3;

use crate::error::DegenerateTriangle;

/// Relative size below which a triangle's altitude counts as collapsed: a triangle is degenerate when
/// `2·area ≤ DEGENERACY_TOLERANCE · (longest edge)²`, i.e. its smallest altitude is below about
/// `DEGENERACY_TOLERANCE` times its longest edge. At that size the unit normal computed from a cross
/// product has lost all its digits, so no formula that needs it can be trusted.
pub const DEGENERACY_TOLERANCE: f64 = 16.0 * f64::EPSILON;

/// The pivot corner of a triangle with edge vectors `e` (edge `k` opposite corner `k`) and squared lengths
/// `len_sq`: the corner opposite the longest edge (module docs). Ties go to the corner whose coordinates
/// compare greatest, so the choice does not depend on which corner is listed first.
#[inline(always)]
pub fn pivot_corner(p: [&Vector3<f64>; 3], len_sq: &[f64; 3]) -> usize {
    let mut k = 0;
    for j in 1..3 {
        let longer = len_sq[j] > len_sq[k] || (len_sq[j] == len_sq[k] && lex_greater(p[j], p[k]));
        if longer {
            k = j;
        }
    }
    k
}

#[inline(always)]
fn lex_greater(a: &Vector3<f64>, b: &Vector3<f64>) -> bool {
    for i in 0..3 {
        match a[i].total_cmp(&b[i]) {
            std::cmp::Ordering::Greater => return true,
            std::cmp::Ordering::Less => return false,
            std::cmp::Ordering::Equal => {}
        }
    }
    false
}

/// The cross product `c = e_{k+1} × e_{k+2}` at the pivot corner `k` (`|c| = 2A`, `c / |c|` the unit normal)
/// and the triangle's largest squared edge length, for edge vectors `e = [p2 − p1, p0 − p2, p1 − p0]`.
#[inline(always)]
pub fn pivot_cross(
    p: [&Vector3<f64>; 3],
    e: &[Vector3<f64>; 3],
    len_sq: &[f64; 3],
) -> (Vector3<f64>, f64) {
    let k = pivot_corner(p, len_sq);
    let (a, b) = (&e[(k + 1) % 3], &e[(k + 2) % 3]);
    let c = a.cross(b);
    // |c| = |a||b| sin α_k. On a cap (an obtuse sliver) even the pivot angle has a small sine and the
    // products in each component cancel: recompute them with Kahan's difference of products (error ≤ 1.5
    // ulps per component whatever the cancellation). Well-shaped triangles and needles skip this.
    if c.norm_squared() * 64.0 < len_sq[(k + 1) % 3] * len_sq[(k + 2) % 3] {
        let c = Vector3::new(
            diff_of_products(a.y, b.z, a.z, b.y),
            diff_of_products(a.z, b.x, a.x, b.z),
            diff_of_products(a.x, b.y, a.y, b.x),
        );
        return (c, len_sq[k]);
    }
    (c, len_sq[k])
}

/// `a·b − c·d` with an error of at most 1.5 ulps of the result (Kahan's algorithm with fused multiply-adds).
#[inline]
pub fn diff_of_products(a: f64, b: f64, c: f64, d: f64) -> f64 {
    let w = c * d;
    let err = (-c).mul_add(d, w);
    let f = a.mul_add(b, -w);
    f + err
}

/// The one degeneracy decision every pass shares: a triangle whose pivot cross product has squared norm
/// `cross_sq` and whose longest edge has squared length `lmax_sq` is accepted when
/// `|c| > DEGENERACY_TOLERANCE · l_max²` (tested on squares: no square root), everything is finite and
/// `|c|²` is a normal number (a subnormal one has lost digits: a triangle about 1e-77 across, whose
/// normal would come out inaccurate without a sign of it).
#[inline(always)]
pub fn accepts(cross_sq: f64, lmax_sq: f64) -> bool {
    let t = DEGENERACY_TOLERANCE * lmax_sq;
    cross_sq > t * t && cross_sq >= f64::MIN_POSITIVE && cross_sq.is_finite() && lmax_sq.is_finite()
}

/// The per-triangle quantities of the module docs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangleFrame {
    /// Unit normal `n`.
    pub normal: Vector3<f64>,
    /// Twice the area, `2A`.
    pub double_area: f64,
    /// Unit edges `ê_k` (edge `k` is opposite corner `k`, counter-clockwise).
    pub unit_edge: [Vector3<f64>; 3],
    /// Edge lengths `l_k`.
    pub length: [f64; 3],
    /// Inverse squared edge lengths `1/l_k²`.
    pub inv_length_sq: [f64; 3],
    /// `cos α_k`, the cosine of the interior angle at corner `k`.
    pub cos_angle: [f64; 3],
    /// Inverse altitudes `1/h_k = l_k / 2A`.
    pub inv_altitude: [f64; 3],
    /// Outward in-plane edge normals `m_k = ê_k × n`.
    pub edge_normal: [Vector3<f64>; 3],
}

impl TriangleFrame {
    /// Computes the frame of triangle `(p0, p1, p2)`.
    ///
    /// # Errors
    /// [`DegenerateTriangle`] when [`accepts`] rejects the triangle: `2A ≤ DEGENERACY_TOLERANCE · l_max²` (an
    /// altitude has collapsed; this includes a zero-length edge and non-finite input), naming the corner with
    /// the smallest altitude. The decision and every value are the same under any rotation of the corners.
    #[inline]
    pub fn new(
        p0: &Vector3<f64>,
        p1: &Vector3<f64>,
        p2: &Vector3<f64>,
    ) -> Result<Self, DegenerateTriangle> {
        let e = [p2 - p1, p0 - p2, p1 - p0];
        let len_sq = [
            e[0].norm_squared(),
            e[1].norm_squared(),
            e[2].norm_squared(),
        ];
        let (cross, lmax_sq) = pivot_cross([p0, p1, p2], &e, &len_sq);
        let cross_sq = cross.norm_squared();
        // Negated form: NaN input is rejected too.
        if !accepts(cross_sq, lmax_sq) {
            let corner = (0..3)
                .max_by(|&a, &b| len_sq[a].total_cmp(&len_sq[b]))
                .unwrap_or(0);
            return Err(DegenerateTriangle {
                corner,
                relative_altitude: cross_sq.sqrt() / lmax_sq,
            });
        }
        let double_area = cross_sq.sqrt();
        let inv_2a = 1.0 / double_area;
        let normal = cross * inv_2a;
        let length = [len_sq[0].sqrt(), len_sq[1].sqrt(), len_sq[2].sqrt()];
        let unit_edge = [e[0] / length[0], e[1] / length[1], e[2] / length[2]];
        let cos_angle = [
            -unit_edge[1].dot(&unit_edge[2]),
            -unit_edge[2].dot(&unit_edge[0]),
            -unit_edge[0].dot(&unit_edge[1]),
        ];
        Ok(Self {
            normal,
            double_area,
            unit_edge,
            length,
            inv_length_sq: [1.0 / len_sq[0], 1.0 / len_sq[1], 1.0 / len_sq[2]],
            cos_angle,
            inv_altitude: [length[0] * inv_2a, length[1] * inv_2a, length[2] * inv_2a],
            edge_normal: [
                unit_edge[0].cross(&normal),
                unit_edge[1].cross(&normal),
                unit_edge[2].cross(&normal),
            ],
        })
    }
}
