//! Count vectors with several radars and at most two LiDARs of one type: the LiDAR set first.

use super::{Stop, counts_upper_bound, past, separable_upper_bound, top_visibilities};
use crate::candidates::Modality;
use crate::error::PlacementError;
use crate::instance::{Instance, Outcome, Scratch, coverage_coef, evaluate_with};
use rayon::prelude::*;
use std::time::Instant;

/// Exact search for a count vector with one LiDAR type (at most two LiDARs) and several radars:
/// the LiDAR set is fixed first, which fixes the LiDAR-covered targets C_L; every radar r is then
/// worth at most h(r) = Σ_{j ∈ C_L} w_j V_rj, a tight, consistent bound, and the radar part of
/// the set at most the best `n_r` of h, one per mount. A depth-first search over radars in h
/// order finds the best completion of each set whose bound beats the incumbent, best bound first.
///
/// What makes it fast is computing h for every LiDAR pair cheaply: with each single LiDAR's
/// values H(l) = Σ_{j ∈ C_l} w_j V_·j computed once, a pair's covered set is C_a ∪ C_b plus the
/// targets J only the two together cover, so h = H(a) + Σ_{C_b \ C_a} + Σ_J, or H(b) + Σ_{C_a \
/// C_b} + Σ_J, or H(a) + H(b) − Σ_{C_a ∩ C_b} + Σ_J: whichever touches the fewest targets, each
/// target adding one row of a dense target × radar table (a vectorised loop over the radars).
/// `node_budget` caps the radar search and `deadline` its time; when either runs out the result
/// is returned unproven, with the bound of the first LiDAR set not finished (sets are searched
/// in bound order, so it bounds the rest). Returns (outcome, proven).
pub fn exact_lidar_first(
    inst: &Instance,
    counts: &[u32],
    incumbent: &[usize],
    node_budget: u64,
    deadline: Option<Instant>,
) -> Result<(Outcome, bool), PlacementError> {
    let start = Instant::now();
    let tau = inst.tau() * (1.0 - 1e-9);
    let count = |t: usize| counts.get(t).copied().unwrap_or(0) as usize;
    let lidar_types: Vec<usize> =
        (0..inst.types.len()).filter(|&t| inst.types[t].modality == Modality::Lidar && count(t) > 0).collect();
    let n_r: usize = (0..inst.types.len()).filter(|&t| inst.types[t].modality == Modality::Radar).map(count).sum();
    if lidar_types.len() != 1 || count(lidar_types[0]) > 2 || n_r == 0 {
        return Err(PlacementError::instance(
            "the LiDAR-first search",
            "takes one LiDAR type (at most two) and some radars",
        ));
    }
    let (lt, n_l) = (lidar_types[0], count(lidar_types[0]));
    let lidars: Vec<usize> = (0..inst.options.len()).filter(|&o| inst.options[o].ty == lt).collect();
    let radars: Vec<usize> = (0..inst.options.len())
        .filter(|&o| inst.modality(o) == Modality::Radar && count(inst.options[o].ty) > 0)
        .collect();
    let n = inst.n_targets();
    let nr = radars.len();
    let rt = radar_top_sums(inst, &radars, n_r, n);
    let tables = RadarTables::new(inst, &lidars, &radars, &rt, tau);
    let (radar_mount, n_mounts) = dense_mounts(inst, &radars);
    // The radar part's bound of a LiDAR set: the best h per mount, top n_r of them.
    let radar_bound = |h: &[f64], lidar_mounts: &[u32], per_mount: &mut Vec<f64>| -> f64 {
        per_mount.clear();
        per_mount.resize(n_mounts, 0.0);
        for (k, &x) in h.iter().enumerate() {
            if !lidar_mounts.contains(&inst.options[radars[k]].mount) {
                let m = &mut per_mount[radar_mount[k]];
                *m = m.max(x);
            }
        }
        per_mount.sort_by(|a, b| b.total_cmp(a));
        per_mount.iter().take(n_r).sum()
    };
    let sets = lidar_sets(inst, &lidars, n_l);
    let best0 = crate::instance::evaluate(inst, incumbent);
    struct Cand {
        set: Vec<usize>,
        base: f64,
        ub: f64,
    }
    // Stopped before the sets are bounded: the incumbent, and the count vector's bound.
    let stopped = |what: &str| {
        let tops = top_visibilities(inst, counts.iter().copied().max().unwrap_or(0) as usize);
        let bound = counts_upper_bound(inst, counts, &tops).min(separable_upper_bound(inst, counts, &tops));
        Outcome::new(
            inst,
            sorted(incumbent),
            bound,
            false,
            start.elapsed().as_secs_f64(),
            &format!("exact LiDAR-first search ({what})"),
        )
    };
    if past(deadline) {
        return Ok((stopped("stopped before bounding"), false));
    }
    // Bounding every LiDAR set is most of the search's time at the default scale: past the
    // deadline the remaining sets are not bounded (`None`).
    let cands: Option<Vec<Cand>> = sets
        .into_par_iter()
        .map_init(
            || (SetScratch::new(n), vec![0.0; nr], Vec::new()),
            |(sc, h, per_mount), set| {
                if past(deadline) {
                    return None;
                }
                let opts: Vec<usize> = set.iter().map(|&i| lidars[i]).collect();
                let (base, ub0) = sc.cover(inst, &opts, &rt, tau);
                let mut ub = ub0;
                // The tight bound only where the cheap one does not already prune (and time is
                // left: the cheap one is a valid bound too).
                if ub0 > best0 + 1e-9 && !past(deadline) {
                    tables.values(&set, &sc.joint, h);
                    let mounts: Vec<u32> = opts.iter().map(|&o| inst.options[o].mount).collect();
                    ub = ub.min(base + radar_bound(h, &mounts, per_mount));
                }
                Some(Cand { set, base, ub })
            },
        )
        .collect();
    let Some(mut cands) = cands else {
        return Ok((stopped("stopped while bounding"), false));
    };
    cands.sort_by(|x, y| y.ub.total_cmp(&x.ub).then_with(|| x.set.cmp(&y.set)));
    let mut best_sel = incumbent.to_vec();
    let mut best = best0;
    let mut scratch = Scratch::new(n);
    let mut sc = SetScratch::new(n);
    let mut h = vec![0.0; nr];
    let mut stop = Stop { deadline, stopped: false, nodes: 0, budget: node_budget };
    let mut open = f64::NEG_INFINITY;
    for c in &cands {
        if c.ub <= best + 1e-9 {
            break;
        }
        if past(deadline) {
            stop.stopped = true;
        }
        if stop.stopped {
            open = c.ub;
            break;
        }
        let opts: Vec<usize> = c.set.iter().map(|&i| lidars[i]).collect();
        sc.cover(inst, &opts, &rt, tau);
        tables.values(&c.set, &sc.joint, &mut h);
        let lidar_mounts: Vec<u32> = opts.iter().map(|&o| inst.options[o].mount).collect();
        let mut order: Vec<(f64, usize)> = h
            .iter()
            .zip(&radars)
            .filter(|&(&x, &r)| x > 0.0 && !lidar_mounts.contains(&inst.options[r].mount))
            .map(|(&x, &r)| (x, r))
            .collect();
        order.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut chosen = opts.clone();
        let mut used: Vec<u32> = lidar_mounts;
        radar_dfs(
            inst,
            &order,
            0,
            n_r,
            c.base,
            &mut chosen,
            &mut used,
            &mut best,
            &mut best_sel,
            &mut scratch,
            &mut stop,
        );
        if stop.stopped {
            open = c.ub;
            break;
        }
    }
    best_sel.sort_unstable();
    let proven = open <= best + 1e-9;
    let bound = if proven { best } else { open };
    Ok((Outcome::new(inst, best_sel, bound, proven, start.elapsed().as_secs_f64(), "exact LiDAR-first search"), proven))
}

