//! Sensor specifications and the priced catalog (`fixtures/sensors.toml`).
//!
//! Specs are read with serde and validated once ([`Catalog::from_toml_str`]); the simulation
//! and probability models then trust them.

use crate::error::SensorError;
use crate::radar_effects::{Azimuth, AzimuthRow, RadarEffects};
use hilo_core::Class;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The default catalog: the paper's Table I.
pub const DEFAULT_CATALOG_TOML: &str = include_str!("../../../fixtures/sensors.toml");

/// The datasheet catalog (`fixtures/sensors-datasheet.toml`): the same sensors with published beam
/// tables and the field radar's effects; the embedded default study names it.
pub const DATASHEET_CATALOG_TOML: &str = include_str!("../../../fixtures/sensors-datasheet.toml");

/// The catalogs hilo embeds, by the file name a study gives for them.
pub const EMBEDDED_CATALOGS: [(&str, &str); 2] =
    [("sensors.toml", DEFAULT_CATALOG_TOML), ("sensors-datasheet.toml", DATASHEET_CATALOG_TOML)];

/// A spinning multi-beam LiDAR.
#[derive(Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LidarSpec {
    pub name: String,
    pub beams: u32,
    pub rate_hz: f32,
    pub hfov_deg: f32,
    /// Vertical field of view, centred on the horizon, when `elevations_deg` is not given.
    pub vfov_deg: f32,
    /// Per-beam elevations (any order); overrides the uniform spread over `vfov_deg`.
    #[serde(default)]
    pub elevations_deg: Option<Vec<f32>>,
    pub azimuth_resolution_deg: f32,
    pub min_range_m: f32,
    pub max_range_m: f32,
    /// Standard deviation of Gaussian range noise.
    pub range_noise_m: f32,
    /// Intensity falls as exp(−a·d) with range d (CARLA's atmosphere attenuation).
    pub atmosphere_attenuation_per_m: f32,
    /// Probability that any return is dropped (CARLA `dropoff_general_rate`).
    pub dropoff_general_rate: f32,
    /// Returns with intensity above this are never dropped by the intensity rule.
    pub dropoff_intensity_limit: f32,
    /// Drop probability of a zero-intensity return; falls linearly to 0 at the limit.
    pub dropoff_zero_intensity: f32,
    pub price_usd: f64,
    /// Where the price comes from, or "assumption: …".
    pub price_source: String,
    /// The lidar equation's detection limit, from a datasheet's "range R at reflectivity ρ":
    /// a return is kept only where its received power, ρ·|cos incidence|·e^{−2αr}/r², reaches
    /// that of the reference target at its range, ρ_ref/R_ref² (a Lambertian target filling the
    /// beam). A dark car is then seen less far than a white one, and grazing returns fall out
    /// first. Absent: every return within `max_range_m` is kept (the paper's sensors).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detection_range: Option<DetectionRange>,
    /// Extinction of the air, per metre one way (the α above): 0 in clear air; set by
    /// [`crate::weather::Weather::lidar`] in fog and rain for a sensor with a `detection_range`.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub extinction_per_m: f32,
    /// Foliage that moves in the wind, a property of the scene's weather rather than of the
    /// sensor: set from a dataset's `foliage` setting, never read from a catalog (absent: crowns
    /// are still and opaque). See [`Foliage`].
    #[serde(skip)]
    pub foliage: Option<Foliage>,
    /// The beam's footprint and the sensor's return mode (absent: a ray of no width, one
    /// return). Needs a `detection_range`: the lidar equation decides which partial hits are
    /// seen. See [`Beam`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beam: Option<Beam>,
    /// The echo of fog in front of the sensor, a property of the scene's weather: set by
    /// [`crate::weather::Weather::lidar`] when the weather asks for fog's backscatter, never read
    /// from a catalog (absent: fog only attenuates). See [`crate::fog`].
    #[serde(skip)]
    pub fog_echo: Option<crate::fog::FogEcho>,
}

/// A LiDAR beam of finite width and the echoes it returns. The pulse leaves the sensor as an
/// elliptical Gaussian spot whose 1/e² full angles are `horizontal_mrad` (across the scan) and
/// `vertical_mrad`; it is sampled by sub-rays on a hexagonal lattice of `rings` rings inside
/// the 1/e² contour (1 + 3·rings·(rings + 1) sub-rays), each weighted by the spot's irradiance.
/// Sub-ray hits closer than `separation_m` along the beam form one echo, reported at their
/// power-weighted range (a mixed pixel, between a pedestrian and the wall behind); an echo is
/// seen when its summed received power reaches the lidar equation's threshold, so a pole
/// narrower than the spot is seen less far than a wall. `returns` says which echoes the
/// sensor reports.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Beam {
    pub horizontal_mrad: f32,
    pub vertical_mrad: f32,
    pub returns: ReturnMode,
    pub separation_m: f32,
    #[serde(default = "two_rings")]
    pub rings: u32,
}

