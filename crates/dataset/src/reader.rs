//! Reads a nuScenes-layout dataset back: tables, link checks, point files.

use crate::error::DatasetError;
use crate::tables::*;
use hilo_core::{LidarPoint, RadarPoint};
use serde::de::DeserializeOwned;
use std::collections::BTreeMap;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

fn load<T: DeserializeOwned>(dir: &Path, name: &str) -> Result<Vec<T>, DatasetError> {
    let p = dir.join(format!("{name}.json"));
    let text = hilo_core::fs::read_text_bounded(&p, hilo_core::fs::limit::TABLE)
        .map_err(|e| DatasetError::from(hilo_core::fs::FileError::io(&p, e)))?;
    serde_json::from_str(&text)
        .map_err(|e| DatasetError::from(hilo_core::fs::FileError::Content { path: p, message: e.to_string() }))
}

/// nuScenes' own categories: a dataset may hold them, and those that are not one of hilo's
/// classes ([`crate::writer::class_of_category`]) are not evaluated, as in the devkit. Any other
/// name is a mistake (a misspelt class would silently drop its every box from the ground truth).
pub const NUSCENES_CATEGORIES: [&str; 23] = [
    "animal",
    "human.pedestrian.adult",
    "human.pedestrian.child",
    "human.pedestrian.construction_worker",
    "human.pedestrian.personal_mobility",
    "human.pedestrian.police_officer",
    "human.pedestrian.stroller",
    "human.pedestrian.wheelchair",
    "movable_object.barrier",
    "movable_object.debris",
    "movable_object.pushable_pullable",
    "movable_object.trafficcone",
    "static_object.bicycle_rack",
    "vehicle.bicycle",
    "vehicle.bus.bendy",
    "vehicle.bus.rigid",
    "vehicle.car",
    "vehicle.construction",
    "vehicle.emergency.ambulance",
    "vehicle.emergency.police",
    "vehicle.motorcycle",
    "vehicle.trailer",
    "vehicle.truck",
];

/// The table folder's name: one folder inside the dataroot.
pub fn check_version(version: &str) -> Result<(), DatasetError> {
    hilo_core::fs::check_file_name(version)
        .map_err(|why| DatasetError::setting("version (the table folder's name)", format!("{version:?}"), why))
}

/// A dataset's file name of a point file: relative, inside the dataroot (no `..`, no root).
fn check_filename(sd: &SampleData) -> Result<(), DatasetError> {
    use std::path::Component;
    let p = Path::new(&sd.filename);
    let inside = !sd.filename.is_empty() && p.components().all(|c| matches!(c, Component::Normal(_)));
    if inside {
        Ok(())
    } else {
        Err(DatasetError::Record {
            table: "sample_data",
            token: sd.token.clone(),
            field: "filename",
            value: format!("{:?}", sd.filename),
            reason: "must be a relative path inside the dataroot (no `..`, no leading `/`)".into(),
        })
    }
}

/// A loaded dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    pub root: PathBuf,
    pub version: String,
    pub tables: Tables,
    /// Annotation token → index in `tables.sample_annotation`.
    annotation_index: HashMap<String, usize>,
    /// Sample token → timestamp, µs.
    sample_time: HashMap<String, u64>,
}

impl Dataset {
    /// Loads `<root>/<version>/*.json` and checks every link between tables.
    pub fn open(root: &Path, version: &str) -> Result<Self, DatasetError> {
        check_version(version)?;
        let dir = root.join(version);
        let tables = Tables {
            category: load(&dir, "category")?,
            attribute: load(&dir, "attribute")?,
            visibility: load(&dir, "visibility")?,
            instance: load(&dir, "instance")?,
            sensor: load(&dir, "sensor")?,
            calibrated_sensor: load(&dir, "calibrated_sensor")?,
            ego_pose: load(&dir, "ego_pose")?,
            log: load(&dir, "log")?,
            scene: load(&dir, "scene")?,
            sample: load(&dir, "sample")?,
            sample_data: load(&dir, "sample_data")?,
            sample_annotation: load(&dir, "sample_annotation")?,
            map: load(&dir, "map")?,
        };
        check_links(&tables)?;
        check_records(&tables)?;
        let annotation_index = tables.sample_annotation.iter().enumerate().map(|(i, a)| (a.token.clone(), i)).collect();
        let sample_time = tables.sample.iter().map(|s| (s.token.clone(), s.timestamp)).collect();
        Ok(Dataset { root: root.to_path_buf(), version: version.to_owned(), tables, annotation_index, sample_time })
    }

