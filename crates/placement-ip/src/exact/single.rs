//! Count vectors of one modality (LiDARs only, or radars only): a branch and bound over the
//! options in the order of a separable bound.
//!
//! An instance that offers one modality asks only for that modality's coverage
//! ([`Instance::requires`]), so f(S) = Σ_{j covered by S} w_j Σ_{o ∈ S} V_oj. The targets any
//! selection with these counts could cover (the best `counts[t]` coverage coefficients of each
//! type reach τ) are fixed up front, and each option is worth at most
//! u_o = Σ_{j coverable} w_j V_oj, so f(S) ≤ Σ_{o ∈ S} u_o. Options are searched depth-first in
//! descending u, one per mount, pruning a branch whose chosen u plus the best remaining u of
//! each type's open slots cannot beat the incumbent; full selections are evaluated exactly
//! (adding a sensor never lowers f, so an optimum fills every slot the mounts allow).

use super::{Stop, counts_upper_bound, top_visibilities};
use crate::candidates::Modality;
use crate::error::PlacementError;
use crate::instance::{Instance, Outcome, Scratch, coverage_coef, evaluate_with};
use std::time::Instant;

/// Solves `Limit::Counts(counts)` exactly for an instance of one modality. `incumbent` (e.g.
/// greedy's selection) seeds the pruning. When `node_budget` or `deadline` runs out the best
/// selection is returned unproven, bounded by [`counts_upper_bound`]. Returns (outcome, proven).
pub fn exact_single(
    inst: &Instance,
    counts: &[u32],
    incumbent: &[usize],
    node_budget: u64,
    deadline: Option<Instant>,
) -> Result<(Outcome, bool), PlacementError> {
    let start = Instant::now();
    if inst.requires(Modality::Lidar) && inst.requires(Modality::Radar) {
        return Err(PlacementError::instance("the single-modality search", "takes an instance of one modality"));
    }
    let count = |t: usize| counts.get(t).copied().unwrap_or(0) as usize;
    let k_max = (0..inst.types.len()).map(count).max().unwrap_or(0);
    let tops = top_visibilities(inst, k_max);
    let tau = inst.tau() * (1.0 - 1e-9);
    let coverable: Vec<bool> = (0..inst.n_targets())
        .map(|j| {
            let a: f64 = (0..inst.types.len())
                .flat_map(|t| tops[t][j].iter().take(count(t)))
                .map(|&v| coverage_coef(v as f64))
                .sum();
            a >= tau
        })
        .collect();
    let mut order: Vec<(f64, usize)> = (0..inst.options.len())
        .filter(|&o| count(inst.options[o].ty) > 0)
        .map(|o| {
            let u = inst.options[o]
                .row
                .iter()
                .filter(|(j, _)| coverable[*j as usize])
                .map(|&(j, v)| inst.weights[j as usize] * v as f64)
                .sum::<f64>();
            (u, o)
        })
        .collect();
    order.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut search = Search {
        inst,
        order: &order,
        open: (0..inst.types.len()).map(count).collect(),
        mounts: Vec::new(),
        chosen: Vec::new(),
        best: evaluate_with(inst, incumbent, &mut Scratch::new(inst.n_targets())),
        best_sel: incumbent.to_vec(),
        scratch: Scratch::new(inst.n_targets()),
        stop: Stop { deadline, stopped: false, nodes: 0, budget: node_budget },
    };
    search.dfs(0, 0.0);
    let proven = !search.stop.stopped;
    let bound = if proven { search.best } else { counts_upper_bound(inst, counts, &tops).max(search.best) };
    let mut sel = search.best_sel;
    sel.sort_unstable();
    let method = "exact search over one modality's options";
    Ok((Outcome::new(inst, sel, bound, proven, start.elapsed().as_secs_f64(), method), proven))
}

struct Search<'a> {
    inst: &'a Instance,
    /// (u, option), u descending.
    order: &'a [(f64, usize)],
    /// Slots still open per type.
    open: Vec<usize>,
    mounts: Vec<u32>,
    chosen: Vec<usize>,
    best: f64,
    best_sel: Vec<usize>,
    scratch: Scratch,
    stop: Stop,
}

