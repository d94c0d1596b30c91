//! A LiDAR beam of finite width: its footprint sampled by sub-rays, the echoes the sub-rays'
//! hits form, and the echoes a return mode reports ([`crate::spec::Beam`]).
//!
//! The spot is an elliptical Gaussian, irradiance ∝ exp(−2ρ²) with ρ = 1 on the 1/e² contour
//! (half-angles `horizontal_mrad / 2` across the scan and `vertical_mrad / 2` along it). The
//! sub-rays sit on a hexagonal lattice of spacing 1/rings inside that contour (the 86.5% of the
//! power the contour holds, renormalised), each weighted by the irradiance at its point: the
//! fraction of the pulse a surface intercepts is the summed weight of the sub-rays it stops.
//! `tests/lidar_beam.rs` holds that fraction to a dense quadrature of the Gaussian over thin
//! poles and edges.
//!
//! An echo's received power adds its sub-rays' w·ρ·|cos incidence|·e^{−2αr}/r², the lidar
//! equation's form ([`crate::spec::LidarSpec::detects`]) for a surface that fills only part of
//! the beam; its range is the power-weighted mean of theirs (a pulse detector finds one peak
//! for returns closer than a pulse length apart); its source is the sub-ray that gives most
//! power. Left out: the pulse's shape in time (two echoes just over `separation_m` apart are
//! split cleanly, just under it merge fully), and the receiver's own field of view (taken
//! equal to the beam).

use crate::lidar::PointSource;
use crate::spec::{Beam, ReturnMode};
use glam::Vec3;

/// More sub-rays than any footprint has (3 rings: 37): a sub-ray's index within its ray's
/// block of random streams.
pub const MAX_SUB_RAYS: usize = 64;

/// One sub-ray of the footprint: its offsets from the beam's axis, rad (across the scan,
/// along it), and its share of the pulse's power (the shares add to 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub across_rad: f32,
    pub along_rad: f32,
    pub weight: f32,
}

/// The sub-rays that sample one beam's footprint, the axis first, and the beam they sample
/// (its echoes' separation and return mode).
#[derive(Clone, Debug, PartialEq)]
pub struct Footprint {
    pub beam: Beam,
    pub samples: Vec<Sample>,
}

impl Footprint {
    /// The footprint of `beam`: 1 + 3·rings·(rings + 1) sub-rays.
    pub fn new(beam: &Beam) -> Footprint {
        let n = beam.rings.max(1) as i32;
        let spacing = 1.0 / n as f32;
        let mut points = Vec::new();
        for a in -2 * n..=2 * n {
            for b in -2 * n..=2 * n {
                // The lattice a·(1, 0) + b·(1/2, √3/2), scaled by the spacing.
                let x = spacing * (a as f32 + 0.5 * b as f32);
                let y = spacing * (b as f32 * 0.75f32.sqrt());
                if x * x + y * y <= 1.0 + 1e-4 {
                    points.push((x, y));
                }
            }
        }
        // The axis first, then outwards; ties in a fixed order.
        points.sort_by(|p, q| {
            (p.0.hypot(p.1), p.1, p.0).partial_cmp(&(q.0.hypot(q.1), q.1, q.0)).unwrap_or(std::cmp::Ordering::Equal)
        });
        let total: f32 = points.iter().map(|(x, y)| (-2.0 * (x * x + y * y)).exp()).sum();
        let (half_across, half_along) = (0.5e-3 * beam.horizontal_mrad, 0.5e-3 * beam.vertical_mrad);
        let samples = points
            .iter()
            .map(|&(x, y)| Sample {
                across_rad: x * half_across,
                along_rad: y * half_along,
                weight: (-2.0 * (x * x + y * y)).exp() / total,
            })
            .collect();
        Footprint { beam: *beam, samples }
    }

