//! What `hilo bench` measures: every stage's speed together with the error it pays, against an
//! independent implementation in the same run where one exists (the ray engine against
//! parry3d's TriMesh and raw obvhs; the placement's exact search against plain CBC; the
//! training step against the machine's measured matrix-product peak).

pub mod simulate;

use anyhow::{Context, Result};
use glam::Vec3;
use hilo_raycast::reference::{compare_with_parry, ground_triangles, parry_trimesh, pole_top_sweeps};
use hilo_raycast::{QueryRegion, Ray, Scene, World};
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::triangle::Triangle;
use parry3d::query::RayCast;
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

#[derive(Serialize, Debug)]
pub struct RaycastReport {
    pub rays: usize,
    pub hilo_mrays_per_s: f64,
    pub parry_mrays_per_s: f64,
    /// Hit/miss disagreements with parry3d.
    pub mismatches: usize,
    /// Largest distance difference where both engines hit, except where parry leaked
    /// through a shared mesh edge.
    pub max_abs_dist_err_m: f64,
    /// Rays where both hit at distances more than 1e-4 m apart.
    pub distance_disagreements: usize,
    /// Disagreements where hilo's hit lies on a mesh edge that parry's test leaks through.
    pub explained_by_shared_edge: usize,
    /// Disagreements without that explanation (should be 0).
    pub unexplained: usize,
    /// hilo / parry, all cores.
    pub speedup_vs_parry: f64,
    pub threads: usize,
    pub hilo_1t_mrays_per_s: f64,
    pub parry_1t_mrays_per_s: f64,
    /// obvhs's own BVH2 traversal and (non-watertight) triangle test, ground tessellated.
    pub obvhs_raw_mrays_per_s: f64,
    pub obvhs_raw_mismatches: usize,
    pub hit_fraction: f64,
    pub static_triangles: usize,
    pub parry_triangles: usize,
    pub hilo_build_ms: f64,
    pub parry_build_ms: f64,
}

