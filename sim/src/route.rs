//! Routes: the path a robot follows, built from the row layout.
//!
//! A [`Route`] is a dense polyline in the world's horizontal plane (points about
//! [`ROUTE_SAMPLE_M`] apart) sampled from an exact curve made of straight lines and
//! circular arcs. Row routes (`row_loop`, `serpentine`) are laid out in the layout's *row
//! coordinates* `(offset_m, s_m)` and mapped through [`RowLayout::point`], so they follow
//! curved rows too; `waypoints` routes are laid out directly in world coordinates.
//!
//! The arc length stored with each point is the exact arc length of the underlying curve
//! (Simpson's rule on the analytic speed of the mapping: exact for straight rows), and the
//! curvature is computed analytically from the curve and the mapping's metric. The
//! polyline's chords are shorter than the arcs they cut by at most `Δθ²/24` relative
//! (`2.6e-4 m` per 1.25 m-radius half turn), and lie within `0.05²/(8R)` of the curve.
//!
//! A `waypoints` route with `there_and_back` continues past its last point back to its
//! first along the same points in reverse order: the direction of travel reverses at a
//! *cusp* ([`Route::cusps_m`]), where the robot stops and drives back without turning.
//!
//! # Size limits
//! A route is sampled densely up front, so its memory grows with its length (32 bytes per
//! point, 20 points per metre). Routes longer than [`MAX_ROUTE_LENGTH_M`] (100 km, more
//! than a day of driving at 1 m/s) or with more than [`MAX_ROUTE_SAMPLES`] points are
//! refused with a [`ParamError`] naming the key that makes the route long
//! (`route.waypoints.points`, `route.row_loop.laps`, `route.serpentine.last_row`), before
//! anything is sampled: the cost of building a route is linear in its pieces and bounded
//! by these limits whatever the input.

use crate::params::{
    HeadlandsParams, LoopDirection, ParamError, RouteKind, RouteParams, WaypointsParams,
    require_non_negative, require_positive,
};
use crate::world::RowLayout;
use nalgebra::Vector2;
use std::f64::consts::FRAC_PI_2;

/// Nominal distance between consecutive route points, m.
pub const ROUTE_SAMPLE_M: f64 = 0.05;
/// Fillet radius of `waypoints` corners when `route.turn_radius_m` is 0, m.
pub const DEFAULT_FILLET_RADIUS_M: f64 = 1.0;
/// Smallest fillet radius a `waypoints` corner may be shrunk to (where its segments are
/// short), m: sharper corners are rejected so the curvature stays bounded.
pub const MIN_FILLET_RADIUS_M: f64 = 0.1;
/// Longest route [`build_route`] accepts, m (measured along the route in the world; a
/// `there_and_back` route counts both ways). Longer routes are refused with a
/// [`ParamError`] instead of being sampled.
pub const MAX_ROUTE_LENGTH_M: f64 = 100_000.0;
/// Most points of a route's dense polyline (about [`MAX_ROUTE_LENGTH_M`] /
/// [`ROUTE_SAMPLE_M`], plus one per piece): at 32 bytes a point, at most 80 MB per copy.
pub const MAX_ROUTE_SAMPLES: usize = 2_500_000;
/// First and last point closer than this make a closed route, m.
const CLOSED_TOLERANCE_M: f64 = 1e-9;
/// Pieces shorter than this are dropped, m.
const MIN_PIECE_M: f64 = 1e-9;

/// A path in the world's horizontal plane, densely sampled, with the cumulative arc
/// length at each point.
///
/// Consecutive points are distinct and `arc_length_m` is strictly increasing, starting
/// at 0. The robot starts at `points[0]` facing along the first segment.
///
/// Arc length always increases in the direction of travel, also after a cusp: the
/// tangent ([`Route::tangent_at`]) is the direction of travel, and flips by 180° at each
/// cusp.
#[derive(Clone, Debug, PartialEq)]
pub struct Route {
    /// Path points `(x, y)` in the world frame, m, about `ROUTE_SAMPLE_M` apart.
    pub points: Vec<Vector2<f64>>,
    /// Arc length from the start at each point, m.
    pub arc_length_m: Vec<f64>,
    /// Signed curvature at each point, 1/m (positive: turning left, with respect to the
    /// direction of travel). At a cusp point, the value of the leg that ends there.
    pub curvature_per_m: Vec<f64>,
    /// Arc lengths where the direction of travel reverses (*cusps*), m: strictly
    /// increasing, strictly inside `(0, total)`, each the arc length of a route point.
    ///
    /// At a cusp the robot stops; the tangent flips by 180° and the path after the cusp
    /// retraces the path before it (the same points in reverse order, turning the other
    /// way: the curvature changes sign). Empty for routes that only drive forward (row
    /// routes, plain `waypoints`).
    pub cusps_m: Vec<f64>,
}

impl Route {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the route has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Total arc length, m (0 for an empty route).
    pub fn total_length_m(&self) -> f64 {
        self.arc_length_m.last().copied().unwrap_or(0.0)
    }

    /// True when the route ends where it starts (a loop). A route with cusps is never
    /// closed: a there-and-back route ends at its start, but facing backwards.
    pub fn is_closed(&self) -> bool {
        if !self.cusps_m.is_empty() {
            return false;
        }
        match (self.points.first(), self.points.last()) {
            (Some(a), Some(b)) if self.points.len() > 2 => (a - b).norm() <= CLOSED_TOLERANCE_M,
            _ => false,
        }
    }

    /// Index `i` of the polyline segment `[i, i+1]` holding arc length `s` (the first or
    /// last segment outside the route). Needs at least two points.
    fn segment_index(&self, s: f64) -> usize {
        let n = self.arc_length_m.len();
        self.arc_length_m
            .partition_point(|&a| a <= s)
            .saturating_sub(1)
            .min(n.saturating_sub(2))
    }

    /// Position at arc length `s_m`, linearly interpolated between points; before the
    /// start and beyond the end the first and last segments are extended as straight lines
    /// (so a look-ahead point past the end of an open route stays well defined).
    pub fn point_at(&self, s_m: f64) -> Vector2<f64> {
        match self.points.len() {
            0 => Vector2::zeros(),
            1 => self.points[0],
            _ => {
                let i = self.segment_index(s_m);
                let (s0, s1) = (self.arc_length_m[i], self.arc_length_m[i + 1]);
                let f = (s_m - s0) / (s1 - s0);
                self.points[i] + (self.points[i + 1] - self.points[i]) * f
            }
        }
    }

    /// Unit direction of travel at arc length `s_m` (of the polyline segment there).
    pub fn tangent_at(&self, s_m: f64) -> Vector2<f64> {
        if self.points.len() < 2 {
            return Vector2::x();
        }
        let i = self.segment_index(s_m);
        (self.points[i + 1] - self.points[i]).normalize()
    }

    /// Signed curvature at arc length `s_m`, linearly interpolated, 1/m (the end values
    /// outside the route). Just after a cusp the cusp point's curvature counts negated
    /// (the leg leaving it turns the other way), so the curvature does not blend across
    /// the reversal.
    pub fn curvature_at(&self, s_m: f64) -> f64 {
        match self.points.len() {
            0 => 0.0,
            1 => self.curvature_per_m[0],
            _ => {
                let i = self.segment_index(s_m);
                let (s0, s1) = (self.arc_length_m[i], self.arc_length_m[i + 1]);
                let f = ((s_m - s0) / (s1 - s0)).clamp(0.0, 1.0);
                let k0 = if self.cusps_m.contains(&s0) {
                    -self.curvature_per_m[i]
                } else {
                    self.curvature_per_m[i]
                };
                k0 + (self.curvature_per_m[i + 1] - k0) * f
            }
        }
    }

