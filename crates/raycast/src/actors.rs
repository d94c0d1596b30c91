//! Moving actors as analytic shapes, gathered per frame into a small BVH over their bounds.
//!
//! A frame holds tens to a few hundred actors; rebuilding a BVH over their boxes costs
//! microseconds, far less than re-triangulating and refitting meshes would, and the analytic
//! tests are exact.

use crate::bvh::BoxBvh;
use crate::error::RaycastError;
use crate::ray::{Hit, HitTarget, Material, Ray};
use crate::shapes::{Capsule, intersect_box};
use glam::Vec3;
use hilo_core::{Box3, Class};

/// The shape an actor presents to rays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ActorShape {
    /// An oriented box (vehicles, and pedestrians when boxes are preferred).
    Box(Box3),
    /// A vertical capsule (pedestrians).
    Capsule(Capsule),
    /// A cyclist in its annotated box: the bicycle as a slab as long as the box, as wide as a
    /// tyre and as high as the wheels, and the rider as an upright capsule from the pedals to
    /// the top of the box ([`ActorShape::cyclist_parts`]). The slab is solid where a wheel's
    /// spokes let most beams through, so a side view returns more points than a real bicycle.
    Cyclist(Box3),
}

/// A bicycle's wheel height and tyre width, m, and its rider's lowest point (the pedals) above
/// the ground and half-width.
const WHEEL_M: f32 = 0.7;
const TYRE_M: f32 = 0.06;
const PEDALS_M: f32 = 0.3;
const RIDER_RADIUS_M: f32 = 0.2;

impl ActorShape {
    /// A pedestrian-like capsule inscribed in `b` (radius = half the smaller planar size).
    pub fn capsule_in(b: &Box3) -> Self {
        let r = 0.5 * b.length_m.min(b.width_m);
        ActorShape::Capsule(Capsule {
            center: b.center.truncate(),
            z0: b.center.z - 0.5 * b.height_m,
            z1: b.center.z + 0.5 * b.height_m,
            radius: r,
        })
    }

    /// A cyclist's bicycle and rider in its annotated box `b` (see [`ActorShape::Cyclist`]);
    /// each part stays inside `b`.
    pub fn cyclist_parts(b: &Box3) -> (Box3, Capsule) {
        let ground = b.center.z - 0.5 * b.height_m;
        let wheels = WHEEL_M.min(b.height_m);
        let bicycle = Box3::new(
            b.center.truncate().extend(ground + 0.5 * wheels),
            b.length_m,
            TYRE_M.min(b.width_m),
            wheels,
            b.yaw,
        );
        let radius = RIDER_RADIUS_M.min(0.5 * b.width_m).min(0.5 * b.length_m);
        let top = ground + b.height_m;
        let rider = Capsule { center: b.center.truncate(), z0: (ground + PEDALS_M).min(top), z1: top, radius };
        (bicycle, rider)
    }

    pub fn aabb(&self) -> (Vec3, Vec3) {
        match self {
            ActorShape::Box(b) | ActorShape::Cyclist(b) => b.aabb(),
            ActorShape::Capsule(c) => c.aabb(),
        }
    }

    fn intersect(&self, ray: &Ray, t_max: f32) -> Option<(f32, Vec3)> {
        match self {
            ActorShape::Box(b) => intersect_box(b, ray, t_max),
            ActorShape::Capsule(c) => c.intersect(ray, t_max),
            ActorShape::Cyclist(b) => {
                let (bicycle, rider) = Self::cyclist_parts(b);
                let frame = intersect_box(&bicycle, ray, t_max);
                let body = rider.intersect(ray, frame.map_or(t_max, |h| h.0));
                body.or(frame)
            }
        }
    }

    /// The box a road user is annotated with: its box, or a capsule's bounding box.
    pub fn outline(&self) -> Box3 {
        match *self {
            ActorShape::Box(b) | ActorShape::Cyclist(b) => b,
            ActorShape::Capsule(c) => {
                Box3::new(c.center.extend(0.5 * (c.z0 + c.z1)), 2.0 * c.radius, 2.0 * c.radius, c.z1 - c.z0, 0.0)
            }
        }
    }
}

