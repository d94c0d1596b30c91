//! Visibility matrices V[i, j] ∈ [0, 1]: the probability that a road user standing in target
//! cell j is detected from candidate i.
//!
//! For each probe (by default a pedestrian and a car, weighted one half each):
//! - line of sight: rays from the sensor to points on the probe at a few heights, against the
//!   static scene; the visible fraction scales the probe's returns;
//! - LiDAR: the expected returns of the sensor type's beam pattern on the probe (the
//!   [`hilo_sensor_models::probability`] model, which knows range, beam spacing, field of view and
//!   drop-off), times the visible fraction; the detection probability is P(N ≥ min_points)
//!   for N Poisson with that mean. So V depends on resolution, which is the paper's point;
//! - radar: the Swerling-I detection probability of the probe's class, if any of it is in line of
//!   sight, scaled by the visible fraction.
//!
//! V is stored sparse (entries below `min_v` dropped) and computed in parallel, only for pairs
//! within the sensor's range.

use crate::candidates::{Candidate, Modality};
use crate::error::PlacementError;
use crate::targets::Target;
use glam::Vec3;
use hilo_core::Class;
use hilo_raycast::{Ray, World};
use hilo_sensor_models::SensorSpec;
use hilo_sensor_models::probability::{LidarPattern, Probe, radar_detection_probability};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One probe road user.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeConfig {
    pub class: Class,
    pub weight: f32,
    /// LiDAR returns needed to detect it.
    pub min_points: u32,
    /// Heights of the line-of-sight test points above the ground, metres.
    pub los_heights_m: Vec<f32>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VisibilityConfig {
    pub probes: Vec<ProbeConfig>,
    /// Entries below this are dropped from the sparse matrices.
    pub min_v: f32,
}

impl Default for VisibilityConfig {
    fn default() -> Self {
        VisibilityConfig {
            probes: vec![
                ProbeConfig {
                    class: Class::Pedestrian,
                    weight: 0.5,
                    min_points: 3,
                    los_heights_m: vec![0.3, 0.9, 1.5],
                },
                ProbeConfig { class: Class::Car, weight: 0.5, min_points: 5, los_heights_m: vec![0.4, 0.9, 1.4] },
            ],
            min_v: 1e-3,
        }
    }
}

impl VisibilityConfig {
    pub fn validate(&self) -> Result<(), PlacementError> {
        if self.probes.is_empty() {
            return Err(PlacementError::setting("visibility.probes", "[]", "give at least one probe"));
        }
        let total: f32 = self.probes.iter().map(|p| p.weight).sum();
        if self.probes.iter().any(|p| !(p.weight.is_finite() && p.weight >= 0.0)) || (total - 1.0).abs() > 1e-4 {
            return Err(PlacementError::setting(
                "visibility.probes[].weight",
                format!("sum {total}"),
                "weights must be >= 0 and sum to 1",
            ));
        }
        if self.probes.iter().any(|p| p.los_heights_m.is_empty() || p.min_points == 0) {
            return Err(PlacementError::setting(
                "visibility.probes",
                "a probe without los_heights_m or with min_points = 0",
                "every probe needs los_heights_m and min_points >= 1",
            ));
        }
        if !(0.0..1.0).contains(&self.min_v) {
            return Err(PlacementError::setting("visibility.min_v", self.min_v, "must be in [0, 1)"));
        }
        Ok(())
    }
}

fn probe_of(class: Class) -> Probe {
    match class {
        Class::Pedestrian => Probe::PEDESTRIAN,
        Class::Car => Probe::CAR,
        Class::Truck => Probe { class, length_m: 8.5, width_m: 2.5, height_m: 3.4 },
        Class::Bus => Probe { class, length_m: 12.0, width_m: 2.6, height_m: 3.2 },
        Class::Motorcycle => Probe { class, length_m: 2.2, width_m: 0.8, height_m: 1.4 },
        Class::GolfCart => Probe { class, length_m: 2.5, width_m: 1.3, height_m: 1.8 },
        Class::Bicycle => Probe { class, length_m: 1.75, width_m: 0.65, height_m: 1.7 },
    }
}

/// P(N ≥ m) for N ~ Poisson(mean).
pub fn poisson_at_least(mean: f64, m: u32) -> f64 {
    if m == 0 {
        return 1.0;
    }
    if mean <= 0.0 {
        return 0.0;
    }
    let mut term = (-mean).exp();
    let mut cdf = term;
    for k in 1..m {
        term *= mean / k as f64;
        cdf += term;
    }
    (1.0 - cdf).clamp(0.0, 1.0)
}

/// A sparse visibility matrix for one sensor type: for each candidate of its modality (in the
/// order given), the targets it sees with V > `min_v`, sorted by target.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Visibility {
    pub sensor: String,
    pub modality: Modality,
    pub n_targets: usize,
    /// Candidate ids (into the full candidate list) of the rows.
    pub candidates: Vec<u32>,
    pub rows: Vec<Vec<(u32, f32)>>,
}