fn two_rings() -> u32 {
    2
}

/// Which of a pulse's echoes a LiDAR reports (Velodyne's three modes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReturnMode {
    /// The echo of the highest received power.
    Strongest,
    /// The farthest echo that is seen.
    Last,
    /// The strongest and the last; when they are one echo, the strongest and the second
    /// strongest.
    Dual,
}

/// Tree crowns as a LiDAR sees them in wind: porous and moving. A ray whose first surface is
/// foliage passes through a gap between the leaves with `gap_probability` (and returns from
/// whatever lies behind), and otherwise returns from a leaf displaced along the ray by a
/// Gaussian of `sway_m`; each ray and frame draws anew (leaf motion is uncorrelated at a beam's
/// footprint from one 10 Hz frame to the next). So the static scene no longer returns the same
/// range frame after frame, and a learned background does not remove it for free.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Foliage {
    pub gap_probability: f32,
    pub sway_m: f32,
}

fn is_zero(v: &f32) -> bool {
    *v == 0.0
}

/// A datasheet's range at a stated target reflectivity (normal incidence, clear air).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectionRange {
    pub range_m: f32,
    /// Lambertian reflectivity of the reference target at the LiDAR's wavelength, (0, 1].
    pub reflectivity: f32,
}

/// As derived, but the fields added after the first catalogs (`detection_range`,
/// `extinction_per_m`, `foliage`, `beam`) appear only when set: a catalog's content hash (taken
/// over this form) stays what it was for the LiDARs it already described.
impl std::fmt::Debug for LidarSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("LidarSpec");
        d.field("name", &self.name)
            .field("beams", &self.beams)
            .field("rate_hz", &self.rate_hz)
            .field("hfov_deg", &self.hfov_deg)
            .field("vfov_deg", &self.vfov_deg)
            .field("elevations_deg", &self.elevations_deg)
            .field("azimuth_resolution_deg", &self.azimuth_resolution_deg)
            .field("min_range_m", &self.min_range_m)
            .field("max_range_m", &self.max_range_m)
            .field("range_noise_m", &self.range_noise_m)
            .field("atmosphere_attenuation_per_m", &self.atmosphere_attenuation_per_m)
            .field("dropoff_general_rate", &self.dropoff_general_rate)
            .field("dropoff_intensity_limit", &self.dropoff_intensity_limit)
            .field("dropoff_zero_intensity", &self.dropoff_zero_intensity)
            .field("price_usd", &self.price_usd)
            .field("price_source", &self.price_source);
        if let Some(r) = &self.detection_range {
            d.field("detection_range", r);
        }
        if self.extinction_per_m != 0.0 {
            d.field("extinction_per_m", &self.extinction_per_m);
        }
        if let Some(f) = &self.foliage {
            d.field("foliage", f);
        }
        if let Some(b) = &self.beam {
            d.field("beam", b);
        }
        if let Some(e) = &self.fog_echo {
            d.field("fog_echo", e);
        }
        d.finish()
    }
}

