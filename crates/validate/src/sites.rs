//! Leave one site out: does the calibrated objective rank placements at a junction its fit never
//! saw, and does it rank them better than counting LiDARs? (`hilo validate --sites`)
//!
//! Cross-fitting within one validation ([`crate::calibrate`]) scores a fit on placements it did
//! not see, but at the junction, under the traffic and with the detector build it was fitted on;
//! a user's junction is always another junction. Here each site's finished validation
//! (`validation.json`) is held out in turn: the objective is fitted on the placements of every
//! other site, frozen, and ranks the held-out site's placements.
//!
//! - **Features chosen across sites.** Of the feature subsets whose weights are all ≥ 0, the fit
//!   keeps the one with the smallest leave-one-site-out error *within the fitting sites* (each
//!   of them predicted by the fit on the others), not the smallest PRESS: PRESS rewards a term
//!   that explains one site's placements, and such a term need not carry to the next site.
//! - **Intervals that know sites differ.** A 95% prediction interval from the pooled fit's
//!   residuals alone covers the placements of the sites it was fitted on; a new site may sit
//!   higher or lower as a whole. The interval adds the between-site variance measured by the
//!   inner leave-one-site-out (the mean squared site-mean error), scaled by the t quantile with
//!   the fitting sites less one degrees of freedom (few sites, wide intervals), so its coverage
//!   at the held-out site is the check.
//! - **Baselines it must beat**, on the same placements, with no fitting: the number of LiDARs,
//!   the number of mounting structures holding one, the total LiDAR beams, the paper's
//!   objective where defined, and every predictor the sets record. The best baseline is the one
//!   with the highest mean ρ over the held-out sites (chosen with hindsight, so the comparison
//!   favours the baseline); the calibrated objective's mean ρ minus it gets a paired bootstrap
//!   interval: each replicate draws every site's placements with replacement and takes their
//!   accuracy under one scene-bootstrap replicate, and scores both predictors on that draw.
//!
//! What it leaves out: the fitted weights are taken as fixed within a held-out site's
//! interval (refitting under the bootstrap would widen it); and sites validated by different
//! detector builds or profiles differ in level for reasons other than the junction, so the
//! report lists each site's profile and commit.

use crate::ValidationReport;
use crate::calibrate::{FEATURES, HeldOut, Row, fit_subset, missing_feature, replicates, subsets};
use crate::rank::{Agreement, agreement, percentile, spearman};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// Sites a leave-one-site-out needs at least: two to fit on (one to choose features by), one
/// held out.
pub const MIN_SITES: usize = 3;

/// Bootstrap replicates of the paired difference.
pub const REPLICATES: usize = 1000;

/// One predictor's ranking of a held-out site's placements, without any fitting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Baseline {
    pub predictor: String,
    pub spearman: Agreement,
}

/// One site held out: the fit on the others, its predictions here, and the baselines here.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeldOutSite {
    /// The `validation.json` as given, its study, profile and the commit that trained it.
    pub site: String,
    pub study: String,
    pub profile: String,
    pub commit: String,
    /// The sites the objective was fitted on.
    pub fitted_on: Vec<String>,
    /// The fit (feature names in the order of `weights`; 0 where not used).
    pub features: Vec<String>,
    pub intercept: f64,
    pub weights: Vec<f64>,
    /// Root mean square of the fitting sites' errors, each site predicted by the fit on the
    /// others (what chose the features), and the between-site variance the interval adds.
    pub inner_rmse: f64,
    pub between_site_sd: f64,
    pub predicted: Vec<HeldOut>,
    pub spearman: Agreement,
    pub kendall: Agreement,
    /// ρ over the placements whose measured mAP is at or above the site's median: the rigs a
    /// buyer chooses between.
    pub better_half_spearman: Agreement,
    /// Mean of measured − predicted, and the root mean square error.
    pub mean_error: f64,
    pub rmse: f64,
    /// Measured values inside their 95% prediction interval.
    pub covered: usize,
    pub baselines: Vec<Baseline>,
    /// What a perfect predictor of the site's accuracy could reach, given how much its
    /// trainings disagree (None with one training per placement).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ceiling: Option<crate::ceiling::Ceiling>,
}

/// The leave-one-site-out validation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SitesReport {
    pub sites: Vec<String>,
    pub held_out: Vec<HeldOutSite>,
    /// Mean over held-out sites of the calibrated objective's ρ.
    pub mean_spearman: f64,
    /// The baseline with the highest mean ρ over held-out sites, and that mean.
    pub best_baseline: String,
    pub best_baseline_spearman: f64,
    /// Calibrated mean ρ − the best baseline's, with its paired 95% bootstrap interval.
    pub difference: Agreement,
    /// The same against the best baseline computable from the placement alone (the others
    /// count points in each rig's simulated validation scenes, the scenes mAP is scored on).
    pub best_placement_baseline: String,
    pub best_placement_baseline_spearman: f64,
    pub placement_difference: Agreement,
    /// The fit on every site (features chosen by leave-one-site-out error over all of them):
    /// the weights a study at another junction places with.
    pub pooled: Pooled,
    /// The objective written to `calibration.toml`: the pooled fit, or the single term that
    /// ranked the held-out sites better, with its prediction model and the sites' ranges.
    pub shipped: hilo_placement_ip::calibrated::file::CalibrationFile,
    pub seed: u64,
    /// What the intervals resample: placements and scenes, and the trainings of the sites
    /// that have several (seeds, training-traffic draws; [`crate::resample`]).
    #[serde(default)]
    pub resampled: String,
}

