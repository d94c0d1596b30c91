//! Placement of every configuration of a study: visibility computed once for every sensor type,
//! each configuration solved (exact search or CBC; one of a single modality for that
//! modality's coverage), coverage measured by casting the chosen LiDARs' rays.

use crate::error::{Result, StudyError};
use crate::render::scene_canvas;
use crate::study::{Configuration, Study};
use glam::{Vec2, Vec3};
use hilo_placement_ip::calibrated::file::Prediction;
use hilo_placement_ip::greedy::greedy;
use hilo_placement_ip::pipeline::{ObjectiveKind, Prepared, instance, prepare, solve_from};
use hilo_placement_ip::{Instance, Limit, Modality, Outcome, PlacedSensor, Placement};
use hilo_raycast::scene::config::RoiKind;
use hilo_raycast::{QueryRegion, World};
use std::collections::{HashMap, HashSet};

/// What placing a study computed: the targets, candidates and visibility of every sensor type
/// (reused by the trade-off sweeps), and each configuration's placement with its coverage.
#[derive(Debug)]
pub struct Placed {
    pub prepared: Prepared,
    pub placements: Vec<Placement>,
    /// Per placement (same order): the targets its LiDARs hit and its radars cover.
    pub lidar_hits: Vec<HashSet<usize>>,
    pub radar_covered: Vec<HashSet<usize>>,
}

/// The limit a configuration puts on an instance over `types`.
pub fn limit_for(cfg: &Configuration, types: &[String]) -> Limit {
    match cfg.budget_usd {
        Some(usd) => Limit::Budget {
            usd,
            min: types.iter().map(|t| cfg.min.get(t).copied().unwrap_or(0)).collect(),
            max: types.iter().map(|t| cfg.max.get(t).copied().unwrap_or(u32::MAX)).collect(),
        },
        None => Limit::Counts(types.iter().map(|t| cfg.sensors.get(t).copied().unwrap_or(0)).collect()),
    }
}

/// The options of `inst` that hold the sensors configuration `name` was placed with (already
/// among `placements`): the same type at the same candidate.
fn given_options(
    inst: &Instance,
    prep: &Prepared,
    conf: &Configuration,
    name: &str,
    placements: &[Placement],
    source: &str,
) -> Result<Vec<usize>> {
    let refuse =
        |reason: String| StudyError::setting(source, format!("configuration {:?}: given", conf.name), name, reason);
    let base = placements
        .iter()
        .find(|p| p.name == name)
        .ok_or_else(|| refuse("is not placed before this configuration".into()))?;
    base.sensors
        .iter()
        .map(|s| {
            (0..inst.options.len())
                .find(|&o| {
                    let opt = &inst.options[o];
                    inst.types[opt.ty].name == s.ty && prep.candidates[opt.candidate as usize].id == s.candidate_id
                })
                .ok_or_else(|| {
                    refuse(format!(
                        "its {} at candidate {} is not an option of this configuration",
                        s.ty, s.candidate_id
                    ))
                })
        })
        .collect()
}

/// Drops the options that would stand a sensor on a structure holding one of `given` of its
/// type (a configuration placed `apart`), keeping the given sensors' own options.
fn keep_apart(inst: &mut Instance, prep: &Prepared, given: &[PlacedSensor]) {
    let taken: HashSet<(&str, &str)> = given.iter().map(|s| (s.ty.as_str(), s.structure.as_str())).collect();
    let types = &inst.types;
    inst.options.retain(|o| {
        let c = &prep.candidates[o.candidate as usize];
        let ty = types[o.ty].name.as_str();
        !taken.contains(&(ty, c.structure.as_str())) || given.iter().any(|s| s.ty == ty && s.candidate_id == c.id)
    });
}

/// The sensors an instance's selection places (type, candidate, structure, pose).
pub fn placed(inst: &Instance, prep: &Prepared, sel: &[usize]) -> Vec<PlacedSensor> {
    sel.iter()
        .map(|&o| {
            let opt = &inst.options[o];
            let c = &prep.candidates[opt.candidate as usize];
            PlacedSensor::new(&inst.types[opt.ty].name, c.modality, c.id, &c.structure, c.pose)
        })
        .collect()
}

