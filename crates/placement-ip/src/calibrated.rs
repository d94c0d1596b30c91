//! The calibrated objective: accuracy predicted from saturated coverage, weighted per modality
//! by what trained detectors measured (`hilo validate` fits the weights).
//!
//! f(S) = Σ_m Σ_{k ∈ {1, 2}} β_mk Σ_j (w_j / W) min(1, s_mj / k), with s_mj = Σ_{o ∈ S_m}
//! min(1, a_oj / τ), a_oj = −ln(1 − V_oj), W = Σ_j w_j and β_mk ≥ 0. The k = 1 term is the
//! paper's coverage made partial (a target partly seen counts in part; min(1, s) = min(1, Σ a / τ));
//! the k = 2 term counts a target fully only when two sensors each see it well, so it pays for
//! the second viewpoint (other sides of a road user, views past occluders) that one denser
//! sensor cannot give. A modality the detectors gain nothing from (β = 0) is worth nothing to
//! the optimiser. As an IP: maximise Σ_mkj β_mk (w_j / W) z_mkj with 0 ≤ z_mkj ≤ 1 and
//! z_mkj ≤ Σ_{o ∈ m} (min(1, a_oj / τ) / k) x_o, the limit and one sensor per mount; z needs
//! no integrality (with β ≥ 0 the optimum sets each z to its cap). f is monotone and submodular
//! (a non-negative sum of concave functions of modular sums), so greedy is a
//! (1 − 1/e)-approximation under a count limit; CBC, warm-started from greedy, closes or bounds
//! the gap.

use crate::candidates::Modality;
use crate::error::PlacementError;
use crate::instance::{Instance, Limit, Outcome, coverage_coef};
use good_lp::solvers::coin_cbc::coin_cbc;
use good_lp::{
    Expression, ProblemVariables, Solution, SolutionStatus, SolverModel, Variable, WithInitialSolution, WithTimeLimit,
    variable,
};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// The weights (mAP per unit of saturated coverage): per modality, of the coverage term and of
/// the two-view term (`lidar_two_views`, `radar_two_views`; 0 when absent).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Weights {
    pub lidar: f64,
    pub radar: f64,
    #[serde(default)]
    pub lidar_two_views: f64,
    #[serde(default)]
    pub radar_two_views: f64,
}

impl Weights {
    /// Only the terms saturating at τ.
    pub fn once(lidar: f64, radar: f64) -> Self {
        Weights { lidar, radar, ..Weights::default() }
    }

    /// The terms: (modality, views k that count a target fully, weight), zero weights included.
    fn terms(&self) -> [(Modality, f64, f64); 4] {
        [
            (Modality::Lidar, 1.0, self.lidar),
            (Modality::Radar, 1.0, self.radar),
            (Modality::Lidar, 2.0, self.lidar_two_views),
            (Modality::Radar, 2.0, self.radar_two_views),
        ]
    }

    /// Refuses weights that would not keep the objective an IP with capped terms.
    pub fn check(&self) -> Result<(), PlacementError> {
        for (name, v) in [
            ("lidar", self.lidar),
            ("radar", self.radar),
            ("lidar_two_views", self.lidar_two_views),
            ("radar_two_views", self.radar_two_views),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(PlacementError::Invalid(format!(
                    "placement.calibration.{name} = {v}: a weight must be finite and ≥ 0"
                )));
            }
        }
        if self.terms().iter().all(|t| t.2 == 0.0) {
            return Err(PlacementError::Invalid(
                "placement.calibration: every weight is 0; nothing to maximise".into(),
            ));
        }
        Ok(())
    }
}

/// The calibrated objective of a selection.
pub fn evaluate(inst: &Instance, sel: &[usize], w: &Weights) -> f64 {
    let tau = inst.tau();
    let total: f64 = inst.weights.iter().sum::<f64>().max(1e-12);
    let mut f = 0.0;
    for (m, k, beta) in w.terms() {
        if beta == 0.0 {
            continue;
        }
        let s = views(inst, sel, m, tau);
        f += beta * s.iter().zip(&inst.weights).map(|(s, wj)| wj * (s / k).min(1.0)).sum::<f64>() / total;
    }
    f
}

/// Per target, s_j = Σ_{o ∈ sel, of modality m} min(1, a_oj / τ): how many sensors see it well,
/// each counting at most once.
fn views(inst: &Instance, sel: &[usize], m: Modality, tau: f64) -> Vec<f64> {
    let mut s = vec![0.0; inst.n_targets()];
    for &o in sel.iter().filter(|&&o| inst.modality(o) == m) {
        for &(j, v) in &inst.options[o].row {
            s[j as usize] += (coverage_coef(v as f64) / tau).min(1.0);
        }
    }
    s
}

