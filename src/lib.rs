//! hilo: which roadside sensors to mount where at an intersection, and how well they will detect
//! road users. This umbrella package re-exports the workspace crates so that the top-level
//! `tests/` (cross-crate, end-to-end) and `benches/` (criterion) are ordinary Cargo targets.

pub use hilo_core as core;
pub use hilo_raycast as raycast;
pub use hilo_sensor_models as sensors;
