//! Positive semi-definite projection of a local Hessian ([`super::HessianMode::ProjectPerHinge`]).

use nalgebra::SMatrix;

/// The nearest positive semi-definite matrix (eigenvalues clamped at zero) of a symmetric 12×12 matrix.
pub(super) fn project_psd(h: SMatrix<f64, 12, 12>) -> SMatrix<f64, 12, 12> {
    let eig = h.symmetric_eigen();
    let clamped = eig.eigenvalues.map(|l| l.max(0.0));
    let q = eig.eigenvectors;
    let p = q * SMatrix::<f64, 12, 12>::from_diagonal(&clamped) * q.transpose();
    // Exactly symmetric.
    (p + p.transpose()) * 0.5
}