/// The objective fitted on every site, as `[placement] calibration` takes it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pooled {
    pub intercept: f64,
    pub weights: hilo_placement_ip::calibrated::Weights,
    /// Its leave-one-site-out RMSE over the sites, and the between-site s.d. it measured.
    pub site_rmse: f64,
    pub between_site_sd: f64,
}

impl Pooled {
    /// The study-file line that places with these weights.
    pub fn toml(&self) -> String {
        // `lidar` and `radar` are always written (a study file must give both).
        let terms: Vec<String> = self
            .weights
            .named()
            .iter()
            .filter(|(n, w)| *w > 0.0 || matches!(*n, "lidar" | "radar"))
            .map(|(n, w)| format!("{n} = {w:.4}"))
            .collect();
        format!("calibration = {{ {} }}", terms.join(", "))
    }
}

/// Whether a predictor counts points in the rig's simulated validation scenes (the occupancy
/// predictors) rather than following from the placement alone.
pub fn needs_simulation(name: &str) -> bool {
    use crate::occupancy::{HIT_SHARE, POINTS_PER_USER, RADAR_SHARE};
    (name.starts_with(HIT_SHARE) && name != crate::set::HIT_SHARE_TRAINING)
        || name == POINTS_PER_USER
        || name == RADAR_SHARE
}

/// The count baselines and every predictor all sites record (features and all), by name.
fn baseline_names(sites: &[&ValidationReport]) -> Vec<String> {
    let mut names: Vec<String> = sites
        .first()
        .and_then(|r| r.members.first())
        .map(|(m, _)| m.predictors.keys().cloned().collect())
        .unwrap_or_default();
    names.retain(|n| sites.iter().all(|r| r.members.iter().all(|(m, _)| m.predictors.contains_key(n))));
    names
}

/// The rows of a set of sites, one list per site.
fn site_rows<'a>(sites: &[&'a ValidationReport]) -> Vec<Vec<Row<'a>>> {
    sites
        .iter()
        .map(|r| r.members.iter().map(|(m, t)| Row { predictors: &m.predictors, map: t.map_mean }).collect())
        .collect()
}

/// The fit over `groups` (each a site's rows) whose features minimise the leave-one-site-out
/// squared error within them: for each subset, each group predicted by the fit on the others.
/// Returns the fit on all groups with that subset, the RMS of those errors and the mean squared
/// site-mean error. None when no subset fits every split.
fn fit_across_sites(groups: &[Vec<Row>]) -> Option<(crate::calibrate::Fit, f64, f64)> {
    let mut best: Option<(crate::calibrate::Fit, f64, f64)> = None;
    for used in subsets() {
        let Some((whole, rmse, shift2)) = site_fit(groups, used) else { continue };
        if best.as_ref().is_none_or(|(_, b, _)| rmse < b - 1e-15) {
            best = Some((whole, rmse, shift2));
        }
    }
    best
}

/// The fit on the features `used` over every group, with its leave-one-group-out RMSE and the
/// mean squared group-mean error (the between-site variance); None when a fit fails.
fn site_fit(groups: &[Vec<Row>], used: Vec<usize>) -> Option<(crate::calibrate::Fit, f64, f64)> {
    let all: Vec<Row> = groups.iter().flatten().copied().collect();
    let whole = fit_subset(&all, used.clone())?;
    let (mut sse, mut n, mut shift2) = (0.0, 0usize, 0.0);
    for g in 0..groups.len() {
        let others: Vec<Row> =
            groups.iter().enumerate().filter(|(k, _)| *k != g).flat_map(|(_, r)| r).copied().collect();
        let f = fit_subset(&others, used.clone())?;
        let errors: Vec<f64> = groups[g].iter().map(|r| r.map - f.predict(&|name| r.value(name))).collect();
        sse += errors.iter().map(|e| e * e).sum::<f64>();
        n += errors.len();
        let mean = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
        shift2 += mean * mean;
    }
    (n > 0).then(|| (whole, (sse / n as f64).sqrt(), shift2 / groups.len() as f64))
}

/// A fit's weights as the placement IP takes them.
fn fixed_weights(fit: &crate::calibrate::Fit) -> hilo_placement_ip::calibrated::Weights {
    let w = fit.weights();
    hilo_placement_ip::calibrated::Weights::from_array(std::array::from_fn(|f| w[f]))
}

