//! The expectation language of scenario files: what must hold for a run to pass.
//!
//! An expectation compares a metric of one source with a number or with another
//! source's metric, optionally scaled:
//!
//! ```text
//! ate_rmse_m.eif <= 0.3
//! sigma_u_m.eif < sigma_u_m.gnss
//! d_m.tracking_camera > 2 * d_m.eif
//! collisions.robot <= 0
//! max_cross_track_m.robot < 0.2
//! ```
//!
//! Sources are the estimators the scenario runs (`[estimators] run`), with the metrics of
//! [`METRICS`] (and, for the sources `[mapper]` maps, [`MAP_METRICS`]), and the
//! pseudo-source [`ROBOT_SOURCE`] (`robot`): the robot's own run
//! from ground truth, always available, with the metrics of [`ROBOT_METRICS`].
//!
//! ```
//! use vinebench::scoring::expect::Expectation;
//! let e = Expectation::parse("sigma_u_m.eif < 0.5 * sigma_u_m.gnss", &["eif", "gnss"]).unwrap();
//! let r = e.evaluate(|metric, source| match (metric, source) {
//!     ("sigma_u_m", "eif") => Some(0.2),
//!     ("sigma_u_m", "gnss") => Some(0.45),
//!     _ => None,
//! });
//! assert!(r.holds);
//! assert!((r.margin.unwrap() - 0.025).abs() < 1e-12);
//! ```

use serde::Serialize;
use std::fmt;
use thiserror::Error;

/// Metric names an expectation may use (see `scenarios/defaults.toml`).
pub const METRICS: &[(&str, &str)] = &[
    (
        "ate_rmse_m",
        "absolute trajectory error, RMSE, no alignment (m)",
    ),
    (
        "ate_rmse_aligned_m",
        "absolute trajectory error, RMSE, after SE(3) Umeyama alignment (m)",
    ),
    (
        "ate_mean_m",
        "absolute trajectory error, mean, no alignment (m)",
    ),
    (
        "ate_max_m",
        "absolute trajectory error, maximum, no alignment (m)",
    ),
    (
        "rpe_rmse_m",
        "relative pose error over the scoring distance, translation RMSE (m)",
    ),
    ("d_m", "start-to-end distance, 3D (m) (Table 1: D)"),
    (
        "d_en_m",
        "start-to-end distance in the East-North plane (m) (Table 1: D_EN)",
    ),
    (
        "d_u_m",
        "start-to-end altitude difference (m) (Table 1: D_U)",
    ),
    (
        "sigma_u_m",
        "standard deviation of the altitude along the path (m) (Table 1: σ_U)",
    ),
    (
        "outage_max_error_m",
        "largest position error inside the fault windows, no alignment (m)",
    ),
    (
        "coverage",
        "fraction of ground-truth poses with an estimate within the time tolerance",
    ),
];

/// Map metrics of an estimate source that `[mapper]` maps (see `scenarios/defaults.toml`
/// and [`crate::scoring::map`]).
pub const MAP_METRICS: &[(&str, &str)] = &[
    (
        "map_accuracy_m",
        "mean distance from the map's points to the true surfaces (m)",
    ),
    (
        "map_completeness_m",
        "mean distance from the true surfaces the cameras saw to the map (m)",
    ),
    (
        "map_chamfer_m",
        "mean of map_accuracy_m and map_completeness_m (m)",
    ),
    (
        "map_precision_1cm",
        "fraction of map points within 1 cm of the true surfaces",
    ),
    (
        "map_precision_2cm",
        "fraction of map points within 2 cm of the true surfaces",
    ),
    (
        "map_precision_5cm",
        "fraction of map points within 5 cm of the true surfaces",
    ),
    (
        "map_recall_1cm",
        "fraction of the seen true surface within 1 cm of the map",
    ),
    (
        "map_recall_2cm",
        "fraction of the seen true surface within 2 cm of the map",
    ),
    (
        "map_recall_5cm",
        "fraction of the seen true surface within 5 cm of the map",
    ),
    (
        "map_f_score_1cm",
        "F-score at 1 cm (harmonic mean of precision and recall)",
    ),
    ("map_f_score_2cm", "F-score at 2 cm"),
    ("map_f_score_5cm", "F-score at 5 cm"),
];

