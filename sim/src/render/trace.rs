//! The ray-casting seam and its default backend.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::{Affine3, Instance, MeshGeometry, TraceScene};

/// Rays per packet: an 8×8 pixel tile.
pub const PACKET_SIZE: usize = 64;

/// Up to [`PACKET_SIZE`] rays sharing one origin (a pinhole camera's tile), directions
/// stored structure-of-arrays.
#[derive(Clone, Debug)]
pub struct RayPacket {
    /// Common origin, scene frame, m.
    pub origin: [f32; 3],
    /// Direction components `[x, y, z]`, one lane per ray; the hit parameter `t` is in
    /// units of each direction's length (unit directions give ranges in metres).
    pub dir: [[f32; PACKET_SIZE]; 3],
    /// Number of valid lanes, 1..=PACKET_SIZE; lanes beyond are ignored.
    pub len: usize,
    /// Hits closer than this are ignored.
    pub t_min: f32,
    /// Hits farther than this are ignored.
    pub t_max: f32,
}

/// The first hit of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit ([`f32::INFINITY`] for a miss).
    pub t: f32,
    /// Index of the instance hit in [`TraceScene::instances`] ([`Hit::NONE`] for a miss).
    pub instance: u32,
    /// Triangle index within the instance's mesh.
    pub prim: u32,
    /// Barycentric coordinate of the triangle's second vertex.
    pub u: f32,
    /// Barycentric coordinate of the triangle's third vertex.
    pub v: f32,
}

impl Hit {
    /// Instance index of a miss.
    pub const NONE: u32 = u32::MAX;
    /// A miss.
    pub const MISS: Hit = Hit {
        t: f32::INFINITY,
        instance: Hit::NONE,
        prim: 0,
        u: 0.0,
        v: 0.0,
    };

    /// Whether the ray hit anything.
    pub fn is_hit(&self) -> bool {
        self.instance != Hit::NONE
    }
}

/// Finds first hits of rays against a [`TraceScene`]. Backends must agree on what they
/// return up to floating-point rounding; results never depend on the thread count.
pub trait RayCaster: Send + Sync {
    /// Backend name for reports (`bvh`, `embree`).
    fn name(&self) -> &'static str;
    /// First hits of the packet's valid lanes, written to `hits[..packet.len]`.
    fn cast_packet(&self, packet: &RayPacket, hits: &mut [Hit; PACKET_SIZE]);
    /// First hit of one ray with its own origin.
    fn cast_ray(&self, origin: [f32; 3], dir: [f32; 3], t_min: f32, t_max: f32) -> Hit;
    /// Bytes held by the acceleration structure (not counting the scene itself).
    fn memory_bytes(&self) -> usize;
}

/// Rows of [`synthetic_vegetation_scene`].
const VEG_ROWS: usize = 6;
/// Distance between rows, m.
const VEG_ROW_PITCH: f32 = 2.5;
/// Distance between plants along a row, m.
const VEG_PLANT_PITCH: f32 = 1.2;
/// Plant prototypes (distinct meshes).
const VEG_PROTOTYPES: usize = 4;
/// Triangles per plant prototype, at most.
const VEG_PLANT_TRIS: usize = 4000;

