//! A calibrated objective: trained mAP predicted from saturated LiDAR and radar coverage,
//! fitted on part of the placement set and scored on the placements it did not see.
//!
//! predicted mAP = β₀ + Σ_m (Σ_k β_mk · C_mk + δ_m · D_m), with C_mk = Σ_j w_j min(1, s_mj / k) / Σ_j w_j,
//! s_mj = Σ_o min(1, a_oj / τ), for each modality m and views k ∈ {1, 2} ([`super::set::LIDAR_SATURATED`],
//! [`super::set::RADAR_SATURATED`], [`super::set::LIDAR_TWO_VIEWS`], [`super::set::RADAR_TWO_VIEWS`]),
//! and D_m = Σ_j w_j min(1, Σ_o a_oj / 2τ) / Σ_j w_j, coverage that pays for density
//! ([`super::set::LIDAR_DENSE`], [`super::set::RADAR_DENSE`]); and the same six with w_j the
//! road users of the study's traffic on target j ([`hilo_plan::road_users`], [`super::set::TERMS`]):
//! coverage of where road users are, class-balanced, rather than of the regions of interest.
//! The weights are fitted by least squares with every β ≥ 0: a non-negative weight on a capped
//! sum keeps the objective an integer program ([`hilo_placement_ip::calibrated`]), and the radar
//! weights are the measured marginal accuracy of radar coverage — zero when the trained
//! detectors gain nothing from it, so an optimiser stops buying radars. Of the subsets of the
//! features whose fitted weights are all ≥ 0, the one with the smallest leave-one-out error on
//! the fitting placements is kept (PRESS: more features always fit better in sample, not out
//! of it). The placements are dealt into folds by a seeded shuffle and each is predicted by the
//! fit on the other folds (cross-fitting); these out-of-fold predictions get Spearman's ρ and
//! Kendall's τ against the measured mAP (intervals by the bootstrap over placements and scenes
//! of [`crate::rank`]) and a 95% prediction interval per placement.

use super::ValidationReport;
use super::set::{PAPER_OBJECTIVE, TERMS};
use crate::rank::{Agreement, agreement};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};

/// One held-out placement: predicted mAP with its 95% prediction interval, and measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeldOut {
    pub placement: String,
    pub predicted: f64,
    pub lo: f64,
    pub hi: f64,
    pub measured: f64,
}

/// The fitted objective and how it predicts placements it did not see.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Calibrated {
    /// Feature names, in the order of `weights`.
    pub features: Vec<String>,
    pub intercept: f64,
    /// Per feature, ≥ 0 (0 where the constrained fit dropped it).
    pub weights: Vec<f64>,
    /// The members the weights were fitted on.
    pub fit_on: Vec<String>,
    /// Residual standard deviation of the fit and its degrees of freedom.
    pub residual_sd: f64,
    pub df: usize,
    /// Root mean square of the leave-one-out errors of the fit on every member (what chose its
    /// features).
    #[serde(default)]
    pub loo_rmse: f64,
    /// Folds of the cross-fitting behind `held_out` (0 in reports from before it: a half split).
    #[serde(default)]
    pub folds: usize,
    /// Every member, predicted by the fit on the folds it is not in.
    pub held_out: Vec<HeldOut>,
    pub held_out_spearman: Agreement,
    pub held_out_kendall: Agreement,
    /// The paper's objective on the same held-out placements (where it is defined).
    pub paper_held_out_spearman: Agreement,
    /// Held-out placements whose measured mAP lies in their prediction interval.
    pub covered: usize,
    /// The held-out Spearman ρ of the same cross-fitting under [`RESHUFFLES`] other deals of the
    /// placements into folds (seeds after the validation's): how far the figure above moves
    /// with the deal alone, the placements and their mAP unchanged (empty in reports from
    /// before it).
    #[serde(default)]
    pub reshuffled_spearman: Vec<f64>,
}

