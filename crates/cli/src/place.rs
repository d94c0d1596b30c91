//! `hilo place`: optimal placement of each configuration of a study, with coverage maps.

use crate::render::scene_canvas;
use crate::study::{Configuration, Study};
use crate::{load_scene, write_atomic};
use anyhow::{Context, Result, bail};
use glam::{Vec2, Vec3};
use hilo_placement_ip::greedy::greedy;
use hilo_placement_ip::mip::{Formulation, write_mps};
use hilo_placement_ip::pipeline::{Prepared, instance, prepare, solve_from};
use hilo_placement_ip::{Instance, Limit, Modality};
use hilo_raycast::scene::config::RoiKind;
use hilo_raycast::{QueryRegion, Scene, World};
use hilo_sensor_models::{Catalog, SensorPose};
use serde::Serialize;
use serde_json::json;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct PlaceArgs {
    /// Study TOML; the embedded default (the paper's three configurations) when omitted.
    pub study: Option<PathBuf>,
    /// Output folder: <configuration>.json and <configuration>.png per configuration.
    #[arg(long, default_value = "placements")]
    pub out: PathBuf,
    /// Print a JSON summary array on stdout.
    #[arg(long)]
    pub json: bool,
    /// Also write visibility matrices (JSON) and each model (MPS) to this folder.
    #[arg(long)]
    pub export: Option<PathBuf>,
}

#[derive(Serialize, Debug, Clone)]
pub struct PlacedSensor {
    #[serde(rename = "type")]
    pub ty: String,
    pub modality: Modality,
    pub candidate_id: u32,
    pub structure: String,
    pub pose: SensorPose,
    pub position_m: [f32; 3],
    pub yaw_deg: f32,
    pub pitch_deg: f32,
}

#[derive(Serialize, Debug, Clone)]
pub struct Placement {
    pub name: String,
    pub sensors: Vec<PlacedSensor>,
    pub objective: f64,
    pub bound: f64,
    pub gap: f64,
    pub proven_optimal: bool,
    pub solve_seconds: f64,
    pub method: String,
    pub greedy_objective: f64,
    /// Share of central-ROI cells hit by at least one LiDAR ray (the paper's central coverage).
    pub central_coverage: f64,
    /// Share of all ROI cells hit by a LiDAR ray and covered by a radar.
    pub lidar_radar_overlap: f64,
    pub cost_usd: f64,
    pub targets: usize,
    pub candidates: usize,
}

/// Which targets the chosen LiDARs hit with at least one ray.
fn lidar_hit_cells(
    scene: &Scene,
    world: &World,
    catalog: &Catalog,
    prep: &Prepared,
    cell: f32,
    sensors: &[PlacedSensor],
) -> Result<HashSet<usize>> {
    let lidars = sensors
        .iter()
        .filter(|s| s.modality == Modality::Lidar)
        .map(|s| Ok((catalog.lidar(&s.ty)?.clone(), s.pose)))
        .collect::<Result<Vec<_>>>()?;
    Ok(hilo_placement_ip::coverage::lidar_hit_targets(scene, world, &prep.targets, cell, &lidars)?)
}

/// The modalities of a configuration's sensor types.
pub(crate) fn modalities(conf: &Configuration, catalog: &Catalog) -> HashSet<Modality> {
    conf.type_names().iter().map(|t| if catalog.lidar(t).is_ok() { Modality::Lidar } else { Modality::Radar }).collect()
}

/// Whether a configuration has sensors of one modality only: the paper's objective (targets
/// covered by both) is then zero whatever the placement, so it takes the poses of a sibling
/// configuration instead of being optimised.
pub(crate) fn single_modality(conf: &Configuration, catalog: &Catalog) -> bool {
    modalities(conf, catalog).len() == 1
}

