//! Microscopic traffic at a signalised intersection: the road users a dataset records.
//!
//! Every road user follows a path sampled every 0.5 m: vehicles a [`routes::Route`] of the lane
//! graph, pedestrians a path over sidewalks and a crosswalk (or, for jaywalkers, straight across
//! an arm). Longitudinal motion is the Intelligent Driver Model (Treiber et al. 2000) towards the
//! nearest obstacle on the path ahead. The obstacle search is geometric: the road user's own
//! rectangle is swept along its path and the first place it would overlap another road user's
//! rectangle is the gap, so following, merging, crossing and yielding to pedestrians are one
//! mechanism. When two road users each find the other ahead (a crossing conflict), the one
//! nearer to the conflict goes first. Virtual obstacles stop vehicles at the stop line on red,
//! on yellow when they can stop comfortably, when a permissive left turn finds no acceptable gap
//! in opposing traffic (critical gap per driver), and when the exit is blocked (no vehicle
//! enters the junction without room beyond it). Pedestrians wait at the curb for WALK and step
//! off only if they can finish before the conflicting green and no vehicle would reach their
//! path within a few seconds; jaywalkers cross mid-block when no vehicle would reach them
//! before they are across.
//!
//! What it leaves out, on purpose: lane changes (vehicles keep the lane they enter on), right
//! turns on red, cyclists, parking, and lateral dynamics (road users are on their path's
//! centreline, heading along its tangent). The sensors see boxes, so none of this changes what a
//! detector has to learn beyond the mix of poses and speeds, which the model covers.
//!
//! The traffic depends only on the scene, the [`TrafficConfig`] and the seed.

pub mod geom;
pub mod routes;
pub mod signal;

use crate::error::DatasetError;
use geom::{Rect, point_segment_distance};
use glam::Vec2;
use hilo_core::{Box3, Class};
use hilo_raycast::scene::layout::{LaneKind, Layout};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Exp, Normal};
use routes::{DS, Movement, Path, Route, build_routes, crosswalk_width, cw0, junction_conflicts};
use serde::{Deserialize, Serialize};
use signal::{Light, SignalConfig, SignalPlan};
use std::collections::BTreeMap;

/// Traffic settings (`[traffic]` in a study file).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct TrafficConfig {
    /// Vehicle arrivals per approach (Poisson).
    pub vehicles_per_hour: f64,
    /// Per-approach overrides by arm name.
    pub approach_vehicles_per_hour: BTreeMap<String, f64>,
    /// Turning shares of arriving vehicles (the rest go straight).
    pub left_share: f64,
    pub right_share: f64,
    /// Relative frequencies of the vehicle classes (car, truck, bus, motorcycle, golf_cart).
    pub class_mix: BTreeMap<String, f64>,
    /// Pedestrian arrivals per crosswalk and direction (Poisson).
    pub pedestrians_per_hour: f64,
    /// Share of arriving pedestrians who cross mid-block instead.
    pub jaywalk_share: f64,
    /// Simulated before the first recorded frame, so scenes start with traffic in them.
    pub warmup_s: f64,
    /// Integration step.
    pub step_s: f64,
    pub signal: SignalConfig,
}

impl Default for TrafficConfig {
    fn default() -> Self {
        let class_mix = [("car", 0.74), ("truck", 0.06), ("bus", 0.03), ("motorcycle", 0.05), ("golf_cart", 0.12)]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect();
        TrafficConfig {
            vehicles_per_hour: 500.0,
            approach_vehicles_per_hour: BTreeMap::new(),
            left_share: 0.2,
            right_share: 0.15,
            class_mix,
            pedestrians_per_hour: 90.0,
            jaywalk_share: 0.08,
            warmup_s: 45.0,
            step_s: 0.05,
            signal: SignalConfig::default(),
        }
    }
}

fn invalid(field: &str, value: impl std::fmt::Display, why: &str) -> DatasetError {
    DatasetError::Invalid(format!("traffic.{field} = {value}: {why}"))
}

impl TrafficConfig {
    /// Checks every field; errors name the field and value.
    pub fn validate(&self, layout: &Layout) -> Result<(), DatasetError> {
        let nonneg = |f: &str, v: f64| {
            if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(invalid(f, v, "must be a finite number ≥ 0")) }
        };
        nonneg("vehicles_per_hour", self.vehicles_per_hour)?;
        nonneg("pedestrians_per_hour", self.pedestrians_per_hour)?;
        nonneg("warmup_s", self.warmup_s)?;
        for (f, v) in
            [("left_share", self.left_share), ("right_share", self.right_share), ("jaywalk_share", self.jaywalk_share)]
        {
            if !(0.0..=1.0).contains(&v) {
                return Err(invalid(f, v, "must be a share in [0, 1]"));
            }
        }
        if self.left_share + self.right_share > 1.0 {
            return Err(invalid(
                "left_share + right_share",
                self.left_share + self.right_share,
                "turning shares exceed 1",
            ));
        }
        if !(self.step_s > 0.0 && self.step_s <= 0.2) {
            return Err(invalid("step_s", self.step_s, "must be in (0, 0.2] s"));
        }
        for (arm, v) in &self.approach_vehicles_per_hour {
            if !layout.arms.iter().any(|a| &a.name == arm) {
                let known: Vec<&str> = layout.arms.iter().map(|a| a.name.as_str()).collect();
                return Err(invalid(
                    &format!("approach_vehicles_per_hour.{arm}"),
                    v,
                    &format!("no arm is named {arm:?} (arms: {})", known.join(", ")),
                ));
            }
            nonneg(&format!("approach_vehicles_per_hour.{arm}"), *v)?;
        }
        let mut total = 0.0;
        for (name, w) in &self.class_mix {
            let c: Class = name.parse().map_err(|_| {
                invalid(&format!("class_mix.{name}"), w, "unknown class (car, truck, bus, motorcycle, golf_cart)")
            })?;
            if c == Class::Pedestrian {
                return Err(invalid(
                    &format!("class_mix.{name}"),
                    w,
                    "pedestrians have their own rate, pedestrians_per_hour",
                ));
            }
            nonneg(&format!("class_mix.{name}"), *w)?;
            total += w;
        }
        if total <= 0.0 && self.vehicles_per_hour > 0.0 {
            return Err(invalid("class_mix", "{…}", "needs at least one class with a positive share"));
        }
        let s = &self.signal;
        for (f, v) in [
            ("signal.green_s", s.green_s),
            ("signal.protected_left_s", s.protected_left_s),
            ("signal.all_red_s", s.all_red_s),
        ] {
            nonneg(f, v)?;
        }
        if s.green_s < 5.0 {
            return Err(invalid("signal.green_s", s.green_s, "must be at least 5 s"));
        }
        if let Some(y) = s.yellow_s
            && !(2.0..=8.0).contains(&y)
        {
            return Err(invalid("signal.yellow_s", y, "must be in [2, 8] s"));
        }
        Ok(())
    }
}

