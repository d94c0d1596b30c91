//! From every trained detector's scores to the study's verdict: comparisons between rigs, the
//! paper's claims answered one by one, the test's calibration, and the learning curves.

use crate::stats::{Scores, SeedVariance, Test, compare, holm, pooled_seed_variance, test};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The metrics a verdict compares.
pub const METRICS: [&str; 2] = ["mAP", "pedestrian AP"];

/// One trained detector's scores on the common ground truth, per metric.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DetectorScores {
    pub configuration: String,
    pub preset: String,
    pub seed: u64,
    /// By metric name ([`METRICS`]).
    pub scores: BTreeMap<String, Scores>,
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
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Significant (Holm-adjusted p < 0.05) in the paper's direction.
    Supported,
    /// Significant against it.
    Contradicted,
    /// Not significant, or not estimable.
    Undecided,
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
}

/// The test's measured calibration in this study.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Calibration {
    pub alpha: f64,
    /// A/A comparisons: two seeds of one (configuration, preset) group, and the LiDAR-only
    /// preset on the two rigs that see the same LiDAR data.
    pub pairs: usize,
    pub false_positives: usize,
    pub false_positive_rate: f64,
    /// A planted degradation (a share of every box dropped) against the undegraded seeds.
    pub planted_drop_share: f64,
    pub planted_pairs: usize,
    pub planted_mean_effect: f64,
    pub power: f64,
    /// The pooled seed variance behind every test, per metric.
    pub seed_variance: BTreeMap<String, SeedVariance>,
}

/// A detector's mAP at points of its training (seed 0).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Curve {
    pub configuration: String,
    pub preset: String,
    /// (samples seen, mAP on the common ground truth).
    pub points: Vec<(usize, f64)>,
    /// mAP gained over the last doubling of training (the last point against the one at half).
    pub gain_last_doubling: f64,
}

