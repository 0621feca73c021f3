//! Render geometry of a [`World`]: triangle meshes with materials, normals and texture
//! coordinates.
//!
//! - **Vines** are instances of a few canopy prototypes (shoots trained upright from the
//!   cordon, lobed leaf blades along them, grape bunches of berries below the cordon),
//!   each placed at its vine's cordon, turned with the row and scaled to the vine's own
//!   canopy height and width: a two-level scene, so a 10-row × 120 m vineyard costs the
//!   prototypes once plus one transform per vine.
//! - **Unique geometry** (trunks and cordon arms, which follow each vine's own trunk
//!   height, posts, wires, occluder boxes) is one static mesh; the ground is a second one,
//!   triangulated from the terrain at `[render] terrain_cell_m`.
//! - **AprilTag boards** are one small mesh each, so the shader knows the tag id from the
//!   instance.
//!
//! Positions are in the scene frame (the world frame shifted by
//! [`TraceScene::origin_in_world`], the centre of the terrain).

use super::{Affine3, Instance, MeshGeometry, TraceScene};
use crate::params::{CanopyParams, GrapeColour};
use crate::rng;
use crate::world::World;
use nalgebra::{Isometry3, Matrix3, Point3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{PI, TAU};

/// Surface kinds; each has its own texture and reflectance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Material {
    /// Bare soil (texture mapped from the ground position).
    Soil,
    /// Trunks and cordon arms.
    Bark,
    /// Green shoots.
    Shoot,
    /// Leaf blades (two-sided, translucent).
    Leaf,
    /// Grape berries, red variety.
    GrapeRed,
    /// Grape berries, white variety.
    GrapeWhite,
    /// Trellis posts and tag stakes (weathered wood).
    Post,
    /// Galvanised trellis wire.
    Wire,
    /// A featureless carton occluder.
    Carton,
    /// The printed face of an AprilTag board (the tag comes from the instance).
    Tag,
    /// The back and edges of a tag board (plain white plastic).
    Board,
    /// A loaded mesh (`[world.mesh]`): albedo from its vertex colours.
    VertexColour,
}

/// What the shader needs of a mesh beyond what the ray caster sees.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShadingMesh {
    /// Unit vertex normals, mesh frame.
    pub normals: Vec<[f32; 3]>,
    /// Texture coordinates per vertex (texture repeats per unit).
    pub uvs: Vec<[f32; 2]>,
    /// Material per triangle.
    pub materials: Vec<Material>,
    /// Linear albedo per vertex, for [`Material::VertexColour`] (empty otherwise).
    pub colors: Vec<[f32; 3]>,
}

/// The vineyard as the renderer sees it.
#[derive(Clone, Debug)]
pub struct RenderScene {
    /// Geometry for the ray caster.
    pub trace: TraceScene,
    /// Shading data, one per mesh of `trace.meshes`.
    pub shading: Vec<ShadingMesh>,
    /// Per instance: the inverse-transpose of its linear part (normals to the scene frame).
    pub normal_from_mesh: Vec<[[f32; 3]; 3]>,
    /// Per instance: the index into [`World::tags`] of the board it shows, or `u32::MAX`.
    pub instance_tag: Vec<u32>,
    /// Tag ids, in [`World::tags`] order.
    pub tag_ids: Vec<u32>,
    /// Axis-aligned bounds of the vegetation, posts and boards (everything that casts a
    /// shadow on something else), scene frame: min and max corners.
    pub caster_bounds: ([f32; 3], [f32; 3]),
    /// Grape variety, for the shader.
    pub grape: GrapeColour,
}

impl RenderScene {
    /// The material a ray hit (`hit` must be a hit in this scene).
    pub fn material_of(&self, hit: &super::Hit) -> Material {
        let mesh = self.trace.instances[hit.instance as usize].mesh as usize;
        self.shading[mesh].materials[hit.prim as usize]
    }

    /// Number of triangles in the prototypes and unique meshes.
    pub fn stored_triangles(&self) -> usize {
        self.trace.meshes.iter().map(|m| m.indices.len()).sum()
    }

    /// Number of triangles in the scene, counting every instance.
    pub fn instanced_triangles(&self) -> usize {
        self.trace
            .instances
            .iter()
            .map(|i| self.trace.meshes[i.mesh as usize].indices.len())
            .sum()
    }

