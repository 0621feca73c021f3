//! Parameter types of the simulator, one per table of `scenarios/defaults.toml`.
//!
//! Field meanings and default values are documented in that file (the one place where
//! defaults live); these types only give them shape. Every type rejects unknown keys.
//! `Default` reads the type's table from the embedded defaults.

use serde::{Deserialize, Serialize};
use vinebench_msgs::defaults;

macro_rules! default_from_section {
    ($ty:ty, $path:literal) => {
        impl Default for $ty {
            #[doc = concat!("The values of `[", $path, "]` in `scenarios/defaults.toml`.")]
            fn default() -> Self {
                defaults::section($path)
                    .expect("the embedded scenarios/defaults.toml is checked by tests")
            }
        }
    };
}

/// `[world]`: the procedural vineyard.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldParams {
    /// `[world.rows]`.
    pub rows: RowsParams,
    /// `[world.posts]`.
    pub posts: PostsParams,
    /// `[world.plants]`.
    pub plants: PlantsParams,
    /// `[world.terrain]`.
    pub terrain: TerrainParams,
    /// `[world.headlands]`.
    pub headlands: HeadlandsParams,
    /// `[world.canopy]`: leaves, shoots and grapes (render geometry only).
    pub canopy: CanopyParams,
    /// `[[world.tags]]`: AprilTag boards.
    pub tags: Vec<TagParams>,
    /// `[[world.occluders]]`: plain featureless boxes.
    pub occluders: Vec<OccluderParams>,
    /// `[world.mesh]`: a triangle mesh the cameras see instead of the generated geometry.
    pub mesh: WorldMeshParams,
}
default_from_section!(WorldParams, "world");

/// `[world.mesh]`: a reconstructed mesh (such as a run's `map/eif/mesh.ply`) as the world
/// the cameras see and the maps are scored against. The vineyard is still generated from
/// the seed for everything else (rows and route, terrain under the robot, GNSS), so the
/// mesh must be in this world's coordinates: a map of the same seed, or a field map
/// registered to it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldMeshParams {
    /// Binary or ASCII PLY with vertices (x y z, optional red green blue) and triangle
    /// faces, world frame, m; relative to the scenario file. Empty: the generated vineyard.
    pub file: String,
    /// Also draw the generated ground under the mesh (a map has holes where nothing was
    /// seen, and the cameras would see the sky through them).
    pub keep_ground: bool,
}

/// `[world.canopy]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanopyParams {
    /// Growth stage in [0, 1]: 0 bare cordons at budburst, 1 full canopy at veraison.
    pub growth_stage: f64,
    /// Leaves per vine at full growth.
    pub leaves_per_plant: u32,
    /// Leaf blade width at full growth, m.
    pub leaf_size_m: f64,
    /// Shoots per vine.
    pub shoots_per_plant: u32,
    /// Grape bunches per vine at full growth.
    pub bunches_per_plant: u32,
    /// Grape colour.
    pub grape_colour: GrapeColour,
    /// Number of distinct vine prototypes the vines are instances of.
    pub prototypes: u32,
}

/// Grape berry colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GrapeColour {
    /// Dark blue-purple (red varieties).
    Red,
    /// Yellow-green (white varieties).
    White,
}

/// Where a tag or occluder stands, in row coordinates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RowPlacement {
    /// Row whose centre line the placement refers to.
    pub row: u32,
    /// Arc length along that row from its first post, m (negative: in the headland
    /// before the row).
    pub s_m: f64,
    /// Offset to the left of the row centre line (towards the next row), m.
    pub offset_m: f64,
    /// Yaw relative to the row direction, degrees (counterclockwise seen from above).
    pub yaw_deg: f64,
}

