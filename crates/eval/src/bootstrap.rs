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
use crate::nuscenes::{ClassData, DetectionMetrics, Matches, MetricData, NELEM, summarize};
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

/// Fewer scenes than this and a scene bootstrap has too few distinct resamples to say anything
/// (2 scenes: 3 distinct resamples): its intervals are reported as not estimable.
pub const MIN_SCENES: usize = 5;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BootstrapSummary {
    pub resamples: usize,
    pub level: f64,
    pub scenes: usize,
    /// Whether there are at least [`MIN_SCENES`] scenes; without them the intervals mean nothing.
    pub estimable: bool,
    pub mean_ap: Interval,
    pub nd_score: Interval,
    pub class_ap: BTreeMap<String, Interval>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairedSummary {
    pub resamples: usize,
    pub level: f64,
    pub scenes: usize,
    /// Whether there are at least [`MIN_SCENES`] scenes; without them the intervals and the
    /// p-value mean nothing.
    pub estimable: bool,
    /// B − A.
    pub mean_ap_diff: Interval,
    pub nd_score_diff: Interval,
    pub class_ap_diff: BTreeMap<String, Interval>,
    /// Share of replicates in which B's mAP is not above A's (a one-sided bootstrap p-value).
    pub p_mean_ap_not_better: f64,
    pub p_nd_score_not_better: f64,
}

/// One replicate: (mAP, NDS, per-class mean AP), or their differences.
pub type Replicate = (f64, f64, BTreeMap<String, f64>);

/// One replicate's velocity errors in m/s: mAVE (the mean over classes, as NDS takes it) and
/// each class's AVE (NaN where the devkit exempts the class; 1 where the class has no true
/// positive up to the minimum recall, as the devkit scores it).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VelocityErrors {
    pub mean: f64,
    pub by_class: BTreeMap<String, f64>,
}

impl VelocityErrors {
    fn of(m: &DetectionMetrics) -> Self {
        let vel = |e: &BTreeMap<String, f64>| e.get("vel_err").copied().unwrap_or(f64::NAN);
        VelocityErrors {
            mean: vel(&m.tp_errors),
            by_class: m.label_tp_errors.iter().map(|(c, e)| (c.clone(), vel(e))).collect(),
        }
    }
}

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

/// (mAP, NDS, per-class mean AP) and the velocity errors, with sample weights.
fn score(t: &Tables, cfg: &DetectionConfig, w: Option<&[u32]>) -> (Replicate, VelocityErrors) {
    let m = summarize(&t.classes, cfg, |c, th| {
        t.by_key.iter().find(|(kc, kt, _)| kc == c && *kt == th).map(|x| x.2.curves(w))
    });
    let v = VelocityErrors::of(&m);
    ((m.mean_ap, m.nd_score, m.mean_dist_aps), v)
}

/// Replicates scored together: every matched entry is read once for all of them.
const LANES: usize = 8;

/// (mAP, NDS, per-class mean AP) and the velocity errors of `LANES` replicates; `w[s][r]` counts
/// sample s in replicate r. Thresholds that only feed AP need only the precision, streamed for
/// all lanes in one pass; the TP threshold needs the full curves, one lane at a time.
fn score_lanes(t: &Tables, cfg: &DetectionConfig, w: &[[u32; LANES]]) -> Vec<(Replicate, VelocityErrors)> {
    let precision: Vec<Option<[[f64; NELEM]; LANES]>> = t
        .by_key
        .iter()
        .map(|(_, th, m)| {
            (*th != cfg.dist_th_tp).then(|| {
                let mut p = [[0.0; NELEM]; LANES];
                m.precision_batch(w, &mut p);
                p
            })
        })
        .collect();
    (0..LANES)
        .map(|r| {
            let lane: Vec<u32> = w.iter().map(|c| c[r]).collect();
            let m = summarize(&t.classes, cfg, |c, th| {
                let k = t.by_key.iter().position(|(kc, kt, _)| kc == c && *kt == th)?;
                Some(match &precision[k] {
                    Some(p) => {
                        let mut md = MetricData::no_predictions();
                        md.precision = p[r].to_vec();
                        md
                    }
                    None => t.by_key[k].2.curves(Some(&lane)),
                })
            });
            let v = VelocityErrors::of(&m);
            ((m.mean_ap, m.nd_score, m.mean_dist_aps), v)
        })
        .collect()
}

