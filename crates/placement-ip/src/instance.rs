//! The placement problem as solvers see it, independent of the scene: target weights, sensor
//! types with prices, sensor *options* (a candidate with a type, its visibility row), limits.
//!
//! Objective (the paper's Algorithm 1): maximise Σ_j t_j ρ_j with
//! ρ_j = w_j Σ_{o ∈ S} V_oj, where t_j = 1 only if both modalities see target j:
//! Σ_{o ∈ S_L} −ln(1 − V_oj) ≥ τ and Σ_{o ∈ S_R} −ln(1 − V_oj) ≥ τ, τ = −ln(1 − p_min)
//! (the paper's "≥ 1" is p_min = 1 − e⁻¹ ≈ 0.632). For a given selection the best t is forced,
//! so [`evaluate`] is the exact objective of any selection, whichever solver produced it.
//!
//! "Both modalities" means the modalities the instance *offers* ([`Instance::requires`]): an
//! instance whose types are all LiDARs asks only for LiDAR coverage (and one of radars only for
//! radar coverage). The paper poses the problem for mixed rigs only, where the two readings
//! agree; read literally, its objective is zero for every LiDAR-only rig, which could then be
//! neither placed nor ranked.

use crate::candidates::Modality;
use crate::error::PlacementError;
use serde::{Deserialize, Serialize};

/// A sensor type offered to the solver.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorType {
    pub name: String,
    pub modality: Modality,
    pub price_usd: f64,
}

/// A candidate with a sensor type: one binary decision.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorOption {
    pub ty: usize,
    pub candidate: u32,
    /// At most one option per mount point is chosen.
    pub mount: u32,
    /// Visibility row: (target, V) with V in (0, 1], sorted by target.
    pub row: Vec<(u32, f32)>,
}

/// How many sensors may be bought.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Limit {
    /// At most `counts[t]` sensors of type t (the paper's configurations, e.g. 2 × 16-beam + radar).
    Counts(Vec<u32>),
    /// At most `n` sensors in all (the paper's constraint (2)).
    Total(u32),
    /// A dollar budget, with optional minimum and maximum counts per type.
    Budget { usd: f64, min: Vec<u32>, max: Vec<u32> },
}

/// Why a selection is not a placement of an instance under a limit.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Infeasible {
    #[error("option {0} does not exist")]
    NoOption(usize),
    #[error("two sensors on mount {0}")]
    SharedMount(u32),
    #[error("{n} x {ty} exceeds {rule}")]
    TypeCount { n: u32, ty: String, rule: &'static str },
    #[error("{n} sensors exceed the limit {limit}")]
    Total { n: usize, limit: u32 },
    #[error("cost {cost_usd} exceeds the budget {budget_usd}")]
    Budget { cost_usd: f64, budget_usd: f64 },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Instance {
    pub weights: Vec<f64>,
    pub types: Vec<SensorType>,
    pub options: Vec<SensorOption>,
    /// Detection threshold p_min; the coverage right-hand side is τ = −ln(1 − p_min).
    pub p_min: f64,
    /// Per target, the class-balanced share of the simulated traffic's road users found there
    /// (empty unless computed): the target weights of the calibrated objective's terms over
    /// road users ([`crate::calibrated`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub road_users: Vec<f64>,
    /// Road users of sampled traffic frames and the LiDAR points each option puts on them (empty
    /// unless computed): the calibrated objective's point-count term ([`crate::calibrated`]).
    #[serde(default, skip_serializing_if = "PointRows::is_empty")]
    pub points: PointRows,
    /// The same road users and, per option, the share of each one's footprint (length × width)
    /// its points span, in thousandths (`k` = 1000; empty unless computed): the calibrated
    /// objective's footprint term ([`crate::calibrated`]). Shares add up over sensors, capped at
    /// 1, as points do.
    #[serde(default, skip_serializing_if = "PointRows::is_empty")]
    pub extents: PointRows,
    /// Floors on the share of a class's sampled road users that at least one chosen LiDAR puts
    /// a point on (empty: none). The calibrated objective's solvers keep every selection above
    /// them ([`crate::calibrated`]); the paper's solvers do not read them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub floors: Vec<HitFloor>,
}

/// A floor on how many of one class's sampled road users the chosen LiDARs hit: at least
/// `share` of its `samples` must get a point from at least one of them. A road user hit by one
/// LiDAR is hit by any rig that holds it, so the floor is a covering constraint, exact in an IP
/// (y_s ≤ Σ_{o hits s} x_o, 0 ≤ y_s ≤ 1, Σ_s y_s ≥ ⌈share × samples⌉) and monotone in the
/// selection: adding a sensor never breaks it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HitFloor {
    /// The class's name, for messages.
    pub class: String,
    /// The share of its samples that must be hit, in (0, 1].
    pub share: f64,
    /// Its sampled road users (one road user in one frame each).
    pub samples: u32,
    /// Per option, the samples (indices below `samples`, ascending) it puts a point on (empty
    /// for a radar).
    pub rows: Vec<Vec<u32>>,
}