/// One `[[world.tags]]` board: a tag36h11 tag printed with a white border on a board
/// standing upright.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TagParams {
    /// Tag id in the tag36h11 family (0..=586).
    pub id: u32,
    /// Edge of the black square (AprilTag's "tag size"), m.
    pub size_m: f64,
    /// Height of the tag centre above the ground, m.
    pub height_m: f64,
    /// Position; at `yaw_deg = 0` the printed face looks along the row direction, at 90
    /// towards the row's left side.
    #[serde(flatten)]
    pub at: RowPlacement,
}

/// One `[[world.occluders]]` box, standing on the ground.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OccluderParams {
    /// Length (along its yaw), width and height, m.
    pub size_m: [f64; 3],
    /// Position of the box's footprint centre.
    #[serde(flatten)]
    pub at: RowPlacement,
}

/// `[world.rows]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RowsParams {
    /// Number of rows.
    pub count: u32,
    /// Row length, m.
    pub length_m: f64,
    /// Row spacing, m.
    pub spacing_m: f64,
    /// Row direction as ENU yaw, degrees.
    pub yaw_deg: f64,
    /// Signed centre-line curvature, 1/m.
    pub curvature_per_m: f64,
}

/// `[world.posts]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PostsParams {
    /// Spacing along the row, m.
    pub spacing_m: f64,
    /// Height, m.
    pub height_m: f64,
    /// Diameter, m.
    pub diameter_m: f64,
    /// Wire heights above ground, m.
    pub wire_heights_m: Vec<f64>,
}

/// `[world.plants]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantsParams {
    /// Planting distance, m.
    pub spacing_m: f64,
    /// Probability of a missing vine.
    pub missing_probability: f64,
    /// Trunk position noise (1σ), m.
    pub position_sigma_m: f64,
    /// Trunk height, m.
    pub trunk_height_m: f64,
    /// Trunk height noise (1σ), m.
    pub trunk_height_sigma_m: f64,
    /// Trunk diameter, m.
    pub trunk_diameter_m: f64,
    /// Trunk diameter noise (1σ), m.
    pub trunk_diameter_sigma_m: f64,
    /// Canopy height above the cordon, m.
    pub canopy_height_m: f64,
    /// Canopy width, m.
    pub canopy_width_m: f64,
    /// Relative canopy size noise (1σ).
    pub canopy_size_sigma_rel: f64,
}

/// `[world.terrain]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TerrainParams {
    /// Grid resolution, m.
    pub cell_m: f64,
    /// Extent beyond the field, m.
    pub margin_m: f64,
    /// Slope along the rows, degrees.
    pub slope_along_deg: f64,
    /// Slope across the rows, degrees.
    pub slope_across_deg: f64,
    /// Undulation amplitude, m.
    pub undulation_m: f64,
    /// Undulation wavelength, m.
    pub undulation_wavelength_m: f64,
    /// Roughness (1σ), m.
    pub roughness_m: f64,
    /// Roughness correlation length, m.
    pub roughness_wavelength_m: f64,
}

/// `[world.headlands]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadlandsParams {
    /// Headland width beyond each row end, m.
    pub width_m: f64,
}

/// `[robot]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotParams {
    /// Built-in model name.
    pub model: String,
    /// URDF path overriding `model` when not empty.
    pub urdf: String,
}
default_from_section!(RobotParams, "robot");

/// Motion model choice.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionModelKind {
    /// Rigid-body dynamics with rapier3d (`[physics]`).
    Rapier,
    /// Rigid-body dynamics with MuJoCo 3.17 (`[physics.mujoco]`; cargo feature `mujoco`).
    Mujoco,
    /// Terrain-following kinematic skid-steer.
    Kinematic,
}

impl MotionModelKind {
    /// The name scenarios use (`motion.model`).
    pub fn name(self) -> &'static str {
        match self {
            MotionModelKind::Rapier => "rapier",
            MotionModelKind::Mujoco => "mujoco",
            MotionModelKind::Kinematic => "kinematic",
        }
    }
}

/// How a holonomic robot points while it follows its route.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HeadingMode {
    /// Along the route (plus `heading_offset_deg`), like a differential robot.
    Path,
    /// Keep the start heading (route tangent plus `heading_offset_deg`) all the way.
    Fixed,
}

