//! From a scene and a catalog to solved placements: targets, candidates, line of sight,
//! visibility per sensor type, instances, and the solver chosen for the limit.

use crate::candidates::{Candidate, CandidateConfig, Modality, sample_candidates};
use crate::error::PlacementError;
use crate::exact::{counts_upper_bound, exact_counts, exact_lidar_first, separable_upper_bound, top_visibilities};
use crate::greedy::greedy;
use crate::instance::{Instance, Limit, Outcome, SensorOption, SensorType};
use crate::mip::{Formulation, SolveLimit, solve as solve_mip};
use crate::targets::{Target, roi_targets};
use crate::visibility::{LineOfSight, Visibility, VisibilityConfig, compute_visibility};
use hilo_core::{Check, Valid};
use hilo_raycast::{QueryRegion, Scene, World};
use hilo_sensor_models::{Catalog, SensorSpec};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::time::Instant;

/// Placement settings (the `[placement]` table of a study).
#[derive(Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlacementConfig {
    pub cell_m: f32,
    /// Detection probability a target needs from each modality (the paper: 1 − e⁻¹).
    pub p_min: f64,
    /// Time limit of CBC when the exact search does not apply (and of the exact searches).
    pub time_limit_s: f64,
    /// Limit on CBC's branch-and-bound nodes. A solve it stops gives the same placement on any
    /// machine; one the time limit stops depends on the machine's speed and load. None: the
    /// time limit alone.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub node_limit: Option<u64>,
    pub candidates: CandidateConfig,
    pub visibility: VisibilityConfig,
    /// What the solvers maximise: the paper's objective, or the calibrated one
    /// ([`crate::calibrated`]) with the weights `hilo validate` fitted.
    pub objective: ObjectiveKind,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<crate::calibrated::Weights>,
    /// The largest calibrated IP (non-zeros of its coverage rows) handed to CBC; a larger one is
    /// solved by greedy and swaps with the submodular bound ([`crate::calibrated::solve`]).
    pub calibrated_cbc_max_nonzeros: usize,
    /// Per class, the share of its road users in sampled frames of the study's training traffic
    /// that every rig with a LiDAR must put at least one LiDAR point on (the calibrated
    /// objective only: [`crate::instance::HitFloor`]). Empty: no floor.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub min_hit_share: BTreeMap<hilo_core::Class, f64>,
}

/// The derived form, with `min_hit_share` only when set: the study's content hashes read this
/// text, so a study that sets no floor keeps its hashes (and its folders open).
impl std::fmt::Debug for PlacementConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("PlacementConfig");
        d.field("cell_m", &self.cell_m)
            .field("p_min", &self.p_min)
            .field("time_limit_s", &self.time_limit_s)
            .field("node_limit", &self.node_limit)
            .field("candidates", &self.candidates)
            .field("visibility", &self.visibility)
            .field("objective", &self.objective)
            .field("calibration", &self.calibration)
            .field("calibrated_cbc_max_nonzeros", &self.calibrated_cbc_max_nonzeros);
        if !self.min_hit_share.is_empty() {
            d.field("min_hit_share", &self.min_hit_share);
        }
        d.finish()
    }
}

/// Which objective placement maximises.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectiveKind {
    /// The paper's: weighted visibility of the targets every offered modality covers.
    #[default]
    Paper,
    /// Saturated coverage per modality, weighted by measured accuracy (`calibration`).
    Calibrated,
}

impl Default for PlacementConfig {
    fn default() -> Self {
        PlacementConfig {
            cell_m: 1.0,
            p_min: 1.0 - (-1.0f64).exp(),
            time_limit_s: 60.0,
            node_limit: None,
            candidates: CandidateConfig::default(),
            visibility: VisibilityConfig::default(),
            objective: ObjectiveKind::Paper,
            calibration: None,
            calibrated_cbc_max_nonzeros: crate::calibrated::CBC_MAX_NONZEROS,
            min_hit_share: BTreeMap::new(),
        }
    }
}

impl PlacementConfig {
    /// The checked configuration that [`prepare`] takes ([`Check`]).
    pub fn validate(self) -> Result<Valid<PlacementConfig>, PlacementError> {
        Valid::new(self)
    }

    /// The time and node limits of every solve.
    pub fn solve_limit(&self) -> SolveLimit {
        SolveLimit { seconds: self.time_limit_s, nodes: self.node_limit }
    }
}

