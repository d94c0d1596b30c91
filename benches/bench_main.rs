//! Criterion benchmarks of the researcher's loop, comparing hilo's components with independent
//! implementations on the same fixture. Each group prints the error it pays before it is timed:
//! ray casting (hilo's engine against parry3d), sensor frames, placement (the exact search
//! against CBC on an instance CBC can finish), evaluation (the nuScenes metric on a fixed
//! fixture, the bootstrap's reweighted curves against a direct evaluation), and fusion (forward
//! and forward + backward of one batch for every registered plugin: a new plugin appears here
//! by its registration alone), and the loss (its fused nodes against their composite). Run:
//! `cargo bench --bench bench_main`; list: `-- --list`.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use hilo::raycast::reference::{compare_with_parry, lidar_sweep, parry_trimesh};
use hilo::raycast::{QueryRegion, Scene, World};
use parry3d::query::RayCast;
use std::hint::black_box;

fn raycast(c: &mut Criterion) {
    let scene = Scene::default_fixture().expect("default scene");
    let world = World::build(&scene, &QueryRegion::everything()).expect("world");
    let parry = parry_trimesh(&scene, 10.0).expect("parry mesh");
    let ne = scene.mounts.iter().find(|m| m.name == "NE").expect("NE pole");
    let rays = lidar_sweep(ne.base.extend(7.8), 64, -35.0, 10.0, 1024, 120.0);
    let cmp = compare_with_parry(&scene, &world, &parry, 10.0, &rays);
    eprintln!("raycast error paid vs parry3d on these rays: {cmp:?}");

    let mut g = c.benchmark_group("closest_hit_64x1024_sweep");
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.bench_function("hilo", |b| {
        b.iter(|| rays.iter().filter(|r| world.closest_hit(black_box(r), None).is_some()).count())
    });
    g.bench_function("parry3d_trimesh", |b| {
        b.iter(|| {
            rays.iter()
                .filter(|r| parry.cast_local_ray(&parry3d::query::Ray::new(r.origin, r.dir), r.t_max, false).is_some())
                .count()
        })
    });
    g.bench_function("hilo_occlusion", |b| {
        b.iter(|| rays.iter().filter(|r| world.occluded(black_box(r), None)).count())
    });
    g.finish();

    let mut g = c.benchmark_group("build_default_scene");
    g.bench_function("hilo_world", |b| {
        b.iter(|| World::build(black_box(&scene), &QueryRegion::everything()).expect("world"))
    });
    g.bench_function("parry3d_trimesh", |b| b.iter(|| parry_trimesh(black_box(&scene), 10.0).expect("parry")));
    g.finish();
}

fn sensors(c: &mut Criterion) {
    use hilo::sensors::{Catalog, SensorPose, simulate_lidar, simulate_radar};
    let scene = Scene::default_fixture().expect("default scene");
    let world = World::build(&scene, &QueryRegion::everything()).expect("world");
    let catalog = Catalog::default_catalog().expect("catalog");
    let pose = SensorPose::new(hilo::core::glam::Vec3::new(13.0, 16.6, 7.8), -2.2, 0.17, 0.0);
    let mut g = c.benchmark_group("sensor_frame_static_scene");
    for name in ["lidar-16", "lidar-64"] {
        let spec = catalog.lidar(name).expect("lidar");
        g.bench_function(name, |b| b.iter(|| simulate_lidar(spec, &pose, &world, None, 1).expect("scan").points.len()));
    }
    let radar = catalog.radar("radar-4d").expect("radar");
    g.bench_function("radar-4d", |b| {
        b.iter(|| simulate_radar(radar, &pose, &world, None, 1).expect("scan").points.len())
    });
    // The same radar with a field radar's effects (multipath rays, side lobes, false alarms,
    // merging of unresolved detections): what they cost a frame.
    let field = Catalog::from_toml_str(
        include_str!("../fixtures/sensors-datasheet.toml"),
        std::path::Path::new("sensors-datasheet.toml"),
    )
    .expect("datasheet catalog");
    let radar = field.radar("radar-4d").expect("radar");
    g.bench_function("radar-4d-field-effects", |b| {
        b.iter(|| simulate_radar(radar, &pose, &world, None, 1).expect("scan").points.len())
    });
    // The datasheet LiDARs with their beams' width (19 sub-rays a pulse) and as rays of no
    // width: what the footprint costs a frame, and the points it changes.
    for name in ["lidar-16", "lidar-64"] {
        let wide = field.lidar(name).expect("lidar").clone();
        let thin = hilo::sensors::LidarSpec { beam: None, ..wide.clone() };
        let n = |s: &hilo::sensors::LidarSpec| simulate_lidar(s, &pose, &world, None, 1).expect("scan").points.len();
        eprintln!("{name} datasheet: {} points with the beam's width, {} as rays of no width", n(&wide), n(&thin));
        for (variant, spec) in [("no-width", thin), ("beam-width", wide)] {
            g.bench_function(format!("{name}-datasheet/{variant}"), |b| b.iter(|| n(&spec)));
        }
    }
    g.finish();
    lidar_points(c, &world, &catalog, &pose);
}

