use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// What is wrong with a box as nuScenes stores it (centre `translation`, `size` as width,
/// length, height, `rotation` as a w x y z quaternion): the field, its value and why. The ground
/// truth's reader and the metric's submission reader both check boxes with it.
pub fn nuscenes_box_defect(
    translation: &[f64; 3],
    size: &[f64; 3],
    rotation: &[f64; 4],
) -> Option<(&'static str, String, &'static str)> {
    if translation.iter().any(|v| !v.is_finite()) {
        return Some(("translation", format!("{translation:?}"), "must be finite"));
    }
    if size.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Some(("size", format!("{size:?}"), "must be finite and > 0"));
    }
    if rotation.iter().any(|v| !v.is_finite()) || rotation.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
        return Some(("rotation", format!("{rotation:?}"), "must be a finite, non-zero quaternion"));
    }
    None
}

/// An oriented 3-D box: yaw-only rotation about z, as road-user annotations are.
///
/// `center` is the geometric centre (not the bottom centre); `length_m` runs along the heading
/// (local +x), `width_m` across it (local +y), `height_m` along z. `yaw` is in radians,
/// counter-clockwise from +x.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Box3 {
    pub center: Vec3,
    pub length_m: f32,
    pub width_m: f32,
    pub height_m: f32,
    pub yaw: f32,
}

impl Box3 {
    pub fn new(center: Vec3, length_m: f32, width_m: f32, height_m: f32, yaw: f32) -> Self {
        Self { center, length_m, width_m, height_m, yaw }
    }

    /// Half extents along the box's own axes.
    pub fn half_extents(&self) -> Vec3 {
        Vec3::new(self.length_m, self.width_m, self.height_m) * 0.5
    }

    /// Unit heading in the xy plane.
    pub fn heading(&self) -> Vec2 {
        Vec2::from_angle(self.yaw)
    }

    /// True when every field is finite and no size is negative.
    pub fn is_valid(&self) -> bool {
        self.center.is_finite()
            && self.yaw.is_finite()
            && [self.length_m, self.width_m, self.height_m].iter().all(|s| s.is_finite() && *s >= 0.0)
    }

    /// World point to the box's local frame (origin at the centre, x along the heading).
    pub fn to_local(&self, p: Vec3) -> Vec3 {
        let d = p - self.center;
        let h = self.heading();
        Vec3::new(d.x * h.x + d.y * h.y, -d.x * h.y + d.y * h.x, d.z)
    }

    /// Local direction back to the world frame.
    pub fn local_dir_to_world(&self, v: Vec3) -> Vec3 {
        let h = self.heading();
        Vec3::new(v.x * h.x - v.y * h.y, v.x * h.y + v.y * h.x, v.z)
    }

    /// True when `p` lies inside or on the box.
    pub fn contains(&self, p: Vec3) -> bool {
        let l = self.to_local(p).abs();
        let h = self.half_extents();
        l.x <= h.x && l.y <= h.y && l.z <= h.z
    }

    /// The four bird's-eye-view corners, counter-clockwise starting front-left.
    pub fn bev_corners(&self) -> [Vec2; 4] {
        let h = self.half_extents();
        let f = self.heading() * h.x;
        let l = self.heading().perp() * h.y;
        let c = self.center.truncate();
        [c + f + l, c - f + l, c - f - l, c + f - l]
    }

    /// The eight corners: the BEV corners at the bottom, then at the top.
    pub fn corners(&self) -> [Vec3; 8] {
        let b = self.bev_corners();
        let z0 = self.center.z - self.height_m * 0.5;
        let z1 = self.center.z + self.height_m * 0.5;
        [
            b[0].extend(z0),
            b[1].extend(z0),
            b[2].extend(z0),
            b[3].extend(z0),
            b[0].extend(z1),
            b[1].extend(z1),
            b[2].extend(z1),
            b[3].extend(z1),
        ]
    }

    /// Axis-aligned bounds `(min, max)` of the box.
    pub fn aabb(&self) -> (Vec3, Vec3) {
        let cs = self.corners();
        let mut lo = cs[0];
        let mut hi = cs[0];
        for c in &cs[1..] {
            lo = lo.min(*c);
            hi = hi.max(*c);
        }
        (lo, hi)
    }

    pub fn volume(&self) -> f32 {
        self.length_m * self.width_m * self.height_m
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn corners_of_a_rotated_box() {
        let b = Box3::new(Vec3::new(1.0, 2.0, 1.0), 4.0, 2.0, 2.0, std::f32::consts::FRAC_PI_2);
        // Heading +y: front-left corner is at +y (front) and -x (left of +y).
        let c = b.bev_corners();
        assert!((c[0] - Vec2::new(0.0, 4.0)).length() < 1e-5);
        let (lo, hi) = b.aabb();
        assert!((lo - Vec3::new(0.0, 0.0, 0.0)).length() < 1e-5);
        assert!((hi - Vec3::new(2.0, 4.0, 2.0)).length() < 1e-5);
        assert_eq!(b.volume(), 16.0);
    }

    proptest! {
        #[test]
        fn corners_are_contained_and_local_round_trips(
            cx in -100.0f32..100.0, cy in -100.0f32..100.0, yaw in -7.0f32..7.0,
            l in 0.1f32..20.0, w in 0.1f32..5.0, h in 0.1f32..5.0,
        ) {
            let b = Box3::new(Vec3::new(cx, cy, h / 2.0), l, w, h, yaw);
            for c in b.corners() {
                // Shrink slightly towards the centre: a corner lies on the boundary.
                prop_assert!(b.contains(b.center + (c - b.center) * 0.999));
                prop_assert!(!b.contains(b.center + (c - b.center) * 1.01));
            }
            let v = Vec3::new(0.3, -0.4, 0.5);
            let back = b.local_dir_to_world(b.to_local(b.center + v));
            prop_assert!((back - v).length() < 1e-3);
        }
    }
}