/// A deterministic vegetation-like test scene of about `triangles` triangles when
/// instanced triangles are counted: a bumpy ground grid (a fifth of the budget, one
/// mesh, identity instance) and six rows, 2.5 m apart, along +x starting at `y = 0`, of
/// plants 1.2 m apart, each an instance (yaw, per-axis scale 0.85–1.15) of one
/// of four prototypes made of a trunk and small leaves (two triangles each, 5–10 cm) in a
/// canopy 0.55–1.85 m high, 1.3 m long and about 0.6 m thick. 1.5 M triangles give a
/// 300 k-triangle ground and 300 plants of 4000 triangles. Everything derives from
/// `seed`.
pub fn synthetic_vegetation_scene(seed: u64, triangles: usize) -> TraceScene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let ground_tris = (triangles / 5).max(2);
    let plant_budget = triangles.saturating_sub(ground_tris).max(2);
    let per_plant = ((plant_budget / 4).clamp(2, VEG_PLANT_TRIS)) & !1;
    let plants = (plant_budget / per_plant).max(1);
    let per_row = plants.div_ceil(VEG_ROWS);
    let row_len = per_row as f32 * VEG_PLANT_PITCH;
    let height = |x: f32, y: f32| {
        0.04 * (0.9 * x + 0.3).sin() * (0.7 * y).cos() + 0.015 * (2.3 * x - 1.7 * y).sin()
    };

    // Ground grid.
    let (x0, x1) = (-6.0f32, row_len + 6.0);
    let (y0, y1) = (-VEG_ROW_PITCH, VEG_ROWS as f32 * VEG_ROW_PITCH);
    let cells = (ground_tris / 2).max(1);
    let ny = (((cells as f32) * (y1 - y0) / (x1 - x0)).sqrt().round() as usize).max(1);
    let nx = (cells / ny).max(1);
    let mut ground = MeshGeometry::default();
    for iy in 0..=ny {
        for ix in 0..=nx {
            let x = x0 + (x1 - x0) * ix as f32 / nx as f32;
            let y = y0 + (y1 - y0) * iy as f32 / ny as f32;
            let z = height(x, y) + rng.random_range(-0.005..0.005);
            ground.positions.push([x, y, z]);
        }
    }
    let at = |ix: usize, iy: usize| (iy * (nx + 1) + ix) as u32;
    for iy in 0..ny {
        for ix in 0..nx {
            let (a, b, c, d) = (
                at(ix, iy),
                at(ix + 1, iy),
                at(ix + 1, iy + 1),
                at(ix, iy + 1),
            );
            ground.indices.push([a, b, c]);
            ground.indices.push([a, c, d]);
        }
    }

    // Plant prototypes.
    let mut meshes = vec![ground];
    for _ in 0..VEG_PROTOTYPES {
        let mut m = MeshGeometry::default();
        let quad = |m: &mut MeshGeometry, v: [[f32; 3]; 4]| {
            let base = m.positions.len() as u32;
            m.positions.extend_from_slice(&v);
            m.indices.push([base, base + 1, base + 2]);
            m.indices.push([base, base + 2, base + 3]);
        };
        let mut tris = 0;
        if per_plant >= 64 {
            // Trunk: four sides of a 4 cm square post up to the canopy.
            let (r, top) = (0.02f32, 0.7f32);
            let c = [[-r, -r], [r, -r], [r, r], [-r, r]];
            for k in 0..4 {
                let (p, q) = (c[k], c[(k + 1) % 4]);
                quad(
                    &mut m,
                    [
                        [p[0], p[1], 0.0],
                        [q[0], q[1], 0.0],
                        [q[0], q[1], top],
                        [p[0], p[1], top],
                    ],
                );
            }
            tris += 8;
        }
        while tris + 2 <= per_plant {
            let cx = rng.random_range(-0.65f32..0.65);
            let cy = (rng.random::<f32>() + rng.random::<f32>() - 1.0) * 0.3;
            let cz = 0.55 + 1.3 * rng.random::<f32>().sqrt();
            let size = rng.random_range(0.05f32..0.10);
            // Random leaf plane: normal n, axes u, v.
            let n = loop {
                let v: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0f32..1.0));
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if l > 0.1 && l <= 1.0 {
                    break v.map(|x| x / l);
                }
            };
            let t = if n[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            let u = normalize(cross3(n, t));
            let v = cross3(n, u);
            let (h, w) = (0.5 * size, 0.3 * size);
            let p = |a: f32, b: f32| {
                [
                    cx + a * u[0] + b * v[0],
                    cy + a * u[1] + b * v[1],
                    cz + a * u[2] + b * v[2],
                ]
            };
            quad(&mut m, [p(-h, 0.0), p(0.0, -w), p(h, 0.0), p(0.0, w)]);
            tris += 2;
        }
        meshes.push(m);
    }

    // Instances.
    let mut instances = vec![Instance {
        mesh: 0,
        scene_from_mesh: Affine3::IDENTITY,
    }];
    'rows: for row in 0..VEG_ROWS {
        for k in 0..per_row {
            if instances.len() > plants {
                break 'rows;
            }
            let x = (k as f32 + 0.5) * VEG_PLANT_PITCH + rng.random_range(-0.1f32..0.1);
            let y = row as f32 * VEG_ROW_PITCH + rng.random_range(-0.05f32..0.05);
            let yaw = rng.random_range(-0.2f32..0.2)
                + if rng.random::<bool>() {
                    std::f32::consts::PI
                } else {
                    0.0
                };
            let s: [f32; 3] = std::array::from_fn(|_| rng.random_range(0.85f32..1.15));
            let (sn, cs) = yaw.sin_cos();
            let proto = 1 + rng.random_range(0..VEG_PROTOTYPES) as u32;
            instances.push(Instance {
                mesh: proto,
                scene_from_mesh: Affine3 {
                    rows: [
                        [cs * s[0], -sn * s[1], 0.0, x],
                        [sn * s[0], cs * s[1], 0.0, y],
                        [0.0, 0.0, s[2], height(x, y)],
                    ],
                },
            });
        }
    }
    TraceScene {
        origin_in_world: nalgebra::Vector3::zeros(),
        meshes,
        instances,
    }
}

fn cross3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    a.map(|x| x / l)
}

/// A pinhole view for [`measure_mrays`]: origin, forward, right and up axes (scene frame).
#[derive(Clone, Copy, Debug)]
struct BenchView {
    origin: [f32; 3],
    fwd: [f32; 3],
    right: [f32; 3],
    up: [f32; 3],
}

/// The fixed benchmark poses: 1.2 m above the ground, in the inter-row nearest the middle
/// of the instances' extent across rows, looking along +x (the rows) with small yaw and
/// pitch changes from frame to frame, stepping 0.8 m along the row.
fn bench_view(scene: &TraceScene, frame: usize) -> BenchView {
    let (mut xmin, mut ymin, mut ymax, mut zmin) = (
        f32::INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::INFINITY,
    );
    for i in scene.instances.iter().skip(1) {
        let t = [
            i.scene_from_mesh.rows[0][3],
            i.scene_from_mesh.rows[1][3],
            i.scene_from_mesh.rows[2][3],
        ];
        xmin = xmin.min(t[0]);
        ymin = ymin.min(t[1]);
        ymax = ymax.max(t[1]);
        zmin = zmin.min(t[2]);
    }
    if !xmin.is_finite() {
        (xmin, ymin, ymax, zmin) = (0.0, 0.0, 0.0, 0.0);
    }
    let y = ((0.5 * (ymin + ymax) / VEG_ROW_PITCH).floor() + 0.5) * VEG_ROW_PITCH;
    let f = frame as f32;
    let yaw = 0.04 * (1.3 * f).sin();
    let pitch = -0.06 + 0.03 * (0.7 * f).cos();
    let fwd = [
        yaw.cos() * pitch.cos(),
        yaw.sin() * pitch.cos(),
        pitch.sin(),
    ];
    let right = normalize(cross3(fwd, [0.0, 0.0, 1.0]));
    let up = cross3(right, fwd);
    BenchView {
        origin: [xmin - 1.5 + 0.8 * f, y, zmin + 1.2],
        fwd,
        right,
        up,
    }
}