impl Check for PlacementConfig {
    type Error = PlacementError;

    /// Checks the settings that are not checked where they are used, before any visibility is
    /// computed (p_min is used only when the instances are built, seconds of ray casting later).
    fn check(&self) -> Result<(), PlacementError> {
        let bad = |f: &str, v: String, why: &str| Err(PlacementError::setting(format!("placement.{f}"), v, why));
        if !(self.p_min > 0.0 && self.p_min < 1.0) {
            return bad("p_min", self.p_min.to_string(), "must be a probability in (0, 1)");
        }
        if !(self.cell_m.is_finite() && self.cell_m >= 0.1) {
            return bad("cell_m", self.cell_m.to_string(), "must be at least 0.1 m");
        }
        if !(self.time_limit_s >= 0.0 && self.time_limit_s <= 86_400.0) {
            return bad("time_limit_s", self.time_limit_s.to_string(), "must be in [0, 86400] seconds");
        }
        if self.node_limit == Some(0) {
            return bad("node_limit", "0".to_owned(), "must be at least 1 node (leave it out for no node limit)");
        }
        match (self.objective, &self.calibration) {
            (ObjectiveKind::Calibrated, None) => {
                return Err(PlacementError::setting(
                    "placement.objective",
                    "\"calibrated\"",
                    "needs placement.calibration = { lidar = …, radar = … } (the weights `hilo validate` fits)",
                ));
            }
            (ObjectiveKind::Calibrated, Some(w)) => w.check()?,
            (ObjectiveKind::Paper, _) => {}
        }
        for (class, &share) in &self.min_hit_share {
            if !(share > 0.0 && share <= 1.0) {
                return bad(&format!("min_hit_share.{class}"), share.to_string(), "must be a share in (0, 1]");
            }
            if self.objective != ObjectiveKind::Calibrated {
                return bad(
                    &format!("min_hit_share.{class}"),
                    share.to_string(),
                    "needs the calibrated objective (calibration_file = \"…\", or [placement] objective = \"calibrated\")",
                );
            }
        }
        self.visibility.validate()
    }
}

/// Everything placement computes once per scene.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub targets: Vec<Target>,
    pub candidates: Vec<Candidate>,
    /// Per sensor type name.
    pub visibility: BTreeMap<String, Visibility>,
    pub seconds_line_of_sight: f64,
    pub seconds_visibility: f64,
}

/// Computes targets, candidates and the visibility of every named sensor type.
pub fn prepare(
    scene: &Scene,
    catalog: &Catalog,
    types: &[String],
    cfg: &Valid<PlacementConfig>,
) -> Result<Prepared, PlacementError> {
    let targets = roi_targets(scene, cfg.cell_m)?;
    let candidates = sample_candidates(scene, &cfg.candidates)?;
    let specs: Vec<&SensorSpec> = types.iter().map(|t| catalog.get(t)).collect::<Result<_, _>>()?;
    let range = specs
        .iter()
        .map(|s| match s {
            SensorSpec::Lidar(l) => l.max_range_m,
            SensorSpec::Radar(r) => r.max_range_m,
        })
        .fold(0.0, f32::max);
    let mut mounts = vec![glam::Vec3::ZERO; candidates.iter().map(|c| c.mount as usize + 1).max().unwrap_or(0)];
    for c in &candidates {
        mounts[c.mount as usize] = c.pose.position;
    }
    let t = Instant::now();
    let region = QueryRegion::spheres(mounts.iter().map(|m| (*m, range + 5.0)));
    let world = World::build(scene, &region)?;
    let los = LineOfSight::compute(&world, scene.ground.z_m, &mounts, &targets, &cfg.visibility, range + 5.0)?;
    let seconds_line_of_sight = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut visibility = BTreeMap::new();
    for (name, spec) in types.iter().zip(specs) {
        visibility.insert(
            name.clone(),
            compute_visibility(spec, &candidates, &targets, &los, scene.ground.z_m, &cfg.visibility),
        );
    }
    Ok(Prepared {
        targets,
        candidates,
        visibility,
        seconds_line_of_sight,
        seconds_visibility: t.elapsed().as_secs_f64(),
    })
}

