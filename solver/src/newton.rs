//! Newton's method for statics (`E(x)`) and for the implicit-Euler incremental potential
//! `F(x) = Σ_i m_i |x_i − x̂_i|² / (2Δt²) + E(x)` with `x̂ = x⁰ + Δt v⁰` (lecture P14–P18), with pinned
//! vertices eliminated from the system and a backtracking Armijo line search on F.
//!
//! # Globalization
//! The hinge, membrane, spring and contact Hessians are indefinite in general (compressed membranes and
//! springs, bent hinges, penalty contact on curved obstacles). Two policies, both measured:
//! - [`Globalization::ShiftedExact`] (the default): the exact Hessian; when its Cholesky factorization fails,
//!   a diagonal shift starting near the last one that worked, raised 4-fold until it factors. Every
//!   iteration tries the unshifted matrix first, so the last iterations are exact Newton steps. The ladder
//!   starts at a quarter of the previous iteration's shift or, with [`NewtonParams::remember_shift`] (the
//!   default), a quarter of the last positive shift of this solve or of an earlier one of the same
//!   `Newton`: without that memory every time step climbed the ladder from
//!   [`NewtonParams::initial_shift`] again (about 10 failed factorizations in each drape frame whose first
//!   Hessian is indefinite). Measured (`hinge run drape --no-frames`, `hinge run shell-drop --no-frames`,
//!   without → with the memory): drape 737 → 771 iterations, 1 550 → 1 213 factorizations; shell-drop
//!   1 230 → 1 169 iterations, 3 259 → 2 714 factorizations, per frame median 11 → 11, max 71 → 61.
//!   Starting at 1/16 of the remembered shift instead: drape 729 / 1 181, shell-drop 1 339 / 3 301
//!   (max 77); at 1/64: 733 / 1 235 and 1 387 / 3 523.
//!
//!   In a time step, a shift far above the inertia switches the iteration to the definite Hessian: when the
//!   shift the ladder accepts exceeds [`NewtonParams::definite_shift_ratio`] (default
//!   [`DEFINITE_SHIFT_RATIO`], 1 000) times the largest `m/Δt²` of a free vertex, the iteration solves with
//!   each energy's definite Hessian instead (the ladder on it if that fails too), and so do the following
//!   ones until a full step, as [`Globalization::ProjectOnDemand`] does. A shift `σ` scales every soft
//!   mode's step by about `m/(Δt² σ)`: a few stiff elements whose negative curvature needs 10³–10⁸ times the
//!   inertia (the public `cow` mesh as a soft shell: a hinge next to a sliver, folded to −3.09 rad at rest,
//!   where tan bending is 2.7·10⁶ times stiffer than flat) make the whole shell crawl, hundreds of
//!   iterations per frame; the definite Hessian keeps each element's own curvature. Measured (`hinge run`
//!   of the scenes, `docs/newton/ensemble.sh` or five OBJ starts 0–3e-5 m apart; iterations /
//!   factorizations, per-frame median / max, each the median over the five starts; ratio ∞ is the shift
//!   alone): `cow` (one run) ∞: 6 432 / 18 304, 9.5 / 1 120, 72 substeps; 10⁵: 2 222 / 5 716, 10 / 590;
//!   10⁴: 1 585 / 3 782, 8 / 635; 10³: 1 193 / 2 397, 8 / 245, no substeps; 10²: 1 252 / 2 342, 7 / 384; 10: 948 / 1 933,
//!   10 / 74 (`project-on-demand`: 1 100 / 1 454, 9 / 86). `shell-drop` ∞: 1 217 / 3 021, 11.5 / 70;
//!   10³: 961 / 2 176, 12 / 57; 10: 917 / 2 147, 13 / 48; 1: 905 / 1 998, 11.5 / 52. The drape: 612–617
//!   iterations at 10³ and ∞ (no shift that large), 542–546 at 10, 546–552 at 1, 688–1 080 at 10². A
//!   generated torus: ∞ 1 138 / 2 878, 5.5 / 89; 10³ 1 107 / 2 751, 5.5 / 76; 1: 979 / 2 225, 9.5 / 94. A
//!   box with 90° creases: ∞ 1 130 / 2 727, 11 / 65; 10³ 1 033 / 2 324, 10 / 56; 1: 1 133 / 2 363,
//!   15 / 56. Small ratios cost the torus and the box their per-frame medians (the definite Hessian drops
//!   the curvature a folding shell needs, as project on demand does); 10³ lowers every scene's total and
//!   maximum and leaves its median within its spread.
//!
//!   "Until a full step" is [`NewtonParams::definite_hold`] full steps (default [`DEFINITE_HOLD`], 1): the
//!   exact Hessian is tried again only after that many. Measured (2026-12-07, nineteenth session;
//!   `docs/newton/ensemble.sh` and `docs/newton/obj_ensemble.sh` with `[solver] definite_hold` set, five
//!   starts, medians; hold 2 against 1): `project-on-demand` on the drape 585 / 661 (1.13 factorizations per
//!   iteration) against 574 / 698 (hold 4: 656–673 iterations, hold 8: 777–800); `shell-drop` with
//!   `project-on-demand` 1 093 / 1 289, 15 / 78 against 1 077 / 1 452, 14 / 63. With `shifted-exact` (the
//!   hold acts where `definite_shift_ratio` switched): the drape unchanged, `shell-drop` 1 009 / 2 167, per
//!   frame 9 / 58 against 961 / 2 176, 12 / 57 (its default start 1 084 / 2 167, 10.5 / 59 against
//!   904 / 2 122, 9 / 50), the torus 1 107 / 2 753, 6 / 80 against 1 107 / 2 751, 5.5 / 76, the box
//!   1 063 / 2 283, 11 / 58 against 1 033 / 2 324, 10 / 56, the UV sphere 1 086 / 1 943, 8.5 / 100 against
//!   1 144 / 2 447, 8.5 / 103, the lumpy shell 1 129 / 2 492, 13.5 / 65 against 1 148 / 2 832, 14 / 67:
//!   within the spreads, so the default stays 1; 2 is the setting that brings `project-on-demand` to 1.13
//!   factorizations per iteration on the drape (the issue's ≤ 1.15, not its ≤ 450 iterations).
//! - [`Globalization::ProjectOnDemand`]: the exact Hessian when it factors; after a failure, each energy's
//!   positive semi-definite Hessian ([`Request::definite`]: Gauss–Newton for hinge terms, the membrane's
//!   stress clamped to its positive part in the geometric stiffness, the compressive spring term and the
//!   obstacle-curvature contact term dropped) for this and the following iterations until
//!   [`NewtonParams::definite_hold`] of them took a full step (`α = 1`), then the exact one again. A
//!   diagonal shift only if the definite Hessian fails too (statics, singular).
//!
//! Measured with `hinge run drape --no-frames`, `hinge run shell-drop --no-frames` and the same scenes with
//! `solver.globalization = "project-on-demand"`: on the drape project-on-demand needs 727 iterations and 928
//! factorizations against the shift's 939 and 2 265; on the folding `shell-drop` 1 331 iterations and
//! 2 250 factorizations against 1 181 and 3 189, with the worst frame at 167 iterations instead of 74 (in
//! the impact frames 1–19: 571 against 409 — the definite membrane and hinge Hessians drop curvature a
//! folding shell needs). Neither policy reaches one factorization per iteration on both scenes, so the default
//! stays the shift. Always using the definite Hessian (STARK's and Codim-IPC's projected Newton) factors
//! once per iteration but needs 1 647 iterations on the drape: it converges only linearly (nineteenth
//! session, with extrapolation and the shift memory, a temporary switch in `Newton::iterate`: 1 094
//! iterations / 1 094 factorizations, the resting frames taking 6–8 iterations instead of 4–5).
//!
//! # Extrapolation
//! Near a saddle of F (a compressed cloth about to buckle) the shifted system's step along a direction of
//! negative curvature `−μ` is the gradient's component times `1/(σ − μ)` for a shift `σ > μ`: when the
//! shift overshoots (the 4-fold ladder lands anywhere in `[μ, 4μ]`), every iteration moves only a fraction
//! of the way off the saddle, and Newton crawls (one drape step took 25 such iterations with F falling by
//! 1e-10 each). So after a full step (`α = 1`) of a shifted or definite system, Newton tries `α = 2, 4, …`
//! (at most 4 096) while F keeps decreasing and takes the best ([`NewtonParams::extrapolate`], on by
//! default; each trial is one energy evaluation, counted in [`NewtonStats::line_search_steps`]). Exact
//! unshifted steps are never extrapolated, so the quadratic convergence at the end is unchanged. Measured
//! on the drape (`hinge run drape --no-frames`, and with `extrapolate = false` under `[solver]`): see the
//! README's performance section.
//!
//! # Geodesic acceleration
//! A folding cloth or a crumpling shell turns its panels: their points move on arcs, and a straight
//! Newton step along an arc stretches the membrane, which the line search then shortens, so Newton
//! creeps along the curved valleys of F in short steps. With [`NewtonParams::geodesic_acceleration`]
//! (on by default) each exact or shifted direction `d`, `(H + σ) d = −∇F`, gets a second-order
//! correction `a`, `(H + σ) a = −∇³F[d, d]`: the next term of the expansion of `∇F(x + t d + t²a/2) = 0`
//! (Chebyshev's method when `σ = 0`; Transtrum & Sethna's geodesic acceleration of Levenberg–Marquardt,
//! arXiv:1201.5885). The third-derivative term comes from one extra gradient, at `x + h d` with
//! `h` = [`ACCELERATION_STEP`]: `2/h² (∇F(x + h d) − ∇F(x) − h H d)`, where `H d = −∇F(x) − σ d` needs no
//! product; the factorization of `d` solves for `a` (one triangular solve, no factorization). The
//! corrected full step `x + d + a/2` is tried first when `‖a‖ ≤` [`ACCELERATION_RATIO`] `‖d‖` and taken
//! when F falls by Armijo's fraction of the decrease predicted along `d` (within any step bound; a
//! shifted one is then extrapolated as usual, along `α d + α²/2 a`); otherwise the plain line search
//! along `d` runs, from the full step. Definite directions ([`Globalization::ProjectOnDemand`]) are not
//! corrected: `H d` is not known for them, and a correction from central differences of the gradient
//! measured worse (drape 611–620 iterations against 570–577). Nor are the directions of a system with a
//! term whose Hessian is not exact ([`Objective::hessian_is_exact`]: a hinge term in Gauss–Newton or
//! projected mode): there the factored `M` is not `H`, the difference quotient holds `2 (H − M) d / h`
//! besides the third-derivative term, and the step `a/2` it gives is `1/h` = 10 times the quasi-Newton
//! correction `−M⁻¹ (H − M) d`. Measured on the
//! drape's five starts with its bending in Gauss–Newton mode (`bending.hessian = "gauss-newton"`),
//! corrected → not: 830–1 072 (median 1 016 / 1 853) → 762–774 (772 / 1 212); projected: 912–1 059
//! (939 / 1 508) → 762–777 (767 / 1 169). Every corrected step counts in
//! [`NewtonStats::accelerated_iterations`].
//!
//! Measured over `docs/newton/ensemble.sh`'s five starts (`iterations / factorizations` of the median
//! run), without → with the correction: drape 742–771 (757 / 1 203) → 612–617 (614 / 1 030); with
//! project on demand 677–681 → 570–577 (574 / 698). `shell-drop`, whose runs spread far more:
//! 1 085–1 424 (1 192 / 2 802; per-frame medians 10.5–15.5, maxima 54–74) → 1 059–1 324 (1 217 / 3 021;
//! 8.5–11.5, 58–92); with project on demand 1 072–1 239 (1 130 / 1 505) → 984–1 258 (1 077 / 1 452). The
//! figures for the correction's constants are at [`ACCELERATION_STEP`], [`ACCELERATION_RATIO`] and
//! [`ACCELERATION_RESOLUTION`].
//!
//! # Step bounds
//! An objective may bound the move of a step ([`Objective::max_step`]: a barrier contact's continuous
//! collision bound, the fraction of the step after which some vertex would have closed 90 % of its gap to an
//! obstacle). The line search then starts at that fraction instead of 1, and extrapolation never passes it;
//! such a shortened step is not a Newton step for the step tests. [`ImplicitEuler`] starts a step at `x̂`,
//! or, when the bound of the move from the last state `x` to `x̂` is `t < 1`, at `x + t (x̂ − x)` (pinned
//! vertices at their targets): `x̂` itself may lie beyond an obstacle the straight path crosses. With a
//! moving barrier obstacle `x` is first carried with it ([`System::carry`]). Measured
//! (`hinge run` of the drape and `shell-drop` with `model = "barrier"`): drape 791 iterations / 1 169
//! factorizations, `shell-drop` 1 004 / 2 144 (median 13, max 47 per frame); starting at `x̂` whenever it
//! can be evaluated (from `x` otherwise) gave 718 / 951 and 1 013 / 2 074 (median 15, max 42) but lets a
//! fast vertex start beyond a sphere; holding back only the vertices whose move reaches the obstacle gave
//! the drape 765 / 1 145 and distorted `shell-drop`'s starts (median 30 over its first 35 frames).
//!
//! When the line search fails — a near-singular Hessian (say a sheet pinned along one row of vertices, free
//! to swing about it) gives an enormous step along the soft mode — the iteration is retried with a
//! Levenberg–Marquardt shift raised 100-fold each time ([`NewtonParams::damped_retries`]).
//!
//! # Stopping
//! A solve stops at the first of: ‖∇F‖ ≤ [`NewtonParams::gradient_tolerance`] (absolute, in the problem's
//! force units); ‖∇F‖ ≤ [`NewtonParams::relative_gradient_tolerance`] × ‖∇F(x_start)‖ (unit-free: for
//! implicit Euler the start is `x̂`, whose gradient is the force imbalance the step resolves); a step
//! ‖Δx‖ ≤ [`NewtonParams::step_tolerance`] (absolute); a step whose largest vertex displacement is at most
//! [`NewtonParams::relative_step_tolerance`] × [`NewtonParams::length_scale`] (unit-free: the CLI sets the
//! length scale to the mean rest edge length). The relative tests are off (0) by default. The two step
//! tests count only after a full step (`α = 1`) of the exact, unshifted Newton system, or when that
//! system's direction predicts a decrease `|∇Fᵀd|` below the rounding of F (see Rounding: no iteration can
//! make measurable progress, as for stiff strips whose gradient floors at rounding); a shifted or definite
//! direction predicts a small decrease because of its shift, not because F is at its floor. A diagonal
//! shift, a Levenberg–Marquardt retry or the line search shortens steps far from a solution too: before this
//! rule, a shifted and halved step of 1e-9 m ended a step of the 81×81 drape with ‖∇F‖ = 287. A system
//! with a term whose Hessian is not exact ([`Objective::hessian_is_exact`]: a hinge term in Gauss–Newton
//! or projected mode) has no exact Newton direction, so its step tests never count: with the `cow`'s
//! bending projected per hinge, a full step of 1e-9 m ended a time step at ‖∇F‖ = 0.19 N before this rule
//! (its gradient tests and the stall rule end such solves). In a time
//! step ([`ImplicitEuler`]) a solve that a step test ends above the gradient tests and above √ε times its
//! start's gradient, with a last step that moves no coordinate by more than a few units in the last place,
//! is [`SolverError::Stuck`] and the step is retried with substeps: such an iterate cannot move (a
//! collapsed triangle) and solves nothing; so is one that a step test ends with ‖∇F‖ more than ten times
//! its start's.
//!
//! A solve that cannot get closer stops early instead of running to the iteration limit: after
//! [`STALL_ITERATIONS`] accepted steps in a row that are shorter than [`STALL_STEP`] of the Newton
//! direction or lie within F's rounding (accepted within it, full exact Newton steps predicted to change
//! F by less than [`ROUNDING_BAND`] rounding allowances, or any step predicted to change it by less than
//! one allowance — a shifted step along a gradient that no step lowers: a collapsing triangle's, or the
//! kink of the test `a_shifted_step_below_the_rounding_does_not_end_a_solve`), none lowering the smallest
//! gradient norm so far by a tenth, it fails with [`SolverError::Stalled`]. That is where a gradient
//! tolerance lies below what rounding lets the gradient reach: a strip of Y = 5e9 Pa asked for 1e-9 N
//! crawled at 1.2e-9 … 2.3e-9 for 2 000 iterations before this rule.
//!
//! # Rounding
//! F is a sum over many elements and terms (and the inertia energy), so its rounding error scales with
//! `Σ |term energy|`, not with |F|: gravity's energy of a cloth far from the origin, say, is large and
//! cancels against the elastic terms' in F. The rounding allowance is `8ε (Σ_terms |E_term| + E_inertia)`
//! (at least `8ε|F|`). Near the floor, F's values cannot tell a step that lowers F from one that raises
//! it, so the line search judges a trial whose F differs from the current one by at most
//! [`ROUNDING_BAND`] allowances by its slope instead: it is accepted when the directional derivative
//! there is at most `(1 − 2c)` times the magnitude of the one at the start (c the Armijo constant; for F
//! quadratic along the line this is Armijo's test, computed from gradients, which round at the scale of
//! the forces, not of the energies; Hager & Zhang's approximate Wolfe condition). A trial within the
//! allowance itself is accepted as before. Measured on the strip of the stall test
//! (`solver::a_tolerance_below_the_rounding_floor_stalls_early`): the smallest gradient norm a solve
//! reaches went from 8.8e-10 N (allowance `8ε|F|`, F's value only) to 2.9e-10 N; the drape's and
//! `shell-drop`'s counts are unchanged (their steps end far above the floor).
//!
//! A failed solve leaves the caller's state untouched and reports diagnostics.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use hinge_core::EvalError;
use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{System, SystemEvaluation};
use hinge_core::nalgebra::Vector3;
use hinge_core::pattern::SymmetricPattern;
use hinge_energies::pins::Pins;

