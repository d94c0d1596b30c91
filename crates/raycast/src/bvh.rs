//! Bounding volume hierarchies: built by obvhs (PLOC BVH2), traversed here.
//!
//! hilo keeps obvhs's builder and node layout but traverses with its own loop, for three
//! reasons: the triangle test must be watertight (obvhs's Möller–Trumbore is not), the
//! traversal stack carries entry distances so that subtrees behind a closer hit are skipped
//! when popped, and the slab test is made conservative (Ize, "Robust BVH Ray Traversal",
//! JCGT 2013) so that rays grazing a box face are never culled by rounding.
//!
//! BVH2 was chosen over obvhs's CWBVH by measurement (docs/measurements.md): with hilo's own
//! closest-hit loop it traverses and builds faster on the default scene.

use crate::error::RaycastError;
use crate::ray::Ray;
use crate::shapes::triangle::{ShearedRay, triangle_normal};
use glam::{Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::{Bvh2, builder::build_bvh2, builder::build_bvh2_from_tris};
use obvhs::triangle::Triangle;
use std::time::Duration;

/// Traversal stack depth; builds deeper than this are rejected (PLOC trees over a few million
/// primitives stay far below it).
const STACK: usize = 64;

/// `1 + 2γ₃` (Ize 2013): scaling the far slab distance by it makes the box test conservative.
const ROBUST_FAR: f32 = 1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// A ray prepared for slab tests.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SlabRay {
    origin: Vec3A,
    inv_dir: Vec3A,
    t_min: f32,
}

impl SlabRay {
    pub(crate) fn new(ray: &Ray) -> Self {
        // A zero component becomes ±1e-30 instead of ±0 so that 1/d stays finite and
        // (bound - origin) * inv_dir never evaluates 0 * inf = NaN.
        let safe = |d: f32| if d.abs() < 1e-30 { 1e-30f32.copysign(d) } else { d };
        let d = ray.dir;
        SlabRay {
            origin: Vec3A::from(ray.origin),
            inv_dir: Vec3A::new(1.0 / safe(d.x), 1.0 / safe(d.y), 1.0 / safe(d.z)),
            t_min: ray.t_min,
        }
    }

    /// Entry distance into the box if the ray overlaps it within `[t_min, t_max]`, else +inf.
    #[inline(always)]
    pub(crate) fn entry(&self, aabb: &Aabb, t_max: f32) -> f32 {
        let t1 = (aabb.min - self.origin) * self.inv_dir;
        let t2 = (aabb.max - self.origin) * self.inv_dir;
        let near = t1.min(t2).max_element();
        // Plain comparisons: f32::min/max with NaN semantics cost twice the whole traversal.
        let far = t1.max(t2).min_element() * ROBUST_FAR;
        if far >= near && far >= self.t_min && near < t_max { near } else { f32::INFINITY }
    }
}

/// Front-to-back traversal of an obvhs BVH2. `leaf(first, count, t_max)` tests the primitives
/// `first..first + count` (indices into the BVH's primitive order), may lower `t_max` to a new
/// closest hit, and returns true to stop the traversal (any-hit queries).
#[inline(always)]
pub(crate) fn traverse(bvh: &Bvh2, ray: &SlabRay, t_max: &mut f32, mut leaf: impl FnMut(u32, u32, &mut f32) -> bool) {
    let nodes = &bvh.nodes;
    let Some(root) = nodes.first() else { return };
    if ray.entry(root.aabb(), *t_max) == f32::INFINITY {
        return;
    }
    if root.is_leaf() {
        leaf(root.first_index, root.prim_count, t_max);
        return;
    }
    let mut stack = [(0u32, 0f32); STACK];
    let mut len = 0usize;
    let mut current = root.first_index as usize;
    loop {
        let (mut a, mut b) = (&nodes[current], &nodes[current + 1]);
        let mut ta = ray.entry(a.aabb(), *t_max);
        let mut tb = ray.entry(b.aabb(), *t_max);
        if tb < ta {
            std::mem::swap(&mut a, &mut b);
            std::mem::swap(&mut ta, &mut tb);
        }
        let mut next = None;
        if ta != f32::INFINITY {
            if a.is_leaf() {
                if leaf(a.first_index, a.prim_count, t_max) {
                    return;
                }
            } else {
                next = Some(a.first_index as usize);
            }
        }
        // The first leaf may have lowered t_max: re-check the farther child against it.
        if tb < *t_max {
            if b.is_leaf() {
                if leaf(b.first_index, b.prim_count, t_max) {
                    return;
                }
            } else if next.is_none() {
                next = Some(b.first_index as usize);
            } else {
                stack[len] = (b.first_index, tb);
                len += 1;
            }
        }
        match next {
            Some(n) => current = n,
            None => loop {
                if len == 0 {
                    return;
                }
                len -= 1;
                let (n, t) = stack[len];
                if t < *t_max {
                    current = n as usize;
                    break;
                }
            },
        }
    }
}

