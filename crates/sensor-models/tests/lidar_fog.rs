//! Fog's echo against its sources: Hahner et al.'s soft-target channel against a brute-force
//! sum, its far-field closed form and the tables of their published implementation; the echo's
//! peak against a fine scan; and scans in fog reporting the fog's echo exactly where the lidar
//! equation's closed form says it outshines a wall, at two visibilities, in each return mode.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use glam::Vec3;
use hilo_raycast::World;
use hilo_sensor_models::fog::{FogChannel, FogEcho};
use hilo_sensor_models::range::max_range_m;
use hilo_sensor_models::weather::{Weather, fog_extinction_per_m};
use hilo_sensor_models::{Beam, DetectionRange, LidarSpec, PointSource, ReturnMode, SensorPose, simulate_lidar};

fn channel(visibility_m: f64) -> FogChannel {
    FogChannel::hahner(visibility_m, f64::from(fog_extinction_per_m(visibility_m as f32)))
}

/// P(R) by the midpoint rule over 200,000 slabs of fog, written from the definition: each slab
/// at r is a surface of reflectivity π·β·dr, seen through the crossover and the extinction,
/// weighted by the pulse's sin² at its delay.
fn brute_power(c: &FogChannel, range_m: f64) -> f64 {
    let n = 200_000;
    let du = c.pulse_m / n as f64;
    let (r1, r2) = c.crossover_m;
    (0..n)
        .map(|i| {
            let u = (i as f64 + 0.5) * du;
            let r = range_m - u;
            if r <= r1 {
                return 0.0;
            }
            let xi = ((r - r1) / (r2 - r1)).min(1.0);
            let w = (std::f64::consts::PI * u / c.pulse_m).sin().powi(2);
            std::f64::consts::PI * c.beta_per_m_sr * du * w * xi * (-2.0 * c.alpha_per_m * r).exp() / (r * r)
        })
        .sum()
}

#[test]
fn fogs_echo_is_the_pulse_swept_over_the_fog() {
    for v in [30.0, 60.0, 300.0] {
        let c = channel(v);
        assert!((c.pulse_m - 5.996).abs() < 1e-3, "τ_H = 20 ns is 6 m of pulse");
        assert!((c.beta_per_m_sr * v - 0.046).abs() < 1e-12);
        assert_eq!(c.power(0.9), 0.0, "no fog in the receiver's view before the crossover");
        for r in [0.95, 1.0, 1.3, 2.0, 3.0, 4.0, 5.5, 7.0, 12.0, 40.0] {
            let (p, b) = (c.power(r), brute_power(&c, r));
            assert!((p - b).abs() <= 1e-4 * b, "V {v} m, R {r} m: Simpson {p:e} against the sum {b:e}");
        }
    }
}

#[test]
fn far_away_fog_is_a_surface_at_the_pulses_centre() {
    let c = channel(60.0);
    let err = |r: f64| (c.power(r) / c.far_power(r) - 1.0).abs();
    let (e20, e50, e150) = (err(20.0), err(50.0), err(150.0));
    assert!(e150 < e50 && e50 < e20, "the error falls with range: {e20} {e50} {e150}");
    // The second-order term of the pulse's spread σ² = L²(1/12 − 1/2π²) about its centre r:
    // ½σ²·f''/f for f = e^{−2αr}/r², f''/f = (2α + 2/r)² + 2/r².
    for (r, e) in [(20.0, e20), (50.0, e50), (150.0, e150)] {
        let centre = r - 0.5 * c.pulse_m;
        let var = c.pulse_m.powi(2) * (1.0 / 12.0 - 0.5 / std::f64::consts::PI.powi(2));
        let a = c.alpha_per_m;
        let second = 0.5 * var * ((2.0 * a + 2.0 / centre).powi(2) + 2.0 / centre.powi(2));
        assert!((e - second).abs() < 0.15 * second, "R {r}: relative error {e} against the second-order term {second}");
    }
}