/// The targets in the scene's central ROIs (where the paper's central coverage is measured).
pub fn central_targets(study: &Study, prep: &Prepared) -> Vec<usize> {
    let central_roi: Vec<usize> =
        study.scene.config.roi.iter().enumerate().filter(|(_, r)| r.kind == RoiKind::Central).map(|(i, _)| i).collect();
    (0..prep.targets.len()).filter(|&j| central_roi.contains(&(prep.targets[j].roi as usize))).collect()
}

/// The targets the placed LiDARs hit with a ray (ideal scans of the static `world`).
pub fn lidar_hits(
    study: &Study,
    world: &World,
    prep: &Prepared,
    cell_m: f32,
    sensors: &[PlacedSensor],
) -> Result<HashSet<usize>> {
    let lidars = sensors
        .iter()
        .filter(|s| s.modality == Modality::Lidar)
        .map(|s| Ok((study.catalog.lidar(&s.ty)?.clone(), s.pose)))
        .collect::<Result<Vec<_>>>()?;
    Ok(hilo_placement_ip::coverage::lidar_hit_targets(&study.scene, world, &prep.targets, cell_m, &lidars)?)
}

/// Visibility of every sensor type of the study.
pub fn prepare_study(study: &Study) -> Result<Prepared> {
    Ok(prepare(&study.scene, &study.catalog, &study.type_names(), &study.placement)?)
}

/// The calibrated objective's point-count and footprint rows, each computed once per (type,
/// candidate) over the study's training traffic ([`crate::road_users::TrafficPoints::rows`],
/// [`crate::road_users::TrafficPoints::extent_rows`]).
#[derive(Default)]
struct PointCache {
    traffic: Option<crate::road_users::TrafficPoints>,
    points: CachedRows,
    extents: CachedRows,
}

#[derive(Default)]
struct CachedRows {
    k: f64,
    weights: Vec<f64>,
    rows: HashMap<(String, u32), Vec<(u32, u32)>>,
}

/// Key frames between two the point-count term samples (as the validation's occupancy
/// predictor does).
pub const POINTS_EVERY: usize = 20;

impl PointCache {
    /// The point rows, or with `extents` the footprint rows, of `inst`'s options.
    fn rows(
        &mut self,
        study: &Study,
        world: &World,
        prep: &Prepared,
        inst: &Instance,
        extents: bool,
    ) -> Result<hilo_placement_ip::instance::PointRows> {
        let tp = sampled(&mut self.traffic, study)?;
        let cache = if extents { &mut self.extents } else { &mut self.points };
        let key = |o: usize| (inst.types[inst.options[o].ty].name.clone(), inst.options[o].candidate);
        let missing: Vec<usize> = (0..inst.options.len())
            .filter(|&o| inst.modality(o) == Modality::Lidar && !cache.rows.contains_key(&key(o)))
            .collect();
        let lidar_of = |i: usize| option_lidar(study, prep, inst, missing[i]);
        let new = if extents {
            tp.extent_rows(world, missing.len(), lidar_of)?
        } else {
            tp.rows(world, missing.len(), lidar_of, study.file.validation.min_points)?
        };
        cache.k = new.k;
        cache.weights = new.weights;
        for (i, row) in new.rows.into_iter().enumerate() {
            cache.rows.insert(key(missing[i]), row);
        }
        let rows = (0..inst.options.len()).map(|o| cache.rows.get(&key(o)).cloned().unwrap_or_default()).collect();
        Ok(hilo_placement_ip::instance::PointRows { k: cache.k, weights: cache.weights.clone(), rows })
    }

