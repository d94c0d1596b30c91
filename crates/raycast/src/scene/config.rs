//! The scene file: a TOML description of an intersection's digital twin.
//!
//! Coordinates are metres in the scene's local frame (x east, y north, z up) whose world
//! position is `[origin]`; imported meshes may instead be given in world coordinates
//! (`world_coordinates = true`), and are then shifted by the origin in f64 before rounding.
//! See `fixtures/intersection.toml` for a commented example of every field.

use crate::error::RaycastError;
use crate::ray::Material;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneConfig {
    pub name: String,
    #[serde(default)]
    pub origin: OriginConfig,
    #[serde(default)]
    pub ground: GroundConfig,
    #[serde(default)]
    pub arms: Vec<ArmConfig>,
    #[serde(default)]
    pub buildings: Vec<BuildingConfig>,
    #[serde(default)]
    pub trees: Vec<TreeConfig>,
    #[serde(default)]
    pub signal_poles: Vec<SignalPoleConfig>,
    #[serde(default)]
    pub street_lights: Vec<StreetLightConfig>,
    #[serde(default)]
    pub roi: Vec<RoiConfig>,
    #[serde(default)]
    pub meshes: Vec<MeshConfig>,
    /// A roundabout at the centre in place of a junction box ([`RoundaboutConfig`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roundabout: Option<RoundaboutConfig>,
    /// The junction's lane graph: which inbound lane leads to which outbound lane
    /// ([`ConnectionConfig`]). Empty (the default), hilo's own rules connect the lanes; an
    /// imported junction lists its file's connections.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub connections: Vec<ConnectionConfig>,
    /// The signal's phases (`signal_groups = [["north", "south"], ["east", "west"]]`): the arms
    /// whose traffic gets green together, in the order the groups run. A group is one arm, or
    /// two arms that face each other (headings within 20° of opposite); every arm with an
    /// inbound lane is in one group. Empty (the default), hilo pairs opposing arms in the order
    /// of the arms' headings. An imported junction lists the groups its file's controllers give,
    /// where they form such phases. The intervals (green, protected left, yellow, all-red) are
    /// the study's (`[traffic.signal]`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub signal_groups: Vec<Vec<String>>,
}

/// As derived, but without `connections` or `signal_groups` where there are none: a dataset's
/// fingerprint reads this text, so a scene without them keeps the fingerprints it had before
/// scenes could list them.
impl std::fmt::Debug for SceneConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("SceneConfig");
        d.field("name", &self.name)
            .field("origin", &self.origin)
            .field("ground", &self.ground)
            .field("arms", &self.arms)
            .field("buildings", &self.buildings)
            .field("trees", &self.trees)
            .field("signal_poles", &self.signal_poles)
            .field("street_lights", &self.street_lights)
            .field("roi", &self.roi)
            .field("meshes", &self.meshes)
            .field("roundabout", &self.roundabout);
        if !self.connections.is_empty() {
            d.field("connections", &self.connections);
        }
        if !self.signal_groups.is_empty() {
            d.field("signal_groups", &self.signal_groups);
        }
        d.finish()
    }
}

/// One movement the junction allows (`[[connections]]`): from an inbound lane of one arm to an
/// outbound lane of another. Lanes count from the arm's centre line outward (0: the innermost,
/// beside the median), inbound and outbound each on their own. Where a scene lists connections,
/// vehicles drive these and no others: a turn no connection allows is not made, and a lane
/// carries the turns its connections give it. Whether a movement is a left turn, a right turn or
/// through follows from the two arms' headings, as for hilo's own rules. A left turn from the
/// innermost lane of an arm with a left-turn bay uses the bay. Where a connection gives its
/// `path` (an imported junction's connecting lane), vehicles drive that curve through the
/// junction; otherwise hilo draws the turn.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConnectionConfig {
    /// The arm the movement comes from, by name.
    pub from: String,
    /// Its inbound lane, 0 the innermost.
    pub from_lane: u32,
    /// The arm it leaves by, by name (another arm: hilo models no U-turns).
    pub to: String,
    /// Its outbound lane, 0 the innermost.
    pub to_lane: u32,
    /// The way through the junction as the road network draws it: the connecting lane's centre
    /// line in scene coordinates (m), in the direction of travel, from about the inbound lane's
    /// end to about the outbound lane's start. The route follows the inbound lane to its stop
    /// line, then the points of this line past it, then the outbound lane. Empty: hilo draws
    /// the turn.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub path: Vec<[f32; 2]>,
}

/// The most points a connection's `path` may list.
pub const MAX_CONNECTION_POINTS: usize = 2_000;

