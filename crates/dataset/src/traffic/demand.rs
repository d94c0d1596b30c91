//! Demand levels: the traffic of an hour named the way a traffic engineer names it, `off_peak` or
//! `peak`, turned into arrival rates for the junction at hand.
//!
//! A level is a volume-to-capacity ratio (v/c) of the most loaded lane of each approach, so a
//! peak hour loads a two-lane side street and a six-lane arterial alike to the edge of what their
//! signal lets through, as peak hours do. The capacity is the Highway Capacity Manual's critical-
//! lane analysis in its simplest form, for the lane graph and the fixed-time plan this traffic
//! model runs:
//!
//! - A lane discharges at a saturation flow of [`SATURATION_FLOW_VPHPL`] during its effective
//!   green, the green plus yellow plus all-red less [`LOST_TIME_S`] of start-up and clearance.
//! - Through vehicles spread evenly over the inbound lanes; right turns use the outermost; left
//!   turns use the bay when the arm has one, and otherwise the innermost lane, which they then
//!   share with through traffic (their time shares add).
//! - A left turn's capacity is its protected interval (less 2 s of start-up) plus the permissive
//!   capacity of a gap-acceptance stream against the opposing through and right traffic during
//!   the green: `λ e^(−λ t_c) / (1 − e^(−λ t_f))` (Drew), with the critical gap [`CRITICAL_GAP_S`]
//!   (the mean of the drivers' gaps in this model) and the follow-up [`FOLLOW_UP_S`].
//! - Movements a junction does not offer fall back as the traffic model spawns them: a left or
//!   right turn with no exit goes straight, and a through movement with no exit is not spawned.
//!
//! What it leaves out: right turns slowed by pedestrians, heavy vehicles' longer headways, lane
//! utilisation that is not even, sneakers at the end of the green, spill-back from a full
//! left-turn bay, and a scene's own lane graph (`[[connections]]`) where it gives the lanes
//! other turns than hilo's rules do: the lane groups above are the rules'. In this model the first matters most: its right turners wait out a crosswalk's
//! pedestrians far longer than drivers do (304 right turns an hour from a flooded lane with no
//! pedestrians, 48 with 90 per crosswalk and direction; HCM's adjustment keeps about three
//! quarters), and its permissive lefts find few gaps. So over many cycles a level runs hotter
//! than its nominal v/c: at the default junction's peak, queues beyond the arms' ends grow from
//! the fifth minute on (`tests/demand.rs`, the ignored test, prints the figures). A scene
//! records 20 s after a 45 s warm-up, less than a cycle of build-up, so datasets do not reach
//! that state.

use super::TrafficConfig;
use super::routes::{Movement, Route, spawned_movement};
use super::signal::{Phase, SignalPlan};
use hilo_raycast::scene::layout::{LaneKind, Layout};
use serde::{Deserialize, Serialize};

/// Vehicles per hour of effective green per lane: the rate at which this model's queues
/// discharge (its Intelligent Driver Model parameters), measured by the traffic test. The field
/// reaches 1,800–1,900 (HCM's base is 1,900 pc/h); see the module's notes.
pub const SATURATION_FLOW_VPHPL: f64 = 1300.0;
/// Start-up and clearance lost time per phase (HCM's default).
pub const LOST_TIME_S: f64 = 4.0;
/// Mean critical gap of a permissive left turn (the model draws 4–6 s).
pub const CRITICAL_GAP_S: f64 = 5.0;
/// Follow-up headway of permissive left turns: the model's discharge headway, 3600 s / the
/// saturation flow.
pub const FOLLOW_UP_S: f64 = 3600.0 / SATURATION_FLOW_VPHPL;

/// A named level of traffic demand (`demand` in `[traffic]`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Demand {
    /// Midday or evening traffic: each approach's most loaded lane at v/c 0.35.
    OffPeak,
    /// The peak hour: each approach's most loaded lane at v/c 0.85, where queues still clear
    /// within a cycle or two.
    Peak,
}

impl Demand {
    pub fn name(self) -> &'static str {
        match self {
            Demand::OffPeak => "off_peak",
            Demand::Peak => "peak",
        }
    }

    /// The volume-to-capacity ratio of each approach's most loaded lane.
    pub fn volume_to_capacity(self) -> f64 {
        match self {
            Demand::OffPeak => 0.35,
            Demand::Peak => 0.85,
        }
    }

    /// Pedestrian arrivals per crosswalk and direction: stated figures for an urban arterial
    /// (set `pedestrians_per_hour` without a level where counts exist).
    pub fn pedestrians_per_hour(self) -> f64 {
        match self {
            Demand::OffPeak => 30.0,
            Demand::Peak => 200.0,
        }
    }
}

