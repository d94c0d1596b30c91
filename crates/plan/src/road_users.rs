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
//!
//! [`TrafficPoints`] scans sampled key frames of the same traffic with a rig's LiDARs, as the
//! dataset would: the points on each road user ([`TrafficPoints::points`]) and
//! where they fall on it ([`TrafficPoints::per_user`]); [`TrafficPoints::occupancy`] gives a
//! rig's point term and its footprint term (the share of each road user's footprint the points
//! span, summed LiDAR by LiDAR: [`footprint_extent`]) from one scan.

use crate::error::Result;
use crate::study::Study;
use hilo_dataset::simulate::{SceneId, Split, key_frame_states};
use hilo_dataset::traffic::ActorState;
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

/// The key frames of a study's training scenes, its traffic stepped once without sensors, and
/// which road users count: what [`road_users`] and [`TrafficPoints`] both read.
#[derive(Clone, Debug)]
pub struct TrainingTraffic {
    /// Per training scene, its key frames' road users.
    scenes: Vec<(SceneId, Vec<Vec<ActorState>>)>,
    /// The evaluated classes (in the order of [`hilo_core::Class::ALL`]) and their ranges.
    classes: Vec<&'static str>,
    ranges: BTreeMap<String, f64>,
    seed: u64,
}

impl TrainingTraffic {
    /// Steps the traffic of `study`'s training scenes.
    pub fn new(study: &Study) -> Result<TrainingTraffic> {
        let ranges = study.file.detection_config().class_range;
        let classes = hilo_core::Class::ALL.iter().map(|c| c.name()).filter(|n| ranges.contains_key(*n)).collect();
        let scenes = study
            .dataset
            .scene_ids()
            .into_iter()
            .filter(|id| id.split == Split::Train)
            .map(|id| Ok((id, key_frame_states(&study.scene, &study.dataset, &id)?)))
            .collect::<Result<_>>()?;
        Ok(TrainingTraffic { scenes, classes, ranges, seed: study.dataset.seed })
    }

    /// The index in `classes` of road user `a`'s class when it counts: the class is evaluated
    /// and the centre lies within its range of the origin.
    fn counted(&self, a: &ActorState) -> Option<usize> {
        let c = self.classes.iter().position(|n| *n == a.class.name())?;
        (f64::from(a.box3.center.truncate().length()) < self.ranges[self.classes[c]]).then_some(c)
    }
}

