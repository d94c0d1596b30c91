//! Solving the calibrated objective without CBC: greedy, then swaps, with a certified bound.
//!
//! The calibrated objective f is monotone and submodular, so for any selection S and any
//! feasible T, f(T) ≤ f(S ∪ T) ≤ f(S) + Σ_{o ∈ T} Δ(o | S) with Δ(o | S) = f(S + o) − f(S).
//! Maximising the right-hand side over a relaxation of the limit (the mount rule dropped; a
//! budget as a fractional knapsack) bounds the optimum from above ([`upper_bound`]): the bound
//! a large instance reports when its LP is too big for CBC to finish the root (CBC checks its
//! time limit only between nodes, so a root LP of millions of non-zeros runs unbounded).
//!
//! Greedy adds the option of largest gain (per dollar under a budget; under a budget also by
//! plain gain, the better of the two kept, the usual guard against a cheap sensor that blocks a
//! better dear one), after first meeting each type's minimum count. Swaps then exchange one
//! chosen option for one not chosen while that raises f (first the best swap, until none helps).
//! Every gain is computed incrementally from the per-target view sums.
//!
//! With hit floors ([`crate::instance::HitFloor`]) greedy first meets them (after the minimum
//! counts: each step adds the option that closes most of what the floors still lack, per dollar
//! in the per-dollar run under a budget, the larger gain among equals), and swaps take only
//! exchanges that leave the floors no further from met; the floors only remove selections, so
//! the bound above still bounds the optimum.

use super::{Term, Weights};
use crate::instance::{Instance, Limit, Outcome};
use std::collections::HashMap;
use std::time::Instant;

/// A selection with its per-target sums s_tj (one per non-zero term t) and its objective.
pub(super) struct State<'a> {
    inst: &'a Instance,
    /// The non-zero terms, with their weight divided by their W = Σ_j w_j.
    terms: Vec<Term>,
    tau: f64,
    s: Vec<Vec<f64>>,
    /// Per hit floor of the instance: per sample, the chosen options that hit it; and the
    /// samples hit.
    hits: Vec<(Vec<u32>, u32)>,
    pub sel: Vec<usize>,
    pub f: f64,
}

impl<'a> State<'a> {
    pub fn new(inst: &'a Instance, w: &Weights) -> Self {
        let terms: Vec<Term> = w
            .terms()
            .into_iter()
            .filter(|t| t.weight > 0.0)
            .map(|t| Term { weight: t.weight / t.total(inst), ..t })
            .collect();
        let s = terms.iter().map(|t| vec![0.0; t.targets(inst).len()]).collect();
        let hits = inst.floors.iter().map(|f| (vec![0; f.samples as usize], 0)).collect();
        State { inst, terms, tau: inst.tau(), s, hits, sel: Vec::new(), f: 0.0 }
    }

    /// What the hit floors still lack, each as a share of what it needs: 0 when all are met.
    pub fn shortfall(&self) -> f64 {
        self.shortfall_with(None)
    }

    /// [`State::shortfall`] after adding option `o` (None: as it is).
    fn shortfall_with(&self, o: Option<usize>) -> f64 {
        let mut lack = 0.0;
        for (f, (count, hit)) in self.inst.floors.iter().zip(&self.hits) {
            let new = o.map_or(0, |o| f.rows[o].iter().filter(|&&s| count[s as usize] == 0).count() as u32);
            let needed = f.needed();
            lack += f64::from(needed.saturating_sub(hit + new)) / f64::from(needed.max(1));
        }
        lack
    }

    /// What option `o` changes in the objective when its coefficients are added (`sign` 1) to,
    /// or taken (−1) from, the current sums.
    fn change(&self, o: usize, sign: f64) -> f64 {
        let m = self.inst.modality(o);
        let mut total = 0.0;
        for (t, s) in self.terms.iter().zip(&self.s).filter(|(t, _)| t.modality == m) {
            let wt = t.targets(self.inst);
            t.for_each(self.inst, o, self.tau, |j, c| {
                let Some(&wj) = wt.get(j) else { return };
                let (now, then) = (s[j].max(0.0), (s[j] + sign * c).max(0.0));
                total += t.weight * wj * ((then / t.k).min(1.0) - (now / t.k).min(1.0));
            });
        }
        total
    }