/// One approach's arrival rate at a level, and what limits it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ApproachLoad {
    pub arm: String,
    /// Vehicle arrivals per hour, all movements.
    pub vehicles_per_hour: f64,
    /// The most loaded lane group at that rate: `"through"`, `"right"` (the outermost lane),
    /// `"left"` (the bay, or the innermost lane it shares); `"entry"` at a roundabout.
    pub critical: &'static str,
    /// Its volume-to-capacity ratio (the level's, unless the approach carries no traffic).
    pub volume_to_capacity: f64,
}

/// Per-hour flows of one approach's movements at arrival rate 1 (shares after fallback).
#[derive(Clone, Copy, Debug, Default)]
struct Shares {
    left: f64,
    through: f64,
    right: f64,
}

/// One approach as the capacity analysis sees it.
#[derive(Clone, Debug)]
struct Approach {
    shares: Shares,
    lanes: usize,
    bay: bool,
    /// Effective green share of the cycle for the through lanes and of the protected left.
    g: f64,
    g_left: f64,
    opposed: bool,
    opposing: Vec<usize>,
}

fn shares(cfg: &TrafficConfig, routes: &[Route], arm: usize) -> Shares {
    let (l, r) = (cfg.left_share, cfg.right_share);
    let t = (1.0 - l - r).max(0.0);
    let mut out = Shares::default();
    for (m, share) in [(Movement::Left, l), (Movement::Right, r), (Movement::Through, t)] {
        let Some(to) = spawned_movement(routes, arm, m) else { continue };
        match to {
            Movement::Left => out.left += share,
            Movement::Through => out.through += share,
            Movement::Right => out.right += share,
        }
    }
    out
}

/// The effective green of a phase as a share of the cycle: green + yellow + all-red less the
/// lost time.
pub fn effective_green_share(p: &Phase, cycle_s: f64) -> f64 {
    ((p.green_s + p.yellow_s + p.all_red_s - LOST_TIME_S) / cycle_s.max(1e-9)).max(0.0)
}

/// Permissive left-turn capacity (veh/h) against an opposing flow of `v_o` veh/h that runs only
/// during the effective green share `g`.
fn permissive_capacity(v_o: f64, g: f64) -> f64 {
    if g <= 0.0 {
        return 0.0;
    }
    let lambda = v_o / 3600.0 / g;
    let per_s = if lambda < 1e-9 {
        1.0 / FOLLOW_UP_S
    } else {
        lambda * (-lambda * CRITICAL_GAP_S).exp() / (1.0 - (-lambda * FOLLOW_UP_S).exp())
    };
    g * 3600.0 * per_s
}

impl Approach {
    /// The most loaded lane group at arrival rate `r` with an opposing flow `v_o` (veh/h).
    fn critical(&self, r: f64, v_o: f64) -> (f64, &'static str) {
        let lane = SATURATION_FLOW_VPHPL * self.g;
        let left_cap = SATURATION_FLOW_VPHPL * self.g_left
            + if self.opposed { permissive_capacity(v_o, self.g) } else { SATURATION_FLOW_VPHPL * self.g };
        let ratio = |v: f64, c: f64| {
            if v <= 0.0 {
                0.0
            } else if c <= 0.0 {
                f64::INFINITY
            } else {
                v / c
            }
        };
        let n = self.lanes.max(1) as f64;
        let through = ratio(r * self.shares.through / n, lane);
        let right = ratio(r * self.shares.right, lane);
        let left = ratio(r * self.shares.left, left_cap);
        let mut groups = vec![(through, "through"), (through + right, "right")];
        if self.bay {
            groups.push((left, "left"));
        } else if self.lanes == 1 {
            groups.push((through + right + left, "left"));
        } else {
            groups.push((through + left, "left"));
        }
        groups.into_iter().fold((0.0, "through"), |best, g| if g.0 > best.0 { g } else { best })
    }

