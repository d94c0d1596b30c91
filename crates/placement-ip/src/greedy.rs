//! Greedy placement by marginal gain, the baseline of single-modality placement work (e.g. the
//! ICCV'23 roadside-LiDAR study): add the option with the largest gain in the objective until
//! the limit is reached. With a budget the gain is divided by the price.
//!
//! Under the paper's objective no single sensor scores anything (a target needs both
//! modalities), so ties are broken by a modality-relaxed gain: the weighted visibility a sensor
//! adds on targets its own modality covers. That makes the first steps meaningful; it is still a
//! heuristic, and [`crate::exact`] shows where it falls short.

use crate::candidates::Modality;
use crate::instance::{Instance, Limit, Outcome, Scratch, evaluate_with};
use rayon::prelude::*;
use std::time::Instant;

/// Modality-relaxed score: weighted V on targets covered by the option's own modality.
fn relaxed(inst: &Instance, sel: &[usize]) -> f64 {
    let tau = inst.tau() * (1.0 - 1e-9);
    let a_l = crate::instance::modality_coverage(inst, sel, Modality::Lidar);
    let a_r = crate::instance::modality_coverage(inst, sel, Modality::Radar);
    sel.iter()
        .map(|&o| {
            let a = if inst.modality(o) == Modality::Lidar { &a_l } else { &a_r };
            inst.options[o]
                .row
                .iter()
                .filter(|(j, _)| a[*j as usize] >= tau)
                .map(|&(j, v)| inst.weights[j as usize] * v as f64)
                .sum::<f64>()
        })
        .sum()
}

pub fn greedy(inst: &Instance, limit: &Limit) -> Outcome {
    greedy_given(inst, limit, &[])
}

/// [`greedy`] from the options of `fixed` (a feasible part of a selection), which it keeps.
pub fn greedy_given(inst: &Instance, limit: &Limit, fixed: &[usize]) -> Outcome {
    let start = Instant::now();
    let mut sel: Vec<usize> = fixed.to_vec();
    let budget = matches!(limit, Limit::Budget { .. });
    loop {
        let f0 = evaluate_with(inst, &sel, &mut Scratch::new(inst.n_targets()));
        let g0 = relaxed(inst, &sel);
        let best = (0..inst.options.len())
            .into_par_iter()
            .filter(|&o| !sel.contains(&o))
            .filter_map(|o| {
                let mut s = sel.clone();
                s.push(o);
                // Budget limits with minimum counts: adding is allowed while the budget holds.
                let ok = match limit {
                    Limit::Budget { usd, max, .. } => {
                        inst.cost(&s) <= usd + 1e-6
                            && s.iter().filter(|&&x| inst.options[x].ty == inst.options[o].ty).count() as u32
                                <= max.get(inst.options[o].ty).copied().unwrap_or(u32::MAX)
                            && s.iter().map(|&x| inst.options[x].mount).collect::<std::collections::HashSet<_>>().len()
                                == s.len()
                    }
                    _ => inst.check(limit, &s).is_ok(),
                };
                if !ok {
                    return None;
                }
                let mut scratch = Scratch::new(inst.n_targets());
                let df = evaluate_with(inst, &s, &mut scratch) - f0;
                let dg = relaxed(inst, &s) - g0;
                let price = if budget { inst.types[inst.options[o].ty].price_usd.max(1e-9) } else { 1.0 };
                Some((df / price, dg / price, o))
            })
            .max_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)).then(b.2.cmp(&a.2)));
        match best {
            Some((_, _, o)) => sel.push(o),
            None => break,
        }
    }
    sel.sort_unstable();
    Outcome::new(inst, sel, f64::INFINITY, false, start.elapsed().as_secs_f64(), "greedy")
}
