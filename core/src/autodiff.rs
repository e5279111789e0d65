//! θ, ∇θ and Hess θ by forward-mode automatic differentiation (num-dual) over the 12 stencil coordinates.
//!
//! [`hinge_angle_generic`] is the same θ as [`crate::hinge`] written once for any [`DualNum`] scalar, so
//! `f64`, first- and second-order dual numbers (and higher-precision scalars) all run one code path. It is the
//! test oracle for the closed forms and the slow `autodiff` baseline: a `Dual2SVec64<12>` value is about
//! 1.3 KB, and one Hessian costs microseconds, not nanoseconds.
//!
//! The form used avoids normalising the normals: with unnormalised `u = (x1 − x0) × (x2 − x0)` and
//! `v = (x2 − x3) × (x1 − x3)`, `θ = atan2((u × v) · e0 / |e0|, u · v)`, since scaling both atan2 arguments by
//! the positive `|u||v|` leaves the angle unchanged.

use nalgebra::{SMatrix, SVector};
use num_dual::{Dual2SVec64, DualNum, hessian};

use crate::error::StencilError;
use crate::hinge::{HingeAngleDerivatives, HingeFrames, Stencil};

fn sub<D: DualNum<Primitive = f64> + Copy>(a: [D; 3], b: [D; 3]) -> [D; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross<D: DualNum<Primitive = f64> + Copy>(a: [D; 3], b: [D; 3]) -> [D; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot<D: DualNum<Primitive = f64> + Copy>(a: [D; 3], b: [D; 3]) -> D {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// θ of a stencil given as 12 coordinates `x0.x, x0.y, x0.z, x1.x, …, x3.z`, for any dual scalar.
pub fn hinge_angle_generic<D: DualNum<Primitive = f64> + Copy>(x: &[D; 12]) -> D {
    let p = |v: usize| [x[3 * v], x[3 * v + 1], x[3 * v + 2]];
    let (x0, x1, x2, x3) = (p(0), p(1), p(2), p(3));
    let e0 = sub(x2, x1);
    let u = cross(sub(x1, x0), sub(x2, x0));
    let v = cross(sub(x2, x3), sub(x1, x3));
    let y = dot(cross(u, v), e0) / dot(e0, e0).sqrt();
    atan2(y, dot(u, v))
}

/// `atan2(y, x)` whose derivatives stay accurate for every quadrant.
///
/// num-dual 0.15 differentiates `atan2` through `atan(y / x)`, which loses all digits of the derivatives as
/// `x → 0` (θ near ±π/2 here: we measured 10⁴ ulps of Hessian error there). This version takes
/// `atan(y/x)` where `|x| ≥ |y|` and `±π/2 − atan(x/y)` elsewhere; both branches are exact identities, so
/// the value agrees with `f64::atan2` to rounding and the derivatives are those of a well-conditioned atan.
pub fn atan2<D: DualNum<Primitive = f64> + Copy>(y: D, x: D) -> D {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (yr, xr) = (y.re(), x.re());
    if xr.abs() >= yr.abs() {
        let base = (y / x).atan();
        if xr < 0.0 {
            base + if yr < 0.0 { -PI } else { PI }
        } else {
            base
        }
    } else {
        let quarter = if yr < 0.0 { -FRAC_PI_2 } else { FRAC_PI_2 };
        -(x / y).atan() + quarter
    }
}

/// Flattens a stencil into 12 coordinates.
pub fn flatten(x: &Stencil) -> [f64; 12] {
    let mut out = [0.0; 12];
    for (v, p) in x.iter().enumerate() {
        out[3 * v..3 * v + 3].copy_from_slice(p.as_slice());
    }
    out
}

/// θ, ∇θ and Hess θ of a stencil by num-dual (`Dual2SVec64<12>`).
///
/// # Errors
/// The same stencil checks as the closed form ([`HingeFrames::new`]), so both paths reject the same input.
pub fn hinge_angle_autodiff(x: &Stencil) -> Result<HingeAngleDerivatives, StencilError> {
    HingeFrames::new(x)?;
    let coords = SVector::<f64, 12>::from(flatten(x));
    let (theta, gradient, hess): (f64, SVector<f64, 12>, SMatrix<f64, 12, 12>) = hessian(
        |v: SVector<Dual2SVec64<12>, 12>| {
            let arr: [Dual2SVec64<12>; 12] = v.into();
            hinge_angle_generic(&arr)
        },
        &coords,
    );
    Ok(HingeAngleDerivatives {
        theta,
        gradient,
        hessian: hess,
    })
}