/// Physical parameters of a class: size distribution and driver model.
#[derive(Clone, Copy, Debug)]
pub struct ClassModel {
    /// (mean, standard deviation, min, max) of length, width, height in metres.
    pub length: (f32, f32, f32, f32),
    pub width: (f32, f32, f32, f32),
    pub height: (f32, f32, f32, f32),
    /// Top speed (m/s); vehicles also keep to the speed limit.
    pub v_max: f32,
    /// IDM maximum acceleration, comfortable deceleration, time headway, standstill gap.
    pub a: f32,
    pub b: f32,
    pub headway_s: f32,
    pub s0: f32,
    /// The hardest braking the class can do (m/s²).
    pub b_max: f32,
}

pub fn class_model(c: Class) -> ClassModel {
    match c {
        Class::Car => ClassModel {
            length: (4.6, 0.35, 3.8, 5.4),
            width: (1.85, 0.08, 1.65, 2.05),
            height: (1.55, 0.12, 1.35, 1.95),
            v_max: 30.0,
            a: 2.0,
            b: 3.0,
            headway_s: 1.4,
            s0: 2.0,
            b_max: 8.0,
        },
        Class::Truck => ClassModel {
            length: (8.0, 1.4, 6.0, 11.0),
            width: (2.45, 0.08, 2.3, 2.6),
            height: (3.3, 0.3, 2.8, 4.0),
            v_max: 25.0,
            a: 1.2,
            b: 2.5,
            headway_s: 1.8,
            s0: 3.0,
            b_max: 6.0,
        },
        Class::Bus => ClassModel {
            length: (12.0, 0.5, 10.5, 13.0),
            width: (2.55, 0.04, 2.45, 2.6),
            height: (3.2, 0.12, 2.95, 3.5),
            v_max: 22.0,
            a: 1.0,
            b: 2.5,
            headway_s: 1.8,
            s0: 3.0,
            b_max: 6.0,
        },
        Class::Motorcycle => ClassModel {
            length: (2.1, 0.15, 1.8, 2.4),
            width: (0.8, 0.06, 0.65, 0.95),
            height: (1.45, 0.08, 1.25, 1.65),
            v_max: 30.0,
            a: 3.0,
            b: 3.5,
            headway_s: 1.1,
            s0: 2.0,
            b_max: 8.0,
        },
        Class::GolfCart => ClassModel {
            length: (2.5, 0.2, 2.2, 3.0),
            width: (1.2, 0.05, 1.1, 1.35),
            height: (1.8, 0.08, 1.65, 2.0),
            v_max: 7.0,
            a: 1.2,
            b: 2.0,
            headway_s: 1.5,
            s0: 1.5,
            b_max: 5.0,
        },
        Class::Pedestrian => ClassModel {
            length: (0.55, 0.08, 0.4, 0.75),
            width: (0.65, 0.07, 0.5, 0.8),
            height: (1.70, 0.09, 1.45, 1.95),
            v_max: 1.9,
            a: 1.0,
            b: 1.5,
            headway_s: 0.6,
            s0: 0.4,
            b_max: 3.0,
        },
    }
}

/// Lateral clearance kept from other road users when sweeping a path.
const MARGIN_M: f32 = 0.15;
/// How far ahead (in seconds of walking) vehicles keep clear of a crossing pedestrian.
const PED_ANTICIPATION_S: f32 = 3.0;
/// How close to the stop line a vehicle stops on red.
const STOP_LINE_GAP_M: f32 = 0.5;

#[derive(Clone, Debug)]
enum Role {
    Vehicle {
        route: usize,
        /// Decided at the onset of yellow: true = stop.
        yellow_stop: Option<bool>,
        /// A permissive left turn that accepted its gap.
        committed: bool,
        critical_gap_s: f32,
    },
    Pedestrian {
        path: Path,
        /// Arc lengths of the curb (where waiting ends) and of the far curb.
        curb_s: f32,
        far_s: f32,
        arm: usize,
        jaywalk: bool,
        started: bool,
    },
}

#[derive(Clone, Debug)]
struct Agent {
    id: u32,
    class: Class,
    length: f32,
    width: f32,
    height: f32,
    v_desired: f32,
    s: f32,
    v: f32,
    a: f32,
    role: Role,
}

