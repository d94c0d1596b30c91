//! hilo's engine against parry3d's TriMesh, an independent implementation, on the default scene.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec3;
use hilo_raycast::reference::{DIST_TOL_M, compare_with_parry, ground_triangles, on_mesh_edge, parry_trimesh};
use hilo_raycast::{HitTarget, QueryRegion, Ray, Scene, World};
use parry3d::query::RayCast;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_dir(rng: &mut ChaCha8Rng) -> Vec3 {
    loop {
        let v = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
            return v.normalize();
        }
    }
}

#[test]
fn random_rays_agree_with_parry_everywhere_except_documented_edge_cases() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let tile = 10.0;
    let parry = parry_trimesh(&scene, tile).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut rays = Vec::with_capacity(120_000);
    // Anywhere in the scene, any direction (many start inside buildings or crowns on purpose).
    for _ in 0..80_000 {
        let o =
            Vec3::new(rng.random_range(-140.0..140.0), rng.random_range(-140.0..140.0), rng.random_range(0.2..25.0));
        rays.push(Ray::new(o, random_dir(&mut rng), 200.0));
    }
    // From the mounting poles, where sensors will sit.
    for k in 0..40_000 {
        let m = &scene.mounts[k % scene.mounts.len()];
        let o = m.base.extend(rng.random_range(3.0..8.0)) + Vec3::new(0.5, 0.5, 0.0);
        rays.push(Ray::new(o, random_dir(&mut rng), 150.0));
    }
    let c = compare_with_parry(&scene, &world, &parry, tile, &rays);
    assert_eq!(c.rays, 120_000);
    assert_eq!(c.unexplained, 0, "{c:?}");
    assert!(c.max_abs_dist_err_m <= DIST_TOL_M as f64, "{c:?}");
    // Every hit/miss disagreement is a ray through a mesh edge.
    assert!(c.hit_miss_mismatches <= c.explained_by_shared_edge, "{c:?}");
}

/// A ray lying in the vertical plane of a mast arm's axis passes exactly through the shared
/// top edge of the arm's cylinder mesh. hilo's watertight test hits the arm there; parry's test
/// lets the ray slip through the crack and reports a surface behind it. This is the documented
/// source of the disagreements the comparison above tolerates.
#[test]
fn regression_parry_leaks_through_the_mast_arm_top_edge_where_hilo_hits() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let parry = parry_trimesh(&scene, 10.0).unwrap();
    // SW pole: arm along +x at y = -16.6, z = 6.0, radius 0.6 * 0.18.
    let sw = scene.mounts.iter().find(|m| m.name == "SW").unwrap();
    let origin = sw.base.extend(7.8);
    let dir = Vec3::new(0.8262388, 0.0, -0.56332004);
    let ray = Ray::new(origin, dir, 120.0);
    let h = world.closest_hit(&ray, None).unwrap();
    let arm_top = 6.0 + 0.6 * 0.18;
    let expected_t = (7.8 - arm_top) / 0.56332004_f32;
    assert!((h.t - expected_t).abs() < 1e-4, "hit at {} expected {expected_t}", h.t);
    match h.target {
        HitTarget::Static { object, .. } => assert_eq!(scene.objects[object as usize].name, "SW/mast_arm"),
        other => panic!("expected the mast arm, got {other:?}"),
    }
    let mut all = ground_triangles(&scene, 10.0);
    all.extend_from_slice(&scene.mesh.triangles);
    assert!(on_mesh_edge(h.point, &all, 2e-4));
    let tp = parry.cast_local_ray(&parry3d::query::Ray::new(ray.origin, ray.dir), 120.0, false).unwrap();
    assert!(tp > h.t + 0.1, "parry {tp} hilo {}", h.t);
}
