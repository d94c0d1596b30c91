//! The study report: `report.md`, `report.json` and figures (every chart as SVG and PNG with the
//! same text; pictures as PNG).

use crate::assemble::{Entry, Pictures, Report, ResultsBy};
use crate::verdict::Verdict;
use glam::{Vec2, Vec3};
use hilo_core::Box3;
use hilo_core::fs::{write_atomic, write_json};
use hilo_eval::EvalBox;
use hilo_plan::charts::{Bars, Series, XY, dollars, save};
use hilo_plan::error::Result;
use hilo_plan::study::Configuration;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

pub(crate) fn esc(s: &str) -> String {
    s.replace('|', "\\|").replace('<', "&lt;").replace('>', "&gt;")
}

/// How a configuration was placed, and whether it was solved (placements of older versions gave
/// a single-modality configuration a sibling's poses, without a gap).
fn placement_status(c: &crate::assemble::ConfigSummary) -> (String, bool) {
    if !c.placement_solved {
        (c.placement_method.clone(), false)
    } else if c.placement_proven_optimal {
        ("proven optimal".into(), true)
    } else {
        (format!("not proven, gap {:.2}%", 100.0 * c.placement_gap), true)
    }
}

/// Mean, min and max over a group's seeds.
fn over_seeds(r: &Report, conf: &str, preset: &str, f: impl Fn(&Entry) -> Option<f64>) -> Option<(f64, f64, f64)> {
    let v: Vec<f64> =
        r.entries.iter().filter(|e| e.configuration == conf && e.preset == preset).filter_map(f).collect();
    crate::stats::OverSeeds::of(&v).map(|o| (o.mean, o.min, o.max))
}

fn fmt3(v: Option<(f64, f64, f64)>) -> String {
    v.map_or("–".into(), |(m, lo, hi)| format!("{m:.3} [{lo:.3}, {hi:.3}]"))
}

fn to_box(b: &EvalBox) -> Box3 {
    Box3::new(
        Vec3::new(b.translation[0] as f32, b.translation[1] as f32, b.translation[2] as f32),
        b.size[1] as f32,
        b.size[0] as f32,
        b.size[2] as f32,
        b.yaw() as f32,
    )
}

/// A bird's-eye picture of one validation frame: points, ground truth (green; yellow when
/// missed), detections with score ≥ 0.3 (blue when within 2 m of a same-class box, red when
/// false).
fn detection_png(
    frame: &hilo_detector::data::Frame,
    key: &str,
    gboxes: &[EvalBox],
    preds: &[(String, Vec<EvalBox>)],
    path: &Path,
) -> Result<()> {
    let pboxes: Vec<EvalBox> = preds
        .iter()
        .find(|p| p.0 == key)
        .map(|p| p.1.iter().filter(|b| b.detection_score >= 0.3).cloned().collect())
        .unwrap_or_default();
    let mut canvas = hilo_plan::render::blank_canvas(Vec2::splat(-55.0), Vec2::splat(55.0), 7.0)?;
    let dots: Vec<(Vec2, (u8, u8, u8))> = frame
        .lidar
        .iter()
        .map(|p| (Vec2::new(p[0], p[1]), (150, 150, 150)))
        .chain(frame.radar.iter().map(|p| (Vec2::new(p[0], p[1]), (230, 0, 230))))
        .collect();
    canvas.dots(&dots, 1.0);
    let near = |a: &EvalBox, b: &EvalBox| {
        a.detection_name == b.detection_name
            && (a.translation[0] - b.translation[0]).hypot(a.translation[1] - b.translation[1]) <= 2.0
    };
    for g in gboxes {
        let col = if pboxes.iter().any(|p| near(p, g)) { (0, 200, 0) } else { (255, 220, 0) };
        canvas.boxes(&[to_box(g)], col);
    }
    for p in &pboxes {
        let col = if gboxes.iter().any(|g| near(p, g)) { (40, 120, 255) } else { (255, 40, 40) };
        canvas.boxes(&[to_box(p)], col);
    }
    canvas.legend(&[
        ((150, 150, 150), "LiDAR point"),
        ((230, 0, 230), "radar point"),
        ((0, 200, 0), "road user found"),
        ((255, 220, 0), "road user missed"),
        ((40, 120, 255), "detection (score >= 0.3)"),
        ((255, 40, 40), "false detection"),
    ]);
    canvas.scale_bar(20.0);
    canvas.north_arrow();
    Ok(write_atomic(path, &canvas.png()?)?)
}

fn relation_word(r: crate::stats::PaperRelation) -> &'static str {
    use crate::stats::PaperRelation::*;
    match r {
        Consistent => "consistent",
        Larger => "larger",
        Smaller => "smaller",
        Opposite => "opposite",
    }
}

pub(crate) fn verdict_word(v: Verdict) -> &'static str {
    match v {
        Verdict::Supported => "supported",
        Verdict::Contradicted => "contradicted",
        Verdict::Equivalent => "equivalent",
        Verdict::Undecided => "undecided",
        Verdict::BudgetBound => "budget-bound",
    }
}

fn test_cells(t: &crate::stats::Test) -> (String, String) {
    if t.estimable {
        (format!("{:+.3} [{:+.3}, {:+.3}]", t.estimate, t.lo, t.hi), format!("{:.3}", t.p_adjusted))
    } else {
        (
            format!(
                "{:+.3} (interval not estimable: {} scenes, {} + {} seeds)",
                t.estimate, t.scenes, t.seeds_a, t.seeds_b
            ),
            "–".into(),
        )
    }
}

