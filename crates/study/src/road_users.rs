//! Where the study's road users are: per placement target, the class-balanced share of the
//! simulated traffic found on it, the target weights of the calibrated objective's terms over
//! road users ([`hilo_placement_ip::calibrated`]).
//!
//! The traffic is the study's own (`[dataset]`: its seed, flows and signal plan), stepped
//! without any sensor through the key frames of its training scenes, so the validation split
//! that scores detectors is not read. Every road user within its class's evaluation range
//! (measured from the intersection's origin, as the evaluation measures it) counts on the
//! target cell holding its box centre; each class's counts are divided by that class's road
//! users, and the classes are averaged, as mAP averages them: a cell crossed by pedestrians
//! weighs what pedestrians are worth to mAP, though cars outnumber them. A road user whose
//! centre lies on no target (outside every region of interest) counts towards its class's total
//! but on no cell, so the weights sum to the share of road users the targets hold.
//!
//! What it leaves out: a road user's extent (only the centre's cell counts) and occlusion by
//! other road users (which depends on the instant, not on the cell; the occupancy predictors of
//! `hilo validate` count it from the simulated scans).

use crate::error::Result;
use crate::study::Study;
use hilo_dataset::simulate::{SceneId, Split, key_frame_states};
use hilo_placement_ip::targets::Target;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};

/// The target weights and what they were counted from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoadUsers {
    /// Per target, Σ over classes of (road users of the class on it / road users of the class)
    /// / classes.
    pub weights: Vec<f64>,
    /// Per class, road users counted (key frames × road users within range).
    pub per_class: BTreeMap<String, usize>,
    /// Of those, the ones whose centre lies on no target.
    pub off_targets: usize,
    /// Training scenes and key frames stepped.
    pub scenes: usize,
    pub key_frames: usize,
}

/// Counts the road users of `study`'s training scenes on `targets`, a grid of `cell_m` squares.
pub fn road_users(study: &Study, targets: &[Target], cell_m: f32) -> Result<RoadUsers> {
    let cfg = &study.dataset;
    let ranges = study.file.evaluation.detection_config().class_range;
    let Some(origin) = targets.first().map(|t| t.center) else {
        return Ok(RoadUsers {
            weights: Vec::new(),
            per_class: BTreeMap::new(),
            off_targets: 0,
            scenes: 0,
            key_frames: 0,
        });
    };
    let key = |p: glam::Vec2| {
        let d = (p - origin) / cell_m;
        (d.x.round() as i64, d.y.round() as i64)
    };
    let cell: HashMap<(i64, i64), usize> = targets.iter().enumerate().map(|(j, t)| (key(t.center), j)).collect();
    let ids: Vec<SceneId> = cfg.scene_ids().into_iter().filter(|id| id.split == Split::Train).collect();
    let mut on: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    let mut per_class: BTreeMap<String, usize> = BTreeMap::new();
    let (mut off_targets, mut key_frames) = (0, 0);
    for id in &ids {
        for frame in key_frame_states(&study.scene, cfg, id)? {
            key_frames += 1;
            for a in frame {
                let name = a.class.name();
                let Some(&range) = ranges.get(name) else { continue };
                let p = a.box3.center.truncate();
                if f64::from(p.length()) >= range {
                    continue;
                }
                *per_class.entry(name.to_owned()).or_default() += 1;
                // A centre on a cell's edge rounds to one of the two cells; either holds it.
                let inside = |j: usize| {
                    let d = (p - targets[j].center).abs();
                    d.x <= 0.5 * cell_m + 1e-4 && d.y <= 0.5 * cell_m + 1e-4
                };
                match cell.get(&key(p)).copied().filter(|&j| inside(j)) {
                    Some(j) => on.entry(name.to_owned()).or_default().push(j),
                    None => off_targets += 1,
                }
            }
        }
    }
    let mut weights = vec![0.0; targets.len()];
    let classes = per_class.len().max(1) as f64;
    for (name, cells) in &on {
        let n = per_class[name] as f64;
        for &j in cells {
            weights[j] += 1.0 / (n * classes);
        }
    }
    Ok(RoadUsers { weights, per_class, off_targets, scenes: ids.len(), key_frames })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    /// Against a brute-force count: every counted road user found on the one target whose cell
    /// holds its centre (a linear search over all targets), class-balanced by hand; the weights
    /// sum to the share of road users on targets, averaged over classes.
    #[test]
    fn road_user_weights_equal_a_brute_force_count() {
        let study =
            Study::parse(include_str!("../../../fixtures/study.toml"), std::path::Path::new("."), "s.toml").unwrap();
        let study = Study {
            dataset: hilo_dataset::simulate::SimulateConfig {
                scenes: 2,
                seconds: 2.0,
                val_scenes: 1,
                ..study.dataset.clone().into_inner()
            }
            .validate()
            .unwrap(),
            ..study
        };
        let cell_m = 2.0;
        let targets = hilo_placement_ip::targets::roi_targets(&study.scene, cell_m).unwrap();
        let got = road_users(&study, &targets, cell_m).unwrap();
        assert_eq!((got.scenes, got.key_frames), (2, 40));
        let ranges = study.file.evaluation.detection_config().class_range;
        let mut count: BTreeMap<String, Vec<f64>> = BTreeMap::new();
        let mut off = 0;
        for index in 0..2 {
            let id = SceneId { split: Split::Train, index };
            for frame in key_frame_states(&study.scene, &study.dataset, &id).unwrap() {
                for a in frame {
                    let p = a.box3.center.truncate();
                    let Some(&r) = ranges.get(a.class.name()) else { continue };
                    if f64::from(p.length()) >= r {
                        continue;
                    }
                    let c = count.entry(a.class.name().to_owned()).or_insert_with(|| vec![0.0; targets.len() + 1]);
                    let holds = |t: &Target| {
                        let d = (p - t.center).abs();
                        d.x <= 0.5 * cell_m + 1e-4 && d.y <= 0.5 * cell_m + 1e-4
                    };
                    match targets.iter().position(holds) {
                        Some(j) => c[j] += 1.0,
                        None => {
                            c[targets.len()] += 1.0;
                            off += 1;
                        }
                    }
                }
            }
        }
        assert!(count.len() >= 2, "classes counted: {:?}", count.keys());
        assert_eq!(off, got.off_targets);
        let k = count.len() as f64;
        for (j, w) in got.weights.iter().enumerate() {
            let want: f64 = count.values().map(|c| c[j] / c.iter().sum::<f64>() / k).sum();
            assert!((w - want).abs() < 1e-12, "target {j}: {w} against {want}");
        }
        let on_share: f64 = count.values().map(|c| 1.0 - c[targets.len()] / c.iter().sum::<f64>()).sum::<f64>() / k;
        assert!((got.weights.iter().sum::<f64>() - on_share).abs() < 1e-9);
        assert!(on_share > 0.5, "most road users should stand on a target: {on_share}");
    }
}
