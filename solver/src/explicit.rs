//! Symplectic (semi-implicit) Euler: the explicit baseline whose step-size limit motivates implicit Euler
//! (lecture P12–P14).
//!
//! Each substep of size `h`: `v ← v − h M⁻¹ ∇E(x)`, then `x ← x + h v` (pinned vertices keep their
//! positions and zero velocity). It is stable only for `h < 2/ω_max`, with `ω_max²` the largest eigenvalue of
//! `M⁻¹ Hess E` ([`critical_step`] estimates it): stiff membranes make that limit tiny, which is why cloth
//! and shell simulators step implicitly.
//!
//! **Detecting a blow-up.** Without energy input (fixed pins, conservative or dissipative energies) the
//! kinetic energy of a run can only come from the initial kinetic energy and the work of the forces. A
//! substep is reported as unstable ([`SolverError::Unstable`]) when a position or velocity is not finite,
//! when the energies cannot be evaluated (a triangle collapsed), or when the kinetic energy exceeds twice
//! the initial kinetic energy plus the work the initial forces could do across the scene,
//! `2 (½ Σᵢ mᵢ |vᵢ⁰|² + Σᵢ |fᵢ⁰| L)` (L the diagonal of the start's bounding box): an unstable mode grows
//! geometrically and passes it within a few periods, a stable run does not reach it. (The kinetic energy,
//! not the total: the damping terms' step potentials are not energies.) On error `x` and `v` are those of
//! the frame's start; no NaN is ever returned.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use hinge_core::bending::Request;
use hinge_core::energy::{System, SystemEvaluation};
use hinge_core::nalgebra::Vector3;
use hinge_energies::pins::Pins;

use crate::newton::{FrameStats, Objective, PinMotion, Reduced, SolverError};

/// Symplectic Euler with a fixed number of substeps per frame.
pub struct SymplecticEuler {
    /// The frame's time step.
    pub dt: f64,
    /// Substeps per frame (the explicit step is `dt / substeps`).
    pub substeps: usize,
    masses: Vec<f64>,
    pinned: Vec<bool>,
    out: SystemEvaluation,
    /// Positions of the previous substep (the damping terms' step state).
    prev: Vec<Vector3<f64>>,
    /// The kinetic-energy bound of the blow-up test (see the module documentation), set at the first
    /// substep.
    bound: Option<f64>,
    substeps_done: usize,
    /// The time of the current state (s).
    time: f64,
    /// Checked before every substep ([`SymplecticEuler::set_stop`]).
    stop: Option<Arc<AtomicBool>>,
}

impl std::fmt::Debug for SymplecticEuler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SymplecticEuler")
            .field("dt", &self.dt)
            .field("substeps", &self.substeps)
            .finish()
    }
}

impl SymplecticEuler {
    /// A stepper for `system` with frame step `dt` split into `substeps`, masses `masses`, pins `pins`.
    ///
    /// # Errors
    /// [`SolverError::Input`] for a non-positive `dt`, zero substeps, non-positive masses or masses of the
    /// wrong length.
    pub fn new(
        system: &System,
        dt: f64,
        substeps: usize,
        masses: Vec<f64>,
        pins: &Pins,
    ) -> Result<Self, SolverError> {
        let n = system.n_vertices();
        if !(dt > 0.0 && dt.is_finite()) || substeps == 0 || masses.len() != n {
            return Err(SolverError::Input(format!(
                "dt = {dt} must be positive and substeps = {substeps} at least 1; {} masses for {n} vertices",
                masses.len()
            )));
        }
        let pinned: Vec<bool> = {
            let mut p = vec![false; n];
            for &v in pins.vertices() {
                if let Some(slot) = p.get_mut(v) {
                    *slot = true;
                }
            }
            p
        };
        if let Some(i) = (0..n).find(|&i| !(pinned[i] || masses[i] > 0.0 && masses[i].is_finite()))
        {
            return Err(SolverError::Input(format!(
                "vertex {i} is free but its mass {} is not positive: explicit steps divide by it",
                masses[i]
            )));
        }
        Ok(Self {
            dt,
            substeps,
            masses,
            pinned,
            out: SystemEvaluation {
                energy: 0.0,
                terms: Vec::new(),
                gradient: Vec::new(),
                hessian: Vec::new(),
            },
            prev: Vec::new(),
            bound: None,
            substeps_done: 0,
            time: 0.0,
            stop: None,
        })
    }

