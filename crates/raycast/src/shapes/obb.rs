//! Ray against an oriented (yaw-only) box, in closed form: the ray is moved into the box frame
//! and clipped against its three slabs.

use crate::ray::Ray;
use glam::Vec3;
use hilo_core::Box3;

/// Closest intersection of `ray` with the surface of `b` in `(ray.t_min, t_max)`:
/// `(t, outward world normal)`. A ray starting inside the box hits its exit face, as a ray
/// inside a closed triangle mesh would.
#[inline]
pub fn intersect_box(b: &Box3, ray: &Ray, t_max: f32) -> Option<(f32, Vec3)> {
    let o = b.to_local(ray.origin);
    let h = b.heading();
    let d = Vec3::new(ray.dir.x * h.x + ray.dir.y * h.y, -ray.dir.x * h.y + ray.dir.y * h.x, ray.dir.z);
    let half = b.half_extents().to_array();
    let (o, d) = (o.to_array(), d.to_array());
    let (mut t_near, mut t_far) = (f32::NEG_INFINITY, f32::INFINITY);
    let (mut axis_near, mut axis_far) = (0usize, 0usize);
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k].abs() > half[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[k];
        let (mut t0, mut t1) = ((-half[k] - o[k]) * inv, (half[k] - o[k]) * inv);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        if t0 > t_near {
            t_near = t0;
            axis_near = k;
        }
        if t1 < t_far {
            t_far = t1;
            axis_far = k;
        }
    }
    if t_near > t_far {
        return None;
    }
    let (t, axis) = if t_near > ray.t_min {
        (t_near, axis_near)
    } else if t_far > ray.t_min {
        (t_far, axis_far)
    } else {
        return None;
    };
    if t >= t_max {
        return None;
    }
    let mut n = [0.0f32; 3];
    let p = o[axis] + d[axis] * t;
    n[axis] = if p >= 0.0 { 1.0 } else { -1.0 };
    Some((t, b.local_dir_to_world(Vec3::from(n))))
}
