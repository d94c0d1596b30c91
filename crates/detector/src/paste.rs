//! Ground-truth paste ("GT sampling", as SECOND, PointPillars and CenterPoint train on KITTI and
//! nuScenes): rare road users cut from training frames, with their LiDAR and radar points, are
//! pasted into other training frames so that every step sees them.
//!
//! Roadside sensors never move, so an instance is pasted where it stood: seen from the same rig
//! at the same place, its points are exactly those the rig would measure there (an ego-vehicle
//! dataset cannot say as much). What the paste leaves out: occlusion between a pasted instance
//! and the frame's own road users (a pasted bus does not hide the car behind it, nor is it hidden
//! by a truck in front of it), and the ground and background points the instance would have
//! hidden (removed before training anyway). Instances whose footprints would overlap a box
//! already in the frame (its own or pasted) are left out; the frame's points inside a pasted
//! footprint (residual clutter) make way for the instance's.

use crate::data::{Frame, GtBox, LIDAR_FEATURES, RADAR_FEATURES};
use crate::error::Result;
use hilo_core::Valid;
pub use hilo_fusion::config::PasteConfig;
use rand::Rng;

/// One instance cut from a training frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Instance {
    /// Index of the frame it was cut from.
    pub frame: usize,
    pub gt: GtBox,
    pub lidar: Vec<[f32; LIDAR_FEATURES]>,
    pub radar: Vec<[f32; RADAR_FEATURES]>,
}

/// Whether `p` (x, y, z) lies in `b` grown by `margin` on every side.
pub fn in_box(b: &GtBox, p: [f32; 3], margin: f32) -> bool {
    let (dx, dy) = (p[0] - b.center[0], p[1] - b.center[1]);
    let (c, s) = (b.yaw.cos(), b.yaw.sin());
    let (along, across) = (dx * c + dy * s, -dx * s + dy * c);
    along.abs() <= 0.5 * b.wlh[1] + margin
        && across.abs() <= 0.5 * b.wlh[0] + margin
        && (p[2] - b.center[2]).abs() <= 0.5 * b.wlh[2] + margin
}

/// Whether the bird's-eye footprints of two boxes overlap (separating axes; touching edges do
/// not count).
pub fn footprints_overlap(a: &GtBox, b: &GtBox) -> bool {
    let axes = |g: &GtBox| {
        let (c, s) = (g.yaw.cos(), g.yaw.sin());
        [[c, s], [-s, c]]
    };
    let half = |g: &GtBox, n: [f32; 2]| {
        let [u, v] = axes(g);
        0.5 * g.wlh[1] * (u[0] * n[0] + u[1] * n[1]).abs() + 0.5 * g.wlh[0] * (v[0] * n[0] + v[1] * n[1]).abs()
    };
    let d = [b.center[0] - a.center[0], b.center[1] - a.center[1]];
    let [a0, a1] = axes(a);
    let [b0, b1] = axes(b);
    [a0, a1, b0, b1].into_iter().all(|n| (d[0] * n[0] + d[1] * n[1]).abs() < half(a, n) + half(b, n))
}

/// The instances of the pasted classes in a set of training frames, by class.
#[derive(Clone, Debug, Default)]
pub struct PasteDb {
    /// (class index, fill count) in class order.
    fill: Vec<(usize, usize)>,
    /// Instances of each class in `fill`, in frame then box order.
    by_class: Vec<Vec<Instance>>,
    lidar_margin_m: f32,
}

impl PasteDb {
    /// Cuts every instance of a filled class with at least `min_lidar_points` LiDAR points out
    /// of `frames` (deterministic: frame order, then box order).
    pub fn build(frames: &[Frame], cfg: &Valid<PasteConfig>) -> Result<Self> {
        let fill = cfg.fill_by_class()?;
        let mut by_class = vec![Vec::new(); fill.len()];
        for (fi, f) in frames.iter().enumerate() {
            for b in &f.boxes {
                let Some(k) = fill.iter().position(|(c, _)| *c == b.class) else { continue };
                let lidar: Vec<_> =
                    f.lidar.iter().filter(|p| in_box(b, [p[0], p[1], p[2]], cfg.lidar_margin_m)).copied().collect();
                if lidar.len() < cfg.min_lidar_points {
                    continue;
                }
                let radar =
                    f.radar.iter().filter(|p| in_box(b, [p[0], p[1], p[2]], cfg.radar_margin_m)).copied().collect();
                by_class[k].push(Instance { frame: fi, gt: *b, lidar, radar });
            }
        }
        Ok(PasteDb { fill, by_class, lidar_margin_m: cfg.lidar_margin_m })
    }

