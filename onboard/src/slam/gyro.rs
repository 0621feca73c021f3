//! The body's rotation between two stamps from the IMU's gyro, for cameras that run free:
//! a stereo pair stamped `Δt` away from its rig frame is seen from a body that turned by
//! [`GyroBuffer::rotation`] in between.
//!
//! The angular rates (rotated from the IMU into the body frame) are kept for the last
//! [`GyroBuffer::KEEP`]; the rotation from `t0` to `t1` integrates them on SO(3),
//! `R ← R · Exp(ω̄ δt)` over each interval between samples (and the parts of the first
//! and last ones inside `[t0, t1]`), `ω̄` the rate at the interval's midpoint, linearly
//! interpolated: exact for a rate that is constant about a fixed axis, second order
//! otherwise. Over the tens of milliseconds between free-running cameras a MEMS gyro's
//! bias (10 °/h for an MTi-300) is negligible, far below what a constant-velocity guess
//! misses on a shaking chassis.
//!
//! ```
//! use nalgebra::{UnitQuaternion, Vector3};
//! use vinebench_onboard::slam::gyro::GyroBuffer;
//! use vinebench_msgs::Nanos;
//!
//! let mut gyro = GyroBuffer::default();
//! // 200 Hz, turning left at 0.5 rad/s.
//! for i in 0..40 {
//!     gyro.push(Nanos(i * 5_000_000), Vector3::new(0.0, 0.0, 0.5));
//! }
//! let r = gyro.rotation(Nanos(20_000_000), Nanos(82_000_000)).expect("covered");
//! let expected = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.5 * 0.062));
//! assert!(r.angle_to(&expected) < 1e-12);
//! ```

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector3};
use vinebench_msgs::Nanos;

/// Recent body-frame angular rates, by stamp.
#[derive(Clone, Debug, Default)]
pub struct GyroBuffer {
    /// `(stamp, ω)` with `ω` in the body frame (rad/s), stamps increasing.
    samples: VecDeque<(Nanos, Vector3<f64>)>,
}

impl GyroBuffer {
    /// How long samples are kept behind the newest (free-running cameras are paired
    /// within `slam.max_camera_offset_s`, and images arrive after their latency).
    pub const KEEP: Nanos = Nanos(2_000_000_000);

