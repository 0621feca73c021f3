//! The GNSS receiver's sky (`[sensors.gnss.sky]`): which satellites the antenna sees
//! through the world, and what solution that allows.
//!
//! - **Constellation** ([`constellation`]): GPS, the 24-slot reference constellation
//!   (six planes A–F, right ascensions of the ascending nodes and arguments of latitude of
//!   each slot at 1 July 1993 0 h UT, a = 26 559.7 km, i = 55°), and Galileo, the Walker
//!   24/3/1 reference constellation (a = 29 600.318 km, i = 56°, three planes 120° apart,
//!   eight slots 45° apart, 15° phase step between planes), GLONASS (24 in three planes,
//!   a = 25 508.2 km, i = 64.8°) and the BeiDou-3 MEO constellation (Walker 24/3/1,
//!   a = 27 906.1 km, i = 55°); the Walker planes' nodes at J2000 are our choice.
//!   Circular Keplerian orbits, `μ` and `Ω_E` of IS-GPS-200; the Earth turns
//!   under them by Greenwich mean sidereal time ([`gmst_rad`]). Almanac-like: a realistic
//!   sky for the scenario's date and place, not the real satellites of that day.
//! - **Line of sight** ([`LineOfSight`]): a ray from the antenna towards each satellite
//!   through the world's own render geometry. Leaves, shoots and bunches let part of the
//!   signal through (each crossing keeps `leaf_transmission` of its power); trellis wire
//!   is too thin to matter; anything else (posts, boards, occluders, the ground, a loaded
//!   mesh) blocks it.
//! - **C/N0**: `cn0_horizon + (cn0_zenith − cn0_horizon)·sin(elevation)`, minus the
//!   foliage loss, plus a per-satellite fading process (Gauss-Markov, `cn0_sigma_db`,
//!   `cn0_correlation_time_s`). Tracked: above the elevation mask and at least
//!   `tracking_cn0_dbhz`.
//! - **Solution** ([`SkyState`]): fewer than four tracked satellites or a PDOP above
//!   `max_pdop` give no fix; with corrections and at least `rtk_min_satellites` tracked,
//!   an RTK solution, fixed once `fix_min_satellites` of them reach `fix_cn0_dbhz` for a
//!   time-to-fix drawn from a log-normal (median `time_to_fix_s`, log-σ
//!   `time_to_fix_spread`); a fix survives shorter gaps than `fix_hold_s`, a longer one
//!   restarts the convergence (float meanwhile). Otherwise a single-point solution. The
//!   receiver was on before the run: a first epoch that allows a fix is fixed.
//! - **Errors**: the solution type's error process (see [`super::gnss`]) scaled by
//!   HDOP / `reference_hdop` (east, north) and VDOP / `reference_vdop` (up), with the
//!   reported covariance scaled alike; plus multipath: each satellite seen through
//!   foliage has a pseudorange bias (Gauss-Markov, σ `multipath_<type>_m`, correlation
//!   `multipath_correlation_time_s`), and the position error is their least-squares
//!   projection `(GᵀG)⁻¹Gᵀb`. The receiver does not know its multipath: the reported
//!   covariance leaves it out, as real receivers' do.

use super::noise::standard_normal;
use crate::params::{GnssSkyParams, ParamError, require_non_negative, require_positive};
use crate::render::Hit;
use crate::render::scene::{Material, RenderScene};
use crate::render::trace::RayCaster;
use nalgebra::{Matrix4, Rotation3, Vector3, Vector4};
use rand::Rng;
use vinebench_msgs::geodesy::{Geodetic, ecef_from_geodetic, enu_from_ecef_rotation};
use vinebench_msgs::{Dop, FixStatus, GnssSatellite, GnssSystem, Nanos};

/// Earth's gravitational constant, m³/s² (IS-GPS-200).
pub const MU_EARTH: f64 = 3.986_005e14;
/// Earth's rotation rate, rad/s (IS-GPS-200).
pub const OMEGA_EARTH: f64 = 7.292_115_146_7e-5;
/// Unix time of the GPS reference constellation's epoch, 1 July 1993 0 h UT.
pub const GPS_REFERENCE_EPOCH_UNIX_S: f64 = 741_484_800.0;
/// Unix time of J2000 (2000-01-01 12:00 UT).
pub const J2000_UNIX_S: f64 = 946_728_000.0;
/// Most surfaces one line of sight may cross before it counts as blocked.
pub const MAX_CROSSINGS: usize = 64;
/// Length of a line of sight through the world, m (well beyond any vineyard).
pub const SIGHT_RANGE_M: f32 = 5_000.0;

