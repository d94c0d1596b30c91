//! A fixed-time signal plan. The scene's signal groups, or else opposing arms (directions
//! within 20° of opposite) paired, form the groups; the groups run in turn, each with an
//! optional protected-left interval, a green for through, right and permissive left (protected
//! where the group is one arm), a yellow and an all-red. Pedestrians get WALK on an arm's
//! crosswalk while a group that does not contain that arm is green (the crosswalk runs parallel
//! to that traffic). Right turns on red are not allowed. A roundabout has no signal
//! ([`SignalPlan::unsignalised`]).

use super::routes::Movement;
use glam::Vec2;
use hilo_raycast::scene::layout::{LaneKind, Layout};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SignalConfig {
    /// Green for through/right/permissive-left, per group.
    pub green_s: f64,
    /// Protected left before the green, for groups with a left-turn bay (0 disables it).
    pub protected_left_s: f64,
    /// Yellow; when absent, the ITE formula 1 s + v / (2 · 3.05 m/s²) at the group's speed limit.
    pub yellow_s: Option<f64>,
    pub all_red_s: f64,
}

impl Default for SignalConfig {
    fn default() -> Self {
        SignalConfig { green_s: 24.0, protected_left_s: 8.0, yellow_s: None, all_red_s: 2.0 }
    }
}

/// The plan of a layout's arms: directions, speed limits and left-turn bays from the layout;
/// none at a roundabout ([`SignalPlan::unsignalised`]). The phases are the scene's own signal
/// groups ([`Layout::signal_groups`]) where it lists them, else opposing arms paired
/// ([`opposing_pairs`]); an arm with no inbound lane (an exit) has no phase. Where the scene
/// lists its own lane graph ([`Layout::connections`]), an arm's bay gets its protected left only
/// when the graph turns left from that arm: a junction whose connections allow no left turn
/// there runs no left arrow for it.
pub fn plan_for(layout: &Layout, cfg: &SignalConfig) -> SignalPlan {
    if layout.ring.is_some() {
        return SignalPlan::unsignalised();
    }
    let speeds: Vec<f32> = layout.arms.iter().map(|a| a.speed_limit_mps).collect();
    let turns_left = |i: usize| {
        layout.connections.is_empty()
            || layout
                .connections
                .iter()
                .any(|c| c.from == i && super::routes::movement_between(layout, c.from, c.to) == Movement::Left)
    };
    let bays: Vec<bool> = layout
        .arms
        .iter()
        .enumerate()
        .map(|(i, a)| a.lanes.iter().any(|l| l.kind == LaneKind::LeftTurnBay) && turns_left(i))
        .collect();
    let groups = if layout.signal_groups.is_empty() {
        let dirs: Vec<Vec2> = layout.arms.iter().map(|a| a.dir).collect();
        let inbound: Vec<bool> =
            layout.arms.iter().map(|a| a.lanes.iter().any(|l| l.kind != LaneKind::Outbound)).collect();
        opposing_pairs(&dirs, &inbound)
    } else {
        layout.signal_groups.clone()
    };
    SignalPlan::new(cfg, &groups, &speeds, &bays)
}

/// hilo's own phases: each arm with inbound traffic (`inbound`) in arm order, paired with the
/// first later such arm within 20° of opposite it (`dirs`: the arms' outward directions), if any.
pub fn opposing_pairs(dirs: &[Vec2], inbound: &[bool]) -> Vec<Vec<usize>> {
    let n = dirs.len();
    let mut taken = vec![false; n];
    let mut groups = Vec::new();
    for i in 0..n {
        if taken[i] || !inbound[i] {
            continue;
        }
        let mut arms = vec![i];
        if let Some(j) =
            (i + 1..n).find(|&j| !taken[j] && inbound[j] && dirs[i].dot(dirs[j]) < -(20f32.to_radians().cos()))
        {
            arms.push(j);
        }
        for &a in &arms {
            taken[a] = true;
        }
        groups.push(arms);
    }
    groups
}

/// What a signal head shows a movement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Light {
    /// Green; `protected` when conflicting traffic is held.
    Green {
        protected: bool,
    },
    Yellow,
    Red,
}

/// The intervals of one arm's phase, as [`SignalPlan::phase`] reports them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phase {
    pub left_s: f64,
    pub green_s: f64,
    pub yellow_s: f64,
    pub all_red_s: f64,
    pub opposed: bool,
}

#[derive(Clone, Debug)]
struct Group {
    arms: Vec<usize>,
    left_s: f64,
    green_s: f64,
    yellow_s: f64,
    all_red_s: f64,
    /// Cycle offset of this group's start.
    offset_s: f64,
}

impl Group {
    fn duration(&self) -> f64 {
        self.left_s + self.green_s + self.yellow_s + self.all_red_s
    }
}

#[derive(Clone, Debug)]
pub struct SignalPlan {
    groups: Vec<Group>,
    group_of_arm: Vec<usize>,
    cycle_s: f64,
}