    /// Bytes held by the meshes, shading data and per-instance tables.
    pub fn memory_bytes(&self) -> usize {
        let meshes: usize = self
            .trace
            .meshes
            .iter()
            .map(|m| m.positions.len() * 12 + m.indices.len() * 12)
            .sum();
        let shading: usize = self
            .shading
            .iter()
            .map(|s| s.normals.len() * 12 + s.uvs.len() * 8 + s.materials.len())
            .sum();
        meshes + shading + self.trace.instances.len() * (std::mem::size_of::<Instance>() + 36 + 4)
    }
}

/// Mesh being built: geometry and shading data side by side.
#[derive(Default)]
struct MeshBuilder {
    geo: MeshGeometry,
    shade: ShadingMesh,
}

impl MeshBuilder {
    fn vertex(&mut self, p: Vector3<f64>, n: Vector3<f64>, uv: [f64; 2]) -> u32 {
        let i = self.geo.positions.len() as u32;
        self.geo
            .positions
            .push([p.x as f32, p.y as f32, p.z as f32]);
        let n = n.try_normalize(1e-12).unwrap_or_else(Vector3::z);
        self.shade
            .normals
            .push([n.x as f32, n.y as f32, n.z as f32]);
        self.shade.uvs.push([uv[0] as f32, uv[1] as f32]);
        i
    }

    fn tri(&mut self, a: u32, b: u32, c: u32, m: Material) {
        self.geo.indices.push([a, b, c]);
        self.shade.materials.push(m);
    }

    /// A tube along `path` (at least two points) with a radius per point; texture `u`
    /// goes around, `v` along (one unit per `v_per_m` metres).
    fn tube(&mut self, path: &[Vector3<f64>], radii: &[f64], sides: usize, m: Material) {
        let mut rings = Vec::with_capacity(path.len());
        let mut arc = 0.0;
        for (i, p) in path.iter().enumerate() {
            let t = if i + 1 < path.len() {
                path[i + 1] - p
            } else {
                p - path[i - 1]
            }
            .normalize();
            if i > 0 {
                arc += (p - path[i - 1]).norm();
            }
            let reference = if t.z.abs() < 0.9 {
                Vector3::z()
            } else {
                Vector3::x()
            };
            let n1 = reference.cross(&t).normalize();
            let n2 = t.cross(&n1);
            let r = radii[i];
            let circumference = TAU * r.max(1e-3);
            let first = self.geo.positions.len() as u32;
            for k in 0..=sides {
                let a = TAU * k as f64 / sides as f64;
                let dir = n1 * a.cos() + n2 * a.sin();
                self.vertex(
                    p + dir * r,
                    dir,
                    [k as f64 / sides as f64, arc / circumference],
                );
            }
            rings.push(first);
        }
        for w in rings.windows(2) {
            for k in 0..sides as u32 {
                let (a, b) = (w[0] + k, w[0] + k + 1);
                let (c, d) = (w[1] + k, w[1] + k + 1);
                self.tri(a, b, d, m);
                self.tri(a, d, c, m);
            }
        }
    }

    /// A lobed vine leaf blade: a fan of 8 triangles around the blade centre. `up` runs
    /// from the petiole to the tip, `normal` is the blade's upper side.
    fn leaf(&mut self, centre: Vector3<f64>, normal: Vector3<f64>, up: Vector3<f64>, size: f64) {
        let n = normal.normalize();
        let up = (up - n * up.dot(&n)).normalize();
        let right = up.cross(&n);
        let r = 0.5 * size;
        let c = self.vertex(centre, n, [0.5, 0.5]);
        let first = c + 1;
        const RIM: usize = 8;
        for k in 0..RIM {
            // Angle from the tip (k = 0) around; the petiole sinus at the bottom is deep.
            let a = TAU * k as f64 / RIM as f64;
            let lobe = match k {
                0 => 1.0,
                1 | 7 => 0.78,
                2 | 6 => 0.95,
                3 | 5 => 0.7,
                _ => 0.25,
            };
            let (x, y) = (a.sin() * lobe, a.cos() * lobe);
            let p = centre + (right * x + up * y) * r;
            // Blades cup slightly: normals lean outward at the rim.
            let nk = (n + (right * x + up * y) * 0.25).normalize();
            self.vertex(p, nk, [0.5 + 0.5 * x, 0.5 - 0.5 * y]);
        }
        for k in 0..RIM as u32 {
            self.tri(c, first + k, first + (k + 1) % RIM as u32, Material::Leaf);
        }
    }