/// Counts the road users of the training traffic on `targets`, a grid of `cell_m` squares.
pub fn road_users(traffic: &TrainingTraffic, targets: &[Target], cell_m: f32) -> Result<RoadUsers> {
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
    let mut on: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    let mut per_class: BTreeMap<String, usize> = BTreeMap::new();
    let (mut off_targets, mut key_frames) = (0, 0);
    for (_, frames) in &traffic.scenes {
        for frame in frames {
            key_frames += 1;
            for a in frame {
                let Some(c) = traffic.counted(a) else { continue };
                let (name, p) = (traffic.classes[c], a.box3.center.truncate());
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
    Ok(RoadUsers { weights, per_class, off_targets, scenes: traffic.scenes.len(), key_frames })
}

/// Sampled frames of the study's training traffic with the LiDAR points a rig puts on each road
/// user: the occupancy predictor computed from the placement alone (no dataset), on traffic the
/// validation split does not hold.
///
/// Every `every`-th key frame of each training scene is kept; each LiDAR of the rig is simulated
/// on it as the dataset simulates it (the same scan, seeds and occlusion by buildings and by the
/// other road users: a rig's dataset of the training scenes holds these counts), and each road
/// user within its class's evaluation range gets the points of all LiDARs summed, as the
/// dataset's `num_lidar_pts` sums them. Per class the mean over (frame, road user) of
/// min(1, n / k) (points capped at k: linear in per-sensor terms, the form an IP can hold) and
/// of [n ≥ k] (the share hit by k points); each averaged over classes, as mAP averages them.
pub struct TrafficPoints {
    /// Per frame: the road users as the ray engine sees them, (scene stream, key frame index)
    /// for the seeds, and the road users that count with their class's index.
    frames: Vec<Frame>,
    classes: usize,
    /// The evaluated classes' names, by index.
    names: Vec<&'static str>,
    seed: u64,
}

struct Frame {
    actors: hilo_raycast::ActorSet,
    stream: u64,
    index: usize,
    users: Vec<(u32, usize)>,
}

impl std::fmt::Debug for TrafficPoints {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "TrafficPoints {{ frames: {}, classes: {} }}", self.frames.len(), self.classes)
    }
}

/// A LiDAR of a rig: its index among the rig's sensors (the dataset's seeds follow it), spec
/// and pose.
pub type RigLidar = (usize, hilo_sensor_models::LidarSpec, hilo_sensor_models::SensorPose);

impl TrafficPoints {
    /// Every `every`-th key frame of each training scene of `traffic`.
    pub fn new(traffic: &TrainingTraffic, every: usize) -> Result<TrafficPoints> {
        let mut frames = Vec::new();
        for (id, states) in &traffic.scenes {
            for (index, states) in states.iter().enumerate().step_by(every.max(1)) {
                let users: Vec<(u32, usize)> =
                    states.iter().filter_map(|a| traffic.counted(a).map(|c| (a.id, c))).collect();
                let actors = hilo_raycast::ActorSet::new(states.iter().map(|a| a.actor()).collect())
                    .map_err(|e| crate::error::StudyError::step(format!("training traffic, {}", id.name()), e))?;
                frames.push(Frame { actors, stream: id.stream(), index, users });
            }
        }
        Ok(TrafficPoints { frames, classes: traffic.classes.len(), names: traffic.classes.clone(), seed: traffic.seed })
    }

    /// Frames held.
    pub fn frames(&self) -> usize {
        self.frames.len()
    }

    /// Per frame, the LiDAR points of `lidars` on each road user (by id; every road user of the
    /// frame, in range or not).
    pub fn points(&self, world: &hilo_raycast::World, lidars: &[RigLidar]) -> Result<Vec<BTreeMap<u32, usize>>> {
        self.frames
            .iter()
            .map(|fr| {
                let mut points: BTreeMap<u32, usize> = BTreeMap::new();
                for (k, spec, pose) in lidars {
                    let scan = self.scan(world, fr, *k, spec, pose)?;
                    for (a, n) in scan.points_per_actor() {
                        *points.entry(a).or_default() += n;
                    }
                }
                Ok(points)
            })
            .collect()
    }

    /// The calibrated objective's point-count rows ([`hilo_placement_ip::instance::PointRows`])
    /// for options whose LiDAR pose (or `None`: a radar) `lidar_of(o)` gives: every counted road
    /// user of every frame is a sample, weighted 1 / (its class's samples × classes); each
    /// option's points on them are counted with [`hilo_sensor_models::lidar_points_on`] (rays cast
    /// only towards the road users, the full scan's counts exactly) as if it were the rig's
    /// first sensor (the dataset seeds a sensor's dropouts by its place in the rig, so a rig's
    /// own count, [`TrafficPoints::occupancy`], differs from the term's by those draws alone).
    pub fn rows(
        &self,
        world: &hilo_raycast::World,
        options: usize,
        lidar_of: impl Fn(usize) -> Option<(hilo_sensor_models::LidarSpec, hilo_sensor_models::SensorPose)> + Sync,
        k: u32,
    ) -> Result<hilo_placement_ip::instance::PointRows> {
        let rows = self.option_rows(options, lidar_of, |spec, pose, fr, seed, ids| {
            hilo_sensor_models::lidar_points_on(spec, pose, world, &fr.actors, seed, ids)
                .map(|n| ids.iter().map(|id| n.get(id).map_or(0, |&p| p as u32)).collect())
        })?;
        Ok(hilo_placement_ip::instance::PointRows { k: f64::from(k.max(1)), weights: self.sample_weights(), rows })
    }

    /// The calibrated objective's footprint rows ([`hilo_placement_ip::Instance::extents`]): the
    /// samples of [`TrafficPoints::rows`], and per option the share of each one's footprint its
    /// points span ([`footprint_extent`]), in thousandths rounded to the nearest; its points are
    /// those [`TrafficPoints::rows`] counts.
    pub fn extent_rows(
        &self,
        world: &hilo_raycast::World,
        options: usize,
        lidar_of: impl Fn(usize) -> Option<(hilo_sensor_models::LidarSpec, hilo_sensor_models::SensorPose)> + Sync,
    ) -> Result<hilo_placement_ip::instance::PointRows> {
        use hilo_placement_ip::instance::EXTENT_UNITS;
        let rows = self.option_rows(options, lidar_of, |spec, pose, fr, seed, ids| {
            let mut on: BTreeMap<u32, Vec<glam::Vec3>> = BTreeMap::new();
            hilo_sensor_models::lidar_points_on_each(spec, pose, world, &fr.actors, seed, ids, |id, q| {
                on.entry(id).or_default().push(q)
            })?;
            Ok(ids
                .iter()
                .map(|id| {
                    let actor = fr.actors.actors().iter().find(|a| a.id == *id);
                    match (actor, on.get(id)) {
                        (Some(a), Some(q)) => (footprint_extent(a, q.iter().copied()) * EXTENT_UNITS).round() as u32,
                        _ => 0,
                    }
                })
                .collect())
        })?;
        Ok(hilo_placement_ip::instance::PointRows { k: EXTENT_UNITS, weights: self.sample_weights(), rows })
    }

    /// Per evaluated class with sampled road users (by name), the share of them that none of
    /// the `lidars` LiDARs (`lidar_of`, each scanning as in [`TrafficPoints::rows`]) puts a
    /// point on.
    pub fn never_hit(
        &self,
        world: &hilo_raycast::World,
        lidars: usize,
        lidar_of: impl Fn(usize) -> Option<(hilo_sensor_models::LidarSpec, hilo_sensor_models::SensorPose)> + Sync,
    ) -> Result<BTreeMap<String, f64>> {
        let rows = self.rows(world, lidars, lidar_of, 1)?;
        let mut hit = vec![false; self.frames.iter().map(|fr| fr.users.len()).sum()];
        for &(sample, _) in rows.rows.iter().flatten() {
            hit[sample as usize] = true;
        }
        let mut counts = vec![(0usize, 0usize); self.classes];
        for (c, h) in self.sample_classes().zip(&hit) {
            counts[c].0 += 1;
            counts[c].1 += usize::from(!*h);
        }
        Ok(counts
            .iter()
            .zip(&self.names)
            .filter(|((n, _), _)| *n > 0)
            .map(|((n, missed), name)| ((*name).to_owned(), *missed as f64 / *n as f64))
            .collect())
    }

    /// The hit floors of `shares` (`[placement] min_hit_share` of the study file `source`) over
    /// the options of `points` (their [`TrafficPoints::rows`]): per class, its samples and, per
    /// option, those it puts a point on, numbered among the class's samples. A class with no
    /// sample (not evaluated, or absent from the traffic) is refused by name.
    pub fn hit_floors(
        &self,
        points: &hilo_placement_ip::instance::PointRows,
        shares: &BTreeMap<hilo_core::Class, f64>,
        source: &str,
    ) -> Result<Vec<hilo_placement_ip::instance::HitFloor>> {
        let classes: Vec<usize> = self.sample_classes().collect();
        let mut floors = Vec::new();
        for (class, &share) in shares {
            // Each sample of the class by its index among the class's samples.
            let mut local = vec![None; classes.len()];
            let mut samples = 0u32;
            for (s, &c) in classes.iter().enumerate() {
                if self.names[c] == class.name() {
                    local[s] = Some(samples);
                    samples += 1;
                }
            }
            if samples == 0 {
                return Err(crate::error::StudyError::setting(
                    source,
                    format!("placement.min_hit_share.{class}"),
                    share,
                    format!("the sampled training traffic holds no {class} within its evaluation range"),
                ));
            }
            let rows =
                points.rows.iter().map(|row| row.iter().filter_map(|&(s, _)| local.get(s as usize).copied().flatten()));
            floors.push(hilo_placement_ip::instance::HitFloor {
                class: class.name().to_owned(),
                share,
                samples,
                rows: rows.map(Iterator::collect).collect(),
            });
        }
        Ok(floors)
    }

    /// Every counted road user of every frame as a sample, weighted 1 / (its class's samples ×
    /// classes), frame by frame.
    fn sample_weights(&self) -> Vec<f64> {
        let mut per_class = vec![0usize; self.classes];
        for c in self.sample_classes() {
            per_class[c] += 1;
        }
        let seen = per_class.iter().filter(|&&n| n > 0).count().max(1) as f64;
        self.sample_classes().map(|c| 1.0 / (per_class[c] as f64 * seen)).collect()
    }

    /// Per sample (every counted road user of every frame, frame by frame, as the rows number
    /// them), its class's index.
    fn sample_classes(&self) -> impl Iterator<Item = usize> + '_ {
        self.frames.iter().flat_map(|fr| fr.users.iter().map(|u| u.1))
    }

    /// Per option (its LiDAR from `lidar_of`; none: an empty row), (sample, value) for the
    /// samples of non-zero value, `value` giving per frame the values of its counted road users
    /// (`ids`) as a rig's first sensor scans them (`seed`).
    fn option_rows(
        &self,
        options: usize,
        lidar_of: impl Fn(usize) -> Option<(hilo_sensor_models::LidarSpec, hilo_sensor_models::SensorPose)> + Sync,
        value: impl Fn(
            &hilo_sensor_models::LidarSpec,
            &hilo_sensor_models::SensorPose,
            &Frame,
            u64,
            &[u32],
        ) -> std::result::Result<Vec<u32>, hilo_sensor_models::SensorError>
        + Sync,
    ) -> Result<Vec<Vec<(u32, u32)>>> {
        use rayon::prelude::*;
        let mut first = Vec::with_capacity(self.frames.len());
        let mut n = 0usize;
        for fr in &self.frames {
            first.push(n);
            n += fr.users.len();
        }
        // Per frame, the counted road users' ids and the seed a rig's first sensor scans it with.
        let frames: Vec<(Vec<u32>, u64)> = self
            .frames
            .iter()
            .map(|fr| {
                let seed = hilo_dataset::simulate::derive_seed(self.seed, &[2, fr.stream, fr.index as u64, 0]);
                (fr.users.iter().map(|u| u.0).collect(), seed)
            })
            .collect();
        (0..options)
            .into_par_iter()
            .map(|o| {
                let Some((spec, pose)) = lidar_of(o) else { return Ok(Vec::new()) };
                let mut row = Vec::new();
                for ((fr, &base), (ids, seed)) in self.frames.iter().zip(&first).zip(&frames) {
                    let v = value(&spec, &pose, fr, *seed, ids).map_err(|e| {
                        crate::error::StudyError::step(format!("LiDAR option {o} on a training key frame"), e)
                    })?;
                    row.extend(v.iter().enumerate().filter(|(_, v)| **v > 0).map(|(i, v)| ((base + i) as u32, *v)));
                }
                Ok(row)
            })
            .collect()
    }

    /// Per evaluated class (in the order of [`hilo_core::Class::ALL`]), `summary` of each counted
    /// road user of every frame, frame by frame: the road user as the rays see it and the points
    /// of `lidars` on it, in the scene frame, each with the index into `lidars` of the LiDAR
    /// that returned it. The points are those [`TrafficPoints::points`] counts.
    pub fn per_user<T>(
        &self,
        world: &hilo_raycast::World,
        lidars: &[RigLidar],
        summary: impl Fn(&hilo_raycast::Actor, &[(usize, glam::Vec3)]) -> T,
    ) -> Result<Vec<Vec<T>>> {
        let mut out: Vec<Vec<T>> = (0..self.classes).map(|_| Vec::new()).collect();
        for fr in &self.frames {
            let mut points: BTreeMap<u32, Vec<(usize, glam::Vec3)>> = BTreeMap::new();
            for (l, (k, spec, pose)) in lidars.iter().enumerate() {
                let scan = self.scan(world, fr, *k, spec, pose)?;
                for (p, s) in scan.points_local().iter().zip(&scan.sources) {
                    if let Some(a) = s.actor() {
                        points.entry(a).or_default().push((l, glam::Vec3::new(p.x, p.y, p.z)));
                    }
                }
            }
            for &(a, c) in &fr.users {
                let Some(actor) = fr.actors.actors().iter().find(|x| x.id == a) else { continue };
                out[c].push(summary(actor, points.get(&a).map_or(&[], Vec::as_slice)));
            }
        }
        Ok(out)
    }

    /// LiDAR `k` of a rig on frame `fr`, seeded as the dataset seeds it.
    fn scan(
        &self,
        world: &hilo_raycast::World,
        fr: &Frame,
        k: usize,
        spec: &hilo_sensor_models::LidarSpec,
        pose: &hilo_sensor_models::SensorPose,
    ) -> Result<hilo_sensor_models::LidarScan> {
        let seed = hilo_dataset::simulate::derive_seed(self.seed, &[2, fr.stream, fr.index as u64, k as u64]);
        hilo_sensor_models::simulate_lidar(spec, pose, world, Some(&fr.actors), seed)
            .map_err(|e| crate::error::StudyError::step(format!("LiDAR {k} on a training key frame"), e))
    }

    /// What the LiDARs `lidars` show of the counted road users, class-balanced, from one scan of
    /// every frame ([`Occupancy`]).
    pub fn occupancy(&self, world: &hilo_raycast::World, lidars: &[RigLidar], k: u32) -> Result<Occupancy> {
        let per_class = self.per_user(world, lidars, |a, points| {
            let extent = (0..lidars.len())
                .map(|l| footprint_extent(a, points.iter().filter(|p| p.0 == l).map(|p| p.1)))
                .sum::<f64>()
                .min(1.0);
            (points.len() as f64, extent)
        })?;
        // Per class: the sums of min(1, n / k), [n ≥ k] and the extent, and the road users.
        let mut sum = vec![([0.0f64; 3], 0usize); self.classes];
        for (c, users) in per_class.into_iter().enumerate() {
            for (n, extent) in users {
                sum[c].0[0] += (n / f64::from(k.max(1))).min(1.0);
                sum[c].0[1] += if n >= f64::from(k) { 1.0 } else { 0.0 };
                sum[c].0[2] += extent;
                sum[c].1 += 1;
            }
        }
        let seen: Vec<_> = sum.iter().filter(|s| s.1 > 0).collect();
        let mean = |i: usize| seen.iter().map(|s| s.0[i] / s.1 as f64).sum::<f64>() / seen.len().max(1) as f64;
        Ok(Occupancy { capped: mean(0), hit: mean(1), extent: mean(2) })
    }
}

