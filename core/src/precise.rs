//! A higher-precision reference for hinge Hessians: double-double arithmetic ([`Dd`], about 106 bits) and
//! second-order forward-mode differentiation over it ([`Jet`]), so that ψ(θ(x)) of one hinge is
//! differentiated twice with no formula of ours involved and about 32 significant digits.
//!
//! Why this route: the f64 methods (closed form, per-hinge, num-dual) all round at 2⁻⁵³; their errors can
//! only be told apart against something about 10¹⁶ times more accurate. num-dual's scalar must be `f32` or
//! `f64` (its `DualNumFloat` is sealed to those by the orphan rule), so the reference differentiates θ's
//! definition — `atan2((u × v)·e/|e|, u·v)` with unnormalised normals — with its own jets over
//! double-double. Its derivatives are exact for the operations it is given; the only rounding is
//! double-double's (≈ 2⁻¹⁰⁴ relative per operation), far below one f64 ulp.
//!
//! ```
//! use hinge_core::precise::{Dd, reference_hinge_hessian};
//! let x = [0.0, 0.0, 0.0, 1.0, 0.1, 0.0, 0.1, 1.0, 0.0, 1.1, 1.2, 0.3];
//! // ψ = θ²: the reference gradient of θ² at θ ≈ … agrees with f64 arithmetic to rounding.
//! let (psi, grad, hess) = reference_hinge_hessian(&x, |t| t * t);
//! assert!(psi.to_f64() > 0.0 && hess[0][0].to_f64().is_finite());
//! assert!(grad.iter().any(|g| g.to_f64() != 0.0));
//! let third = Dd::from(1.0) / Dd::from(3.0);
//! assert!(((third * Dd::from(3.0)) - Dd::from(1.0)).to_f64().abs() < 1e-31);
//! ```

use std::ops::{Add, Div, Mul, Neg, Sub};

/// A double-double number `hi + lo` with `|lo| ≤ ulp(hi)/2`: about 106 significant bits.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Default)]
pub struct Dd {
    /// Leading part.
    pub hi: f64,
    /// Trailing part.
    pub lo: f64,
}

#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

#[inline]
fn quick_two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    (s, b - (s - a))
}

#[inline]
fn two_prod(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    (p, a.mul_add(b, -p))
}

/// π as a double-double.
pub const DD_PI: Dd = Dd {
    hi: std::f64::consts::PI,
    lo: 1.224_646_799_147_353_2e-16,
};
const DD_FRAC_PI_2: Dd = Dd {
    hi: std::f64::consts::FRAC_PI_2,
    lo: 6.123_233_995_736_766e-17,
};

impl From<f64> for Dd {
    fn from(x: f64) -> Self {
        Self { hi: x, lo: 0.0 }
    }
}

impl Dd {
    /// Rounds to the nearest f64.
    pub fn to_f64(self) -> f64 {
        self.hi + self.lo
    }

    /// Absolute value.
    pub fn abs(self) -> Self {
        if self.hi < 0.0 { -self } else { self }
    }

    /// Square root (one Newton step from the f64 root; 0 for non-positive input).
    pub fn sqrt(self) -> Self {
        if self.hi <= 0.0 {
            return Dd::from(0.0);
        }
        let q = Dd::from(self.hi.sqrt());
        q + (self - q * q) / (q * 2.0)
    }