    /// A berry: an octahedron with radial normals.
    fn berry(&mut self, centre: Vector3<f64>, radius: f64, m: Material) {
        let first = self.geo.positions.len() as u32;
        let axes = [
            Vector3::x(),
            -Vector3::x(),
            Vector3::y(),
            -Vector3::y(),
            Vector3::z(),
            -Vector3::z(),
        ];
        for (i, a) in axes.iter().enumerate() {
            self.vertex(centre + a * radius, *a, [i as f64 / 6.0, 0.5]);
        }
        for (x, y, z) in [
            (0, 2, 4),
            (2, 1, 4),
            (1, 3, 4),
            (3, 0, 4),
            (2, 0, 5),
            (1, 2, 5),
            (3, 1, 5),
            (0, 3, 5),
        ] {
            self.tri(first + x, first + y, first + z, m);
        }
    }

    /// A box given by its pose (bottom-face centre, x along `size.x`) and size, flat
    /// shaded, texture coordinates in metres.
    fn cuboid(&mut self, pose: &Isometry3<f64>, size: &Vector3<f64>, m: Material) {
        let h = size * 0.5;
        // Faces: outward normal, then two in-plane axes (u, v) with u × v = normal.
        let faces = [
            (Vector3::x(), Vector3::y(), Vector3::z()),
            (-Vector3::x(), -Vector3::y(), Vector3::z()),
            (Vector3::y(), -Vector3::x(), Vector3::z()),
            (-Vector3::y(), Vector3::x(), Vector3::z()),
            (Vector3::z(), Vector3::x(), Vector3::y()),
            (-Vector3::z(), -Vector3::x(), Vector3::y()),
        ];
        for (n, u, v) in faces {
            let centre = Vector3::new(n.x * h.x, n.y * h.y, h.z + n.z * h.z);
            let hu = u.component_mul(&h).norm();
            let hv = v.component_mul(&h).norm();
            let nw = pose.rotation * n;
            let first = self.geo.positions.len() as u32;
            for (su, sv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let p = centre + u * (su * hu) + v * (sv * hv);
                self.vertex(
                    (pose * Point3::from(p)).coords,
                    nw,
                    [su * hu + hu, sv * hv + hv],
                );
            }
            self.tri(first, first + 1, first + 2, m);
            self.tri(first, first + 2, first + 3, m);
        }
    }

    fn finish(self) -> (MeshGeometry, ShadingMesh) {
        (self.geo, self.shade)
    }
}

/// A triangle mesh drawn instead of the generated vineyard (`[world.mesh]`), world
/// frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WorldMesh {
    /// Vertex positions, world frame, m.
    pub vertices: Vec<[f64; 3]>,
    /// sRGB vertex colours (empty: light grey).
    pub colors: Vec<[u8; 3]>,
    /// Counter-clockwise triangles (seen from the front; both sides are drawn).
    pub triangles: Vec<[u32; 3]>,
}

impl WorldMesh {
    /// Checks indices and values; the first problem, in words.
    pub fn validate(&self) -> Result<(), String> {
        if self.triangles.is_empty() {
            return Err("no triangles".into());
        }
        if !self.colors.is_empty() && self.colors.len() != self.vertices.len() {
            return Err(format!(
                "{} colours for {} vertices",
                self.colors.len(),
                self.vertices.len()
            ));
        }
        if let Some(i) = self
            .vertices
            .iter()
            .position(|v| !v.iter().all(|c| c.is_finite()))
        {
            return Err(format!("vertex {i} is not finite: {:?}", self.vertices[i]));
        }
        let n = self.vertices.len();
        if let Some((k, t)) = self
            .triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&i| i as usize >= n))
        {
            return Err(format!("triangle {k} {t:?} refers past the {n} vertices"));
        }
        Ok(())
    }
}

