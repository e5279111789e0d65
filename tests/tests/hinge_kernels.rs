//! The closed-form hinge-angle kernels (θ, ∇θ by Eq. 4, Hess θ by the corrected Eqs. 5–6) against num-dual
//! autodiff and against central finite differences, on seeded random stencils; symmetry and invariances;
//! typed errors on degenerate stencils.

use hinge_core::StencilError;
use hinge_core::autodiff::{flatten, hinge_angle_autodiff, hinge_angle_generic};
use hinge_core::hinge::{
    HingeAngleDerivatives, hinge_angle, hinge_angle_gradient, hinge_angle_hessian, tan_half_angle,
    theta_and_gradient,
};
use hinge_tests::*;
use nalgebra::{Rotation3, Vector3};
use std::f64::consts::PI;

const N_HINGES: usize = 10_000;

/// Bounds in ulps (units of 2⁻⁵³, normwise relative) of closed form vs autodiff. Measured on these 10 000
/// hinges (`cargo test -p hinge-tests --release --test integration hinge_kernels:: -- --nocapture`): gradient median 2.5,
/// p99 6.1, max 9.0; Hessian median 5.2, p99 10.8, max 22.9. The bounds leave under 2× head room.
const GRADIENT_ULPS: f64 = 16.0;
const HESSIAN_ULPS: f64 = 40.0;

/// Target angles: a quarter uniform over (−π + 1e-3, π − 1e-3), a quarter near 0 (|θ| from 1e-12 to 1e-2),
/// a quarter near ±π (π − |θ| from 1e-5 to 1e-1), a quarter uniform.
fn target_theta(rng: &mut SplitMix64, i: usize) -> f64 {
    let sign = if rng.unit() < 0.5 { -1.0 } else { 1.0 };
    match i % 4 {
        0 | 1 => rng.range(-PI + 1e-3, PI - 1e-3),
        2 => sign * 10f64.powf(rng.range(-12.0, -2.0)),
        _ => sign * (PI - 10f64.powf(rng.range(-5.0, -1.0))),
    }
}

fn sample() -> Vec<(f64, hinge_core::hinge::Stencil)> {
    let mut rng = SplitMix64(42);
    (0..N_HINGES)
        .map(|i| {
            let t = target_theta(&mut rng, i);
            (t, random_stencil(&mut rng, t))
        })
        .collect()
}

fn summary(name: &str, e: &[f64]) -> f64 {
    let (med, p99, max) = (quantile(e, 0.5), quantile(e, 0.99), quantile(e, 1.0));
    println!(
        "{name}: median {med:.3e} p99 {p99:.3e} max {max:.3e} over {} hinges",
        e.len()
    );
    max
}

#[test]
fn closed_form_matches_autodiff_on_random_hinges() {
    let (mut eg, mut eh, mut ef) = (Vec::new(), Vec::new(), Vec::new());
    let mut max_abs_theta: f64 = 0.0;
    let mut near_zero = 0;
    for (target, x) in sample() {
        let cf = hinge_angle_hessian(&x).unwrap();
        let ad = hinge_angle_autodiff(&x).unwrap();
        // The engine's unnormalised form of Eq. 4.
        let (tf, gf) = theta_and_gradient(&x).unwrap();
        assert!((tf - ad.theta).abs() < 1e-14);
        let gf: Vec<f64> = gf.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
        ef.push(rel_error(&gf, ad.gradient.as_slice()) / UNIT_ROUNDOFF);
        // Same angle (absolute error: θ's condition number is 1/|θ|-free), and the construction's |θ|.
        assert!(
            (cf.theta - ad.theta).abs() < 1e-14,
            "{} vs {}",
            cf.theta,
            ad.theta
        );
        assert!(
            (cf.theta.abs() - target.abs()).abs() < 1e-9,
            "{} vs target {target}",
            cf.theta
        );
        max_abs_theta = max_abs_theta.max(cf.theta.abs());
        near_zero += usize::from(cf.theta.abs() < 1e-6);
        eg.push(rel_error(cf.gradient.as_slice(), ad.gradient.as_slice()) / UNIT_ROUNDOFF);
        eh.push(rel_error(cf.hessian.as_slice(), ad.hessian.as_slice()) / UNIT_ROUNDOFF);
    }
    println!("max |theta| = {max_abs_theta}, {near_zero} hinges with |theta| < 1e-6");
    assert!(
        max_abs_theta > PI - 1e-3,
        "the sample must reach |θ| close to π"
    );
    assert!(near_zero > 1000, "the sample must include θ near 0");
    let g = summary("gradient closed form vs num-dual (ulps)", &eg);
    let h = summary("hessian closed form vs num-dual (ulps)", &eh);
    let f = summary(
        "unnormalised gradient (theta_and_gradient) vs num-dual (ulps)",
        &ef,
    );
    assert!(f <= GRADIENT_ULPS, "theta_and_gradient: {f} ulps");
    assert!(g <= GRADIENT_ULPS, "gradient: {g} ulps");
    assert!(h <= HESSIAN_ULPS, "hessian: {h} ulps");
}

