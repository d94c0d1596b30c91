//! The bird's-eye-view grid the detectors work on: it covers the evaluation range around the
//! scene origin (cars are evaluated to 50 m), not more.

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BevGrid {
    /// Half the side of the square covered, metres (centred on the scene origin).
    pub half_extent_m: f32,
    /// Pillar size, metres.
    pub cell_m: f32,
    /// Points outside [z_min, z_max] (local frame) are dropped.
    pub z_min_m: f32,
    pub z_max_m: f32,
    /// At most this many points per pillar (the rest are dropped, deterministically).
    pub max_points_per_pillar: usize,
    /// At most this many non-empty pillars per frame and modality.
    pub max_pillars: usize,
}

impl Default for BevGrid {
    fn default() -> Self {
        BevGrid {
            half_extent_m: 51.2,
            cell_m: 0.8,
            z_min_m: -1.0,
            z_max_m: 5.0,
            max_points_per_pillar: 10,
            max_pillars: 8000,
        }
    }
}

impl BevGrid {
    pub fn cells(&self) -> usize {
        (2.0 * self.half_extent_m / self.cell_m).round() as usize
    }

    /// Cell (column, row) of a point, if inside the grid.
    pub fn cell_of(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        let n = self.cells() as f32;
        let (cx, cy) = ((x + self.half_extent_m) / self.cell_m, (y + self.half_extent_m) / self.cell_m);
        (cx >= 0.0 && cy >= 0.0 && cx < n && cy < n).then_some((cx as usize, cy as usize))
    }

    /// Centre of a cell.
    pub fn center(&self, col: usize, row: usize) -> (f32, f32) {
        (-self.half_extent_m + (col as f32 + 0.5) * self.cell_m, -self.half_extent_m + (row as f32 + 0.5) * self.cell_m)
    }

    pub fn validate(&self) -> Result<(), String> {
        use crate::limits;
        if !(self.cell_m.is_finite() && self.cell_m >= limits::CELL_M_MIN) {
            return Err(format!("grid: cell_m = {} must be at least {} m", self.cell_m, limits::CELL_M_MIN));
        }
        let n = 2.0 * self.half_extent_m / self.cell_m;
        if !(n.is_finite() && n <= limits::GRID_CELLS as f32) {
            return Err(format!(
                "grid: half_extent_m = {} and cell_m = {} give {n} cells a side, more than the {} allowed (a \
                 {}-cell grid needs gigabytes per map)",
                self.half_extent_m,
                self.cell_m,
                limits::GRID_CELLS,
                limits::GRID_CELLS
            ));
        }
        if !(self.z_min_m.is_finite() && self.z_max_m.is_finite()) {
            return Err(format!("grid: z_min_m = {} and z_max_m = {} must be finite", self.z_min_m, self.z_max_m));
        }
        if self.max_points_per_pillar > limits::POINTS_PER_PILLAR || self.max_pillars > limits::PILLARS {
            return Err(format!(
                "grid: max_points_per_pillar = {} (at most {}) and max_pillars = {} (at most {}) size every batch's \
                 point tensor",
                self.max_points_per_pillar,
                limits::POINTS_PER_PILLAR,
                self.max_pillars,
                limits::PILLARS
            ));
        }
        if !(self.half_extent_m > 0.0 && self.cell_m > 0.0)
            || (n - n.round()).abs() > 1e-3
            || !(n.round() as usize).is_multiple_of(4)
        {
            return Err(format!("grid: 2 × half_extent_m / cell_m = {n} must be a whole multiple of 4"));
        }
        if self.z_max_m <= self.z_min_m || self.max_points_per_pillar == 0 || self.max_pillars == 0 {
            return Err("grid: need z_max_m > z_min_m and positive point and pillar limits".into());
        }
        Ok(())
    }
}

/// A 32 × 32 grid of 0.8 m pillars: small enough for tests.
pub fn small_grid() -> BevGrid {
    BevGrid { half_extent_m: 12.8, cell_m: 0.8, max_pillars: 2000, ..BevGrid::default() }
}