/// A road user at one instant.
#[derive(Clone, Debug, PartialEq)]
pub struct ActorState {
    pub id: u32,
    pub class: Class,
    pub box3: Box3,
    pub velocity_mps: Vec2,
    pub accel_mps2: f32,
    /// nuScenes attribute name.
    pub attribute: &'static str,
    pub jaywalking: bool,
    /// Vehicles: approach arm, movement, arc length of the front and of the stop line.
    pub route: Option<RouteProgress>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RouteProgress {
    pub approach: usize,
    pub movement: Movement,
    pub front_s: f32,
    pub stop_s: f32,
}

/// An obstacle found ahead: the gap to it (to its anticipated footprint for a crossing
/// pedestrian or, seen by a pedestrian, a moving vehicle), its speed along the path, its index,
/// and the gap to its real footprint.
#[derive(Clone, Copy, Debug)]
struct Hit {
    gap: f32,
    v_along: f32,
    other: usize,
    real_gap: f32,
}

#[derive(Clone, Debug)]
struct PendingVehicle {
    class: Class,
    size: (f32, f32, f32),
    v_desired: f32,
    critical_gap_s: f32,
}

#[derive(Clone, Debug)]
struct PedSource {
    arm: usize,
    /// Candidate paths (one per waiting slot) with their curb and far-curb arc lengths.
    paths: Vec<(Path, f32, f32)>,
    next_arrival_s: f64,
    pending: usize,
    jaywalk: bool,
}

/// The traffic of one scene.
#[derive(Debug)]
pub struct Traffic {
    cfg: TrafficConfig,
    routes: Vec<Route>,
    /// `conflicts[a][b]`: where on route b a vehicle stops blocking route a (see
    /// [`junction_conflicts`]).
    conflicts: Vec<Vec<Option<f32>>>,
    plan: SignalPlan,
    ground_z: f32,
    rng: ChaCha8Rng,
    t: f64,
    agents: Vec<Agent>,
    next_id: u32,
    /// Per approach: next arrival time and the routes by movement.
    approach_rate: Vec<f64>,
    next_arrival: Vec<f64>,
    pending: Vec<Vec<PendingVehicle>>,
    ped_sources: Vec<PedSource>,
    speed_limits: Vec<f32>,
    /// The warm-up, rounded to whole steps.
    warm_s: f64,
    steps: u64,
    /// Emergency stops: steps in which a road user's travel had to be cut to the free distance
    /// ahead (it then brakes at its hardest). They happen where the model's anticipation
    /// fails (a road user entering a path at close range); rare, counted and reported.
    pub clamps: u64,
}

fn sample(rng: &mut ChaCha8Rng, (mean, sd, lo, hi): (f32, f32, f32, f32)) -> f32 {
    let n = Normal::new(mean, sd).map(|d| d.sample(rng)).unwrap_or(mean);
    n.clamp(lo, hi)
}

fn next_arrival(rng: &mut ChaCha8Rng, now: f64, per_hour: f64) -> f64 {
    if per_hour <= 0.0 {
        return f64::INFINITY;
    }
    let e = Exp::new(per_hour / 3600.0).map(|d| d.sample(rng)).unwrap_or(f64::INFINITY);
    now + e
}

impl Traffic {
    /// Builds the lane graph, signal plan and sources and runs the warm-up.
    pub fn new(layout: &Layout, ground_z: f32, cfg: &TrafficConfig, seed: u64) -> Result<Traffic, DatasetError> {
        cfg.validate(layout)?;
        let routes = build_routes(layout);
        let dirs: Vec<Vec2> = layout.arms.iter().map(|a| a.dir).collect();
        let speeds: Vec<f32> = layout.arms.iter().map(|a| a.speed_limit_mps).collect();
        let bays: Vec<bool> =
            layout.arms.iter().map(|a| a.lanes.iter().any(|l| l.kind == LaneKind::LeftTurnBay)).collect();
        let plan = SignalPlan::new(&cfg.signal, &dirs, &speeds, &bays);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let approach_rate: Vec<f64> = layout
            .arms
            .iter()
            .enumerate()
            .map(|(i, a)| {
                if routes.iter().any(|r| r.approach == i) {
                    cfg.approach_vehicles_per_hour.get(&a.name).copied().unwrap_or(cfg.vehicles_per_hour)
                } else {
                    0.0
                }
            })
            .collect();
        let next_arrival_v = approach_rate.iter().map(|&q| next_arrival(&mut rng, 0.0, q)).collect();
        let mut ped_sources = pedestrian_sources(layout);
        for src in &mut ped_sources {
            let rate = if src.jaywalk {
                cfg.pedestrians_per_hour * cfg.jaywalk_share
            } else {
                cfg.pedestrians_per_hour * (1.0 - cfg.jaywalk_share)
            };
            src.next_arrival_s = next_arrival(&mut rng, 0.0, rate);
        }
        let n_routes = routes.len();
        let conflicts = junction_conflicts(&routes, 3.2);
        let mut traffic = Traffic {
            cfg: cfg.clone(),
            routes,
            conflicts,
            plan,
            ground_z,
            rng,
            t: 0.0,
            agents: Vec::new(),
            next_id: 0,
            approach_rate,
            next_arrival: next_arrival_v,
            pending: vec![Vec::new(); n_routes],
            ped_sources,
            speed_limits: speeds,
            warm_s: (cfg.warmup_s / cfg.step_s).round() * cfg.step_s,
            steps: 0,
            clamps: 0,
        };
        // The clock runs from -warmup_s, so recorded time starts at 0 without a jump in the
        // signal plan.
        let warm = (cfg.warmup_s / cfg.step_s).round() as usize;
        traffic.t = -traffic.warm_s;
        for _ in 0..warm {
            traffic.step();
        }
        Ok(traffic)
    }

    /// Time since the end of the warm-up (seconds).
    pub fn time_s(&self) -> f64 {
        self.t
    }

    pub fn step_s(&self) -> f64 {
        self.cfg.step_s
    }

    pub fn routes(&self) -> &[Route] {
        &self.routes
    }

    pub fn signal(&self) -> &SignalPlan {
        &self.plan
    }

    /// Signal time (the plan runs from the start of the warm-up).
    fn signal_t(&self) -> f64 {
        self.t + self.warm_s
    }

    /// The light a movement sees now.
    pub fn light(&self, approach: usize, m: Movement) -> Light {
        self.plan.light(approach, m, self.signal_t())
    }

    fn path<'a>(&'a self, a: &'a Agent) -> &'a Path {
        match &a.role {
            Role::Vehicle { route, .. } => &self.routes[*route].path,
            Role::Pedestrian { path, .. } => path,
        }
    }

    fn rect(&self, a: &Agent) -> Rect {
        footprint(self.path(a), a.s, 0.5 * a.length, 0.5 * a.width)
    }

