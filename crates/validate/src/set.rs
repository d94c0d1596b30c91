//! The placement set: placements of the study's scene that span what a buyer might mount, each
//! with the predictors computed without training.
//!
//! For every configuration of the study, and for the rigs a buyer compares them with (each
//! LiDAR type of the study alone, two of the cheapest, the cheapest with one radar and two with
//! two radars, the budgeted optimum at the cost of the dearest configuration), the optimum and
//! greedy's answer; then, in turn over the count configurations, the optimum with one sensor
//! moved (another mount, yaw or tilt) and a random selection, until the set has the size asked.
//! With `near_budget = N`, N more rigs whose cost lies within ±10% of the budget: type counts
//! drawn among every count the budget's band allows ([`counts_near`]), placed alternately by
//! greedy and at random; the recommendation's regret is measured against the set's rigs in that
//! band. Candidates offer every tilt of the `[validation]` section, so poses differ in tilt too.
//! Same seed, same set.

use super::ValidationSettings;
use hilo_placement_ip::calibrated;
use hilo_placement_ip::greedy::greedy;
use hilo_placement_ip::instance::{covered_targets, evaluate};
use hilo_placement_ip::pipeline::{Prepared, instance, prepare, solve_from};
use hilo_placement_ip::{Instance, Limit, Modality, PlacedSensor, Placement};
use hilo_plan::error::{Result, StudyError};
use hilo_plan::place::{central_targets, lidar_hits, limit_for, placed};
use hilo_plan::study::{Configuration, Study};
use hilo_raycast::{QueryRegion, World};
use hilo_sensor_models::{SensorPose, SensorSpec};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};

/// One placement of the set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Member {
    /// File-name-safe and unique: `m<k>-<kind>-<configuration slug>`.
    pub slug: String,
    /// optimum (proven), best-found (a solve stopped at its time limit), greedy, perturbed,
    /// random, near-budget-greedy or near-budget-random.
    pub kind: String,
    pub configuration: String,
    pub placement: Placement,
    /// Predictors without training: name → value (None where undefined for this rig).
    pub predictors: BTreeMap<String, Option<f64>>,
}

/// Predictor names computed from the placement alone.
pub const PAPER_OBJECTIVE: &str = "paper objective";
pub const OWN_OBJECTIVE: &str = "objective (offered modalities)";
pub const LIDAR_COVERAGE: &str = "LiDAR coverage";
pub const RADAR_COVERAGE: &str = "radar coverage";
pub const CENTRAL_COVERAGE: &str = "central coverage";
/// Σ_j w_j min(1, A_j / τ) / Σ_j w_j with A_j a modality's coverage sum Σ −ln(1 − V): coverage
/// that counts a partly seen target in part and saturates at the paper's threshold; linear in
/// per-candidate, per-target terms under a cap, so an IP can maximise it.
pub const LIDAR_SATURATED: &str = "LiDAR coverage (saturated)";
pub const RADAR_SATURATED: &str = "radar coverage (saturated)";
/// Σ_j w_j min(1, s_j / 2) / Σ_j w_j with s_j = Σ_o min(1, a_oj / τ): a target counts fully
/// only when two sensors of the modality each see it well (one sensor, however dense, counts
/// half).
pub const LIDAR_TWO_VIEWS: &str = "LiDAR coverage by two views";
pub const RADAR_TWO_VIEWS: &str = "radar coverage by two views";
/// Σ_j w_j min(1, d_j / 2) / Σ_j w_j with d_j = Σ_o a_oj / τ: a target counts fully when the
/// modality's summed coverage reaches twice the detection threshold, from one sensor or
/// several (density, which the capped terms ignore).
pub const LIDAR_DENSE: &str = "LiDAR coverage at twice the threshold";
pub const RADAR_DENSE: &str = "radar coverage at twice the threshold";
/// The same three per modality with each target weighted by the road users of the study's
/// traffic found on it, class-balanced ([`hilo_plan::road_users`]) instead of by its region of
/// interest: the occupancy of the traffic made linear.
pub const LIDAR_SATURATED_USERS: &str = "LiDAR coverage of road users (saturated)";
pub const RADAR_SATURATED_USERS: &str = "radar coverage of road users (saturated)";
pub const LIDAR_TWO_VIEWS_USERS: &str = "LiDAR coverage of road users by two views";
pub const RADAR_TWO_VIEWS_USERS: &str = "radar coverage of road users by two views";
pub const LIDAR_DENSE_USERS: &str = "LiDAR coverage of road users at twice the threshold";
pub const RADAR_DENSE_USERS: &str = "radar coverage of road users at twice the threshold";

/// Baselines that need no model: how many LiDARs the rig has, on how many mounting structures,
/// and their beams summed (from the catalog).
pub const LIDARS: &str = "LiDARs";
pub const LIDAR_MOUNTS: &str = "mounting structures holding a LiDAR";
pub const LIDAR_BEAMS: &str = "LiDAR beams";

/// The occupancy of the study's training traffic from the placement alone
/// ([`hilo_plan::road_users::TrafficPoints`]): the class-balanced mean of min(1, n / k) over road
/// users with n LiDAR points (capped-linear, the form an IP could hold) and the share with
/// n ≥ k, on every [`TRAFFIC_EVERY`]-th key frame of the training scenes.
pub const LIDAR_POINTS_CAPPED: &str = "LiDAR points on road users, capped at k (training traffic)";
pub const HIT_SHARE_TRAINING: &str = "road users hit by k LiDAR points (training traffic)";
/// The share of each counted road user's footprint that the rig's LiDARs span, one LiDAR at a
/// time, summed and capped at 1 ([`hilo_plan::road_users::Occupancy::extent`]), on the same
/// frames: the geometry of the points rather than their number.
pub const LIDAR_EXTENT: &str = "road users' footprint spanned by each LiDAR's points, summed (training traffic)";
/// Key frames of the training traffic between two the occupancy predictors read.
pub const TRAFFIC_EVERY: usize = 20;

