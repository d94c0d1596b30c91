//! The datasheet LiDARs (`fixtures/sensors-datasheet.toml`): beam tables as their source gives
//! them, and range by reflectivity from the lidar equation against its closed form.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use glam::{Vec2, Vec3};
use hilo_raycast::{Actor, ActorSet};
use hilo_sensor_models::probability::{Probe, lidar_expected_returns};
use hilo_sensor_models::weather::{Weather, fog_extinction_per_m};
use hilo_sensor_models::{Catalog, DetectionRange, LidarSpec, SensorPose, simulate_lidar};
use std::path::Path;

const DATASHEET: &str = include_str!("../../../fixtures/sensors-datasheet.toml");

fn datasheet() -> Catalog {
    Catalog::from_toml_str(DATASHEET, Path::new("sensors-datasheet.toml")).unwrap()
}

/// The VLP-32C's vertical angles in laser order, as its calibration file lists them (rounded
/// to 1/1000 deg); the catalog gives them sorted.
const VLP32C_LASER_ORDER: [f32; 32] = [
    -25.0, -1.0, -1.667, -15.639, -11.31, 0.0, -0.667, -8.843, -7.254, 0.333, -0.333, -6.148, -5.333, 1.333, 0.667,
    -4.0, -4.667, 1.667, 1.0, -3.667, -3.333, 3.333, 2.333, -2.667, -3.0, 7.0, 4.667, -2.333, -2.0, 15.0, 10.333,
    -1.333,
];

#[test]
fn beam_tables_are_the_calibration_files_angles() {
    let c = datasheet();
    let mut want = VLP32C_LASER_ORDER.to_vec();
    want.sort_by(f32::total_cmp);
    let got: Vec<f32> = c.lidar("lidar-32").unwrap().elevations_rad().iter().map(|e| e.to_degrees()).collect();
    assert_eq!(got.len(), 32);
    for (g, w) in got.iter().zip(&want) {
        assert!((g - w).abs() < 1e-4, "{got:?}\n{want:?}");
    }
    // Not the paper's uniform spread: the 32-beam sensor's beams crowd the horizon (1/3 deg
    // apart within 2 deg of it, 4.6 deg and more apart below -11 deg).
    let gaps: Vec<(f32, f32)> = got.windows(2).map(|w| (0.5 * (w[0] + w[1]), w[1] - w[0])).collect();
    assert!(gaps.iter().filter(|(m, _)| m.abs() < 2.0).all(|(_, g)| (g - 1.0 / 3.0).abs() < 0.01), "{gaps:?}");
    assert!(gaps.iter().filter(|(m, _)| *m < -11.0).all(|(_, g)| *g > 2.4), "{gaps:?}");
    // The 64-beam table: two blocks of 32, the upper one finer, -24.6 to +2.0 deg.
    let e64: Vec<f32> = c.lidar("lidar-64").unwrap().elevations_rad().iter().map(|e| e.to_degrees()).collect();
    assert_eq!(e64.len(), 64);
    assert!((e64[0] + 24.555).abs() < 1e-3 && (e64[63] - 1.960).abs() < 1e-3, "{e64:?}");
    let spread = |s: &[f32]| (s[s.len() - 1] - s[0]) / (s.len() - 1) as f32;
    assert!(spread(&e64[32..]) < 0.36 && spread(&e64[..32]) > 0.5, "{e64:?}");
    // The 16-beam table is the uniform one the default catalog already has.
    let d = Catalog::default_catalog().unwrap();
    assert_eq!(c.lidar("lidar-16").unwrap().elevations_rad(), d.lidar("lidar-16").unwrap().elevations_rad());
}

/// An ideal sensor (no noise or drop-off) with a detection range of `range_m` at `reflectivity`.
fn with_range(name: &str, range_m: f32, reflectivity: f32) -> LidarSpec {
    LidarSpec {
        detection_range: Some(DetectionRange { range_m, reflectivity }),
        max_range_m: 250.0,
        ..ideal_lidar(name)
    }
}

/// Over open asphalt (reflectivity 0.12) a ring at elevation e < 0 from height h meets the
/// ground at r = h / sin(−e) and incidence cos = sin(−e); the lidar equation keeps it where
/// 0.12 · sin(−e) · R² ≥ ρ_ref · r². Each ring is then whole or absent.
#[test]
fn ground_rings_are_kept_where_the_lidar_equation_says() {
    let world = ground_world();
    let h = 6.0;
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, h), 0.0, 0.0, 0.0);
    let spec = with_range("lidar-16", 200.0, 0.8);
    let scan = simulate_lidar(&spec, &pose, &world, None, 3).unwrap();
    let cols = spec.columns() as usize;
    let mut kept = 0;
    for (ring, e) in spec.elevations_rad().iter().enumerate() {
        let n = scan.points.iter().filter(|p| p.ring as usize == ring).count();
        if *e >= 0.0 {
            assert_eq!(n, 0, "ring {ring} looks up");
            continue;
        }
        let (s, r) = ((-e).sin(), h / (-e).sin());
        let margin = 0.12 * s * 200.0 * 200.0 / (0.8 * r * r);
        assert!((margin - 1.0).abs() > 0.05, "ring {ring} too close to the limit to test: {margin}");
        let want = if margin >= 1.0 { cols } else { 0 };
        assert_eq!(n, want, "ring {ring} at {:.1} deg, {r:.1} m: power ratio {margin:.2}", e.to_degrees());
        kept += usize::from(n > 0);
    }
    // The case is a real one: some rings below the horizon kept, some lost.
    assert!(kept > 0 && kept < 8, "{kept}");
    // Without the detection range every ring below the horizon that meets the ground within
    // the range gate is whole.
    let plain = ideal_lidar("lidar-16");
    let within = plain.elevations_rad().iter().filter(|e| **e < 0.0 && h / (-*e).sin() <= plain.max_range_m).count();
    assert!(within > kept);
    assert_eq!(simulate_lidar(&plain, &pose, &world, None, 3).unwrap().points.len(), within * cols);
}

