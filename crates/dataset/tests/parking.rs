//! Curbside parking: the parking lane's place in the layout, parked vehicles that stay in their
//! lane and clear of every other road user, moving traffic that parking leaves as it was, and
//! bays whose renewal process holds the occupancy and the mean stay it was given.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod footprints;

use hilo_dataset::traffic::{ActorState, PARKED_ID_BASE, ParkingConfig, Traffic, TrafficConfig};
use hilo_raycast::Scene;
use std::collections::BTreeMap;
use std::path::Path;

/// The default junction, its arms given parking lanes `park` m wide (its buildings, trees and
/// poles removed: they stand where the wider road would be).
fn scene(park: f32) -> Scene {
    let mut cfg = Scene::default_fixture().unwrap().config;
    for a in &mut cfg.arms {
        a.parking_lane_width_m = park;
    }
    cfg.buildings.clear();
    cfg.trees.clear();
    cfg.signal_poles.clear();
    cfg.street_lights.clear();
    cfg.meshes.clear();
    Scene::from_config(cfg, Path::new("."), Path::new("parking.toml")).unwrap()
}

fn run(s: &Scene, cfg: &TrafficConfig, seed: u64, seconds: f64) -> (Traffic, Vec<Vec<ActorState>>) {
    let mut t = Traffic::new(&s.layout, s.ground.z_m, cfg, seed).unwrap();
    let mut frames = Vec::new();
    for _ in 0..(seconds / t.step_s()).round() as usize {
        frames.push(t.snapshot());
        t.step();
    }
    (t, frames)
}

#[test]
fn a_parking_lane_widens_the_road_and_leaves_the_lanes() {
    let (a, b) = (scene(0.0), scene(2.4));
    for (x, y) in a.layout.arms.iter().zip(&b.layout.arms) {
        // The lanes keep their place across the arm (the junction's corners move outward).
        let across = |arm: &hilo_raycast::scene::layout::ArmLayout| -> Vec<_> {
            arm.lanes.iter().map(|l| (l.kind, (l.start.dot(arm.normal) * 1e3).round(), l.width_m)).collect()
        };
        assert_eq!(across(x), across(y), "arm {}", x.name);
        assert!((y.edge_in_m - x.edge_in_m - 2.4).abs() < 1e-4, "arm {}", x.name);
        assert!((x.edge_out_m - y.edge_out_m - 2.4).abs() < 1e-4, "arm {}", x.name);
        assert_eq!(y.parking_lane_m, 2.4);
        // The stop line spans the lanes, not the parking lane; the sidewalk starts at the curb.
        let stop_end = (y.stop_line[1].dot(y.normal) - (y.edge_in_m - 2.4)).abs();
        assert!(stop_end < 1e-4, "arm {}: stop line ends {stop_end} m from the lanes", y.name);
        let inner = y.sidewalks[0].iter().map(|p| p.dot(y.normal)).fold(f32::INFINITY, f32::min);
        assert!((inner - y.edge_in_m).abs() < 1e-3, "arm {}: sidewalk starts at {inner}", y.name);
    }
    // The scene file refuses a parking lane no car fits, naming the field.
    let mut cfg = Scene::default_fixture().unwrap().config;
    cfg.arms[1].parking_lane_width_m = 1.0;
    let e = Scene::from_config(cfg, Path::new("."), Path::new("p.toml")).unwrap_err().to_string();
    assert!(e.contains("arms[1].parking_lane_width_m") && e.contains('1'), "{e}");
}

#[test]
fn parked_vehicles_stay_in_their_lane_clear_of_everyone_and_leave_traffic_alone() {
    let s = scene(2.4);
    let base = TrafficConfig { pedestrians_per_hour: 240.0, jaywalk_share: 0.15, ..TrafficConfig::default() };
    // A short stay, so that vehicles come and go within the run.
    let parking = ParkingConfig { occupancy: 0.8, mean_stay_s: 40.0, ..ParkingConfig::default() };
    let cfg = TrafficConfig { parking: Some(parking.clone()), ..base.clone() };
    let (traffic, frames) = run(&s, &cfg, 7, 150.0);
    let (_, plain) = run(&s, &base, 7, 150.0);
    let bays = traffic.parking_bays();
    assert!(bays.len() >= 40, "only {} bays", bays.len());
    let (mut arrivals, mut departures, mut jaywalker_frames) = (0, 0, 0);
    let mut before: Vec<u32> = Vec::new();
    for (k, (actors, moving)) in frames.iter().zip(&plain).enumerate() {
        // Moving traffic is the same with parking as without it.
        let own: Vec<&ActorState> = actors.iter().filter(|a| a.id < PARKED_ID_BASE).collect();
        assert_eq!(own, moving.iter().collect::<Vec<_>>(), "frame {k}: parking changed the moving traffic");
        footprints::assert_apart(&format!("frame {k}"), actors);
        jaywalker_frames += actors.iter().filter(|a| a.jaywalking).count();
        let parked: Vec<&ActorState> = actors.iter().filter(|a| a.id >= PARKED_ID_BASE).collect();
        for p in &parked {
            assert_eq!(p.velocity_mps.length(), 0.0);
            assert_eq!(p.attribute, "vehicle.parked");
            // Every corner in one arm's parking lane, beyond the crosswalk's clearance.
            let inside = s.layout.arms.iter().any(|arm| {
                footprints::rect(p, 0.0).corners().iter().all(|c| {
                    let (along, side) = (c.dot(arm.dir), c.dot(arm.normal));
                    let lane_in = side <= arm.edge_in_m + 1e-3 && side >= arm.edge_in_m - arm.parking_lane_m - 1e-3;
                    let lane_out = side >= arm.edge_out_m - 1e-3 && side <= arm.edge_out_m + arm.parking_lane_m + 1e-3;
                    let past = along >= arm.crosswalk[1].dot(arm.dir).max(arm.crosswalk[0].dot(arm.dir)) + 6.0;
                    (lane_in || lane_out) && past
                })
            });
            assert!(inside, "frame {k}: parked vehicle {} at {:?} is outside every parking lane", p.id, p.box3);
        }
        let now: Vec<u32> = parked.iter().map(|a| a.id).collect();
        if k > 0 {
            arrivals += now.iter().filter(|id| !before.contains(id)).count();
            departures += before.iter().filter(|id| !now.contains(id)).count();
        }
        before = now;
    }
    let share = before.len() as f64 / bays.len() as f64;
    eprintln!(
        "{} bays, {} taken at the end ({share:.2}), {arrivals} arrivals, {departures} departures, {jaywalker_frames} jaywalker-frames",
        bays.len(),
        before.len()
    );
    assert!(arrivals >= 20 && departures >= 20, "{arrivals} arrivals and {departures} departures in 150 s");
    assert!(jaywalker_frames > 0, "no jaywalker crossed between the parked cars");
}

