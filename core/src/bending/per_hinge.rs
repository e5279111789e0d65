//! The per-hinge kernels: Eqs. 4–6 in closed form ([`super::Method::PerHinge`]) and num-dual's second-order
//! duals over the 12 stencil coordinates ([`super::Method::Autodiff`]); each writes a hinge's 10 blocks.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use num_dual::{Dual2SVec64, hessian};

use crate::autodiff::{flatten, hinge_angle_generic};
use crate::error::EvalError;
use crate::hinge::{BLOCK_PAIRS as PAIRS, HingeFrames, Stencil, hessian_blocks};
use crate::psi::HingePsi;

use super::projection::project_hinge_psd;
use super::scatter::{Ctx, Owned};
use super::{HessianMode, Method};

impl<P: HingePsi> Ctx<'_, P> {
    /// One per-hinge element (closed form or autodiff) for state slot `slot`.
    #[inline]
    pub(super) fn hinge(&self, slot: usize, own: &mut Owned) -> Result<(), (u32, EvalError)> {
        let m = self.model;
        let l = &m.layout;
        let hid = l.state_order[slot] as usize;
        let s = &self.states[slot];
        let hv = l.state_vertices[slot].map(|v| v as usize);
        let st: Stencil = hv.map(|v| self.x[v]);
        let slots = &l.hinge_slots[slot];
        let project = self.request.hessian && self.mode == HessianMode::ProjectPerHinge;
        if self.method == Method::Autodiff {
            let p = &m.slot_params[slot];
            let coords = SVector::<f64, 12>::from(flatten(&st));
            let (_, g, hm): (f64, SVector<f64, 12>, SMatrix<f64, 12, 12>) = hessian(
                |c: SVector<Dual2SVec64<12>, 12>| {
                    let arr: [Dual2SVec64<12>; 12] = c.into();
                    m.psi.psi_dual(p, hinge_angle_generic(&arr))
                },
                &coords,
            );
            if self.request.gradient {
                for a in 0..4 {
                    own.add_grad(hv[a], &Vector3::new(g[3 * a], g[3 * a + 1], g[3 * a + 2]));
                }
            }
            if self.request.hessian {
                let hm = if project {
                    project_hinge_psd(&hm, &st)
                } else {
                    hm
                };
                for (q, &(a, b)) in PAIRS.iter().enumerate() {
                    let blk: Matrix3<f64> = hm.fixed_view::<3, 3>(3 * a, 3 * b).into_owned();
                    own.add_block(slots[q], hv[a], hv[b], &blk);
                }
            }
            return Ok(());
        }
        if self.request.gradient {
            for a in 0..4 {
                own.add_grad(hv[a], &(s.grad[a] * self.dpsi[slot]));
            }
        }
        if !self.request.hessian {
            return Ok(());
        }
        // Same decisions as the hinge pass on the same positions: cannot fail, but is reported if it does.
        let f = HingeFrames::new(&st).map_err(|source| {
            let h = &m.topology.hinges()[hid];
            let err = EvalError::Hinge {
                hinge: hid,
                edge: h.edge,
                vertices: h.vertices,
                source,
            };
            (hid as u32, err)
        })?;
        let g = f.gradient();
        let d2_zero = m.psi.second_derivative_vanishes();
        let (dpsi, d2psi) = match self.mode {
            HessianMode::GaussNewton => (0.0, s.d2psi.max(0.0)),
            _ => (self.dpsi[slot], s.d2psi),
        };
        let hb = if dpsi != 0.0 {
            hessian_blocks(&f)
        } else {
            [[Matrix3::zeros(); 4]; 4]
        };
        let block = |a: usize, b: usize| {
            let mut blk = if a == b {
                (hb[a][a] + hb[a][a].transpose()) * (0.5 * dpsi)
            } else {
                hb[a][b] * dpsi
            };
            if !d2_zero {
                blk += (g[a] * d2psi) * g[b].transpose();
            }
            blk
        };
        if project {
            let mut local = SMatrix::<f64, 12, 12>::zeros();
            for a in 0..4 {
                for b in 0..=a {
                    let blk = block(a, b);
                    local.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&blk);
                    local
                        .fixed_view_mut::<3, 3>(3 * b, 3 * a)
                        .copy_from(&blk.transpose());
                }
            }
            let projected = project_hinge_psd(&local, &st);
            for (q, &(a, b)) in PAIRS.iter().enumerate() {
                let blk: Matrix3<f64> = projected.fixed_view::<3, 3>(3 * a, 3 * b).into_owned();
                own.add_block(slots[q], hv[a], hv[b], &blk);
            }
        } else {
            for (q, &(a, b)) in PAIRS.iter().enumerate() {
                own.add_block(slots[q], hv[a], hv[b], &block(a, b));
            }
        }
        Ok(())
    }
}
