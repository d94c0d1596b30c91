//! The digital twin of an intersection: configuration, derived layout, static geometry.

pub mod config;
pub mod import;
pub mod layout;
pub mod opendrive;

use crate::error::RaycastError;
use crate::mesh::TriangleMesh;
use crate::ray::Material;
use crate::shapes::GroundPlane;
use config::SceneConfig;
use glam::{DVec3, Vec2, Vec3};
use hilo_core::{Box3, LocalFrame};
use layout::{Layout, Roi};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The default four-arm suburban intersection, embedded so that `hilo` runs without files.
pub const DEFAULT_SCENE_TOML: &str = include_str!("../../../../fixtures/intersection.toml");

/// What a static object is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectKind {
    Sidewalk,
    Median,
    /// A roundabout's central island: a curb and what grows on it, as one raised block.
    Island,
    Building,
    TreeTrunk,
    TreeCrown,
    SignalPole,
    MastArm,
    SignalHead,
    StreetLight,
    Mesh,
}

/// One entry of the scene's object table; triangles refer to it by index.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneObject {
    pub name: String,
    pub kind: ObjectKind,
    pub material: Material,
}

/// A pole with a mast arm, where sensors can be mounted (local frame).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MountStructure {
    pub name: String,
    pub base: Vec2,
    pub pole_height_m: f32,
    pub pole_radius_m: f32,
    /// Unit direction of the mast arm in the xy plane.
    pub arm_dir: Vec2,
    pub arm_length_m: f32,
    pub arm_height_m: f32,
}

impl MountStructure {
    /// The mast arm's radius: a share of the pole's, as the scene builds it.
    pub fn arm_radius_m(&self) -> f32 {
        ARM_RADIUS_SHARE * self.pole_radius_m
    }

    /// The mast arm's axis, from the pole's centre to its tip, at its height above `ground_z`.
    pub fn arm_axis(&self, ground_z: f32) -> (Vec3, Vec3) {
        let z = ground_z + self.arm_height_m;
        (self.base.extend(z), (self.base + self.arm_dir * self.arm_length_m).extend(z))
    }
}

/// A mast arm's radius as a share of its pole's.
const ARM_RADIUS_SHARE: f32 = 0.6;

/// A loaded scene: configuration, layout, ROIs, static triangles with their objects, ground.
#[derive(Clone, Debug)]
pub struct Scene {
    pub config: SceneConfig,
    /// The file it came from (None for the embedded default).
    pub source: Option<PathBuf>,
    pub frame: LocalFrame,
    pub layout: Layout,
    pub rois: Vec<Roi>,
    pub ground: GroundPlane,
    pub mesh: TriangleMesh,
    pub objects: Vec<SceneObject>,
    pub mounts: Vec<MountStructure>,
    /// What loading assumed where the source said nothing (an OpenDRIVE junction's stated
    /// defaults, [`opendrive::Imported::notes`]); empty for a scene file.
    pub assumed: Vec<String>,
}

/// Whether two simple polygons overlap: a corner of either inside the other, or two edges
/// crossing (a thin building laid across a road without a corner on it).
fn polygons_overlap(a: &[Vec2], b: &[Vec2]) -> bool {
    use layout::point_in_polygon as inside;
    let edges = |v: &[Vec2]| -> Vec<([f32; 2], [f32; 2])> {
        (0..v.len()).map(|i| (v[i].to_array(), v[(i + 1) % v.len()].to_array())).collect()
    };
    let (ea, eb) = (edges(a), edges(b));
    a.iter().any(|&v| inside(v, b))
        || b.iter().any(|&v| inside(v, a))
        || ea.iter().any(|&(p, q)| eb.iter().any(|&(r, s)| config::segments_cross(p, q, r, s)))
}