/// `[motion]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionParams {
    /// Which model.
    pub model: MotionModelKind,
    /// Integration rate, Hz.
    pub step_hz: f64,
    /// Cruise speed, m/s.
    pub cruise_speed_mps: f64,
    /// Yaw-rate limit, rad/s.
    pub max_yaw_rate_radps: f64,
    /// Longitudinal acceleration limit, m/s².
    pub max_accel_mps2: f64,
    /// Lateral acceleration limit, m/s².
    pub max_lateral_accel_mps2: f64,
    /// Drive response time constant, s.
    pub response_time_s: f64,
    /// Skid-steer ICR expansion factor.
    pub icr_expansion: f64,
    /// Longitudinal track slip fraction at full speed.
    pub track_slip: f64,
    /// Pure-pursuit look-ahead, m.
    pub lookahead_m: f64,
    /// Controller rate, Hz.
    pub controller_hz: f64,
    /// Standstill before the route, s.
    pub still_before_s: f64,
    /// Standstill after the route, s.
    pub still_after_s: f64,
    /// Heading policy of holonomic robots.
    pub heading: HeadingMode,
    /// Heading relative to the route tangent, degrees (holonomic robots).
    pub heading_offset_deg: f64,
    /// Other motion models that drive the same route for comparison (ground truth only).
    pub compare_with: Vec<MotionModelKind>,
}
default_from_section!(MotionParams, "motion");

/// `[physics]`: the rigid-body backend and the ground contact model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhysicsParams {
    /// Multiplier on the URDF friction coefficients.
    pub friction_scale: f64,
    /// Shear deformation modulus of the soil, m.
    pub shear_deformation_m: f64,
    /// Damping time of the shear, s.
    pub shear_damping_s: f64,
    /// Rolling-resistance coefficient.
    pub rolling_resistance: f64,
    /// Contact probes per track.
    pub track_probes: u32,
    /// Track link pitch, m.
    pub track_link_pitch_m: f64,
    /// Rollers per mecanum wheel.
    pub mecanum_rollers: u32,
    /// Ride ripple amplitude of track links and rollers, m.
    pub ripple_m: f64,
    /// Bandwidth of the drive joints' speed servos, Hz.
    pub motor_bandwidth_hz: f64,
    /// Yaw-rate loop gain of the drive controller, 1/s.
    pub yaw_rate_gain_per_s: f64,
    /// Resolution of the terrain heightfield that the chassis collides with, m.
    pub heightfield_cell_m: f64,
    /// The run ends when the route follower has not advanced for this long, s.
    pub stuck_timeout_s: f64,
    /// `[physics.mujoco]`: the MuJoCo backend's model of the running gear and terrain.
    pub mujoco: MujocoParams,
}
default_from_section!(PhysicsParams, "physics");

/// `[physics.mujoco]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MujocoParams {
    /// Cell size of the terrain heightfield the tracks and wheels ride on, m.
    pub heightfield_cell_m: f64,
    /// Passive rollers (capsules on hinge joints) per mecanum wheel.
    pub mecanum_rollers: u32,
    /// Roller radius as a fraction of the wheel radius.
    pub roller_radius_fraction: f64,
    /// Spheres per track along its ground run (a conveyor belt driven by the sprocket).
    pub road_wheels: u32,
    /// Contact `solref` time constant, s (stiffness of the soft contacts).
    pub contact_timeconst_s: f64,
}
default_from_section!(MujocoParams, "physics.mujoco");

/// Route kind.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RouteKind {
    /// Closed loop around one row.
    RowLoop,
    /// Up and down every lane over a range of rows.
    Serpentine,
    /// A polyline in world coordinates.
    Waypoints,
}

/// Loop direction around a row.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LoopDirection {
    /// Up the right side, back on the left.
    Counterclockwise,
    /// Up the left side, back on the right.
    Clockwise,
}