    /// The hit floors of `[placement] min_hit_share` over `inst`'s options: per class, its road
    /// users in the sampled training traffic and, per LiDAR option, those it puts a point on
    /// (the point rows' samples, so the floors and the point term see the same scans; `inst`'s
    /// own point rows where the weights had them computed).
    fn floors(
        &mut self,
        study: &Study,
        world: &World,
        prep: &Prepared,
        inst: &Instance,
    ) -> Result<Vec<hilo_placement_ip::instance::HitFloor>> {
        let counted;
        let points = if inst.points.is_empty() {
            counted = self.rows(study, world, prep, inst, false)?;
            &counted
        } else {
            &inst.points
        };
        sampled(&mut self.traffic, study)?.hit_floors(points, &study.placement.min_hit_share, &study.source)
    }

    /// The calibration file's prediction for `selection` (options of `inst`), with the share
    /// of each class of the sampled training traffic its LiDARs put no point on
    /// ([`crate::road_users::TrafficPoints::never_hit`]); None without a calibration file.
    fn predicted(
        &mut self,
        study: &Study,
        world: &World,
        prep: &Prepared,
        inst: &Instance,
        selection: &[usize],
    ) -> Result<Option<Prediction>> {
        let Some(c) = &study.calibration else { return Ok(None) };
        let tp = sampled(&mut self.traffic, study)?;
        let lidars: Vec<usize> = selection.iter().copied().filter(|&o| inst.modality(o) == Modality::Lidar).collect();
        let never_hit = tp.never_hit(world, lidars.len(), |i| option_lidar(study, prep, inst, lidars[i]))?;
        Ok(Some(Prediction { never_hit, ..c.predict(inst, selection) }))
    }
}

/// The study's training traffic sampled for the point terms, sampled into `traffic` on first
/// use (a free function over the one field, so the caller may borrow the caches beside it).
fn sampled<'a>(
    traffic: &'a mut Option<crate::road_users::TrafficPoints>,
    study: &Study,
) -> Result<&'a crate::road_users::TrafficPoints> {
    match traffic {
        Some(tp) => Ok(tp),
        None => {
            let t = crate::road_users::TrainingTraffic::new(study)?;
            Ok(traffic.insert(crate::road_users::TrafficPoints::new(&t, POINTS_EVERY)?))
        }
    }
}

/// Option `o` of `inst` as a LiDAR: its spec and the pose of its candidate mount (None for a
/// radar), as the point-count term casts it.
pub fn option_lidar(
    study: &Study,
    prep: &Prepared,
    inst: &Instance,
    o: usize,
) -> Option<(hilo_sensor_models::LidarSpec, hilo_sensor_models::SensorPose)> {
    let opt = &inst.options[o];
    let c = &prep.candidates[opt.candidate as usize];
    study.catalog.lidar(&inst.types[opt.ty].name).ok().map(|l| (l.clone(), c.pose))
}