use crate::linear::{LinearError, LinearSolver, LowerCsc};

/// Anything Newton can minimise: energy, gradient and a Hessian in a fixed pattern.
pub trait Objective {
    /// Number of vertices.
    fn n_vertices(&self) -> usize;
    /// The Hessian's pattern.
    fn pattern(&self) -> &SymmetricPattern;
    /// Evaluates at `x` into `out`.
    ///
    /// # Errors
    /// The objective's typed errors.
    fn evaluate(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        out: &mut SystemEvaluation,
    ) -> Result<(), EvalError>;

    /// The largest fraction of the move `from → to` the objective admits ([`Energy::max_step`]); the line
    /// search starts there. Default: 1.
    ///
    /// [`Energy::max_step`]: hinge_core::energy::Energy::max_step
    fn max_step(&self, from: &[Vector3<f64>], to: &[Vector3<f64>]) -> f64 {
        let _ = (from, to);
        1.0
    }

    /// Whether [`Objective::evaluate`]'s Hessian is the energy's exact second derivative (the step tests
    /// count only after full steps of an exact Hessian; module documentation, Stopping). Default: true.
    fn hessian_is_exact(&self) -> bool {
        true
    }
}

impl Objective for System {
    fn n_vertices(&self) -> usize {
        System::n_vertices(self)
    }
    fn pattern(&self) -> &SymmetricPattern {
        System::pattern(self)
    }
    fn evaluate(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        out: &mut SystemEvaluation,
    ) -> Result<(), EvalError> {
        // Derivatives that overflowed would reach the factorization as a failed pivot or a NaN step: the
        // evaluation names the term and the vertex instead (`System::check_finite`).
        self.evaluate_into(x, request, Parallelism::Rayon, out)
    }
    fn max_step(&self, from: &[Vector3<f64>], to: &[Vector3<f64>]) -> f64 {
        System::max_step(self, from, to)
    }
    fn hessian_is_exact(&self) -> bool {
        System::hessian_is_exact(self)
    }
}

/// The inertia term of implicit Euler.
#[derive(Debug, Clone)]
pub struct Inertia {
    /// Lumped vertex masses.
    pub masses: Vec<f64>,
    /// `x̂ = x⁰ + Δt v⁰`.
    pub x_hat: Vec<Vector3<f64>>,
    /// The time step.
    pub dt: f64,
}

/// The largest [`NewtonParams::max_iterations`] the scene files and the Python package accept: a budget
/// beyond a million Newton iterations per solve is a run that never ends, not a limit.
pub const MAX_ITERATIONS_CEILING: usize = 1_000_000;

/// [`MAX_ITERATIONS_CEILING`] as front ends' messages print it, digits grouped by threes with spaces (a
/// unit test keeps the two equal).
pub const MAX_ITERATIONS_CEILING_TEXT: &str = "1 000 000";

/// Newton parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct NewtonParams {
    /// Iteration limit, at least 1 ([`NewtonParams::validate`]; front ends accept 1 to
    /// [`MAX_ITERATIONS_CEILING`]).
    pub max_iterations: usize,
    /// Stop when the free gradient norm ‖∇F‖ is at most this.
    pub gradient_tolerance: f64,
    /// Stop when the step norm ‖Δx‖ is at most this.
    pub step_tolerance: f64,
    /// Armijo constant.
    pub armijo: f64,
    /// Line-search halvings before giving up.
    pub max_line_search: usize,
    /// First diagonal shift tried when the factorization fails (relative to the largest diagonal entry).
    pub initial_shift: f64,
    /// Shift attempts before giving up.
    pub max_shifts: usize,
    /// Baraff–Witkin mode: take exactly one (line-searched) Newton step per solve and accept it, converged
    /// or not — the classic single-iteration implicit Euler.
    pub single_iteration: bool,
    /// When the line search fails (a near-singular Hessian gives a huge step along a soft mode), retry the
    /// iteration this many times with a diagonal shift raised 100-fold each time (Levenberg–Marquardt
    /// damping: shorter, more gradient-like steps) before reporting [`SolverError::LineSearch`].
    pub damped_retries: usize,
    /// What to do with an indefinite Hessian (see the module documentation).
    pub globalization: Globalization,
    /// Stop when ‖∇F‖ ≤ this × ‖∇F‖ at the start of the solve (0: off).
    pub relative_gradient_tolerance: f64,
    /// Stop when the largest vertex displacement of a step is ≤ this × [`NewtonParams::length_scale`]
    /// (0: off).
    pub relative_step_tolerance: f64,
    /// The length the relative step test is measured against (the mean rest edge length, say; 0: off).
    pub length_scale: f64,
    /// After a full step (`α = 1`) of a shifted or definite Newton system, try `α = 2, 4, …` (at most
    /// 4 096) while F keeps decreasing, and take the best (module documentation, Extrapolation).
    pub extrapolate: bool,
    /// Start the shift ladder at a quarter of the last shift that factored, in this solve or an earlier one
    /// of the same [`Newton`] (module documentation, Globalization); `false`: every solve starts from
    /// [`NewtonParams::initial_shift`], independent of the solves before it.
    pub remember_shift: bool,
    /// Correct the full step of an exact or shifted Newton direction `d` by geodesic acceleration: try
    /// `x + d + a/2`, with `(H + σ) a = −∇³F[d, d]` from one extra gradient evaluation, before the plain
    /// line search along `d` (module documentation, Geodesic acceleration). Only on an exact Hessian: a
    /// system whose [`Objective::hessian_is_exact`] is false gets no correction.
    pub geodesic_acceleration: bool,
    /// With [`Globalization::ShiftedExact`] in a time step: when the diagonal shift an iteration's ladder
    /// needs exceeds this many times the largest inertia term `m/Δt²` of a free vertex, the iteration takes
    /// each energy's definite Hessian instead, and so do the following ones until
    /// [`NewtonParams::definite_hold`] full steps, as [`Globalization::ProjectOnDemand`] does (module
    /// documentation, Globalization). `f64::INFINITY`: never (the shift alone). Statics are unaffected
    /// (no inertia).
    pub definite_shift_ratio: f64,
    /// Full steps (`α = 1`; an extrapolated one does not count) taken with the definite Hessian, once an
    /// iteration switched to it ([`Globalization::ProjectOnDemand`] after a failed exact factorization, or
    /// a shift above [`NewtonParams::definite_shift_ratio`]), before the exact Hessian is tried again
    /// (module documentation, Globalization). 1: right after the first full definite step. At least 1.
    pub definite_hold: usize,
}

/// How Newton handles a Hessian that is not positive definite (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Globalization {
    /// The exact Hessian when it factors, otherwise each energy's definite Hessian until
    /// [`NewtonParams::definite_hold`] full steps are taken; a diagonal shift only if that fails too.
    ProjectOnDemand,
    /// The exact Hessian, with a diagonal shift raised until it factors (the default).
    #[default]
    ShiftedExact,
}

impl Globalization {
    /// The scene-file name: `project-on-demand` or `shifted-exact`.
    pub fn name(self) -> &'static str {
        match self {
            Globalization::ProjectOnDemand => "project-on-demand",
            Globalization::ShiftedExact => "shifted-exact",
        }
    }

    /// Parses [`Globalization::name`].
    pub fn from_name(s: &str) -> Option<Self> {
        [Globalization::ProjectOnDemand, Globalization::ShiftedExact]
            .into_iter()
            .find(|g| g.name() == s)
    }
}

impl NewtonParams {
    /// The stopping tests (module documentation): `gradient` is ‖∇F‖ now, `initial` at the start of the
    /// solve, `step` the last step's norm and largest vertex displacement (none before the first step).
    pub fn converged(&self, gradient: f64, initial: f64, step: Option<(f64, f64)>) -> bool {
        if gradient <= self.gradient_tolerance
            || (self.relative_gradient_tolerance > 0.0
                && gradient <= self.relative_gradient_tolerance * initial)
        {
            return true;
        }
        step.is_some_and(|(norm, largest)| {
            norm <= self.step_tolerance
                || (self.relative_step_tolerance > 0.0
                    && self.length_scale > 0.0
                    && largest <= self.relative_step_tolerance * self.length_scale)
        })
    }
}

