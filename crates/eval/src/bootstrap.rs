//! Confidence intervals by resampling scenes.
//!
//! Frames of one scene are correlated (the same road users, seconds apart), so the unit of
//! resampling is the scene: a replicate draws as many scenes as there are, with replacement, and
//! counts every frame of a scene drawn k times k times. Matching is decided within each frame, so
//! it is done once ([`Matches`]) and each replicate only reweights it; a scene drawn k times adds
//! its predictions to the precision–recall curve as steps of weight k (the devkit would interleave
//! k copies of equal score; the difference lies within a step). Intervals are percentile
//! intervals; replicates are seeded by (seed, index), so the same seed gives the same interval.
//!
//! The paired bootstrap draws the same scenes for two submissions on the same ground truth; the
//! interval of the difference, and the share of replicates where the second is not better, say
//! whether a gain is real.

use crate::boxes::{EvalBox, GroundTruth};
use crate::config::DetectionConfig;
use crate::nuscenes::{ClassData, Matches, summarize};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A point estimate (on the original data) with a percentile interval from the replicates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    pub estimate: f64,
    pub lo: f64,
    pub hi: f64,
    pub std: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BootstrapSummary {
    pub resamples: usize,
    pub level: f64,
    pub scenes: usize,
    pub mean_ap: Interval,
    pub nd_score: Interval,
    pub class_ap: BTreeMap<String, Interval>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairedSummary {
    pub resamples: usize,
    pub level: f64,
    /// B − A.
    pub mean_ap_diff: Interval,
    pub nd_score_diff: Interval,
    pub class_ap_diff: BTreeMap<String, Interval>,
    /// Share of replicates in which B's mAP is not above A's (a one-sided bootstrap p-value).
    pub p_mean_ap_not_better: f64,
    pub p_nd_score_not_better: f64,
}

/// One replicate: (mAP, NDS, per-class mean AP), or their differences.
type Replicate = (f64, f64, BTreeMap<String, f64>);

/// Matched tables of one submission.
struct Tables {
    classes: Vec<String>,
    /// (class, threshold) → matches.
    by_key: Vec<(String, f64, Matches)>,
}

fn tables(gt: &BTreeMap<String, Vec<EvalBox>>, pred: &[(String, Vec<EvalBox>)], cfg: &DetectionConfig) -> Tables {
    let classes = cfg.class_names();
    let mut ths = cfg.dist_ths.clone();
    if !ths.contains(&cfg.dist_th_tp) {
        ths.push(cfg.dist_th_tp);
    }
    let by_key = classes
        .par_iter()
        .flat_map_iter(|c| {
            let cd = ClassData::new(gt, pred, c);
            ths.iter().map(move |&t| (c.clone(), t, cd.matches(c, t))).collect::<Vec<_>>()
        })
        .collect();
    Tables { classes, by_key }
}

/// (mAP, NDS, per-class mean AP) with sample weights.
fn score(t: &Tables, cfg: &DetectionConfig, w: Option<&[f64]>) -> Replicate {
    // Thresholds that only feed AP need only the precision, streamed; the TP threshold needs the
    // full curves.
    let m = summarize(&t.classes, cfg, |c, th| {
        t.by_key.iter().find(|(kc, kt, _)| kc == c && *kt == th).map(|x| {
            if th == cfg.dist_th_tp {
                x.2.curves(w)
            } else {
                let mut p = [0.0; crate::nuscenes::NELEM];
                x.2.precision_only(w, &mut p);
                let mut md = crate::nuscenes::MetricData::no_predictions();
                md.precision = p.to_vec();
                md
            }
        })
    });
    (m.mean_ap, m.nd_score, m.mean_dist_aps)
}

fn interval(estimate: f64, mut v: Vec<f64>, level: f64) -> Interval {
    v.retain(|x| !x.is_nan());
    if v.is_empty() {
        return Interval { estimate, lo: f64::NAN, hi: f64::NAN, std: f64::NAN };
    }
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let std = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len().max(2) - 1) as f64).sqrt();
    Interval { estimate, lo: q(0.5 * (1.0 - level)), hi: q(1.0 - 0.5 * (1.0 - level)), std }
}

/// How often each scene is drawn in replicate `i` (scenes drawn with replacement).
fn scene_counts(n_scenes: usize, seed: u64, i: usize) -> Vec<f64> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let mut count = vec![0.0; n_scenes];
    for _ in 0..n_scenes {
        count[rng.random_range(0..n_scenes)] += 1.0;
    }
    count
}

/// Sample weights of one replicate.
fn weights(sample_scene: &[usize], n_scenes: usize, seed: u64, i: usize) -> Vec<f64> {
    let count = scene_counts(n_scenes, seed, i);
    sample_scene.iter().map(|&s| count[s]).collect()
}

