//! The nuScenes detection metric, exactly as nuscenes-devkit 1.2 computes it
//! (`nuscenes/eval/detection/algo.py`, `data_classes.py`, `evaluate.py`): center-distance
//! matching, 101-point interpolated precision, AP above min_recall and min_precision, TP errors
//! averaged over the recall range, mAP and NDS.
//!
//! Where the devkit's numerics decide a result, hilo reproduces them rather than improving them:
//! predictions are ordered by (score, index) descending, so among equal scores the later box
//! comes first; `np.interp`'s handling of repeated recall values is reproduced by
//! [`np_interp`]; a class without ground truth gets AP 0 and TP errors 1 (the devkit's
//! "no predictions"), and an error that is NaN for every class gives that TP score 0 in NDS.

use crate::boxes::EvalBox;
use crate::config::DetectionConfig;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Number of recall points.
pub const NELEM: usize = 101;
/// The TP metrics in the devkit's order.
pub const TP_METRICS: [&str; 5] = ["trans_err", "scale_err", "orient_err", "vel_err", "attr_err"];

/// `numpy.linspace(0, 1, NELEM)` bit for bit: `i * step` with `step = 1 / (NELEM - 1)` and the
/// end point set to 1 (so point 70 is 0.7000000000000001, not 0.7: that decides whether a curve
/// whose maximum recall is exactly 0.7 reaches it).
pub fn recall_points() -> Vec<f64> {
    let step = 1.0 / (NELEM - 1) as f64;
    let mut r: Vec<f64> = (0..NELEM).map(|i| i as f64 * step).collect();
    r[NELEM - 1] = 1.0;
    r
}

/// `numpy.interp(x, xp, fp, left, right)` for non-decreasing `xp`, including numpy's choice of
/// the last of several equal `xp` values and its exact-hit shortcut.
pub fn np_interp(x: &[f64], xp: &[f64], fp: &[f64], left: Option<f64>, right: Option<f64>) -> Vec<f64> {
    let n = xp.len();
    let lval = left.unwrap_or(fp[0]);
    let rval = right.unwrap_or(fp[n - 1]);
    x.iter()
        .map(|&v| {
            if v.is_nan() {
                return v;
            }
            if v > xp[n - 1] {
                return rval;
            }
            if v < xp[0] {
                return lval;
            }
            // Last j with xp[j] <= v.
            let j = xp.partition_point(|&q| q <= v) - 1;
            if j == n - 1 || xp[j] == v {
                return fp[j];
            }
            let slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]);
            let mut r = slope * (v - xp[j]) + fp[j];
            if r.is_nan() {
                r = slope * (v - xp[j + 1]) + fp[j + 1];
                if r.is_nan() && fp[j] == fp[j + 1] {
                    r = fp[j];
                }
            }
            r
        })
        .collect()
}

/// The devkit's NaN-aware cumulative mean (all NaN → ones).
pub fn cummean(x: &[f64]) -> Vec<f64> {
    if x.iter().all(|v| v.is_nan()) {
        return vec![1.0; x.len()];
    }
    let (mut s, mut c) = (0.0, 0usize);
    x.iter()
        .map(|&v| {
            if !v.is_nan() {
                s += v;
                c += 1;
            }
            if c == 0 { 0.0 } else { s / c as f64 }
        })
        .collect()
}

/// Per class and threshold: precision, confidence and TP errors on the 101 recall points.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MetricData {
    pub recall: Vec<f64>,
    pub precision: Vec<f64>,
    pub confidence: Vec<f64>,
    pub trans_err: Vec<f64>,
    pub vel_err: Vec<f64>,
    pub scale_err: Vec<f64>,
    pub orient_err: Vec<f64>,
    pub attr_err: Vec<f64>,
}

impl MetricData {
    pub fn no_predictions() -> Self {
        MetricData {
            recall: recall_points(),
            precision: vec![0.0; NELEM],
            confidence: vec![0.0; NELEM],
            trans_err: vec![1.0; NELEM],
            vel_err: vec![1.0; NELEM],
            scale_err: vec![1.0; NELEM],
            orient_err: vec![1.0; NELEM],
            attr_err: vec![1.0; NELEM],
        }
    }

    /// Index of the last non-zero confidence (0 when there is none).
    pub fn max_recall_ind(&self) -> usize {
        self.confidence.iter().rposition(|&c| c != 0.0).unwrap_or(0)
    }

