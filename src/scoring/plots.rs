//! SVG plots for the run report: top view of the trajectories, translation error over
//! time with fault windows shaded, and altitude over time (where σ_U shows).
//!
//! Pure functions render to a `String` ([`trajectories_svg`], [`errors_svg`],
//! [`altitude_svg`]); the `plot_*_svg` wrappers write the file. Colours are the Okabe-Ito
//! palette (distinguishable with the common colour-vision deficiencies); ground truth is
//! black. Text uses plotters' built-in font metrics, so no font files are needed. Long
//! series are thinned to at most [`MAX_POINTS_PER_SERIES`] points (error series keep each
//! bucket's minimum and maximum, so spikes stay visible).

use super::metrics::closed_loop;
use super::spool::Poses;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;
use thiserror::Error;
use vinebench_msgs::Nanos;

/// Most points drawn per series.
pub const MAX_POINTS_PER_SERIES: usize = 4000;

/// Width and height of every plot, px.
pub(crate) const SIZE_PX: (u32, u32) = (900, 700);
/// Margin around the chart, px.
const MARGIN_PX: u32 = 15;
/// Height of the x label area, px.
const X_LABEL_AREA_PX: u32 = 45;
/// Width of the y label area, px.
const Y_LABEL_AREA_PX: u32 = 70;
/// Relative padding added around the data range.
const PAD: f64 = 0.05;

/// Okabe-Ito colours for the estimate sources, in order of use.
const SOURCE_COLOURS: [RGBColor; 7] = [
    RGBColor(0, 114, 178),   // blue
    RGBColor(213, 94, 0),    // vermillion
    RGBColor(0, 158, 115),   // bluish green
    RGBColor(204, 121, 167), // reddish purple
    RGBColor(230, 159, 0),   // orange
    RGBColor(86, 180, 233),  // sky blue
    RGBColor(240, 228, 66),  // yellow
];
/// Ground truth.
const TRUTH_COLOUR: RGBColor = RGBColor(0, 0, 0);
/// Fault-window shading (drawn with [`SHADE_OPACITY`]).
const SHADE_COLOUR: RGBColor = RGBColor(150, 150, 150);
/// Opacity of the fault-window shading.
const SHADE_OPACITY: f64 = 0.25;

/// A plot could not be drawn or written.
#[derive(Debug, Error)]
pub enum PlotError {
    /// plotters reported an error.
    #[error("drawing the plot failed: {0}")]
    Draw(String),
    /// The file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What the OS said.
        #[source]
        source: std::io::Error,
    },
}

pub(crate) fn draw_err<E: std::error::Error + Send + Sync>(
    e: DrawingAreaErrorKind<E>,
) -> PlotError {
    PlotError::Draw(e.to_string())
}

/// Draws the series legend in a corner, on a translucent white box.
pub(crate) fn draw_legend<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> Result<(), PlotError>
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    CT: CoordTranslate,
{
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(draw_err)
}

/// Ground truth (black) followed by every source with its colour.
fn with_truth<'a>(
    truth: &'a dyn Poses,
    sources: &[(&'a str, &'a dyn Poses)],
) -> Vec<(&'a str, &'a dyn Poses, RGBColor)> {
    with_reference("ground truth", truth, sources)
}

/// [`with_truth`] with another reference (a field recording's GNSS track).
fn with_reference<'a>(
    label: &'a str,
    truth: &'a dyn Poses,
    sources: &[(&'a str, &'a dyn Poses)],
) -> Vec<(&'a str, &'a dyn Poses, RGBColor)> {
    std::iter::once((label, truth, TRUTH_COLOUR))
        .chain(
            sources
                .iter()
                .enumerate()
                .map(|(i, &(name, t))| (name, t, source_colour(i))),
        )
        .collect()
}

/// Colour of the `i`-th source.
pub(crate) fn source_colour(i: usize) -> RGBColor {
    SOURCE_COLOURS[i % SOURCE_COLOURS.len()]
}

