//! The keypoint grid for projection search (ORB-SLAM's `Frame::mGrid`): each keypoint is
//! assigned to one cell of a `cols × rows` grid over the image, so that the keypoints
//! near a projected landmark are found by visiting a few cells.
//!
//! Cells are stored compactly (one index array, one offset per cell); rebuilding for a
//! new frame reuses both.

use super::orb::KeyPoint;
use super::{ConfigError, check};
use serde::{Deserialize, Serialize};

/// Grid size.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct GridConfig {
    /// Cells across (ORB-SLAM's `FRAME_GRID_COLS`).
    pub cols: usize,
    /// Cells down (`FRAME_GRID_ROWS`).
    pub rows: usize,
}

impl Default for GridConfig {
    fn default() -> Self {
        GridConfig { cols: 64, rows: 48 }
    }
}

impl GridConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            self.cols >= 1 && self.rows >= 1,
            "grid: cols and rows must be >= 1",
        )
    }
}

/// Keypoint positions bucketed into grid cells.
#[derive(Clone, Debug, Default)]
pub struct FeatureGrid {
    cols: usize,
    rows: usize,
    inv_cell_w: f32,
    inv_cell_h: f32,
    /// `x, y, level` of every keypoint.
    points: Vec<(f32, f32, u8)>,
    /// Keypoint indices of cell `c` are `items[starts[c]..starts[c + 1]]`, ascending.
    starts: Vec<u32>,
    items: Vec<u32>,
    cell_of: Vec<u32>,
    fill: Vec<u32>,
}

impl FeatureGrid {
    /// An empty grid.
    pub fn new(cfg: &GridConfig) -> FeatureGrid {
        FeatureGrid {
            cols: cfg.cols.max(1),
            rows: cfg.rows.max(1),
            ..FeatureGrid::default()
        }
    }

    /// The grid of `keypoints` over a `width × height` image. Keypoints outside the image
    /// go to the nearest border cell.
    pub fn build(cfg: &GridConfig, width: usize, height: usize, keypoints: &[KeyPoint]) -> Self {
        let mut g = FeatureGrid::new(cfg);
        g.assign(width, height, keypoints);
        g
    }

    /// Re-assigns `keypoints` (reusing the buffers).
    pub fn assign(&mut self, width: usize, height: usize, keypoints: &[KeyPoint]) {
        self.inv_cell_w = self.cols as f32 / width.max(1) as f32;
        self.inv_cell_h = self.rows as f32 / height.max(1) as f32;
        self.points.clear();
        self.points
            .extend(keypoints.iter().map(|k| (k.x, k.y, k.level)));
        let n_cells = self.cols * self.rows;
        self.starts.clear();
        self.starts.resize(n_cells + 1, 0);
        self.cell_of.clear();
        for &(x, y, _) in &self.points {
            let c = self.row_of(y) * self.cols + self.col_of(x);
            self.cell_of.push(c as u32);
            self.starts[c + 1] += 1;
        }
        for c in 0..n_cells {
            self.starts[c + 1] += self.starts[c];
        }
        self.items.clear();
        self.items.resize(self.points.len(), 0);
        // Counting sort, stable: indices ascend within a cell.
        self.fill.clear();
        self.fill.extend_from_slice(&self.starts);
        for (i, &c) in self.cell_of.iter().enumerate() {
            let slot = &mut self.fill[c as usize];
            self.items[*slot as usize] = i as u32;
            *slot += 1;
        }
    }

    // `as usize` truncates (= floor for x ≥ 0) and saturates negatives and NaN to 0.
    fn col_of(&self, x: f32) -> usize {
        ((x * self.inv_cell_w) as usize).min(self.cols - 1)
    }

    fn row_of(&self, y: f32) -> usize {
        ((y * self.inv_cell_h) as usize).min(self.rows - 1)
    }

    /// The cell `(col, row)` of a keypoint index.
    pub fn cell_of(&self, index: usize) -> (usize, usize) {
        let c = self.cell_of[index] as usize;
        (c % self.cols, c / self.cols)
    }

    /// Grid size `(cols, rows)`.
    pub fn size(&self) -> (usize, usize) {
        (self.cols, self.rows)
    }

    /// Keypoint indices (ascending) in cell `(col, row)`.
    pub fn cell(&self, col: usize, row: usize) -> &[u32] {
        let c = row * self.cols + col;
        &self.items[self.starts[c] as usize..self.starts[c + 1] as usize]
    }

    /// Indices (ascending) of the keypoints with `|x − kx| < radius`, `|y − ky| < radius`
    /// and `min_level ≤ level ≤ max_level` (ORB-SLAM's `GetFeaturesInArea`: a square
    /// window, strict bounds).
    pub fn features_in_area(
        &self,
        x: f32,
        y: f32,
        radius: f32,
        min_level: u8,
        max_level: u8,
    ) -> Vec<usize> {
        let mut out = Vec::new();
        self.features_in_area_into(x, y, radius, min_level, max_level, &mut out);
        out
    }

    /// [`FeatureGrid::features_in_area`] into a reused vector (cleared first).
    pub fn features_in_area_into(
        &self,
        x: f32,
        y: f32,
        radius: f32,
        min_level: u8,
        max_level: u8,
        out: &mut Vec<usize>,
    ) {
        out.clear();
        if self.points.is_empty() || radius <= 0.0 || radius.is_nan() {
            return;
        }
        let (c0, c1) = (self.col_of(x - radius), self.col_of(x + radius));
        let (r0, r1) = (self.row_of(y - radius), self.row_of(y + radius));
        for row in r0..=r1 {
            for col in c0..=c1 {
                for &i in self.cell(col, row) {
                    let (kx, ky, l) = self.points[i as usize];
                    if (kx - x).abs() < radius
                        && (ky - y).abs() < radius
                        && (min_level..=max_level).contains(&l)
                    {
                        out.push(i as usize);
                    }
                }
            }
        }
        out.sort_unstable();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kp(x: f32, y: f32, level: u8) -> KeyPoint {
        KeyPoint {
            x,
            y,
            level,
            angle_rad: 0.0,
            response: 1.0,
            size: 31.0,
        }
    }

    #[test]
    fn cells_and_queries() {
        let kps = [kp(5.0, 5.0, 0), kp(100.0, 50.0, 1), kp(-3.0, 500.0, 2)];
        let g = FeatureGrid::build(&GridConfig { cols: 10, rows: 5 }, 200, 100, &kps);
        assert_eq!(g.cell_of(0), (0, 0));
        assert_eq!(g.cell_of(1), (5, 2));
        assert_eq!(g.cell_of(2), (0, 4));
        assert_eq!(g.features_in_area(100.0, 50.0, 1.0, 0, 7), vec![1]);
        assert!(g.features_in_area(100.0, 50.0, 1.0, 2, 7).is_empty());
        assert_eq!(g.features_in_area(0.0, 0.0, 6.0, 0, 0), vec![0]);
        // Strict bounds: exactly `radius` away is outside.
        assert!(g.features_in_area(0.0, 5.0, 5.0, 0, 7).is_empty());
    }
}