impl Default for NewtonParams {
    fn default() -> Self {
        Self {
            max_iterations: 50,
            gradient_tolerance: 1e-8,
            step_tolerance: 1e-12,
            armijo: 1e-4,
            max_line_search: 40,
            initial_shift: 1e-8,
            max_shifts: 40,
            single_iteration: false,
            damped_retries: 8,
            globalization: Globalization::ShiftedExact,
            relative_gradient_tolerance: 0.0,
            relative_step_tolerance: 0.0,
            length_scale: 0.0,
            extrapolate: true,
            remember_shift: true,
            geodesic_acceleration: true,
            definite_shift_ratio: DEFINITE_SHIFT_RATIO,
            definite_hold: DEFINITE_HOLD,
        }
    }
}

/// The default [`NewtonParams::definite_shift_ratio`] (module documentation, Globalization).
pub const DEFINITE_SHIFT_RATIO: f64 = 1000.0;

/// The default [`NewtonParams::definite_hold`] (module documentation, Globalization).
pub const DEFINITE_HOLD: usize = 1;

impl NewtonParams {
    /// Checks that every parameter lies in the range where it means what its documentation says:
    /// `max_iterations` ≥ 1 (any budget above: the histories grow only as a solve runs) and
    /// `definite_hold` ≥ 1; `armijo` in (0, ½) (a unit Newton step near a minimum passes Armijo's test
    /// only below ½, and the rounding band's slope test takes `1 − 2c`); `gradient_tolerance`,
    /// `step_tolerance`, `relative_gradient_tolerance`, `relative_step_tolerance` and `length_scale`
    /// finite and ≥ 0 (0: that test off); `initial_shift` finite and > 0 (the shift ladder multiplies
    /// it); `definite_shift_ratio` ≥ 0, `f64::INFINITY` allowed (never). The counts other than
    /// `max_iterations` may be 0 (no halvings, shifts or damped retries). [`Newton::new`] and
    /// [`Newton::minimize`] call it, so that a parameter out of range is an error naming it instead of
    /// a solve that silently never converges (a NaN tolerance) or a ladder that never climbs (a zero
    /// initial shift).
    ///
    /// # Errors
    /// [`SolverError::Input`] naming the first parameter out of its range and its value.
    pub fn validate(&self) -> Result<(), SolverError> {
        let bad = |name: &str, range: &str, value: f64| {
            Err(SolverError::Input(format!(
                "NewtonParams::{name} must be {range}, got {}",
                hinge_core::error::Num(value)
            )))
        };
        for (name, count) in [
            ("max_iterations", self.max_iterations),
            ("definite_hold", self.definite_hold),
        ] {
            if count == 0 {
                return Err(SolverError::Input(format!(
                    "NewtonParams::{name} must be at least 1, got 0"
                )));
            }
        }
        if !(self.armijo > 0.0 && self.armijo < 0.5) {
            return bad("armijo", "in (0, 1/2)", self.armijo);
        }
        for (name, value) in [
            ("gradient_tolerance", self.gradient_tolerance),
            ("step_tolerance", self.step_tolerance),
            (
                "relative_gradient_tolerance",
                self.relative_gradient_tolerance,
            ),
            ("relative_step_tolerance", self.relative_step_tolerance),
            ("length_scale", self.length_scale),
        ] {
            if !(value >= 0.0 && value.is_finite()) {
                return bad(name, "finite and non-negative (0: off)", value);
            }
        }
        if !(self.initial_shift > 0.0 && self.initial_shift.is_finite()) {
            return bad("initial_shift", "finite and positive", self.initial_shift);
        }
        if !(self.definite_shift_ratio >= 0.0) {
            return bad(
                "definite_shift_ratio",
                "non-negative (inf: never)",
                self.definite_shift_ratio,
            );
        }
        Ok(())
    }
}

/// Iterations the per-solve histories ([`NewtonStats::gradient_norms`], [`NewtonStats::step_norms`]) have
/// room for before they grow: `max_iterations` can be anything a scene file says (`4294967296` once
/// asked for 32 GiB up front and aborted the process).
const HISTORY_CAPACITY: usize = 1024;

/// What a Newton solve did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NewtonStats {
    /// Newton iterations.
    pub iterations: usize,
    /// Line-search trials after the first: halvings, and the doublings of an extrapolated step, summed.
    pub line_search_steps: usize,
    /// Numeric factorizations attempted (failed shifted ones included).
    pub factorizations: usize,
    /// Iterations whose step used the definite Hessian ([`Globalization::ProjectOnDemand`]).
    pub definite_iterations: usize,
    /// Iterations whose step was the full step corrected by geodesic acceleration
    /// ([`NewtonParams::geodesic_acceleration`]).
    pub accelerated_iterations: usize,
    /// ‖∇F‖ over the free degrees of freedom after each iteration (the first entry is the start).
    pub gradient_norms: Vec<f64>,
    /// ‖Δx‖ of each accepted step (near the solution, the error of the iterate before it).
    pub step_norms: Vec<f64>,
    /// The largest diagonal shift used (0 when the Hessian was positive definite throughout).
    pub max_shift: f64,
    /// Seconds in evaluation and assembly.
    pub eval_seconds: f64,
    /// Seconds in factorization (including failed attempts).
    pub factor_seconds: f64,
    /// Seconds in triangular solves.
    pub solve_seconds: f64,
    /// Where the residual is at the solve's last iterate (the solution, or where a failed solve stopped):
    /// the vertex whose free dofs carry the largest force `‖∂F/∂x_v‖`, and that norm. `None` when no
    /// gradient was evaluated or no dof is free. It tells which part of a mesh a solve that does not
    /// converge is stuck on (a sliver, a crushed triangle, a vertex pushed into an obstacle).
    pub largest_residual: Option<(usize, f64)>,
}

/// Why a Newton solve failed. The caller's state is untouched.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SolverError {
    /// The objective could not be evaluated.
    #[error("evaluation failed: {source}")]
    Eval {
        /// The error.
        source: EvalError,
        /// What was done before.
        stats: Box<NewtonStats>,
    },
    /// The linear system could not be solved, even with the largest shift.
    #[error("linear solve failed after {} iterations (shift {:.3e}): {source}", stats.iterations, stats.max_shift)]
    Linear {
        /// The error.
        source: LinearError,
        /// What was done before.
        stats: Box<NewtonStats>,
    },
    /// The line search found no decrease.
    #[error("line search failed at iteration {} (gradient norm {:.3e})", stats.iterations, stats.gradient_norms.last().copied().unwrap_or(f64::NAN))]
    LineSearch {
        /// What was done.
        stats: Box<NewtonStats>,
    },
    /// The iteration limit was reached.
    #[error("no convergence in {} iterations (gradient norm {:.3e})", stats.iterations, stats.gradient_norms.last().copied().unwrap_or(f64::NAN))]
    NotConverged {
        /// What was done.
        stats: Box<NewtonStats>,
    },
    /// The iterates stopped moving before the tolerances were met: [`STALL_ITERATIONS`] accepted steps in a
    /// row shorter than [`STALL_STEP`] of the Newton direction or within F's rounding, none of which
    /// lowered the smallest gradient norm so far by a tenth (module documentation, Stopping).
    #[error("stalled after {} iterations at gradient norm {:.3e}: {STALL_ITERATIONS} steps in a row were shorter than {STALL_STEP:e} of Newton's or within the energy's rounding and lowered it by less than a tenth (the rounding floor of this problem, which a gradient tolerance below it cannot meet? or an element collapsing, such as a triangle that a StVK membrane lets be crushed?)", stats.iterations, stats.gradient_norms.last().copied().unwrap_or(f64::NAN))]
    Stalled {
        /// What was done.
        stats: Box<NewtonStats>,
    },
    /// A time step's solve stopped on a step test with ‖∇F‖ above the gradient tolerance and above √ε
    /// times its start's, and a last step that moved no coordinate by more than a few units in the last
    /// place: it stopped where it could not move (a collapsed triangle, say), which is no solution of the
    /// step
    /// ([`ImplicitEuler::advance`] retries the step with smaller substeps).
    #[error("stuck after {} iterations at gradient norm {:.3e}: its steps no longer move the positions or lower the gradient, which is above its tolerance (a collapsed triangle?)", stats.iterations, stats.gradient_norms.last().copied().unwrap_or(f64::NAN))]
    Stuck {
        /// What was done.
        stats: Box<NewtonStats>,
    },
    /// The stop flag ([`Newton::set_stop`]) was raised: the solve ended before its next iteration, with the
    /// positions untouched.
    #[error("interrupted after {} iterations", stats.iterations)]
    Interrupted {
        /// What was done.
        stats: Box<NewtonStats>,
    },
    /// The Hessian of F is zero on every free dof while its gradient is not: F is linear there, and Newton
    /// has neither a step nor a scale to shift by (a static solve of gravity alone, with no energy to hold
    /// the mesh).
    #[error("the Hessian is zero on every free dof at iteration {} while the gradient is not (norm {:.3e}): nothing resists the load there (gravity or forces with no stiffness against them, or no energy acting on these vertices?)", stats.iterations, stats.gradient_norms.last().copied().unwrap_or(f64::NAN))]
    ZeroHessian {
        /// What was done before.
        stats: Box<NewtonStats>,
    },
    /// Inputs that do not fit (sizes, non-finite time step).
    #[error("{0}")]
    Input(String),
    /// An explicit step blew up (see [`crate::explicit`]).
    #[error("unstable: {message}")]
    Unstable {
        /// Where and why.
        message: String,
    },
}

impl NewtonStats {
    /// Adds another solve's counters and times, but not its norms (a failed attempt before this solve: its
    /// work counts, its gradient norms are not this solve's).
    pub fn absorb_counts(&mut self, other: &NewtonStats) {
        self.iterations += other.iterations;
        self.line_search_steps += other.line_search_steps;
        self.factorizations += other.factorizations;
        self.definite_iterations += other.definite_iterations;
        self.accelerated_iterations += other.accelerated_iterations;
        self.max_shift = self.max_shift.max(other.max_shift);
        self.eval_seconds += other.eval_seconds;
        self.factor_seconds += other.factor_seconds;
        self.solve_seconds += other.solve_seconds;
    }

    /// Adds another solve's counters and times (iterations, halvings, factorizations, seconds; the largest
    /// shift; the norms are appended, and the later solve's [`NewtonStats::largest_residual`] is kept).
    pub fn absorb(&mut self, other: &NewtonStats) {
        self.absorb_counts(other);
        self.gradient_norms.extend_from_slice(&other.gradient_norms);
        self.step_norms.extend_from_slice(&other.step_norms);
        if other.largest_residual.is_some() {
            self.largest_residual = other.largest_residual;
        }
    }
}

impl SolverError {
    /// What the failed solve did before it stopped (empty for input errors).
    pub fn stats(&self) -> NewtonStats {
        match self {
            SolverError::Eval { stats, .. }
            | SolverError::Linear { stats, .. }
            | SolverError::LineSearch { stats }
            | SolverError::NotConverged { stats }
            | SolverError::Stalled { stats }
            | SolverError::Stuck { stats }
            | SolverError::ZeroHessian { stats }
            | SolverError::Interrupted { stats } => (**stats).clone(),
            SolverError::Input(_) | SolverError::Unstable { .. } => NewtonStats::default(),
        }
    }

    /// The stats of a solve that stopped at an iterate whose gradient is known (every kind but an
    /// evaluation failure, input errors and explicit blow-ups).
    fn stopped_stats_mut(&mut self) -> Option<&mut NewtonStats> {
        match self {
            SolverError::Linear { stats, .. }
            | SolverError::LineSearch { stats }
            | SolverError::NotConverged { stats }
            | SolverError::Stalled { stats }
            | SolverError::Stuck { stats }
            | SolverError::ZeroHessian { stats }
            | SolverError::Interrupted { stats } => Some(stats),
            SolverError::Eval { .. } | SolverError::Input(_) | SolverError::Unstable { .. } => None,
        }
    }
}

/// Prescribed positions of pinned vertices over a frame (moving boundaries): see
/// [`ImplicitEuler::advance_with`]. Closures `Fn(f64, &mut [Vector3<f64>])` implement it.
pub trait PinMotion {
    /// Writes the target position of every moving pinned vertex at `fraction` ∈ (0, 1] of the frame into
    /// `x` (a full position vector; entries of other vertices are to be left alone).
    fn targets(&self, fraction: f64, x: &mut [Vector3<f64>]);
}

impl<F: Fn(f64, &mut [Vector3<f64>])> PinMotion for F {
    fn targets(&self, fraction: f64, x: &mut [Vector3<f64>]) {
        self(fraction, x);
    }
}

/// How [`ImplicitEuler::advance`] splits a frame when a step fails: halve the substep (retrying from the same
/// state), down to `dt / 2^max_halvings`, and after each success grow it back (doubling, never beyond the
/// frame's dt).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SubstepPolicy {
    /// The floor: the smallest substep is `dt / 2^max_halvings` (at most 30). Default 5 (dt/32).
    pub max_halvings: u32,
}

impl Default for SubstepPolicy {
    fn default() -> Self {
        Self { max_halvings: 5 }
    }
}

/// What [`ImplicitEuler::advance`] did for one frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameStats {
    /// Newton counters summed over every attempt, failed substeps included (their work was done).
    pub newton: NewtonStats,
    /// Accepted substeps (1 when the frame's dt worked at once).
    pub substeps: usize,
    /// Failed attempts that were retried with a smaller substep.
    pub failed_attempts: usize,
    /// The smallest accepted substep as a fraction of the frame's dt.
    pub smallest_fraction: f64,
    /// The largest final ‖∇F‖ over the accepted substeps.
    pub max_final_gradient_norm: f64,
}

