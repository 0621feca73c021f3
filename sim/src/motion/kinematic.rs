//! Terrain-following kinematic skid-steer driven by pure pursuit.
//!
//! # Model
//! The robot's *planar state* is `(x, y, ψ, v, v̇, r, ṙ)`: the ground contact point
//! (`base_footprint`) in the world's horizontal plane, the heading ψ (ENU yaw of the
//! direction of travel), the horizontal speed `v` and the yaw rate `r = ψ̇`, with their
//! derivatives. Each of `v` and `r` follows its command through a critically damped
//! second-order system with time constant τ = `response_time_s`:
//! `v̈ = (v_cmd - v)/τ² - 2·v̇/τ` (likewise `r`), so `v̇` and `ṙ` are continuous and the
//! ground-truth acceleration and angular rate are continuous in time. The state is
//! integrated with RK4 on a fixed grid of step `1/step_hz` from the start time; commands
//! change only at controller ticks, which lie on the grid (`step_hz / controller_hz`
//! must be an integer), so every RK4 step integrates a smooth right-hand side.
//!
//! Because the impulse response of a critically damped system is non-negative with unit
//! integral, `0 <= v <= max v_cmd <= cruise` and `|r| <= max |r_cmd| <= max_yaw_rate`
//! hold exactly (up to the integrator's rounding), and the command's rate limit
//! `a_max / (1 + T/(e·τ))` (controller period T) bounds `|v̇| <= a_max`.
//!
//! # Controller
//! Pure pursuit: the target is the route point a look-ahead `L` of arc length beyond the
//! current progress (the route's end segment is extended beyond its end), and the
//! commanded path curvature is `κ = 2·y_t/|d|²`, with `d` the vector to the target and
//! `y_t` its component to the left of the heading. Two refinements keep the robot on the
//! route with the drive's lag: the look-ahead scales with speed,
//! `L = lookahead_m · clamp(v/cruise, `[`MIN_LOOKAHEAD_FRACTION`]`, 1)` (so
//! `lookahead_m` is the look-ahead at cruise speed: 1.5 m by default, 1.06 m in the
//! default headland turns), and `d`, `y_t` are taken from the pose predicted one
//! response time τ ahead under the current command. With the defaults this gives
//! 0.2 mm cross-track error on straights, 4.3 cm at most in 1.25 m-radius headland
//! turns, and a row loop that closes within 2 mm (plain pure pursuit with a fixed
//! 1.5 m look-ahead: 10 cm and 3.9 cm).
//!
//! Progress along the route is monotone and searched only within
//! [`PROGRESS_WINDOW_M`] of the previous progress, so the robot is never assigned to the
//! neighbouring lane. The speed command is the minimum of the cruise speed, a
//! precomputed speed profile (curvature limits `√(a_lat/|κ|)` and `r_max/|κ|` over the
//! next `lookahead_m + 2τ·cruise` of route, braked backwards at 0.8 × the command's
//! acceleration limit), the same limits at the current pure-pursuit curvature, and a
//! stop profile `√(2·a·(remaining - roll_out))`, where `roll_out = 2τ·v + τ²·v̇` is the
//! exact distance the drive still rolls if the command drops to zero now. The speed
//! command is then rate limited; the yaw-rate command is `κ · v_cmd`, clamped to
//! `max_yaw_rate_radps` (commanding `κ · v_cmd` rather than `κ · v` gives `r` and `v`
//! the same filter, so the driven curvature `r/v` equals κ in steady state). The
//! controller is planar: the horizontal path does not depend on the terrain.
//!
//! The robot stands still for `still_before_s` (rounded up to a controller tick), drives
//! until the remaining route is within the roll-out distance, stops (`|v|` and `|r|`
//! below 1 mm/s and 1 mrad/s, decaying exponentially afterwards), and reports
//! [`MotionModel::finished`] `still_after_s` later.
//!
//! # 3D ground truth
//! The body follows the terrain `h(x, y)` of a [`Surface`] with gradient `g` and Hessian
//! `H`:
//! - `base_footprint` = `(x, y, h)`; body z = the surface's upward unit normal `n`;
//! - body x = `w/|w|` with `w = (cos ψ, sin ψ, g·u)`, `u = (cos ψ, sin ψ)`: the tangent
//!   vector of the surface that lies *vertically above* the heading (the heading projected
//!   onto the tangent plane along z). The footprint's velocity `v·w` is then exactly along
//!   body x (no side slip, as a skid-steer without lateral skid), and the body's yaw is ψ;
//! - body y = z × x;
//! - `base_link` = footprint + `ride_height · n` (along the body z axis, consistent with
//!   the URDF's fixed `base_link → base_footprint` joint).
//!
//! Velocity and angular velocity are analytic: `ṅ` from `H·ṗ`, `ẋ_b` from
//! `ẇ = (-r·sin ψ, r·cos ψ, (H·ṗ)·u + r·g·u⊥)`, and `ω_body = (ẏ_b·n, ṅ·x_b, ẋ_b·y_b)`
//! (the components of ω in the body axes, from `ė_i = ω × e_i`). The footprint's
//! acceleration is analytic too. The lever term `ride_height · n̈` needs third
//! derivatives of `h`, which a [`Surface`] does not give, and the angular acceleration
//! needs them too: both are central differences of the analytic `ṅ` and `ω` over a
//! `±`[`EXPANSION_STEP_S`] expansion of the planar state integrated (RK4) from the
//! state at the queried time with the command in effect then. That expansion shares the
//! true trajectory's first and second derivatives at the queried time (the command only
//! changes `v̈`, `r̈`), so the result is the exact derivative up to a truncation error
//! `δ²/6 · |d³ṅ/dt³|` (δ²/6 = 1.7e-7 s²; times the ride height for the acceleration) and
//! a rounding error near `ε·|ṅ|/δ ≈ 1e-14`. On a C² spline terrain
//! `n̈` jumps where the third derivatives do (at knot lines); within `δ` of a knot the
//! difference blends the two sides.
//!
//! # Truth at any time
//! [`MotionModel::advance_to`] first commits whole grid steps up to the queried time,
//! then integrates from the last grid state by one RK4 sub-step to the exact time
//! *without committing it*: the truth at `t` is a function of `t` only, whichever other
//! times were queried. The odometer (path length of the `base_link` origin) is
//! integrated with the trapezoid rule on the grid, plus a trapezoid over the sub-step.
//!
//! Speeds and limits (`cruise_speed_mps`, accelerations) apply to the horizontal motion;
//! the 3D speed along the ground is `v·|w|` (1.5 % more on a 10° slope along the path).
//!
//! # Track speeds
//! With ground speed `v_g = v·|w|` along body x and the yaw rate `r_b` about the body z
//! axis, the encoders see `v_{left,right} = v_g/(1 - track_slip) ∓ icr_expansion ·
//! track_width · r_b / 2`, so a naive odometry `(v_r - v_l)/track_width` over-estimates
//! turns by the factor `icr_expansion`, and distance by `1/(1 - track_slip)`, as real
//! skid-steer robots do.

use super::MotionModel;
use crate::params::{MotionParams, ParamError, require_in, require_non_negative, require_positive};
use crate::robot::{DriveKinematics, RobotGeometry};
use crate::route::Route;
use crate::truth::TruthSample;
use crate::world::Surface;
use nalgebra::{
    Isometry3, Matrix3, Rotation3, SVector, Translation3, UnitQuaternion, Vector2, Vector3,
};
use vinebench_msgs::Nanos;