/// Least squares of `y` on the columns `x` (an intercept added): coefficients and (XᵀX)⁻¹, or
/// None when XᵀX is singular.
fn least_squares(x: &[Vec<f64>], y: &[f64]) -> Option<(Vec<f64>, Vec<Vec<f64>>)> {
    let k = x.len() + 1;
    let row = |i: usize| -> Vec<f64> { std::iter::once(1.0).chain(x.iter().map(|c| c[i])).collect() };
    let mut a = vec![vec![0.0; 2 * k]; k];
    let mut b = vec![0.0; k];
    for (i, yi) in y.iter().enumerate() {
        let r = row(i);
        for p in 0..k {
            b[p] += r[p] * yi;
            for q in 0..k {
                a[p][q] += r[p] * r[q];
            }
        }
    }
    // Gauss–Jordan on [XᵀX | I].
    for (p, r) in a.iter_mut().enumerate() {
        r[k + p] = 1.0;
    }
    for c in 0..k {
        let piv = (c..k).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[piv][c].abs() < 1e-12 {
            return None;
        }
        a.swap(c, piv);
        let d = a[c][c];
        for v in a[c].iter_mut() {
            *v /= d;
        }
        for r in 0..k {
            if r != c {
                let f = a[r][c];
                let pivot_row = a[c].clone();
                for (v, p) in a[r].iter_mut().zip(&pivot_row) {
                    *v -= f * p;
                }
            }
        }
    }
    let inv: Vec<Vec<f64>> = a.iter().map(|r| r[k..].to_vec()).collect();
    let beta = (0..k).map(|p| (0..k).map(|q| inv[p][q] * b[q]).sum()).collect();
    Some((beta, inv))
}

/// The features the calibrated objective may use, in the order of [`Calibrated::weights`]:
/// its terms ([`TERMS`]).
pub const FEATURES: [&str; hilo_placement_ip::calibrated::N_TERMS] = TERMS;

/// The placement's weights for the calibrated IP, from a fit over [`FEATURES`] (a feature the
/// fit does not name weighs 0).
pub fn weights(c: &Calibrated) -> hilo_placement_ip::calibrated::Weights {
    let w = |name: &str| c.features.iter().position(|f| f == name).map_or(0.0, |k| c.weights[k]);
    hilo_placement_ip::calibrated::Weights::from_array(TERMS.map(w))
}

/// The 97.5% quantile of Student's t with `df` degrees of freedom (1.96 where statrs refuses
/// the df): the half-width factor of every 95% interval here.
pub(crate) fn t975(df: f64) -> f64 {
    statrs::distribution::StudentsT::new(0.0, 1.0, df)
        .map(|d| statrs::distribution::ContinuousCDF::inverse_cdf(&d, 0.975))
        .unwrap_or(1.96)
}

/// xᵀ (XᵀX)⁻¹ x: a row's leverage.
fn leverage(x: &[f64], inv: &[Vec<f64>]) -> f64 {
    (0..x.len()).map(|p| (0..x.len()).map(|q| x[p] * inv[p][q] * x[q]).sum::<f64>()).sum()
}

/// One constrained fit: the features used, coefficients (intercept first), (XᵀX)⁻¹, residual SD,
/// degrees of freedom and PRESS.
pub(crate) struct Fit {
    pub(crate) used: Vec<usize>,
    pub(crate) beta: Vec<f64>,
    inv: Vec<Vec<f64>>,
    sd: f64,
    df: usize,
    press: f64,
}

impl Fit {
    /// Its coefficients per feature of [`FEATURES`] (0 for a feature it does not use).
    pub(crate) fn weights(&self) -> Vec<f64> {
        let mut w = vec![0.0; FEATURES.len()];
        for (&f, b) in self.used.iter().zip(&self.beta[1..]) {
            w[f] = *b;
        }
        w
    }

