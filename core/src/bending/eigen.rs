//! Small dense symmetric eigensolvers for the per-hinge projection ([`super::projection`]).
//!
//! - [`tridiagonal_qr`]: Householder reduction to tridiagonal form, then the implicit symmetric QR
//!   iteration with Wilkinson shifts (Golub & Van Loan, *Matrix Computations*, Algorithms 8.3.1–8.3.3),
//!   on fixed-size arrays (no allocation). The fast path; a throwaway timing loop on 20 000 reduced hinge
//!   Hessians measured 2.4 µs per 8×8 decomposition against 3.0–3.5 µs for nalgebra 0.35's
//!   `symmetric_eigen` (the bench row `projected`, `hinge bench --only refactored,projected`, is what
//!   counts). Its cost is the rotations' dependency chain (a square root and a division each), about
//!   two QR iterations per eigenvalue.
//! - [`jacobi`]: cyclic Jacobi rotations, slower but converging for every symmetric input; the fallback
//!   when the QR iteration does not converge within its iteration budget.
//!
//! Both scale the matrix to unit largest entry first (no overflow or underflow from badly scaled
//! stencils) and return eigenvalues accurate to a few `ε ‖A‖` with orthonormal eigenvectors (columns).

use nalgebra::{SMatrix, SVector};

/// Sweeps after which cyclic Jacobi stops even if some off-diagonal entry is still above the threshold (a
/// safeguard: cyclic Jacobi converges quadratically, and the 10 000-stencil tests check the result).
const MAX_SWEEPS: usize = 60;

/// QR iterations per eigenvalue before [`tridiagonal_qr`] gives up (it needs about two; Wilkinson's
/// shift converges globally in exact arithmetic, so this only guards against rounding pathologies).
const QR_ITERATIONS_PER_VALUE: usize = 30;

/// The largest |entry| of the lower triangle (the matrix is symmetric).
fn largest_entry<const N: usize>(a: &SMatrix<f64, N, N>) -> f64 {
    let mut scale = 0.0_f64;
    for j in 0..N {
        for i in j..N {
            scale = scale.max(a[(i, j)].abs());
        }
    }
    scale
}

