//! The calibrated objective: accuracy predicted from saturated coverage, weighted per modality
//! by what trained detectors measured (`hilo validate` fits the weights).
//!
//! f(S) = Σ_m [Σ_{k ∈ {1, 2}} β_mk Σ_j (w_j / W) min(1, s_mj / k) + δ_m Σ_j (w_j / W) min(1, d_mj / 2)],
//! with s_mj = Σ_{o ∈ S_m} min(1, a_oj / τ), d_mj = Σ_{o ∈ S_m} a_oj / τ, a_oj = −ln(1 − V_oj),
//! W = Σ_j w_j and β_mk, δ_m ≥ 0. The k = 1 term is the paper's coverage made partial (a target
//! partly seen counts in part; min(1, s) = min(1, Σ a / τ)); the k = 2 term counts a target
//! fully only when two sensors each see it well, so it pays for the second viewpoint (other
//! sides of a road user, views past occluders) that one denser sensor cannot give; the dense
//! term (δ) counts a target fully when the modality's summed coverage reaches twice the
//! threshold, from one sensor or several, so it pays for density (more points on a road user
//! than detection barely needs) that the capped terms ignore. A modality the detectors gain
//! nothing from (zero weights) is worth nothing to the optimiser. As an IP: maximise
//! Σ_t β_t Σ_j (w_j / W) z_tj with 0 ≤ z_tj ≤ 1 and z_tj ≤ Σ_{o ∈ m_t} c_t(a_oj) x_o (c_t is
//! min(1, a / τ) / k, or a / (2τ) for the dense term), the limit and one sensor per mount; z
//! needs no integrality (with β ≥ 0 the optimum sets each z to its cap). f is monotone and submodular
//! (a non-negative sum of concave functions of modular sums), so greedy is a
//! (1 − 1/e)-approximation under a count limit; swaps improve it ([`search`]), and CBC,
//! warm-started from them, closes or bounds the gap where the IP is small enough for CBC to
//! finish its root relaxation; past that size the submodular bound bounds it.
//!
//! Each term exists twice: over the regions of interest (w_j, the scene's target weights) and
//! over the road users of the simulated traffic (w_j = u_j, [`Instance::road_users`]: per
//! target, the class-balanced share of road users found there, so a cell where pedestrians
//! cross weighs what the pedestrians are worth to mAP, and a lane no one drives weighs
//! nothing). The second family is the occupancy predictor "share of road users seen" made
//! linear: it weighs where road users are, but not the occlusion by other road users that the
//! simulated scans count (that depends on the traffic at each instant, not on the cell).
//!
//! The thirteenth term (`lidar_points`) counts what the simulated scans do count: over road users
//! of sampled frames of the study's traffic (class-balanced), min(1, Σ_{o ∈ S} n_oj / k) with n_oj
//! the LiDAR points option o puts on road user j in its frame, occlusion by the frame's other road
//! users, buildings and poles included ([`crate::instance::PointRows`]). Points add up over
//! sensors, so the term is exact: z_j ≤ Σ_o n_oj x_o / k, 0 ≤ z_j ≤ 1, like the others.
//!
//! The fourteenth (`lidar_extent`) reads the same road users for where the points fall: min(1,
//! Σ_{o ∈ S} e_oj), e_oj the share of road user j's footprint (length × width, in its own frame)
//! that option o's points span alone ([`crate::instance::Instance::extents`], in thousandths).
//! One face seen end-on spans a car's width and none of its length; a corner view spans both.
//! The shares are summed sensor by sensor, not taken over the union of the points, so the term
//! keeps the point term's exact form (two LiDARs that each see one face add up to less than
//! the corner their union shows: the term undervalues such pairs).
//!
//! Hit floors ([`crate::instance::HitFloor`], `[placement] min_hit_share`) are constraints, not
//! terms: at least a share of a class's sampled road users must get a point from some chosen
//! LiDAR (y_s ≤ Σ_{o hits s} x_o, 0 ≤ y_s ≤ 1, Σ_s y_s ≥ ⌈share × samples⌉; y needs no
//! integrality, as the x are). The objective averages classes, so it may buy a point of mAP
//! on cars and trucks with a crosswalk no beam reaches; a floor rules such rigs out. A limit no
//! selection meets them under is an error that names the shares reached.

use crate::candidates::Modality;
use crate::error::PlacementError;
use crate::instance::{Instance, Limit, Outcome, coverage_coef};
use crate::mip::SolveLimit;
use good_lp::solvers::coin_cbc::coin_cbc;
use good_lp::{Expression, ProblemVariables, SolverModel, Variable, WithInitialSolution, variable};
use serde::{Deserialize, Serialize};
use std::time::Instant;

pub mod file;
pub mod search;
pub use search::{greedy, greedy_given, swaps, upper_bound};

/// The largest calibrated IP (non-zeros of its coverage rows) handed to CBC by default
/// (`[placement] calibrated_cbc_max_nonzeros`). CBC checks its time limit only between
/// branch-and-bound nodes, so the root LP of a larger one runs without a time bound (docs/
/// measurements.md has a default-scale instance that never finished it); beyond this size the
/// solve is greedy and swaps with the submodular bound.
pub const CBC_MAX_NONZEROS: usize = 1_000_000;

/// The non-zeros of the calibrated IP's coverage rows: per non-zero term, its modality's
/// visibility entries (or point counts) on targets of positive weight; and the hit floors'
/// entries.
pub fn nonzeros(inst: &Instance, w: &Weights) -> usize {
    let tau = inst.tau();
    let floors: usize = inst.floors.iter().flat_map(|f| &f.rows).map(Vec::len).sum();
    floors
        + w.terms()
            .iter()
            .filter(|t| t.weight > 0.0)
            .map(|t| {
                let wt = t.targets(inst);
                let mut n = 0;
                for o in (0..inst.options.len()).filter(|&o| inst.modality(o) == t.modality) {
                    t.for_each(inst, o, tau, |j, _| n += usize::from(wt.get(j).is_some_and(|&w| w > 0.0)));
                }
                n
            })
            .sum::<usize>()
}

/// The weights (mAP per unit of saturated coverage): per modality, of the coverage term, of
/// the two-view term (`lidar_two_views`, `radar_two_views`) and of the dense term
/// (`lidar_dense`, `radar_dense`), over the regions of interest, and the same six over the
/// road users of the simulated traffic (`…_road_users`); 0 when absent.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Weights {
    pub lidar: f64,
    pub radar: f64,
    #[serde(default)]
    pub lidar_two_views: f64,
    #[serde(default)]
    pub radar_two_views: f64,
    #[serde(default)]
    pub lidar_dense: f64,
    #[serde(default)]
    pub radar_dense: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub lidar_road_users: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub radar_road_users: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub lidar_two_views_road_users: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub radar_two_views_road_users: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub lidar_dense_road_users: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub radar_dense_road_users: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub lidar_points: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub lidar_extent: f64,
}

/// The largest weight [`Weights::check`] admits: the objective sums weight × coverage over
/// thousands of targets in f64 and hands the coefficients to CBC, which aborts past 1e25.
pub const MAX_WEIGHT: f64 = 1e6;

/// The smallest positive weight, as a share of the largest, that [`Weights::check`] admits.
pub const MIN_WEIGHT_RATIO: f64 = 1e-9;

