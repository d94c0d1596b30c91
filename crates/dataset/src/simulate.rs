//! Frames for a sensor rig: the traffic of [`crate::traffic`] scanned by every sensor.
//!
//! Each scene has its own traffic seed derived from the dataset seed and the scene's index,
//! never from the sensors, so every rig records the same traffic. All sensors of a frame scan
//! the same instant (synchronised sensors; a spinning LiDAR's 50 ms sweep is treated as
//! instantaneous, the same simplification the radar makes for its chirps). Ground truth lists
//! the road users within `annotate_radius_m` of the scene origin, each with its LiDAR and radar
//! point counts and a nuScenes visibility level: the share of nine probe points of its box
//! (centre and eight inner corners) in line of sight of at least one LiDAR.

use crate::error::DatasetError;
use crate::paint::VehiclePaint;
pub use crate::seed::derive_seed;
use crate::traffic::{ActorState, Traffic, TrafficConfig};
use crate::writer::{Annotation, FrameData, SceneData, Sweep};
use glam::Vec3;
use hilo_core::{Check, Valid};
use hilo_raycast::{ActorSet, HitTarget, Ray, Scene, World};
use hilo_sensor_models::{
    CalibrationError, Foliage, LidarSpec, SensorPose, SensorSpec, Weather, simulate_lidar, simulate_radar,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Dataset settings (`[dataset]` in a study file).
///
/// Training and validation are scenes of their own traffic seeds, recorded at their own rates:
/// adjacent frames a tenth of a second apart are near duplicates, so validation spends its
/// frames on many scenes at a low rate (the scene is the unit a confidence interval resamples),
/// while training may record fewer scenes densely. Between key frames the radars also record
/// sweeps at `sweep_rate_hz` (nuScenes' non-key-frame sample_data), so a detector can stack a
/// radar's last sweeps however far apart the key frames are.
#[derive(Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SimulateConfig {
    /// Training scenes, their length (s) and key frames per second.
    pub scenes: usize,
    pub seconds: f64,
    pub rate_hz: f64,
    /// Validation scenes (other traffic seeds), their length and key frames per second.
    pub val_scenes: usize,
    pub val_seconds: f64,
    pub val_rate_hz: f64,
    /// Radar sweeps per second, key frames included (a multiple of both key-frame rates);
    /// the radar's sweeps between key frames are written as non-key-frame sample_data.
    pub sweep_rate_hz: f64,
    /// The LiDARs scan at `sweep_rate_hz` too (false: at key frames only), so a detector can
    /// stack a LiDAR's last sweeps (multi-sweep input, as nuScenes detectors read ten) however
    /// far apart the key frames are. Each sweep costs a key frame's ray casting.
    pub lidar_sweeps: bool,
    /// Seed of the traffic and of the sensor noise.
    pub seed: u64,
    /// Which draw of training traffic the training scenes hold (0: the dataset's own). Another
    /// draw gives the training scenes other traffic (and sensor noise) from the same settings
    /// and leaves the validation scenes as they are, so detectors trained on different draws
    /// are scored on the same scenes: the study's way of measuring how much a result depends
    /// on the traffic a detector happened to be trained on.
    #[serde(skip_serializing_if = "is_zero")]
    pub train_traffic_draw: u64,
    /// Road users farther than this from the scene origin are not annotated.
    pub annotate_radius_m: f32,
    pub traffic: TrafficConfig,
    /// Rain and fog (clear when absent): the sensors' specs are changed by the published
    /// models of [`hilo_sensor_models::weather`] before every scan.
    pub weather: Weather,
    /// The rig's extrinsic calibration error (absent: perfect calibration). Each sensor scans
    /// from a true pose drawn once per dataset seed and sensor around the pose its
    /// `calibrated_sensor` record keeps, so a detector that merges the sensors' points with the
    /// recorded calibration sees them misaligned, as a field rig's are.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration_error: Option<CalibrationError>,
    /// The rig's time-synchronisation error: standard deviation, s, of each sensor's clock
    /// offset, drawn once per dataset seed and sensor (absent: perfect synchronisation). A
    /// sensor whose clock is δ off samples the road users δ later than the time it records, so a
    /// detector that merges the sensors sees a moving road user where each saw it at its own
    /// instant (a PTP-synchronised rig: well under a millisecond; NTP: milliseconds; none: tens).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_sync_error_s: Option<f32>,
    /// Spinning LiDARs see road users move during a rotation: each azimuth column meets them
    /// where they are at its time within the sweep (the frame's timestamp is the sweep's start),
    /// so a moving road user is skewed. False: frozen at the frame's instant.
    #[serde(skip_serializing_if = "is_false")]
    pub rolling_shutter: bool,
    /// Vehicles' LiDAR reflectivity: `class` (absent: every vehicle the class's 0.5) or `fleet`
    /// (each vehicle a colour of the fleet, drawn per road user and seed: [`crate::paint`]).
    #[serde(skip_serializing_if = "is_class_paint")]
    pub vehicle_paint: VehiclePaint,
    /// Tree crowns in wind, as the LiDARs see them (absent: still and opaque): each ray that
    /// meets a crown passes through a gap with `gap_probability`, and otherwise returns from a
    /// leaf displaced along it by a Gaussian of `sway_m` ([`hilo_sensor_models::Foliage`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub foliage: Option<Foliage>,
    /// Whether the LiDARs whose catalog entry gives a `beam` cast it with its width (sub-rays
    /// over the footprint: partial hits, mixed pixels, dual returns; about twenty times a thin
    /// ray's casting) or as rays of no width, the entry's `beam` ignored. Absent: in a study the
    /// profile decides (quick and default: rays of no width; paper: the width); `hilo simulate`
    /// casts the width.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lidar_beam_width: Option<bool>,
}