/// Metrics of the SLAM's estimate sources (`slam` and its baselines; see `[slam]` in
/// `scenarios/defaults.toml`).
pub const SLAM_METRICS: &[(&str, &str)] = &[
    (
        "tracking_losses",
        "times the SLAM lost track (each ends when it tracks again or restarts its map)",
    ),
    (
        "tracking_lost_s",
        "total time the SLAM was lost, to the end of the run if it never recovered (s)",
    ),
    ("keyframes", "keyframes the SLAM inserted"),
    (
        "maps_started",
        "maps the SLAM started (1 + reinitializations after losses)",
    ),
    ("loops", "loop closures the SLAM accepted (loops.csv)"),
    (
        "false_loops",
        "accepted loops whose true poses are farther apart than scoring.loop_distance_m",
    ),
    (
        "loop_precision",
        "true loops / accepted loops (undefined without loops)",
    ),
    (
        "loop_precision_heading",
        "loops true with the heading check too / accepted loops",
    ),
    (
        "loop_recall",
        "ground-truth revisit episodes with a loop / revisit episodes (undefined without revisits)",
    ),
    ("revisits", "ground-truth revisit episodes of the run"),
    (
        "bow_candidates",
        "loop candidates bag of words reported, before the geometric check (loop_closure.method = \"bow\" only)",
    ),
    (
        "bow_rejected",
        "bag-of-words candidates the geometric check rejected (loop_closure.method = \"bow\" only)",
    ),
];

/// The pseudo-source of the robot's own run (ground truth against its route).
pub const ROBOT_SOURCE: &str = "robot";

/// Metric names of the pseudo-source [`ROBOT_SOURCE`] (see `scenarios/defaults.toml`).
pub const ROBOT_METRICS: &[(&str, &str)] = &[
    (
        "collisions",
        "contacts with trellis posts, vine trunks or the ground (the chassis bottoming out) begun during the run (count)",
    ),
    (
        "route_completed",
        "1 when the robot completed its route, 0 when it got stuck, a time limit or the \
         closed-loop safety layer stopped it, its physics diverged or it tipped over",
    ),
    (
        "max_cross_track_m",
        "largest horizontal distance of the body origin from the route (m)",
    ),
    (
        "max_heading_error_deg",
        "largest heading error against the route's heading policy while moving faster than 5 cm/s (degrees)",
    ),
    (
        "max_tilt_deg",
        "largest angle between the body z axis and the vertical (degrees)",
    ),
    ("distance_m", "distance travelled by the body origin (m)"),
    (
        "canopy_intrusion_s",
        "time the robot's footprint spent inside a vine's leaf wall seen from above (s)",
    ),
    (
        "canopy_intrusion_max_m",
        "deepest intrusion of the footprint into a leaf wall, across the row (m)",
    ),
    (
        "min_clearance_m",
        "smallest horizontal distance between the footprint and a trellis post or vine trunk (m; negative: overlap)",
    ),
    (
        "stopped_by_safety",
        "1 when the closed-loop safety layer stopped the robot (estimate lost or too uncertain), else 0",
    ),
    (
        "gnss_fixed_share",
        "share of the GNSS receiver's epochs with an RTK fixed solution (0 to 1)",
    ),
    (
        "gnss_no_fix_share",
        "share of the GNSS receiver's epochs without a position (0 to 1)",
    ),
    (
        "gnss_fix_losses",
        "times the GNSS receiver lost its RTK fixed solution (count)",
    ),
    (
        "gnss_refix_max_s",
        "longest time from losing an RTK fix to fixing again (s; none without a loss that came back)",
    ),
    (
        "gnss_mean_satellites",
        "mean number of satellites the GNSS receiver used (needs [sensors.gnss.sky])",
    ),
    (
        "compare_end_gap_m",
        "largest horizontal distance between the run's end position and that of a `motion.compare_with` model (m)",
    ),
    (
        "compare_path_separation_m",
        "largest distance of a position of the run from the path of a `motion.compare_with` model (m)",
    ),
];

/// A comparison operator.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
pub enum Op {
    /// `<`
    Lt,
    /// `<=`
    Le,
    /// `>`
    Gt,
    /// `>=`
    Ge,
}

impl Op {
    /// Every operator with its symbol, two-character symbols first (for parsers).
    pub const ALL: [(&'static str, Op); 4] =
        [("<=", Op::Le), (">=", Op::Ge), ("<", Op::Lt), (">", Op::Gt)];

    /// The operator as written.
    pub fn symbol(self) -> &'static str {
        match self {
            Op::Lt => "<",
            Op::Le => "<=",
            Op::Gt => ">",
            Op::Ge => ">=",
        }
    }
}

/// `metric.source`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct MetricRef {
    /// Metric name (one of [`METRICS`] for an estimate source, of [`ROBOT_METRICS`] for
    /// `robot`).
    pub metric: String,
    /// Source name (`eif`, `gnss`, `tracking_camera`, or [`ROBOT_SOURCE`]).
    pub source: String,
}

