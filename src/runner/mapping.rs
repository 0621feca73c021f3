//! The mapping stage of a run (`[mapper]`): one [`Mapper`] per estimate source, fed the
//! delivered messages and that source's trajectory *as it grows*, so frames are
//! integrated within a fraction of a second of their arrival and memory grows with the
//! mapped area, not with the run's length. After the run each map is finished (normals,
//! GRVI, elevation, the main map's mesh), scored against the true surfaces of the render
//! geometry ([`crate::scoring::map`]) and exported to `<run>/map/`.
//!
//! The mappers see only what the estimators see (messages, `/tf_static`, estimated
//! trajectories); the scene used for scoring is handed over only after the run.

use crate::scenario::{LoadedScenario, ScenarioError};
use crate::scoring::map::{MapScore, MapScoreParams, score_map};
use serde::Serialize;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;
use vinebench_msgs::{Message, StaticTransforms};
use vinebench_onboard::estimator::{EstimatorKind, EstimatorOutput, EstimatorSet};
use vinebench_onboard::mapper::{
    COLOR_SUFFIX, DEPTH_SUFFIX, FinishTiming, INFO_SUFFIX, Map, Mapper, MapperError, MapperParams,
    MapperStats,
};
use vinebench_sim::render::camera::CameraProfile;
use vinebench_sim::render::shade::Renderer;

/// Whether a scenario has a camera with an aligned depth image (what the mapper needs).
pub fn scenario_has_depth_camera(sc: &LoadedScenario) -> bool {
    sc.scenario.sensors.cameras.iter().any(|c| {
        c.depth
            .unwrap_or(c.profile == CameraProfile::D435Depth && c.right_frame.is_none())
    })
}

/// The map metrics an expectation may use for a mapped source (`map_f_score_2cm.eif`).
pub fn is_map_metric(metric: &str) -> bool {
    MapScore::METRIC_NAMES.contains(&metric)
}

/// One source's mapper while the run goes on.
struct SourceMapper {
    kind: EstimatorKind,
    mapper: Mapper,
}

/// The mappers of a run.
pub struct MappingStage {
    mappers: Vec<SourceMapper>,
    scoring: MapScoreParams,
    busy_s: f64,
}

/// A finished map of one source.
#[derive(Clone, Debug)]
pub struct SourceMap {
    /// The estimate source (`eif`, `gnss`, ...).
    pub source: String,
    /// The map.
    pub map: Map,
    /// Wall-clock seconds of finishing it, step by step (`timing.json`).
    pub timing: FinishTiming,
}

/// What the mapping stage hands to scoring and the run folder.
pub struct MappingOutput {
    /// One map per source of `[mapper] sources`, in that order.
    pub maps: Vec<SourceMap>,
    /// Scoring settings.
    pub scoring: MapScoreParams,
    /// The simulator's render geometry: the true surfaces the maps are scored against
    /// (scoring side only; the mappers never saw it). `None` for a field recording: its
    /// maps are built and exported, not scored.
    pub truth: Option<Arc<Renderer>>,
    /// Wall-clock seconds spent mapping (integration during the run, then finishing);
    /// for `timing.json`, not the report.
    pub wall_s: f64,
    /// Of `wall_s`: integrating frames during the run.
    pub during_run_s: f64,
}

impl std::fmt::Debug for MappingOutput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MappingOutput")
            .field("maps", &self.maps)
            .field("scoring", &self.scoring)
            .field("wall_s", &self.wall_s)
            .finish_non_exhaustive()
    }
}