/// The instance over the given sensor types (each with all candidates of its modality).
pub fn instance(prep: &Prepared, catalog: &Catalog, types: &[String], p_min: f64) -> Result<Instance, PlacementError> {
    let mut inst = Instance {
        weights: prep.targets.iter().map(|t| t.weight as f64).collect(),
        types: Vec::new(),
        options: Vec::new(),
        p_min,
        road_users: Vec::new(),
        points: Default::default(),
        extents: Default::default(),
        floors: Vec::new(),
    };
    for (ty, name) in types.iter().enumerate() {
        let spec = catalog.get(name)?;
        let vis = prep
            .visibility
            .get(name)
            .ok_or_else(|| PlacementError::instance(format!("sensor type {name}"), "no visibility computed for it"))?;
        inst.types.push(SensorType { name: name.clone(), modality: vis.modality, price_usd: spec.price_usd() });
        for (row, &cand) in vis.rows.iter().zip(&vis.candidates) {
            let c = &prep.candidates[cand as usize];
            inst.options.push(SensorOption { ty, candidate: cand, mount: c.mount, row: row.clone() });
        }
    }
    inst.validate()?;
    Ok(inst)
}

/// Nonzeros above which CBC is not tried: at the default scale (millions of nonzeros) CBC spends
/// minutes in the root LP, where its time limit is not checked.
pub const CBC_MAX_NONZEROS: usize = 2_000_000;

/// An upper bound of the objective over every selection of at most `counts` sensors that needs
/// no search ([`counts_upper_bound`] and [`separable_upper_bound`], the tighter): loose, but
/// finite, so a placement that no exact method finished still states its gap.
pub fn counts_bound(inst: &Instance, counts: &[u32]) -> f64 {
    let kmax = counts.iter().copied().max().unwrap_or(0) as usize;
    let tops = top_visibilities(inst, kmax);
    counts_upper_bound(inst, counts, &tops).min(separable_upper_bound(inst, counts, &tops))
}

/// Solves an instance for a limit: greedy for a first solution; the exact search when the limit
/// asks for counts with one radar, or a budget (exact over the one-radar count vectors, with a
/// proven bound over the rest); otherwise CBC on the strengthened model, warm-started from
/// greedy, within the time limit, if the model is small enough. A result that is not proven
/// optimal carries its bound and gap.
pub fn solve(inst: &Instance, limit: &Limit, solve_limit: impl Into<SolveLimit>) -> Result<Outcome, PlacementError> {
    solve_from(inst, limit, solve_limit, &greedy(inst, limit))
}

/// The best placement that keeps the sensors of `fixed` (option indices) and places the rest
/// within `limit`: CBC on the strengthened model with their variables fixed to 1, so the result
/// is proven optimal over every selection holding them (or carries its bound when the time limit
/// stops CBC). `fixed` must be a feasible part of a selection: no option twice, no two on one
/// mount, no more of a type than the limit allows (its minimum counts aside).
pub fn solve_given(
    inst: &Instance,
    limit: &Limit,
    fixed: &[usize],
    solve_limit: impl Into<SolveLimit>,
) -> Result<Outcome, PlacementError> {
    let partial = match limit {
        Limit::Budget { usd, max, .. } => Limit::Budget { usd: *usd, min: Vec::new(), max: max.clone() },
        other => other.clone(),
    };
    inst.check(&partial, fixed).map_err(|e| PlacementError::instance("the given sensors", e.to_string()))?;
    let start = std::time::Instant::now();
    if let Some(sel) = enumerate_completions(inst, limit, fixed) {
        let method = format!("every completion of {} given sensor(s) evaluated", fixed.len());
        return Ok(Outcome::new(inst, sel, f64::INFINITY, true, start.elapsed().as_secs_f64(), &method));
    }
    let g = crate::greedy::greedy_given(inst, limit, fixed);
    let out = crate::mip::solve_fixing(inst, limit, Formulation::Strengthened, solve_limit, Some(&g.selection), fixed)?
        .no_worse_than(&g, 1e-9);
    if let Some(o) = fixed.iter().find(|o| !out.selection.contains(o)) {
        return Err(PlacementError::Solver(format!("CBC dropped the given option {o}")));
    }
    let method = format!("CBC, strengthened formulation, {} given sensor(s) fixed", fixed.len());
    Ok(Outcome { method, solve_seconds: start.elapsed().as_secs_f64(), ..out })
}

/// The most completions [`solve_given`] evaluates one by one instead of handing the problem to
/// CBC: a radar added to fixed LiDARs has a few hundred.
pub const MAX_COMPLETIONS: f64 = 200_000.0;

