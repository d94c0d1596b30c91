//! The lane graph: one route per (approach, inbound lane, movement), as a densely sampled
//! centreline from the end of the arm, through the junction, to the end of the exit arm.
//!
//! Movements are found by angle, so any number of straight arms works: through is the exit arm
//! within 35° of straight on, left and right the arms nearest to ±90°. Left turns use the
//! left-turn bay when the arm has one (entering it by a 30 m taper from the innermost lane),
//! right turns the outermost lane. Where the scene's lane graph draws a connection's way
//! through the junction (an imported junction's connecting lane), the route follows it from
//! the stop line; otherwise junction connectors are cubic Bézier curves between the
//! junction-side edges of the two crosswalks, swung wide where a car's body would otherwise clip
//! a corner ([`ROUTE_HALF_WIDTH_M`]); the speed on a route is capped by its curvature
//! (lateral acceleration ≤ 2.5 m/s²) with comfortable braking into curves. At a roundabout a
//! route curves onto the ring's circulating lane, follows it counter-clockwise and curves off it
//! ([`ring_conflicts`] says where each route yields to which).

use glam::Vec2;
pub use hilo_raycast::scene::layout::ROUTE_HALF_WIDTH_M;
use hilo_raycast::scene::layout::{ArmLayout, Lane, LaneKind, Layout, Ring, arc, point_in_polygon};

/// Route sample spacing.
pub const DS: f32 = 0.5;
const LATERAL_ACCEL: f32 = 2.5;
const CURVE_BRAKING: f32 = 2.0;
const TAPER_M: f32 = 30.0;

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Movement {
    Left,
    Through,
    Right,
}

/// A path sampled every [`DS`] metres.
#[derive(Clone, Debug)]
pub struct Path {
    pub points: Vec<Vec2>,
    pub dirs: Vec<Vec2>,
}

impl Path {
    /// Resamples a polyline every [`DS`] metres.
    pub fn from_polyline(poly: &[Vec2]) -> Path {
        let mut points = Vec::new();
        let mut carry = 0.0f32;
        for w in poly.windows(2) {
            let (a, b) = (w[0], w[1]);
            let len = (b - a).length();
            if len < 1e-6 {
                continue;
            }
            let mut t = carry;
            while t < len {
                points.push(a + (b - a) * (t / len));
                t += DS;
            }
            carry = t - len;
        }
        if let Some(&last) = poly.last() {
            points.push(last);
        }
        let n = points.len();
        let dirs = (0..n)
            .map(|k| {
                let (a, b) = (points[k.saturating_sub(1)], points[(k + 1).min(n - 1)]);
                (b - a).normalize_or(Vec2::X)
            })
            .collect();
        Path { points, dirs }
    }

    pub fn length(&self) -> f32 {
        (self.points.len().saturating_sub(1)) as f32 * DS
    }

    /// Position and unit direction at arc length `s` (clamped to the path).
    pub fn at(&self, s: f32) -> (Vec2, Vec2) {
        let n = self.points.len();
        let x = (s / DS).clamp(0.0, (n - 1) as f32);
        let k = (x.floor() as usize).min(n.saturating_sub(2));
        let f = x - k as f32;
        if n < 2 {
            return (self.points[0], self.dirs[0]);
        }
        let p = self.points[k].lerp(self.points[k + 1], f);
        let d = self.dirs[k].lerp(self.dirs[k + 1], f).normalize_or(self.dirs[k]);
        (p, d)
    }
}

/// One vehicle route.
#[derive(Clone, Debug)]
pub struct Route {
    pub approach: usize,
    pub exit: usize,
    pub movement: Movement,
    pub path: Path,
    /// Arc length of the stop line.
    pub stop_s: f32,
    /// Arc length where the route leaves the junction (far edge of the exit crosswalk).
    pub clear_s: f32,
    /// Curvature speed cap per sample (m/s).
    pub v_cap: Vec<f32>,
    /// The crosswalks the route crosses, in order along it.
    pub crosswalks: Vec<Crossing>,
    /// At a roundabout, the arc length where the route joins the circulating lane (its merge
    /// with the traffic it yields to); None at a signalised junction.
    pub merge_s: Option<f32>,
}