/// Half-width of the central differences giving `n̈` and the angular acceleration, s.
pub const EXPANSION_STEP_S: f64 = 1e-3;
pub use crate::control::PROGRESS_WINDOW_M;
/// The robot stops when the remaining route is within its roll-out distance plus this, m.
const STOP_TOLERANCE_M: f64 = 0.005;
/// Below this horizontal speed (and yaw rate in rad/s) a stopping robot counts as stopped.
const STOPPED_SPEED_MPS: f64 = 1e-3;
/// The pure-pursuit look-ahead shrinks with speed, `lookahead_m · v / cruise`, down to
/// this fraction of `lookahead_m`.
pub const MIN_LOOKAHEAD_FRACTION: f64 = 0.4;
/// Fraction of the command's acceleration limit used to brake in the speed profile, so the
/// rate limiter can follow it.
const PROFILE_ACCEL_FRACTION: f64 = 0.8;
/// Largest integration rate, Hz (a step of at least 1 µs).
const MAX_STEP_HZ: f64 = 1e6;
/// Longest stand-still, s.
const MAX_STILL_S: f64 = 1e6;
/// Extra time for the drive to settle after the route, s, in [`MotionModel::expected_duration`].
const SETTLE_S: f64 = 2.0;

/// Planar state `(x, y, ψ, v, v̇, r, ṙ)`.
type State = SVector<f64, 7>;
const X: usize = 0;
const Y: usize = 1;
const PSI: usize = 2;
const V: usize = 3;
const VDOT: usize = 4;
const R: usize = 5;
const RDOT: usize = 6;

/// Drive commands, constant between controller ticks.
#[derive(Copy, Clone, Debug, PartialEq)]
struct Command {
    /// Horizontal speed, m/s.
    speed_mps: f64,
    /// Yaw rate, rad/s.
    yaw_rate_radps: f64,
}

/// Where the robot is in its run.
#[derive(Copy, Clone, Debug, PartialEq)]
enum Phase {
    /// Standing still before the route.
    Waiting,
    /// Following the route.
    Driving,
    /// At the end of the route, commands zero, still rolling.
    Stopping,
    /// Stopped at `since` (a grid time).
    Stopped { since: Nanos },
}

/// Validated constants of the model.
#[derive(Clone, Debug)]
struct Config {
    tau_s: f64,
    step: Nanos,
    step_s: f64,
    control_every: u64,
    control_period_s: f64,
    drive_start_step: u64,
    cruise_mps: f64,
    max_yaw_rate_radps: f64,
    command_accel_mps2: f64,
    profile_accel_mps2: f64,
    max_lateral_accel_mps2: f64,
    lookahead_m: f64,
    icr_expansion: f64,
    track_slip: f64,
    track_width_m: f64,
    ride_height_m: f64,
    left_radius_m: f64,
    right_radius_m: f64,
    still_after: Nanos,
}

/// Body axes and their rates at one planar state.
struct Frame {
    /// Ground contact (`base_footprint`), world, m.
    foot: Vector3<f64>,
    /// Body x, y, z (= surface normal) in the world.
    x_b: Vector3<f64>,
    y_b: Vector3<f64>,
    n: Vector3<f64>,
    /// Time derivative of `n`, 1/s.
    n_dot: Vector3<f64>,
    /// Angular velocity in the body frame, rad/s.
    omega_body: Vector3<f64>,
    /// Footprint velocity, world, m/s.
    foot_vel: Vector3<f64>,
    /// Footprint acceleration, world, m/s².
    foot_acc: Vector3<f64>,
    /// `|w|`: ground speed per unit horizontal speed.
    w_norm: f64,
}

/// A tracked robot that follows its route with pure pursuit, with ground contact from a
/// [`Surface`]. See the module documentation for the model and its guarantees.
pub struct KinematicSkidSteer<S: Surface> {
    surface: S,
    route: Route,
    /// Speed limit at each route point, m/s.
    speed_profile_mps: Vec<f64>,
    cfg: Config,
    start: Nanos,
    expected: Nanos,
    /// Grid steps committed since `start`.
    step_index: u64,
    /// Planar state at the grid time.
    state: State,
    /// Command in effect from the grid time on.
    command: Command,
    /// Odometer at the grid time, m.
    odometer_m: f64,
    /// Speed of the `base_link` origin at the grid time, m/s.
    base_speed_mps: f64,
    /// Arc length along the route reached, m (monotone).
    progress_m: f64,
    phase: Phase,
    /// Latest queried time.
    latest: Nanos,
}

impl<S: Surface> KinematicSkidSteer<S> {
    /// A robot at the start of `route`, at rest, facing along it, from time `start`.
    ///
    /// Fails with the `motion.*` path of the first unusable parameter (`motion.model`
    /// for a route that reverses, i.e. has cusps: this model only drives forward;
    /// `route` for a route with fewer than two points, `robot` for impossible drive
    /// geometry).
    pub fn new(
        params: &MotionParams,
        route: Route,
        surface: S,
        geometry: &RobotGeometry,
        start: Nanos,
    ) -> Result<Self, ParamError> {
        if !route.cusps_m.is_empty() {
            return Err(ParamError::new(
                "motion.model",
                "`rapier` for a route that reverses (route.waypoints.there_and_back)",
                "kinematic",
            ));
        }
        let cfg = validate(params, geometry)?;
        let consistent = route.len() >= 2
            && route.arc_length_m.len() == route.len()
            && route.curvature_per_m.len() == route.len()
            && route.arc_length_m.windows(2).all(|w| w[1] > w[0])
            && route
                .arc_length_m
                .iter()
                .chain(&route.curvature_per_m)
                .all(|x| x.is_finite())
            && route
                .points
                .iter()
                .all(|p| p.x.is_finite() && p.y.is_finite());
        if !consistent {
            return Err(ParamError::new(
                "route",
                "at least 2 finite points with strictly increasing arc lengths and a \
                 curvature each",
                format!("{} points", route.len()),
            ));
        }
        let speed_profile_mps = speed_profile(&route, &cfg);
        let expected = expected_duration(&route, &speed_profile_mps, &cfg);
        let p0 = route.points[0];
        let t0 = route.tangent_at(0.0);
        let mut state = State::zeros();
        state[X] = p0.x;
        state[Y] = p0.y;
        state[PSI] = t0.y.atan2(t0.x);
        let mut model = KinematicSkidSteer {
            surface,
            route,
            speed_profile_mps,
            cfg,
            start,
            expected,
            step_index: 0,
            state,
            command: Command {
                speed_mps: 0.0,
                yaw_rate_radps: 0.0,
            },
            odometer_m: 0.0,
            base_speed_mps: 0.0,
            progress_m: 0.0,
            phase: Phase::Waiting,
            latest: start,
        };
        model.control();
        Ok(model)
    }

    /// The route being followed.
    pub fn route(&self) -> &Route {
        &self.route
    }

    /// Arc length along the route reached by the controller, m (as of the last committed
    /// controller tick).
    pub fn progress_m(&self) -> f64 {
        self.progress_m
    }

    fn grid_time(&self) -> Nanos {
        self.start + Nanos(self.cfg.step.0 * self.step_index as i64)
    }

