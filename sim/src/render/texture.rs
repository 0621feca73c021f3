//! Procedural albedo textures, baked once per scene.
//!
//! The renderer shades with Lambert in linear reflectance; these textures give soil, bark,
//! leaves, posts, grapes and wires real detail (so feature detectors such as ORB/FAST find
//! corners on them) while their colours keep a sensible green-red vegetation index
//! [`grvi`]: leaves clearly positive, soil, bark and posts negative.
//!
//! # Noise
//!
//! All noise is a pure function of the coordinates and a `u32` seed through an integer
//! hash ([`hash_u32`], [`hash2`]): no random-number state. Every noise function is
//! periodic with integer lattice periods `(px, py)`, so a texture that only uses lattice
//! frequencies that are whole numbers of cycles per texture tiles seamlessly. Each seed
//! shifts its lattice by its own fraction of a cell, so the lattice lines of the layers of
//! a texture do not all meet on the tile's edges (which would show the seam).
//!
//! # Texture coordinates and storage
//!
//! A [`Texture`] is `width × height` texels stored **sRGB-encoded** (`[u8; 3]`, 8 bits per
//! channel keep dark reflectances such as leaves at ~0.05 well resolved); every sampler
//! returns **linear** reflectance in `0..=1`. Texel `(i, j)` has its centre at
//! `u = (i + 0.5) / width`, `v = (j + 0.5) / height`; `u` runs right, `v` down, and
//! sampling wraps (period 1 in `u` and `v`). A mip chain (box-filtered in linear space)
//! is built at bake time for [`Texture::sample_lod`], with every level also decoded to
//! linear reflectance (16 bytes a texel) for that hot path.
//!
//! # Mapping conventions (advisory, see [`TextureKind::period_m`])
//!
//! - [`TextureKind::Soil`]: planar, `u` along world x and `v` along world y, one period
//!   per [`TextureKind::period_m`] (2 m).
//! - Cylinders ([`TextureKind::Bark`], [`TextureKind::Cordon`], [`TextureKind::Post`],
//!   [`TextureKind::Wire`]): `u` = angle around the axis / 2π, `v` = length along the axis
//!   / `period_m`; fissures, grain and streaks run along `v`.
//! - [`TextureKind::Leaf`], [`TextureKind::LeafUnderside`]: `[0, 1]²` spans the leaf's
//!   bounding square (not tileable): tip towards `v = 0`, petiole junction at
//!   [`LEAF_PETIOLE_UV`], five palmate main veins radiate from it.
//! - [`TextureKind::Grape`], [`TextureKind::GrapeWhite`]: berry-scale pattern, about 16
//!   berries per period (`period_m` 0.28 m, berries ≈ 17 mm).
//! - [`TextureKind::Carton`]: uniform brown with no detail at all (a featureless occluder).

use std::sync::LazyLock;
use wide::f32x4;

// ----------------------------------------------------------------------------------------
// Integer hash and noise.

/// A 32-bit integer hash with good avalanche (Wellons' "lowbias32").
pub fn hash_u32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// Hash of the lattice point `(ix, iy)` under `seed`.
pub fn hash2(ix: i32, iy: i32, seed: u32) -> u32 {
    hash_u32(
        (ix as u32).wrapping_mul(0x8da6_b343)
            ^ (iy as u32).wrapping_mul(0xd816_3841)
            ^ seed.wrapping_mul(0x9e37_79b9),
    )
}

/// A hash mapped to `[0, 1)`.
pub fn hash_unit(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Floor as an integer, without a libm call (`x` well inside the `i32` range).
fn ifloor(x: f32) -> i32 {
    let i = x as i32;
    if (i as f32) > x { i - 1 } else { i }
}

/// Quintic fade `6t⁵ − 15t⁴ + 10t³`.
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Hermite smoothstep of `x` between `e0` and `e1`.
pub fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

/// Wraps a lattice index into `0..period` (`period ≥ 1`).
fn wrap(i: i32, period: i32) -> i32 {
    // Bakes query in-range lattice points almost always: skip the division then.
    if (0..period).contains(&i) {
        i
    } else {
        i.rem_euclid(period.max(1))
    }
}

/// A seed-dependent shift of the lattice by a fraction of a cell in x and y, so that the
/// lattice lines of different layers (different seeds) do not all pass through `u = 0`
/// and `v = 0`, which would mark the tile seam. Shifting keeps the periods.
fn lattice_shift(seed: u32) -> (f32, f32) {
    (
        (seed.wrapping_mul(0x9e37_79b9) >> 8) as f32 * (1.0 / 16_777_216.0),
        (seed.wrapping_mul(0x85eb_ca6b) >> 8) as f32 * (1.0 / 16_777_216.0),
    )
}

/// Tileable value noise in `[0, 1]`: hashed lattice values at integer points, quintic
/// interpolation, lattice periods `px`, `py` (at least 1).
pub fn value_noise(x: f32, y: f32, px: i32, py: i32, seed: u32) -> f32 {
    let (sx, sy) = lattice_shift(seed);
    let (x, y) = (x + sx, y + sy);
    let (x0, y0) = (ifloor(x), ifloor(y));
    let (fx, fy) = (fade(x - x0 as f32), fade(y - y0 as f32));
    let (ix0, iy0) = (wrap(x0, px), wrap(y0, py));
    let (ix1, iy1) = (wrap(x0 + 1, px), wrap(y0 + 1, py));
    let v = |ix, iy| hash_unit(hash2(ix, iy, seed));
    lerp(
        lerp(v(ix0, iy0), v(ix1, iy0), fx),
        lerp(v(ix0, iy1), v(ix1, iy1), fx),
        fy,
    )
}

/// Tileable gradient (Perlin) noise, about `[-1, 1]` with zero mean; lattice periods
/// `px`, `py` (at least 1).
pub fn gradient_noise(x: f32, y: f32, px: i32, py: i32, seed: u32) -> f32 {
    // Eight unit gradients at 22.5° + k·45°: none is axis-aligned, so zero crossings
    // (used for fissures and cracks) do not line up with the lattice.
    const C: f32 = 0.923_879_5;
    const S: f32 = 0.382_683_43;
    const GRAD: [(f32, f32); 8] = [
        (C, S),
        (S, C),
        (-S, C),
        (-C, S),
        (-C, -S),
        (-S, -C),
        (S, -C),
        (C, -S),
    ];
    let (sx, sy) = lattice_shift(seed);
    let (x, y) = (x + sx, y + sy);
    let (x0, y0) = (ifloor(x), ifloor(y));
    let (tx, ty) = (x - x0 as f32, y - y0 as f32);
    let (ix0, iy0) = (wrap(x0, px), wrap(y0, py));
    let (ix1, iy1) = (wrap(x0 + 1, px), wrap(y0 + 1, py));
    let g = |ix, iy, dx: f32, dy: f32| {
        let (gx, gy) = GRAD[(hash2(ix, iy, seed) >> 29) as usize];
        gx * dx + gy * dy
    };
    let (fx, fy) = (fade(tx), fade(ty));
    let n = lerp(
        lerp(g(ix0, iy0, tx, ty), g(ix1, iy0, tx - 1.0, ty), fx),
        lerp(
            g(ix0, iy1, tx, ty - 1.0),
            g(ix1, iy1, tx - 1.0, ty - 1.0),
            fx,
        ),
        fy,
    );
    (n * 1.41).clamp(-1.0, 1.0)
}

/// Fractal Brownian motion of [`gradient_noise`]: `octaves` octaves, each at twice the
/// frequency (and period) and half the amplitude of the previous, normalised to about
/// `[-1, 1]`. Tileable with base periods `px`, `py`.
pub fn fbm(x: f32, y: f32, px: i32, py: i32, octaves: u32, seed: u32) -> f32 {
    let (mut sum, mut amp, mut norm) = (0.0, 1.0, 0.0);
    let (mut x, mut y, mut px, mut py) = (x, y, px, py);
    for o in 0..octaves {
        sum += amp * gradient_noise(x, y, px, py, seed.wrapping_add(o.wrapping_mul(0x68e3_1da4)));
        norm += amp;
        amp *= 0.5;
        x *= 2.0;
        y *= 2.0;
        px *= 2;
        py *= 2;
    }
    if norm > 0.0 {
        (sum / norm * 1.5).clamp(-1.0, 1.0)
    } else {
        0.0
    }
}

/// The result of [`cellular`] noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    /// Distance to the nearest feature point, in lattice cells.
    pub f1: f32,
    /// Distance to the second-nearest feature point.
    pub f2: f32,
    /// Hash identifying the nearest feature point's (wrapped) cell, independent of the
    /// point's position in it.
    pub id: u32,
    /// Vector from the query point to the nearest feature point, x.
    pub dx: f32,
    /// Vector from the query point to the nearest feature point, y.
    pub dy: f32,
}

/// Offset of a cell's feature point from the cell's corner, from the cell's hash.
fn feature_offset(h: u32, jitter: f32) -> (f32, f32) {
    (
        0.5 + jitter * ((h & 0xffff) as f32 * (1.0 / 65_536.0) - 0.5),
        0.5 + jitter * ((h >> 16) as f32 * (1.0 / 65_536.0) - 0.5),
    )
}