/// Where a route crosses an arm's crosswalk.
#[derive(Clone, Debug)]
pub struct Crossing {
    pub arm: usize,
    /// First and last arc length of the route's centre line inside the crosswalk.
    pub s_in: f32,
    pub s_out: f32,
    /// The crosswalk's outline.
    pub polygon: Vec<Vec2>,
}

impl Route {
    pub fn v_cap_at(&self, s: f32) -> f32 {
        let k = ((s / DS).round().max(0.0) as usize).min(self.v_cap.len() - 1);
        self.v_cap[k]
    }

    /// The lowest curvature speed cap from arc length `from` over the next `d` metres (sampled
    /// every [`DS`], both ends included), and no more than `v`: the fastest a vehicle wanting
    /// `v` can go all the way.
    pub fn v_cap_over(&self, from: f32, d: f32, v: f32) -> f32 {
        (0..=(d / DS).ceil() as usize).map(|k| self.v_cap_at(from + k as f32 * DS)).fold(v, f32::min)
    }
}

fn bezier(p0: Vec2, p1: Vec2, p2: Vec2, p3: Vec2, n: usize) -> Vec<Vec2> {
    (0..=n)
        .map(|i| {
            let t = i as f32 / n as f32;
            let u = 1.0 - t;
            p0 * (u * u * u) + p1 * (3.0 * u * u * t) + p2 * (3.0 * u * t * t) + p3 * (t * t * t)
        })
        .collect()
}

/// The connector through the junction from `entry` (heading `h`) to `exit` (heading
/// `exit_dir`): a cubic Bézier whose handles are 0.45 of the chord, lengthened in steps of 0.05
/// up to 0.9 (the path then follows its lanes farther before it turns, as a driver swings wide)
/// until a car's body along it stays on the carriageway; the shortest handles that do, or 0.45
/// where none does.
fn connector(layout: &Layout, entry: Vec2, h: Vec2, exit: Vec2, exit_dir: Vec2) -> Vec<Vec2> {
    let chord = (exit - entry).length();
    let curve = |share: f32| {
        let c = share * chord;
        bezier(entry, entry + h * c, exit - exit_dir * c, exit, 24)
    };
    let clear = |pts: &[Vec2]| {
        pts.windows(2).all(|w| layout.car_on_carriageway(0.5 * (w[0] + w[1]), (w[1] - w[0]).normalize_or_zero()))
    };
    let first = curve(0.45);
    if clear(&first) {
        return first;
    }
    (10..=18).map(|k| curve(k as f32 * 0.05)).find(|c| clear(c)).unwrap_or(first)
}

/// Signed angle from `a` to `b`, radians.
fn signed_angle(a: Vec2, b: Vec2) -> f32 {
    a.perp_dot(b).atan2(a.dot(b))
}

/// The exit arm of each movement from arm `i`, if the junction has one.
pub fn exit_arm(layout: &Layout, i: usize, m: Movement) -> Option<usize> {
    let h = -layout.arms[i].dir;
    let target = match m {
        Movement::Through => 0.0f32,
        Movement::Left => std::f32::consts::FRAC_PI_2,
        Movement::Right => -std::f32::consts::FRAC_PI_2,
    };
    layout
        .arms
        .iter()
        .enumerate()
        .filter(|(j, _)| *j != i)
        .map(|(j, a)| (j, signed_angle(h, a.dir)))
        .filter(|(_, ang)| match m {
            Movement::Through => ang.abs() < 35f32.to_radians(),
            Movement::Left => *ang >= 35f32.to_radians() && *ang <= 145f32.to_radians(),
            Movement::Right => *ang <= -35f32.to_radians() && *ang >= -145f32.to_radians(),
        })
        .min_by(|a, b| (a.1 - target).abs().total_cmp(&(b.1 - target).abs()))
        .map(|(j, _)| j)
}

