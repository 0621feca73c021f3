//! The terrain height field and its C²-smooth surface. (Implementation pending.)

use super::surface::{Surface, SurfacePoint};

/// The ground of the vineyard: a regular grid of heights over the field and its margin,
/// evaluated as a smooth surface.
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
    /// Heights, row-major: `heights[iy * nx + ix]`, m.
    pub heights: Vec<f64>,
}

impl Surface for Terrain {
    fn sample(&self, _x: f64, _y: f64) -> SurfacePoint {
        todo!("terrain surface")
    }
}
