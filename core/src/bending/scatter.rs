//! Pass 2's driver: the partitions of the storage order, what each owns, and how a local 3×3 block is
//! written into the lower-triangle CSC values (shared with [`crate::energy::Accumulator`]).

use nalgebra::{Matrix3, Vector3};

use crate::energy::all_finite;
use crate::error::{ElementRef, EvalError};
use crate::psi::HingePsi;

use super::hinge_pass::HingeState;
use super::setup::Partition;
use super::{BendingModel, HessianMode, Method, Parallelism, Request};

pub(super) const NONE: u32 = u32::MAX;

/// Where a local block goes: the value offset of its first stored entry (`NONE` for a block the pattern does
/// not hold). The offsets in its other two scalar columns follow from the block column's length
/// ([`block_offsets`]), so an element's slot table is a third of what three offsets per block would be: it
/// is read once per evaluation, like the value array itself.
pub(super) type Slot = u32;
pub(super) const NO_SLOT: Slot = NONE;

/// The value offsets of a block's three scalar columns from its first offset and the length `len0` of the
/// first scalar column of its block column (see [`SymmetricPattern`](crate::pattern::SymmetricPattern)'s
/// layout: the diagonal block stores 3, 2, 1 entries per column, an off-diagonal block 3 in each).
#[inline(always)]
pub(crate) fn block_offsets(first: usize, len0: usize, diagonal: bool) -> [usize; 3] {
    if diagonal {
        [first, first + len0, first + 2 * len0 - 1]
    } else {
        [first, first + len0 - 1, first + 2 * len0 - 3]
    }
}

/// How a block `b = H[r][c]` lands in the stored lower block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Orient {
    /// A diagonal block: its lower triangle is stored.
    Diagonal,
    /// The stored block is `(r, c)`: `b` as is.
    AsIs,
    /// The stored block is `(c, r)`: `bᵀ`.
    Transposed,
}

/// Adds `b` into `values` at a block whose three scalar columns start at `off[0..3]` (already relative to
/// `values`), in the orientation `orient`. The one block writer of the crate.
#[inline(always)]
pub(crate) fn add_block_values(
    values: &mut [f64],
    off: [usize; 3],
    orient: Orient,
    b: &Matrix3<f64>,
) {
    match orient {
        Orient::Diagonal => {
            for cc in 0..3 {
                let o = off[cc];
                let dst = &mut values[o..o + 3 - cc];
                for (k, rr) in (cc..3).enumerate() {
                    dst[k] += b[(rr, cc)];
                }
            }
        }
        Orient::AsIs => {
            for cc in 0..3 {
                let o = off[cc];
                let dst = &mut values[o..o + 3];
                dst[0] += b[(0, cc)];
                dst[1] += b[(1, cc)];
                dst[2] += b[(2, cc)];
            }
        }
        Orient::Transposed => {
            for cc in 0..3 {
                let o = off[cc];
                let dst = &mut values[o..o + 3];
                dst[0] += b[(cc, 0)];
                dst[1] += b[(cc, 1)];
                dst[2] += b[(cc, 2)];
            }
        }
    }
}

/// The part of the output one partition owns.
pub(super) struct Owned<'a> {
    /// Storage positions owned.
    vertices: std::ops::Range<usize>,
    /// Owned value offsets (empty when the Hessian is not requested).
    values: std::ops::Range<usize>,
    /// The owned gradient entries, storage order (empty when not requested).
    grad: &'a mut [f64],
    hess: &'a mut [f64],
    /// Length of the first scalar column of each storage block column.
    col_len: &'a [u32],
    /// Benchmark mode: blocks are folded into `checksum` instead of being written.
    local_only: bool,
    checksum: f64,
}

impl Owned<'_> {
    /// Adds `g` to the gradient of storage position `v`, if this partition owns it.
    #[inline]
    pub fn add_grad(&mut self, v: usize, g: &Vector3<f64>) {
        if !self.grad.is_empty() && self.vertices.contains(&v) {
            let o = 3 * (v - self.vertices.start);
            self.grad[o] += g.x;
            self.grad[o + 1] += g.y;
            self.grad[o + 2] += g.z;
        }
    }

    /// Adds block `b` for (row `r`, column `c`; storage positions) at `slot`, if this partition owns it.
    #[inline(always)]
    pub fn add_block(&mut self, slot: Slot, r: usize, c: usize, b: &Matrix3<f64>) {
        if self.local_only {
            self.checksum += b[(0, 0)] + b[(1, 1)] + b[(2, 2)] + b[(2, 0)];
            return;
        }
        let first = slot as usize;
        // A block's three columns lie in one block column, so its first offset decides ownership. NONE
        // (a block the pattern does not hold) and an empty Hessian (not requested) fall outside too.
        if first < self.values.start || first >= self.values.end {
            return;
        }
        let orient = if r == c {
            Orient::Diagonal
        } else if r > c {
            Orient::AsIs
        } else {
            Orient::Transposed
        };
        let len0 = self.col_len[r.min(c)] as usize;
        let off = block_offsets(first - self.values.start, len0, r == c);
        add_block_values(self.hess, off, orient, b);
    }
}