/// Under fixed counts, the best selection holding `fixed` by evaluating every completion (at
/// most the remaining count of each type, one sensor per mount), when there are at most
/// [`MAX_COMPLETIONS`] of them; None otherwise or under other limits. The objective only grows
/// with a sensor, so this is the optimum over every selection that holds `fixed`.
fn enumerate_completions(inst: &Instance, limit: &Limit, fixed: &[usize]) -> Option<Vec<usize>> {
    let Limit::Counts(counts) = limit else { return None };
    let taken: std::collections::HashSet<u32> = fixed.iter().map(|&o| inst.options[o].mount).collect();
    // Per type: the options still open and how many more it may hold.
    let mut open: Vec<(Vec<usize>, usize)> = Vec::new();
    for (t, &n) in counts.iter().enumerate() {
        let have = fixed.iter().filter(|&&o| inst.options[o].ty == t).count();
        let more = (n as usize).saturating_sub(have);
        let opts: Vec<usize> = (0..inst.options.len())
            .filter(|&o| inst.options[o].ty == t && !taken.contains(&inst.options[o].mount))
            .collect();
        if more > 0 && !opts.is_empty() {
            open.push((opts, more));
        }
    }
    // Subsets of at most k of n, per type, multiplied.
    let subsets = |n: usize, k: usize| -> f64 {
        let mut c = 1.0;
        let mut total = 1.0;
        for i in 0..k.min(n) {
            c *= (n - i) as f64 / (i + 1) as f64;
            total += c;
        }
        total
    };
    if open.iter().map(|(o, k)| subsets(o.len(), *k)).product::<f64>() > MAX_COMPLETIONS {
        return None;
    }
    let mut all: Vec<Vec<usize>> = vec![fixed.to_vec()];
    for (opts, k) in &open {
        let mut next = Vec::new();
        for base in &all {
            extend_subsets(inst, base, opts, 0, *k, &mut next);
        }
        all = next;
    }
    use rayon::prelude::*;
    all.into_par_iter()
        .map(|mut s| {
            s.sort_unstable();
            (crate::instance::evaluate(inst, &s), s)
        })
        .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)))
        .map(|x| x.1)
}

/// Pushes `base` with every subset of at most `k` of `opts[from..]` that keeps one sensor per mount.
fn extend_subsets(inst: &Instance, base: &[usize], opts: &[usize], from: usize, k: usize, out: &mut Vec<Vec<usize>>) {
    out.push(base.to_vec());
    if k == 0 {
        return;
    }
    for i in from..opts.len() {
        let o = opts[i];
        if base.iter().any(|&x| inst.options[x].mount == inst.options[o].mount) {
            continue;
        }
        let mut b = base.to_vec();
        b.push(o);
        extend_subsets(inst, &b, opts, i + 1, k - 1, out);
    }
}

