//! The hinge bending family, declared with the derive macro (ψ′ and ψ″ derived at compile time).

use hinge_core::HingeEnergy;
use hinge_core::psi::HingePsi;
pub use hinge_core::psi::{DiscreteShells, TanBending};

/// The built-in elastic bending energies by name: the one place their names (as scene files, `hinge eval`
/// and the Python package spell them) and the text of their ψ are kept. Each ψ is its own type, so code
/// that builds one from a name hands a [`PsiConsumer`] to [`BuiltinBending::with_psi`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BuiltinBending {
    /// [`DiscreteShells`], `"discrete-shells"`.
    DiscreteShells,
    /// [`TanBending`], `"tan-bending"`.
    TanBending,
    /// [`Willmore`], `"willmore"`.
    Willmore,
    /// [`Bridson`], `"bridson"`.
    Bridson,
}

/// A bending energy's name that is not one of [`BuiltinBending::NAMES`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown `{0}` ({known})", known = BuiltinBending::NAMES.join(", "))]
pub struct UnknownBending(pub String);

/// What [`BuiltinBending::with_psi`] hands the energy's ψ to: code generic over the ψ type (build a
/// bending model, a hinge term, a bench row) for an energy chosen by name at run time.
pub trait PsiConsumer {
    /// What consuming the ψ gives.
    type Output;
    /// Consumes the ψ of the energy [`BuiltinBending::with_psi`] was called on.
    fn consume<P>(self, psi: P) -> Self::Output
    where
        P: HingePsi + Clone + Send + Sync + std::fmt::Debug + 'static;
}

impl BuiltinBending {
    /// Every built-in bending energy, in the order of [`BuiltinBending::NAMES`].
    pub const ALL: [Self; 4] = [
        Self::DiscreteShells,
        Self::TanBending,
        Self::Willmore,
        Self::Bridson,
    ];
    /// Their names, as scene files (`bending.energy`), `hinge eval` and the Python package spell them.
    pub const NAMES: [&'static str; 4] = ["discrete-shells", "tan-bending", "willmore", "bridson"];

    /// The energy's name (`"discrete-shells"`, `"tan-bending"`, `"willmore"`, `"bridson"`).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::DiscreteShells => Self::NAMES[0],
            Self::TanBending => Self::NAMES[1],
            Self::Willmore => Self::NAMES[2],
            Self::Bridson => Self::NAMES[3],
        }
    }

    /// The text of the energy's `#[psi(…)]` in the derive's language, which the run-time ψ language
    /// (`hinge_symbolic`) parses too: the Python package builds the built-in energies from it. The
    /// integration test `runtime_psi::builtin_bending_sources_match_the_derive` checks that it gives the
    /// derived energy's ψ, ψ′ and ψ″.
    #[must_use]
    pub fn psi_source(self) -> &'static str {
        match self {
            Self::DiscreteShells => "k * a * (theta - theta_bar).powi(2)",
            Self::TanBending => {
                "k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2)"
            }
            Self::Willmore => {
                "k * a * (2.0 * (theta / 2.0).sin() - 2.0 * (theta_bar / 2.0).sin()).powi(2)"
            }
            Self::Bridson => {
                "k * a * (2.0 * (theta_bar / 2.0).cos() - 2.0 * (theta / 2.0).cos() - (theta - theta_bar) * (theta_bar / 2.0).sin())"
            }
        }
    }

    /// Hands the energy's ψ with stiffness `k` to `consumer`.
    pub fn with_psi<C: PsiConsumer>(self, k: f64, consumer: C) -> C::Output {
        match self {
            Self::DiscreteShells => consumer.consume(DiscreteShells { k }),
            Self::TanBending => consumer.consume(TanBending { k }),
            Self::Willmore => consumer.consume(Willmore { k }),
            Self::Bridson => consumer.consume(Bridson { k }),
        }
    }
}

impl std::str::FromStr for BuiltinBending {
    type Err = UnknownBending;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| UnknownBending(s.to_string()))
    }
}

impl std::fmt::Display for BuiltinBending {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

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

impl ViscousDamping {
    /// Its name, as `hinge eval` and the Python package spell it.
    pub const NAME: &'static str = "viscous-damping";
    /// The text of its `#[psi(…)]` in the derive's language, which the run-time ψ language
    /// (`hinge_symbolic`) parses too: the Python package builds viscous damping from it. The integration
    /// test `runtime_psi::viscous_damping_source_matches_the_derive` checks that it gives the derived
    /// energy's ψ, ψ′ and ψ″.
    pub const PSI_SOURCE: &'static str =
        "kd / dt * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_prev / 2.0).tan()).powi(2)";
}
