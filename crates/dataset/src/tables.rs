//! The nuScenes v1.0 tables, field for field as nuscenes-devkit reads them.

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    pub token: String,
    pub log_token: String,
    pub nbr_samples: usize,
    pub first_sample_token: String,
    pub last_sample_token: String,
    pub name: String,
    pub description: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    pub token: String,
    pub timestamp: u64,
    pub prev: String,
    pub next: String,
    pub scene_token: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleData {
    pub token: String,
    pub sample_token: String,
    pub ego_pose_token: String,
    pub calibrated_sensor_token: String,
    pub timestamp: u64,
    pub fileformat: String,
    pub is_key_frame: bool,
    pub height: u32,
    pub width: u32,
    pub filename: String,
    pub prev: String,
    pub next: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleAnnotation {
    pub token: String,
    pub sample_token: String,
    pub instance_token: String,
    pub visibility_token: String,
    pub attribute_tokens: Vec<String>,
    /// Centre, metres (global = the scene's local frame).
    pub translation: [f64; 3],
    /// Width, length, height, metres.
    pub size: [f64; 3],
    /// Quaternion w, x, y, z.
    pub rotation: [f64; 4],
    pub prev: String,
    pub next: String,
    pub num_lidar_pts: u32,
    pub num_radar_pts: u32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Instance {
    pub token: String,
    pub category_token: String,
    pub nbr_annotations: usize,
    pub first_annotation_token: String,
    pub last_annotation_token: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Category {
    pub token: String,
    pub name: String,
    pub description: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Attribute {
    pub token: String,
    pub name: String,
    pub description: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Visibility {
    pub token: String,
    pub level: String,
    pub description: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sensor {
    pub token: String,
    pub channel: String,
    pub modality: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibratedSensor {
    pub token: String,
    pub sensor_token: String,
    pub translation: [f64; 3],
    pub rotation: [f64; 4],
    pub camera_intrinsic: Vec<Vec<f64>>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EgoPose {
    pub token: String,
    pub timestamp: u64,
    pub rotation: [f64; 4],
    pub translation: [f64; 3],
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Log {
    pub token: String,
    pub logfile: String,
    pub vehicle: String,
    pub date_captured: String,
    pub location: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Map {
    pub token: String,
    pub log_tokens: Vec<String>,
    pub category: String,
    pub filename: String,
}

/// All tables of one dataset version.
#[derive(Clone, Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct Tables {
    pub scene: Vec<Scene>,
    pub sample: Vec<Sample>,
    pub sample_data: Vec<SampleData>,
    pub sample_annotation: Vec<SampleAnnotation>,
    pub instance: Vec<Instance>,
    pub category: Vec<Category>,
    pub attribute: Vec<Attribute>,
    pub visibility: Vec<Visibility>,
    pub sensor: Vec<Sensor>,
    pub calibrated_sensor: Vec<CalibratedSensor>,
    pub ego_pose: Vec<EgoPose>,
    pub log: Vec<Log>,
    pub map: Vec<Map>,
}

/// The table file names (without `.json`), in the devkit's loading order.
pub const TABLE_NAMES: [&str; 13] = [
    "category",
    "attribute",
    "visibility",
    "instance",
    "sensor",
    "calibrated_sensor",
    "ego_pose",
    "log",
    "scene",
    "sample",
    "sample_data",
    "sample_annotation",
    "map",
];
