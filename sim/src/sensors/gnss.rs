//! RTK GNSS receiver, u-blox ZED-F9P-like (`[sensors.gnss]`, `[faults]`).
//!
//! - **Epochs** are aligned to absolute time: the multiples of the period since the Unix
//!   epoch ([`EpochClock::aligned`]), the first at or after `ctx.start`, like a receiver
//!   whose measurement epochs are aligned to GPS time.
//! - **Solution type** at an epoch: the last `[[faults.gnss]]` window containing it
//!   (window times are seconds after `ctx.start`, half-open `[start_s, end_s)`), else
//!   `nominal_status`.
//! - **Position error**: one independent three-axis first-order Gauss-Markov process per
//!   solution type (`rtk_fixed`, `rtk_float`, `single`): east and north with
//!   `sigma_horizontal_m`, up with `sigma_vertical_m`, each type with its own correlation
//!   time (0 = white). All three are advanced every epoch whatever the current type, so
//!   the error after a switch does not depend on how long the other types were active
//!   (the same seed gives the same single-point error with or without an RTK fault
//!   window before it). The fix is the antenna's true position plus the active type's
//!   error, converted ENU → WGS84 with the scenario's [`LocalEnu`] (exact, via ECEF).
//! - **Reported covariance**: `diag(σ_h², σ_h², σ_v²) · reported_variance_scale` (ENU, m²),
//!   the steady-state covariance of the active error process times the factor.
//! - **No fix**: status `NoFix`, position NaN, covariance zero, and no velocity message.
//! - **Velocity** (each epoch with a fix): the antenna's true ENU velocity plus white
//!   noise of σ `velocity_sigma_mps` per axis, covariance `σ²·I`.
//! - **Sky** (`[sensors.gnss.sky] enabled`, [`super::sky`]): the solution type comes from
//!   the satellites the antenna sees through the world, capped by the fault windows; the
//!   error and reported covariance scale with the DOP, foliage adds multipath; each epoch
//!   also publishes a [`GnssSkyMsg`] (`/gnss/gpsfix`). Its random stream is
//!   `sensors.gnss.sky`, so the `sensors.gnss` draws stay those of a receiver without it.

use super::noise::{GaussMarkov3, white3};
use super::sky::{LineOfSight, SkyConfig, SkyState};
use super::{EpochClock, SensorContext, SensorModel, latency_from_ms, mount, require_rate};
use crate::params::{
    GnssErrorParams, GnssFault, GnssParams, ParamError, require_non_negative, require_positive,
};
use crate::rng;
use crate::truth::TruthSample;
use nalgebra::{Isometry3, Matrix3, Vector3};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;
use vinebench_msgs::geodesy::{Geodetic, LocalEnu};
use vinebench_msgs::{
    FixStatus, FrameId, GnssFixMsg, GnssSkyMsg, GnssVelocityMsg, Message, Nanos, TimedMessage,
};

/// A forced solution type during `[start, end)` (times after the run's first sample).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StatusWindow {
    /// Window start, relative to `ctx.start`.
    pub start: Nanos,
    /// Window end (exclusive), relative to `ctx.start`.
    pub end: Nanos,
    /// The solution type inside the window.
    pub status: FixStatus,
}

/// Checks `[[faults.gnss]]` (finite times, `0 ≤ start_s < end_s`) and converts the
/// windows to nanoseconds, in file order.
pub fn status_windows(faults: &[GnssFault]) -> Result<Vec<StatusWindow>, ParamError> {
    faults
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let path = |k: &str| format!("faults.gnss[{i}].{k}");
            require_non_negative(&path("start_s"), f.start_s)?;
            if !(f.end_s.is_finite() && f.end_s > f.start_s) {
                return Err(ParamError::new(
                    path("end_s"),
                    format!("a finite time after start_s = {} s", f.start_s),
                    f.end_s,
                ));
            }
            Ok(StatusWindow {
                start: Nanos::from_secs_f64(f.start_s),
                end: Nanos::from_secs_f64(f.end_s),
                status: f.status.into(),
            })
        })
        .collect()
}

