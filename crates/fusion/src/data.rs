//! Frames from a dataset, augmentation, and pillars: everything the network reads, prepared on
//! the host (and on another thread during training).

use crate::error::Result;
use crate::grid::BevGrid;
use hilo_core::Class;
use hilo_dataset::Dataset;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// The detection classes, in head-channel order ([`Class::ALL`]; names by [`Class::name`]).
pub const CLASSES: [Class; 6] = Class::ALL;

/// A ground-truth box in the scene's local frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GtBox {
    pub class: usize,
    pub center: [f32; 3],
    /// Width, length, height (nuScenes order).
    pub wlh: [f32; 3],
    pub yaw: f32,
    pub velocity: [f32; 2],
}

/// LiDAR point features: x, y, z, intensity (local frame).
pub const LIDAR_FEATURES: usize = 4;
/// Radar point features: x, y, z, RCS (dBsm), v_r (m/s), line of sight x, y (unit, from the
/// sensor): the direction v_r is measured along.
pub const RADAR_FEATURES: usize = 7;

/// One sample.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub sample_token: String,
    pub lidar: Vec<[f32; LIDAR_FEATURES]>,
    pub radar: Vec<[f32; RADAR_FEATURES]>,
    pub boxes: Vec<GtBox>,
}

fn quat_rotate(q: [f64; 4], p: [f64; 3]) -> [f64; 3] {
    let [w, x, y, z] = q;
    let r = glam::DQuat::from_xyzw(x, y, z, w).normalize();
    r.mul_vec3(glam::DVec3::from(p)).to_array()
}

/// Loads the samples of a split (scenes listed in the dataset's `splits.json`), in sample order.
/// Boxes without any LiDAR or radar point are left out, as the nuScenes loader does.
pub fn load_split(ds: &Dataset, split: &str) -> Result<Vec<Frame>> {
    let scenes: std::collections::HashSet<String> = ds.split(split)?.into_iter().collect();
    let t = &ds.tables;
    let scene_tokens: std::collections::HashSet<&str> =
        t.scene.iter().filter(|s| scenes.contains(&s.name)).map(|s| s.token.as_str()).collect();
    let calib: std::collections::HashMap<&str, &hilo_dataset::tables::CalibratedSensor> =
        t.calibrated_sensor.iter().map(|c| (c.token.as_str(), c)).collect();
    let sensors: std::collections::HashMap<&str, &hilo_dataset::tables::Sensor> =
        t.sensor.iter().map(|s| (s.token.as_str(), s)).collect();
    let instance_class: std::collections::HashMap<&str, Option<Class>> = t
        .instance
        .iter()
        .map(|i| {
            let cat = t.category.iter().find(|c| c.token == i.category_token).map(|c| c.name.as_str()).unwrap_or("");
            (i.token.as_str(), hilo_dataset::writer::class_of_category(cat))
        })
        .collect();
    let mut by_sample: std::collections::HashMap<&str, Vec<&hilo_dataset::tables::SampleData>> =
        std::collections::HashMap::new();
    for sd in &t.sample_data {
        by_sample.entry(sd.sample_token.as_str()).or_default().push(sd);
    }
    let mut anns: std::collections::HashMap<&str, Vec<&hilo_dataset::tables::SampleAnnotation>> =
        std::collections::HashMap::new();
    for a in &t.sample_annotation {
        anns.entry(a.sample_token.as_str()).or_default().push(a);
    }
    let mut samples: Vec<&hilo_dataset::tables::Sample> =
        t.sample.iter().filter(|s| scene_tokens.contains(s.scene_token.as_str())).collect();
    samples.sort_by(|a, b| (a.scene_token.as_str(), a.timestamp).cmp(&(b.scene_token.as_str(), b.timestamp)));
    let mut frames = Vec::with_capacity(samples.len());
    for s in samples {
        let mut lidar = Vec::new();
        let mut radar = Vec::new();
        let mut sds = by_sample.get(s.token.as_str()).cloned().unwrap_or_default();
        sds.sort_by(|a, b| a.filename.cmp(&b.filename));
        for sd in sds {
            let Some(c) = calib.get(sd.calibrated_sensor_token.as_str()) else { continue };
            let modality = sensors.get(c.sensor_token.as_str()).map(|x| x.modality.as_str()).unwrap_or("");
            let to_local = |p: [f64; 3]| {
                let r = quat_rotate(c.rotation, p);
                [(r[0] + c.translation[0]) as f32, (r[1] + c.translation[1]) as f32, (r[2] + c.translation[2]) as f32]
            };
            match modality {
                "lidar" => {
                    for p in ds.lidar_points(sd)? {
                        let q = to_local([p.x as f64, p.y as f64, p.z as f64]);
                        lidar.push([q[0], q[1], q[2], p.intensity]);
                    }
                }
                "radar" => {
                    for p in ds.radar_points(sd)? {
                        let q = to_local([p.x as f64, p.y as f64, p.z as f64]);
                        let (dx, dy) = (q[0] - c.translation[0] as f32, q[1] - c.translation[1] as f32);
                        let n = (dx * dx + dy * dy).sqrt().max(1e-6);
                        radar.push([q[0], q[1], q[2], p.rcs_dbsm, p.v_r_mps, dx / n, dy / n]);
                    }
                }
                _ => {}
            }
        }
        let mut boxes = Vec::new();
        for a in anns.get(s.token.as_str()).cloned().unwrap_or_default() {
            let Some(Some(class)) = instance_class.get(a.instance_token.as_str()) else { continue };
            if a.num_lidar_pts + a.num_radar_pts == 0 {
                continue;
            }
            let k = class.index();
            let [w, x, y, z] = a.rotation;
            let yaw = (2.0 * (x * y + w * z)).atan2(1.0 - 2.0 * (y * y + z * z)) as f32;
            let v = ds.box_velocity(a);
            let velocity = if v[0].is_finite() && v[1].is_finite() { [v[0] as f32, v[1] as f32] } else { [0.0, 0.0] };
            boxes.push(GtBox {
                class: k,
                center: a.translation.map(|v| v as f32),
                wlh: a.size.map(|v| v as f32),
                yaw,
                velocity,
            });
        }
        frames.push(Frame { sample_token: s.token.clone(), lidar, radar, boxes });
    }
    Ok(frames)
}