/// How many terms the calibrated objective has ([`Weights::named`]).
pub const N_TERMS: usize = 14;

/// Each term's name in a study file and its shape: modality, the multiple k of the threshold
/// that counts a target fully, whether each sensor's coefficient is capped at 1, what its
/// targets are; in the order of [`Weights::values`].
const SHAPES: [(&str, Modality, f64, bool, Source); N_TERMS] = [
    ("lidar", Modality::Lidar, 1.0, true, Source::Regions),
    ("radar", Modality::Radar, 1.0, true, Source::Regions),
    ("lidar_two_views", Modality::Lidar, 2.0, true, Source::Regions),
    ("radar_two_views", Modality::Radar, 2.0, true, Source::Regions),
    ("lidar_dense", Modality::Lidar, 2.0, false, Source::Regions),
    ("radar_dense", Modality::Radar, 2.0, false, Source::Regions),
    ("lidar_road_users", Modality::Lidar, 1.0, true, Source::RoadUsers),
    ("radar_road_users", Modality::Radar, 1.0, true, Source::RoadUsers),
    ("lidar_two_views_road_users", Modality::Lidar, 2.0, true, Source::RoadUsers),
    ("radar_two_views_road_users", Modality::Radar, 2.0, true, Source::RoadUsers),
    ("lidar_dense_road_users", Modality::Lidar, 2.0, false, Source::RoadUsers),
    ("radar_dense_road_users", Modality::Radar, 2.0, false, Source::RoadUsers),
    ("lidar_points", Modality::Lidar, 1.0, false, Source::Points),
    ("lidar_extent", Modality::Lidar, 1.0, false, Source::Extent),
];

/// What a term sums over: the target cells weighted by their region of interest, the same
/// cells weighted by the road users found there, or road users of sampled traffic frames with
/// the LiDAR points each option puts on them ([`Instance::points`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Source {
    Regions,
    RoadUsers,
    Points,
    Extent,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// One term of the objective: its modality, the multiple k of its coefficient sum that counts a
/// target fully, whether each sensor's coefficient is capped at 1 (min(1, a / τ)) or not
/// (a / τ, the dense term), whether its targets are weighted by the road users found there
/// rather than by their region of interest, and its weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Term {
    pub modality: Modality,
    pub k: f64,
    pub capped: bool,
    pub source: Source,
    pub weight: f64,
}

impl Term {
    /// The target weights this term sums over.
    pub fn targets<'a>(&self, inst: &'a Instance) -> &'a [f64] {
        match self.source {
            Source::Regions => &inst.weights,
            Source::RoadUsers => &inst.road_users,
            Source::Points => &inst.points.weights,
            Source::Extent => &inst.extents.weights,
        }
    }

    /// Calls `f(target, coefficient)` for each target option `o` adds to this term's sums
    /// (τ: the coverage threshold). The caller keeps `o` to the term's modality.
    #[inline]
    pub fn for_each(&self, inst: &Instance, o: usize, tau: f64, mut f: impl FnMut(usize, f64)) {
        match self.source {
            Source::Points | Source::Extent => {
                let rows = if self.source == Source::Points { &inst.points } else { &inst.extents };
                for &(j, n) in rows.rows.get(o).map_or(&[][..], |r| r.as_slice()) {
                    f(j as usize, f64::from(n) / rows.k);
                }
            }
            Source::Regions | Source::RoadUsers => {
                for &(j, v) in &inst.options[o].row {
                    f(j as usize, self.coef(coverage_coef(v as f64) / tau));
                }
            }
        }
    }

    /// Their sum (the term's normaliser W).
    pub fn total(&self, inst: &Instance) -> f64 {
        self.targets(inst).iter().sum::<f64>().max(1e-12)
    }

    /// A sensor's contribution to a coverage term's sum for a target it sees with a / τ = `r`.
    pub fn coef(&self, r: f64) -> f64 {
        if self.capped { r.min(1.0) } else { r }
    }
}

impl Weights {
    /// Only the terms saturating at τ.
    pub fn once(lidar: f64, radar: f64) -> Self {
        Weights { lidar, radar, ..Weights::default() }
    }

    /// The terms, zero weights included.
    pub(crate) fn terms(&self) -> [Term; N_TERMS] {
        let v = self.values();
        std::array::from_fn(|i| {
            let (_, modality, k, capped, source) = SHAPES[i];
            Term { modality, k, capped, source, weight: v[i] }
        })
    }

    /// Whether a term over the road users has a weight (the instance then needs
    /// [`Instance::road_users`]).
    pub fn reads_road_users(&self) -> bool {
        self.terms().iter().any(|t| t.source == Source::RoadUsers && t.weight > 0.0)
    }

    /// Whether the point-count term has a weight (the instance then needs
    /// [`Instance::points`]).
    pub fn reads_points(&self) -> bool {
        self.lidar_points > 0.0
    }

    /// Whether the footprint term has a weight (the instance then needs
    /// [`Instance::extents`]).
    pub fn reads_extents(&self) -> bool {
        self.lidar_extent > 0.0
    }