/// A series of `len` points read as a stream, thinned to at most
/// [`MAX_POINTS_PER_SERIES`] points by stride (keeping the last).
pub(crate) fn thin<T: Copy + PartialEq>(len: usize, points: impl Iterator<Item = T>) -> Vec<T> {
    if len <= MAX_POINTS_PER_SERIES {
        return points.collect();
    }
    let stride = len.div_ceil(MAX_POINTS_PER_SERIES - 1);
    let mut out = Vec::with_capacity(MAX_POINTS_PER_SERIES);
    let mut last = None;
    for (i, p) in points.enumerate() {
        if i % stride == 0 {
            out.push(p);
        }
        last = Some(p);
    }
    if let Some(l) = last
        && out.last() != Some(&l)
    {
        out.push(l);
    }
    out
}

/// Thins a time series to at most [`MAX_POINTS_PER_SERIES`] points, keeping each bucket's
/// smallest and largest `value` (in time order).
pub(crate) fn thin_min_max<T: Copy>(points: Vec<T>, value: impl Fn(&T) -> f64) -> Vec<T> {
    if points.len() <= MAX_POINTS_PER_SERIES {
        return points;
    }
    let bucket = points.len().div_ceil(MAX_POINTS_PER_SERIES / 2);
    let mut out = Vec::with_capacity(MAX_POINTS_PER_SERIES);
    for chunk in points.chunks(bucket) {
        let lo = chunk
            .iter()
            .enumerate()
            .min_by(|a, b| value(a.1).total_cmp(&value(b.1)));
        let hi = chunk
            .iter()
            .enumerate()
            .max_by(|a, b| value(a.1).total_cmp(&value(b.1)));
        if let (Some((i, &a)), Some((j, &b))) = (lo, hi) {
            match i.cmp(&j) {
                std::cmp::Ordering::Less => out.extend([a, b]),
                std::cmp::Ordering::Greater => out.extend([b, a]),
                std::cmp::Ordering::Equal => out.push(a),
            }
        }
    }
    out
}

/// An error series `(stamp, error)` thinned as [`errors_svg`] draws it (each bucket's
/// smallest and largest error): what a report keeps of a long run's errors.
pub fn thin_errors(errors: Vec<(Nanos, f64)>) -> Vec<(Nanos, f64)> {
    thin_min_max(errors, |e| e.1)
}

/// `[lo, hi]` of the values, padded by [`PAD`]; `[0, 1]` without values, `±1` around a
/// single value.
pub(crate) fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if lo > hi {
        return (0.0, 1.0);
    }
    if hi - lo <= f64::EPSILON * lo.abs().max(1.0) {
        return (lo - 1.0, hi + 1.0);
    }
    let pad = (hi - lo) * PAD;
    (lo - pad, hi + pad)
}

/// Seconds of `t` after `t0`.
fn secs_since(t: Nanos, t0: Nanos) -> f64 {
    (t - t0).as_secs_f64()
}

/// Pixel size of the plotting area the charts here get (margins, label areas and caption
/// are fixed, so it does not depend on the data).
pub(crate) fn plotting_area_px(caption: &str) -> Result<(u32, u32), PlotError> {
    let mut scratch = String::new();
    let root = SVGBackend::with_string(&mut scratch, SIZE_PX).into_drawing_area();
    let chart = chart_builder(&root, caption)
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)
        .map_err(draw_err)?;
    Ok(chart.plotting_area().dim_in_pixel())
}

pub(crate) fn chart_builder<'a, 'b>(
    root: &'a DrawingArea<SVGBackend<'b>, Shift>,
    caption: &str,
) -> ChartBuilder<'a, 'b, SVGBackend<'b>> {
    let mut b = ChartBuilder::on(root);
    b.margin(MARGIN_PX)
        .caption(caption, ("sans-serif", 22))
        .x_label_area_size(X_LABEL_AREA_PX)
        .y_label_area_size(Y_LABEL_AREA_PX);
    b
}