    /// Every road user now.
    pub fn snapshot(&self) -> Vec<ActorState> {
        self.agents
            .iter()
            .map(|a| {
                let r = self.rect(a);
                let b = Box3::new(
                    r.center.extend(self.ground_z + 0.5 * a.height),
                    a.length,
                    a.width,
                    a.height,
                    r.dir.y.atan2(r.dir.x),
                );
                let moving = a.v > 0.2;
                let (attribute, jaywalking, route) = match &a.role {
                    Role::Vehicle { route, .. } => {
                        let rt = &self.routes[*route];
                        let attr = if a.class == Class::Motorcycle {
                            "cycle.with_rider"
                        } else if moving {
                            "vehicle.moving"
                        } else {
                            "vehicle.stopped"
                        };
                        (
                            attr,
                            false,
                            Some(RouteProgress {
                                approach: rt.approach,
                                movement: rt.movement,
                                front_s: a.s + 0.5 * a.length,
                                stop_s: rt.stop_s,
                            }),
                        )
                    }
                    Role::Pedestrian { jaywalk, .. } => {
                        (if moving { "pedestrian.moving" } else { "pedestrian.standing" }, *jaywalk, None)
                    }
                };
                ActorState {
                    id: a.id,
                    class: a.class,
                    box3: b,
                    velocity_mps: r.dir * a.v,
                    accel_mps2: a.a,
                    attribute,
                    jaywalking,
                    route,
                }
            })
            .collect()
    }

    /// The first arc-length distance from `s` at which `me`, moved along `path`, touches `r`
    /// (samples `lo_k..=hi_k`, refined by bisection).
    fn first_contact(path: &Path, me: &Rect, s: f32, r: &Rect, lo_k: usize, hi_k: usize) -> Option<f32> {
        let touches = |x: f32| footprint(path, x, me.half_l, me.half_w + MARGIN_M).overlaps(r);
        for k in lo_k..=hi_k {
            if touches(k as f32 * DS) {
                let (mut lo, mut hi) = (((k as f32 - 1.0) * DS).max(s), k as f32 * DS);
                if touches(lo) {
                    return Some(0.0);
                }
                for _ in 0..5 {
                    let mid = 0.5 * (lo + hi);
                    if touches(mid) { hi = mid } else { lo = mid }
                }
                return Some((lo - s).max(0.0));
            }
        }
        None
    }

    /// The obstacles on `i`'s path within `lookahead` metres.
    fn sweep(&self, i: usize, rects: &[Rect], lookahead: f32) -> Vec<Hit> {
        let a = &self.agents[i];
        let path = self.path(a);
        let me = rects[i];
        let is_ped = a.class == Class::Pedestrian;
        // Pedestrians on the road also yield to vehicles in their way.
        let ped_on_road = matches!(&a.role, Role::Pedestrian { started: true, far_s, .. } if a.s < *far_s + 0.5);
        let n = path.points.len();
        let k0 = ((a.s / DS).ceil() as usize).min(n - 1);
        let k1 = (((a.s + lookahead) / DS).ceil() as usize).min(n - 1);
        let mut hits = Vec::new();
        for (j, o) in self.agents.iter().enumerate() {
            if j == i || (is_ped && !ped_on_road && o.class != Class::Pedestrian) {
                continue;
            }
            let mut r = rects[j];
            let mut anticipated = false;
            // A pedestrian on the road keeps out of the lane just ahead of a moving vehicle.
            if ped_on_road && o.class != Class::Pedestrian && o.v > 0.1 {
                let ext = 0.5 * (1.0 + 1.5 * o.v);
                r.center += r.dir * ext;
                r.half_l += ext;
                anticipated = true;
            }
            // Vehicles anticipate a crossing pedestrian: it occupies where it will walk in
            // the next few seconds, unless that area is already under the vehicle (then the
            // pedestrian waits for it; see `ped_on_road`).
            if !is_ped
                && let Role::Pedestrian { started: true, far_s, .. } = &o.role
                && o.s < *far_s
            {
                let ext = 0.5 * o.v_desired * PED_ANTICIPATION_S;
                let mut long = r;
                long.center += r.dir * ext;
                long.half_l += ext;
                let now = Rect { half_w: me.half_w + MARGIN_M, ..me };
                if !now.overlaps(&long) {
                    r = long;
                    anticipated = true;
                }
            }
            let reach = me.radius() + r.radius() + MARGIN_M;
            if (r.center - me.center).length() > lookahead + reach + 1.0 {
                continue;
            }
            // Coarse: the path sample nearest to the other's centre.
            let (mut best, mut kb) = (f32::INFINITY, k0);
            let mut k = k0;
            while k <= k1 {
                let d = (path.points[k] - r.center).length_squared();
                if d < best {
                    best = d;
                    kb = k;
                }
                k += 4;
            }
            if best.sqrt() > reach + 4.0 * DS {
                continue;
            }
            let w = ((reach / DS).ceil() as usize) + 4 + if anticipated { (r.half_l / DS) as usize } else { 0 };
            let (lo_k, hi_k) = (kb.saturating_sub(w).max(k0), (kb + w).min(k1));
            if let Some(gap) = Self::first_contact(path, &me, a.s, &r, lo_k, hi_k) {
                // The real footprint bounds how far the road user may move this step.
                let real = if anticipated {
                    Self::first_contact(path, &me, a.s, &rects[j], k0, k1).unwrap_or(f32::INFINITY)
                } else {
                    gap
                };
                let along = o.v * rects[j].dir.dot(path.at(a.s + gap).1);
                hits.push(Hit { gap, v_along: along, other: j, real_gap: real });
            }
        }
        hits
    }

    /// Whether a pedestrian stepping onto `a`–`b` now could be reached by a vehicle within
    /// `horizon_s` seconds.
    fn vehicles_threaten(&self, a: Vec2, b: Vec2, horizon_s: f32) -> bool {
        self.agents.iter().any(|o| {
            let Role::Vehicle { route, .. } = &o.role else { return false };
            let path = &self.routes[*route].path;
            let (from, to) = (o.s - 0.5 * o.length, o.s + 0.5 * o.length + o.v * horizon_s + 0.3);
            let mut s = from;
            while s <= to {
                let (p, _) = path.at(s);
                if point_segment_distance(p, a, b) < 0.5 * o.width + 0.8 {
                    return true;
                }
                s += 0.5;
            }
            false
        })
    }

