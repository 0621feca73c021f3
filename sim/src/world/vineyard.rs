//! Vineyard generation: terrain, trellis posts and wires, and vines from a seed.
//!
//! Randomness comes from separate named streams of the world seed, so changing one part's
//! parameters never changes another part: `"world.terrain"` for the ground and
//! `"world.plants"` for the vines. Posts and wires have no random parameters.

use super::World;
use super::layout::RowLayout;
use super::terrain::{self, Terrain};
use crate::params::{CanopyParams, RowPlacement, TagParams};
use crate::params::{
    HeadlandsParams, ParamError, PlantsParams, PostsParams, RowsParams, TerrainParams, WorldParams,
    require_non_negative, require_positive,
};
use crate::rng;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;
use sha2::{Digest, Sha256};
use std::f64::consts::PI;

/// Name of the terrain's random stream.
pub const TERRAIN_STREAM: &str = "world.terrain";
/// Name of the vines' random stream.
pub const PLANTS_STREAM: &str = "world.plants";
/// Rows must satisfy `|curvature| · (count · spacing + headland width)` below this, so
/// every row and headland keeps a radius of at least half the curvature radius.
pub const MAX_CURVATURE_FOOTPRINT: f64 = 0.5;
/// A random size (trunk height or diameter, canopy height or width) is clamped to at
/// least this fraction of its mean so it stays positive.
pub const SIZE_FLOOR_FRACTION: f64 = 0.1;
/// Most rows a world may have (`world.rows.count`).
pub const MAX_ROWS: u32 = 1_000;
/// Longest row, m (`world.rows.length_m`).
pub const MAX_ROW_LENGTH_M: f64 = 10_000.0;
/// Widest row spacing, m (`world.rows.spacing_m`).
pub const MAX_ROW_SPACING_M: f64 = 50.0;
/// Widest headland, m (`world.headlands.width_m`).
pub const MAX_HEADLAND_WIDTH_M: f64 = 1_000.0;
/// Most trellis posts in a world (rows × posts per row; `world.posts.spacing_m`).
pub const MAX_POSTS: f64 = 200_000.0;
/// Most planting slots in a world (rows × slots per row; `world.plants.spacing_m`).
pub const MAX_PLANTS: f64 = 200_000.0;
/// Most trellis wire heights (`world.posts.wire_heights_m`).
pub const MAX_WIRE_HEIGHTS: usize = 16;
/// Most AprilTag boards (`world.tags`).
pub const MAX_TAGS: usize = 1_000;
/// Most occluder boxes (`world.occluders`).
pub const MAX_OCCLUDERS: usize = 10_000;
/// Most distinct vine canopies (`world.canopy.prototypes`).
pub const MAX_PROTOTYPES: u32 = 64;
/// Most shoots per vine (`world.canopy.shoots_per_plant`).
pub const MAX_SHOOTS_PER_PLANT: u32 = 200;
/// Most grape bunches per vine (`world.canopy.bunches_per_plant`).
pub const MAX_BUNCHES_PER_PLANT: u32 = 200;

/// A trellis post.
#[derive(Clone, Debug, PartialEq)]
pub struct Post {
    /// Row index.
    pub row: u32,
    /// Foot of the post on the ground, world frame, m.
    pub base_in_world: Vector3<f64>,
    /// Height above ground, m.
    pub height_m: f64,
    /// Diameter, m.
    pub diameter_m: f64,
}

/// A trellis wire: a polyline through the row's posts at one height above ground.
#[derive(Clone, Debug, PartialEq)]
pub struct Wire {
    /// Row index.
    pub row: u32,
    /// Height above ground at the posts, m.
    pub height_m: f64,
    /// Attachment points on the posts, world frame, m.
    pub points_in_world: Vec<Vector3<f64>>,
}

/// A vine.
#[derive(Clone, Debug, PartialEq)]
pub struct Plant {
    /// Row index.
    pub row: u32,
    /// Planting position index along the row.
    pub slot: u32,
    /// Foot of the trunk on the ground, world frame, m.
    pub base_in_world: Vector3<f64>,
    /// Trunk height up to the cordon, m.
    pub trunk_height_m: f64,
    /// Trunk diameter, m.
    pub trunk_diameter_m: f64,
    /// Canopy height above the cordon, m.
    pub canopy_height_m: f64,
    /// Canopy width across the row, m.
    pub canopy_width_m: f64,
    /// Per-plant seed for appearance variation (leaf placement, bunches) in rendering.
    pub appearance_seed: u64,
}

/// An AprilTag board (tag36h11) standing upright.
#[derive(Clone, Debug, PartialEq)]
pub struct TagBoard {
    /// Tag id.
    pub id: u32,
    /// Edge of the black square, m (AprilTag's tag size); the printed board adds one
    /// white cell (`size_m / 8`) on every side.
    pub size_m: f64,
    /// Pose of the tag frame in the world, AprilTag 3 / `apriltag_ros` convention: origin
    /// at the tag centre, x to the right and y down as printed, z into the board (the
    /// printed face looks along -z).
    pub world_from_tag: Isometry3<f64>,
}

/// A plain, uniformly coloured box (a carton) standing on the ground.
#[derive(Clone, Debug, PartialEq)]
pub struct Occluder {
    /// Length, width, height, m.
    pub size_m: Vector3<f64>,
    /// Pose of the box's bottom face centre: x along its length, z up.
    pub world_from_box: Isometry3<f64>,
}

