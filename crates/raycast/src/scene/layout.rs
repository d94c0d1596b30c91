//! The road layout derived from the arms: lanes, stop lines, crosswalks, sidewalks, medians,
//! the junction box and ROI polygons. Everything is 2-D in the local frame.
//!
//! Simplifications (documented for users): arms are straight; the junction corners are sharp
//! unless an arm gives its corner a curb radius (`corner_radius_m`, which an OpenDRIVE import
//! fits to the file's right turns); right turns share the outermost through lane (no right-turn
//! bays); roads are flat at ground height, and only sidewalks and medians are raised (by the
//! curb height).
//! A parking lane (`parking_lane_width_m`) widens the road on both curb sides of an arm; the
//! crosswalk crosses it, the stop line does not. Sidewalks run along the curbs from each corner
//! and meet in a corner piece behind both curbs: a square at a right corner, a rhombus at an
//! obtuse one; at an acute corner each strip starts where its outer edge meets the neighbour's
//! curb and the corner piece is a parallelogram along the two curbs, so no sidewalk lies on a
//! carriageway. A rounded corner's curb is an arc tangent to both edges; its sidewalk follows
//! the arc, the strips start at the tangent points, and the crosswalks and stop lines of both
//! arms lie beyond them (a crosswalk starts where both its ends stand on a straight sidewalk).
//!
//! A roundabout (`[roundabout]`) replaces the junction box with a ring around a raised island:
//! each arm's yield line lies just off the ring and its crosswalk a setback behind it, and each
//! curb flares onto the ring along an arc tangent to the arm's edge and to the ring ([`Ring`]);
//! the sidewalks follow the flares and the ring between the arms.

use super::config::{ArmConfig, RoiConfig, RoiKind, SceneConfig};
use glam::Vec2;
use serde::{Deserialize, Serialize};

/// What a lane is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LaneKind {
    /// Towards the junction, through (and, for the outermost, right) movements.
    Inbound,
    /// A left-turn bay next to the median, inbound.
    LeftTurnBay,
    /// Away from the junction.
    Outbound,
}

/// A lane as a straight centreline in its driving direction.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Lane {
    pub kind: LaneKind,
    pub start: Vec2,
    pub end: Vec2,
    pub width_m: f32,
}

/// One arm's derived geometry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArmLayout {
    pub name: String,
    /// Unit outward direction and its counter-clockwise normal (the inbound side).
    pub dir: Vec2,
    pub normal: Vec2,
    /// Lateral offsets of the road edges along `normal` from the junction's centre (outbound
    /// edge is the lower).
    pub edge_in_m: f32,
    pub edge_out_m: f32,
    /// Lateral offset of the arm's centre line (the median's middle) from the junction's centre
    /// along `normal`: [`ArmConfig::offset_m`].
    #[serde(default, skip_serializing_if = "super::config::is_zero")]
    pub offset_m: f32,
    /// Half the median width: the lanes start this far from the arm's centre line on each side.
    pub median_half_width_m: f32,
    /// Width of the parking lane inside each road edge, between the outermost lane and the
    /// curb (0: none).
    #[serde(default, skip_serializing_if = "super::config::is_zero")]
    pub parking_lane_m: f32,
    pub lanes: Vec<Lane>,
    /// Stop line across the inbound lanes, `[median side, curb side]`.
    pub stop_line: [Vec2; 2],
    /// Distance of the stop line from the centre along `dir`.
    pub stop_line_at_m: f32,
    pub crosswalk: Vec<Vec2>,
    pub road: Vec<Vec2>,
    pub sidewalks: Vec<Vec<Vec2>>,
    pub median: Option<Vec<Vec2>>,
    pub curb_height_m: f32,
    pub speed_limit_mps: f32,
}

/// The whole junction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct Layout {
    pub arms: Vec<ArmLayout>,
    /// The junction box and the crosswalks (the central conflict zone).
    pub central: Vec<Vec2>,
    /// Sidewalk squares at the corners between neighbouring arms (parallelograms along the
    /// curbs at acute corners).
    pub corner_sidewalks: Vec<Vec<Vec2>>,
    /// Where a pole stands at each of those corners: the middle of the rhombus spanned by the
    /// two curbs' outward normals, as wide as the narrower sidewalk (behind both curbs at any
    /// angle).
    #[serde(default)]
    pub corner_posts: Vec<Vec2>,
    /// The roundabout's ring, when the scene has one: `central` is then the inscribed circle
    /// and the arms' stubs out to their crosswalks, and the corners' sidewalks follow the ring.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ring: Option<Ring>,
    /// The scene's lane graph ([`super::config::ConnectionConfig`]) by arm index into `arms`;
    /// empty where hilo's own rules connect the lanes.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub connections: Vec<Connection>,
    /// The scene's signal groups ([`super::config::SceneConfig::signal_groups`]) by arm index
    /// into `arms`, in the order they run; empty where hilo pairs opposing arms itself.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub signal_groups: Vec<Vec<usize>>,
}

/// Half the width a route keeps clear on either side of its centre line through the junction:
/// the widest car's half width (the traffic model's cars are up to 2.0 m wide).
pub const ROUTE_HALF_WIDTH_M: f32 = 1.0;

