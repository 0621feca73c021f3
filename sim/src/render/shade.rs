//! Shading: what a camera pixel sees where its ray hits the [`RenderScene`].
//!
//! Lambert surfaces lit by the sun and the sky: `L = ρ · (E_sun · max(0, n·s) · V + E_sky ·
//! (0.6 + 0.4 n_z))`, where `V` is the sun's visibility from a shadow map rendered once
//! per scene (an orthographic depth map along the sun direction over everything that
//! casts shadows, looked up with 2×2 percentage-closer filtering), not a shadow ray per
//! pixel. Leaves are two-sided and translucent: a blade lit from behind transmits part of
//! the sunlight. Rays that miss see a sky that brightens towards the horizon, with the sun
//! disc and its glare when enabled. Albedo comes from baked textures ([`super::texture`],
//! trilinear with the level of detail of the pixel's footprint) and tag36h11 boards
//! ([`super::tag`]).
//!
//! The output is linear radiance times the exposure (1 = white paper in full sun), plus
//! the range along each ray; the camera sensors add noise and encode.

use super::camera::RayTable;
use super::scene::{Material, RenderScene};
use super::tag::tag_board_albedo;
use super::texture::{self, Texture, TextureKind};
use super::trace::{Hit, PACKET_SIZE, RayCaster, RayPacket};
use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;

/// Light and exposure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lighting {
    /// Unit vector from the scene towards the sun, world (ENU) frame.
    pub to_sun: Vector3<f64>,
    /// Irradiance of direct sunlight on a surface facing the sun (relative units).
    pub sun: f32,
    /// Irradiance from the sky on an upward-facing surface (relative units).
    pub sky: f32,
    /// Multiplier from radiance to the linear pixel value.
    pub exposure: f32,
    /// Draw the sun disc and its glare when it is in view.
    pub sun_glare: bool,
}

impl Lighting {
    /// Sun direction from its compass azimuth (degrees clockwise from north) and elevation
    /// above the horizon.
    pub fn sun_direction(azimuth_deg: f64, elevation_deg: f64) -> Vector3<f64> {
        let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
        Vector3::new(az.sin() * el.cos(), az.cos() * el.cos(), el.sin())
    }
}

