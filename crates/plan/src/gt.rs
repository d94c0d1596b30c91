//! Ground truth of a dataset split, as evaluation reads it.
//!
//! Two conventions:
//! - **visible-only** (nuScenes'): boxes with at least one point of the rig's sensors; what the
//!   devkit's `load_gt` and `filter_eval_boxes` keep. A rig is never penalised for the road
//!   users its sensors miss.
//! - **common** (the verdict's): every road user of the evaluated classes within the evaluation
//!   ranges of the intersection's centre, whatever the rig saw. Every rig of a study records
//!   the same traffic, so every rig is scored against the same boxes, and a miss caused by
//!   coverage or occlusion counts against the rig that was bought.
//!
//! Samples are keyed by their token (one dataset) or by `<scene>@<timestamp µs>`, which is the
//! same for every rig of a study (datasets of different rigs have different tokens).

use crate::error::Result;
use hilo_dataset::Dataset;
use hilo_eval::EvalBox;
use hilo_eval::boxes::{GroundTruth, SampleInfo};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Which boxes count.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GtKind {
    /// Every road user, seen or not (`num_pts` is −1: not a filter criterion).
    Common,
    /// Boxes with at least one LiDAR or radar point of the rig (nuScenes' convention).
    VisibleOnly,
}

/// How samples are named.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleKey {
    /// The dataset's sample token.
    Token,
    /// `<scene name>@<timestamp µs>`: the same sample in every rig's dataset of a study.
    SceneTime,
}

/// The ground truth of `split`, as the devkit's `load_gt` builds it (classes from categories,
/// sizes and rotations as annotated, velocity by the devkit's finite difference, points as
/// LiDAR plus radar points, the attribute if there is one), with scenes named by name. Also returns each
/// sample token's key.
pub fn ground_truth(
    ds: &Dataset,
    split: &str,
    kind: GtKind,
    key: SampleKey,
) -> Result<(GroundTruth, BTreeMap<String, String>)> {
    let scenes: std::collections::HashSet<String> = ds.split(split)?.into_iter().collect();
    let t = &ds.tables;
    let scene_of: BTreeMap<&str, &hilo_dataset::tables::Scene> =
        t.scene.iter().map(|s| (s.token.as_str(), s)).collect();
    let mut gt = GroundTruth::default();
    let mut keys = BTreeMap::new();
    for s in &t.sample {
        if let Some(sc) = scene_of.get(s.scene_token.as_str()).filter(|sc| scenes.contains(&sc.name)) {
            let k = match key {
                SampleKey::Token => s.token.clone(),
                SampleKey::SceneTime => format!("{}@{}", sc.name, s.timestamp),
            };
            gt.samples.insert(k.clone(), SampleInfo { scene: sc.name.clone(), ego_translation: [0.0; 3] });
            gt.boxes.insert(k.clone(), Vec::new());
            keys.insert(s.token.clone(), k);
        }
    }
    if gt.samples.is_empty() {
        return Err(crate::error::StudyError::folder(
            ds.root.join(&ds.version),
            format!(
                "split {split:?} has no samples ({} scenes listed); an evaluation over nothing would print mAP 0",
                scenes.len()
            ),
        ));
    }
    let category: BTreeMap<&str, &str> = t
        .instance
        .iter()
        .filter_map(|i| {
            t.category.iter().find(|c| c.token == i.category_token).map(|c| (i.token.as_str(), c.name.as_str()))
        })
        .collect();
    let attribute: BTreeMap<&str, &str> = t.attribute.iter().map(|a| (a.token.as_str(), a.name.as_str())).collect();
    for a in &t.sample_annotation {
        let Some(k) = keys.get(&a.sample_token) else { continue };
        let Some(list) = gt.boxes.get_mut(k) else { continue };
        let Some(class) =
            category.get(a.instance_token.as_str()).and_then(|c| hilo_dataset::writer::class_of_category(c))
        else {
            continue;
        };
        let points = (a.num_lidar_pts + a.num_radar_pts) as i64;
        let v = ds.box_velocity(a);
        list.push(EvalBox {
            sample_token: k.clone(),
            translation: a.translation,
            size: a.size,
            rotation: a.rotation,
            velocity: [v[0], v[1]],
            detection_name: class.name().to_owned(),
            detection_score: -1.0,
            attribute_name: a
                .attribute_tokens
                .first()
                .and_then(|x| attribute.get(x.as_str()))
                .map_or(String::new(), |s| (*s).to_owned()),
            num_pts: match kind {
                GtKind::Common => -1,
                GtKind::VisibleOnly => points,
            },
        });
    }
    Ok((gt, keys))
}

/// Boxes the rig's sensors never hit, as a share of the common ground truth's boxes within the
/// evaluation ranges (per class and over all).
pub fn unseen_share(
    ds: &Dataset,
    split: &str,
    cfg: &hilo_eval::DetectionConfig,
) -> Result<(f64, BTreeMap<String, f64>)> {
    let (gt, _) = ground_truth(ds, split, GtKind::VisibleOnly, SampleKey::Token)?;
    let (mut all, mut unseen) = (0usize, 0usize);
    let mut per: BTreeMap<String, (usize, usize)> = BTreeMap::new();
    for (s, boxes) in &gt.boxes {
        let ego = gt.samples.get(s).map_or([0.0; 3], |i| i.ego_translation);
        for b in boxes {
            let d = ((b.translation[0] - ego[0]).powi(2) + (b.translation[1] - ego[1]).powi(2)).sqrt();
            if !cfg.class_range.get(&b.detection_name).is_some_and(|r| d < *r) {
                continue;
            }
            let e = per.entry(b.detection_name.clone()).or_default();
            e.0 += 1;
            all += 1;
            if b.num_pts == 0 {
                e.1 += 1;
                unseen += 1;
            }
        }
    }
    Ok((
        unseen as f64 / all.max(1) as f64,
        per.into_iter().map(|(c, (n, u))| (c, u as f64 / n.max(1) as f64)).collect(),
    ))
}

/// Detections keyed by sample token, re-keyed to the ground truth's keys (samples without a key
/// are dropped: they are not in the split).
pub fn rekey(results: Vec<(String, Vec<EvalBox>)>, keys: &BTreeMap<String, String>) -> Vec<(String, Vec<EvalBox>)> {
    results
        .into_iter()
        .filter_map(|(s, boxes)| {
            let k = keys.get(&s)?;
            Some((k.clone(), boxes.into_iter().map(|b| EvalBox { sample_token: k.clone(), ..b }).collect()))
        })
        .collect()
}

/// Scene-count vectors of the study's bootstrap: replicate `r` draws `n` scenes with
/// replacement, the same for every detector (seeded by `seed` and `r`).
pub fn scene_draws(n: usize, replicates: usize, seed: u64) -> Vec<Vec<u32>> {
    use rand::{Rng, SeedableRng};
    (0..replicates)
        .map(|r| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ (r as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            let mut c = vec![0u32; n];
            for _ in 0..n {
                c[rng.random_range(0..n)] += 1;
            }
            c
        })
        .collect()
}