/// What the field would refuse in a scene whose numbers are each valid: a pole, street light
/// or tree standing on the carriageway (on a median is fine) or in the junction box, a pole or
/// light inside a building; a building reaching into the junction box or onto an arm's
/// carriageway. Poles and trees count by their centre; a building by its footprint.
fn plausible(cfg: &SceneConfig, layout: &Layout, file: &Path) -> Result<(), RaycastError> {
    use layout::point_in_polygon as inside;
    let err = |field: String, value: String, reason: String| RaycastError::Invalid {
        path: file.to_path_buf(),
        field,
        value,
        reason,
    };
    // A curb's arc pushes both arms' crosswalks out: they must stay on the arms' inner halves.
    for (k, a) in cfg.arms.iter().enumerate().filter(|(_, a)| a.corner_radius_m > 0.0) {
        let reach =
            layout.arms.iter().filter(|l| l.name == a.name).map(|l| l.crosswalk[1].dot(l.dir)).fold(0.0f32, f32::max);
        if reach > 0.5 * a.length_m {
            return Err(err(
                format!("arms[{k}].corner_radius_m"),
                a.corner_radius_m.to_string(),
                format!(
                    "the curb's arc puts the arm's crosswalk {reach:.1} m out, beyond half its length ({} m)",
                    a.length_m
                ),
            ));
        }
    }
    let footprints: Vec<Vec<Vec2>> =
        cfg.buildings.iter().map(|b| b.footprint.iter().map(|p| Vec2::from(*p)).collect()).collect();
    for (k, f) in footprints.iter().enumerate() {
        let in_box = (layout.central.len() >= 3 && polygons_overlap(f, &layout.central))
            .then(|| "reaches into the junction box, where the arms' traffic crosses".to_owned());
        // A building may stand beside a median, not on the lanes either side of it: the road
        // polygon spans both carriageways, so a footprint wholly inside the median is allowed.
        let on_road = layout
            .arms
            .iter()
            .find(|a| {
                polygons_overlap(f, &a.road) && !a.median.as_ref().is_some_and(|m| f.iter().all(|&v| inside(v, m)))
            })
            .map(|a| format!("reaches onto the carriageway of arm {:?}", a.name));
        if let Some(why) = in_box.or(on_road) {
            return Err(err(format!("buildings[{k}].footprint"), format!("{} corners", f.len()), why));
        }
    }
    let poles = cfg.signal_poles.iter().enumerate().map(|(i, p)| (format!("signal_poles[{i}].position"), p.position));
    let lights =
        cfg.street_lights.iter().enumerate().map(|(i, s)| (format!("street_lights[{i}].position"), s.position));
    let trees = cfg.trees.iter().enumerate().map(|(i, t)| (format!("trees[{i}].position"), t.position));
    let standing = poles.map(|(f, p)| (f, p, "pole")).chain(lights.map(|(f, p)| (f, p, "pole")));
    for (field, pos, what) in standing.chain(trees.map(|(f, p)| (f, p, "tree"))) {
        let p = Vec2::from(pos);
        // A roundabout's island is raised ground, like a median.
        let island = layout.on_island(p);
        let on_road = layout
            .arms
            .iter()
            .find(|a| inside(p, &a.road) && !a.median.as_ref().is_some_and(|m| inside(p, m)) && !island)
            .map(|a| format!("stands on the carriageway of arm {:?}", a.name));
        let in_box = (layout.central.len() >= 3 && inside(p, &layout.central) && !island)
            .then(|| "stands in the junction box".into());
        let in_building = footprints.iter().position(|f| inside(p, f)).map(|k| format!("stands inside buildings[{k}]"));
        if let Some(why) = in_box.or(on_road).or(in_building) {
            return Err(err(
                field,
                format!("{pos:?}"),
                format!("{why}; a {what} stands on a sidewalk, a median, an island or the verge"),
            ));
        }
    }
    Ok(())
}

impl Scene {
    /// Loads and builds a scene file (meshes are resolved against its folder).
    pub fn load(path: &Path) -> Result<Self, RaycastError> {
        let cfg = SceneConfig::load(path)?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut scene = Self::from_config(cfg, dir, path)?;
        scene.source = Some(path.to_path_buf());
        Ok(scene)
    }