    /// (XᵀX)⁻¹ (intercept first), the residual s.d. and the 97.5% t quantile of its degrees of
    /// freedom: what a prediction interval away from the fit needs.
    pub(crate) fn interval_parts(&self) -> (Vec<Vec<f64>>, f64, f64) {
        (self.inv.clone(), self.sd, t975(self.df as f64))
    }

    fn row(&self, x: &dyn Fn(&str) -> f64) -> Vec<f64> {
        std::iter::once(1.0).chain(self.used.iter().map(|&f| x(FEATURES[f]))).collect()
    }

    pub(crate) fn predict(&self, x: &dyn Fn(&str) -> f64) -> f64 {
        self.row(x).iter().zip(&self.beta).map(|(a, b)| a * b).sum()
    }

    /// Half-width of the 95% prediction interval at `x`.
    pub(crate) fn half_width(&self, x: &dyn Fn(&str) -> f64) -> f64 {
        t975(self.df as f64) * self.sd * (1.0 + leverage(&self.row(x), &self.inv)).sqrt()
    }
}

/// One placement as a fit reads it: its predictors and its measured mAP.
#[derive(Clone, Copy)]
pub(crate) struct Row<'a> {
    pub predictors: &'a std::collections::BTreeMap<String, Option<f64>>,
    pub map: f64,
}

impl Row<'_> {
    /// A feature's value (0 where the predictor is undefined for the rig).
    pub(crate) fn value(&self, f: &str) -> f64 {
        self.predictors.get(f).copied().flatten().unwrap_or(0.0)
    }
}

/// The members `idx` of `r` as rows.
fn rows<'a>(r: &'a ValidationReport, idx: &[usize]) -> Vec<Row<'a>> {
    idx.iter().map(|&i| Row { predictors: &r.members[i].0.predictors, map: r.members[i].1.map_mean }).collect()
}

/// The subsets of [`FEATURES`] a fit may use, each as its feature indices.
pub(crate) fn subsets() -> impl Iterator<Item = Vec<usize>> {
    (0..(1usize << FEATURES.len())).map(|mask| (0..FEATURES.len()).filter(|f| mask & (1 << f) != 0).collect())
}

/// The least-squares fit of mAP on the features `used` over `rows`, with its PRESS; None when
/// too few rows, collinear columns, or a weight below 0.
pub(crate) fn fit_subset(rows: &[Row], used: Vec<usize>) -> Option<Fit> {
    if used.len() + 2 > rows.len() {
        return None;
    }
    let y: Vec<f64> = rows.iter().map(|r| r.map).collect();
    let cols: Vec<Vec<f64>> = used.iter().map(|&f| rows.iter().map(|r| r.value(FEATURES[f])).collect()).collect();
    let (beta, inv) = least_squares(&cols, &y)?;
    if beta[1..].iter().any(|b| *b < 0.0) {
        return None;
    }
    let df = rows.len() - used.len() - 1;
    let mut f = Fit { used, beta, inv, sd: 0.0, df, press: 0.0 };
    let mut sse = 0.0;
    for (r, yi) in rows.iter().zip(&y) {
        let x = |name: &str| r.value(name);
        let e = yi - f.predict(&x);
        sse += e * e;
        f.press += (e / (1.0 - leverage(&f.row(&x), &f.inv)).max(1e-9)).powi(2);
    }
    f.sd = (sse / df as f64).sqrt();
    Some(f)
}

/// Fits mAP on [`FEATURES`] over `rows`: of the feature subsets whose least-squares weights are
/// all ≥ 0, the one with the smallest PRESS.
pub(crate) fn fit_rows(rows: &[Row]) -> Option<Fit> {
    let mut best: Option<Fit> = None;
    for used in subsets() {
        let Some(f) = fit_subset(rows, used) else { continue };
        if best.as_ref().is_none_or(|b| f.press < b.press - 1e-15) {
            best = Some(f);
        }
    }
    best
}

/// [`fit_rows`] over the members `idx` of `r`.
fn fit(r: &ValidationReport, idx: &[usize]) -> Option<Fit> {
    fit_rows(&rows(r, idx))
}

