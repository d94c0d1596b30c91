//! The noise ceiling: the Spearman ρ a perfect predictor of a placement's accuracy could reach
//! against the accuracy a validation measured, given how much its trainings disagree.
//!
//! A placement's measured mAP is the mean of its trainings (seeds on each training-traffic draw).
//! Two halves of those trainings (draw 0 against draw 1, or seed 0 against seed 1 where there is
//! one draw) rank the placements at some ρ₁; that is the agreement of *half* the trainings with
//! another half, and it understates what the full mean allows. Under the classical model
//! (measured = true + independent noise of equal variance in each part), the reliability of the
//! mean of `m` parts is Spearman–Brown's `m ρ₁ / (1 + (m − 1) ρ₁)`, and the correlation of any
//! predictor with the measured mean is at most the square root of that reliability: the
//! correlation of the truth itself with it. Here `ρ₁` is the mean Spearman ρ over every pair of
//! parts, and `m` the number of parts.
//!
//! What it leaves out: Spearman–Brown is exact for Pearson's correlation of normal scores and an
//! approximation for ranks (on a planted model the test below finds it about 0.01 high); the
//! validation scenes are common to every training, so their sampling is part of the "truth" the
//! ceiling refers to (the held-out ρ's interval resamples them; the ceiling does not); and with
//! one traffic draw the draw's share of the noise is invisible, so the ceiling is then an upper
//! bound on the one a second draw would show.

use crate::Trained;
use crate::rank::{percentile, spearman};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// Bootstrap replicates (placements drawn with replacement) behind the ceiling's interval.
pub const REPLICATES: usize = 1000;

/// The noise ceiling of one validation set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ceiling {
    /// What the parts are: `"draws"` (each the mean of its seeds) or `"seeds"` (on draw 0).
    pub parts: String,
    /// How many parts the measured mean averages.
    pub count: usize,
    /// Mean Spearman ρ between two parts.
    pub part_spearman: f64,
    /// √(Spearman–Brown reliability of the mean of `count` parts): the ceiling.
    pub value: f64,
    /// Its 95% interval over placements drawn with replacement.
    pub lo: f64,
    pub hi: f64,
    /// Placements it was computed over.
    pub n: usize,
}

/// √ of the Spearman–Brown reliability of the mean of `m` parts whose pairwise correlation is
/// `r` (0 where `r` ≤ 0: the parts share nothing the mean could be ranked by).
pub fn from_part_correlation(r: f64, m: usize) -> f64 {
    if !r.is_finite() || r <= 0.0 {
        return 0.0;
    }
    let m = m as f64;
    (m * r / (1.0 + (m - 1.0) * r)).sqrt()
}

/// Each placement's accuracy by part: per draw (the mean of its seeds) where every placement
/// has two draws or more, else per seed on draw 0 where every placement has two seeds or more.
fn parts(trained: &[&Trained]) -> Option<(&'static str, Vec<Vec<f64>>)> {
    let draws = trained
        .iter()
        .map(|t| {
            let mut ds: Vec<u64> = (0..t.map.len()).map(|i| t.draw_of(i)).collect();
            ds.sort_unstable();
            ds.dedup();
            ds
        })
        .min_by_key(Vec::len)?;
    if draws.len() >= 2 {
        let by: Option<Vec<Vec<f64>>> =
            trained.iter().map(|t| draws.iter().map(|&d| t.draw_mean(d)).collect()).collect();
        return by.map(|b| ("draws", b));
    }
    let seeds = trained.iter().map(|t| (0..t.map.len()).filter(|&i| t.draw_of(i) == 0).count()).min()?;
    (seeds >= 2).then(|| {
        let by = trained
            .iter()
            .map(|t| (0..t.map.len()).filter(|&i| t.draw_of(i) == 0).take(seeds).map(|i| t.map[i]).collect())
            .collect();
        ("seeds", by)
    })
}

/// Mean Spearman ρ over every pair of parts, on the placements `rows` (indices into `by`).
fn mean_pairwise(by: &[Vec<f64>], rows: &[usize], m: usize) -> f64 {
    let (mut sum, mut pairs) = (0.0, 0usize);
    for a in 0..m {
        for b in a + 1..m {
            let x: Vec<f64> = rows.iter().map(|&i| by[i][a]).collect();
            let y: Vec<f64> = rows.iter().map(|&i| by[i][b]).collect();
            let r = spearman(&x, &y);
            if r.is_finite() {
                sum += r;
                pairs += 1;
            }
        }
    }
    if pairs == 0 { f64::NAN } else { sum / pairs as f64 }
}

/// The ceiling of a set whose placements were trained as `trained` (None with one training per
/// placement, or fewer than four placements).
pub fn ceiling(trained: &[&Trained], seed: u64) -> Option<Ceiling> {
    let (kind, by) = parts(trained)?;
    let n = by.len();
    let m = by.first()?.len();
    if n < 4 || m < 2 {
        return None;
    }
    let all: Vec<usize> = (0..n).collect();
    let r = mean_pairwise(&by, &all, m);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut reps: Vec<f64> = (0..REPLICATES)
        .filter_map(|_| {
            let rows: Vec<usize> = (0..n).map(|_| rng.random_range(0..n)).collect();
            let r = mean_pairwise(&by, &rows, m);
            r.is_finite().then(|| from_part_correlation(r, m))
        })
        .collect();
    reps.sort_by(f64::total_cmp);
    Some(Ceiling {
        parts: kind.to_owned(),
        count: m,
        part_spearman: r,
        value: from_part_correlation(r, m),
        lo: percentile(&reps, 0.025),
        hi: percentile(&reps, 0.975),
        n,
    })
}

