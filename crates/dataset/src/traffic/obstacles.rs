//! The geometric obstacle search (a road user's rectangle swept along its path) and the checks
//! built on it: gap acceptance for permissive lefts, a blocked junction, a busy crosswalk, and
//! whether vehicles would reach a pedestrian's crossing.

use super::*;

impl Traffic {
    /// The first arc-length distance from `s` at which `me`, moved along `path`, touches `r`
    /// (samples `lo_k..=hi_k`, refined by bisection).
    pub(super) fn first_contact(path: &Path, me: &Rect, s: f32, r: &Rect, lo_k: usize, hi_k: usize) -> Option<f32> {
        let touches = |x: f32| footprint(path, x, me.half_l, me.half_w + MARGIN_M).overlaps(r);
        for k in lo_k..=hi_k {
            if touches(k as f32 * DS) {
                let (mut lo, mut hi) = (((k as f32 - 1.0) * DS).max(s), k as f32 * DS);
                if touches(lo) {
                    return Some(0.0);
                }
                for _ in 0..5 {
                    let mid = 0.5 * (lo + hi);
                    if touches(mid) { hi = mid } else { lo = mid }
                }
                return Some((lo - s).max(0.0));
            }
        }
        None
    }

    /// The obstacles on `i`'s path within `lookahead` metres.
    pub(super) fn sweep(&self, i: usize, rects: &[Rect], lookahead: f32) -> Vec<Hit> {
        let a = &self.agents[i];
        let path = self.path(a);
        let me = rects[i];
        let is_ped = a.class == Class::Pedestrian;
        // Pedestrians on the road also yield to vehicles in their way.
        let ped_on_road = matches!(&a.role, Role::Pedestrian { started: true, far_s, .. } if a.s < *far_s + 0.5);
        let n = path.points.len();
        let k0 = ((a.s / DS).ceil() as usize).min(n - 1);
        let k1 = (((a.s + lookahead) / DS).ceil() as usize).min(n - 1);
        let mut hits = Vec::new();
        for (j, o) in self.agents.iter().enumerate() {
            if j == i || (is_ped && !ped_on_road && o.class != Class::Pedestrian) {
                continue;
            }
            let mut r = rects[j];
            let mut anticipated = false;
            // A pedestrian on the road keeps out of the lane just ahead of a moving vehicle.
            if ped_on_road && o.class != Class::Pedestrian && o.v > 0.1 {
                let ext = 0.5 * (1.0 + 1.5 * o.v);
                r.center += r.dir * ext;
                r.half_l += ext;
                anticipated = true;
            }
            // Vehicles anticipate a crossing pedestrian: it occupies where it will walk in
            // the next few seconds, unless that area is already under the vehicle (then the
            // pedestrian waits for it; see `ped_on_road`).
            if !is_ped
                && let Role::Pedestrian { started: true, far_s, .. } = &o.role
                && o.s < *far_s
            {
                let ext = 0.5 * o.v_desired * PED_ANTICIPATION_S;
                let mut long = r;
                long.center += r.dir * ext;
                long.half_l += ext;
                let now = Rect { half_w: me.half_w + MARGIN_M, ..me };
                if !now.overlaps(&long) {
                    r = long;
                    anticipated = true;
                }
            }
            let reach = me.radius() + r.radius() + MARGIN_M;
            if (r.center - me.center).length() > lookahead + reach + 1.0 {
                continue;
            }
            // Coarse: the path sample nearest to the other's centre.
            let (mut best, mut kb) = (f32::INFINITY, k0);
            let mut k = k0;
            while k <= k1 {
                let d = (path.points[k] - r.center).length_squared();
                if d < best {
                    best = d;
                    kb = k;
                }
                k += 4;
            }
            if best.sqrt() > reach + 4.0 * DS {
                continue;
            }
            let w = ((reach / DS).ceil() as usize) + 4 + if anticipated { (r.half_l / DS) as usize } else { 0 };
            let (lo_k, hi_k) = (kb.saturating_sub(w).max(k0), (kb + w).min(k1));
            if let Some(gap) = Self::first_contact(path, &me, a.s, &r, lo_k, hi_k) {
                // The real footprint bounds how far the road user may move this step.
                let real = if anticipated {
                    Self::first_contact(path, &me, a.s, &rects[j], k0, k1).unwrap_or(f32::INFINITY)
                } else {
                    gap
                };
                let along = o.v * rects[j].dir.dot(path.at(a.s + gap).1);
                hits.push(Hit { gap, v_along: along, other: j, real_gap: real });
            }
        }
        hits
    }