/// The render geometry of `world` with `mesh` in place of its vines, posts, wires, tags
/// and occluders (and of its ground unless `keep_ground`): one instance of the mesh in
/// the world's scene frame, vertex normals area-weighted from the triangles, shading from
/// the vertex colours. `mesh` must pass [`WorldMesh::validate`].
pub fn build_with_mesh(
    world: &World,
    opts: &GeometryOptions,
    mesh: &WorldMesh,
    keep_ground: bool,
) -> RenderScene {
    let origin = scene_origin(world);
    let to_scene = |p: Vector3<f64>| p - origin;
    let mut meshes = Vec::new();
    let mut shading = Vec::new();
    if keep_ground {
        let (g, s) = terrain_mesh(world, opts.terrain_cell_m, &to_scene).finish();
        meshes.push(g);
        shading.push(s);
    }
    let positions: Vec<[f32; 3]> = mesh
        .vertices
        .iter()
        .map(|p| {
            let q = to_scene(Vector3::from(*p));
            [q.x as f32, q.y as f32, q.z as f32]
        })
        .collect();
    let mut normals = vec![Vector3::<f64>::zeros(); positions.len()];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| Vector3::from(mesh.vertices[i as usize]));
        // Cross product: area-weighted.
        let n = (b - a).cross(&(c - a));
        for &i in t {
            normals[i as usize] += n;
        }
    }
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in &positions {
        let v = Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        lo = lo.inf(&v);
        hi = hi.sup(&v);
    }
    meshes.push(MeshGeometry {
        positions,
        indices: mesh.triangles.clone(),
    });
    shading.push(ShadingMesh {
        normals: normals
            .iter()
            .map(|n| {
                let n = n.try_normalize(1e-30).unwrap_or_else(Vector3::z);
                [n.x as f32, n.y as f32, n.z as f32]
            })
            .collect(),
        uvs: vec![[0.0; 2]; mesh.vertices.len()],
        materials: vec![Material::VertexColour; mesh.triangles.len()],
        colors: if mesh.colors.is_empty() {
            vec![[0.5; 3]; mesh.vertices.len()]
        } else {
            mesh.colors
                .iter()
                .map(|c| c.map(super::texture::decode_srgb))
                .collect()
        },
    });
    let instances: Vec<Instance> = (0..meshes.len() as u32)
        .map(|mesh| Instance {
            mesh,
            scene_from_mesh: Affine3::IDENTITY,
        })
        .collect();
    let f3 = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
    RenderScene {
        normal_from_mesh: vec![
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
            instances.len()
        ],
        instance_tag: vec![u32::MAX; instances.len()],
        trace: TraceScene {
            origin_in_world: origin,
            meshes,
            instances,
        },
        shading,
        tag_ids: Vec::new(),
        caster_bounds: (f3(lo), f3(hi)),
        grape: world.params.canopy.grape_colour,
    }
}

/// The scene frame's origin: the centre of the terrain, on the ground.
fn scene_origin(world: &World) -> Vector3<f64> {
    let (lo, hi) = world.terrain.domain();
    let centre = (lo + hi) * 0.5;
    Vector3::new(
        centre.x,
        centre.y,
        world.terrain.height_at(centre.x, centre.y),
    )
}

/// `[render]` values the geometry depends on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeometryOptions {
    /// Ground triangulation step, m.
    pub terrain_cell_m: f64,
}

