//! What a field engineer sees in a real imaging radar's detections that the ideal model of
//! [`crate::radar`] leaves out, each a catalog setting that is off when absent:
//!
//! - **Azimuth by angle** (`[[radar.azimuth_table]]`): a digitally beam-formed array's beam
//!   widens as 1/cos of the angle off boresight, so resolution and accuracy worsen toward the
//!   edge of the field (an ARS548-class radar: 1.2° at boresight, 1.68° at ±45°).
//!   Resolution cells follow the table ([`Azimuth::cell`]).
//! - **Unresolved targets** (`doppler_resolution_mps`): detections of different targets (or a
//!   target and clutter) closer than one resolution in range, azimuth, elevation and radial
//!   velocity at once are one detection: powers add, position and velocity are the
//!   power-weighted means. Absent, two targets are always reported apart.
//! - **Multipath ghosts** (`wall_multipath_loss_db`, `ground_multipath_loss_db`): a ray that
//!   meets a smooth static surface (anything but vegetation and grass) is reflected
//!   specularly; if the reflection meets a road user, the radar sees that road user along the
//!   first ray at the whole path's length, which is its mirror image in the surface, with the
//!   Doppler of its velocity along the reflected ray and the stated loss.
//! - **Side lobes** (`side_lobe_level_db`): a detection strong enough gives two more at the
//!   array's first side lobes, ±1.6 resolutions in azimuth (where a uniform aperture's first
//!   side lobe sits, 1.43 λ/D against a 0.886 λ/D beam), the stated level weaker.
//! - **False alarms** (`false_alarms_per_frame`): noise crossings of the detection threshold,
//!   Poisson per frame, uniform over range, azimuth and elevation cells and over ±
//!   `false_alarm_speed_mps`; their power is the threshold plus an exponential excess (noise
//!   power conditioned on crossing it).
//! - **Vegetation Doppler** (`vegetation_doppler_mps`): wind-blown foliage gives clutter with a
//!   Gaussian spread of radial velocity instead of exactly zero, so a Doppler filter no longer
//!   removes it for free.
//! - **RCS by aspect** (`rcs_aspect_db`): a vehicle's cross-section is larger broadside than
//!   head-on: the class's mean RCS (dB) plus a·(−cos 2φ), φ the angle between the line of sight
//!   and the vehicle's heading; its mean over all aspects is the class mean. Pedestrians
//!   (capsules) have no aspect.

use glam::{Vec2, Vec3};
use hilo_raycast::{Actor, ActorShape};
use serde::{Deserialize, Serialize};

/// One row of an azimuth table: resolution and accuracy (1σ) at an angle off boresight.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AzimuthRow {
    pub off_boresight_deg: f32,
    pub resolution_deg: f32,
    pub accuracy_deg: f32,
}

/// The effects of a real radar beyond the ideal model; every one is off by default.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RadarEffects {
    /// Doppler resolution: when set, detections of different targets within one resolution
    /// in range, azimuth, elevation and radial velocity merge.
    pub doppler_resolution_mps: Option<f32>,
    /// Loss of a ghost seen over a wall (a static surface that is not horizontal), dB.
    pub wall_multipath_loss_db: Option<f32>,
    /// Loss of a ghost seen over the road (a horizontal surface), dB.
    pub ground_multipath_loss_db: Option<f32>,
    /// How far below its main lobe a detection's first side lobes lie, dB.
    pub side_lobe_level_db: Option<f32>,
    /// Mean number of false alarms per frame (Poisson).
    pub false_alarms_per_frame: f32,
    /// False alarms' radial velocity is uniform in ± this, m/s.
    pub false_alarm_speed_mps: f32,
    /// Standard deviation of the radial velocity of vegetation clutter, m/s.
    pub vegetation_doppler_mps: f32,
    /// Half the broadside-to-head-on swing of a vehicle's RCS, dB.
    pub rcs_aspect_db: f32,
}

impl RadarEffects {
    /// No effect is on.
    pub fn is_ideal(&self) -> bool {
        *self == Self::default()
    }
}

/// Where a uniform aperture's first side lobe sits, in resolutions (3 dB beam widths) off the
/// main lobe: 1.43 λ/D against a 0.886 λ/D beam.
pub const SIDE_LOBE_OFFSET: f32 = 1.43 / 0.886;

/// Azimuth resolution, accuracy and resolution cells of a radar, uniform or by table.
#[derive(Clone, Debug)]
pub struct Azimuth<'a> {
    table: &'a [AzimuthRow],
    half_fov: f32,
    uniform_resolution: f32,
    uniform_accuracy: f32,
    /// Added to the table's cell coordinate so that every cell index in the field is positive.
    offset: f32,
}

