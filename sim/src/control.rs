//! The route follower of the dynamic motion models: from the robot's planar state to a
//! body twist command `(vx, vy, ωz)`, at the controller rate.
//!
//! It plays the driver, not the algorithm under test, so it reads the true state.
//!
//! - **Progress** along the route is monotone and searched within
//!   [`PROGRESS_WINDOW_M`] of the previous value; it never
//!   crosses a cusp ([`Route::cusps_m`]) before the robot has stopped there, after which
//!   the direction of travel flips (a differential robot reverses; a holonomic robot in
//!   `fixed` heading mode strafes back).
//! - **Speed**: the minimum of the cruise speed and a precomputed profile over the route:
//!   the curvature limits `√(a_lat/|κ|)` and `ω_max/|κ|` (the latter not for holonomic
//!   robots holding a fixed heading), braked backwards at [`BRAKE_FRACTION`] of the
//!   acceleration limit to zero at every cusp and at the end, read at the current progress
//!   and [`PREVIEW_S`] of travel ahead; then rate-limited by the acceleration limit. Near
//!   a stop it never drops below [`CREEP_MPS`] until within [`ARRIVE_TOLERANCE_M`].
//! - **Steering, differential** (tracks): pure pursuit towards the route point a
//!   look-ahead `L = lookahead_m·clamp(|v|/cruise, 0.4, 1)` ahead (continued straight
//!   along the last tangent beyond a cusp or the end), `κ = 2·y/d²` in the frame of the
//!   direction of travel, `ωz = κ·v` clamped to `max_yaw_rate_radps`.
//! - **Steering, holonomic** (mecanum): the velocity follows the route tangent
//!   [`LATERAL_PREVIEW_S`] ahead plus a sideways pull of [`CROSS_TRACK_GAIN_PER_S`] per
//!   metre off the route (no corner cutting), and the heading is regulated separately: `ωz = ω_ff + k_ψ·(ψ_target − ψ)`, `k_ψ` = [`HEADING_GAIN_PER_S`], with
//!   `ψ_target` the route tangent plus the offset (`path`, feed-forward `κ·v`) or the start
//!   heading (`fixed`).

use crate::params::{HeadingMode, MotionParams, ParamError, require_in, require_positive};
use crate::route::Route;
use nalgebra::Vector2;
use std::f64::consts::PI;

/// Half-width of the arc-length window in which progress along the route is searched
/// around its previous value, m. The robot moves about 2 cm per controller tick.
pub const PROGRESS_WINDOW_M: f64 = 1.0;
/// Fraction of the acceleration limit used to brake in the speed profile.
pub const BRAKE_FRACTION: f64 = 0.8;
/// Travel time ahead of the current progress over which the speed profile is read, s
/// (the drive's lag).
pub const PREVIEW_S: f64 = 0.5;
/// Slowest speed commanded while the robot is still short of a stop, m/s.
pub const CREEP_MPS: f64 = 0.03;
/// A stop (cusp or end) is reached within this distance, m.
pub const ARRIVE_TOLERANCE_M: f64 = 0.03;
/// Below this speed a robot at a stop counts as stopped, m/s.
pub const STOPPED_MPS: f64 = 0.01;
/// Heading loop gain of holonomic robots, 1/s.
pub const HEADING_GAIN_PER_S: f64 = 2.0;
/// Cross-track gain of holonomic robots: sideways speed per metre off the route, 1/s.
pub const CROSS_TRACK_GAIN_PER_S: f64 = 2.0;
/// Holonomic robots follow the route tangent this far ahead (in travel time), s.
pub const LATERAL_PREVIEW_S: f64 = 0.2;
/// The look-ahead shrinks with speed down to this fraction of `lookahead_m`.
pub const MIN_LOOKAHEAD_FRACTION: f64 = 0.4;

/// The robot's true planar state, as the follower sees it.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PlanarState {
    /// Position of `base_link`, world, m.
    pub xy: Vector2<f64>,
    /// Heading: ENU yaw of the body x axis, rad.
    pub yaw_rad: f64,
    /// Horizontal velocity, world, m/s.
    pub velocity: Vector2<f64>,
}

/// A body twist command.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct TwistCommand {
    /// Forward speed, m/s.
    pub vx_mps: f64,
    /// Leftward speed, m/s (0 for differential robots).
    pub vy_mps: f64,
    /// Yaw rate, rad/s.
    pub wz_radps: f64,
}

