//! One comparison across a sweep's studies ([`hilo_plan::sweep`]): `comparison.md` and
//! `comparison.json` beside the studies' folders, made from their `report.json` files only.
//!
//! Each study keeps its own verdict (its own traffic, validation scenes, seeds, calibration).
//! Across them, a claim is *supported at every site* only when every study supports it: an
//! intersection–union test, valid at the studies' own level with no further correction, and the
//! question a buyer with several intersections asks. A claim supported at one site and
//! contradicted at another *depends on the site*. Nothing is pooled across sites: scenes and
//! catalogs differ on purpose, so an average over them answers no one's question.

use crate::assemble::Report;
use crate::report::{esc, verdict_word};
use crate::verdict::Verdict;
use hilo_core::fs::{limit, read_json, write_atomic, write_json};
use hilo_plan::charts::dollars;
use hilo_plan::error::{Result, StudyError};
use hilo_plan::plan::FolderRecord;
use hilo_plan::sweep::{ShardRecord, Sweep, SweepRecord};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Comparison {
    /// The sweep's study file or directory.
    pub sweep: String,
    pub profile: String,
    pub shards: Vec<ShardSummary>,
    /// Every configuration any study holds, in order of first appearance.
    pub configurations: Vec<ConfigAcross>,
    /// Per preset, the configuration with the highest mean mAP in each study (in the study's
    /// own weather: a rig recorded again in a condition is not a rig to buy).
    pub leaders: Vec<Leader>,
    /// Per preset and budget, the best configuration each study holds within the budget.
    #[serde(default)]
    pub budgets: Vec<BudgetBest>,
    pub claims: Vec<ClaimAcross>,
    /// Per study and metric, what the radar adds (the `radar_adds` claim) and per $1,000 it
    /// costs: the radar's marginal value per condition when the sweep is over weathers.
    #[serde(default)]
    pub radar_worth: Vec<RadarWorth>,
}

/// What a radar adds in one study (in its own weather or one of its conditions), for one
/// metric: the study's name beside its report's [`crate::verdict::RadarValue`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RadarWorth {
    pub study: String,
    #[serde(flatten)]
    pub value: crate::verdict::RadarValue,
}

/// The `radar_adds` rows (accuracy) and `radar_adds_velocity` rows (velocity error) of each
/// study and each of its weather conditions, priced by the configurations they compare
/// ([`crate::verdict::radar_value`]).
fn radar_worth(reports: &[(ShardRecord, Report)]) -> Vec<RadarWorth> {
    let mut out = Vec::new();
    for (s, r) in reports {
        let cost = |name: &str| r.configurations.iter().find(|c| c.name == name).map(|c| c.cost_usd);
        out.extend(
            crate::verdict::radar_value(&r.claims, &cost, crate::assemble::replicates(&r.profile))
                .into_iter()
                .map(|value| RadarWorth { study: s.name.clone(), value }),
        );
    }
    out
}

/// The comparison's cell for the design that would find
/// [`RADAR_TARGET_MDE`](crate::verdict::RADAR_TARGET_MDE): "–" for a velocity error, "reached"
/// when the study's own MDE is at most the target.
fn design_cell(w: &crate::verdict::RadarValue) -> String {
    if crate::verdict::lower_is_better(&w.metric) || !w.mde.is_finite() {
        return "–".into();
    }
    if w.mde <= crate::verdict::RADAR_TARGET_MDE {
        return "reached".into();
    }
    match &w.design {
        Some(d) => format!("{} replicates, {} scenes (MDE {:.3})", d.replicates, d.val_scenes, d.mde),
        None => format!(
            "out of reach within {} replicates and {} scenes",
            crate::stats::MAX_DESIGN_REPLICATES,
            crate::stats::MAX_DESIGN_SCENES
        ),
    }
}

/// One study of the sweep: its design and its test's measured calibration.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ShardSummary {
    pub name: String,
    pub scene: Option<PathBuf>,
    pub catalog: Option<PathBuf>,
    pub ground_truth: String,
    pub validation_scenes: usize,
    pub seeds: usize,
    pub calibration_pairs: usize,
    pub false_positive_rate: f64,
    pub power: f64,
}

