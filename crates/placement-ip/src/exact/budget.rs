//! The budgeted problem: sensor types chosen per candidate under a dollar budget, solved over the
//! maximal count vectors the budget allows, each bounded before it is searched.

use super::{exact_counts, exact_lidar_first, past};
use crate::candidates::Modality;
use crate::error::PlacementError;
use crate::instance::{Instance, Outcome, coverage_coef};
use rayon::prelude::*;
use std::time::Instant;

/// Every per-type count vector that fits `usd` and the min/max counts and to which no further
/// sensor can be added (the objective never falls when a sensor is added, so an optimum is
/// among these).
pub fn maximal_count_vectors(inst: &Instance, usd: f64, min: &[u32], max: &[u32]) -> Vec<Vec<u32>> {
    let nt = inst.types.len();
    // No more of a type than it has options (this bounds a free type, which money does not).
    let options = inst.options_per_type();
    let cap = |t: usize| max.get(t).copied().unwrap_or(u32::MAX).min(options[t] as u32);
    let mut out = Vec::new();
    let mut cur = vec![0u32; nt];
    fn rec(
        inst: &Instance,
        t: usize,
        left: f64,
        cur: &mut Vec<u32>,
        min: &[u32],
        cap: &dyn Fn(usize) -> u32,
        out: &mut Vec<Vec<u32>>,
    ) {
        if t == inst.types.len() {
            let fits_more = (0..inst.types.len()).any(|k| inst.types[k].price_usd <= left + 1e-9 && cur[k] < cap(k));
            let mins = (0..inst.types.len()).all(|k| cur[k] >= min.get(k).copied().unwrap_or(0));
            if !fits_more && mins {
                out.push(cur.clone());
            }
            return;
        }
        let price = inst.types[t].price_usd;
        let most = if price > 0.0 { ((left + 1e-9) / price).floor() as u32 } else { cap(t) };
        for n in 0..=most.min(cap(t)) {
            cur[t] = n;
            rec(inst, t + 1, left - n as f64 * price, cur, min, cap, out);
        }
        cur[t] = 0;
    }
    rec(inst, 0, usd, &mut cur, min, &cap, &mut out);
    out
}

/// An upper bound of the objective over all selections with at most `counts[t]` sensors of each
/// type: per target, the best `counts[t]` visibilities of each type, counted only where the best
/// coverage coefficients of every required modality could reach τ.
pub fn counts_upper_bound(inst: &Instance, counts: &[u32], tops: &[Vec<Vec<f32>>]) -> f64 {
    let tau = inst.tau() * (1.0 - 1e-9);
    (0..inst.n_targets())
        .map(|j| {
            let (mut rho, mut a_l, mut a_r) = (0.0, 0.0, 0.0);
            for (t, ty) in inst.types.iter().enumerate() {
                for &v in tops[t][j].iter().take(counts.get(t).copied().unwrap_or(0) as usize) {
                    rho += v as f64;
                    let a = coverage_coef(v as f64);
                    if ty.modality == Modality::Lidar { a_l += a } else { a_r += a }
                }
            }
            if inst.counts_target(a_l, a_r, tau) { inst.weights[j] * rho } else { 0.0 }
        })
        .sum()
}

/// A second upper bound for a count vector, consistent across targets: each sensor is worth at
/// most its weighted visibility over the targets both modalities could cover with these counts,
/// u_o = Σ_{j coverable} w_j V_oj, and a selection at most the sum of the best `counts[t]` u_o
/// of each type. It is never looser than [`counts_upper_bound`] (which lets every target pick
/// its own best sensors).
pub fn separable_upper_bound(inst: &Instance, counts: &[u32], tops: &[Vec<Vec<f32>>]) -> f64 {
    let tau = inst.tau() * (1.0 - 1e-9);
    let coverable: Vec<bool> = (0..inst.n_targets())
        .map(|j| {
            let (mut a_l, mut a_r) = (0.0, 0.0);
            for (t, ty) in inst.types.iter().enumerate() {
                for &v in tops[t][j].iter().take(counts.get(t).copied().unwrap_or(0) as usize) {
                    let a = coverage_coef(v as f64);
                    if ty.modality == Modality::Lidar { a_l += a } else { a_r += a }
                }
            }
            inst.counts_target(a_l, a_r, tau)
        })
        .collect();
    (0..inst.types.len())
        .map(|t| {
            let mut u: Vec<f64> = inst
                .options
                .iter()
                .filter(|o| o.ty == t)
                .map(|o| {
                    o.row
                        .iter()
                        .filter(|(j, _)| coverable[*j as usize])
                        .map(|&(j, v)| inst.weights[j as usize] * v as f64)
                        .sum()
                })
                .collect();
            u.sort_by(|a, b| b.total_cmp(a));
            u.iter().take(counts.get(t).copied().unwrap_or(0) as usize).sum::<f64>()
        })
        .sum()
}

