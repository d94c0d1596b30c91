//! Closed-form checks: plane, oriented box, capsule and triangle-mesh box hits to 1e-5 m.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::{Vec2, Vec3};
use hilo_core::{Box3, Class};
use hilo_raycast::shapes::{Capsule, GroundPlane, intersect_box};
use hilo_raycast::{Actor, ActorSet, ActorShape, HitTarget, Ray, TriangleMesh, World};
use proptest::prelude::*;

const TOL: f32 = 1e-5;

fn ground() -> GroundPlane {
    GroundPlane { z_m: 0.25, min: Vec2::splat(-200.0), max: Vec2::splat(200.0) }
}

proptest! {
    #[test]
    fn plane_hit_is_height_over_sine(h in 0.5f32..30.0, el_deg in 1.0f32..89.0, az in 0.0f32..std::f32::consts::TAU, x in -50.0f32..50.0) {
        let el = el_deg.to_radians();
        let dir = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin());
        let ray = Ray::new(Vec3::new(x, 3.0, 0.25 + h), dir, 1e4);
        let t = ground().intersect(&ray, ray.t_max);
        let expected = h / el.sin();
        if ray.at(expected).truncate().abs().max_element() <= 200.0 {
            let t = t.unwrap();
            prop_assert!((t - expected).abs() <= TOL * expected.max(1.0), "{t} vs {expected}");
        }
    }

    #[test]
    fn box_hit_along_its_axis_is_distance_minus_half_length(
        cx in -80.0f32..80.0, cy in -80.0f32..80.0, yaw in -3.2f32..3.2,
        l in 0.5f32..12.0, w in 0.5f32..3.0, hgt in 0.5f32..4.0,
        dist in 15.0f32..60.0, ly in -0.49f32..0.49, lz in -0.49f32..0.49,
    ) {
        let b = Box3::new(Vec3::new(cx, cy, hgt / 2.0), l, w, hgt, yaw);
        // Start on the box's local +x axis (offset across it), aim back along -x.
        let local = Vec3::new(dist, ly * w, lz * hgt);
        let origin = b.center + b.local_dir_to_world(local);
        let dir = b.local_dir_to_world(Vec3::NEG_X);
        let ray = Ray::new(origin, dir, 1e3);
        let (t, n) = intersect_box(&b, &ray, ray.t_max).unwrap();
        prop_assert!((t - (dist - l / 2.0)).abs() <= TOL * dist, "{t}");
        prop_assert!((n - b.local_dir_to_world(Vec3::X)).length() < 1e-5);
        // Through the actor set, the same answer.
        let set = ActorSet::new(vec![Actor { id: 9, class: Class::Car, shape: ActorShape::Box(b), velocity_mps: Vec3::ZERO, reflectivity: 0.5 }]).unwrap();
        let h = set.closest(&ray, ray.t_max).unwrap();
        prop_assert!((h.t - t).abs() <= 1e-6);
        let is_car9 = matches!(h.target, HitTarget::Actor { id: 9, class: Class::Car, .. });
        prop_assert!(is_car9);
    }

    #[test]
    fn capsule_side_and_cap_hits(
        cx in -50.0f32..50.0, cy in -50.0f32..50.0, r in 0.2f32..0.6, height in 1.4f32..2.0,
        dist in 3.0f32..40.0, az in 0.0f32..std::f32::consts::TAU, frac in 0.0f32..1.0, off in 0.0f32..0.95,
    ) {
        let c = Capsule { center: Vec2::new(cx, cy), z0: 0.0, z1: height, radius: r };
        // Horizontal ray at a height on the cylindrical part, aimed at the axis.
        let z = r + frac * (height - 2.0 * r);
        let d = Vec2::from_angle(az);
        let ray = Ray::new((c.center + d * dist).extend(z), (-d).extend(0.0), 1e3);
        let (t, n) = c.intersect(&ray, ray.t_max).unwrap();
        prop_assert!((t - (dist - r)).abs() <= TOL * dist, "side {t} vs {}", dist - r);
        prop_assert!((n - d.extend(0.0)).length() < 1e-4);
        // Straight down at a lateral offset: the upper hemisphere.
        let delta = off * r;
        let ray = Ray::new((c.center + d * delta).extend(height + dist), Vec3::NEG_Z, 1e3);
        let (t, _) = c.intersect(&ray, ray.t_max).unwrap();
        let top = (height - r) + (r * r - delta * delta).sqrt();
        prop_assert!((t - (height + dist - top)).abs() <= TOL * (dist + height), "cap {t}");
    }
}

#[test]
fn mesh_box_hits_are_exact_from_all_six_sides() {
    let b = Box3::new(Vec3::new(3.0, -2.0, 1.5), 4.0, 2.0, 3.0, 0.0);
    let mut m = TriangleMesh::default();
    m.push_box(&b, 0);
    let world = World::from_triangles(&m.triangles, None).unwrap();
    for (axis, half) in [(Vec3::X, 2.0), (Vec3::Y, 1.0), (Vec3::Z, 1.5)] {
        for s in [1.0f32, -1.0] {
            // Off-centre so the ray crosses a face interior, not the quad's diagonal.
            let offset = Vec3::new(0.3, 0.2, 0.1) * (Vec3::ONE - axis);
            let origin = b.center + offset + axis * s * 10.0;
            let h = world.closest_hit(&Ray::new(origin, -axis * s, 100.0), None).unwrap();
            assert!((h.t - (10.0 - half)).abs() < TOL, "{axis} {s}: {}", h.t);
            assert!((h.normal - axis * s).length() < 1e-6);
        }
    }
}
