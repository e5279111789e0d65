//! Contact with analytic obstacles as a smooth one-sided quadratic penalty.
//!
//! With `d(x)` the signed distance of a vertex to the obstacle and `δ ≥ 0` a margin, each vertex contributes
//! `½ κ (δ − d)²` when `d < δ`, else nothing (C¹: energy and gradient are continuous at `d = δ`). With
//! `s = δ − d > 0`: `∇E = −κ s ∇d`, `Hess E = κ ∇d ∇dᵀ − κ s Hess d`.
//! - Plane through `p` with unit normal `n`: `d = n · (x − p)`, `∇d = n`, `Hess d = 0`.
//! - Sphere of centre `c`, radius `r`: `d = |x − c| − r`, `∇d = u = (x − c)/|x − c|`,
//!   `Hess d = (I − u uᵀ)/|x − c|` (so the exact Hessian has a negative part inside the sphere).
//!
//! A [`Request::definite`](hinge_core::bending::Request::definite) evaluation drops the `− κ s Hess d` term
//! (positive semi-definite: `κ ∇d ∇dᵀ`); for the plane that is the exact Hessian.
//!
//! **Smoothing** ([`Contact::with_smoothing`], a length `ε ≥ 0`, default 0). The quadratic penalty's Hessian
//! jumps from 0 to κ where a vertex crosses the margin, so Newton's quadratic model is wrong for every vertex
//! a step carries across it (a lightly touching cloth crosses it back and forth). With `ε > 0` the penalty
//! of `s = δ − d` is C²:
//! `φ(s) = κ s³/(6ε)` for `0 < s < ε` and `φ(s) = ½ κ (s² − ε s + ε²/3)` for `s ≥ ε`
//! (value, `φ′ = κ s²/(2ε)` resp. `κ (s − ε/2)`, and `φ″ = κ s/ε` resp. `κ` continuous at `ε` and at 0),
//! so `∇E = −φ′ ∇d`, `Hess E = φ″ ∇d ∇dᵀ − φ′ Hess d`. `ε = 0` is the quadratic penalty above; deep
//! penetrations are resisted as by it, shifted by `ε/2`.
//!
//! **Barrier** ([`Contact::with_barrier`]; scene key `[[obstacles]] model = "barrier"`). Instead of the
//! penalty, the logarithmic barrier of incremental potential contact (Li et al. 2020):
//! `b(d) = −κ (d − δ)² ln(d/δ)` for `0 < d < δ`, zero beyond (C² at `d = δ`: value, slope and curvature
//! vanish there), infinite at `d → 0`, so that the margin δ becomes the barrier's reach and κ keeps the
//! penalty's units (N/m). `b′ = −κ (2 (d − δ) ln(d/δ) + (d − δ)²/d)`,
//! `b″ = −κ (2 ln(d/δ) + 4 (d − δ)/d − (d − δ)²/d²) > 0`; `∇E = b′ ∇d`, `Hess E = b″ ∇d ∇dᵀ + b′ Hess d`
//! (the second term dropped by a definite request, as for the penalty). A vertex on or inside the obstacle is
//! an error naming it. The barrier only holds if no step crosses the obstacle: [`Energy::max_step`] is the
//! largest fraction of a straight move of all vertices that closes at most 90 % of any vertex's distance
//! ([`BARRIER_GAP_KEPT`]; the root of a linear equation for a plane, of a quadratic for a sphere, so a fast
//! vertex cannot pass through a sphere within one step): Newton's line search starts there, and implicit
//! Euler starts a step from `x̂` or, where the move from the last state to `x̂` exceeds the bound, that
//! fraction of the way. Every state Newton visits is then outside the obstacle, whatever the speeds and the
//! time step, and a fast vertex does not start a step beyond a sphere it would have hit. A moving
//! obstacle carries the vertices within its reach ([`Energy::carry`]: a sphere's vertices by its centre's
//! displacement, a plane's along its new normal to their old distance), so that a step starts outside it
//! where it has moved to; a vertex outside the reach that the obstacle overtakes within one step makes the
//! step fail (and implicit Euler retries it in substeps, over which the obstacle moves less). Symplectic
//! Euler does not carry: its substeps must be short enough for the barrier's force to act first.
//!
//! **Moving obstacles.** [`Contact::with_motion`] gives the obstacle a rigid [`Motion`]: at time `t` a
//! sphere's centre is at `motion.target(centre, t)`, a plane passes through `motion.target(point, t)` with
//! its normal turned by the motion's rotation. [`Energy::set_time`] places it (the time steppers call it with
//! each (sub)step's end time, so a step's contact is that of the obstacle where the step ends); within an
//! evaluation the obstacle is fixed, so the derivatives above are unchanged.

use std::sync::Arc;

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy};
use hinge_core::nalgebra::{Matrix3, Vector3};
use hinge_core::pattern::SymmetricPattern;
use hinge_core::{ElementRef, EvalError};