/// Places every configuration; `progress` hears one line per configuration.
pub fn place_all(study: &Study, prep: Prepared, progress: &mut dyn FnMut(&str)) -> Result<Placed> {
    let scene = &study.scene;
    let catalog = &study.catalog;
    let cfg = &study.placement;
    let world = World::build(scene, &QueryRegion::everything())?;
    let central = central_targets(study, &prep);
    let hits_of = |sensors: &[PlacedSensor]| lidar_hits(study, &world, &prep, cfg.cell_m, sensors);
    struct Out {
        placements: Vec<Placement>,
        lidar_hits: Vec<HashSet<usize>>,
        radar_covered: Vec<HashSet<usize>>,
    }
    let mut out = Out { placements: Vec::new(), lidar_hits: Vec::new(), radar_covered: Vec::new() };
    // The road users of the study's traffic on each target, counted once when the calibrated
    // objective weighs them.
    let mut road_users: Option<Vec<f64>> = None;
    // And the LiDAR points every LiDAR option puts on them and the footprint they span, counted
    // once per (type, candidate).
    let mut points = PointCache::default();
    // Each configuration after the one it is placed given (by depth in its chain; the study
    // file's check refuses cycles), so it finds its given rig placed; the result is in the
    // file's order.
    let confs = &study.file.configurations;
    let depths = crate::study::given_depths(confs);
    let mut order: Vec<usize> = (0..confs.len()).collect();
    order.sort_by_key(|&i| depths[i]);
    for &ci in &order {
        let conf = &confs[ci];
        // A configuration of one modality is placed for that modality's coverage
        // (`Instance::requires`): the paper's both-modality objective would be zero for it.
        let types = conf.type_names();
        let mut inst = instance(&prep, catalog, &types, cfg.p_min)?;
        let limit = limit_for(conf, &types);
        if conf.apart
            && let Some(base) = conf.given.as_ref().and_then(|g| out.placements.iter().find(|p| &p.name == g))
        {
            keep_apart(&mut inst, &prep, &base.sensors);
        }
        check_limit(study, conf, &inst, &limit, &prep)?;
        let given = match &conf.given {
            Some(name) => Some(given_options(&inst, &prep, conf, name, &out.placements, &study.source)?),
            None => None,
        };
        let (g, o) = match (cfg.objective, &cfg.calibration, given) {
            (ObjectiveKind::Paper, _, Some(fixed)) => {
                let g = hilo_placement_ip::greedy::greedy_given(&inst, &limit, &fixed);
                let o = hilo_placement_ip::pipeline::solve_given(&inst, &limit, &fixed, cfg.solve_limit())?;
                (g, o)
            }
            (ObjectiveKind::Calibrated, Some(w), fixed) => {
                let fixed = fixed.unwrap_or_default();
                if w.reads_road_users() {
                    if road_users.is_none() {
                        let traffic = crate::road_users::TrainingTraffic::new(study)?;
                        road_users = Some(crate::road_users::road_users(&traffic, &prep.targets, cfg.cell_m)?.weights);
                    }
                    inst.road_users = road_users.clone().unwrap_or_default();
                }
                if w.reads_points() {
                    inst.points = points.rows(study, &world, &prep, &inst, false)?;
                }
                if w.reads_extents() {
                    inst.extents = points.rows(study, &world, &prep, &inst, true)?;
                }
                // The hit floors hold for every rig with a LiDAR (one without can hit nothing).
                if !cfg.min_hit_share.is_empty() && (0..inst.options.len()).any(|o| inst.modality(o) == Modality::Lidar)
                {
                    inst.floors = points.floors(study, &world, &prep, &inst)?;
                }
                let g = hilo_placement_ip::calibrated::greedy_given(&inst, &limit, w, &fixed);
                let o = hilo_placement_ip::calibrated::solve_given(
                    &inst,
                    &limit,
                    w,
                    (cfg.solve_limit(), cfg.calibrated_cbc_max_nonzeros),
                    &g,
                    &fixed,
                )
                .map_err(|e| StudyError::step(format!("placing configuration {:?}", conf.name), e))?;
                let o = if fixed.is_empty() {
                    o
                } else {
                    Outcome { method: format!("{}, {} given sensor(s) fixed", o.method, fixed.len()), ..o }
                };
                (g, o)
            }
            _ => {
                let g = greedy(&inst, &limit);
                let o = solve_from(&inst, &limit, cfg.solve_limit(), &g)?;
                (g, o)
            }
        };
        let sensors = placed(&inst, &prep, &o.selection);
        let hits = hits_of(&sensors)?;
        let radar: HashSet<usize> =
            hilo_placement_ip::instance::covered_targets(&inst, &o.selection, Modality::Radar).into_iter().collect();
        let overlap = (0..prep.targets.len()).filter(|j| hits.contains(j) && radar.contains(j)).count() as f64
            / prep.targets.len().max(1) as f64;
        let p = Placement {
            name: conf.name.clone(),
            sensors,
            objective: o.objective,
            bound: o.bound,
            gap: o.gap,
            proven_optimal: o.proven_optimal,
            solve_seconds: o.solve_seconds,
            method: o.method.clone(),
            solved: true,
            greedy_objective: g.objective,
            central_coverage: hilo_placement_ip::coverage::share(&central, &hits),
            lidar_radar_overlap: overlap,
            cost_usd: inst.cost(&o.selection),
            targets: prep.targets.len(),
            candidates: prep.candidates.len(),
            scene_hash: study.scene_hash.clone(),
            catalog_hash: study.catalog_hash.clone(),
            prediction: points.predicted(study, &world, &prep, &inst, &o.selection)?,
        };
        progress(&format!(
            "{:<24} objective {:>9.1} (greedy {:>9.1}) {} in {:.3} s, central coverage {:.1}%, cost {} USD",
            p.name,
            p.objective,
            p.greedy_objective,
            if p.proven_optimal { "proven optimal".to_owned() } else { format!("gap {:.1}%", 100.0 * p.gap) },
            p.solve_seconds,
            100.0 * p.central_coverage,
            p.cost_usd
        ));
        for line in p.prediction.iter().flat_map(prediction_lines).chain(unfilled(&p, &limit, &types)) {
            progress(&format!("{:<24} {line}", ""));
        }
        out.placements.push(p);
        out.lidar_hits.push(hits);
        out.radar_covered.push(radar);
    }
    // Back to the file's order: the k-th placed is configuration order[k].
    let mut at = vec![0; order.len()];
    for (k, &ci) in order.iter().enumerate() {
        at[ci] = k;
    }
    let Out { placements, mut lidar_hits, mut radar_covered } = out;
    let placements = at.iter().map(|&k| placements[k].clone()).collect();
    let lidar_hits = at.iter().map(|&k| std::mem::take(&mut lidar_hits[k])).collect();
    let radar_covered = at.iter().map(|&k| std::mem::take(&mut radar_covered[k])).collect();
    Ok(Placed { prepared: prep, placements, lidar_hits, radar_covered })
}