/// The objective to ship (`calibration.toml`): the fit across all sites, or, when one placement
/// term alone (any feature the fit may choose, a baseline computable from the placement alone)
/// ranked the held-out sites better on average, that term with its own fit across sites; with
/// the ranges of its features over every site's placements.
fn shipped(
    sites: &[(&str, &ValidationReport)],
    groups: &[Vec<Row>],
    held: &[HeldOutSite],
    baselines: &[String],
    pooled: (crate::calibrate::Fit, f64),
    mean_spearman: f64,
) -> Result<hilo_placement_ip::calibrated::file::CalibrationFile, String> {
    use hilo_placement_ip::calibrated::file::{CalibrationFile, FeatureRange, PredictionModel};
    let mean_of = |b: usize| held.iter().map(|h| h.baselines[b].spearman.value).sum::<f64>() / held.len() as f64;
    let best_term = FEATURES
        .iter()
        .enumerate()
        .filter_map(|(k, f)| baselines.iter().position(|b| b == f).map(|b| (k, mean_of(b))))
        .filter(|(_, v)| v.is_finite())
        .max_by(|a, b| a.1.total_cmp(&b.1));
    let single =
        best_term.filter(|&(_, v)| v > mean_spearman).and_then(|(k, v)| Some((site_fit(groups, vec![k])?, k, v)));
    let ((fit, shift2), choice, rho) = match single {
        Some(((f, _, shift2), k, v)) => (
            (f, shift2),
            format!(
                "{} alone: it ranked the held-out sites at mean rho {v:+.2}, the fit across sites at {mean_spearman:+.2}",
                FEATURES[k]
            ),
            v,
        ),
        None => {
            (pooled, "the fit across sites (features chosen by leave-one-site-out error)".to_owned(), mean_spearman)
        }
    };
    let names = hilo_placement_ip::calibrated::Weights::default().named();
    let (inverse, residual_sd, t_fit) = fit.interval_parts();
    let t_sites = crate::calibrate::t975((sites.len() as f64 - 1.0).max(1.0));
    let ranges = fit
        .used
        .iter()
        .map(|&f| {
            let v: Vec<f64> = groups.iter().flatten().map(|r| r.value(FEATURES[f])).collect();
            let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
            let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len().max(2) - 1) as f64).sqrt();
            FeatureRange {
                name: names[f].0.to_owned(),
                min: v.iter().copied().fold(f64::INFINITY, f64::min),
                max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                mean,
                sd,
            }
        })
        .collect();
    let file = CalibrationFile {
        fitted_on: sites.iter().map(|s| s.0.to_owned()).collect(),
        validations: sites
            .iter()
            .map(|(_, r)| {
                format!("{}, {}", r.profile, &r.provenance.git_commit[..r.provenance.git_commit.len().min(7)])
            })
            .collect(),
        choice,
        held_out_spearman: rho,
        weights: fixed_weights(&fit),
        prediction: PredictionModel {
            intercept: fit.beta[0],
            features: fit.used.iter().map(|&f| names[f].0.to_owned()).collect(),
            coefficients: fit.beta[1..].to_vec(),
            inverse,
            residual_sd,
            t_fit,
            between_site_sd: shift2.sqrt(),
            t_sites,
        },
        ranges,
    };
    file.check().map(|()| file)
}

/// Each member's value of predictor `name` (NaN where undefined for the rig).
fn values(r: &ValidationReport, name: &str) -> Vec<f64> {
    r.members.iter().map(|(m, _)| m.predictors.get(name).copied().flatten().unwrap_or(f64::NAN)).collect()
}

