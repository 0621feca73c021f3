//! The mapper of the seed paper's sections 4 and 5: a geo-referenced, coloured point map
//! from RGB-D images and *estimated* poses, vegetation index and elevation per point, a
//! Ball-Pivoting mesh, and exports for Gazebo and MuJoCo.
//!
//! Behind the ground-truth firewall (`tests/firewall.rs`): it sees only messages,
//! static transforms and an estimated [`Trajectory`], so it runs unchanged on a robot's
//! recording.
//!
//! # Pipeline
//!
//! 1. **Pairing** ([`Mapper::push`]): per camera, the colour image
//!    (`/<cam>/color/image_raw`, `rgb8`), the aligned depth
//!    (`/<cam>/aligned_depth_to_color/image_raw`, `16UC1` mm, 0 = none) and the
//!    calibration (`/<cam>/color/camera_info`) of the same stamp make one RGB-D frame.
//!    A camera keeps at most [`MapperParams::max_pending_frames`] incomplete stamps; older
//!    ones are dropped and counted.
//! 2. **Assembly** (eqs. 4-6, [`Mapper::integrate`]): each valid depth pixel inside
//!    `[min_depth_m, max_depth_m]` is back-projected with the undistorted ray of its pixel
//!    (`K`, plumb-bob `D` inverted by Newton's method, [`camera::RayTable`]):
//!    `p_in_cam = z·(x_n, y_n, 1)`; then `p_in_world = world_from_body(t) ·
//!    body_from_cam · p_in_cam`, where `body_from_cam` comes from the static transforms
//!    (the image's `frame_id`) and `world_from_body(t)` is the estimate **interpolated**
//!    at the image stamp (linear in position, slerp in rotation, between the bracketing
//!    samples). Frames outside the trajectory's span are skipped and counted.
//! 3. **Merging** ([`voxel::VoxelGrid`]): the three cameras' points go into one
//!    incremental voxel grid (default 1 cm): running sums per voxel, so memory grows with
//!    the mapped area, not with the number of frames. The map holds the centroid and
//!    mean colour of each voxel with at least [`MapperParams::min_points_per_voxel`]
//!    points; sparser voxels that no frame touched for [`MapperParams::prune_after_s`]
//!    are dropped during the run (depth noise scatters single points over many voxels).
//! 4. **Attributes** ([`Mapper::finish`]): GRVI = (G − R)/(G + R) of the mean sRGB
//!    colour, vegetation where GRVI > [`MapperParams::grvi_threshold`]; elevation = height
//!    above the local ground, where the ground of a `ground_cell_m` × `ground_cell_m` xy
//!    cell is the `ground_percentile` quantile of the map's z in that cell, lowered to the
//!    smallest such value of its 3 × 3 neighbourhood (so cells seen only through canopy
//!    take the ground of their neighbours); normals from the
//!    [`MapperParams::normal_neighbours`] nearest neighbours (PCA; a grid search that
//!    answers as kiddo's k-d tree, [`normals`]), oriented towards the camera centre that
//!    last saw each voxel.
//! 5. **Meshing** (section 5): Poisson-disk subsampling ([`poisson`], beside the normals:
//!    it needs only the positions), Ball-Pivoting with a list of radii ([`bpa`]) in square
//!    xy tiles of [`MapperParams::mesh_tile_m`] meshed in parallel
//!    ([`bpa::ball_pivoting_tiled`]), vertex colours from the cloud. The mesh can be
//!    loaded back as the world the simulator's cameras see (`[world.mesh]`).
//! 6. **Export** ([`Map::export`]): `map.ply` (binary: x y z, colour, normals, GRVI,
//!    elevation), `map_grvi.ply` and `map_elevation.ply` (the same points coloured as the
//!    paper's Figure 15 b and c), `mesh.ply`, `mesh.obj`, a Gazebo model folder and an
//!    MJCF file.
//!
//! ```
//! use vinebench_onboard::mapper::{Mapper, MapperParams};
//! use vinebench_msgs::{StaticTransforms, Trajectory};
//! let mapper = Mapper::new(MapperParams::default(), StaticTransforms::new("base_link"))
//!     .expect("valid parameters");
//! let map = mapper.finish(&Trajectory::new()).expect("an empty map");
//! assert!(map.cloud.positions.is_empty());
//! ```

pub mod bpa;
pub mod camera;
pub mod export;
pub mod grid;
pub mod normals;
pub mod ply;
pub mod poisson;
pub mod voxel;
pub mod voxel_table;

/// Test inputs: xorshift64 (Marsaglia), and a uniform number in [0, 1) from it.
#[cfg(test)]
pub(crate) mod test_rng {
    /// The next state of xorshift64 (`state` must not be 0).
    pub fn next_u64(state: &mut u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state
    }

    /// A uniform `f64` in [0, 1) from the top 53 bits of the next state.
    pub fn next_unit(state: &mut u64) -> f64 {
        (next_u64(state) >> 11) as f64 / (1u64 << 53) as f64
    }
}

