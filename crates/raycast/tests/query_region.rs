//! Model only what a query needs: geometry outside the query region is not in the structure,
//! and queries inside it answer exactly as with the whole scene.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec3;
use hilo_raycast::reference::lidar_sweep;
use hilo_raycast::{ObjectKind, QueryRegion, Scene, World};

#[test]
fn geometry_outside_the_region_is_left_out_and_answers_inside_are_unchanged() {
    let scene = Scene::default_fixture().unwrap();
    let full = World::build(&scene, &QueryRegion::everything()).unwrap();
    let ne = scene.mounts.iter().find(|m| m.name == "NE").unwrap();
    let sensor = ne.base.extend(7.8);
    let range = 40.0;
    let part = World::build(&scene, &QueryRegion::spheres([(sensor, range)])).unwrap();
    assert!(
        part.triangle_count() < full.triangle_count() / 2,
        "{} of {}",
        part.triangle_count(),
        full.triangle_count()
    );
    let present = part.objects_present();
    for (i, o) in scene.objects.iter().enumerate() {
        if matches!(o.name.as_str(), "church" | "office" | "strip mall") {
            assert!(!present.contains(&(i as u32)), "{} is 60+ m away but was built", o.name);
        }
        if o.name == "NE/pole" {
            assert!(present.contains(&(i as u32)));
        }
    }
    assert!(present.iter().any(|&i| scene.objects[i as usize].kind == ObjectKind::Sidewalk));
    // Every ray within the range sees the same thing.
    for r in lidar_sweep(sensor, 32, -30.0, 10.0, 720, range) {
        let (a, b) = (full.closest_hit(&r, None), part.closest_hit(&r, None));
        assert_eq!(a.map(|h| (h.t, h.target)), b.map(|h| (h.t, h.target)));
    }
    // A region that excludes everything static still has the ground.
    let empty = World::build(&scene, &QueryRegion::spheres([(Vec3::new(0.0, 0.0, -500.0), 1.0)])).unwrap();
    assert_eq!(empty.triangle_count(), 0);
    assert!(empty.closest_hit(&hilo_raycast::Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z, 10.0), None).is_some());
}
