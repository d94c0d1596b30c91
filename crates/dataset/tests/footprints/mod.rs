//! Road users' footprints, shared by the traffic tests.

#![allow(clippy::panic)]

use hilo_dataset::traffic::ActorState;
use hilo_dataset::traffic::geom::Rect;

/// A road user's footprint on the ground, `shrink` m smaller on every side.
pub fn rect(a: &ActorState, shrink: f32) -> Rect {
    let b = a.box3;
    Rect {
        center: b.center.truncate(),
        dir: b.heading(),
        half_l: 0.5 * b.length_m - shrink,
        half_w: 0.5 * b.width_m - shrink,
    }
}

/// Fails, naming `when`, if two road users' footprints overlap (1 cm tolerance for touching).
pub fn assert_apart(when: &str, actors: &[ActorState]) {
    for i in 0..actors.len() {
        for j in i + 1..actors.len() {
            let (a, b) = (&actors[i], &actors[j]);
            assert!(
                !rect(a, 0.01).overlaps(&rect(b, 0.01)),
                "{when}: {:?} {} and {:?} {} overlap\n{:?}\n{:?}",
                a.class,
                a.id,
                b.class,
                b.id,
                a.box3,
                b.box3
            );
        }
    }
}