/// The error model of one solution type: its process and its reported covariance.
#[derive(Clone, Debug)]
struct SolutionError {
    process: GaussMarkov3,
    reported_covariance: Matrix3<f64>,
}

impl SolutionError {
    fn new(
        p: &GnssErrorParams,
        path: &str,
        scale: f64,
        dt: f64,
        rng: &mut ChaCha8Rng,
    ) -> Result<SolutionError, ParamError> {
        let h = require_non_negative(&format!("{path}.sigma_horizontal_m"), p.sigma_horizontal_m)?;
        let v = require_non_negative(&format!("{path}.sigma_vertical_m"), p.sigma_vertical_m)?;
        let tau =
            require_non_negative(&format!("{path}.correlation_time_s"), p.correlation_time_s)?;
        let sigma = Vector3::new(h, h, v);
        Ok(SolutionError {
            process: GaussMarkov3::stationary(sigma, tau, dt, rng),
            reported_covariance: Matrix3::from_diagonal(&sigma.map(|s| s * s * scale)),
        })
    }
}

/// The sky model of a receiver: its state and the world it looks through.
struct Sky {
    state: SkyState,
    sight: Arc<dyn LineOfSight>,
}

/// The simulated GNSS receiver. Random streams `sensors.gnss` and `sensors.gnss.sky`.
pub struct Gnss {
    frame_id: FrameId,
    body_from_antenna: Isometry3<f64>,
    clock: EpochClock,
    latency: Nanos,
    start: Nanos,
    nominal: FixStatus,
    windows: Vec<StatusWindow>,
    enu: LocalEnu,
    rng: ChaCha8Rng,
    rtk_fixed: SolutionError,
    rtk_float: SolutionError,
    single: SolutionError,
    velocity_sigma: Vector3<f64>,
    velocity_covariance: Matrix3<f64>,
    sky: Option<Sky>,
}

impl Gnss {
    /// Checks `[sensors.gnss]` and the fault windows, and builds the receiver.
    pub fn new(
        p: &GnssParams,
        faults: &[GnssFault],
        ctx: &SensorContext,
    ) -> Result<Gnss, ParamError> {
        Gnss::with_windows(p, status_windows(faults)?, ctx, None)
    }

    /// Like [`Gnss::new`] with fault windows already checked by [`status_windows`], and
    /// `sight` the world the antenna looks through (needed with `sky.enabled`).
    pub fn with_windows(
        p: &GnssParams,
        windows: Vec<StatusWindow>,
        ctx: &SensorContext,
        sight: Option<Arc<dyn LineOfSight>>,
    ) -> Result<Gnss, ParamError> {
        let path = |k: &str| format!("sensors.gnss.{k}");
        let rate_hz = require_rate(&path("rate_hz"), p.rate_hz)?;
        let latency = latency_from_ms(&path("latency_ms"), p.latency_ms, rate_hz)?;
        let vel_sigma = require_non_negative(&path("velocity_sigma_mps"), p.velocity_sigma_mps)?;
        let scale = require_positive(&path("reported_variance_scale"), p.reported_variance_scale)?;
        let body_from_antenna = mount(ctx, "gnss", &p.frame)?;
        let dt = 1.0 / rate_hz;
        let mut rng = rng::stream(ctx.master_seed, "sensors.gnss");
        // Draw order (fixed): initial states of rtk_fixed, rtk_float, single.
        let rtk_fixed = SolutionError::new(&p.rtk_fixed, &path("rtk_fixed"), scale, dt, &mut rng)?;
        let rtk_float = SolutionError::new(&p.rtk_float, &path("rtk_float"), scale, dt, &mut rng)?;
        let single = SolutionError::new(&p.single, &path("single"), scale, dt, &mut rng)?;
        let sky = if p.sky.enabled {
            let cfg = SkyConfig::new(&p.sky)?;
            let sight = sight.ok_or_else(|| {
                ParamError::new(
                    path("sky.enabled"),
                    "false where no world geometry is built",
                    "true",
                )
            })?;
            let rng = rng::stream(ctx.master_seed, "sensors.gnss.sky");
            Some(Sky {
                state: SkyState::new(cfg, dt, rng),
                sight,
            })
        } else {
            None
        };
        Ok(Gnss {
            frame_id: FrameId::new(&p.frame),
            body_from_antenna,
            clock: EpochClock::aligned(rate_hz, ctx.start),
            latency,
            start: ctx.start,
            nominal: p.nominal_status.into(),
            windows,
            enu: ctx.enu.clone(),
            rng,
            rtk_fixed,
            rtk_float,
            single,
            velocity_sigma: Vector3::repeat(vel_sigma),
            velocity_covariance: Matrix3::identity() * (vel_sigma * vel_sigma),
            sky,
        })
    }