/// LiDAR points on road users (the calibrated objective's point-count rows): the rays towards
/// the road users' bounds only, against the full scan; the error paid is the road users whose
/// counts differ (0 by construction, checked here).
fn lidar_points(c: &mut Criterion, world: &World, catalog: &hilo::sensors::Catalog, pose: &hilo::sensors::SensorPose) {
    use hilo::core::glam::Vec3;
    use hilo::core::{Box3, Class};
    use hilo::raycast::{Actor, ActorSet};
    use hilo::sensors::{lidar_points_on, simulate_lidar};
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    // 40 road users over the junction, none overlapping: cars, pedestrians and buses.
    let mut actors: Vec<Actor> = Vec::new();
    let sizes = [(Class::Car, 4.5, 1.9, 1.6), (Class::Pedestrian, 0.6, 0.6, 1.75), (Class::Bus, 12.0, 2.6, 3.2)];
    while actors.len() < 40 {
        let (class, l, w, h) = sizes[actors.len() % 3];
        let c = Vec3::new(rng.random_range(-40.0..40.0), rng.random_range(-40.0..40.0), 0.5 * h);
        let a = Actor::from_box(actors.len() as u32, class, Box3::new(c, l, w, h, rng.random_range(-3.1..3.1)));
        let (lo, hi) = a.shape.aabb();
        if actors.iter().all(|b| {
            let (l2, h2) = b.shape.aabb();
            hi.x < l2.x || h2.x < lo.x || hi.y < l2.y || h2.y < lo.y
        }) {
            actors.push(a);
        }
    }
    let set = ActorSet::new(actors).expect("actors");
    let ids: Vec<u32> = (0..40).collect();
    let mut g = c.benchmark_group("lidar_points_on_40_road_users");
    for name in ["lidar-16", "lidar-64"] {
        let spec = catalog.lidar(name).expect("lidar");
        let full = simulate_lidar(spec, pose, world, Some(&set), 1).expect("scan").points_per_actor();
        let windowed = lidar_points_on(spec, pose, world, &set, 1, &ids).expect("count");
        let differ = ids.iter().filter(|id| full.get(id).copied().unwrap_or(0) != windowed[id]).count();
        eprintln!(
            "{name} points on road users, error paid: {differ} of {} road users' counts differ ({} points)",
            ids.len(),
            windowed.values().sum::<usize>()
        );
        g.bench_function(format!("{name}/full-scan"), |b| {
            b.iter(|| simulate_lidar(spec, pose, world, Some(&set), 1).expect("scan").points_per_actor().len())
        });
        g.bench_function(format!("{name}/windowed"), |b| {
            b.iter(|| lidar_points_on(spec, pose, world, &set, 1, black_box(&ids)).expect("count").len())
        });
    }
    g.finish();
}

