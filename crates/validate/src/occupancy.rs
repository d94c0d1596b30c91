//! Occupancy predictors: what a rig sees of the study's simulated traffic, without training.
//!
//! For every road user annotated in a split's key frames and within its class's evaluation
//! range (measured from the intersection's origin, as the evaluation does), the LiDAR and radar
//! points the rig put on it, as the simulator counted them (rays that hit the road user, after
//! occlusion by buildings, poles and other road users). Per class: the share hit by at least k
//! LiDAR points and the share with a radar point; over classes (each class weighted equally, as
//! mAP weighs them): the same shares, and the mean LiDAR points per road user.

use hilo_dataset::Dataset;
use hilo_eval::DetectionConfig;
use hilo_plan::error::Result;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashSet};

/// The predictor names [`Occupancy::predictors`] gives.
pub const HIT_SHARE: &str = "road users hit by k LiDAR points";
pub const POINTS_PER_USER: &str = "LiDAR points per road user";
pub const RADAR_SHARE: &str = "road users with a radar point";

/// A class's counts.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClassOccupancy {
    pub road_users: usize,
    /// Hit by at least k LiDAR points.
    pub hit: usize,
    pub with_radar: usize,
    pub lidar_points: u64,
}

/// Per class, over a split's key frames.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Occupancy {
    pub classes: BTreeMap<String, ClassOccupancy>,
}

/// Counts the annotations of `split` within `cfg`'s class ranges; a road user counts as hit
/// when it holds at least `k` LiDAR points.
pub fn occupancy(ds: &Dataset, split: &str, cfg: &DetectionConfig, k: u32) -> Result<Occupancy> {
    let scenes: HashSet<String> = ds.split(split)?.into_iter().collect();
    let t = &ds.tables;
    let in_split: HashSet<&str> =
        t.scene.iter().filter(|s| scenes.contains(&s.name)).map(|s| s.token.as_str()).collect();
    let samples: HashSet<&str> =
        t.sample.iter().filter(|s| in_split.contains(s.scene_token.as_str())).map(|s| s.token.as_str()).collect();
    let class_of = ds.instance_classes();
    let mut out = Occupancy::default();
    for a in t.sample_annotation.iter().filter(|a| samples.contains(a.sample_token.as_str())) {
        let Some(class) = class_of.get(a.instance_token.as_str()) else { continue };
        let Some(range) = cfg.class_range.get(class) else { continue };
        if a.translation[0].hypot(a.translation[1]) >= *range {
            continue;
        }
        let c = out.classes.entry(class.clone()).or_default();
        c.road_users += 1;
        c.hit += usize::from(a.num_lidar_pts >= k);
        c.with_radar += usize::from(a.num_radar_pts > 0);
        c.lidar_points += a.num_lidar_pts as u64;
    }
    Ok(out)
}

impl Occupancy {
    /// Class-averaged shares and points: (hit share, radar share, points per road user).
    pub fn means(&self) -> (f64, f64, f64) {
        let n = self.classes.len().max(1) as f64;
        let per = |f: &dyn Fn(&ClassOccupancy) -> f64| {
            self.classes.values().map(|c| if c.road_users == 0 { 0.0 } else { f(c) / c.road_users as f64 }).sum::<f64>()
                / n
        };
        (per(&|c| c.hit as f64), per(&|c| c.with_radar as f64), per(&|c| c.lidar_points as f64))
    }

    /// The predictors, by name (per class too: `<name> (<class>)`).
    pub fn predictors(&self) -> BTreeMap<String, Option<f64>> {
        let (hit, radar, points) = self.means();
        let mut m = BTreeMap::from([
            (HIT_SHARE.to_owned(), Some(hit)),
            (RADAR_SHARE.to_owned(), Some(radar)),
            (POINTS_PER_USER.to_owned(), Some(points)),
        ]);
        if let Some(p) = self.classes.get("pedestrian").filter(|c| c.road_users > 0) {
            m.insert(format!("{HIT_SHARE} (pedestrian)"), Some(p.hit as f64 / p.road_users as f64));
        }
        m
    }
}