    /// A flag another thread (a Ctrl-C handler, a GUI's cancel button) raises to end the stepping: every
    /// [`SymplecticEuler::advance`] reads it before each substep and, once it is set, returns
    /// [`SolverError::Interrupted`] with the frame's state restored (as for a failed frame). A frame of
    /// many substeps on a large mesh thus stops within one substep. The flag is never cleared here;
    /// `None` removes it.
    pub fn set_stop(&mut self, flag: Option<Arc<AtomicBool>>) {
        self.stop = flag;
    }

    /// The time (s) of the current state: 0 for a new stepper, advanced by `dt` per frame.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Sets the time of the current state and places the system there ([`System::set_time`]).
    ///
    /// # Errors
    /// [`SolverError::Input`] for a non-finite time; the system's error (nothing changed then).
    pub fn set_time(&mut self, system: &mut System, time: f64) -> Result<(), SolverError> {
        crate::newton::place_at(system, time)?;
        self.time = time;
        Ok(())
    }

    /// The explicit step `dt / substeps`.
    pub fn step_size(&self) -> f64 {
        self.dt / self.substeps as f64
    }

    /// Advances one frame ([`SymplecticEuler::substeps`] substeps).
    ///
    /// # Errors
    /// [`SolverError::Unstable`] when a substep blows up (see the module documentation), with `x`, `v`,
    /// the time and the system's step state (damping's previous positions, and plastic rest angles through
    /// [`System::rewind_step_state`]) set back to the frame's start; [`SolverError::Interrupted`] (no Newton
    /// work: its statistics are empty) when the stop flag ([`SymplecticEuler::set_stop`]) is up before a
    /// substep, with the same restore; [`SolverError::Input`] for sizes that do not fit.
    pub fn advance(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        v: &mut [Vector3<f64>],
    ) -> Result<FrameStats, SolverError> {
        self.advance_with(system, x, v, None)
    }

