//! One time step: obstacles for every road user, each one's decision (signal, yielding, the
//! Intelligent Driver Model's acceleration), integration, the no-overlap guarantee, departures
//! and arrivals.

use super::*;

/// What a road user decided this step, applied when everyone has decided.
#[derive(Clone, Copy, Debug, Default)]
struct Decision {
    accel: f32,
    /// A permissive left turn found its gap and commits to it.
    commit: bool,
    /// At yellow: stop (Some(true)) or go (Some(false)); None when not at yellow.
    yellow: Option<bool>,
    /// A pedestrian steps off the curb.
    start: bool,
}

impl Traffic {
    /// Advances one step.
    pub fn step(&mut self) {
        let dt = self.cfg.step_s as f32;
        let st = self.signal_t();
        let mut hits = self.obstacles();
        let decisions: Vec<Decision> = (0..self.agents.len()).map(|i| self.decide(i, &hits[i], st)).collect();
        for h in &mut hits {
            h.retain(|h| h.gap.is_finite());
        }
        let (old_s, old_v) = self.integrate(&decisions, &hits, dt);
        self.separate(&old_s, &old_v, dt);
        // Leave at the end of the path.
        let routes = &self.routes;
        self.agents.retain(|a| {
            let len = match &a.role {
                Role::Vehicle { route, .. } => routes[*route].path.length(),
                Role::Pedestrian { path, .. } => path.length(),
            };
            a.s + 0.5 * a.length < len
        });
        self.steps += 1;
        self.t = self.steps as f64 * self.cfg.step_s - self.warm_s;
        self.spawn();
        let now = self.signal_t();
        if let Some(p) = &mut self.parking {
            p.advance(now);
        }
    }

    /// Every road user's obstacles ahead, with crossing conflicts settled: whoever can no longer
    /// stop comfortably goes first, otherwise the one nearer to the conflict (the other's gap to
    /// the first becomes infinite: it does not wait for a road user that waits for it).
    fn obstacles(&self) -> Vec<Vec<Hit>> {
        let rects: Vec<Rect> = self.agents.iter().map(|a| self.rect(a)).collect();
        let mut hits: Vec<Vec<Hit>> = (0..self.agents.len())
            .map(|i| {
                let a = &self.agents[i];
                let look = match &a.role {
                    Role::Pedestrian { .. } => 3.0,
                    Role::Vehicle { route, .. } => {
                        let r = &self.routes[*route];
                        let base = 12.0 + 5.0 * a.v;
                        // Near the stop line, look through the junction (do not block the box).
                        let to_clear = r.clear_s + 0.5 * a.length + 2.0 - a.s;
                        if r.stop_s - (a.s + 0.5 * a.length) < 40.0 { base.max(to_clear) } else { base }
                    }
                };
                self.sweep(i, &rects, look.min(120.0))
            })
            .collect();
        let must_go = |k: usize, gap: f32| {
            let a = &self.agents[k];
            a.v * a.v / (2.0 * class_model(a.class).b) > gap
        };
        let original = hits.clone();
        for (i, mine) in hits.iter_mut().enumerate() {
            for hit in mine.iter_mut() {
                let (gi, j) = (hit.gap, hit.other);
                if let Some((gj, real_j)) = original[j].iter().find(|x| x.other == i).map(|x| (x.gap, x.real_gap)) {
                    let (mi, mj) = (must_go(i, gi), must_go(j, gj));
                    let mut i_first =
                        if mi != mj { mi } else { gi < gj || (gi == gj && self.agents[i].id < self.agents[j].id) };
                    // Merging into a roundabout's ring two bodies can stand side by side: the one
                    // that cannot move without touching the other does not go first.
                    if self.on_ring(i) && self.on_ring(j) {
                        let (stuck_i, stuck_j) = (hit.real_gap < 0.05, real_j < 0.05);
                        if stuck_i != stuck_j {
                            i_first = stuck_j;
                        }
                    }
                    if i_first {
                        hit.gap = f32::INFINITY;
                    }
                }
            }
        }
        hits
    }

    /// Whether road user `i` is a vehicle on a roundabout's route.
    fn on_ring(&self, i: usize) -> bool {
        matches!(&self.agents[i].role, Role::Vehicle { route, .. } if self.routes[*route].merge_s.is_some())
    }