impl HitFloor {
    /// Samples that must be hit: ⌈share × samples⌉ (a hair below an integer counts as it).
    pub fn needed(&self) -> u32 {
        ((self.share * f64::from(self.samples) - 1e-9).ceil().max(0.0) as u32).min(self.samples)
    }

    /// Samples the options of `sel` hit.
    pub fn hits(&self, sel: &[usize]) -> u32 {
        let mut hit = vec![false; self.samples as usize];
        for &o in sel {
            for &s in self.rows.get(o).map_or(&[][..], Vec::as_slice) {
                hit[s as usize] = true;
            }
        }
        hit.iter().filter(|&&h| h).count() as u32
    }

    /// The share of the samples `sel` hits.
    pub fn share_hit(&self, sel: &[usize]) -> f64 {
        f64::from(self.hits(sel)) / f64::from(self.samples.max(1))
    }
}

/// The units of [`Instance::extents`]: thousandths of a road user's footprint.
pub const EXTENT_UNITS: f64 = 1000.0;

/// Road users of sampled traffic frames ("samples": one road user in one frame), each with its
/// weight, and per option the LiDAR points it puts on each sample it hits. A sample counts
/// fully once the chosen LiDARs put `k` points on it, in part below that: the capped count
/// min(1, Σ_o n_oj / k), linear in per-option terms under a cap, which an IP holds exactly
/// (LiDAR points add up over sensors: each casts its own rays).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointRows {
    /// Points that count a sample fully.
    pub k: f64,
    /// Per sample, its weight (class-balanced: each class's samples share 1 / classes).
    pub weights: Vec<f64>,
    /// Per option, (sample, points) for the samples it puts points on (empty for a radar).
    pub rows: Vec<Vec<(u32, u32)>>,
}

impl PointRows {
    pub fn is_empty(&self) -> bool {
        self.weights.is_empty() && self.rows.is_empty()
    }
}

/// V is clamped to this before taking logs, so that V = 1 gives a finite coefficient.
pub const V_MAX: f64 = 1.0 - 1e-12;

/// The coverage coefficient −ln(1 − V), computed stably as −ln_1p(−V) with V clamped below 1.
pub fn coverage_coef(v: f64) -> f64 {
    -(-v.clamp(0.0, V_MAX)).ln_1p()
}

impl Instance {
    /// How many options (candidate × orientation) each sensor type has, in type order: no
    /// selection holds more of a type than this, whatever its price.
    pub fn options_per_type(&self) -> Vec<usize> {
        let mut n = vec![0; self.types.len()];
        for o in &self.options {
            if let Some(c) = n.get_mut(o.ty) {
                *c += 1;
            }
        }
        n
    }

    pub fn tau(&self) -> f64 {
        coverage_coef(self.p_min)
    }

    pub fn n_targets(&self) -> usize {
        self.weights.len()
    }

    /// Whether the objective asks for coverage by `m`: some offered type is of that modality.
    pub fn requires(&self, m: Modality) -> bool {
        self.types.iter().any(|t| t.modality == m)
    }

    /// Whether coverage sums `a_l` (LiDAR) and `a_r` (radar) make a target count.
    pub fn counts_target(&self, a_l: f64, a_r: f64, tau: f64) -> bool {
        (a_l >= tau || !self.requires(Modality::Lidar)) && (a_r >= tau || !self.requires(Modality::Radar))
    }

    pub fn modality(&self, o: usize) -> Modality {
        self.types[self.options[o].ty].modality
    }