    /// Δ(o | S): what adding `o` would add.
    pub fn gain(&self, o: usize) -> f64 {
        self.change(o, 1.0)
    }

    /// f(S) − f(S − r) for a chosen `r`.
    fn loss(&self, r: usize) -> f64 {
        -self.change(r, -1.0)
    }

    fn shift(&mut self, o: usize, sign: f64) {
        for (f, (count, hit)) in self.inst.floors.iter().zip(self.hits.iter_mut()) {
            for &s in &f.rows[o] {
                let c = &mut count[s as usize];
                if sign > 0.0 {
                    *hit += u32::from(*c == 0);
                    *c += 1;
                } else {
                    *c -= 1;
                    *hit -= u32::from(*c == 0);
                }
            }
        }
        let m = self.inst.modality(o);
        let tau = self.tau;
        for (t, s) in self.terms.iter().zip(self.s.iter_mut()).filter(|(t, _)| t.modality == m) {
            t.for_each(self.inst, o, tau, |j, c| {
                if let Some(x) = s.get_mut(j) {
                    *x += sign * c;
                }
            });
        }
    }

    pub fn add(&mut self, o: usize) {
        self.f += self.gain(o);
        self.shift(o, 1.0);
        self.sel.push(o);
    }

    fn remove(&mut self, r: usize) {
        self.f -= self.loss(r);
        self.shift(r, -1.0);
        self.sel.retain(|&x| x != r);
    }
}

/// The minimum count of each type a limit asks for.
fn minimum(inst: &Instance, limit: &Limit) -> Vec<u32> {
    match limit {
        Limit::Budget { min, .. } => (0..inst.types.len()).map(|t| min.get(t).copied().unwrap_or(0)).collect(),
        _ => vec![0; inst.types.len()],
    }
}

fn count(inst: &Instance, sel: &[usize], ty: usize) -> u32 {
    sel.iter().filter(|&&o| inst.options[o].ty == ty).count() as u32
}

/// Whether `sel` plus option `o` stays within `limit` and leaves the money for the minimum
/// counts not yet met.
fn can_add(inst: &Instance, limit: &Limit, sel: &[usize], o: usize) -> bool {
    let opt = &inst.options[o];
    if sel.iter().any(|&x| x == o || inst.options[x].mount == opt.mount) {
        return false;
    }
    let same = count(inst, sel, opt.ty) + 1;
    match limit {
        Limit::Counts(c) => same <= c.get(opt.ty).copied().unwrap_or(0),
        Limit::Total(n) => sel.len() < *n as usize,
        Limit::Budget { usd, min, max } => {
            let owed: f64 = (0..inst.types.len())
                .map(|t| {
                    let have = count(inst, sel, t) + u32::from(t == opt.ty);
                    min.get(t).copied().unwrap_or(0).saturating_sub(have) as f64 * inst.types[t].price_usd
                })
                .sum();
            inst.cost(sel) + inst.types[opt.ty].price_usd + owed <= usd + 1e-6
                && same <= max.get(opt.ty).copied().unwrap_or(u32::MAX)
        }
    }
}

/// The best addable option by gain (per dollar when `per_dollar`), among those `allowed`.
fn best_addition(st: &State, limit: &Limit, per_dollar: bool, allowed: impl Fn(usize) -> bool) -> Option<(f64, usize)> {
    let inst = st.inst;
    (0..inst.options.len())
        .filter(|&o| allowed(o) && can_add(inst, limit, &st.sel, o))
        .map(|o| {
            let gain = st.gain(o);
            let price = if per_dollar { inst.types[inst.options[o].ty].price_usd.max(1e-9) } else { 1.0 };
            (gain / price, gain, o)
        })
        .filter(|x| x.1 > 1e-12)
        .max_by(|a, b| a.0.total_cmp(&b.0).then(b.2.cmp(&a.2)))
        .map(|(_, g, o)| (g, o))
}