    /// Road user `i`'s decision given its obstacles: a virtual obstacle at the stop line or the
    /// curb where it must wait, then the Intelligent Driver Model towards the nearest obstacle.
    fn decide(&self, i: usize, hits: &[Hit], st: f64) -> Decision {
        let a = &self.agents[i];
        let m = class_model(a.class);
        // The nearest obstacle that `keep` admits: its gap and its speed along the path.
        let nearest = |keep: &dyn Fn(&Hit) -> bool| {
            hits.iter()
                .filter(|h| h.gap.is_finite() && keep(h))
                .map(|h| (h.gap, h.v_along))
                .min_by(|x, y| x.0.total_cmp(&y.0))
                .unwrap_or((f32::INFINITY, 0.0))
        };
        let (mut gap, mut v_obst) = nearest(&|_| true);
        let mut d = Decision::default();
        let mut v0 = a.v_desired;
        // Wait `g` metres ahead (stop line, curb) if that is nearer than the obstacle.
        let wait_at = |g: f32, gap: &mut f32, v_obst: &mut f32| {
            if g < *gap {
                *gap = g.max(0.0);
                *v_obst = 0.0;
            }
        };
        match &a.role {
            Role::Vehicle { route, yellow_stop, .. } => {
                let r = &self.routes[*route];
                v0 = v0.min(r.v_cap_at(a.s + 0.5 * a.length + 3.0));
                d.yellow = *yellow_stop;
                let front = a.s + 0.5 * a.length;
                // Before the line, the vehicle ahead decides whether there is room beyond the
                // junction (pedestrians are yielded to at their crosswalks, below).
                let at_line = front <= r.stop_s + 0.05 && {
                    let (ahead, v_ahead) = nearest(&|h| self.agents[h.other].class != Class::Pedestrian);
                    self.holds_at_line(i, ahead, v_ahead, st, &mut d)
                };
                // At a roundabout the entry's crosswalk comes before the yield line.
                let walk_first = r.crosswalks.first().is_some_and(|c| c.s_in < r.stop_s);
                // And crosswalks are kept clear: no driver there moves onto one without room
                // beyond it behind the road user ahead, or a queue's last car would stand on it
                // and hold its pedestrians (who may be holding the queue's first).
                if r.merge_s.is_some()
                    && gap.is_finite()
                    && v_obst < 2.0
                    && let Some(c) = r.crosswalks.iter().find(|c| c.s_in >= front - 0.05)
                    && front + gap - m.s0 - a.length < c.s_out + 0.5
                    && c.s_in - front >= a.v * a.v / (2.0 * m.b) - 0.5
                {
                    wait_at(c.s_in - front - 0.5 + m.s0, &mut gap, &mut v_obst);
                }
                if at_line {
                    wait_at(r.stop_s - front - STOP_LINE_GAP_M + m.s0, &mut gap, &mut v_obst);
                }
                if (!at_line || walk_first)
                    && d.yellow != Some(false)
                    && let Some(edge) = self.crosswalk_wait(a, *route)
                    && edge - front >= a.v * a.v / (2.0 * m.b) - 0.5
                {
                    // Yield to pedestrians at the crosswalk's edge (while the driver can still
                    // stop comfortably; a vehicle that went on yellow only clears the junction).
                    wait_at(edge - front - STOP_LINE_GAP_M + m.s0, &mut gap, &mut v_obst);
                }
            }
            Role::Pedestrian { path, curb_s, far_s, arm, jaywalk, started } => {
                if !*started && a.s + 0.5 * a.length >= *curb_s - 0.6 {
                    let (p_a, _) = path.at(*curb_s);
                    let (p_b, _) = path.at(*far_s);
                    let cross_time = (*far_s - *curb_s) / a.v_desired.max(0.5);
                    let may = *jaywalk || self.plan.walk(*arm, st).is_some_and(|rem| rem as f32 >= cross_time + 2.0);
                    let horizon = if *jaywalk { cross_time + 2.0 } else { 4.0 };
                    if may && !self.vehicles_threaten(p_a, p_b, horizon) {
                        d.start = true;
                    } else {
                        wait_at(*curb_s - (a.s + 0.5 * a.length) + m.s0, &mut gap, &mut v_obst);
                    }
                }
            }
        }
        // The Intelligent Driver Model.
        let free = 1.0 - (a.v / v0.max(0.1)).powi(4);
        let inter = if gap.is_finite() {
            let s_star = m.s0 + (a.v * m.headway_s + a.v * (a.v - v_obst) / (2.0 * (m.a * m.b).sqrt())).max(0.0);
            (s_star / gap.max(0.01)).powi(2)
        } else {
            0.0
        };
        d.accel = (m.a * (free - inter)).clamp(-m.b_max, m.a);
        d
    }

