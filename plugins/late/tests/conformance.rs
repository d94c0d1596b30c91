//! The shared conformance suite on every preset of the plugin, dense and sparse.

#![allow(clippy::unwrap_used)]

#[test]
fn conformance() {
    let mut r = hilo_fusion::Registry::with_builtin();
    hilo_fusion_late::register(&mut r).unwrap();
    hilo_fusion::conformance::check_plugin(&r, "late").unwrap();
}
