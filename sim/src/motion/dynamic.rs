//! A [`Physics`] backend driven along a route: the dynamic motion model.
//!
//! # Stepping
//! The physics advances on a fixed grid `t_k = start + k·dt` (`dt = 1/motion.step_hz`).
//! At every controller tick (`motion.controller_hz`, dividing the step rate) the
//! [`RouteFollower`] turns the robot's true planar state into a body twist command. A
//! yaw-rate loop adds `k_I·∫(ω_cmd − ω_meas)` to the commanded turn rate (gyro feedback,
//! `physics.yaw_rate_gain_per_s`), as skid-steer controllers do to overcome lateral skid;
//! the drive's nominal inverse kinematics gives joint speed targets, scaled down together
//! to the joints' speed limits. Every physics step the joint speed references ramp
//! towards the targets at the joints' acceleration limits (all joints reaching their
//! targets together, so the direction of motion holds during ramps).
//!
//! # Truth at any time
//! A backend's velocities are the mean velocities over each step (symplectic Euler), i.e.
//! the velocities at the half steps `t_{k−½}`. The truth at `t ∈ [t_k, t_{k+1})` is:
//! - pose: linear in position and spherical-linear in rotation between the poses at
//!   `t_k` and `t_{k+1}` (exact for the integrator's constant-velocity step);
//! - velocity, angular velocity and drive-joint speeds: piecewise linear through the
//!   half-step values, so `v(t_k) = (v_k + v_{k+1})/2`;
//! - acceleration and angular acceleration: constant between half steps,
//!   `(v_{k+1} − v_k)/dt` around `t_k`.
//!
//! Integrating the truth's acceleration over any interval therefore reproduces its
//! velocity change exactly, which is what the interval-averaging IMU measures. Steps are
//! taken up to two ahead of the latest query; the trajectory is a function of time only,
//! not of the query schedule.
//!
//! # End of the run
//! [`MotionModel::finished`] turns true `motion.still_after_s` after the follower has
//! arrived and stopped, or as soon as the robot has made no progress along its route for
//! `physics.stuck_timeout_s` while it should have been driving (for example blocked by a
//! post): then [`MotionModel::outcome`] is [`MotionOutcome::Stuck`].
//!
//! # Physics failures
//! After every physics step the body state is checked. A non-finite pose, velocity or
//! joint speed, a speed above [`MAX_BODY_SPEED_MPS`], an angular speed above
//! [`MAX_BODY_RATE_RADPS`] or an acceleration (velocity change over one step) above
//! [`MAX_BODY_ACCEL_MPS2`] means the integration has diverged (an unphysical robot, a
//! contact blow-up): the run ends at that step with [`MotionOutcome::PhysicsDiverged`],
//! and the truth holds the last valid pose at rest from there on (nothing non-finite
//! reaches the sensors). A body z axis more than [`TIP_OVER_TILT_DEG`] from the vertical
//! for [`TIP_OVER_HOLD_S`] means the robot tipped over: the run ends with
//! [`MotionOutcome::TippedOver`]. Both make the run fail.

use super::{MotionModel, MotionOutcome, Steering};
use crate::control::{FollowPhase, PlanarState, RouteFollower, TwistCommand};
use crate::params::{MotionParams, ParamError, PhysicsParams, require_in};
use crate::physics::{CollisionEvent, Physics};
use crate::robot::{Drive, DriveKinematics, MAX_DRIVE_JOINTS, RobotModel};
use crate::route::Route;
use crate::truth::TruthSample;
use crate::world::Surface;
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};
use std::collections::VecDeque;
use vinebench_msgs::Nanos;

/// Progress along the route that counts as moving on, m (the stuck detector).
pub const PROGRESS_STEP_M: f64 = 0.05;
/// Extra time for the drive to settle after the route, s, in the expected duration.
const SETTLE_S: f64 = 2.0;
/// Fastest the robot body may move, m/s (180 km/h: no field robot comes close); faster
/// means the physics diverged.
pub const MAX_BODY_SPEED_MPS: f64 = 50.0;
/// Fastest the robot body may turn, rad/s (about 8 turns a second).
pub const MAX_BODY_RATE_RADPS: f64 = 50.0;
/// Largest acceleration of the body origin over one physics step, m/s² (about 1000 g;
/// a hard collision with a post at cruise speed stays far below).
pub const MAX_BODY_ACCEL_MPS2: f64 = 10_000.0;
/// Tilt of the body z axis from the vertical beyond which the robot counts as tipped
/// over, degrees: terrain slopes stay below 45°
/// ([`crate::world::terrain::MAX_SLOPE_DEG`]), so a robot standing on its tracks or
/// wheels stays well inside it.
pub const TIP_OVER_TILT_DEG: f64 = 75.0;
/// How long the tilt must stay beyond [`TIP_OVER_TILT_DEG`] before the run ends, s.
pub const TIP_OVER_HOLD_S: f64 = 1.0;

