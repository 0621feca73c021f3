//! The sweep's figures (SVG): each metric against each varied axis, a line per source
//! with its 95 % confidence band; for a two-axis grid, a heat map of each metric's mean.
//!
//! An axis is plotted against its numbers when its values are numbers, against the one
//! component that varies when they are lists of numbers (`size_m = [0.4, w, 1.0]`
//! plots against `w`), and as categories otherwise. Style (size, palette, legend) is
//! that of the run report's plots ([`crate::scoring::plots`]).

use crate::scoring::plots::{
    PlotError, SIZE_PX, chart_builder, draw_err, draw_legend, padded_range, source_colour,
};
use crate::sweep::run::SweepRunError;
use crate::sweep::spec::value_text;
use crate::sweep::summary::{MergeSummary, SweepInfo};
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;

/// Most lines in one plot (sources × values of the other axes).
pub const MAX_SERIES: usize = 8;

/// How an axis's values map to the x axis.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisScale {
    /// x per cell.
    pub x: Vec<f64>,
    /// Axis title.
    pub title: String,
    /// Category labels (x = 0, 1, ...), when the values are not numbers.
    pub categories: Option<Vec<String>>,
}

fn number(v: &toml::Value) -> Option<f64> {
    match v {
        toml::Value::Integer(i) => Some(*i as f64),
        toml::Value::Float(f) => Some(*f),
        _ => None,
    }
}

/// The x of each cell for axis `a`.
pub fn axis_scale(info: &SweepInfo, a: usize) -> AxisScale {
    let axis = &info.axes[a];
    let key = axis.label.as_ref().unwrap_or(&axis.key);
    let values: Vec<&toml::Value> = info.cells.iter().map(|c| &c[a]).collect();
    if let Some(xs) = &axis.x {
        // Each cell's value at its position in the axis's list.
        let x: Option<Vec<f64>> = values
            .iter()
            .map(|v| {
                axis.values
                    .iter()
                    .position(|w| w == *v)
                    .and_then(|i| xs.get(i).copied())
            })
            .collect();
        if let Some(x) = x {
            return AxisScale {
                x,
                title: key.clone(),
                categories: None,
            };
        }
    }
    if let Some(x) = values
        .iter()
        .map(|v| number(v))
        .collect::<Option<Vec<f64>>>()
    {
        return AxisScale {
            x,
            title: key.clone(),
            categories: None,
        };
    }
    // Lists of numbers of one length where exactly one component varies.
    let lists: Option<Vec<Vec<f64>>> = values
        .iter()
        .map(|v| match v {
            toml::Value::Array(items) => items.iter().map(number).collect(),
            _ => None,
        })
        .collect();
    if let Some(lists) = lists
        && let Some(first) = lists.first()
        && lists.iter().all(|l| l.len() == first.len())
    {
        let varying: Vec<usize> = (0..first.len())
            .filter(|&k| lists.iter().any(|l| l[k] != first[k]))
            .collect();
        if let [k] = varying[..] {
            return AxisScale {
                x: lists.iter().map(|l| l[k]).collect(),
                title: format!("{key}[{k}]"),
                categories: None,
            };
        }
    }
    let mut labels: Vec<String> = Vec::new();
    let x = values
        .iter()
        .map(|v| {
            let t = value_text(v);
            let i = labels.iter().position(|l| *l == t).unwrap_or_else(|| {
                labels.push(t);
                labels.len() - 1
            });
            i as f64
        })
        .collect();
    AxisScale {
        x,
        title: key.clone(),
        categories: Some(labels),
    }
}

/// One line: (x, mean, ci low, ci high) points.
struct Line {
    label: String,
    points: Vec<(f64, f64, f64, f64)>,
}