    /// The first cusp with arc length strictly greater than `s_m`, m (`None` when the
    /// rest of the route drives in one direction). The robot must stop there.
    pub fn next_cusp_after(&self, s_m: f64) -> Option<f64> {
        let i = self.cusps_m.partition_point(|&c| c <= s_m);
        self.cusps_m.get(i).copied()
    }

    /// The last cusp with arc length at most `s_m`, m (`None` before the first cusp): the
    /// start of the leg that `s_m` lies on (a cusp belongs to the leg it starts).
    pub fn previous_cusp_at_or_before(&self, s_m: f64) -> Option<f64> {
        let i = self.cusps_m.partition_point(|&c| c <= s_m);
        i.checked_sub(1).map(|i| self.cusps_m[i])
    }

    /// Arc length of the point of the route closest to `xy` among the route's part with
    /// arc length in `[hint_s_m - window_m, hint_s_m + window_m]` (projected onto the
    /// polyline segments, clamped to `[0, total]`).
    ///
    /// The search never crosses a cusp: it covers only the leg holding `hint_s_m`, i.e.
    /// `[max(hint - window, last cusp <= hint), min(hint + window, first cusp > hint)]`.
    /// The legs before and after a cusp share their points, so a position on the path
    /// maps to the leg the robot is on, never to the other one.
    ///
    /// The bounded window is what keeps progress tracking local: a point of the
    /// neighbouring lane 2.5 m away but 4 m further along the route is never considered.
    /// No allocation; cost is proportional to `window_m / ROUTE_SAMPLE_M`.
    pub fn closest_progress(&self, xy: &Vector2<f64>, hint_s_m: f64, window_m: f64) -> f64 {
        let n = self.points.len();
        if n < 2 {
            return 0.0;
        }
        let mut lo = self.segment_index(hint_s_m - window_m);
        let mut hi = self.segment_index(hint_s_m + window_m);
        let leg_start = self.previous_cusp_at_or_before(hint_s_m);
        let leg_end = self.next_cusp_after(hint_s_m);
        if let Some(c) = leg_start {
            // The leg starts with the segment beginning at the cusp.
            lo = lo.max(self.segment_index(c));
        }
        if let Some(c) = leg_end {
            // The leg ends with the last segment starting before the cusp.
            let last = self
                .arc_length_m
                .partition_point(|&a| a < c)
                .saturating_sub(1)
                .min(n - 2);
            hi = hi.min(last);
        }
        let mut best = (f64::INFINITY, self.arc_length_m[lo]);
        for i in lo..=hi {
            let a = self.points[i];
            let ab = self.points[i + 1] - a;
            let f = ((xy - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
            let d2 = (a + ab * f - xy).norm_squared();
            if d2 < best.0 {
                let s =
                    self.arc_length_m[i] + f * (self.arc_length_m[i + 1] - self.arc_length_m[i]);
                best = (d2, s);
            }
        }
        // A safety net for a hand-built route with a cusp between its points.
        let mut s = best.1;
        if let Some(c) = leg_start {
            s = s.max(c);
        }
        if let Some(c) = leg_end {
            s = s.min(c);
        }
        s
    }
}

/// Builds the route a scenario's `[route]` table asks for.
///
/// Row routes need `layout` (rows, lanes) and `headlands` (room to turn); `waypoints`
/// routes use neither. Errors name the offending scenario key.
pub fn build_route(
    params: &RouteParams,
    layout: &RowLayout,
    headlands: &HeadlandsParams,
) -> Result<Route, ParamError> {
    match params.kind {
        RouteKind::RowLoop => {
            let turn = RowTurns::new(params, layout, headlands)?;
            let p = &params.row_loop;
            if p.row >= layout.count {
                return Err(ParamError::new(
                    "route.row_loop.row",
                    format!("a row index below world.rows.count = {}", layout.count),
                    p.row,
                ));
            }
            if p.laps == 0 {
                return Err(ParamError::new(
                    "route.row_loop.laps",
                    "at least 1 lap",
                    p.laps,
                ));
            }
            let (first, second) = match p.direction {
                LoopDirection::Counterclockwise => (p.row, p.row + 1),
                LoopDirection::Clockwise => (p.row + 1, p.row),
            };
            turn.check_lanes(layout, &[first, second])?;
            let (oa, ob) = (layout.lane_offset_m(first), layout.lane_offset_m(second));
            let (top, bottom) = (layout.length_m + turn.overshoot_m, -turn.overshoot_m);
            let mut lap = Vec::new();
            lap.push(Piece::line(Vector2::new(0.0, oa), Vector2::new(top, oa)));
            turn.u_turn(&mut lap, top, 1.0, oa, ob);
            lap.push(Piece::line(Vector2::new(top, ob), Vector2::new(bottom, ob)));
            turn.u_turn(&mut lap, bottom, -1.0, ob, oa);
            lap.push(Piece::line(Vector2::new(bottom, oa), Vector2::new(0.0, oa)));
            // Checked before the laps are laid out: their number is input.
            let one = SampledSize::of(&lap, layout);
            let laps = f64::from(p.laps);
            check_size(
                "route.row_loop.laps",
                SampledSize {
                    // One end point for all laps.
                    points: (one.points - 1)
                        .saturating_mul(p.laps as usize)
                        .saturating_add(1),
                    length_m: one.length_m * laps,
                },
                format!("{} laps of {:.1} m", p.laps, one.length_m),
            )?;
            let pieces = lap.repeat(p.laps as usize);
            Ok(sample_pieces(&pieces, layout))
        }
        RouteKind::Serpentine => {
            let turn = RowTurns::new(params, layout, headlands)?;
            let p = &params.serpentine;
            if p.last_row >= layout.count {
                return Err(ParamError::new(
                    "route.serpentine.last_row",
                    format!("a row index below world.rows.count = {}", layout.count),
                    p.last_row,
                ));
            }
            if p.first_row > p.last_row {
                return Err(ParamError::new(
                    "route.serpentine.first_row",
                    format!("a row index <= route.serpentine.last_row = {}", p.last_row),
                    p.first_row,
                ));
            }
            // At least one row length per lane: refuse a huge serpentine before laying out
            // its lanes.
            let lane_count = f64::from(p.last_row - p.first_row) + 2.0;
            check_size(
                "route.serpentine.last_row",
                SampledSize {
                    points: 0,
                    length_m: lane_count * layout.length_m,
                },
                format!(
                    "{lane_count} lanes of world.rows.length_m = {} m",
                    layout.length_m
                ),
            )?;
            let lanes: Vec<u32> = (p.first_row..=p.last_row + 1).collect();
            turn.check_lanes(layout, &lanes)?;
            let (top, bottom) = (layout.length_m + turn.overshoot_m, -turn.overshoot_m);
            let mut pieces = Vec::new();
            for (i, &lane) in lanes.iter().enumerate() {
                let up = i % 2 == 0;
                let last = i + 1 == lanes.len();
                let o = layout.lane_offset_m(lane);
                let from = match (i, up) {
                    (0, _) => 0.0,
                    (_, true) => bottom,
                    (_, false) => top,
                };
                let to = match (last, up) {
                    (true, true) => layout.length_m,
                    (true, false) => 0.0,
                    (false, true) => top,
                    (false, false) => bottom,
                };
                pieces.push(Piece::line(Vector2::new(from, o), Vector2::new(to, o)));
                if !last {
                    let next = layout.lane_offset_m(lanes[i + 1]);
                    turn.u_turn(&mut pieces, to, if up { 1.0 } else { -1.0 }, o, next);
                }
            }
            check_size(
                "route.serpentine.last_row",
                SampledSize::of(&pieces, layout),
                format!("rows {} to {}", p.first_row, p.last_row),
            )?;
            Ok(sample_pieces(&pieces, layout))
        }
        RouteKind::Waypoints => {
            let w = &params.waypoints;
            if w.closed && w.there_and_back {
                return Err(ParamError::new(
                    "route.waypoints.there_and_back",
                    "false when route.waypoints.closed = true (a closed route has no last \
                     point to turn back at)",
                    true,
                ));
            }
            let radius = require_non_negative("route.turn_radius_m", params.turn_radius_m)?;
            let radius = if radius == 0.0 {
                DEFAULT_FILLET_RADIUS_M
            } else {
                radius
            };
            let pieces = waypoint_pieces(w, radius)?;
            // Plane coordinates are world coordinates: the identity layout.
            let identity = RowLayout {
                count: 1,
                length_m: 0.0,
                spacing_m: 1.0,
                yaw_rad: 0.0,
                curvature_per_m: 0.0,
            };
            let size = SampledSize::of(&pieces, &identity);
            let legs = if w.there_and_back { 2 } else { 1 };
            check_size(
                "route.waypoints.points",
                SampledSize {
                    points: size.points.saturating_mul(legs),
                    length_m: size.length_m * legs as f64,
                },
                format!(
                    "{} points{}",
                    w.points.len(),
                    if w.there_and_back {
                        ", there and back"
                    } else {
                        ""
                    }
                ),
            )?;
            let forward = sample_pieces(&pieces, &identity);
            Ok(if w.there_and_back {
                there_and_back(forward)
            } else {
                forward
            })
        }
    }
}

/// `forward` followed by its points in reverse order back to its start (the last point,
/// the cusp, appears once), arc length continuing to increase and the curvature negated
/// (a path traversed backwards turns the other way).
fn there_and_back(mut route: Route) -> Route {
    let n = route.len();
    if n < 2 {
        return route;
    }
    let total = route.total_length_m();
    route.points.reserve(n - 1);
    route.arc_length_m.reserve(n - 1);
    route.curvature_per_m.reserve(n - 1);
    for i in (0..n - 1).rev() {
        route.points.push(route.points[i]);
        route.arc_length_m.push(2.0 * total - route.arc_length_m[i]);
        route.curvature_per_m.push(-route.curvature_per_m[i]);
    }
    route.cusps_m = vec![total];
    route
}

/// Validated headland-turn geometry of a row route.
struct RowTurns {
    /// Turn radius, m.
    radius_m: f64,
    /// Overshoot beyond the row ends, m.
    overshoot_m: f64,
}

impl RowTurns {
    fn new(
        params: &RouteParams,
        layout: &RowLayout,
        headlands: &HeadlandsParams,
    ) -> Result<RowTurns, ParamError> {
        let d = require_positive("world.rows.spacing_m", layout.spacing_m)?;
        require_positive("world.rows.length_m", layout.length_m)?;
        if layout.count == 0 {
            return Err(ParamError::new("world.rows.count", "at least 1 row", 0));
        }
        if !layout.curvature_per_m.is_finite() {
            return Err(ParamError::new(
                "world.rows.curvature_per_m",
                "a finite number",
                layout.curvature_per_m,
            ));
        }
        let r = require_non_negative("route.turn_radius_m", params.turn_radius_m)?;
        let radius_m = if r == 0.0 { d / 2.0 } else { r };
        if radius_m > d / 2.0 {
            return Err(ParamError::new(
                "route.turn_radius_m",
                format!(
                    "at most half the row spacing ({} m), or 0 for exactly half",
                    d / 2.0
                ),
                r,
            ));
        }
        let overshoot_m =
            require_non_negative("route.headland_overshoot_m", params.headland_overshoot_m)?;
        let width = headlands.width_m;
        if !(width.is_finite() && overshoot_m + radius_m <= width) {
            return Err(ParamError::new(
                "route.headland_overshoot_m",
                format!(
                    "overshoot + turn radius ({radius_m} m) <= world.headlands.width_m ({width} m)"
                ),
                overshoot_m,
            ));
        }
        Ok(RowTurns {
            radius_m,
            overshoot_m,
        })
    }

    /// Checks that the lanes lie on the inner side of the rows' centre of curvature
    /// (lane offsets below the bend radius), so the row-coordinate mapping is regular.
    fn check_lanes(&self, layout: &RowLayout, lanes: &[u32]) -> Result<(), ParamError> {
        let k = layout.curvature_per_m;
        for &lane in lanes {
            let o = layout.lane_offset_m(lane);
            if 1.0 - k * o <= 0.0 {
                return Err(ParamError::new(
                    "world.rows.curvature_per_m",
                    format!("a bend radius larger than the offset of lane {lane} ({o} m)"),
                    k,
                ));
            }
        }
        Ok(())
    }

    /// Appends a headland turn at row coordinate `s_end` (plane X), driving in direction
    /// `dir` (+1 up the rows, -1 down), from the lane at offset `from_o` to the lane at
    /// `to_o`: quarter arc, straight across, quarter arc.
    fn u_turn(&self, pieces: &mut Vec<Piece>, s_end: f64, dir: f64, from_o: f64, to_o: f64) {
        let r = self.radius_m;
        let side = (to_o - from_o).signum();
        // Left turn (counterclockwise in the plane) when the target lies to the left.
        let sweep = FRAC_PI_2 * dir * side;
        let c1 = Vector2::new(s_end, from_o + side * r);
        let a1 = (-side).atan2(0.0);
        pieces.push(Piece::Arc {
            centre: c1,
            radius: r,
            start_angle: a1,
            sweep,
        });
        let p1 = Vector2::new(s_end + dir * r, from_o + side * r);
        let p2 = Vector2::new(s_end + dir * r, to_o - side * r);
        if (p2 - p1).norm() > MIN_PIECE_M {
            pieces.push(Piece::line(p1, p2));
        }
        let c2 = Vector2::new(s_end, to_o - side * r);
        let a2 = 0.0f64.atan2(dir);
        pieces.push(Piece::Arc {
            centre: c2,
            radius: r,
            start_angle: a2,
            sweep,
        });
    }
}

/// Lines and fillet arcs through the waypoints, in world coordinates.
fn waypoint_pieces(p: &WaypointsParams, radius: f64) -> Result<Vec<Piece>, ParamError> {
    const PATH: &str = "route.waypoints.points";
    let mut pts: Vec<Vector2<f64>> = Vec::with_capacity(p.points.len() + 1);
    for (i, q) in p.points.iter().enumerate() {
        if !(q[0].is_finite() && q[1].is_finite()) {
            return Err(ParamError::new(
                PATH,
                "finite coordinates",
                format!("point {i} = [{}, {}]", q[0], q[1]),
            ));
        }
        pts.push(Vector2::new(q[0], q[1]));
    }
    if p.closed && pts.len() > 2 && pts.first() == pts.last() {
        // The loop is written out explicitly; `closed` adds nothing.
        pts.pop();
    }
    if pts.len() < 2 {
        return Err(ParamError::new(
            PATH,
            "at least 2 points",
            format!("{} points", pts.len()),
        ));
    }
    if p.closed {
        pts.push(pts[0]);
    }
    for i in 0..pts.len() - 1 {
        if (pts[i + 1] - pts[i]).norm() <= MIN_PIECE_M {
            return Err(ParamError::new(
                PATH,
                "consecutive points that differ",
                format!(
                    "point {} repeats point {}",
                    (i + 1) % p.points.len().max(1),
                    i
                ),
            ));
        }
    }
    let n = pts.len();
    // Corners at every interior point (the start/end point of a closed route is not
    // rounded: the robot starts and stops there). Straight-through corners get none.
    let dir = |i: usize| (pts[i + 1] - pts[i]).normalize();
    let seg_len = |i: usize| (pts[i + 1] - pts[i]).norm();
    let turn_angle = |i: usize| {
        let (a, b) = (dir(i - 1), dir(i));
        (a.x * b.y - a.y * b.x).atan2(a.dot(&b))
    };
    let has_corner = |i: usize| i > 0 && i + 1 < n && turn_angle(i).abs() > 1e-12;
    // Length of segment j available to the fillet at either of its ends: half when both
    // ends are rounded.
    let available = |j: usize| {
        let shared = has_corner(j) && has_corner(j + 1);
        if shared { seg_len(j) / 2.0 } else { seg_len(j) }
    };
    let mut pieces = Vec::new();
    let mut cursor = pts[0];
    for (i, &corner) in pts.iter().enumerate().take(n - 1).skip(1) {
        if !has_corner(i) {
            continue;
        }
        let delta = turn_angle(i);
        let half_tan = (delta.abs() / 2.0).tan();
        let room = available(i - 1).min(available(i));
        let r = radius.min(room / half_tan);
        if r < MIN_FILLET_RADIUS_M {
            return Err(ParamError::new(
                PATH,
                format!(
                    "corners that fit a fillet of radius >= {MIN_FILLET_RADIUS_M} m within their \
                     segments"
                ),
                format!(
                    "a {:.1}° turn at point {} between segments of {:.3} m and {:.3} m",
                    delta.to_degrees(),
                    i % p.points.len().max(1),
                    seg_len(i - 1),
                    seg_len(i)
                ),
            ));
        }
        let t = r * half_tan;
        let (d1, d2) = (dir(i - 1), dir(i));
        let a = corner - d1 * t;
        let b = corner + d2 * t;
        let left = Vector2::new(-d1.y, d1.x);
        let centre = a + left * (r * delta.signum());
        if (a - cursor).norm() > MIN_PIECE_M {
            pieces.push(Piece::line(cursor, a));
        }
        let start_angle = (a.y - centre.y).atan2(a.x - centre.x);
        pieces.push(Piece::Arc {
            centre,
            radius: r,
            start_angle,
            sweep: delta,
        });
        cursor = b;
    }
    if (pts[n - 1] - cursor).norm() > MIN_PIECE_M {
        pieces.push(Piece::line(cursor, pts[n - 1]));
    }
    Ok(pieces)
}

/// One piece of a route in plane coordinates `(X, Y)`: for row routes `X = s_m` (along
/// the rows) and `Y = offset_m`; for waypoints, world `(x, y)`.
#[derive(Copy, Clone, Debug)]
enum Piece {
    /// Straight line from `from` to `to`.
    Line {
        from: Vector2<f64>,
        to: Vector2<f64>,
    },
    /// Circular arc around `centre`, starting at angle `start_angle` (rad, from +X),
    /// sweeping `sweep` rad (positive: counterclockwise, i.e. turning left).
    Arc {
        centre: Vector2<f64>,
        radius: f64,
        start_angle: f64,
        sweep: f64,
    },
}

/// Position, first and second derivative with respect to the plane arc length.
struct PieceEval {
    pos: Vector2<f64>,
    d1: Vector2<f64>,
    d2: Vector2<f64>,
}

impl Piece {
    fn line(from: Vector2<f64>, to: Vector2<f64>) -> Piece {
        Piece::Line { from, to }
    }

    fn length(&self) -> f64 {
        match *self {
            Piece::Line { from, to } => (to - from).norm(),
            Piece::Arc { radius, sweep, .. } => radius * sweep.abs(),
        }
    }

    fn eval(&self, u: f64) -> PieceEval {
        match *self {
            Piece::Line { from, to } => {
                let d = (to - from).normalize();
                PieceEval {
                    pos: from + d * u,
                    d1: d,
                    d2: Vector2::zeros(),
                }
            }
            Piece::Arc {
                centre,
                radius,
                start_angle,
                sweep,
            } => {
                let sigma = sweep.signum();
                let th = start_angle + sigma * u / radius;
                let (s, c) = th.sin_cos();
                PieceEval {
                    pos: centre + Vector2::new(c, s) * radius,
                    d1: Vector2::new(-s, c) * sigma,
                    d2: Vector2::new(c, s) * (-1.0 / radius),
                }
            }
        }
    }

    /// The exact end point (not re-derived from the length).
    fn end(&self) -> Vector2<f64> {
        match *self {
            Piece::Line { to, .. } => to,
            Piece::Arc {
                centre,
                radius,
                start_angle,
                sweep,
            } => {
                let (s, c) = (start_angle + sweep).sin_cos();
                centre + Vector2::new(c, s) * radius
            }
        }
    }
}

/// World speed (|dp/du|) and signed curvature of the mapped curve at a piece sample.
///
/// The row mapping `p(o, s)` has `∂p/∂s = t·a` and `∂p/∂o = n` with `a = 1 - k·o` and
/// `(t, n)` a right-handed unit frame turning at rate `k` along `s` (see
/// [`RowLayout::point`]). With `X = s`, `Y = o`:
/// `p' = t·a·s' + n·o'`, `p'' = t·(a·s'' - 2k·o'·s') + n·(k·a·s'² + o'')`, so
/// `κ = [a·s'·(k·a·s'² + o'') - o'·(a·s'' - 2k·o'·s')] / |p'|³`.
fn speed_and_curvature(e: &PieceEval, k: f64) -> (f64, f64) {
    let (s1, o1, s2, o2) = (e.d1.x, e.d1.y, e.d2.x, e.d2.y);
    let a = 1.0 - k * e.pos.y;
    let speed = ((a * s1).powi(2) + o1 * o1).sqrt();
    let cross = a * s1 * (k * a * s1 * s1 + o2) - o1 * (a * s2 - 2.0 * k * o1 * s1);
    (speed, cross / speed.powi(3))
}

/// How big sampling some pieces makes a route: what [`check_size`] judges before
/// [`sample_pieces`] allocates anything.
#[derive(Copy, Clone, Debug)]
struct SampledSize {
    /// Points of the dense polyline (saturating).
    points: usize,
    /// The route's length in the world, m (an upper bound on curved rows; infinite or
    /// NaN for an unusable route).
    length_m: f64,
}

impl SampledSize {
    /// The size [`sample_pieces`] gives `pieces` through `layout` (same per-piece point
    /// counts, plus the end point); linear in the pieces, allocates nothing.
    fn of(pieces: &[Piece], layout: &RowLayout) -> SampledSize {
        let mut size = SampledSize {
            points: 1,
            length_m: 0.0,
        };
        for piece in pieces {
            if let Some((n, world_m)) = piece_samples(piece, layout.curvature_per_m) {
                size.points = size.points.saturating_add(n);
                size.length_m += world_m;
            } else if piece.length().is_nan() {
                // A NaN length: unusable whatever the limits.
                size.length_m = f64::NAN;
            }
        }
        size
    }
}

/// Refuses a route beyond [`MAX_ROUTE_LENGTH_M`] or [`MAX_ROUTE_SAMPLES`], naming `path`
/// (the key that makes it long) and what it holds (`found`).
fn check_size(path: &str, size: SampledSize, found: String) -> Result<(), ParamError> {
    // Written so that a NaN length fails.
    if size.length_m <= MAX_ROUTE_LENGTH_M && size.points <= MAX_ROUTE_SAMPLES {
        return Ok(());
    }
    Err(ParamError::new(
        path,
        format!(
            "a route of at most {MAX_ROUTE_LENGTH_M} m (MAX_ROUTE_LENGTH_M) and \
             {MAX_ROUTE_SAMPLES} points {ROUTE_SAMPLE_M} m apart (MAX_ROUTE_SAMPLES): routes \
             are sampled densely before the run"
        ),
        format!(
            "{found}: a route of {:.4e} m ({} points)",
            size.length_m,
            if size.points == usize::MAX {
                "too many".to_string()
            } else {
                size.points.to_string()
            }
        ),
    ))
}

/// Points [`sample_pieces`] takes on `piece` and an upper bound of its world length, m
/// (`None` for a piece it skips: shorter than [`MIN_PIECE_M`], or of NaN length).
fn piece_samples(piece: &Piece, k: f64) -> Option<(usize, f64)> {
    let len = piece.length();
    if len.is_nan() || len <= MIN_PIECE_M {
        return None;
    }
    // The world length is at most len · max(a) along the piece.
    let (e0, e1) = (piece.eval(0.0), piece.eval(len));
    let a_max = (1.0 - k * e0.pos.y)
        .abs()
        .max((1.0 - k * e1.pos.y).abs())
        .max(1.0);
    // `as` saturates: an infinite length gives usize::MAX (refused by check_size).
    let n = ((len * a_max / ROUTE_SAMPLE_M).ceil() as usize).max(1);
    Some((n, len * a_max))
}

/// Samples the pieces about [`ROUTE_SAMPLE_M`] apart (in the world), mapping plane
/// coordinates through `layout`. Callers check the size first ([`check_size`]).
fn sample_pieces(pieces: &[Piece], layout: &RowLayout) -> Route {
    let k = layout.curvature_per_m;
    let map = |p: &Vector2<f64>| layout.point(p.y, p.x).0;
    let points = SampledSize::of(pieces, layout)
        .points
        .min(MAX_ROUTE_SAMPLES);
    let mut route = Route {
        points: Vec::with_capacity(points),
        arc_length_m: Vec::with_capacity(points),
        curvature_per_m: Vec::with_capacity(points),
        cusps_m: Vec::new(),
    };
    let mut arc = 0.0;
    for piece in pieces {
        let Some((n, _)) = piece_samples(piece, k) else {
            continue;
        };
        let len = piece.length();
        let h = len / n as f64;
        for i in 0..n {
            let u = len * i as f64 / n as f64;
            let e = piece.eval(u);
            let (f0, kappa) = speed_and_curvature(&e, k);
            route.points.push(map(&e.pos));
            route.arc_length_m.push(arc);
            route.curvature_per_m.push(kappa);
            // Simpson's rule on the world speed over [u, u + h].
            let (fm, _) = speed_and_curvature(&piece.eval(u + h / 2.0), k);
            let (f1, _) = speed_and_curvature(&piece.eval(u + h), k);
            arc += h / 6.0 * (f0 + 4.0 * fm + f1);
        }
    }
    if let Some(last) = pieces.iter().rev().find(|p| p.length() > MIN_PIECE_M) {
        let e = last.eval(last.length());
        let (_, kappa) = speed_and_curvature(&e, k);
        route.points.push(map(&last.end()));
        route.arc_length_m.push(arc);
        route.curvature_per_m.push(kappa);
    }
    route
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{RowLoopParams, SerpentineParams};
    use std::f64::consts::PI;

    fn layout(k: f64) -> RowLayout {
        RowLayout {
            count: 6,
            length_m: 40.0,
            spacing_m: 2.5,
            yaw_rad: 0.3,
            curvature_per_m: k,
        }
    }

    fn headlands() -> HeadlandsParams {
        HeadlandsParams { width_m: 8.0 }
    }

    fn row_loop(row: u32, direction: LoopDirection, radius: f64) -> RouteParams {
        RouteParams {
            kind: RouteKind::RowLoop,
            turn_radius_m: radius,
            headland_overshoot_m: 1.5,
            row_loop: RowLoopParams {
                row,
                direction,
                laps: 1,
            },
            ..RouteParams::default()
        }
    }

    /// Closed-form length of one row loop: two lanes of `length + 2·overshoot` and two
    /// turns of `π·R + (d - 2R)`.
    fn loop_length(l: &RowLayout, overshoot: f64, r: f64) -> f64 {
        let d = l.spacing_m;
        2.0 * (l.length_m + 2.0 * overshoot) + 2.0 * (PI * r + (d - 2.0 * r))
    }

    #[test]
    fn row_loop_is_closed_with_the_closed_form_length() {
        let l = layout(0.0);
        for (radius, r_eff) in [(0.0, 1.25), (1.0, 1.0), (0.5, 0.5), (1.25, 1.25)] {
            for dir in [LoopDirection::Counterclockwise, LoopDirection::Clockwise] {
                let route = build_route(&row_loop(2, dir, radius), &l, &headlands()).unwrap();
                assert!(route.is_closed(), "r={radius} {dir:?}");
                assert_eq!(route.points[0], *route.points.last().unwrap());
                let expect = loop_length(&l, 1.5, r_eff);
                assert!(
                    (route.total_length_m() - expect).abs() < 1e-9,
                    "r={radius}: {} vs {expect}",
                    route.total_length_m()
                );
                // The polyline's own length is shorter by at most Δθ²/24 on the arcs.
                let chord: f64 = route.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
                assert!(
                    chord <= expect + 1e-9 && expect - chord < 2e-3,
                    "{chord} vs {expect}"
                );
                // Samples are about ROUTE_SAMPLE_M apart.
                for w in route.arc_length_m.windows(2) {
                    assert!(w[1] > w[0] && w[1] - w[0] <= ROUTE_SAMPLE_M + 1e-12);
                }
            }
        }
    }

    #[test]
    fn row_loop_straights_lie_half_a_spacing_from_the_row_and_turn_the_right_way() {
        let l = layout(0.0);
        for (dir, first_side, turn_sign) in [
            (LoopDirection::Counterclockwise, -1.0, 1.0),
            (LoopDirection::Clockwise, 1.0, -1.0),
        ] {
            let route = build_route(&row_loop(2, dir, 0.0), &l, &headlands()).unwrap();
            let row_o = l.row_offset_m(2);
            let mut lanes_seen = [0usize; 2];
            for (p, &kappa) in route.points.iter().zip(&route.curvature_per_m) {
                let (o, s) = l.row_coords(p);
                if kappa == 0.0 {
                    // On a straight part (R = d/2: only lanes): exactly half a spacing
                    // beside the row, at most the overshoot beyond the row ends.
                    assert!(
                        ((o - row_o).abs() - 1.25).abs() < 1e-9,
                        "offset {o} at s {s}"
                    );
                    assert!(
                        (-1.5 - 1e-9..=l.length_m + 1.5 + 1e-9).contains(&s),
                        "s {s}"
                    );
                    lanes_seen[usize::from(o > row_o)] += 1;
                } else {
                    // In a turn: curvature 1/R with the loop's sense.
                    assert!(
                        (kappa - turn_sign / 1.25).abs() < 1e-12,
                        "κ {kappa} at s {s}"
                    );
                    assert!(
                        !(0.0..=l.length_m).contains(&s),
                        "turn inside the rows at s {s}"
                    );
                }
            }
            // Both lanes, about 40 m / 0.05 m samples each.
            assert!(lanes_seen[0] > 700 && lanes_seen[1] > 700, "{lanes_seen:?}");
            // Starts at s = 0 on the expected side, heading up the rows.
            let (o0, s0) = l.row_coords(&route.points[0]);
            assert!((o0 - (row_o + first_side * 1.25)).abs() < 1e-12 && s0.abs() < 1e-12);
            let t = route.tangent_at(0.0);
            assert!((t - Vector2::new(0.3f64.cos(), 0.3f64.sin())).norm() < 1e-9);
        }
    }

    #[test]
    fn laps_repeat_the_loop() {
        let l = layout(0.0);
        let mut p = row_loop(1, LoopDirection::Counterclockwise, 0.0);
        p.row_loop.laps = 3;
        let route = build_route(&p, &l, &headlands()).unwrap();
        assert!(route.is_closed());
        assert!((route.total_length_m() - 3.0 * loop_length(&l, 1.5, 1.25)).abs() < 1e-8);
    }

    #[test]
    fn curved_rows_keep_lanes_between_rows_and_curvature_matches_the_polyline() {
        let k = 0.01; // 100 m radius, bending left
        let l = layout(k);
        let route = build_route(
            &row_loop(1, LoopDirection::Counterclockwise, 0.0),
            &l,
            &headlands(),
        )
        .unwrap();
        assert!(route.is_closed());
        // Lane straights: length (1 - k·o)·Δs each, turns about π·d/2 (slightly distorted).
        let (oa, ob) = (l.lane_offset_m(1), l.lane_offset_m(2));
        let lanes = (1.0 - k * oa) * (l.length_m + 3.0) + (1.0 - k * ob) * (l.length_m + 3.0);
        let turns = route.total_length_m() - lanes;
        assert!((turns - PI * 2.5).abs() < 0.15, "turns {turns}");
        // The integrated arc length agrees with the polyline (shorter by <= Δθ²/24).
        let chord: f64 = route.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        assert!(chord <= route.total_length_m() + 1e-9, "{chord}");
        assert!(route.total_length_m() - chord < 2e-3, "{chord}");
        for p in &route.points {
            let (o, s) = l.row_coords(p);
            if (0.0..=l.length_m).contains(&s) {
                let d = (o - oa).abs().min((o - ob).abs());
                assert!(d < 1e-9, "off-lane point at s {s}: offset {o}");
            }
        }
        // The analytic curvature agrees with the three-point (Menger) curvature of the
        // polyline away from piece junctions, where the curvature is continuous.
        let mut checked = 0;
        for i in 1..route.len() - 1 {
            let (a, b, c) = (route.points[i - 1], route.points[i], route.points[i + 1]);
            let (k0, k1, k2) = (
                route.curvature_per_m[i - 1],
                route.curvature_per_m[i],
                route.curvature_per_m[i + 1],
            );
            if (k0 - k1).abs() > 1e-3 || (k2 - k1).abs() > 1e-3 {
                continue;
            }
            let cross = (b - a).x * (c - b).y - (b - a).y * (c - b).x;
            let menger = 2.0 * cross / ((b - a).norm() * (c - b).norm() * (c - a).norm());
            assert!(
                (menger - k1).abs() < 2e-3 * k1.abs().max(0.01),
                "{menger} vs {k1}"
            );
            checked += 1;
        }
        assert!(checked > route.len() / 2);
    }

    #[test]
    fn serpentine_visits_the_lanes_in_alternating_directions() {
        let l = layout(0.0);
        let p = RouteParams {
            kind: RouteKind::Serpentine,
            serpentine: SerpentineParams {
                first_row: 1,
                last_row: 3,
            },
            ..RouteParams::default()
        };
        let route = build_route(&p, &l, &headlands()).unwrap();
        assert!(!route.is_closed());
        // Walk the route at mid-row crossings: lanes 1, 2, 3, 4 with directions +, -, +, -.
        let mut visits = Vec::new();
        for w in route.points.windows(2) {
            let ((o0, s0), (_, s1)) = (l.row_coords(&w[0]), l.row_coords(&w[1]));
            let mid = l.length_m / 2.0 + 0.01; // between samples
            if (s0 - mid) * (s1 - mid) <= 0.0 && s0 != s1 {
                let lane = (o0 / l.spacing_m + 0.5).round() as i64;
                assert!((l.lane_offset_m(lane as u32) - o0).abs() < 1e-9);
                visits.push((lane, (s1 - s0).signum() as i64));
            }
        }
        assert_eq!(visits, vec![(1, 1), (2, -1), (3, 1), (4, -1)]);
        // Starts at s = 0 in lane 1; ends at the far (s = 0) end of lane 4.
        let (o0, s0) = l.row_coords(&route.points[0]);
        let (o1, s1) = l.row_coords(route.points.last().unwrap());
        assert!((o0 - l.lane_offset_m(1)).abs() < 1e-12 && s0.abs() < 1e-12);
        assert!((o1 - l.lane_offset_m(4)).abs() < 1e-9 && s1.abs() < 1e-9);
        // Left turns at the top, right turns at the bottom.
        for (p, &kappa) in route.points.iter().zip(&route.curvature_per_m) {
            let (_, s) = l.row_coords(p);
            if s > l.length_m + 1.5 + 1e-9 {
                assert!(kappa > 0.0);
            } else if s < -1.5 - 1e-9 {
                assert!(kappa < 0.0);
            }
        }
        let d = l.spacing_m;
        let expect = 4.0 * l.length_m + 3.0 * 2.0 * 1.5 + 3.0 * PI * d / 2.0;
        assert!((route.total_length_m() - expect).abs() < 1e-9);
    }

    #[test]
    fn bad_row_parameters_name_their_path() {
        let l = layout(0.0);
        let h = headlands();
        let err = |p: &RouteParams, h: &HeadlandsParams| build_route(p, &l, h).unwrap_err().path;
        assert_eq!(
            err(&row_loop(6, LoopDirection::Counterclockwise, 0.0), &h),
            "route.row_loop.row"
        );
        // Row 5 is the last row: its loop uses lane 6, which exists.
        assert!(build_route(&row_loop(5, LoopDirection::Clockwise, 0.0), &l, &h).is_ok());
        assert_eq!(
            err(&row_loop(1, LoopDirection::Clockwise, 1.3), &h),
            "route.turn_radius_m"
        );
        assert_eq!(
            err(&row_loop(1, LoopDirection::Clockwise, -0.1), &h),
            "route.turn_radius_m"
        );
        assert_eq!(
            err(
                &row_loop(1, LoopDirection::Clockwise, 0.0),
                &HeadlandsParams { width_m: 2.7 }
            ),
            "route.headland_overshoot_m"
        );
        assert!(
            build_route(
                &row_loop(1, LoopDirection::Clockwise, 0.0),
                &l,
                &HeadlandsParams { width_m: 2.75 }
            )
            .is_ok()
        );
        let mut p = row_loop(1, LoopDirection::Clockwise, 0.0);
        p.row_loop.laps = 0;
        assert_eq!(err(&p, &h), "route.row_loop.laps");
        let serp = |first_row, last_row| RouteParams {
            kind: RouteKind::Serpentine,
            serpentine: SerpentineParams {
                first_row,
                last_row,
            },
            ..RouteParams::default()
        };
        assert_eq!(err(&serp(0, 6), &h), "route.serpentine.last_row");
        assert_eq!(err(&serp(3, 2), &h), "route.serpentine.first_row");
        assert!(build_route(&serp(0, 5), &l, &h).is_ok());
        let e = build_route(&row_loop(9, LoopDirection::Clockwise, 0.0), &l, &h).unwrap_err();
        assert!(e.to_string().contains("route.row_loop.row") && e.to_string().contains('9'));
    }

    fn waypoints(points: Vec<[f64; 2]>, closed: bool, radius: f64) -> RouteParams {
        RouteParams {
            kind: RouteKind::Waypoints,
            turn_radius_m: radius,
            waypoints: WaypointsParams {
                points,
                closed,
                there_and_back: false,
            },
            ..RouteParams::default()
        }
    }

    #[test]
    fn waypoint_corners_are_filleted() {
        // A 10 m square, closed: three rounded corners (the start corner is not rounded).
        let sq = vec![[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]];
        let route = build_route(&waypoints(sq, true, 0.0), &layout(0.0), &headlands()).unwrap();
        assert!(route.is_closed());
        // Each fillet of radius 1 replaces 2 m of corner by a π/2 arc.
        let expect = 40.0 - 3.0 * (2.0 - FRAC_PI_2);
        assert!(
            (route.total_length_m() - expect).abs() < 1e-9,
            "{}",
            route.total_length_m()
        );
        let kmax = route
            .curvature_per_m
            .iter()
            .fold(0.0f64, |m, k| m.max(k.abs()));
        assert!((kmax - 1.0).abs() < 1e-12);
        assert_eq!(route.points[0], Vector2::new(0.0, 0.0));
        // Short segments shrink the fillet: 1.2 m legs leave room for r = 0.6 at 90°.
        let zig = vec![[0.0, 0.0], [1.2, 0.0], [1.2, 1.2], [2.4, 1.2]];
        let route = build_route(&waypoints(zig, false, 2.0), &layout(0.0), &headlands()).unwrap();
        let kmax = route
            .curvature_per_m
            .iter()
            .fold(0.0f64, |m, k| m.max(k.abs()));
        assert!((kmax - 1.0 / 0.6).abs() < 1e-9, "{kmax}");
        // Straight-through points add nothing.
        let line = vec![[0.0, 0.0], [5.0, 0.0], [9.0, 0.0]];
        let route = build_route(&waypoints(line, false, 0.0), &layout(0.0), &headlands()).unwrap();
        assert!((route.total_length_m() - 9.0).abs() < 1e-12);
        assert!(route.curvature_per_m.iter().all(|&k| k == 0.0));
    }

    #[test]
    fn bad_waypoints_are_rejected() {
        let l = layout(0.0);
        let h = headlands();
        let bad = |pts: Vec<[f64; 2]>, closed| {
            build_route(&waypoints(pts, closed, 0.0), &l, &h)
                .unwrap_err()
                .path
        };
        assert_eq!(bad(vec![[0.0, 0.0]], false), "route.waypoints.points");
        assert_eq!(
            bad(vec![[0.0, 0.0], [0.0, 0.0]], false),
            "route.waypoints.points"
        );
        assert_eq!(
            bad(vec![[0.0, 0.0], [f64::NAN, 1.0]], false),
            "route.waypoints.points"
        );
        // Out and back: a 180° corner cannot be rounded.
        assert_eq!(
            bad(vec![[0.0, 0.0], [5.0, 0.0]], true),
            "route.waypoints.points"
        );
        assert_eq!(
            bad(vec![[0.0, 0.0], [5.0, 0.0], [0.0, 0.0]], false),
            "route.waypoints.points"
        );
        let e = build_route(
            &waypoints(vec![[0.0, 0.0], [1.0, 0.0]], false, -1.0),
            &l,
            &h,
        );
        assert_eq!(e.unwrap_err().path, "route.turn_radius_m");
    }

    /// Three waypoints with a 90° left corner at (10, 0), filleted with radius 1: forward
    /// length 10 + 8 - 2 + π/2.
    fn corner_there_and_back(there_and_back: bool) -> Route {
        let mut p = waypoints(vec![[0.0, 0.0], [10.0, 0.0], [10.0, 8.0]], false, 1.0);
        p.waypoints.there_and_back = there_and_back;
        build_route(&p, &layout(0.0), &headlands()).unwrap()
    }

    const CORNER_FORWARD_M: f64 = 16.0 + FRAC_PI_2;

    #[test]
    fn there_and_back_retraces_the_forward_path_with_a_cusp_at_its_end() {
        let fwd = corner_there_and_back(false);
        let route = corner_there_and_back(true);
        let big_l = fwd.total_length_m();
        assert!((big_l - CORNER_FORWARD_M).abs() < 1e-9, "{big_l}");
        assert!(fwd.cusps_m.is_empty());
        let n = fwd.len();
        // The forward leg unchanged, then the same points reversed, the cusp point once.
        assert_eq!(route.len(), 2 * n - 1);
        assert_eq!(route.points[..n], fwd.points[..]);
        assert_eq!(route.arc_length_m[..n], fwd.arc_length_m[..]);
        assert_eq!(route.curvature_per_m[..n], fwd.curvature_per_m[..]);
        for j in 1..n {
            let (back, ahead) = (n - 1 + j, n - 1 - j);
            assert_eq!(route.points[back], fwd.points[ahead], "point {back}");
            // As far past the cusp as the forward point is before it.
            let past = route.arc_length_m[back] - big_l;
            let before = big_l - fwd.arc_length_m[ahead];
            assert!((past - before).abs() < 1e-12, "{past} vs {before}");
            assert_eq!(route.curvature_per_m[back], -fwd.curvature_per_m[ahead]);
        }
        assert!(route.arc_length_m.windows(2).all(|w| w[1] > w[0]));
        assert!((route.total_length_m() - 2.0 * CORNER_FORWARD_M).abs() < 1e-9);
        assert_eq!(route.cusps_m, vec![big_l]);
        // Back at the start, but facing the other way: not a loop.
        assert_eq!(route.points[0], *route.points.last().unwrap());
        assert!(!route.is_closed());
        // Out along +x, left turn, up +y to the cusp; then down -y, right turn, back
        // along -x.
        let t = |s: f64| route.tangent_at(s);
        assert!((t(0.5) - Vector2::new(1.0, 0.0)).norm() < 1e-12);
        assert!((t(big_l - 0.01) - Vector2::new(0.0, 1.0)).norm() < 1e-12);
        assert!((t(big_l + 0.01) - Vector2::new(0.0, -1.0)).norm() < 1e-12);
        assert!((t(big_l + 0.01) + t(big_l - 0.01)).norm() < 1e-12);
        assert!((t(2.0 * big_l - 0.5) - Vector2::new(-1.0, 0.0)).norm() < 1e-12);
        let mid_fillet = 9.0 + FRAC_PI_2 / 2.0;
        assert!((route.curvature_at(mid_fillet) - 1.0).abs() < 1e-12);
        assert!((route.curvature_at(2.0 * big_l - mid_fillet) + 1.0).abs() < 1e-12);
        assert!(route.curvature_at(big_l + 0.01).abs() < 1e-12);
        for s in [0.0, 3.0, 9.5, mid_fillet, 12.0, big_l - 0.02] {
            let (a, b) = (route.point_at(s), route.point_at(2.0 * big_l - s));
            assert!((a - b).norm() < 1e-9, "s {s}: {a:?} vs {b:?}");
        }
        // Cusp queries: a cusp starts the leg after it.
        assert_eq!(route.next_cusp_after(0.0), Some(big_l));
        assert_eq!(route.next_cusp_after(big_l - 1e-9), Some(big_l));
        assert_eq!(route.next_cusp_after(big_l), None);
        assert_eq!(route.previous_cusp_at_or_before(big_l - 1e-9), None);
        assert_eq!(route.previous_cusp_at_or_before(big_l), Some(big_l));
        assert_eq!(route.previous_cusp_at_or_before(1e6), Some(big_l));
        assert_eq!(fwd.next_cusp_after(0.0), None);
        assert_eq!(fwd.previous_cusp_at_or_before(1e6), None);
    }

    #[test]
    fn closest_progress_never_crosses_a_cusp() {
        let route = corner_there_and_back(true);
        let big_l = route.cusps_m[0];
        // A point on the shared path, 3 m before the cusp going out (x = 10, y = 5).
        let q = Vector2::new(10.0, 5.0);
        assert!((route.point_at(big_l - 3.0) - q).norm() < 1e-12);
        // Going out, even a window spanning the whole route stays on the way out.
        for window in [1.0, 5.0, 100.0] {
            let s = route.closest_progress(&q, big_l - 0.5, window);
            assert!(s <= big_l, "window {window}: {s}");
        }
        assert!((route.closest_progress(&q, big_l - 0.5, 100.0) - (big_l - 3.0)).abs() < 1e-9);
        // At the cusp and after it, the same point maps to the way back.
        for hint in [big_l, big_l + 0.5, big_l + 6.0] {
            let s = route.closest_progress(&q, hint, 100.0);
            assert!((s - (big_l + 3.0)).abs() < 1e-9, "hint {hint}: {s}");
        }
        // The start point: s = 0 going out, the total coming back.
        let start = route.points[0];
        assert!(route.closest_progress(&start, big_l - 0.5, 100.0).abs() < 1e-12);
        let total = route.total_length_m();
        assert!((route.closest_progress(&start, big_l + 0.5, 100.0) - total).abs() < 1e-12);
        // Beyond the cusp's end of the path: the cusp itself, from either side.
        let off_end = Vector2::new(10.0, 12.0);
        assert_eq!(route.closest_progress(&off_end, big_l - 0.5, 100.0), big_l);
        assert_eq!(route.closest_progress(&off_end, big_l + 0.5, 100.0), big_l);
        // A small window still bounds the search within the leg.
        let s = route.closest_progress(&start, big_l + 0.5, 1.0);
        assert!((big_l..=big_l + 1.5 + ROUTE_SAMPLE_M).contains(&s), "{s}");
    }

    #[test]
    fn there_and_back_is_not_allowed_on_a_closed_route() {
        let l = layout(0.0);
        let h = headlands();
        let mut p = waypoints(vec![[0.0, 0.0], [10.0, 0.0], [10.0, 8.0]], true, 0.0);
        p.waypoints.there_and_back = true;
        let e = build_route(&p, &l, &h).unwrap_err();
        assert_eq!(e.path, "route.waypoints.there_and_back");
        assert!(e.expected.contains("closed"), "{e}");
        // The points are still checked on a there-and-back route.
        let mut p = waypoints(vec![[0.0, 0.0]], false, 0.0);
        p.waypoints.there_and_back = true;
        assert_eq!(
            build_route(&p, &l, &h).unwrap_err().path,
            "route.waypoints.points"
        );
    }

    #[test]
    fn kinematic_model_rejects_a_route_with_a_cusp() {
        use crate::motion::KinematicSkidSteer;
        use crate::params::MotionParams;
        use crate::world::PlaneSurface;
        use vinebench_msgs::Nanos;
        let new = |route: Route| {
            KinematicSkidSteer::new(
                &MotionParams::default(),
                route,
                PlaneSurface {
                    z0_m: 0.0,
                    gradient: Vector2::zeros(),
                },
                &crate::robot::RobotModel::builtin("tracked-sensorbox")
                    .expect("built-in robot")
                    .geometry,
                Nanos::from_secs(1_631_696_400),
            )
        };
        // The forward path alone is fine; reversing at its end is not.
        assert!(new(corner_there_and_back(false)).is_ok());
        let e = new(corner_there_and_back(true)).err().unwrap();
        assert_eq!(e.path, "motion.model");
        assert!(e.expected.contains("rapier"), "{e}");
    }

    #[test]
    fn closest_progress_stays_in_its_window() {
        let l = layout(0.0);
        let route = build_route(
            &row_loop(2, LoopDirection::Counterclockwise, 0.0),
            &l,
            &headlands(),
        )
        .unwrap();
        // A point in the middle of the other lane, but the hint says we are in lane 2
        // at s = 20: the answer stays on this lane even though the point is closest to
        // the return lane.
        let (p_other, _) = l.point(l.lane_offset_m(3) - 0.1, 20.0);
        let s = route.closest_progress(&p_other, 20.0, 1.0);
        assert!((s - 20.0).abs() <= 1.0 + 1e-12);
        // With the hint on the return lane the projection is exact.
        let total = route.total_length_m();
        let s_back = (l.length_m + 1.5) + PI * 1.25 + (l.length_m + 1.5 - 20.0);
        let s2 = route.closest_progress(&p_other, s_back + 0.3, 1.0);
        assert!((s2 - s_back).abs() < 1e-9, "{s2} vs {s_back}");
        // The start point of a closed route maps to 0 near the start and to the total
        // length near the end.
        assert!(route.closest_progress(&route.points[0], 0.2, 1.0).abs() < 1e-12);
        assert!((route.closest_progress(&route.points[0], total - 0.2, 1.0) - total).abs() < 1e-12);
        // point_at extends the end segments: look-ahead past the end stays on the line.
        let beyond = route.point_at(total + 1.0);
        let expect = route.points[0] + route.tangent_at(total) * 1.0;
        assert!((beyond - expect).norm() < 1e-9);
    }
}