use camera::RayTable;
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use thiserror::Error;
use vinebench_msgs::{
    CameraInfoMsg, ImageEncoding, ImageMsg, Message, Nanos, StaticTransforms, Trajectory,
};
use voxel::VoxelGrid;

/// Topic suffix of a colour image.
pub const COLOR_SUFFIX: &str = "/color/image_raw";
/// Topic suffix of a depth image aligned to the colour camera.
pub const DEPTH_SUFFIX: &str = "/aligned_depth_to_color/image_raw";
/// Topic suffix of the colour camera's calibration.
pub const INFO_SUFFIX: &str = "/color/camera_info";

/// Mapper settings (SI units); `[mapper.map]` of a scenario, documented with their
/// defaults in `scenarios/defaults.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapperParams {
    /// Voxel edge of the merged map, m (paper: 0.01).
    pub voxel_m: f64,
    /// Points a voxel needs to be in the map (1 keeps every occupied voxel).
    pub min_points_per_voxel: u32,
    /// A voxel with fewer than `min_points_per_voxel` points that no frame of the last
    /// `prune_after_s` (s, message time) touched is dropped while the run goes on.
    pub prune_after_s: f64,
    /// Nearest depth used, m.
    pub min_depth_m: f64,
    /// Farthest depth used, m (the D435's error grows with z²).
    pub max_depth_m: f64,
    /// GRVI above which a point counts as vegetation.
    pub grvi_threshold: f64,
    /// xy cell of the ground estimate, m.
    pub ground_cell_m: f64,
    /// Quantile of z taken as the ground of a cell (0..1).
    pub ground_percentile: f64,
    /// Neighbours of the PCA normals (paper: 10).
    pub normal_neighbours: usize,
    /// Whether [`Mapper::finish`] builds the mesh.
    pub mesh: bool,
    /// Minimum distance of the Poisson-disk subsampling before meshing, m.
    pub poisson_radius_m: f64,
    /// Ball-Pivoting radii, m, ascending.
    pub ball_radii_m: Vec<f64>,
    /// Edge of the square xy tiles the mesh is built in, m ([`bpa::ball_pivoting_tiled`]).
    pub mesh_tile_m: f64,
    /// Incomplete stamps (colour, depth or calibration missing) kept per camera.
    pub max_pending_frames: usize,
    /// A complete frame that the trajectory has not reached while frames this much newer
    /// (s, message time) are waiting is dropped and counted
    /// ([`MapperStats::frames_unposed`]), so an estimate that stops does not make frames
    /// pile up.
    pub max_pose_wait_s: f64,
}

impl Default for MapperParams {
    /// The values of `[mapper.map]` in `scenarios/defaults.toml` (the seed paper's 1 cm
    /// voxels and 10-neighbour normals, Ball-Pivoting radii of 1, 2 and 4 cm).
    fn default() -> Self {
        vinebench_msgs::defaults::section("mapper.map")
            .expect("the embedded scenarios/defaults.toml is checked by tests")
    }
}

impl MapperParams {
    /// Checks every value; the first problem names its field.
    pub fn validate(&self) -> Result<(), MapperError> {
        let bad = |field: &'static str, expected: &'static str, found: String| {
            Err(MapperError::BadParam {
                field,
                expected,
                found,
            })
        };
        if !(self.voxel_m >= 1e-4 && self.voxel_m <= 10.0) {
            return bad("voxel_m", "in 1e-4..=10 m", self.voxel_m.to_string());
        }
        if !(self.min_depth_m >= 0.0 && self.min_depth_m < self.max_depth_m) {
            return bad(
                "min_depth_m",
                "non-negative and below max_depth_m",
                self.min_depth_m.to_string(),
            );
        }
        if !(self.max_depth_m.is_finite() && self.max_depth_m <= 65.535) {
            return bad(
                "max_depth_m",
                "finite, at most 65.535 m (16-bit mm)",
                self.max_depth_m.to_string(),
            );
        }
        if !(self.grvi_threshold > -1.0 && self.grvi_threshold < 1.0) {
            return bad(
                "grvi_threshold",
                "in (-1, 1)",
                self.grvi_threshold.to_string(),
            );
        }
        if !(self.ground_cell_m >= 0.01 && self.ground_cell_m <= 100.0) {
            return bad(
                "ground_cell_m",
                "in 0.01..=100 m",
                self.ground_cell_m.to_string(),
            );
        }
        if !(0.0..=1.0).contains(&self.ground_percentile) {
            return bad(
                "ground_percentile",
                "in 0..=1",
                self.ground_percentile.to_string(),
            );
        }
        if !(3..=100).contains(&self.normal_neighbours) {
            return bad(
                "normal_neighbours",
                "in 3..=100",
                self.normal_neighbours.to_string(),
            );
        }
        if !(self.poisson_radius_m > 0.0 && self.poisson_radius_m.is_finite()) {
            return bad(
                "poisson_radius_m",
                "positive and finite",
                self.poisson_radius_m.to_string(),
            );
        }
        if !(self.mesh_tile_m >= 0.1 && self.mesh_tile_m.is_finite()) {
            return bad(
                "mesh_tile_m",
                "finite, at least 0.1 m",
                self.mesh_tile_m.to_string(),
            );
        }
        if self.ball_radii_m.is_empty()
            || self
                .ball_radii_m
                .iter()
                .any(|r| !(*r > self.poisson_radius_m * 0.5 && r.is_finite()))
        {
            return bad(
                "ball_radii_m",
                "a non-empty list of finite radii above poisson_radius_m / 2",
                format!("{:?}", self.ball_radii_m),
            );
        }
        if self.min_points_per_voxel == 0 {
            return bad("min_points_per_voxel", "at least 1", "0".to_string());
        }
        if !(self.prune_after_s > 0.0 && self.prune_after_s.is_finite()) {
            return bad(
                "prune_after_s",
                "positive and finite",
                self.prune_after_s.to_string(),
            );
        }
        if self.max_pending_frames == 0 {
            return bad("max_pending_frames", "at least 1", "0".to_string());
        }
        if !(self.max_pose_wait_s > 0.0 && self.max_pose_wait_s.is_finite()) {
            return bad(
                "max_pose_wait_s",
                "positive and finite",
                self.max_pose_wait_s.to_string(),
            );
        }
        Ok(())
    }
}