    /// The arrival rate whose most loaded lane group reaches `vc`, by bisection (the load grows
    /// with the rate).
    fn rate_at(&self, vc: f64, v_o: f64) -> f64 {
        if self.critical(1.0, v_o).0 <= 0.0 {
            return 0.0;
        }
        let (mut lo, mut hi) = (0.0f64, 20_000.0f64);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.critical(mid, v_o).0 < vc {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }
}

/// Each approach's arrival rate at `demand` on `layout` with `plan`, the turning shares of `cfg`.
/// Opposing flows and left-turn capacities depend on each other; a damped fixed-point iteration
/// settles them (to well under a vehicle per hour).
pub fn level_rates(
    layout: &Layout,
    routes: &[Route],
    plan: &SignalPlan,
    cfg: &TrafficConfig,
    demand: Demand,
) -> Vec<ApproachLoad> {
    if !plan.is_signalised() {
        return ring_rates(layout, routes, cfg, demand);
    }
    let cycle = plan.cycle_s().max(1e-9);
    let approaches: Vec<Approach> = layout
        .arms
        .iter()
        .enumerate()
        .map(|(i, arm)| {
            let p = plan.phase(i);
            Approach {
                shares: shares(cfg, routes, i),
                lanes: arm.lanes.iter().filter(|l| l.kind == LaneKind::Inbound).count(),
                bay: arm.lanes.iter().any(|l| l.kind == LaneKind::LeftTurnBay),
                g: effective_green_share(&p, cycle),
                g_left: ((p.left_s - 0.5 * LOST_TIME_S) / cycle).max(0.0),
                opposed: p.opposed,
                opposing: plan.opposing(i),
            }
        })
        .collect();
    let vc = demand.volume_to_capacity();
    let opposing_flow = |rates: &[f64], a: &Approach| -> f64 {
        a.opposing.iter().map(|&j| rates[j] * (approaches[j].shares.through + approaches[j].shares.right)).sum()
    };
    let rates =
        settle(approaches.len(), |rates| approaches.iter().map(|a| a.rate_at(vc, opposing_flow(rates, a))).collect());
    layout
        .arms
        .iter()
        .zip(&approaches)
        .zip(&rates)
        .map(|((arm, a), &r)| {
            let (x, critical) = a.critical(r, opposing_flow(&rates, a));
            ApproachLoad { arm: arm.name.clone(), vehicles_per_hour: r, critical, volume_to_capacity: x }
        })
        .collect()
}

/// The damped fixed point of `n` approaches' rates, from none: each round moves every rate
/// halfway to what `next` gives for the current ones, until no rate would move by 0.01 veh/h
/// (or 200 rounds).
fn settle(n: usize, next: impl Fn(&[f64]) -> Vec<f64>) -> Vec<f64> {
    let mut rates = vec![0.0; n];
    for _ in 0..200 {
        let next = next(&rates);
        let change = rates.iter().zip(&next).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        for (r, q) in rates.iter_mut().zip(&next) {
            *r = 0.5 * (*r + q);
        }
        if change < 0.01 {
            break;
        }
    }
    rates
}

/// Whether arm `i` lies strictly between arms `j` and `k` going counter-clockwise (the layout's
/// arms are in that order), of `n`.
fn between_ccw(j: usize, i: usize, k: usize, n: usize) -> bool {
    let (di, dk) = ((i + n - j) % n, (k + n - j) % n);
    di > 0 && di < dk
}

/// The least headway between vehicles circulating on a roundabout's ring in this model (its
/// Intelligent Driver Model at the ring's curvature speed, about 5.5 m/s), measured by the
/// roundabout test. The field's is nearer 2 s: like [`SATURATION_FLOW_VPHPL`] at the signal,
/// the model's queues are slower than real ones.
pub const RING_MIN_HEADWAY_S: f64 = 3.0;
/// The headway between two circulating vehicles that an entering driver needs, fitted to the
/// roundabout test's discharges: the lag it accepts (the larger of its critical gap, 4–6 s, and
/// the time its body takes to get onto the ring from the yield line plus a second: 5.2 s on
/// average) and the time the vehicle before takes to clear the merge point (about 1.5 s).
pub const RING_CRITICAL_S: f64 = 6.7;
/// The headway at which a queue enters an empty ring, measured by the roundabout test.
pub const RING_FOLLOW_UP_S: f64 = 3.5;

/// A single-lane roundabout entry's capacity (veh/h) against `v_c` veh/h circulating past it:
/// Tanner's gap-acceptance formula, `q (1 − Δ q) e^(−q (t_c − Δ)) / (1 − e^(−q t_f))` with the
/// circulating stream's least headway Δ ([`RING_MIN_HEADWAY_S`]), [`RING_CRITICAL_S`] and
/// [`RING_FOLLOW_UP_S`] (HCM 6's single-lane formula, `1380 e^(−0.00102 v_c)`, is of this
/// family with the field's headways).
pub fn ring_entry_capacity(v_c: f64) -> f64 {
    let q = v_c / 3600.0;
    if q < 1e-9 {
        return 3600.0 / RING_FOLLOW_UP_S;
    }
    let free = (1.0 - RING_MIN_HEADWAY_S * q).max(0.0);
    3600.0 * q * free * (-q * (RING_CRITICAL_S - RING_MIN_HEADWAY_S)).exp() / (1.0 - (-q * RING_FOLLOW_UP_S).exp())
}

/// At a roundabout, each entry's rate at `demand`: its one lane's capacity is
/// [`ring_entry_capacity`] against the flow circulating past it, and that flow is the other
/// entries' vehicles bound past it, so the rates settle by the same damped iteration.
/// Pedestrians on the crosswalks, who hold entering and exiting drivers here as in the field,
/// are left out, as at the signal.
fn ring_rates(layout: &Layout, routes: &[Route], cfg: &TrafficConfig, demand: Demand) -> Vec<ApproachLoad> {
    let n = layout.arms.len();
    // passing[j][i]: the share of approach j's arrivals that circulate past entry i.
    let passing: Vec<Vec<f64>> = (0..n)
        .map(|j| {
            let sh = shares(cfg, routes, j);
            let bound = [(Movement::Left, sh.left), (Movement::Through, sh.through), (Movement::Right, sh.right)]
                .into_iter()
                .filter_map(|(m, share)| {
                    Some((routes.iter().find(|r| r.approach == j && r.movement == m)?.exit, share))
                })
                .collect::<Vec<_>>();
            (0..n).map(|i| bound.iter().filter(|(k, _)| between_ccw(j, i, *k, n)).map(|(_, s)| s).sum()).collect()
        })
        .collect();
    let served: Vec<bool> = (0..n).map(|i| routes.iter().any(|r| r.approach == i)).collect();
    let vc = demand.volume_to_capacity();
    let circulating = |rates: &[f64], i: usize| (0..n).map(|j| rates[j] * passing[j][i]).sum::<f64>();
    let rates = settle(n, |rates| {
        (0..n).map(|i| if served[i] { vc * ring_entry_capacity(circulating(rates, i)) } else { 0.0 }).collect()
    });
    (0..n)
        .map(|i| {
            let cap = ring_entry_capacity(circulating(&rates, i));
            ApproachLoad {
                arm: layout.arms[i].name.clone(),
                vehicles_per_hour: rates[i],
                critical: "entry",
                volume_to_capacity: if rates[i] > 0.0 { rates[i] / cap } else { 0.0 },
            }
        })
        .collect()
}

/// Each approach's rate at `demand` on `layout` under the turning shares and signal timing of
/// `cfg`: what `Traffic` runs for a study with that level.
pub fn levels_of(layout: &Layout, cfg: &TrafficConfig, demand: Demand) -> Vec<ApproachLoad> {
    let routes = super::routes::build_routes(layout);
    let plan = super::signal::plan_for(layout, &cfg.signal);
    level_rates(layout, &routes, &plan, cfg, demand)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permissive_capacity_meets_its_limits() {
        // No opposing traffic: one vehicle per follow-up headway during the green.
        let g = 0.4;
        let free = permissive_capacity(0.0, g);
        assert!((free - g * 3600.0 / FOLLOW_UP_S).abs() < 1e-9, "{free}");
        assert!((permissive_capacity(1e-6, g) - free).abs() / free < 1e-3);
        // It falls as the opposing flow grows, towards nothing.
        let caps: Vec<f64> = [0.0, 200.0, 600.0, 1200.0, 3000.0].iter().map(|&v| permissive_capacity(v, g)).collect();
        assert!(caps.windows(2).all(|w| w[1] < w[0]), "{caps:?}");
        assert!(caps[4] < 0.05 * caps[0], "{caps:?}");
        // A hand-computed point: 600 veh/h opposing in a 0.4 green share, λ = 1/2.4 s⁻¹, critical
        // gap 5 s, follow-up 3600 / 1300 s.
        let l: f64 = 1.0 / 2.4;
        let want = 0.4 * 3600.0 * l * (-l * 5.0).exp() / (1.0 - (-l * (3600.0 / 1300.0)).exp());
        assert!((permissive_capacity(600.0, 0.4) - want).abs() < 1e-9);
        assert_eq!(permissive_capacity(600.0, 0.0), 0.0);
    }

    #[test]
    fn the_rate_found_loads_the_critical_lane_to_the_level() {
        let a = Approach {
            shares: Shares { left: 0.2, through: 0.65, right: 0.15 },
            lanes: 2,
            bay: false,
            g: 0.4,
            g_left: 0.0,
            opposed: true,
            opposing: vec![],
        };
        for vc in [0.35, 0.85] {
            let r = a.rate_at(vc, 500.0);
            let (x, _) = a.critical(r, 500.0);
            assert!((x - vc).abs() < 1e-6, "{x} vs {vc}");
            // Brute force: no lower rate on a grid reaches the level.
            let below = (0..1000).map(|k| r * k as f64 / 1000.0).all(|q| a.critical(q, 500.0).0 < vc + 1e-9);
            assert!(below);
        }
        // A shared lane with heavy opposing traffic: the left is critical.
        assert_eq!(a.critical(a.rate_at(0.85, 1500.0), 1500.0).1, "left");
    }
}