/// One moving road user in a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Actor {
    /// Stable id across frames (the instance).
    pub id: u32,
    pub class: Class,
    pub shape: ActorShape,
    /// Velocity in the local frame, m/s (radar Doppler reads it; rays do not).
    pub velocity_mps: Vec3,
    /// Diffuse reflectivity at a LiDAR's wavelength, [0, 1]: its material's by default
    /// ([`Material::lidar_reflectivity`]), or its own paint's.
    pub reflectivity: f32,
}

impl Actor {
    /// The shape hilo uses for a class: capsules for pedestrians, a bicycle and rider for
    /// cyclists, boxes otherwise.
    pub fn from_box(id: u32, class: Class, b: Box3) -> Self {
        let shape = match class {
            Class::Pedestrian => ActorShape::capsule_in(&b),
            Class::Bicycle => ActorShape::Cyclist(b),
            _ => ActorShape::Box(b),
        };
        let mut a = Actor { id, class, shape, velocity_mps: Vec3::ZERO, reflectivity: 0.0 };
        a.reflectivity = a.material().lidar_reflectivity();
        a
    }

    /// The same actor with its own LiDAR reflectivity (a paint), clamped to [0, 1].
    pub fn with_reflectivity(mut self, r: f32) -> Self {
        self.reflectivity = r.clamp(0.0, 1.0);
        self
    }

    /// The same actor moving at `v` (local frame, m/s).
    pub fn with_velocity(mut self, v: Vec3) -> Self {
        self.velocity_mps = v;
        self
    }

    /// The same actor `dt` seconds later: its shape moved by velocity × dt.
    pub fn moved(&self, dt: f32) -> Self {
        let d = self.velocity_mps * dt;
        let shape = match self.shape {
            ActorShape::Box(b) => ActorShape::Box(Box3 { center: b.center + d, ..b }),
            ActorShape::Cyclist(b) => ActorShape::Cyclist(Box3 { center: b.center + d, ..b }),
            ActorShape::Capsule(c) => {
                ActorShape::Capsule(Capsule { center: c.center + d.truncate(), z0: c.z0 + d.z, z1: c.z1 + d.z, ..c })
            }
        };
        Actor { shape, ..*self }
    }

    /// Contains `p` (inside or on the surface).
    pub fn contains(&self, p: Vec3) -> bool {
        match &self.shape {
            ActorShape::Box(b) => b.contains(p),
            ActorShape::Capsule(c) => capsule_contains(c, p),
            ActorShape::Cyclist(b) => {
                let (bicycle, rider) = ActorShape::cyclist_parts(b);
                bicycle.contains(p) || capsule_contains(&rider, p)
            }
        }
    }

    /// What rays meet: a person for pedestrians and cyclists (the rider is most of what a
    /// cyclist shows), a vehicle's body otherwise.
    pub fn material(&self) -> Material {
        if matches!(self.class, Class::Pedestrian | Class::Bicycle) { Material::Person } else { Material::VehicleBody }
    }
}

fn capsule_contains(c: &Capsule, p: Vec3) -> bool {
    let (za, zb) = (c.z0 + c.radius, (c.z1 - c.radius).max(c.z0 + c.radius));
    let z = p.z.clamp(za, zb);
    (p - c.center.extend(z)).length() <= c.radius
}

/// The actors of one frame and a BVH over their bounds. Built with [`ActorSet::moving`], the
/// actors move at their velocities for a span of time after the frame's instant (a spinning
/// LiDAR's rotation): [`ActorSet::closest_at`] meets each where it is at a given time.
#[derive(Clone, Debug, Default)]
pub struct ActorSet {
    actors: Vec<Actor>,
    bvh: BoxBvh,
    /// The span of time after the frame's instant the bounds cover, s (0: the instant only).
    span_s: f32,
}

impl ActorSet {
    /// Builds the per-frame structure. Shapes with non-finite or negative sizes are rejected.
    pub fn new(actors: Vec<Actor>) -> Result<Self, RaycastError> {
        Self::moving(actors, 0.0)
    }

