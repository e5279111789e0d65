//! Positive semi-definite projection of a local Hessian ([`super::HessianMode::ProjectPerHinge`]).
//!
//! # Why an eigensolver, and not a closed form
//! The issue that asked for this module hoped for the analytic eigensystem of Wang, Yang & Wang (2023). We
//! checked it for this project's ψ family and found no closed form for the *exact* projection:
//! - `Hess θ` has four positive, four negative and four zero eigenvalues (confirmed on 10 000 random stencils
//!   by `hess_theta_inertia_is_four_four_four` below), and `∇θ` lies in its range. The hinge Hessian
//!   `H = ψ″ ∇θ∇θᵀ + ψ′ Hess θ` is, on that 8-dimensional range, `ψ′ Λ + ψ″ γγᵀ` with `γ` the components of
//!   `∇θ` on `Hess θ`'s eigenvectors, all eight of them non-zero on random stencils (same test).
//! - The eigenvalues `μ = ψ′ s` of such a matrix solve `ψ″/ψ′ = t(s)` with the degree-8 rational map
//!   `t(s) = Σ_k γ_k² / (s − λ_k)`. Following the eight roots around each of its 14 branch points (the script
//!   `docs/projection/monodromy.py`, output in `docs/projection/monodromy.txt`) gives a transposition every
//!   time, and the transpositions connect all eight roots: the monodromy group is the full symmetric group
//!   S₈, which is not solvable. So no formula in radicals gives the eigenvalues as functions of `ψ″/ψ′`,
//!   and since a ψ from the derive can make that ratio anything, no closed form covers the family.
//! - Not even `Hess θ` alone (the whole Hessian of a ψ linear in θ, and what a rank-one secular-equation
//!   update of a closed form would have to start from) has eigenvalues in closed form: at stencils with
//!   rational coordinates and a hinge edge of rational length along an axis, its eight non-zero
//!   eigenvalues are the roots of an octic with rational coefficients, irreducible over ℚ and over ℚ with
//!   the normals' square roots adjoined, whose factorization patterns modulo primes contain a 7-cycle and
//!   a transposition (Dedekind): its Galois group is S₈, so the roots are not expressible in radicals of
//!   the coordinates (exact rational arithmetic, `docs/projection/galois.py`, output in
//!   `docs/projection/galois.txt`: five stencils, S₈ at each). An "analytic eigensystem" of the dihedral
//!   angle's Hessian can therefore only be one of an approximation of it.
//! - Projecting the two terms separately (`max(ψ″, 0) ∇θ∇θᵀ` plus the projection of `ψ′ Hess θ`, which is
//!   what a per-term analytic eigensystem gives) is PSD but not the nearest PSD matrix: it differs from the
//!   exact projection by far more than 1e-10 (test `termwise_projection_is_not_the_projection`).
//!
//! The projection is therefore computed by an eigensolver (module `eigen`: Householder tridiagonalization
//! and implicit QR with Wilkinson shifts on fixed-size arrays, cyclic Jacobi as the fallback when it does
//! not converge). nalgebra 0.35's `symmetric_eigen`, used before, returned NaN eigenvectors on a rank-one
//! hinge Hessian with entries of 1e-2 and 1e-64 from the drape (test `jacobi_survives_the_drape_matrix`).
//!
//! # The null space: an 8×8 eigenproblem instead of 12×12
//! `Hess θ`'s four-dimensional null space is known in closed form: the three translations, and the
//! *stretch along the hinge*, vertex `i` moving by `((x_i − x1)·ê) ê` (ê the unit hinge edge). Every move
//! along `ê` keeps both triangles in their planes, so θ is constant on the affine space of such moves and
//! only the gradients of the hinge ends change (through where the wings' feet fall on the edge); the
//! affine stretch keeps those feet at the same fractions of the edge, so `∇θ` does not change either
//! (test `hess_theta_null_space_is_the_translations_and_the_stretch_along_the_edge`, against num-dual).
//! Since `∇θ` lies in the range, every hinge Hessian `H` of a ψ of θ alone vanishes on that null space,
//! `H = Q H₈ Qᵀ` with an orthonormal 12×8 basis `Q` of its complement, and the projection is
//! `Q (H₈)₊ Qᵀ` ([`project_hinge_psd`]): the eigensolver works on 8×8 (test
//! `hinge_projection_equals_faer_projection`: 10 000 random and sliver stencils, ψ′ and ψ″ of either sign
//! over six orders of magnitude, within 6.6e-15 relative of faer's 12×12 projection). This makes the
//! `projected` bench row about twice as fast; it does not give the eigenvalues in closed form (the
//! monodromy argument above is about `H₈`'s eight non-zero ones).

