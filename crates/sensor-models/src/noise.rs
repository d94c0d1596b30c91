//! Deterministic random numbers for scans: every ray and every target draws from its own
//! generator, seeded from (seed, stream, index), so results do not depend on thread scheduling
//! and the same seed gives the same bytes.

use rand::SeedableRng;
use rand_pcg::Pcg32;

/// A 64-bit mix (the splitmix64 finaliser) of the seed, a stream id and an index; also how a
/// caller derives the seed of one sensor in one frame: `mix(seed, sensor_index, frame_index)`.
pub fn mix(seed: u64, stream: u64, index: u64) -> u64 {
    let mut z = seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The generator for one (seed, stream, index).
pub fn rng_for(seed: u64, stream: u64, index: u64) -> Pcg32 {
    Pcg32::seed_from_u64(mix(seed, stream, index))
}

/// Stream ids, so that LiDAR rays, radar cells and radar targets never share generators.
pub mod stream {
    pub const LIDAR_RAY: u64 = 1;
    pub const RADAR_TARGET: u64 = 2;
    pub const RADAR_CELL: u64 = 3;
    /// A rig sensor's calibration error (one draw per dataset seed and sensor).
    pub const CALIBRATION: u64 = 4;
    /// A radar's side lobes and false alarms.
    pub const RADAR_ARTEFACT: u64 = 5;
    /// A rig sensor's clock offset (one draw per dataset seed and sensor).
    pub const TIME_SYNC: u64 = 6;
    /// A LiDAR ray's passage through moving foliage.
    pub const LIDAR_FOLIAGE: u64 = 7;
    /// Where in fog's echo a LiDAR ray's fog point lies, and whether it survives the drop-off.
    pub const LIDAR_FOG: u64 = 8;
}
