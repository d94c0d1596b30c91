//! `hilo bench raycast`: hilo's engine against parry3d's TriMesh and raw obvhs on the same rays.

use anyhow::Result;
use hilo_raycast::reference::{compare_with_parry, ground_triangles, parry_trimesh, pole_top_sweeps};
use hilo_raycast::{QueryRegion, Ray, Scene, World};
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::triangle::Triangle;
use parry3d::query::RayCast;
use rayon::prelude::*;
use serde::Serialize;
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
        println!("{:<28} {:>12.2} {:>12.2} {:>10.1}", "hilo (watertight)", self.hilo_mrays_per_s, self.hilo_1t_mrays_per_s, self.hilo_build_ms);
        println!("{:<28} {:>12.2} {:>12.2} {:>10.1}", "parry3d TriMesh", self.parry_mrays_per_s, self.parry_1t_mrays_per_s, self.parry_build_ms);
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
    let (hilo_s, hilo_t) = time(repeats, || rays.par_chunks(chunk).flat_map_iter(|c| c.iter().map(hilo_cast)).collect::<Vec<_>>());
    let (parry_s, parry_t) = time(repeats, || rays.par_chunks(chunk).flat_map_iter(|c| c.iter().map(parry_cast)).collect::<Vec<_>>());

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
    let (obvhs_s, obvhs_t) = time(repeats, || rays.par_chunks(chunk).flat_map_iter(|c| c.iter().map(obvhs_cast)).collect::<Vec<_>>());

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
