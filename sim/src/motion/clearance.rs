//! What the robot did to the vines: canopy intrusion and clearance to row elements, from
//! the ground truth and the true world (truth-only metrics, like [`super::tracking`]).
//!
//! # Geometry
//! The robot's footprint is the rectangle `footprint_length_m × footprint_width_m` of
//! its [`RobotGeometry`](crate::robot::RobotGeometry), centred on `base_link` and turned
//! with its heading, in the horizontal plane.
//!
//! - **Canopy**: each vine's leaf wall, seen from above, is the band of its
//!   `canopy_width_m` centred on the vine's trunk across the row, over the vine's slot
//!   along the row (half the plant spacing either side of its nominal spot); missing vines
//!   leave gaps. A real robot tears leaves and grapes wherever its footprint enters that
//!   band, even without touching a trunk (the leaf wall hangs down to the cordon and
//!   below). The footprint's extent across and along the row is that of its corners in
//!   row coordinates ([`RowLayout::row_coords`]); where it overlaps a vine's slot along
//!   the row, the **intrusion depth** is the width of the overlap of that extent with the
//!   vine's band across the row (0 outside).
//! - **Clearance**: the smallest horizontal distance between the footprint rectangle and
//!   the circle of a trellis post or vine trunk (exact, in the body frame); negative when
//!   they overlap. Elements farther than [`CLEARANCE_SEARCH_M`] from the footprint are not
//!   looked at (in the open headland the clearance is not defined).
//!
//! # Metrics
//! `canopy_intrusion_s` (time with a depth > 0, counting each ground-truth sample for its
//! period), `canopy_intrusion_max_m` (largest depth), `min_clearance_m` and the list of
//! intrusions (start, end, deepest moment and where it was) for the report's plot.

use crate::world::{RowLayout, World};
use nalgebra::{Isometry3, Vector2};
use serde::Serialize;
use vinebench_msgs::Nanos;

/// Row elements (posts, trunks) within this horizontal distance of the footprint are
/// checked for the clearance, m.
pub const CLEARANCE_SEARCH_M: f64 = 3.0;

/// One stretch of time with the footprint inside the canopy.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Intrusion {
    /// First sample inside.
    pub start: Nanos,
    /// Last sample inside.
    pub end: Nanos,
    /// Deepest intrusion of the stretch, m.
    pub max_depth_m: f64,
    /// When it was deepest.
    pub deepest_at: Nanos,
    /// Where `base_link` was then (world x, y), m.
    pub deepest_xy: [f64; 2],
    /// Row whose canopy it entered there.
    pub row: u32,
}

/// The canopy and clearance metrics of the samples so far.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ClearanceMetrics {
    /// Time with the footprint inside a canopy, s.
    pub canopy_intrusion_s: f64,
    /// Largest intrusion depth, m.
    pub canopy_intrusion_max_m: f64,
    /// Smallest clearance to a post or trunk, m (`None`: never within
    /// [`CLEARANCE_SEARCH_M`]).
    pub min_clearance_m: Option<f64>,
    /// The intrusions, in time order.
    pub intrusions: Vec<Intrusion>,
}

/// A vine's canopy along its row: slot `[s_lo, s_hi]`, band centre and half width across.
#[derive(Clone, Copy, Debug)]
struct CanopySlot {
    s_lo: f64,
    s_hi: f64,
    offset: f64,
    half_width: f64,
}

/// A post or trunk: row coordinate along, world centre and radius.
#[derive(Clone, Copy, Debug)]
struct Element {
    s: f64,
    centre: Vector2<f64>,
    radius: f64,
}

/// Feeds on ground-truth poses and keeps [`ClearanceMetrics`]; see the module
/// documentation.
#[derive(Clone, Debug)]
pub struct RowClearance {
    layout: RowLayout,
    half_length: f64,
    half_width: f64,
    /// Per row, canopies sorted by `s_lo`.
    canopies: Vec<Vec<CanopySlot>>,
    /// Per row, posts and trunks sorted by `s`.
    elements: Vec<Vec<Element>>,
    max_half_width: f64,
    last: Option<Nanos>,
    /// The previous sample was inside a canopy.
    inside: bool,
    metrics: ClearanceMetrics,
}

