//! The camera model of a `CameraInfo` message: pinhole `K` with plumb-bob (Brown-Conrady)
//! distortion `D = [k1, k2, p1, p2, k3]`, inverted per pixel into a table of normalised
//! rays, so back-projecting a depth image is one multiply per coordinate.
//!
//! Pixel convention (OpenCV, ROS): the centre of pixel `(u, v)` is at `(u, v)`.

use super::MapperError;
use vinebench_msgs::CameraInfoMsg;

/// Undistorted normalised coordinates `(x, y) = (X/Z, Y/Z)` of every pixel centre, row
/// major; `NaN` where the distortion could not be inverted (outside the lens's image
/// circle).
#[derive(Clone, Debug, PartialEq)]
pub struct RayTable {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// `X/Z` per pixel.
    pub x: Vec<f32>,
    /// `Y/Z` per pixel.
    pub y: Vec<f32>,
    /// The calibration the table was computed from (`k` then `d`), to notice changes.
    calibration: [f64; 14],
}

/// Distortion of an ideal normalised point (plumb bob).
pub fn distort(d: &[f64; 5], x: f64, y: f64) -> (f64, f64) {
    let [k1, k2, p1, p2, k3] = *d;
    let r2 = x * x + y * y;
    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    (
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    )
}

/// Inverts [`distort`] by Newton's method (numeric-free analytic Jacobian) from the
/// distorted point; `None` when it does not converge to `1e-12`.
pub fn undistort(d: &[f64; 5], xd: f64, yd: f64) -> Option<(f64, f64)> {
    if d.iter().all(|c| *c == 0.0) {
        return Some((xd, yd));
    }
    let [k1, k2, p1, p2, k3] = *d;
    let (mut x, mut y) = (xd, yd);
    for _ in 0..30 {
        let (fx, fy) = distort(d, x, y);
        let (rx, ry) = (fx - xd, fy - yd);
        if rx.abs().max(ry.abs()) < 1e-14 {
            break;
        }
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        let j00 = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x;
        let j01 = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y;
        let j11 = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x;
        let det = j00 * j11 - j01 * j01;
        if !det.is_finite() || det.abs() < 1e-300 {
            return None;
        }
        x -= (j11 * rx - j01 * ry) / det;
        y -= (-j01 * rx + j00 * ry) / det;
    }
    let (fx, fy) = distort(d, x, y);
    let ok = (fx - xd).abs().max((fy - yd).abs()) < 1e-12 && x.is_finite() && y.is_finite();
    ok.then_some((x, y))
}

impl RayTable {
    /// The ray table of a `CameraInfo`; fails (naming the topic and field) when `K` is
    /// not a pinhole matrix with positive focal lengths.
    pub fn from_camera_info(info: &CameraInfoMsg) -> Result<RayTable, MapperError> {
        let k = &info.k;
        let bad = |field: &'static str, expected: &'static str| MapperError::BadCalibration {
            topic: info.topic.to_string(),
            field,
            expected,
        };
        if !(k[0] > 0.0 && k[4] > 0.0 && k.iter().all(|c| c.is_finite())) {
            return Err(bad(
                "k",
                "finite, with positive focal lengths k[0] and k[4]",
            ));
        }
        if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
            return Err(bad("k", "a pinhole matrix [fx, s, cx, 0, fy, cy, 0, 0, 1]"));
        }
        if !info.d.iter().all(|c| c.is_finite()) {
            return Err(bad(
                "d",
                "finite plumb-bob coefficients [k1, k2, p1, p2, k3]",
            ));
        }
        let (fx, skew, cx, fy, cy) = (k[0], k[1], k[2], k[4], k[5]);
        let n = info.width as usize * info.height as usize;
        let (mut xs, mut ys) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for v in 0..info.height {
            for u in 0..info.width {
                let yd = (f64::from(v) - cy) / fy;
                let xd = (f64::from(u) - cx - skew * yd) / fx;
                match undistort(&info.d, xd, yd) {
                    Some((x, y)) => {
                        xs.push(x as f32);
                        ys.push(y as f32);
                    }
                    None => {
                        xs.push(f32::NAN);
                        ys.push(f32::NAN);
                    }
                }
            }
        }
        Ok(RayTable {
            width: info.width,
            height: info.height,
            x: xs,
            y: ys,
            calibration: calibration_of(info),
        })
    }

    /// Whether this table was computed from the same calibration and size as `info`.
    pub fn matches(&self, info: &CameraInfoMsg) -> bool {
        self.width == info.width
            && self.height == info.height
            && self.calibration == calibration_of(info)
    }
}

fn calibration_of(info: &CameraInfoMsg) -> [f64; 14] {
    let mut c = [0.0; 14];
    c[..9].copy_from_slice(&info.k);
    c[9..].copy_from_slice(&info.d);
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistort_inverts_distort() {
        let d = [-0.1, 0.02, 0.001, -0.0005, 0.001];
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.6, 0.45), (0.7, 0.5)] {
            let (xd, yd) = distort(&d, x, y);
            let (ux, uy) = undistort(&d, xd, yd).expect("converges");
            assert!((ux - x).abs() < 1e-12 && (uy - y).abs() < 1e-12, "{x} {y}");
        }
    }
}
