//! One junction of an OpenDRIVE road network (`.xodr`) as a scene.
//!
//! The file is read by the `xodr` crate (OpenDRIVE 1.4–1.9: reference lines, lane sections, the
//! lane graph through junctions, signals). The junction is chosen by its `<junction id>` or as
//! the one nearest a point. What hilo takes from the file:
//! - **arms**: every road that leads into the junction is an arm, straight along its heading
//!   where it meets the junction: its driving lanes that lead into the junction (inbound) and
//!   out of it (outbound), their mean width, the width of its `median` lanes (a raised median)
//!   and of its widest `sidewalk` lane, its name (`road <id>` where the road has none), and its
//!   offset from the junction's centre (`offset_m`: the middle between the two directions' inner
//!   edges, about 12 m out), so its lanes stand where the file draws them
//!   ([`lane_deviations`] measures how near);
//! - **divided roads**: a one-way road into the junction and a one-way road out of it that
//!   leave it side by side (within 25°, the inbound one on the left looking outward, as
//!   right-hand traffic drives) are one arm, the gap between their carriageways its median.
//!   Maps derived from OpenStreetMap (by SUMO's `netconvert`, say) draw every dual carriageway
//!   so;
//! - **mounting structures**: a signal pole at each corner between neighbouring arms that has a
//!   traffic light (a dynamic `<signal>`) nearer to it than to any other corner, with its mast
//!   arm over the junction; at every corner when the file has no traffic light at this junction;
//! - **regions of interest**: the junction box and crosswalks (weight 3) and the approach lanes'
//!   first 60 m (weight 1), as in hilo's default intersection;
//! - **lane graph**: which of the arm's inbound lanes leads, through the junction's connecting
//!   lanes, to which outbound lanes of the other arms (`[[connections]]`, each end read as the
//!   scene's lane nearest the file's; U-turns left out), so traffic drives the movements the
//!   file allows and no others, each along the connecting lane's own centre line (`path`)
//!   where a car's body along it stays on the scene's carriageway (hilo draws the turn where
//!   not, with a note);
//! - **curb radii**: each corner whose right turn the file gives is rounded (`corner_radius_m`)
//!   with the radius, 0 to 30 m in steps of 0.1 m, whose curb stands nearest half a lane from
//!   that turn's centre line (RMS over its points, kept within 0.5 m; the note gives each
//!   radius and its RMS), so the file's right turns fit the scene's carriageway as they fit
//!   the file's;
//! - **signal phases**: the junction's `<controller>`s, in the order of their `sequence` and
//!   then of the file, each switching the lights of the arms whose inbound lanes its signals
//!   govern (controllers over the same arms are one phase), become the scene's `signal_groups`
//!   where each phase is one arm or two facing arms and every inbound arm has one; otherwise
//!   (no controller at the junction, or phases hilo could not run) hilo pairs opposing arms, and
//!   the notes say why. OpenDRIVE carries no timings: the study's intervals run the phases;
//! - **origin**: the junction's centre (the mean of its lanes' centre lines) in the file's
//!   coordinates, and its geo reference as the CRS where the header gives one.
//!
//! What the file does not say is a stated default, listed in [`Imported::notes`] (and by
//! `hilo scene info`): arm length 120 m (the file's roads bend or end elsewhere), crosswalk
//! width 3.5 m, curb height 0.15 m, speed limit 50 km/h, mast arms of up to 8 m over the junction,
//! pole height 7 m, no buildings or trees (OpenDRIVE objects carry no heights hilo could trust;
//! add them to the written scene file). Left out: the roads' curvature and elevation (hilo's arms
//! are straight and flat), turn bays as their own lanes (they count as inbound lanes), and the
//! junction's own road surface (hilo derives the box and its corners from the arms; the turns
//! follow the file's curves over it).
//! `<include>`s are not followed: the one file given is read, with a bound on its size.

use crate::error::RaycastError;
use crate::scene::config::{
    ArmConfig, GroundConfig, MAX_ARM_OFFSET_M, MAX_CONNECTION_POINTS, MAX_CORNER_RADIUS_M, OriginConfig, RoiConfig,
    RoiKind, SceneConfig, SignalPoleConfig,
};
use crate::scene::layout::{Layout, build_layout, point_segment_distance};
use glam::Vec2;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::path::{Path, PathBuf};

/// Which junction of a road network to study: its `<junction id>`, or the one whose centre is
/// nearest `near` (file coordinates, metres) within `radius_m`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JunctionPick {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub id: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub near: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius_m: Option<f64>,
}

impl JunctionPick {
    pub fn id(id: &str) -> Self {
        JunctionPick { id: Some(id.to_owned()), near: None, radius_m: None }
    }
}

/// A junction imported as a scene configuration, and what was assumed.
#[derive(Clone, Debug, PartialEq)]
pub struct Imported {
    pub config: SceneConfig,
    /// The `<junction id>` imported.
    pub junction: String,
    /// Each default used where the file says nothing, and each thing of the file left out.
    pub notes: Vec<String>,
}

/// How a scene file written by [`write_scene`] begins.
const HEADER: &str = "# Imported by `hilo scene import`";

/// The stated defaults (see the module doc).
const ARM_LENGTH_M: f32 = 120.0;
const CROSSWALK_M: f32 = 3.5;
const CURB_M: f32 = 0.15;
const SPEED_KPH: f32 = 50.0;
const POLE_HEIGHT_M: f32 = 7.0;
const MAST_ARM_MAX_M: f32 = 8.0;
const APPROACH_ROI_M: f32 = 60.0;

/// Reads `path` (bounded, includes not followed) and imports the junction `pick` names.
pub fn import_file(path: &Path, pick: &JunctionPick) -> Result<Imported, RaycastError> {
    let bytes = hilo_core::fs::read_bounded(path, hilo_core::fs::limit::ROAD_NETWORK)
        .map_err(|e| hilo_core::fs::FileError::io(path, e))?;
    let xml = String::from_utf8(bytes).map_err(|e| hilo_core::fs::FileError::content(path, e))?;
    import_str(&xml, path, pick)
}