/// Writes `report.json`, `report.md` and `figures/`.
pub fn write(
    out: &Path,
    r: &Report,
    results: &ResultsBy,
    pictures: &Pictures,
    placements: &Path,
    configs: &[Configuration],
) -> Result<()> {
    let fig = out.join("figures");
    std::fs::create_dir_all(fig.join("detections")).map_err(|e| hilo_core::fs::FileError::io(&fig, e))?;
    write_json(&out.join("report.json"), r)?;
    let mut presets: Vec<String> = r.profile.presets.clone();
    presets.extend(r.profile.ablations.iter().cloned());
    figures(&fig, r, &presets)?;
    // Coverage maps (of the configurations placed for themselves: a weather condition's keeps
    // its clear-weather rig's poses and has none) and detection pictures (seed 0).
    let mut mapped: Vec<&Configuration> = Vec::new();
    for c in configs {
        let src = placements.join(format!("{}.png", c.slug()));
        if src.exists() {
            std::fs::copy(&src, fig.join(format!("coverage_{}.png", c.slug())))
                .map_err(|e| hilo_core::fs::FileError::io(&src, e))?;
            mapped.push(c);
        }
        for p in &presets {
            if let (Some(pred), Some((frame, key, gboxes))) =
                (results.get(&(c.name.clone(), p.clone(), 0)), pictures.get(&c.name))
            {
                detection_png(
                    frame,
                    key,
                    gboxes,
                    pred,
                    &fig.join("detections").join(format!("{}__{}.png", c.slug(), p)),
                )?;
            }
        }
    }
    let mut md = markdown(r, results, configs, &mapped, &presets);
    md.push_str(&validation_section(out, &r.study)?);
    Ok(write_atomic(&out.join("report.md"), md.as_bytes())?)
}

/// The folder, inside a study's, where `hilo validate --out <study>/validation` puts the
/// validation that the study's report then includes.
pub const VALIDATION_DIR: &str = "validation";

/// The section "Does the objective predict accuracy?" from `<out>/validation/validation.json`
/// when that folder holds a finished validation of this study (headings one level down, under
/// the report's); empty otherwise, and a line saying why when it holds another study's.
fn validation_section(out: &Path, study: &str) -> Result<String> {
    let path = out.join(VALIDATION_DIR).join("validation.json");
    if !path.exists() {
        return Ok(String::new());
    }
    let v: hilo_validate::ValidationReport = hilo_core::fs::read_json(&path, hilo_core::fs::limit::TABLE)?;
    if v.study != study {
        return Ok(format!(
            "\n## Does the objective predict accuracy?\n\n{} holds a validation of {}, not of this study; it is not \
             included.\n",
            path.display(),
            v.study
        ));
    }
    let body = hilo_validate::markdown(&v);
    let demoted: String =
        body.lines().map(|l| if l.starts_with('#') { format!("#{l}\n") } else { format!("{l}\n") }).collect();
    Ok(format!(
        "\n{demoted}\n(From `{VALIDATION_DIR}/validation.json`, made by `hilo validate --out <this folder>/{VALIDATION_DIR}` \
         with the study's file; its charts are in `{VALIDATION_DIR}/`.)\n"
    ))
}