    /// Instances held, per filled class (class index, count).
    pub fn counts(&self) -> Vec<(usize, usize)> {
        self.fill.iter().zip(&self.by_class).map(|((c, _), v)| (*c, v.len())).collect()
    }

    /// The instances held, per class by name: `car 120, pedestrian 45`.
    pub fn describe(&self) -> String {
        let held: Vec<String> =
            self.counts().iter().map(|(c, n)| format!("{} {n}", hilo_core::Class::ALL[*c].name())).collect();
        held.join(", ")
    }

    /// Every instance held, class by class.
    pub fn instances(&self) -> impl Iterator<Item = &Instance> {
        self.by_class.iter().flatten()
    }

    /// `f` with instances pasted: for each filled class (in class order) n − k candidates drawn
    /// uniformly with replacement, each kept unless its footprint overlaps a box already there
    /// (the frame's own or one pasted before it). The frame's points inside a kept footprint's
    /// column are replaced by the instance's. Deterministic in `rng`.
    pub fn paste(&self, f: &Frame, rng: &mut impl Rng) -> Frame {
        let mut boxes = f.boxes.clone();
        let mut chosen: Vec<&Instance> = Vec::new();
        for ((class, n), pool) in self.fill.iter().zip(&self.by_class) {
            let have = f.boxes.iter().filter(|b| b.class == *class).count();
            if pool.is_empty() {
                continue;
            }
            for _ in 0..n.saturating_sub(have) {
                let inst = &pool[rng.random_range(0..pool.len())];
                if boxes.iter().any(|b| footprints_overlap(b, &inst.gt)) {
                    continue;
                }
                boxes.push(inst.gt);
                chosen.push(inst);
            }
        }
        if chosen.is_empty() {
            return f.clone();
        }
        // Points in a pasted footprint's column (any height) give way to the instance's.
        let clear = |p: [f32; 3]| {
            chosen.iter().any(|i| {
                let column = GtBox { wlh: [i.gt.wlh[0], i.gt.wlh[1], f32::INFINITY], ..i.gt };
                in_box(&column, p, self.lidar_margin_m)
            })
        };
        let mut out = Frame {
            sample_token: f.sample_token.clone(),
            scene: f.scene.clone(),
            lidar: f.lidar.iter().filter(|p| !clear([p[0], p[1], p[2]])).copied().collect(),
            radar: f.radar.iter().filter(|p| !clear([p[0], p[1], p[2]])).copied().collect(),
            // The pasted instances' radars are not this frame's: no origins.
            radar_origin: Vec::new(),
            boxes,
        };
        for i in chosen {
            out.lidar.extend_from_slice(&i.lidar);
            out.radar.extend_from_slice(&i.radar);
        }
        out
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use hilo_core::Class;
    use hilo_core::iou::{YawBox, bev_iou};
    use rand::SeedableRng;

    fn gt(class: Class, x: f32, y: f32, yaw: f32, w: f32, l: f32) -> GtBox {
        GtBox { class: class.index(), center: [x, y, 1.0], wlh: [w, l, 2.0], yaw, velocity: [0.0, 0.0] }
    }

    fn yaw_box(b: &GtBox) -> YawBox {
        YawBox {
            center: [b.center[0] as f64, b.center[1] as f64, b.center[2] as f64],
            length_m: b.wlh[1] as f64,
            width_m: b.wlh[0] as f64,
            height_m: b.wlh[2] as f64,
            yaw: b.yaw as f64,
        }
    }

    #[test]
    fn footprint_overlap_agrees_with_the_rotated_iou() {
        // Oracle: hilo-core's clipped-polygon BEV IoU is positive exactly when footprints overlap.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut both = [0usize; 2];
        for _ in 0..20_000 {
            let mut r = |lo: f32, hi: f32| rng.random_range(lo..hi);
            let a = gt(Class::Bus, r(-6.0, 6.0), r(-6.0, 6.0), r(-3.2, 3.2), r(0.5, 3.0), r(0.5, 12.0));
            let b = gt(Class::Car, r(-6.0, 6.0), r(-6.0, 6.0), r(-3.2, 3.2), r(0.5, 3.0), r(0.5, 12.0));
            let iou = bev_iou(&yaw_box(&a), &yaw_box(&b));
            let overlap = footprints_overlap(&a, &b);
            assert_eq!(overlap, iou > 0.0, "{a:?} {b:?} iou {iou}");
            both[overlap as usize] += 1;
        }
        assert!(both[0] > 1000 && both[1] > 1000, "{both:?}");
        // Hard cases: touching edges do not overlap; a sliver does; a box overlaps itself.
        let a = gt(Class::Bus, 0.0, 0.0, 0.0, 2.0, 4.0);
        assert!(!footprints_overlap(&a, &gt(Class::Car, 4.0, 0.0, 0.0, 2.0, 4.0)));
        assert!(footprints_overlap(&a, &gt(Class::Car, 3.99, 0.0, 0.0, 2.0, 4.0)));
        assert!(footprints_overlap(&a, &a));
        // A box rotated 45° whose corner just reaches into the other.
        let d = gt(Class::Car, 2.0 + 0.5 * 2f32.sqrt() - 0.01, 0.0, std::f32::consts::FRAC_PI_4, 1.0, 1.0);
        assert!(footprints_overlap(&a, &d));
        let e = GtBox { center: [d.center[0] + 0.02, 0.0, 1.0], ..d };
        assert!(!footprints_overlap(&a, &e));
    }

    #[test]
    fn in_box_respects_yaw_and_margin() {
        let b = gt(Class::Bus, 10.0, 5.0, std::f32::consts::FRAC_PI_2, 2.0, 10.0);
        // Length runs along +y after a quarter turn.
        assert!(in_box(&b, [10.0, 9.9, 1.0], 0.0));
        assert!(!in_box(&b, [10.0, 10.1, 1.0], 0.0));
        assert!(in_box(&b, [10.0, 10.1, 1.0], 0.15));
        assert!(!in_box(&b, [11.1, 5.0, 1.0], 0.0));
        assert!(!in_box(&b, [10.0, 5.0, 2.1], 0.0));
        assert!(in_box(&b, [10.0, 5.0, 2.1], 0.15));
    }

    fn frame_with(boxes: Vec<GtBox>) -> Frame {
        // 20 LiDAR points and 2 radar points in every box, and clutter at the origin.
        let mut lidar = vec![[0.0, 0.0, 0.5, 1.0, 0.0]];
        let mut radar = vec![crate::data::radar_point([0.0, 0.0, 0.5], 0.0, 0.0, [1.0, 0.0], 0.0)];
        for (k, b) in boxes.iter().enumerate() {
            for i in 0..20 {
                let t = i as f32 / 20.0 - 0.5;
                let (c, s) = (b.yaw.cos(), b.yaw.sin());
                let (a, x) = (t * b.wlh[1] * 0.9, 0.3 * t * b.wlh[0]);
                lidar.push([b.center[0] + a * c - x * s, b.center[1] + a * s + x * c, b.center[2], k as f32, 0.0]);
            }
            for _ in 0..2 {
                radar.push(crate::data::radar_point(
                    [b.center[0] + 0.6, b.center[1], b.center[2]],
                    5.0,
                    1.0,
                    [1.0, 0.0],
                    0.0,
                ));
            }
        }
        Frame { sample_token: "s".into(), scene: "a".into(), lidar, radar, radar_origin: Vec::new(), boxes }
    }

    #[test]
    fn paste_fills_to_the_count_without_overlaps_and_carries_the_points() {
        let bus = |x: f32, y: f32| gt(Class::Bus, x, y, 0.3, 2.5, 11.0);
        let frames = vec![
            frame_with(vec![bus(20.0, 0.0), gt(Class::Car, -20.0, 0.0, 0.0, 1.8, 4.5)]),
            frame_with(vec![bus(0.0, 20.0)]),
            frame_with(vec![bus(0.0, -20.0), gt(Class::Motorcycle, 30.0, 30.0, 0.0, 0.8, 2.0)]),
            // A bus too far from every point: left out of the database (0 < 5 points).
            Frame { boxes: vec![bus(-40.0, -40.0)], ..frame_with(vec![]) },
            // A target frame: one bus already, clutter at its centre of x = 20.
            frame_with(vec![bus(20.0, 0.0)]),
        ];
        let cfg = Valid::new(PasteConfig { fill: [("bus".to_string(), 3)].into(), ..PasteConfig::default() }).unwrap();
        let db = PasteDb::build(&frames, &cfg).unwrap();
        assert_eq!(db.counts(), vec![(Class::Bus.index(), 4)]);
        for inst in &db.by_class[0] {
            assert_eq!(inst.lidar.len(), 20);
            assert_eq!(inst.radar.len(), 2, "radar within 0.5 m of the box");
        }
        let target = &frames[4];
        let mut pasted_any = false;
        for seed in 0..50 {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let out = db.paste(target, &mut rng);
            let again = db.paste(target, &mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
            assert_eq!(out, again, "deterministic in the seed");
            let buses = out.boxes.iter().filter(|b| b.class == Class::Bus.index()).count();
            assert!((1..=3).contains(&buses), "filled up to 3, never beyond: {buses}");
            assert_eq!(out.boxes[0], target.boxes[0], "the frame's own boxes come first, unchanged");
            for (i, a) in out.boxes.iter().enumerate() {
                for b in &out.boxes[i + 1..] {
                    assert!(!footprints_overlap(a, b), "pasted boxes never overlap: {a:?} {b:?}");
                }
            }
            // Every pasted box holds its instance's 20 LiDAR and 2 radar points; the origin's
            // clutter, outside every pasted box, stays.
            for b in &out.boxes[1..] {
                pasted_any = true;
                assert_eq!(out.lidar.iter().filter(|p| in_box(b, [p[0], p[1], p[2]], 0.15)).count(), 20);
                assert_eq!(out.radar.iter().filter(|p| in_box(b, [p[0], p[1], p[2]], 0.5)).count(), 2);
            }
            assert_eq!(out.lidar.len(), target.lidar.len() + 20 * (buses - 1));
            assert!(out.lidar.contains(&[0.0, 0.0, 0.5, 1.0, 0.0]));
        }
        assert!(pasted_any);
        // A class not filled is never pasted, and a frame already full receives nothing.
        let full = frame_with(vec![bus(-20.0, 20.0), bus(20.0, 20.0), bus(-20.0, -20.0)]);
        assert_eq!(db.paste(&full, &mut rand_chacha::ChaCha8Rng::seed_from_u64(1)), full);
    }

    #[test]
    fn points_under_a_pasted_instance_give_way() {
        let bus = gt(Class::Bus, 20.0, 0.0, 0.0, 2.5, 11.0);
        let source = frame_with(vec![bus]);
        let mut target = frame_with(vec![]);
        // Residual points where the bus will stand, at two heights, and one just outside.
        target.lidar.extend([[20.0, 0.0, 0.2, 0.0, 0.0], [21.0, 0.5, 5.0, 0.0, 0.0], [20.0, 1.6, 0.5, 0.0, 0.0]]);
        let cfg = Valid::new(PasteConfig { fill: [("bus".to_string(), 1)].into(), ..PasteConfig::default() }).unwrap();
        let db = PasteDb::build(std::slice::from_ref(&source), &cfg).unwrap();
        let out = db.paste(&target, &mut rand_chacha::ChaCha8Rng::seed_from_u64(0));
        assert_eq!(out.boxes, vec![bus]);
        assert!(!out.lidar.contains(&[20.0, 0.0, 0.2, 0.0, 0.0]) && !out.lidar.contains(&[21.0, 0.5, 5.0, 0.0, 0.0]));
        assert!(out.lidar.contains(&[20.0, 1.6, 0.5, 0.0, 0.0]), "0.35 m beyond the side, more than the margin");
        assert_eq!(out.lidar.len(), 1 + 1 + 20);
    }

    #[test]
    fn bad_fill_names_the_field_and_value() {
        let cfg = PasteConfig { fill: [("tram".to_string(), 2)].into(), ..PasteConfig::default() };
        let e = cfg.validate().unwrap_err().to_string();
        assert!(e.contains("train.paste.fill") && e.contains("tram"), "{e}");
        let cfg = PasteConfig { radar_margin_m: f32::NAN, ..PasteConfig::default() };
        assert!(cfg.validate().unwrap_err().to_string().contains("train.paste.radar_margin_m = NaN"));
        let cfg = PasteConfig { fill: [("bus".to_string(), 1000)].into(), ..PasteConfig::default() };
        assert!(cfg.validate().unwrap_err().to_string().contains("train.paste.fill.bus = 1000"));
    }
}