/// Per target, the sum of its best `n_r` radar visibilities (for the cheap bound).
fn radar_top_sums(inst: &Instance, radars: &[usize], n_r: usize, n: usize) -> Vec<f64> {
    let mut radar_top = vec![Vec::<f32>::new(); n];
    for &r in radars {
        for &(j, v) in &inst.options[r].row {
            let l = &mut radar_top[j as usize];
            l.push(v);
            if l.len() > n_r {
                l.sort_by(|a, b| b.total_cmp(a));
                l.truncate(n_r);
            }
        }
    }
    radar_top.iter().map(|l| l.iter().map(|&v| v as f64).sum()).collect()
}

/// Each radar option's mount as a dense index, and the number of mounts, for "one sensor per
/// mount" in the bound.
fn dense_mounts(inst: &Instance, radars: &[usize]) -> (Vec<usize>, usize) {
    let mut mount_ids: std::collections::BTreeMap<u32, usize> = std::collections::BTreeMap::new();
    for &r in radars {
        let k = mount_ids.len();
        mount_ids.entry(inst.options[r].mount).or_insert(k);
    }
    (radars.iter().map(|&r| mount_ids[&inst.options[r].mount]).collect(), mount_ids.len())
}

/// LiDAR sets as indices into `lidars`: singles, and with two LiDARs pairs on different mounts
/// (with one sensor per mount, fewer LiDARs than the count can be optimal).
fn lidar_sets(inst: &Instance, lidars: &[usize], n_l: usize) -> Vec<Vec<usize>> {
    let mut sets: Vec<Vec<usize>> = (0..lidars.len()).map(|a| vec![a]).collect();
    if n_l == 2 {
        for a in 0..lidars.len() {
            for b in a + 1..lidars.len() {
                if inst.options[lidars[a]].mount != inst.options[lidars[b]].mount {
                    sets.push(vec![a, b]);
                }
            }
        }
    }
    sets
}

