//! The validation's placement set and its occupancy predictor, on a coarse version of the
//! default scene.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_study::Study;
use hilo_study::validation::ValidationSettings;
use hilo_study::validation::set::{PAPER_OBJECTIVE, placement_set};

const COARSE: &str = r#"
[placement]
cell_m = 3.0
time_limit_s = 5.0
[placement.candidates]
pole_step_m = 1.5
arm_step_m = 3.0
lidar_yaw_offsets_deg = [0.0]
radar_yaw_offsets_deg = [-30.0, 30.0]

[dataset]
scenes = 1
seconds = 1.5
val_scenes = 2
val_seconds = 2.0
val_rate_hz = 2.0

[[configurations]]
name = "2x lidar-16 + radar"
sensors = { "lidar-16" = 2, "radar-4d" = 1 }

[[configurations]]
name = "1x lidar-32 + radar"
sensors = { "lidar-32" = 1, "radar-4d" = 1 }
"#;

fn settings() -> ValidationSettings {
    ValidationSettings {
        placements: 26,
        lidar_tilts_deg: vec![5.0, 15.0],
        radar_tilts_deg: vec![4.0, 12.0],
        ..ValidationSettings::default()
    }
}

/// Same seed, same set; it holds every kind of placement, LiDAR-only rigs (for which the
/// paper's objective is undefined, and only for them), and poses at more than one tilt.
#[test]
fn the_placement_set_is_deterministic_and_spans_kinds_tilts_and_modalities() {
    let dir = tempfile::tempdir().unwrap();
    let study = Study::parse(COARSE, dir.path(), "coarse.toml").unwrap();
    let a = placement_set(&study, &settings(), &mut |_| {}).unwrap();
    let b = placement_set(&study, &settings(), &mut |_| {}).unwrap();
    assert_eq!(serde_json::to_string(&a).unwrap(), serde_json::to_string(&b).unwrap());
    assert!(a.len() >= 26, "{}", a.len());
    for kind in ["optimum", "greedy", "perturbed", "random"] {
        assert!(a.iter().any(|m| m.kind == kind), "no {kind} placement");
    }
    let radar = |m: &hilo_study::validation::set::Member| {
        m.placement.sensors.iter().any(|s| s.modality == hilo_placement_ip::Modality::Radar)
    };
    assert!(a.iter().any(|m| !radar(m)), "no LiDAR-only rig");
    // Rigs of the sizes a budget buys, and four LiDARs without radars.
    let sizes: std::collections::BTreeSet<usize> = a.iter().map(|m| m.placement.sensors.len()).collect();
    assert!(sizes.iter().any(|&n| (5..=8).contains(&n)) && sizes.contains(&8), "{sizes:?}");
    assert!(a.iter().any(|m| !radar(m) && m.placement.sensors.len() == 4), "no 4-LiDAR rig");
    for m in &a {
        assert_eq!(m.predictors[PAPER_OBJECTIVE].is_some(), radar(m), "{}", m.slug);
        assert!((1..=9).contains(&m.placement.sensors.len()));
    }
    let tilts: std::collections::BTreeSet<i32> =
        a.iter().flat_map(|m| m.placement.sensors.iter().map(|s| s.pitch_deg.round() as i32)).collect();
    assert!(tilts.len() >= 2, "{tilts:?}");
    // Another seed draws other random and perturbed placements.
    let c = placement_set(&study, &ValidationSettings { seed: 1, ..settings() }, &mut |_| {}).unwrap();
    assert_ne!(serde_json::to_string(&a).unwrap(), serde_json::to_string(&c).unwrap());
}