    fn get(&self, metric: &str) -> &[f64] {
        match metric {
            "trans_err" => &self.trans_err,
            "vel_err" => &self.vel_err,
            "scale_err" => &self.scale_err,
            "orient_err" => &self.orient_err,
            _ => &self.attr_err,
        }
    }
}

/// Signed smallest difference from y to x for the given period, as the devkit computes it.
pub fn angle_diff(x: f64, y: f64, period: f64) -> f64 {
    let mut d = (x - y + period / 2.0).rem_euclid(period) - period / 2.0;
    if d > std::f64::consts::PI {
        d -= 2.0 * std::f64::consts::PI;
    }
    d
}

fn center_distance(a: &EvalBox, b: &EvalBox) -> f64 {
    ((a.translation[0] - b.translation[0]).powi(2) + (a.translation[1] - b.translation[1]).powi(2)).sqrt()
}

fn scale_iou(a: &EvalBox, b: &EvalBox) -> f64 {
    let inter: f64 = (0..3).map(|k| a.size[k].min(b.size[k])).product();
    let va: f64 = a.size.iter().product();
    let vb: f64 = b.size.iter().product();
    inter / (va + vb - inter)
}

/// One class's boxes prepared once for all thresholds: ground truth per sample (this class
/// only) and the predictions in the devkit's order.
#[derive(Debug)]
pub struct ClassData<'a> {
    gt: Vec<Vec<&'a EvalBox>>,
    /// (sample index or None when the sample has no ground truth, box), in matching order.
    pred: Vec<(Option<usize>, &'a EvalBox)>,
}

impl<'a> ClassData<'a> {
    pub fn new(gt: &'a BTreeMap<String, Vec<EvalBox>>, pred: &'a [(String, Vec<EvalBox>)], class: &str) -> Self {
        let index: std::collections::HashMap<&str, usize> =
            gt.keys().enumerate().map(|(i, k)| (k.as_str(), i)).collect();
        let gtc: Vec<Vec<&EvalBox>> =
            gt.values().map(|v| v.iter().filter(|b| b.detection_name == class).collect()).collect();
        let list: Vec<&EvalBox> =
            pred.iter().flat_map(|(_, v)| v.iter()).filter(|b| b.detection_name == class).collect();
        let mut order: Vec<usize> = (0..list.len()).collect();
        // sorted((score, index)) reversed: score descending, then index descending.
        order.sort_by(|&a, &b| list[b].detection_score.total_cmp(&list[a].detection_score).then(b.cmp(&a)));
        let pred = order.into_iter().map(|i| (index.get(list[i].sample_token.as_str()).copied(), list[i])).collect();
        ClassData { gt: gtc, pred }
    }

    /// The devkit's `accumulate` at one distance threshold.
    pub fn accumulate(&self, class: &str, dist_th: f64) -> MetricData {
        self.matches(class, dist_th).curves(None)
    }

    /// Matches every prediction (in the devkit's order) at one distance threshold. Matching is
    /// decided within each sample, so the table can be reweighted by sample (the bootstrap)
    /// without matching again.
    pub fn matches(&self, class: &str, dist_th: f64) -> Matches {
        let mut entries = Vec::with_capacity(self.pred.len());
        let mut taken: Vec<Vec<bool>> = self.gt.iter().map(|v| vec![false; v.len()]).collect();
        let period = if class == "barrier" { std::f64::consts::PI } else { 2.0 * std::f64::consts::PI };
        for &(si, p) in &self.pred {
            let mut min_dist = f64::INFINITY;
            let mut best = None;
            if let Some(si) = si {
                for (gi, g) in self.gt[si].iter().enumerate() {
                    if !taken[si][gi] {
                        let d = center_distance(g, p);
                        if d < min_dist {
                            min_dist = d;
                            best = Some(gi);
                        }
                    }
                }
            }
            let errors = match (si, best.filter(|_| min_dist < dist_th)) {
                (Some(si), Some(gi)) => {
                    taken[si][gi] = true;
                    let g = self.gt[si][gi];
                    let v = ((p.velocity[0] - g.velocity[0]).powi(2) + (p.velocity[1] - g.velocity[1]).powi(2)).sqrt();
                    let attr = if g.attribute_name.is_empty() {
                        f64::NAN
                    } else {
                        (g.attribute_name == p.attribute_name) as u8 as f64
                    };
                    Some([
                        center_distance(g, p),
                        v,
                        1.0 - scale_iou(g, p),
                        angle_diff(g.yaw(), p.yaw(), period).abs(),
                        1.0 - attr,
                    ])
                }
                _ => None,
            };
            entries.push(MatchEntry { score: p.detection_score, sample: si, errors });
        }
        let packed = entries
            .iter()
            .map(|e| e.sample.map_or(NO_SAMPLE, |s| s as u32) | if e.errors.is_some() { TP_BIT } else { 0 })
            .collect();
        let scores = entries.iter().map(|e| e.score).collect();
        let tp_errors = entries.iter().filter_map(|e| e.errors).collect();
        Matches { entries, npos_per_sample: self.gt.iter().map(Vec::len).collect(), packed, scores, tp_errors }
    }
}

