//! What the robot's GNSS receiver delivered along the run: the solution type of every
//! epoch and, with `[sensors.gnss.sky]`, the satellites and DOP behind it. The runner
//! feeds it every delivered message; the report shows its summary, `gnss.svg` (satellites
//! and solution over time) and `gnss_fix_map.svg` (fixes coloured by solution type).
//!
//! Memory is bounded: the summary is exact over every epoch, the plotted samples are
//! thinned to every second one whenever [`MAX_SAMPLES`] are held.

use crate::scoring::plots::{
    PlotError, SIZE_PX, chart_builder, draw_err, draw_legend, equal_scale, padded_range,
    plotting_area_px,
};
use serde::Serialize;
use std::collections::BTreeMap;
use vinebench_msgs::geodesy::LocalEnu;
use vinebench_msgs::{FixStatus, Message, Nanos};

/// Most plotted samples held (then every second one is dropped and the stride doubles).
pub const MAX_SAMPLES: usize = 100_000;
/// Most re-fix durations kept for the median (the count and maximum stay exact).
const MAX_REFIXES: usize = 100_000;

/// One plotted epoch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GnssSample {
    /// Epoch.
    pub t: Nanos,
    /// Solution type.
    pub status: FixStatus,
    /// The fix, east and north in the world, m (None without a fix).
    pub position: Option<[f64; 2]>,
    /// Satellites tracked and used (with the sky model).
    pub tracked: Option<u16>,
    /// Satellites used.
    pub used: Option<u16>,
    /// Satellites above the horizon with a clear line of sight or through foliage.
    pub in_view: Option<u16>,
    /// Satellites strong enough to help fix RTK ambiguities.
    pub strong: Option<u16>,
    /// HDOP (sky model, with a solution).
    pub hdop: Option<f64>,
}

/// The receiver's run in numbers (`report.json` → `robot.gnss`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct GnssSummary {
    /// Epochs (fixes delivered).
    pub epochs: u64,
    /// Share of the epochs per solution type (`rtk_fixed`, `rtk_float`, `single`,
    /// `no_fix`).
    pub share: BTreeMap<String, f64>,
    /// Times an RTK fixed solution was lost.
    pub fix_losses: u64,
    /// Times it came back, and how long each took from the loss, s: median and maximum.
    pub refixes: u64,
    /// Median time from a fix loss to the next fix, s.
    pub refix_median_s: Option<f64>,
    /// Longest time from a fix loss to the next fix, s.
    pub refix_max_s: Option<f64>,
    /// Whether the sky model produced the solutions (the fields below need it).
    pub sky_model: bool,
    /// Mean number of satellites used.
    pub mean_satellites_used: Option<f64>,
    /// Fewest satellites used at an epoch.
    pub min_satellites_used: Option<u64>,
    /// Mean HDOP over epochs with a solution.
    pub mean_hdop: Option<f64>,
    /// Largest HDOP of an epoch with a solution.
    pub max_hdop: Option<f64>,
}

impl GnssSummary {
    /// Share of epochs of one solution type (0 without epochs).
    pub fn share_of(&self, status: FixStatus) -> f64 {
        self.share.get(status.name()).copied().unwrap_or(0.0)
    }
}

/// Collects the receiver's epochs as they are delivered.
#[derive(Clone, Debug)]
pub struct GnssLog {
    enu: LocalEnu,
    sky_model: bool,
    samples: Vec<GnssSample>,
    stride: u64,
    epochs: u64,
    counts: [u64; 4],
    last_status: Option<FixStatus>,
    lost_at: Option<Nanos>,
    fix_losses: u64,
    refixes: Vec<f64>,
    refix_count: u64,
    refix_max: f64,
    used_sum: u64,
    used_min: Option<u64>,
    hdop_sum: f64,
    hdop_n: u64,
    hdop_max: Option<f64>,
}