fn is_class_paint(p: &VehiclePaint) -> bool {
    *p == VehiclePaint::Class
}

fn is_false(v: &bool) -> bool {
    !*v
}

/// As derived, but `calibration_error`, `time_sync_error_s`, `rolling_shutter`,
/// `vehicle_paint`, `foliage` and `lidar_beam_width` appear only when set: the form a study's fingerprint
/// is taken over stays what it was for the datasets made before the field existed.
impl std::fmt::Debug for SimulateConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("SimulateConfig");
        d.field("scenes", &self.scenes)
            .field("seconds", &self.seconds)
            .field("rate_hz", &self.rate_hz)
            .field("val_scenes", &self.val_scenes)
            .field("val_seconds", &self.val_seconds)
            .field("val_rate_hz", &self.val_rate_hz)
            .field("sweep_rate_hz", &self.sweep_rate_hz)
            .field("lidar_sweeps", &self.lidar_sweeps)
            .field("seed", &self.seed)
            .field("train_traffic_draw", &self.train_traffic_draw)
            .field("annotate_radius_m", &self.annotate_radius_m)
            .field("traffic", &self.traffic)
            .field("weather", &self.weather);
        if let Some(e) = &self.calibration_error {
            d.field("calibration_error", e);
        }
        if let Some(e) = &self.time_sync_error_s {
            d.field("time_sync_error_s", e);
        }
        if self.rolling_shutter {
            d.field("rolling_shutter", &self.rolling_shutter);
        }
        if self.vehicle_paint != VehiclePaint::Class {
            d.field("vehicle_paint", &self.vehicle_paint);
        }
        if let Some(f) = &self.foliage {
            d.field("foliage", f);
        }
        if let Some(b) = &self.lidar_beam_width {
            d.field("lidar_beam_width", b);
        }
        d.finish()
    }
}

impl Default for SimulateConfig {
    fn default() -> Self {
        SimulateConfig {
            scenes: 10,
            seconds: 20.0,
            rate_hz: 10.0,
            val_scenes: 20,
            val_seconds: 20.0,
            val_rate_hz: 2.0,
            sweep_rate_hz: 10.0,
            lidar_sweeps: false,
            seed: 0,
            train_traffic_draw: 0,
            annotate_radius_m: 70.0,
            traffic: TrafficConfig::default(),
            weather: Weather::default(),
            calibration_error: None,
            time_sync_error_s: None,
            rolling_shutter: false,
            vehicle_paint: VehiclePaint::Class,
            foliage: None,
            lidar_beam_width: None,
        }
    }
}

/// The two splits of a dataset.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    Train,
    Val,
}

impl Split {
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
        }
    }
}

/// Scene `index` of a split: its name, traffic seed stream and start time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SceneId {
    pub split: Split,
    pub index: usize,
}

impl SceneId {
    /// `scene-0007` (training) or `val-0007`.
    pub fn name(&self) -> String {
        match self.split {
            Split::Train => scene_name(self.index),
            Split::Val => format!("val-{:04}", self.index),
        }
    }

