//! The placement IP for CBC (through good_lp), as the paper writes it (`Formulation::Plain`) or
//! strengthened (`Formulation::Strengthened`), for any limit (counts, total, budget).
//!
//! Variables: x_o ∈ {0,1} per option, t_j ∈ {0,1} per target, z_j ≥ 0 (the linearised t_j ρ_j).
//! maximise Σ_j z_j subject to
//! - z_j ≤ ρ_j = w_j Σ_o V_oj x_o and z_j ≤ ρ̄_j t_j (ρ̄_j an upper bound of ρ_j);
//! - Σ_{o ∈ L} a_oj x_o ≥ τ t_j and Σ_{o ∈ R} a_oj x_o ≥ τ t_j, a_oj = −ln(1 − V_oj), τ = −ln(1 − p_min)
//!   (for each modality the instance offers, [`Instance::requires`]);
//! - the limit, and Σ_{o at mount m} x_o ≤ 1.
//!
//! The strengthened model keeps the same integer solutions but a tighter relaxation:
//! coefficients are cut to τ (t_j ≤ 1 makes a_oj > τ no stronger than τ); targets that one
//! modality cannot see are dropped (their t_j is 0); t_j ≤ Σ_{o ∈ L sees j} x_o and the same for
//! R; ρ̄_j is the sum of the largest V at j that the limit could buy rather than of all of them.

use crate::candidates::Modality;
use crate::error::PlacementError;
use crate::instance::{Instance, Limit, Outcome, coverage_coef};
use good_lp::solvers::coin_cbc::{CoinCbcProblem, coin_cbc};
use good_lp::{Expression, ProblemVariables, SolverModel, Variable, WithInitialSolution, WithTimeLimit, variable};
use std::collections::BTreeMap;
use std::time::Instant;

/// What stops a solve that has not proven its optimum: a wall-clock limit (CBC rounds it to
/// whole seconds) and, optionally, a limit on CBC's branch-and-bound nodes. A solve the node
/// limit stops returns the same placement on any machine and under any load; one the clock
/// stops depends on both. A plain number of seconds converts into a limit without nodes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveLimit {
    pub seconds: f64,
    pub nodes: Option<u64>,
}

impl From<f64> for SolveLimit {
    fn from(seconds: f64) -> Self {
        SolveLimit { seconds, nodes: None }
    }
}

/// What one CBC run gave: the option variables' values, CBC's bound, whether it proved the
/// optimum, and, when it did not, what stopped it (for the outcome's method).
pub(crate) struct CbcRun {
    pub selection: Vec<usize>,
    pub bound: f64,
    pub proven: bool,
    pub stopped: Option<String>,
}

impl CbcRun {
    /// `base` (the model's name), with what stopped CBC when it proved nothing.
    pub fn method(&self, base: &str) -> String {
        match &self.stopped {
            Some(why) => format!("{base}, {why}"),
            None => base.to_owned(),
        }
    }
}