pub(crate) fn limit_for(cfg: &Configuration, types: &[String]) -> Limit {
    match cfg.budget_usd {
        Some(usd) => Limit::Budget {
            usd,
            min: types.iter().map(|t| cfg.min.get(t).copied().unwrap_or(0)).collect(),
            max: types.iter().map(|t| cfg.max.get(t).copied().unwrap_or(u32::MAX)).collect(),
        },
        None => Limit::Counts(types.iter().map(|t| cfg.sensors.get(t).copied().unwrap_or(0)).collect()),
    }
}

pub fn run(args: &PlaceArgs) -> Result<Vec<Placement>> {
    let study = Study::load(args.study.as_deref())?;
    let scene = load_scene(study.file.scene.as_ref().map(|p| study.resolve(p)).as_deref())?;
    let catalog = match &study.file.catalog {
        Some(p) => Catalog::load(&study.resolve(p))?,
        None => Catalog::default_catalog()?,
    };
    let all_types = study.type_names();
    for t in &all_types {
        catalog.get(t).with_context(|| format!("{}: a configuration names sensor {t:?}", study.source))?;
    }
    let cfg = &study.file.placement;
    eprintln!("placement: computing visibility of {} sensor types on {}", all_types.len(), scene.source_name());
    let prep = prepare(&scene, &catalog, &all_types, cfg)?;
    eprintln!(
        "  {} targets, {} candidates; line of sight {:.2} s, visibility {:.2} s",
        prep.targets.len(),
        prep.candidates.len(),
        prep.seconds_line_of_sight,
        prep.seconds_visibility
    );
    let world = World::build(&scene, &QueryRegion::everything())?;
    let central_roi: Vec<usize> =
        scene.config.roi.iter().enumerate().filter(|(_, r)| r.kind == RoiKind::Central).map(|(i, _)| i).collect();
    let central: Vec<usize> =
        (0..prep.targets.len()).filter(|&j| central_roi.contains(&(prep.targets[j].roi as usize))).collect();
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    if let Some(dir) = &args.export {
        export_visibility(dir, &prep, &all_types)?;
    }
    let mut out = Vec::new();
    let mut deferred = Vec::new();
    for conf in &study.file.configurations {
        // One modality: the paper's objective (targets covered by both) is zero whatever the
        // placement; placed after the others, from a configuration that adds the other modality.
        if single_modality(conf, &catalog) {
            deferred.push(conf);
            continue;
        }
        let types = conf.type_names();
        let inst = instance(&prep, &catalog, &types, cfg.p_min)?;
        let limit = limit_for(conf, &types);
        if let Limit::Budget { usd, .. } = &limit {
            let cheapest = inst.types.iter().map(|t| t.price_usd).fold(f64::INFINITY, f64::min);
            if cheapest > *usd {
                bail!(
                    "{}: configuration {:?}: the budget of {usd} USD buys no sensor (cheapest {cheapest} USD)",
                    study.source,
                    conf.name
                );
            }
        }
        let g = greedy(&inst, &limit);
        let o = solve_from(&inst, &limit, cfg.time_limit_s, &g)?;
        let sensors = placed(&inst, &prep, &o.selection);
        let hits = lidar_hit_cells(&scene, &world, &catalog, &prep, cfg.cell_m, &sensors)?;
        let radar_cov = radar_covered(&inst, &o.selection);
        let central_coverage = hilo_placement_ip::coverage::share(&central, &hits);
        let overlap = (0..prep.targets.len()).filter(|j| hits.contains(j) && radar_cov.contains(j)).count() as f64
            / prep.targets.len() as f64;
        let p = Placement {
            name: conf.name.clone(),
            sensors,
            objective: o.objective,
            bound: o.bound,
            gap: o.gap,
            proven_optimal: o.proven_optimal,
            solve_seconds: o.solve_seconds,
            method: o.method.clone(),
            greedy_objective: g.objective,
            central_coverage,
            lidar_radar_overlap: overlap,
            cost_usd: inst.cost(&o.selection),
            targets: prep.targets.len(),
            candidates: prep.candidates.len(),
        };
        let slug = conf.slug();
        write_atomic(&args.out.join(format!("{slug}.json")), serde_json::to_string_pretty(&p)?.as_bytes())?;
        let png = coverage_png(&scene, &prep, &p, &hits, &radar_cov)?;
        write_atomic(&args.out.join(format!("{slug}.png")), &png)?;
        if let Some(dir) = &args.export {
            write_mps(&inst, &limit, Formulation::Strengthened, &dir.join(&slug))?;
        }
        eprintln!(
            "  {:<24} objective {:>9.1} (greedy {:>9.1}) {} in {:.3} s, central coverage {:.1}%, cost {} USD",
            p.name,
            p.objective,
            p.greedy_objective,
            if p.proven_optimal { "proven optimal".to_owned() } else { format!("gap {:.1}%", 100.0 * p.gap) },
            p.solve_seconds,
            100.0 * p.central_coverage,
            p.cost_usd
        );
        out.push(p);
    }
    for conf in deferred {
        let want = &conf.sensors;
        let sibling = out.iter().find(|p| {
            let mut counts: std::collections::BTreeMap<String, u32> = std::collections::BTreeMap::new();
            for s in p.sensors.iter().filter(|s| want.contains_key(&s.ty)) {
                *counts.entry(s.ty.clone()).or_default() += 1;
            }
            conf.budget_usd.is_none() && &counts == want && p.sensors.len() > want.values().sum::<u32>() as usize
        });
        let Some(sib) = sibling else {
            bail!(
                "{}: configuration {:?} has a single modality, for which the paper's objective (targets seen by both LiDAR and radar) is zero whatever the placement; add a configuration with the same sensors plus the other modality (hilo then uses its poses), e.g. {:?} + a radar",
                study.source,
                conf.name,
                conf.name
            );
        };
        let sensors: Vec<PlacedSensor> = sib.sensors.iter().filter(|s| want.contains_key(&s.ty)).cloned().collect();
        let hits = lidar_hit_cells(&scene, &world, &catalog, &prep, cfg.cell_m, &sensors)?;
        let cost_usd = sensors.iter().map(|s| catalog.get(&s.ty).map(|c| c.price_usd())).sum::<Result<f64, _>>()?;
        let p = Placement {
            name: conf.name.clone(),
            sensors,
            objective: 0.0,
            bound: 0.0,
            gap: 0.0,
            proven_optimal: false,
            solve_seconds: 0.0,
            method: format!(
                "the {} poses of {:?} (one modality: the multimodal objective is zero)",
                conf.type_names().join(", "),
                sib.name
            ),
            greedy_objective: 0.0,
            central_coverage: hilo_placement_ip::coverage::share(&central, &hits),
            lidar_radar_overlap: 0.0,
            cost_usd,
            targets: prep.targets.len(),
            candidates: prep.candidates.len(),
        };
        let slug = conf.slug();
        write_atomic(&args.out.join(format!("{slug}.json")), serde_json::to_string_pretty(&p)?.as_bytes())?;
        let png = coverage_png(&scene, &prep, &p, &hits, &HashSet::new())?;
        write_atomic(&args.out.join(format!("{slug}.png")), &png)?;
        eprintln!(
            "  {:<24} {}, central coverage {:.1}%, cost {} USD",
            p.name,
            p.method,
            100.0 * p.central_coverage,
            p.cost_usd
        );
        out.push(p);
    }
    if args.json {
        let summary: Vec<_> = out
            .iter()
            .map(|p| json!({"name": p.name, "objective": p.objective, "bound": p.bound, "gap": p.gap, "proven_optimal": p.proven_optimal, "solve_seconds": p.solve_seconds, "central_coverage": p.central_coverage, "lidar_radar_overlap": p.lidar_radar_overlap, "cost_usd": p.cost_usd, "sensors": p.sensors.len()}))
            .collect();
        println!("{}", serde_json::to_string(&summary)?);
    }
    Ok(out)
}

