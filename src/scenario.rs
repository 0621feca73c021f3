//! Scenario files: TOML merged over the embedded defaults, validated, with errors that
//! point at the file, line, column and key.
//!
//! A scenario names the world, robot, route, sensors, faults, estimators and the
//! expectations that must hold. Every key and its default is documented in
//! `scenarios/defaults.toml`; a scenario file only states what differs. Tables merge key
//! by key; arrays and plain values replace the default.
//!
//! ```
//! let s = vinebench::scenario::LoadedScenario::from_str(
//!     "name = \"short\"\n[world.rows]\ncount = 3\n",
//!     "inline.toml",
//! )
//! .unwrap();
//! assert_eq!(s.scenario.world.rows.count, 3);
//! assert_eq!(s.scenario.world.rows.length_m, 120.0); // from the defaults
//! ```

use crate::scoring::ScoringParams;
use crate::scoring::expect::{Expectation, ExpectationError};
use serde::{Deserialize, Serialize};
use std::ops::Range;
use std::path::{Path, PathBuf};
use thiserror::Error;
use vinebench_msgs::Nanos;
use vinebench_msgs::geodesy::Geodetic;
use vinebench_onboard::estimator::EstimatorsParams;
use vinebench_sim::params::{
    FaultsParams, MotionParams, ParamError, PhysicsParams, RenderParams, RobotParams, RouteParams,
    SensorsParams, WorldParams,
};

/// The longest run a scenario may ask for (`max_duration_s`): 30 days.
pub const MAX_DURATION_S: f64 = 30.0 * 86_400.0;

/// The latest `start_time_utc`: early enough that any run ends before i64 nanoseconds do
/// (2262-04-11).
pub const LATEST_START_UTC: &str = "2200-01-01T00:00:00Z";

/// A complete scenario, every field resolved (scenario file over defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Name, used in the run folder name.
    pub name: String,
    /// Free text for the report.
    pub description: String,
    /// Master seed.
    pub seed: u64,
    /// UTC time of the first sample (`YYYY-MM-DDTHH:MM:SSZ`).
    pub start_time_utc: String,
    /// Hard stop, s (0 = until the route is complete).
    pub max_duration_s: f64,
    /// Geodetic origin of the ENU world frame.
    pub origin: Geodetic,
    /// `[world]`.
    pub world: WorldParams,
    /// `[robot]`.
    pub robot: RobotParams,
    /// `[motion]`.
    pub motion: MotionParams,
    /// `[physics]`.
    pub physics: PhysicsParams,
    /// `[route]`.
    pub route: RouteParams,
    /// `[sensors]`.
    pub sensors: SensorsParams,
    /// `[render]`.
    pub render: RenderParams,
    /// `[faults]`.
    pub faults: FaultsParams,
    /// `[estimators]`.
    pub estimators: EstimatorsParams,
    /// `[control]`: what the route follower steers on (closed loop).
    pub control: ControlParams,
    /// `[scoring]`.
    pub scoring: ScoringParams,
    /// `[recording]`.
    pub recording: crate::recording::RecordingParams,
    /// `[mapper]`.
    pub mapper: MappingParams,
    /// `[slam]`: the visual SLAM (an estimate source named `slam`).
    pub slam: vinebench_onboard::slam::SlamConfig,
    /// Expectations, in the expectation language (see [`crate::scoring::expect`]).
    pub expect: Vec<String>,
}

/// A position in a scenario file (1-based line and column).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Location {
    /// Line, from 1.
    pub line: usize,
    /// Column (in characters), from 1.
    pub column: usize,
}