/// Camera-frame unit directions (right, up, forward) of the pixels of one 8×8 tile, lanes
/// row-major: the pinhole's ray table (87° horizontal field of view, square pixels).
struct TileRays {
    cam: [[f32; PACKET_SIZE]; 3],
    len: usize,
}

impl TileRays {
    fn new(width: usize, height: usize, tx: usize, ty: usize) -> TileRays {
        let fx = 0.5 * width as f32 / (0.5 * 87f32.to_radians()).tan();
        let mut t = TileRays {
            cam: [[0.0; PACKET_SIZE]; 3],
            len: 0,
        };
        for py in ty..(ty + 8).min(height) {
            for px in tx..(tx + 8).min(width) {
                let x = (px as f32 + 0.5 - 0.5 * width as f32) / fx;
                let y = (0.5 * height as f32 - py as f32 - 0.5) / fx;
                let d = normalize([x, y, 1.0]);
                for (a, da) in d.into_iter().enumerate() {
                    t.cam[a][t.len] = da;
                }
                t.len += 1;
            }
        }
        t
    }

    /// The tile's packet for a view (directions rotated into the scene frame).
    fn packet(&self, v: &BenchView) -> RayPacket {
        let mut p = RayPacket {
            origin: v.origin,
            dir: [[0.0; PACKET_SIZE]; 3],
            len: self.len,
            t_min: 0.0,
            t_max: f32::INFINITY,
        };
        let [cx, cy, cz] = &self.cam;
        for (a, da) in p.dir.iter_mut().enumerate() {
            for (l, d) in da.iter_mut().enumerate().take(self.len) {
                *d = v.right[a] * cx[l] + v.up[a] * cy[l] + v.fwd[a] * cz[l];
            }
        }
        p
    }
}

/// Renders `frames` fixed `width`×`height` pinhole views (87° horizontal field of view,
/// camera 1.2 m above the ground looking along a row; poses as for
/// [`synthetic_vegetation_scene`]'s layout) with [`RayCaster::cast_packet`], rayon over
/// 8×8 tiles, and returns the throughput in millions of primary rays per second.
pub fn measure_mrays(
    caster: &dyn RayCaster,
    scene: &TraceScene,
    width: usize,
    height: usize,
    frames: usize,
) -> f64 {
    measure(caster, scene, width, height, frames, true)
}

/// As [`measure_mrays`] with one [`RayCaster::cast_ray`] per pixel.
pub fn measure_mrays_single(
    caster: &dyn RayCaster,
    scene: &TraceScene,
    width: usize,
    height: usize,
    frames: usize,
) -> f64 {
    measure(caster, scene, width, height, frames, false)
}