    /// The stream its seeds derive from: validation scenes never share a training scene's.
    pub fn stream(&self) -> u64 {
        match self.split {
            Split::Train => self.index as u64,
            Split::Val => 1_000_000 + self.index as u64,
        }
    }
}

/// The most training (and, separately, validation) scenes a dataset may have.
pub const MAX_SCENES: usize = 10_000;

/// The most training-traffic draws ([`SimulateConfig::train_traffic_draw`] is below it).
pub const MAX_TRAFFIC_DRAWS: u64 = 100;

/// Training-traffic draw `d` seeds its training scenes from streams `d · TRAIN_DRAW_STRIDE +
/// index`: above every validation stream (`1_000_000 + index`, index < [`MAX_SCENES`]).
const TRAIN_DRAW_STRIDE: u64 = 2_000_000;

fn is_zero(v: &u64) -> bool {
    *v == 0
}

/// The most key frames a dataset may have (the paper's: 14,800).
pub const MAX_FRAMES: usize = 2_000_000;

impl SimulateConfig {
    /// The checked configuration that simulation takes ([`Check`]).
    pub fn validate(self) -> Result<Valid<SimulateConfig>, DatasetError> {
        Valid::new(self)
    }
}

impl Check for SimulateConfig {
    type Error = DatasetError;

    /// Checks every setting before anything is simulated; counts are bounded ([`MAX_SCENES`],
    /// [`MAX_FRAMES`]) so a typo is an error, not an allocation that exhausts memory.
    fn check(&self) -> Result<(), DatasetError> {
        let bad = |f: &str, v: String, why: &str| Err(DatasetError::setting(format!("dataset.{f}"), v, why));
        self.weather
            .check()
            .map_err(|e| DatasetError::setting(format!("dataset.weather.{}", e.field), e.value, e.reason))?;
        if let Some(e) = &self.calibration_error {
            if !(e.rotation_deg.is_finite() && (0.0..=10.0).contains(&e.rotation_deg)) {
                return bad("calibration_error.rotation_deg", e.rotation_deg.to_string(), "give 0 to 10 degrees");
            }
            if !(e.translation_m.is_finite() && (0.0..=1.0).contains(&e.translation_m)) {
                return bad("calibration_error.translation_m", e.translation_m.to_string(), "give 0 to 1 m");
            }
        }
        if let Some(e) = self.time_sync_error_s
            && !(e.is_finite() && (0.0..=1.0).contains(&e))
        {
            return bad("time_sync_error_s", e.to_string(), "give 0 to 1 s");
        }
        if let Some(f) = &self.foliage {
            if !(0.0..1.0).contains(&f.gap_probability) {
                return bad("foliage.gap_probability", f.gap_probability.to_string(), "give a probability in [0, 1)");
            }
            if !(f.sway_m.is_finite() && (0.0..=2.0).contains(&f.sway_m)) {
                return bad("foliage.sway_m", f.sway_m.to_string(), "give 0 to 2 m");
            }
        }
        if self.scenes == 0 {
            return bad("scenes", "0".into(), "at least one training scene is needed");
        }
        for (f, n) in [("scenes", self.scenes), ("val_scenes", self.val_scenes)] {
            if n > MAX_SCENES {
                return bad(f, n.to_string(), &format!("at most {MAX_SCENES} scenes (the paper's dataset has 37)"));
            }
        }
        for (f, v) in [("seconds", self.seconds), ("val_seconds", self.val_seconds)] {
            if !(v > 0.0 && v <= 3600.0) {
                return bad(f, v.to_string(), "must be in (0, 3600]");
            }
        }
        let step = self.traffic.step_s;
        let per = 1.0 / (self.sweep_rate_hz * step);
        if self.sweep_rate_hz.is_nan()
            || self.sweep_rate_hz <= 0.0
            || (per - per.round()).abs() > 1e-6
            || per.round() < 1.0
        {
            return bad(
                "sweep_rate_hz",
                self.sweep_rate_hz.to_string(),
                &format!("must divide the traffic rate {} Hz (1 / traffic.step_s)", 1.0 / step),
            );
        }
        for (f, r) in [("rate_hz", self.rate_hz), ("val_rate_hz", self.val_rate_hz)] {
            let k = self.sweep_rate_hz / r;
            if r.is_nan() || r <= 0.0 || (k - k.round()).abs() > 1e-6 || k.round() < 1.0 {
                return bad(f, r.to_string(), &format!("must divide sweep_rate_hz = {} Hz", self.sweep_rate_hz));
            }
        }
        if self.train_traffic_draw >= MAX_TRAFFIC_DRAWS {
            return bad(
                "train_traffic_draw",
                self.train_traffic_draw.to_string(),
                &format!("give a draw from 0 to {}", MAX_TRAFFIC_DRAWS - 1),
            );
        }
        if self.annotate_radius_m.is_nan() || self.annotate_radius_m <= 0.0 {
            return bad("annotate_radius_m", self.annotate_radius_m.to_string(), "must be > 0");
        }
        if self.total_frames() > MAX_FRAMES {
            return bad(
                "scenes",
                self.scenes.to_string(),
                &format!(
                    "{} key frames in all ({} training and {} validation scenes), above the {MAX_FRAMES} a dataset may have",
                    self.total_frames(),
                    self.scenes,
                    self.val_scenes
                ),
            );
        }
        Ok(())
    }
}