/// The calibrated objective's terms as predictors, in the order of
/// [`calibrated::Weights::named`] (each is the objective with that term's weight 1, the others 0).
pub const TERMS: [&str; calibrated::N_TERMS] = [
    LIDAR_SATURATED,
    RADAR_SATURATED,
    LIDAR_TWO_VIEWS,
    RADAR_TWO_VIEWS,
    LIDAR_DENSE,
    RADAR_DENSE,
    LIDAR_SATURATED_USERS,
    RADAR_SATURATED_USERS,
    LIDAR_TWO_VIEWS_USERS,
    RADAR_TWO_VIEWS_USERS,
    LIDAR_DENSE_USERS,
    RADAR_DENSE_USERS,
    LIDAR_POINTS_CAPPED,
    LIDAR_EXTENT,
];

/// The calibrated objective with weight 1 on term `k` of [`TERMS`].
pub fn unit_term(k: usize) -> calibrated::Weights {
    calibrated::Weights::unit(k)
}

/// The configurations the set is drawn from: the study's, then the rigs a buyer compares them
/// with (one to eight sensors), once each (by sensor counts).
pub fn set_configurations(study: &Study) -> Vec<Configuration> {
    let cat = &study.catalog;
    let price = |t: &String| cat.get(t).map_or(f64::INFINITY, |s| s.price_usd());
    let mut lidars: Vec<String> =
        study.type_names().into_iter().filter(|t| matches!(cat.get(t), Ok(SensorSpec::Lidar(_)))).collect();
    lidars.sort_by(|a, b| price(a).total_cmp(&price(b)).then(a.cmp(b)));
    let mut radars: Vec<String> =
        study.type_names().into_iter().filter(|t| matches!(cat.get(t), Ok(SensorSpec::Radar(_)))).collect();
    radars.sort_by(|a, b| price(a).total_cmp(&price(b)).then(a.cmp(b)));
    let counts = |name: String, s: &[(&String, u32)]| Configuration {
        name,
        sensors: s.iter().map(|(t, n)| ((*t).clone(), *n)).collect(),
        budget_usd: None,
        types: Vec::new(),
        min: BTreeMap::new(),
        max: BTreeMap::new(),
        given: None,
        apart: false,
    };
    // A configuration placed apart from a given rig's sensors is a variant of that rig's
    // placement; the set places every configuration for itself, and draws its own rigs of two
    // radars below.
    let mut out: Vec<Configuration> = study.file.configurations.iter().filter(|c| !c.apart).cloned().collect();
    for l in &lidars {
        out.push(counts(format!("1x {l}"), &[(l, 1)]));
    }
    if let Some(l) = lidars.first() {
        out.push(counts(format!("2x {l}"), &[(l, 2)]));
        if let Some(r) = radars.first() {
            out.push(counts(format!("1x {l} + {r}"), &[(l, 1), (r, 1)]));
            out.push(counts(format!("2x {l} + 2x {r}"), &[(l, 2), (r, 2)]));
        }
        // Rigs of four to eight sensors, the sizes a budget buys (a fit that saw only smaller
        // rigs extrapolates its saturating terms to them), and the four LiDARs without their
        // radars beside them. Counts are upper limits: a scene with fewer mounts places fewer.
        out.push(counts(format!("4x {l}"), &[(l, 4)]));
        if let Some(r) = radars.first() {
            out.push(counts(format!("4x {l} + {r}"), &[(l, 4), (r, 1)]));
            out.push(counts(format!("4x {l} + 3x {r}"), &[(l, 4), (r, 3)]));
            out.push(counts(format!("6x {l} + 2x {r}"), &[(l, 6), (r, 2)]));
        }
    }
    let dearest = study
        .file
        .configurations
        .iter()
        .filter(|c| c.budget_usd.is_none())
        .map(|c| c.sensors.iter().map(|(t, n)| price(t) * *n as f64).sum::<f64>())
        .fold(0.0, f64::max);
    if !radars.is_empty() && !lidars.is_empty() && study.file.configurations.iter().all(|c| c.budget_usd.is_none()) {
        out.push(Configuration {
            name: format!("budget {dearest:.0} USD"),
            sensors: BTreeMap::new(),
            budget_usd: Some(dearest),
            types: study.type_names(),
            min: BTreeMap::new(),
            max: BTreeMap::new(),
            given: None,
            apart: false,
        });
    }
    let mut seen = BTreeSet::new();
    out.retain(|c| seen.insert((format!("{:?}", c.sensors), c.budget_usd.map(f64::to_bits), c.types.clone())));
    out
}

/// The study's placement settings with the validation's tilts.
fn settings_with_tilts(
    study: &Study,
    v: &ValidationSettings,
) -> Result<hilo_core::Valid<hilo_placement_ip::pipeline::PlacementConfig>> {
    let mut pc = study.placement.clone().into_inner();
    pc.candidates.lidar_tilts_deg = v.lidar_tilts_deg.clone();
    pc.candidates.radar_tilts_deg = v.radar_tilts_deg.clone();
    Ok(pc.validate()?)
}