impl RaycastReport {
    pub fn print_table(&self) {
        println!("rays: {} ({} threads), {:.1}% hit something", self.rays, self.threads, 100.0 * self.hit_fraction);
        println!("{:<28} {:>12} {:>12} {:>10}", "engine", "Mrays/s", "1 thread", "build ms");
        println!(
            "{:<28} {:>12.2} {:>12.2} {:>10.1}",
            "hilo (watertight)", self.hilo_mrays_per_s, self.hilo_1t_mrays_per_s, self.hilo_build_ms
        );
        println!(
            "{:<28} {:>12.2} {:>12.2} {:>10.1}",
            "parry3d TriMesh", self.parry_mrays_per_s, self.parry_1t_mrays_per_s, self.parry_build_ms
        );
        println!("{:<28} {:>12.2} {:>12} {:>10}", "obvhs BVH2 raw (reference)", self.obvhs_raw_mrays_per_s, "-", "-");
        println!("speed-up over parry3d: {:.2}x", self.speedup_vs_parry);
        println!(
            "error paid: {} hit/miss mismatches against parry3d, max |distance difference| {:.2e} m",
            self.mismatches, self.max_abs_dist_err_m
        );
        println!(
            "{} distance disagreements > 1e-4 m; {} disagreements are rays through a mesh edge (parry leaking through a crack, or rounding picking the other face), {} unexplained",
            self.distance_disagreements, self.explained_by_shared_edge, self.unexplained
        );
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Times `f` `repeats` times after one warm-up and returns (median seconds, last output).
fn time<T>(repeats: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut out = f();
    let mut secs = Vec::with_capacity(repeats);
    for _ in 0..repeats {
        let t = Instant::now();
        out = f();
        secs.push(t.elapsed().as_secs_f64());
    }
    (median(secs), out)
}

pub fn raycast(scene: &Scene, azimuth_steps: usize, repeats: usize) -> Result<RaycastReport> {
    let rays = pole_top_sweeps(scene, azimuth_steps);
    anyhow::ensure!(!rays.is_empty(), "the scene has no mounting poles to cast from");
    let n = rays.len();

    let t = Instant::now();
    let world = World::build(scene, &QueryRegion::everything())?;
    let hilo_build_ms = t.elapsed().as_secs_f64() * 1e3;
    let tile = 10.0;
    let t = Instant::now();
    let parry = parry_trimesh(scene, tile)?;
    let parry_build_ms = t.elapsed().as_secs_f64() * 1e3;

    let hilo_cast = |r: &Ray| world.closest_hit(r, None).map(|h| h.t);
    let parry_cast = |r: &Ray| {
        let pr = parry3d::query::Ray::new(r.origin, r.dir);
        parry.cast_local_ray(&pr, r.t_max, false)
    };
    let chunk = 1024;
    let (hilo_s, hilo_t) =
        time(repeats, || rays.par_chunks(chunk).flat_map_iter(|c| c.iter().map(hilo_cast)).collect::<Vec<_>>());
    let (parry_s, parry_t) =
        time(repeats, || rays.par_chunks(chunk).flat_map_iter(|c| c.iter().map(parry_cast)).collect::<Vec<_>>());

    // Raw obvhs: its BVH2 and Möller–Trumbore test over the same triangles, ground tiled.
    let tris: Vec<Triangle> = ground_triangles(scene, tile)
        .iter()
        .chain(&scene.mesh.triangles)
        .map(|t| Triangle { v0: t[0].into(), v1: t[1].into(), v2: t[2].into() })
        .collect();
    let bvh = build_bvh2_from_tris(&tris, obvhs::BvhBuildParams::medium_build(), &mut Duration::default());
    let ordered: Vec<Triangle> = bvh.primitive_indices.iter().map(|&i| tris[i as usize]).collect();
    let obvhs_cast = |r: &Ray| {
        let ray = obvhs::ray::Ray::new(r.origin.into(), r.dir.into(), 0.0, r.t_max);
        let mut hit = obvhs::ray::RayHit::none();
        bvh.ray_traverse(ray, &mut hit, |ray, id| ordered[id].intersect(ray)).then_some(hit.t)
    };
    let (obvhs_s, obvhs_t) =
        time(repeats, || rays.par_chunks(chunk).flat_map_iter(|c| c.iter().map(obvhs_cast)).collect::<Vec<_>>());

    let single = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let (hilo_1t, parry_1t) = single.install(|| {
        let (a, _) = time(repeats.min(3), || rays.iter().map(hilo_cast).filter(Option::is_some).count());
        let (b, _) = time(repeats.min(3), || rays.iter().map(parry_cast).filter(Option::is_some).count());
        (a, b)
    });

    let cmp = compare_with_parry(scene, &world, &parry, tile, &rays);
    let obvhs_raw_mismatches = obvhs_t.iter().zip(&parry_t).filter(|(a, b)| a.is_some() != b.is_some()).count();
    let mr = |s: f64| n as f64 / s / 1e6;
    Ok(RaycastReport {
        rays: n,
        hilo_mrays_per_s: mr(hilo_s),
        parry_mrays_per_s: mr(parry_s),
        mismatches: cmp.hit_miss_mismatches,
        max_abs_dist_err_m: cmp.max_abs_dist_err_m,
        distance_disagreements: cmp.distance_disagreements,
        explained_by_shared_edge: cmp.explained_by_shared_edge,
        unexplained: cmp.unexplained,
        speedup_vs_parry: parry_s / hilo_s,
        threads: rayon::current_num_threads(),
        hilo_1t_mrays_per_s: mr(hilo_1t),
        parry_1t_mrays_per_s: mr(parry_1t),
        obvhs_raw_mrays_per_s: mr(obvhs_s),
        obvhs_raw_mismatches,
        hit_fraction: hilo_t.iter().filter(|h| h.is_some()).count() as f64 / n as f64,
        static_triangles: world.triangle_count(),
        parry_triangles: parry.indices().len(),
        hilo_build_ms,
        parry_build_ms,
    })
}

/// `hilo bench sensors`.
#[derive(Serialize, Debug)]
pub struct SensorsReport {
    pub actors: usize,
    pub frames: usize,
    pub threads: usize,
    /// Median wall time of one frame of 2 x lidar-16 + radar-4d (actor structure included).
    pub cheap_suite_frame_ms: f64,
    pub cheap_suite_rays_per_frame: usize,
    pub cheap_suite_points_per_frame: f64,
    /// Median wall time of one frame of lidar-64 + radar-4d.
    pub lidar64_radar_frame_ms: f64,
    pub lidar64_radar_rays_per_frame: usize,
    pub lidar64_radar_points_per_frame: f64,
    /// The error the placement model pays: expected returns on a car (detection-probability
    /// model, occlusion ignored) against the mean of simulated scans of the same car.
    pub probe_car_expected_returns: f64,
    pub probe_car_simulated_mean_returns: f64,
    pub realtime_factor_cheap_suite: f64,
}

impl SensorsReport {
    pub fn print_table(&self) {
        println!("{} moving actors, {} frames, {} threads", self.actors, self.frames, self.threads);
        println!("{:<28} {:>10} {:>10} {:>12}", "suite", "ms/frame", "rays", "points");
        println!(
            "{:<28} {:>10.2} {:>10} {:>12.0}",
            "2 x lidar-16 + radar-4d",
            self.cheap_suite_frame_ms,
            self.cheap_suite_rays_per_frame,
            self.cheap_suite_points_per_frame
        );
        println!(
            "{:<28} {:>10.2} {:>10} {:>12.0}",
            "lidar-64 + radar-4d",
            self.lidar64_radar_frame_ms,
            self.lidar64_radar_rays_per_frame,
            self.lidar64_radar_points_per_frame
        );
        println!("cheap suite runs {:.1}x faster than real time at 20 Hz", self.realtime_factor_cheap_suite);
        println!(
            "placement model vs simulation (car probe, lidar-16): expected {:.1} returns, simulated mean {:.1}",
            self.probe_car_expected_returns, self.probe_car_simulated_mean_returns
        );
    }
}

pub fn sensors(n_actors: usize, frames: usize) -> Result<SensorsReport> {
    use hilo_raycast::ActorSet;
    use hilo_sensor_models::probability::{Probe, lidar_expected_returns};
    use hilo_sensor_models::{Catalog, SensorPose, simulate_lidar, simulate_radar};
    let scene = Scene::default_fixture()?;
    let world = World::build(&scene, &QueryRegion::everything())?;
    let catalog = Catalog::default_catalog()?;
    let (l16, l64, radar) = (catalog.lidar("lidar-16")?, catalog.lidar("lidar-64")?, catalog.radar("radar-4d")?);
    let deg = f32::to_radians;
    // Two 16-beam LiDARs on opposite pole tops, tilted 10° down toward the centre; the radar on
    // the SE mast arm looking across the junction.
    let ne = SensorPose::new(Vec3::new(13.0, 16.6, 7.8), deg(-127.0), deg(10.0), 0.0);
    let sw = SensorPose::new(Vec3::new(-13.0, -16.6, 7.8), deg(53.0), deg(10.0), 0.0);
    let rp = SensorPose::new(Vec3::new(16.6, -7.0, 6.4), deg(165.0), deg(8.0), 0.0);
    let base = hilo_study::demo::demo_actors(&scene, n_actors, true, 1);
    let dt = 1.0 / 20.0;
    let mut cheap = Vec::new();
    let mut high = Vec::new();
    let (mut cheap_pts, mut high_pts) = (0usize, 0usize);
    for f in 0..frames + 1 {
        let actors = hilo_study::demo::advance(&base, f as f32 * dt);
        let t = Instant::now();
        // The sensors of a frame are independent: simulate them concurrently.
        let set = ActorSet::new(actors.clone())?;
        let ((a, b), r) = rayon::join(
            || {
                rayon::join(
                    || simulate_lidar(l16, &ne, &world, Some(&set), 3 * f as u64),
                    || simulate_lidar(l16, &sw, &world, Some(&set), 3 * f as u64 + 1),
                )
            },
            || simulate_radar(radar, &rp, &world, Some(&set), 3 * f as u64 + 2),
        );
        let (a, b, r) = (a?, b?, r?);
        let t_cheap = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let set = ActorSet::new(actors)?;
        let (c, r2) = rayon::join(
            || simulate_lidar(l64, &ne, &world, Some(&set), 3 * f as u64),
            || simulate_radar(radar, &rp, &world, Some(&set), 3 * f as u64 + 2),
        );
        let (c, r2) = (c?, r2?);
        let t_high = t.elapsed().as_secs_f64();
        if f > 0 {
            cheap.push(t_cheap * 1e3);
            high.push(t_high * 1e3);
            cheap_pts += a.points.len() + b.points.len() + r.points.len();
            high_pts += c.points.len() + r2.points.len();
        }
    }
    // Placement model against simulation: an unoccluded car 30 m from a 16-beam LiDAR.
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, 6.5), 0.0, deg(5.0), 0.0);
    let open = World::from_triangles(&[], Some(scene.ground))?;
    let b = Probe::CAR.at(glam::Vec2::new(30.0, 2.0), scene.ground.z_m, 0.3);
    let expected = lidar_expected_returns(l16, &pose, &Probe::CAR, &b) as f64;
    let set = ActorSet::new(vec![hilo_raycast::Actor::from_box(1, Probe::CAR.class, b)])?;
    let trials = 50;
    let mut sum = 0usize;
    for s in 0..trials {
        sum += simulate_lidar(l16, &pose, &open, Some(&set), s)?.points_per_actor().get(&1).copied().unwrap_or(0);
    }
    let cheap_ms = median(cheap);
    Ok(SensorsReport {
        actors: base.len(),
        frames,
        threads: rayon::current_num_threads(),
        cheap_suite_frame_ms: cheap_ms,
        cheap_suite_rays_per_frame: 2 * l16.rays_per_frame()
            + (radar.hfov_deg / radar.ray_azimuth_step_deg).round() as usize
                * (radar.vfov_deg / radar.ray_elevation_step_deg).round() as usize,
        cheap_suite_points_per_frame: cheap_pts as f64 / frames as f64,
        lidar64_radar_frame_ms: median(high),
        lidar64_radar_rays_per_frame: l64.rays_per_frame()
            + (radar.hfov_deg / radar.ray_azimuth_step_deg).round() as usize
                * (radar.vfov_deg / radar.ray_elevation_step_deg).round() as usize,
        lidar64_radar_points_per_frame: high_pts as f64 / frames as f64,
        probe_car_expected_returns: expected,
        probe_car_simulated_mean_returns: sum as f64 / trials as f64,
        realtime_factor_cheap_suite: 50.0 / cheap_ms,
    })
}