/// Greenwich mean sidereal time (IAU 1982, to 0.1 s over decades) at a Unix time, rad.
pub fn gmst_rad(unix_s: f64) -> f64 {
    let days = (unix_s - J2000_UNIX_S) / 86_400.0;
    (280.460_618_37 + 360.985_647_366_29 * days)
        .rem_euclid(360.0)
        .to_radians()
}

/// A circular orbit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    /// Semi-major axis (= radius), m.
    pub a_m: f64,
    /// Inclination, rad.
    pub inclination_rad: f64,
    /// Right ascension of the ascending node at the reference epoch (inertial), rad.
    pub raan_rad: f64,
    /// Argument of latitude at the reference epoch, rad.
    pub arg_lat_rad: f64,
    /// Reference epoch, Unix seconds.
    pub epoch_unix_s: f64,
}

impl Orbit {
    /// Mean motion, rad/s.
    pub fn mean_motion(&self) -> f64 {
        (MU_EARTH / self.a_m.powi(3)).sqrt()
    }

    /// Period, s.
    pub fn period_s(&self) -> f64 {
        std::f64::consts::TAU / self.mean_motion()
    }

    /// Position in the Earth-centred inertial frame (equator and equinox of date, as far
    /// as this model goes), m.
    pub fn position_eci(&self, unix_s: f64) -> Vector3<f64> {
        let u = self.arg_lat_rad + self.mean_motion() * (unix_s - self.epoch_unix_s);
        let (su, cu) = u.sin_cos();
        let (so, co) = self.raan_rad.sin_cos();
        let (si, ci) = self.inclination_rad.sin_cos();
        self.a_m * Vector3::new(co * cu - so * su * ci, so * cu + co * su * ci, su * si)
    }

    /// Position in ECEF: the inertial position turned by −GMST about the pole, m.
    pub fn position_ecef(&self, unix_s: f64) -> Vector3<f64> {
        Rotation3::from_axis_angle(&Vector3::z_axis(), -gmst_rad(unix_s))
            * self.position_eci(unix_s)
    }
}

/// One satellite of the constellation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Satellite {
    /// Its system.
    pub system: GnssSystem,
    /// PRN within the system.
    pub prn: u16,
    /// Its orbit.
    pub orbit: Orbit,
}

/// GPS reference constellation: per plane (A–F), the node's right ascension and the four
/// slots' arguments of latitude at [`GPS_REFERENCE_EPOCH_UNIX_S`], degrees.
const GPS_SLOTS: [(f64, [f64; 4]); 6] = [
    (272.847, [268.126, 161.786, 11.676, 41.806]),
    (332.847, [80.956, 173.336, 309.976, 204.376]),
    (32.847, [111.876, 11.796, 339.666, 241.556]),
    (92.847, [135.226, 265.446, 35.156, 167.356]),
    (152.847, [197.046, 302.596, 66.066, 333.686]),
    (212.847, [238.886, 345.226, 105.206, 135.346]),
];

/// The constellations of `systems`, GPS PRN 1–24 in slot order A1…F4, the others PRN (or
/// slot) 1–24 in plane order.
pub fn constellation(systems: &[GnssSystem]) -> Vec<Satellite> {
    let mut out = Vec::new();
    if systems.contains(&GnssSystem::Gps) {
        for (p, (raan, slots)) in GPS_SLOTS.iter().enumerate() {
            for (s, u) in slots.iter().enumerate() {
                out.push(Satellite {
                    system: GnssSystem::Gps,
                    prn: (p * 4 + s + 1) as u16,
                    orbit: Orbit {
                        a_m: 26_559_700.0,
                        inclination_rad: 55f64.to_radians(),
                        raan_rad: raan.to_radians(),
                        arg_lat_rad: u.to_radians(),
                        epoch_unix_s: GPS_REFERENCE_EPOCH_UNIX_S,
                    },
                });
            }
        }
    }
    for &(system, a_m, inc_deg, node0_deg) in WALKER {
        if !systems.contains(&system) {
            continue;
        }
        // Walker 24/3/1: three planes 120° apart, eight slots 45° apart, 15° between
        // neighbouring planes.
        for p in 0..3 {
            for s in 0..8 {
                out.push(Satellite {
                    system,
                    prn: (p * 8 + s + 1) as u16,
                    orbit: Orbit {
                        a_m,
                        inclination_rad: inc_deg.to_radians(),
                        raan_rad: (node0_deg + 120.0 * p as f64).to_radians(),
                        arg_lat_rad: (45.0 * s as f64 + 15.0 * p as f64).to_radians(),
                        epoch_unix_s: J2000_UNIX_S,
                    },
                });
            }
        }
    }
    out
}