#[test]
fn the_echos_peak_is_the_maximum_of_a_fine_scan() {
    for v in [30.0, 60.0, 200.0] {
        let c = channel(v);
        let e = FogEcho::new(&c);
        let (mut best_r, mut best) = (0.0, 0.0);
        for i in 0..12_000 {
            let r = 0.9 + i as f64 * 0.001;
            let p = c.power(r);
            if p > best {
                (best_r, best) = (r, p);
            }
        }
        let half = c.pulse_m / 2.0;
        assert!((f64::from(e.power) - best).abs() < 1e-4 * best, "V {v}: peak {} against {best}", e.power);
        assert!(
            (f64::from(e.range_m) + half - best_r).abs() < 0.01,
            "V {v}: at {} against {}",
            e.range_m,
            best_r - half
        );
        // The half-power span: at least half the peak inside, less one grid step outside.
        let (lo, hi) = e.span_m;
        assert!(lo < e.range_m && e.range_m < hi);
        assert!(
            c.power(f64::from(hi) + half) >= 0.5 * best * 0.999 && c.power(f64::from(hi) + half + 0.011) < 0.5 * best
        );
        if lo > 0.0 {
            assert!(
                c.power(f64::from(lo) + half) >= 0.5 * best * 0.999
                    && c.power(f64::from(lo) + half - 0.011) < 0.5 * best
            );
        }
    }
}

/// Hahner et al.'s own numbers for free fog (the echo's peak with no hard target in front of
/// it), from the lookup tables their published simulation ships
/// (github.com/MartinHahner/LiDAR_fog_sim, commit 1cb9e072, `integral_lookup_tables`, entry
/// r₀ = 200 m; CC BY-NC 4.0, quoted here as reference values): (α per m; the peak's range
/// coordinate on their 0.1 m grid, unshifted; the same shifted by c·τ_H/2 so that a hard
/// target's peak reads at its range, which is what hilo reports; the soft-target integral at
/// that grid point, in seconds: their P_R_fog_soft / (C_A·P₀·β)).
const HAHNER_TABLES: [(f64, f64, f64, f64); 4] = [
    (0.005, 4.702351175587793, 1.704426595587793, 4.567987868107191e-09),
    (0.02, 4.702351175587793, 1.704426595587793, 4.346567239173599e-09),
    (0.06, 4.602301150575287, 1.6043765705752868, 3.815637193358727e-09),
    (0.1, 4.602301150575287, 1.6043765705752868, 3.36208322143135e-09),
];

/// The echo against Hahner et al.'s published implementation, at four visibilities (599, 150,
/// 50 and 30 m). Their integral runs over the pulse's time t, hilo's over its range u = c·t/2,
/// so theirs times c/2 is hilo's P(R) / (π·β). Their peak is the best point of a grid of
/// 0.10005 m (2,000 points over 200 m): hilo's peak lies within half a step of it, and its
/// power is at least the grid's best and above it by no more than a grid's half step costs.
#[test]
fn the_echo_equals_hahner_et_al_s_published_tables() {
    const C: f64 = 299_792_458.0;
    let grid_m = 200.0 / 1999.0;
    for (alpha, peak_r, reported_r, integral_s) in HAHNER_TABLES {
        let visibility = 20f64.ln() / alpha;
        let c = FogChannel::hahner(visibility, alpha);
        let theirs = integral_s * C / 2.0;
        let ours = c.power(peak_r) / (std::f64::consts::PI * c.beta_per_m_sr);
        assert!(
            (ours / theirs - 1.0).abs() < 1e-4,
            "α {alpha}: P({peak_r}) / πβ = {ours:.7} against their {theirs:.7}"
        );
        assert!((peak_r - reported_r - c.pulse_m / 2.0).abs() < 1e-9, "their shift is c·τ_H/2");
        let e = FogEcho::new(&c);
        assert!(
            (f64::from(e.range_m) - reported_r).abs() <= 0.5 * grid_m,
            "α {alpha}: peak reported at {} m against their {reported_r} m",
            e.range_m
        );
        let peak = f64::from(e.power) / (std::f64::consts::PI * c.beta_per_m_sr);
        eprintln!(
            "α {alpha} (V {visibility:.0} m): P/πβ at their peak {ours:.6} against {theirs:.6}; peak {peak:.6} reported at {:.3} m against their {reported_r:.3} m",
            e.range_m
        );
        assert!(
            peak >= theirs * (1.0 - 1e-4) && peak <= theirs * 1.002,
            "α {alpha}: peak {peak:.7} against {theirs:.7}"
        );
    }
}