impl SimulateConfig {
    /// Key frames of a training scene.
    pub fn frames_per_scene(&self) -> usize {
        (self.seconds * self.rate_hz).round() as usize
    }

    /// Key frames of a validation scene.
    pub fn val_frames_per_scene(&self) -> usize {
        (self.val_seconds * self.val_rate_hz).round() as usize
    }

    /// Key frames of the whole dataset.
    pub fn total_frames(&self) -> usize {
        self.scenes
            .saturating_mul(self.frames_per_scene())
            .saturating_add(self.val_scenes.saturating_mul(self.val_frames_per_scene()))
    }

    /// The seed stream of a scene: its own ([`SceneId::stream`]), moved past every other draw's
    /// for a training scene of another training-traffic draw.
    pub fn stream(&self, id: &SceneId) -> u64 {
        match id.split {
            Split::Train => self.train_traffic_draw * TRAIN_DRAW_STRIDE + id.stream(),
            Split::Val => id.stream(),
        }
    }

    /// Every scene, training first.
    pub fn scene_ids(&self) -> Vec<SceneId> {
        (0..self.scenes)
            .map(|index| SceneId { split: Split::Train, index })
            .chain((0..self.val_scenes).map(|index| SceneId { split: Split::Val, index }))
            .collect()
    }

    /// Key frames of one scene.
    pub fn frames_of(&self, id: &SceneId) -> usize {
        match id.split {
            Split::Train => self.frames_per_scene(),
            Split::Val => self.val_frames_per_scene(),
        }
    }

    /// Scene names of each split.
    pub fn splits(&self) -> BTreeMap<String, Vec<String>> {
        let mut m: BTreeMap<String, Vec<String>> = BTreeMap::from([("train".into(), vec![]), ("val".into(), vec![])]);
        for id in self.scene_ids() {
            m.entry(id.split.name().to_owned()).or_default().push(id.name());
        }
        m
    }
}

/// Where rig sensor `s` really scans from: its recorded pose, or with the dataset's calibration
/// error a draw around it, the same for every scene and split of the dataset (keyed by the
/// dataset seed and the sensor's channel, so a sensor keeps its error in every rig that holds
/// its channel).
pub fn true_pose(cfg: &SimulateConfig, s: &RigSensor) -> SensorPose {
    let Some(e) = &cfg.calibration_error else { return s.pose };
    let key = crate::writer::name_hash(&s.channel);
    let mut rng = hilo_sensor_models::noise::rng_for(cfg.seed, hilo_sensor_models::noise::stream::CALIBRATION, key);
    s.pose.miscalibrated(e, &mut rng)
}

/// How late rig sensor `s` samples the road users against the time it records, s: 0, or with
/// the dataset's time-synchronisation error a Gaussian draw of that standard deviation, the
/// same for every scene and split of the dataset (keyed by the dataset seed and the channel).
pub fn clock_offset_s(cfg: &SimulateConfig, s: &RigSensor) -> f32 {
    let Some(sigma) = cfg.time_sync_error_s else { return 0.0 };
    let key = crate::writer::name_hash(&s.channel);
    let mut rng = hilo_sensor_models::noise::rng_for(cfg.seed, hilo_sensor_models::noise::stream::TIME_SYNC, key);
    sigma * rand::Rng::sample::<f32, _>(&mut rng, rand_distr::StandardNormal)
}

/// Road user `a` of the scene with seed stream `stream` as the sensors meet it: its shape,
/// velocity and, with a fleet's paint, its colour's reflectivity.
pub fn painted(cfg: &SimulateConfig, stream: u64, a: &ActorState) -> hilo_raycast::Actor {
    let actor = a.actor();
    match crate::paint::reflectivity(cfg.vehicle_paint, cfg.seed, stream, a.id, a.class) {
        Some(r) => actor.with_reflectivity(r),
        None => actor,
    }
}

