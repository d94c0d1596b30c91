//! Which summary of the training traffic's LiDAR points ranks trained mAP across junctions?
//!
//! For each site folder given (each holding the `study.toml` and the finished `validation.json`
//! of a `hilo validate` run), every member's LiDAR points on the counted road users of the
//! sampled training frames are recounted ([`hilo_plan::road_users::TrafficPoints::counts`]) and
//! summarised several ways, each class weighted equally as mAP weighs them: the mean of
//! min(1, n / K) and the share with n ≥ K for K from 5 to 640, the mean of ln(1 + n), the worst
//! class's capped mean, and each class's mean capped at 20. It prints, as markdown, each
//! summary's Spearman ρ with the measured mAP (the mean of a member's trainings) per site, and a
//! nested leave-one-site-out choice: for each held-out site, the summary with the best mean ρ on
//! the other sites, and the ρ it reaches on the held-out one. No training is run; the recount
//! of K = 5 must equal the set's recorded predictor, or the study and the set do not belong
//! together and the run stops.
//!
//! `cargo run --release -p hilo-validate --example point_terms -- docs/validation-sites/<site>…`
use hilo_placement_ip::Modality;
use std::collections::BTreeMap;
use std::path::Path;

type Terms = BTreeMap<String, f64>;
/// A site's name and, per member, its summaries and measured mAP.
type Site = (String, Vec<(Terms, f64)>);

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n.max(1) as f64
}

/// The summaries of one member's counts (per class, per (frame, road user)).
fn summaries(counts: &[Vec<usize>]) -> Terms {
    let names = hilo_core::Class::ALL;
    let seen: Vec<(usize, &Vec<usize>)> = counts.iter().enumerate().filter(|(_, c)| !c.is_empty()).collect();
    let per_class = |f: &dyn Fn(f64) -> f64| -> Vec<f64> {
        seen.iter().map(|(_, c)| mean(c.iter().map(|&n| f(n as f64)))).collect()
    };
    let mut t = Terms::new();
    for k in [5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0, 640.0] {
        let capped = per_class(&|n| (n / k).min(1.0));
        t.insert(format!("points capped at {k}"), mean(capped.iter().copied()));
        t.insert(format!("share with {k} points"), mean(per_class(&|n| f64::from(u8::from(n >= k))).into_iter()));
        if k == 5.0 || k == 20.0 {
            let worst = capped.iter().copied().fold(f64::INFINITY, f64::min);
            t.insert(format!("worst class, points capped at {k}"), worst);
        }
        if k == 20.0 {
            for ((c, _), v) in seen.iter().zip(&capped) {
                t.insert(format!("{}, points capped at 20", names[*c].name()), *v);
            }
        }
    }
    t.insert("mean ln(1 + points)".into(), mean(per_class(&|n| n.ln_1p()).into_iter()));
    t
}

fn site(dir: &Path) -> Result<Site, Box<dyn std::error::Error>> {
    let study = hilo_plan::study::Study::load(&dir.join("study.toml"))?;
    let text = std::fs::read_to_string(dir.join("validation.json"))?;
    let report: hilo_validate::ValidationReport = serde_json::from_str(&text)?;
    let traffic = hilo_plan::road_users::TrainingTraffic::new(&study)?;
    let points = hilo_plan::road_users::TrafficPoints::new(&traffic, hilo_validate::set::TRAFFIC_EVERY)?;
    let world = hilo_raycast::world::World::build(&study.scene, &hilo_raycast::world::QueryRegion::everything())?;
    let mut rows = Vec::new();
    for (m, trained) in &report.members {
        let lidars = m
            .placement
            .sensors
            .iter()
            .enumerate()
            .filter(|(_, s)| s.modality == Modality::Lidar)
            .map(|(k, s)| Ok((k, study.catalog.lidar(&s.ty)?.clone(), s.pose)))
            .collect::<Result<Vec<_>, hilo_sensor_models::SensorError>>()?;
        let terms = summaries(&points.counts(&world, &lidars)?);
        let recorded = m.predictors.get(hilo_validate::set::LIDAR_POINTS_CAPPED).copied().flatten();
        let recount = terms["points capped at 5"];
        if recorded.is_none_or(|r| (r - recount).abs() > 1e-9) {
            return Err(
                format!("{}: {} recounts {recount}, the set recorded {recorded:?}", dir.display(), m.slug).into()
            );
        }
        rows.push((terms, trained.map_mean));
    }
    let name = dir.file_name().map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into_owned());
    Ok((name, rows))
}

fn rho(rows: &[(Terms, f64)], term: &str) -> f64 {
    let x: Vec<f64> = rows.iter().map(|r| r.0[term]).collect();
    let y: Vec<f64> = rows.iter().map(|r| r.1).collect();
    hilo_validate::rank::spearman(&x, &y)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let sites = std::env::args().skip(1).map(|d| site(Path::new(&d))).collect::<Result<Vec<_>, _>>()?;
    let Some(first) = sites.iter().find_map(|s| s.1.first()) else {
        return Err("give one or more site folders whose sets hold members".into());
    };
    let terms: Vec<String> = first
        .0
        .keys()
        .filter(|t| sites.iter().all(|(_, rows)| rows.iter().all(|r| r.0.contains_key(*t))))
        .cloned()
        .collect();
    let fmt = |r: f64| if r.is_nan() { "—".to_owned() } else { format!("{r:+.2}") };
    // ρ per term and site, computed once for the table and the nested choice.
    let rhos: Vec<Vec<f64>> = terms.iter().map(|t| sites.iter().map(|s| rho(&s.1, t)).collect()).collect();
    println!("| summary | {} | mean |", sites.iter().map(|s| s.0.as_str()).collect::<Vec<_>>().join(" | "));
    println!("|---|{}---:|", "---:|".repeat(sites.len()));
    for (t, r) in terms.iter().zip(&rhos) {
        let cells: Vec<String> = r.iter().map(|&x| fmt(x)).collect();
        println!("| {t} | {} | {} |", cells.join(" | "), fmt(mean(r.iter().copied())));
    }
    println!("\n| held out | chosen on the others | its mean ρ there | ρ at the held-out site |\n|---|---|---:|---:|");
    let mut held = Vec::new();
    for (h, (name, _)) in sites.iter().enumerate() {
        let others: Vec<f64> =
            rhos.iter().map(|r| mean(r.iter().enumerate().filter(|(i, _)| *i != h).map(|(_, x)| *x))).collect();
        let Some(best) =
            (0..terms.len()).filter(|&t| !others[t].is_nan()).max_by(|&a, &b| others[a].total_cmp(&others[b]))
        else {
            continue;
        };
        held.push(rhos[best][h]);
        println!("| {name} | {} | {} | {} |", terms[best], fmt(others[best]), fmt(rhos[best][h]));
    }
    println!("\nMean held-out ρ of the nested choice: {}", fmt(mean(held.into_iter())));
    Ok(())
}