    /// The scene names of a split (`<version>/splits.json`).
    pub fn split(&self, name: &str) -> Result<Vec<String>, DatasetError> {
        let p = self.root.join(&self.version).join("splits.json");
        let text = hilo_core::fs::read_text_bounded(&p, hilo_core::fs::limit::CONFIG)
            .map_err(|e| DatasetError::from(hilo_core::fs::FileError::io(&p, e)))?;
        let splits: std::collections::BTreeMap<String, Vec<String>> = serde_json::from_str(&text)
            .map_err(|e| DatasetError::from(hilo_core::fs::FileError::content(&p, e.to_string())))?;
        splits.get(name).cloned().ok_or_else(|| {
            DatasetError::from(hilo_core::fs::FileError::Content {
                path: p,
                message: format!(
                    "no split {name:?}; splits: {}",
                    splits.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            })
        })
    }

    /// The devkit's `box_velocity`: centred difference over the previous and next annotation of
    /// the instance (one-sided at the ends), NaN when there is neither or the time gap exceeds
    /// 1.5 s (3 s for a centred difference). Metres per second, x y z.
    pub fn box_velocity(&self, ann: &SampleAnnotation) -> [f64; 3] {
        let by_token = |t: &str| self.annotation_index.get(t).map(|&i| &self.tables.sample_annotation[i]);
        let time = |a: &SampleAnnotation| self.sample_time.get(&a.sample_token).map_or(0.0, |&t| 1e-6 * t as f64);
        let (has_prev, has_next) = (!ann.prev.is_empty(), !ann.next.is_empty());
        if !has_prev && !has_next {
            return [f64::NAN; 3];
        }
        let first = if has_prev { by_token(&ann.prev).unwrap_or(ann) } else { ann };
        let last = if has_next { by_token(&ann.next).unwrap_or(ann) } else { ann };
        let dt = time(last) - time(first);
        let max = if has_prev && has_next { 3.0 } else { 1.5 };
        if dt > max {
            return [f64::NAN; 3];
        }
        [0, 1, 2].map(|k| (last.translation[k] - first.translation[k]) / dt)
    }

    /// The LiDAR points of a sample_data record (sensor frame; time is not stored).
    pub fn lidar_points(&self, sd: &SampleData) -> Result<Vec<LidarPoint>, DatasetError> {
        let (p, bytes) = self.point_file(sd)?;
        if bytes.len() % 20 != 0 {
            return Err(DatasetError::PointFile {
                path: p,
                message: format!("truncated: {} bytes is not a whole number of 20-byte points", bytes.len()),
            });
        }
        let points: Vec<LidarPoint> = bytes
            .chunks_exact(20)
            .map(|c| {
                let f = |k: usize| f32::from_le_bytes([c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]]);
                LidarPoint { x: f(0), y: f(1), z: f(2), intensity: f(3), ring: f(4) as u16, time_s: 0.0 }
            })
            .collect();
        finite(&p, points.iter().map(|q| [q.x, q.y, q.z, q.intensity]))?;
        Ok(points)
    }

    /// The radar points of a sample_data record (sensor frame).
    pub fn radar_points(&self, sd: &SampleData) -> Result<Vec<RadarPoint>, DatasetError> {
        let (p, bytes) = self.point_file(sd)?;
        let points = hilo_sensor_models::export::from_nuscenes_radar_pcd(&bytes, &p)
            .map_err(|e| DatasetError::PointFile { path: p.clone(), message: e.to_string() })?;
        finite(&p, points.iter().map(|q| [q.x, q.y, q.z, q.rcs_dbsm, q.v_r_mps]))?;
        Ok(points)
    }
}