/// Along-arm distance of the junction-side crosswalk edge.
pub fn cw0(arm: &ArmLayout) -> f32 {
    arm.crosswalk[0].dot(arm.dir)
}

/// Width of an arm's crosswalk (along the arm).
pub fn crosswalk_width(arm: &ArmLayout) -> f32 {
    (arm.crosswalk[1] - arm.crosswalk[0]).dot(arm.dir)
}

fn lanes(arm: &ArmLayout, kind: LaneKind) -> Vec<hilo_raycast::scene::layout::Lane> {
    arm.lanes.iter().copied().filter(|l| l.kind == kind).collect()
}

/// The movement a vehicle that wants `want` from approach `arm` makes: its own where the
/// junction offers it, else straight on; None where the approach has neither (the vehicle is not
/// spawned). Spawning and the demand levels' capacity analysis both follow this rule.
pub fn spawned_movement(routes: &[Route], arm: usize, want: Movement) -> Option<Movement> {
    let has = |m: Movement| routes.iter().any(|r| r.approach == arm && r.movement == m);
    [want, Movement::Through].into_iter().find(|&m| has(m))
}

/// The longest and widest body the model drives (a bus): a route onto or off a roundabout's
/// ring keeps all of it on the carriageway.
const BODY_HALF_L_M: f32 = 6.5;
const BODY_HALF_W_M: f32 = 1.3;

/// A curve onto or off a roundabout's ring from `p0` (heading `h0`) to `p1` (heading `h1`): of
/// the cubic Béziers with handles of 0.25 to 0.9 of the chord at either end, the one whose
/// slowest curvature speed cap is highest among those that keep a bus's whole body on the
/// carriageway; [`connector`]'s curve where none does.
fn ring_curve(
    layout: &Layout,
    (p0, h0, before): (Vec2, Vec2, &[Vec2]),
    (p1, h1, after): (Vec2, Vec2, &[Vec2]),
) -> Vec<Vec2> {
    let chord = (p1 - p0).length();
    let len = polyline_length;
    let mut best: Option<(f32, Vec<Vec2>)> = None;
    for a in 5..=18 {
        for b in 5..=18 {
            let (ca, cb) = (a as f32 * 0.05 * chord, b as f32 * 0.05 * chord);
            let pts = bezier(p0, p0 + h0 * ca, p1 - h1 * cb, p1, 32);
            // The way there and on, as the route has them, so the body's ends are where they
            // will be.
            let mut poly = before[..before.len().saturating_sub(1)].to_vec();
            poly.extend_from_slice(&pts);
            poly.extend_from_slice(after.get(1..).unwrap_or_default());
            let path = Path::from_polyline(&poly);
            let (from, to) = (len(before), len(before) + len(&pts));
            let body_on_road = (0..).map(|k| from + k as f32 * DS).take_while(|&s| s <= to).all(|s| {
                // Its sides every metre, not only its corners: a curb can reach in between.
                let body = super::footprint(&path, s, BODY_HALF_L_M, BODY_HALF_W_M);
                let side = body.dir.perp() * BODY_HALF_W_M;
                (0..=13).all(|k| {
                    let along = body.center + body.dir * (BODY_HALF_L_M * (k as f32 / 6.5 - 1.0));
                    layout.on_carriageway(along + side) && layout.on_carriageway(along - side)
                })
            });
            if !body_on_road {
                continue;
            }
            let slowest = speed_caps(&path).into_iter().fold(f32::INFINITY, f32::min);
            if best.as_ref().is_none_or(|(v, _)| slowest > *v) {
                best = Some((slowest, pts));
            }
        }
    }
    best.map_or_else(|| connector(layout, p0, h0, p1, h1), |(_, pts)| pts)
}