/// `hilo bench placement`.
#[derive(Serialize, Debug)]
pub struct PlacementReport {
    pub candidates: usize,
    pub targets: usize,
    /// Line of sight and V for lidar-16/32/64 and radar-4d.
    pub visibility_seconds: f64,
    /// The slowest of the paper's three count-limited configurations (exact search, greedy seed
    /// included).
    pub hilo_seconds: f64,
    pub configurations: Vec<serde_json::Value>,
    /// LiDAR type chosen per candidate among 16/32/64 beams plus radars, budget = one 64-beam
    /// LiDAR + one radar.
    pub budgeted_seconds: f64,
    pub budgeted_proven: bool,
    pub budgeted_objective: f64,
    pub budgeted_bound: f64,
    pub budgeted_gap: f64,
    pub budgeted_method: String,
    /// The paper's plain formulation of "2x lidar-16 + radar" handed to CBC, capped.
    pub plain_cbc_seconds: f64,
    pub plain_cbc_status: String,
    pub plain_cbc_objective: f64,
    pub plain_cbc_bound: f64,
    /// CBC's own gap: (bound − its objective) / its objective.
    pub plain_cbc_gap: f64,
    pub plain_cbc_rows: usize,
    pub plain_cbc_nonzeros: usize,
    /// Whether CBC's objective equals hilo's proven optimum (to 1e-6 relative).
    pub objective_equal: bool,
}

pub fn placement(cbc_seconds: f64) -> Result<PlacementReport> {
    use hilo_placement_ip::Limit;
    use hilo_placement_ip::mip::{Formulation, build, solve as cbc};
    use hilo_placement_ip::pipeline::{PlacementConfig, instance, prepare, solve};
    use hilo_sensor_models::Catalog;
    let scene = Scene::default_fixture()?;
    let catalog = Catalog::default_catalog()?;
    let cfg = PlacementConfig::default().validate()?;
    let names: Vec<String> = ["lidar-16", "lidar-32", "lidar-64", "radar-4d"].iter().map(|s| s.to_string()).collect();
    let t = Instant::now();
    let prep = prepare(&scene, &catalog, &names, &cfg)?;
    let visibility_seconds = t.elapsed().as_secs_f64();
    let mut configurations = Vec::new();
    let mut hilo_seconds: f64 = 0.0;
    let mut two16 = None;
    for (label, lidar, n) in [
        ("2x lidar-16 + radar", "lidar-16", 2u32),
        ("1x lidar-32 + radar", "lidar-32", 1),
        ("1x lidar-64 + radar", "lidar-64", 1),
    ] {
        let types = vec![lidar.to_owned(), "radar-4d".to_owned()];
        let inst = instance(&prep, &catalog, &types, cfg.p_min)?;
        let limit = Limit::Counts(vec![n, 1]);
        let o = solve(&inst, &limit, cfg.solve_limit())?;
        hilo_seconds = hilo_seconds.max(o.solve_seconds);
        configurations.push(serde_json::json!({"name": label, "objective": o.objective, "proven_optimal": o.proven_optimal, "seconds": o.solve_seconds, "method": o.method}));
        if two16.is_none() {
            two16 = Some((inst, limit, o.objective));
        }
    }
    let inst = instance(&prep, &catalog, &names, cfg.p_min)?;
    let budget = catalog.get("lidar-64")?.price_usd() + catalog.get("radar-4d")?.price_usd();
    let limit = Limit::Budget { usd: budget, min: vec![], max: vec![] };
    let b = solve(&inst, &limit, cbc_seconds)?;
    let (inst, limit, best) = two16.context("no configuration was solved")?;
    let m = build(&inst, &limit, Formulation::Plain)?;
    let (rows, nonzeros) = (m.rows, m.nonzeros);
    drop(m);
    let t = Instant::now();
    let (status, obj, bound) = match cbc(&inst, &limit, Formulation::Plain, cbc_seconds, None) {
        Ok(o) => (if o.proven_optimal { "optimal".to_owned() } else { "time limit".to_owned() }, o.objective, o.bound),
        Err(e) => (format!("error: {e}"), f64::NAN, f64::NAN),
    };
    let plain_cbc_seconds = t.elapsed().as_secs_f64();
    Ok(PlacementReport {
        candidates: prep.candidates.len(),
        targets: prep.targets.len(),
        visibility_seconds,
        hilo_seconds,
        configurations,
        budgeted_seconds: b.solve_seconds,
        budgeted_proven: b.proven_optimal,
        budgeted_objective: b.objective,
        budgeted_bound: b.bound,
        budgeted_gap: b.gap,
        budgeted_method: b.method,
        plain_cbc_seconds,
        plain_cbc_status: status,
        plain_cbc_objective: obj,
        plain_cbc_bound: bound,
        plain_cbc_gap: (bound - obj) / obj.abs().max(1e-9),
        plain_cbc_rows: rows,
        plain_cbc_nonzeros: nonzeros,
        objective_equal: (obj - best).abs() <= 1e-6 * best.abs().max(1.0),
    })
}