/// The tree's real depth (obvhs's `max_depth` is a stack capacity, not a measurement).
fn tree_depth(bvh: &Bvh2) -> usize {
    let Some(root) = bvh.nodes.first() else { return 0 };
    let mut deepest = 1;
    let mut todo = vec![(root, 1usize)];
    while let Some((node, d)) = todo.pop() {
        deepest = deepest.max(d);
        if !node.is_leaf() {
            let i = node.first_index as usize;
            todo.push((&bvh.nodes[i], d + 1));
            todo.push((&bvh.nodes[i + 1], d + 1));
        }
    }
    deepest
}

/// Grows every node box by a few ulps of its coordinates (plus 1e-6 m). A ray lying exactly
/// in a box's face plane, with a zero direction component, would otherwise get an exit
/// distance of exactly 0 on that axis and be culled; padded, it stays strictly inside the slab.
/// The cost is a negligible number of extra node visits.
fn pad_boxes(bvh: &mut Bvh2) {
    for node in &mut bvh.nodes {
        let a = *node.aabb();
        let pad = a.min.abs().max(a.max.abs()) * (8.0 * f32::EPSILON) + Vec3A::splat(1e-6);
        node.set_aabb(Aabb::new(a.min - pad, a.max + pad));
    }
}

/// Rejects trees deeper than the traversal stack (a pushed entry per level at most).
fn check_depth(bvh: &Bvh2, what: &str) -> Result<(), RaycastError> {
    let depth = tree_depth(bvh);
    if depth >= STACK {
        return Err(RaycastError::Geometry(format!(
            "{what} BVH is {depth} levels deep, above the traversal limit {STACK}"
        )));
    }
    Ok(())
}

/// Static triangles in a BVH2, stored in the BVH's leaf order so a leaf reads contiguous memory.
#[derive(Clone)]
pub struct TriangleBvh {
    bvh: Bvh2,
    /// Vertices in BVH primitive order.
    tris: Vec<[Vec3; 3]>,
    /// For each BVH-ordered triangle, its index in the caller's triangle list.
    original: Vec<u32>,
}

impl TriangleBvh {
    /// Builds over `tris` (a triangle's index in this slice is what queries return).
    pub fn build(tris: &[[Vec3; 3]]) -> Result<Self, RaycastError> {
        if tris.is_empty() {
            return Ok(TriangleBvh { bvh: Bvh2::default(), tris: Vec::new(), original: Vec::new() });
        }
        if let Some(i) = tris.iter().position(|t| !t.iter().all(|v| v.is_finite())) {
            return Err(RaycastError::Geometry(format!("triangle {i} has a non-finite vertex")));
        }
        let obvhs_tris: Vec<Triangle> =
            tris.iter().map(|t| Triangle { v0: t[0].into(), v1: t[1].into(), v2: t[2].into() }).collect();
        let mut bvh = build_bvh2_from_tris(&obvhs_tris, BvhBuildParams::medium_build(), &mut Duration::default());
        check_depth(&bvh, "triangle")?;
        pad_boxes(&mut bvh);
        let original = bvh.primitive_indices.clone();
        let tris = original.iter().map(|&i| tris[i as usize]).collect();
        Ok(TriangleBvh { bvh, tris, original })
    }

    /// Renames the caller's triangle indices: index `i` becomes `ids[i]`.
    pub(crate) fn remap_ids(&mut self, ids: &[u32]) {
        for o in &mut self.original {
            *o = ids[*o as usize];
        }
    }

    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// The caller's indices of the triangles held, in no particular order.
    pub fn triangle_ids(&self) -> &[u32] {
        &self.original
    }

    /// Closest triangle hit in `(ray.t_min, t_max)`: `(t, caller's triangle index, unit
    /// geometric normal by the triangle's winding)`.
    #[inline]
    pub fn closest(&self, ray: &Ray, t_max: f32) -> Option<(f32, u32, Vec3)> {
        let sheared = ShearedRay::new(ray);
        match sheared.kz {
            0 => self.closest_axis::<0>(&sheared, ray, t_max),
            1 => self.closest_axis::<1>(&sheared, ray, t_max),
            _ => self.closest_axis::<2>(&sheared, ray, t_max),
        }
    }