impl Visibility {
    pub fn nonzeros(&self) -> usize {
        self.rows.iter().map(Vec::len).sum()
    }
}

/// Visible fraction of each probe's test points, per (mount, target): `frac[p]`.
#[derive(Clone, Debug)]
pub struct LineOfSight {
    /// mount → target → per-probe visible fraction (0..=1), dense.
    frac: Vec<Vec<[f32; 4]>>,
}

impl LineOfSight {
    /// Casts the occlusion rays of every mount point to every target within `range_m`.
    pub fn compute(
        world: &World,
        ground_z: f32,
        mounts: &[Vec3],
        targets: &[Target],
        cfg: &VisibilityConfig,
        range_m: f32,
    ) -> Result<Self, PlacementError> {
        if cfg.probes.len() > 4 {
            return Err(PlacementError::setting(
                "visibility.probes",
                format!("{} probes", cfg.probes.len()),
                "at most 4",
            ));
        }
        let frac = mounts
            .par_iter()
            .map(|&m| {
                targets
                    .iter()
                    .map(|t| {
                        let mut f = [0f32; 4];
                        if (t.center - m.truncate()).length() > range_m {
                            return f;
                        }
                        for (k, p) in cfg.probes.iter().enumerate() {
                            let visible = p
                                .los_heights_m
                                .iter()
                                .filter(|h| {
                                    let q = t.center.extend(ground_z + **h);
                                    let d = q - m;
                                    let len = d.length();
                                    len > 0.0
                                        && !world.occluded(
                                            &Ray { origin: m, dir: d / len, t_min: 1e-3, t_max: len - 0.05 },
                                            None,
                                        )
                                })
                                .count();
                            f[k] = visible as f32 / p.los_heights_m.len() as f32;
                        }
                        f
                    })
                    .collect()
            })
            .collect();
        Ok(LineOfSight { frac })
    }
}

/// V for one sensor type over the candidates of its modality. `los` is indexed by mount.
pub fn compute_visibility(
    spec: &SensorSpec,
    candidates: &[Candidate],
    targets: &[Target],
    los: &LineOfSight,
    ground_z: f32,
    cfg: &VisibilityConfig,
) -> Visibility {
    let modality = match spec {
        SensorSpec::Lidar(_) => Modality::Lidar,
        SensorSpec::Radar(_) => Modality::Radar,
    };
    let own: Vec<&Candidate> = candidates.iter().filter(|c| c.modality == modality).collect();
    let probes: Vec<Probe> = cfg.probes.iter().map(|p| probe_of(p.class)).collect();
    let pattern = match spec {
        SensorSpec::Lidar(l) => Some(LidarPattern::new(l)),
        SensorSpec::Radar(_) => None,
    };
    let range = match spec {
        SensorSpec::Lidar(l) => l.max_range_m,
        SensorSpec::Radar(r) => r.max_range_m,
    };
    let rows = own
        .par_iter()
        .map(|c| {
            let mut row = Vec::new();
            for (j, t) in targets.iter().enumerate() {
                if (t.center - c.pose.position.truncate()).length() > range + 5.0 {
                    continue;
                }
                let f = los.frac[c.mount as usize][j];
                if f.iter().all(|x| *x == 0.0) {
                    continue;
                }
                let mut v = 0.0f64;
                for (k, (pc, probe)) in cfg.probes.iter().zip(&probes).enumerate() {
                    if f[k] == 0.0 {
                        continue;
                    }
                    let b = probe.at(t.center, ground_z, 0.0);
                    let p = match (spec, &pattern) {
                        (SensorSpec::Lidar(_), Some(pat)) => {
                            // P(N ≥ m) is 1 to 1e-12 once the mean passes m + 40.
                            let cap = (pc.min_points as f32 + 40.0) / f[k];
                            let n = pat.expected_returns_capped(&c.pose, probe, &b, cap) as f64 * f[k] as f64;
                            poisson_at_least(n, pc.min_points)
                        }
                        (SensorSpec::Radar(r), _) => {
                            radar_detection_probability(r, &c.pose, probe, &b) as f64 * f[k] as f64
                        }
                        _ => 0.0,
                    };
                    v += pc.weight as f64 * p;
                }
                if v as f32 > cfg.min_v {
                    row.push((j as u32, (v as f32).min(1.0)));
                }
            }
            row
        })
        .collect();
    Visibility {
        sensor: spec.name().to_owned(),
        modality,
        n_targets: targets.len(),
        candidates: own.iter().map(|c| c.id).collect(),
        rows,
    }
}