impl GnssLog {
    /// A log for a receiver in the world `enu`; `sky_model` says whether its epochs come
    /// with a `/gnss/gpsfix` sky (then those are read and `/gnss/fix` is not).
    pub fn new(enu: LocalEnu, sky_model: bool) -> GnssLog {
        GnssLog {
            enu,
            sky_model,
            samples: Vec::new(),
            stride: 1,
            epochs: 0,
            counts: [0; 4],
            last_status: None,
            lost_at: None,
            fix_losses: 0,
            refixes: Vec::new(),
            refix_count: 0,
            refix_max: 0.0,
            used_sum: 0,
            used_min: None,
            hdop_sum: 0.0,
            hdop_n: 0,
            hdop_max: None,
        }
    }

    /// Takes note of a delivered message (others than the receiver's are ignored).
    pub fn push(&mut self, msg: &Message) {
        let sample = match (msg, self.sky_model) {
            (Message::GnssFix(f), false) => GnssSample {
                t: f.stamp,
                status: f.status,
                position: self.en(f.status, &f.position),
                tracked: None,
                used: None,
                in_view: None,
                strong: None,
                hdop: None,
            },
            (Message::GnssSky(s), true) => {
                let used = s.used() as u64;
                self.used_sum += used;
                self.used_min = Some(self.used_min.map_or(used, |m| m.min(used)));
                let hdop = s
                    .dop
                    .filter(|_| s.status != FixStatus::NoFix)
                    .map(|d| d.hdop);
                if let Some(h) = hdop {
                    self.hdop_sum += h;
                    self.hdop_n += 1;
                    self.hdop_max = Some(self.hdop_max.map_or(h, |m| m.max(h)));
                }
                GnssSample {
                    t: s.stamp,
                    status: s.status,
                    position: self.en(s.status, &s.position),
                    tracked: Some(s.tracked() as u16),
                    used: Some(used as u16),
                    in_view: Some(s.satellites.iter().filter(|x| !x.blocked).count() as u16),
                    strong: Some(s.satellites.iter().filter(|x| x.strong).count() as u16),
                    hdop,
                }
            }
            _ => return,
        };
        self.count(sample.t, sample.status);
        if self.epochs.is_multiple_of(self.stride) {
            if self.samples.len() >= MAX_SAMPLES {
                let mut i = 0;
                self.samples.retain(|_| {
                    i += 1;
                    i % 2 == 1
                });
                self.stride *= 2;
            }
            if self.epochs.is_multiple_of(self.stride) {
                self.samples.push(sample);
            }
        }
        self.epochs += 1;
    }

    fn en(&self, status: FixStatus, g: &vinebench_msgs::geodesy::Geodetic) -> Option<[f64; 2]> {
        if status == FixStatus::NoFix || !g.is_valid() {
            return None;
        }
        let p = self.enu.enu_from_geodetic(g);
        Some([p.x, p.y])
    }

    fn count(&mut self, t: Nanos, status: FixStatus) {
        self.counts[status as usize] += 1;
        let was_fixed = self.last_status == Some(FixStatus::RtkFixed);
        let fixed = status == FixStatus::RtkFixed;
        if was_fixed && !fixed {
            self.fix_losses += 1;
            self.lost_at = Some(t);
        }
        if fixed && let Some(lost) = self.lost_at.take() {
            let d = (t - lost).as_secs_f64();
            self.refix_count += 1;
            self.refix_max = self.refix_max.max(d);
            if self.refixes.len() < MAX_REFIXES {
                self.refixes.push(d);
            }
        }
        self.last_status = Some(status);
    }

    /// Writes `gnss.svg` and `gnss_fix_map.svg` into `dir` (fault windows shaded, the
    /// vine rows drawn under the fixes).
    pub fn plot(
        &self,
        dir: &std::path::Path,
        t0: Nanos,
        windows: &[(Nanos, Nanos)],
        rows: &[Vec<(f64, f64)>],
    ) -> Result<(), PlotError> {
        let write = |name: &str, svg: String| {
            let path = dir.join(name);
            crate::fsio::write_atomic(&path, svg.as_bytes()).map_err(|source| PlotError::Io {
                path: path.display().to_string(),
                source,
            })
        };
        write("gnss.svg", gnss_svg(&self.samples, t0, windows)?)?;
        write("gnss_fix_map.svg", fix_map_svg(&self.samples, rows)?)
    }

