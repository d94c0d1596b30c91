//! Curbside parking: vehicles that stand in an arm's parking lane for minutes to hours, and come
//! and go.
//!
//! Each arm with a parking lane (`parking_lane_width_m` in the scene file) is divided into bays
//! of `bay_length_m` on both curb sides, from `clear_of_crosswalk_m` beyond the crosswalk to the
//! arm's end, leaving a gap where jaywalkers cross (they step out between parked cars). Each bay
//! is an alternating renewal process: a vehicle stays an exponential time of mean
//! `mean_stay_s`, the bay then stays empty an exponential time whose mean makes `occupancy` the
//! long-run share of the time it is taken. A scene starts from that long-run state (each bay
//! taken with probability `occupancy`, its remaining time exponential, which a memoryless stay
//! allows), so scenes drawn at different seeds see different bays taken, as a background model
//! learned over hours of a real junction does.
//!
//! A parked vehicle stands parallel to the curb, facing the adjacent lane's traffic, 0.1–0.3 m
//! from the curb, anywhere in its bay that leaves 0.2 m to the next. It is annotated as nuScenes
//! does: its class, zero velocity, `vehicle.parked` (a motorcycle `cycle.without_rider`).
//!
//! Left out, on purpose: the manoeuvres. A vehicle appears in its bay, or leaves it, between two
//! time steps; it does not pull in from the lane or out into it, so moving traffic never yields
//! to it and a departure is never a moving road user. With a mean stay of half an hour, a bay of
//! a 20 s scene changes hands about once in 90 scenes. Parked vehicles draw from their own random
//! stream and ids, and stand outside the lanes, the crosswalks and the jaywalkers' paths: the
//! moving traffic of a seed is the same with parking as without it.

use super::*;
use crate::traffic::spawn::jaywalk_lines;

/// Curbside parking (`[traffic.parking]` in a study file); see the module's documentation.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ParkingConfig {
    /// Long-run share of the bays that hold a vehicle.
    pub occupancy: f64,
    /// Mean time a vehicle stays in its bay (exponential), s.
    pub mean_stay_s: f64,
    /// Length of a bay along the curb, m.
    pub bay_length_m: f32,
    /// No bays within this distance beyond a crosswalk, m.
    pub clear_of_crosswalk_m: f32,
    /// Relative frequencies of the parked vehicles' classes (car, truck, bus, motorcycle,
    /// golf_cart); each class's largest vehicle must fit a bay and the parking lane.
    pub class_mix: BTreeMap<String, f64>,
}

impl Default for ParkingConfig {
    fn default() -> Self {
        ParkingConfig {
            occupancy: 0.7,
            mean_stay_s: 1800.0,
            bay_length_m: 6.5,
            clear_of_crosswalk_m: 6.0,
            class_mix: [("car".to_string(), 1.0)].into_iter().collect(),
        }
    }
}

/// Room a parked vehicle keeps from the next bay's vehicle (each side) and, at least, from the
/// lane beside it, m.
const BAY_GAP_M: f32 = 0.2;
const LANE_GAP_M: f32 = 0.05;
/// Half the width of the corridor kept free of bays where jaywalkers cross, m.
const JAYWALK_CORRIDOR_M: f32 = 1.2;
/// Parked vehicles' ids start here, apart from the moving road users'.
pub const PARKED_ID_BASE: u32 = 1 << 31;

