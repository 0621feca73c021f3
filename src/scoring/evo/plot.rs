//! `--save_plot`: an SVG with the error of each estimate along the trajectory (over
//! seconds from the start, or over the pose index without stamps) beside the
//! trajectories in the plane of `--plot_mode` (the reference dashed grey; one estimate
//! coloured by its error, as evo's colour map shows it; several in their own colours).

use super::EvoResult;
use crate::scoring::plots::{
    PlotError, chart_builder, draw_err, draw_legend, equal_scale, padded_range, plotting_area_px,
    source_colour, thin, thin_min_max,
};
use plotters::prelude::*;

/// evo's `--plot_mode`: the plane of the trajectory view.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PlotMode {
    /// x right, y up.
    Xy,
    /// x right, z up.
    Xz,
    /// y right, x up.
    Yx,
    /// y right, z up.
    Yz,
    /// z right, x up.
    Zx,
    /// z right, y up.
    Zy,
    /// evo's 3D view; drawn here as the xy plane.
    Xyz,
}

impl PlotMode {
    fn axes(self) -> (usize, usize) {
        match self {
            PlotMode::Xy | PlotMode::Xyz => (0, 1),
            PlotMode::Xz => (0, 2),
            PlotMode::Yx => (1, 0),
            PlotMode::Yz => (1, 2),
            PlotMode::Zx => (2, 0),
            PlotMode::Zy => (2, 1),
        }
    }
}

/// A perceptually ordered colour map (viridis, by five anchors) at `v` in [0, 1].
fn colour_map(v: f64) -> RGBColor {
    const ANCHORS: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let x = v.clamp(0.0, 1.0) * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    let (a, b) = (ANCHORS[i], ANCHORS[i + 1]);
    let c = |p: f64, q: f64| (p + (q - p) * f).round() as u8;
    RGBColor(c(a.0, b.0), c(a.1, b.1), c(a.2, b.2))
}

/// The plot of `results` as SVG text.
pub fn svg(results: &[EvoResult], mode: PlotMode) -> Result<String, PlotError> {
    let mut out = String::new();
    let size = (1600, 700);
    {
        let root = SVGBackend::with_string(&mut out, size).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (left, right) = root.split_horizontally(800);
        let label = results.first().map_or("error", |r| r.info.label.as_str());
        // Error along the trajectory.
        let x_of = |r: &EvoResult| -> Vec<f64> {
            match &r.np_arrays.seconds_from_start {
                Some(s) => s.clone(),
                None => (0..r.np_arrays.error_array.len())
                    .map(|i| i as f64)
                    .collect(),
            }
        };
        let timed = results
            .iter()
            .all(|r| r.np_arrays.seconds_from_start.is_some());
        let (x0, x1) = padded_range(results.iter().flat_map(x_of));
        let (_, y1) = padded_range(
            results
                .iter()
                .flat_map(|r| r.np_arrays.error_array.iter().copied()),
        );
        let caption = results
            .first()
            .map_or(String::new(), |r| r.info.title.replace('\n', " "));
        let mut chart = chart_builder(&left, &caption)
            .build_cartesian_2d(x0..x1, 0.0..y1.max(f64::MIN_POSITIVE))
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(if timed { "seconds from start" } else { "index" })
            .y_desc(label)
            .draw()
            .map_err(draw_err)?;
        for (i, r) in results.iter().enumerate() {
            let style = source_colour(i).stroke_width(2);
            let xs = x_of(r);
            let e = &r.np_arrays.error_array;
            // Thinned as the run's error plot is: each bucket's extremes stay.
            let points: Vec<(f64, f64)> = xs.iter().zip(e).map(|(&x, &y)| (x, y)).collect();
            let points = thin_min_max(points, |p| p.1);
            let legend = format!("{} (rmse {:.4})", r.label(), r.stats.rmse);
            chart
                .draw_series(LineSeries::new(points, style))
                .map_err(draw_err)?
                .label(legend)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;

        // The trajectories in the plane.
        let (a, b) = mode.axes();
        let names = ["x (m)", "y (m)", "z (m)"];
        let pa = |v: &nalgebra::Vector3<f64>| (v[a], v[b]);
        let all = results
            .iter()
            .flat_map(|r| r.plot.reference.iter().chain(&r.plot.estimate))
            .map(pa)
            .collect::<Vec<_>>();
        let xr = padded_range(all.iter().map(|p| p.0));
        let yr = padded_range(all.iter().map(|p| p.1));
        let title = "trajectories";
        let ((xa, xb), (ya, yb)) = equal_scale(xr, yr, plotting_area_px(title)?);
        let mut chart = chart_builder(&right, title)
            .build_cartesian_2d(xa..xb, ya..yb)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(names[a])
            .y_desc(names[b])
            .draw()
            .map_err(draw_err)?;
        if let Some(r) = results.first() {
            let grey = RGBColor(120, 120, 120);
            chart
                .draw_series(DashedLineSeries::new(
                    thin(r.plot.reference.len(), r.plot.reference.iter().map(pa)),
                    6,
                    4,
                    grey.stroke_width(2),
                ))
                .map_err(draw_err)?
                .label("reference")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey));
        }
        if let [r] = results {
            // One estimate: coloured by its error from min (dark) to max (yellow).
            let (lo, hi) = (r.stats.min, r.stats.max);
            let span = if hi > lo { hi - lo } else { 1.0 };
            let pts = thin(
                r.plot.estimate.len(),
                r.plot
                    .estimate
                    .iter()
                    .zip(&r.np_arrays.error_array)
                    .map(|(p, e)| (pa(p), (e - lo) / span)),
            );
            chart
                .draw_series(pts.windows(2).map(|w| {
                    PathElement::new(vec![w[0].0, w[1].0], colour_map(w[1].1).stroke_width(3))
                }))
                .map_err(draw_err)?
                .label(format!("estimate: colour = error {lo:.4} .. {hi:.4}"))
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour_map(0.7).stroke_width(3))
                });
        } else {
            for (i, r) in results.iter().enumerate() {
                let style = source_colour(i).stroke_width(2);
                chart
                    .draw_series(LineSeries::new(
                        thin(r.plot.estimate.len(), r.plot.estimate.iter().map(pa)),
                        style,
                    ))
                    .map_err(draw_err)?
                    .label(r.label())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            }
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        root.present().map_err(draw_err)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_colour_map_runs_from_dark_to_light() {
        let lum = |c: RGBColor| 0.3 * f64::from(c.0) + 0.6 * f64::from(c.1) + 0.1 * f64::from(c.2);
        let mut last = -1.0;
        for k in 0..=20 {
            let l = lum(colour_map(f64::from(k) / 20.0));
            assert!(l > last, "{k}");
            last = l;
        }
    }
}
