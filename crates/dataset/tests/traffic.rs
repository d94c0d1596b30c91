//! Physical sanity of the traffic simulation on the default intersection.
//!
//! `HILO_TRAFFIC_SEEDS=0,1,2 HILO_TRAFFIC_SECONDS=345` runs the sanity test on more seeds and
//! longer;
//! `HILO_TRAFFIC_WARMUP=0` starts from an empty junction so that every step is checked.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod footprints;

use hilo_core::Class;
use hilo_dataset::traffic::routes::Movement;
use hilo_dataset::traffic::signal::Light;
use hilo_dataset::traffic::{ActorState, Traffic, TrafficConfig, class_model};
use hilo_raycast::Scene;
use hilo_raycast::scene::layout::point_in_polygon;
use std::collections::{BTreeMap, BTreeSet};

fn scene() -> Scene {
    Scene::default_fixture().expect("default scene")
}

type Frames = Vec<(f64, Vec<ActorState>, BTreeMap<(usize, Movement), Light>)>;

fn run(seed: u64, seconds: f64, cfg: &TrafficConfig) -> (Traffic, Frames) {
    let s = scene();
    let mut t = Traffic::new(&s.layout, s.ground.z_m, cfg, seed).expect("traffic");
    let mut out = Vec::new();
    let steps = (seconds / t.step_s()).round() as usize;
    for _ in 0..steps {
        let mut lights = BTreeMap::new();
        for r in t.routes() {
            lights.insert((r.approach, r.movement), t.light(r.approach, r.movement));
        }
        out.push((t.time_s(), t.snapshot(), lights));
        t.step();
    }
    (t, out)
}

#[test]
fn traffic_is_physically_sane() {
    let seeds: Vec<u64> = std::env::var("HILO_TRAFFIC_SEEDS")
        .ok()
        .map_or(vec![7, 8], |s| s.split(',').filter_map(|x| x.parse().ok()).collect());
    let seconds: f64 = std::env::var("HILO_TRAFFIC_SECONDS").ok().and_then(|s| s.parse().ok()).unwrap_or(150.0);
    let mut classes = BTreeSet::new();
    for seed in seeds {
        eprintln!("seed {seed}");
        classes.extend(sane(seed, seconds));
    }
    // Every class of the mix drives (buses are 3% of vehicles: over the seeds together).
    assert_eq!(classes.len(), 6, "classes seen: {classes:?}");
}