/// The occupancy predictor (the simulator's per-ray count of points on each road user) against
/// a brute-force count of the LiDAR points inside each annotated box, on a small dataset.
#[test]
fn occupancy_agrees_with_a_brute_force_count_of_points_in_boxes() {
    use hilo_detector::data::{LoadOptions, load_split};
    let dir = tempfile::tempdir().unwrap();
    let study = Study::parse(COARSE, dir.path(), "coarse.toml").unwrap();
    let set = placement_set(&study, &settings(), &mut |_| {}).unwrap();
    let m = set.iter().find(|m| m.kind == "optimum").unwrap();
    let ppath = dir.path().join("p.json");
    std::fs::write(&ppath, m.placement.to_json().unwrap()).unwrap();
    let data = dir.path().join("data");
    hilo_study::rig::simulate(&study, &m.placement, &ppath, &study.dataset, &data, "v1.0-trainval", &|_| {}).unwrap();
    let ds = hilo_dataset::Dataset::open(&data, "v1.0-trainval").unwrap();
    let cfg = hilo_eval::DetectionConfig::default();
    // k where shares are neither 0 nor 1, so that a miscount shows.
    let k = 25;
    let occ = hilo_study::validation::occupancy::occupancy(&ds, "val", &cfg, k).unwrap();
    // Brute force: points within each box (grown by 0.15 m sideways and on top; from 0.1 m above
    // its bottom, so the ground under it does not count).
    // Every box a sensor hit, as occupancy counts them (radar-only ones too).
    let all_boxes = LoadOptions { radar_only_boxes: true, ..LoadOptions::default() };
    let (frames, _) = load_split(&ds, "val", &all_boxes).unwrap();
    let mut brute: std::collections::BTreeMap<String, (usize, usize)> = Default::default();
    for f in &frames {
        for b in &f.boxes {
            let class = hilo_core::Class::ALL[b.class].name();
            let range = cfg.class_range[class];
            if (b.center[0] as f64).hypot(b.center[1] as f64) >= range {
                continue;
            }
            let (s, c) = b.yaw.sin_cos();
            let inside = f
                .lidar
                .iter()
                .filter(|p| {
                    let (dx, dy) = (p[0] - b.center[0], p[1] - b.center[1]);
                    let (along, across) = (c * dx + s * dy, -s * dx + c * dy);
                    let dz = p[2] - b.center[2];
                    along.abs() <= b.wlh[1] / 2.0 + 0.15
                        && across.abs() <= b.wlh[0] / 2.0 + 0.15
                        && dz >= -b.wlh[2] / 2.0 + 0.1
                        && dz <= b.wlh[2] / 2.0 + 0.15
                })
                .count();
            let e = brute.entry(class.to_owned()).or_default();
            e.0 += 1;
            e.1 += usize::from(inside >= k as usize);
        }
    }
    assert!(!occ.classes.is_empty());
    assert!(occ.classes.values().any(|c| (0.1..0.9).contains(&(c.hit as f64 / c.road_users as f64))), "{occ:?}");
    for (class, o) in &occ.classes {
        let (n, hit) = brute[class];
        assert_eq!(n, o.road_users, "{class}: the same road users in range");
        let (a, b) = (o.hit as f64 / n as f64, hit as f64 / n as f64);
        eprintln!("{class}: {} road users, hit share {a:.3} (per-ray count) vs {b:.3} (points in boxes)", n);
        assert!((a - b).abs() <= 0.05, "{class}: {a} vs {b}");
    }
}

