//! Statics of thin shells by membrane continuation.
//!
//! In a thin shell the membrane is stiffer than the bending by `12 ℓ²/h²` at the scale of an element of
//! length `ℓ` (thickness `h`; 2·10⁴ for a 0.1 mm strip on 4 mm elements). A Newton step in displacements is
//! linear in the rotations, so it stretches the membrane by the square of the deflection it makes: its
//! quadratic model holds only within deflections of about the thickness, and a strip that bends down by a
//! large part of its length from the flat state takes hundreds of line-searched steps (418 for a clamped
//! 0.3 m strip of Y = 1e10 Pa, h = 0.1 mm; a ramp of the load does not help: 967 in all). With the
//! membrane softened to about the inverse of that ratio the same deflection takes a few steps; raising the
//! stiffness back in stages of at most 100×, each a Newton solve from the last, reaches the equilibrium of
//! the real material in 37 iterations in all (`hinge stability`'s stiff beams: 2–418 → 2–51).
//!
//! [`membrane_scales`] chooses the stages for a [`System`] whose StVK membrane term is named `membrane`;
//! [`continuation_scales`] for a membrane whose Young's modulus and thickness the caller knows (the
//! co-rotational membrane: its `stiffness` is then the parameter to scale); [`minimize_continued`] runs
//! them. In dynamics this is not used: inertia already keeps the steps short (the same pre-solve per step
//! makes the drape slower: 737 → 1 914 Newton iterations).

use hinge_core::TriMesh;
use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::System;
use hinge_core::nalgebra::Vector3;

use crate::newton::{Newton, NewtonStats, SolverError};

/// Largest membrane strain the loads may cause at the softest stage (see [`membrane_scales`]).
pub const STAGE_STRAIN: f64 = 1e-2;

/// Largest ratio between two successive stages.
pub const STAGE_RATIO: f64 = 100.0;

/// The stiffness scales, ascending and below 1, that a static solve of `system` on `rest` passes its
/// membrane through before the real one (empty: none needed).
///
/// The softest is `s₀ = max(h² / (12 ℓ²), ε_load / STAGE_STRAIN)` with `h` and `Y` the `membrane.thickness`
/// and `membrane.young` parameters of `system`, `ℓ` the mean rest edge length, and `ε_load = q D / (Y h)` the
/// strain the loads would cause at full stiffness: `q` the net force of `system` at the rest positions (the
/// loads: the elastic terms vanish at rest) per rest area, `D` the rest mesh's bounding-box diagonal. Then
/// stages evenly spaced in log scale, at most [`STAGE_RATIO`] apart, up to 1 (excluded). None when
/// `s₀ ≥ 0.1`, when the system has no `membrane.young` / `membrane.thickness` (no StVK membrane named
/// `membrane`), or for an empty mesh.
///
/// # Errors
/// [`SolverError::Eval`] if `system` cannot be evaluated at the rest positions.
pub fn membrane_scales(system: &mut System, rest: &TriMesh) -> Result<Vec<f64>, SolverError> {
    let scalar =
        |system: &System, name: &str| system.parameter(name).ok().and_then(|v| v.first().copied());
    let (Some(young), Some(thickness)) = (
        scalar(system, "membrane.young"),
        scalar(system, "membrane.thickness"),
    ) else {
        return Ok(Vec::new());
    };
    continuation_scales(system, rest, young, thickness)
}

/// [`membrane_scales`] for a membrane of Young's modulus `young` and thickness `thickness` given by the
/// caller: for a membrane term that does not carry them as parameters, such as the co-rotational membrane
/// (whose `stiffness` k = Y h / (1 + ν) is then the parameter to scale: the energy is proportional to it).
///
/// # Errors
/// [`SolverError::Eval`] if `system` cannot be evaluated at the rest positions.
pub fn continuation_scales(
    system: &mut System,
    rest: &TriMesh,
    young: f64,
    thickness: f64,
) -> Result<Vec<f64>, SolverError> {
    let x = rest.positions();
    let area: f64 = rest
        .triangles()
        .iter()
        .map(|t| 0.5 * (x[t[1]] - x[t[0]]).cross(&(x[t[2]] - x[t[0]])).norm())
        .sum();
    if !(young > 0.0 && thickness > 0.0 && area > 0.0) {
        return Ok(Vec::new());
    }
    let l = mean_edge_length(rest);
    let mut out = system.new_output();
    system
        .evaluate_into(x, Request::GRADIENT, Parallelism::Rayon, &mut out)
        .map_err(|source| SolverError::Eval {
            source,
            stats: Box::default(),
        })?;
    let net = out
        .gradient
        .chunks_exact(3)
        .fold(Vector3::zeros(), |s, g| s + Vector3::new(g[0], g[1], g[2]));
    let (lo, hi) = x.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    let load_strain = net.norm() / area * (hi - lo).norm() / (young * thickness);
    let softest = (thickness * thickness / (12.0 * l * l)).max(load_strain / STAGE_STRAIN);
    if !(softest < 0.1) {
        return Ok(Vec::new());
    }
    let n = (-softest.ln() / STAGE_RATIO.ln()).ceil() as i32;
    Ok((0..n)
        .map(|k| softest.powf(1.0 - f64::from(k) / f64::from(n)))
        .collect())
}

/// The mean length of `rest`'s edges (each triangle's three, shared edges counted twice; 0 for no
/// triangles): the element length of [`membrane_scales`], and the CLI's length scale of the relative step
/// test.
pub fn mean_edge_length(rest: &TriMesh) -> f64 {
    let x = rest.positions();
    let (mut sum, mut count) = (0.0, 0usize);
    for t in rest.triangles() {
        for k in 0..3 {
            sum += (x[t[(k + 1) % 3]] - x[t[k]]).norm();
            count += 1;
        }
    }
    if count == 0 { 0.0 } else { sum / count as f64 }
}