/// What `hilo place` prints of a rig's prediction: its predicted mAP and how far the junction
/// lies from the fitted sites, and the share of each class its LiDARs never hit.
fn prediction_lines(pr: &Prediction) -> Vec<String> {
    let mut lines = vec![format!("predicted mAP {:.3} [{:.3}, {:.3}]; {}", pr.map, pr.lo, pr.hi, pr.advice)];
    if !pr.never_hit.is_empty() {
        let shares: Vec<String> = pr.never_hit.iter().map(|(c, v)| format!("{c} {:.1}%", 100.0 * v)).collect();
        lines.push(format!("no LiDAR point on (sampled training traffic): {}", shares.join(", ")));
    }
    lines
}

/// For a configuration of sensor counts (each an upper limit), the types of which `p` holds
/// fewer than it may: the objective gains nothing from more of them (a calibrated objective that
/// weighs radar 0 places no radar), which a user who named the rig should be told.
fn unfilled(p: &Placement, limit: &Limit, types: &[String]) -> Vec<String> {
    let Limit::Counts(counts) = limit else { return Vec::new() };
    types
        .iter()
        .zip(counts)
        .filter_map(|(ty, &n)| {
            let held = p.sensors.iter().filter(|s| &s.ty == ty).count();
            (held < n as usize)
                .then(|| format!("holds {held} of the {n} {ty} it may: this objective gains nothing from more"))
        })
        .collect()
}