/// See [`World::generate`].
///
/// - Terrain: [`Terrain::generate`] from the `"world.terrain"` stream.
/// - Posts: on every row's centre line at `s = 0, spacing, 2·spacing, …` and always one
///   at `s = length`; a regular post closer than half a spacing to the end post is left
///   out. Their feet are on the terrain.
/// - Wires: per row and wire height, a polyline through that row's posts at that height
///   above each post's foot.
/// - Vines: planting slots at `s = spacing/2 + j·spacing` while `s < length` (`s` is the
///   arc length along row 0, so slots line up across concentric rows). Each slot draws,
///   in this order and whether or not it stays empty: emptiness (probability
///   `missing_probability`), the trunk's displacement along and across the row
///   (N(0, position_sigma_m) each, in metres at that row), trunk height and diameter
///   (mean + N(0, sigma)), canopy height and width (mean · (1 + N(0, size_sigma_rel)),
///   independently) and the appearance seed. Sizes are clamped to at least
///   [`SIZE_FLOOR_FRACTION`] of their mean.
pub fn generate(seed: u64, params: &WorldParams) -> Result<World, ParamError> {
    validate(params)?;
    let layout = RowLayout::new(&params.rows);
    let terrain = Terrain::generate(
        &params.terrain,
        &layout,
        params.headlands.width_m,
        &mut rng::stream(seed, TERRAIN_STREAM),
    )?;
    let posts = place_posts(&params.posts, &layout, &terrain);
    let wires = string_wires(&params.posts, &posts);
    let plants = plant_vines(
        &params.plants,
        &layout,
        &terrain,
        &mut rng::stream(seed, PLANTS_STREAM),
    );
    let tags = params
        .tags
        .iter()
        .map(|t| place_tag(t, &layout, &terrain))
        .collect();
    let occluders = params
        .occluders
        .iter()
        .map(|o| Occluder {
            size_m: Vector3::from(o.size_m),
            world_from_box: placement_pose(&o.at, 0.0, &layout, &terrain),
        })
        .collect();
    Ok(World {
        seed,
        params: params.clone(),
        layout,
        terrain,
        posts,
        wires,
        plants,
        tags,
        occluders,
    })
}

/// Pose of a row placement `height_m` above the ground: x along the placement's yaw,
/// z up.
fn placement_pose(
    at: &RowPlacement,
    height_m: f64,
    layout: &RowLayout,
    terrain: &Terrain,
) -> Isometry3<f64> {
    let (xy, tangent) = layout.point(layout.row_offset_m(at.row) + at.offset_m, at.s_m);
    let yaw = tangent.y.atan2(tangent.x) + at.yaw_deg.to_radians();
    Isometry3::from_parts(
        Translation3::new(xy.x, xy.y, terrain.height_at(xy.x, xy.y) + height_m),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

fn place_tag(t: &TagParams, layout: &RowLayout, terrain: &Terrain) -> TagBoard {
    let facing = placement_pose(&t.at, t.height_m, layout, terrain);
    // Columns: tag x (the viewer's right), y (down), z (into the board) in the facing
    // frame (x = the direction the printed face looks, z up).
    let facing_from_tag = Rotation3::from_matrix_unchecked(Matrix3::new(
        0.0, 0.0, -1.0, //
        1.0, 0.0, 0.0, //
        0.0, -1.0, 0.0,
    ));
    TagBoard {
        id: t.id,
        size_m: t.size_m,
        world_from_tag: facing * UnitQuaternion::from_rotation_matrix(&facing_from_tag),
    }
}

/// Checks every `[world.*]` value; the first problem is returned with its dotted path.
///
/// Sizes the input drives are bounded before anything is generated: [`MAX_ROWS`],
/// [`MAX_ROW_LENGTH_M`], [`MAX_ROW_SPACING_M`], [`MAX_HEADLAND_WIDTH_M`], [`MAX_POSTS`],
/// [`MAX_PLANTS`], [`MAX_WIRE_HEIGHTS`], [`MAX_TAGS`], [`MAX_OCCLUDERS`],
/// [`MAX_PROTOTYPES`], [`MAX_SHOOTS_PER_PLANT`], [`MAX_BUNCHES_PER_PLANT`] (and the
/// terrain's [`terrain::MAX_GRID_POINTS`]); each error names the key to change.
pub fn validate(p: &WorldParams) -> Result<(), ParamError> {
    validate_headlands(&p.headlands)?;
    validate_rows(&p.rows, &p.headlands)?;
    validate_posts(&p.posts)?;
    validate_plants(&p.plants)?;
    validate_canopy(&p.canopy)?;
    validate_counts(p)?;
    for (i, t) in p.tags.iter().enumerate() {
        validate_tag(&format!("world.tags[{i}]"), t, p.rows.count)?;
    }
    for (i, o) in p.occluders.iter().enumerate() {
        let path = format!("world.occluders[{i}]");
        validate_placement(&path, &o.at, p.rows.count)?;
        for v in o.size_m {
            if !(v.is_finite() && v > 0.0) {
                return Err(ParamError::new(
                    format!("{path}.size_m"),
                    "three positive lengths [length, width, height] in m",
                    format!("{:?}", o.size_m),
                ));
            }
        }
    }
    terrain::validate_params(&p.terrain)
}

/// Largest tag36h11 id.
pub const MAX_TAG36H11_ID: u32 = 586;

fn validate_tag(path: &str, t: &TagParams, rows: u32) -> Result<(), ParamError> {
    if t.id > MAX_TAG36H11_ID {
        return Err(ParamError::new(
            format!("{path}.id"),
            format!("a tag36h11 id in 0..={MAX_TAG36H11_ID}"),
            t.id,
        ));
    }
    require_positive(&format!("{path}.size_m"), t.size_m)?;
    require_non_negative(&format!("{path}.height_m"), t.height_m)?;
    validate_placement(path, &t.at, rows)
}

fn validate_placement(path: &str, at: &RowPlacement, rows: u32) -> Result<(), ParamError> {
    if at.row >= rows {
        return Err(ParamError::new(
            format!("{path}.row"),
            format!("a row index below world.rows.count = {rows}"),
            at.row,
        ));
    }
    require_finite(&format!("{path}.s_m"), at.s_m)?;
    require_finite(&format!("{path}.offset_m"), at.offset_m)?;
    require_finite(&format!("{path}.yaw_deg"), at.yaw_deg)?;
    Ok(())
}

fn validate_canopy(p: &CanopyParams) -> Result<(), ParamError> {
    let g = p.growth_stage;
    if !(g.is_finite() && (0.0..=1.0).contains(&g)) {
        return Err(ParamError::new(
            "world.canopy.growth_stage",
            "a number in [0, 1]",
            g,
        ));
    }
    require_positive("world.canopy.leaf_size_m", p.leaf_size_m)?;
    if p.prototypes < 1 || p.prototypes > MAX_PROTOTYPES {
        return Err(ParamError::new(
            "world.canopy.prototypes",
            format!("1 to {MAX_PROTOTYPES} (MAX_PROTOTYPES)"),
            p.prototypes,
        ));
    }
    for (path, n, max, name) in [
        (
            "world.canopy.shoots_per_plant",
            p.shoots_per_plant,
            MAX_SHOOTS_PER_PLANT,
            "MAX_SHOOTS_PER_PLANT",
        ),
        (
            "world.canopy.bunches_per_plant",
            p.bunches_per_plant,
            MAX_BUNCHES_PER_PLANT,
            "MAX_BUNCHES_PER_PLANT",
        ),
    ] {
        if n > max {
            return Err(ParamError::new(path, format!("at most {max} ({name})"), n));
        }
    }
    if p.leaves_per_plant > 20_000 {
        return Err(ParamError::new(
            "world.canopy.leaves_per_plant",
            "at most 20000",
            p.leaves_per_plant,
        ));
    }
    Ok(())
}

fn require_finite(path: &str, value: f64) -> Result<f64, ParamError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(ParamError::new(path, "a finite number", value))
    }
}

