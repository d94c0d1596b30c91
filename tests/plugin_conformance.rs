//! The shared conformance suite on every preset of every registered fusion plugin, dense and
//! sparse. The plugins depend on `hilo-fusion` alone; the suite lives in `hilo-detector`, so it
//! runs here, over the one list of plugins, `hilo::registry()`.

#![allow(clippy::unwrap_used, clippy::panic)]

/// Every plugin of the registry hilo ships, the LiDAR-only one included, each on a thread of
/// its own: a plugin added to `hilo::registry()` is checked with no line here.
#[test]
fn every_registered_plugin_conforms() {
    let registry = hilo::registry().unwrap();
    let plugins = registry.names();
    for shipped in ["lidar", "raw", "early", "middle", "late"] {
        assert!(plugins.iter().any(|p| p == shipped), "{shipped} is not registered: {plugins:?}");
    }
    std::thread::scope(|s| {
        let checks: Vec<_> = plugins
            .iter()
            .map(|plugin| (plugin, s.spawn(|| hilo_detector::conformance::check_plugin(&registry, plugin))))
            .collect();
        for (plugin, check) in checks {
            match check.join() {
                Ok(result) => result.unwrap_or_else(|e| panic!("plugin {plugin}: {e}")),
                Err(_) => panic!("plugin {plugin}: the conformance check panicked"),
            }
        }
    });
}

/// The registry answers which presets a study compares: each fusion preset's LiDAR-only
/// counterpart is the one with its head, and the study's fusion preset is the one named, else
/// the first registered fusion preset that has a counterpart.
#[test]
fn the_registry_names_each_fusion_presets_counterpart_and_the_studys_pair() {
    let registry = hilo::registry().unwrap();
    assert_eq!(registry.primary(), Some(("lirafusion-like", "centerpoint")));
    for (fusion, lidar) in [
        ("pointpillars-lr", "pointpillars"),
        ("l4dr-like", "centerpoint"),
        ("lirafusion-like", "centerpoint"),
        ("lirafusion-like-no-early", "centerpoint"),
    ] {
        assert_eq!(registry.lidar_counterpart(fusion), Some(lidar), "{fusion}");
    }
    for lidar_only_or_unknown in ["centerpoint", "pointpillars", "no-such-preset"] {
        assert_eq!(registry.lidar_counterpart(lidar_only_or_unknown), None);
    }
    let mut r = hilo::registry().unwrap();
    for refused in ["centerpoint", "lirafusion-like-no-early", "no-such-preset"] {
        let e = r.set_primary(refused).unwrap_err().to_string();
        assert!(e.contains(refused) && e.contains("counterpart"), "{e}");
    }
    // Unnamed: the first registered fusion preset with a counterpart (raw registers first).
    let mut unnamed = hilo_fusion::Registry::with_builtin();
    hilo_fusion_raw::register(&mut unnamed).unwrap();
    hilo_fusion_early::register(&mut unnamed).unwrap();
    assert_eq!(unnamed.primary(), Some(("pointpillars-lr", "pointpillars")));
    assert_eq!(hilo_fusion::Registry::with_builtin().primary(), None);
}

/// Every preset that reads the radar reads its boxes' velocity from the Doppler (and only
/// those: a LiDAR-only preset has no radar to read); the patch the docs give (`false`, or
/// null) turns it off, and the preset's JSON then equals the one without the step; `true` is
/// the defaults; a misspelt field is named with the ones expected.
#[test]
fn every_radar_preset_reads_the_doppler_and_a_null_patch_turns_it_off() {
    let registry = hilo::registry().unwrap();
    for name in registry.detector_names().into_iter().chain(registry.ablation_names()) {
        let det = &registry.preset(&name).unwrap().detector;
        let reads = det.decode.radar_velocity.is_some();
        assert_eq!(reads, registry.uses_radar(det), "{name}");
        if reads {
            let off = det.with_patch(&serde_json::json!({ "decode": { "radar_velocity": false } })).unwrap();
            assert_eq!(off.decode.radar_velocity, None, "{name}");
            let null = det.with_patch(&serde_json::json!({ "decode": { "radar_velocity": null } })).unwrap();
            assert_eq!(null, off, "{name}");
            let on = off.with_patch(&serde_json::json!({ "decode": { "radar_velocity": true } })).unwrap();
            assert_eq!(&on, det, "{name}: true is the defaults");
            let typo = det.with_patch(&serde_json::json!({ "decode": { "radar_velocity": { "margn_m": 2.0 } } }));
            let e = typo.unwrap_err().to_string();
            assert!(e.contains("decode.radar_velocity") && e.contains("margn_m") && e.contains("margin_m"), "{e}");
            let json = serde_json::to_string(&off.decode).unwrap();
            assert!(!json.contains("radar_velocity"), "{name}: {json}");
            assert!(!format!("{:?}", off.decode).contains("radar_velocity"), "{name}");
        }
    }
}