    /// [`SymplecticEuler::advance`] with moving pinned vertices: after each substep a pinned vertex that
    /// `motion` writes is at its target for the substep's end, with the velocity that took it there (see
    /// [`crate::newton::PinMotion`]). The forces of a substep are those with the system's moving parts
    /// (obstacles) at the substep's start time ([`System::set_time`]: the explicit step evaluates the
    /// forces once, at its start); a failed frame leaves the time and the system at the frame's start.
    ///
    /// # Errors
    /// As [`SymplecticEuler::advance`].
    pub fn advance_with(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        v: &mut [Vector3<f64>],
        motion: Option<&dyn PinMotion>,
    ) -> Result<FrameStats, SolverError> {
        let n = self.masses.len();
        if x.len() != n || v.len() != n {
            return Err(SolverError::Input(format!(
                "{} positions and {} velocities for {n} vertices",
                x.len(),
                v.len()
            )));
        }
        let (x0, v0) = (x.to_vec(), v.to_vec());
        let h = self.step_size();
        let time0 = self.time;
        // What a failed frame sets back besides `x` and `v`: the damping terms' previous positions (and
        // the system's step state they set) and what the substeps' ends changed (plastic rest angles).
        let prev0 = self.prev.clone();
        let done0 = self.substeps_done;
        system.mark_step_state();
        let restore =
            |me: &mut Self, system: &mut System, x: &mut [Vector3<f64>], v: &mut [Vector3<f64>]| {
                x.copy_from_slice(&x0);
                v.copy_from_slice(&v0);
                // Each call succeeded with these arguments before (the time is finite, it was placed at; the
                // previous positions started a substep; the marked state was the energies' own).
                let _ = system.set_time(time0);
                if !prev0.is_empty() {
                    let _ = system.begin_step(&prev0, h);
                }
                let _ = system.rewind_step_state();
                me.prev.clone_from(&prev0);
                // Substeps are numbered over the run (in messages): the undone ones do not count.
                me.substeps_done = done0;
            };
        let mut targets = Vec::new();
        for k in 0..self.substeps {
            let t_start = time0 + self.dt * (k as f64 / self.substeps as f64);
            if let Err(e) = system.set_time(t_start) {
                restore(self, system, x, v);
                return Err(SolverError::Input(format!(
                    "placing the system at time {t_start}: {e}"
                )));
            }
            let t = motion.map(|m| {
                targets.clear();
                targets.extend_from_slice(x);
                m.targets((k + 1) as f64 / self.substeps as f64, &mut targets);
                targets.as_slice()
            });
            if self
                .stop
                .as_ref()
                .is_some_and(|f| f.load(Ordering::Relaxed))
            {
                restore(self, system, x, v);
                return Err(SolverError::Interrupted {
                    stats: Box::default(),
                });
            }
            if let Err(e) = self.substep(system, x, v, h, t) {
                restore(self, system, x, v);
                return Err(e);
            }
        }
        self.time = time0 + self.dt;
        let _ = system.set_time(self.time);
        Ok(FrameStats {
            substeps: self.substeps,
            smallest_fraction: 1.0 / self.substeps as f64,
            ..FrameStats::default()
        })
    }

    fn substep(
        &mut self,
        system: &mut System,
        x: &mut [Vector3<f64>],
        v: &mut [Vector3<f64>],
        h: f64,
        targets: Option<&[Vector3<f64>]>,
    ) -> Result<(), SolverError> {
        let k = self.substeps_done;
        let unstable = |reason: String| SolverError::Unstable {
            message: format!(
                "explicit substep {} (h = {h:.3e} s): {reason}; h is above the stability limit (see `critical_step`): use more substeps or implicit Euler",
                k + 1
            ),
        };
        if self.prev.len() != x.len() {
            self.prev = x.to_vec();
        }
        system
            .begin_step(&self.prev, h)
            .and_then(|()| Objective::evaluate(system, x, Request::GRADIENT, &mut self.out))
            .map_err(|e| unstable(format!("the energies cannot be evaluated ({e})")))?;
        let kinetic = |v: &[Vector3<f64>], m: &[f64]| -> f64 {
            v.iter()
                .zip(m)
                .map(|(w, m)| 0.5 * m * w.norm_squared())
                .sum()
        };
        let bound = *self.bound.get_or_insert_with(|| {
            let (lo, hi) = x.iter().fold(
                (
                    Vector3::repeat(f64::INFINITY),
                    Vector3::repeat(f64::NEG_INFINITY),
                ),
                |(lo, hi), p| (lo.inf(p), hi.sup(p)),
            );
            let size = (hi - lo).norm();
            let work: f64 = (0..x.len())
                .filter(|&i| !self.pinned[i])
                .map(|i| {
                    let g = Vector3::new(
                        self.out.gradient[3 * i],
                        self.out.gradient[3 * i + 1],
                        self.out.gradient[3 * i + 2],
                    );
                    g.norm() * size
                })
                .sum();
            2.0 * (work + kinetic(v, &self.masses)) + f64::MIN_POSITIVE
        });
        self.prev.copy_from_slice(x);
        for i in 0..x.len() {
            if self.pinned[i] {
                match targets {
                    Some(t) => {
                        v[i] = (t[i] - x[i]) / h;
                        x[i] = t[i];
                    }
                    None => v[i] = Vector3::zeros(),
                }
                continue;
            }
            let g = Vector3::new(
                self.out.gradient[3 * i],
                self.out.gradient[3 * i + 1],
                self.out.gradient[3 * i + 2],
            );
            v[i] -= g * (h / self.masses[i]);
            x[i] += v[i] * h;
            if !(x[i].iter().all(|c| c.is_finite()) && v[i].iter().all(|c| c.is_finite())) {
                return Err(unstable(format!("vertex {i} left the finite numbers")));
            }
        }
        let ke = kinetic(v, &self.masses);
        if ke > bound {
            return Err(unstable(format!(
                "the kinetic energy reached {ke:.3e} J, more than the {bound:.3e} J the start's energy and forces could supply"
            )));
        }
        system
            .end_step(x)
            .map_err(|e| unstable(format!("the step cannot be ended ({e})")))?;
        self.substeps_done += 1;
        Ok(())
    }
}

