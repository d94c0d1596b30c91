//! Frames from a dataset, augmentation, and pillars: everything the network reads, prepared on
//! the host (and on another thread during training).
//!
//! What a frame holds is decided by the detector's [`InputConfig`]: LiDAR without its static
//! background ([`hilo_dataset::background`], learned from the training split) or whole, and the
//! radar's last `radar_sweeps` sweeps, each point carrying its sweep's time lag. The sensors are
//! static, so older sweeps need no motion compensation: a road user's older detections trail
//! behind it, which is the motion cue nuScenes detectors take from stacked sweeps.
//!
//! Radar static clutter ([`RadarClutterConfig`]) is dropped by a cross-sensor rule: a radar
//! detection that does not move (|v_r| at most `max_speed_mps`) and has no LiDAR foreground
//! point within `lidar_radius_m` in the bird's-eye view is taken as clutter. The LiDAR foreground
//! is what the background model leaves, so the rule needs it: road users seen by the LiDAR keep
//! every radar detection, moving or not, and moving ones keep theirs wherever they are. What it
//! loses: a stationary road user (or one crossing the radar's line of sight, whose v_r is near 0)
//! that no LiDAR point reaches, and a real system's clutter that moves (swaying trees, multipath
//! ghosts of moving targets), which hilo's radar does not simulate.

use crate::error::{DetectorError, Result};
use hilo_core::Class;
use hilo_dataset::Dataset;
use hilo_dataset::background::BackgroundModel;
use hilo_dataset::tables::SampleData;
pub use hilo_fusion::config::{
    Augmentation, InputConfig, LIDAR_FEATURES, RADAR_FEATURES, RadarClutterConfig, RadarPairConfig, is_radial,
    radar_point,
};
pub use hilo_fusion::pillars::{Pillars, pillarize};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// A ground-truth box in the scene's local frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GtBox {
    pub class: usize,
    pub center: [f32; 3],
    /// Width, length, height (nuScenes order).
    pub wlh: [f32; 3],
    pub yaw: f32,
    /// m/s, x y; NaN where it is unknown (an annotation without a neighbour in time: the
    /// devkit's velocity is NaN there too), which the loss leaves out rather than training
    /// the box as standing still.
    pub velocity: [f32; 2],
}

/// Gives each detection of the frame's own sweep (lag 0) that another radar also sees the full
/// ground velocity of the pair ([`hilo_sensor_models::radar_pair`]) in place of its radial
/// velocity vector (features 8 and 9); `origin[i]` is point i's radar (an index) and that
/// radar's position. Of several pairs (three radars or more) the one of least dilution wins.
/// Returns how many detections were paired.
pub fn pair_radar_velocities(
    radar: &mut [[f32; RADAR_FEATURES]],
    origin: &[(usize, [f32; 3])],
    cfg: &RadarPairConfig,
) -> usize {
    use glam::Vec3;
    use hilo_sensor_models::radar_pair::pair_velocities;
    let radars = origin.iter().map(|o| o.0 + 1).max().unwrap_or(0);
    /// One radar: its position, the indices of its own-sweep detections, and each one's
    /// (position, v_r).
    #[derive(Clone, Default)]
    struct View {
        at: Vec3,
        index: Vec<usize>,
        points: Vec<(Vec3, f32)>,
    }
    let mut views: Vec<View> = vec![View::default(); radars];
    for (i, (p, &(k, at))) in radar.iter().zip(origin).enumerate() {
        if p[7] == 0.0 {
            views[k].at = Vec3::from(at);
            views[k].index.push(i);
            views[k].points.push((Vec3::new(p[0], p[1], p[2]), p[4]));
        }
    }
    let min_angle = cfg.min_angle_deg.to_radians();
    let mut best: HashMap<usize, (f32, [f32; 2])> = HashMap::new();
    for a in 0..radars {
        for b in (0..radars).filter(|&b| b != a) {
            let (va, vb) = (&views[a], &views[b]);
            for (ia, _, v) in pair_velocities((va.at, &va.points), (vb.at, &vb.points), cfg.max_gap_m, min_angle) {
                let i = va.index[ia];
                if best.get(&i).is_none_or(|(d, _)| v.dilution < *d) {
                    best.insert(i, (v.dilution, v.velocity.to_array()));
                }
            }
        }
    }
    for (&i, (_, v)) in &best {
        radar[i][8] = v[0];
        radar[i][9] = v[1];
    }
    best.len()
}

/// Drops the radar detections of `radar` that [`RadarClutterConfig`] calls clutter, given the
/// frame's LiDAR foreground (both in the scene's local frame); returns how many it dropped.
/// LiDAR points are hashed into square buckets of the radius, so each detection looks at nine
/// buckets.
pub fn drop_radar_clutter(
    lidar: &[[f32; LIDAR_FEATURES]],
    radar: &mut Vec<[f32; RADAR_FEATURES]>,
    cfg: &RadarClutterConfig,
) -> usize {
    let keep = radar_kept(lidar, radar, cfg);
    let before = radar.len();
    let mut k = keep.iter();
    radar.retain(|_| k.next().copied().unwrap_or(true));
    before - radar.len()
}