#[test]
fn closed_form_matches_finite_differences() {
    let (mut eg, mut eh) = (Vec::new(), Vec::new());
    for (_, x) in sample() {
        let cf = hinge_angle_hessian(&x).unwrap();
        let c = flatten(&x);
        let step = 1e-6;
        let theta = |y: &[f64; 12]| hinge_angle(&stencil(y)).unwrap();
        let fd_g = fd_gradient(theta, &c, step);
        eg.push(rel_error(cf.gradient.as_slice(), &fd_g));
        let mut fd_h = [0.0; 144];
        for i in 0..12 {
            let (mut xp, mut xm) = (c, c);
            xp[i] += step;
            xm[i] -= step;
            let gp = hinge_angle_hessian(&stencil(&xp)).unwrap().gradient;
            let gm = hinge_angle_hessian(&stencil(&xm)).unwrap().gradient;
            for j in 0..12 {
                fd_h[12 * i + j] = (gp[j] - gm[j]) / (2.0 * step);
            }
        }
        eh.push(rel_error(cf.hessian.as_slice(), &fd_h));
    }
    let g = summary("gradient vs central FD (relative)", &eg);
    let h = summary("hessian vs central FD of the gradient (relative)", &eh);
    // FD truncation (h² ≈ 1e-12) plus cancellation (ε/h ≈ 1e-10); measured max 4.8e-10 (gradient) and
    // 3.6e-10 (Hessian).
    assert!(g < 2e-9, "gradient vs FD: {g}");
    assert!(h < 2e-9, "hessian vs FD: {h}");
}

#[test]
fn generic_theta_in_f64_matches_closed_form() {
    for (_, x) in sample().into_iter().take(1000) {
        let a = hinge_angle_generic(&flatten(&x));
        let b = hinge_angle(&x).unwrap();
        assert!((a - b).abs() < 1e-14, "{a} vs {b}");
    }
}

#[test]
fn sign_convention_is_pinned() {
    // n = +z for the upper triangle; lifting x3 toward +n folds the hinge to θ = −π/4.
    let x = [
        Vector3::new(0.5, 1.0, 0.0),
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.5, -1.0, 1.0),
    ];
    let theta = hinge_angle(&x).unwrap();
    assert!((theta + PI / 4.0).abs() <= 2.0 * f64::EPSILON, "{theta}");
    let mut y = x;
    y[3].z = -1.0;
    assert!((hinge_angle(&y).unwrap() - PI / 4.0).abs() <= 2.0 * f64::EPSILON);
    // Flat: exactly zero.
    y[3].z = 0.0;
    assert_eq!(hinge_angle(&y).unwrap(), 0.0);
}

#[test]
fn tan_half_angle_by_eq12_matches_theta() {
    for (_, x) in sample() {
        let theta = hinge_angle(&x).unwrap();
        let t = tan_half_angle(&x).unwrap();
        // Compare the angles: 2·atan(tan(θ/2)) is well conditioned everywhere.
        let back = 2.0 * t.atan();
        assert!(
            (back - theta).abs() < 1e-13 * (1.0 + theta.abs()),
            "{back} vs {theta}"
        );
    }
}

fn sym_check(d: &HingeAngleDerivatives) {
    for i in 0..12 {
        for j in 0..12 {
            assert_eq!(
                d.hessian[(i, j)].to_bits(),
                d.hessian[(j, i)].to_bits(),
                "H[{i},{j}]"
            );
        }
    }
}

