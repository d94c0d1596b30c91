//! Writes a dataset in the nuScenes v1.0 layout: `<root>/<version>/*.json` tables and
//! `<root>/samples/<CHANNEL>/*` point files.
//!
//! Roadside conventions: the global frame is the scene's local frame; every ego pose is the
//! identity (the "ego" is the intersection's origin, so the devkit's range filter measures from
//! it); each sensor's calibrated pose is its mount pose. LiDAR files are nuScenes `.pcd.bin`
//! (float32 x, y, z, intensity, ring, in the sensor frame; nuScenes has no per-point time, so
//! point timestamps are not written: the sample_data timestamp is the start of the sweep). Radar
//! files are nuScenes radar PCD with its 18 fields
//! ([`hilo_sensor_models::export::to_nuscenes_radar_pcd`]: the radial velocity as its sensor-frame
//! `vx, vy` components). Tokens are 32 hex digits derived from names, so the same input gives
//! the same bytes; every file is written atomically.

use crate::error::DatasetError;
use crate::tables::*;
use glam::Vec2;
use hilo_core::fs::write_atomic;
use hilo_core::{Box3, Class, LidarPoint, RadarPoint};
use hilo_sensor_models::SensorPose;
use hilo_sensor_models::export::to_nuscenes_radar_pcd;
use std::path::{Path, PathBuf};

/// Which kind of sensor a channel is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorModality {
    Lidar,
    Radar,
}

/// One sensor of the dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorSetup {
    /// Unique channel name, e.g. "LIDAR_0".
    pub channel: String,
    pub modality: SensorModality,
    pub pose: SensorPose,
}

/// One annotated road user in one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Annotation {
    /// Stable within the scene.
    pub instance: u32,
    pub class: Class,
    pub box3: Box3,
    pub velocity_mps: Vec2,
    /// nuScenes attribute name or empty.
    pub attribute: String,
    pub num_lidar_pts: u32,
    pub num_radar_pts: u32,
    /// nuScenes visibility level 1..=4 (0–40%, 40–60%, 60–80%, 80–100%).
    pub visibility: u8,
}

/// One frame: timestamp, each sensor's points (in the order of the dataset's sensors of that
/// modality), annotations.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameData {
    pub timestamp_us: u64,
    pub lidar: Vec<Vec<LidarPoint>>,
    pub radar: Vec<Vec<RadarPoint>>,
    pub annotations: Vec<Annotation>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct SceneData {
    pub name: String,
    pub description: String,
    /// Key frames: every sensor, annotated.
    pub frames: Vec<FrameData>,
    /// Sweeps between key frames (nuScenes' non-key-frame sample_data), in time order: what a
    /// detector stacks to see motion when key frames are far apart.
    pub sweeps: Vec<Sweep>,
}

/// One sweep at a time without a key frame: each radar's points, in the order of the dataset's
/// radar sensors, and each LiDAR's in the order of its LiDARs (or none: the LiDARs scanned at
/// key frames only).
#[derive(Clone, Debug, PartialEq)]
pub struct Sweep {
    pub timestamp_us: u64,
    pub lidar: Vec<Vec<LidarPoint>>,
    pub radar: Vec<Vec<RadarPoint>>,
}

/// nuScenes category name of a class.
pub fn category_name(c: Class) -> &'static str {
    match c {
        Class::Car => "vehicle.car",
        Class::Truck => "vehicle.truck",
        Class::Bus => "vehicle.bus.rigid",
        Class::Motorcycle => "vehicle.motorcycle",
        Class::Pedestrian => "human.pedestrian.adult",
        Class::GolfCart => "vehicle.golf_cart",
        Class::Bicycle => "vehicle.bicycle",
    }
}

/// The class of a category name (inverse of [`category_name`]).
pub fn class_of_category(name: &str) -> Option<Class> {
    Class::ALL.into_iter().find(|c| category_name(*c) == name)
}

