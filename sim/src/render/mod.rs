//! Rendering: camera images of the vineyard by CPU ray casting.
//!
//! - [`trace`]: the ray-casting seam ([`RayCaster`], ray packets and hits) and the
//!   synthetic vegetation scene its throughput is measured on.
//! - [`bvh`]: the default pure-Rust backend ([`build_default`]), a two-level wide BVH
//!   traversed with common-origin ray packets; `embree` (cargo feature) the other one.
//! - [`camera`]: pinhole cameras with Brown-Conrady distortion, camera profiles, the
//!   D435 depth error model and image noise.
//!
//! Geometry handed to a [`RayCaster`] is a [`TraceScene`]: triangle meshes in their own
//! frames and instances placing them in the scene frame. The scene frame is the world
//! frame shifted by [`TraceScene::origin_in_world`] so `f32` keeps sub-millimetre
//! precision over the whole vineyard.

pub mod blur;
pub mod bvh;
pub mod camera;
pub mod depth_light;
#[cfg(feature = "embree")]
pub mod embree;
pub mod exposure;
pub mod scene;
pub mod shade;
pub mod tag;
pub mod texture;
pub mod trace;

pub use trace::{Hit, RayCaster, RayPacket};

/// Most vertices of the rendered ground mesh (`render.terrain_cell_m` over the terrain);
/// the default vineyard at 0.25 m has about 0.2 M.
pub const MAX_TERRAIN_VERTICES: usize = 4_000_000;

/// Builds the default backend for a scene: the two-level wide BVH of [`bvh`] (name `bvh`).
pub fn build_default(scene: &TraceScene) -> Box<dyn RayCaster> {
    Box::new(bvh::TwoLevelBvh::build(scene))
}

/// A triangle mesh in its own frame, as the ray caster sees it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshGeometry {
    /// Vertex positions, m.
    pub positions: Vec<[f32; 3]>,
    /// Triangles as indices into `positions`, counter-clockwise seen from the front.
    pub indices: Vec<[u32; 3]>,
}

/// An affine map `y = m·x + t` stored row-major as three rows `[m_r0, m_r1, m_r2, t_r]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Affine3 {
    /// Rows of the 3×4 matrix `[m | t]`.
    pub rows: [[f32; 4]; 3],
}

impl Affine3 {
    /// The identity map.
    pub const IDENTITY: Affine3 = Affine3 {
        rows: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
    };

    /// Applies the map to a point.
    pub fn point(&self, p: [f32; 3]) -> [f32; 3] {
        let r = &self.rows;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + r[0][3],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + r[1][3],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + r[2][3],
        ]
    }

    /// Applies the linear part to a vector.
    pub fn vector(&self, v: [f32; 3]) -> [f32; 3] {
        let r = &self.rows;
        [
            r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
        ]
    }

    /// The inverse map, computed in `f64`; `None` when the linear part is singular.
    pub fn inverse(&self) -> Option<Affine3> {
        let m = nalgebra::Matrix3::from_fn(|i, j| f64::from(self.rows[i][j]));
        let t = nalgebra::Vector3::from_fn(|i, _| f64::from(self.rows[i][3]));
        let mi = m.try_inverse()?;
        let ti = -(mi * t);
        Some(Affine3 {
            rows: std::array::from_fn(|i| {
                [
                    mi[(i, 0)] as f32,
                    mi[(i, 1)] as f32,
                    mi[(i, 2)] as f32,
                    ti[i] as f32,
                ]
            }),
        })
    }
}

/// One placement of a mesh in the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    /// Index into [`TraceScene::meshes`].
    pub mesh: u32,
    /// Scene frame from the mesh's frame; any invertible affine map (rotation, translation
    /// and per-axis scale are what the vineyard uses).
    pub scene_from_mesh: Affine3,
}

/// Everything a [`RayCaster`] intersects.
#[derive(Clone, Debug, Default)]
pub struct TraceScene {
    /// World position of the scene frame's origin (the scene frame is the world frame
    /// translated by this), m.
    pub origin_in_world: nalgebra::Vector3<f64>,
    /// Prototype meshes.
    pub meshes: Vec<MeshGeometry>,
    /// Placements; a [`Hit`] names the instance by its index here.
    pub instances: Vec<Instance>,
}

/// Builds the renderer of a world: render geometry, the `[render] backend` ray caster,
/// textures and the sun's shadow map. Fails with the dotted path of the first `[render]`
/// value that cannot be used.
pub fn build_renderer(
    world: &crate::world::World,
    p: &crate::params::RenderParams,
) -> Result<shade::Renderer, crate::params::ParamError> {
    build_renderer_with_mesh(world, p, None)
}