/// `hilo bench eval`.
#[derive(Serialize, Debug)]
pub struct EvalReport {
    pub frames: usize,
    pub gt_boxes: usize,
    pub pred_boxes: usize,
    pub max_pred_per_frame: usize,
    /// nuScenes metric (6 classes × 4 thresholds, TP errors, NDS), median of the repeats.
    pub evaluate_seconds: f64,
    pub mean_ap: f64,
    pub nd_score: f64,
    pub threads: usize,
    /// 1,000 scene-bootstrap resamples (10 frames a scene) of the same data.
    pub bootstrap_resamples: usize,
    pub bootstrap_seconds: f64,
    pub bootstrap_map_interval: [f64; 2],
}

/// Synthetic frames: ~45 ground-truth boxes each over the six classes, predictions near most of
/// them plus false positives, up to `max_pred` per frame.
pub fn eval(frames: usize, max_pred: usize, repeats: usize) -> Result<EvalReport> {
    use hilo_eval::{DetectionConfig, EvalBox, evaluate};
    use rand::{Rng, SeedableRng};
    use std::collections::BTreeMap;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let classes = ["car", "truck", "bus", "motorcycle", "pedestrian", "golf_cart"];
    let mut gt: BTreeMap<String, Vec<EvalBox>> = BTreeMap::new();
    let mut pred: Vec<(String, Vec<EvalBox>)> = Vec::new();
    for f in 0..frames {
        let token = format!("sample{f:06}");
        let mut g = Vec::new();
        let mut p = Vec::new();
        for _ in 0..45 {
            let c = classes[rng.random_range(0..classes.len())];
            let (x, y) = (rng.random_range(-45.0..45.0), rng.random_range(-45.0..45.0));
            let yaw = rng.random_range(-3.1..3.1);
            let mut b = EvalBox::from_yaw(&token, c, [x, y, 0.8], [1.9, 4.5, 1.6], yaw, [2.0, 0.0], 1.0);
            b.num_pts = 10;
            g.push(b);
            if rng.random_bool(0.8) && p.len() < max_pred {
                p.push(EvalBox::from_yaw(
                    &token,
                    c,
                    [x + rng.random_range(-1.5..1.5), y + rng.random_range(-1.5..1.5), 0.8],
                    [2.0, 4.4, 1.5],
                    yaw + 0.1,
                    [1.5, 0.2],
                    rng.random_range(0.0..1.0),
                ));
            }
        }
        while p.len() < max_pred {
            let c = classes[rng.random_range(0..classes.len())];
            p.push(EvalBox::from_yaw(
                &token,
                c,
                [rng.random_range(-45.0..45.0), rng.random_range(-45.0..45.0), 0.8],
                [1.9, 4.5, 1.6],
                0.0,
                [0.0, 0.0],
                rng.random_range(0.0..0.5),
            ));
        }
        gt.insert(token.clone(), g);
        pred.push((token, p));
    }
    let cfg = DetectionConfig::default();
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..repeats {
        let t = Instant::now();
        last = Some(evaluate(&gt, &pred, &cfg));
        times.push(t.elapsed().as_secs_f64());
    }
    let m = last.context("no evaluation was run")?;
    let mut gtf = hilo_eval::GroundTruth::default();
    for (k, v) in &gt {
        let f: usize = k.trim_start_matches("sample").parse().unwrap_or(0);
        gtf.samples.insert(
            k.clone(),
            hilo_eval::boxes::SampleInfo { scene: format!("scene{}", f / 10), ego_translation: [0.0; 3] },
        );
        gtf.boxes.insert(k.clone(), v.clone());
    }
    let t = Instant::now();
    let b = hilo_eval::bootstrap::bootstrap(&gtf, &pred, &cfg, 1000, 0.95, 0);
    let bootstrap_seconds = t.elapsed().as_secs_f64();
    Ok(EvalReport {
        bootstrap_resamples: 1000,
        bootstrap_seconds,
        bootstrap_map_interval: [b.mean_ap.lo, b.mean_ap.hi],
        frames,
        gt_boxes: gt.values().map(Vec::len).sum(),
        pred_boxes: pred.iter().map(|(_, v)| v.len()).sum(),
        max_pred_per_frame: max_pred,
        evaluate_seconds: median(times),
        mean_ap: m.mean_ap,
        nd_score: m.nd_score,
        threads: rayon::current_num_threads(),
    })
}