/// What can go wrong in the mapper.
#[derive(Debug, Error)]
pub enum MapperError {
    /// A parameter out of range.
    #[error("mapper parameter `{field}` must be {expected}, got {found}")]
    BadParam {
        /// The field.
        field: &'static str,
        /// What it must be.
        expected: &'static str,
        /// What it is.
        found: String,
    },
    /// A `CameraInfo` that is not a pinhole/plumb-bob calibration.
    #[error("{topic}: CameraInfo field `{field}` must be {expected}")]
    BadCalibration {
        /// The calibration's topic.
        topic: String,
        /// The field.
        field: &'static str,
        /// What it must be.
        expected: &'static str,
    },
    /// An image that does not fit its calibration or encoding.
    #[error("{topic} at {stamp}: field `{field}` must be {expected}, got {found}")]
    BadImage {
        /// The image's topic.
        topic: String,
        /// Its stamp.
        stamp: Nanos,
        /// The field.
        field: &'static str,
        /// What it must be.
        expected: String,
        /// What it is.
        found: String,
    },
    /// A camera frame the static transforms do not know.
    #[error("{topic}: frame `{frame}` is not in the static transforms (`/tf_static`)")]
    UnknownFrame {
        /// The image's topic.
        topic: String,
        /// Its `frame_id`.
        frame: String,
    },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A Wavefront OBJ file the reader cannot parse.
    #[error("{path}: not a readable OBJ mesh: {problem}")]
    Obj {
        /// The file.
        path: PathBuf,
        /// What the parser reported.
        problem: String,
    },
    /// A PLY file that is not what the reader expects.
    #[error("{path}: `{field}`: expected {expected}, found {found}")]
    Ply {
        /// The file.
        path: PathBuf,
        /// The header line or element/property.
        field: String,
        /// What was expected.
        expected: String,
        /// What was found.
        found: String,
    },
}

/// A coloured point cloud with per-point attributes, parallel arrays (world frame).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Positions, m.
    pub positions: Vec<[f32; 3]>,
    /// sRGB colours.
    pub colors: Vec<[u8; 3]>,
    /// Unit normals (empty when not computed).
    pub normals: Vec<[f32; 3]>,
    /// Green-red vegetation index (G − R)/(G + R) of the colour (empty when not computed).
    pub grvi: Vec<f32>,
    /// Height above the local ground, m (empty when not computed).
    pub elevation: Vec<f32>,
}

/// A triangle mesh with vertex normals and colours (world frame).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriangleMesh {
    /// Vertex positions, m.
    pub vertices: Vec<[f32; 3]>,
    /// Unit vertex normals (may be empty).
    pub normals: Vec<[f32; 3]>,
    /// sRGB vertex colours (may be empty).
    pub colors: Vec<[u8; 3]>,
    /// Counter-clockwise triangles (seen from the normals' side).
    pub triangles: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// Total triangle area, m².
    pub fn area_m2(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let p = t.map(|i| {
                    let v = self.vertices[i as usize];
                    nalgebra::Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))
                });
                0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm()
            })
            .sum()
    }
}

/// Counters of a mapping run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MapperStats {
    /// RGB-D frames assembled into the map.
    pub frames_integrated: u64,
    /// Complete frames whose stamp the trajectory does not cover (skipped).
    pub frames_outside_trajectory: u64,
    /// Stamps dropped because colour, depth or calibration never came.
    pub frames_incomplete: u64,
    /// Complete frames dropped because the trajectory did not reach them within
    /// [`MapperParams::max_pose_wait_s`].
    pub frames_unposed: u64,
    /// Depth pixels back-projected into the map.
    pub points_integrated: u64,
    /// Depth pixels without a measurement or outside the depth range.
    pub pixels_invalid: u64,
    /// Occupied voxels (map points).
    pub voxels: u64,
    /// Voxels left out with fewer than [`MapperParams::min_points_per_voxel`] points
    /// (during the run and at the end).
    pub voxels_sparse: u64,
    /// Map points with GRVI above the threshold.
    pub vegetation_points: u64,
    /// Points of the Poisson-disk subsample.
    pub mesh_samples: u64,
    /// Mesh triangles.
    pub mesh_triangles: u64,
    /// Mesh edges that belong to one triangle only (the mesh's boundary).
    pub mesh_boundary_edges: u64,
}