use nalgebra::{SMatrix, SVector, Vector3};

#[cfg(test)]
use super::eigen::jacobi;
use super::eigen::symmetric_eigen;
use crate::hinge::Stencil;

/// The nearest positive semi-definite matrix (in the Frobenius norm: eigenvalues clamped at zero) of a
/// symmetric 12×12 matrix, exactly symmetric, by a 12×12 eigen-decomposition (any symmetric matrix; hinge
/// Hessians take [`project_hinge_psd`], which works on 8×8).
pub(super) fn project_psd(h: SMatrix<f64, 12, 12>) -> SMatrix<f64, 12, 12> {
    let (values, vectors) = symmetric_eigen(&h);
    positive_part(&values, &vectors)
}

/// The nearest positive semi-definite matrix of a hinge Hessian `h = ψ″ ∇θ∇θᵀ + ψ′ Hess θ` of the stencil
/// `st` (any ψ of θ alone), computed on the 8-dimensional complement of its known null space (module
/// documentation, "The null space"): `h = Q H₈ Qᵀ` with the orthonormal 12×8 basis `Q` of
/// [`complement_basis`], so the projection is `Q (H₈)₊ Qᵀ` and the eigensolver works on 8×8 instead of
/// 12×12. Equal to [`project_psd`] up to rounding (test `hinge_projection_equals_faer_projection`); a
/// stencil whose hinge edge has no direction (never the case once θ was evaluated) takes [`project_psd`].
pub(super) fn project_hinge_psd(h: &SMatrix<f64, 12, 12>, st: &Stencil) -> SMatrix<f64, 12, 12> {
    let Some(q) = complement_basis(st) else {
        return project_psd(*h);
    };
    // H₈ = Qᵀ (H Q): y[c] = H q_c (columns of H are contiguous), then the lower triangle, mirrored.
    let mut y = [[0.0_f64; 12]; 8];
    for (c, yc) in y.iter_mut().enumerate() {
        for j in 0..12 {
            let qjc = q[(j, c)];
            if qjc != 0.0 {
                for (yi, hij) in yc.iter_mut().zip(h.column(j).iter()) {
                    *yi += hij * qjc;
                }
            }
        }
    }
    let mut reduced = SMatrix::<f64, 8, 8>::zeros();
    for (c, yc) in y.iter().enumerate() {
        for r in c..8 {
            let v = q.column(r).iter().zip(yc).map(|(a, b)| a * b).sum::<f64>();
            reduced[(r, c)] = v;
            reduced[(c, r)] = v;
        }
    }
    let (values, vectors) = symmetric_eigen(&reduced);
    positive_part(&values, &(q * vectors))
}

/// An orthonormal basis (columns) of the complement of `Hess θ`'s null space at the stencil `st`: with `ê`
/// the unit hinge edge, `a`, `b` completing it to an orthonormal frame and `u₁, u₂, u₃` an orthonormal
/// basis of the zero-sum vectors of ℝ⁴ (one weight per stencil vertex), the columns are `u_k ⊗ a`,
/// `u_k ⊗ b` (moves across the edge without a translation) and `z₁ ⊗ ê`, `z₂ ⊗ ê` with `z₁, z₂` the
/// zero-sum weights orthogonal to the stretch `s_i = (x_i − x1)·ê`. `None` when the edge has no direction.
fn complement_basis(st: &Stencil) -> Option<SMatrix<f64, 12, 8>> {
    let edge = st[2] - st[1];
    let length = edge.norm();
    if !(length > 0.0 && length.is_finite()) {
        return None;
    }
    let e_hat = edge / length;
    let (a, b) = orthonormal_pair(&e_hat);
    // Helmert's zero-sum basis of ℝ⁴.
    let r2 = std::f64::consts::FRAC_1_SQRT_2;
    let r6 = 1.0 / 6f64.sqrt();
    let r12 = 1.0 / 12f64.sqrt();
    let u = [
        [r2, -r2, 0.0, 0.0],
        [r6, r6, -2.0 * r6, 0.0],
        [r12, r12, r12, -3.0 * r12],
    ];
    // The stretch along the edge in those coordinates (non-zero: s1 = 0 and s2 = |e|).
    let s: [f64; 4] = std::array::from_fn(|i| (st[i] - st[1]).dot(&e_hat));
    let c = Vector3::from_fn(|k, _| (0..4).map(|i| u[k][i] * s[i]).sum::<f64>());
    let c_norm = c.norm();
    if !(c_norm > 0.0 && c_norm.is_finite()) {
        return None;
    }
    let (z1, z2) = orthonormal_pair(&(c / c_norm));
    let weights = |z: &Vector3<f64>| -> [f64; 4] {
        std::array::from_fn(|i| (0..3).map(|k| z[k] * u[k][i]).sum::<f64>())
    };
    let mut q = SMatrix::<f64, 12, 8>::zeros();
    let mut put = |col: usize, w: &[f64; 4], dir: &Vector3<f64>| {
        for i in 0..4 {
            for d in 0..3 {
                q[(3 * i + d, col)] = w[i] * dir[d];
            }
        }
    };
    for (k, uk) in u.iter().enumerate() {
        put(2 * k, uk, &a);
        put(2 * k + 1, uk, &b);
    }
    put(6, &weights(&z1), &e_hat);
    put(7, &weights(&z2), &e_hat);
    Some(q)
}