    /// sin and cos, by reduction modulo π/2 and Taylor series (|x| up to a few thousand).
    pub fn sin_cos(self) -> (Self, Self) {
        let k = (self.hi / std::f64::consts::FRAC_PI_2).round();
        let r = self - DD_FRAC_PI_2 * k;
        // Taylor series on |r| ≤ π/4 + tiny: terms fall below 2⁻¹¹⁰ by n = 27.
        let r2 = r * r;
        let (mut s, mut c) = (r, Dd::from(1.0));
        let (mut ts, mut tc) = (r, Dd::from(1.0));
        let mut n = 1.0;
        while n < 40.0 {
            ts = -(ts * r2) / ((n + 1.0) * (n + 2.0));
            tc = -(tc * r2) / (n * (n + 1.0));
            s = s + ts;
            c = c + tc;
            if ts.hi.abs() < 1e-36 && tc.hi.abs() < 1e-36 {
                break;
            }
            n += 2.0;
        }
        match (k as i64).rem_euclid(4) {
            0 => (s, c),
            1 => (c, -s),
            2 => (-s, -c),
            _ => (-c, s),
        }
    }

    /// tan.
    pub fn tan(self) -> Self {
        let (s, c) = self.sin_cos();
        s / c
    }

    /// atan2(y = self, x): f64 estimate refined by one Newton step on `y cos θ − x sin θ = 0`.
    pub fn atan2(self, x: Self) -> Self {
        let t0 = Dd::from(self.hi.atan2(x.hi));
        let (s, c) = t0.sin_cos();
        // tan(θ − θ0) = (y c − x s)/(x c + y s); its size is ~1e-16, so atan of it is itself to 2⁻¹⁰⁶.
        let d = (self * c - x * s) / (x * c + self * s);
        t0 + d
    }
}

impl Neg for Dd {
    type Output = Dd;
    fn neg(self) -> Dd {
        Dd {
            hi: -self.hi,
            lo: -self.lo,
        }
    }
}

impl Add for Dd {
    type Output = Dd;
    fn add(self, y: Dd) -> Dd {
        let (s, e) = two_sum(self.hi, y.hi);
        let (t, f) = two_sum(self.lo, y.lo);
        let (s, e) = quick_two_sum(s, e + t);
        let (hi, lo) = quick_two_sum(s, e + f);
        Dd { hi, lo }
    }
}

impl Sub for Dd {
    type Output = Dd;
    fn sub(self, y: Dd) -> Dd {
        self + (-y)
    }
}

impl Mul for Dd {
    type Output = Dd;
    fn mul(self, y: Dd) -> Dd {
        let (p, e) = two_prod(self.hi, y.hi);
        let (hi, lo) = quick_two_sum(p, e + (self.hi * y.lo + self.lo * y.hi));
        Dd { hi, lo }
    }
}

impl Mul<f64> for Dd {
    type Output = Dd;
    fn mul(self, y: f64) -> Dd {
        self * Dd::from(y)
    }
}

impl Div for Dd {
    type Output = Dd;
    fn div(self, y: Dd) -> Dd {
        let q1 = self.hi / y.hi;
        let r = self - y * q1;
        let q2 = r.hi / y.hi;
        let r = r - y * q2;
        let q3 = r.hi / y.hi;
        let (hi, lo) = quick_two_sum(q1, q2);
        Dd { hi, lo } + Dd::from(q3)
    }
}

impl Div<f64> for Dd {
    type Output = Dd;
    fn div(self, y: f64) -> Dd {
        self / Dd::from(y)
    }
}

/// Number of variables of a hinge stencil.
pub const N: usize = 12;

/// A value with its gradient and Hessian over the 12 stencil coordinates, in double-double.
#[derive(Debug, Clone, Copy)]
pub struct Jet {
    /// Value.
    pub v: Dd,
    /// Gradient.
    pub g: [Dd; N],
    /// Hessian: the upper triangle `h[i][j]`, `i ≤ j`, is kept (the rest is zero); read it with
    /// [`Jet::hessian`].
    pub h: [[Dd; N]; N],
}

impl Jet {
    /// A constant.
    pub fn constant(v: Dd) -> Self {
        Self {
            v,
            g: [Dd::default(); N],
            h: [[Dd::default(); N]; N],
        }
    }

    /// Variable `i` with value `v`.
    pub fn variable(i: usize, v: f64) -> Self {
        let mut j = Self::constant(Dd::from(v));
        j.g[i] = Dd::from(1.0);
        j
    }

