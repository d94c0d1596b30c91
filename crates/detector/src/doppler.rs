//! A decoded box's velocity from the Doppler of the radar detections inside it.
//!
//! A radar measures a road user's velocity along its line of sight: v_r = u · v, with u the
//! unit vector from the radar to the detection (3-D: the radar stands on a pole above the
//! road). A vehicle moves along its heading h (its velocity is s h, with s its signed speed),
//! so each detection inside the box gives s = v_r / (u · h). The box's heading comes from the
//! detector, its speed from the radar: one detection of one radar is enough, where a learned
//! head has to infer the speed from what the points look like.
//!
//! - **Geometry.** u · h = cos ε (g · h), with g the unit ground line of sight and ε the
//!   detection's elevation seen from its radar; ε comes from the radar's position where the
//!   frame knows it ([`Frame::radar_origin`]), else it is taken as 0. A detection whose ground
//!   line of sight is more than `max_angle_deg` off the heading axis is left out: the speed's
//!   error is the radial noise over cos of that angle, and across the heading the radar
//!   measures nothing of it.
//! - **Two radars.** A detection paired with another radar's ([`crate::data::pair_radar_velocities`])
//!   carries its full ground velocity v; it gives s = v · h at any angle.
//! - **Robustness.** The speed is the median of the detections' speeds weighted by (u · h)²
//!   (the inverse of each one's noise variance): static clutter or another road user's
//!   detection inside the margin is outvoted when it is the minority.
//! - **Sweeps.** Only the frame's own sweep counts (lag 0): an older sweep's detections lie
//!   where the road user was.
//!
//! What it leaves out: a road user that does not move along its heading (a pedestrian turning,
//! a vehicle skidding), so the step reads the classes it is given (vehicles by default); a
//! heading the detector got wrong, whose error passes into the speed as 1 / cos of it; the
//! road user's rotation (a turning vehicle's detections differ by ω × r).

use crate::data::Frame;
use crate::data::is_radial;
use glam::{Vec2, Vec3};
use hilo_core::Detection;
use hilo_fusion::config::RadarVelocityConfig;

/// What the step did to one frame's boxes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DopplerCount {
    /// Boxes of the classes the step reads.
    pub boxes: usize,
    /// Of those, the boxes whose velocity the radar gave.
    pub read: usize,
}

impl DopplerCount {
    /// What `hilo detect` says of it: nothing when no box was of a class the step reads.
    pub fn note(&self) -> String {
        if self.boxes == 0 {
            return String::new();
        }
        format!("; velocity read from the radar's Doppler for {} of {} boxes it reads", self.read, self.boxes)
    }
}

impl std::ops::AddAssign for DopplerCount {
    fn add_assign(&mut self, o: DopplerCount) {
        self.boxes += o.boxes;
        self.read += o.read;
    }
}

/// Sets the velocity of each box of `dets` (of `cfg.classes`) that holds enough of `frame`'s
/// own-sweep radar detections from their Doppler; the others keep theirs.
pub fn read_velocities(cfg: &RadarVelocityConfig, frame: &Frame, dets: &mut [Detection]) -> DopplerCount {
    let origins = (frame.radar_origin.len() == frame.radar.len()).then_some(frame.radar_origin.as_slice());
    let min_cos = cfg.max_angle_deg.to_radians().cos();
    let mut count = DopplerCount::default();
    let mut speeds: Vec<(f32, f32)> = Vec::new();
    for d in dets.iter_mut().filter(|d| cfg.classes.contains(&d.class)) {
        count.boxes += 1;
        let h = d.box3.heading();
        let across = Vec2::new(-h.y, h.x);
        let centre = d.box3.center.truncate();
        let (half_l, half_w) = (0.5 * d.box3.length_m + cfg.margin_m, 0.5 * d.box3.width_m + cfg.margin_m);
        speeds.clear();
        for (i, p) in frame.radar.iter().enumerate() {
            let off = Vec2::new(p[0], p[1]) - centre;
            if p[7] != 0.0 || off.dot(h).abs() > half_l || off.dot(across).abs() > half_w {
                continue;
            }
            if !is_radial(p) {
                // Paired: the full ground velocity, at any angle to the heading.
                speeds.push((Vec2::new(p[8], p[9]).dot(h), 1.0));
                continue;
            }
            let cos_g = Vec2::new(p[5], p[6]).dot(h);
            if cos_g.abs() < min_cos {
                continue;
            }
            let cos_e = origins.map_or(1.0, |o| {
                let r = Vec3::new(p[0], p[1], p[2]) - Vec3::from(o[i]);
                r.truncate().length() / r.length().max(1e-6)
            });
            let a = cos_e * cos_g;
            speeds.push((p[4] / a, a * a));
        }
        if speeds.len() >= cfg.min_detections
            && let Some(s) = weighted_median(&mut speeds)
        {
            d.velocity_mps = s * h;
            count.read += 1;
        }
    }
    count
}