/// The back-projected points of one image row: world positions, colours, and the count
/// of invalid pixels.
type RowPoints = (Vec<[f64; 3]>, Vec<[u8; 3]>, u64);

/// One colour image, its aligned depth and its calibration, of one stamp and camera.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbdFrame {
    /// Camera name (topic prefix, e.g. `camera_center`).
    pub camera: String,
    /// `rgb8` image.
    pub color: ImageMsg,
    /// `16UC1` depth in mm aligned to `color`.
    pub depth: ImageMsg,
    /// Calibration of `color`.
    pub info: CameraInfoMsg,
}

impl RgbdFrame {
    /// The exposure stamp.
    pub fn stamp(&self) -> Nanos {
        self.color.stamp
    }
}

#[derive(Default)]
struct Partial {
    color: Option<ImageMsg>,
    depth: Option<ImageMsg>,
    info: Option<CameraInfoMsg>,
}

/// The incremental mapper: feed it messages ([`Mapper::push`]) and estimated poses
/// ([`Mapper::integrate`]), then [`Mapper::finish`] for the [`Map`].
pub struct Mapper {
    params: MapperParams,
    tf: StaticTransforms,
    partial: BTreeMap<String, BTreeMap<Nanos, Partial>>,
    ready: BTreeMap<(Nanos, String), RgbdFrame>,
    rays: BTreeMap<String, RayTable>,
    grid: VoxelGrid,
    /// Stamp of every frame inserted into the grid (its batch index).
    batch_stamps: Vec<Nanos>,
    /// Stamp of the newest frame when the grid was last pruned.
    pruned_at: Option<Nanos>,
    stats: MapperStats,
    points: Vec<[f64; 3]>,
    colors: Vec<[u8; 3]>,
}

/// The camera name and kind of a topic the mapper consumes.
fn classify(topic: &str) -> Option<(&str, u8)> {
    for (kind, suffix) in [COLOR_SUFFIX, DEPTH_SUFFIX, INFO_SUFFIX].iter().enumerate() {
        if let Some(cam) = topic.strip_suffix(suffix) {
            return Some((cam.trim_start_matches('/'), kind as u8));
        }
    }
    None
}

