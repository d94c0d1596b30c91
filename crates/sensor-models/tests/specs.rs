//! Bad sensor specifications are errors naming the field; unknown names list the known ones.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_sensor_models::Catalog;
use hilo_sensor_models::spec::DEFAULT_CATALOG_TOML;
use std::path::Path;

fn with(replace: &str, by: &str) -> String {
    assert!(DEFAULT_CATALOG_TOML.contains(replace), "{replace}");
    DEFAULT_CATALOG_TOML.replacen(replace, by, 1)
}

fn err(text: &str) -> String {
    Catalog::from_toml_str(text, Path::new("my_sensors.toml")).unwrap_err().to_string()
}

#[test]
fn bad_specs_name_file_field_and_value() {
    let e = err(&with("beams = 64", "beams = 0"));
    assert!(e.contains("my_sensors.toml") && e.contains("lidar[0].beams") && e.contains('0'), "{e}");
    let e = err(&with("vfov_deg = 45.0", "vfov_deg = 180.0"));
    assert!(e.contains("lidar[0].vfov_deg") && e.contains("180"), "{e}");
    let e = err(&with("max_range_m = 90.0", "max_range_m = -90.0"));
    assert!(e.contains("lidar[0].max_range_m") && e.contains("-90"), "{e}");
    let e = err(&with("price_usd = 20750.0", "price_usd = nan"));
    assert!(e.contains("lidar[0].price_usd") && e.contains("NaN"), "{e}");
    let e = err(&with("hfov_deg = 120.0", "hfov_deg = 200.0"));
    assert!(e.contains("radar[0].hfov_deg"), "{e}");
    let e = err(&with("pedestrian = -8.0", "pedestrian = inf"));
    assert!(e.contains("radar[0].rcs_dbsm.pedestrian"), "{e}");
    let e = err(&with("beams = 16", "beams = 15"));
    assert!(e.contains("lidar[2].elevations_deg") && e.contains("beams = 15"), "{e}");
    let e = err(&with("name = \"lidar-32\"", "name = \"lidar-64\""));
    assert!(e.contains("duplicate"), "{e}");
    let e = err(&with("rate_hz = 20.0", "rate_hz = 20.0\nspin = true"));
    assert!(e.contains("spin"), "{e}");
}

#[test]
fn unknown_sensor_lists_the_known_ones() {
    let c = Catalog::default_catalog().unwrap();
    let e = c.get("lidar-128").unwrap_err().to_string();
    for n in ["lidar-128", "lidar-16", "lidar-32", "lidar-64", "radar-4d"] {
        assert!(e.contains(n), "{e}");
    }
    assert!(c.lidar("radar-4d").is_err());
}