fn figures(fig: &Path, r: &Report, presets: &[String]) -> Result<()> {
    // mAP against cost, per preset: seed mean with the seeds' range, in the study's own weather
    // (a condition's copy of a rig costs the same; its line would fold back on itself).
    let own = || r.configurations.iter().filter(|c| c.condition.is_none());
    let max_cost = own().map(|c| c.cost_usd).fold(0.0, f64::max);
    let series: Vec<Series> = presets
        .iter()
        .filter_map(|p| {
            let mut pts: Vec<(f64, f64, f64, f64)> = own()
                .filter_map(|c| over_seeds(r, &c.name, p, |e| Some(e.mean_ap)).map(|m| (c.cost_usd, m.0, m.1, m.2)))
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            (!pts.is_empty()).then(|| Series { label: p.clone(), points: pts, line: true })
        })
        .collect();
    let y_max = series.iter().flat_map(|s| s.points.iter().map(|p| p.3)).fold(0.1, f64::max) * 1.15;
    let notes: Vec<(f64, f64, String)> = own().map(|c| (c.cost_usd, 0.02 * y_max, c.name.clone())).collect();
    save(
        fig,
        "map_vs_cost",
        &XY {
            title: "mAP against hardware cost (common ground truth; seed mean and range)",
            x_label: "hardware cost (USD)",
            y_label: "mAP (validation)",
            x: (0.0, max_cost * 1.15),
            y: (0.0, y_max),
            series: &series,
            x_fmt: &dollars,
            notes: &notes,
        },
    )?;
    // Pedestrian AP per configuration and preset.
    let cats: Vec<String> = r.configurations.iter().map(|c| c.name.clone()).collect();
    let bars: Vec<hilo_plan::charts::BarSeries> = presets
        .iter()
        .map(|p| {
            (
                p.clone(),
                r.configurations
                    .iter()
                    .map(|c| over_seeds(r, &c.name, p, |e| e.class_ap.get("pedestrian").copied().flatten()))
                    .collect(),
            )
        })
        .collect();
    let y_max = bars.iter().flat_map(|b| b.1.iter().flatten().map(|v| v.2)).fold(0.1, f64::max) * 1.2;
    save(
        fig,
        "pedestrian_ap",
        &Bars {
            title: "Pedestrian AP per configuration (seed mean and range)",
            x_label: "configuration",
            y_label: "pedestrian AP (validation)",
            categories: &cats,
            series: &bars,
            y_max,
        },
    )?;
    // Per-class AP (the paper's Fig. 6): one chart per preset, classes along x, a bar per rig.
    let classes: Vec<String> =
        r.classes.iter().map(|c| if c.few_boxes { format!("{}*", c.name) } else { c.name.clone() }).collect();
    for p in presets {
        let bars: Vec<hilo_plan::charts::BarSeries> = r
            .configurations
            .iter()
            .map(|c| {
                (
                    c.name.clone(),
                    r.classes
                        .iter()
                        .map(|k| over_seeds(r, &c.name, p, |e| e.class_ap.get(&k.name).copied().flatten()))
                        .collect(),
                )
            })
            .filter(|(_, v): &hilo_plan::charts::BarSeries| v.iter().any(Option::is_some))
            .collect();
        if bars.is_empty() {
            continue;
        }
        let title = format!("AP per class, {p} (* fewer than 50 validation boxes)");
        save(
            fig,
            &format!("class_ap_{p}"),
            &Bars {
                title: &title,
                x_label: "class",
                y_label: "AP (validation)",
                categories: &classes,
                series: &bars,
                y_max: 1.05,
            },
        )?;
    }
    // Learning curves.
    let series: Vec<Series> = r
        .learning_curves
        .iter()
        .map(|c| Series {
            label: format!("{} on {}", c.preset, c.configuration),
            points: c.points.iter().map(|p| (p.0 as f64, p.1, p.1, p.1)).collect(),
            line: true,
        })
        .collect();
    let x_max = series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).fold(1.0, f64::max) * 1.05;
    let y_max = series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).fold(0.1, f64::max) * 1.15;
    save(
        fig,
        "learning_curves",
        &XY {
            title: "mAP against training budget (seed 0)",
            x_label: "training samples (each a schedule of its own)",
            y_label: "mAP (validation, common ground truth)",
            x: (0.0, x_max),
            y: (0.0, y_max),
            series: &series,
            x_fmt: &|v| format!("{v:.0}"),
            notes: &[],
        },
    )
}

fn markdown(
    r: &Report,
    results: &ResultsBy,
    configs: &[Configuration],
    mapped: &[&Configuration],
    presets: &[String],
) -> String {
    let mut md = String::new();
    md_header(&mut md, r);
    md_claims(&mut md, r);
    md_weather(&mut md, r);
    md_configurations(&mut md, r);
    md_modelled(&mut md, r);
    md_accuracy(&mut md, r, presets);
    md_comparisons(&mut md, r);
    md_learning_curves(&mut md, r);
    md_figures(&mut md, r, results, configs, mapped, presets);
    md_speed(&mut md, r);
    md
}

/// Where the report came from: study, profile, provenance, datasets, ground truth.
fn md_header(md: &mut String, r: &Report) {
    let p = &r.profile;
    let pv = &r.provenance;
    let _ = writeln!(
        md,
        "# hilo study report\n\nStudy `{}`, profile `{}`: {}, {} validation scenes, {} scene-bootstrap replicates. Generated by `hilo study{} --out <dir>{}{}` with hilo {} ({}; {}; {} threads, {} trainings at once) in {:.0} s on this machine (stages already complete in the folder are reused).\n",
        r.study,
        p.name,
        if p.traffic_draws > 1 {
            format!(
                "{} seeds per detector on each of {} training-traffic draws (the draw a random effect of the verdict)",
                r.seeds, p.traffic_draws
            )
        } else {
            format!("{} seeds per detector", r.seeds)
        },
        r.validation_scenes,
        p.resamples,
        if r.study.starts_with("<embedded>") { String::new() } else { format!(" {}", r.study) },
        if p.name == hilo_plan::profile::ProfileName::Default {
            String::new()
        } else {
            format!(" --profile {}", p.name)
        },
        if p.traffic_draws > 1 { format!(" --traffic-draws {}", p.traffic_draws) } else { String::new() },
        pv.hilo_version,
        if pv.git_commit.is_empty() {
            "not built from a checkout".to_owned()
        } else {
            format!("commit {}", pv.git_commit)
        },
        if pv.cpu_features.is_empty() {
            pv.arch.clone()
        } else {
            format!("{} with {}", pv.arch, pv.cpu_features.join(", "))
        },
        pv.threads,
        pv.trainings_at_once,
        r.seconds
    );
    let d = &p.dataset;
    let _ = writeln!(
        md,
        "Datasets (the same traffic for every configuration): training {} scenes × {} s at {} Hz; validation {} scenes of their own traffic seeds × {} s at {} Hz (radar sweeps at {} Hz between key frames). Each detector trained on {} samples.\n",
        d.scenes,
        d.seconds,
        d.rate_hz,
        d.val_scenes,
        d.val_seconds,
        d.val_rate_hz,
        d.sweep_rate_hz,
        p.train_samples.map_or("its preset's default".to_owned(), |n| n.to_string())
    );
    let counted = match r.classes.len() {
        6 => "six".to_owned(),
        7 => "seven".to_owned(),
        n => n.to_string(),
    };
    let _ = writeln!(
        md,
        "**Ground truth: common.** Every rig is scored on every road user of the {counted} classes within the evaluation ranges of the intersection's centre at each validation frame, whatever its sensors saw (a miss caused by coverage or occlusion counts against the rig); the nuScenes convention (boxes with at least one point of the rig) is given beside it as *visible-only*. mAP is over the classes present in the validation split: {}.\n",
        r.classes
            .iter()
            .map(|c| format!(
                "{} ({} boxes{}{})",
                c.name,
                c.validation_boxes,
                if c.in_map { "" } else { ", not in mAP" },
                if c.few_boxes && c.in_map { ", few: noisy" } else { "" }
            ))
            .collect::<Vec<_>>()
            .join(", ")
    );
}