impl RowClearance {
    /// A tracker for a robot with a `length × width` footprint in `world`.
    pub fn new(world: &World, footprint_length_m: f64, footprint_width_m: f64) -> RowClearance {
        let layout = world.layout.clone();
        let rows = layout.count as usize;
        let half_slot = world.params.plants.spacing_m / 2.0;
        let mut canopies = vec![Vec::new(); rows];
        let mut elements = vec![Vec::new(); rows];
        let mut max_half_width: f64 = 0.0;
        for p in &world.plants {
            let xy = p.base_in_world.xy();
            let (offset, s) = layout.row_coords(&xy);
            let Some(row) = canopies.get_mut(p.row as usize) else {
                continue;
            };
            let half = p.canopy_width_m / 2.0;
            max_half_width = max_half_width.max(half);
            row.push(CanopySlot {
                s_lo: s - half_slot,
                s_hi: s + half_slot,
                offset,
                half_width: half,
            });
            if let Some(e) = elements.get_mut(p.row as usize) {
                e.push(Element {
                    s,
                    centre: xy,
                    radius: p.trunk_diameter_m / 2.0,
                });
            }
        }
        for p in &world.posts {
            let xy = p.base_in_world.xy();
            let (_, s) = layout.row_coords(&xy);
            if let Some(e) = elements.get_mut(p.row as usize) {
                e.push(Element {
                    s,
                    centre: xy,
                    radius: p.diameter_m / 2.0,
                });
            }
        }
        for c in &mut canopies {
            c.sort_by(|a, b| a.s_lo.total_cmp(&b.s_lo));
        }
        for e in &mut elements {
            e.sort_by(|a, b| a.s.total_cmp(&b.s));
        }
        RowClearance {
            layout,
            half_length: footprint_length_m / 2.0,
            half_width: footprint_width_m / 2.0,
            canopies,
            elements,
            max_half_width,
            last: None,
            inside: false,
            metrics: ClearanceMetrics::default(),
        }
    }

    /// Indices of the rows whose centre line lies within `[lo, hi]` across the rows (row
    /// `i` at offset `i · spacing`): a constant number per query, whatever the row count.
    fn rows_between(&self, lo: f64, hi: f64) -> std::ops::Range<usize> {
        let n = self.canopies.len();
        let spacing = self.layout.spacing_m;
        let first = (lo / spacing).ceil().clamp(0.0, n as f64) as usize;
        let end = ((hi / spacing).floor() + 1.0).clamp(0.0, n as f64) as usize;
        first..end.max(first)
    }

    /// The footprint's corners in the world's horizontal plane.
    fn corners(&self, pose: &Isometry3<f64>) -> [Vector2<f64>; 4] {
        let c = pose.translation.vector.xy();
        let x = pose.rotation * nalgebra::Vector3::x();
        let fwd = Vector2::new(x.x, x.y);
        let fwd = if fwd.norm() > 1e-9 {
            fwd.normalize()
        } else {
            Vector2::x()
        };
        let left = Vector2::new(-fwd.y, fwd.x);
        let (l, w) = (self.half_length, self.half_width);
        [
            c + fwd * l + left * w,
            c + fwd * l - left * w,
            c - fwd * l - left * w,
            c - fwd * l + left * w,
        ]
    }