fn sorted(selection: &[usize]) -> Vec<usize> {
    let mut s = selection.to_vec();
    s.sort_unstable();
    s
}

/// Buffers for the targets a LiDAR set covers.
struct SetScratch {
    a: Vec<f64>,
    rho: Vec<f64>,
    touched: Vec<u32>,
    single: Vec<bool>,
    /// Covered targets that no single LiDAR of the set covers alone (J).
    joint: Vec<u32>,
}

impl SetScratch {
    fn new(n: usize) -> Self {
        SetScratch {
            a: vec![0.0; n],
            rho: vec![0.0; n],
            touched: Vec::new(),
            single: vec![false; n],
            joint: Vec::new(),
        }
    }

    /// (base, cheap bound) of a LiDAR set: base = Σ_{j ∈ C_L} w_j ρ_L(j) over the covered targets
    /// some radar sees; the bound adds each target's best possible radar sum. Fills `joint`.
    fn cover(&mut self, inst: &Instance, set: &[usize], rt: &[f64], tau: f64) -> (f64, f64) {
        for &o in set {
            for &(j, v) in &inst.options[o].row {
                let ju = j as usize;
                if self.a[ju] == 0.0 && self.rho[ju] == 0.0 {
                    self.touched.push(j);
                }
                let c = coverage_coef(v as f64);
                self.a[ju] += c;
                self.rho[ju] += v as f64;
                self.single[ju] |= c >= tau;
            }
        }
        self.joint.clear();
        let (mut base, mut ub0) = (0.0, 0.0);
        for &j in &self.touched {
            let ju = j as usize;
            if self.a[ju] >= tau && rt[ju] > 0.0 {
                base += inst.weights[ju] * self.rho[ju];
                ub0 += inst.weights[ju] * (self.rho[ju] + rt[ju]);
                if !self.single[ju] {
                    self.joint.push(j);
                }
            }
            self.a[ju] = 0.0;
            self.rho[ju] = 0.0;
            self.single[ju] = false;
        }
        self.touched.clear();
        (base, ub0)
    }
}