/// A 4D imaging radar (range, azimuth, elevation, Doppler).
#[derive(Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RadarSpec {
    pub name: String,
    pub rate_hz: f32,
    pub hfov_deg: f32,
    pub vfov_deg: f32,
    pub min_range_m: f32,
    pub max_range_m: f32,
    /// Angular grid of the rays cast per frame.
    pub ray_azimuth_step_deg: f32,
    pub ray_elevation_step_deg: f32,
    /// Resolution cells: hits in one cell give one detection.
    pub range_resolution_m: f32,
    pub azimuth_resolution_deg: f32,
    pub elevation_resolution_deg: f32,
    pub range_noise_m: f32,
    pub azimuth_noise_deg: f32,
    pub elevation_noise_deg: f32,
    pub velocity_noise_mps: f32,
    pub rcs_noise_db: f32,
    /// SNR of a 10 dBsm target at `max_range_m`; SNR scales with σ/R⁴ (the radar equation).
    pub snr_at_max_range_db: f32,
    pub detection_threshold_db: f32,
    /// Probability that a resolution cell on static structures (poles, buildings, trees) is
    /// reported.
    pub clutter_probability: f32,
    /// The same for the road surface, far lower: at grazing incidence the ground scatters
    /// little back.
    pub ground_clutter_probability: f32,
    pub static_rcs_dbsm: f32,
    /// At most this many detections per frame (the strongest are kept).
    pub max_points: u32,
    /// At most this many detections per target: the cells with the most hits, standing for
    /// the target's dominant scattering centres (a real radar's peak detection reports a
    /// handful per vehicle, not one per resolution cell it spans).
    pub max_detections_per_target: u32,
    pub rcs_dbsm: RcsTable,
    pub price_usd: f64,
    pub price_source: String,
    /// Carrier frequency, GHz (what rain attenuates by; 77 for automotive and roadside 4D
    /// radars).
    #[serde(default = "carrier_77")]
    pub carrier_ghz: f32,
    /// One-way path loss of the air, dB per metre: 0 in clear air; set by
    /// [`crate::weather::Weather::radar`] for rain. The SNR loses it twice over the range.
    #[serde(default)]
    pub path_loss_db_per_m: f32,
    /// Azimuth resolution and accuracy by angle off boresight (`[[radar.azimuth_table]]`,
    /// from boresight outward); empty: `azimuth_resolution_deg` and `azimuth_noise_deg` over
    /// the whole field. See [`crate::radar_effects`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub azimuth_table: Vec<AzimuthRow>,
    /// Multipath ghosts, side lobes, false alarms, unresolved targets, vegetation Doppler and
    /// RCS by aspect (`[radar.effects]`); all off when absent.
    #[serde(default, skip_serializing_if = "RadarEffects::is_ideal")]
    pub effects: RadarEffects,
}

fn carrier_77() -> f32 {
    77.0
}

/// As derived, but the fields added after the first catalogs (`carrier_ghz`,
/// `path_loss_db_per_m`, `azimuth_table`, `effects`) appear only when they differ from their
/// defaults: a catalog's content
/// hash (taken over this form) stays what it was for the radars it already described.
impl std::fmt::Debug for RadarSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("RadarSpec");
        d.field("name", &self.name)
            .field("rate_hz", &self.rate_hz)
            .field("hfov_deg", &self.hfov_deg)
            .field("vfov_deg", &self.vfov_deg)
            .field("min_range_m", &self.min_range_m)
            .field("max_range_m", &self.max_range_m)
            .field("ray_azimuth_step_deg", &self.ray_azimuth_step_deg)
            .field("ray_elevation_step_deg", &self.ray_elevation_step_deg)
            .field("range_resolution_m", &self.range_resolution_m)
            .field("azimuth_resolution_deg", &self.azimuth_resolution_deg)
            .field("elevation_resolution_deg", &self.elevation_resolution_deg)
            .field("range_noise_m", &self.range_noise_m)
            .field("azimuth_noise_deg", &self.azimuth_noise_deg)
            .field("elevation_noise_deg", &self.elevation_noise_deg)
            .field("velocity_noise_mps", &self.velocity_noise_mps)
            .field("rcs_noise_db", &self.rcs_noise_db)
            .field("snr_at_max_range_db", &self.snr_at_max_range_db)
            .field("detection_threshold_db", &self.detection_threshold_db)
            .field("clutter_probability", &self.clutter_probability)
            .field("ground_clutter_probability", &self.ground_clutter_probability)
            .field("static_rcs_dbsm", &self.static_rcs_dbsm)
            .field("max_points", &self.max_points)
            .field("max_detections_per_target", &self.max_detections_per_target)
            .field("rcs_dbsm", &self.rcs_dbsm)
            .field("price_usd", &self.price_usd)
            .field("price_source", &self.price_source);
        if self.carrier_ghz != carrier_77() {
            d.field("carrier_ghz", &self.carrier_ghz);
        }
        if self.path_loss_db_per_m != 0.0 {
            d.field("path_loss_db_per_m", &self.path_loss_db_per_m);
        }
        if !self.azimuth_table.is_empty() {
            d.field("azimuth_table", &self.azimuth_table);
        }
        if !self.effects.is_ideal() {
            d.field("effects", &self.effects);
        }
        d.finish()
    }
}

/// Mean radar cross-section per class, dBsm.
#[derive(Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RcsTable {
    pub car: f32,
    pub truck: f32,
    pub bus: f32,
    pub motorcycle: f32,
    pub pedestrian: f32,
    pub golf_cart: f32,
    /// A bicycle with its rider; absent: [`RcsTable::BICYCLE_DBSM`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bicycle: Option<f32>,
}