/// Tileable cellular (Worley) noise: one feature point per lattice cell, jittered by up
/// to `jitter` (0 = a regular grid, 1 = anywhere in its cell); lattice periods `px`, `py`.
pub fn cellular(x: f32, y: f32, px: i32, py: i32, jitter: f32, seed: u32) -> Cell {
    let (sx, sy) = lattice_shift(seed);
    let (x, y) = (x + sx, y + sy);
    let (x0, y0) = (ifloor(x), ifloor(y));
    let (tx, ty) = (x - x0 as f32, y - y0 as f32);
    let (mut d1, mut d2) = (f32::MAX, f32::MAX);
    let (mut id, mut bdx, mut bdy) = (0u32, 0.0f32, 0.0f32);
    for j in -1..=1 {
        let wy = wrap(y0 + j, py);
        for i in -1..=1 {
            let h = hash2(wrap(x0 + i, px), wy, seed);
            let (ox, oy) = feature_offset(h, jitter);
            let (dx, dy) = (i as f32 + ox - tx, j as f32 + oy - ty);
            let d = dx * dx + dy * dy;
            // Select rather than branch: the comparisons are unpredictable.
            let nearer = d < d1;
            d2 = if nearer { d1 } else { d2.min(d) };
            d1 = if nearer { d } else { d1 };
            id = if nearer { h } else { id };
            bdx = if nearer { dx } else { bdx };
            bdy = if nearer { dy } else { bdy };
        }
    }
    Cell {
        f1: d1.sqrt(),
        f2: d2.sqrt(),
        id: hash_u32(id),
        dx: bdx,
        dy: bdy,
    }
}

/// Whether the cell with hash `h` holds a sparse feature at `density` (cheap, independent
/// enough of the jitter bits of `h`).
fn holds_feature(h: u32, density: f32) -> bool {
    ((h ^ (h >> 13)).wrapping_mul(0x2c1b_3c6d) >> 8) as f32 * (1.0 / 16_777_216.0) < density
}

/// The nearest of the sparse feature points near `(x, y)`: the cells, points and
/// [`Cell::id`]s are those of [`cellular`] with the same arguments, but only a fraction
/// `density` of the cells (chosen by their hash) hold a point. Only the 2×2 cells around
/// `(x, y)` are searched, which finds every point closer than `1 − jitter / 2` (in cells);
/// `None` when none of them holds one. [`Cell::f2`] is not computed (`f32::MAX`).
pub fn sparse_feature(
    x: f32,
    y: f32,
    px: i32,
    py: i32,
    jitter: f32,
    density: f32,
    seed: u32,
) -> Option<Cell> {
    let (sx, sy) = lattice_shift(seed);
    let (x, y) = (x + sx, y + sy);
    let (x0, y0) = (ifloor(x), ifloor(y));
    let (tx, ty) = (x - x0 as f32, y - y0 as f32);
    let di = if tx < 0.5 { -1 } else { 1 };
    let dj = if ty < 0.5 { -1 } else { 1 };
    let (mut best_d, mut best_h, mut best_dx, mut best_dy) = (f32::MAX, 0u32, 0.0f32, 0.0f32);
    for j in [0, dj] {
        let wy = wrap(y0 + j, py);
        for i in [0, di] {
            let h = hash2(wrap(x0 + i, px), wy, seed);
            if !holds_feature(h, density) {
                continue;
            }
            let (ox, oy) = feature_offset(h, jitter);
            let (dx, dy) = (i as f32 + ox - tx, j as f32 + oy - ty);
            let d = dx * dx + dy * dy;
            if d < best_d {
                (best_d, best_h, best_dx, best_dy) = (d, h, dx, dy);
            }
        }
    }
    (best_d < f32::MAX).then(|| Cell {
        f1: best_d.sqrt(),
        f2: f32::MAX,
        id: hash_u32(best_h),
        dx: best_dx,
        dy: best_dy,
    })
}

// ----------------------------------------------------------------------------------------
// Colour helpers.

/// The green-red vegetation index `(G − R) / (G + R)` of a linear colour (0 for black).
pub fn grvi(rgb: [f32; 3]) -> f32 {
    let s = rgb[0] + rgb[1];
    if s > 0.0 { (rgb[1] - rgb[0]) / s } else { 0.0 }
}

/// Linear reflectance of an sRGB-encoded byte.
pub fn decode_srgb(b: u8) -> f32 {
    SRGB_TO_LINEAR[usize::from(b)]
}

/// sRGB encoding of a linear reflectance (clamped to `0..=1`), rounded to a byte.
pub fn encode_srgb(lin: f32) -> u8 {
    let l = if lin.is_nan() {
        0.0
    } else {
        lin.clamp(0.0, 1.0)
    };
    let s = if l <= 0.003_130_8 {
        12.92 * l
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round() as u8
}

static SRGB_TO_LINEAR: LazyLock<[f32; 256]> = LazyLock::new(|| {
    std::array::from_fn(|i| {
        let s = i as f32 / 255.0;
        if s <= 0.040_45 {
            s / 12.92
        } else {
            ((s + 0.055) / 1.055).powf(2.4)
        }
    })
});

/// Resolution of the linear → sRGB table used when baking.
const ENCODE_STEPS: usize = 16_384;

static LINEAR_TO_SRGB: LazyLock<Vec<u8>> = LazyLock::new(|| {
    (0..=ENCODE_STEPS)
        .map(|i| encode_srgb(i as f32 / ENCODE_STEPS as f32))
        .collect()
});

/// Fast [`encode_srgb`] through the table `lut` (`&LINEAR_TO_SRGB`, dereferenced once by
/// the caller); NaN encodes as 0 (the saturating cast).
fn encode_with(lut: &[u8], lin: f32) -> u8 {
    lut[(lin.clamp(0.0, 1.0) * ENCODE_STEPS as f32 + 0.5) as usize]
}

type Rgb = [f32; 3];

fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        lerp(a[0], b[0], t),
        lerp(a[1], b[1], t),
        lerp(a[2], b[2], t),
    ]
}

/// Euclidean length of `(x, y)` (no overflow care needed at texture scales).
fn len2(x: f32, y: f32) -> f32 {
    (x * x + y * y).sqrt()
}

fn scale(a: Rgb, k: f32) -> Rgb {
    [a[0] * k, a[1] * k, a[2] * k]
}

// ----------------------------------------------------------------------------------------
// Textures.

/// What a baked texture depicts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TextureKind {
    /// Vineyard inter-row soil: clods, pebbles, dry-grass tufts, darker wet patches;
    /// tileable, one period ≈ 2 m × 2 m.
    Soil,
    /// Old grapevine trunk bark: shaggy plates split by vertical fissures (along `v`).
    Bark,
    /// Cordon (arm) bark: younger, finer and shallower fissures than [`TextureKind::Bark`].
    Cordon,
    /// Upper side of a vine leaf: midrib, palmate main veins, secondary and reticulate
    /// venation, mottling and a few spots. Not tileable.
    Leaf,
    /// Lower side of a vine leaf: lighter, greyer green with prominent veins.
    LeafUnderside,
    /// Weathered wooden post: grain and checks along `v`, knots.
    Post,
    /// Dark (red/black) grape bunch surface: berries with bloom speckle.
    Grape,
    /// Green-yellow (white) grape bunch surface.
    GrapeWhite,
    /// Galvanised steel wire: streaks along `v`, spangle, rust spots.
    Wire,
    /// Plain uniform brown carton: no texture at all (a featureless occluder).
    Carton,
}

impl TextureKind {
    /// Every kind.
    pub const ALL: [TextureKind; 10] = [
        TextureKind::Soil,
        TextureKind::Bark,
        TextureKind::Cordon,
        TextureKind::Leaf,
        TextureKind::LeafUnderside,
        TextureKind::Post,
        TextureKind::Grape,
        TextureKind::GrapeWhite,
        TextureKind::Wire,
        TextureKind::Carton,
    ];

    /// Recommended bake size (texels per edge): about 2 mm per texel on soil and 1 mm or
    /// finer on bark, posts and leaves; all kinds together take ≈ 6 MB with their mips.
    pub fn recommended_size(self) -> usize {
        match self {
            TextureKind::Soil => 1024,
            TextureKind::Bark
            | TextureKind::Cordon
            | TextureKind::Leaf
            | TextureKind::LeafUnderside
            | TextureKind::Post
            | TextureKind::Grape
            | TextureKind::GrapeWhite => 256,
            TextureKind::Wire => 64,
            TextureKind::Carton => 4,
        }
    }

    /// World length one texture period is designed to cover, m (advisory; see the module
    /// docs for how `u` and `v` are meant to be mapped). For the leaves, the edge of the
    /// leaf's bounding square.
    pub fn period_m(self) -> f32 {
        match self {
            TextureKind::Soil => 2.0,
            TextureKind::Bark => 0.25,
            TextureKind::Cordon => 0.15,
            TextureKind::Leaf | TextureKind::LeafUnderside => 0.15,
            TextureKind::Post => 0.35,
            TextureKind::Grape | TextureKind::GrapeWhite => 0.28,
            TextureKind::Wire => 0.5,
            TextureKind::Carton => 1.0,
        }
    }