/// The paper's claims and their verdicts, and what the profile leaves out.
fn md_claims(md: &mut String, r: &Report) {
    let p = &r.profile;
    let _ = writeln!(
        md,
        "## The paper's claims\n\nEach row is B − A; `paper` is the paper's number (AP points as a fraction), `hilo` the estimate with its 95% interval over scenes and seeds (Student's t with Welch–Satterthwaite degrees of freedom), `p` Holm-adjusted over the claims' own rows (the rig comparisons and the other readings are families of their own). Rows marked ↳ read the same question another way and do not decide the claim: *visible-only ground truth* scores each rig under the nuScenes convention (only boxes with a point of that rig; common ground truth, the default, counts every road user the rig should have seen), and *the paper's averaging* takes the mean of the fusion presets against the LiDAR-only baseline, as the paper's +7.7 and +3.1 do. Verdict: *supported* (significant in the paper's direction), *contradicted* (significant against it), *equivalent* (not significant, and within ±{:.3} by two one-sided tests; ±{:.2} m/s for a velocity error), *budget-bound* (its sign changed over the last doubling of training), *undecided*. `vs paper`: where the interval lies against the paper's number; `MDE`: the smallest true difference this design finds with 80% power. Velocity errors (mAVE, car AVE; m/s) are errors: their claims are supported when B − A is below 0.\n\n| claim | metric | B − A | paper | hilo [95%] | adjusted p | vs paper | MDE | verdict |\n|---|---|---|---:|---|---:|---|---:|---|",
        r.margin, r.velocity_margin_m_s
    );
    for c in &r.claims {
        if c.rows.is_empty() {
            let _ = writeln!(
                md,
                "| {} | – | – | – | not tested: {} | – | – | – | {} |",
                esc(&c.statement),
                esc(c.not_tested.as_deref().unwrap_or("")),
                verdict_word(c.verdict)
            );
        }
        for row in &c.rows {
            claim_row(md, &esc(&c.statement), row);
        }
        for row in &c.readings {
            claim_row(md, &format!("↳ {}", esc(row.reading.as_deref().unwrap_or(""))), row);
        }
        if !c.per_preset.is_empty() {
            let _ = writeln!(
                md,
                "| ↳ per preset | mAP | | | {} | | | | |",
                c.per_preset.iter().map(|(p, d)| format!("{p} {d:+.3}")).collect::<Vec<_>>().join(", ")
            );
        }
    }
    let _ = writeln!(md, "\nWhat this profile leaves out: {}.\n", p.leaves_out);
    if let Some(patch) = &r.detector_patch {
        let _ = writeln!(md, "Every detector is its preset with the study's `[detector_patch]`: `{patch}`.\n");
    }
    if let Some(schedule) = &r.train_schedule {
        let _ = writeln!(
            md,
            "Every training is its preset's schedule with the study's `[train_schedule]`: `{schedule}`.\n"
        );
    }
}

/// One row of the claims table: `first` in the claim column, then the row's cells.
fn claim_row(md: &mut String, first: &str, row: &crate::verdict::ClaimRow) {
    let (est, pv) = test_cells(&row.test);
    let _ = writeln!(
        md,
        "| {first} | {} | {} | {} | {} | {} | {} | {} | {} |",
        row.metric,
        esc(&row.comparison),
        row.paper.map_or("–".into(), |v| format!("{v:+.3}")),
        est,
        pv,
        row.paper_relation.map_or("–", relation_word),
        if row.mde.is_finite() { format!("{:.3}", row.mde) } else { "–".into() },
        verdict_word(row.verdict)
    );
}

/// What the radar adds and costs in the study's own weather and in each condition.
fn md_weather(md: &mut String, r: &Report) {
    if r.radar_value.is_empty() {
        return;
    }
    let own = r.profile.dataset.weather;
    let _ = writeln!(
        md,
        "## What the radar is worth, per weather\n\nThe rig under study with its radar (fused) against the LiDAR-only rig (LiDAR-only preset): the `radar_adds` and `radar_adds_velocity` claims above, in the study's own weather ({own}){}. Per $1,000 of what the radar rig costs more; for a velocity error (m/s) below 0 the radar lowers it. `MDE`: the smallest true effect this design finds with 80% power.\n\n| weather | metric | radar adds [95%] | MDE | per $1,000 | extra cost | verdict |\n|---|---|---|---:|---:|---:|---|",
        if r.conditions.is_empty() {
            String::new()
        } else {
            format!(
                " and in each condition, where {} were recorded again at the same poses with the same traffic and their detectors trained the same way",
                r.conditions
                    .iter()
                    .map(|c| format!("{} ({})", c.configurations.join(", "), c.name))
                    .collect::<Vec<_>>()
                    .join("; ")
            )
        }
    );
    for v in r.radar_value.iter().filter(|v| !v.second) {
        let weather = match &v.condition {
            None => format!("{own} (the study's)"),
            Some(name) => match r.conditions.iter().find(|c| &c.name == name) {
                Some(c) => format!("{name}: {}", c.weather),
                None => name.clone(),
            },
        };
        let _ = writeln!(md, "| {} | {} |", esc(&weather), value_cells(v));
    }
    md.push('\n');
    md_second_radar(md, r);
    md_radar_power(md, r);
}