/// A roundabout (`[roundabout]`): the arms meet a one-way circulatory roadway, driven
/// counter-clockwise, around a raised central island at the junction's centre. Entering traffic
/// yields at the ring; each arm's crosswalk stands back from the ring by about a car length, so
/// a driver leaving the ring can stop for a pedestrian without blocking it (FHWA's roundabout
/// guide, NCHRP Report 672, puts the crosswalk 6 m behind the yield line). No signal runs it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoundaboutConfig {
    /// Radius of the raised central island, m.
    pub island_radius_m: f32,
    /// Width of the circulatory roadway around the island, m (one lane: 4.5–7 m).
    #[serde(default = "d_ring_width")]
    pub ring_width_m: f32,
    /// Height of what stands on the island (a mound, shrubs), m: it hides the ring's far side
    /// from a sensor as low as a driver's eye.
    #[serde(default = "d_island_height")]
    pub island_height_m: f32,
    /// How far each arm's crosswalk stands back from the ring's outer edge, m.
    #[serde(default = "d_setback")]
    pub crosswalk_setback_m: f32,
}

fn d_ring_width() -> f32 {
    6.0
}
fn d_island_height() -> f32 {
    1.0
}
fn d_setback() -> f32 {
    6.0
}

impl RoundaboutConfig {
    /// Radius of the ring's outer edge (the inscribed circle), m.
    pub fn outer_radius_m(&self) -> f32 {
        self.island_radius_m + self.ring_width_m
    }
}

/// World position of the local origin (e.g. a UTM easting/northing and altitude).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OriginConfig {
    #[serde(default)]
    pub x_m: f64,
    #[serde(default)]
    pub y_m: f64,
    #[serde(default)]
    pub z_m: f64,
    /// Coordinate reference system of the world coordinates, e.g. "EPSG:32612"; informative.
    #[serde(default)]
    pub crs: Option<String>,
}

/// A flat ground square centred on the local origin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GroundConfig {
    pub z_m: f32,
    pub half_size_m: f32,
}

impl Default for GroundConfig {
    fn default() -> Self {
        GroundConfig { z_m: 0.0, half_size_m: 150.0 }
    }
}

/// One approach of the intersection. Traffic drives on the right: inbound lanes lie on the
/// counter-clockwise side of the arm's outward heading.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmConfig {
    pub name: String,
    /// Outward direction of the arm, degrees counter-clockwise from +x (east).
    pub heading_deg: f32,
    #[serde(default = "d_arm_length")]
    pub length_m: f32,
    #[serde(default = "d_two")]
    pub lanes_in: u32,
    #[serde(default = "d_two")]
    pub lanes_out: u32,
    #[serde(default = "d_lane_width")]
    pub lane_width_m: f32,
    /// Left-turn bay lanes next to the median, inbound.
    #[serde(default)]
    pub left_turn_lanes: u32,
    #[serde(default = "d_bay_length")]
    pub left_turn_bay_length_m: f32,
    /// Raised median width (0 = painted centre line only).
    #[serde(default)]
    pub median_width_m: f32,
    /// How far the arm's centre line (the middle of its median) lies to the left of the line
    /// through the junction's centre along `heading_deg`, m (negative: to the right). 0 for a
    /// road through the centre; an OpenDRIVE import sets it from the file's lanes.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub offset_m: f32,
    /// A parking lane on each curb side, between the outermost lane and the sidewalk, m (0:
    /// none). Vehicles park there when the traffic has a `[traffic.parking]` section.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub parking_lane_width_m: f32,
    #[serde(default = "d_sidewalk")]
    pub sidewalk_width_m: f32,
    #[serde(default = "d_curb")]
    pub curb_height_m: f32,
    #[serde(default = "d_crosswalk")]
    pub crosswalk_width_m: f32,
    #[serde(default = "d_speed")]
    pub speed_limit_kph: f32,
    /// Radius of the curb at the corner on this arm's inbound side, m: the corner it shares with
    /// the next arm counter-clockwise, which traffic entering on this arm passes on a right
    /// turn. 0 (the default): a sharp corner. The curb runs along an arc tangent to both edges,
    /// the corner's sidewalk follows it, and the crosswalks and stop lines of both arms move out
    /// to where the arc meets their edges. An OpenDRIVE import fits it to the file's right turn.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub corner_radius_m: f32,
}

/// The largest curb radius at a corner (`corner_radius_m`), m.
pub const MAX_CORNER_RADIUS_M: f32 = 30.0;

/// The farthest an arm's centre line may lie from the junction's centre (`offset_m`).
pub const MAX_ARM_OFFSET_M: f32 = 20.0;

/// Serde's test for a width left at its default of none.
pub(crate) fn is_zero(v: &f32) -> bool {
    *v == 0.0
}
fn d_arm_length() -> f32 {
    120.0
}
fn d_two() -> u32 {
    2
}
fn d_lane_width() -> f32 {
    3.6
}
fn d_bay_length() -> f32 {
    50.0
}
fn d_sidewalk() -> f32 {
    2.0
}
fn d_curb() -> f32 {
    0.15
}
fn d_crosswalk() -> f32 {
    3.5
}
fn d_speed() -> f32 {
    60.0
}

/// A building as an extruded footprint (any simple polygon, either winding).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuildingConfig {
    #[serde(default)]
    pub name: String,
    pub footprint: Vec<[f32; 2]>,
    pub height_m: f32,
    #[serde(default)]
    pub material: Material,
}

