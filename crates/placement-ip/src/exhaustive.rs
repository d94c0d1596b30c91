//! Exhaustive enumeration of every feasible selection: the oracle for small instances.

use crate::error::PlacementError;
use crate::instance::{Instance, Limit, Outcome, Scratch, evaluate_with};
use std::time::Instant;

/// Enumerates all selections allowed by `limit` (refuses more than `max_evaluations`).
pub fn exhaustive(inst: &Instance, limit: &Limit, max_evaluations: u64) -> Result<Outcome, PlacementError> {
    let start = Instant::now();
    let n = inst.options.len();
    let mut best = (f64::NEG_INFINITY, Vec::new());
    let mut count = 0u64;
    let mut scratch = Scratch::new(inst.n_targets());
    let mut stack: Vec<usize> = Vec::new();
    // Depth-first over include/exclude in index order; a branch stops as soon as the partial
    // selection breaks the limit (all limits are monotone: adding never repairs them, except
    // budget minimums, which are checked at the leaves).
    #[allow(clippy::too_many_arguments)]
    fn rec(
        inst: &Instance,
        limit: &Limit,
        n: usize,
        next: usize,
        stack: &mut Vec<usize>,
        best: &mut (f64, Vec<usize>),
        count: &mut u64,
        max: u64,
        scratch: &mut Scratch,
    ) -> Result<(), PlacementError> {
        *count += 1;
        if *count > max {
            return Err(PlacementError::instance(
                format!("exhaustive search over {n} options"),
                format!("exceeds {max} selections"),
            ));
        }
        let leaf_ok = inst.check(limit, stack).is_ok();
        if leaf_ok {
            let f = evaluate_with(inst, stack, scratch);
            if f > best.0 + 1e-12 || (f >= best.0 - 1e-12 && stack.len() < best.1.len()) {
                *best = (f, stack.clone());
            }
        }
        for o in next..n {
            stack.push(o);
            let partial_ok = match limit {
                Limit::Budget { usd, max, .. } => {
                    let ty = inst.options[o].ty;
                    inst.cost(stack) <= usd + 1e-6
                        && stack.iter().filter(|&&x| inst.options[x].ty == ty).count() as u32
                            <= max.get(ty).copied().unwrap_or(u32::MAX)
                        && stack.iter().filter(|&&x| inst.options[x].mount == inst.options[o].mount).count() == 1
                }
                _ => inst.check(limit, stack).is_ok(),
            };
            if partial_ok {
                rec(inst, limit, n, o + 1, stack, best, count, max, scratch)?;
            }
            stack.pop();
        }
        Ok(())
    }
    rec(inst, limit, n, 0, &mut stack, &mut best, &mut count, max_evaluations, &mut scratch)?;
    if best.0 == f64::NEG_INFINITY {
        return Err(PlacementError::Infeasible("no selection satisfies the limits".into()));
    }
    Ok(Outcome::new(inst, best.1, best.0, true, start.elapsed().as_secs_f64(), "exhaustive"))
}