/// Minimises `system`'s energy from `x` (no inertia) by continuation in `parameter`: for each of `scales`,
/// the parameter's values times the scale, a Newton solve from the last stage's result (a stage that fails
/// is skipped: the next starts where the last good one ended); then the parameter's own values (set back
/// bitwise) and the final solve. The statistics sum every stage's (their iterations and factorizations
/// count); the last gradient norm is the final solve's. On failure `x` is unchanged, and so is the parameter.
/// Without scales it is one plain Newton solve, and `parameter` is not looked up: a system without it (no
/// membrane, the co-rotational one) solves as well.
///
/// # Errors
/// [`SolverError::Eval`] for an unknown parameter when there are scales; the final solve's error;
/// [`SolverError::Interrupted`] with every stage's statistics as soon as any stage sees the Newton solver's
/// stop flag ([`Newton::set_stop`]).
pub fn minimize_continued(
    newton: &mut Newton,
    system: &mut System,
    x: &mut [Vector3<f64>],
    parameter: &str,
    scales: &[f64],
) -> Result<NewtonStats, SolverError> {
    minimize_continued_all(newton, system, x, &[parameter], scales)
}

/// [`minimize_continued`] scaling every one of `parameters` by each stage's scale (several membranes of one
/// system: `membrane.young` and `membrane#2.young`, see [`System::term_labels`]). On failure `x`, every
/// parameter and the Newton solver's shift memory ([`crate::newton::NewtonParams::remember_shift`], which
/// the stages that succeeded moved) are unchanged.
///
/// # Errors
/// As [`minimize_continued`].
pub fn minimize_continued_all(
    newton: &mut Newton,
    system: &mut System,
    x: &mut [Vector3<f64>],
    parameters: &[&str],
    scales: &[f64],
) -> Result<NewtonStats, SolverError> {
    let memory = newton.shift_memory();
    let result = stages(newton, system, x, parameters, scales);
    if result.is_err() {
        newton.set_shift_memory(memory);
    }
    result
}

/// The stages of [`minimize_continued_all`].
fn stages(
    newton: &mut Newton,
    system: &mut System,
    x: &mut [Vector3<f64>],
    parameters: &[&str],
    scales: &[f64],
) -> Result<NewtonStats, SolverError> {
    let eval = |source| SolverError::Eval {
        source,
        stats: Box::default(),
    };
    if scales.is_empty() || parameters.is_empty() {
        return newton.minimize(system, x, None);
    }
    let base = parameters
        .iter()
        .map(|p| system.parameter(p))
        .collect::<Result<Vec<_>, _>>()
        .map_err(eval)?;
    // Every parameter back to its own values (they were accepted once, so setting them succeeds).
    let restore = |system: &mut System| {
        for (p, b) in parameters.iter().zip(&base) {
            let _ = system.set_parameter(p, b);
        }
    };
    let mut y = x.to_vec();
    let mut stats = NewtonStats::default();
    let stages = scales.len() + 1;
    for (k, &s) in scales.iter().enumerate() {
        for (p, b) in parameters.iter().zip(&base) {
            let scaled: Vec<f64> = b.iter().map(|v| v * s).collect();
            if let Err(e) = system.set_parameter(p, &scaled) {
                restore(system);
                newton.set_stage(None);
                return Err(eval(e));
            }
        }
        newton.set_stage(Some((k + 1, stages)));
        match newton.minimize(system, &mut y, None) {
            Ok(st) => stats.absorb(&st),
            Err(SolverError::Interrupted { stats: st }) => {
                // A stop request ends the whole continuation, not just this stage.
                restore(system);
                newton.set_stage(None);
                stats.absorb(&st);
                return Err(SolverError::Interrupted {
                    stats: Box::new(stats),
                });
            }
            Err(e) => stats.absorb(&e.stats()),
        }
    }
    restore(system);
    newton.set_stage(Some((stages, stages)));
    let last = newton.minimize(system, &mut y, None);
    newton.set_stage(None);
    let last = match last {
        Ok(last) => last,
        Err(SolverError::Interrupted { stats: st }) => {
            stats.absorb(&st);
            return Err(SolverError::Interrupted {
                stats: Box::new(stats),
            });
        }
        Err(e) => return Err(e),
    };
    stats.absorb(&last);
    x.copy_from_slice(&y);
    Ok(stats)
}

/// A start for later solves (a fit's first equilibrium, say): when there are `scales`, moves `x` to the
/// equilibrium [`minimize_continued`] reaches, or leaves it where it is if that fails (the caller's own solve
/// from there then reports what goes wrong); without scales, does nothing. Returns the Newton iterations
/// spent.
pub fn continued_start(
    newton: &mut Newton,
    system: &mut System,
    x: &mut [Vector3<f64>],
    parameter: &str,
    scales: &[f64],
) -> usize {
    continued_start_all(newton, system, x, &[parameter], scales)
}

/// [`continued_start`] through [`minimize_continued_all`].
pub fn continued_start_all(
    newton: &mut Newton,
    system: &mut System,
    x: &mut [Vector3<f64>],
    parameters: &[&str],
    scales: &[f64],
) -> usize {
    if scales.is_empty() {
        return 0;
    }
    match minimize_continued_all(newton, system, x, parameters, scales) {
        Ok(stats) => stats.iterations,
        Err(e) => e.stats().iterations,
    }
}
