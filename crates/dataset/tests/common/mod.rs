//! Shared by the dataset tests.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

/// With `HILO_DEVKIT_CHECK` set, loads the dataset at `root` with nuscenes-devkit
/// (`scripts/check_nuscenes_layout.py`) and fails on any error; otherwise does nothing.
pub fn devkit_check(root: &std::path::Path) {
    if std::env::var("HILO_DEVKIT_CHECK").is_err() {
        return;
    }
    let out = std::process::Command::new("python3")
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/../../scripts/check_nuscenes_layout.py"))
        .arg(root)
        .arg("v1.0-trainval")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    eprintln!("{}", String::from_utf8_lossy(&out.stdout));
}