/// The weighted median of (value, weight) pairs: the smallest value whose cumulative weight
/// reaches half the total (values sorted, ties in input order). `None` when empty or weightless.
pub fn weighted_median(v: &mut [(f32, f32)]) -> Option<f32> {
    let total: f32 = v.iter().map(|x| x.1).sum();
    if v.is_empty() || total.is_nan() || total <= 0.0 {
        return None;
    }
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut acc = 0.0;
    for &(x, w) in v.iter() {
        acc += w;
        if acc >= 0.5 * total {
            return Some(x);
        }
    }
    v.last().map(|x| x.0)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::data::radar_point;
    use hilo_core::{Box3, Class};

    fn car(x: f32, y: f32, yaw: f32) -> Detection {
        Detection {
            box3: Box3::new(Vec3::new(x, y, 0.8), 4.6, 1.9, 1.6, yaw),
            class: Class::Car,
            score: 0.9,
            velocity_mps: Vec2::new(0.1, 0.1),
        }
    }

    /// A detection at `p` of a road user moving at `v`, seen by a radar at `at`: its radial
    /// velocity along the 3-D line of sight, its ground line of sight as the loader stores it.
    fn seen(at: Vec3, p: Vec3, v: Vec2) -> [f32; 10] {
        let u = (p - at).normalize();
        let g = (p - at).truncate().normalize();
        radar_point(p.to_array(), 5.0, u.dot(v.extend(0.0)), g.to_array(), 0.0)
    }

    #[test]
    fn the_weighted_median_is_the_half_weight_point() {
        assert_eq!(weighted_median(&mut []), None);
        assert_eq!(weighted_median(&mut [(3.0, 0.0)]), None);
        assert_eq!(weighted_median(&mut [(3.0, 1.0)]), Some(3.0));
        assert_eq!(weighted_median(&mut [(5.0, 1.0), (1.0, 1.0), (2.0, 1.0)]), Some(2.0));
        // One heavy value outweighs two light ones on either side.
        assert_eq!(weighted_median(&mut [(9.0, 0.1), (4.0, 3.0), (0.0, 0.2)]), Some(4.0));
    }

    /// On noise-free detections from a radar 6 m up, the speed is exact whatever the heading
    /// (within the angle) and whichever way the box points: the elevation is corrected where
    /// the origin is known, and without it the speed is short by cos ε.
    #[test]
    fn a_noise_free_detection_gives_the_exact_velocity_and_the_elevation_matters() {
        let at = Vec3::new(0.0, 0.0, 6.0);
        let cfg = RadarVelocityConfig::default();
        for (yaw, speed) in [(0.2f32, 8.0f32), (2.9, 5.0), (-1.0, 12.0), (0.6, 0.0)] {
            let p = Vec3::new(14.0, 5.0, 0.7);
            let v = speed * Vec2::from_angle(yaw);
            let los = (p - at).truncate().normalize();
            if los.dot(v.normalize_or_zero()).abs() < 0.5 && speed > 0.0 {
                continue;
            }
            let frame = Frame { radar: vec![seen(at, p, v)], radar_origin: vec![at.to_array()], ..Frame::default() };
            // The box points either way along the road user: the velocity is the same.
            for flip in [0.0, std::f32::consts::PI] {
                let mut dets = vec![car(p.x, p.y, yaw + flip)];
                let n = read_velocities(&cfg, &frame, &mut dets);
                assert_eq!(n, DopplerCount { boxes: 1, read: 1 });
                assert!((dets[0].velocity_mps - v).length() < 1e-4, "{yaw} {flip}: {} vs {v}", dets[0].velocity_mps);
            }
            let unknown = Frame { radar_origin: Vec::new(), ..frame.clone() };
            let mut dets = vec![car(p.x, p.y, yaw)];
            read_velocities(&cfg, &unknown, &mut dets);
            let cos_e = (p - at).truncate().length() / (p - at).length();
            assert!((dets[0].velocity_mps.length() - cos_e * speed).abs() < 1e-4);
        }
    }

    /// What the step leaves alone: a detection across the heading, outside the margin, of an
    /// older sweep, a class it does not read; a box with fewer detections than asked.
    #[test]
    fn detections_it_cannot_use_leave_the_heads_velocity() {
        const NORTH: f32 = std::f32::consts::FRAC_PI_2;
        let at = Vec3::new(0.0, 0.0, 5.0);
        let cfg = RadarVelocityConfig { min_detections: 1, ..RadarVelocityConfig::default() };
        let v = Vec2::new(0.0, 6.0);
        let head = Vec2::new(0.1, 0.1);
        // The car drives north at (20, 0): the radar at the origin looks at it from the side.
        let across = seen(at, Vec3::new(20.0, 0.0, 0.5), v);
        let mut older = seen(at, Vec3::new(20.0, 40.0, 0.5), v);
        older[7] = 0.1;
        let outside = seen(at, Vec3::new(20.0, 40.0 + 2.3 + cfg.margin_m + 0.2, 0.5), v);
        let cases = [
            (Frame { radar: vec![across], ..Frame::default() }, car(20.0, 0.0, NORTH)),
            (Frame { radar: vec![older], ..Frame::default() }, car(20.0, 40.0, NORTH)),
            (Frame { radar: vec![outside], ..Frame::default() }, car(20.0, 40.0, NORTH)),
        ];
        for (frame, det) in cases {
            let mut dets = vec![det];
            assert_eq!(read_velocities(&cfg, &frame, &mut dets), DopplerCount { boxes: 1, read: 0 });
            assert_eq!(dets[0].velocity_mps, head);
        }
        let inside = seen(at, Vec3::new(20.0, 42.5, 0.5), v);
        let frame = Frame { radar: vec![inside], ..Frame::default() };
        let mut walker = vec![Detection { class: Class::Pedestrian, ..car(20.0, 42.5, NORTH) }];
        assert_eq!(read_velocities(&cfg, &frame, &mut walker), DopplerCount::default());
        let two = RadarVelocityConfig { min_detections: 2, ..cfg.clone() };
        let mut dets = vec![car(20.0, 40.0, NORTH)];
        assert_eq!(read_velocities(&two, &frame, &mut dets).read, 0);
        let mut dets = vec![car(20.0, 40.0, NORTH)];
        assert_eq!(read_velocities(&cfg, &frame, &mut dets).read, 1);
        assert!((dets[0].velocity_mps - v).length() < 0.2, "{}", dets[0].velocity_mps);
    }

    /// With radial noise of s.d. σ on one detection, the speed's error is σ / (cos ε cos θ),
    /// θ the angle between the ground line of sight and the heading: the law `max_angle_deg`
    /// guards against (at 60° twice the error straight along the road).
    #[test]
    fn the_speed_error_grows_as_one_over_cos_of_the_angle() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let sigma = 0.1f32;
        let noise = Normal::new(0.0, sigma).unwrap();
        let at = Vec3::new(-30.0, 0.0, 6.0);
        let p = Vec3::new(0.0, 0.0, 0.6);
        let cos_e = (p - at).truncate().length() / (p - at).length();
        let cfg = RadarVelocityConfig::default();
        for theta in [0.0f32, 30.0, 50.0, 59.0] {
            let yaw = theta.to_radians();
            let v = 5.0 * Vec2::from_angle(yaw);
            let n = 4000;
            let mut sq = 0.0f64;
            for _ in 0..n {
                let mut d = seen(at, p, v);
                d[4] += noise.sample(&mut rng);
                d[8] = d[4] * d[5];
                d[9] = d[4] * d[6];
                let frame = Frame { radar: vec![d], radar_origin: vec![at.to_array()], ..Frame::default() };
                let mut dets = vec![car(p.x, p.y, yaw)];
                read_velocities(&cfg, &frame, &mut dets);
                sq += (dets[0].velocity_mps - v).length_squared() as f64;
            }
            let rms = (sq / n as f64).sqrt() as f32;
            let law = sigma / (cos_e * yaw.cos());
            assert!((rms / law - 1.0).abs() < 0.05, "θ {theta}: rms {rms} against {law}");
        }
    }

    /// Static clutter inside the box (a pole the car passes) is outvoted by the car's own
    /// detections; a paired detection's full velocity counts at any angle.
    #[test]
    fn clutter_is_outvoted_and_a_paired_velocity_counts_across_the_heading() {
        let at = Vec3::new(-30.0, 2.0, 5.0);
        let v = Vec2::new(7.0, 0.0);
        let cfg = RadarVelocityConfig::default();
        let mut radar: Vec<[f32; 10]> =
            [-1.5f32, 0.0, 1.5].iter().map(|&dx| seen(at, Vec3::new(dx, 0.3, 0.6), v)).collect();
        radar.push(seen(at, Vec3::new(0.5, -0.8, 1.0), Vec2::ZERO));
        let origin = vec![at.to_array(); radar.len()];
        let frame = Frame { radar, radar_origin: origin, ..Frame::default() };
        let mut dets = vec![car(0.0, 0.0, 0.0)];
        read_velocities(&cfg, &frame, &mut dets);
        assert!((dets[0].velocity_mps - v).length() < 1e-4, "{}", dets[0].velocity_mps);

        // A radar straight to the side, and the same detection paired with a second radar.
        let side = Vec3::new(0.0, -25.0, 5.0);
        let mut p = seen(side, Vec3::new(0.0, 0.0, 0.6), v);
        let mut dets = vec![car(0.0, 0.0, 0.0)];
        let frame = Frame { radar: vec![p], ..Frame::default() };
        assert_eq!(read_velocities(&cfg, &frame, &mut dets).read, 0);
        (p[8], p[9]) = (v.x, v.y);
        let frame = Frame { radar: vec![p], ..Frame::default() };
        assert_eq!(read_velocities(&cfg, &frame, &mut dets).read, 1);
        assert!((dets[0].velocity_mps - v).length() < 1e-5);
    }
}