    /// Whether the texture wraps seamlessly in `u` and `v` (all but the leaves).
    pub fn tileable(self) -> bool {
        !matches!(self, TextureKind::Leaf | TextureKind::LeafUnderside)
    }

    fn tag(self) -> u32 {
        match self {
            TextureKind::Soil => 1,
            TextureKind::Bark => 2,
            TextureKind::Cordon => 3,
            TextureKind::Leaf => 4,
            TextureKind::LeafUnderside => 5,
            TextureKind::Post => 6,
            TextureKind::Grape => 7,
            TextureKind::GrapeWhite => 8,
            TextureKind::Wire => 9,
            TextureKind::Carton => 10,
        }
    }
}

/// One mip level: `width × height` sRGB texels, row-major.
#[derive(Clone, Debug, PartialEq)]
struct Level {
    width: usize,
    height: usize,
    texels: Vec<[u8; 3]>,
}

/// A baked albedo texture: `width × height` sRGB-encoded texels, sampled as linear
/// reflectance with wrapping (see the module docs for the conventions).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major sRGB-encoded texels, row 0 at `v ≈ 0`.
    texels: Vec<[u8; 3]>,
    /// Mip levels 1.. (each half the previous size, box-filtered in linear space).
    mips: Vec<Level>,
    /// Every level (0 = full resolution, then the mips) decoded to linear reflectance,
    /// one aligned SIMD vector per texel: what [`Texture::sample_lod`], the shader's hot
    /// path, reads (the same values as decoding the sRGB texels, without the table
    /// look-ups).
    linear: Vec<LinearLevel>,
}

/// One mip level decoded to linear reflectance.
#[derive(Clone, Debug, PartialEq)]
struct LinearLevel {
    width: usize,
    height: usize,
    texels: Vec<LinearTexel>,
}

/// Linear `r, g, b` and a zero pad, aligned for one SIMD load.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
struct LinearTexel([f32; 4]);

impl LinearLevel {
    fn decode(width: usize, height: usize, texels: &[[u8; 3]]) -> LinearLevel {
        let texels = texels
            .iter()
            .map(|&t| {
                let [r, g, b] = decode(t);
                LinearTexel([r, g, b, 0.0])
            })
            .collect();
        LinearLevel {
            width,
            height,
            texels,
        }
    }

    /// [`bilinear`] on the decoded texels: the same lerps in the same order, four
    /// channels per operation, so the same bits.
    #[inline(always)]
    fn bilinear(&self, u: f32, v: f32) -> f32x4 {
        let (x0, x1, fx) = wrap_coord(u, self.width);
        let (y0, y1, fy) = wrap_coord(v, self.height);
        let t = |x: usize, y: usize| f32x4::from(self.texels[y * self.width + x].0);
        let lerp4 = |a: f32x4, b: f32x4, f: f32| a + (b - a) * f32x4::splat(f);
        let top = lerp4(t(x0, y0), t(x1, y0), fx);
        let bottom = lerp4(t(x0, y1), t(x1, y1), fx);
        lerp4(top, bottom, fy)
    }
}

/// Splits a wrapped texture coordinate into the two neighbouring texel indices and the
/// blend weight of the second (texel centres at `(i + 0.5) / n`).
#[inline(always)]
fn wrap_coord(t: f32, n: usize) -> (usize, usize, f32) {
    // Floor without a libm call; |t| ≥ 2²³ is an integer already (and wraps to 0).
    let floor = |x: f32| {
        if x.abs() < 8_388_608.0 {
            let i = x as i32 as f32;
            if i > x { i - 1.0 } else { i }
        } else {
            x
        }
    };
    let t = if t.is_finite() { t - floor(t) } else { 0.0 };
    let x = t * n as f32 - 0.5;
    let x0 = floor(x);
    let f = x - x0;
    // x0 is in -1..n here: wrap without a division.
    let i0 = if x0 < 0.0 {
        n - 1
    } else {
        (x0 as usize).min(n - 1)
    };
    let i1 = if i0 + 1 >= n { 0 } else { i0 + 1 };
    (i0, i1, f)
}

fn decode(t: [u8; 3]) -> Rgb {
    let lut: &[f32; 256] = &SRGB_TO_LINEAR;
    [
        lut[usize::from(t[0])],
        lut[usize::from(t[1])],
        lut[usize::from(t[2])],
    ]
}

fn bilinear(width: usize, height: usize, texels: &[[u8; 3]], u: f32, v: f32) -> Rgb {
    let (x0, x1, fx) = wrap_coord(u, width);
    let (y0, y1, fy) = wrap_coord(v, height);
    let t = |x: usize, y: usize| decode(texels[y * width + x]);
    let top = mix(t(x0, y0), t(x1, y0), fx);
    let bottom = mix(t(x0, y1), t(x1, y1), fx);
    mix(top, bottom, fy)
}

impl Texture {
    /// A texture from sRGB-encoded texels (row-major, `width × height`), building its
    /// mip chain; `None` when the sizes do not match or are zero.
    pub fn from_srgb(width: usize, height: usize, texels: Vec<[u8; 3]>) -> Option<Texture> {
        if width == 0 || height == 0 || texels.len() != width.checked_mul(height)? {
            return None;
        }
        let lut: &[u8] = &LINEAR_TO_SRGB;
        let mut mips: Vec<Level> = Vec::new();
        let (mut w, mut h) = (width, height);
        while w > 1 || h > 1 {
            let src = mips.last().map_or(&texels[..], |l| &l.texels[..]);
            let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
            let mut out = Vec::with_capacity(nw * nh);
            for y in 0..nh {
                for x in 0..nw {
                    let mut acc = [0.0f32; 3];
                    let (sx, sy) = ((2 * x).min(w - 1), (2 * y).min(h - 1));
                    let (sx1, sy1) = ((sx + 1).min(w - 1), (sy + 1).min(h - 1));
                    for (xx, yy) in [(sx, sy), (sx1, sy), (sx, sy1), (sx1, sy1)] {
                        let c = decode(src[yy * w + xx]);
                        for k in 0..3 {
                            acc[k] += 0.25 * c[k];
                        }
                    }
                    out.push(acc.map(|a| encode_with(lut, a)));
                }
            }
            mips.push(Level {
                width: nw,
                height: nh,
                texels: out,
            });
            (w, h) = (nw, nh);
        }
        let linear = std::iter::once(LinearLevel::decode(width, height, &texels))
            .chain(
                mips.iter()
                    .map(|m| LinearLevel::decode(m.width, m.height, &m.texels)),
            )
            .collect();
        Some(Texture {
            width,
            height,
            texels,
            mips,
            linear,
        })
    }

    /// The sRGB-encoded texels, row-major.
    pub fn texels(&self) -> &[[u8; 3]] {
        &self.texels
    }

    /// Linear reflectance of texel `(x, y)` (indices wrap).
    pub fn texel(&self, x: usize, y: usize) -> [f32; 3] {
        decode(self.texels[(y % self.height) * self.width + x % self.width])
    }

    /// Bilinearly filtered linear reflectance at `(u, v)`, wrapping (period 1).
    pub fn sample(&self, u: f32, v: f32) -> [f32; 3] {
        bilinear(self.width, self.height, &self.texels, u, v)
    }

    /// Linear reflectance of the texel containing `(u, v)`, wrapping (period 1).
    pub fn sample_nearest(&self, u: f32, v: f32) -> [f32; 3] {
        let f = |t: f32, n: usize| {
            let t = if t.is_finite() { t - t.floor() } else { 0.0 };
            ((t * n as f32) as usize).min(n - 1)
        };
        self.texel(f(u, self.width), f(v, self.height))
    }

    /// Number of mip levels including the full-resolution one.
    pub fn mip_levels(&self) -> usize {
        1 + self.mips.len()
    }

    /// Trilinearly filtered linear reflectance at `(u, v)` and level of detail `lod`
    /// (`log2` of the footprint in full-resolution texels; `≤ 0` is [`Texture::sample`]).
    /// Use it to avoid aliasing when a pixel covers many texels.
    pub fn sample_lod(&self, u: f32, v: f32, lod: f32) -> [f32; 3] {
        let max = self.mips.len() as f32;
        let lod = if lod.is_nan() {
            0.0
        } else {
            lod.clamp(0.0, max)
        };
        let l0 = lod as usize;
        let f = lod - l0 as f32;
        let at = |l: usize| self.linear[l.min(self.linear.len() - 1)].bilinear(u, v);
        let a = at(l0);
        let c = if f > 0.0 && l0 < self.mips.len() {
            let b = at(l0 + 1);
            a + (b - a) * f32x4::splat(f)
        } else {
            a
        };
        let c = c.to_array();
        [c[0], c[1], c[2]]
    }

