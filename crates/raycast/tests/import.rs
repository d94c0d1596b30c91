//! OBJ and glTF import: geometry arrives where the scene file says, with the right up axis.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use base64::Engine;
use glam::Vec3;
use hilo_raycast::{QueryRegion, Ray, Scene, World};

const CUBE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";

/// A glTF with one triangle in the y-up convention: the triangle lies in the xz plane at
/// y = 2 (2 m up), its buffer embedded as base64.
fn gltf_y_up_triangle() -> String {
    let mut buf = Vec::new();
    for v in [[0.0f32, 2.0, 0.0], [4.0, 2.0, 0.0], [0.0, 2.0, -4.0]] {
        for c in v {
            buf.extend_from_slice(&c.to_le_bytes());
        }
    }
    let b64 = base64::engine::general_purpose::STANDARD.encode(&buf);
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
"nodes":[{{"mesh":0,"translation":[10.0,0.0,0.0]}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
"buffers":[{{"byteLength":36,"uri":"data:application/octet-stream;base64,{b64}"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0.0,2.0,-4.0],"max":[4.0,2.0,0.0]}}]}}"#
    )
}

#[test]
fn obj_and_gltf_meshes_land_where_the_scene_says() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("cube.obj"), CUBE_OBJ).unwrap();
    std::fs::write(d.path().join("tri.gltf"), gltf_y_up_triangle()).unwrap();
    let text = "name = \"imports\"\n\
[[meshes]]\nname = \"cube\"\npath = \"cube.obj\"\ntranslation_m = [5.0, 5.0, 0.0]\nscale = 2.0\nyaw_deg = 90.0\n\
[[meshes]]\nname = \"tri\"\npath = \"tri.gltf\"\n";
    std::fs::write(d.path().join("s.toml"), text).unwrap();
    let scene = Scene::load(&d.path().join("s.toml")).unwrap();
    assert_eq!(scene.mesh.len(), 12 + 1);
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    // Cube: scaled to 2 m, rotated 90° about z (x -> y), moved to (5, 5): spans x 3..5, y 5..7.
    let h = world.closest_hit(&Ray::new(Vec3::new(4.0, 6.0, 10.0), Vec3::NEG_Z, 50.0), None).unwrap();
    assert!((h.t - 8.0).abs() < 1e-5, "{}", h.t);
    assert!(world.closest_hit(&Ray::new(Vec3::new(5.5, 6.0, 10.0), Vec3::NEG_Z, 9.99), None).is_none());
    // glTF triangle: y-up (x, 2, -z) becomes z-up (x, z, 2), then the node moves it to x + 10.
    let h = world.closest_hit(&Ray::new(Vec3::new(11.0, 1.0, 10.0), Vec3::NEG_Z, 50.0), None).unwrap();
    assert!((h.t - 8.0).abs() < 1e-5, "{}", h.t);
}