/// A tree: a cylindrical trunk and an ellipsoidal crown, both opaque.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TreeConfig {
    pub position: [f32; 2],
    #[serde(default = "d_trunk_r")]
    pub trunk_radius_m: f32,
    #[serde(default = "d_trunk_h")]
    pub trunk_height_m: f32,
    #[serde(default = "d_crown_r")]
    pub crown_radius_m: f32,
    #[serde(default = "d_crown_h")]
    pub crown_height_m: f32,
}

fn d_trunk_r() -> f32 {
    0.2
}
fn d_trunk_h() -> f32 {
    2.5
}
fn d_crown_r() -> f32 {
    2.5
}
fn d_crown_h() -> f32 {
    4.0
}

/// A traffic-signal pole with a mast arm: the mounting structure for roadside sensors.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SignalPoleConfig {
    pub name: String,
    pub position: [f32; 2],
    #[serde(default = "d_pole_h")]
    pub height_m: f32,
    #[serde(default = "d_pole_r")]
    pub radius_m: f32,
    /// Direction the mast arm points, degrees counter-clockwise from +x.
    pub arm_heading_deg: f32,
    pub arm_length_m: f32,
    #[serde(default = "d_arm_h")]
    pub arm_height_m: f32,
    /// Signal heads hang below the arm at these distances from the pole, metres.
    #[serde(default)]
    pub head_offsets_m: Vec<f32>,
}

fn d_pole_h() -> f32 {
    7.5
}
fn d_pole_r() -> f32 {
    0.18
}
fn d_arm_h() -> f32 {
    6.0
}

/// A street-light pole with a short arm and a luminaire.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StreetLightConfig {
    pub position: [f32; 2],
    #[serde(default = "d_light_h")]
    pub height_m: f32,
    #[serde(default)]
    pub arm_heading_deg: f32,
    #[serde(default = "d_light_arm")]
    pub arm_length_m: f32,
}

fn d_light_h() -> f32 {
    9.0
}
fn d_light_arm() -> f32 {
    2.0
}

/// A region of interest for placement, weighted in the objective.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoiConfig {
    pub name: String,
    #[serde(default = "d_weight")]
    pub weight: f32,
    pub kind: RoiKind,
    /// For `kind = "polygon"`: the polygon in local coordinates.
    #[serde(default)]
    pub polygon: Option<Vec<[f32; 2]>>,
    /// For `kind = "approaches"`: how far out from the crosswalk the queue lanes are covered.
    #[serde(default)]
    pub length_m: Option<f32>,
}

fn d_weight() -> f32 {
    1.0
}

/// Where an ROI lies: an explicit polygon, or derived from the road layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RoiKind {
    /// The `polygon` field.
    Polygon,
    /// The central conflict zone: the junction box and its crosswalks.
    Central,
    /// The inbound (queue) lanes of every arm, from the far edge of the crosswalk out to
    /// `length_m`.
    Approaches,
}

/// Which axis of an imported mesh points up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum UpAxis {
    /// Z up for OBJ, Y up for glTF (its specification's convention).
    #[default]
    Auto,
    Z,
    Y,
}

/// A triangle mesh imported from a Wavefront OBJ or glTF (.gltf/.glb) file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshConfig {
    #[serde(default)]
    pub name: String,
    /// Relative paths are resolved against the scene file's folder.
    pub path: PathBuf,
    #[serde(default)]
    pub translation_m: [f64; 3],
    #[serde(default)]
    pub yaw_deg: f64,
    #[serde(default = "d_scale")]
    pub scale: f64,
    #[serde(default)]
    pub up_axis: UpAxis,
    /// The file's coordinates are world coordinates: the scene origin is subtracted (in f64).
    #[serde(default)]
    pub world_coordinates: bool,
    #[serde(default)]
    pub material: Material,
}

fn d_scale() -> f64 {
    1.0
}

/// Field checks that name the file, field and value.
struct Check<'a> {
    path: &'a Path,
}