#[test]
fn hessian_is_exactly_symmetric() {
    for (_, x) in sample().into_iter().take(2000) {
        sym_check(&hinge_angle_hessian(&x).unwrap());
    }
}

#[test]
fn swapping_the_triangles_leaves_theta_unchanged() {
    for (_, x) in sample().into_iter().take(2000) {
        let swapped = [x[3], x[2], x[1], x[0]];
        let (t, g) = hinge_angle_gradient(&x).unwrap();
        let (ts, gs) = hinge_angle_gradient(&swapped).unwrap();
        assert_eq!(t.to_bits(), ts.to_bits());
        for v in 0..4 {
            assert_eq!(g[v], gs[3 - v], "gradient of x{v}");
        }
        let h = hinge_angle_hessian(&x).unwrap().hessian;
        let hs = hinge_angle_hessian(&swapped).unwrap().hessian;
        let mut permuted = h;
        for a in 0..4 {
            for b in 0..4 {
                permuted
                    .fixed_view_mut::<3, 3>(3 * a, 3 * b)
                    .copy_from(&hs.fixed_view::<3, 3>(3 * (3 - a), 3 * (3 - b)));
            }
        }
        // Same terms, summed in another order: measured at most 8.8 ulps.
        let e = rel_error(permuted.as_slice(), h.as_slice()) / UNIT_ROUNDOFF;
        assert!(e <= 16.0, "swapped Hessian differs by {e} ulps");
    }
}

#[test]
fn rigid_motion_and_uniform_scaling() {
    let mut rng = SplitMix64(9);
    for (_, x) in sample().into_iter().take(2000) {
        let d = hinge_angle_hessian(&x).unwrap();
        let rot =
            Rotation3::new(Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 2.0);
        let shift = Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 10.0;
        let moved = x.map(|p| rot * p + shift);
        let dm = hinge_angle_hessian(&moved).unwrap();
        assert!(
            (dm.theta - d.theta).abs() < 1e-12,
            "{} vs {}",
            dm.theta,
            d.theta
        );
        // ∇θ rotates with the mesh, Hess θ as R H Rᵀ block by block.
        let mut g_rot = d.gradient;
        let mut h_rot = d.hessian;
        let r = rot.matrix();
        for a in 0..4 {
            g_rot
                .fixed_rows_mut::<3>(3 * a)
                .copy_from(&(r * d.gradient.fixed_rows::<3>(3 * a)));
            for b in 0..4 {
                let blk = r * d.hessian.fixed_view::<3, 3>(3 * a, 3 * b) * r.transpose();
                h_rot.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&blk);
            }
        }
        assert!(rel_error(dm.gradient.as_slice(), g_rot.as_slice()) < 1e-12);
        assert!(rel_error(dm.hessian.as_slice(), h_rot.as_slice()) < 1e-12);

        // The ends of `STENCIL_SIZE_RANGE` (the sample's stencils are of size about 1): evaluated as
        // unscaled.
        for s in [3.7e-4, 2.9e5, 1e-59, 1e59] {
            let scaled = x.map(|p| p * s);
            let ds = hinge_angle_hessian(&scaled).unwrap();
            assert!((ds.theta - d.theta).abs() < 1e-12);
            assert!(rel_error((ds.gradient * s).as_slice(), d.gradient.as_slice()) < 1e-13);
            assert!(rel_error((ds.hessian * (s * s)).as_slice(), d.hessian.as_slice()) < 1e-13);
        }
    }
}