#[test]
fn bays_hold_their_occupancy_and_mean_stay() {
    let s = scene(2.2);
    let (occupancy, stay) = (0.6, 20.0);
    let cfg = TrafficConfig {
        vehicles_per_hour: 0.0,
        pedestrians_per_hour: 0.0,
        warmup_s: 0.0,
        step_s: 0.2,
        parking: Some(ParkingConfig { occupancy, mean_stay_s: stay, ..ParkingConfig::default() }),
        ..TrafficConfig::default()
    };
    // The start is the long-run state: over many scenes, a bay is taken `occupancy` of the time.
    let (mut taken, mut all) = (0, 0);
    for seed in 0..100 {
        let t = Traffic::new(&s.layout, 0.0, &cfg, seed).unwrap();
        let b = t.parking_bays();
        taken += b.iter().filter(|b| b.taken).count();
        all += b.len();
    }
    let start = taken as f64 / all as f64;
    assert!((start - occupancy).abs() < 0.03, "{start:.3} of {all} bays taken at the start");
    // Over a long run: the time share taken, and the mean stay of the vehicles seen to arrive
    // and leave (an exponential's mean; a step of 0.2 s rounds each stay).
    let seconds = 1500.0;
    let (t, frames) = run(&s, &cfg, 5, seconds);
    let n_bays = t.parking_bays().len();
    let per_frame: f64 = frames.iter().map(|f| f.len() as f64 / n_bays as f64).sum::<f64>() / frames.len() as f64;
    let mut seen: BTreeMap<u32, (usize, usize)> = BTreeMap::new();
    for (k, f) in frames.iter().enumerate() {
        for a in f {
            seen.entry(a.id).and_modify(|e| e.1 = k).or_insert((k, k));
        }
    }
    let last = frames.len() - 1;
    let stays: Vec<f64> =
        seen.values().filter(|(a, b)| *a > 0 && *b < last).map(|(a, b)| (b - a + 1) as f64 * 0.2).collect();
    let mean = stays.iter().sum::<f64>() / stays.len() as f64;
    eprintln!("{n_bays} bays: time share taken {per_frame:.3}, {} stays of mean {mean:.2} s", stays.len());
    assert!((per_frame - occupancy).abs() < 0.03, "time share taken {per_frame:.3}");
    assert!(stays.len() > 500, "{} stays", stays.len());
    assert!((mean - stay).abs() < 2.0, "mean stay {mean:.2} s against {stay} s");
    // Same seed, same parked vehicles.
    assert_eq!(run(&s, &cfg, 5, 30.0).1, frames[..150].to_vec());
}

#[test]
fn bad_parking_settings_name_the_field() {
    let s = scene(2.2);
    let with = |p: ParkingConfig| TrafficConfig { parking: Some(p), ..TrafficConfig::default() };
    let err = |s: &Scene, cfg: &TrafficConfig| Traffic::new(&s.layout, 0.0, cfg, 0).unwrap_err().to_string();
    let e = err(&s, &with(ParkingConfig { occupancy: 1.5, ..ParkingConfig::default() }));
    assert!(e.contains("traffic.parking.occupancy") && e.contains("1.5"), "{e}");
    let e = err(&s, &with(ParkingConfig { mean_stay_s: f64::NAN, ..ParkingConfig::default() }));
    assert!(e.contains("traffic.parking.mean_stay_s"), "{e}");
    for (class, why) in [("truck", "does not fit a bay"), ("pedestrian", "do not park"), ("tank", "unknown class")] {
        let mut p = ParkingConfig::default();
        p.class_mix.insert(class.into(), 0.1);
        let e = err(&s, &with(p));
        assert!(e.contains(&format!("traffic.parking.class_mix.{class}")) && e.contains(why), "{e}");
    }
    // A car does not fit a 2 m parking lane with room to the curb and the lane.
    let e = err(&scene(2.0), &with(ParkingConfig::default()));
    assert!(e.contains("class_mix.car") && e.contains("parking lane of 2 m"), "{e}");
    // Parking needs a parking lane.
    let e = err(&scene(0.0), &with(ParkingConfig::default()));
    assert!(e.contains("traffic.parking") && e.contains("parking_lane_width_m"), "{e}");
}