/// `hilo bench train`: where a training step's time goes, per part, for each preset, and the
/// step's arithmetic rate against the machine's matrix-product peak measured in the same run.
#[derive(Serialize, Debug)]
pub struct TrainReport {
    pub data: String,
    /// Where the steps ran: "cpu" or "cuda:0".
    pub device: String,
    pub threads: usize,
    /// candle's f32 matrix product on the same device ([`matmul_peak`]): the highest of
    /// `matmul_peak_samples_gflops`, measured before the first preset and after each one (a
    /// shared machine's rate drifts within a run; the ratios below are to the highest).
    pub matmul_peak_gflops: f64,
    pub matmul_peak_samples_gflops: Vec<f64>,
    pub presets: Vec<TrainRow>,
}

#[derive(Serialize, Debug)]
pub struct TrainRow {
    pub preset: String,
    pub layout: &'static str,
    pub background_removed: bool,
    /// Radar static clutter dropped (fusion presets only).
    pub radar_clutter_removed: bool,
    /// Rare road users pasted into training frames ([`hilo_detector::paste`]).
    pub ground_truth_paste: bool,
    pub batch: usize,
    /// Data-parallel replicas of a step, and how many of them ran at once here.
    pub replicas: usize,
    pub replicas_at_once: usize,
    /// BatchNorm over the whole batch (synchronised across the replicas) or each replica's.
    pub sync_batch_norm: bool,
    /// How the sparse convolutions' backward pass forms the input gradient: `gather` (through
    /// the inverted rulebook) or `scatter`.
    #[serde(default)]
    pub sparse_backward: String,
    /// The optimizer's update: `fused` (in place) or `composite` (candle's operations).
    #[serde(default)]
    pub optimizer: String,
    /// The fused layers that ran, `+`-separated (`--variant fused=off`: none, each its
    /// composite of candle's operations).
    pub fused: String,
    pub steps: usize,
    /// From the wall time of the steps as training runs them (replicas side by side where
    /// there are threads for them; data prepared on another thread, so not counted unless it
    /// is slower).
    pub samples_per_s: f64,
    /// Milliseconds per step of each part (data: on the batch thread when training), each
    /// measured alone: with several replicas, summed over them, one after the other.
    pub ms: BTreeMap<&'static str, f64>,
    /// Forward FLOPs of convolutions and pillar layers per step; a training step is counted as
    /// three times that (forward, and the two products of the backward pass).
    pub forward_gflop_per_step: f64,
    pub achieved_gflops: f64,
    pub ratio_to_peak: f64,
    /// candle's matrix product alone at the sizes this row's products have: every forward
    /// product of the timed steps and the two products of its backward pass, replayed on random
    /// matrices of the same shapes, each thread of the pool replaying all of them at once (as
    /// [`matmul_peak`] measures the peak); GFLOP/s summed over the threads.
    pub products_gflops: f64,
    /// `products_gflops` over the peak: what the products' sizes alone leave of it.
    pub products_ratio_to_peak: f64,
    /// The products' time at `products_gflops` over the step's wall time; the rest of the step
    /// is everything else (gathers, normalisation, element-wise layers, loss, optimizer, memory).
    /// `ratio_to_peak` = `products_share_of_step` × `products_ratio_to_peak`.
    pub products_share_of_step: f64,
    /// The replay by product family (inner dimension k, output columns n), most time first.
    pub product_families: Vec<ProductFamily>,
    /// Mean pillars per frame (LiDAR + radar) and sites of the sparse layout per batch.
    pub pillars_per_frame: f64,
    pub level0_sites_per_batch: f64,
    pub head_sites_per_batch: f64,
}

/// One family of a step's matrix products in [`replay_products`]: forward `(m × k) · (k × n)`
/// products of any row count `m` with the same `k` and `n`, and their backward products.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct ProductFamily {
    pub k: usize,
    pub n: usize,
    /// Forward products per step, and their mean row count.
    pub products_per_step: f64,
    pub mean_rows: f64,
    /// Forward and backward FLOPs per step (three times the forward products').
    pub gflop_per_step: f64,
    /// The rate candle's product reaches on this family, on the first thread, and the family's
    /// share of the replay's time.
    pub gflops: f64,
    pub share_of_time: f64,
}