/// As derived, but without `bicycle` when a table leaves it out: a catalog's `Debug` is part of
/// a study folder's fingerprint, and catalogs written before cyclists existed keep theirs.
impl std::fmt::Debug for RcsTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("RcsTable");
        d.field("car", &self.car)
            .field("truck", &self.truck)
            .field("bus", &self.bus)
            .field("motorcycle", &self.motorcycle)
            .field("pedestrian", &self.pedestrian)
            .field("golf_cart", &self.golf_cart);
        if let Some(b) = &self.bicycle {
            d.field("bicycle", b);
        }
        d.finish()
    }
}

impl RcsTable {
    /// A cyclist's mean RCS where a table leaves it out: −3 dBsm, between the pedestrian's
    /// −8 and the motorcycle's +5 of the shipped tables (a rider on a metal frame). An
    /// assumption, not a measurement; a table's `bicycle` replaces it.
    pub const BICYCLE_DBSM: f32 = -3.0;

    pub fn get(&self, class: Class) -> f32 {
        match class {
            Class::Car => self.car,
            Class::Truck => self.truck,
            Class::Bus => self.bus,
            Class::Motorcycle => self.motorcycle,
            Class::Pedestrian => self.pedestrian,
            Class::GolfCart => self.golf_cart,
            Class::Bicycle => self.bicycle.unwrap_or(Self::BICYCLE_DBSM),
        }
    }
}

/// Any catalog entry.
#[derive(Clone, Debug, PartialEq)]
pub enum SensorSpec {
    Lidar(LidarSpec),
    Radar(RadarSpec),
}

impl SensorSpec {
    pub fn name(&self) -> &str {
        match self {
            SensorSpec::Lidar(l) => &l.name,
            SensorSpec::Radar(r) => &r.name,
        }
    }

    pub fn price_usd(&self) -> f64 {
        match self {
            SensorSpec::Lidar(l) => l.price_usd,
            SensorSpec::Radar(r) => r.price_usd,
        }
    }
}

impl RadarSpec {
    /// Azimuth resolution, accuracy and cells, by the table when there is one.
    pub fn azimuth(&self) -> Azimuth<'_> {
        Azimuth::new(&self.azimuth_table, self.hfov_deg, self.azimuth_resolution_deg, self.azimuth_noise_deg)
    }
}

impl LidarSpec {
    /// Beam elevations in radians, sorted ascending: index = ring.
    pub fn elevations_rad(&self) -> Vec<f32> {
        let mut e: Vec<f32> = match &self.elevations_deg {
            Some(t) => t.clone(),
            None if self.beams == 1 => vec![0.0],
            None => (0..self.beams)
                .map(|b| -0.5 * self.vfov_deg + self.vfov_deg * b as f32 / (self.beams - 1) as f32)
                .collect(),
        };
        e.sort_by(f32::total_cmp);
        e.into_iter().map(f32::to_radians).collect()
    }

    /// Azimuth columns per revolution (or per `hfov_deg` sweep).
    pub fn columns(&self) -> u32 {
        (self.hfov_deg / self.azimuth_resolution_deg).round().max(1.0) as u32
    }

    /// Rays fired per frame.
    pub fn rays_per_frame(&self) -> usize {
        self.beams as usize * self.columns() as usize
    }

    /// Whether a return from a surface of `reflectivity`, hit at `cos_incidence`, at `range_m`
    /// is strong enough to be detected ([`LidarSpec::detection_range`]); always, without one.
    /// The range gate (`min_range_m`, `max_range_m`) is the caller's.
    pub fn detects(&self, reflectivity: f32, cos_incidence: f32, range_m: f32) -> bool {
        let Some(d) = self.detection_range else { return true };
        let received = reflectivity * cos_incidence.abs() * (-2.0 * self.extinction_per_m * range_m).exp();
        received * d.range_m * d.range_m >= d.reflectivity * range_m * range_m
    }

    /// [`Self::detects`] for a received power already summed, ρ·|cos|·e^{−2αr}/r² over the
    /// parts of a beam's footprint (each weighted by its share of the pulse): at least the
    /// reference target's ρ_ref/R_ref². True without a detection range.
    pub fn detects_power(&self, power: f32) -> bool {
        let Some(d) = self.detection_range else { return true };
        power * d.range_m * d.range_m >= d.reflectivity
    }

