//! WGS84 geodesy: geodetic ↔ ECEF ↔ local East-North-Up.
//!
//! Latitude/longitude exist only at the GNSS boundary: the simulator converts its
//! ENU antenna position to [`Geodetic`] when it writes a fix, and the estimator
//! converts the fix back to ENU with the same [`LocalEnu`] origin. Both conversions
//! are exact on the ellipsoid (no flat-earth approximation), so a 1 km field keeps
//! millimetre consistency.

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// WGS84 semi-major axis, metres.
pub const WGS84_A: f64 = 6_378_137.0;
/// WGS84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// WGS84 semi-minor axis, metres.
pub const WGS84_B: f64 = WGS84_A * (1.0 - WGS84_F);
/// WGS84 first eccentricity squared.
pub const WGS84_E2: f64 = WGS84_F * (2.0 - WGS84_F);

/// A geodetic position on WGS84: latitude and longitude in degrees, ellipsoidal height in metres.
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Geodetic {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the WGS84 ellipsoid, metres.
    pub alt_m: f64,
}

impl Geodetic {
    /// True when all three fields are finite and latitude is within ±90°.
    pub fn is_valid(&self) -> bool {
        self.lat_deg.is_finite()
            && self.lon_deg.is_finite()
            && self.alt_m.is_finite()
            && self.lat_deg.abs() <= 90.0
    }
}

/// Earth-centred, earth-fixed coordinates of a geodetic position.
pub fn ecef_from_geodetic(g: &Geodetic) -> Vector3<f64> {
    let (sl, cl) = g.lat_deg.to_radians().sin_cos();
    let (so, co) = g.lon_deg.to_radians().sin_cos();
    let n = WGS84_A / (1.0 - WGS84_E2 * sl * sl).sqrt();
    Vector3::new(
        (n + g.alt_m) * cl * co,
        (n + g.alt_m) * cl * so,
        (n * (1.0 - WGS84_E2) + g.alt_m) * sl,
    )
}

/// Geodetic position of an ECEF point (iterative; converges to < 1e-12 rad in a few steps).
pub fn geodetic_from_ecef(p: &Vector3<f64>) -> Geodetic {
    let lon = p.y.atan2(p.x);
    let r = (p.x * p.x + p.y * p.y).sqrt();
    if r < 1e-9 {
        // On the polar axis.
        let lat = if p.z >= 0.0 { 90.0 } else { -90.0 };
        return Geodetic {
            lat_deg: lat,
            lon_deg: 0.0,
            alt_m: p.z.abs() - WGS84_B,
        };
    }
    // Bowring's initial guess, then Newton-like fixed-point refinement.
    let mut lat = (p.z / (r * (1.0 - WGS84_E2))).atan();
    for _ in 0..8 {
        let sl = lat.sin();
        let n = WGS84_A / (1.0 - WGS84_E2 * sl * sl).sqrt();
        let h = r / lat.cos() - n;
        let next = (p.z / (r * (1.0 - WGS84_E2 * n / (n + h)))).atan();
        let done = (next - lat).abs() < 1e-14;
        lat = next;
        if done {
            break;
        }
    }
    let sl = lat.sin();
    let n = WGS84_A / (1.0 - WGS84_E2 * sl * sl).sqrt();
    // Height formula that stays accurate near the poles.
    let h = if lat.cos().abs() > 1e-3 {
        r / lat.cos() - n
    } else {
        p.z / sl - n * (1.0 - WGS84_E2)
    };
    Geodetic {
        lat_deg: lat.to_degrees(),
        lon_deg: lon.to_degrees(),
        alt_m: h,
    }
}

/// Rotation that takes ECEF vectors into the ENU frame at a geodetic origin.
pub fn enu_from_ecef_rotation(origin: &Geodetic) -> Matrix3<f64> {
    let (sl, cl) = origin.lat_deg.to_radians().sin_cos();
    let (so, co) = origin.lon_deg.to_radians().sin_cos();
    Matrix3::new(
        -so,
        co,
        0.0, // east
        -sl * co,
        -sl * so,
        cl, // north
        cl * co,
        cl * so,
        sl, // up
    )
}

/// Normal gravity magnitude (m/s²) on WGS84 at a latitude and ellipsoidal height:
/// Somigliana's formula with the second-order free-air correction.
pub fn normal_gravity(lat_deg: f64, alt_m: f64) -> f64 {
    const GE: f64 = 9.780_325_335_9; // equatorial normal gravity
    const K: f64 = 0.001_931_852_652_41; // Somigliana constant
    const M: f64 = 0.003_449_786_506_84; // ω²a²b/GM
    let s2 = lat_deg.to_radians().sin().powi(2);
    let g0 = GE * (1.0 + K * s2) / (1.0 - WGS84_E2 * s2).sqrt();
    g0 * (1.0 - 2.0 / WGS84_A * (1.0 + WGS84_F + M - 2.0 * WGS84_F * s2) * alt_m
        + 3.0 / (WGS84_A * WGS84_A) * alt_m * alt_m)
}