fn placement(c: &mut Criterion) {
    use hilo::placement::mip::{Formulation, solve};
    use hilo::placement::{Instance, Limit, Modality, SensorOption, SensorType};
    use rand::{Rng, SeedableRng};
    // 24 LiDAR and 12 radar candidates on 8 mounts, 120 targets: small enough for CBC to prove
    // its optimum in well under a second.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let n_t = 120;
    let types = vec![
        SensorType { name: "lidar".into(), modality: Modality::Lidar, price_usd: 4000.0 },
        SensorType { name: "radar".into(), modality: Modality::Radar, price_usd: 2000.0 },
    ];
    let mut options = Vec::new();
    for (ty, n) in [(0usize, 24usize), (1, 12)] {
        for k in 0..n {
            let mut row = Vec::new();
            for j in 0..n_t as u32 {
                if rng.random_bool(0.35) {
                    row.push((
                        j,
                        if rng.random_bool(0.5) { rng.random_range(0.6f32..1.0) } else { rng.random_range(0.01..0.6) },
                    ));
                }
            }
            options.push(SensorOption { ty, candidate: options.len() as u32, mount: (k % 8) as u32, row });
        }
    }
    let weights = (0..n_t).map(|_| if rng.random_bool(0.3) { 3.0 } else { 1.0 }).collect();
    let inst = Instance {
        weights,
        types,
        options,
        p_min: 1.0 - (-1.0f64).exp(),
        road_users: Vec::new(),
        points: Default::default(),
        extents: Default::default(),
        floors: Vec::new(),
    };
    let limit = Limit::Counts(vec![2, 1]);
    let exact = hilo::placement::pipeline::solve(&inst, &limit, 60.0).expect("exact");
    let cbc = solve(&inst, &limit, Formulation::Plain, 60.0, None).expect("cbc");
    eprintln!(
        "placement error paid: exact search {:.3} (proven {}), CBC {:.3} (proven {}): difference {:.2e}",
        exact.objective,
        exact.proven_optimal,
        cbc.objective,
        cbc.proven_optimal,
        (exact.objective - cbc.objective).abs()
    );
    let mut g = c.benchmark_group("placement_36_candidates_120_targets");
    g.sample_size(10);
    g.bench_function("exact_search", |b| {
        b.iter(|| hilo::placement::pipeline::solve(black_box(&inst), &limit, 60.0).expect("exact").objective)
    });
    g.bench_function("cbc_plain", |b| {
        b.iter(|| solve(black_box(&inst), &limit, Formulation::Plain, 60.0, None).expect("cbc").objective)
    });
    g.finish();
}

fn evaluation(c: &mut Criterion) {
    use hilo::eval::boxes::{GroundTruth, SampleInfo};
    use hilo::eval::{DetectionConfig, EvalBox, evaluate_files};
    use rand::{Rng, SeedableRng};
    // 300 frames of 30 scenes, 45 ground-truth boxes and 100 predictions each.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let classes = ["car", "truck", "bus", "motorcycle", "pedestrian", "golf_cart"];
    let mut gt = GroundTruth::default();
    let mut pred = Vec::new();
    for f in 0..300 {
        let token = format!("s{f:04}");
        gt.samples.insert(token.clone(), SampleInfo { scene: format!("scene{}", f / 10), ego_translation: [0.0; 3] });
        let (mut g, mut p) = (Vec::new(), Vec::new());
        for _ in 0..45 {
            let cl = classes[rng.random_range(0..6)];
            let (x, y, yaw) =
                (rng.random_range(-40.0..40.0), rng.random_range(-40.0..40.0), rng.random_range(-3.0..3.0));
            g.push(EvalBox {
                num_pts: 10,
                ..EvalBox::from_yaw(&token, cl, [x, y, 0.8], [1.9, 4.5, 1.6], yaw, [2.0, 0.0], 1.0)
            });
            if rng.random_bool(0.8) {
                let d = [rng.random_range(-1.5..1.5), rng.random_range(-1.5..1.5)];
                let score = rng.random_range(0.0..1.0);
                p.push(EvalBox::from_yaw(
                    &token,
                    cl,
                    [x + d[0], y + d[1], 0.8],
                    [2.0, 4.4, 1.5],
                    yaw,
                    [1.5, 0.0],
                    score,
                ));
            }
        }
        while p.len() < 100 {
            let (x, y) = (rng.random_range(-40.0..40.0), rng.random_range(-40.0..40.0));
            let (cl, score) = (classes[rng.random_range(0..6)], rng.random_range(0.0..0.5));
            p.push(EvalBox::from_yaw(&token, cl, [x, y, 0.8], [1.9, 4.5, 1.6], 0.0, [0.0; 2], score));
        }
        gt.boxes.insert(token.clone(), g);
        pred.push((token, p));
    }
    let cfg = DetectionConfig::default();
    let direct = evaluate_files(&gt, &pred, &cfg);
    // The bootstrap reweights matches computed once; its point estimate must be the direct metric.
    let b = hilo::eval::bootstrap::bootstrap(&gt, &pred, &cfg, 8, 0.95, 0);
    eprintln!(
        "evaluation error paid: bootstrap point estimate {:.6} against the direct metric {:.6} (difference {:.2e})",
        b.mean_ap.estimate,
        direct.mean_ap,
        (b.mean_ap.estimate - direct.mean_ap).abs()
    );
    let mut g = c.benchmark_group("nuscenes_metric_300_frames");
    g.sample_size(10);
    g.bench_function("metric", |bch| bch.iter(|| evaluate_files(black_box(&gt), &pred, &cfg).mean_ap));
    g.bench_function("bootstrap_100", |bch| {
        bch.iter(|| hilo::eval::bootstrap::bootstrap(black_box(&gt), &pred, &cfg, 100, 0.95, 0).mean_ap.lo)
    });
    g.finish();
}