/// The Walker 24/3/1 constellations: system, semi-major axis (m), inclination and plane
/// A's node at J2000 (degrees; the node is our choice, spread between systems).
const WALKER: &[(GnssSystem, f64, f64, f64)] = &[
    (GnssSystem::Galileo, 29_600_318.0, 56.0, 0.0),
    (GnssSystem::Glonass, 25_508_200.0, 64.8, 40.0),
    (GnssSystem::Beidou, 27_906_100.0, 55.0, 80.0),
];

/// Azimuth (clockwise from north) and elevation of `to` seen from `from` (ECEF, m), with
/// `enu_from_ecef` the rotation at `from`; also the ENU unit line of sight.
pub fn azimuth_elevation(
    from: &Vector3<f64>,
    to: &Vector3<f64>,
    enu_from_ecef: &nalgebra::Matrix3<f64>,
) -> (f64, f64, Vector3<f64>) {
    let los = (enu_from_ecef * (to - from)).normalize();
    let az = los.x.atan2(los.y).to_degrees().rem_euclid(360.0);
    let el = los.z.clamp(-1.0, 1.0).asin().to_degrees();
    (az, el, los)
}

/// Dilutions of precision of unit lines of sight (ENU) with one receiver clock: rows
/// `[−eᵀ, 1]` of G, `Q = (GᵀG)⁻¹`. None with fewer than four or a singular geometry.
pub fn dop(lines_of_sight: &[Vector3<f64>]) -> Option<Dop> {
    let q = normal_matrix(lines_of_sight)?;
    let d = q.diagonal();
    if d.iter().any(|x| !(x.is_finite() && *x >= 0.0)) {
        return None;
    }
    Some(Dop {
        gdop: d.sum().sqrt(),
        pdop: (d[0] + d[1] + d[2]).sqrt(),
        hdop: (d[0] + d[1]).sqrt(),
        vdop: d[2].sqrt(),
        tdop: d[3].sqrt(),
    })
}

/// `(GᵀG)⁻¹` of [`dop`].
fn normal_matrix(lines_of_sight: &[Vector3<f64>]) -> Option<Matrix4<f64>> {
    if lines_of_sight.len() < 4 {
        return None;
    }
    let mut n = Matrix4::zeros();
    for e in lines_of_sight {
        let g = Vector4::new(-e.x, -e.y, -e.z, 1.0);
        n += g * g.transpose();
    }
    let inv = n.try_inverse()?;
    // A nearly singular geometry (all satellites on one cone) is no geometry.
    (inv.amax() < 1e6).then_some(inv)
}

/// Least-squares position error (ENU, m) that pseudorange errors `bias_m` cause for
/// lines of sight `los`: the first three components of `(GᵀG)⁻¹Gᵀb`.
pub fn position_error(los: &[Vector3<f64>], bias_m: &[f64]) -> Option<Vector3<f64>> {
    let q = normal_matrix(los)?;
    let mut gtb = Vector4::zeros();
    for (e, b) in los.iter().zip(bias_m) {
        gtb += Vector4::new(-e.x, -e.y, -e.z, 1.0) * *b;
    }
    let x = q * gtb;
    Some(Vector3::new(x[0], x[1], x[2]))
}

/// What a line of sight crosses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sight {
    /// Foliage surfaces crossed (leaves, shoots, bunches).
    pub leaves: u16,
    /// Blocked by something solid.
    pub blocked: bool,
}

