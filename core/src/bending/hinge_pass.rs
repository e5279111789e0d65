//! Pass 1, per hinge: θ and ψ always; ∇θ and ψ′ for a gradient; ψ″ (and ∇θ) for a Hessian. Each hinge
//! writes its own record, so the pass runs in parallel chunks; the error reported is that of the
//! lowest-numbered failing hinge whatever the thread count.

use nalgebra::Vector3;
#[cfg(feature = "rayon")]
use rayon::prelude::*;

use crate::error::EvalError;
use crate::hinge::{Stencil, theta_and_gradient, theta_only};
use crate::psi::HingePsi;

use super::{BendingModel, Parallelism, Request};

/// Hinges per chunk of the hinge pass: a parallel task, and the unit the energy is summed over (large enough
/// that task overhead is negligible).
pub(super) const HINGE_CHUNK: usize = 4096;

/// One hinge's pass-1 record for pass 2 (ψ goes into the chunk sums, ψ′ into the compact `dpsi` array).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct HingeState {
    pub d2psi: f64,
    pub grad: [Vector3<f64>; 4],
}

/// What pass 1 computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Need {
    /// θ and ψ (an energy-only request).
    Value,
    /// θ, ∇θ, ψ and ψ′ (a gradient).
    Gradient,
    /// θ, ∇θ, ψ, ψ′ and ψ″ (a Hessian).
    All,
}

impl Need {
    pub fn of(request: Request, d2_is_zero: bool) -> Self {
        if request.hessian {
            if d2_is_zero {
                Need::Gradient
            } else {
                Need::All
            }
        } else if request.gradient {
            Need::Gradient
        } else {
            Need::Value
        }
    }
}

impl<P: HingePsi> BendingModel<P> {
    /// Pass 1 over every hinge state (storage order) at storage-ordered positions `xs`; returns the energy.
    /// The energy is summed per chunk of [`HINGE_CHUNK`] slots (in slot order) into `sums`, then over the
    /// chunks in order: the same additions whatever the thread count and whatever the request. ψ′ also
    /// goes to the compact `dpsi` the triangle pass reads. An energy-only request writes no state at all.
    pub(super) fn run_hinge_pass(
        &self,
        xs: &[Vector3<f64>],
        need: Need,
        par: Parallelism,
        states: &mut [HingeState],
        dpsi: &mut [f64],
        sums: &mut [f64],
    ) -> Result<f64, EvalError> {
        let order = &self.layout.state_order[..];
        let n = order.len();
        let keep_first = |first: &mut Option<(u32, EvalError)>, slot: usize, e: EvalError| {
            if first.as_ref().is_none_or(|(h, _)| order[slot] < *h) {
                *first = Some((order[slot], e));
            }
        };
        // One chunk: its ψ sum into `sum`, and its lowest-numbered failing hinge.
        let chunk = |c: usize, states: Option<(&mut [HingeState], &mut [f64])>, sum: &mut f64| {
            let base = c * HINGE_CHUNK;
            let (mut acc, mut first) = (0.0, None);
            match states {
                Some((states, dpsi)) => {
                    for (k, (s, d)) in states.iter_mut().zip(dpsi.iter_mut()).enumerate() {
                        match self.hinge_pass(base + k, xs, need, Some((s, d))) {
                            Ok(psi) => acc += psi,
                            Err(e) => keep_first(&mut first, base + k, e),
                        }
                    }
                }
                None => {
                    for slot in base..(base + HINGE_CHUNK).min(n) {
                        match self.hinge_pass(slot, xs, need, None) {
                            Ok(psi) => acc += psi,
                            Err(e) => keep_first(&mut first, slot, e),
                        }
                    }
                }
            }
            *sum = acc;
            first
        };
        let value_only = need == Need::Value;
        let first_error = match par {
            #[cfg(feature = "rayon")]
            Parallelism::Rayon if value_only => sums
                .par_iter_mut()
                .enumerate()
                .filter_map(|(c, sum)| chunk(c, None, sum))
                .min_by_key(|(h, _)| *h),
            #[cfg(feature = "rayon")]
            Parallelism::Rayon => states
                .par_chunks_mut(HINGE_CHUNK)
                .zip(dpsi.par_chunks_mut(HINGE_CHUNK))
                .zip(sums.par_iter_mut())
                .enumerate()
                .filter_map(|(c, (states, sum))| chunk(c, Some(states), sum))
                .min_by_key(|(h, _)| *h),
            // Sequential; without the rayon feature `Parallelism::Rayon` runs here too.
            _ if value_only => sums
                .iter_mut()
                .enumerate()
                .filter_map(|(c, sum)| chunk(c, None, sum))
                .min_by_key(|(h, _)| *h),
            _ => states
                .chunks_mut(HINGE_CHUNK)
                .zip(dpsi.chunks_mut(HINGE_CHUNK))
                .zip(sums.iter_mut())
                .enumerate()
                .filter_map(|(c, (states, sum))| chunk(c, Some(states), sum))
                .min_by_key(|(h, _)| *h),
        };
        match first_error {
            Some((_, e)) => Err(e),
            None => Ok(sums.iter().sum()),
        }
    }

    /// One hinge: writes its record and ψ′ into `s` (unless energy-only, where `s` is `None`) and returns ψ.
    #[inline]
    fn hinge_pass(
        &self,
        slot: usize,
        xs: &[Vector3<f64>],
        need: Need,
        s: Option<(&mut HingeState, &mut f64)>,
    ) -> Result<f64, EvalError> {
        let i = self.layout.state_order[slot] as usize;
        let [a, b, c, d] = self.layout.state_vertices[slot];
        let st: Stencil = [
            xs[a as usize],
            xs[b as usize],
            xs[c as usize],
            xs[d as usize],
        ];
        let err = |source| {
            let h = &self.topology.hinges()[i];
            EvalError::Hinge {
                hinge: i,
                edge: h.edge,
                vertices: h.vertices,
                source,
            }
        };
        let p = &self.slot_params[slot];
        let (theta, psi, ok) = match need {
            Need::Value => {
                let theta = theta_only(&st).map_err(err)?;
                let psi = self.psi.value(p, theta);
                (theta, psi, psi.is_finite())
            }
            Need::Gradient => {
                let (theta, grad) = theta_and_gradient(&st).map_err(err)?;
                let [psi, dpsi] = self.psi.eval_d1(p, theta);
                if let Some((s, d)) = s {
                    (s.d2psi, s.grad, *d) = (0.0, grad, dpsi);
                }
                (theta, psi, psi.is_finite() && dpsi.is_finite())
            }
            Need::All => {
                let (theta, grad) = theta_and_gradient(&st).map_err(err)?;
                let [psi, dpsi, d2psi] = self.psi.eval(p, theta);
                if let Some((s, d)) = s {
                    (s.d2psi, s.grad, *d) = (d2psi, grad, dpsi);
                }
                let ok = psi.is_finite() && dpsi.is_finite() && d2psi.is_finite();
                (theta, psi, ok)
            }
        };
        if ok {
            Ok(psi)
        } else {
            Err(EvalError::NonFiniteEnergy {
                hinge: i,
                vertices: self.topology.hinges()[i].vertices,
                theta,
            })
        }
    }
}