    /// Checks shapes and values once; solvers trust a validated instance.
    pub fn validate(&self) -> Result<(), PlacementError> {
        let bad = |m: String| Err(PlacementError::instance("instance", m));
        if !(self.p_min > 0.0 && self.p_min < 1.0) {
            return bad(format!("p_min = {}: must be in (0, 1)", self.p_min));
        }
        if self.weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return bad("target weights must be finite and >= 0".into());
        }
        for (i, t) in self.types.iter().enumerate() {
            if !(t.price_usd.is_finite() && t.price_usd >= 0.0) {
                return bad(format!("type {i} ({}) has price {}", t.name, t.price_usd));
            }
        }
        for (i, o) in self.options.iter().enumerate() {
            if o.ty >= self.types.len() {
                return bad(format!("option {i} has type {} of {}", o.ty, self.types.len()));
            }
            for &(j, v) in &o.row {
                if j as usize >= self.weights.len() || !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                    return bad(format!("option {i}: entry (target {j}, V = {v}) out of range"));
                }
            }
        }
        for (what, pts) in [("point", &self.points), ("footprint", &self.extents)] {
            if pts.is_empty() {
                continue;
            }
            if pts.rows.len() != self.options.len() {
                return bad(format!("{what} rows for {} of {} options", pts.rows.len(), self.options.len()));
            }
            if !(pts.k.is_finite() && pts.k >= 1.0) {
                return bad(format!("{what} units that count a road user fully: {} (must be >= 1)", pts.k));
            }
            if pts.weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
                return bad(format!("{what} rows: road-user sample weights must be finite and >= 0"));
            }
            for (i, row) in pts.rows.iter().enumerate() {
                if let Some(&(j, _)) = row.iter().find(|(j, _)| *j as usize >= pts.weights.len()) {
                    return bad(format!("option {i}: {what} entry on sample {j} of {}", pts.weights.len()));
                }
            }
        }
        for f in &self.floors {
            if !(f.share > 0.0 && f.share <= 1.0) || f.samples == 0 {
                return bad(format!(
                    "{} hit floor: share {} of {} samples (must be in (0, 1] of at least one)",
                    f.class, f.share, f.samples
                ));
            }
            if f.rows.len() != self.options.len() {
                return bad(format!(
                    "{} hit floor: rows for {} of {} options",
                    f.class,
                    f.rows.len(),
                    self.options.len()
                ));
            }
            for (i, row) in f.rows.iter().enumerate() {
                if row.windows(2).any(|w| w[0] >= w[1]) || row.last().is_some_and(|&s| s >= f.samples) {
                    return bad(format!(
                        "option {i}: {} hit floor rows must be ascending samples below {}",
                        f.class, f.samples
                    ));
                }
            }
        }
        Ok(())
    }

    /// Whether `sel` meets every floor of [`Instance::floors`].
    pub fn meets_floors(&self, sel: &[usize]) -> bool {
        self.floors.iter().all(|f| f.hits(sel) >= f.needed())
    }

    /// Whether a selection respects the limit and the one-sensor-per-mount rule; the error
    /// says which rule it breaks.
    pub fn check(&self, limit: &Limit, sel: &[usize]) -> Result<(), Infeasible> {
        let mut mounts = std::collections::HashSet::new();
        let mut per_type = vec![0u32; self.types.len()];
        let mut cost = 0.0;
        for &o in sel {
            let opt = self.options.get(o).ok_or(Infeasible::NoOption(o))?;
            if !mounts.insert(opt.mount) {
                return Err(Infeasible::SharedMount(opt.mount));
            }
            per_type[opt.ty] += 1;
            cost += self.types[opt.ty].price_usd;
        }
        let count = |t: usize| (per_type[t], self.types[t].name.clone());
        match limit {
            Limit::Counts(c) => {
                if let Some(t) = (0..self.types.len()).find(|&t| per_type[t] > c.get(t).copied().unwrap_or(0)) {
                    let (n, ty) = count(t);
                    return Err(Infeasible::TypeCount { n, ty, rule: "the limit" });
                }
            }
            Limit::Total(n) => {
                if sel.len() as u32 > *n {
                    return Err(Infeasible::Total { n: sel.len(), limit: *n });
                }
            }
            Limit::Budget { usd, min, max } => {
                if cost > usd + 1e-6 {
                    return Err(Infeasible::Budget { cost_usd: cost, budget_usd: *usd });
                }
                for (t, &n) in per_type.iter().enumerate() {
                    if n < min.get(t).copied().unwrap_or(0) || n > max.get(t).copied().unwrap_or(u32::MAX) {
                        let (n, ty) = count(t);
                        return Err(Infeasible::TypeCount { n, ty, rule: "its min/max" });
                    }
                }
            }
        }
        Ok(())
    }

    pub fn cost(&self, sel: &[usize]) -> f64 {
        sel.iter().map(|&o| self.types[self.options[o].ty].price_usd).sum()
    }
}