/// A priced radar effect's cells: metric, estimate [95%], MDE, per $1,000, extra cost, verdict.
fn value_cells(v: &crate::verdict::RadarValue) -> String {
    format!(
        "{} | {:+.3} [{:+.3}, {:+.3}] | {} | {} | {} | {}",
        v.metric,
        v.estimate,
        v.lo,
        v.hi,
        if v.mde.is_finite() { format!("{:.3}", v.mde) } else { "–".into() },
        v.per_1000_usd.map_or("–".into(), |x| format!("{x:+.4}")),
        dollars(&v.extra_cost_usd),
        verdict_word(v.verdict)
    )
}

/// What a second radar adds and costs: the `second_radar_adds` and `second_radar_velocity`
/// claims, priced like the radar's.
fn md_second_radar(md: &mut String, r: &Report) {
    let second: Vec<&crate::verdict::RadarValue> = r.radar_value.iter().filter(|v| v.second).collect();
    if second.is_empty() {
        return;
    }
    md.push_str(
        "A second radar: the rig of more radars placed given the rig under study (its LiDARs and radar at the same poses) against it, both fused (the `second_radar_adds` and `second_radar_velocity` claims), per $1,000 of what the added radars cost.\n\n| metric | second radar adds [95%] | MDE | per $1,000 | extra cost | verdict |\n|---|---|---:|---:|---:|---|\n",
    );
    for v in second {
        let _ = writeln!(md, "| {} |", value_cells(v));
    }
    md.push('\n');
}

/// What design would find a radar effect of [`RADAR_TARGET_MDE`](crate::verdict::RADAR_TARGET_MDE)
/// on each accuracy metric whose MDE is larger, projected from this study's variance components.
fn md_radar_power(md: &mut String, r: &Report) {
    let target = crate::verdict::RADAR_TARGET_MDE;
    let short: Vec<&crate::verdict::RadarValue> = r
        .radar_value
        .iter()
        .filter(|v| !v.second && !crate::verdict::lower_is_better(&v.metric) && v.mde > target)
        .collect();
    if short.is_empty() {
        return;
    }
    let draws = r.profile.traffic_draws > 1;
    let (unit, flag) = if draws { ("training-traffic draws", "--traffic-draws") } else { ("seeds", "--seeds") };
    let _ = writeln!(
        md,
        "This design's MDE is above {target:.3}, half the paper's fusion gain, for these effects. The design that would find {target:.3}, projected from this study's variance components (the scene bootstrap's shrinks as 1/scenes, the {unit}' as 1/{unit}; the fewest {unit} first, then the fewest validation scenes; `{flag} N`, and `[dataset] val_scenes = V` in the study file, which the `default` profile takes):\n\n| weather | metric | MDE now ({} {unit}, {} scenes) | {unit} | validation scenes | projected MDE |\n|---|---|---:|---:|---:|---:|",
        crate::assemble::replicates(&r.profile),
        r.validation_scenes
    );
    for v in short {
        let weather = v.condition.clone().unwrap_or_else(|| "the study's".into());
        let (n, scenes, projected) = match &v.design {
            Some(d) => (d.replicates.to_string(), d.val_scenes.to_string(), format!("{:.3}", d.mde)),
            None => (
                "–".into(),
                "–".into(),
                format!(
                    "out of reach within {} {unit} and {} scenes",
                    crate::stats::MAX_DESIGN_REPLICATES,
                    crate::stats::MAX_DESIGN_SCENES
                ),
            ),
        };
        let mde = if v.mde.is_finite() { format!("{:.3}", v.mde) } else { "–".into() };
        let _ = writeln!(md, "| {} | {} | {mde} | {n} | {scenes} | {projected} |", esc(&weather), v.metric);
    }
    md.push('\n');
}

/// Which field effects the simulation models, and what it leaves out.
fn md_modelled(md: &mut String, r: &Report) {
    if r.modelled.is_empty() {
        return;
    }
    let _ = writeln!(
        md,
        "\n## What the simulation models\n\nField effects are catalog entries or `[dataset]` settings, off when absent; a study of ideal sensors reads as one. Left out whatever the settings: {}.\n\n| effect | modelled | where |\n|---|---|---|",
        crate::modelled::LEFT_OUT
    );
    for m in &r.modelled {
        let _ = writeln!(md, "| {} | {} | {} |", m.effect, if m.on { "yes" } else { "no" }, esc(&m.detail));
    }
}