/// One prediction's outcome: its score, its sample (None when the sample has no ground truth)
/// and, for a true positive, its errors (trans, vel, scale, orient, attr).
#[derive(Clone, Debug, PartialEq)]
pub struct MatchEntry {
    pub score: f64,
    pub sample: Option<usize>,
    pub errors: Option<[f64; 5]>,
}

/// All predictions of one class at one threshold, matched, in the devkit's order.
#[derive(Clone, Debug, PartialEq)]
pub struct Matches {
    pub entries: Vec<MatchEntry>,
    /// Ground-truth boxes of the class per sample.
    pub npos_per_sample: Vec<usize>,
    /// The same entries packed for replicates: sample index (or [`NO_SAMPLE`]) | [`TP_BIT`].
    pub packed: Vec<u32>,
    /// Scores of the entries, in order.
    pub scores: Vec<f64>,
    /// Errors of the true positives, in order.
    pub tp_errors: Vec<[f64; 5]>,
}

/// Packed entry flag: a true positive.
pub const TP_BIT: u32 = 1 << 31;
/// Packed sample index of a prediction whose sample has no ground truth.
pub const NO_SAMPLE: u32 = TP_BIT - 1;

impl Matches {
    /// The devkit's curves, with every prediction and ground-truth box of sample s counted
    /// `weights[s]` times (all 1 when `None`: then this is `accumulate` exactly). A sample counted
    /// k times adds its predictions as one step of weight k.
    pub fn curves(&self, weights: Option<&[u32]>) -> MetricData {
        let npos: f64 = match weights {
            Some(ws) => self.npos_per_sample.iter().zip(ws).map(|(n, w)| (*n as u64 * u64::from(*w)) as f64).sum(),
            None => self.npos_per_sample.iter().sum::<usize>() as f64,
        };
        if npos == 0.0 {
            return MetricData::no_predictions();
        }
        let n = self.packed.len();
        let nt = self.tp_errors.len();
        // Branch-free compaction: every entry is written at the current end, which only advances
        // for entries of drawn scenes (k > 0).
        let (mut prec, mut rec, mut conf) = (vec![0.0; n + 1], vec![0.0; n + 1], vec![0.0; n + 1]);
        let mut m_conf = vec![0.0; nt + 1];
        let mut m_w = vec![0.0; nt + 1];
        let mut errs: [Vec<f64>; 5] = std::array::from_fn(|_| vec![0.0; nt + 1]);
        let (mut ctp, mut cfp) = (0.0, 0.0);
        let (mut len, mut mlen, mut tp_index) = (0usize, 0usize, 0usize);
        for (&e, &score) in self.packed.iter().zip(&self.scores) {
            let s = e & !TP_BIT;
            let is_tp = e & TP_BIT != 0;
            let k = match weights {
                Some(ws) if s != NO_SAMPLE => f64::from(ws[s as usize]),
                _ => 1.0,
            };
            let live = k > 0.0;
            let kt = if is_tp { k } else { 0.0 };
            ctp += kt;
            cfp += k - kt;
            prec[len] = ctp / (cfp + ctp);
            rec[len] = ctp / npos;
            conf[len] = score;
            len += live as usize;
            if is_tp {
                let er = self.tp_errors[tp_index];
                for (v, x) in errs.iter_mut().zip(er) {
                    v[mlen] = x;
                }
                m_conf[mlen] = score;
                m_w[mlen] = k;
                mlen += live as usize;
                tp_index += 1;
            }
        }
        prec.truncate(len);
        rec.truncate(len);
        conf.truncate(len);
        m_conf.truncate(mlen);
        m_w.truncate(mlen);
        for v in &mut errs {
            v.truncate(mlen);
        }
        if m_conf.is_empty() {
            return MetricData::no_predictions();
        }
        let rec_interp = recall_points();
        let precision = np_interp(&rec_interp, &rec, &prec, None, Some(0.0));
        let confidence = np_interp(&rec_interp, &rec, &conf, None, Some(0.0));
        let conf_rev: Vec<f64> = confidence.iter().rev().copied().collect();
        let mconf_rev: Vec<f64> = m_conf.iter().rev().copied().collect();
        let resample = |errors: &[f64]| {
            let tmp = weighted_cummean(errors, &m_w);
            let tmp_rev: Vec<f64> = tmp.iter().rev().copied().collect();
            let mut r = np_interp(&conf_rev, &mconf_rev, &tmp_rev, None, None);
            r.reverse();
            r
        };
        MetricData {
            recall: rec_interp,
            precision,
            trans_err: resample(&errs[0]),
            vel_err: resample(&errs[1]),
            scale_err: resample(&errs[2]),
            orient_err: resample(&errs[3]),
            attr_err: resample(&errs[4]),
            confidence,
        }
    }
}