impl Check<'_> {
    fn err(&self, field: &str, value: impl std::fmt::Debug, reason: &str) -> RaycastError {
        RaycastError::Invalid {
            path: self.path.to_path_buf(),
            field: field.to_owned(),
            value: format!("{value:?}"),
            reason: reason.to_owned(),
        }
    }

    fn positive(&self, field: &str, v: f32) -> Result<(), RaycastError> {
        if v.is_finite() && v > 0.0 { Ok(()) } else { Err(self.err(field, v, "must be a finite number > 0")) }
    }

    fn non_negative(&self, field: &str, v: f32) -> Result<(), RaycastError> {
        if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(self.err(field, v, "must be a finite number >= 0")) }
    }

    fn finite(&self, field: &str, v: f32) -> Result<(), RaycastError> {
        if v.is_finite() { Ok(()) } else { Err(self.err(field, v, "must be finite")) }
    }

    /// A heading or yaw in degrees, within one turn either way (past that, f32 degrees lose the
    /// angle: 1e30° is no direction).
    fn heading<T: Into<f64> + Copy + std::fmt::Debug>(&self, field: &str, v: T) -> Result<(), RaycastError> {
        let x: f64 = v.into();
        if x.is_finite() && x.abs() <= 360.0 {
            Ok(())
        } else {
            Err(self.err(field, v, "must be an angle in [-360, 360] degrees"))
        }
    }

    fn polygon(&self, field: &str, poly: &[[f32; 2]]) -> Result<(), RaycastError> {
        if poly.len() < 3 {
            return Err(self.err(field, poly, "a polygon needs at least 3 points"));
        }
        if poly.len() > MAX_POLYGON_POINTS {
            // Checked before the O(n²) self-intersection test, and printed by count: the
            // polygon itself would be megabytes of message.
            return Err(self.err(
                field,
                poly.len(),
                &format!("a polygon may have at most {MAX_POLYGON_POINTS} points (this count); simplify it"),
            ));
        }
        if poly.iter().flatten().any(|v| !v.is_finite()) {
            return Err(self.err(field, poly, "coordinates must be finite"));
        }
        if let Some((i, j)) = self_intersection(poly) {
            return Err(self.err(
                field,
                poly,
                &format!("the polygon crosses itself (edge {i} meets edge {j}); list its corners in order around it"),
            ));
        }
        if polygon_area(poly).abs() < 1e-6 {
            return Err(self.err(field, poly, "polygon has zero area"));
        }
        Ok(())
    }

    /// Every point of a polygon lies on the ground plane's square.
    fn on_ground(&self, field: &str, poly: &[[f32; 2]], half: f32) -> Result<(), RaycastError> {
        if let Some(p) = poly.iter().find(|p| p[0].abs() > half || p[1].abs() > half) {
            return Err(self.err(field, p, &format!("lies off the ground (ground.half_size_m = {half})")));
        }
        Ok(())
    }
}

/// The most points a scene polygon (footprint, ROI, sidewalk, median) may have: far more than a
/// surveyed footprint needs, and few enough that the pairwise self-intersection check stays
/// well under a second.
pub const MAX_POLYGON_POINTS: usize = 4096;

/// Twice the signed area of the triangle o, a, b, in f64: positive when b lies to the left of
/// o → a.
fn cross(o: [f32; 2], a: [f32; 2], b: [f32; 2]) -> f64 {
    (a[0] as f64 - o[0] as f64) * (b[1] as f64 - o[1] as f64)
        - (a[1] as f64 - o[1] as f64) * (b[0] as f64 - o[0] as f64)
}

/// Whether segments a–b and c–d cross at a point inside both (touching is not crossing).
pub(crate) fn segments_cross(a: [f32; 2], b: [f32; 2], c: [f32; 2], d: [f32; 2]) -> bool {
    let (d1, d2) = (cross(c, d, a), cross(c, d, b));
    let (d3, d4) = (cross(a, b, c), cross(a, b, d));
    (d1 > 0.0) != (d2 > 0.0) && d1 != 0.0 && d2 != 0.0 && (d3 > 0.0) != (d4 > 0.0) && d3 != 0.0 && d4 != 0.0
}

/// The first pair of non-adjacent edges of a closed polygon that touch or cross, if any.
pub fn self_intersection(poly: &[[f32; 2]]) -> Option<(usize, usize)> {
    let n = poly.len();
    let on = |p: [f32; 2], a: [f32; 2], b: [f32; 2]| {
        cross(a, b, p).abs() < 1e-9
            && p[0] >= a[0].min(b[0])
            && p[0] <= a[0].max(b[0])
            && p[1] >= a[1].min(b[1])
            && p[1] <= a[1].max(b[1])
    };
    let meet = |a: [f32; 2], b: [f32; 2], c: [f32; 2], d: [f32; 2]| {
        segments_cross(a, b, c, d) || on(a, c, d) || on(b, c, d) || on(c, a, b) || on(d, a, b)
    };
    for i in 0..n {
        for j in i + 2..n {
            if i == 0 && j == n - 1 {
                continue; // the closing edge is adjacent to the first
            }
            if meet(poly[i], poly[(i + 1) % n], poly[j], poly[(j + 1) % n]) {
                return Some((i, j));
            }
        }
    }
    None
}

/// Signed area (positive counter-clockwise).
pub fn polygon_area(poly: &[[f32; 2]]) -> f32 {
    let n = poly.len();
    (0..n)
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum::<f32>()
        * 0.5
}

