//! Which field effects a study's sensors and rig model: the report's statement of what the
//! simulation holds, so that no reader takes an ideal sensor for a datasheet one. Every effect
//! is a catalog entry or a `[dataset]` setting, off when absent (`docs/realism.md` measures
//! what each does to the verdict).

use hilo_dataset::paint::VehiclePaint;
use hilo_dataset::simulate::SimulateConfig;
use hilo_plan::study::Study;
use hilo_sensor_models::SensorSpec;
use serde::{Deserialize, Serialize};

/// One effect: whether the study models it, and with what (the sensors it applies to, or the
/// setting).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Modelled {
    pub effect: String,
    pub on: bool,
    pub detail: String,
}

/// What no setting models yet.
pub const LEFT_OUT: &str = "per-laser origin offsets, \
parking manoeuvres, radar velocity aliasing and chirp timing, ghosts of more than one \
bounce, clock drift";

/// The effects of the sensors the study's configurations use, under its dataset settings
/// `dataset` (the profile's: the study's `[dataset]` with the profile's sizes).
pub fn modelled(study: &Study, dataset: &SimulateConfig) -> Vec<Modelled> {
    let sensors: Vec<&SensorSpec> = study.type_names().iter().filter_map(|n| study.catalog.get(n).ok()).collect();
    let lidars: Vec<_> =
        sensors.iter().filter_map(|s| if let SensorSpec::Lidar(l) = s { Some(l) } else { None }).collect();
    let radars: Vec<_> =
        sensors.iter().filter_map(|s| if let SensorSpec::Radar(r) = s { Some(r) } else { None }).collect();
    let which = |names: Vec<&str>| -> (bool, String) { (!names.is_empty(), names.join(", ")) };
    let mut out = Vec::new();
    let mut push = |effect: &str, (on, detail): (bool, String)| {
        out.push(Modelled { effect: effect.to_owned(), on, detail });
    };
    push(
        "LiDAR beam tables (published, not spread uniformly)",
        which(lidars.iter().filter(|l| l.elevations_deg.is_some()).map(|l| l.name.as_str()).collect()),
    );
    push(
        "LiDAR range by reflectivity (the lidar equation)",
        which(lidars.iter().filter(|l| l.detection_range.is_some()).map(|l| l.name.as_str()).collect()),
    );
    let beams: Vec<String> = lidars
        .iter()
        .filter_map(|l| {
            let b = l.beam.as_ref()?;
            let mode = format!("{:?}", b.returns).to_lowercase();
            Some(format!("{} ({mode}, {} × {} mrad)", l.name, b.horizontal_mrad, b.vertical_mrad))
        })
        .collect();
    // A profile that casts rays of no width leaves the catalog's beams out ([`SimulateConfig`]).
    let thin = dataset.lidar_beam_width == Some(false) && !beams.is_empty();
    push(
        "LiDAR beam width and return mode (partial hits, mixed pixels)",
        if thin {
            (false, format!("rays of no width in this profile (the catalog's: {})", beams.join(", ")))
        } else {
            which(beams.iter().map(String::as_str).collect())
        },
    );
    // Fog's own echo: the conditions that ask for it, for the LiDARs with a detection range.
    let ranged: Vec<&str> = lidars.iter().filter(|l| l.detection_range.is_some()).map(|l| l.name.as_str()).collect();
    let echo: Vec<String> = study
        .file
        .conditions
        .iter()
        .filter(|c| c.weather.fog_backscatter && !ranged.is_empty())
        .map(|c| format!("{} ({})", c.name, ranged.join(", ")))
        .collect();
    push("fog's echo (LiDAR backscatter)", which(echo.iter().map(String::as_str).collect()));
    let fx = |f: &dyn Fn(&hilo_sensor_models::RadarSpec) -> bool| -> (bool, String) {
        which(radars.iter().filter(|r| f(r)).map(|r| r.name.as_str()).collect())
    };
    push("radar azimuth resolution by angle", fx(&|r| !r.azimuth_table.is_empty()));
    push("radar: unresolved targets merged", fx(&|r| r.effects.doppler_resolution_mps.is_some()));
    push(
        "radar multipath ghosts",
        fx(&|r| r.effects.wall_multipath_loss_db.is_some() || r.effects.ground_multipath_loss_db.is_some()),
    );
    push("radar side lobes", fx(&|r| r.effects.side_lobe_level_db.is_some()));
    push("radar false alarms", fx(&|r| r.effects.false_alarms_per_frame > 0.0));
    push("radar Doppler of foliage", fx(&|r| r.effects.vegetation_doppler_mps > 0.0));
    push("radar RCS by aspect", fx(&|r| r.effects.rcs_aspect_db != 0.0));
    let setting = |on: bool, detail: String| (on, if on { detail } else { String::new() });
    push(
        "rig calibration error",
        match &dataset.calibration_error {
            Some(e) => setting(true, format!("{}°, {} m (1σ)", e.rotation_deg, e.translation_m)),
            None => setting(false, String::new()),
        },
    );
    push(
        "rig clock offsets",
        match dataset.time_sync_error_s {
            Some(s) => setting(true, format!("{} ms (1σ)", s * 1000.0)),
            None => setting(false, String::new()),
        },
    );
    push("LiDAR rolling shutter", setting(dataset.rolling_shutter, "on".into()));
    push("vehicles' own paint", setting(dataset.vehicle_paint == VehiclePaint::Fleet, "the fleet's colours".into()));
    push(
        "tree crowns in wind (LiDAR)",
        match &dataset.foliage {
            Some(f) => setting(
                true,
                format!("{:.0}% of rays through gaps, leaves {} m (1σ)", f.gap_probability * 100.0, f.sway_m),
            ),
            None => setting(false, String::new()),
        },
    );
    push(
        "parked cars that come and go",
        match &dataset.traffic.parking {
            Some(p) => setting(
                true,
                format!("{:.0}% of bays taken, {:.0} min mean stay", p.occupancy * 100.0, p.mean_stay_s / 60.0),
            ),
            None => setting(false, String::new()),
        },
    );
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use std::path::Path;

    fn fixture(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures").join(name)
    }

    #[test]
    fn the_paper_sensors_study_models_no_field_effect_and_a_field_study_all() {
        let s = Study::load(&fixture("paper-sensors-study.toml")).unwrap();
        let m = modelled(&s, &s.dataset);
        assert_eq!(m.len(), 17);
        // The paper's 16-beam sensor has its published table; nothing else is on.
        assert_eq!((m[0].on, m[0].detail.as_str()), (true, "lidar-16"));
        assert!(m[1..].iter().all(|e| !e.on && e.detail.is_empty()), "{m:?}");
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("field.toml");
        std::fs::write(
            &f,
            format!(
                "extends = {:?}\ncatalog = {:?}\nscene = {:?}\n[dataset.traffic.parking]\noccupancy = 0.6\n[dataset]\nrolling_shutter = true\ntime_sync_error_s = 0.005\nvehicle_paint = \"fleet\"\nfoliage = {{ gap_probability = 0.3, sway_m = 0.1 }}\ncalibration_error = {{ rotation_deg = 0.2, translation_m = 0.02 }}\n[[conditions]]\nname = \"dense fog, echo\"\nweather = {{ fog_visibility_m = 60.0, fog_backscatter = true }}\nconfigurations = [\"2x lidar-16\"]\n",
                fixture("paper-sensors-study.toml"),
                fixture("sensors-datasheet.toml"),
                fixture("sites/arterial_parking.toml")
            ),
        )
        .unwrap();
        let s = Study::load(&f).unwrap();
        let m = modelled(&s, &s.dataset);
        assert!(m.iter().all(|e| e.on), "{m:?}");
        let by = |name: &str| m.iter().find(|e| e.effect.starts_with(name)).unwrap().detail.clone();
        assert_eq!(by("LiDAR beam tables"), "lidar-16, lidar-32, lidar-64");
        assert_eq!(by("radar side lobes"), "radar-4d", "only the radars the configurations use");
        assert_eq!(
            by("LiDAR beam width"),
            "lidar-16 (strongest, 3 × 1.5 mrad), lidar-32 (strongest, 3 × 1.5 mrad), lidar-64 (strongest, 3 × 1.5 mrad)"
        );
        assert_eq!(by("rig clock offsets"), "5 ms (1σ)");
        assert_eq!(by("fog's echo"), "dense fog, echo (lidar-16, lidar-32, lidar-64)");
        assert_eq!(by("parked cars"), "60% of bays taken, 30 min mean stay");
        // A profile that casts rays of no width says the catalog's widths are not modelled.
        let thin = SimulateConfig { lidar_beam_width: Some(false), ..(*s.dataset).clone() };
        let m = modelled(&s, &thin);
        let beam = m.iter().find(|e| e.effect.starts_with("LiDAR beam width")).unwrap();
        assert!(!beam.on);
        assert!(
            beam.detail.starts_with("rays of no width in this profile (the catalog's: lidar-16 (strongest"),
            "{beam:?}"
        );
        assert_eq!(m.iter().filter(|e| !e.on).count(), 1);
    }

    /// The default study, read from its file or embedded: everything a setting models is on at
    /// the default profile but the beams' width, which the paper profile adds.
    #[test]
    fn the_default_study_models_every_field_effect_but_the_beams_width_at_the_default_profile() {
        let s = Study::load(&fixture("study.toml")).unwrap();
        let embedded = Study::parse_embedded(include_str!("../../../fixtures/study.toml"), "s.toml").unwrap();
        assert_eq!(format!("{:?}", modelled(&embedded, &embedded.dataset)), format!("{:?}", modelled(&s, &s.dataset)));
        let registry = hilo_detector::Registry::with_builtin();
        for (name, off) in [
            (hilo_plan::profile::ProfileName::Default, vec!["LiDAR beam width", "fog's echo", "parked cars"]),
            (hilo_plan::profile::ProfileName::Paper, vec!["fog's echo", "parked cars"]),
        ] {
            let p = hilo_plan::profile::profile(name, &s, &registry).unwrap();
            let m = modelled(&s, &p.dataset);
            let not: Vec<&str> = m.iter().filter(|e| !e.on).map(|e| e.effect.as_str()).collect();
            assert_eq!(not.len(), off.len(), "{name}: {not:?}");
            assert!(not.iter().zip(&off).all(|(a, b)| a.starts_with(b)), "{name}: {not:?}");
        }
    }
}