    /// The solution type at epoch `t`.
    pub fn status_at(&self, t: Nanos) -> FixStatus {
        let rel = t - self.start;
        self.windows
            .iter()
            .rev()
            .find(|w| w.start <= rel && rel < w.end)
            .map_or(self.nominal, |w| w.status)
    }

    /// `body_from_antenna`, from the robot's URDF.
    pub fn body_from_antenna(&self) -> &Isometry3<f64> {
        &self.body_from_antenna
    }
}

impl SensorModel for Gnss {
    fn name(&self) -> &'static str {
        "gnss"
    }

    fn next_time(&self) -> Nanos {
        self.clock.time()
    }

    fn sample(&mut self, truth: &TruthSample, out: &mut Vec<TimedMessage>) {
        let stamp = self.clock.time();
        debug_assert_eq!(truth.stamp, stamp, "the runner must sample at next_time()");
        let forced = self.status_at(stamp);
        let k = truth.at_mount(&self.body_from_antenna);
        // Draw order per epoch (fixed): velocity noise (also without a fix), then the
        // three error processes step to the next epoch.
        let velocity_noise = white3(&mut self.rng, &self.velocity_sigma);
        let antenna = k.world_from_sensor.translation.vector;
        let sky = self.sky.as_mut().map(|sky| {
            let e = sky
                .state
                .epoch(stamp, self.enu.origin(), &antenna, &*sky.sight, forced);
            let (h, v) = sky.state.dop_scale(e.dop.as_ref());
            (e, Vector3::new(h, h, v))
        });
        let status = sky.as_ref().map_or(forced, |(e, _)| e.status);
        let active = match status {
            FixStatus::RtkFixed => Some(&self.rtk_fixed),
            FixStatus::RtkFloat => Some(&self.rtk_float),
            FixStatus::Single => Some(&self.single),
            FixStatus::NoFix => None,
        };
        let arrival = stamp + self.latency;
        let nan = Geodetic {
            lat_deg: f64::NAN,
            lon_deg: f64::NAN,
            alt_m: f64::NAN,
        };
        let (position, position_covariance) = match (active, &sky) {
            (None, _) => (nan, Matrix3::zeros()),
            (Some(err), None) => (
                self.enu.geodetic_from_enu(&(antenna + err.process.value())),
                err.reported_covariance,
            ),
            (Some(err), Some((e, scale))) => {
                // The error at the epoch's DOP, plus multipath the receiver does not know.
                let p_in_world = antenna + err.process.value().component_mul(scale) + e.multipath;
                let s = Matrix3::from_diagonal(scale);
                (
                    self.enu.geodetic_from_enu(&p_in_world),
                    s * err.reported_covariance * s,
                )
            }
        };
        out.push(TimedMessage {
            arrival,
            msg: Message::GnssFix(GnssFixMsg {
                stamp,
                frame_id: self.frame_id.clone(),
                status,
                position,
                position_covariance,
            }),
        });
        if active.is_some() {
            out.push(TimedMessage {
                arrival,
                msg: Message::GnssVelocity(GnssVelocityMsg {
                    stamp,
                    frame_id: self.frame_id.clone(),
                    velocity_in_world: k.velocity_in_world + velocity_noise,
                    covariance: self.velocity_covariance,
                }),
            });
        }
        if let Some((e, _)) = sky {
            out.push(TimedMessage {
                arrival,
                msg: Message::GnssSky(GnssSkyMsg {
                    stamp,
                    frame_id: self.frame_id.clone(),
                    status,
                    position,
                    position_covariance,
                    dop: e.dop,
                    corrections: self.sky.as_ref().is_some_and(|s| s.state.corrections()),
                    satellites: e.satellites,
                }),
            });
        }
        self.rtk_fixed.process.step(&mut self.rng);
        self.rtk_float.process.step(&mut self.rng);
        self.single.process.step(&mut self.rng);
        self.clock.advance();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::GnssStatusParam;
    use crate::sensors::noise::stats::autocorrelation;
    use crate::sensors::test_support::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// The antenna lever arm of the built-in robot: sensor_frame (0.30, 0, 0.18) +
    /// sensor_box (0, 0, 0.62) + antenna (−0.08, 0, 0.32), read off the URDF.
    const LEVER: [f64; 3] = [0.22, 0.0, 1.12];

    fn noise_free() -> GnssParams {
        let zero = GnssErrorParams {
            sigma_horizontal_m: 0.0,
            sigma_vertical_m: 0.0,
            correlation_time_s: 1.0,
        };
        GnssParams {
            velocity_sigma_mps: 0.0,
            rtk_fixed: zero.clone(),
            rtk_float: zero.clone(),
            single: zero,
            ..GnssParams::default()
        }
    }

    /// Short correlation times so that statistics converge in a few thousand epochs.
    fn fast(p: GnssParams, tau: f64) -> GnssParams {
        let f = |e: GnssErrorParams| GnssErrorParams {
            correlation_time_s: tau,
            ..e
        };
        GnssParams {
            rtk_fixed: f(p.rtk_fixed),
            rtk_float: f(p.rtk_float),
            single: f(p.single),
            ..p
        }
    }

    fn fixes(out: &[TimedMessage]) -> Vec<&GnssFixMsg> {
        out.iter()
            .filter_map(|m| {
                if let Message::GnssFix(f) = &m.msg {
                    Some(f)
                } else {
                    None
                }
            })
            .collect()
    }

    fn velocities(out: &[TimedMessage]) -> Vec<&GnssVelocityMsg> {
        out.iter()
            .filter_map(|m| {
                if let Message::GnssVelocity(v) = &m.msg {
                    Some(v)
                } else {
                    None
                }
            })
            .collect()
    }

    fn window(start_s: f64, end_s: f64, status: GnssStatusParam) -> GnssFault {
        GnssFault {
            start_s,
            end_s,
            status,
        }
    }

    /// ENU errors (reported − true antenna) of every fix with a position.
    fn errors(
        gnss: &Gnss,
        c: &SensorContext,
        out: &[TimedMessage],
        truth: &dyn Fn(Nanos) -> TruthSample,
    ) -> Vec<(FixStatus, Vector3<f64>, Matrix3<f64>)> {
        fixes(out)
            .iter()
            .filter(|f| f.status != FixStatus::NoFix)
            .map(|f| {
                let antenna = truth(f.stamp)
                    .at_mount(gnss.body_from_antenna())
                    .world_from_sensor;
                let e = c.enu.enu_from_geodetic(&f.position) - antenna.translation.vector;
                (f.status, e, f.position_covariance)
            })
            .collect()
    }

    #[test]
    fn noise_free_fix_is_the_antenna_position_and_velocity() {
        // On the circle (radius 6 m, 1.2 m/s) the antenna is at p + Rz(θ)·lever and moves
        // at v + ω ẑ × (Rz(θ)·lever); the fix, read back through LocalEnu, must match to
        // 1e-6 m (the ellipsoid round trip is exact to ~1e-9 m).
        let c = ctx(1);
        let mut g = Gnss::new(&noise_free(), &[], &c).unwrap();
        let (radius, speed) = (6.0, 1.2);
        let truth = |t| circle(t, radius, speed, Drive::IDEAL);
        let out = run_n(&mut g, &truth, 300);
        let lever = Vector3::from(LEVER);
        for f in fixes(&out) {
            let tr = truth(f.stamp);
            let rot = tr.world_from_body.rotation;
            let antenna = tr.world_from_body.translation.vector + rot * lever;
            let p = c.enu.enu_from_geodetic(&f.position);
            assert!((p - antenna).norm() < 1e-6, "{:?}", p - antenna);
            assert_eq!(f.status, FixStatus::RtkFixed);
            assert_eq!(f.frame_id.as_str(), "gnss_antenna");
        }
        let omega = Vector3::new(0.0, 0.0, speed / radius);
        for v in velocities(&out) {
            let tr = truth(v.stamp);
            let expected =
                tr.velocity_in_world + omega.cross(&(tr.world_from_body.rotation * lever));
            assert!((v.velocity_in_world - expected).norm() < 1e-12);
        }
        // Tilted and at rest: the lever arm follows the attitude.
        let pose = Isometry3::from_parts(
            Translation3::new(40.0, -25.0, 3.0),
            UnitQuaternion::from_euler_angles(0.2, -0.1, 2.5),
        );
        let mut g = Gnss::new(&noise_free(), &[], &c).unwrap();
        let out = run_n(&mut g, &|t| stationary(t, pose), 3);
        for f in fixes(&out) {
            let p = c.enu.enu_from_geodetic(&f.position);
            assert!((p - (pose * nalgebra::Point3::from(lever)).coords).norm() < 1e-6);
        }
    }

    #[test]
    fn epochs_are_multiples_of_the_period_since_the_unix_epoch() {
        // START is 37 ms past a 100 ms boundary: the first 10 Hz epoch is 63 ms later.
        let c = ctx(1);
        let mut g = Gnss::new(&GnssParams::default(), &[], &c).unwrap();
        assert_eq!(g.next_time(), START + Nanos(63_000_000));
        let out = run_n(&mut g, &|t| stationary(t, Isometry3::identity()), 50);
        for (i, f) in fixes(&out).iter().enumerate() {
            assert_eq!(f.stamp.0 % 100_000_000, 0);
            assert_eq!(f.stamp, START + Nanos(63_000_000 + 100_000_000 * i as i64));
        }
        for m in &out {
            assert_eq!(m.arrival, m.msg.stamp() + Nanos(60_000_000));
        }
        // 4 Hz: multiples of 250 ms.
        let p = GnssParams {
            rate_hz: 4.0,
            ..GnssParams::default()
        };
        let mut g = Gnss::new(&p, &[], &c).unwrap();
        let out = run_n(&mut g, &|t| stationary(t, Isometry3::identity()), 9);
        let stamps: Vec<i64> = fixes(&out).iter().map(|f| f.stamp.0).collect();
        assert!(stamps.iter().all(|s| s % 250_000_000 == 0));
        assert!(stamps[0] >= START.0 && stamps[0] - START.0 < 250_000_000);
    }

    #[test]
    fn fault_windows_set_the_status_at_the_right_epochs() {
        // Windows overlap: the later one wins in [12, 13) s.
        let faults = [
            window(2.0, 5.0, GnssStatusParam::NoFix),
            window(10.0, 13.0, GnssStatusParam::Single),
            window(12.0, 14.0, GnssStatusParam::RtkFloat),
        ];
        let c = ctx(3);
        let mut g = Gnss::new(&GnssParams::default(), &faults, &c).unwrap();
        let out = run_n(&mut g, &|t| circle(t, 10.0, 1.0, Drive::IDEAL), 200);
        let vel_stamps: Vec<Nanos> = velocities(&out).iter().map(|v| v.stamp).collect();
        let fx = fixes(&out);
        assert_eq!(fx.len(), 200);
        for f in &fx {
            // Independent oracle: seconds since START, windows as written above.
            let s = secs(f.stamp);
            let expected = if (12.0..14.0).contains(&s) {
                FixStatus::RtkFloat
            } else if (10.0..13.0).contains(&s) {
                FixStatus::Single
            } else if (2.0..5.0).contains(&s) {
                FixStatus::NoFix
            } else {
                FixStatus::RtkFixed
            };
            assert_eq!(f.status, expected, "at {s} s");
            Message::GnssFix((*f).clone()).validate().unwrap();
            let has_velocity = vel_stamps.contains(&f.stamp);
            if f.status == FixStatus::NoFix {
                assert!(
                    f.position.lat_deg.is_nan()
                        && f.position.lon_deg.is_nan()
                        && f.position.alt_m.is_nan()
                );
                assert_eq!(f.position_covariance, Matrix3::zeros());
                assert!(!has_velocity, "velocity without a fix at {s} s");
            } else {
                assert!(f.position.is_valid());
                assert!(has_velocity);
            }
        }
        // The window edges: 1.963 s is before the NoFix window, 2.063 s inside; 4.963 s
        // inside, 5.063 s after.
        let st = |s: f64| g.status_at(START + Nanos::from_secs_f64(s));
        assert_eq!(
            (st(1.999), st(2.0), st(4.999), st(5.0)),
            (
                FixStatus::RtkFixed,
                FixStatus::NoFix,
                FixStatus::NoFix,
                FixStatus::RtkFixed
            )
        );
        assert_eq!(
            fx.iter().filter(|f| f.status == FixStatus::NoFix).count(),
            30
        );
    }

    #[test]
    fn switching_type_is_deterministic_because_every_process_advances() {
        // During a `single` window, the fix equals that of a receiver that was `single`
        // all along with the same seed: the single process advanced while RTK was active.
        let c = ctx(4);
        let truth = |t| circle(t, 10.0, 1.0, Drive::IDEAL);
        let mut a = Gnss::new(
            &GnssParams::default(),
            &[window(20.0, 30.0, GnssStatusParam::Single)],
            &c,
        )
        .unwrap();
        let p = GnssParams {
            nominal_status: GnssStatusParam::Single,
            ..GnssParams::default()
        };
        let mut b = Gnss::new(&p, &[], &c).unwrap();
        let fa = run_n(&mut a, &truth, 400);
        let fb = run_n(&mut b, &truth, 400);
        let mut compared = 0;
        for (x, y) in fixes(&fa).iter().zip(fixes(&fb)) {
            if x.status == FixStatus::Single {
                assert_eq!(*x, y);
                compared += 1;
            } else {
                assert_ne!(x.position, y.position);
            }
        }
        assert_eq!(compared, 100);
    }

    #[test]
    fn nees_per_status_is_three_and_correlation_matches() {
        // Correlation times 0.3 s at 10 Hz: φ = e^{−1/3} = 0.7165. 18 000 epochs, 6000
        // in each solution type (three 600 s blocks). For each
        // type, the mean NEES of AR(1) errors over N = 6000 epochs has variance
        // 3·2·(1+φ²)/((1−φ²)·N) ≈ 3.1e-3 (std 0.056); tolerance 0.3 (5σ). Lag-1
        // autocorrelation over 18 000 epochs of the single-type process (run alone):
        // std √((1−φ²)/N) = 0.005; tolerance 0.03.
        let c = ctx(12);
        let p = fast(GnssParams::default(), 0.3);
        let faults = [
            window(600.0, 1200.0, GnssStatusParam::RtkFloat),
            window(1200.0, 1800.0, GnssStatusParam::Single),
        ];
        let truth = |t| circle(t, 15.0, 1.0, Drive::IDEAL);
        let mut g = Gnss::new(&p, &faults, &c).unwrap();
        let out = run_n(&mut g, &truth, 18_000);
        let errs = errors(&g, &c, &out, &truth);
        for status in [FixStatus::RtkFixed, FixStatus::RtkFloat, FixStatus::Single] {
            let sel: Vec<_> = errs.iter().filter(|e| e.0 == status).collect();
            assert!(sel.len() > 5900, "{status:?}: {}", sel.len());
            let nees = sel
                .iter()
                .map(|(_, e, cov)| (e.transpose() * cov.try_inverse().unwrap() * e)[0])
                .sum::<f64>()
                / sel.len() as f64;
            assert!((nees - 3.0).abs() < 0.3, "{status:?}: mean NEES {nees}");
        }
        // The reported covariance is exactly diag(σ_h², σ_h², σ_v²) of the active type.
        let single_cov = errs.iter().find(|e| e.0 == FixStatus::Single).unwrap().2;
        assert_eq!(
            single_cov,
            Matrix3::from_diagonal(&Vector3::new(1.44, 1.44, 6.25))
        );

        let p_single = GnssParams {
            nominal_status: GnssStatusParam::Single,
            ..p.clone()
        };
        let mut g = Gnss::new(&p_single, &[], &c).unwrap();
        let out = run_n(&mut g, &truth, 18_000);
        let errs = errors(&g, &c, &out, &truth);
        let phi = (-1.0f64 / 3.0).exp();
        for axis in 0..3 {
            let x: Vec<f64> = errs.iter().map(|e| e.1[axis]).collect();
            let r = autocorrelation(&x, 1);
            assert!((r - phi).abs() < 0.03, "axis {axis}: lag-1 {r} vs {phi}");
        }

        // A pessimistic receiver (scale 4) reports 4× the variance: mean NEES ≈ 3/4.
        let p4 = GnssParams {
            reported_variance_scale: 4.0,
            ..p
        };
        let mut g = Gnss::new(&p4, &[], &c).unwrap();
        let out = run_n(&mut g, &truth, 6000);
        let errs = errors(&g, &c, &out, &truth);
        let nees = errs
            .iter()
            .map(|(_, e, cov)| (e.transpose() * cov.try_inverse().unwrap() * e)[0])
            .sum::<f64>()
            / errs.len() as f64;
        assert!((nees - 0.75).abs() < 0.08, "scaled NEES {nees}");
    }

    #[test]
    fn velocity_noise_matches_its_covariance() {
        // White velocity noise: 5000 epochs × 3 axes, mean NEES 3 with std √(6/5000) =
        // 0.035; tolerance 0.2.
        let c = ctx(13);
        let mut g = Gnss::new(&GnssParams::default(), &[], &c).unwrap();
        let truth = |t| circle(t, 15.0, 1.0, Drive::IDEAL);
        let out = run_n(&mut g, &truth, 5000);
        let vs = velocities(&out);
        let nees = vs
            .iter()
            .map(|v| {
                let k = truth(v.stamp).at_mount(g.body_from_antenna());
                let e = v.velocity_in_world - k.velocity_in_world;
                (e.transpose() * v.covariance.try_inverse().unwrap() * e)[0]
            })
            .sum::<f64>()
            / vs.len() as f64;
        assert!((nees - 3.0).abs() < 0.2, "velocity NEES {nees}");
        assert_eq!(vs[0].covariance, Matrix3::identity() * 0.03f64.powi(2));
    }
}