/// Imports the junction `pick` names from the OpenDRIVE text `xml`; `path` names it in errors.
pub fn import_str(xml: &str, path: &Path, pick: &JunctionPick) -> Result<Imported, RaycastError> {
    let err = |field: &str, value: String, reason: String| RaycastError::Invalid {
        path: path.to_path_buf(),
        field: field.to_owned(),
        value,
        reason,
    };
    let (net, ids) = parse_with_ids(xml, path)?;
    let (lanes_of, centres) = junctions(&net);
    let known = || centres.keys().map(|s| s.as_str()).collect::<Vec<_>>().join(", ");
    let junction = pick_junction(pick, &centres).map_err(|reason| {
        err("junction", format!("{pick:?}"), format!("{reason}; the file's junctions with lanes: {}", known()))
    })?;
    let centre = centres[&junction];
    let mut notes = Vec::new();
    let approaches =
        join_divided(approaches(&net, &lanes_of[&junction], Vec2::new(centre[0] as f32, centre[1] as f32)), &mut notes);
    if approaches.len() < 2 {
        return Err(err(
            "junction",
            format!("{junction:?}"),
            format!("{} arm(s) lead into it; a junction to study has two or more", approaches.len()),
        ));
    }
    let c = Vec2::new(centre[0] as f32, centre[1] as f32);
    let mut arms: Vec<ArmConfig> = approaches.iter().map(|a| arm(&net, a, c, &mut notes)).collect();
    arms.sort_by(|a, b| a.heading_deg.rem_euclid(360.0).total_cmp(&b.heading_deg.rem_euclid(360.0)));
    notes.push(format!(
        "{} arms, each straight along its road's heading at the junction, {ARM_LENGTH_M} m long (the file's roads bend or end elsewhere)",
        arms.len()
    ));
    if net.geo_reference().offset.is_some() {
        notes.push("origin in the file's own frame: its header <offset> is not applied".into());
    }
    notes.push(format!(
        "defaults: crosswalks {CROSSWALK_M} m wide, curbs {CURB_M} m high, {SPEED_KPH} km/h; turn bays count as inbound lanes"
    ));
    let stem = path.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned());
    let mut config = SceneConfig {
        name: format!("{stem} junction {junction}"),
        origin: OriginConfig {
            x_m: centre[0],
            y_m: centre[1],
            z_m: 0.0,
            crs: net.geo_reference().proj.clone().filter(|g| !g.trim().is_empty()),
        },
        ground: GroundConfig { z_m: 0.0, half_size_m: ARM_LENGTH_M + 30.0 },
        arms,
        buildings: Vec::new(),
        trees: Vec::new(),
        signal_poles: Vec::new(),
        street_lights: Vec::new(),
        roi: default_rois(),
        meshes: Vec::new(),
        roundabout: None,
        connections: Vec::new(),
        signal_groups: Vec::new(),
    };
    // The arms' geometry, which the lane graph, the signal groups and the poles are read against,
    // with its corners rounded as the file's right turns go round them.
    // The file's ways are read once: rounding moves where lanes end along their arms, not the
    // lanes themselves, so each way matches the same scene lanes on either layout.
    let sharp = build_layout(&config);
    let ways = file_ways(&net, &lanes_of[&junction], &sharp, c);
    let layout = round_corners(&mut config, &sharp, &ways.ways, path, &mut notes);
    config.connections = connections(ways, &layout, &mut notes);
    match controller_groups(&net, &ids, &lanes_of[&junction], &junction, &layout, c) {
        Ok((groups, read)) => {
            notes.push(format!(
                "signal groups from the file's {read}: {} (OpenDRIVE gives no timings: the study's intervals run them)",
                groups.iter().map(|g| format!("[{}]", g.join(", "))).collect::<Vec<_>>().join(" then ")
            ));
            config.signal_groups = groups;
        }
        Err(why) => notes.push(format!("{why}: hilo pairs opposing arms into phases")),
    }
    let written = signals_written(xml);
    if written > net.signals().len() {
        notes.push(format!(
            "{} of the file's {written} signals were skipped: off their road (an `s` past the road's end, as a \
             rounded file can write) or incomplete",
            written - net.signals().len()
        ));
    }
    let lights = traffic_lights(&net, &centres, &junction);
    config.signal_poles = corner_poles(&layout, &lights);
    notes.push(if lights.is_empty() {
        format!(
            "no traffic light at this junction in the file: a signal pole at each of the {} corners",
            config.signal_poles.len()
        )
    } else {
        format!(
            "{} traffic lights in the file: a signal pole at each of the {} corners nearest them",
            lights.len(),
            config.signal_poles.len()
        )
    });
    notes.push(format!(
        "signal poles {POLE_HEIGHT_M} m high with mast arms of up to {MAST_ARM_MAX_M} m over the junction; no buildings or trees (add them to the scene file)"
    ));
    Ok(Imported { config, junction, notes })
}

/// How far one of the file's lanes stands from the scene's: see [`lane_deviations`].
#[derive(Clone, Debug, PartialEq)]
pub struct LaneDeviation {
    /// The lane's road (`<road id>`) in the file.
    pub road: String,
    /// Whether it leads into the junction (else out of it).
    pub into: bool,
    /// The largest lateral distance (m) over the samples from [`FIDELITY_FROM_M`] out to each
    /// reach asked for.
    pub worst_m: Vec<f32>,
}

/// Samples nearer the junction's centre than this lie in its box, where every arm's lanes meet.
pub const FIDELITY_FROM_M: f32 = 10.0;

/// How far the lanes of `layout` (a scene imported from the OpenDRIVE text `xml`, junction
/// `junction`, its origin at the file's `origin`) stand from the file's own: for each of the
/// file's driving lanes that leads into or out of the junction, the largest lateral distance
/// from a sample of its centre line (the parser's polyline) to the nearest lane of the scene
/// that runs the same way on the arm the sample lies along, over the samples from
/// [`FIDELITY_FROM_M`] out to each of `reaches_m` from the junction's centre.
pub fn lane_deviations(
    xml: &str,
    path: &Path,
    junction: &str,
    layout: &crate::scene::layout::Layout,
    origin: Vec2,
    reaches_m: &[f32],
) -> Result<Vec<LaneDeviation>, RaycastError> {
    let net = parse(xml, path)?;
    let inside = junctions(&net).0.remove(junction).unwrap_or_default();
    let mut out = Vec::new();
    for (l, road, _, into) in approach_lanes(&net, &inside) {
        let out_of = !into;
        let mut worst_m = vec![0.0f32; reaches_m.len()];
        for p in l.center.points() {
            let q = Vec2::new(p.x, p.y) - origin;
            // No lane of that kind on the nearest arm: as far from the file as can be.
            let d = nearest_lane(layout, q, out_of, true).map_or(f32::INFINITY, |(_, _, d)| d);
            widen_within_reach(&mut worst_m, reaches_m, q, d);
        }
        out.push(LaneDeviation { road: road.od_id().to_owned(), into, worst_m });
    }
    Ok(out)
}

/// Which edge of an approach's carriageway an [`EdgeDeviation`] measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RoadEdge {
    /// The curb side: the outer border of the outermost driving lane.
    Curb,
    /// The median side of a divided arm: the inner border of the innermost driving lane.
    Median,
}

/// How far one road edge of the file stands from the scene's: see [`edge_deviations`].
#[derive(Clone, Debug, PartialEq)]
pub struct EdgeDeviation {
    /// The road (`<road id>`) in the file whose lanes the edge borders.
    pub road: String,
    /// Whether its lanes lead into the junction (else out of it).
    pub into: bool,
    pub edge: RoadEdge,
    /// The largest lateral distance (m) over the samples from [`FIDELITY_FROM_M`] out to each
    /// reach asked for.
    pub worst_m: Vec<f32>,
}