/// Traces lines of sight from the antenna through the world.
pub trait LineOfSight: Send + Sync {
    /// What the ray from `from` (world ENU, m) along the unit `dir` crosses.
    fn sight(&self, from: &Vector3<f64>, dir: &Vector3<f64>) -> Sight;
}

/// The render geometry as a [`LineOfSight`].
pub struct SceneSight<'a> {
    /// The scene (materials, its origin in the world).
    pub scene: &'a RenderScene,
    /// Its ray caster.
    pub caster: &'a dyn RayCaster,
}

/// Whether a material lets part of a GNSS signal through: foliage only (wire is thin
/// enough to be transparent and is skipped too).
fn passes(m: Material) -> Option<bool> {
    match m {
        Material::Leaf | Material::Shoot | Material::GrapeRed | Material::GrapeWhite => Some(true),
        Material::Wire => Some(false),
        _ => None,
    }
}

impl LineOfSight for SceneSight<'_> {
    fn sight(&self, from: &Vector3<f64>, dir: &Vector3<f64>) -> Sight {
        let o = from - self.scene.trace.origin_in_world;
        let origin = [o.x as f32, o.y as f32, o.z as f32];
        let d = [dir.x as f32, dir.y as f32, dir.z as f32];
        let mut t_min = 0.0f32;
        let mut sight = Sight::default();
        for _ in 0..MAX_CROSSINGS {
            let hit: Hit = self.caster.cast_ray(origin, d, t_min, SIGHT_RANGE_M);
            if !hit.is_hit() {
                return sight;
            }
            match passes(self.scene.material_of(&hit)) {
                Some(foliage) => {
                    sight.leaves += u16::from(foliage);
                    t_min = hit.t * (1.0 + 1e-6) + 1e-4;
                }
                None => {
                    sight.blocked = true;
                    return sight;
                }
            }
        }
        sight.blocked = true;
        sight
    }
}

impl LineOfSight for crate::render::SceneGeometry {
    fn sight(&self, from: &Vector3<f64>, dir: &Vector3<f64>) -> Sight {
        SceneSight {
            scene: &self.scene,
            caster: &*self.caster,
        }
        .sight(from, dir)
    }
}

impl LineOfSight for crate::render::shade::Renderer {
    fn sight(&self, from: &Vector3<f64>, dir: &Vector3<f64>) -> Sight {
        SceneSight {
            scene: self.scene(),
            caster: self.caster(),
        }
        .sight(from, dir)
    }
}

/// `[sensors.gnss.sky]`, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct SkyConfig {
    systems: Vec<GnssSystem>,
    mask_deg: f64,
    cn0_zenith: f64,
    cn0_horizon: f64,
    cn0_sigma: f64,
    cn0_tau: f64,
    leaf_loss_db: f64,
    tracking_cn0: f64,
    fix_cn0: f64,
    max_pdop: f64,
    rtk_min: usize,
    fix_min: usize,
    ttf_median: f64,
    ttf_spread: f64,
    fix_hold: Nanos,
    corrections: bool,
    reference_hdop: f64,
    reference_vdop: f64,
    multipath: [f64; 3],
    multipath_tau: f64,
}