/// What candle's matrix product reaches at the shapes a step uses: each forward product
/// `(m, k, n)` of `shapes` as `A · B` on random matrices of its shape, with the two products of
/// its backward pass (`G · Bᵀ` and `Aᵀ · G`, `G` the output's gradient), timed one by one. On
/// the CPU every thread of rayon's pool replays all of them at once (candle itself on one thread
/// each, as training's replicas run) and the rates add up; elsewhere one replay. Returns the
/// summed GFLOP/s and the first thread's families. The layouts are plain (a step's kernels are
/// sometimes stored transposed), and a step's products meet caches that its other layers have
/// filled, so the replay measures the sizes, not the surroundings.
pub fn replay_products(
    shapes: &[[usize; 3]],
    steps: usize,
    device: &candle_core::Device,
) -> candle_core::Result<(f64, Vec<ProductFamily>)> {
    use candle_core::Tensor;
    let mut rows: BTreeMap<(usize, usize), usize> = BTreeMap::new();
    for &[m, k, n] in shapes {
        let r = rows.entry((k, n)).or_default();
        *r = (*r).max(m);
    }
    // One set of operands per family, as large as its largest product; a product reads the
    // first `m` rows (still contiguous).
    let mut operands = BTreeMap::new();
    for (&(k, n), &m) in &rows {
        let a = Tensor::randn(0f32, 1.0, (m.max(1), k.max(1)), device)?;
        let b = Tensor::randn(0f32, 1.0, (k.max(1), n.max(1)), device)?;
        let g = Tensor::randn(0f32, 1.0, (m.max(1), n.max(1)), device)?;
        operands.insert((k, n), (a, b, g));
    }
    // Per family: seconds, FLOPs, products and rows.
    type Families = BTreeMap<(usize, usize), (f64, f64, usize, usize)>;
    let replay = || -> candle_core::Result<Families> {
        let run = |&[m, k, n]: &[usize; 3]| -> candle_core::Result<f64> {
            let Some((a, b, g)) = operands.get(&(k, n)) else { return Ok(0.0) };
            let (a, g) = (a.narrow(0, 0, m)?, g.narrow(0, 0, m)?);
            let s = Instant::now();
            let y = a.matmul(b)?;
            let ga = g.matmul(&b.t()?)?;
            let gb = a.t()?.matmul(&g)?;
            device.synchronize()?;
            let t = s.elapsed().as_secs_f64();
            drop((y, ga, gb));
            Ok(t)
        };
        // Warm-up: the allocator and the first products' caches.
        for s in shapes.iter().take(20) {
            run(s)?;
        }
        let mut fam = Families::new();
        for s in shapes {
            if s.contains(&0) {
                continue;
            }
            let t = run(s)?;
            let e = fam.entry((s[1], s[2])).or_default();
            e.0 += t;
            e.1 += 6.0 * (s[0] * s[1] * s[2]) as f64;
            e.2 += 1;
            e.3 += s[0];
        }
        Ok(fam)
    };
    let threads: Vec<_> = if device.is_cpu() {
        rayon::broadcast(|_| replay()).into_iter().collect::<candle_core::Result<_>>()?
    } else {
        vec![replay()?]
    };
    let rate = threads
        .iter()
        .map(|fam| {
            let (t, f) = fam.values().fold((0.0, 0.0), |(t, f), e| (t + e.0, f + e.1));
            if t > 0.0 { f / t / 1e9 } else { 0.0 }
        })
        .sum();
    let first = threads.into_iter().next().unwrap_or_default();
    let total: f64 = first.values().map(|e| e.0).sum();
    let mut families: Vec<ProductFamily> = first
        .into_iter()
        .map(|((k, n), (t, f, count, m))| ProductFamily {
            k,
            n,
            products_per_step: count as f64 / steps.max(1) as f64,
            mean_rows: m as f64 / count.max(1) as f64,
            gflop_per_step: f / 1e9 / steps.max(1) as f64,
            gflops: if t > 0.0 { f / t / 1e9 } else { 0.0 },
            share_of_time: if total > 0.0 { t / total } else { 0.0 },
        })
        .collect();
    families.sort_by(|a, b| b.share_of_time.total_cmp(&a.share_of_time));
    Ok((rate, families))
}

fn device_name(device: &candle_core::Device) -> String {
    match device.location() {
        candle_core::DeviceLocation::Cpu => "cpu".into(),
        candle_core::DeviceLocation::Cuda { gpu_id } => format!("cuda:{gpu_id}"),
        candle_core::DeviceLocation::Metal { gpu_id } => format!("metal:{gpu_id}"),
    }
}

/// candle's f32 matrix product on `device`. On the CPU 2048 × 2048 matrices, one product per
/// thread of rayon's pool at once (the way a training's replicas use the cores: candle itself on
/// one thread each, as `hilo bench train` runs it), GFLOP/s summed over the threads; on a GPU one
/// 8192 × 8192 product (cuBLAS).
fn matmul_peak(device: &candle_core::Device) -> Result<f64> {
    if !device.is_cpu() {
        return Ok(product_rate(device, 8192)?);
    }
    let rates = rayon::broadcast(|_| product_rate(&candle_core::Device::Cpu, 2048));
    Ok(rates.into_iter().collect::<candle_core::Result<Vec<f64>>>()?.iter().sum())
}

/// GFLOP/s of one `n` × `n` f32 product on `device`: the median of 5 products after a warm-up,
/// each summed and read back (which waits for a GPU's queued work).
fn product_rate(device: &candle_core::Device, n: usize) -> candle_core::Result<f64> {
    let a = candle_core::Tensor::randn(0f32, 1.0, (n, n), device)?;
    let b = candle_core::Tensor::randn(0f32, 1.0, (n, n), device)?;
    let _ = a.matmul(&b)?.sum_all()?.to_scalar::<f32>()?;
    let mut t = Vec::new();
    for _ in 0..5 {
        let s = Instant::now();
        let c = a.matmul(&b)?;
        let _ = c.sum_all()?.to_scalar::<f32>()?;
        t.push(s.elapsed().as_secs_f64());
    }
    Ok(2.0 * (n * n * n) as f64 / median(t) / 1e9)
}

/// The fused layers `--variant fused=V` keeps on: `on` (all), `off` (none), or names joined by
/// `+` (`conv+bn_relu`).
fn fused_layers(v: &serde_json::Value) -> Result<Vec<hilo_fusion::cpu::Layer>> {
    use hilo_fusion::cpu::{Layer, parse_layers};
    match v {
        serde_json::Value::Bool(true) => Ok(Layer::ALL.to_vec()),
        serde_json::Value::Bool(false) => Ok(Vec::new()),
        serde_json::Value::String(s) => parse_layers(s).map_err(|e| anyhow::anyhow!("variant fused = {v}: {e}")),
        _ => anyhow::bail!("variant fused = {v}: expected on, off, or layers joined by + (conv+bn_relu+loss)"),
    }
}

/// One `--variant` of `hilo bench train`: `key=value` with a JSON (or bare word) value.
pub fn parse_variant(s: &str) -> std::result::Result<(String, serde_json::Value), String> {
    let (k, v) = s.split_once('=').ok_or_else(|| format!("{s:?}: expected key=value"))?;
    let v = serde_json::from_str(v).unwrap_or_else(|_| serde_json::Value::String(v.to_owned()));
    Ok((k.to_owned(), v))
}