    /// The weights by their names in a study file, in the order of [`Weights::terms`].
    pub fn named(&self) -> [(&'static str, f64); N_TERMS] {
        let v = self.values();
        std::array::from_fn(|i| (SHAPES[i].0, v[i]))
    }

    /// The weights in the order of [`Weights::named`].
    pub fn values(&self) -> [f64; N_TERMS] {
        let mut w = *self;
        w.fields_mut().map(|f| *f)
    }

    /// Weight 1 on term `k` of [`Weights::named`], 0 on the others: that term alone.
    pub fn unit(k: usize) -> Self {
        let mut v = [0.0; N_TERMS];
        v[k] = 1.0;
        Weights::from_array(v)
    }

    /// Weights from their values in the order of [`Weights::named`].
    pub fn from_array(v: [f64; N_TERMS]) -> Self {
        let mut w = Weights::default();
        for (f, x) in w.fields_mut().into_iter().zip(v) {
            *f = x;
        }
        w
    }

    /// The fields in the order of [`SHAPES`]: the one place that order is written.
    fn fields_mut(&mut self) -> [&mut f64; N_TERMS] {
        [
            &mut self.lidar,
            &mut self.radar,
            &mut self.lidar_two_views,
            &mut self.radar_two_views,
            &mut self.lidar_dense,
            &mut self.radar_dense,
            &mut self.lidar_road_users,
            &mut self.radar_road_users,
            &mut self.lidar_two_views_road_users,
            &mut self.radar_two_views_road_users,
            &mut self.lidar_dense_road_users,
            &mut self.radar_dense_road_users,
            &mut self.lidar_points,
            &mut self.lidar_extent,
        ]
    }

    /// Refuses weights that would not keep the objective an IP with capped terms.
    pub fn check(&self) -> Result<(), PlacementError> {
        for (name, v) in self.named() {
            if !(v.is_finite() && (0.0..=MAX_WEIGHT).contains(&v)) {
                return Err(PlacementError::setting(
                    format!("placement.calibration.{name}"),
                    format!("{v:e}"),
                    format!(
                        "a weight must be in [0, {MAX_WEIGHT:e}] (only the weights' ratios matter; fitted ones are mAP \
                         per unit of coverage, well below 1)"
                    ),
                ));
            }
        }
        if self.terms().iter().all(|t| t.weight == 0.0) {
            return Err(PlacementError::setting("placement.calibration", "0 everywhere", "nothing to maximise"));
        }
        // One IP weighs every term against the largest: a term below this share of it is
        // within the solver's tolerances of nothing, and would be dropped without a word.
        let largest = self.largest();
        if let Some((name, v)) = self.named().into_iter().find(|&(_, v)| v > 0.0 && v < largest * MIN_WEIGHT_RATIO) {
            return Err(PlacementError::setting(
                format!("placement.calibration.{name}"),
                format!("{v:e}"),
                format!(
                    "less than {MIN_WEIGHT_RATIO:e} of the largest weight ({largest:e}); the solver cannot tell it \
                     from 0: set it to 0, or bring the weights closer"
                ),
            ));
        }
        Ok(())
    }

    /// The largest weight (the scale the IP divides every weight by).
    pub fn largest(&self) -> f64 {
        self.named().into_iter().map(|(_, v)| v).fold(0.0, f64::max)
    }
}

/// Refuses weights over road users for an instance that holds none (or holds them for other
/// targets).
pub fn check_instance(inst: &Instance, w: &Weights) -> Result<(), PlacementError> {
    if w.reads_road_users() && inst.road_users.len() != inst.n_targets() {
        return Err(PlacementError::instance(
            "placement.calibration",
            format!(
                "weighs road users, but the instance has road-user weights for {} of its {} targets",
                inst.road_users.len(),
                inst.n_targets()
            ),
        ));
    }
    let rows = [
        (w.reads_points(), &inst.points, "lidar_points", "LiDAR points on road users", "point counts"),
        (w.reads_extents(), &inst.extents, "lidar_extent", "the footprint LiDAR points span", "footprint shares"),
    ];
    for (reads, rows, term, what, held) in rows {
        if reads && rows.rows.len() != inst.options.len() {
            return Err(PlacementError::instance(
                format!("placement.calibration.{term}"),
                format!(
                    "weighs {what}, but the instance has {held} for {} of its {} options",
                    rows.rows.len(),
                    inst.options.len()
                ),
            ));
        }
    }
    if let Some(f) = inst.floors.iter().find(|f| f.rows.len() != inst.options.len()) {
        return Err(PlacementError::instance(
            "placement.min_hit_share",
            format!("the {} hit floor has rows for {} of {} options", f.class, f.rows.len(), inst.options.len()),
        ));
    }
    Ok(())
}

/// The calibrated objective of a selection (a term over road users counts 0 on an instance
/// without them: [`check_instance`]).
pub fn evaluate(inst: &Instance, sel: &[usize], w: &Weights) -> f64 {
    let tau = inst.tau();
    let mut f = 0.0;
    for t in w.terms().iter().filter(|t| t.weight > 0.0) {
        let s = sums(inst, sel, t, tau);
        let covered: f64 = s.iter().zip(t.targets(inst)).map(|(s, wj)| wj * (s / t.k).min(1.0)).sum();
        f += t.weight * covered / t.total(inst);
    }
    f
}

/// Per target, the sum of term `t`'s coefficients over the sensors of `sel` of its modality
/// (for a capped term, how many sensors see the target well, each counting at most once).
fn sums(inst: &Instance, sel: &[usize], t: &Term, tau: f64) -> Vec<f64> {
    let mut s = vec![0.0; t.targets(inst).len()];
    for &o in sel.iter().filter(|&&o| inst.modality(o) == t.modality) {
        t.for_each(inst, o, tau, |j, c| {
            if let Some(x) = s.get_mut(j) {
                *x += c;
            }
        });
    }
    s
}

pub(crate) fn outcome(
    inst: &Instance,
    sel: Vec<usize>,
    w: &Weights,
    bound: f64,
    proven: bool,
    start: Instant,
    method: &str,
) -> Outcome {
    let objective = evaluate(inst, &sel, w);
    let bound = if proven { objective } else { bound.max(objective) };
    Outcome {
        gap: (bound - objective) / objective.abs().max(1e-9),
        selection: sel,
        objective,
        bound,
        proven_optimal: proven,
        solve_seconds: start.elapsed().as_secs_f64(),
        method: method.to_owned(),
    }
}

/// Solves the calibrated objective: swaps from `warm` (at most the limit's seconds), then CBC
/// warm-started from them within `solve_limit` (seconds and, optionally, nodes) when the IP
/// has at most `max_nonzeros` non-zeros (default [`CBC_MAX_NONZEROS`]); otherwise the swaps'
/// selection with the submodular bound ([`upper_bound`]). Never returns less than the warm
/// start; an unproven result reports the tighter of the two bounds.
pub fn solve(
    inst: &Instance,
    limit: &Limit,
    w: &Weights,
    solve_limit: impl Into<SolveLimit>,
    max_nonzeros: usize,
    warm: &Outcome,
) -> Result<Outcome, PlacementError> {
    solve_given(inst, limit, w, (solve_limit, max_nonzeros), warm, &[])
}

/// [`solve`] keeping the options of `fixed` (a feasible part of a selection, all of them in
/// `warm`, as [`greedy_given`] makes it): swaps never take them out and CBC holds them at 1, so a
/// proven result is optimal over every selection that holds them. The submodular bound of a
/// large instance bounds every selection, those holding them among them.
pub fn solve_given(
    inst: &Instance,
    limit: &Limit,
    w: &Weights,
    (solve_limit, max_nonzeros): (impl Into<SolveLimit>, usize),
    warm: &Outcome,
    fixed: &[usize],
) -> Result<Outcome, PlacementError> {
    let start = Instant::now();
    let solve_limit: SolveLimit = solve_limit.into();
    let time_limit_s = solve_limit.seconds;
    w.check()?;
    check_instance(inst, w)?;
    if let Some(o) = fixed.iter().find(|o| !warm.selection.contains(o)) {
        return Err(PlacementError::Solver(format!("the warm start lacks the given option {o}")));
    }
    let local = no_worse_than(inst, swaps(inst, limit, w, warm, time_limit_s, fixed), warm);
    let nz = nonzeros(inst, w);
    if nz > max_nonzeros {
        let out = Outcome {
            solve_seconds: start.elapsed().as_secs_f64(),
            method: format!(
                "greedy and swaps, calibrated objective{} (CBC not run: {nz} non-zeros > {max_nonzeros})",
                floors_said(inst)
            ),
            ..local
        };
        let what = format!(
            "greedy and swaps (CBC not run: {nz} non-zeros > {max_nonzeros}, placement.calibrated_cbc_max_nonzeros) found no selection within the limit"
        );
        return floors_met(inst, out, &what);
    }
    let out = cbc(inst, limit, w, solve_limit, &local, fixed).map_err(|e| match e {
        PlacementError::Solver(m) if !inst.floors.is_empty() && m.ends_with("infeasible or unbounded") => {
            PlacementError::Infeasible(format!(
                "no selection within the limit meets the hit floors ({}; CBC proved it); the most greedy and swaps reached: {}",
                floor_list(inst),
                floor_shares(inst, &local.selection)
            ))
        }
        e => e,
    })?;
    let out = Outcome { method: format!("{}{} ({nz} non-zeros)", out.method, floors_said(inst)), ..out };
    let out = if out.proven_optimal || out.bound <= local.bound {
        Outcome { solve_seconds: start.elapsed().as_secs_f64(), ..out }
    } else {
        let bound = local.bound.max(out.objective);
        Outcome {
            gap: (bound - out.objective) / out.objective.abs().max(1e-9),
            bound,
            solve_seconds: start.elapsed().as_secs_f64(),
            ..out
        }
    };
    floors_met(inst, out, "CBC stopped before it found a selection within the limit")
}

/// Per hit floor of `inst`, its samples some option hits, each with those options (a sample
/// no option hits needs no column: it stays unhit).
fn floor_columns(inst: &Instance) -> Vec<Vec<(u32, Vec<usize>)>> {
    inst.floors
        .iter()
        .map(|f| {
            let mut by: std::collections::BTreeMap<u32, Vec<usize>> = std::collections::BTreeMap::new();
            for (o, row) in f.rows.iter().enumerate() {
                for &s in row {
                    by.entry(s).or_default().push(o);
                }
            }
            by.into_iter().collect()
        })
        .collect()
}

/// `out`, or `warm`'s selection where that is better by more than rounding and meets the hit
/// floors (a selection below them is no placement, however high its objective).
fn no_worse_than(inst: &Instance, out: Outcome, warm: &Outcome) -> Outcome {
    if inst.meets_floors(&warm.selection) { out.no_worse_than(warm, 1e-12) } else { out }
}

/// `out` when its selection meets the instance's hit floors; otherwise why not (`what` says
/// which search came short), with the shares it reaches.
fn floors_met(inst: &Instance, out: Outcome, what: &str) -> Result<Outcome, PlacementError> {
    if inst.meets_floors(&out.selection) {
        return Ok(out);
    }
    Err(PlacementError::Infeasible(format!(
        "{what} that meets the hit floors ({}); the selection it found: {}",
        floor_list(inst),
        floor_shares(inst, &out.selection)
    )))
}

/// The instance's hit floors as a method's suffix: ", hit floors pedestrian ≥ 95.0%" (empty
/// without floors).
fn floors_said(inst: &Instance) -> String {
    if inst.floors.is_empty() { String::new() } else { format!(", hit floors {}", floor_list(inst)) }
}

/// The instance's hit floors: "pedestrian ≥ 95.0%, car ≥ 90.0%".
fn floor_list(inst: &Instance) -> String {
    let f: Vec<String> = inst.floors.iter().map(|f| format!("{} ≥ {:.1}%", f.class, 100.0 * f.share)).collect();
    f.join(", ")
}

/// The share of each floor's class that `sel` hits ("pedestrian 91.2% of 1024").
fn floor_shares(inst: &Instance, sel: &[usize]) -> String {
    let f: Vec<String> =
        inst.floors.iter().map(|f| format!("{} {:.1}% of {}", f.class, 100.0 * f.share_hit(sel), f.samples)).collect();
    f.join(", ")
}

/// The calibrated IP by CBC within `solve_limit`, warm-started from `warm`, the options of
/// `fixed` held at 1.
fn cbc(
    inst: &Instance,
    limit: &Limit,
    w: &Weights,
    solve_limit: SolveLimit,
    warm: &Outcome,
    fixed: &[usize],
) -> Result<Outcome, PlacementError> {
    let start = Instant::now();
    let tau = inst.tau();
    let mut vars = ProblemVariables::new();
    let x: Vec<Variable> = (0..inst.options.len()).map(|_| vars.add(variable().binary())).collect();
    // Per non-zero term, per target, the options adding to it with their coefficients.
    let terms = w.terms();
    let cols: Vec<Vec<Vec<(usize, f64)>>> = terms
        .iter()
        .map(|t| {
            let mut c = vec![Vec::new(); if t.weight > 0.0 { t.targets(inst).len() } else { 0 }];
            for o in (0..inst.options.len()).filter(|&o| t.weight > 0.0 && inst.modality(o) == t.modality) {
                t.for_each(inst, o, tau, |j, a| {
                    if let Some(col) = c.get_mut(j) {
                        col.push((o, a));
                    }
                });
            }
            c
        })
        .collect();
    // (variable, objective coefficient, term's index, target). The weights enter divided by
    // the largest: the argmax is the same, and CBC's coefficients stay in its range however
    // large the weights are (CBC aborts past 1e25 and loses the smaller terms long before).
    let scale = w.largest();
    let mut z: Vec<(Variable, f64, usize, usize)> = Vec::new();
    for (ti, t) in terms.iter().enumerate().filter(|(_, t)| t.weight > 0.0) {
        let (wt, total) = (t.targets(inst), t.total(inst));
        for (j, col) in cols[ti].iter().enumerate() {
            if !col.is_empty() && wt[j] > 0.0 {
                z.push((vars.add(variable().min(0.0).max(1.0)), t.weight / scale * wt[j] / total, ti, j));
            }
        }
    }
    let floors = floor_columns(inst);
    let y: Vec<Vec<Variable>> =
        floors.iter().map(|f| f.iter().map(|_| vars.add(variable().min(0.0).max(1.0))).collect()).collect();
    let objective: Expression = z.iter().map(|&(v, c, ..)| c * v).sum();
    let mut problem = vars.maximise(objective).using(coin_cbc);
    problem.set_parameter("log", "0");
    for &(v, _, ti, j) in &z {
        let t = &terms[ti];
        let cover: Expression = cols[ti][j].iter().map(|&(o, a)| (a / t.k) * x[o]).sum();
        problem.add_constraint((v - cover).leq(0.0));
    }
    crate::mip::add_limit(&mut problem, inst, limit, &x);
    for &o in fixed {
        problem.add_constraint(Expression::from(x[o]).geq(1.0));
    }
    let chosen: std::collections::HashSet<usize> = warm.selection.iter().copied().collect();
    let mut init: Vec<(Variable, f64)> =
        x.iter().enumerate().map(|(o, &v)| (v, if chosen.contains(&o) { 1.0 } else { 0.0 })).collect();
    let s: Vec<Vec<f64>> =
        terms.iter().map(|t| if t.weight > 0.0 { sums(inst, &warm.selection, t, tau) } else { Vec::new() }).collect();
    init.extend(z.iter().map(|&(v, _, ti, j)| (v, (s[ti][j] / terms[ti].k).min(1.0))));
    // The hit floors: y_s ≤ Σ_{o hits s} x_o, Σ_s y_s ≥ what the floor needs.
    for ((f, cols), ys) in inst.floors.iter().zip(&floors).zip(&y) {
        for ((_, col), &v) in cols.iter().zip(ys) {
            let cover: Expression = col.iter().map(|&o| x[o]).sum();
            problem.add_constraint((v - cover).leq(0.0));
            init.push((v, if col.iter().any(|o| chosen.contains(o)) { 1.0 } else { 0.0 }));
        }
        let total: Expression = ys.iter().copied().sum();
        problem.add_constraint(total.geq(f64::from(f.needed())));
    }
    let problem = problem.with_initial_solution(init);
    let run = crate::mip::run_cbc(problem, x.len(), solve_limit, "CBC, calibrated objective")?;
    let method = run.method("CBC, calibrated objective");
    // Without proof and without an incumbent CBC's columns may break the limit or the floors:
    // the warm start stands.
    let valid = |sel: &[usize]| inst.check(limit, sel).is_ok() && inst.meets_floors(sel);
    let selection = if run.proven || valid(&run.selection) { run.selection } else { warm.selection.clone() };
    let bound = if run.bound.is_finite() { run.bound * scale } else { f64::INFINITY };
    let out = outcome(inst, selection, w, bound, run.proven, start, &method);
    Ok(no_worse_than(inst, out, warm))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::instance::{SensorOption, SensorType};
    use rand::{Rng, SeedableRng};

    fn random_instance(seed: u64) -> Instance {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let types = vec![
            SensorType { name: "l".into(), modality: Modality::Lidar, price_usd: 4.0 },
            SensorType { name: "r".into(), modality: Modality::Radar, price_usd: 2.0 },
        ];
        let options = (0..12)
            .map(|i| {
                let mut row = Vec::new();
                for j in 0..25u32 {
                    if rng.random::<f32>() < 0.35 {
                        row.push((j, rng.random_range(0.05f32..0.99)));
                    }
                }
                SensorOption { ty: i % 2, candidate: i as u32, mount: (i / 2) as u32, row }
            })
            .collect();
        Instance {
            weights: (0..25).map(|_| rng.random_range(0.5..3.0)).collect(),
            types,
            options,
            p_min: 1.0 - (-1.0f64).exp(),
            // Road users on some targets only (lanes no one drives weigh 0).
            road_users: (0..25)
                .map(|_| if rng.random::<f32>() < 0.4 { 0.0 } else { rng.random_range(0.0..0.1) })
                .collect(),
            points: random_points(&mut rng, 12),
            extents: random_extents(&mut rng, 12),
            floors: Vec::new(),
        }
    }

    /// The same 30 samples and, per LiDAR option, the share of each one's footprint it spans
    /// (thousandths, 0.05 to 0.7: two views can fill a sample, one cannot).
    fn random_extents(rng: &mut rand::rngs::StdRng, options: usize) -> crate::instance::PointRows {
        let mut r = random_points(rng, options);
        r.k = crate::instance::EXTENT_UNITS;
        for row in &mut r.rows {
            for e in row.iter_mut() {
                e.1 = rng.random_range(50..700);
            }
        }
        r
    }

    /// 30 road-user samples of two classes (class-balanced weights) and, per LiDAR option, the
    /// points it puts on some of them (0 to 12, k = 5: one dense view can fill a sample).
    fn random_points(rng: &mut rand::rngs::StdRng, options: usize) -> crate::instance::PointRows {
        let class: Vec<usize> = (0..30).map(|j| usize::from(j % 3 == 0)).collect();
        let per = [20.0, 10.0];
        let weights = class.iter().map(|&c| 1.0 / (per[c] * 2.0)).collect();
        let rows = (0..options)
            .map(|o| {
                if o % 2 == 1 {
                    return Vec::new();
                }
                let mut row = Vec::new();
                for j in 0..30u32 {
                    if rng.random::<f32>() < 0.4 {
                        row.push((j, rng.random_range(1..12)));
                    }
                }
                row
            })
            .collect();
        crate::instance::PointRows { k: 5.0, weights, rows }
    }

    /// Every feasible selection of a small instance, by brute force.
    fn brute(inst: &Instance, limit: &Limit, w: &Weights) -> f64 {
        let n = inst.options.len();
        (0u32..1 << n)
            .map(|mask| (0..n).filter(|o| mask & (1 << o) != 0).collect::<Vec<_>>())
            .filter(|s| inst.check(limit, s).is_ok())
            .map(|s| evaluate(inst, &s, w))
            .fold(0.0, f64::max)
    }

    /// CBC's optimum equals brute force under two counts and under a budget; greedy is never
    /// above it; with `proven`, CBC says it proved it.
    fn assert_cbc_is_brute_force(inst: &Instance, w: &Weights, seed: u64, proven: bool) {
        for limit in [Limit::Counts(vec![2, 1]), Limit::Budget { usd: 10.0, min: vec![0, 0], max: vec![9, 9] }] {
            let g = greedy(inst, &limit, w);
            let out = solve(inst, &limit, w, 30.0, CBC_MAX_NONZEROS, &g).unwrap();
            let best = brute(inst, &limit, w);
            assert!(inst.check(&limit, &out.selection).is_ok(), "seed {seed} {limit:?}: {:?}", out.selection);
            assert!((out.objective - best).abs() < 1e-6, "seed {seed} {limit:?}: {} vs {best}", out.objective);
            assert!(g.objective <= best + 1e-9, "seed {seed} {limit:?}: greedy {} above {best}", g.objective);
            assert!(!proven || out.proven_optimal, "seed {seed} {limit:?}: {}", out.method);
        }
    }

    /// CBC on the calibrated IP equals brute force over every selection, under counts and under
    /// a budget, with both weights, with the radar's at 0 and with the two-view terms;
    /// greedy is never above it.
    #[test]
    fn the_calibrated_ip_equals_brute_force() {
        for seed in 0..8 {
            let inst = random_instance(seed);
            let w = match seed % 4 {
                0 => Weights::once(0.6, 0.2),
                1 => Weights::once(0.5, 0.0),
                3 => Weights {
                    lidar: 0.2,
                    lidar_road_users: 0.5,
                    radar_road_users: 0.1,
                    lidar_two_views_road_users: 0.3,
                    radar_dense_road_users: 0.05,
                    lidar_points: if seed == 7 { 0.4 } else { 0.0 },
                    lidar_extent: if seed == 3 { 0.6 } else { 0.0 },
                    ..Weights::default()
                },
                _ => Weights {
                    lidar: 0.3,
                    radar: 0.1,
                    lidar_two_views: 0.4,
                    radar_two_views: 0.05,
                    lidar_dense: 0.2,
                    radar_dense: 0.0,
                    ..Weights::default()
                },
            };
            assert_cbc_is_brute_force(&inst, &w, seed, false);
        }
    }

    /// A floor of 40 samples that the LiDAR options (even options) each hit about a third of.
    fn random_floor(seed: u64, options: usize) -> crate::instance::HitFloor {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0xf100);
        let rows = (0..options)
            .map(|o| if o % 2 == 1 { Vec::new() } else { (0..40u32).filter(|_| rng.random::<f32>() < 0.3).collect() })
            .collect();
        crate::instance::HitFloor { class: "pedestrian".into(), share: 1.0, samples: 40, rows }
    }

