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
//! At a roundabout (the layout's ring) no signal runs: entering vehicles yield to the ring's
//! traffic at the yield line by gap acceptance, drivers
//! keep its crosswalks clear, and pedestrians cross them whenever no vehicle is about to reach
//! them, with the right of way once on them.
//!
//! Vehicles parked at the curb ([`ParkingConfig`]) stand in bays of the arms' parking lanes and
//! come and go between scenes (and, rarely, within one).
//!
//! What it leaves out, on purpose: lane changes (vehicles keep the lane they enter on), right
//! turns on red, cyclists, parking manoeuvres, and lateral dynamics (road users are on their path's
//! centreline, heading along its tangent). The sensors see boxes, so none of this changes what a
//! detector has to learn beyond the mix of poses and speeds, which the model covers.
//!
//! Arrivals are the study's rates, or a named demand level's ([`Demand`]), which [`demand`] derives
//! from each approach's capacity. Turning vehicles wait out the pedestrians on the crosswalk they
//! cross longer than drivers do, so over many signal cycles an approach's outermost lane
//! saturates below that capacity ([`demand`] says by how much); a scene's 20 s do not reach it.
//!
//! The traffic depends only on the scene, the [`TrafficConfig`] and the seed.

pub mod demand;
pub mod geom;
mod obstacles;
mod parking;
pub mod routes;
pub mod signal;
mod spawn;
mod step;

use crate::error::DatasetError;
pub use demand::Demand;
use geom::{Rect, point_segment_distance};
use glam::Vec2;
use hilo_core::{Box3, Class};
use hilo_raycast::scene::layout::{ArmLayout, Layout};
pub use parking::{BayState, PARKED_ID_BASE, ParkingConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Exp, Normal};
use routes::{
    Crossing, DS, Movement, Path, Route, build_routes, crosswalk_width, cw0, junction_conflicts, spawned_movement,
};
use serde::{Deserialize, Serialize};
use signal::{Light, SignalConfig, SignalPlan};
use spawn::pedestrian_sources;
use std::collections::BTreeMap;

/// Traffic settings (`[traffic]` in a study file).
#[derive(Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct TrafficConfig {
    /// A named level of demand ([`Demand`]): sets each approach's vehicle rate from its
    /// capacity and the pedestrian rate, in place of `vehicles_per_hour` and
    /// `pedestrians_per_hour` (per-approach overrides still apply). None: the rates as written.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub demand: Option<Demand>,
    /// Vehicle arrivals per approach (Poisson).
    pub vehicles_per_hour: f64,
    /// Per-approach overrides by arm name.
    pub approach_vehicles_per_hour: BTreeMap<String, f64>,
    /// Turning shares of arriving vehicles (the rest go straight).
    pub left_share: f64,
    pub right_share: f64,
    /// Relative frequencies of the vehicle classes (car, truck, bus, motorcycle, golf_cart, and
    /// bicycle: cyclists ride the roadway with the vehicles, none by default).
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
    /// Vehicles parked in the arms' parking lanes, coming and going ([`ParkingConfig`]); none
    /// when absent.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub parking: Option<ParkingConfig>,
}

impl Default for TrafficConfig {
    fn default() -> Self {
        let class_mix = [("car", 0.74), ("truck", 0.06), ("bus", 0.03), ("motorcycle", 0.05), ("golf_cart", 0.12)]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect();
        TrafficConfig {
            demand: None,
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
            parking: None,
        }
    }
}

/// The derived form, with `demand` and `parking` only when they are set: the Debug form that
/// stage hashes take is the same as before either existed for a study without them.
impl std::fmt::Debug for TrafficConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("TrafficConfig");
        if let Some(level) = &self.demand {
            d.field("demand", level);
        }
        d.field("vehicles_per_hour", &self.vehicles_per_hour)
            .field("approach_vehicles_per_hour", &self.approach_vehicles_per_hour)
            .field("left_share", &self.left_share)
            .field("right_share", &self.right_share)
            .field("class_mix", &self.class_mix)
            .field("pedestrians_per_hour", &self.pedestrians_per_hour)
            .field("jaywalk_share", &self.jaywalk_share)
            .field("warmup_s", &self.warmup_s)
            .field("step_s", &self.step_s)
            .field("signal", &self.signal);
        if let Some(p) = &self.parking {
            d.field("parking", p);
        }
        d.finish()
    }
}