/// `[route]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteParams {
    /// Which route table applies.
    pub kind: RouteKind,
    /// Headland turn radius, m (0 = half the spacing).
    pub turn_radius_m: f64,
    /// Overshoot into the headland before turning, m.
    pub headland_overshoot_m: f64,
    /// `[route.row_loop]`.
    pub row_loop: RowLoopParams,
    /// `[route.serpentine]`.
    pub serpentine: SerpentineParams,
    /// `[route.waypoints]`.
    pub waypoints: WaypointsParams,
}
default_from_section!(RouteParams, "route");

/// `[route.row_loop]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RowLoopParams {
    /// Row index.
    pub row: u32,
    /// Direction.
    pub direction: LoopDirection,
    /// Number of laps.
    pub laps: u32,
}

/// `[route.serpentine]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerpentineParams {
    /// First row.
    pub first_row: u32,
    /// Last row (inclusive).
    pub last_row: u32,
}

/// `[route.waypoints]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaypointsParams {
    /// Points `[x, y]` in world ENU, m.
    pub points: Vec<[f64; 2]>,
    /// Return to the first point.
    pub closed: bool,
    /// After the last point, stop and drive back along the same path to the first point
    /// without turning (a cusp at the last point). Not allowed with `closed`.
    pub there_and_back: bool,
}

/// `[sensors]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorsParams {
    /// `[sensors.imu]`.
    pub imu: ImuParams,
    /// `[sensors.gnss]`.
    pub gnss: GnssParams,
    /// `[sensors.tracking_camera]`.
    pub tracking_camera: TrackingCameraParams,
    /// `[sensors.wheel_odom]`.
    pub wheel_odom: WheelOdomParams,
    /// `[[sensors.cameras]]`: rendered cameras.
    pub cameras: Vec<CameraParams>,
    /// `[sensors.stereo_depth]`: the light the depth cameras measure in.
    pub stereo_depth: StereoDepthParams,
    /// `[sensors.camera_exposure]`: auto-exposure and lens shading of colour images.
    pub camera_exposure: CameraExposureParams,
}
default_from_section!(SensorsParams, "sensors");

/// Light the D435 depth cameras measure in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthLighting {
    /// The projector's dots texture every surface in range (the D435 error model alone).
    Indoor,
    /// Daylight washes the dots out: depth where the surface has texture
    /// ([`crate::render::depth_light`]).
    Sunlight,
}

/// `[sensors.stereo_depth]`: active stereo in daylight ([`crate::render::depth_light`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StereoDepthParams {
    /// `indoor` or `sunlight`.
    pub lighting: DepthLighting,
    /// Band irradiance of one relative unit of the renderer's light, W/m².
    pub ambient_w_m2: f64,
    /// Projector optical power, mW.
    pub projector_power_mw: f64,
    /// Projector field of projection `[h, v]`, degrees.
    pub projector_fov_deg: [f64; 2],
    /// Contrast (σ/μ) of the dot pattern.
    pub dot_contrast: f64,
    /// Matching window edge, px (odd).
    pub window_px: u32,
    /// Mean level of the infrared frame under auto-exposure, fraction of full scale.
    pub ae_level: f64,
    /// Matching SNR at which half the pixels get depth.
    pub snr_threshold: f64,
    /// Width of the validity's logistic in `ln SNR`.
    pub snr_softness: f64,
    /// Matching SNR from which the datasheet disparity noise holds.
    pub snr_reference: f64,
}
default_from_section!(StereoDepthParams, "sensors.stereo_depth");

