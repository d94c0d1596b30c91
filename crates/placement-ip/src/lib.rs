//! Sensor placement for hilo: the paper's Algorithm 1 and its extensions.
//!
//! - [`targets`]: the ROI target grid with weights;
//! - [`candidates`]: mount points along signal poles and mast arms, sensor orientations;
//! - [`visibility`]: V per sensor type from the sensor models and line of sight;
//! - [`instance`]: the problem as solvers see it, and the exact objective of any selection;
//! - solvers: [`exact`] (branch and bound that proves the paper's count-limited
//!   configurations optimal), [`mip`] (the IP for CBC, plain or strengthened, any limit),
//!   [`calibrated`] (the objective `hilo validate` fits to trained accuracy, for CBC; its
//!   [`calibrated::file`] ships a fit across sites with its prediction of a rig's mAP),
//!   [`greedy`] (the baseline), [`exhaustive`] (the oracle on small instances).

pub mod calibrated;
pub mod candidates;
pub mod coverage;
pub mod error;
pub mod exact;
pub mod exhaustive;
pub mod greedy;
pub mod instance;
pub mod mip;
pub mod pipeline;
pub mod placement;
pub mod targets;
pub mod visibility;

pub use candidates::{Candidate, CandidateConfig, Modality, sample_candidates};
pub use error::PlacementError;
pub use instance::{Instance, Limit, Outcome, SensorOption, SensorType, evaluate};
pub use placement::{PlacedSensor, Placement};
pub use targets::{Target, roi_targets};
pub use visibility::{LineOfSight, Visibility, VisibilityConfig, compute_visibility};
