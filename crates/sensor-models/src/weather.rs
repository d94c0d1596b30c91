//! Weather as a scene condition: rain and fog, applied to the sensor specs before a scan.
//!
//! What each sensor loses, by published models:
//!
//! - **LiDAR (905 nm), fog.** Extinction from the meteorological optical range V (WMO's
//!   definition: the distance over which a collimated beam keeps 5% of its power), α = ln 20 / V
//!   (Koschmieder; the coefficient Hahner et al., ICCV 2021, derive their fog from).
//! - **LiDAR, rain.** ITU-R P.1814 (terrestrial free-space optical links): γ = 1.076 R^0.67 dB/km
//!   for rain rate R in mm/h, here as an extinction coefficient α = γ ln 10 / 10 per km.
//! - **LiDAR, both.** A return travels the path twice: its power falls by exp(−2αr), on top of the
//!   1/r² of a hard target. A target that the clear sensor just sees at its maximum range R₀ is
//!   then seen up to R with R² e^{2αR} = R₀², i.e. R = W(αR₀)/α (W the principal branch of
//!   Lambert's function): the maximum range against visibility. The scan's intensity carries the
//!   same two-way factor, so the catalog's intensity drop-off thins weak returns further.
//! - **Radar (77 GHz), rain.** ITU-R P.838-3: γ = k R^α dB/km with k and α from the
//!   recommendation's fitted coefficients at the carrier frequency (horizontal polarisation);
//!   the SNR loses 2γr over the two-way path.
//!
//! - **LiDAR, fog's backscatter** (`fog_backscatter = true`): the pulse's echo from the fog
//!   itself, a metre or two in front of the sensor ([`crate::fog`], Hahner et al.'s
//!   soft-target model). It does not only add points around the sensor: a beam reporting its
//!   strongest echo reports the fog's wherever it outshines the road user behind it, so dense
//!   fog takes the distant road users of a strongest-return sensor. It needs a sensor with a
//!   datasheet detection range (the lidar equation's units compare the two echoes); the
//!   paper's sensors, which keep every return, are left as they are.
//!
//! Left out, and why: rain's drop returns (sparse points within a few metres of the sensor,
//! where a roadside mast sees no road user, so they move no detection here); fog's attenuation
//! of the radar (ITU-R P.840: liquid water of dense fog costs a 77 GHz link a few dB/km at most, a
//! fraction of a dB over an intersection); snow; wet-road spray; and the weather's effect on the
//! placement IP's visibility (placement assumes clear air).

use crate::fog::{FogChannel, FogEcho};
pub use crate::range::{lambert_w0, max_range_m};
use crate::spec::{LidarSpec, RadarSpec};
use serde::{Deserialize, Serialize};

/// A weather condition (`[dataset.weather]` in a study or dataset file). Clear by default.
#[derive(Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Weather {
    /// Rain rate, mm/h (0: none; 2.5 light, 10 moderate, 25 heavy, 50+ violent).
    pub rain_mm_h: f32,
    /// Meteorological optical range in fog, m (absent: no fog; < 1,000 m is fog, < 200 m dense).
    pub fog_visibility_m: Option<f32>,
    /// The fog's own echo ([`crate::fog`]) for the LiDARs with a detection range (false:
    /// fog only attenuates). Needs `fog_visibility_m`.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub fog_backscatter: bool,
}

/// As derived, but `fog_backscatter` appears only when set: the content hash of a dataset
/// (taken over this form) stays what it was for the weathers it already described.
impl std::fmt::Debug for Weather {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("Weather");
        d.field("rain_mm_h", &self.rain_mm_h).field("fog_visibility_m", &self.fog_visibility_m);
        if self.fog_backscatter {
            d.field("fog_backscatter", &self.fog_backscatter);
        }
        d.finish()
    }
}

/// dB per km to an extinction coefficient per metre (power).
const DB_PER_KM_TO_PER_M: f32 = std::f32::consts::LN_10 / 10.0 / 1000.0;

impl std::fmt::Display for Weather {
    /// "clear", or the rain rate and the fog's visibility, e.g. "fog (visibility 60 m)".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut parts = Vec::new();
        if self.rain_mm_h > 0.0 {
            parts.push(format!("rain ({} mm/h)", self.rain_mm_h));
        }
        if let Some(v) = self.fog_visibility_m {
            let echo = if self.fog_backscatter { ", its echo" } else { "" };
            parts.push(format!("fog (visibility {v} m{echo})"));
        }
        if parts.is_empty() { f.write_str("clear") } else { f.write_str(&parts.join(" and ")) }
    }
}

/// A weather value outside what the models cover: the field of `[weather]`, its value, and why.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("weather.{field} = {value}: {reason}")]
pub struct WeatherError {
    pub field: &'static str,
    pub value: String,
    pub reason: &'static str,
}

impl Weather {
    pub fn is_clear(&self) -> bool {
        self.rain_mm_h == 0.0 && self.fog_visibility_m.is_none()
    }