/// Radar values of LiDAR sets: a dense target-major table `w_j V_rj` over the radars, and each
/// single LiDAR's covered targets and values.
struct RadarTables {
    nr: usize,
    table: Vec<f64>,
    /// Per LiDAR (index into the LiDAR list): covered targets that some radar sees, sorted.
    covered: Vec<Vec<u32>>,
    covers: Vec<Vec<bool>>,
    /// Per LiDAR: H(l) = Σ_{j ∈ C_l} w_j V_rj for every radar.
    single: Vec<Vec<f64>>,
}

impl RadarTables {
    fn new(inst: &Instance, lidars: &[usize], radars: &[usize], rt: &[f64], tau: f64) -> Self {
        let (n, nr) = (inst.n_targets(), radars.len());
        let mut table = vec![0.0; n * nr];
        for (k, &r) in radars.iter().enumerate() {
            for &(j, v) in &inst.options[r].row {
                table[j as usize * nr + k] = inst.weights[j as usize] * v as f64;
            }
        }
        let covered: Vec<Vec<u32>> = lidars
            .iter()
            .map(|&l| {
                inst.options[l]
                    .row
                    .iter()
                    .filter(|&&(j, v)| coverage_coef(v as f64) >= tau && rt[j as usize] > 0.0)
                    .map(|&(j, _)| j)
                    .collect()
            })
            .collect();
        let covers: Vec<Vec<bool>> = covered
            .iter()
            .map(|c| {
                let mut b = vec![false; n];
                for &j in c {
                    b[j as usize] = true;
                }
                b
            })
            .collect();
        let mut t = RadarTables { nr, table, covered, covers, single: Vec::new() };
        t.single = t
            .covered
            .par_iter()
            .map(|c| {
                let mut h = vec![0.0; nr];
                t.add(&mut h, c.iter().copied());
                h
            })
            .collect();
        t
    }

    fn add(&self, acc: &mut [f64], targets: impl Iterator<Item = u32>) {
        for j in targets {
            let row = &self.table[j as usize * self.nr..][..self.nr];
            for (a, x) in acc.iter_mut().zip(row) {
                *a += x;
            }
        }
    }

    fn sub(&self, acc: &mut [f64], targets: impl Iterator<Item = u32>) {
        for j in targets {
            let row = &self.table[j as usize * self.nr..][..self.nr];
            for (a, x) in acc.iter_mut().zip(row) {
                *a -= x;
            }
        }
    }

    /// h(r) for every radar, for a set of one or two LiDARs whose jointly covered targets (covered
    /// by neither alone) are `joint`.
    fn values(&self, set: &[usize], joint: &[u32], h: &mut [f64]) {
        match *set {
            [a] => h.copy_from_slice(&self.single[a]),
            [a, b] => {
                let (ca, cb) = (&self.covered[a], &self.covered[b]);
                let (ia, ib) = (&self.covers[a], &self.covers[b]);
                let both = ca.iter().filter(|&&j| ib[j as usize]).count();
                let (only_a, only_b) = (ca.len() - both, cb.len() - both);
                if both <= only_a.min(only_b) {
                    for ((x, ha), hb) in h.iter_mut().zip(&self.single[a]).zip(&self.single[b]) {
                        *x = ha + hb;
                    }
                    self.sub(h, ca.iter().copied().filter(|&j| ib[j as usize]));
                } else if only_b <= only_a {
                    h.copy_from_slice(&self.single[a]);
                    self.add(h, cb.iter().copied().filter(|&j| !ia[j as usize]));
                } else {
                    h.copy_from_slice(&self.single[b]);
                    self.add(h, ca.iter().copied().filter(|&j| !ib[j as usize]));
                }
            }
            _ => h.fill(0.0),
        }
        self.add(h, joint.iter().copied());
    }
}