/// Widens the smaller of two ranges so that one metre takes as many pixels on x as on y.
pub(crate) fn equal_scale(
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
    (w_px, h_px): (u32, u32),
) -> ((f64, f64), (f64, f64)) {
    let (w, h) = (f64::from(w_px.max(1)), f64::from(h_px.max(1)));
    let m_per_px = ((x1 - x0) / w).max((y1 - y0) / h);
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let (hw, hh) = (m_per_px * w / 2.0, m_per_px * h / 2.0);
    ((cx - hw, cx + hw), (cy - hh, cy + hh))
}

/// The top view (East vs North, equal scale) of the ground truth and the sources, with
/// start (●) and end (×) markers and a legend, as SVG text.
pub fn trajectories_svg(
    truth: &dyn Poses,
    sources: &[(&str, &dyn Poses)],
) -> Result<String, PlotError> {
    trajectories_marked_svg(truth, sources, &[], &[])
}

/// [`trajectories_svg`] with the vine `rows` (centre lines, world x, y) drawn under the
/// paths in green, and `marks` (world x, y; e.g. where the robot entered a leaf wall) as
/// red triangles with a legend entry "canopy intrusion".
pub fn trajectories_marked_svg(
    truth: &dyn Poses,
    sources: &[(&str, &dyn Poses)],
    rows: &[Vec<(f64, f64)>],
    marks: &[(f64, f64)],
) -> Result<String, PlotError> {
    top_view_svg("ground truth", truth, sources, rows, marks)
}

/// Writes the top view of `sources` against a `reference` drawn (and labelled
/// `reference_label`) where the ground truth would be: a field recording's GNSS track.
pub fn plot_trajectories_against_svg(
    path: impl AsRef<Path>,
    reference_label: &str,
    reference: &dyn Poses,
    sources: &[(&str, &dyn Poses)],
) -> Result<(), PlotError> {
    write(
        path.as_ref(),
        &top_view_svg(reference_label, reference, sources, &[], &[])?,
    )
}

fn top_view_svg(
    reference_label: &str,
    truth: &dyn Poses,
    sources: &[(&str, &dyn Poses)],
    rows: &[Vec<(f64, f64)>],
    marks: &[(f64, f64)],
) -> Result<String, PlotError> {
    let caption = "Top view (ENU)";
    let all = with_reference(reference_label, truth, sources);
    let xr = padded_range(
        all.iter()
            .flat_map(|(_, t, _)| t.poses().map(|p| p.1.translation.x)),
    );
    let yr = padded_range(
        all.iter()
            .flat_map(|(_, t, _)| t.poses().map(|p| p.1.translation.y)),
    );
    let ((x0, x1), (y0, y1)) = equal_scale(xr, yr, plotting_area_px(caption)?);

    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE_PX).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = chart_builder(&root, caption)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("East (m)")
            .y_desc("North (m)")
            .draw()
            .map_err(draw_err)?;
        let green = RGBColor(120, 180, 90);
        let inside = |&(x, y): &(f64, f64)| (x0..=x1).contains(&x) && (y0..=y1).contains(&y);
        for (i, row) in rows.iter().enumerate() {
            // Only what lies in the view (SVG lines are not clipped to the chart).
            let points: Vec<(f64, f64)> = row.iter().copied().filter(inside).collect();
            let series = chart
                .draw_series(LineSeries::new(points, green.stroke_width(4)))
                .map_err(draw_err)?;
            if i == 0 {
                series.label("vine rows").legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], green.stroke_width(4))
                });
            }
        }
        for &(name, traj, colour) in &all {
            let xy = |p: crate::scoring::spool::Pose| (p.1.translation.x, p.1.translation.y);
            let (Some(start), Some(end)) = (traj.first().map(xy), traj.last().map(xy)) else {
                continue;
            };
            let points = thin(traj.len(), traj.poses().map(xy));
            let style = colour.stroke_width(2);
            chart
                .draw_series(LineSeries::new(points, style))
                .map_err(draw_err)?
                .label(name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            chart
                .draw_series([Circle::new(start, 5, colour.filled())])
                .map_err(draw_err)?;
            chart
                .draw_series([Cross::new(end, 7, colour.stroke_width(3))])
                .map_err(draw_err)?;
        }
        if !marks.is_empty() {
            let red = RGBColor(220, 0, 0);
            chart
                .draw_series(
                    marks
                        .iter()
                        .map(|&p| TriangleMarker::new(p, 6, red.filled())),
                )
                .map_err(draw_err)?
                .label("canopy intrusion")
                .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 6, red.filled()));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        root.draw(&Text::new(
            "start: dot, end: cross",
            (
                MARGIN_PX as i32 + Y_LABEL_AREA_PX as i32,
                SIZE_PX.1 as i32 - 18,
            ),
            ("sans-serif", 14),
        ))
        .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Translation error over time (s since `t0`) of each named series, with the fault