pub const ATTRIBUTES: [&str; 6] = [
    "vehicle.moving",
    "vehicle.stopped",
    "vehicle.parked",
    "pedestrian.moving",
    "pedestrian.standing",
    "cycle.with_rider",
];

/// FNV-1a over `bytes` from the offset basis `basis`, each step's product rotated left by
/// `rotate` bits (0: plain FNV-1a).
fn fnv1a(bytes: impl Iterator<Item = u8>, basis: u64, rotate: u32) -> u64 {
    bytes.fold(basis, |h, byte| (h ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3).rotate_left(rotate))
}

/// FNV-1a (64 bits, the standard offset basis) of a name: a stable number for it, the same in
/// every build.
pub fn name_hash(name: &str) -> u64 {
    fnv1a(name.bytes(), 0xcbf2_9ce4_8422_2325, 0)
}

/// A 32-hex-digit token from names (two independent 64-bit FNV-1a hashes).
pub fn token(parts: &[&str]) -> String {
    let bytes = || parts.iter().flat_map(|p| p.bytes().chain([0x1f]));
    let a = fnv1a(bytes(), 0xcbf2_9ce4_8422_2325, 0);
    let b = fnv1a(bytes(), 0x8422_2325_cbf2_9ce4, 7);
    format!("{a:016x}{b:016x}")
}