#[test]
fn degenerate_stencils_give_typed_errors() {
    let good = [
        Vector3::new(0.5, 1.0, 0.0),
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.5, -1.0, 0.3),
    ];
    assert!(hinge_angle_hessian(&good).is_ok());

    // x0 on the line of the hinge edge: altitude collapse in the upper triangle at x0.
    let mut x = good;
    x[0] = Vector3::new(0.25, 0.0, 0.0);
    match hinge_angle_hessian(&x) {
        Err(StencilError::AltitudeCollapse { side, vertex, .. }) => {
            assert_eq!(side, hinge_core::HingeSide::Upper);
            assert_eq!(vertex, 0);
        }
        other => panic!("expected altitude collapse, got {other:?}"),
    }
    // x3 on the line: the lower triangle.
    let mut x = good;
    x[3] = Vector3::new(0.75, 0.0, 0.0);
    assert!(matches!(
        hinge_angle_gradient(&x),
        Err(StencilError::AltitudeCollapse {
            side: hinge_core::HingeSide::Lower,
            vertex: 3,
            ..
        })
    ));
    // A collapsed hinge edge.
    let mut x = good;
    x[2] = x[1];
    assert!(matches!(
        hinge_angle(&x),
        Err(StencilError::ZeroLengthHingeEdge { .. })
    ));
    // Beyond the size range the checks fail for rounding's sake, and say so: a sound stencil scaled to
    // 1e300 (its squared lengths overflow) or 1e-300 (they underflow to zero) is out of range, not a
    // collapsed edge; a collapsed edge at an ordinary size is still one.
    for s in [1e300, 1e-300, 1e80, 1e-80] {
        let x = good.map(|p| p * s);
        for r in [
            hinge_angle(&x).map(|_| ()),
            hinge_angle_hessian(&x).map(|_| ()),
            hinge_angle_autodiff(&x).map(|_| ()),
        ] {
            match r {
                Err(StencilError::OutOfRange { size }) => {
                    assert!(size > 0.5 * s && size < 2.0 * s, "{size} for scale {s}")
                }
                other => panic!("scale {s}: expected out of range, got {other:?}"),
            }
        }
    }
    let mut x = good.map(|p| p * 1e300);
    x[2] = x[1];
    assert!(matches!(
        hinge_angle(&x),
        Err(StencilError::OutOfRange { .. })
    ));
    // Non-finite input, and the autodiff path rejects the same stencils.
    let mut x = good;
    x[2].y = f64::NAN;
    assert!(matches!(
        hinge_angle_hessian(&x),
        Err(StencilError::NonFinite { coordinate: 7 })
    ));
    assert!(matches!(
        hinge_angle_autodiff(&x),
        Err(StencilError::NonFinite { coordinate: 7 })
    ));
    assert!(tan_half_angle(&x).is_err());
    // Nearly degenerate (relative altitude 1e-12) is still evaluated, and finite.
    let mut x = good;
    x[0] = Vector3::new(0.5, 1e-12, 0.0);
    let d = hinge_angle_hessian(&x).unwrap();
    assert!(d.hessian.iter().all(|v| v.is_finite()));
}

#[test]
fn closed_form_and_num_dual_against_the_double_double_reference() {
    use hinge_core::precise::reference_hinge_angle;
    let (mut cf_h, mut ad_h, mut cf_g) = (Vec::new(), Vec::new(), Vec::new());
    for (_, x) in sample().into_iter().step_by(10) {
        let flat = flatten(&x);
        let r = reference_hinge_angle(&flat);
        assert!((r.v.to_f64() - hinge_angle(&x).unwrap()).abs() < 1e-15);
        let href: Vec<_> = (0..144).map(|k| r.hessian(k / 12, k % 12)).collect();
        let cf = hinge_angle_hessian(&x).unwrap();
        let ad = hinge_angle_autodiff(&x).unwrap();
        // nalgebra stores column-major; the Hessian is symmetric, so the order does not matter.
        cf_h.push(hinge_core::precise::ulps(cf.hessian.as_slice(), &href));
        ad_h.push(hinge_core::precise::ulps(ad.hessian.as_slice(), &href));
        cf_g.push(hinge_core::precise::ulps(cf.gradient.as_slice(), &r.g));
    }
    let g = summary(
        "gradient closed form vs double-double reference (ulps)",
        &cf_g,
    );
    let c = summary(
        "hessian closed form vs double-double reference (ulps)",
        &cf_h,
    );
    let a = summary("hessian num-dual vs double-double reference (ulps)", &ad_h);
    assert!(g <= GRADIENT_ULPS && c <= HESSIAN_ULPS, "{g} {c}");
    // num-dual rounds in f64 too: a few ulps, and it must not be exact (else the reference is not
    // independent of f64 rounding).
    assert!(a <= HESSIAN_ULPS && quantile(&ad_h, 0.5) > 0.1, "{a}");
}
