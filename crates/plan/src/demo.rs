//! A deterministic set of road users for commands that need a populated scene without running
//! the traffic simulation (`hilo scan`, `hilo bench sensors`): vehicles on
//! the lanes (queued at stop lines or driving) and pedestrians on the crosswalks.

use hilo_core::{Box3, Class};
use hilo_raycast::Actor;
use hilo_raycast::Scene;
use hilo_raycast::scene::layout::LaneKind;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn size(class: Class) -> (f32, f32, f32) {
    match class {
        Class::Car => (4.6, 1.9, 1.55),
        Class::Truck => (8.5, 2.5, 3.4),
        Class::Bus => (12.0, 2.6, 3.2),
        Class::Motorcycle => (2.2, 0.8, 1.4),
        Class::Pedestrian => (0.6, 0.6, 1.75),
        Class::GolfCart => (2.5, 1.3, 1.8),
        Class::Bicycle => (1.75, 0.65, 1.7),
    }
}

/// Up to `n` actors: about one in six a pedestrian on a crosswalk, the rest vehicles spaced
/// along the lanes; `moving` decides whether vehicles drive along their lane (at 6–14 m/s) or
/// stand. The same seed gives the same actors.
pub fn demo_actors(scene: &Scene, n: usize, moving: bool, seed: u64) -> Vec<Actor> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    let gz = scene.ground.z_m;
    let lanes: Vec<_> =
        scene.layout.arms.iter().flat_map(|a| a.lanes.iter()).filter(|l| l.kind != LaneKind::LeftTurnBay).collect();
    let crosswalks: Vec<_> = scene.layout.arms.iter().map(|a| a.crosswalk.clone()).collect();
    // About one in six road users walks; at most six side by side on a crosswalk.
    let n_ped = (n / 6).min(6 * crosswalks.len());
    for k in 0..n_ped {
        let cw = &crosswalks[k % crosswalks.len()];
        let (along, across) = (cw[1] - cw[0], cw[3] - cw[0]);
        let p =
            cw[0] + along * rng.random_range(0.2..0.8) + across * ((k / crosswalks.len()) as f32 * 0.17 + 0.1).fract();
        let dir = across.normalize_or_zero();
        let speed = if moving { rng.random_range(1.0..1.6) } else { 0.0 };
        let (l, w, h) = size(Class::Pedestrian);
        let b = Box3::new(p.extend(gz + 0.5 * h), l, w, h, dir.y.atan2(dir.x));
        out.push(Actor::from_box(out.len() as u32, Class::Pedestrian, b).with_velocity((dir * speed).extend(0.0)));
    }
    let classes = [
        Class::Car,
        Class::Car,
        Class::Car,
        Class::Truck,
        Class::Car,
        Class::Bus,
        Class::Motorcycle,
        Class::GolfCart,
        Class::Car,
    ];
    let mut slot = 0usize;
    while out.len() < n && !lanes.is_empty() && slot < 40 * lanes.len() {
        let lane = lanes[slot % lanes.len()];
        let k = slot / lanes.len();
        slot += 1;
        let class = classes[(slot * 7 + k) % classes.len()];
        let (l, w, h) = size(class);
        let dir = (lane.end - lane.start).normalize_or_zero();
        let len = (lane.end - lane.start).length();
        // Inbound lanes fill from the stop line back; outbound from the junction out.
        let s = 3.0 + k as f32 * 15.0 + 0.5 * l;
        if s + 0.5 * l > len {
            continue;
        }
        let c = if lane.kind == LaneKind::Inbound { lane.end - dir * s } else { lane.start + dir * s };
        let b = Box3::new(c.extend(gz + 0.5 * h), l, w, h, dir.y.atan2(dir.x));
        let speed = if moving { rng.random_range(6.0..14.0) } else { 0.0 };
        out.push(Actor::from_box(out.len() as u32, class, b).with_velocity((dir * speed).extend(0.0)));
    }
    out
}

/// The actors `dt` seconds later (straight-line motion).
pub fn advance(actors: &[Actor], dt: f32) -> Vec<Actor> {
    actors.iter().map(|a| a.moved(dt)).collect()
}

/// Box of an actor, for drawing.
pub fn actor_box(a: &Actor) -> Box3 {
    a.shape.outline()
}