    /// One committed grid step, then the controller if the new grid time is a tick.
    fn step(&mut self) {
        self.state = rk4(&self.state, &self.command, self.cfg.tau_s, self.cfg.step_s);
        self.step_index += 1;
        let f = self.frame(&self.state);
        let speed = (f.foot_vel + f.n_dot * self.cfg.ride_height_m).norm();
        self.odometer_m += 0.5 * self.cfg.step_s * (self.base_speed_mps + speed);
        self.base_speed_mps = speed;
        if self.step_index.is_multiple_of(self.cfg.control_every) {
            self.control();
        }
    }

    /// Pure pursuit and speed planning at a controller tick (the grid state is at a tick).
    fn control(&mut self) {
        let c = &self.cfg;
        if matches!(self.phase, Phase::Stopped { .. }) {
            return;
        }
        if self.phase == Phase::Waiting {
            if self.step_index < c.drive_start_step {
                return;
            }
            self.phase = Phase::Driving;
        }
        let s = &self.state;
        let xy = Vector2::new(s[X], s[Y]);
        let found = self
            .route
            .closest_progress(&xy, self.progress_m, PROGRESS_WINDOW_M);
        self.progress_m = self.progress_m.max(found);
        let remaining = self.route.total_length_m() - self.progress_m;
        let roll_out = (2.0 * c.tau_s * s[V] + c.tau_s * c.tau_s * s[VDOT]).max(0.0);

        // Pure pursuit, steering from the pose predicted one response time ahead under
        // the current command (compensating the drive's lag), towards the route point a
        // speed-scaled look-ahead beyond the current progress.
        let mut pred = *s;
        let n_pred = (c.tau_s / c.control_period_s).ceil().max(1.0);
        for _ in 0..n_pred as usize {
            pred = rk4(&pred, &self.command, c.tau_s, c.tau_s / n_pred);
        }
        let pred_xy = Vector2::new(pred[X], pred[Y]);
        let lookahead = c.lookahead_m * (s[V] / c.cruise_mps).clamp(MIN_LOOKAHEAD_FRACTION, 1.0);
        let pred_progress = self.route.closest_progress(
            &pred_xy,
            self.progress_m,
            PROGRESS_WINDOW_M + c.tau_s * s[V].abs(),
        );
        let target = self.route.point_at(
            (self.progress_m + lookahead).max(pred_progress + MIN_LOOKAHEAD_FRACTION * lookahead),
        );
        let (sin_psi, cos_psi) = pred[PSI].sin_cos();
        let d = target - pred_xy;
        let lateral = -sin_psi * d.x + cos_psi * d.y;
        let d2 = d.norm_squared();
        let curvature = if d2 > 1e-12 { 2.0 * lateral / d2 } else { 0.0 };

        if self.phase == Phase::Driving && remaining <= roll_out + STOP_TOLERANCE_M {
            self.phase = Phase::Stopping;
        }
        let target_speed = if self.phase == Phase::Driving {
            let mut v = c
                .cruise_mps
                .min(self.profile_at(self.progress_m))
                .min((2.0 * c.profile_accel_mps2 * (remaining - roll_out).max(0.0)).sqrt());
            let k = curvature.abs();
            if k > 0.0 {
                v = v
                    .min(c.max_yaw_rate_radps / k)
                    .min((c.max_lateral_accel_mps2 / k).sqrt());
            }
            v
        } else {
            0.0
        };
        let dv = c.command_accel_mps2 * c.control_period_s;
        let prev = self.command.speed_mps;
        let speed = target_speed.clamp(prev - dv, prev + dv).max(0.0);
        let yaw_rate = (curvature * speed).clamp(-c.max_yaw_rate_radps, c.max_yaw_rate_radps);
        self.command = Command {
            speed_mps: speed,
            yaw_rate_radps: yaw_rate,
        };

        if self.phase == Phase::Stopping
            && speed == 0.0
            && s[V].abs() < STOPPED_SPEED_MPS
            && s[R].abs() < STOPPED_SPEED_MPS
        {
            self.phase = Phase::Stopped {
                since: self.grid_time(),
            };
        }
    }

    /// The speed profile at arc length `s_m`, linearly interpolated.
    fn profile_at(&self, s_m: f64) -> f64 {
        let a = &self.route.arc_length_m;
        let n = a.len();
        let i = a
            .partition_point(|&x| x <= s_m)
            .saturating_sub(1)
            .min(n - 2);
        let f = ((s_m - a[i]) / (a[i + 1] - a[i])).clamp(0.0, 1.0);
        self.speed_profile_mps[i] + (self.speed_profile_mps[i + 1] - self.speed_profile_mps[i]) * f
    }

    /// Body axes, their rates and the footprint's motion at a planar state.
    fn frame(&self, s: &State) -> Frame {
        let sp = self.surface.sample(s[X], s[Y]);
        let (v, r) = (s[V], s[R]);
        let (sin_psi, cos_psi) = s[PSI].sin_cos();
        let u = Vector2::new(cos_psi, sin_psi);
        let u_perp = Vector2::new(-sin_psi, cos_psi);
        let g = sp.gradient;
        let (gu, gu_perp) = (g.dot(&u), g.dot(&u_perp));
        // Body x: the tangent vector above the heading.
        let w = Vector3::new(cos_psi, sin_psi, gu);
        let w_norm = w.norm();
        let x_b = w / w_norm;
        // Body z: the upward normal.
        let m = Vector3::new(-g.x, -g.y, 1.0);
        let m_norm = m.norm();
        let n = m / m_norm;
        let y_b = n.cross(&x_b);
        // Rates: ġ = H·ṗ with ṗ = v·u.
        let g_dot = sp.hessian * (u * v);
        let m_dot = Vector3::new(-g_dot.x, -g_dot.y, 0.0);
        let n_dot = (m_dot - n * n.dot(&m_dot)) / m_norm;
        let w_dot = Vector3::new(-sin_psi * r, cos_psi * r, g_dot.dot(&u) + r * gu_perp);
        let x_dot = (w_dot - x_b * x_b.dot(&w_dot)) / w_norm;
        let y_dot = n_dot.cross(&x_b) + n.cross(&x_dot);
        let omega_body = Vector3::new(y_dot.dot(&n), n_dot.dot(&x_b), x_dot.dot(&y_b));
        let v_dot = s[VDOT];
        let foot_acc = Vector3::new(
            v_dot * cos_psi - v * r * sin_psi,
            v_dot * sin_psi + v * r * cos_psi,
            v_dot * gu + v * g_dot.dot(&u) + v * r * gu_perp,
        );
        Frame {
            foot: Vector3::new(s[X], s[Y], sp.height_m),
            x_b,
            y_b,
            n,
            n_dot,
            omega_body,
            foot_vel: w * v,
            foot_acc,
            w_norm,
        }
    }