impl SkyConfig {
    /// Checks `p` (paths `sensors.gnss.sky.<key>`).
    pub fn new(p: &GnssSkyParams) -> Result<SkyConfig, ParamError> {
        let path = |k: &str| format!("sensors.gnss.sky.{k}");
        let mut systems = Vec::new();
        for (i, s) in p.systems.iter().enumerate() {
            let all = [
                GnssSystem::Gps,
                GnssSystem::Galileo,
                GnssSystem::Glonass,
                GnssSystem::Beidou,
            ];
            let Some(sys) = all.into_iter().find(|x| x.name() == s.as_str()) else {
                return Err(ParamError::new(
                    format!("sensors.gnss.sky.systems[{i}]"),
                    "\"gps\", \"galileo\", \"glonass\" or \"beidou\"",
                    format!("\"{s}\""),
                ));
            };
            if systems.contains(&sys) {
                return Err(ParamError::new(
                    format!("sensors.gnss.sky.systems[{i}]"),
                    "each system once",
                    format!("\"{s}\" twice"),
                ));
            }
            systems.push(sys);
        }
        if systems.is_empty() {
            return Err(ParamError::new(
                path("systems"),
                "at least one of \"gps\", \"galileo\", \"glonass\", \"beidou\"",
                "[]",
            ));
        }
        let mask = p.elevation_mask_deg;
        if !(0.0..90.0).contains(&mask) {
            return Err(ParamError::new(
                path("elevation_mask_deg"),
                "an angle in [0, 90) degrees",
                mask,
            ));
        }
        let t = p.leaf_transmission;
        if !(t > 0.0 && t <= 1.0) {
            return Err(ParamError::new(
                path("leaf_transmission"),
                "a power fraction in (0, 1]",
                t,
            ));
        }
        let finite = |k: &str, v: f64| {
            if v.is_finite() {
                Ok(v)
            } else {
                Err(ParamError::new(path(k), "a finite number", v))
            }
        };
        let cn0_zenith = finite("cn0_zenith_dbhz", p.cn0_zenith_dbhz)?;
        let cn0_horizon = finite("cn0_horizon_dbhz", p.cn0_horizon_dbhz)?;
        let tracking_cn0 = finite("tracking_cn0_dbhz", p.tracking_cn0_dbhz)?;
        let fix_cn0 = finite("fix_cn0_dbhz", p.fix_cn0_dbhz)?;
        let count = |k: &str, v: u32| {
            if (4..=64).contains(&v) {
                Ok(v as usize)
            } else {
                Err(ParamError::new(path(k), "a satellite count in 4..=64", v))
            }
        };
        let spread = require_non_negative(&path("time_to_fix_spread"), p.time_to_fix_spread)?;
        if spread > 3.0 {
            return Err(ParamError::new(
                path("time_to_fix_spread"),
                "a log-normal σ of at most 3",
                spread,
            ));
        }
        let hold = require_non_negative(&path("fix_hold_s"), p.fix_hold_s)?;
        let ttf = require_non_negative(&path("time_to_fix_s"), p.time_to_fix_s)?;
        const DAY_S: f64 = 86_400.0;
        for (k, v) in [("time_to_fix_s", ttf), ("fix_hold_s", hold)] {
            if v > DAY_S {
                return Err(ParamError::new(path(k), "at most a day (86400 s)", v));
            }
        }
        Ok(SkyConfig {
            systems,
            mask_deg: mask,
            cn0_zenith,
            cn0_horizon,
            cn0_sigma: require_non_negative(&path("cn0_sigma_db"), p.cn0_sigma_db)?,
            cn0_tau: require_non_negative(
                &path("cn0_correlation_time_s"),
                p.cn0_correlation_time_s,
            )?,
            leaf_loss_db: -10.0 * t.log10(),
            tracking_cn0,
            fix_cn0,
            max_pdop: require_positive(&path("max_pdop"), p.max_pdop)?,
            rtk_min: count("rtk_min_satellites", p.rtk_min_satellites)?,
            fix_min: count("fix_min_satellites", p.fix_min_satellites)?,
            ttf_median: ttf,
            ttf_spread: spread,
            fix_hold: Nanos::from_secs_f64(hold),
            corrections: p.corrections,
            reference_hdop: require_positive(&path("reference_hdop"), p.reference_hdop)?,
            reference_vdop: require_positive(&path("reference_vdop"), p.reference_vdop)?,
            multipath: [
                require_non_negative(&path("multipath_single_m"), p.multipath_single_m)?,
                require_non_negative(&path("multipath_float_m"), p.multipath_float_m)?,
                require_non_negative(&path("multipath_fixed_m"), p.multipath_fixed_m)?,
            ],
            multipath_tau: require_non_negative(
                &path("multipath_correlation_time_s"),
                p.multipath_correlation_time_s,
            )?,
        })
    }

    /// C/N0 of a clear line of sight at `elevation_deg`, before fading, dB-Hz.
    pub fn clear_cn0(&self, elevation_deg: f64) -> f64 {
        self.cn0_horizon
            + (self.cn0_zenith - self.cn0_horizon) * elevation_deg.to_radians().sin().max(0.0)
    }

    /// Power lost per leaf crossed, dB.
    pub fn leaf_loss_db(&self) -> f64 {
        self.leaf_loss_db
    }

    /// Draws a time to fix, s (log-normal: median `time_to_fix_s`, log-σ
    /// `time_to_fix_spread`; one normal draw).
    pub fn draw_time_to_fix<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        self.ttf_median * (self.ttf_spread * standard_normal(rng)).exp()
    }
}