/// `[sensors.camera_exposure]`: how colour cameras expose ([`crate::render::exposure`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraExposureParams {
    /// Auto-exposure for cameras without `exposure_ms`.
    pub auto: bool,
    /// Mean linear level the auto-exposure holds, fraction of full scale.
    pub target_level: f64,
    /// Time constant of the auto-exposure's response to a change of brightness, s.
    pub time_constant_s: f64,
    /// Exposure time at which a pixel value is radiance × `[render] exposure`, ms.
    pub reference_exposure_ms: f64,
    /// Shortest exposure time, ms.
    pub min_exposure_ms: f64,
    /// Longest exposure time, ms (at most the frame period).
    pub max_exposure_ms: f64,
    /// Largest analog gain once the exposure time is at its longest.
    pub max_gain: f64,
    /// Residual vignetting: image corners darkened by this share of the natural
    /// `cos⁴θ` fall-off (0: flat, 1: no lens-shading correction).
    pub vignetting: f64,
}
default_from_section!(CameraExposureParams, "sensors.camera_exposure");

/// Named camera devices (their datasheet geometry: `CameraProfile::spec` in
/// [`crate::render::camera`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraProfile {
    /// Intel RealSense D435 depth stream (left IR imager geometry).
    D435Depth,
    /// Intel RealSense D435 colour stream (OV2740).
    D435Color,
    /// Stereolabs ZED 2i, 2.1 mm lenses, rectified left image.
    Zed2i,
    /// Stereolabs ZED X Mini, 2.2 mm lenses, raw left image (tag camera).
    ZedXMini,
}

/// One `[[sensors.cameras]]` entry. Optional values default to the profile's datasheet
/// values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraParams {
    /// Name; topics are `/<name>/...` and its random streams `sensors.camera.<name>.*`.
    pub name: String,
    /// Camera model.
    pub profile: CameraProfile,
    /// Optical frame (URDF link; the left one of a stereo pair).
    pub frame: String,
    /// Right optical frame of a stereo pair: both images are rendered and published.
    #[serde(default)]
    pub right_frame: Option<String>,
    /// Image width, px (default: the profile's).
    #[serde(default)]
    pub width: Option<u32>,
    /// Image height, px (default: the profile's).
    #[serde(default)]
    pub height: Option<u32>,
    /// Frame rate, Hz (default: the profile's).
    #[serde(default)]
    pub rate_hz: Option<f64>,
    /// Publish a depth image aligned to the colour image (default: true for `d435`).
    #[serde(default)]
    pub depth: Option<bool>,
    /// Frame period jitter (1σ), ms.
    #[serde(default)]
    pub jitter_ms: Option<f64>,
    /// Delivery latency, ms.
    #[serde(default)]
    pub latency_ms: Option<f64>,
    /// Farthest range a colour pixel sees geometry, m (beyond it: sky).
    #[serde(default)]
    pub max_range_m: Option<f64>,
    /// Fixed exposure time, ms: colour images are blurred by the camera's motion over it
    /// ([`crate::render::blur`]) at the render's brightness. Default: the auto-exposure
    /// of `[sensors.camera_exposure]` (or, with `auto = false`, 0: sharp images).
    #[serde(default)]
    pub exposure_ms: Option<f64>,
    /// Rolling-shutter readout time of a whole frame, ms (0: global shutter); default the
    /// profile's ([`crate::render::camera::CameraProfile::readout_ms`]).
    #[serde(default)]
    pub readout_ms: Option<f64>,
}

/// `[render]`: how camera images are made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderParams {
    /// Ray-casting backend.
    pub backend: RenderBackend,
    /// Ground triangulation step, m.
    pub terrain_cell_m: f64,
    /// Shadow-map texel, m.
    pub shadow_cell_m: f64,
    /// Sun compass azimuth, degrees clockwise from north.
    pub sun_azimuth_deg: f64,
    /// Sun elevation above the horizon, degrees.
    pub sun_elevation_deg: f64,
    /// Direct sun irradiance (relative).
    pub sun_irradiance: f64,
    /// Sky irradiance on an upward surface (relative).
    pub sky_irradiance: f64,
    /// Exposure multiplier.
    pub exposure: f64,
    /// Draw the sun disc and glare.
    pub sun_glare: bool,
    /// Read noise σ, linear units.
    pub read_noise: f64,
    /// Shot-noise variance per unit of linear signal.
    pub shot_gain: f64,
    /// Write every n-th image of each camera as PNG into the run folder (0 = none).
    pub debug_png_every: u32,
}
default_from_section!(RenderParams, "render");