/// Builds the render geometry of a world. Deterministic: the canopies come from the
/// streams `render.canopy.<k>`, each vine's trunk shape and prototype from its
/// appearance seed.
pub fn build(world: &World, opts: &GeometryOptions) -> RenderScene {
    let origin = scene_origin(world);
    let to_scene = |p: Vector3<f64>| p - origin;

    let mut meshes = Vec::new();
    let mut shading = Vec::new();
    let mut instances = Vec::new();
    let mut normal_from_mesh = Vec::new();
    let mut instance_tag = Vec::new();
    let mut push_instance = |mesh: u32, scene_from_mesh: Affine3, tag: u32| {
        let m = Matrix3::from_fn(|i, j| f64::from(scene_from_mesh.rows[i][j]));
        let nm = m
            .try_inverse()
            .map(|mi| mi.transpose())
            .unwrap_or_else(Matrix3::identity);
        instances.push(Instance {
            mesh,
            scene_from_mesh,
        });
        normal_from_mesh.push(std::array::from_fn(|i| {
            std::array::from_fn(|j| nm[(i, j)] as f32)
        }));
        instance_tag.push(tag);
    };
    let mut add_mesh = |b: MeshBuilder| {
        let (g, s) = b.finish();
        meshes.push(g);
        shading.push(s);
        (meshes.len() - 1) as u32
    };

    // Ground.
    let ground = add_mesh(terrain_mesh(world, opts.terrain_cell_m, &to_scene));
    push_instance(ground, Affine3::IDENTITY, u32::MAX);

    // Unique geometry: trunks, cordons, posts, wires, occluders.
    let mut unique = MeshBuilder::default();
    let plants = &world.params.plants;
    for plant in &world.plants {
        let mut r = ChaCha8Rng::seed_from_u64(plant.appearance_seed ^ 0x7472_756e_6b00);
        let (_, tangent) = row_frame(world, &plant.base_in_world);
        trunk_and_cordon(
            &mut unique,
            &mut r,
            to_scene(plant.base_in_world),
            tangent,
            plant.trunk_height_m,
            plant.trunk_diameter_m,
            plants.spacing_m,
        );
    }
    for post in &world.posts {
        let base = to_scene(post.base_in_world) - Vector3::new(0.0, 0.0, 0.1);
        let path = [base, base + Vector3::new(0.0, 0.0, post.height_m + 0.1)];
        let r = 0.5 * post.diameter_m;
        unique.tube(&path, &[r, r], 8, Material::Post);
    }
    for wire in &world.wires {
        let path: Vec<_> = wire.points_in_world.iter().map(|p| to_scene(*p)).collect();
        for seg in path.windows(2) {
            // Wires sag a little between posts.
            let mid = (seg[0] + seg[1]) * 0.5 - Vector3::new(0.0, 0.0, 0.01);
            unique.tube(&[seg[0], mid, seg[1]], &[0.0015; 3], 3, Material::Wire);
        }
    }
    for o in &world.occluders {
        let pose = Isometry3::from_parts(
            (o.world_from_box.translation.vector - origin - Vector3::new(0.0, 0.0, 0.02)).into(),
            o.world_from_box.rotation,
        );
        unique.cuboid(
            &pose,
            &(o.size_m + Vector3::new(0.0, 0.0, 0.02)),
            Material::Carton,
        );
    }
    for t in &world.tags {
        // The stake the board is screwed to, behind the board down to the ground.
        let centre = t.world_from_tag.translation.vector;
        let back = t.world_from_tag.rotation * Vector3::z();
        let foot = centre + back * 0.03;
        let ground_z = world.terrain.height_at(foot.x, foot.y);
        let top = foot.z + 0.25 * t.size_m;
        let stake = Isometry3::from_parts(
            (to_scene(Vector3::new(foot.x, foot.y, ground_z - 0.1))).into(),
            nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), back.y.atan2(back.x)),
        );
        unique.cuboid(
            &stake,
            &Vector3::new(0.04, 0.04, top - ground_z + 0.1),
            Material::Post,
        );
    }
    let unique_mesh = add_mesh(unique);
    push_instance(unique_mesh, Affine3::IDENTITY, u32::MAX);

    // Tag boards: the printed face (tag plus white border) and a 1 cm thick board.
    for (k, t) in world.tags.iter().enumerate() {
        let mut b = MeshBuilder::default();
        let half = 0.5 * t.size_m * 10.0 / 8.0;
        let n = Vector3::new(0.0, 0.0, -1.0);
        let corners = [(-half, -half), (half, -half), (half, half), (-half, half)];
        let first = b.geo.positions.len() as u32;
        for (x, y) in corners {
            // Printed u right, v down: the tag frame's x and y.
            b.vertex(
                Vector3::new(x, y, 0.0),
                n,
                [(x + half) / (2.0 * half), (y + half) / (2.0 * half)],
            );
        }
        // Counter-clockwise seen from the printed side (-z).
        b.tri(first, first + 2, first + 1, Material::Tag);
        b.tri(first, first + 3, first + 2, Material::Tag);
        // The board behind the face: a box 1 cm thick whose front is at z = +1 mm.
        let pose = Isometry3::translation(0.0, 0.0, 0.001);
        b.cuboid(
            &pose,
            &Vector3::new(2.0 * half, 2.0 * half, 0.01),
            Material::Board,
        );
        let mesh = add_mesh(b);
        let world_from_tag = Isometry3::from_parts(
            (t.world_from_tag.translation.vector - origin).into(),
            t.world_from_tag.rotation,
        );
        push_instance(
            mesh,
            affine_of(&world_from_tag, &Vector3::repeat(1.0)),
            k as u32,
        );
    }

    // Canopy prototypes and one instance per vine.
    let canopy = &world.params.canopy;
    let proto_meshes: Vec<u32> = (0..canopy.prototypes)
        .map(|k| {
            let mut r = rng::stream(world.seed, &format!("render.canopy.{k}"));
            add_mesh(canopy_prototype(
                canopy,
                plants.spacing_m,
                plants.canopy_height_m,
                plants.canopy_width_m,
                &mut r,
            ))
        })
        .collect();
    let mut caster_lo = Vector3::repeat(f64::INFINITY);
    let mut caster_hi = Vector3::repeat(f64::NEG_INFINITY);
    let mut grow = |p: Vector3<f64>, pad: f64| {
        caster_lo = caster_lo.inf(&(p - Vector3::repeat(pad)));
        caster_hi = caster_hi.sup(&(p + Vector3::repeat(pad)));
    };
    for plant in &world.plants {
        let (_, tangent) = row_frame(world, &plant.base_in_world);
        let yaw = tangent.y.atan2(tangent.x);
        let mirror = if (plant.appearance_seed >> 17) & 1 == 1 {
            -1.0
        } else {
            1.0
        };
        let scale = Vector3::new(
            mirror,
            plant.canopy_width_m / plants.canopy_width_m,
            plant.canopy_height_m / plants.canopy_height_m,
        );
        let cordon = to_scene(plant.base_in_world) + Vector3::new(0.0, 0.0, plant.trunk_height_m);
        let pose = Isometry3::new(cordon, Vector3::z() * yaw);
        let proto = proto_meshes[(plant.appearance_seed % u64::from(canopy.prototypes)) as usize];
        push_instance(proto, affine_of(&pose, &scale), u32::MAX);
        grow(
            cordon,
            plant.canopy_height_m + plant.canopy_width_m + plants.spacing_m,
        );
    }
    for post in &world.posts {
        grow(to_scene(post.base_in_world), post.height_m);
        grow(
            to_scene(post.base_in_world) + Vector3::new(0.0, 0.0, post.height_m),
            0.1,
        );
    }
    for t in &world.tags {
        grow(t.world_from_tag.translation.vector - origin, t.size_m);
    }
    for o in &world.occluders {
        grow(
            o.world_from_box.translation.vector - origin,
            o.size_m.norm(),
        );
    }
    if !caster_lo.x.is_finite() {
        caster_lo = Vector3::zeros();
        caster_hi = Vector3::zeros();
    }
    let f3 = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
    RenderScene {
        trace: TraceScene {
            origin_in_world: origin,
            meshes,
            instances,
        },
        shading,
        normal_from_mesh,
        instance_tag,
        tag_ids: world.tags.iter().map(|t| t.id).collect(),
        caster_bounds: (f3(caster_lo), f3(caster_hi)),
        grape: canopy.grape_colour,
    }
}