    /// Hit floors, by brute force: CBC's optimum is the best selection that meets them, and it
    /// meets them; greedy and swaps (CBC not run) meet them too, never above that optimum; a
    /// floor no selection meets is refused by both paths, naming the class and the share
    /// reached. The floors are set at the best share any selection reaches, so they bind.
    #[test]
    fn hit_floors_keep_every_solver_above_them() {
        let (mut binding, mut searched) = (0, 0);
        for seed in 0..8 {
            let mut inst = random_instance(seed);
            inst.floors = vec![random_floor(seed, inst.options.len())];
            inst.validate().unwrap();
            // Rows out of order, past the samples, or of another length are refused.
            let mut bad = inst.clone();
            bad.floors[0].rows[0] = vec![3, 2];
            assert!(bad.validate().unwrap_err().to_string().contains("ascending"));
            bad.floors[0].rows[0] = vec![40];
            assert!(bad.validate().is_err());
            bad.floors[0].rows.pop();
            assert!(bad.validate().unwrap_err().to_string().contains("rows for 11 of 12"));
            let w = if seed % 2 == 0 {
                Weights::once(0.6, 0.2)
            } else {
                Weights { lidar: 0.2, lidar_road_users: 0.5, radar_road_users: 0.1, ..Weights::default() }
            };
            for limit in [Limit::Counts(vec![2, 1]), Limit::Budget { usd: 10.0, min: vec![0, 0], max: vec![9, 9] }] {
                let n = inst.options.len();
                let feasible: Vec<Vec<usize>> = (0u32..1 << n)
                    .map(|mask| (0..n).filter(|o| mask & (1 << o) != 0).collect::<Vec<_>>())
                    .filter(|s| inst.check(&limit, s).is_ok())
                    .collect();
                let floor = &inst.floors[0];
                let most = feasible.iter().map(|s| floor.hits(s)).max().unwrap();
                inst.floors[0].share = f64::from(most) / 40.0;
                let meets = |s: &Vec<usize>| inst.meets_floors(s);
                let best = feasible.iter().filter(|s| meets(s)).map(|s| evaluate(&inst, s, &w)).fold(0.0, f64::max);
                let free = feasible.iter().map(|s| evaluate(&inst, s, &w)).fold(0.0, f64::max);
                binding += usize::from(best < free - 1e-9);
                let g = greedy(&inst, &limit, &w);
                let out = solve(&inst, &limit, &w, 30.0, CBC_MAX_NONZEROS, &g).unwrap();
                assert!(meets(&out.selection), "seed {seed} {limit:?}: {:?}", out.selection);
                assert!((out.objective - best).abs() < 1e-6, "seed {seed} {limit:?}: {} vs {best}", out.objective);
                assert!(out.method.contains("hit floors pedestrian"), "{}", out.method);
                match solve(&inst, &limit, &w, 30.0, 0, &g) {
                    Ok(local) => {
                        searched += 1;
                        assert!(meets(&local.selection), "seed {seed} {limit:?}: {:?}", local.selection);
                        assert!(local.objective <= best + 1e-9 && local.bound >= best - 1e-9, "seed {seed}");
                    }
                    Err(e) => assert!(e.to_string().contains("greedy and swaps found no selection"), "{e}"),
                }
                // One more sample than any selection hits.
                inst.floors[0].share = f64::from(most + 1) / 40.0;
                for max_nonzeros in [CBC_MAX_NONZEROS, 0] {
                    let e = solve(&inst, &limit, &w, 30.0, max_nonzeros, &g).unwrap_err().to_string();
                    assert!(e.starts_with("infeasible: ") && e.contains("pedestrian"), "seed {seed}: {e}");
                    assert!(max_nonzeros == 0 || e.contains("CBC proved it"), "{e}");
                    assert!(max_nonzeros > 0 || e.contains("the selection it found: pedestrian"), "{e}");
                }
            }
        }
        // The floors change the optimum in most cases, and greedy and swaps meet most of them.
        assert!(binding >= 8 && searched >= 12, "binding {binding}, met by the search {searched} of 16");
    }