/// A placement outside the set predicted by the fit on every member: (mAP, 95% prediction
/// interval low, high).
pub fn predict(r: &ValidationReport, m: &super::set::Member) -> Option<(f64, f64, f64)> {
    let all: Vec<usize> = (0..r.members.len()).collect();
    let f = fit(r, &all)?;
    let x = |name: &str| m.predictors.get(name).copied().flatten().unwrap_or(0.0);
    let (p, half) = (f.predict(&x), f.half_width(&x));
    Some((p, p - half, p + half))
}

/// Folds of the cross-fitting.
pub const FOLDS: usize = 5;

/// Other deals into folds whose held-out ρ [`Calibrated::reshuffled_spearman`] reports.
pub const RESHUFFLES: u64 = 20;

/// Every member predicted by the fit on the [`FOLDS`] − 1 folds it is not in, the members
/// dealt into folds by a shuffle seeded with `seed`; None when a fold's fit fails.
fn cross_fit(r: &ValidationReport, seed: u64) -> Option<Vec<HeldOut>> {
    let n = r.members.len();
    let value = |i: usize, f: &str| r.members[i].0.predictors.get(f).copied().flatten().unwrap_or(0.0);
    let mut order: Vec<usize> = (0..n).collect();
    order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
    let mut held_out = vec![None; n];
    for k in 0..FOLDS {
        let train: Vec<usize> = order.iter().enumerate().filter(|(p, _)| p % FOLDS != k).map(|(_, &i)| i).collect();
        let f = fit(r, &train)?;
        for (_, &i) in order.iter().enumerate().filter(|(p, _)| p % FOLDS == k) {
            let x = |name: &str| value(i, name);
            let (p, half) = (f.predict(&x), f.half_width(&x));
            held_out[i] = Some(HeldOut {
                placement: r.members[i].0.slug.clone(),
                predicted: p,
                lo: p - half,
                hi: p + half,
                measured: r.members[i].1.map_mean,
            });
        }
    }
    held_out.into_iter().collect()
}

/// Fits the calibrated objective and scores it on placements it did not see: the members are
/// dealt into [`FOLDS`] folds by a seeded shuffle, each fold is predicted by a fit on the
/// others (ρ, τ and the 95% prediction intervals are over these out-of-fold predictions), and
/// the weights an optimiser uses are those of the fit on every member. None with fewer than
/// ten placements.
pub fn calibrate(r: &ValidationReport, seed: u64) -> Option<Calibrated> {
    let n = r.members.len();
    if n < 10 {
        return None;
    }
    let held_out = cross_fit(r, seed)?;
    let rho = |h: &[HeldOut]| {
        let (p, m): (Vec<f64>, Vec<f64>) = h.iter().map(|h| (h.predicted, h.measured)).unzip();
        crate::rank::spearman(&p, &m)
    };
    let reshuffled_spearman: Vec<f64> =
        (1..=RESHUFFLES).filter_map(|k| cross_fit(r, seed.wrapping_add(k))).map(|h| rho(&h)).collect();
    let all: Vec<usize> = (0..n).collect();
    let whole = fit(r, &all)?;
    let weights = whole.weights();
    let reps = replicates(r);
    let acc: Vec<f64> = held_out.iter().map(|h| h.measured).collect();
    let pred: Vec<f64> = held_out.iter().map(|h| h.predicted).collect();
    let (held_out_spearman, held_out_kendall) = agreement(&pred, &acc, &reps, 0.95, seed);
    let paper: Vec<f64> = r
        .members
        .iter()
        .map(|(m, _)| m.predictors.get(PAPER_OBJECTIVE).copied().flatten().unwrap_or(f64::NAN))
        .collect();
    let (paper_held_out_spearman, _) = agreement(&paper, &acc, &reps, 0.95, seed);
    let covered = held_out.iter().filter(|h| (h.lo..=h.hi).contains(&h.measured)).count();
    Some(Calibrated {
        features: FEATURES.iter().map(|f| f.to_string()).collect(),
        intercept: whole.beta[0],
        weights,
        fit_on: r.members.iter().map(|(m, _)| m.slug.clone()).collect(),
        residual_sd: whole.sd,
        df: whole.df,
        loo_rmse: (whole.press / n as f64).sqrt(),
        folds: FOLDS,
        held_out,
        held_out_spearman,
        held_out_kendall,
        paper_held_out_spearman,
        covered,
        reshuffled_spearman,
    })
}