/// The free-dof subsystem of a pattern: reduced lower CSC and where each reduced value comes from.
#[derive(Debug, Clone)]
pub struct Reduced {
    /// The reduced pattern.
    pub csc: LowerCsc,
    /// For each reduced value, the full value index.
    pub source: Vec<usize>,
    /// Full scalar dof of each reduced dof.
    pub dofs: Vec<usize>,
    /// Reduced value index of each reduced diagonal.
    pub diag: Vec<usize>,
}

impl Reduced {
    /// Eliminates the dofs with `free[i] == false` (`free` indexed by the caller's scalar dofs). The reduced
    /// system keeps the pattern's storage order (a locality order): reduced dof `k` is the caller's dof
    /// `dofs[k]`.
    pub fn new(pattern: &SymmetricPattern, free: &[bool]) -> Self {
        let n = pattern.dim();
        // Storage scalar index → reduced index.
        let mut map = vec![usize::MAX; n];
        let mut dofs = Vec::new();
        for i in 0..n {
            let d = pattern.caller_dof(i);
            if free.get(d).copied().unwrap_or(true) {
                map[i] = dofs.len();
                dofs.push(d);
            }
        }
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        let mut col_ptr = vec![0usize];
        let (mut row_idx, mut source, mut diag) = (Vec::new(), Vec::new(), Vec::new());
        for c in 0..n {
            if map[c] == usize::MAX {
                continue;
            }
            for k in cp[c]..cp[c + 1] {
                let r = ri[k];
                if map[r] != usize::MAX {
                    if r == c {
                        diag.push(row_idx.len());
                    }
                    row_idx.push(map[r]);
                    source.push(k);
                }
            }
            col_ptr.push(row_idx.len());
        }
        Self {
            csc: LowerCsc {
                n: dofs.len(),
                col_ptr,
                row_idx,
            },
            source,
            dofs,
            diag,
        }
    }
}

/// What [`Newton::set_observer`]'s callback sees after each accepted iteration of [`Newton::minimize`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct IterationReport {
    /// The iteration just done, counted from 1 in this solve (as [`NewtonStats::iterations`]).
    pub iteration: usize,
    /// F at the new iterate: the objective plus the inertia term when there is one.
    pub energy: f64,
    /// ‖∇F‖ over the free degrees of freedom at the new iterate (the entry this iteration appends to
    /// [`NewtonStats::gradient_norms`]).
    pub gradient_norm: f64,
    /// ‖Δx‖ of the accepted step (the entry appended to [`NewtonStats::step_norms`]).
    pub step_norm: f64,
    /// The line search's step length α (1 for a full step; above 1 for an extrapolated one).
    pub step_length: f64,
    /// The diagonal shift of the factored matrix (0 for the unshifted Hessian).
    pub shift: f64,
    /// Whether the step used the definite Hessian ([`Globalization::ProjectOnDemand`]).
    pub definite: bool,
    /// Whether the step was the full step corrected by geodesic acceleration
    /// ([`NewtonParams::geodesic_acceleration`]).
    pub accelerated: bool,
    /// The vertex with the largest force `‖∂F/∂x_v‖` over its free dofs at the new iterate, and that norm
    /// (as [`NewtonStats::largest_residual`]).
    pub largest_residual: Option<(usize, f64)>,
    /// The continuation stage this solve is, `(k, n)` with `k` counted from 1 and the final solve at the
    /// full parameter being stage `n` ([`crate::statics::minimize_continued`], [`Newton::set_stage`]);
    /// `None` outside a continuation.
    pub stage: Option<(usize, usize)>,
}

/// The callback of [`Newton::set_observer`].
pub type Observer = Box<dyn FnMut(&IterationReport) + Send>;

/// A callback [`ImplicitEuler::set_substep_observer`] calls after every accepted (sub)step with its end
/// positions and end time.
pub type SubstepObserver = Box<dyn FnMut(&[Vector3<f64>], f64) + Send>;

/// A Newton minimiser bound to an objective's pattern and a set of pins (the symbolic analysis is done once
/// here and reused by every iteration and every later solve).
pub struct Newton {
    /// Parameters.
    pub params: NewtonParams,
    solver: Box<dyn LinearSolver>,
    reduced: Reduced,
    values: Vec<f64>,
    /// `values` plus the diagonal shift being tried (reused: no allocation per factorization).
    shifted: Vec<f64>,
    /// The last positive shift the ladder found (in this solve or an earlier one): the next ladder starts
    /// near it.
    ladder_hint: f64,
    out: Option<SystemEvaluation>,
    work: Work,
    /// Checked before every iteration ([`Newton::set_stop`]).
    stop: Option<Arc<AtomicBool>>,
    /// Called after every accepted iteration ([`Newton::set_observer`]).
    observer: Option<Observer>,
    /// Passed to the observer ([`Newton::set_stage`]).
    stage: Option<(usize, usize)>,
}

impl std::fmt::Debug for Newton {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Newton")
            .field("params", &self.params)
            .field("solver", &self.solver.name())
            .field("observer", &self.observer.is_some())
            .finish()
    }
}

impl Newton {
    /// Binds to `objective`'s pattern with `pins` eliminated, analysing it with `solver`.
    ///
    /// # Errors
    /// [`SolverError::Input`] for a parameter out of its range ([`NewtonParams::validate`]);
    /// [`SolverError::Linear`] if the analysis fails.
    pub fn new<O: Objective>(
        objective: &O,
        pins: &Pins,
        mut solver: Box<dyn LinearSolver>,
        params: NewtonParams,
    ) -> Result<Self, SolverError> {
        params.validate()?;
        let mut free = pins.free_dofs();
        free.resize(3 * objective.n_vertices(), true);
        let reduced = Reduced::new(objective.pattern(), &free);
        solver
            .analyze(&reduced.csc)
            .map_err(|source| SolverError::Linear {
                source,
                stats: Box::default(),
            })?;
        let values = vec![0.0; reduced.source.len()];
        Ok(Self {
            params,
            solver,
            reduced,
            values,
            shifted: Vec::new(),
            ladder_hint: 0.0,
            out: None,
            work: Work::default(),
            stop: None,
            observer: None,
            stage: None,
        })
    }

    /// The linear solver (for its statistics, such as [`LinearSolver::analyses`]).
    pub fn solver(&self) -> &dyn LinearSolver {
        self.solver.as_ref()
    }

    /// The shift memory ([`NewtonParams::remember_shift`]): the last positive shift the ladder found (0
    /// before any). It carries from one solve to the next, so a checkpoint that is to continue a run
    /// exactly holds it ([`Newton::restore_shift_memory`]).
    pub fn shift_memory(&self) -> f64 {
        self.ladder_hint
    }

    /// Sets the shift memory to a value [`Newton::shift_memory`] returned (a run resumed from a
    /// checkpoint: its solves then take the steps the uninterrupted run took).
    ///
    /// # Errors
    /// [`SolverError::Input`] for a negative or non-finite value (nothing changes then).
    pub fn restore_shift_memory(&mut self, memory: f64) -> Result<(), SolverError> {
        if !(memory >= 0.0 && memory.is_finite()) {
            return Err(SolverError::Input(format!(
                "shift memory must be non-negative and finite, got {memory}"
            )));
        }
        self.ladder_hint = memory;
        Ok(())
    }

    /// Sets the shift memory back (a failed sequence of solves, [`crate::statics::minimize_continued`]).
    pub(crate) fn set_shift_memory(&mut self, memory: f64) {
        self.ladder_hint = memory;
    }

    /// A flag another thread (a Ctrl-C handler, a GUI's cancel button) raises to end the solves: every
    /// [`Newton::minimize`] reads it before each iteration and, once it is set, returns
    /// [`SolverError::Interrupted`] with the positions untouched (like every failed solve). The flag is
    /// never cleared here; `None` removes it.
    pub fn set_stop(&mut self, flag: Option<Arc<AtomicBool>>) {
        self.stop = flag;
    }

    /// A callback every [`Newton::minimize`] calls after each accepted iteration, with the new iterate's
    /// energy and gradient norm and the step taken ([`IterationReport`]): progress output for long solves,
    /// logging, convergence plots. It sees nothing of an iteration whose line search fails (the solve then
    /// ends with [`SolverError::LineSearch`]) and cannot change the solve: with or without it, the iterates
    /// are bitwise the same. `None` removes it.
    pub fn set_observer(&mut self, observer: Option<Observer>) {
        self.observer = observer;
    }

    /// The continuation stage the following solves belong to, passed to the observer as
    /// [`IterationReport::stage`] (set by [`crate::statics::minimize_continued`] around its stages and
    /// cleared after; `None` outside one). It changes nothing else.
    pub fn set_stage(&mut self, stage: Option<(usize, usize)>) {
        self.stage = stage;
    }

    /// The shift above which an iteration of [`Globalization::ShiftedExact`] switches to the definite
    /// Hessian: [`NewtonParams::definite_shift_ratio`] times the largest `m/Δt²` of a free vertex; ∞
    /// without inertia (statics), for the other globalization, or when no free vertex has mass.
    fn definite_above(&self, params: &NewtonParams, inertia: Option<&Inertia>) -> f64 {
        let Some(i) = inertia else {
            return f64::INFINITY;
        };
        if params.globalization != Globalization::ShiftedExact {
            return f64::INFINITY;
        }
        let mass = self
            .reduced
            .dofs
            .iter()
            .map(|&d| i.masses[d / 3])
            .fold(0.0, f64::max);
        let above = params.definite_shift_ratio * mass / (i.dt * i.dt);
        if mass > 0.0 && above.is_finite() {
            above
        } else {
            f64::INFINITY
        }
    }

    /// Minimises the objective (plus `inertia` when given) starting from `x`, with pinned vertices held at
    /// their values in `x`. On success `x` holds the minimiser; on failure `x` is unchanged, and so is the
    /// remembered shift ([`NewtonParams::remember_shift`]).
    ///
    /// Each iteration: assemble the reduced Hessian, factor it under the [`Globalization`], solve for the
    /// direction, line-search it (with Levenberg–Marquardt retries when that fails), and stop when
    /// [`NewtonParams::converged`] says so. The work vectors live in the solver and are reused: nothing is
    /// allocated per iteration.
    ///
    /// # Errors
    /// [`SolverError::Input`] for positions or inertia of the wrong size or a parameter out of its range
    /// ([`NewtonParams::validate`], checked again here since [`Newton::params`] is public; nothing
    /// changes then); otherwise [`SolverError`] with the statistics so far.
    pub fn minimize<O: Objective>(
        &mut self,
        objective: &mut O,
        x: &mut [Vector3<f64>],
        inertia: Option<&Inertia>,
    ) -> Result<NewtonStats, SolverError> {
        let n = objective.n_vertices();
        if x.len() != n
            || inertia.is_some_and(|i| {
                i.masses.len() != n || i.x_hat.len() != n || !(i.dt > 0.0 && i.dt.is_finite())
            })
        {
            return Err(SolverError::Input(format!(
                "{} positions for {n} vertices, or inertia of the wrong size / non-positive dt",
                x.len()
            )));
        }
        // `params` is a public field: checked again here, where a change after `new` takes effect.
        self.params.validate()?;
        let params = self.params.clone();
        let mut stats = NewtonStats {
            // Room for the iterations a solve usually takes; a larger budget (a user may give any) grows
            // the histories only when a solve actually runs that long.
            gradient_norms: Vec::with_capacity(params.max_iterations.min(HISTORY_CAPACITY) + 1),
            step_norms: Vec::with_capacity(params.max_iterations.min(HISTORY_CAPACITY)),
            ..NewtonStats::default()
        };
        let mut out = self.out.take().unwrap_or_else(|| SystemEvaluation {
            energy: 0.0,
            terms: Vec::new(),
            gradient: Vec::new(),
            hessian: Vec::new(),
        });
        let mut w = std::mem::take(&mut self.work);
        w.cur.clear();
        w.cur.extend_from_slice(x);
        w.trial.clear();
        w.trial.extend_from_slice(x);
        let hessian_exact = objective.hessian_is_exact();
        let mut solve = Solve {
            objective,
            inertia,
            params: &params,
            stats: &mut stats,
            out: &mut out,
            magnitude: 0.0,
            definite_above: self.definite_above(&params, inertia),
            hessian_exact,
        };
        let hint = self.ladder_hint;
        let mut result = self.iterate(&mut solve, &mut w);
        // `w.g` is the gradient at `w.cur`, the last iterate, unless an evaluation failed on the way.
        let largest = largest_vertex(&self.reduced.dofs, &w.g);
        match &mut result {
            Ok(()) => {
                stats.largest_residual = largest;
                x.copy_from_slice(&w.cur);
            }
            Err(e) => {
                if let Some(s) = e.stopped_stats_mut() {
                    s.largest_residual = largest;
                }
                // A failed solve leaves the shift memory as it found it: the shift its ladder climbed to
                // belongs to a state that is thrown away.
                self.ladder_hint = hint;
            }
        }
        self.out = Some(out);
        self.work = w;
        result.map(|()| stats)
    }