/// [`build_renderer`] with `mesh` (the loaded `[world.mesh]` file) in place of the
/// generated geometry ([`scene::build_with_mesh`]; `world.params.mesh.keep_ground` says
/// whether the generated ground stays).
pub fn build_renderer_with_mesh(
    world: &crate::world::World,
    p: &crate::params::RenderParams,
    mesh: Option<&scene::WorldMesh>,
) -> Result<shade::Renderer, crate::params::ParamError> {
    let SceneGeometry { scene, caster } = build_geometry(world, p, mesh)?;
    let light = shade::Lighting {
        to_sun: shade::Lighting::sun_direction(p.sun_azimuth_deg, p.sun_elevation_deg),
        sun: p.sun_irradiance as f32,
        sky: p.sky_irradiance as f32,
        exposure: p.exposure as f32,
        sun_glare: p.sun_glare,
    };
    Ok(shade::Renderer::new(
        scene,
        caster,
        light,
        p.shadow_cell_m,
        world.seed,
    ))
}

/// The render geometry and its `[render] backend` ray caster, without lights, textures
/// or shadows: what the GNSS sky model traces its lines of sight through.
pub struct SceneGeometry {
    /// The geometry.
    pub scene: scene::RenderScene,
    /// Its ray caster.
    pub caster: Box<dyn RayCaster>,
}

/// Builds the [`SceneGeometry`] of a world (`mesh` as in [`build_renderer_with_mesh`]).
pub fn build_geometry(
    world: &crate::world::World,
    p: &crate::params::RenderParams,
    mesh: Option<&scene::WorldMesh>,
) -> Result<SceneGeometry, crate::params::ParamError> {
    use crate::params::{ParamError, RenderBackend};
    validate(p)?;
    let (lo, hi) = world.terrain.domain();
    let vertices = (((hi.x - lo.x) / p.terrain_cell_m).ceil() + 1.0)
        * (((hi.y - lo.y) / p.terrain_cell_m).ceil() + 1.0);
    if vertices.is_nan() || vertices > MAX_TERRAIN_VERTICES as f64 {
        return Err(ParamError::new(
            "render.terrain_cell_m",
            format!(
                "a cell size giving at most {MAX_TERRAIN_VERTICES} ground vertices \
                 (MAX_TERRAIN_VERTICES) over the terrain's {:.0} m × {:.0} m, i.e. at least \
                 {:.3} m",
                hi.x - lo.x,
                hi.y - lo.y,
                ((hi.x - lo.x) * (hi.y - lo.y) / MAX_TERRAIN_VERTICES as f64).sqrt()
            ),
            format!("{} ({vertices:.0} vertices)", p.terrain_cell_m),
        ));
    }
    let opts = scene::GeometryOptions {
        terrain_cell_m: p.terrain_cell_m,
    };
    let scene = match mesh {
        Some(m) => {
            m.validate()
                .map_err(|e| ParamError::new("world.mesh.file", "a valid triangle mesh", e))?;
            scene::build_with_mesh(world, &opts, m, world.params.mesh.keep_ground)
        }
        None => scene::build(world, &opts),
    };
    let caster: Box<dyn RayCaster> = match p.backend {
        RenderBackend::Bvh => build_default(&scene.trace),
        #[cfg(feature = "embree")]
        RenderBackend::Embree => {
            Box::new(embree::EmbreeCaster::new(&scene.trace).map_err(|e| {
                ParamError::new(
                    "render.backend",
                    "an Embree device that builds the scene",
                    e,
                )
            })?)
        }
        #[cfg(not(feature = "embree"))]
        RenderBackend::Embree => {
            return Err(ParamError::new(
                "render.backend",
                "\"bvh\" (this build has no Embree: build with `--features embree`)",
                "\"embree\"",
            ));
        }
    };
    Ok(SceneGeometry { scene, caster })
}

/// Checks every `[render]` value; the first problem comes back with its dotted path.
pub fn validate(p: &crate::params::RenderParams) -> Result<(), crate::params::ParamError> {
    use crate::params::require_in;
    require_in("render.terrain_cell_m", p.terrain_cell_m, 0.02, 5.0)?;
    require_in("render.shadow_cell_m", p.shadow_cell_m, 0.005, 1.0)?;
    require_in("render.sun_azimuth_deg", p.sun_azimuth_deg, -360.0, 360.0)?;
    require_in("render.sun_elevation_deg", p.sun_elevation_deg, 1.0, 90.0)?;
    require_in("render.sun_irradiance", p.sun_irradiance, 0.0, 100.0)?;
    require_in("render.sky_irradiance", p.sky_irradiance, 0.0, 100.0)?;
    require_in("render.exposure", p.exposure, 0.0, 1000.0)?;
    require_in("render.read_noise", p.read_noise, 0.0, 1.0)?;
    require_in("render.shot_gain", p.shot_gain, 0.0, 1.0)?;
    Ok(())
}

#[cfg(test)]
mod tests;