fn invalid(field: &str, value: impl std::fmt::Display, why: &str) -> DatasetError {
    DatasetError::setting(format!("traffic.{field}"), value, why)
}

/// Checks a class mix named `field`: known classes, pedestrians refused (`pedestrian_why`),
/// finite shares ≥ 0. Returns the shares' sum.
fn check_class_mix(field: &str, mix: &BTreeMap<String, f64>, pedestrian_why: &str) -> Result<f64, DatasetError> {
    let mut total = 0.0;
    for (name, w) in mix {
        let f = format!("{field}.{name}");
        let c: Class = name
            .parse()
            .map_err(|_| invalid(&f, w, "unknown class (car, truck, bus, motorcycle, golf_cart, bicycle)"))?;
        if c == Class::Pedestrian {
            return Err(invalid(&f, w, pedestrian_why));
        }
        if !(w.is_finite() && *w >= 0.0) {
            return Err(invalid(&f, w, "must be a finite number ≥ 0"));
        }
        total += w;
    }
    Ok(total)
}

/// A class drawn from a checked class mix by its relative shares; None only when rounding
/// leaves the draw past the last share.
fn draw_from(rng: &mut ChaCha8Rng, mix: &BTreeMap<String, f64>) -> Option<Class> {
    let total: f64 = mix.values().sum();
    let mut u = rng.random::<f64>() * total;
    for (name, w) in mix {
        if u < *w {
            return name.parse().ok();
        }
        u -= w;
    }
    None
}

impl TrafficConfig {
    /// The classes this traffic can carry, for a dataset's category table ([`Self::carries`]).
    pub fn classes(&self) -> Vec<Class> {
        Class::ALL.into_iter().filter(|&c| self.carries(c)).collect()
    }

    /// Whether this traffic can carry class `c`: each of the paper's six, and the cyclist when a
    /// class mix (moving or parked) gives it a positive share.
    pub fn carries(&self, c: Class) -> bool {
        let mut mixes = std::iter::once(&self.class_mix).chain(self.parking.as_ref().map(|p| &p.class_mix));
        Class::PAPER.contains(&c) || mixes.any(|m| m.get(c.name()).is_some_and(|w| *w > 0.0))
    }

    /// Pedestrian arrivals per crosswalk and direction: the level's when `demand` is set.
    pub fn pedestrian_rate(&self) -> f64 {
        self.demand.map_or(self.pedestrians_per_hour, Demand::pedestrians_per_hour)
    }

    /// Arrivals per hour of one pedestrian source: its share of [`Self::pedestrian_rate`], the
    /// jaywalkers' or the crosswalk users'.
    fn pedestrian_source_rate(&self, jaywalk: bool) -> f64 {
        let share = if jaywalk { self.jaywalk_share } else { 1.0 - self.jaywalk_share };
        self.pedestrian_rate() * share
    }