    /// The plotted samples (thinned evenly when there were many).
    pub fn samples(&self) -> &[GnssSample] {
        &self.samples
    }

    /// Whether any epoch was delivered.
    pub fn is_empty(&self) -> bool {
        self.epochs == 0
    }

    /// The summary.
    pub fn summary(&self) -> GnssSummary {
        let n = self.epochs;
        let share = if n == 0 {
            BTreeMap::new()
        } else {
            [
                FixStatus::RtkFixed,
                FixStatus::RtkFloat,
                FixStatus::Single,
                FixStatus::NoFix,
            ]
            .iter()
            .map(|s| {
                (
                    s.name().to_string(),
                    self.counts[*s as usize] as f64 / n as f64,
                )
            })
            .collect()
        };
        let mut r = self.refixes.clone();
        r.sort_by(f64::total_cmp);
        let median = (!r.is_empty()).then(|| {
            let m = r.len() / 2;
            if r.len() % 2 == 1 {
                r[m]
            } else {
                0.5 * (r[m - 1] + r[m])
            }
        });
        let sky = self.sky_model && n > 0;
        GnssSummary {
            epochs: n,
            share,
            fix_losses: self.fix_losses,
            refixes: self.refix_count,
            refix_median_s: median,
            refix_max_s: (self.refix_count > 0).then_some(self.refix_max),
            sky_model: self.sky_model,
            mean_satellites_used: sky.then(|| self.used_sum as f64 / n as f64),
            min_satellites_used: if sky { self.used_min } else { None },
            mean_hdop: (self.hdop_n > 0).then(|| self.hdop_sum / self.hdop_n as f64),
            max_hdop: self.hdop_max,
        }
    }
}

impl GnssSummary {
    /// The report's section: solution shares, fix losses, satellites and DOP, plots.
    pub fn markdown(&self) -> String {
        use std::fmt::Write;
        let mut md = String::from("\n## GNSS receiver\n\n");
        let pct = |s: FixStatus| format!("{:.1} %", 100.0 * self.share_of(s));
        let _ = writeln!(
            md,
            "{} epochs{}: RTK fixed {}, float {}, single {}, no fix {}.\n",
            self.epochs,
            if self.sky_model {
                " (solution from the sky: satellites seen through the world)"
            } else {
                " (solution from `nominal_status` and the fault windows)"
            },
            pct(FixStatus::RtkFixed),
            pct(FixStatus::RtkFloat),
            pct(FixStatus::Single),
            pct(FixStatus::NoFix)
        );
        let f = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |v| format!("{v:.d$}"));
        let _ = writeln!(
            md,
            "| fix losses | re-fixed | time to re-fix, median [s] | max [s] | satellites used, mean | min | HDOP, mean | max |\n\
             |---:|---:|---:|---:|---:|---:|---:|---:|\n\
             | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            self.fix_losses,
            self.refixes,
            f(self.refix_median_s, 1),
            f(self.refix_max_s, 1),
            f(self.mean_satellites_used, 1),
            self.min_satellites_used
                .map_or("–".to_string(), |v| v.to_string()),
            f(self.mean_hdop, 2),
            f(self.max_hdop, 2),
        );
        md.push_str(
            "![Satellites and solution type over time](gnss.svg)\n\n\
             ![Fixes by solution type](gnss_fix_map.svg)\n",
        );
        md
    }
}

/// Colour of a solution type in the plots: fixed green, float orange, single red, none
/// black.
fn status_colour(s: FixStatus) -> plotters::style::RGBColor {
    use plotters::style::RGBColor;
    match s {
        FixStatus::RtkFixed => RGBColor(0, 150, 60),
        FixStatus::RtkFloat => RGBColor(240, 150, 0),
        FixStatus::Single => RGBColor(210, 30, 30),
        FixStatus::NoFix => RGBColor(0, 0, 0),
    }
}

