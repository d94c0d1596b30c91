//! hilo: which roadside sensors to mount where at an intersection, and how well they will detect
//! road users.
//!
//! This umbrella package re-exports the workspace crates (so that the top-level `tests/`, end to
//! end, and `benches/`, criterion, are ordinary Cargo targets) and holds the one list of fusion
//! plugins hilo ships, [`registry`], which the command line, the tests and the benchmarks share.

pub use hilo_bench as bench;
pub use hilo_core as core;
pub use hilo_dataset as dataset;
pub use hilo_detector as detector;
pub use hilo_eval as eval;
pub use hilo_fusion as fusion;
pub use hilo_placement_ip as placement;
pub use hilo_raycast as raycast;
pub use hilo_sensor_models as sensors;
pub use hilo_study as study;

/// Every fusion plugin hilo ships, with its presets, and the LiDAR-only ones; `lirafusion-like`
/// (LiRaFusion's design, the paper's fusion network) is the fusion preset a study tests by
/// default, against its LiDAR-only counterpart, `centerpoint`. Adding a plugin is one crate
/// and one line here.
pub fn registry() -> hilo_detector::Result<hilo_detector::Registry> {
    let mut r = hilo_detector::Registry::with_builtin();
    hilo_fusion_raw::register(&mut r)?;
    hilo_fusion_early::register(&mut r)?;
    hilo_fusion_middle::register(&mut r)?;
    hilo_fusion_late::register(&mut r)?;
    r.set_primary("lirafusion-like")?;
    Ok(r)
}