/// Which radar detections [`drop_radar_clutter`] keeps (true), in their order.
pub fn radar_kept(
    lidar: &[[f32; LIDAR_FEATURES]],
    radar: &[[f32; RADAR_FEATURES]],
    cfg: &RadarClutterConfig,
) -> Vec<bool> {
    let r = cfg.lidar_radius_m;
    let bucket = |x: f32, y: f32| ((x / r).floor() as i64, (y / r).floor() as i64);
    let mut buckets: HashMap<(i64, i64), Vec<[f32; 2]>> = HashMap::new();
    for p in lidar {
        buckets.entry(bucket(p[0], p[1])).or_default().push([p[0], p[1]]);
    }
    let near_lidar = |x: f32, y: f32| {
        let (bx, by) = bucket(x, y);
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                buckets
                    .get(&(bx + dx, by + dy))
                    .is_some_and(|v| v.iter().any(|q| (q[0] - x) * (q[0] - x) + (q[1] - y) * (q[1] - y) <= r * r))
            })
        })
    };
    radar.iter().map(|p| p[4].abs() > cfg.max_speed_mps || near_lidar(p[0], p[1])).collect()
}

/// One sample.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Frame {
    pub sample_token: String,
    /// Name of the scene the sample belongs to.
    pub scene: String,
    pub lidar: Vec<[f32; LIDAR_FEATURES]>,
    pub radar: Vec<[f32; RADAR_FEATURES]>,
    /// Each radar point's sensor position (local frame, m) where it is known: frames loaded
    /// from a dataset have one per point; augmentation moves them with the points; a frame
    /// with pasted instances, or built by hand, has none (empty).
    pub radar_origin: Vec<[f32; 3]>,
    pub boxes: Vec<GtBox>,
}

fn quat_rotate(q: [f64; 4], p: [f64; 3]) -> [f64; 3] {
    let [w, x, y, z] = q;
    let r = glam::DQuat::from_xyzw(x, y, z, w).normalize();
    r.mul_vec3(glam::DVec3::from(p)).to_array()
}

/// How [`load_split`] reads frames. The default reads every class's boxes and nothing else.
#[derive(Clone, Copy, Debug)]
pub struct LoadOptions<'a> {
    /// LiDAR points this model calls background are left out.
    pub background: Option<&'a BackgroundModel>,
    /// Radar and LiDAR sweeps per frame (0 or 1: the frame's own) and the largest lag of an
    /// older one.
    pub radar_sweeps: usize,
    pub lidar_sweeps: usize,
    pub max_sweep_lag_s: f32,
    /// Radar static clutter is dropped by this rule (against the frame's LiDAR foreground).
    pub radar_clutter: Option<RadarClutterConfig>,
    /// Detections two radars see get their full ground velocity ([`pair_radar_velocities`]).
    pub radar_pairs: Option<RadarPairConfig>,
    /// LiDAR points closer than this to their own sensor are left out, m (0: none).
    pub lidar_min_range_m: f32,
    /// Boxes that no LiDAR point of their key frame hit but a radar detection did are kept. True
    /// for a detector that reads radar; a LiDAR-only detector is not trained to find road users
    /// only the radar saw (on a radar rig it would otherwise learn from boxes it cannot see, and
    /// its score at the same LiDAR poses would depend on whether a radar hangs beside them).
    pub radar_only_boxes: bool,
    /// Boxes of the first this many classes of [`Class::ALL`] are kept (a detector's head
    /// classes, [`hilo_fusion::DetectorConfig::classes`]); others are not loaded.
    pub classes: usize,
}

impl Default for LoadOptions<'_> {
    fn default() -> Self {
        LoadOptions {
            background: None,
            radar_sweeps: 0,
            lidar_sweeps: 0,
            max_sweep_lag_s: 0.0,
            radar_clutter: None,
            radar_pairs: None,
            lidar_min_range_m: 0.0,
            radar_only_boxes: false,
            classes: Class::ALL.len(),
        }
    }
}

impl<'a> LoadOptions<'a> {
    /// The options of a detector's input, with its learned background model; `uses_radar`:
    /// whether the detector reads radar ([`LoadOptions::radar_only_boxes`]).
    pub fn new(input: &InputConfig, background: Option<&'a BackgroundModel>, uses_radar: bool) -> Self {
        LoadOptions {
            background,
            radar_sweeps: input.radar_sweeps,
            lidar_sweeps: input.lidar_sweeps,
            max_sweep_lag_s: input.max_sweep_lag_s,
            radar_clutter: input.radar_clutter,
            radar_pairs: input.radar_pairs,
            lidar_min_range_m: input.lidar_min_range_m,
            radar_only_boxes: uses_radar,
            classes: Class::ALL.len(),
        }
    }

    /// The options of detector `cfg`'s input: [`LoadOptions::new`] with whether the registry's
    /// plugin reads radar, keeping the boxes of the classes its head detects.
    pub fn of(
        cfg: &hilo_fusion::DetectorConfig,
        registry: &hilo_fusion::Registry,
        background: Option<&'a BackgroundModel>,
    ) -> Self {
        LoadOptions { classes: cfg.classes().len(), ..Self::new(&cfg.input, background, registry.uses_radar(cfg)) }
    }
}