impl Mapper {
    /// A mapper with `params` and the robot's static transforms (camera extrinsics).
    pub fn new(
        params: MapperParams,
        static_transforms: StaticTransforms,
    ) -> Result<Mapper, MapperError> {
        params.validate()?;
        Ok(Mapper {
            grid: VoxelGrid::new(params.voxel_m),
            batch_stamps: Vec::new(),
            pruned_at: None,
            params,
            tf: static_transforms,
            partial: BTreeMap::new(),
            ready: BTreeMap::new(),
            rays: BTreeMap::new(),
            stats: MapperStats::default(),
            points: Vec::new(),
            colors: Vec::new(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &MapperParams {
        &self.params
    }

    /// Counters so far.
    pub fn stats(&self) -> MapperStats {
        let mut s = self.stats;
        s.voxels = self.grid.len() as u64;
        s
    }

    /// Complete RGB-D frames waiting for a pose.
    pub fn pending_frames(&self) -> usize {
        self.ready.len()
    }

    /// Occupied voxels so far.
    pub fn voxel_count(&self) -> usize {
        self.grid.len()
    }

    /// Takes one message: colour, aligned depth and colour `camera_info` are paired by
    /// camera and stamp; every other message is ignored. Cheap: images are shared, not
    /// copied.
    pub fn push(&mut self, msg: &Message) {
        let (topic, stamp) = match msg {
            Message::Image(m) => (&*m.topic, m.stamp),
            Message::CameraInfo(m) => (&*m.topic, m.stamp),
            _ => return,
        };
        let Some((cam, kind)) = classify(topic) else {
            return;
        };
        let cam_map = self.partial.entry(cam.to_string()).or_default();
        let p = cam_map.entry(stamp).or_default();
        match (kind, msg) {
            (0, Message::Image(m)) => p.color = Some(m.clone()),
            (1, Message::Image(m)) => p.depth = Some(m.clone()),
            (2, Message::CameraInfo(m)) => p.info = Some(m.clone()),
            _ => return,
        }
        if p.color.is_some() && p.depth.is_some() && p.info.is_some() {
            if let Some(Partial {
                color: Some(color),
                depth: Some(depth),
                info: Some(info),
            }) = cam_map.remove(&stamp)
            {
                self.ready.insert(
                    (stamp, cam.to_string()),
                    RgbdFrame {
                        camera: cam.to_string(),
                        color,
                        depth,
                        info,
                    },
                );
            }
        }
        while cam_map.len() > self.params.max_pending_frames {
            cam_map.pop_first();
            self.stats.frames_incomplete += 1;
        }
    }

    /// Assembles every complete frame whose stamp `trajectory` covers into the map, in
    /// stamp order; frames before its first pose are skipped (counted), frames after its
    /// last pose wait for a longer trajectory. Returns the number of frames integrated.
    /// Call it as the estimate grows to keep memory bounded.
    pub fn integrate(&mut self, trajectory: &Trajectory) -> Result<usize, MapperError> {
        let (Some(first), Some(last)) = (trajectory.samples.first(), trajectory.samples.last())
        else {
            return Ok(0);
        };
        let (t0, t1) = (first.stamp, last.stamp);
        let mut n = 0;
        while let Some(entry) = self.ready.first_entry() {
            let stamp = entry.key().0;
            if stamp > t1 {
                break;
            }
            let frame = entry.remove();
            if stamp < t0 {
                self.stats.frames_outside_trajectory += 1;
                continue;
            }
            match trajectory.interpolate(stamp) {
                Some(world_from_body) => {
                    self.add_frame(&frame, &world_from_body)?;
                    n += 1;
                }
                None => self.stats.frames_outside_trajectory += 1,
            }
        }
        // Frames the trajectory has not reached: drop those far older than the newest.
        if let Some(newest) = self.ready.last_key_value().map(|(k, _)| k.0) {
            let limit = newest - Nanos::from_secs_f64(self.params.max_pose_wait_s);
            while self
                .ready
                .first_key_value()
                .is_some_and(|(k, _)| k.0 < limit)
            {
                self.ready.pop_first();
                self.stats.frames_unposed += 1;
            }
        }
        Ok(n)
    }

    /// Assembles one RGB-D frame seen with the body at `world_from_body` (eqs. 4-6).
    pub fn add_frame(
        &mut self,
        frame: &RgbdFrame,
        world_from_body: &Isometry3<f64>,
    ) -> Result<(), MapperError> {
        let (color, depth, info) = (&frame.color, &frame.depth, &frame.info);
        let bad = |m: &ImageMsg, field: &'static str, expected: String, found: String| {
            MapperError::BadImage {
                topic: m.topic.to_string(),
                stamp: m.stamp,
                field,
                expected,
                found,
            }
        };
        let (w, h) = (info.width, info.height);
        for (m, enc) in [
            (color, ImageEncoding::Rgb8),
            (depth, ImageEncoding::Depth16Mm),
        ] {
            if m.encoding != enc {
                return Err(bad(
                    m,
                    "encoding",
                    enc.ros_name().into(),
                    m.encoding.ros_name().into(),
                ));
            }
            if (m.width, m.height) != (w, h) {
                return Err(bad(
                    m,
                    "width, height",
                    format!("{w}×{h} as its camera_info"),
                    format!("{}×{}", m.width, m.height),
                ));
            }
            let expected = w as usize * h as usize * enc.bytes_per_pixel();
            if m.data.len() != expected {
                return Err(bad(
                    m,
                    "data",
                    format!("{expected} bytes"),
                    format!("{} bytes", m.data.len()),
                ));
            }
        }
        let body_from_cam = self.tf.body_from(depth.frame_id.as_str()).ok_or_else(|| {
            MapperError::UnknownFrame {
                topic: depth.topic.to_string(),
                frame: depth.frame_id.to_string(),
            }
        })?;
        if !self
            .rays
            .get(&frame.camera)
            .is_some_and(|r| r.matches(info))
        {
            self.rays
                .insert(frame.camera.clone(), RayTable::from_camera_info(info)?);
        }
        let Some(rays) = self.rays.get(&frame.camera) else {
            return Ok(());
        };
        let world_from_cam = world_from_body * body_from_cam;
        let rot = world_from_cam.rotation.to_rotation_matrix().into_inner();
        let t = world_from_cam.translation.vector;
        let (zmin, zmax) = (self.params.min_depth_m, self.params.max_depth_m);
        let w = w as usize;
        let rows: Vec<RowPoints> = (0..h as usize)
            .into_par_iter()
            .map(|v| {
                let mut pts = Vec::with_capacity(w);
                let mut cols = Vec::with_capacity(w);
                let mut invalid = 0u64;
                for u in 0..w {
                    let i = v * w + u;
                    let mm = u16::from_le_bytes([depth.data[2 * i], depth.data[2 * i + 1]]);
                    let z = f64::from(mm) * 1e-3;
                    let (x, y) = (f64::from(rays.x[i]), f64::from(rays.y[i]));
                    if mm == 0 || z < zmin || z > zmax || !x.is_finite() || !y.is_finite() {
                        invalid += 1;
                        continue;
                    }
                    let p_in_world = rot * nalgebra::Vector3::new(x * z, y * z, z) + t;
                    pts.push([p_in_world.x, p_in_world.y, p_in_world.z]);
                    cols.push([
                        color.data[3 * i],
                        color.data[3 * i + 1],
                        color.data[3 * i + 2],
                    ]);
                }
                (pts, cols, invalid)
            })
            .collect();
        self.points.clear();
        self.colors.clear();
        for (p, c, inv) in rows {
            self.points.extend_from_slice(&p);
            self.colors.extend_from_slice(&c);
            self.stats.pixels_invalid += inv;
        }
        let eye = Point3::from(t);
        self.grid.insert(
            &self.points,
            &self.colors,
            [eye.x as f32, eye.y as f32, eye.z as f32],
        );
        self.batch_stamps.push(depth.stamp);
        self.stats.points_integrated += self.points.len() as u64;
        self.stats.frames_integrated += 1;
        self.prune(depth.stamp);
        Ok(())
    }

    /// Drops the sparse voxels that no frame of the last `prune_after_s` touched, at most
    /// every quarter of that (message time, so the result does not depend on speed).
    fn prune(&mut self, newest: Nanos) {
        if self.params.min_points_per_voxel <= 1 {
            return;
        }
        let after = Nanos::from_secs_f64(self.params.prune_after_s);
        let every = Nanos::from_secs_f64(self.params.prune_after_s / 4.0);
        if self.pruned_at.is_some_and(|t| newest < t + every) {
            return;
        }
        self.pruned_at = Some(newest);
        let horizon = newest - after;
        // Frames come in stamp order (within the estimators' re-ordering window).
        let before = self.batch_stamps.partition_point(|t| *t < horizon) as u32;
        if before > 0 {
            let n = self.grid.prune(self.params.min_points_per_voxel, before);
            self.stats.voxels_sparse += n as u64;
        }
    }

    /// Integrates what `trajectory` covers, skips the rest (counted), and builds the
    /// map: attributes, normals and (if enabled) the mesh.
    pub fn finish(self, trajectory: &Trajectory) -> Result<Map, MapperError> {
        self.finish_timed(trajectory).map(|(map, _)| map)
    }

    /// As [`Mapper::finish`], with the wall-clock time of each step (for timing files,
    /// never for reports: it varies from run to run).
    pub fn finish_timed(
        mut self,
        trajectory: &Trajectory,
    ) -> Result<(Map, FinishTiming), MapperError> {
        let mut timing = FinishTiming::default();
        let mut clock = std::time::Instant::now();
        let mut lap = |slot: &mut f64| {
            *slot = clock.elapsed().as_secs_f64();
            clock = std::time::Instant::now();
        };
        self.integrate(trajectory)?;
        lap(&mut timing.integrate_s);
        self.stats.frames_outside_trajectory += self.ready.len() as u64;
        self.stats.frames_incomplete += self.partial.values().map(|m| m.len() as u64).sum::<u64>();
        let mut stats = self.stats;
        let params = self.params;
        let occupied = self.grid.len() as u64;
        let voxel::VoxelPoints {
            centroids: positions,
            colors,
            viewpoints,
        } = self.grid.into_points(params.min_points_per_voxel);
        stats.voxels_sparse += occupied - positions.len() as u64;
        lap(&mut timing.points_s);
        let grvi: Vec<f32> = colors.iter().map(|c| grvi_of(*c)).collect();
        let elevation = elevation(&positions, params.ground_cell_m, params.ground_percentile);
        lap(&mut timing.attributes_s);
        // The mesh's Poisson-disk sample needs only the positions, and it is one greedy
        // pass (serial): it runs beside the normals, which take the other threads.
        let (normals, keep) = rayon::join(
            || {
                normals::estimate_normals(
                    &positions,
                    &viewpoints,
                    params.normal_neighbours,
                    2.0 * params.voxel_m,
                )
            },
            || {
                params
                    .mesh
                    .then(|| poisson::poisson_disk(&positions, params.poisson_radius_m))
            },
        );
        voxel::release_freed_memory();
        lap(&mut timing.normals_s);
        stats.voxels = positions.len() as u64;
        stats.vegetation_points = grvi
            .iter()
            .filter(|g| f64::from(**g) > params.grvi_threshold)
            .count() as u64;
        let cloud = PointCloud {
            positions,
            colors,
            normals,
            grvi,
            elevation,
        };
        let mesh = if let Some(keep) = keep {
            let (mesh, samples, boundary) = mesh_cloud(&cloud, keep, &params);
            stats.mesh_samples = samples as u64;
            stats.mesh_triangles = mesh.triangles.len() as u64;
            stats.mesh_boundary_edges = boundary as u64;
            Some(mesh)
        } else {
            None
        };
        lap(&mut timing.mesh_s);
        let map = Map {
            cloud,
            viewpoints,
            mesh,
            stats,
            grvi_threshold: params.grvi_threshold as f32,
        };
        Ok((map, timing))
    }
}

/// (G − R)/(G + R) of an sRGB colour, 0 for black.
pub fn grvi_of(c: [u8; 3]) -> f32 {
    let (r, g) = (f32::from(c[0]), f32::from(c[1]));
    if r + g > 0.0 { (g - r) / (g + r) } else { 0.0 }
}

/// Height of each point (`f64` or `f32`) above the local ground (see the
/// [module docs](self)).
pub fn elevation<T: Copy + Into<f64> + Sync>(
    points: &[[T; 3]],
    cell_m: f64,
    percentile: f64,
) -> Vec<f32> {
    let cell = |p: &[T; 3]| {
        (
            (p[0].into() / cell_m).floor() as i64,
            (p[1].into() / cell_m).floor() as i64,
        )
    };
    // Each cell's heights in a hash map (the order within a cell does not matter: they
    // are sorted by a total order), and each cell's ground computed once.
    let mut zs: FxHashMap<(i64, i64), Vec<f64>> = FxHashMap::default();
    for p in points {
        zs.entry(cell(p)).or_default().push(p[2].into());
    }
    let quantile: FxHashMap<(i64, i64), f64> = zs
        .into_par_iter()
        .map(|(k, mut v)| {
            v.sort_by(f64::total_cmp);
            let i = ((v.len() - 1) as f64 * percentile).round() as usize;
            (k, v[i.min(v.len() - 1)])
        })
        .collect();
    let ground: FxHashMap<(i64, i64), f64> = quantile
        .keys()
        .map(|&c| {
            let mut g = f64::INFINITY;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    if let Some(z) = quantile.get(&(c.0 + dx, c.1 + dy)) {
                        g = g.min(*z);
                    }
                }
            }
            (c, g)
        })
        .collect();
    points
        .par_iter()
        .map(|p| (p[2].into() - ground.get(&cell(p)).copied().unwrap_or(f64::INFINITY)) as f32)
        .collect()
}

/// Ball-Pivoting in tiles over the Poisson-disk subsample `keep` (indices into the
/// cloud), vertex colours and normals from the cloud; unreferenced samples are left out
/// of the mesh. Returns the mesh, the sample count and the boundary edge count.
fn mesh_cloud(
    cloud: &PointCloud,
    keep: Vec<u32>,
    params: &MapperParams,
) -> (TriangleMesh, usize, usize) {
    let pts: Vec<[f32; 3]> = keep.iter().map(|&i| cloud.positions[i as usize]).collect();
    let nrm: Vec<[f32; 3]> = keep.iter().map(|&i| cloud.normals[i as usize]).collect();
    let mut triangles =
        bpa::ball_pivoting_tiled(&pts, &nrm, &params.ball_radii_m, params.mesh_tile_m);
    drop((pts, nrm));
    // Vertices in the order the triangles first use them, indices rewritten in place.
    let mut remap = vec![u32::MAX; keep.len()];
    let mut used = 0u32;
    for t in &mut triangles {
        *t = t.map(|i| {
            let slot = &mut remap[i as usize];
            if *slot == u32::MAX {
                *slot = used;
                used += 1;
            }
            *slot
        });
    }
    let mut mesh = TriangleMesh {
        vertices: vec![[0.0; 3]; used as usize],
        normals: vec![[0.0; 3]; used as usize],
        colors: vec![[0; 3]; used as usize],
        triangles,
    };
    for (&slot, &src) in remap.iter().zip(&keep) {
        if slot != u32::MAX {
            let (slot, src) = (slot as usize, src as usize);
            mesh.vertices[slot] = cloud.positions[src];
            mesh.normals[slot] = cloud.normals[src];
            mesh.colors[slot] = cloud.colors[src];
        }
    }
    let samples = keep.len();
    drop((remap, keep));
    voxel::release_freed_memory();
    let boundary = bpa::boundary_edges(&mesh.triangles);
    voxel::release_freed_memory();
    (mesh, samples, boundary)
}

/// Wall-clock seconds of the steps of [`Mapper::finish_timed`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FinishTiming {
    /// Integrating the frames the trajectory had not covered yet.
    pub integrate_s: f64,
    /// Voxels to points (centroids, colours, viewpoints; sparse voxels left out).
    pub points_s: f64,
    /// GRVI and elevation.
    pub attributes_s: f64,
    /// Normals (k nearest neighbours, oriented to the viewpoints), with the mesh's
    /// Poisson-disk sampling beside them on another thread.
    pub normals_s: f64,
    /// Ball-Pivoting meshing (0 without a mesh).
    pub mesh_s: f64,
}

