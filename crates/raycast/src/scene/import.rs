//! Mesh import from Wavefront OBJ (tobj) and glTF 2.0 (.gltf with external or embedded
//! buffers, and .glb). Only triangle geometry is read: materials, textures and normals are
//! ignored, since rays need surfaces only; the scene's `material` field labels the whole mesh.

use super::config::{MeshConfig, UpAxis};
use crate::error::RaycastError;
use base64::Engine;
use glam::{DMat4, DVec3};
use std::path::Path;

/// Vertices (in the file's own coordinates, f64) and triangles of an imported file.
#[derive(Debug, Clone, Default)]
pub struct RawMesh {
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

fn mesh_err(path: &Path, message: impl Into<String>) -> RaycastError {
    RaycastError::Mesh { path: path.to_path_buf(), message: message.into() }
}

fn check_indices(path: &Path, mesh: &RawMesh) -> Result<(), RaycastError> {
    if mesh.triangles.is_empty() {
        return Err(mesh_err(path, "the file holds no triangles"));
    }
    let n = mesh.vertices.len();
    for (k, t) in mesh.triangles.iter().enumerate() {
        if let Some(&i) = t.iter().find(|&&i| i as usize >= n) {
            return Err(mesh_err(path, format!("face {k} refers to vertex {i}, but there are only {n} vertices")));
        }
    }
    if let Some(i) = mesh.vertices.iter().position(|v| !v.is_finite()) {
        return Err(mesh_err(path, format!("vertex {i} is not finite: {:?}", mesh.vertices[i])));
    }
    Ok(())
}

/// Reads an OBJ file (polygons are triangulated by tobj).
pub fn read_obj(path: &Path) -> Result<RawMesh, RaycastError> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ignore_points: true, ignore_lines: true };
    let (models, _) = tobj::load_obj(path, &opts).map_err(|e| match e {
        tobj::LoadError::OpenFileFailed | tobj::LoadError::ReadError => {
            RaycastError::from(hilo_core::fs::FileError::io(path, std::io::Error::other(e.to_string())))
        }
        other => mesh_err(path, format!("malformed OBJ: {other}")),
    })?;
    let mut mesh = RawMesh::default();
    for m in models {
        let base = mesh.vertices.len() as u32;
        let p = &m.mesh.positions;
        mesh.vertices.extend(p.chunks_exact(3).map(|c| DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64)));
        let local_n = (p.len() / 3) as u32;
        for (k, c) in m.mesh.indices.chunks_exact(3).enumerate() {
            if let Some(&i) = c.iter().find(|&&i| i >= local_n) {
                return Err(mesh_err(
                    path,
                    format!("object {:?} face {k} refers to vertex {i}, but it has {local_n}", m.name),
                ));
            }
            mesh.triangles.push([base + c[0], base + c[1], base + c[2]]);
        }
    }
    check_indices(path, &mesh)?;
    Ok(mesh)
}