/// Checks one run; returns the classes of the road users seen.
fn sane(seed: u64, seconds: f64) -> BTreeSet<Class> {
    let warmup_s = std::env::var("HILO_TRAFFIC_WARMUP").ok().and_then(|s| s.parse().ok()).unwrap_or(45.0);
    let cfg = TrafficConfig { pedestrians_per_hour: 240.0, jaywalk_share: 0.15, warmup_s, ..TrafficConfig::default() };
    let (traffic, frames) = run(seed, seconds, &cfg);
    let s = scene();
    let dt = traffic.step_s() as f32;
    let mut classes = BTreeSet::new();
    let mut max_count = 0;
    let mut crossings = 0;
    let mut prev: BTreeMap<u32, ActorState> = BTreeMap::new();
    let mut jay = 0;
    let mut hist: BTreeMap<u32, Vec<String>> = BTreeMap::new();
    let mut prev_lights: Option<&BTreeMap<(usize, Movement), Light>> = None;
    for (t, actors, lights) in &frames {
        for a in actors {
            if let Some(r) = a.route {
                hist.entry(a.id).or_default().push(format!(
                    "t {t:.2} {:?} front {:.2} stop {:.2} v {:.2} a {:.2}",
                    lights[&(r.approach, r.movement)],
                    r.front_s,
                    r.stop_s,
                    a.velocity_mps.length(),
                    a.accel_mps2
                ));
            }
        }
        max_count = max_count.max(actors.len());
        footprints::assert_apart(&format!("t = {t:.2}"), actors);
        for a in actors {
            classes.insert(a.class);
            let m = class_model(a.class);
            let v = a.velocity_mps.length();
            assert!(v <= m.v_max + 1e-3, "t = {t:.2}: {:?} {} at {v} m/s", a.class, a.id);
            if a.class != Class::Pedestrian {
                assert!(
                    v <= 72.0 / 3.6 * 1.15 + 1e-3,
                    "t = {t:.2}: {:?} {} at {v} m/s exceeds the speed limit by >15%",
                    a.class,
                    a.id
                );
            }
            if let Some(p) = prev.get(&a.id) {
                let acc = (v - p.velocity_mps.length()) / dt;
                assert!(
                    acc >= -m.b_max - 1e-3 && acc <= m.a + 1e-3,
                    "t = {t:.2}: {:?} {} accelerates at {acc} m/s²",
                    a.class,
                    a.id
                );
                // Red means stop: the front may not pass the stop line during a step that starts
                // on red.
                if let (Some(r0), Some(r1), Some(lights)) = (p.route, a.route, prev_lights)
                    && r0.front_s <= r0.stop_s
                    && r1.front_s > r1.stop_s
                {
                    crossings += 1;
                    if lights[&(r1.approach, r1.movement)] == Light::Red {
                        let h = &hist[&a.id];
                        eprintln!("{}", h[h.len().saturating_sub(80)..].join("\n"));
                    }
                    assert_ne!(
                        lights[&(r1.approach, r1.movement)],
                        Light::Red,
                        "t = {t:.2}: vehicle {} ({:?}) crosses its stop line on red: {:?} -> {:?}, v {} -> {}",
                        a.id,
                        a.class,
                        r0,
                        r1,
                        p.velocity_mps.length(),
                        v
                    );
                }
            }
            if a.class == Class::Pedestrian {
                let p = a.box3.center.truncate();
                let on_walkable = s.layout.arms.iter().any(|arm| {
                    point_in_polygon(p, &arm.crosswalk) || arm.sidewalks.iter().any(|w| point_in_polygon(p, w))
                }) || s.layout.corner_sidewalks.iter().any(|w| point_in_polygon(p, w));
                if a.jaywalking {
                    jay += 1;
                } else {
                    assert!(on_walkable, "t = {t:.2}: pedestrian {} at {p} is off the sidewalks and crosswalks", a.id);
                }
            }
        }
        prev = actors.iter().map(|a| (a.id, a.clone())).collect();
        prev_lights = Some(lights);
    }
    eprintln!(
        "max actors {max_count}, stop-line crossings {crossings}, jaywalker-frames {jay}, clamps {}",
        traffic.clamps
    );
    // Emergency stops are rare: well under one per ten vehicles through the junction.
    assert!(traffic.clamps * 10 <= crossings, "{} emergency stops for {crossings} vehicles", traffic.clamps);
    assert!(crossings as f64 > seconds / 8.0, "only {crossings} vehicles crossed a stop line in {seconds} s");
    assert!(max_count >= 15, "at most {max_count} road users at once");
    assert!(jay > 0, "no jaywalker crossed");
    classes
}

#[test]
fn same_seed_same_traffic_other_seed_other_traffic() {
    let cfg = TrafficConfig::default();
    let a = run(3, 20.0, &cfg).1;
    let b = run(3, 20.0, &cfg).1;
    let c = run(4, 20.0, &cfg).1;
    let key = |f: &Frames| f.iter().map(|x| x.1.clone()).collect::<Vec<_>>();
    assert_eq!(key(&a), key(&b));
    assert_ne!(key(&a), key(&c));
}

#[test]
fn bad_traffic_settings_name_the_field() {
    let s = scene();
    let mut cfg = TrafficConfig::default();
    cfg.class_mix.insert("tank".into(), 1.0);
    let e = Traffic::new(&s.layout, 0.0, &cfg, 0).expect_err("unknown class").to_string();
    assert!(e.contains("class_mix.tank"), "{e}");
    let cfg = TrafficConfig { left_share: 1.5, ..TrafficConfig::default() };
    let e = Traffic::new(&s.layout, 0.0, &cfg, 0).expect_err("share").to_string();
    assert!(e.contains("left_share") && e.contains("1.5"), "{e}");
    let mut cfg = TrafficConfig::default();
    cfg.approach_vehicles_per_hour.insert("south-east".into(), 100.0);
    let e = Traffic::new(&s.layout, 0.0, &cfg, 0).expect_err("arm").to_string();
    assert!(e.contains("south-east") && e.contains("east"), "{e}");
}