/// Whether `sel` plus option `o` stays within `limit` (minimum counts are not asked of a
/// partial selection).
fn can_add(inst: &Instance, limit: &Limit, sel: &[usize], o: usize) -> bool {
    let opt = &inst.options[o];
    if sel.iter().any(|&x| x == o || inst.options[x].mount == opt.mount) {
        return false;
    }
    let same = sel.iter().filter(|&&x| inst.options[x].ty == opt.ty).count() as u32 + 1;
    match limit {
        Limit::Counts(c) => same <= c.get(opt.ty).copied().unwrap_or(0),
        Limit::Total(n) => sel.len() < *n as usize,
        Limit::Budget { usd, max, .. } => {
            inst.cost(sel) + inst.types[opt.ty].price_usd <= usd + 1e-6
                && same <= max.get(opt.ty).copied().unwrap_or(u32::MAX)
        }
    }
}

/// Greedy by marginal gain (per dollar under a budget) until nothing more fits or helps.
pub fn greedy(inst: &Instance, limit: &Limit, w: &Weights) -> Outcome {
    let start = Instant::now();
    let mut sel: Vec<usize> = Vec::new();
    let mut f = evaluate(inst, &sel, w);
    let budget = matches!(limit, Limit::Budget { .. });
    loop {
        let best = (0..inst.options.len())
            .filter(|&o| can_add(inst, limit, &sel, o))
            .map(|o| {
                let mut s = sel.clone();
                s.push(o);
                let gain = evaluate(inst, &s, w) - f;
                let price = if budget { inst.types[inst.options[o].ty].price_usd.max(1e-9) } else { 1.0 };
                (gain / price, gain, o)
            })
            .filter(|x| x.1 > 1e-12)
            .max_by(|a, b| a.0.total_cmp(&b.0).then(b.2.cmp(&a.2)));
        match best {
            Some((_, gain, o)) => {
                sel.push(o);
                f += gain;
            }
            None => break,
        }
    }
    sel.sort_unstable();
    outcome(inst, sel, w, f64::INFINITY, false, start, "greedy, calibrated objective")
}

fn outcome(
    inst: &Instance,
    sel: Vec<usize>,
    w: &Weights,
    bound: f64,
    proven: bool,
    start: Instant,
    method: &str,
) -> Outcome {
    let objective = evaluate(inst, &sel, w);
    let bound = if proven { objective } else { bound.max(objective) };
    Outcome {
        gap: (bound - objective) / objective.abs().max(1e-9),
        selection: sel,
        objective,
        bound,
        proven_optimal: proven,
        solve_seconds: start.elapsed().as_secs_f64(),
        method: method.to_owned(),
    }
}