impl MappingStage {
    /// The mapping stage of a scenario, `None` when `[mapper] enabled = false`. Checks
    /// `[mapper]` (located errors): valid parameters, sources that the estimators run, a
    /// camera with depth, and expectations on map metrics only for mapped sources.
    ///
    /// The depth camera is looked for in the scenario's `[[sensors.cameras]]`, or, when
    /// `recorded_topics` is given (a replay), among those topics (one ending in
    /// [`DEPTH_SUFFIX`]).
    pub fn from_scenario(
        sc: &LoadedScenario,
        static_transforms: &StaticTransforms,
        recorded_topics: Option<&[&str]>,
    ) -> Result<Option<MappingStage>, ScenarioError> {
        let s = &sc.scenario;
        let m = &s.mapper;
        let mapped: Vec<&str> = if m.enabled {
            m.sources.iter().map(|k| k.name()).collect()
        } else {
            Vec::new()
        };
        for (i, x) in sc.expectations.iter().enumerate() {
            for r in x.refs() {
                if is_map_metric(&r.metric) && !mapped.contains(&r.source.as_str()) {
                    return Err(sc.field_error(
                        &format!("expect[{i}]"),
                        format!(
                            "`{r}` needs a map of `{}`: set [mapper] enabled = true and list \
                             it in [mapper] sources (mapped now: {})",
                            r.source,
                            if mapped.is_empty() {
                                "none".to_string()
                            } else {
                                mapped.join(", ")
                            }
                        ),
                    ));
                }
            }
        }
        if !m.enabled {
            return Ok(None);
        }
        if m.sources.is_empty() {
            return Err(sc.field_error("mapper.sources", "expected at least one source"));
        }
        for (i, k) in m.sources.iter().enumerate() {
            if m.sources[..i].contains(k) {
                return Err(sc.field_error(
                    &format!("mapper.sources[{i}]"),
                    format!("`{}` is listed twice", k.name()),
                ));
            }
            if !s.estimators.run.contains(k) {
                return Err(sc.field_error(
                    &format!("mapper.sources[{i}]"),
                    format!(
                        "`{}` is not an estimate source of this run ([estimators] run = {:?})",
                        k.name(),
                        s.estimators
                            .run
                            .iter()
                            .map(|k| k.name())
                            .collect::<Vec<_>>()
                    ),
                ));
            }
        }
        match recorded_topics {
            None if !scenario_has_depth_camera(sc) => {
                return Err(sc.field_error(
                    "mapper.enabled",
                    "true needs a camera with an aligned depth image ([[sensors.cameras]] with \
                     profile \"d435_depth\" or depth = true)",
                ));
            }
            Some(topics) if !topics.iter().any(|t| t.ends_with(DEPTH_SUFFIX)) => {
                return Err(sc.field_error(
                    "mapper.enabled",
                    format!(
                        "true needs aligned depth images: no recorded topic ends in \
                         `{DEPTH_SUFFIX}` (16UC1, with `{COLOR_SUFFIX}` and `{INFO_SUFFIX}` of \
                         the same camera)"
                    ),
                ));
            }
            _ => {}
        }
        if let Err(MapperError::BadParam {
            field,
            expected,
            found,
        }) = m.map.validate()
        {
            return Err(sc.field_error(
                &format!("mapper.map.{field}"),
                format!("expected {expected}, found {found}"),
            ));
        }
        m.scoring.validate().map_err(|e| sc.param_error(e))?;
        let mut mappers = Vec::with_capacity(m.sources.len());
        for (i, &kind) in m.sources.iter().enumerate() {
            // Only the main map is meshed.
            let params = MapperParams {
                mesh: m.map.mesh && i == 0,
                ..m.map.clone()
            };
            let mapper = Mapper::new(params, static_transforms.clone())
                .map_err(|e| sc.field_error("mapper.map", e.to_string()))?;
            mappers.push(SourceMapper { kind, mapper });
        }
        Ok(Some(MappingStage {
            mappers,
            scoring: m.scoring.clone(),
            busy_s: 0.0,
        }))
    }

    /// Takes one delivered message (after the estimators have had it) and integrates the
    /// frames that each source's trajectory now covers.
    pub fn push(&mut self, msg: &Message, estimators: &EstimatorSet) -> Result<(), MapperError> {
        let started = Instant::now();
        for m in &mut self.mappers {
            m.mapper.push(msg);
            if m.mapper.pending_frames() > 0
                && let Some(t) = estimators.trajectory(m.kind)
            {
                m.mapper.integrate(t)?;
            }
        }
        self.busy_s += started.elapsed().as_secs_f64();
        Ok(())
    }

