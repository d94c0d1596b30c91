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

/// Reads an OBJ file (polygons are triangulated by tobj). The file is read bounded, as every
/// input is ([`hilo_core::fs::read_bounded`]: a regular file of at most
/// [`hilo_core::fs::limit::MESH`] bytes), and parsed from memory; the material libraries it
/// names are never opened (materials are ignored), so no path inside the file is followed.
pub fn read_obj(path: &Path) -> Result<RawMesh, RaycastError> {
    let bytes = hilo_core::fs::read_bounded(path, hilo_core::fs::limit::MESH)
        .map_err(|e| RaycastError::from(hilo_core::fs::FileError::io(path, e)))?;
    parse_obj(&bytes, path)
}

/// [`read_obj`] of bytes already read; `path` names them in errors.
pub fn parse_obj(bytes: &[u8], path: &Path) -> Result<RawMesh, RaycastError> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ignore_points: true, ignore_lines: true };
    let (models, _) =
        tobj::load_obj_buf(&mut &bytes[..], &opts, |_| Err(tobj::LoadError::OpenFileFailed)).map_err(|e| match e {
            tobj::LoadError::ReadError => mesh_err(path, "not OBJ text (a read error while parsing)"),
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
    parse_gltf(&bytes, path)
}

/// [`read_gltf`] of bytes already read; `path` names them in errors, and external buffers are
/// read (bounded) from its folder.
pub fn parse_gltf(bytes: &[u8], path: &Path) -> Result<RawMesh, RaycastError> {
    let malformed = |e: gltf::Error| mesh_err(path, format!("malformed glTF: {e}"));
    // gltf's validation indexes the accessors by each primitive's POSITION without a bounds
    // check (it panics on an index past them), so that index is checked first, then the rest
    // of the document is validated.
    let raw = gltf::Gltf::from_slice_without_validation(bytes).map_err(malformed)?;
    let json = raw.document.into_json();
    for (mi, m) in json.meshes.iter().enumerate() {
        for (pi, p) in m.primitives.iter().enumerate() {
            let position = gltf::json::validation::Checked::Valid(gltf::Semantic::Positions);
            if let Some(a) = p.attributes.get(&position).filter(|a| a.value() >= json.accessors.len()) {
                return Err(mesh_err(
                    path,
                    format!(
                        "mesh {mi} primitive {pi}: POSITION is accessor {}, but the file has {} accessors",
                        a.value(),
                        json.accessors.len()
                    ),
                ));
            }
        }
    }
    let gltf = gltf::Gltf { document: gltf::Document::from_json(json).map_err(malformed)?, blob: raw.blob };
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
                let at = format!("mesh {} primitive {pi}", gm.index());
                if let Some(a) = prim.get(&gltf::Semantic::Positions) {
                    check_accessor(path, &at, "POSITION", &a, &[(gltf::accessor::DataType::F32, 12)])?;
                }
                if let Some(a) = prim.indices() {
                    use gltf::accessor::DataType::{U8, U16, U32};
                    check_accessor(path, &at, "indices", &a, &[(U8, 1), (U16, 2), (U32, 4)])?;
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

/// Checks what gltf's accessor reader assumes (it asserts, or underflows, otherwise): a
/// component type and element size it reads as (`ok`: data type and bytes per element, with
/// vectors of three for POSITION and scalars for indices), at least one element, a stride no
/// smaller than the element, and no sparse storage (which hilo does not read).
fn check_accessor(
    path: &Path,
    at: &str,
    what: &str,
    a: &gltf::Accessor,
    ok: &[(gltf::accessor::DataType, usize)],
) -> Result<(), RaycastError> {
    let fits = ok.iter().any(|&(t, size)| a.data_type() == t && a.size() == size);
    let stride_ok = a.view().is_some_and(|v| v.stride().is_none_or(|s| s >= a.size()));
    if !fits || a.count() == 0 || !stride_ok || a.sparse().is_some() {
        return Err(mesh_err(
            path,
            format!(
                "{at}: the {what} accessor ({} × {:?} {:?}, stride {:?}{}) is not one hilo reads: {what} need {}, at \
                 least one, stored densely in a buffer view",
                a.count(),
                a.dimensions(),
                a.data_type(),
                a.view().and_then(|v| v.stride()),
                if a.sparse().is_some() { ", sparse" } else { "" },
                if what == "POSITION" { "three 32-bit floats each" } else { "one unsigned integer each" }
            ),
        ));
    }
    Ok(())
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
