//! A vertical capsule (cylinder with hemispherical caps): hilo's pedestrian shape.

use crate::ray::Ray;
use glam::{Vec2, Vec3};

/// Axis from `(center.x, center.y, z0 + r)` to `(center.x, center.y, z1 - r)`, radius `r`:
/// the whole capsule spans `z0..=z1`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Capsule {
    pub center: Vec2,
    pub z0: f32,
    pub z1: f32,
    pub radius: f32,
}

impl Capsule {
    /// Axis-aligned bounds.
    pub fn aabb(&self) -> (Vec3, Vec3) {
        let r = Vec2::splat(self.radius);
        ((self.center - r).extend(self.z0), (self.center + r).extend(self.z1))
    }

    fn axis_ends(&self) -> (f32, f32) {
        let a = self.z0 + self.radius;
        let b = (self.z1 - self.radius).max(a);
        (a, b)
    }

    /// Closest intersection in `(ray.t_min, t_max)`: `(t, outward normal)`. Rays starting
    /// inside hit the surface on the way out.
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<(f32, Vec3)> {
        let (za, zb) = self.axis_ends();
        let mut best: Option<(f32, Vec3)> = None;
        let mut consider = |t: f32, n: Vec3| {
            if t > ray.t_min && t < t_max && best.is_none_or(|(b, _)| t < b) {
                best = Some((t, n));
            }
        };
        // Infinite cylinder, kept where the hit's z lies between the axis ends.
        let oc = ray.origin.truncate() - self.center;
        let d = ray.dir.truncate();
        let a = d.dot(d);
        if a > 0.0 {
            let b = oc.dot(d);
            let c = oc.dot(oc) - self.radius * self.radius;
            // b² − ac cancels catastrophically for a small capsule far away; the same value from
            // the perpendicular offset f does not (Haines et al., Ray Tracing Gems, ch. 7).
            let f = oc - d * (b / a);
            let disc = a * (self.radius * self.radius - f.dot(f));
            if disc >= 0.0 {
                let s = disc.sqrt();
                // Numerically stable pair of roots.
                let q = -(b + s.copysign(b));
                let roots = if q != 0.0 { [q / a, c / q] } else { [-b / a, -b / a] };
                for t in roots {
                    let p = ray.at(t);
                    if p.z >= za && p.z <= zb {
                        consider(t, ((p.truncate() - self.center) / self.radius).extend(0.0));
                    }
                }
            }
        }
        // Hemispherical caps: spheres at both axis ends, kept on their outer halves.
        for (zc, upper) in [(za, false), (zb, true)] {
            let c3 = self.center.extend(zc);
            let oc = ray.origin - c3;
            let b = oc.dot(ray.dir);
            let c = oc.dot(oc) - self.radius * self.radius;
            let f = oc - ray.dir * b;
            let disc = self.radius * self.radius - f.dot(f);
            if disc < 0.0 {
                continue;
            }
            let s = disc.sqrt();
            let q = -(b + s.copysign(b));
            let roots = if q != 0.0 { [q, c / q] } else { [-b, -b] };
            for t in roots {
                let p = ray.at(t);
                if (upper && p.z >= zb) || (!upper && p.z <= za) {
                    consider(t, (p - c3) / self.radius);
                }
            }
        }
        best
    }
}