    /// The truth at `t` from the (uncommitted) planar state `s` there.
    fn truth(&self, t: Nanos, s: &State, f: &Frame, odometer_m: f64) -> TruthSample {
        let c = &self.cfg;
        let rho = c.ride_height_m;
        let delta = EXPANSION_STEP_S;
        let plus = self.frame(&rk4(s, &self.command, c.tau_s, delta));
        let minus = self.frame(&rk4(s, &self.command, c.tau_s, -delta));
        let n_ddot = (plus.n_dot - minus.n_dot) / (2.0 * delta);
        let alpha = (plus.omega_body - minus.omega_body) / (2.0 * delta);
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
            Matrix3::from_columns(&[f.x_b, f.y_b, f.n]),
        ));
        let position = f.foot + f.n * rho;
        let ground_speed = s[V] * f.w_norm / (1.0 - c.track_slip);
        let differential = c.icr_expansion * c.track_width_m * f.omega_body.z / 2.0;
        TruthSample {
            stamp: t,
            world_from_body: Isometry3::from_parts(Translation3::from(position), rotation),
            velocity_in_world: f.foot_vel + f.n_dot * rho,
            acceleration_in_world: f.foot_acc + n_ddot * rho,
            angular_velocity_in_body: f.omega_body,
            angular_acceleration_in_body: alpha,
            drive_speeds_radps: [
                (ground_speed - differential) / c.left_radius_m,
                (ground_speed + differential) / c.right_radius_m,
                0.0,
                0.0,
            ],
            odometer_m,
        }
    }
}

impl<S: Surface> MotionModel for KinematicSkidSteer<S> {
    /// The true state at `t`. Times before the start give the start state. A time before
    /// the latest committed grid step (a decreasing query, against the contract) is
    /// integrated backwards from that step: accurate, but not bit-identical to a
    /// monotone schedule.
    fn advance_to(&mut self, t: Nanos) -> TruthSample {
        let t = t.max(self.start);
        while self.grid_time() + self.cfg.step <= t {
            self.step();
        }
        let h = (t - self.grid_time()).as_secs_f64();
        let s = rk4(&self.state, &self.command, self.cfg.tau_s, h);
        let f = self.frame(&s);
        let speed = (f.foot_vel + f.n_dot * self.cfg.ride_height_m).norm();
        let odometer_m = self.odometer_m + 0.5 * h * (self.base_speed_mps + speed);
        self.latest = self.latest.max(t);
        self.truth(t, &s, &f, odometer_m)
    }

    fn start_time(&self) -> Nanos {
        self.start
    }

    fn finished(&self) -> bool {
        match self.phase {
            Phase::Stopped { since } => self.latest >= since + self.cfg.still_after,
            _ => false,
        }
    }

    fn expected_duration(&self) -> Nanos {
        self.expected
    }
}

/// Right-hand side of the planar model under a constant command.
fn deriv(s: &State, c: &Command, tau: f64) -> State {
    let (sin_psi, cos_psi) = s[PSI].sin_cos();
    let inv_tau2 = 1.0 / (tau * tau);
    State::from([
        s[V] * cos_psi,
        s[V] * sin_psi,
        s[R],
        s[VDOT],
        (c.speed_mps - s[V]) * inv_tau2 - 2.0 * s[VDOT] / tau,
        s[RDOT],
        (c.yaw_rate_radps - s[R]) * inv_tau2 - 2.0 * s[RDOT] / tau,
    ])
}

/// One classical Runge-Kutta step of size `h` (may be negative or zero).
fn rk4(s: &State, c: &Command, tau: f64, h: f64) -> State {
    let k1 = deriv(s, c, tau);
    let k2 = deriv(&(s + k1 * (h / 2.0)), c, tau);
    let k3 = deriv(&(s + k2 * (h / 2.0)), c, tau);
    let k4 = deriv(&(s + k3 * h), c, tau);
    s + (k1 + (k2 + k3) * 2.0 + k4) * (h / 6.0)
}

/// Checks the parameters and derives the model's constants.
fn validate(p: &MotionParams, geometry: &RobotGeometry) -> Result<Config, ParamError> {
    let step_hz = require_in("motion.step_hz", p.step_hz, f64::MIN_POSITIVE, MAX_STEP_HZ)?;
    let step = Nanos::period_of_hz(step_hz);
    let control_every = super::steps_per_tick(step_hz, p.controller_hz)?;
    let step_s = step.as_secs_f64();
    let tau_s = require_positive("motion.response_time_s", p.response_time_s)?;
    if tau_s < 2.0 * step_s {
        return Err(ParamError::new(
            "motion.response_time_s",
            format!("at least two integration steps ({} s)", 2.0 * step_s),
            tau_s,
        ));
    }
    let cruise_mps = require_positive("motion.cruise_speed_mps", p.cruise_speed_mps)?;
    let max_yaw_rate_radps = require_positive("motion.max_yaw_rate_radps", p.max_yaw_rate_radps)?;
    let max_accel = require_positive("motion.max_accel_mps2", p.max_accel_mps2)?;
    let max_lateral_accel_mps2 =
        require_positive("motion.max_lateral_accel_mps2", p.max_lateral_accel_mps2)?;
    let lookahead_m = require_positive("motion.lookahead_m", p.lookahead_m)?;
    let icr_expansion = p.icr_expansion;
    if !(icr_expansion.is_finite() && icr_expansion >= 1.0) {
        return Err(ParamError::new(
            "motion.icr_expansion",
            "a finite number >= 1",
            icr_expansion,
        ));
    }
    let track_slip = p.track_slip;
    if !(track_slip.is_finite() && (0.0..0.5).contains(&track_slip)) {
        return Err(ParamError::new(
            "motion.track_slip",
            "a number in [0, 0.5)",
            track_slip,
        ));
    }
    let still_before = require_non_negative("motion.still_before_s", p.still_before_s)?;
    let still_before = require_in("motion.still_before_s", still_before, 0.0, MAX_STILL_S)?;
    let still_after = require_non_negative("motion.still_after_s", p.still_after_s)?;
    let still_after = require_in("motion.still_after_s", still_after, 0.0, MAX_STILL_S)?;
    if !(geometry.track_width_m.is_finite() && geometry.track_width_m > 0.0) {
        return Err(ParamError::new(
            "robot",
            "a track width > 0 m",
            geometry.track_width_m,
        ));
    }
    let DriveKinematics::SkidSteer {
        left_radius_m,
        right_radius_m,
        ..
    } = geometry.kinematics
    else {
        return Err(ParamError::new(
            "motion.model",
            "`rapier` for a robot that is not skid-steered (the kinematic model drives \
             tracks only)",
            "kinematic",
        ));
    };
    if !(geometry.ride_height_m.is_finite() && geometry.ride_height_m >= 0.0) {
        return Err(ParamError::new(
            "robot",
            "a ride height >= 0 m",
            geometry.ride_height_m,
        ));
    }
    let control_period_s = step_s * control_every as f64;
    // Σ_j T·h(t - t_j) <= 1 + T·max h = 1 + T/(e·τ) for the impulse response h of the
    // drive: this rate limit keeps |v̇| <= max_accel.
    let command_accel_mps2 = max_accel / (1.0 + control_period_s / (std::f64::consts::E * tau_s));
    // First tick at or after the stand-still.
    let still_steps = (Nanos::from_secs_f64(still_before).0 as u64).div_ceil(step.0 as u64);
    let drive_start_step = still_steps.div_ceil(control_every) * control_every;
    Ok(Config {
        tau_s,
        step,
        step_s,
        control_every,
        control_period_s,
        drive_start_step,
        cruise_mps,
        max_yaw_rate_radps,
        command_accel_mps2,
        profile_accel_mps2: PROFILE_ACCEL_FRACTION * command_accel_mps2,
        max_lateral_accel_mps2,
        lookahead_m,
        icr_expansion,
        track_slip,
        track_width_m: geometry.track_width_m,
        ride_height_m: geometry.ride_height_m,
        left_radius_m,
        right_radius_m,
        still_after: Nanos::from_secs_f64(still_after),
    })
}