#[allow(clippy::too_many_arguments)]
fn radar_dfs(
    inst: &Instance,
    h: &[(f64, usize)],
    start: usize,
    slots: usize,
    partial: f64,
    chosen: &mut Vec<usize>,
    used: &mut Vec<u32>,
    best: &mut f64,
    best_sel: &mut Vec<usize>,
    scratch: &mut Scratch,
    stop: &mut Stop,
) {
    if stop.stopped || stop.tick() {
        return;
    }
    if slots == 0 || start >= h.len() {
        let f = evaluate_with(inst, chosen, scratch);
        if f > *best + 1e-12 {
            *best = f;
            *best_sel = chosen.clone();
        }
        return;
    }
    let mut descended = false;
    let mut cut = false;
    for p in start..h.len() {
        let bound: f64 = partial + h[p..].iter().take(slots).map(|x| x.0).sum::<f64>();
        if bound <= *best + 1e-9 {
            cut = true;
            break;
        }
        let (v, r) = h[p];
        let m = inst.options[r].mount;
        if used.contains(&m) {
            continue;
        }
        descended = true;
        chosen.push(r);
        used.push(m);
        radar_dfs(inst, h, p + 1, slots - 1, partial + v, chosen, used, best, best_sel, scratch, stop);
        chosen.pop();
        used.pop();
        if stop.stopped {
            return;
        }
    }
    // Every remaining radar sits on a used mount: evaluate what is chosen ("at most").
    if !descended && !cut {
        let f = evaluate_with(inst, chosen, scratch);
        if f > *best + 1e-12 {
            *best = f;
            *best_sel = chosen.clone();
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::candidates::Modality;
    use crate::instance::{SensorOption, SensorType, coverage_coef};
    use rand::{Rng, SeedableRng};

    /// Every pair's radar values, by whichever of the three formulas the sizes pick, equal the
    /// direct sum over the pair's covered targets (overlapping, nested and disjoint pairs).
    #[test]
    fn pair_values_equal_the_direct_sum() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n = 60;
        let types = vec![
            SensorType { name: "l".into(), modality: Modality::Lidar, price_usd: 1.0 },
            SensorType { name: "r".into(), modality: Modality::Radar, price_usd: 1.0 },
        ];
        let mut options = Vec::new();
        for (ty, k) in [(0usize, 12), (1, 6)] {
            for i in 0..k {
                // LiDARs see windows of different widths (nested, overlapping, disjoint).
                let (lo, hi) = if ty == 0 { (rng.random_range(0..40), rng.random_range(45..n)) } else { (0, n) };
                let mut row = Vec::new();
                for j in lo..hi {
                    if rng.random_bool(0.8) {
                        row.push((j as u32, rng.random_range(0.05f32..1.0)));
                    }
                }
                options.push(SensorOption {
                    ty,
                    candidate: options.len() as u32,
                    mount: i as u32 + 100 * ty as u32,
                    row,
                });
            }
        }
        let inst = Instance {
            weights: (0..n).map(|j| 1.0 + (j % 3) as f64).collect(),
            types,
            options,
            p_min: 0.5,
            road_users: Vec::new(),
            points: Default::default(),
            extents: Default::default(),
            floors: Vec::new(),
        };
        let tau = inst.tau() * (1.0 - 1e-9);
        let lidars: Vec<usize> = (0..12).collect();
        let radars: Vec<usize> = (12..18).collect();
        let rt = vec![1.0; n];
        let tables = RadarTables::new(&inst, &lidars, &radars, &rt, tau);
        let mut sc = SetScratch::new(n);
        let mut h = vec![0.0; radars.len()];
        for a in 0..12 {
            for b in a..12 {
                let set = if a == b { vec![a] } else { vec![a, b] };
                sc.cover(&inst, &set, &rt, tau);
                tables.values(&set, &sc.joint, &mut h);
                let mut cov = vec![0.0; n];
                for &o in &set {
                    for &(j, v) in &inst.options[o].row {
                        cov[j as usize] += coverage_coef(v as f64);
                    }
                }
                for (k, &r) in radars.iter().enumerate() {
                    let direct: f64 = inst.options[r]
                        .row
                        .iter()
                        .filter(|(j, _)| cov[*j as usize] >= tau)
                        .map(|&(j, v)| inst.weights[j as usize] * v as f64)
                        .sum();
                    assert!((h[k] - direct).abs() < 1e-9, "{set:?} radar {k}: {} vs {direct}", h[k]);
                }
            }
        }
    }
}