/// Ray-casting backend.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RenderBackend {
    /// The built-in two-level BVH with packet traversal (pure Rust).
    Bvh,
    /// Embree 3 (cargo feature `embree`).
    Embree,
}

/// `[sensors.imu]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuParams {
    /// Simulate this sensor.
    pub enabled: bool,
    /// URDF link.
    pub frame: String,
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Reception delay, ms.
    pub latency_ms: f64,
    /// Gyro white noise density, °/s/√Hz.
    pub gyro_noise_density_dps_rthz: f64,
    /// Gyro in-run bias stability, °/h.
    pub gyro_bias_instability_dph: f64,
    /// Accelerometer white noise density, µg/√Hz.
    pub accel_noise_density_ug_rthz: f64,
    /// Accelerometer in-run bias stability, µg.
    pub accel_bias_instability_ug: f64,
    /// In-run bias model: `"flicker"` (1/f: the Allan deviation's flat floor at the
    /// bias instability) or `"gauss_markov"` (one first-order process of that σ).
    pub bias_model: ImuBiasModel,
    /// Band of the flicker model's correlation times, s: `[shortest, longest]`.
    pub flicker_band_s: [f64; 2],
    /// Bias Gauss-Markov correlation time, s (`bias_model = "gauss_markov"`).
    pub bias_correlation_time_s: f64,
    /// The gyro senses the Earth's rotation (15.04 °/h, its direction from the latitude).
    pub earth_rate: bool,
    /// Gyro turn-on bias (1σ), °/h.
    pub gyro_turn_on_bias_dph: f64,
    /// Accelerometer turn-on bias (1σ), µg.
    pub accel_turn_on_bias_ug: f64,
    /// AHRS roll/pitch error (1σ), degrees.
    pub orientation_roll_pitch_sigma_deg: f64,
    /// AHRS yaw error (1σ), degrees.
    pub orientation_yaw_sigma_deg: f64,
    /// AHRS error correlation time, s (0 = white).
    pub orientation_correlation_time_s: f64,
}
default_from_section!(ImuParams, "sensors.imu");

/// The in-run bias model of an IMU.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImuBiasModel {
    /// Flicker (1/f) noise: a flat Allan-deviation floor.
    Flicker,
    /// One first-order Gauss-Markov process.
    GaussMarkov,
}

/// A GNSS solution type in scenario files.
#[derive(Copy, Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GnssStatusParam {
    /// No fix.
    NoFix,
    /// Single point.
    Single,
    /// RTK float.
    RtkFloat,
    /// RTK fixed.
    RtkFixed,
}

impl From<GnssStatusParam> for vinebench_msgs::FixStatus {
    fn from(s: GnssStatusParam) -> Self {
        match s {
            GnssStatusParam::NoFix => vinebench_msgs::FixStatus::NoFix,
            GnssStatusParam::Single => vinebench_msgs::FixStatus::Single,
            GnssStatusParam::RtkFloat => vinebench_msgs::FixStatus::RtkFloat,
            GnssStatusParam::RtkFixed => vinebench_msgs::FixStatus::RtkFixed,
        }
    }
}

/// `[sensors.gnss]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssParams {
    /// Simulate this sensor.
    pub enabled: bool,
    /// URDF link of the antenna.
    pub frame: String,
    /// Fix rate, Hz.
    pub rate_hz: f64,
    /// Reception delay, ms.
    pub latency_ms: f64,
    /// Solution type outside fault windows.
    pub nominal_status: GnssStatusParam,
    /// Velocity noise (1σ per axis), m/s.
    pub velocity_sigma_mps: f64,
    /// Reported-covariance factor.
    pub reported_variance_scale: f64,
    /// Error model with RTK fixed ambiguities.
    pub rtk_fixed: GnssErrorParams,
    /// Error model with RTK float ambiguities.
    pub rtk_float: GnssErrorParams,
    /// Error model of a single-point solution.
    pub single: GnssErrorParams,
    /// `[sensors.gnss.sky]`: the solution from the satellites the antenna sees.
    pub sky: GnssSkyParams,
}
default_from_section!(GnssParams, "sensors.gnss");