/// The finished map.
#[derive(Clone, Debug, PartialEq)]
pub struct Map {
    /// One point per occupied voxel: centroid, mean colour, normal, GRVI, elevation.
    pub cloud: PointCloud,
    /// Per point: the camera centre that last saw it (world frame).
    pub viewpoints: Vec<[f32; 3]>,
    /// The Ball-Pivoting mesh, when meshing was enabled.
    pub mesh: Option<TriangleMesh>,
    /// Counters.
    pub stats: MapperStats,
    /// GRVI threshold of the vegetation mask.
    pub grvi_threshold: f32,
}

/// The top of the elevation colour scale: the element at the 99th percentile of
/// `elevation`'s sorted order (`total_cmp`), at least 1 mm; 1 m for an empty map. A
/// selection finds it, not a sort: elements equal under `total_cmp` have the same bits.
fn elevation_scale(elevation: &[f32]) -> f32 {
    let mut e = elevation.to_vec();
    let at = ((e.len() as f64) * 0.99) as usize;
    let top = if at < e.len() {
        *e.select_nth_unstable_by(at, f32::total_cmp).1
    } else {
        1.0
    };
    top.max(1e-3)
}

/// Jet colour map of `t` in 0..1.
fn jet(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let c = |x: f32| ((1.5 - (4.0 * t - x).abs()).clamp(0.0, 1.0) * 255.0).round() as u8;
    [c(3.0), c(2.0), c(1.0)]
}