impl Dataset {
    /// A point file's path and bytes: inside the dataroot (checked when the tables were
    /// loaded, and again here for records built by hand), at most [`hilo_core::fs::limit::POINTS`].
    fn point_file(&self, sd: &SampleData) -> Result<(PathBuf, Vec<u8>), DatasetError> {
        check_filename(sd)?;
        let p = self.root.join(&sd.filename);
        let bytes = hilo_core::fs::read_bounded(&p, hilo_core::fs::limit::POINTS)
            .map_err(|e| DatasetError::from(hilo_core::fs::FileError::io(&p, e)))?;
        Ok((p, bytes))
    }
}

/// Refuses a point with a NaN or infinite value: it would be drawn and counted as if measured.
fn finite<const N: usize>(path: &Path, points: impl Iterator<Item = [f32; N]>) -> Result<(), DatasetError> {
    match points.enumerate().find(|(_, v)| v.iter().any(|x| !x.is_finite())) {
        Some((i, v)) => Err(DatasetError::PointFile {
            path: path.to_path_buf(),
            message: format!("point {i} has a value that is not a finite number: {v:?}"),
        }),
        None => Ok(()),
    }
}

/// Checks every record as the devkit would trust it: tokens unique per table, `prev`/`next`
/// chains that agree both ways, annotations with finite translations, positive sizes and
/// non-zero finite rotations, categories that nuScenes or hilo knows, point file names inside
/// the dataroot. A defect in the ground truth is refused like one in the predictions.
fn check_records(t: &Tables) -> Result<(), DatasetError> {
    let rec = |table: &'static str, token: &str, field: &'static str, value: String, reason: &str| {
        Err(DatasetError::Record { table, token: token.to_owned(), field, value, reason: reason.to_owned() })
    };
    fn unique<'a>(table: &'static str, tokens: impl Iterator<Item = &'a String>) -> Result<(), DatasetError> {
        let mut seen = HashSet::new();
        for tk in tokens {
            if !seen.insert(tk) {
                return Err(DatasetError::Record {
                    table,
                    token: tk.clone(),
                    field: "token",
                    value: format!("{tk:?}"),
                    reason: "appears twice in the table".into(),
                });
            }
        }
        Ok(())
    }
    unique("scene", t.scene.iter().map(|r| &r.token))?;
    unique("sample", t.sample.iter().map(|r| &r.token))?;
    unique("sample_data", t.sample_data.iter().map(|r| &r.token))?;
    unique("sample_annotation", t.sample_annotation.iter().map(|r| &r.token))?;
    unique("instance", t.instance.iter().map(|r| &r.token))?;
    unique("category", t.category.iter().map(|r| &r.token))?;
    unique("attribute", t.attribute.iter().map(|r| &r.token))?;
    unique("visibility", t.visibility.iter().map(|r| &r.token))?;
    unique("sensor", t.sensor.iter().map(|r| &r.token))?;
    unique("calibrated_sensor", t.calibrated_sensor.iter().map(|r| &r.token))?;
    unique("ego_pose", t.ego_pose.iter().map(|r| &r.token))?;
    unique("log", t.log.iter().map(|r| &r.token))?;
    unique("map", t.map.iter().map(|r| &r.token))?;
    // Chains: if a.next = b then b.prev = a, and the other way round.
    fn chain<'a>(
        table: &'static str,
        rows: impl Iterator<Item = (&'a String, &'a String, &'a String)> + Clone,
    ) -> Result<(), DatasetError> {
        let prev_of: HashMap<&String, &String> = rows.clone().map(|(tk, prev, _)| (tk, prev)).collect();
        let next_of: HashMap<&String, &String> = rows.clone().map(|(tk, _, next)| (tk, next)).collect();
        for (tk, prev, next) in rows {
            if !next.is_empty() && prev_of.get(next).is_some_and(|p| *p != tk) {
                return Err(DatasetError::Record {
                    table,
                    token: tk.clone(),
                    field: "next",
                    value: format!("{next:?}"),
                    reason: format!("that record's `prev` is {:?}, not this record", prev_of[next]),
                });
            }
            if !prev.is_empty() && next_of.get(prev).is_some_and(|n| *n != tk) {
                return Err(DatasetError::Record {
                    table,
                    token: tk.clone(),
                    field: "prev",
                    value: format!("{prev:?}"),
                    reason: format!("that record's `next` is {:?}, not this record", next_of[prev]),
                });
            }
        }
        Ok(())
    }
    chain("sample", t.sample.iter().map(|r| (&r.token, &r.prev, &r.next)))?;
    chain("sample_data", t.sample_data.iter().map(|r| (&r.token, &r.prev, &r.next)))?;
    chain("sample_annotation", t.sample_annotation.iter().map(|r| (&r.token, &r.prev, &r.next)))?;
    for c in &t.category {
        if crate::writer::class_of_category(&c.name).is_none() && !NUSCENES_CATEGORIES.contains(&c.name.as_str()) {
            return rec(
                "category",
                &c.token,
                "name",
                format!("{:?}", c.name),
                "neither a nuScenes category nor one of hilo's (vehicle.golf_cart)",
            );
        }
    }
    for a in &t.sample_annotation {
        if let Some((field, value, why)) = hilo_core::nuscenes_box_defect(&a.translation, &a.size, &a.rotation) {
            return rec("sample_annotation", &a.token, field, value, why);
        }
    }
    for sd in &t.sample_data {
        check_filename(sd)?;
    }
    Ok(())
}

