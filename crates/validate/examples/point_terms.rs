//! Which summary of the training traffic's LiDAR points ranks trained mAP across junctions?
//!
//! For each site folder given (each holding the `study.toml` and the finished `validation.json`
//! of a `hilo validate` run), every member's LiDAR points on the counted road users of the
//! sampled training frames are recomputed ([`hilo_plan::road_users::TrafficPoints::per_user`])
//! and summarised several ways, each class weighted equally as mAP weighs them. By number: the
//! mean of min(1, n / K) and the share with n ≥ K for K from 5 to 640, the mean of ln(1 + n),
//! the worst class's capped mean, and each class's mean capped at 20. By what the points show of
//! each road user, in its own frame: the share of its length × width they span (all LiDARs
//! together, the best single one, and each LiDAR's share summed, capped at 1: the recorded
//! footprint predictor), whether the middle of their extent lies near its centre, how many of
//! its sides hold three points, and the widest angle between two LiDARs that see it. It prints,
//! as markdown, each summary's Spearman ρ with the measured mAP (the mean of a member's
//! trainings) per site; a nested leave-one-site-out choice (for each held-out site, the summary
//! with the best mean ρ on the other sites, and the ρ it reaches on the held-out one); and the
//! recorded footprint predictor against the recorded point term with the paired interval of
//! `hilo validate --sites`. No training is run; the recounts must equal the set's recorded
//! point term and footprint, or the study and the set do not belong together (or the set was
//! scored by an older build: refit it) and the run stops.
//!
//! `cargo run --release -p hilo-validate --example point_terms -- docs/validation-sites/<site>…`
use hilo_placement_ip::Modality;
use std::collections::BTreeMap;
use std::path::Path;

type Terms = BTreeMap<String, f64>;
/// A site's name, per member its summaries and measured mAP, and its finished set.
type Site = (String, Vec<(Terms, f64)>, hilo_validate::ValidationReport);

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n.max(1) as f64
}

/// What one road user's points show: how many, the share of its length × width they span, how
/// far the middle of their extent lies from its centre, how many of its four sides hold 3 or more
/// (a pedestrian's sides: the four quarters around it), and the widest angle between two
/// LiDARs that put 3 or more points on it.
#[derive(Clone, Copy, Debug)]
struct View {
    n: usize,
    extent: f64,
    centre_off_m: f64,
    sides: usize,
    spread_deg: f64,
    /// The largest extent one LiDAR's points span alone, and the sum over LiDARs (capped at 1).
    best_single: f64,
    sum_single: f64,
}

fn view(actor: &hilo_raycast::Actor, points: &[(usize, glam::Vec3)], lidar_xy: &[(f32, f32)]) -> View {
    let b = actor.shape.outline();
    let (centre, half, yaw) = ((b.center.x, b.center.y), (0.5 * b.length_m, 0.5 * b.width_m), b.yaw);
    let (s, c) = yaw.sin_cos();
    let local: Vec<(f32, f32)> = points
        .iter()
        .map(|(_, p)| {
            let (dx, dy) = (p.x - centre.0, p.y - centre.1);
            (dx * c + dy * s, -dx * s + dy * c)
        })
        .collect();
    let mut side = [0usize; 4];
    let (mut lo, mut hi) = ((f32::INFINITY, f32::INFINITY), (f32::NEG_INFINITY, f32::NEG_INFINITY));
    for &(x, y) in &local {
        lo = (lo.0.min(x), lo.1.min(y));
        hi = (hi.0.max(x), hi.1.max(y));
        let (u, v) = (x / half.0, y / half.1);
        if u.abs().max(v.abs()) >= 0.8 {
            side[if u.abs() >= v.abs() { usize::from(u > 0.0) } else { 2 + usize::from(v > 0.0) }] += 1;
        }
    }
    let mut per_lidar = vec![0usize; lidar_xy.len()];
    for (l, _) in points {
        per_lidar[*l] += 1;
    }
    let bearings: Vec<f32> = per_lidar
        .iter()
        .zip(lidar_xy)
        .filter(|(n, _)| **n >= 3)
        .map(|(_, (x, y))| (y - centre.1).atan2(x - centre.0))
        .collect();
    let mut spread = 0.0f64;
    for a in &bearings {
        for b in &bearings {
            let d = f64::from((a - b).rem_euclid(std::f32::consts::TAU));
            spread = spread.max(d.min(std::f64::consts::TAU - d).to_degrees());
        }
    }
    let n = points.len();
    let footprint = |l: Option<usize>| {
        hilo_plan::road_users::footprint_extent(
            actor,
            points.iter().filter(|p| l.is_none_or(|l| p.0 == l)).map(|p| p.1),
        )
    };
    let singles: Vec<f64> = (0..lidar_xy.len()).map(|l| footprint(Some(l))).collect();
    View {
        best_single: singles.iter().copied().fold(0.0, f64::max),
        sum_single: singles.iter().sum::<f64>().min(1.0),
        n,
        extent: footprint(None),
        centre_off_m: if n == 0 { f64::INFINITY } else { f64::from((0.5 * (lo.0 + hi.0)).hypot(0.5 * (lo.1 + hi.1))) },
        sides: side.iter().filter(|&&k| k >= 3).count(),
        spread_deg: spread,
    }
}