impl Matches {
    /// Only the interpolated precision (what AP needs), in one pass without allocation:
    /// `np.interp(recall_points, rec, prec, right=0)` evaluated as `rec` streams by, with the same
    /// choices as [`np_interp`] (the last of equal recalls; exact hits; linear in between).
    ///
    /// Counts are integers, so the running sums are integers: the loop carries two integer adds
    /// (one cycle each) instead of two dependent float adds, and a recall point is crossed exactly
    /// when the true-positive sum reaches a precomputed integer threshold, the only place where
    /// anything is divided.
    pub fn precision_only(&self, counts: Option<&[u32]>, out: &mut [f64; NELEM]) {
        let mut o = [[0.0; NELEM]; 1];
        match counts {
            None => self.stream_precision(|_| [1], &mut o),
            Some(c) => self.stream_precision(|s| [c.get(s as usize).copied().unwrap_or(1)], &mut o),
        }
        *out = o[0];
    }

    /// [`Matches::precision_only`] for `R` replicates in one pass: `counts[s][r]` is how often
    /// sample s is drawn in replicate r. Each entry is read once for all of them and the `R`
    /// running sums are independent, so the pass costs little more than one.
    pub fn precision_batch<const R: usize>(&self, counts: &[[u32; R]], out: &mut [[f64; NELEM]; R]) {
        self.stream_precision(|s| counts.get(s as usize).copied().unwrap_or([1; R]), out);
    }