/// Draws the placement set (see the module doc); `progress` hears one line per step.
pub fn placement_set(study: &Study, v: &ValidationSettings, progress: &mut dyn FnMut(&str)) -> Result<Vec<Member>> {
    let pc = settings_with_tilts(study, v)?;
    let types = study.type_names();
    let prep = prepare(&study.scene, &study.catalog, &types, &pc)?;
    progress(&format!(
        "placement set: {} candidates ({} LiDAR and {} radar tilts), {} targets",
        prep.candidates.len(),
        v.lidar_tilts_deg.len(),
        v.radar_tilts_deg.len(),
        prep.targets.len()
    ));
    let confs = set_configurations(study);
    let mut drawn: Vec<(String, String, Vec<PlacedSensor>, bool)> = Vec::new();
    let mut keys = BTreeSet::new();
    let mut push = |kind: &str, conf: &str, sensors: Vec<PlacedSensor>, proven: bool, out: &mut Vec<_>| {
        let mut key: Vec<(String, u32)> = sensors.iter().map(|s| (s.ty.clone(), s.candidate_id)).collect();
        key.sort();
        if !sensors.is_empty() && keys.insert(key) {
            out.push((kind.to_owned(), conf.to_owned(), sensors, proven));
        }
    };
    let mut optima: Vec<(usize, Instance, Limit, Vec<usize>)> = Vec::new();
    for (ci, conf) in confs.iter().enumerate() {
        let ctypes = conf.type_names();
        let inst = instance(&prep, &study.catalog, &ctypes, pc.p_min)?;
        let limit = limit_for(conf, &ctypes);
        let g = greedy(&inst, &limit);
        let o = solve_from(&inst, &limit, pc.solve_limit(), &g)?;
        progress(&format!(
            "  {:<28} optimum {:>9.1} ({}), greedy {:>9.1}",
            conf.name,
            o.objective,
            if o.proven_optimal { "proven".to_owned() } else { format!("gap {:.1}%", 100.0 * o.gap) },
            g.objective
        ));
        // An unproven solve (stopped at the time limit) is the best found, not an optimum.
        let kind = if o.proven_optimal { "optimum" } else { "best-found" };
        push(kind, &conf.name, placed(&inst, &prep, &o.selection), o.proven_optimal, &mut drawn);
        push("greedy", &conf.name, placed(&inst, &prep, &g.selection), false, &mut drawn);
        if matches!(limit, Limit::Counts(_)) {
            optima.push((ci, inst, limit, o.selection));
        }
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(v.seed);
    let mut attempts = 0;
    // Perturbed and random placements up to the set's size, and at least a quarter of it
    // however many configurations there are: the optima alone span too narrow a range.
    let target = v.placements.max(drawn.len() + v.placements / 4);
    while drawn.len() < target && !optima.is_empty() && attempts < 100 * target {
        // Each configuration in turn, perturbed then random.
        let (ci, inst, limit, opt) = &optima[(attempts / 2) % optima.len()];
        let (kind, sel) = if attempts.is_multiple_of(2) {
            ("perturbed", perturb(inst, opt, &mut rng))
        } else {
            ("random", random(inst, limit, &mut rng))
        };
        attempts += 1;
        if let Some(sel) = sel {
            push(kind, &confs[*ci].name, placed(inst, &prep, &sel), false, &mut drawn);
        }
    }
    if v.near_budget > 0
        && let Some(conf) = budget_configuration(study)
    {
        let ctypes = conf.type_names();
        let inst = instance(&prep, &study.catalog, &ctypes, pc.p_min)?;
        for (kind, sel) in near_budget(&inst, &limit_for(&conf, &ctypes), v.near_budget, &mut rng) {
            push(kind, &conf.name, placed(&inst, &prep, &sel), false, &mut drawn);
        }
    }
    if drawn.len() < v.placements {
        return Err(StudyError::setting(
            &study.source,
            "validation.placements",
            v.placements,
            format!("the scene offers {} distinct placements of these configurations", drawn.len()),
        ));
    }
    let mut ctx = Context::new(study, &prep, &pc, v.min_points)?;
    drawn
        .into_iter()
        .enumerate()
        .map(|(k, (kind, conf, sensors, proven))| ctx.member(k, &kind, &conf, sensors, proven))
        .collect()
}

/// The budget the set's budgeted optimum is placed under: the study's own budgeted
/// configuration, or else the cost of its dearest configuration (None without both a LiDAR and
/// a radar type).
pub fn budget_configuration(study: &Study) -> Option<Configuration> {
    set_configurations(study).into_iter().find(|c| c.budget_usd.is_some())
}

/// The rig the calibrated objective buys under the budgeted configuration `conf` (see
/// [`budget_configuration`]; [`calibrated::solve`] from greedy within the study's time limit),
/// as member number `k` of kind `calibrated` (or `calibrated-best-found` when not proven
/// optimal), with its predictors; its placement's objective, bound, gap and method are those
/// of the calibrated solve (its time is not recorded: the placement is hashed).
pub fn calibrated_member(
    study: &Study,
    v: &ValidationSettings,
    w: &calibrated::Weights,
    conf: &Configuration,
    k: usize,
) -> Result<Member> {
    Ok(buy(study, v, w, (w.reads_points(), w.reads_extents()), conf, k, "calibrated", |_, _| ())?.0)
}

/// The rig a calibration file's frozen weights buy under `conf` at this study's junction (a file
/// `hilo validate --sites` fitted at other junctions), as [`calibrated_member`] places it but of
/// kind `frozen` (`frozen-best-found`), with the file's prediction of its mAP and how far the rig
/// lies from the sites it was fitted on.
pub fn frozen_member(
    study: &Study,
    v: &ValidationSettings,
    file: &calibrated::file::CalibrationFile,
    conf: &Configuration,
    k: usize,
) -> Result<(Member, calibrated::file::Prediction)> {
    let reads = |term: &str| file.prediction.features.iter().any(|f| f == term);
    let needs =
        (file.weights.reads_points() || reads("lidar_points"), file.weights.reads_extents() || reads("lidar_extent"));
    buy(study, v, &file.weights, needs, conf, k, "frozen", |inst, sel| file.predict(inst, sel))
}

/// Places the rig the weights `w` buy under `conf` (member `k`, of `kind` or `<kind>-best-found`)
/// and hands its instance and selection to `then`; `needs`: whether the instance needs the point
/// counts, and the footprint shares.
#[allow(clippy::too_many_arguments)]
fn buy<T>(
    study: &Study,
    v: &ValidationSettings,
    w: &calibrated::Weights,
    needs: (bool, bool),
    conf: &Configuration,
    k: usize,
    kind: &str,
    then: impl FnOnce(&Instance, &[usize]) -> T,
) -> Result<(Member, T)> {
    w.check()?;
    let pc = settings_with_tilts(study, v)?;
    let prep = prepare(&study.scene, &study.catalog, &study.type_names(), &pc)?;
    let types = conf.type_names();
    let mut ctx = Context::new(study, &prep, &pc, v.min_points)?;
    let mut inst = instance(&prep, &study.catalog, &types, pc.p_min)?;
    inst.road_users = ctx.all.road_users.clone();
    if needs.0 {
        inst.points = ctx.point_rows(&inst)?;
    }
    if needs.1 {
        let lidar_of = |o: usize| hilo_plan::place::option_lidar(ctx.study, ctx.prep, &inst, o);
        inst.extents = ctx.traffic.extent_rows(&ctx.world, inst.options.len(), lidar_of)?;
    }
    // The study's hit floors hold for a rig with a LiDAR, as `hilo place` holds them.
    if !pc.min_hit_share.is_empty() && (0..inst.options.len()).any(|o| inst.modality(o) == Modality::Lidar) {
        let counted;
        let points = if needs.0 {
            &inst.points
        } else {
            counted = ctx.point_rows(&inst)?;
            &counted
        };
        inst.floors = ctx.traffic.hit_floors(points, &pc.min_hit_share, &study.source)?;
    }
    let limit = limit_for(conf, &types);
    let g = calibrated::greedy(&inst, &limit, w);
    let o = calibrated::solve(&inst, &limit, w, pc.solve_limit(), pc.calibrated_cbc_max_nonzeros, &g)?;
    let extra = then(&inst, &o.selection);
    let sensors = placed(&inst, &prep, &o.selection);
    let kind = if o.proven_optimal { kind.to_owned() } else { format!("{kind}-best-found") };
    let mut m = ctx.member(k, &kind, &conf.name, sensors, o.proven_optimal)?;
    // The placement records the solve of the objective it was placed for, but not its time: the
    // placement names the recommendation's dataset and runs (a content hash), so it must be the
    // same bytes whenever the same rig is bought.
    m.placement.objective = o.objective;
    m.placement.bound = o.bound;
    m.placement.gap = o.gap;
    m.placement.greedy_objective = g.objective;
    m.placement.method = o.method;
    Ok((m, extra))
}

/// The members' placement predictors computed again by this build (a set drawn by an older one
/// gains the predictors added since); the predictors of the traffic are kept as they were.
pub fn recompute(study: &Study, v: &ValidationSettings, members: &[Member]) -> Result<Vec<Member>> {
    recompute_from(study, v, members, 0)
}

/// [`recompute`] for members that stand at `first`, `first` + 1, … of their set.
pub fn recompute_from(study: &Study, v: &ValidationSettings, members: &[Member], first: usize) -> Result<Vec<Member>> {
    let pc = settings_with_tilts(study, v)?;
    let prep = prepare(&study.scene, &study.catalog, &study.type_names(), &pc)?;
    let mut ctx = Context::new(study, &prep, &pc, v.min_points)?;
    members
        .iter()
        .enumerate()
        .map(|(k, m)| {
            if m.placement.scene_hash != study.scene_hash || m.placement.catalog_hash != study.catalog_hash {
                return Err(StudyError::Unknown {
                    what: "placement",
                    name: m.slug.clone(),
                    place: study.source.clone(),
                    known: "it was drawn on another scene or catalog".into(),
                });
            }
            let mut again = ctx.member(
                first + k,
                &m.kind,
                &m.configuration,
                m.placement.sensors.clone(),
                m.placement.proven_optimal,
            )?;
            if again.slug != m.slug {
                return Err(StudyError::Unknown {
                    what: "placement",
                    name: m.slug.clone(),
                    place: study.source.clone(),
                    known: format!("it reads back as {}", again.slug),
                });
            }
            let mut predictors = m.predictors.clone();
            predictors.append(&mut again.predictors);
            Ok(Member { predictors, ..m.clone() })
        })
        .collect()
}

/// Every count of each type (within the limit's minimum and maximum, one sensor per mount)
/// whose cost lies within ±10% of a budget limit's dollars; none under another limit.
pub fn counts_near(inst: &Instance, limit: &Limit) -> Vec<Vec<u32>> {
    let Limit::Budget { usd, min, max } = limit else { return Vec::new() };
    let mounts = inst.options.iter().map(|o| o.mount).collect::<BTreeSet<u32>>().len() as u32;
    let (lo, hi) = (0.9 * usd, 1.1 * usd);
    let mut out = Vec::new();
    let mut counts = vec![0u32; inst.types.len()];
    fn walk(
        inst: &Instance,
        t: usize,
        (min, max, mounts): (&[u32], &[u32], u32),
        (lo, hi, cost): (f64, f64, f64),
        counts: &mut Vec<u32>,
        out: &mut Vec<Vec<u32>>,
    ) {
        if t == counts.len() {
            if cost >= lo && cost > 0.0 {
                out.push(counts.clone());
            }
            return;
        }
        let used: u32 = counts[..t].iter().sum();
        let price = inst.types[t].price_usd;
        let first = min.get(t).copied().unwrap_or(0);
        let last = max.get(t).copied().unwrap_or(u32::MAX).min(mounts.saturating_sub(used));
        let mut n = first;
        while n <= last && cost + n as f64 * price <= hi {
            counts[t] = n;
            walk(inst, t + 1, (min, max, mounts), (lo, hi, cost + n as f64 * price), counts, out);
            if price <= 0.0 {
                break;
            }
            n += 1;
        }
        counts[t] = 0;
    }
    walk(inst, 0, (min, max, mounts), (lo, hi, 0.0), &mut counts, &mut out);
    out
}

/// `n` rigs whose cost lies within ±10% of the budget: type counts drawn without repetition
/// until each has been used (then again), each placed alternately by greedy and at random.
fn near_budget(inst: &Instance, limit: &Limit, n: usize, rng: &mut impl Rng) -> Vec<(&'static str, Vec<usize>)> {
    let all = counts_near(inst, limit);
    let mut out = Vec::new();
    let mut pool: Vec<usize> = Vec::new();
    let mut attempts = 0;
    while out.len() < n && !all.is_empty() && attempts < 20 * n {
        attempts += 1;
        if pool.is_empty() {
            pool = (0..all.len()).collect();
        }
        let counts = all[pool.swap_remove(rng.random_range(0..pool.len()))].clone();
        let size = counts.iter().sum::<u32>() as usize;
        let limit = Limit::Counts(counts);
        let (kind, sel) = if out.len().is_multiple_of(2) {
            ("near-budget-greedy", Some(greedy(inst, &limit).selection))
        } else {
            ("near-budget-random", random(inst, &limit, rng))
        };
        // Greedy stops when no sensor adds coverage: keep only rigs of the counts drawn.
        if let Some(sel) = sel.filter(|s| s.len() == size) {
            out.push((kind, sel));
        }
    }
    out
}

/// The optimum with one sensor moved to another option of its type (another mount, or the same
/// mount at another yaw or tilt).
fn perturb(inst: &Instance, opt: &[usize], rng: &mut impl Rng) -> Option<Vec<usize>> {
    if opt.is_empty() {
        return None;
    }
    let i = rng.random_range(0..opt.len());
    let ty = inst.options[opt[i]].ty;
    let taken: BTreeSet<u32> =
        opt.iter().enumerate().filter(|(k, _)| *k != i).map(|(_, &o)| inst.options[o].mount).collect();
    let choices: Vec<usize> = (0..inst.options.len())
        .filter(|&o| o != opt[i] && inst.options[o].ty == ty && !taken.contains(&inst.options[o].mount))
        .collect();
    if choices.is_empty() {
        return None;
    }
    let mut sel = opt.to_vec();
    sel[i] = choices[rng.random_range(0..choices.len())];
    Some(sel)
}

/// A uniformly random selection with the limit's counts, one sensor per mount.
fn random(inst: &Instance, limit: &Limit, rng: &mut impl Rng) -> Option<Vec<usize>> {
    let Limit::Counts(counts) = limit else { return None };
    let mut sel = Vec::new();
    let mut mounts = BTreeSet::new();
    for (ty, &n) in counts.iter().enumerate() {
        for _ in 0..n {
            let choices: Vec<usize> = (0..inst.options.len())
                .filter(|&o| inst.options[o].ty == ty && !mounts.contains(&inst.options[o].mount))
                .collect();
            if choices.is_empty() {
                return None;
            }
            let o = choices[rng.random_range(0..choices.len())];
            mounts.insert(inst.options[o].mount);
            sel.push(o);
        }
    }
    Some(sel)
}

/// The options of `inst` that are these sensors, by type and pose: a candidate's id is its
/// index in the sampling, which another build may number otherwise (a set drawn by it is
/// recomputed by `--refit`), while the pose is where the sensor is. Sensors whose candidate sees
/// no target, or stands where this build samples none, have no option and add nothing.
fn selection(inst: &Instance, prep: &Prepared, sensors: &[PlacedSensor]) -> Vec<usize> {
    let same = |a: &SensorPose, b: &SensorPose| {
        a.position.distance(b.position) < 1e-3 && (a.yaw - b.yaw).abs() < 1e-4 && (a.pitch - b.pitch).abs() < 1e-4
    };
    sensors
        .iter()
        .filter_map(|s| {
            inst.options.iter().position(|o| {
                inst.types[o.ty].name == s.ty
                    && prep.candidates.get(o.candidate as usize).is_some_and(|c| same(&c.pose, &s.pose))
            })
        })
        .collect()
}

/// What every member's predictors are computed from, once for the set.
struct Context<'a> {
    study: &'a Study,
    prep: &'a Prepared,
    world: World,
    /// The instance over every type of the study (the paper's objective asks for both
    /// modalities there).
    all: Instance,
    central: Vec<usize>,
    /// The instance over each set of types a member uses (its own objective), built once.
    own: BTreeMap<Vec<String>, Instance>,
    cell_m: f32,
    p_min: f64,
    traffic: hilo_plan::road_users::TrafficPoints,
    min_points: u32,
}