/// Site `k` of `sites` held out: fitted on the others, predicted, scored beside `baselines`.
fn hold_out(
    sites: &[(&str, &ValidationReport)],
    k: usize,
    baselines: &[String],
    seed: u64,
) -> Result<HeldOutSite, String> {
    let (name, r) = sites[k];
    let fitting: Vec<&ValidationReport> = sites.iter().enumerate().filter(|(j, _)| *j != k).map(|(_, s)| s.1).collect();
    let (fit, inner_rmse, shift2) = fit_across_sites(&site_rows(&fitting)).ok_or_else(|| {
        format!("the sites other than {name} give no fit (too few placements, or collinear predictors)")
    })?;
    // The between-site variance is estimated from the fitting sites' mean errors: its t
    // quantile has their number less one degrees of freedom (4.30 with three sites).
    let site_df = (fitting.len() as f64 - 1.0).max(1.0);
    let t = crate::calibrate::t975(site_df);
    let predicted: Vec<HeldOut> = r
        .members
        .iter()
        .map(|(m, tr)| {
            let row = Row { predictors: &m.predictors, map: tr.map_mean };
            let x = |f: &str| row.value(f);
            let p = fit.predict(&x);
            // The fit's own interval, widened by the between-site variance.
            let own = fit.half_width(&x);
            let half = (own * own + t * t * shift2).sqrt();
            HeldOut { placement: m.slug.clone(), predicted: p, lo: p - half, hi: p + half, measured: tr.map_mean }
        })
        .collect();
    let pred: Vec<f64> = predicted.iter().map(|h| h.predicted).collect();
    let acc: Vec<f64> = predicted.iter().map(|h| h.measured).collect();
    let reps = replicates(r);
    let (spearman, kendall) = agreement(&pred, &acc, &reps, 0.95, seed);
    let mut sorted = acc.clone();
    sorted.sort_by(f64::total_cmp);
    let median = percentile(&sorted, 0.5);
    let better: Vec<usize> = (0..acc.len()).filter(|&i| acc[i] >= median).collect();
    let pick = |v: &[f64]| better.iter().map(|&i| v[i]).collect::<Vec<f64>>();
    let better_reps: Vec<Vec<f64>> = reps.iter().map(|rep| pick(rep)).collect();
    let (better_half_spearman, _) = agreement(&pick(&pred), &pick(&acc), &better_reps, 0.95, seed);
    let errors: Vec<f64> = predicted.iter().map(|h| h.measured - h.predicted).collect();
    let n = errors.len().max(1) as f64;
    let weights = fit.weights();
    Ok(HeldOutSite {
        site: name.to_owned(),
        study: r.study.clone(),
        profile: r.profile.clone(),
        commit: r.provenance.git_commit.clone(),
        fitted_on: sites.iter().enumerate().filter(|(j, _)| *j != k).map(|(_, s)| s.0.to_owned()).collect(),
        features: FEATURES.iter().map(|f| f.to_string()).collect(),
        intercept: fit.beta[0],
        weights,
        inner_rmse,
        between_site_sd: shift2.sqrt(),
        covered: predicted.iter().filter(|h| (h.lo..=h.hi).contains(&h.measured)).count(),
        mean_error: errors.iter().sum::<f64>() / n,
        rmse: (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
        baselines: baselines
            .iter()
            .map(|b| Baseline { predictor: b.clone(), spearman: agreement(&values(r, b), &acc, &reps, 0.95, seed).0 })
            .collect(),
        ceiling: crate::ceiling::ceiling(&r.members.iter().map(|(_, t)| t).collect::<Vec<_>>(), seed),
        predicted,
        spearman,
        kendall,
        better_half_spearman,
    })
}

/// One site's side of the paired comparison: the calibrated predictions, the baseline's values
/// (NaN where undefined) and the measured accuracy, placement by placement.
#[derive(Clone)]
struct Paired {
    calibrated: Vec<f64>,
    baseline: Vec<f64>,
    accuracy: Vec<f64>,
}

impl Paired {
    /// ρ(calibrated) − ρ(baseline) over the placements where the baseline is defined.
    fn difference(&self) -> f64 {
        let keep: Vec<usize> = (0..self.accuracy.len()).filter(|&i| self.baseline[i].is_finite()).collect();
        let pick = |v: &[f64]| keep.iter().map(|&i| v[i]).collect::<Vec<f64>>();
        let acc = pick(&self.accuracy);
        spearman(&pick(&self.calibrated), &acc) - spearman(&pick(&self.baseline), &acc)
    }

    /// The placements `draw` (with repetition), with the accuracy `rep` (a scene replicate).
    fn drawn(&self, draw: &[usize], rep: &[f64]) -> Paired {
        let pick = |v: &[f64]| draw.iter().map(|&i| v[i]).collect::<Vec<f64>>();
        Paired { calibrated: pick(&self.calibrated), baseline: pick(&self.baseline), accuracy: pick(rep) }
    }
}

/// The mean over sites of [`Paired::difference`]; None when one is not defined.
fn mean_difference(sites: &[Paired]) -> Option<f64> {
    let d: Vec<f64> = sites.iter().map(Paired::difference).collect();
    d.iter().all(|v| v.is_finite()).then(|| d.iter().sum::<f64>() / d.len().max(1) as f64)
}

/// The paired bootstrap of (mean over sites of the calibrated ρ) − (mean of the baseline's),
/// both over the placements where the baseline is defined (the paper's objective: rigs with
/// both modalities): each replicate draws every site's placements with replacement and their
/// accuracy under one scene replicate, the same draw for both predictors.
fn paired_difference(
    sites: &[(&str, &ValidationReport)],
    held: &[HeldOutSite],
    baseline: &str,
    seed: u64,
) -> Agreement {
    let data: Vec<(Paired, Vec<Vec<f64>>)> = sites
        .iter()
        .zip(held)
        .map(|((_, r), h)| {
            let p = Paired {
                calibrated: h.predicted.iter().map(|p| p.predicted).collect(),
                baseline: values(r, baseline),
                accuracy: h.predicted.iter().map(|p| p.measured).collect(),
            };
            (p, replicates(r))
        })
        .collect();
    paired_bootstrap(&data, seed)
}

/// (Mean over `sites` of predictor `a`'s Spearman ρ with measured mAP) − (the same of `b`'s),
/// both recorded predictors and neither fitted, over the placements where `b` is defined, with
/// the interval of [`leave_one_site_out`]'s paired bootstrap (placements, scenes and trainings
/// resampled, the same draw for both): do two placement-only predictors rank the sites apart?
pub fn predictor_difference(sites: &[&ValidationReport], a: &str, b: &str, seed: u64) -> Agreement {
    let data: Vec<(Paired, Vec<Vec<f64>>)> = sites
        .iter()
        .map(|r| {
            let p = Paired {
                calibrated: values(r, a),
                baseline: values(r, b),
                accuracy: r.members.iter().map(|(_, t)| t.map_mean).collect(),
            };
            (p, replicates(r))
        })
        .collect();
    paired_bootstrap(&data, seed)
}

/// The paired bootstrap over `data` (per site, its paired values and its accuracy replicates).
fn paired_bootstrap(data: &[(Paired, Vec<Vec<f64>>)], seed: u64) -> Agreement {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let whole: Vec<Paired> = data.iter().map(|(p, _)| p.clone()).collect();
    let value = mean_difference(&whole).unwrap_or(f64::NAN);
    let mut diffs = Vec::with_capacity(REPLICATES);
    for _ in 0..REPLICATES {
        let drawn: Option<Vec<Paired>> = data
            .iter()
            .map(|(p, reps)| {
                let rep = reps.get(rng.random_range(0..reps.len().max(1)))?;
                let n = p.accuracy.len();
                let draw: Vec<usize> = (0..n).map(|_| rng.random_range(0..n)).collect();
                Some(p.drawn(&draw, rep))
            })
            .collect();
        diffs.extend(drawn.as_deref().and_then(mean_difference));
    }
    diffs.sort_by(f64::total_cmp);
    Agreement { value, lo: percentile(&diffs, 0.025), hi: percentile(&diffs, 0.975), n: data.len() }
}

/// Holds each of `sites` (name, finished validation) out in turn; an error naming the site
/// when fewer than [`MIN_SITES`] are given, a site lacks one of the fit's features (validated
/// by a build from before it: refit it), or a site has fewer than ten placements.
pub fn leave_one_site_out(sites: &[(&str, &ValidationReport)], seed: u64) -> Result<SitesReport, String> {
    if sites.len() < MIN_SITES {
        return Err(format!("{} sites given; leaving one out needs at least {MIN_SITES}", sites.len()));
    }
    for (name, r) in sites {
        if r.members.len() < 10 {
            return Err(format!("{name}: {} placements; a site needs at least 10", r.members.len()));
        }
        if let Some((f, slug)) = missing_feature(r) {
            return Err(format!(
                "{name}: placement {slug:?} has no predictor {f:?}: run `hilo validate --refit` on it with this build"
            ));
        }
    }
    let reports: Vec<&ValidationReport> = sites.iter().map(|s| s.1).collect();
    let baselines = baseline_names(&reports);
    let held: Vec<HeldOutSite> =
        (0..sites.len()).map(|k| hold_out(sites, k, &baselines, seed)).collect::<Result<_, _>>()?;
    let mean = |f: &dyn Fn(&HeldOutSite) -> f64| held.iter().map(f).sum::<f64>() / held.len() as f64;
    let mean_spearman = mean(&|h| h.spearman.value);
    let best = |admit: &dyn Fn(&str) -> bool| {
        baselines
            .iter()
            .enumerate()
            .filter(|(_, name)| admit(name))
            .map(|(b, name)| (name.clone(), mean(&|h| h.baselines[b].spearman.value)))
            .filter(|(_, v)| v.is_finite())
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or_default()
    };
    let (best_baseline, best_baseline_spearman) = best(&|_| true);
    let difference = paired_difference(sites, &held, &best_baseline, seed);
    let (best_placement_baseline, best_placement_baseline_spearman) = best(&|n| !needs_simulation(n));
    let placement_difference = paired_difference(sites, &held, &best_placement_baseline, seed);
    let groups = site_rows(&reports);
    let (fit, site_rmse, shift2) =
        fit_across_sites(&groups).ok_or("the sites together give no fit (collinear predictors)")?;
    let pooled =
        Pooled { intercept: fit.beta[0], weights: fixed_weights(&fit), site_rmse, between_site_sd: shift2.sqrt() };
    let shipped = shipped(sites, &groups, &held, &baselines, (fit, shift2), mean_spearman)?;
    Ok(SitesReport {
        shipped,
        pooled,
        sites: sites.iter().map(|s| s.0.to_owned()).collect(),
        held_out: held,
        mean_spearman,
        best_baseline,
        best_baseline_spearman,
        difference,
        best_placement_baseline,
        best_placement_baseline_spearman,
        placement_difference,
        seed,
        resampled: resampled(sites),
    })
}

/// The bootstrap's units in words: placements and validation scenes, and each placement's
/// trainings at the sites that record several.
fn resampled(sites: &[(&str, &ValidationReport)]) -> String {
    let several: Vec<String> = sites
        .iter()
        .filter_map(|(name, r)| {
            let trained: Vec<&crate::Trained> = r.members.iter().map(|(_, t)| t).collect();
            crate::resample::trainings_resampled(&trained).map(|k| format!("{name} ({k})"))
        })
        .collect();
    match several.is_empty() {
        true => crate::resample::ONE_TRAINING.into(),
        false => format!("placements, validation scenes and the trainings of {}", several.join(", ")),
    }
}

/// `sites.md`: per held-out site the calibrated objective's ranking beside the baselines, then
/// the pooled comparison.
pub fn markdown(r: &SitesReport) -> String {
    let mut s = String::from("# Does the calibrated objective carry to a junction it never saw?\n\n");
    s.push_str(&format!(
        "Leave one site out over {} sites: each site's placements ranked by the objective fitted on the others \
         (features chosen by the leave-one-site-out error among the fitting sites), 95% intervals from the \
         bootstrap over {}.\n\n",
        r.sites.len(),
        r.resampled
    ));
    s.push_str("| held-out site | profile, commit | placements | ρ [95%] | ceiling [95%] | τ [95%] | ρ, better half | mean error | RMSE | inside 95% interval | best baseline here (ρ) |\n|---|---|---:|---|---|---|---|---:|---:|---:|---|\n");
    for h in &r.held_out {
        let best = h
            .baselines
            .iter()
            .filter(|b| b.spearman.value.is_finite())
            .max_by(|a, b| a.spearman.value.total_cmp(&b.spearman.value));
        s.push_str(&format!(
            "| {} | {}, {} | {} | {} | {} | {} | {} | {:+.3} | {:.3} | {} of {} | {} |\n",
            h.site,
            h.profile,
            &h.commit[..h.commit.len().min(7)],
            h.predicted.len(),
            crate::fmt_agreement(&h.spearman),
            h.ceiling.as_ref().map_or("–".into(), |c| c.describe()),
            crate::fmt_agreement(&h.kendall),
            crate::fmt_agreement(&h.better_half_spearman),
            h.mean_error,
            h.rmse,
            h.covered,
            h.predicted.len(),
            best.map_or("–".into(), |b| format!("{} ({:+.2})", b.predictor, b.spearman.value)),
        ));
    }
    if r.held_out.iter().any(|h| h.ceiling.is_some()) {
        let short: Vec<&str> = r
            .held_out
            .iter()
            .filter(|h| h.ceiling.as_ref().is_some_and(|c| h.spearman.hi < c.lo))
            .map(|h| h.site.as_str())
            .collect();
        s.push_str(&format!(
            "\nThe ceiling is the ρ a perfect predictor of a placement's accuracy could reach against the mean of its \
             trainings: two parts of them (draws, each the mean of its seeds, or seeds where there is one draw) rank \
             the placements at the ρ given last, and the square root of the Spearman–Brown reliability of their mean \
             is the most any predictor can agree with it (interval: placements drawn with replacement; the validation \
             scenes are taken as given, and with one draw the traffic's share of the noise is not seen, so the ceiling \
             is then an upper bound). {}\n",
            if short.is_empty() {
                "No held-out ρ's interval lies wholly below its site's ceiling interval.".to_owned()
            } else {
                format!(
                    "Held-out ρ whose interval lies wholly below the ceiling's, short of what the trainings' noise allows: {}.",
                    short.join(", ")
                )
            }
        ));
    }
    s.push_str(&format!(
        "\nMean ρ over held-out sites: calibrated {:+.2}; the best baseline, **{}**, {:+.2} (chosen as the best \
         mean over these sites, with hindsight). Calibrated − baseline: **{}** (paired bootstrap over every site's \
         placements, scenes and trainings, on the placements where the baseline is defined).\n\n",
        r.mean_spearman,
        r.best_baseline,
        r.best_baseline_spearman,
        crate::fmt_agreement(&r.difference)
    ));
    if r.best_placement_baseline != r.best_baseline {
        s.push_str(&format!(
            "That baseline counts points in each rig's simulated validation scenes (a simulation per rig, and the \
             scenes mAP is scored on). From the placement alone the best is **{}**, {:+.2}; calibrated − it: **{}**.\n\n",
            r.best_placement_baseline,
            r.best_placement_baseline_spearman,
            crate::fmt_agreement(&r.placement_difference)
        ));
    }
    s.push_str(&format!(
        "Fitted on all {} sites (leave-one-site-out RMSE {:.3}, between-site s.d. {:.3}), the objective a study at \
         another junction places with: `[placement] objective = \"calibrated\"` and `{}` (predicted mAP = {:+.3} + \
         the weighted terms).\n\n",
        r.sites.len(),
        r.pooled.site_rmse,
        r.pooled.between_site_sd,
        r.pooled.toml(),
        r.pooled.intercept
    ));
    s.push_str(&format!(
        "`calibration.toml` (beside this file; `calibration_file = \"calibration.toml\"` in a study file) ships {} (mean held-out ρ {:+.2}), with its prediction of a rig's mAP and the range of its terms over these sites.\n\n",
        r.shipped.choice, r.shipped.held_out_spearman
    ));
    s.push_str("## The fits\n\n| held-out site | fitted on | intercept | weights | inner leave-one-site-out RMSE | between-site s.d. |\n|---|---|---:|---|---:|---:|\n");
    for h in &r.held_out {
        let w: Vec<String> = h
            .features
            .iter()
            .zip(&h.weights)
            .filter(|(_, w)| **w > 0.0)
            .map(|(f, w)| format!("{w:.3} × {f}"))
            .collect();
        s.push_str(&format!(
            "| {} | {} | {:+.3} | {} | {:.3} | {:.3} |\n",
            h.site,
            h.fitted_on.join(", "),
            h.intercept,
            if w.is_empty() { "none (the intercept alone)".into() } else { w.join(" + ") },
            h.inner_rmse,
            h.between_site_sd
        ));
    }
    s.push_str("\n## Every baseline, per held-out site (Spearman ρ with mAP)\n\n");
    if let Some(first) = r.held_out.first() {
        s.push_str(&format!(
            "| predictor | {} | mean |\n|---|{}---:|\n",
            r.sites.join(" | "),
            "---:|".repeat(r.sites.len())
        ));
        for (b, base) in first.baselines.iter().enumerate() {
            let vals: Vec<f64> = r.held_out.iter().map(|h| h.baselines[b].spearman.value).collect();
            let mean = vals.iter().sum::<f64>() / vals.len() as f64;
            let cells: Vec<String> =
                r.held_out.iter().map(|h| crate::fmt_agreement(&h.baselines[b].spearman)).collect();
            s.push_str(&format!(
                "| {}{} | {} | {} |\n",
                base.predictor,
                if needs_simulation(&base.predictor) { " (simulated scenes)" } else { "" },
                cells.join(" | "),
                if mean.is_finite() { format!("{mean:+.2}") } else { "–".into() }
            ));
        }
    }
    s
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::set::{LIDAR_SATURATED, LIDARS, RADAR_SATURATED};
    use std::collections::BTreeMap;

    /// A site of `n` placements: every feature of the fit drawn uniformly, a LiDAR count, and
    /// mAP = `truth(C_L, C_R)` + noise of s.d. ~0.01 (per member, and ±0.005 per scene replicate).
    fn site(n: usize, seed: u64, truth: impl Fn(f64, f64) -> f64) -> ValidationReport {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        // Features added later draw from a stream of their own, so the others keep their values.
        let mut later = rand_chacha::ChaCha8Rng::seed_from_u64(seed + 1000);
        let members = (0..n)
            .map(|i| {
                let mut predictors: BTreeMap<String, Option<f64>> = FEATURES
                    .iter()
                    .map(|f| {
                        let r = if *f == crate::set::LIDAR_EXTENT { &mut later } else { &mut rng };
                        (f.to_string(), Some(r.random_range(0.0..1.0)))
                    })
                    .collect();
                let (cl, cr) = (rng.random_range(0.3..0.95), rng.random_range(0.0..0.9));
                predictors.insert(LIDAR_SATURATED.into(), Some(cl));
                predictors.insert(RADAR_SATURATED.into(), Some(cr));
                // Counting LiDARs: more LiDARs tend to cover more, with much scatter.
                predictors.insert(LIDARS.into(), Some((cl * 4.0 + rng.random_range(-1.5..1.5)).round().max(1.0)));
                let map = truth(cl, cr) + rng.random_range(-0.017..0.017);
                crate::testing::member(i, predictors, map, 60, &mut rng)
            })
            .collect();
        crate::testing::report(members, 60, &format!("site{seed}"), "quick")
    }

    fn weight(h: &HeldOutSite, f: &str) -> f64 {
        h.features.iter().position(|x| x == f).map_or(0.0, |k| h.weights[k])
    }

    /// LiDAR coverage raises mAP alike at every site (a term that generalises); radar coverage
    /// raises it strongly at site 0 alone (a site-specific term). Held out, the last site is
    /// predicted by a fit that keeps the first and drops the second, although a fit chosen by
    /// PRESS over the same placements keeps both; it ranks the site nearly perfectly, beats a
    /// scattered LiDAR count, and its intervals cover the site.
    #[test]
    fn a_generalising_term_is_kept_and_a_site_specific_one_is_not() {
        let general = |cl: f64, _: f64| 0.1 + 0.6 * cl;
        let sites = [
            site(30, 1, |cl, cr| general(cl, cr) + 0.35 * cr),
            site(30, 2, general),
            site(30, 3, general),
            site(30, 4, general),
        ];
        let named: Vec<(&str, &ValidationReport)> = ["a", "b", "c", "d"].into_iter().zip(sites.iter()).collect();
        let r = leave_one_site_out(&named, 5).unwrap();
        let last = &r.held_out[3];
        assert_eq!(last.fitted_on, vec!["a", "b", "c"]);
        assert!((weight(last, LIDAR_SATURATED) - 0.6).abs() < 0.08, "{last:?}");
        assert_eq!(weight(last, RADAR_SATURATED), 0.0, "the site-specific term is dropped: {:?}", last.weights);
        // PRESS over the pooled placements of a, b and c keeps the radar term.
        let pooled: Vec<Row> = site_rows(&[&sites[0], &sites[1], &sites[2]]).concat();
        let press = crate::calibrate::fit_rows(&pooled).unwrap();
        let radar = FEATURES.iter().position(|f| *f == RADAR_SATURATED).unwrap();
        assert!(press.used.contains(&radar), "PRESS keeps what one site explains");
        assert!(last.spearman.value > 0.9 && last.spearman.lo > 0.7, "{:?}", last.spearman);
        // Site a sits higher as a whole (its radar gain, 0.35 × E[C_R] ≈ 0.16), so the pooled
        // level is about a third of that above the others': the held-out site's bias says so,
        // and its intervals, widened by the between-site spread, still cover it.
        assert!((-0.08..-0.03).contains(&last.mean_error) && last.rmse < 0.08, "{} {}", last.mean_error, last.rmse);
        assert!(last.between_site_sd > 0.03, "{}", last.between_site_sd);
        assert!(last.covered >= 26, "{} of 30 inside", last.covered);
        // The LiDAR count is a baseline, and the objective beats it with an interval above 0.
        assert!(r.held_out.iter().all(|h| h.baselines.iter().any(|b| b.predictor == LIDARS)));
        assert!(
            r.held_out[1..].iter().all(|h| h.spearman.value > 0.85),
            "{:?}",
            r.held_out.iter().map(|h| h.spearman.value).collect::<Vec<_>>()
        );
        // The best baseline is the feature the truth is made of: the fit ranks as it does, and
        // the difference's interval holds 0. Against the count it is clearly positive.
        assert_eq!(r.best_baseline, LIDAR_SATURATED);
        let d = r.difference;
        assert!(d.value.abs() < 0.05 && d.lo <= 0.0 && d.hi >= 0.0, "{d:?}");
        let vs_count = paired_difference(&named, &r.held_out, LIDARS, 5);
        assert!(vs_count.lo > 0.1, "{vs_count:?}");
        // Fitted on all four sites: the general term, not the site-specific one, and a line a
        // study file reads back as the same weights.
        let w = r.pooled.weights;
        assert!((w.lidar - 0.6).abs() < 0.08 && w.radar == 0.0, "{w:?}");
        let table: toml::Table = toml::from_str(&r.pooled.toml()).unwrap();
        let back: hilo_placement_ip::calibrated::Weights = table["calibration"].clone().try_into().unwrap();
        assert!(back.values().iter().zip(w.values()).all(|(a, b)| (a - b).abs() < 1e-4), "{back:?} {w:?}");
        // The shipped file: whichever of the fit and its single terms ranked the held-out sites
        // better (never worse than the fit), the general term's weight, ranges that hold every
        // site's values, and a TOML that reads back equal.
        use hilo_placement_ip::calibrated::file::CalibrationFile;
        let f = &r.shipped;
        assert!(f.held_out_spearman >= r.mean_spearman - 1e-12, "{} {}", f.held_out_spearman, r.mean_spearman);
        assert!((f.weights.lidar - 0.6).abs() < 0.08 && f.weights.radar == 0.0, "{:?}", f.weights);
        assert_eq!(f.fitted_on, vec!["a", "b", "c", "d"]);
        let lidar = f.ranges.iter().find(|x| x.name == "lidar").unwrap();
        for site in &sites {
            for (m, _) in &site.members {
                let v = m.predictors[LIDAR_SATURATED].unwrap();
                assert!(lidar.min <= v && v <= lidar.max);
            }
        }
        assert_eq!(CalibrationFile::from_toml(&f.to_toml().unwrap()).unwrap(), *f);
    }

    /// Two recorded predictors compared without a fit: the one the truth is made of ranks the
    /// sites clearly above a scattered LiDAR count, a predictor against itself differs by
    /// exactly 0 in every replicate, and the order of the two flips the sign.
    #[test]
    fn two_predictors_are_compared_with_a_paired_interval() {
        let g = |cl: f64, _: f64| 0.1 + 0.6 * cl;
        let sites = [site(30, 1, g), site(30, 2, g), site(30, 3, g)];
        let refs: Vec<&ValidationReport> = sites.iter().collect();
        let d = predictor_difference(&refs, LIDAR_SATURATED, LIDARS, 7);
        assert!(d.value > 0.1 && d.lo > 0.0 && d.hi >= d.value, "{d:?}");
        assert_eq!(d.n, 3);
        let back = predictor_difference(&refs, LIDARS, LIDAR_SATURATED, 7);
        assert!((back.value + d.value).abs() < 1e-12, "{back:?} {d:?}");
        let same = predictor_difference(&refs, LIDARS, LIDARS, 7);
        assert_eq!((same.value, same.lo, same.hi), (0.0, 0.0, 0.0));
    }

    /// Too few sites, a small site, and a site without one of the fit's features are refused
    /// with the site named and what to do.
    #[test]
    fn sites_it_cannot_use_are_refused_by_name() {
        let g = |cl: f64, _: f64| 0.1 + 0.6 * cl;
        let (a, b, c) = (site(20, 1, g), site(20, 2, g), site(8, 3, g));
        assert!(leave_one_site_out(&[("a", &a), ("b", &b)], 0).unwrap_err().contains("at least 3"));
        assert!(leave_one_site_out(&[("a", &a), ("b", &b), ("c", &c)], 0).unwrap_err().contains("c: 8 placements"));
        let mut c = site(20, 3, g);
        c.members[2].0.predictors.remove(RADAR_SATURATED);
        let e = leave_one_site_out(&[("a", &a), ("b", &b), ("c", &c)], 0).unwrap_err();
        assert!(e.contains("c:") && e.contains("p2") && e.contains("--refit"), "{e}");
    }

    /// The occupancy of the simulated validation scenes is told apart from what a placement
    /// gives alone (the training traffic's share is ray-cast from the placement).
    #[test]
    fn simulated_predictors_are_told_from_placement_ones() {
        use crate::occupancy::{HIT_SHARE, POINTS_PER_USER, RADAR_SHARE};
        for n in [HIT_SHARE, POINTS_PER_USER, RADAR_SHARE, "road users hit by k LiDAR points (pedestrian)"] {
            assert!(needs_simulation(n), "{n}");
        }
        for n in [crate::set::HIT_SHARE_TRAINING, crate::set::LIDAR_POINTS_CAPPED, crate::set::LIDAR_EXTENT, LIDARS] {
            assert!(!needs_simulation(n), "{n}");
        }
    }

    /// Sites trained twice on each of two draws get a ceiling near 1 (the trainings disagree
    /// little); a site whose accuracy none of the features explains ranks far below it and is
    /// named as short of its ceiling, the others are not; one training per placement gives none.
    #[test]
    fn a_held_out_rho_below_its_ceiling_is_named() {
        let g = |cl: f64, _: f64| 0.1 + 0.6 * cl;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut sites = [site(25, 1, g), site(25, 2, g), site(25, 3, g), site(25, 4, |_, _| 0.0)];
        let single = leave_one_site_out(&sites.iter().map(|s| ("x", s)).collect::<Vec<_>>(), 2).unwrap();
        assert!(single.held_out.iter().all(|h| h.ceiling.is_none()));
        for (k, s) in sites.iter_mut().enumerate() {
            for (_, t) in &mut s.members {
                // The unexplained site: accuracy of its own, the same in every training.
                let base = if k == 3 { rng.random_range(0.2..0.6) } else { t.map_mean };
                t.map = (0..4).map(|_| base + rng.random_range(-0.02..0.02)).collect();
                t.draw = vec![0, 0, 1, 1];
                t.map_mean = t.map.iter().sum::<f64>() / 4.0;
            }
        }
        let named: Vec<(&str, &ValidationReport)> = ["a", "b", "c", "d"].into_iter().zip(sites.iter()).collect();
        let r = leave_one_site_out(&named, 2).unwrap();
        for h in &r.held_out {
            let c = h.ceiling.as_ref().unwrap();
            assert_eq!((c.parts.as_str(), c.count, c.n), ("draws", 2, 25));
            assert!(c.value > 0.95 && c.lo > 0.85, "{}: {c:?}", h.site);
        }
        assert!(r.held_out[3].spearman.value < 0.6, "{:?}", r.held_out[3].spearman);
        let md = markdown(&r);
        assert!(md.contains("short of what the trainings' noise allows: d."), "{md}");
    }

    /// Same inputs and seed, same report.
    #[test]
    fn the_report_is_deterministic() {
        let g = |cl: f64, _: f64| 0.2 + 0.5 * cl;
        let s = [site(15, 1, g), site(15, 2, g), site(15, 3, g)];
        let named: Vec<(&str, &ValidationReport)> = ["a", "b", "c"].into_iter().zip(s.iter()).collect();
        assert_eq!(leave_one_site_out(&named, 9).unwrap(), leave_one_site_out(&named, 9).unwrap());
    }
}
