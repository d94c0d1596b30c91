//! Actors that move during a sweep: meeting the set at time dt is meeting the actors moved by
//! velocity × dt (an independent oracle: a still set of moved actors), and the swept bounds
//! never lose a hit however far the actor moves within the span.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::{Vec2, Vec3};
use hilo_core::{Box3, Class};
use hilo_raycast::shapes::GroundPlane;
use hilo_raycast::{Actor, ActorSet, Ray, World};
use proptest::prelude::*;

fn actors(v: f32) -> Vec<Actor> {
    (0..12u32)
        .map(|i| {
            let at = Vec3::new(-30.0 + 5.5 * i as f32, (i as f32 * 2.3) % 11.0 - 5.5, 0.9);
            let class = if i % 4 == 0 { Class::Pedestrian } else { Class::Car };
            let b = Box3::new(at, 4.2, 1.8, 1.6, 0.37 * i as f32);
            let dir = Vec3::new((0.9 * i as f32).cos(), (0.9 * i as f32).sin(), 0.0);
            Actor::from_box(i, class, b).with_velocity(dir * v * (1.0 + (i % 3) as f32))
        })
        .collect()
}

proptest! {
    #[test]
    fn meeting_the_set_at_dt_is_meeting_the_moved_actors(
        dt in 0.0f32..0.1, az in -3.1f32..3.1, el in -0.5f32..0.1, x in -20.0f32..20.0, v in 0.0f32..25.0
    ) {
        let a = actors(v);
        let moving = ActorSet::moving(a.clone(), 0.1).unwrap();
        let moved = ActorSet::new(a.iter().map(|x| x.moved(dt)).collect()).unwrap();
        let dir = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
        let ray = Ray { origin: Vec3::new(x, 12.0, 5.0), dir, t_min: 0.0, t_max: 200.0 };
        let got = moving.closest_at(&ray, 200.0, dt);
        let want = moved.closest(&ray, 200.0);
        prop_assert_eq!(got.is_some(), want.is_some());
        if let (Some(g), Some(w)) = (got, want) {
            prop_assert!((g.t - w.t).abs() < 1e-3 * w.t.max(1.0), "{} vs {}", g.t, w.t);
            prop_assert_eq!(g.target, w.target);
            prop_assert!((g.normal - w.normal).length() < 1e-4);
        }
        // The frame's instant is the still set's.
        let still = ActorSet::new(a).unwrap();
        prop_assert_eq!(moving.closest_at(&ray, 200.0, 0.0).map(|h| h.t), still.closest(&ray, 200.0).map(|h| h.t));
    }
}

#[test]
fn a_fast_actor_is_met_far_from_where_it_started() {
    // 30 m/s for 0.1 s: 3 m along x, well outside its bounds at the frame's instant.
    let car = Actor::from_box(1, Class::Car, Box3::new(Vec3::new(20.0, 0.0, 0.8), 4.0, 1.8, 1.6, 0.0))
        .with_velocity(Vec3::new(0.0, 30.0, 0.0));
    let set = ActorSet::moving(vec![car], 0.1).unwrap();
    let world =
        World::from_triangles(&[], Some(GroundPlane { z_m: 0.0, min: Vec2::splat(-100.0), max: Vec2::splat(100.0) }))
            .unwrap();
    let ray = Ray { origin: Vec3::new(0.0, 3.0, 0.8), dir: Vec3::X, t_min: 0.0, t_max: 100.0 };
    assert!(world.closest_hit_at(&ray, Some(&set), 0.0).is_none_or(|h| h.target == hilo_raycast::HitTarget::Ground));
    let h = world.closest_hit_at(&ray, Some(&set), 0.1).unwrap();
    assert!(matches!(h.target, hilo_raycast::HitTarget::Actor { id: 1, .. }));
    assert!((h.t - 18.0).abs() < 1e-4, "{}", h.t);
    // Past the span, the actor stays where the span ends.
    assert_eq!(world.closest_hit_at(&ray, Some(&set), 5.0).map(|h| h.t), Some(h.t));
    // A still set ignores time.
    let still = ActorSet::new(set.actors().to_vec()).unwrap();
    assert_eq!(still.span_s(), 0.0);
    assert!(world.closest_hit_at(&ray, Some(&still), 0.1).is_none_or(|h| h.target == hilo_raycast::HitTarget::Ground));
    // Bad spans and velocities are refused.
    assert!(ActorSet::moving(vec![car], f32::NAN).is_err());
    assert!(ActorSet::moving(vec![car.with_velocity(Vec3::splat(f32::INFINITY))], 0.1).is_err());
}