/// The calibrated objective of one validation set predicting the placements of another with its
/// weights frozen: no refitting, so the other set's traffic, random rigs and trainings are
/// all unseen. Cross-fitting within one set cannot show this: the set's residuals may have
/// chosen the form of the objective (its features), and its folds share their traffic.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transfer {
    /// The fitted set's `validation.json` as it was named, its study, its validation seed and
    /// the code that ran it.
    pub source: String,
    pub source_study: String,
    pub source_seed: u64,
    pub source_commit: String,
    /// The source's fit on every member (feature names in the order of `weights`).
    pub features: Vec<String>,
    pub intercept: f64,
    pub weights: Vec<f64>,
    /// Every placement of this set, predicted by the source's fit with its 95% prediction
    /// interval, and measured.
    pub predicted: Vec<HeldOut>,
    pub spearman: Agreement,
    pub kendall: Agreement,
    /// Measured values inside their prediction interval.
    pub covered: usize,
    /// Mean of measured − predicted (the fit's bias on this set) and the root mean square error.
    pub mean_error: f64,
    pub rmse: f64,
}

/// Each member's mAP under replicate k, for each k every member has: its validation scenes and
/// its trainings (seeds and training-traffic draws) resampled ([`crate::resample`]).
pub(crate) fn replicates(r: &ValidationReport) -> Vec<Vec<f64>> {
    let trained: Vec<&crate::Trained> = r.members.iter().map(|(_, t)| t).collect();
    crate::resample::map_replicates(&trained, r.settings.seed)
}

/// The first of [`FEATURES`] that some member of `r` lacks (a set scored by a build from before
/// that predictor), with the member: a fit would read it as 0.
pub(crate) fn missing_feature(r: &ValidationReport) -> Option<(&'static str, String)> {
    r.members
        .iter()
        .find_map(|(m, _)| FEATURES.iter().find(|f| !m.predictors.contains_key(**f)).map(|f| (*f, m.slug.clone())))
}