/// A depth map along the sun direction (see the module docs).
#[derive(Clone, Debug)]
pub struct ShadowMap {
    /// Unit vector towards the sun, scene frame.
    to_sun: [f32; 3],
    /// Map axes perpendicular to `to_sun`.
    axis_a: [f32; 3],
    axis_b: [f32; 3],
    /// Map coordinates of texel (0, 0)'s corner.
    a0: f32,
    b0: f32,
    cell_m: f32,
    width: usize,
    height: usize,
    /// Per texel: the largest `to_sun · p` of anything the sun ray hits (−∞ for none).
    lit_level: Vec<f32>,
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl ShadowMap {
    /// Renders the map over the scene's shadow casters with `cell_m` texels. Rows in
    /// parallel; deterministic.
    pub fn bake(
        scene: &RenderScene,
        caster: &dyn RayCaster,
        to_sun: Vector3<f64>,
        cell_m: f64,
    ) -> ShadowMap {
        let s = to_sun.normalize();
        let a = if s.z.abs() < 0.99 {
            Vector3::z().cross(&s).normalize()
        } else {
            Vector3::x()
        };
        let b = s.cross(&a);
        let f3 = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
        let (lo, hi) = scene.caster_bounds;
        let mut amin = f64::INFINITY;
        let mut amax = f64::NEG_INFINITY;
        let mut bmin = f64::INFINITY;
        let mut bmax = f64::NEG_INFINITY;
        let mut smax = f64::NEG_INFINITY;
        for k in 0..8 {
            let c = Vector3::new(
                f64::from(if k & 1 == 0 { lo[0] } else { hi[0] }),
                f64::from(if k & 2 == 0 { lo[1] } else { hi[1] }),
                f64::from(if k & 4 == 0 { lo[2] } else { hi[2] }),
            );
            amin = amin.min(c.dot(&a));
            amax = amax.max(c.dot(&a));
            bmin = bmin.min(c.dot(&b));
            bmax = bmax.max(c.dot(&b));
            smax = smax.max(c.dot(&s));
        }
        let width = (((amax - amin) / cell_m).ceil().max(1.0) as usize).min(1 << 15);
        let height = (((bmax - bmin) / cell_m).ceil().max(1.0) as usize).min(1 << 15);
        let start = smax + 1.0;
        let dir = f3(-s);
        let mut lit_level = vec![f32::NEG_INFINITY; width * height];
        lit_level
            .par_chunks_mut(width)
            .enumerate()
            .for_each(|(j, row)| {
                let bj = bmin + (j as f64 + 0.5) * cell_m;
                for (i, out) in row.iter_mut().enumerate() {
                    let ai = amin + (i as f64 + 0.5) * cell_m;
                    let o = a * ai + b * bj + s * start;
                    let hit = caster.cast_ray(f3(o), dir, 0.0, f32::INFINITY);
                    if hit.is_hit() {
                        *out = (start - f64::from(hit.t)) as f32;
                    }
                }
            });
        ShadowMap {
            to_sun: f3(s),
            axis_a: f3(a),
            axis_b: f3(b),
            a0: amin as f32,
            b0: bmin as f32,
            cell_m: cell_m as f32,
            width,
            height,
            lit_level,
        }
    }

    /// Fraction of the sun visible from scene point `p` (0 shadowed .. 1 lit), 2×2 PCF.
    pub fn visibility(&self, p: [f32; 3], bias_m: f32) -> f32 {
        let x = (dot(p, self.axis_a) - self.a0) / self.cell_m - 0.5;
        let y = (dot(p, self.axis_b) - self.b0) / self.cell_m - 0.5;
        let level = dot(p, self.to_sun) + bias_m;
        let fl = |v: f32| {
            let i = v as i64 as f32;
            if i > v { i - 1.0 } else { i }
        };
        let (xf, yf) = (fl(x), fl(y));
        let (fx, fy) = (x - xf, y - yf);
        let (x0, y0) = (xf as i64, yf as i64);
        let lit = |xi: i64, yi: i64| -> f32 {
            if xi < 0 || yi < 0 || xi >= self.width as i64 || yi >= self.height as i64 {
                return 1.0;
            }
            let l = self.lit_level[yi as usize * self.width + xi as usize];
            if level >= l { 1.0 } else { 0.0 }
        };
        let top = lit(x0, y0) * (1.0 - fx) + lit(x0 + 1, y0) * fx;
        let bottom = lit(x0, y0 + 1) * (1.0 - fx) + lit(x0 + 1, y0 + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        self.lit_level.len() * 4
    }
}

/// Baked textures with their texel size in metres, indexed by `TextureKind as usize`
/// (the order of [`TextureKind::ALL`]).
#[derive(Clone, Debug)]
struct Textures {
    by_kind: Vec<(Texture, f32)>,
}

impl Textures {
    fn bake(seed: u64) -> Textures {
        debug_assert!(
            TextureKind::ALL
                .iter()
                .enumerate()
                .all(|(i, k)| *k as usize == i),
            "TextureKind::ALL lists the kinds in declaration order"
        );
        let by_kind = TextureKind::ALL
            .par_iter()
            .map(|&k| {
                let t = texture::bake(k, k.recommended_size(), seed);
                // Texel size in metres, for the level of detail.
                let texel_m = k.period_m() / t.width as f32;
                (t, texel_m)
            })
            .collect();
        Textures { by_kind }
    }

    fn get(&self, k: TextureKind) -> (&Texture, f32) {
        let (t, m) = &self.by_kind[k as usize];
        (t, *m)
    }

    fn memory_bytes(&self) -> usize {
        self.by_kind.iter().map(|(t, _)| t.memory_bytes()).sum()
    }
}

/// Output of one render: linear pixel values (RGB, row-major) and the range along each
/// pixel's ray (0 where it hit nothing within range).
#[derive(Clone, Debug, Default)]
pub struct Frame {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Linear RGB, 3 values per pixel.
    pub linear: Vec<f32>,
    /// Depth along the optical axis (range · ray z), m; 0 = no hit.
    pub depth_m: Vec<f32>,
    /// Irradiance on the surface each pixel sees, in the [`Lighting`]'s relative units
    /// (sun and sky, shadows included, before albedo and exposure: 1 makes white paper
    /// full scale at exposure 1); 0 = no hit. The stereo depth model's ambient light
    /// ([`super::camera::SunlightStereo`]).
    pub irradiance: Vec<f32>,
}

impl Frame {
    /// The frame's images, for [`super::depth_light::SunlightStereo::snr`].
    pub fn view(&self) -> super::depth_light::FrameView<'_> {
        super::depth_light::FrameView {
            width: self.width,
            height: self.height,
            linear: &self.linear,
            depth_m: &self.depth_m,
            irradiance: &self.irradiance,
        }
    }

    /// A frame for images of `width × height`.
    pub fn new(width: u32, height: u32) -> Frame {
        let n = width as usize * height as usize;
        Frame {
            width,
            height,
            linear: vec![0.0; 3 * n],
            depth_m: vec![0.0; n],
            irradiance: vec![0.0; n],
        }
    }
}

/// Renders camera images of one scene.
pub struct Renderer {
    scene: RenderScene,
    caster: Box<dyn RayCaster>,
    textures: Textures,
    shadow: ShadowMap,
    light: Lighting,
    to_sun_scene: [f32; 3],
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("backend", &self.caster.name())
            .field("triangles", &self.scene.stored_triangles())
            .finish()
    }
}