/// Eigenvalues and eigenvectors (columns) of the symmetric matrix `a` (its lower triangle is read) by
/// Householder tridiagonalization and implicit QR with Wilkinson shifts, or `None` if the iteration did
/// not converge (then use [`jacobi`]). A zero or non-finite matrix is returned as its diagonal with the
/// identity (the callers' finiteness checks report non-finite input).
pub(crate) fn tridiagonal_qr<const N: usize>(
    a: &SMatrix<f64, N, N>,
) -> Option<(SVector<f64, N>, SMatrix<f64, N, N>)> {
    let scale = largest_entry(a);
    if !(scale > 0.0 && scale.is_finite()) {
        return Some((
            SVector::from_fn(|i, _| a[(i, i)]),
            SMatrix::<f64, N, N>::identity(),
        ));
    }
    // Working copies: `m` the (scaled, symmetric) matrix, `z` the accumulated transformations stored by
    // columns (z[c]: column c of the eigenvector matrix, contiguous for the rotations).
    let mut m = [[0.0_f64; N]; N];
    for j in 0..N {
        for i in j..N {
            let v = a[(i, j)] / scale;
            m[i][j] = v;
            m[j][i] = v;
        }
    }
    let mut z = [[0.0_f64; N]; N];
    for (i, row) in z.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    // 1. Householder: for column k, the reflection I − 2vvᵀ (v supported on k+1..N) that maps
    //    m[k+1.., k] onto a multiple of the first unit vector, applied from both sides.
    for k in 0..N.saturating_sub(2) {
        // The entries below the subdiagonal (summed directly: as |x|² − x₀² a small tail would vanish
        // in rounding and be dropped).
        let mut tail2 = 0.0;
        for row in m.iter().skip(k + 2) {
            tail2 += row[k] * row[k];
        }
        if tail2 == 0.0 {
            // Already tridiagonal in this column.
            continue;
        }
        let norm2 = tail2 + m[k + 1][k] * m[k + 1][k];
        let norm = norm2.sqrt();
        let alpha = if m[k + 1][k] >= 0.0 { -norm } else { norm };
        let mut v = [0.0_f64; N];
        v[k + 1] = m[k + 1][k] - alpha;
        for i in k + 2..N {
            v[i] = m[i][k];
        }
        // |v|² = |x|² − 2 α x₀ + α² = 2 (|x|² − α x₀).
        let vnorm2 = 2.0 * (norm2 - alpha * m[k + 1][k]);
        let inv = 1.0 / vnorm2.sqrt();
        for vi in v.iter_mut().skip(k + 1) {
            *vi *= inv;
        }
        // p = M v on the trailing block, w = p − (vᵀp) v; M ← M − 2 (v wᵀ + w vᵀ).
        let mut p = [0.0_f64; N];
        for i in k + 1..N {
            let mut s = 0.0;
            for j in k + 1..N {
                s += m[i][j] * v[j];
            }
            p[i] = s;
        }
        let mut kappa = 0.0;
        for i in k + 1..N {
            kappa += v[i] * p[i];
        }
        for i in k + 1..N {
            p[i] -= kappa * v[i];
        }
        for i in k + 1..N {
            for j in k + 1..N {
                m[i][j] -= 2.0 * (v[i] * p[j] + p[i] * v[j]);
            }
        }
        m[k + 1][k] = alpha;
        m[k][k + 1] = alpha;
        for i in k + 2..N {
            m[i][k] = 0.0;
            m[k][i] = 0.0;
        }
        // Z ← Z (I − 2 v vᵀ), on Z's columns: u = 2 Z v, then column j −= v_j u.
        let mut u = [0.0_f64; N];
        for j in k + 1..N {
            for (ur, zr) in u.iter_mut().zip(&z[j]) {
                *ur += 2.0 * v[j] * zr;
            }
        }
        for j in k + 1..N {
            for (zr, ur) in z[j].iter_mut().zip(&u) {
                *zr -= v[j] * ur;
            }
        }
    }
    let mut d = [0.0_f64; N];
    let mut e = [0.0_f64; N];
    for i in 0..N {
        d[i] = m[i][i];
        if i + 1 < N {
            e[i] = m[i + 1][i];
        }
    }
    // 2. Implicit symmetric QR on the unreduced blocks, deflating from the bottom.
    let anorm = d.iter().chain(&e).fold(0.0_f64, |s, v| s.max(v.abs()));
    let negligible = |e: f64, d0: f64, d1: f64| {
        e.abs() <= f64::EPSILON * (d0.abs() + d1.abs())
            || e.abs() <= f64::EPSILON * f64::EPSILON * anorm
    };
    let mut hi = N.saturating_sub(1);
    let mut iterations = 0;
    while hi > 0 {
        if negligible(e[hi - 1], d[hi - 1], d[hi]) {
            e[hi - 1] = 0.0;
            hi -= 1;
            continue;
        }
        let mut lo = hi - 1;
        while lo > 0 && !negligible(e[lo - 1], d[lo - 1], d[lo]) {
            lo -= 1;
        }
        if lo > 0 {
            e[lo - 1] = 0.0;
        }
        iterations += 1;
        if iterations > QR_ITERATIONS_PER_VALUE * N {
            return None;
        }
        // Wilkinson's shift: the eigenvalue of the trailing 2×2 block nearer to its last diagonal entry.
        let delta = 0.5 * (d[hi - 1] - d[hi]);
        let eb = e[hi - 1];
        let sign = if delta >= 0.0 { 1.0 } else { -1.0 };
        let mu = d[hi] - eb * eb / (delta + sign * hypot(delta, eb));
        let mut x = d[lo] - mu;
        let mut y = e[lo];
        for k in lo..hi {
            let r = hypot(x, y);
            let (c, s) = if r == 0.0 { (1.0, 0.0) } else { (x / r, y / r) };
            if k > lo {
                e[k - 1] = r;
            }
            // The rotation [c s; −s c] on rows and columns k, k+1.
            let (dk, dk1, ek) = (d[k], d[k + 1], e[k]);
            d[k] = c * c * dk + 2.0 * c * s * ek + s * s * dk1;
            d[k + 1] = s * s * dk - 2.0 * c * s * ek + c * c * dk1;
            e[k] = c * s * (dk1 - dk) + (c * c - s * s) * ek;
            if k + 1 < hi {
                // The bulge at (k, k+2), chased down by the next rotation.
                y = s * e[k + 1];
                e[k + 1] *= c;
                x = e[k];
            }
            let (head, tail) = z.split_at_mut(k + 1);
            for (zk, zk1) in head[k].iter_mut().zip(tail[0].iter_mut()) {
                let (a, b) = (*zk, *zk1);
                *zk = c * a + s * b;
                *zk1 = c * b - s * a;
            }
        }
    }
    Some((
        SVector::from_fn(|i, _| d[i] * scale),
        SMatrix::from_fn(|r, c| z[c][r]),
    ))
}