    fn stream_precision<const R: usize>(&self, count: impl Fn(u32) -> [u32; R], out: &mut [[f64; NELEM]; R]) {
        for o in out.iter_mut() {
            o.fill(0.0);
        }
        let mut npos_i = [0u64; R];
        for (s, &n) in self.npos_per_sample.iter().enumerate() {
            for (a, k) in npos_i.iter_mut().zip(count(s as u32)) {
                *a += n as u64 * u64::from(k);
            }
        }
        let npos = npos_i.map(|n| n as f64);
        let step = 1.0 / (NELEM - 1) as f64;
        let x = |i: usize| if i == NELEM - 1 { 1.0 } else { i as f64 * step };
        // The smallest true-positive sum t with x(i) < t / npos (division is monotone in t, so
        // the search from floor(x · npos) moves a step or two); never reached when done.
        let threshold = |i: usize, npos: f64| -> u64 {
            if i >= NELEM || npos == 0.0 {
                return u64::MAX;
            }
            let xi = x(i);
            let mut t = (xi * npos).floor().max(0.0) as u64;
            while t > 0 && xi < (t - 1) as f64 / npos {
                t -= 1;
            }
            while xi >= t as f64 / npos {
                t += 1;
            }
            t
        };
        let (mut ctp, mut cfp) = ([0u64; R], [0u64; R]);
        let mut i = [0usize; R];
        let mut next: [u64; R] = std::array::from_fn(|r| threshold(0, npos[r]));
        for &e in &self.packed {
            let k = count(e & !TP_BIT).map(u64::from);
            let tp_mask = if e & TP_BIT != 0 { u64::MAX } else { 0 };
            let mut crossed = false;
            for r in 0..R {
                let kt = k[r] & tp_mask;
                ctp[r] += kt;
                cfp[r] += k[r] - kt;
                crossed |= ctp[r] >= next[r];
            }
            if !crossed {
                continue;
            }
            // A recall point is crossed: only by a drawn true positive (the sum grew past it).
            for r in 0..R {
                if ctp[r] < next[r] {
                    continue;
                }
                let kt = k[r] & tp_mask;
                // The sums at the previous drawn entry (entries of scenes not drawn add nothing).
                let (t0, f0) = (ctp[r] - kt, cfp[r] - (k[r] - kt));
                let (r1, p1) = (ctp[r] as f64 / npos[r], ctp[r] as f64 / (cfp[r] + ctp[r]) as f64);
                let o = &mut out[r];
                let mut j = i[r];
                while j < NELEM && x(j) < r1 {
                    o[j] = if t0 + f0 == 0 {
                        p1 // below the first recall: numpy's left value, fp[0]
                    } else {
                        let (r0, p0) = (t0 as f64 / npos[r], t0 as f64 / (f0 + t0) as f64);
                        if r0 == x(j) {
                            p0
                        } else {
                            let slope = (p1 - p0) / (r1 - r0);
                            let v = slope * (x(j) - r0) + p0;
                            if v.is_nan() { slope * (x(j) - r1) + p1 } else { v }
                        }
                    };
                    j += 1;
                }
                i[r] = j;
                next[r] = threshold(j, npos[r]);
            }
        }
        // The rest: equal to the last recall gives its precision, above it numpy's right value 0.
        // (No drawn true positive: all zero, as `curves` gives for no predictions.)
        for r in 0..R {
            if npos_i[r] == 0 || ctp[r] == 0 {
                continue;
            }
            let (r1, p1) = (ctp[r] as f64 / npos[r], ctp[r] as f64 / (cfp[r] + ctp[r]) as f64);
            let mut j = i[r];
            while j < NELEM && x(j) <= r1 {
                out[r][j] = p1;
                j += 1;
            }
        }
    }
}

/// [`cummean`] with weights (all weights 1 gives the same numbers).
fn weighted_cummean(x: &[f64], w: &[f64]) -> Vec<f64> {
    if x.iter().all(|v| v.is_nan()) {
        return vec![1.0; x.len()];
    }
    let (mut s, mut c) = (0.0, 0.0);
    x.iter()
        .zip(w)
        .map(|(&v, &k)| {
            if !v.is_nan() {
                s += k * v;
                c += k;
            }
            if c == 0.0 { 0.0 } else { s / c }
        })
        .collect()
}

/// Matches predictions of one class to ground truth at one distance threshold and builds the
/// interpolated curves (the devkit's `accumulate`). Boxes are grouped by sample in `gt`/`pred`.
pub fn accumulate(
    gt: &BTreeMap<String, Vec<EvalBox>>,
    pred: &[(String, Vec<EvalBox>)],
    class: &str,
    dist_th: f64,
) -> MetricData {
    ClassData::new(gt, pred, class).accumulate(class, dist_th)
}

/// The devkit's `calc_ap`.
pub fn calc_ap(md: &MetricData, min_recall: f64, min_precision: f64) -> f64 {
    let start = (100.0 * min_recall).round() as usize + 1;
    let p = &md.precision[start.min(NELEM)..];
    let mean = p.iter().map(|v| (v - min_precision).max(0.0)).sum::<f64>() / p.len().max(1) as f64;
    mean / (1.0 - min_precision)
}

/// The devkit's `calc_tp`.
pub fn calc_tp(md: &MetricData, min_recall: f64, metric: &str) -> f64 {
    let first = (100.0 * min_recall).round() as usize + 1;
    let last = md.max_recall_ind();
    if last < first {
        return 1.0;
    }
    let v = &md.get(metric)[first..=last];
    v.iter().sum::<f64>() / v.len() as f64
}

/// The summary the devkit writes as `metrics_summary.json` (same keys).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DetectionMetrics {
    pub label_aps: BTreeMap<String, BTreeMap<String, f64>>,
    pub mean_dist_aps: BTreeMap<String, f64>,
    pub mean_ap: f64,
    pub label_tp_errors: BTreeMap<String, BTreeMap<String, f64>>,
    pub tp_errors: BTreeMap<String, f64>,
    pub tp_scores: BTreeMap<String, f64>,
    pub nd_score: f64,
    pub eval_time: f64,
    pub cfg: DetectionConfig,
}