    #[inline(always)]
    fn closest_axis<const KZ: usize>(&self, sheared: &ShearedRay, ray: &Ray, t_max: f32) -> Option<(f32, u32, Vec3)> {
        let slab = SlabRay::new(ray);
        let mut best = t_max;
        let mut hit = None;
        traverse(&self.bvh, &slab, &mut best, |first, count, t_max| {
            for k in first..first + count {
                let [a, b, c] = self.tris[k as usize];
                if let Some(t) = sheared.intersect_axis::<KZ>(a, b, c, *t_max) {
                    *t_max = t;
                    hit = Some(k);
                }
            }
            false
        });
        hit.map(|k| {
            let [a, b, c] = self.tris[k as usize];
            (refine_t(ray, a, b, c, best), self.original[k as usize], triangle_normal(a, b, c))
        })
    }

    /// True when any triangle is hit in `(ray.t_min, t_max)`.
    #[inline]
    pub fn any(&self, ray: &Ray, t_max: f32) -> bool {
        let sheared = ShearedRay::new(ray);
        let slab = SlabRay::new(ray);
        let mut limit = t_max;
        let mut found = false;
        traverse(&self.bvh, &slab, &mut limit, |first, count, t_max| {
            for k in first..first + count {
                let [a, b, c] = self.tris[k as usize];
                if sheared.intersect(a, b, c, *t_max).is_some() {
                    found = true;
                    return true;
                }
            }
            false
        });
        found
    }
}

/// The distance to the plane of a triangle already known to be hit, recomputed in f64.
///
/// The watertight test decides *whether* a triangle is hit robustly, but its distance, a
/// barycentric blend of sheared vertex depths, loses digits on long sliver triangles (a 130 m
/// curb face 0.15 m high gave 1.8e-4 m errors at 40–60 m). Intersecting the triangle's plane in
/// f64 brings the error back to f32 rounding of the inputs. Grazing rays (nearly parallel to the
/// plane) keep the watertight value.
#[inline]
fn refine_t(ray: &Ray, a: Vec3, b: Vec3, c: Vec3, t: f32) -> f32 {
    let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
    let n = (b - a).cross(c - a);
    let (o, d) = (ray.origin.as_dvec3(), ray.dir.as_dvec3());
    let denom = n.dot(d);
    if denom.abs() <= 1e-6 * n.length() {
        return t;
    }
    let refined = (n.dot(a - o) / denom) as f32;
    // Stay inside the bracket the traversal accepted.
    if refined > ray.t_min && (refined - t).abs() <= 1e-3 * t.max(1.0) { refined } else { t }
}

/// A BVH2 over axis-aligned boxes (one per actor); leaves refer to box indices.
#[derive(Clone, Default)]
pub(crate) struct BoxBvh {
    bvh: Bvh2,
}

impl BoxBvh {
    pub(crate) fn build(boxes: &[(Vec3, Vec3)]) -> Result<Self, RaycastError> {
        if boxes.is_empty() {
            return Ok(Self::default());
        }
        let aabbs: Vec<Aabb> = boxes.iter().map(|(lo, hi)| Aabb::new((*lo).into(), (*hi).into())).collect();
        let mut bvh = build_bvh2(&aabbs, BvhBuildParams::fastest_build(), &mut Duration::default());
        check_depth(&bvh, "actor")?;
        pad_boxes(&mut bvh);
        Ok(Self { bvh })
    }

    /// Runs `leaf(box index, t_max) -> stop` on every box whose bounds the ray reaches.
    #[inline]
    pub(crate) fn traverse(&self, ray: &Ray, t_max: &mut f32, mut leaf: impl FnMut(u32, &mut f32) -> bool) {
        let slab = SlabRay::new(ray);
        let order = &self.bvh.primitive_indices;
        traverse(&self.bvh, &slab, t_max, |first, count, t_max| {
            (first..first + count).any(|k| leaf(order[k as usize], t_max))
        });
    }
}

impl std::fmt::Debug for TriangleBvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TriangleBvh")
            .field("triangles", &self.tris.len())
            .field("nodes", &self.bvh.nodes.len())
            .field("max_depth", &self.bvh.max_depth)
            .finish()
    }
}

impl std::fmt::Debug for BoxBvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BoxBvh").field("nodes", &self.bvh.nodes.len()).finish()
    }
}