/// LiDAR points as nuScenes `.pcd.bin` bytes.
pub fn lidar_bin(points: &[LidarPoint]) -> Vec<u8> {
    let mut out = Vec::with_capacity(points.len() * 20);
    for p in points {
        for v in [p.x, p.y, p.z, p.intensity, p.ring as f32] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

fn quat_wxyz(q: glam::Quat) -> [f64; 4] {
    [q.w as f64, q.x as f64, q.y as f64, q.z as f64]
}

/// Builds the tables scene by scene; point files are written as scenes arrive.
#[derive(Debug)]
pub struct DatasetWriter {
    root: PathBuf,
    version: String,
    namespace: String,
    sensors: Vec<SensorSetup>,
    tables: Tables,
}

/// The category row of class `c`.
fn category(ns: &str, c: Class) -> Category {
    Category {
        token: token(&[ns, "category", category_name(c)]),
        name: category_name(c).into(),
        description: format!("hilo class {c}"),
    }
}

impl DatasetWriter {
    /// The category table lists `classes` (in [`Class::ALL`] order) instead of the paper's six:
    /// a dataset whose traffic may carry cyclists lists `bicycle`, one whose traffic cannot
    /// does not. An annotation of a class the table lacks is refused when its scene is added.
    pub fn with_classes(mut self, classes: &[Class]) -> Self {
        let ns = self.namespace.clone();
        self.tables.category = Class::ALL.iter().filter(|c| classes.contains(c)).map(|&c| category(&ns, c)).collect();
        self
    }

    /// `namespace` (e.g. the configuration name) makes tokens unique across datasets.
    pub fn new(root: &Path, version: &str, namespace: &str, sensors: Vec<SensorSetup>) -> Result<Self, DatasetError> {
        let mut seen = std::collections::HashSet::new();
        if let Some(s) = sensors.iter().find(|s| !seen.insert(s.channel.clone())) {
            return Err(DatasetError::Writer {
                what: format!("sensor channel {:?}", s.channel),
                reason: "appears twice".into(),
            });
        }
        let ns = namespace.to_owned();
        let mut t = Tables { category: Class::PAPER.iter().map(|&c| category(&ns, c)).collect(), ..Tables::default() };
        for a in ATTRIBUTES {
            t.attribute.push(Attribute {
                token: token(&[&ns, "attribute", a]),
                name: a.into(),
                description: String::new(),
            });
        }
        for (i, lvl) in ["v0-40", "v40-60", "v60-80", "v80-100"].iter().enumerate() {
            t.visibility.push(Visibility {
                token: (i + 1).to_string(),
                level: (*lvl).into(),
                description: format!("visible fraction {lvl}"),
            });
        }
        for s in &sensors {
            let st = token(&[&ns, "sensor", &s.channel]);
            let modality = match s.modality {
                SensorModality::Lidar => "lidar",
                SensorModality::Radar => "radar",
            };
            t.sensor.push(Sensor { token: st.clone(), channel: s.channel.clone(), modality: modality.into() });
            let p = s.pose.position;
            t.calibrated_sensor.push(CalibratedSensor {
                token: token(&[&ns, "calibrated_sensor", &s.channel]),
                sensor_token: st,
                translation: [p.x as f64, p.y as f64, p.z as f64],
                rotation: quat_wxyz(s.pose.rotation()),
                camera_intrinsic: Vec::new(),
            });
        }
        t.map.push(Map {
            token: token(&[&ns, "map"]),
            log_tokens: Vec::new(),
            category: "semantic_prior".into(),
            filename: String::new(),
        });
        Ok(DatasetWriter { root: root.to_path_buf(), version: version.to_owned(), namespace: ns, sensors, tables: t })
    }

    /// Adds a scene: writes its point files and records its rows.
    pub fn add_scene(&mut self, scene: &SceneData, location: &str) -> Result<(), DatasetError> {
        let ns = self.namespace.clone();
        let t = &mut self.tables;
        let lidar: Vec<&SensorSetup> = self.sensors.iter().filter(|s| s.modality == SensorModality::Lidar).collect();
        let radar: Vec<&SensorSetup> = self.sensors.iter().filter(|s| s.modality == SensorModality::Radar).collect();
        check_scene(t, scene, lidar.len(), radar.len())?;
        let log_token = token(&[&ns, "log", &scene.name]);
        t.log.push(Log {
            token: log_token.clone(),
            logfile: scene.name.clone(),
            vehicle: "roadside".into(),
            date_captured: "2026-01-01".into(),
            location: location.into(),
        });
        t.map[0].log_tokens.push(log_token.clone());
        let scene_token = token(&[&ns, "scene", &scene.name]);
        let sample_tokens: Vec<String> =
            scene.frames.iter().map(|f| token(&[&ns, "sample", &scene.name, &f.timestamp_us.to_string()])).collect();
        add_annotations(t, &ns, scene, &sample_tokens)?;
        // Samples.
        for (fi, f) in scene.frames.iter().enumerate() {
            t.sample.push(Sample {
                token: sample_tokens[fi].clone(),
                timestamp: f.timestamp_us,
                prev: if fi > 0 { sample_tokens[fi - 1].clone() } else { String::new() },
                next: sample_tokens.get(fi + 1).cloned().unwrap_or_default(),
                scene_token: scene_token.clone(),
            });
        }
        // Sample data: per channel, its chain in time order (key frames and the sweeps that hold
        // the channel's points); a sweep belongs to the first key frame at or after it (the one
        // that stacks it).
        let channels = lidar.iter().map(|s| (*s, true)).chain(radar.iter().map(|s| (*s, false)));
        for (ci, (s, is_lidar)) in channels.enumerate() {
            let k = if is_lidar { ci } else { ci - lidar.len() };
            // (timestamp, key frame index or None for a sweep, sweep index)
            let mut chain: Vec<(u64, Option<usize>, usize)> =
                scene.frames.iter().enumerate().map(|(fi, f)| (f.timestamp_us, Some(fi), 0)).collect();
            let holds = |sw: &Sweep| if is_lidar { !sw.lidar.is_empty() } else { !sw.radar.is_empty() };
            chain.extend(
                scene.sweeps.iter().enumerate().filter(|(_, sw)| holds(sw)).map(|(si, sw)| (sw.timestamp_us, None, si)),
            );
            chain.sort_by_key(|c| c.0);
            if chain.windows(2).any(|w| w[0].0 == w[1].0) {
                return Err(DatasetError::Scene {
                    scene: scene.name.clone(),
                    reason: "a sweep shares a key frame's time".into(),
                });
            }
            let sd_token = |c: &(u64, Option<usize>, usize)| match c.1 {
                Some(fi) => token(&[&ns, "sample_data", &s.channel, &sample_tokens[fi]]),
                None => token(&[&ns, "sample_data", &s.channel, "sweep", &c.0.to_string()]),
            };
            for (i, c) in chain.iter().enumerate() {
                let (bytes, ext) = match c.1 {
                    Some(fi) if is_lidar => (lidar_bin(&scene.frames[fi].lidar[k]), "pcd.bin"),
                    Some(fi) => (to_nuscenes_radar_pcd(&scene.frames[fi].radar[k]), "pcd"),
                    None if is_lidar => (lidar_bin(&scene.sweeps[c.2].lidar[k]), "pcd.bin"),
                    None => (to_nuscenes_radar_pcd(&scene.sweeps[c.2].radar[k]), "pcd"),
                };
                let folder = if c.1.is_some() { "samples" } else { "sweeps" };
                let filename = format!("{folder}/{}/{}__{}__{}.{ext}", s.channel, scene.name, s.channel, c.0);
                write_atomic(&self.root.join(&filename), &bytes)?;
                let owner = match c.1 {
                    Some(fi) => fi,
                    None => scene.frames.iter().position(|f| f.timestamp_us >= c.0).unwrap_or(scene.frames.len() - 1),
                };
                let token_here = sd_token(c);
                let ego = token(&[&ns, "ego_pose", &token_here]);
                t.ego_pose.push(EgoPose {
                    token: ego.clone(),
                    timestamp: c.0,
                    rotation: [1.0, 0.0, 0.0, 0.0],
                    translation: [0.0; 3],
                });
                t.sample_data.push(SampleData {
                    token: token_here,
                    sample_token: sample_tokens[owner].clone(),
                    ego_pose_token: ego,
                    calibrated_sensor_token: token(&[&ns, "calibrated_sensor", &s.channel]),
                    timestamp: c.0,
                    fileformat: "pcd".into(),
                    is_key_frame: c.1.is_some(),
                    height: 0,
                    width: 0,
                    filename,
                    prev: if i > 0 { sd_token(&chain[i - 1]) } else { String::new() },
                    next: chain.get(i + 1).map(sd_token).unwrap_or_default(),
                });
            }
        }
        t.scene.push(Scene {
            token: scene_token,
            log_token,
            nbr_samples: scene.frames.len(),
            first_sample_token: sample_tokens[0].clone(),
            last_sample_token: sample_tokens[sample_tokens.len() - 1].clone(),
            name: scene.name.clone(),
            description: scene.description.clone(),
        });
        Ok(())
    }

    /// Adds a scene like [`Self::add_scene`] and returns the rows it added, so that a
    /// resumable run can store them and later [`Self::add_rows`] instead of simulating again.
    pub fn add_scene_rows(&mut self, scene: &SceneData, location: &str) -> Result<Tables, DatasetError> {
        let t = &self.tables;
        let before = (
            t.scene.len(),
            t.sample.len(),
            t.sample_data.len(),
            t.sample_annotation.len(),
            t.instance.len(),
            t.ego_pose.len(),
            t.log.len(),
        );
        self.add_scene(scene, location)?;
        let t = &self.tables;
        Ok(Tables {
            scene: t.scene[before.0..].to_vec(),
            sample: t.sample[before.1..].to_vec(),
            sample_data: t.sample_data[before.2..].to_vec(),
            sample_annotation: t.sample_annotation[before.3..].to_vec(),
            instance: t.instance[before.4..].to_vec(),
            ego_pose: t.ego_pose[before.5..].to_vec(),
            log: t.log[before.6..].to_vec(),
            ..Tables::default()
        })
    }

    /// Adds the rows of a scene written earlier (by [`Self::add_scene_rows`] with the same
    /// namespace and sensors); its point files must already be in place.
    pub fn add_rows(&mut self, rows: Tables) -> Result<(), DatasetError> {
        let t = &mut self.tables;
        for s in &rows.scene {
            if t.scene.iter().any(|x| x.token == s.token) {
                return Err(DatasetError::Scene { scene: s.name.clone(), reason: "added twice".into() });
            }
        }
        for s in &rows.sample_data {
            let path = self.root.join(&s.filename);
            if !path.is_file() {
                return Err(DatasetError::PointFile { path, message: format!("missing (sample_data {})", s.token) });
            }
        }
        t.map[0].log_tokens.extend(rows.log.iter().map(|l| l.token.clone()));
        t.scene.extend(rows.scene);
        t.sample.extend(rows.sample);
        t.sample_data.extend(rows.sample_data);
        t.sample_annotation.extend(rows.sample_annotation);
        t.instance.extend(rows.instance);
        t.ego_pose.extend(rows.ego_pose);
        t.log.extend(rows.log);
        Ok(())
    }

    /// Records the train/val split by scene name (`<version>/splits.json`; nuScenes keeps its
    /// splits in code, the devkit ignores this file).
    pub fn write_splits(&self, splits: &std::collections::BTreeMap<String, Vec<String>>) -> Result<(), DatasetError> {
        let names: std::collections::HashSet<&str> = self.tables.scene.iter().map(|s| s.name.as_str()).collect();
        for (split, scenes) in splits {
            if let Some(s) = scenes.iter().find(|s| !names.contains(s.as_str())) {
                return Err(DatasetError::Writer {
                    what: format!("split {split:?}"),
                    reason: format!("names scene {s:?}, which the dataset does not have"),
                });
            }
        }
        let p = self.root.join(&self.version).join("splits.json");
        let bytes = serde_json::to_vec_pretty(splits)
            .map_err(|e| DatasetError::from(hilo_core::fs::FileError::content(&p, e.to_string())))?;
        Ok(write_atomic(&p, &bytes)?)
    }

    /// Writes the tables and returns them.
    pub fn finish(self) -> Result<Tables, DatasetError> {
        let dir = self.root.join(&self.version);
        let t = self.tables;
        macro_rules! put {
            ($name:ident) => {
                let p = dir.join(concat!(stringify!($name), ".json"));
                let bytes = serde_json::to_vec_pretty(&t.$name)
                    .map_err(|e| DatasetError::from(hilo_core::fs::FileError::content(&p, e.to_string())))?;
                write_atomic(&p, &bytes)?;
            };
        }
        put!(category);
        put!(attribute);
        put!(visibility);
        put!(instance);
        put!(sensor);
        put!(calibrated_sensor);
        put!(ego_pose);
        put!(log);
        put!(scene);
        put!(sample);
        put!(sample_data);
        put!(sample_annotation);
        put!(map);
        Ok(t)
    }
}

/// What a scene must hold before any of it is written: frames with increasing timestamps, a
/// start time no other scene has (nuscenes-devkit orders scenes by it), and one cloud per sensor
/// in every frame and sweep.
fn check_scene(t: &Tables, scene: &SceneData, lidars: usize, radars: usize) -> Result<(), DatasetError> {
    if scene.frames.is_empty() {
        return Err(DatasetError::Scene { scene: scene.name.clone(), reason: "has no frames".into() });
    }
    // nuscenes-devkit sorts scenes by start time and cannot order two equal ones.
    let start = scene.frames[0].timestamp_us;
    if let Some(other) =
        t.scene.iter().find(|s| t.sample.iter().any(|x| x.token == s.first_sample_token && x.timestamp == start))
    {
        return Err(DatasetError::Scene {
            scene: scene.name.clone(),
            reason: format!("starts at {start} µs, as scene {:?} does: scene start times must differ", other.name),
        });
    }
    if scene.frames.windows(2).any(|w| w[1].timestamp_us <= w[0].timestamp_us) {
        return Err(DatasetError::Scene { scene: scene.name.clone(), reason: "frame timestamps must increase".into() });
    }
    for (fi, f) in scene.frames.iter().enumerate() {
        if f.lidar.len() != lidars || f.radar.len() != radars {
            return Err(DatasetError::Scene {
                scene: scene.name.clone(),
                reason: format!(
                    "frame {fi}: {} LiDAR and {} radar clouds for {lidars} and {radars} sensors",
                    f.lidar.len(),
                    f.radar.len()
                ),
            });
        }
    }
    if let Some(sw) = scene.sweeps.iter().find(|sw| {
        (!sw.radar.is_empty() && sw.radar.len() != radars) || (!sw.lidar.is_empty() && sw.lidar.len() != lidars)
    }) {
        return Err(DatasetError::Scene {
            scene: scene.name.clone(),
            reason: format!(
                "the sweep at {} µs has {} LiDAR and {} radar clouds for {lidars} and {radars} sensors",
                sw.timestamp_us,
                sw.lidar.len(),
                sw.radar.len()
            ),
        });
    }
    Ok(())
}

/// Records a scene's instances and their annotation chains (first to last, linked both ways).
fn add_annotations(t: &mut Tables, ns: &str, scene: &SceneData, sample_tokens: &[String]) -> Result<(), DatasetError> {
    let mut chains: std::collections::BTreeMap<u32, Vec<(usize, usize)>> = std::collections::BTreeMap::new();
    for (fi, f) in scene.frames.iter().enumerate() {
        for (ai, a) in f.annotations.iter().enumerate() {
            chains.entry(a.instance).or_default().push((fi, ai));
        }
    }
    let ann_token =
        |inst: u32, fi: usize| token(&[ns, "annotation", &scene.name, &inst.to_string(), &sample_tokens[fi]]);
    for (inst, chain) in &chains {
        let first = &scene.frames[chain[0].0].annotations[chain[0].1];
        let Some(cat) = t.category.iter().find(|c| c.name == category_name(first.class)).map(|c| c.token.clone())
        else {
            return Err(DatasetError::Writer {
                what: format!("scene {:?}, class {}", scene.name, first.class),
                reason: "not in the dataset's category table (the writer's classes)".into(),
            });
        };
        let inst_token = token(&[ns, "instance", &scene.name, &inst.to_string()]);
        t.instance.push(Instance {
            token: inst_token.clone(),
            category_token: cat,
            nbr_annotations: chain.len(),
            first_annotation_token: ann_token(*inst, chain[0].0),
            last_annotation_token: ann_token(*inst, chain[chain.len() - 1].0),
        });
        for (k, &(fi, ai)) in chain.iter().enumerate() {
            let a = &scene.frames[fi].annotations[ai];
            let b = a.box3;
            let attrs = if a.attribute.is_empty() {
                Vec::new()
            } else {
                match t.attribute.iter().find(|x| x.name == a.attribute) {
                    Some(x) => vec![x.token.clone()],
                    None => {
                        return Err(DatasetError::Writer {
                            what: format!("attribute {:?}", a.attribute),
                            reason: "is not one of nuScenes' attributes".into(),
                        });
                    }
                }
            };
            t.sample_annotation.push(SampleAnnotation {
                token: ann_token(*inst, fi),
                sample_token: sample_tokens[fi].clone(),
                instance_token: inst_token.clone(),
                visibility_token: a.visibility.clamp(1, 4).to_string(),
                attribute_tokens: attrs,
                translation: [b.center.x as f64, b.center.y as f64, b.center.z as f64],
                size: [b.width_m as f64, b.length_m as f64, b.height_m as f64],
                rotation: [(b.yaw as f64 / 2.0).cos(), 0.0, 0.0, (b.yaw as f64 / 2.0).sin()],
                prev: if k > 0 { ann_token(*inst, chain[k - 1].0) } else { String::new() },
                next: if k + 1 < chain.len() { ann_token(*inst, chain[k + 1].0) } else { String::new() },
                num_lidar_pts: a.num_lidar_pts,
                num_radar_pts: a.num_radar_pts,
            });
        }
    }
    Ok(())
}
