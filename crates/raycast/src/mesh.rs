//! Triangle soup with a per-triangle object id, and builders for the primitives a scene is made
//! of (extruded polygons, boxes, cylinders, ellipsoids).

use crate::error::RaycastError;
use glam::{Vec2, Vec3};

/// Triangles of the static scene. `object[k]` is the scene object that triangle `k` belongs to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriangleMesh {
    pub triangles: Vec<[Vec3; 3]>,
    pub object: Vec<u32>,
}

impl TriangleMesh {
    pub fn len(&self) -> usize {
        self.triangles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    pub fn push(&mut self, tri: [Vec3; 3], object: u32) {
        self.triangles.push(tri);
        self.object.push(object);
    }

    /// Adds an indexed triangle list, checking every index.
    pub fn push_indexed(&mut self, vertices: &[Vec3], indices: &[[u32; 3]], object: u32) -> Result<(), String> {
        for (k, idx) in indices.iter().enumerate() {
            let mut tri = [Vec3::ZERO; 3];
            for (slot, &i) in tri.iter_mut().zip(idx) {
                *slot = *vertices.get(i as usize).ok_or_else(|| {
                    format!("face {k} refers to vertex {i}, but there are only {} vertices", vertices.len())
                })?;
            }
            self.push(tri, object);
        }
        Ok(())
    }

    /// Adds a quad `a b c d` (in order around its boundary) as two triangles.
    pub fn push_quad(&mut self, q: [Vec3; 4], object: u32) {
        self.push([q[0], q[1], q[2]], object);
        self.push([q[0], q[2], q[3]], object);
    }

    /// A vertical prism over a simple polygon from `z0` to `z1`: walls, top and bottom.
    pub fn push_prism(&mut self, footprint: &[Vec2], z0: f32, z1: f32, object: u32) -> Result<(), RaycastError> {
        let cap = triangulate(footprint)?;
        let n = footprint.len();
        for i in 0..n {
            let (a, b) = (footprint[i], footprint[(i + 1) % n]);
            self.push_quad([a.extend(z0), b.extend(z0), b.extend(z1), a.extend(z1)], object);
        }
        for [i, j, k] in cap {
            let (a, b, c) = (footprint[i], footprint[j], footprint[k]);
            self.push([a.extend(z1), b.extend(z1), c.extend(z1)], object);
            self.push([a.extend(z0), c.extend(z0), b.extend(z0)], object);
        }
        Ok(())
    }

    /// A closed cylinder from `a` to `b` of the given radius, with `segments` sides.
    pub fn push_cylinder(&mut self, a: Vec3, b: Vec3, radius: f32, segments: usize, object: u32) {
        let axis = (b - a).normalize_or_zero();
        if axis == Vec3::ZERO {
            return;
        }
        let (u, v) = axis.any_orthonormal_pair();
        let ring = |c: Vec3, k: usize| {
            let ang = std::f32::consts::TAU * k as f32 / segments as f32;
            c + (u * ang.cos() + v * ang.sin()) * radius
        };
        for k in 0..segments {
            let (p0, p1) = (ring(a, k), ring(a, k + 1));
            let (q0, q1) = (ring(b, k), ring(b, k + 1));
            self.push_quad([p0, p1, q1, q0], object);
            self.push([a, p1, p0], object);
            self.push([b, q0, q1], object);
        }
    }

    /// An axis-aligned-in-yaw box from its centre, size and yaw.
    pub fn push_box(&mut self, b: &hilo_core::Box3, object: u32) {
        let c = b.corners();
        let faces = [[0, 1, 2, 3], [4, 7, 6, 5], [0, 4, 5, 1], [1, 5, 6, 2], [2, 6, 7, 3], [3, 7, 4, 0]];
        for f in faces {
            self.push_quad([c[f[0]], c[f[1]], c[f[2]], c[f[3]]], object);
        }
    }

    /// An ellipsoid as a subdivided icosahedron (level 1: 80 triangles).
    pub fn push_ellipsoid(&mut self, center: Vec3, radii: Vec3, subdivisions: u32, object: u32) {
        for [a, b, c] in icosphere(subdivisions) {
            self.push([center + a * radii, center + b * radii, center + c * radii], object);
        }
    }
}

/// Ear-clipping triangulation of a simple polygon (either winding); indices into `poly`.
pub fn triangulate(poly: &[Vec2]) -> Result<Vec<[usize; 3]>, RaycastError> {
    let mut out: Vec<u32> = Vec::new();
    earcut::Earcut::new().earcut(poly.iter().map(|p| [p.x as f64, p.y as f64]), &[] as &[u32], &mut out);
    if out.is_empty() && poly.len() >= 3 {
        return Err(RaycastError::Geometry(format!("polygon {poly:?} could not be triangulated (self-intersecting?)")));
    }
    Ok(out.chunks_exact(3).map(|c| [c[0] as usize, c[1] as usize, c[2] as usize]).collect())
}

/// Unit icosphere triangles, outward winding.
pub fn icosphere(subdivisions: u32) -> Vec<[Vec3; 3]> {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let v: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| Vec3::from(*p).normalize())
    .collect();
    let faces = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let mut tris: Vec<[Vec3; 3]> = faces.iter().map(|f| [v[f[0]], v[f[1]], v[f[2]]]).collect();
    for _ in 0..subdivisions {
        tris = tris
            .iter()
            .flat_map(|&[a, b, c]| {
                let (ab, bc, ca) = ((a + b).normalize(), (b + c).normalize(), (c + a).normalize());
                [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
            })
            .collect();
    }
    tris
}