/// What loading dropped or kept, for logs and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct LoadStats {
    pub frames: usize,
    pub lidar_points: usize,
    /// LiDAR points removed as background.
    pub background_points: usize,
    /// LiDAR points removed as too near their sensor ([`LoadOptions::lidar_min_range_m`]).
    pub near_points: usize,
    pub radar_points: usize,
    /// Radar points from older sweeps (included in `radar_points`).
    pub older_sweep_points: usize,
    /// Radar points dropped as static clutter (not in `radar_points`).
    pub radar_clutter_points: usize,
    /// Radar detections given a full velocity by a second radar.
    pub radar_paired_points: usize,
    /// Boxes kept (some sensor of the rig hit them).
    pub boxes: usize,
    /// Boxes only a radar hit, left out for a detector that reads no radar
    /// ([`LoadOptions::radar_only_boxes`]; not in `boxes`).
    pub radar_only_boxes: usize,
}

impl LoadStats {
    /// What the input rules removed, one line each, as `hilo train` reports them: the LiDAR
    /// points of the static background (when a model was learned) and the radar's static
    /// clutter (when the rule is on and there were radar points), the LiDAR points too near
    /// their sensor and the boxes left out as only a radar's (when there were any).
    pub fn notes(&self, background: bool, radar_clutter: bool) -> Vec<String> {
        let share = |part: usize, of: usize| 100.0 * part as f64 / of.max(1) as f64;
        let mut notes = Vec::new();
        if self.near_points > 0 {
            let of = self.near_points + self.background_points + self.lidar_points;
            notes.push(format!(
                "near-range LiDAR points removed: {} of {of} ({:.1}%)",
                self.near_points,
                share(self.near_points, of)
            ));
        }
        if background {
            let of = self.background_points + self.lidar_points;
            notes.push(format!(
                "static background removed: {} of {of} LiDAR points ({:.1}%)",
                self.background_points,
                share(self.background_points, of)
            ));
        }
        let of = self.radar_points + self.radar_clutter_points;
        if radar_clutter && of > 0 {
            notes.push(format!(
                "radar static clutter removed: {} of {of} radar points ({:.1}%)",
                self.radar_clutter_points,
                share(self.radar_clutter_points, of)
            ));
        }
        if self.radar_paired_points > 0 {
            notes.push(format!(
                "radar points paired with another radar's for their full ground velocity: {} of {of} ({:.1}%)",
                self.radar_paired_points,
                share(self.radar_paired_points, of)
            ));
        }
        if self.radar_only_boxes > 0 {
            let of = self.boxes + self.radar_only_boxes;
            notes.push(format!(
                "boxes only a radar hit, left out (the detector reads no radar): {} of {of} ({:.1}%)",
                self.radar_only_boxes,
                share(self.radar_only_boxes, of)
            ));
        }
        notes
    }
}

/// Refuses a detector that fuses radar (`uses_radar`) on a dataset with no radar channel: its
/// radar branch would train and run on empty input, and its scores read as a fusion result.
pub fn check_modalities(ds: &Dataset, detector: &str, uses_radar: bool) -> std::result::Result<(), DetectorError> {
    let has = |m: &str| ds.tables.sensor.iter().any(|s| s.modality == m);
    if uses_radar && !has("radar") {
        return Err(DetectorError::Config(format!(
            "detector {detector} fuses radar, but the dataset {} has no radar channel (sensors: {}); use a LiDAR-only preset such as centerpoint",
            ds.root.display(),
            ds.tables.sensor.iter().map(|s| s.channel.as_str()).collect::<Vec<_>>().join(", ")
        )));
    }
    if !has("lidar") {
        return Err(DetectorError::Config(format!(
            "the dataset {} has no LiDAR channel; every detector needs one",
            ds.root.display()
        )));
    }
    Ok(())
}

/// Loads the samples of a split (scenes listed in the dataset's `splits.json`), in sample order.
/// Boxes that no point of the detector's sensors hit are left out, as nuScenes' loaders do
/// ([`LoadOptions::radar_only_boxes`]: a LiDAR-only detector keeps the boxes with a LiDAR point).
pub fn load_split(ds: &Dataset, split: &str, opts: &LoadOptions) -> Result<(Vec<Frame>, LoadStats)> {
    load_samples(ds, split, opts, None)
}

/// The `index`-th frame of a split (in [`load_split`]'s order) alone, or `None` past its end.
pub fn load_split_frame(ds: &Dataset, split: &str, opts: &LoadOptions, index: usize) -> Result<Option<Frame>> {
    Ok(load_samples(ds, split, opts, Some(index))?.0.pop())
}

/// A key frame's sample_data and the `count − 1` sweeps before it on its channel (by `prev`
/// links), newest first, each with its lag behind the key frame (s); an older sweep more than
/// `max_lag_s` behind ends the chain.
fn sweeps<'a>(
    key: &'a SampleData,
    count: usize,
    max_lag_s: f32,
    by_token: &HashMap<&str, &'a SampleData>,
) -> Vec<(&'a SampleData, f32)> {
    let mut chain = Vec::new();
    let mut sweep = Some(key);
    while let Some(cur) = sweep.filter(|_| chain.len() < count.max(1)) {
        let lag = 1e-6 * key.timestamp.saturating_sub(cur.timestamp) as f32;
        if !chain.is_empty() && lag > max_lag_s {
            break;
        }
        chain.push((cur, lag));
        sweep = by_token.get(cur.prev.as_str()).copied().filter(|_| !cur.prev.is_empty());
    }
    chain
}