    /// The Newton loop of [`Newton::minimize`] on the work vectors (`w.cur` is the iterate).
    fn iterate<O: Objective>(
        &mut self,
        s: &mut Solve<'_, O>,
        w: &mut Work,
    ) -> Result<(), SolverError> {
        let p = s.params;
        // Project on demand: the exact Hessian unless the last exact one failed to factor and fewer than
        // `definite_hold` full steps have been taken since.
        let mut definite = false;
        let mut held = 0_usize;
        let mut f = s.eval(&w.cur, Request::ALL)?;
        let mut noise = s.noise();
        self.free_gradient(s, &w.cur, &mut w.g);
        let g0 = norm(&w.g);
        s.stats.gradient_norms.push(g0);
        let mut shift = 0.0_f64;
        let mut stall = Stall {
            best: g0,
            short_steps: 0,
        };
        for it in 0..p.max_iterations {
            if p.converged(norm(&w.g), g0, None) {
                return Ok(());
            }
            if self
                .stop
                .as_ref()
                .is_some_and(|f| f.load(Ordering::Relaxed))
            {
                return Err(SolverError::Interrupted {
                    stats: Box::new(s.stats.clone()),
                });
            }
            self.assemble(s);
            // Levenberg–Marquardt retries: a failed line search raises a minimum diagonal shift.
            let mut damping = 0.0_f64;
            let mut retries = 0;
            let (alpha, accepted) = loop {
                let factored = self.direction(s, w, definite, damping, &mut shift)?;
                definite = factored.definite;
                let expand = p.extrapolate && (shift > 0.0 || definite);
                let (alpha, accepted) = self.line_search(s, w, f, noise, expand);
                if accepted.is_some() || retries >= p.damped_retries {
                    break (alpha, accepted);
                }
                retries += 1;
                damping = if damping == 0.0 {
                    (1e-4 * factored.max_diagonal).max(4.0 * shift)
                } else {
                    damping * 100.0
                };
                s.stats.max_shift = s.stats.max_shift.max(damping);
            };
            s.stats.iterations = it + 1;
            let step_definite = definite;
            if definite {
                s.stats.definite_iterations += 1;
            }
            // The line search leaves the correction in place only when it took the corrected step.
            let accelerated = !w.a.is_empty();
            if accelerated {
                s.stats.accelerated_iterations += 1;
            }
            // A Gauss–Newton or projected term makes no direction an exact Newton one.
            let exact = !definite && s.hessian_exact;
            let tests = StepTests::new(!exact, shift, alpha, dot(&w.g, &w.d).abs(), noise);
            let Some(acceptance) = accepted else {
                return Err(SolverError::LineSearch {
                    stats: Box::new(s.stats.clone()),
                });
            };
            // `definite_hold` full steps with the definite Hessian: try the exact one again.
            if definite && alpha == 1.0 {
                held += 1;
                if held >= p.definite_hold {
                    definite = false;
                    held = 0;
                }
            }
            std::mem::swap(&mut w.cur, &mut w.trial);
            f = s.eval(&w.cur, Request::ALL.with_definite(definite))?;
            noise = s.noise();
            self.free_gradient(s, &w.cur, &mut w.g);
            let gn = norm(&w.g);
            s.stats.gradient_norms.push(gn);
            let (step, largest) = self.step_size(w, alpha);
            s.stats.step_norms.push(step);
            if let Some(observe) = self.observer.as_mut() {
                observe(&IterationReport {
                    iteration: it + 1,
                    energy: f,
                    gradient_norm: gn,
                    step_norm: step,
                    step_length: alpha,
                    shift,
                    definite: step_definite,
                    accelerated,
                    largest_residual: largest_vertex(&self.reduced.dofs, &w.g),
                    stage: self.stage,
                });
            }
            let step_test = tests.trusted().then_some((step, largest));
            if p.single_iteration || p.converged(gn, g0, step_test) {
                return Ok(());
            }
            let short = tests.short(acceptance);
            if stall.stalled(short, gn) {
                return Err(SolverError::Stalled {
                    stats: Box::new(s.stats.clone()),
                });
            }
        }
        Err(SolverError::NotConverged {
            stats: Box::new(s.stats.clone()),
        })
    }

    /// The search direction `w.d` at `w.cur` (and its geodesic acceleration `w.a`, if it gets one): factors
    /// the Hessian in `self.values` ([`Newton::factor`]), solves `(H + σ) d = −∇F`, falls back to `−∇F` if
    /// that is not a descent direction, and corrects exact and shifted directions
    /// ([`NewtonParams::geodesic_acceleration`]). Returns what was factored.
    fn direction<O: Objective>(
        &mut self,
        s: &mut Solve<'_, O>,
        w: &mut Work,
        definite: bool,
        damping: f64,
        shift: &mut f64,
    ) -> Result<Factored, SolverError> {
        let factored = self.factor(s, &w.cur, definite, damping, shift)?;
        w.d.clear();
        w.d.extend(w.g.iter().map(|v| -v));
        let t = Instant::now();
        let r = self.solver.solve(&mut w.d);
        s.stats.solve_seconds += t.elapsed().as_secs_f64();
        r.map_err(|source| SolverError::Linear {
            source,
            stats: Box::new(s.stats.clone()),
        })?;
        if !(dot(&w.g, &w.d) < 0.0) {
            // Not a descent direction (possible with an indefinite backend): fall back to −g.
            w.d.clear();
            w.d.extend(w.g.iter().map(|v| -v));
        }
        w.a.clear();
        if s.params.geodesic_acceleration && !factored.definite && s.hessian_exact {
            self.accelerate(s, w, *shift);
        }
        Ok(factored)
    }

    /// The gradient of F over the free dofs (reduced order) into `g`.
    fn free_gradient<O>(&self, s: &Solve<'_, O>, y: &[Vector3<f64>], g: &mut Vec<f64>) {
        g.clear();
        g.extend(self.reduced.dofs.iter().map(|&d| {
            let mut v = s.out.gradient[d];
            if let Some(i) = s.inertia {
                let k = d / 3;
                v += i.masses[k] * (y[k][d % 3] - i.x_hat[k][d % 3]) / (i.dt * i.dt);
            }
            v
        }));
    }

    /// The reduced Hessian of F (the objective's, plus the inertia's `m/Δt²` on the diagonal) into
    /// `self.values`.
    fn assemble<O>(&mut self, s: &Solve<'_, O>) {
        for (v, &k) in self.values.iter_mut().zip(&self.reduced.source) {
            *v = s.out.hessian[k];
        }
        if let Some(i) = s.inertia {
            for (r, &dk) in self.reduced.diag.iter().enumerate() {
                self.values[dk] += i.masses[self.reduced.dofs[r] / 3] / (i.dt * i.dt);
            }
        }
    }

    /// Factors the reduced Hessian in `self.values` under the globalization:
    /// 1. as it is (exact, or definite when `definite`), plus `damping` on the diagonal;
    /// 2. with [`Globalization::ProjectOnDemand`], if the exact one is not positive definite: the objective's
    ///    definite Hessian at `y` ([`Request::definite`], re-evaluated, the Hessian only);
    /// 3. if that fails too (or with [`Globalization::ShiftedExact`]): a diagonal shift, starting near the last
    ///    one that worked (`shift`) and raised 4-fold until the factorization succeeds.
    ///
    /// Every attempt counts in [`NewtonStats::factorizations`].
    fn factor<O: Objective>(
        &mut self,
        s: &mut Solve<'_, O>,
        y: &[Vector3<f64>],
        mut definite: bool,
        damping: f64,
        shift: &mut f64,
    ) -> Result<Factored, SolverError> {
        let p = s.params;
        let last_shift = *shift;
        *shift = damping;
        let mut attempts = 0;
        loop {
            let diagonal = self
                .reduced
                .diag
                .iter()
                .map(|&k| self.values[k].abs())
                .fold(0.0, f64::max);
            // The shifts' scale. A zero diagonal leaves the largest entry; a zero matrix has no scale and no
            // Newton step (F is linear on the free dofs here, and the gradient is not zero).
            let max_diagonal = if diagonal > 0.0 {
                diagonal.max(f64::MIN_POSITIVE)
            } else {
                let largest = self.values.iter().fold(0.0, |m: f64, v| m.max(v.abs()));
                if !(largest > 0.0) {
                    return Err(SolverError::ZeroHessian {
                        stats: Box::new(s.stats.clone()),
                    });
                }
                largest
            };
            self.shifted.clone_from(&self.values);
            if *shift > 0.0 {
                for &k in &self.reduced.diag {
                    self.shifted[k] += *shift;
                }
            }
            let t = Instant::now();
            let r = self.solver.factor(&self.shifted);
            s.stats.factor_seconds += t.elapsed().as_secs_f64();
            s.stats.factorizations += 1;
            match r {
                // A shift far above the inertia's curvature: the shifted step would be nearly a gradient
                // step; the definite Hessian keeps each element's own curvature instead.
                Ok(()) if !definite && *shift > damping && *shift > s.definite_above => {
                    if p.remember_shift {
                        self.ladder_hint = *shift;
                    }
                    definite = true;
                    *shift = damping;
                    s.eval(y, DEFINITE_HESSIAN)?;
                    self.assemble(s);
                }
                Ok(()) => {
                    // Remember shifts the ladder found, not a Levenberg–Marquardt damping (which can be
                    // orders of magnitude larger, for one iteration's line search).
                    if *shift > damping && p.remember_shift {
                        self.ladder_hint = *shift;
                    }
                    return Ok(Factored {
                        definite,
                        max_diagonal,
                    });
                }
                Err(LinearError::NotPositiveDefinite { .. })
                    if !definite && p.globalization == Globalization::ProjectOnDemand =>
                {
                    definite = true;
                    s.eval(y, DEFINITE_HESSIAN)?;
                    self.assemble(s);
                }
                Err(LinearError::NotPositiveDefinite { .. }) if attempts < p.max_shifts => {
                    attempts += 1;
                    *shift = if *shift == 0.0 {
                        (p.initial_shift * max_diagonal)
                            .max(0.25 * last_shift)
                            .max(LADDER_HINT * self.ladder_hint)
                    } else {
                        *shift * 4.0
                    };
                    s.stats.max_shift = s.stats.max_shift.max(*shift);
                }
                Err(source) => {
                    return Err(SolverError::Linear {
                        source,
                        stats: Box::new(s.stats.clone()),
                    });
                }
            }
        }
    }

    /// Backtracking Armijo line search on F from `w.cur` along `w.d` (trial points in `w.trial`): the step
    /// length and how it was accepted, or `None` after [`NewtonParams::max_line_search`] halvings. `noise`
    /// is F's rounding allowance at `w.cur` (module documentation, Rounding).
    fn line_search<O: Objective>(
        &self,
        s: &mut Solve<'_, O>,
        w: &mut Work,
        f: f64,
        noise: f64,
        expand: bool,
    ) -> (f64, Option<Acceptance>) {
        let p = s.params;
        let slope = dot(&w.g, &w.d);
        // Geodesic acceleration: the corrected full step, if it lowers F by Armijo's fraction of the
        // decrease predicted along d (within any step bound); otherwise the plain search along d.
        if !w.a.is_empty() {
            self.place_trial(w, 1.0);
            if s.objective.max_step(&w.cur, &w.trial) >= 1.0
                && let Ok(ft) = s.eval(&w.trial, Request::VALUE)
                && ft.is_finite()
                && ft <= f + p.armijo * slope
            {
                let alpha = if expand { self.expand(s, w, ft) } else { 1.0 };
                return (alpha, Some(Acceptance::Decrease));
            }
            w.a.clear();
            s.stats.line_search_steps += 1;
        }
        // A barrier's bound on the move (continuous collision): start there instead of at the full step.
        self.place_trial(w, 1.0);
        let mut alpha = s.objective.max_step(&w.cur, &w.trial).clamp(0.0, 1.0);
        for _ in 0..=p.max_line_search {
            self.place_trial(w, alpha);
            let decrease = p.armijo * alpha * slope;
            // Near convergence the predicted decrease drops below the rounding of F: then accept any trial
            // that does not increase F beyond that rounding, instead of halving against noise.
            let target = if decrease.abs() <= noise {
                f + noise
            } else {
                f + decrease
            };
            if let Ok(ft) = s.eval(&w.trial, Request::VALUE)
                && ft.is_finite()
            {
                if ft <= f + decrease {
                    if expand && alpha == 1.0 {
                        return (self.expand(s, w, ft), Some(Acceptance::Decrease));
                    }
                    return (alpha, Some(Acceptance::Decrease));
                }
                // F's change is within its rounding band: its value cannot tell, its slope can.
                if ft <= target
                    || ((ft - f).abs() <= ROUNDING_BAND * noise && self.slope_accepts(s, w, slope))
                {
                    return (alpha, Some(Acceptance::WithinRounding));
                }
            }
            alpha *= 0.5;
            s.stats.line_search_steps += 1;
        }
        (alpha, None)
    }

