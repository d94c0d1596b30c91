//! Stated limits on the values that size a training's allocations: far above any detector of
//! this field (the presets use a 128-cell grid, 10 points a pillar, 8,000 pillars, 16–128
//! channels, batch 2–16), and low enough that a typing slip (`1e9` channels) is refused with
//! the field named instead of ending in an allocation failure after the datasets were made.

/// Cells along a side of the bird's-eye grid.
pub const GRID_CELLS: usize = 2048;
/// Smallest pillar, metres.
pub const CELL_M_MIN: f32 = 0.05;
pub const POINTS_PER_PILLAR: usize = 1024;
pub const PILLARS: usize = 1 << 20;
/// Channels of a backbone block, its neck or the head.
pub const CHANNELS: usize = 2048;
/// Convolutions after a block's first.
pub const LAYERS: usize = 64;
pub const BLOCKS: usize = 16;
pub const BATCH: usize = 4096;
/// Training samples of one schedule (a billion: years of CPU time); small enough that
/// twice it (a validation trains to 2b) cannot overflow.
pub const SAMPLES: usize = 1_000_000_000;