    /// Whether a pedestrian stepping onto `a`–`b` now could be reached by a vehicle within
    /// `horizon_s` seconds.
    pub(super) fn vehicles_threaten(&self, a: Vec2, b: Vec2, horizon_s: f32) -> bool {
        self.agents.iter().any(|o| {
            let Role::Vehicle { route, .. } = &o.role else { return false };
            let path = &self.routes[*route].path;
            let (from, to) = (o.s - 0.5 * o.length, o.s + 0.5 * o.length + o.v * horizon_s + 0.3);
            let mut s = from;
            while s <= to {
                let (p, _) = path.at(s);
                if point_segment_distance(p, a, b) < 0.5 * o.width + 0.8 {
                    return true;
                }
                s += 0.5;
            }
            false
        })
    }

    /// Time for a vehicle to reach arc length `target` from rest-aware kinematics.
    pub(super) fn time_to(o: &Agent, d: f32) -> f32 {
        if d <= 0.0 {
            return 0.0;
        }
        let acc = class_model(o.class).a;
        ((o.v * o.v + 2.0 * acc * d).sqrt() - o.v) / acc
    }

    /// Whether a vehicle inside the junction still occupies part of `route`'s path through it.
    pub(super) fn junction_blocked(&self, me: usize, route: usize) -> bool {
        self.agents.iter().enumerate().any(|(j, o)| {
            let Role::Vehicle { route: rb, .. } = &o.role else { return false };
            if j == me {
                return false;
            }
            let Some(exit) = self.conflicts[route][*rb] else { return false };
            o.s + 0.5 * o.length > self.routes[*rb].stop_s && o.s - 0.5 * o.length < exit
        })
    }

    /// Whether a pedestrian on one of the crosswalks `route` crosses (ahead of the vehicle) is
    /// close enough to its crossing to reach it before the vehicle has passed.
    pub(super) fn crosswalk_busy(&self, me: &Agent, route: usize) -> bool {
        let r = &self.routes[route];
        let front = me.s + 0.5 * me.length;
        r.crosswalks.iter().any(|&(arm, s_in, s_out)| {
            if front > s_in {
                return false;
            }
            let t_clear = (s_out - s_in + me.length + (s_in - front)) / me.v.max(2.0);
            let reach = 1.5 + 1.5 * t_clear;
            self.agents.iter().any(|o| match &o.role {
                Role::Pedestrian { arm: pa, started: true, far_s, jaywalk: false, .. }
                    if *pa == arm && o.s < *far_s =>
                {
                    let c = self.rect(o).center;
                    let mut s = s_in;
                    while s <= s_out {
                        if r.path.at(s).0.distance(c) < reach + 0.5 * me.width {
                            return true;
                        }
                        s += 1.0;
                    }
                    false
                }
                _ => false,
            })
        })
    }

    /// Whether a permissive left turn from `route` can go now.
    pub(super) fn left_gap_ok(&self, route: usize, critical_gap_s: f32) -> bool {
        let r = &self.routes[route];
        let opposing = self.plan.opposing(r.approach);
        for o in &self.agents {
            match &o.role {
                Role::Vehicle { route: orr, .. } => {
                    let or = &self.routes[*orr];
                    if !opposing.contains(&or.approach) || or.movement == Movement::Left {
                        continue;
                    }
                    let front = o.s + 0.5 * o.length;
                    if front < or.stop_s {
                        if Self::time_to(o, or.stop_s - front) < critical_gap_s {
                            return false;
                        }
                    } else if o.s - 0.5 * o.length < or.clear_s {
                        return false;
                    }
                }
                Role::Pedestrian { arm, started, far_s, .. } => {
                    // Pedestrians on the exit crosswalk would hold the turner inside the junction.
                    if *arm == r.exit && *started && o.s < *far_s + 0.5 {
                        return false;
                    }
                }
            }
        }
        true
    }
}