/// Each configuration: cost, coverage, placement, sensors.
fn md_configurations(md: &mut String, r: &Report) {
    let _ = writeln!(
        md,
        "## Configurations\n\n| configuration | cost | central coverage | road users never hit (validation) | placement | sensors |\n|---|---:|---:|---:|---|---|"
    );
    for c in &r.configurations {
        let (status, solved) = placement_status(c);
        let how = if solved { format!("{status} in {:.2} s", c.placement_s) } else { status };
        let _ = writeln!(
            md,
            "| {} | {} | {:.1}% | {:.1}% | {} | {} |",
            c.name,
            dollars(&c.cost_usd),
            c.central_coverage * 100.0,
            c.unseen_share * 100.0,
            esc(&how),
            c.sensors.join(", ")
        );
    }
    let mounts: Vec<String> = r
        .configurations
        .iter()
        .filter(|c| !c.radar_mounts.is_empty() && c.condition.is_none())
        .map(|c| {
            let each: Vec<String> = c
                .radar_mounts
                .iter()
                .map(|(m, shared)| {
                    format!("{} ({})", esc(m), if *shared { "beside a LiDAR" } else { "a structure of its own" })
                })
                .collect();
            format!("{}: {}", c.name, each.join(", "))
        })
        .collect();
    if !mounts.is_empty() {
        let _ = writeln!(
            md,
            "\nWhere the radars stand (a radar beside a LiDAR adds no viewpoint of its own, only its measurements): {}.",
            mounts.join("; ")
        );
    }
    if !r.cost_reduction.is_empty() {
        let _ = writeln!(
            md,
            "\nCost of the rig under study (the cheapest with a radar) against the others: {}.",
            r.cost_reduction
                .iter()
                .map(|(k, v)| format!("{:+.1}% against {k}", -v * 100.0))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
}

/// mAP, pedestrian AP and per-class AP of every configuration and preset.
fn md_accuracy(md: &mut String, r: &Report, presets: &[String]) {
    let _ = writeln!(
        md,
        "\n## Accuracy\n\nSeed mean [min, max] over {}; common ground truth unless marked.\n\n| configuration | preset | mAP | pedestrian AP | NDS | mAVE (m/s) | mAP, visible-only | training | inference |\n|---|---|---|---|---|---|---|---:|---:|",
        match r.profile.traffic_draws {
            1 => format!("{} seeds", r.seeds),
            d => format!("{} detectors ({} seeds on each of {d} training-traffic draws)", r.seeds * d, r.seeds),
        }
    );
    for c in &r.configurations {
        for pr in presets {
            let Some(m) = over_seeds(r, &c.name, pr, |e| Some(e.mean_ap)) else { continue };
            let ped = over_seeds(r, &c.name, pr, |e| e.class_ap.get("pedestrian").copied().flatten());
            let vis = over_seeds(r, &c.name, pr, |e| Some(e.visible_only.mean_ap));
            let nds = over_seeds(r, &c.name, pr, |e| Some(e.nd_score));
            let mave = over_seeds(r, &c.name, pr, |e| Some(e.mean_ave).filter(|v| v.is_finite()));
            let t = over_seeds(r, &c.name, pr, |e| Some(e.train_s)).map_or(0.0, |x| x.0);
            let ms = over_seeds(r, &c.name, pr, |e| Some(e.ms_per_frame)).map_or(0.0, |x| x.0);
            let samples =
                r.entries.iter().find(|e| e.configuration == c.name && &e.preset == pr).map_or(0, |e| e.samples);
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} | {} | {} | {:.0} s ({} samples) | {:.1} ms/frame |",
                c.name,
                pr,
                fmt3(Some(m)),
                fmt3(ped),
                fmt3(nds),
                fmt3(mave),
                fmt3(vis),
                t,
                samples,
                ms
            );
        }
    }
    let classes: Vec<String> = r.classes.iter().map(|c| c.name.clone()).collect();
    md_rig_table(
        md,
        r,
        presets,
        "AP per class (seed mean; – where the class has no validation box)",
        &classes,
        &|e, k| e.class_ap.get(&classes[k]).copied().flatten(),
        3,
    );
    md_velocity(md, r, presets);
    md_range(md, r, presets);
}

/// mAP per range bin from the intersection's origin (seed mean), over the classes with ground
/// truth in each bin.
fn md_range(md: &mut String, r: &Report, presets: &[String]) {
    if r.range_bins.is_empty() {
        return;
    }
    let head: Vec<String> =
        r.range_bins.iter().map(|(label, n)| format!("{label} ({} boxes)", n.values().sum::<usize>())).collect();
    let value = |e: &Entry, k: usize| {
        let label = &r.range_bins[k].0;
        e.map_by_range.iter().find(|(l, _)| l == label).and_then(|(_, v)| *v)
    };
    md_rig_table(
        md,
        r,
        presets,
        "mAP by range from the intersection's origin (seed mean; each bin's mean over the classes with validation boxes in it; ranges and bins: `[evaluation]` in the study file)",
        &head,
        &value,
        3,
    );
}

/// A table introduced by `intro`, with a row per (configuration, preset) with a detector: the
/// seed mean of `value(entry, k)` under each of `columns`, with `digits` decimals ("–" where
/// no seed has a value).
fn md_rig_table(
    md: &mut String,
    r: &Report,
    presets: &[String],
    intro: &str,
    columns: &[String],
    value: &dyn Fn(&Entry, usize) -> Option<f64>,
    digits: usize,
) {
    let _ = writeln!(
        md,
        "\n{intro}:\n\n| configuration | preset | {} |\n|---|---|{}",
        columns.join(" | "),
        columns.iter().map(|_| "---:|").collect::<String>()
    );
    for c in &r.configurations {
        for pr in presets {
            if over_seeds(r, &c.name, pr, |e| Some(e.mean_ap)).is_none() {
                continue;
            }
            let cells: Vec<String> = (0..columns.len())
                .map(|k| {
                    over_seeds(r, &c.name, pr, |e| value(e, k)).map_or("–".into(), |v| format!("{:.digits$}", v.0))
                })
                .collect();
            let _ = writeln!(md, "| {} | {} | {} |", c.name, pr, cells.join(" | "));
        }
    }
}

