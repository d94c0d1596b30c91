//! Rank agreement between a predictor and trained accuracy over a set of placements: Spearman's
//! ρ and Kendall's τ-b, with intervals from a bootstrap over placements and validation scenes.
//!
//! A placement objective is useful to a buyer if it orders rigs as trained detectors do; the
//! scale of the objective is arbitrary, so rank correlations are the measure. The interval's
//! replicate r draws the placements with replacement and, for the accuracy, takes each
//! placement's score under the study's scene-bootstrap replicate r (the same validation-scene
//! draw for every placement), so both the choice of placements and the day's traffic move it.

use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// Ranks of `v` (1-based), ties sharing the mean of their ranks.
pub fn ranks(v: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..v.len()).collect();
    idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    let mut out = vec![0.0; v.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && v[idx[j + 1]] == v[idx[i]] {
            j += 1;
        }
        let r = (i + j) as f64 / 2.0 + 1.0;
        for &k in &idx[i..=j] {
            out[k] = r;
        }
        i = j + 1;
    }
    out
}

fn pearson(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    if sxx == 0.0 || syy == 0.0 { f64::NAN } else { sxy / (sxx * syy).sqrt() }
}

/// Spearman's ρ: the Pearson correlation of the ranks (ties averaged). NaN with fewer than
/// three pairs or a constant side.
pub fn spearman(x: &[f64], y: &[f64]) -> f64 {
    if x.len() != y.len() || x.len() < 3 {
        return f64::NAN;
    }
    pearson(&ranks(x), &ranks(y))
}

/// Kendall's τ-b: (concordant − discordant) / √((n₀ − n₁)(n₀ − n₂)), with n₁ and n₂ the pairs
/// tied in x and in y. NaN with fewer than three pairs or a constant side.
pub fn kendall(x: &[f64], y: &[f64]) -> f64 {
    if x.len() != y.len() || x.len() < 3 {
        return f64::NAN;
    }
    let (mut s, mut tx, mut ty, mut n0) = (0i64, 0i64, 0i64, 0i64);
    for i in 0..x.len() {
        for j in i + 1..x.len() {
            n0 += 1;
            let (a, b) = (x[i].total_cmp(&x[j]) as i64, y[i].total_cmp(&y[j]) as i64);
            if a == 0 {
                tx += 1;
            }
            if b == 0 {
                ty += 1;
            }
            s += a * b;
        }
    }
    let d = (((n0 - tx) * (n0 - ty)) as f64).sqrt();
    if d == 0.0 { f64::NAN } else { s as f64 / d }
}

/// A rank correlation with its bootstrap interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Agreement {
    /// On every placement, at the full-data scores.
    pub value: f64,
    pub lo: f64,
    pub hi: f64,
    /// Placements it was computed over.
    pub n: usize,
}

/// The `p` quantile of sorted `v` (the nearest rank, p ∈ [0, 1]); NaN when `v` is empty.
pub(crate) fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() { f64::NAN } else { v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)] }
}

