//! The accuracy a placement might have had: its mAP under a resample of the validation scenes
//! *and* of its trainings (seeds and training-traffic draws), so an interval on a ranking carries
//! what two runs of the same set would have shown.
//!
//! Each replicate k takes scene-bootstrap replicate k (the mean over trainings of mAP on
//! resampled scenes, as recorded) and moves it by how far a resample of the placement's trainings
//! lies from their mean:
//!
//! 1. **Draws resampled first.** A placement's training-traffic draws are drawn with
//!    replacement, then within each drawn draw its seeds with replacement (a two-stage bootstrap;
//!    a training on another draw saw other traffic, one on another seed the same traffic).
//! 2. **The traffic's common shift removed.** A draw's traffic is the same for every placement
//!    (its seed depends on the draw, not on the rig), so a draw that is easy for all rigs moves
//!    them together and no ranking changes. Each training is first shifted by its draw's mean
//!    offset over the placements (from the mean of all draws); what is resampled is the
//!    placement × draw interaction, which does move rankings.
//! 3. **Small-sample correction.** A bootstrap of the mean of n units has variance (n − 1)/n of
//!    the mean's; with two draws, half. The resampled offset is scaled by √(n/(n − 1)), n the
//!    number of draws (of seeds when there is one draw). For the within-draw stage this
//!    over-corrects slightly, which widens the interval.
//!
//! Placements are resampled independently. A set with one training per placement is left as
//! recorded: its replicates are the scene bootstrap alone. The pedestrian AP uses the same
//! resample of trainings where the set records it per training (sets from before that record
//! it alone carry the scene bootstrap).

use crate::Trained;
use rand::{Rng, SeedableRng};
use std::collections::BTreeMap;

/// Replicates of one accuracy (mAP or pedestrian AP): `replicates[k][i]` is placement i's
/// accuracy under replicate k.
pub type Replicates = Vec<Vec<f64>>;

/// Each placement's trainings, `(draw, value)` per training, and its scene-bootstrap replicates
/// (means over the trainings).
struct Accuracy<'a> {
    trainings: Vec<(u64, f64)>,
    scene: &'a [f64],
}

/// mAP replicates of `trained` (one per placement), scenes and trainings resampled together.
pub fn map_replicates(trained: &[&Trained], seed: u64) -> Replicates {
    let acc: Vec<Accuracy> =
        trained.iter().map(|t| Accuracy { trainings: trainings(t, &t.map), scene: &t.map_replicates }).collect();
    resample(&acc, seed)
}

/// Pedestrian-AP replicates of `trained`, as [`map_replicates`] (trainings resampled where
/// each training's pedestrian AP is recorded).
pub fn pedestrian_replicates(trained: &[&Trained], seed: u64) -> Replicates {
    let acc: Vec<Accuracy> = trained
        .iter()
        .map(|t| {
            let per = if t.pedestrian_ap.len() == t.map.len() { t.pedestrian_ap.as_slice() } else { &[] };
            Accuracy { trainings: trainings(t, per), scene: &t.pedestrian_replicates }
        })
        .collect();
    resample(&acc, seed)
}

/// Replicates of `a`'s mAP less `b`'s, two rigs trained on the same training-traffic draws:
/// scene replicate k's difference, moved by a resample of the trainings in which the draws are
/// drawn *jointly* (a draw's traffic is the same for both rigs, so its common part cancels) and
/// each rig's seeds within a drawn draw independently, scaled as [`map_replicates`]. Rigs whose
/// draws differ are resampled independently instead.
pub fn difference_replicates(a: &Trained, b: &Trained, seed: u64) -> Vec<f64> {
    let n_reps = a.map_replicates.len().min(b.map_replicates.len());
    let (ta, tb) = (
        Accuracy { trainings: trainings(a, &a.map), scene: &[] },
        Accuracy { trainings: trainings(b, &b.map), scene: &[] },
    );
    let (da, db) = (by_draw(&ta.trainings), by_draw(&tb.trainings));
    let finite = a.map.iter().chain(&b.map).all(|v| v.is_finite());
    let joint = da.keys().eq(db.keys());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x6469_6666_5f74_7261);
    let none = BTreeMap::new();
    (0..n_reps)
        .map(|k| {
            let scene = a.map_replicates[k] - b.map_replicates[k];
            if !finite || a.map.len() + b.map.len() < 3 {
                return scene;
            }
            if !joint {
                let mut one = |t: &Accuracy| if t.trainings.len() < 2 { 0.0 } else { offset(t, &none, &mut rng) };
                return scene + one(&ta) - one(&tb);
            }
            let draws: Vec<&u64> = da.keys().collect();
            let pick: Vec<&u64> = (0..draws.len()).map(|_| draws[rng.random_range(0..draws.len())]).collect();
            let drawn: Vec<f64> =
                pick.iter().map(|d| resampled_mean(&da[*d], &mut rng) - resampled_mean(&db[*d], &mut rng)).collect();
            let full = mean(&draws.iter().map(|d| mean(&da[*d]) - mean(&db[*d])).collect::<Vec<f64>>());
            let units = if draws.len() > 1 {
                draws.len()
            } else {
                da.values().chain(db.values()).map(Vec::len).max().unwrap_or(1)
            };
            scene + (mean(&drawn) - full) * correction(units)
        })
        .collect()
}