/// One connection of the lane graph: arm `from`'s inbound lane `from_lane` to arm `to`'s
/// outbound lane `to_lane` (lanes of each kind counted from the arm's centre line, 0 the
/// innermost; arms by index into [`Layout::arms`]), through the junction along `path` where
/// the scene gives one (else hilo draws the turn).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Connection {
    pub from: usize,
    pub from_lane: usize,
    pub to: usize,
    pub to_lane: usize,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub path: Vec<Vec2>,
}

/// A roundabout's circulatory roadway around its raised island, centred on the origin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ring {
    pub island_radius_m: f32,
    /// The inscribed circle: the ring's outer edge.
    pub outer_radius_m: f32,
    pub island_height_m: f32,
    /// The island's outline (counter-clockwise).
    pub island: Vec<Vec2>,
}

impl Ring {
    /// The circulating lane's centre line radius.
    pub fn lane_radius_m(&self) -> f32 {
        0.5 * (self.island_radius_m + self.outer_radius_m)
    }
}

/// Distance from `p` to the segment `a`–`b`.
pub fn point_segment_distance(p: Vec2, a: Vec2, b: Vec2) -> f32 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    (a + ab * t - p).length()
}

/// Vertices of the polygons that stand for circles and arcs: one every 7.5° or less.
const ARC_STEP_RAD: f32 = std::f32::consts::PI / 24.0;

/// Points on the circle of radius `r` from angle `a0` counter-clockwise to `a1` (radians), ends
/// included, at most [`ARC_STEP_RAD`] apart.
pub fn arc(r: f32, a0: f32, a1: f32) -> Vec<Vec2> {
    let span = (a1 - a0).rem_euclid(std::f32::consts::TAU);
    let n = (span / ARC_STEP_RAD).ceil().max(1.0) as usize;
    (0..=n).map(|k| Vec2::from_angle(a0 + span * k as f32 / n as f32) * r).collect()
}

/// The circle of radius `r` as a counter-clockwise polygon, vertices [`ARC_STEP_RAD`] apart.
pub fn circle(r: f32) -> Vec<Vec2> {
    let n = (std::f32::consts::TAU / ARC_STEP_RAD).round() as usize;
    (0..n).map(|k| Vec2::from_angle(std::f32::consts::TAU * k as f32 / n as f32) * r).collect()
}

impl Layout {
    /// Whether `p` is on the carriageway: on an arm's road or in the junction box, and on
    /// nothing the scene raises by the curb (a sidewalk, a corner's sidewalk, a median).
    pub fn on_carriageway(&self, p: Vec2) -> bool {
        let on_road = point_in_polygon(p, &self.central) || self.arms.iter().any(|a| point_in_polygon(p, &a.road));
        let raised = self.corner_sidewalks.iter().any(|w| point_in_polygon(p, w))
            || self.arms.iter().any(|a| {
                a.sidewalks.iter().any(|w| point_in_polygon(p, w))
                    || a.median.as_ref().is_some_and(|m| point_in_polygon(p, m))
            });
        on_road && !raised && !self.on_island(p)
    }

    /// Whether a car at `p` heading `dir` (a unit vector) is on the carriageway: its centre and
    /// its sides, [`ROUTE_HALF_WIDTH_M`] to either side.
    pub fn car_on_carriageway(&self, p: Vec2, dir: Vec2) -> bool {
        let side = dir.perp() * ROUTE_HALF_WIDTH_M;
        [p, p + side, p - side].iter().all(|&q| self.on_carriageway(q))
    }

    /// Whether `p` is on a roundabout's central island.
    pub fn on_island(&self, p: Vec2) -> bool {
        self.ring.as_ref().is_some_and(|r| p.length() < r.island_radius_m && point_in_polygon(p, &r.island))
    }
}

/// A resolved region of interest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Roi {
    pub name: String,
    pub weight: f32,
    /// One or more polygons (counter-clockwise).
    pub polygons: Vec<Vec<Vec2>>,
    /// Areas inside them that are not part of it (a roundabout's island in the central zone).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub holes: Vec<Vec<Vec2>>,
}

impl Roi {
    /// True when `p` lies in any of the ROI's polygons and in none of its holes.
    pub fn contains(&self, p: Vec2) -> bool {
        self.polygons.iter().any(|poly| point_in_polygon(p, poly)) && !self.holes.iter().any(|h| point_in_polygon(p, h))
    }
}