fn placed(inst: &Instance, prep: &Prepared, sel: &[usize]) -> Vec<PlacedSensor> {
    sel.iter()
        .map(|&o| {
            let opt = &inst.options[o];
            let c = &prep.candidates[opt.candidate as usize];
            PlacedSensor {
                ty: inst.types[opt.ty].name.clone(),
                modality: c.modality,
                candidate_id: c.id,
                structure: c.structure.clone(),
                pose: c.pose,
                position_m: c.pose.position.to_array(),
                yaw_deg: c.pose.yaw.to_degrees(),
                pitch_deg: c.pose.pitch.to_degrees(),
            }
        })
        .collect()
}

fn radar_covered(inst: &Instance, sel: &[usize]) -> HashSet<usize> {
    hilo_placement_ip::instance::covered_targets(inst, sel, Modality::Radar).into_iter().collect()
}

fn coverage_png(
    scene: &Scene,
    prep: &Prepared,
    p: &Placement,
    hits: &HashSet<usize>,
    radar: &HashSet<usize>,
) -> Result<Vec<u8>> {
    let mut c = scene_canvas(scene, 4.0)?;
    let cells: Vec<(Vec2, (u8, u8, u8))> = prep
        .targets
        .iter()
        .enumerate()
        .filter_map(|(j, t)| match (hits.contains(&j), radar.contains(&j)) {
            (true, true) => Some((t.center, (250, 220, 30))),
            (true, false) => Some((t.center, (40, 200, 80))),
            (false, true) => Some((t.center, (230, 60, 60))),
            (false, false) => None,
        })
        .collect();
    c.dots(&cells, 1.6);
    let cands: Vec<(Vec2, (u8, u8, u8))> =
        prep.candidates.iter().map(|k| (k.pose.position.truncate(), (120, 120, 120))).collect();
    c.dots(&cands, 1.2);
    for s in &p.sensors {
        let pos = Vec3::from(s.position_m).truncate();
        let col = if s.modality == Modality::Lidar { (0, 160, 60) } else { (220, 0, 0) };
        let tip = pos + Vec2::from_angle(s.pose.yaw) * 12.0;
        c.line(&[pos, tip], col, 0.5);
        c.dots(&[(pos, (0, 0, 0))], 7.0);
        c.dots(&[(pos, col)], 5.5);
    }
    c.png()
}