    /// Checks every field; errors name the field and value.
    pub fn validate(&self, layout: &Layout) -> Result<(), DatasetError> {
        let nonneg = |f: &str, v: f64| {
            if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(invalid(f, v, "must be a finite number ≥ 0")) }
        };
        nonneg("vehicles_per_hour", self.vehicles_per_hour)?;
        nonneg("pedestrians_per_hour", self.pedestrians_per_hour)?;
        if let Some(level) = self.demand {
            let d = TrafficConfig::default();
            for (f, v, default) in [
                ("vehicles_per_hour", self.vehicles_per_hour, d.vehicles_per_hour),
                ("pedestrians_per_hour", self.pedestrians_per_hour, d.pedestrians_per_hour),
            ] {
                if v != default {
                    return Err(invalid(
                        f,
                        v,
                        &format!(
                            "demand = \"{}\" sets this rate; give either the level or the rates \
                             (approach_vehicles_per_hour may refine a level)",
                            level.name()
                        ),
                    ));
                }
            }
        }
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
        let total =
            check_class_mix("class_mix", &self.class_mix, "pedestrians have their own rate, pedestrians_per_hour")?;
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
        if let Some(p) = &self.parking {
            p.validate(layout)?;
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
        // A bicycle with its rider: a 1.75 m bicycle, the box up to the rider's head; an urban
        // cyclist's cruising speed of about 20 km/h, gentle acceleration and braking.
        Class::Bicycle => ClassModel {
            length: (1.75, 0.08, 1.6, 1.95),
            width: (0.65, 0.05, 0.55, 0.8),
            height: (1.70, 0.08, 1.5, 1.9),
            v_max: 5.5,
            a: 1.0,
            b: 1.5,
            headway_s: 1.0,
            s0: 1.5,
            b_max: 3.5,
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

impl ActorState {
    /// The road user as the ray engine sees it: its box, moving at its velocity (on the ground
    /// plane), for simulating sensors.
    pub fn actor(&self) -> hilo_raycast::Actor {
        hilo_raycast::Actor::from_box(self.id, self.class, self.box3).with_velocity(self.velocity_mps.extend(0.0))
    }
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
    /// At a roundabout, `ring[a][b]`: where on route b a circulating vehicle passes route a's
    /// merge point ([`routes::ring_conflicts`]); empty elsewhere.
    ring: Vec<Vec<Option<f32>>>,
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
    /// Parked vehicles, with their own random stream.
    parking: Option<parking::Parking>,
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
        let speeds: Vec<f32> = layout.arms.iter().map(|a| a.speed_limit_mps).collect();
        let plan = signal::plan_for(layout, &cfg.signal);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let level = cfg.demand.map(|d| demand::level_rates(layout, &routes, &plan, cfg, d));
        let approach_rate: Vec<f64> = layout
            .arms
            .iter()
            .enumerate()
            .map(|(i, a)| {
                let base = level.as_ref().map_or(cfg.vehicles_per_hour, |l| l[i].vehicles_per_hour);
                if routes.iter().any(|r| r.approach == i) {
                    cfg.approach_vehicles_per_hour.get(&a.name).copied().unwrap_or(base)
                } else {
                    0.0
                }
            })
            .collect();
        let next_arrival_v = approach_rate.iter().map(|&q| next_arrival(&mut rng, 0.0, q)).collect();
        let mut ped_sources = pedestrian_sources(layout);
        for src in &mut ped_sources {
            src.next_arrival_s = next_arrival(&mut rng, 0.0, cfg.pedestrian_source_rate(src.jaywalk));
        }
        let n_routes = routes.len();
        let conflicts = junction_conflicts(&routes, 3.2);
        let ring = if layout.ring.is_some() { routes::ring_conflicts(&routes, 2.0) } else { Vec::new() };
        let mut traffic = Traffic {
            cfg: cfg.clone(),
            routes,
            conflicts,
            ring,
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
            parking: cfg.parking.as_ref().map(|p| parking::Parking::new(layout, p, seed)),
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

    /// Vehicle arrivals per hour of each approach (by arm), as the traffic runs them.
    pub fn approach_rates(&self) -> &[f64] {
        &self.approach_rate
    }

    /// Vehicles that have arrived but not yet found room to enter their lane: a queue beyond
    /// the scene's end of the arm, which grows without bound when demand exceeds capacity.
    pub fn waiting_to_enter(&self) -> usize {
        self.pending.iter().map(Vec::len).sum()
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

    /// Every parking bay now (none without `[traffic.parking]`).
    pub fn parking_bays(&self) -> Vec<BayState> {
        self.parking.as_ref().map(|p| p.bays().collect()).unwrap_or_default()
    }

    /// Every road user now: the moving ones, then the parked vehicles.
    pub fn snapshot(&self) -> Vec<ActorState> {
        let parked = self.parking.iter().flat_map(|p| p.snapshot(self.ground_z));
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
                        let attr = if matches!(a.class, Class::Motorcycle | Class::Bicycle) {
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
            .chain(parked)
            .collect()
    }
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