impl SceneConfig {
    /// Parses a scene from TOML text; `path` is only used in error messages.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self, RaycastError> {
        let cfg: SceneConfig = toml::from_str(text)
            .map_err(|e| RaycastError::from(hilo_core::fs::FileError::content(path, e.to_string())))?;
        cfg.validate(path)?;
        Ok(cfg)
    }

    /// Reads and validates a scene file.
    pub fn load(path: &Path) -> Result<Self, RaycastError> {
        let text = hilo_core::fs::read_text_bounded(path, hilo_core::fs::limit::CONFIG)
            .map_err(|e| RaycastError::from(hilo_core::fs::FileError::io(path, e)))?;
        Self::from_toml_str(&text, path)
    }

    /// Checks every number for finiteness and sign and every polygon for shape.
    pub fn validate(&self, path: &Path) -> Result<(), RaycastError> {
        let c = Check { path };
        let o = &self.origin;
        if ![o.x_m, o.y_m, o.z_m].iter().all(|v| v.is_finite()) {
            return Err(c.err("origin", [o.x_m, o.y_m, o.z_m], "must be finite"));
        }
        c.finite("ground.z_m", self.ground.z_m)?;
        c.positive("ground.half_size_m", self.ground.half_size_m)?;
        let mut names = std::collections::HashSet::new();
        for (i, a) in self.arms.iter().enumerate() {
            let f = |n: &str| format!("arms[{i}].{n}");
            if !names.insert(a.name.as_str()) {
                return Err(c.err(&f("name"), &a.name, "duplicate arm name"));
            }
            check_arm(&c, i, a, self.ground.half_size_m)?;
        }
        if let Some(r) = &self.roundabout {
            check_roundabout(&c, r, &self.arms)?;
        }
        check_corner_radii(&c, &self.arms)?;
        check_connections(&c, &self.connections, &self.arms, self.roundabout.is_some(), self.ground.half_size_m)?;
        check_signal_groups(&c, &self.signal_groups, &self.arms, self.roundabout.is_some())?;
        if let Some((i, j, along)) = overlapping_arms(&self.arms, self.roundabout.as_ref()) {
            let (a, b) = (&self.arms[i], &self.arms[j]);
            let gap = (b.heading_deg - a.heading_deg).rem_euclid(360.0);
            let how = if gap.min(360.0 - gap) < 1.0 {
                format!(
                    "arms {:?} and {:?} point the same way ({}° and {}°)",
                    a.name, b.name, a.heading_deg, b.heading_deg
                )
            } else if along >= a.length_m.min(b.length_m) {
                format!("the roadways of arms {:?} and {:?} overlap along their whole length", a.name, b.name)
            } else {
                format!("the roadways of arms {:?} and {:?} overlap for {along:.0} m from the centre", a.name, b.name)
            };
            return Err(c.err(
                &format!("arms[{j}].heading_deg"),
                b.heading_deg,
                &format!("{how}: arms need more angle between them"),
            ));
        }
        for (i, b) in self.buildings.iter().enumerate() {
            c.polygon(&format!("buildings[{i}].footprint"), &b.footprint)?;
            c.on_ground(&format!("buildings[{i}].footprint"), &b.footprint, self.ground.half_size_m)?;
            c.positive(&format!("buildings[{i}].height_m"), b.height_m)?;
        }
        for (i, t) in self.trees.iter().enumerate() {
            let f = |n: &str| format!("trees[{i}].{n}");
            c.finite(&f("position"), t.position[0])?;
            c.finite(&f("position"), t.position[1])?;
            c.positive(&f("trunk_radius_m"), t.trunk_radius_m)?;
            c.positive(&f("trunk_height_m"), t.trunk_height_m)?;
            c.positive(&f("crown_radius_m"), t.crown_radius_m)?;
            c.positive(&f("crown_height_m"), t.crown_height_m)?;
        }
        let mut pole_names = std::collections::HashSet::new();
        for (i, p) in self.signal_poles.iter().enumerate() {
            let f = |n: &str| format!("signal_poles[{i}].{n}");
            if !pole_names.insert(p.name.as_str()) {
                return Err(c.err(&f("name"), &p.name, "duplicate signal pole name"));
            }
            c.finite(&f("position"), p.position[0])?;
            c.finite(&f("position"), p.position[1])?;
            c.positive(&f("height_m"), p.height_m)?;
            c.positive(&f("radius_m"), p.radius_m)?;
            c.heading(&f("arm_heading_deg"), p.arm_heading_deg)?;
            c.non_negative(&f("arm_length_m"), p.arm_length_m)?;
            c.positive(&f("arm_height_m"), p.arm_height_m)?;
            if p.arm_height_m > p.height_m {
                return Err(c.err(&f("arm_height_m"), p.arm_height_m, "the mast arm must not be above the pole top"));
            }
            for (k, h) in p.head_offsets_m.iter().enumerate() {
                c.non_negative(&f(&format!("head_offsets_m[{k}]")), *h)?;
                if *h > p.arm_length_m {
                    return Err(c.err(
                        &f(&format!("head_offsets_m[{k}]")),
                        *h,
                        "signal head beyond the end of the arm",
                    ));
                }
            }
        }
        for (i, s) in self.street_lights.iter().enumerate() {
            let f = |n: &str| format!("street_lights[{i}].{n}");
            c.finite(&f("position"), s.position[0])?;
            c.finite(&f("position"), s.position[1])?;
            c.positive(&f("height_m"), s.height_m)?;
            c.heading(&f("arm_heading_deg"), s.arm_heading_deg)?;
            c.non_negative(&f("arm_length_m"), s.arm_length_m)?;
        }
        for (i, r) in self.roi.iter().enumerate() {
            let f = |n: &str| format!("roi[{i}].{n}");
            c.positive(&f("weight"), r.weight)?;
            match r.kind {
                RoiKind::Polygon => match &r.polygon {
                    Some(p) => {
                        c.polygon(&f("polygon"), p)?;
                        c.on_ground(&f("polygon"), p, self.ground.half_size_m)?;
                    }
                    None => return Err(c.err(&f("polygon"), "missing", "kind = \"polygon\" needs a polygon")),
                },
                RoiKind::Approaches => match r.length_m {
                    Some(l) => c.positive(&f("length_m"), l)?,
                    None => return Err(c.err(&f("length_m"), "missing", "kind = \"approaches\" needs length_m")),
                },
                RoiKind::Central => {}
            }
            if r.kind != RoiKind::Polygon && self.arms.is_empty() {
                return Err(c.err(&f("kind"), r.kind, "derived ROIs need at least one arm"));
            }
        }
        for (i, m) in self.meshes.iter().enumerate() {
            let f = |n: &str| format!("meshes[{i}].{n}");
            if !m.translation_m.iter().all(|v| v.is_finite()) {
                return Err(c.err(&f("translation_m"), m.translation_m, "must be finite"));
            }
            c.heading(&f("yaw_deg"), m.yaw_deg)?;
            if !(m.scale.is_finite() && m.scale > 0.0) {
                return Err(c.err(&f("scale"), m.scale, "must be a finite number > 0"));
            }
        }
        Ok(())
    }
}

