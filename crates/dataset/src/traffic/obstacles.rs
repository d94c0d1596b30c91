//! The geometric obstacle search (a road user's rectangle swept along its path) and the checks
//! built on it: gap acceptance for permissive lefts, a blocked junction, a busy crosswalk, and
//! whether vehicles would reach a pedestrian's crossing.

use super::*;

impl Traffic {
    /// The first arc-length distance from `s` at which `me`, moved along `path` with `margin`
    /// metres to spare on each side, touches `r` (samples `lo_k..=hi_k`, refined by bisection).
    pub(super) fn first_contact(
        path: &Path,
        me: &Rect,
        margin: f32,
        s: f32,
        r: &Rect,
        lo_k: usize,
        hi_k: usize,
    ) -> Option<f32> {
        let touches = |x: f32| footprint(path, x, me.half_l, me.half_w + margin).overlaps(r);
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
            // A pedestrian still on the sidewalk is passed as close as the bodies allow: a
            // turning vehicle's corner may sweep near the curb where someone waits (who, in
            // turn, waits for the vehicle; see `vehicles_threaten`).
            let on_sidewalk = !is_ped && matches!(&o.role, Role::Pedestrian { started: false, .. });
            let margin = if on_sidewalk { 0.0 } else { MARGIN_M };
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
            if let Some(gap) = Self::first_contact(path, &me, margin, a.s, &r, lo_k, hi_k) {
                // The real footprint bounds how far the road user may move this step.
                let real = if anticipated {
                    Self::first_contact(path, &me, margin, a.s, &rects[j], k0, k1).unwrap_or(f32::INFINITY)
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

    /// At a roundabout, whether driver `me` on `route` at its yield line finds the lag it needs
    /// in the circulating traffic at its merge point: the larger of `critical_gap_s` and the time
    /// its own body takes to get onto the ring plus a second. No circulating vehicle may reach
    /// the merge point sooner (accelerating from its speed up to the ring's curvature caps), and
    /// one at it holds the entry until its rear is past. Vehicles not yet on the ring yield
    /// themselves and are not waited for.
    pub(super) fn ring_gap_ok(&self, me: &Agent, route: usize, critical_gap_s: f32) -> bool {
        // The lag a driver needs: its critical gap, and at least the time its whole body takes
        // to get onto the ring from where it is (a bus's is the longer), with a second to spare.
        let r = &self.routes[route];
        let front = me.s + 0.5 * me.length;
        let onto = r.merge_s.unwrap_or(front) - front + me.length + 2.0;
        let v_ring = r.v_cap_at(r.merge_s.unwrap_or(front)).min(me.v_desired).max(me.v);
        let need = critical_gap_s.max(time_capped(me.v, class_model(me.class).a, v_ring, onto) + 1.0);
        self.agents.iter().all(|o| {
            let Role::Vehicle { route: rb, .. } = &o.role else { return true };
            let Some(at) = self.ring[route][*rb] else { return true };
            let front = o.s + 0.5 * o.length;
            let in_ring = self.routes[*rb].merge_s.is_some_and(|m| front > m);
            if !in_ring || o.s - 0.5 * o.length > at + 1.0 {
                return true;
            }
            // One at the merge point holds the entry until its rear is past.
            let d = at - 1.0 - front;
            if d <= 0.0 {
                return false;
            }
            // The time to reach it respects the ring's curvature speed caps.
            let v_max = self.routes[*rb].v_cap_over(front, d, o.v_desired).max(o.v);
            time_capped(o.v, class_model(o.class).a, v_max, d) >= need
        })
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

    /// Where the vehicle's front waits (an arc length on its route) for the first crosswalk
    /// ahead with a pedestrian the driver must yield to ([`yields_to`]): one who is in the
    /// vehicle's path over the crosswalk, or would be while the vehicle crosses it. A pedestrian
    /// already past that path, walking away, holds nobody. The wait is as near the crosswalk as
    /// the body stays off it ([`clear_of`]): a right turner pulls into the junction and waits
    /// at the crosswalk it turns over, as field drivers do. None when no pedestrian holds the
    /// vehicle, or its body is already over the crosswalk.
    pub(super) fn crosswalk_wait(&self, me: &Agent, route: usize) -> Option<f32> {
        let r = &self.routes[route];
        let front = me.s + 0.5 * me.length;
        let m = class_model(me.class);
        let (half_l, half_w) = (0.5 * me.length, 0.5 * me.width + MARGIN_M);
        // The pedestrians a crosswalk's driver may yield to: started, on it, not jaywalking.
        let on = |arm: usize| {
            self.agents.iter().filter(move |o| {
                matches!(&o.role, Role::Pedestrian { arm: pa, started: true, far_s, jaywalk: false, .. }
                    if *pa == arm && o.s < *far_s)
            })
        };
        r.crosswalks.iter().filter(|c| c.s_in >= front).find_map(|c| {
            // Nobody on it: nothing to wait for (and no footprint search on every step).
            on(c.arm).next()?;
            let wait = clear_of(&r.path, half_l, half_w, c)?;
            if wait < front - 0.05 {
                return None;
            }
            // The speed the vehicle can reach on its way over the crosswalk.
            let v_max = r.v_cap_over(front, c.s_out + me.length - front, me.v_desired).max(1.0);
            let t_arrive = time_capped(me.v, m.a, v_max, wait - front);
            let t_leave = time_capped(me.v, m.a, v_max, c.s_out + me.length - front);
            let busy = on(c.arm).any(|o| match &o.role {
                Role::Pedestrian { path, .. } => {
                    let (p, u) = path.at(o.s);
                    // The vehicle's path over the crosswalk, along the pedestrian's way.
                    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                    let mut s = c.s_in;
                    while s <= c.s_out + 0.5 * DS {
                        let x = (r.path.at(s.min(c.s_out)).0 - p).dot(u);
                        (lo, hi) = (lo.min(x), hi.max(x));
                        s += DS;
                    }
                    let reach = 0.5 * me.width + PED_CLEARANCE_M + 0.5 * o.length;
                    yields_to(t_arrive, t_leave, lo - reach, hi + reach, o.v.max(o.v_desired))
                }
                Role::Vehicle { .. } => false,
            });
            busy.then_some(wait)
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

/// Room a driver leaves between the side of the vehicle and a pedestrian crossing its path.
const PED_CLEARANCE_M: f32 = 1.0;
/// The least post-encroachment time a driver accepts against a pedestrian: the time between one
/// leaving the conflict zone and the other entering it (below 1.5 s, the surrogate-safety
/// literature's serious conflict).
const PED_PET_S: f32 = 1.5;

/// Whether a driver who reaches the conflict zone in `t_arrive` s and leaves it in `t_leave` s
/// yields to a pedestrian at 0 walking at `v` (m/s, > 0) towards and through the zone, which
/// spans `[lo, hi]` along the pedestrian's way (vehicle, clearance and pedestrian included): yes
/// unless one of them is out of the zone at least [`PED_PET_S`] before the other enters it. A
/// pedestrian already beyond `hi` has passed.
pub(super) fn yields_to(t_arrive: f32, t_leave: f32, lo: f32, hi: f32, v: f32) -> bool {
    if hi < 0.0 {
        return false;
    }
    let v = v.max(0.3);
    let (t_in, t_out) = ((lo / v).max(0.0), hi / v);
    t_out + PED_PET_S > t_arrive && t_in < t_leave + PED_PET_S
}

/// The farthest position of a vehicle's front along `path` (at most the crosswalk's first
/// centre-line sample) at which its footprint, `half_l` by `half_w`, keeps off the crosswalk:
/// mid-turn, a body's outer corner reaches a crosswalk before its centre line does. None if
/// the body cannot keep off it within 8 m.
pub(super) fn clear_of(path: &Path, half_l: f32, half_w: f32, c: &Crossing) -> Option<f32> {
    (0..=32)
        .map(|k| c.s_in - 0.25 * k as f32)
        .find(|&front| !footprint(path, front - half_l, half_l, half_w).overlaps_convex(&c.polygon))
}

/// Time to cover `d` m from speed `v0` at acceleration `a` up to the speed `v_max` (then held).
pub(super) fn time_capped(v0: f32, a: f32, v_max: f32, d: f32) -> f32 {
    if d <= 0.0 {
        return 0.0;
    }
    if v0 >= v_max {
        return d / v0.max(0.1);
    }
    let d_acc = (v_max * v_max - v0 * v0) / (2.0 * a);
    if d <= d_acc { ((v0 * v0 + 2.0 * a * d).sqrt() - v0) / a } else { (v_max - v0) / a + (d - d_acc) / v_max }
}

#[cfg(test)]
mod tests {
    use super::{PED_PET_S, time_capped, yields_to};

    #[test]
    fn a_pedestrian_past_the_vehicle_s_path_holds_nobody() {
        // Zone 2..6 m ahead of the pedestrian, or already behind them.
        assert!(!yields_to(3.0, 6.0, -5.0, -0.1, 1.3));
        // Inside the zone now: hold a vehicle arriving before the pedestrian is out and the
        // time has passed, not one that arrives long after.
        assert!(yields_to(0.5, 2.0, -1.0, 1.0, 1.3));
        assert!(yields_to(1.0 / 1.3 + PED_PET_S - 0.01, 9.0, -1.0, 1.0, 1.3));
        assert!(!yields_to(1.0 / 1.3 + PED_PET_S + 0.01, 9.0, -1.0, 1.0, 1.3));
    }

    #[test]
    fn the_post_encroachment_time_decides_both_ways() {
        let v = 1.25;
        // The pedestrian leaves the zone [2.5, 5] at 4 s.
        let (lo, hi) = (2.5, 5.0);
        assert!(!yields_to(4.0 + PED_PET_S + 0.01, 9.0, lo, hi, v));
        assert!(yields_to(4.0 + PED_PET_S - 0.01, 9.0, lo, hi, v));
        // The pedestrian enters at 2 s: the vehicle must be out by 0.5 s.
        assert!(!yields_to(0.0, 2.0 - PED_PET_S - 0.01, lo, hi, v));
        assert!(yields_to(0.0, 2.0 - PED_PET_S + 0.01, lo, hi, v));
        // A pedestrian who stands still is taken as walking slowly, not as never arriving.
        assert!(yields_to(1.0, 3.0, 0.5, 1.5, 0.0));
    }

    #[test]
    fn capped_travel_times_match_closed_forms() {
        // From rest at 2 m/s² to 10 m/s: 25 m to reach it, then 10 m/s.
        assert!((time_capped(0.0, 2.0, 10.0, 16.0) - 4.0).abs() < 1e-6);
        assert!((time_capped(0.0, 2.0, 10.0, 45.0) - 7.0).abs() < 1e-6);
        assert!((time_capped(12.0, 2.0, 10.0, 24.0) - 2.0).abs() < 1e-6);
        assert_eq!(time_capped(3.0, 2.0, 10.0, -1.0), 0.0);
        // Continuous where the cap is reached.
        let (a, b) = (time_capped(1.0, 1.5, 6.0, 11.666_666), time_capped(1.0, 1.5, 6.0, 11.666_667));
        assert!((a - b).abs() < 1e-4, "{a} {b}");
    }
}
