//! Independent references for tests and benchmarks: the same scene as a parry3d `TriMesh`,
//! and LiDAR-like sweeps of rays.

use crate::error::RaycastError;
use crate::ray::Ray;
use crate::scene::Scene;
use glam::Vec3;
use parry3d::shape::TriMesh;

/// The scene's static triangles plus its ground, tessellated into square tiles of
/// `ground_tile_m` (parry has no analytic plane; tiles keep its BVH tight), as one parry
/// `TriMesh`.
pub fn parry_trimesh(scene: &Scene, ground_tile_m: f32) -> Result<TriMesh, RaycastError> {
    let mut vertices: Vec<Vec3> = Vec::with_capacity(scene.mesh.len() * 3);
    let mut indices: Vec<[u32; 3]> = Vec::with_capacity(scene.mesh.len());
    for t in ground_triangles(scene, ground_tile_m).iter().chain(&scene.mesh.triangles) {
        let base = vertices.len() as u32;
        vertices.extend_from_slice(t);
        indices.push([base, base + 1, base + 2]);
    }
    TriMesh::new(vertices, indices).map_err(|e| RaycastError::Geometry(format!("parry TriMesh: {e:?}")))
}

/// The ground rectangle as triangles on a grid of `tile_m` squares (at least one tile).
pub fn ground_triangles(scene: &Scene, tile_m: f32) -> Vec<[Vec3; 3]> {
    let g = scene.ground;
    let size = g.max - g.min;
    let nx = ((size.x / tile_m).ceil() as usize).max(1);
    let ny = ((size.y / tile_m).ceil() as usize).max(1);
    let p = |i: usize, j: usize| {
        Vec3::new(
            if i == nx { g.max.x } else { g.min.x + size.x * i as f32 / nx as f32 },
            if j == ny { g.max.y } else { g.min.y + size.y * j as f32 / ny as f32 },
            g.z_m,
        )
    };
    let mut out = Vec::with_capacity(nx * ny * 2);
    for i in 0..nx {
        for j in 0..ny {
            out.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
            out.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
        }
    }
    out
}

/// A spinning-LiDAR sweep from `origin`: `beams` elevations spread uniformly over
/// `elev_min_deg..=elev_max_deg`, `azimuth_steps` azimuths over 360°, unit directions,
/// range `max_range_m`. Rays are ordered column by column, as the sensor fires them.
pub fn lidar_sweep(
    origin: Vec3,
    beams: usize,
    elev_min_deg: f32,
    elev_max_deg: f32,
    azimuth_steps: usize,
    max_range_m: f32,
) -> Vec<Ray> {
    let mut rays = Vec::with_capacity(beams * azimuth_steps);
    for a in 0..azimuth_steps {
        let az = std::f32::consts::TAU * a as f32 / azimuth_steps as f32;
        for b in 0..beams {
            let el = if beams == 1 {
                elev_min_deg
            } else {
                elev_min_deg + (elev_max_deg - elev_min_deg) * b as f32 / (beams - 1) as f32
            }
            .to_radians();
            let dir = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            rays.push(Ray::new(origin, dir, max_range_m));
        }
    }
    rays
}

/// The benchmark pattern: a 64-beam sweep (−35°..+10°, 4,096 azimuth steps, 120 m) from
/// 0.3 m above the top of every mounting pole of the scene.
pub fn pole_top_sweeps(scene: &Scene, azimuth_steps: usize) -> Vec<Ray> {
    scene
        .mounts
        .iter()
        .flat_map(|m| {
            let o = m.base.extend(scene.ground.z_m + m.pole_height_m + 0.3);
            lidar_sweep(o, 64, -35.0, 10.0, azimuth_steps, 120.0)
        })
        .collect()
}