    /// Finishes every map with its source's final trajectory; `truth` is what scoring
    /// compares the maps with (`None`: not scored).
    pub fn finish(
        self,
        estimates: &[EstimatorOutput],
        truth: Option<Arc<Renderer>>,
    ) -> Result<MappingOutput, MapperError> {
        let started = Instant::now();
        let mut maps = Vec::with_capacity(self.mappers.len());
        for m in self.mappers {
            let name = m.kind.name();
            let Some(e) = estimates.iter().find(|e| e.name == name) else {
                continue;
            };
            let (map, timing) = m.mapper.finish_timed(&e.trajectory)?;
            maps.push(SourceMap {
                source: name.to_string(),
                map,
                timing,
            });
        }
        Ok(MappingOutput {
            maps,
            scoring: self.scoring,
            truth,
            wall_s: self.busy_s + started.elapsed().as_secs_f64(),
            during_run_s: self.busy_s,
        })
    }
}

/// One source's map in the report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MapReport {
    /// The estimate source.
    pub source: String,
    /// Where its files are, relative to the run folder.
    pub folder: String,
    /// Counters of the mapper.
    pub stats: MapperStats,
    /// The score against the true surfaces (`None` without them: a field recording).
    pub score: Option<MapScore>,
}

impl MapReport {
    /// The value of a map metric (see [`MapScore::METRIC_NAMES`]).
    pub fn metric(&self, name: &str) -> Option<f64> {
        self.score.as_ref()?.metric(name)
    }
}

/// The folder of a source's map, relative to the run folder: `map` for the main map,
/// `map/<source>` for the others.
pub fn map_folder(index: usize, source: &str) -> String {
    if index == 0 {
        MAP_DIR.to_string()
    } else {
        format!("{MAP_DIR}/{source}")
    }
}

/// The map folder in a run folder.
pub const MAP_DIR: &str = "map";

/// Scores every map against the true surfaces (each map independently; deterministic);
/// without them ([`MappingOutput::truth`] `None`) the reports carry the counters only.
pub fn score(out: &MappingOutput) -> Vec<MapReport> {
    out.maps
        .iter()
        .enumerate()
        .map(|(i, m)| MapReport {
            source: m.source.clone(),
            folder: map_folder(i, &m.source),
            stats: m.map.stats,
            score: out
                .truth
                .as_ref()
                .map(|truth| score_map(&m.map.cloud.positions, &truth.scene().trace, &out.scoring)),
        })
        .collect()
}

/// Writes every map into `run_dir` (see [`map_folder`]): clouds, and for the main map
/// the mesh, Gazebo model and MJCF. Whole or not at all: the maps are written into a
/// temporary folder beside `map/`, which is renamed into place once every file is
/// complete (a full disk leaves no half-written map).
pub fn export(run_dir: &Path, out: &MappingOutput) -> Result<(), MapperError> {
    if out.maps.is_empty() {
        return Ok(());
    }
    let tmp = run_dir.join(format!(".{MAP_DIR}.tmp{}", std::process::id()));
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| MapperError::Io { path, source }
    };
    let _ = std::fs::remove_dir_all(&tmp);
    let written = (|| {
        for (i, m) in out.maps.iter().enumerate() {
            let rel = map_folder(i, &m.source);
            let sub = rel
                .strip_prefix(MAP_DIR)
                .unwrap_or(&rel)
                .trim_start_matches('/');
            m.map.export(&if sub.is_empty() {
                tmp.clone()
            } else {
                tmp.join(sub)
            })?;
        }
        let dest = run_dir.join(MAP_DIR);
        if dest.exists() {
            std::fs::remove_dir_all(&dest).map_err(io(&dest))?;
        }
        std::fs::rename(&tmp, &dest).map_err(io(&dest))
    })();
    if written.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    written
}