/// `[sensors.gnss.sky]`: constellation, line of sight through the world, solution
/// state (see `vinebench_sim::sensors::sky`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssSkyParams {
    /// Derive the solution type and DOP from the sky (off: `nominal_status` and fault
    /// windows alone).
    pub enabled: bool,
    /// Satellite systems: `"gps"`, `"galileo"`.
    pub systems: Vec<String>,
    /// Elevation mask, degrees.
    pub elevation_mask_deg: f64,
    /// C/N0 of a clear line of sight at the zenith, dB-Hz.
    pub cn0_zenith_dbhz: f64,
    /// C/N0 of a clear line of sight at the horizon, dB-Hz.
    pub cn0_horizon_dbhz: f64,
    /// Fading of each satellite's C/N0 (1σ), dB.
    pub cn0_sigma_db: f64,
    /// Correlation time of the fading, s.
    pub cn0_correlation_time_s: f64,
    /// Fraction of the signal power one leaf lets through.
    pub leaf_transmission: f64,
    /// Weakest C/N0 tracked and used, dB-Hz.
    pub tracking_cn0_dbhz: f64,
    /// Weakest C/N0 that helps fix RTK ambiguities, dB-Hz.
    pub fix_cn0_dbhz: f64,
    /// Largest PDOP that gives a position.
    pub max_pdop: f64,
    /// Satellites an RTK (float) solution needs.
    pub rtk_min_satellites: u32,
    /// Satellites at `fix_cn0_dbhz` or better that fixing ambiguities needs.
    pub fix_min_satellites: u32,
    /// Median time to fix after the fix conditions return, s.
    pub time_to_fix_s: f64,
    /// Log-normal σ of the time to fix.
    pub time_to_fix_spread: f64,
    /// A fix survives gaps in the fix conditions up to this long, s.
    pub fix_hold_s: f64,
    /// RTK corrections arrive.
    pub corrections: bool,
    /// HDOP at which the solution types' σ hold.
    pub reference_hdop: f64,
    /// VDOP at which the solution types' σ hold.
    pub reference_vdop: f64,
    /// Pseudorange multipath of a satellite seen through foliage (1σ), single-point, m.
    pub multipath_single_m: f64,
    /// The same for an RTK float solution, m.
    pub multipath_float_m: f64,
    /// The same for an RTK fixed solution (carrier-phase multipath), m.
    pub multipath_fixed_m: f64,
    /// Correlation time of multipath, s.
    pub multipath_correlation_time_s: f64,
}
default_from_section!(GnssSkyParams, "sensors.gnss.sky");

/// Error model of one GNSS solution type.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssErrorParams {
    /// Horizontal error (1σ per axis), m.
    pub sigma_horizontal_m: f64,
    /// Vertical error (1σ), m.
    pub sigma_vertical_m: f64,
    /// Correlation time, s (0 = white).
    pub correlation_time_s: f64,
}

