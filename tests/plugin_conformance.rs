//! The shared conformance suite on every preset of each fusion plugin, dense and sparse. The
//! plugins depend on `hilo-fusion` alone; the suite lives in `hilo-detector`, so it runs here.

#![allow(clippy::unwrap_used, clippy::panic)]

fn check(plugin: &str, register: fn(&mut hilo_fusion::Registry) -> hilo_fusion::Result<()>) {
    let mut r = hilo_fusion::Registry::with_builtin();
    register(&mut r).unwrap();
    hilo_detector::conformance::check_plugin(&r, plugin).unwrap();
}

#[test]
fn raw_plugin_conforms() {
    check("raw", hilo_fusion_raw::register);
}

#[test]
fn early_plugin_conforms() {
    check("early", hilo_fusion_early::register);
}

#[test]
fn middle_plugin_conforms() {
    check("middle", hilo_fusion_middle::register);
}

#[test]
fn late_plugin_conforms() {
    check("late", hilo_fusion_late::register);
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
