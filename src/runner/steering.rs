//! Closed loop: the route follower steers on an estimate source instead of the truth
//! (`[control] localization`), with a robot's safety layer.
//!
//! **What the robot has at a control tick.** After the messages that arrived by time `t`
//! are delivered, the steering source's newest output pose (its stamp is the stamp of
//! the message that produced it) becomes *available* at `t + estimate_latency_ms` (the
//! processing time the robot's computer would need). At each later control tick the
//! follower takes the newest available pose and predicts it to the tick with the
//! velocity and yaw rate between that pose and the previous one (a robot's controller
//! does the same with a pose that is a few tens of ms old). Availability is defined by
//! stamps, arrival times and the modelled latency only, never by how fast this machine
//! computed anything, so a closed-loop run is as deterministic as an open-loop one.
//!
//! **Frames.** The estimators' outputs are `world_from_body` in the world's ENU frame:
//! the EIF and the GNSS source work in the local ENU frame of the scenario's `[origin]`,
//! the tracking camera is anchored on the GNSS pose at its first fix. The route is given
//! in world coordinates, i.e. surveyed in that same ENU frame, as a robot would have its
//! rows mapped with RTK GNSS. (A source in another frame would need the route expressed
//! in it; none of the estimators has one.)
//!
//! `estimate_offset_m` adds a known error to every steering estimate (for experiments on
//! localization bias).
//!
//! **Safety layer.** The robot is stopped (zero command; the run ends when it stands) when
//! the newest available estimate is older than `max_estimate_age_ms` at a tick after
//! the route's start (also when there has been none by then), giving
//! [`SteeringStop::EstimateLost`]; or, with `max_position_sigma_m > 0`, when its
//! reported horizontal position σ (the larger axis of the 2×2 position covariance)
//! exceeds the bound: [`SteeringStop::Uncertain`]. A source without covariance is never
//! stopped by the second rule: an over-confident filter keeps driving, which is the
//! point of measuring it.

use super::outcome::SteeringStop;
use crate::scenario::ControlParams;
use nalgebra::{Matrix2, Vector2};
use std::collections::VecDeque;
use vinebench_msgs::{Nanos, PoseSample};
use vinebench_onboard::estimator::{EstimatorKind, EstimatorSet};
use vinebench_sim::control::{PlanarState, heading_rad};
use vinebench_sim::motion::{MotionModel, Steering, SteeringFix};

/// The robot is considered standing (the run ends after a safety stop) below this
/// horizontal speed, m/s.
pub const STANDING_MPS: f64 = 0.01;
/// A safety stop ends the run at the latest this long after it was decided, s.
pub const STOP_SETTLE_S: f64 = 10.0;

/// A pose the robot will have, from when.
#[derive(Clone, Copy, Debug)]
struct Pending {
    available: Nanos,
    fix: SteeringFix,
    sigma_m: Option<f64>,
}

/// The closed loop of one run: which estimate the follower steers on, and when the
/// safety layer stops the robot. See the module documentation.
#[derive(Debug)]
pub struct SteeringLoop {
    kind: EstimatorKind,
    latency: Nanos,
    max_age: Nanos,
    max_sigma_m: f64,
    offset: Vector2<f64>,
    start: Nanos,
    drive_start: Nanos,
    /// Stamp of the newest pose seen from the source.
    seen: Option<Nanos>,
    /// The previous pose seen (for velocity and yaw rate).
    previous: Option<PoseSample>,
    pending: VecDeque<Pending>,
    current: Option<Pending>,
    stop: Option<(Nanos, SteeringStop)>,
}

/// Horizontal position σ of a pose covariance: the square root of the larger eigenvalue
/// of its 2×2 east-north block.
pub fn horizontal_sigma_m(s: &PoseSample) -> Option<f64> {
    let c = s.covariance.as_deref()?;
    let m = Matrix2::new(c[(0, 0)], c[(0, 1)], c[(1, 0)], c[(1, 1)]);
    let (a, d, b) = (m[(0, 0)], m[(1, 1)], 0.5 * (m[(0, 1)] + m[(1, 0)]));
    let largest = 0.5 * (a + d) + (0.25 * (a - d).powi(2) + b * b).sqrt();
    Some(largest.max(0.0).sqrt())
}

