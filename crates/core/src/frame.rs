use glam::{DQuat, DVec3, EulerRot, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// A rigid pose in the world frame, kept in f64 so that geo-referenced coordinates
/// (hundreds of kilometres) keep sub-millimetre precision.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// World position, metres.
    pub translation: DVec3,
    /// Orientation; the body's +x is its forward axis, +z its up axis.
    pub rotation: DQuat,
}

impl Default for Pose {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Pose {
    pub const IDENTITY: Pose = Pose { translation: DVec3::ZERO, rotation: DQuat::IDENTITY };

    /// A pose from a position and yaw/pitch/roll in radians (intrinsic z-y-x: yaw about z,
    /// then pitch about the new y, then roll about the new x). Positive pitch tilts +x down,
    /// as aerospace conventions do.
    pub fn from_xyz_ypr(translation: DVec3, yaw: f64, pitch: f64, roll: f64) -> Self {
        Pose { translation, rotation: DQuat::from_euler(EulerRot::ZYX, yaw, pitch, roll) }
    }

    /// Yaw, pitch, roll in radians, inverse of [`Pose::from_xyz_ypr`].
    pub fn yaw_pitch_roll(&self) -> (f64, f64, f64) {
        self.rotation.to_euler(EulerRot::ZYX)
    }

    /// Maps a point from the body frame to the world frame.
    pub fn transform_point(&self, p: DVec3) -> DVec3 {
        self.translation + self.rotation * p
    }

    /// Maps a direction from the body frame to the world frame.
    pub fn transform_vector(&self, v: DVec3) -> DVec3 {
        self.rotation * v
    }

    /// Maps a world point into this body's frame.
    pub fn inverse_transform_point(&self, p: DVec3) -> DVec3 {
        self.rotation.inverse() * (p - self.translation)
    }

    /// The composition `self ∘ other` (apply `other` first).
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose {
            translation: self.transform_point(other.translation),
            rotation: (self.rotation * other.rotation).normalize(),
        }
    }

    /// This pose expressed in a local f32 frame: translation relative to the frame origin
    /// (subtracted in f64 first, then rounded), rotation rounded to f32.
    pub fn to_local(&self, frame: &LocalFrame) -> (Vec3, Quat) {
        (frame.to_local(self.translation), self.rotation.as_quat())
    }
}

/// A local Cartesian frame: the world point `origin` is local (0, 0, 0) and the axes are the
/// world axes. All scene geometry is stored relative to it in f32.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LocalFrame {
    /// World coordinates of the local origin, metres (e.g. UTM easting, northing, altitude).
    pub origin: DVec3,
}

impl LocalFrame {
    pub fn new(origin: DVec3) -> Self {
        Self { origin }
    }

    /// World point to local f32 (the subtraction happens in f64).
    pub fn to_local(&self, world: DVec3) -> Vec3 {
        (world - self.origin).as_vec3()
    }

    /// Local f32 point back to world f64.
    pub fn to_world(&self, local: Vec3) -> DVec3 {
        self.origin + local.as_dvec3()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn ypr_round_trip_and_axes() {
        let p = Pose::from_xyz_ypr(DVec3::new(1.0, 2.0, 3.0), 0.3, -0.2, 0.1);
        let (y, pi, r) = p.yaw_pitch_roll();
        assert!((y - 0.3).abs() < 1e-12 && (pi + 0.2).abs() < 1e-12 && (r - 0.1).abs() < 1e-12);
        // Pure yaw of 90°: body +x points to world +y.
        let q = Pose::from_xyz_ypr(DVec3::ZERO, std::f64::consts::FRAC_PI_2, 0.0, 0.0);
        assert!((q.transform_vector(DVec3::X) - DVec3::Y).length() < 1e-12);
        // Positive pitch tilts +x downwards.
        let d = Pose::from_xyz_ypr(DVec3::ZERO, 0.0, 0.2, 0.0).transform_vector(DVec3::X);
        assert!(d.z < 0.0);
    }

    #[test]
    fn inverse_and_compose() {
        let a = Pose::from_xyz_ypr(DVec3::new(5.0, -1.0, 2.0), 1.0, 0.1, 0.0);
        let b = Pose::from_xyz_ypr(DVec3::new(0.5, 0.5, 0.0), -0.4, 0.0, 0.2);
        let p = DVec3::new(0.3, 0.7, -1.1);
        assert!((a.inverse_transform_point(a.transform_point(p)) - p).length() < 1e-12);
        let ab = a.compose(&b);
        assert!((ab.transform_point(p) - a.transform_point(b.transform_point(p))).length() < 1e-12);
    }

    #[test]
    fn far_from_origin_keeps_millimetres() {
        let frame = LocalFrame::new(DVec3::new(500_000.0, 3_700_000.0, 300.0));
        let world = DVec3::new(500_012.345_6, 3_700_045.678_9, 306.25);
        let local = frame.to_local(world);
        assert!((local.as_dvec3() - DVec3::new(12.3456, 45.6789, 6.25)).length() < 1e-5);
        assert!((frame.to_world(local) - world).length() < 1e-5);
    }
}
