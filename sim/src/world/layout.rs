//! Row geometry: where rows, lanes and headlands are, as pure functions of the parameters.

use crate::params::RowsParams;
use nalgebra::Vector2;

/// The geometry of the rows: straight or concentric circular-arc centre lines.
///
/// Positions along the rows use *row coordinates* `(offset_m, s_m)`: `offset_m` is the
/// signed distance to the left of row 0's centre line, and `s_m` is the arc length along
/// row 0's centre line from its start (negative or beyond `length_m` in the headlands).
/// Row `i` lies at `offset_m = i · spacing`; lane `k` (between rows `k-1` and `k`) at
/// `(k - 0.5) · spacing`.
#[derive(Clone, Debug, PartialEq)]
pub struct RowLayout {
    /// Number of rows.
    pub count: u32,
    /// Row length (of row 0), m.
    pub length_m: f64,
    /// Row spacing, m.
    pub spacing_m: f64,
    /// Direction of the rows at their start, ENU yaw, rad.
    pub yaw_rad: f64,
    /// Signed curvature of the centre lines, 1/m (positive bends left).
    pub curvature_per_m: f64,
}

/// Curvatures below this are treated as straight rows.
const STRAIGHT_CURVATURE: f64 = 1e-9;

impl RowLayout {
    /// The layout described by `[world.rows]`.
    pub fn new(p: &RowsParams) -> RowLayout {
        RowLayout {
            count: p.count,
            length_m: p.length_m,
            spacing_m: p.spacing_m,
            yaw_rad: p.yaw_deg.to_radians(),
            curvature_per_m: p.curvature_per_m,
        }
    }

    /// Lateral offset of row `i`'s centre line, m.
    pub fn row_offset_m(&self, row: u32) -> f64 {
        f64::from(row) * self.spacing_m
    }

    /// Lateral offset of lane `k` (between rows `k-1` and `k`), m.
    pub fn lane_offset_m(&self, lane: u32) -> f64 {
        (f64::from(lane) - 0.5) * self.spacing_m
    }

    fn start_tangent(&self) -> Vector2<f64> {
        Vector2::new(self.yaw_rad.cos(), self.yaw_rad.sin())
    }

    fn start_normal(&self) -> Vector2<f64> {
        Vector2::new(-self.yaw_rad.sin(), self.yaw_rad.cos())
    }

    /// World position (x, y) of row coordinates `(offset_m, s_m)` and the unit tangent
    /// of the rows' direction there.
    pub fn point(&self, offset_m: f64, s_m: f64) -> (Vector2<f64>, Vector2<f64>) {
        let t0 = self.start_tangent();
        let n0 = self.start_normal();
        let k = self.curvature_per_m;
        if k.abs() < STRAIGHT_CURVATURE {
            return (t0 * s_m + n0 * offset_m, t0);
        }
        // Concentric arcs around the centre C = n0 / k; the angle swept is k · s.
        let phi = k * s_m;
        let (sp, cp) = phi.sin_cos();
        let t = t0 * cp + n0 * sp;
        let n = n0 * cp - t0 * sp;
        let centre = n0 / k;
        (centre - n * (1.0 / k - offset_m), t)
    }

    /// Row coordinates `(offset_m, s_m)` of a world position (inverse of [`Self::point`]).
    pub fn row_coords(&self, p: &Vector2<f64>) -> (f64, f64) {
        let t0 = self.start_tangent();
        let n0 = self.start_normal();
        let k = self.curvature_per_m;
        if k.abs() < STRAIGHT_CURVATURE {
            return (p.dot(&n0), p.dot(&t0));
        }
        let centre = n0 / k;
        let r = p - centre;
        // Direction from the centre to the point is -n(phi) · sign(1/k - offset).
        let radius = 1.0 / k;
        let (along, across) = (r.dot(&t0), r.dot(&n0));
        // -n(phi) = -n0 cos(phi) + t0 sin(phi); with radius > 0 (k > 0) the point is at
        // centre + (radius - offset) · (-n(phi)).
        let s = k.signum();
        let phi = (s * along).atan2(-s * across);
        let dist = (along * along + across * across).sqrt();
        let offset = radius - s * dist;
        (offset, phi / k)
    }

    /// Rough axis-aligned bounds (min, max) of the rows' footprint including `margin_m`
    /// (and headland room) on every side.
    pub fn bounds(&self, margin_m: f64) -> (Vector2<f64>, Vector2<f64>) {
        let mut lo = Vector2::repeat(f64::INFINITY);
        let mut hi = Vector2::repeat(f64::NEG_INFINITY);
        let last = self.row_offset_m(self.count.saturating_sub(1));
        let n = 64;
        for off in [-self.spacing_m, last + self.spacing_m] {
            for i in 0..=n {
                let s = self.length_m * f64::from(i) / f64::from(n);
                let (p, _) = self.point(off, s);
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
        }
        (lo.add_scalar(-margin_m), hi.add_scalar(margin_m))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn layout(k: f64) -> RowLayout {
        RowLayout {
            count: 5,
            length_m: 100.0,
            spacing_m: 2.5,
            yaw_rad: 0.4,
            curvature_per_m: k,
        }
    }

    #[test]
    fn straight_rows_are_parallel_lines() {
        let l = layout(0.0);
        let (p, t) = l.point(2.5, 10.0);
        let expect = Vector2::new(0.4f64.cos(), 0.4f64.sin()) * 10.0
            + Vector2::new(-0.4f64.sin(), 0.4f64.cos()) * 2.5;
        assert!((p - expect).norm() < 1e-12);
        assert!((t.norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn curved_rows_keep_their_spacing() {
        let l = layout(0.004);
        for s in [0.0, 30.0, 99.0] {
            let (a, _) = l.point(0.0, s);
            let (b, _) = l.point(2.5, s);
            assert!(((b - a).norm() - 2.5).abs() < 1e-9);
        }
        // Arc length of row 0 between s and s+ds is ds.
        let (a, _) = l.point(0.0, 50.0);
        let (b, _) = l.point(0.0, 50.001);
        assert!(((b - a).norm() - 0.001).abs() < 1e-9);
    }

    proptest! {
        #[test]
        fn row_coords_invert_point(k in prop_oneof![Just(0.0), -0.01f64..0.01], off in -5.0f64..12.0, s in -10.0f64..110.0) {
            let l = layout(k);
            let (p, _) = l.point(off, s);
            let (o2, s2) = l.row_coords(&p);
            prop_assert!((o2 - off).abs() < 1e-7, "offset {} vs {}", o2, off);
            prop_assert!((s2 - s).abs() < 1e-7, "s {} vs {}", s2, s);
        }
    }
}
