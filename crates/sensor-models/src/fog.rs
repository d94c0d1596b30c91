//! Fog's own echo: the pulse's backscatter from the droplets in front of the sensor.
//!
//! The model is the soft-target channel of Hahner et al. (ICCV 2021, "Fog Simulation on Real
//! LiDAR Point Clouds"), put in the units of hilo's lidar equation, where a Lambertian surface
//! of reflectivity ρ filling the beam at range r returns ρ·|cos|·e^{−2αr}/r²:
//!
//! - the pulse is P₀·sin²(πt / 2τ_H) for 0 ≤ t ≤ 2τ_H (τ_H its half-power width), so it is
//!   `L = c·τ_H` long in range; along the range coordinate R = ct/2 its shape is
//!   w(u) = sin²(πu / L) for 0 ≤ u ≤ L;
//! - fog at range r backscatters β per metre and steradian; a Lambertian surface returns ρ/π per
//!   steradian, so a slab dr of fog is a surface of reflectivity π·β·dr;
//! - the transmitter and the receiver's fields of view overlap only beyond the crossover: ξ(r) is
//!   0 up to r₁, rises linearly to 1 at r₂ and stays 1;
//! - the received power at R is then the pulse swept over the fog in front of it:
//!   P(R) = π·β·∫₀^L w(u)·ξ(R−u)·e^{−2α(R−u)}/(R−u)² du. Far from the sensor, where 1/r² barely
//!   changes over a pulse, P(R) → π·β·(L/2)·e^{−2αr}/r² at the pulse's centre r = R − L/2
//!   (w integrates to L/2);
//! - a hard target at R₀ returns ρ·|cos|·e^{−2αR₀}/R₀²·w(R − R₀), peaking at R₀ + L/2, which the
//!   sensor reports as R₀: so a fog echo peaking at R is reported at R − L/2.
//!
//! The fog is homogeneous, so every beam meets the same echo: its peak power and range are
//! computed once per sensor and weather ([`FogEcho::new`]). The peak lies a metre or two past
//! the crossover, where 1/r² is large: in dense fog it outshines most road users, and a sensor
//! reporting its strongest echo loses them to a cloud of points around itself. Whether a beam
//! reports it is the return mode's choice ([`crate::spec::ReturnMode`]); a beam without a hard
//! target reports it too.
//!
//! Constants, all Hahner et al.'s: β = 0.046 / V per m·sr for meteorological optical range V
//! (after Rasshofer et al., 2011), τ_H = 20 ns, crossover from 0.9 m to 1.0 m. The point's range
//! is drawn uniformly over the echo's half-power span: a broad, weak echo triggers the detector
//! anywhere on its crest (Hahner et al. jitter their fog points likewise).
//!
//! Left out: the droplets' randomness within a beam (the echo is the fog's mean), fog that is
//! not homogeneous (patches, a wall of fog), multiple scattering, and the receiver's saturation,
//! gain control and blanking at near range, which real sensors have in varying degree and no
//! datasheet states: this is the harsh end of what fog's echo does.

/// β·V: the backscatter coefficient times the meteorological optical range (Rasshofer et al.,
/// 2011, as Hahner et al. use it), per steradian.
pub const BACKSCATTER_TIMES_VISIBILITY: f64 = 0.046;

/// The pulse's half-power width τ_H, s (Hahner et al.'s 20 ns).
pub const PULSE_HALF_POWER_S: f64 = 20e-9;

/// Where the receiver's field of view starts to overlap the transmitted beam, and where it
/// covers it, m (Hahner et al.'s 0.9 m and 1.0 m).
pub const CROSSOVER_M: (f64, f64) = (0.9, 1.0);

const LIGHT_M_PER_S: f64 = 299_792_458.0;

/// Quadrature intervals over the pulse (Simpson's rule).
const STEPS: usize = 600;

/// The fog's channel for one sensor: extinction α (per metre, one way), backscatter β (per
/// metre and steradian), the pulse's length L = c·τ_H (m) and the crossover.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FogChannel {
    pub alpha_per_m: f64,
    pub beta_per_m_sr: f64,
    pub pulse_m: f64,
    pub crossover_m: (f64, f64),
}

impl FogChannel {
    /// Hahner et al.'s channel for fog of visibility `visibility_m` and extinction `alpha_per_m`
    /// (fog's and any rain's, which attenuates the echo too).
    pub fn hahner(visibility_m: f64, alpha_per_m: f64) -> Self {
        FogChannel {
            alpha_per_m,
            beta_per_m_sr: BACKSCATTER_TIMES_VISIBILITY / visibility_m,
            pulse_m: LIGHT_M_PER_S * PULSE_HALF_POWER_S,
            crossover_m: CROSSOVER_M,
        }
    }

    /// ξ(r): the share of the transmitted beam the receiver sees at range r.
    pub fn crossover(&self, r: f64) -> f64 {
        let (r1, r2) = self.crossover_m;
        if r <= r1 {
            0.0
        } else if r >= r2 {
            1.0
        } else {
            (r - r1) / (r2 - r1)
        }
    }