fn check_links(t: &Tables) -> Result<(), DatasetError> {
    let set = |v: Vec<&String>| -> HashSet<String> { v.into_iter().cloned().collect() };
    let scenes = set(t.scene.iter().map(|r| &r.token).collect());
    let samples = set(t.sample.iter().map(|r| &r.token).collect());
    let sds = set(t.sample_data.iter().map(|r| &r.token).collect());
    let anns = set(t.sample_annotation.iter().map(|r| &r.token).collect());
    let instances = set(t.instance.iter().map(|r| &r.token).collect());
    let categories = set(t.category.iter().map(|r| &r.token).collect());
    let attributes = set(t.attribute.iter().map(|r| &r.token).collect());
    let visibilities = set(t.visibility.iter().map(|r| &r.token).collect());
    let sensors = set(t.sensor.iter().map(|r| &r.token).collect());
    let calibrated = set(t.calibrated_sensor.iter().map(|r| &r.token).collect());
    let egos = set(t.ego_pose.iter().map(|r| &r.token).collect());
    let logs = set(t.log.iter().map(|r| &r.token).collect());
    let need = |table: &'static str,
                token: &str,
                field: &'static str,
                target: &'static str,
                set: &HashSet<String>,
                value: &str,
                optional: bool| {
        if (optional && value.is_empty()) || set.contains(value) {
            Ok(())
        } else {
            Err(DatasetError::Dangling { table, token: token.to_owned(), field, target, missing: value.to_owned() })
        }
    };
    for r in &t.scene {
        need("scene", &r.token, "log_token", "log", &logs, &r.log_token, false)?;
        need("scene", &r.token, "first_sample_token", "sample", &samples, &r.first_sample_token, false)?;
        need("scene", &r.token, "last_sample_token", "sample", &samples, &r.last_sample_token, false)?;
    }
    for r in &t.sample {
        need("sample", &r.token, "scene_token", "scene", &scenes, &r.scene_token, false)?;
        need("sample", &r.token, "prev", "sample", &samples, &r.prev, true)?;
        need("sample", &r.token, "next", "sample", &samples, &r.next, true)?;
    }
    for r in &t.sample_data {
        need("sample_data", &r.token, "sample_token", "sample", &samples, &r.sample_token, false)?;
        need("sample_data", &r.token, "ego_pose_token", "ego_pose", &egos, &r.ego_pose_token, false)?;
        need(
            "sample_data",
            &r.token,
            "calibrated_sensor_token",
            "calibrated_sensor",
            &calibrated,
            &r.calibrated_sensor_token,
            false,
        )?;
        need("sample_data", &r.token, "prev", "sample_data", &sds, &r.prev, true)?;
        need("sample_data", &r.token, "next", "sample_data", &sds, &r.next, true)?;
    }
    for r in &t.calibrated_sensor {
        need("calibrated_sensor", &r.token, "sensor_token", "sensor", &sensors, &r.sensor_token, false)?;
    }
    for r in &t.sample_annotation {
        need("sample_annotation", &r.token, "sample_token", "sample", &samples, &r.sample_token, false)?;
        need("sample_annotation", &r.token, "instance_token", "instance", &instances, &r.instance_token, false)?;
        need(
            "sample_annotation",
            &r.token,
            "visibility_token",
            "visibility",
            &visibilities,
            &r.visibility_token,
            false,
        )?;
        need("sample_annotation", &r.token, "prev", "sample_annotation", &anns, &r.prev, true)?;
        need("sample_annotation", &r.token, "next", "sample_annotation", &anns, &r.next, true)?;
        for a in &r.attribute_tokens {
            need("sample_annotation", &r.token, "attribute_tokens", "attribute", &attributes, a, false)?;
        }
    }
    for r in &t.instance {
        need("instance", &r.token, "category_token", "category", &categories, &r.category_token, false)?;
        need(
            "instance",
            &r.token,
            "first_annotation_token",
            "sample_annotation",
            &anns,
            &r.first_annotation_token,
            false,
        )?;
        need(
            "instance",
            &r.token,
            "last_annotation_token",
            "sample_annotation",
            &anns,
            &r.last_annotation_token,
            false,
        )?;
    }
    for r in &t.map {
        for l in &r.log_tokens {
            need("map", &r.token, "log_tokens", "log", &logs, l, false)?;
        }
    }
    Ok(())
}