/// Speed limit at each route point: the curvature limits over the next
/// `lookahead + 2τ·cruise` of route (what pure pursuit steers towards, plus the drive's
/// lag), braked backwards at the profile deceleration. The end of the route is handled by
/// the stop profile, not here.
fn speed_profile(route: &Route, c: &Config) -> Vec<f64> {
    let limit = |k: f64| {
        let k = k.abs();
        if k > 0.0 {
            c.cruise_mps
                .min(c.max_yaw_rate_radps / k)
                .min((c.max_lateral_accel_mps2 / k).sqrt())
        } else {
            c.cruise_mps
        }
    };
    let s = &route.arc_length_m;
    let n = s.len();
    let window = c.lookahead_m + 2.0 * c.tau_s * c.cruise_mps;
    let mut v = vec![0.0; n];
    for i in 0..n {
        let mut m = limit(route.curvature_per_m[i]);
        let mut j = i + 1;
        while j < n && s[j] <= s[i] + window {
            m = m.min(limit(route.curvature_per_m[j]));
            j += 1;
        }
        v[i] = m;
    }
    for i in (0..n - 1).rev() {
        let braked = (v[i + 1] * v[i + 1] + 2.0 * c.profile_accel_mps2 * (s[i + 1] - s[i])).sqrt();
        v[i] = v[i].min(braked);
    }
    v
}

