//! Placement on the default scene: the physics of coverage and visibility, and bad inputs.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec2;
use hilo_placement_ip::coverage::lidar_hit_targets;
use hilo_placement_ip::pipeline::{PlacementConfig, prepare};
use hilo_placement_ip::{CandidateConfig, roi_targets, sample_candidates};
use hilo_raycast::{QueryRegion, Scene, World};
use hilo_sensor_models::{Catalog, SensorPose};

#[test]
fn at_one_pose_coverage_does_not_fall_with_beam_count() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let targets = roi_targets(&scene, 1.0).unwrap();
    let catalog = Catalog::default_catalog().unwrap();
    for (pos, yaw) in [(glam::Vec3::new(13.0, 16.3, 6.0), -2.2f32), (glam::Vec3::new(-12.8, -16.3, 4.5), 0.9)] {
        let pose = SensorPose::new(pos, yaw, 10f32.to_radians(), 0.0);
        let cov: Vec<usize> = ["lidar-16", "lidar-32", "lidar-64"]
            .iter()
            .map(|n| {
                lidar_hit_targets(&scene, &world, &targets, 1.0, &[(catalog.lidar(n).unwrap().clone(), pose)])
                    .unwrap()
                    .len()
            })
            .collect();
        assert!(cov[0] <= cov[1] && cov[1] <= cov[2], "{pos}: {cov:?}");
        assert!(cov[0] > 100, "{cov:?}");
    }
}

#[test]
fn visibility_grows_with_resolution_and_candidates_number_about_six_hundred() {
    let scene = Scene::default_fixture().unwrap();
    let catalog = Catalog::default_catalog().unwrap();
    let mut cfg = PlacementConfig { cell_m: 3.0, ..PlacementConfig::default() };
    cfg.candidates.pole_step_m = 1.5;
    let full = sample_candidates(&scene, &CandidateConfig::default()).unwrap();
    assert!((550..=700).contains(&full.len()), "{} candidates", full.len());
    let types: Vec<String> = ["lidar-16", "lidar-32", "lidar-64", "radar-4d"].iter().map(|s| s.to_string()).collect();
    let prep = prepare(&scene, &catalog, &types, &cfg.clone().validate().unwrap()).unwrap();
    let total = |t: &str| prep.visibility[t].rows.iter().flatten().map(|(_, v)| *v as f64).sum::<f64>();
    let (v16, v32, v64) = (total("lidar-16"), total("lidar-32"), total("lidar-64"));
    assert!(v16 < v32 && v32 <= v64, "{v16} {v32} {v64}");
    // Everything in [0, 1], sparse rows sorted by target.
    for v in prep.visibility.values() {
        for row in &v.rows {
            assert!(row.windows(2).all(|w| w[0].0 < w[1].0));
            assert!(row.iter().all(|(_, x)| *x > 0.0 && *x <= 1.0));
        }
    }
}

#[test]
fn targets_are_weighted_by_the_heaviest_roi() {
    let scene = Scene::default_fixture().unwrap();
    let t = roi_targets(&scene, 1.0).unwrap();
    assert!((4000..6000).contains(&t.len()), "{}", t.len());
    let centre = t.iter().find(|x| (x.center - Vec2::new(0.5, 0.5)).length() < 0.8).unwrap();
    assert_eq!(centre.weight, 3.0);
    assert!(t.iter().any(|x| x.weight == 1.0));
    assert!(roi_targets(&scene, 0.0).is_err());
}

#[test]
fn a_pole_outside_the_scene_is_refused() {
    let mut cfg = Scene::default_fixture().unwrap().config;
    cfg.signal_poles[0].position = [400.0, 0.0];
    let scene = Scene::from_config(cfg, std::path::Path::new("."), std::path::Path::new("s.toml")).unwrap();
    let e = sample_candidates(&scene, &CandidateConfig::default()).unwrap_err().to_string();
    assert!(e.contains("NE") && e.contains("outside"), "{e}");
}

