//! Oriented rectangles in the ground plane and their separating-axis overlap test.

use glam::Vec2;

/// A rectangle: centre, unit heading, half length (along the heading) and half width.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    pub center: Vec2,
    pub dir: Vec2,
    pub half_l: f32,
    pub half_w: f32,
}

impl Rect {
    pub fn corners(&self) -> [Vec2; 4] {
        let (a, b) = (self.dir * self.half_l, self.dir.perp() * self.half_w);
        [self.center + a + b, self.center - a + b, self.center - a - b, self.center + a - b]
    }

    /// Radius of the circumscribed circle.
    pub fn radius(&self) -> f32 {
        (self.half_l * self.half_l + self.half_w * self.half_w).sqrt()
    }

    /// Half the extent of the rectangle projected on unit axis `n`.
    fn half_extent(&self, n: Vec2) -> f32 {
        self.half_l * self.dir.dot(n).abs() + self.half_w * self.dir.perp().dot(n).abs()
    }

    /// Whether the interiors overlap (touching edges do not count).
    pub fn overlaps(&self, o: &Rect) -> bool {
        let d = o.center - self.center;
        for n in [self.dir, self.dir.perp(), o.dir, o.dir.perp()] {
            if d.dot(n).abs() >= self.half_extent(n) + o.half_extent(n) {
                return false;
            }
        }
        true
    }

    /// Whether the interiors of the rectangle and a convex polygon (either winding) overlap:
    /// the separating-axis test over the rectangle's axes and the polygon's edge normals.
    pub fn overlaps_convex(&self, poly: &[Vec2]) -> bool {
        if poly.len() < 3 {
            return false;
        }
        let edges = (0..poly.len()).map(|k| (poly[(k + 1) % poly.len()] - poly[k]).perp());
        for n in [self.dir, self.dir.perp()].into_iter().chain(edges) {
            if n.length_squared() == 0.0 {
                continue;
            }
            let c = self.center.dot(n);
            let (lo, hi) = (c - self.half_extent(n), c + self.half_extent(n));
            let (plo, phi) = poly.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), q| {
                let x = q.dot(n);
                (a.min(x), b.max(x))
            });
            if phi <= lo || plo >= hi {
                return false;
            }
        }
        true
    }
}

/// Distance from `p` to the segment `a`–`b` (the scene's own, which the importer also uses).
pub use hilo_raycast::scene::layout::point_segment_distance;

#[cfg(test)]
mod tests {
    use super::*;

    fn r(x: f32, y: f32, yaw: f32, l: f32, w: f32) -> Rect {
        Rect { center: Vec2::new(x, y), dir: Vec2::from_angle(yaw), half_l: l / 2.0, half_w: w / 2.0 }
    }

    /// Whether any of a dense grid of points inside `b` (just within its edges) passes `test`.
    fn any_sample(b: &Rect, test: impl Fn(Vec2) -> bool) -> bool {
        (0..=60).any(|i| {
            (0..=60).any(|j| {
                test(
                    b.center
                        + b.dir * (b.half_l * (i as f32 / 30.0 - 1.0) * 0.999)
                        + b.dir.perp() * (b.half_w * (j as f32 / 30.0 - 1.0) * 0.999),
                )
            })
        })
    }

    #[test]
    fn overlap_matches_a_dense_point_oracle() {
        // Brute force: sample points of one rectangle and test containment in the other.
        let inside = |q: &Rect, p: Vec2| {
            let d = p - q.center;
            d.dot(q.dir).abs() < q.half_l && d.dot(q.dir.perp()).abs() < q.half_w
        };
        let a = r(0.0, 0.0, 0.3, 4.0, 2.0);
        for (x, y, yaw) in
            [(3.0, 0.5, 1.2), (4.5, 0.0, 0.0), (0.0, 2.2, 0.3), (2.6, 2.0, -0.7), (0.5, 0.5, 2.0), (5.0, 3.0, 0.9)]
        {
            let b = r(x, y, yaw, 3.0, 1.5);
            assert_eq!(a.overlaps(&b), any_sample(&b, |p| inside(&a, p)), "b at ({x}, {y}, {yaw})");
        }
    }

    #[test]
    fn overlap_with_a_convex_polygon_matches_a_dense_point_oracle() {
        // A skewed quadrilateral (a crosswalk of an oblique arm) in both windings.
        let quad = [Vec2::new(0.0, 0.0), Vec2::new(4.0, 0.0), Vec2::new(6.0, 9.0), Vec2::new(2.0, 9.0)];
        let in_quad = |p: Vec2| {
            (0..4).all(|k| {
                let (a, b) = (quad[k], quad[(k + 1) % 4]);
                (b - a).perp_dot(p - a) > 0.0
            })
        };
        let mut reversed = quad;
        reversed.reverse();
        for (x, y, yaw) in [
            (-1.5, 4.0, 0.2),
            (-2.2, 4.0, 0.0),
            (3.0, -1.2, 0.0),
            (3.0, -0.6, 0.4),
            (7.5, 8.0, 1.1),
            (6.9, 4.0, 1.35),
            (3.0, 4.0, 2.5),
            (-1.0, -1.0, 0.78),
        ] {
            let b = r(x, y, yaw, 3.0, 1.5);
            let any = any_sample(&b, in_quad);
            assert_eq!(b.overlaps_convex(&quad), any, "rectangle at ({x}, {y}, {yaw})");
            assert_eq!(b.overlaps_convex(&reversed), any, "reversed, rectangle at ({x}, {y}, {yaw})");
        }
        assert!(!r(0.0, 0.0, 0.0, 2.0, 2.0).overlaps_convex(&quad[..2]));
    }

    #[test]
    fn touching_rectangles_do_not_overlap() {
        assert!(!r(0.0, 0.0, 0.0, 2.0, 2.0).overlaps(&r(2.0, 0.0, 0.0, 2.0, 2.0)));
        assert!(r(0.0, 0.0, 0.0, 2.0, 2.0).overlaps(&r(1.99, 0.0, 0.0, 2.0, 2.0)));
    }
}