pub use crate::stats::OverSeeds;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ConfigAcross {
    pub name: String,
    /// By study name; absent where the study does not hold the configuration.
    pub at: BTreeMap<String, ConfigAt>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ConfigAt {
    pub cost_usd: f64,
    pub central_coverage: f64,
    /// Share of the common ground truth no sensor of the rig hit.
    pub unseen_share: f64,
    /// By preset: mAP and pedestrian AP over seeds, on the common ground truth.
    pub map: BTreeMap<String, OverSeeds>,
    pub pedestrian_ap: BTreeMap<String, OverSeeds>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Leader {
    pub preset: String,
    pub at: BTreeMap<String, Lead>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Lead {
    pub configuration: String,
    pub mean_ap: f64,
    pub runner_up: Option<String>,
    /// Mean mAP over the runner-up's.
    pub margin: f64,
    /// Whether the study's own test (Holm-adjusted) separates the two; None when its report
    /// does not compare them.
    pub significant: Option<bool>,
}

/// The best configuration within one budget for one preset, per study: what a buyer with this
/// much to spend gets at each site. The budgets are the costs of the sweep's configurations, so
/// each one is where a rig first becomes affordable.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BudgetBest {
    pub preset: String,
    pub budget_usd: f64,
    /// By study name: its best configuration costing at most the budget, against its next best
    /// within the budget; absent where the study holds none.
    pub at: BTreeMap<String, Lead>,
    /// The configuration that is best within the budget at every study of the sweep; None when
    /// the studies differ or one of them holds none within the budget.
    pub everywhere: Option<String>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClaimAcross {
    pub id: String,
    pub statement: String,
    /// By study name.
    pub at: BTreeMap<String, ClaimAt>,
    pub across: Across,
    /// Which studies gave which verdict.
    pub why: String,
    /// Each of the claim's metrics on its own across the sweep (a claim is supported at a site
    /// only when all its metrics are, so a metric can hold everywhere while its claim does not).
    pub metrics: Vec<MetricAcross>,
}

/// One metric of a claim across a sweep: its verdict at each study, combined as a claim's.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MetricAcross {
    pub metric: String,
    pub across: Across,
    /// Which studies gave which verdict.
    pub why: String,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClaimAt {
    /// None: the study could not test it (a configuration or preset missing).
    pub verdict: Option<Verdict>,
    pub rows: Vec<RowAt>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RowAt {
    pub metric: String,
    /// The row's own verdict in its study (Holm-adjusted there).
    pub verdict: Verdict,
    pub estimate: f64,
    pub lo: f64,
    pub hi: f64,
    pub p_adjusted: f64,
    pub estimable: bool,
}

/// A claim's verdict across a sweep.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Across {
    /// Every study supports it.
    SupportedEverywhere,
    /// Every study contradicts it.
    ContradictedEverywhere,
    /// Supported in some studies and contradicted in others.
    DependsOnSite,
    /// Anything else: some study is undecided or could not test it, and none contradicts a
    /// support elsewhere.
    Undecided,
    /// No study could test it.
    NotTested,
}

impl Across {
    /// The verdict across studies from each one's (None: not tested).
    pub fn of(verdicts: &[Option<Verdict>]) -> Across {
        let all = |v: Verdict| verdicts.iter().all(|x| *x == Some(v));
        let any = |v: Verdict| verdicts.contains(&Some(v));
        if verdicts.iter().all(Option::is_none) {
            Across::NotTested
        } else if all(Verdict::Supported) {
            Across::SupportedEverywhere
        } else if all(Verdict::Contradicted) {
            Across::ContradictedEverywhere
        } else if any(Verdict::Supported) && any(Verdict::Contradicted) {
            Across::DependsOnSite
        } else {
            Across::Undecided
        }
    }

    pub fn words(self) -> &'static str {
        match self {
            Across::SupportedEverywhere => "supported at every site",
            Across::ContradictedEverywhere => "contradicted at every site",
            Across::DependsOnSite => "depends on the site",
            Across::Undecided => "undecided",
            Across::NotTested => "not tested",
        }
    }
}

/// Reads the sweep in `out` (its `sweep.json` and every study's `report.json`, each checked to
/// hold the study the sweep recorded) and compares the studies.
pub fn compare(out: &Path) -> Result<Comparison> {
    let record = SweepRecord::read(out)?;
    let mut reports = Vec::new();
    for s in &record.shards {
        let dir = Sweep::shard_out(out, &s.name);
        let folder = FolderRecord::read(&dir)?;
        if folder.fingerprint != s.fingerprint {
            return Err(StudyError::folder(
                dir.join("study.json"),
                format!(
                    "holds study fingerprint {}, the sweep recorded {}; rerun the sweep into a new folder",
                    folder.fingerprint, s.fingerprint
                ),
            ));
        }
        let path = dir.join("report.json");
        if !path.exists() {
            return Err(StudyError::NotReady {
                path,
                what: "missing".into(),
                remedy: format!("run the study's report stage first (`hilo study report --out {}`)", dir.display()),
            });
        }
        reports.push((s.clone(), read_json::<Report>(&path, limit::TABLE)?));
    }
    Ok(build(&record, &reports))
}

/// The comparison of already-read reports, in the sweep's order.
pub fn build(record: &SweepRecord, reports: &[(ShardRecord, Report)]) -> Comparison {
    let shards = reports
        .iter()
        .map(|(s, r)| ShardSummary {
            name: s.name.clone(),
            scene: s.scene.clone(),
            catalog: s.catalog.clone(),
            ground_truth: r.ground_truth.clone(),
            validation_scenes: r.validation_scenes,
            seeds: r.seeds,
            calibration_pairs: r.calibration.pairs,
            false_positive_rate: r.calibration.false_positive_rate,
            power: r.calibration.power,
        })
        .collect();
    let mut configurations: Vec<ConfigAcross> = Vec::new();
    let mut presets: Vec<String> = Vec::new();
    for (s, r) in reports {
        for c in &r.configurations {
            let mut at = ConfigAt {
                cost_usd: c.cost_usd,
                central_coverage: c.central_coverage,
                unseen_share: c.unseen_share,
                map: BTreeMap::new(),
                pedestrian_ap: BTreeMap::new(),
            };
            let mut groups: BTreeMap<&str, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
            for e in r.entries.iter().filter(|e| e.configuration == c.name) {
                let g = groups.entry(e.preset.as_str()).or_default();
                g.0.push(e.mean_ap);
                if let Some(Some(p)) = e.class_ap.get("pedestrian") {
                    g.1.push(*p);
                }
                if !presets.contains(&e.preset) {
                    presets.push(e.preset.clone());
                }
            }
            for (p, (m, ped)) in groups {
                if let Some(o) = OverSeeds::of(&m) {
                    at.map.insert(p.to_owned(), o);
                }
                if let Some(o) = OverSeeds::of(&ped) {
                    at.pedestrian_ap.insert(p.to_owned(), o);
                }
            }
            match configurations.iter_mut().find(|x| x.name == c.name) {
                Some(x) => {
                    x.at.insert(s.name.clone(), at);
                }
                None => configurations.push(ConfigAcross { name: c.name.clone(), at: [(s.name.clone(), at)].into() }),
            }
        }
    }
    // Each study's rigs recorded again in a weather condition, left out of every ranking.
    let skips: Vec<Vec<String>> = reports.iter().map(|(_, r)| in_conditions(r)).collect();
    let leaders = presets
        .iter()
        .map(|p| Leader {
            preset: p.clone(),
            at: reports
                .iter()
                .zip(&skips)
                .filter_map(|((s, r), skip)| {
                    lead(r, skip, &configurations, &s.name, p, f64::INFINITY).map(|l| (s.name.clone(), l))
                })
                .collect(),
        })
        .collect();
    let budgets = budget_leads(reports, &skips, &configurations, &presets);
    let mut claims: Vec<ClaimAcross> = Vec::new();
    for (_, r) in reports {
        for c in &r.claims {
            if !claims.iter().any(|x| x.id == c.id) {
                claims.push(ClaimAcross {
                    id: c.id.clone(),
                    statement: c.statement.clone(),
                    at: BTreeMap::new(),
                    across: Across::Undecided,
                    why: String::new(),
                    metrics: Vec::new(),
                });
            }
        }
    }
    for claim in &mut claims {
        let mut verdicts = Vec::new();
        let mut by: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
        for (s, r) in reports {
            let at = match r.claims.iter().find(|c| c.id == claim.id) {
                Some(c) if c.not_tested.is_none() => ClaimAt {
                    verdict: Some(c.verdict),
                    rows: c
                        .rows
                        .iter()
                        .map(|row| RowAt {
                            metric: row.metric.clone(),
                            verdict: row.verdict,
                            estimate: row.test.estimate,
                            lo: row.test.lo,
                            hi: row.test.hi,
                            p_adjusted: row.test.p_adjusted,
                            estimable: row.test.estimable,
                        })
                        .collect(),
                },
                _ => ClaimAt { verdict: None, rows: Vec::new() },
            };
            verdicts.push(at.verdict);
            by.entry(at.verdict.map_or("not tested", verdict_word)).or_default().push(&s.name);
            claim.at.insert(s.name.clone(), at);
        }
        claim.across = Across::of(&verdicts);
        claim.why = why(&by);
        claim.metrics = metrics_across(claim, reports);
    }
    Comparison {
        sweep: record.source.clone(),
        profile: record.profile.clone(),
        shards,
        configurations,
        leaders,
        budgets,
        claims,
        radar_worth: radar_worth(reports),
    }
}

/// The configurations of a study recorded in one of its weather conditions ("… in fog"): the
/// same rigs in other weather, not rigs to choose between.
/// "supported at a, b; undecided at c": which studies gave which verdict.
fn why(by: &BTreeMap<&str, Vec<&str>>) -> String {
    by.iter().map(|(v, names)| format!("{v} at {}", names.join(", "))).collect::<Vec<_>>().join("; ")
}

/// Each metric of `claim` (in the order its studies first give them) across the sweep, from its
/// row's verdict at each study; a study without the row (or the claim untested) tested nothing.
fn metrics_across(claim: &ClaimAcross, reports: &[(ShardRecord, Report)]) -> Vec<MetricAcross> {
    let mut metrics: Vec<&str> = Vec::new();
    for at in claim.at.values() {
        for r in &at.rows {
            if !metrics.contains(&r.metric.as_str()) {
                metrics.push(&r.metric);
            }
        }
    }
    metrics
        .into_iter()
        .map(|m| {
            let mut verdicts = Vec::new();
            let mut by: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
            for (s, _) in reports {
                let v = claim.at.get(&s.name).and_then(|at| at.rows.iter().find(|r| r.metric == m)).map(|r| r.verdict);
                verdicts.push(v);
                by.entry(v.map_or("not tested", verdict_word)).or_default().push(&s.name);
            }
            MetricAcross { metric: m.to_owned(), across: Across::of(&verdicts), why: why(&by) }
        })
        .collect()
}

fn in_conditions(r: &Report) -> Vec<String> {
    r.conditions.iter().flat_map(|c| c.configurations.iter().map(|b| c.label(b))).collect()
}

/// Per preset and budget (each distinct cost of a configuration in its study's own weather,
/// cheapest first), each study's best configuration within the budget.
fn budget_leads(
    reports: &[(ShardRecord, Report)],
    skips: &[Vec<String>],
    configurations: &[ConfigAcross],
    presets: &[String],
) -> Vec<BudgetBest> {
    let mut costs: Vec<f64> = reports
        .iter()
        .zip(skips)
        .flat_map(|((_, r), skip)| r.configurations.iter().filter(move |c| !skip.contains(&c.name)).map(|c| c.cost_usd))
        .filter(|c| c.is_finite())
        .collect();
    costs.sort_by(f64::total_cmp);
    costs.dedup_by(|a, b| (*a - *b).abs() < 0.5);
    let mut out = Vec::new();
    for p in presets {
        for &budget in &costs {
            let at: BTreeMap<String, Lead> = reports
                .iter()
                .zip(skips)
                .filter_map(|((s, r), skip)| {
                    lead(r, skip, configurations, &s.name, p, budget).map(|l| (s.name.clone(), l))
                })
                .collect();
            let first = at.values().next().map(|l| l.configuration.clone());
            let everywhere = first.filter(|f| at.len() == reports.len() && at.values().all(|l| &l.configuration == f));
            out.push(BudgetBest { preset: p.clone(), budget_usd: budget, at, everywhere });
        }
    }
    out
}

/// The configuration with the highest mean mAP for `preset` in one study among those in its own
/// weather (`skip`: its [`in_conditions`]) costing at most `budget_usd`, against the next.
fn lead(
    r: &Report,
    skip: &[String],
    configurations: &[ConfigAcross],
    shard: &str,
    preset: &str,
    budget_usd: f64,
) -> Option<Lead> {
    let mut ranked: Vec<(&str, f64)> = configurations
        .iter()
        .filter(|c| !skip.contains(&c.name))
        .filter_map(|c| {
            let at = c.at.get(shard).filter(|a| a.cost_usd <= budget_usd + 0.5)?;
            at.map.get(preset).map(|o| (c.name.as_str(), o.mean))
        })
        .collect();
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(b.0)));
    let (best, m) = *ranked.first()?;
    let second = ranked.get(1);
    let significant = second.and_then(|(other, _)| {
        let (a, b) = (format!("{preset} on {other}"), format!("{preset} on {best}"));
        r.comparisons.iter().find(|c| c.metric == "mAP" && ((c.a == a && c.b == b) || (c.a == b && c.b == a))).map(
            |c| c.test.estimable && c.test.p_adjusted < r.calibration.alpha && (c.test.estimate > 0.0) == (c.b == b),
        )
    });
    Some(Lead {
        configuration: best.to_owned(),
        mean_ap: m,
        runner_up: second.map(|s| s.0.to_owned()),
        margin: second.map_or(0.0, |s| m - s.1),
        significant,
    })
}