/// Over the whole split (one frame loaded alone is refused alike): the dataset's LiDAR sweep
/// period is the shortest gap between a LiDAR record and the one before it on its channel;
/// stacking where the split's key-frame records lie farther apart (key frames only) would feed
/// one split older points than another. Of the gaps behind the key frames, those a stack would
/// bridge count (a longer one ends the stack anyway), and their median: an occasional dropped
/// sweep is no matter.
fn check_lidar_sweeps(
    ds: &Dataset,
    split: &str,
    opts: &LoadOptions,
    samples: &[&hilo_dataset::tables::Sample],
    by_sample: &HashMap<&str, Vec<&SampleData>>,
    sd_by_token: &HashMap<&str, &SampleData>,
    is_lidar: &dyn Fn(&SampleData) -> bool,
) -> Result<()> {
    let gap_behind =
        |sd: &SampleData| sd_by_token.get(sd.prev.as_str()).map(|p| sd.timestamp.saturating_sub(p.timestamp));
    let period = ds.tables.sample_data.iter().filter(|sd| is_lidar(sd)).filter_map(gap_behind).filter(|&g| g > 0).min();
    let Some(period) = period else { return Ok(()) };
    let max_lag_us = 1e6 * opts.max_sweep_lag_s as f64;
    let mut gaps: Vec<u64> = samples
        .iter()
        .flat_map(|s| by_sample.get(s.token.as_str()).into_iter().flatten())
        .filter(|sd| is_lidar(sd))
        .filter_map(|sd| gap_behind(sd))
        .filter(|&gap| gap as f64 <= max_lag_us)
        .collect();
    gaps.sort_unstable();
    match gaps.get(gaps.len() / 2) {
        Some(&median) if median as f64 > 1.5 * period as f64 => Err(DetectorError::Config(format!(
            "input.lidar_sweeps = {} stacks LiDAR sweeps, but the dataset {} has LiDAR only at the key frames of split {split:?} (a median {:.2} s apart, against sweeps every {:.2} s elsewhere): record it with `[dataset] lidar_sweeps = true`",
            opts.lidar_sweeps,
            ds.root.display(),
            1e-6 * median as f64,
            1e-6 * period as f64
        ))),
        _ => Ok(()),
    }
}