/// A scenario that cannot be used. Every variant names the file; where the problem is a
/// key of the file, its line and column.
#[derive(Debug, Error)]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("{file}: cannot read the scenario: {source}")]
    Io {
        /// The file.
        file: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Not valid TOML.
    #[error("{file}:{}:{}: TOML syntax error: {message}", .at.line, .at.column)]
    Syntax {
        /// The file.
        file: String,
        /// Where.
        at: Location,
        /// The parser's message.
        message: String,
    },
    /// A value set from outside the file ([`LoadedScenario::from_str_with`]: a sweep's
    /// axis or seed) cannot be applied or is wrong.
    #[error("{file}: `{path}` (set by {by}): {message}")]
    Override {
        /// The scenario file.
        file: String,
        /// Dotted path of the key.
        path: String,
        /// Who set it (`sweep.toml axis ...`).
        by: String,
        /// What is wrong and what was expected.
        message: String,
    },
    /// A key has the wrong type or value, or is unknown.
    #[error("{}: `{path}`: {message}", located(.file, .at))]
    Field {
        /// The file.
        file: String,
        /// Where the key is, when the file sets it (absent for a default value).
        at: Option<Location>,
        /// Dotted path of the key.
        path: String,
        /// What is wrong and what was expected.
        message: String,
    },
}

fn located(file: &str, at: &Option<Location>) -> String {
    match at {
        Some(l) => format!("{file}:{}:{}", l.line, l.column),
        None => format!("{file} (value from scenarios/defaults.toml)"),
    }
}

/// A scenario as loaded from a file, with what is needed to point at its keys later.
#[derive(Clone, Debug)]
pub struct LoadedScenario {
    /// The resolved scenario.
    pub scenario: Scenario,
    /// The file it came from (as given), or a name for inline text.
    pub file: String,
    /// The scenario file's directory (relative paths in the scenario are resolved from it).
    pub base_dir: PathBuf,
    /// Time of the first sample.
    pub start: Nanos,
    /// Parsed expectations.
    pub expectations: Vec<Expectation>,
    /// The scenario file's text.
    text: String,
    /// Keys set from outside the file, with who set them (errors name them).
    overrides: Vec<(String, String)>,
}

/// A value for a scenario key from outside the scenario file: a sweep's axis or seed.
#[derive(Clone, Debug, PartialEq)]
pub struct Override {
    /// Dotted key path (`world.occluders[0].size_m`, `faults.gnss[1].end_s`, `seed`).
    pub path: String,
    /// The value, as TOML.
    pub value: toml::Value,
    /// Who sets it, for errors (`sweeps/x.toml: axis "world.occluders[0].s_m" = 4.8`).
    pub by: String,
}

impl LoadedScenario {
    /// Reads and validates a scenario file.
    pub fn load(path: &Path) -> Result<LoadedScenario, ScenarioError> {
        LoadedScenario::load_with(path, &[])
    }

    /// Reads a scenario file with some keys set from outside it (see [`Override`]).
    pub fn load_with(path: &Path, overrides: &[Override]) -> Result<LoadedScenario, ScenarioError> {
        let file = path.display().to_string();
        let text = crate::fsio::read_text_bounded(path, crate::fsio::MAX_SCENARIO_BYTES).map_err(
            |source| ScenarioError::Io {
                file: file.clone(),
                source,
            },
        )?;
        let mut s = LoadedScenario::from_str_with(&text, &file, overrides)?;
        s.base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Ok(s)
    }

    /// Validates scenario text; `file` names it in errors.
    #[allow(clippy::should_implement_trait)]
    pub fn from_str(text: &str, file: &str) -> Result<LoadedScenario, ScenarioError> {
        LoadedScenario::from_str_with(text, file, &[])
    }