impl ParkingConfig {
    /// Checks every field against the layout; errors name the field and value.
    pub(super) fn validate(&self, layout: &Layout) -> Result<(), DatasetError> {
        let f = |n: &str| format!("parking.{n}");
        if !(0.0..=1.0).contains(&self.occupancy) {
            return Err(invalid(&f("occupancy"), self.occupancy, "must be a share in [0, 1]"));
        }
        if !(self.mean_stay_s.is_finite() && self.mean_stay_s >= 1.0) {
            return Err(invalid(&f("mean_stay_s"), self.mean_stay_s, "must be at least 1 s"));
        }
        if !(3.0..=20.0).contains(&self.bay_length_m) {
            return Err(invalid(&f("bay_length_m"), self.bay_length_m, "must be in [3, 20] m"));
        }
        if !(0.0..=50.0).contains(&self.clear_of_crosswalk_m) {
            return Err(invalid(&f("clear_of_crosswalk_m"), self.clear_of_crosswalk_m, "must be in [0, 50] m"));
        }
        let lanes: Vec<&ArmLayout> = layout.arms.iter().filter(|a| a.parking_lane_m > 0.0).collect();
        let Some(narrowest) = lanes.iter().min_by(|a, b| a.parking_lane_m.total_cmp(&b.parking_lane_m)) else {
            return Err(invalid(
                "parking",
                "[traffic.parking]",
                "no arm of the scene has a parking lane (set arms[].parking_lane_width_m in the scene file)",
            ));
        };
        if check_class_mix(&f("class_mix"), &self.class_mix, "pedestrians do not park")? <= 0.0 {
            return Err(invalid(&f("class_mix"), "{…}", "needs at least one class with a positive share"));
        }
        for (name, w) in self.class_mix.iter().filter(|(_, w)| **w > 0.0) {
            let field = f(&format!("class_mix.{name}"));
            if let Ok(c) = name.parse::<Class>() {
                let m = class_model(c);
                if m.length.3 + 2.0 * BAY_GAP_M > self.bay_length_m {
                    return Err(invalid(
                        &field,
                        w,
                        &format!(
                            "a {name} up to {} m long does not fit a bay of {} m (bay_length_m) with {BAY_GAP_M} m each side",
                            m.length.3, self.bay_length_m
                        ),
                    ));
                }
                if m.width.3 + 0.1 + LANE_GAP_M > narrowest.parking_lane_m {
                    return Err(invalid(
                        &field,
                        w,
                        &format!(
                            "a {name} up to {} m wide does not fit arm {:?}'s parking lane of {} m",
                            m.width.3, narrowest.name, narrowest.parking_lane_m
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// A vehicle standing in a bay.
#[derive(Clone, Debug, PartialEq)]
struct Parked {
    id: u32,
    class: Class,
    /// Length, width and height, m.
    size: (f32, f32, f32),
    /// Its centre, and its heading (the adjacent lane's driving direction).
    center: Vec2,
    dir: Vec2,
}

/// One bay of a parking lane.
#[derive(Clone, Debug)]
pub(super) struct Bay {
    /// Where the bay starts and ends along its arm, m from the junction's centre.
    from_m: f32,
    to_m: f32,
    /// Its arm's outward direction and the normal towards its curb.
    dir: Vec2,
    to_curb: Vec2,
    /// Lateral offset of the curb and the parking lane's width, m.
    curb_m: f32,
    width_m: f32,
    /// The adjacent lane's traffic heads outward (the outbound side).
    outbound: bool,
    occupant: Option<Parked>,
    /// Signal time of its next arrival or departure, s.
    change_s: f64,
}

/// The bays of every arm's parking lanes, inbound side first, from the junction outward.
pub(super) fn bays(layout: &Layout, cfg: &ParkingConfig) -> Vec<Bay> {
    let mut out = Vec::new();
    for arm in layout.arms.iter().filter(|a| a.parking_lane_m > 0.0) {
        let start = cw0(arm) + crosswalk_width(arm) + cfg.clear_of_crosswalk_m;
        let end = arm.road[1].dot(arm.dir) - 0.5;
        let corridors: Vec<(f32, f32)> =
            jaywalk_lines(arm).iter().map(|a| (a - JAYWALK_CORRIDOR_M, a + JAYWALK_CORRIDOR_M)).collect();
        for (outbound, curb_m, to_curb) in [(false, arm.edge_in_m, arm.normal), (true, arm.edge_out_m, -arm.normal)] {
            let mut b0 = start;
            while b0 + cfg.bay_length_m <= end {
                let b1 = b0 + cfg.bay_length_m;
                if let Some(&(_, c1)) = corridors.iter().find(|(c0, c1)| b0 < *c1 && b1 > *c0) {
                    b0 = c1;
                    continue;
                }
                out.push(Bay {
                    from_m: b0,
                    to_m: b1,
                    dir: arm.dir,
                    to_curb,
                    curb_m: curb_m.abs(),
                    width_m: arm.parking_lane_m,
                    outbound,
                    occupant: None,
                    change_s: f64::INFINITY,
                });
                b0 = b1;
            }
        }
    }
    out
}

/// The parked vehicles of a scene: the bays, their random stream and the next id.
#[derive(Debug)]
pub(super) struct Parking {
    cfg: ParkingConfig,
    bays: Vec<Bay>,
    rng: ChaCha8Rng,
    next_id: u32,
}

impl Parking {
    /// The bays in their long-run state at signal time 0.
    pub(super) fn new(layout: &Layout, cfg: &ParkingConfig, seed: u64) -> Parking {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // Its own stream: the moving traffic's draws are the same with parking as without.
        rng.set_stream(1);
        let mut p = Parking { cfg: cfg.clone(), bays: bays(layout, cfg), rng, next_id: PARKED_ID_BASE };
        for k in 0..p.bays.len() {
            let taken = p.rng.random::<f64>() < p.cfg.occupancy;
            if taken {
                p.occupy(k);
            }
            p.bays[k].change_s = p.next_change(0.0, taken);
        }
        p
    }

    /// Mean time a bay stays empty, s: the occupancy is stay / (stay + empty).
    fn mean_empty_s(&self) -> f64 {
        self.cfg.mean_stay_s * (1.0 - self.cfg.occupancy) / self.cfg.occupancy
    }

    /// When a bay that is `taken` (or not) at `now` next changes.
    fn next_change(&mut self, now: f64, taken: bool) -> f64 {
        let occ = self.cfg.occupancy;
        if (taken && occ >= 1.0) || (!taken && occ <= 0.0) {
            return f64::INFINITY;
        }
        let mean = if taken { self.cfg.mean_stay_s } else { self.mean_empty_s() };
        let d = Exp::new(1.0 / mean).map(|d| d.sample(&mut self.rng)).unwrap_or(f64::INFINITY);
        now + d
    }

    /// A new vehicle in bay `k`.
    fn occupy(&mut self, k: usize) {
        let mix = &self.cfg.class_mix;
        let last = || mix.iter().rev().find(|(_, w)| **w > 0.0).and_then(|(name, _)| name.parse().ok());
        let class = draw_from(&mut self.rng, mix).or_else(last).unwrap_or(Class::Car);
        let m = class_model(class);
        let (l, w, h) =
            (sample(&mut self.rng, m.length), sample(&mut self.rng, m.width), sample(&mut self.rng, m.height));
        let bay = &self.bays[k];
        // Anywhere in the bay that leaves BAY_GAP_M to its ends; 0.1–0.3 m from the curb, within
        // the parking lane.
        let slack = (0.5 * (bay.to_m - bay.from_m - l) - BAY_GAP_M).max(0.0);
        let along = 0.5 * (bay.from_m + bay.to_m) + self.rng.random_range(-1.0..=1.0f32) * slack;
        let gap = self.rng.random_range(0.1..=0.3f32).min(bay.width_m - w - LANE_GAP_M).max(0.0);
        let center = bay.dir * along + bay.to_curb * (bay.curb_m - gap - 0.5 * w);
        let dir = if bay.outbound { bay.dir } else { -bay.dir };
        self.bays[k].occupant = Some(Parked { id: self.next_id, class, size: (l, w, h), center, dir });
        self.next_id = self.next_id.wrapping_add(1).max(PARKED_ID_BASE);
    }

    /// Arrivals and departures up to signal time `now`.
    pub(super) fn advance(&mut self, now: f64) {
        for k in 0..self.bays.len() {
            while self.bays[k].change_s <= now {
                let at = self.bays[k].change_s;
                let taken = self.bays[k].occupant.is_some();
                if taken {
                    self.bays[k].occupant = None;
                } else {
                    self.occupy(k);
                }
                self.bays[k].change_s = self.next_change(at, !taken);
            }
        }
    }

    /// The parked vehicles now, standing on the ground at `ground_z`.
    pub(super) fn snapshot(&self, ground_z: f32) -> impl Iterator<Item = ActorState> + '_ {
        self.bays.iter().filter_map(move |b| b.occupant.as_ref()).map(move |p| {
            let (l, w, h) = p.size;
            ActorState {
                id: p.id,
                class: p.class,
                box3: Box3::new(p.center.extend(ground_z + 0.5 * h), l, w, h, p.dir.y.atan2(p.dir.x)),
                velocity_mps: Vec2::ZERO,
                accel_mps2: 0.0,
                attribute: if matches!(p.class, Class::Motorcycle | Class::Bicycle) {
                    "cycle.without_rider"
                } else {
                    "vehicle.parked"
                },
                jaywalking: false,
                route: None,
            }
        })
    }

    /// Every bay as (its arm's outward direction, start and end along the arm in m, whether
    /// a vehicle stands in it).
    pub(super) fn bays(&self) -> impl Iterator<Item = BayState> + '_ {
        self.bays.iter().map(|b| BayState {
            from_m: b.from_m,
            to_m: b.to_m,
            dir: b.dir,
            outbound: b.outbound,
            taken: b.occupant.is_some(),
        })
    }
}

/// A bay as [`Traffic::parking_bays`] reports it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BayState {
    /// Where the bay starts and ends along its arm, m from the junction's centre.
    pub from_m: f32,
    pub to_m: f32,
    /// Its arm's outward direction.
    pub dir: Vec2,
    /// On the outbound side of the arm (else the inbound side).
    pub outbound: bool,
    /// A vehicle stands in it now.
    pub taken: bool,
}
