//! Hard cases of the triangle engine: vertices and shared edges of closed meshes, rays parallel
//! to faces, origins on surfaces, and a scene far from the origin.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::{DVec3, Vec3};
use hilo_core::Box3;
use hilo_raycast::mesh::icosphere;
use hilo_raycast::{QueryRegion, Ray, Scene, TriangleMesh, World};
use std::collections::HashSet;

fn closed_meshes() -> Vec<(&'static str, Vec<[Vec3; 3]>)> {
    let mut boxm = TriangleMesh::default();
    boxm.push_box(&Box3::new(Vec3::new(0.5, -0.25, 1.0), 2.0, 1.5, 2.0, 0.4), 0);
    let mut cyl = TriangleMesh::default();
    cyl.push_cylinder(Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.3, 0.2, 3.0), 0.7, 12, 0);
    let sphere: Vec<[Vec3; 3]> = icosphere(2).iter().map(|t| t.map(|v| v * 1.3 + Vec3::new(0.1, 0.2, 1.4))).collect();
    vec![("box", boxm.triangles), ("cylinder", cyl.triangles), ("icosphere", sphere)]
}

/// Directions from a fixed set spread over the sphere (not axis-aligned, not degenerate).
fn directions() -> Vec<Vec3> {
    (0..24)
        .map(|k| {
            let z = -1.0 + (2.0 * k as f32 + 1.0) / 24.0;
            let a = k as f32 * 2.399_963; // golden angle
            let r = (1.0 - z * z).sqrt();
            Vec3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect()
}

/// Inside test for a closed convex mesh: behind every face plane (normals turned outward).
fn inside_convex(tris: &[[Vec3; 3]], x: Vec3) -> bool {
    let c = tris.iter().flatten().copied().sum::<Vec3>() / (3 * tris.len()) as f32;
    tris.iter().all(|&[a, b, cc]| {
        let mut n = (b - a).cross(cc - a);
        if n.dot(a - c) < 0.0 {
            n = -n;
        }
        (x - a).dot(n) < 0.0
    })
}

/// A ray aimed exactly at a vertex or at a point of an edge shared by two triangles must hit
/// whenever it passes through the solid there (it is inside 1 mm before or after the point).
/// Rays that only touch the solid at that point (tangent) may go either way under rounding.
#[test]
fn rays_at_every_vertex_and_along_every_shared_edge_hit() {
    for (name, tris) in closed_meshes() {
        let world = World::from_triangles(&tris, None).unwrap();
        let mut targets: Vec<Vec3> = Vec::new();
        let mut edges = HashSet::new();
        for t in &tris {
            targets.extend_from_slice(t);
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                let key = if a.to_array() < b.to_array() {
                    (a.to_array().map(f32::to_bits), b.to_array().map(f32::to_bits))
                } else {
                    (b.to_array().map(f32::to_bits), a.to_array().map(f32::to_bits))
                };
                if edges.insert(key) {
                    for s in [0.125f32, 0.3, 0.5, 0.77] {
                        targets.push(a + (b - a) * s);
                    }
                }
            }
        }
        let mut misses = 0;
        let mut total = 0;
        for p in &targets {
            for d in directions() {
                if !(inside_convex(&tris, *p + d * 1e-3) || inside_convex(&tris, *p - d * 1e-3)) {
                    continue;
                }
                // Aim at the point from 20 m away; the ray passes exactly through it.
                let ray = Ray::new(*p - d * 20.0, d, 100.0);
                total += 1;
                if world.closest_hit(&ray, None).is_none() {
                    misses += 1;
                }
            }
        }
        assert!(total > 500, "{name}: only {total} rays through the solid");
        assert_eq!(misses, 0, "{name}: {misses} of {total} rays leaked through vertices or edges");
    }
}

#[test]
fn ray_in_the_plane_of_a_face_hits_the_edge_and_a_parallel_offset_ray_misses() {
    let mut m = TriangleMesh::default();
    m.push_box(&Box3::new(Vec3::new(0.0, 0.0, 1.0), 2.0, 2.0, 2.0, 0.0), 0);
    let world = World::from_triangles(&m.triangles, None).unwrap();
    // Along the top face's plane z = 2: touches the front face's top edge at x = -1.
    let h = world.closest_hit(&Ray::new(Vec3::new(-5.0, 0.3, 2.0), Vec3::X, 100.0), None);
    assert!((h.unwrap().t - 4.0).abs() < 1e-5);
    // Parallel, 1 mm above the top face: nothing.
    assert!(world.closest_hit(&Ray::new(Vec3::new(-5.0, 0.3, 2.001), Vec3::X, 100.0), None).is_none());
    // Parallel to a side face, 1 mm outside it: nothing.
    assert!(world.closest_hit(&Ray::new(Vec3::new(-5.0, 1.001, 1.0), Vec3::X, 100.0), None).is_none());
}

#[test]
fn origin_on_a_surface_does_not_hit_that_surface() {
    let mut m = TriangleMesh::default();
    m.push_box(&Box3::new(Vec3::new(0.0, 0.0, 1.0), 2.0, 2.0, 2.0, 0.0), 0);
    let world = World::from_triangles(&m.triangles, None).unwrap();
    let on_top = Vec3::new(0.2, 0.3, 2.0);
    // Pointing away: the surface it sits on is not reported.
    assert!(world.closest_hit(&Ray::new(on_top, Vec3::new(0.1, 0.0, 1.0), 50.0), None).is_none());
    assert!(!world.occluded(&Ray::new(on_top, Vec3::Z, 50.0), None));
    // Pointing in: the opposite face, 2 m below.
    let h = world.closest_hit(&Ray::new(on_top, Vec3::NEG_Z, 50.0), None).unwrap();
    assert!((h.t - 2.0).abs() < 1e-5);
}

fn write_obj(path: &std::path::Path, offset: DVec3) {
    // A 4 m cube standing on the ground 20 m east of the local origin, plus a slanted roof.
    let mut s = String::new();
    let v = [
        (18.0, -2.0, 0.0),
        (22.0, -2.0, 0.0),
        (22.0, 2.0, 0.0),
        (18.0, 2.0, 0.0),
        (18.0, -2.0, 4.0),
        (22.0, -2.0, 4.0),
        (22.0, 2.0, 4.0),
        (18.0, 2.0, 4.0),
        (20.0, 0.0, 6.0),
    ];
    for (x, y, z) in v {
        let p = DVec3::new(x, y, z) + offset;
        s.push_str(&format!("v {:.6} {:.6} {:.6}\n", p.x, p.y, p.z));
    }
    s.push_str("f 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\nf 5 6 9\nf 6 7 9\nf 7 8 9\nf 8 5 9\n");
    std::fs::write(path, s).unwrap();
}

#[test]
fn a_scene_far_from_the_origin_gives_the_same_hits() {
    let dir = tempfile::tempdir().unwrap();
    let far = DVec3::new(500_000.0, 3_700_000.0, 300.0);
    write_obj(&dir.path().join("local.obj"), DVec3::ZERO);
    write_obj(&dir.path().join("world.obj"), far);
    let base = Scene::default_fixture().unwrap().config;
    let mut near_cfg = base.clone();
    near_cfg.meshes = vec![toml::from_str("path = \"local.obj\"").unwrap()];
    let mut far_cfg = base;
    far_cfg.origin.x_m = far.x;
    far_cfg.origin.y_m = far.y;
    far_cfg.origin.z_m = far.z;
    far_cfg.meshes = vec![toml::from_str("path = \"world.obj\"\nworld_coordinates = true").unwrap()];
    let near = Scene::from_config(near_cfg, dir.path(), &dir.path().join("near.toml")).unwrap();
    let farsc = Scene::from_config(far_cfg, dir.path(), &dir.path().join("far.toml")).unwrap();
    let wn = World::build(&near, &QueryRegion::everything()).unwrap();
    let wf = World::build(&farsc, &QueryRegion::everything()).unwrap();
    assert_eq!(wn.triangle_count(), wf.triangle_count());
    let mut hits = 0;
    for k in 0..2000 {
        // The same rays, given in world coordinates (f64) and brought to each scene's frame.
        let o_world = DVec3::new(-10.0 + (k % 40) as f64 * 0.9, -15.0 + (k / 40) as f64 * 0.6, 6.5);
        let d = Vec3::new(1.0, 0.05 * ((k % 7) as f32 - 3.0), -0.1 - 0.02 * ((k % 5) as f32)).normalize();
        let rn = Ray::new(near.frame.to_local(o_world), d, 150.0);
        let rf = Ray::new(farsc.frame.to_local(o_world + far), d, 150.0);
        let (hn, hf) = (wn.closest_hit(&rn, None), wf.closest_hit(&rf, None));
        assert_eq!(hn.is_some(), hf.is_some(), "ray {k}");
        if let (Some(a), Some(b)) = (hn, hf) {
            hits += 1;
            assert!((a.t - b.t).abs() < 1e-5, "ray {k}: {} vs {}", a.t, b.t);
            assert_eq!(a.target, b.target);
        }
    }
    assert!(hits > 1500);
}

/// Rays whose line lies exactly (in f32) in a plane containing shared edges of a tiled floor:
/// a ray with no y component starting at a row's y coordinate meets the floor exactly on the
/// edge shared by two rows of tiles, the hardest case for a ray–triangle test. The tiles have
/// awkward coordinates (0.7 m, offset, floor at z = 0.37) so that rounding is not exact.
#[test]
fn rays_exactly_through_shared_edges_of_a_tiled_floor_never_leak() {
    let n = 40;
    let xs: Vec<f32> = (0..=n).map(|i| 13.1 + 0.7 * i as f32).collect();
    let ys: Vec<f32> = (0..=n).map(|j| -7.3 + 0.7 * j as f32).collect();
    let z = 0.37f32;
    let mut tris = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = |a: usize, b: usize| Vec3::new(xs[a], ys[b], z);
            tris.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
            tris.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
        }
    }
    let world = World::from_triangles(&tris, None).unwrap();
    let (mut total, mut misses) = (0, 0);
    for &y in &ys[1..n] {
        for a in 0..120 {
            let el = (4.0 + a as f32 * 0.71).to_radians();
            let h = 2.0 + (a % 7) as f32 * 1.3;
            let az = ((a % 13) as f32 - 6.0) * 0.2;
            // Heading ±x with no y component keeps the line in the plane of the row edge.
            let dir = Vec3::new(az.signum() * el.cos(), 0.0, -el.sin());
            let origin = Vec3::new(13.1 + 14.0 + az * 10.0 - dir.x * h / el.tan(), y, z + h);
            let ray = Ray::new(origin, dir, 200.0);
            let expected_t = -h / ray.dir.z;
            let p = ray.at(expected_t);
            if p.x <= xs[0] + 0.01 || p.x >= xs[n] - 0.01 {
                continue;
            }
            total += 1;
            match world.closest_hit(&ray, None) {
                Some(hit) => assert!((hit.t - expected_t).abs() < 1e-4, "{} vs {expected_t}", hit.t),
                None => misses += 1,
            }
        }
    }
    assert!(total > 2000);
    assert_eq!(misses, 0, "{misses} of {total} rays slipped through shared edges");
}