fn fusion(c: &mut Criterion) {
    use hilo::detector::conformance::{car, synthetic_frame};
    use hilo::detector::detector::{Detector, HostBatch};
    let registry = hilo::registry().expect("registry");
    // Two frames of road users without their static background (what the detectors read): 12
    // cars with LiDAR and radar returns each, on the default grid, on each preset's layout.
    let frames: Vec<_> = (0..2u64)
        .map(|s| {
            let boxes: Vec<_> = (0..12)
                .map(|k| car(-40.0 + 7.0 * k as f32, 6.0 * (s as f32 - 0.5) + (k % 3) as f32, 0.2 * k as f32, 5.0))
                .collect();
            let mut f = synthetic_frame(s, &boxes, true, true);
            f.lidar.retain(|p| p[2] > 0.1);
            f
        })
        .collect();
    // The error the sparse layout pays: one 3×3 convolution on these frames' occupied cells,
    // gathered along its rulebook, against candle's dense conv2d of the same input.
    {
        use candle_core::{Device, Tensor};
        let cfg = registry.preset("centerpoint").expect("centerpoint").detector.clone();
        let b = HostBatch::new(&cfg, &frames, false, 0);
        let h = b.sparse.as_ref().expect("sparse layout");
        let (n, cells, ci) = (h.sites[0].len(), cfg.grid.cells(), 8usize);
        let x = Tensor::randn(0f32, 1.0, (n, ci), &Device::Cpu).expect("x");
        let w = Tensor::randn(0f32, 1.0, (8, ci, 3, 3), &Device::Cpu).expect("w");
        let rules = hilo::fusion::layout::Rules::new(&h.subm[0], h.sites[0].len(), &Device::Cpu).expect("rules");
        let ys = hilo::fusion::layout::gather_conv(&x, &w, &rules).expect("sparse").to_vec2::<f32>().expect("ys");
        let xv = x.to_vec2::<f32>().expect("xv");
        let mut dense = vec![0f32; 2 * ci * cells * cells];
        for (i, &s) in h.sites[0].iter().enumerate() {
            let (bb, rc) = (s as usize / (cells * cells), s as usize % (cells * cells));
            for c in 0..ci {
                dense[(bb * ci + c) * cells * cells + rc] = xv[i][c];
            }
        }
        let xd = Tensor::from_vec(dense, (2, ci, cells, cells), &Device::Cpu).expect("xd");
        let yd = xd.conv2d(&w, 1, 1, 1, 1).expect("dense").flatten_all().expect("flat").to_vec1::<f32>().expect("yd");
        let mut err = 0f32;
        for (i, &s) in h.sites[0].iter().enumerate() {
            let (bb, rc) = (s as usize / (cells * cells), s as usize % (cells * cells));
            for c in 0..8 {
                err = err.max((ys[i][c] - yd[(bb * 8 + c) * cells * cells + rc]).abs());
            }
        }
        eprintln!(
            "fusion error paid: sparse 3x3 convolution on {n} of {} cells against candle's conv2d: max |difference| {err:.2e}",
            2 * cells * cells
        );
    }
    let mut g = c.benchmark_group("fusion_batch_of_2");
    g.sample_size(10);
    for plugin in registry.names() {
        let Some(preset) =
            registry.preset_names().into_iter().find(|p| registry.preset(p).is_ok_and(|x| x.detector.fusion == plugin))
        else {
            eprintln!("fusion plugin {plugin}: no preset uses it, not benchmarked");
            continue;
        };
        let cfg = registry.preset(&preset).expect("preset").detector.clone().validate().expect("a valid preset");
        let det = Detector::new(&cfg, &registry, &candle_core::Device::Cpu, 0).expect("detector");
        let batch = HostBatch::new(&cfg, &frames, det.uses_radar(), 0);
        g.bench_function(format!("{plugin}/{preset}/forward"), |b| {
            b.iter(|| det.forward_heads(black_box(&batch), false).expect("forward").len())
        });
        g.bench_function(format!("{plugin}/{preset}/forward_backward"), |b| {
            b.iter(|| {
                let heads = det.forward_heads(black_box(&batch), true).expect("forward");
                let loss = det.loss_all(&heads, &batch.targets).expect("loss");
                loss.total.backward().expect("backward")
            })
        });
    }
    g.finish();
}