impl MetricRef {
    /// True for a metric of the robot's own run ([`ROBOT_SOURCE`]).
    pub fn is_robot(&self) -> bool {
        self.source == ROBOT_SOURCE
    }
}

impl fmt::Display for MetricRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}", self.metric, self.source)
    }
}

/// The right-hand side of an expectation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum Rhs {
    /// A number.
    Number(f64),
    /// `factor * metric.source`.
    Metric {
        /// Scale factor (1 when not written).
        factor: f64,
        /// The metric.
        metric: MetricRef,
    },
}

/// A parsed expectation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Expectation {
    /// The text as written.
    pub text: String,
    /// Left-hand side.
    pub lhs: MetricRef,
    /// Operator.
    pub op: Op,
    /// Right-hand side.
    pub rhs: Rhs,
}

/// An expectation that cannot be parsed; the message says what was expected.
#[derive(Clone, Debug, Error, PartialEq)]
#[error("{0}")]
pub struct ExpectationError(pub String);

/// The outcome of one expectation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ExpectationResult {
    /// The text as written.
    pub text: String,
    /// Whether it holds.
    pub holds: bool,
    /// Value of the left-hand side (absent when the source produced no value).
    pub lhs: Option<f64>,
    /// Value of the right-hand side.
    pub rhs: Option<f64>,
    /// How far inside the bound the value is (positive) or outside it (negative), in the
    /// metric's unit.
    pub margin: Option<f64>,
    /// Why it could not be evaluated, if so.
    pub note: Option<String>,
}

impl fmt::Display for ExpectationResult {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let verdict = if self.holds { "holds" } else { "FAILS" };
        match (self.lhs, self.rhs, self.margin) {
            (Some(l), Some(r), Some(m)) => write!(
                f,
                "{verdict}: {}  ({l:.4} vs {r:.4}, {} {:.4})",
                self.text,
                if m >= 0.0 { "margin" } else { "off by" },
                m.abs()
            ),
            _ => write!(
                f,
                "{verdict}: {}  ({})",
                self.text,
                self.note.as_deref().unwrap_or("no value")
            ),
        }
    }
}

impl Expectation {
    /// The metric references it uses: the left-hand side, then the right's if any.
    pub fn refs(&self) -> impl Iterator<Item = &MetricRef> {
        std::iter::once(&self.lhs).chain(match &self.rhs {
            Rhs::Metric { metric, .. } => Some(metric),
            Rhs::Number(_) => None,
        })
    }

    /// Parses `text`; `sources` are the estimate sources the scenario runs
    /// ([`ROBOT_SOURCE`] is always valid and need not be listed).
    pub fn parse(text: &str, sources: &[&str]) -> Result<Expectation, ExpectationError> {
        let t = text.trim();
        let (pos, sym, op) = Op::ALL
            .iter()
            .filter_map(|(s, o)| t.find(s).map(|p| (p, *s, *o)))
            .min_by_key(|(p, s, _)| (*p, std::cmp::Reverse(s.len())))
            .ok_or_else(|| {
                ExpectationError(format!(
                    "expected `<metric>.<source> <op> <value>` with op one of < <= > >=, found {t:?}"
                ))
            })?;
        let lhs = parse_ref(t[..pos].trim(), sources)?;
        let right = t[pos + sym.len()..].trim();
        let rhs = if let Ok(v) = right.parse::<f64>() {
            if !v.is_finite() {
                return Err(ExpectationError(format!(
                    "the bound must be finite, found {right}"
                )));
            }
            Rhs::Number(v)
        } else if let Some((f, m)) = right.split_once('*') {
            let factor: f64 = f.trim().parse().map_err(|_| {
                ExpectationError(format!(
                    "expected `<number> * <metric>.<source>` on the right, found {right:?}"
                ))
            })?;
            Rhs::Metric {
                factor,
                metric: parse_ref(m.trim(), sources)?,
            }
        } else {
            Rhs::Metric {
                factor: 1.0,
                metric: parse_ref(right, sources)?,
            }
        };
        Ok(Expectation {
            text: t.to_string(),
            lhs,
            op,
            rhs,
        })
    }

    /// Evaluates with `value(metric, source)`.
    pub fn evaluate(&self, value: impl Fn(&str, &str) -> Option<f64>) -> ExpectationResult {
        let lhs = value(&self.lhs.metric, &self.lhs.source);
        let rhs = match &self.rhs {
            Rhs::Number(v) => Some(*v),
            Rhs::Metric { factor, metric } => {
                value(&metric.metric, &metric.source).map(|v| factor * v)
            }
        };
        judge(&self.text, self.op, (lhs, &self.lhs.to_string()), rhs)
    }