/// How far the road edges of `layout` (imported as for [`lane_deviations`]) stand from the
/// file's: for each road leading into or out of the junction, the border of its driving lanes
/// on the curb side (the outermost lane's outer border, centre line ± half the lane's width at
/// each of the parser's samples, across its tangent) against the scene's road edge on that side
/// (`edge_in_m`, `edge_out_m`), and on a divided arm the border on the median side against the
/// median's edge; over the samples from [`FIDELITY_FROM_M`] out to each of `reaches_m`. The
/// edge is the lanes' border, where the scene's curb stands; the file's non-driving lanes
/// beyond it (sidewalks) are modelled by their width, not measured here.
pub fn edge_deviations(
    xml: &str,
    path: &Path,
    junction: &str,
    layout: &Layout,
    origin: Vec2,
    reaches_m: &[f32],
) -> Result<Vec<EdgeDeviation>, RaycastError> {
    let net = parse(xml, path)?;
    let inside = junctions(&net).0.remove(junction).unwrap_or_default();
    // Per road and way: per lane, its border samples (position, outer and inner lateral offset
    // on the arm the sample lies along, that arm's index).
    type Borders = Vec<(Vec2, f32, f32, usize)>;
    let mut groups: BTreeMap<(String, bool), Vec<Borders>> = BTreeMap::new();
    for (l, road, _, into) in approach_lanes(&net, &inside) {
        let pts = l.center.points();
        let mut samples = Vec::new();
        for (i, (p, t)) in pts.iter().zip(l.center.tangents()).enumerate() {
            let q = Vec2::new(p.x, p.y) - origin;
            let Some((a, arm)) = nearest_arm(layout, q) else { continue };
            let half = 0.5 * l.widths.get(i).copied().unwrap_or(l.width);
            let across = Vec2::new(-t.y, t.x) * half;
            let (s1, s2) = ((q + across).dot(arm.normal), (q - across).dot(arm.normal));
            // Inbound lanes lie on the normal's side of the arm, outbound ones on the other.
            let (outer, inner) = if into { (s1.max(s2), s1.min(s2)) } else { (s1.min(s2), s1.max(s2)) };
            samples.push((q, outer, inner, a));
        }
        groups.entry((road.od_id().to_owned(), into)).or_default().push(samples);
    }
    let mut out = Vec::new();
    for ((road, into), lanes) in groups {
        let sign = if into { 1.0 } else { -1.0 };
        let mean = |s: &Borders, k: fn(&(Vec2, f32, f32, usize)) -> f32| {
            s.iter().map(k).sum::<f32>() / s.len().max(1) as f32 * sign
        };
        let pick = |k: fn(&(Vec2, f32, f32, usize)) -> f32, outermost: bool| {
            lanes.iter().filter(|s| !s.is_empty()).max_by(|a, b| {
                let o = mean(a, k).total_cmp(&mean(b, k));
                if outermost { o } else { o.reverse() }
            })
        };
        let worst = |samples: &Borders, edge: RoadEdge| {
            let mut worst_m = vec![0.0f32; reaches_m.len()];
            for &(q, outer, inner, a) in samples {
                let arm = &layout.arms[a];
                let (s, scene) = match (edge, into) {
                    (RoadEdge::Curb, true) => (outer, arm.edge_in_m),
                    (RoadEdge::Curb, false) => (outer, arm.edge_out_m),
                    (RoadEdge::Median, _) => (inner, arm.offset_m + sign * arm.median_half_width_m),
                };
                widen_within_reach(&mut worst_m, reaches_m, q, (s - scene).abs());
            }
            worst_m
        };
        if let Some(s) = pick(|x| x.1, true) {
            out.push(EdgeDeviation {
                road: road.clone(),
                into,
                edge: RoadEdge::Curb,
                worst_m: worst(s, RoadEdge::Curb),
            });
        }
        let divided = lanes.iter().flatten().any(|x| layout.arms[x.3].median_half_width_m > 0.0);
        if let Some(s) = pick(|x| x.2, false).filter(|_| divided) {
            out.push(EdgeDeviation { road, into, edge: RoadEdge::Median, worst_m: worst(s, RoadEdge::Median) });
        }
    }
    Ok(out)
}

/// Raises each reach's largest distance in `worst_m` to `d`, a sample at `q` from the
/// junction's centre, where the sample lies from [`FIDELITY_FROM_M`] out to that reach.
fn widen_within_reach(worst_m: &mut [f32], reaches_m: &[f32], q: Vec2, d: f32) {
    for (w, &reach) in worst_m.iter_mut().zip(reaches_m) {
        if (FIDELITY_FROM_M..=reach).contains(&q.length()) {
            *w = w.max(d);
        }
    }
}

/// The arm of `layout` whose direction is nearest that of `q` from the junction's centre.
fn nearest_arm(layout: &Layout, q: Vec2) -> Option<(usize, &crate::scene::layout::ArmLayout)> {
    let u = q.normalize_or_zero();
    layout.arms.iter().enumerate().min_by(|a, b| (u - a.1.dir).length().total_cmp(&(u - b.1.dir).length()))
}

/// Reads the OpenDRIVE text `xml` (its `<include>`s refused); `path` names it in errors.
fn parse(xml: &str, path: &Path) -> Result<xodr::RoadNetwork, RaycastError> {
    Ok(parse_with_ids(xml, path)?.0)
}

/// [`parse`], with the file's own ids of what it read (the junctions' controllers among them).
fn parse_with_ids(xml: &str, path: &Path) -> Result<(xodr::RoadNetwork, xodr::Provenance), RaycastError> {
    xodr::load_str_with(xml, |name| Err(format!("{name}: hilo reads one file; includes are not followed"))).map_err(
        |e| RaycastError::Invalid {
            path: path.to_path_buf(),
            field: "OpenDRIVE".into(),
            value: String::new(),
            reason: e.to_string(),
        },
    )
}

/// The driving lanes outside any junction that lead into a lane of `inside` or out of one:
/// each with its road, its lane section's index and whether it leads in.
fn approach_lanes<'a>(
    net: &'a xodr::RoadNetwork,
    inside: &'a HashSet<xodr::LaneId>,
) -> impl Iterator<Item = (&'a xodr::Lane, &'a xodr::Road, usize, bool)> + 'a {
    net.lanes().iter().filter(|l| l.kind == xodr::LaneType::Driving).filter_map(move |l| {
        let (road, section) = road_of(net, l)?;
        let into = l.successors.iter().any(|s| inside.contains(s));
        let out_of = l.predecessors.iter().any(|p| inside.contains(p));
        (road.junction().is_none() && (into || out_of)).then_some((l, road, section, into))
    })
}

/// A lane's road and its lane section's index.
fn road_of<'a>(net: &'a xodr::RoadNetwork, l: &xodr::Lane) -> Option<(&'a xodr::Road, usize)> {
    net.road_lane(l.id).and_then(|rl| net.road(rl.road).map(|r| (r, rl.section)))
}

/// Every junction's lanes, and the centre of those with driving lanes (the mean of their
/// centre-line points), by `<junction id>`.
type Junctions = (BTreeMap<String, HashSet<xodr::LaneId>>, BTreeMap<String, [f64; 2]>);

fn junctions(net: &xodr::RoadNetwork) -> Junctions {
    let mut lanes_of: BTreeMap<String, HashSet<xodr::LaneId>> = BTreeMap::new();
    let mut sums: BTreeMap<String, (f64, f64, usize)> = BTreeMap::new();
    for l in net.lanes() {
        let Some(j) = road_of(net, l).and_then(|(r, _)| r.junction().map(str::to_owned)) else { continue };
        lanes_of.entry(j.clone()).or_default().insert(l.id);
        if l.kind == xodr::LaneType::Driving {
            let c = sums.entry(j).or_insert((0.0, 0.0, 0));
            for p in l.center.points() {
                *c = (c.0 + f64::from(p.x), c.1 + f64::from(p.y), c.2 + 1);
            }
        }
    }
    let centres =
        sums.into_iter().filter(|(_, c)| c.2 > 0).map(|(j, c)| (j, [c.0 / c.2 as f64, c.1 / c.2 as f64])).collect();
    (lanes_of, centres)
}

/// The roads outside the junction with driving lanes into it (`inside`'s lanes) or out of it,
/// by `<road id>`; `c` is the junction's centre.
fn approaches(net: &xodr::RoadNetwork, inside: &HashSet<xodr::LaneId>, c: Vec2) -> BTreeMap<String, Approach> {
    let mut out: BTreeMap<String, Approach> = BTreeMap::new();
    for (l, road, section, into) in approach_lanes(net, inside) {
        let a = out.entry(road.od_id().to_owned()).or_insert_with(|| Approach {
            name: if road.name().is_empty() { format!("road {}", road.od_id()) } else { road.name().to_owned() },
            roads: vec![(road.id(), section)],
            lanes_in: 0,
            lanes_out: 0,
            widths: Vec::new(),
            out: Vec::new(),
            across: Vec::new(),
            median_m: None,
        });
        if into {
            a.lanes_in += 1;
        } else {
            a.lanes_out += 1;
        }
        a.widths.push(l.width);
        let (near, dir, mid) = outward(&l.center, c);
        a.out.push((near, dir));
        a.across.push((into, mid, l.width));
    }
    out
}