    /// The farthest a surface of `reflectivity` at normal incidence is detected: `max_range_m`
    /// without a detection range, else the root of ρ·e^{−2αr}/r² = ρ_ref/R_ref² (at most
    /// `max_range_m`): R_ref·√(ρ/ρ_ref) in clear air, W(α·that)/α through extinction α.
    pub fn reach_m(&self, reflectivity: f32) -> f32 {
        let Some(d) = self.detection_range else { return self.max_range_m };
        let clear = d.range_m * (reflectivity.max(0.0) / d.reflectivity).sqrt();
        crate::range::max_range_m(clear, self.extinction_per_m).min(self.max_range_m)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CatalogFile {
    #[serde(default)]
    lidar: Vec<LidarSpec>,
    #[serde(default)]
    radar: Vec<RadarSpec>,
}

/// Validated sensor specifications, looked up by name.
#[derive(Clone, Debug, PartialEq)]
pub struct Catalog {
    sensors: Vec<SensorSpec>,
    source: PathBuf,
}

/// The highest frame rate a catalog may give: spinning LiDARs run at 5–20 Hz, imaging radars
/// up to ~30 Hz; a rate far above makes a dataset of absurd size.
pub const MAX_RATE_HZ: f32 = 100.0;

/// The finest angular (degrees) or range (metres) step a catalog may give.
pub const MIN_STEP: f32 = 0.01;

/// The widest beam divergence a catalog may give, mrad (roadside LiDARs: 1–5).
pub const MAX_DIVERGENCE_MRAD: f32 = 50.0;

struct Check<'a> {
    path: &'a Path,
    prefix: String,
}

impl Check<'_> {
    fn err(&self, field: &str, value: impl std::fmt::Debug, reason: &str) -> SensorError {
        SensorError::Invalid {
            path: self.path.to_path_buf(),
            field: format!("{}.{field}", self.prefix),
            value: format!("{value:?}"),
            reason: reason.to_owned(),
        }
    }
    fn positive(&self, field: &str, v: f32) -> Result<(), SensorError> {
        if v.is_finite() && v > 0.0 { Ok(()) } else { Err(self.err(field, v, "must be a finite number > 0")) }
    }
    fn non_negative(&self, field: &str, v: f32) -> Result<(), SensorError> {
        if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(self.err(field, v, "must be a finite number >= 0")) }
    }
    fn finite(&self, field: &str, v: f32) -> Result<(), SensorError> {
        if v.is_finite() { Ok(()) } else { Err(self.err(field, v, "must be finite")) }
    }
    fn probability(&self, field: &str, v: f32) -> Result<(), SensorError> {
        if (0.0..=1.0).contains(&v) { Ok(()) } else { Err(self.err(field, v, "must be a probability in [0, 1]")) }
    }
    /// A sensor's name becomes a file name (visibility exports, dataset channels).
    fn name(&self, name: &str) -> Result<(), SensorError> {
        hilo_core::fs::check_file_name(name).map_err(|why| self.err("name", name, why))
    }
    /// Frame rates a real roadside sensor runs at: above 0, at most [`MAX_RATE_HZ`].
    fn rate(&self, v: f32) -> Result<(), SensorError> {
        if v.is_finite() && v > 0.0 && v <= MAX_RATE_HZ {
            Ok(())
        } else {
            Err(self.err("rate_hz", v, &format!("must be a frame rate in (0, {MAX_RATE_HZ}] Hz")))
        }
    }
    /// An angular or range step of at least [`MIN_STEP`]: finer makes billions of rays a frame.
    fn fine_step(&self, field: &str, v: f32) -> Result<(), SensorError> {
        if v >= MIN_STEP { Ok(()) } else { Err(self.err(field, v, &format!("must be at least {MIN_STEP}"))) }
    }
    fn price(&self, v: f64) -> Result<(), SensorError> {
        if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(self.err("price_usd", v, "must be a finite number >= 0")) }
    }
}