impl<'a> Context<'a> {
    fn new(
        study: &'a Study,
        prep: &'a Prepared,
        pc: &hilo_placement_ip::pipeline::PlacementConfig,
        min_points: u32,
    ) -> Result<Self> {
        // The training traffic, stepped once for the road users on each target and the points
        // on them.
        let traffic = hilo_plan::road_users::TrainingTraffic::new(study)?;
        let mut all = instance(prep, &study.catalog, &study.type_names(), pc.p_min)?;
        all.road_users = hilo_plan::road_users::road_users(&traffic, &prep.targets, pc.cell_m)?.weights;
        Ok(Context {
            study,
            world: World::build(&study.scene, &QueryRegion::everything())?,
            all,
            central: central_targets(study, prep),
            own: BTreeMap::new(),
            prep,
            cell_m: pc.cell_m,
            p_min: pc.p_min,
            traffic: hilo_plan::road_users::TrafficPoints::new(&traffic, TRAFFIC_EVERY)?,
            min_points,
        })
    }

    /// The point counts of `inst`'s LiDAR options on the road users of the training traffic (the
    /// `lidar_points` term's, over the frames the occupancy predictors read, with their k).
    fn point_rows(&self, inst: &Instance) -> Result<hilo_placement_ip::instance::PointRows> {
        let lidar_of = |o: usize| hilo_plan::place::option_lidar(self.study, self.prep, inst, o);
        self.traffic.rows(&self.world, inst.options.len(), lidar_of, self.min_points)
    }