fn export_visibility(dir: &Path, prep: &Prepared, types: &[String]) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let targets: Vec<_> = prep
        .targets
        .iter()
        .map(|t| json!({"x": t.center.x, "y": t.center.y, "weight": t.weight, "roi": t.roi}))
        .collect();
    let candidates: Vec<_> = prep
        .candidates
        .iter()
        .map(|c| json!({"id": c.id, "modality": c.modality, "mount": c.mount, "structure": c.structure, "position_m": c.pose.position.to_array(), "yaw_deg": c.pose.yaw.to_degrees(), "pitch_deg": c.pose.pitch.to_degrees()}))
        .collect();
    write_atomic(&dir.join("targets.json"), serde_json::to_string(&targets)?.as_bytes())?;
    write_atomic(&dir.join("candidates.json"), serde_json::to_string(&candidates)?.as_bytes())?;
    for t in types {
        let v = &prep.visibility[t];
        // Coordinate (COO) sparse format: parallel arrays of candidate id, target index and V.
        let (mut ci, mut tj, mut vv) = (Vec::new(), Vec::new(), Vec::new());
        for (row, &cand) in v.rows.iter().zip(&v.candidates) {
            for &(j, x) in row {
                ci.push(cand);
                tj.push(j);
                vv.push(x);
            }
        }
        let doc =
            json!({"sensor": t, "format": "coo", "n_targets": v.n_targets, "candidate": ci, "target": tj, "v": vv});
        write_atomic(&dir.join(format!("visibility_{t}.json")), serde_json::to_string(&doc)?.as_bytes())?;
    }
    Ok(())
}