/// Where the follower is.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum FollowPhase {
    /// Following the route.
    Driving,
    /// At the end of the route, commanding zero.
    Arrived,
}

/// Validated follower settings.
#[derive(Clone, Debug, PartialEq)]
struct Config {
    cruise_mps: f64,
    max_yaw_rate_radps: f64,
    accel_mps2: f64,
    lateral_accel_mps2: f64,
    lookahead_m: f64,
    period_s: f64,
    holonomic: bool,
    heading: HeadingMode,
    heading_offset_rad: f64,
}

/// Follows a [`Route`]; see the module documentation.
#[derive(Clone, Debug)]
pub struct RouteFollower {
    route: Route,
    cfg: Config,
    /// Speed limit at each route point, m/s.
    profile_mps: Vec<f64>,
    progress_m: f64,
    /// Cusps the robot has stopped at and turned back from.
    cusps_passed: usize,
    speed_mps: f64,
    phase: FollowPhase,
    fixed_heading_rad: f64,
}

/// Heading of a pose: the ENU yaw of its body x axis (projected on the horizontal), rad.
pub fn heading_rad(pose: &nalgebra::Isometry3<f64>) -> f64 {
    let x = pose.rotation * nalgebra::Vector3::x();
    x.y.atan2(x.x)
}

/// `a − b` wrapped to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let mut x = a % (2.0 * PI);
    if x > PI {
        x -= 2.0 * PI;
    } else if x <= -PI {
        x += 2.0 * PI;
    }
    x
}

impl RouteFollower {
    /// A follower at the start of `route` for a robot that is `holonomic` or not,
    /// called every `period_s`. Fails with the `motion.*` path of the first unusable
    /// parameter.
    pub fn new(
        route: Route,
        p: &MotionParams,
        holonomic: bool,
        period_s: f64,
    ) -> Result<RouteFollower, ParamError> {
        let cfg = Config {
            cruise_mps: require_positive("motion.cruise_speed_mps", p.cruise_speed_mps)?,
            max_yaw_rate_radps: require_positive(
                "motion.max_yaw_rate_radps",
                p.max_yaw_rate_radps,
            )?,
            accel_mps2: require_positive("motion.max_accel_mps2", p.max_accel_mps2)?,
            lateral_accel_mps2: require_positive(
                "motion.max_lateral_accel_mps2",
                p.max_lateral_accel_mps2,
            )?,
            lookahead_m: require_positive("motion.lookahead_m", p.lookahead_m)?,
            period_s,
            holonomic,
            heading: p.heading,
            heading_offset_rad: require_in(
                "motion.heading_offset_deg",
                p.heading_offset_deg,
                -180.0,
                180.0,
            )?
            .to_radians(),
        };
        if !holonomic && (p.heading == HeadingMode::Fixed || p.heading_offset_deg != 0.0) {
            let (path, found) = if p.heading == HeadingMode::Fixed {
                ("motion.heading", "\"fixed\"".to_string())
            } else {
                (
                    "motion.heading_offset_deg",
                    p.heading_offset_deg.to_string(),
                )
            };
            return Err(ParamError::new(
                path,
                "\"path\" with no offset: this robot's drive cannot move sideways (only \
                 mecanum robots can)",
                found,
            ));
        }
        if route.len() < 2 {
            return Err(ParamError::new(
                "route",
                "at least 2 points",
                format!("{} points", route.len()),
            ));
        }
        let profile_mps = speed_profile(&route, &cfg);
        let t0 = route.tangent_at(0.0);
        let fixed_heading_rad = wrap_angle(t0.y.atan2(t0.x) + cfg.heading_offset_rad);
        Ok(RouteFollower {
            route,
            cfg,
            profile_mps,
            progress_m: 0.0,
            cusps_passed: 0,
            speed_mps: 0.0,
            phase: FollowPhase::Driving,
            fixed_heading_rad,
        })
    }

    /// The route.
    pub fn route(&self) -> &Route {
        &self.route
    }

    /// The heading the robot should start with, rad.
    pub fn start_heading_rad(&self) -> f64 {
        self.fixed_heading_rad
    }

    /// Arc length reached, m.
    pub fn progress_m(&self) -> f64 {
        self.progress_m
    }