    /// Validates scenario text with some keys set from outside it, after the text is
    /// merged over the defaults: a key the resolved scenario does not have, an index past
    /// the end of an array, a value of the wrong type or out of range is an error naming
    /// the override's `by`.
    pub fn from_str_with(
        text: &str,
        file: &str,
        overrides: &[Override],
    ) -> Result<LoadedScenario, ScenarioError> {
        let doc = toml_edit::Document::parse(text).map_err(|e| ScenarioError::Syntax {
            file: file.to_string(),
            at: location_of(text, e.span().map(|s| s.start).unwrap_or(0)),
            message: e.message().trim().to_string(),
        })?;
        let user: toml::Table = toml::from_str(text).map_err(|e| ScenarioError::Syntax {
            file: file.to_string(),
            at: location_of(text, e.span().map(|s| s.start).unwrap_or(0)),
            message: e.message().trim().to_string(),
        })?;
        let mut merged =
            vinebench_msgs::defaults::defaults_table().map_err(|e| ScenarioError::Field {
                file: "scenarios/defaults.toml".into(),
                at: None,
                path: String::new(),
                message: e.to_string(),
            })?;
        merge(&mut merged, user);
        for o in overrides {
            set_path(&mut merged, &o.path, o.value.clone()).map_err(|message| {
                ScenarioError::Override {
                    file: file.to_string(),
                    path: o.path.clone(),
                    by: o.by.clone(),
                    message,
                }
            })?;
        }
        let overridden: Vec<(String, String)> = overrides
            .iter()
            .map(|o| (o.path.clone(), o.by.clone()))
            .collect();
        let scenario: Scenario = serde_path_to_error::deserialize(toml::Value::Table(merged))
            .map_err(|e| {
                let path = e.path().to_string();
                let message = e.inner().message().trim().to_string();
                if let Some(by) = overridden_by(&overridden, &path) {
                    return ScenarioError::Override {
                        file: file.to_string(),
                        path,
                        by,
                        message,
                    };
                }
                let at_key = message.starts_with("unknown field");
                let at = span_of(&doc, &path, at_key).map(|s| location_of(text, s.start));
                ScenarioError::Field {
                    file: file.to_string(),
                    at,
                    path,
                    message,
                }
            })?;
        let mut loaded = LoadedScenario {
            scenario,
            file: file.to_string(),
            base_dir: PathBuf::new(),
            start: Nanos(0),
            expectations: Vec::new(),
            text: text.to_string(),
            overrides: overridden,
        };
        loaded.validate()?;
        Ok(loaded)
    }

    /// The error for a value that fails a check, located at its key.
    pub fn field_error(&self, path: &str, message: impl Into<String>) -> ScenarioError {
        if let Some(by) = overridden_by(&self.overrides, path) {
            return ScenarioError::Override {
                file: self.file.clone(),
                path: path.to_string(),
                by,
                message: message.into(),
            };
        }
        ScenarioError::Field {
            file: self.file.clone(),
            at: self.locate(path),
            path: path.to_string(),
            message: message.into(),
        }
    }

    /// Converts a simulator parameter error into a located scenario error.
    pub fn param_error(&self, e: ParamError) -> ScenarioError {
        self.field_error(
            &e.path,
            format!("expected {}, found {}", e.expected, e.found),
        )
    }

    /// Where a dotted key path (`sensors.gnss.rate_hz`, `faults.gnss[1].end_s`) is set in
    /// the scenario file, if it is.
    pub fn locate(&self, path: &str) -> Option<Location> {
        let doc = toml_edit::Document::parse(self.text.as_str()).ok()?;
        span_of(&doc, path, false).map(|s| location_of(&self.text, s.start))
    }

    /// The scenario resolved over the defaults, as TOML (written to the run folder so a
    /// run can be reproduced from it alone).
    pub fn resolved_toml(&self) -> String {
        toml::to_string(&self.scenario).unwrap_or_else(|e| format!("# cannot serialize: {e}\n"))
    }

