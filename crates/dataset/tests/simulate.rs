//! Datasets simulated end to end: round trip, determinism, resume, and radar Doppler against
//! the annotated motion.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use glam::{Vec2, Vec3};
use hilo_dataset::Dataset;
use hilo_dataset::simulate::{RigSensor, SceneId, SimulateConfig, Split, simulate_scene, write_dataset};
use hilo_raycast::{QueryRegion, Scene, World};
use hilo_sensor_models::{Catalog, SensorPose};
use std::path::Path;

fn rig(scene: &Scene) -> Vec<RigSensor> {
    let catalog = Catalog::default_catalog().unwrap();
    let m = &scene.mounts[0];
    let p = m.base + m.arm_dir * (0.5 * m.arm_length_m);
    let yaw = (-p.y).atan2(-p.x);
    let pos = p.extend(scene.ground.z_m + m.arm_height_m + 0.4);
    vec![
        RigSensor {
            channel: "LIDAR_0".into(),
            spec: catalog.get("lidar-16").unwrap().clone(),
            pose: SensorPose::new(pos, yaw, 10f32.to_radians(), 0.0),
        },
        RigSensor {
            channel: "RADAR_0".into(),
            spec: catalog.get("radar-4d").unwrap().clone(),
            pose: SensorPose::new(pos - Vec3::Z * 0.3, yaw, 8f32.to_radians(), 0.0),
        },
    ]
}

fn cfg() -> SimulateConfig {
    SimulateConfig {
        scenes: 3,
        seconds: 2.0,
        rate_hz: 10.0,
        val_scenes: 2,
        val_seconds: 2.0,
        val_rate_hz: 2.0,
        sweep_rate_hz: 10.0,
        seed: 5,
        ..SimulateConfig::default()
    }
}

fn train(index: usize) -> SceneId {
    SceneId { split: Split::Train, index }
}

fn world(scene: &Scene) -> World {
    World::build(scene, &QueryRegion::everything()).unwrap()
}