/// Everything the verdict needs about the study's design.
#[derive(Debug)]
pub struct Design<'a> {
    pub scores: &'a [DetectorScores],
    /// Configurations with cost and whether they have a radar.
    pub configurations: &'a [(String, f64, bool)],
    /// Presets trained on every configuration, in order; and ablations (cheapest only).
    pub presets: &'a [String],
    pub ablations: &'a [String],
    /// The preset each ablation ablates (as its plugin registered it).
    pub ablation_of: &'a BTreeMap<String, String>,
    /// Which presets read radar.
    pub uses_radar: &'a BTreeMap<String, bool>,
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
        let mut groups: BTreeMap<(&str, &str), Vec<f64>> = BTreeMap::new();
        for d in self.scores {
            if let Some(s) = d.scores.get(metric) {
                groups.entry((&d.configuration, &d.preset)).or_default().push(s.full);
            }
        }
        pooled_seed_variance(&groups.into_values().collect::<Vec<_>>())
    }

    fn cmp(&self, metric: &str, (ca, pa): (&str, &str), (cb, pb): (&str, &str)) -> Option<Test> {
        let (a, b) = (self.seeds(ca, pa, metric), self.seeds(cb, pb, metric));
        (!a.is_empty() && !b.is_empty()).then(|| compare(&a, &b, self.seed_variance(metric), self.scenes, self.level))
    }

    /// The cheapest configuration with a radar, the dearest with a radar, the dearest without.
    fn roles(&self) -> (Option<&str>, Option<&str>, Option<&str>) {
        let by_cost = |radar: bool| {
            let mut v: Vec<&(String, f64, bool)> = self.configurations.iter().filter(|c| c.2 == radar).collect();
            v.sort_by(|a, b| a.1.total_cmp(&b.1));
            v
        };
        let radar = by_cost(true);
        let lidar = by_cost(false);
        (radar.first().map(|c| c.0.as_str()), radar.last().map(|c| c.0.as_str()), lidar.last().map(|c| c.0.as_str()))
    }

    fn fusion_and_lidar(&self) -> (Option<&str>, Option<&str>) {
        let f = self.presets.iter().find(|p| self.uses_radar.get(*p).copied().unwrap_or(false));
        let l = self.presets.iter().find(|p| !self.uses_radar.get(*p).copied().unwrap_or(true));
        (f.map(String::as_str), l.map(String::as_str))
    }

    /// The cheapest configuration against every other one, per preset and metric.
    pub fn comparisons(&self) -> Vec<Comparison> {
        let mut out = Vec::new();
        let Some(cheap) = self.configurations.iter().min_by(|a, b| a.1.total_cmp(&b.1)) else { return out };
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

    /// The paper's claims, each as B − A in the paper's favoured direction.
    pub fn claims(&self) -> Vec<Claim> {
        let (cheap, dear_radar, lidar_alone) = self.roles();
        let (fusion, lidar) = self.fusion_and_lidar();
        let mut claims = Vec::new();
        let row = |metric: &str, what: String, paper: Option<f64>, t: Test| ClaimRow {
            metric: metric.into(),
            comparison: what,
            paper,
            test: t,
            verdict: Verdict::Undecided,
        };
        let claim = |id: &str, statement: &str, rows: Vec<ClaimRow>, missing: Option<String>| Claim {
            id: id.into(),
            statement: statement.into(),
            rows,
            verdict: Verdict::Undecided,
            not_tested: missing,
            per_preset: BTreeMap::new(),
        };
        // 1. Low-resolution LiDAR + radar against a high-resolution LiDAR alone.
        let c1 = match (cheap, lidar_alone, fusion, lidar) {
            (Some(c), Some(l), Some(f), Some(lp)) => {
                let rows = [("mAP", Some(0.015)), ("pedestrian AP", Some(0.14))]
                    .iter()
                    .filter_map(|(m, paper)| {
                        self.cmp(m, (l, lp), (c, f)).map(|t| row(m, format!("{f} on {c} − {lp} on {l}"), *paper, t))
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
        // 2. Against the high-resolution LiDAR with the same radar, same detector (pooled).
        let st2 = "Two cheap LiDARs and a radar beat one high-resolution LiDAR and a radar with the same detector";
        let c2 = match (cheap, dear_radar) {
            (Some(c), Some(d)) if c != d => {
                let rows = [("mAP", Some(0.015)), ("pedestrian AP", None)]
                    .iter()
                    .filter_map(|(m, paper)| {
                        self.pooled(m, d, c).map(|(t, _)| row(m, format!("{c} − {d}, mean over presets"), *paper, t))
                    })
                    .collect();
                claim("vs_lidar_radar", st2, rows, None)
            }
            _ => claim("vs_lidar_radar", st2, vec![], Some("needs two configurations with radar".into())),
        };
        claims.push(c2);
        // 3. Fusion against LiDAR only on the same (cheapest) rig.
        let st3 = "Fusing radar beats the LiDAR-only detector on the same rig";
        let c3 = match (cheap, fusion, lidar) {
            (Some(c), Some(f), Some(lp)) => {
                let rows = self
                    .cmp("mAP", (c, lp), (c, f))
                    .map(|t| row("mAP", format!("{f} − {lp} on {c}"), Some(0.031), t))
                    .into_iter()
                    .collect();
                claim("fusion_vs_lidar_only", st3, rows, None)
            }
            _ => claim("fusion_vs_lidar_only", st3, vec![], Some("needs a fusion and a LiDAR-only preset".into())),
        };
        claims.push(c3);
        // 4. The early-fusion ablation.
        let st4 = "Early fusion helps: the detector with it beats the same detector without it";
        let ablation = fusion
            .and_then(|f| self.ablations.iter().find(|a| self.ablation_of.get(*a).is_some_and(|of| of == f)).cloned());
        let c4 = match (cheap, fusion, ablation) {
            (Some(c), Some(f), Some(a)) => {
                let rows = self
                    .cmp("mAP", (c, &a), (c, f))
                    .map(|t| row("mAP", format!("{f} − {a} on {c}"), Some(0.009), t))
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
        // 5. Whichever module: the cheap rig's advantage over the dear radar rig, per preset.
        let st5 = "The cheap rig's advantage holds whichever detector module is used";
        let c5 = match (cheap, dear_radar) {
            (Some(c), Some(d)) if c != d => match self.pooled("mAP", d, c) {
                Some((t, per)) => {
                    let mut cl = claim(
                        "whichever_module",
                        st5,
                        vec![row("mAP", format!("{c} − {d}, mean over presets"), Some(0.015), t)],
                        None,
                    );
                    cl.per_preset = per;
                    cl
                }
                None => claim("whichever_module", st5, vec![], Some("no preset ran on both configurations".into())),
            },
            _ => claim("whichever_module", st5, vec![], Some("needs two configurations with radar".into())),
        };
        claims.push(c5);
        claims
    }

    /// B − A averaged over the presets that ran on both, paired by preset and seed structure;
    /// and each preset's own difference.
    fn pooled(&self, metric: &str, a: &str, b: &str) -> Option<(Test, BTreeMap<String, f64>)> {
        let mut wa = Vec::new();
        let mut wb = Vec::new();
        let mut seed_term = 0.0;
        let mut per = BTreeMap::new();
        let presets: Vec<&String> = self
            .presets
            .iter()
            .filter(|p| !self.seeds(a, p, metric).is_empty() && !self.seeds(b, p, metric).is_empty())
            .collect();
        let n = presets.len() as f64;
        for p in &presets {
            let (sa, sb) = (self.seeds(a, p, metric), self.seeds(b, p, metric));
            per.insert(
                (*p).clone(),
                mean(&sb.iter().map(|s| s.full).collect::<Vec<_>>())
                    - mean(&sa.iter().map(|s| s.full).collect::<Vec<_>>()),
            );
            for s in &sa {
                wa.push((*s, 1.0 / (n * sa.len() as f64)));
            }
            for s in &sb {
                wb.push((*s, 1.0 / (n * sb.len() as f64)));
            }
            seed_term += (1.0 / sa.len() as f64 + 1.0 / sb.len() as f64) / (n * n);
        }
        (!presets.is_empty())
            .then(|| (test(&wa, &wb, self.seed_variance(metric), seed_term, self.scenes, self.level), per))
    }

    /// A/A pairs: for every group, each pair of its seeds; for the LiDAR-only preset on the
    /// two rigs with the same LiDAR (the dearest with and without radar), seed against seed.
    pub fn aa_pairs(&self) -> Vec<Test> {
        let metric = "mAP";
        let sv = self.seed_variance(metric);
        let mut out = Vec::new();
        let mut groups: BTreeMap<(&str, &str), Vec<&Scores>> = BTreeMap::new();
        for d in self.scores {
            if let Some(s) = d.scores.get(metric) {
                groups.entry((&d.configuration, &d.preset)).or_default().push(s);
            }
        }
        for seeds in groups.values() {
            for i in 0..seeds.len() {
                for j in i + 1..seeds.len() {
                    out.push(compare(&[seeds[i]], &[seeds[j]], sv, self.scenes, self.level));
                }
            }
        }
        let (_, dear_radar, lidar_alone) = self.roles();
        let (_, lidar) = self.fusion_and_lidar();
        if let (Some(d), Some(l), Some(lp)) = (dear_radar, lidar_alone, lidar) {
            let (a, b) = (self.seeds(l, lp, metric), self.seeds(d, lp, metric));
            for (x, y) in a.iter().zip(&b) {
                out.push(compare(&[*x], &[*y], sv, self.scenes, self.level));
            }
        }
        out
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Holm-adjusts a family of tests (claims' rows and comparisons together) and sets each claim
/// row's and claim's verdict: supported when every row is significant in the paper's favoured
/// direction (B − A > 0), contradicted when one is significant against it, undecided otherwise.
pub fn adjust(claims: &mut [Claim], comparisons: &mut [Comparison], alpha: f64) {
    let mut p: Vec<f64> = claims.iter().flat_map(|c| c.rows.iter().map(|r| r.test.p)).collect();
    p.extend(comparisons.iter().map(|c| c.test.p));
    let adj = holm(&p);
    let mut k = 0;
    for c in claims.iter_mut() {
        for r in &mut c.rows {
            r.test.p_adjusted = adj[k];
            k += 1;
            r.verdict = if !(r.test.estimable && r.test.p_adjusted < alpha) {
                Verdict::Undecided
            } else if r.test.estimate > 0.0 {
                Verdict::Supported
            } else {
                Verdict::Contradicted
            };
        }
        c.verdict = if c.rows.is_empty() {
            Verdict::Undecided
        } else if c.rows.iter().any(|r| r.verdict == Verdict::Contradicted) {
            Verdict::Contradicted
        } else if c.rows.iter().all(|r| r.verdict == Verdict::Supported) && c.per_preset.values().all(|d| *d > 0.0) {
            Verdict::Supported
        } else {
            Verdict::Undecided
        };
    }
    for c in comparisons.iter_mut() {
        c.test.p_adjusted = adj[k];
        k += 1;
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn det(conf: &str, preset: &str, seed: u64, map: f64) -> DetectorScores {
        // 30 replicates that move every detector together (the same scenes drawn), plus a little.
        let reps = (0..30).map(|r| map + 0.01 * ((r % 7) as f64 - 3.0) + 0.001 * seed as f64).collect();
        let s = Scores { full: map, replicates: reps };
        DetectorScores {
            configuration: conf.into(),
            preset: preset.into(),
            seed,
            scores: BTreeMap::from([("mAP".to_string(), s.clone()), ("pedestrian AP".to_string(), s)]),
        }
    }

    #[test]
    fn claims_follow_the_roles_and_a_clear_gap_is_supported() {
        let mut scores = Vec::new();
        for s in 0..3 {
            let j = 0.004 * s as f64;
            scores.push(det("2x16+R", "cp", s, 0.70 + j));
            scores.push(det("2x16+R", "lf", s, 0.80 + j));
            scores.push(det("2x16+R", "lf-no-early", s, 0.70 + j));
            scores.push(det("64", "cp", s, 0.60 + j));
            scores.push(det("64+R", "cp", s, 0.60 + j));
            scores.push(det("64+R", "lf", s, 0.62 + j));
        }
        let configurations = vec![
            ("2x16+R".to_string(), 10_000.0, true),
            ("64".to_string(), 20_750.0, false),
            ("64+R".to_string(), 22_750.0, true),
        ];
        let uses =
            BTreeMap::from([("cp".to_string(), false), ("lf".to_string(), true), ("lf-no-early".to_string(), true)]);
        let presets = vec!["cp".to_string(), "lf".to_string()];
        let ablations = vec!["lf-no-early".to_string()];
        let ablation_of = BTreeMap::from([("lf-no-early".to_string(), "lf".to_string())]);
        let d = Design {
            scores: &scores,
            configurations: &configurations,
            presets: &presets,
            ablations: &ablations,
            ablation_of: &ablation_of,
            uses_radar: &uses,
            scenes: 20,
            level: 0.95,
        };
        let mut claims = d.claims();
        let mut comps = d.comparisons();
        adjust(&mut claims, &mut comps, 0.05);
        assert_eq!(claims.len(), 5);
        let by = |id: &str| claims.iter().find(|c| c.id == id).unwrap();
        // lf on 2x16+R (0.804) against cp on 64 (0.604).
        assert!((by("vs_lidar_alone").rows[0].test.estimate - 0.2).abs() < 1e-9);
        assert_eq!(by("vs_lidar_alone").verdict, Verdict::Supported);
        // Pooled over cp and lf: (0.704 − 0.604 + 0.804 − 0.624) / 2 = 0.14.
        assert!((by("vs_lidar_radar").rows[0].test.estimate - 0.14).abs() < 1e-9);
        assert_eq!(by("whichever_module").per_preset.len(), 2);
        assert_eq!(by("early_fusion_ablation").verdict, Verdict::Supported);
        // Every adjusted p is at least the raw one.
        assert!(comps.iter().all(|c| c.test.p_adjusted >= c.test.p - 1e-15));
        // A/A: 6 groups × 3 pairs, and cp on 64 against cp on 64+R seed by seed.
        assert_eq!(d.aa_pairs().len(), 6 * 3 + 3);
    }
}