/// Predicts every member of `target` by the calibrated fit of `source` on all of its members
/// (the weights `source` recommends with) and scores the predictions against `target`'s
/// measured mAP: ρ and τ with intervals from `target`'s scene-bootstrap replicates, interval
/// coverage, bias and RMSE. `source_name` names the source in the result. An error when
/// either set lacks one of [`FEATURES`], when `source` is too small to fit, or when its
/// recorded fit differs from the one its members give (fitted by other code).
pub fn transfer(source: &ValidationReport, target: &ValidationReport, source_name: &str) -> Result<Transfer, String> {
    for (r, which) in [(source, "the fitted set"), (target, "this set")] {
        if let Some((f, slug)) = missing_feature(r) {
            return Err(format!(
                "{which} has no predictor {f:?} for placement {slug:?}: run `hilo validate --refit` on it with this build"
            ));
        }
    }
    if source.members.len() < 10 {
        return Err(format!("the fitted set has {} placements; a fit needs at least 10", source.members.len()));
    }
    let all: Vec<usize> = (0..source.members.len()).collect();
    let f = fit(source, &all).ok_or("the fitted set's placements give no fit (collinear predictors)")?;
    let weights = f.weights();
    if let Some(c) = &source.calibrated {
        let same = c.features.len() == FEATURES.len()
            && c.features.iter().zip(FEATURES).all(|(a, b)| a == b)
            && (c.intercept - f.beta[0]).abs() < 1e-9
            && c.weights.iter().zip(&weights).all(|(a, b)| (a - b).abs() < 1e-9);
        if !same {
            return Err("the fitted set's recorded objective is not the fit of its placements by this build: \
                        run `hilo validate --refit` on it first"
                .into());
        }
    }
    let predicted: Vec<HeldOut> = target
        .members
        .iter()
        .map(|(m, t)| {
            let x = |name: &str| m.predictors.get(name).copied().flatten().unwrap_or(0.0);
            let (p, half) = (f.predict(&x), f.half_width(&x));
            HeldOut { placement: m.slug.clone(), predicted: p, lo: p - half, hi: p + half, measured: t.map_mean }
        })
        .collect();
    let n = target.members.len();
    let reps = replicates(target);
    let acc: Vec<f64> = predicted.iter().map(|h| h.measured).collect();
    let pred: Vec<f64> = predicted.iter().map(|h| h.predicted).collect();
    let (spearman, kendall) = agreement(&pred, &acc, &reps, 0.95, target.settings.seed);
    let errors: Vec<f64> = predicted.iter().map(|h| h.measured - h.predicted).collect();
    let denom = n.max(1) as f64;
    Ok(Transfer {
        source: source_name.to_owned(),
        source_study: source.study.clone(),
        source_seed: source.settings.seed,
        source_commit: source.provenance.git_commit.clone(),
        features: FEATURES.iter().map(|f| f.to_string()).collect(),
        intercept: f.beta[0],
        weights,
        covered: predicted.iter().filter(|h| (h.lo..=h.hi).contains(&h.measured)).count(),
        mean_error: errors.iter().sum::<f64>() / denom,
        rmse: (errors.iter().map(|e| e * e).sum::<f64>() / denom).sqrt(),
        predicted,
        spearman,
        kendall,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    use crate::set::{LIDAR_DENSE, LIDAR_SATURATED, LIDAR_TWO_VIEWS, RADAR_DENSE, RADAR_SATURATED, RADAR_TWO_VIEWS};
    use rand::Rng;
    use std::collections::BTreeMap;

    /// A report of `n` placements whose mAP is `truth(C_L, C_R, C_L by two views)` plus seed noise of
    /// SD 0.01.
    fn synthetic(n: usize, truth: impl Fn(f64, f64, f64) -> f64) -> ValidationReport {
        synthetic_seeded(n, 3, truth)
    }

    /// [`synthetic`] with the draws of placements and noise seeded by `seed`.
    fn synthetic_seeded(n: usize, seed: u64, truth: impl Fn(f64, f64, f64) -> f64) -> ValidationReport {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let members = (0..n)
            .map(|i| {
                let (cl, cr) = (rng.random_range(0.3..0.95), if i % 3 == 0 { 0.0 } else { rng.random_range(0.2..0.9) });
                // By two views a target counts at most half as much as by one, up to as much;
                // how much depends on the second views, independent of C_L.
                let cl2 = cl * rng.random_range(0.5..1.0);
                let predictors = BTreeMap::from([
                    (LIDAR_SATURATED.to_owned(), Some(cl)),
                    (RADAR_SATURATED.to_owned(), Some(cr)),
                    (LIDAR_TWO_VIEWS.to_owned(), Some(cl2)),
                    (RADAR_TWO_VIEWS.to_owned(), Some(cr * 0.5)),
                    (PAPER_OBJECTIVE.to_owned(), (cr > 0.0).then_some(cl * cr)),
                ]);
                let map = truth(cl, cr, cl2) + rng.random_range(-0.017..0.017);
                crate::testing::member(i, predictors, map, 50, &mut rng)
            })
            .collect();
        crate::testing::report(members, 50, "", "")
    }

    /// A planted relation (LiDAR coverage helps, radar coverage does nothing) is recovered: β_L
    /// near its value, β_R near 0, held-out ρ near 1, and the prediction intervals hold most of
    /// the measured values.
    #[test]
    fn a_planted_calibration_is_recovered_on_held_out_placements() {
        let r = synthetic(40, |cl, _, _| 0.1 + 0.6 * cl);
        let c = calibrate(&r, 0).unwrap();
        assert!((c.weights[0] - 0.6).abs() < 0.06, "{c:?}");
        assert!(c.weights[1] < 0.03 && c.weights[3] < 0.03, "{c:?}");
        assert!(c.held_out_spearman.value > 0.9, "{:?}", c.held_out_spearman);
        assert!(c.covered as f64 >= 0.8 * c.held_out.len() as f64, "{} of {}", c.covered, c.held_out.len());
        assert_eq!((c.fit_on.len(), c.held_out.len()), (40, 40), "every placement fitted and predicted out of fold");
        // Other deals into folds find it too, each its own cross-fitting.
        assert_eq!(c.reshuffled_spearman.len(), RESHUFFLES as usize);
        assert!(c.reshuffled_spearman.iter().all(|r| *r > 0.85), "{:?}", c.reshuffled_spearman);
        assert!(c.reshuffled_spearman.windows(2).any(|w| w[0] != w[1]), "the deals differ");
    }

    /// Radar coverage that lowers accuracy gets weight 0, not a negative one (the objective must
    /// stay an IP with capped terms), and an optimiser then buys no radar for it.
    #[test]
    fn a_harmful_feature_is_dropped_not_weighted_negatively() {
        let r = synthetic(30, |cl, cr, _| 0.1 + 0.6 * cl - 0.2 * cr);
        let c = calibrate(&r, 0).unwrap();
        assert_eq!(c.weights[1], 0.0, "{c:?}");
        assert_eq!(c.weights[3], 0.0, "{c:?}");
        assert!(c.weights[0] > 0.0);
    }

    /// Accuracy that keeps rising with second views is found in the two-view term, and
    /// the weights go to the IP under their names; a fit without it predicts worse out of
    /// sample.
    #[test]
    fn a_second_view_term_is_found_when_accuracy_needs_it() {
        let r = synthetic(40, |cl, _, cl2| 0.1 + 0.2 * cl + 0.5 * cl2);
        let c = calibrate(&r, 0).unwrap();
        assert!((c.weights[2] - 0.5).abs() < 0.1, "{c:?}");
        let w = weights(&c);
        assert_eq!((w.lidar, w.lidar_two_views), (c.weights[0], c.weights[2]));
        assert!(c.held_out_spearman.value > 0.9, "{:?}", c.held_out_spearman);
        assert!(c.loo_rmse < 0.02, "{c:?}");
    }

    /// `r` with density predictors that accuracy does not depend on (every feature present, as
    /// a set scored by this build has them), and its calibrated objective fitted.
    fn complete(mut r: ValidationReport, seed: u64) -> ValidationReport {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        // Features added later draw from a stream of their own, so the others keep their values.
        let mut later = rand_chacha::ChaCha8Rng::seed_from_u64(seed + 1000);
        for (m, _) in &mut r.members {
            for f in [LIDAR_DENSE, RADAR_DENSE].iter().chain(&TERMS[6..]) {
                let r = if *f == crate::set::LIDAR_EXTENT { &mut later } else { &mut rng };
                m.predictors.insert(f.to_string(), Some(r.random_range(0.0..1.0)));
            }
        }
        r.calibrated = calibrate(&r, 0);
        r
    }

    /// A fit carries to a set drawn apart from it (other placements, other noise) when the
    /// relation is the same: the frozen weights are the source's, they rank the unseen set
    /// nearly perfectly, their intervals hold most of it and the bias is near 0.
    #[test]
    fn a_fit_carries_to_a_set_it_never_saw() {
        let truth = |cl: f64, _: f64, cl2: f64| 0.1 + 0.3 * cl + 0.3 * cl2;
        let source = complete(synthetic_seeded(30, 3, truth), 11);
        let target = complete(synthetic_seeded(30, 7, truth), 12);
        let t = transfer(&source, &target, "a/validation.json").unwrap();
        let c = source.calibrated.as_ref().unwrap();
        assert_eq!((t.intercept, &t.weights), (c.intercept, &c.weights), "the source's weights, frozen");
        assert_eq!(t.predicted.len(), 30);
        assert!(t.spearman.value > 0.9 && t.spearman.lo <= t.spearman.value, "{:?}", t.spearman);
        assert!(t.covered >= 24, "{} of 30 inside", t.covered);
        assert!(t.mean_error.abs() < 0.01 && t.rmse < 0.03, "{t:?}");
        assert_eq!(t.source, "a/validation.json");
    }

    /// A set whose accuracy is 0.1 higher at the same coverage (other traffic, say) is ranked
    /// as well, but the transfer reports the bias and the intervals miss: level and order are
    /// told apart.
    #[test]
    fn a_shifted_set_is_ranked_but_its_bias_is_measured() {
        let truth = |cl: f64, _: f64, _: f64| 0.1 + 0.6 * cl;
        let source = complete(synthetic_seeded(30, 3, truth), 11);
        let target = complete(synthetic_seeded(30, 7, |cl, cr, cl2| truth(cl, cr, cl2) + 0.1), 12);
        let t = transfer(&source, &target, "a").unwrap();
        assert!((t.mean_error - 0.1).abs() < 0.02, "{t:?}");
        assert!(t.rmse >= t.mean_error.abs() - 1e-12);
        assert!(t.spearman.value > 0.9, "{:?}", t.spearman);
        assert!(t.covered < 10, "{} of 30 inside", t.covered);
    }

    /// A set scored by a build without one of the features, or a source whose recorded weights
    /// are not its placements' fit, is refused with what to do, not read as zeros.
    #[test]
    fn a_transfer_refuses_sets_it_cannot_fit_alike() {
        let truth = |cl: f64, _: f64, _: f64| 0.1 + 0.6 * cl;
        let source = complete(synthetic_seeded(30, 3, truth), 11);
        let mut target = complete(synthetic_seeded(30, 7, truth), 12);
        target.members[4].0.predictors.remove(RADAR_DENSE);
        let e = transfer(&source, &target, "a").unwrap_err();
        assert!(e.contains(RADAR_DENSE) && e.contains("p4") && e.contains("--refit"), "{e}");
        let target = complete(synthetic_seeded(30, 7, truth), 12);
        let mut tampered = source.clone();
        if let Some(c) = tampered.calibrated.as_mut() {
            c.weights[0] += 0.05;
        }
        let e = transfer(&tampered, &target, "a").unwrap_err();
        assert!(e.contains("--refit"), "{e}");
        let small = complete(synthetic_seeded(8, 3, truth), 11);
        assert!(transfer(&small, &target, "a").unwrap_err().contains("at least 10"));
    }

    /// Least squares recovers an exact plane, and its (XᵀX)⁻¹ is the inverse.
    #[test]
    fn least_squares_recovers_a_plane() {
        let x1 = [0.1, 0.4, 0.5, 0.9, 0.3, 0.7];
        let x2 = [0.0, 0.2, 0.9, 0.1, 0.5, 0.6];
        let y: Vec<f64> = x1.iter().zip(&x2).map(|(a, b)| 0.2 + 0.5 * a + 0.1 * b).collect();
        let (beta, _) = least_squares(&[x1.to_vec(), x2.to_vec()], &y).unwrap();
        assert!((beta[0] - 0.2).abs() < 1e-12 && (beta[1] - 0.5).abs() < 1e-12 && (beta[2] - 0.1).abs() < 1e-12);
        assert!(least_squares(&[x1.to_vec(), x1.to_vec()], &y).is_none(), "collinear columns");
    }
}