/// How far round the ring (radians) a route joins the circulating lane after its yield line's
/// bearing: the entry curve's sweep, a third of the way round to the exit where that is less (a
/// right turn's curves are the tightest). A longer entry merges so tangentially that an
/// entering and a circulating body can end up side by side.
const RING_ENTRY_RAD: f32 = 0.5;
/// How far before the exit lane's bearing a route leaves the circulating lane: exits are drawn
/// flatter than entries, as roundabout design guides ask, so circulating drivers do not brake
/// for their exit while they pass the entry before it.
const RING_EXIT_RAD: f32 = 0.9;

/// The way through a roundabout from `entry` on the approach lane (heading `h`) to `exit` on the
/// exit lane (heading `exit_dir`): a curve onto the circulating lane's centre line, the lane
/// counter-clockwise, a curve off it. Returns the points and the index of the merge point.
fn ring_connector(
    layout: &Layout,
    ring: &Ring,
    entry: Vec2,
    h: Vec2,
    exit: Vec2,
    exit_dir: Vec2,
) -> (Vec<Vec2>, usize) {
    let rc = ring.lane_radius_m();
    let bearing = |p: Vec2| p.y.atan2(p.x);
    let span = (bearing(exit) - bearing(entry)).rem_euclid(std::f32::consts::TAU);
    let (a_in, a_out) =
        (bearing(entry) + RING_ENTRY_RAD.min(span / 3.0), bearing(exit) - RING_EXIT_RAD.min(span / 3.0));
    let tangent = |a: f32| Vec2::from_angle(a).perp();
    let on = arc(rc, a_in, a_out);
    let (m_in, m_out) = (on[0], on[on.len() - 1]);
    // A bus's length of straight lane before the entry and after the exit, of ring after the
    // merge and before the diverge.
    let lead = 2.0 * BODY_HALF_L_M;
    let (ahead, behind) = (arc(rc, a_in, a_in + lead / rc), arc(rc, a_out - lead / rc, a_out));
    let mut pts = ring_curve(layout, (entry, h, &[entry - h * lead, entry]), (m_in, tangent(a_in), &ahead));
    let merge = pts.len() - 1;
    pts.extend_from_slice(&on[1..on.len() - 1]);
    pts.extend(ring_curve(layout, (m_out, tangent(a_out), &behind), (exit, exit_dir, &[exit, exit + exit_dir * lead])));
    (pts, merge)
}

/// One movement's start: the approach arm, the movement, the exit arm, and per route the
/// inbound polyline (its last point the stop line), the exit lane (index among the exit arm's
/// outbound lanes) and the way through the junction the scene draws (empty: hilo draws it).
type Starts = (usize, Movement, usize, Vec<(Vec<Vec2>, usize, Vec<Vec2>)>);

/// The polyline a vehicle drives on inbound lane `k` of `arm` up to its stop line: for a left
/// turn from the innermost lane where the arm has a left-turn bay, into the bay by a taper.
fn start_polyline(arm: &ArmLayout, k: usize, m: Movement) -> Option<Vec<Vec2>> {
    let ins = lanes(arm, LaneKind::Inbound);
    let bays = lanes(arm, LaneKind::LeftTurnBay);
    let l = *ins.get(k)?;
    match (m, bays.first()) {
        (Movement::Left, Some(bay)) if k == 0 => {
            let dir = (l.end - l.start).normalize_or_zero();
            // The taper ends where the bay starts.
            let bay_start_on_l0 = l.end - dir * (bay.start - bay.end).length();
            let taper_start = bay_start_on_l0 - dir * TAPER_M;
            let mut poly = vec![l.start];
            if (taper_start - l.start).dot(dir) > 0.0 {
                poly.push(taper_start);
            }
            poly.push(bay.start);
            poly.push(bay.end);
            Some(poly)
        }
        _ => Some(vec![l.start, l.end]),
    }
}