/// Per type, per target: the visibilities sorted descending, at most `k` kept.
pub fn top_visibilities(inst: &Instance, k: usize) -> Vec<Vec<Vec<f32>>> {
    (0..inst.types.len())
        .map(|t| {
            let mut tops: Vec<Vec<f32>> = vec![Vec::new(); inst.n_targets()];
            for o in inst.options.iter().filter(|o| o.ty == t) {
                for &(j, v) in &o.row {
                    tops[j as usize].push(v);
                }
            }
            for l in &mut tops {
                l.sort_by(|a, b| b.total_cmp(a));
                l.truncate(k);
            }
            tops
        })
        .collect()
}

/// Per count vector searched: the counts and the optimum found (NaN where not searched).
pub type VectorReport = Vec<(Vec<u32>, f64)>;

/// The budgeted problem (sensor types chosen per candidate, a dollar budget, per-type min/max):
/// decomposed into the maximal count vectors the budget allows, each bounded by the smaller of
/// [`counts_upper_bound`] and [`separable_upper_bound`]; vectors are solved exactly in bound order
/// (one radar: [`exact_counts`]; several radars and at most two LiDARs of one type:
/// [`exact_lidar_first`]) until no remaining vector's bound beats the incumbent. Any other vector
/// whose bound still beats the incumbent is not searched: the outcome is then labelled unproven,
/// with that bound. At `deadline` the search stops with the best selection and the largest bound
/// of what it did not finish.
pub fn exact_budget(
    inst: &Instance,
    usd: f64,
    min: &[u32],
    max: &[u32],
    incumbent: &[usize],
    deadline: Option<Instant>,
) -> Result<(Outcome, VectorReport), PlacementError> {
    let start = Instant::now();
    let vectors = maximal_count_vectors(inst, usd, min, max);
    if vectors.is_empty() {
        return Err(PlacementError::Infeasible(format!(
            "no combination of sensors fits the budget of {usd} USD and the per-type minimums"
        )));
    }
    let kmax = vectors.iter().flatten().copied().max().unwrap_or(0) as usize;
    let tops = top_visibilities(inst, kmax);
    let mut ranked: Vec<(f64, Vec<u32>)> = vectors
        .into_par_iter()
        .map(|c| (counts_upper_bound(inst, &c, &tops).min(separable_upper_bound(inst, &c, &tops)), c))
        .collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best_sel = incumbent.to_vec();
    let mut best = crate::instance::evaluate(inst, incumbent);
    let mut open_bound: f64 = f64::NEG_INFINITY;
    let mut report = Vec::new();
    for (ub, counts) in &ranked {
        if *ub <= best + 1e-9 {
            break;
        }
        if past(deadline) {
            open_bound = open_bound.max(*ub); // the vectors left are bounded by this one's
            break;
        }
        let radars: u32 =
            (0..inst.types.len()).filter(|&t| inst.types[t].modality == Modality::Radar).map(|t| counts[t]).sum();
        let lidar_types: Vec<usize> =
            (0..inst.types.len()).filter(|&t| inst.types[t].modality == Modality::Lidar && counts[t] > 0).collect();
        if radars >= 2 && lidar_types.len() == 1 && counts[lidar_types[0]] <= 2 {
            let (out, proven) = exact_lidar_first(inst, counts, &best_sel, 50_000_000, deadline)?;
            report.push((counts.clone(), out.objective));
            if !proven {
                open_bound = open_bound.max(out.bound.min(*ub));
            }
            if out.objective > best + 1e-12 {
                best = out.objective;
                best_sel = out.selection;
            }
        } else if radars == 1 {
            let (out, _) = exact_counts(inst, counts, &best_sel, deadline)?;
            report.push((counts.clone(), out.objective));
            if !out.proven_optimal {
                open_bound = open_bound.max(out.bound.min(*ub));
            }
            if out.objective > best + 1e-12 {
                best = out.objective;
                best_sel = out.selection;
            }
        } else {
            open_bound = open_bound.max(*ub);
            report.push((counts.clone(), f64::NAN));
        }
    }
    let proven = open_bound <= best + 1e-9;
    let bound = if proven { best } else { open_bound };
    best_sel.sort_unstable();
    Ok((
        Outcome::new(
            inst,
            best_sel,
            bound,
            proven,
            start.elapsed().as_secs_f64(),
            "exact search over budget-maximal sensor counts",
        ),
        report,
    ))
}