fn validate_headlands(p: &HeadlandsParams) -> Result<(), ParamError> {
    require_non_negative("world.headlands.width_m", p.width_m)?;
    require_at_most(
        "world.headlands.width_m",
        p.width_m,
        MAX_HEADLAND_WIDTH_M,
        "MAX_HEADLAND_WIDTH_M",
    )?;
    Ok(())
}

/// `value <= max` (a positive finite `value` already checked), else an error naming the
/// limit's constant.
fn require_at_most(path: &str, value: f64, max: f64, name: &str) -> Result<f64, ParamError> {
    if value <= max {
        Ok(value)
    } else {
        Err(ParamError::new(
            path,
            format!("at most {max} ({name})"),
            value,
        ))
    }
}

/// The numbers of posts, planting slots, wire heights, tags and occluders: bounded
/// before any is generated, each naming the key that sets it.
fn validate_counts(p: &WorldParams) -> Result<(), ParamError> {
    let rows = f64::from(p.rows.count);
    let length = p.rows.length_m;
    // Posts: 0, spacing, ... and the end post; slots: spacing/2 + j·spacing < length.
    let posts = rows * (length / p.posts.spacing_m + 2.0);
    if posts.is_nan() || posts > MAX_POSTS {
        return Err(ParamError::new(
            "world.posts.spacing_m",
            format!(
                "a spacing giving at most {MAX_POSTS} posts over world.rows.count = {} rows of \
                 {length} m (MAX_POSTS), i.e. at least {} m",
                p.rows.count,
                rows * length / (MAX_POSTS - 2.0 * rows).max(1.0)
            ),
            format!("{} ({posts:.0} posts)", p.posts.spacing_m),
        ));
    }
    let slots = rows * (length / p.plants.spacing_m + 1.0);
    if slots.is_nan() || slots > MAX_PLANTS {
        return Err(ParamError::new(
            "world.plants.spacing_m",
            format!(
                "a spacing giving at most {MAX_PLANTS} vines over world.rows.count = {} rows of \
                 {length} m (MAX_PLANTS), i.e. at least {} m",
                p.rows.count,
                rows * length / (MAX_PLANTS - rows).max(1.0)
            ),
            format!("{} ({slots:.0} vines)", p.plants.spacing_m),
        ));
    }
    let counts = [
        (
            "world.posts.wire_heights_m",
            p.posts.wire_heights_m.len(),
            MAX_WIRE_HEIGHTS,
            "MAX_WIRE_HEIGHTS",
            "wire heights",
        ),
        ("world.tags", p.tags.len(), MAX_TAGS, "MAX_TAGS", "tags"),
        (
            "world.occluders",
            p.occluders.len(),
            MAX_OCCLUDERS,
            "MAX_OCCLUDERS",
            "occluders",
        ),
    ];
    for (path, n, max, name, what) in counts {
        if n > max {
            return Err(ParamError::new(
                path,
                format!("at most {max} {what} ({name})"),
                format!("{n} {what}"),
            ));
        }
    }
    Ok(())
}