/// [`solve`] from a greedy outcome the caller already has (`greedy(inst, limit)`), so a caller
/// that also reports the greedy objective does not run greedy twice. Its seconds are counted in
/// the result's `solve_seconds`.
pub fn solve_from(
    inst: &Instance,
    limit: &Limit,
    solve_limit: impl Into<SolveLimit>,
    g: &Outcome,
) -> Result<Outcome, PlacementError> {
    let solve_limit: SolveLimit = solve_limit.into();
    let time_limit_s = solve_limit.seconds;
    // The exact searches stop at the time limit too, with their best selection and bound.
    let deadline = (time_limit_s.is_finite() && time_limit_s >= 0.0)
        .then(|| std::time::Instant::now() + std::time::Duration::from_secs_f64(time_limit_s.min(1e7)));
    let mut fallback = g.clone();
    if let Limit::Counts(c) = limit {
        let of = |m: Modality| {
            (0..inst.types.len()).filter(move |&t| inst.types[t].modality == m && c.get(t).is_some_and(|n| *n > 0))
        };
        let radars: u32 = of(Modality::Radar).map(|t| c[t]).sum();
        let lidar_types: Vec<usize> = of(Modality::Lidar).collect();
        // One modality offered: its own coverage objective, searched exactly.
        if !(inst.requires(Modality::Lidar) && inst.requires(Modality::Radar)) {
            let (mut out, proven) = crate::exact::exact_single(inst, c, &g.selection, 50_000_000, deadline)?;
            out.solve_seconds += g.solve_seconds;
            if proven {
                return Ok(out);
            }
            fallback = out;
        } else if radars == 1 {
            let (mut out, _) = exact_counts(inst, c, &g.selection, deadline)?;
            out.solve_seconds += g.solve_seconds;
            return Ok(out);
        } else if radars > 1 && lidar_types.len() == 1 && c[lidar_types[0]] <= 2 {
            // Several radars with one LiDAR type (at most two): the LiDAR-first exact search.
            let (mut out, proven) = exact_lidar_first(inst, c, &g.selection, 50_000_000, deadline)?;
            out.solve_seconds += g.solve_seconds;
            if proven {
                return Ok(out);
            }
            fallback = out;
        }
    }
    if let Limit::Budget { usd, min, max } = limit {
        let (mut out, _) = crate::exact::exact_budget(inst, *usd, min, max, &g.selection, deadline)?;
        out.solve_seconds += g.solve_seconds;
        if out.proven_optimal {
            return Ok(out);
        }
        fallback = out;
    }
    let nonzeros: usize = inst.options.iter().map(|o| o.row.len()).sum::<usize>() * 3;
    // CBC gets what is left of the time limit (none left: the exact search's result stands).
    let left = deadline.map_or(time_limit_s, |d| d.saturating_duration_since(std::time::Instant::now()).as_secs_f64());
    if nonzeros > CBC_MAX_NONZEROS || left <= 0.0 {
        // No search proves more here: state how far the answer can be from the optimum.
        let cheap = match limit {
            Limit::Counts(c) => counts_bound(inst, c),
            _ => f64::INFINITY,
        };
        let bound = fallback.bound.min(cheap).max(fallback.objective);
        return Ok(Outcome {
            bound,
            gap: (bound - fallback.objective) / fallback.objective.abs().max(1e-9),
            ..fallback
        });
    }
    let out = solve_mip(
        inst,
        limit,
        Formulation::Strengthened,
        SolveLimit { seconds: left, ..solve_limit },
        Some(&g.selection),
    )?;
    // CBC may stop with something worse than its warm start: never return less than greedy.
    Ok(out.no_worse_than(g, 1e-9))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A hit floor is read per class, refused outside (0, 1], for an unknown class and with the
    /// paper's objective (which does not read it), and shown in the settings' text only when
    /// set, so a study without one keeps its content hashes.
    #[test]
    fn hit_floors_are_checked_and_shown_only_when_set() {
        let calibrated = "objective = \"calibrated\"\ncalibration = { lidar = 1.0, radar = 0.0 }\n";
        let read = |text: &str| toml::from_str::<PlacementConfig>(text);
        let c = read(&format!("{calibrated}min_hit_share = {{ pedestrian = 0.95, car = 1.0 }}")).unwrap();
        assert_eq!(c.min_hit_share.get(&hilo_core::Class::Pedestrian), Some(&0.95));
        assert!(c.clone().validate().is_ok());
        assert!(format!("{c:?}").ends_with(", min_hit_share: {Car: 1.0, Pedestrian: 0.95} }"), "{c:?}");
        let plain = PlacementConfig::default();
        assert!(!format!("{plain:?}").contains("min_hit_share"));
        assert!(
            format!("{plain:?}")
                .ends_with(&format!("calibrated_cbc_max_nonzeros: {} }}", plain.calibrated_cbc_max_nonzeros))
        );
        for (share, said) in
            [("0.0", "must be a share in (0, 1]"), ("1.5", "must be a share in (0, 1]"), ("nan", "(0, 1]")]
        {
            let e = read(&format!("{calibrated}min_hit_share = {{ pedestrian = {share} }}"))
                .unwrap()
                .validate()
                .unwrap_err();
            assert!(
                e.to_string().starts_with("placement.min_hit_share.pedestrian = ") && e.to_string().contains(said),
                "{e}"
            );
        }
        let e = read("min_hit_share = { pedestrian = 0.9 }").unwrap().validate().unwrap_err().to_string();
        assert!(e.contains("placement.min_hit_share.pedestrian = 0.9") && e.contains("calibrated objective"), "{e}");
        let e = read(&format!("{calibrated}min_hit_share = {{ pedestrians = 0.9 }}")).unwrap_err().to_string();
        assert!(e.contains("pedestrians"), "{e}");
    }
}