pub(super) struct Ctx<'a, P: HingePsi> {
    pub model: &'a BendingModel<P>,
    /// Positions in storage order.
    pub x: &'a [Vector3<f64>],
    pub states: &'a [HingeState],
    pub dpsi: &'a [f64],
    pub request: Request,
    pub method: Method,
    /// The Hessian mode of this evaluation (the model's, or Gauss–Newton for a definite request).
    pub mode: HessianMode,
    pub local_only: bool,
    /// Add to the Hessian output instead of zeroing it first.
    pub accumulate: bool,
}

/// The lowest-numbered of two errors (by the element they name), so the error reported does not depend on
/// how the work was split.
fn first_of(a: Option<(u32, EvalError)>, b: Option<(u32, EvalError)>) -> Option<(u32, EvalError)> {
    match (a, b) {
        (Some(a), Some(b)) => Some(if b.0 < a.0 { b } else { a }),
        (a, None) => a,
        (None, b) => b,
    }
}

impl<P: HingePsi> Ctx<'_, P> {
    /// Pass 2 over all partitions: `grad` is the storage-ordered gradient (or empty), `hess` the values (or
    /// empty).
    pub fn run(
        &self,
        par: Parallelism,
        grad: &mut [f64],
        hess: &mut [f64],
    ) -> Result<(), EvalError> {
        let parts = &self.model.layout.partitions[..];
        let err = match par {
            Parallelism::Sequential => {
                let mut err = None;
                for p in parts {
                    let (g, h) = (
                        slice_of(grad, 3 * p.vertices.start, 3 * p.vertices.end),
                        slice_of(hess, p.values.start, p.values.end),
                    );
                    err = first_of(err, self.run_partition(p, g, h).err());
                }
                err
            }
            Parallelism::Rayon => self.run_range(parts, grad, hess),
        };
        match err {
            Some((_, e)) => Err(e),
            None => Ok(()),
        }
    }

    fn run_range(
        &self,
        parts: &[Partition],
        grad: &mut [f64],
        hess: &mut [f64],
    ) -> Option<(u32, EvalError)> {
        match parts.len() {
            0 => None,
            1 => self.run_partition(&parts[0], grad, hess).err(),
            n => {
                let (a, b) = parts.split_at(n / 2);
                let gsplit = 3 * (b[0].vertices.start - a[0].vertices.start);
                let hsplit = b[0].values.start - a[0].values.start;
                let (ga, gb) = if grad.is_empty() {
                    (&mut [][..], &mut [][..])
                } else {
                    grad.split_at_mut(gsplit)
                };
                let (ha, hb) = if hess.is_empty() {
                    (&mut [][..], &mut [][..])
                } else {
                    hess.split_at_mut(hsplit)
                };
                #[cfg(feature = "rayon")]
                let (ea, eb) =
                    rayon::join(|| self.run_range(a, ga, ha), || self.run_range(b, gb, hb));
                #[cfg(not(feature = "rayon"))]
                let (ea, eb) = (self.run_range(a, ga, ha), self.run_range(b, gb, hb));
                first_of(ea, eb)
            }
        }
    }

    /// One partition; returns the checksum (benchmark mode) or the first element that could not be
    /// evaluated, as `(triangle or hinge index, error)`.
    fn run_partition(
        &self,
        p: &Partition,
        grad: &mut [f64],
        hess: &mut [f64],
    ) -> Result<f64, (u32, EvalError)> {
        grad.fill(0.0);
        let per_hinge_path = self.method != Method::Refactored
            || (self.request.hessian && self.mode == HessianMode::ProjectPerHinge);
        // The refactored pass zeroes its values just ahead of the elements (`Layout::tri_zero_end`;
        // `hinge bench --only refactored --sizes 400`, three interleaved runs, medians: 4–8 % faster on two
        // threads, −4 … +1 % on one); the per-hinge pass, all of them first.
        let frontier = !self.accumulate && !per_hinge_path && !hess.is_empty();
        if !self.accumulate && !frontier {
            hess.fill(0.0);
        }
        let mut own = Owned {
            vertices: p.vertices.clone(),
            values: if hess.is_empty() {
                0..0
            } else {
                p.values.clone()
            },
            grad,
            hess,
            col_len: &self.model.layout.col_len,
            local_only: self.local_only,
            checksum: 0.0,
        };
        let mut first: Option<(u32, EvalError)> = None;
        if per_hinge_path {
            for &h in &p.hinges {
                if let Err(e) = self.hinge(h as usize, &mut own) {
                    first = first_of(first, Some(e));
                }
            }
        } else {
            // Values below `zeroed` (relative to the partition's) are zero or hold what elements added.
            let zero_end = &self.model.layout.tri_zero_end;
            let mut zeroed = 0;
            for &e in &p.tris {
                if frontier {
                    let end = (zero_end[e as usize] as usize).clamp(p.values.start, p.values.end)
                        - p.values.start;
                    if end > zeroed {
                        // At least a few cache lines at a time.
                        let end = end.max(zeroed + 64).min(own.hess.len());
                        own.hess[zeroed..end].fill(0.0);
                        zeroed = end;
                    }
                }
                if let Err(e) = self.triangle(e as usize, &mut own) {
                    first = first_of(first, Some(e));
                }
            }
            if frontier {
                own.hess[zeroed..].fill(0.0);
            }
        }
        if first.is_none() && !self.local_only && !self.accumulate {
            first = self.non_finite(p, own.grad, own.hess);
        }
        match first {
            Some(e) => Err(e),
            None => Ok(own.checksum),
        }
    }

    /// A non-finite entry among what partition `p` wrote (`grad`: its gradient entries in storage order,
    /// `hess`: its Hessian values; either may be empty). Every hinge's ψ, ψ′ and ψ″ is finite by now (the
    /// hinge pass checked), but their products with ∇θ and Hess θ, and the sums over hinges, can still
    /// overflow f64 (a stiffness of 1e306 at a bent hinge). Named by the lowest caller vertex with a
    /// non-finite gradient entry, else by the lowest caller vertex whose Hessian row (lower triangle) has
    /// one; keyed after every element error (those name hinges or triangles, keys below 2³¹), so the error
    /// reported does not depend on how the partitions were split over threads.
    fn non_finite(&self, p: &Partition, grad: &[f64], hess: &[f64]) -> Option<(u32, EvalError)> {
        let pattern = &*self.model.pattern;
        let worst = |what: &str, found: Option<(usize, f64)>| {
            found.map(|(vertex, value)| {
                let key = (1u32 << 31) | u32::try_from(vertex).map_or(u32::MAX >> 1, |v| v.min(u32::MAX >> 1));
                let err = EvalError::AtElement {
                    energy: "bending".into(),
                    element: ElementRef::Vertex(vertex),
                    message: format!(
                        "its {what} is not finite here ({value}) although every hinge's ψ, ψ′ and ψ″ is: the energy's scale overflows f64 in the derivatives"
                    ),
                };
                (key, err)
            })
        };
        if !all_finite(grad) {
            let found = grad
                .iter()
                .enumerate()
                .filter(|(_, v)| !v.is_finite())
                .map(|(k, &v)| (pattern.order()[p.vertices.start + k / 3] as usize, v))
                .min_by_key(|&(vertex, _)| vertex);
            return worst("gradient", found);
        }
        if !all_finite(hess) {
            let found = hess
                .iter()
                .enumerate()
                .filter(|(_, v)| !v.is_finite())
                .map(|(k, &v)| {
                    (
                        pattern.caller_dof(pattern.row_idx()[p.values.start + k]) / 3,
                        v,
                    )
                })
                .min_by_key(|&(vertex, _)| vertex);
            return worst("Hessian", found);
        }
        None
    }

    /// Benchmark mode over every partition, sequentially; the gradient goes to `grad` (storage order).
    pub fn local_checksum(&self, grad: &mut [f64]) -> Result<f64, EvalError> {
        let mut sum = 0.0;
        for p in &self.model.layout.partitions {
            let g = &mut grad[3 * p.vertices.start..3 * p.vertices.end];
            sum += self.run_partition(p, g, &mut []).map_err(|(_, e)| e)?;
        }
        Ok(sum)
    }
}

fn slice_of(s: &mut [f64], a: usize, b: usize) -> &mut [f64] {
    if s.is_empty() { s } else { &mut s[a..b] }
}