/// Spearman's ρ and Kendall's τ of `predictor` with `accuracy`, and their percentile intervals
/// at `level` over `replicates[r]` (each placement's accuracy under scene replicate r; one
/// entry per placement) with placements drawn with replacement (seeded by `seed`). Placements
/// whose predictor is not finite (undefined for that rig) are left out first.
pub fn agreement(
    predictor: &[f64],
    accuracy: &[f64],
    replicates: &[Vec<f64>],
    level: f64,
    seed: u64,
) -> (Agreement, Agreement) {
    let keep: Vec<usize> =
        (0..predictor.len()).filter(|&i| predictor[i].is_finite() && accuracy[i].is_finite()).collect();
    let x: Vec<f64> = keep.iter().map(|&i| predictor[i]).collect();
    let y: Vec<f64> = keep.iter().map(|&i| accuracy[i]).collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (mut rhos, mut taus) = (Vec::new(), Vec::new());
    for rep in replicates {
        let draw: Vec<usize> = (0..keep.len()).map(|_| keep[rng.random_range(0..keep.len().max(1))]).collect();
        if keep.is_empty() {
            break;
        }
        let xs: Vec<f64> = draw.iter().map(|&i| predictor[i]).collect();
        let ys: Vec<f64> = draw.iter().map(|&i| rep.get(i).copied().unwrap_or(f64::NAN)).collect();
        if ys.iter().any(|v| !v.is_finite()) {
            continue;
        }
        let (r, t) = (spearman(&xs, &ys), kendall(&xs, &ys));
        if r.is_finite() && t.is_finite() {
            rhos.push(r);
            taus.push(t);
        }
    }
    let interval = |mut v: Vec<f64>, value: f64| -> Agreement {
        v.sort_by(f64::total_cmp);
        let a = (1.0 - level) / 2.0;
        Agreement { value, lo: percentile(&v, a), hi: percentile(&v, 1.0 - a), n: keep.len() }
    };
    (interval(rhos, spearman(&x, &y)), interval(taus, kendall(&x, &y)))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::seq::SliceRandom;

    /// Closed forms: ranks with ties; τ of one swapped pair among n is 1 − 4/(n(n−1)); ρ of a
    /// reversal is −1; one tie in x gives τ-b = 5/√(5·6) on (1, 1, 2, 3) against (1, 2, 3, 4).
    #[test]
    fn rank_correlations_match_closed_forms() {
        assert_eq!(ranks(&[3.0, 1.0, 3.0, 2.0]), vec![3.5, 1.0, 3.5, 2.0]);
        let x: Vec<f64> = (0..10).map(f64::from).collect();
        let mut y = x.clone();
        y.swap(3, 4);
        assert!((kendall(&x, &y) - (1.0 - 4.0 / 90.0)).abs() < 1e-12);
        // Spearman with distinct ranks: 1 − 6 Σd² / (n(n² − 1)), Σd² = 2.
        assert!((spearman(&x, &y) - (1.0 - 12.0 / 990.0)).abs() < 1e-12);
        let rev: Vec<f64> = x.iter().rev().copied().collect();
        assert!((spearman(&x, &rev) + 1.0).abs() < 1e-12 && (kendall(&x, &rev) + 1.0).abs() < 1e-12);
        let t = kendall(&[1.0, 1.0, 2.0, 3.0], &[1.0, 2.0, 3.0, 4.0]);
        assert!((t - 5.0 / 30f64.sqrt()).abs() < 1e-12, "{t}");
        assert!(spearman(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]).is_nan());
    }

    /// A planted monotone (non-linear, noisy) relation is found, ρ ≈ 1 with an interval near 1;
    /// the same pairs shuffled give ρ ≈ 0 with an interval that holds 0.
    #[test]
    fn a_planted_relation_is_found_and_a_shuffled_one_is_not() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 40;
        let x: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..10.0)).collect();
        let acc: Vec<f64> = x.iter().map(|v| 1.0 - (-0.3 * v).exp()).collect();
        // Scene replicates: the accuracy plus small noise per replicate.
        let reps: Vec<Vec<f64>> =
            (0..300).map(|_| acc.iter().map(|a| a + rng.random_range(-0.002..0.002)).collect()).collect();
        let (rho, tau) = agreement(&x, &acc, &reps, 0.95, 1);
        assert!(rho.value > 0.999 && tau.value > 0.99, "{rho:?} {tau:?}");
        assert!(rho.lo > 0.95 && tau.lo > 0.85, "{rho:?} {tau:?}");
        // Shuffled pairs: ρ averages ≈ 0 over shuffles and its interval holds 0 about as often
        // as its level says (a single shuffle may correlate by chance).
        let (mut sum, mut holds) = (0.0, 0);
        let shuffles = 40;
        for k in 0..shuffles {
            let mut shuffled = acc.clone();
            shuffled.shuffle(&mut rng);
            let reps: Vec<Vec<f64>> = (0..200).map(|_| shuffled.clone()).collect();
            let (rho, _) = agreement(&x, &shuffled, &reps, 0.95, k);
            sum += rho.value;
            holds += usize::from(rho.lo < 0.0 && rho.hi > 0.0);
        }
        assert!((sum / shuffles as f64).abs() < 0.08, "mean ρ {}", sum / shuffles as f64);
        assert!(holds >= 34, "the interval held 0 in {holds} of {shuffles}");
    }

    /// A predictor undefined for some rigs (NaN) is scored over the others, and says how many.
    #[test]
    fn undefined_predictor_values_are_left_out() {
        let x = [f64::NAN, 1.0, 2.0, 3.0, f64::NAN, 4.0];
        let y = [0.9, 0.1, 0.2, 0.3, 0.0, 0.4];
        let (rho, _) = agreement(&x, &y, &[y.to_vec()], 0.95, 0);
        assert_eq!(rho.n, 4);
        assert!((rho.value - 1.0).abs() < 1e-12);
    }
}
