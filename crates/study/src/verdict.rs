//! From every trained detector's scores to the study's verdict: comparisons between rigs, the
//! paper's claims answered one by one, the test's calibration, and the learning curves.

use crate::stats::{
    PaperRelation, Scores, SeedVariance, Test, compare, held_out_aa, holm, mde, paper_relation, pooled_seed_variance,
    test, tost_p,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The metrics a verdict compares.
pub const METRICS: [&str; 2] = ["mAP", "pedestrian AP"];

/// The name of a metric of [`METRICS`] scored under the nuScenes convention (boxes with at least
/// one point of the rig), beside the common ground truth.
pub fn visible_only(metric: &str) -> String {
    format!("{metric}, visible-only")
}

/// The velocity errors the velocity claims compare (m/s, lower is better): the devkit's mAVE
/// (over the classes present) and the car AVE (the moving class the radar's Doppler serves
/// most).
pub const VELOCITY_METRICS: [&str; 2] = ["mAVE", "car AVE"];

/// The claims judged again in each weather condition: what the radar adds, in accuracy and in
/// velocity, to the rig under study and to the cheapest LiDAR-only rig.
pub const CONDITION_CLAIMS: [&str; 4] =
    ["radar_adds", "radar_adds_velocity", "fusion_vs_lidar_only", "fusion_lowers_velocity_error"];

/// What the radar adds on one metric in one weather: a row of the `radar_adds` (accuracy) or
/// `radar_adds_velocity` (velocity error) claim, priced by what the rig with the radar costs
/// over the LiDAR-only rig it is compared with.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RadarValue {
    /// The weather condition; None: the study's own weather.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub condition: Option<String>,
    /// A second radar's value (the `second_radar_adds` and `second_radar_velocity` claims): the
    /// rig placed given the rig under study with more radars, against it. False: the radar's.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub second: bool,
    pub metric: String,
    /// The rig with the radar, fused, minus the LiDAR-only rig (for a second radar: minus the
    /// rig under study), and its 95% interval.
    pub estimate: f64,
    pub lo: f64,
    pub hi: f64,
    /// What the rig with the radar costs over the LiDAR-only one (for a second radar: over the
    /// rig under study), USD.
    pub extra_cost_usd: f64,
    /// `estimate` per $1,000 of `extra_cost_usd` (None when it costs nothing more).
    pub per_1000_usd: Option<f64>,
    pub verdict: Verdict,
    /// The smallest true difference this design finds with 80% power.
    #[serde(default = "nan")]
    pub mde: f64,
    /// For an accuracy metric: the cheapest design projected to find [`RADAR_TARGET_MDE`]
    /// ([`crate::stats::design_for_mde`]); None for a velocity error, or out of reach.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub design: Option<crate::stats::PowerDesign>,
}

/// The verdict's significance level.
pub const ALPHA: f64 = 0.05;

/// The radar effect on an accuracy metric (mAP, AP) a study should be able to find: half the
/// paper's +3.1 points of fusion gain.
pub const RADAR_TARGET_MDE: f64 = 0.015;

/// The radar's value in every weather the claims were judged in: each tested row of
/// `radar_adds` and `radar_adds_velocity` (and of their `@<condition>` copies), then of
/// `second_radar_adds` and `second_radar_velocity` (what a second radar adds), priced by `cost`
/// (a configuration's cost by name), with the design that would find [`RADAR_TARGET_MDE`] from
/// `replicates` per group (seeds, or training-traffic draws when there are several).
pub fn radar_value(claims: &[Claim], cost: &dyn Fn(&str) -> Option<f64>, replicates: usize) -> Vec<RadarValue> {
    let side = |v: &[(String, String)]| v.first().and_then(|(c, _)| cost(c));
    let mut out = Vec::new();
    for (second, priced) in [(false, ["radar_adds", "radar_adds_velocity"]), (true, SECOND_RADAR_CLAIMS)] {
        out.extend(claims.iter().filter(|c| c.not_tested.is_none()).flat_map(|c| {
            let id = c.id.split('@').next().unwrap_or_default();
            let rows = if priced.contains(&id) { &c.rows[..] } else { &[] };
            rows.iter().filter_map(move |row| {
                let extra = side(&row.b).zip(side(&row.a)).map(|(b, a)| b - a)?;
                Some(priced_row(c, row, second, extra, replicates))
            })
        }));
    }
    out
}

/// The claims of what a second radar adds, in accuracy and in velocity error.
pub const SECOND_RADAR_CLAIMS: [&str; 2] = ["second_radar_adds", "second_radar_velocity"];

/// One claim row of the radar's (or a second radar's) effect, priced by `extra` USD.
fn priced_row(c: &Claim, row: &ClaimRow, second: bool, extra: f64, replicates: usize) -> RadarValue {
    RadarValue {
        condition: c.condition.clone(),
        second,
        metric: row.metric.clone(),
        estimate: row.test.estimate,
        lo: row.test.lo,
        hi: row.test.hi,
        extra_cost_usd: extra,
        per_1000_usd: (extra > 0.0).then(|| 1000.0 * row.test.estimate / extra),
        verdict: row.verdict,
        mde: row.mde,
        design: (!lower_is_better(&row.metric))
            .then(|| crate::stats::design_for_mde(&row.test, replicates, RADAR_TARGET_MDE, ALPHA, 0.8))
            .flatten(),
    }
}

/// Whether a metric is an error, where a smaller value is the better one.
pub fn lower_is_better(metric: &str) -> bool {
    VELOCITY_METRICS.contains(&metric)
}

/// The equivalence margins of the claims' TOST, by kind of metric.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Margins {
    /// AP and mAP, as a fraction (0.02 = 2 points).
    pub ap: f64,
    /// Velocity errors, m/s.
    pub velocity_m_s: f64,
}

impl Margins {
    pub fn of(&self, metric: &str) -> f64 {
        if lower_is_better(metric) { self.velocity_m_s } else { self.ap }
    }
}

/// One trained detector's scores on the common ground truth, per metric.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DetectorScores {
    pub configuration: String,
    pub preset: String,
    pub seed: u64,
    /// The training-traffic draw it was trained on (0: the study's own traffic).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub draw: u64,
    /// By metric name ([`METRICS`]).
    pub scores: BTreeMap<String, Scores>,
}

/// A field left out of report.json at its default 0.
pub(crate) fn is_zero(v: &u64) -> bool {
    *v == 0
}

/// The replicates the verdict compares. With one training-traffic draw, each detector (seed) is
/// one. With several, the draw is a random effect: each (configuration, preset, draw) becomes
/// one replicate, the mean of its seeds' scores (the full score and every bootstrap replicate,
/// which share their scene draws), numbered by its draw. Its variance between draws then holds
/// both the traffic's part and the seeds' (divided by the seeds per draw), which is the
/// variance of a group's mean over draws; the tests read it as they read the seed variance.
/// Groups missing a metric on some seed of a draw leave that draw's metric out.
pub fn draw_units(scores: &[DetectorScores]) -> Vec<DetectorScores> {
    if scores.iter().all(|d| d.draw == 0) {
        return scores.to_vec();
    }
    let mut by: BTreeMap<(&str, &str, u64), Vec<&DetectorScores>> = BTreeMap::new();
    for d in scores {
        by.entry((&d.configuration, &d.preset, d.draw)).or_default().push(d);
    }
    by.into_iter()
        .map(|((conf, preset, draw), ds)| {
            let metrics: std::collections::BTreeSet<&String> = ds.iter().flat_map(|d| d.scores.keys()).collect();
            let scores = metrics
                .into_iter()
                .filter_map(|m| {
                    let all: Vec<&Scores> = ds.iter().map(|d| d.scores.get(m)).collect::<Option<_>>()?;
                    let n = all.len() as f64;
                    let reps = all.iter().map(|s| s.replicates.len()).min().unwrap_or(0);
                    Some((
                        m.clone(),
                        Scores {
                            full: all.iter().map(|s| s.full).sum::<f64>() / n,
                            replicates: (0..reps)
                                .map(|r| all.iter().map(|s| s.replicates[r]).sum::<f64>() / n)
                                .collect(),
                        },
                    ))
                })
                .collect();
            DetectorScores { configuration: conf.to_owned(), preset: preset.to_owned(), seed: draw, draw, scores }
        })
        .collect()
}

/// How a metric's variance between detectors of one group splits when the study trains on
/// several training-traffic draws (one-way random effects, per group, pooled).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DrawVariance {
    /// Draws per group.
    pub draws: usize,
    /// Seeds per draw.
    pub seeds: usize,
    /// Between seeds of one draw (pooled; degrees of freedom Σ draws × (seeds − 1)).
    pub seed: SeedVariance,
    /// Between draws of one group, each the mean of its seeds (pooled; Σ (draws − 1)).
    pub draw_means: SeedVariance,
    /// The traffic's own component, σ²_draw = Var(draw means) − σ²_seed / seeds (method of
    /// moments, not below 0): how much one draw of training traffic moves a detector's score
    /// beyond the spread of its seeds.
    pub traffic: f64,
}

/// [`DrawVariance`] of `metric`, when the scores hold two or more draws.
pub fn draw_variance(scores: &[DetectorScores], metric: &str) -> Option<DrawVariance> {
    let draws = scores.iter().map(|d| d.draw).collect::<std::collections::BTreeSet<_>>().len();
    if draws < 2 {
        return None;
    }
    let mut by_draw: BTreeMap<(&str, &str, u64), Vec<&Scores>> = BTreeMap::new();
    for d in scores {
        if let Some(s) = d.scores.get(metric) {
            by_draw.entry((&d.configuration, &d.preset, d.draw)).or_default().push(s);
        }
    }
    let seeds = by_draw.values().map(Vec::len).max().unwrap_or(0);
    let seed = pooled_seed_variance(&by_draw.into_values().collect::<Vec<_>>());
    let units = draw_units(scores);
    let mut by_group: BTreeMap<(&str, &str), Vec<&Scores>> = BTreeMap::new();
    for d in &units {
        if let Some(s) = d.scores.get(metric) {
            by_group.entry((&d.configuration, &d.preset)).or_default().push(s);
        }
    }
    let draw_means = pooled_seed_variance(&by_group.into_values().collect::<Vec<_>>());
    let per_seed = if seed.df > 0 { seed.variance / seeds.max(1) as f64 } else { 0.0 };
    Some(DrawVariance { draws, seeds, seed, draw_means, traffic: (draw_means.variance - per_seed).max(0.0) })
}

/// One comparison of the report: B − A on a metric.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Comparison {
    pub metric: String,
    /// Who is compared: e.g. "lirafusion-like on 2x lidar-16 + radar".
    pub a: String,
    pub b: String,
    pub test: Test,
}

