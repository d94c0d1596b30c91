//! Watertight ray–triangle intersection (Woop, Benthin and Wald, "Watertight Ray/Triangle
//! Intersection", JCGT 2013).
//!
//! The ray is sheared so that it runs along +z from the origin; each triangle is then tested
//! in 2-D with edge functions U, V, W. Two triangles sharing an edge evaluate the edge function
//! on the same two transformed vertices, so a ray through the edge or a shared vertex hits at
//! least one of them: no leaks. Edge functions that come out exactly zero in f32 are recomputed
//! in f64 so that the sign decision is made on an exact (or far more precise) value.

use crate::ray::Ray;
use glam::Vec3;

/// A ray prepared for watertight triangle tests: the dominant axis and shear computed once.
///
/// Woop et al. swap the two minor axes when the ray points down its dominant axis, to keep
/// the winding for back-face culling; hilo counts both faces, and a swap only flips the signs
/// of U, V, W and the determinant together, so it is left out.
#[derive(Clone, Copy, Debug)]
pub struct ShearedRay {
    pub(crate) origin: Vec3,
    /// Dominant axis of the direction (0 = x, 1 = y, 2 = z).
    pub(crate) kz: usize,
    sx: f32,
    sy: f32,
    sz: f32,
    pub(crate) t_min: f32,
}

impl ShearedRay {
    pub fn new(ray: &Ray) -> Self {
        let d = ray.dir.to_array();
        let a = ray.dir.abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let (kx, ky) = ((kz + 1) % 3, (kz + 2) % 3);
        ShearedRay { origin: ray.origin, kz, sx: d[kx] / d[kz], sy: d[ky] / d[kz], sz: 1.0 / d[kz], t_min: ray.t_min }
    }

    /// Distance to the triangle `(v0, v1, v2)` if it is hit in `(t_min, t_max)`, else `None`.
    /// Both faces count (no back-face culling).
    #[inline(always)]
    pub fn intersect(&self, v0: Vec3, v1: Vec3, v2: Vec3, t_max: f32) -> Option<f32> {
        match self.kz {
            0 => self.intersect_axis::<0>(v0, v1, v2, t_max),
            1 => self.intersect_axis::<1>(v0, v1, v2, t_max),
            _ => self.intersect_axis::<2>(v0, v1, v2, t_max),
        }
    }

    /// The test with the dominant axis `KZ` known at compile time (callers that test many
    /// triangles against one ray dispatch once and call this in the loop).
    #[inline(always)]
    pub fn intersect_axis<const KZ: usize>(&self, v0: Vec3, v1: Vec3, v2: Vec3, t_max: f32) -> Option<f32> {
        let pick = |v: Vec3| -> (f32, f32, f32) {
            match KZ {
                0 => (v.y, v.z, v.x),
                1 => (v.z, v.x, v.y),
                _ => (v.x, v.y, v.z),
            }
        };
        let (a0, a1, a2) = pick(v0 - self.origin);
        let (b0, b1, b2) = pick(v1 - self.origin);
        let (c0, c1, c2) = pick(v2 - self.origin);
        let ax = a0 - self.sx * a2;
        let ay = a1 - self.sy * a2;
        let bx = b0 - self.sx * b2;
        let by = b1 - self.sy * b2;
        let cx = c0 - self.sx * c2;
        let cy = c1 - self.sy * c2;
        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        if u == 0.0 || v == 0.0 || w == 0.0 {
            let (ax, ay, bx, by, cx, cy) = (ax as f64, ay as f64, bx as f64, by as f64, cx as f64, cy as f64);
            u = (cx * by - cy * bx) as f32;
            v = (ax * cy - ay * cx) as f32;
            w = (bx * ay - by * ax) as f32;
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let t_scaled = (u * a2 + v * b2 + w * c2) * self.sz;
        // Compare t = t_scaled / det against the range without dividing: flip signs by det's.
        let (t_scaled, det_abs) = if det < 0.0 { (-t_scaled, -det) } else { (t_scaled, det) };
        if t_scaled <= self.t_min * det_abs || t_scaled >= t_max * det_abs {
            return None;
        }
        Some(t_scaled / det_abs)
    }
}

/// Unit normal of a triangle by the right-hand rule (zero for a degenerate triangle).
pub fn triangle_normal(v0: Vec3, v1: Vec3, v2: Vec3) -> Vec3 {
    (v1 - v0).cross(v2 - v0).normalize_or_zero()
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    fn ray(o: [f32; 3], d: [f32; 3]) -> ShearedRay {
        ShearedRay::new(&Ray { origin: Vec3::from(o), dir: Vec3::from(d).normalize(), t_min: 0.0, t_max: f32::MAX })
    }

    #[test]
    fn hits_the_interior_from_both_sides() {
        let (a, b, c) = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0));
        let t = ray([0.25, 0.25, 2.0], [0.0, 0.0, -1.0]).intersect(a, b, c, f32::MAX);
        assert_eq!(t, Some(2.0));
        let t = ray([0.25, 0.25, -3.0], [0.0, 0.0, 1.0]).intersect(a, b, c, f32::MAX);
        assert_eq!(t, Some(3.0));
        assert_eq!(ray([2.0, 2.0, 2.0], [0.0, 0.0, -1.0]).intersect(a, b, c, f32::MAX), None);
    }

    #[test]
    fn respects_the_range_and_degenerate_triangles() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        assert_eq!(ray([0.2, 0.2, 2.0], [0.0, 0.0, -1.0]).intersect(a, b, c, 1.5), None);
        assert_eq!(ray([0.2, 0.2, 2.0], [0.0, 0.0, 1.0]).intersect(a, b, c, 10.0), None);
        // Degenerate (collinear) triangle: never a hit, never NaN.
        assert_eq!(ray([0.5, 0.0, 2.0], [0.0, 0.0, -1.0]).intersect(a, b, b * 2.0, 10.0), None);
        // Ray in the triangle's plane: det = 0, no hit.
        assert_eq!(ray([-1.0, 0.2, 0.0], [1.0, 0.0, 0.0]).intersect(a, b, c, 10.0), None);
    }

    #[test]
    fn shared_edge_and_vertex_of_a_quad_hit_exactly_once_or_twice_never_zero() {
        // Two triangles of a unit square sharing the diagonal (0,0)-(1,1).
        let q =
            [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)];
        // Interior points of the shared diagonal (its ends are the quad's outer corners).
        for i in 1..100 {
            let s = i as f32 / 100.0;
            for dir in [[0.0, 0.0, -1.0], [0.3, -0.2, -1.0], [-0.7, 0.1, -0.4]] {
                let d = Vec3::from(dir).normalize();
                let target = Vec3::new(s, s, 0.0);
                let r = ray((target - d * 3.0).to_array(), d.to_array());
                let h1 = r.intersect(q[0], q[1], q[2], f32::MAX).is_some();
                let h2 = r.intersect(q[0], q[2], q[3], f32::MAX).is_some();
                assert!(h1 || h2, "leak at diagonal point {s} dir {dir:?}");
            }
        }
    }
}