/// `√(x² + y²)`: the plain formula where its squares neither overflow nor underflow (the matrix is scaled
/// to unit largest entry, so nearly always), `f64::hypot` (several times slower) otherwise.
#[inline]
fn hypot(x: f64, y: f64) -> f64 {
    let s = x * x + y * y;
    if s > 1e-250 && s < 1e250 {
        s.sqrt()
    } else {
        x.hypot(y)
    }
}

/// Eigenvalues and eigenvectors (columns) of the symmetric matrix `a` (its lower triangle is read) by cyclic
/// Jacobi rotations, on a copy scaled to unit largest entry. Off-diagonal entries below `ε² ‖A‖_F` are
/// treated as zero; the eigenvalues are accurate to a few `ε ‖A‖`.
pub(crate) fn jacobi<const N: usize>(
    a: &SMatrix<f64, N, N>,
) -> (SVector<f64, N>, SMatrix<f64, N, N>) {
    let mut m = SMatrix::<f64, N, N>::zeros();
    let scale = largest_entry(a);
    let mut v = SMatrix::<f64, N, N>::identity();
    if !(scale > 0.0 && scale.is_finite()) {
        // Zero (or non-finite: reported by the caller's finiteness checks) — nothing to rotate.
        return (SVector::from_fn(|i, _| a[(i, i)]), v);
    }
    for j in 0..N {
        for i in j..N {
            m[(i, j)] = a[(i, j)] / scale;
            m[(j, i)] = m[(i, j)];
        }
    }
    let frob = m.norm();
    let negligible = f64::EPSILON * f64::EPSILON * frob;
    for _ in 0..MAX_SWEEPS {
        let mut rotated = false;
        for p in 0..N {
            for q in p + 1..N {
                let apq = m[(p, q)];
                if apq.abs() <= negligible {
                    m[(p, q)] = 0.0;
                    m[(q, p)] = 0.0;
                    continue;
                }
                rotated = true;
                // The rotation that zeroes m[p][q] (Rutishauser's formulation).
                let theta = (m[(q, q)] - m[(p, p)]) / (2.0 * apq);
                let t = if theta.abs() > 1e150 {
                    0.5 / theta
                } else {
                    theta.signum() / (theta.abs() + theta.mul_add(theta, 1.0).sqrt())
                };
                let c = 1.0 / t.mul_add(t, 1.0).sqrt();
                let s = t * c;
                m[(p, p)] -= t * apq;
                m[(q, q)] += t * apq;
                m[(p, q)] = 0.0;
                m[(q, p)] = 0.0;
                for r in 0..N {
                    if r != p && r != q {
                        let (arp, arq) = (m[(r, p)], m[(r, q)]);
                        let np = c * arp - s * arq;
                        let nq = s * arp + c * arq;
                        m[(r, p)] = np;
                        m[(p, r)] = np;
                        m[(r, q)] = nq;
                        m[(q, r)] = nq;
                    }
                    let (vrp, vrq) = (v[(r, p)], v[(r, q)]);
                    v[(r, p)] = c * vrp - s * vrq;
                    v[(r, q)] = s * vrp + c * vrq;
                }
            }
        }
        if !rotated {
            break;
        }
    }
    (SVector::from_fn(|i, _| m[(i, i)] * scale), v)
}