/// Per target, the coverage sum Σ −ln(1 − V) of the selected sensors of one modality.
pub fn modality_coverage(inst: &Instance, sel: &[usize], modality: Modality) -> Vec<f64> {
    let mut a = vec![0.0; inst.n_targets()];
    for &o in sel.iter().filter(|&&o| inst.modality(o) == modality) {
        for &(j, v) in &inst.options[o].row {
            a[j as usize] += coverage_coef(v as f64);
        }
    }
    a
}

/// Targets the selected sensors of one modality cover (coverage sum ≥ τ).
pub fn covered_targets(inst: &Instance, sel: &[usize], modality: Modality) -> Vec<usize> {
    let tau = inst.tau() * (1.0 - 1e-9);
    modality_coverage(inst, sel, modality).iter().enumerate().filter(|(_, a)| **a >= tau).map(|(j, _)| j).collect()
}

/// Reusable buffers for evaluating selections.
#[derive(Clone, Debug)]
pub struct Scratch {
    a_l: Vec<f64>,
    a_r: Vec<f64>,
    rho: Vec<f64>,
    touched: Vec<u32>,
}

impl Scratch {
    pub fn new(n_targets: usize) -> Self {
        Scratch { a_l: vec![0.0; n_targets], a_r: vec![0.0; n_targets], rho: vec![0.0; n_targets], touched: Vec::new() }
    }
}

/// The exact objective of a selection (see the module doc).
pub fn evaluate(inst: &Instance, sel: &[usize]) -> f64 {
    evaluate_with(inst, sel, &mut Scratch::new(inst.n_targets()))
}

/// [`evaluate`] with caller-owned buffers.
pub fn evaluate_with(inst: &Instance, sel: &[usize], s: &mut Scratch) -> f64 {
    let tau = inst.tau() * (1.0 - 1e-9);
    let (need_l, need_r) = (inst.requires(Modality::Lidar), inst.requires(Modality::Radar));
    for &o in sel {
        let lidar = inst.modality(o) == Modality::Lidar;
        for &(j, v) in &inst.options[o].row {
            let j = j as usize;
            if s.a_l[j] == 0.0 && s.a_r[j] == 0.0 && s.rho[j] == 0.0 {
                s.touched.push(j as u32);
            }
            let a = coverage_coef(v as f64);
            if lidar {
                s.a_l[j] += a;
            } else {
                s.a_r[j] += a;
            }
            s.rho[j] += v as f64;
        }
    }
    let mut f = 0.0;
    for &j in &s.touched {
        let j = j as usize;
        if (s.a_l[j] >= tau || !need_l) && (s.a_r[j] >= tau || !need_r) {
            f += inst.weights[j] * s.rho[j];
        }
        s.a_l[j] = 0.0;
        s.a_r[j] = 0.0;
        s.rho[j] = 0.0;
    }
    s.touched.clear();
    f
}

/// The result of a solver.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    /// Chosen option indices.
    pub selection: Vec<usize>,
    /// Exact objective of the selection ([`evaluate`]).
    pub objective: f64,
    /// Proven upper bound on the optimum.
    pub bound: f64,
    /// (bound − objective) / max(|objective|, 1e-9).
    pub gap: f64,
    pub proven_optimal: bool,
    pub solve_seconds: f64,
    /// Which method produced it.
    pub method: String,
}

impl Outcome {
    /// This outcome, or `warm`'s selection and objective (with this outcome's bound) where this
    /// one is worse by more than `tol`: a solver warm-started from `warm` and stopped early may
    /// return less than it was given.
    pub fn no_worse_than(self, warm: &Outcome, tol: f64) -> Outcome {
        if self.objective + tol < warm.objective {
            Outcome {
                selection: warm.selection.clone(),
                objective: warm.objective,
                gap: (self.bound - warm.objective) / warm.objective.max(1e-9),
                ..self
            }
        } else {
            self
        }
    }

    pub fn new(inst: &Instance, selection: Vec<usize>, bound: f64, proven: bool, seconds: f64, method: &str) -> Self {
        let objective = evaluate(inst, &selection);
        let bound = if proven { objective } else { bound.max(objective) };
        let gap = (bound - objective) / objective.abs().max(1e-9);
        Outcome {
            selection,
            objective,
            bound,
            gap,
            proven_optimal: proven,
            solve_seconds: seconds,
            method: method.to_owned(),
        }
    }
}