/// Tile edge, px (a tile is one [`RayPacket`]).
const TILE: u32 = 8;

impl Renderer {
    /// Bakes the textures (from `texture_seed`) and the shadow map (`shadow_cell_m`
    /// texels) for `scene`, traced by `caster`.
    pub fn new(
        scene: RenderScene,
        caster: Box<dyn RayCaster>,
        light: Lighting,
        shadow_cell_m: f64,
        texture_seed: u64,
    ) -> Renderer {
        let textures = Textures::bake(texture_seed);
        let shadow = ShadowMap::bake(&scene, caster.as_ref(), light.to_sun, shadow_cell_m);
        let s = light.to_sun.normalize();
        Renderer {
            scene,
            caster,
            textures,
            shadow,
            light,
            to_sun_scene: [s.x as f32, s.y as f32, s.z as f32],
        }
    }

    /// The scene.
    pub fn scene(&self) -> &RenderScene {
        &self.scene
    }

    /// The ray caster.
    pub fn caster(&self) -> &dyn RayCaster {
        self.caster.as_ref()
    }

    /// Bytes held by the scene, acceleration structure, textures and shadow map.
    pub fn memory_bytes(&self) -> usize {
        self.scene.memory_bytes()
            + self.caster.memory_bytes()
            + self.textures.memory_bytes()
            + self.shadow.memory_bytes()
    }