    /// The derivative form of the Armijo test at `w.trial` (module documentation, Rounding): the slope of F
    /// along `w.d` there is at most `(1 − 2c)` times the magnitude of the slope `slope` at `w.cur` (for F
    /// quadratic along the line, the same test as Armijo's with constant `c`). One gradient evaluation.
    fn slope_accepts<O: Objective>(&self, s: &mut Solve<'_, O>, w: &mut Work, slope: f64) -> bool {
        if s.eval(&w.trial, Request::GRADIENT).is_err() {
            return false;
        }
        let mut gt = std::mem::take(&mut w.gt);
        self.free_gradient(s, &w.trial, &mut gt);
        let trial_slope = dot(&gt, &w.d);
        w.gt = gt;
        trial_slope.is_finite() && trial_slope <= (1.0 - 2.0 * s.params.armijo) * slope.abs()
    }

    /// After a full shifted or definite step with F = `f1`: doubles the step while F keeps decreasing
    /// (escaping a saddle along a negative-curvature direction; module documentation, Extrapolation),
    /// leaving the best trial in `w.trial`. Returns its step length.
    fn expand<O: Objective>(&self, s: &mut Solve<'_, O>, w: &mut Work, f1: f64) -> f64 {
        let (mut best_alpha, mut best) = (1.0, f1);
        let mut alpha = 2.0;
        for _ in 0..12 {
            self.place_trial(w, alpha);
            if s.objective.max_step(&w.cur, &w.trial) < 1.0 {
                break;
            }
            s.stats.line_search_steps += 1;
            match s.eval(&w.trial, Request::VALUE) {
                Ok(ft) if ft.is_finite() && ft < best => {
                    best = ft;
                    best_alpha = alpha;
                    alpha *= 2.0;
                }
                _ => break,
            }
        }
        self.place_trial(w, best_alpha);
        best_alpha
    }

    /// `w.trial = w.cur + alpha · w.d + alpha²/2 · w.a` on the free dofs (pinned entries keep `w.cur`'s
    /// values; `w.a` is empty unless a geodesic acceleration is being tried).
    fn place_trial(&self, w: &mut Work, alpha: f64) {
        if w.a.is_empty() {
            for (k, &dof) in self.reduced.dofs.iter().enumerate() {
                w.trial[dof / 3][dof % 3] = w.cur[dof / 3][dof % 3] + alpha * w.d[k];
            }
        } else {
            let half = 0.5 * alpha * alpha;
            for (k, &dof) in self.reduced.dofs.iter().enumerate() {
                w.trial[dof / 3][dof % 3] =
                    w.cur[dof / 3][dof % 3] + alpha * w.d[k] + half * w.a[k];
            }
        }
    }

    /// The norm and the largest vertex displacement of the step [`Newton::place_trial`] places at
    /// `alpha` (uses `w.gt` as scratch when the step carries an acceleration).
    fn step_size(&self, w: &mut Work, alpha: f64) -> (f64, f64) {
        if w.a.is_empty() {
            return (
                alpha * norm(&w.d),
                alpha * largest_vertex(&self.reduced.dofs, &w.d).map_or(0.0, |l| l.1),
            );
        }
        let half = 0.5 * alpha * alpha;
        w.gt.clear();
        w.gt.extend(w.d.iter().zip(&w.a).map(|(d, a)| alpha * d + half * a));
        let largest = largest_vertex(&self.reduced.dofs, &w.gt).map_or(0.0, |l| l.1);
        (norm(&w.gt), largest)
    }

    /// Geodesic acceleration of the direction `w.d` into `w.a` (module documentation, Geodesic
    /// acceleration): `(H + σ) a = −∇³F[d, d]` with the matrix `self.solver` holds (the exact Hessian plus
    /// the shift `shift`), the third-derivative term from the gradient at `x + h d`:
    /// `∇³F[d, d] ≈ 2/h² (∇F(x + h d) − ∇F(x) − h H d)`, where `H d = −∇F(x) − σ d` by construction of `d`.
    /// `w.a` stays empty when the move `h d` is within the positions' rounding
    /// ([`ACCELERATION_RESOLUTION`]), when that point cannot be evaluated or lies beyond the objective's
    /// step bound, or when the acceleration is not small against `d` (`‖a‖ > ACCELERATION_RATIO ‖d‖`: the local
    /// quadratic-plus-cubic model does not hold there). One gradient evaluation and one triangular solve.
    fn accelerate<O: Objective>(&mut self, s: &mut Solve<'_, O>, w: &mut Work, shift: f64) {
        let h = ACCELERATION_STEP;
        // The difference quotient needs a move well above the positions' rounding: near a solution the
        // exact Newton step converges quadratically anyway, and a correction of rounding noise would spoil
        // it.
        let (mut reach, mut size) = (0.0_f64, 0.0_f64);
        for (k, &dof) in self.reduced.dofs.iter().enumerate() {
            reach = reach.max(w.d[k].abs());
            size = size.max(w.cur[dof / 3][dof % 3].abs());
        }
        if !(h * reach > ACCELERATION_RESOLUTION * size) {
            return;
        }
        self.place_trial(w, h);
        if s.objective.max_step(&w.cur, &w.trial) < 1.0
            || s.eval(&w.trial, Request::GRADIENT).is_err()
        {
            return;
        }
        let mut gh = std::mem::take(&mut w.gt);
        self.free_gradient(s, &w.trial, &mut gh);
        let c = 2.0 / (h * h);
        w.a.extend(
            gh.iter()
                .zip(&w.g)
                .zip(&w.d)
                .map(|((&gh, &g), &d)| -c * (gh - g + h * (g + shift * d))),
        );
        w.gt = gh;
        let t = Instant::now();
        let solved = self.solver.solve(&mut w.a);
        s.stats.solve_seconds += t.elapsed().as_secs_f64();
        let a = norm(&w.a);
        if solved.is_err() || !a.is_finite() || a > ACCELERATION_RATIO * norm(&w.d) {
            w.a.clear();
        }
    }
}

/// The definite Hessian alone (energy and gradient are already known), for project on demand.
const DEFINITE_HESSIAN: Request = Request {
    value: false,
    gradient: false,
    hessian: true,
    definite: true,
};

/// One solve's borrowed inputs and outputs, shared by the pieces of [`Newton::minimize`].
struct Solve<'a, O> {
    objective: &'a mut O,
    inertia: Option<&'a Inertia>,
    params: &'a NewtonParams,
    stats: &'a mut NewtonStats,
    out: &'a mut SystemEvaluation,
    /// The scale of F's rounding at the last evaluated point: `Σ |term energy| + inertia energy` (at least
    /// |F|; Rounding).
    magnitude: f64,
    /// A ladder shift above this switches the iteration to the definite Hessian
    /// ([`NewtonParams::definite_shift_ratio`] times the largest free inertia diagonal entry; ∞: never).
    definite_above: f64,
    /// [`Objective::hessian_is_exact`], asked once per solve: whether an undamped, unshifted direction that
    /// is not the definite Hessian's is an exact Newton step (the step tests trust it; geodesic
    /// acceleration corrects only exact and shifted directions of the exact Hessian).
    hessian_exact: bool,
}

impl<O: Objective> Solve<'_, O> {
    /// F at `y`: the objective (evaluated into `out` as `request` asks) plus the inertia energy.
    fn eval(&mut self, y: &[Vector3<f64>], request: Request) -> Result<f64, SolverError> {
        let t = Instant::now();
        let r = self.objective.evaluate(y, request, self.out);
        self.stats.eval_seconds += t.elapsed().as_secs_f64();
        r.map_err(|source| SolverError::Eval {
            source,
            stats: Box::new(self.stats.clone()),
        })?;
        let kinetic = self.inertia.map_or(0.0, |i| {
            y.iter()
                .zip(&i.x_hat)
                .zip(&i.masses)
                .map(|((a, b), m)| m * (a - b).norm_squared())
                .sum::<f64>()
                / (2.0 * i.dt * i.dt)
        });
        let f = self.out.energy + kinetic;
        let terms: f64 = self.out.terms.iter().map(|e| e.abs()).sum();
        self.magnitude = (terms + kinetic).max(f.abs()).max(f64::MIN_POSITIVE);
        Ok(f)
    }

    /// The rounding allowance of F at the last evaluated point (Rounding): `8ε` times its magnitude.
    fn noise(&self) -> f64 {
        8.0 * f64::EPSILON * self.magnitude
    }
}

/// What [`Newton::factor`] factored.
struct Factored {
    /// The definite Hessian (not the exact one).
    definite: bool,
    /// The largest |diagonal| of the unshifted matrix (the scale of the shifts).
    max_diagonal: f64,
}

/// How the line search accepted a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Acceptance {
    /// F decreased by Armijo's fraction of the predicted decrease.
    Decrease,
    /// F's change is within its rounding (module documentation, Rounding): accepted on F's rounding
    /// allowance or on the slope test. Such steps count towards [`STALL_ITERATIONS`].
    WithinRounding,
}

/// What the stopping tests may conclude from an accepted step (module documentation, Stopping).
#[derive(Debug, Clone, Copy)]
struct StepTests {
    /// A full step along the direction of the exact, unshifted Newton system.
    newton_step: bool,
    /// The exact direction's predicted decrease `|∇F · d|` is below F's rounding.
    at_rounding_floor: bool,
    /// A full Newton step predicted to change F by less than [`ROUNDING_BAND`] rounding allowances.
    in_rounding_band: bool,
    /// The step `alpha · d` was predicted to change F by less than its rounding.
    below_rounding: bool,
    /// The step length.
    alpha: f64,
}

impl StepTests {
    /// The tests of a step of length `alpha` along a direction factored with `shift` from a Hessian that is
    /// `inexact` (the definite one, or one with a term's Gauss–Newton or projected Hessian) or not, whose
    /// predicted decrease is `predicted` = |∇F · d|; `noise` is F's rounding allowance.
    fn new(inexact: bool, shift: f64, alpha: f64, predicted: f64, noise: f64) -> Self {
        let exact_direction = !inexact && shift == 0.0;
        let newton_step = exact_direction && alpha == 1.0;
        Self {
            newton_step,
            // Only the exact Newton direction's predicted decrease measures how far F can still fall: a
            // shifted or damped one is short because of the shift.
            at_rounding_floor: exact_direction && predicted <= noise,
            in_rounding_band: newton_step && predicted <= ROUNDING_BAND * noise,
            below_rounding: alpha * predicted <= noise,
            alpha,
        }
    }

    /// Whether the step tests (relative step, mesh-size step) may judge convergence by this step: a full
    /// step of the exact Newton system, or an exact Newton direction whose predicted decrease is below F's
    /// rounding. A shifted or definite direction's predicted decrease is small because of its shift (a
    /// triangle collapsing on a public mesh, `spot`, drove the shift to 5e12 and ended a step on a
    /// 6e-15 m step with ‖∇F‖ = 4e3 N before this rule asked for the exact direction).
    fn trusted(&self) -> bool {
        self.newton_step || self.at_rounding_floor
    }

    /// Whether the step counts towards [`STALL_ITERATIONS`]: shorter than [`STALL_STEP`], accepted within
    /// F's rounding, a Newton step within the rounding band, or any step predicted to change F by less
    /// than its rounding (a shifted step that Armijo's test accepts because F did not change at all).
    fn short(&self, acceptance: Acceptance) -> bool {
        self.alpha < STALL_STEP
            || acceptance == Acceptance::WithinRounding
            || self.in_rounding_band
            || self.below_rounding
    }
}

/// Stall detection (module documentation, Stopping): the smallest gradient norm so far, and the short
/// steps since it last fell by a tenth.
#[derive(Debug, Clone, Copy)]
struct Stall {
    best: f64,
    short_steps: usize,
}

impl Stall {
    /// Records an accepted step (`short` as [`StepTests::short`]) that reached gradient norm `gn`; true
    /// once [`STALL_ITERATIONS`] short steps in a row have not lowered the best gradient norm by a tenth.
    fn stalled(&mut self, short: bool, gn: f64) -> bool {
        self.short_steps = if short && gn > 0.9 * self.best {
            self.short_steps + 1
        } else {
            0
        };
        self.best = self.best.min(gn);
        self.short_steps >= STALL_ITERATIONS
    }
}

/// A trial whose F differs from the current F by at most this many rounding allowances (`8ε Σ|term|`)
/// is judged by the slope test instead of by F, and a full exact Newton step whose predicted decrease is
/// below this many allowances counts towards [`STALL_ITERATIONS`] (module documentation, Rounding).
pub const ROUNDING_BAND: f64 = 128.0;

/// Where the shift ladder starts relative to the last shift that factored
/// ([`NewtonParams::remember_shift`]).
const LADDER_HINT: f64 = 0.25;

/// The finite-difference step `h` (a fraction of the Newton direction) of the geodesic acceleration's
/// third-derivative term ([`NewtonParams::geodesic_acceleration`]): Transtrum & Sethna's choice.
/// Measured on the drape over `docs/newton/ensemble.sh`'s five starts (a prototype that searched along
/// the curve `α d + α²/2 a`, without [`ACCELERATION_RESOLUTION`]): h = 0.1 gives 611–615 iterations, 0.2 and 0.05 are bimodal
/// (637–1 047, 732–985), 0.03 gives 747–983; h = 1 (the gradient at the full step) 583–745; a central
/// difference at 0.1 / 0.3, two extra gradients, 636–750 / 620–633 (module documentation, Geodesic
/// acceleration).
pub const ACCELERATION_STEP: f64 = 0.1;