/// The checks of one arm's numbers (`arms[i]`), the ground's half size given.
fn check_arm(c: &Check, i: usize, a: &ArmConfig, ground_half_m: f32) -> Result<(), RaycastError> {
    let f = |n: &str| format!("arms[{i}].{n}");
    c.heading(&f("heading_deg"), a.heading_deg)?;
    c.positive(&f("length_m"), a.length_m)?;
    c.positive(&f("lane_width_m"), a.lane_width_m)?;
    c.non_negative(&f("median_width_m"), a.median_width_m)?;
    if !(a.offset_m.is_finite() && a.offset_m.abs() <= MAX_ARM_OFFSET_M) {
        return Err(c.err(
            &f("offset_m"),
            a.offset_m,
            &format!("an arm's centre line lies within {MAX_ARM_OFFSET_M} m of the junction's centre"),
        ));
    }
    c.non_negative(&f("sidewalk_width_m"), a.sidewalk_width_m)?;
    c.non_negative(&f("curb_height_m"), a.curb_height_m)?;
    c.positive(&f("crosswalk_width_m"), a.crosswalk_width_m)?;
    c.positive(&f("speed_limit_kph"), a.speed_limit_kph)?;
    c.non_negative(&f("left_turn_bay_length_m"), a.left_turn_bay_length_m)?;
    if !(a.corner_radius_m.is_finite() && (0.0..=MAX_CORNER_RADIUS_M).contains(&a.corner_radius_m)) {
        return Err(c.err(
            &f("corner_radius_m"),
            a.corner_radius_m,
            &format!("a curb's radius at a corner is 0 (sharp) to {MAX_CORNER_RADIUS_M} m"),
        ));
    }
    if a.lanes_in + a.lanes_out == 0 {
        return Err(c.err(&f("lanes_in"), a.lanes_in, "an arm needs at least one lane"));
    }
    for (name, n, most) in
        [("lanes_in", a.lanes_in, 8), ("lanes_out", a.lanes_out, 8), ("left_turn_lanes", a.left_turn_lanes, 3)]
    {
        if n > most {
            return Err(c.err(&f(name), n, &format!("more than {most} lanes in one direction: not a road")));
        }
    }
    if !(2.0..=6.0).contains(&a.lane_width_m) {
        return Err(c.err(&f("lane_width_m"), a.lane_width_m, "a lane is 2 to 6 m wide"));
    }
    let park = a.parking_lane_width_m;
    if !(park == 0.0 || (1.8..=3.0).contains(&park)) {
        return Err(c.err(&f("parking_lane_width_m"), park, "a parking lane is 1.8 to 3 m wide (0: none)"));
    }
    if a.length_m > ground_half_m {
        return Err(c.err(
            &f("length_m"),
            a.length_m,
            &format!("the arm runs off the ground (ground.half_size_m = {})", ground_half_m),
        ));
    }
    Ok(())
}

/// A curb radius only where the arm's inbound side meets a corner: the next arm
/// counter-clockwise turns off by less than 179° (a T-junction's straight side has none).
fn check_corner_radii(c: &Check, arms: &[ArmConfig]) -> Result<(), RaycastError> {
    let key = |a: &ArmConfig| a.heading_deg.rem_euclid(360.0);
    for (i, a) in arms.iter().enumerate() {
        if a.corner_radius_m == 0.0 {
            continue;
        }
        // The next arm counter-clockwise, and the angle to it (360° when alone).
        let gap = arms
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, b)| (key(b) - key(a)).rem_euclid(360.0))
            .filter(|g| *g > 0.0)
            .fold(360.0f32, f32::min);
        if gap >= 179.0 {
            return Err(c.err(
                &format!("arms[{i}].corner_radius_m"),
                a.corner_radius_m,
                &format!(
                    "the arm's inbound side meets no corner: the next arm counter-clockwise is {gap:.0}° round, \
                     a road running on"
                ),
            ));
        }
    }
    Ok(())
}

