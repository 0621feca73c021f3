//! The terrain: a regular grid of heights over the field and its margin, evaluated as a
//! C²-smooth uniform bicubic B-spline.
//!
//! The height field is the sum of three parts, all sampled at the grid nodes:
//! - a uniform slope expressed in row coordinates ([`RowLayout::row_coords`]): uphill
//!   along the rows (increasing `s`) and across them (increasing offset, towards the last
//!   row);
//! - a large, gentle undulation: a few plane waves of one wavelength with random
//!   directions and phases, scaled so that its largest |height| over the grid nodes is
//!   exactly the requested amplitude;
//! - small-scale roughness: Gaussian noise with the requested standard deviation and a
//!   Gaussian autocorrelation `ρ(r) = exp(-r²/L²)` of correlation length `L`, made by
//!   smoothing white noise with a Gaussian kernel of standard deviation `L/2`.
//!
//! The grid values are the *control points* of the spline, so the surface slightly
//! smooths them: at a node it equals `(1/36)·[1 4 1] ⊗ [1 4 1]` applied to the
//! neighbouring values. Linear functions (slopes) are reproduced exactly; the default
//! undulation (60 m on 0.5 m cells) is attenuated by less than 0.1 %, and the default
//! roughness (1.5 m correlation length) loses about 3.5 % of its standard deviation.

use super::layout::RowLayout;
use super::surface::{Surface, SurfacePoint};
use crate::params::{ParamError, TerrainParams, require_non_negative, require_positive};
use nalgebra::{Matrix2, Vector2};
use rand::Rng;
use rand_distr::StandardNormal;
use std::f64::consts::{PI, TAU};

/// Largest accepted terrain grid (points); 20 M heights are 160 MB.
pub const MAX_GRID_POINTS: usize = 20_000_000;
/// Widest terrain margin beyond the rows' footprint, m (`world.terrain.margin_m`).
pub const MAX_MARGIN_M: f64 = 1_000.0;
/// Largest accepted |slope| along or across the rows, degrees (exclusive).
pub const MAX_SLOPE_DEG: f64 = 45.0;
/// The undulation wavelength must span at least this many grid cells (the spline
/// attenuates a wave of 4 cells to 2/3 of its amplitude; of 20 cells by 1.6 %).
pub const MIN_UNDULATION_WAVELENGTH_CELLS: f64 = 4.0;
/// The roughness correlation length must span at least this many grid cells: the grid
/// cannot represent finer roughness.
pub const MIN_ROUGHNESS_WAVELENGTH_CELLS: f64 = 1.0;
/// The roughness correlation length may span at most this many grid cells (the
/// smoothing kernel grows with it; larger features are the undulation's job).
pub const MAX_ROUGHNESS_WAVELENGTH_CELLS: f64 = 64.0;
/// Number of plane waves summed for the undulation.
const UNDULATION_WAVES: usize = 3;
/// Random deviation of each wave's direction from an even spread over 180°, rad (±).
const UNDULATION_DIRECTION_JITTER_RAD: f64 = PI / 12.0;
/// The roughness kernel is truncated at this many standard deviations.
const ROUGHNESS_KERNEL_RADIUS_SIGMAS: f64 = 4.0;

/// The ground of the vineyard: a regular grid of heights over the field and its margin,
/// evaluated as a uniform bicubic B-spline surface (C², see the module docs).
///
/// Grid node `(ix, iy)` lies at world `(origin_x_m + ix·cell_m, origin_y_m + iy·cell_m)`.
/// The spline is defined on the *interior domain* [`Terrain::domain`], one cell inside
/// the grid on every side; [`Terrain::generate`] sizes the grid so that this domain
/// covers the rows, their headlands and the margin. Outside it the coordinates are
/// clamped to the domain (the height continues constant outwards and the derivatives
/// across the edge are zero there), so [`Surface::sample`] never panics; the surface is
/// C² only inside the domain.
///
/// Invariants (kept by the constructors; required if the fields are set directly):
/// `nx ≥ 4`, `ny ≥ 4`, `heights.len() == nx · ny`, `cell_m > 0`.
#[derive(Clone, Debug, PartialEq)]
pub struct Terrain {
    /// World x of grid column 0, m.
    pub origin_x_m: f64,
    /// World y of grid row 0, m.
    pub origin_y_m: f64,
    /// Grid spacing, m.
    pub cell_m: f64,
    /// Number of grid columns (x).
    pub nx: usize,
    /// Number of grid rows (y).
    pub ny: usize,
    /// Heights (spline control points), row-major: `heights[iy * nx + ix]`, m.
    pub heights: Vec<f64>,
}

/// One axis of a spline evaluation: the first control index, the basis values and
/// whether the coordinate was clamped to the domain.
struct AxisSpan {
    /// Index of the first of the four control points.
    first: usize,
    /// Local coordinate in the cell, in [0, 1].
    t: f64,
    /// The coordinate lay outside the interior domain.
    clamped: bool,
}