    /// Intrusion depth and row of the footprint at `pose` (depth 0: outside every canopy).
    pub fn intrusion(&self, pose: &Isometry3<f64>) -> (f64, u32) {
        let rc = self.corners(pose).map(|p| self.layout.row_coords(&p));
        let (o_lo, o_hi) = rc
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                (a.min(p.0), b.max(p.0))
            });
        let (s_lo, s_hi) = rc
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                (a.min(p.1), b.max(p.1))
            });
        let mut best = (0.0, 0);
        let margin = 2.0 * self.max_half_width;
        for row in self.rows_between(o_lo - margin, o_hi + margin) {
            let slots = &self.canopies[row];
            // Slots that start before the footprint ends; those ending before it starts
            // are skipped (slots do not overlap, so they end in the same order).
            let first = slots.partition_point(|c| c.s_hi < s_lo);
            for c in slots[first..].iter().take_while(|c| c.s_lo <= s_hi) {
                let depth = o_hi.min(c.offset + c.half_width) - o_lo.max(c.offset - c.half_width);
                if depth > best.0 {
                    best = (depth, row as u32);
                }
            }
        }
        best
    }

    /// Smallest clearance between the footprint at `pose` and a post or trunk within
    /// [`CLEARANCE_SEARCH_M`], m.
    pub fn clearance(&self, pose: &Isometry3<f64>) -> Option<f64> {
        let c = pose.translation.vector.xy();
        let (o, s) = self.layout.row_coords(&c);
        let reach = self.half_length.hypot(self.half_width) + CLEARANCE_SEARCH_M;
        let inv = pose.inverse();
        let mut best: Option<f64> = None;
        for row in self.rows_between(o - reach, o + reach) {
            let elements = &self.elements[row];
            let first = elements.partition_point(|e| e.s < s - reach);
            for e in elements[first..].iter().take_while(|e| e.s <= s + reach) {
                let p = inv * nalgebra::Point3::new(e.centre.x, e.centre.y, pose.translation.z);
                let dx = (p.x.abs() - self.half_length).max(0.0);
                let dy = (p.y.abs() - self.half_width).max(0.0);
                let d = dx.hypot(dy) - e.radius;
                if d <= CLEARANCE_SEARCH_M {
                    best = Some(best.map_or(d, |b: f64| b.min(d)));
                }
            }
        }
        best
    }

    /// Takes the next ground-truth pose (in time order).
    pub fn push(&mut self, t: Nanos, pose: &Isometry3<f64>) {
        let dt = self.last.map_or(0.0, |l| (t - l).as_secs_f64());
        self.last = Some(t);
        let (depth, row) = self.intrusion(pose);
        let clearance = self.clearance(pose);
        let m = &mut self.metrics;
        if depth > 0.0 {
            m.canopy_intrusion_s += dt;
            m.canopy_intrusion_max_m = m.canopy_intrusion_max_m.max(depth);
            let xy = [pose.translation.x, pose.translation.y];
            match m.intrusions.last_mut() {
                Some(i) if self.inside => {
                    i.end = t;
                    if depth > i.max_depth_m {
                        (i.max_depth_m, i.deepest_at, i.deepest_xy, i.row) = (depth, t, xy, row);
                    }
                }
                _ => m.intrusions.push(Intrusion {
                    start: t,
                    end: t,
                    max_depth_m: depth,
                    deepest_at: t,
                    deepest_xy: xy,
                    row,
                }),
            }
        }
        if let Some(c) = clearance {
            m.min_clearance_m = Some(m.min_clearance_m.map_or(c, |b| b.min(c)));
        }
        self.inside = depth > 0.0;
    }

    /// The metrics so far.
    pub fn metrics(&self) -> &ClearanceMetrics {
        &self.metrics
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::WorldParams;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A vineyard with every vine at its nominal spot, none missing, all the same size.
    fn regular_world() -> World {
        let mut p = WorldParams::default();
        p.plants.position_sigma_m = 0.0;
        p.plants.missing_probability = 0.0;
        p.plants.canopy_size_sigma_rel = 0.0;
        p.plants.trunk_diameter_sigma_m = 0.0;
        World::generate(3, &p).expect("default world")
    }

    /// The robot at row coordinates (offset, s), heading along the rows.
    fn pose_at(layout: &RowLayout, offset: f64, s: f64) -> Isometry3<f64> {
        let (xy, t) = layout.point(offset, s);
        Isometry3::from_parts(
            Translation3::new(xy.x, xy.y, 0.3),
            UnitQuaternion::from_euler_angles(0.0, 0.0, t.y.atan2(t.x)),
        )
    }

    #[test]
    fn intrusion_and_clearance_match_hand_computed_geometry() {
        let world = regular_world();
        let (w, h) = (
            world.params.plants.canopy_width_m,
            world.params.plants.trunk_diameter_m,
        );
        assert_eq!((w, h), (0.5, 0.06), "the defaults this test computes with");
        // A 1.0 m × 0.6 m footprint centred between the vines at s = 9.5 and 10.5 of row 1
        // (offset 2.5 m), its left edge 0.1 m inside the leaf wall (which spans
        // 2.25-2.75 m across): centre at 2.5 − 0.25 − 0.3 + 0.1 = 2.05 m.
        let c = RowClearance::new(&world, 1.0, 0.6);
        let l = &world.layout;
        let (depth, row) = c.intrusion(&pose_at(l, 2.05, 10.0));
        assert!(
            (depth - 0.1).abs() < 1e-9 && row == 1,
            "{depth} in row {row}"
        );
        // Both trunks are 0.5 m along (the footprint's end) and 0.45 m across from the
        // centre: 0.45 − 0.3 − 0.03 (radius) = 0.12 m from the footprint.
        let clearance = c.clearance(&pose_at(l, 2.05, 10.0)).expect("trunks nearby");
        assert!((clearance - 0.12).abs() < 1e-9, "{clearance}");
        // In the middle of the lane: no intrusion, 1.25 − 0.3 − 0.03 = 0.92 m clearance.
        assert_eq!(c.intrusion(&pose_at(l, 1.25, 10.0)).0, 0.0);
        let lane = c.clearance(&pose_at(l, 1.25, 10.0)).expect("trunks nearby");
        assert!((lane - 0.92).abs() < 1e-9, "{lane}");
        // Over the row: the whole leaf wall is under the footprint.
        assert!((c.intrusion(&pose_at(l, 2.5, 10.0)).0 - 0.5).abs() < 1e-9);
        // Far out in the headland: nothing near.
        assert!(c.clearance(&pose_at(l, 2.5, -20.0)).is_none());
    }

    #[test]
    fn intrusions_are_timed_and_grouped() {
        let world = regular_world();
        let l = world.layout.clone();
        let mut c = RowClearance::new(&world, 1.0, 0.6);
        let ms = |k: i64| Nanos(k * 5_000_000);
        c.push(ms(0), &pose_at(&l, 1.25, 10.0));
        c.push(ms(1), &pose_at(&l, 2.05, 10.0));
        c.push(ms(2), &pose_at(&l, 2.10, 10.0));
        c.push(ms(3), &pose_at(&l, 1.25, 10.0));
        c.push(ms(4), &pose_at(&l, 2.00, 10.0));
        let m = c.metrics();
        assert!(
            (m.canopy_intrusion_s - 0.015).abs() < 1e-12,
            "{}",
            m.canopy_intrusion_s
        );
        assert!((m.canopy_intrusion_max_m - 0.15).abs() < 1e-9);
        assert_eq!(m.intrusions.len(), 2);
        let first = &m.intrusions[0];
        assert_eq!(
            (first.start, first.end, first.deepest_at),
            (ms(1), ms(2), ms(2))
        );
        assert!((first.max_depth_m - 0.15).abs() < 1e-9);
        assert!((m.min_clearance_m.unwrap() - 0.07).abs() < 1e-9);
    }
}
