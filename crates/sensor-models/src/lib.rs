//! LiDAR and 4D-radar sensor models for hilo.
//!
//! - [`spec`]: specifications and the priced catalog (`fixtures/sensors.toml`, the paper's
//!   Table I; `fixtures/sensors-datasheet.toml`, LiDARs with datasheet beam tables and range by
//!   reflectivity), validated once.
//! - [`lidar`], [`radar`]: scan simulation over a [`hilo_raycast::World`] and the frame's
//!   actors; deterministic for a seed. [`lidar::beam`]: a LiDAR beam of finite width (sub-rays
//!   over its footprint, echoes, the strongest, last or dual returns). [`fog`]: fog's own
//!   echo for a LiDAR (Hahner et al.'s soft-target channel).
//! - [`radar_effects`]: what a real radar adds to the ideal one, each a catalog setting:
//!   azimuth by angle, unresolved targets, multipath ghosts, side lobes, false alarms,
//!   vegetation Doppler, RCS by aspect.
//! - [`probability`]: the detection-probability model placement uses (expected LiDAR returns,
//!   radar detection probability) for probe targets.
//! - [`export`]: PCD and PLY writers and readers.
//! - [`weather`]: rain and fog (published attenuation models) applied to the specs.
//! - [`range`]: the hard-target range equation through extinction (Lambert's W), which the
//!   specs and the weather share.
//!
//! The difference the paper studies is made physical here: a LiDAR returns dense geometry whose
//! density falls with range and beam count; a radar returns a few detections per target, each
//! with RCS and an exact radial velocity.

pub mod error;
pub mod export;
pub mod fog;
pub mod lidar;
pub mod noise;
pub mod pose;
pub mod probability;
pub mod radar;
pub mod radar_effects;
pub mod radar_pair;
pub mod range;
pub mod spec;
pub mod weather;

pub use error::SensorError;
pub use lidar::{LidarScan, PointSource, lidar_points_on, lidar_points_on_each, simulate_lidar};
pub use pose::{CalibrationError, SensorPose};
pub use probability::{Probe, lidar_expected_returns, radar_detection_probability};
pub use radar::{RadarScan, simulate_radar};
pub use spec::{Beam, Catalog, DetectionRange, Foliage, LidarSpec, RadarSpec, ReturnMode, SensorSpec};
pub use weather::Weather;
