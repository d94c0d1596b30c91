//! Traffic at a roundabout (`fixtures/sites/roundabout.toml`): an entry takes the gaps in the
//! circulating flow that its capacity formula (what the demand levels use) says it does, the ring
//! flows at the default rates, and the curves on and off the ring keep a bus on the road.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_dataset::traffic::demand::{Demand, RING_FOLLOW_UP_S, ring_entry_capacity};
use hilo_dataset::traffic::routes::build_routes;
use hilo_dataset::traffic::{Traffic, TrafficConfig, footprint};
use hilo_raycast::Scene;
use std::collections::BTreeMap;
use std::path::Path;

fn scene() -> Scene {
    Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/sites/roundabout.toml")).unwrap()
}

/// Runs `seconds` after the warm-up; returns the vehicles that passed each approach's yield
/// line, by arm name, and the traffic at the end.
fn run(scene: &Scene, cfg: &TrafficConfig, seed: u64, seconds: f64) -> (BTreeMap<String, usize>, Traffic) {
    let mut t = Traffic::new(&scene.layout, scene.ground.z_m, cfg, seed).unwrap();
    let steps = (seconds / t.step_s()).round() as usize;
    let mut before = BTreeMap::new();
    let mut entered = BTreeMap::new();
    for _ in 0..steps {
        for a in &t.snapshot() {
            if let Some(r) = a.route {
                let past = r.front_s > r.stop_s;
                if before.insert(a.id, past) == Some(false) && past {
                    *entered.entry(scene.layout.arms[r.approach].name.clone()).or_insert(0) += 1;
                }
            }
        }
        t.step();
    }
    (entered, t)
}

/// North flooded with through traffic and east's through traffic circulating past north's entry
/// at `east` veh/h (nothing else): north's entries per hour and the circulating flow per hour.
fn flooded_north(scene: &Scene, east: f64, seconds: f64) -> (f64, f64) {
    let mut cfg = TrafficConfig {
        vehicles_per_hour: 0.0,
        pedestrians_per_hour: 0.0,
        left_share: 0.0,
        right_share: 0.0,
        ..TrafficConfig::default()
    };
    cfg.approach_vehicles_per_hour.insert("north".into(), 3000.0);
    cfg.approach_vehicles_per_hour.insert("east".into(), east);
    let (n, _) = run(scene, &cfg, 5, seconds);
    let per_hour = |arm: &str| n.get(arm).copied().unwrap_or(0) as f64 * 3600.0 / seconds;
    (per_hour("north"), per_hour("east"))
}

/// An entry's discharge against the flow circulating past it is Tanner's gap-acceptance
/// capacity with the model's headways (the formula the demand levels load entries with): an
/// empty ring takes a queue at the follow-up headway, and 300 and 600 veh/h circulating leave
/// what the formula says, within 15%. (HCM 6's single-lane entry, `1380 e^(−0.00102 v_c)`,
/// passes more: the model's queues are slower than the field's, as at its signal.)
#[test]
fn an_entry_takes_the_gaps_its_capacity_formula_counts() {
    let scene = scene();
    let seconds = 900.0;
    for east in [0.0, 300.0, 600.0] {
        let (entered, circulating) = flooded_north(&scene, east, seconds);
        let formula = ring_entry_capacity(circulating);
        let hcm = 1380.0 * (-0.00102 * circulating).exp();
        eprintln!(
            "circulating {circulating:.0} veh/h: north enters {entered:.0} veh/h, formula {formula:.0}, HCM 6 {hcm:.0}"
        );
        if east == 0.0 {
            assert!((entered * RING_FOLLOW_UP_S / 3600.0 - 1.0).abs() < 0.1, "{entered}");
        }
        assert!((entered / formula - 1.0).abs() < 0.15, "{entered:.0} vs {formula:.0} at {circulating:.0}");
    }
}

/// At the off-peak level (each entry at v/c 0.35 by the capacity formula, 30 pedestrians per
/// crosswalk and direction) the approaches keep up with their arrivals and no queue grows beyond
/// the arm; at the default rates (500 veh/h per approach, past this junction's capacity in the
/// model, and 90 pedestrians) the ring still flows: every approach enters, nobody is stuck.
/// (`docs/models.md` gives 20-minute figures for every level.)
#[test]
fn the_ring_keeps_up_off_peak_and_flows_at_the_default_rates() {
    let scene = scene();
    let seconds = 400.0;
    for (cfg, keeps_up) in [
        (TrafficConfig { demand: Some(Demand::OffPeak), ..TrafficConfig::default() }, true),
        (TrafficConfig::default(), false),
    ] {
        let (entered, t) = run(&scene, &cfg, 2, seconds);
        let rates = t.approach_rates().to_vec();
        eprintln!(
            "{:?}: {entered:?} in {seconds} s at {rates:.0?} veh/h, {} waiting, {} emergency stops",
            cfg.demand,
            t.waiting_to_enter(),
            t.clamps
        );
        // Arrivals are Poisson: each approach's count is noisy, all four together less so.
        let expected: Vec<f64> = rates.iter().map(|r| r * seconds / 3600.0).collect();
        let counts: Vec<f64> =
            scene.layout.arms.iter().map(|a| entered.get(&a.name).copied().unwrap_or(0) as f64).collect();
        for ((arm, n), e) in scene.layout.arms.iter().zip(&counts).zip(&expected) {
            assert!(*n > 0.4 * e, "{:?} {}: {n} of {e:.0}", cfg.demand, arm.name);
        }
        assert!(t.clamps < 50, "{}", t.clamps);
        if keeps_up {
            let (n, e) = (counts.iter().sum::<f64>(), expected.iter().sum::<f64>());
            assert!(n > 0.8 * e, "{:?}: {n} of {e:.0}", cfg.demand);
            assert!(t.waiting_to_enter() < 5, "{:?}: {} waiting", cfg.demand, t.waiting_to_enter());
        }
    }
}

/// The curves on and off the ring keep the longest, widest body the model drives (a 13 m × 2.6 m
/// bus) on the carriageway: its sides, every metre, along every route from one crosswalk to the
/// next.
#[test]
fn a_bus_stays_on_the_road_through_the_ring() {
    let scene = scene();
    let routes = build_routes(&scene.layout);
    assert_eq!(routes.len(), 12, "four arms, three movements each");
    let mut off = Vec::new();
    for r in &routes {
        let (from, to) = (r.crosswalks[0].s_out + 6.5, r.clear_s - 6.5);
        let mut s = from;
        while s < to {
            let body = footprint(&r.path, s, 6.5, 1.3);
            let side = body.dir.perp() * 1.3;
            for k in 0..=13 {
                let along = body.center + body.dir * (6.5 * (k as f32 / 6.5 - 1.0));
                for q in [along + side, along - side] {
                    if !scene.layout.on_carriageway(q) {
                        off.push(format!("{} -> {} at s {s:.1}: ({:.2}, {:.2})", r.approach, r.exit, q.x, q.y));
                    }
                }
            }
            s += 0.5;
        }
    }
    assert!(off.is_empty(), "{} points off the road:\n{}", off.len(), off[..off.len().min(10)].join("\n"));
}