use crate::motion::Motion;

/// The share of a vertex's distance to the obstacle that a barrier's step bound keeps
/// ([`Energy::max_step`]): a step may close at most 90 % of the gap.
pub const BARRIER_GAP_KEPT: f64 = 0.1;

/// An analytic obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Obstacle {
    /// A sphere.
    Sphere {
        /// Centre.
        center: Vector3<f64>,
        /// Radius.
        radius: f64,
    },
    /// A half-space bounded by a plane; vertices are pushed to the side `normal` points to.
    Plane {
        /// A point on the plane.
        point: Vector3<f64>,
        /// Unit normal (normalised on construction).
        normal: Vector3<f64>,
    },
}

impl Obstacle {
    /// Signed distance of `p` to the obstacle's surface (negative inside).
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        match *self {
            Obstacle::Sphere { center, radius } => (p - center).norm() - radius,
            Obstacle::Plane { point, normal } => normal.dot(&(p - point)),
        }
    }
}

/// A penalty contact energy against one obstacle.
#[derive(Debug, Clone)]
pub struct Contact {
    /// Where the obstacle is now.
    obstacle: Obstacle,
    /// Where it is at t = 0, and how it moves.
    motion: Option<(Obstacle, Motion)>,
    stiffness: f64,
    margin: f64,
    smoothing: f64,
    barrier: bool,
    n_vertices: usize,
    diag: Vec<usize>,
}

impl Contact {
    /// Penalty contact of stiffness `stiffness` (κ) and margin `margin` (δ) against `obstacle`.
    ///
    /// # Errors
    /// [`EvalError::Element`] for non-finite or negative parameters or a zero plane normal.
    pub fn new(
        n_vertices: usize,
        obstacle: Obstacle,
        stiffness: f64,
        margin: f64,
    ) -> Result<Self, EvalError> {
        let bad = |m: String| EvalError::Element {
            element: "contact".into(),
            message: m,
        };
        if !(stiffness >= 0.0 && stiffness.is_finite() && margin >= 0.0 && margin.is_finite()) {
            return Err(bad(format!(
                "stiffness {stiffness} and margin {margin} must be finite and non-negative"
            )));
        }
        let obstacle = match obstacle {
            Obstacle::Sphere { center, radius } => {
                if !(radius > 0.0 && radius.is_finite() && center.iter().all(|c| c.is_finite())) {
                    return Err(bad(format!(
                        "sphere radius {radius} / centre {center:?} invalid"
                    )));
                }
                obstacle
            }
            Obstacle::Plane { point, normal } => {
                let len = normal.norm();
                if !(len > 0.0 && len.is_finite() && point.iter().all(|c| c.is_finite())) {
                    return Err(bad(format!(
                        "plane normal {normal:?} / point {point:?} invalid"
                    )));
                }
                Obstacle::Plane {
                    point,
                    normal: normal / len,
                }
            }
        };
        Ok(Self {
            obstacle,
            motion: None,
            stiffness,
            margin,
            smoothing: 0.0,
            barrier: false,
            n_vertices,
            diag: Vec::new(),
        })
    }

    /// A C² penalty that rises from zero curvature over the first `smoothing` (ε) of penetration into the
    /// margin (module documentation, Smoothing); 0 is the quadratic penalty.
    ///
    /// # Errors
    /// [`EvalError::Element`] for a negative or non-finite `smoothing`.
    pub fn with_smoothing(mut self, smoothing: f64) -> Result<Self, EvalError> {
        if !(smoothing >= 0.0 && smoothing.is_finite()) || (self.barrier && smoothing != 0.0) {
            return Err(EvalError::Element {
                element: "contact".into(),
                message: format!(
                    "smoothing {smoothing} must be finite and non-negative (and 0 for a barrier)"
                ),
            });
        }
        self.smoothing = smoothing;
        Ok(self)
    }

    /// A logarithmic barrier instead of the penalty (module documentation, Barrier): the margin δ becomes the
    /// barrier's reach, which must be positive, and a vertex on or inside the obstacle is an error.
    ///
    /// # Errors
    /// [`EvalError::Element`] for a zero margin or a smoothing (the barrier is C² by itself).
    pub fn with_barrier(mut self) -> Result<Self, EvalError> {
        if !(self.margin > 0.0) || self.smoothing != 0.0 {
            return Err(EvalError::Element {
                element: "contact".into(),
                message: format!(
                    "a barrier needs a positive margin (its reach; got {}) and no smoothing (got {})",
                    hinge_core::error::Num(self.margin),
                    hinge_core::error::Num(self.smoothing)
                ),
            });
        }
        self.barrier = true;
        Ok(self)
    }

