//! Per-triangle quantities (Algorithm 2, lines 1–11 of Tamstorf & Grinspun 2013).
//!
//! For a triangle `(p0, p1, p2)`, counter-clockwise about its normal, corner `k` has
//!
//! | quantity | formula |
//! |---|---|
//! | opposite edge | `e0 = p2 − p1`, `e1 = p0 − p2`, `e2 = p1 − p0` (they circulate counter-clockwise) |
//! | unit edge, inverse length | `ê_k = e_k / l_k`, `1/l_k` |
//! | normal, doubled area | `n = (e1 × e2) / |e1 × e2|`, `2A = |e1 × e2|` (note `e1 × e2 = (p1 − p0) × (p2 − p0)`) |
//! | interior angle | `cos α_k = −ê_{k+1} · ê_{k+2}` |
//! | inverse altitude | `1/h_k = l_k / 2A` (altitude from corner `k` onto `e_k`) |
//! | outward edge normal | `m_k = ê_k × n` (in-plane, unit, pointing away from the triangle) |
//!
//! Indices are taken mod 3. The paper writes `cos α_i = ê_j · ê_k`; here the two edges at corner `k` circulate
//! (one arrives at the corner, the other leaves it), hence the minus sign.

use nalgebra::Vector3;

use crate::error::DegenerateTriangle;
use crate::mesh::DEGENERACY_TOLERANCE;

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
    /// [`DegenerateTriangle`] when `2A ≤ DEGENERACY_TOLERANCE · l_max²` (an altitude has collapsed; this
    /// includes a zero-length edge and non-finite input), naming the corner with the smallest altitude.
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
        let cross = e[1].cross(&e[2]);
        let double_area = cross.norm();
        let lmax_sq = len_sq[0].max(len_sq[1]).max(len_sq[2]);
        // Negated comparison: NaN input also lands here.
        if !(double_area > DEGENERACY_TOLERANCE * lmax_sq) || !double_area.is_finite() {
            let corner = (0..3)
                .max_by(|&a, &b| len_sq[a].total_cmp(&len_sq[b]))
                .unwrap_or(0);
            return Err(DegenerateTriangle {
                corner,
                relative_altitude: double_area / lmax_sq,
            });
        }
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
