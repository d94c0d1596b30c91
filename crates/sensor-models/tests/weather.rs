//! Rain and fog against their published models: ITU-R P.838-3's table of rain coefficients, the
//! Koschmieder visibility law, the hard-target range equation, and a scan in fog that loses
//! exactly the returns the equation says it loses.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::{catalog, dome_world, ideal_lidar};
use glam::Vec3;
use hilo_sensor_models::radar::snr_db;
use hilo_sensor_models::weather::{
    fog_extinction_per_m, lambert_w0, max_range_m, p838_horizontal, rain_radio_db_per_km,
};
use hilo_sensor_models::{SensorPose, Weather, simulate_lidar};

/// ITU-R P.838-3, Table 5 (horizontal polarisation): (GHz, k_H, α_H) as the recommendation
/// prints them; its fitted equations reproduce them to the printed digits.
#[test]
fn p838_coefficients_reproduce_the_recommendations_table() {
    for (f, k, a) in [(10.0, 0.01217, 1.2571), (20.0, 0.09164, 1.0568), (30.0, 0.2403, 0.9485)] {
        let (kk, aa) = p838_horizontal(f);
        assert!((kk - k).abs() / k < 5e-4, "{f} GHz: k {kk} vs {k}");
        assert!((aa - a).abs() < 1e-4, "{f} GHz: α {aa} vs {a}");
    }
    // At the radar's 77 GHz: a few dB/km in moderate rain, about 30 in a cloudburst; rising
    // with the rate, sub-linearly (α < 1 above ~30 GHz).
    let g = |r: f32| rain_radio_db_per_km(77.0, r);
    assert!((5.0..7.0).contains(&g(10.0)) && (28.0..34.0).contains(&g(100.0)), "{} {}", g(10.0), g(100.0));
    assert!(g(50.0) < 2.0 * g(25.0) && g(25.0) > g(10.0) && g(0.0) == 0.0);
}

/// Lambert's W against its defining identity and two known values (W(1) is the omega
/// constant, W(e) = 1), including arguments where a poor start would not converge.
#[test]
fn lambert_w_is_exact() {
    assert!((lambert_w0(1.0) - 0.567_143_290_409_783_8).abs() < 1e-14);
    assert!((lambert_w0(std::f64::consts::E) - 1.0).abs() < 1e-14);
    for x in [1e-9, 1e-3, 0.5, 2.9, 3.0, 10.0, 1e3, 1e8] {
        let w = lambert_w0(x);
        assert!((w * w.exp() - x).abs() <= 1e-12 * x.max(1.0), "W({x}) = {w}");
    }
}

/// Visibility is where a beam keeps 5% (the definition the extinction comes from); the fog's
/// maximum range solves the two-way range equation, falls with thicker fog and tends to the
/// clear range as the fog thins.
#[test]
fn fog_range_follows_the_visibility_law_and_the_range_equation() {
    for v in [30.0f32, 100.0, 300.0, 1000.0] {
        let a = fog_extinction_per_m(v);
        assert!(((-a * v).exp() - 0.05).abs() < 1e-6, "transmission over the visibility");
    }
    let clear = 90.0f32;
    let mut last = 0.0;
    for v in [20.0f32, 50.0, 100.0, 200.0, 500.0, 2000.0, 10_000.0] {
        let a = fog_extinction_per_m(v);
        let r = max_range_m(clear, a);
        let (r64, a64, c64) = (f64::from(r), f64::from(a), f64::from(clear));
        assert!((r64 * r64 * (2.0 * a64 * r64).exp() - c64 * c64).abs() / (c64 * c64) < 1e-4, "V {v}: R {r}");
        assert!(r > last && r < clear, "V {v}: R {r}");
        last = r;
    }
    assert!(clear - max_range_m(clear, fog_extinction_per_m(10_000.0)) < 5.0);
    assert_eq!(max_range_m(clear, 0.0), clear);
}