/// One row of a claim.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClaimRow {
    pub metric: String,
    /// What is compared, B − A.
    pub comparison: String,
    /// The paper's number (points of AP as a fraction: 0.015 = 1.5 points), if it gives one.
    pub paper: Option<f64>,
    pub test: Test,
    pub verdict: Verdict,
    /// The detector groups (configuration, preset) of each side, A and B.
    #[serde(default)]
    pub a: Vec<(String, String)>,
    #[serde(default)]
    pub b: Vec<(String, String)>,
    /// Where the interval lies against the paper's number.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub paper_relation: Option<PaperRelation>,
    /// TOST p-value of |B − A| < the study's equivalence margin.
    #[serde(default = "nan")]
    pub tost_p: f64,
    /// The smallest true difference this design finds with 80% power at α = 0.05.
    #[serde(default = "nan")]
    pub mde: f64,
    /// For a claim's other readings ([`Claim::readings`]): which one (visible-only ground
    /// truth, the paper's averaging); None on the claim's own rows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reading: Option<String>,
}

fn nan() -> f64 {
    f64::NAN
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Significant (Holm-adjusted p < 0.05) in the paper's direction.
    Supported,
    /// Significant against it.
    Contradicted,
    /// Not significant, and shown to lie within the equivalence margin (TOST p < 0.05): no
    /// difference that matters.
    Equivalent,
    /// Not significant and not shown equivalent: the design cannot tell.
    Undecided,
    /// The sign of the difference changed over the last doubling of training: the answer is
    /// about the training budget, not the rigs or detectors.
    BudgetBound,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Claim {
    pub id: String,
    pub statement: String,
    pub rows: Vec<ClaimRow>,
    pub verdict: Verdict,
    /// Why it could not be tested, when it could not (a configuration or preset missing).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_tested: Option<String>,
    /// Per preset, the sign of its own difference (the "whichever module" claim).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub per_preset: BTreeMap<String, f64>,
    /// Of its first row: where the interval lies against the paper's number, and the minimum
    /// detectable effect at 80% power.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub paper_relation: Option<PaperRelation>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mde: Option<f64>,
    /// The weather condition it is judged in (`[[conditions]]`); None: the study's own weather.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub condition: Option<String>,
    /// The same question read other ways, each row labelled: under the nuScenes convention
    /// (visible-only ground truth), and for the fusion claims the paper's averaging (the mean
    /// of the fusion presets against the LiDAR-only baseline). A family of their own for Holm;
    /// they do not decide the claim's verdict.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub readings: Vec<ClaimRow>,
}

/// How a calibration's A/A false-positive rate reads against the nominal α.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CalibrationReading {
    /// The rate's interval holds α.
    Nominal,
    /// The rate's interval lies below α: the standard errors are too large and power is lost.
    Conservative,
    /// The rate's interval lies above α: the standard errors are too small.
    Liberal,
}

impl CalibrationReading {
    /// Where the exact interval of the false-positive rate lies against `alpha`.
    pub fn of(interval: (f64, f64), alpha: f64) -> CalibrationReading {
        if interval.1 < alpha {
            CalibrationReading::Conservative
        } else if interval.0 > alpha {
            CalibrationReading::Liberal
        } else {
            CalibrationReading::Nominal
        }
    }
}

/// The test's measured calibration in this study.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Calibration {
    pub alpha: f64,
    /// A/A comparisons: two seeds of one (configuration, preset) group.
    pub pairs: usize,
    pub false_positives: usize,
    pub false_positive_rate: f64,
    /// The rate's exact 95% binomial interval (every pair an independent trial).
    #[serde(default)]
    pub false_positive_interval: (f64, f64),
    /// The rate's 95% interval with the groups resampled: pairs of one group share its seeds,
    /// so they are not independent trials ([`crate::stats::cluster_rate_interval`]). The
    /// reading takes the envelope of the two. None in reports written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub false_positive_interval_groups: Option<(f64, f64)>,
    /// Whether each A/A pair was tested with a seed variance pooled over the other groups only
    /// (leave one group out), so that the test cannot be calibrated by the pairs it judges.
    #[serde(default)]
    pub held_out: bool,
    /// Where the rate's interval lies against α (None in reports written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reading: Option<CalibrationReading>,
    /// A planted degradation (a share of every box dropped) against the undegraded seeds.
    pub planted_drop_share: f64,
    pub planted_pairs: usize,
    pub planted_mean_effect: f64,
    pub power: f64,
    /// The pooled seed variance behind every test, per metric: between detectors of a group,
    /// or, when the study trains on several training-traffic draws, between its draws (each
    /// the mean of its seeds; [`draw_units`]).
    pub seed_variance: BTreeMap<String, SeedVariance>,
    /// With several training-traffic draws, each metric's variance split into the seeds' and
    /// the traffic's part (empty with one draw).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub traffic_draws: BTreeMap<String, DrawVariance>,
}

/// A detector's mAP against its training budget (seed 0).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Curve {
    pub configuration: String,
    pub preset: String,
    /// (samples seen, mAP on the common ground truth).
    pub points: Vec<(usize, f64)>,
    /// mAP gained over the last doubling of training (the last point against the one at half).
    pub gain_last_doubling: f64,
    /// Whether each point below the end is a training of its own over that many samples (what
    /// that budget reaches), or, as in reports written before these existed (false), the
    /// weights kept at that point of the one training: at a one-cycle learning rate still near
    /// its peak, which reads up to 0.06 mAP low near the plateau.
    #[serde(default)]
    pub own_schedules: bool,
}

/// Everything the verdict needs about the study's design.
#[derive(Clone, Copy, Debug)]
pub struct Design<'a> {
    pub scores: &'a [DetectorScores],
    /// Configurations with cost and how many radars they have. The paper's roles (the rig
    /// under study, the dearest radar rig, the mid-resolution one) are rigs of one radar; a rig
    /// of several radars placed given the rig under study is what a second radar adds.
    pub configurations: &'a [(String, f64, usize)],
    /// The weather condition of each configuration recorded in one (`[[conditions]]`), by name;
    /// the others are in the study's own weather.
    pub conditions: &'a BTreeMap<String, String>,
    /// The configuration each one keeps the placed sensors of (`given`), by name.
    pub given: &'a BTreeMap<String, String>,
    /// Presets trained on every configuration, in order; and ablations (cheapest only).
    pub presets: &'a [String],
    pub ablations: &'a [String],
    /// The preset each ablation ablates (as its plugin registered it).
    pub ablation_of: &'a BTreeMap<String, String>,
    /// Which presets read radar.
    pub uses_radar: &'a BTreeMap<String, bool>,
    /// Each fusion preset's LiDAR-only counterpart: the LiDAR-only preset of the profile with
    /// the same head and target assignment, so a comparison isolates the fusion.
    pub counterpart: &'a BTreeMap<String, String>,
    /// The LiDAR-only presets with PointPillars' head (every cell of a box footprint positive),
    /// as against CenterPoint's (a peak at each centre).
    pub pointpillars_head: &'a std::collections::BTreeSet<String>,
    pub scenes: usize,
    pub level: f64,
}

