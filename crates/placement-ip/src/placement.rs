//! A solved placement as every stage reads and writes it (`placements/<name>.json`): the chosen
//! sensors with their poses, how the solution was found and how good it is, its coverage and
//! cost, and the content hashes of the scene and catalog it was made for.

use crate::candidates::Modality;
use crate::error::PlacementError;
use hilo_sensor_models::SensorPose;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One chosen sensor.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlacedSensor {
    /// Catalog name.
    #[serde(rename = "type")]
    pub ty: String,
    pub modality: Modality,
    pub candidate_id: u32,
    /// The mounting structure (pole or mast arm) it hangs on.
    pub structure: String,
    pub pose: SensorPose,
    /// The pose for people: position, heading and down-tilt.
    pub position_m: [f32; 3],
    pub yaw_deg: f32,
    pub pitch_deg: f32,
}

impl PlacedSensor {
    pub fn new(ty: &str, modality: Modality, candidate_id: u32, structure: &str, pose: SensorPose) -> Self {
        PlacedSensor {
            ty: ty.to_owned(),
            modality,
            candidate_id,
            structure: structure.to_owned(),
            pose,
            position_m: pose.position.to_array(),
            yaw_deg: pose.yaw.to_degrees(),
            pitch_deg: pose.pitch.to_degrees(),
        }
    }
}

/// A bound or gap in a placement file: JSON has no infinity, so an unknown bound is written as
/// `null` and read back as infinity (a placement hilo writes, hilo reads).
mod unbounded {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() { s.serialize_f64(*v) } else { s.serialize_none() }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
    }
}

/// A configuration's placement.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Placement {
    /// The configuration's name.
    pub name: String,
    pub sensors: Vec<PlacedSensor>,
    pub objective: f64,
    /// The best proven upper bound of the objective; infinite (`null` in the file) when no
    /// bound is known.
    #[serde(with = "unbounded")]
    pub bound: f64,
    /// `(bound − objective) / objective`; infinite (`null`) without a bound.
    #[serde(with = "unbounded")]
    pub gap: f64,
    pub proven_optimal: bool,
    pub solve_seconds: f64,
    pub method: String,
    /// Whether it was optimised (hilo places every configuration now, one of a single modality
    /// for that modality's coverage; placements of older versions gave such a configuration the
    /// poses of a sibling with both modalities and wrote `false`).
    pub solved: bool,
    pub greedy_objective: f64,
    /// Share of central-ROI cells hit by at least one LiDAR ray (the paper's central coverage).
    pub central_coverage: f64,
    /// Share of all ROI cells hit by a LiDAR ray and covered by a radar.
    pub lidar_radar_overlap: f64,
    pub cost_usd: f64,
    pub targets: usize,
    pub candidates: usize,
    /// Content hashes of the scene and the catalog the placement was made for.
    pub scene_hash: String,
    pub catalog_hash: String,
    /// Placed with a calibration file: the rig's predicted mAP and how far the junction lies
    /// from the sites the file was fitted on ([`crate::calibrated::file`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prediction: Option<crate::calibrated::file::Prediction>,
}

impl Placement {
    /// Reads a placement written by [`Placement::save`]; the error names the file and field.
    pub fn load(path: &Path) -> Result<Placement, PlacementError> {
        let text = hilo_core::fs::read_text_bounded(path, hilo_core::fs::limit::CONFIG)
            .map_err(|e| hilo_core::fs::FileError::io(path, e))?;
        Placement::from_json(&text, path)
    }

    /// [`Placement::load`] of text already read; `path` names it in errors.
    pub fn from_json(text: &str, path: &Path) -> Result<Placement, PlacementError> {
        let content = |m: String| PlacementError::from(hilo_core::fs::FileError::content(path, m));
        let p: Placement =
            serde_json::from_str(text).map_err(|e| content(format!("not a placement written by `hilo place`: {e}")))?;
        if p.sensors.is_empty() {
            return Err(content("the placement has no sensors".into()));
        }
        for (i, s) in p.sensors.iter().enumerate() {
            if !s.pose.is_valid() {
                return Err(content(format!("sensors[{i}].pose is not finite: {:?}", s.pose)));
            }
        }
        Ok(p)
    }