    fn validate(&mut self) -> Result<(), ScenarioError> {
        let s = &self.scenario;
        self.start = vinebench_msgs::time::parse_utc(&s.start_time_utc).ok_or_else(|| {
            self.field_error(
                "start_time_utc",
                format!(
                    "expected a UTC time like \"2021-09-15T09:00:00Z\" from 1970-01-01T00:00:00Z \
                     to {LATEST_START_UTC}, found {:?}",
                    s.start_time_utc
                ),
            )
        })?;
        // Stamps are i64 nanoseconds since 1970 (they end in 2262) and MCAP log times are
        // unsigned: a run must start and end inside that range, with room for the longest
        // run (MAX_DURATION_S) and its safety margin.
        let latest = vinebench_msgs::time::parse_utc(LATEST_START_UTC).unwrap_or(Nanos(0));
        if self.start < Nanos(0) || self.start > latest {
            return Err(self.field_error(
                "start_time_utc",
                format!(
                    "expected a UTC time from 1970-01-01T00:00:00Z to {LATEST_START_UTC} \
                     (stamps are nanoseconds since 1970 in 64 bits, which end in 2262), \
                     found {:?}",
                    s.start_time_utc
                ),
            ));
        }
        if !s.origin.is_valid() {
            return Err(self.field_error(
                "origin",
                "expected finite lat_deg in [-90, 90], lon_deg and alt_m",
            ));
        }
        if !(s.max_duration_s.is_finite() && (0.0..=MAX_DURATION_S).contains(&s.max_duration_s)) {
            return Err(self.field_error(
                "max_duration_s",
                format!(
                    "expected seconds from 0 (no limit) to {MAX_DURATION_S} (30 days), found {}",
                    s.max_duration_s
                ),
            ));
        }
        if s.name.is_empty()
            || !s
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        {
            return Err(self.field_error(
                "name",
                format!(
                    "expected a non-empty name of letters, digits, '-', '_' or '.' (it names the run folder), found {:?}",
                    s.name
                ),
            ));
        }
        let c = &s.control;
        if let Some(src) = c.source() {
            let mut sources: Vec<&str> = s.estimators.run.iter().map(|k| k.name()).collect();
            if s.slam.enabled {
                sources.extend(s.slam.runs().iter().map(|(name, _)| *name));
            }
            if !sources.contains(&src) {
                return Err(self.field_error(
                    "control.localization",
                    format!(
                        "\"truth\" or an estimate source of the run ({sources:?}: [estimators] \
                         run, and the SLAM and its baselines when [slam] is enabled), found \
                         {src:?}"
                    ),
                ));
            }
        }
        for (key, v, lo, hi) in [
            (
                "control.estimate_latency_ms",
                c.estimate_latency_ms,
                0.0,
                10_000.0,
            ),
            (
                "control.max_estimate_age_ms",
                c.max_estimate_age_ms,
                1.0,
                3_600_000.0,
            ),
            (
                "control.max_position_sigma_m",
                c.max_position_sigma_m,
                0.0,
                1e6,
            ),
            (
                "control.estimate_offset_m[0]",
                c.estimate_offset_m[0],
                -100.0,
                100.0,
            ),
            (
                "control.estimate_offset_m[1]",
                c.estimate_offset_m[1],
                -100.0,
                100.0,
            ),
        ] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(self.field_error(
                    key,
                    format!("expected a number from {lo} to {hi}, found {v}"),
                ));
            }
        }
        let e = &s.estimators;
        if !(e.reorder_window_ms.is_finite() && e.reorder_window_ms >= 0.0) {
            return Err(self.field_error(
                "estimators.reorder_window_ms",
                format!("expected a number >= 0, found {}", e.reorder_window_ms),
            ));
        }
        for (i, a) in e.run.iter().enumerate() {
            if e.run[..i].contains(a) {
                return Err(self.field_error(
                    &format!("estimators.run[{i}]"),
                    format!("`{}` is listed twice", a.name()),
                ));
            }
        }
        s.scoring.validate().map_err(|e| self.param_error(e))?;
        s.recording.validate().map_err(|e| self.param_error(e))?;
        for (i, f) in s.faults.gnss.iter().enumerate() {
            if !(f.start_s.is_finite()
                && f.end_s.is_finite()
                && f.start_s >= 0.0
                && f.end_s > f.start_s)
            {
                return Err(self.field_error(
                    &format!("faults.gnss[{i}]"),
                    format!(
                        "expected 0 <= start_s < end_s, found start_s = {}, end_s = {}",
                        f.start_s, f.end_s
                    ),
                ));
            }
        }
        if let Err(e) = s.slam.validate() {
            return Err(self.field_error("slam", e.0));
        }
        let mut sources: Vec<&'static str> = e.run.iter().map(|k| k.name()).collect();
        let slam_sources: Vec<&'static str> = if s.slam.enabled {
            s.slam.runs().iter().map(|r| r.0).collect()
        } else {
            Vec::new()
        };
        sources.extend(&slam_sources);
        let mut parsed = Vec::with_capacity(s.expect.len());
        for (i, text) in s.expect.iter().enumerate() {
            match Expectation::parse(text, &sources) {
                Ok(x) => {
                    for r in x.refs() {
                        let slam_metric = crate::scoring::expect::SLAM_METRICS
                            .iter()
                            .any(|(m, _)| *m == r.metric);
                        if slam_metric && !slam_sources.contains(&r.source.as_str()) {
                            return Err(self.field_error(
                                &format!("expect[{i}]"),
                                format!(
                                    "`{}` is a metric of the SLAM's sources ({}), not of `{}`; \
                                     enable [slam] (and its baselines) to use it",
                                    r.metric,
                                    if slam_sources.is_empty() {
                                        "none: [slam] is off".to_string()
                                    } else {
                                        slam_sources.join(", ")
                                    },
                                    r.source
                                ),
                            ));
                        }
                    }
                    parsed.push(x)
                }
                Err(ExpectationError(msg)) => {
                    return Err(self.field_error(&format!("expect[{i}]"), msg));
                }
            }
        }
        self.expectations = parsed;
        Ok(())
    }
}