/// The JSON files the project ships in `fixtures/<folder>/` (at least one), parsed, and the
/// registry of every preset they must apply to.
fn shipped(folder: &str) -> (Vec<(std::path::PathBuf, serde_json::Value)>, hilo_fusion::Registry) {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(folder);
    let files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|entry| {
            let path = entry.unwrap().path();
            let value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
            (path, value)
        })
        .collect();
    assert!(!files.is_empty(), "no file in {}", dir.display());
    (files, hilo::registry().unwrap())
}

/// Every patch the project ships (`fixtures/patches/`) applies to every registered preset and
/// gives a detector config that validates, so a preset's change cannot leave a patch behind.
#[test]
fn every_shipped_patch_applies_to_every_preset() {
    let (patches, registry) = shipped("patches");
    for (path, patch) in &patches {
        for name in registry.preset_names() {
            let preset = registry.preset(&name).unwrap();
            let patched =
                preset.detector.with_patch(patch).unwrap_or_else(|e| panic!("{}: {name}: {e}", path.display()));
            assert_ne!(patched, preset.detector, "{}: changes nothing of {name}", path.display());
            patched.validate().unwrap_or_else(|e| panic!("{}: {name}: {e}", path.display()));
        }
    }
}

/// Every schedule the project ships (`fixtures/schedules/`) applies to every registered preset's
/// schedule, changes it and validates: a schedule file cannot name a field that does not exist.
#[test]
fn every_shipped_schedule_applies_to_every_preset() {
    let (schedules, registry) = shipped("schedules");
    for (path, fields) in &schedules {
        for name in registry.preset_names() {
            let preset = registry.preset(&name).unwrap();
            let train = preset.train.with_fields(fields).unwrap_or_else(|e| panic!("{}: {name}: {e}", path.display()));
            assert_ne!(train, preset.train, "{}: changes nothing of {name}", path.display());
            train.validate().unwrap_or_else(|e| panic!("{}: {name}: {e}", path.display()));
        }
    }
}

/// With cyclists, every preset of every plugin, the late one's per-modality heads included,
/// has a seventh class channel, takes a cyclist's box as its positive and decodes only its
/// own classes; without, six, and the cyclist is no target.
#[test]
fn every_preset_detects_cyclists_when_asked() {
    use hilo_detector::data::{Frame, GtBox};
    use hilo_detector::detector::{Detector, HostBatch};
    let registry = hilo::registry().unwrap();
    let cyclist = GtBox { class: 6, center: [2.0, 1.0, 0.85], wlh: [0.65, 1.75, 1.7], yaw: 0.4, velocity: [4.0, 1.7] };
    let mut lidar: Vec<[f32; 5]> =
        (0..200).map(|i| [0.1 * (i % 20) as f32 - 1.0, 0.1 * (i / 20) as f32, 0.0, 0.2, 0.0]).collect();
    lidar.extend((0..40).map(|i| [2.0 + 0.02 * i as f32, 1.0, 0.3 + 0.03 * i as f32, 0.5, 0.0]));
    let radar = vec![hilo_detector::data::radar_point([2.0, 1.0, 1.0], -3.0, 2.5, [0.8, 0.6], 0.0)];
    let frame = Frame {
        sample_token: "s".into(),
        scene: "s".into(),
        lidar,
        radar,
        radar_origin: vec![[0.0, 0.0, 5.0]],
        boxes: vec![cyclist],
    };
    for name in registry.detector_names() {
        for cyclists in [false, true] {
            let mut cfg = registry.preset(&name).unwrap().detector.clone();
            cfg.grid = hilo_detector::grid::BevGrid { half_extent_m: 12.8, cell_m: 0.8, max_pillars: 2000, ..cfg.grid };
            cfg.cyclists = cyclists;
            let k = cfg.classes().len();
            assert_eq!(
                (k, cfg.classes().last().copied()),
                if cyclists { (7, Some(hilo_core::Class::Bicycle)) } else { (6, Some(hilo_core::Class::GolfCart)) }
            );
            let det = Detector::new(&cfg.clone().validate().unwrap(), &registry, &candle_core::Device::Cpu, 0)
                .unwrap_or_else(|e| panic!("{name}, cyclists {cyclists}: {e}"));
            let b = HostBatch::new(&cfg, std::slice::from_ref(&frame), true, 0);
            let heads = det.forward_heads(&b, true).unwrap();
            for (cls, _) in &heads {
                assert_eq!(cls.dims()[1], k, "{name}, cyclists {cyclists}");
            }
            // The cyclist is a positive of the seventh channel only when there is one.
            let positives: f32 = b.targets.pos_per_class.iter().sum();
            assert_eq!(positives > 0.0, cyclists, "{name}, cyclists {cyclists}: {:?}", b.targets.pos_per_class);
            assert!(det.loss_all(&heads, &b.targets).unwrap().total.to_scalar::<f32>().unwrap().is_finite(), "{name}");
            for d in det.detect(&b).unwrap().concat() {
                assert!(cfg.classes().contains(&d.class), "{name}, cyclists {cyclists}: a {} box", d.class);
            }
        }
    }
}