/// `[sensors.tracking_camera]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackingCameraParams {
    /// Simulate this sensor.
    pub enabled: bool,
    /// URDF link of the camera's pose frame.
    pub frame: String,
    /// Output rate, Hz.
    pub rate_hz: f64,
    /// Reception delay, ms.
    pub latency_ms: f64,
    /// Scale error (1σ).
    pub scale_error_sigma: f64,
    /// Constant pitch error (1σ), degrees.
    pub pitch_bias_sigma_deg: f64,
    /// Yaw random walk, °/√m.
    pub yaw_random_walk_deg_per_rtm: f64,
    /// Roll/pitch random walk, °/√m.
    pub roll_pitch_random_walk_deg_per_rtm: f64,
    /// Position random walk, m/√m.
    pub position_random_walk_m_per_rtm: f64,
    /// Position jitter (1σ), m.
    pub jitter_sigma_m: f64,
    /// Linear velocity noise (1σ per axis), m/s.
    pub twist_linear_sigma_mps: f64,
    /// Angular velocity noise (1σ per axis), rad/s.
    pub twist_angular_sigma_radps: f64,
}
default_from_section!(TrackingCameraParams, "sensors.tracking_camera");

/// `[sensors.wheel_odom]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WheelOdomParams {
    /// Simulate this sensor.
    pub enabled: bool,
    /// Output rate, Hz.
    pub rate_hz: f64,
    /// Reception delay, ms.
    pub latency_ms: f64,
    /// Encoder noise per drive joint as surface speed (1σ), m/s.
    pub speed_sigma_mps: f64,
}
default_from_section!(WheelOdomParams, "sensors.wheel_odom");

/// `[faults]`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultsParams {
    /// GNSS windows.
    pub gnss: Vec<GnssFault>,
}

/// One `[[faults.gnss]]` window: the receiver reports `status` during `[start_s, end_s)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssFault {
    /// Window start, s after the first sample.
    pub start_s: f64,
    /// Window end, s after the first sample.
    pub end_s: f64,
    /// Forced solution type.
    pub status: GnssStatusParam,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_section_reads_from_the_embedded_defaults() {
        // Each Default impl panics if its table is missing or malformed.
        let _ = WorldParams::default();
        let _ = RobotParams::default();
        let _ = MotionParams::default();
        let _ = RouteParams::default();
        let s = SensorsParams::default();
        assert_eq!(s.imu.rate_hz, 200.0);
        assert_eq!(s.gnss.nominal_status, GnssStatusParam::RtkFixed);
        let f: FaultsParams = defaults::section("faults").unwrap();
        assert!(f.gnss.is_empty());
    }
}

/// A parameter value that cannot be used, named by its dotted path in the scenario
/// (`world.rows.spacing_m`) so the scenario loader can point at its line and column.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("`{path}`: expected {expected}, found {found}")]
pub struct ParamError {
    /// Dotted path of the offending key.
    pub path: String,
    /// What would have been accepted.
    pub expected: String,
    /// What was given.
    pub found: String,
}

impl ParamError {
    /// A new error for `path`.
    pub fn new(path: impl Into<String>, expected: impl Into<String>, found: impl ToString) -> Self {
        ParamError {
            path: path.into(),
            expected: expected.into(),
            found: found.to_string(),
        }
    }
}

/// Checks `value > 0` and finite.
pub fn require_positive(path: &str, value: f64) -> Result<f64, ParamError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(ParamError::new(path, "a finite number > 0", value))
    }
}

/// Checks `value >= 0` and finite.
pub fn require_non_negative(path: &str, value: f64) -> Result<f64, ParamError> {
    if value.is_finite() && value >= 0.0 {
        Ok(value)
    } else {
        Err(ParamError::new(path, "a finite number >= 0", value))
    }
}

/// `value` if within `[lo, hi]` (a count: rollers, probes), else an error naming `path`.
pub fn require_count_in(path: &str, value: u32, lo: u32, hi: u32) -> Result<u32, ParamError> {
    if (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(ParamError::new(
            path,
            format!("an integer in [{lo}, {hi}]"),
            value,
        ))
    }
}

/// Checks `lo <= value <= hi` and finite.
pub fn require_in(path: &str, value: f64, lo: f64, hi: f64) -> Result<f64, ParamError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(value)
    } else {
        Err(ParamError::new(
            path,
            format!("a number in [{lo}, {hi}]"),
            value,
        ))
    }
}