    /// Whether this is the barrier ([`Contact::with_barrier`]).
    pub fn is_barrier(&self) -> bool {
        self.barrier
    }

    /// The barrier `b(d) = −κ (d − δ)² ln(d/δ)` of a distance `0 < d < δ` and its first two derivatives in
    /// `d`; zero for `d ≥ δ`, `None` for `d ≤ 0` (module documentation, Barrier).
    pub fn barrier(&self, d: f64) -> Option<(f64, f64, f64)> {
        let (kappa, delta) = (self.stiffness, self.margin);
        if !(d > 0.0) {
            return None;
        }
        if d >= delta {
            return Some((0.0, 0.0, 0.0));
        }
        let (e, l) = (d - delta, (d / delta).ln());
        Some((
            -kappa * e * e * l,
            -kappa * (2.0 * e * l + e * e / d),
            -kappa * (2.0 * l + 4.0 * e / d - e * e / (d * d)),
        ))
    }

    /// The smoothing length ε ([`Contact::with_smoothing`]).
    pub fn smoothing(&self) -> f64 {
        self.smoothing
    }

    /// The penalty `φ(s)` of a penetration `s` into the margin and its first two derivatives (module
    /// documentation): `κ s²/2` without smoothing, C² with it; zero for `s ≤ 0`.
    pub fn penalty(&self, s: f64) -> (f64, f64, f64) {
        let (kappa, eps) = (self.stiffness, self.smoothing);
        if !(s > 0.0) {
            (0.0, 0.0, 0.0)
        } else if eps == 0.0 {
            (0.5 * kappa * s * s, kappa * s, kappa)
        } else if s < eps {
            (
                kappa * s * s * s / (6.0 * eps),
                kappa * s * s / (2.0 * eps),
                kappa * s / eps,
            )
        } else {
            (
                0.5 * kappa * (s * s - eps * s + eps * eps / 3.0),
                kappa * (s - 0.5 * eps),
                kappa,
            )
        }
    }

    /// The obstacle moves along `motion` ([`Motion::target`] from its position at t = 0, the one given to
    /// [`Contact::new`]); [`Energy::set_time`] places it.
    ///
    /// # Errors
    /// [`EvalError::Element`] with [`Motion::check`]'s reason.
    pub fn with_motion(mut self, motion: Motion) -> Result<Self, EvalError> {
        motion.check().map_err(|why| EvalError::Element {
            element: "contact".into(),
            message: format!("obstacle motion: {why}"),
        })?;
        self.motion = Some((self.obstacle, motion));
        Ok(self)
    }

    /// Where the obstacle is now (after the last [`Energy::set_time`]).
    pub fn obstacle(&self) -> Obstacle {
        self.obstacle
    }

    /// Where an obstacle with `motion` is at time `t`, from `rest` (its position at t = 0).
    pub fn moved(rest: &Obstacle, motion: &Motion, t: f64) -> Obstacle {
        match *rest {
            Obstacle::Sphere { center, radius } => Obstacle::Sphere {
                center: motion.target(center, t),
                radius,
            },
            Obstacle::Plane { point, normal } => Obstacle::Plane {
                point: motion.target(point, t),
                normal: motion.direction(normal, t),
            },
        }
    }

    /// The fraction `t ∈ [0, 1]` of the straight move `p → q` at which the distance to the obstacle first
    /// falls to `kept` times its value at `p` (1 if it never does, or if `p` is not outside the obstacle).
    pub fn time_to_gap(&self, p: &Vector3<f64>, q: &Vector3<f64>, kept: f64) -> f64 {
        let d0 = self.distance(p);
        if !(d0 > 0.0) {
            return 1.0;
        }
        let v = q - p;
        let t = match self.obstacle {
            Obstacle::Plane { normal, .. } => {
                let rate = normal.dot(&v);
                if rate < 0.0 {
                    (1.0 - kept) * d0 / -rate
                } else {
                    1.0
                }
            }
            Obstacle::Sphere { center, radius } => {
                // |r + t v| = R with R = radius + kept·d0 < |r|: the smaller root of a t² + 2 b t + c = 0.
                let r = p - center;
                let big_r = radius + kept * d0;
                let (a, b, c) = (
                    v.norm_squared(),
                    r.dot(&v),
                    (r.norm() - big_r) * (r.norm() + big_r),
                );
                let disc = b * b - a * c;
                if b >= 0.0 || disc < 0.0 {
                    1.0
                } else {
                    c / (-b + disc.sqrt())
                }
            }
        };
        if t.is_nan() { 1.0 } else { t.clamp(0.0, 1.0) }
    }

    /// Signed distance of `p` to the obstacle ([`Obstacle::distance`]).
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        self.obstacle.distance(p)
    }
}

impl Energy for Contact {
    // `stiffness` (≥ 0): the energy is proportional to it.
    proportional_parameter!("stiffness", stiffness);