/// AVE per class: the velocity error of the true positives at the devkit's 2 m threshold, in
/// m/s (1 where a class has no true positive up to 10% recall, as the devkit scores it).
fn md_velocity(md: &mut String, r: &Report, presets: &[String]) {
    if !r.entries.iter().any(|e| e.mean_ave.is_finite()) {
        return;
    }
    let classes: Vec<String> = r.classes.iter().map(|c| c.name.clone()).collect();
    md_rig_table(
        md,
        r,
        presets,
        "Velocity error per class (AVE, m/s, seed mean; lower is better; 1.0 where a class has no true positive up to 10% recall, as the nuScenes devkit scores it)",
        &classes,
        &|e, k| e.class_ave.get(&classes[k]).copied().flatten(),
        2,
    );
}

/// The rig under study against the others, and the calibration of the test.
fn md_comparisons(md: &mut String, r: &Report) {
    if !r.comparisons.is_empty() {
        let _ = writeln!(
            md,
            "\n## Is the difference real?\n\nThe rig under study (the cheapest configuration with a radar) against each other one, per preset: B − A with its 95% interval, whose standard error combines the scene bootstrap (paired: the same traffic) and the pooled seed variance net of the scene noise the bootstrap already carries, with Welch–Satterthwaite degrees of freedom; p Holm-adjusted over these rig comparisons, a family of their own.\n\n| metric | B | A | B − A [95%] | SE (scenes, seeds) | df | p | adjusted p |\n|---|---|---|---|---|---:|---:|---:|"
        );
        for c in &r.comparisons {
            let (est, _) = test_cells(&c.test);
            let t = &c.test;
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {:.4} ({:.4}, {:.4}) | {} | {} | {} |",
                c.metric,
                esc(&c.b),
                esc(&c.a),
                est,
                t.se,
                t.se_scenes,
                t.se_seeds,
                if t.df.is_finite() && t.df > 0.0 { format!("{:.0}", t.df) } else { "–".into() },
                if t.p.is_finite() { format!("{:.3}", t.p) } else { "–".into() },
                if t.p_adjusted.is_finite() { format!("{:.3}", t.p_adjusted) } else { "–".into() }
            );
        }
    }
    let cal = &r.calibration;
    let sv = cal.seed_variance.get("mAP");
    let _ = writeln!(
        md,
        "\n## Calibration of the test\n\nOn {} A/A pairs (two seeds of one configuration and preset), each tested with the seed variance of the other groups only (so the test is not calibrated by the pairs it judges), the test called {} significant at α = {}: a false-positive rate of {:.3} [{:.3}, {:.3}] (exact 95% interval, every pair an independent trial{}){} A planted degradation ({:.0}% of every detector's boxes dropped, a mean mAP change of {:+.3}) was found in {:.0}% of {} groups. Seed standard deviation of mAP (pooled over every group): {:.4} ({} degrees of freedom), of which the scene bootstrap already carries {:.4}; the seed component proper is {:.4}.\n",
        cal.pairs,
        cal.false_positives,
        cal.alpha,
        cal.false_positive_rate,
        cal.false_positive_interval.0,
        cal.false_positive_interval.1,
        cal.false_positive_interval_groups.map_or(String::new(), |(lo, hi)| format!(
            "; [{lo:.3}, {hi:.3}] with the groups resampled, since the pairs of one group share its seeds; the reading takes both"
        )),
        calibration_words(cal),
        100.0 * cal.planted_drop_share,
        cal.planted_mean_effect,
        100.0 * cal.power,
        cal.planted_pairs,
        sv.map_or(f64::NAN, |s| s.variance.sqrt()),
        sv.map_or(0, |s| s.df),
        sv.map_or(f64::NAN, |s| s.within.sqrt()),
        sv.map_or(f64::NAN, |s| s.seed_only().sqrt()),
    );
    if let Some(d) = cal.traffic_draws.get("mAP") {
        let _ = writeln!(
            md,
            "The detectors trained on {} training-traffic draws ({} seeds each; the validation scenes shared), and the verdict's replicates are the draws, each the mean of its seeds, so the traffic a detector happened to train on is in every interval above (A/A pairs are then two draws). Standard deviation of mAP between seeds of one draw: {:.4} ({} degrees of freedom); between draw means: {:.4} ({} degrees of freedom); the traffic's own component: {:.4}.\n",
            d.draws,
            d.seeds,
            d.seed.variance.sqrt(),
            d.seed.df,
            d.draw_means.variance.sqrt(),
            d.draw_means.df,
            d.traffic.sqrt(),
        );
    }
}

/// What the A/A rate's interval says against α: a warning when it excludes α either way.
fn calibration_words(cal: &crate::verdict::Calibration) -> String {
    use crate::verdict::CalibrationReading::*;
    match cal.reading {
        Some(Nominal) => format!(", which holds the nominal {}.", cal.alpha),
        Some(Conservative) => format!(
            ". **Warning: conservative.** The interval lies below the nominal {}: the standard errors are larger than the seeds' spread bears out, and the verdicts lose power (more *undecided* than the data warrant).",
            cal.alpha
        ),
        Some(Liberal) => format!(
            ". **Warning: liberal.** The interval lies above the nominal {}: the standard errors are too small, and a *supported* or *contradicted* verdict may be a chance result.",
            cal.alpha
        ),
        None => ".".into(),
    }
}