impl SteeringLoop {
    /// The closed loop of `[control]` (`None` for `localization = "truth"`): `kind` is
    /// the steering source; the route starts at `drive_start`.
    pub fn new(
        p: &ControlParams,
        kind: EstimatorKind,
        start: Nanos,
        drive_start: Nanos,
    ) -> SteeringLoop {
        SteeringLoop {
            kind,
            latency: Nanos::from_secs_f64(p.estimate_latency_ms / 1e3),
            max_age: Nanos::from_secs_f64(p.max_estimate_age_ms / 1e3),
            max_sigma_m: p.max_position_sigma_m,
            offset: Vector2::new(p.estimate_offset_m[0], p.estimate_offset_m[1]),
            start,
            drive_start,
            seen: None,
            previous: None,
            pending: VecDeque::new(),
            current: None,
            stop: None,
        }
    }

    /// After the messages that arrived by `t` were delivered: the source's newest pose, if
    /// new, becomes available at `t + latency`.
    pub fn observe(&mut self, t: Nanos, estimators: &EstimatorSet) {
        let Some(newest) = estimators
            .trajectory(self.kind)
            .and_then(|tr| tr.samples.last())
        else {
            return;
        };
        if self.seen.is_some_and(|s| newest.stamp <= s) {
            return;
        }
        self.seen = Some(newest.stamp);
        let xy = newest.world_from_body.translation.vector.xy();
        let yaw = heading_rad(&newest.world_from_body);
        let (velocity, yaw_rate) = match &self.previous {
            Some(p) => {
                let dt = (newest.stamp - p.stamp).as_secs_f64();
                let pxy = p.world_from_body.translation.vector.xy();
                let dyaw =
                    vinebench_sim::control::wrap_angle(yaw - heading_rad(&p.world_from_body));
                ((xy - pxy) / dt, dyaw / dt)
            }
            None => (Vector2::zeros(), 0.0),
        };
        self.pending.push_back(Pending {
            available: t + self.latency,
            fix: SteeringFix {
                stamp: newest.stamp,
                state: PlanarState {
                    xy: xy + self.offset,
                    yaw_rad: yaw,
                    velocity,
                },
                yaw_rate_radps: yaw_rate,
            },
            sigma_m: horizontal_sigma_m(newest),
        });
        self.previous = Some(newest.clone());
    }

    /// Before the motion advances past `t`: hands the follower what the robot has at `t`,
    /// or stops it. Returns the stop when it is decided now.
    pub fn steer(&mut self, t: Nanos, motion: &mut dyn MotionModel) -> Option<SteeringStop> {
        while self.pending.front().is_some_and(|p| p.available <= t) {
            self.current = self.pending.pop_front();
        }
        if self.stop.is_some() {
            motion.set_steering(Steering::Stop);
            return None;
        }
        let at_s = (t - self.start).as_secs_f64();
        let decided = if t < self.drive_start {
            None
        } else {
            match self.current {
                None if t - self.drive_start > self.max_age => Some(SteeringStop::EstimateLost {
                    at_s,
                    age_s: f64::INFINITY,
                }),
                Some(c) if t - c.fix.stamp > self.max_age => Some(SteeringStop::EstimateLost {
                    at_s,
                    age_s: (t - c.fix.stamp).as_secs_f64(),
                }),
                Some(Pending {
                    sigma_m: Some(sigma_m),
                    ..
                }) if self.max_sigma_m > 0.0 && sigma_m > self.max_sigma_m => {
                    Some(SteeringStop::Uncertain { at_s, sigma_m })
                }
                _ => None,
            }
        };
        if let Some(stop) = decided {
            self.stop = Some((t, stop.clone()));
            motion.set_steering(Steering::Stop);
            return Some(stop);
        }
        motion.set_steering(Steering::Estimate(self.current.map(|c| c.fix)));
        None
    }

    /// When the safety layer stopped the robot.
    pub fn stopped_at(&self) -> Option<Nanos> {
        self.stop.as_ref().map(|s| s.0)
    }
}