/// The widest angle between the two carriageways of one divided arm, in degrees.
const DIVIDED_MAX_DEG: f32 = 25.0;

/// Joins each one-way road into the junction to the one-way road out of it that leaves beside
/// it (see the module doc), nearest in direction first; the gap between the two carriageways'
/// driving lanes becomes the arm's median. Roads that pair with none stay arms of their own.
fn join_divided(approaches: BTreeMap<String, Approach>, notes: &mut Vec<String>) -> Vec<Approach> {
    let centre = |a: &Approach| a.out.iter().fold(Vec2::ZERO, |s, (p, _)| s + *p) / a.out.len().max(1) as f32;
    let width = |a: &Approach| a.widths.iter().sum::<f32>();
    let mut all: Vec<Option<Approach>> = approaches.into_values().map(Some).collect();
    let mut pairs = Vec::new();
    for (i, a) in all.iter().enumerate() {
        let Some(a) = a.as_ref().filter(|a| a.lanes_in > 0 && a.lanes_out == 0) else { continue };
        for (j, b) in all.iter().enumerate() {
            let Some(b) = b.as_ref().filter(|b| b.lanes_out > 0 && b.lanes_in == 0) else { continue };
            let (da, db) = (a.direction(), b.direction());
            let angle = da.angle_to(db).abs().to_degrees();
            let d = (da + db).normalize_or_zero();
            // The inbound carriageway's offset to the left of the outbound one, across the arm.
            let across = (centre(a) - centre(b)).dot(d.perp());
            let median = across - 0.5 * (width(a) + width(b));
            if angle <= DIVIDED_MAX_DEG && median >= 0.0 {
                pairs.push((angle, i, j, median));
            }
        }
    }
    pairs.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let mut joined = Vec::new();
    for (_, i, j, median) in pairs {
        if all[i].is_none() || all[j].is_none() {
            continue;
        }
        let (Some(mut a), Some(b)) = (all[i].take(), all[j].take()) else { continue };
        notes.push(format!(
            "{} (in) and {} (out): one divided arm, the {median:.2} m between their carriageways its median",
            a.name, b.name
        ));
        a.name = format!("{} / {}", a.name, b.name);
        a.roads.extend(b.roads);
        a.lanes_out = b.lanes_out;
        a.widths.extend(b.widths);
        a.out.extend(b.out);
        a.across.extend(b.across);
        a.median_m = Some(median);
        joined.push(a);
    }
    joined.extend(all.into_iter().flatten());
    joined
}

/// An approach as an arm: its lanes, their mean width, and its section's medians and sidewalks
/// (a note where it has no sidewalk).
fn arm(net: &xodr::RoadNetwork, a: &Approach, c: Vec2, notes: &mut Vec<String>) -> ArmConfig {
    let of = |kind: xodr::LaneType, road: xodr::RoadId, section: usize| {
        net.lanes()
            .iter()
            .filter(move |l| road_of(net, l).is_some_and(|(r, s)| r.id() == road && s == section))
            .filter(move |l| l.kind == kind)
            .map(|l| l.width)
    };
    let widest = |kind| a.roads.iter().flat_map(|&(r, s)| of(kind, r, s)).fold(0.0f32, f32::max);
    let sidewalk = widest(xodr::LaneType::Sidewalk);
    // A divided arm's median is the gap between its carriageways; a road's own median lanes.
    let median: f32 =
        a.median_m.unwrap_or_else(|| a.roads.iter().flat_map(|&(r, s)| of(xodr::LaneType::Median, r, s)).sum());
    let dir = a.direction();
    if sidewalk == 0.0 {
        notes.push(format!("{}: no sidewalk lane in the file; none modelled", a.name));
    }
    // A parking lane, the widest of the section's, within what a scene file accepts.
    let parking = widest(xodr::LaneType::Parking);
    let parking_lane_width_m = if parking > 0.0 { round(parking.clamp(1.8, 3.0), 0.01) } else { 0.0 };
    if parking > 0.0 && parking_lane_width_m != round(parking, 0.01) {
        notes.push(format!(
            "{}: parking lane {parking:.2} m wide in the file; modelled {parking_lane_width_m} m wide",
            a.name
        ));
    }
    let median_width_m = round(median, 0.01);
    let offset_m = round(centre_line_offset(a, dir, c, median_width_m), 0.01);
    if offset_m.abs() > MAX_ARM_OFFSET_M {
        notes.push(format!(
            "{}: its lanes lie {offset_m} m from the junction's centre; modelled through the centre",
            a.name
        ));
    }
    ArmConfig {
        name: a.name.clone(),
        heading_deg: round(dir.y.atan2(dir.x).to_degrees(), 0.1),
        length_m: ARM_LENGTH_M,
        lanes_in: a.lanes_in,
        lanes_out: a.lanes_out,
        lane_width_m: round(a.widths.iter().sum::<f32>() / a.widths.len().max(1) as f32, 0.01),
        left_turn_lanes: 0,
        left_turn_bay_length_m: 0.0,
        median_width_m,
        offset_m: if offset_m.abs() > MAX_ARM_OFFSET_M { 0.0 } else { offset_m },
        parking_lane_width_m,
        sidewalk_width_m: round(sidewalk, 0.01),
        curb_height_m: CURB_M,
        crosswalk_width_m: CROSSWALK_M,
        speed_limit_kph: SPEED_KPH,
        corner_radius_m: 0.0,
    }
}

/// Gives each corner of `config` the curb radius its file's right turn fits
/// ([`fitted_corner_radii`], read on the sharp-cornered `sharp` layout), keeps those the scene
/// can hold (crosswalks on the arms' inner halves), and returns the layout with them.
fn round_corners(
    config: &mut SceneConfig,
    sharp: &Layout,
    ways: &[Way],
    path: &Path,
    notes: &mut Vec<String>,
) -> Layout {
    let radii = fitted_corner_radii(sharp, ways);
    let mut fitted = Vec::new();
    for (arm, r) in sharp.arms.iter().zip(&radii) {
        // A best fit of 0 leaves the corner sharp, as it was.
        if let (Some((r, rms)), Some(cfg)) =
            (r.filter(|f| f.0 > 0.0), config.arms.iter_mut().find(|a| a.name == arm.name))
        {
            cfg.corner_radius_m = r;
            fitted.push(format!("{r:.1} m (RMS {rms:.2} m)"));
        }
    }
    if fitted.is_empty() {
        notes.push("corners sharp: the file has no right turn a curb's arc fits".into());
        return sharp.clone();
    }
    let layout = build_layout(config);
    if let Err(e) = config.validate(path).and_then(|()| super::plausible(config, &layout, path)) {
        for a in &mut config.arms {
            a.corner_radius_m = 0.0;
        }
        notes.push(format!("corners sharp: the curb radii the file's right turns fit do not fit the scene ({e})"));
        return sharp.clone();
    }
    notes.push(format!(
        "{} of {} corners rounded as the file's right turns go round them, each curb half a lane from its turn's \
         centre line: radii {}",
        fitted.len(),
        radii.len(),
        fitted.join(", ")
    ));
    layout
}

