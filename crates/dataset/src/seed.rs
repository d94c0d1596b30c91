//! The dataset's seed derivation, shared by the simulation and the road users' paint.

/// SplitMix64 of the dataset seed and a stream: independent seeds per scene, frame, sensor.
pub fn derive_seed(seed: u64, stream: &[u64]) -> u64 {
    let mut x = seed ^ 0x9e37_79b9_7f4a_7c15;
    for &s in stream {
        x = x.wrapping_add(s.wrapping_mul(0xbf58_476d_1ce4_e5b9)).wrapping_add(0x9e37_79b9_7f4a_7c15);
        x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        x ^= x >> 31;
    }
    x
}