impl<'a> Azimuth<'a> {
    /// A radar's azimuth: by `table` when it has rows, else `resolution_deg` and
    /// `accuracy_deg` over the whole field of `hfov_deg` ([`crate::spec::RadarSpec::azimuth`]).
    pub fn new(table: &'a [AzimuthRow], hfov_deg: f32, resolution_deg: f32, accuracy_deg: f32) -> Self {
        let half_fov = 0.5 * hfov_deg.to_radians();
        let mut a = Azimuth {
            table,
            half_fov,
            uniform_resolution: resolution_deg.to_radians(),
            uniform_accuracy: accuracy_deg.to_radians(),
            offset: 0.0,
        };
        if !a.table.is_empty() {
            a.offset = a.coordinate(half_fov).ceil() + 1.0;
        }
        a
    }

    /// The table's value of `column` at `az` (radians), linear between rows, constant past the
    /// last; degrees.
    fn interpolate(&self, az: f32, column: impl Fn(&AzimuthRow) -> f32) -> f32 {
        let x = az.abs().to_degrees();
        let t = self.table;
        let i = t.partition_point(|r| r.off_boresight_deg <= x);
        if i == 0 {
            return column(&t[0]);
        }
        if i == t.len() {
            return column(&t[i - 1]);
        }
        let (a, b) = (&t[i - 1], &t[i]);
        let f = (x - a.off_boresight_deg) / (b.off_boresight_deg - a.off_boresight_deg);
        column(a) + f * (column(b) - column(a))
    }

    /// Resolution at azimuth `az`, radians.
    pub fn resolution(&self, az: f32) -> f32 {
        if self.table.is_empty() {
            self.uniform_resolution
        } else {
            self.interpolate(az, |r| r.resolution_deg).to_radians()
        }
    }

    /// Accuracy (1σ of the measured azimuth) at `az`, radians.
    pub fn accuracy(&self, az: f32) -> f32 {
        if self.table.is_empty() {
            self.uniform_accuracy
        } else {
            self.interpolate(az, |r| r.accuracy_deg).to_radians()
        }
    }

    /// Cells between boresight and `az` (signed): ∫ dθ / resolution(θ), in closed form over
    /// the table's linear pieces (the table starts at boresight; validated).
    pub fn coordinate(&self, az: f32) -> f32 {
        if self.table.is_empty() {
            return az / self.uniform_resolution;
        }
        let x = az.abs().to_degrees();
        let t = self.table;
        let mut u = 0.0;
        for w in t.windows(2) {
            let (a, b) = (&w[0], &w[1]);
            if x <= a.off_boresight_deg {
                break;
            }
            let len = x.min(b.off_boresight_deg) - a.off_boresight_deg;
            let slope = (b.resolution_deg - a.resolution_deg) / (b.off_boresight_deg - a.off_boresight_deg);
            u += if slope.abs() < 1e-9 {
                len / a.resolution_deg
            } else {
                (1.0 + slope * len / a.resolution_deg).ln() / slope
            };
        }
        let last = t[t.len() - 1];
        if x > last.off_boresight_deg {
            u += (x - last.off_boresight_deg) / last.resolution_deg;
        }
        u.copysign(az)
    }

    /// The resolution cell of azimuth `az` (radians, within the field). Uniform: cells of the
    /// resolution from the field's edge. By table: cells of the local resolution, one of them
    /// centred on boresight.
    pub fn cell(&self, az: f32) -> u32 {
        if self.table.is_empty() {
            ((az + self.half_fov) / self.uniform_resolution) as u32
        } else {
            (self.coordinate(az) + 0.5 + self.offset).floor().max(0.0) as u32
        }
    }
}

/// The aspect term of a road user's RCS, dB: −a·cos 2φ for a vehicle (a box) or a cyclist seen
/// from `sensor`, φ the angle between the line of sight and its heading; 0 for a pedestrian.
pub fn aspect_db(effects: &RadarEffects, actor: &Actor, sensor: Vec3) -> f32 {
    if effects.rcs_aspect_db == 0.0 {
        return 0.0;
    }
    match &actor.shape {
        ActorShape::Box(b) | ActorShape::Cyclist(b) => {
            let los = (b.center - sensor).truncate().normalize_or_zero();
            let heading = Vec2::new(b.yaw.cos(), b.yaw.sin());
            let c = los.dot(heading);
            -effects.rcs_aspect_db * (2.0 * c * c - 1.0)
        }
        ActorShape::Capsule(_) => 0.0,
    }
}
