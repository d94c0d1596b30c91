//! Arrivals: vehicles join their route's queue as Poisson processes per approach and movement,
//! pedestrians appear on the sidewalks by their crosswalks (and jaywalkers mid-block).

use super::*;

impl Traffic {
    pub(super) fn spawn(&mut self) {
        let now = self.signal_t();
        // Vehicle arrivals join the queue of their route.
        for ap in 0..self.approach_rate.len() {
            while self.next_arrival[ap] <= now {
                self.next_arrival[ap] = next_arrival(&mut self.rng, self.next_arrival[ap], self.approach_rate[ap]);
                let u: f64 = self.rng.random();
                let want = if u < self.cfg.left_share {
                    Movement::Left
                } else if u < self.cfg.left_share + self.cfg.right_share {
                    Movement::Right
                } else {
                    Movement::Through
                };
                let Some(movement) = spawned_movement(&self.routes, ap, want) else { continue };
                let cands: Vec<usize> = self
                    .routes
                    .iter()
                    .enumerate()
                    .filter(|(_, r)| r.approach == ap && r.movement == movement)
                    .map(|(k, _)| k)
                    .collect();
                let route = cands[self.rng.random_range(0..cands.len())];
                let class = self.draw_class();
                let m = class_model(class);
                let size =
                    (sample(&mut self.rng, m.length), sample(&mut self.rng, m.width), sample(&mut self.rng, m.height));
                let speed_limit = self.speed_limits[ap];
                let factor = Normal::new(1.0f32, 0.08).map(|d| d.sample(&mut self.rng)).unwrap_or(1.0).clamp(0.8, 1.15);
                let v_desired = (speed_limit * factor).min(m.v_max);
                let critical_gap_s = self.rng.random_range(4.0..6.0);
                self.pending[route].push(PendingVehicle { class, size, v_desired, critical_gap_s });
            }
        }
        // Footprints of everyone present, kept in step with `agents` as road users enter.
        let mut rects: Vec<Rect> = self.agents.iter().map(|a| self.rect(a)).collect();
        for route in 0..self.pending.len() {
            if self.pending[route].is_empty() {
                continue;
            }
            let p = self.pending[route][0].clone();
            let m = class_model(p.class);
            let s = 0.5 * p.size.0;
            let probe = Agent {
                id: u32::MAX,
                class: p.class,
                length: p.size.0,
                width: p.size.1,
                height: p.size.2,
                v_desired: p.v_desired,
                s,
                v: 0.0,
                a: 0.0,
                role: Role::Vehicle { route, yellow_stop: None, committed: false, critical_gap_s: p.critical_gap_s },
            };
            rects.push(self.rect(&probe));
            self.agents.push(probe);
            let i = self.agents.len() - 1;
            let hit = self.sweep(i, &rects, 80.0).into_iter().min_by(|x, y| x.gap.total_cmp(&y.gap));
            let (gap, v_lead) = hit.map_or((f32::INFINITY, 0.0), |h| (h.gap, h.v_along));
            if gap < m.s0 + 1.0 {
                self.agents.pop();
                rects.pop();
                continue;
            }
            // Enter at a speed the gap allows (IDM equilibrium-ish, never faster than the leader
            // can be followed safely).
            let safe = ((gap - m.s0) / m.headway_s).max(0.0);
            let v = p.v_desired.min(self.routes[route].v_cap_at(s)).min(if gap.is_finite() {
                safe.min(v_lead.max(0.0) + safe * 0.5)
            } else {
                f32::INFINITY
            });
            let id = self.next_id;
            self.next_id += 1;
            if let Some(a) = self.agents.last_mut() {
                a.id = id;
                a.v = v;
            }
            self.pending[route].remove(0);
        }
        // Pedestrians.
        let ped = class_model(Class::Pedestrian);
        for k in 0..self.ped_sources.len() {
            let rate = self.cfg.pedestrian_source_rate(self.ped_sources[k].jaywalk);
            while self.ped_sources[k].next_arrival_s <= now {
                self.ped_sources[k].next_arrival_s =
                    next_arrival(&mut self.rng, self.ped_sources[k].next_arrival_s, rate);
                self.ped_sources[k].pending += 1;
            }
            if self.ped_sources[k].pending == 0 {
                continue;
            }
            let slot = self.rng.random_range(0..self.ped_sources[k].paths.len());
            let (path, curb_s, far_s) = self.ped_sources[k].paths[slot].clone();
            let start = path.points[0];
            let free = self
                .agents
                .iter()
                .zip(&rects)
                .all(|(o, r)| (r.center - start).length() > 1.2 + 0.5 * o.length.max(o.width));
            if !free {
                continue;
            }
            self.ped_sources[k].pending -= 1;
            let size = (
                sample(&mut self.rng, ped.length),
                sample(&mut self.rng, ped.width),
                sample(&mut self.rng, ped.height),
            );
            let v_desired =
                Normal::new(1.35f32, 0.2).map(|d| d.sample(&mut self.rng)).unwrap_or(1.35).clamp(0.8, ped.v_max);
            let id = self.next_id;
            self.next_id += 1;
            let (arm, jaywalk) = (self.ped_sources[k].arm, self.ped_sources[k].jaywalk);
            let walker = Agent {
                id,
                class: Class::Pedestrian,
                length: size.0,
                width: size.1,
                height: size.2,
                v_desired,
                s: 0.5 * size.0,
                v: 0.0,
                a: 0.0,
                role: Role::Pedestrian { path, curb_s, far_s, arm, jaywalk, started: false },
            };
            rects.push(self.rect(&walker));
            self.agents.push(walker);
        }
    }