/// How hilo's closest hits compare with parry3d's on the same rays.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Comparison {
    pub rays: usize,
    /// One engine hit something, the other nothing.
    pub hit_miss_mismatches: usize,
    /// Both hit, at distances more than [`DIST_TOL_M`] apart.
    pub distance_disagreements: usize,
    /// Disagreements (either kind) where the earlier of the two hit points lies on an edge or
    /// vertex of the mesh (within 2e-4 m). Two causes, both legitimate: parry's ray–triangle
    /// test is not watertight, so a ray through the crack between two triangles slips through
    /// (hilo hits, parry hits something behind or nothing); or the ray crosses an edge where two
    /// faces meet at an angle, and f32 rounding of a few 1e-5 m decides which face is first,
    /// which at a grazing angle moves the distance by more than the tolerance.
    pub explained_by_shared_edge: usize,
    /// Disagreements with no such explanation (a correct pair of engines has none).
    pub unexplained: usize,
    /// Largest |t_hilo − t_parry| over rays where both hit, leaving out those explained by a
    /// shared edge, metres.
    pub max_abs_dist_err_m: f64,
}

/// Distance tolerance of the comparison, metres.
pub const DIST_TOL_M: f32 = 1e-4;

/// Distance from `p` to segment `ab`.
fn seg_dist(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
    (a + ab * t - p).length()
}

/// True when `p` lies (within `eps`) on an edge of a triangle of `tris` whose plane holds it.
pub fn on_mesh_edge(p: Vec3, tris: &[[Vec3; 3]], eps: f32) -> bool {
    tris.iter().any(|&[a, b, c]| {
        let n = (b - a).cross(c - a).normalize_or_zero();
        n != Vec3::ZERO
            && (p - a).dot(n).abs() < eps
            && (seg_dist(p, a, b) < eps || seg_dist(p, b, c) < eps || seg_dist(p, c, a) < eps)
    })
}

/// Casts `rays` through hilo's `world` and parry's `mesh` (built by [`parry_trimesh`] with
/// the same `ground_tile_m`) and classifies every disagreement.
pub fn compare_with_parry(
    scene: &Scene,
    world: &crate::World,
    mesh: &TriMesh,
    ground_tile_m: f32,
    rays: &[Ray],
) -> Comparison {
    use parry3d::query::RayCast;
    use rayon::prelude::*;
    let mut all = ground_triangles(scene, ground_tile_m);
    all.extend_from_slice(&scene.mesh.triangles);
    rays.par_iter()
        .map(|r| {
            let mut c = Comparison { rays: 1, ..Comparison::default() };
            let h = world.closest_hit(r, None);
            let p = mesh.cast_local_ray(&parry3d::query::Ray::new(r.origin, r.dir), r.t_max, false);
            // The earlier hit point of the two, if it lies on a mesh edge.
            let first_on_edge = |th: Option<f32>, tp: Option<f32>| {
                let t = th.unwrap_or(f32::INFINITY).min(tp.unwrap_or(f32::INFINITY));
                t.is_finite() && on_mesh_edge(r.at(t), &all, 2e-4)
            };
            let th = h.map(|h| h.t);
            match (th, p) {
                (None, None) => {}
                (Some(t), Some(tp)) => {
                    let err = (t - tp).abs();
                    if err > DIST_TOL_M && first_on_edge(th, p) {
                        c.distance_disagreements = 1;
                        c.explained_by_shared_edge = 1;
                    } else {
                        c.max_abs_dist_err_m = err as f64;
                        if err > DIST_TOL_M {
                            c.distance_disagreements = 1;
                            c.unexplained = 1;
                        }
                    }
                }
                _ => {
                    c.hit_miss_mismatches = 1;
                    if first_on_edge(th, p) {
                        c.explained_by_shared_edge = 1;
                    } else {
                        c.unexplained = 1;
                    }
                }
            }
            c
        })
        .reduce(Comparison::default, |a, b| Comparison {
            rays: a.rays + b.rays,
            hit_miss_mismatches: a.hit_miss_mismatches + b.hit_miss_mismatches,
            distance_disagreements: a.distance_disagreements + b.distance_disagreements,
            explained_by_shared_edge: a.explained_by_shared_edge + b.explained_by_shared_edge,
            unexplained: a.unexplained + b.unexplained,
            max_abs_dist_err_m: a.max_abs_dist_err_m.max(b.max_abs_dist_err_m),
        })
}