fn validate_rows(p: &RowsParams, headlands: &HeadlandsParams) -> Result<(), ParamError> {
    if p.count < 1 || p.count > MAX_ROWS {
        return Err(ParamError::new(
            "world.rows.count",
            format!("1 to {MAX_ROWS} rows (MAX_ROWS)"),
            p.count,
        ));
    }
    require_positive("world.rows.length_m", p.length_m)?;
    require_at_most(
        "world.rows.length_m",
        p.length_m,
        MAX_ROW_LENGTH_M,
        "MAX_ROW_LENGTH_M",
    )?;
    require_positive("world.rows.spacing_m", p.spacing_m)?;
    require_at_most(
        "world.rows.spacing_m",
        p.spacing_m,
        MAX_ROW_SPACING_M,
        "MAX_ROW_SPACING_M",
    )?;
    require_finite("world.rows.yaw_deg", p.yaw_deg)?;
    let k = require_finite("world.rows.curvature_per_m", p.curvature_per_m)?.abs();
    let footprint = f64::from(p.count) * p.spacing_m + headlands.width_m;
    if k * footprint >= MAX_CURVATURE_FOOTPRINT {
        return Err(ParamError::new(
            "world.rows.curvature_per_m",
            format!(
                "|curvature| · (count · spacing_m + headland width_m) < {MAX_CURVATURE_FOOTPRINT}, \
                 i.e. |curvature| < {} 1/m",
                MAX_CURVATURE_FOOTPRINT / footprint
            ),
            p.curvature_per_m,
        ));
    }
    // Row coordinates are unique only within half a turn of the row start.
    let sweep = p.length_m + headlands.width_m;
    if k * sweep >= PI {
        return Err(ParamError::new(
            "world.rows.curvature_per_m",
            format!(
                "|curvature| · (length_m + headland width_m) < π (rows within half a turn), \
                 i.e. |curvature| < {} 1/m",
                PI / sweep
            ),
            p.curvature_per_m,
        ));
    }
    Ok(())
}

fn validate_posts(p: &PostsParams) -> Result<(), ParamError> {
    require_positive("world.posts.spacing_m", p.spacing_m)?;
    require_positive("world.posts.height_m", p.height_m)?;
    require_positive("world.posts.diameter_m", p.diameter_m)?;
    for (i, &h) in p.wire_heights_m.iter().enumerate() {
        if !(h.is_finite() && h > 0.0 && h <= p.height_m) {
            return Err(ParamError::new(
                "world.posts.wire_heights_m",
                format!("heights in (0, post height_m = {}]", p.height_m),
                format!("{h} (entry {i})"),
            ));
        }
    }
    Ok(())
}

fn validate_plants(p: &PlantsParams) -> Result<(), ParamError> {
    require_positive("world.plants.spacing_m", p.spacing_m)?;
    let q = p.missing_probability;
    if !(q.is_finite() && (0.0..1.0).contains(&q)) {
        return Err(ParamError::new(
            "world.plants.missing_probability",
            "a number in [0, 1)",
            q,
        ));
    }
    require_non_negative("world.plants.position_sigma_m", p.position_sigma_m)?;
    require_positive("world.plants.trunk_height_m", p.trunk_height_m)?;
    require_non_negative("world.plants.trunk_height_sigma_m", p.trunk_height_sigma_m)?;
    require_positive("world.plants.trunk_diameter_m", p.trunk_diameter_m)?;
    require_non_negative(
        "world.plants.trunk_diameter_sigma_m",
        p.trunk_diameter_sigma_m,
    )?;
    require_positive("world.plants.canopy_height_m", p.canopy_height_m)?;
    require_positive("world.plants.canopy_width_m", p.canopy_width_m)?;
    require_non_negative(
        "world.plants.canopy_size_sigma_rel",
        p.canopy_size_sigma_rel,
    )?;
    Ok(())
}

/// Row-0 arc lengths of one row's posts, m: `0, spacing, …` up to half a spacing before
/// the end, then `length`.
fn post_stations(length_m: f64, spacing_m: f64) -> impl Iterator<Item = f64> {
    let last_regular = length_m - 0.5 * spacing_m;
    std::iter::once(0.0)
        .chain(
            (1u32..)
                .map(move |j| f64::from(j) * spacing_m)
                .take_while(move |&s| s <= last_regular),
        )
        .chain(std::iter::once(length_m))
}

fn place_posts(p: &PostsParams, layout: &RowLayout, terrain: &Terrain) -> Vec<Post> {
    let mut posts = Vec::new();
    for row in 0..layout.count {
        let offset = layout.row_offset_m(row);
        for s in post_stations(layout.length_m, p.spacing_m) {
            let (xy, _) = layout.point(offset, s);
            posts.push(Post {
                row,
                base_in_world: Vector3::new(xy.x, xy.y, terrain.height_at(xy.x, xy.y)),
                height_m: p.height_m,
                diameter_m: p.diameter_m,
            });
        }
    }
    posts
}

fn string_wires(p: &PostsParams, posts: &[Post]) -> Vec<Wire> {
    let mut wires = Vec::new();
    // Posts are grouped by row, in order.
    for row_posts in posts.chunk_by(|a, b| a.row == b.row) {
        for &h in &p.wire_heights_m {
            wires.push(Wire {
                row: row_posts[0].row,
                height_m: h,
                points_in_world: row_posts
                    .iter()
                    .map(|post| post.base_in_world + Vector3::new(0.0, 0.0, h))
                    .collect(),
            });
        }
    }
    wires
}

/// `mean + sigma·n`, at least [`SIZE_FLOOR_FRACTION`] of `mean`.
fn positive_size(mean: f64, sigma: f64, n: f64) -> f64 {
    (mean + sigma * n).max(SIZE_FLOOR_FRACTION * mean)
}