    /// The actors at the frame's instant and for `span_s` seconds after it, each moving at its
    /// velocity: the BVH holds each actor's bounds swept over the span.
    pub fn moving(actors: Vec<Actor>, span_s: f32) -> Result<Self, RaycastError> {
        if !(span_s.is_finite() && span_s >= 0.0) {
            return Err(RaycastError::Geometry(format!("a span of time must be finite and >= 0 s, not {span_s}")));
        }
        let mut bounds = Vec::with_capacity(actors.len());
        for (i, a) in actors.iter().enumerate() {
            let ok = match a.shape {
                ActorShape::Box(b) | ActorShape::Cyclist(b) => b.is_valid(),
                ActorShape::Capsule(c) => {
                    c.center.is_finite() && c.z0.is_finite() && c.z1 >= c.z0 && c.radius.is_finite() && c.radius >= 0.0
                }
            };
            if !ok {
                return Err(RaycastError::Geometry(format!(
                    "actor {i} (id {}) has an invalid shape: {:?}",
                    a.id, a.shape
                )));
            }
            if !a.velocity_mps.is_finite() {
                return Err(RaycastError::Geometry(format!("actor {i} (id {}) has a non-finite velocity", a.id)));
            }
            if !(0.0..=1.0).contains(&a.reflectivity) {
                return Err(RaycastError::Geometry(format!(
                    "actor {i} (id {}) has reflectivity {}, not in [0, 1]",
                    a.id, a.reflectivity
                )));
            }
            let (lo, hi) = a.shape.aabb();
            let d = a.velocity_mps * span_s;
            bounds.push((lo.min(lo + d), hi.max(hi + d)));
        }
        Ok(ActorSet { bvh: BoxBvh::build(&bounds)?, actors, span_s })
    }

    /// The span of time after the frame's instant the actors move for (0: a still frame).
    pub fn span_s(&self) -> f32 {
        self.span_s
    }

    pub fn actors(&self) -> &[Actor] {
        &self.actors
    }

    pub fn len(&self) -> usize {
        self.actors.len()
    }

    pub fn is_empty(&self) -> bool {
        self.actors.is_empty()
    }

    /// Closest actor hit in `(ray.t_min, t_max)`.
    pub fn closest(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        self.closest_at(ray, t_max, 0.0)
    }

    /// Closest actor hit in `(ray.t_min, t_max)` with every actor where it is `dt` seconds
    /// after the frame's instant (its shape moved by velocity × dt); `dt` is clamped to the
    /// set's span. Meeting a shape moved by d is meeting the shape with the ray moved by −d.
    pub fn closest_at(&self, ray: &Ray, t_max: f32, dt: f32) -> Option<Hit> {
        if self.actors.is_empty() {
            return None;
        }
        let dt = dt.clamp(0.0, self.span_s);
        let mut best: Option<(f32, Vec3, u32)> = None;
        let mut limit = t_max;
        self.bvh.traverse(ray, &mut limit, |i, t_max| {
            let a = &self.actors[i as usize];
            let hit = if dt == 0.0 {
                a.shape.intersect(ray, *t_max)
            } else {
                a.shape.intersect(&Ray { origin: ray.origin - a.velocity_mps * dt, ..*ray }, *t_max)
            };
            if let Some((t, n)) = hit {
                *t_max = t;
                best = Some((t, n, i));
            }
            false
        });
        best.map(|(t, n, i)| {
            let a = &self.actors[i as usize];
            Hit::new(ray, t, n, HitTarget::Actor { index: i, id: a.id, class: a.class }, a.material())
        })
    }

    /// True when any actor is hit in `(ray.t_min, t_max)`.
    pub fn any(&self, ray: &Ray, t_max: f32) -> bool {
        let mut found = false;
        let mut limit = t_max;
        self.bvh.traverse(ray, &mut limit, |i, t_max| {
            found = self.actors[i as usize].shape.intersect(ray, *t_max).is_some();
            found
        });
        found
    }
}