/// The lane graph's checks: arms that exist, lanes they have, no U-turn, each connection once,
/// and none at a roundabout (its ring connects every entry to every exit).
fn check_connections(
    c: &Check,
    connections: &[ConnectionConfig],
    arms: &[ArmConfig],
    roundabout: bool,
    ground_half_m: f32,
) -> Result<(), RaycastError> {
    if roundabout && !connections.is_empty() {
        return Err(c.err("connections", connections.len(), "a roundabout's ring connects every entry to every exit"));
    }
    let mut seen = std::collections::BTreeSet::new();
    for (k, x) in connections.iter().enumerate() {
        let f = |n: &str| format!("connections[{k}].{n}");
        let arm = |field: &str, name: &str| {
            arms.iter().find(|a| a.name == name).ok_or_else(|| {
                let known: Vec<&str> = arms.iter().map(|a| a.name.as_str()).collect();
                c.err(&f(field), name, &format!("no arm of that name; the arms: {}", known.join(", ")))
            })
        };
        let (from, to) = (arm("from", &x.from)?, arm("to", &x.to)?);
        if from.name == to.name {
            return Err(c.err(&f("to"), &x.to, "a U-turn: a connection leads to another arm"));
        }
        if x.from_lane >= from.lanes_in {
            return Err(c.err(
                &f("from_lane"),
                x.from_lane,
                &format!("arm {:?} has {} inbound lane(s), counted from 0", from.name, from.lanes_in),
            ));
        }
        if x.to_lane >= to.lanes_out {
            return Err(c.err(
                &f("to_lane"),
                x.to_lane,
                &format!("arm {:?} has {} outbound lane(s), counted from 0", to.name, to.lanes_out),
            ));
        }
        if !seen.insert((&x.from, x.from_lane, &x.to, x.to_lane)) {
            return Err(c.err(&format!("connections[{k}]"), x, "listed twice"));
        }
        check_connection_path(c, &f("path"), &x.path, ground_half_m)?;
    }
    Ok(())
}

/// A connection's drawn path: none, or 2 to [`MAX_CONNECTION_POINTS`] finite points on the
/// ground.
fn check_connection_path(c: &Check, field: &str, path: &[[f32; 2]], ground_half_m: f32) -> Result<(), RaycastError> {
    if path.is_empty() {
        return Ok(());
    }
    if path.len() < 2 || path.len() > MAX_CONNECTION_POINTS {
        let why = format!("a path lists 2 to {MAX_CONNECTION_POINTS} points, or none (hilo draws the turn)");
        return Err(c.err(field, path.len(), &why));
    }
    if let Some((k, p)) = path.iter().enumerate().find(|(_, p)| !p[0].is_finite() || !p[1].is_finite()) {
        return Err(c.err(&format!("{field}[{k}]"), p, "must be finite numbers"));
    }
    c.on_ground(field, path, ground_half_m)
}

/// The signal groups' checks: arms that exist, each in one group, a group of one arm or two
/// facing each other, every arm with an inbound lane served and none without one, and no
/// signal at a roundabout.
fn check_signal_groups(
    c: &Check,
    groups: &[Vec<String>],
    arms: &[ArmConfig],
    roundabout: bool,
) -> Result<(), RaycastError> {
    if groups.is_empty() {
        return Ok(());
    }
    if roundabout {
        return Err(c.err("signal_groups", groups, "no signal runs a roundabout"));
    }
    let mut served = std::collections::BTreeSet::new();
    for (k, g) in groups.iter().enumerate() {
        let f = format!("signal_groups[{k}]");
        if g.is_empty() || g.len() > 2 {
            return Err(c.err(&f, g, "a group is one arm or two arms facing each other"));
        }
        let mut headings = Vec::new();
        for name in g {
            let Some(a) = arms.iter().find(|a| &a.name == name) else {
                let known: Vec<&str> = arms.iter().map(|a| a.name.as_str()).collect();
                return Err(c.err(&f, name, &format!("no arm of that name; the arms: {}", known.join(", "))));
            };
            if a.lanes_in + a.left_turn_lanes == 0 {
                return Err(c.err(&f, name, "the arm has no inbound lane: no signal faces its traffic"));
            }
            if !served.insert(name.as_str()) {
                return Err(c.err(&f, name, "the arm is in another group too: each arm has one phase"));
            }
            headings.push(a.heading_deg);
        }
        if let [h0, h1] = headings[..] {
            let gap = (h1 - h0).rem_euclid(360.0);
            if (gap - 180.0).abs() >= 20.0 {
                return Err(c.err(
                    &f,
                    g,
                    &format!(
                        "the two arms' headings ({h0}° and {h1}°) are {:.0}° from opposite: their traffic would cross on \
                         green; a group's two arms face each other within 20°",
                        (gap - 180.0).abs()
                    ),
                ));
            }
        }
    }
    if let Some(a) = arms.iter().find(|a| a.lanes_in + a.left_turn_lanes > 0 && !served.contains(a.name.as_str())) {
        return Err(c.err("signal_groups", &a.name, "an arm with inbound lanes is in no group: give it a phase"));
    }
    Ok(())
}