/// The largest ‖a‖ / ‖d‖ of a geodesic acceleration that is tried (Transtrum & Sethna bound the ratio
/// of the step's second-order to first-order part; measured with the same prototype on the drape's five
/// starts: 0.75 → 611–615, 1.0 → 603–620, 0.5 → 710–1 016, 1.5 → 1 071 on one start).
pub const ACCELERATION_RATIO: f64 = 0.75;

/// The smallest move of the geodesic acceleration's difference quotient, `h ‖d‖_∞`, relative to the
/// largest free coordinate ([`NewtonParams::geodesic_acceleration`]). The positions' rounding `ε |x|`
/// perturbs the quotient's second difference by about `ε / 1e-12 ≈ 2e-4` of its size at this bound (the third
/// derivative taken at the scale of the coordinates). Without a bound, corrections of rounding noise
/// stopped the damped `beam5` run (frame 122, a step "stuck" at ‖∇F‖ = 8e-6 N) and a stiff static strip
/// at 3.4e-8 N instead of below 1e-8 N; drape over the five starts: ε^(1/3) 632–640 iterations, 1e-6
/// 612–617, 1e-7 610–615 (no bound 609–617).
pub const ACCELERATION_RESOLUTION: f64 = 1e-6;

/// Accepted steps in a row that may stay shorter than [`STALL_STEP`] of the Newton direction (or within F's
/// rounding, module documentation, Rounding) without
/// lowering the smallest gradient norm so far by a tenth before a solve stops as [`SolverError::Stalled`].
pub const STALL_ITERATIONS: usize = 10;

/// The step length (a fraction of the Newton direction) below which an accepted step counts towards
/// [`STALL_ITERATIONS`].
pub const STALL_STEP: f64 = 1e-6;

/// Work vectors of [`Newton::minimize`], kept between solves.
#[derive(Debug, Clone, Default)]
struct Work {
    cur: Vec<Vector3<f64>>,
    trial: Vec<Vector3<f64>>,
    g: Vec<f64>,
    /// The free gradient at a trial point (the line search's slope test).
    gt: Vec<f64>,
    d: Vec<f64>,
    /// The geodesic acceleration of `d` while it is tried (empty otherwise).
    a: Vec<f64>,
}

/// The Euclidean norm; when the sum of squares overflows (entries beyond ~1e154, say a gradient under an
/// absurd load) it is taken again scaled by the largest entry, so a finite vector has a finite norm (the
/// common case is the one plain pass, bitwise as before).
pub(crate) fn norm(v: &[f64]) -> f64 {
    let squares = v.iter().map(|a| a * a).sum::<f64>();
    if squares.is_finite() {
        return squares.sqrt();
    }
    let largest = v.iter().fold(0.0_f64, |m, a| m.max(a.abs()));
    if !(largest.is_finite() && largest > 0.0) {
        return squares.sqrt();
    }
    largest
        * v.iter()
            .map(|a| (a / largest) * (a / largest))
            .sum::<f64>()
            .sqrt()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The vertex whose entries of the reduced vector `d` (a step, a gradient; dofs grouped by vertex, in
/// increasing order) have the largest Euclidean norm, and that norm (finite for finite entries: a norm whose
/// sum of squares overflows is taken again scaled, as [`norm`] does); the first such vertex on a tie, and
/// `None` for an empty `d` (or one of NaN entries only).
fn largest_vertex(dofs: &[usize], d: &[f64]) -> Option<(usize, f64)> {
    let mut largest: Option<(usize, f64)> = None;
    let mut start = 0;
    while start < dofs.len().min(d.len()) {
        let vertex = dofs[start] / 3;
        let mut end = start + 1;
        while end < dofs.len().min(d.len()) && dofs[end] / 3 == vertex {
            end += 1;
        }
        let size = norm(&d[start..end]);
        if !size.is_nan() && largest.is_none_or(|(_, l)| size > l) {
            largest = Some((vertex, size));
        }
        start = end;
    }
    largest
}

/// Places `system` at `time` ([`System::set_time`]) for a stepper's `set_time`.
///
/// # Errors
/// [`SolverError::Input`] for a non-finite time; the system's error as [`SolverError::Eval`].
pub(crate) fn place_at(system: &mut System, time: f64) -> Result<(), SolverError> {
    if !time.is_finite() {
        return Err(SolverError::Input(format!("time {time} is not finite")));
    }
    system.set_time(time).map_err(|source| SolverError::Eval {
        source,
        stats: Box::default(),
    })
}

/// Implicit Euler time stepping on a [`System`] with lumped masses and pins.
pub struct ImplicitEuler {
    /// The time step.
    pub dt: f64,
    /// Lumped masses.
    pub masses: Vec<f64>,
    newton: Newton,
    pins: Pins,
    /// The start positions and step of the last accepted step: the system's step state (damping's θ_prev,
    /// drag's previous positions) is set back to them when an attempt fails.
    committed: Option<(Vec<Vector3<f64>>, f64)>,
    /// The time of the current state (s): the system's moving parts are placed at it between steps.
    time: f64,
    /// Called after every accepted (sub)step of [`ImplicitEuler::advance_with`].
    substep_observer: Option<SubstepObserver>,
}

impl std::fmt::Debug for ImplicitEuler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ImplicitEuler")
            .field("dt", &self.dt)
            .field("newton", &self.newton)
            .finish()
    }
}

impl ImplicitEuler {
    /// A stepper for `system` with step `dt`, masses `masses`, pinned vertices `pins`.
    ///
    /// # Errors
    /// [`SolverError::Input`] for a non-positive `dt`, masses of the wrong length or a mass that is negative
    /// or not finite (naming its vertex); analysis errors.
    pub fn new(
        system: &System,
        dt: f64,
        masses: Vec<f64>,
        pins: Pins,
        solver: Box<dyn LinearSolver>,
        params: NewtonParams,
    ) -> Result<Self, SolverError> {
        if !(dt > 0.0 && dt.is_finite()) || masses.len() != system.n_vertices() {
            return Err(SolverError::Input(format!(
                "dt = {dt} must be positive; {} masses for {} vertices",
                masses.len(),
                system.n_vertices()
            )));
        }
        if let Some((i, m)) = masses
            .iter()
            .enumerate()
            .find(|(_, m)| !(**m >= 0.0 && m.is_finite()))
        {
            return Err(SolverError::Input(format!(
                "vertex {i}: mass {m} must be non-negative and finite"
            )));
        }
        let newton = Newton::new(system, &pins, solver, params)?;
        Ok(Self {
            dt,
            masses,
            newton,
            pins,
            committed: None,
            time: 0.0,
            substep_observer: None,
        })
    }

    /// A callback called after every accepted (sub)step of [`ImplicitEuler::advance`] and
    /// [`ImplicitEuler::advance_with`] with the positions and time it ends at: the path a frame took
    /// through its substeps (a frame that fails after some were accepted sets its state back, and those
    /// calls were made all the same). It cannot change the steps. `None` removes it.
    pub fn set_substep_observer(&mut self, observer: Option<SubstepObserver>) {
        self.substep_observer = observer;
    }

    /// Checks that every position and velocity coordinate is finite (what every step checks first).
    ///
    /// # Errors
    /// [`SolverError::Input`] naming the first vertex with a coordinate that is not, in the slices'
    /// numbering.
    pub fn check_state(x: &[Vector3<f64>], v: &[Vector3<f64>]) -> Result<(), SolverError> {
        for (what, list) in [("position", x), ("velocity", v)] {
            for (i, p) in list.iter().enumerate() {
                if let Some(c) = (0..3).find(|&c| !p[c].is_finite()) {
                    return Err(SolverError::Input(format!(
                        "vertex {i}: {what} coordinate {c} is not finite ({})",
                        p[c]
                    )));
                }
            }
        }
        Ok(())
    }

    /// The time (s) of the state the stepper last accepted (0 for a new stepper; see
    /// [`ImplicitEuler::set_time`]). Every step is solved with the system placed at the step's end time
    /// ([`System::set_time`]: moving obstacles).
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Sets the time of the current state (a restart, or a stepper built mid-run) and places the system
    /// there.
    ///
    /// # Errors
    /// [`SolverError::Input`] for a non-finite time; the system's error (nothing changed then).
    pub fn set_time(&mut self, system: &mut System, time: f64) -> Result<(), SolverError> {
        place_at(system, time)?;
        self.time = time;
        Ok(())
    }

    /// The Newton solver (for statistics).
    pub fn newton(&self) -> &Newton {
        &self.newton
    }

    /// The Newton solver, to change its parameters between steps.
    pub fn newton_mut(&mut self) -> &mut Newton {
        &mut self.newton
    }

    /// One step of [`ImplicitEuler::dt`]: minimises the incremental potential from `x̂ = x + Δt v` (pinned
    /// vertices stay put and keep zero velocity; when the energies cannot be evaluated at `x̂` — a hinge of a
    /// tan energy carried through its pole, a vertex onto a sphere's centre — from `x` instead, the counts
    /// of both attempts summed), ends the step for the energies at the new positions
    /// ([`System::end_step`]: plastic rest angles), then sets `v = (x_new − x)/Δt`. On failure `x` and `v` are
    /// unchanged, and the system's step state (damping's θ_prev, drag's previous positions) is set back to
    /// that of the last accepted step (before any step was accepted, it stays as set for this attempt's
    /// start, which is what a retry sets again).
    ///
    /// # Errors
    /// [`SolverError`] with diagnostics.
    pub fn step(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        v: &mut [Vector3<f64>],
    ) -> Result<NewtonStats, SolverError> {
        self.step_dt(system, x, v, self.dt, self.time + self.dt, None)
    }

    /// One step of size `dt` ending at time `t_end` (see [`ImplicitEuler::step`]).
    fn step_dt(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        v: &mut [Vector3<f64>],
        dt: f64,
        t_end: f64,
        targets: Option<&[Vector3<f64>]>,
    ) -> Result<NewtonStats, SolverError> {
        let n = system.n_vertices();
        if x.len() != n || v.len() != n {
            return Err(SolverError::Input(format!(
                "{} positions and {} velocities for {n} vertices",
                x.len(),
                v.len()
            )));
        }
        Self::check_state(x, v)?;
        let mut x_hat: Vec<Vector3<f64>> =
            x.iter().zip(v.iter()).map(|(p, w)| p + w * dt).collect();
        for &pv in self.pins.vertices() {
            x_hat[pv] = targets.map_or(x[pv], |t| t[pv]);
        }
        let result = system
            .set_time(t_end)
            .and_then(|()| system.begin_step(x, dt))
            .map_err(|source| SolverError::Eval {
                source,
                stats: Box::default(),
            })
            .and_then(|()| {
                // The start (Step bounds, module documentation): x̂, or as far towards it as a barrier
                // admits from x, with vertices a moving obstacle carries moved along with it. `start`
                // holds where the move begins (x, carried) until it becomes the start.
                let mut start = x.to_vec();
                let carried = system.carry(t_end - dt, &mut start);
                let bound = system.max_step(&start, &x_hat);
                if bound < 1.0 || carried {
                    for (s, h) in start.iter_mut().zip(&x_hat) {
                        *s += (h - *s) * bound;
                    }
                    for &pv in self.pins.vertices() {
                        start[pv] = x_hat[pv];
                    }
                } else {
                    start.copy_from_slice(&x_hat);
                }
                let inertia = Inertia {
                    masses: self.masses.clone(),
                    x_hat: x_hat.clone(),
                    dt,
                };
                let mut next = start;
                match self
                    .newton
                    .minimize(system, &mut next, Some(&inertia))
                    .and_then(|stats| self.unstuck(stats, &next))
                {
                    Ok(stats) => Ok((next, stats)),
                    // x̂ itself cannot be evaluated (a hinge carried through the pole of a tan energy, a
                    // vertex onto a sphere's centre): the same step from x, which the last step accepted
                    // (pinned vertices at their targets), before giving up on this step size.
                    Err(SolverError::Eval { stats: first, .. }) if first.iterations == 0 => {
                        let mut start = x.to_vec();
                        for &pv in self.pins.vertices() {
                            start[pv] = targets.map_or(x[pv], |t| t[pv]);
                        }
                        let mut stats = self.newton.minimize(system, &mut start, Some(&inertia))?;
                        stats.absorb_counts(&first);
                        let stats = self.unstuck(stats, &start)?;
                        Ok((start, stats))
                    }
                    Err(e) => Err(e),
                }
            });
        // An accepted step ends for the energies (plastic rest angles follow it); a rejected one never does.
        let result = result.and_then(|(next, stats)| match system.end_step(&next) {
            Ok(()) => Ok((next, stats)),
            Err(source) => Err(SolverError::Eval {
                source,
                stats: Box::new(stats),
            }),
        });
        match result {
            Ok((next, stats)) => {
                self.committed = Some((x.to_vec(), dt));
                self.time = t_end;
                for i in 0..n {
                    v[i] = (next[i] - x[i]) / dt;
                    x[i] = next[i];
                }
                Ok(stats)
            }
            Err(e) => {
                self.restore_step_state(system);
                Err(e)
            }
        }
    }