    /// The pulse's shape along range, w(u) = sin²(πu/L) on [0, L].
    pub fn pulse(&self, u: f64) -> f64 {
        if (0.0..=self.pulse_m).contains(&u) { (std::f64::consts::PI * u / self.pulse_m).sin().powi(2) } else { 0.0 }
    }

    /// The received power at range coordinate R (R = ct/2), in the lidar equation's units:
    /// P(R) = π·β·∫₀^L w(u)·ξ(R−u)·e^{−2α(R−u)}/(R−u)² du, by Simpson's rule over the part of
    /// the pulse that has fog in the receiver's view (R − u > r₁). The integrand is smooth but
    /// for the crossover's two kinks, which the rule's `STEPS` intervals resolve to ~1e-5.
    pub fn power(&self, range_m: f64) -> f64 {
        let hi = self.pulse_m.min(range_m - self.crossover_m.0);
        if hi <= 0.0 {
            return 0.0;
        }
        let f = |u: f64| {
            let r = range_m - u;
            self.pulse(u) * self.crossover(r) * (-2.0 * self.alpha_per_m * r).exp() / (r * r)
        };
        let h = hi / STEPS as f64;
        let mut sum = f(0.0) + f(hi);
        for i in 1..STEPS {
            sum += f(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
        }
        std::f64::consts::PI * self.beta_per_m_sr * sum * h / 3.0
    }

    /// Far from the sensor (R ≫ L): the fog as a surface of reflectivity π·β·L/2 at the pulse's
    /// centre R − L/2, π·β·(L/2)·e^{−2α(R−L/2)}/(R−L/2)²; [`Self::power`] differs from it by
    /// O((L/R)²).
    pub fn far_power(&self, range_m: f64) -> f64 {
        let r = range_m - 0.5 * self.pulse_m;
        std::f64::consts::PI * self.beta_per_m_sr * 0.5 * self.pulse_m * (-2.0 * self.alpha_per_m * r).exp() / (r * r)
    }
}

/// The echo of the fog itself, as a sensor reports it: its peak's received power and range,
/// and the span of reported ranges where it holds at least half its peak.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FogEcho {
    /// Received power at the peak, in the lidar equation's units (ρ·e^{−2αr}/r²).
    pub power: f32,
    /// Reported range of the peak, m (its range coordinate less half the pulse).
    pub range_m: f32,
    /// Reported ranges where the echo holds at least half its peak power, m.
    pub span_m: (f32, f32),
}

impl FogEcho {
    /// The echo of `channel`: the peak of P(R) over a 1 cm grid of R from the crossover to
    /// a pulse past it (beyond, P falls as 1/R²), refined by a parabola through the grid's
    /// best three points.
    pub fn new(channel: &FogChannel) -> FogEcho {
        const STEP_M: f64 = 0.01;
        let start = channel.crossover_m.0;
        let n = ((channel.crossover_m.1 - start + 1.5 * channel.pulse_m) / STEP_M).ceil() as usize;
        let grid: Vec<f64> = (0..=n).map(|i| channel.power(start + i as f64 * STEP_M)).collect();
        let best = (1..n).max_by(|&a, &b| grid[a].total_cmp(&grid[b])).unwrap_or(1);
        let (y0, y1, y2) = (grid[best - 1], grid[best], grid[best + 1]);
        let curvature = y0 - 2.0 * y1 + y2;
        let shift = if curvature < 0.0 { (0.5 * (y0 - y2) / curvature).clamp(-0.5, 0.5) } else { 0.0 };
        let peak_r = start + (best as f64 + shift) * STEP_M;
        let peak = channel.power(peak_r).max(y1);
        let above: Vec<usize> = (0..=n).filter(|&i| grid[i] >= 0.5 * peak).collect();
        let at = |i: usize| start + i as f64 * STEP_M - 0.5 * channel.pulse_m;
        let (lo, hi) = (above.first().map_or(peak_r, |&i| at(i)), above.last().map_or(peak_r, |&i| at(i)));
        FogEcho {
            power: peak as f32,
            range_m: (peak_r - 0.5 * channel.pulse_m) as f32,
            span_m: (lo.max(0.0) as f32, hi.max(0.0) as f32),
        }
    }

    /// The echo's range for a draw `u` uniform on [0, 1): uniform over the half-power span.
    pub fn range_at(&self, u: f32) -> f32 {
        self.span_m.0 + u * (self.span_m.1 - self.span_m.0)
    }

    /// The reflectance of a surface at range `r` that returns the echo's power through
    /// extinction `alpha_per_m`: what the point's intensity is computed from.
    pub fn reflectance_at(&self, r: f32, alpha_per_m: f32) -> f32 {
        self.power * r * r * (2.0 * alpha_per_m * r).exp()
    }
}