    /// Under a budget greedy meets a floor the way a weighted set cover does, by what each option
    /// closes per dollar: one dear LiDAR closes most of the floor alone but leaves no money for
    /// the rest, two cheap ones close all of it for less. Brute force says the floor is met only
    /// by selections holding both cheap ones; greedy alone (no swaps, no CBC) finds one.
    #[test]
    fn under_a_budget_greedy_meets_a_floor_per_dollar() {
        let types = vec![
            SensorType { name: "dear".into(), modality: Modality::Lidar, price_usd: 20.0 },
            SensorType { name: "cheap".into(), modality: Modality::Lidar, price_usd: 4.0 },
            SensorType { name: "r".into(), modality: Modality::Radar, price_usd: 2.0 },
        ];
        let options: Vec<SensorOption> =
            [(0, vec![(0, 0.9), (1, 0.9), (2, 0.9)]), (1, vec![(0, 0.5)]), (1, vec![(1, 0.5)])]
                .into_iter()
                .enumerate()
                .map(|(i, (ty, row))| SensorOption { ty, candidate: i as u32, mount: i as u32, row })
                .collect();
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let inst = Instance {
            weights: vec![1.0, 1.0, 1.0],
            types,
            options,
            p_min: 1.0 - (-1.0f64).exp(),
            road_users: vec![0.05, 0.05, 0.05],
            points: random_points(&mut rng, 3),
            extents: random_extents(&mut rng, 3),
            floors: vec![crate::instance::HitFloor {
                class: "pedestrian".into(),
                share: 11.0 / 12.0,
                samples: 12,
                rows: vec![(0..10).collect(), (0..6).collect(), (6..12).collect()],
            }],
        };
        inst.validate().unwrap();
        let limit = Limit::Budget { usd: 22.0, min: vec![0, 0, 0], max: vec![9, 9, 9] };
        let w = Weights::once(0.6, 0.2);
        let meeting: Vec<Vec<usize>> = (0u32..1 << 3)
            .map(|mask| (0..3).filter(|o| mask & (1 << o) != 0).collect::<Vec<_>>())
            .filter(|s| inst.check(&limit, s).is_ok() && inst.meets_floors(s))
            .collect();
        assert!(!meeting.is_empty() && meeting.iter().all(|s| s.contains(&1) && s.contains(&2)), "{meeting:?}");
        let g = greedy(&inst, &limit, &w);
        assert!(inst.meets_floors(&g.selection), "greedy: {:?}", g.selection);
        assert!(inst.check(&limit, &g.selection).is_ok());
        let best = meeting.iter().map(|s| evaluate(&inst, s, &w)).fold(0.0, f64::max);
        let out = solve(&inst, &limit, &w, 30.0, CBC_MAX_NONZEROS, &g).unwrap();
        assert!((out.objective - best).abs() < 1e-6 && inst.meets_floors(&out.selection));
    }