/// One committed physics step.
#[derive(Clone, Debug)]
struct Grid {
    index: u64,
    pose: Isometry3<f64>,
    /// Mean velocity of the body origin over the step ending here, world.
    velocity: Vector3<f64>,
    /// Mean angular velocity over the step ending here, world.
    angular_velocity: Vector3<f64>,
    /// Drive joint speeds over the step ending here.
    joints: [f64; MAX_DRIVE_JOINTS],
    /// Path length of the body origin up to here, m.
    odometer_m: f64,
}

#[derive(Copy, Clone, Debug, PartialEq)]
enum Phase {
    Waiting,
    Driving,
    Arrived {
        step: u64,
    },
    Stuck {
        step: u64,
    },
    /// The physics diverged at this step (see [`Dynamic::divergence`]).
    Diverged {
        step: u64,
    },
    /// Tipped over: tilted beyond the bound since `since`, declared at `step`.
    TippedOver {
        step: u64,
        since: u64,
        tilt_deg: f64,
    },
}

/// The drive controller between a twist command and the motors: yaw-rate loop, inverse
/// kinematics, speed limits and acceleration ramps (see the module documentation).
#[derive(Clone, Debug)]
pub struct DriveController {
    kinematics: DriveKinematics,
    joint_count: usize,
    max_speed_radps: [f64; MAX_DRIVE_JOINTS],
    max_accel_radps2: [f64; MAX_DRIVE_JOINTS],
    yaw_gain_per_s: f64,
    max_yaw_rate_radps: f64,
    yaw_integral_rad: f64,
    targets_radps: [f64; MAX_DRIVE_JOINTS],
    refs_radps: [f64; MAX_DRIVE_JOINTS],
}

impl DriveController {
    /// A controller for `robot`'s drive, at rest. `yaw_gain_per_s` is the yaw-rate loop's
    /// integral gain (0: open loop); its integral is limited to what adds
    /// `max_yaw_rate_radps`.
    pub fn new(robot: &RobotModel, yaw_gain_per_s: f64, max_yaw_rate_radps: f64) -> Self {
        let joints = robot.drive.joints();
        let mut max_speed_radps = [0.0; MAX_DRIVE_JOINTS];
        let mut max_accel_radps2 = [0.0; MAX_DRIVE_JOINTS];
        for (i, j) in joints.iter().enumerate() {
            max_speed_radps[i] = j.max_speed_radps;
            max_accel_radps2[i] = j.max_accel_radps2;
        }
        DriveController {
            kinematics: robot.drive.kinematics(),
            joint_count: joints.len(),
            max_speed_radps,
            max_accel_radps2,
            yaw_gain_per_s,
            max_yaw_rate_radps,
            yaw_integral_rad: 0.0,
            targets_radps: [0.0; MAX_DRIVE_JOINTS],
            refs_radps: [0.0; MAX_DRIVE_JOINTS],
        }
    }

    /// A new twist command, with the body's measured yaw rate (gyro, rad/s) and the time
    /// since the last command (s): updates the joint speed targets.
    pub fn command(&mut self, command: &TwistCommand, measured_yaw_rate_radps: f64, period_s: f64) {
        let wz = if *command == TwistCommand::default() {
            self.yaw_integral_rad = 0.0;
            0.0
        } else {
            let limit = if self.yaw_gain_per_s > 0.0 {
                self.max_yaw_rate_radps / self.yaw_gain_per_s
            } else {
                0.0
            };
            self.yaw_integral_rad = (self.yaw_integral_rad
                + (command.wz_radps - measured_yaw_rate_radps) * period_s)
                .clamp(-limit, limit);
            command.wz_radps + self.yaw_gain_per_s * self.yaw_integral_rad
        };
        let mut targets = self
            .kinematics
            .joint_speeds(command.vx_mps, command.vy_mps, wz);
        let mut scale = 1.0f64;
        for (t, max) in targets
            .iter()
            .zip(&self.max_speed_radps)
            .take(self.joint_count)
        {
            if t.abs() > *max {
                scale = scale.min(max / t.abs());
            }
        }
        for t in targets.iter_mut() {
            *t *= scale;
        }
        self.targets_radps = targets;
    }

