//! Scene geometry and ray casting for hilo.
//!
//! A [`Scene`] is the digital twin of an intersection, read from TOML (roads, sidewalks,
//! buildings, trees, signal poles, street lights, ROIs, imported OBJ/glTF meshes). A [`World`]
//! answers ray queries over it: the ground as an analytic plane, static triangles in an obvhs
//! BVH2 traversed by hilo with a watertight triangle test, and each frame's moving actors as
//! analytic boxes and capsules ([`ActorSet`]). A [`QueryRegion`] limits what is built to what
//! the queries can reach.
//!
//! ```
//! use hilo_raycast::{Scene, World, QueryRegion, Ray};
//! use glam::Vec3;
//! let scene = Scene::default_fixture().unwrap();
//! let world = World::build(&scene, &QueryRegion::everything()).unwrap();
//! // Straight down from 10 m above the centre: the road surface at 10 m.
//! let hit = world.closest_hit(&Ray::new(Vec3::new(0.0, 0.0, 10.0), -Vec3::Z, 100.0), None).unwrap();
//! assert!((hit.t - 10.0).abs() < 1e-5);
//! ```

pub mod actors;
pub mod bvh;
pub mod error;
pub mod mesh;
pub mod ray;
pub mod reference;
pub mod scene;
pub mod shapes;
pub mod world;

pub use actors::{Actor, ActorSet, ActorShape};
pub use error::RaycastError;
pub use mesh::TriangleMesh;
pub use ray::{Hit, HitTarget, Material, Ray};
pub use scene::{MountStructure, ObjectKind, Scene, SceneObject};
pub use world::{QueryRegion, World};