/// Who set `path` or a key above or below it, if an override did (`faults.gnss[0]` is
/// about the override of `faults.gnss[0].end_s`, and the other way round).
fn overridden_by(overrides: &[(String, String)], path: &str) -> Option<String> {
    let related = |a: &str, b: &str| {
        a == b || (a.starts_with(b) && matches!(a.as_bytes().get(b.len()), Some(b'.' | b'[')))
    };
    overrides
        .iter()
        .find(|(p, _)| related(p, path) || related(path, p))
        .map(|(_, by)| by.clone())
}

/// Sets the value at a dotted key path (`a.b[2].c`) of a resolved scenario table. Every
/// table and array on the way must exist (the resolved scenario has every key of the
/// defaults); the last key may be new only in a table (serde then rejects unknown keys).
fn set_path(root: &mut toml::Table, path: &str, value: toml::Value) -> Result<(), String> {
    let segs = strict_segments(path)?;
    let mut whole = toml::Value::Table(std::mem::take(root));
    let result = set_in(&mut whole, &segs, value);
    if let toml::Value::Table(t) = whole {
        *root = t;
    }
    result
}

/// [`set_path`] on a value: walks every segment but the last, then sets the last.
fn set_in(mut node: &mut toml::Value, segs: &[Seg], value: toml::Value) -> Result<(), String> {
    let Some((last, ancestors)) = segs.split_last() else {
        return Err("expected a key path such as `world.rows.count`".into());
    };
    let mut here = String::new();
    for seg in ancestors {
        node = step(node, seg, &here)?;
        here = join_seg(&here, seg);
    }
    match (last, node) {
        (Seg::Key(k), toml::Value::Table(t)) => {
            t.insert((*k).to_string(), value);
            Ok(())
        }
        (Seg::Index(_), node @ toml::Value::Array(_)) => {
            *step(node, last, &here)? = value;
            Ok(())
        }
        (seg, other) => Err(format!(
            "`{here}` is {}, not {}",
            kind_of(other),
            match seg {
                Seg::Key(_) => "a table",
                Seg::Index(_) => "an array",
            }
        )),
    }
}