    /// Renders the view of a camera whose pixel rays are `rays` (optical frame) at
    /// `world_from_camera`; `pixel_angle_rad` is the angle one pixel subtends (for texture
    /// filtering), `max_range_m` the farthest hit reported. Rows of 8×8 tiles in parallel;
    /// the result does not depend on the thread count. `frame` must match the ray table's
    /// size; nothing is allocated.
    pub fn render(
        &self,
        rays: &RayTable,
        world_from_camera: &Isometry3<f64>,
        pixel_angle_rad: f32,
        max_range_m: f32,
        frame: &mut Frame,
    ) {
        assert_eq!(
            (frame.width, frame.height),
            (rays.width, rays.height),
            "frame and ray table sizes"
        );
        let width = rays.width as usize;
        let origin_scene = world_from_camera.translation.vector - self.scene.trace.origin_in_world;
        let origin = [
            origin_scene.x as f32,
            origin_scene.y as f32,
            origin_scene.z as f32,
        ];
        let r = world_from_camera.rotation.to_rotation_matrix();
        let rot: [[f32; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)] as f32));
        let band = TILE as usize * width;
        frame
            .linear
            .par_chunks_mut(3 * band)
            .zip(frame.depth_m.par_chunks_mut(band))
            .zip(frame.irradiance.par_chunks_mut(band))
            .enumerate()
            .for_each(|(ty, ((linear, depth), irradiance))| {
                let y0 = ty as u32 * TILE;
                let mut packet = RayPacket {
                    origin,
                    dir: [[0.0; PACKET_SIZE]; 3],
                    len: 0,
                    t_min: 0.0,
                    t_max: max_range_m,
                };
                let mut cam_dir = [[0.0f32; PACKET_SIZE]; 3];
                let mut hits = [Hit::MISS; PACKET_SIZE];
                for x0 in (0..rays.width).step_by(TILE as usize) {
                    let n = rays.fill_tile(x0, y0, TILE, TILE, &mut cam_dir);
                    let tile_w = TILE.min(rays.width - x0) as usize;
                    for (lane, ((x, y), z)) in cam_dir[0][..n]
                        .iter()
                        .zip(&cam_dir[1][..n])
                        .zip(&cam_dir[2][..n])
                        .enumerate()
                    {
                        for (k, row) in rot.iter().enumerate() {
                            packet.dir[k][lane] = dot(*row, [*x, *y, *z]);
                        }
                    }
                    packet.len = n;
                    self.caster.cast_packet(&packet, &mut hits);
                    for lane in 0..n {
                        let (lx, ly) = (lane % tile_w, lane / tile_w);
                        let px = (ly * width) + x0 as usize + lx;
                        let d = [
                            packet.dir[0][lane],
                            packet.dir[1][lane],
                            packet.dir[2][lane],
                        ];
                        let hit = &hits[lane];
                        let rgb = if hit.is_hit() {
                            depth[px] = hit.t * cam_dir[2][lane];
                            let (rgb, e) = self.shade(origin, d, hit, pixel_angle_rad);
                            irradiance[px] = e;
                            rgb
                        } else {
                            depth[px] = 0.0;
                            irradiance[px] = 0.0;
                            self.sky(d)
                        };
                        let e = self.light.exposure;
                        linear[3 * px] = rgb[0] * e;
                        linear[3 * px + 1] = rgb[1] * e;
                        linear[3 * px + 2] = rgb[2] * e;
                    }
                }
            });
    }

    /// Radiance of a miss in direction `d` (scene frame = world axes).
    fn sky(&self, d: [f32; 3]) -> [f32; 3] {
        let len = dot(d, d).sqrt().max(1e-12);
        let z = d[2] / len;
        let base = if z < 0.0 {
            // Below the horizon beyond the modelled ground: distant haze.
            [0.42, 0.43, 0.42]
        } else {
            let f = (1.0 - z).powi(3);
            let zenith = [0.18, 0.32, 0.75];
            let horizon = [0.72, 0.80, 0.90];
            std::array::from_fn(|k| zenith[k] + (horizon[k] - zenith[k]) * f)
        };
        if !self.light.sun_glare {
            return base;
        }
        let c = dot(d, self.to_sun_scene) / len;
        // Sun disc (0.27 deg radius) saturates anything; a glow around it.
        let disc = if c > 0.999_989 { 50.0 } else { 0.0 };
        let glow = 1.5 * exp_or_underflow(200.0 * (c - 1.0)) + 0.2 * (12.0 * (c - 1.0)).exp();
        std::array::from_fn(|k| base[k] + disc + glow)
    }

    /// Radiance of a hit, and the irradiance on the surface (sun and sky).
    fn shade(
        &self,
        origin: [f32; 3],
        d: [f32; 3],
        hit: &Hit,
        pixel_angle_rad: f32,
    ) -> ([f32; 3], f32) {
        let inst = hit.instance as usize;
        let mesh_index = self.scene.trace.instances[inst].mesh as usize;
        let sh = &self.scene.shading[mesh_index];
        let tri = self.scene.trace.meshes[mesh_index].indices[hit.prim as usize];
        let (u, v) = (hit.u, hit.v);
        let w = 1.0 - u - v;
        let nv = |k: usize| sh.normals[tri[k] as usize];
        let uvv = |k: usize| sh.uvs[tri[k] as usize];
        let n_mesh: [f32; 3] = std::array::from_fn(|i| w * nv(0)[i] + u * nv(1)[i] + v * nv(2)[i]);
        let uv: [f32; 2] = std::array::from_fn(|i| w * uvv(0)[i] + u * uvv(1)[i] + v * uvv(2)[i]);
        let nm = &self.scene.normal_from_mesh[inst];
        let mut n = [dot(nm[0], n_mesh), dot(nm[1], n_mesh), dot(nm[2], n_mesh)];
        let nl = dot(n, n).sqrt().max(1e-12);
        n = n.map(|c| c / nl);
        let mut back = false;
        if dot(n, d) > 0.0 {
            n = n.map(|c| -c);
            back = true;
        }
        let dl = dot(d, d).sqrt();
        let range = hit.t * dl;
        let p: [f32; 3] = std::array::from_fn(|i| origin[i] + d[i] * hit.t);
        let material = self.scene.material_of(hit);
        let tex = |k: TextureKind| {
            let (t, texel_m) = self.textures.get(k);
            let footprint = range * pixel_angle_rad / texel_m;
            t.sample_lod(uv[0], uv[1], footprint.max(1e-6).log2())
        };
        let albedo = match material {
            Material::Soil => tex(TextureKind::Soil),
            Material::Bark => tex(TextureKind::Bark),
            Material::Shoot => {
                let c = tex(TextureKind::Cordon);
                [c[0] * 0.7, c[1] * 1.25, c[2] * 0.55]
            }
            Material::Leaf => tex(if back {
                TextureKind::LeafUnderside
            } else {
                TextureKind::Leaf
            }),
            Material::GrapeRed => tex(TextureKind::Grape),
            Material::GrapeWhite => tex(TextureKind::GrapeWhite),
            Material::Post => tex(TextureKind::Post),
            Material::Wire => tex(TextureKind::Wire),
            Material::Carton => tex(TextureKind::Carton),
            Material::Tag => {
                let k = self.scene.instance_tag[inst];
                let a = self
                    .scene
                    .tag_ids
                    .get(k as usize)
                    .map_or(0.8, |&id| tag_board_albedo(id, uv[0], uv[1]));
                [a, a, a]
            }
            Material::Board => [0.8, 0.8, 0.8],
            Material::VertexColour => {
                let c = |k: usize| sh.colors.get(tri[k] as usize).copied().unwrap_or([0.5; 3]);
                let (c0, c1, c2) = (c(0), c(1), c(2));
                std::array::from_fn(|i| w * c0[i] + u * c1[i] + v * c2[i])
            }
        };
        let s = self.to_sun_scene;
        let ns = dot(n, s);
        let vis = if ns > 0.0 || material == Material::Leaf {
            self.shadow.visibility(p, 0.03 + 2.0 * self.shadow.cell_m)
        } else {
            0.0
        };
        let mut direct = self.light.sun * ns.max(0.0) * vis;
        if material == Material::Leaf && ns < 0.0 {
            // Light through the blade.
            direct += 0.35 * self.light.sun * (-ns) * vis;
        }
        let ambient = self.light.sky * (0.6 + 0.4 * n[2]);
        let e = direct + ambient;
        (albedo.map(|a| a * e), e)
    }
}