fn validate_lidar(l: &LidarSpec, c: &Check) -> Result<(), SensorError> {
    c.name(&l.name)?;
    if l.beams == 0 || l.beams > 512 {
        return Err(c.err("beams", l.beams, "a LiDAR has 1 to 512 beams"));
    }
    c.rate(l.rate_hz)?;
    c.positive("hfov_deg", l.hfov_deg)?;
    if l.hfov_deg > 360.0 {
        return Err(c.err("hfov_deg", l.hfov_deg, "must be at most 360"));
    }
    c.non_negative("vfov_deg", l.vfov_deg)?;
    if l.vfov_deg >= 180.0 {
        return Err(c.err("vfov_deg", l.vfov_deg, "must be below 180"));
    }
    if let Some(t) = &l.elevations_deg {
        if t.len() != l.beams as usize {
            return Err(c.err("elevations_deg", t.len(), &format!("has {} entries, but beams = {}", t.len(), l.beams)));
        }
        if let Some(e) = t.iter().find(|e| !(e.is_finite() && e.abs() < 90.0)) {
            return Err(c.err("elevations_deg", e, "every elevation must be finite and within (-90, 90)"));
        }
    }
    c.positive("azimuth_resolution_deg", l.azimuth_resolution_deg)?;
    c.fine_step("azimuth_resolution_deg", l.azimuth_resolution_deg)?;
    c.non_negative("min_range_m", l.min_range_m)?;
    c.positive("max_range_m", l.max_range_m)?;
    if l.min_range_m >= l.max_range_m {
        return Err(c.err("min_range_m", l.min_range_m, "must be below max_range_m"));
    }
    c.non_negative("range_noise_m", l.range_noise_m)?;
    c.non_negative("atmosphere_attenuation_per_m", l.atmosphere_attenuation_per_m)?;
    c.probability("dropoff_general_rate", l.dropoff_general_rate)?;
    c.non_negative("dropoff_intensity_limit", l.dropoff_intensity_limit)?;
    c.probability("dropoff_zero_intensity", l.dropoff_zero_intensity)?;
    if let Some(d) = &l.detection_range {
        c.positive("detection_range.range_m", d.range_m)?;
        if !(d.reflectivity.is_finite() && d.reflectivity > 0.0 && d.reflectivity <= 1.0) {
            return Err(c.err("detection_range.reflectivity", d.reflectivity, "must be a reflectivity in (0, 1]"));
        }
    }
    c.non_negative("extinction_per_m", l.extinction_per_m)?;
    if let Some(b) = &l.beam {
        validate_beam(l, b, c)?;
    }
    c.price(l.price_usd)
}

/// A beam a real LiDAR has: divergence of at most [`MAX_DIVERGENCE_MRAD`] each way, a
/// separation of echoes above 0, 1 to 3 rings of sub-rays, and a detection range to decide
/// which partial hits are seen.
fn validate_beam(l: &LidarSpec, b: &Beam, c: &Check) -> Result<(), SensorError> {
    for (field, v) in [("beam.horizontal_mrad", b.horizontal_mrad), ("beam.vertical_mrad", b.vertical_mrad)] {
        c.positive(field, v)?;
        if v > MAX_DIVERGENCE_MRAD {
            return Err(c.err(
                field,
                v,
                &format!("must be at most {MAX_DIVERGENCE_MRAD} mrad (a LiDAR's beam, not a floodlight)"),
            ));
        }
    }
    c.positive("beam.separation_m", b.separation_m)?;
    if !(1..=3).contains(&b.rings) {
        return Err(c.err("beam.rings", b.rings, "must be 1, 2 or 3 (7, 19 or 37 sub-rays)"));
    }
    if l.detection_range.is_none() {
        return Err(c.err(
            "beam",
            "set",
            "needs a detection_range: the lidar equation decides which partial hits of the footprint are seen",
        ));
    }
    Ok(())
}