impl Map {
    /// The vegetation mask: GRVI above the threshold.
    pub fn vegetation(&self) -> Vec<bool> {
        self.cloud
            .grvi
            .iter()
            .map(|g| *g > self.grvi_threshold)
            .collect()
    }

    /// The cloud's colours by GRVI as the paper's Figure 15 b, one per point: vegetation
    /// green, lighter for higher GRVI; everything else blue.
    pub fn grvi_colors(&self) -> Vec<[u8; 3]> {
        self.cloud
            .grvi
            .iter()
            .map(|&g| {
                if g > self.grvi_threshold {
                    let s =
                        ((g - self.grvi_threshold) / (1.0 - self.grvi_threshold)).clamp(0.0, 1.0);
                    let l = (s * 4.0).min(1.0);
                    [
                        (l * 180.0) as u8,
                        (120.0 + l * 135.0) as u8,
                        (l * 180.0) as u8,
                    ]
                } else {
                    [30, 60, 200]
                }
            })
            .collect()
    }

    /// The cloud's colours by elevation as the paper's Figure 15 c, one per point (jet,
    /// 0 to the 99th percentile of elevation).
    pub fn elevation_colors(&self) -> Vec<[u8; 3]> {
        let top = elevation_scale(&self.cloud.elevation);
        self.cloud.elevation.iter().map(|&z| jet(z / top)).collect()
    }