impl Design<'_> {
    fn seeds(&self, conf: &str, preset: &str, metric: &str) -> Vec<&Scores> {
        self.scores
            .iter()
            .filter(|d| d.configuration == conf && d.preset == preset)
            .filter_map(|d| d.scores.get(metric))
            .collect()
    }

    /// The pooled seed variance of a metric over every (configuration, preset) group.
    pub fn seed_variance(&self, metric: &str) -> SeedVariance {
        let mut groups: BTreeMap<(&str, &str), Vec<&Scores>> = BTreeMap::new();
        for d in self.scores {
            if let Some(s) = d.scores.get(metric) {
                groups.entry((&d.configuration, &d.preset)).or_default().push(s);
            }
        }
        pooled_seed_variance(&groups.into_values().collect::<Vec<_>>())
    }

    /// B − A on `metric`; None when a side has no detector, or a velocity error that is not
    /// finite (a class without ground truth has none).
    fn cmp(&self, metric: &str, (ca, pa): (&str, &str), (cb, pb): (&str, &str)) -> Option<Test> {
        let (a, b) = (self.seeds(ca, pa, metric), self.seeds(cb, pb, metric));
        let finite = !lower_is_better(metric) || a.iter().chain(&b).all(|s| s.full.is_finite());
        (!a.is_empty() && !b.is_empty() && finite)
            .then(|| compare(&a, &b, self.seed_variance(metric), self.scenes, self.level))
    }

    /// B − A where each side is a set of detector groups (configuration, preset): every group
    /// weighs the same within its side and every seed the same within its group (one group a
    /// side is a plain comparison). None when a group has no detector, or for a velocity error
    /// that is not finite.
    fn groups_test(&self, metric: &str, a: &[(String, String)], b: &[(String, String)]) -> Option<Test> {
        let side = |groups: &[(String, String)]| -> Option<(Vec<(&Scores, f64)>, f64)> {
            let n = groups.len() as f64;
            let (mut w, mut term) = (Vec::new(), 0.0);
            for (c, p) in groups {
                let s = self.seeds(c, p, metric);
                if s.is_empty() || (lower_is_better(metric) && s.iter().any(|x| !x.full.is_finite())) {
                    return None;
                }
                let m = s.len() as f64;
                w.extend(s.into_iter().map(|x| (x, 1.0 / (n * m))));
                term += 1.0 / (n * n * m);
            }
            (!groups.is_empty()).then_some((w, term))
        };
        let ((wa, ta), (wb, tb)) = (side(a)?, side(b)?);
        Some(test(&wa, &wb, self.seed_variance(metric), ta + tb, self.scenes, self.level))
    }

    /// A claim's other readings: each of its rows on [`METRICS`] under the visible-only ground
    /// truth; and for the fusion claims, the paper's averaging (every fusion preset of the rig
    /// against the row's LiDAR-only baseline, the fusion presets averaged), in both
    /// conventions, when the rig has more than one fusion preset.
    fn readings(&self, c: &Claim) -> Vec<ClaimRow> {
        let mut out = Vec::new();
        let paper_way = matches!(c.id.split('@').next(), Some("fusion_vs_lidar_only" | "fusion_over_pointpillars"));
        for r in c.rows.iter().filter(|r| METRICS.contains(&r.metric.as_str())) {
            let vis = visible_only(&r.metric);
            if let Some(t) = self.groups_test(&vis, &r.a, &r.b) {
                let mut v = row(&vis, r.comparison.clone(), r.paper, t);
                (v.a, v.b, v.reading) = (r.a.clone(), r.b.clone(), Some("visible-only ground truth".into()));
                out.push(v);
            }
            let Some((conf, _)) = r.b.first().filter(|_| paper_way && r.a.len() == 1 && r.b.len() == 1) else {
                continue;
            };
            let fusions: Vec<(String, String)> = self
                .presets
                .iter()
                .filter(|p| {
                    self.uses_radar.get(*p).copied().unwrap_or(false) && !self.seeds(conf, p, &r.metric).is_empty()
                })
                .map(|p| (conf.clone(), p.clone()))
                .collect();
            if fusions.len() < 2 {
                continue;
            }
            let names: Vec<&str> = fusions.iter().map(|f| f.1.as_str()).collect();
            let what = format!("mean of {} − {} on {conf}", names.join(", "), r.a[0].1);
            for (metric, label) in [
                (r.metric.clone(), "the paper's averaging (the mean of the fusion presets)"),
                (vis.clone(), "the paper's averaging, visible-only ground truth"),
            ] {
                if let Some(t) = self.groups_test(&metric, &r.a, &fusions) {
                    let mut v = row(&metric, what.clone(), r.paper, t);
                    (v.a, v.b, v.reading) = (r.a.clone(), fusions.clone(), Some(label.into()));
                    out.push(v);
                }
            }
        }
        out
    }

    /// A claim of B − A on each of [`VELOCITY_METRICS`] that both sides have (not tested when
    /// neither has: detectors scored before velocity errors were).
    /// B − A on mAP and pedestrian AP, each group a (configuration, preset), with no paper
    /// number; a metric either side lacks is left out.
    fn accuracy_rows(&self, a: (&str, &str), b: (&str, &str)) -> Vec<ClaimRow> {
        ["mAP", "pedestrian AP"]
            .iter()
            .filter_map(|m| {
                self.cmp(m, a, b)
                    .map(|t| with(row(m, format!("{} on {} − {} on {}", b.1, b.0, a.1, a.0), None, t), &[a], &[b]))
            })
            .collect()
    }

    fn velocity_claim(&self, id: &str, statement: &str, a: (&str, &str), b: (&str, &str)) -> Claim {
        let rows: Vec<ClaimRow> = VELOCITY_METRICS
            .iter()
            .filter_map(|m| {
                self.cmp(m, a, b)
                    .map(|t| with(row(m, format!("{} on {} − {} on {}", b.1, b.0, a.1, a.0), None, t), &[a], &[b]))
            })
            .collect();
        let missing = rows.is_empty().then(|| "no finite velocity error on both sides".to_string());
        claim(id, statement, rows, missing)
    }

    /// The cheapest configuration with one radar, the dearest with one radar, the dearest
    /// without (with no rig of one radar, as when every radar rig is budgeted, the rigs with
    /// any radars take the radar roles).
    fn roles(&self) -> (Option<&str>, Option<&str>, Option<&str>) {
        let radar = self.radar_role_rigs();
        let lidar = self.by_cost(&|n| n == 0);
        (radar.first().map(|c| c.0.as_str()), radar.last().map(|c| c.0.as_str()), lidar.last().map(|c| c.0.as_str()))
    }

    /// The fusion preset under study and the LiDAR-only preset it is compared with: the first
    /// fusion preset of the profile whose counterpart has CenterPoint's head, and that
    /// counterpart (without counterparts: the first fusion and the first LiDAR-only preset).
    fn fusion_and_lidar(&self) -> (Option<&str>, Option<&str>) {
        if let Some((f, l)) = self.fusion_with_head(false) {
            return (Some(f), Some(l));
        }
        let f = self.presets.iter().find(|p| self.uses_radar.get(*p).copied().unwrap_or(false));
        let l = self.presets.iter().find(|p| !self.uses_radar.get(*p).copied().unwrap_or(true));
        (f.map(String::as_str), l.map(String::as_str))
    }

    /// The first fusion preset of the profile whose LiDAR-only counterpart has PointPillars'
    /// head (`pointpillars`) or CenterPoint's, and the counterpart.
    fn fusion_with_head(&self, pointpillars: bool) -> Option<(&str, &str)> {
        self.presets.iter().find_map(|f| {
            let l = self.counterpart.get(f)?;
            (self.presets.contains(l) && self.pointpillars_head.contains(l) == pointpillars)
                .then_some((f.as_str(), l.as_str()))
        })
    }

    /// The rig under study: the cheapest configuration with one radar (with none, the cheapest
    /// with any radars; the cheapest of all when none has one).
    fn under_study(&self) -> Option<&(String, f64, usize)> {
        self.radar_role_rigs().first().copied().or_else(|| self.by_cost(&|_| true).first().copied())
    }

    /// The rigs that take the radar roles, cheapest first: those of one radar, or with none of
    /// one radar (every radar rig budgeted, say), those with any radars.
    fn radar_role_rigs(&self) -> Vec<&(String, f64, usize)> {
        let one = self.by_cost(&|n| n == 1);
        if one.is_empty() { self.by_cost(&|n| n > 0) } else { one }
    }

    /// The configurations whose radar count `keep` accepts, cheapest first (stable on ties).
    fn by_cost(&self, keep: &dyn Fn(usize) -> bool) -> Vec<&(String, f64, usize)> {
        let mut v: Vec<&(String, f64, usize)> = self.configurations.iter().filter(|c| keep(c.2)).collect();
        v.sort_by(|a, b| a.1.total_cmp(&b.1));
        v
    }

    /// The configurations recorded in `condition` (None: the study's own weather).
    fn in_condition(&self, condition: Option<&str>) -> Vec<(String, f64, usize)> {
        self.configurations
            .iter()
            .filter(|c| self.conditions.get(&c.0).map(String::as_str) == condition)
            .cloned()
            .collect()
    }

    /// The weather conditions of the design, in order of first appearance.
    fn condition_names(&self) -> Vec<&str> {
        let mut out: Vec<&str> = Vec::new();
        for c in self.configurations {
            if let Some(k) = self.conditions.get(&c.0)
                && !out.contains(&k.as_str())
            {
                out.push(k);
            }
        }
        out
    }

    /// The rig under study against every other one in the study's own weather, per preset
    /// and metric.
    pub fn comparisons(&self) -> Vec<Comparison> {
        let own = self.in_condition(None);
        Design { configurations: &own, ..*self }.comparisons_here()
    }

    fn comparisons_here(&self) -> Vec<Comparison> {
        let mut out = Vec::new();
        let Some(cheap) = self.under_study() else { return out };
        for other in self.configurations.iter().filter(|c| c.0 != cheap.0) {
            for p in self.presets {
                for m in METRICS {
                    if let Some(t) = self.cmp(m, (&other.0, p), (&cheap.0, p)) {
                        out.push(Comparison {
                            metric: m.into(),
                            a: format!("{p} on {}", other.0),
                            b: format!("{p} on {}", cheap.0),
                            test: t,
                        });
                    }
                }
            }
        }
        out
    }

    /// The paper's claims, each as B − A in the paper's favoured direction: the rigs against
    /// each other with the fusion detector, fusion against LiDAR only and the ablation, and
    /// the rigs over every preset; then the confounds: what the radar adds to a rig, and what
    /// two viewpoints add.
    ///
    /// Then, per weather condition, the claims about the radar judged on that condition's
    /// configurations alone ([`CONDITION_CLAIMS`]): their ids end in `@<condition>`.
    pub fn claims(&self) -> Vec<Claim> {
        let own = self.in_condition(None);
        let here = Design { configurations: &own, ..*self };
        let mut claims = here.claims_rigs();
        claims.extend(here.claims_confounds());
        claims.extend(here.claims_fusion());
        claims.extend(here.claims_pooled());
        claims.extend(here.claims_second_radar());
        for cond in self.condition_names() {
            let confs = self.in_condition(Some(cond));
            let there = Design { configurations: &confs, ..*self };
            let mut found = there.claims_confounds();
            found.extend(there.claims_fusion());
            for mut c in found.into_iter().filter(|c| CONDITION_CLAIMS.contains(&c.id.as_str())) {
                c.id = format!("{}@{cond}", c.id);
                c.statement = format!("{}, in {cond}", c.statement);
                c.condition = Some(cond.to_owned());
                claims.push(c);
            }
        }
        for c in &mut claims {
            c.readings = self.readings(c);
        }
        claims
    }

    /// The cheap rig against one high-resolution LiDAR, alone and with a radar.
    fn claims_rigs(&self) -> Vec<Claim> {
        let (cheap, dear_radar, lidar_alone) = self.roles();
        let (fusion, lidar) = self.fusion_and_lidar();
        let mut claims = Vec::new();
        // 1. Low-resolution LiDAR + radar against a high-resolution LiDAR alone.
        let c1 = match (cheap, lidar_alone, fusion, lidar) {
            (Some(c), Some(l), Some(f), Some(lp)) => {
                let rows = [("mAP", Some(0.015)), ("pedestrian AP", Some(0.14))]
                    .iter()
                    .filter_map(|(m, paper)| {
                        self.cmp(m, (l, lp), (c, f)).map(|t| {
                            with(row(m, format!("{f} on {c} − {lp} on {l}"), *paper, t), &[(l, lp)], &[(c, f)])
                        })
                    })
                    .collect();
                claim(
                    "vs_lidar_alone",
                    "Two cheap LiDARs and a radar, fused, beat one high-resolution LiDAR alone",
                    rows,
                    None,
                )
            }
            _ => claim(
                "vs_lidar_alone",
                "Two cheap LiDARs and a radar, fused, beat one high-resolution LiDAR alone",
                vec![],
                Some(
                    "needs a LiDAR-only configuration, a configuration with radar, a fusion and a LiDAR-only preset"
                        .into(),
                ),
            ),
        };
        claims.push(c1);
        // 2. Against the high-resolution LiDAR with the same radar, same detector (pooled over
        // presets), supported only when every preset's own difference favours the cheap rig: the
        // paper's "whichever module is used".
        let st2 = "Two cheap LiDARs and a radar beat one high-resolution LiDAR and a radar with the same \
                   detector, whichever module is used";
        let c2 = match (cheap, dear_radar) {
            (Some(c), Some(d)) if c != d => {
                let mut per = BTreeMap::new();
                let rows = [("mAP", Some(0.015)), ("pedestrian AP", None)]
                    .iter()
                    .filter_map(|(m, paper)| {
                        let (r, p) = self.pooled_row(m, d, c, *paper)?;
                        if *m == "mAP" {
                            per = p;
                        }
                        Some(r)
                    })
                    .collect();
                let mut cl = claim("vs_lidar_radar", st2, rows, None);
                cl.per_preset = per;
                cl
            }
            _ => claim("vs_lidar_radar", st2, vec![], Some("needs two configurations with radar".into())),
        };
        claims.push(c2);
        claims
    }

    /// The cheapest and the dearest LiDAR-only configuration.
    fn lidar_only_rigs(&self) -> (Option<&str>, Option<&str>) {
        let v = self.by_cost(&|n| n == 0);
        (v.first().map(|c| c.0.as_str()), v.last().map(|c| c.0.as_str()))
    }

    /// What the rig's radar adds (the cheapest rig with a radar, fused, against the LiDAR-only
    /// rig it was placed given, its LiDARs at the same poses, when its configuration names one
    /// with `given`; otherwise against the cheapest LiDAR-only rig, each rig placed for itself,
    /// so the LiDARs' poses may differ too), with its LiDAR-only counterpart, and what two viewpoints add (the cheapest LiDAR-only rig
    /// against the dearest, both with the LiDAR-only preset). The radar's rows need a LiDAR-only
    /// rig that costs less than the radar rig (its LiDARs without the radar): a dearer one, as
    /// when a profile keeps only the radar rig and the 64-beam LiDAR, would compare rigs, not
    /// the radar. No paper number: the paper compares detectors on one rig and rigs with radar.
    fn claims_confounds(&self) -> Vec<Claim> {
        let (cheap, _, _) = self.roles();
        let (lidar_cheap, lidar_dear) = self.lidar_only_rigs();
        let cost = |name: &str| self.configurations.iter().find(|c| c.0 == name).map_or(f64::NAN, |c| c.1);
        // The rig the radar rig was placed given (its LiDARs at the same poses) when it names a
        // LiDAR-only one here; else the cheapest LiDAR-only rig, placed for itself.
        let same_poses = cheap
            .and_then(|c| self.given.get(c))
            .map(String::as_str)
            .filter(|g| self.configurations.iter().any(|x| x.0 == *g && x.2 == 0));
        let without_radar = same_poses.or(match (cheap, lidar_cheap) {
            (Some(c), Some(l)) if cost(l) < cost(c) => Some(l),
            _ => None,
        });
        let (fusion, lidar) = self.fusion_and_lidar();
        let st1 = "A radar, fused, adds accuracy to the cheapest LiDAR-only rig";
        let needs = "needs a configuration with radar, a LiDAR-only one that costs less (its LiDARs without the \
                     radar), a fusion and a LiDAR-only preset";
        let st1 = if same_poses.is_some() { format!("{st1}, its LiDARs at the same poses") } else { st1.to_owned() };
        let c1 = match (cheap, without_radar, fusion, lidar) {
            (Some(c), Some(l), Some(f), Some(lp)) => {
                claim("radar_adds", &st1, self.accuracy_rows((l, lp), (c, f)), None)
            }
            _ => claim("radar_adds", &st1, vec![], Some(needs.into())),
        };
        let st1v = "A radar, fused, lowers the velocity error of the cheapest LiDAR-only rig";
        let c1v = match (cheap, without_radar, fusion, lidar) {
            (Some(c), Some(l), Some(f), Some(lp)) => self.velocity_claim("radar_adds_velocity", st1v, (l, lp), (c, f)),
            _ => claim("radar_adds_velocity", st1v, vec![], Some(needs.into())),
        };
        let st2 = "Two viewpoints of cheap LiDARs beat one high-resolution LiDAR, both without radar";
        let c2 = match (lidar_cheap, lidar_dear, lidar) {
            (Some(c), Some(d), Some(lp)) if c != d => {
                claim("second_viewpoint", st2, self.accuracy_rows((d, lp), (c, lp)), None)
            }
            _ => claim("second_viewpoint", st2, vec![], Some("needs two LiDAR-only configurations".into())),
        };
        vec![c1, c1v, c2]
    }

    /// What a second radar adds: the rig placed given the rig under study (its LiDARs and its
    /// radar at the same poses) with more radars, against it, both with the fusion preset, in
    /// accuracy and in velocity error. Two lines of sight measure a road user's full ground
    /// velocity where one measures its radial part (the fusion presets pair the radars'
    /// detections, `input.radar_pairs`).
    fn claims_second_radar(&self) -> Vec<Claim> {
        let (cheap, _, _) = self.roles();
        let (fusion, _) = self.fusion_and_lidar();
        let more = cheap.and_then(|c| {
            self.configurations
                .iter()
                .filter(|x| x.2 > 1 && self.given.get(&x.0).is_some_and(|g| g == c))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|x| x.0.as_str())
        });
        let st = "A second radar, fused, adds accuracy to the rig under study, its LiDARs and radar at the same poses";
        let stv = "A second radar, fused, lowers the velocity error of the rig under study, its LiDARs and radar at \
                   the same poses";
        let needs =
            "needs a configuration of more radars placed given the rig under study (`given`), and a fusion preset";
        let [adds, velocity] = SECOND_RADAR_CLAIMS;
        match (cheap, more, fusion) {
            (Some(c), Some(m), Some(f)) => vec![
                claim(adds, st, self.accuracy_rows((c, f), (m, f)), None),
                self.velocity_claim(velocity, stv, (c, f), (m, f)),
            ],
            _ => vec![claim(adds, st, vec![], Some(needs.into())), claim(velocity, stv, vec![], Some(needs.into()))],
        }
    }

    /// Fusion against the LiDAR-only counterpart on the cheap rig, and the early-fusion ablation.
    fn claims_fusion(&self) -> Vec<Claim> {
        let (cheap, _, _) = self.roles();
        let (fusion, lidar) = self.fusion_and_lidar();
        let mut claims = Vec::new();
        // 3. Fusion against LiDAR only on the same (cheapest) rig.
        let st3 = "Fusing radar beats the LiDAR-only detector on the same rig";
        let c3 = match (cheap, fusion, lidar) {
            (Some(c), Some(f), Some(lp)) => {
                let rows = self
                    .cmp("mAP", (c, lp), (c, f))
                    .map(|t| with(row("mAP", format!("{f} − {lp} on {c}"), Some(0.031), t), &[(c, lp)], &[(c, f)]))
                    .into_iter()
                    .collect();
                claim("fusion_vs_lidar_only", st3, rows, None)
            }
            _ => claim("fusion_vs_lidar_only", st3, vec![], Some("needs a fusion and a LiDAR-only preset".into())),
        };
        claims.push(c3);
        // 3v. Velocity: what the radar's Doppler is bought for, on the same rig.
        let st3v = "Fusing radar lowers velocity error against the LiDAR-only detector on the same rig";
        let c3v = match (cheap, fusion, lidar) {
            (Some(c), Some(f), Some(lp)) => self.velocity_claim("fusion_lowers_velocity_error", st3v, (c, lp), (c, f)),
            _ => claim(
                "fusion_lowers_velocity_error",
                st3v,
                vec![],
                Some("needs a fusion and a LiDAR-only preset".into()),
            ),
        };
        claims.push(c3v);
        // 3b. Fused pedestrian AP over CenterPoint's head; 3c. fusion over PointPillars' head.
        let st3b = "Fusing radar raises pedestrian AP over the LiDAR-only CenterPoint on the same rig";
        let c3b = match (cheap, self.fusion_with_head(false)) {
            (Some(c), Some((f, lp))) => {
                let rows = self
                    .cmp("pedestrian AP", (c, lp), (c, f))
                    .map(|t| {
                        with(row("pedestrian AP", format!("{f} − {lp} on {c}"), Some(0.068), t), &[(c, lp)], &[(c, f)])
                    })
                    .into_iter()
                    .collect();
                claim("fused_pedestrian_over_centerpoint", st3b, rows, None)
            }
            _ => claim(
                "fused_pedestrian_over_centerpoint",
                st3b,
                vec![],
                Some("needs a fusion preset and its LiDAR-only counterpart with CenterPoint's head".into()),
            ),
        };
        claims.push(c3b);
        let st3c = "Fusing radar beats the LiDAR-only PointPillars on the same rig";
        let c3c = match (cheap, self.fusion_with_head(true)) {
            (Some(c), Some((f, lp))) => {
                let rows = [("mAP", 0.077), ("pedestrian AP", 0.092)]
                    .iter()
                    .filter_map(|(m, paper)| {
                        self.cmp(m, (c, lp), (c, f))
                            .map(|t| with(row(m, format!("{f} − {lp} on {c}"), Some(*paper), t), &[(c, lp)], &[(c, f)]))
                    })
                    .collect();
                claim("fusion_over_pointpillars", st3c, rows, None)
            }
            _ => claim(
                "fusion_over_pointpillars",
                st3c,
                vec![],
                Some("needs a fusion preset and its LiDAR-only counterpart with PointPillars' head".into()),
            ),
        };
        claims.push(c3c);
        // 4. The early-fusion ablation.
        let st4 = "Early fusion helps: the detector with it beats the same detector without it";
        let ablation = fusion
            .and_then(|f| self.ablations.iter().find(|a| self.ablation_of.get(*a).is_some_and(|of| of == f)).cloned());
        let c4 = match (cheap, fusion, ablation) {
            (Some(c), Some(f), Some(a)) => {
                let rows = self
                    .cmp("mAP", (c, &a), (c, f))
                    .map(|t| with(row("mAP", format!("{f} − {a} on {c}"), Some(0.009), t), &[(c, &a)], &[(c, f)]))
                    .into_iter()
                    .collect();
                claim("early_fusion_ablation", st4, rows, None)
            }
            _ => claim(
                "early_fusion_ablation",
                st4,
                vec![],
                Some("needs an ablation of the fusion preset in the profile".into()),
            ),
        };
        claims.push(c4);
        claims
    }

    /// The cheap rig's advantage over a mid-resolution radar rig, over every preset (against
    /// the dearest radar rig: `vs_lidar_radar`).
    fn claims_pooled(&self) -> Vec<Claim> {
        let (cheap, dear_radar, _) = self.roles();
        // 5. Against a mid-resolution LiDAR and a radar (a radar rig between the cheapest and
        // the dearest), pooled over presets.
        let mid = self
            .configurations
            .iter()
            .filter(|x| x.2 == 1 && Some(x.0.as_str()) != cheap && Some(x.0.as_str()) != dear_radar)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|x| x.0.as_str());
        let c6 = self.pooled_claim(
            "vs_mid_lidar_radar",
            "Two cheap LiDARs and a radar beat one mid-resolution LiDAR and a radar with the same detector",
            cheap.zip(mid).map(|(c, m)| (m, c)),
            0.032,
            "needs a third configuration with radar, between the cheapest and the dearest",
        );
        vec![c6]
    }

    /// [`Self::pooled`] as a claim row "b − a, mean over presets" with each side's groups, and
    /// each preset's own difference.
    fn pooled_row(
        &self,
        metric: &str,
        a: &str,
        b: &str,
        paper: Option<f64>,
    ) -> Option<(ClaimRow, BTreeMap<String, f64>)> {
        let (t, per) = self.pooled(metric, a, b)?;
        let side = |rig: &str| per.keys().map(|p| (rig.to_owned(), p.clone())).collect::<Vec<_>>();
        let mut r = row(metric, format!("{b} − {a}, mean over presets"), paper, t);
        (r.a, r.b) = (side(a), side(b));
        Some((r, per))
    }

    /// A claim of one mAP row pooled over presets, rig `b` against rig `a` (`rigs` as (a, b);
    /// None: not tested, for `missing`), supported only when every preset's own difference
    /// favours `b` too.
    fn pooled_claim(&self, id: &str, statement: &str, rigs: Option<(&str, &str)>, paper: f64, missing: &str) -> Claim {
        let Some((a, b)) = rigs else { return claim(id, statement, vec![], Some(missing.into())) };
        match self.pooled_row("mAP", a, b, Some(paper)) {
            Some((r, per)) => {
                let mut cl = claim(id, statement, vec![r], None);
                cl.per_preset = per;
                cl
            }
            None => claim(id, statement, vec![], Some("no preset ran on both configurations".into())),
        }
    }

    /// B − A averaged over the presets that ran on both (each side their groups, weighed by
    /// [`Self::groups_test`]); and each preset's own difference.
    fn pooled(&self, metric: &str, a: &str, b: &str) -> Option<(Test, BTreeMap<String, f64>)> {
        let presets: Vec<&String> = self
            .presets
            .iter()
            .filter(|p| !self.seeds(a, p, metric).is_empty() && !self.seeds(b, p, metric).is_empty())
            .collect();
        let full = |rig: &str, p: &str| mean(&self.seeds(rig, p, metric).iter().map(|s| s.full).collect::<Vec<_>>());
        let per = presets.iter().map(|p| ((*p).clone(), full(b, p) - full(a, p))).collect();
        let side = |rig: &str| presets.iter().map(|p| (rig.to_owned(), (*p).clone())).collect::<Vec<_>>();
        Some((self.groups_test(metric, &side(a), &side(b))?, per))
    }

    /// A/A pairs: for every group, each pair of its seeds, each tested with a seed variance
    /// pooled over the other groups ([`held_out_aa`]), so the variance is never estimated from
    /// the pair it judges. (Rigs are placed each for itself, so two rigs' LiDAR data are not
    /// the same and no pair across rigs is an A/A pair.) One list per group.
    pub fn aa_pairs(&self) -> Vec<Vec<Test>> {
        let mut groups: BTreeMap<(&str, &str), Vec<&Scores>> = BTreeMap::new();
        for d in self.scores {
            if let Some(s) = d.scores.get("mAP") {
                groups.entry((&d.configuration, &d.preset)).or_default().push(s);
            }
        }
        held_out_aa(&groups.into_values().collect::<Vec<_>>(), self.scenes, self.level, 1.0)
    }
}