    /// Joint speed references for the next step of `dt` seconds: one step closer to the
    /// targets at the joints' acceleration limits, all joints arriving together.
    pub fn references(&mut self, dt: f64) -> [f64; MAX_DRIVE_JOINTS] {
        let mut fraction = 1.0f64;
        for i in 0..self.joint_count {
            let d = (self.targets_radps[i] - self.refs_radps[i]).abs();
            if d > 0.0 {
                fraction = fraction.min(self.max_accel_radps2[i] * dt / d);
            }
        }
        for i in 0..self.joint_count {
            self.refs_radps[i] += fraction * (self.targets_radps[i] - self.refs_radps[i]);
        }
        self.refs_radps
    }
}

/// A robot in a [`Physics`] backend following a route. See the module documentation.
pub struct Dynamic<P: Physics> {
    physics: P,
    follower: RouteFollower,
    drive: DriveController,
    start: Nanos,
    step: Nanos,
    step_s: f64,
    control_every: u64,
    drive_start_step: u64,
    still_after_steps: u64,
    stuck_steps: u64,
    grids: VecDeque<Grid>,
    phase: Phase,
    progress_mark: (f64, u64),
    collisions: Vec<CollisionEvent>,
    latest: Nanos,
    expected: Nanos,
    /// Why the physics diverged (empty unless it did).
    divergence: String,
    /// The step since which the tilt has been beyond [`TIP_OVER_TILT_DEG`].
    tilted_since: Option<u64>,
    /// Steps of [`TIP_OVER_HOLD_S`].
    tip_hold_steps: u64,
    /// What the follower steers on (closed loop).
    steering: Steering,
}

