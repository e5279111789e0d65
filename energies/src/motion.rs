//! Prescribed rigid motions over time: of pinned vertices (pin groups) and of obstacles
//! ([`crate::contact::Contact::with_motion`]).

use hinge_core::nalgebra::{Rotation3, Unit, Vector3};

/// A rigid motion of time: where a point whose rest position is `p` is at time `t` (s), from `p` at t = 0.
#[derive(Debug, Clone, PartialEq)]
pub enum Motion {
    /// Held at rest.
    Fixed,
    /// Constant velocity (m/s).
    Translation(Vector3<f64>),
    /// Rotation about the line through `center` along the unit `axis` (right-handed).
    Rotation {
        /// A point on the axis.
        center: Vector3<f64>,
        /// Unit axis.
        axis: Vector3<f64>,
        /// rad/s.
        angular_velocity: f64,
    },
    /// Piecewise linear offsets `(time, offset)`: from zero at t = 0 to the first, held after the last.
    /// Times must be positive and increasing.
    Keyframes(Vec<(f64, Vector3<f64>)>),
}

impl Motion {
    /// Checks the data: finite, a unit rotation axis, keyframes non-empty with positive increasing times.
    ///
    /// # Errors
    /// What is wrong, in one line.
    pub fn check(&self) -> Result<(), String> {
        let finite = |v: &Vector3<f64>| v.iter().all(|c| c.is_finite());
        match self {
            Motion::Fixed => Ok(()),
            Motion::Translation(v) if finite(v) => Ok(()),
            Motion::Translation(v) => Err(format!("velocity {v:?} is not finite")),
            Motion::Rotation {
                center,
                axis,
                angular_velocity,
            } => {
                if !(finite(center) && angular_velocity.is_finite()) {
                    Err(format!(
                        "centre {center:?} / angular velocity {angular_velocity} not finite"
                    ))
                } else if !((axis.norm() - 1.0).abs() < 1e-12) {
                    Err(format!("axis {axis:?} is not a unit vector"))
                } else {
                    Ok(())
                }
            }
            Motion::Keyframes(k) => {
                if k.is_empty() {
                    Err("no keyframes".into())
                } else if !(k[0].0 > 0.0
                    && k.iter().all(|(t, o)| t.is_finite() && finite(o))
                    && k.windows(2).all(|w| w[1].0 > w[0].0))
                {
                    Err(
                        "keyframe times must be finite, positive and increasing, offsets finite"
                            .into(),
                    )
                } else {
                    Ok(())
                }
            }
        }
    }

    /// The target at time `t` of a point whose rest position is `p`.
    pub fn target(&self, p: Vector3<f64>, t: f64) -> Vector3<f64> {
        match self {
            Motion::Fixed => p,
            Motion::Translation(v) => p + v * t,
            Motion::Rotation {
                center,
                axis,
                angular_velocity,
            } => {
                let r =
                    Rotation3::from_axis_angle(&Unit::new_unchecked(*axis), angular_velocity * t);
                center + r * (p - center)
            }
            Motion::Keyframes(k) => p + keyframe_offset(k, t),
        }
    }

    /// The image at time `t` of a direction (a difference of two points) fixed to the moving body: turned
    /// by a rotation, unchanged by the translations.
    pub fn direction(&self, d: Vector3<f64>, t: f64) -> Vector3<f64> {
        match self {
            Motion::Rotation {
                axis,
                angular_velocity,
                ..
            } => Rotation3::from_axis_angle(&Unit::new_unchecked(*axis), angular_velocity * t) * d,
            _ => d,
        }
    }
}

fn keyframe_offset(k: &[(f64, Vector3<f64>)], t: f64) -> Vector3<f64> {
    match k.iter().position(|(tk, _)| *tk > t) {
        None => k.last().map_or(Vector3::zeros(), |(_, o)| *o),
        Some(0) => k[0].1 * (t / k[0].0),
        Some(i) => {
            let ((ta, a), (tb, b)) = (k[i - 1], k[i]);
            a + (b - a) * ((t - ta) / (tb - ta))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Motion;
    use hinge_core::nalgebra::Vector3;

    #[test]
    fn directions_follow_the_points() {
        let motions = [
            Motion::Fixed,
            Motion::Translation(Vector3::new(0.1, -0.2, 0.3)),
            Motion::Rotation {
                center: Vector3::new(0.5, 0.0, -1.0),
                axis: Vector3::new(1.0, 2.0, 2.0) / 3.0,
                angular_velocity: 0.7,
            },
            Motion::Keyframes(vec![
                (0.5, Vector3::new(0.0, 0.0, 1.0)),
                (1.0, Vector3::new(1.0, 0.0, 1.0)),
            ]),
        ];
        let (p, d) = (Vector3::new(0.3, 0.4, 0.5), Vector3::new(-0.2, 0.1, 0.9));
        for m in &motions {
            for t in [0.0, 0.25, 0.75, 3.0] {
                let moved = m.target(p + d, t) - m.target(p, t);
                assert!((moved - m.direction(d, t)).norm() < 1e-15, "{m:?} at {t}");
            }
            assert_eq!(m.target(p, 0.0), p);
        }
        // Keyframes: linear from zero to the first, between keyframes, held after the last.
        let k = &motions[3];
        assert!((k.target(p, 0.25) - p - Vector3::new(0.0, 0.0, 0.5)).norm() < 1e-15);
        assert!((k.target(p, 0.75) - p - Vector3::new(0.5, 0.0, 1.0)).norm() < 1e-15);
        assert_eq!(k.target(p, 9.0) - p, Vector3::new(1.0, 0.0, 1.0));
    }
}