    /// Mean linear reflectance over all texels.
    pub fn mean_linear(&self) -> [f32; 3] {
        let mut acc = [0.0f64; 3];
        for t in &self.texels {
            let c = decode(*t);
            for k in 0..3 {
                acc[k] += f64::from(c[k]);
            }
        }
        let n = self.texels.len().max(1) as f64;
        acc.map(|a| (a / n) as f32)
    }

    /// Bytes of texel storage: the sRGB texels and mips, and their decoded linear copy.
    pub fn memory_bytes(&self) -> usize {
        3 * (self.texels.len() + self.mips.iter().map(|m| m.texels.len()).sum::<usize>())
            + self
                .linear
                .iter()
                .map(|l| l.texels.len() * std::mem::size_of::<LinearTexel>())
                .sum::<usize>()
    }
}

/// Bakes a `size × size` texture of `kind` from `seed` (`size` is raised to at least 1).
/// The same `(kind, size, seed)` always gives the same texels; a different seed gives a
/// different texture of the same look (except [`TextureKind::Carton`], which is uniform).
pub fn bake(kind: TextureKind, size: usize, seed: u64) -> Texture {
    let size = size.max(1);
    let prep = Prepared::new(kind, size, seed);
    let inv = 1.0 / size as f32;
    let mut texels = vec![[0u8; 3]; size * size];
    // Rows are independent pure functions of (u, v): bake bands of rows in parallel.
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(size.div_ceil(64))
        .max(1);
    let rows_per_band = size.div_ceil(threads);
    let lut: &[u8] = &LINEAR_TO_SRGB;
    let fill = |first_row: usize, band: &mut [[u8; 3]]| {
        for (r, row) in band.chunks_mut(size).enumerate() {
            let v = ((first_row + r) as f32 + 0.5) * inv;
            for (i, t) in row.iter_mut().enumerate() {
                let u = (i as f32 + 0.5) * inv;
                let [r, g, b] = prep.color(u, v);
                *t = [
                    encode_with(lut, r),
                    encode_with(lut, g),
                    encode_with(lut, b),
                ];
            }
        }
    };
    if threads == 1 {
        fill(0, &mut texels);
    } else {
        std::thread::scope(|scope| {
            for (b, band) in texels.chunks_mut(rows_per_band * size).enumerate() {
                let fill = &fill;
                scope.spawn(move || fill(b * rows_per_band, band));
            }
        });
    }
    match Texture::from_srgb(size, size, texels) {
        Some(t) => t,
        None => unreachable!("size ≥ 1 and size² texels"),
    }
}

/// Resolution of the precomputed grid of smooth soil layers.
const SMOOTH_GRID: usize = 256;

/// Everything one bake shares between texels.
struct Prepared {
    kind: TextureKind,
    seeds: Seeds,
    /// Lattice frequency of texel-scale grain (half the bake size).
    fine: i32,
    /// For large soil bakes, the smooth layers (base tone, wetness) on a periodic
    /// `SMOOTH_GRID²` grid, bilinearly interpolated; empty: evaluate them per texel.
    smooth: Vec<[f32; SOIL_SMOOTH]>,
}

impl Prepared {
    fn new(kind: TextureKind, size: usize, seed: u64) -> Prepared {
        let mut prep = Prepared {
            kind,
            seeds: Seeds::new(kind, seed),
            fine: (size / 2).max(1) as i32,
            smooth: Vec::new(),
        };
        if kind == TextureKind::Soil && size > SMOOTH_GRID {
            let inv = 1.0 / SMOOTH_GRID as f32;
            prep.smooth = (0..SMOOTH_GRID * SMOOTH_GRID)
                .map(|k| {
                    let (i, j) = (k % SMOOTH_GRID, k / SMOOTH_GRID);
                    soil_smooth(i as f32 * inv, j as f32 * inv, &prep.seeds)
                })
                .collect();
        }
        prep
    }

    /// The smooth soil layers at `(u, v)`: from the grid when there is one.
    fn soil_smooth(&self, u: f32, v: f32) -> [f32; SOIL_SMOOTH] {
        if self.smooth.is_empty() {
            return soil_smooth(u, v, &self.seeds);
        }
        let n = SMOOTH_GRID as f32;
        let (x, y) = (u * n, v * n);
        let (x0, y0) = (ifloor(x), ifloor(y));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let g = SMOOTH_GRID as i32;
        let (ix0, iy0) = (wrap(x0, g) as usize, wrap(y0, g) as usize);
        let (ix1, iy1) = (wrap(x0 + 1, g) as usize, wrap(y0 + 1, g) as usize);
        let at = |ix: usize, iy: usize| self.smooth[iy * SMOOTH_GRID + ix];
        let (a, b, c, d) = (at(ix0, iy0), at(ix1, iy0), at(ix0, iy1), at(ix1, iy1));
        std::array::from_fn(|k| lerp(lerp(a[k], b[k], fx), lerp(c[k], d[k], fx), fy))
    }

    /// Linear albedo at `(u, v)`.
    fn color(&self, u: f32, v: f32) -> Rgb {
        let (fine, seeds) = (self.fine, &self.seeds);
        match self.kind {
            TextureKind::Soil => soil(u, v, fine, seeds, self.soil_smooth(u, v)),
            TextureKind::Bark => bark(u, v, fine, seeds, &BARK_TRUNK),
            TextureKind::Cordon => bark(u, v, fine, seeds, &BARK_CORDON),
            TextureKind::Leaf => leaf(u, v, fine, seeds, &LEAF_UPPER),
            TextureKind::LeafUnderside => leaf(u, v, fine, seeds, &LEAF_LOWER),
            TextureKind::Post => post(u, v, fine, seeds),
            TextureKind::Grape => grape(u, v, fine, seeds, &GRAPE_DARK),
            TextureKind::GrapeWhite => grape(u, v, fine, seeds, &GRAPE_WHITE),
            TextureKind::Wire => wire(u, v, fine, seeds),
            TextureKind::Carton => CARTON_ALBEDO,
        }
    }
}

/// Linear albedo of [`TextureKind::Carton`].
pub const CARTON_ALBEDO: [f32; 3] = [0.30, 0.20, 0.11];

/// Leaf texture coordinates of the petiole junction, where the main veins start.
pub const LEAF_PETIOLE_UV: [f32; 2] = [0.5, 0.8];

/// Per-layer seeds of one bake.
struct Seeds {
    s: [u32; 12],
    /// Seed-dependent jitter in `[-1, 1]` for layout parameters.
    jit: [f32; 8],
    /// Leaf main veins: unit direction from the petiole junction and length (uv units).
    veins: [[f32; 3]; 5],
}

impl Seeds {
    fn new(kind: TextureKind, seed: u64) -> Seeds {
        let base = hash_u32(
            hash_u32(seed as u32 ^ kind.tag().wrapping_mul(0x2c1b_3c6d)) ^ (seed >> 32) as u32,
        );
        let s = std::array::from_fn(|k| {
            hash_u32(base.wrapping_add((k as u32 + 1).wrapping_mul(0x9e37_79b9)))
        });
        let jit = std::array::from_fn(|k| {
            2.0 * hash_unit(hash_u32(base ^ (0x5bd1_e995u32.wrapping_mul(k as u32 + 7)))) - 1.0
        });
        let angles = [0.0f32, 0.85, -0.85, 1.75, -1.75];
        let lengths = [0.76f32, 0.62, 0.62, 0.42, 0.42];
        let veins = std::array::from_fn(|k| {
            let a = angles[k] + 0.06 * jit[k];
            [a.sin(), -a.cos(), lengths[k] * (1.0 + 0.05 * jit[k + 1])]
        });
        Seeds { s, jit, veins }
    }
}

/// Number of smooth soil layers.
const SOIL_SMOOTH: usize = 5;

/// The smooth soil layers: base tone (fbm, 50 cm down to 6 cm), wetness, the domain warp
/// of the clods (x, y) and crustiness (where clods and cracks show).
fn soil_smooth(u: f32, v: f32, sd: &Seeds) -> [f32; SOIL_SMOOTH] {
    let s = &sd.s;
    [
        fbm(u * 4.0, v * 4.0, 4, 4, 4, s[0]),
        fbm(u * 3.0, v * 3.0, 3, 3, 2, s[1]),
        fbm(u * 8.0, v * 8.0, 8, 8, 2, s[6]),
        fbm(u * 8.0, v * 8.0, 8, 8, 2, s[7]),
        fbm(u * 5.0, v * 5.0, 5, 5, 2, s[8]),
    ]
}

