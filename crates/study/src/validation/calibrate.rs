//! A calibrated objective: trained mAP predicted from saturated LiDAR and radar coverage,
//! fitted on part of the placement set and scored on the placements it did not see.
//!
//! predicted mAP = β₀ + β_L · C_L + β_R · C_R, with C_m = Σ_j w_j min(1, A_mj / τ) / Σ_j w_j
//! ([`super::set::LIDAR_SATURATED`], [`super::set::RADAR_SATURATED`]). The weights are fitted by
//! least squares with β_L, β_R ≥ 0 (the best of the fits on every subset of the two features
//! whose weights come out non-negative): a non-negative weight on a capped sum keeps the
//! objective an integer program (maximise Σ_j w_j z_j with z_j ≤ 1, z_j ≤ A_j / τ), and β_R is
//! the measured marginal accuracy of radar coverage — zero when the trained detectors gain
//! nothing from it, so an optimiser stops buying radars. The placements are split in half by a
//! seeded shuffle; the held-out half gets Spearman's ρ and Kendall's τ against its measured mAP
//! (intervals by the bootstrap over placements and scenes of [`crate::rank`]) and a 95%
//! prediction interval per placement.

use super::ValidationReport;
use super::set::{LIDAR_SATURATED, PAPER_OBJECTIVE, RADAR_SATURATED};
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
    pub features: Vec<String>,
    pub intercept: f64,
    /// Per feature, ≥ 0 (0 where the constrained fit dropped it).
    pub weights: Vec<f64>,
    pub fit_on: Vec<String>,
    /// Residual standard deviation of the fit and its degrees of freedom.
    pub residual_sd: f64,
    pub df: usize,
    pub held_out: Vec<HeldOut>,
    pub held_out_spearman: Agreement,
    pub held_out_kendall: Agreement,
    /// The paper's objective on the same held-out placements (where it is defined).
    pub paper_held_out_spearman: Agreement,
    /// Held-out placements whose measured mAP lies in their prediction interval.
    pub covered: usize,
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