/// hilo's own lane graph, by angle ([`exit_arm`]): every inbound lane goes through to the
/// outbound lane of its index (or the outermost), the innermost turns left (from its bay where
/// the arm has one), the outermost turns right into the outermost outbound lane.
fn rule_starts(layout: &Layout) -> Vec<Starts> {
    let mut out = Vec::new();
    for (i, arm) in layout.arms.iter().enumerate() {
        let n_in = lanes(arm, LaneKind::Inbound).len();
        if n_in == 0 {
            continue;
        }
        for m in [Movement::Left, Movement::Through, Movement::Right] {
            let Some(j) = exit_arm(layout, i, m) else { continue };
            let n_out = lanes(&layout.arms[j], LaneKind::Outbound).len();
            if n_out == 0 {
                continue;
            }
            let pairs: Vec<(usize, usize)> = match m {
                Movement::Through => (0..n_in).map(|k| (k, k.min(n_out - 1))).collect(),
                Movement::Right => vec![(n_in - 1, n_out - 1)],
                Movement::Left => vec![(0, 0)],
            };
            let starts =
                pairs.into_iter().filter_map(|(k, o)| Some((start_polyline(arm, k, m)?, o, Vec::new()))).collect();
            out.push((i, m, j, starts));
        }
    }
    out
}

/// The movement from arm `i` to arm `j` by the angle between them, as [`exit_arm`] reads it:
/// through within 35° of straight on, else a left or a right turn by the side it turns to.
pub fn movement_between(layout: &Layout, i: usize, j: usize) -> Movement {
    let ang = signed_angle(-layout.arms[i].dir, layout.arms[j].dir);
    if ang.abs() < 35f32.to_radians() {
        Movement::Through
    } else if ang > 0.0 {
        Movement::Left
    } else {
        Movement::Right
    }
}

/// The scene's own lane graph ([`Layout::connections`]): one route per connection, in the
/// order of [`rule_starts`] (by approach, then left, through, right, then lane), so that a lane
/// graph equal to hilo's own rules gives the same routes in the same order.
fn connection_starts(layout: &Layout) -> Vec<Starts> {
    let rank = |m: Movement| [Movement::Left, Movement::Through, Movement::Right].iter().position(|x| *x == m);
    let mut out: Vec<(usize, Option<usize>, usize, Starts)> = layout
        .connections
        .iter()
        .filter_map(|c| {
            let m = movement_between(layout, c.from, c.to);
            let poly = start_polyline(layout.arms.get(c.from)?, c.from_lane, m)?;
            Some((c.from, rank(m), c.from_lane, (c.from, m, c.to, vec![(poly, c.to_lane, c.path.clone())])))
        })
        .collect();
    out.sort_by_key(|x| (x.0, x.1, x.2));
    out.into_iter().map(|x| x.3).collect()
}

