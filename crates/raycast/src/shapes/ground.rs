//! The ground as an analytic horizontal rectangle.
//!
//! Most LiDAR rays from a pole end on the ground. Intersecting it in closed form first gives
//! every ray a short `t_max` before the BVH is entered, so the traversal skips everything
//! behind the ground hit; a tessellated ground would instead put large, overlapping boxes at
//! the top of the BVH.

use crate::ray::Ray;
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// The plane `z = z_m` bounded by `min..=max` in x and y (local frame).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroundPlane {
    pub z_m: f32,
    pub min: Vec2,
    pub max: Vec2,
}

impl GroundPlane {
    /// Distance to the ground if it is hit in `(ray.t_min, t_max)`. A ray lying in the plane
    /// (dir.z = 0) does not hit it.
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<f32> {
        if ray.dir.z == 0.0 {
            return None;
        }
        let t = (self.z_m - ray.origin.z) / ray.dir.z;
        if !(t > ray.t_min && t < t_max) {
            return None;
        }
        let p = ray.origin.truncate() + ray.dir.truncate() * t;
        (p.x >= self.min.x && p.x <= self.max.x && p.y >= self.min.y && p.y <= self.max.y).then_some(t)
    }

    /// The upward normal.
    pub fn normal(&self) -> Vec3 {
        Vec3::Z
    }
}
