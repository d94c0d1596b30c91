//! Rigs of a set that share their LiDARs: a free, clean measure of what radars add.
//!
//! A validation set often holds rigs whose LiDARs stand at identical poses and that differ
//! only in their radars (the LiDAR-only optimum and the same LiDARs with a radar placed given
//! them, or a budget rig that keeps an optimum's LiDARs). Between two such rigs the LiDAR data
//! are the same recording, so the difference of their trained mAP is the radars' effect plus
//! the trainings' noise and nothing else: the comparison "what the radar adds" wants, and a
//! direct test of the objective's radar terms, which alone can tell such rigs apart.
//!
//! Each group of rigs with the same LiDARs (same type at the same position, heading and
//! tilt) is compared against its member with the fewest radars (the first in the set on a
//! tie). The interval is the 2.5–97.5% percentile of [`crate::resample::difference_replicates`]:
//! the paired scene bootstrap moved by a resample of both rigs' trainings, the common part of a
//! training-traffic draw cancelling. With the calibrated objective, each pair also gets the
//! difference of the two rigs' out-of-fold predictions, and whether it has the measured sign.

use crate::{ValidationReport, rank};
use hilo_placement_ip::{Modality, PlacedSensor};
use std::collections::BTreeMap;

/// One rig against the member of its group with the fewest radars.
#[derive(Clone, Debug, PartialEq)]
pub struct Pair {
    /// The rig with more radars, and the one it is compared against (indices into the set).
    pub with: usize,
    pub base: usize,
    /// Radars of each rig.
    pub radars: (usize, usize),
    /// The radars of `with` that hang on a structure holding one of its LiDARs.
    pub radars_on_lidar_structures: usize,
    /// Mean mAP of `with` less that of `base`, and its 95% interval.
    pub difference: f64,
    pub lo: f64,
    pub hi: f64,
    /// The calibrated objective's out-of-fold prediction for `with` less that for `base`
    /// (None without a calibrated objective that predicted both).
    pub predicted: Option<f64>,
}

/// A LiDAR's identity within a set: its type and its pose to the millimetre and the
/// hundredth of a degree (one candidate pose of one scene).
fn lidar_key(s: &PlacedSensor) -> (String, [i64; 5]) {
    let mm = |v: f32| (f64::from(v) * 1000.0).round() as i64;
    let cdeg = |v: f32| (f64::from(v).to_degrees() * 100.0).round() as i64;
    let p = s.pose.position;
    (s.ty.clone(), [mm(p.x), mm(p.y), mm(p.z), cdeg(s.pose.yaw), cdeg(s.pose.pitch)])
}

/// Every pair of rigs with the same LiDARs in `r`'s set: each group of two or more against
/// its member with the fewest radars. Rigs without a LiDAR are left out.
pub fn pairs(r: &ValidationReport) -> Vec<Pair> {
    let mut groups: BTreeMap<Vec<(String, [i64; 5])>, Vec<usize>> = BTreeMap::new();
    for (i, (m, _)) in r.members.iter().enumerate() {
        let mut key: Vec<_> =
            m.placement.sensors.iter().filter(|s| s.modality == Modality::Lidar).map(lidar_key).collect();
        if key.is_empty() {
            continue;
        }
        key.sort();
        groups.entry(key).or_default().push(i);
    }
    let radars = |i: usize| r.members[i].0.placement.sensors.iter().filter(|s| s.modality == Modality::Radar).count();
    let predicted: Option<BTreeMap<&str, f64>> =
        r.calibrated.as_ref().map(|c| c.held_out.iter().map(|h| (h.placement.as_str(), h.predicted)).collect());
    let mut out = Vec::new();
    for members in groups.values().filter(|g| g.len() > 1) {
        let Some(&base) = members.iter().min_by_key(|&&i| (radars(i), i)) else { continue };
        for &with in members.iter().filter(|&&i| i != base) {
            let (m, t) = &r.members[with];
            let tb = &r.members[base].1;
            let structures: Vec<&str> = m
                .placement
                .sensors
                .iter()
                .filter(|s| s.modality == Modality::Lidar)
                .map(|s| s.structure.as_str())
                .collect();
            let mut d = crate::resample::difference_replicates(t, tb, r.settings.seed);
            d.retain(|v| v.is_finite());
            d.sort_by(f64::total_cmp);
            let slug = |i: usize| r.members[i].0.slug.as_str();
            out.push(Pair {
                with,
                base,
                radars: (radars(with), radars(base)),
                radars_on_lidar_structures: m
                    .placement
                    .sensors
                    .iter()
                    .filter(|s| s.modality == Modality::Radar && structures.contains(&s.structure.as_str()))
                    .count(),
                difference: t.map_mean - tb.map_mean,
                lo: rank::percentile(&d, 0.025),
                hi: rank::percentile(&d, 0.975),
                predicted: predicted.as_ref().and_then(|p| Some(p.get(slug(with))? - p.get(slug(base))?)),
            });
        }
    }
    out.sort_by_key(|p| (p.base, p.with));
    out
}