fn scene_index(gt: &GroundTruth) -> (Vec<usize>, usize) {
    let mut ids: BTreeMap<&str, usize> = BTreeMap::new();
    for info in gt.samples.values() {
        let n = ids.len();
        ids.entry(info.scene.as_str()).or_insert(n);
    }
    (gt.samples.values().map(|i| ids[i.scene.as_str()]).collect(), ids.len())
}

/// Percentile intervals of mAP, NDS and per-class AP at `level` (e.g. 0.95).
pub fn bootstrap(gt: &GroundTruth, pred: &[(String, Vec<EvalBox>)], cfg: &DetectionConfig, resamples: usize, level: f64, seed: u64) -> BootstrapSummary {
    let (gt_f, pred_f) = crate::filtered(gt, pred, cfg);
    let t = tables(&gt_f, &pred_f, cfg);
    let (map0, nds0, cls0) = score(&t, cfg, None);
    let (sample_scene, n_scenes) = scene_index(gt);
    let reps: Vec<Replicate> =
        (0..resamples).into_par_iter().map(|i| score(&t, cfg, Some(&weights(&sample_scene, n_scenes, seed, i)))).collect();
    let class_ap = cls0.iter().map(|(c, e)| (c.clone(), interval(*e, reps.iter().map(|r| r.2[c]).collect(), level))).collect();
    BootstrapSummary {
        resamples,
        level,
        scenes: n_scenes,
        mean_ap: interval(map0, reps.iter().map(|r| r.0).collect(), level),
        nd_score: interval(nds0, reps.iter().map(|r| r.1).collect(), level),
        class_ap,
    }
}

/// The paired bootstrap of B − A on the same ground truth.
pub fn paired(gt: &GroundTruth, a: &[(String, Vec<EvalBox>)], b: &[(String, Vec<EvalBox>)], cfg: &DetectionConfig, resamples: usize, level: f64, seed: u64) -> PairedSummary {
    paired_between(gt, a, gt, b, cfg, resamples, level, seed)
}

/// The paired bootstrap of B − A where A and B have their own ground truth over the same
/// scenes (e.g. two sensor configurations recording the same traffic: each keeps the boxes its
/// own sensors saw, as the nuScenes loader does). Scenes are matched by `SampleInfo::scene`,
/// which must name the same scene in both; each replicate draws the same scenes for both.
#[allow(clippy::too_many_arguments)]
pub fn paired_between(gt_a: &GroundTruth, a: &[(String, Vec<EvalBox>)], gt_b: &GroundTruth, b: &[(String, Vec<EvalBox>)], cfg: &DetectionConfig, resamples: usize, level: f64, seed: u64) -> PairedSummary {
    let (ga_f, a_f) = crate::filtered(gt_a, a, cfg);
    let (gb_f, b_f) = crate::filtered(gt_b, b, cfg);
    let (ta, tb) = (tables(&ga_f, &a_f, cfg), tables(&gb_f, &b_f, cfg));
    let (ma, na, ca) = score(&ta, cfg, None);
    let (mb, nb, cb) = score(&tb, cfg, None);
    let mut ids: BTreeMap<&str, usize> = BTreeMap::new();
    for info in gt_a.samples.values().chain(gt_b.samples.values()) {
        let n = ids.len();
        ids.entry(info.scene.as_str()).or_insert(n);
    }
    let sa: Vec<usize> = gt_a.samples.values().map(|i| ids[i.scene.as_str()]).collect();
    let sb: Vec<usize> = gt_b.samples.values().map(|i| ids[i.scene.as_str()]).collect();
    let n_scenes = ids.len();
    let reps: Vec<Replicate> = (0..resamples)
        .into_par_iter()
        .map(|i| {
            let count = scene_counts(n_scenes, seed, i);
            let wa: Vec<f64> = sa.iter().map(|&s| count[s]).collect();
            let wb: Vec<f64> = sb.iter().map(|&s| count[s]).collect();
            let (xa, ya, za) = score(&ta, cfg, Some(&wa));
            let (xb, yb, zb) = score(&tb, cfg, Some(&wb));
            (xb - xa, yb - ya, zb.iter().map(|(c, v)| (c.clone(), v - za.get(c).copied().unwrap_or(f64::NAN))).collect())
        })
        .collect();
    let share = |f: &dyn Fn(&Replicate) -> bool| reps.iter().filter(|r| f(r)).count() as f64 / reps.len().max(1) as f64;
    PairedSummary {
        resamples,
        level,
        mean_ap_diff: interval(mb - ma, reps.iter().map(|r| r.0).collect(), level),
        nd_score_diff: interval(nb - na, reps.iter().map(|r| r.1).collect(), level),
        class_ap_diff: cb.iter().map(|(c, v)| (c.clone(), interval(v - ca.get(c).copied().unwrap_or(f64::NAN), reps.iter().map(|r| r.2.get(c).copied().unwrap_or(f64::NAN)).collect(), level))).collect(),
        p_mean_ap_not_better: share(&|r| r.0 <= 0.0),
        p_nd_score_not_better: share(&|r| r.1 <= 0.0),
    }
}