/// The junction's lane graph in the scene's terms, from the file's ways through it
/// ([`file_ways`]: each driving lane into the junction, through its connecting lanes, to each
/// driving lane out of it, each end read as the scene's lane nearest it). Each connection keeps
/// the connecting lanes' centre line as its `path` where a car's body along it stays on the
/// scene's carriageway ([`drivable_path`]); where several of the file's ways join the same two
/// scene lanes, the first the file lists. U-turns are left out, with a note.
fn connections(
    FileWays { ways, u_turns, unread }: FileWays,
    layout: &Layout,
    notes: &mut Vec<String>,
) -> Vec<crate::scene::config::ConnectionConfig> {
    let mut out: BTreeMap<(String, u32, String, u32), Vec<[f32; 2]>> = BTreeMap::new();
    let mut drawn_by_hilo = 0;
    for (from, to, way) in ways {
        let key = (layout.arms[from.0].name.clone(), from.1 as u32, layout.arms[to.0].name.clone(), to.1 as u32);
        let path = if drivable_path(layout, &way) {
            way.iter().map(|p| [(p.x * 100.0).round() / 100.0 + 0.0, (p.y * 100.0).round() / 100.0 + 0.0]).collect()
        } else {
            drawn_by_hilo += 1;
            Vec::new()
        };
        out.insert(key, path);
    }
    notes.push(if out.is_empty() {
        "no connection through the junction read from the file's lane graph: hilo's own rules connect its lanes"
            .to_owned()
    } else if drawn_by_hilo == 0 {
        format!("{} connections through the junction from the file's lane graph, each along its own curve", out.len())
    } else {
        format!(
            "{} connections through the junction from the file's lane graph; {drawn_by_hilo} of their curves would \
             take a car off the scene's carriageway, and hilo draws those turns",
            out.len()
        )
    });
    if u_turns > 0 {
        notes.push(format!("{u_turns} U-turn connection(s) of the file left out"));
    }
    if unread > 0 {
        notes.push(format!("{unread} lane(s) of the file's connections match no lane of the scene; left out"));
    }
    out.into_iter()
        .map(|((from, from_lane, to, to_lane), path)| crate::scene::config::ConnectionConfig {
            from,
            from_lane,
            to,
            to_lane,
            path,
        })
        .collect()
}

/// One way through the junction read as the scene's lanes: an inbound lane `(arm, lane)`, an
/// outbound one (arms by index into the layout, lanes counted from the arm's centre line), and
/// the file's connecting lanes' centre line joined between them, in scene coordinates.
type Way = ((usize, usize), (usize, usize), Vec<Vec2>);

/// The file's ways through the junction, the first for each pair of scene lanes; and the
/// U-turns and the lanes that match no scene lane, left out.
struct FileWays {
    ways: Vec<Way>,
    u_turns: usize,
    unread: usize,
}

fn file_ways(net: &xodr::RoadNetwork, inside: &HashSet<xodr::LaneId>, layout: &Layout, c: Vec2) -> FileWays {
    let mut found = FileWays { ways: Vec::new(), u_turns: 0, unread: 0 };
    let mut seen = HashSet::new();
    for (l, _, _, into) in approach_lanes(net, inside) {
        if !into {
            continue;
        }
        let Some(from) = scene_lane(layout, &l.center, c, false) else {
            found.unread += 1;
            continue;
        };
        for (exit, way) in exits(net, inside, l) {
            let Some(to) = scene_lane(layout, &exit.center, c, true) else {
                found.unread += 1;
                continue;
            };
            if from.0 == to.0 {
                found.u_turns += 1;
                continue;
            }
            if seen.insert((from, to)) {
                found.ways.push((from, to, thinned(way.into_iter().map(|p| p - c).collect(), MAX_CONNECTION_POINTS)));
            }
        }
    }
    found
}

/// The largest RMS distance, m, between a right turn's centre line and half a lane off the
/// fitted curb at which the fit is kept.
const CURB_FIT_RMS_M: f32 = 0.5;

/// The curb radius of each corner that the file's right turn round it fits best, by the
/// layout's arm index `i` (the corner between arm `i`'s inbound side and the next arm's
/// outbound side): the radius, from 0 (sharp) to [`MAX_CORNER_RADIUS_M`] in steps of 0.1 m,
/// whose curb ([`corner_curb`]) stands nearest half a lane (and the arm's parking lane) from
/// the turn's centre line, over the line's points, RMS. The turn read is the one from the
/// outermost inbound lane to the outermost outbound lane. `None` where the file has no right
/// turn there, or none within [`CURB_FIT_RMS_M`] of any radius; else the radius and its RMS.
fn fitted_corner_radii(layout: &Layout, ways: &[Way]) -> Vec<Option<(f32, f32)>> {
    let n = layout.arms.len();
    (0..n)
        .map(|i| {
            let j = (i + 1) % n;
            let (_, _, way) =
                ways.iter().filter(|(from, to, _)| from.0 == i && to.0 == j).max_by_key(|w| (w.0.1, w.1.1))?;
            let (a, b) = (&layout.arms[i], &layout.arms[j]);
            let off = 0.5 * a.lanes.first().map_or(0.0, |l| l.width_m) + a.parking_lane_m;
            let rms = |r: f32| {
                let curb = crate::scene::layout::corner_curb(a, b, r, 200.0)?;
                let sq: f32 = way.iter().map(|&p| (distance_to_polyline(p, &curb) - off).powi(2)).sum();
                Some((sq / way.len().max(1) as f32).sqrt())
            };
            let steps = (MAX_CORNER_RADIUS_M * 10.0).round() as usize;
            let (r, e) = (0..=steps)
                .filter_map(|k| {
                    let r = k as f32 / 10.0;
                    rms(r).map(|e| (r, e))
                })
                .min_by(|x, y| x.1.total_cmp(&y.1))?;
            (e <= CURB_FIT_RMS_M).then_some((r, e))
        })
        .collect()
}

/// The distance from `p` to the polyline `line`.
fn distance_to_polyline(p: Vec2, line: &[Vec2]) -> f32 {
    line.windows(2).map(|w| point_segment_distance(p, w[0], w[1])).fold(f32::INFINITY, f32::min)
}

/// `pts` with at most `most` points (at least 2): every k-th, and the last.
fn thinned(pts: Vec<Vec2>, most: usize) -> Vec<Vec2> {
    if pts.len() <= most.max(2) {
        return pts;
    }
    let k = pts.len().div_ceil(most.max(2) - 1);
    let mut out: Vec<Vec2> = pts.iter().step_by(k).copied().collect();
    if let (Some(&last), Some(&end)) = (out.last(), pts.last())
        && last != end
    {
        out.push(end);
    }
    out
}

/// Whether a car driving the centre line `way` (scene coordinates) keeps its body on the
/// scene's carriageway ([`Layout::car_on_carriageway`]) at every segment's middle and at every
/// point. The scene's arms are straight where the file's roads
/// bend, and its corners its own, so a file's curve can cut one.
fn drivable_path(layout: &Layout, way: &[Vec2]) -> bool {
    way.len() >= 2
        && way.windows(2).all(|w| {
            let dir = (w[1] - w[0]).normalize_or_zero();
            [0.5 * (w[0] + w[1]), w[1]].iter().all(|&p| layout.car_on_carriageway(p, dir))
        })
}

