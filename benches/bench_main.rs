//! Criterion benchmarks comparing hilo's components with independent implementations on the
//! same fixture. Each group prints the error it pays before it is timed.
//! Run: `cargo bench --bench bench_main` (the whole-machine figure is `hilo bench raycast --json`).

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
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(std::time::Duration::from_secs(3));
    targets = raycast, sensors
}
criterion_main!(benches);
