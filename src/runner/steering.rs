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
//! A visual SLAM (`slam`, `slam_single_camera`, ...) steers with the pose each rig frame
//! was tracked at (before any later optimisation: what the robot had then). The frame is
//! tracked as soon as its images have arrived ([`VisualSlam::track_waiting`]; the
//! pipelined SLAM would otherwise track it alongside the next image), so its pose too is
//! available at arrival + latency, whatever this machine's speed.
//!
//! **Frames.** The estimators' outputs are `world_from_body` in the world's ENU frame:
//! the EIF and the GNSS source work in the local ENU frame of the scenario's `[origin]`,
//! the tracking camera is anchored on the GNSS pose at its first fix. The route is given
//! in world coordinates, i.e. surveyed in that same ENU frame, as a robot would have its
//! rows mapped with RTK GNSS. A SLAM's map starts at the body pose of its first frame; the
//! robot knows where it was placed (a surveyed start marker: the pose at the run's start,
//! [`SteeringLoop::place`]), so `world_from_map = world_from_start · map_from_body⁻¹` of
//! that first frame, provided the robot had not set off yet. A SLAM whose first map
//! starts later has no known place in the world: the robot never drives on it (and stops
//! by the age rule).
//!
//! `estimate_offset_m` adds a known error to every steering estimate (for experiments on
//! localization bias).
//!
//! **Safety layer.** The robot is stopped (zero command; the run ends when it stands) when
//! the newest available estimate is older than `max_estimate_age_ms` at a tick after
//! the route's start (also when there has been none by then), giving
//! [`SteeringStop::EstimateLost`]; with `stop_on_tracking_lost`, when the source reports
//! tracking lost (a SLAM frame not tracked, or a map restarted after a loss at a
//! dead-reckoned pose), once that report is available: the same outcome, marked
//! `tracking_lost`; or, with `max_position_sigma_m > 0`, when its
//! reported horizontal position σ (the larger axis of the 2×2 position covariance)
//! exceeds the bound: [`SteeringStop::Uncertain`]. A source without covariance is never
//! stopped by the second rule: an over-confident filter keeps driving, which is the
//! point of measuring it.

use super::outcome::SteeringStop;
use crate::scenario::ControlParams;
use nalgebra::{Isometry3, Matrix2, Vector2};
use std::collections::VecDeque;
use vinebench_msgs::{Nanos, PoseSample};
use vinebench_onboard::estimator::{EstimatorKind, EstimatorSet};
use vinebench_onboard::slam::VisualSlam;
use vinebench_onboard::slam::tracking::TrackingState;
use vinebench_sim::control::{PlanarState, heading_rad};
use vinebench_sim::motion::{MotionModel, Steering, SteeringFix};

/// The robot is considered standing (the run ends after a safety stop) below this
/// horizontal speed, m/s.
pub const STANDING_MPS: f64 = 0.01;
/// A safety stop ends the run at the latest this long after it was decided, s.
pub const STOP_SETTLE_S: f64 = 10.0;

/// What the follower steers on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SteeringSource {
    /// An estimator's output (`eif`, `gnss`, `tracking_camera`).
    Estimator(EstimatorKind),
    /// The run's visual SLAM number `.0` (the SLAM or one of its baselines).
    Slam(usize),
}

/// What the robot will have, from when.
#[derive(Clone, Copy, Debug)]
struct Pending {
    available: Nanos,
    /// Stamp of the estimate.
    stamp: Nanos,
    /// The pose (`None`: the source reported tracking lost).
    fix: Option<SteeringFix>,
    sigma_m: Option<f64>,
}

/// Where a SLAM's map lies in the world.
#[derive(Clone, Copy, Debug, PartialEq)]
enum MapPlace {
    /// No map yet.
    Unknown,
    /// `world_from_map`, from the start pose.
    Placed(Isometry3<f64>),
    /// The first map started after the robot had set off.
    Unplaced,
}

/// The closed loop of one run: which estimate the follower steers on, and when the
/// safety layer stops the robot. See the module documentation.
#[derive(Debug)]
pub struct SteeringLoop {
    source: SteeringSource,
    latency: Nanos,
    max_age: Nanos,
    max_sigma_m: f64,
    stop_on_lost: bool,
    offset: Vector2<f64>,
    start: Nanos,
    drive_start: Nanos,
    /// The robot's pose at the start of the run (where it was placed).
    world_from_start: Option<Isometry3<f64>>,
    map: MapPlace,
    /// Stamp of the newest estimate seen from the source.
    seen: Option<Nanos>,
    /// The previous pose seen (stamp, `world_from_body`; for velocity and yaw rate).
    previous: Option<(Nanos, Isometry3<f64>)>,
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
    /// The closed loop of `[control]` (`None` for `localization = "truth"`): `source` is
    /// the steering source; the route starts at `drive_start`.
    pub fn new(
        p: &ControlParams,
        source: SteeringSource,
        start: Nanos,
        drive_start: Nanos,
    ) -> SteeringLoop {
        SteeringLoop {
            source,
            latency: Nanos::from_secs_f64(p.estimate_latency_ms / 1e3),
            max_age: Nanos::from_secs_f64(p.max_estimate_age_ms / 1e3),
            max_sigma_m: p.max_position_sigma_m,
            stop_on_lost: p.stop_on_tracking_lost,
            offset: Vector2::new(p.estimate_offset_m[0], p.estimate_offset_m[1]),
            start,
            drive_start,
            world_from_start: None,
            map: MapPlace::Unknown,
            seen: None,
            previous: None,
            pending: VecDeque::new(),
            current: None,
            stop: None,
        }
    }