fn soil(u: f32, v: f32, fine: i32, sd: &Seeds, smooth: [f32; SOIL_SMOOTH]) -> Rgb {
    let s = &sd.s;
    let [n, w, wx, wy, crust] = smooth;
    // Base: dry loam, light and dark tones.
    let mut c = mix([0.14, 0.105, 0.075], [0.27, 0.205, 0.14], 0.5 + 0.5 * n);
    // Darker, slightly redder wet patches.
    let wet = smoothstep(0.15, 0.45, w);
    c = mix(c, [c[0] * 0.55, c[1] * 0.5, c[2] * 0.5], wet);
    // Clods (≈ 5 cm, irregular by a domain warp): per-clod tone, relief lit from the top
    // left and dark cracks, strong where the soil is crusted, faint where it is loose.
    let crusted = smoothstep(-0.35, 0.25, crust);
    let cl = cellular(u * 40.0 + 0.7 * wx, v * 40.0 + 0.7 * wy, 40, 40, 0.9, s[2]);
    let tone = lerp(1.0, 0.75 + 0.5 * hash_unit(cl.id), 0.3 + 0.7 * crusted);
    let relief = (1.0 + (0.2 + 0.5 * crusted) * (cl.dx + cl.dy)).clamp(0.6, 1.5);
    let crack = smoothstep(0.0, 0.12, cl.f2 - cl.f1);
    c = scale(c, tone * relief * (1.0 - 0.7 * crusted * (1.0 - crack)));
    // Crumbs at two texels and at eight, coarser where the soil is loose.
    let g = value_noise(u * fine as f32, v * fine as f32, fine, fine, s[3]);
    let f4 = (fine / 4).max(1);
    let g4 = value_noise(u * f4 as f32, v * f4 as f32, f4, f4, s[9]);
    c = scale(
        c,
        (0.8 + 0.4 * g) * (1.0 + (0.6 - 0.35 * crusted) * (g4 - 0.5)),
    );
    // Stones (≈ 7 cm cells, one in ten holds one): elongated, randomly turned.
    let stone = sparse_feature(u * 30.0, v * 30.0, 30, 30, 0.8, 0.1, s[10]);
    if let Some(st) = stone.filter(|st| st.f1 < 0.45) {
        let hs = hash_u32(st.id);
        let a = std::f32::consts::PI * hash_unit(hs);
        let (sa, ca) = a.sin_cos();
        let (ex, ey) = (st.dx * ca + st.dy * sa, -st.dx * sa + st.dy * ca);
        let e = len2(ex, 1.6 * ey) / (0.15 + 0.15 * hash_unit(hash_u32(hs)));
        if e < 1.0 {
            let stone = mix(
                [0.33, 0.31, 0.28],
                [0.40, 0.33, 0.24],
                hash_unit(hs ^ 0x1234),
            );
            let shade = 1.0 + 0.5 * (st.dx + st.dy) / 0.3;
            c = scale(stone, (0.75 + 0.3 * g) * shade * (1.0 - 0.35 * e * e));
        } else if e < 1.3 {
            c = scale(c, 0.5 + 0.35 * smoothstep(-0.1, 0.2, st.dx + st.dy));
        }
    }
    // Pebbles (≈ 2.5 cm cells, a fifth of them hold one).
    if let Some(pb) = sparse_feature(u * 80.0, v * 80.0, 80, 80, 0.8, 0.22, s[4]) {
        let hp = hash_u32(pb.id);
        let r = 0.18 + 0.17 * hash_unit(hp);
        if pb.f1 < r {
            let stone = mix(
                [0.30, 0.29, 0.27],
                [0.38, 0.31, 0.22],
                hash_unit(hash_u32(hp)),
            );
            let shade = 1.0 + 1.2 * (pb.dx + pb.dy) / r * 0.3;
            c = scale(stone, (0.6 + 0.6 * hash_unit(hp ^ 0xabcd)) * shade);
        } else if pb.f1 < r + 0.12 {
            // Shadow ring, deeper on the bottom-right.
            let k = 0.45 + 0.35 * smoothstep(-0.1, 0.2, pb.dx + pb.dy);
            c = scale(c, k);
        }
    }
    // Dry-grass tufts (≈ 20 cm cells, 40 % hold one): radiating straw blades.
    if let Some(tf) = sparse_feature(u * 10.0, v * 10.0, 10, 10, 0.8, 0.4, s[5]) {
        let ht = hash_u32(tf.id);
        let radius = 0.2 + 0.25 * hash_unit(ht);
        if tf.f1 < radius {
            let a = (-tf.dy).atan2(-tf.dx) * (0.5 / std::f32::consts::PI) + 0.5;
            let blades = 36;
            let x = a * blades as f32;
            let stripe = value_noise(x * 2.0, 0.5, 2 * blades, 1, ht);
            let len = radius * (0.45 + 0.55 * value_noise(x, 3.5, blades, 1, ht ^ 0x55));
            let r = tf.f1 / len;
            if stripe > 0.55 && r < 1.0 {
                let straw = mix(
                    [0.42, 0.34, 0.16],
                    [0.30, 0.27, 0.20],
                    value_noise(x, 7.5, blades, 1, ht ^ 0x77),
                );
                c = scale(straw, 0.75 + 0.35 * stripe);
            } else if r < 1.0 {
                c = scale(c, 0.55 + 0.3 * r);
            }
        }
    }
    c
}

/// Parameters of the bark look.
struct BarkParams {
    /// Fissure lattice frequency around and along.
    fissure: (i32, i32),
    /// Fissure half-width in noise units and darkening.
    fissure_width: f32,
    fissure_depth: f32,
    dark: Rgb,
    light: Rgb,
    peel: Rgb,
}

const BARK_TRUNK: BarkParams = BarkParams {
    fissure: (14, 2),
    fissure_width: 0.2,
    fissure_depth: 0.85,
    dark: [0.09, 0.065, 0.05],
    light: [0.21, 0.17, 0.13],
    peel: [0.27, 0.23, 0.19],
};

const BARK_CORDON: BarkParams = BarkParams {
    fissure: (20, 3),
    fissure_width: 0.12,
    fissure_depth: 0.6,
    dark: [0.12, 0.08, 0.055],
    light: [0.25, 0.18, 0.13],
    peel: [0.30, 0.24, 0.19],
};

fn bark(u: f32, v: f32, fine: i32, sd: &Seeds, p: &BarkParams) -> Rgb {
    let s = &sd.s;
    let (fx, fy) = p.fissure;
    // Fissures: zero crossings of noise stretched along v.
    let n1 = gradient_noise(u * fx as f32, v * fy as f32, fx, fy, s[0])
        + 0.5
            * gradient_noise(
                u * (2 * fx) as f32,
                v * (2 * fy) as f32,
                2 * fx,
                2 * fy,
                s[1],
            );
    let fiss = 1.0 - smoothstep(0.0, p.fissure_width, n1.abs());
    let n2 = gradient_noise(
        u * (3 * fx) as f32,
        v * (3 * fy) as f32,
        3 * fx,
        3 * fy,
        s[2],
    );
    let fiss2 = 1.0 - smoothstep(0.0, 0.12, n2.abs());
    // Plates: tone varying slowly, peeling strips lighter.
    let plate = fbm(u * 6.0, v * 2.0, 6, 2, 3, s[3]);
    let mut c = mix(p.dark, p.light, (0.5 + 0.6 * plate).clamp(0.0, 1.0));
    let strips = value_noise(u * 48.0, v * 6.0, 48, 6, s[4]);
    c = mix(c, p.peel, smoothstep(0.6, 0.8, strips));
    // Fibres along v and small scaly flecks.
    let fib = value_noise(
        u * fine as f32,
        v * (fine / 8).max(1) as f32,
        fine,
        (fine / 8).max(1),
        s[5],
    );
    let fleck = value_noise(
        u * (fine / 2).max(1) as f32,
        v * (fine / 2).max(1) as f32,
        (fine / 2).max(1),
        (fine / 2).max(1),
        s[6],
    );
    c = scale(c, 0.75 + 0.35 * fib + 0.3 * (fleck - 0.5));
    // Fissure shading: one edge of a fissure catches light, the bottom is dark.
    let k = 1.0 - p.fissure_depth * fiss - 0.35 * p.fissure_depth * fiss2;
    scale(c, k.max(0.08))
}

/// Parameters of the leaf look.
struct LeafParams {
    lamina: Rgb,
    lamina_alt: Rgb,
    vein: Rgb,
    vein_contrast: f32,
    mottle: f32,
}

const LEAF_UPPER: LeafParams = LeafParams {
    lamina: [0.060, 0.120, 0.032],
    lamina_alt: [0.085, 0.140, 0.038],
    vein: [0.15, 0.21, 0.08],
    vein_contrast: 1.0,
    mottle: 0.35,
};

const LEAF_LOWER: LeafParams = LeafParams {
    lamina: [0.105, 0.160, 0.075],
    lamina_alt: [0.120, 0.170, 0.085],
    vein: [0.20, 0.25, 0.13],
    vein_contrast: 1.2,
    mottle: 0.2,
};