/// A LiDAR inside a 60 m dome (54–66 m away from its mount): in fog whose maximum range is
/// 40 m no return comes from the dome (only ground within 40 m), in fog whose maximum range is
/// 75 m the dome is seen; clear weather leaves the spec unchanged.
#[test]
fn a_scan_in_fog_loses_the_returns_beyond_the_fog_range() {
    let world = dome_world();
    let spec = ideal_lidar("lidar-16");
    let pose = SensorPose::new(Vec3::new(3.0, -2.0, 6.0), 0.0, 0.0, 0.0);
    assert_eq!(Weather::default().lidar(&spec), spec);
    // The visibility whose fog range is `r`: R = W(aR₀)/a ⇔ a = ln(R₀/R)/R.
    let visibility_for = |r: f32| 20f32.ln() / ((spec.max_range_m / r).ln() / r);
    for (range, dome_seen) in [(40.0f32, false), (75.0, true)] {
        let w = Weather { fog_visibility_m: Some(visibility_for(range)), ..Weather::default() };
        let foggy = w.lidar(&spec);
        assert!((foggy.max_range_m - range).abs() < 0.05, "{} vs {range}", foggy.max_range_m);
        let scan = simulate_lidar(&foggy, &pose, &world, None, 3).unwrap();
        let far = scan.points.iter().map(|p| Vec3::new(p.x, p.y, p.z).length()).fold(0.0f32, f32::max);
        assert!(far <= range + 1e-3, "a return at {far} m beyond the fog's {range} m");
        // Above the ground plane (z = 0 in the world; the mount is 6 m up, level).
        let on_dome = scan.points.iter().filter(|p| p.z + 6.0 > 0.1).count();
        assert_eq!(on_dome > 0, dome_seen, "{range} m: {on_dome} dome returns");
        // Intensity carries the two-way transmission.
        let clear = simulate_lidar(&spec, &pose, &world, None, 3).unwrap();
        assert!(
            scan.points.iter().map(|p| p.intensity).sum::<f32>()
                < clear.points.iter().map(|p| p.intensity).sum::<f32>()
        );
    }
}

/// Rain costs the radar's SNR exactly twice the P.838 specific attenuation over the range, and
/// nothing in clear air; bad weather values are refused by name.
#[test]
fn rain_lowers_the_radar_snr_by_the_two_way_path_loss() {
    let spec = catalog().radar("radar-4d").unwrap().clone();
    let w = Weather { rain_mm_h: 25.0, ..Weather::default() };
    let wet = w.radar(&spec);
    assert_eq!(Weather::default().radar(&spec), spec);
    let gamma = rain_radio_db_per_km(spec.carrier_ghz, 25.0);
    for r in [10.0f32, 50.0, 150.0] {
        let loss = snr_db(&spec, 10.0, r) - snr_db(&wet, 10.0, r);
        assert!((loss - 2.0 * gamma * r / 1000.0).abs() < 1e-4, "{r} m: {loss} dB");
    }
    assert!(Weather { rain_mm_h: -1.0, ..Weather::default() }.check().unwrap_err().to_string().contains("rain_mm_h"));
    assert!(
        Weather { fog_visibility_m: Some(0.0), ..Weather::default() }
            .check()
            .unwrap_err()
            .to_string()
            .contains("fog_visibility_m")
    );
    assert!(w.check().is_ok());
}

/// The radar's fields added for weather appear in its `Debug` form (which catalog hashes are
/// taken over) only when set: a catalog that does not set them hashes as before they existed.
#[test]
fn weather_fields_at_their_defaults_leave_a_catalogs_hash_as_it_was() {
    let spec = catalog().radar("radar-4d").unwrap().clone();
    let plain = format!("{spec:?}");
    assert!(!plain.contains("carrier_ghz") && !plain.contains("path_loss_db_per_m"), "{plain}");
    assert!(plain.ends_with(&format!("price_source: {:?} }}", spec.price_source)), "{plain}");
    let wet = Weather { rain_mm_h: 10.0, ..Weather::default() }.radar(&spec);
    assert!(format!("{wet:?}").contains("path_loss_db_per_m"));
    let other = hilo_sensor_models::RadarSpec { carrier_ghz: 24.0, ..spec };
    assert!(format!("{other:?}").contains("carrier_ghz: 24.0"));
}