fn greedy_run<'a>(inst: &'a Instance, limit: &Limit, w: &Weights, per_dollar: bool, fixed: &[usize]) -> State<'a> {
    let mut st = State::new(inst, w);
    for &o in fixed {
        st.add(o);
    }
    let min = minimum(inst, limit);
    // First each type's minimum count (by gain, or the first option of the type if none gains).
    for (t, &n) in min.iter().enumerate() {
        while count(inst, &st.sel, t) < n {
            let pick = best_addition(&st, limit, false, |o| inst.options[o].ty == t).map(|x| x.1).or_else(|| {
                (0..inst.options.len()).find(|&o| inst.options[o].ty == t && can_add(inst, limit, &st.sel, o))
            });
            match pick {
                Some(o) => st.add(o),
                None => break,
            }
        }
    }
    // Then the hit floors: the option that closes most of what they lack (per dollar when
    // `per_dollar`, the weighted set cover's greedy), the larger gain among equals; none
    // closing any of it leaves them unmet (the solver says so).
    while st.shortfall() > 0.0 {
        let now = st.shortfall();
        let pick = (0..inst.options.len())
            .filter(|&o| can_add(inst, limit, &st.sel, o))
            .filter_map(|o| {
                let closed = now - st.shortfall_with(Some(o));
                let price = if per_dollar { inst.types[inst.options[o].ty].price_usd.max(1e-9) } else { 1.0 };
                (closed > 1e-12).then(|| (closed / price, st.gain(o) / price, o))
            })
            .max_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)).then(b.2.cmp(&a.2)));
        match pick {
            Some((.., o)) => st.add(o),
            None => break,
        }
    }
    while let Some((_, o)) = best_addition(&st, limit, per_dollar, |_| true) {
        st.add(o);
    }
    st
}

/// Greedy by marginal gain (per dollar under a budget, and also by plain gain there, the better
/// kept) until nothing more fits or helps, after each type's minimum count.
pub fn greedy(inst: &Instance, limit: &Limit, w: &Weights) -> Outcome {
    greedy_given(inst, limit, w, &[])
}

/// [`greedy`] from the options of `fixed` (a feasible part of a selection), which it keeps.
pub fn greedy_given(inst: &Instance, limit: &Limit, w: &Weights, fixed: &[usize]) -> Outcome {
    let start = Instant::now();
    let mut st = greedy_run(inst, limit, w, matches!(limit, Limit::Budget { .. }), fixed);
    if matches!(limit, Limit::Budget { .. }) {
        let plain = greedy_run(inst, limit, w, false, fixed);
        // The one nearer to meeting the hit floors, then the larger objective.
        let (a, b) = (plain.shortfall(), st.shortfall());
        if a < b - 1e-12 || (a <= b + 1e-12 && plain.f > st.f + 1e-12) {
            st = plain;
        }
    }
    let mut sel = st.sel;
    sel.sort_unstable();
    super::outcome(inst, sel, w, f64::INFINITY, false, start, "greedy, calibrated objective")
}