    /// Time for a vehicle to reach arc length `target` from rest-aware kinematics.
    fn time_to(o: &Agent, d: f32) -> f32 {
        if d <= 0.0 {
            return 0.0;
        }
        let acc = class_model(o.class).a;
        ((o.v * o.v + 2.0 * acc * d).sqrt() - o.v) / acc
    }

    /// Whether a vehicle inside the junction still occupies part of `route`'s path through it.
    fn junction_blocked(&self, me: usize, route: usize) -> bool {
        self.agents.iter().enumerate().any(|(j, o)| {
            let Role::Vehicle { route: rb, .. } = &o.role else { return false };
            if j == me {
                return false;
            }
            let Some(exit) = self.conflicts[route][*rb] else { return false };
            o.s + 0.5 * o.length > self.routes[*rb].stop_s && o.s - 0.5 * o.length < exit
        })
    }

    /// Whether a pedestrian on one of the crosswalks `route` crosses (ahead of the vehicle) is
    /// close enough to its crossing to reach it before the vehicle has passed.
    fn crosswalk_busy(&self, me: &Agent, route: usize) -> bool {
        let r = &self.routes[route];
        let front = me.s + 0.5 * me.length;
        r.crosswalks.iter().any(|&(arm, s_in, s_out)| {
            if front > s_in {
                return false;
            }
            let t_clear = (s_out - s_in + me.length + (s_in - front)) / me.v.max(2.0);
            let reach = 1.5 + 1.5 * t_clear;
            self.agents.iter().any(|o| match &o.role {
                Role::Pedestrian { arm: pa, started: true, far_s, jaywalk: false, .. }
                    if *pa == arm && o.s < *far_s =>
                {
                    let c = self.rect(o).center;
                    let mut s = s_in;
                    while s <= s_out {
                        if r.path.at(s).0.distance(c) < reach + 0.5 * me.width {
                            return true;
                        }
                        s += 1.0;
                    }
                    false
                }
                _ => false,
            })
        })
    }

