//! How well the robot followed its route: truth-only metrics of the robot's own run.
//!
//! A [`RouteTracking`] is fed every ground-truth sample in time order and keeps the worst
//! values seen. It needs nothing but the truth and the route the robot was asked to
//! follow, so it measures any motion model the same way.
//!
//! # Progress along the route
//! Like the route follower ([`crate::control::RouteFollower`]), the tracker keeps a
//! monotone progress `p` (arc length, m). For each sample it searches the closest point of
//! the route with [`Route::closest_progress`] around `p`, within
//! [`PROGRESS_WINDOW_M`] plus the distance travelled since the previous sample (so a
//! coarse ground-truth rate cannot outrun the window), and sets `p ← max(p, found)`.
//!
//! The search never crosses a cusp ([`Route::cusps_m`]): it stays on the current leg
//! (the search hint is kept strictly before the leg's cusp, also once the robot has
//! reached it). The tracker moves on to the next leg when both hold:
//! - the remaining arc length to the cusp, `c − p`, is at most [`CUSP_REACH_M`] (measured
//!   along the route, so a lateral offset at the cusp does not prevent the switch), and
//! - the robot's horizontal speed is below [`MOVING_MPS`] (nearly stopped).
//!
//! Then `p ← c`, and the direction of travel flips. Below [`MOVING_MPS`] heading errors
//! are not counted (see below), so switching a little before the robot's actual reversal
//! cannot produce a spurious heading error.
//!
//! # Metrics ([`RobotMetrics`])
//! - `max_cross_track_m`: the largest horizontal distance between the body origin
//!   (`base_link`) and the closest route point found by the search above (before the
//!   start and past the end of the route, the distance to its first or last point).
//! - `max_heading_error_deg`: the largest `|wrap(ψ − ψ_target)|`, with `ψ` the ENU yaw of
//!   the body x axis (its horizontal projection) and `ψ_target` from
//!   [`crate::control::target_heading_rad`] at the current progress: the route tangent plus
//!   `heading_offset_deg`, plus π after an odd number of cusps (`heading = "path"`: a
//!   differential robot drives back without turning), or the start heading (tangent at 0
//!   plus the offset) for `heading = "fixed"`. Only samples with a horizontal speed above
//!   [`MOVING_MPS`] count: stand-stills (before and after the route, stuck) and the
//!   transients of stopping, turning round and starting again at cusps are excluded.
//!   0 when the robot never moved.
//! - `max_tilt_deg`: the largest angle between the body z axis and the world z axis.
//! - `distance_m`: the odometer (path length of the body origin) at the last sample.

use crate::control::{heading_rad, target_heading_rad, wrap_angle};
use crate::motion::kinematic::PROGRESS_WINDOW_M;
use crate::params::HeadingMode;
use crate::route::Route;
use crate::truth::TruthSample;
use nalgebra::{Vector2, Vector3};
use serde::Serialize;

/// Horizontal speed above which the robot counts as moving (heading errors are counted),
/// and below which it counts as nearly stopped at a cusp, m/s.
pub const MOVING_MPS: f64 = 0.05;
/// The tracker moves on past a cusp once the progress is within this arc length of it
/// (and the robot is nearly stopped), m.
pub const CUSP_REACH_M: f64 = 0.05;
/// The search hint stays this far before the cusp that ends the current leg, m (a hint
/// at the cusp itself would search the next leg).
const BEFORE_CUSP_M: f64 = 1e-6;

/// Truth-only metrics of the robot's run against its route (see the module
/// documentation for their exact definitions).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RobotMetrics {
    /// Largest horizontal distance of the body origin from the route, m.
    pub max_cross_track_m: f64,
    /// Largest heading error while moving faster than [`MOVING_MPS`], degrees.
    pub max_heading_error_deg: f64,
    /// Largest angle between the body z axis and the vertical, degrees.
    pub max_tilt_deg: f64,
    /// Distance travelled (odometer at the last sample), m.
    pub distance_m: f64,
    /// Arc length reached along the route, m.
    pub progress_m: f64,
    /// Total arc length of the route, m.
    pub route_length_m: f64,
    /// Cusps the robot turned round at.
    pub cusps_passed: usize,
    /// Ground-truth samples seen.
    pub samples: u64,
}