    /// The widest angle of a sub-ray from the axis, rad.
    pub fn spread_rad(&self) -> f32 {
        self.samples.iter().map(|s| s.across_rad.hypot(s.along_rad)).fold(0.0, f32::max)
    }

    /// The direction of each sub-ray about the unit axis `axis` = (cos e cos a, cos e sin a,
    /// sin e): offset across the scan along the azimuth's tangent and along it on the
    /// elevation's.
    pub fn directions(&self, azimuth: f32, elevation: f32, axis: Vec3) -> impl Iterator<Item = (Vec3, &Sample)> {
        let (sa, ca) = azimuth.sin_cos();
        let se = elevation.sin();
        let across = Vec3::new(-sa, ca, 0.0);
        let along = Vec3::new(-se * ca, -se * sa, elevation.cos());
        self.samples
            .iter()
            .map(move |s| ((axis + across * s.across_rad.tan() + along * s.along_rad.tan()).normalize(), s))
    }
}

/// What one sub-ray met: its range, the reflectance it carries (w·ρ·|cos incidence|), the power
/// received from it (that over r², through the air's extinction), and what it hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SubHit {
    pub range_m: f32,
    pub reflectance: f32,
    pub power: f32,
    pub source: PointSource,
}

/// One echo of a pulse: sub-ray hits within the separation of each other along the beam.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Echo {
    /// Power-weighted mean range of its sub-rays, m.
    pub range_m: f32,
    /// Σ w·ρ·|cos incidence|: the reflectance of a surface filling the beam times the share of
    /// the beam it fills (the intensity's ρ·|cos|).
    pub reflectance: f32,
    /// Σ w·ρ·|cos incidence|·e^{−2αr}/r².
    pub power: f32,
    pub source: PointSource,
}

/// The echoes of `hits`: sorted by range, a new echo wherever the gap to the previous hit
/// exceeds `separation_m`.
pub fn echoes(hits: &mut [SubHit], separation_m: f32) -> Vec<Echo> {
    hits.sort_by(|a, b| a.range_m.total_cmp(&b.range_m));
    let mut out: Vec<Echo> = Vec::new();
    let mut start = 0;
    for i in 1..=hits.len() {
        if i < hits.len() && hits[i].range_m - hits[i - 1].range_m <= separation_m {
            continue;
        }
        let group = &hits[start..i];
        let power: f32 = group.iter().map(|h| h.power).sum();
        let reflectance: f32 = group.iter().map(|h| h.reflectance).sum();
        let range_m = if power > 0.0 {
            group.iter().map(|h| h.power * h.range_m).sum::<f32>() / power
        } else {
            group.iter().map(|h| h.range_m).sum::<f32>() / group.len() as f32
        };
        let source = group.iter().max_by(|a, b| a.power.total_cmp(&b.power)).map_or(PointSource::Ground, |h| h.source);
        out.push(Echo { range_m, reflectance, power, source });
        start = i;
    }
    out
}

/// The echoes `mode` reports among the `seen` ones of `all` (in range order), nearest first: at
/// most two.
pub fn reported(all: &[Echo], mode: ReturnMode, seen: impl Fn(&Echo) -> bool) -> Vec<Echo> {
    let seen: Vec<Echo> = all.iter().copied().filter(|e| seen(e)).collect();
    let strongest = |skip: Option<usize>| {
        (0..seen.len())
            .filter(|&i| Some(i) != skip)
            .max_by(|&a, &b| seen[a].power.total_cmp(&seen[b].power).then(b.cmp(&a)))
    };
    let Some(s) = strongest(None) else { return Vec::new() };
    let last = seen.len() - 1;
    let mut picked = match mode {
        ReturnMode::Strongest => vec![s],
        ReturnMode::Last => vec![last],
        ReturnMode::Dual if s != last => vec![s, last],
        ReturnMode::Dual => std::iter::once(s).chain(strongest(Some(s))).collect(),
    };
    picked.sort_unstable();
    picked.into_iter().map(|i| seen[i]).collect()
}