    /// Refuses values outside what the models cover.
    pub fn check(&self) -> Result<(), WeatherError> {
        if !(self.rain_mm_h.is_finite() && (0.0..=200.0).contains(&self.rain_mm_h)) {
            return Err(WeatherError {
                field: "rain_mm_h",
                value: self.rain_mm_h.to_string(),
                reason: "give 0 to 200 mm/h",
            });
        }
        if let Some(v) = self.fog_visibility_m
            && !(v.is_finite() && (10.0..=10_000.0).contains(&v))
        {
            return Err(WeatherError {
                field: "fog_visibility_m",
                value: v.to_string(),
                reason: "give 10 to 10,000 m, or leave it out for no fog",
            });
        }
        if self.fog_backscatter && self.fog_visibility_m.is_none() {
            return Err(WeatherError {
                field: "fog_backscatter",
                value: "true".to_owned(),
                reason: "fog's echo needs fog: give fog_visibility_m too",
            });
        }
        Ok(())
    }

    /// The LiDAR's extinction coefficient (per metre, one way): fog and rain.
    pub fn lidar_extinction_per_m(&self) -> f32 {
        self.fog_visibility_m.map_or(0.0, fog_extinction_per_m)
            + rain_optical_db_per_km(self.rain_mm_h) * DB_PER_KM_TO_PER_M
    }

    /// `spec` in this weather: maximum range from the hard-target range equation (for a sensor
    /// with a datasheet detection range, the extinction in its lidar equation instead, which
    /// shortens each target's reach by its reflectivity), intensity with the two-way
    /// transmission, and with `fog_backscatter` the fog's echo ([`Self::fog_echo`]). Clear
    /// weather returns it unchanged.
    pub fn lidar(&self, spec: &LidarSpec) -> LidarSpec {
        let mut s = spec.clone();
        if self.is_clear() {
            return s;
        }
        let a = self.lidar_extinction_per_m();
        if s.detection_range.is_some() {
            // The lidar equation carries the extinction to every target by its reflectivity;
            // `max_range_m` stays the sensor's range gate. Its units also weigh fog's echo
            // against a surface's.
            s.fog_echo = self.fog_echo();
            s.extinction_per_m += a;
        } else {
            s.max_range_m = max_range_m(spec.max_range_m, a).max(spec.min_range_m);
        }
        s.atmosphere_attenuation_per_m += 2.0 * a;
        s
    }

    /// The fog's echo a LiDAR meets in this weather (Hahner et al.'s channel through the fog's
    /// and the rain's extinction): none without `fog_backscatter`.
    pub fn fog_echo(&self) -> Option<FogEcho> {
        let v = self.fog_visibility_m.filter(|_| self.fog_backscatter)?;
        Some(FogEcho::new(&FogChannel::hahner(f64::from(v), f64::from(self.lidar_extinction_per_m()))))
    }

    /// `spec` in this weather: the rain's one-way loss at its carrier (dB per metre).
    pub fn radar(&self, spec: &RadarSpec) -> RadarSpec {
        let mut s = spec.clone();
        if self.rain_mm_h > 0.0 {
            s.path_loss_db_per_m += rain_radio_db_per_km(spec.carrier_ghz, self.rain_mm_h) / 1000.0;
        }
        s
    }
}

/// Koschmieder: the extinction coefficient (per metre) that leaves 5% over the visibility.
pub fn fog_extinction_per_m(visibility_m: f32) -> f32 {
    20f32.ln() / visibility_m
}

/// ITU-R P.1814: specific attenuation of rain for optical links, dB/km.
pub fn rain_optical_db_per_km(rain_mm_h: f32) -> f32 {
    if rain_mm_h <= 0.0 { 0.0 } else { 1.076 * rain_mm_h.powf(0.67) }
}

/// ITU-R P.838-3 coefficients (k, α) for horizontal polarisation at `f_ghz` (1–1,000 GHz).
pub fn p838_horizontal(f_ghz: f32) -> (f64, f64) {
    const K: [(f64, f64, f64); 4] = [
        (-5.33980, -0.10008, 1.13098),
        (-0.35351, 1.26970, 0.45400),
        (-0.23789, 0.86036, 0.15354),
        (-0.94158, 0.64552, 0.16817),
    ];
    const K_M: f64 = -0.18961;
    const K_C: f64 = 0.71147;
    const A: [(f64, f64, f64); 5] = [
        (-0.14318, 1.82442, -0.55187),
        (0.29591, 0.77564, 0.19822),
        (0.32177, 0.63773, 0.13164),
        (-5.37610, -0.96230, 1.47828),
        (16.1721, -3.29980, 3.43990),
    ];
    const A_M: f64 = 0.67849;
    const A_C: f64 = -1.95537;
    let lf = f64::from(f_ghz).log10();
    let gauss = |t: &[(f64, f64, f64)]| t.iter().map(|(a, b, c)| a * (-((lf - b) / c).powi(2)).exp()).sum::<f64>();
    let k = 10f64.powf(gauss(&K) + K_M * lf + K_C);
    let alpha = gauss(&A) + A_M * lf + A_C;
    (k, alpha)
}

/// ITU-R P.838-3: specific attenuation of rain at `f_ghz`, dB/km (horizontal polarisation).
pub fn rain_radio_db_per_km(f_ghz: f32, rain_mm_h: f32) -> f32 {
    if rain_mm_h <= 0.0 {
        return 0.0;
    }
    let (k, alpha) = p838_horizontal(f_ghz);
    (k * f64::from(rain_mm_h).powf(alpha)) as f32
}