/// Global augmentation (roadside: about the scene origin).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Augmentation {
    /// Uniform rotation in ±this many degrees.
    pub rotate_deg: f32,
    /// Probability of mirroring across the x axis.
    pub flip_p: f32,
    /// Uniform scaling in [1 − s, 1 + s].
    pub scale: f32,
}

impl Default for Augmentation {
    fn default() -> Self {
        Augmentation { rotate_deg: 180.0, flip_p: 0.5, scale: 0.05 }
    }
}

impl Augmentation {
    pub fn none() -> Self {
        Augmentation { rotate_deg: 0.0, flip_p: 0.0, scale: 0.0 }
    }

    pub fn apply(&self, f: &Frame, rng: &mut impl Rng) -> Frame {
        let th =
            if self.rotate_deg > 0.0 { rng.random_range(-self.rotate_deg..=self.rotate_deg).to_radians() } else { 0.0 };
        let flip = self.flip_p > 0.0 && rng.random::<f32>() < self.flip_p;
        let s = if self.scale > 0.0 { rng.random_range(1.0 - self.scale..=1.0 + self.scale) } else { 1.0 };
        let (c, sn) = (th.cos(), th.sin());
        let xy = |x: f32, y: f32| {
            let y = if flip { -y } else { y };
            (c * x - sn * y, sn * x + c * y)
        };
        let mut out = f.clone();
        for p in &mut out.lidar {
            let (x, y) = xy(p[0], p[1]);
            *p = [x * s, y * s, p[2] * s, p[3]];
        }
        for p in &mut out.radar {
            let (x, y) = xy(p[0], p[1]);
            let (lx, ly) = xy(p[5], p[6]);
            *p = [x * s, y * s, p[2] * s, p[3], p[4] * s, lx, ly];
        }
        for b in &mut out.boxes {
            let (x, y) = xy(b.center[0], b.center[1]);
            let (vx, vy) = xy(b.velocity[0], b.velocity[1]);
            let yaw = if flip { -b.yaw } else { b.yaw } + th;
            *b = GtBox {
                class: b.class,
                center: [x * s, y * s, b.center[2] * s],
                wlh: b.wlh.map(|v| v * s),
                yaw,
                velocity: [vx * s, vy * s],
            };
        }
        out
    }
}

/// Pillars of one modality for a batch: decorated point features, a validity mask, and the
/// flat BEV cell index (`b · H · W + row · W + col`) of each pillar.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pillars {
    pub features: Vec<f32>,
    pub mask: Vec<f32>,
    pub index: Vec<u32>,
    /// Decorated features per point.
    pub width: usize,
    pub points_per_pillar: usize,
}

impl Pillars {
    pub fn count(&self) -> usize {
        self.index.len()
    }
}

/// Groups points into pillars and decorates each point with its offsets from the pillar's mean
/// and from the pillar's centre (PointPillars). `raw` features come first.
pub fn pillarize<const F: usize>(grid: &BevGrid, frames: &[&[[f32; F]]]) -> Pillars {
    let n = grid.cells();
    let npp = grid.max_points_per_pillar;
    let width = F + 5;
    let mut out = Pillars { width, points_per_pillar: npp, ..Pillars::default() };
    for (b, pts) in frames.iter().enumerate() {
        let mut cells: std::collections::BTreeMap<usize, Vec<usize>> = std::collections::BTreeMap::new();
        for (k, p) in pts.iter().enumerate() {
            if !(p[2] >= grid.z_min_m && p[2] <= grid.z_max_m) {
                continue;
            }
            if let Some((c, r)) = grid.cell_of(p[0], p[1]) {
                let v = cells.entry(r * n + c).or_default();
                if v.len() < npp {
                    v.push(k);
                }
            }
        }
        for (cell, members) in cells.into_iter().take(grid.max_pillars) {
            let (cx, cy) = grid.center(cell % n, cell / n);
            let m = members.len() as f32;
            let mean = members
                .iter()
                .fold([0.0f32; 3], |a, &k| [a[0] + pts[k][0] / m, a[1] + pts[k][1] / m, a[2] + pts[k][2] / m]);
            for slot in 0..npp {
                match members.get(slot) {
                    Some(&k) => {
                        let p = &pts[k];
                        out.features.extend_from_slice(p);
                        out.features.extend_from_slice(&[
                            p[0] - mean[0],
                            p[1] - mean[1],
                            p[2] - mean[2],
                            p[0] - cx,
                            p[1] - cy,
                        ]);
                        out.mask.push(1.0);
                    }
                    None => {
                        out.features.extend(std::iter::repeat_n(0.0, width));
                        out.mask.push(0.0);
                    }
                }
            }
            out.index.push((b * n * n + cell) as u32);
        }
    }
    out
}