/// Stand-stills plus the time to drive the profile from rest to rest, plus the drive's lag
/// and settling: an estimate for progress bars.
fn expected_duration(route: &Route, profile: &[f64], c: &Config) -> Nanos {
    let s = &route.arc_length_m;
    let total = route.total_length_m();
    let a = c.profile_accel_mps2;
    let mut v_prev = 0.0f64;
    let mut time_s = 0.0;
    for i in 1..s.len() {
        let ds = s[i] - s[i - 1];
        let v = profile[i]
            .min((v_prev * v_prev + 2.0 * a * ds).sqrt())
            .min((2.0 * a * (total - s[i])).sqrt());
        time_s += ds / (0.5 * (v + v_prev)).max(1e-3);
        v_prev = v;
    }
    let drive_start_s = c.step_s * c.drive_start_step as f64;
    Nanos::from_secs_f64(drive_start_s + time_s + 2.0 * c.tau_s + SETTLE_S) + c.still_after
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{
        HeadlandsParams, LoopDirection, RouteKind, RouteParams, RowLoopParams, WaypointsParams,
    };
    use crate::route::build_route;
    use crate::world::{PlaneSurface, RowLayout, SurfacePoint};
    use nalgebra::{Matrix2, Point3};

    /// A smooth analytic test terrain: two crossed sinusoids plus an oblique one, slopes up
    /// to about 12°.
    #[derive(Clone, Copy)]
    struct SineSurface;

    impl Surface for SineSurface {
        fn sample(&self, x: f64, y: f64) -> SurfacePoint {
            let (a1, k1, k2, p1) = (0.25, 2.0 * PI / 15.0, 2.0 * PI / 11.0, 0.7);
            let (a2, k3, dir) = (0.1, 2.0 * PI / 7.0, 1.0f64);
            let (dx, dy) = (dir.cos(), dir.sin());
            let (s1, c1) = (k1 * x + p1).sin_cos();
            let (s2, c2) = (k2 * y).sin_cos();
            let (s3, c3) = (k3 * (dx * x + dy * y)).sin_cos();
            SurfacePoint {
                height_m: a1 * s1 * c2 + a2 * s3,
                gradient: Vector2::new(
                    a1 * k1 * c1 * c2 + a2 * k3 * dx * c3,
                    -a1 * k2 * s1 * s2 + a2 * k3 * dy * c3,
                ),
                hessian: Matrix2::new(
                    -a1 * k1 * k1 * s1 * c2 - a2 * k3 * k3 * dx * dx * s3,
                    -a1 * k1 * k2 * c1 * s2 - a2 * k3 * k3 * dx * dy * s3,
                    -a1 * k1 * k2 * c1 * s2 - a2 * k3 * k3 * dx * dy * s3,
                    -a1 * k2 * k2 * s1 * c2 - a2 * k3 * k3 * dy * dy * s3,
                ),
            }
        }
    }

    use std::f64::consts::PI;

    const START: Nanos = Nanos(1_631_696_400_000_000_000);

    /// Sprocket pitch radius of the test geometry, m.
    const SPROCKET_M: f64 = 0.1;

    fn geometry() -> RobotGeometry {
        RobotGeometry {
            track_width_m: 0.6,
            ride_height_m: 0.18,
            footprint_length_m: 1.1,
            footprint_width_m: 0.8,
            kinematics: DriveKinematics::SkidSteer {
                track_width_m: 0.6,
                left_radius_m: SPROCKET_M,
                right_radius_m: SPROCKET_M,
            },
        }
    }

    /// Left track surface speed, m/s.
    fn left(s: &TruthSample) -> f64 {
        s.drive_speeds_radps[0] * SPROCKET_M
    }

    /// Right track surface speed, m/s.
    fn right(s: &TruthSample) -> f64 {
        s.drive_speeds_radps[1] * SPROCKET_M
    }

    fn layout(length_m: f64) -> RowLayout {
        RowLayout {
            count: 6,
            length_m,
            spacing_m: 2.5,
            yaw_rad: 0.3,
            curvature_per_m: 0.0,
        }
    }

    fn loop_route(length_m: f64) -> Route {
        let p = RouteParams {
            kind: RouteKind::RowLoop,
            row_loop: RowLoopParams {
                row: 2,
                direction: LoopDirection::Counterclockwise,
                laps: 1,
            },
            ..RouteParams::default()
        };
        build_route(&p, &layout(length_m), &HeadlandsParams { width_m: 8.0 }).unwrap()
    }

    fn line_route(to: [f64; 2]) -> Route {
        let p = RouteParams {
            kind: RouteKind::Waypoints,
            waypoints: WaypointsParams {
                points: vec![[0.0, 0.0], to],
                closed: false,
                there_and_back: false,
            },
            ..RouteParams::default()
        };
        build_route(&p, &layout(10.0), &HeadlandsParams { width_m: 8.0 }).unwrap()
    }

    fn flat() -> PlaneSurface {
        PlaneSurface {
            z0_m: 0.0,
            gradient: Vector2::zeros(),
        }
    }

    fn model<S: Surface>(route: Route, surface: S) -> KinematicSkidSteer<S> {
        KinematicSkidSteer::new(&MotionParams::default(), route, surface, &geometry(), START)
            .unwrap()
    }

    fn ms(t: i64) -> Nanos {
        START + Nanos::from_millis(t)
    }

    fn bits(s: &TruthSample) -> Vec<u64> {
        let p = &s.world_from_body;
        let mut v = vec![s.stamp.0 as u64];
        v.extend(p.translation.vector.iter().map(|x| x.to_bits()));
        v.extend(p.rotation.coords.iter().map(|x| x.to_bits()));
        for x in [
            &s.velocity_in_world,
            &s.acceleration_in_world,
            &s.angular_velocity_in_body,
            &s.angular_acceleration_in_body,
        ] {
            v.extend(x.iter().map(|x| x.to_bits()));
        }
        v.extend([left(s), right(s), s.odometer_m].map(f64::to_bits));
        v
    }

    /// Distance from `p` to the route polyline (brute force over all segments).
    fn distance_to_route(route: &Route, p: &Vector2<f64>) -> f64 {
        route
            .points
            .windows(2)
            .map(|w| {
                let ab = w[1] - w[0];
                let f = ((p - w[0]).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
                (w[0] + ab * f - p).norm()
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Runs a model at 200 Hz to the end; returns (max distance to the route, end error,
    /// duration).
    fn drive<S: Surface>(route: &Route, mut m: KinematicSkidSteer<S>) -> (f64, f64, f64) {
        let mut t = START;
        let mut worst = 0.0f64;
        let mut last = Vector2::zeros();
        while !m.finished() && t < START + Nanos::from_secs(2000) {
            let s = m.advance_to(t);
            // The footprint's horizontal position.
            let foot = s.world_from_body * Point3::new(0.0, 0.0, -0.18);
            last = foot.coords.xy();
            if (t - START).0 % 50_000_000 == 0 {
                worst = worst.max(distance_to_route(route, &last));
            }
            t += Nanos::from_millis(5);
        }
        assert!(m.finished());
        (
            worst,
            (last - route.points.last().copied().unwrap()).norm(),
            (t - START).as_secs_f64(),
        )
    }

    #[test]
    fn follows_other_routes_closely() {
        let h = HeadlandsParams { width_m: 8.0 };
        let curved = RowLayout {
            curvature_per_m: 0.01,
            ..layout(25.0)
        };
        let serpentine = RouteParams {
            kind: RouteKind::Serpentine,
            ..RouteParams::default()
        };
        let tight = RouteParams {
            turn_radius_m: 0.5,
            ..RouteParams::default()
        };
        let square = RouteParams {
            kind: RouteKind::Waypoints,
            waypoints: WaypointsParams {
                points: vec![[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]],
                closed: true,
                there_and_back: false,
            },
            ..RouteParams::default()
        };
        let clockwise = RouteParams {
            row_loop: RowLoopParams {
                row: 0,
                direction: LoopDirection::Clockwise,
                laps: 2,
            },
            ..RouteParams::default()
        };
        for (name, params, l) in [
            ("serpentine on curved rows", serpentine, curved),
            ("row loop with 0.5 m turns", tight, layout(20.0)),
            ("closed square", square, layout(20.0)),
            ("two clockwise laps", clockwise, layout(20.0)),
        ] {
            let route = build_route(&params, &l, &h).unwrap();
            let (worst, end, duration) = drive(&route, model(route.clone(), flat()));
            eprintln!("{name}: off route <= {worst:.4} m, end error {end:.4} m, {duration:.1} s");
            // Pure pursuit cuts corners (bounded), and stops on the route's end point.
            assert!(worst < 0.06, "{name}: {worst} m off the route");
            assert!(end < 0.02, "{name}: ends {end} m from the route's end");
        }
    }

    #[test]
    fn follows_a_row_loop_on_flat_ground() {
        let length = 30.0;
        let l = layout(length);
        let route = loop_route(length);
        let mut m = model(route.clone(), flat());
        let p = MotionParams::default();
        let rho = geometry().ride_height_m;
        let dt = Nanos::from_millis(5);
        let mut t = START;
        let (mut max_straight, mut max_turn, mut max_lat_acc) = (0.0f64, 0.0f64, 0.0f64);
        let (mut naive_yaw, mut naive_dist, mut path, mut turned) = (0.0, 0.0, 0.0, 0.0);
        let mut prev: Option<TruthSample> = None;
        let mut finished_at = None;
        while t < START + Nanos::from_secs(200) {
            let s = m.advance_to(t);
            let pos = s.world_from_body.translation.vector;
            assert!((pos.z - rho).abs() < 1e-12);
            let xy = pos.xy();
            let v = s.velocity_in_world.norm();
            let x_b = s.world_from_body.rotation * Vector3::x();
            let y_b = s.world_from_body.rotation * Vector3::y();
            // Limits: speed, yaw rate, longitudinal acceleration.
            assert!(v <= p.cruise_speed_mps * (1.0 + 1e-12), "speed {v}");
            assert!(s.angular_velocity_in_body.z.abs() <= p.max_yaw_rate_radps * (1.0 + 1e-9));
            let a_long = s.acceleration_in_world.dot(&x_b);
            assert!(
                a_long.abs() <= p.max_accel_mps2 * (1.0 + 1e-9),
                "a {a_long}"
            );
            max_lat_acc = max_lat_acc.max(s.acceleration_in_world.dot(&y_b).abs());
            // Flat ground: no roll or pitch motion, velocity along the body x axis.
            assert!(s.angular_velocity_in_body.xy().norm() < 1e-12);
            assert!(s.velocity_in_world.dot(&y_b).abs() < 1e-12);
            // Cross-track error: on the lane straights once settled after a turn, and
            // anywhere along the route.
            let (o, along) = l.row_coords(&xy);
            let lane = (o - l.row_offset_m(2)).abs();
            let before_top = along < length && m.progress_m() < length + 1.5;
            let on_return = m.progress_m() > length + 3.0 + 1.25 * PI + 6.0 && along > 0.0;
            if (before_top || on_return) && along > 0.0 && m.progress_m() > 0.0 {
                max_straight = max_straight.max((lane - 1.25).abs());
            }
            max_turn = max_turn.max(distance_to_route(&route, &xy));
            if let Some(q) = &prev {
                let h = (s.stamp - q.stamp).as_secs_f64();
                naive_yaw += h * 0.5 * ((right(&s) - left(&s)) + (right(q) - left(q)))
                    / geometry().track_width_m;
                naive_dist += h * 0.25 * (right(&s) + left(&s) + right(q) + left(q));
                path += (pos - q.world_from_body.translation.vector).norm();
                let (_, _, yaw0) = q.world_from_body.rotation.euler_angles();
                let (_, _, yaw1) = s.world_from_body.rotation.euler_angles();
                turned += (yaw1 - yaw0 + PI).rem_euclid(2.0 * PI) - PI;
            }
            prev = Some(s);
            if m.finished() {
                finished_at = Some(t);
                break;
            }
            t += dt;
        }
        let end = prev.unwrap();
        let finished_at = finished_at.expect("the run finishes");
        eprintln!(
            "straight {max_straight:.4} m, route {max_turn:.4} m, lateral acc {max_lat_acc:.6}, \
             finished after {finished_at}, expected {}",
            m.expected_duration()
        );
        assert!(
            max_straight < 0.02,
            "cross-track on the straights {max_straight} m"
        );
        // The lateral limit is enforced on the commands (κ·v_cmd² <= a_lat); the product of
        // the filtered v and r may exceed it by a fraction of a percent in transients.
        assert!(
            max_lat_acc <= 1.01 * p.max_lateral_accel_mps2,
            "lateral {max_lat_acc}"
        );
        assert!(max_turn < 0.06, "distance to the route {max_turn} m");
        let end_xy = end.world_from_body.translation.vector.xy();
        assert!((end_xy - route.points[0]).norm() < 0.01, "end {end_xy:?}");
        assert!(end.velocity_in_world.norm() < 1e-3);
        // The run took about as long as expected.
        let ratio = (finished_at - START).as_secs_f64() / m.expected_duration().as_secs_f64();
        assert!((0.85..1.15).contains(&ratio), "duration ratio {ratio}");
        // Odometer = path length of the samples (chords at 200 Hz: shorter by ~v²h²κ²/24).
        assert!(
            (end.odometer_m - path).abs() < 1e-4 * path,
            "{} vs {path}",
            end.odometer_m
        );
        assert!((end.odometer_m - route.total_length_m()).abs() < 0.5);
        // A naive odometry over-estimates the loop's turning (about 2π, from the
        // orientations) by the ICR factor and the distance by the slip.
        assert!((turned - 2.0 * PI).abs() < 0.05, "{turned}");
        assert!(
            (naive_yaw - turned * p.icr_expansion).abs() < 1e-4,
            "{naive_yaw} vs {turned}"
        );
        assert!((naive_dist - end.odometer_m / (1.0 - p.track_slip)).abs() < 1e-3 * path);
    }

    #[test]
    fn at_rest_before_the_route_everything_is_zero() {
        let route = loop_route(20.0);
        let mut m = model(route.clone(), SineSurface);
        let still = Nanos::from_secs_f64(MotionParams::default().still_before_s);
        let mut t = START;
        let first = m.advance_to(t);
        while t < START + still {
            let s = m.advance_to(t);
            assert_eq!(s.velocity_in_world, Vector3::zeros());
            assert_eq!(s.acceleration_in_world, Vector3::zeros());
            assert_eq!(s.angular_velocity_in_body, Vector3::zeros());
            assert_eq!(s.angular_acceleration_in_body, Vector3::zeros());
            assert_eq!(left(&s), 0.0);
            assert_eq!(right(&s), 0.0);
            assert_eq!(s.odometer_m, 0.0);
            assert_eq!(s.world_from_body, first.world_from_body);
            t += Nanos::from_millis(7);
        }
        // The pose stands on the surface: footprint on the ground, z axis its normal.
        let sp = SineSurface.sample(route.points[0].x, route.points[0].y);
        let foot = first.world_from_body * Point3::new(0.0, 0.0, -0.18);
        assert!(
            (foot.coords - Vector3::new(route.points[0].x, route.points[0].y, sp.height_m)).norm()
                < 1e-12
        );
        assert!((first.world_from_body.rotation * Vector3::z() - sp.normal()).norm() < 1e-12);
        // Facing along the route (horizontally).
        let x_b = first.world_from_body.rotation * Vector3::x();
        let t0 = route.tangent_at(0.0);
        assert!((x_b.xy().normalize() - t0).norm() < 1e-12);
        // The robot starts moving after the stand-still.
        assert!(
            m.advance_to(START + still + Nanos::from_secs(2))
                .velocity_in_world
                .norm()
                > 0.1
        );
    }

    #[test]
    fn truth_is_consistent_with_finite_differences_on_a_sinusoidal_surface() {
        let mut m = model(loop_route(20.0), SineSurface);
        let h = 1e-4;
        let hn = Nanos::from_secs_f64(h);
        let (mut ev, mut ea, mut ew, mut eal) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        let mut max_tilt = 0.0f64;
        // Every 0.37 s through the drive (turns included), at off-grid and on-tick times.
        for i in 0..150 {
            let tc = ms(5_500 + 370 * i) + Nanos(i * 7_919);
            let a = m.advance_to(tc - hn);
            let c = m.advance_to(tc);
            let b = m.advance_to(tc + hn);
            let (pa, pb) = (
                a.world_from_body.translation.vector,
                b.world_from_body.translation.vector,
            );
            ev = ev.max(((pb - pa) / (2.0 * h) - c.velocity_in_world).norm());
            let fd_acc = (b.velocity_in_world - a.velocity_in_world) / (2.0 * h);
            ea = ea.max((fd_acc - c.acceleration_in_world).norm());
            let rel = a.world_from_body.rotation.inverse() * b.world_from_body.rotation;
            ew = ew.max((rel.scaled_axis() / (2.0 * h) - c.angular_velocity_in_body).norm());
            let fd_alpha = (b.angular_velocity_in_body - a.angular_velocity_in_body) / (2.0 * h);
            eal = eal.max((fd_alpha - c.angular_acceleration_in_body).norm());
            max_tilt = max_tilt.max((c.world_from_body.rotation * Vector3::z()).z.acos());
        }
        eprintln!(
            "velocity {ev:.2e} acceleration {ea:.2e} rate {ew:.2e} angular acc {eal:.2e} tilt {:.1}°",
            max_tilt.to_degrees()
        );
        // The terrain matters: the body tilts by several degrees.
        assert!(max_tilt.to_degrees() > 5.0);
        // Central differences with h = 1e-4 s: truncation h²/6·|third derivative| below
        // 1e-8, rounding of ~40 m coordinates 1e-10; where a controller tick falls inside
        // [t-h, t+h] the jerk jumps by at most a_max·T/τ² plus the lateral part
        // (≈ 0.3 m/s³), giving up to h·0.3/4 ≈ 1e-5 m/s² on the acceleration and
        // likewise for the angular acceleration.
        assert!(ev < 1e-6, "velocity vs finite difference: {ev}");
        assert!(ea < 3e-5, "acceleration vs finite difference: {ea}");
        assert!(ew < 1e-6, "angular velocity vs finite difference: {ew}");
        assert!(
            eal < 1e-4,
            "angular acceleration vs finite difference: {eal}"
        );
    }

    /// `R·Exp(φ)` with `φ` in the body frame.
    fn rotate(q: &UnitQuaternion<f64>, phi: &Vector3<f64>) -> UnitQuaternion<f64> {
        q * UnitQuaternion::from_scaled_axis(*phi)
    }

    #[test]
    fn strapdown_integration_of_truth_reproduces_the_trajectory() {
        let mut m = model(loop_route(20.0), SineSurface);
        let t0 = ms(7_000);
        let dt = 1e-3;
        let first = m.advance_to(t0);
        let odometer0 = first.odometer_m;
        let mut p = first.world_from_body.translation.vector;
        let mut v = first.velocity_in_world;
        let mut q = first.world_from_body.rotation;
        let mut prev = first;
        for k in 1..=30_000 {
            let s = m.advance_to(t0 + Nanos::from_millis(k));
            // Position and velocity: exact for an acceleration linear over the step.
            p += v * dt
                + (prev.acceleration_in_world * 2.0 + s.acceleration_in_world) * (dt * dt / 6.0);
            v += (prev.acceleration_in_world + s.acceleration_in_world) * (dt / 2.0);
            // Orientation: second-order Magnus expansion with endpoint rates.
            let (w0, w1) = (prev.angular_velocity_in_body, s.angular_velocity_in_body);
            q = rotate(
                &q,
                &((w0 + w1) * (dt / 2.0) + w0.cross(&w1) * (dt * dt / 12.0)),
            );
            prev = s;
        }
        let ep = (p - prev.world_from_body.translation.vector).norm();
        let eq = q.angle_to(&prev.world_from_body.rotation).to_degrees();
        let travelled = prev.odometer_m - odometer0;
        eprintln!(
            "strapdown after 30 s ({travelled:.1} m): position {ep:.2e} m, attitude {eq:.2e}°"
        );
        assert!(travelled > 20.0);
        assert!(ep < 1e-3, "position error {ep} m");
        assert!(eq < 0.01, "attitude error {eq}°");
    }

    #[test]
    fn slopes_give_rep103_pitch_and_roll() {
        let slope = 10f64.to_radians();
        // Ground rising towards +x (east) by 10°.
        let ground = PlaneSurface {
            z0_m: 3.0,
            gradient: Vector2::new(slope.tan(), 0.0),
        };
        let rho = geometry().ride_height_m;
        // (heading of the route, expected roll, expected pitch), REP-103: positive pitch
        // is nose down, positive roll is left side up.
        for (to, roll, pitch) in [
            ([30.0, 0.0], 0.0, -10.0), // straight uphill: nose up
            ([-30.0, 0.0], 0.0, 10.0), // downhill: nose down
            ([0.0, 30.0], -10.0, 0.0), // north: uphill on the right, right side up
            ([0.0, -30.0], 10.0, 0.0), // south: uphill on the left
        ] {
            let mut m = model(line_route(to), ground);
            for t in [0, 2_000, 9_000, 14_000] {
                let s = m.advance_to(ms(t));
                let (r, p, _) = s.world_from_body.rotation.euler_angles();
                assert!(
                    (r.to_degrees() - roll).abs() < 1e-9,
                    "{to:?}: roll {}",
                    r.to_degrees()
                );
                assert!(
                    (p.to_degrees() - pitch).abs() < 1e-9,
                    "{to:?}: pitch {}",
                    p.to_degrees()
                );
                // base_link is the ride height above the footprint along the normal.
                let pos = s.world_from_body.translation.vector;
                let n = Vector3::new(-slope.sin(), 0.0, slope.cos());
                let foot = pos - n * rho;
                assert!((foot.z - (3.0 + slope.tan() * foot.x)).abs() < 1e-12);
                // On a plane the velocity is along body x and the body does not rotate
                // about its x or y axes.
                let v_body = s.world_from_body.rotation.inverse() * s.velocity_in_world;
                assert!(v_body.yz().norm() < 1e-12);
                assert!(s.angular_velocity_in_body.norm() < 1e-12);
                if t == 14_000 {
                    // Cruising: the horizontal speed is the cruise speed.
                    assert!(
                        (s.velocity_in_world.xy().norm() - 1.0).abs() < 1e-6,
                        "{}",
                        s.velocity_in_world.xy().norm()
                    );
                }
            }
        }
    }

    #[test]
    fn truth_does_not_depend_on_the_query_schedule() {
        let route = loop_route(10.0);
        let mut a = model(route.clone(), SineSurface);
        let mut b = model(route.clone(), SineSurface);
        let mut c = model(route, SineSurface);
        let mut extra = 0u64;
        for k in 0..6_000 {
            // A: 200 Hz. B: 200 Hz plus irregular queries in between. C: like A.
            let t = ms(5 * k);
            let sa = a.advance_to(t);
            let sc = c.advance_to(t);
            assert_eq!(bits(&sa), bits(&sc), "determinism at {t}");
            if k % 3 == 1 {
                b.advance_to(t - Nanos(1_234_567));
                b.advance_to(t - Nanos(1_000_000));
                extra += 2;
            }
            let sb = b.advance_to(t);
            assert_eq!(bits(&sa), bits(&sb), "schedule dependence at {t}");
        }
        assert!(extra > 3_000);
        assert!(a.advance_to(ms(30_000)).odometer_m > 20.0);
        // Querying the same time twice gives the same sample.
        let s1 = a.advance_to(ms(30_000) + Nanos(333));
        let s2 = a.advance_to(ms(30_000) + Nanos(333));
        assert_eq!(bits(&s1), bits(&s2));
    }

    #[test]
    fn bad_motion_parameters_name_their_path() {
        let check = |f: &dyn Fn(&mut MotionParams), path: &str| {
            let mut p = MotionParams::default();
            f(&mut p);
            let e = KinematicSkidSteer::new(&p, loop_route(10.0), flat(), &geometry(), START)
                .err()
                .unwrap_or_else(|| panic!("{path} accepted"));
            assert_eq!(e.path, path);
        };
        check(&|p| p.step_hz = 0.0, "motion.step_hz");
        check(&|p| p.step_hz = f64::NAN, "motion.step_hz");
        check(&|p| p.controller_hz = -1.0, "motion.controller_hz");
        check(&|p| p.controller_hz = 300.0, "motion.controller_hz");
        check(&|p| p.controller_hz = 2000.0, "motion.controller_hz");
        check(&|p| p.response_time_s = 0.0, "motion.response_time_s");
        check(&|p| p.response_time_s = 0.0015, "motion.response_time_s");
        check(&|p| p.cruise_speed_mps = 0.0, "motion.cruise_speed_mps");
        check(
            &|p| p.max_yaw_rate_radps = f64::INFINITY,
            "motion.max_yaw_rate_radps",
        );
        check(&|p| p.max_accel_mps2 = -0.5, "motion.max_accel_mps2");
        check(
            &|p| p.max_lateral_accel_mps2 = 0.0,
            "motion.max_lateral_accel_mps2",
        );
        check(&|p| p.lookahead_m = 0.0, "motion.lookahead_m");
        check(&|p| p.icr_expansion = 0.9, "motion.icr_expansion");
        check(&|p| p.track_slip = 0.5, "motion.track_slip");
        check(&|p| p.track_slip = -0.01, "motion.track_slip");
        check(&|p| p.still_before_s = -1.0, "motion.still_before_s");
        check(&|p| p.still_after_s = f64::NAN, "motion.still_after_s");
        // A too-short route.
        let short = Route {
            points: vec![Vector2::zeros()],
            arc_length_m: vec![0.0],
            curvature_per_m: vec![0.0],
            cusps_m: Vec::new(),
        };
        let e =
            KinematicSkidSteer::new(&MotionParams::default(), short, flat(), &geometry(), START);
        assert_eq!(e.err().unwrap().path, "route");
        // Rates that divide work: 500 Hz steps with a 100 Hz controller.
        let p = MotionParams {
            step_hz: 500.0,
            controller_hz: 100.0,
            ..MotionParams::default()
        };
        assert!(KinematicSkidSteer::new(&p, loop_route(10.0), flat(), &geometry(), START).is_ok());
    }

    /// Release-mode timing of the default scenario's route (120 m rows, row loop around
    /// row 2) on flat ground with 200 Hz queries:
    /// `cargo test -p vinebench-sim --release -- --ignored --nocapture time_default`.
    #[test]
    #[ignore]
    fn time_default_row_loop_at_200_hz() {
        let world = crate::params::WorldParams::default();
        let l = RowLayout::new(&world.rows);
        let route = build_route(&RouteParams::default(), &l, &world.headlands).unwrap();
        let length = route.total_length_m();
        for surface in [0, 1] {
            let clock = std::time::Instant::now();
            let (samples, odo, end) = if surface == 0 {
                run_to_end(model(route.clone(), flat()))
            } else {
                run_to_end(model(route.clone(), SineSurface))
            };
            let wall = clock.elapsed();
            eprintln!(
                "{} route {length:.1} m: {samples} samples, {:.1} s simulated, odometer {odo:.1} m, wall {:.3} s",
                if surface == 0 { "flat" } else { "sine" },
                end.as_secs_f64(),
                wall.as_secs_f64()
            );
        }
    }

    fn run_to_end<S: Surface>(mut m: KinematicSkidSteer<S>) -> (usize, f64, Nanos) {
        let mut t = START;
        let mut n = 0;
        let mut odo = 0.0;
        while !m.finished() && t < START + Nanos::from_secs(1000) {
            let s = m.advance_to(t);
            odo = s.odometer_m;
            n += 1;
            t += Nanos::from_millis(5);
        }
        (n, odo, t - START)
    }
}