/// `hilo bench train`'s `--variant` levers applied to a preset's detector config and schedule;
/// returns the sparse convolutions' backward pass (None: the device's default), whether the
/// optimizer updates in place and whether the fused layers are on.
fn apply_variants(
    overrides: &[(String, serde_json::Value)],
    det_cfg: &mut hilo_detector::detector::DetectorConfig,
    cfg: &mut hilo_detector::train::TrainConfig,
) -> Result<(Option<hilo_fusion::layout::Backward>, bool, Vec<hilo_fusion::cpu::Layer>)> {
    let mut backward = None;
    let mut fused_optimizer = true;
    let mut fused = hilo_fusion::cpu::Layer::ALL.to_vec();
    // Variants for the levers' rows.
    for (k, v) in overrides {
        match (k.as_str(), v.as_u64()) {
            ("layout", _) if v == "dense" => det_cfg.sparse = None,
            ("background", _) if v == false => {
                // The clutter rule reads the LiDAR foreground, so it goes with the background.
                det_cfg.input.background = None;
                det_cfg.input.radar_clutter = None;
            }
            ("radar_clutter", _) if v == false => det_cfg.input.radar_clutter = None,
            ("paste", _) if v == false => cfg.paste = None,
            ("paste", _) if v == true => cfg.paste = Some(Default::default()),
            ("radar_sweeps", Some(n)) if n >= 1 => det_cfg.input.radar_sweeps = n as usize,
            ("lidar_sweeps", Some(n)) if n >= 1 => det_cfg.input.lidar_sweeps = n as usize,
            ("batch", Some(n)) if n >= 1 => cfg.batch = n as usize,
            ("replicas", Some(n)) if n >= 1 => cfg.replicas = n as usize,
            ("sync_batch_norm", _) if v.is_boolean() => cfg.sync_batch_norm = v == true,
            ("sparse_backward", _) if v == "scatter" => backward = Some(hilo_fusion::layout::Backward::Scatter),
            ("sparse_backward", _) if v == "gather" => backward = Some(hilo_fusion::layout::Backward::Gather),
            ("optimizer", _) if v == "composite" => fused_optimizer = false,
            ("optimizer", _) if v == "fused" => fused_optimizer = true,
            ("fused", _) => fused = fused_layers(v)?,
            ("head_dilation", Some(n)) => {
                if let Some(sp) = det_cfg.sparse.as_mut() {
                    sp.head_dilation = n as usize;
                }
            }
            ("layers", Some(n)) => det_cfg.backbone.blocks.iter_mut().for_each(|b| b.layers = n as usize),
            ("blocks", _) => {
                det_cfg.backbone.blocks = serde_json::from_value(v.clone()).with_context(|| {
                    format!("variant blocks = {v}: expected [{{\"stride\": 2, \"channels\": 32, \"layers\": 2}}, ...]")
                })?
            }
            _ => anyhow::bail!(
                "unknown variant {k} = {v} (layout=dense, background=false, radar_clutter=false, paste=true|false, radar_sweeps=K, lidar_sweeps=K, batch=N, replicas=N, sync_batch_norm=true|false, sparse_backward=gather|scatter, optimizer=fused|composite, fused=on|off|conv+bn_relu+loss, head_dilation=N, layers=N, blocks=[{{stride, channels, layers}}, ...])"
            ),
        }
    }
    Ok((backward, fused_optimizer, fused))
}