    /// The robot's pose at the start of the run, where it was placed (the first call
    /// counts): what anchors a SLAM's map in the world.
    pub fn place(&mut self, world_from_body: &Isometry3<f64>) {
        self.world_from_start.get_or_insert(*world_from_body);
    }

    /// `world_from_map` of a steering SLAM whose map was placed in the world.
    pub fn world_from_map(&self) -> Option<Isometry3<f64>> {
        match self.map {
            MapPlace::Placed(p) => Some(p),
            _ => None,
        }
    }

    /// After the messages that arrived by `t` were delivered: the source's newest
    /// estimate, if new, becomes available at `t + latency`. A steering SLAM first tracks
    /// the frame its images completed.
    pub fn observe(&mut self, t: Nanos, estimators: &EstimatorSet, slam: &mut [VisualSlam]) {
        let (stamp, pose, sigma_m) = match self.source {
            SteeringSource::Estimator(kind) => {
                let Some(newest) = estimators.trajectory(kind).and_then(|tr| tr.samples.last())
                else {
                    return;
                };
                (
                    newest.stamp,
                    Some(newest.world_from_body),
                    horizontal_sigma_m(newest),
                )
            }
            SteeringSource::Slam(i) => {
                let Some(v) = slam.get_mut(i) else {
                    return;
                };
                v.track_waiting();
                let Some(f) = v.last_frame() else {
                    return;
                };
                // (A frame already seen ends below, at the stamp check of every source.)
                let lost = f.state == TrackingState::Lost
                    || (f.initialized && self.map != MapPlace::Unknown);
                let (stamp, pose) = (f.stamp, f.world_from_body);
                match (self.map, pose) {
                    (MapPlace::Unknown, Some(map_from_body)) => {
                        self.map = match self.world_from_start {
                            Some(w) if stamp <= self.drive_start => {
                                MapPlace::Placed(w * map_from_body.inverse())
                            }
                            _ => MapPlace::Unplaced,
                        };
                    }
                    (MapPlace::Unknown, None) => return,
                    _ => {}
                }
                let MapPlace::Placed(world_from_map) = self.map else {
                    return;
                };
                if lost && self.stop_on_lost {
                    (stamp, None, None)
                } else if let Some(p) = pose {
                    (stamp, Some(world_from_map * p), None)
                } else {
                    return;
                }
            }
        };
        if self.seen.is_some_and(|s| stamp <= s) {
            return;
        }
        self.seen = Some(stamp);
        let fix = pose.map(|pose| {
            let xy = pose.translation.vector.xy();
            let yaw = heading_rad(&pose);
            let (velocity, yaw_rate) = match &self.previous {
                Some((pt, p)) => {
                    let dt = (stamp - *pt).as_secs_f64();
                    let pxy = p.translation.vector.xy();
                    let dyaw = vinebench_sim::control::wrap_angle(yaw - heading_rad(p));
                    ((xy - pxy) / dt, dyaw / dt)
                }
                None => (Vector2::zeros(), 0.0),
            };
            self.previous = Some((stamp, pose));
            SteeringFix {
                stamp,
                state: PlanarState {
                    xy: xy + self.offset,
                    yaw_rad: yaw,
                    velocity,
                },
                yaw_rate_radps: yaw_rate,
            }
        });
        self.pending.push_back(Pending {
            available: t + self.latency,
            stamp,
            fix,
            sigma_m,
        });
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
                    tracking_lost: false,
                }),
                Some(Pending {
                    stamp, fix: None, ..
                }) => Some(SteeringStop::EstimateLost {
                    at_s,
                    age_s: (t - stamp).as_secs_f64(),
                    tracking_lost: true,
                }),
                Some(c) if t - c.stamp > self.max_age => Some(SteeringStop::EstimateLost {
                    at_s,
                    age_s: (t - c.stamp).as_secs_f64(),
                    tracking_lost: false,
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
        motion.set_steering(Steering::Estimate(self.current.and_then(|c| c.fix)));
        None
    }

    /// When the safety layer stopped the robot.
    pub fn stopped_at(&self) -> Option<Nanos> {
        self.stop.as_ref().map(|s| s.0)
    }
}