/// A set's placement predictors computed again (as `hilo validate --refit` does) are the same
/// values; the two-view coverage lies between half the coverage and the coverage, and is
/// exactly half for a rig with one sensor of the modality (one sensor is one view); coverage at
/// twice the threshold (uncapped per sensor) is never below the two-view coverage.
#[test]
fn predictors_recompute_to_the_same_values_and_two_views_need_two_sensors() {
    use hilo_study::validation::set::{
        LIDAR_DENSE, LIDAR_DENSE_USERS, LIDAR_SATURATED, LIDAR_SATURATED_USERS, LIDAR_TWO_VIEWS, LIDAR_TWO_VIEWS_USERS,
        RADAR_DENSE, RADAR_DENSE_USERS, RADAR_SATURATED, RADAR_SATURATED_USERS, RADAR_TWO_VIEWS, RADAR_TWO_VIEWS_USERS,
        recompute,
    };
    let dir = tempfile::tempdir().unwrap();
    let study = Study::parse(COARSE, dir.path(), "coarse.toml").unwrap();
    let set = placement_set(&study, &settings(), &mut |_| {}).unwrap();
    let again = recompute(&study, &settings(), &set).unwrap();
    assert_eq!(serde_json::to_string(&set).unwrap(), serde_json::to_string(&again).unwrap());
    // Sensors are matched by pose, not by candidate number (which another build's sampling
    // may give otherwise): a set whose numbers are all off by one recomputes the same.
    let mut renumbered = set.clone();
    renumbered.iter_mut().flat_map(|m| m.placement.sensors.iter_mut()).for_each(|s| s.candidate_id += 1);
    let again = recompute(&study, &settings(), &renumbered).unwrap();
    for (a, b) in set.iter().zip(&again) {
        assert_eq!(a.predictors, b.predictors, "{}", a.slug);
    }
    use hilo_study::validation::set::{LIDAR_BEAMS, LIDAR_MOUNTS, LIDARS};
    for m in &set {
        // The baselines that need no model: count, structures and beams of the LiDARs.
        let lidars: Vec<_> =
            m.placement.sensors.iter().filter(|s| s.modality == hilo_placement_ip::Modality::Lidar).collect();
        let structures: std::collections::BTreeSet<&str> = lidars.iter().map(|s| s.structure.as_str()).collect();
        let beams: u32 = lidars.iter().map(|s| study.catalog.lidar(&s.ty).unwrap().beams).sum();
        assert_eq!(m.predictors[LIDARS], Some(lidars.len() as f64), "{}", m.slug);
        assert_eq!(m.predictors[LIDAR_MOUNTS], Some(structures.len() as f64), "{}", m.slug);
        assert_eq!(m.predictors[LIDAR_BEAMS], Some(f64::from(beams)), "{}", m.slug);
        // The same relations hold over the regions of interest and over the traffic's road users.
        for (one, two, dense, modality) in [
            (LIDAR_SATURATED, LIDAR_TWO_VIEWS, LIDAR_DENSE, hilo_placement_ip::Modality::Lidar),
            (RADAR_SATURATED, RADAR_TWO_VIEWS, RADAR_DENSE, hilo_placement_ip::Modality::Radar),
            (LIDAR_SATURATED_USERS, LIDAR_TWO_VIEWS_USERS, LIDAR_DENSE_USERS, hilo_placement_ip::Modality::Lidar),
            (RADAR_SATURATED_USERS, RADAR_TWO_VIEWS_USERS, RADAR_DENSE_USERS, hilo_placement_ip::Modality::Radar),
        ] {
            let (c1, c2, d) = (m.predictors[one].unwrap(), m.predictors[two].unwrap(), m.predictors[dense].unwrap());
            assert!(c2 <= c1 + 1e-12 && c2 >= c1 / 2.0 - 1e-12, "{}: {c1} {c2}", m.slug);
            assert!(d >= c2 - 1e-12 && d <= 1.0 + 1e-12, "{}: {c2} {d}", m.slug);
            if m.placement.sensors.iter().filter(|s| s.modality == modality).count() == 1 {
                assert!((c2 - c1 / 2.0).abs() < 1e-12, "{}: {c1} {c2}", m.slug);
            }
        }
    }
    assert!(
        set.iter()
            .any(|m| m.predictors[LIDAR_TWO_VIEWS].unwrap() > m.predictors[LIDAR_SATURATED].unwrap() / 2.0 + 0.01),
        "some rig sees targets twice"
    );
    assert!(
        set.iter().any(|m| m.predictors[LIDAR_DENSE].unwrap() > m.predictors[LIDAR_TWO_VIEWS].unwrap() + 0.01),
        "some rig sees targets densely with fewer views"
    );
    // Weighting by road users changes the figures (lanes and crossings are not the regions'
    // weights), and a rig sees some road users.
    assert!(
        set.iter()
            .any(|m| (m.predictors[LIDAR_SATURATED_USERS].unwrap() - m.predictors[LIDAR_SATURATED].unwrap()).abs()
                > 0.01)
    );
    assert!(set.iter().all(|m| m.predictors[LIDAR_SATURATED_USERS].unwrap() > 0.0));
    // A placement drawn on another scene is refused by name.
    let mut moved = set.clone();
    moved[0].placement.scene_hash = "other".into();
    let e = recompute(&study, &settings(), &moved).unwrap_err().to_string();
    assert!(e.contains(&set[0].slug), "{e}");
}

/// The validation trains as the study would: `[detector_patch]` and `[train_schedule]` reach
/// every training (and its run folder, so a patched validation never reuses a plain run),
/// except the sample count, which stays the validation's budget 2b; the placement set is the
/// same one.
#[test]
fn the_validation_trains_with_the_studys_patch_and_schedule() {
    let dir = tempfile::tempdir().unwrap();
    let mut registry = hilo_detector::Registry::with_builtin();
    hilo_fusion_early::register(&mut registry).unwrap();
    let plan = |text: &str, out: &str| {
        let study = Study::parse(text, dir.path(), "coarse.toml").unwrap();
        let profile = hilo_study::profile(hilo_study::ProfileName::Tiny, &study, &registry).unwrap();
        hilo_study::validation::plan(&study, &registry, &profile, &settings(), &dir.path().join(out), &mut |_| {})
            .unwrap()
    };
    let plain = plan(COARSE, "plain");
    let extra =
        "\n[detector_patch]\nvelocity_weight = 2.0\n\n[train_schedule]\nbatch = 4\nlr_max = 0.012\nsamples = 99\n";
    let patched = plan(&format!("{COARSE}{extra}"), "patched");
    assert_eq!(serde_json::to_string(&plain.members).unwrap(), serde_json::to_string(&patched.members).unwrap());
    assert_eq!(patched.jobs.len(), plain.jobs.len());
    assert!(!patched.jobs.is_empty());
    for (p, q) in patched.jobs.iter().zip(&plain.jobs) {
        assert_eq!((p.detector.velocity_weight, p.train.batch, p.train.lr_max), (2.0, 4, 0.012), "{}", p.id);
        assert_eq!(p.train.samples, 2 * settings().samples, "{}: the validation's budget, not the schedule's", p.id);
        assert_eq!(p.train.keep, vec![(settings().samples / 4) * 4]);
        assert_ne!(q.detector.velocity_weight, 2.0);
        assert_ne!(p.run.file_name(), q.run.file_name(), "{}", p.id);
    }
}