/// Every route of the layout: one per connection of the scene's lane graph where it has one,
/// else by hilo's own rules ([`rule_starts`]).
pub fn build_routes(layout: &Layout) -> Vec<Route> {
    let mut routes = Vec::new();
    let starts = if layout.connections.is_empty() { rule_starts(layout) } else { connection_starts(layout) };
    for (i, m, j, starts) in starts {
        let (arm, exit) = (&layout.arms[i], &layout.arms[j]);
        let out = lanes(exit, LaneKind::Outbound);
        if let Some(ring) = &layout.ring {
            for (poly, k, _) in starts {
                let (first, last) = (poly[0], poly[poly.len() - 1]);
                routes.push(ring_route(layout, ring, (i, first, last), (j, out[k]), m));
            }
            continue;
        }
        for (mut poly, k, drawn) in starts {
            let Some(&o) = out.get(k) else { continue };
            let stop_line = *poly.last().unwrap_or(&o.start);
            let h = (stop_line - poly[poly.len() - 2]).normalize_or(-arm.dir);
            let stop_s = polyline_length(&poly);
            let exit_dir = (o.end - o.start).normalize_or(exit.dir);
            if drawn.is_empty() {
                // Straight over the own crosswalk to its junction-side edge.
                let entry = stop_line + h * (stop_line.dot(arm.dir) - cw0(arm)).max(0.0);
                poly.push(entry);
                let curve = connector(layout, entry, h, o.start, exit_dir);
                poly.extend_from_slice(&curve[1..]);
            } else {
                // The scene's own curve from where it has passed the stop line.
                poly.extend(drawn.iter().copied().skip_while(|p| (*p - stop_line).dot(h) <= DS));
            }
            poly.push(o.end);
            let path = Path::from_polyline(&poly);
            let clear_s = if drawn.is_empty() {
                path.length() - (o.end - o.start).length() + crosswalk_width(exit)
            } else {
                leaves_at(&path, exit)
            };
            let v_cap = speed_caps(&path);
            let crosswalks = crossings(layout, &path, [i, j]);
            routes.push(Route {
                approach: i,
                exit: j,
                movement: m,
                path,
                stop_s,
                clear_s,
                v_cap,
                crosswalks,
                merge_s: None,
            });
        }
    }
    routes
}

/// The arc length where `path`, ending out along the arm `exit`, passes the far edge of that
/// arm's crosswalk for the last time.
fn leaves_at(path: &Path, exit: &ArmLayout) -> f32 {
    let far = exit.crosswalk[1].dot(exit.dir);
    let last_inside = path.points.iter().rposition(|p| p.dot(exit.dir) < far);
    last_inside.map_or(0.0, |k| (k + 1) as f32 * DS).min(path.length())
}

/// The length of a polyline, summed segment by segment.
fn polyline_length(pts: &[Vec2]) -> f32 {
    pts.windows(2).map(|w| (w[1] - w[0]).length()).sum()
}

/// Where `path` crosses the crosswalks of `arms`, in that order.
fn crossings(layout: &Layout, path: &Path, arms: [usize; 2]) -> Vec<Crossing> {
    arms.iter()
        .filter_map(|&arm| {
            let inside: Vec<f32> = path
                .points
                .iter()
                .enumerate()
                .filter(|(_, p)| point_in_polygon(**p, &layout.arms[arm].crosswalk))
                .map(|(k, _)| k as f32 * DS)
                .collect();
            let polygon = layout.arms[arm].crosswalk.clone();
            Some(Crossing { arm, s_in: *inside.first()?, s_out: *inside.last()?, polygon })
        })
        .collect()
}

/// A route through a roundabout from approach `i`'s lane (`first` to `last`, its yield line) to
/// exit arm `j`'s lane `o`. The curves on and off the ring start and end a metre beyond the
/// crosswalks, so they are as flat as the arm allows; the yield line is where the path comes
/// within half a metre of the ring, and the route leaves the junction where its exit curve
/// ends.
fn ring_route(
    layout: &Layout,
    ring: &Ring,
    (i, first, last): (usize, Vec2, Vec2),
    (j, o): (usize, Lane),
    m: Movement,
) -> Route {
    let (arm, exit) = (&layout.arms[i], &layout.arms[j]);
    let h = (last - first).normalize_or(-arm.dir);
    let a_in = arm.crosswalk[1].dot(arm.dir) + 1.0;
    let entry = first + h * (first.dot(arm.dir) - a_in);
    let d_out = (o.end - o.start).normalize_or(exit.dir);
    let leave = o.start + d_out * (exit.crosswalk[1].dot(exit.dir) + 1.0 - o.start.dot(exit.dir));
    let (curve, merge) = ring_connector(layout, ring, entry, h, leave, d_out);
    let mut poly = vec![first, entry];
    poly.extend_from_slice(&curve[1..]);
    poly.push(o.end);
    let merge_s = polyline_length(&poly[..=1 + merge]);
    let path = Path::from_polyline(&poly);
    let near = ring.outer_radius_m + 0.5;
    let stop_s = path.points.iter().position(|p| p.length() <= near).map_or(merge_s, |k| k as f32 * DS);
    let clear_s = path.length() - (o.end - leave).length();
    let v_cap = speed_caps(&path);
    let crosswalks = crossings(layout, &path, [i, j]);
    Route { approach: i, exit: j, movement: m, path, stop_s, clear_s, v_cap, crosswalks, merge_s: Some(merge_s) }
}

