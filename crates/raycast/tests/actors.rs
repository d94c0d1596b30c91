//! The per-frame actor structure against brute force over the same actors.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec3;
use hilo_core::{Box3, Class};
use hilo_raycast::{Actor, ActorSet, Ray};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn actor_bvh_matches_brute_force_closest_and_any() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let actors: Vec<Actor> = (0..150)
        .map(|i| {
            let class = Class::ALL[i % Class::ALL.len()];
            let (l, w, h) = match class {
                Class::Pedestrian => (0.6, 0.6, 1.75),
                Class::Bicycle => (1.75, 0.65, 1.7),
                Class::Bus => (12.0, 2.6, 3.2),
                _ => (4.5, 1.9, 1.6),
            };
            let c = Vec3::new(rng.random_range(-60.0..60.0), rng.random_range(-60.0..60.0), h / 2.0);
            Actor::from_box(
                i as u32,
                class,
                Box3::new(c, l, w, h, rng.random_range(-std::f32::consts::PI..std::f32::consts::PI)),
            )
        })
        .collect();
    let set = ActorSet::new(actors.clone()).unwrap();
    let singles: Vec<ActorSet> = actors.iter().map(|a| ActorSet::new(vec![*a]).unwrap()).collect();
    let mut hits = 0;
    for _ in 0..5000 {
        let o = Vec3::new(rng.random_range(-70.0..70.0), rng.random_range(-70.0..70.0), rng.random_range(0.3..8.0));
        let d = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-0.3..0.1));
        let ray = Ray::new(o, d, 90.0);
        let brute = singles.iter().filter_map(|s| s.closest(&ray, ray.t_max)).min_by(|a, b| a.t.total_cmp(&b.t));
        let got = set.closest(&ray, ray.t_max);
        let key = |h: hilo_raycast::Hit| match h.target {
            hilo_raycast::HitTarget::Actor { id, class, .. } => (h.t, id, class),
            other => panic!("not an actor: {other:?}"),
        };
        // Distances agree exactly; on a tie (random actors may overlap) any tied actor is right.
        assert_eq!(got.map(|h| h.t), brute.map(|h| h.t));
        if let Some(h) = got {
            let (t, id, class) = key(h);
            let a = &actors[id as usize];
            assert_eq!((a.id, a.class), (id, class));
            assert_eq!(singles[id as usize].closest(&ray, ray.t_max).map(|s| s.t), Some(t));
        }
        assert_eq!(set.any(&ray, ray.t_max), brute.is_some());
        hits += brute.is_some() as usize;
    }
    assert!(hits > 200, "only {hits} hits: the test would prove little");
}

/// A cyclist is a bicycle as high as its wheels and as wide as a tyre, and a rider above the
/// pedals: rays through the rest of its box pass, rays at the parts meet them where closed
/// forms put them, every hit lies in the annotated box, and a side view returns fewer hits
/// than a solid box of the same size would.
#[test]
fn a_cyclist_is_a_bicycle_and_a_rider_not_a_box() {
    let b = Box3::new(Vec3::new(0.0, 0.0, 0.85), 1.75, 0.65, 1.7, 0.0);
    let cyclist = ActorSet::new(vec![Actor::from_box(1, Class::Bicycle, b)]).unwrap();
    let solid = ActorSet::new(vec![Actor::from_box(1, Class::Car, b)]).unwrap();
    let t = |set: &ActorSet, o: Vec3, d: Vec3| set.closest(&Ray::new(o, d, 50.0), 50.0).map(|h| h.t);
    let side = |x: f32, z: f32| (Vec3::new(x, 10.0, z), Vec3::NEG_Y);
    // Wheel height, off the rider: the tyre's face, 3 cm from the centre line.
    let (o, d) = side(0.5, 0.4);
    assert!((t(&cyclist, o, d).unwrap() - 9.97).abs() < 1e-4);
    // Above the wheels, off the rider: nothing (the solid box's side is there).
    let (o, d) = side(0.5, 1.2);
    assert_eq!(t(&cyclist, o, d), None);
    assert!((t(&solid, o, d).unwrap() - (10.0 - 0.325)).abs() < 1e-4);
    // The rider, 0.2 m from the centre line.
    let (o, d) = side(0.0, 1.2);
    assert!((t(&cyclist, o, d).unwrap() - 9.8).abs() < 1e-4);
    // From the front, beside the tyre and the rider but inside the box: nothing.
    assert_eq!(t(&cyclist, Vec3::new(10.0, 0.25, 0.5), Vec3::NEG_X), None);
    // A fan of rays from a pole: every hit inside the annotated box; far fewer than the box's.
    let sensor = Vec3::new(6.0, 8.0, 5.0);
    let (mut on_cyclist, mut on_box) = (0, 0);
    for i in 0..60 {
        for j in 0..60 {
            let target = Vec3::new(-1.2 + 2.4 * i as f32 / 59.0, -0.6, 0.05 + 1.8 * j as f32 / 59.0);
            let ray = Ray::new(sensor, target - sensor, 50.0);
            if let Some(h) = cyclist.closest(&ray, 50.0) {
                on_cyclist += 1;
                let p = sensor + (target - sensor).normalize() * h.t;
                let grown =
                    Box3 { length_m: b.length_m + 2e-3, width_m: b.width_m + 2e-3, height_m: b.height_m + 2e-3, ..b };
                assert!(grown.contains(p), "hit {p} outside the cyclist's box");
            }
            on_box += solid.closest(&ray, 50.0).is_some() as usize;
        }
    }
    assert!(on_cyclist > 100 && (on_cyclist as f64) < 0.8 * on_box as f64, "{on_cyclist} hits against {on_box}");
}

#[test]
fn invalid_actor_shapes_are_errors() {
    let bad = Box3::new(Vec3::ZERO, f32::NAN, 1.0, 1.0, 0.0);
    let err = ActorSet::new(vec![Actor::from_box(4, Class::Car, bad)]).unwrap_err();
    assert!(err.to_string().contains("id 4"), "{err}");
    assert!(ActorSet::new(vec![]).unwrap().closest(&Ray::new(Vec3::ZERO, Vec3::X, 10.0), 10.0).is_none());
}