/// How long after the frame's instant the road users are met: the longest LiDAR rotation of
/// the rig with a rolling shutter, else 0 (frozen).
pub fn sweep_span_s(cfg: &SimulateConfig, rig: &[RigSensor]) -> f32 {
    if !cfg.rolling_shutter {
        return 0.0;
    }
    rig.iter()
        .filter_map(|s| match &s.spec {
            SensorSpec::Lidar(l) => Some(1.0 / l.rate_hz),
            SensorSpec::Radar(_) => None,
        })
        .fold(0.0, f32::max)
}

/// The road users of one frame as rig sensor k meets them: moved by its clock offset, moving
/// for the sweep's span. Sensors without an offset share `still`.
fn actor_sets(
    actors: &[hilo_raycast::Actor],
    offsets: &[f32],
    span_s: f32,
) -> Result<(ActorSet, Vec<Option<ActorSet>>), hilo_raycast::RaycastError> {
    let still = ActorSet::moving(actors.to_vec(), span_s)?;
    let shifted = offsets
        .iter()
        .map(|&d| {
            if d == 0.0 {
                Ok(None)
            } else {
                ActorSet::moving(actors.iter().map(|a| a.moved(d)).collect(), span_s).map(Some)
            }
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((still, shifted))
}

pub fn scene_name(index: usize) -> String {
    format!("scene-{index:04}")
}

/// One mounted sensor.
#[derive(Clone, Debug)]
pub struct RigSensor {
    pub channel: String,
    pub spec: SensorSpec,
    pub pose: SensorPose,
}

/// The start of a scene in µs: scenes are an hour apart (the devkit orders scenes by start
/// time and needs them distinct), validation scenes after every training scene.
pub fn scene_start_us(id: &SceneId) -> u64 {
    1_767_225_600_000_000 + id.stream() * 3_600_000_000
}

/// nuScenes visibility level (1..=4) of a box seen from the LiDAR positions.
fn visibility(world: &World, actors: &ActorSet, a: &ActorState, eyes: &[Vec3]) -> u8 {
    if eyes.is_empty() {
        return 4;
    }
    let b = a.box3;
    let mut probes = vec![b.center];
    probes.extend(b.corners().iter().map(|c| b.center + (*c - b.center) * 0.8));
    let seen = probes
        .iter()
        .filter(|p| {
            eyes.iter().any(|e| {
                let d = **p - *e;
                let dist = d.length();
                if dist < 1e-3 {
                    return true;
                }
                let ray = Ray::new(*e, d / dist, dist + 0.5);
                match world.closest_hit(&ray, Some(actors)) {
                    None => true,
                    Some(h) => matches!(h.target, HitTarget::Actor { id, .. } if id == a.id) || h.t >= dist - 0.05,
                }
            })
        })
        .count();
    let frac = seen as f32 / probes.len() as f32;
    match frac {
        f if f <= 0.4 => 1,
        f if f <= 0.6 => 2,
        f if f <= 0.8 => 3,
        _ => 4,
    }
}

/// Simulates one scene for the rig: traffic, scans, annotations, radar sweeps between key frames.
pub fn simulate_scene(
    scene: &Scene,
    world: &World,
    rig: &[RigSensor],
    cfg: &Valid<SimulateConfig>,
    id: &SceneId,
) -> Result<SceneData, DatasetError> {
    simulate_scene_with(scene, world, rig, cfg, id, &|_| {})
}

/// [`simulate_scene`], calling `on_frame` with the number of key frames done after each one.
pub fn simulate_scene_with(
    scene: &Scene,
    world: &World,
    rig: &[RigSensor],
    cfg: &Valid<SimulateConfig>,
    id: &SceneId,
    on_frame: &(dyn Fn(usize) + Sync),
) -> Result<SceneData, DatasetError> {
    let stream = cfg.stream(id);
    // The rig in the scene's weather (clear weather leaves every spec as it is).
    let weathered: Vec<RigSensor> = rig
        .iter()
        .map(|s| RigSensor {
            spec: match &s.spec {
                SensorSpec::Lidar(l) => {
                    let l = LidarSpec { foliage: cfg.foliage, ..cfg.weather.lidar(l) };
                    let beam = if cfg.lidar_beam_width == Some(false) { None } else { l.beam };
                    SensorSpec::Lidar(LidarSpec { beam, ..l })
                }
                SensorSpec::Radar(r) => SensorSpec::Radar(cfg.weather.radar(r)),
            },
            pose: true_pose(cfg, s),
            ..s.clone()
        })
        .collect();
    let rig = &weathered[..];
    let offsets: Vec<f32> = rig.iter().map(|s| clock_offset_s(cfg, s)).collect();
    let span_s = sweep_span_s(cfg, rig);
    let mut traffic = Traffic::new(&scene.layout, scene.ground.z_m, &cfg.traffic, derive_seed(cfg.seed, &[1, stream]))?;
    let (per_key, steps_per_sweep) = cadence(cfg, id);
    let start = scene_start_us(id);
    let sweep_us = (1e6 / cfg.sweep_rate_hz).round() as u64;
    let n_frames = cfg.frames_of(id);
    let eyes: Vec<Vec3> =
        rig.iter().filter(|s| matches!(s.spec, SensorSpec::Lidar(_))).map(|s| s.pose.position).collect();
    let has_radar = rig.iter().any(|s| matches!(s.spec, SensorSpec::Radar(_)));
    let mut frames = Vec::with_capacity(n_frames);
    let mut sweeps = Vec::new();
    for m in 0..=(n_frames.saturating_sub(1) * per_key) {
        let key = m % per_key == 0;
        let f = m / per_key;
        if key || has_radar || cfg.lidar_sweeps {
            let states = traffic.snapshot();
            let actors: Vec<hilo_raycast::Actor> = states.iter().map(|a| painted(cfg, stream, a)).collect();
            let (set, shifted) = actor_sets(&actors, &offsets, span_s).map_err(|e| DatasetError::Actors {
                scene: id.name(),
                sweep: m,
                source: Box::new(e),
            })?;
            let mut lidar = Vec::new();
            let mut radar = Vec::new();
            let mut lidar_pts: BTreeMap<u32, u32> = BTreeMap::new();
            let mut radar_pts: BTreeMap<u32, u32> = BTreeMap::new();
            for (k, s) in rig.iter().enumerate() {
                let sensor_set = shifted[k].as_ref().unwrap_or(&set);
                let noise = if key {
                    derive_seed(cfg.seed, &[2, stream, f as u64, k as u64])
                } else {
                    derive_seed(cfg.seed, &[4, stream, m as u64, k as u64])
                };
                let err = |e: hilo_sensor_models::SensorError| DatasetError::Sensor {
                    channel: s.channel.clone(),
                    source: Box::new(e),
                };
                match &s.spec {
                    SensorSpec::Lidar(l) if key || cfg.lidar_sweeps => {
                        let scan = simulate_lidar(l, &s.pose, world, Some(sensor_set), noise).map_err(err)?;
                        for (a, n) in scan.points_per_actor() {
                            *lidar_pts.entry(a).or_default() += n as u32;
                        }
                        lidar.push(scan.points);
                    }
                    SensorSpec::Lidar(_) => {}
                    SensorSpec::Radar(r) => {
                        let scan = simulate_radar(r, &s.pose, world, Some(sensor_set), noise).map_err(err)?;
                        for src in &scan.sources {
                            if let Some(a) = src.actor() {
                                *radar_pts.entry(a).or_default() += 1;
                            }
                        }
                        radar.push(scan.points);
                    }
                }
            }
            let timestamp_us = start + m as u64 * sweep_us;
            if key {
                let annotations = states
                    .iter()
                    .filter(|a| a.box3.center.truncate().length() <= cfg.annotate_radius_m)
                    .map(|a| Annotation {
                        instance: a.id,
                        class: a.class,
                        box3: a.box3,
                        velocity_mps: a.velocity_mps,
                        attribute: a.attribute.to_string(),
                        num_lidar_pts: lidar_pts.get(&a.id).copied().unwrap_or(0),
                        num_radar_pts: radar_pts.get(&a.id).copied().unwrap_or(0),
                        visibility: visibility(world, &set, a, &eyes),
                    })
                    .collect();
                frames.push(FrameData { timestamp_us, lidar, radar, annotations });
                on_frame(f + 1);
            } else {
                sweeps.push(Sweep { timestamp_us, lidar, radar });
            }
        }
        for _ in 0..steps_per_sweep {
            traffic.step();
        }
    }
    Ok(SceneData {
        name: id.name(),
        description: format!(
            "hilo traffic, seed {}, {} scene, {} key frames at {} Hz, {} sweeps at {} Hz",
            cfg.seed,
            id.split.name(),
            n_frames,
            key_rate_hz(cfg, id),
            if cfg.lidar_sweeps { "LiDAR and radar" } else { "radar" },
            cfg.sweep_rate_hz
        ),
        frames,
        sweeps,
    })
}

/// Key frames per second of scene `id`.
fn key_rate_hz(cfg: &SimulateConfig, id: &SceneId) -> f64 {
    match id.split {
        Split::Train => cfg.rate_hz,
        Split::Val => cfg.val_rate_hz,
    }
}

/// Sweeps per key frame and traffic steps per sweep of scene `id`.
fn cadence(cfg: &SimulateConfig, id: &SceneId) -> (usize, usize) {
    let per_key = (cfg.sweep_rate_hz / key_rate_hz(cfg, id)).round() as usize;
    (per_key, (1.0 / (cfg.sweep_rate_hz * cfg.traffic.step_s)).round() as usize)
}

/// The road users of scene `id`'s key frames within the annotation radius, moved as
/// [`simulate_scene`] moves them but with no sensor simulated: the states it annotates (the
/// traffic does not depend on the rig, so every rig's dataset holds these road users).
pub fn key_frame_states(
    scene: &Scene,
    cfg: &Valid<SimulateConfig>,
    id: &SceneId,
) -> Result<Vec<Vec<ActorState>>, DatasetError> {
    let mut traffic =
        Traffic::new(&scene.layout, scene.ground.z_m, &cfg.traffic, derive_seed(cfg.seed, &[1, cfg.stream(id)]))?;
    let (per_key, steps_per_sweep) = cadence(cfg, id);
    let n_frames = cfg.frames_of(id);
    let mut frames = Vec::with_capacity(n_frames);
    for m in 0..=(n_frames.saturating_sub(1) * per_key) {
        if m % per_key == 0 {
            let states = traffic.snapshot();
            frames.push(
                states.into_iter().filter(|a| a.box3.center.truncate().length() <= cfg.annotate_radius_m).collect(),
            );
        }
        for _ in 0..steps_per_sweep {
            traffic.step();
        }
    }
    Ok(frames)
}

/// What [`write_dataset`] did.
#[derive(Clone, Debug, Serialize)]
pub struct WriteSummary {
    pub scenes: usize,
    /// Scenes found complete from an earlier run and kept, and their key frames.
    pub resumed_scenes: usize,
    pub resumed_frames: usize,
    pub frames: usize,
    pub annotations: usize,
    pub bytes_written: u64,
    pub seconds: f64,
}

const RUN_FILE: &str = ".hilo/run.json";

fn parts_dir(root: &std::path::Path) -> std::path::PathBuf {
    root.join(".hilo").join("parts")
}

/// Simulates every scene of `cfg` for `rig` and writes the dataset under `root` in the nuScenes
/// layout (`version` folder for the tables). Resumable: each finished scene's rows are kept in
/// `<root>/.hilo/parts/`, so a rerun after an interruption simulates only the missing scenes
/// (bit-identical, as the seeds are per scene). A folder made with other settings is refused, and
/// so is one that another run is writing or that holds a symbolic link
/// ([`hilo_core::folder::claim`]).
/// `progress` is called with the frames finished so far (resumed ones included).
#[allow(clippy::too_many_arguments)]
pub fn write_dataset(
    scene: &Scene,
    world: &World,
    rig: &[RigSensor],
    cfg: &Valid<SimulateConfig>,
    root: &std::path::Path,
    version: &str,
    namespace: &str,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<WriteSummary, DatasetError> {
    use crate::writer::{DatasetWriter, SensorModality, SensorSetup, token};
    use hilo_core::fs::write_atomic;
    let t0 = std::time::Instant::now();
    crate::reader::check_version(version)?;
    // One writer, and no link inside that would send the tables or points elsewhere.
    let _claim = hilo_core::folder::claim(root, hilo_core::folder::Mode::Exclusive)?;
    let fingerprint =
        token(&[&format!("{cfg:?}"), &format!("{rig:?}"), &format!("{:?}", scene.config), version, namespace]);
    let run_path = root.join(RUN_FILE);
    let run = serde_json::json!({ "fingerprint": fingerprint, "namespace": namespace, "version": version, "scenes": cfg.scenes });
    match hilo_core::fs::read_bounded(&run_path, hilo_core::fs::limit::CONFIG) {
        Ok(bytes) => {
            let old: serde_json::Value = serde_json::from_slice(&bytes)
                .map_err(|e| DatasetError::from(hilo_core::fs::FileError::content(&run_path, e.to_string())))?;
            // A run refused before it finished a scene left only this file: nothing is lost by
            // taking the folder over, and the corrected rerun must not be blocked by it.
            if old.get("fingerprint") != run.get("fingerprint") && hilo_core::fs::holds_file(&parts_dir(root)) {
                return Err(DatasetError::Folder {
                    path: root.to_path_buf(),
                    reason: format!(
                        "holds a dataset made with other settings (fingerprint {} here, {} now); choose another output folder or delete it",
                        old.get("fingerprint").and_then(|v| v.as_str()).unwrap_or("?"),
                        fingerprint
                    ),
                });
            }
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            // Not ours: another program's files are never overwritten.
            if let Some(first) = std::fs::read_dir(root).ok().and_then(|mut d| d.next()).and_then(|e| e.ok()) {
                return Err(DatasetError::Folder {
                    path: root.to_path_buf(),
                    reason: format!(
                        "already holds files not written by `hilo simulate` (e.g. {:?}); choose an empty or new output folder",
                        first.file_name()
                    ),
                });
            }
        }
        Err(e) => return Err(DatasetError::from(hilo_core::fs::FileError::Io { path: run_path, source: e })),
    }
    let bytes = serde_json::to_vec_pretty(&run)
        .map_err(|e| DatasetError::from(hilo_core::fs::FileError::content(&run_path, e.to_string())))?;
    write_atomic(&run_path, &bytes)?;
    let setups: Vec<SensorSetup> = rig
        .iter()
        .map(|s| {
            let modality = match s.spec {
                SensorSpec::Lidar(_) => SensorModality::Lidar,
                SensorSpec::Radar(_) => SensorModality::Radar,
            };
            SensorSetup { channel: s.channel.clone(), modality, pose: s.pose }
        })
        .collect();
    let mut writer = DatasetWriter::new(root, version, namespace, setups)?.with_classes(&cfg.traffic.classes());
    let location = scene.config.name.clone();
    let mut summary = WriteSummary {
        scenes: cfg.scenes + cfg.val_scenes,
        resumed_scenes: 0,
        resumed_frames: 0,
        frames: 0,
        annotations: 0,
        bytes_written: 0,
        seconds: 0.0,
    };
    for id in cfg.scene_ids() {
        let part = parts_dir(root).join(format!("{}.json", id.name()));
        let rows: Option<crate::tables::Tables> = match hilo_core::fs::read_bounded(&part, hilo_core::fs::limit::TABLE)
        {
            Ok(bytes) => Some(
                serde_json::from_slice(&bytes)
                    .map_err(|e| DatasetError::from(hilo_core::fs::FileError::content(&part, e.to_string())))?,
            ),
            Err(_) => None,
        };
        match rows {
            Some(rows) => {
                summary.annotations += rows.sample_annotation.len();
                writer.add_rows(rows)?;
                summary.resumed_scenes += 1;
                summary.resumed_frames += cfg.frames_of(&id);
            }
            None => {
                let done = summary.frames;
                let data = simulate_scene_with(scene, world, rig, cfg, &id, &|f| progress(done + f))?;
                summary.bytes_written += data
                    .frames
                    .iter()
                    .map(|f| {
                        f.lidar.iter().map(|c| c.len() as u64 * 20).sum::<u64>()
                            + f.radar.iter().map(|c| c.len() as u64 * 28).sum::<u64>()
                    })
                    .sum::<u64>()
                    + data.sweeps.iter().flat_map(|s| &s.radar).map(|c| c.len() as u64 * 28).sum::<u64>()
                    + data.sweeps.iter().flat_map(|s| &s.lidar).map(|c| c.len() as u64 * 20).sum::<u64>();
                let rows = writer.add_scene_rows(&data, &location)?;
                summary.annotations += rows.sample_annotation.len();
                let bytes = serde_json::to_vec(&rows)
                    .map_err(|e| DatasetError::from(hilo_core::fs::FileError::content(&part, e.to_string())))?;
                write_atomic(&part, &bytes)?;
            }
        }
        summary.frames += cfg.frames_of(&id);
        progress(summary.frames);
    }
    writer.write_splits(&cfg.splits())?;
    writer.finish()?;
    summary.seconds = t0.elapsed().as_secs_f64();
    Ok(summary)
}