/// Refuses what no solver can satisfy: a budget that buys no sensor, more sensors of a type than
/// it has candidates.
fn check_limit(
    study: &Study,
    conf: &Configuration,
    inst: &Instance,
    limit: &Limit,
    prep: &Prepared,
) -> std::result::Result<(), StudyError> {
    match limit {
        Limit::Budget { usd, .. } => {
            let cheapest = inst.types.iter().map(|t| t.price_usd).fold(f64::INFINITY, f64::min);
            if cheapest > *usd {
                return Err(StudyError::setting(
                    &study.source,
                    format!("configuration {:?}: budget", conf.name),
                    format!("{usd} USD"),
                    format!("buys no sensor (cheapest {cheapest} USD)"),
                ));
            }
        }
        Limit::Total(_) => {}
        Limit::Counts(counts) => {
            for (t, &n) in inst.types.iter().zip(counts) {
                let mounts: HashSet<u32> =
                    prep.candidates.iter().filter(|c| c.modality == t.modality).map(|c| c.mount).collect();
                let available = inst
                    .options
                    .iter()
                    .filter(|o| inst.types[o.ty].name == t.name)
                    .map(|o| o.mount)
                    .collect::<HashSet<_>>()
                    .len();
                if n as usize > available {
                    return Err(StudyError::setting(
                        &study.source,
                        format!("configuration {:?}", conf.name),
                        format!("{n} x {}", t.name),
                        format!(
                            "the scene offers {available} mount points for it ({} candidate mounts of its modality; one sensor per mount point)",
                            mounts.len()
                        ),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The coverage map of a placement: green LiDAR-hit cells, red radar-covered, yellow both; grey
/// candidates; the chosen sensors with their headings.
pub fn coverage_png(
    study: &Study,
    prep: &Prepared,
    p: &Placement,
    hits: &HashSet<usize>,
    radar: &HashSet<usize>,
) -> Result<Vec<u8>> {
    let mut c = scene_canvas(&study.scene, 4.0)?;
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
    draw_sensors(&mut c, p);
    c.legend(&[
        ((40, 200, 80), "cell hit by a LiDAR ray"),
        ((230, 60, 60), "cell covered by a radar"),
        ((250, 220, 30), "both"),
        ((120, 120, 120), "candidate mount"),
        ((0, 160, 60), "chosen LiDAR, heading"),
        ((220, 0, 0), "chosen radar, heading"),
    ]);
    c.png()
}

/// Margin around the sensors in [`mounts_png`], metres.
pub const MOUNTS_MARGIN_M: f32 = 20.0;

/// The placement's sensors on the study's site picture, each with its heading and, beside each
/// mount, the sensors it holds (no coverage: it needs only the placement, so any placement a
/// report holds can be drawn again). The window is the sensors' bounding box widened by
/// [`MOUNTS_MARGIN_M`] on every side, within the scene's ground, at 16 px per metre.
pub fn mounts_png(study: &Study, p: &Placement) -> Result<Vec<u8>> {
    let g = study.scene.ground;
    let xy: Vec<Vec2> = p.sensors.iter().map(|s| Vec3::from(s.position_m).truncate()).collect();
    let (lo, hi) = xy.iter().fold((g.max, g.min), |(lo, hi), q| (lo.min(*q), hi.max(*q)));
    let (lo, hi) = if xy.is_empty() { (g.min, g.max) } else { (lo - MOUNTS_MARGIN_M, hi + MOUNTS_MARGIN_M) };
    let mut c = crate::render::scene_canvas_within(&study.scene, lo.max(g.min), hi.min(g.max), 16.0)?;
    draw_sensors(&mut c, p);
    // One label per mount: the sensors on it, by type.
    let mut mounts: Vec<(Vec2, std::collections::BTreeMap<&str, usize>)> = Vec::new();
    for (s, q) in p.sensors.iter().zip(&xy) {
        match mounts.iter_mut().find(|(m, _)| m.distance(*q) < 0.5) {
            Some((_, types)) => *types.entry(s.ty.as_str()).or_default() += 1,
            None => mounts.push((*q, [(s.ty.as_str(), 1)].into())),
        }
    }
    for (q, types) in &mounts {
        let text: Vec<String> =
            types.iter().map(|(t, n)| if *n > 1 { format!("{n}× {t}") } else { (*t).to_owned() }).collect();
        let (x, y) = c.px(*q);
        c.text((x + 8.0, y + 6.0), &text.join(", "), 14.0, (0, 0, 0));
    }
    c.legend(&[((0, 160, 60), "LiDAR, heading"), ((220, 0, 0), "radar, heading")]);
    c.png()
}

/// Each sensor of `p` as a disc at its mount with a line along its heading.
fn draw_sensors(c: &mut crate::render::Canvas, p: &Placement) {
    for s in &p.sensors {
        let pos = Vec3::from(s.position_m).truncate();
        let col = if s.modality == Modality::Lidar { (0, 160, 60) } else { (220, 0, 0) };
        let tip = pos + Vec2::from_angle(s.pose.yaw) * 12.0;
        c.line(&[pos, tip], col, 0.5);
        c.dots(&[(pos, (0, 0, 0))], 7.0);
        c.dots(&[(pos, col)], 5.5);
    }
}

/// Writes `<dir>/<slug>.json` and `<slug>.png` for every placement.
///
/// The folder is claimed for the write ([`hilo_core::folder::claim`]: one writer, no links
/// inside), and a file of the same name that hilo did not write (a JSON that is not a placement,
/// a PNG whose placement is not beside it) is refused before anything is written.
pub fn write_placements(study: &Study, placed: &Placed, dir: &std::path::Path) -> Result<()> {
    let _claim = hilo_core::folder::claim(dir, hilo_core::folder::Mode::Exclusive)?;
    for p in &placed.placements {
        let slug = crate::study::slug(&p.name);
        refuse_foreign(&dir.join(format!("{slug}.json")), &dir.join(format!("{slug}.png")))?;
    }
    for (i, p) in placed.placements.iter().enumerate() {
        let slug = crate::study::slug(&p.name);
        hilo_core::fs::write_atomic(&dir.join(format!("{slug}.json")), p.to_json()?.as_bytes())?;
        let png = coverage_png(study, &placed.prepared, p, &placed.lidar_hits[i], &placed.radar_covered[i])?;
        hilo_core::fs::write_atomic(&dir.join(format!("{slug}.png")), &png)?;
    }
    Ok(())
}

/// Refuses to replace `json` or `png` unless hilo wrote them: the JSON must read as a
/// placement, and the PNG must be a PNG beside such a JSON.
fn refuse_foreign(json: &std::path::Path, png: &std::path::Path) -> Result<()> {
    let foreign = |path: &std::path::Path, what: &str| {
        StudyError::folder(
            path,
            format!(
                "exists and is not {what} hilo wrote; hilo does not replace another program's files: move it, or \
                 choose another output folder"
            ),
        )
    };
    let ours = match std::fs::symlink_metadata(json) {
        Err(_) => false,
        Ok(_) => match Placement::load(json) {
            Ok(_) => true,
            Err(_) => return Err(foreign(json, "a placement")),
        },
    };
    if std::fs::symlink_metadata(png).is_ok() {
        let magic = hilo_core::fs::read_bounded(png, hilo_core::fs::limit::TABLE)
            .is_ok_and(|b| b.starts_with(b"\x89PNG\r\n\x1a\n"));
        if !(ours && magic) {
            return Err(foreign(png, "a coverage map"));
        }
    }
    Ok(())
}

/// Writes what other solvers need to reproduce a study's placement: `targets.json`,
/// `candidates.json`, `visibility_<type>.json` (COO sparse: parallel arrays candidate, target,
/// v) and each configuration's strengthened model as gzip MPS (`<slug>.mps.gz`).
pub fn export(study: &Study, prep: &Prepared, dir: &std::path::Path) -> Result<()> {
    use serde_json::json;
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
    hilo_core::fs::write_json(&dir.join("targets.json"), &targets)?;
    hilo_core::fs::write_json(&dir.join("candidates.json"), &candidates)?;
    for t in study.type_names() {
        let Some(v) = prep.visibility.get(&t) else { continue };
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
        hilo_core::fs::write_json(&dir.join(format!("visibility_{t}.json")), &doc)?;
    }
    for conf in &study.file.configurations {
        let types = conf.type_names();
        let inst = instance(prep, &study.catalog, &types, study.placement.p_min)?;
        let limit = limit_for(conf, &types);
        hilo_placement_ip::mip::write_mps(
            &inst,
            &limit,
            hilo_placement_ip::mip::Formulation::Strengthened,
            &dir.join(conf.slug()),
        )?;
    }
    Ok(())
}