const STATUSES: [FixStatus; 4] = [
    FixStatus::RtkFixed,
    FixStatus::RtkFloat,
    FixStatus::Single,
    FixStatus::NoFix,
];

/// Satellites in view, tracked and used over time (with the sky model) above a band
/// coloured by the solution type of each epoch, fault windows shaded; as SVG text.
pub fn gnss_svg(
    samples: &[GnssSample],
    t0: Nanos,
    windows: &[(Nanos, Nanos)],
) -> Result<String, PlotError> {
    use plotters::prelude::*;
    let secs = |t: Nanos| (t - t0).as_secs_f64();
    let (tx0, tx1) = padded_range(samples.iter().map(|s| secs(s.t)));
    let ymax = samples
        .iter()
        .filter_map(|s| s.in_view)
        .map(f64::from)
        .fold(4.0f64, f64::max)
        * 1.15;
    // The solution band sits below zero: [−0.16, −0.04]·ymax.
    let (band0, band1) = (-0.16 * ymax, -0.04 * ymax);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE_PX).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = chart_builder(&root, "GNSS receiver: satellites and solution")
            .build_cartesian_2d(tx0..tx1, (-0.2 * ymax)..ymax)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("time since start (s)")
            .y_desc("satellites (band: solution type)")
            .draw()
            .map_err(draw_err)?;
        let shade = RGBColor(150, 150, 150).mix(0.25).filled();
        let shaded: Vec<_> = windows
            .iter()
            .map(|&(a, b)| (secs(a).max(tx0), secs(b).min(tx1)))
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
        type Count = fn(&GnssSample) -> Option<u16>;
        let lines: [(&str, Count, RGBColor); 3] = [
            (
                "above the horizon, not blocked",
                |s| s.in_view,
                RGBColor(150, 150, 150),
            ),
            (
                "used (tracked above the mask)",
                |s| s.used,
                RGBColor(0, 0, 0),
            ),
            (
                "strong enough to fix RTK",
                |s| s.strong,
                RGBColor(31, 119, 180),
            ),
        ];
        for (label, f, colour) in lines {
            let pts: Vec<(f64, f64)> = samples
                .iter()
                .filter_map(|s| f(s).map(|n| (secs(s.t), f64::from(n))))
                .collect();
            if pts.is_empty() {
                continue;
            }
            let style = colour.stroke_width(2);
            chart
                .draw_series(LineSeries::new(
                    crate::scoring::plots::thin(pts.len(), pts.into_iter()),
                    style,
                ))
                .map_err(draw_err)?
                .label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
        // The band: one rectangle per run of equal solution types.
        let mut runs: Vec<(f64, f64, FixStatus)> = Vec::new();
        for w in samples.windows(2) {
            let (a, b) = (secs(w[0].t), secs(w[1].t));
            match runs.last_mut() {
                Some(r) if r.2 == w[0].status && (r.1 - a).abs() < 1e-9 => r.1 = b,
                _ => runs.push((a, b, w[0].status)),
            }
        }
        for status in STATUSES {
            let c = status_colour(status).filled();
            let rects: Vec<_> = runs
                .iter()
                .filter(|r| r.2 == status)
                .map(|r| Rectangle::new([(r.0, band0), (r.1, band1)], c))
                .collect();
            if rects.is_empty() {
                continue;
            }
            chart
                .draw_series(rects)
                .map_err(draw_err)?
                .label(status.name())
                .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], c));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// The fixes in the East-North plane, coloured by solution type, over the vine rows'