fn validate_radar(r: &RadarSpec, c: &Check) -> Result<(), SensorError> {
    c.name(&r.name)?;
    c.rate(r.rate_hz)?;
    c.positive("hfov_deg", r.hfov_deg)?;
    if r.hfov_deg >= 180.0 {
        return Err(c.err("hfov_deg", r.hfov_deg, "must be below 180 (a radar looks forward)"));
    }
    c.positive("vfov_deg", r.vfov_deg)?;
    if r.vfov_deg >= 180.0 {
        return Err(c.err("vfov_deg", r.vfov_deg, "must be below 180"));
    }
    c.non_negative("min_range_m", r.min_range_m)?;
    c.positive("max_range_m", r.max_range_m)?;
    if r.min_range_m >= r.max_range_m {
        return Err(c.err("min_range_m", r.min_range_m, "must be below max_range_m"));
    }
    for (f, v) in [
        ("ray_azimuth_step_deg", r.ray_azimuth_step_deg),
        ("ray_elevation_step_deg", r.ray_elevation_step_deg),
        ("range_resolution_m", r.range_resolution_m),
        ("azimuth_resolution_deg", r.azimuth_resolution_deg),
        ("elevation_resolution_deg", r.elevation_resolution_deg),
    ] {
        c.positive(f, v)?;
        c.fine_step(f, v)?;
    }
    for (f, v) in [
        ("range_noise_m", r.range_noise_m),
        ("azimuth_noise_deg", r.azimuth_noise_deg),
        ("elevation_noise_deg", r.elevation_noise_deg),
        ("velocity_noise_mps", r.velocity_noise_mps),
        ("rcs_noise_db", r.rcs_noise_db),
    ] {
        c.non_negative(f, v)?;
    }
    c.finite("snr_at_max_range_db", r.snr_at_max_range_db)?;
    c.finite("detection_threshold_db", r.detection_threshold_db)?;
    c.probability("clutter_probability", r.clutter_probability)?;
    c.probability("ground_clutter_probability", r.ground_clutter_probability)?;
    c.finite("static_rcs_dbsm", r.static_rcs_dbsm)?;
    for class in Class::ALL {
        c.finite(&format!("rcs_dbsm.{class}"), r.rcs_dbsm.get(class))?;
    }
    if r.max_detections_per_target == 0 {
        return Err(c.err("max_detections_per_target", r.max_detections_per_target, "must be at least 1"));
    }
    if r.max_points == 0 {
        return Err(c.err("max_points", r.max_points, "must be at least 1"));
    }
    if !(r.carrier_ghz.is_finite() && (1.0..=1000.0).contains(&r.carrier_ghz)) {
        return Err(c.err("carrier_ghz", r.carrier_ghz, "must be 1 to 1,000 GHz (the rain model's range)"));
    }
    c.non_negative("path_loss_db_per_m", r.path_loss_db_per_m)?;
    validate_azimuth_table(r, c)?;
    validate_effects(&r.effects, c)?;
    c.price(r.price_usd)
}

fn validate_azimuth_table(r: &RadarSpec, c: &Check) -> Result<(), SensorError> {
    let t = &r.azimuth_table;
    if t.is_empty() {
        return Ok(());
    }
    if t[0].off_boresight_deg != 0.0 {
        return Err(c.err(
            "azimuth_table[0].off_boresight_deg",
            t[0].off_boresight_deg,
            "the table starts at boresight (0)",
        ));
    }
    for (i, row) in t.iter().enumerate() {
        c.positive(&format!("azimuth_table[{i}].resolution_deg"), row.resolution_deg)?;
        c.fine_step(&format!("azimuth_table[{i}].resolution_deg"), row.resolution_deg)?;
        c.non_negative(&format!("azimuth_table[{i}].accuracy_deg"), row.accuracy_deg)?;
        c.non_negative(&format!("azimuth_table[{i}].off_boresight_deg"), row.off_boresight_deg)?;
        if i > 0 && row.off_boresight_deg <= t[i - 1].off_boresight_deg {
            return Err(c.err(
                &format!("azimuth_table[{i}].off_boresight_deg"),
                row.off_boresight_deg,
                "rows must go outward from boresight, each angle above the last",
            ));
        }
    }
    let edge = t[t.len() - 1].off_boresight_deg;
    if edge < 0.5 * r.hfov_deg {
        return Err(c.err(
            &format!("azimuth_table[{}].off_boresight_deg", t.len() - 1),
            edge,
            &format!("the table must reach the field's edge, {} deg", 0.5 * r.hfov_deg),
        ));
    }
    Ok(())
}

fn validate_effects(e: &RadarEffects, c: &Check) -> Result<(), SensorError> {
    if let Some(v) = e.doppler_resolution_mps {
        c.positive("effects.doppler_resolution_mps", v)?;
    }
    for (f, v) in [
        ("effects.wall_multipath_loss_db", e.wall_multipath_loss_db),
        ("effects.ground_multipath_loss_db", e.ground_multipath_loss_db),
        ("effects.side_lobe_level_db", e.side_lobe_level_db),
    ] {
        if let Some(v) = v {
            c.non_negative(f, v)?;
        }
    }
    c.non_negative("effects.false_alarms_per_frame", e.false_alarms_per_frame)?;
    if e.false_alarms_per_frame > 10_000.0 {
        return Err(c.err("effects.false_alarms_per_frame", e.false_alarms_per_frame, "must be at most 10,000"));
    }
    c.non_negative("effects.false_alarm_speed_mps", e.false_alarm_speed_mps)?;
    c.non_negative("effects.vegetation_doppler_mps", e.vegetation_doppler_mps)?;
    c.finite("effects.rcs_aspect_db", e.rcs_aspect_db)
}