fn plant_vines<R: Rng + ?Sized>(
    p: &PlantsParams,
    layout: &RowLayout,
    terrain: &Terrain,
    rng: &mut R,
) -> Vec<Plant> {
    let mut plants = Vec::new();
    for row in 0..layout.count {
        let offset = layout.row_offset_m(row);
        // A metre along row `row` is 1/(1 - k·offset) metres of row-0 arc length
        // (validation keeps the denominator above 1/2).
        let s_per_m = 1.0 / (1.0 - layout.curvature_per_m * offset);
        for slot in 0u32.. {
            let s_nominal = p.spacing_m * (0.5 + f64::from(slot));
            if s_nominal >= layout.length_m {
                break;
            }
            let missing = rng.random::<f64>() < p.missing_probability;
            let mut normal = || rng.sample::<f64, _>(StandardNormal);
            let along = p.position_sigma_m * normal();
            let across = p.position_sigma_m * normal();
            let trunk_height_m = positive_size(p.trunk_height_m, p.trunk_height_sigma_m, normal());
            let trunk_diameter_m =
                positive_size(p.trunk_diameter_m, p.trunk_diameter_sigma_m, normal());
            let canopy_height_m = positive_size(
                p.canopy_height_m,
                p.canopy_height_m * p.canopy_size_sigma_rel,
                normal(),
            );
            let canopy_width_m = positive_size(
                p.canopy_width_m,
                p.canopy_width_m * p.canopy_size_sigma_rel,
                normal(),
            );
            let appearance_seed = rng.random::<u64>();
            if missing {
                continue;
            }
            let (xy, _) = layout.point(offset + across, s_nominal + along * s_per_m);
            plants.push(Plant {
                row,
                slot,
                base_in_world: Vector3::new(xy.x, xy.y, terrain.height_at(xy.x, xy.y)),
                trunk_height_m,
                trunk_diameter_m,
                canopy_height_m,
                canopy_width_m,
                appearance_seed,
            });
        }
    }
    plants
}

/// Canonical little-endian serialization into a SHA-256 hasher.
struct DigestWriter(Sha256);