/// A local East-North-Up frame anchored at a geodetic origin: vinebench's `world` frame.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalEnu {
    origin: Geodetic,
    origin_ecef: Vector3<f64>,
    enu_from_ecef: Matrix3<f64>,
}

impl LocalEnu {
    /// The ENU frame whose origin is `origin`.
    pub fn new(origin: Geodetic) -> LocalEnu {
        LocalEnu {
            origin,
            origin_ecef: ecef_from_geodetic(&origin),
            enu_from_ecef: enu_from_ecef_rotation(&origin),
        }
    }
    /// The geodetic origin.
    pub fn origin(&self) -> &Geodetic {
        &self.origin
    }
    /// ENU coordinates (`p_in_world`, metres) of a geodetic position.
    pub fn enu_from_geodetic(&self, g: &Geodetic) -> Vector3<f64> {
        self.enu_from_ecef * (ecef_from_geodetic(g) - self.origin_ecef)
    }
    /// Geodetic position of an ENU point.
    pub fn geodetic_from_enu(&self, p_in_world: &Vector3<f64>) -> Geodetic {
        geodetic_from_ecef(&(self.origin_ecef + self.enu_from_ecef.transpose() * p_in_world))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn ecef_closed_form_points() {
        let eq = ecef_from_geodetic(&Geodetic {
            lat_deg: 0.0,
            lon_deg: 0.0,
            alt_m: 0.0,
        });
        assert!((eq - Vector3::new(WGS84_A, 0.0, 0.0)).norm() < 1e-9);
        let e90 = ecef_from_geodetic(&Geodetic {
            lat_deg: 0.0,
            lon_deg: 90.0,
            alt_m: 100.0,
        });
        assert!((e90 - Vector3::new(0.0, WGS84_A + 100.0, 0.0)).norm() < 1e-6);
        let pole = ecef_from_geodetic(&Geodetic {
            lat_deg: 90.0,
            lon_deg: 0.0,
            alt_m: 0.0,
        });
        assert!((pole - Vector3::new(0.0, 0.0, WGS84_B)).norm() < 1e-6);
        let back = geodetic_from_ecef(&pole);
        assert!((back.lat_deg - 90.0).abs() < 1e-9 && back.alt_m.abs() < 1e-6);
    }

    #[test]
    fn enu_curvature_drop_matches_sphere_approximation() {
        // 1 km north of the origin on the ellipsoid surface the local horizontal plane is
        // above the surface by about d²/(2R) with R the meridian radius of curvature.
        let origin = Geodetic {
            lat_deg: 40.4545,
            lon_deg: 17.9085,
            alt_m: 0.0,
        };
        let enu = LocalEnu::new(origin);
        let d = 1000.0;
        let sl2 = origin.lat_deg.to_radians().sin().powi(2);
        let m = WGS84_A * (1.0 - WGS84_E2) / (1.0 - WGS84_E2 * sl2).powf(1.5);
        let north = Geodetic {
            lat_deg: origin.lat_deg + (d / m).to_degrees(),
            ..origin
        };
        let p = enu.enu_from_geodetic(&north);
        assert!(p.x.abs() < 1e-6, "east {}", p.x);
        assert!((p.y - d).abs() < 1e-3, "north {}", p.y);
        assert!((p.z + d * d / (2.0 * m)).abs() < 1e-3, "up {}", p.z);
    }

    #[test]
    fn normal_gravity_reference_values() {
        // WGS84 normal gravity: 9.7803253359 at the equator, 9.8321849379 at the poles.
        assert!((normal_gravity(0.0, 0.0) - 9.780_325_335_9).abs() < 1e-9);
        assert!((normal_gravity(90.0, 0.0) - 9.832_184_937_9).abs() < 1e-8);
        // Free-air gradient ≈ -3.086e-6 s⁻² per metre.
        let grad = normal_gravity(45.0, 1000.0) - normal_gravity(45.0, 0.0);
        assert!((grad + 3.086e-3).abs() < 2e-5, "{grad}");
    }

    proptest! {
        #[test]
        fn geodetic_ecef_round_trip(lat in -89.9f64..89.9, lon in -180.0f64..180.0, h in -500.0f64..10_000.0) {
            let g = Geodetic { lat_deg: lat, lon_deg: lon, alt_m: h };
            let back = geodetic_from_ecef(&ecef_from_geodetic(&g));
            prop_assert!((back.lat_deg - lat).abs() < 1e-10);
            prop_assert!((back.lon_deg - lon).abs() < 1e-10);
            prop_assert!((back.alt_m - h).abs() < 1e-6);
        }

        #[test]
        fn enu_round_trip(e in -2000.0f64..2000.0, n in -2000.0f64..2000.0, u in -100.0f64..100.0) {
            let enu = LocalEnu::new(Geodetic { lat_deg: 40.4545, lon_deg: 17.9085, alt_m: 50.0 });
            let p = Vector3::new(e, n, u);
            let back = enu.enu_from_geodetic(&enu.geodetic_from_enu(&p));
            prop_assert!((back - p).norm() < 1e-6);
        }
    }
}