/// centre lines (grey); as SVG text.
pub fn fix_map_svg(samples: &[GnssSample], rows: &[Vec<(f64, f64)>]) -> Result<String, PlotError> {
    use plotters::prelude::*;
    let caption = "GNSS fixes by solution type (ENU)";
    let fixes: Vec<([f64; 2], FixStatus)> = samples
        .iter()
        .filter_map(|s| s.position.map(|p| (p, s.status)))
        .collect();
    let xr = padded_range(fixes.iter().map(|f| f.0[0]));
    let yr = padded_range(fixes.iter().map(|f| f.0[1]));
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
        let grey = RGBColor(170, 170, 170).stroke_width(1);
        for (i, row) in rows.iter().enumerate() {
            let s = chart
                .draw_series(LineSeries::new(row.iter().copied(), grey))
                .map_err(draw_err)?;
            if i == 0 {
                s.label("vine rows")
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey));
            }
        }
        for status in STATUSES {
            let c = status_colour(status).filled();
            let pts: Vec<(f64, f64)> = fixes
                .iter()
                .filter(|f| f.1 == status)
                .map(|f| (f.0[0], f.0[1]))
                .collect();
            if pts.is_empty() {
                continue;
            }
            chart
                .draw_series(
                    crate::scoring::plots::thin(pts.len(), pts.into_iter())
                        .into_iter()
                        .map(|p| Circle::new(p, 2, c)),
                )
                .map_err(draw_err)?
                .label(status.name())
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, c));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;
    use vinebench_msgs::geodesy::Geodetic;
    use vinebench_msgs::{FrameId, GnssFixMsg};

    fn fix(t_s: i64, status: FixStatus) -> Message {
        Message::GnssFix(GnssFixMsg {
            stamp: Nanos(t_s * 100_000_000),
            frame_id: FrameId::new("gnss_antenna"),
            status,
            position: Geodetic {
                lat_deg: 40.0,
                lon_deg: 17.0,
                alt_m: 50.0,
            },
            position_covariance: Matrix3::identity(),
        })
    }

    #[test]
    fn shares_losses_and_refix_times_count_every_epoch() {
        // 10 Hz: fixed 10 epochs, no fix 5, float 5, fixed 10, single 3, fixed 2.
        // Losses at 1.0 s and 3.0 s; back at 2.0 s (1.0 s later) and 3.3 s (0.3 s).
        let enu = LocalEnu::new(Geodetic {
            lat_deg: 40.0,
            lon_deg: 17.0,
            alt_m: 50.0,
        });
        let mut log = GnssLog::new(enu, false);
        let plan = [
            (10, FixStatus::RtkFixed),
            (5, FixStatus::NoFix),
            (5, FixStatus::RtkFloat),
            (10, FixStatus::RtkFixed),
            (3, FixStatus::Single),
            (2, FixStatus::RtkFixed),
        ];
        let mut t = 0;
        for (n, s) in plan {
            for _ in 0..n {
                log.push(&fix(t, s));
                t += 1;
            }
        }
        let s = log.summary();
        assert_eq!(s.epochs, 35);
        assert!((s.share_of(FixStatus::RtkFixed) - 22.0 / 35.0).abs() < 1e-12);
        assert!((s.share_of(FixStatus::NoFix) - 5.0 / 35.0).abs() < 1e-12);
        assert_eq!((s.fix_losses, s.refixes), (2, 2));
        assert!((s.refix_max_s.unwrap() - 1.0).abs() < 1e-9);
        assert!((s.refix_median_s.unwrap() - 0.65).abs() < 1e-9);
        assert_eq!(s.mean_satellites_used, None);
        // No-fix epochs have no position; the origin's fixes sit at (0, 0).
        assert_eq!(
            log.samples()
                .iter()
                .filter(|x| x.position.is_none())
                .count(),
            5
        );
        assert!(log.samples()[0].position.unwrap()[0].abs() < 1e-6);
    }

    #[test]
    fn samples_stay_bounded_and_even() {
        let enu = LocalEnu::new(Geodetic {
            lat_deg: 40.0,
            lon_deg: 17.0,
            alt_m: 50.0,
        });
        let mut log = GnssLog::new(enu, false);
        let n = 3 * MAX_SAMPLES as i64;
        for t in 0..n {
            log.push(&fix(t, FixStatus::RtkFixed));
        }
        let s = log.samples();
        assert!(
            s.len() <= MAX_SAMPLES && s.len() > MAX_SAMPLES / 2,
            "{}",
            s.len()
        );
        let step = s[1].t - s[0].t;
        assert!(s.windows(2).all(|w| w[1].t - w[0].t == step));
        assert_eq!(log.summary().epochs, n as u64);
    }
}