/// The summaries of one member's views (per class, per (frame, road user)).
fn summaries(views: &[Vec<View>]) -> Terms {
    let names = hilo_core::Class::ALL;
    let seen: Vec<(usize, &Vec<View>)> = views.iter().enumerate().filter(|(_, c)| !c.is_empty()).collect();
    let per_class =
        |f: &dyn Fn(&View) -> f64| -> Vec<f64> { seen.iter().map(|(_, c)| mean(c.iter().map(f))).collect() };
    let share = |f: &dyn Fn(&View) -> bool| mean(per_class(&|v| f64::from(u8::from(f(v)))).into_iter());
    let mut t = Terms::new();
    for k in [5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0, 640.0] {
        let capped = per_class(&|v| (v.n as f64 / k).min(1.0));
        t.insert(format!("points capped at {k}"), mean(capped.iter().copied()));
        t.insert(format!("share with {k} points"), share(&|v| v.n as f64 >= k));
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
    t.insert("mean ln(1 + points)".into(), mean(per_class(&|v| (v.n as f64).ln_1p()).into_iter()));
    t.insert("extent: length × width spanned".into(), mean(per_class(&|v| v.extent).into_iter()));
    for d in [0.25, 0.5, 1.0] {
        t.insert(format!("extent's middle within {d} m of the centre"), share(&|v| v.centre_off_m <= d));
    }
    t.insert("extent: the best single LiDAR's".into(), mean(per_class(&|v| v.best_single).into_iter()));
    t.insert("extent: single LiDARs' summed, capped at 1".into(), mean(per_class(&|v| v.sum_single).into_iter()));
    t.insert("two sides with 3 points".into(), share(&|v| v.sides >= 2));
    t.insert("mean sides with 3 points / 4".into(), mean(per_class(&|v| v.sides as f64 / 4.0).into_iter()));
    for a in [30.0, 60.0, 90.0] {
        t.insert(format!("two LiDARs {a}° apart, 3 points each"), share(&|v| v.spread_deg >= a));
    }
    t.insert(
        "points capped at 5 × (1 + two sides) / 2".into(),
        mean(per_class(&|v| (v.n as f64 / 5.0).min(1.0) * (1.0 + f64::from(u8::from(v.sides >= 2))) / 2.0).into_iter()),
    );
    t.insert(
        "points capped at 20 × extent".into(),
        mean(per_class(&|v| (v.n as f64 / 20.0).min(1.0) * v.extent).into_iter()),
    );
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
        let lidar_xy: Vec<(f32, f32)> = lidars.iter().map(|l| (l.2.position.x, l.2.position.y)).collect();
        let terms = summaries(&points.per_user(&world, &lidars, |a, p| view(a, p, &lidar_xy))?);
        for (name, summary) in [
            (hilo_validate::set::LIDAR_POINTS_CAPPED, "points capped at 5"),
            (hilo_validate::set::LIDAR_EXTENT, "extent: single LiDARs' summed, capped at 1"),
        ] {
            let recorded = m.predictors.get(name).copied().flatten();
            let recount = terms[summary];
            if recorded.is_none_or(|r| (r - recount).abs() > 1e-9) {
                return Err(format!(
                    "{}: {} recounts {name:?} as {recount}, the set recorded {recorded:?} (refit the set with this build)",
                    dir.display(),
                    m.slug
                )
                .into());
            }
        }
        rows.push((terms, trained.map_mean));
    }
    let name = dir.file_name().map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into_owned());
    Ok((name, rows, report))
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
        .filter(|t| sites.iter().all(|(_, rows, _)| rows.iter().all(|r| r.0.contains_key(*t))))
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
    for (h, (name, _, _)) in sites.iter().enumerate() {
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
    let reports: Vec<&hilo_validate::ValidationReport> = sites.iter().map(|s| &s.2).collect();
    let (a, b) = (hilo_validate::set::LIDAR_EXTENT, hilo_validate::set::LIDAR_POINTS_CAPPED);
    let d = hilo_validate::sites::predictor_difference(&reports, a, b, 5);
    println!(
        "\nMean ρ over the sites, {a:?} − {b:?}: {:+.2} [{:+.2}, {:+.2}] (paired bootstrap over placements, scenes and trainings)",
        d.value, d.lo, d.hi
    );
    Ok(())
}