/// `comparison.md`.
pub fn markdown(c: &Comparison) -> String {
    let mut s = String::new();
    let names: Vec<&str> = c.shards.iter().map(|s| s.name.as_str()).collect();
    let file = |p: &Option<PathBuf>| p.as_ref().map_or("default".to_owned(), |p| esc(&p.display().to_string()));
    let _ = writeln!(s, "# Sweep: {}\n", esc(&c.sweep));
    let _ = writeln!(
        s,
        "{} studies, profile `{}`. Each study has its own folder and report; this page puts them side by side. \
         Each study's numbers are its own (its scene's traffic, validation scenes and seeds); nothing is pooled \
         across sites.\n",
        c.shards.len(),
        c.profile
    );
    s.push_str("## Studies\n\n| study | scene | catalog | ground truth | validation scenes | seeds | A/A false positives | planted-drop power |\n|---|---|---|---|---|---|---|---|\n");
    for sh in &c.shards {
        let _ = writeln!(
            s,
            "| [{0}]({0}/report.md) | {1} | {2} | {3} | {4} | {5} | {6:.3} of {7} | {8:.2} |",
            sh.name,
            file(&sh.scene),
            file(&sh.catalog),
            sh.ground_truth,
            sh.validation_scenes,
            sh.seeds,
            sh.false_positive_rate,
            sh.calibration_pairs,
            sh.power
        );
    }
    s.push_str(
        "\n## The paper's claims across the sweep\n\n\
         A claim is supported at every site only when each study supports it on its own (an \
         intersection–union test: no correction beyond each study's Holm adjustment). Cells: the study's \
         verdict, and its first metric's difference with its 95% interval.\n\n",
    );
    let _ = writeln!(s, "| claim | {} | across the sweep |", names.join(" | "));
    let _ = writeln!(s, "|---|{}---|", "---|".repeat(names.len()));
    for cl in &c.claims {
        let cells: Vec<String> = names
            .iter()
            .map(|n| match cl.at.get(*n) {
                Some(ClaimAt { verdict: Some(v), rows }) => match rows.first() {
                    Some(r) if r.estimable => {
                        format!("{} {:+.3} [{:+.3}, {:+.3}]", verdict_word(*v), r.estimate, r.lo, r.hi)
                    }
                    _ => verdict_word(*v).to_owned(),
                },
                _ => "not tested".to_owned(),
            })
            .collect();
        let _ = writeln!(s, "| {} | {} | **{}** |", esc(&cl.statement), cells.join(" | "), cl.across.words());
    }
    s.push_str(
        "\n### Each metric across the sweep\n\nA claim holds at a site only when all its metrics do; here each \
         metric of a claim on its own, by the same rule (each study's verdict for it, Holm-adjusted there).\n\n\
         | claim | metric | across the sweep | where |\n|---|---|---|---|\n",
    );
    for cl in &c.claims {
        for m in &cl.metrics {
            let _ =
                writeln!(s, "| {} | {} | **{}** | {} |", esc(&cl.statement), m.metric, m.across.words(), esc(&m.why));
        }
    }
    s.push_str("\n## Configurations\n\nCost, share of road users no sensor hit, and mAP on the common ground truth (mean [min, max] over seeds) per study.\n\n");
    let _ = writeln!(s, "| configuration | {} |", names.join(" | "));
    let _ = writeln!(s, "|---|{}", "---|".repeat(names.len()));
    for conf in &c.configurations {
        let cells: Vec<String> = names
            .iter()
            .map(|n| {
                conf.at.get(*n).map_or("–".into(), |a| {
                    let maps: Vec<String> =
                        a.map.iter().map(|(p, o)| format!("{p} {:.3} [{:.3}, {:.3}]", o.mean, o.min, o.max)).collect();
                    format!("{}, {:.1}% never hit; {}", dollars(&a.cost_usd), 100.0 * a.unseen_share, maps.join("; "))
                })
            })
            .collect();
        let _ = writeln!(s, "| {} | {} |", esc(&conf.name), cells.join(" | "));
    }
    s.push_str("\n## Best configuration per detector\n\nThe highest mean mAP in each study, its margin over the next, and whether that study's own test separates the two.\n\n");
    let _ = writeln!(s, "| detector | {} |", names.join(" | "));
    let _ = writeln!(s, "|---|{}", "---|".repeat(names.len()));
    for l in &c.leaders {
        let cells: Vec<String> = names.iter().map(|n| l.at.get(*n).map_or("–".into(), lead_cell)).collect();
        let _ = writeln!(s, "| {} | {} |", l.preset, cells.join(" | "));
    }
    if !c.budgets.is_empty() {
        s.push_str(
            "\n## Best configuration per budget\n\nWhat each budget buys at each site: per detector, the \
             configuration with the highest mean mAP among those costing at most the budget (each budget is \
             the price of one of the sweep's configurations), its margin over the next within the budget, and \
             whether that study's own test separates the two. The last column names the configuration when \
             it is best within the budget at every site.\n\n",
        );
        let _ = writeln!(s, "| detector | budget | {} | every site |", names.join(" | "));
        let _ = writeln!(s, "|---|---:|{}---|", "---|".repeat(names.len()));
        for b in &c.budgets {
            let cells: Vec<String> = names.iter().map(|n| b.at.get(*n).map_or("–".into(), lead_cell)).collect();
            let every = match &b.everywhere {
                Some(name) => esc(name),
                None if b.at.len() < names.len() => "– (a site holds none within it)".to_owned(),
                None => "depends on the site".to_owned(),
            };
            let _ = writeln!(s, "| {} | {} | {} | {} |", b.preset, dollars(&b.budget_usd), cells.join(" | "), every);
        }
    }
    if !c.radar_worth.is_empty() {
        s.push_str(
            "\n## What the radar is worth, per study\n\nThe rig with the radar (fused) against the cheapest \
             LiDAR-only rig (a row marked \"a second radar\": the rig of more radars placed given the rig \
             under study, against it), each study's own test (95% interval), and per $1,000 the radar rig costs more \
             (for a velocity error, m/s: below 0 the radar lowers it). `MDE`: the smallest true effect the \
             study's design finds with 80% power; `design for 0.015`: for an accuracy metric, the fewest \
             replicates per group (seeds, or training-traffic draws) and then validation scenes projected \
             to find 0.015, from the study's own variance components.\n\n\
             | study | metric | radar adds | MDE | design for 0.015 | per $1,000 | extra cost (USD) | verdict |\n\
             |---|---|---:|---:|---|---:|---:|---|\n",
        );
        for RadarWorth { study, value: w } in &c.radar_worth {
            let study = match (&w.condition, w.second) {
                (Some(cond), false) => format!("{study} ({cond})"),
                (Some(cond), true) => format!("{study} ({cond}, a second radar)"),
                (None, true) => format!("{study} (a second radar)"),
                (None, false) => study.clone(),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {:+.3} [{:+.3}, {:+.3}] | {} | {} | {} | {:.0} | {} |",
                esc(&study),
                w.metric,
                w.estimate,
                w.lo,
                w.hi,
                if w.mde.is_finite() { format!("{:.3}", w.mde) } else { "–".into() },
                design_cell(w),
                w.per_1000_usd.map_or("–".into(), |v| format!("{v:+.4}")),
                w.extra_cost_usd,
                verdict_word(w.verdict)
            );
        }
    }
    s.push_str(
        "\n## What this comparison leaves out\n\n\
         Differences between studies mix the scene's or catalog's effect with each study's sampling noise \
         (its report gives the seed variance and the test's power); no test here compares one study's number \
         with another's. A claim undecided at a site may hide an effect smaller than that study resolves.\n",
    );
    s
}