    /// Given a sensor: CBC keeps it and equals brute force over the selections that hold it;
    /// without CBC, greedy and swaps keep it and the bound is never below that optimum.
    #[test]
    fn the_calibrated_ip_keeps_the_given_sensor() {
        for seed in 0..6 {
            let inst = random_instance(seed);
            let w = Weights { lidar: 0.3, radar: 0.1, lidar_two_views: 0.4, ..Weights::default() };
            let Some(fixed) = (0..inst.options.len()).find(|&o| inst.options[o].ty == 0) else { continue };
            for limit in [Limit::Counts(vec![2, 1]), Limit::Budget { usd: 10.0, min: vec![0, 0], max: vec![9, 9] }] {
                let n = inst.options.len();
                let best = (0u32..1 << n)
                    .map(|mask| (0..n).filter(|o| mask & (1 << o) != 0).collect::<Vec<_>>())
                    .filter(|s| s.contains(&fixed) && inst.check(&limit, s).is_ok())
                    .map(|s| evaluate(&inst, &s, &w))
                    .fold(0.0, f64::max);
                let g = greedy_given(&inst, &limit, &w, &[fixed]);
                assert!(g.selection.contains(&fixed) && g.objective <= best + 1e-9, "seed {seed}");
                let out = solve_given(&inst, &limit, &w, (30.0, CBC_MAX_NONZEROS), &g, &[fixed]).unwrap();
                assert!(out.selection.contains(&fixed) && inst.check(&limit, &out.selection).is_ok());
                assert!((out.objective - best).abs() < 1e-6, "seed {seed} {limit:?}: {} vs {best}", out.objective);
                let local = solve_given(&inst, &limit, &w, (30.0, 0), &g, &[fixed]).unwrap();
                assert!(local.selection.contains(&fixed) && local.objective <= best + 1e-9, "seed {seed}");
                assert!(local.bound >= best - 1e-9, "seed {seed}: bound {} below {best}", local.bound);
            }
            let free = greedy(&inst, &Limit::Counts(vec![2, 1]), &w);
            assert!(
                solve_given(&inst, &Limit::Counts(vec![2, 1]), &w, (30.0, 0), &free, &[n_missing(&free, &inst)])
                    .is_err_and(|e| e.to_string().contains("given option"))
            );
        }
    }