/// All replicates, `LANES` at a time in parallel; `sample_scene[s]` is sample s's scene.
fn replicates(
    t: &Tables,
    cfg: &DetectionConfig,
    sample_scene: &[usize],
    n_scenes: usize,
    resamples: usize,
    seed: u64,
) -> Vec<Replicate> {
    let chunks: Vec<Vec<Replicate>> = (0..resamples.div_ceil(LANES))
        .into_par_iter()
        .map(|chunk| {
            let counts: Vec<Vec<u32>> = (0..LANES).map(|r| scene_counts(n_scenes, seed, chunk * LANES + r)).collect();
            let w: Vec<[u32; LANES]> = sample_scene.iter().map(|&s| std::array::from_fn(|r| counts[r][s])).collect();
            score_lanes(t, cfg, &w).into_iter().map(|x| x.0).collect::<Vec<_>>()
        })
        .collect();
    chunks.into_iter().flatten().take(resamples).collect()
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
fn scene_counts(n_scenes: usize, seed: u64, i: usize) -> Vec<u32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let mut count = vec![0; n_scenes];
    for _ in 0..n_scenes {
        count[rng.random_range(0..n_scenes)] += 1;
    }
    count
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
pub fn bootstrap(
    gt: &GroundTruth,
    pred: &[(String, Vec<EvalBox>)],
    cfg: &DetectionConfig,
    resamples: usize,
    level: f64,
    seed: u64,
) -> BootstrapSummary {
    let (gt_f, pred_f) = crate::filtered(gt, pred, cfg);
    let t = tables(&gt_f, &pred_f, cfg);
    let ((map0, nds0, cls0), _) = score(&t, cfg, None);
    let (sample_scene, n_scenes) = scene_index(gt);
    let reps = replicates(&t, cfg, &sample_scene, n_scenes, resamples, seed);
    let class_ap =
        cls0.iter().map(|(c, e)| (c.clone(), interval(*e, reps.iter().map(|r| r.2[c]).collect(), level))).collect();
    BootstrapSummary {
        resamples,
        level,
        scenes: n_scenes,
        estimable: n_scenes >= MIN_SCENES,
        mean_ap: interval(map0, reps.iter().map(|r| r.0).collect(), level),
        nd_score: interval(nds0, reps.iter().map(|r| r.1).collect(), level),
        class_ap,
    }
}

/// The paired bootstrap of B − A on the same ground truth.
pub fn paired(
    gt: &GroundTruth,
    a: &[(String, Vec<EvalBox>)],
    b: &[(String, Vec<EvalBox>)],
    cfg: &DetectionConfig,
    resamples: usize,
    level: f64,
    seed: u64,
) -> PairedSummary {
    paired_between(gt, a, gt, b, cfg, resamples, level, seed)
}

/// The paired bootstrap of B − A where A and B have their own ground truth over the same
/// scenes (e.g. two sensor configurations recording the same traffic: each keeps the boxes its
/// own sensors saw, as the nuScenes loader does). Scenes are matched by `SampleInfo::scene`,
/// which must name the same scene in both; each replicate draws the same scenes for both.
#[allow(clippy::too_many_arguments)]
pub fn paired_between(
    gt_a: &GroundTruth,
    a: &[(String, Vec<EvalBox>)],
    gt_b: &GroundTruth,
    b: &[(String, Vec<EvalBox>)],
    cfg: &DetectionConfig,
    resamples: usize,
    level: f64,
    seed: u64,
) -> PairedSummary {
    let (ga_f, a_f) = crate::filtered(gt_a, a, cfg);
    let (gb_f, b_f) = crate::filtered(gt_b, b, cfg);
    let (ta, tb) = (tables(&ga_f, &a_f, cfg), tables(&gb_f, &b_f, cfg));
    let ((ma, na, ca), _) = score(&ta, cfg, None);
    let ((mb, nb, cb), _) = score(&tb, cfg, None);
    let mut ids: BTreeMap<&str, usize> = BTreeMap::new();
    for info in gt_a.samples.values().chain(gt_b.samples.values()) {
        let n = ids.len();
        ids.entry(info.scene.as_str()).or_insert(n);
    }
    let sa: Vec<usize> = gt_a.samples.values().map(|i| ids[i.scene.as_str()]).collect();
    let sb: Vec<usize> = gt_b.samples.values().map(|i| ids[i.scene.as_str()]).collect();
    let n_scenes = ids.len();
    // Same seed, same draws: replicate i of A and of B see the same scenes.
    let ra = replicates(&ta, cfg, &sa, n_scenes, resamples, seed);
    let rb = replicates(&tb, cfg, &sb, n_scenes, resamples, seed);
    let reps: Vec<Replicate> = ra
        .into_iter()
        .zip(rb)
        .map(|((xa, ya, za), (xb, yb, zb))| {
            (
                xb - xa,
                yb - ya,
                zb.iter().map(|(c, v)| (c.clone(), v - za.get(c).copied().unwrap_or(f64::NAN))).collect(),
            )
        })
        .collect();
    let share = |f: &dyn Fn(&Replicate) -> bool| reps.iter().filter(|r| f(r)).count() as f64 / reps.len().max(1) as f64;
    PairedSummary {
        resamples,
        level,
        scenes: n_scenes,
        estimable: n_scenes >= MIN_SCENES,
        mean_ap_diff: interval(mb - ma, reps.iter().map(|r| r.0).collect(), level),
        nd_score_diff: interval(nb - na, reps.iter().map(|r| r.1).collect(), level),
        class_ap_diff: cb
            .iter()
            .map(|(c, v)| {
                (
                    c.clone(),
                    interval(
                        v - ca.get(c).copied().unwrap_or(f64::NAN),
                        reps.iter().map(|r| r.2.get(c).copied().unwrap_or(f64::NAN)).collect(),
                        level,
                    ),
                )
            })
            .collect(),
        p_mean_ap_not_better: share(&|r| r.0 <= 0.0),
        p_nd_score_not_better: share(&|r| r.1 <= 0.0),
    }
}

/// A submission matched once against its ground truth and scored again under any weighting of
/// its scenes: the building block of comparisons that must draw the same scenes for many
/// submissions (every rig, preset and seed of a study).
#[derive(Debug)]
pub struct Reweighable {
    tables: Tables,
    /// Scene index (into the caller's scene list) of each ground-truth sample, in sample order.
    sample_scene: Vec<usize>,
}

impl std::fmt::Debug for Tables {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Tables({} classes, {} class-threshold tables)", self.classes.len(), self.by_key.len())
    }
}

