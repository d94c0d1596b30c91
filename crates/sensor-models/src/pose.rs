//! Where a sensor sits: a pose in the scene's local frame.

use crate::error::SensorError;
use glam::{EulerRot, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// Sensor mount in the scene's local frame. The sensor's +x is its boresight (azimuth 0), +z its
/// up axis. Angles in radians; positive pitch tilts the boresight down.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorPose {
    pub position: Vec3,
    pub yaw: f32,
    pub pitch: f32,
    pub roll: f32,
}

impl SensorPose {
    pub fn new(position: Vec3, yaw: f32, pitch: f32, roll: f32) -> Self {
        Self { position, yaw, pitch, roll }
    }

    /// Parses `x,y,z[,yaw_deg[,pitch_deg[,roll_deg]]]` (metres, degrees).
    pub fn parse(text: &str) -> Result<Self, SensorError> {
        let v: Vec<f32> = text
            .split(',')
            .map(|s| s.trim().parse::<f32>().map_err(|_| SensorError::Pose(format!("{text:?}: {s:?} is not a number"))))
            .collect::<Result<_, _>>()?;
        if !(3..=6).contains(&v.len()) || v.iter().any(|x| !x.is_finite()) {
            return Err(SensorError::Pose(format!(
                "{text:?}: expected x,y,z[,yaw_deg[,pitch_deg[,roll_deg]]] with finite numbers"
            )));
        }
        let a = |i: usize| v.get(i).copied().unwrap_or(0.0).to_radians();
        Ok(Self::new(Vec3::new(v[0], v[1], v[2]), a(3), a(4), a(5)))
    }

    pub fn rotation(&self) -> Quat {
        Quat::from_euler(EulerRot::ZYX, self.yaw, self.pitch, self.roll)
    }

    /// Sensor-frame point to the local (scene) frame.
    pub fn to_local(&self, p: Vec3) -> Vec3 {
        self.position + self.rotation() * p
    }

    /// Local-frame point to the sensor frame.
    pub fn to_sensor(&self, p: Vec3) -> Vec3 {
        self.rotation().inverse() * (p - self.position)
    }

    pub fn is_valid(&self) -> bool {
        self.position.is_finite() && self.yaw.is_finite() && self.pitch.is_finite() && self.roll.is_finite()
    }
}

/// A rig's calibration error: how far a mounted sensor's true pose lies from the pose its
/// calibration records (the extrinsic error a survey or a target-based calibration leaves).
/// Each component is drawn once per sensor from a zero-mean Gaussian of these standard
/// deviations: the position per axis, and yaw, pitch and roll each.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationError {
    pub rotation_deg: f32,
    pub translation_m: f32,
}

impl SensorPose {
    /// This (recorded) pose moved by a draw of `error` from `rng`: the sensor's true pose.
    pub fn miscalibrated(&self, error: &CalibrationError, rng: &mut impl rand::Rng) -> SensorPose {
        let mut normal = || -> f32 { rng.sample(rand_distr::StandardNormal) };
        let t = error.translation_m;
        let position = self.position + Vec3::new(t * normal(), t * normal(), t * normal());
        let r = error.rotation_deg.to_radians();
        let (dy, dp, dr) = (r * normal(), r * normal(), r * normal());
        SensorPose { position, yaw: self.yaw + dy, pitch: self.pitch + dp, roll: self.roll + dr }
    }
}

/// Unit direction for azimuth `az` (counter-clockwise from +x) and elevation `el`, radians.
#[inline]
pub fn spherical_dir(az: f32, el: f32) -> Vec3 {
    let (se, ce) = el.sin_cos();
    let (sa, ca) = az.sin_cos();
    Vec3::new(ce * ca, ce * sa, se)
}