impl DigestWriter {
    fn u64(&mut self, v: u64) {
        self.0.update(v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.update(v.to_le_bytes());
    }
    fn len(&mut self, n: usize) {
        self.u64(n as u64);
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn f64s(&mut self, vs: &[f64]) {
        self.len(vs.len());
        for &v in vs {
            self.f64(v);
        }
    }
    fn pose(&mut self, p: &Isometry3<f64>) {
        self.vec3(&p.translation.vector);
        for c in p.rotation.coords.iter() {
            self.f64(*c);
        }
    }
    fn vec3(&mut self, v: &Vector3<f64>) {
        self.f64(v.x);
        self.f64(v.y);
        self.f64(v.z);
    }
}

/// See [`World::digest`]. Serializes, in this order: a format tag, the seed, every
/// parameter (struct fields in declaration order, lists with their length first), the
/// row layout, the terrain grid, posts, wires and plants; integers and `f64::to_bits`
/// little-endian.
pub fn digest(world: &World) -> String {
    let mut w = DigestWriter(Sha256::new());
    w.0.update(b"vinebench-world-v1\0");
    w.u64(world.seed);
    // Exhaustive destructuring: adding a parameter field fails to compile here until it
    // is added to the digest.
    let WorldParams {
        rows,
        posts,
        plants,
        terrain,
        headlands,
        canopy,
        tags,
        occluders,
        // Not generated: the runner loads the file into the render geometry.
        mesh: _,
    } = &world.params;
    let CanopyParams {
        growth_stage,
        leaves_per_plant,
        leaf_size_m,
        shoots_per_plant,
        bunches_per_plant,
        grape_colour,
        prototypes,
    } = canopy;
    w.f64(*growth_stage);
    w.f64(*leaf_size_m);
    for v in [
        leaves_per_plant,
        shoots_per_plant,
        bunches_per_plant,
        prototypes,
    ] {
        w.u32(*v);
    }
    w.u32(*grape_colour as u32);
    // Tags and occluders enter through their resolved poses below.
    let _ = (tags, occluders);
    let RowsParams {
        count,
        length_m,
        spacing_m,
        yaw_deg,
        curvature_per_m,
    } = rows;
    w.u32(*count);
    for v in [length_m, spacing_m, yaw_deg, curvature_per_m] {
        w.f64(*v);
    }
    let PostsParams {
        spacing_m,
        height_m,
        diameter_m,
        wire_heights_m,
    } = posts;
    for v in [spacing_m, height_m, diameter_m] {
        w.f64(*v);
    }
    w.f64s(wire_heights_m);
    let PlantsParams {
        spacing_m,
        missing_probability,
        position_sigma_m,
        trunk_height_m,
        trunk_height_sigma_m,
        trunk_diameter_m,
        trunk_diameter_sigma_m,
        canopy_height_m,
        canopy_width_m,
        canopy_size_sigma_rel,
    } = plants;
    for v in [
        spacing_m,
        missing_probability,
        position_sigma_m,
        trunk_height_m,
        trunk_height_sigma_m,
        trunk_diameter_m,
        trunk_diameter_sigma_m,
        canopy_height_m,
        canopy_width_m,
        canopy_size_sigma_rel,
    ] {
        w.f64(*v);
    }
    let TerrainParams {
        cell_m,
        margin_m,
        slope_along_deg,
        slope_across_deg,
        undulation_m,
        undulation_wavelength_m,
        roughness_m,
        roughness_wavelength_m,
    } = terrain;
    for v in [
        cell_m,
        margin_m,
        slope_along_deg,
        slope_across_deg,
        undulation_m,
        undulation_wavelength_m,
        roughness_m,
        roughness_wavelength_m,
    ] {
        w.f64(*v);
    }
    let HeadlandsParams { width_m } = headlands;
    w.f64(*width_m);

    let RowLayout {
        count,
        length_m,
        spacing_m,
        yaw_rad,
        curvature_per_m,
    } = &world.layout;
    w.u32(*count);
    for v in [length_m, spacing_m, yaw_rad, curvature_per_m] {
        w.f64(*v);
    }

    let Terrain {
        origin_x_m,
        origin_y_m,
        cell_m,
        nx,
        ny,
        heights,
    } = &world.terrain;
    for v in [origin_x_m, origin_y_m, cell_m] {
        w.f64(*v);
    }
    w.len(*nx);
    w.len(*ny);
    w.f64s(heights);

    w.len(world.posts.len());
    for Post {
        row,
        base_in_world,
        height_m,
        diameter_m,
    } in &world.posts
    {
        w.u32(*row);
        w.vec3(base_in_world);
        w.f64(*height_m);
        w.f64(*diameter_m);
    }
    w.len(world.wires.len());
    for Wire {
        row,
        height_m,
        points_in_world,
    } in &world.wires
    {
        w.u32(*row);
        w.f64(*height_m);
        w.len(points_in_world.len());
        for p in points_in_world {
            w.vec3(p);
        }
    }
    w.len(world.plants.len());
    for plant in &world.plants {
        let Plant {
            row,
            slot,
            base_in_world,
            trunk_height_m,
            trunk_diameter_m,
            canopy_height_m,
            canopy_width_m,
            appearance_seed,
        } = plant;
        w.u32(*row);
        w.u32(*slot);
        w.vec3(base_in_world);
        for v in [
            trunk_height_m,
            trunk_diameter_m,
            canopy_height_m,
            canopy_width_m,
        ] {
            w.f64(*v);
        }
        w.u64(*appearance_seed);
    }
    w.len(world.tags.len());
    for TagBoard {
        id,
        size_m,
        world_from_tag,
    } in &world.tags
    {
        w.u32(*id);
        w.f64(*size_m);
        w.pose(world_from_tag);
    }
    w.len(world.occluders.len());
    for Occluder {
        size_m,
        world_from_box,
    } in &world.occluders
    {
        w.vec3(size_m);
        w.pose(world_from_box);
    }
    let bytes: [u8; 32] = w.0.finalize().into();
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Surface;

    fn defaults() -> WorldParams {
        WorldParams::default()
    }

    /// A big, cheap world for statistics: 20 rows × 500 m of flat ground on 2 m cells.
    fn statistics_params() -> WorldParams {
        let mut p = defaults();
        p.rows.count = 20;
        p.rows.length_m = 500.0;
        p.rows.yaw_deg = 0.0;
        p.terrain.cell_m = 2.0;
        p.terrain.margin_m = 5.0;
        p.terrain.undulation_m = 0.0;
        p.terrain.roughness_m = 0.0;
        p
    }

    #[test]
    fn same_seed_same_world_and_digest() {
        let a = World::generate(1, &defaults()).unwrap();
        let b = World::generate(1, &defaults()).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.digest(), b.digest());
        assert_eq!(a.digest().len(), 64);
        assert!(a.digest().bytes().all(|c| c.is_ascii_hexdigit()));
        let c = World::generate(2, &defaults()).unwrap();
        assert_ne!(a.digest(), c.digest());
        assert_ne!(a.terrain, c.terrain);
        assert_ne!(a.plants, c.plants);
    }

    #[test]
    fn plant_parameters_do_not_change_the_terrain_or_posts() {
        let a = World::generate(1, &defaults()).unwrap();
        let mut p = defaults();
        p.plants.missing_probability = 0.3;
        let b = World::generate(1, &p).unwrap();
        assert_ne!(a.digest(), b.digest());
        assert_eq!(a.terrain, b.terrain);
        assert_eq!(a.posts, b.posts);
        assert_eq!(a.wires, b.wires);
        assert!(b.plants.len() < a.plants.len());
        // Every slot draws the same numbers whether or not it is empty, so the vines
        // present in both worlds are identical.
        for plant in &b.plants {
            let same = a
                .plants
                .iter()
                .find(|q| q.row == plant.row && q.slot == plant.slot);
            assert_eq!(same, Some(plant));
        }
    }

    #[test]
    fn every_parameter_changes_the_digest() {
        let base = World::generate(1, &defaults()).unwrap().digest();
        let changes: Vec<fn(&mut WorldParams)> = vec![
            |p| p.rows.count = 5,
            |p| p.rows.length_m = 119.0,
            |p| p.rows.spacing_m = 2.4,
            |p| p.rows.yaw_deg = 24.0,
            |p| p.rows.curvature_per_m = 0.001,
            |p| p.posts.spacing_m = 5.0,
            |p| p.posts.height_m = 2.0,
            |p| p.posts.diameter_m = 0.1,
            |p| p.posts.wire_heights_m.push(1.8),
            |p| p.plants.spacing_m = 1.1,
            |p| p.plants.missing_probability = 0.05,
            |p| p.plants.position_sigma_m = 0.04,
            |p| p.plants.trunk_height_m = 0.8,
            |p| p.plants.trunk_height_sigma_m = 0.0,
            |p| p.plants.trunk_diameter_m = 0.05,
            |p| p.plants.trunk_diameter_sigma_m = 0.02,
            |p| p.plants.canopy_height_m = 1.1,
            |p| p.plants.canopy_width_m = 0.6,
            |p| p.plants.canopy_size_sigma_rel = 0.1,
            |p| p.terrain.cell_m = 0.6,
            |p| p.terrain.margin_m = 15.0,
            |p| p.terrain.slope_along_deg = 1.0,
            |p| p.terrain.slope_across_deg = 1.0,
            |p| p.terrain.undulation_m = 0.3,
            |p| p.terrain.undulation_wavelength_m = 50.0,
            |p| p.terrain.roughness_m = 0.03,
            |p| p.terrain.roughness_wavelength_m = 2.0,
            |p| p.headlands.width_m = 9.0,
        ];
        let mut seen = vec![base];
        for change in changes {
            let mut p = defaults();
            change(&mut p);
            let d = World::generate(1, &p).unwrap().digest();
            assert!(!seen.contains(&d), "{p:?}");
            seen.push(d);
        }
    }

    #[test]
    fn posts_per_row_follow_the_closed_form() {
        // Ends always; regular posts every spacing up to half a spacing before the end.
        for (length, expect_per_row) in [
            (120.0, 21),
            (121.0, 21),
            (124.0, 22),
            (2.0, 2),
            (8.9, 2),
            (9.1, 3),
        ] {
            let mut p = defaults();
            p.rows.length_m = length;
            let w = World::generate(3, &p).unwrap();
            let closed_form = 2 + (length / p.posts.spacing_m - 0.5).floor().max(0.0) as usize;
            assert_eq!(closed_form, expect_per_row);
            assert_eq!(
                w.posts.len(),
                expect_per_row * p.rows.count as usize,
                "length {length}"
            );
            for row in 0..p.rows.count {
                let stations: Vec<f64> = w
                    .posts
                    .iter()
                    .filter(|q| q.row == row)
                    .map(|q| w.layout.row_coords(&q.base_in_world.xy()).1)
                    .collect();
                assert!(
                    stations[0].abs() < 1e-9
                        && (stations[stations.len() - 1] - length).abs() < 1e-9
                );
                for pair in stations.windows(2) {
                    let gap = pair[1] - pair[0];
                    // (A row shorter than half a spacing has only its two end posts.)
                    let min_gap = (0.5 * p.posts.spacing_m).min(length);
                    assert!(gap >= min_gap - 1e-9 && gap < 1.5 * p.posts.spacing_m + 1e-9);
                }
            }
        }
    }

    #[test]
    fn posts_wires_and_trunks_sit_on_the_terrain_in_their_rows() {
        let mut p = defaults();
        p.rows.curvature_per_m = 0.003;
        p.terrain.slope_across_deg = 4.0;
        let w = World::generate(9, &p).unwrap();
        for post in &w.posts {
            let b = post.base_in_world;
            assert_eq!(b.z, w.terrain.sample(b.x, b.y).height_m);
            let (offset, _) = w.layout.row_coords(&b.xy());
            assert!((offset - w.layout.row_offset_m(post.row)).abs() < 1e-9);
        }
        assert_eq!(
            w.wires.len(),
            p.rows.count as usize * p.posts.wire_heights_m.len()
        );
        for wire in &w.wires {
            let posts: Vec<&Post> = w.posts.iter().filter(|q| q.row == wire.row).collect();
            assert_eq!(wire.points_in_world.len(), posts.len());
            for (pt, post) in wire.points_in_world.iter().zip(posts) {
                assert_eq!(pt.xy(), post.base_in_world.xy());
                assert!((pt.z - post.base_in_world.z - wire.height_m).abs() < 1e-12);
            }
        }
        for plant in &w.plants {
            let b = plant.base_in_world;
            assert_eq!(b.z, w.terrain.sample(b.x, b.y).height_m);
            let (offset, s) = w.layout.row_coords(&b.xy());
            // Within 6σ of the nominal spot.
            assert!(
                (offset - w.layout.row_offset_m(plant.row)).abs() < 6.0 * p.plants.position_sigma_m
            );
            let s_nominal = p.plants.spacing_m * (0.5 + f64::from(plant.slot));
            assert!((s - s_nominal).abs() < 6.0 * p.plants.position_sigma_m / 0.9);
            assert!(plant.trunk_height_m > 0.0 && plant.trunk_diameter_m > 0.0);
            assert!(plant.canopy_height_m > 0.0 && plant.canopy_width_m > 0.0);
        }
    }

    #[test]
    fn missing_fraction_is_binomial() {
        let mut p = statistics_params();
        p.plants.missing_probability = 0.2;
        let w = World::generate(4, &p).unwrap();
        let per_row = (p.rows.length_m / p.plants.spacing_m - 0.5).ceil() as usize;
        let slots = per_row * p.rows.count as usize;
        assert_eq!(slots, 10_000);
        let missing = (slots - w.plants.len()) as f64;
        let (n, q) = (slots as f64, p.plants.missing_probability);
        let sd = (n * q * (1.0 - q)).sqrt();
        assert!((missing - n * q).abs() < 4.0 * sd, "{missing} of {n}");
        // Slots are unique and in order within each row.
        for pair in w.plants.windows(2) {
            assert!((pair[0].row, pair[0].slot) < (pair[1].row, pair[1].slot));
        }
        // No vine without missing probability.
        p.plants.missing_probability = 0.0;
        assert_eq!(World::generate(4, &p).unwrap().plants.len(), slots);
    }

    #[test]
    fn trunk_positions_spread_by_position_sigma() {
        for k in [0.0, 0.004] {
            let mut p = statistics_params();
            p.rows.length_m = 250.0;
            p.rows.count = 40;
            p.rows.curvature_per_m = k;
            p.headlands.width_m = 2.0;
            p.plants.missing_probability = 0.0;
            p.plants.position_sigma_m = 0.05;
            let w = World::generate(5, &p).unwrap();
            let (mut across, mut along) = (Vec::new(), Vec::new());
            for plant in &w.plants {
                let offset = w.layout.row_offset_m(plant.row);
                let (o, s) = w.layout.row_coords(&plant.base_in_world.xy());
                across.push(o - offset);
                // Row-0 arc length back to metres along this row.
                let s_nominal = p.plants.spacing_m * (0.5 + f64::from(plant.slot));
                along.push((s - s_nominal) * (1.0 - k * offset));
            }
            // N = 10 000 normal samples: the sample std has a relative standard error of
            // 1/√(2N) = 0.7 %, the mean a standard error of σ/√N = 0.0005 m. Bounds at
            // about 5 standard errors.
            for v in [&across, &along] {
                let n = v.len() as f64;
                assert_eq!(n, 10_000.0);
                let mean = v.iter().sum::<f64>() / n;
                let std = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
                assert!(mean.abs() < 5.0 * 0.05 / n.sqrt(), "k {k}: mean {mean}");
                assert!((std / 0.05 - 1.0).abs() < 0.035, "k {k}: std {std}");
            }
        }
    }

    #[test]
    fn sizes_follow_their_means_and_stay_positive() {
        let mut p = statistics_params();
        p.plants.trunk_height_sigma_m = 0.05;
        p.plants.canopy_size_sigma_rel = 0.15;
        let w = World::generate(6, &p).unwrap();
        let n = w.plants.len() as f64;
        let mean = |f: fn(&Plant) -> f64| w.plants.iter().map(f).sum::<f64>() / n;
        // Standard errors: 0.05/√9600 ≈ 5e-4 m, 0.15·1.0/√9600 ≈ 1.5e-3 m.
        assert!((mean(|q| q.trunk_height_m) - 0.7).abs() < 0.003);
        assert!((mean(|q| q.canopy_height_m) - 1.0).abs() < 0.008);
        assert!((mean(|q| q.canopy_width_m) - 0.5).abs() < 0.004);
        // A sigma far larger than the mean hits the floor instead of going negative.
        p.plants.trunk_diameter_sigma_m = 1.0;
        let w = World::generate(6, &p).unwrap();
        let floor = SIZE_FLOOR_FRACTION * p.plants.trunk_diameter_m;
        assert!(w.plants.iter().all(|q| q.trunk_diameter_m >= floor));
        assert!(w.plants.iter().any(|q| q.trunk_diameter_m == floor));
    }

    /// Puts one bad value into the parameters.
    type Spoil = fn(&mut WorldParams);

    #[test]
    fn bad_parameters_name_their_path() {
        let cases: Vec<(&str, Spoil)> = vec![
            ("world.rows.count", |p| p.rows.count = 0),
            ("world.rows.length_m", |p| p.rows.length_m = f64::INFINITY),
            ("world.rows.spacing_m", |p| p.rows.spacing_m = -2.5),
            ("world.rows.yaw_deg", |p| p.rows.yaw_deg = f64::NAN),
            ("world.rows.curvature_per_m", |p| {
                p.rows.curvature_per_m = 0.025
            }),
            ("world.rows.curvature_per_m", |p| {
                p.rows.length_m = 1000.0;
                p.rows.curvature_per_m = -0.004;
            }),
            ("world.posts.spacing_m", |p| p.posts.spacing_m = 0.0),
            ("world.posts.height_m", |p| p.posts.height_m = 0.0),
            ("world.posts.diameter_m", |p| p.posts.diameter_m = -0.1),
            ("world.posts.wire_heights_m", |p| {
                p.posts.wire_heights_m = vec![0.7, 2.0]
            }),
            ("world.posts.wire_heights_m", |p| {
                p.posts.wire_heights_m = vec![0.0]
            }),
            ("world.plants.spacing_m", |p| p.plants.spacing_m = 0.0),
            ("world.plants.missing_probability", |p| {
                p.plants.missing_probability = 1.0
            }),
            ("world.plants.missing_probability", |p| {
                p.plants.missing_probability = -0.1
            }),
            ("world.plants.position_sigma_m", |p| {
                p.plants.position_sigma_m = -0.01
            }),
            ("world.plants.trunk_height_m", |p| {
                p.plants.trunk_height_m = 0.0
            }),
            ("world.plants.trunk_diameter_sigma_m", |p| {
                p.plants.trunk_diameter_sigma_m = f64::NAN
            }),
            ("world.plants.canopy_width_m", |p| {
                p.plants.canopy_width_m = 0.0
            }),
            ("world.plants.canopy_size_sigma_rel", |p| {
                p.plants.canopy_size_sigma_rel = -1.0
            }),
            ("world.terrain.cell_m", |p| p.terrain.cell_m = 0.0),
            ("world.terrain.slope_across_deg", |p| {
                p.terrain.slope_across_deg = -50.0
            }),
            ("world.terrain.roughness_m", |p| {
                p.terrain.roughness_m = -0.02
            }),
            ("world.headlands.width_m", |p| p.headlands.width_m = -8.0),
        ];
        for (path, spoil) in cases {
            let mut p = defaults();
            spoil(&mut p);
            let err = World::generate(1, &p).unwrap_err();
            assert_eq!(err.path, path, "{err}");
            assert!(!err.expected.is_empty() && !err.found.is_empty());
        }
    }
}