    /// A solve's statistics unless it got stuck: it ended on a step test with ‖∇F‖ above the gradient
    /// tests ([`NewtonParams::converged`] without a step) and above √ε times its start's (a solve at its
    /// rounding floor has lowered it by more: tight tolerances end there, 7.4 → 9.4e-13 N), and a last
    /// step that moved no coordinate of `x` by more than a few units in the last place
    /// (`‖Δx‖ ≤ 4ε · max |x|`). Such an iterate cannot move, and it is not the step's solution: on a lumpy closed shell dropped on a plane
    /// (`docs/shells/closed_meshes.py`, frame 28) a triangle collapsed to an altitude of 1e-14 m, Newton's
    /// steps shrank to 1e-18 m with ‖∇F‖ = 3.3e5 N, and the frame was accepted. That solve is now a failed
    /// step, [`SolverError::Stuck`], which [`ImplicitEuler::advance`] retries with smaller substeps. So is
    /// a solve that ends on a step test with ‖∇F‖ more than ten times its start's, however far its last
    /// step moved: it has solved nothing. Steps that end on a step test above the tolerance while they
    /// still move and have not raised ‖∇F‖ tenfold (a stiff beam whose gradient floors at rounding, 2.5e-9 N
    /// against 1e-9, whose solves started at that floor end a little above or below it) are accepted as
    /// before.
    fn unstuck(&self, stats: NewtonStats, x: &[Vector3<f64>]) -> Result<NewtonStats, SolverError> {
        if stuck(&self.newton.params, &stats, x) {
            Err(SolverError::Stuck {
                stats: Box::new(stats),
            })
        } else {
            Ok(stats)
        }
    }

    /// Sets the system's step state back to the last accepted step's, and its moving parts to the current
    /// time.
    fn restore_step_state(&self, system: &mut System) {
        if let Some((xp, dtp)) = &self.committed {
            // The same call succeeded when that step was accepted, on the same positions.
            let _ = system.begin_step(xp, *dtp);
        }
        // The time is finite (set by `set_time` or by an accepted step), so placing succeeds.
        let _ = system.set_time(self.time);
    }

    /// Advances by one frame of [`ImplicitEuler::dt`], splitting it into substeps when a step fails (see
    /// [`SubstepPolicy`]): a failed attempt is retried from the same state with half the substep, an
    /// accepted one lets the next grow back (doubling, aligned so that the substeps tile the frame
    /// exactly). Step state is committed per accepted substep only. Below the floor the frame fails: `x` and
    /// `v` are then those of the frame's start, and so are the Newton solver's shift memory
    /// ([`NewtonParams::remember_shift`]) and the system's step state (if no step was ever
    /// accepted, it stays as set for the last attempt's start, which is what a retry sets again), including
    /// what the accepted substeps' ends changed ([`System::rewind_step_state`]: plastic rest angles). Every
    /// substep is solved with the system's moving parts at the substep's end time ([`System::set_time`]);
    /// a failed frame leaves [`ImplicitEuler::time`] and the system at the frame's start, an accepted one
    /// advances the time by `dt`.
    ///
    /// # Errors
    /// The last attempt's [`SolverError`] when a substep of `dt / 2^max_halvings` fails too;
    /// [`SolverError::Input`] and [`SolverError::Interrupted`] (the Newton solver's stop flag,
    /// [`Newton::set_stop`]) at once, without smaller substeps. The frame's state is restored either way.
    /// The interruption's statistics are the whole frame's (every attempt's, the undone accepted substeps'
    /// included: the work spent on it); the other errors' are the last attempt's.
    pub fn advance(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        v: &mut [Vector3<f64>],
        policy: SubstepPolicy,
    ) -> Result<FrameStats, SolverError> {
        self.advance_with(system, x, v, policy, None)
    }

    /// [`ImplicitEuler::advance`] with pinned vertices that move: every (sub)step ends with each pinned
    /// vertex at `motion`'s target for the substep's end (as a fraction of the frame, in (0, 1]), so the
    /// pins reach the frame's targets at its end whether or not it took substeps. Pinned vertices the motion
    /// does not write stay where they are.
    ///
    /// # Errors
    /// As [`ImplicitEuler::advance`].
    pub fn advance_with(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        v: &mut [Vector3<f64>],
        policy: SubstepPolicy,
        motion: Option<&dyn PinMotion>,
    ) -> Result<FrameStats, SolverError> {
        let levels = policy.max_halvings.min(30);
        let total: u64 = 1 << levels;
        let (x0, v0) = (x.to_vec(), v.to_vec());
        let committed0 = self.committed.clone();
        let time0 = self.time;
        // The shift memory, which accepted substeps move: a failed frame sets it back with the rest.
        let hint0 = self.newton.shift_memory();
        // Accepted substeps end (plastic rest angles move); a frame that fails after some sets that back.
        system.mark_step_state();
        let mut fs = FrameStats {
            smallest_fraction: 1.0,
            ..FrameStats::default()
        };
        let (mut t, mut level) = (0u64, 0u32);
        while t < total {
            let h = total >> level;
            let dt = self.dt * (h as f64 / total as f64);
            let mut targets = None;
            if let Some(m) = motion {
                let mut t_end = x.to_vec();
                m.targets((t + h) as f64 / total as f64, &mut t_end);
                targets = Some(t_end);
            }
            let t_end = time0 + self.dt * ((t + h) as f64 / total as f64);
            match self.step_dt(system, x, v, dt, t_end, targets.as_deref()) {
                Ok(s) => {
                    fs.newton.absorb(&s);
                    fs.substeps += 1;
                    fs.smallest_fraction = fs.smallest_fraction.min(h as f64 / total as f64);
                    let g = s.gradient_norms.last().copied().unwrap_or(0.0);
                    fs.max_final_gradient_norm = fs.max_final_gradient_norm.max(g);
                    if let Some(o) = &mut self.substep_observer {
                        o(x, t_end);
                    }
                    t += h;
                    // Grow back when the next, doubled substep starts on its own grid.
                    if level > 0 && t % (total >> (level - 1)) == 0 {
                        level -= 1;
                    }
                }
                Err(e) => {
                    fs.newton.absorb(&e.stats());
                    // Smaller substeps cannot help inputs that do not fit, and must not outlast a stop request.
                    if level >= levels
                        || matches!(e, SolverError::Input(_) | SolverError::Interrupted { .. })
                    {
                        x.copy_from_slice(&x0);
                        v.copy_from_slice(&v0);
                        self.committed = committed0;
                        self.time = time0;
                        self.newton.set_shift_memory(hint0);
                        self.restore_step_state(system);
                        // The marked state was the energies' own a frame ago: rewinding to it succeeds.
                        let _ = system.rewind_step_state();
                        // A stop request reports the whole frame's work (its accepted substeps were
                        // undone, but their iterations were spent); other errors the last attempt's.
                        if matches!(e, SolverError::Interrupted { .. }) {
                            return Err(SolverError::Interrupted {
                                stats: Box::new(fs.newton),
                            });
                        }
                        return Err(e);
                    }
                    fs.failed_attempts += 1;
                    level += 1;
                }
            }
        }
        Ok(fs)
    }
}

/// The test of [`ImplicitEuler::unstuck`]: a solve (`stats`, ending at `x`) that is not converged by the
/// gradient tests, has not lowered ‖∇F‖ below √ε of its start's, and either ended with ‖∇F‖ more than ten
/// times its start's or on a last step that moved no coordinate by more than 4 ulps.
fn stuck(p: &NewtonParams, stats: &NewtonStats, x: &[Vector3<f64>]) -> bool {
    let first = stats.gradient_norms.first().copied().unwrap_or(0.0);
    let last = stats.gradient_norms.last().copied().unwrap_or(0.0);
    let step = stats.step_norms.last().copied().unwrap_or(f64::INFINITY);
    let size = x.iter().map(|p| p.amax()).fold(0.0, f64::max);
    // Ten times its start's: a solve that starts at its gradient's rounding floor (a settled stiff strip
    // asked for less) ends a little above or below where it started, and stays accepted.
    let solved_nothing = last > 10.0 * first;
    !(p.single_iteration
        || p.converged(last, first, None)
        || last <= f64::EPSILON.sqrt() * first
        || (step > 4.0 * f64::EPSILON * size && !solved_nothing))
}

#[cfg(test)]
mod tests {
    use super::norm;

    #[test]
    fn ceiling_text_prints_the_ceiling() {
        use super::{MAX_ITERATIONS_CEILING, MAX_ITERATIONS_CEILING_TEXT};
        let groups: Vec<&str> = MAX_ITERATIONS_CEILING_TEXT.split(' ').collect();
        assert!(
            (1..=3).contains(&groups[0].len()),
            "{MAX_ITERATIONS_CEILING_TEXT}"
        );
        assert!(
            groups[1..].iter().all(|g| g.len() == 3),
            "{MAX_ITERATIONS_CEILING_TEXT}"
        );
        assert_eq!(groups.concat().parse::<usize>(), Ok(MAX_ITERATIONS_CEILING));
    }

    /// The stuck test on the solves that motivated it and on those it must leave alone (their recorded
    /// gradient and step norms): the lumpy shell's frame 28 (stuck), a plastic hinge and a spring cloth
    /// solved to their rounding floor with tight tolerances, a stiff beam's step test on a step that moves.
    #[test]
    fn only_a_solve_that_cannot_move_and_has_not_converged_is_stuck() {
        use super::{NewtonParams, NewtonStats, Vector3, stuck};
        let x = vec![Vector3::new(0.3, -0.7, 1.0); 4];
        let solve = |g: &[f64], s: &[f64]| NewtonStats {
            iterations: s.len(),
            gradient_norms: g.to_vec(),
            step_norms: s.to_vec(),
            ..NewtonStats::default()
        };
        let p = NewtonParams {
            gradient_tolerance: 1e-6,
            ..NewtonParams::default()
        };
        let lumpy = solve(
            &[9.9e5, 324158.6, 1841.3, 334893.6],
            &[1e-9, 2.3e-15, 5.5e-18],
        );
        assert!(stuck(&p, &lumpy, &x));
        // The same gradients, but the last step still moves: a step test there is left to Newton.
        assert!(!stuck(&p, &solve(&[9.9e5, 3.3e5], &[1e-13]), &x));
        // A public closed mesh (`spot`, dropped like `shell-drop`), frame 17 at dt/4: the shift climbed to
        // 5e12 while a triangle collapsed, steps of 6e-15 m (about 50 ulps of its coordinates) moved it, and
        // ‖∇F‖ rose from 1.4 to 4e3 N. It solved nothing, so it is stuck although it still moves; the same
        // solve ending at ‖∇F‖ below ten times its start's is left to Newton, as is a solve that starts at
        // its rounding floor (a settled stiff strip asked for 1e-9 N) and ends a little above it.
        let spot = solve(
            &[1.376, 0.2227, 5.423, 8.415e2, 3.953e3],
            &[5.5e-2, 1.2e-2, 1.2e-6, 5.8e-15],
        );
        assert!(stuck(&p, &spot, &x));
        assert!(!stuck(
            &p,
            &solve(&[1.376, 0.2227, 1.3], &[5.5e-2, 5.8e-15]),
            &x
        ));
        let strict = NewtonParams {
            gradient_tolerance: 1e-9,
            ..NewtonParams::default()
        };
        let floor = solve(&[2.3e-9, 2.9e-9, 2.6e-9], &[1.1e-13, 4.2e-14]);
        assert!(!stuck(&strict, &floor, &x));
        // Converged by the gradient: never stuck.
        assert!(!stuck(&p, &solve(&[9.9e5, 9e-7], &[5.5e-18]), &x));
        let tight = NewtonParams {
            gradient_tolerance: 1e-14,
            ..NewtonParams::default()
        };
        let plastic = solve(
            &[7.44, 1.28e-6, 9.41e-13, 9.41e-13],
            &[3.1e-4, 5.3e-11, 3.9e-17],
        );
        assert!(!stuck(&tight, &plastic, &x));
        let cloth = solve(&[0.31, 1.2e-10, 9.6e-12], &[1.2e-6, 5.4e-16]);
        assert!(!stuck(&tight, &cloth, &x));
        // Baraff–Witkin single iterations are accepted as they are.
        let single = NewtonParams {
            single_iteration: true,
            ..p.clone()
        };
        assert!(!stuck(&single, &lumpy, &x));
    }

    #[test]
    fn norms_of_finite_vectors_are_finite() {
        assert_eq!(norm(&[3.0, 4.0]), 5.0);
        assert_eq!(norm(&[]), 0.0);
        let big = norm(&[3e200, -4e200, 0.0]);
        assert!((big / 5e200 - 1.0).abs() < 4.0 * f64::EPSILON, "{big}");
        assert_eq!(norm(&[f64::MAX, f64::MAX]), f64::INFINITY);
        assert_eq!(norm(&[1e300, f64::INFINITY]), f64::INFINITY);
        assert!(norm(&[1e300, f64::NAN]).is_nan());
        assert!(norm(&[1.0, f64::NAN]).is_nan());
    }
}