    fn member(&mut self, k: usize, kind: &str, conf: &str, sensors: Vec<PlacedSensor>, proven: bool) -> Result<Member> {
        let (study, prep, all) = (self.study, self.prep, &self.all);
        let mut own_types: Vec<String> = sensors.iter().map(|s| s.ty.clone()).collect();
        own_types.sort();
        own_types.dedup();
        if !self.own.contains_key(&own_types) {
            let inst = instance(prep, &study.catalog, &own_types, self.p_min)?;
            self.own.insert(own_types.clone(), inst);
        }
        let own = &self.own[&own_types];
        let sel_own = selection(own, prep, &sensors);
        let sel_all = selection(all, prep, &sensors);
        let has = |m: Modality| sensors.iter().any(|s| s.modality == m);
        let weight: f64 = all.weights.iter().sum::<f64>().max(1e-12);
        let share =
            |m: Modality| covered_targets(all, &sel_all, m).iter().map(|&j| all.weights[j]).sum::<f64>() / weight;
        // The calibrated objective's terms, one modality at a time.
        let hits = lidar_hits(study, &self.world, prep, self.cell_m, &sensors)?;
        let central = &self.central;
        let own_objective = evaluate(own, &sel_own);
        let mut predictors = BTreeMap::from([
            // The paper's objective reads literally: targets seen by both modalities; undefined
            // (zero whatever the poses) for a rig of one modality.
            (
                PAPER_OBJECTIVE.to_owned(),
                (has(Modality::Lidar) && has(Modality::Radar)).then(|| evaluate(all, &sel_all)),
            ),
            (OWN_OBJECTIVE.to_owned(), Some(own_objective)),
            (LIDAR_COVERAGE.to_owned(), Some(share(Modality::Lidar))),
            (RADAR_COVERAGE.to_owned(), Some(share(Modality::Radar))),
            (CENTRAL_COVERAGE.to_owned(), Some(hilo_placement_ip::coverage::share(central, &hits))),
        ]);
        // The sensors' order is the rig's (the dataset's seeds follow it).
        let lidars = sensors
            .iter()
            .enumerate()
            .filter(|(_, s)| s.modality == Modality::Lidar)
            .map(|(k, s)| Ok((k, study.catalog.lidar(&s.ty)?.clone(), s.pose)))
            .collect::<Result<Vec<_>>>()?;
        let structures: BTreeSet<&str> =
            sensors.iter().filter(|s| s.modality == Modality::Lidar).map(|s| s.structure.as_str()).collect();
        predictors.insert(LIDARS.to_owned(), Some(lidars.len() as f64));
        predictors.insert(LIDAR_MOUNTS.to_owned(), Some(structures.len() as f64));
        predictors.insert(LIDAR_BEAMS.to_owned(), Some(lidars.iter().map(|(_, l, _)| f64::from(l.beams)).sum()));
        let seen = self.traffic.occupancy(&self.world, &lidars, self.min_points)?;
        predictors.insert(LIDAR_POINTS_CAPPED.to_owned(), Some(seen.capped));
        predictors.insert(HIT_SHARE_TRAINING.to_owned(), Some(seen.hit));
        predictors.insert(LIDAR_EXTENT.to_owned(), Some(seen.extent));
        // The calibrated objective's coverage terms, one at a time (the point-count and footprint
        // terms are the rig's own above: the same sums with the rig's dropout draws).
        for (k, name) in TERMS.iter().enumerate().filter(|(_, n)| ![LIDAR_POINTS_CAPPED, LIDAR_EXTENT].contains(*n)) {
            predictors.insert(name.to_string(), Some(calibrated::evaluate(all, &sel_all, &unit_term(k))));
        }
        let cost_usd = sensors
            .iter()
            .map(|s| study.catalog.get(&s.ty).map(|c| c.price_usd()))
            .sum::<std::result::Result<f64, _>>()?;
        let slug = format!("m{k:02}-{kind}-{}", hilo_plan::study::slug(conf));
        let placement = Placement {
            name: slug.clone(),
            sensors,
            objective: own_objective,
            bound: if proven { own_objective } else { f64::INFINITY },
            gap: if proven { 0.0 } else { f64::INFINITY },
            proven_optimal: proven,
            solve_seconds: 0.0,
            method: format!("{kind} placement of {conf:?} (validation set)"),
            solved: kind == "optimum" || kind == "best-found",
            greedy_objective: 0.0,
            central_coverage: predictors[CENTRAL_COVERAGE].unwrap_or(0.0),
            lidar_radar_overlap: 0.0,
            cost_usd,
            targets: prep.targets.len(),
            candidates: prep.candidates.len(),
            scene_hash: study.scene_hash.clone(),
            catalog_hash: study.catalog_hash.clone(),
            prediction: None,
        };
        Ok(Member { slug, kind: kind.to_owned(), configuration: conf.to_owned(), placement, predictors })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// The coarse validation scene (the default junction on 3 m cells, few candidate mounts).
    fn coarse() -> Study {
        crate::testing::study()
    }

    /// The counts near a budget are every count vector a brute force over a box finds within
    /// ±10% of the dollars, no more sensors than mounts, each type within its minimum and
    /// maximum; and the rigs drawn near the coarse scene's budget cost that much, have the
    /// counts drawn, and alternate greedy and random poses.
    #[test]
    fn rigs_near_the_budget_cost_within_a_tenth_of_it() {
        let ty = |name: &str, modality, price_usd| hilo_placement_ip::instance::SensorType {
            name: name.into(),
            modality,
            price_usd,
        };
        let types =
            vec![ty("a", Modality::Lidar, 4000.0), ty("b", Modality::Lidar, 7500.0), ty("r", Modality::Radar, 2750.0)];
        let options = (0..7)
            .map(|m| hilo_placement_ip::instance::SensorOption {
                ty: m % 3,
                candidate: m as u32,
                mount: m as u32 / 2,
                row: vec![],
            })
            .collect();
        let inst = Instance {
            weights: vec![],
            types,
            options,
            p_min: 0.5,
            road_users: vec![],
            points: Default::default(),
            extents: Default::default(),
            floors: Vec::new(),
        };
        let limit = Limit::Budget { usd: 22_750.0, min: vec![0, 0, 1], max: vec![u32::MAX, 2, u32::MAX] };
        let mut brute = Vec::new();
        for a in 0..10u32 {
            for b in 0..10u32 {
                for r in 0..10u32 {
                    let cost = 4000.0 * a as f64 + 7500.0 * b as f64 + 2750.0 * r as f64;
                    if (cost - 22_750.0).abs() <= 2275.0 && a + b + r <= 4 && b <= 2 && r >= 1 {
                        brute.push(vec![a, b, r]);
                    }
                }
            }
        }
        let mut found = counts_near(&inst, &limit);
        found.sort();
        assert_eq!(found, brute);
        assert!(!brute.is_empty());
        assert!(counts_near(&inst, &Limit::Counts(vec![1, 1, 1])).is_empty());

        let study = coarse();
        let v = &study.file.validation;
        let pc = settings_with_tilts(&study, v).unwrap();
        let prep = prepare(&study.scene, &study.catalog, &study.type_names(), &pc).unwrap();
        let conf = budget_configuration(&study).unwrap();
        let ctypes = conf.type_names();
        let inst = instance(&prep, &study.catalog, &ctypes, pc.p_min).unwrap();
        let limit = limit_for(&conf, &ctypes);
        let usd = conf.budget_usd.unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let rigs = near_budget(&inst, &limit, 6, &mut rng);
        assert_eq!(rigs.len(), 6);
        for (i, (kind, sel)) in rigs.iter().enumerate() {
            assert!((inst.cost(sel) - usd).abs() <= 0.1 * usd + 1e-6, "{kind}: {}", inst.cost(sel));
            assert_eq!(*kind, if i % 2 == 0 { "near-budget-greedy" } else { "near-budget-random" });
            let mounts: BTreeSet<u32> = sel.iter().map(|&o| inst.options[o].mount).collect();
            assert_eq!(mounts.len(), sel.len(), "one sensor per mount");
        }
        let mut again = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        assert_eq!(near_budget(&inst, &limit, 6, &mut again), rigs);
    }

    /// A fit that weighs the point-count term places its recommendation with the counts of every
    /// LiDAR option (it was refused for want of them), and the rig it buys scores, by its own
    /// count, what the solve claimed of it (the two differ by the dropout draws alone) and at
    /// least what a rig placed for saturated coverage scores.
    #[test]
    fn a_recommendation_weighing_points_is_placed_with_the_counts() {
        let study = coarse();
        // Far more points than the default k, so that the term does not saturate.
        let v = &ValidationSettings { min_points: 100, ..study.file.validation.clone() };
        let points = calibrated::Weights { lidar_points: 1.0, ..calibrated::Weights::default() };
        buys_what_it_counts(&study, v, &points, LIDAR_POINTS_CAPPED);
    }

    /// The rig `term` (one term's weights) buys under the study's budget scores, by the rig's
    /// own recorded predictor `recorded`, what the solve claimed of it (the two differ by the
    /// dropout draws alone), and at least what a rig placed for saturated coverage scores.
    fn buys_what_it_counts(study: &Study, v: &ValidationSettings, term: &calibrated::Weights, recorded: &str) {
        let budget = budget_configuration(study).unwrap();
        let m = calibrated_member(study, v, term, &budget, 0).unwrap();
        let own = m.predictors[recorded].unwrap();
        assert!(m.placement.cost_usd <= budget.budget_usd.unwrap() + 1e-6);
        assert!(m.placement.objective > 0.05, "{}", m.placement.objective);
        assert!((own - m.placement.objective).abs() < 0.01, "{own} vs {}", m.placement.objective);
        let coverage = calibrated::Weights { lidar: 1.0, ..calibrated::Weights::default() };
        let other = calibrated_member(study, v, &coverage, &budget, 1).unwrap();
        assert!(other.predictors[recorded].unwrap() <= own + 0.005, "{:?}", other.predictors);
    }

    /// The study's hit floor holds for the rig calibrated weights buy under its budget, as
    /// `hilo place` holds it: set just above the share the unfloored purchase hits, the purchase
    /// under it meets it, within the budget, at no higher objective.
    #[test]
    fn a_budgeted_purchase_meets_the_studys_hit_floor() {
        let mut study = coarse();
        let mut pc = study.placement.clone().into_inner();
        (pc.time_limit_s, pc.node_limit) = (600.0, Some(100));
        let v = &ValidationSettings { min_points: 100, ..study.file.validation.clone() };
        let budget = budget_configuration(&study).unwrap();
        let w = calibrated::Weights { lidar: 1.0, ..calibrated::Weights::default() };
        // A floor needs the calibrated objective in the study; the purchase reads `w`.
        (pc.objective, pc.calibration) = (hilo_placement_ip::pipeline::ObjectiveKind::Calibrated, Some(w));
        let bought = |study: &Study| {
            buy(study, v, &w, (false, false), &budget, 0, "calibrated", |inst, sel| {
                (inst.floors[0].share_hit(sel), inst.floors[0].samples, inst.meets_floors(sel))
            })
            .unwrap()
        };
        // A floor of one road user: every rig with a LiDAR meets it, and it says what the rig hits.
        pc.min_hit_share = BTreeMap::from([(hilo_core::Class::Pedestrian, 1e-9)]);
        study.placement = pc.clone().validate().unwrap();
        let (free, (share, samples, met)) = bought(&study);
        assert!(met && share < 1.0 && samples > 20, "{share} of {samples}");
        pc.min_hit_share = BTreeMap::from([(hilo_core::Class::Pedestrian, share + 0.5 / f64::from(samples))]);
        study.placement = pc.validate().unwrap();
        let (held, (above, _, met)) = bought(&study);
        assert!(met && above > share, "{above} against {share}");
        assert!(held.placement.cost_usd <= budget.budget_usd.unwrap() + 1e-6);
        assert!(held.placement.objective <= free.placement.objective + 1e-9);
    }

    /// A calibration file's frozen weights buy the rig the calibrated objective with those
    /// weights buys (the same poses), of kind `frozen`; the file's prediction is its intercept plus
    /// its coefficient times the term at that rig, which is the solve's objective over the weight
    /// and the rig's own point-count predictor within the dropout draws.
    #[test]
    fn a_frozen_calibration_buys_what_its_weights_buy_and_predicts_from_the_term() {
        // The two solves must stop at the same point: on the coarse fixture's 5 s the swaps and
        // CBC stop on the wall clock, which a debug build or a busy machine reaches at another
        // point each time. A node limit stops CBC the same way every time.
        let mut study = coarse();
        let mut pc = study.placement.clone().into_inner();
        (pc.time_limit_s, pc.node_limit) = (600.0, Some(100));
        study.placement = pc.validate().unwrap();
        let v = &ValidationSettings { min_points: 100, ..study.file.validation.clone() };
        let budget = budget_configuration(&study).unwrap();
        let file =
            calibrated::file::CalibrationFile::from_toml(include_str!("../../../fixtures/calibration-sites.toml"))
                .unwrap();
        let (m, p) = frozen_member(&study, v, &file, &budget, 7).unwrap();
        let same = calibrated_member(&study, v, &file.weights, &budget, 7).unwrap();
        assert_eq!(m.placement.sensors, same.placement.sensors);
        assert!(m.kind.starts_with("frozen") && m.slug.starts_with("m07-frozen"), "{}", m.slug);
        // The shipped file predicts from one term: the point count or the footprint spanned.
        let term = file.prediction.features[0].as_str();
        let recorded = [("lidar_points", LIDAR_POINTS_CAPPED), ("lidar_extent", LIDAR_EXTENT)]
            .into_iter()
            .find_map(|(t, name)| (t == term).then_some(name));
        assert!(recorded.is_some(), "the shipped file predicts from {term}");
        let recorded = recorded.unwrap();
        let (b, x) = (file.prediction.coefficients[0], p.features[term]);
        assert!((p.map - (file.prediction.intercept + b * x)).abs() < 1e-12, "{p:?}");
        assert!(p.lo < p.map && p.map < p.hi, "{p:?}");
        assert!((b * x - m.placement.objective).abs() < 1e-9 * b, "{} vs {}", b * x, m.placement.objective);
        assert!((x - m.predictors[recorded].unwrap()).abs() < 0.01, "{x} vs {:?}", m.predictors);
    }

    /// The footprint term as the objective: the rig it buys spans, by its own recorded
    /// predictor, what the solve counted (within the sensors' dropout draws), and a rig bought
    /// for coverage spans no more.
    #[test]
    fn the_footprint_term_buys_the_footprint_it_counts() {
        let study = coarse();
        let footprint = calibrated::Weights { lidar_extent: 1.0, ..calibrated::Weights::default() };
        buys_what_it_counts(&study, &study.file.validation, &footprint, LIDAR_EXTENT);
    }
}