/// A study's best configuration, its mean mAP, and its margin over the next.
fn lead_cell(x: &Lead) -> String {
    let sig = match x.significant {
        Some(true) => "significant",
        Some(false) => "not significant",
        None => "not compared in its report",
    };
    match &x.runner_up {
        Some(r) => format!("{} ({:.3}; +{:.3} over {}, {sig})", esc(&x.configuration), x.mean_ap, x.margin, esc(r)),
        None => format!("{} ({:.3})", esc(&x.configuration), x.mean_ap),
    }
}

/// Writes `comparison.json` and `comparison.md` into the sweep's folder.
pub fn write(out: &Path, c: &Comparison) -> Result<Vec<PathBuf>> {
    let (json, md) = (out.join("comparison.json"), out.join("comparison.md"));
    write_json(&json, c)?;
    write_atomic(&md, markdown(c).as_bytes())?;
    Ok(vec![json, md])
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use Verdict::*;

    #[test]
    fn a_claim_holds_across_the_sweep_only_where_every_study_holds_it() {
        let s = Some(Supported);
        let c = Some(Contradicted);
        let u = Some(Undecided);
        assert_eq!(Across::of(&[s, s, s]), Across::SupportedEverywhere);
        assert_eq!(Across::of(&[c, c]), Across::ContradictedEverywhere);
        assert_eq!(Across::of(&[s, s, u]), Across::Undecided);
        assert_eq!(Across::of(&[s, None]), Across::Undecided, "a study that could not test it decides nothing");
        assert_eq!(Across::of(&[s, c, u]), Across::DependsOnSite);
        assert_eq!(Across::of(&[u, u]), Across::Undecided);
        assert_eq!(Across::of(&[None, None]), Across::NotTested);
        assert_eq!(Across::of(&[]), Across::NotTested);
        assert_eq!(Across::of(&[s]), Across::SupportedEverywhere);
    }

    /// Each metric of a claim is judged across the sweep on its own: on two copies of a committed
    /// report as two sites, where the first metric of a claim is supported at one site and
    /// undecided at the other (so the claim is undecided across the sweep) and its second metric is
    /// supported at both, the second metric holds at every site. Every metric's verdict is
    /// [`Across::of`] its rows' verdicts, and the markdown lists it.
    #[test]
    fn a_metric_can_hold_at_every_site_where_its_claim_does_not() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/paper-sensors-report/report.json");
        let r: Report = hilo_core::fs::read_json(&path, hilo_core::fs::limit::TABLE).unwrap();
        let shard = |n: &str| ShardRecord { name: n.into(), scene: None, catalog: None, fingerprint: String::new() };
        let set = |r: &mut Report, first: Verdict, claim: Verdict| {
            let c = r.claims.iter_mut().find(|c| c.id == "vs_lidar_alone").unwrap();
            assert_eq!(c.rows.len(), 2, "mAP and pedestrian AP");
            (c.rows[0].verdict, c.rows[1].verdict, c.verdict) = (first, Supported, claim);
        };
        let (mut a, mut b) = (r.clone(), r);
        set(&mut a, Supported, Supported);
        set(&mut b, Undecided, Undecided);
        let record =
            SweepRecord { source: "s.toml".into(), profile: "default".into(), shards: vec![shard("a"), shard("b")] };
        let c = build(&record, &[(shard("a"), a.clone()), (shard("b"), b.clone())]);
        let claim = c.claims.iter().find(|x| x.id == "vs_lidar_alone").unwrap();
        assert_eq!(claim.across, Across::Undecided);
        let m: Vec<(&str, Across)> = claim.metrics.iter().map(|m| (m.metric.as_str(), m.across)).collect();
        assert_eq!(m, [("mAP", Across::Undecided), ("pedestrian AP", Across::SupportedEverywhere)]);
        assert_eq!(claim.metrics[0].why, "supported at a; undecided at b");
        // Every metric of every claim, against its rows' verdicts at the two sites.
        for cl in &c.claims {
            let rows = |r: &Report| r.claims.iter().find(|x| x.id == cl.id).map(|x| x.rows.clone()).unwrap_or_default();
            let tested = |r: &Report| r.claims.iter().any(|x| x.id == cl.id && x.not_tested.is_none());
            assert_eq!(cl.metrics.len(), if tested(&a) { rows(&a).len() } else { 0 }, "{}", cl.id);
            for (k, m) in cl.metrics.iter().enumerate() {
                let v = [&a, &b].map(|r| Some(rows(r)[k].verdict));
                assert_eq!((m.metric.as_str(), m.across), (rows(&a)[k].metric.as_str(), Across::of(&v)), "{}", cl.id);
            }
        }
        let md = markdown(&c);
        assert!(md.contains("| pedestrian AP | **supported at every site** | supported at a, b |"), "{md}");
    }

    /// The radar's worth is the `radar_adds` and `radar_adds_velocity` claims' rows, in the
    /// study's weather and in each condition, priced by the configurations they compare: on the
    /// committed default-study report on the paper's sensors (clear and fog), the radar rig's
    /// extra cost is the radar's price, and each metric's value per $1,000 is its estimate
    /// scaled by it.
    #[test]
    fn the_radar_is_priced_by_what_its_rig_costs_more() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/paper-sensors-report/report.json");
        let r: Report = hilo_core::fs::read_json(&path, hilo_core::fs::limit::TABLE).unwrap();
        let shard = ShardRecord { name: "clear".into(), scene: None, catalog: None, fingerprint: String::new() };
        let record = SweepRecord { source: "s.toml".into(), profile: "default".into(), shards: vec![shard.clone()] };
        let c = build(&record, &[(shard, r.clone())]);
        let priced = ["radar_adds", "radar_adds_velocity", "radar_adds@fog", "radar_adds_velocity@fog"];
        let of = |ids: &[&str]| -> Vec<(String, crate::verdict::ClaimRow)> {
            r.claims
                .iter()
                .filter(|c| ids.contains(&c.id.as_str()))
                .flat_map(|c| c.rows.iter().map(move |row| (c.id.clone(), row.clone())))
                .collect()
        };
        let mut rows = of(&priced);
        assert_eq!(rows.len(), 8, "mAP, pedestrian AP, mAVE and car AVE in clear weather and in fog");
        // Then what the second radar adds, in clear weather: the same four metrics.
        let second = of(&crate::verdict::SECOND_RADAR_CLAIMS);
        assert_eq!(second.len(), 4);
        rows.extend(second);
        assert_eq!(c.radar_worth.len(), rows.len());
        let cost = |name: &str| r.configurations.iter().find(|x| x.name == name).unwrap().cost_usd;
        for (RadarWorth { study, value: w }, (id, row)) in c.radar_worth.iter().zip(&rows) {
            assert_eq!(study, "clear");
            assert_eq!(w.second, id.starts_with("second_radar"));
            assert_eq!(w.condition.as_deref(), id.strip_suffix("@fog").map(|_| "fog"));
            assert_eq!(w.metric, row.metric);
            let extra = cost(&row.b[0].0) - cost(&row.a[0].0);
            assert!(extra > 0.0 && (w.extra_cost_usd - extra).abs() < 1e-9, "{w:?}");
            assert!((w.per_1000_usd.unwrap() - 1000.0 * row.test.estimate / extra).abs() < 1e-12);
            assert_eq!((w.estimate, w.lo, w.hi, w.verdict), (row.test.estimate, row.test.lo, row.test.hi, row.verdict));
        }
        assert!(markdown(&c).contains("## What the radar is worth, per study"));
        // The report's own table is the same rows.
        assert_eq!(r.radar_value.len(), rows.len());
        assert!(r.radar_value.iter().zip(&c.radar_worth).all(|(v, w)| *v == w.value));
        assert!(markdown(&c).contains("| clear (fog) | mAP |"));
        assert!(markdown(&c).contains("| clear (a second radar) | mAP |"));
        // Each value's MDE is its claim row's. Each accuracy effect gets the design that finds
        // 0.015, never smaller than the study's, or is said to be out of reach: on this report
        // (the radar placed given the LiDARs, the site kept in training), pedestrian AP in clear
        // weather is found by the study's own design (MDE 0.014), pedestrian AP in fog by more
        // scenes, and mAP, whose seed variance alone exceeds the target within the caps, by no
        // design in clear weather or in fog.
        let mut reached = Vec::new();
        for (w, (_, row)) in c.radar_worth.iter().zip(&rows) {
            let v = &w.value;
            assert_eq!(v.mde, row.mde);
            match &v.design {
                _ if crate::verdict::lower_is_better(&v.metric) => assert_eq!(v.design, None),
                Some(d) => {
                    assert!(d.mde <= 0.015 && d.val_scenes >= r.validation_scenes && d.replicates >= r.seeds, "{d:?}");
                    let more = (d.replicates > r.seeds, d.val_scenes > r.validation_scenes);
                    if !v.second {
                        reached.push((v.condition.as_deref(), v.metric.as_str(), more));
                    }
                    // The study's own design where its MDE is already within the target.
                    assert_eq!(more == (false, false), v.mde <= 0.015, "{w:?}");
                }
                None => assert!(v.mde > 0.015, "{w:?}"),
            }
        }
        assert_eq!(reached, [(None, "pedestrian AP", (false, false)), (Some("fog"), "pedestrian AP", (false, true))]);
        // The accuracy effects no design finds (the loop above holds each one's MDE above 0.015).
        let beyond_caps: Vec<_> = c
            .radar_worth
            .iter()
            .map(|w| &w.value)
            .filter(|v| !v.second && v.design.is_none() && !crate::verdict::lower_is_better(&v.metric))
            .map(|v| (v.condition.as_deref(), v.metric.as_str()))
            .collect();
        assert_eq!(beyond_caps, [(None, "mAP"), (Some("fog"), "mAP")]);
        assert!(c.radar_worth.iter().all(|w| w.value.design.is_some() || w.value.mde > 0.015));
        let md = markdown(&c);
        assert!(md.contains("| clear (fog) | mAP |") && md.contains(" scenes (MDE 0.015)"), "{md}");
        assert!(md.contains("| reached |"), "{md}");
        // An effect no design within the caps finds says so.
        let mut beyond = c.clone();
        beyond.radar_worth[0].value.design = None;
        assert!(markdown(&beyond).contains("out of reach within 10 replicates and 2000 scenes"));
    }

    /// Each budget's best configuration is the brute-force argmax of the report's own entries
    /// (mean mAP over seeds, among the configurations in the study's own weather that cost at
    /// most the budget), on two committed reports as two sites; the highest budget's is the
    /// overall leader; a rig recorded in fog never leads however well it scores; a site without
    /// a configuration within a budget has no cell and keeps the budget from holding everywhere.
    #[test]
    fn each_budget_buys_the_best_configuration_it_affords_at_each_site() {
        let read = |rel: &str| -> Report {
            let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs").join(rel);
            hilo_core::fs::read_json(&path, hilo_core::fs::limit::TABLE).unwrap()
        };
        let shard = |n: &str| ShardRecord { name: n.into(), scene: None, catalog: None, fingerprint: String::new() };
        let mut field = read("example-report/report.json");
        let paper = read("paper-sensors-report/report.json");
        // A rig in fog that would lead everything were it a rig to buy.
        let fog = field.conditions[0].label(&field.conditions[0].configurations[0]);
        for e in field.entries.iter_mut().filter(|e| e.configuration == fog) {
            e.mean_ap = 0.99;
        }
        let reports = vec![(shard("field"), field.clone()), (shard("paper"), paper.clone())];
        let record = SweepRecord { source: "s.toml".into(), profile: "default".into(), shards: vec![] };
        let c = build(&record, &reports);
        let brute = |r: &Report, preset: &str, budget: f64| -> Option<(String, f64)> {
            let skip = in_conditions(r);
            let mut best: Option<(String, f64)> = None;
            for conf in r.configurations.iter().filter(|x| !skip.contains(&x.name) && x.cost_usd <= budget) {
                let m: Vec<f64> = r
                    .entries
                    .iter()
                    .filter(|e| e.configuration == conf.name && e.preset == preset && e.mean_ap.is_finite())
                    .map(|e| e.mean_ap)
                    .collect();
                if m.is_empty() {
                    continue;
                }
                let mean = m.iter().sum::<f64>() / m.len() as f64;
                if best.as_ref().is_none_or(|b| mean > b.1) {
                    best = Some((conf.name.clone(), mean));
                }
            }
            best
        };
        let mut costs: Vec<f64> = [&field, &paper]
            .iter()
            .flat_map(|r| {
                let skip = in_conditions(r);
                r.configurations.iter().filter(|x| !skip.contains(&x.name)).map(|x| x.cost_usd).collect::<Vec<_>>()
            })
            .collect();
        costs.sort_by(f64::total_cmp);
        costs.dedup();
        assert!(costs.len() >= 4, "{costs:?}");
        assert_eq!(c.budgets.len(), costs.len() * c.leaders.len());
        let mut checked = 0;
        for b in &c.budgets {
            assert!(costs.contains(&b.budget_usd));
            for (name, r) in [("field", &field), ("paper", &paper)] {
                let want = brute(r, &b.preset, b.budget_usd);
                let got = b.at.get(name);
                assert_eq!(got.map(|l| l.configuration.clone()), want.as_ref().map(|w| w.0.clone()), "{b:?}");
                if let (Some(g), Some(w)) = (got, want) {
                    assert!((g.mean_ap - w.1).abs() < 1e-12);
                    assert!(g.margin >= 0.0 && g.configuration != fog);
                    checked += 1;
                }
            }
            let both: Vec<&str> = b.at.values().map(|l| l.configuration.as_str()).collect();
            let same = both.len() == 2 && both[0] == both[1];
            assert_eq!(b.everywhere.as_deref(), if same { Some(both[0]) } else { None }, "{b:?}");
        }
        assert!(checked > 10);
        for l in &c.leaders {
            let top = c.budgets.iter().rfind(|b| b.preset == l.preset).unwrap();
            for (name, x) in &l.at {
                assert_eq!(x.configuration, top.at[name].configuration, "the whole sweep's budget buys the leader");
                assert_ne!(x.configuration, fog);
            }
        }
        // The cheapest budget buys nothing at a site without its rig.
        let cheapest = costs[0];
        let mut lacking = paper.clone();
        lacking.configurations.retain(|x| (x.cost_usd - cheapest).abs() > 0.5);
        let c2 = build(&record, &[(shard("field"), field.clone()), (shard("paper"), lacking)]);
        let b0 = c2.budgets.iter().find(|b| b.budget_usd == cheapest).unwrap();
        assert!(!b0.at.contains_key("paper") && b0.everywhere.is_none());
        let md = markdown(&c2);
        assert!(md.contains("## Best configuration per budget") && md.contains("a site holds none within it"), "{md}");
    }

    #[test]
    fn seed_summaries_skip_missing_values() {
        assert_eq!(OverSeeds::of(&[]), None);
        assert_eq!(OverSeeds::of(&[f64::NAN]), None);
        let o = OverSeeds::of(&[0.2, f64::NAN, 0.4]).unwrap();
        assert!((o.mean - 0.3).abs() < 1e-12 && o.min == 0.2 && o.max == 0.4 && o.seeds == 2);
    }
}
