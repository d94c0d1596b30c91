//! Rotated bird's-eye-view and 3-D IoU of yaw-only boxes, in f64.
//!
//! Intersection areas come from clipping one box's footprint by the other's four edge lines
//! (Sutherland–Hodgman). A crossing point is only computed between two vertices on opposite
//! sides of a line, as `t = d_p / (d_p − d_q)` with `d_p`, `d_q` of opposite signs, so `t` is
//! always in [0, 1] and near-parallel edges cannot blow it up. Identical boxes give exactly 1;
//! boxes of zero area give 0 (never NaN); IoU is clamped to [0, 1].
//!
//! [`crate::Box3`] (f32, what detectors and simulation carry) converts to [`YawBox`] (f64, what
//! evaluation files carry) without loss; `Box3::bev_iou` and `Box3::iou_3d` are the shortcut.

use crate::Box3;

type P = [f64; 2];

/// A yaw-only box in f64: centre (m), length along the heading, width across it, height (m),
/// yaw (rad, counter-clockwise from +x).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct YawBox {
    pub center: [f64; 3],
    pub length_m: f64,
    pub width_m: f64,
    pub height_m: f64,
    pub yaw: f64,
}

impl From<&Box3> for YawBox {
    fn from(b: &Box3) -> Self {
        YawBox {
            center: [b.center.x as f64, b.center.y as f64, b.center.z as f64],
            length_m: b.length_m as f64,
            width_m: b.width_m as f64,
            height_m: b.height_m as f64,
            yaw: b.yaw as f64,
        }
    }
}

impl YawBox {
    /// Footprint corners, counter-clockwise.
    pub fn footprint(&self) -> [P; 4] {
        let (s, c) = self.yaw.sin_cos();
        let (hl, hw) = (0.5 * self.length_m, 0.5 * self.width_m);
        let (cx, cy) = (self.center[0], self.center[1]);
        let at = |l: f64, w: f64| [cx + l * c - w * s, cy + l * s + w * c];
        [at(hl, hw), at(-hl, hw), at(-hl, -hw), at(hl, -hw)]
    }
}

fn area(poly: &[P]) -> f64 {
    let n = poly.len();
    if n < 3 {
        return 0.0;
    }
    0.5 * (0..n).map(|i| poly[i][0] * poly[(i + 1) % n][1] - poly[(i + 1) % n][0] * poly[i][1]).sum::<f64>()
}

/// Area of the intersection of two convex counter-clockwise polygons.
pub fn convex_intersection_area(subject: &[P], clip: &[P]) -> f64 {
    let mut out: Vec<P> = subject.to_vec();
    let m = clip.len();
    for k in 0..m {
        if out.is_empty() {
            return 0.0;
        }
        let (a, b) = (clip[k], clip[(k + 1) % m]);
        // Signed distance-like value: > 0 left of a→b (inside for a CCW polygon).
        let side = |p: P| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
        let input = std::mem::take(&mut out);
        let n = input.len();
        for i in 0..n {
            let (p, q) = (input[i], input[(i + 1) % n]);
            let (dp, dq) = (side(p), side(q));
            if dp >= 0.0 {
                out.push(p);
            }
            if (dp > 0.0 && dq < 0.0) || (dp < 0.0 && dq > 0.0) {
                let t = dp / (dp - dq);
                out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
            }
        }
    }
    area(&out).max(0.0)
}

/// Rotated bird's-eye-view IoU in [0, 1].
pub fn bev_iou(a: &YawBox, b: &YawBox) -> f64 {
    let (aa, ab) = (a.width_m * a.length_m, b.width_m * b.length_m);
    if aa <= 0.0 || ab <= 0.0 {
        return 0.0;
    }
    if a == b {
        return 1.0;
    }
    let inter = convex_intersection_area(&a.footprint(), &b.footprint());
    (inter / (aa + ab - inter)).clamp(0.0, 1.0)
}

/// 3-D IoU of yaw-only boxes in [0, 1].
pub fn iou_3d(a: &YawBox, b: &YawBox) -> f64 {
    let (va, vb) = (a.width_m * a.length_m * a.height_m, b.width_m * b.length_m * b.height_m);
    if va <= 0.0 || vb <= 0.0 {
        return 0.0;
    }
    if a == b {
        return 1.0;
    }
    let (za0, za1) = (a.center[2] - 0.5 * a.height_m, a.center[2] + 0.5 * a.height_m);
    let (zb0, zb1) = (b.center[2] - 0.5 * b.height_m, b.center[2] + 0.5 * b.height_m);
    let dz = (za1.min(zb1) - za0.max(zb0)).max(0.0);
    let inter = convex_intersection_area(&a.footprint(), &b.footprint()) * dz;
    (inter / (va + vb - inter)).clamp(0.0, 1.0)
}

impl Box3 {
    /// Rotated bird's-eye-view IoU with another box, in [0, 1].
    pub fn bev_iou(&self, other: &Box3) -> f64 {
        bev_iou(&self.into(), &other.into())
    }

    /// 3-D IoU with another box, in [0, 1].
    pub fn iou_3d(&self, other: &Box3) -> f64 {
        iou_3d(&self.into(), &other.into())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn box3_iou_on_closed_forms() {
        let a = Box3::new(Vec3::new(3.0, -2.0, 1.0), 4.0, 2.0, 2.0, 0.7);
        assert_eq!(a.bev_iou(&a), 1.0);
        // A 4 x 2 box against itself turned 90°: the 2 x 2 middle overlaps, 4 / (8 + 8 - 4).
        let b = Box3::new(Vec3::ZERO, 4.0, 2.0, 2.0, 0.0);
        let c = Box3 { yaw: std::f32::consts::FRAC_PI_2, ..b };
        assert!((b.bev_iou(&c) - 1.0 / 3.0).abs() < 1e-6);
        // Heights overlapping by half: 1 / 3 in 3-D.
        let up = Box3 { center: Vec3::new(0.0, 0.0, 1.0), ..b };
        assert!((b.iou_3d(&up) - 1.0 / 3.0).abs() < 1e-6);
        assert_eq!(Box3 { width_m: 0.0, ..b }.bev_iou(&b), 0.0);
    }
}