    /// Where the follower is.
    pub fn phase(&self) -> FollowPhase {
        self.phase
    }

    /// The heading the follower wants at its current progress, rad.
    pub fn target_heading_rad(&self) -> f64 {
        target_heading_rad(
            &self.route,
            self.progress_m,
            self.cusps_passed % 2 == 1,
            self.cfg.heading,
            self.cfg.heading_offset_rad,
        )
    }

    /// Expected time to drive the route at its speed profile, s.
    pub fn expected_duration_s(&self) -> f64 {
        let s = &self.route.arc_length_m;
        let v = &self.profile_mps;
        (1..s.len())
            .map(|i| (s[i] - s[i - 1]) / (0.5 * (v[i] + v[i - 1])).max(CREEP_MPS))
            .sum()
    }

    /// The end of the current leg: the next cusp not yet passed, or the route's end.
    fn next_stop_m(&self) -> f64 {
        self.route
            .cusps_m
            .get(self.cusps_passed)
            .copied()
            .unwrap_or_else(|| self.route.total_length_m())
    }

    /// +1 along the route's tangent, −1 after an odd number of cusps.
    fn direction(&self) -> f64 {
        if self.cusps_passed % 2 == 1 {
            -1.0
        } else {
            1.0
        }
    }

    /// The look-ahead point at arc length `s`, continued straight past the next stop.
    fn point_ahead(&self, s: f64) -> Vector2<f64> {
        let stop = self.next_stop_m();
        if s <= stop {
            return self.route.point_at(s);
        }
        // The tangent just before the stop.
        let before = self.route.tangent_at((stop - 1e-6).max(0.0));
        self.route.point_at(stop) + before * (s - stop)
    }

    /// Speed limit of the profile at arc length `s`.
    fn profile_at(&self, s: f64) -> f64 {
        let a = &self.route.arc_length_m;
        let i = a.partition_point(|&x| x <= s).clamp(1, a.len() - 1);
        let f = ((s - a[i - 1]) / (a[i] - a[i - 1])).clamp(0.0, 1.0);
        self.profile_mps[i - 1] + f * (self.profile_mps[i] - self.profile_mps[i - 1])
    }

    /// One controller tick: the twist command for the robot in `state`.
    pub fn update(&mut self, state: &PlanarState) -> TwistCommand {
        if self.phase == FollowPhase::Arrived {
            self.speed_mps = 0.0;
            return TwistCommand::default();
        }
        let c = self.cfg.clone();
        let found = self
            .route
            .closest_progress(&state.xy, self.progress_m, PROGRESS_WINDOW_M);
        // Never past the end of the current leg (the robot may overshoot a cusp).
        self.progress_m = self.progress_m.max(found).min(self.next_stop_m());
        let speed = state.velocity.norm();
        let stop = self.next_stop_m();
        let remaining = stop - self.progress_m;
        if remaining <= ARRIVE_TOLERANCE_M && speed < STOPPED_MPS && self.speed_mps == 0.0 {
            if stop >= self.route.total_length_m() {
                self.phase = FollowPhase::Arrived;
                return TwistCommand::default();
            }
            // At a cusp: turn round and go on.
            self.progress_m = stop;
            self.cusps_passed += 1;
        }
        let stop = self.next_stop_m();
        let remaining = stop - self.progress_m;

        // Speed.
        let mut v = c.cruise_mps;
        let preview = self.progress_m + self.speed_mps * PREVIEW_S;
        let mut s = self.progress_m;
        while s <= preview.min(stop) {
            v = v.min(self.profile_at(s));
            s += crate::route::ROUTE_SAMPLE_M;
        }
        let braking =
            (2.0 * BRAKE_FRACTION * c.accel_mps2 * (remaining - ARRIVE_TOLERANCE_M / 2.0).max(0.0))
                .sqrt();
        v = v.min(braking);
        if remaining > ARRIVE_TOLERANCE_M {
            v = v.max(CREEP_MPS);
        } else {
            v = 0.0;
        }
        let dv = c.accel_mps2 * c.period_s;
        v = v.clamp(self.speed_mps - dv, self.speed_mps + dv).max(0.0);
        self.speed_mps = v;

        // Steering.
        let lookahead = c.lookahead_m * (speed / c.cruise_mps).clamp(MIN_LOOKAHEAD_FRACTION, 1.0);
        let target = self.point_ahead(self.progress_m + lookahead);
        let to_target = target - state.xy;
        let dist = to_target.norm().max(1e-6);
        if !c.holonomic {
            let yaw = state.yaw_rad + if self.direction() < 0.0 { PI } else { 0.0 };
            let (sn, cs) = yaw.sin_cos();
            let y_local = -sn * to_target.x + cs * to_target.y;
            let kappa = 2.0 * y_local / (dist * dist);
            TwistCommand {
                vx_mps: self.direction() * v,
                vy_mps: 0.0,
                wz_radps: (kappa * v).clamp(-c.max_yaw_rate_radps, c.max_yaw_rate_radps),
            }
        } else {
            // Along the route's tangent a little ahead (the drive's lag), plus a
            // proportional pull back onto it: no corner cutting in curves.
            let ahead = (self.progress_m + self.speed_mps * LATERAL_PREVIEW_S).min(stop);
            let on_route = self.route.point_at(self.progress_m);
            let v_world =
                self.route.tangent_at(ahead) * v + (on_route - state.xy) * CROSS_TRACK_GAIN_PER_S;
            let target_yaw = self.target_heading_rad();
            let feed_forward = if c.heading == HeadingMode::Path {
                self.route.curvature_at(self.progress_m) * v
            } else {
                0.0
            };
            let wz = (feed_forward + HEADING_GAIN_PER_S * wrap_angle(target_yaw - state.yaw_rad))
                .clamp(-c.max_yaw_rate_radps, c.max_yaw_rate_radps);
            let (sn, cs) = state.yaw_rad.sin_cos();
            TwistCommand {
                vx_mps: cs * v_world.x + sn * v_world.y,
                vy_mps: -sn * v_world.x + cs * v_world.y,
                wz_radps: wz,
            }
        }
    }
}