fn load_samples(ds: &Dataset, split: &str, opts: &LoadOptions, only: Option<usize>) -> Result<(Vec<Frame>, LoadStats)> {
    let scenes: std::collections::HashSet<String> = ds.split(split).map_err(DetectorError::from)?.into_iter().collect();
    let t = &ds.tables;
    let scene_name: HashMap<&str, &str> =
        t.scene.iter().filter(|s| scenes.contains(&s.name)).map(|s| (s.token.as_str(), s.name.as_str())).collect();
    let calib: HashMap<&str, &hilo_dataset::tables::CalibratedSensor> =
        t.calibrated_sensor.iter().map(|c| (c.token.as_str(), c)).collect();
    let sensors: HashMap<&str, &hilo_dataset::tables::Sensor> =
        t.sensor.iter().map(|s| (s.token.as_str(), s)).collect();
    let sd_by_token: HashMap<&str, &SampleData> = t.sample_data.iter().map(|s| (s.token.as_str(), s)).collect();
    let category: HashMap<&str, &str> = t.category.iter().map(|c| (c.token.as_str(), c.name.as_str())).collect();
    let instance_class: HashMap<&str, Option<Class>> = t
        .instance
        .iter()
        .map(|i| {
            let cat = category.get(i.category_token.as_str()).copied().unwrap_or("");
            (i.token.as_str(), hilo_dataset::writer::class_of_category(cat))
        })
        .collect();
    let mut by_sample: HashMap<&str, Vec<&SampleData>> = HashMap::new();
    for sd in t.sample_data.iter().filter(|sd| sd.is_key_frame) {
        by_sample.entry(sd.sample_token.as_str()).or_default().push(sd);
    }
    let mut anns: HashMap<&str, Vec<&hilo_dataset::tables::SampleAnnotation>> = HashMap::new();
    for a in &t.sample_annotation {
        anns.entry(a.sample_token.as_str()).or_default().push(a);
    }
    let mut samples: Vec<&hilo_dataset::tables::Sample> =
        t.sample.iter().filter(|s| scene_name.contains_key(s.scene_token.as_str())).collect();
    samples.sort_by(|a, b| (a.scene_token.as_str(), a.timestamp).cmp(&(b.scene_token.as_str(), b.timestamp)));
    if opts.lidar_sweeps > 1 {
        let is_lidar = |sd: &SampleData| {
            calib
                .get(sd.calibrated_sensor_token.as_str())
                .and_then(|c| sensors.get(c.sensor_token.as_str()))
                .is_some_and(|x| x.modality == "lidar")
        };
        check_lidar_sweeps(ds, split, opts, &samples, &by_sample, &sd_by_token, &is_lidar)?;
    }
    if let Some(i) = only {
        samples = samples.get(i).copied().into_iter().collect();
    }
    let mut stats = LoadStats { frames: samples.len(), ..LoadStats::default() };
    let mut frames = Vec::with_capacity(samples.len());
    for s in samples {
        let mut lidar = Vec::new();
        let mut radar = Vec::new();
        // Per radar point, its radar (index into `radar_channels`) and that radar's position.
        let mut radar_origin: Vec<(usize, [f32; 3])> = Vec::new();
        let mut radar_channels: Vec<String> = Vec::new();
        let mut sds = by_sample.get(s.token.as_str()).cloned().unwrap_or_default();
        sds.sort_by(|a, b| a.filename.cmp(&b.filename));
        for sd in sds {
            let Some(c) = calib.get(sd.calibrated_sensor_token.as_str()) else { continue };
            let sensor = sensors.get(c.sensor_token.as_str());
            let modality = sensor.map(|x| x.modality.as_str()).unwrap_or("");
            let channel = sensor.map(|x| x.channel.as_str()).unwrap_or("");
            let to_local = |p: [f64; 3]| {
                let r = quat_rotate(c.rotation, p);
                [(r[0] + c.translation[0]) as f32, (r[1] + c.translation[1]) as f32, (r[2] + c.translation[2]) as f32]
            };
            match modality {
                "lidar" => {
                    for (cur, lag) in sweeps(sd, opts.lidar_sweeps, opts.max_sweep_lag_s, &sd_by_token) {
                        let mut points = ds.lidar_points(cur).map_err(DetectorError::from)?;
                        if opts.lidar_min_range_m > 0.0 {
                            let before = points.len();
                            let r2 = opts.lidar_min_range_m * opts.lidar_min_range_m;
                            points.retain(|p| p.x * p.x + p.y * p.y + p.z * p.z >= r2);
                            stats.near_points += before - points.len();
                        }
                        let n = points.len();
                        let points = match opts.background {
                            Some(m) => m.foreground(channel, points),
                            None => points,
                        };
                        stats.lidar_points += points.len();
                        stats.background_points += n - points.len();
                        for p in points {
                            let q = to_local([p.x as f64, p.y as f64, p.z as f64]);
                            lidar.push([q[0], q[1], q[2], p.intensity, lag]);
                        }
                    }
                }
                "radar" => {
                    let at = c.translation.map(|v| v as f32);
                    let k = radar_channels.iter().position(|ch| ch == channel).unwrap_or_else(|| {
                        radar_channels.push(channel.to_owned());
                        radar_channels.len() - 1
                    });
                    for (cur, lag) in sweeps(sd, opts.radar_sweeps, opts.max_sweep_lag_s, &sd_by_token) {
                        for p in ds.radar_points(cur).map_err(DetectorError::from)? {
                            let q = to_local([p.x as f64, p.y as f64, p.z as f64]);
                            let (dx, dy) = (q[0] - at[0], q[1] - at[1]);
                            let n = (dx * dx + dy * dy).sqrt().max(1e-6);
                            radar.push(radar_point([q[0], q[1], q[2]], p.rcs_dbsm, p.v_r_mps, [dx / n, dy / n], lag));
                            radar_origin.push((k, at));
                            stats.radar_points += 1;
                        }
                    }
                }
                _ => {}
            }
        }
        if let Some(c) = &opts.radar_pairs {
            stats.radar_paired_points += pair_radar_velocities(&mut radar, &radar_origin, c);
        }
        if let Some(c) = &opts.radar_clutter {
            // Against the frame's own LiDAR sweep: older sweeps' points lie where road users were.
            let own: Vec<[f32; LIDAR_FEATURES]> = lidar.iter().filter(|p| p[4] == 0.0).copied().collect();
            let keep = radar_kept(&own, &radar, c);
            let dropped = keep.iter().filter(|k| !**k).count();
            (radar, radar_origin) =
                radar.into_iter().zip(radar_origin).zip(keep).filter(|(_, k)| *k).map(|(pair, _)| pair).unzip();
            stats.radar_points -= dropped;
            stats.radar_clutter_points += dropped;
        }
        // Older sweeps' points carry a positive lag (their timestamps are earlier).
        stats.older_sweep_points += radar.iter().filter(|p| p[7] > 0.0).count();
        let mut boxes = Vec::new();
        for a in anns.get(s.token.as_str()).cloned().unwrap_or_default() {
            let Some(Some(class)) = instance_class.get(a.instance_token.as_str()) else { continue };
            if class.index() >= opts.classes {
                continue;
            }
            if a.num_lidar_pts == 0 && !(opts.radar_only_boxes && a.num_radar_pts > 0) {
                stats.radar_only_boxes += usize::from(a.num_radar_pts > 0);
                continue;
            }
            stats.boxes += 1;
            let k = class.index();
            let [w, x, y, z] = a.rotation;
            let yaw = (2.0 * (x * y + w * z)).atan2(1.0 - 2.0 * (y * y + z * z)) as f32;
            let v = ds.box_velocity(a);
            let velocity =
                if v[0].is_finite() && v[1].is_finite() { [v[0] as f32, v[1] as f32] } else { [f32::NAN; 2] };
            boxes.push(GtBox {
                class: k,
                center: a.translation.map(|v| v as f32),
                wlh: a.size.map(|v| v as f32),
                yaw,
                velocity,
            });
        }
        let scene = scene_name.get(s.scene_token.as_str()).copied().unwrap_or_default().to_owned();
        let radar_origin = radar_origin.iter().map(|&(_, at)| at).collect();
        frames.push(Frame { sample_token: s.token.clone(), scene, lidar, radar, radar_origin, boxes });
    }
    Ok((frames, stats))
}