/// What the replicates resample when every placement has one training.
pub const ONE_TRAINING: &str = "placements and validation scenes (one training per placement: not the trainings)";

/// Which trainings a set's replicates resample: none (one training per placement), "seeds",
/// or "traffic draws, then seeds".
pub fn trainings_resampled(trained: &[&Trained]) -> Option<&'static str> {
    let draws = trained.iter().any(|t| t.draw.iter().any(|d| *d != 0));
    match (trained.iter().any(|t| t.map.len() > 1), draws) {
        (false, _) => None,
        (true, false) => Some("seeds"),
        (true, true) => Some("traffic draws, then seeds"),
    }
}

/// What a set's replicates resample, for a report: "placements, validation scenes and …".
pub fn units(trained: &[&Trained]) -> String {
    match trainings_resampled(trained) {
        None => ONE_TRAINING.into(),
        Some("seeds") => "placements, validation scenes and each placement's seeds".into(),
        Some(k) => format!("placements, validation scenes and each placement's trainings ({k})"),
    }
}

fn resample(acc: &[Accuracy], seed: u64) -> Replicates {
    let n_reps = acc.iter().map(|a| a.scene.len()).min().unwrap_or(0);
    let shift = draw_shifts(acc);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x7261_6e6b_5f74_7261);
    (0..n_reps)
        .map(|k| {
            acc.iter()
                .map(|a| {
                    let scene = a.scene[k];
                    if a.trainings.len() < 2 || !a.trainings.iter().all(|(_, v)| v.is_finite()) {
                        return scene;
                    }
                    scene + offset(a, &shift, &mut rng)
                })
                .collect()
        })
        .collect()
}

/// Each draw's mean offset over the placements that trained on it: a placement's mean on the
/// draw less its mean over its draws, averaged over placements.
fn draw_shifts(acc: &[Accuracy]) -> BTreeMap<u64, f64> {
    let mut sums: BTreeMap<u64, (f64, usize)> = BTreeMap::new();
    for a in acc {
        let by = by_draw(&a.trainings);
        if by.len() < 2 {
            continue;
        }
        let means: BTreeMap<u64, f64> = by.iter().map(|(d, v)| (*d, mean(v))).collect();
        let overall = mean(&means.values().copied().collect::<Vec<f64>>());
        for (d, m) in means {
            let s = sums.entry(d).or_default();
            s.0 += m - overall;
            s.1 += 1;
        }
    }
    sums.into_iter().map(|(d, (s, n))| (d, s / n as f64)).collect()
}

/// The resampled mean of a placement's trainings (draws, then seeds within each draw, with
/// the common draw shift removed) less their mean, scaled for the bootstrap's small-sample bias.
fn offset(a: &Accuracy, shift: &BTreeMap<u64, f64>, rng: &mut impl Rng) -> f64 {
    let by = by_draw(&a.trainings);
    let centred: Vec<Vec<f64>> =
        by.values().zip(by.keys()).map(|(v, d)| v.iter().map(|x| x - shift.get(d).unwrap_or(&0.0)).collect()).collect();
    let full = mean(&centred.iter().map(|v| mean(v)).collect::<Vec<f64>>());
    let draws = centred.len();
    let drawn: Vec<f64> = (0..draws)
        .map(|_| {
            let v = &centred[rng.random_range(0..draws)];
            resampled_mean(v, rng)
        })
        .collect();
    let units = if draws > 1 { draws } else { centred.first().map_or(1, Vec::len) };
    (mean(&drawn) - full) * correction(units)
}

/// √(n/(n − 1)): the bootstrap's variance of a mean of n units made the mean's (0 for one
/// unit, which has nothing to resample).
fn correction(units: usize) -> f64 {
    if units > 1 { (units as f64 / (units as f64 - 1.0)).sqrt() } else { 0.0 }
}

/// `(draw, value)` per training of `t`, `values` in the order of its `map`.
fn trainings(t: &Trained, values: &[f64]) -> Vec<(u64, f64)> {
    values.iter().enumerate().map(|(i, v)| (t.draw_of(i), *v)).collect()
}