/// Runs CBC on `problem`, whose first `n_x` variables are the options' x_o (created before any
/// other, so they are its first columns), within `limit`. Reads CBC's own status rather than
/// good_lp's, which takes a stop on the node limit for an error or an optimum. `what` names the
/// model in errors.
pub(crate) fn run_cbc(
    problem: CoinCbcProblem,
    n_x: usize,
    limit: SolveLimit,
    what: &str,
) -> Result<CbcRun, PlacementError> {
    let start = Instant::now();
    let mut problem = problem.with_time_limit(limit.seconds.max(1.0));
    if let Some(n) = limit.nodes {
        problem.set_parameter("maxNodes", &n.to_string());
    }
    let sol = problem.as_inner().solve();
    let raw = sol.raw();
    if raw.is_proven_infeasible() || raw.is_continuous_unbounded() {
        let ran = start.elapsed().as_secs_f64();
        // At its time limit without an incumbent CBC may report "infeasible"; say what happened.
        // CBC does not check the limit inside its root LP, so it may run past it.
        return Err(PlacementError::Solver(if ran >= 0.95 * limit.seconds.max(1.0) {
            format!(
                "{what}: time limit ({:.0} s) reached with no solution found (ran {ran:.0} s: CBC does not check its limit inside the root LP)",
                limit.seconds
            )
        } else {
            format!("{what}: the model is infeasible or unbounded")
        }));
    }
    let values = raw.col_solution();
    if values.len() < n_x {
        return Err(PlacementError::Solver(format!("{what}: {} columns, {n_x} options", values.len())));
    }
    let selection = (0..n_x).filter(|&o| values[o] > 0.5).collect();
    let proven = raw.is_proven_optimal();
    let stopped = (!proven).then(|| {
        use coin_cbc::raw::SecondaryStatus as S;
        match raw.secondary_status() {
            S::StoppedOnNodes => format!("stopped at the node limit ({})", limit.nodes.unwrap_or(0)),
            S::StoppedOnTime => format!("stopped at the time limit ({:.0} s)", limit.seconds.max(1.0)),
            other => format!("stopped ({other:?})"),
        }
    });
    let bound = raw.best_possible_value();
    Ok(CbcRun { selection, bound: if bound.is_finite() { bound } else { f64::INFINITY }, proven, stopped })
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Formulation {
    Plain,
    Strengthened,
}

/// A built model and its variables.
#[allow(missing_debug_implementations)]
pub struct Model {
    pub problem: CoinCbcProblem,
    pub x: Vec<Variable>,
    pub t: Vec<(usize, Variable)>,
    pub z: Vec<Variable>,
    pub rows: usize,
    pub nonzeros: usize,
}

/// Most sensors any selection within `limit` can hold. Under a budget: the cheapest types
/// first, each up to its cap and its number of options (buying the cheapest first maximises
/// the count; a free type is bounded by its options).
fn max_sensors(inst: &Instance, limit: &Limit) -> usize {
    match limit {
        Limit::Counts(c) => c.iter().map(|&x| x as usize).sum(),
        Limit::Total(n) => *n as usize,
        Limit::Budget { usd, max, .. } => {
            let mut order: Vec<usize> = (0..inst.types.len()).collect();
            order.sort_by(|&a, &b| inst.types[a].price_usd.total_cmp(&inst.types[b].price_usd));
            let options = inst.options_per_type();
            let mut left = *usd;
            let mut n = 0usize;
            for t in order {
                let avail = options[t].min(max.get(t).copied().unwrap_or(u32::MAX) as usize);
                let price = inst.types[t].price_usd;
                let take =
                    if price > 0.0 { (((left + 1e-9) / price).floor().max(0.0) as usize).min(avail) } else { avail };
                n += take;
                left -= take as f64 * price;
            }
            n
        }
    }
}

pub fn build(inst: &Instance, limit: &Limit, form: Formulation) -> Result<Model, PlacementError> {
    let n = inst.n_targets();
    let tau = inst.tau();
    let strong = form == Formulation::Strengthened;
    let mut vars = ProblemVariables::new();
    let x: Vec<Variable> = (0..inst.options.len()).map(|_| vars.add(variable().binary())).collect();
    // Per-target columns.
    let mut by_target: Vec<Vec<(usize, f32)>> = vec![Vec::new(); n];
    for (o, opt) in inst.options.iter().enumerate() {
        for &(j, v) in &opt.row {
            by_target[j as usize].push((o, v));
        }
    }
    let required: Vec<Modality> =
        [Modality::Lidar, Modality::Radar].into_iter().filter(|&m| inst.requires(m)).collect();
    let sees = |j: usize, m: Modality| by_target[j].iter().any(|&(o, _)| inst.modality(o) == m);
    let kept: Vec<usize> =
        (0..n).filter(|&j| !strong || (required.iter().all(|&m| sees(j, m)) && inst.weights[j] > 0.0)).collect();
    let t: Vec<(usize, Variable)> = kept.iter().map(|&j| (j, vars.add(variable().binary()))).collect();
    let z: Vec<Variable> = kept.iter().map(|_| vars.add(variable().min(0.0))).collect();
    let objective: Expression = z.iter().copied().sum();
    let mut problem = vars.maximise(objective).using(coin_cbc);
    problem.set_parameter("log", "0");
    let mut rows = 0usize;
    let mut nonzeros = 0usize;
    let top = max_sensors(inst, limit);
    for (k, &(j, tj)) in t.iter().enumerate() {
        let w = inst.weights[j];
        let col = &by_target[j];
        let rho: Expression = col.iter().map(|&(o, v)| (w * v as f64) * x[o]).sum();
        let rho_max = if strong {
            let mut vs: Vec<f32> = col.iter().map(|c| c.1).collect();
            vs.sort_by(|a, b| b.total_cmp(a));
            w * vs.iter().take(top).map(|&v| v as f64).sum::<f64>()
        } else {
            w * col.iter().map(|c| c.1 as f64).sum::<f64>()
        };
        problem.add_constraint((z[k] - rho).leq(0.0));
        problem.add_constraint((z[k] - rho_max * tj).leq(0.0));
        rows += 2;
        nonzeros += col.len() + 3;
        for &m in &required {
            let cover: Expression = col
                .iter()
                .filter(|&&(o, _)| inst.modality(o) == m)
                .map(|&(o, v)| {
                    let a = coverage_coef(v as f64);
                    (if strong { a.min(tau) } else { a }) * x[o]
                })
                .sum();
            problem.add_constraint((cover - tau * tj).geq(0.0));
            rows += 1;
            if strong {
                let any: Expression = col.iter().filter(|&&(o, _)| inst.modality(o) == m).map(|&(o, _)| x[o]).sum();
                problem.add_constraint((any - tj).geq(0.0));
                rows += 1;
            }
            nonzeros += 2 * col.len();
        }
    }
    rows += add_limit(&mut problem, inst, limit, &x);
    Ok(Model { problem, x, t, z, rows, nonzeros })
}

/// Adds `limit` and one sensor per mount point to `problem` over the option variables `x`;
/// returns the rows added.
pub(crate) fn add_limit(problem: &mut CoinCbcProblem, inst: &Instance, limit: &Limit, x: &[Variable]) -> usize {
    let mut rows = 0usize;
    match limit {
        Limit::Counts(c) => {
            for (ty, &cap) in c.iter().enumerate() {
                let e: Expression = (0..inst.options.len()).filter(|&o| inst.options[o].ty == ty).map(|o| x[o]).sum();
                problem.add_constraint(e.leq(cap as f64));
                rows += 1;
            }
            for (o, opt) in inst.options.iter().enumerate() {
                if c.get(opt.ty).copied().unwrap_or(0) == 0 {
                    problem.add_constraint(Expression::from(x[o]).leq(0.0));
                }
            }
        }
        Limit::Total(cap) => {
            let e: Expression = x.iter().copied().sum();
            problem.add_constraint(e.leq(*cap as f64));
            rows += 1;
        }
        Limit::Budget { usd, min, max } => {
            let e: Expression = x.iter().enumerate().map(|(o, &v)| inst.types[inst.options[o].ty].price_usd * v).sum();
            problem.add_constraint(e.leq(*usd));
            for ty in 0..inst.types.len() {
                let e: Expression = (0..inst.options.len()).filter(|&o| inst.options[o].ty == ty).map(|o| x[o]).sum();
                if let Some(&lo) = min.get(ty) {
                    problem.add_constraint(e.clone().geq(lo as f64));
                }
                if let Some(&hi) = max.get(ty) {
                    problem.add_constraint(e.leq(hi as f64));
                }
            }
            rows += 1 + 2 * inst.types.len();
        }
    }
    // One sensor per mount point.
    let mut mounts: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    for (o, opt) in inst.options.iter().enumerate() {
        mounts.entry(opt.mount).or_default().push(o);
    }
    for group in mounts.values().filter(|g| g.len() > 1) {
        let e: Expression = group.iter().map(|&o| x[o]).sum();
        problem.add_constraint(e.leq(1.0));
        rows += 1;
    }
    rows
}

/// Solves with CBC within `limit` (seconds, or a [`SolveLimit`] with nodes), optionally
/// warm-started from a selection. The objective reported is the exact objective of the
/// selection CBC returns; the bound is CBC's best possible value.
pub fn solve(
    inst: &Instance,
    limit: &Limit,
    form: Formulation,
    solve_limit: impl Into<SolveLimit>,
    warm: Option<&[usize]>,
) -> Result<Outcome, PlacementError> {
    solve_fixing(inst, limit, form, solve_limit, warm, &[])
}

/// [`solve`] with the options in `fixed` chosen (x_o = 1): the best placement of the rest given
/// them, and a bound over every selection that holds them. The caller checks that `fixed` is a
/// feasible part of a selection ([`crate::pipeline::solve_given`] does). A selection CBC returns
/// without proof that breaks the limit (no incumbent when it stopped) is replaced by the warm
/// start, or refused without one.
pub fn solve_fixing(
    inst: &Instance,
    limit: &Limit,
    form: Formulation,
    solve_limit: impl Into<SolveLimit>,
    warm: Option<&[usize]>,
    fixed: &[usize],
) -> Result<Outcome, PlacementError> {
    let start = Instant::now();
    let mut m = build(inst, limit, form)?;
    for &o in fixed {
        m.problem.add_constraint(Expression::from(m.x[o]).geq(1.0));
    }
    // Without CBC's preprocessing: stopped by the time limit inside it, its post-processing
    // crashes the process on some instances (SIGSEGV in `CglPreProcess::postProcess`, CBC 2.10;
    // the budgeted problem at the Fabriksgatan site, tests/scene.rs). The default study's
    // placements and trade-off rows are the same without it.
    m.problem.set_parameter("preprocess", "off");
    let mut problem = m.problem;
    if let Some(sel) = warm {
        let chosen: std::collections::HashSet<usize> = sel.iter().copied().collect();
        let tau = inst.tau() * (1.0 - 1e-9);
        // Initial values for every variable, consistent with the selection.
        let n = inst.n_targets();
        let (mut a_l, mut a_r, mut rho) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for &o in sel {
            for &(j, v) in &inst.options[o].row {
                let a = coverage_coef(v as f64);
                if inst.modality(o) == Modality::Lidar {
                    a_l[j as usize] += a
                } else {
                    a_r[j as usize] += a
                }
                rho[j as usize] += inst.weights[j as usize] * v as f64;
            }
        }
        let mut init: Vec<(Variable, f64)> =
            m.x.iter().enumerate().map(|(o, &v)| (v, if chosen.contains(&o) { 1.0 } else { 0.0 })).collect();
        for (k, &(j, tv)) in m.t.iter().enumerate() {
            let on = a_l[j] >= tau && a_r[j] >= tau;
            init.push((tv, if on { 1.0 } else { 0.0 }));
            init.push((m.z[k], if on { rho[j] } else { 0.0 }));
        }
        problem = problem.with_initial_solution(init);
    }
    let run = run_cbc(problem, m.x.len(), solve_limit.into(), "CBC")?;
    let method = match form {
        Formulation::Plain => "CBC, plain formulation",
        Formulation::Strengthened => "CBC, strengthened formulation",
    };
    let method = run.method(method);
    let selection = match (inst.check(limit, &run.selection), warm) {
        (Ok(()), _) => run.selection,
        (Err(_), Some(w)) if !run.proven => w.to_vec(),
        (Err(e), _) => {
            return Err(PlacementError::Solver(format!("CBC returned a selection that breaks the limit: {e}")));
        }
    };
    Ok(Outcome::new(inst, selection, run.bound, run.proven, start.elapsed().as_secs_f64(), &method))
}

/// Writes the model as gzip-compressed MPS (CBC's writer), to `<stem>.mps.gz`; returns that
/// path. Gurobi, HiGHS, CBC and SCIP read it as it is.
pub fn write_mps(
    inst: &Instance,
    limit: &Limit,
    form: Formulation,
    stem: &std::path::Path,
) -> Result<std::path::PathBuf, PlacementError> {
    let m = build(inst, limit, form)?;
    let raw = m.problem.as_inner().to_raw();
    let name = std::ffi::CString::new(stem.to_string_lossy().as_bytes())
        .map_err(|e| PlacementError::Export { path: stem.to_path_buf(), reason: e.to_string() })?;
    raw.write_mps(&name);
    let written = std::path::PathBuf::from(format!("{}.mps.gz", stem.display()));
    if !written.exists() {
        return Err(PlacementError::Solver(format!("CBC did not write {}", written.display())));
    }
    Ok(written)
}