    /// `f(self)` given `f`, `f′`, `f″` at the value: chain rule to second order.
    pub fn chain(&self, f: Dd, d1: Dd, d2: Dd) -> Self {
        let mut out = Self::constant(f);
        for i in 0..N {
            out.g[i] = d1 * self.g[i];
            for j in i..N {
                out.h[i][j] = d1 * self.h[i][j] + d2 * self.g[i] * self.g[j];
            }
        }
        out
    }

    /// Hessian entry `(i, j)` in either order.
    pub fn hessian(&self, i: usize, j: usize) -> Dd {
        self.h[i.min(j)][i.max(j)]
    }

    /// Square root.
    pub fn sqrt(&self) -> Self {
        let s = self.v.sqrt();
        let d1 = Dd::from(0.5) / s;
        let d2 = -(d1 / (self.v * 2.0));
        self.chain(s, d1, d2)
    }

    /// tan.
    pub fn tan(&self) -> Self {
        let t = self.v.tan();
        let d1 = Dd::from(1.0) + t * t;
        self.chain(t, d1, t * d1 * 2.0)
    }

    /// `atan2(self, x)`.
    pub fn atan2(&self, x: &Jet) -> Self {
        let y = self;
        let r2 = x.v * x.v + y.v * y.v;
        let (ty, tx) = (x.v / r2, -(y.v / r2));
        let r4 = r2 * r2;
        let tyy = -(x.v * y.v * 2.0) / r4;
        let txx = (x.v * y.v * 2.0) / r4;
        let txy = (y.v * y.v - x.v * x.v) / r4;
        let mut out = Self::constant(y.v.atan2(x.v));
        for i in 0..N {
            out.g[i] = ty * y.g[i] + tx * x.g[i];
            for j in i..N {
                out.h[i][j] = ty * y.h[i][j]
                    + tx * x.h[i][j]
                    + tyy * y.g[i] * y.g[j]
                    + txx * x.g[i] * x.g[j]
                    + txy * (x.g[i] * y.g[j] + y.g[i] * x.g[j]);
            }
        }
        out
    }
}

impl Add for Jet {
    type Output = Jet;
    fn add(mut self, b: Jet) -> Jet {
        self.v = self.v + b.v;
        for i in 0..N {
            self.g[i] = self.g[i] + b.g[i];
            for j in i..N {
                self.h[i][j] = self.h[i][j] + b.h[i][j];
            }
        }
        self
    }
}

impl Neg for Jet {
    type Output = Jet;
    fn neg(mut self) -> Jet {
        self.v = -self.v;
        for i in 0..N {
            self.g[i] = -self.g[i];
            for j in i..N {
                self.h[i][j] = -self.h[i][j];
            }
        }
        self
    }
}

impl Sub for Jet {
    type Output = Jet;
    fn sub(self, b: Jet) -> Jet {
        self + (-b)
    }
}

impl Mul for Jet {
    type Output = Jet;
    fn mul(self, b: Jet) -> Jet {
        let mut out = Jet::constant(self.v * b.v);
        for i in 0..N {
            out.g[i] = self.v * b.g[i] + b.v * self.g[i];
            for j in i..N {
                out.h[i][j] = self.v * b.h[i][j]
                    + b.v * self.h[i][j]
                    + self.g[i] * b.g[j]
                    + b.g[i] * self.g[j];
            }
        }
        out
    }
}

impl Mul<Dd> for Jet {
    type Output = Jet;
    fn mul(mut self, c: Dd) -> Jet {
        self.v = self.v * c;
        for i in 0..N {
            self.g[i] = self.g[i] * c;
            for j in i..N {
                self.h[i][j] = self.h[i][j] * c;
            }
        }
        self
    }
}