/// The affine map `pose · diag(scale)`.
fn affine_of(pose: &Isometry3<f64>, scale: &Vector3<f64>) -> Affine3 {
    let r = pose.rotation.to_rotation_matrix();
    let m = r.matrix() * Matrix3::from_diagonal(scale);
    let t = pose.translation.vector;
    Affine3 {
        rows: std::array::from_fn(|i| {
            [
                m[(i, 0)] as f32,
                m[(i, 1)] as f32,
                m[(i, 2)] as f32,
                t[i] as f32,
            ]
        }),
    }
}

/// Row position and unit tangent at a world point.
fn row_frame(world: &World, p: &Vector3<f64>) -> (Vector2<f64>, Vector2<f64>) {
    let (offset, s) = world.layout.row_coords(&p.xy());
    world.layout.point(offset, s)
}

fn terrain_mesh(
    world: &World,
    cell_m: f64,
    to_scene: &dyn Fn(Vector3<f64>) -> Vector3<f64>,
) -> MeshBuilder {
    let (lo, hi) = world.terrain.domain();
    let nx = ((hi.x - lo.x) / cell_m).ceil().max(1.0) as usize;
    let ny = ((hi.y - lo.y) / cell_m).ceil().max(1.0) as usize;
    let dx = (hi.x - lo.x) / nx as f64;
    let dy = (hi.y - lo.y) / ny as f64;
    let mut b = MeshBuilder::default();
    let h = |x: f64, y: f64| world.terrain.height_at(x, y);
    let e = 0.05;
    for iy in 0..=ny {
        for ix in 0..=nx {
            let (x, y) = (lo.x + ix as f64 * dx, lo.y + iy as f64 * dy);
            let gx = (h(x + e, y) - h(x - e, y)) / (2.0 * e);
            let gy = (h(x, y + e) - h(x, y - e)) / (2.0 * e);
            let p = to_scene(Vector3::new(x, y, h(x, y)));
            // Soil texture: one repeat per 2 m, in scene coordinates.
            b.vertex(p, Vector3::new(-gx, -gy, 1.0), [p.x / 2.0, p.y / 2.0]);
        }
    }
    let row = (nx + 1) as u32;
    for iy in 0..ny as u32 {
        for ix in 0..nx as u32 {
            let a = iy * row + ix;
            b.tri(a, a + 1, a + row + 1, Material::Soil);
            b.tri(a, a + row + 1, a + row, Material::Soil);
        }
    }
    b
}