    /// Whether vehicle `i`, before its stop line, must hold there: on red; on yellow when it can
    /// stop comfortably or would not reach the line before red; on a permissive green without
    /// an acceptable gap in opposing traffic; for vehicles still in the junction on a crossing
    /// path (while it can still stop); or without room beyond the junction behind the vehicle
    /// `gap` ahead. Pedestrians are waited for at their crosswalk's edge instead
    /// ([`Traffic::crosswalk_wait`]). Records the yellow and gap decisions in `d`.
    fn holds_at_line(&self, i: usize, gap: f32, v_obst: f32, st: f64, d: &mut Decision) -> bool {
        let a = &self.agents[i];
        let m = class_model(a.class);
        let Role::Vehicle { route, yellow_stop, committed, critical_gap_s } = &a.role else { return false };
        let r = &self.routes[*route];
        let front = a.s + 0.5 * a.length;
        let mut hold = match self.plan.light(r.approach, r.movement, st) {
            Light::Red => true,
            Light::Yellow => {
                let stop = yellow_stop.unwrap_or_else(|| {
                    // Go only if stopping would be uncomfortable and the line is reached
                    // before red (slowing for a turn counts).
                    let dist = r.stop_s - front;
                    let v_line = a.v.min(r.v_cap_at(r.stop_s));
                    let arrive = dist / (0.5 * (a.v + v_line)).max(0.1);
                    let left = self.plan.yellow_left(r.approach, r.movement, st).unwrap_or(0.0) as f32;
                    dist >= a.v * a.v / (2.0 * m.b) + 0.5 || arrive > left - 0.2
                });
                d.yellow = Some(stop);
                stop
            }
            Light::Green { protected } => {
                d.yellow = None;
                let gap_ok = |route: usize| match r.merge_s {
                    Some(_) => self.ring_gap_ok(a, route, *critical_gap_s),
                    None => self.left_gap_ok(route, *critical_gap_s),
                };
                if protected || *committed {
                    false
                } else if gap_ok(*route) {
                    d.commit = r.stop_s - front < 3.0;
                    false
                } else {
                    true
                }
            }
        };
        // A vehicle that chose to go on yellow is not held by anything but red.
        let can_stop = r.stop_s - front >= a.v * a.v / (2.0 * m.b) - 0.5 && d.yellow != Some(false);
        // At a roundabout the ring's gap is the rule; everyone shares the ring's path.
        hold = hold || (can_stop && r.merge_s.is_none() && self.junction_blocked(i, *route));
        // Do not enter the junction without room to leave it behind the vehicle ahead (at a
        // roundabout the ring's gap is the rule: what crosses the entry's path is circulating).
        hold || (r.merge_s.is_none()
            && gap.is_finite()
            && a.s + gap < r.clear_s + 0.5 * a.length + 1.0
            && a.s + gap > r.stop_s - 0.5 * a.length
            && v_obst < 2.0)
    }

    /// Moves everyone by their decision, never farther than the real gap to an obstacle (an
    /// emergency stop, counted in `clamps`). Returns the positions and speeds before the move.
    fn integrate(&mut self, decisions: &[Decision], hits: &[Vec<Hit>], dt: f32) -> (Vec<f32>, Vec<f32>) {
        let old_s: Vec<f32> = self.agents.iter().map(|a| a.s).collect();
        let old_v: Vec<f32> = self.agents.iter().map(|a| a.v).collect();
        for (i, d) in decisions.iter().enumerate() {
            let acc = d.accel;
            let a = &mut self.agents[i];
            let v_new = (a.v + acc * dt).max(0.0);
            let travel = if v_new == 0.0 && acc < 0.0 {
                (a.v * a.v / (2.0 * -acc)).min(a.v * dt)
            } else {
                0.5 * (a.v + v_new) * dt
            };
            let limit = hits[i].iter().map(|h| h.real_gap).fold(f32::INFINITY, f32::min);
            let (travel, v_new) = if travel > limit {
                self.clamps += 1;
                (limit.max(0.0), (a.v - class_model(a.class).b_max * dt).max(0.0).min(v_new))
            } else {
                (travel, v_new)
            };
            a.s += travel;
            a.a = (v_new - a.v) / dt;
            a.v = v_new;
            match &mut a.role {
                Role::Vehicle { yellow_stop, committed, .. } => {
                    *yellow_stop = d.yellow;
                    *committed |= d.commit;
                }
                Role::Pedestrian { started, .. } => *started |= d.start,
            }
        }
        (old_s, old_v)
    }

    /// The guarantee that nobody ends a step overlapping another road user: whoever moved into
    /// an overlap goes back to where it was (an emergency stop), until none is left; the state
    /// before the step had no overlap, so this ends.
    fn separate(&mut self, old_s: &[f32], old_v: &[f32], dt: f32) {
        let n = self.agents.len();
        let moved: Vec<bool> = (0..n).map(|i| self.agents[i].s != old_s[i]).collect();
        let mut reverted = vec![false; n];
        loop {
            let rects: Vec<Rect> = self.agents.iter().map(|a| self.rect(a)).collect();
            let mut changed = false;
            for i in 0..n {
                if !moved[i] || reverted[i] {
                    continue;
                }
                let hit = (0..n).any(|j| {
                    j != i
                        && rects[i].center.distance(rects[j].center) < rects[i].radius() + rects[j].radius()
                        && rects[i].overlaps(&rects[j])
                });
                if hit {
                    let a = &mut self.agents[i];
                    a.s = old_s[i];
                    a.v = (old_v[i] - class_model(a.class).b_max * dt).max(0.0);
                    a.a = (a.v - old_v[i]) / dt;
                    reverted[i] = true;
                    self.clamps += 1;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
    }
}