/// A claim row of B − A, its verdict not yet set.
fn row(metric: &str, what: String, paper: Option<f64>, t: Test) -> ClaimRow {
    ClaimRow {
        metric: metric.into(),
        comparison: what,
        paper,
        test: t,
        verdict: Verdict::Undecided,
        a: Vec::new(),
        b: Vec::new(),
        paper_relation: None,
        tost_p: f64::NAN,
        mde: f64::NAN,
        reading: None,
    }
}

/// The row with the detector groups of its sides.
fn with(mut r: ClaimRow, a: &[(&str, &str)], b: &[(&str, &str)]) -> ClaimRow {
    let groups = |v: &[(&str, &str)]| v.iter().map(|(c, p)| (c.to_string(), p.to_string())).collect::<Vec<_>>();
    r.a = groups(a);
    r.b = groups(b);
    r
}

/// A claim of rows (none, with the reason, when it cannot be tested).
fn claim(id: &str, statement: &str, rows: Vec<ClaimRow>, missing: Option<String>) -> Claim {
    Claim {
        id: id.into(),
        statement: statement.into(),
        rows,
        verdict: Verdict::Undecided,
        not_tested: missing,
        per_preset: BTreeMap::new(),
        paper_relation: None,
        mde: None,
        condition: None,
        readings: Vec::new(),
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// What the verdict needs to know of a profile's presets, from the registry: which read radar,
/// which ablation ablates which preset, each fusion preset's LiDAR-only counterpart (the same
/// head, target assignment and output stride) and which LiDAR-only presets have PointPillars'
/// head.
#[derive(Clone, Debug, Default)]
pub struct PresetRoles {
    pub uses_radar: BTreeMap<String, bool>,
    pub ablation_of: BTreeMap<String, String>,
    pub counterpart: BTreeMap<String, String>,
    pub pointpillars_head: std::collections::BTreeSet<String>,
}

impl PresetRoles {
    pub fn of(prof: &hilo_plan::profile::Profile, registry: &hilo_detector::Registry) -> PresetRoles {
        let uses_radar: BTreeMap<String, bool> = prof
            .presets
            .iter()
            .chain(&prof.ablations)
            .filter_map(|p| registry.preset(p).ok().map(|x| (p.clone(), registry.uses_radar(&x.detector))))
            .collect();
        let ablation_of: BTreeMap<String, String> = prof
            .ablations
            .iter()
            .filter_map(|a| registry.ablation_of(a).map(|of| (a.clone(), of.to_owned())))
            .collect();
        // Each fusion preset's LiDAR-only counterpart (the registry's: same head and target
        // assignment), where the profile trains it.
        let cfg_of = |p: &str| registry.preset(p).ok().map(|x| &x.detector);
        let lidar_only: Vec<&String> =
            prof.presets.iter().filter(|p| !uses_radar.get(*p).copied().unwrap_or(true)).collect();
        let counterpart: BTreeMap<String, String> = prof
            .presets
            .iter()
            .chain(&prof.ablations)
            .filter_map(|f| {
                let l = registry.lidar_counterpart(f).filter(|l| prof.presets.iter().any(|p| p == l))?;
                Some((f.clone(), l.to_owned()))
            })
            .collect();
        let pointpillars_head: std::collections::BTreeSet<String> = lidar_only
            .iter()
            .filter(|l| cfg_of(l).is_some_and(|c| c.assignment == hilo_detector::targets::Assignment::Inside))
            .map(|l| (*l).clone())
            .collect();
        PresetRoles { uses_radar, ablation_of, counterpart, pointpillars_head }
    }
}

/// Holm-adjusts each family of tests and sets each claim row's and claim's verdict. Three
/// families, each adjusted on its own: the paper's claims (every claim's own rows), the rig
/// comparisons, and the claims' other readings ([`Claim::readings`]). A row is supported when
/// it is significant in the claim's favoured direction (B − A > 0; B − A < 0 for an error such
/// as mAVE), contradicted when significant against it, equivalent when not significant and its
/// TOST against ± its metric's margin is (unadjusted p < α), undecided otherwise. A claim is
/// contradicted when a row is, supported when every row is (and every preset's own difference
/// is positive), equivalent when every row is, undecided otherwise; its readings do not decide
/// it. Each row also gets where its interval lies against the paper's number and its minimum
/// detectable effect (80% power).
pub fn adjust(claims: &mut [Claim], comparisons: &mut [Comparison], alpha: f64, margins: Margins) {
    let judge = |r: &mut ClaimRow, p_adjusted: f64| {
        r.test.p_adjusted = p_adjusted;
        r.tost_p = tost_p(&r.test, margins.of(&r.metric));
        r.mde = if r.test.estimable { mde(r.test.se, r.test.df, alpha, 0.8) } else { f64::NAN };
        r.paper_relation = r.paper.and_then(|x| paper_relation(r.test.lo, r.test.hi, x));
        r.verdict = if r.test.estimable && r.test.p_adjusted < alpha {
            let gain = if lower_is_better(&r.metric) { -r.test.estimate } else { r.test.estimate };
            if gain > 0.0 { Verdict::Supported } else { Verdict::Contradicted }
        } else if r.tost_p < alpha {
            Verdict::Equivalent
        } else {
            Verdict::Undecided
        };
    };
    let own = holm(&claims.iter().flat_map(|c| c.rows.iter().map(|r| r.test.p)).collect::<Vec<_>>());
    let other = holm(&claims.iter().flat_map(|c| c.readings.iter().map(|r| r.test.p)).collect::<Vec<_>>());
    let (mut k, mut j) = (0, 0);
    for c in claims.iter_mut() {
        for r in &mut c.rows {
            judge(r, own[k]);
            k += 1;
        }
        for r in &mut c.readings {
            judge(r, other[j]);
            j += 1;
        }
        let all = |v: Verdict| !c.rows.is_empty() && c.rows.iter().all(|r| r.verdict == v);
        c.verdict = if c.rows.iter().any(|r| r.verdict == Verdict::Contradicted) {
            Verdict::Contradicted
        } else if all(Verdict::Supported) && c.per_preset.values().all(|d| *d > 0.0) {
            Verdict::Supported
        } else if all(Verdict::Equivalent) {
            Verdict::Equivalent
        } else {
            Verdict::Undecided
        };
        c.paper_relation = c.rows.first().and_then(|r| r.paper_relation);
        c.mde = c.rows.first().map(|r| r.mde).filter(|m| m.is_finite());
    }
    let rigs = holm(&comparisons.iter().map(|c| c.test.p).collect::<Vec<_>>());
    for (c, p) in comparisons.iter_mut().zip(rigs) {
        c.test.p_adjusted = p;
    }
}

/// The budget gate: a claim row whose difference, seed 0 against seed 0, changes sign between
/// half the training budget and the full one (the learning curves' points) is budget-bound, and so is its
/// claim when it would otherwise be supported, contradicted or equivalent. Rows without curves
/// on both sides are left as they are.
pub fn budget_gate(claims: &mut [Claim], curves: &[Curve]) {
    let at = |conf: &str, preset: &str| -> Option<(f64, f64)> {
        let c = curves.iter().find(|c| c.configuration == conf && c.preset == preset)?;
        let (end, last) = *c.points.last()?;
        let half = c.points.iter().min_by_key(|q| (2 * q.0).abs_diff(end))?;
        (half.0 < end).then_some((half.1, last))
    };
    let side = |g: &[(String, String)]| -> Option<(f64, f64)> {
        let v: Vec<(f64, f64)> = g.iter().map(|(c, p)| at(c, p)).collect::<Option<_>>()?;
        (!v.is_empty()).then(|| {
            let n = v.len() as f64;
            (v.iter().map(|x| x.0).sum::<f64>() / n, v.iter().map(|x| x.1).sum::<f64>() / n)
        })
    };
    for c in claims.iter_mut() {
        let mut bound = false;
        for r in &mut c.rows {
            if r.metric != "mAP" {
                continue;
            }
            if let (Some(a), Some(b)) = (side(&r.a), side(&r.b)) {
                let (half, end) = (b.0 - a.0, b.1 - a.1);
                if half * end < 0.0 && r.verdict != Verdict::Undecided {
                    r.verdict = Verdict::BudgetBound;
                    bound = true;
                }
            }
        }
        if bound && c.verdict != Verdict::Undecided {
            c.verdict = Verdict::BudgetBound;
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    const MARGINS: Margins = Margins { ap: 0.02, velocity_m_s: 0.1 };

    /// The presets of these tests: `cp` (LiDAR only), `lf` (fusion) and, with an ablation,
    /// `lf-no-early` (lf's); no counterparts or PointPillars heads.
    struct Roles {
        presets: Vec<String>,
        ablations: Vec<String>,
        ablation_of: BTreeMap<String, String>,
        uses: BTreeMap<String, bool>,
        counterpart: BTreeMap<String, String>,
        pointpillars_head: std::collections::BTreeSet<String>,
        conditions: BTreeMap<String, String>,
        given: BTreeMap<String, String>,
    }

    impl Roles {
        fn new(ablation: bool) -> Self {
            let mut r = Roles {
                presets: vec!["cp".to_string(), "lf".to_string()],
                ablations: Vec::new(),
                ablation_of: BTreeMap::new(),
                uses: BTreeMap::from([("cp".to_string(), false), ("lf".to_string(), true)]),
                counterpart: BTreeMap::new(),
                pointpillars_head: std::collections::BTreeSet::new(),
                conditions: BTreeMap::new(),
                given: BTreeMap::new(),
            };
            if ablation {
                r.uses.insert("lf-no-early".to_string(), true);
                r.ablations.push("lf-no-early".to_string());
                r.ablation_of.insert("lf-no-early".to_string(), "lf".to_string());
            }
            r
        }

        /// A design of `scores` over `configurations`, 20 scenes, 95% intervals.
        fn design<'a>(
            &'a self,
            scores: &'a [DetectorScores],
            configurations: &'a [(String, f64, usize)],
        ) -> Design<'a> {
            Design {
                scores,
                configurations,
                conditions: &self.conditions,
                given: &self.given,
                presets: &self.presets,
                ablations: &self.ablations,
                ablation_of: &self.ablation_of,
                uses_radar: &self.uses,
                counterpart: &self.counterpart,
                pointpillars_head: &self.pointpillars_head,
                scenes: 20,
                level: 0.95,
            }
        }
    }

    fn det(conf: &str, preset: &str, seed: u64, map: f64) -> DetectorScores {
        // 30 replicates that move every detector together (the same scenes drawn), plus a little.
        let reps = (0..30).map(|r| map + 0.01 * ((r % 7) as f64 - 3.0) + 0.001 * seed as f64).collect();
        let s = Scores { full: map, replicates: reps };
        DetectorScores {
            configuration: conf.into(),
            preset: preset.into(),
            seed,
            draw: 0,
            scores: BTreeMap::from([("mAP".to_string(), s.clone()), ("pedestrian AP".to_string(), s)]),
        }
    }

    /// Three seeds of each (configuration, preset, mAP) group, seed s at mAP + 0.004 s.
    fn seeded(groups: &[(&str, &str, f64)]) -> Vec<DetectorScores> {
        (0..3)
            .flat_map(|s| groups.iter().map(move |&(conf, preset, map)| det(conf, preset, s, map + 0.004 * s as f64)))
            .collect()
    }

    #[test]
    fn claims_follow_the_roles_and_a_clear_gap_is_supported() {
        let scores = seeded(&[
            ("2x16+R", "cp", 0.70),
            ("2x16+R", "lf", 0.80),
            ("2x16+R", "lf-no-early", 0.70),
            ("64", "cp", 0.60),
            ("64+R", "cp", 0.60),
            ("64+R", "lf", 0.62),
        ]);
        let configurations = vec![
            ("2x16+R".to_string(), 10_000.0, 1),
            ("64".to_string(), 20_750.0, 0),
            ("64+R".to_string(), 22_750.0, 1),
        ];
        let roles = Roles::new(true);
        let d = roles.design(&scores, &configurations);
        let mut claims = d.claims();
        let mut comps = d.comparisons();
        // The claims are a family of their own: the rig comparisons do not move their adjusted p.
        let mut alone = claims.clone();
        adjust(&mut alone, &mut [], 0.05, MARGINS);
        adjust(&mut claims, &mut comps, 0.05, MARGINS);
        let adjusted =
            |v: &[Claim]| v.iter().flat_map(|c| c.rows.iter().map(|r| r.test.p_adjusted)).collect::<Vec<_>>();
        assert_eq!(adjusted(&alone).len(), adjusted(&claims).len());
        assert!(adjusted(&alone).iter().zip(adjusted(&claims)).all(|(a, b)| a.to_bits() == b.to_bits()));
        let raw: Vec<f64> = claims.iter().flat_map(|c| c.rows.iter().map(|r| r.test.p)).collect();
        let expected = holm(&raw);
        assert!(adjusted(&claims).iter().zip(&expected).all(|(a, b)| a.to_bits() == b.to_bits()));
        // Each claim is one test: no two rows of different claims compare the same groups.
        let mut seen = std::collections::BTreeSet::new();
        for c in &claims {
            for r in &c.rows {
                assert!(seen.insert((r.metric.clone(), r.a.clone(), r.b.clone())), "{} repeats a row", c.id);
            }
        }
        assert_eq!(claims.len(), 13);
        let by = |id: &str| claims.iter().find(|c| c.id == id).unwrap();
        // The confounds: the one LiDAR-only rig costs more than the radar rig, so it is not the
        // radar rig's LiDARs without the radar and the radar's claims are not tested; two
        // viewpoints need two LiDAR-only rigs.
        assert!(by("radar_adds").rows.is_empty() && by("radar_adds").not_tested.is_some());
        assert!(by("second_viewpoint").not_tested.is_some());
        // lf on 2x16+R (0.804) against cp on 64 (0.604).
        assert!((by("vs_lidar_alone").rows[0].test.estimate - 0.2).abs() < 1e-9);
        assert_eq!(by("vs_lidar_alone").verdict, Verdict::Supported);
        // Pooled over cp and lf: (0.704 − 0.604 + 0.804 − 0.624) / 2 = 0.14.
        assert!((by("vs_lidar_radar").rows[0].test.estimate - 0.14).abs() < 1e-9);
        assert_eq!(by("vs_lidar_radar").per_preset.len(), 2);
        assert_eq!(by("early_fusion_ablation").verdict, Verdict::Supported);
        // Every adjusted p is at least the raw one.
        assert!(comps.iter().all(|c| c.test.p_adjusted >= c.test.p - 1e-15));
        // A/A: 6 groups × 3 pairs of seeds.
        assert_eq!(d.aa_pairs().iter().map(Vec::len).collect::<Vec<_>>(), vec![3; 6]);
    }

    /// A difference shown within the margin is equivalent, not undecided; a claim whose sign
    /// flips over the last doubling of training is budget-bound; each row carries its MDE and
    /// its relation to the paper's number.
    #[test]
    fn equivalence_budget_gate_mde_and_paper_relation() {
        let scores = seeded(&[
            ("2x16+R", "cp", 0.70),
            ("2x16+R", "lf", 0.80),
            // The ablation scores as the preset does: no difference.
            ("2x16+R", "lf-no-early", 0.80),
            ("64+R", "cp", 0.60),
            ("64+R", "lf", 0.62),
        ]);
        let configurations = vec![("2x16+R".to_string(), 10_000.0, 1), ("64+R".to_string(), 22_750.0, 1)];
        let roles = Roles::new(true);
        let d = roles.design(&scores, &configurations);
        let (mut claims, mut comps) = (d.claims(), d.comparisons());
        adjust(&mut claims, &mut comps, 0.05, MARGINS);
        let by = |claims: &[Claim], id: &str| claims.iter().find(|c| c.id == id).unwrap().clone();
        let early = by(&claims, "early_fusion_ablation");
        assert_eq!(early.verdict, Verdict::Equivalent, "{:?}", early.rows[0]);
        assert!(early.rows[0].tost_p < 0.05);
        // A margin below what the design resolves leaves it undecided.
        let (mut tight, mut c2) = (d.claims(), d.comparisons());
        adjust(&mut tight, &mut c2, 0.05, Margins { ap: 0.001, ..MARGINS });
        assert_eq!(by(&tight, "early_fusion_ablation").verdict, Verdict::Undecided);
        // lf − cp on 2x16+R: +0.10 against the paper's +0.031, interval well above it.
        let fusion = by(&claims, "fusion_vs_lidar_only");
        assert_eq!(fusion.verdict, Verdict::Supported);
        assert_eq!(fusion.paper_relation, Some(PaperRelation::Larger));
        let r = &fusion.rows[0];
        assert!((r.mde - mde(r.test.se, r.test.df, 0.05, 0.8)).abs() < 1e-12 && r.mde > 2.0 * r.test.se);
        assert_eq!(
            (r.a.clone(), r.b.clone()),
            (vec![("2x16+R".into(), "cp".into())], vec![("2x16+R".into(), "lf".into())])
        );
        // Learning curves: at half the training cp led lf (0.50 against 0.45); at the end lf leads.
        let curve = |conf: &str, preset: &str, half: f64, end: f64| Curve {
            configuration: conf.into(),
            preset: preset.into(),
            points: vec![(3000, half), (6000, end)],
            gain_last_doubling: end - half,
            own_schedules: true,
        };
        let curves = vec![curve("2x16+R", "cp", 0.50, 0.70), curve("2x16+R", "lf", 0.45, 0.80)];
        budget_gate(&mut claims, &curves);
        assert_eq!(by(&claims, "fusion_vs_lidar_only").verdict, Verdict::BudgetBound);
        // The same ranking at half and at the end keeps the verdict.
        let (mut kept, mut c3) = (d.claims(), d.comparisons());
        adjust(&mut kept, &mut c3, 0.05, MARGINS);
        budget_gate(&mut kept, &[curve("2x16+R", "cp", 0.40, 0.70), curve("2x16+R", "lf", 0.45, 0.80)]);
        assert_eq!(by(&kept, "fusion_vs_lidar_only").verdict, Verdict::Supported);
    }

    /// A radar rig placed given a LiDAR-only rig is compared with that rig for what the radar
    /// adds (the same LiDAR poses), not with the cheapest LiDAR-only rig, and says so.
    #[test]
    fn the_radar_is_judged_against_the_rig_it_was_placed_given() {
        let mut roles = Roles::new(false);
        let scores =
            seeded(&[("2x16+R", "cp", 0.70), ("2x16+R", "lf", 0.75), ("2x16", "cp", 0.71), ("1x16", "cp", 0.50)]);
        let configurations = vec![
            ("2x16+R".to_string(), 10_000.0, 1),
            ("2x16".to_string(), 8_000.0, 0),
            ("1x16".to_string(), 4_000.0, 0),
        ];
        let by = |claims: &[Claim]| claims.iter().find(|c| c.id == "radar_adds").unwrap().clone();
        // Without `given`: the cheapest LiDAR-only rig.
        let placed_alone = by(&roles.design(&scores, &configurations).claims());
        assert_eq!(placed_alone.rows[0].a, [("1x16".to_string(), "cp".to_string())]);
        assert!(!placed_alone.statement.contains("same poses"));
        roles.given.insert("2x16+R".into(), "2x16".into());
        let given = by(&roles.design(&scores, &configurations).claims());
        assert_eq!(given.rows[0].a, [("2x16".to_string(), "cp".to_string())]);
        assert!((given.rows[0].test.estimate - 0.04).abs() < 1e-9);
        assert!(given.statement.ends_with("its LiDARs at the same poses"), "{}", given.statement);
    }

    /// The visible-only reading and the paper's averaging: the same groups scored the other
    /// way, every fusion preset of the rig averaged against the LiDAR-only baseline, labelled,
    /// adjusted as a family of their own and without a say in the claim's verdict.
    #[test]
    fn readings_give_the_other_convention_and_the_papers_averaging() {
        let mut roles = Roles::new(false);
        roles.presets.push("lf2".into());
        roles.uses.insert("lf2".into(), true);
        let with_visible = |conf: &str, preset: &str, seed: u64, map: f64, vis: f64| {
            let mut d = det(conf, preset, seed, map);
            let v = det(conf, preset, seed, vis).scores["mAP"].clone();
            for m in METRICS {
                d.scores.insert(visible_only(m), v.clone());
            }
            d
        };
        let mut scores = Vec::new();
        for s in 0..3 {
            let j = 0.004 * s as f64;
            scores.push(with_visible("2x16+R", "cp", s, 0.70 + j, 0.75 + j));
            scores.push(with_visible("2x16+R", "lf", s, 0.74 + j, 0.76 + j));
            scores.push(with_visible("2x16+R", "lf2", s, 0.66 + j, 0.80 + j));
            scores.push(with_visible("64", "cp", s, 0.60 + j, 0.70 + j));
        }
        let configurations = vec![("2x16+R".to_string(), 10_000.0, 1), ("64".to_string(), 20_750.0, 0)];
        let d = roles.design(&scores, &configurations);
        let mut claims = d.claims();
        adjust(&mut claims, &mut [], 0.05, MARGINS);
        let c = claims.iter().find(|c| c.id == "fusion_vs_lidar_only").unwrap();
        assert!((c.rows[0].test.estimate - 0.04).abs() < 1e-9);
        let reading = |label: &str| c.readings.iter().find(|r| r.reading.as_deref() == Some(label)).unwrap();
        // lf on the visible-only ground truth: 0.76 − 0.75.
        assert!((reading("visible-only ground truth").test.estimate - 0.01).abs() < 1e-9);
        // The paper's way: (0.74 + 0.66) / 2 − 0.70 = 0, and (0.76 + 0.80) / 2 − 0.75 = +0.03.
        let paper = reading("the paper's averaging (the mean of the fusion presets)");
        assert!(paper.test.estimate.abs() < 1e-9 && paper.b.len() == 2 && paper.paper == Some(0.031));
        let paper_vis = reading("the paper's averaging, visible-only ground truth");
        assert!((paper_vis.test.estimate - 0.03).abs() < 1e-9);
        // The readings' family: Holm over every reading of every claim.
        let raw: Vec<f64> = claims.iter().flat_map(|c| c.readings.iter().map(|r| r.test.p)).collect();
        let adj: Vec<f64> = claims.iter().flat_map(|c| c.readings.iter().map(|r| r.test.p_adjusted)).collect();
        assert!(holm(&raw).iter().zip(&adj).all(|(a, b)| a.to_bits() == b.to_bits()));
        // The claim's verdict is its own row's (lf beats cp by 0.04), whatever the readings say.
        assert_eq!(c.verdict, c.rows[0].verdict);
        // A rig comparison claim gets the visible-only reading but not the paper's averaging.
        let alone = claims.iter().find(|c| c.id == "vs_lidar_alone").unwrap();
        assert!(alone.readings.iter().all(|r| r.reading.as_deref() == Some("visible-only ground truth")));
        assert_eq!(alone.readings.len(), 2);
    }

    /// `det` with velocity errors (m/s): mAVE `mave` and car AVE 1.5 × `mave`.
    fn det_v(conf: &str, preset: &str, seed: u64, map: f64, mave: f64) -> DetectorScores {
        let mut d = det(conf, preset, seed, map);
        for (name, v) in [("mAVE", mave), ("car AVE", 1.5 * mave)] {
            let reps = (0..30).map(|r| v + 0.02 * ((r % 5) as f64 - 2.0) + 0.002 * seed as f64).collect();
            d.scores.insert(name.to_string(), Scores { full: v, replicates: reps });
        }
        d
    }

    /// The velocity claims favour the lower error: a fused detector whose mAVE is 0.9 m/s below
    /// the LiDAR-only one's is supported, one 0.9 above is contradicted, an equal one is
    /// equivalent within the velocity margin (m/s, not the mAP margin), and a velocity error
    /// that is not finite leaves its row out.
    #[test]
    fn velocity_claims_favour_the_lower_error() {
        let verdicts = |fused: f64, car_finite: bool| -> (Claim, Claim) {
            let mut scores = Vec::new();
            for s in 0..3 {
                let j = 0.004 * s as f64;
                scores.push(det_v("2x16+R", "cp", s, 0.70 + j, 1.5 + j));
                scores.push(det_v("2x16+R", "lf", s, 0.80 + j, fused + j));
                scores.push(det_v("2x16", "cp", s, 0.65 + j, 1.6 + j));
            }
            if !car_finite {
                scores[0].scores.get_mut("car AVE").unwrap().full = f64::NAN;
            }
            let configurations = vec![("2x16+R".to_string(), 10_000.0, 1), ("2x16".to_string(), 8_000.0, 0)];
            let roles = Roles::new(false);
            let d = roles.design(&scores, &configurations);
            let (mut claims, mut comps) = (d.claims(), d.comparisons());
            adjust(&mut claims, &mut comps, 0.05, MARGINS);
            let by = |id: &str| claims.iter().find(|c| c.id == id).unwrap().clone();
            (by("fusion_lowers_velocity_error"), by("radar_adds_velocity"))
        };
        let (same_rig, radar) = verdicts(0.6, true);
        assert_eq!(same_rig.rows.len(), 2);
        assert_eq!((same_rig.rows[0].metric.as_str(), same_rig.rows[1].metric.as_str()), ("mAVE", "car AVE"));
        assert!((same_rig.rows[0].test.estimate + 0.9).abs() < 1e-9, "{:?}", same_rig.rows[0].test);
        assert_eq!(same_rig.verdict, Verdict::Supported);
        assert_eq!(same_rig.rows[0].paper, None);
        assert_eq!(radar.rows[0].a, vec![("2x16".to_string(), "cp".to_string())]);
        assert!((radar.rows[0].test.estimate + 1.0).abs() < 1e-9);
        assert_eq!(radar.verdict, Verdict::Supported);
        assert_eq!(verdicts(2.4, true).0.verdict, Verdict::Contradicted);
        let (equal, _) = verdicts(1.5, true);
        assert_eq!(equal.verdict, Verdict::Equivalent, "{:?}", equal.rows[0]);
        assert!(equal.rows[0].tost_p < 0.05 && equal.rows[0].tost_p.is_finite());
        let (partial, _) = verdicts(0.6, false);
        assert_eq!(partial.rows.iter().map(|r| r.metric.as_str()).collect::<Vec<_>>(), ["mAVE"]);
    }

    /// A rig of two radars placed given the rig under study is judged as what the second radar
    /// adds (fused on both, accuracy and velocity), and takes none of the one-radar roles: the
    /// rig under study, the dearest radar rig and the mid-resolution one stay rigs of one radar,
    /// though it costs between them. Without the `given` link it is not tested.
    #[test]
    fn a_second_radar_is_judged_against_the_rig_it_was_placed_given() {
        let mut scores = Vec::new();
        for s in 0..3 {
            let j = 0.004 * s as f64;
            for (rig, cp, lf, v) in [
                ("2x16+R", 0.70, 0.72, 1.5),
                ("2x16+2R", 0.70, 0.75, 0.5),
                ("64+R", 0.60, 0.62, 1.5),
                ("2x16", 0.69, 0.0, 1.6),
            ] {
                scores.push(det_v(rig, "cp", s, cp + j, 1.6 + j));
                if lf > 0.0 {
                    scores.push(det_v(rig, "lf", s, lf + j, v + j));
                }
            }
        }
        let configurations = vec![
            ("2x16+R".to_string(), 10_000.0, 1),
            ("2x16+2R".to_string(), 12_000.0, 2),
            ("64+R".to_string(), 22_750.0, 1),
            ("2x16".to_string(), 8_000.0, 0),
        ];
        let mut roles = Roles::new(false);
        roles.given.insert("2x16+2R".into(), "2x16+R".into());
        let d = roles.design(&scores, &configurations);
        let claims = d.claims();
        let by = |id: &str| claims.iter().find(|c| c.id == id).unwrap().clone();
        let adds = by("second_radar_adds");
        assert_eq!(adds.rows[0].a, vec![("2x16+R".to_string(), "lf".to_string())]);
        assert_eq!(adds.rows[0].b, vec![("2x16+2R".to_string(), "lf".to_string())]);
        assert!((adds.rows[0].test.estimate - 0.03).abs() < 1e-9, "{:?}", adds.rows[0].test);
        let v = by("second_radar_velocity");
        assert!((v.rows[0].test.estimate + 1.0).abs() < 1e-9, "{:?}", v.rows[0].test);
        // Priced by what the second radar costs ($2,000), after the radar's own rows.
        let cost = |n: &str| configurations.iter().find(|c| c.0 == n).map(|c| c.1);
        let value = radar_value(&claims, &cost, 3);
        let first = value.iter().position(|v| v.second).unwrap();
        assert!(first > 0 && value[first..].iter().all(|v| v.second) && !value[..first].iter().any(|v| v.second));
        let priced: Vec<&ClaimRow> = adds.rows.iter().chain(&v.rows).collect();
        assert_eq!(value[first..].len(), priced.len());
        for (p, row) in value[first..].iter().zip(priced) {
            assert_eq!(
                (p.metric.as_str(), p.estimate, p.verdict),
                (row.metric.as_str(), row.test.estimate, row.verdict)
            );
            assert!((p.extra_cost_usd - 2000.0).abs() < 1e-9, "{p:?}");
            assert!((p.per_1000_usd.unwrap() - row.test.estimate / 2.0).abs() < 1e-12, "{p:?}");
        }
        assert!(value[..first].iter().all(|p| (p.extra_cost_usd - 2000.0).abs() < 1e-9 && p.condition.is_none()));
        // The one-radar roles: the rig under study is still 2x16+R, the dearest 64+R, and no
        // mid-resolution radar rig is left for the pooled claim.
        assert!(by("vs_lidar_radar").rows.iter().all(|r| r.a.iter().all(|(c, _)| c == "64+R")));
        assert!(by("vs_mid_lidar_radar").not_tested.is_some());
        assert!(by("radar_adds").rows[0].b.iter().all(|(c, _)| c == "2x16+R"));
        // Rigs of several radars alone (budgeted ones, say) take the radar roles.
        let several = vec![("2x16+2R".to_string(), 12_000.0, 2), ("2x16".to_string(), 8_000.0, 0)];
        let d = roles.design(&scores, &several);
        let c = d.claims().into_iter().find(|c| c.id == "radar_adds").unwrap();
        assert!(c.rows[0].b.iter().all(|(r, _)| r == "2x16+2R"), "{:?}", c.rows);
        // Without the link the two-radar rig compares nothing.
        roles.given.clear();
        let d = roles.design(&scores, &configurations);
        let claims = d.claims();
        let c = claims.iter().find(|c| c.id == "second_radar_adds").unwrap();
        assert!(c.rows.is_empty() && c.not_tested.as_deref().is_some_and(|m| m.contains("given")));
    }

    /// A weather condition's configurations are judged apart: the study's claims and
    /// comparisons read the configurations in its own weather only (a fog copy of the cheap rig
    /// costs the same and is never taken for it), and each condition gets the radar's claims
    /// again on its own configurations, ids ending in `@<condition>`.
    #[test]
    fn conditions_are_judged_on_their_own_configurations() {
        let mut scores = Vec::new();
        for s in 0..3 {
            let j = 0.004 * s as f64;
            for (rig, cp, lf) in [("2x16+R", 0.70, 0.72), ("2x16+R in fog", 0.40, 0.60)] {
                scores.push(det_v(rig, "cp", s, cp + j, 1.5 + j));
                scores.push(det_v(rig, "lf", s, lf + j, 0.5 + j));
            }
            scores.push(det_v("2x16", "cp", s, 0.69 + j, 1.6 + j));
            scores.push(det_v("2x16 in fog", "cp", s, 0.35 + j, 1.7 + j));
            scores.push(det_v("64", "cp", s, 0.60 + j, 1.6 + j));
        }
        let configurations = vec![
            ("2x16+R".to_string(), 10_000.0, 1),
            ("64".to_string(), 20_750.0, 0),
            ("2x16".to_string(), 8_000.0, 0),
            ("2x16+R in fog".to_string(), 10_000.0, 1),
            ("2x16 in fog".to_string(), 8_000.0, 0),
        ];
        let mut roles = Roles::new(false);
        roles.conditions = BTreeMap::from([
            ("2x16+R in fog".to_string(), "fog".to_string()),
            ("2x16 in fog".to_string(), "fog".to_string()),
        ]);
        let d = roles.design(&scores, &configurations);
        let (mut claims, mut comps) = (d.claims(), d.comparisons());
        adjust(&mut claims, &mut comps, 0.05, MARGINS);
        let by = |id: &str| claims.iter().find(|c| c.id == id).unwrap();
        // The study's own claims never name a fog configuration.
        for c in claims.iter().filter(|c| c.condition.is_none()) {
            for r in &c.rows {
                assert!(r.a.iter().chain(&r.b).all(|(conf, _)| !conf.contains("fog")), "{}: {:?}", c.id, r);
            }
        }
        assert!(comps.iter().all(|c| !c.a.contains("fog") && !c.b.contains("fog")));
        assert!((by("fusion_vs_lidar_only").rows[0].test.estimate - 0.02).abs() < 1e-9);
        assert!((by("radar_adds").rows[0].test.estimate - 0.03).abs() < 1e-9);
        // In fog: the condition's claims, on its configurations, with their own estimates.
        let fog: Vec<&str> =
            claims.iter().filter(|c| c.condition.as_deref() == Some("fog")).map(|c| c.id.as_str()).collect();
        assert_eq!(fog, CONDITION_CLAIMS.iter().map(|id| format!("{id}@fog")).collect::<Vec<_>>());
        let f = by("fusion_vs_lidar_only@fog");
        assert!(f.statement.ends_with(", in fog"));
        assert_eq!(f.rows[0].a, vec![("2x16+R in fog".to_string(), "cp".to_string())]);
        assert!((f.rows[0].test.estimate - 0.20).abs() < 1e-9);
        assert_eq!(f.verdict, Verdict::Supported);
        let r = by("radar_adds@fog");
        assert_eq!(r.rows[0].a, vec![("2x16 in fog".to_string(), "cp".to_string())]);
        assert!((r.rows[0].test.estimate - 0.25).abs() < 1e-9);
        assert!((by("radar_adds_velocity@fog").rows[0].test.estimate + 1.2).abs() < 1e-9);
    }

    /// Detectors of `groups` groups (A, B = A + `effect`, and others that only feed the pooled
    /// variance) trained on `draws` training-traffic draws of `seeds` seeds each: scores over 20
    /// scenes with a shared scene effect, an arm-by-scene effect, a traffic effect per (group,
    /// draw), a seed effect and per-scene noise; full scores and bootstrap replicates.
    fn drawn_study(
        rng: &mut rand_chacha::ChaCha8Rng,
        effect: f64,
        (draws, seeds, groups): (u64, u64, usize),
        (sd_traffic, sd_seed): (f64, f64),
        boot: &[Vec<u32>],
    ) -> Vec<DetectorScores> {
        use rand_distr::{Distribution, Normal};
        let n = Normal::new(0.0, 1.0).unwrap();
        let scene: Vec<f64> = (0..20).map(|_| 0.05 * n.sample(rng)).collect();
        let mut out = Vec::new();
        for g in 0..groups {
            let shift = if g == 1 { effect } else { 0.0 };
            let own: Vec<f64> = (0..20).map(|_| 0.01 * n.sample(rng)).collect();
            for draw in 0..draws {
                let u = sd_traffic * n.sample(rng);
                for seed in 0..seeds {
                    let e = sd_seed * n.sample(rng);
                    let x: Vec<f64> =
                        (0..20).map(|k| 0.6 + shift + u + e + scene[k] + own[k] + 0.01 * n.sample(rng)).collect();
                    let score = |w: &[u32]| {
                        let tot: f64 = w.iter().map(|&c| c as f64).sum();
                        x.iter().zip(w).map(|(v, &c)| v * c as f64).sum::<f64>() / tot
                    };
                    let s = Scores { full: score(&[1; 20]), replicates: boot.iter().map(|w| score(w)).collect() };
                    out.push(DetectorScores {
                        configuration: format!("g{g}"),
                        preset: "p".into(),
                        seed,
                        draw,
                        scores: BTreeMap::from([("mAP".to_string(), s)]),
                    });
                }
            }
        }
        out
    }

    fn group_test(scores: &[DetectorScores], effect: f64) -> (Test, bool) {
        let side = |g: &str| scores.iter().filter(|d| d.configuration == g).map(|d| &d.scores["mAP"]).collect();
        let mut groups: BTreeMap<&str, Vec<&Scores>> = BTreeMap::new();
        for d in scores {
            groups.entry(&d.configuration).or_default().push(&d.scores["mAP"]);
        }
        let sv = pooled_seed_variance(&groups.into_values().collect::<Vec<_>>());
        let (a, b): (Vec<&Scores>, Vec<&Scores>) = (side("g0"), side("g1"));
        let t = compare(&a, &b, sv, 20, 0.95);
        let covered = t.lo <= effect && effect <= t.hi;
        (t, covered)
    }

    /// A draw's replicate is the mean of its seeds, exactly; one draw leaves the detectors as
    /// they are; the traffic component is recovered from many groups (method of moments).
    #[test]
    fn draw_units_average_seeds_and_recover_the_traffic_component() {
        let boot = hilo_plan::gt::scene_draws(20, 50, 1);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let one = drawn_study(&mut rng, 0.0, (1, 3, 4), (0.0, 0.01), &boot);
        assert_eq!(draw_units(&one), one);
        assert!(draw_variance(&one, "mAP").is_none());
        let two = drawn_study(&mut rng, 0.0, (2, 3, 400), (0.02, 0.01), &boot);
        let units = draw_units(&two);
        assert_eq!(units.len(), 800);
        let u = units.iter().find(|d| d.configuration == "g5" && d.draw == 1).unwrap();
        let mine: Vec<&DetectorScores> = two.iter().filter(|d| d.configuration == "g5" && d.draw == 1).collect();
        let full = mine.iter().map(|d| d.scores["mAP"].full).sum::<f64>() / 3.0;
        let rep7 = mine.iter().map(|d| d.scores["mAP"].replicates[7]).sum::<f64>() / 3.0;
        assert!((u.scores["mAP"].full - full).abs() < 1e-12 && (u.scores["mAP"].replicates[7] - rep7).abs() < 1e-12);
        let dv = draw_variance(&two, "mAP").unwrap();
        assert_eq!((dv.draws, dv.seeds, dv.seed.df, dv.draw_means.df), (2, 3, 1600, 400));
        let (traffic, seed) = (dv.traffic.sqrt(), dv.seed.variance.sqrt());
        eprintln!("traffic sd {traffic:.4} (planted 0.02), seed sd {seed:.4} (planted 0.01 plus scene noise)");
        assert!((0.017..0.023).contains(&traffic), "traffic sd {traffic}");
    }

    /// Coverage of the 95% interval when the training traffic moves detectors more than their
    /// seeds do (two draws of two seeds, 20 groups): with the draw as the replicate the interval
    /// covers the planted effect in 93–97% of 1,000 synthetic studies; counting the four
    /// detectors of a group as independent seeds (what a study without draws would do, were
    /// its detectors trained on different traffic) misses the band.
    #[test]
    fn the_draw_as_random_effect_keeps_coverage_when_traffic_varies() {
        let boot = hilo_plan::gt::scene_draws(20, 200, 2);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let (effect, trials) = (0.03, 1000);
        let (mut units_in, mut naive_in) = (0usize, 0usize);
        for _ in 0..trials {
            let study = drawn_study(&mut rng, effect, (2, 2, 20), (0.02, 0.005), &boot);
            units_in += usize::from(group_test(&draw_units(&study), effect).1);
            naive_in += usize::from(group_test(&study, effect).1);
        }
        let (cov, naive) = (units_in as f64 / trials as f64, naive_in as f64 / trials as f64);
        eprintln!("coverage with the draw as replicate {cov:.3}; draws ignored {naive:.3}");
        assert!((0.93..=0.97).contains(&cov), "coverage {cov}");
        assert!(naive < 0.90, "ignoring the draws should undercover: {naive}");
    }
}