impl Search<'_> {
    /// The best u the open slots could still add from position `i` on.
    fn remaining(&self, i: usize) -> f64 {
        let mut left = self.open.clone();
        let mut slots: usize = left.iter().sum();
        let mut sum = 0.0;
        for &(u, o) in &self.order[i..] {
            if slots == 0 {
                break;
            }
            let t = self.inst.options[o].ty;
            if left[t] > 0 && !self.mounts.contains(&self.inst.options[o].mount) {
                left[t] -= 1;
                slots -= 1;
                sum += u;
            }
        }
        sum
    }

    fn leaf(&mut self) {
        let f = evaluate_with(self.inst, &self.chosen, &mut self.scratch);
        if f > self.best + 1e-12 {
            self.best = f;
            self.best_sel = self.chosen.clone();
        }
    }

    fn dfs(&mut self, i: usize, u_sum: f64) {
        if self.stop.tick() {
            return;
        }
        if self.open.iter().all(|&n| n == 0) {
            self.leaf();
            return;
        }
        let mut any = false;
        for pos in i..self.order.len() {
            if u_sum + self.remaining(pos) <= self.best + 1e-9 {
                break;
            }
            let (u, o) = self.order[pos];
            let opt = &self.inst.options[o];
            if self.open[opt.ty] == 0 || self.mounts.contains(&opt.mount) {
                continue;
            }
            any = true;
            self.open[opt.ty] -= 1;
            self.mounts.push(opt.mount);
            self.chosen.push(o);
            self.dfs(pos + 1, u_sum + u);
            self.chosen.pop();
            self.mounts.pop();
            self.open[opt.ty] += 1;
            if self.stop.stopped {
                return;
            }
        }
        // No option left to add (too few mounts): the partial selection is a leaf.
        if !any && !self.chosen.is_empty() {
            self.leaf();
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::exhaustive::exhaustive;
    use crate::instance::{Limit, SensorOption, SensorType};
    use rand::{Rng, SeedableRng};

    /// A random instance of LiDAR types only: options on `mounts` mounts with sparse rows.
    fn lidar_instance(seed: u64, types: usize, options: usize, mounts: u32, targets: usize) -> Instance {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let types = (0..types)
            .map(|t| SensorType { name: format!("l{t}"), modality: Modality::Lidar, price_usd: 1.0 })
            .collect::<Vec<_>>();
        let options = (0..options)
            .map(|i| {
                let mut row: Vec<(u32, f32)> = Vec::new();
                for j in 0..targets as u32 {
                    if rng.random::<f32>() < 0.4 {
                        row.push((j, rng.random_range(0.05f32..0.95)));
                    }
                }
                SensorOption { ty: i % types.len(), candidate: i as u32, mount: rng.random_range(0..mounts), row }
            })
            .collect();
        Instance {
            weights: (0..targets).map(|_| rng.random_range(0.5..2.0)).collect(),
            types,
            options,
            p_min: 1.0 - (-1.0f64).exp(),
            road_users: Vec::new(),
            points: Default::default(),
            extents: Default::default(),
            floors: Vec::new(),
        }
    }

    /// The exhaustive oracle agrees on random LiDAR-only instances, one and two types.
    #[test]
    fn single_modality_search_matches_the_exhaustive_oracle() {
        for seed in 0..12 {
            let types = 1 + (seed as usize % 2);
            let inst = lidar_instance(seed, types, 14, 9, 30);
            let counts: Vec<u32> = if types == 1 { vec![2] } else { vec![1, 2] };
            let limit = Limit::Counts(counts.clone());
            let oracle = exhaustive(&inst, &limit, 10_000_000).unwrap();
            let (out, proven) = exact_single(&inst, &counts, &[], u64::MAX, None).unwrap();
            assert!(proven);
            assert!(
                (out.objective - oracle.objective).abs() < 1e-9,
                "seed {seed}: {} vs {}",
                out.objective,
                oracle.objective
            );
            assert!(inst.check(&limit, &out.selection).is_ok());
        }
    }

    /// A LiDAR-only objective is the weighted visibility of the LiDAR-covered targets (closed
    /// form on two targets): it does not ask for a radar.
    #[test]
    fn a_lidar_only_instance_asks_for_lidar_coverage_only() {
        let inst = Instance {
            weights: vec![1.0, 2.0],
            types: vec![SensorType { name: "l".into(), modality: Modality::Lidar, price_usd: 1.0 }],
            options: vec![
                SensorOption { ty: 0, candidate: 0, mount: 0, row: vec![(0, 0.9), (1, 0.3)] },
                SensorOption { ty: 0, candidate: 1, mount: 1, row: vec![(1, 0.5)] },
            ],
            p_min: 1.0 - (-1.0f64).exp(),
            road_users: Vec::new(),
            points: Default::default(),
            extents: Default::default(),
            floors: Vec::new(),
        };
        // Option 0 alone covers target 0 (−ln 0.1 ≥ 1), not target 1 (−ln 0.7 < 1).
        assert!((crate::instance::evaluate(&inst, &[0]) - 0.9).abs() < 1e-6);
        // Together target 1 reaches −ln 0.7 − ln 0.5 = 1.05 ≥ 1: 0.9 + 2 (0.3 + 0.5).
        assert!((crate::instance::evaluate(&inst, &[0, 1]) - 2.5).abs() < 1e-6);
        let (out, proven) = exact_single(&inst, &[2], &[], u64::MAX, None).unwrap();
        assert!(proven && (out.objective - 2.5).abs() < 1e-6);
    }

    /// A node budget of one stops the search unproven, with a bound no lower than the optimum.
    #[test]
    fn a_stopped_search_returns_a_valid_bound() {
        let inst = lidar_instance(3, 1, 14, 9, 30);
        let oracle = exhaustive(&inst, &Limit::Counts(vec![2]), 10_000_000).unwrap();
        let (out, proven) = exact_single(&inst, &[2], &[], 1, None).unwrap();
        assert!(!proven);
        assert!(out.bound + 1e-9 >= oracle.objective);
    }
}