/// What a rig's LiDARs show of the counted road users of the sampled training traffic, each a
/// mean over the road users of a class, averaged over classes as mAP averages them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Occupancy {
    /// min(1, n / k) for a road user with n LiDAR points: linear in per-sensor terms under a
    /// cap, the form an IP can hold (the point term).
    pub capped: f64,
    /// [n ≥ k]: the share hit by k points.
    pub hit: f64,
    /// min(1, Σ_l e_l), e_l the share of the road user's footprint that LiDAR l's points span
    /// ([`footprint_extent`]): how much of its length and width the rig shows a detector, one
    /// LiDAR's view at a time; summed and capped like the point count, so an IP can hold it
    /// (the footprint term).
    pub extent: f64,
}

/// The share of a road user's footprint that `points` (scene frame) span: in its own frame,
/// the product over its length and its width of min(1, the points' spread along that axis / the
/// axis's size); a pedestrian's capsule counts as a square of its diameter. 0 below two points.
/// One face seen end-on spans its width but none of its length, so a view along a road user
/// scores less than a view of its corner with the same points: where the centre and heading
/// sit is what a detector must regress, and the points' extent is what shows it.
pub fn footprint_extent(actor: &hilo_raycast::Actor, points: impl Iterator<Item = glam::Vec3>) -> f64 {
    let b = actor.shape.outline();
    let (centre, size, yaw) = (b.center.truncate(), glam::Vec2::new(b.length_m, b.width_m), b.yaw);
    let to_local = glam::Mat2::from_angle(-yaw);
    let (mut lo, mut hi, mut n) = (glam::Vec2::INFINITY, glam::Vec2::NEG_INFINITY, 0usize);
    for p in points {
        let q = to_local * (p.truncate() - centre);
        lo = lo.min(q);
        hi = hi.max(q);
        n += 1;
    }
    if n < 2 || size.min_element() <= 0.0 {
        return 0.0;
    }
    let share = ((hi - lo) / size).min(glam::Vec2::ONE);
    f64::from(share.x) * f64::from(share.y)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    /// The default study on the paper's sensors and a perfect rig, with `scenes` training scenes
    /// of 2 s (20 key frames each). A field rig's dataset (calibration and clock errors, the
    /// rolling shutter, swaying foliage) moves its points off the count this predictor makes
    /// from the placement's poses: a predictor, not the dataset.
    fn small_study(scenes: usize) -> Study {
        let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
        let study = Study::load(&fixtures.join("paper-sensors-study.toml")).unwrap();
        let dataset = hilo_dataset::simulate::SimulateConfig {
            scenes,
            seconds: 2.0,
            val_scenes: 1,
            ..study.dataset.clone().into_inner()
        };
        Study { dataset: dataset.validate().unwrap(), ..study }
    }

    /// Against a brute-force count: every counted road user found on the one target whose cell
    /// holds its centre (a linear search over all targets), class-balanced by hand; the weights
    /// sum to the share of road users on targets, averaged over classes.
    #[test]
    fn road_user_weights_equal_a_brute_force_count() {
        let study = small_study(2);
        let cell_m = 2.0;
        let targets = hilo_placement_ip::targets::roi_targets(&study.scene, cell_m).unwrap();
        let got = road_users(&TrainingTraffic::new(&study).unwrap(), &targets, cell_m).unwrap();
        assert_eq!((got.scenes, got.key_frames), (2, 40));
        let ranges = study.file.detection_config().class_range;
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

    /// The points the predictor counts are the dataset's: a rig's dataset of the same training
    /// scenes annotates every road user of the sampled key frames with exactly these LiDAR
    /// points (same scans, seeds and occlusion), a radar among the sensors changing nothing.
    #[test]
    fn traffic_points_are_the_datasets_lidar_points() {
        use hilo_dataset::simulate::{RigSensor, simulate_scene};
        use hilo_sensor_models::{Catalog, SensorPose, SensorSpec};
        let study = small_study(1);
        let catalog = Catalog::default_catalog().unwrap();
        let pose = |m: usize, z: f32| {
            let m = &study.scene.mounts[m];
            let p = m.base + m.arm_dir * (0.5 * m.arm_length_m);
            SensorPose::new(p.extend(study.scene.ground.z_m + m.arm_height_m + z), (-p.y).atan2(-p.x), 0.17, 0.0)
        };
        let rig: Vec<RigSensor> = [("lidar-16", 0, 0.4), ("radar-4d", 0, 0.1), ("lidar-32", 1, 0.4)]
            .iter()
            .enumerate()
            .map(|(k, &(ty, m, z))| RigSensor {
                channel: format!("S{k}"),
                spec: catalog.get(ty).unwrap().clone(),
                pose: pose(m, z),
            })
            .collect();
        let lidars: Vec<RigLidar> = rig
            .iter()
            .enumerate()
            .filter_map(|(k, s)| match &s.spec {
                SensorSpec::Lidar(l) => Some((k, l.clone(), s.pose)),
                SensorSpec::Radar(_) => None,
            })
            .collect();
        let world = hilo_raycast::World::build(&study.scene, &hilo_raycast::QueryRegion::everything()).unwrap();
        let every = 7;
        let tp = TrafficPoints::new(&TrainingTraffic::new(&study).unwrap(), every).unwrap();
        assert_eq!(tp.frames(), 3, "key frames 0, 7 and 14 of one 20-frame scene");
        let counted = tp.points(&world, &lidars).unwrap();
        let id = SceneId { split: Split::Train, index: 0 };
        let data = simulate_scene(&study.scene, &world, &rig, &study.dataset, &id).unwrap();
        let mut hit = 0;
        for (f, points) in counted.iter().enumerate() {
            for a in &data.frames[f * every].annotations {
                assert_eq!(points.get(&a.instance).copied().unwrap_or(0) as u32, a.num_lidar_pts, "frame {f}");
                hit += usize::from(a.num_lidar_pts > 0);
            }
        }
        assert!(hit > 3, "the rig sees road users: {hit}");
        let o = tp.occupancy(&world, &lidars, 5).unwrap();
        assert!(o.capped >= o.hit && o.capped > 0.0 && o.hit <= 1.0, "{o:?}");
    }

    /// The calibrated objective's point-count term over rows from [`TrafficPoints::rows`]
    /// against a brute-force count: every chosen LiDAR's full scan of every sampled frame (seeded
    /// as the rows are), points summed per road user, min(1, n / k) averaged per class and over
    /// classes; for every selection of three LiDAR options and a radar (which adds nothing).
    #[test]
    fn the_point_term_equals_a_brute_force_count() {
        use hilo_placement_ip::Modality;
        use hilo_placement_ip::calibrated::{Weights, evaluate};
        use hilo_placement_ip::instance::{Instance, SensorOption, SensorType};
        use hilo_sensor_models::{Catalog, SensorPose};
        let study = small_study(1);
        let catalog = Catalog::default_catalog().unwrap();
        let pose = |m: usize| {
            let m = &study.scene.mounts[m];
            let p = m.base + m.arm_dir * (0.5 * m.arm_length_m);
            SensorPose::new(p.extend(study.scene.ground.z_m + m.arm_height_m + 0.4), (-p.y).atan2(-p.x), 0.17, 0.0)
        };
        // Options: three LiDARs on three mounts, then a radar.
        let lidar = |o: usize| -> Option<(hilo_sensor_models::LidarSpec, SensorPose)> {
            let ty = ["lidar-16", "lidar-64", "lidar-32"].get(o)?;
            Some((catalog.lidar(ty).unwrap().clone(), pose(o)))
        };
        let world = hilo_raycast::World::build(&study.scene, &hilo_raycast::QueryRegion::everything()).unwrap();
        let traffic = TrainingTraffic::new(&study).unwrap();
        let tp = TrafficPoints::new(&traffic, 5).unwrap();
        let k = 5;
        let rows = tp.rows(&world, 4, lidar, k).unwrap();
        assert!(rows.rows[3].is_empty() && rows.rows[..3].iter().all(|r| !r.is_empty()), "{:?}", rows.rows);
        let inst = Instance {
            weights: vec![1.0],
            types: vec![
                SensorType { name: "l".into(), modality: Modality::Lidar, price_usd: 1.0 },
                SensorType { name: "r".into(), modality: Modality::Radar, price_usd: 1.0 },
            ],
            options: (0..4)
                .map(|o| SensorOption {
                    ty: usize::from(o == 3),
                    candidate: o as u32,
                    mount: o as u32,
                    row: Vec::new(),
                })
                .collect(),
            p_min: 0.5,
            road_users: Vec::new(),
            points: rows,
            extents: tp.extent_rows(&world, 4, lidar).unwrap(),
            floors: Vec::new(),
        };
        // The hit floors of every class the sampled traffic holds; one it does not hold is refused.
        let present: std::collections::BTreeSet<usize> =
            tp.frames.iter().flat_map(|fr| fr.users.iter().map(|u| u.1)).collect();
        let shares: BTreeMap<hilo_core::Class, f64> =
            present.iter().map(|&c| (tp.names[c].parse().unwrap(), 0.5)).collect();
        let inst = Instance { floors: tp.hit_floors(&inst.points, &shares, "study.toml").unwrap(), ..inst };
        let cyclists = BTreeMap::from([(hilo_core::Class::Bicycle, 0.5)]);
        let e = tp.hit_floors(&inst.points, &cyclists, "study.toml").unwrap_err().to_string();
        assert!(
            e.starts_with("study.toml: placement.min_hit_share.bicycle = 0.5: ") && e.contains("no bicycle"),
            "{e}"
        );
        assert_eq!(inst.floors.iter().map(|f| f.samples as usize).sum::<usize>(), inst.points.weights.len());
        inst.validate().unwrap();
        let w = Weights { lidar_points: 1.0, ..Weights::default() };
        for mask in 1u32..16 {
            let sel: Vec<usize> = (0..4).filter(|o| mask & (1 << o) != 0).collect();
            // Brute force: full scans, the road users' classes and ranges from the traffic; per
            // class the capped count and the road users no chosen LiDAR puts a point on.
            let lidars: Vec<usize> = sel.iter().copied().filter(|&o| o < 3).collect();
            let mut per_class: BTreeMap<usize, (f64, usize)> = BTreeMap::new();
            let mut missed: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
            for fr in &tp.frames {
                let mut n: BTreeMap<u32, usize> = BTreeMap::new();
                for &o in &lidars {
                    let (spec, pose) = lidar(o).unwrap();
                    let seed = hilo_dataset::simulate::derive_seed(tp.seed, &[2, fr.stream, fr.index as u64, 0]);
                    let scan =
                        hilo_sensor_models::simulate_lidar(&spec, &pose, &world, Some(&fr.actors), seed).unwrap();
                    for (a, p) in scan.points_per_actor() {
                        *n.entry(a).or_default() += p;
                    }
                }
                for &(a, c) in &fr.users {
                    let points = n.get(&a).copied().unwrap_or(0);
                    let e = per_class.entry(c).or_default();
                    e.0 += (points as f64 / f64::from(k)).min(1.0);
                    e.1 += 1;
                    let m = missed.entry(tp.names[c]).or_default();
                    m.0 += usize::from(points == 0);
                    m.1 += 1;
                }
            }
            let want = per_class.values().map(|(s, n)| s / *n as f64).sum::<f64>() / per_class.len() as f64;
            let got = evaluate(&inst, &sel, &w);
            assert!((got - want).abs() < 1e-12, "{sel:?}: {got} against {want}");
            if sel == [0, 1, 2] {
                assert!(want > 0.05, "the rig sees its road users: {want}");
            }
            // The share of each class no chosen LiDAR puts a point on, against the same scans.
            let never = tp.never_hit(&world, lidars.len(), |i| lidar(lidars[i])).unwrap();
            let want: BTreeMap<String, f64> =
                missed.iter().map(|(c, (m, n))| ((*c).to_owned(), *m as f64 / *n as f64)).collect();
            assert_eq!(never, want, "{sel:?}");
            // Each floor's share hit is one minus its class's share missed.
            for f in &inst.floors {
                let (m, n) = missed[f.class.as_str()];
                assert_eq!((f.samples as usize, f.hits(&sel) as usize), (n, n - m), "{sel:?} {}", f.class);
            }
            if lidars.is_empty() {
                assert!(never.values().all(|v| *v == 1.0), "a radar alone hits nobody: {never:?}");
            } else if lidars == [0, 1, 2] {
                assert!(never.values().any(|v| *v < 1.0), "the rig hits someone: {never:?}");
            }
        }
        // The footprint term: per road user, the options' shares from full scans, each rounded
        // to thousandths as the rows hold them, summed and capped; the same without rounding
        // within half a thousandth per LiDAR.
        let w = Weights { lidar_extent: 1.0, ..Weights::default() };
        for mask in 1u32..16 {
            let sel: Vec<usize> = (0..4).filter(|o| mask & (1 << o) != 0).collect();
            let mut per_class: BTreeMap<usize, (f64, f64, usize)> = BTreeMap::new();
            for fr in &tp.frames {
                let mut share: BTreeMap<u32, (f64, f64)> = BTreeMap::new();
                for &o in sel.iter().filter(|&&o| o < 3) {
                    let (spec, pose) = lidar(o).unwrap();
                    let seed = hilo_dataset::simulate::derive_seed(tp.seed, &[2, fr.stream, fr.index as u64, 0]);
                    let scan =
                        hilo_sensor_models::simulate_lidar(&spec, &pose, &world, Some(&fr.actors), seed).unwrap();
                    let pts: Vec<(glam::Vec3, Option<u32>)> = scan
                        .points_local()
                        .iter()
                        .zip(&scan.sources)
                        .map(|(p, s)| (glam::Vec3::new(p.x, p.y, p.z), s.actor()))
                        .collect();
                    for a in fr.actors.actors() {
                        let e = footprint_extent(a, pts.iter().filter(|p| p.1 == Some(a.id)).map(|p| p.0));
                        let s = share.entry(a.id).or_default();
                        s.0 += (e * 1000.0).round() / 1000.0;
                        s.1 += e;
                    }
                }
                for &(a, c) in &fr.users {
                    let (r, e) = share.get(&a).copied().unwrap_or_default();
                    let x = per_class.entry(c).or_default();
                    x.0 += r.min(1.0);
                    x.1 += e.min(1.0);
                    x.2 += 1;
                }
            }
            let classes = per_class.len() as f64;
            let want = per_class.values().map(|(s, _, n)| s / *n as f64).sum::<f64>() / classes;
            let exact = per_class.values().map(|(_, s, n)| s / *n as f64).sum::<f64>() / classes;
            let got = evaluate(&inst, &sel, &w);
            assert!((got - want).abs() < 1e-12, "{sel:?}: {got} against {want}");
            assert!((got - exact).abs() <= 5e-4 * sel.len() as f64, "{sel:?}: {got} against {exact}");
            if sel == [0, 1, 2] {
                assert!(want > 0.05, "the rig spans its road users: {want}");
                // A rig's own footprint predictor is the same sum (its dropouts drawn per sensor).
                let rig: Vec<RigLidar> = (0..3).map(|o| (o, lidar(o).unwrap().0, lidar(o).unwrap().1)).collect();
                let own = tp.occupancy(&world, &rig, 5).unwrap().extent;
                assert!((own - exact).abs() < 0.03, "{own} against {exact}");
            }
        }
    }

    #[test]
    fn footprint_extent_has_its_closed_forms() {
        use glam::{Vec2, Vec3};
        let yaw = 0.5f32;
        let b = hilo_core::Box3::new(Vec3::new(3.0, -2.0, 0.8), 4.0, 2.0, 1.6, yaw);
        let car = hilo_raycast::Actor::from_box(1, hilo_core::Class::Car, b);
        // A point at (x, y) of the car's own frame, in the scene frame.
        let at = |x: f32, y: f32| (b.center.truncate() + glam::Mat2::from_angle(yaw) * Vec2::new(x, y)).extend(1.0);
        let e = |p: &[Vec3]| footprint_extent(&car, p.iter().copied());
        let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-5, "{a} against {b}");
        close(e(&[at(2.0, 1.0), at(-2.0, -1.0)]), 1.0);
        close(e(&[at(2.0, 1.0), at(2.0, -1.0), at(2.0, 0.0)]), 0.0); // the front face end-on
        close(e(&[at(2.0, 1.0), at(0.0, 1.0), at(2.0, -1.0)]), 0.5); // a corner: half the length
        close(e(&[at(1.0, 0.5), at(0.0, 0.0)]), 0.25 * 0.25);
        close(e(&[at(9.0, 9.0), at(-9.0, -9.0)]), 1.0); // capped on both axes
        close(e(&[at(1.0, 1.0)]), 0.0);
        close(e(&[]), 0.0);
        let walker = hilo_raycast::Actor::from_box(2, hilo_core::Class::Pedestrian, b);
        let r = 1.0; // half the smaller planar size
        let pts = [Vec3::new(3.0 - r, -2.0 - r, 1.0), Vec3::new(3.0 + r, -2.0 + r, 1.0)];
        close(footprint_extent(&walker, pts.into_iter()), 1.0);
        close(footprint_extent(&walker, pts.into_iter().map(|p| p * Vec3::new(1.0, 0.0, 1.0) - Vec3::Y * 2.0)), 0.0);
    }

    #[test]
    fn the_extent_grows_with_the_rig_and_stays_a_share() {
        let study = small_study(1);
        let traffic = TrainingTraffic::new(&study).unwrap();
        let points = TrafficPoints::new(&traffic, 5).unwrap();
        let world =
            hilo_raycast::world::World::build(&study.scene, &hilo_raycast::world::QueryRegion::everything()).unwrap();
        let spec = hilo_sensor_models::Catalog::default_catalog().unwrap().lidar("lidar-16").unwrap().clone();
        let pose = |m: usize| {
            let m = &study.scene.mounts[m];
            let p = m.base + m.arm_dir * (0.5 * m.arm_length_m);
            let z = study.scene.ground.z_m + m.arm_height_m + 0.4;
            hilo_sensor_models::SensorPose::new(p.extend(z), (-p.y).atan2(-p.x), 0.17, 0.0)
        };
        let poses = [pose(0), pose(2)];
        let extent = |rig: &[RigLidar]| points.occupancy(&world, rig, 5).unwrap().extent;
        let one = extent(&[(0, spec.clone(), poses[0])]);
        let two = extent(&[(0, spec.clone(), poses[0]), (1, spec, poses[1])]);
        assert!(one > 0.05 && one <= 1.0, "{one}");
        assert!(two >= one && two <= 1.0, "{one} then {two}");
        assert_eq!(extent(&[]), 0.0);
    }
}