/// Two unit vectors completing the unit vector `n` to an orthonormal frame (the first orthogonal to the
/// coordinate axis `n` is least aligned with).
fn orthonormal_pair(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let abs = n.abs();
    let axis = if abs.x <= abs.y && abs.x <= abs.z {
        Vector3::x()
    } else if abs.y <= abs.z {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let a = n.cross(&axis).normalize();
    let b = n.cross(&a);
    (a, b)
}

/// `Σ_k max(λ_k, 0) w_k w_kᵀ` over the positive eigenvalues `λ_k` (`values`) and the columns `w_k` of
/// `vectors` (eigenvectors, or eigenvectors mapped back by a basis): the lower triangle, mirrored, so the
/// result is exactly symmetric.
fn positive_part<const R: usize, const N: usize>(
    values: &SVector<f64, N>,
    vectors: &SMatrix<f64, R, N>,
) -> SMatrix<f64, R, R> {
    let mut p = SMatrix::<f64, R, R>::zeros();
    for k in 0..N {
        let l = values[k];
        if l > 0.0 {
            let w = vectors.column(k);
            for j in 0..R {
                let lw = l * w[j];
                for i in j..R {
                    p[(i, j)] += lw * w[i];
                }
            }
        }
    }
    for j in 0..R {
        for i in j + 1..R {
            p[(j, i)] = p[(i, j)];
        }
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::autodiff::hinge_angle_autodiff;
    use crate::grid::SplitMix64;

    /// `∇θ` and `Hess θ` of a stencil by num-dual (independent of the closed-form kernels); `None` for a
    /// degenerate stencil.
    fn theta_derivatives(st: &Stencil) -> Option<(SVector<f64, 12>, SMatrix<f64, 12, 12>)> {
        hinge_angle_autodiff(st)
            .ok()
            .map(|d| (d.gradient, (d.hessian + d.hessian.transpose()) * 0.5))
    }

    fn random_stencil(rng: &mut SplitMix64) -> Stencil {
        [0; 4].map(|_| Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()))
    }

    /// The projection by faer's self-adjoint eigendecomposition (an independent eigensolver).
    fn faer_projection(h: &SMatrix<f64, 12, 12>) -> SMatrix<f64, 12, 12> {
        let m = faer::Mat::<f64>::from_fn(12, 12, |i, j| h[(i, j)]);
        let e = m
            .self_adjoint_eigen(faer::Side::Lower)
            .expect("faer eigendecomposition of a finite matrix");
        let (s, u) = (e.S(), e.U());
        SMatrix::<f64, 12, 12>::from_fn(|i, j| {
            (0..12)
                .map(|k| s[k].max(0.0) * u[(i, k)] * u[(j, k)])
                .sum::<f64>()
        })
    }

    #[test]
    fn projections_equal_faer_projection_on_10000_hinge_hessians() {
        let mut rng = SplitMix64(0x9e37_79b9_7f4a_7c15);
        let mut worst = 0.0_f64;
        let mut done = 0;
        while done < 10_000 {
            let st = random_stencil(&mut rng);
            let Some((g, k)) = theta_derivatives(&st) else {
                continue;
            };
            // ψ′ and ψ″ of either sign and of very different sizes.
            let dpsi = rng.symmetric() * 10f64.powf(3.0 * rng.symmetric());
            let d2psi = rng.symmetric() * 10f64.powf(3.0 * rng.symmetric());
            let h = k * dpsi + g * g.transpose() * d2psi;
            let q = faer_projection(&h);
            let (values, vectors) = jacobi(&h);
            let jacobi = positive_part(&values, &vectors);
            let p = project_psd(h);
            worst = worst
                .max((p - q).norm() / h.norm())
                .max((jacobi - q).norm() / h.norm());
            // PSD: the smallest eigenvalue (by faer) is at most rounding below zero.
            let min = faer::Mat::<f64>::from_fn(12, 12, |i, j| p[(i, j)])
                .self_adjoint_eigenvalues(faer::Side::Lower)
                .expect("eigenvalues")
                .into_iter()
                .fold(f64::INFINITY, f64::min);
            assert!(min >= -1e-13 * h.norm(), "projection not PSD: {min:e}");
            done += 1;
        }
        assert!(worst <= 1e-12, "worst relative difference {worst:e}");
    }

    /// Stencils with slivers: a wing whose height over the edge is 1e-6 of the edge's length, or a wing
    /// corner next to a hinge end, in random position, scale and orientation.
    fn sliver_stencil(rng: &mut SplitMix64) -> Stencil {
        let mut st = random_stencil(rng);
        let e = st[2] - st[1];
        let (w, tiny) = if rng.symmetric() > 0.0 {
            (0, 1e-6)
        } else {
            (3, 1e-5)
        };
        let foot = st[1] + e * (0.5 + rng.symmetric());
        let off = st[w] - foot;
        let normal = (off - e * (off.dot(&e) / e.norm_squared())).normalize();
        st[w] = foot + normal * (tiny * e.norm());
        st
    }

    #[test]
    fn hess_theta_null_space_is_the_translations_and_the_stretch_along_the_edge() {
        // num-dual's Hess θ (independent of the basis' construction) annihilates every vector orthogonal
        // to the complement basis, and the basis is orthonormal: Q Qᵀ H Q Qᵀ = H.
        let mut rng = SplitMix64(4242);
        let mut worst = 0.0_f64;
        for n in 0..10_000 {
            let st = if n % 4 == 3 {
                sliver_stencil(&mut rng)
            } else {
                random_stencil(&mut rng)
            };
            let Some((_, k)) = theta_derivatives(&st) else {
                continue;
            };
            let q = complement_basis(&st).expect("a stencil with a hinge edge");
            let gram = q.transpose() * q;
            assert!((gram - SMatrix::<f64, 8, 8>::identity()).norm() <= 1e-14);
            let p = q * q.transpose();
            worst = worst.max((p * k * p - k).norm() / k.norm());
            // The stretch along the edge itself, built independently of the basis.
            let e = (st[2] - st[1]).normalize();
            let stretch =
                SVector::<f64, 12>::from_fn(|r, _| (st[r / 3] - st[1]).dot(&e) * e[r % 3]);
            assert!((k * stretch).norm() <= 1e-11 * k.norm() * stretch.norm());
        }
        eprintln!("largest relative part of Hess θ outside the complement: {worst:e}");
        assert!(worst <= 1e-12, "Hess θ outside the complement: {worst:e}");
    }

    #[test]
    fn hinge_projection_equals_faer_projection() {
        let mut rng = SplitMix64(0x5eed_1234);
        let (mut worst, mut done) = (0.0_f64, 0);
        while done < 10_000 {
            let st = if done % 4 == 3 {
                sliver_stencil(&mut rng)
            } else {
                random_stencil(&mut rng)
            };
            let Some((g, k)) = theta_derivatives(&st) else {
                continue;
            };
            let dpsi = rng.symmetric() * 10f64.powf(3.0 * rng.symmetric());
            let d2psi = rng.symmetric() * 10f64.powf(3.0 * rng.symmetric());
            let h = k * dpsi + g * g.transpose() * d2psi;
            let p = project_hinge_psd(&h, &st);
            worst = worst.max((p - faer_projection(&h)).norm() / h.norm());
            // The projection keeps the null space: no translation enters it.
            let t = SVector::<f64, 12>::from_fn(|r, _| if r % 3 == 1 { 1.0 } else { 0.0 });
            assert!((p * t).norm() <= 1e-14 * h.norm());
            done += 1;
        }
        eprintln!("reduced projection against faer's: worst relative difference {worst:e}");
        assert!(worst <= 1e-12, "worst relative difference {worst:e}");
    }

    #[test]
    fn jacobi_survives_the_drape_matrix() {
        // A hinge Hessian from the drape (ψ′ = 0, ψ″ > 0, z components only) on which nalgebra 0.35's
        // `symmetric_eigen` returned NaN eigenvectors.
        let entries = [
            (2, 2, 0.006181318681318683),
            (5, 2, 1.3003201734412284e-33),
            (8, 2, -0.012362637362637378),
            (11, 2, 0.006181318681318693),
            (5, 5, 2.7353913309279744e-64),
            (8, 5, -2.6006403468824592e-33),
            (11, 5, 1.3003201734412306e-33),
            (8, 8, 0.024725274725274776),
            (11, 8, -0.012362637362637399),
            (11, 11, 0.0061813186813187045),
        ];
        let mut h = SMatrix::<f64, 12, 12>::zeros();
        for (i, j, v) in entries {
            h[(i, j)] = v;
            h[(j, i)] = v;
        }
        let (values, vectors) = jacobi(&h);
        let jacobi = positive_part(&values, &vectors);
        assert!((jacobi - faer_projection(&h)).norm() <= 1e-14 * h.norm());
        let p = project_psd(h);
        assert!(p.iter().all(|v| v.is_finite()));
        // PSD already (rank one up to rounding): the projection is the matrix itself.
        assert!((p - h).norm() <= 1e-14 * h.norm(), "{:e}", (p - h).norm());
        assert!((p - faer_projection(&h)).norm() <= 1e-14 * h.norm());
    }

    #[test]
    fn hess_theta_inertia_is_four_four_four() {
        let mut rng = SplitMix64(12345);
        let (mut done, mut mins) = (0, Vec::new());
        while done < 10_000 {
            let st = random_stencil(&mut rng);
            let Some((g, k)) = theta_derivatives(&st) else {
                continue;
            };
            let (values, vectors) = symmetric_eigen(&k);
            let tol = 1e-9 * values.amax();
            let pos = values.iter().filter(|&&l| l > tol).count();
            let neg = values.iter().filter(|&&l| l < -tol).count();
            assert_eq!((pos, neg), (4, 4), "inertia of Hess θ: {values:?}");
            // ∇θ lies in the range (no component on the null space) and has a component on every one
            // of the eight range eigenvectors.
            let mut range_components = Vec::new();
            for c in 0..12 {
                let gamma = vectors.column(c).dot(&g) / g.norm();
                if values[c].abs() <= tol {
                    assert!(
                        gamma.abs() <= 1e-8,
                        "∇θ has a null-space component {gamma:e}"
                    );
                } else {
                    range_components.push(gamma.abs());
                }
            }
            let min = range_components
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min);
            mins.push(min);
            done += 1;
        }
        // Per stencil, the smallest of the eight |γ_k|/|∇θ|: far from rounding level on typical stencils
        // (γ_k = 0 would let the exact eigenvectors of that mode be Hess θ's, and the spectrum factor).
        mins.sort_by(f64::total_cmp);
        let (p1, p50) = (mins[mins.len() / 100], mins[mins.len() / 2]);
        eprintln!("smallest |γ_k|/|∇θ| per stencil: 1st percentile {p1:e}, median {p50:e}");
        assert!(
            p50 > 1e-3 && p1 > 1e-6,
            "components vanish: {p1:e}, {p50:e}"
        );
    }

    #[test]
    fn termwise_projection_is_not_the_projection() {
        let mut rng = SplitMix64(777);
        let mut differing = 0;
        let mut done = 0;
        while done < 1000 {
            let st = random_stencil(&mut rng);
            let Some((g, k)) = theta_derivatives(&st) else {
                continue;
            };
            let (dpsi, d2psi) = (rng.symmetric(), rng.symmetric().abs());
            let h = k * dpsi + g * g.transpose() * d2psi;
            let exact = project_psd(h);
            let termwise = project_psd(k * dpsi) + g * g.transpose() * d2psi;
            if (exact - termwise).norm() > 1e-6 * h.norm() {
                differing += 1;
            }
            done += 1;
        }
        assert!(differing > 900, "only {differing} of 1000 differ");
    }
}