/// The largest stable explicit step `2/ω_max` at `x`, with `ω_max²` the largest eigenvalue of
/// `M⁻¹ Hess E(x)` over the free vertices (at a state where that Hessian is positive semi-definite, such as
/// the rest state: the power iteration finds the eigenvalue largest in magnitude), by power iteration on `M^{-1/2} H M^{-1/2}` (`iterations`
/// steps from a fixed start vector; the Rayleigh quotient approaches ω_max² from below, so the step is an
/// upper estimate).
///
/// # Errors
/// [`SolverError::Eval`] if the Hessian cannot be evaluated; [`SolverError::Input`] for masses that do not
/// fit or no free vertex.
pub fn critical_step(
    system: &mut System,
    x: &[Vector3<f64>],
    masses: &[f64],
    pins: &Pins,
    iterations: usize,
) -> Result<f64, SolverError> {
    let n = system.n_vertices();
    if masses.len() != n || x.len() != n {
        return Err(SolverError::Input(format!(
            "{} masses and {} positions for {n} vertices",
            masses.len(),
            x.len()
        )));
    }
    let mut out = SystemEvaluation {
        energy: 0.0,
        terms: Vec::new(),
        gradient: Vec::new(),
        hessian: Vec::new(),
    };
    Objective::evaluate(system, x, Request::ALL, &mut out).map_err(|source| SolverError::Eval {
        source,
        stats: Box::default(),
    })?;
    let mut free = pins.free_dofs();
    free.resize(3 * n, true);
    let reduced = Reduced::new(system.pattern(), &free);
    let m = reduced.csc.n;
    if m == 0 {
        return Err(SolverError::Input("no free vertex".into()));
    }
    let scale: Vec<f64> = reduced
        .dofs
        .iter()
        .map(|&d| 1.0 / masses[d / 3].sqrt())
        .collect();
    if scale.iter().any(|s| !s.is_finite()) {
        return Err(SolverError::Input(
            "a free vertex has no positive mass".into(),
        ));
    }
    let values: Vec<f64> = reduced.source.iter().map(|&k| out.hessian[k]).collect();
    // A fixed, generic start vector (deterministic).
    let mut y: Vec<f64> = (0..m)
        .map(|i| 1.0 + 0.5 * ((i as f64) * 0.618_033_988_749_895).fract())
        .collect();
    let (mut t, mut hy) = (vec![0.0; m], vec![0.0; m]);
    let mut lambda = 0.0_f64;
    for _ in 0..iterations.max(1) {
        let norm = y.iter().map(|a| a * a).sum::<f64>().sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            break;
        }
        for a in &mut y {
            *a /= norm;
        }
        for i in 0..m {
            t[i] = y[i] * scale[i];
        }
        reduced.csc.mul(&values, &t, &mut hy);
        for i in 0..m {
            hy[i] *= scale[i];
        }
        lambda = y.iter().zip(&hy).map(|(a, b)| a * b).sum::<f64>();
        y.copy_from_slice(&hy);
    }
    Ok(if lambda > 0.0 {
        2.0 / lambda.sqrt()
    } else {
        f64::INFINITY
    })
}
