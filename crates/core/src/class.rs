use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The six road-user classes of the paper's dataset. Serde and `Display` use the snake_case
/// names that the nuScenes-layout dataset and the submission files carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Class {
    Car,
    Truck,
    Bus,
    Motorcycle,
    Pedestrian,
    GolfCart,
}

impl Class {
    /// All classes in a fixed order (the order of per-class tables and heatmap channels).
    pub const ALL: [Class; 6] =
        [Class::Car, Class::Truck, Class::Bus, Class::Motorcycle, Class::Pedestrian, Class::GolfCart];

    /// The snake_case name used in files.
    pub const fn name(self) -> &'static str {
        match self {
            Class::Car => "car",
            Class::Truck => "truck",
            Class::Bus => "bus",
            Class::Motorcycle => "motorcycle",
            Class::Pedestrian => "pedestrian",
            Class::GolfCart => "golf_cart",
        }
    }

    /// Position in [`Class::ALL`].
    pub const fn index(self) -> usize {
        self as usize
    }
}

impl fmt::Display for Class {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A class name that is not one of [`Class::ALL`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown class {0:?}; known classes: car, truck, bus, motorcycle, pedestrian, golf_cart")]
pub struct UnknownClass(pub String);

impl FromStr for Class {
    type Err = UnknownClass;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Class::ALL.into_iter().find(|c| c.name() == s).ok_or_else(|| UnknownClass(s.to_owned()))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_through_str_and_serde() {
        for c in Class::ALL {
            assert_eq!(c.name().parse::<Class>(), Ok(c));
            let json = serde_json::to_string(&c).unwrap();
            assert_eq!(json, format!("\"{}\"", c.name()));
            assert_eq!(serde_json::from_str::<Class>(&json).unwrap(), c);
            assert_eq!(Class::ALL[c.index()], c);
        }
    }

    #[test]
    fn unknown_name_lists_known_ones() {
        let err = "bicycle".parse::<Class>().unwrap_err();
        assert!(err.to_string().contains("golf_cart"));
        assert!(err.to_string().contains("bicycle"));
    }
}
