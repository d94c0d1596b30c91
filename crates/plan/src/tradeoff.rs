//! The placement half of the study's speed-against-error table: how many line-of-sight samples
//! a visibility cell needs (time against the change in V and in the placement it leads to), and
//! what a solver time limit costs in optimality gap on the budgeted problem.

use crate::error::{Result, StudyError};
use crate::study::{Configuration, Study};
use hilo_placement_ip::Limit;
use hilo_placement_ip::greedy::greedy;
use hilo_placement_ip::instance::{Instance, Outcome, evaluate};
use hilo_placement_ip::pipeline::{PlacementConfig, Prepared, instance, prepare, solve_from};
use hilo_sensor_models::Catalog;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Line-of-sight samples per probe: each probe's heights spread evenly over the default range.
pub const LOS_SAMPLES: [usize; 3] = [1, 3, 9];
/// Time limits of the budgeted solve, seconds (the last: effectively none).
pub const TIME_LIMITS_S: [f64; 5] = [0.1, 0.3, 1.0, 3.0, 600.0];

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LosRow {
    pub samples_per_probe: usize,
    /// Line of sight and visibility of the configuration's sensor types.
    pub seconds: f64,
    /// |ΔV| against the most samples, over every (candidate, target) pair either one sees.
    pub mean_abs_dv: f64,
    pub max_abs_dv: f64,
    /// The configuration's optimum under this V, valued on the most samples' V.
    pub objective_on_reference: f64,
    /// 1 − that value / the reference optimum: what the coarser V costs the placement.
    pub placement_loss: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LimitRow {
    pub time_limit_s: f64,
    pub seconds: f64,
    pub objective: f64,
    pub bound: f64,
    pub gap: f64,
    pub proven_optimal: bool,
    pub selection: String,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Tradeoffs {
    /// The configuration the line-of-sight rows place.
    pub configuration: String,
    pub los: Vec<LosRow>,
    /// The budgeted problem: every sensor type of the study, the budget of its dearest
    /// configuration.
    pub budget_usd: f64,
    pub types: Vec<String>,
    pub greedy_objective: f64,
    pub limits: Vec<LimitRow>,
}

fn spread(heights: &[f32], k: usize) -> Vec<f32> {
    let lo = heights.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = heights.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    if k == 1 {
        return vec![0.5 * (lo + hi)];
    }
    (0..k).map(|i| lo + (hi - lo) * i as f32 / (k - 1) as f32).collect()
}

/// Σ|ΔV| and max |ΔV| over the union of two sparse rows sorted by target, and the pair count.
fn row_diff(a: &[(u32, f32)], b: &[(u32, f32)]) -> (f64, f64, usize) {
    let (mut i, mut j, mut sum, mut max, mut n) = (0, 0, 0.0f64, 0.0f64, 0usize);
    while i < a.len() || j < b.len() {
        let d = match (a.get(i), b.get(j)) {
            (Some(x), Some(y)) if x.0 == y.0 => {
                i += 1;
                j += 1;
                (x.1 - y.1) as f64
            }
            (Some(x), Some(y)) if x.0 < y.0 => {
                i += 1;
                x.1 as f64
            }
            (Some(x), None) => {
                i += 1;
                x.1 as f64
            }
            (_, Some(y)) => {
                j += 1;
                y.1 as f64
            }
            (None, None) => break,
        };
        sum += d.abs();
        max = max.max(d.abs());
        n += 1;
    }
    (sum, max, n)
}

/// A configuration's price: its budget, or its sensors at catalog prices.
fn cost(catalog: &Catalog, c: &Configuration) -> Result<f64> {
    match c.budget_usd {
        Some(usd) => Ok(usd),
        None => c.sensors.iter().map(|(t, n)| Ok(catalog.get(t)?.price_usd() * *n as f64)).sum::<Result<f64>>(),
    }
}

/// Both sweeps. `prepared` is the study's visibility of every sensor type when it was just
/// computed (the budgeted sweep reuses it); `cell_m` overrides the study's target cell size (a
/// coarse grid for quick tests, which then recomputes).
pub fn compute(study: &Study, prepared: Option<&Prepared>, cell_m: Option<f32>) -> Result<Tradeoffs> {
    let (scene, catalog) = (&study.scene, &study.catalog);
    let cfg = match cell_m {
        Some(c) => PlacementConfig { cell_m: c, ..study.placement.clone().into_inner() }.validate()?,
        None => study.placement.clone(),
    };
    // Line-of-sight samples, on the first configuration with fixed counts of both modalities
    // (none: no rows).
    let conf = study
        .file
        .configurations
        .iter()
        .find(|c| c.budget_usd.is_none() && c.has_lidar(catalog) && c.has_radar(catalog));
    let los = match conf {
        Some(conf) => los_rows(scene, catalog, &cfg, conf)?,
        None => Vec::new(),
    };
    // Time limits, on the budgeted problem over every type of the study.
    let all = study.type_names();
    let budget_usd = study
        .file
        .configurations
        .iter()
        .map(|c| cost(catalog, c))
        .collect::<Result<Vec<f64>>>()?
        .into_iter()
        .fold(0.0, f64::max);
    let computed;
    let prep = match prepared {
        Some(p) if cell_m.is_none() => p,
        _ => {
            computed = prepare(scene, catalog, &all, &cfg)?;
            &computed
        }
    };
    let inst = instance(prep, catalog, &all, cfg.p_min)?;
    let blimit = Limit::Budget { usd: budget_usd, min: vec![], max: vec![] };
    let g = greedy(&inst, &blimit);
    let mut limits = Vec::new();
    for &tl in &TIME_LIMITS_S {
        let o = solve_from(&inst, &blimit, tl, &g)?;
        let mut counts = std::collections::BTreeMap::new();
        for &s in &o.selection {
            *counts.entry(inst.types[inst.options[s].ty].name.clone()).or_insert(0) += 1;
        }
        limits.push(LimitRow {
            time_limit_s: tl,
            seconds: o.solve_seconds,
            objective: o.objective,
            bound: o.bound,
            gap: o.gap,
            proven_optimal: o.proven_optimal,
            selection: counts.iter().map(|(t, n)| format!("{n}x {t}")).collect::<Vec<_>>().join(" + "),
        });
    }
    Ok(Tradeoffs {
        configuration: conf.map(|c| c.name.clone()).unwrap_or_default(),
        los,
        budget_usd,
        types: all,
        greedy_objective: g.objective,
        limits,
    })
}

fn los_rows(
    scene: &hilo_raycast::Scene,
    catalog: &Catalog,
    cfg: &PlacementConfig,
    conf: &Configuration,
) -> Result<Vec<LosRow>> {
    let types = conf.type_names();
    let limit = crate::place::limit_for(conf, &types);
    // Each sample count's visibility, instance and placement, built and solved once.
    let mut runs: Vec<(usize, f64, Prepared, Instance, Outcome)> = Vec::new();
    for &k in &LOS_SAMPLES {
        let mut c = cfg.clone();
        for p in &mut c.visibility.probes {
            p.los_heights_m = spread(&p.los_heights_m, k);
        }
        let t = Instant::now();
        let prep = prepare(scene, catalog, &types, &c.validate()?)?;
        let seconds = t.elapsed().as_secs_f64();
        let inst = instance(&prep, catalog, &types, cfg.p_min)?;
        let o = solve_from(&inst, &limit, cfg.solve_limit(), &greedy(&inst, &limit))?;
        runs.push((k, seconds, prep, inst, o));
    }
    let (_, _, reference, ref_inst, ref_out) =
        runs.last().ok_or(StudyError::Internal("the trade-off sweep made no line-of-sight run"))?;
    let ref_opt = ref_out.objective;
    let mut los = Vec::new();
    for (k, seconds, prep, _, o) in &runs {
        let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0usize);
        for t in &types {
            let (a, b) = (&prep.visibility[t], &reference.visibility[t]);
            for (ra, rb) in a.rows.iter().zip(&b.rows) {
                let (s, m, c) = row_diff(ra, rb);
                sum += s;
                max = max.max(m);
                n += c;
            }
        }
        // Options are (type, candidate) in the same order in both instances.
        let on_ref = evaluate(ref_inst, &o.selection);
        los.push(LosRow {
            samples_per_probe: *k,
            seconds: *seconds,
            mean_abs_dv: sum / n.max(1) as f64,
            max_abs_dv: max,
            objective_on_reference: on_ref,
            placement_loss: 1.0 - on_ref / ref_opt.max(1e-12),
        });
    }
    Ok(los)
}