    /// The placement as pretty JSON (what [`Placement::load`] reads).
    pub fn to_json(&self) -> Result<String, PlacementError> {
        Ok(serde_json::to_string_pretty(self)?)
    }

    /// Refuses a placement made for another scene or catalog than the one given.
    pub fn check_made_for(&self, scene_hash: &str, catalog_hash: &str, source: &Path) -> Result<(), PlacementError> {
        if self.scene_hash != scene_hash {
            return Err(PlacementError::MadeFor {
                source_file: source.to_path_buf(),
                name: self.name.clone(),
                reason: format!(
                    "for another scene (scene hash {} there, {scene_hash} here); place it again on this scene",
                    self.scene_hash
                ),
            });
        }
        if self.catalog_hash != catalog_hash {
            return Err(PlacementError::MadeFor {
                source_file: source.to_path_buf(),
                name: self.name.clone(),
                reason: format!(
                    "with another sensor catalog (catalog hash {} there, {catalog_hash} here)",
                    self.catalog_hash
                ),
            });
        }
        Ok(())
    }

    /// Whether any sensor is a radar.
    pub fn has_radar(&self) -> bool {
        self.sensors.iter().any(|s| s.modality == Modality::Radar)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn a_placement_round_trips_through_its_file() {
        let pose = SensorPose::new(Vec3::new(13.0, 16.5, 7.8), -2.2, 0.17, 0.0);
        let p = Placement {
            name: "2x lidar-16 + radar".into(),
            sensors: vec![PlacedSensor::new("lidar-16", Modality::Lidar, 7, "NE pole", pose)],
            objective: 12107.3,
            bound: 12107.3,
            gap: 0.0,
            proven_optimal: true,
            solve_seconds: 0.1,
            method: "exact".into(),
            solved: true,
            greedy_objective: 12081.8,
            central_coverage: 0.545,
            lidar_radar_overlap: 0.3,
            cost_usd: 10000.0,
            targets: 4846,
            candidates: 616,
            scene_hash: "s".into(),
            catalog_hash: "c".into(),
            prediction: None,
        };
        let dir = std::env::temp_dir().join(format!("hilo-placement-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("p.json");
        std::fs::write(&path, p.to_json().unwrap()).unwrap();
        assert_eq!(Placement::load(&path).unwrap(), p);
        assert!(p.check_made_for("s", "c", &path).is_ok());
        let e = p.check_made_for("t", "c", &path).unwrap_err().to_string();
        assert!(e.contains("another scene"), "{e}");
        std::fs::write(&path, "{\"name\": 1}").unwrap();
        assert!(Placement::load(&path).unwrap_err().to_string().contains("p.json"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_placement_without_a_bound_round_trips_through_its_file() {
        let pose = SensorPose::new(Vec3::new(1.0, 2.0, 6.0), 0.5, 0.1, 0.0);
        let p = Placement {
            name: "2x lidar-16 + 2x radar".into(),
            sensors: vec![PlacedSensor::new("radar-4d", Modality::Radar, 3, "pole", pose)],
            objective: 10.0,
            bound: f64::INFINITY,
            gap: f64::INFINITY,
            proven_optimal: false,
            solve_seconds: 1.0,
            method: "greedy".into(),
            solved: true,
            greedy_objective: 10.0,
            central_coverage: 0.5,
            lidar_radar_overlap: 0.2,
            cost_usd: 1.0,
            targets: 1,
            candidates: 1,
            scene_hash: "s".into(),
            catalog_hash: "c".into(),
            prediction: None,
        };
        let json = p.to_json().unwrap();
        assert!(json.contains("\"bound\": null") && json.contains("\"gap\": null"), "{json}");
        let d = std::env::temp_dir().join(format!("hilo-placement-null-{}.json", std::process::id()));
        std::fs::write(&d, &json).unwrap();
        let back = Placement::load(&d).unwrap();
        std::fs::remove_file(&d).unwrap();
        assert_eq!(back, p);
    }
}
