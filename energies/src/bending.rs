//! The hinge bending family, declared with the derive macro (ψ′ and ψ″ derived at compile time).

use hinge_core::HingeEnergy;
pub use hinge_core::psi::{DiscreteShells, TanBending};

/// Bending stiffness from material (paper Eq. 11): `k = Y h³ / (24 (1 − ν²))` for Young's modulus `Y`,
/// thickness `h` and Poisson ratio `ν`.
pub fn stiffness_from_material(young: f64, thickness: f64, poisson: f64) -> f64 {
    young * thickness.powi(3) / (24.0 * (1.0 - poisson * poisson))
}

/// Bending stiffness that makes the hinge energies reproduce the plate's energy of cylindrical bending:
/// Eq. 11 divided by three, `k = Y h³ / (72 (1 − ν²))`.
///
/// Why: with the weight `a = 3‖ē‖²/Ā`, a mesh bent into a cylinder of curvature κ stores
/// `Σ a θ² → 3 κ² A` (`A` the mesh area), while the plate stores `(D/2) κ² A = k_Eq.11 κ² A`. On a grid
/// bent across its columns this is exact in the limit (the column edges carry θ = κ·h_x and every other
/// edge θ = 0, so each cell contributes `3 h_y²/(h_x h_y) · κ² h_x² = 3 κ² h_x h_y`, for any cell aspect);
/// on equilateral meshes it holds for every bending direction. The test
/// `cylinder_patch_test_gives_three_times_the_plate_energy` (tests/tests/energies.rs) measures it, and the
/// `beam` scenes use this stiffness to match the cantilever formula `w = q L⁴ / (8D)` within 10%. On a
/// grid bent along its diagonals the factor is larger (up to ≈ 9 for forward diagonals), the known mesh
/// dependence of hinge energies: use meshes aligned with the expected bending, or isotropic ones.
pub fn plate_consistent_stiffness(young: f64, thickness: f64, poisson: f64) -> f64 {
    stiffness_from_material(young, thickness, poisson) / 3.0
}

/// `ψ = k·a·(2 sin(θ/2) − 2 sin(θ̄/2))²`: for a flat rest state `4k·a·sin²(θ/2)`, the paper's `a·sin²(θ/2)`
/// (Willmore-type) row up to the factor. Bounded as θ → ±π.
#[derive(Debug, Clone, PartialEq, HingeEnergy)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[psi(k * a * (2.0 * (theta / 2.0).sin() - 2.0 * (theta_bar / 2.0).sin()).powi(2))]
pub struct Willmore {
    /// Bending stiffness.
    pub k: f64,
}

/// Bridson et al. (2003), integrated as the paper does: the energy whose `ψ′ = k·a·(sin(θ/2) − sin(θ̄/2))`,
/// with `ψ(θ̄) = 0`: `ψ = k·a·(2cos(θ̄/2) − 2cos(θ/2) − (θ − θ̄) sin(θ̄/2))`.
#[derive(Debug, Clone, PartialEq, HingeEnergy)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[psi(k * a * (2.0 * (theta_bar / 2.0).cos() - 2.0 * (theta / 2.0).cos() - (theta - theta_bar) * (theta_bar / 2.0).sin()))]
pub struct Bridson {
    /// Bending stiffness.
    pub k: f64,
}

/// Viscous (Rayleigh) damping of the tan-based energy (paper §5): `ψ = (k_d/Δt)·a·(φ(θ) − φ(θ̂))²` with
/// `φ = 2 tan(θ/2)` and θ̂ the angle at the end of the previous step (`theta_prev`, set by
/// [`hinge_core::bending::BendingModel::set_step`]). Compose it with the elastic term as a tuple
/// `(TanBending { .. }, ViscousDamping { .. })` so both share one geometric pass.
#[derive(Debug, Clone, PartialEq, HingeEnergy)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[psi(kd / dt * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_prev / 2.0).tan()).powi(2))]
pub struct ViscousDamping {
    /// Damping coefficient k_d.
    pub kd: f64,
}