/// Tilt is a decision variable: every (yaw, tilt) pair of a mount is a candidate, a placement
/// chosen among them keeps its tilt through the placement file, and a LiDAR-only configuration
/// is placed for its own objective (LiDAR coverage), which is positive.
#[test]
fn tilt_candidates_round_trip_through_a_placement_file() {
    use hilo_placement_ip::greedy::greedy;
    use hilo_placement_ip::pipeline::{instance, solve_from};
    use hilo_placement_ip::{Limit, PlacedSensor, Placement};
    let scene = Scene::default_fixture().unwrap();
    let catalog = Catalog::default_catalog().unwrap();
    let mut cfg = PlacementConfig { cell_m: 3.0, ..PlacementConfig::default() };
    cfg.candidates.pole_step_m = 1.5;
    cfg.candidates.lidar_tilts_deg = vec![4.0, 16.0];
    cfg.candidates.lidar_yaw_offsets_deg = vec![0.0];
    let one = sample_candidates(&scene, &CandidateConfig { lidar_tilts_deg: vec![4.0], ..cfg.candidates.clone() })
        .unwrap()
        .len();
    let cands = sample_candidates(&scene, &cfg.candidates).unwrap();
    let lidar = |c: &&hilo_placement_ip::Candidate| c.modality == hilo_placement_ip::Modality::Lidar;
    assert_eq!(cands.iter().filter(lidar).count(), 2 * (one - cands.iter().filter(|c| !lidar(c)).count()));
    let tilts: std::collections::BTreeSet<i32> =
        cands.iter().filter(lidar).map(|c| c.pose.pitch.to_degrees().round() as i32).collect();
    assert_eq!(tilts.into_iter().collect::<Vec<_>>(), vec![4, 16]);
    let types = vec!["lidar-16".to_string()];
    let prep = prepare(&scene, &catalog, &types, &cfg.clone().validate().unwrap()).unwrap();
    let inst = instance(&prep, &catalog, &types, cfg.p_min).unwrap();
    let limit = Limit::Counts(vec![2]);
    let g = greedy(&inst, &limit);
    let out = solve_from(&inst, &limit, 60.0, &g).unwrap();
    assert!(out.objective > 0.0 && out.proven_optimal, "{out:?}");
    let sensors: Vec<PlacedSensor> = out
        .selection
        .iter()
        .map(|&o| {
            let c = &prep.candidates[inst.options[o].candidate as usize];
            PlacedSensor::new("lidar-16", c.modality, c.id, &c.structure, c.pose)
        })
        .collect();
    let p = Placement {
        name: "2x lidar-16".into(),
        sensors,
        objective: out.objective,
        bound: out.bound,
        gap: out.gap,
        proven_optimal: out.proven_optimal,
        solve_seconds: out.solve_seconds,
        method: out.method.clone(),
        solved: true,
        greedy_objective: g.objective,
        central_coverage: 0.0,
        lidar_radar_overlap: 0.0,
        cost_usd: inst.cost(&out.selection),
        targets: prep.targets.len(),
        candidates: prep.candidates.len(),
        scene_hash: "s".into(),
        catalog_hash: "c".into(),
        prediction: None,
    };
    let back = Placement::from_json(&p.to_json().unwrap(), std::path::Path::new("p.json")).unwrap();
    assert_eq!(back, p);
    for (s, &o) in back.sensors.iter().zip(&out.selection) {
        let c = &prep.candidates[inst.options[o].candidate as usize];
        assert_eq!(s.pose.pitch, c.pose.pitch);
        assert!([4.0, 16.0].iter().any(|t: &f32| (s.pitch_deg - t).abs() < 1e-4), "{}", s.pitch_deg);
    }
}

/// CBC stopped by its time limit returns its incumbent and bound. On the budgeted problem of the
/// Fabriksgatan site (every catalog type, a $22,750 budget, the default placement settings), a
/// one-second limit stopped CBC inside its preprocessing, whose post-processing then crashed
/// the process (SIGSEGV in `CglPreProcess::postProcess`, CBC 2.10): the MIP now runs without it.
#[test]
fn cbc_stopped_by_its_time_limit_returns_on_the_fabriksgatan_budget_problem() {
    use hilo_placement_ip::greedy::greedy;
    use hilo_placement_ip::mip::{Formulation, solve};
    use hilo_placement_ip::pipeline::instance;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/sites/fabriksgatan.toml");
    let scene = Scene::load(&path).unwrap();
    let catalog = Catalog::default_catalog().unwrap();
    let cfg = PlacementConfig::default().validate().unwrap();
    let types: Vec<String> = ["lidar-16", "lidar-32", "lidar-64", "radar-4d"].map(String::from).to_vec();
    let prep = prepare(&scene, &catalog, &types, &cfg).unwrap();
    let inst = instance(&prep, &catalog, &types, cfg.p_min).unwrap();
    let limit = hilo_placement_ip::Limit::Budget { usd: 22_750.0, min: vec![], max: vec![] };
    let g = greedy(&inst, &limit);
    let o = solve(&inst, &limit, Formulation::Strengthened, 0.1, Some(&g.selection)).unwrap();
    assert!(o.objective.is_finite() && o.bound >= o.objective - 1e-6, "{o:?}");
}

/// Every candidate mount of every site of the library is outside the scene's geometry (the
/// sensor models refuse one inside): on the imported sites the mast arms point at the
/// junction, through the spot just outside the pole where pole candidates stand, and at
/// the arm's height that spot was inside the arm.
#[test]
fn no_candidate_of_any_site_is_inside_its_geometry() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
    let mut scenes = vec![dir.join("intersection.toml")];
    scenes.extend(
        [
            "t_junction",
            "skewed",
            "five_leg",
            "urban_canyon",
            "arterial_parking",
            "fabriksgatan",
            "three_arm_grid",
            "braunschweig",
        ]
        .map(|s| dir.join(format!("sites/{s}.toml"))),
    );
    // The default steps, and a pole step that lands on the arm's height (6 m) wherever the
    // lowest pole candidate starts.
    for cfg in [CandidateConfig::default(), CandidateConfig { pole_step_m: 0.5, ..CandidateConfig::default() }] {
        for path in &scenes {
            let scene = Scene::load(path).unwrap();
            let world = World::build(&scene, &QueryRegion::everything()).unwrap();
            let candidates = sample_candidates(&scene, &cfg).unwrap();
            assert!(!candidates.is_empty());
            for c in &candidates {
                if let Err(e) = hilo_sensor_models::lidar::check_mount(&world, None, &c.pose) {
                    panic!("{}: candidate {} on {}: {e}", path.display(), c.id, c.structure);
                }
            }
        }
    }
}