impl Div for Jet {
    type Output = Jet;
    fn div(self, b: Jet) -> Jet {
        let inv = Dd::from(1.0) / b.v;
        let r = b.chain(inv, -(inv * inv), inv * inv * inv * 2.0);
        self * r
    }
}

fn sub3(a: &[Jet; 3], b: &[Jet; 3]) -> [Jet; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross3(a: &[Jet; 3], b: &[Jet; 3]) -> [Jet; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot3(a: &[Jet; 3], b: &[Jet; 3]) -> Jet {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// θ of a stencil (`x0.x, x0.y, …, x3.z`) with its gradient and Hessian, in double-double: the definition
/// `θ = atan2((u × v)·e0/|e0|, u·v)`, `u = (x1 − x0) × (x2 − x0)`, `v = (x2 − x3) × (x1 − x3)`,
/// `e0 = x2 − x1`, differentiated by jets.
pub fn reference_hinge_angle(x: &[f64; 12]) -> Jet {
    let p = |v: usize| {
        [
            Jet::variable(3 * v, x[3 * v]),
            Jet::variable(3 * v + 1, x[3 * v + 1]),
            Jet::variable(3 * v + 2, x[3 * v + 2]),
        ]
    };
    let (x0, x1, x2, x3) = (p(0), p(1), p(2), p(3));
    let e0 = sub3(&x2, &x1);
    let u = cross3(&sub3(&x1, &x0), &sub3(&x2, &x0));
    let v = cross3(&sub3(&x2, &x3), &sub3(&x1, &x3));
    let y = dot3(&cross3(&u, &v), &e0) / dot3(&e0, &e0).sqrt();
    y.atan2(&dot3(&u, &v))
}

/// ψ(θ(x)) of one hinge with its gradient and full Hessian (12×12) in double-double; `psi` maps the θ jet
/// to the ψ jet (write it with [`Jet`]'s operations and constants from [`Jet::constant`]).
pub fn reference_hinge_hessian(
    x: &[f64; 12],
    psi: impl Fn(Jet) -> Jet,
) -> (Dd, [Dd; N], [[Dd; N]; N]) {
    let j = psi(reference_hinge_angle(x));
    let mut h = [[Dd::default(); N]; N];
    for (r, row) in h.iter_mut().enumerate() {
        for (c, e) in row.iter_mut().enumerate() {
            *e = j.hessian(r, c);
        }
    }
    (j.v, j.g, h)
}

/// Normwise relative error `‖a − r‖ / ‖r‖` of f64 values against a double-double reference, the difference
/// taken in double-double, in units of 2⁻⁵³ (ulps). Entry `k` counts `weight(k)` times (2 for an
/// off-diagonal entry stored once for a symmetric matrix, 1 otherwise).
pub fn ulps_weighted(a: &[f64], r: &[Dd], weight: impl Fn(usize) -> f64) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (k, (x, y)) in a.iter().zip(r).enumerate() {
        let (d, y) = ((Dd::from(*x) - *y).to_f64(), y.to_f64());
        num += weight(k) * d * d;
        den += weight(k) * y * y;
    }
    (num / den).sqrt() / (f64::EPSILON / 2.0)
}

/// [`ulps_weighted`] with every entry counted once.
pub fn ulps(a: &[f64], r: &[Dd]) -> f64 {
    ulps_weighted(a, r, |_| 1.0)
}

/// The reference Hessian of `Σ_h ψ_h(θ_h)` over `model`'s hinges at `x`, each hinge's 12×12 Hessian computed
/// in double-double by [`reference_hinge_hessian`] and assembled into `model`'s pattern (its lower CSC values,
/// storage order). `psi(h, θ)` maps hinge `h`'s θ jet to its ψ jet (use [`crate::bending::BendingModel::rest_hinges`]
/// for θ̄ and `a`). What `hinge report`, `hinge stability` and the tests compare every method against.
pub fn reference_hessian<P: crate::psi::HingePsi>(
    model: &crate::bending::BendingModel<P>,
    x: &[nalgebra::Vector3<f64>],
    psi: impl Fn(usize, Jet) -> Jet + Sync,
) -> Vec<Dd> {
    let hinges = model.topology().hinges();
    let local = |i: usize| {
        let mut s = [0.0; 12];
        for (a, &v) in hinges[i].vertices.iter().enumerate() {
            s[3 * a..3 * a + 3].copy_from_slice(x[v].as_slice());
        }
        reference_hinge_hessian(&s, |t| psi(i, t)).2
    };
    #[cfg(feature = "rayon")]
    let locals: Vec<[[Dd; N]; N]> = {
        use rayon::prelude::*;
        (0..hinges.len()).into_par_iter().map(local).collect()
    };
    #[cfg(not(feature = "rayon"))]
    let locals: Vec<[[Dd; N]; N]> = (0..hinges.len()).map(local).collect();
    let pattern = model.pattern();
    let mut values = vec![Dd::default(); pattern.nnz()];
    for (h, local) in hinges.iter().zip(&locals) {
        for a in 0..4 {
            for b in 0..4 {
                let (va, vb) = (h.vertices[a], h.vertices[b]);
                // The stored lower block is the one whose row comes later in the storage order.
                if pattern.storage_of(va) < pattern.storage_of(vb) {
                    continue;
                }
                let Some(slot) = pattern.find(va, vb) else {
                    continue;
                };
                let off = pattern.blocks()[slot].offset;
                for c in 0..3 {
                    let rows = if va == vb { c..3 } else { 0..3 };
                    for r in rows {
                        let o = off[c] as usize + if va == vb { r - c } else { r };
                        values[o] = values[o] + local[3 * a + r][3 * b + c];
                    }
                }
            }
        }
    }
    values
}

/// [`ulps_weighted`] of a symmetric matrix stored as `pattern`'s lower triangle: off-diagonal entries count
/// twice (the normwise error of the full matrix).
pub fn hessian_ulps(
    pattern: &crate::pattern::SymmetricPattern,
    values: &[f64],
    reference: &[Dd],
) -> f64 {
    let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
    let mut weight = vec![2.0; pattern.nnz()];
    for c in 0..pattern.dim() {
        for k in cp[c]..cp[c + 1] {
            if ri[k] == c {
                weight[k] = 1.0;
            }
        }
    }
    ulps_weighted(values, reference, |k| weight[k])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn double_double_arithmetic() {
        let third = Dd::from(1.0) / Dd::from(3.0);
        assert!((third * 3.0 - Dd::from(1.0)).to_f64().abs() < 1e-31);
        let two = Dd::from(2.0).sqrt();
        assert!((two * two - Dd::from(2.0)).to_f64().abs() < 1e-31);
        for x in [0.3, 1.0, 2.5, -3.0, 7.0] {
            let (s, c) = Dd::from(x).sin_cos();
            assert!(
                (s * s + c * c - Dd::from(1.0)).to_f64().abs() < 1e-30,
                "{x}"
            );
            assert!((s.to_f64() - x.sin()).abs() < 2e-16);
            let t = Dd::from(x).atan2(Dd::from(1.0));
            assert!((t.to_f64() - x.atan()).abs() < 4e-16);
            let (st, ct) = t.sin_cos();
            assert!((st / ct - Dd::from(x)).to_f64().abs() < 1e-30 * x.abs().max(1.0));
        }
        // atan2 in every quadrant.
        for (y, x) in [(1.0, -2.0), (-1.0, -2.0), (-3.0, 0.5), (2.0, 1e-9)] {
            let t = Dd::from(y).atan2(Dd::from(x));
            assert!((t.to_f64() - f64::atan2(y, x)).abs() < 4e-16);
        }
        assert!((DD_PI.to_f64() - std::f64::consts::PI).abs() == 0.0);
    }
}