/// `hilo bench train`: the presets of `registry` named in `presets`, each with `overrides`
/// applied, timed over `steps` steps on the training split of the dataset at `data`.
pub fn train(
    registry: &hilo_detector::Registry,
    data: &std::path::Path,
    presets: &[String],
    steps: usize,
    overrides: &[(String, serde_json::Value)],
) -> Result<TrainReport> {
    use hilo_detector::data::{LoadOptions, load_split};
    use hilo_detector::detector::Detector;
    use std::sync::atomic::Ordering;
    let ds = hilo_dataset::Dataset::open(data, "v1.0-trainval")
        .with_context(|| format!("opening dataset {}", data.display()))?;
    // The device training runs on: the first GPU when built with `cuda`, else the CPU.
    let device = hilo_detector::default_device();
    let mut peaks = vec![matmul_peak(&device)?];
    let mut rows = Vec::new();
    for name in presets {
        let preset = registry.preset(name)?;
        let mut det_cfg = preset.detector.clone();
        let mut cfg = preset.train.clone();
        let (backward, fused_optimizer, fused) = apply_variants(overrides, &mut det_cfg, &mut cfg)?;
        // A plugin that builds its own branches (`late`) carries the backbone in its config too.
        if let Some(b) = det_cfg.fusion_config.get_mut("backbone") {
            *b = serde_json::to_value(&det_cfg.backbone)?;
        }
        let cfg = cfg.validate().with_context(|| format!("bench train {name}"))?;
        let det_cfg = det_cfg.validate().with_context(|| format!("bench train {name}: detector"))?;
        let background = hilo_detector::train::learn_background(&ds, "train", &det_cfg)?;
        let (frames, _) = load_split(&ds, "train", &LoadOptions::of(&det_cfg, registry, background.as_ref()))?;
        let det = Detector::new(&det_cfg, registry, &device, 0)?;
        hilo_fusion::layout::Backward::set_default(backward);
        hilo_detector::train::AdamW::set_fused_default(fused_optimizer);
        hilo_fusion::cpu::set_fused(&fused);
        // Warm-up steps (allocator, caches), then the timed ones.
        hilo_detector::train::time_steps(&det, &frames, &cfg, 3)?;
        hilo_detector::conv::FORWARD_FLOPS.store(0, Ordering::Relaxed);
        let _ = hilo_detector::cpu::take_matmul_shapes();
        hilo_detector::cpu::record_matmul_shapes(true);
        let t = hilo_detector::train::time_steps(&det, &frames, &cfg, steps);
        hilo_detector::cpu::record_matmul_shapes(false);
        let t = t?;
        let flops = hilo_detector::conv::FORWARD_FLOPS.load(Ordering::Relaxed) as f64 / steps as f64;
        let shapes = hilo_detector::cpu::take_matmul_shapes();
        let (wall_s, replicas_at_once) = hilo_detector::train::time_replicated_steps(&det, &frames, &cfg, steps)?;
        let per = |s: f64| 1e3 * s / steps as f64;
        let ms = BTreeMap::from([
            ("data (host: augmentation, pillars, layout, targets)", per(t.data_s)),
            ("to device", per(t.forward.to_device_s)),
            ("pillar net + fusion", per(t.forward.fusion_s)),
            ("backbone + neck", per(t.forward.backbone_s)),
            ("head", per(t.forward.head_s)),
            ("loss", per(t.loss_s)),
            ("backward", per(t.backward_s)),
            ("optimizer", per(t.optimizer_s)),
        ]);
        // Training overlaps data preparation with the step; the step itself (replicas side by
        // side) is the rest.
        let step_s = wall_s.max(t.data_s) / steps as f64;
        let achieved = 3.0 * flops / step_s / 1e9;
        let (products_gflops, product_families) = replay_products(&shapes, steps, &device)?;
        drop(shapes);
        let products_s = if products_gflops > 0.0 { 3.0 * flops / products_gflops / 1e9 } else { 0.0 };
        let occupancy = {
            let mut pillars = 0usize;
            let (mut l0, mut head) = (0usize, 0usize);
            let n = 8.min(frames.len() / cfg.batch.max(1)).max(1);
            let paste = hilo_detector::train::paste_db(&frames, &cfg)?;
            for k in 0..n {
                let mut chunk = frames[k * cfg.batch..((k + 1) * cfg.batch).min(frames.len())].to_vec();
                if let Some(db) = &paste {
                    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(k as u64);
                    chunk = chunk.iter().map(|f| db.paste(f, &mut rng)).collect();
                }
                let b = hilo_detector::detector::HostBatch::new(&det_cfg, &chunk, det.uses_radar(), 0);
                pillars += b.lidar.count() + b.radar.count();
                if let Some(h) = &b.sparse {
                    l0 += h.sites[0].len();
                    head += h.head_sites.len();
                }
            }
            (pillars as f64 / (n * cfg.batch) as f64, l0 as f64 / n as f64, head as f64 / n as f64)
        };
        rows.push(TrainRow {
            preset: name.clone(),
            layout: if det_cfg.sparse.is_some() { "sparse" } else { "dense" },
            background_removed: det_cfg.input.background.is_some(),
            radar_clutter_removed: det_cfg.input.radar_clutter.is_some() && det.uses_radar(),
            ground_truth_paste: cfg.paste.is_some(),
            batch: cfg.batch,
            replicas: cfg.replicas,
            replicas_at_once,
            sync_batch_norm: cfg.sync_batch_norm,
            sparse_backward: format!("{:?}", hilo_fusion::layout::Backward::default_on(&device)).to_lowercase(),
            optimizer: if fused_optimizer { "fused" } else { "composite" }.into(),
            fused: fused.iter().map(|l| l.name()).collect::<Vec<_>>().join("+"),
            steps,
            samples_per_s: cfg.batch as f64 / step_s,
            ms,
            forward_gflop_per_step: flops / 1e9,
            achieved_gflops: achieved,
            // Set below, against the run's highest peak.
            ratio_to_peak: 0.0,
            products_gflops,
            products_ratio_to_peak: 0.0,
            products_share_of_step: products_s / step_s,
            product_families,
            pillars_per_frame: occupancy.0,
            level0_sites_per_batch: occupancy.1,
            head_sites_per_batch: occupancy.2,
        });
        peaks.push(matmul_peak(&device)?);
    }
    hilo_fusion::layout::Backward::set_default(None);
    hilo_detector::train::AdamW::set_fused_default(true);
    let peak = peaks.iter().copied().fold(f64::MIN, f64::max);
    for r in &mut rows {
        r.ratio_to_peak = r.achieved_gflops / peak;
        r.products_ratio_to_peak = r.products_gflops / peak;
    }
    Ok(TrainReport {
        data: data.display().to_string(),
        device: device_name(&device),
        threads: rayon::current_num_threads(),
        matmul_peak_gflops: peak,
        matmul_peak_samples_gflops: peaks,
        presets: rows,
    })
}

impl TrainReport {
    pub fn print_table(&self) {
        println!(
            "device {}: matrix-product peak {:.1} GFLOP/s (highest of {}; {} host threads); data {}",
            self.device,
            self.matmul_peak_gflops,
            self.matmul_peak_samples_gflops.iter().map(|p| format!("{p:.1}")).collect::<Vec<_>>().join(", "),
            self.threads,
            self.data
        );
        for r in &self.presets {
            println!(
                "{} ({}, {} backward, {} optimizer, fused layers: {}, background {}{}{}, batch {} in {} replicas, {} at once): {:.1} samples/s, {:.2} GFLOP forward per step, {:.1} GFLOP/s = {:.1}% of peak; {:.0} pillars/frame, {:.0} level-0 and {:.0} head sites per batch",
                r.preset,
                r.layout,
                r.sparse_backward,
                r.optimizer,
                if r.fused.is_empty() { "none" } else { &r.fused },
                if r.background_removed { "removed" } else { "kept" },
                if r.radar_clutter_removed { ", radar clutter removed" } else { "" },
                if r.ground_truth_paste { ", ground-truth paste" } else { "" },
                r.batch,
                r.replicas,
                r.replicas_at_once,
                r.samples_per_s,
                r.forward_gflop_per_step,
                r.achieved_gflops,
                100.0 * r.ratio_to_peak,
                r.pillars_per_frame,
                r.level0_sites_per_batch,
                r.head_sites_per_batch
            );
            for (k, v) in &r.ms {
                println!("    {k:<52} {v:>8.2} ms/step");
            }
            println!(
                "    matrix products alone at their sizes: {:.1} GFLOP/s = {:.1}% of peak, {:.1}% of the step's time",
                r.products_gflops,
                100.0 * r.products_ratio_to_peak,
                100.0 * r.products_share_of_step
            );
            for f in r.product_families.iter().take(6) {
                println!(
                    "      k {:>4} n {:>4}: {:>5.1} products/step of {:>7.0} rows, {:>6.2} GFLOP/step at {:>6.1} GFLOP/s, {:>4.1}% of the products' time",
                    f.k,
                    f.n,
                    f.products_per_step,
                    f.mean_rows,
                    f.gflop_per_step,
                    f.gflops,
                    100.0 * f.share_of_time
                );
            }
        }
    }
}