/// Boxes of a class in a dataset and the points on them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClassStats {
    pub boxes: usize,
    pub lidar_points: u64,
    pub radar_points: u64,
}

impl Dataset {
    /// The hilo classes the category table lists (the classes the dataset's traffic can carry),
    /// in [`hilo_core::Class::ALL`] order.
    pub fn classes(&self) -> Vec<hilo_core::Class> {
        let listed: Vec<_> =
            self.tables.category.iter().filter_map(|c| crate::writer::class_of_category(&c.name)).collect();
        hilo_core::Class::ALL.into_iter().filter(|c| listed.contains(c)).collect()
    }

    /// Each instance's class name (hilo's name where the category maps to one, the category's
    /// name otherwise), by instance token.
    pub fn instance_classes(&self) -> BTreeMap<&str, String> {
        let t = &self.tables;
        t.instance
            .iter()
            .filter_map(|i| {
                let c = t.category.iter().find(|c| c.token == i.category_token)?;
                let name = crate::writer::class_of_category(&c.name).map_or(c.name.clone(), |k| k.name().to_owned());
                Some((i.token.as_str(), name))
            })
            .collect()
    }

    /// Per class: its annotated boxes and the LiDAR and radar points they hold ("?" for boxes
    /// whose instance has no category).
    pub fn class_stats(&self) -> BTreeMap<String, ClassStats> {
        let class_of = self.instance_classes();
        let mut per_class: BTreeMap<String, ClassStats> = BTreeMap::new();
        for a in &self.tables.sample_annotation {
            let c = class_of.get(a.instance_token.as_str()).cloned().unwrap_or_else(|| "?".into());
            let e = per_class.entry(c).or_default();
            e.boxes += 1;
            e.lidar_points += a.num_lidar_pts as u64;
            e.radar_points += a.num_radar_pts as u64;
        }
        per_class
    }
}