    fn name(&self) -> &str {
        match self.obstacle {
            Obstacle::Sphere { .. } => "contact-sphere",
            Obstacle::Plane { .. } => "contact-plane",
        }
    }

    fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    fn couplings(&self, _: &mut Vec<(usize, usize)>) {}

    fn carry(&self, from_time: f64, x: &mut [Vector3<f64>]) -> bool {
        let Some((rest, motion)) = &self.motion.as_ref().filter(|_| self.barrier) else {
            return false;
        };
        if !from_time.is_finite() {
            return false;
        }
        let reach = self.margin;
        let mut moved = false;
        // Within reach of the obstacle where it was: moved so as to keep that distance to it now (a sphere's
        // centre's displacement; for a plane, along its new normal).
        match (Self::moved(rest, motion, from_time), self.obstacle) {
            (Obstacle::Sphere { center: c0, radius }, Obstacle::Sphere { center: c1, .. })
                if c1 != c0 =>
            {
                for p in x.iter_mut().filter(|p| (**p - c0).norm() - radius < reach) {
                    *p += c1 - c0;
                    moved = true;
                }
            }
            (
                Obstacle::Plane {
                    point: p0,
                    normal: n0,
                },
                Obstacle::Plane {
                    point: p1,
                    normal: n1,
                },
            ) => {
                for p in x.iter_mut() {
                    let d0 = n0.dot(&(*p - p0));
                    let shift = n1 * (d0 - n1.dot(&(*p - p1)));
                    if d0 < reach && shift != Vector3::zeros() {
                        *p += shift;
                        moved = true;
                    }
                }
            }
            // A resting sphere; a rigid motion keeps the obstacle's kind.
            _ => {}
        }
        moved
    }

    fn max_step(&self, from: &[Vector3<f64>], to: &[Vector3<f64>]) -> f64 {
        if !self.barrier {
            return 1.0;
        }
        let mut t = 1.0_f64;
        for (p, q) in from.iter().zip(to) {
            t = t.min(self.time_to_gap(p, q, BARRIER_GAP_KEPT));
        }
        t
    }

    fn set_time(&mut self, time: f64) -> Result<(), EvalError> {
        let Some((rest, motion)) = &self.motion else {
            return Ok(());
        };
        if !time.is_finite() {
            return Err(EvalError::Element {
                element: "contact".into(),
                message: format!("time {time} is not finite"),
            });
        }
        self.obstacle = Self::moved(rest, motion, time);
        Ok(())
    }

    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError> {
        self.diag = crate::util::diagonal_slots(pattern, self.n_vertices)?;
        Ok(())
    }

    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        hinge_core::mesh::check_same_vertex_count(self.n_vertices, x.len())?;
        let delta = self.margin;
        let mut e = 0.0;
        for (i, p) in x.iter().enumerate() {
            let (d, grad_d, hess_d) = match self.obstacle {
                Obstacle::Plane { point, normal } => (normal.dot(&(p - point)), normal, None),
                Obstacle::Sphere { center, radius } => {
                    let r = p - center;
                    let len = r.norm();
                    if len - radius >= delta {
                        continue;
                    }
                    if !(len > 0.0) {
                        return Err(EvalError::AtElement {
                            energy: "contact".into(),
                            element: ElementRef::Vertex(i),
                            message: "the vertex is at the sphere's centre: the contact normal is undefined".into(),
                        });
                    }
                    let u = r / len;
                    (
                        len - radius,
                        u,
                        Some((Matrix3::identity() - u * u.transpose()) / len),
                    )
                }
            };
            // E = φ, ∇E = g1 ∇d, Hess E = g2 ∇d ∇dᵀ + g1 Hess d.
            let (phi, g1, g2) = if self.barrier {
                let Some((b, db, ddb)) = self.barrier(d) else {
                    return Err(EvalError::AtElement {
                        energy: "contact".into(),
                        element: ElementRef::Vertex(i),
                        message: format!(
                            "the vertex is on or inside the obstacle (distance {d:e}): the barrier is infinite there"
                        ),
                    });
                };
                if b == 0.0 && db == 0.0 {
                    continue;
                }
                (b, db, ddb)
            } else {
                let s = delta - d;
                if !(s > 0.0) {
                    continue;
                }
                let (phi, dphi, ddphi) = self.penalty(s);
                (phi, -dphi, ddphi)
            };
            e += phi;
            if request.gradient {
                acc.add_gradient(i, &(grad_d * g1));
            }
            if request.hessian && !self.diag.is_empty() {
                let mut h = grad_d * grad_d.transpose() * g2;
                if let Some(hd) = hess_d.filter(|_| !request.definite) {
                    h += hd * g1;
                }
                acc.add_block(self.diag[i], i, i, &h);
            }
        }
        Ok(if request.value { e } else { 0.0 })
    }
}