/// The learning curves and whether the ranking held over the last doubling.
fn md_learning_curves(md: &mut String, r: &Report) {
    let _ = writeln!(
        md,
        "## Learning curves\n\nmAP (common ground truth) of seed 0 trained on shares of its schedule, each a training of its own (warmed up and annealed over its samples, so a point is what that budget reaches, not weights taken mid-run), and what the last doubling of the budget added. {}\n\n| configuration | preset | mAP at samples | gain over the last doubling |\n|---|---|---|---:|",
        if r.ranking_stable {
            "Every preset ranks the configurations the same at half its training as at the end.".to_owned()
        } else {
            format!(
                "The ranking of the configurations changed between half the training and the end for: {}; the study is comparing training budgets there.",
                r.ranking_changed.join(", ")
            )
        }
    );
    for c in &r.learning_curves {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:+.3} |",
            c.configuration,
            c.preset,
            c.points.iter().map(|(s, m)| format!("{m:.3} @ {s}")).collect::<Vec<_>>().join(", "),
            c.gain_last_doubling
        );
    }
}

/// The figures: charts, coverage maps (of `mapped`, the configurations whose map was written),
/// the detection grid.
fn md_figures(
    md: &mut String,
    r: &Report,
    results: &ResultsBy,
    configs: &[Configuration],
    mapped: &[&Configuration],
    presets: &[String],
) {
    let _ = writeln!(
        md,
        "\n## Figures\n\n![mAP against cost](figures/map_vs_cost.svg)\n\n![pedestrian AP](figures/pedestrian_ap.svg)\n\n![learning curves](figures/learning_curves.svg)\n"
    );
    for pr in presets {
        if r.entries.iter().any(|e| &e.preset == pr) {
            let _ = writeln!(md, "![AP per class, {pr}](figures/class_ap_{pr}.svg)\n");
        }
    }
    let _ = writeln!(
        md,
        "Coverage maps (green: LiDAR-hit cells, red: radar-covered, yellow: both; placed in the study's own weather, whose poses each weather condition keeps): {}\n",
        mapped
            .iter()
            .map(|c| format!("[{}](figures/coverage_{}.png)", c.name, c.slug()))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(
        md,
        "Detections on one validation frame (seed 0):\n\n| configuration | {} |\n|---|{}",
        presets.join(" | "),
        presets.iter().map(|_| "---|").collect::<String>()
    );
    for c in configs {
        let cells: Vec<String> = presets
            .iter()
            .map(|p| {
                if results.contains_key(&(c.name.clone(), p.clone(), 0)) {
                    format!("![{} {}](figures/detections/{}__{}.png)", c.name, p, c.slug(), p)
                } else {
                    "–".into()
                }
            })
            .collect();
        let _ = writeln!(md, "| {} | {} |", c.name, cells.join(" | "));
    }
}

/// Speed against error of each stage.
fn md_speed(md: &mut String, r: &Report) {
    let _ = writeln!(md, "\n## Speed against error\n\n| stage | speed | error paid |\n|---|---|---|");
    for c in &r.configurations {
        let (status, solved) = placement_status(c);
        let paid = if !solved {
            "none: not an optimisation".to_owned()
        } else if c.placement_proven_optimal {
            "none: proven optimal".to_owned()
        } else {
            status
        };
        let _ = writeln!(md, "| placement, {} | {:.2} s | {} |", c.name, c.placement_s, esc(&paid));
    }
    let t = &r.tradeoffs;
    for l in &t.los {
        let _ = writeln!(
            md,
            "| visibility of {}, {} line-of-sight sample{} per probe and cell | {:.2} s | mean \\|ΔV\\| {:.4} (max {:.3}) against {} samples; the placement it gives is worth {:.2}% less on that V |",
            t.configuration,
            l.samples_per_probe,
            if l.samples_per_probe == 1 { "" } else { "s" },
            l.seconds,
            l.mean_abs_dv,
            l.max_abs_dv,
            t.los.last().map_or(0, |x| x.samples_per_probe),
            100.0 * l.placement_loss
        );
    }
    for l in &t.limits {
        let _ = writeln!(
            md,
            "| placement under a budget of {} (any of {}), time limit {} s | {:.2} s | {}: objective {:.1}, bound {:.1}, gap {:.2}% ({}; greedy {:.1}) |",
            dollars(&t.budget_usd),
            t.types.join(", "),
            l.time_limit_s,
            l.seconds,
            l.selection,
            l.objective,
            l.bound,
            100.0 * l.gap,
            if l.proven_optimal { "proven optimal" } else { "not proven" },
            t.greedy_objective
        );
    }
    let mut seen = BTreeMap::new();
    for e in r.entries.iter().filter(|e| e.seed == 0 && e.draw == 0) {
        seen.entry((e.configuration.clone(), e.preset.clone())).or_insert(e);
    }
    for e in seen.values() {
        let _ = writeln!(
            md,
            "| detector {} on {} ({:.2} M parameters) | {:.1} ms/frame, trained in {:.0} s | mAP {:.3} |",
            e.preset,
            e.configuration,
            e.parameters as f64 / 1e6,
            e.ms_per_frame,
            e.train_s,
            e.mean_ap
        );
    }
}