impl Catalog {
    /// Parses and validates a catalog; `path` names the file in errors.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self, SensorError> {
        let file: CatalogFile = toml::from_str(text)
            .map_err(|e| SensorError::from(hilo_core::fs::FileError::content(path, e.to_string())))?;
        let mut sensors = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for (i, l) in file.lidar.into_iter().enumerate() {
            let c = Check { path, prefix: format!("lidar[{i}]") };
            validate_lidar(&l, &c)?;
            if !seen.insert(l.name.clone()) {
                return Err(c.err("name", &l.name, "duplicate sensor name"));
            }
            sensors.push(SensorSpec::Lidar(l));
        }
        for (i, r) in file.radar.into_iter().enumerate() {
            let c = Check { path, prefix: format!("radar[{i}]") };
            validate_radar(&r, &c)?;
            if !seen.insert(r.name.clone()) {
                return Err(c.err("name", &r.name, "duplicate sensor name"));
            }
            sensors.push(SensorSpec::Radar(r));
        }
        Ok(Catalog { sensors, source: path.to_path_buf() })
    }

    pub fn load(path: &Path) -> Result<Self, SensorError> {
        let text = hilo_core::fs::read_text_bounded(path, hilo_core::fs::limit::CONFIG)
            .map_err(|e| SensorError::from(hilo_core::fs::FileError::io(path, e)))?;
        Self::from_toml_str(&text, path)
    }

    /// The embedded default catalog (the paper's Table I).
    pub fn default_catalog() -> Result<Self, SensorError> {
        Self::from_toml_str(DEFAULT_CATALOG_TOML, Path::new("<embedded>/fixtures/sensors.toml"))
    }

    /// The embedded catalog of that file name ([`EMBEDDED_CATALOGS`]), None for any other name.
    pub fn embedded(name: &str) -> Option<Result<Self, SensorError>> {
        let (name, text) = EMBEDDED_CATALOGS.iter().find(|(n, _)| *n == name)?;
        Some(Self::from_toml_str(text, &Path::new("<embedded>/fixtures").join(name)))
    }

    pub fn sensors(&self) -> &[SensorSpec] {
        &self.sensors
    }

    pub fn names(&self) -> Vec<&str> {
        self.sensors.iter().map(SensorSpec::name).collect()
    }

    /// Looks a sensor up by name; an unknown name lists the known ones.
    pub fn get(&self, name: &str) -> Result<&SensorSpec, SensorError> {
        self.sensors.iter().find(|s| s.name() == name).ok_or_else(|| SensorError::UnknownSensor {
            name: name.to_owned(),
            catalog: self.source.clone(),
            known: self.names().join(", "),
        })
    }

    pub fn lidar(&self, name: &str) -> Result<&LidarSpec, SensorError> {
        match self.get(name)? {
            SensorSpec::Lidar(l) => Ok(l),
            SensorSpec::Radar(_) => Err(SensorError::WrongKind { name: name.to_owned(), expected: "LiDAR" }),
        }
    }

    pub fn radar(&self, name: &str) -> Result<&RadarSpec, SensorError> {
        match self.get(name)? {
            SensorSpec::Radar(r) => Ok(r),
            SensorSpec::Lidar(_) => Err(SensorError::WrongKind { name: name.to_owned(), expected: "radar" }),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn default_catalog_is_table_one_with_the_papers_cost_ratios() {
        let c = Catalog::default_catalog().unwrap();
        let (l16, l32, l64, r) = (
            c.lidar("lidar-16").unwrap(),
            c.lidar("lidar-32").unwrap(),
            c.lidar("lidar-64").unwrap(),
            c.radar("radar-4d").unwrap(),
        );
        assert_eq!((l16.beams, l32.beams, l64.beams), (16, 32, 64));
        assert_eq!((l16.max_range_m, l64.max_range_m, r.max_range_m), (100.0, 90.0, 90.0));
        assert_eq!((r.hfov_deg, r.vfov_deg, r.rate_hz), (120.0, 28.0, 20.0));
        let cheap = 2.0 * l16.price_usd + r.price_usd;
        // −26.7% against 32-beam + radar, −56% against 64-beam + radar.
        assert!((1.0 - cheap / (l32.price_usd + r.price_usd) - 0.267).abs() < 0.001);
        assert!((1.0 - cheap / (l64.price_usd + r.price_usd) - 0.56).abs() < 0.001);
        // The 16-beam table: -15..15 every 2 degrees.
        let e = l16.elevations_rad();
        assert_eq!(e.len(), 16);
        assert!((e[0].to_degrees() + 15.0).abs() < 1e-4 && (e[15].to_degrees() - 15.0).abs() < 1e-4);
        assert_eq!(l64.elevations_rad().len(), 64);
    }
}