/// `x.exp()`, without the call where it is exactly `+0.0`: below `UNDERFLOWS_TO_ZERO`
/// `e^x` is under half of `f32`'s smallest subnormal (`e^-103.97`) and rounds to zero.
/// Most sky pixels are far from the sun, and the sun glow's narrow term took libm's slow
/// underflow path for each of them (1.5 % of a `camera-row` run's CPU). NaN still goes
/// to `exp`, so the result has the same bits as `x.exp()` for every `x`.
#[inline]
fn exp_or_underflow(x: f32) -> f32 {
    if x < UNDERFLOWS_TO_ZERO { 0.0 } else { x.exp() }
}

/// An exponent whose `exp` is `+0.0` in `f32`, with a margin (see [`exp_or_underflow`]).
const UNDERFLOWS_TO_ZERO: f32 = -110.0;

#[cfg(test)]
mod tests {
    use super::*;

    /// The premise of `exp_or_underflow`: `exp` is `+0.0` at and below the threshold (a
    /// sweep of every 4096th `f32` from there to the largest negative, and −∞), so the
    /// skipped call changes no bit; above it the call is made.
    #[test]
    fn exp_is_zero_below_the_threshold_and_called_above() {
        let mut bits = UNDERFLOWS_TO_ZERO.to_bits();
        while bits < f32::NEG_INFINITY.to_bits() {
            let x = f32::from_bits(bits);
            assert_eq!(x.exp().to_bits(), 0.0f32.to_bits(), "exp({x})");
            assert_eq!(exp_or_underflow(x).to_bits(), x.exp().to_bits(), "{x}");
            bits += 4096;
        }
        assert_eq!(f32::NEG_INFINITY.exp().to_bits(), 0.0f32.to_bits());
        for x in [-109.99f32, -103.0, -87.5, -1.0, 0.0, 3.0, f32::NAN] {
            assert_eq!(exp_or_underflow(x).to_bits(), x.exp().to_bits(), "{x}");
        }
        assert!(exp_or_underflow(-103.0) > 0.0);
    }
}
