//! Analytic primitives and the watertight triangle test, one file each.

pub mod capsule;
pub mod ground;
pub mod obb;
pub mod triangle;

pub use capsule::Capsule;
pub use ground::GroundPlane;
pub use obb::intersect_box;