/// The checks of a roundabout's numbers against its arms: a ring the arms can meet (every
/// arm's carriageway narrower than the inscribed circle), one lane each way and no left-turn
/// bays (the ring serves every turn).
fn check_roundabout(c: &Check, r: &RoundaboutConfig, arms: &[ArmConfig]) -> Result<(), RaycastError> {
    for (field, v, lo, hi) in [
        ("roundabout.island_radius_m", r.island_radius_m, 2.0, 60.0),
        ("roundabout.ring_width_m", r.ring_width_m, 4.0, 8.0),
        ("roundabout.crosswalk_setback_m", r.crosswalk_setback_m, 2.0, 30.0),
    ] {
        if !(v.is_finite() && (lo..=hi).contains(&v)) {
            return Err(c.err(field, v, &format!("must be in [{lo}, {hi}] m")));
        }
    }
    let curb = arms.iter().map(|a| a.curb_height_m).fold(0.0, f32::max);
    if !(r.island_height_m.is_finite() && (curb..=5.0).contains(&r.island_height_m)) {
        return Err(c.err(
            "roundabout.island_height_m",
            r.island_height_m,
            &format!("must be in [{curb}, 5] m (at least the curb's height)"),
        ));
    }
    if arms.len() < 3 {
        return Err(c.err("arms", arms.len(), "a roundabout needs at least three arms"));
    }
    for (i, a) in arms.iter().enumerate() {
        let f = |n: &str| format!("arms[{i}].{n}");
        if a.left_turn_lanes > 0 {
            return Err(c.err(
                &f("left_turn_lanes"),
                a.left_turn_lanes,
                "a roundabout's ring serves every turn: no bays",
            ));
        }
        if a.corner_radius_m > 0.0 {
            return Err(c.err(
                &f("corner_radius_m"),
                a.corner_radius_m,
                "a roundabout's curbs flare onto its ring on their own: no corner radius",
            ));
        }
        if a.lanes_in > 1 || a.lanes_out > 1 {
            return Err(c.err(
                &f("lanes_in"),
                format!("{} in, {} out", a.lanes_in, a.lanes_out),
                "the roundabout model has one circulating lane: one lane each way per arm",
            ));
        }
        let half = a.offset_m.abs()
            + 0.5 * a.median_width_m
            + a.lanes_in.max(a.lanes_out) as f32 * a.lane_width_m
            + a.parking_lane_width_m;
        if half + 1.0 > r.outer_radius_m() {
            return Err(c.err(
                "roundabout.island_radius_m",
                r.island_radius_m,
                &format!("arm {:?} is wider than the ring it meets: a larger island_radius_m or ring_width_m", a.name),
            ));
        }
    }
    Ok(())
}

/// Two arms whose roadways (lanes, median, sidewalks) still overlap beyond half the shorter
/// arm's length (beyond the ring's crosswalks at a roundabout): neighbours in heading whose
/// facing roadway edges meet farther out than that (or never, when nearly parallel). Returns
/// (i, j, metres from the centre where they part).
fn overlapping_arms(arms: &[ArmConfig], ring: Option<&RoundaboutConfig>) -> Option<(usize, usize, f32)> {
    if arms.len() < 2 {
        return None;
    }
    let mut order: Vec<usize> = (0..arms.len()).collect();
    let key = |i: usize| arms[i].heading_deg.rem_euclid(360.0);
    order.sort_by(|&a, &b| key(a).total_cmp(&key(b)));
    for k in 0..order.len() {
        let (i, j) = (order[k], order[(k + 1) % order.len()]);
        let gap = (key(j) - key(i)).rem_euclid(360.0);
        if gap >= 179.0 || (arms.len() == 2 && k == 1) {
            continue; // a straight road, or the far side of a two-arm junction
        }
        let (a, b) = (&arms[i], &arms[j]);
        // Arm i's left (inbound) edge and arm j's right (outbound) edge, as offsets from their
        // centre lines, sidewalks included.
        let left_a = a.offset_m
            + 0.5 * a.median_width_m
            + (a.left_turn_lanes + a.lanes_in) as f32 * a.lane_width_m
            + a.parking_lane_width_m
            + a.sidewalk_width_m;
        let right_b =
            0.5 * b.median_width_m + b.lanes_out as f32 * b.lane_width_m + b.parking_lane_width_m + b.sidewalk_width_m
                - b.offset_m;
        let theta = gap.to_radians();
        // Distance along the arms where the two edges meet: the corner of the junction.
        let along = (left_a + right_b * theta.cos()) / theta.sin().max(1e-6);
        let along = along.max((right_b + left_a * theta.cos()) / theta.sin().max(1e-6));
        let limit = match ring {
            // At a roundabout the arms must part before their crosswalks.
            Some(r) => r.outer_radius_m() + r.crosswalk_setback_m,
            None => 0.5 * a.length_m.min(b.length_m),
        };
        if along > limit {
            return Some((i, j, along));
        }
    }
    None
}