/// One step down a key path.
fn step<'a>(
    node: &'a mut toml::Value,
    seg: &Seg,
    here: &str,
) -> Result<&'a mut toml::Value, String> {
    let name = if here.is_empty() {
        "the scenario"
    } else {
        here
    };
    match (seg, node) {
        (Seg::Key(k), toml::Value::Table(t)) => {
            let keys: Vec<String> = t.keys().cloned().collect();
            t.get_mut(*k)
                .ok_or_else(|| format!("{name} has no key `{k}` (it has: {})", keys.join(", ")))
        }
        (Seg::Index(i), toml::Value::Array(a)) => {
            let n = a.len();
            a.get_mut(*i).ok_or_else(|| {
                format!(
                    "`{here}` has {n} entr{}; index {i} is past its end",
                    if n == 1 { "y" } else { "ies" }
                )
            })
        }
        (Seg::Key(_), other) => Err(format!("`{name}` is {}, not a table", kind_of(other))),
        (Seg::Index(_), other) => Err(format!("`{name}` is {}, not an array", kind_of(other))),
    }
}

fn join_seg(here: &str, seg: &Seg) -> String {
    match seg {
        Seg::Key(k) if here.is_empty() => (*k).to_string(),
        Seg::Key(k) => format!("{here}.{k}"),
        Seg::Index(i) => format!("{here}[{i}]"),
    }
}

fn kind_of(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a float",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a date-time",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

/// Splits `a.b[2].c` into keys and indices, rejecting anything else.
fn strict_segments(path: &str) -> Result<Vec<Seg<'_>>, String> {
    let bad = || format!("expected a key path such as `faults.gnss[0].end_s`, found `{path}`");
    let mut out = Vec::new();
    for part in path.split('.') {
        let (name, mut rest) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            return Err(bad());
        }
        out.push(Seg::Key(name));
        while !rest.is_empty() {
            let close = rest.find(']').ok_or_else(bad)?;
            if !rest.starts_with('[') {
                return Err(bad());
            }
            out.push(Seg::Index(rest[1..close].parse().map_err(|_| bad())?));
            rest = &rest[close + 1..];
        }
    }
    Ok(out)
}

/// Merges `over` into `base`: tables key by key (recursively), everything else replaces.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// 1-based line and column of a byte offset.
fn location_of(text: &str, offset: usize) -> Location {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map(|i| i + 1).unwrap_or(0);
    Location {
        line,
        column: text[line_start..offset].chars().count() + 1,
    }
}

/// The span of the deepest element of `path` (`a.b[2].c`) that the document sets: the
/// value for plain keys (the key itself when `at_key`), the key for tables.
fn span_of(doc: &toml_edit::Document<&str>, path: &str, at_key: bool) -> Option<Range<usize>> {
    use toml_edit::{Item, TableLike, Value};
    enum Node<'a> {
        Item(&'a Item),
        Value(&'a Value),
        Table(&'a toml_edit::Table),
    }
    let mut node = Node::Item(doc.as_item());
    let mut best = None;
    for seg in segments(path) {
        node = match (seg, node) {
            (Seg::Key(k), n) => {
                let table: &dyn TableLike = match n {
                    Node::Item(it) => it.as_table_like()?,
                    Node::Value(Value::InlineTable(t)) => t,
                    Node::Table(t) => t,
                    Node::Value(_) => return best,
                };
                let Some((key, next)) = table.get_key_value(k) else {
                    return best;
                };
                best = match next {
                    Item::Value(v) if !at_key => v.span().or_else(|| key.span()),
                    _ => key.span(),
                }
                .or(best);
                Node::Item(next)
            }
            (Seg::Index(i), Node::Item(Item::ArrayOfTables(a))) => {
                let Some(t) = a.get(i) else { return best };
                best = t.span().or(best);
                Node::Table(t)
            }
            (Seg::Index(i), Node::Item(Item::Value(Value::Array(a))))
            | (Seg::Index(i), Node::Value(Value::Array(a))) => {
                let Some(v) = a.get(i) else { return best };
                best = v.span().or(best);
                Node::Value(v)
            }
            (Seg::Index(_), _) => return best,
        };
    }
    best
}

enum Seg<'a> {
    Key(&'a str),
    Index(usize),
}

/// Splits `a.b[2].c` into keys and indices.
fn segments(path: &str) -> Vec<Seg<'_>> {
    let mut out = Vec::new();
    for part in path.split('.').filter(|p| !p.is_empty()) {
        let (name, mut rest) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        if !name.is_empty() {
            out.push(Seg::Key(name));
        }
        while let Some(close) = rest.find(']') {
            if let Ok(i) = rest[1..close].parse::<usize>() {
                out.push(Seg::Index(i));
            }
            rest = &rest[close + 1..];
        }
    }
    out
}

/// `[mapper]` of a scenario (every key documented in `scenarios/defaults.toml`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MappingParams {
    /// Build maps at all.
    pub enabled: bool,
    /// Estimate sources to map with; the first is the main map (mesh and exports).
    pub sources: Vec<vinebench_onboard::estimator::EstimatorKind>,
    /// `[mapper.map]`: how each map is built.
    pub map: vinebench_onboard::mapper::MapperParams,
    /// `[mapper.scoring]`: how each map is scored.
    pub scoring: crate::scoring::map::MapScoreParams,
}