fn leaf(u: f32, v: f32, fine: i32, sd: &Seeds, p: &LeafParams) -> Rgb {
    let s = &sd.s;
    let j = &sd.jit;
    // Lamina: mottled, slightly varying hue.
    let m = fbm(u * 6.0, v * 6.0, 6, 6, 4, s[0]);
    let hue = fbm(u * 3.0, v * 3.0, 3, 3, 2, s[1]);
    let mut c = mix(p.lamina, p.lamina_alt, (0.5 + 0.8 * hue).clamp(0.0, 1.0));
    c = scale(c, 1.0 + p.mottle * m);
    let g = value_noise(u * fine as f32, v * fine as f32, fine, fine, s[2]);
    c = scale(c, 0.88 + 0.24 * g);
    // Reticulate venation: faint lighter network (areoles ≈ 1/30 of the leaf).
    let ar = cellular(u * 30.0, v * 30.0, 30, 30, 0.85, s[3]);
    let net = 1.0 - smoothstep(0.0, 0.07, ar.f2 - ar.f1);
    // Each areole slightly different.
    c = scale(c, 0.9 + 0.2 * hash_unit(ar.id));
    let mut vein = 0.35 * net;
    // Five palmate main veins from the petiole junction, secondary veins off them.
    let (qx, qy) = (u - LEAF_PETIOLE_UV[0], v - LEAF_PETIOLE_UV[1]);
    let mut best = (f32::MAX, 0.0f32, 0.0f32, 1.0f32);
    for &[dx, dy, l] in &sd.veins {
        let t = qx * dx + qy * dy;
        let sgn = qx * dy - qy * dx;
        let tc = t.clamp(0.0, l);
        let d = len2(qx - tc * dx, qy - tc * dy);
        if d < best.0 {
            best = (d, t, sgn, l);
        }
    }
    let (d, t, sgn, l) = best;
    let tn = (t / l).clamp(0.0, 1.0);
    let w_main = 0.011 * (1.0 - 0.75 * tn) + 0.002;
    vein = vein.max(1.0 - smoothstep(0.5 * w_main, w_main, d));
    if t > 0.0 && t < l {
        // Secondary veins leave the main vein at ~50° towards the margin, alternating.
        let theta: f32 = 0.9;
        let spacing = 0.09;
        let side_off = if sgn > 0.0 { 0.5 * spacing } else { 0.0 };
        let off = 0.03 + 0.02 * j[6] + side_off;
        let along_s = sgn.abs();
        let t0 = t - along_s / theta.tan();
        let k = ((t0 - off) / spacing).round();
        let tk = off + k * spacing;
        if tk > 0.04 && tk < 0.9 * l {
            let len = 0.22 * (1.0 - tk / l) + 0.05;
            let along = along_s / theta.sin();
            if along < len {
                let d2 = (t0 - tk).abs() * theta.sin();
                let w2 = 0.0045 * (1.0 - along / len) + 0.0015;
                vein = vein.max(0.8 * (1.0 - smoothstep(0.5 * w2, w2, d2)));
            }
        }
    }
    c = mix(c, p.vein, (vein * p.vein_contrast).clamp(0.0, 1.0));
    // A few small necrotic spots with dark rims.
    if let Some(sp) = sparse_feature(u * 22.0, v * 22.0, 22, 22, 0.8, 0.12, s[4]) {
        let r = 0.08 + 0.1 * hash_unit(hash_u32(sp.id));
        if sp.f1 < r {
            c = mix([0.11, 0.08, 0.035], [0.16, 0.13, 0.05], sp.f1 / r);
        } else if sp.f1 < 1.6 * r {
            c = scale(c, 0.6);
        }
    }
    c
}

fn post(u: f32, v: f32, fine: i32, sd: &Seeds) -> Rgb {
    let s = &sd.s;
    // Weathered grey-brown wood.
    let base = fbm(u * 4.0, v * 2.0, 4, 2, 3, s[0]);
    let mut c = mix(
        [0.24, 0.21, 0.17],
        [0.40, 0.35, 0.28],
        (0.5 + 0.6 * base).clamp(0.0, 1.0),
    );
    // Grain streaks along v.
    let grain = gradient_noise(u * 48.0, v * 2.0, 48, 2, s[1]) * 0.6
        + gradient_noise(u * 96.0, v * 4.0, 96, 4, s[2]) * 0.4;
    let ring = 1.0 - smoothstep(0.0, 0.15, grain.abs());
    c = scale(c, 0.9 + 0.15 * grain - 0.3 * ring);
    let fib = value_noise(
        u * fine as f32,
        v * (fine / 8).max(1) as f32,
        fine,
        (fine / 8).max(1),
        s[3],
    );
    c = scale(c, 0.85 + 0.3 * fib);
    // Weathering: small dark pits and lighter flakes (≈ 9 mm cells, a third hold one).
    if let Some(pit) = sparse_feature(u * 40.0, v * 40.0, 40, 40, 0.8, 0.35, s[8]) {
        let hp = hash_u32(pit.id);
        let r = 0.12 + 0.18 * hash_unit(hp);
        let e = len2(pit.dx * 1.6, pit.dy * 0.6);
        if e < r {
            let k = if hash_unit(hash_u32(hp)) < 0.7 {
                0.45
            } else {
                1.35
            };
            c = scale(c, k);
        }
    }
    // Checks (long drying cracks) along v: the post's circumference is cut into 10
    // wobbling columns, 60 % of them carry a crack that opens and closes along v.
    const COLUMNS: i32 = 10;
    let wobble = 0.012 * gradient_noise(u * 4.0, v * 6.0, 4, 6, s[4]);
    let xk = (u + wobble) * COLUMNS as f32;
    let col = ifloor(xk);
    let hc = hash2(wrap(col, COLUMNS), 0, s[5]);
    if hash_unit(hc) < 0.6 {
        let at = 0.2 + 0.6 * hash_unit(hash_u32(hc));
        let d = (xk - col as f32 - at).abs() / COLUMNS as f32;
        let open = value_noise(v * 3.0, wrap(col, COLUMNS) as f32 + 0.5, 3, COLUMNS, s[7]);
        let width = 0.007 * smoothstep(0.35, 0.65, open);
        if d < width {
            c = scale(c, 0.2 + 0.8 * smoothstep(0.3 * width, width, d));
        }
    }
    // Knots: dark elliptical cores with a ring, half of the cells hold one.
    if let Some(kn) = sparse_feature(u * 4.0, v * 3.0, 4, 3, 0.7, 0.5, s[6]) {
        let e = len2(kn.dx * 3.0, kn.dy * 1.5);
        if e < 0.12 {
            c = mix([0.10, 0.075, 0.055], [0.18, 0.14, 0.10], e / 0.12);
        } else if e < 0.3 {
            let band = (e * 60.0).sin();
            c = scale(c, 0.85 + 0.12 * band);
        }
    }
    c
}

/// Parameters of the grape look.
struct GrapeParams {
    berry: Rgb,
    berry_alt: Rgb,
    bloom: Rgb,
    bloom_amount: f32,
}

const GRAPE_DARK: GrapeParams = GrapeParams {
    berry: [0.035, 0.020, 0.050],
    berry_alt: [0.080, 0.030, 0.060],
    bloom: [0.15, 0.15, 0.21],
    bloom_amount: 0.45,
};

const GRAPE_WHITE: GrapeParams = GrapeParams {
    berry: [0.27, 0.33, 0.10],
    berry_alt: [0.36, 0.37, 0.12],
    bloom: [0.40, 0.42, 0.34],
    bloom_amount: 0.3,
};

fn grape(u: f32, v: f32, fine: i32, sd: &Seeds, p: &GrapeParams) -> Rgb {
    let s = &sd.s;
    // Round, tightly packed berries on a jittered 16 × 16 lattice, dark gaps where three
    // meet.
    let b = cellular(u * 16.0, v * 16.0, 16, 16, 0.45, s[0]);
    let hb = hash_u32(b.id);
    let radius = 0.5 + 0.08 * hash_unit(hb);
    let r = b.f1 / radius;
    let base = mix(p.berry, p.berry_alt, hash_unit(b.id));
    if r >= 1.0 {
        return scale(base, 0.12);
    }
    // Bloom: fine waxy speckle, rubbed off on some berries.
    let sp = value_noise(u * fine as f32, v * fine as f32, fine, fine, s[1]);
    let rubbed = hash_unit(hash_u32(hb));
    let mut c = mix(
        base,
        p.bloom,
        (p.bloom_amount * (0.3 + rubbed) * sp).clamp(0.0, 1.0),
    );
    // Dome shading (darker limb) and a light fleck where the berry faces the top left.
    let dome = (1.0 - r * r).max(0.0).sqrt();
    c = scale(c, 0.3 + 0.8 * dome);
    let (hx, hy) = (b.dx - 0.3 * radius, b.dy - 0.3 * radius);
    let fleck = (1.0 - len2(hx, hy) / (0.25 * radius)).max(0.0);
    c = mix(c, p.bloom, 0.7 * fleck);
    // Where two berries touch.
    let touch = smoothstep(0.0, 0.08, b.f2 - b.f1);
    scale(c, 0.2 + 0.8 * touch)
}