fn hashes(root: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((p.strip_prefix(root).unwrap().display().to_string(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn simulated_datasets_round_trip_are_deterministic_and_resume() {
    let scene = Scene::default_fixture().unwrap();
    let (w, r, c) = (world(&scene), rig(&scene), cfg().validate().unwrap());
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let sa = write_dataset(&scene, &w, &r, &c, a.path(), "v1.0-trainval", "test", &|_| {}).unwrap();
    // 3 training scenes of 20 key frames (10 Hz), 2 validation scenes of 4 (2 Hz).
    assert_eq!((sa.frames, sa.resumed_scenes), (68, 0));
    // Round trip: the reader gives back what the simulation produced.
    let ds = Dataset::open(a.path(), "v1.0-trainval").unwrap();
    assert_eq!(ds.tables.sample.len(), 68);
    assert_eq!(ds.split("train").unwrap(), ["scene-0000", "scene-0001", "scene-0002"]);
    assert_eq!(ds.split("val").unwrap(), ["val-0000", "val-0001"]);
    // Validation scenes record the radar's sweeps between key frames (10 Hz): 4 between each
    // pair of key frames, linked in time order, none for LiDAR.
    let sweeps: Vec<_> = ds.tables.sample_data.iter().filter(|s| !s.is_key_frame).collect();
    assert_eq!(sweeps.len(), 2 * 3 * 4);
    assert!(sweeps.iter().all(|s| s.filename.starts_with("sweeps/RADAR_0/val-")));
    let by_token: std::collections::HashMap<&str, _> =
        ds.tables.sample_data.iter().map(|s| (s.token.as_str(), s)).collect();
    let key = ds
        .tables
        .sample_data
        .iter()
        .filter(|s| s.is_key_frame && s.filename.contains("RADAR_0/val-0001"))
        .max_by_key(|s| s.timestamp)
        .unwrap();
    let mut cur = key;
    for _ in 0..4 {
        let prev = by_token[cur.prev.as_str()];
        assert!(
            !prev.is_key_frame && cur.timestamp - prev.timestamp == 100_000 && prev.sample_token == key.sample_token
        );
        cur = prev;
    }
    assert!(by_token[cur.prev.as_str()].is_key_frame);
    let direct = simulate_scene(&scene, &w, &r, &c, &train(1)).unwrap();
    let scene_row = ds.tables.scene.iter().find(|s| s.name == "scene-0001").unwrap();
    let first = ds.tables.sample.iter().find(|s| s.token == scene_row.first_sample_token).unwrap();
    assert_eq!(first.timestamp, direct.frames[0].timestamp_us);
    let anns: Vec<_> = ds.tables.sample_annotation.iter().filter(|x| x.sample_token == first.token).collect();
    assert_eq!(anns.len(), direct.frames[0].annotations.len());
    for (x, y) in anns.iter().zip(&direct.frames[0].annotations) {
        assert_eq!(x.translation, [y.box3.center.x as f64, y.box3.center.y as f64, y.box3.center.z as f64]);
        assert_eq!(x.num_lidar_pts, y.num_lidar_pts);
        assert_eq!(x.num_radar_pts, y.num_radar_pts);
    }
    let sd =
        ds.tables.sample_data.iter().find(|s| s.sample_token == first.token && s.filename.contains("LIDAR_0")).unwrap();
    let pts = ds.lidar_points(sd).unwrap();
    assert_eq!(pts.len(), direct.frames[0].lidar[0].len());
    assert!(pts.iter().zip(&direct.frames[0].lidar[0]).all(|(p, q)| p.x == q.x
        && p.y == q.y
        && p.z == q.z
        && p.intensity == q.intensity
        && p.ring == q.ring));
    assert!(anns.iter().any(|x| x.num_lidar_pts > 0) && anns.iter().any(|x| x.num_radar_pts > 0));
    // Same seed, same bytes.
    write_dataset(&scene, &w, &r, &c, b.path(), "v1.0-trainval", "test", &|_| {}).unwrap();
    let ha = hashes(a.path());
    assert_eq!(ha, hashes(b.path()));
    // Resume: lose a finished scene's rows and the tables, as a killed run would; rerun.
    std::fs::remove_file(b.path().join(".hilo/parts/scene-0002.json")).unwrap();
    std::fs::remove_file(b.path().join("v1.0-trainval/sample.json")).unwrap();
    let sb = write_dataset(&scene, &w, &r, &c, b.path(), "v1.0-trainval", "test", &|_| {}).unwrap();
    assert_eq!(sb.resumed_scenes, 4);
    assert_eq!(ha, hashes(b.path()));
    // Another seed is another dataset, and the folder refuses it.
    let other = SimulateConfig { seed: 6, ..c.clone().into_inner() }.validate().unwrap();
    let e = write_dataset(&scene, &w, &r, &other, b.path(), "v1.0-trainval", "test", &|_| {}).unwrap_err().to_string();
    assert!(e.contains("other settings"), "{e}");
    common::devkit_check(a.path());
}

/// Another training-traffic draw: the training scenes hold other traffic, the validation
/// scenes the same bytes (so detectors trained on either are scored on one test set), and a
/// draw out of range is refused by name.
#[test]
fn another_traffic_draw_changes_training_scenes_only() {
    use hilo_core::Check;
    let scene = Scene::default_fixture().unwrap();
    let (w, r) = (world(&scene), rig(&scene));
    let c0 = SimulateConfig { scenes: 1, val_scenes: 1, ..cfg() }.validate().unwrap();
    let c1 = SimulateConfig { train_traffic_draw: 1, ..c0.clone().into_inner() }.validate().unwrap();
    let boxes = |c: &hilo_core::Valid<SimulateConfig>, id: &SceneId| {
        let d = simulate_scene(&scene, &w, &r, c, id).unwrap();
        d.frames.iter().flat_map(|f| f.annotations.iter().map(|a| a.box3.center.to_array())).collect::<Vec<_>>()
    };
    let val = SceneId { split: Split::Val, index: 0 };
    assert_eq!(boxes(&c0, &val), boxes(&c1, &val));
    let (t0, t1) = (boxes(&c0, &train(0)), boxes(&c1, &train(0)));
    assert!(!t0.is_empty() && !t1.is_empty());
    assert_ne!(t0, t1);
    assert_eq!(c0.stream(&val), c1.stream(&val));
    assert!(c1.stream(&train(9_999)) > c0.stream(&SceneId { split: Split::Val, index: 9_999 }));
    let e = SimulateConfig { train_traffic_draw: 100, ..cfg() }.check().unwrap_err().to_string();
    assert!(e.contains("dataset.train_traffic_draw") && e.contains("100"), "{e}");
}

/// Not circular: the road users' velocity is taken from the finite difference of their
/// annotated positions (their true motion, frame to frame), not from the simulator's velocity
/// field. The annotated velocity equals it, and the radar's Doppler equals its projection on the
/// line of sight, within the radar's noise.
#[test]
fn radar_doppler_is_the_true_velocity_on_the_line_of_sight() {
    let scene = Scene::default_fixture().unwrap();
    let (w, r) = (world(&scene), rig(&scene));
    let c = SimulateConfig { scenes: 1, seconds: 3.0, ..cfg() }.validate().unwrap();
    let data = simulate_scene(&scene, &w, &r, &c, &train(0)).unwrap();
    // Each road user's centre per frame, and the centred difference at the frames between two.
    let mut track: std::collections::BTreeMap<u32, Vec<(f64, Vec2)>> = Default::default();
    for f in &data.frames {
        for a in &f.annotations {
            track.entry(a.instance).or_default().push((1e-6 * f.timestamp_us as f64, a.box3.center.truncate()));
        }
    }
    let true_velocity = |instance: u32, t: f64| -> Option<Vec2> {
        let tr = track.get(&instance)?;
        let k = tr.iter().position(|(s, _)| (s - t).abs() < 1e-6)?;
        let (prev, next) = (tr.get(k.checked_sub(1)?)?, tr.get(k + 1)?);
        Some((next.1 - prev.1) / (next.0 - prev.0) as f32)
    };
    let mut annotation_errs = Vec::new();
    for f in &data.frames {
        for a in &f.annotations {
            if let Some(v) = true_velocity(a.instance, 1e-6 * f.timestamp_us as f64) {
                annotation_errs.push((a.velocity_mps - v).length());
            }
        }
    }
    annotation_errs.sort_by(f32::total_cmp);
    assert!(annotation_errs.len() > 100);
    let (median, p95) = (annotation_errs[annotation_errs.len() / 2], annotation_errs[annotation_errs.len() * 95 / 100]);
    eprintln!("{} annotations: |v − Δx/Δt| median {median:.4}, p95 {p95:.4} m/s", annotation_errs.len());
    // Centred differences over ±1/rate_hz err by the acceleration's change and the turns'
    // curvature: millimetres per second in straight driving, a few cm/s in turns and stops.
    assert!(median <= 0.01 && p95 <= 0.25, "median {median}, p95 {p95}");
    let pose = r[1].pose;
    let rot = pose.rotation();
    let sigma = match &r[1].spec {
        hilo_sensor_models::SensorSpec::Radar(s) => s.velocity_noise_mps,
        _ => unreachable!(),
    };
    let mut errs = Vec::new();
    for f in &data.frames {
        for p in &f.radar[0] {
            let q = pose.position + rot * Vec3::new(p.x, p.y, p.z);
            // Detections inside exactly one (slightly grown) annotated box.
            let inside: Vec<_> = f
                .annotations
                .iter()
                .filter(|a| {
                    let l = a.box3.to_local(q);
                    let h = a.box3.half_extents() + Vec3::splat(0.3);
                    l.x.abs() <= h.x && l.y.abs() <= h.y && l.z.abs() <= h.z
                })
                .collect();
            if let [a] = inside.as_slice()
                && let Some(v) = true_velocity(a.instance, 1e-6 * f.timestamp_us as f64)
            {
                let los = (q - pose.position).normalize();
                let expected = Vec2::new(los.x, los.y).dot(v);
                errs.push((p.v_r_mps - expected).abs());
            }
        }
    }
    assert!(errs.len() > 50, "only {} radar detections on annotated road users", errs.len());
    errs.sort_by(f32::total_cmp);
    let median = errs[errs.len() / 2];
    let p95 = errs[errs.len() * 95 / 100];
    eprintln!("{} detections: |v_r - v·los| median {median:.3}, p95 {p95:.3} m/s (noise σ {sigma})", errs.len());
    // Within noise: averaging over a cell and the box's extent add little beyond σ.
    assert!(median <= sigma + 0.05, "median error {median} m/s for σ = {sigma}");
    assert!(p95 <= 3.0 * sigma + 0.3, "95th percentile error {p95} m/s for σ = {sigma}");
}

/// The velocity error floor of the validation split: at its 2 Hz the devkit's centred
/// difference (one-sided at a track's ends) spans a second of driving, yet a detector that knew
/// every road user's true velocity would score a car velocity error (AVE) of a few cm/s against
/// it, the default traffic's stops and turns included. So the metric leaves room for a velocity
/// error far below the 0.5 m/s that fused detectors aim at, and what a detector misses is its own.
#[test]
fn the_validation_velocity_definition_costs_a_perfect_detector_little() {
    let scene = Scene::default_fixture().unwrap();
    let w = world(&scene);
    let c = SimulateConfig { val_scenes: 4, ..SimulateConfig::default() }.validate().unwrap();
    let mut errs: Vec<(hilo_core::Class, bool, f32)> = Vec::new();
    for index in 0..4 {
        let data = simulate_scene(&scene, &w, &[], &c, &SceneId { split: Split::Val, index }).unwrap();
        let mut track: std::collections::BTreeMap<u32, Vec<(f64, Vec2)>> = Default::default();
        for f in &data.frames {
            for a in &f.annotations {
                track.entry(a.instance).or_default().push((1e-6 * f.timestamp_us as f64, a.box3.center.truncate()));
            }
        }
        for f in &data.frames {
            let t = 1e-6 * f.timestamp_us as f64;
            // Within the cars' evaluation range (50 m), as the metric scores them.
            for a in f.annotations.iter().filter(|a| a.box3.center.truncate().length() < 50.0) {
                let tr = &track[&a.instance];
                let k = tr.iter().position(|(s, _)| (s - t).abs() < 1e-6).unwrap();
                // Annotations of an instance are linked only from one key frame to the next.
                let prev = k.checked_sub(1).map(|j| tr[j]).filter(|p| t - p.0 < 0.75);
                let next = tr.get(k + 1).copied().filter(|n| n.0 - t < 0.75);
                let (first, last) = match (prev, next) {
                    (Some(p), Some(n)) => (p, n),
                    (Some(p), None) => (p, tr[k]),
                    (None, Some(n)) => (tr[k], n),
                    (None, None) => continue,
                };
                let v = (last.1 - first.1) / (last.0 - first.0) as f32;
                errs.push((a.class, prev.is_some() && next.is_some(), (v - a.velocity_mps).length()));
            }
        }
    }
    let mean = |keep: &dyn Fn(&(hilo_core::Class, bool, f32)) -> bool| {
        let e: Vec<f32> = errs.iter().filter(|e| keep(e)).map(|e| e.2).collect();
        (e.len(), e.iter().sum::<f32>() / e.len().max(1) as f32)
    };
    let (n, car) = mean(&|e| e.0 == hilo_core::Class::Car);
    let (n_ends, ends) = mean(&|e| e.0 == hilo_core::Class::Car && !e.1);
    let (n_ped, ped) = mean(&|e| e.0 == hilo_core::Class::Pedestrian);
    eprintln!(
        "cars: {n} annotations, mean error {car:.3} m/s ({n_ends} one-sided: {ends:.3}); pedestrians: {n_ped}, {ped:.3}"
    );
    assert!(n > 500 && n_ends > 10 && n_ped > 100, "{n} cars, {n_ends} one-sided, {n_ped} pedestrians");
    // 0.038 m/s for cars over the 20 validation scenes of the default profile.
    assert!(car <= 0.1 && ped <= 0.05, "car {car} m/s, pedestrian {ped} m/s");
    // One-sided differences at a track's ends err more (an acceleration over half a second).
    assert!(ends > car, "one-sided {ends} against all {car}");
}

/// Weather reaches the scans and nothing else: the same traffic is annotated in every condition;
/// in dense fog the LiDAR returns fewer points and none beyond the fog's maximum range; in a
/// cloudburst the radar reports fewer detections. A bad weather value is refused by its name.
#[test]
fn fog_and_rain_thin_the_scans_of_the_same_traffic() {
    use hilo_core::Check;
    use hilo_sensor_models::Weather;
    use hilo_sensor_models::weather::{fog_extinction_per_m, max_range_m};
    let scene = Scene::default_fixture().unwrap();
    let (w, r) = (world(&scene), rig(&scene));
    let run = |weather: Weather| {
        let c = SimulateConfig { scenes: 1, seconds: 1.0, weather, ..cfg() }.validate().unwrap();
        simulate_scene(&scene, &w, &r, &c, &train(0)).unwrap()
    };
    let clear = run(Weather::default());
    let fog = run(Weather { fog_visibility_m: Some(60.0), ..Weather::default() });
    let rain = run(Weather { rain_mm_h: 100.0, ..Weather::default() });
    let boxes = |d: &hilo_dataset::writer::SceneData| -> Vec<String> {
        d.frames.iter().flat_map(|f| f.annotations.iter().map(|a| format!("{:?}", a.box3))).collect()
    };
    assert_eq!(boxes(&clear), boxes(&fog));
    assert_eq!(boxes(&clear), boxes(&rain));
    let lidar = |d: &hilo_dataset::writer::SceneData| d.frames.iter().map(|f| f.lidar[0].len()).sum::<usize>();
    let radar = |d: &hilo_dataset::writer::SceneData| d.frames.iter().map(|f| f.radar[0].len()).sum::<usize>();
    let clear_reach = match &r[0].spec {
        hilo_sensor_models::SensorSpec::Lidar(l) => l.max_range_m,
        _ => unreachable!(),
    };
    let reach = max_range_m(clear_reach, fog_extinction_per_m(60.0));
    let far = fog
        .frames
        .iter()
        .flat_map(|f| f.lidar[0].iter())
        .map(|p| Vec3::new(p.x, p.y, p.z).length())
        .fold(0.0, f32::max);
    assert!(far <= reach + 1e-3, "a return at {far} m, beyond the fog's {reach} m");
    assert!(lidar(&fog) < lidar(&clear) * 9 / 10, "fog {} vs clear {}", lidar(&fog), lidar(&clear));
    assert!(radar(&rain) < radar(&clear), "rain {} vs clear {}", radar(&rain), radar(&clear));
    let e = SimulateConfig { weather: Weather { rain_mm_h: f32::NAN, ..Weather::default() }, ..cfg() }.check();
    assert!(e.unwrap_err().to_string().contains("dataset.weather.rain_mm_h"));
}

/// The traffic alone, stepped without sensors, holds exactly the road users a rig's dataset
/// annotates at every key frame (same instances, classes and boxes), in both splits and with
/// radar sweeps between key frames: the rig does not move the traffic.
#[test]
fn key_frame_states_are_the_annotated_road_users() {
    let scene = Scene::default_fixture().unwrap();
    let w = world(&scene);
    let r = rig(&scene);
    let c = cfg().validate().unwrap();
    for id in [train(0), SceneId { split: Split::Val, index: 1 }] {
        let data = simulate_scene(&scene, &w, &r, &c, &id).unwrap();
        let states = hilo_dataset::simulate::key_frame_states(&scene, &c, &id).unwrap();
        assert_eq!(states.len(), data.frames.len(), "{}", id.name());
        let mut seen = 0;
        for (frame, st) in data.frames.iter().zip(&states) {
            let a: Vec<_> = frame.annotations.iter().map(|a| (a.instance, a.class, a.box3)).collect();
            let b: Vec<_> = st.iter().map(|s| (s.id, s.class, s.box3)).collect();
            assert_eq!(a, b, "{}", id.name());
            seen += a.len();
        }
        assert!(seen > 0, "{}: no road user in any key frame", id.name());
    }
}

/// A rig with a calibration error scans from a true pose drawn once per seed and channel, and
/// records the nominal one: the same traffic, other points, exactly the points a scan from the
/// true pose gives; an error of zero is no error; the written calibration is the nominal pose.
#[test]
fn a_miscalibrated_rig_scans_from_its_true_pose_and_records_the_nominal_one() {
    use hilo_core::Check;
    use hilo_sensor_models::CalibrationError;
    let scene = Scene::default_fixture().unwrap();
    let (w, r) = (world(&scene), rig(&scene));
    let base = SimulateConfig { scenes: 1, seconds: 0.5, val_scenes: 1, val_seconds: 1.0, ..cfg() };
    let error = CalibrationError { rotation_deg: 0.2, translation_m: 0.02 };
    let exact = base.clone().validate().unwrap();
    let off = SimulateConfig { calibration_error: Some(error), ..base.clone() }.validate().unwrap();
    let zero = SimulateConfig {
        calibration_error: Some(CalibrationError { rotation_deg: 0.0, translation_m: 0.0 }),
        ..base.clone()
    }
    .validate()
    .unwrap();
    let (a, b, z) = (
        simulate_scene(&scene, &w, &r, &exact, &train(0)).unwrap(),
        simulate_scene(&scene, &w, &r, &off, &train(0)).unwrap(),
        simulate_scene(&scene, &w, &r, &zero, &train(0)).unwrap(),
    );
    let boxes = |d: &hilo_dataset::writer::SceneData| {
        d.frames.iter().flat_map(|f| f.annotations.iter().map(|x| x.box3.center.to_array())).collect::<Vec<_>>()
    };
    assert_eq!(boxes(&a), boxes(&b));
    assert_eq!(a.frames[0].lidar, z.frames[0].lidar);
    assert_ne!(a.frames[0].lidar, b.frames[0].lidar);
    // The points are a scan from the true pose: a draw within a few sigma of the nominal one,
    // the same for every scene (and for the seed's other datasets).
    let truth = hilo_dataset::simulate::true_pose(&off, &r[0]);
    assert_eq!(truth, hilo_dataset::simulate::true_pose(&off, &r[0]));
    let moved = (truth.position - r[0].pose.position).length();
    assert!(moved > 0.0 && moved < 6.0 * 0.02 * 3f32.sqrt(), "{moved}");
    let turned = [truth.yaw - r[0].pose.yaw, truth.pitch - r[0].pose.pitch, truth.roll - r[0].pose.roll];
    assert!(turned.iter().all(|d| d.abs() < 6.0 * 0.2f32.to_radians()) && turned.iter().any(|d| *d != 0.0));
    assert_ne!(truth, hilo_dataset::simulate::true_pose(&SimulateConfig { seed: 6, ..(*off).clone() }, &r[0]));
    let d = tempfile::tempdir().unwrap();
    write_dataset(&scene, &w, &r, &off, d.path(), "v1.0-trainval", "test", &|_| {}).unwrap();
    let ds = Dataset::open(d.path(), "v1.0-trainval").unwrap();
    let p = r[0].pose.position;
    let recorded: Vec<[f64; 3]> = ds.tables.calibrated_sensor.iter().map(|c| c.translation).collect();
    assert!(recorded.contains(&[p.x as f64, p.y as f64, p.z as f64]), "the nominal pose is recorded: {recorded:?}");
    let e = SimulateConfig { calibration_error: Some(CalibrationError { rotation_deg: 20.0, ..error }), ..base }
        .check()
        .unwrap_err()
        .to_string();
    assert!(e.contains("dataset.calibration_error.rotation_deg") && e.contains("20"), "{e}");
    // Stage and study hashes are taken over the Debug form: without the error it is as before
    // the field existed, and with it, it differs.
    let plain = format!("{:?}", SimulateConfig::default());
    assert!(
        !plain.contains("calibration_error")
            && plain.ends_with("weather: Weather { rain_mm_h: 0.0, fog_visibility_m: None } }"),
        "{plain}"
    );
    assert!(format!("{off:?}").contains("calibration_error"));
}

/// A rig with a time-synchronisation error samples the road users at each sensor's own clock
/// offset (drawn once per seed and channel) and records the common time; with a rolling shutter
/// each LiDAR column meets them at its own time in the sweep. The points are exactly a scan of
/// the key frame's road users moved by the sensor's offset and moving for the sweep; the
/// annotations stay where the road users are at the recorded time.
#[test]
fn an_unsynchronised_rig_scans_each_sensor_at_its_own_instant() {
    use hilo_core::Check;
    use hilo_dataset::simulate::{clock_offset_s, derive_seed, key_frame_states, sweep_span_s};
    use hilo_raycast::ActorSet;
    use hilo_sensor_models::{SensorSpec, simulate_lidar, simulate_radar};
    let scene = Scene::default_fixture().unwrap();
    let (w, r) = (world(&scene), rig(&scene));
    let base =
        SimulateConfig { scenes: 1, seconds: 0.5, val_scenes: 1, val_seconds: 1.0, annotate_radius_m: 1e6, ..cfg() };
    let exact = base.clone().validate().unwrap();
    let skewed =
        SimulateConfig { time_sync_error_s: Some(0.02), rolling_shutter: true, ..base.clone() }.validate().unwrap();
    let (a, b) = (
        simulate_scene(&scene, &w, &r, &exact, &train(0)).unwrap(),
        simulate_scene(&scene, &w, &r, &skewed, &train(0)).unwrap(),
    );
    let boxes = |d: &hilo_dataset::writer::SceneData| {
        d.frames.iter().flat_map(|f| f.annotations.iter().map(|x| x.box3.center.to_array())).collect::<Vec<_>>()
    };
    assert_eq!(boxes(&a), boxes(&b), "the annotations keep the recorded time");
    assert_ne!(a.frames[0].lidar, b.frames[0].lidar);
    // Offsets: one draw per channel and seed, within a few sigma, and none without the error.
    let offsets: Vec<f32> = r.iter().map(|s| clock_offset_s(&skewed, s)).collect();
    assert!(offsets.iter().all(|d| *d != 0.0 && d.abs() < 6.0 * 0.02), "{offsets:?}");
    assert_ne!(offsets[0], offsets[1]);
    assert_eq!(offsets, r.iter().map(|s| clock_offset_s(&skewed, s)).collect::<Vec<_>>());
    assert!(r.iter().all(|s| clock_offset_s(&exact, s) == 0.0));
    let span = sweep_span_s(&skewed, &r);
    assert_eq!((span, sweep_span_s(&exact, &r)), (0.05, 0.0), "a 20 Hz LiDAR's rotation, or frozen");
    // The oracle: scan the key frame's road users moved by each sensor's offset.
    let states = key_frame_states(&scene, &skewed, &train(0)).unwrap();
    let actors: Vec<hilo_raycast::Actor> = states[0].iter().map(|s| s.actor()).collect();
    let (mut li, mut ri) = (0, 0);
    for (k, s) in r.iter().enumerate() {
        let set = ActorSet::moving(actors.iter().map(|x| x.moved(offsets[k])).collect(), span).unwrap();
        let noise = derive_seed(skewed.seed, &[2, skewed.stream(&train(0)), 0, k as u64]);
        match &s.spec {
            SensorSpec::Lidar(l) => {
                let want = simulate_lidar(l, &s.pose, &w, Some(&set), noise).unwrap().points;
                assert_eq!(b.frames[0].lidar[li], want, "{}", s.channel);
                li += 1;
            }
            SensorSpec::Radar(x) => {
                let want = simulate_radar(x, &s.pose, &w, Some(&set), noise).unwrap().points;
                assert_eq!(b.frames[0].radar[ri], want, "{}", s.channel);
                ri += 1;
            }
        }
    }
    let e = SimulateConfig { time_sync_error_s: Some(2.0), ..base }.check().unwrap_err().to_string();
    assert!(e.contains("dataset.time_sync_error_s") && e.contains('2'), "{e}");
    let plain = format!("{:?}", SimulateConfig::default());
    assert!(
        !plain.contains("time_sync")
            && !plain.contains("rolling_shutter")
            && !plain.contains("vehicle_paint")
            && !plain.contains("foliage"),
        "{plain}"
    );
    // Foliage in wind reaches the LiDARs' scans (the fixture's crowns), and is checked.
    let windy = SimulateConfig {
        foliage: Some(hilo_sensor_models::Foliage { gap_probability: 0.3, sway_m: 0.1 }),
        ..SimulateConfig { time_sync_error_s: None, rolling_shutter: false, ..(*exact).clone() }
    }
    .validate()
    .unwrap();
    let w2 = simulate_scene(&scene, &w, &r, &windy, &train(0)).unwrap();
    assert_ne!(w2.frames[0].lidar, a.frames[0].lidar);
    assert_eq!(w2.frames[0].radar, a.frames[0].radar, "the radar sees foliage as before");
    for (f, field) in [(f32::NAN, "gap_probability"), (1.0, "gap_probability")] {
        let bad = SimulateConfig {
            foliage: Some(hilo_sensor_models::Foliage { gap_probability: f, sway_m: 0.1 }),
            ..SimulateConfig::default()
        };
        let e = bad.check().unwrap_err().to_string();
        assert!(e.contains(&format!("dataset.foliage.{field}")), "{e}");
    }
    assert!(format!("{skewed:?}").contains("time_sync_error_s: 0.02, rolling_shutter: true"));
}

/// `lidar_beam_width = false` casts a wide-beam LiDAR as rays of no width: its scans equal, to
/// the bit, those of the same entry without its `beam`; left unset or true, the width is cast
/// (other points), and the setting enters the fingerprint only when given.
#[test]
fn a_thin_beam_setting_scans_as_the_entry_without_its_beam() {
    let scene = Scene::default_fixture().unwrap();
    let w = world(&scene);
    let beam = hilo_sensor_models::Beam {
        horizontal_mrad: 3.0,
        vertical_mrad: 1.5,
        returns: hilo_sensor_models::ReturnMode::Strongest,
        separation_m: 1.0,
        rings: 2,
    };
    let with_beam = |b: Option<hilo_sensor_models::Beam>| -> Vec<RigSensor> {
        rig(&scene)
            .into_iter()
            .map(|mut s| {
                if let hilo_sensor_models::SensorSpec::Lidar(l) = &mut s.spec {
                    l.beam = b;
                    l.detection_range = Some(hilo_sensor_models::DetectionRange { range_m: 100.0, reflectivity: 0.8 });
                }
                s
            })
            .collect()
    };
    let (wide, none) = (with_beam(Some(beam)), with_beam(None));
    let base = SimulateConfig { scenes: 1, seconds: 0.2, val_scenes: 1, val_seconds: 1.0, ..cfg() };
    let run = |rig: &[RigSensor], width: Option<bool>| {
        let c = SimulateConfig { lidar_beam_width: width, ..base.clone() }.validate().unwrap();
        simulate_scene(&scene, &w, rig, &c, &train(0)).unwrap()
    };
    let thin = run(&none, None);
    assert_eq!(run(&wide, Some(false)).frames[0].lidar, thin.frames[0].lidar);
    let cast = run(&wide, None);
    assert_ne!(cast.frames[0].lidar, thin.frames[0].lidar);
    assert_eq!(run(&wide, Some(true)).frames[0].lidar, cast.frames[0].lidar);
    assert_eq!(cast.frames[0].radar, thin.frames[0].radar, "the radar casts as before");
    assert!(!format!("{base:?}").contains("lidar_beam_width"));
    let off = SimulateConfig { lidar_beam_width: Some(false), ..base };
    assert!(format!("{off:?}").contains("lidar_beam_width: false"));
}