    /// Adds a body-frame angular rate (rad/s) measured at `stamp`. A sample not after
    /// the newest is ignored (the IMU's stream is in stamp order).
    pub fn push(&mut self, stamp: Nanos, omega_body: Vector3<f64>) {
        if self.samples.back().is_some_and(|(t, _)| *t >= stamp) {
            return;
        }
        self.samples.push_back((stamp, omega_body));
        while self
            .samples
            .front()
            .is_some_and(|(t, _)| *t + Self::KEEP < stamp)
        {
            self.samples.pop_front();
        }
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// No samples.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// `body(t0)_from_body(t1)`; `None` unless samples cover `[min(t0, t1), max(t0, t1)]`.
    pub fn rotation(&self, t0: Nanos, t1: Nanos) -> Option<UnitQuaternion<f64>> {
        if t1 < t0 {
            return self.rotation(t1, t0).map(|r| r.inverse());
        }
        let (first, _) = *self.samples.front()?;
        let (last, _) = *self.samples.back()?;
        if t0 < first || t1 > last {
            return None;
        }
        let mut r = UnitQuaternion::identity();
        let start = self.samples.partition_point(|(t, _)| *t <= t0).max(1) - 1;
        for i in start..self.samples.len() - 1 {
            let (ta, wa) = self.samples[i];
            let (tb, wb) = self.samples[i + 1];
            if ta >= t1 {
                break;
            }
            let (a, b) = (ta.max(t0), tb.min(t1));
            if b <= a {
                continue;
            }
            let span = (tb - ta).as_secs_f64();
            let mid = 0.5 * ((a - ta).as_secs_f64() + (b - ta).as_secs_f64()) / span;
            let omega = wa + (wb - wa) * mid;
            r *= UnitQuaternion::from_scaled_axis(omega * (b - a).as_secs_f64());
        }
        Some(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: i64 = 1_000_000;

    /// A rate ramping linearly about a fixed axis: the angle is the integral, in closed
    /// form, and the midpoint rule is exact for it.
    #[test]
    fn a_ramping_rate_about_one_axis_integrates_exactly() {
        let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
        let rate = |t: f64| 0.3 + 4.0 * t;
        let mut gyro = GyroBuffer::default();
        for i in 0..100 {
            let t = i as f64 * 0.005;
            gyro.push(Nanos(i * 5 * MS), axis * rate(t));
        }
        let (t0, t1) = (0.0123, 0.1987);
        let angle = 0.3 * (t1 - t0) + 2.0 * (t1 * t1 - t0 * t0);
        let r = gyro
            .rotation(Nanos::from_secs_f64(t0), Nanos::from_secs_f64(t1))
            .expect("covered");
        let expected = UnitQuaternion::from_scaled_axis(axis * angle);
        assert!(r.angle_to(&expected) < 1e-9, "{}", r.angle_to(&expected));
        // Backwards is the inverse.
        let back = gyro
            .rotation(Nanos::from_secs_f64(t1), Nanos::from_secs_f64(t0))
            .expect("covered");
        assert!(back.angle_to(&expected.inverse()) < 1e-9);
        // Empty interval: identity.
        let none = gyro
            .rotation(Nanos(50 * MS), Nanos(50 * MS))
            .expect("covered");
        assert!(none.angle() < 1e-15);
    }

    /// A rate turning about a moving axis: against a fine numerical integration of the
    /// same (linearly interpolated) rate.
    #[test]
    fn a_varying_axis_matches_fine_integration() {
        let omega = |t: f64| {
            Vector3::new(
                0.4 * (30.0 * t).sin(),
                0.3 * (23.0 * t).cos(),
                0.5 + 0.2 * (11.0 * t).sin(),
            )
        };
        let mut gyro = GyroBuffer::default();
        for i in 0..60 {
            gyro.push(Nanos(i * 5 * MS), omega(i as f64 * 0.005));
        }
        let (t0, t1) = (0.021, 0.187);
        let r = gyro
            .rotation(Nanos::from_secs_f64(t0), Nanos::from_secs_f64(t1))
            .expect("covered");
        // Fine integration of the piecewise-linear rate.
        let interp = |t: f64| {
            let i = (t / 0.005).floor();
            let f = t / 0.005 - i;
            omega(i * 0.005) * (1.0 - f) + omega((i + 1.0) * 0.005) * f
        };
        let steps = 100_000;
        let dt = (t1 - t0) / steps as f64;
        let mut fine = UnitQuaternion::identity();
        for k in 0..steps {
            fine *= UnitQuaternion::from_scaled_axis(interp(t0 + (k as f64 + 0.5) * dt) * dt);
        }
        // Second-order error of the midpoint rule on 5 ms intervals: micro-radians.
        assert!(r.angle_to(&fine) < 2e-5, "{}", r.angle_to(&fine));
        assert!(fine.angle() > 0.05);
    }

    #[test]
    fn outside_the_samples_there_is_no_rotation_and_old_samples_go() {
        let mut gyro = GyroBuffer::default();
        assert!(gyro.rotation(Nanos(0), Nanos(1)).is_none());
        for i in 0..1000 {
            gyro.push(Nanos(i * 5 * MS), Vector3::new(0.0, 0.0, 1.0));
        }
        // An out-of-order sample is ignored.
        gyro.push(Nanos(10 * MS), Vector3::new(9.0, 9.0, 9.0));
        assert_eq!(gyro.len(), 401, "2 s at 200 Hz, both ends");
        assert!(
            gyro.rotation(Nanos(4_000 * MS), Nanos(4_990 * MS))
                .is_some()
        );
        assert!(
            gyro.rotation(Nanos(2_000 * MS), Nanos(4_990 * MS))
                .is_none()
        );
        assert!(
            gyro.rotation(Nanos(4_900 * MS), Nanos(5_000 * MS))
                .is_none()
        );
    }
}
