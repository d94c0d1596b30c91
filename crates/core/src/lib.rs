//! Shared value types of hilo.
//!
//! Units everywhere: metres, seconds, radians inside the code (degrees only in config field names
//! ending in `_deg`), velocities in m/s, radar cross-section in dBsm. The world frame is
//! right-handed with z up and yaw counter-clockwise from +x.
//!
//! World coordinates (e.g. UTM eastings of several hundred kilometres) do not fit f32 at
//! millimetre precision, so geometry lives in a *local* f32 frame whose origin is an f64 world
//! point ([`LocalFrame`]); [`Pose`] keeps f64 and converts once.

pub mod background;
mod boxes;
mod class;
pub mod folder;
mod frame;
pub mod fs;
pub mod iou;
pub mod machine;
mod points;
pub mod valid;

pub use boxes::{Box3, nuscenes_box_defect};
pub use class::{Class, UnknownClass};
pub use frame::{LocalFrame, Pose};
pub use points::{Detection, LidarPoint, RadarPoint};
pub use valid::{Check, Valid};

/// A configuration value refused: its field (with its section), the value, and why. The error
/// of the small validators a section's owner wraps into its own error type.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{field} = {value}: {reason}")]
pub struct FieldError {
    pub field: String,
    pub value: String,
    pub reason: String,
}

impl FieldError {
    pub fn new(field: impl Into<String>, value: impl ToString, reason: impl Into<String>) -> Self {
        FieldError { field: field.into(), value: value.to_string(), reason: reason.into() }
    }
}

/// Re-exported so that every crate names the same glam.
pub use glam;