fn wire(u: f32, v: f32, fine: i32, sd: &Seeds) -> Rgb {
    let s = &sd.s;
    let streak = gradient_noise(u * 16.0, v * 2.0, 16, 2, s[0]);
    let sp = cellular(u * 24.0, v * 24.0, 24, 24, 0.9, s[1]);
    let mut c = scale(
        [0.42, 0.42, 0.43],
        (1.0 + 0.12 * streak) * (0.92 + 0.16 * hash_unit(sp.id)),
    );
    let g = value_noise(u * fine as f32, v * fine as f32, fine, fine, s[2]);
    c = scale(c, 0.93 + 0.14 * g);
    let rust = smoothstep(0.45, 0.75, fbm(u * 3.0, v * 8.0, 3, 8, 3, s[3]));
    mix(c, [0.24, 0.11, 0.05], 0.8 * rust)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Display grey of a texture: sRGB-encoded luminance of the linear albedo (a fixed
    /// exposure at which white paper reads ≈ 240), as bytes.
    fn grey(t: &Texture) -> Vec<u8> {
        (0..t.height)
            .flat_map(|y| (0..t.width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let c = t.texel(x, y);
                encode_srgb(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
            })
            .collect()
    }

    /// FAST-9 corners (Rosten & Drummond): a pixel is a corner when 9 contiguous pixels of
    /// its radius-3 Bresenham circle are all brighter than it by more than `t` or all
    /// darker by more than `t`; then 3×3 non-maximum suppression on the score (sum of the
    /// excess over `t` on the circle).
    fn fast9(img: &[u8], w: usize, h: usize, t: i32) -> usize {
        const CIRCLE: [(i32, i32); 16] = [
            (0, -3),
            (1, -3),
            (2, -2),
            (3, -1),
            (3, 0),
            (3, 1),
            (2, 2),
            (1, 3),
            (0, 3),
            (-1, 3),
            (-2, 2),
            (-3, 1),
            (-3, 0),
            (-3, -1),
            (-2, -2),
            (-1, -3),
        ];
        let at = |x: usize, y: usize, d: (i32, i32)| {
            i32::from(img[(y as i32 + d.1) as usize * w + (x as i32 + d.0) as usize])
        };
        let mut score = vec![0i32; w * h];
        for y in 3..h - 3 {
            for x in 3..w - 3 {
                let p = i32::from(img[y * w + x]);
                let diffs: [i32; 16] = CIRCLE.map(|d| at(x, y, d) - p);
                let mut best = 0;
                for sign in [1, -1] {
                    let mut run = 0;
                    let mut found = false;
                    for k in 0..32 {
                        if sign * diffs[k % 16] > t {
                            run += 1;
                            if run >= 9 {
                                found = true;
                                break;
                            }
                        } else {
                            run = 0;
                        }
                    }
                    if found {
                        let s: i32 = diffs.iter().map(|&d| (sign * d - t).max(0)).sum();
                        best = best.max(s);
                    }
                }
                score[y * w + x] = best;
            }
        }
        let mut n = 0;
        for y in 3..h - 3 {
            for x in 3..w - 3 {
                let s = score[y * w + x];
                if s == 0 {
                    continue;
                }
                let mut is_max = true;
                for dy in -1i32..=1 {
                    for dx in -1i32..=1 {
                        let q = score[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize];
                        let earlier = dy < 0 || (dy == 0 && dx < 0);
                        if (dx, dy) != (0, 0) && (q > s || (q == s && earlier)) {
                            is_max = false;
                        }
                    }
                }
                n += usize::from(is_max);
            }
        }
        n
    }

    /// Standard deviation of the grey image minus its 16×16 box mean (wrapping), in
    /// units of full scale.
    fn highpass_std(t: &Texture) -> f64 {
        let g = grey(t);
        let (w, h) = (t.width, t.height);
        let mut sum = 0.0f64;
        let mut sum2 = 0.0f64;
        for y in 0..h {
            for x in 0..w {
                let mut m = 0.0f64;
                for dy in 0..16 {
                    for dx in 0..16 {
                        m += f64::from(g[((y + h + dy - 8) % h) * w + (x + w + dx - 8) % w]);
                    }
                }
                let d = (f64::from(g[y * w + x]) - m / 256.0) / 255.0;
                sum += d;
                sum2 += d * d;
            }
        }
        let n = (w * h) as f64;
        (sum2 / n - (sum / n).powi(2)).max(0.0).sqrt()
    }

    #[test]
    fn srgb_round_trips() {
        for b in 0..=255u8 {
            assert_eq!(encode_srgb(decode_srgb(b)), b);
            assert_eq!(encode_with(&LINEAR_TO_SRGB, decode_srgb(b)), b);
            assert_eq!(encode_with(&LINEAR_TO_SRGB, f32::NAN), 0);
        }
        assert_eq!(encode_srgb(f32::NAN), 0);
        assert_eq!(encode_srgb(2.0), 255);
    }

    #[test]
    fn noise_is_bounded_and_periodic() {
        for k in 0..2000 {
            let x = (k as f32) * 0.173 - 40.0;
            let y = (k as f32) * 0.311 - 90.0;
            let vn = value_noise(x, y, 7, 5, 3);
            assert!((0.0..=1.0).contains(&vn));
            let gn = gradient_noise(x, y, 7, 5, 3);
            assert!((-1.0..=1.0).contains(&gn));
            assert!((gradient_noise(x + 7.0, y - 10.0, 7, 5, 3) - gn).abs() < 1e-3);
            assert!((value_noise(x - 14.0, y + 5.0, 7, 5, 3) - vn).abs() < 1e-3);
            let f = fbm(x, y, 3, 4, 4, 9);
            assert!((fbm(x + 3.0, y + 4.0, 3, 4, 4, 9) - f).abs() < 1e-3);
            let c = cellular(x, y, 6, 6, 0.9, 1);
            let c2 = cellular(x + 6.0, y - 12.0, 6, 6, 0.9, 1);
            assert!((c.f1 - c2.f1).abs() < 1e-3 && c.id == c2.id);
            assert!(c.f1 <= c.f2);
        }
        // The 2×2 sparse search finds the same nearest present point as a 5×5 brute
        // force whenever it is closer than 1 − jitter / 2.
        let (jitter, density, seed) = (0.8, 0.3, 17);
        let mut found = 0;
        let (sx, sy) = lattice_shift(seed);
        for k in 0..5000u32 {
            let x = 20.0 * hash_unit(hash_u32(k)) - 3.0 + sx;
            let y = 20.0 * hash_unit(hash_u32(k ^ 0xdead_beef)) - 3.0 + sy;
            let mut brute: Option<(f32, u32)> = None;
            for j in -2..=2 {
                for i in -2..=2 {
                    let (cx, cy) = (ifloor(x) + i, ifloor(y) + j);
                    let h = hash2(wrap(cx, 9), wrap(cy, 7), seed);
                    if !holds_feature(h, density) {
                        continue;
                    }
                    let (ox, oy) = feature_offset(h, jitter);
                    let d = (cx as f32 + ox - x).hypot(cy as f32 + oy - y);
                    if brute.is_none_or(|b| d < b.0) {
                        brute = Some((d, hash_u32(h)));
                    }
                }
            }
            let sparse = sparse_feature(x - sx, y - sy, 9, 7, jitter, density, seed);
            if let Some((d, id)) = brute.filter(|b| b.0 < 1.0 - 0.5 * jitter) {
                let s = sparse.expect("found");
                assert!((s.f1 - d).abs() < 1e-4 && s.id == id);
                found += 1;
            }
        }
        assert!(found > 500);
        assert_ne!(hash2(1, 2, 3), hash2(2, 1, 3));
        assert_ne!(hash2(1, 2, 3), hash2(1, 2, 4));
    }

    #[test]
    fn grvi_of_mean_albedo() {
        for kind in TextureKind::ALL {
            let t = bake(kind, 256, 7);
            let m = t.mean_linear();
            println!("{kind:?}: mean linear albedo {m:.3?}, GRVI {:.3}", grvi(m));
        }
        let g = |kind| grvi(bake(kind, 256, 7).mean_linear());
        for kind in [TextureKind::Leaf, TextureKind::LeafUnderside] {
            assert!((0.15..=0.35).contains(&g(kind)), "{kind:?}");
        }
        for kind in [
            TextureKind::Soil,
            TextureKind::Bark,
            TextureKind::Cordon,
            TextureKind::Post,
        ] {
            assert!((-0.25..=-0.05).contains(&g(kind)), "{kind:?}: {}", g(kind));
        }
        assert!(g(TextureKind::Carton) < 0.0);
        assert!(g(TextureKind::Grape) < 0.0);
        assert!(g(TextureKind::GrapeWhite) > 0.0);
    }

    #[test]
    fn same_seed_same_texture_other_seed_differs() {
        for kind in TextureKind::ALL {
            let a = bake(kind, 128, 11);
            let b = bake(kind, 128, 11);
            assert_eq!(a, b, "{kind:?}");
            let c = bake(kind, 128, 12);
            let c2 = bake(kind, 128, 11 + (1 << 40));
            if kind == TextureKind::Carton {
                assert_eq!(a.texels(), c.texels());
                continue;
            }
            for other in [&c, &c2] {
                let differ = a
                    .texels()
                    .iter()
                    .zip(other.texels())
                    .filter(|(x, y)| x != y)
                    .count();
                assert!(
                    differ > a.texels().len() / 2,
                    "{kind:?}: only {differ} texels differ"
                );
            }
        }
    }

    #[test]
    fn tileable_textures_wrap_seamlessly() {
        for kind in TextureKind::ALL.into_iter().filter(|k| k.tileable()) {
            // Mean absolute grey difference between columns (rows) `a` and `b`, averaged
            // over 8 seeds so that one feature lying on the seam by chance does not decide.
            let n = 128;
            let greys: Vec<Vec<u8>> = (0..8).map(|seed| grey(&bake(kind, n, seed))).collect();
            let col_mad = |a: usize, b: usize| {
                let sum: f64 = greys
                    .iter()
                    .flat_map(|g| {
                        (0..n).map(move |y| f64::from(g[y * n + a].abs_diff(g[y * n + b])))
                    })
                    .sum();
                sum / (8 * n) as f64
            };
            let row_mad = |a: usize, b: usize| {
                let sum: f64 = greys
                    .iter()
                    .flat_map(|g| {
                        (0..n).map(move |x| f64::from(g[a * n + x].abs_diff(g[b * n + x])))
                    })
                    .sum();
                sum / (8 * n) as f64
            };
            let inner_c = (0..n - 1).map(|x| col_mad(x, x + 1)).sum::<f64>() / (n - 1) as f64;
            let inner_r = (0..n - 1).map(|y| row_mad(y, y + 1)).sum::<f64>() / (n - 1) as f64;
            let far_c = (0..n).map(|x| col_mad(x, (x + n / 2) % n)).sum::<f64>() / n as f64;
            let far_r = (0..n).map(|y| row_mad(y, (y + n / 2) % n)).sum::<f64>() / n as f64;
            let (seam_c, seam_r) = (col_mad(n - 1, 0), row_mad(n - 1, 0));
            println!(
                "{kind:?}: u seam {seam_c:.2}, adjacent columns {inner_c:.2}, columns n/2 apart \
                 {far_c:.2}; v seam {seam_r:.2}, adjacent rows {inner_r:.2}, rows n/2 apart \
                 {far_r:.2}"
            );
            // The seam looks like any pair of adjacent columns (rows), not like two
            // unrelated ones.
            assert!(seam_c <= 1.3 * inner_c + 0.5, "{kind:?} u seam");
            assert!(seam_r <= 1.3 * inner_r + 0.5, "{kind:?} v seam");
            // And the texel function itself is periodic.
            let prep = Prepared::new(kind, 1024, 3);
            for k in 0..500 {
                let (u, v) = (hash_unit(hash_u32(k)), hash_unit(hash_u32(k + 1000)));
                let a = prep.color(u, v);
                let b = prep.color(u + 1.0, v - 1.0);
                for c in 0..3 {
                    assert!(
                        (a[c] - b[c]).abs() < 2e-3,
                        "{kind:?} at ({u}, {v}): {a:?} vs {b:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn textures_have_detail_and_carton_has_none() {
        for kind in TextureKind::ALL {
            let t = bake(kind, 256, 5);
            let hp = highpass_std(&t);
            let corners = fast9(&grey(&t), t.width, t.height, 20);
            println!("{kind:?}: high-pass std {hp:.4}, FAST-9 (t = 20) corners {corners}");
            if kind == TextureKind::Carton {
                assert!(hp < 1e-9);
                assert_eq!(corners, 0);
            } else if kind != TextureKind::Wire {
                assert!(hp > 0.02, "{kind:?}: high-pass std {hp}");
            }
            if matches!(
                kind,
                TextureKind::Soil | TextureKind::Bark | TextureKind::Leaf | TextureKind::Post
            ) {
                assert!(corners >= 50, "{kind:?}: {corners} corners");
            }
        }
    }

    #[test]
    fn sampling_wraps_and_interpolates() {
        let t = bake(TextureKind::Soil, 64, 1);
        let n = 64.0;
        for (x, y) in [(0usize, 0usize), (5, 9), (63, 63), (31, 0)] {
            let (u, v) = ((x as f32 + 0.5) / n, (y as f32 + 0.5) / n);
            let c = t.texel(x, y);
            for s in [
                t.sample(u, v),
                t.sample(u + 1.0, v - 3.0),
                t.sample_nearest(u, v),
                t.sample_nearest(u - 2.0, v + 1.0),
            ] {
                for k in 0..3 {
                    assert!((s[k] - c[k]).abs() < 1e-5);
                }
            }
        }
        // Halfway between the last and the first texel of a row, across the seam.
        let (a, b) = (t.texel(63, 10), t.texel(0, 10));
        let s = t.sample(0.0, 10.5 / n);
        for k in 0..3 {
            assert!((s[k] - 0.5 * (a[k] + b[k])).abs() < 1e-5);
        }
        let s = t.sample(f32::NAN, f32::INFINITY);
        assert!(s.iter().all(|c| c.is_finite()));
        // Mips: level 0 is the texture, the coarsest level is its mean.
        assert_eq!(t.mip_levels(), 7);
        assert_eq!(t.sample_lod(0.3, 0.6, 0.0), t.sample(0.3, 0.6));
        let mean = t.mean_linear();
        let top = t.sample_lod(0.3, 0.6, 10.0);
        for k in 0..3 {
            assert!((top[k] - mean[k]).abs() < 0.01, "{top:?} vs {mean:?}");
        }
        let carton = bake(TextureKind::Carton, 4, 0);
        let c = carton.sample(0.123, 0.456);
        for k in 0..3 {
            assert!((c[k] - CARTON_ALBEDO[k]).abs() < 0.005);
        }
    }

    /// The trilinear lookup on the decoded linear pyramid gives the same bits as the
    /// scalar one it replaced: bilinear on each level's sRGB texels through the decoding
    /// table, then a lerp between levels.
    #[test]
    fn trilinear_on_the_linear_pyramid_equals_the_srgb_reference() {
        let reference = |t: &Texture, u: f32, v: f32, lod: f32| -> [f32; 3] {
            let lod = if lod.is_nan() {
                0.0
            } else {
                lod.clamp(0.0, t.mips.len() as f32)
            };
            let l0 = lod as usize;
            let f = lod - l0 as f32;
            let at = |l: usize| match l {
                0 => bilinear(t.width, t.height, &t.texels, u, v),
                _ => {
                    let m = &t.mips[(l - 1).min(t.mips.len() - 1)];
                    bilinear(m.width, m.height, &m.texels, u, v)
                }
            };
            let a = at(l0);
            if f > 0.0 && l0 < t.mips.len() {
                mix(a, at(l0 + 1), f)
            } else {
                a
            }
        };
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        for (kind, size) in [(TextureKind::Leaf, 64), (TextureKind::Soil, 96)] {
            let t = bake(kind, size, 5);
            assert_eq!(t.linear.len(), t.mip_levels());
            for _ in 0..4000 {
                let (u, v) = (8.0 * next() - 4.0, 8.0 * next() - 4.0);
                let lod = 12.0 * next() - 2.0;
                assert_eq!(t.sample_lod(u, v, lod), reference(&t, u, v, lod));
            }
            for lod in [f32::NAN, f32::INFINITY, -1.0, 0.0, 1.0, 100.0] {
                assert_eq!(t.sample_lod(0.3, 0.7, lod), reference(&t, 0.3, 0.7, lod));
            }
        }
    }

    /// Writes every kind as a binary PPM (sRGB) into `$VINEBENCH_TEXTURE_DUMP` for a
    /// visual check: `VINEBENCH_TEXTURE_DUMP=/tmp/tex cargo test ... dump -- --ignored`.
    #[test]
    #[ignore = "writes images for inspection"]
    fn dump_textures() {
        let Some(dir) = std::env::var_os("VINEBENCH_TEXTURE_DUMP") else {
            return;
        };
        let dir = std::path::PathBuf::from(dir);
        std::fs::create_dir_all(&dir).expect("dump dir");
        for kind in TextureKind::ALL {
            let t = bake(kind, kind.recommended_size().max(256), 1);
            let mut ppm = format!("P6\n{} {}\n255\n", t.width, t.height).into_bytes();
            ppm.extend(t.texels().iter().flatten());
            std::fs::write(dir.join(format!("{kind:?}.ppm")), ppm).expect("write");
        }
    }

    #[test]
    fn the_scene_textures_stay_small() {
        let (mut total, mut bytes) = (0.0, 0);
        for kind in TextureKind::ALL {
            let start = std::time::Instant::now();
            let t = bake(kind, kind.recommended_size(), 42);
            let dt = start.elapsed().as_secs_f64();
            println!("{kind:?} {}²: {:.1} ms", t.width, dt * 1e3);
            total += dt;
            bytes += t.memory_bytes();
        }
        // The time is printed, not asserted (benchmarks measure speed).
        println!(
            "baked every kind in {total:.3} s, {:.2} MB",
            bytes as f64 / 1e6
        );
        // 2.0 M texels with the mips: 6.0 MB as sRGB bytes, 32.2 MB as the decoded
        // linear pyramid (16 bytes a texel), 38.3 MB together.
        assert!(bytes <= 40_000_000, "{bytes} bytes");
    }
}