/// The reach of a surface at normal incidence: R·√(ρ/ρ_ref) in clear air, and through fog
/// the root of ρ·e^{−2αr}/r² = ρ_ref/R²; `detects` agrees on both sides of it.
#[test]
fn reach_is_the_closed_form_in_clear_air_and_in_fog() {
    let spec = with_range("lidar-32", 200.0, 0.8);
    for rho in [0.05f32, 0.1, 0.3, 0.8] {
        let reach = spec.reach_m(rho);
        let want = (200.0 * (rho / 0.8).sqrt()).min(spec.max_range_m);
        assert!((reach - want).abs() < 1e-3 * want, "{rho}: {reach} vs {want}");
        if reach < spec.max_range_m {
            assert!(spec.detects(rho, 1.0, 0.999 * reach) && !spec.detects(rho, 1.0, 1.001 * reach), "{rho}");
        }
    }
    // The dark car (0.1) is seen about a third as far as the white one (0.8): √(1/8).
    assert!((spec.reach_m(0.1) / spec.reach_m(0.8) - (0.125f32).sqrt()).abs() < 1e-4);
    let fog = Weather { fog_visibility_m: Some(100.0), ..Weather::default() }.lidar(&spec);
    let a = fog_extinction_per_m(100.0);
    assert!((fog.extinction_per_m - a).abs() < 1e-7 && fog.max_range_m == spec.max_range_m);
    for rho in [0.1f32, 0.5] {
        let r = fog.reach_m(rho);
        let lhs = rho * (-2.0 * a * r).exp() / (r * r);
        let rhs = 0.8 / (200.0 * 200.0);
        assert!((lhs / rhs - 1.0).abs() < 1e-3, "{rho}: {r} m, {lhs} vs {rhs}");
        assert!(r < spec.reach_m(rho));
        assert!(fog.detects(rho, 1.0, 0.999 * r) && !fog.detects(rho, 1.0, 1.001 * r));
    }
    // A sensor without a detection range keeps the hard-target model of the weather module.
    let plain = Weather { fog_visibility_m: Some(100.0), ..Weather::default() }.lidar(&ideal_lidar("lidar-32"));
    assert!(plain.max_range_m < 90.0 && plain.extinction_per_m == 0.0);
}

/// The placement model counts exactly the returns the scan keeps, with the lidar equation on,
/// for a car near, at and past its reach.
#[test]
fn expected_returns_follow_the_lidar_equation_as_the_scan_does() {
    let world = ground_world();
    let spec = with_range("lidar-64", 50.0, 0.12);
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, 6.5), 0.0, 0.1, 0.0);
    let reach = spec.reach_m(0.5);
    let mut seen = Vec::new();
    for x in [20.0, 0.8 * reach, 0.97 * reach, 1.1 * reach] {
        let b = Probe::CAR.at(Vec2::new(x, 2.0), 0.0, 0.3);
        let expected = lidar_expected_returns(&spec, &pose, &Probe::CAR, &b);
        let actors = ActorSet::new(vec![Actor::from_box(1, Probe::CAR.class, b)]).unwrap();
        let got = simulate_lidar(&spec, &pose, &world, Some(&actors), 0).unwrap();
        let got = got.points_per_actor().get(&1).copied().unwrap_or(0) as f32;
        assert_eq!(got, expected, "car at {x:.1} m (reach {reach:.1} m)");
        let plain = LidarSpec { max_range_m: 250.0, ..ideal_lidar("lidar-64") };
        let all = lidar_expected_returns(&plain, &pose, &Probe::CAR, &b);
        seen.push((expected, all));
    }
    // Near, the equation removes only grazing returns; past the reach, everything.
    assert!(seen[0].0 > 0.8 * seen[0].1, "{seen:?}");
    assert!(seen[2].0 < seen[2].1 && seen[3].0 == 0.0, "{seen:?}");
}

#[test]
fn detection_range_fields_are_checked_and_hash_only_when_set() {
    let bad = DATASHEET.replacen("reflectivity = 0.12", "reflectivity = 1.5", 1);
    let e = Catalog::from_toml_str(&bad, Path::new("mine.toml")).unwrap_err().to_string();
    assert!(e.contains("mine.toml") && e.contains("lidar[0].detection_range.reflectivity") && e.contains("1.5"), "{e}");
    let bad = DATASHEET.replacen("range_m = 50.0", "range_m = -1.0", 1);
    let e = Catalog::from_toml_str(&bad, Path::new("mine.toml")).unwrap_err().to_string();
    assert!(e.contains("lidar[0].detection_range.range_m"), "{e}");
    // The default catalog's LiDARs print (and hash) as before the fields existed.
    let plain = format!("{:?}", catalog().lidar("lidar-64").unwrap());
    assert!(!plain.contains("detection_range") && !plain.contains("extinction_per_m"), "{plain}");
    assert!(format!("{:?}", datasheet().lidar("lidar-64").unwrap()).contains("detection_range"));
}