/// The detector's loss, forward and backward, as one fused node per loss against its composite
/// of candle's operations (the lever `hilo bench train --variant fused=...` turns), on the head
/// outputs of `centerpoint` (sparse sites) and `pointpillars` (dense maps) for a batch of two
/// frames. The error paid: the largest difference of the loss and of its gradient, relative to
/// the composite's largest value.
fn loss(c: &mut Criterion) {
    use hilo::detector::conformance::{car, synthetic_frame};
    use hilo::detector::detector::{Detector, HostBatch};
    use hilo::fusion::cpu::{Layer, set_fused};
    // The composite loss, every other layer fused as in training.
    const COMPOSITE_LOSS: [Layer; 2] = [Layer::Conv, Layer::BnRelu];
    let registry = hilo::registry().expect("registry");
    let frames: Vec<_> = (0..2u64)
        .map(|s| {
            let boxes: Vec<_> =
                (0..12).map(|k| car(-40.0 + 7.0 * k as f32, 6.0 * (s as f32 - 0.5), 0.2 * k as f32, 5.0)).collect();
            synthetic_frame(s, &boxes, true, false)
        })
        .collect();
    let mut g = c.benchmark_group("loss_batch_of_2");
    for preset in ["centerpoint", "pointpillars"] {
        let cfg = registry.preset(preset).expect("preset").detector.clone().validate().expect("a valid preset");
        let det = Detector::new(&cfg, &registry, &candle_core::Device::Cpu, 0).expect("detector");
        let batch = HostBatch::new(&cfg, &frames, det.uses_radar(), 0);
        let (cls, reg) = det.forward(&batch, false).expect("forward");
        let (cls, reg) =
            (candle_core::Var::from_tensor(&cls).expect("cls"), candle_core::Var::from_tensor(&reg).expect("reg"));
        let run = || {
            let l = det.loss(cls.as_tensor(), reg.as_tensor(), &batch.targets).expect("loss");
            let g = l.total.backward().expect("backward");
            let grad = |v: &candle_core::Var| {
                g.get(v.as_tensor()).expect("gradient").flatten_all().expect("flat").to_vec1::<f32>().expect("host")
            };
            (l.total.to_scalar::<f32>().expect("scalar"), [grad(&cls), grad(&reg)].concat())
        };
        let fused = run();
        set_fused(&COMPOSITE_LOSS);
        let composite = run();
        set_fused(&Layer::ALL);
        let scale = composite.1.iter().fold(0f32, |m, v| m.max(v.abs()));
        let worst = fused.1.iter().zip(&composite.1).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        eprintln!(
            "loss error paid ({preset}, {} elements): value {:.1e} relative, gradient {:.1e} of its largest",
            cls.elem_count() + reg.elem_count(),
            ((fused.0 - composite.0) / composite.0).abs(),
            worst / scale
        );
        g.bench_function(format!("{preset}/fused"), |b| b.iter(|| black_box(run()).0));
        set_fused(&COMPOSITE_LOSS);
        g.bench_function(format!("{preset}/composite"), |b| b.iter(|| black_box(run()).0));
        set_fused(&Layer::ALL);
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(std::time::Duration::from_secs(3));
    targets = raycast, sensors, placement, evaluation, fusion, loss
}
criterion_main!(benches);