/// A frame under a random draw of `aug` (rotation about the scene origin, mirror, scale). With
/// `keep_site_p` > 0 a draw either keeps the site's geometry (a small rotation, no mirror) or
/// takes the full rotation and mirror with its boxes' velocities unknown.
pub fn augment(aug: &Augmentation, f: &Frame, rng: &mut impl Rng) -> Frame {
    let keep_site = aug.keep_site_p > 0.0 && rng.random::<f32>() < aug.keep_site_p;
    let (rotate_deg, flip_p) = if keep_site { (aug.keep_site_rotate_deg, 0.0) } else { (aug.rotate_deg, aug.flip_p) };
    let forget_velocity = aug.keep_site_p > 0.0 && !keep_site;
    let th = if rotate_deg > 0.0 { rng.random_range(-rotate_deg..=rotate_deg).to_radians() } else { 0.0 };
    let flip = flip_p > 0.0 && rng.random::<f32>() < flip_p;
    let s = if aug.scale > 0.0 { rng.random_range(1.0 - aug.scale..=1.0 + aug.scale) } else { 1.0 };
    let (c, sn) = (th.cos(), th.sin());
    let xy = |x: f32, y: f32| {
        let y = if flip { -y } else { y };
        (c * x - sn * y, sn * x + c * y)
    };
    let mut out = f.clone();
    for p in &mut out.lidar {
        let (x, y) = xy(p[0], p[1]);
        *p = [x * s, y * s, p[2] * s, p[3], p[4]];
    }
    for p in &mut out.radar {
        let (x, y) = xy(p[0], p[1]);
        let (lx, ly) = xy(p[5], p[6]);
        // A paired detection's velocity vector (`pair_radar_velocities`) turns as a vector; a
        // radial one is rebuilt from v_r and the line of sight, bit for bit as before.
        let radial = is_radial(p);
        let (vx, vy) = xy(p[8], p[9]);
        *p = radar_point([x * s, y * s, p[2] * s], p[3], p[4] * s, [lx, ly], p[7]);
        if !radial {
            (p[8], p[9]) = (vx * s, vy * s);
        }
    }
    for o in &mut out.radar_origin {
        let (x, y) = xy(o[0], o[1]);
        *o = [x * s, y * s, o[2] * s];
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
            velocity: if forget_velocity { [f32::NAN; 2] } else { [vx * s, vy * s] },
        };
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// The clutter rule against a brute-force oracle (every radar point against every LiDAR
    /// point), on seeded random points spread over negative and positive coordinates, with hard
    /// cases on purpose: a LiDAR point at exactly the radius, one just beyond it, a moving
    /// detection far from any LiDAR point, a detection at exactly the speed limit.
    #[test]
    fn radar_clutter_rule_matches_a_brute_force_oracle() {
        let cfg = RadarClutterConfig { max_speed_mps: 0.15, lidar_radius_m: 1.0 };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut lidar: Vec<[f32; LIDAR_FEATURES]> =
            (0..400).map(|_| [rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0), 0.5, 0.2, 0.0]).collect();
        let mut radar: Vec<[f32; RADAR_FEATURES]> = (0..600)
            .map(|_| {
                let v = if rng.random::<f32>() < 0.5 { 0.0 } else { rng.random_range(-5.0..5.0) };
                let (x, y) = (rng.random_range(-32.0..32.0), rng.random_range(-32.0..32.0));
                radar_point([x, y, 1.0], 5.0, v, [1.0, 0.0], 0.0)
            })
            .collect();
        // Hard cases: LiDAR at (40, -40.5); radar exactly 1 m away (kept), 1.001 m away (dropped),
        // a fast one 10 m from everything (kept), one at exactly the speed limit (static: dropped).
        lidar.push([40.0, -40.5, 0.0, 0.0, 0.0]);
        radar.push(radar_point([40.0, -39.5, 0.0], 0.0, 0.0, [1.0, 0.0], 0.0));
        radar.push(radar_point([41.001, -40.5, 0.0], 0.0, 0.0, [1.0, 0.0], 0.0));
        radar.push(radar_point([60.0, 60.0, 0.0], 0.0, 3.0, [1.0, 0.0], 0.0));
        radar.push(radar_point([-60.0, 60.0, 0.0], 0.0, -0.15, [1.0, 0.0], 0.0));
        let oracle: Vec<[f32; RADAR_FEATURES]> = radar
            .iter()
            .filter(|p| {
                p[4].abs() > cfg.max_speed_mps
                    || lidar.iter().any(|q| (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) <= cfg.lidar_radius_m.powi(2))
            })
            .copied()
            .collect();
        let n = radar.len();
        let mut kept = radar.clone();
        let dropped = drop_radar_clutter(&lidar, &mut kept, &cfg);
        assert_eq!(kept, oracle, "the kept detections, in their order");
        assert_eq!(dropped, n - oracle.len());
        assert!(dropped > 50 && oracle.len() > 300, "both outcomes exercised ({dropped} dropped)");
        let tail: Vec<[f32; RADAR_FEATURES]> = kept.iter().rev().take(2).rev().copied().collect();
        assert_eq!(tail[1], radar[n - 2], "the fast detection far from the LiDAR is kept");
        assert_eq!(tail[0], radar[n - 4], "the detection exactly at the radius is kept");
        // No LiDAR at all: every static detection goes, every moving one stays.
        let mut alone = radar.clone();
        drop_radar_clutter(&[], &mut alone, &cfg);
        assert!(alone.iter().all(|p| p[4].abs() > cfg.max_speed_mps));
        assert_eq!(alone.len(), radar.iter().filter(|p| p[4].abs() > cfg.max_speed_mps).count());
    }

    /// Two radars 90° apart around a car moving at (4, 3) m/s: every own-sweep detection near
    /// the car gets (4, 3) in place of its radial vector; a detection only one radar sees, and
    /// an older sweep's, keep theirs. Augmented, a paired vector turns with the frame and a
    /// radial one is rebuilt exactly as before; bad pair settings are refused by field.
    #[test]
    fn two_radars_give_detections_their_full_velocity() {
        let v = [4.0f32, 3.0];
        let at = [[-20.0f32, 0.0, 1.5], [0.0, -20.0, 1.5]];
        let mut radar = Vec::new();
        let mut origin = Vec::new();
        let point = |k: usize, p: [f32; 3], lag: f32| {
            let d = [p[0] - at[k][0], p[1] - at[k][1], p[2] - at[k][2]];
            let n3 = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let vr = (d[0] * v[0] + d[1] * v[1]) / n3;
            let n = (d[0] * d[0] + d[1] * d[1]).sqrt();
            radar_point(p, 5.0, vr, [d[0] / n, d[1] / n], lag)
        };
        for (k, p, lag) in [
            (0, [0.1, 0.2, 0.8], 0.0),
            (0, [-0.4, 0.5, 0.6], 0.0),
            (1, [0.3, -0.1, 0.9], 0.0),
            (1, [-0.2, 0.6, 0.7], 0.0),
            (0, [15.0, 15.0, 0.5], 0.0),
            (0, [0.0, 0.1, 0.8], 0.1),
        ] {
            radar.push(point(k, p, lag));
            origin.push((k, at[k]));
        }
        let before = radar.clone();
        let paired = pair_radar_velocities(&mut radar, &origin, &RadarPairConfig::default());
        assert_eq!(paired, 4);
        for p in &radar[..4] {
            assert!((p[8] - v[0]).abs() < 1e-3 && (p[9] - v[1]).abs() < 1e-3, "{p:?}");
        }
        assert_eq!(&radar[4..], &before[4..], "one radar's, and an older sweep's, keep the radial vector");
        // Augmentation: a turn of up to 90°, no mirror, no scale.
        let f = Frame {
            sample_token: "t".into(),
            scene: "s".into(),
            lidar: Vec::new(),
            radar: radar.clone(),
            radar_origin: Vec::new(),
            boxes: Vec::new(),
        };
        let aug = Augmentation { rotate_deg: 90.0, ..Augmentation::none() };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let out = augment(&aug, &f, &mut rng);
        for (a, b) in out.radar.iter().zip(&radar) {
            // The turn the positions took, applied to the velocity vector.
            let th = a[1].atan2(a[0]) - b[1].atan2(b[0]);
            let (c, s) = (th.cos(), th.sin());
            let want = [c * b[8] - s * b[9], s * b[8] + c * b[9]];
            assert!((a[8] - want[0]).abs() < 1e-3 && (a[9] - want[1]).abs() < 1e-3, "{a:?} {b:?}");
        }
        for (a, b) in out.radar[4..].iter().zip(&radar[4..]) {
            let rebuilt = radar_point([a[0], a[1], a[2]], b[3], b[4], [a[5], a[6]], b[7]);
            assert_eq!(a, &rebuilt);
        }
        let input = InputConfig {
            radar_pairs: Some(RadarPairConfig { min_angle_deg: 0.0, ..RadarPairConfig::default() }),
            ..InputConfig::default()
        };
        let e = input.validate().unwrap_err().to_string();
        assert!(e.contains("input.radar_pairs.min_angle_deg"), "{e}");
    }

    #[test]
    fn radar_clutter_needs_the_lidar_background_and_sane_values() {
        let mut input = crate::presets::default_input();
        assert!(input.validate().is_ok());
        input.background = None;
        let e = input.validate().unwrap_err().to_string();
        assert!(e.contains("input.background = (not given): input.radar_clutter needs it"), "{e}");
        let mut input = crate::presets::default_input();
        input.radar_clutter = Some(RadarClutterConfig { lidar_radius_m: 0.0, ..RadarClutterConfig::default() });
        let e = input.validate().unwrap_err().to_string();
        assert!(e.contains("input.radar_clutter.lidar_radius_m = 0"), "{e}");
        input.radar_clutter = Some(RadarClutterConfig { max_speed_mps: f32::NAN, ..RadarClutterConfig::default() });
        let e = input.validate().unwrap_err().to_string();
        assert!(e.contains("input.radar_clutter.max_speed_mps = NaN"), "{e}");
    }

    /// Augmentation turns a radar point's radial velocity vector with its line of sight and
    /// scales it with v_r: the vector stays v_r times the line of sight, and the box's
    /// velocity projected on the line of sight stays v_r (rotation, mirror and scale together).
    #[test]
    fn augmentation_keeps_the_radial_velocity_vector_consistent() {
        let aug = Augmentation::default();
        let (lx, ly) = (0.6f32, 0.8f32);
        let velocity = [3.0f32, -4.0];
        let v_r = velocity[0] * lx + velocity[1] * ly;
        let frame = Frame {
            sample_token: "s".into(),
            scene: "a".into(),
            lidar: Vec::new(),
            radar: vec![radar_point([10.0, 5.0, 1.0], 3.0, v_r, [lx, ly], 0.0)],
            radar_origin: Vec::new(),
            boxes: vec![GtBox { class: 0, center: [10.0, 5.0, 1.0], wlh: [1.9, 4.6, 1.6], yaw: 0.3, velocity }],
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for _ in 0..20 {
            let f = augment(&aug, &frame, &mut rng);
            let p = f.radar[0];
            assert!((p[8] - p[4] * p[5]).abs() < 1e-5 && (p[9] - p[4] * p[6]).abs() < 1e-5, "{p:?}");
            assert!((p[5].hypot(p[6]) - 1.0).abs() < 1e-5, "the line of sight stays a unit vector");
            let v = f.boxes[0].velocity;
            assert!((v[0] * p[5] + v[1] * p[6] - p[4]).abs() < 1e-4, "{v:?} {p:?}");
        }
    }

    /// With `keep_site_p`, a draw either keeps the site (turned by at most
    /// `keep_site_rotate_deg`, never mirrored, velocity kept and turned) or takes the full turn
    /// and mirror with its velocity unknown; the share of the first within binomial bounds.
    /// Without it, the draws are those of the plain augmentation, bit for bit.
    #[test]
    fn keeping_the_site_teaches_velocity_only_in_the_sites_geometry() {
        let frame = Frame {
            sample_token: "s".into(),
            scene: "a".into(),
            lidar: vec![[10.0, 5.0, 1.0, 0.2, 0.0]],
            radar: Vec::new(),
            radar_origin: Vec::new(),
            boxes: vec![GtBox {
                class: 0,
                center: [10.0, 5.0, 1.0],
                wlh: [1.9, 4.6, 1.6],
                yaw: 0.3,
                velocity: [3.0, -4.0],
            }],
        };
        let aug = Augmentation { keep_site_p: 0.3, ..Augmentation::default() };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let n = 4_000;
        let (mut kept, mut wide_forgotten) = (0, 0);
        for _ in 0..n {
            let f = augment(&aug, &frame, &mut rng);
            let (b, p) = (&f.boxes[0], f.lidar[0]);
            // The turn and mirror the draw took, from the point: a mirror flips the sign of the
            // cross product of (10, 5) with its image direction relative to the turn.
            let turn = (p[1].atan2(p[0]) - 5.0f32.atan2(10.0)).to_degrees();
            let turn = (turn + 540.0).rem_euclid(360.0) - 180.0;
            if b.velocity.iter().all(|v| v.is_finite()) {
                kept += 1;
                assert!(turn.abs() <= 15.0 + 1e-3, "a site-keeping draw turned by {turn}°");
                // Unmirrored: the yaw turned by the same angle as the position.
                let dyaw = ((b.yaw - 0.3).to_degrees() - turn + 540.0).rem_euclid(360.0) - 180.0;
                assert!(dyaw.abs() < 1e-2, "mirrored or turned apart: {dyaw}");
                let speed = b.velocity[0].hypot(b.velocity[1]) / (p[0].hypot(p[1]) / 10.0f32.hypot(5.0));
                assert!((speed - 5.0).abs() < 1e-3, "{speed}");
            } else {
                assert!(b.velocity.iter().all(|v| v.is_nan()), "{:?}", b.velocity);
                wide_forgotten += usize::from(turn.abs() > 15.0);
            }
        }
        let (p, sd) = (0.3 * n as f64, (n as f64 * 0.3 * 0.7).sqrt());
        assert!((kept as f64 - p).abs() < 4.0 * sd, "{kept} of {n} kept the site");
        assert!(wide_forgotten > (n - kept) * 3 / 4, "the others turn freely: {wide_forgotten}");
        // Off (0), the draws are the plain augmentation's, bit for bit.
        let plain = Augmentation::default();
        let off = Augmentation { keep_site_p: 0.0, keep_site_rotate_deg: 40.0, ..Augmentation::default() };
        let (mut r1, mut r2) = (rand_chacha::ChaCha8Rng::seed_from_u64(2), rand_chacha::ChaCha8Rng::seed_from_u64(2));
        for _ in 0..50 {
            let (a, b) = (augment(&plain, &frame, &mut r1), augment(&off, &frame, &mut r2));
            assert_eq!((a.lidar, a.boxes[0].velocity), (b.lidar, b.boxes[0].velocity));
        }
        let bad = Augmentation { keep_site_p: 1.5, ..Augmentation::default() };
        let e = bad.check().unwrap_err().to_string();
        assert!(e.contains("augmentation.keep_site_p") && e.contains("1.5"), "{e}");
        let bad = Augmentation { rotate_deg: f32::NAN, ..Augmentation::default() };
        assert!(bad.check().unwrap_err().to_string().contains("augmentation.rotate_deg"));
        // The default's text and JSON do not name the share (stage hashes and run.json keep theirs).
        assert_eq!(format!("{plain:?}"), "Augmentation { rotate_deg: 180.0, flip_p: 0.5, scale: 0.05 }");
        assert_eq!(serde_json::to_string(&plain).unwrap(), r#"{"rotate_deg":180.0,"flip_p":0.5,"scale":0.05}"#);
    }
}