#[test]
fn denser_fog_echoes_stronger_in_proportion_to_its_backscatter() {
    let clear_air = |v: f64| FogChannel { alpha_per_m: 0.0, ..channel(v) };
    let mut last = f32::INFINITY;
    for v in [20.0, 40.0, 80.0, 160.0, 320.0, 640.0] {
        let p = FogEcho::new(&channel(v)).power;
        assert!(p < last, "V {v}: {p} not below the denser fog's {last}");
        last = p;
        // Without extinction the echo is β times a constant of the sensor; extinction takes at
        // most e^{−2α·r} of it over the few metres the peak draws on.
        let bare = FogEcho::new(&clear_air(v)).power;
        assert!((f64::from(bare) * v / f64::from(FogEcho::new(&clear_air(100.0)).power * 100.0) - 1.0).abs() < 1e-5);
        let alpha = f64::from(fog_extinction_per_m(v as f32));
        let ratio = f64::from(p / bare);
        assert!(ratio < 1.0 && ratio > (-2.0 * alpha * 6.0).exp(), "V {v}: extinction took {ratio}");
    }
}

/// One level beam along +x (column 0), no noise or drop-off, a 16-beam LiDAR's datasheet
/// threshold (100 m at 0.8); in fog of visibility `v` with its echo.
fn in_fog(v: f32, beam: Option<Beam>) -> LidarSpec {
    let spec = LidarSpec {
        beams: 1,
        elevations_deg: Some(vec![0.0]),
        azimuth_resolution_deg: 0.5,
        max_range_m: 200.0,
        atmosphere_attenuation_per_m: 0.0,
        detection_range: Some(DetectionRange { range_m: 100.0, reflectivity: 0.8 }),
        beam,
        ..common::ideal_lidar("lidar-16")
    };
    Weather { fog_visibility_m: Some(v), fog_backscatter: true, ..Weather::default() }.lidar(&spec)
}

/// A wall across +x at `x` (a building: reflectivity 0.4).
fn wall(x: f32) -> World {
    let (a, b, c, d) =
        (Vec3::new(x, -30.0, -5.0), Vec3::new(x, 30.0, -5.0), Vec3::new(x, 30.0, 5.0), Vec3::new(x, -30.0, 5.0));
    World::from_triangles(&[[a, b, c], [a, c, d]], None).unwrap()
}

/// What the beam along +x reports: (range, source), nearest first.
fn along_x(spec: &LidarSpec, world: &World) -> Vec<(f32, PointSource)> {
    let scan = simulate_lidar(spec, &SensorPose::new(Vec3::ZERO, 0.0, 0.0, 0.0), world, None, 7).unwrap();
    let mut out: Vec<(f32, PointSource)> = scan
        .points
        .iter()
        .zip(&scan.sources)
        .filter(|(p, _)| p.x > 0.0 && p.y.abs() < 1e-4 * p.x)
        .map(|(p, s)| (p.x, *s))
        .collect();
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out
}

