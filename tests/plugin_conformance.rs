//! The shared conformance suite on every preset of each fusion plugin, dense and sparse. The
//! plugins depend on `hilo-fusion` alone; the suite lives in `hilo-detector`, so it runs here.

#![allow(clippy::unwrap_used)]

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
