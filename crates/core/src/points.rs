use crate::{Box3, Class};
use glam::Vec2;
use serde::{Deserialize, Serialize};

/// One LiDAR return, in whichever frame the container says (sensor or local world).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LidarPoint {
    pub x: f32,
    pub y: f32,
    pub z: f32,
    /// Return intensity in [0, 1] (reflectivity attenuated by range).
    pub intensity: f32,
    /// Beam (laser) index, 0 = lowest elevation.
    pub ring: u16,
    /// Time of the return relative to the start of the frame, seconds.
    pub time_s: f32,
}

/// One 4D-radar detection, with the fields of the View-of-Delft radar format.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RadarPoint {
    pub x: f32,
    pub y: f32,
    pub z: f32,
    /// Radar cross-section, dBsm.
    pub rcs_dbsm: f32,
    /// Radial (Doppler) velocity, m/s; negative when the target approaches the sensor.
    pub v_r_mps: f32,
    /// Radial velocity compensated for the sensor's own motion, m/s. A roadside radar is
    /// static, so this equals `v_r_mps`.
    pub v_r_comp_mps: f32,
    /// Time of the detection relative to the start of the frame, seconds.
    pub time_s: f32,
}

/// A detected (or annotated) road user.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    #[serde(rename = "box")]
    pub box3: Box3,
    pub class: Class,
    /// Confidence in [0, 1]; 1 for ground truth.
    pub score: f32,
    /// Planar velocity, m/s, world frame.
    pub velocity_mps: Vec2,
}