/// The report's section on rigs with the same LiDARs (empty when the set holds none).
pub fn markdown(r: &ValidationReport) -> String {
    let pairs = pairs(r);
    if pairs.is_empty() {
        return String::new();
    }
    let slug = |i: usize| r.members[i].0.slug.as_str();
    let mut s = String::from("## Rigs with the same LiDARs\n\n");
    let above = pairs.iter().filter(|p| p.lo > 0.0).count();
    let below = pairs.iter().filter(|p| p.hi < 0.0).count();
    let mean = pairs.iter().map(|p| p.difference).sum::<f64>() / pairs.len() as f64;
    s.push_str(&format!(
        "{} pair(s) of rigs whose LiDARs stand at identical poses and that differ only in their radars: the same \
         LiDAR recording, so the difference in trained mAP is what the radars add plus the trainings' noise. Mean \
         difference {mean:+.3} mAP; {above} interval(s) above zero, {below} below, {} include zero (95%, paired \
         scene bootstrap with the trainings resampled).",
        pairs.len(),
        pairs.len() - above - below
    ));
    let judged: Vec<&Pair> = pairs.iter().filter(|p| p.predicted.is_some()).collect();
    if !judged.is_empty() {
        let sign = judged.iter().filter(|p| p.predicted.unwrap_or(0.0) * p.difference > 0.0).count();
        let decided: Vec<&&Pair> = judged.iter().filter(|p| p.lo > 0.0 || p.hi < 0.0).collect();
        let decided_sign = decided.iter().filter(|p| p.predicted.unwrap_or(0.0) * p.difference > 0.0).count();
        s.push_str(&format!(
            " Only the calibrated objective's radar terms can tell such rigs apart: its out-of-fold predictions \
             have the measured sign in {sign} of {} pair(s) ({decided_sign} of the {} whose interval excludes zero).",
            judged.len(),
            decided.len()
        ));
    }
    s.push_str(
        "\n\n| rig | against | radars | radars on a LiDAR's structure | mAP difference | 95% interval | predicted |\n\
         |---|---|---:|---:|---:|---|---:|\n",
    );
    for p in &pairs {
        s.push_str(&format!(
            "| {} | {} | {} vs {} | {} | {:+.3} | [{:+.3}, {:+.3}] | {} |\n",
            slug(p.with),
            slug(p.base),
            p.radars.0,
            p.radars.1,
            p.radars_on_lidar_structures,
            p.difference,
            p.lo,
            p.hi,
            p.predicted.map_or("–".into(), |v| format!("{v:+.3}"))
        ));
    }
    s.push('\n');
    s
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::calibrate::HeldOut;
    use crate::testing;
    use rand::SeedableRng;

    fn sensor(ty: &str, modality: &str, structure: &str, x: f32, yaw: f32) -> serde_json::Value {
        serde_json::json!({
            "type": ty, "modality": modality, "candidate_id": 0, "structure": structure,
            "pose": { "position": [x, 1.0, 4.0], "yaw": yaw, "pitch": 0.1, "roll": 0.0 },
            "position_m": [x, 1.0, 4.0], "yaw_deg": yaw.to_degrees(), "pitch_deg": 5.73
        })
    }

    /// Members with these sensors; member i's trainings score `map[i]` (two seeds, ±0.01).
    fn set(rigs: Vec<Vec<serde_json::Value>>, map: &[f64]) -> ValidationReport {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let members = rigs
            .into_iter()
            .zip(map)
            .enumerate()
            .map(|(i, (sensors, &v))| {
                let (mut m, mut t) = testing::member(i, BTreeMap::new(), v, 200, &mut rng);
                m.placement.sensors = serde_json::from_value(serde_json::Value::Array(sensors)).unwrap();
                t.map = vec![v - 0.01, v + 0.01];
                (m, t)
            })
            .collect();
        testing::report(members, 200, "s.toml", "tiny")
    }

    /// Groups form on identical LiDAR poses only (a LiDAR turned by a degree, or of another
    /// type, is another group); each is compared against its member with the fewest radars;
    /// radars on a LiDAR's pole are counted; the interval brackets the difference; the fit's
    /// prediction is the difference of the two rigs' out-of-fold predictions.
    #[test]
    fn rigs_pair_on_identical_lidars_against_the_fewest_radars() {
        let l = |x: f32, yaw: f32| sensor("lidar-16", "lidar", "N/pole", x, yaw);
        let radar = |structure: &str| sensor("radar-4d", "radar", structure, 2.0, 0.0);
        let mut r = set(
            vec![
                vec![l(0.0, 0.5), radar("N/pole"), radar("S/pole")], // 0: two radars
                vec![l(0.0, 0.5)],                                   // 1: the base
                vec![l(0.0, 0.5), radar("S/pole")],                  // 2: one radar
                vec![l(0.0, 0.5 + 1f32.to_radians())],               // 3: turned: alone
                vec![sensor("lidar-32", "lidar", "N/pole", 0.0, 0.5), radar("S/pole")], // 4: other type
                vec![radar("S/pole")],                               // 5: no LiDAR
            ],
            &[0.50, 0.40, 0.45, 0.41, 0.30, 0.10],
        );
        let p = pairs(&r);
        assert_eq!(p.iter().map(|p| (p.with, p.base)).collect::<Vec<_>>(), vec![(0, 1), (2, 1)]);
        assert_eq!((p[0].radars, p[0].radars_on_lidar_structures), ((2, 0), 1));
        assert_eq!((p[1].radars, p[1].radars_on_lidar_structures), ((1, 0), 0));
        assert!((p[0].difference - 0.10).abs() < 1e-12 && p[0].lo < 0.10 && p[0].hi > 0.10);
        assert!(p[0].lo > 0.0, "a difference of 0.10 with noise of 0.01 is decided: {:?}", p[0]);
        assert!(p.iter().all(|p| p.predicted.is_none()));
        let md = markdown(&r);
        assert!(
            md.starts_with("## Rigs with the same LiDARs") && md.contains("| p0 | p1 | 2 vs 0 | 1 | +0.100 |"),
            "{md}"
        );
        // A fit that predicted every rig: differences of its predictions, and their sign judged.
        let none = crate::rank::Agreement { value: f64::NAN, lo: f64::NAN, hi: f64::NAN, n: 0 };
        r.calibrated = Some(crate::calibrate::Calibrated {
            features: Vec::new(),
            intercept: 0.0,
            weights: Vec::new(),
            fit_on: Vec::new(),
            residual_sd: 0.0,
            df: 0,
            loo_rmse: 0.0,
            folds: 0,
            held_out: [0.6, 0.4, 0.3, 0.4, 0.3, 0.1]
                .iter()
                .enumerate()
                .map(|(i, &v)| HeldOut { placement: format!("p{i}"), predicted: v, lo: 0.0, hi: 1.0, measured: 0.0 })
                .collect(),
            held_out_spearman: none,
            held_out_kendall: none,
            paper_held_out_spearman: none,
            covered: 0,
            reshuffled_spearman: Vec::new(),
        });
        let p = pairs(&r);
        assert!((p[0].predicted.unwrap() - 0.2).abs() < 1e-12 && (p[1].predicted.unwrap() + 0.1).abs() < 1e-12);
        assert!(markdown(&r).contains("measured sign in 1 of 2 pair(s)"), "{}", markdown(&r));
        // No two rigs share their LiDARs: no section.
        r.members.truncate(2);
        r.members[1].0.placement.sensors.clear();
        assert!(pairs(&r).is_empty() && markdown(&r).is_empty());
    }
}