#[test]
fn the_fogs_echo_takes_a_wall_exactly_where_it_outshines_it() {
    const WALL: f32 = 0.4;
    for v in [30.0f32, 100.0] {
        let alpha = fog_extinction_per_m(v);
        let echo = FogEcho::new(&channel(f64::from(v)));
        // The closed form: the wall's echo ρ·e^{−2αd}/d² equals the fog's at d* = W(α·√(ρ/P))/α.
        let d_star = max_range_m((WALL / echo.power).sqrt(), alpha);
        let strongest = in_fog(v, None);
        let modes = |m: ReturnMode| {
            in_fog(v, Some(Beam { horizontal_mrad: 3.0, vertical_mrad: 1.5, returns: m, separation_m: 1.0, rings: 2 }))
        };
        let (last, dual) = (modes(ReturnMode::Last), modes(ReturnMode::Dual));
        let reach = strongest.reach_m(WALL);
        let (mut fog_seen, mut wall_seen) = (0, 0);
        for i in 0..60 {
            let d = 4.5 + i as f32 * 0.25;
            if (d - d_star).abs() < 0.02 * d_star || (d - reach).abs() < 0.02 * reach {
                continue;
            }
            let world = wall(d);
            let got = along_x(&strongest, &world);
            let want = if d > reach || d > d_star { PointSource::Fog } else { PointSource::Static };
            assert_eq!(got.len(), 1, "V {v}, wall at {d}: one return, got {got:?}");
            assert_eq!(got[0].1, want, "V {v}, wall at {d} (d* {d_star}, reach {reach}): {got:?}");
            if want == PointSource::Fog {
                fog_seen += 1;
                let (lo, hi) = echo.span_m;
                assert!(got[0].0 >= lo.max(0.5) && got[0].0 <= hi, "a fog point at {} outside {lo}–{hi}", got[0].0);
            } else {
                wall_seen += 1;
                assert!((got[0].0 - d).abs() < 1e-3);
            }
            // Last: the wall wherever it is seen; dual: the fog's echo and the wall's both.
            let seen = d <= reach;
            let l = along_x(&last, &world);
            let dl = along_x(&dual, &world);
            if seen {
                assert!(l.len() == 1 && (l[0].0 - d).abs() < 1e-3, "V {v}, last at {d}: {l:?}");
                assert!(
                    dl.len() == 2 && dl[0].1 == PointSource::Fog && (dl[1].0 - d).abs() < 1e-3,
                    "dual at {d}: {dl:?}"
                );
            } else {
                assert!(l.len() == 1 && l[0].1 == PointSource::Fog, "V {v}, last at {d}, the wall unseen: {l:?}");
            }
        }
        assert!(
            fog_seen >= 3 && wall_seen >= 3,
            "V {v}: both sides of d* = {d_star} tested ({wall_seen} walls, {fog_seen} fog)"
        );
    }
}

#[test]
fn the_sky_in_fog_returns_the_fogs_echo_and_clear_air_returns_nothing() {
    let open = World::from_triangles(&[], None).unwrap();
    let got = along_x(&in_fog(60.0, None), &open);
    assert!(got.len() == 1 && got[0].1 == PointSource::Fog, "{got:?}");
    let clear = LidarSpec { fog_echo: None, ..in_fog(60.0, None) };
    assert!(along_x(&clear, &open).is_empty());
    // A sensor without a datasheet detection range (the paper's) keeps fog as attenuation only.
    let paper = Weather { fog_visibility_m: Some(60.0), fog_backscatter: true, ..Weather::default() }
        .lidar(&common::ideal_lidar("lidar-16"));
    assert!(paper.fog_echo.is_none());
}

#[test]
fn the_setting_needs_fog_and_leaves_other_weathers_bytes_alone() {
    let bad = Weather { fog_backscatter: true, ..Weather::default() };
    let e = bad.check().unwrap_err().to_string();
    assert!(e.contains("fog_backscatter") && e.contains("fog_visibility_m"), "{e}");
    let plain = Weather { fog_visibility_m: Some(60.0), ..Weather::default() };
    assert_eq!(format!("{plain:?}"), "Weather { rain_mm_h: 0.0, fog_visibility_m: Some(60.0) }");
    let with = Weather { fog_backscatter: true, ..plain };
    assert!(format!("{with:?}").contains("fog_backscatter: true"));
    assert_eq!(toml::to_string(&plain).unwrap(), "rain_mm_h = 0.0\nfog_visibility_m = 60.0\n");
    let back: Weather = toml::from_str(&toml::to_string(&with).unwrap()).unwrap();
    assert_eq!(back, with);
    assert_eq!(with.to_string(), "fog (visibility 60 m, its echo)");
}