impl SignalPlan {
    /// `groups`: the arms of each phase, in the order they run (an arm in none has no signal
    /// facing it); `speed_mps`: each arm's speed limit; `has_bay`: whether it has a left-turn
    /// bay that runs a protected left.
    pub fn new(cfg: &SignalConfig, groups: &[Vec<usize>], speed_mps: &[f32], has_bay: &[bool]) -> SignalPlan {
        let mut group_of_arm = vec![usize::MAX; speed_mps.len()];
        let mut groups: Vec<Group> = groups
            .iter()
            .enumerate()
            .map(|(g, arms)| {
                for &a in arms {
                    group_of_arm[a] = g;
                }
                let v = arms.iter().map(|&a| speed_mps[a]).fold(0.0f32, f32::max) as f64;
                let yellow_s = cfg.yellow_s.unwrap_or((1.0 + v / (2.0 * 3.05)).max(3.0));
                let left_s = if arms.iter().any(|&a| has_bay[a]) { cfg.protected_left_s } else { 0.0 };
                Group {
                    arms: arms.clone(),
                    left_s,
                    green_s: cfg.green_s,
                    yellow_s,
                    all_red_s: cfg.all_red_s,
                    offset_s: 0.0,
                }
            })
            .collect();
        let mut t = 0.0;
        for g in &mut groups {
            g.offset_s = t;
            t += g.duration();
        }
        SignalPlan { groups, group_of_arm, cycle_s: t }
    }

    /// No signal: every movement may always go, yielding as the junction's rules say (at a
    /// roundabout, to the ring), and pedestrians cross whenever no vehicle is about to reach
    /// them, with the right of way once on the crosswalk (a zebra crossing).
    pub fn unsignalised() -> SignalPlan {
        SignalPlan { groups: Vec::new(), group_of_arm: Vec::new(), cycle_s: 0.0 }
    }

    /// The group that serves arm `arm` (none without a signal).
    fn group(&self, arm: usize) -> Option<&Group> {
        self.group_of_arm.get(arm).and_then(|&k| self.groups.get(k))
    }

    /// Whether a signal runs the junction.
    pub fn is_signalised(&self) -> bool {
        !self.groups.is_empty()
    }

    /// The cycle's length (0 without a signal).
    pub fn cycle_s(&self) -> f64 {
        self.cycle_s
    }

    /// The phase that serves arm `arm`: its intervals, and whether an opposing arm runs with it
    /// (its left turns are then permissive after the protected interval).
    pub fn phase(&self, arm: usize) -> Phase {
        let Some(g) = self.group(arm) else {
            // No signal: green all the time, nobody opposing.
            return Phase { left_s: 0.0, green_s: 1.0, yellow_s: 0.0, all_red_s: 0.0, opposed: false };
        };
        Phase {
            left_s: g.left_s,
            green_s: g.green_s,
            yellow_s: g.yellow_s,
            all_red_s: g.all_red_s,
            opposed: g.arms.len() > 1,
        }
    }

    /// The group running at `t` and the time since its start.
    fn active(&self, t: f64) -> (usize, f64) {
        let c = t.rem_euclid(self.cycle_s);
        for (k, g) in self.groups.iter().enumerate() {
            if c < g.offset_s + g.duration() {
                return (k, c - g.offset_s);
            }
        }
        (self.groups.len() - 1, c - self.groups[self.groups.len() - 1].offset_s)
    }

    /// The light a movement from arm `arm` sees at time `t`.
    pub fn light(&self, arm: usize, m: Movement, t: f64) -> Light {
        if !self.is_signalised() {
            return Light::Green { protected: false };
        }
        let (k, dt) = self.active(t);
        if self.group_of_arm[arm] != k {
            return Light::Red;
        }
        let g = &self.groups[k];
        if dt < g.left_s {
            return if m == Movement::Left { Light::Green { protected: true } } else { Light::Red };
        }
        let dt = dt - g.left_s;
        if dt < g.green_s {
            // Left is permissive when an opposing arm runs with it.
            let protected = m != Movement::Left || g.arms.len() == 1;
            return Light::Green { protected };
        }
        if dt < g.green_s + g.yellow_s { Light::Yellow } else { Light::Red }
    }

    /// While a movement sees yellow, the seconds until its red.
    pub fn yellow_left(&self, arm: usize, m: Movement, t: f64) -> Option<f64> {
        if self.light(arm, m, t) != Light::Yellow {
            return None;
        }
        let (k, dt) = self.active(t);
        let g = &self.groups[k];
        Some(g.left_s + g.green_s + g.yellow_s - dt)
    }

    /// Whether a pedestrian may start crossing arm `arm` at `t`, and until when the crossing
    /// stays protected from the traffic it runs parallel to (seconds from `t`).
    pub fn walk(&self, arm: usize, t: f64) -> Option<f64> {
        if !self.is_signalised() {
            return Some(f64::INFINITY);
        }
        let (k, dt) = self.active(t);
        if self.group_of_arm[arm] == k {
            return None;
        }
        let g = &self.groups[k];
        if dt < g.left_s || dt >= g.left_s + g.green_s {
            return None;
        }
        Some(g.duration() - dt)
    }

    /// The arms of the group that opposes `arm` in its own green (the other arm of its pair).
    pub fn opposing(&self, arm: usize) -> Vec<usize> {
        let Some(g) = self.group(arm) else { return Vec::new() };
        g.arms.iter().copied().filter(|&a| a != arm).collect()
    }
}
