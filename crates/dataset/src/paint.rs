//! Vehicle paint: each vehicle's reflectivity at a LiDAR's wavelength (905 nm), drawn from a
//! fleet's colours, so that a black car is seen less far than a white one.
//!
//! The colour shares are those colour-popularity surveys of new cars report for the world's
//! fleet in the 2020s, rounded (white about a third; black and grey a fifth each; silver,
//! blue and red under a tenth each). The reflectivities at 905 nm are assumptions of the order
//! measured for automotive paints (a white or red paint reflects much of the near infrared, a
//! carbon-black paint almost none): replace both with your fleet's and your paint's if you
//! know them. Pedestrians keep their class's reflectivity (clothing varies as much, and is not
//! modelled).

use hilo_core::Class;
use serde::{Deserialize, Serialize};

/// How vehicles' LiDAR reflectivity is chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VehiclePaint {
    /// Every vehicle has its class's reflectivity (0.5): one paint for the whole fleet.
    #[default]
    Class,
    /// Each vehicle a colour of [`FLEET`], drawn once per road user and dataset seed.
    Fleet,
}

/// One colour of the fleet: its share of vehicles and its reflectivity at 905 nm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Colour {
    pub name: &'static str,
    pub share: f64,
    pub reflectivity: f32,
}

/// The fleet's colours; the shares sum to 1.
pub const FLEET: [Colour; 7] = [
    Colour { name: "white", share: 0.35, reflectivity: 0.75 },
    Colour { name: "black", share: 0.19, reflectivity: 0.06 },
    Colour { name: "grey", share: 0.19, reflectivity: 0.25 },
    Colour { name: "silver", share: 0.09, reflectivity: 0.55 },
    Colour { name: "blue", share: 0.07, reflectivity: 0.20 },
    Colour { name: "red", share: 0.07, reflectivity: 0.45 },
    Colour { name: "other", share: 0.04, reflectivity: 0.35 },
];

/// The colour of road user `id` of the scene with seed stream `stream` in the dataset of seed
/// `seed`: a uniform draw from a hash of the three, against the shares' cumulative sum.
pub fn colour(seed: u64, stream: u64, id: u32) -> &'static Colour {
    let u = (crate::seed::derive_seed(seed, &[7, stream, id as u64]) >> 11) as f64 / (1u64 << 53) as f64;
    let mut acc = 0.0;
    for c in &FLEET {
        acc += c.share;
        if u < acc {
            return c;
        }
    }
    &FLEET[FLEET.len() - 1]
}

/// The LiDAR reflectivity of road user `id` of `class` (in the scene of `stream`) under
/// `paint`, or None to keep its class's.
pub fn reflectivity(paint: VehiclePaint, seed: u64, stream: u64, id: u32, class: Class) -> Option<f32> {
    match paint {
        VehiclePaint::Class => None,
        VehiclePaint::Fleet if class == Class::Pedestrian => None,
        VehiclePaint::Fleet => Some(colour(seed, stream, id).reflectivity),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn the_fleet_draws_its_colours_at_their_shares() {
        assert!((FLEET.iter().map(|c| c.share).sum::<f64>() - 1.0).abs() < 1e-12);
        let n = 40_000u32;
        for c in &FLEET {
            let k = (0..n).filter(|id| colour(3, 17, *id).name == c.name).count() as f64;
            let sd = (n as f64 * c.share * (1.0 - c.share)).sqrt();
            assert!((k - n as f64 * c.share).abs() < 4.5 * sd, "{}: {k} of {n}", c.name);
        }
        // One colour per road user, scene and seed; other scenes and seeds draw again.
        assert!((0..100).all(|id| colour(3, 17, id) == colour(3, 17, id)));
        assert!((0..100).any(|id| colour(3, 17, id) != colour(3, 18, id)));
        assert!((0..100).any(|id| colour(3, 17, id) != colour(4, 17, id)));
        assert_eq!(reflectivity(VehiclePaint::Class, 3, 17, 5, Class::Car), None);
        assert_eq!(reflectivity(VehiclePaint::Fleet, 3, 17, 5, Class::Pedestrian), None);
        assert_eq!(reflectivity(VehiclePaint::Fleet, 3, 17, 5, Class::Bus), Some(colour(3, 17, 5).reflectivity));
        let parsed: VehiclePaint = serde_json::from_str("\"fleet\"").unwrap();
        assert_eq!(parsed, VehiclePaint::Fleet);
    }
}