/// Formats a threshold as Python prints a float key (`0.5`, `1.0`).
pub fn th_key(t: f64) -> String {
    if t.fract() == 0.0 { format!("{t:.1}") } else { format!("{t}") }
}

/// Evaluates already filtered boxes (see [`crate::boxes::filter_boxes`]).
pub fn evaluate(
    gt: &BTreeMap<String, Vec<EvalBox>>,
    pred: &[(String, Vec<EvalBox>)],
    cfg: &DetectionConfig,
) -> DetectionMetrics {
    use rayon::prelude::*;
    let start = std::time::Instant::now();
    let classes = cfg.class_names();
    let data: Vec<(String, f64, MetricData)> = classes
        .par_iter()
        .flat_map_iter(|c| {
            let cd = ClassData::new(gt, pred, c);
            let mut ths = cfg.dist_ths.clone();
            if !ths.contains(&cfg.dist_th_tp) {
                ths.push(cfg.dist_th_tp);
            }
            ths.into_iter().map(|t| (c.clone(), t, cd.accumulate(c, t))).collect::<Vec<_>>()
        })
        .collect();
    let mut m =
        summarize(&classes, cfg, |c, t| data.iter().find(|(dc, dt, _)| dc == c && *dt == t).map(|x| x.2.clone()));
    m.eval_time = start.elapsed().as_secs_f64();
    m
}

/// AP per class and threshold, TP errors per class, mAP, TP scores and NDS from the metric data
/// (`md(class, threshold)`), as the devkit's `DetectionEval.evaluate` assembles them.
pub fn summarize(
    classes: &[String],
    cfg: &DetectionConfig,
    md: impl Fn(&str, f64) -> Option<MetricData>,
) -> DetectionMetrics {
    let find = |c: &str, t: f64| md(c, t);
    let mut label_aps: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    let mut label_tp_errors: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    for c in classes {
        let mut aps = BTreeMap::new();
        for &t in &cfg.dist_ths {
            let md = find(c, t).unwrap_or_else(MetricData::no_predictions);
            aps.insert(th_key(t), calc_ap(&md, cfg.min_recall, cfg.min_precision));
        }
        label_aps.insert(c.clone(), aps);
        let md = find(c, cfg.dist_th_tp).unwrap_or_else(MetricData::no_predictions);
        let mut errs = BTreeMap::new();
        for metric in TP_METRICS {
            // The devkit's exemptions for its cone and barrier classes (unused by hilo's classes,
            // kept so a user's config with them evaluates as the devkit does).
            let exempt = (c.as_str() == "traffic_cone" && ["attr_err", "vel_err", "orient_err"].contains(&metric))
                || (c.as_str() == "barrier" && ["attr_err", "vel_err"].contains(&metric));
            let tp = if exempt { f64::NAN } else { calc_tp(&md, cfg.min_recall, metric) };
            errs.insert(metric.to_owned(), tp);
        }
        label_tp_errors.insert(c.clone(), errs);
    }
    let mean_dist_aps: BTreeMap<String, f64> =
        label_aps.iter().map(|(c, d)| (c.clone(), d.values().sum::<f64>() / d.len().max(1) as f64)).collect();
    let mean_ap = mean_dist_aps.values().sum::<f64>() / mean_dist_aps.len().max(1) as f64;
    let mut tp_errors = BTreeMap::new();
    let mut tp_scores = BTreeMap::new();
    for metric in TP_METRICS {
        let vals: Vec<f64> = classes.iter().map(|c| label_tp_errors[c][metric]).filter(|v: &f64| !v.is_nan()).collect();
        let e = if vals.is_empty() { f64::NAN } else { vals.iter().sum::<f64>() / vals.len() as f64 };
        tp_errors.insert(metric.to_owned(), e);
        // Python's max(0.0, nan) is 0.0.
        let s = 1.0 - e;
        tp_scores.insert(metric.to_owned(), if s > 0.0 { s } else { 0.0 });
    }
    let nd_score = (cfg.mean_ap_weight * mean_ap + tp_scores.values().sum::<f64>())
        / (cfg.mean_ap_weight + tp_scores.len() as f64);
    DetectionMetrics {
        label_aps,
        mean_dist_aps,
        mean_ap,
        label_tp_errors,
        tp_errors,
        tp_scores,
        nd_score,
        eval_time: 0.0,
        cfg: cfg.clone(),
    }
}