/// Uniform cubic B-spline basis functions at local coordinate `t ∈ [0, 1]`.
#[inline]
fn basis(t: f64) -> [f64; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    let u = 1.0 - t;
    [
        u * u * u / 6.0,
        (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
        (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
        t3 / 6.0,
    ]
}

/// First derivatives of [`basis`] with respect to `t`.
#[inline]
fn basis_d1(t: f64) -> [f64; 4] {
    let u = 1.0 - t;
    [
        -0.5 * u * u,
        (3.0 * t * t - 4.0 * t) / 2.0,
        (-3.0 * t * t + 2.0 * t + 1.0) / 2.0,
        0.5 * t * t,
    ]
}

/// Second derivatives of [`basis`] with respect to `t`.
#[inline]
fn basis_d2(t: f64) -> [f64; 4] {
    [1.0 - t, 3.0 * t - 2.0, 1.0 - 3.0 * t, t]
}

#[inline]
fn dot4(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
}

impl Terrain {
    /// A terrain from an explicit grid (spline control points, row-major
    /// `heights[iy * nx + ix]`, m). Fails unless `cell_m > 0`, the origin is finite,
    /// `nx, ny ≥ 4` and `heights.len() == nx · ny`.
    pub fn from_grid(
        origin_x_m: f64,
        origin_y_m: f64,
        cell_m: f64,
        nx: usize,
        ny: usize,
        heights: Vec<f64>,
    ) -> Result<Terrain, ParamError> {
        require_positive("world.terrain.cell_m", cell_m)?;
        if !(origin_x_m.is_finite() && origin_y_m.is_finite()) {
            return Err(ParamError::new(
                "world.terrain",
                "a finite grid origin",
                format!("({origin_x_m}, {origin_y_m})"),
            ));
        }
        if nx < 4 || ny < 4 || nx.checked_mul(ny) != Some(heights.len()) {
            return Err(ParamError::new(
                "world.terrain",
                "a grid of at least 4 × 4 points with nx · ny heights",
                format!("{nx} × {ny} with {} heights", heights.len()),
            ));
        }
        Ok(Terrain {
            origin_x_m,
            origin_y_m,
            cell_m,
            nx,
            ny,
            heights,
        })
    }

    /// Generates the terrain of a vineyard with row geometry `layout` and headlands of
    /// `headland_width_m` beyond both row ends, drawing all randomness from `rng` (the
    /// world passes its `"world.terrain"` stream). The grid's interior domain covers
    /// `layout.bounds(margin_m + headland_width_m)`.
    ///
    /// Fails with the dotted path of a parameter that cannot be used: see
    /// [`validate_params`]; also when the grid would exceed [`MAX_GRID_POINTS`]
    /// (`world.terrain.cell_m`), and when the rows are curved, `slope_along_deg ≠ 0` and
    /// the grid reaches the far side of the rows' circle centre, where a constant slope
    /// along concentric arcs cannot be continuous (`world.terrain.slope_along_deg`).
    pub fn generate<R: Rng + ?Sized>(
        params: &TerrainParams,
        layout: &RowLayout,
        headland_width_m: f64,
        rng: &mut R,
    ) -> Result<Terrain, ParamError> {
        validate_params(params)?;
        require_non_negative("world.headlands.width_m", headland_width_m)?;
        let cell = params.cell_m;
        let (lo, hi) = layout.bounds(params.margin_m + headland_width_m);
        let span = hi - lo;
        if !(span.x.is_finite() && span.y.is_finite()) {
            return Err(ParamError::new(
                "world.rows",
                "a row layout with a finite footprint",
                format!("bounds {lo:?} to {hi:?}"),
            ));
        }
        // The interior domain [origin + cell, origin + (n - 2)·cell] must cover [lo, hi].
        let cells = |extent: f64| (extent / cell).ceil() + 3.0;
        let (nxf, nyf) = (cells(span.x), cells(span.y));
        if nxf * nyf > MAX_GRID_POINTS as f64 {
            return Err(ParamError::new(
                "world.terrain.cell_m",
                format!(
                    "a cell size giving at most {MAX_GRID_POINTS} grid points (MAX_GRID_POINTS) \
                     over the terrain's {:.0} m × {:.0} m (the rows' footprint: \
                     world.rows.length_m, count × spacing_m, plus world.headlands.width_m \
                     and world.terrain.margin_m on every side), i.e. at least {:.3} m",
                    span.x,
                    span.y,
                    ((span.x * span.y) / MAX_GRID_POINTS as f64).sqrt()
                ),
                format!("{cell} ({nxf} × {nyf} points)"),
            ));
        }
        // Both are small positive integers here (checked just above).
        let (nx, ny) = (nxf as usize, nyf as usize);
        let origin = lo.add_scalar(-cell);
        let slope = SlopeField::new(params, layout);
        slope.check_continuous_over(origin, origin + Vector2::new(nxf - 1.0, nyf - 1.0) * cell)?;

        let node = |ix: usize, iy: usize| origin + Vector2::new(ix as f64, iy as f64) * cell;
        let mut heights = Vec::with_capacity(nx * ny);
        for iy in 0..ny {
            for ix in 0..nx {
                heights.push(slope.height(&node(ix, iy)));
            }
        }

        // Undulation: the wave parameters are always drawn so that switching it off
        // leaves the roughness of the same seed unchanged.
        let waves = UndulationWaves::draw(params.undulation_wavelength_m, rng);
        if params.undulation_m > 0.0 {
            let mut wave = Vec::with_capacity(nx * ny);
            for iy in 0..ny {
                for ix in 0..nx {
                    wave.push(waves.value(&node(ix, iy)));
                }
            }
            let peak = wave.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if peak > 0.0 {
                let scale = params.undulation_m / peak;
                for (h, w) in heights.iter_mut().zip(&wave) {
                    *h += scale * w;
                }
            }
        }

        if params.roughness_m > 0.0 {
            let noise =
                gaussian_noise_field(nx, ny, params.roughness_wavelength_m / (2.0 * cell), rng);
            for (h, n) in heights.iter_mut().zip(&noise) {
                *h += params.roughness_m * n;
            }
        }

        Terrain::from_grid(origin.x, origin.y, cell, nx, ny, heights)
    }

    /// The interior domain `(min, max)` in world `(x, y)`, m, where the surface is the
    /// true spline (and C²); outside it coordinates are clamped.
    pub fn domain(&self) -> (Vector2<f64>, Vector2<f64>) {
        let o = Vector2::new(self.origin_x_m, self.origin_y_m);
        let lo = o.add_scalar(self.cell_m);
        let hi = o + Vector2::new((self.nx - 2) as f64, (self.ny - 2) as f64) * self.cell_m;
        (lo, hi)
    }

    /// World `(x, y)` of grid node `(ix, iy)`, m.
    pub fn node_position(&self, ix: usize, iy: usize) -> Vector2<f64> {
        Vector2::new(
            self.origin_x_m + ix as f64 * self.cell_m,
            self.origin_y_m + iy as f64 * self.cell_m,
        )
    }

    /// Ground height at world `(x, y)`, m (the height of [`Surface::sample`], cheaper).
    pub fn height_at(&self, x: f64, y: f64) -> f64 {
        let sx = self.span(x, self.origin_x_m, self.nx);
        let sy = self.span(y, self.origin_y_m, self.ny);
        let bx = basis(sx.t);
        let by = basis(sy.t);
        let mut h = 0.0;
        for (j, wy) in by.iter().enumerate() {
            h += wy * dot4(&bx, &self.row4(sx.first, sy.first + j));
        }
        h
    }

    /// The four control points of grid row `iy` from column `first`.
    #[inline]
    fn row4(&self, first: usize, iy: usize) -> [f64; 4] {
        let k = iy * self.nx + first;
        [
            self.heights[k],
            self.heights[k + 1],
            self.heights[k + 2],
            self.heights[k + 3],
        ]
    }

    /// Locates coordinate `v` on an axis starting at `origin` with `n` nodes.
    #[inline]
    fn span(&self, v: f64, origin: f64, n: usize) -> AxisSpan {
        let u = (v - origin) / self.cell_m;
        let top = (n - 2) as f64;
        let clamped = u < 1.0 || u > top;
        // `clamp` keeps NaN, so a NaN coordinate gives a NaN height rather than a panic.
        let uc = u.clamp(1.0, top);
        // `as` saturates (NaN → 0); the cell index runs over 1..=n-3.
        let cell = (uc.floor() as usize).clamp(1, n - 3);
        AxisSpan {
            first: cell - 1,
            t: uc - cell as f64,
            clamped,
        }
    }
}

impl Surface for Terrain {
    fn sample(&self, x: f64, y: f64) -> SurfacePoint {
        let sx = self.span(x, self.origin_x_m, self.nx);
        let sy = self.span(y, self.origin_y_m, self.ny);
        let inv = 1.0 / self.cell_m;
        let (bx, dx, ddx) = (basis(sx.t), basis_d1(sx.t), basis_d2(sx.t));
        let (by, dy, ddy) = (basis(sy.t), basis_d1(sy.t), basis_d2(sy.t));
        let (mut h, mut hx, mut hy, mut hxx, mut hxy, mut hyy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for j in 0..4 {
            let c = self.row4(sx.first, sy.first + j);
            let (r0, r1, r2) = (dot4(&bx, &c), dot4(&dx, &c), dot4(&ddx, &c));
            h += by[j] * r0;
            hx += by[j] * r1;
            hy += dy[j] * r0;
            hxx += by[j] * r2;
            hxy += dy[j] * r1;
            hyy += ddy[j] * r0;
        }
        // Outside the domain the height is constant across the edge: zero derivatives.
        if sx.clamped {
            hx = 0.0;
            hxx = 0.0;
            hxy = 0.0;
        }
        if sy.clamped {
            hy = 0.0;
            hyy = 0.0;
            hxy = 0.0;
        }
        let (i1, i2) = (inv, inv * inv);
        SurfacePoint {
            height_m: h,
            gradient: Vector2::new(hx * i1, hy * i1),
            hessian: Matrix2::new(hxx * i2, hxy * i2, hxy * i2, hyy * i2),
        }
    }
}

/// Checks every `[world.terrain]` value on its own (relations to the row layout are
/// checked by [`Terrain::generate`]).
pub fn validate_params(p: &TerrainParams) -> Result<(), ParamError> {
    require_positive("world.terrain.cell_m", p.cell_m)?;
    require_non_negative("world.terrain.margin_m", p.margin_m)?;
    if p.margin_m > MAX_MARGIN_M {
        return Err(ParamError::new(
            "world.terrain.margin_m",
            format!("at most {MAX_MARGIN_M} m (MAX_MARGIN_M)"),
            p.margin_m,
        ));
    }
    for (path, v) in [
        ("world.terrain.slope_along_deg", p.slope_along_deg),
        ("world.terrain.slope_across_deg", p.slope_across_deg),
    ] {
        if !(v.is_finite() && v.abs() < MAX_SLOPE_DEG) {
            return Err(ParamError::new(
                path,
                format!("a slope in (-{MAX_SLOPE_DEG}, {MAX_SLOPE_DEG}) degrees"),
                v,
            ));
        }
    }
    require_non_negative("world.terrain.undulation_m", p.undulation_m)?;
    require_positive(
        "world.terrain.undulation_wavelength_m",
        p.undulation_wavelength_m,
    )?;
    require_non_negative("world.terrain.roughness_m", p.roughness_m)?;
    require_positive(
        "world.terrain.roughness_wavelength_m",
        p.roughness_wavelength_m,
    )?;
    let min_undulation = MIN_UNDULATION_WAVELENGTH_CELLS * p.cell_m;
    if p.undulation_m > 0.0 && p.undulation_wavelength_m < min_undulation {
        return Err(ParamError::new(
            "world.terrain.undulation_wavelength_m",
            format!(
                "at least {MIN_UNDULATION_WAVELENGTH_CELLS} grid cells ({min_undulation} m) \
                 while undulation_m > 0"
            ),
            p.undulation_wavelength_m,
        ));
    }
    let min_roughness = MIN_ROUGHNESS_WAVELENGTH_CELLS * p.cell_m;
    let max_roughness = MAX_ROUGHNESS_WAVELENGTH_CELLS * p.cell_m;
    if p.roughness_m > 0.0 && !(min_roughness..=max_roughness).contains(&p.roughness_wavelength_m) {
        return Err(ParamError::new(
            "world.terrain.roughness_wavelength_m",
            format!(
                "{MIN_ROUGHNESS_WAVELENGTH_CELLS} to {MAX_ROUGHNESS_WAVELENGTH_CELLS} grid cells \
                 ({min_roughness} to {max_roughness} m) while roughness_m > 0"
            ),
            p.roughness_wavelength_m,
        ));
    }
    Ok(())
}

/// The uniform slope part of the height, in row coordinates.
struct SlopeField<'a> {
    layout: &'a RowLayout,
    tan_along: f64,
    tan_across: f64,
    /// Row-0 arc length of the middle of the rows, m: for curved rows the along-row
    /// coordinate is measured within ±π/|k| of it, so the unavoidable discontinuity of a
    /// slope that winds around the circle centre lies as far from the rows as possible.
    s_mid_m: f64,
}

impl<'a> SlopeField<'a> {
    fn new(p: &TerrainParams, layout: &'a RowLayout) -> Self {
        SlopeField {
            layout,
            tan_along: p.slope_along_deg.to_radians().tan(),
            tan_across: p.slope_across_deg.to_radians().tan(),
            s_mid_m: 0.5 * layout.length_m,
        }
    }

    fn curved(&self) -> bool {
        // Same threshold below which RowLayout treats rows as straight.
        self.layout.curvature_per_m.abs() >= 1e-9
    }

    fn height(&self, p: &Vector2<f64>) -> f64 {
        if self.tan_along == 0.0 && self.tan_across == 0.0 {
            return 0.0;
        }
        let (offset, mut s) = self.layout.row_coords(p);
        if self.curved() {
            let k = self.layout.curvature_per_m;
            let dphi = k * (s - self.s_mid_m);
            let wrapped = dphi - TAU * ((dphi + PI) / TAU).floor();
            s = self.s_mid_m + wrapped / k;
        }
        self.tan_along * s + self.tan_across * offset
    }

    /// Fails if the along-row slope is discontinuous somewhere in the box `[lo, hi]`:
    /// for curved rows that is the ray from the circle centre pointing away from the
    /// middle of the rows.
    fn check_continuous_over(&self, lo: Vector2<f64>, hi: Vector2<f64>) -> Result<(), ParamError> {
        if self.tan_along == 0.0 || !self.curved() {
            return Ok(());
        }
        let k = self.layout.curvature_per_m;
        // Offset 1/k is radius zero: the common centre of the arcs.
        let (centre, _) = self.layout.point(1.0 / k, 0.0);
        let (mid, _) = self.layout.point(0.0, self.s_mid_m);
        let dir = centre - mid;
        if ray_hits_box(&centre, &dir, &lo, &hi) {
            return Err(ParamError::new(
                "world.terrain.slope_along_deg",
                format!(
                    "0 for rows this curved (curvature {k} 1/m): the terrain reaches past the \
                     rows' circle centre, where a constant slope along the rows cannot be \
                     continuous; use less curvature or a smaller margin"
                ),
                format!("{}", self.tan_along.atan().to_degrees()),
            ));
        }
        Ok(())
    }
}

/// Whether the ray `origin + t·dir`, `t ≥ 0`, meets the closed box `[lo, hi]`.
fn ray_hits_box(
    origin: &Vector2<f64>,
    dir: &Vector2<f64>,
    lo: &Vector2<f64>,
    hi: &Vector2<f64>,
) -> bool {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..2 {
        if dir[a] == 0.0 {
            if origin[a] < lo[a] || origin[a] > hi[a] {
                return false;
            }
        } else {
            let ta = (lo[a] - origin[a]) / dir[a];
            let tb = (hi[a] - origin[a]) / dir[a];
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    t0 <= t1
}

/// Plane waves of one wavelength with random directions and phases (unnormalised sum of
/// unit cosines).
struct UndulationWaves {
    /// Wave vectors `(kx, ky)`, rad/m, and phases, rad.
    waves: [(Vector2<f64>, f64); UNDULATION_WAVES],
}

impl UndulationWaves {
    fn draw<R: Rng + ?Sized>(wavelength_m: f64, rng: &mut R) -> Self {
        let k = TAU / wavelength_m;
        let theta0 = rng.random::<f64>() * PI;
        let mut waves = [(Vector2::zeros(), 0.0); UNDULATION_WAVES];
        for (i, w) in waves.iter_mut().enumerate() {
            let jitter = (2.0 * rng.random::<f64>() - 1.0) * UNDULATION_DIRECTION_JITTER_RAD;
            let theta = theta0 + PI * i as f64 / UNDULATION_WAVES as f64 + jitter;
            let phase = rng.random::<f64>() * TAU;
            *w = (Vector2::new(theta.cos(), theta.sin()) * k, phase);
        }
        UndulationWaves { waves }
    }

    fn value(&self, p: &Vector2<f64>) -> f64 {
        self.waves
            .iter()
            .map(|(kv, phase)| (kv.dot(p) + phase).cos())
            .sum()
    }
}

/// A `nx × ny` row-major field of zero-mean, unit-variance Gaussian noise with Gaussian
/// autocorrelation `exp(-r²/(4σ²))` (`σ = sigma_cells`, in grid cells): white noise
/// convolved with a truncated Gaussian kernel of standard deviation σ, normalised so
/// that the output variance is exactly 1. The white noise is drawn on a grid padded by
/// the kernel radius so the edges are as rough as the middle.
fn gaussian_noise_field<R: Rng + ?Sized>(
    nx: usize,
    ny: usize,
    sigma_cells: f64,
    rng: &mut R,
) -> Vec<f64> {
    // Small: sigma_cells is bounded by the grid size check of the caller in practice.
    let radius = (ROUGHNESS_KERNEL_RADIUS_SIGMAS * sigma_cells)
        .ceil()
        .max(1.0) as usize;
    let mut kernel: Vec<f64> = (0..=2 * radius)
        .map(|i| {
            let d = i as f64 - radius as f64;
            (-0.5 * (d / sigma_cells).powi(2)).exp()
        })
        .collect();
    // Separable 2-D kernel w_i·w_j on unit white noise gives variance (Σ w_i²)².
    let energy: f64 = kernel.iter().map(|w| w * w).sum();
    for w in &mut kernel {
        *w /= energy.sqrt();
    }
    let (pw, ph) = (nx + 2 * radius, ny + 2 * radius);
    let white: Vec<f64> = (0..pw * ph)
        .map(|_| rng.sample::<f64, _>(StandardNormal))
        .collect();
    // Along x: ph rows of nx values.
    let mut along_x = vec![0.0; nx * ph];
    for y in 0..ph {
        let src = &white[y * pw..(y + 1) * pw];
        for x in 0..nx {
            along_x[y * nx + x] = kernel.iter().zip(&src[x..]).map(|(w, v)| w * v).sum();
        }
    }
    // Along y: ny rows of nx values.
    let mut out = vec![0.0; nx * ny];
    for (k, w) in kernel.iter().enumerate() {
        for y in 0..ny {
            let src = &along_x[(y + k) * nx..(y + k + 1) * nx];
            for (o, v) in out[y * nx..(y + 1) * nx].iter_mut().zip(src) {
                *o += w * v;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::WorldParams;
    use crate::rng::stream;

    const CELL: f64 = 0.5;

    /// A 12 × 10 grid of random heights (std 1 m) on 0.5 m cells.
    fn random_terrain() -> Terrain {
        let mut rng = stream(11, "test.terrain.grid");
        let (nx, ny) = (12, 10);
        let heights = (0..nx * ny)
            .map(|_| rng.sample::<f64, _>(StandardNormal))
            .collect();
        Terrain::from_grid(-3.0, 2.0, CELL, nx, ny, heights).unwrap()
    }

    /// Random points strictly inside the interior domain.
    fn interior_points(t: &Terrain, n: usize) -> Vec<(f64, f64)> {
        let (lo, hi) = t.domain();
        let mut rng = stream(12, "test.terrain.points");
        (0..n)
            .map(|_| {
                let u: f64 = rng.random_range(0.01..0.99);
                let v: f64 = rng.random_range(0.01..0.99);
                (lo.x + u * (hi.x - lo.x), lo.y + v * (hi.y - lo.y))
            })
            .collect()
    }

    fn flat_params() -> TerrainParams {
        TerrainParams {
            cell_m: CELL,
            margin_m: 20.0,
            slope_along_deg: 0.0,
            slope_across_deg: 0.0,
            undulation_m: 0.0,
            undulation_wavelength_m: 60.0,
            roughness_m: 0.0,
            roughness_wavelength_m: 1.5,
        }
    }

    fn layout(yaw_deg: f64, k: f64) -> RowLayout {
        RowLayout {
            count: 6,
            length_m: 120.0,
            spacing_m: 2.5,
            yaw_rad: yaw_deg.to_radians(),
            curvature_per_m: k,
        }
    }

    fn generate(p: &TerrainParams, l: &RowLayout) -> Terrain {
        Terrain::generate(p, l, 8.0, &mut stream(5, "world.terrain")).unwrap()
    }

    // Central differences with step H: truncation error ≤ H²/6 · max|third derivative|.
    // On 0.5 m cells with O(1 m) control points the spline's third derivative is below
    // ~12·max|c|/cell³ ≈ 300 (grid std 1, |c| < 4), so ≤ 5e-9; rounding adds about
    // 1e-16 · 4 / 1e-5 = 4e-11. 1e-7 leaves a margin.
    const H: f64 = 1e-5;
    const FD_TOL: f64 = 1e-7;

    #[test]
    fn gradient_and_hessian_match_finite_differences() {
        let t = random_terrain();
        for (x, y) in interior_points(&t, 200) {
            let s = t.sample(x, y);
            let gx = (t.sample(x + H, y).height_m - t.sample(x - H, y).height_m) / (2.0 * H);
            let gy = (t.sample(x, y + H).height_m - t.sample(x, y - H).height_m) / (2.0 * H);
            assert!(
                (s.gradient - Vector2::new(gx, gy)).norm() < FD_TOL,
                "{:?} vs {gx} {gy}",
                s.gradient
            );
            let dgx = (t.sample(x + H, y).gradient - t.sample(x - H, y).gradient) / (2.0 * H);
            let dgy = (t.sample(x, y + H).gradient - t.sample(x, y - H).gradient) / (2.0 * H);
            let fd = Matrix2::from_columns(&[dgx, dgy]);
            assert!(
                (s.hessian - fd).norm() < 10.0 * FD_TOL,
                "{} vs {fd}",
                s.hessian
            );
            assert_eq!(s.hessian[(0, 1)], s.hessian[(1, 0)]);
            assert!((t.height_at(x, y) - s.height_m).abs() < 1e-12);
        }
    }

    #[test]
    fn surface_is_c2_across_cell_boundaries() {
        let t = random_terrain();
        let e = 1e-9;
        // Across a jump of 2e-9 m: height changes ≤ |grad|·2e-9, gradient ≤ |H|·2e-9,
        // Hessian ≤ |third derivative|·2e-9 (< 1e-6); a C¹-only surface (e.g. Catmull-Rom)
        // would jump by O(1/cell²) in the Hessian here.
        for ix in 2..t.nx - 2 {
            for y in [2.6, 3.3, 4.1, 5.45] {
                let x = t.origin_x_m + ix as f64 * CELL;
                let (a, b) = (t.sample(x - e, y), t.sample(x + e, y));
                assert!((a.height_m - b.height_m).abs() < 1e-7);
                assert!((a.gradient - b.gradient).norm() < 1e-6);
                assert!(
                    (a.hessian - b.hessian).norm() < 1e-5,
                    "{} vs {}",
                    a.hessian,
                    b.hessian
                );
            }
        }
        for iy in 2..t.ny - 2 {
            for x in [-2.2, -1.1, 0.3, 1.7] {
                let y = t.origin_y_m + iy as f64 * CELL;
                let (a, b) = (t.sample(x, y - e), t.sample(x, y + e));
                assert!((a.height_m - b.height_m).abs() < 1e-7);
                assert!((a.gradient - b.gradient).norm() < 1e-6);
                assert!(
                    (a.hessian - b.hessian).norm() < 1e-5,
                    "{} vs {}",
                    a.hessian,
                    b.hessian
                );
            }
        }
    }

    #[test]
    fn constant_grid_gives_a_constant_surface() {
        let t = Terrain::from_grid(0.0, 0.0, CELL, 8, 7, vec![3.25; 56]).unwrap();
        for (x, y) in interior_points(&t, 100)
            .into_iter()
            .chain([(-10.0, 50.0), (0.0, 0.0)])
        {
            let s = t.sample(x, y);
            assert!((s.height_m - 3.25).abs() < 1e-14);
            assert!(s.gradient.norm() < 1e-12 && s.hessian.norm() < 1e-10);
        }
    }

    #[test]
    fn linear_grid_is_reproduced_exactly() {
        let (a, b, c) = (0.3, -0.7, 1.5);
        let (nx, ny, ox, oy) = (9, 8, 10.0, -4.0);
        let heights = (0..ny)
            .flat_map(|iy| (0..nx).map(move |ix| (ix, iy)))
            .map(|(ix, iy)| a * (ox + ix as f64 * CELL) + b * (oy + iy as f64 * CELL) + c)
            .collect();
        let t = Terrain::from_grid(ox, oy, CELL, nx, ny, heights).unwrap();
        for (x, y) in interior_points(&t, 200) {
            let s = t.sample(x, y);
            assert!((s.height_m - (a * x + b * y + c)).abs() < 1e-12);
            assert!((s.gradient - Vector2::new(a, b)).norm() < 1e-12);
            assert!(s.hessian.norm() < 1e-10);
        }
    }

    #[test]
    fn outside_the_domain_coordinates_are_clamped() {
        let t = random_terrain();
        let (lo, hi) = t.domain();
        let edge = t.sample(hi.x, 4.0);
        let out = t.sample(hi.x + 7.0, 4.0);
        assert!((out.height_m - edge.height_m).abs() < 1e-12);
        assert_eq!(out.gradient.x, 0.0);
        assert!((out.gradient.y - edge.gradient.y).abs() < 1e-12);
        let corner = t.sample(lo.x - 1e6, lo.y - 1e6);
        assert!((corner.height_m - t.height_at(lo.x, lo.y)).abs() < 1e-12);
        assert_eq!(corner.gradient, Vector2::zeros());
        assert!(
            t.sample(f64::INFINITY, f64::NEG_INFINITY)
                .height_m
                .is_finite()
        );
        assert!(t.sample(f64::NAN, 3.0).height_m.is_nan());
    }

    #[test]
    fn from_grid_rejects_malformed_grids() {
        assert!(Terrain::from_grid(0.0, 0.0, CELL, 3, 5, vec![0.0; 15]).is_err());
        assert!(Terrain::from_grid(0.0, 0.0, CELL, 4, 5, vec![0.0; 19]).is_err());
        assert!(Terrain::from_grid(0.0, 0.0, 0.0, 4, 4, vec![0.0; 16]).is_err());
    }

    #[test]
    fn grid_domain_covers_rows_headlands_and_margin() {
        let l = layout(25.0, 0.0);
        let t = generate(&flat_params(), &l);
        let (lo, hi) = l.bounds(20.0 + 8.0);
        let (dlo, dhi) = t.domain();
        assert!(dlo.x <= lo.x && dlo.y <= lo.y && dhi.x >= hi.x && dhi.y >= hi.y);
        // ... and not by more than a cell.
        assert!(hi.x - dhi.x > -CELL - 1e-9 && dlo.x - lo.x > -1e-9);
        assert_eq!(t.heights.len(), t.nx * t.ny);
    }

    /// Directional derivative of the surface at `(offset, s)` along and across the rows.
    fn slopes_at(t: &Terrain, l: &RowLayout, offset: f64, s: f64) -> (f64, f64) {
        let (p, tangent) = l.point(offset, s);
        let normal = Vector2::new(-tangent.y, tangent.x);
        let g = t.sample(p.x, p.y).gradient;
        (g.dot(&tangent), g.dot(&normal))
    }

    #[test]
    fn pure_slope_has_the_requested_gradient_along_and_across_rows() {
        let mut p = flat_params();
        p.slope_along_deg = 3.0;
        p.slope_across_deg = -2.0;
        let (ta, tc) = (3f64.to_radians().tan(), (-2f64).to_radians().tan());
        // Straight rows at yaw 25°: the field is linear, which the spline reproduces.
        let l = layout(25.0, 0.0);
        let t = generate(&p, &l);
        for (off, s) in [(0.0, 0.0), (6.25, 60.0), (12.5, 119.0), (-3.0, -5.0)] {
            let (along, across) = slopes_at(&t, &l, off, s);
            assert!((along - ta).abs() < 1e-10, "{along} vs {ta}");
            assert!((across - tc).abs() < 1e-10, "{across} vs {tc}");
        }
        let expect = Vector2::new(25f64.to_radians().cos(), 25f64.to_radians().sin()) * ta
            + Vector2::new(-(25f64.to_radians().sin()), 25f64.to_radians().cos()) * tc;
        assert!((t.sample(10.0, 20.0).gradient - expect).norm() < 1e-10);
        // Curved rows (250 m radius): at offset o a metre along the row is 1/(1 - k·o)
        // metres of row-0 arc length, so the along-row slope is tan(α)/(1 - k·o); across,
        // the offset grows one metre per metre. The field is no longer linear; the
        // spline's error in the gradient is O(cell² · tan(α)/R²) ≈ 1e-7.
        let k = 0.004;
        let l = layout(25.0, k);
        let t = generate(&p, &l);
        for (off, s) in [
            (0.0, 0.0),
            (0.0, 3.0),
            (0.0, 10.0),
            (10.0, 2.0),
            (-2.5, 60.0),
        ] {
            let (along, across) = slopes_at(&t, &l, off, s);
            let along_expect = ta / (1.0 - k * off);
            assert!(
                (along - along_expect).abs() < 1e-5,
                "{along} vs {along_expect}"
            );
            assert!((across - tc).abs() < 1e-5, "{across} vs {tc}");
        }
    }

    #[test]
    fn strongly_curved_sloped_rows_are_rejected_where_the_slope_would_tear() {
        let mut p = flat_params();
        p.slope_along_deg = 2.0;
        // 50 m radius over 120 m: the grid reaches past the circle centre.
        let l = layout(0.0, 0.02);
        let err = Terrain::generate(&p, &l, 8.0, &mut stream(5, "world.terrain")).unwrap_err();
        assert_eq!(err.path, "world.terrain.slope_along_deg");
        // Without an along-row slope the same rows are fine, and so is a gentle curve.
        p.slope_along_deg = 0.0;
        assert!(Terrain::generate(&p, &l, 8.0, &mut stream(5, "world.terrain")).is_ok());
        p.slope_along_deg = 2.0;
        assert!(Terrain::generate(&p, &layout(0.0, 0.002), 8.0, &mut stream(5, "x")).is_ok());
    }

    #[test]
    fn undulation_has_its_amplitude_and_wavelength() {
        let mut p = flat_params();
        p.undulation_m = 0.4;
        let l = layout(25.0, 0.0);
        let t = generate(&p, &l);
        // Grid nodes: peak-normalised to the amplitude.
        let peak = t.heights.iter().fold(0.0f64, |m, h| m.max(h.abs()));
        assert!((peak - 0.4).abs() < 1e-12, "{peak}");
        // The spline smooths by (4 + 2cos(2π·cell/λ))/6 per axis, < 0.1 % here.
        let (lo, hi) = t.domain();
        let mut max_surface = 0.0f64;
        let k2 = (TAU / p.undulation_wavelength_m).powi(2);
        for i in 0..200 {
            for j in 0..200 {
                let x = lo.x + (hi.x - lo.x) * (i as f64 + 0.5) / 200.0;
                let y = lo.y + (hi.y - lo.y) * (j as f64 + 0.5) / 200.0;
                let s = t.sample(x, y);
                max_surface = max_surface.max(s.height_m.abs());
                // Plane waves of one wavelength solve ∇²h + k²h = 0 (Helmholtz), an
                // independent check of the wavelength and of the analytic Hessian. The
                // spline's Laplacian error is O((k·cell)²)·k²·A ≈ 3e-4 · 4.4e-3.
                let laplacian = s.hessian.trace();
                assert!(
                    (laplacian + k2 * s.height_m).abs() < 2e-6,
                    "{laplacian} vs {}",
                    -k2 * s.height_m
                );
            }
        }
        assert!(
            max_surface > 0.38 && max_surface <= 0.4 + 1e-9,
            "{max_surface}"
        );
    }

    /// Sample mean and standard deviation.
    fn mean_std(v: &[f64]) -> (f64, f64) {
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean, var.sqrt())
    }

    #[test]
    fn roughness_has_its_standard_deviation_and_correlation_length() {
        let mut p = flat_params();
        p.roughness_m = 0.02;
        p.roughness_wavelength_m = 1.5;
        p.margin_m = 60.0;
        let t = generate(&p, &layout(0.0, 0.0));
        // ~ 340 × 280 nodes. With ρ(r) = exp(-r²/L²) the field holds about
        // N / (π L²/cell²) ≈ 95 000 / 28 ≈ 3 400 independent values: the sample std is
        // within ~1/√(2·3400) ≈ 1.2 % of the true one; 10 % is a wide bound.
        let (mean, std) = mean_std(&t.heights);
        assert!(mean.abs() < 0.02 * 0.1, "{mean}");
        assert!((std / 0.02 - 1.0).abs() < 0.1, "{std}");
        // Correlation at lag L (3 cells) should be 1/e.
        let lag = 3;
        let (mut num, mut den) = (0.0, 0.0);
        for iy in 0..t.ny {
            for ix in 0..t.nx - lag {
                let a = t.heights[iy * t.nx + ix] - mean;
                num += a * (t.heights[iy * t.nx + ix + lag] - mean);
                den += a * a;
            }
        }
        let rho = num / den;
        assert!((rho - (-1f64).exp()).abs() < 0.05, "{rho}");
        // The surface is the grid smoothed by the spline: its std is a few % lower.
        let (lo, hi) = t.domain();
        let mut rng = stream(3, "test.points");
        let samples: Vec<f64> = (0..20_000)
            .map(|_| {
                let x = rng.random_range(lo.x..hi.x);
                let y = rng.random_range(lo.y..hi.y);
                t.height_at(x, y)
            })
            .collect();
        let (_, surface_std) = mean_std(&samples);
        assert!(
            surface_std < std && (surface_std / 0.02 - 1.0).abs() < 0.1,
            "{surface_std}"
        );
    }

    #[test]
    fn roughness_is_as_rough_at_the_grid_edges_as_in_the_middle() {
        let mut p = flat_params();
        p.roughness_m = 0.05;
        p.margin_m = 60.0;
        let t = generate(&p, &layout(0.0, 0.0));
        // The first and last two rows of nodes: 4 · ~340 values, correlated over ~3 cells
        // along the row → a few hundred independent values, std known to ~5 %.
        let edge: Vec<f64> = [0, 1, t.ny - 2, t.ny - 1]
            .iter()
            .flat_map(|&iy| t.heights[iy * t.nx..(iy + 1) * t.nx].to_vec())
            .collect();
        let (_, std) = mean_std(&edge);
        assert!((std / 0.05 - 1.0).abs() < 0.2, "{std}");
    }

    #[test]
    fn same_rng_same_terrain() {
        let p = WorldParams::default().terrain;
        let l = layout(25.0, 0.0);
        assert_eq!(generate(&p, &l), generate(&p, &l));
        let other = Terrain::generate(&p, &l, 8.0, &mut stream(6, "world.terrain")).unwrap();
        assert_ne!(generate(&p, &l), other);
    }

    /// Puts one bad value into the parameters.
    type Spoil = fn(&mut TerrainParams);

    #[test]
    fn bad_terrain_parameters_name_their_path() {
        let cases: [(&str, Spoil); 9] = [
            ("world.terrain.cell_m", |p| p.cell_m = 0.0),
            ("world.terrain.margin_m", |p| p.margin_m = -1.0),
            ("world.terrain.slope_along_deg", |p| {
                p.slope_along_deg = 45.0
            }),
            ("world.terrain.slope_across_deg", |p| {
                p.slope_across_deg = f64::NAN
            }),
            ("world.terrain.undulation_m", |p| p.undulation_m = -0.1),
            ("world.terrain.undulation_wavelength_m", |p| {
                p.undulation_wavelength_m = 1.0
            }),
            ("world.terrain.roughness_wavelength_m", |p| {
                p.roughness_wavelength_m = 0.2
            }),
            ("world.terrain.roughness_wavelength_m", |p| {
                p.roughness_wavelength_m = 40.0
            }),
            // Too many grid points (with the roughness off, whose length would not fit).
            ("world.terrain.cell_m", |p| {
                p.cell_m = 0.01;
                p.roughness_m = 0.0;
            }),
        ];
        for (path, spoil) in cases {
            let mut p = WorldParams::default().terrain;
            spoil(&mut p);
            let err =
                Terrain::generate(&p, &layout(25.0, 0.0), 8.0, &mut stream(1, "t")).unwrap_err();
            assert_eq!(err.path, path, "{err}");
        }
    }
}