/// `windows` (`[start, end)`) shaded, as SVG text.
pub fn errors_svg(
    series: &[(&str, &[(Nanos, f64)])],
    t0: Nanos,
    windows: &[(Nanos, Nanos)],
) -> Result<String, PlotError> {
    series_svg(
        "Translation error (unaligned)",
        "translation error (m)",
        series,
        t0,
        windows,
        &[],
    )
}

/// Named time series (s since `t0`) as lines on one chart, with `windows` shaded and
/// horizontal reference lines `hlines` (value, legend label; dashed grey), as SVG text.
/// The y axis starts at 0 and ends above the largest value (and reference line).
pub fn series_svg(
    caption: &str,
    y_desc: &str,
    series: &[(&str, &[(Nanos, f64)])],
    t0: Nanos,
    windows: &[(Nanos, Nanos)],
    hlines: &[(f64, &str)],
) -> Result<String, PlotError> {
    let times = series
        .iter()
        .flat_map(|(_, s)| s.iter().map(|&(t, _)| secs_since(t, t0)));
    let (tx0, tx1) = padded_range(times);
    let ymax = series
        .iter()
        .flat_map(|(_, s)| s.iter().map(|&(_, e)| e))
        .chain(hlines.iter().map(|h| h.0))
        .filter(|e| e.is_finite())
        .fold(0.0f64, f64::max);
    let ymax = if ymax > 0.0 { ymax * (1.0 + PAD) } else { 1.0 };

    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE_PX).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = chart_builder(&root, caption)
            .build_cartesian_2d(tx0..tx1, 0.0..ymax)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("time since start (s)")
            .y_desc(y_desc)
            .draw()
            .map_err(draw_err)?;
        let shade = SHADE_COLOUR.mix(SHADE_OPACITY).filled();
        let shaded: Vec<_> = windows
            .iter()
            .map(|&(a, b)| (secs_since(a, t0).max(tx0), secs_since(b, t0).min(tx1)))
            .filter(|(a, b)| a < b)
            .map(|(a, b)| Rectangle::new([(a, 0.0), (b, ymax)], shade))
            .collect();
        if !shaded.is_empty() {
            chart
                .draw_series(shaded)
                .map_err(draw_err)?
                .label("fault window")
                .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], shade));
        }
        for (i, &(name, errs)) in series.iter().enumerate() {
            if errs.is_empty() {
                continue;
            }
            let style = source_colour(i).stroke_width(2);
            let points = errs.iter().map(|&(t, e)| (secs_since(t, t0), e)).collect();
            chart
                .draw_series(LineSeries::new(thin_min_max(points, |p| p.1), style))
                .map_err(draw_err)?
                .label(name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
        for &(v, label) in hlines {
            let style = BLACK.mix(0.5).stroke_width(1);
            chart
                .draw_series(DashedLineSeries::new(vec![(tx0, v), (tx1, v)], 6, 4, style))
                .map_err(draw_err)?
                .label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Writes [`series_svg`] to `path`.
pub fn plot_series_svg(
    path: impl AsRef<Path>,
    caption: &str,
    y_desc: &str,
    series: &[(&str, &[(Nanos, f64)])],
    t0: Nanos,
    hlines: &[(f64, &str)],
) -> Result<(), PlotError> {
    write(
        path.as_ref(),
        &series_svg(caption, y_desc, series, t0, &[], hlines)?,
    )
}

/// Altitude U over time (s since `t0`) of the ground truth and each source; legend
/// entries carry each trajectory's σ_U. As SVG text.
pub fn altitude_svg(
    truth: &dyn Poses,
    sources: &[(&str, &dyn Poses)],
    t0: Nanos,
) -> Result<String, PlotError> {
    let all = with_truth(truth, sources);
    // The time axis spans first to last stamps: no pass needed.
    let (tx0, tx1) = padded_range(all.iter().flat_map(|(_, t, _)| {
        [t.first(), t.last()]
            .into_iter()
            .flatten()
            .map(|p| secs_since(p.0, t0))
    }));
    let (u0, u1) = padded_range(
        all.iter()
            .flat_map(|(_, t, _)| t.poses().map(|p| p.1.translation.z)),
    );

    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE_PX).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = chart_builder(&root, "Altitude")
            .build_cartesian_2d(tx0..tx1, u0..u1)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("time since start (s)")
            .y_desc("U (m)")
            .draw()
            .map_err(draw_err)?;
        for &(name, traj, colour) in &all {
            let Ok(l) = closed_loop(traj) else {
                continue;
            };
            let style = colour.stroke_width(2);
            let points = thin(
                traj.len(),
                traj.poses()
                    .map(|p| (secs_since(p.0, t0), p.1.translation.z)),
            );
            chart
                .draw_series(LineSeries::new(points, style))
                .map_err(draw_err)?
                .label(format!("{name} (σU = {:.3} m)", l.sigma_u_m))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

fn write(path: &Path, svg: &str) -> Result<(), PlotError> {
    crate::fsio::write_atomic(path, svg.as_bytes()).map_err(|source| PlotError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// Writes [`trajectories_svg`] to `path`.
pub fn plot_trajectories_svg(
    path: impl AsRef<Path>,
    truth: &dyn Poses,
    sources: &[(&str, &dyn Poses)],
) -> Result<(), PlotError> {
    write(path.as_ref(), &trajectories_svg(truth, sources)?)
}

/// Writes [`trajectories_marked_svg`] to `path`.
pub fn plot_trajectories_marked_svg(
    path: impl AsRef<Path>,
    truth: &dyn Poses,
    sources: &[(&str, &dyn Poses)],
    rows: &[Vec<(f64, f64)>],
    marks: &[(f64, f64)],
) -> Result<(), PlotError> {
    write(
        path.as_ref(),
        &trajectories_marked_svg(truth, sources, rows, marks)?,
    )
}

/// Writes [`errors_svg`] to `path`.
pub fn plot_errors_svg(
    path: impl AsRef<Path>,
    series: &[(&str, &[(Nanos, f64)])],
    t0: Nanos,
    windows: &[(Nanos, Nanos)],
) -> Result<(), PlotError> {
    write(path.as_ref(), &errors_svg(series, t0, windows)?)
}

/// Writes [`altitude_svg`] to `path`.
pub fn plot_altitude_svg(
    path: impl AsRef<Path>,
    truth: &dyn Poses,
    sources: &[(&str, &dyn Poses)],
    t0: Nanos,
) -> Result<(), PlotError> {
    write(path.as_ref(), &altitude_svg(truth, sources, t0)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use vinebench_msgs::{PoseSample, Trajectory};

    fn loop_traj(n: usize, r: f64, dz: f64) -> Trajectory {
        let mut t = Trajectory::new();
        for k in 0..n {
            let a = k as f64 / n as f64 * std::f64::consts::TAU;
            t.push(PoseSample {
                stamp: Nanos::from_millis(1000 + 10 * k as i64),
                world_from_body: Isometry3::from_parts(
                    Translation3::new(r * a.cos(), 2.0 * r * a.sin(), dz * (3.0 * a).sin()),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, a),
                ),
                covariance: None,
            });
        }
        t
    }

    /// How plotters-svg starts a 2 px polyline (our series and their legend samples).
    const SERIES_POLYLINE: &str = "stroke-width=\"2\" points=";

    fn count(svg: &str, needle: &str) -> usize {
        svg.matches(needle).count()
    }

    fn is_svg(svg: &str) -> bool {
        let head = svg.trim_start();
        (head.starts_with("<svg") || head.starts_with("<?xml"))
            && svg.trim_end().ends_with("</svg>")
    }

    #[test]
    fn trajectory_plot_has_one_line_and_one_legend_entry_per_series() {
        let truth = loop_traj(300, 10.0, 0.5);
        let a = loop_traj(300, 10.5, 1.0);
        let b = loop_traj(150, 9.5, 0.2);
        let base = trajectories_svg(&Trajectory::new(), &[]).unwrap();
        let one = trajectories_svg(&truth, &[]).unwrap();
        let three = trajectories_svg(&truth, &[("eif", &a), ("gnss", &b)]).unwrap();
        for svg in [&base, &one, &three] {
            assert!(is_svg(svg));
        }
        // Each trajectory adds its polyline and its legend sample (series are drawn 2 px
        // wide; axes and ticks 1 px).
        assert_eq!(count(&base, SERIES_POLYLINE), 0);
        assert_eq!(count(&one, SERIES_POLYLINE), 2);
        assert_eq!(count(&three, SERIES_POLYLINE), 6);
        for (i, svg) in [(0, &one), (1, &three)] {
            let c = source_colour(i);
            let stroke = format!("stroke=\"#{:02X}{:02X}{:02X}\"", c.0, c.1, c.2);
            assert_eq!(
                count(svg, &stroke) > 0,
                i == 1,
                "source colours only with sources"
            );
        }
        for name in ["ground truth", "eif", "gnss", "East (m)", "North (m)"] {
            assert!(three.contains(name), "{name}");
        }
        // Start markers: one filled circle per trajectory.
        assert_eq!(count(&three, "<circle") - count(&base, "<circle"), 3);
    }

    #[test]
    fn equal_scale_keeps_the_data_and_equalises_metres_per_pixel() {
        for (xr, yr, px) in [
            ((0.0, 100.0), (-5.0, 5.0), (800, 600)),
            ((0.0, 1.0), (0.0, 50.0), (700, 700)),
            ((-3.0, 3.0), (-3.0, 3.0), (300, 900)),
        ] {
            let ((x0, x1), (y0, y1)) = equal_scale(xr, yr, px);
            assert!(x0 <= xr.0 && x1 >= xr.1 && y0 <= yr.0 && y1 >= yr.1);
            let sx = (x1 - x0) / f64::from(px.0);
            let sy = (y1 - y0) / f64::from(px.1);
            assert!((sx - sy).abs() <= 1e-12 * sx, "{sx} vs {sy}");
        }
        let (w, h) = plotting_area_px("Top view (ENU)").unwrap();
        assert!(w > 0 && h > 0 && w < SIZE_PX.0 && h < SIZE_PX.1);
    }

    #[test]
    fn error_plot_shades_windows_and_draws_each_series() {
        let t0 = Nanos::from_secs(100);
        let e1: Vec<(Nanos, f64)> = (0..10_000)
            .map(|k| (t0 + Nanos::from_millis(k), (k as f64 * 0.01).sin().abs()))
            .collect();
        let e2: Vec<(Nanos, f64)> = (0..50)
            .map(|k| (t0 + Nanos::from_millis(200 * k), 0.1))
            .collect();
        let windows = [
            (t0 + Nanos::from_secs(2), t0 + Nanos::from_secs(3)),
            (t0 + Nanos::from_secs(5), t0 + Nanos::from_secs(6)),
        ];
        let svg = errors_svg(&[("eif", &e1), ("gnss", &e2)], t0, &windows).unwrap();
        assert!(is_svg(&svg));
        assert_eq!(count(&svg, SERIES_POLYLINE), 4);
        // Shading: one rectangle per window plus the legend swatch, in the shade colour.
        let shade = format!(
            "fill=\"#{:02X}{:02X}{:02X}\"",
            SHADE_COLOUR.0, SHADE_COLOUR.1, SHADE_COLOUR.2
        );
        assert_eq!(count(&svg, &shade), 3, "{shade}");
        for name in [
            "eif",
            "gnss",
            "fault window",
            "time since start (s)",
            "translation error (m)",
        ] {
            assert!(svg.contains(name), "{name}");
        }
        // Plotting to a file works and writes the same text.
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("errors.svg");
        plot_errors_svg(&p, &[("eif", &e1), ("gnss", &e2)], t0, &windows).unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), svg);
    }

    #[test]
    fn altitude_plot_reports_sigma_u() {
        let truth = loop_traj(200, 10.0, 0.0);
        let noisy = loop_traj(200, 10.0, 2.0);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("alt.svg");
        plot_altitude_svg(
            &p,
            &truth,
            &[("tracking_camera", &noisy)],
            truth.samples[0].stamp,
        )
        .unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        assert!(is_svg(&svg));
        let sigma = closed_loop(&noisy).unwrap().sigma_u_m;
        // 2·sin(3a) over whole periods has population std 2/√2.
        assert!((sigma - 2f64.sqrt()).abs() < 1e-9);
        assert!(svg.contains(&format!("tracking_camera (σU = {sigma:.3} m)")));
        assert!(svg.contains("ground truth (σU = 0.000 m)"));
        assert!(svg.contains("U (m)"));
        let p2 = dir.path().join("top.svg");
        plot_trajectories_svg(&p2, &truth, &[("tracking_camera", &noisy)]).unwrap();
        assert!(is_svg(&std::fs::read_to_string(&p2).unwrap()));
        // A folder that cannot exist: its parent is a file.
        let missing = p.join("x.svg");
        assert!(matches!(
            plot_trajectories_svg(&missing, &truth, &[]),
            Err(PlotError::Io { .. })
        ));
    }

    #[test]
    fn thinning_keeps_ends_and_extremes() {
        let pts: Vec<(f64, f64)> = (0..100_000)
            .map(|k| (k as f64, if k == 31_337 { 9.0 } else { (k % 7) as f64 }))
            .collect();
        let t = thin(pts.len(), pts.iter().copied());
        assert!(t.len() <= MAX_POINTS_PER_SERIES);
        assert_eq!(t.first(), pts.first());
        assert_eq!(t.last(), pts.last());
        let stride = t[1].0 - t[0].0;
        assert!(
            t[..t.len() - 1]
                .windows(2)
                .all(|w| w[1].0 - w[0].0 == stride)
        );
        let m = thin_min_max(pts.clone(), |p| p.1);
        assert!(m.len() <= MAX_POINTS_PER_SERIES);
        assert!(m.contains(&(31_337.0, 9.0)));
        assert!(m.windows(2).all(|w| w[0].0 < w[1].0), "time order kept");
        let short = vec![(0.0, 1.0), (1.0, 2.0)];
        assert_eq!(thin_min_max(short.clone(), |p| p.1), short);
        assert_eq!(thin(short.len(), short.iter().copied()), short);
    }
}