/// The signal groups the junction's controllers give, with what was read: each controller of
/// the junction (its `<controller>` list), in the order of their `sequence` and then of the
/// file, switches the lights of the arms whose inbound lanes its signals govern; controllers
/// over the same arms are one group, and one over no inbound lane (pedestrian lights) runs no
/// vehicle phase. `Err` says why the file gives no phases hilo can run: no controller, none over
/// an inbound lane, groups that share an arm, leave an inbound arm without a light, or put arms
/// whose traffic crosses on one green.
fn controller_groups(
    net: &xodr::RoadNetwork,
    ids: &xodr::Provenance,
    inside: &HashSet<xodr::LaneId>,
    junction: &str,
    layout: &Layout,
    c: Vec2,
) -> Result<(Vec<Vec<String>>, String), String> {
    let mut mine: Vec<(Option<u32>, usize, &xodr::ControllerProvenance)> = ids
        .controllers
        .iter()
        .enumerate()
        .filter_map(|(k, p)| p.junctions.iter().find(|j| j.junction_id == junction).map(|j| (j.sequence, k, p)))
        .collect();
    if mine.is_empty() {
        return Err("the file lists no signal controller for this junction".into());
    }
    mine.sort_by_key(|&(seq, k, _)| (seq.unwrap_or(u32::MAX), k));
    let mut groups: Vec<BTreeSet<usize>> = Vec::new();
    let mut skipped = 0;
    for &(_, _, p) in &mine {
        let arms: BTreeSet<usize> = net
            .controller(p.controller)
            .into_iter()
            .flat_map(|ctl| ctl.signals.iter())
            .filter_map(|control| net.signal(control.signal))
            .flat_map(|signal| signal.lanes.iter())
            .filter_map(|&id| net.lane(id))
            .filter(|l| l.kind == xodr::LaneType::Driving && l.successors.iter().any(|s| inside.contains(s)))
            .filter_map(|l| scene_lane(layout, &l.center, c, false).map(|(arm, _)| arm))
            .collect();
        // A controller of lights over no driving lane into the junction (pedestrian lights,
        // valid for lane 0 only) runs no vehicle phase.
        if arms.is_empty() {
            skipped += 1;
        } else if !groups.contains(&arms) {
            groups.push(arms);
        }
    }
    if groups.is_empty() {
        return Err(format!("the file's {} controller(s) of the junction govern no inbound lane", mine.len()));
    }
    let read = match skipped {
        0 => format!("{} controller(s) of the junction", mine.len()),
        k => format!("{} controller(s) of the junction ({k} over no inbound lane, as pedestrian lights)", mine.len()),
    };
    let mut served = BTreeSet::new();
    for g in &groups {
        let names: Vec<&str> = g.iter().map(|&a| layout.arms[a].name.as_str()).collect();
        if g.len() > 2 {
            return Err(format!("{read} switch the lights of {} arms at once ({})", g.len(), names.join(", ")));
        }
        if let [a, b] = g.iter().copied().collect::<Vec<_>>()[..]
            && layout.arms[a].dir.dot(layout.arms[b].dir) >= -(20f32.to_radians().cos())
        {
            return Err(format!("{read} give one green to arms whose traffic crosses ({})", names.join(", ")));
        }
        if let Some(&a) = g.iter().find(|a| !served.insert(**a)) {
            return Err(format!("{read} give arm {:?} more than one phase", layout.arms[a].name));
        }
    }
    if let Some(a) = layout.arms.iter().enumerate().find(|(i, a)| {
        a.lanes.iter().any(|l| l.kind != crate::scene::layout::LaneKind::Outbound) && !served.contains(i)
    }) {
        return Err(format!("{read} leave arm {:?}'s inbound lanes without a light", a.1.name));
    }
    let names = groups.iter().map(|g| g.iter().map(|&a| layout.arms[a].name.clone()).collect()).collect();
    Ok((names, read))
}

/// The driving lanes outside the junction that lane `l` leads to through the junction's lanes
/// (`inside`), in the order the file lists them, each with the way there: the centre lines of
/// the connecting lanes driven, joined in the direction of travel (file coordinates).
fn exits<'a>(
    net: &'a xodr::RoadNetwork,
    inside: &HashSet<xodr::LaneId>,
    l: &xodr::Lane,
) -> Vec<(&'a xodr::Lane, Vec<Vec2>)> {
    let mut seen: HashSet<xodr::LaneId> = HashSet::new();
    let mut stack: Vec<(xodr::LaneId, Vec<Vec2>)> =
        l.successors.iter().copied().filter(|s| inside.contains(s)).map(|s| (s, Vec::new())).collect();
    let mut out: Vec<(&xodr::Lane, Vec<Vec2>)> = Vec::new();
    while let Some((id, before)) = stack.pop() {
        if !seen.insert(id) {
            continue;
        }
        let Some(lane) = net.lane(id) else { continue };
        let mut way = before;
        way.extend(travel_points(lane, way.last().copied()));
        for &next in &lane.successors {
            if inside.contains(&next) {
                stack.push((next, way.clone()));
            } else if let Some(o) = net.lane(next).filter(|o| o.kind == xodr::LaneType::Driving)
                && !out.iter().any(|x| x.0.id == o.id)
            {
                out.push((o, way.clone()));
            }
        }
    }
    out
}

/// A lane's centre line in the direction of travel; a lane driven both ways runs from its end
/// nearest `from` (the way so far), or as drawn.
fn travel_points(lane: &xodr::Lane, from: Option<Vec2>) -> Vec<Vec2> {
    let mut pts: Vec<Vec2> = lane.center.points().iter().map(|p| Vec2::new(p.x, p.y)).collect();
    let backward = match (lane.direction, from, pts.first(), pts.last()) {
        (xodr::Direction::Backward, ..) => true,
        (xodr::Direction::Both, Some(f), Some(&a), Some(&b)) => f.distance(b) < f.distance(a),
        _ => false,
    };
    if backward {
        pts.reverse();
    }
    pts
}

/// The scene's lane nearest a lane of the file (its centre line `center`; `c` the junction's
/// centre, the scene's origin): on the arm whose direction is nearest the lane's point about
/// 12 m beyond the junction, the lane running the same way (`outbound` or inbound) whose centre
/// line stands nearest that point across the arm. The arm's index into the layout and the
/// lane's among its kind (0 the innermost).
fn scene_lane(
    layout: &crate::scene::layout::Layout,
    center: &xodr::Polyline,
    c: Vec2,
    outbound: bool,
) -> Option<(usize, usize)> {
    let (i, k, _) = nearest_lane(layout, outward(center, c).2 - c, outbound, false)?;
    Some((i, k))
}

/// The scene lane nearest the point `q` (relative to the junction's centre): the arm whose
/// direction is nearest `q`'s, then among its outbound (or inbound) lanes, turn bays counted
/// when `bays`, the one whose centre line lies least far across the arm from `q`. Returns the
/// arm, the lane's index among the lanes counted, and that lateral distance.
fn nearest_lane(
    layout: &crate::scene::layout::Layout,
    q: Vec2,
    outbound: bool,
    bays: bool,
) -> Option<(usize, usize, f32)> {
    use crate::scene::layout::LaneKind;
    let (i, arm) = nearest_arm(layout, q)?;
    let (k, d) = arm
        .lanes
        .iter()
        .filter(|ln| (ln.kind == LaneKind::Outbound) == outbound && (bays || ln.kind != LaneKind::LeftTurnBay))
        .map(|ln| (q - ln.end).dot(arm.normal).abs())
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    Some((i, k, d))
}

/// The default intersection's regions of interest: the junction box and crosswalks, and the
/// approaches' first metres.
fn default_rois() -> Vec<RoiConfig> {
    vec![
        RoiConfig {
            name: "central conflict zone".into(),
            weight: 3.0,
            kind: RoiKind::Central,
            polygon: None,
            length_m: None,
        },
        RoiConfig {
            name: "queue lanes".into(),
            weight: 1.0,
            kind: RoiKind::Approaches,
            polygon: None,
            length_m: Some(APPROACH_ROI_M),
        },
    ]
}

/// The traffic lights of `junction`, relative to its centre: dynamic signals within 60 m of it
/// and no nearer any other junction's centre.
fn traffic_lights(net: &xodr::RoadNetwork, centres: &BTreeMap<String, [f64; 2]>, junction: &str) -> Vec<Vec2> {
    let dist = |s: &xodr::Signal, c: &[f64; 2]| (f64::from(s.position.x) - c[0]).hypot(f64::from(s.position.y) - c[1]);
    let mine = centres[junction];
    net.signals()
        .iter()
        .filter(|s| s.dynamic && dist(s, &mine) < 60.0 && centres.values().all(|o| dist(s, &mine) <= dist(s, o)))
        .map(|s| Vec2::new((f64::from(s.position.x) - mine[0]) as f32, (f64::from(s.position.y) - mine[1]) as f32))
        .collect()
}

