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
            let class = Class::ALL[i % 6];
            let (l, w, h) = match class {
                Class::Pedestrian => (0.6, 0.6, 1.75),
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

#[test]
fn invalid_actor_shapes_are_errors() {
    let bad = Box3::new(Vec3::ZERO, f32::NAN, 1.0, 1.0, 0.0);
    let err = ActorSet::new(vec![Actor::from_box(4, Class::Car, bad)]).unwrap_err();
    assert!(err.to_string().contains("id 4"), "{err}");
    assert!(ActorSet::new(vec![]).unwrap().closest(&Ray::new(Vec3::ZERO, Vec3::X, 10.0), 10.0).is_none());
}
