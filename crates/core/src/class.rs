use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The road-user classes: the paper dataset's six, then the cyclist (nuScenes `bicycle`, a bicycle
/// with its rider), which traffic carries only when a study's class mix names it. Serde and
/// `Display` use the snake_case names that the nuScenes-layout dataset and the submission files
/// carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Class {
    Car,
    Truck,
    Bus,
    Motorcycle,
    Pedestrian,
    GolfCart,
    Bicycle,
}

impl Class {
    /// All classes in a fixed order (the order of per-class tables and heatmap channels).
    pub const ALL: [Class; 7] =
        [Class::Car, Class::Truck, Class::Bus, Class::Motorcycle, Class::Pedestrian, Class::GolfCart, Class::Bicycle];

    /// The paper dataset's six classes, a prefix of [`Class::ALL`]: what a detector's head and an
    /// evaluation cover unless the road users include cyclists.
    pub const PAPER: [Class; 6] =
        [Class::Car, Class::Truck, Class::Bus, Class::Motorcycle, Class::Pedestrian, Class::GolfCart];

    /// The first `n` classes of [`Class::ALL`] (at most all of them): a detector's head channels.
    pub fn first(n: usize) -> &'static [Class] {
        &Class::ALL[..n.min(Class::ALL.len())]
    }

    /// The snake_case name used in files.
    pub const fn name(self) -> &'static str {
        match self {
            Class::Car => "car",
            Class::Truck => "truck",
            Class::Bus => "bus",
            Class::Motorcycle => "motorcycle",
            Class::Pedestrian => "pedestrian",
            Class::GolfCart => "golf_cart",
            Class::Bicycle => "bicycle",
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
#[error("unknown class {0:?}; known classes: car, truck, bus, motorcycle, pedestrian, golf_cart, bicycle")]
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
        let err = "tram".parse::<Class>().unwrap_err();
        assert!(err.to_string().contains("golf_cart"));
        assert!(err.to_string().contains("bicycle"));
        assert!(err.to_string().contains("\"tram\""));
    }

    #[test]
    fn the_paper_classes_are_a_prefix_of_all() {
        assert_eq!(Class::first(Class::PAPER.len()), &Class::PAPER[..]);
        assert_eq!(Class::first(99), &Class::ALL[..]);
        assert_eq!(Class::ALL[Class::PAPER.len()], Class::Bicycle);
    }
}