/// The robot standing on `surface` at `xy` with heading `yaw_rad`: body z along the
/// ground normal, `base_link` `height_m` above the ground along it.
pub fn standing_pose<S: Surface>(
    surface: &S,
    xy: Vector2<f64>,
    yaw_rad: f64,
    height_m: f64,
) -> Isometry3<f64> {
    let g = surface.sample(xy.x, xy.y);
    let n = g.normal();
    let heading = Vector3::new(yaw_rad.cos(), yaw_rad.sin(), 0.0);
    let x_b = (heading - n * n.dot(&heading)).normalize();
    let y_b = n.cross(&x_b);
    let rot = Rotation3::from_basis_unchecked(&[x_b, y_b, n]);
    Isometry3::from_parts(
        Translation3::from(Vector3::new(xy.x, xy.y, g.height_m) + n * height_m),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// Static sinkage of a robot on its ground-contact springs (`m·g/Σkp`), m.
pub fn static_sinkage_m(robot: &RobotModel, gravity_mps2: f64) -> f64 {
    let k: f64 = match &robot.drive {
        Drive::Tracked(t) => t.left.contact.stiffness_n_per_m + t.right.contact.stiffness_n_per_m,
        Drive::Mecanum(m) => m.wheels.iter().map(|w| w.contact.stiffness_n_per_m).sum(),
    };
    robot.inertia.mass_kg * gravity_mps2 / k
}

impl<P: Physics> Dynamic<P> {
    /// A robot at rest at the start of `route` from time `start`; `make_physics` builds
    /// the backend with the robot at the given start pose (standing on `surface` at its
    /// static sinkage).
    ///
    /// Fails with the `motion.*`/`physics.*` path of the first unusable parameter.
    #[allow(clippy::too_many_arguments)]
    pub fn new<S: Surface>(
        params: &MotionParams,
        physics_params: &PhysicsParams,
        route: Route,
        robot: &RobotModel,
        surface: &S,
        gravity_mps2: f64,
        start: Nanos,
        make_physics: impl FnOnce(&Isometry3<f64>) -> Result<P, ParamError>,
    ) -> Result<Dynamic<P>, ParamError> {
        let step_hz = require_in("motion.step_hz", params.step_hz, 100.0, 100_000.0)?;
        let step = Nanos::period_of_hz(step_hz);
        if (step.as_secs_f64() * step_hz - 1.0).abs() > 1e-9 {
            return Err(ParamError::new(
                "motion.step_hz",
                "a rate whose period is a whole number of nanoseconds (e.g. 500, 1000, 2000)",
                step_hz,
            ));
        }
        let control_every = super::steps_per_tick(step_hz, params.controller_hz)?;
        let step_s = step.as_secs_f64();
        let period_s = step_s * control_every as f64;
        let still_before = require_in("motion.still_before_s", params.still_before_s, 0.0, 1e6)?;
        let still_after = require_in("motion.still_after_s", params.still_after_s, 0.0, 1e6)?;
        let follower = RouteFollower::new(route, params, robot.drive.is_holonomic(), period_s)?;
        let sinkage = static_sinkage_m(robot, gravity_mps2);
        let start_xy = follower.route().points[0];
        let pose = standing_pose(
            surface,
            start_xy,
            follower.start_heading_rad(),
            robot.geometry.ride_height_m - sinkage,
        );
        let physics = make_physics(&pose)?;
        let still_steps = (still_before / step_s).ceil() as u64;
        let drive_start_step = still_steps.div_ceil(control_every) * control_every;
        let expected_s = still_before + follower.expected_duration_s() + still_after + SETTLE_S;
        let mut grids = VecDeque::with_capacity(4);
        grids.push_back(Grid {
            index: 0,
            pose,
            velocity: Vector3::zeros(),
            angular_velocity: Vector3::zeros(),
            joints: [0.0; MAX_DRIVE_JOINTS],
            odometer_m: 0.0,
        });
        Ok(Dynamic {
            physics,
            follower,
            drive: DriveController::new(
                robot,
                physics_params.yaw_rate_gain_per_s,
                params.max_yaw_rate_radps,
            ),
            start,
            step,
            step_s,
            control_every,
            drive_start_step,
            still_after_steps: (still_after / step_s).round() as u64,
            stuck_steps: (physics_params.stuck_timeout_s / step_s).ceil() as u64,
            grids,
            phase: Phase::Waiting,
            progress_mark: (0.0, 0),
            collisions: Vec::new(),
            latest: start,
            expected: Nanos::from_secs_f64(expected_s),
            divergence: String::new(),
            tilted_since: None,
            tip_hold_steps: (TIP_OVER_HOLD_S / step_s).ceil() as u64,
            steering: Steering::Truth,
        })
    }

    /// The physics backend.
    pub fn physics(&self) -> &P {
        &self.physics
    }

    /// The route follower.
    pub fn follower(&self) -> &RouteFollower {
        &self.follower
    }

    fn newest(&self) -> &Grid {
        // The deque always holds at least the start state.
        &self.grids[self.grids.len() - 1]
    }

    fn time_of(&self, step: u64) -> Nanos {
        self.start + Nanos(self.step.0 * step as i64)
    }

    /// A controller tick at the newest grid state.
    fn control(&mut self) {
        let g = self.newest().clone();
        let k = g.index;
        if self.phase == Phase::Waiting && k >= self.drive_start_step {
            self.phase = Phase::Driving;
            self.progress_mark = (self.follower.progress_m(), k);
        }
        let truth = PlanarState {
            xy: g.pose.translation.vector.xy(),
            yaw_rad: crate::control::heading_rad(&g.pose),
            velocity: g.velocity.xy(),
        };
        // Closed loop: the follower steers on the estimate predicted to this tick; without
        // one yet, or stopped by the safety layer, the drive gets a zero command.
        let steer_on = match self.steering {
            Steering::Truth => Some(truth),
            Steering::Estimate(fix) => fix.map(|f| f.at(self.time_of(k))),
            Steering::Stop => None,
        };
        let command = if self.phase == Phase::Driving
            && let Some(state) = steer_on
        {
            let cmd = self.follower.update(&state);
            let progress = self.follower.progress_m();
            if progress > self.progress_mark.0 + PROGRESS_STEP_M {
                self.progress_mark = (progress, k);
            }
            if self.follower.phase() == FollowPhase::Arrived {
                self.phase = Phase::Arrived { step: k };
                TwistCommand::default()
            } else if k - self.progress_mark.1 > self.stuck_steps {
                self.phase = Phase::Stuck { step: k };
                TwistCommand::default()
            } else {
                cmd
            }
        } else {
            TwistCommand::default()
        };
        let period = self.step_s * self.control_every as f64;
        let yaw_rate = (g.pose.rotation.inverse() * g.angular_velocity).z;
        self.drive.command(&command, yaw_rate, period);
    }

    /// Why the state after a step is not physical (see the module documentation), or
    /// `None`.
    fn divergence(
        &self,
        body: &crate::physics::BodyState,
        joints: &[crate::physics::JointState],
    ) -> Option<String> {
        let p = &body.world_from_body;
        let finite = p.translation.vector.iter().all(|c| c.is_finite())
            && p.rotation.coords.iter().all(|c| c.is_finite())
            && body.velocity_in_world.iter().all(|c| c.is_finite())
            && body.angular_velocity_in_world.iter().all(|c| c.is_finite())
            && joints.iter().all(|j| j.speed_radps.is_finite());
        if !finite {
            return Some(
                "the body pose, velocity or a drive joint speed is not finite (NaN or infinite)"
                    .to_string(),
            );
        }
        let speed = body.velocity_in_world.norm();
        if speed > MAX_BODY_SPEED_MPS {
            return Some(format!(
                "body speed {speed:.4e} m/s above MAX_BODY_SPEED_MPS = {MAX_BODY_SPEED_MPS} m/s"
            ));
        }
        let rate = body.angular_velocity_in_world.norm();
        if rate > MAX_BODY_RATE_RADPS {
            return Some(format!(
                "body angular speed {rate:.4e} rad/s above MAX_BODY_RATE_RADPS = \
                 {MAX_BODY_RATE_RADPS} rad/s"
            ));
        }
        let accel = (body.velocity_in_world - self.newest().velocity).norm() / self.step_s;
        if accel > MAX_BODY_ACCEL_MPS2 {
            return Some(format!(
                "body acceleration {accel:.4e} m/s² above MAX_BODY_ACCEL_MPS2 = \
                 {MAX_BODY_ACCEL_MPS2} m/s²"
            ));
        }
        None
    }

    /// After a divergence: the last valid pose at rest, one more step along the grid.
    fn hold(&mut self) {
        let prev = self.newest().clone();
        self.grids.push_back(Grid {
            index: prev.index + 1,
            velocity: Vector3::zeros(),
            angular_velocity: Vector3::zeros(),
            joints: [0.0; MAX_DRIVE_JOINTS],
            ..prev
        });
        while self.grids.len() > 4 {
            self.grids.pop_front();
        }
    }

    /// Tracks the tilt after step `k`: declares the robot tipped over once it has been
    /// beyond [`TIP_OVER_TILT_DEG`] for [`TIP_OVER_HOLD_S`].
    fn watch_tilt(&mut self, k: u64, pose: &Isometry3<f64>) {
        let up = (pose.rotation * Vector3::z()).z.clamp(-1.0, 1.0);
        let tilt_deg = up.acos().to_degrees();
        if tilt_deg <= TIP_OVER_TILT_DEG {
            self.tilted_since = None;
            return;
        }
        let since = *self.tilted_since.get_or_insert(k);
        let done = matches!(
            self.phase,
            Phase::Stuck { .. } | Phase::Diverged { .. } | Phase::TippedOver { .. }
        );
        if !done && k - since >= self.tip_hold_steps {
            self.phase = Phase::TippedOver {
                step: k,
                since,
                tilt_deg,
            };
        }
    }

    /// Commits one physics step.
    fn step_once(&mut self) {
        let k = self.newest().index;
        if matches!(self.phase, Phase::Diverged { .. }) {
            self.hold();
            return;
        }
        if k.is_multiple_of(self.control_every) {
            self.control();
        }
        let refs = self.drive.references(self.step_s);
        self.physics.step(&refs);
        let body = self.physics.body();
        let joints = self.physics.joints();
        if let Some(reason) = self.divergence(&body, &joints) {
            self.phase = Phase::Diverged { step: k + 1 };
            self.divergence = reason;
            self.hold();
            return;
        }
        self.watch_tilt(k + 1, &body.world_from_body);
        let prev = self.newest();
        let odometer_m = prev.odometer_m
            + (body.world_from_body.translation.vector - prev.pose.translation.vector).norm();
        let time_s = (k + 1) as f64 * self.step_s;
        let before = self.collisions.len();
        self.physics.take_collisions(&mut self.collisions);
        for c in &mut self.collisions[before..] {
            c.time_s = time_s;
        }
        let mut speeds = [0.0; MAX_DRIVE_JOINTS];
        for (s, j) in speeds.iter_mut().zip(joints.iter()) {
            *s = j.speed_radps;
        }
        self.grids.push_back(Grid {
            index: k + 1,
            pose: body.world_from_body,
            velocity: body.velocity_in_world,
            angular_velocity: body.angular_velocity_in_world,
            joints: speeds,
            odometer_m,
        });
        while self.grids.len() > 4 {
            self.grids.pop_front();
        }
    }

    fn grid(&self, index: u64) -> &Grid {
        let first = self.grids[0].index;
        let i = (index.saturating_sub(first) as usize).min(self.grids.len() - 1);
        &self.grids[i]
    }
}

impl<P: Physics> MotionModel for Dynamic<P> {
    fn advance_to(&mut self, t: Nanos) -> TruthSample {
        let since = (t - self.start).0.max(0);
        let k = (since / self.step.0) as u64;
        while self.newest().index < k + 2 {
            self.step_once();
        }
        self.latest = self.latest.max(t);
        let f = (since - self.step.0 * k as i64) as f64 / self.step.0 as f64;
        let (a, b, c) = (self.grid(k), self.grid(k + 1), self.grid(k + 2));
        let position = a
            .pose
            .translation
            .vector
            .lerp(&b.pose.translation.vector, f);
        let rotation = a.pose.rotation.slerp(&b.pose.rotation, f);
        // Half-step values: a's are at t_{k−½}, b's at t_{k+½}, c's at t_{k+3/2}.
        let (lo, hi, g) = if f < 0.5 {
            (a, b, f + 0.5)
        } else {
            (b, c, f - 0.5)
        };
        let lerp = |x: &Vector3<f64>, y: &Vector3<f64>| x + (y - x) * g;
        let velocity = lerp(&lo.velocity, &hi.velocity);
        let acceleration = (hi.velocity - lo.velocity) / self.step_s;
        let omega_world = lerp(&lo.angular_velocity, &hi.angular_velocity);
        let alpha_world = (hi.angular_velocity - lo.angular_velocity) / self.step_s;
        let mut drive = [0.0; MAX_DRIVE_JOINTS];
        for (i, d) in drive.iter_mut().enumerate() {
            *d = lo.joints[i] + (hi.joints[i] - lo.joints[i]) * g;
        }
        TruthSample {
            stamp: t,
            world_from_body: Isometry3::from_parts(Translation3::from(position), rotation),
            velocity_in_world: velocity,
            acceleration_in_world: acceleration,
            angular_velocity_in_body: rotation.inverse() * omega_world,
            angular_acceleration_in_body: rotation.inverse() * alpha_world,
            drive_speeds_radps: drive,
            odometer_m: a.odometer_m + (b.odometer_m - a.odometer_m) * f,
        }
    }

    fn start_time(&self) -> Nanos {
        self.start
    }

    fn finished(&self) -> bool {
        match self.phase {
            Phase::Arrived { step } => self.latest >= self.time_of(step + self.still_after_steps),
            Phase::Stuck { step } | Phase::Diverged { step } | Phase::TippedOver { step, .. } => {
                self.latest >= self.time_of(step)
            }
            _ => false,
        }
    }

    fn expected_duration(&self) -> Nanos {
        self.expected
    }

    fn outcome(&self) -> MotionOutcome {
        match self.phase {
            Phase::Stuck { step } if self.latest >= self.time_of(step) => MotionOutcome::Stuck {
                at_s: step as f64 * self.step_s,
                progress_m: self.follower.progress_m(),
            },
            Phase::Arrived { .. } if self.finished() => MotionOutcome::Completed,
            Phase::Diverged { step } if self.latest >= self.time_of(step) => {
                MotionOutcome::PhysicsDiverged {
                    at_s: step as f64 * self.step_s,
                    reason: self.divergence.clone(),
                }
            }
            Phase::TippedOver {
                step,
                since,
                tilt_deg,
            } if self.latest >= self.time_of(step) => MotionOutcome::TippedOver {
                at_s: step as f64 * self.step_s,
                tilted_at_s: since as f64 * self.step_s,
                tilt_deg,
            },
            _ => MotionOutcome::Running,
        }
    }

    fn collisions(&self) -> &[CollisionEvent] {
        &self.collisions
    }

    fn supports_steering(&self) -> bool {
        true
    }

    fn set_steering(&mut self, steering: Steering) {
        self.steering = steering;
    }
}

#[cfg(test)]
mod tests;