    /// The operator as written.
    pub fn op_symbol(&self) -> &'static str {
        self.op.symbol()
    }
}

/// The outcome of `lhs op rhs`: whether it holds and by what margin; a missing or
/// non-finite side fails with a note (`lhs.1` names the left-hand side).
pub fn judge(text: &str, op: Op, lhs: (Option<f64>, &str), rhs: Option<f64>) -> ExpectationResult {
    let (lhs, lhs_name) = lhs;
    let (holds, margin, note) = match (lhs, rhs) {
        (Some(l), Some(r)) if l.is_finite() && r.is_finite() => {
            let m = match op {
                Op::Lt | Op::Le => r - l,
                Op::Gt | Op::Ge => l - r,
            };
            let holds = match op {
                Op::Lt => l < r,
                Op::Le => l <= r,
                Op::Gt => l > r,
                Op::Ge => l >= r,
            };
            (holds, Some(m), None)
        }
        (None, _) => (false, None, Some(format!("{lhs_name} has no value"))),
        (_, None) => (
            false,
            None,
            Some("the right-hand side has no value".to_string()),
        ),
        _ => (false, None, Some("a value is NaN or infinite".to_string())),
    };
    ExpectationResult {
        text: text.to_string(),
        holds,
        lhs,
        rhs,
        margin,
        note,
    }
}

/// True when `name` is a metric some source can report: an estimate source's, the
/// robot's, the SLAM's or a map's.
pub fn is_known_metric(name: &str) -> bool {
    [METRICS, ROBOT_METRICS, SLAM_METRICS, MAP_METRICS]
        .iter()
        .any(|list| list.iter().any(|(m, _)| *m == name))
}

fn names(list: &[(&str, &str)]) -> String {
    list.iter().map(|m| m.0).collect::<Vec<_>>().join(", ")
}

/// Which metrics each kind of source has, for error messages.
fn metrics_by_kind(sources: &[&str]) -> String {
    format!(
        "estimate sources ({}) have: {}, and when [mapper] maps them: {}; SLAM sources \
         also have: {}; `{ROBOT_SOURCE}` (the robot's own run) has: {}",
        sources.join(", "),
        names(METRICS),
        names(MAP_METRICS),
        names(SLAM_METRICS),
        names(ROBOT_METRICS)
    )
}