/// The mean of `v` resampled with replacement.
fn resampled_mean(v: &[f64], rng: &mut impl Rng) -> f64 {
    mean(&(0..v.len()).map(|_| v[rng.random_range(0..v.len())]).collect::<Vec<f64>>())
}

fn by_draw(trainings: &[(u64, f64)]) -> BTreeMap<u64, Vec<f64>> {
    let mut by: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
    for (d, v) in trainings {
        by.entry(*d).or_default().push(*v);
    }
    by
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::rank::agreement;
    use crate::testing;

    /// A placement whose trainings are `(draw, mAP)`, with `reps` scene replicates all at their mean.
    fn placement(i: usize, trainings: &[(u64, f64)], reps: usize) -> Trained {
        let mut rng = rand::rngs::StdRng::seed_from_u64(i as u64);
        let (_, mut t) = testing::member(i, BTreeMap::new(), 0.0, reps, &mut rng);
        t.map = trainings.iter().map(|x| x.1).collect();
        t.draw = trainings.iter().map(|x| x.0).collect();
        t.map_mean = mean(&t.map);
        t.map_replicates = vec![t.map_mean; reps];
        t
    }

    fn offsets(reps: &Replicates, i: usize, at: f64) -> Vec<f64> {
        reps.iter().map(|r| r[i] - at).collect()
    }

    /// One training per placement, or draws that move every placement alike: the scene
    /// bootstrap alone, unchanged.
    #[test]
    fn nothing_to_resample_leaves_the_scene_bootstrap() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let one: Vec<Trained> =
            (0..6).map(|i| testing::member(i, BTreeMap::new(), 0.1 * i as f64, 50, &mut rng).1).collect();
        let refs: Vec<&Trained> = one.iter().collect();
        let reps = map_replicates(&refs, 9);
        assert_eq!(reps.len(), 50);
        for (k, rep) in reps.iter().enumerate() {
            assert_eq!(rep, &one.iter().map(|t| t.map_replicates[k]).collect::<Vec<f64>>());
        }
        // Draw 1 is 0.15 easier for every rig; seeds agree.
        let shifted: Vec<Trained> = (0..6)
            .map(|i| {
                let x = 0.1 * i as f64;
                placement(i, &[(0, x), (0, x), (1, x + 0.15), (1, x + 0.15)], 50)
            })
            .collect();
        let refs: Vec<&Trained> = shifted.iter().collect();
        for rep in map_replicates(&refs, 9) {
            for (v, t) in rep.iter().zip(&shifted) {
                assert!((v - t.map_mean).abs() < 1e-12, "{v} against {}", t.map_mean);
            }
        }
    }

    /// Two draws of one seed each, an interaction of ±e: the resampled offset is 0 half the
    /// time and ±e√2 otherwise (after the small-sample correction), variance e², which is s²/2
    /// for s² the two values' variance; seeds within one draw give s²/n likewise.
    #[test]
    fn the_resample_carries_the_variance_of_a_mean_of_trainings() {
        let e = 0.04;
        // Interactions of opposite sign cancel in the common draw shift.
        let set: Vec<Trained> = (0..4)
            .map(|i| {
                let (x, s) = (0.2 + 0.1 * i as f64, if i % 2 == 0 { e } else { -e });
                placement(i, &[(0, x + s), (1, x - s)], 4000)
            })
            .collect();
        let refs: Vec<&Trained> = set.iter().collect();
        let reps = map_replicates(&refs, 1);
        let o = offsets(&reps, 0, set[0].map_mean);
        let var = o.iter().map(|v| v * v).sum::<f64>() / o.len() as f64;
        // Mean of two values x ± e: s² = 2e², its variance s²/2 = e².
        assert!((var / (e * e) - 1.0).abs() < 0.1, "variance {var} against {}", e * e);
        let zero = o.iter().filter(|v| v.abs() < 1e-12).count() as f64 / o.len() as f64;
        assert!((zero - 0.5).abs() < 0.05, "{zero}");
        // Four seeds on one draw: 0, 0.1, 0.2, 0.3 (s² = 1/60), the mean's variance s²/4.
        let seeds: Vec<Trained> =
            (0..3).map(|i| placement(i, &[(0, 0.0), (0, 0.1), (0, 0.2), (0, 0.3)], 4000)).collect();
        let refs: Vec<&Trained> = seeds.iter().collect();
        let o = offsets(&map_replicates(&refs, 2), 1, 0.15);
        let var = o.iter().map(|v| v * v).sum::<f64>() / o.len() as f64;
        assert!((var / (1.0 / 240.0) - 1.0).abs() < 0.1, "variance {var}");
        // Same seed, same replicates; another seed, others.
        assert_eq!(map_replicates(&refs, 2), map_replicates(&refs, 2));
        assert_ne!(map_replicates(&refs, 2), map_replicates(&refs, 3));
    }

    /// Draws that rank the rigs in opposite orders: the interval on a predictor's ρ, narrow
    /// under the scenes alone, spans the disagreement once the trainings are resampled.
    #[test]
    fn draws_that_disagree_widen_the_ranking_interval() {
        let set: Vec<Trained> = (0..10)
            .map(|i| {
                let x = 0.3 + 0.01 * i as f64;
                let swing = if i % 2 == 0 { 0.08 } else { -0.08 };
                placement(i, &[(0, x + swing), (1, x - swing)], 400)
            })
            .collect();
        let refs: Vec<&Trained> = set.iter().collect();
        let predictor: Vec<f64> = (0..10).map(|i| i as f64).collect();
        let acc: Vec<f64> = set.iter().map(|t| t.map_mean).collect();
        let scene_only: Replicates = (0..400).map(|k| set.iter().map(|t| t.map_replicates[k]).collect()).collect();
        let (narrow, _) = agreement(&predictor, &acc, &scene_only, 0.95, 0);
        let (wide, _) = agreement(&predictor, &acc, &map_replicates(&refs, 0), 0.95, 0);
        assert!((narrow.value - 1.0).abs() < 1e-12 && (wide.value - 1.0).abs() < 1e-12);
        assert!(narrow.lo > 0.99, "{narrow:?}");
        assert!(wide.lo < 0.0, "{wide:?}");
    }

    /// Two rigs on the same draws: a draw that is 0.12 easier for both cancels in their
    /// difference, while a draw that favours one rig spreads it; rigs on different draws are
    /// resampled apart.
    #[test]
    fn a_difference_resamples_the_draws_jointly() {
        let a = placement(0, &[(0, 0.60), (0, 0.62), (1, 0.72), (1, 0.74)], 2000);
        let b = placement(1, &[(0, 0.50), (0, 0.52), (1, 0.62), (1, 0.64)], 2000);
        let d = difference_replicates(&a, &b, 4);
        assert_eq!(d.len(), 2000);
        // Only the seeds move it (±0.01 about each draw's mean, so at most 0.02·√2 after the
        // correction); the draws' 0.12 resampled apart would move it by up to 0.06·√2.
        let far = d.iter().map(|v| (v - 0.1).abs()).fold(0.0, f64::max);
        assert!(far <= 0.02 * 2f64.sqrt() + 1e-9 && far > 0.004, "{far}");
        // Draw 1 favours b: the difference is 0.2 on draw 0 and 0.0 on draw 1.
        let c = placement(2, &[(0, 0.50), (0, 0.50), (1, 0.50), (1, 0.50)], 2000);
        let e = placement(3, &[(0, 0.30), (0, 0.30), (1, 0.50), (1, 0.50)], 2000);
        let mut d = difference_replicates(&c, &e, 4);
        d.sort_by(f64::total_cmp);
        let (lo, hi) = (crate::rank::percentile(&d, 0.025), crate::rank::percentile(&d, 0.975));
        // Offsets ±0.1√2 a quarter of the time each.
        assert!(
            (lo - (0.1 - 0.1 * 2f64.sqrt())).abs() < 1e-9 && (hi - (0.1 + 0.1 * 2f64.sqrt())).abs() < 1e-9,
            "{lo} {hi}"
        );
        // One training each: the scenes alone.
        let (f, g) = (placement(4, &[(0, 0.4)], 50), placement(5, &[(0, 0.3)], 50));
        assert!(difference_replicates(&f, &g, 4).iter().all(|v| (v - 0.1).abs() < 1e-12));
        assert_eq!(difference_replicates(&c, &e, 4), difference_replicates(&c, &e, 4));
    }

    /// The pedestrian AP is resampled only where each training's is recorded.
    #[test]
    fn pedestrian_trainings_resampled_when_recorded() {
        let mut set: Vec<Trained> = (0..4).map(|i| placement(i, &[(0, 0.1), (1, 0.3)], 200)).collect();
        for t in &mut set {
            t.pedestrian_replicates = vec![0.2; 200];
            t.pedestrian_ap_mean = 0.2;
        }
        let refs: Vec<&Trained> = set.iter().collect();
        assert!(pedestrian_replicates(&refs, 0).iter().flatten().all(|v| *v == 0.2));
        for t in &mut set {
            t.pedestrian_ap = vec![0.1, 0.3];
        }
        set[0].pedestrian_ap = vec![0.3, 0.1];
        let refs: Vec<&Trained> = set.iter().collect();
        assert!(pedestrian_replicates(&refs, 0).iter().flatten().any(|v| (v - 0.2).abs() > 0.05));
    }
}