/// Tracks the robot's ground truth against its route; see the module documentation.
#[derive(Clone, Debug)]
pub struct RouteTracking {
    route: Route,
    mode: HeadingMode,
    offset_rad: f64,
    progress_m: f64,
    cusps_passed: usize,
    last_odometer_m: Option<f64>,
    metrics: RobotMetrics,
}

impl RouteTracking {
    /// A tracker for a robot asked to follow `route` with the heading policy `heading`
    /// and `heading_offset_deg` (`motion.heading`, `motion.heading_offset_deg`; a
    /// differential robot follows `path` with no offset).
    pub fn new(route: Route, heading: HeadingMode, heading_offset_deg: f64) -> RouteTracking {
        let metrics = RobotMetrics {
            route_length_m: route.total_length_m(),
            ..RobotMetrics::default()
        };
        RouteTracking {
            route,
            mode: heading,
            offset_rad: heading_offset_deg.to_radians(),
            progress_m: 0.0,
            cusps_passed: 0,
            last_odometer_m: None,
            metrics,
        }
    }

    /// The route.
    pub fn route(&self) -> &Route {
        &self.route
    }

    /// Arc length reached along the route, m.
    pub fn progress_m(&self) -> f64 {
        self.progress_m
    }

    /// The cusp ending the current leg, if any.
    fn leg_end(&self) -> Option<f64> {
        self.route.cusps_m.get(self.cusps_passed).copied()
    }

    /// `s` kept strictly before the cusp ending the current leg (where arc-length queries
    /// would otherwise answer for the next leg).
    fn on_leg(&self, s: f64) -> f64 {
        match self.leg_end() {
            Some(c) => s.min(c - BEFORE_CUSP_M),
            None => s,
        }
    }

    /// Takes the next ground-truth sample (samples must come in time order).
    pub fn push(&mut self, truth: &TruthSample) {
        let pose = &truth.world_from_body;
        let p = pose.translation.vector;
        let xy = Vector2::new(p.x, p.y);
        let v = truth.velocity_in_world;
        let speed = v.x.hypot(v.y);
        let step_m = self
            .last_odometer_m
            .map_or(0.0, |o| (truth.odometer_m - o).abs());
        self.last_odometer_m = Some(truth.odometer_m);

        // Progress, on the current leg.
        let hint = self.on_leg(self.progress_m);
        let found = self
            .route
            .closest_progress(&xy, hint, PROGRESS_WINDOW_M + step_m);
        let cross_track = (xy - self.route.point_at(found)).norm();
        self.progress_m = self.progress_m.max(found);
        if let Some(c) = self.leg_end()
            && c - self.progress_m <= CUSP_REACH_M
            && speed < MOVING_MPS
        {
            self.progress_m = c;
            self.cusps_passed += 1;
        }

        let heading_error_deg = (speed > MOVING_MPS).then(|| {
            let target = target_heading_rad(
                &self.route,
                self.on_leg(self.progress_m),
                self.cusps_passed % 2 == 1,
                self.mode,
                self.offset_rad,
            );
            wrap_angle(heading_rad(pose) - target).abs().to_degrees()
        });
        let z_b = pose.rotation * Vector3::z();
        let tilt = z_b.x.hypot(z_b.y).atan2(z_b.z).to_degrees();

        let m = &mut self.metrics;
        m.max_cross_track_m = m.max_cross_track_m.max(cross_track);
        if let Some(e) = heading_error_deg {
            m.max_heading_error_deg = m.max_heading_error_deg.max(e);
        }
        m.max_tilt_deg = m.max_tilt_deg.max(tilt);
        m.distance_m = truth.odometer_m;
        m.progress_m = self.progress_m;
        m.cusps_passed = self.cusps_passed;
        m.samples += 1;
    }