fn parse_ref(s: &str, sources: &[&str]) -> Result<MetricRef, ExpectationError> {
    let (metric, source) = s.split_once('.').ok_or_else(|| {
        ExpectationError(format!(
            "expected `<metric>.<source>` such as `ate_rmse_m.eif` or `collisions.robot`, found {s:?}"
        ))
    })?;
    let estimate_metric = METRICS
        .iter()
        .chain(MAP_METRICS)
        .chain(SLAM_METRICS)
        .any(|(m, _)| *m == metric);
    let robot_metric = ROBOT_METRICS.iter().any(|(m, _)| *m == metric);
    if !estimate_metric && !robot_metric {
        return Err(ExpectationError(format!(
            "unknown metric `{metric}`; {}",
            metrics_by_kind(sources)
        )));
    }
    if source == ROBOT_SOURCE {
        if !robot_metric {
            return Err(ExpectationError(format!(
                "`{metric}` is a metric of estimate sources, not of `{ROBOT_SOURCE}`; {}",
                metrics_by_kind(sources)
            )));
        }
    } else {
        if !sources.contains(&source) {
            return Err(ExpectationError(format!(
                "unknown source `{source}`; this scenario runs: {} (set [estimators] run), and \
                 `{ROBOT_SOURCE}` (the robot's own run) is always available",
                sources.join(", ")
            )));
        }
        if !estimate_metric {
            return Err(ExpectationError(format!(
                "`{metric}` is a metric of `{ROBOT_SOURCE}` (write `{metric}.{ROBOT_SOURCE}`), \
                 not of the estimate source `{source}`; {}",
                metrics_by_kind(sources)
            )));
        }
    }
    Ok(MetricRef {
        metric: metric.to_string(),
        source: source.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SRC: &[&str] = &["eif", "gnss", "tracking_camera"];

    fn eval(text: &str, l: f64, r: f64) -> ExpectationResult {
        Expectation::parse(text, SRC)
            .unwrap()
            .evaluate(|m, s| match (m, s) {
                ("ate_rmse_m", "eif") | ("d_m", "tracking_camera") => Some(l),
                ("ate_rmse_m", "gnss") | ("d_m", "eif") => Some(r),
                _ => None,
            })
    }

    #[test]
    fn map_metric_names_are_those_map_scoring_computes() {
        let ours: Vec<&str> = MAP_METRICS.iter().map(|m| m.0).collect();
        assert_eq!(ours, crate::scoring::map::MapScore::METRIC_NAMES.to_vec());
        let e = Expectation::parse("map_f_score_2cm.eif > 0.9 * map_f_score_2cm.gnss", SRC);
        assert!(e.is_ok(), "{e:?}");
        let e = Expectation::parse("map_f_score_2cm.robot > 0.5", SRC).unwrap_err();
        assert!(e.0.contains("metric of estimate sources"), "{e}");
    }

    #[test]
    fn metric_names_are_those_scoring_computes() {
        let mut ours: Vec<&str> = METRICS.iter().map(|m| m.0).collect();
        let mut scoring = crate::scoring::SourceScore::METRIC_NAMES.to_vec();
        ours.sort_unstable();
        scoring.sort_unstable();
        assert_eq!(ours, scoring);
    }

    #[test]
    fn robot_is_always_a_source_with_its_own_metrics() {
        for sources in [SRC, &["gnss"][..], &[][..]] {
            let x = Expectation::parse("collisions.robot <= 0", sources).unwrap();
            assert!(x.lhs.is_robot());
            assert_eq!(x.lhs.metric, "collisions");
        }
        let x = Expectation::parse("distance_m.robot > 100 * ate_rmse_m.eif", SRC).unwrap();
        assert!(x.lhs.is_robot());
        let Rhs::Metric { factor, metric } = &x.rhs else {
            panic!("{x:?}")
        };
        assert_eq!((*factor, metric.is_robot()), (100.0, false));

        // A robot metric on an estimate source, an estimate metric on `robot`: the error
        // says which metrics each kind of source has.
        let e = |t| Expectation::parse(t, SRC).unwrap_err().0;
        for msg in [
            e("max_tilt_deg.eif < 5"),
            e("ate_rmse_m.robot < 1"),
            e("tilt.robot < 5"),
        ] {
            assert!(
                msg.contains("estimate sources (eif, gnss, tracking_camera) have: ate_rmse_m,"),
                "{msg}"
            );
            assert!(
                msg.contains("`robot` (the robot's own run) has: collisions, route_completed,"),
                "{msg}"
            );
        }
        assert!(e("max_tilt_deg.eif < 5").contains("write `max_tilt_deg.robot`"));
        assert!(e("ate_rmse_m.robot < 1").contains("not of `robot`"));
        assert!(e("tilt.robot < 5").contains("unknown metric `tilt`"));
        // On the right-hand side too.
        assert!(e("collisions.robot <= d_m.robot").contains("not of `robot`"));
        // Unknown sources mention `robot`.
        assert!(e("collisions.robots <= 0").contains("`robot` (the robot's own run) is always"));
    }

    #[test]
    fn operators_and_margins() {
        assert!(eval("ate_rmse_m.eif <= 0.3", 0.3, 0.0).holds);
        assert!(!eval("ate_rmse_m.eif < 0.3", 0.3, 0.0).holds);
        let r = eval("ate_rmse_m.eif < ate_rmse_m.gnss", 0.4, 0.5);
        assert!(r.holds && (r.margin.unwrap() - 0.1).abs() < 1e-12);
        let r = eval("d_m.tracking_camera > 2 * d_m.eif", 1.0, 0.6);
        assert!(!r.holds && (r.margin.unwrap() + 0.2).abs() < 1e-12);
        assert!(eval("d_m.tracking_camera >= 2*d_m.eif", 1.2, 0.6).holds);
    }

    #[test]
    fn missing_values_fail_with_a_note() {
        let r = eval("sigma_u_m.eif < 1", 0.0, 0.0);
        assert!(!r.holds);
        assert!(r.note.unwrap().contains("sigma_u_m.eif"));
    }

    #[test]
    fn parse_errors_say_what_was_expected() {
        let e = |t| Expectation::parse(t, SRC).unwrap_err().0;
        assert!(e("ate_rmse_m.eif = 0.3").contains("op one of"));
        assert!(e("ate.eif < 1").contains("unknown metric `ate`"));
        assert!(e("ate_rmse_m.ekf < 1").contains("unknown source `ekf`"));
        assert!(e("ate_rmse_m < 1").contains("<metric>.<source>"));
        assert!(e("ate_rmse_m.eif < x * d_m.eif").contains("<number> *"));
        assert!(e("ate_rmse_m.eif < inf").contains("finite"));
    }
}