    /// An option a selection lacks.
    fn n_missing(o: &Outcome, inst: &Instance) -> usize {
        (0..inst.options.len()).find(|x| !o.selection.contains(x)).unwrap_or(0)
    }

    /// Without CBC: greedy meets the minimum counts, swaps never lose, and the submodular
    /// bound (from the empty selection and from the swaps' result) is never below the optimum
    /// found by brute force.
    #[test]
    fn swaps_and_the_submodular_bound_bracket_the_optimum() {
        for seed in 0..12 {
            let inst = random_instance(100 + seed);
            let w = match seed % 4 {
                0 => Weights::once(0.6, 0.2),
                1 => Weights { radar: 0.3, lidar_two_views: 0.5, radar_dense: 0.2, ..Weights::default() },
                3 => Weights {
                    lidar_road_users: 0.4,
                    radar_two_views_road_users: 0.2,
                    lidar_dense_road_users: 0.3,
                    lidar_points: if seed == 7 { 0.5 } else { 0.0 },
                    ..Weights::default()
                },
                _ => Weights {
                    lidar: 0.3,
                    radar: 0.1,
                    lidar_two_views: 0.4,
                    radar_two_views: 0.05,
                    lidar_dense: 0.3,
                    radar_dense: 0.0,
                    ..Weights::default()
                },
            };
            for limit in [
                Limit::Counts(vec![2, 1]),
                Limit::Total(3),
                Limit::Budget { usd: 10.0, min: vec![0, 0], max: vec![9, 9] },
                Limit::Budget { usd: 8.0, min: vec![0, 2], max: vec![1, 9] },
            ] {
                let best = brute(&inst, &limit, &w);
                let g = greedy(&inst, &limit, &w);
                assert!(inst.check(&limit, &g.selection).is_ok(), "seed {seed} {limit:?}: {:?}", g.selection);
                let s = swaps(&inst, &limit, &w, &g, 30.0, &[]);
                assert!(inst.check(&limit, &s.selection).is_ok(), "seed {seed} {limit:?}: {:?}", s.selection);
                assert!(s.objective >= g.objective - 1e-12 && s.objective <= best + 1e-9);
                assert!((s.objective - evaluate(&inst, &s.selection, &w)).abs() < 1e-9, "incremental sums drift");
                for b in [s.bound, upper_bound(&inst, &limit, &w, &[])] {
                    assert!(b >= best - 1e-9, "seed {seed} {limit:?}: bound {b} below the optimum {best}");
                }
            }
        }
    }

    /// A term over road users weighs each target by its road users: hand-computed on two
    /// targets, and refused on an instance that holds no road-user weights.
    #[test]
    fn road_user_terms_weigh_targets_by_their_road_users() {
        let mut inst = Instance {
            weights: vec![1.0, 1.0],
            types: vec![SensorType { name: "l".into(), modality: Modality::Lidar, price_usd: 1.0 }],
            options: vec![SensorOption { ty: 0, candidate: 0, mount: 0, row: vec![(0, 0.99)] }],
            p_min: 1.0 - (-1.0f64).exp(),
            road_users: vec![0.3, 0.1],
            points: Default::default(),
            extents: Default::default(),
            floors: Vec::new(),
        };
        let w = Weights { lidar_road_users: 1.0, ..Weights::default() };
        // Target 0 seen fully holds 0.3 of the 0.4 road users on targets; by region, 1 of 2.
        assert!((evaluate(&inst, &[0], &w) - 0.75).abs() < 1e-9);
        assert!((evaluate(&inst, &[0], &Weights::once(1.0, 0.0)) - 0.5).abs() < 1e-9);
        assert!(w.reads_road_users() && !Weights::once(1.0, 1.0).reads_road_users());
        assert!(Weights { radar_dense_road_users: -1.0, ..w }.check().is_err());
        inst.road_users.clear();
        let limit = Limit::Counts(vec![1]);
        let e = solve(&inst, &limit, &w, 5.0, CBC_MAX_NONZEROS, &greedy(&inst, &limit, &w)).unwrap_err();
        assert!(e.to_string().contains("road-user weights for 0 of its 2 targets"), "{e}");
    }

    /// An instance past the size CBC is given is solved by swaps with a finite bound, and says so.
    #[test]
    fn a_large_instance_is_not_handed_to_cbc() {
        let mut inst = random_instance(7);
        let n = 4_000u32;
        inst.weights = (0..n).map(|j| 1.0 + (j % 7) as f64).collect();
        for (i, opt) in inst.options.iter_mut().enumerate() {
            opt.row = (0..n).map(|j| (j, 0.05 + 0.9 * (((i as u32 * 31 + j * 17) % 97) as f32 / 97.0))).collect();
        }
        let mut more: Vec<SensorOption> = (0..14)
            .flat_map(|rep| {
                inst.options.iter().map(move |o| SensorOption { mount: o.mount + 6 * (rep + 1), ..o.clone() })
            })
            .collect();
        inst.options.append(&mut more);
        let w = Weights { lidar: 0.5, radar: 0.1, lidar_two_views: 0.3, ..Weights::default() };
        assert!(nonzeros(&inst, &w) > CBC_MAX_NONZEROS);
        let limit = Limit::Counts(vec![2, 1]);
        let out = solve(&inst, &limit, &w, 30.0, CBC_MAX_NONZEROS, &greedy(&inst, &limit, &w)).unwrap();
        assert!(out.method.contains("CBC not run"), "{}", out.method);
        assert!(inst.check(&limit, &out.selection).is_ok() && out.selection.len() == 3);
        assert!(out.bound.is_finite() && out.bound >= out.objective && !out.proven_optimal);
    }