    /// The metrics of the samples so far.
    pub fn metrics(&self) -> RobotMetrics {
        self.metrics.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::MAX_DRIVE_JOINTS;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use std::f64::consts::FRAC_PI_2;
    use std::f64::consts::PI;
    use vinebench_msgs::Nanos;

    /// A straight route along +x from the origin, `len` m long (points 5 cm apart).
    fn straight(len: f64) -> Route {
        let n = (len / 0.05).round() as usize;
        let points: Vec<Vector2<f64>> = (0..=n)
            .map(|i| Vector2::new(i as f64 * len / n as f64, 0.0))
            .collect();
        let arc_length_m = points.iter().map(|p| p.x).collect();
        Route {
            curvature_per_m: vec![0.0; points.len()],
            points,
            arc_length_m,
            cusps_m: Vec::new(),
        }
    }

    /// `straight(len)` there and back: out along +x, a cusp at `len`, back along −x.
    fn there_and_back(len: f64) -> Route {
        let mut r = straight(len);
        let n = r.len();
        for i in (0..n - 1).rev() {
            r.points.push(r.points[i]);
            r.arc_length_m.push(2.0 * len - r.arc_length_m[i]);
            r.curvature_per_m.push(0.0);
        }
        r.cusps_m = vec![len];
        r
    }

    /// A truth sample at `t` s, position `xyz`, attitude (roll, pitch, yaw) rad, velocity.
    fn sample(t: f64, xyz: [f64; 3], rpy: [f64; 3], v: [f64; 3], odometer_m: f64) -> TruthSample {
        TruthSample {
            stamp: Nanos::from_secs_f64(t),
            world_from_body: Isometry3::from_parts(
                Translation3::new(xyz[0], xyz[1], xyz[2]),
                UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
            ),
            velocity_in_world: Vector3::new(v[0], v[1], v[2]),
            acceleration_in_world: Vector3::zeros(),
            angular_velocity_in_body: Vector3::zeros(),
            angular_acceleration_in_body: Vector3::zeros(),
            drive_speeds_radps: [0.0; MAX_DRIVE_JOINTS],
            odometer_m,
        }
    }

    /// Drives along +x at 1 m/s from x = 0 to x = `len`, sampled at 100 Hz, with a lateral
    /// offset `y`, attitude `rpy`.
    fn drive_straight(tr: &mut RouteTracking, len: f64, y: f64, rpy: [f64; 3]) {
        let n = (len * 100.0).round() as usize;
        for i in 0..=n {
            let x = i as f64 * 0.01;
            tr.push(&sample(x, [x, y, 0.3], rpy, [1.0, 0.0, 0.0], x));
        }
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn a_parallel_offset_is_the_cross_track_error() {
        let mut tr = RouteTracking::new(straight(20.0), HeadingMode::Path, 0.0);
        drive_straight(&mut tr, 20.0, 0.3, [0.0; 3]);
        let m = tr.metrics();
        assert!(close(m.max_cross_track_m, 0.3, 1e-12), "{m:?}");
        assert!(m.max_heading_error_deg < 1e-9, "{m:?}");
        assert!(m.max_tilt_deg < 1e-9, "{m:?}");
        assert!(close(m.distance_m, 20.0, 1e-9), "{m:?}");
        assert!(close(m.progress_m, 20.0, 1e-9), "{m:?}");
        assert_eq!(m.route_length_m, 20.0);
        assert_eq!(m.samples, 2001);
    }

    #[test]
    fn a_yawed_robot_has_that_heading_error() {
        let mut tr = RouteTracking::new(straight(10.0), HeadingMode::Path, 0.0);
        drive_straight(&mut tr, 10.0, 0.0, [0.0, 0.0, 10f64.to_radians()]);
        let m = tr.metrics();
        assert!(close(m.max_heading_error_deg, 10.0, 1e-9), "{m:?}");
        assert!(m.max_cross_track_m < 1e-12, "{m:?}");

        // The same pose is on target for a robot asked to hold 10° (path or fixed), and
        // wrapping: −350° is the same as +10°.
        for (mode, offset) in [
            (HeadingMode::Path, 10.0),
            (HeadingMode::Fixed, 10.0),
            (HeadingMode::Path, -350.0),
        ] {
            let mut tr = RouteTracking::new(straight(10.0), mode, offset);
            drive_straight(&mut tr, 10.0, 0.0, [0.0, 0.0, 10f64.to_radians()]);
            let e = tr.metrics().max_heading_error_deg;
            assert!(e < 1e-9, "{mode:?} {offset}: {e}");
        }
    }

    #[test]
    fn heading_errors_count_only_while_moving() {
        let mut tr = RouteTracking::new(straight(10.0), HeadingMode::Path, 0.0);
        // Standing still turned 90° (and creeping at 4 cm/s): not counted.
        for (i, v) in [0.0, 0.04, 0.0].into_iter().enumerate() {
            tr.push(&sample(
                i as f64,
                [0.0, 0.0, 0.3],
                [0.0, 0.0, FRAC_PI_2],
                [v, 0.0, 0.0],
                0.0,
            ));
        }
        assert_eq!(tr.metrics().max_heading_error_deg, 0.0);
        // Moving at 6 cm/s (sideways): counted.
        tr.push(&sample(
            3.0,
            [0.0, 0.0, 0.3],
            [0.0, 0.0, FRAC_PI_2],
            [0.0, 0.06, 0.0],
            0.0,
        ));
        assert!(close(tr.metrics().max_heading_error_deg, 90.0, 1e-9));
    }

    #[test]
    fn tilt_is_the_angle_of_body_z_from_vertical() {
        let mut tr = RouteTracking::new(straight(10.0), HeadingMode::Path, 0.0);
        drive_straight(&mut tr, 10.0, 0.0, [7f64.to_radians(), 0.0, 0.0]);
        let m = tr.metrics();
        assert!(close(m.max_tilt_deg, 7.0, 1e-9), "{m:?}");
        // Roll does not change the heading of the body x axis.
        assert!(m.max_heading_error_deg < 1e-9, "{m:?}");

        // Roll and pitch together: cos(tilt) = cos(roll)·cos(pitch) (body z in world is
        // (sin p cos r, −sin r, cos p cos r) for R = Rz·Ry·Rx).
        let (r, p) = (3f64.to_radians(), 4f64.to_radians());
        let mut tr = RouteTracking::new(straight(10.0), HeadingMode::Path, 0.0);
        drive_straight(&mut tr, 10.0, 0.0, [r, p, 0.0]);
        let want = (r.cos() * p.cos()).acos().to_degrees();
        assert!(close(tr.metrics().max_tilt_deg, want, 1e-9));
    }

    #[test]
    fn there_and_back_driven_backwards_has_no_heading_error() {
        let len = 10.0;
        let route = there_and_back(len);
        let mut tr = RouteTracking::new(route.clone(), HeadingMode::Path, 0.0);
        let mut t = 0.0;
        let mut odo = 0.0;
        let push = |tr: &mut RouteTracking, x: f64, vx: f64, odo: f64, t: &mut f64| {
            // Facing +x all the way (a differential robot reversing), 2 cm to the left.
            tr.push(&sample(*t, [x, 0.02, 0.3], [0.0; 3], [vx, 0.0, 0.0], odo));
            *t += 0.01;
        };
        // Out at 1 m/s, slowing to a stop at the cusp over the last 0.5 m.
        let mut x = 0.0;
        while x < len {
            let v = (2.0 * (len - x)).sqrt().clamp(0.02, 1.0);
            push(&mut tr, x, v, odo, &mut t);
            x += v * 0.01;
            odo += v * 0.01;
        }
        for _ in 0..20 {
            push(&mut tr, len, 0.0, odo, &mut t);
        }
        assert_eq!(tr.metrics().cusps_passed, 1);
        // Back at 1 m/s, still facing +x.
        let mut x = len;
        while x > 0.0 {
            let v = (2.0 * x).sqrt().clamp(0.02, 1.0);
            push(&mut tr, x, -v, odo, &mut t);
            x -= v * 0.01;
            odo += v * 0.01;
        }
        push(&mut tr, 0.0, 0.0, odo, &mut t);
        let m = tr.metrics();
        assert!(m.max_heading_error_deg < 1e-9, "{m:?}");
        assert!(close(m.max_cross_track_m, 0.02, 1e-12), "{m:?}");
        // On the way back: progress past the cusp, up to the end.
        assert!(close(m.progress_m, 2.0 * len, 0.02), "{m:?}");
        assert!(close(m.distance_m, 2.0 * len, 0.02), "{m:?}");

        // The same drive facing the way of travel on the return leg (the robot turned
        // round) is 180° off for a robot that should drive back without turning.
        let mut tr = RouteTracking::new(route, HeadingMode::Path, 0.0);
        for i in 0..=1000 {
            let x = i as f64 * 0.01;
            let v = if i == 1000 { 0.0 } else { 1.0 };
            tr.push(&sample(x, [x, 0.0, 0.3], [0.0; 3], [v, 0.0, 0.0], x));
        }
        for i in 1..=1000 {
            let x = len - i as f64 * 0.01;
            tr.push(&sample(
                10.0 + i as f64 * 0.01,
                [x, 0.0, 0.3],
                [0.0, 0.0, PI],
                [-1.0, 0.0, 0.0],
                len + i as f64 * 0.01,
            ));
        }
        let m = tr.metrics();
        assert!(close(m.max_heading_error_deg, 180.0, 1e-9), "{m:?}");
        assert!(m.max_cross_track_m < 1e-12, "{m:?}");
    }

    #[test]
    fn progress_does_not_cross_a_cusp_without_stopping() {
        let len = 10.0;
        // Out to 0.5 m short of the cusp, then straight back at full speed (no stop): the
        // tracker stays on the way out, with its progress at 9.5 m. The first 0.5 m back
        // lie within the search window (distance 0); 3 m back the robot is about 2 m
        // behind the window's start, so it counts as off its route.
        let mut tr = RouteTracking::new(there_and_back(len), HeadingMode::Path, 0.0);
        for i in 0..=950 {
            let x = i as f64 * 0.01;
            tr.push(&sample(x, [x, 0.0, 0.3], [0.0; 3], [1.0, 0.0, 0.0], x));
        }
        let back = |tr: &mut RouteTracking, from: usize, to: usize| {
            for i in from..=to {
                let x = 9.5 - i as f64 * 0.01;
                let odo = 9.5 + i as f64 * 0.01;
                tr.push(&sample(odo, [x, 0.0, 0.3], [0.0; 3], [-1.0, 0.0, 0.0], odo));
            }
        };
        back(&mut tr, 1, 50);
        let m = tr.metrics();
        assert_eq!(m.cusps_passed, 0);
        assert!(close(m.progress_m, 9.5, 1e-9), "{m:?}");
        assert!(m.max_cross_track_m < 1e-12, "{m:?}");
        back(&mut tr, 51, 300);
        let m = tr.metrics();
        assert_eq!(m.cusps_passed, 0);
        assert!(m.max_cross_track_m > 1.9, "{m:?}");

        // Passing the cusp point at speed does not switch legs either: 1 m beyond it, the
        // robot is 1 m from the end of the way out.
        let mut tr = RouteTracking::new(there_and_back(len), HeadingMode::Path, 0.0);
        for i in 0..=1100 {
            let x = i as f64 * 0.01;
            tr.push(&sample(x, [x, 0.0, 0.3], [0.0; 3], [1.0, 0.0, 0.0], x));
        }
        let m = tr.metrics();
        assert_eq!(m.cusps_passed, 0);
        assert!(close(m.progress_m, len, 1e-9), "{m:?}");
        assert!(close(m.max_cross_track_m, 1.0, 1e-9), "{m:?}");
        assert!(m.max_heading_error_deg < 1e-9, "{m:?}");
    }

    #[test]
    fn target_heading_follows_the_policy() {
        let route = there_and_back(10.0);
        let path = |s, rev| target_heading_rad(&route, s, rev, HeadingMode::Path, 0.0);
        assert!(close(path(5.0, false), 0.0, 1e-12));
        // Past the cusp the tangent points back (−x); reversed, the target is +x again.
        assert!(close(path(15.0, false).abs(), PI, 1e-12));
        assert!(close(path(15.0, true), 0.0, 1e-12));
        let fixed = |s| target_heading_rad(&route, s, true, HeadingMode::Fixed, 30f64.to_radians());
        assert!(close(fixed(15.0), 30f64.to_radians(), 1e-12));
        assert!(close(fixed(2.0), 30f64.to_radians(), 1e-12));
    }
}
