//! The ray-query engine: analytic ground, static triangles in a BVH, and the frame's actors.

use crate::actors::ActorSet;
use crate::bvh::TriangleBvh;
use crate::error::RaycastError;
use crate::ray::{Hit, HitTarget, Material, Ray};
use crate::scene::{Scene, SceneObject};
use crate::shapes::GroundPlane;
use glam::Vec3;
use rayon::prelude::*;

/// The part of space a set of queries can reach. Static geometry entirely outside it is left
/// out of the acceleration structure: a sensor's range sphere, or the ROI's bounds, are enough
/// to decide what needs modelling.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct QueryRegion {
    /// `(centre, radius)` spheres, e.g. sensor positions and maximum ranges.
    pub spheres: Vec<(Vec3, f32)>,
    /// Axis-aligned `(min, max)` boxes, e.g. the ROI's bounds extended upward.
    pub boxes: Vec<(Vec3, Vec3)>,
}

impl QueryRegion {
    /// No restriction: everything is modelled.
    pub fn everything() -> Self {
        Self::default()
    }

    /// The union of spheres around sensors.
    pub fn spheres(spheres: impl IntoIterator<Item = (Vec3, f32)>) -> Self {
        Self { spheres: spheres.into_iter().collect(), boxes: Vec::new() }
    }

    pub fn is_everything(&self) -> bool {
        self.spheres.is_empty() && self.boxes.is_empty()
    }

    /// True when the box `lo..=hi` may be reached by a query.
    pub fn overlaps(&self, lo: Vec3, hi: Vec3) -> bool {
        if self.is_everything() {
            return true;
        }
        self.spheres.iter().any(|&(c, r)| (c.clamp(lo, hi) - c).length_squared() <= r * r)
            || self.boxes.iter().any(|&(blo, bhi)| lo.cmple(bhi).all() && blo.cmple(hi).all())
    }
}

/// Closest-hit and occlusion queries over a scene, built once per scene and region and shared
/// read-only by all threads.
#[derive(Clone, Debug)]
pub struct World {
    ground: Option<GroundPlane>,
    bvh: TriangleBvh,
    /// Object index of every scene triangle (by scene triangle index).
    triangle_object: Vec<u32>,
    objects: Vec<SceneObject>,
}

impl World {
    /// Builds the engine for `scene`, keeping only static triangles that `region` can reach.
    pub fn build(scene: &Scene, region: &QueryRegion) -> Result<Self, RaycastError> {
        let keep: Vec<u32> = (0..scene.mesh.len() as u32)
            .filter(|&k| {
                let [a, b, c] = scene.mesh.triangles[k as usize];
                region.overlaps(a.min(b).min(c), a.max(b).max(c))
            })
            .collect();
        let tris: Vec<[Vec3; 3]> = keep.iter().map(|&k| scene.mesh.triangles[k as usize]).collect();
        let mut bvh = TriangleBvh::build(&tris)?;
        bvh.remap_ids(&keep);
        Ok(World {
            ground: Some(scene.ground),
            bvh,
            triangle_object: scene.mesh.object.clone(),
            objects: scene.objects.clone(),
        })
    }

    /// An engine over bare triangles (every triangle is object 0, "mesh"), with an optional
    /// ground: for tests, tools and callers that build geometry themselves.
    pub fn from_triangles(triangles: &[[Vec3; 3]], ground: Option<GroundPlane>) -> Result<Self, RaycastError> {
        let object = SceneObject { name: "mesh".into(), kind: crate::ObjectKind::Mesh, material: Material::Building };
        Ok(World {
            ground,
            bvh: TriangleBvh::build(triangles)?,
            triangle_object: vec![0; triangles.len()],
            objects: vec![object],
        })
    }

    /// Number of static triangles in the acceleration structure.
    pub fn triangle_count(&self) -> usize {
        self.bvh.triangle_count()
    }

    /// Scene objects that have at least one triangle in the structure.
    pub fn objects_present(&self) -> std::collections::BTreeSet<u32> {
        self.bvh.triangle_ids().iter().map(|&k| self.triangle_object[k as usize]).collect()
    }

    pub fn objects(&self) -> &[SceneObject] {
        &self.objects
    }

    pub fn ground(&self) -> Option<&GroundPlane> {
        self.ground.as_ref()
    }

    /// The closest surface hit by `ray` in `(ray.t_min, ray.t_max)`: ground, actors (if given)
    /// or static geometry. The ground is intersected first so that every ray enters the BVH
    /// with the shortest possible range.
    #[inline]
    pub fn closest_hit(&self, ray: &Ray, actors: Option<&ActorSet>) -> Option<Hit> {
        self.closest_hit_at(ray, actors, 0.0)
    }

    /// [`World::closest_hit`] with the actors where they are `dt` seconds after the frame's
    /// instant ([`ActorSet::closest_at`]): a ray of a spinning LiDAR fired `dt` into its sweep.
    #[inline]
    pub fn closest_hit_at(&self, ray: &Ray, actors: Option<&ActorSet>, dt: f32) -> Option<Hit> {
        let mut t_max = ray.t_max;
        let mut best = None;
        if let Some((t, g)) = self.ground.as_ref().and_then(|g| Some((g.intersect(ray, t_max)?, g))) {
            t_max = t;
            best = Some(Hit::new(ray, t, g.normal(), HitTarget::Ground, Material::Asphalt));
        }
        if let Some(h) = actors.and_then(|a| a.closest_at(ray, t_max, dt)) {
            t_max = h.t;
            best = Some(h);
        }
        if let Some((t, tri, n)) = self.bvh.closest(ray, t_max) {
            let object = self.triangle_object[tri as usize];
            let material = self.objects.get(object as usize).map_or(Material::Building, |o| o.material);
            best = Some(Hit::new(ray, t, n, HitTarget::Static { object, triangle: tri }, material));
        }
        best
    }

    /// True when anything blocks `ray` in `(ray.t_min, ray.t_max)` (line-of-sight queries).
    #[inline]
    pub fn occluded(&self, ray: &Ray, actors: Option<&ActorSet>) -> bool {
        self.ground.as_ref().is_some_and(|g| g.intersect(ray, ray.t_max).is_some())
            || actors.is_some_and(|a| a.any(ray, ray.t_max))
            || self.bvh.any(ray, ray.t_max)
    }

    /// Closest hits of many rays, in parallel on rayon's pool; output order = input order.
    pub fn cast_batch(&self, rays: &[Ray], actors: Option<&ActorSet>) -> Vec<Option<Hit>> {
        rays.par_iter().with_min_len(512).map(|r| self.closest_hit(r, actors)).collect()
    }

    /// Occlusion of many rays, in parallel; output order = input order.
    pub fn occluded_batch(&self, rays: &[Ray], actors: Option<&ActorSet>) -> Vec<bool> {
        rays.par_iter().with_min_len(512).map(|r| self.occluded(r, actors)).collect()
    }
}