    /// Whether a permissive left turn from `route` can go now.
    fn left_gap_ok(&self, route: usize, critical_gap_s: f32) -> bool {
        let r = &self.routes[route];
        let opposing = self.plan.opposing(r.approach);
        for o in &self.agents {
            match &o.role {
                Role::Vehicle { route: orr, .. } => {
                    let or = &self.routes[*orr];
                    if !opposing.contains(&or.approach) || or.movement == Movement::Left {
                        continue;
                    }
                    let front = o.s + 0.5 * o.length;
                    if front < or.stop_s {
                        if Self::time_to(o, or.stop_s - front) < critical_gap_s {
                            return false;
                        }
                    } else if o.s - 0.5 * o.length < or.clear_s {
                        return false;
                    }
                }
                Role::Pedestrian { arm, started, far_s, .. } => {
                    // Pedestrians on the exit crosswalk would hold the turner inside the junction.
                    if *arm == r.exit && *started && o.s < *far_s + 0.5 {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// Advances one step.
    pub fn step(&mut self) {
        let dt = self.cfg.step_s as f32;
        let st = self.signal_t();
        let rects: Vec<Rect> = self.agents.iter().map(|a| self.rect(a)).collect();
        let n = self.agents.len();
        // Obstacles per road user.
        let mut hits: Vec<Vec<Hit>> = (0..n)
            .map(|i| {
                let a = &self.agents[i];
                let look = match &a.role {
                    Role::Pedestrian { .. } => 3.0,
                    Role::Vehicle { route, .. } => {
                        let r = &self.routes[*route];
                        let base = 12.0 + 5.0 * a.v;
                        // Near the stop line, look through the junction (do not block the box).
                        let to_clear = r.clear_s + 0.5 * a.length + 2.0 - a.s;
                        if r.stop_s - (a.s + 0.5 * a.length) < 40.0 { base.max(to_clear) } else { base }
                    }
                };
                self.sweep(i, &rects, look.min(120.0))
            })
            .collect();
        // Crossing conflicts: whoever can no longer stop comfortably goes first, otherwise the
        // one nearer to the conflict.
        let must_go = |k: usize, gap: f32| {
            let a = &self.agents[k];
            a.v * a.v / (2.0 * class_model(a.class).b) > gap
        };
        let original = hits.clone();
        for (i, mine) in hits.iter_mut().enumerate() {
            for hit in mine.iter_mut() {
                let (gi, j) = (hit.gap, hit.other);
                if let Some(gj) = original[j].iter().find(|x| x.other == i).map(|x| x.gap) {
                    let (mi, mj) = (must_go(i, gi), must_go(j, gj));
                    let i_first =
                        if mi != mj { mi } else { gi < gj || (gi == gj && self.agents[i].id < self.agents[j].id) };
                    if i_first {
                        hit.gap = f32::INFINITY;
                    }
                }
            }
        }
        let mut accel = vec![0.0f32; n];
        let mut commit = vec![false; n];
        let mut yellow = vec![None; n];
        let mut start = vec![false; n];
        for i in 0..n {
            let a = &self.agents[i];
            let m = class_model(a.class);
            let (mut gap, mut v_obst) = hits[i]
                .iter()
                .filter(|h| h.gap.is_finite())
                .map(|h| (h.gap, h.v_along))
                .min_by(|x, y| x.0.total_cmp(&y.0))
                .unwrap_or((f32::INFINITY, 0.0));
            let mut v0 = a.v_desired;
            let front = a.s + 0.5 * a.length;
            match &a.role {
                Role::Vehicle { route, yellow_stop, committed, critical_gap_s } => {
                    let r = &self.routes[*route];
                    v0 = v0.min(r.v_cap_at(a.s + 0.5 * a.length + 3.0));
                    yellow[i] = *yellow_stop;
                    if front <= r.stop_s + 0.05 {
                        let mut hold = match self.plan.light(r.approach, r.movement, st) {
                            Light::Red => true,
                            Light::Yellow => {
                                let stop = yellow_stop.unwrap_or_else(|| {
                                    // Go only if stopping would be uncomfortable and the line
                                    // is reached before red (slowing for a turn counts).
                                    let d = r.stop_s - front;
                                    let v_line = a.v.min(r.v_cap_at(r.stop_s));
                                    let arrive = d / (0.5 * (a.v + v_line)).max(0.1);
                                    let left = self.plan.yellow_left(r.approach, r.movement, st).unwrap_or(0.0) as f32;
                                    d >= a.v * a.v / (2.0 * m.b) + 0.5 || arrive > left - 0.2
                                });
                                yellow[i] = Some(stop);
                                stop
                            }
                            Light::Green { protected } => {
                                yellow[i] = None;
                                if protected || *committed {
                                    false
                                } else if self.left_gap_ok(*route, *critical_gap_s) {
                                    commit[i] = r.stop_s - front < 3.0;
                                    false
                                } else {
                                    true
                                }
                            }
                        };
                        // Yield to vehicles still inside the junction on a crossing path, while
                        // there is room to stop.
                        // A vehicle that chose to go on yellow is not held by anything but red.
                        let can_stop = r.stop_s - front >= a.v * a.v / (2.0 * m.b) - 0.5 && yellow[i] != Some(false);
                        if !hold && can_stop && self.junction_blocked(i, *route) {
                            hold = true;
                        }
                        // Yield to pedestrians on a crosswalk near the route's crossing.
                        if !hold && can_stop && self.crosswalk_busy(a, *route) {
                            hold = true;
                        }
                        // Do not enter the junction without room to leave it.
                        if !hold
                            && gap.is_finite()
                            && a.s + gap < r.clear_s + 0.5 * a.length + 1.0
                            && a.s + gap > r.stop_s - 0.5 * a.length
                            && v_obst < 2.0
                        {
                            hold = true;
                        }
                        if hold {
                            let g = r.stop_s - front - STOP_LINE_GAP_M + m.s0;
                            if g < gap {
                                gap = g.max(0.0);
                                v_obst = 0.0;
                            }
                        }
                    }
                }
                Role::Pedestrian { path, curb_s, far_s, arm, jaywalk, started } => {
                    if !*started && front >= *curb_s - 0.6 {
                        let (p_a, _) = path.at(*curb_s);
                        let (p_b, _) = path.at(*far_s);
                        let cross_len = *far_s - *curb_s;
                        let cross_time = cross_len / a.v_desired.max(0.5);
                        let may = if *jaywalk {
                            true
                        } else {
                            self.plan.walk(*arm, st).is_some_and(|rem| rem as f32 >= cross_time + 2.0)
                        };
                        let horizon = if *jaywalk { cross_time + 2.0 } else { 4.0 };
                        if may && !self.vehicles_threaten(p_a, p_b, horizon) {
                            start[i] = true;
                        } else {
                            let g = *curb_s - front + m.s0;
                            if g < gap {
                                gap = g.max(0.0);
                                v_obst = 0.0;
                            }
                        }
                    }
                }
            }
            // IDM.
            let free = 1.0 - (a.v / v0.max(0.1)).powi(4);
            let inter = if gap.is_finite() {
                let s_star = m.s0 + (a.v * m.headway_s + a.v * (a.v - v_obst) / (2.0 * (m.a * m.b).sqrt())).max(0.0);
                (s_star / gap.max(0.01)).powi(2)
            } else {
                0.0
            };
            accel[i] = (m.a * (free - inter)).clamp(-m.b_max, m.a);
            hits[i].retain(|h| h.gap.is_finite());
        }
        // Integrate.
        let old_s: Vec<f32> = self.agents.iter().map(|a| a.s).collect();
        let old_v: Vec<f32> = self.agents.iter().map(|a| a.v).collect();
        for i in 0..n {
            let acc = accel[i];
            let a = &mut self.agents[i];
            let v_new = (a.v + acc * dt).max(0.0);
            let travel = if v_new == 0.0 && acc < 0.0 {
                (a.v * a.v / (2.0 * -acc)).min(a.v * dt)
            } else {
                0.5 * (a.v + v_new) * dt
            };
            let limit = hits[i].iter().map(|h| h.real_gap).fold(f32::INFINITY, f32::min);
            let (travel, v_new) = if travel > limit {
                self.clamps += 1;
                (limit.max(0.0), (a.v - class_model(a.class).b_max * dt).max(0.0).min(v_new))
            } else {
                (travel, v_new)
            };
            a.s += travel;
            a.a = (v_new - a.v) / dt;
            a.v = v_new;
            match &mut a.role {
                Role::Vehicle { yellow_stop, committed, .. } => {
                    *yellow_stop = yellow[i];
                    *committed |= commit[i];
                }
                Role::Pedestrian { started, .. } => *started |= start[i],
            }
        }
        // Guarantee: nobody ends a step overlapping another road user. Whoever moved into an
        // overlap goes back to where it was (an emergency stop), until none is left; the state
        // before the step had no overlap, so this ends.
        let moved: Vec<bool> = (0..n).map(|i| self.agents[i].s != old_s[i]).collect();
        let mut reverted = vec![false; n];
        loop {
            let rects: Vec<Rect> = self.agents.iter().map(|a| self.rect(a)).collect();
            let mut changed = false;
            for i in 0..n {
                if !moved[i] || reverted[i] {
                    continue;
                }
                let hit = (0..n).any(|j| {
                    j != i
                        && rects[i].center.distance(rects[j].center) < rects[i].radius() + rects[j].radius()
                        && rects[i].overlaps(&rects[j])
                });
                if hit {
                    let a = &mut self.agents[i];
                    a.s = old_s[i];
                    a.v = (old_v[i] - class_model(a.class).b_max * dt).max(0.0);
                    a.a = (a.v - old_v[i]) / dt;
                    reverted[i] = true;
                    self.clamps += 1;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        // Leave at the end of the path.
        let routes = &self.routes;
        self.agents.retain(|a| {
            let len = match &a.role {
                Role::Vehicle { route, .. } => routes[*route].path.length(),
                Role::Pedestrian { path, .. } => path.length(),
            };
            a.s + 0.5 * a.length < len
        });
        self.steps += 1;
        self.t = self.steps as f64 * self.cfg.step_s - self.warm_s;
        self.spawn();
    }

    fn spawn(&mut self) {
        let now = self.signal_t();
        // Vehicle arrivals join the queue of their route.
        for ap in 0..self.approach_rate.len() {
            while self.next_arrival[ap] <= now {
                self.next_arrival[ap] = next_arrival(&mut self.rng, self.next_arrival[ap], self.approach_rate[ap]);
                let u: f64 = self.rng.random();
                let want = if u < self.cfg.left_share {
                    Movement::Left
                } else if u < self.cfg.left_share + self.cfg.right_share {
                    Movement::Right
                } else {
                    Movement::Through
                };
                let mut cands: Vec<usize> = self
                    .routes
                    .iter()
                    .enumerate()
                    .filter(|(_, r)| r.approach == ap && r.movement == want)
                    .map(|(k, _)| k)
                    .collect();
                if cands.is_empty() {
                    cands = self
                        .routes
                        .iter()
                        .enumerate()
                        .filter(|(_, r)| r.approach == ap && r.movement == Movement::Through)
                        .map(|(k, _)| k)
                        .collect();
                }
                if cands.is_empty() {
                    continue;
                }
                let route = cands[self.rng.random_range(0..cands.len())];
                let class = self.draw_class();
                let m = class_model(class);
                let size =
                    (sample(&mut self.rng, m.length), sample(&mut self.rng, m.width), sample(&mut self.rng, m.height));
                let speed_limit = self.speed_limits[ap];
                let factor = Normal::new(1.0f32, 0.08).map(|d| d.sample(&mut self.rng)).unwrap_or(1.0).clamp(0.8, 1.15);
                let v_desired = (speed_limit * factor).min(m.v_max);
                let critical_gap_s = self.rng.random_range(4.0..6.0);
                self.pending[route].push(PendingVehicle { class, size, v_desired, critical_gap_s });
            }
        }
        // Footprints of everyone present, kept in step with `agents` as road users enter.
        let mut rects: Vec<Rect> = self.agents.iter().map(|a| self.rect(a)).collect();
        for route in 0..self.pending.len() {
            if self.pending[route].is_empty() {
                continue;
            }
            let p = self.pending[route][0].clone();
            let m = class_model(p.class);
            let s = 0.5 * p.size.0;
            let probe = Agent {
                id: u32::MAX,
                class: p.class,
                length: p.size.0,
                width: p.size.1,
                height: p.size.2,
                v_desired: p.v_desired,
                s,
                v: 0.0,
                a: 0.0,
                role: Role::Vehicle { route, yellow_stop: None, committed: false, critical_gap_s: p.critical_gap_s },
            };
            rects.push(self.rect(&probe));
            self.agents.push(probe);
            let i = self.agents.len() - 1;
            let hit = self.sweep(i, &rects, 80.0).into_iter().min_by(|x, y| x.gap.total_cmp(&y.gap));
            let (gap, v_lead) = hit.map_or((f32::INFINITY, 0.0), |h| (h.gap, h.v_along));
            if gap < m.s0 + 1.0 {
                self.agents.pop();
                rects.pop();
                continue;
            }
            // Enter at a speed the gap allows (IDM equilibrium-ish, never faster than the leader
            // can be followed safely).
            let safe = ((gap - m.s0) / m.headway_s).max(0.0);
            let v = p.v_desired.min(self.routes[route].v_cap_at(s)).min(if gap.is_finite() {
                safe.min(v_lead.max(0.0) + safe * 0.5)
            } else {
                f32::INFINITY
            });
            let id = self.next_id;
            self.next_id += 1;
            if let Some(a) = self.agents.last_mut() {
                a.id = id;
                a.v = v;
            }
            self.pending[route].remove(0);
        }
        // Pedestrians.
        let ped = class_model(Class::Pedestrian);
        for k in 0..self.ped_sources.len() {
            let rate = if self.ped_sources[k].jaywalk {
                self.cfg.pedestrians_per_hour * self.cfg.jaywalk_share
            } else {
                self.cfg.pedestrians_per_hour * (1.0 - self.cfg.jaywalk_share)
            };
            while self.ped_sources[k].next_arrival_s <= now {
                self.ped_sources[k].next_arrival_s =
                    next_arrival(&mut self.rng, self.ped_sources[k].next_arrival_s, rate);
                self.ped_sources[k].pending += 1;
            }
            if self.ped_sources[k].pending == 0 {
                continue;
            }
            let slot = self.rng.random_range(0..self.ped_sources[k].paths.len());
            let (path, curb_s, far_s) = self.ped_sources[k].paths[slot].clone();
            let start = path.points[0];
            let free = self
                .agents
                .iter()
                .zip(&rects)
                .all(|(o, r)| (r.center - start).length() > 1.2 + 0.5 * o.length.max(o.width));
            if !free {
                continue;
            }
            self.ped_sources[k].pending -= 1;
            let size = (
                sample(&mut self.rng, ped.length),
                sample(&mut self.rng, ped.width),
                sample(&mut self.rng, ped.height),
            );
            let v_desired =
                Normal::new(1.35f32, 0.2).map(|d| d.sample(&mut self.rng)).unwrap_or(1.35).clamp(0.8, ped.v_max);
            let id = self.next_id;
            self.next_id += 1;
            let (arm, jaywalk) = (self.ped_sources[k].arm, self.ped_sources[k].jaywalk);
            let walker = Agent {
                id,
                class: Class::Pedestrian,
                length: size.0,
                width: size.1,
                height: size.2,
                v_desired,
                s: 0.5 * size.0,
                v: 0.0,
                a: 0.0,
                role: Role::Pedestrian { path, curb_s, far_s, arm, jaywalk, started: false },
            };
            rects.push(self.rect(&walker));
            self.agents.push(walker);
        }
    }

    fn draw_class(&mut self) -> Class {
        let total: f64 = self.cfg.class_mix.values().sum();
        let mut u = self.rng.random::<f64>() * total;
        for (name, w) in &self.cfg.class_mix {
            if u < *w {
                return name.parse().unwrap_or(Class::Car);
            }
            u -= w;
        }
        Class::Car
    }
}

/// Pedestrian paths: per arm with a crosswalk, two directions with waiting slots on the
/// junction-side and outer halves of the crosswalk (so opposing streams never meet), and a
/// jaywalking source mid-block. Pedestrians appear on and leave from the sidewalks next to
/// the crosswalk; paths never cross other streams' paths, so pedestrians only ever queue.
fn pedestrian_sources(layout: &Layout) -> Vec<PedSource> {
    let mut out = Vec::new();
    for (i, arm) in layout.arms.iter().enumerate() {
        let sw = arm.sidewalks.first().map_or(0.0, |p| (p[3] - p[0]).dot(arm.normal).abs());
        let w = crosswalk_width(arm);
        if sw < 1.2 || w < 2.6 {
            continue;
        }
        let at = |a: f32, l: f32| arm.dir * a + arm.normal * l;
        let (c0, ein, eout) = (cw0(arm), arm.edge_in_m, arm.edge_out_m);
        let half = 0.5 * w;
        // Slots 1 m apart keep side-by-side pedestrians clear of each other's sweep; each slot
        // has its own lane on the sidewalks (1 m apart too), so paths never cross.
        let by_width = ((half - 0.95) / 1.0).floor() as usize + 1;
        let by_sidewalk = ((sw - 0.35 - 0.75) / 1.0).floor() as usize + 1;
        let n_slots = by_width.min(by_sidewalk).max(1);
        let mut inward = Vec::new();
        let mut outward = Vec::new();
        for k in 0..n_slots {
            let u_in = 0.45 + 1.0 * k as f32;
            let u_out = w - 0.45 - 1.0 * k as f32;
            let lane = 0.75 + 1.0 * k as f32;
            // Inbound side → outbound side on the junction half, straight over the sidewalks
            // (paths to the corners would cross the neighbouring arm's pedestrians).
            let p = [
                at(c0 + u_in, ein + sw - 0.35),
                at(c0 + u_in, ein + 0.4),
                at(c0 + u_in, eout - 0.4),
                at(c0 + u_in, eout - sw + 0.35),
            ];
            outward.push(with_curbs(&p, &[]));
            // Outbound side → inbound side on the outer half, along the sidewalks.
            let q = [
                at(c0 + u_out + 12.0, eout - lane),
                at(c0 + u_out, eout - 0.4),
                at(c0 + u_out, ein + 0.4),
                at(c0 + u_out + 12.0, ein + lane),
            ];
            let (turn_a, turn_b) = (at(c0 + u_out, eout - lane), at(c0 + u_out, ein + lane));
            inward.push(with_curbs(&q, &[turn_a, turn_b]));
        }
        out.push(PedSource { arm: i, paths: outward, next_arrival_s: 0.0, pending: 0, jaywalk: false });
        out.push(PedSource { arm: i, paths: inward, next_arrival_s: 0.0, pending: 0, jaywalk: false });
        // Jaywalkers: straight across, 15–45 m beyond the stop line (clear of the crosswalk
        // streams on the sidewalks).
        let len = arm.road[1].dot(arm.dir);
        let mut jw = Vec::new();
        for k in 0..4 {
            let a = arm.stop_line_at_m + 15.0 + 10.0 * k as f32;
            if a + 2.0 > len {
                break;
            }
            let (p, q) = if k % 2 == 0 { (ein, eout) } else { (eout, ein) };
            let side = |l: f32| if l > 0.0 { l + 0.5 * sw } else { l - 0.5 * sw };
            let curb = |l: f32| if l > 0.0 { l + 0.4 } else { l - 0.4 };
            jw.push(with_curbs(&[at(a + 3.0, side(p)), at(a, curb(p)), at(a, curb(q)), at(a - 3.0, side(q))], &[]));
        }
        if !jw.is_empty() {
            out.push(PedSource { arm: i, paths: jw, next_arrival_s: 0.0, pending: 0, jaywalk: true });
        }
    }
    out
}

/// The footprint of a road user whose centre is at arc length `s`: front and rear on the path
/// (like axles following it), so long vehicles cut into curves instead of swinging out. Before
/// the path's start the first direction is extended backwards.
pub fn footprint(path: &Path, s: f32, half_l: f32, half_w: f32) -> Rect {
    let point = |x: f32| {
        if x >= 0.0 {
            path.at(x).0
        } else {
            let (p, d) = path.at(0.0);
            p + d * x
        }
    };
    let (f, r) = (point(s + half_l), point(s - half_l));
    let dir = (f - r).normalize_or(path.at(s).1);
    Rect { center: 0.5 * (f + r), dir, half_l, half_w }
}

/// A pedestrian path through `p` (sidewalk, curb, far curb, sidewalk) with optional corner
/// points `[before the curb, after the far curb]`, and the arc lengths of the two curbs.
fn with_curbs(p: &[Vec2; 4], turns: &[Vec2]) -> (Path, f32, f32) {
    let poly: Vec<Vec2> = match turns {
        [a, b] => vec![p[0], *a, p[1], p[2], *b, p[3]],
        _ => p.to_vec(),
    };
    let path = Path::from_polyline(&poly);
    let k = if turns.len() == 2 { 2 } else { 1 };
    let curb: f32 = poly[..=k].windows(2).map(|w| (w[1] - w[0]).length()).sum();
    (path, curb, curb + (poly[k + 1] - poly[k]).length())
}