    pub(super) fn draw_class(&mut self) -> Class {
        draw_from(&mut self.rng, &self.cfg.class_mix).unwrap_or(Class::Car)
    }
}

/// Pedestrian paths: per arm with a crosswalk, two directions with waiting slots on the
/// junction-side and outer halves of the crosswalk (so opposing streams never meet), and a
/// jaywalking source mid-block. Pedestrians appear on and leave from the sidewalks next to
/// the crosswalk; paths never cross other streams' paths, so pedestrians only ever queue.
pub(super) fn pedestrian_sources(layout: &Layout) -> Vec<PedSource> {
    let mut out = Vec::new();
    for (i, arm) in layout.arms.iter().enumerate() {
        let sw = sidewalk_width(arm);
        let w = crosswalk_width(arm);
        if !has_pedestrians(arm) {
            continue;
        }
        let at = |a: f32, l: f32| arm.dir * a + arm.normal * l;
        let (c0, ein, eout) = (cw0(arm), arm.edge_in_m, arm.edge_out_m);
        let half = 0.5 * w;
        // Slots 1 m apart keep side-by-side pedestrians clear of each other's sweep; each slot
        // has its own lane on the sidewalks (1 m apart too), so paths never cross.
        let by_width = ((half - 0.95) / 1.0).floor() as usize + 1;
        let by_sidewalk = ((sw - 0.35 - 0.75) / 1.0).floor() as usize + 1;
        let n_slots = by_width.min(by_sidewalk).max(1);
        let mut inward = Vec::new();
        let mut outward = Vec::new();
        for k in 0..n_slots {
            let u_in = 0.45 + 1.0 * k as f32;
            let u_out = w - 0.45 - 1.0 * k as f32;
            let lane = 0.75 + 1.0 * k as f32;
            // Inbound side → outbound side on the junction half, straight over the sidewalks
            // (paths to the corners would cross the neighbouring arm's pedestrians).
            let p = [
                at(c0 + u_in, ein + sw - 0.35),
                at(c0 + u_in, ein + 0.4),
                at(c0 + u_in, eout - 0.4),
                at(c0 + u_in, eout - sw + 0.35),
            ];
            outward.push(with_curbs(&p, &[]));
            // Outbound side → inbound side on the outer half, along the sidewalks.
            let q = [
                at(c0 + u_out + 12.0, eout - lane),
                at(c0 + u_out, eout - 0.4),
                at(c0 + u_out, ein + 0.4),
                at(c0 + u_out + 12.0, ein + lane),
            ];
            let (turn_a, turn_b) = (at(c0 + u_out, eout - lane), at(c0 + u_out, ein + lane));
            inward.push(with_curbs(&q, &[turn_a, turn_b]));
        }
        out.push(PedSource { arm: i, paths: outward, next_arrival_s: 0.0, pending: 0, jaywalk: false });
        out.push(PedSource { arm: i, paths: inward, next_arrival_s: 0.0, pending: 0, jaywalk: false });
        // Jaywalkers: straight across, 15–45 m beyond the stop line (clear of the crosswalk
        // streams on the sidewalks).
        let mut jw = Vec::new();
        for (k, a) in jaywalk_lines(arm).into_iter().enumerate() {
            let (p, q) = if k % 2 == 0 { (ein, eout) } else { (eout, ein) };
            let side = |l: f32| if l > 0.0 { l + 0.5 * sw } else { l - 0.5 * sw };
            let curb = |l: f32| if l > 0.0 { l + 0.4 } else { l - 0.4 };
            jw.push(with_curbs(&[at(a + 3.0, side(p)), at(a, curb(p)), at(a, curb(q)), at(a - 3.0, side(q))], &[]));
        }
        if !jw.is_empty() {
            out.push(PedSource { arm: i, paths: jw, next_arrival_s: 0.0, pending: 0, jaywalk: true });
        }
    }
    out
}

fn sidewalk_width(arm: &ArmLayout) -> f32 {
    arm.sidewalks.first().map_or(0.0, |p| (p[3] - p[0]).dot(arm.normal).abs())
}

/// Whether an arm has room for pedestrians: a sidewalk and a crosswalk wide enough to walk.
fn has_pedestrians(arm: &ArmLayout) -> bool {
    sidewalk_width(arm) >= 1.2 && crosswalk_width(arm) >= 2.6
}

/// Where an arm's jaywalkers cross the road, m from the junction's centre along the arm: 15,
/// 25, 35 and 45 m beyond the stop line, as many as the arm holds (none without pedestrians).
pub(super) fn jaywalk_lines(arm: &ArmLayout) -> Vec<f32> {
    if !has_pedestrians(arm) {
        return Vec::new();
    }
    let len = arm.road[1].dot(arm.dir);
    (0..4).map(|k| arm.stop_line_at_m + 15.0 + 10.0 * k as f32).take_while(|a| a + 2.0 <= len).collect()
}

/// A pedestrian path through `p` (sidewalk, curb, far curb, sidewalk) with optional corner
/// points `[before the curb, after the far curb]`, and the arc lengths of the two curbs.
fn with_curbs(p: &[Vec2; 4], turns: &[Vec2]) -> (Path, f32, f32) {
    let poly: Vec<Vec2> = match turns {
        [a, b] => vec![p[0], *a, p[1], p[2], *b, p[3]],
        _ => p.to_vec(),
    };
    let path = Path::from_polyline(&poly);
    let k = if turns.len() == 2 { 2 } else { 1 };
    let curb: f32 = poly[..=k].windows(2).map(|w| (w[1] - w[0]).length()).sum();
    (path, curb, curb + (poly[k + 1] - poly[k]).length())
}