fn measure(
    caster: &dyn RayCaster,
    scene: &TraceScene,
    width: usize,
    height: usize,
    frames: usize,
    packets: bool,
) -> f64 {
    // The camera's ray table, computed once (as a camera model does).
    let tiles: Vec<TileRays> = (0..height.div_ceil(8))
        .flat_map(|ty| {
            (0..width.div_ceil(8)).map(move |tx| TileRays::new(width, height, 8 * tx, 8 * ty))
        })
        .collect();
    let views: Vec<BenchView> = (0..frames).map(|f| bench_view(scene, f)).collect();
    let start = std::time::Instant::now();
    let mut checksum = 0.0f64;
    for v in &views {
        checksum += tiles
            .par_iter()
            .map(|tile| {
                let p = tile.packet(v);
                let mut hits = [Hit::MISS; PACKET_SIZE];
                if packets {
                    caster.cast_packet(&p, &mut hits);
                } else {
                    for (l, h) in hits.iter_mut().enumerate().take(p.len) {
                        *h = caster.cast_ray(
                            p.origin,
                            [p.dir[0][l], p.dir[1][l], p.dir[2][l]],
                            p.t_min,
                            p.t_max,
                        );
                    }
                }
                hits[..p.len]
                    .iter()
                    .filter(|h| h.is_hit())
                    .map(|h| f64::from(h.t))
                    .sum::<f64>()
            })
            .sum::<f64>();
    }
    let secs = start.elapsed().as_secs_f64();
    std::hint::black_box(checksum);
    (width * height * frames) as f64 / secs.max(1e-9) / 1e6
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::render::build_default;
    use crate::render::bvh::{TwoLevelBvh, brute_force_ray};

    /// Small deterministic generator for tests.
    struct Lcg(u64);

    impl Lcg {
        fn f(&mut self) -> f32 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 40) as f32) / (1u64 << 24) as f32
        }
        fn range(&mut self, a: f32, b: f32) -> f32 {
            a + (b - a) * self.f()
        }
        fn unit(&mut self) -> [f32; 3] {
            loop {
                let v = [
                    self.range(-1.0, 1.0),
                    self.range(-1.0, 1.0),
                    self.range(-1.0, 1.0),
                ];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if l > 0.1 && l <= 1.0 {
                    return v.map(|x| x / l);
                }
            }
        }
    }

    /// An icosphere of radius 1 (closed, consistently oriented) with `sub` subdivisions.
    fn icosphere(sub: usize) -> MeshGeometry {
        let t = (1.0 + 5f32.sqrt()) / 2.0;
        let mut pos: Vec<[f32; 3]> = [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ]
        .iter()
        .map(|&p| normalize(p))
        .collect();
        let mut idx: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..sub {
            let mut mid = std::collections::HashMap::new();
            let mut next = Vec::new();
            for t in &idx {
                let mut m = [0u32; 3];
                for k in 0..3 {
                    let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
                    m[k] = *mid.entry((a, b)).or_insert_with(|| {
                        let (pa, pb) = (pos[a as usize], pos[b as usize]);
                        pos.push(normalize([pa[0] + pb[0], pa[1] + pb[1], pa[2] + pb[2]]));
                        (pos.len() - 1) as u32
                    });
                }
                next.push([t[0], m[0], m[2]]);
                next.push([t[1], m[1], m[0]]);
                next.push([t[2], m[2], m[1]]);
                next.push([m[0], m[1], m[2]]);
            }
            idx = next;
        }
        MeshGeometry {
            positions: pos,
            indices: idx,
        }
    }

    /// A flat `n`×`n` grid of unit squares in `z = z0`, two triangles each.
    fn grid(n: usize, z0: f32) -> MeshGeometry {
        let mut m = MeshGeometry::default();
        for y in 0..=n {
            for x in 0..=n {
                m.positions.push([x as f32, y as f32, z0]);
            }
        }
        let at = |x: usize, y: usize| (y * (n + 1) + x) as u32;
        for y in 0..n {
            for x in 0..n {
                m.indices.push([at(x, y), at(x + 1, y), at(x + 1, y + 1)]);
                m.indices.push([at(x, y), at(x + 1, y + 1), at(x, y + 1)]);
            }
        }
        m
    }

    fn rotation(axis: [f32; 3], angle: f32) -> [[f32; 3]; 3] {
        let [x, y, z] = axis;
        let (s, c) = angle.sin_cos();
        let t = 1.0 - c;
        [
            [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
        ]
    }

    /// Random soup, closed sphere, empty mesh and grid; random rotated, scaled and
    /// translated instances plus identity, translation-only, empty-mesh and singular
    /// ones.
    fn random_scene(seed: u64) -> TraceScene {
        let mut r = Lcg(seed);
        let mut soup = MeshGeometry::default();
        for _ in 0..300 {
            let c = [r.range(-1.0, 1.0), r.range(-1.0, 1.0), r.range(-1.0, 1.0)];
            let s = r.range(0.01, 0.6);
            let base = soup.positions.len() as u32;
            for _ in 0..3 {
                soup.positions
                    .push(std::array::from_fn(|a| c[a] + s * r.range(-1.0, 1.0)));
            }
            soup.indices.push([base, base + 1, base + 2]);
        }
        // A degenerate triangle and an out-of-range one.
        soup.positions.push([0.0, 0.0, 0.0]);
        let z = soup.positions.len() as u32 - 1;
        soup.indices.push([z, z, z]);
        soup.indices.push([0, 1, 9999]);
        let meshes = vec![soup, icosphere(2), MeshGeometry::default(), grid(6, 0.0)];
        let mut instances = vec![
            Instance {
                mesh: 0,
                scene_from_mesh: Affine3::IDENTITY,
            },
            Instance {
                mesh: 3,
                scene_from_mesh: Affine3 {
                    rows: [
                        [1.0, 0.0, 0.0, -3.0],
                        [0.0, 1.0, 0.0, -3.0],
                        [0.0, 0.0, 1.0, -2.5],
                    ],
                },
            },
            Instance {
                mesh: 2,
                scene_from_mesh: Affine3::IDENTITY,
            },
            Instance {
                mesh: 1,
                scene_from_mesh: Affine3 {
                    rows: [
                        [0.0, 0.0, 0.0, 1.0],
                        [0.0, 1.0, 0.0, 0.0],
                        [0.0, 0.0, 1.0, 0.0],
                    ],
                },
            },
        ];
        for k in 0..40 {
            let rot = rotation(r.unit(), r.range(0.0, 6.3));
            let s = [r.range(0.3, 2.5), r.range(0.3, 2.5), r.range(0.3, 2.5)];
            let t = [r.range(-5.0, 5.0), r.range(-5.0, 5.0), r.range(-5.0, 5.0)];
            instances.push(Instance {
                mesh: [0, 1, 3][k % 3],
                scene_from_mesh: Affine3 {
                    rows: std::array::from_fn(|i| {
                        [rot[i][0] * s[0], rot[i][1] * s[1], rot[i][2] * s[2], t[i]]
                    }),
                },
            });
        }
        TraceScene {
            origin_in_world: nalgebra::Vector3::zeros(),
            meshes,
            instances,
        }
    }

    fn packet_against_reference(
        caster: &dyn RayCaster,
        scene: &TraceScene,
        p: &RayPacket,
    ) -> usize {
        let sentinel = Hit {
            t: -7.0,
            instance: 7,
            prim: 7,
            u: 7.0,
            v: 7.0,
        };
        let mut hits = [sentinel; PACKET_SIZE];
        caster.cast_packet(p, &mut hits);
        let mut n_hit = 0;
        for (l, h) in hits.iter().enumerate() {
            if l >= p.len {
                assert_eq!(*h, sentinel, "lane {l} past len {} written", p.len);
                continue;
            }
            let d = [p.dir[0][l], p.dir[1][l], p.dir[2][l]];
            let want = brute_force_ray(scene, p.origin, d, p.t_min, p.t_max);
            assert_eq!(*h, want, "packet lane {l}: origin {:?} dir {d:?}", p.origin);
            assert_eq!(
                caster.cast_ray(p.origin, d, p.t_min, p.t_max),
                want,
                "single ray {d:?}"
            );
            n_hit += usize::from(want.is_hit());
        }
        n_hit
    }

    /// A packet of `len` rays from `o` around direction `c`, spread by `spread`, scaled
    /// lengths.
    fn cone_packet(r: &mut Lcg, o: [f32; 3], c: [f32; 3], spread: f32, len: usize) -> RayPacket {
        let u = normalize(cross3(
            c,
            if c[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            },
        ));
        let v = cross3(c, u);
        let mut p = RayPacket {
            origin: o,
            dir: [[0.0; PACKET_SIZE]; 3],
            len,
            t_min: 0.0,
            t_max: f32::INFINITY,
        };
        let scale = r.range(0.5, 2.0);
        for l in 0..PACKET_SIZE {
            let (x, y) = ((l % 8) as f32 / 7.0 - 0.5, (l / 8) as f32 / 7.0 - 0.5);
            let (x, y) = (x + 0.05 * r.range(-1.0, 1.0), y + 0.05 * r.range(-1.0, 1.0));
            for a in 0..3 {
                p.dir[a][l] = scale * (c[a] + spread * (x * u[a] + y * v[a]));
            }
        }
        p
    }

    #[test]
    fn single_rays_match_brute_force_on_random_scenes() {
        for seed in 1..4 {
            let scene = random_scene(seed);
            let caster = build_default(&scene);
            assert_eq!(caster.name(), "bvh");
            let mut r = Lcg(seed * 77);
            let mut hits = 0;
            for k in 0..3000 {
                let o = [r.range(-8.0, 8.0), r.range(-8.0, 8.0), r.range(-8.0, 8.0)];
                // Aim at the scene's middle half of the time so many rays hit.
                let d = if k % 2 == 0 {
                    r.unit().map(|x| x * r.range(0.2, 3.0))
                } else {
                    let tgt = [r.range(-3.0, 3.0), r.range(-3.0, 3.0), r.range(-3.0, 3.0)];
                    std::array::from_fn(|a| tgt[a] - o[a])
                };
                let (t_min, t_max) = match k % 4 {
                    0 => (0.0, f32::INFINITY),
                    1 => (r.range(0.0, 2.0), r.range(2.0, 6.0)),
                    2 => (-f32::INFINITY, f32::INFINITY),
                    _ => (0.5, 0.4),
                };
                let want = brute_force_ray(&scene, o, d, t_min, t_max);
                let got = caster.cast_ray(o, d, t_min, t_max);
                assert_eq!(
                    got, want,
                    "seed {seed} ray {k}: o {o:?} d {d:?} [{t_min}, {t_max}]"
                );
                if want.is_hit() {
                    hits += 1;
                    assert!(want.t >= t_min && want.t <= t_max);
                    assert!(want.u >= 0.0 && want.v >= 0.0 && want.u + want.v <= 1.0 + 1e-5);
                }
            }
            assert!(hits > 500, "too few hits to mean anything: {hits}");
        }
    }

    #[test]
    fn packets_match_brute_force_on_random_scenes() {
        for seed in 1..4 {
            let scene = random_scene(seed);
            let caster = build_default(&scene);
            let mut r = Lcg(seed * 1234);
            let mut hits = 0;
            for k in 0..300 {
                let o = [r.range(-9.0, 9.0), r.range(-9.0, 9.0), r.range(-9.0, 9.0)];
                let tgt = [r.range(-3.0, 3.0), r.range(-3.0, 3.0), r.range(-3.0, 3.0)];
                let c = normalize(std::array::from_fn(|a| tgt[a] - o[a]));
                let spread = [0.02, 0.2, 0.8, 3.0][k % 4];
                let len = if k % 5 == 0 {
                    1 + (r.f() * 63.0) as usize
                } else {
                    PACKET_SIZE
                };
                let mut p = cone_packet(&mut r, o, c, spread, len);
                match k % 7 {
                    1 => (p.t_min, p.t_max) = (r.range(0.0, 3.0), r.range(3.0, 12.0)),
                    2 => p.t_max = r.range(0.0, 5.0),
                    3 => p.t_min = -1.0,
                    _ => {}
                }
                hits += packet_against_reference(caster.as_ref(), &scene, &p);
            }
            assert!(hits > 3000, "too few hits to mean anything: {hits}");
        }
    }

    #[test]
    fn far_from_the_scene_origin_matches_brute_force() {
        // Coordinates in the kilometres: rounding of the transforms and of origin-relative
        // vertices must not make the culling drop hits.
        let mut scene = random_scene(4);
        let shift = [3000.0f32, -2000.0, 500.0];
        for i in &mut scene.instances {
            for (row, s) in i.scene_from_mesh.rows.iter_mut().zip(shift) {
                row[3] += s;
            }
        }
        let caster = build_default(&scene);
        let mut r = Lcg(99);
        let mut hits = 0;
        for k in 0..150 {
            let o: [f32; 3] = std::array::from_fn(|a| shift[a] + r.range(-9.0, 9.0));
            let tgt: [f32; 3] = std::array::from_fn(|a| shift[a] + r.range(-3.0, 3.0));
            let c = normalize(std::array::from_fn(|a| tgt[a] - o[a]));
            let p = cone_packet(&mut r, o, c, [0.02, 0.2][k % 2], PACKET_SIZE);
            hits += packet_against_reference(caster.as_ref(), &scene, &p);
        }
        assert!(hits > 1000, "{hits}");
    }

    #[test]
    fn incoherent_packets_match_brute_force() {
        let scene = random_scene(9);
        let caster = build_default(&scene);
        let mut r = Lcg(5);
        for _ in 0..20 {
            let mut p = cone_packet(&mut r, [0.5, -0.3, 0.2], [1.0, 0.0, 0.0], 0.0, PACKET_SIZE);
            for l in 0..PACKET_SIZE {
                let d = r.unit();
                for a in 0..3 {
                    p.dir[a][l] = d[a];
                }
            }
            // A zero direction never hits.
            p.dir[0][3] = 0.0;
            p.dir[1][3] = 0.0;
            p.dir[2][3] = 0.0;
            packet_against_reference(caster.as_ref(), &scene, &p);
        }
    }

    #[test]
    fn rays_through_shared_edges_and_vertices_do_not_leak() {
        // Identity instance of a closed sphere and a grid plane whose edges and vertices
        // sit on exactly representable coordinates.
        let scene = TraceScene {
            origin_in_world: nalgebra::Vector3::zeros(),
            meshes: vec![icosphere(3), grid(8, 0.0)],
            instances: vec![
                Instance {
                    mesh: 0,
                    scene_from_mesh: Affine3::IDENTITY,
                },
                Instance {
                    mesh: 1,
                    scene_from_mesh: Affine3 {
                        rows: [
                            [1.0, 0.0, 0.0, 100.0],
                            [0.0, 1.0, 0.0, 0.0],
                            [0.0, 0.0, 1.0, 0.0],
                        ],
                    },
                },
            ],
        };
        let caster = build_default(&scene);
        let sphere = &scene.meshes[0];
        let mut r = Lcg(42);
        let mut targets: Vec<[f32; 3]> = sphere.positions.clone();
        for t in &sphere.indices {
            for k in 0..3 {
                let (a, b) = (
                    sphere.positions[t[k] as usize],
                    sphere.positions[t[(k + 1) % 3] as usize],
                );
                for lam in [0.5f32, 0.25, 1.0 / 3.0] {
                    targets.push(std::array::from_fn(|i| a[i] + (b[i] - a[i]) * lam));
                }
            }
        }
        for (n, tgt) in targets.iter().enumerate() {
            // From outside, within 45° of the surface normal (no silhouette edges, where a
            // ray a rounding error off the edge legitimately misses).
            let nrm = normalize(*tgt);
            let u = r.unit();
            let dir = normalize(std::array::from_fn(|a| nrm[a] + 0.7 * u[a]));
            let o: [f32; 3] = std::array::from_fn(|a| tgt[a] + 40.0 * dir[a]);
            let d: [f32; 3] = std::array::from_fn(|a| tgt[a] - o[a]);
            let h = caster.cast_ray(o, d, 0.0, f32::INFINITY);
            assert!(
                h.is_hit() && h.instance == 0 && (h.t - 1.0).abs() < 1e-4,
                "target {n} {tgt:?} from {o:?} leaked: {h:?}"
            );
            assert_eq!(h, brute_force_ray(&scene, o, d, 0.0, f32::INFINITY));
        }
        // Packets from one far origin aimed at 64 targets each (a narrow cone: the packet
        // path, not the single-ray fallback).
        let o = [0.3, -0.2, 45.0];
        let visible: Vec<[f32; 3]> = targets.iter().filter(|t| t[2] > 0.75).copied().collect();
        assert!(visible.len() > 200);
        for chunk in visible.chunks(PACKET_SIZE) {
            let mut p = RayPacket {
                origin: o,
                dir: [[0.0; PACKET_SIZE]; 3],
                len: chunk.len(),
                t_min: 0.0,
                t_max: f32::INFINITY,
            };
            for (l, tgt) in chunk.iter().enumerate() {
                for a in 0..3 {
                    p.dir[a][l] = tgt[a] - o[a];
                }
            }
            let mut hits = [Hit::MISS; PACKET_SIZE];
            caster.cast_packet(&p, &mut hits);
            for (l, h) in hits.iter().enumerate().take(p.len) {
                assert!(
                    h.is_hit() && (h.t - 1.0).abs() < 1e-4,
                    "packet lane {l} leaked: {h:?}"
                );
            }
            packet_against_reference(caster.as_ref(), &scene, &p);
        }
        // Grid: integer and half-integer points are edges and vertices.
        let o = [103.7f32, 3.3, 6.0];
        let mut p = RayPacket {
            origin: o,
            dir: [[0.0; PACKET_SIZE]; 3],
            len: PACKET_SIZE,
            t_min: 0.0,
            t_max: f32::INFINITY,
        };
        for l in 0..PACKET_SIZE {
            let tgt = [
                100.5 + 0.5 * (l % 8) as f32,
                0.5 + 0.5 * (l / 8) as f32,
                0.0,
            ];
            for a in 0..3 {
                p.dir[a][l] = tgt[a] - o[a];
            }
            let h = caster.cast_ray(
                o,
                [p.dir[0][l], p.dir[1][l], p.dir[2][l]],
                0.0,
                f32::INFINITY,
            );
            assert!(
                h.is_hit() && h.instance == 1 && (h.t - 1.0).abs() < 1e-6,
                "grid ray {l}: {h:?}"
            );
        }
        assert_eq!(
            packet_against_reference(caster.as_ref(), &scene, &p),
            PACKET_SIZE
        );
    }

    #[test]
    fn parallel_rays_clipping_and_ties() {
        let plane = grid(4, 0.0);
        // Two copies of the same triangle in one mesh (prims 0 and 1), then the mesh
        // twice at the same place (instances 1 and 2): ties everywhere.
        let twin = MeshGeometry {
            positions: vec![[0.0, 0.0, 1.0], [4.0, 0.0, 1.0], [0.0, 4.0, 1.0]],
            indices: vec![[0, 1, 2], [0, 1, 2]],
        };
        let scene = TraceScene {
            origin_in_world: nalgebra::Vector3::zeros(),
            meshes: vec![plane, twin],
            instances: vec![
                Instance {
                    mesh: 0,
                    scene_from_mesh: Affine3::IDENTITY,
                },
                Instance {
                    mesh: 1,
                    scene_from_mesh: Affine3::IDENTITY,
                },
                Instance {
                    mesh: 1,
                    scene_from_mesh: Affine3::IDENTITY,
                },
            ],
        };
        let caster = build_default(&scene);
        // In the plane and parallel above it: misses.
        assert_eq!(
            caster.cast_ray([-1.0, 0.5, 0.0], [1.0, 0.0, 0.0], 0.0, f32::INFINITY),
            Hit::MISS
        );
        assert_eq!(
            caster.cast_ray([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 0.0, f32::INFINITY),
            Hit::MISS
        );
        // Straight down onto the twins at t = 4, the plane at t = 5.
        let (o, d) = ([0.5f32, 0.5, 5.0], [0.0f32, 0.0, -1.0]);
        let h = caster.cast_ray(o, d, 0.0, f32::INFINITY);
        assert_eq!((h.instance, h.prim, h.t), (1, 0, 4.0));
        assert_eq!(caster.cast_ray(o, d, 0.0, 4.0).t, 4.0, "t_max is inclusive");
        assert_eq!(caster.cast_ray(o, d, 4.0, 4.0).t, 4.0, "t_min is inclusive");
        assert_eq!(caster.cast_ray(o, d, 0.0, 3.999), Hit::MISS);
        let h = caster.cast_ray(o, d, 4.001, f32::INFINITY);
        assert_eq!((h.instance, h.t), (0, 5.0));
        assert_eq!(caster.cast_ray(o, d, 5.001, f32::INFINITY), Hit::MISS);
        let h = caster.cast_ray(o, d, 4.001, 5.0);
        assert!((h.u - 0.5 / 1.0).abs() < 1.0 && h.u >= 0.0 && h.v >= 0.0);
        // The same through packets (coherent, so the packet path), short and full.
        let mut r = Lcg(3);
        for (t_min, t_max, len) in [
            (0.0, f32::INFINITY, 64),
            (4.001, 9.0, 13),
            (0.0, 3.5, 1),
            (5.0, 5.0, 64),
        ] {
            let mut p = cone_packet(&mut r, o, d, 0.3, len);
            p.t_min = t_min;
            p.t_max = t_max;
            packet_against_reference(caster.as_ref(), &scene, &p);
        }
    }

    #[test]
    fn empty_scenes_and_meshes_miss() {
        let empty = build_default(&TraceScene::default());
        assert_eq!(
            empty.cast_ray([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY),
            Hit::MISS
        );
        let mut r = Lcg(1);
        let p = cone_packet(&mut r, [0.0; 3], [0.0, 0.0, 1.0], 0.1, 40);
        let mut hits = [Hit::MISS; PACKET_SIZE];
        empty.cast_packet(&p, &mut hits);
        assert!(hits.iter().all(|h| *h == Hit::MISS));
        assert!(empty.memory_bytes() < 1024);
        // Instances of an empty mesh only.
        let scene = TraceScene {
            origin_in_world: nalgebra::Vector3::zeros(),
            meshes: vec![MeshGeometry::default()],
            instances: vec![
                Instance {
                    mesh: 0,
                    scene_from_mesh: Affine3::IDENTITY,
                };
                3
            ],
        };
        let c = build_default(&scene);
        assert_eq!(
            c.cast_ray([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY),
            Hit::MISS
        );
        c.cast_packet(&p, &mut hits);
        assert!(hits.iter().all(|h| *h == Hit::MISS));
    }

    #[test]
    fn build_and_results_are_deterministic() {
        let scene = synthetic_vegetation_scene(11, 60_000);
        let a = TwoLevelBvh::build(&scene);
        let b = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("a one-thread pool")
            .install(|| TwoLevelBvh::build(&scene));
        assert_eq!(a.stats(), b.stats());
        assert_eq!(a.memory_bytes(), b.memory_bytes());
        let view = bench_view(&scene, 0);
        for (tx, ty) in [(0, 0), (160, 120), (320, 240), (600, 400)] {
            let p = TileRays::new(640, 480, tx, ty).packet(&view);
            let mut ha = [Hit::MISS; PACKET_SIZE];
            let mut hb = [Hit::MISS; PACKET_SIZE];
            a.cast_packet(&p, &mut ha);
            b.cast_packet(&p, &mut hb);
            assert_eq!(ha, hb);
        }
    }

    #[test]
    fn synthetic_scene_is_deterministic_and_sized() {
        let a = synthetic_vegetation_scene(3, 200_000);
        let b = synthetic_vegetation_scene(3, 200_000);
        assert_eq!(a.meshes, b.meshes);
        assert_eq!(a.instances, b.instances);
        let total: usize = a
            .instances
            .iter()
            .map(|i| a.meshes[i.mesh as usize].indices.len())
            .sum();
        assert!((180_000..=220_000).contains(&total), "{total}");
        assert_ne!(
            synthetic_vegetation_scene(4, 200_000).instances,
            a.instances
        );
        // Tiny budgets still give a valid scene.
        let s = synthetic_vegetation_scene(1, 10);
        assert!(s.instances.len() >= 2 && s.meshes.iter().all(|m| !m.indices.is_empty()));
    }

    #[test]
    fn bench_views_match_brute_force() {
        let scene = synthetic_vegetation_scene(5, 30_000);
        let caster = build_default(&scene);
        let mut hits = 0;
        for f in 0..2 {
            let view = bench_view(&scene, f);
            for (tx, ty) in [
                (0, 0),
                (320, 200),
                (8, 240),
                (632, 472),
                (312, 232),
                (100, 300),
            ] {
                let p = TileRays::new(640, 480, tx, ty).packet(&view);
                hits += packet_against_reference(caster.as_ref(), &scene, &p);
            }
        }
        assert!(hits > 200, "{hits}");
        assert!(measure_mrays(caster.as_ref(), &scene, 64, 48, 1) > 0.0);
    }

    /// Throughput on the 1.5 M-triangle synthetic scene (release mode:
    /// `cargo test -p vinebench-sim --release --lib render::trace -- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn throughput_on_synthetic_vegetation() {
        let scene = synthetic_vegetation_scene(1, 1_500_000);
        let start = std::time::Instant::now();
        let bvh = TwoLevelBvh::build(&scene);
        let build = start.elapsed().as_secs_f64();
        let stats = bvh.stats();
        let total: usize = scene
            .instances
            .iter()
            .map(|i| scene.meshes[i.mesh as usize].indices.len())
            .sum();
        println!(
            "scene: {total} instanced triangles, {} unique, {} instances; build {build:.3} s; memory {:.1} MB; {stats:?}",
            scene.meshes.iter().map(|m| m.indices.len()).sum::<usize>(),
            scene.instances.len(),
            bvh.memory_bytes() as f64 / 1e6
        );
        let big = synthetic_vegetation_scene(2, 1_500_000);
        let one_mesh = TraceScene {
            origin_in_world: big.origin_in_world,
            meshes: vec![MeshGeometry {
                positions: big
                    .instances
                    .iter()
                    .flat_map(|i| {
                        big.meshes[i.mesh as usize]
                            .positions
                            .iter()
                            .map(|&p| i.scene_from_mesh.point(p))
                    })
                    .collect(),
                indices: {
                    let mut base = 0u32;
                    let mut idx = Vec::new();
                    for i in &big.instances {
                        let m = &big.meshes[i.mesh as usize];
                        idx.extend(m.indices.iter().map(|t| t.map(|v| v + base)));
                        base += m.positions.len() as u32;
                    }
                    idx
                },
            }],
            instances: vec![Instance {
                mesh: 0,
                scene_from_mesh: Affine3::IDENTITY,
            }],
        };
        let start = std::time::Instant::now();
        let flat = TwoLevelBvh::build(&one_mesh);
        println!(
            "flattened {}-triangle single mesh: build {:.3} s, memory {:.1} MB",
            one_mesh.meshes[0].indices.len(),
            start.elapsed().as_secs_f64(),
            flat.memory_bytes() as f64 / 1e6
        );
        // Best of a few runs: the machine may be shared.
        let best = |f: &dyn Fn() -> f64, n: usize| (0..n).map(|_| f()).fold(0.0, f64::max);
        let _ = measure_mrays(&bvh, &scene, 640, 480, 1);
        let packet = best(&|| measure_mrays(&bvh, &scene, 640, 480, 8), 5);
        let single = best(&|| measure_mrays_single(&bvh, &scene, 640, 480, 2), 3);
        let flat_packet = best(&|| measure_mrays(&flat, &one_mesh, 640, 480, 4), 3);
        println!(
            "640x480, {} threads (best of runs): packets {packet:.1} Mrays/s, single rays {single:.1} Mrays/s, flattened scene packets {flat_packet:.1} Mrays/s",
            rayon::current_num_threads()
        );
    }
}