/// Reads a glTF 2.0 file (.gltf or .glb): every triangle primitive of the default scene (or of
/// all scenes if none is marked default), with node transforms applied.
pub fn read_gltf(path: &Path) -> Result<RawMesh, RaycastError> {
    let bytes = hilo_core::fs::read_bounded(path, hilo_core::fs::limit::MESH)
        .map_err(|e| RaycastError::from(hilo_core::fs::FileError::io(path, e)))?;
    let gltf = gltf::Gltf::from_slice(&bytes).map_err(|e| mesh_err(path, format!("malformed glTF: {e}")))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut buffers: Vec<Vec<u8>> = Vec::new();
    for (i, b) in gltf.document.buffers().enumerate() {
        let data = match b.source() {
            gltf::buffer::Source::Bin => {
                gltf.blob.clone().ok_or_else(|| mesh_err(path, format!("buffer {i}: no binary chunk")))?
            }
            gltf::buffer::Source::Uri(uri) => {
                if let Some(rest) = uri.strip_prefix("data:") {
                    let (_, b64) = rest
                        .split_once(";base64,")
                        .ok_or_else(|| mesh_err(path, format!("buffer {i}: unsupported data URI")))?;
                    base64::engine::general_purpose::STANDARD
                        .decode(b64)
                        .map_err(|e| mesh_err(path, format!("buffer {i}: bad base64: {e}")))?
                } else {
                    let p = dir.join(uri);
                    hilo_core::fs::read_bounded(&p, hilo_core::fs::limit::MESH)
                        .map_err(|e| RaycastError::from(hilo_core::fs::FileError::Io { path: p, source: e }))?
                }
            }
        };
        if data.len() < b.length() {
            return Err(mesh_err(
                path,
                format!("buffer {i}: {} bytes, but the file declares {}", data.len(), b.length()),
            ));
        }
        buffers.push(data);
    }
    let mut mesh = RawMesh::default();
    let scenes: Vec<gltf::Scene> = match gltf.document.default_scene() {
        Some(s) => vec![s],
        None => gltf.document.scenes().collect(),
    };
    let mut stack: Vec<(gltf::Node, DMat4)> =
        scenes.iter().flat_map(|s| s.nodes().map(|n| (n, DMat4::IDENTITY))).collect();
    while let Some((node, parent)) = stack.pop() {
        let m = parent * glam::Mat4::from_cols_array_2d(&node.transform().matrix()).as_dmat4();
        if let Some(gm) = node.mesh() {
            for (pi, prim) in gm.primitives().enumerate() {
                if prim.mode() != gltf::mesh::Mode::Triangles {
                    continue;
                }
                let reader = prim.reader(|b| buffers.get(b.index()).map(|d| d.as_slice()));
                let positions: Vec<DVec3> = reader
                    .read_positions()
                    .ok_or_else(|| mesh_err(path, format!("mesh {} primitive {pi}: no POSITION", gm.index())))?
                    .map(|p| m.transform_point3(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)))
                    .collect();
                let idx: Vec<u32> = match reader.read_indices() {
                    Some(i) => i.into_u32().collect(),
                    None => (0..positions.len() as u32).collect(),
                };
                let base = mesh.vertices.len() as u32;
                for (k, c) in idx.chunks_exact(3).enumerate() {
                    if let Some(&i) = c.iter().find(|&&i| i as usize >= positions.len()) {
                        return Err(mesh_err(
                            path,
                            format!(
                                "mesh {} primitive {pi} face {k} refers to vertex {i}, but it has {}",
                                gm.index(),
                                positions.len()
                            ),
                        ));
                    }
                    mesh.triangles.push([base + c[0], base + c[1], base + c[2]]);
                }
                mesh.vertices.extend(positions);
            }
        }
        stack.extend(node.children().map(|c| (c, m)));
    }
    check_indices(path, &mesh)?;
    Ok(mesh)
}

/// Loads the mesh a scene names and places it in the local frame: up-axis conversion, scale,
/// yaw, translation, then (for world coordinates) subtraction of the origin, all in f64.
/// `scene_file` and `index` name the scene entry in errors about the entry itself.
pub fn load_mesh(
    cfg: &MeshConfig,
    scene_dir: &Path,
    origin: DVec3,
    scene_file: &Path,
    index: usize,
) -> Result<Vec<[glam::Vec3; 3]>, RaycastError> {
    let path = if cfg.path.is_absolute() { cfg.path.clone() } else { scene_dir.join(&cfg.path) };
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
    let (raw, y_up) = match ext.as_str() {
        "obj" => (read_obj(&path)?, cfg.up_axis == UpAxis::Y),
        "gltf" | "glb" => (read_gltf(&path)?, cfg.up_axis != UpAxis::Z),
        other => {
            return Err(RaycastError::Invalid {
                path: scene_file.to_path_buf(),
                field: format!("meshes[{index}].path"),
                value: format!("{:?}", cfg.path),
                reason: format!("unsupported mesh format {other:?}; use .obj, .gltf or .glb"),
            });
        }
    };
    let (s, c) = cfg.yaw_deg.to_radians().sin_cos();
    let t = DVec3::from(cfg.translation_m);
    let place = |v: DVec3| {
        // Y-up files: (x, y, z) -> (x, -z, y) keeps the frame right-handed with z up.
        let v = if y_up { DVec3::new(v.x, -v.z, v.y) } else { v } * cfg.scale;
        let v = DVec3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z) + t;
        if cfg.world_coordinates { (v - origin).as_vec3() } else { v.as_vec3() }
    };
    Ok(raw
        .triangles
        .iter()
        .map(|t| {
            [place(raw.vertices[t[0] as usize]), place(raw.vertices[t[1] as usize]), place(raw.vertices[t[2] as usize])]
        })
        .collect())
}