/// How many `<signal>` elements the text holds (not `<signals>` or `<signalReference>`).
fn signals_written(xml: &str) -> usize {
    xml.match_indices("<signal")
        .filter(|(i, m)| xml[i + m.len()..].starts_with(|c: char| c.is_whitespace() || c == '>' || c == '/'))
        .count()
}

/// An approach being gathered: its roads (two for a divided arm) and the lane section of each
/// that meets the junction, its driving lanes by direction, their widths, each lane's end
/// nearer the junction and outward direction, and a divided arm's median.
struct Approach {
    name: String,
    roads: Vec<(xodr::RoadId, usize)>,
    lanes_in: u32,
    lanes_out: u32,
    widths: Vec<f32>,
    out: Vec<(Vec2, Vec2)>,
    /// Each lane's direction (into the junction or not), a point of its centre line about 12 m
    /// from the junction, and its width: where the file puts it across the arm.
    across: Vec<(bool, Vec2, f32)>,
    median_m: Option<f32>,
}

impl Approach {
    /// The mean outward direction of its lanes.
    fn direction(&self) -> Vec2 {
        self.out.iter().fold(Vec2::ZERO, |s, (_, d)| s + *d).normalize_or_zero()
    }
}

/// How far to the left of the line through the junction's centre `c` along `dir` the file puts
/// the arm's centre line: the middle between its two directions' inner edges (each lane's centre
/// about 12 m out, less half its width), or, for a one-way arm, half the median beside its inner
/// edge.
fn centre_line_offset(a: &Approach, dir: Vec2, c: Vec2, median_m: f32) -> f32 {
    let normal = dir.perp();
    let inner = |into: bool| {
        let edges = a.across.iter().filter(move |l| l.0 == into).map(|&(_, p, w)| {
            let s = (p - c).dot(normal);
            if into { s - 0.5 * w } else { s + 0.5 * w }
        });
        if into { edges.fold(f32::INFINITY, f32::min) } else { edges.fold(f32::NEG_INFINITY, f32::max) }
    };
    let (inner_in, inner_out) = (inner(true), inner(false));
    match (inner_in.is_finite(), inner_out.is_finite()) {
        (true, true) => 0.5 * (inner_in + inner_out),
        (true, false) => inner_in - 0.5 * median_m,
        (false, true) => inner_out + 0.5 * median_m,
        (false, false) => 0.0,
    }
}

/// `v` to the nearest multiple of `step`, a unit fraction such as 0.01 (never -0, which TOML
/// would print as `-0.0`). The count of steps is divided by the steps per unit, an exact
/// integer, so the result is the float nearest the decimal and a scene file reads `3.2`, not
/// the `3.1999998` that multiplying by an inexact `0.01` gives.
fn round(v: f32, step: f32) -> f32 {
    let per_unit = (1.0 / step).round();
    (v * per_unit).round() / per_unit + 0.0
}

/// The junction `pick` names among `centres`.
fn pick_junction(pick: &JunctionPick, centres: &BTreeMap<String, [f64; 2]>) -> Result<String, String> {
    match (pick.id.as_deref(), pick.near) {
        (Some(id), None) => {
            centres.keys().find(|j| j.as_str() == id).cloned().ok_or_else(|| "no junction of that id".into())
        }
        (None, Some(p)) => {
            let r = pick.radius_m.unwrap_or(100.0);
            if !(p.iter().all(|v| v.is_finite()) && r.is_finite() && r > 0.0) {
                return Err("near must be finite and radius_m positive".into());
            }
            let d = |c: &[f64; 2]| (c[0] - p[0]).hypot(c[1] - p[1]);
            centres
                .iter()
                .filter(|(_, c)| d(c) <= r)
                .min_by(|a, b| d(a.1).total_cmp(&d(b.1)))
                .map(|(j, _)| j.clone())
                .ok_or_else(|| format!("no junction centre within {r} m"))
        }
        _ => Err("give either id or near (with radius_m)".into()),
    }
}

/// A lane centre line's end nearer the junction centre `c`, its unit direction away from `c`
/// there (from that end to the point 25 m, or the lane's length, along it), and the point
/// halfway to that one.
fn outward(center: &xodr::Polyline, c: Vec2) -> (Vec2, Vec2, Vec2) {
    let pts = center.points();
    let (Some(first), Some(last)) = (pts.first(), pts.last()) else { return (c, Vec2::ZERO, c) };
    let v = |p: &xodr::Point| Vec2::new(p.x, p.y);
    let len = center.length();
    let d = len.min(25.0);
    let (near, far, mid) = if v(first).distance(c) <= v(last).distance(c) {
        (v(first), v(&center.point_at(d)), v(&center.point_at(0.5 * d)))
    } else {
        (v(last), v(&center.point_at(len - d)), v(&center.point_at(len - 0.5 * d)))
    };
    (near, (far - near).normalize_or_zero(), mid)
}

/// Signal poles at the corners between neighbouring arms: at each corner with a light in
/// `lights` nearer to it than to any other corner, or at every corner when there is none. Each
/// stands in its corner's sidewalk square (or, without sidewalks, 1 m outside the meeting of
/// the two arms' edges), its mast arm pointing at the junction centre.
fn corner_poles(layout: &Layout, lights: &[Vec2]) -> Vec<SignalPoleConfig> {
    let corners = &layout.corner_posts;
    let chosen: BTreeSet<usize> = if lights.is_empty() {
        (0..corners.len()).collect()
    } else {
        lights
            .iter()
            .filter_map(|l| {
                (0..corners.len()).min_by(|&a, &b| corners[a].distance(*l).total_cmp(&corners[b].distance(*l)))
            })
            .collect()
    };
    chosen
        .into_iter()
        .map(|k| {
            let p = corners[k];
            let reach = (p.length() * 0.6).min(MAST_ARM_MAX_M);
            SignalPoleConfig {
                name: format!("corner {k}"),
                position: [round(p.x, 0.01), round(p.y, 0.01)],
                height_m: POLE_HEIGHT_M,
                radius_m: 0.15,
                arm_heading_deg: round((-p.y).atan2(-p.x).to_degrees(), 0.1),
                arm_length_m: round(reach, 0.1),
                arm_height_m: 6.0,
                head_offsets_m: vec![round(reach * 0.5, 0.1), round(reach * 0.9, 0.1)],
            }
        })
        .collect()
}

/// `s` fit for a TOML comment: control characters (a line break would end the comment) become
/// spaces.
fn comment(s: &str) -> String {
    s.chars().map(|c| if c.is_control() { ' ' } else { c }).collect()
}