/// `[control]` of a scenario (documented in `scenarios/defaults.toml`; see
/// [`crate::runner::steering`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlParams {
    /// `"truth"` or an estimate source of the run (`[estimators] run`, the SLAM and its
    /// baselines).
    pub localization: String,
    /// Processing time between a message's arrival and the pose it gives, ms.
    pub estimate_latency_ms: f64,
    /// Stop when the newest estimate is older than this, ms.
    pub max_estimate_age_ms: f64,
    /// Stop when the estimate's horizontal position σ exceeds this, m (0 = off).
    pub max_position_sigma_m: f64,
    /// A known error (east, north) added to every steering estimate, m: what a biased
    /// localization (a wrong antenna lever arm, a shifted base station) does to the vines.
    pub estimate_offset_m: [f64; 2],
    /// Stop when the steering source reports tracking lost (a SLAM's lost frame or map
    /// restart).
    pub stop_on_tracking_lost: bool,
}

impl ControlParams {
    /// The steering source (`None` for `"truth"`).
    pub fn source(&self) -> Option<&str> {
        (self.localization != "truth").then_some(self.localization.as_str())
    }
}

impl Default for MappingParams {
    /// The values of `[mapper]` in `scenarios/defaults.toml`.
    fn default() -> Self {
        vinebench_msgs::defaults::section("mapper")
            .expect("the embedded scenarios/defaults.toml is checked by tests")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vinebench_msgs::defaults::DEFAULTS_TOML;

    fn err(text: &str) -> String {
        LoadedScenario::from_str(text, "bad.toml")
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn defaults_alone_are_a_valid_scenario() {
        let s = LoadedScenario::from_str(DEFAULTS_TOML, "scenarios/defaults.toml").unwrap();
        assert_eq!(s.scenario.name, "defaults");
        assert_eq!(s.start, Nanos::from_secs(1_631_696_400));
        // The resolved scenario reloads to itself.
        let again = LoadedScenario::from_str(&s.resolved_toml(), "resolved.toml").unwrap();
        assert_eq!(again.scenario, s.scenario);
    }

    #[test]
    fn scenario_overrides_merge_key_by_key() {
        let s = LoadedScenario::from_str(
            "[sensors.gnss.rtk_float]\nsigma_horizontal_m = 0.5\n[[faults.gnss]]\nstart_s = 1\nend_s = 2\nstatus = \"single\"\n",
            "x.toml",
        )
        .unwrap();
        assert_eq!(s.scenario.sensors.gnss.rtk_float.sigma_horizontal_m, 0.5);
        assert_eq!(s.scenario.sensors.gnss.rtk_float.sigma_vertical_m, 0.45);
        assert_eq!(s.scenario.faults.gnss.len(), 1);
    }

    #[test]
    fn unknown_key_is_located() {
        let e = err("name = \"a\"\n\n[world.rows]\ncount = 3\nspacingg_m = 2.0\n");
        assert!(
            e.starts_with("bad.toml:5:1: `world.rows.spacingg_m`"),
            "{e}"
        );
        assert!(e.contains("unknown field `spacingg_m`"), "{e}");
        assert!(
            e.contains("spacing_m"),
            "should list the expected keys: {e}"
        );
    }

    #[test]
    fn slam_settings_and_metrics_are_checked() {
        let e = err("[slam]\nenabled = true\nmax_camera_offset_s = -1.0\n");
        assert!(
            e.contains("`slam`") && e.contains("max_camera_offset_s"),
            "{e}"
        );
        let e = err("[slam.tracking]\nmin_tracked = 2\n");
        assert!(e.contains("tracking.min_tracked"), "{e}");
        // SLAM metrics only for the SLAM's sources, and only when it runs.
        let e = err("expect = [\"tracking_losses.eif <= 0\"]\n");
        assert!(
            e.contains("`expect[0]`") && e.contains("[slam] is off"),
            "{e}"
        );
        let ok = LoadedScenario::from_str(
            "expect = [\"tracking_losses.slam_single_camera >= 1\", \"ate_rmse_aligned_m.slam < 0.1\"]\n\
             [slam]\nenabled = true\nbaselines = [\"single_camera\"]\n",
            "x.toml",
        )
        .unwrap();
        assert_eq!(ok.expectations.len(), 2);
        let e =
            err("expect = [\"tracking_losses.slam_single_camera >= 1\"]\n[slam]\nenabled = true\n");
        assert!(e.contains("unknown source `slam_single_camera`"), "{e}");
    }

    #[test]
    fn wrong_type_is_located_at_the_value() {
        let e = err("[world.rows]\ncount = \"six\"\n");
        assert!(e.starts_with("bad.toml:2:9: `world.rows.count`"), "{e}");
        assert!(e.contains("invalid type"), "{e}");
    }

    #[test]
    fn bad_enum_value_lists_variants() {
        let e = err("[route]\nkind = \"spiral\"\n");
        assert!(e.starts_with("bad.toml:2:8: `route.kind`"), "{e}");
        assert!(e.contains("row_loop") && e.contains("serpentine"), "{e}");
    }

    #[test]
    fn syntax_error_is_located() {
        let e = err("name = \"a\"\n[world.rows\ncount = 3\n");
        assert!(e.starts_with("bad.toml:2:"), "{e}");
        assert!(e.contains("TOML syntax error"), "{e}");
    }

    #[test]
    fn semantic_errors_are_located() {
        let e = err("start_time_utc = \"yesterday\"\n");
        assert!(e.starts_with("bad.toml:1:18: `start_time_utc`"), "{e}");
        let e = err("[[faults.gnss]]\nstart_s = 5.0\nend_s = 1.0\nstatus = \"no_fix\"\n");
        assert!(
            e.contains("`faults.gnss[0]`") && e.starts_with("bad.toml:1:"),
            "{e}"
        );
        let e = err("expect = [\"ate_rmse_m.eif <= 0.3\", \"ate_rmse_m.ekf <= 0.3\"]\n");
        assert!(e.starts_with("bad.toml:1:36: `expect[1]`"), "{e}");
        assert!(e.contains("ekf"), "{e}");
        let e = err("[estimators]\nrun = [\"eif\", \"eif\"]\n");
        assert!(
            e.contains("`estimators.run[1]`") && e.contains("twice"),
            "{e}"
        );
    }

    #[test]
    fn located_param_errors_point_at_the_key() {
        let s = LoadedScenario::from_str("[route.row_loop]\nrow = 9\n", "r.toml").unwrap();
        let e = s.param_error(ParamError::new("route.row_loop.row", "a row index < 6", 9));
        assert_eq!(
            e.to_string(),
            "r.toml:2:7: `route.row_loop.row`: expected a row index < 6, found 9"
        );
        let e = s.param_error(ParamError::new("world.rows.count", "at least 1", 0));
        assert!(
            e.to_string()
                .starts_with("r.toml (value from scenarios/defaults.toml)")
        );
    }
}