impl Reweighable {
    /// Matches `pred` against `gt` (after the devkit's filter). `scenes` names the scenes whose
    /// counts [`Reweighable::under`] receives, in that order; every ground-truth sample's scene
    /// must be among them.
    pub fn new(
        gt: &GroundTruth,
        pred: &[(String, Vec<EvalBox>)],
        cfg: &DetectionConfig,
        scenes: &[String],
    ) -> Result<Self, String> {
        let index: BTreeMap<&str, usize> = scenes.iter().enumerate().map(|(i, s)| (s.as_str(), i)).collect();
        let sample_scene = gt
            .samples
            .iter()
            .map(|(k, info)| {
                index
                    .get(info.scene.as_str())
                    .copied()
                    .ok_or_else(|| format!("sample {k}: scene {:?} is not in the scene list", info.scene))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let (gt_f, pred_f) = crate::filtered(gt, pred, cfg);
        Ok(Reweighable { tables: tables(&gt_f, &pred_f, cfg), sample_scene })
    }

    /// (mAP, NDS, per-class AP) on every scene once.
    pub fn full(&self, cfg: &DetectionConfig) -> Replicate {
        self.full_with_velocity(cfg).0
    }

    /// [`Reweighable::full`] and the velocity errors, from the same matches.
    pub fn full_with_velocity(&self, cfg: &DetectionConfig) -> (Replicate, VelocityErrors) {
        score(&self.tables, cfg, None)
    }

    /// (mAP, NDS, per-class AP) under each scene-count vector of `draws` (counts per scene, in
    /// the order given to [`Reweighable::new`]), eight at a time in parallel.
    pub fn under(&self, cfg: &DetectionConfig, draws: &[Vec<u32>]) -> Vec<Replicate> {
        self.under_with_velocity(cfg, draws).into_iter().map(|x| x.0).collect()
    }

    /// [`Reweighable::under`] and each replicate's velocity errors.
    pub fn under_with_velocity(&self, cfg: &DetectionConfig, draws: &[Vec<u32>]) -> Vec<(Replicate, VelocityErrors)> {
        let chunks: Vec<Vec<(Replicate, VelocityErrors)>> = draws
            .par_chunks(LANES)
            .map(|chunk| {
                let w: Vec<[u32; LANES]> = self
                    .sample_scene
                    .iter()
                    .map(|&s| std::array::from_fn(|r| chunk.get(r).map_or(0, |c| c.get(s).copied().unwrap_or(0))))
                    .collect();
                let mut out = score_lanes(&self.tables, cfg, &w);
                out.truncate(chunk.len());
                out
            })
            .collect();
        chunks.into_iter().flatten().collect()
    }
}