    /// Loads a scene file, or one junction of an OpenDRIVE road network (`.xodr`, which needs
    /// `junction`; see [`opendrive`]). `junction` is refused for a scene file.
    pub fn load_with(path: &Path, junction: Option<&opendrive::JunctionPick>) -> Result<Self, RaycastError> {
        let xodr = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("xodr"));
        let refuse = |reason: &str| RaycastError::Invalid {
            path: path.to_path_buf(),
            field: "junction".into(),
            value: format!("{junction:?}"),
            reason: reason.into(),
        };
        match (xodr, junction) {
            (false, None) => Self::load(path),
            (false, Some(_)) => {
                Err(refuse("a junction is chosen in an OpenDRIVE road network (.xodr); this is a scene file"))
            }
            (true, None) => {
                Err(refuse("an OpenDRIVE road network holds many junctions: name one (`id`, or `near` a point)"))
            }
            (true, Some(pick)) => {
                let imported = opendrive::import_file(path, pick)?;
                let dir = path.parent().unwrap_or(Path::new("."));
                let mut scene = Self::from_config(imported.config, dir, path)?;
                scene.source = Some(path.to_path_buf());
                scene.assumed = std::iter::once(format!("junction {} of the OpenDRIVE file", imported.junction))
                    .chain(imported.notes)
                    .collect();
                Ok(scene)
            }
        }
    }

    /// The embedded default intersection.
    pub fn default_fixture() -> Result<Self, RaycastError> {
        let name = Path::new("<embedded>/fixtures/intersection.toml");
        let cfg = SceneConfig::from_toml_str(DEFAULT_SCENE_TOML, name)?;
        Self::from_config(cfg, Path::new("."), name)
    }

    /// Builds geometry from a validated configuration. `file` is used in error messages.
    pub fn from_config(cfg: SceneConfig, scene_dir: &Path, file: &Path) -> Result<Self, RaycastError> {
        cfg.validate(file)?;
        let frame = LocalFrame::new(DVec3::new(cfg.origin.x_m, cfg.origin.y_m, cfg.origin.z_m));
        let layout = layout::build_layout(&cfg);
        plausible(&cfg, &layout, file)?;
        let rois = layout::resolve_rois(&cfg.roi, &layout);
        let h = cfg.ground.half_size_m;
        let gz = cfg.ground.z_m;
        let ground = GroundPlane { z_m: gz, min: Vec2::splat(-h), max: Vec2::splat(h) };
        let mut b = Builder::default();
        let named = |e: RaycastError, field: String| match e {
            RaycastError::Geometry(msg) => {
                RaycastError::Invalid { path: file.to_path_buf(), field, value: String::new(), reason: msg }
            }
            other => other,
        };
        for (i, arm) in layout.arms.iter().enumerate() {
            for (k, sw) in arm.sidewalks.iter().enumerate() {
                let o = b.object(format!("{}/sidewalk{k}", arm.name), ObjectKind::Sidewalk, Material::Concrete);
                b.mesh.push_prism(sw, gz, gz + arm.curb_height_m, o).map_err(|e| named(e, format!("arms[{i}]")))?;
            }
            if let Some(m) = &arm.median {
                let o = b.object(format!("{}/median", arm.name), ObjectKind::Median, Material::Concrete);
                b.mesh.push_prism(m, gz, gz + arm.curb_height_m, o).map_err(|e| named(e, format!("arms[{i}]")))?;
            }
        }
        let curb = cfg.arms.iter().map(|a| a.curb_height_m).fold(0.0, f32::max);
        for (k, c) in layout.corner_sidewalks.iter().enumerate() {
            let o = b.object(format!("corner{k}/sidewalk"), ObjectKind::Sidewalk, Material::Concrete);
            b.mesh.push_prism(c, gz, gz + curb, o).map_err(|e| named(e, "arms".into()))?;
        }
        if let Some(r) = &layout.ring {
            let o = b.object("roundabout/island".into(), ObjectKind::Island, Material::Vegetation);
            b.mesh.push_prism(&r.island, gz, gz + r.island_height_m, o).map_err(|e| named(e, "roundabout".into()))?;
        }
        for (i, bc) in cfg.buildings.iter().enumerate() {
            let name = if bc.name.is_empty() { format!("building{i}") } else { bc.name.clone() };
            let o = b.object(name, ObjectKind::Building, bc.material);
            let fp: Vec<Vec2> = bc.footprint.iter().map(|p| Vec2::from(*p)).collect();
            b.mesh
                .push_prism(&fp, gz, gz + bc.height_m, o)
                .map_err(|e| named(e, format!("buildings[{i}].footprint")))?;
        }
        for (i, t) in cfg.trees.iter().enumerate() {
            let p = Vec2::from(t.position);
            let o = b.object(format!("tree{i}/trunk"), ObjectKind::TreeTrunk, Material::Vegetation);
            b.mesh.push_cylinder(
                p.extend(gz),
                p.extend(gz + t.trunk_height_m + 0.5 * t.crown_height_m),
                t.trunk_radius_m,
                8,
                o,
            );
            let o = b.object(format!("tree{i}/crown"), ObjectKind::TreeCrown, Material::Vegetation);
            let cz = gz + t.trunk_height_m + 0.5 * t.crown_height_m;
            b.mesh.push_ellipsoid(
                p.extend(cz),
                Vec3::new(t.crown_radius_m, t.crown_radius_m, 0.5 * t.crown_height_m),
                1,
                o,
            );
        }
        let mut mounts = Vec::new();
        for p in &cfg.signal_poles {
            let base = Vec2::from(p.position);
            let dir = Vec2::from_angle(p.arm_heading_deg.to_radians());
            let o = b.object(format!("{}/pole", p.name), ObjectKind::SignalPole, Material::Metal);
            b.mesh.push_cylinder(base.extend(gz), base.extend(gz + p.height_m), p.radius_m, 12, o);
            if p.arm_length_m > 0.0 {
                let o = b.object(format!("{}/mast_arm", p.name), ObjectKind::MastArm, Material::Metal);
                let z = gz + p.arm_height_m;
                let r = ARM_RADIUS_SHARE * p.radius_m;
                b.mesh.push_cylinder(base.extend(z), (base + dir * p.arm_length_m).extend(z), r, 8, o);
            }
            for (k, off) in p.head_offsets_m.iter().enumerate() {
                let o = b.object(format!("{}/head{k}", p.name), ObjectKind::SignalHead, Material::Metal);
                let c = (base + dir * *off).extend(gz + p.arm_height_m - 0.65);
                let yaw = dir.y.atan2(dir.x);
                b.mesh.push_box(&Box3::new(c, 0.35, 0.35, 1.1, yaw), o);
            }
            mounts.push(MountStructure {
                name: p.name.clone(),
                base,
                pole_height_m: p.height_m,
                pole_radius_m: p.radius_m,
                arm_dir: dir,
                arm_length_m: p.arm_length_m,
                arm_height_m: p.arm_height_m,
            });
        }
        for (i, s) in cfg.street_lights.iter().enumerate() {
            let base = Vec2::from(s.position);
            let dir = Vec2::from_angle(s.arm_heading_deg.to_radians());
            let o = b.object(format!("light{i}"), ObjectKind::StreetLight, Material::Metal);
            b.mesh.push_cylinder(base.extend(gz), base.extend(gz + s.height_m), 0.12, 8, o);
            let tip = base + dir * s.arm_length_m;
            if s.arm_length_m > 0.0 {
                b.mesh.push_cylinder(base.extend(gz + s.height_m - 0.1), tip.extend(gz + s.height_m - 0.1), 0.06, 6, o);
            }
            b.mesh.push_box(
                &Box3::new(tip.extend(gz + s.height_m - 0.25), 0.7, 0.35, 0.2, s.arm_heading_deg.to_radians()),
                o,
            );
        }
        for (i, m) in cfg.meshes.iter().enumerate() {
            let name = if m.name.is_empty() { format!("mesh{i}") } else { m.name.clone() };
            let o = b.object(name, ObjectKind::Mesh, m.material);
            for t in import::load_mesh(m, scene_dir, frame.origin, file, i)? {
                b.mesh.push(t, o);
            }
        }
        let (mesh, objects) = (b.mesh, b.objects);
        Ok(Scene { config: cfg, source: None, frame, layout, rois, ground, mesh, objects, mounts, assumed: Vec::new() })
    }

    /// Display name of the file the scene came from.
    pub fn source_name(&self) -> String {
        self.source.as_ref().map_or_else(|| "<embedded default>".to_owned(), |p| p.display().to_string())
    }
}

#[derive(Default)]
struct Builder {
    mesh: TriangleMesh,
    objects: Vec<SceneObject>,
}

impl Builder {
    fn object(&mut self, name: String, kind: ObjectKind, material: Material) -> u32 {
        self.objects.push(SceneObject { name, kind, material });
        (self.objects.len() - 1) as u32
    }
}