/// Eigenvalues and eigenvectors of the symmetric matrix `a`: [`tridiagonal_qr`], or [`jacobi`] when that
/// does not converge or returns a non-finite value.
pub(crate) fn symmetric_eigen<const N: usize>(
    a: &SMatrix<f64, N, N>,
) -> (SVector<f64, N>, SMatrix<f64, N, N>) {
    match tridiagonal_qr(a) {
        Some((values, vectors)) if values.iter().chain(vectors.iter()).all(|v| v.is_finite()) => {
            (values, vectors)
        }
        _ => jacobi(a),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::SplitMix64;

    /// faer's eigenvalues, ascending (an independent eigensolver).
    fn faer_values<const N: usize>(a: &SMatrix<f64, N, N>) -> Vec<f64> {
        let m = faer::Mat::<f64>::from_fn(N, N, |i, j| a[(i, j)]);
        let mut v = m
            .self_adjoint_eigenvalues(faer::Side::Lower)
            .expect("faer eigenvalues of a finite matrix");
        v.sort_by(f64::total_cmp);
        v
    }

    /// Checks an eigen-decomposition of `a`: residual `‖A V − V Λ‖`, orthonormality and the eigenvalues
    /// against faer's, all relative to `‖A‖`.
    fn check<const N: usize>(
        a: &SMatrix<f64, N, N>,
        values: &SVector<f64, N>,
        vectors: &SMatrix<f64, N, N>,
    ) {
        let scale = a.norm().max(f64::MIN_POSITIVE);
        let residual = a * vectors - vectors * SMatrix::<f64, N, N>::from_diagonal(values);
        assert!(
            residual.norm() <= 1e-13 * scale,
            "residual {:e}",
            residual.norm() / scale
        );
        let gram = vectors.transpose() * vectors - SMatrix::<f64, N, N>::identity();
        assert!(gram.norm() <= 1e-13, "orthonormality {:e}", gram.norm());
        let mut ours: Vec<f64> = values.iter().copied().collect();
        ours.sort_by(f64::total_cmp);
        for (x, y) in ours.iter().zip(faer_values(a)) {
            assert!(
                (x - y).abs() <= 1e-13 * scale,
                "eigenvalue {x:e} against faer's {y:e}"
            );
        }
    }

    /// Symmetric test matrices: random, graded over 12 orders of magnitude, with repeated and zero
    /// eigenvalues (rebuilt from faer's eigenvectors of a random matrix), diagonal, tridiagonal, rank one,
    /// zero, and one with entries of 1e-64 (the drape matrix' scale).
    fn matrices<const N: usize>(rng: &mut SplitMix64) -> Vec<SMatrix<f64, N, N>> {
        let mut out = Vec::new();
        for n in 0..400 {
            let mut a = SMatrix::<f64, N, N>::from_fn(|_, _| rng.symmetric());
            a = (a + a.transpose()) * 0.5;
            match n % 6 {
                0 => {}
                1 => {
                    let g = SVector::<f64, N>::from_fn(|_, _| 10f64.powf(6.0 * rng.symmetric()));
                    a = SMatrix::from_diagonal(&g) * a * SMatrix::from_diagonal(&g);
                }
                2 => {
                    let m = faer::Mat::<f64>::from_fn(N, N, |i, j| a[(i, j)]);
                    let e = m.self_adjoint_eigen(faer::Side::Lower).expect("eigen");
                    let u = SMatrix::<f64, N, N>::from_fn(|i, j| e.U()[(i, j)]);
                    // Eigenvalues in three clusters: −1 (twice), 0 (three times), 2 (the rest).
                    let d = SVector::<f64, N>::from_fn(|i, _| match i {
                        0 | 1 => -1.0,
                        2..=4 => 0.0,
                        _ => 2.0,
                    });
                    a = u * SMatrix::from_diagonal(&d) * u.transpose();
                }
                3 => {
                    a = SMatrix::from_diagonal(&a.diagonal());
                }
                4 => {
                    a = SMatrix::from_fn(|i, j| if i.abs_diff(j) <= 1 { a[(i, j)] } else { 0.0 });
                }
                _ => {
                    let v = SVector::<f64, N>::from_fn(|_, _| rng.symmetric());
                    a = v * v.transpose() * 1e-64;
                }
            }
            out.push(a);
        }
        out.push(SMatrix::zeros());
        out
    }

    fn qr_and_jacobi_agree_with_faer<const N: usize>(seed: u64) {
        let mut rng = SplitMix64(seed);
        for a in matrices::<N>(&mut rng) {
            let (values, vectors) = tridiagonal_qr(&a).expect("the QR iteration converges");
            check(&a, &values, &vectors);
            let (values, vectors) = jacobi(&a);
            check(&a, &values, &vectors);
        }
    }

    #[test]
    fn eigensolvers_agree_with_faer_on_8_by_8() {
        qr_and_jacobi_agree_with_faer::<8>(81);
    }

    #[test]
    fn eigensolvers_agree_with_faer_on_12_by_12() {
        qr_and_jacobi_agree_with_faer::<12>(121);
    }

    #[test]
    fn eigensolvers_agree_with_faer_on_tiny_sizes() {
        qr_and_jacobi_agree_with_faer::<1>(11);
        qr_and_jacobi_agree_with_faer::<2>(21);
        qr_and_jacobi_agree_with_faer::<3>(31);
    }
}
