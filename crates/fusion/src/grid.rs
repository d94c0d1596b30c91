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

    /// A grid that can be allocated and tiled: fine enough cells but not too many, a whole
    /// multiple of 4 cells a side, finite heights in order, bounded point and pillar limits.
    pub fn validate(&self) -> Result<(), hilo_core::FieldError> {
        use crate::limits;
        let bad = |field: &str, value: &dyn std::fmt::Display, reason: String| {
            Err(hilo_core::FieldError::new(format!("grid.{field}"), value, reason))
        };
        if !(self.cell_m.is_finite() && self.cell_m >= limits::CELL_M_MIN) {
            return bad("cell_m", &self.cell_m, format!("must be at least {} m", limits::CELL_M_MIN));
        }
        let n = 2.0 * self.half_extent_m / self.cell_m;
        if !(n.is_finite() && n <= limits::GRID_CELLS as f32) {
            return bad(
                "half_extent_m",
                &self.half_extent_m,
                format!(
                    "with cell_m = {} it gives {n} cells a side, more than the {} allowed (a {}-cell grid needs \
                     gigabytes per map)",
                    self.cell_m,
                    limits::GRID_CELLS,
                    limits::GRID_CELLS
                ),
            );
        }
        if !(self.z_min_m.is_finite() && self.z_max_m.is_finite() && self.z_max_m > self.z_min_m) {
            return bad(
                "z_min_m, z_max_m",
                &format!("{}, {}", self.z_min_m, self.z_max_m),
                "must be finite, in order".into(),
            );
        }
        if !(1..=limits::POINTS_PER_PILLAR).contains(&self.max_points_per_pillar) {
            return bad(
                "max_points_per_pillar",
                &self.max_points_per_pillar,
                format!("give 1 to {} (it sizes every batch's point tensor)", limits::POINTS_PER_PILLAR),
            );
        }
        if !(1..=limits::PILLARS).contains(&self.max_pillars) {
            return bad(
                "max_pillars",
                &self.max_pillars,
                format!("give 1 to {} (it sizes every batch's point tensor)", limits::PILLARS),
            );
        }
        if !(self.half_extent_m > 0.0 && self.cell_m > 0.0)
            || (n - n.round()).abs() > 1e-3
            || !(n.round() as usize).is_multiple_of(4)
        {
            return bad(
                "half_extent_m",
                &self.half_extent_m,
                format!("2 × half_extent_m / cell_m = {n} (cell_m = {}) must be a whole multiple of 4", self.cell_m),
            );
        }
        Ok(())
    }
}

/// A 32 × 32 grid of 0.8 m pillars: small enough for tests.
pub fn small_grid() -> BevGrid {
    BevGrid { half_extent_m: 12.8, cell_m: 0.8, max_pillars: 2000, ..BevGrid::default() }
}