fn file_stem(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Writes the plots into `dir`; returns (title, path relative to the sweep folder).
pub fn write_plots(
    info: &SweepInfo,
    s: &MergeSummary,
    dir: &Path,
) -> Result<Vec<(String, String)>, SweepRunError> {
    let plot_err = |e: PlotError| SweepRunError::Io {
        path: dir.display().to_string(),
        message: e.to_string(),
    };
    let mut out = Vec::new();
    // metric → sources (columns `metric.source`).
    let mut metrics: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for c in &s.cells {
        for col in c.metrics.keys() {
            if let Some((m, src)) = col.split_once('.') {
                let v = metrics.entry(m).or_default();
                if !v.contains(&src) {
                    v.push(src);
                }
            }
        }
    }
    let varied: Vec<usize> = (0..info.axes.len()).filter(|&a| info.varies(a)).collect();
    for &a in &varied {
        let scale = axis_scale(info, a);
        for (metric, sources) in &metrics {
            let mut lines: Vec<Line> = Vec::new();
            for scenario in &info.scenarios {
                for src in sources {
                    let col = format!("{metric}.{src}");
                    // Group cells by the values of the other axes.
                    let mut groups: BTreeMap<String, Vec<(f64, f64, f64, f64)>> = BTreeMap::new();
                    for c in s.cells.iter().filter(|c| &c.scenario == scenario) {
                        let Some(m) = c.metrics.get(&col) else {
                            continue;
                        };
                        let others: Vec<String> = varied
                            .iter()
                            .filter(|&&b| b != a)
                            .map(|&b| {
                                format!(
                                    "{} = {}",
                                    info.axes[b].key,
                                    value_text(&info.cells[c.cell][b])
                                )
                            })
                            .collect();
                        groups.entry(others.join(", ")).or_default().push((
                            scale.x[c.cell],
                            m.mean,
                            m.ci95.0,
                            m.ci95.1,
                        ));
                    }
                    for (others, mut points) in groups {
                        points.sort_by(|p, q| p.0.total_cmp(&q.0));
                        let mut label = (*src).to_string();
                        if info.scenarios.len() > 1 {
                            label = format!("{scenario}: {label}");
                        }
                        if !others.is_empty() {
                            label = format!("{label} ({others})");
                        }
                        lines.push(Line { label, points });
                    }
                }
            }
            if lines.is_empty() {
                continue;
            }
            lines.truncate(MAX_SERIES);
            let title = format!("{metric} against {}", scale.title);
            let svg = line_plot(&title, &scale, metric, &lines).map_err(plot_err)?;
            let name = format!("{}__{}.svg", file_stem(metric), file_stem(&scale.title));
            let p = dir.join(&name);
            crate::sweep::run::write_file(&p, svg.as_bytes())?;
            out.push((title, format!("plots/{name}")));
        }
    }
    if varied.len() == 2 && info.scenarios.len() == 1 {
        let (sa, sb) = (axis_scale(info, varied[0]), axis_scale(info, varied[1]));
        let cols: Vec<&String> = s
            .cells
            .iter()
            .flat_map(|c| c.metrics.keys())
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect();
        for col in cols {
            let cells: Vec<(f64, f64, f64)> = s
                .cells
                .iter()
                .filter_map(|c| {
                    c.metrics
                        .get(col)
                        .map(|m| (sa.x[c.cell], sb.x[c.cell], m.mean))
                })
                .collect();
            let title = format!("mean {col}");
            let svg = heat_map(&title, &sa, &sb, &cells).map_err(plot_err)?;
            let name = format!("heatmap__{}.svg", file_stem(col));
            let p = dir.join(&name);
            crate::sweep::run::write_file(&p, svg.as_bytes())?;
            out.push((title, format!("plots/{name}")));
        }
    }
    Ok(out)
}

fn category_label(scale: &AxisScale, x: f64) -> String {
    match &scale.categories {
        Some(labels) if (x - x.round()).abs() < 1e-9 && x >= 0.0 => {
            labels.get(x.round() as usize).cloned().unwrap_or_default()
        }
        Some(_) => String::new(),
        None => format!("{x}"),
    }
}

fn line_plot(
    title: &str,
    scale: &AxisScale,
    metric: &str,
    lines: &[Line],
) -> Result<String, PlotError> {
    let (x0, x1) = padded_range(lines.iter().flat_map(|l| l.points.iter().map(|p| p.0)));
    let (y0, y1) = padded_range(
        lines
            .iter()
            .flat_map(|l| l.points.iter().flat_map(|p| [p.1, p.2, p.3])),
    );
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE_PX).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = chart_builder(&root, title)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(draw_err)?;
        let fmt = |x: &f64| category_label(scale, *x);
        let mut mesh = chart.configure_mesh();
        mesh.x_desc(scale.title.as_str())
            .y_desc(format!("{metric}: mean, 95 % CI"));
        if scale.categories.is_some() {
            mesh.x_label_formatter(&fmt);
        }
        mesh.draw().map_err(draw_err)?;
        for (i, l) in lines.iter().enumerate() {
            let colour = source_colour(i);
            let band: Vec<(f64, f64)> = l
                .points
                .iter()
                .map(|p| (p.0, p.3))
                .chain(l.points.iter().rev().map(|p| (p.0, p.2)))
                .filter(|p| p.1.is_finite())
                .collect();
            if band.len() >= 3 {
                chart
                    .draw_series(std::iter::once(Polygon::new(
                        band,
                        colour.mix(0.18).filled(),
                    )))
                    .map_err(draw_err)?;
            }
            let style = colour.stroke_width(2);
            chart
                .draw_series(LineSeries::new(l.points.iter().map(|p| (p.0, p.1)), style))
                .map_err(draw_err)?
                .label(l.label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            chart
                .draw_series(
                    l.points
                        .iter()
                        .map(|p| Circle::new((p.0, p.1), 4, colour.filled())),
                )
                .map_err(draw_err)?;
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Viridis, interpolated between five anchors (t in [0, 1]).
fn viridis(t: f64) -> RGBColor {
    const A: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let f = t * 4.0;
    let i = (f.floor() as usize).min(3);
    let u = f - i as f64;
    let (a, b) = (A[i], A[i + 1]);
    let mix = |p: f64, q: f64| (p + (q - p) * u).round().clamp(0.0, 255.0) as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// The label of the grid column (or row) at `at`: the axis value there, nothing between.
fn grid_label(values: &[f64], scale: &AxisScale, at: f64) -> String {
    let i = at.round();
    if (at - i).abs() > 1e-9 || i < 0.0 {
        return String::new();
    }
    values
        .get(i as usize)
        .map(|v| category_label(scale, *v))
        .unwrap_or_default()
}

fn heat_map(
    title: &str,
    sa: &AxisScale,
    sb: &AxisScale,
    cells: &[(f64, f64, f64)],
) -> Result<String, PlotError> {
    let mut xs: Vec<f64> = cells.iter().map(|c| c.0).collect();
    let mut ys: Vec<f64> = cells.iter().map(|c| c.1).collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    ys.sort_by(f64::total_cmp);
    ys.dedup();
    let (lo, hi) = cells
        .iter()
        .map(|c| c.2)
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    let idx = |v: &[f64], x: f64| v.iter().position(|p| *p == x).unwrap_or(0) as f64;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE_PX).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = chart_builder(&root, title)
            .build_cartesian_2d(-0.5..xs.len() as f64 - 0.5, -0.5..ys.len() as f64 - 0.5)
            .map_err(draw_err)?;
        let xl = |x: &f64| grid_label(&xs, sa, *x);
        let yl = |y: &f64| grid_label(&ys, sb, *y);
        chart
            .configure_mesh()
            .disable_mesh()
            .x_labels(xs.len())
            .y_labels(ys.len())
            .x_label_formatter(&xl)
            .y_label_formatter(&yl)
            .x_desc(sa.title.as_str())
            .y_desc(sb.title.as_str())
            .draw()
            .map_err(draw_err)?;
        // Grid position and colour-scale position of each cell.
        let placed: Vec<(f64, f64, f64, f64)> = cells
            .iter()
            .map(|&(x, y, v)| {
                let t = if hi > lo { (v - lo) / (hi - lo) } else { 0.5 };
                (idx(&xs, x), idx(&ys, y), v, t)
            })
            .collect();
        chart
            .draw_series(placed.iter().map(|&(i, j, _, t)| {
                Rectangle::new(
                    [(i - 0.5, j - 0.5), (i + 0.5, j + 0.5)],
                    viridis(t).filled(),
                )
            }))
            .map_err(draw_err)?;
        chart
            .draw_series(placed.iter().map(|&(i, j, v, t)| {
                let colour = if t > 0.6 { BLACK } else { WHITE };
                Text::new(
                    format!("{v:.3}"),
                    (i - 0.2, j),
                    ("sans-serif", 16).into_font().color(&colour),
                )
            }))
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(values: Vec<toml::Value>) -> SweepInfo {
        SweepInfo {
            name: "t".into(),
            description: String::new(),
            scenarios: vec!["s".into()],
            seeds: vec![1],
            axes: vec![crate::sweep::summary::AxisInfo {
                key: "k".into(),
                values: Vec::new(),
                label: None,
                x: None,
            }],
            cells: values.into_iter().map(|v| vec![v]).collect(),
            metrics: Vec::new(),
            per_cell: Vec::new(),
            overall: Vec::new(),
            digest: String::new(),
        }
    }

    #[test]
    fn axes_plot_against_numbers_the_varying_component_or_categories() {
        let f = |x: f64| toml::Value::Float(x);
        let s = axis_scale(&info(vec![f(4.8), toml::Value::Integer(5), f(5.8)]), 0);
        assert_eq!(s.x, vec![4.8, 5.0, 5.8]);
        assert!(s.categories.is_none());
        let list = |w: f64| toml::Value::Array(vec![f(0.4), f(w), f(1.0)]);
        let s = axis_scale(&info(vec![list(0.3), list(0.6), list(0.9)]), 0);
        assert_eq!(
            (s.x.clone(), s.title.as_str()),
            (vec![0.3, 0.6, 0.9], "k[1]")
        );
        let text = |t: &str| toml::Value::String(t.into());
        let s = axis_scale(&info(vec![text("eif"), text("truth"), text("eif")]), 0);
        assert_eq!(s.x, vec![0.0, 1.0, 0.0]);
        assert_eq!(s.categories.unwrap(), vec!["\"eif\"", "\"truth\""]);
    }

    #[test]
    fn viridis_runs_from_purple_to_yellow() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(f64::NAN), RGBColor(68, 1, 84));
    }
}