/// The heading a robot following `route` should have at arc length `s_m`, `reversed`
/// after an odd number of cusps: for `path`, the route tangent plus `offset_rad` (plus π
/// when reversed: a differential robot backs down the return leg); for `fixed`, the
/// start heading (tangent at 0 plus `offset_rad`) everywhere.
pub fn target_heading_rad(
    route: &Route,
    s_m: f64,
    reversed: bool,
    mode: HeadingMode,
    offset_rad: f64,
) -> f64 {
    let yaw_of = |t: Vector2<f64>| t.y.atan2(t.x);
    match mode {
        HeadingMode::Fixed => wrap_angle(yaw_of(route.tangent_at(0.0)) + offset_rad),
        HeadingMode::Path => {
            let flip = if reversed { PI } else { 0.0 };
            wrap_angle(yaw_of(route.tangent_at(s_m)) + offset_rad + flip)
        }
    }
}

/// Speed limit at each route point: curvature limits, braked to zero at the cusps and the
/// end.
fn speed_profile(route: &Route, c: &Config) -> Vec<f64> {
    let turning_limited = !(c.holonomic && c.heading == HeadingMode::Fixed);
    let mut v: Vec<f64> = route
        .curvature_per_m
        .iter()
        .map(|&k| {
            let k = k.abs();
            let mut lim = c.cruise_mps;
            if k > 1e-9 {
                lim = lim.min((c.lateral_accel_mps2 / k).sqrt());
                if turning_limited {
                    lim = lim.min(c.max_yaw_rate_radps / k);
                }
            }
            lim
        })
        .collect();
    let a = BRAKE_FRACTION * c.accel_mps2;
    let stops: Vec<f64> = route
        .cusps_m
        .iter()
        .copied()
        .chain(std::iter::once(route.total_length_m()))
        .collect();
    let s = &route.arc_length_m;
    let n = v.len();
    for i in 0..n {
        if stops.iter().any(|&c| (s[i] - c).abs() < 1e-9) {
            v[i] = 0.0;
        }
    }
    for i in (0..n.saturating_sub(1)).rev() {
        let reach = (v[i + 1] * v[i + 1] + 2.0 * a * (s[i + 1] - s[i])).sqrt();
        v[i] = v[i].min(reach);
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{RouteKind, RouteParams, WaypointsParams, WorldParams};
    use crate::route::build_route;
    use crate::world::RowLayout;

    fn straight(there_and_back: bool) -> Route {
        let world = WorldParams::default();
        let p = RouteParams {
            kind: RouteKind::Waypoints,
            waypoints: WaypointsParams {
                points: vec![[0.0, 0.0], [10.0, 0.0]],
                closed: false,
                there_and_back,
            },
            ..RouteParams::default()
        };
        build_route(&p, &RowLayout::new(&world.rows), &world.headlands).unwrap()
    }

    fn follower(route: Route, holonomic: bool) -> RouteFollower {
        RouteFollower::new(route, &MotionParams::default(), holonomic, 0.02).unwrap()
    }

    fn at(x: f64, y: f64, yaw: f64, vx: f64) -> PlanarState {
        PlanarState {
            xy: Vector2::new(x, y),
            yaw_rad: yaw,
            velocity: Vector2::new(vx, 0.0),
        }
    }

    #[test]
    fn wrap_angle_maps_into_minus_pi_pi() {
        for (a, w) in [
            (0.0, 0.0),
            (3.0 * PI, PI),
            (-3.0 * PI, PI),
            (2.5 * PI, 0.5 * PI),
        ] {
            assert!((wrap_angle(a) - w).abs() < 1e-12, "{a}");
        }
        assert!((wrap_angle(-PI) - PI).abs() < 1e-12);
    }

    #[test]
    fn the_speed_profile_brakes_to_zero_at_cusps_and_the_end() {
        let f = follower(straight(true), false);
        let a = BRAKE_FRACTION * MotionParams::default().max_accel_mps2;
        for s in [0.5, 2.0, 5.0, 9.9, 10.0, 10.1, 15.0, 19.5, 20.0] {
            // Distance to the next stop (10 m cusp, 20 m end); straight lines: only the
            // braking limit and the cruise speed.
            let to_stop = if s <= 10.0 { 10.0 - s } else { 20.0 - s };
            let expected = (2.0 * a * to_stop).sqrt().min(1.0);
            assert!(
                (f.profile_at(s) - expected).abs() < 0.01,
                "s {s}: {}",
                f.profile_at(s)
            );
        }
    }

    #[test]
    fn a_differential_robot_steers_back_onto_the_route() {
        let mut f = follower(straight(false), false);
        // 0.3 m left of the route, heading along it: turn right (negative yaw rate).
        let mut cmd = TwistCommand::default();
        for _ in 0..50 {
            cmd = f.update(&at(2.0, 0.3, 0.0, 0.5));
        }
        assert!(
            cmd.vx_mps > 0.0 && cmd.wz_radps < 0.0 && cmd.vy_mps == 0.0,
            "{cmd:?}"
        );
        // A holonomic robot moves sideways instead, and keeps its heading.
        let mut f = follower(straight(false), true);
        for _ in 0..50 {
            cmd = f.update(&at(2.0, 0.3, 0.0, 0.5));
        }
        assert!(cmd.vy_mps < 0.0 && cmd.wz_radps.abs() < 1e-12, "{cmd:?}");
    }

    #[test]
    fn an_overshoot_past_a_cusp_brakes_and_then_reverses() {
        let mut f = follower(straight(true), false);
        // Drive up to the cusp at 10 m.
        for i in 0..500 {
            let x = (i as f64 * 0.02).min(9.9);
            f.update(&at(x, 0.0, 0.0, 0.5));
        }
        // Coasting 5 cm past the cusp while still moving: progress stays at the cusp and
        // the command is to stop, not to carry on down the return leg.
        let mut cmd = TwistCommand::default();
        for _ in 0..200 {
            cmd = f.update(&at(10.05, 0.0, 0.0, 0.2));
        }
        assert_eq!(f.progress_m(), f.route().cusps_m[0]);
        assert_eq!(cmd.vx_mps, 0.0, "{cmd:?}");
        // Stopped there: it turns back and drives backwards (a differential robot does not
        // turn round), heading still along +x.
        for _ in 0..50 {
            cmd = f.update(&at(10.05, 0.0, 0.0, 0.0));
        }
        assert!(cmd.vx_mps < 0.0, "{cmd:?}");
        assert!(f.progress_m() >= f.route().cusps_m[0]);
        assert!((wrap_angle(f.target_heading_rad())).abs() < 1e-9);
    }
}
