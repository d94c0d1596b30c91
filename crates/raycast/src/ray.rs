//! Rays and hit records in the scene's local f32 frame.

use glam::Vec3;
use hilo_core::Class;
use serde::{Deserialize, Serialize};

/// A ray `origin + t * dir` for `t` in `(t_min, t_max]`.
///
/// `dir` must be unit length for `t` to be a distance in metres; [`Ray::new`] normalises it.
/// `t_min` keeps a ray that starts on a surface from hitting that surface again: a hit at
/// exactly `t_min` or before is not reported.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    pub t_min: f32,
    pub t_max: f32,
}

impl Ray {
    /// Default `t_min`: 0.1 mm, above f32's rounding of coordinates within a few hundred metres
    /// of the local origin (about 3e-5 m at 300 m).
    pub const DEFAULT_T_MIN: f32 = 1e-4;

    /// A ray with normalised `dir` and range `(DEFAULT_T_MIN, t_max]`.
    pub fn new(origin: Vec3, dir: Vec3, t_max: f32) -> Self {
        Self { origin, dir: dir.normalize(), t_min: Self::DEFAULT_T_MIN, t_max }
    }

    /// The point at distance `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }

    /// True when origin and direction are finite, `dir` is non-zero and the range is ordered.
    pub fn is_valid(&self) -> bool {
        self.origin.is_finite()
            && self.dir.is_finite()
            && self.dir.length_squared() > 0.0
            && self.t_min >= 0.0
            && self.t_min <= self.t_max
    }
}

/// Surface material of static geometry; sets LiDAR reflectivity and radar clutter strength.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Material {
    Asphalt,
    Concrete,
    Grass,
    #[default]
    Building,
    Glass,
    Vegetation,
    Metal,
    /// Vehicle bodies (actors).
    VehicleBody,
    /// Clothing and skin (pedestrian actors).
    Person,
}

impl Material {
    /// Diffuse reflectivity at 905 nm in [0, 1]; typical published values, an assumption.
    pub fn lidar_reflectivity(self) -> f32 {
        match self {
            Material::Asphalt => 0.12,
            Material::Concrete => 0.35,
            Material::Grass => 0.45,
            Material::Building => 0.4,
            Material::Glass => 0.08,
            Material::Vegetation => 0.5,
            Material::Metal => 0.6,
            Material::VehicleBody => 0.5,
            Material::Person => 0.3,
        }
    }
}

/// What a ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HitTarget {
    /// The analytic ground plane.
    Ground,
    /// A triangle of the static scene; `object` indexes the scene's object table and
    /// `triangle` the scene mesh's triangle list.
    Static { object: u32, triangle: u32 },
    /// A moving actor; `index` is its position in the frame's actor list.
    Actor { index: u32, id: u32, class: Class },
}

/// The closest intersection of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray direction, metres.
    pub t: f32,
    pub point: Vec3,
    /// Unit geometric normal, turned to face the incoming ray.
    pub normal: Vec3,
    pub target: HitTarget,
    pub material: Material,
}

impl Hit {
    pub(crate) fn new(ray: &Ray, t: f32, normal: Vec3, target: HitTarget, material: Material) -> Self {
        let normal = if normal.dot(ray.dir) > 0.0 { -normal } else { normal };
        Hit { t, point: ray.at(t), normal, target, material }
    }
}