impl Ceiling {
    /// "+0.94 [+0.80, +0.98] (2 draws, +0.78 between them)".
    pub fn describe(&self) -> String {
        format!(
            "{:+.2} [{:+.2}, {:+.2}] ({} {}, {:+.2} between two)",
            self.value, self.lo, self.hi, self.count, self.parts, self.part_spearman
        )
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand_distr::{Distribution, Normal};
    use std::collections::BTreeMap;

    /// A placement trained `draws` × `seeds` times: truth + a draw's noise + a training's noise.
    fn trained(truth: f64, draws: u64, seeds: usize, sd_draw: f64, sd_seed: f64, rng: &mut impl Rng) -> Trained {
        let (nd, ns) = (Normal::new(0.0, sd_draw).unwrap(), Normal::new(0.0, sd_seed).unwrap());
        let mut map = Vec::new();
        let mut draw = Vec::new();
        for d in 0..draws {
            let shift = nd.sample(rng);
            for _ in 0..seeds {
                map.push(truth + shift + ns.sample(rng));
                draw.push(d);
            }
        }
        let mean = map.iter().sum::<f64>() / map.len() as f64;
        Trained {
            preset: String::new(),
            map_at_b: map.clone(),
            map,
            draw,
            map_mean: mean,
            map_at_b_mean: mean,
            pedestrian_ap_mean: mean,
            pedestrian_ap: Vec::new(),
            class_ap: BTreeMap::new(),
            map_replicates: Vec::new(),
            pedestrian_replicates: Vec::new(),
            train_s: 0.0,
        }
    }

    /// The closed form: one part is its own reliability; more parts raise it; nothing shared
    /// gives 0; perfect agreement gives 1.
    #[test]
    fn spearman_brown_closed_forms() {
        assert!((from_part_correlation(0.64, 1) - 0.8).abs() < 1e-12);
        // Two parts at 0.78: reliability 1.56 / 1.78.
        assert!((from_part_correlation(0.78, 2) - (1.56f64 / 1.78).sqrt()).abs() < 1e-12);
        assert_eq!(from_part_correlation(-0.2, 2), 0.0);
        assert_eq!(from_part_correlation(f64::NAN, 2), 0.0);
        assert!((from_part_correlation(1.0, 4) - 1.0).abs() < 1e-12);
        assert!(from_part_correlation(0.5, 4) > from_part_correlation(0.5, 2));
    }

    /// On a planted model (true accuracy + a draw's shift + a training's noise, at the sizes of
    /// hilo's validation sets), the ceiling estimated from the parts matches, on average over
    /// 400 sets, the Spearman ρ of the truth itself with the measured mean (what a perfect
    /// predictor reaches), in the noisy regime and the quiet one, with draws as parts and with
    /// seeds; its interval holds that ρ's average in most sets.
    #[test]
    fn the_ceiling_is_what_the_truth_itself_reaches() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for (draws, seeds, sd_draw, sd_seed) in [(2, 2, 0.03, 0.03), (2, 2, 0.01, 0.01), (1, 2, 0.0, 0.04)] {
            let (mut est, mut truth_rho, mut holds) = (0.0, 0.0, 0);
            let sets = 400;
            let mut per_set = Vec::new();
            for k in 0..sets {
                let truths: Vec<f64> = (0..25).map(|_| rng.random_range(0.3..0.6)).collect();
                let t: Vec<Trained> =
                    truths.iter().map(|&v| trained(v, draws, seeds, sd_draw, sd_seed, &mut rng)).collect();
                let refs: Vec<&Trained> = t.iter().collect();
                let c = ceiling(&refs, k).unwrap();
                assert_eq!((c.parts.as_str(), c.count), if draws >= 2 { ("draws", 2) } else { ("seeds", 2) });
                let measured: Vec<f64> = t.iter().map(|x| x.map_mean).collect();
                let rho = spearman(&truths, &measured);
                est += c.value;
                truth_rho += rho;
                per_set.push(c);
            }
            let (est, truth_rho) = (est / sets as f64, truth_rho / sets as f64);
            for c in &per_set {
                holds += usize::from(c.lo <= truth_rho && truth_rho <= c.hi);
            }
            assert!(
                (est - truth_rho).abs() < 0.03,
                "{draws}×{seeds}: estimated {est:.3}, the truth reaches {truth_rho:.3}"
            );
            assert!(
                holds as f64 >= 0.85 * sets as f64,
                "{draws}×{seeds}: {holds} of {sets} intervals hold {truth_rho:.3}"
            );
        }
    }

    /// One training per placement has no ceiling; nor do three placements.
    #[test]
    fn one_training_or_too_few_placements_give_none() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let one: Vec<Trained> = (0..10).map(|i| trained(0.1 * i as f64, 1, 1, 0.0, 0.01, &mut rng)).collect();
        assert_eq!(ceiling(&one.iter().collect::<Vec<_>>(), 0), None);
        let few: Vec<Trained> = (0..3).map(|i| trained(0.1 * i as f64, 2, 2, 0.01, 0.01, &mut rng)).collect();
        assert_eq!(ceiling(&few.iter().collect::<Vec<_>>(), 0), None);
    }
}