/// One epoch's sky: the satellites above the horizon and the solution they allow.
#[derive(Clone, Debug, PartialEq)]
pub struct Epoch {
    /// Every satellite above the horizon, in constellation order.
    pub satellites: Vec<GnssSatellite>,
    /// The best solution the sky allows now (before fault windows).
    pub status: FixStatus,
    /// DOP of the used satellites.
    pub dop: Option<Dop>,
    /// Multipath position error of the epoch's solution type, ENU, m.
    pub multipath: Vector3<f64>,
}

/// The receiver's sky and its solution state, advanced epoch by epoch.
pub struct SkyState {
    cfg: SkyConfig,
    sats: Vec<Satellite>,
    cn0_fade: Vec<f64>,
    multipath_bias: Vec<f64>,
    /// Since when the fix conditions hold, and the time to fix drawn then.
    converging: Option<(Nanos, f64)>,
    /// Last epoch at which the fix conditions held (a fix survives `fix_hold` after it).
    last_fix_ok: Option<Nanos>,
    fixed: bool,
    first: bool,
    rng: rand_chacha::ChaCha8Rng,
    dt: f64,
}

impl SkyState {
    /// A receiver whose constellation is `cfg`'s, stepping every `dt_s`, with its own
    /// random stream `rng` (fading, multipath, times to fix).
    pub fn new(cfg: SkyConfig, dt_s: f64, mut rng: rand_chacha::ChaCha8Rng) -> SkyState {
        let sats = constellation(&cfg.systems);
        // Start in the stationary distribution: fading and multipath, one draw each.
        let cn0_fade = (0..sats.len())
            .map(|_| cfg.cn0_sigma * standard_normal(&mut rng))
            .collect();
        let multipath_bias = (0..sats.len()).map(|_| standard_normal(&mut rng)).collect();
        SkyState {
            cfg,
            sats,
            cn0_fade,
            multipath_bias,
            converging: None,
            last_fix_ok: None,
            fixed: false,
            first: true,
            rng,
            dt: dt_s,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &SkyConfig {
        &self.cfg
    }

    /// Whether RTK corrections arrive.
    pub fn corrections(&self) -> bool {
        self.cfg.corrections
    }

    /// The satellites of the constellation.
    pub fn satellites(&self) -> &[Satellite] {
        &self.sats
    }

    /// The sky at epoch `stamp` (Unix time) for the antenna at `antenna_in_world` (ENU of
    /// `origin`); advances the fading and multipath processes and the fix state by one
    /// epoch. `forced` caps the solution (a `[[faults.gnss]]` window); a cap below RTK
    /// fixed stops a fix and restarts its convergence.
    pub fn epoch(
        &mut self,
        stamp: Nanos,
        origin: &Geodetic,
        antenna_in_world: &Vector3<f64>,
        sight: &dyn LineOfSight,
        forced: FixStatus,
    ) -> Epoch {
        let cfg = &self.cfg;
        let t = stamp.0 as f64 * 1e-9;
        let enu_from_ecef = enu_from_ecef_rotation(origin);
        let receiver = ecef_from_geodetic(origin) + enu_from_ecef.transpose() * antenna_in_world;
        let mut satellites = Vec::new();
        let mut used_los = Vec::new();
        let mut used_index = Vec::new();
        let mut fix_capable = 0usize;
        for (i, s) in self.sats.iter().enumerate() {
            let (az, el, los) =
                azimuth_elevation(&receiver, &s.orbit.position_ecef(t), &enu_from_ecef);
            if el <= 0.0 {
                continue;
            }
            let sight = sight.sight(antenna_in_world, &los);
            let cn0 = if sight.blocked {
                f64::NAN
            } else {
                cfg.clear_cn0(el) - f64::from(sight.leaves) * cfg.leaf_loss_db + self.cn0_fade[i]
            };
            let tracked = !sight.blocked && el >= cfg.mask_deg && cn0 >= cfg.tracking_cn0;
            let strong = tracked && cn0 >= cfg.fix_cn0;
            if tracked {
                used_los.push(los);
                used_index.push((i, sight.leaves));
                fix_capable += usize::from(strong);
            }
            satellites.push(GnssSatellite {
                system: s.system,
                prn: s.prn,
                azimuth_deg: az,
                elevation_deg: el,
                cn0_dbhz: cn0,
                tracked,
                used: tracked,
                strong,
                leaves: sight.leaves,
                blocked: sight.blocked,
            });
        }
        let dop = dop(&used_los).filter(|d| d.pdop <= cfg.max_pdop);
        let rtk = forced >= FixStatus::RtkFloat && cfg.corrections && used_los.len() >= cfg.rtk_min;
        let fix_ok = rtk && forced == FixStatus::RtkFixed && fix_capable >= cfg.fix_min;
        // Fix state: convergence starts when the fix conditions come (back); a fix
        // survives gaps up to `fix_hold`.
        if fix_ok {
            // The receiver was on before the run: fixed at once if the first epoch
            // allows it.
            if self.first {
                self.fixed = true;
            }
            self.last_fix_ok = Some(stamp);
            let ttf = match self.converging {
                Some((since, ttf)) => (since, ttf),
                None => {
                    let ttf = cfg.draw_time_to_fix(&mut self.rng);
                    self.converging = Some((stamp, ttf));
                    (stamp, ttf)
                }
            };
            if !self.fixed && (stamp - ttf.0).as_secs_f64() >= ttf.1 {
                self.fixed = true;
            }
        } else {
            // Only the sky's own gaps are held: a cap below fixed (a fault window, the
            // corrections gone) ends the fix at once.
            let held = forced == FixStatus::RtkFixed
                && cfg.corrections
                && self
                    .last_fix_ok
                    .is_some_and(|last| stamp - last <= cfg.fix_hold);
            if !held {
                self.fixed = false;
                self.converging = None;
            }
        }
        self.first = false;
        let status = match dop {
            None => FixStatus::NoFix,
            Some(_) if rtk && self.fixed => FixStatus::RtkFixed,
            Some(_) if rtk => FixStatus::RtkFloat,
            Some(_) => FixStatus::Single,
        }
        .min(forced);
        if status == FixStatus::NoFix {
            for s in &mut satellites {
                s.used = false;
                s.strong = false;
            }
        }
        // Multipath of the foliage-crossing satellites, projected into the solution.
        let sigma_mp = match status {
            FixStatus::RtkFixed => cfg.multipath[2],
            FixStatus::RtkFloat => cfg.multipath[1],
            _ => cfg.multipath[0],
        };
        let bias: Vec<f64> = used_index
            .iter()
            .map(|&(i, leaves)| {
                if leaves > 0 {
                    sigma_mp * self.multipath_bias[i]
                } else {
                    0.0
                }
            })
            .collect();
        let multipath = if status == FixStatus::NoFix {
            Vector3::zeros()
        } else {
            position_error(&used_los, &bias).unwrap_or_else(Vector3::zeros)
        };
        self.step_processes();
        Epoch {
            satellites,
            status,
            dop,
            multipath,
        }
    }

    /// Advances every satellite's fading and multipath process by one epoch (fixed draw
    /// order: fading of all satellites, then multipath of all).
    fn step_processes(&mut self) {
        let ar = |tau: f64| {
            if tau > 0.0 {
                (-self.dt / tau).exp()
            } else {
                0.0
            }
        };
        let (pf, pm) = (ar(self.cfg.cn0_tau), ar(self.cfg.multipath_tau));
        let (df, dm) = ((1.0 - pf * pf).sqrt(), (1.0 - pm * pm).sqrt());
        for x in &mut self.cn0_fade {
            *x = pf * *x + df * self.cfg.cn0_sigma * standard_normal(&mut self.rng);
        }
        for x in &mut self.multipath_bias {
            *x = pm * *x + dm * standard_normal(&mut self.rng);
        }
    }

    /// Scale of the solution's error and reported standard deviation: (east and north,
    /// up), from the epoch's DOP against the reference DOPs.
    pub fn dop_scale(&self, dop: Option<&Dop>) -> (f64, f64) {
        dop.map_or((1.0, 1.0), |d| {
            (
                d.hdop / self.cfg.reference_hdop,
                d.vdop / self.cfg.reference_vdop,
            )
        })
    }
}

#[cfg(test)]
#[path = "sky_tests.rs"]
mod tests;