/// Swaps from `from` (one chosen option out, one other in, the best such swap each round) while
/// one raises the objective, until `deadline_s` seconds have passed; then adds what still fits.
/// The options of `fixed` (all in `from`) are never swapped out; a swap that would leave the
/// hit floors further from met is not taken.
pub fn swaps(inst: &Instance, limit: &Limit, w: &Weights, from: &Outcome, deadline_s: f64, fixed: &[usize]) -> Outcome {
    let start = Instant::now();
    let mut st = State::new(inst, w);
    for &o in &from.selection {
        st.add(o);
    }
    let min = minimum(inst, limit);
    while start.elapsed().as_secs_f64() < deadline_s {
        let mut best: Option<(f64, usize, usize)> = None;
        for r in st.sel.clone().into_iter().filter(|r| !fixed.contains(r)) {
            let loss = st.loss(r);
            let ty = inst.options[r].ty;
            // Dropping r would break a minimum count: only a sensor of its type may replace it.
            let keep_type = count(inst, &st.sel, ty) <= min[ty];
            let lack = st.shortfall();
            st.remove(r);
            let allowed = |o: usize| {
                o != r && (!keep_type || inst.options[o].ty == ty) && st.shortfall_with(Some(o)) <= lack + 1e-12
            };
            if let Some((gain, o)) = best_addition(&st, limit, false, allowed) {
                let delta = gain - loss;
                if delta > 1e-9 * st.f.abs().max(1e-9) && best.is_none_or(|b| delta > b.0) {
                    best = Some((delta, r, o));
                }
            }
            st.add(r);
        }
        match best {
            Some((_, r, o)) => {
                st.remove(r);
                st.add(o);
            }
            None => break,
        }
    }
    while let Some((_, o)) = best_addition(&st, limit, false, |_| true) {
        st.add(o);
    }
    let bound = bound_at(&st, limit);
    let mut sel = st.sel;
    sel.sort_unstable();
    super::outcome(inst, sel, w, bound, false, start, "greedy and swaps, calibrated objective")
}

/// An upper bound of the optimum from the marginal gains at `sel` (see the module's docs): per
/// mount and type the best option's gain; per type at most as many as the limit allows; then
/// the largest total within the limit, fractionally under a budget.
pub fn upper_bound(inst: &Instance, limit: &Limit, w: &Weights, sel: &[usize]) -> f64 {
    let mut st = State::new(inst, w);
    for &o in sel {
        st.add(o);
    }
    bound_at(&st, limit)
}

/// [`upper_bound`] at the selection `st` holds.
fn bound_at(st: &State, limit: &Limit) -> f64 {
    let (inst, sel) = (st.inst, &st.sel);
    let mut best: HashMap<(u32, usize), f64> = HashMap::new();
    for o in (0..inst.options.len()).filter(|o| !sel.contains(o)) {
        let g = st.gain(o);
        let e = best.entry((inst.options[o].mount, inst.options[o].ty)).or_insert(0.0);
        *e = e.max(g);
    }
    let cap = |t: usize| -> usize {
        match limit {
            Limit::Counts(c) => c.get(t).copied().unwrap_or(0) as usize,
            Limit::Total(n) => *n as usize,
            Limit::Budget { max, .. } => max.get(t).copied().map_or(usize::MAX, |m| m as usize),
        }
    };
    // Per type its best gains, as many as a selection may hold of it.
    let mut items: Vec<(f64, f64)> = Vec::new();
    for t in 0..inst.types.len() {
        let mut g: Vec<f64> = best.iter().filter(|((_, ty), _)| *ty == t).map(|(_, &g)| g).collect();
        g.sort_by(|a, b| b.total_cmp(a));
        items.extend(g.into_iter().take(cap(t)).map(|g| (g, inst.types[t].price_usd)));
    }
    let extra = match limit {
        Limit::Counts(_) => items.iter().map(|x| x.0).sum(),
        Limit::Total(n) => {
            items.sort_by(|a, b| b.0.total_cmp(&a.0));
            items.iter().take(*n as usize).map(|x| x.0).sum()
        }
        Limit::Budget { usd, .. } => {
            items.sort_by(|a, b| (b.0 / b.1.max(1e-9)).total_cmp(&(a.0 / a.1.max(1e-9))));
            let mut room = *usd;
            let mut total = 0.0;
            for (g, p) in items {
                if room <= 0.0 {
                    break;
                }
                let share = if p <= room { 1.0 } else { room / p };
                total += share * g;
                room -= p.min(room);
            }
            total
        }
    };
    st.f + extra
}