    /// The point-count term is the capped count by hand: per road-user sample, min(1, the
    /// chosen LiDARs' points / k), weighted; CBC's optimum of it alone, and of it with a
    /// coverage term, equals brute force; an instance without point counts is refused.
    #[test]
    fn the_point_term_is_the_capped_point_count() {
        for seed in 0..6 {
            let inst = random_instance(300 + seed);
            inst.validate().unwrap();
            let w = if seed % 2 == 0 {
                Weights { lidar_points: 1.0, ..Weights::default() }
            } else {
                Weights { lidar_points: 0.5, radar: 0.2, ..Weights::default() }
            };
            let p = &inst.points;
            for sel in [vec![0], vec![0, 2], vec![0, 1, 2, 4, 6], (0..12).collect()] {
                let mut n = vec![0u32; p.weights.len()];
                for &o in &sel {
                    for &(j, c) in &p.rows[o] {
                        n[j as usize] += c;
                    }
                }
                let by_hand: f64 =
                    n.iter().zip(&p.weights).map(|(&n, w)| w * (f64::from(n) / p.k).min(1.0)).sum::<f64>()
                        / p.weights.iter().sum::<f64>();
                let only = Weights { lidar_points: 1.0, ..Weights::default() };
                assert!((evaluate(&inst, &sel, &only) - by_hand).abs() < 1e-12, "seed {seed} {sel:?}");
            }
            assert_cbc_is_brute_force(&inst, &w, seed, true);
        }
        let mut bare = random_instance(1);
        bare.points = Default::default();
        let w = Weights { lidar_points: 1.0, ..Weights::default() };
        let limit = Limit::Counts(vec![2, 1]);
        let err = solve(&bare, &limit, &w, 5.0, CBC_MAX_NONZEROS, &greedy(&bare, &limit, &w)).unwrap_err();
        assert!(err.to_string().contains("lidar_points"), "{err}");
        let mut bad = random_instance(2);
        bad.points.rows[0].push((999, 3));
        assert!(bad.validate().unwrap_err().to_string().contains("sample 999"));
    }

    /// The footprint term is the capped sum of shares by hand: per road-user sample, min(1,
    /// Σ of the chosen LiDARs' shares), weighted; CBC's optimum of it alone and beside the point
    /// and coverage terms equals brute force; an instance without shares is refused by name.
    #[test]
    fn the_footprint_term_is_the_capped_sum_of_shares() {
        for seed in 0..6 {
            let inst = random_instance(400 + seed);
            inst.validate().unwrap();
            let e = &inst.extents;
            for sel in [vec![0], vec![0, 2], vec![0, 1, 2, 4, 6], (0..12).collect()] {
                let mut share = vec![0.0f64; e.weights.len()];
                for &o in &sel {
                    for &(j, c) in &e.rows[o] {
                        share[j as usize] += f64::from(c) / 1000.0;
                    }
                }
                let by_hand: f64 = share.iter().zip(&e.weights).map(|(s, w)| w * s.min(1.0)).sum::<f64>()
                    / e.weights.iter().sum::<f64>();
                let only = Weights { lidar_extent: 1.0, ..Weights::default() };
                assert!((evaluate(&inst, &sel, &only) - by_hand).abs() < 1e-12, "seed {seed} {sel:?}");
            }
            let w = match seed % 3 {
                0 => Weights { lidar_extent: 1.0, ..Weights::default() },
                1 => Weights { lidar_extent: 0.7, lidar_points: 0.3, ..Weights::default() },
                _ => Weights { lidar_extent: 0.5, radar: 0.2, lidar_two_views: 0.2, ..Weights::default() },
            };
            assert_cbc_is_brute_force(&inst, &w, seed, true);
        }
        let mut bare = random_instance(1);
        bare.extents = Default::default();
        let w = Weights { lidar_extent: 1.0, ..Weights::default() };
        assert!(w.reads_extents() && !w.reads_points());
        let limit = Limit::Counts(vec![2, 1]);
        let err = solve(&bare, &limit, &w, 5.0, CBC_MAX_NONZEROS, &greedy(&bare, &limit, &w)).unwrap_err();
        assert!(err.to_string().contains("lidar_extent"), "{err}");
        let mut bad = random_instance(2);
        bad.extents.rows[0].push((999, 3));
        assert!(bad.validate().unwrap_err().to_string().contains("footprint entry on sample 999"));
    }

    /// One LiDAR that sees one of two targets fully (a ≈ 4.6 τ) and the other at half the
    /// threshold: its LiDAR coverage term is (1 + 0.5) / 2.
    pub(super) fn one_lidar_two_targets() -> Instance {
        Instance {
            weights: vec![1.0, 1.0],
            types: vec![SensorType { name: "l".into(), modality: Modality::Lidar, price_usd: 1.0 }],
            options: vec![SensorOption {
                ty: 0,
                candidate: 0,
                mount: 0,
                row: vec![(0, 0.99), (1, (1.0 - (-0.5f64).exp()) as f32)],
            }],
            p_min: 1.0 - (-1.0f64).exp(),
            road_users: Vec::new(),
            points: Default::default(),
            extents: Default::default(),
            floors: Vec::new(),
        }
    }

    /// Saturation: a target seen beyond τ counts once; half-seen counts half.
    #[test]
    fn coverage_saturates_at_the_threshold() {
        let inst = one_lidar_two_targets();
        let f = evaluate(&inst, &[0], &Weights::once(1.0, 0.0));
        assert!((f - (1.0 + 0.5) / 2.0).abs() < 1e-6, "{f}");
        // Two views: one sensor, however well it sees (a ≈ 4.6 τ), counts a target half.
        let f2 = evaluate(&inst, &[0], &Weights { lidar_two_views: 1.0, ..Weights::default() });
        assert!((f2 - (0.5 + 0.25) / 2.0).abs() < 1e-6, "{f2}");
        // Dense: the one sensor's uncapped a / τ (4.6 and 0.5) against 2: a full and a quarter.
        let f3 = evaluate(&inst, &[0], &Weights { lidar_dense: 1.0, ..Weights::default() });
        assert!((f3 - (1.0 + 0.25) / 2.0).abs() < 1e-6, "{f3}");
        assert!(Weights::once(-0.1, 1.0).check().is_err());
        assert!(Weights { radar_two_views: -0.1, ..Weights::once(1.0, 0.0) }.check().is_err());
        assert!(Weights { lidar_dense: f64::NAN, ..Weights::once(1.0, 0.0) }.check().is_err());
        assert!(Weights::default().check().is_err());
        // Magnitudes CBC cannot take (it aborts past 1e25), and terms it cannot tell from 0.
        for big in [1e20, 1e308, f64::INFINITY] {
            let e = Weights::once(big, 1.0).check().unwrap_err().to_string();
            assert!(e.contains("placement.calibration.lidar") && e.contains("1e6"), "{e}");
        }
        let e = Weights::once(1.0, 1e-12).check().unwrap_err().to_string();
        assert!(e.contains("placement.calibration.radar") && e.contains("1e-9"), "{e}");
        Weights::once(MAX_WEIGHT, MAX_WEIGHT * MIN_WEIGHT_RATIO).check().unwrap();
    }

    /// The names a study file uses, the values and the terms line up: each field set alone
    /// is the one non-zero entry of `values` and `named` at the same place, `from_array`
    /// inverts `values`, and the weights read back from their names.
    #[test]
    fn names_values_and_terms_line_up() {
        for k in 0..N_TERMS {
            let mut v = [0.0; N_TERMS];
            v[k] = 0.5 + k as f64;
            let w = Weights::from_array(v);
            assert_eq!(w.values(), v);
            assert_eq!(w.terms().iter().map(|t| t.weight).collect::<Vec<_>>(), v.to_vec());
            let (name, value) = w.named()[k];
            assert_eq!(value, v[k]);
            let text = serde_json::json!({ "lidar": 0.0, "radar": 0.0, name: value }).to_string();
            let back: Weights = serde_json::from_str(&text).unwrap();
            assert_eq!(back, w, "{name}");
        }
        let names: std::collections::HashSet<&str> = Weights::default().named().iter().map(|(n, _)| *n).collect();
        assert_eq!(names.len(), N_TERMS);
    }
}