    /// Writes `map.ply`, `map_grvi.ply`, `map_elevation.ply` and, with a mesh,
    /// `mesh.ply`, `mesh.obj`, the Gazebo model folder `vinebench_map/` and
    /// `vinebench_map.mjcf.xml` into `dir` (created if needed).
    ///
    /// The model folder and the MJCF file are written first; the clouds and meshes then
    /// side by side on rayon's threads (most of the time is the kernel copying gigabytes
    /// into the page cache, one thread per file). Where several fail, the error is the
    /// first failed file's in the order above.
    pub fn export(&self, dir: &Path) -> Result<(), MapperError> {
        std::fs::create_dir_all(dir).map_err(|source| MapperError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        type Job<'a> = Box<dyn Fn() -> Result<(), MapperError> + Send + Sync + 'a>;
        let (map_ply, grvi_ply, elevation_ply) = (
            dir.join("map.ply"),
            dir.join("map_grvi.ply"),
            dir.join("map_elevation.ply"),
        );
        let mut jobs: Vec<Job<'_>> = vec![
            Box::new(move || ply::write_cloud(&self.cloud, &map_ply)),
            Box::new(move || ply::write_cloud_colored(&self.cloud, &self.grvi_colors(), &grvi_ply)),
            Box::new(move || {
                ply::write_cloud_colored(&self.cloud, &self.elevation_colors(), &elevation_ply)
            }),
        ];
        if let Some(mesh) = &self.mesh {
            let (mesh_ply, mesh_obj) = (dir.join("mesh.ply"), dir.join("mesh.obj"));
            let model_obj = export::gazebo_model_folder(dir, MODEL_NAME)?.1;
            export::write_mjcf(dir, MODEL_NAME, "mesh.obj")?;
            jobs.push(Box::new(move || ply::write_mesh(mesh, &mesh_ply)));
            // One formatting of the OBJ for both copies.
            jobs.push(Box::new(move || {
                export::write_obj_to(mesh, &[&mesh_obj, &model_obj])
            }));
        }
        let results: Vec<Result<(), MapperError>> = jobs.par_iter().map(|job| job()).collect();
        results.into_iter().collect()
    }
}

/// Name of the exported Gazebo model and MJCF file.
pub const MODEL_NAME: &str = "vinebench_map";

#[cfg(test)]
mod tests {
    use super::*;

    /// The colour scale's top by selection is the sorted order's element at the 99th
    /// percentile, with ties, negative zeros, NaN and the short cases.
    #[test]
    fn the_elevation_scale_is_the_sorted_percentile() {
        let by_sort = |e: &[f32]| {
            let mut s = e.to_vec();
            s.sort_by(f32::total_cmp);
            s.get(((s.len() as f64) * 0.99) as usize)
                .copied()
                .unwrap_or(1.0)
                .max(1e-3)
        };
        let mut state = 0x2545_F491_4F6C_DD1D_u64;
        for n in [0usize, 1, 2, 99, 100, 101, 1000, 4321] {
            let e: Vec<f32> = (0..n)
                .map(|i| match test_rng::next_u64(&mut state) % 9 {
                    0 => -0.0,
                    1 => 0.0,
                    2 => f32::NAN,
                    3 => 2.5,
                    _ => (i as f32).sin() * 3.0,
                })
                .collect();
            assert_eq!(elevation_scale(&e).to_bits(), by_sort(&e).to_bits(), "{n}");
        }
    }
}
