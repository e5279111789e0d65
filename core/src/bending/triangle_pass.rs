//! Eq. 7, the triangle-refactored Hessian: one element per triangle with an interior edge. Per triangle
//! with corners 0, 1, 2 (edge `i` opposite corner `i`, σ_i = 1 on interior edges):
//!
//! ```text
//! c_i = σ_i ψ′_i,   d_i = c_{i−1} cos α_{i+1} + c_{i+1} cos α_{i−1} − c_i,   R_i = c_i N_i
//! H^Δ_ii     = ω_ii (d_i M_iᵀ + d_i M_i) − R_{i+1} − R_{i+2}
//! H^Δ_i,i+1  = ω_i,i+1 (d_i M_{i+1}ᵀ + d_{i+1} M_i) + R_{i+2}^†
//! ```
//!
//! with `M_i = n m_iᵀ`, `N_i = M_i / l_i²`, `ω_ij = 1/(h_i h_j)`, plus the `ψ″ ∇θ∇θᵀ` of the hinges assigned
//! to the triangle (module docs of [`super`]). The frame comes from [`TriangleFrame::new`], whose normal is
//! the pivot corner's cross product: the element's rounding is the same under every rotation of its
//! corners, and its degeneracy decision is the hinge pass's.

use nalgebra::Matrix3;

use crate::error::EvalError;
use crate::geometry::TriangleFrame;
use crate::psi::HingePsi;

use super::HessianMode;
use super::scatter::{Ctx, NONE, Owned};

impl<P: HingePsi> Ctx<'_, P> {
    /// One refactored element: H^Δ (Eq. 7) plus the assigned hinges' outer products and gradients.
    #[inline]
    pub(super) fn triangle(&self, e: usize, own: &mut Owned) -> Result<(), (u32, EvalError)> {
        let l = &self.model.layout;
        let v = l.tri_vertices[e].map(|s| s as usize);
        let slots = &l.tri_slots[e];
        let bits = l.tri_bits[e];
        let hid = l.tri_states[e];
        // The corners of the assigned hinges, in increasing state slot (independent of the corner order).
        let assigned = l.tri_assigned[e];
        let assigned = assigned.iter().take_while(|&&k| k < 3).map(|&k| k as usize);
        if self.request.gradient {
            for k in assigned.clone() {
                let s = &self.states[hid[k] as usize];
                let dpsi = self.dpsi[hid[k] as usize];
                let hv = l.state_vertices[hid[k] as usize];
                for a in 0..4 {
                    own.add_grad(hv[a] as usize, &(s.grad[a] * dpsi));
                }
            }
        }
        if !self.request.hessian {
            return Ok(());
        }
        // The hinge pass accepted this triangle with the same decision on the same positions, so this cannot
        // fail; if it ever did, the triangle is reported rather than skipped.
        let f =
            TriangleFrame::new(&self.x[v[0]], &self.x[v[1]], &self.x[v[2]]).map_err(|source| {
                let t = l.tri_elements[e];
                let err = EvalError::Triangle {
                    triangle: t as usize,
                    vertices: self.model.topology.triangles()[t as usize],
                    source,
                };
                (t, err)
            })?;
        let gauss_newton = self.mode == HessianMode::GaussNewton;
        let c = hid.map(|h| {
            if h == NONE || gauss_newton {
                0.0
            } else {
                self.dpsi[h as usize]
            }
        });
        let cs = &f.cos_angle;
        let d = [0, 1, 2]
            .map(|i| c[(i + 2) % 3] * cs[(i + 1) % 3] + c[(i + 1) % 3] * cs[(i + 2) % 3] - c[i]);
        // Every term of Eq. 7 is a rank-one n ⊗ m_k or m_k ⊗ n, so each block is n pᵀ + q nᵀ for two vectors
        // p, q: M_i = n m_iᵀ, R_i = (c_i / l_i²) n m_iᵀ.
        let n = f.normal;
        let en = &f.edge_normal;
        let r = [0, 1, 2].map(|i| c[i] * f.inv_length_sq[i]);
        let ih = &f.inv_altitude;
        // Blocks 0..3: diagonal (corner i, corner i); blocks 3..6: (corner i, corner i + 1).
        let mut blk = [Matrix3::zeros(); 6];
        for i in 0..3 {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            let q = en[i] * (ih[i] * ih[i] * d[i]);
            let p = q - en[i1] * r[i1] - en[i2] * r[i2];
            blk[i] = n * p.transpose() + q * n.transpose();
            let w = ih[i] * ih[i1];
            let mut left = en[i1] * (w * d[i]);
            let mut right = en[i] * (w * d[i1]);
            // † transposes R_{i+2} in the lower triangle T̃ of edge i+2's hinge (orientation bit clear).
            if bits >> i2 & 1 == 1 {
                right += en[i2] * r[i2];
            } else {
                left += en[i2] * r[i2];
            }
            blk[3 + i] = n * right.transpose() + left * n.transpose();
        }
        // ψ″ ∇θ∇θᵀ of the assigned hinges.
        if !self.model.psi.second_derivative_vanishes() {
            for k in assigned {
                let s = &self.states[hid[k] as usize];
                let d2 = if gauss_newton {
                    s.d2psi.max(0.0)
                } else {
                    s.d2psi
                };
                let g = s.grad.map(|gv| gv * d2);
                let gr = &s.grad;
                // Hinge x0, x1, x2 are corners k, k+1, k+2; own block 3 + i is (corner i, corner i + 1), so
                // (x0, x1) → 3 + k, (x1, x2) → 3 + k1, (x2, x0) → 3 + k2.
                let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
                blk[k] += g[0] * gr[0].transpose();
                blk[k1] += g[1] * gr[1].transpose();
                blk[k2] += g[2] * gr[2].transpose();
                blk[3 + k] += g[0] * gr[1].transpose();
                blk[3 + k1] += g[1] * gr[2].transpose();
                blk[3 + k2] += g[2] * gr[0].transpose();
                let hv = l.state_vertices[hid[k] as usize].map(|s| s as usize);
                let x3 = hv[3];
                own.add_block(slots[6 + 4 * k], x3, x3, &(g[3] * gr[3].transpose()));
                for a in 0..3 {
                    own.add_block(slots[7 + 4 * k + a], x3, hv[a], &(g[3] * gr[a].transpose()));
                }
            }
        }
        for i in 0..3 {
            own.add_block(slots[i], v[i], v[i], &blk[i]);
            let i1 = (i + 1) % 3;
            own.add_block(slots[3 + i], v[i], v[i1], &blk[3 + i]);
        }
        Ok(())
    }
}