fn trunk_and_cordon(
    b: &mut MeshBuilder,
    r: &mut ChaCha8Rng,
    base: Vector3<f64>,
    tangent: Vector2<f64>,
    height_m: f64,
    diameter_m: f64,
    spacing_m: f64,
) {
    let t = Vector3::new(tangent.x, tangent.y, 0.0);
    let n = Vector3::new(-tangent.y, tangent.x, 0.0);
    let radius = 0.5 * diameter_m;
    // A gently bent trunk from 10 cm below ground to the cordon.
    let segments = 5;
    let mut path = Vec::with_capacity(segments + 1);
    let mut radii = Vec::with_capacity(segments + 1);
    let bend_t = r.random_range(-0.03..0.03);
    let bend_n = r.random_range(-0.03..0.03);
    for i in 0..=segments {
        let f = i as f64 / segments as f64;
        let sway = (f * PI).sin();
        let z = -0.1 + f * (height_m + 0.1);
        path.push(base + t * (bend_t * sway) + n * (bend_n * sway) + Vector3::new(0.0, 0.0, z));
        radii.push(radius * (1.0 - 0.25 * f));
    }
    let top = path[segments];
    b.tube(&path, &radii, 6, Material::Bark);
    // Two cordon arms along the row, drooping slightly, tied to the first wire.
    let arm = 0.45 * spacing_m;
    let arm_radius = 0.45 * radius;
    for side in [-1.0, 1.0] {
        let mut path = Vec::with_capacity(5);
        for i in 0..5 {
            let f = i as f64 / 4.0;
            let droop = -0.02 * (f * PI).sin() + r.random_range(-0.005..0.005);
            path.push(top + t * (side * arm * f) + Vector3::new(0.0, 0.0, droop));
        }
        let radii: Vec<f64> = (0..5)
            .map(|i| arm_radius * (1.0 - 0.12 * i as f64))
            .collect();
        b.tube(&path, &radii, 5, Material::Bark);
    }
}