/// Solves the calibrated IP with CBC within `time_limit_s`, warm-started from `warm`; never
/// returns less than the warm start.
pub fn solve(
    inst: &Instance,
    limit: &Limit,
    w: &Weights,
    time_limit_s: f64,
    warm: &Outcome,
) -> Result<Outcome, PlacementError> {
    let start = Instant::now();
    w.check()?;
    let tau = inst.tau();
    let total: f64 = inst.weights.iter().sum::<f64>().max(1e-12);
    let mut vars = ProblemVariables::new();
    let x: Vec<Variable> = (0..inst.options.len()).map(|_| vars.add(variable().binary())).collect();
    let mut cols: Vec<Vec<Vec<(usize, f64)>>> = vec![vec![Vec::new(); inst.n_targets()]; 2];
    for (o, opt) in inst.options.iter().enumerate() {
        let m = usize::from(inst.modality(o) == Modality::Radar);
        for &(j, v) in &opt.row {
            cols[m][j as usize].push((o, coverage_coef(v as f64) / tau));
        }
    }
    // (variable, objective coefficient, modality, saturation multiple, target)
    let mut z: Vec<(Variable, f64, usize, f64, usize)> = Vec::new();
    for (modality, k, beta) in w.terms() {
        if beta == 0.0 {
            continue;
        }
        let m = usize::from(modality == Modality::Radar);
        for (j, col) in cols[m].iter().enumerate() {
            if !col.is_empty() && inst.weights[j] > 0.0 {
                z.push((vars.add(variable().min(0.0).max(1.0)), beta * inst.weights[j] / total, m, k, j));
            }
        }
    }
    let objective: Expression = z.iter().map(|&(v, c, ..)| c * v).sum();
    let mut problem = vars.maximise(objective).using(coin_cbc);
    problem.set_parameter("log", "0");
    for &(v, _, m, k, j) in &z {
        let cover: Expression = cols[m][j].iter().map(|&(o, a)| (a.min(1.0) / k) * x[o]).sum();
        problem.add_constraint((v - cover).leq(0.0));
    }
    crate::mip::add_limit(&mut problem, inst, limit, &x);
    let mut problem = problem.with_time_limit(time_limit_s.max(1.0));
    let chosen: std::collections::HashSet<usize> = warm.selection.iter().copied().collect();
    let mut init: Vec<(Variable, f64)> =
        x.iter().enumerate().map(|(o, &v)| (v, if chosen.contains(&o) { 1.0 } else { 0.0 })).collect();
    let s: Vec<Vec<f64>> =
        [Modality::Lidar, Modality::Radar].iter().map(|&m| views(inst, &warm.selection, m, tau)).collect();
    init.extend(z.iter().map(|&(v, _, m, k, j)| (v, (s[m][j] / k).min(1.0))));
    problem = problem.with_initial_solution(init);
    let sol = problem.solve().map_err(|e| PlacementError::Solver(format!("CBC, calibrated objective: {e}")))?;
    let proven = matches!(sol.status(), SolutionStatus::Optimal);
    let bound = sol.model().best_possible_value();
    let selection: Vec<usize> = x.iter().enumerate().filter(|(_, v)| sol.value(**v) > 0.5).map(|(o, _)| o).collect();
    let out = outcome(
        inst,
        selection,
        w,
        if bound.is_finite() { bound } else { f64::INFINITY },
        proven,
        start,
        "CBC, calibrated objective",
    );
    Ok(out.no_worse_than(warm, 1e-12))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::instance::{SensorOption, SensorType};
    use rand::{Rng, SeedableRng};

    fn random_instance(seed: u64) -> Instance {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let types = vec![
            SensorType { name: "l".into(), modality: Modality::Lidar, price_usd: 4.0 },
            SensorType { name: "r".into(), modality: Modality::Radar, price_usd: 2.0 },
        ];
        let options = (0..12)
            .map(|i| {
                let mut row = Vec::new();
                for j in 0..25u32 {
                    if rng.random::<f32>() < 0.35 {
                        row.push((j, rng.random_range(0.05f32..0.99)));
                    }
                }
                SensorOption { ty: i % 2, candidate: i as u32, mount: (i / 2) as u32, row }
            })
            .collect();
        Instance {
            weights: (0..25).map(|_| rng.random_range(0.5..3.0)).collect(),
            types,
            options,
            p_min: 1.0 - (-1.0f64).exp(),
        }
    }

    /// Every feasible selection of a small instance, by brute force.
    fn brute(inst: &Instance, limit: &Limit, w: &Weights) -> f64 {
        let n = inst.options.len();
        (0u32..1 << n)
            .map(|mask| (0..n).filter(|o| mask & (1 << o) != 0).collect::<Vec<_>>())
            .filter(|s| inst.check(limit, s).is_ok())
            .map(|s| evaluate(inst, &s, w))
            .fold(0.0, f64::max)
    }

    /// CBC on the calibrated IP equals brute force over every selection, under counts and under
    /// a budget, with both weights, with the radar's at 0 and with the two-view terms;
    /// greedy is never above it.
    #[test]
    fn the_calibrated_ip_equals_brute_force() {
        for seed in 0..6 {
            let inst = random_instance(seed);
            let w = match seed % 3 {
                0 => Weights::once(0.6, 0.2),
                1 => Weights::once(0.5, 0.0),
                _ => Weights { lidar: 0.3, radar: 0.1, lidar_two_views: 0.4, radar_two_views: 0.05 },
            };
            for limit in [Limit::Counts(vec![2, 1]), Limit::Budget { usd: 10.0, min: vec![0, 0], max: vec![9, 9] }] {
                let g = greedy(&inst, &limit, &w);
                let out = solve(&inst, &limit, &w, 30.0, &g).unwrap();
                let best = brute(&inst, &limit, &w);
                assert!(inst.check(&limit, &out.selection).is_ok());
                assert!((out.objective - best).abs() < 1e-6, "seed {seed} {limit:?}: {} vs {best}", out.objective);
                assert!(g.objective <= best + 1e-9);
            }
        }
    }

    /// Saturation: a target seen beyond τ counts once; half-seen counts half.
    #[test]
    fn coverage_saturates_at_the_threshold() {
        let inst = Instance {
            weights: vec![1.0, 1.0],
            types: vec![SensorType { name: "l".into(), modality: Modality::Lidar, price_usd: 1.0 }],
            options: vec![SensorOption {
                ty: 0,
                candidate: 0,
                mount: 0,
                row: vec![(0, 0.99), (1, (1.0 - (-0.5f64).exp()) as f32)],
            }],
            p_min: 1.0 - (-1.0f64).exp(),
        };
        let f = evaluate(&inst, &[0], &Weights::once(1.0, 0.0));
        assert!((f - (1.0 + 0.5) / 2.0).abs() < 1e-6, "{f}");
        // Two views: one sensor, however well it sees (a ≈ 4.6 τ), counts a target half.
        let f2 = evaluate(&inst, &[0], &Weights { lidar_two_views: 1.0, ..Weights::default() });
        assert!((f2 - (0.5 + 0.25) / 2.0).abs() < 1e-6, "{f2}");
        assert!(Weights::once(-0.1, 1.0).check().is_err());
        assert!(Weights { radar_two_views: -0.1, ..Weights::once(1.0, 0.0) }.check().is_err());
        assert!(Weights::default().check().is_err());
    }
}