/// Fits the calibrated objective on a seeded half of `r`'s placements and scores it on the
/// other half. None with fewer than eight placements.
pub fn calibrate(r: &ValidationReport, seed: u64) -> Option<Calibrated> {
    let n = r.members.len();
    if n < 8 {
        return None;
    }
    let features = [LIDAR_SATURATED, RADAR_SATURATED];
    let value = |i: usize, f: &str| r.members[i].0.predictors.get(f).copied().flatten().unwrap_or(0.0);
    let mut order: Vec<usize> = (0..n).collect();
    order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
    let (fit, held) = order.split_at(n.div_ceil(2));
    let y: Vec<f64> = fit.iter().map(|&i| r.members[i].1.map_mean).collect();
    // Every subset of the features; keep the best fit whose weights are all ≥ 0.
    // (sum of squared errors, features used, coefficients, (XᵀX)⁻¹)
    type Fit = (f64, Vec<usize>, Vec<f64>, Vec<Vec<f64>>);
    let mut best: Option<Fit> = None;
    for mask in 0..(1usize << features.len()) {
        let used: Vec<usize> = (0..features.len()).filter(|f| mask & (1 << f) != 0).collect();
        let cols: Vec<Vec<f64>> = used.iter().map(|&f| fit.iter().map(|&i| value(i, features[f])).collect()).collect();
        let Some((beta, inv)) = least_squares(&cols, &y) else { continue };
        if beta[1..].iter().any(|b| *b < 0.0) {
            continue;
        }
        let sse: f64 = fit
            .iter()
            .zip(&y)
            .map(|(&i, yi)| {
                let p = beta[0] + used.iter().zip(&beta[1..]).map(|(&f, b)| b * value(i, features[f])).sum::<f64>();
                (yi - p).powi(2)
            })
            .sum();
        if best.as_ref().is_none_or(|b| sse < b.0 - 1e-15) {
            best = Some((sse, used, beta, inv));
        }
    }
    let (sse, used, beta, inv) = best?;
    let df = fit.len().saturating_sub(used.len() + 1).max(1);
    let sd = (sse / df as f64).sqrt();
    let t = statrs::distribution::StudentsT::new(0.0, 1.0, df as f64)
        .map(|d| statrs::distribution::ContinuousCDF::inverse_cdf(&d, 0.975))
        .unwrap_or(1.96);
    let mut weights = vec![0.0; features.len()];
    for (&f, b) in used.iter().zip(&beta[1..]) {
        weights[f] = *b;
    }
    let predict =
        |i: usize| beta[0] + used.iter().zip(&beta[1..]).map(|(&f, b)| b * value(i, features[f])).sum::<f64>();
    let held_out: Vec<HeldOut> = held
        .iter()
        .map(|&i| {
            let x: Vec<f64> = std::iter::once(1.0).chain(used.iter().map(|&f| value(i, features[f]))).collect();
            let h: f64 = (0..x.len()).map(|p| (0..x.len()).map(|q| x[p] * inv[p][q] * x[q]).sum::<f64>()).sum();
            let half = t * sd * (1.0 + h).sqrt();
            let p = predict(i);
            HeldOut {
                placement: r.members[i].0.slug.clone(),
                predicted: p,
                lo: p - half,
                hi: p + half,
                measured: r.members[i].1.map_mean,
            }
        })
        .collect();
    let reps = |idx: &[usize]| -> Vec<Vec<f64>> {
        let m = idx.iter().map(|&i| r.members[i].1.map_replicates.len()).min().unwrap_or(0);
        (0..m).map(|k| idx.iter().map(|&i| r.members[i].1.map_replicates[k]).collect()).collect()
    };
    let acc: Vec<f64> = held.iter().map(|&i| r.members[i].1.map_mean).collect();
    let pred: Vec<f64> = held.iter().map(|&i| predict(i)).collect();
    let (held_out_spearman, held_out_kendall) = agreement(&pred, &acc, &reps(held), 0.95, seed);
    let paper: Vec<f64> = held
        .iter()
        .map(|&i| r.members[i].0.predictors.get(PAPER_OBJECTIVE).copied().flatten().unwrap_or(f64::NAN))
        .collect();
    let (paper_held_out_spearman, _) = agreement(&paper, &acc, &reps(held), 0.95, seed);
    let covered = held_out.iter().filter(|h| (h.lo..=h.hi).contains(&h.measured)).count();
    Some(Calibrated {
        features: features.iter().map(|f| f.to_string()).collect(),
        intercept: beta[0],
        weights,
        fit_on: fit.iter().map(|&i| r.members[i].0.slug.clone()).collect(),
        residual_sd: sd,
        df,
        held_out,
        held_out_spearman,
        held_out_kendall,
        paper_held_out_spearman,
        covered,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    use crate::validation::set::Member;
    use crate::validation::{Trained, ValidationSettings};
    use rand::Rng;
    use std::collections::BTreeMap;

    /// A report of `n` placements whose mAP is `truth(C_L, C_R)` plus seed noise of SD 0.01.
    fn synthetic(n: usize, truth: impl Fn(f64, f64) -> f64) -> ValidationReport {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let members = (0..n)
            .map(|i| {
                let (cl, cr) = (rng.random_range(0.3..0.95), if i % 3 == 0 { 0.0 } else { rng.random_range(0.2..0.9) });
                let placement: hilo_placement_ip::Placement = serde_json::from_value(serde_json::json!({
                    "name": format!("p{i}"), "sensors": [], "objective": 0.0, "bound": null, "gap": null,
                    "proven_optimal": false, "solve_seconds": 0.0, "method": "", "solved": false,
                    "greedy_objective": 0.0, "central_coverage": 0.0, "lidar_radar_overlap": 0.0,
                    "cost_usd": 0.0, "targets": 0, "candidates": 0, "scene_hash": "", "catalog_hash": ""
                }))
                .unwrap();
                let predictors = BTreeMap::from([
                    (LIDAR_SATURATED.to_owned(), Some(cl)),
                    (RADAR_SATURATED.to_owned(), Some(cr)),
                    (PAPER_OBJECTIVE.to_owned(), (cr > 0.0).then_some(cl * cr)),
                ]);
                let m = Member {
                    slug: format!("p{i}"),
                    kind: "random".into(),
                    configuration: String::new(),
                    placement,
                    predictors,
                };
                let map = truth(cl, cr) + rng.random_range(-0.017..0.017);
                let t = Trained {
                    preset: String::new(),
                    map: vec![map],
                    map_mean: map,
                    map_at_b: vec![map],
                    map_at_b_mean: map,
                    pedestrian_ap_mean: map,
                    class_ap: BTreeMap::new(),
                    map_replicates: (0..50).map(|_| map + rng.random_range(-0.005..0.005)).collect(),
                    pedestrian_replicates: vec![map; 50],
                    train_s: 0.0,
                };
                (m, t)
            })
            .collect();
        let none = Agreement { value: f64::NAN, lo: f64::NAN, hi: f64::NAN, n: 0 };
        ValidationReport {
            study: String::new(),
            profile: String::new(),
            settings: ValidationSettings::default(),
            provenance: crate::plan::Provenance::here(1),
            validation_scenes: 0,
            resamples: 50,
            members,
            predictors: Vec::new(),
            budget_spearman: none,
            budget_kendall: none,
            calibrated: None,
            seconds: 0.0,
        }
    }

    /// A planted relation (LiDAR coverage helps, radar coverage does nothing) is recovered: β_L
    /// near its value, β_R near 0, held-out ρ near 1, and the prediction intervals hold most of
    /// the measured values.
    #[test]
    fn a_planted_calibration_is_recovered_on_held_out_placements() {
        let r = synthetic(40, |cl, _| 0.1 + 0.6 * cl);
        let c = calibrate(&r, 0).unwrap();
        assert!((c.weights[0] - 0.6).abs() < 0.06, "{c:?}");
        assert!(c.weights[1] < 0.03, "{c:?}");
        assert!(c.held_out_spearman.value > 0.9, "{:?}", c.held_out_spearman);
        assert!(c.covered as f64 >= 0.8 * c.held_out.len() as f64, "{} of {}", c.covered, c.held_out.len());
        assert_eq!(c.fit_on.len() + c.held_out.len(), 40);
    }

    /// Radar coverage that lowers accuracy gets weight 0, not a negative one (the objective must
    /// stay an IP with capped terms), and an optimiser then buys no radar for it.
    #[test]
    fn a_harmful_feature_is_dropped_not_weighted_negatively() {
        let r = synthetic(30, |cl, cr| 0.1 + 0.6 * cl - 0.2 * cr);
        let c = calibrate(&r, 0).unwrap();
        assert_eq!(c.weights[1], 0.0, "{c:?}");
        assert!(c.weights[0] > 0.0);
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
