//! Roadside datasets in the nuScenes v1.0 layout, readable unchanged by nuscenes-devkit.
//!
//! - [`tables`]: the thirteen v1.0 tables;
//! - [`writer`]: tables and point files from frames (deterministic tokens, atomic files);
//! - [`reader`]: loading with every link between tables checked, and point files read back.
//!
//! - [`simulate`]: frames of a sensor rig over that traffic (scans, annotations, visibility);
//! - [`traffic`]: the road users (lane graph, signal plan, IDM, gap acceptance, pedestrians).

pub mod background;
pub mod error;
pub mod paint;
pub mod reader;
pub mod seed;
pub mod simulate;
pub mod tables;
pub mod traffic;
pub mod writer;

pub use error::DatasetError;
pub use reader::Dataset;
pub use writer::{Annotation, DatasetWriter, FrameData, SceneData, SensorModality, SensorSetup};