/// Curvature speed cap per sample with a backward pass for braking into curves.
fn speed_caps(path: &Path) -> Vec<f32> {
    let n = path.points.len();
    let window = 4usize;
    let mut caps: Vec<f32> = (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(window), (k + window).min(n - 1));
            if b <= a {
                return f32::INFINITY;
            }
            let turn = signed_angle(path.dirs[a], path.dirs[b]).abs();
            let len = (b - a) as f32 * DS;
            let kappa = turn / len;
            if kappa < 1e-4 { f32::INFINITY } else { (LATERAL_ACCEL / kappa).sqrt() }
        })
        .collect();
    for k in (0..n.saturating_sub(1)).rev() {
        let next = caps[k + 1];
        if next.is_finite() {
            caps[k] = caps[k].min((next * next + 2.0 * CURVE_BRAKING * DS).sqrt());
        }
    }
    caps
}

/// At a roundabout, for each ordered pair of routes (a, b) from different approaches: the arc
/// length on b where b, already circulating, passes a's merge point (within `clearance_m`), so
/// a vehicle on a yields to one on b before it. None where b does not pass it, or has not yet
/// joined the ring there (b then yields to a), and everywhere at a signalised junction.
pub fn ring_conflicts(routes: &[Route], clearance_m: f32) -> Vec<Vec<Option<f32>>> {
    routes
        .iter()
        .map(|a| {
            routes
                .iter()
                .map(|b| {
                    let (ma, mb) = (a.merge_s?, b.merge_s?);
                    if a.approach == b.approach {
                        return None;
                    }
                    let (p, _) = a.path.at(ma);
                    let (k, d) = b
                        .path
                        .points
                        .iter()
                        .enumerate()
                        .map(|(k, q)| (k, q.distance(p)))
                        .min_by(|x, y| x.1.total_cmp(&y.1))?;
                    let s = k as f32 * DS;
                    (d < clearance_m && s > mb).then_some(s)
                })
                .collect()
        })
        .collect()
}

/// For each ordered pair of routes (a, b): if b's path through the junction comes within
/// `clearance_m` of a's, the arc length on b after which b's rear has left the conflict.
/// Routes that start on the same lane are never in conflict here (they follow each other).
pub fn junction_conflicts(routes: &[Route], clearance_m: f32) -> Vec<Vec<Option<f32>>> {
    let span = |r: &Route| {
        let (k0, k1) =
            ((r.stop_s / DS).floor() as usize, ((r.clear_s / DS).ceil() as usize).min(r.path.points.len() - 1));
        (k0..=k1).map(|k| (k as f32 * DS, r.path.points[k])).collect::<Vec<_>>()
    };
    let spans: Vec<_> = routes.iter().map(span).collect();
    let c2 = clearance_m * clearance_m;
    routes
        .iter()
        .enumerate()
        .map(|(ia, a)| {
            routes
                .iter()
                .enumerate()
                .map(|(ib, b)| {
                    if ia == ib || a.path.points[0].distance(b.path.points[0]) < 0.1 {
                        return None;
                    }
                    spans[ib]
                        .iter()
                        .filter(|(_, pb)| spans[ia].iter().any(|(_, pa)| pa.distance_squared(*pb) < c2))
                        .map(|(s, _)| *s)
                        .fold(None, |m: Option<f32>, s| Some(m.map_or(s, |m| m.max(s))))
                })
                .collect()
        })
        .collect()
}