/// One canopy prototype in its frame: origin on the cordon at the vine, x along the row,
/// y to the left, z up; `length_m` along the row, nominal canopy height and width.
fn canopy_prototype(
    p: &CanopyParams,
    length_m: f64,
    height_m: f64,
    width_m: f64,
    r: &mut ChaCha8Rng,
) -> MeshBuilder {
    let mut b = MeshBuilder::default();
    let stage = p.growth_stage;
    let shoots = p.shoots_per_plant as usize;
    // Shoots: upright (VSP) between the wires, swaying a little.
    let mut shoot_paths: Vec<Vec<Vector3<f64>>> = Vec::with_capacity(shoots);
    for j in 0..shoots {
        let x0 = length_m * (-0.45 + 0.9 * (j as f64 + 0.5) / shoots as f64)
            + r.random_range(-0.03..0.03);
        let y0 = r.random_range(-0.02..0.02);
        let top = height_m * stage.max(0.08) * r.random_range(0.75..1.0);
        let lean_x = r.random_range(-0.08..0.08);
        let lean_y = r.random_range(-0.3..0.3) * width_m;
        let path: Vec<_> = (0..6)
            .map(|i| {
                let f = i as f64 / 5.0;
                Vector3::new(x0 + lean_x * f * f, y0 + lean_y * f * f, 0.02 + top * f)
            })
            .collect();
        b.tube(
            &path,
            &[0.005, 0.0045, 0.004, 0.0035, 0.003, 0.0025],
            3,
            Material::Shoot,
        );
        shoot_paths.push(path);
    }
    // Leaves along the shoots on alternating sides.
    let leaves = (f64::from(p.leaves_per_plant) * stage).round() as usize;
    let half_w = 0.5 * width_m;
    for i in 0..leaves {
        if shoots == 0 {
            break;
        }
        let path = &shoot_paths[r.random_range(0..shoots)];
        let f: f64 = r.random_range(0.05..1.0);
        let seg = ((f * 5.0).floor() as usize).min(4);
        let local = f * 5.0 - seg as f64;
        let on_shoot = path[seg] + (path[seg + 1] - path[seg]) * local;
        let side = if i % 2 == 0 { 1.0 } else { -1.0 };
        let petiole_dir =
            Vector3::new(r.random_range(-0.6..0.6), side, r.random_range(0.0..0.6)).normalize();
        let size = p.leaf_size_m * stage.sqrt() * r.random_range(0.65..1.15);
        let petiole = r.random_range(0.04..0.1) * stage.sqrt();
        let mut centre = on_shoot + petiole_dir * (petiole + 0.5 * size);
        centre.y = centre.y.clamp(-half_w, half_w);
        // Blades face outward and up toward the light, tilted at random.
        let tilt: f64 = r.random_range(-0.7..0.7);
        let normal = Vector3::new(
            r.random_range(-0.4..0.4),
            side * tilt.cos(),
            tilt.sin().abs() + 0.2,
        );
        let up = Vector3::new(r.random_range(-0.5..0.5), -side * 0.3, 1.0);
        b.leaf(centre, normal, up, size);
    }
    // Grape bunches hanging below the cordon.
    let bunches = (f64::from(p.bunches_per_plant) * stage).round() as usize;
    let material = match p.grape_colour {
        GrapeColour::Red => Material::GrapeRed,
        GrapeColour::White => Material::GrapeWhite,
    };
    for _ in 0..bunches {
        let top = Vector3::new(
            r.random_range(-0.4..0.4) * length_m,
            r.random_range(-0.08..0.08),
            r.random_range(-0.04..0.02),
        );
        let length = 0.16 * stage.sqrt().max(0.3) * r.random_range(0.7..1.2);
        let top_radius = 0.35 * length;
        let berry = 0.0075 * stage.sqrt().max(0.4);
        let layers = (length / (1.6 * berry)).ceil() as usize;
        let twist = r.random_range(0.0..TAU);
        for k in 0..layers {
            let f = k as f64 / layers as f64;
            let ring = top_radius * (1.0 - f).powf(0.7) + 0.3 * berry;
            let count = ((TAU * ring) / (2.1 * berry)).floor().max(1.0) as usize;
            for m in 0..count {
                let a = twist + TAU * (m as f64 + 0.5 * (k % 2) as f64) / count as f64;
                let jitter = Vector3::new(
                    r.random_range(-0.3..0.3),
                    r.random_range(-0.3..0.3),
                    r.random_range(-0.3..0.3),
                ) * berry;
                let c = top + Vector3::new(a.cos() * ring, a.sin() * ring, -f * length) + jitter;
                b.berry(c, berry * r.random_range(0.85..1.1), material);
            }
        }
    }
    b
}