/// Even–odd point-in-polygon test.
pub fn point_in_polygon(p: Vec2, poly: &[Vec2]) -> bool {
    let mut inside = false;
    let n = poly.len();
    let mut j = n.wrapping_sub(1);
    for i in 0..n {
        let (a, b) = (poly[i], poly[j]);
        if (a.y > p.y) != (b.y > p.y) && p.x < (b.x - a.x) * (p.y - a.y) / (b.y - a.y) + a.x {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// An arm's frame. Lateral offsets (`s_med`, `edge_in`, `edge_out`, the `s` of [`Self::at`])
/// are measured from the arm's own centre line, which lies `off` metres along `normal` from the
/// junction's centre.
struct ArmFrame<'a> {
    cfg: &'a ArmConfig,
    dir: Vec2,
    normal: Vec2,
    off: f32,
    s_med: f32,
    edge_in: f32,
    edge_out: f32,
}

impl ArmFrame<'_> {
    /// Point at distance `a` along the arm and lateral offset `s` from its centre line.
    fn at(&self, a: f32, s: f32) -> Vec2 {
        if self.off == 0.0 { self.dir * a + self.normal * s } else { self.dir * a + self.normal * (s + self.off) }
    }

    fn rect(&self, a0: f32, a1: f32, s0: f32, s1: f32) -> Vec<Vec2> {
        vec![self.at(a0, s0), self.at(a1, s0), self.at(a1, s1), self.at(a0, s1)]
    }
}

/// Intersection of the lines `x·n1 = c1` and `x·n2 = c2`, if they are not (nearly) parallel.
fn line_meet(n1: Vec2, c1: f32, n2: Vec2, c2: f32) -> Option<Vec2> {
    let det = n1.x * n2.y - n1.y * n2.x;
    if det.abs() < 1e-3 {
        return None;
    }
    Some(Vec2::new((c1 * n2.y - c2 * n1.y) / det, (n1.x * c2 - n2.x * c1) / det))
}

/// The sine of the angle between two neighbouring arms (`a`, then `b` counter-clockwise) when
/// the corner between them is acute, by more than a hundredth of a degree.
fn acute_sin(a: Vec2, b: Vec2) -> Option<f32> {
    let (sin, cos) = (a.perp_dot(b), a.dot(b));
    (sin > 0.0 && cos > 1.75e-4).then_some(sin)
}

/// How far along its arm a sidewalk strip of width `sw` starts beyond the corner it shares
/// with its neighbour: `sw · cot θ` at an acute corner of angle θ (its outer edge then meets
/// the neighbour's curb), 0 otherwise. `a` is the arm before `b` counter-clockwise.
fn acute_setback(a: Vec2, b: Vec2, sw: f32, corner: bool) -> f32 {
    match acute_sin(a, b) {
        Some(sin) if corner => sw * a.dot(b) / sin,
        _ => 0.0,
    }
}

/// A corner whose curb runs along a circular arc (`corner_radius_m`): the circle of `radius`
/// about `centre`, behind both curbs, tangent to arm `a`'s inbound edge at `on_in` and to the
/// next arm `b`'s outbound edge at `on_out`.
struct Rounded {
    centre: Vec2,
    radius: f32,
    on_in: Vec2,
    on_out: Vec2,
}

impl Rounded {
    /// The rounded corner between arm `a`'s inbound edge and arm `b`'s outbound edge, if
    /// `radius` is positive and the edges are not (nearly) parallel.
    fn of(a: &ArmFrame, b: &ArmFrame, radius: f32) -> Option<Rounded> {
        Rounded::between(a.normal, a.edge_in + a.off, b.normal, b.edge_out + b.off, radius)
    }

    /// The same from the edges' lines: arm `a`'s inbound edge `x · na = ea` and arm `b`'s
    /// outbound edge `x · nb = eb` (lateral offsets from the junction's centre).
    fn between(na: Vec2, ea: f32, nb: Vec2, eb: f32, radius: f32) -> Option<Rounded> {
        if radius <= 0.0 {
            return None;
        }
        // Behind a's inbound edge is +normal, behind b's outbound edge −normal.
        let centre = line_meet(na, ea + radius, nb, eb - radius)?;
        Some(Rounded { centre, radius, on_in: centre - na * radius, on_out: centre + nb * radius })
    }

    /// The curb from `on_in` to `on_out`, bulging towards the sharp corner it replaces.
    fn curb(&self) -> Vec<Vec2> {
        short_arc(self.centre, self.on_in, self.on_out)
    }

    /// The corner's sidewalk, `sw` wide behind the curb: between the curb and the same arc
    /// `sw` nearer the centre, or the sector out to the centre when the radius is no more than
    /// `sw` (the arms' strips, which start at the tangent points, cover the rest).
    fn sidewalk(&self, sw: f32) -> Vec<Vec2> {
        let curb = self.curb();
        let mut walk = curb.clone();
        if self.radius > sw {
            let k = (self.radius - sw) / self.radius;
            walk.extend(curb.iter().rev().map(|&p| self.centre + (p - self.centre) * k));
        } else {
            walk.push(self.centre);
        }
        ccw(walk)
    }

    /// Where a pole stands: on the corner's bisector, half the sidewalk's width `sw` behind the
    /// curb (or, where the curb's radius is under that, as far from both curbs' lines).
    fn post(&self, a: &ArmFrame, b: &ArmFrame, sw: f32) -> Vec2 {
        let bisector = ((self.on_in - self.centre) + (self.on_out - self.centre)).normalize_or_zero();
        if self.radius >= 0.5 * sw {
            return self.centre + bisector * (self.radius - 0.5 * sw);
        }
        line_meet(a.normal, a.edge_in + a.off + 0.5 * sw, b.normal, b.edge_out + b.off - 0.5 * sw)
            .unwrap_or(self.centre)
    }
}

/// The curb from arm `a`'s inbound edge round to arm `b`'s outbound edge (`b` the next arm
/// counter-clockwise), `reach` metres along each edge beyond the corner: two straight runs
/// meeting at the sharp corner, or joined by an arc of `radius` (sampled every degree) as
/// [`build_layout`] rounds it. `None` where the edges are (nearly) parallel.
pub fn corner_curb(a: &ArmLayout, b: &ArmLayout, radius: f32, reach: f32) -> Option<Vec<Vec2>> {
    if radius <= 0.0 {
        let p = line_meet(a.normal, a.edge_in_m, b.normal, b.edge_out_m)?;
        return Some(vec![p + a.dir * reach, p, p + b.dir * reach]);
    }
    let r = Rounded::between(a.normal, a.edge_in_m, b.normal, b.edge_out_m, radius)?;
    // From the centre towards each tangent point.
    let (u0, u1) = (-a.normal, b.normal);
    let delta = u0.perp_dot(u1).atan2(u0.dot(u1));
    let n = (delta.abs().to_degrees().ceil() as usize).max(1);
    let mut curb = vec![r.on_in + a.dir * reach];
    curb.extend((0..=n).map(|k| r.centre + Vec2::from_angle(delta * k as f32 / n as f32).rotate(u0) * radius));
    curb.push(r.on_out + b.dir * reach);
    Some(curb)
}

/// Derives the layout. Arms are handled in counter-clockwise order of heading.
pub fn build_layout(cfg: &SceneConfig) -> Layout {
    let mut frames: Vec<ArmFrame> = cfg
        .arms
        .iter()
        .map(|a| {
            let dir = Vec2::from_angle(a.heading_deg.to_radians());
            let s_med = 0.5 * a.median_width_m;
            ArmFrame {
                cfg: a,
                dir,
                normal: dir.perp(),
                off: a.offset_m,
                s_med,
                edge_in: s_med + (a.left_turn_lanes + a.lanes_in) as f32 * a.lane_width_m + a.parking_lane_width_m,
                edge_out: -(s_med + a.lanes_out as f32 * a.lane_width_m + a.parking_lane_width_m),
            }
        })
        .collect();
    frames.sort_by(|a, b| {
        let ka = a.dir.y.atan2(a.dir.x).rem_euclid(std::f32::consts::TAU);
        let kb = b.dir.y.atan2(b.dir.x).rem_euclid(std::f32::consts::TAU);
        ka.total_cmp(&kb)
    });
    let n = frames.len();
    // corner[i] joins arm i's inbound edge to arm i+1's outbound edge.
    let corners: Vec<Option<Vec2>> = (0..n)
        .map(|i| {
            if n < 2 {
                return None;
            }
            let (a, b) = (&frames[i], &frames[(i + 1) % n]);
            line_meet(a.normal, a.edge_in + a.off, b.normal, b.edge_out + b.off)
                // Keep only corners on the junction side of both arms.
                .filter(|p| p.dot(a.dir) > -1.0 && p.dot(b.dir) > -1.0 && p.length() < 200.0)
        })
        .collect();

    // rounded[i]: corner[i] with arm i's curb radius, where it has one.
    let rounded: Vec<Option<Rounded>> = (0..n)
        .map(|i| corners[i].and_then(|_| Rounded::of(&frames[i], &frames[(i + 1) % n], frames[i].cfg.corner_radius_m)))
        .collect();
    let ring = cfg.roundabout.as_ref();
    let ro = ring.map_or(0.0, |r| r.outer_radius_m());
    let mut layout = Layout::default();
    for (i, f) in frames.iter().enumerate() {
        let a = f.cfg;
        let prev = (i + n - 1) % n;
        // Where the curbs start (a corner, or the ring), the crosswalk and the stop (or yield)
        // line, along the arm from the centre.
        // How far out along the arm a point lies (0 for none, or one behind the centre).
        let along = |p: Option<Vec2>| p.map_or(0.0, |p| p.dot(f.dir)).max(0.0);
        let (a_in, a_out, cw0, stop) = match ring {
            // A rounded corner's curb meets the arm's edge at its tangent point.
            None => {
                let a_in = along(rounded[i].as_ref().map_or(corners[i], |r| Some(r.on_in)));
                let a_out = along(rounded[prev].as_ref().map_or(corners[prev], |r| Some(r.on_out)));
                let cw0 = a_in.max(a_out) + 0.5;
                (a_in, a_out, cw0, cw0 + a.crosswalk_width_m + 1.0)
            }
            // The yield line just off the ring, the crosswalk a setback behind it, the curbs
            // from where the corners' flares meet them.
            Some(r) => {
                let cw0 = ro + r.crosswalk_setback_m;
                (fillet(f, f.edge_in, ro, cw0).along, fillet(f, f.edge_out, ro, cw0).along, cw0, ro + 0.5)
            }
        };
        let cw1 = cw0 + a.crosswalk_width_m;
        let beyond = stop.max(cw1);
        let len = a.length_m.max(beyond + 1.0);
        let w = a.lane_width_m;
        let mut lanes = Vec::new();
        for k in 0..a.left_turn_lanes {
            let s = f.s_med + (k as f32 + 0.5) * w;
            let bay_start = (stop + a.left_turn_bay_length_m).min(len);
            lanes.push(Lane { kind: LaneKind::LeftTurnBay, start: f.at(bay_start, s), end: f.at(stop, s), width_m: w });
        }
        for k in 0..a.lanes_in {
            let s = f.s_med + (a.left_turn_lanes + k) as f32 * w + 0.5 * w;
            lanes.push(Lane { kind: LaneKind::Inbound, start: f.at(len, s), end: f.at(stop, s), width_m: w });
        }
        for k in 0..a.lanes_out {
            let s = -(f.s_med + (k as f32 + 0.5) * w);
            let from = if ring.is_some() { stop } else { cw0 };
            lanes.push(Lane { kind: LaneKind::Outbound, start: f.at(from, s), end: f.at(len, s), width_m: w });
        }
        let sw = a.sidewalk_width_m;
        let mut sidewalks = Vec::new();
        if sw > 0.0 {
            // At an acute corner a strip starting at the corner would reach over the
            // neighbour's carriageway: it starts where its outer edge meets the neighbour's curb.
            let next = &frames[(i + 1) % n];
            let before = &frames[prev];
            // The setback is from the sharp corner; a rounded curb's tangent point may lie
            // beyond it (at a roundabout the flare sets where the strips start).
            let (a_in, a_out) = match ring {
                None => (
                    a_in.max(along(corners[i]) + acute_setback(f.dir, next.dir, sw, corners[i].is_some())),
                    a_out.max(along(corners[prev]) + acute_setback(before.dir, f.dir, sw, corners[prev].is_some())),
                ),
                Some(_) => (a_in, a_out),
            };
            sidewalks.push(f.rect(a_in, len, f.edge_in, f.edge_in + sw));
            sidewalks.push(f.rect(a_out, len, f.edge_out - sw, f.edge_out));
        }
        let median =
            (a.median_width_m > 0.0 && beyond + 1.0 < len).then(|| f.rect(beyond + 1.0, len, -f.s_med, f.s_med));
        layout.arms.push(ArmLayout {
            name: a.name.clone(),
            dir: f.dir,
            normal: f.normal,
            edge_in_m: f.edge_in + f.off,
            edge_out_m: f.edge_out + f.off,
            offset_m: f.off,
            median_half_width_m: f.s_med,
            parking_lane_m: a.parking_lane_width_m,
            lanes,
            stop_line: [f.at(stop, f.s_med), f.at(stop, f.edge_in - a.parking_lane_width_m)],
            stop_line_at_m: stop,
            crosswalk: f.rect(cw0, cw1, f.edge_out, f.edge_in),
            road: f.rect(0.0, len, f.edge_out, f.edge_in),
            sidewalks,
            median,
            curb_height_m: a.curb_height_m,
            speed_limit_mps: a.speed_limit_kph / 3.6,
        });
    }
    if let Some(r) = ring {
        ring_central(&mut layout, &frames, r);
        return layout;
    }
    junction_box(&mut layout, &frames, &corners, &rounded);
    if n == 1 {
        layout.central.clear();
        let f = &frames[0];
        let cw1 = layout.arms[0].crosswalk[1].dot(f.dir);
        layout.central = f.rect(0.0, cw1, f.edge_out, f.edge_in);
    }
    with_graph(cfg, layout)
}

/// The junction box (`central`), walking counter-clockwise round the arms' crosswalks and the
/// corners between them (sharp, or `rounded` along the curb's arc), and each corner's sidewalk
/// piece and pole place.
fn junction_box(layout: &mut Layout, frames: &[ArmFrame], corners: &[Option<Vec2>], rounded: &[Option<Rounded>]) {
    let n = frames.len();
    for i in 0..n {
        let (f, g) = (&frames[i], &frames[(i + 1) % n]);
        let cw1_f = layout.arms[i].crosswalk[1].dot(f.dir);
        layout.central.push(f.at(cw1_f, f.edge_out));
        layout.central.push(f.at(cw1_f, f.edge_in));
        if let Some(r) = &rounded[i] {
            layout.central.extend(r.curb());
            let sw = f.cfg.sidewalk_width_m.min(g.cfg.sidewalk_width_m);
            if sw > 0.0 {
                layout.corner_posts.push(r.post(f, g, sw));
                layout.corner_sidewalks.push(r.sidewalk(sw));
            }
        } else if let Some(p) = corners[i] {
            layout.central.push(p);
            let sw = f.cfg.sidewalk_width_m.min(g.cfg.sidewalk_width_m);
            if sw > 0.0 {
                let rhombus = [p, p - g.normal * sw, p - g.normal * sw + f.normal * sw, p + f.normal * sw];
                layout.corner_posts.push(rhombus.iter().fold(Vec2::ZERO, |s, q| s + *q) / 4.0);
                layout.corner_sidewalks.push(match acute_sin(f.dir, g.dir) {
                    // The parallelogram between the two curbs, out to where each strip's outer
                    // edge meets the other curb (the square of a right corner, skewed).
                    Some(sin) => {
                        let (sw_f, sw_g, cos) = (f.cfg.sidewalk_width_m, g.cfg.sidewalk_width_m, f.dir.dot(g.dir));
                        let along_f = f.dir * (sw_g / sin).max(sw_f * cos / sin);
                        let along_g = g.dir * (sw_f / sin).max(sw_g * cos / sin);
                        vec![p, p + along_f, p + along_f + along_g, p + along_g]
                    }
                    None => rhombus.to_vec(),
                });
            }
        }
    }
}

/// The layout with the scene's lane graph and signal groups, their arms by index into its arms
/// (a name the layout lacks, which a checked scene never has, is dropped).
fn with_graph(cfg: &SceneConfig, layout: Layout) -> Layout {
    let index = |name: &String| layout.arms.iter().position(|a| &a.name == name);
    let signal_groups = cfg.signal_groups.iter().map(|g| g.iter().filter_map(index).collect()).collect();
    Layout { connections: resolve_connections(cfg, &layout.arms), signal_groups, ..layout }
}

/// The scene's lane graph with its arms by index into `arms` (a connection naming an arm the
/// layout lacks, which a checked scene never does, is dropped).
fn resolve_connections(cfg: &SceneConfig, arms: &[ArmLayout]) -> Vec<Connection> {
    let index = |name: &str| arms.iter().position(|a| a.name == name);
    cfg.connections
        .iter()
        .filter_map(|c| {
            Some(Connection {
                from: index(&c.from)?,
                from_lane: c.from_lane as usize,
                to: index(&c.to)?,
                to_lane: c.to_lane as usize,
                path: c.path.iter().map(|p| Vec2::from(*p)).collect(),
            })
        })
        .collect()
}

/// The most and least radius of the curb's flare between an arm and a roundabout's ring.
const FLARE_MAX_M: f32 = 15.0;
const FLARE_MIN_M: f32 = 2.0;

/// The curb's flare where an arm's edge meets a roundabout's ring: a circular arc tangent to the
/// edge's line and to the ring's outer circle, outside both (the entry and exit radii of a
/// roundabout's design), as large as [`FLARE_MAX_M`] while it meets the edge before the crosswalk.
struct Fillet {
    centre: Vec2,
    radius: f32,
    /// Where it meets the edge's line (along the arm) and the ring.
    at_edge: Vec2,
    at_ring: Vec2,
    along: f32,
}

/// The flare of arm `f`'s edge at lateral offset `e` (from its centre line) against a ring of
/// outer radius `ro`, meeting the edge before `cw0` (the crosswalk) where it can.
fn fillet(f: &ArmFrame, e: f32, ro: f32, cw0: f32) -> Fillet {
    let lat = e + f.off;
    let sign = if e >= 0.0 { 1.0 } else { -1.0 };
    // Along the arm, the centre lies at √((ro + R)² − (|lat| + R)²), linear in R when squared.
    let until = (cw0 - 0.5).max(0.0);
    let room = 2.0 * (ro - lat.abs()).max(1e-3);
    let radius = ((until * until - ro * ro + lat * lat) / room).clamp(FLARE_MIN_M, FLARE_MAX_M);
    let along = ((ro + radius).powi(2) - (lat.abs() + radius).powi(2)).max(0.0).sqrt();
    let centre = f.dir * along + f.normal * (lat + sign * radius);
    Fillet { centre, radius, at_edge: f.dir * along + f.normal * lat, at_ring: centre * (ro / (ro + radius)), along }
}

/// Points on the circle about `c` from `p0` to `p1` the short way round, ends included.
fn short_arc(c: Vec2, p0: Vec2, p1: Vec2) -> Vec<Vec2> {
    let (u0, u1) = (p0 - c, p1 - c);
    let r = u0.length();
    let a0 = u0.y.atan2(u0.x);
    let delta = u0.perp_dot(u1).atan2(u0.dot(u1));
    let n = (delta.abs() / ARC_STEP_RAD).ceil().max(1.0) as usize;
    (0..=n).map(|k| c + Vec2::from_angle(a0 + delta * k as f32 / n as f32) * r).collect()
}

/// A roundabout's central polygon (the inscribed circle, the flares and each arm's stub out to
/// its crosswalk's far edge), the island, and the sidewalks along the flares and the ring
/// between the arms, as wide as the narrower of the two arms' sidewalks, with a pole's place in
/// the middle of each.
fn ring_central(layout: &mut Layout, frames: &[ArmFrame], r: &super::config::RoundaboutConfig) {
    let ro = r.outer_radius_m();
    let n = frames.len();
    let angle = |p: Vec2| p.y.atan2(p.x);
    let cw0 = ro + r.crosswalk_setback_m;
    let flares: Vec<(Fillet, Fillet)> =
        frames.iter().map(|f| (fillet(f, f.edge_out, ro, cw0), fillet(f, f.edge_in, ro, cw0))).collect();
    for i in 0..n {
        let (f, g) = (&frames[i], &frames[(i + 1) % n]);
        let cw1 = layout.arms[i].crosswalk[1].dot(f.dir);
        let (out, inn) = (&flares[i].0, &flares[i].1);
        let next = &flares[(i + 1) % n].0;
        layout.central.extend(short_arc(out.centre, out.at_ring, out.at_edge));
        layout.central.extend([f.at(cw1, f.edge_out), f.at(cw1, f.edge_in)]);
        let flare_in = short_arc(inn.centre, inn.at_edge, inn.at_ring);
        layout.central.extend_from_slice(&flare_in);
        let (a0, a1) = (angle(inn.at_ring), angle(next.at_ring));
        let ring = arc(ro, a0, a1);
        layout.central.extend_from_slice(&ring[1..ring.len() - 1]);
        let sw = f.cfg.sidewalk_width_m.min(g.cfg.sidewalk_width_m).min(inn.radius - 0.1).min(next.radius - 0.1);
        if sw > 0.0 {
            // The curb from arm i's edge round to the next arm's, then the same offset by the
            // sidewalk's width (towards the flares' centres, away from the ring's).
            let flare_next = short_arc(next.centre, next.at_ring, next.at_edge);
            let toward = |c: Vec2, rad: f32| move |p: Vec2| c + (p - c) * ((rad - sw) / rad);
            let mut walk = flare_in.clone();
            walk.extend_from_slice(&ring[1..ring.len() - 1]);
            walk.extend_from_slice(&flare_next);
            let mut outer: Vec<Vec2> = flare_in.iter().map(|&p| toward(inn.centre, inn.radius)(p)).collect();
            outer.extend(ring[1..ring.len() - 1].iter().map(|&p| p * ((ro + sw) / ro)));
            outer.extend(flare_next.iter().map(|&p| toward(next.centre, next.radius)(p)));
            walk.extend(outer.into_iter().rev());
            layout.corner_sidewalks.push(walk);
            let mid = a0 + 0.5 * (a1 - a0).rem_euclid(std::f32::consts::TAU);
            layout.corner_posts.push(Vec2::from_angle(mid) * (ro + 0.5 * sw));
        }
    }
    let island = circle(r.island_radius_m);
    layout.ring = Some(Ring {
        island_radius_m: r.island_radius_m,
        outer_radius_m: ro,
        island_height_m: r.island_height_m,
        island,
    });
}

/// Resolves the configured ROIs against the layout.
pub fn resolve_rois(rois: &[RoiConfig], layout: &Layout) -> Vec<Roi> {
    rois.iter()
        .map(|r| {
            let polygons = match r.kind {
                RoiKind::Polygon => {
                    vec![r.polygon.iter().flatten().map(|p| Vec2::from(*p)).collect()]
                }
                RoiKind::Central => vec![layout.central.clone()],
                RoiKind::Approaches => {
                    let length = r.length_m.unwrap_or(0.0);
                    layout
                        .arms
                        .iter()
                        .map(|arm| {
                            let a0 = arm.crosswalk[1].dot(arm.dir);
                            let inner = arm
                                .lanes
                                .iter()
                                .filter(|l| l.kind != LaneKind::Outbound)
                                .map(|l| l.end.dot(arm.normal) - 0.5 * l.width_m)
                                .fold(f32::INFINITY, f32::min);
                            let s0 = if inner.is_finite() { inner } else { 0.0 };
                            let (d, nrm) = (arm.dir, arm.normal);
                            let at = |a: f32, s: f32| d * a + nrm * s;
                            {
                                let e = arm.edge_in_m - arm.parking_lane_m;
                                vec![at(a0, s0), at(a0 + length, s0), at(a0 + length, e), at(a0, e)]
                            }
                        })
                        .collect()
                }
            };
            let polygons = polygons.into_iter().map(ccw).collect();
            let holes = match (&r.kind, &layout.ring) {
                (RoiKind::Central, Some(ring)) => vec![ring.island.clone()],
                _ => Vec::new(),
            };
            Roi { name: r.name.clone(), weight: r.weight, polygons, holes }
        })
        .collect()
}

/// The polygon in counter-clockwise order.
pub fn ccw(mut poly: Vec<Vec2>) -> Vec<Vec2> {
    let n = poly.len();
    let area: f32 = (0..n).map(|i| poly[i].perp_dot(poly[(i + 1) % n])).sum();
    if area < 0.0 {
        poly.reverse();
    }
    poly
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;
    use crate::scene::config::SceneConfig;
    use std::path::Path;

    fn default_cfg() -> SceneConfig {
        SceneConfig::from_toml_str(crate::scene::DEFAULT_SCENE_TOML, Path::new("default")).unwrap()
    }

    #[test]
    fn default_layout_has_lanes_stop_lines_and_a_ccw_central_zone() {
        let cfg = default_cfg();
        let l = build_layout(&cfg);
        assert_eq!(l.arms.len(), 4);
        let area: f32 = (0..l.central.len()).map(|i| l.central[i].perp_dot(l.central[(i + 1) % l.central.len()])).sum();
        assert!(area > 0.0, "central polygon must be counter-clockwise");
        assert!(point_in_polygon(Vec2::ZERO, &l.central));
        for arm in &l.arms {
            assert_eq!(arm.lanes.iter().filter(|x| x.kind == LaneKind::LeftTurnBay).count(), 1);
            assert_eq!(arm.lanes.iter().filter(|x| x.kind == LaneKind::Inbound).count(), 3);
            assert_eq!(arm.lanes.iter().filter(|x| x.kind == LaneKind::Outbound).count(), 3);
            let cw_far = arm.crosswalk[1].dot(arm.dir);
            assert!(arm.stop_line_at_m > cw_far, "{}: stop line inside the crosswalk", arm.name);
            for lane in &arm.lanes {
                // Inbound lanes end at the stop line; outbound lanes point away.
                let along = (lane.end - lane.start).dot(arm.dir);
                match lane.kind {
                    LaneKind::Outbound => assert!(along > 0.0),
                    _ => {
                        assert!(along < 0.0);
                        assert!((lane.end.dot(arm.dir) - arm.stop_line_at_m).abs() < 1e-4);
                        // Right-hand traffic: inbound lanes on the counter-clockwise side.
                        assert!(lane.end.dot(arm.normal) > 0.0);
                    }
                }
            }
        }
    }

    #[test]
    fn approach_rois_cover_inbound_lanes_only() {
        let cfg = default_cfg();
        let l = build_layout(&cfg);
        let rois = resolve_rois(&cfg.roi, &l);
        let queue = rois.iter().find(|r| r.name == "queue lanes").unwrap();
        let central = rois.iter().find(|r| r.name == "central conflict zone").unwrap();
        assert!(central.contains(Vec2::ZERO));
        for arm in &l.arms {
            let a = arm.stop_line_at_m + 10.0;
            for lane in &arm.lanes {
                let p = arm.dir * a + arm.normal * lane.end.dot(arm.normal);
                assert_eq!(queue.contains(p), lane.kind != LaneKind::Outbound, "{} {:?}", arm.name, lane.kind);
            }
            assert!(!queue.contains(arm.dir * (arm.stop_line_at_m + 80.0)));
        }
    }

    /// An arm offset to the left of the junction's centre is the same arm moved sideways: every
    /// lane, edge, sidewalk and its stop line by the offset along the normal, its road still
    /// reaching the junction (corners from the moved edges), the other arms' lanes unmoved.
    #[test]
    fn an_offset_arm_moves_sideways_whole() {
        let cfg = default_cfg();
        let mut moved = cfg.clone();
        moved.arms[0].offset_m = 1.5;
        let (a, b) = (build_layout(&cfg), build_layout(&moved));
        let name = &cfg.arms[0].name;
        let (x, y) =
            (a.arms.iter().find(|x| &x.name == name).unwrap(), b.arms.iter().find(|x| &x.name == name).unwrap());
        assert_eq!(x.lanes.len(), y.lanes.len());
        for (l0, l1) in x.lanes.iter().zip(&y.lanes) {
            for (p0, p1) in [(l0.start, l1.start), (l0.end, l1.end)] {
                assert!(((p1 - p0).dot(x.normal) - 1.5).abs() < 1e-4, "{:?}", l0.kind);
            }
        }
        assert!((y.edge_in_m - x.edge_in_m - 1.5).abs() < 1e-4 && (y.edge_out_m - x.edge_out_m - 1.5).abs() < 1e-4);
        assert_eq!(y.offset_m, 1.5);
        for (w0, w1) in x.sidewalks.iter().zip(&y.sidewalks) {
            assert!(((w1[2] - w0[2]).dot(x.normal) - 1.5).abs() < 1e-4);
        }
        // Every lane of the moved arm lies on its road, and the road reaches the junction box.
        for l in &y.lanes {
            assert!(point_in_polygon(0.5 * (l.start + l.end), &y.road));
        }
        assert!(y.road.iter().any(|p| point_in_polygon(*p + (Vec2::ZERO - *p).normalize() * 0.01, &b.central)));
        // The other arms' lanes keep their lines (their stop lines follow the moved corners).
        for (p, q) in a.arms.iter().zip(&b.arms).filter(|(p, _)| &p.name != name) {
            for (l0, l1) in p.lanes.iter().zip(&q.lanes) {
                assert!(
                    (l1.end - l0.end).dot(p.normal).abs() < 1e-4 && (l1.start - l0.start).dot(p.normal).abs() < 1e-4
                );
            }
        }
    }

    /// Polygon area (shoelace).
    fn area(poly: &[Vec2]) -> f32 {
        0.5 * (0..poly.len()).map(|i| poly[i].perp_dot(poly[(i + 1) % poly.len()])).sum::<f32>().abs()
    }

    /// The default junction's right corners rounded: the corner's sidewalk is the quarter
    /// annulus (or quarter disc) behind the arc, the ground between the arc and the sharp corner
    /// becomes carriageway, the crosswalks move out by the radius, and a radius of 0 is the sharp
    /// layout itself.
    #[test]
    fn a_rounded_corner_is_a_quarter_annulus_of_sidewalk_and_widens_the_carriageway() {
        let sharp = build_layout(&default_cfg());
        for r in [0.0f32, 1.5, 8.0] {
            let mut cfg = default_cfg();
            for a in &mut cfg.arms {
                a.corner_radius_m = r;
            }
            let l = build_layout(&cfg);
            if r == 0.0 {
                assert_eq!(l, sharp);
                continue;
            }
            assert_eq!(l.corner_sidewalks.len(), 4);
            for (i, w) in l.corner_sidewalks.iter().enumerate() {
                let (a, b) = (&l.arms[i], &l.arms[(i + 1) % 4]);
                let sw = 2.5f32;
                let inner = (r - sw).max(0.0);
                let want = std::f32::consts::FRAC_PI_4 * (r * r - inner * inner);
                assert!((area(w) - want).abs() < 0.01 * want, "r {r} corner {i}: {} against {want}", area(w));
                let curb = corner_curb(a, b, r, 5.0).unwrap();
                let p = corner_curb(a, b, 0.0, 5.0).unwrap()[1];
                let mid = curb[curb.len() / 2];
                // Between the arc and the sharp corner: carriageway now, sidewalk before.
                let q = 0.5 * (mid + p);
                assert!(l.on_carriageway(q) && !sharp.on_carriageway(q), "r {r} corner {i} at {q}");
                // Just behind the arc: raised.
                let behind = mid + (mid - p).normalize() * 0.05;
                assert!(!l.on_carriageway(behind), "r {r} corner {i} at {behind}");
                assert!(point_in_polygon(l.corner_posts[i], w) && !l.on_carriageway(l.corner_posts[i]));
            }
            for (arm, before) in l.arms.iter().zip(&sharp.arms) {
                let moved = (arm.crosswalk[0] - before.crosswalk[0]).dot(arm.dir);
                assert!((moved - r).abs() < 1e-3, "{}: crosswalk moved {moved} for r {r}", arm.name);
            }
        }
    }

    #[test]
    fn t_junction_with_collinear_arms_builds() {
        let mut cfg = default_cfg();
        cfg.arms.retain(|a| a.name != "south");
        let l = build_layout(&cfg);
        assert_eq!(l.arms.len(), 3);
        assert!(l.central.len() >= 6);
        assert!(l.central.iter().all(|p| p.is_finite()));
        assert!(point_in_polygon(Vec2::new(0.0, 1.0), &l.central));
    }
}