/// A scene file's text for `imported`: a header naming the source and junction and every note,
/// then the configuration as TOML.
pub fn scene_toml(imported: &Imported, source: &Path) -> Result<String, RaycastError> {
    let unwritable = |e: toml::ser::Error| RaycastError::Invalid {
        path: PathBuf::from(source),
        field: "scene".into(),
        value: String::new(),
        reason: format!("cannot be written as TOML: {e}"),
    };
    // The lane graph last, each connection's path a few points a line (the pretty writer would
    // give every coordinate a line of its own).
    let mut plain = imported.config.clone();
    let connections = std::mem::take(&mut plain.connections);
    let mut body = toml::to_string_pretty(&plain).map_err(unwritable)?;
    for mut c in connections {
        let path = std::mem::take(&mut c.path);
        let head = toml::to_string(&c).map_err(unwritable)?;
        body.push_str(&format!("\n[[connections]]\n{head}"));
        if !path.is_empty() {
            body.push_str("path = [\n");
            for line in path.chunks(4) {
                let pts: Vec<String> = line.iter().map(|p| format!("[{:?}, {:?}]", p[0], p[1])).collect();
                body.push_str(&format!("    {},\n", pts.join(", ")));
            }
            body.push_str("]\n");
        }
    }
    let mut head = format!(
        "{HEADER} from {} (junction {}).\n",
        comment(&source.display().to_string()),
        comment(&imported.junction)
    );
    for n in &imported.notes {
        head.push_str(&format!("# - {}\n", comment(n)));
    }
    Ok(format!("{head}\n{body}"))
}

/// Writes [`scene_toml`] to `out` atomically. An existing `out` is replaced only when an
/// earlier import wrote it: another file of that name is refused, not overwritten.
pub fn write_scene(imported: &Imported, source: &Path, out: &Path) -> Result<(), RaycastError> {
    if std::fs::symlink_metadata(out).is_ok() {
        let ours =
            hilo_core::fs::read_text_bounded(out, hilo_core::fs::limit::CONFIG).is_ok_and(|t| t.starts_with(HEADER));
        if !ours {
            return Err(RaycastError::Invalid {
                path: out.to_path_buf(),
                field: "--out".into(),
                value: out.display().to_string(),
                reason: "exists and is not a scene `hilo scene import` wrote; move it, or choose another name".into(),
            });
        }
    }
    let text = scene_toml(imported, source)?;
    Ok(hilo_core::fs::write_atomic(out, text.as_bytes())?)
}

/// `hilo scene import`: the junction `pick` of `file` imported, built once as a scene (so a
/// junction hilo cannot model is refused before anything is written), and written to `out`.
pub fn import_to(file: &Path, pick: &JunctionPick, out: &Path) -> Result<Imported, RaycastError> {
    let imported = import_file(file, pick)?;
    crate::Scene::from_config(imported.config.clone(), file.parent().unwrap_or(Path::new(".")), file)?;
    write_scene(&imported, file, out)?;
    Ok(imported)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A one-way carriageway of `lanes` 3.2 m lanes leaving the junction (at the origin) along
    /// `deg`, its end 10 m out along the arm's axis (the nearest multiple of 90 degrees) and `off`
    /// metres to the left of it; inbound when `into`.
    fn carriageway(name: &str, deg: f32, off: f32, lanes: u32, into: bool) -> (String, Approach) {
        let d = Vec2::from_angle(deg.to_radians());
        let axis = Vec2::from_angle(((deg / 90.0).round() * 90.0).to_radians());
        let near = 10.0 * axis + off * axis.perp();
        let a = Approach {
            name: name.into(),
            roads: Vec::new(),
            lanes_in: if into { lanes } else { 0 },
            lanes_out: if into { 0 } else { lanes },
            widths: vec![3.2; lanes as usize],
            out: vec![(near, d); lanes as usize],
            across: vec![(into, near, 3.2); lanes as usize],
            median_m: None,
        };
        (name.into(), a)
    }

    /// Every rounded value is the float nearest its decimal, so a scene file prints it with no
    /// more digits than its step has (`3.2`, not `3.1999998`); ties and negatives included.
    #[test]
    fn rounded_values_print_as_their_decimals() {
        for k in -10_000i32..=10_000 {
            for (step, digits) in [(0.01f32, 2usize), (0.1, 1)] {
                let exact = k as f32 * step;
                for v in [exact, exact + 0.3 * step, exact - 0.3 * step] {
                    let r = round(v, step);
                    let text = r.to_string();
                    let decimals = text.split_once('.').map_or(0, |(_, d)| d.len());
                    assert!(decimals <= digits, "round({v}, {step}) = {text}");
                    assert!((r - v).abs() <= 0.5 * step + 1e-4 * v.abs().max(1.0), "round({v}, {step}) = {r}");
                    assert_ne!(text, "-0");
                }
            }
        }
        assert_eq!(round(3.2, 0.01).to_string(), "3.2");
        assert_eq!(round(-0.001, 0.01).to_string(), "0");
    }

    /// A connecting lane sampled more finely than a scene keeps is thinned to the most a path
    /// may list, its ends kept; one within the bound is left alone.
    #[test]
    fn a_long_way_is_thinned_to_what_a_scene_keeps() {
        for n in [2, 3, 1_999, 2_000, 2_001, 4_000, 4_001, 10_007] {
            let way: Vec<Vec2> = (0..n).map(|k| Vec2::new(k as f32 * 0.01, 0.0)).collect();
            let t = thinned(way.clone(), MAX_CONNECTION_POINTS);
            assert!(t.len() >= 2 && t.len() <= MAX_CONNECTION_POINTS, "{n}: {}", t.len());
            assert_eq!((t[0], t[t.len() - 1]), (way[0], way[n - 1]), "{n}");
            if n <= MAX_CONNECTION_POINTS {
                assert_eq!(t, way);
            }
        }
    }

    fn join(list: Vec<(String, Approach)>) -> (Vec<Approach>, Vec<String>) {
        let mut notes = Vec::new();
        (join_divided(list.into_iter().collect(), &mut notes), notes)
    }

    #[test]
    fn side_by_side_one_way_roads_join_with_their_gap_as_the_median() {
        // Centres 10 m apart, each carriageway 6.4 m wide: a 3.6 m median; a few degrees apart.
        let (arms, notes) = join(vec![carriageway("in", 88.0, 5.0, 2, true), carriageway("out", 92.0, -5.0, 2, false)]);
        assert_eq!(arms.len(), 1, "{notes:?}");
        assert_eq!((arms[0].lanes_in, arms[0].lanes_out, arms[0].name.as_str()), (2, 2, "in / out"));
        assert!((arms[0].median_m.unwrap() - 3.6).abs() < 0.05, "{:?}", arms[0].median_m);
        assert!(notes[0].contains("3.6"), "{notes:?}");
        // Each pairs with its own neighbour, not the one across the junction.
        let (arms, _) = join(vec![
            carriageway("n in", 90.0, 5.0, 2, true),
            carriageway("n out", 90.0, -5.0, 2, false),
            carriageway("s in", -90.0, 5.0, 1, true),
            carriageway("s out", -90.0, -5.0, 1, false),
        ]);
        let mut names: Vec<&str> = arms.iter().map(|a| a.name.as_str()).collect();
        names.sort_unstable();
        assert_eq!(names, ["n in / n out", "s in / s out"]);
    }

    #[test]
    fn roads_that_are_not_one_divided_arm_stay_apart() {
        for (list, why) in [
            // Inbound on the right looking outward: left-hand traffic, or two other roads.
            (vec![carriageway("in", 90.0, -5.0, 2, true), carriageway("out", 90.0, 5.0, 2, false)], "sides"),
            // Overlapping carriageways: no gap between them.
            (vec![carriageway("in", 90.0, 2.0, 2, true), carriageway("out", 90.0, -2.0, 2, false)], "overlap"),
            // 40 degrees apart: two arms.
            (vec![carriageway("in", 70.0, 5.0, 2, true), carriageway("out", 110.0, -5.0, 2, false)], "angle"),
            // Two inbound roads.
            (vec![carriageway("a", 90.0, 5.0, 2, true), carriageway("b", 90.0, -5.0, 2, true)], "direction"),
        ] {
            let (arms, notes) = join(list);
            assert_eq!(arms.len(), 2, "{why}: {notes:?}");
            assert!(notes.is_empty() && arms.iter().all(|a| a.median_m.is_none()), "{why}");
        }
    }
}
