//! PCD and PLY round trips: exact headers, identical points; truncated files are errors.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_core::{LidarPoint, RadarPoint};
use hilo_sensor_models::export::{from_pcd, from_ply, to_pcd, to_ply};
use std::path::Path;

fn lidar_points() -> Vec<LidarPoint> {
    (0..257)
        .map(|i| {
            let f = i as f32;
            LidarPoint {
                x: f * 0.37 - 20.0,
                y: -f * 1.1e-3,
                z: (f * 0.1).sin(),
                intensity: (f / 300.0),
                ring: (i % 64) as u16,
                time_s: f * 1e-4,
            }
        })
        .collect()
}

fn radar_points() -> Vec<RadarPoint> {
    (0..33)
        .map(|i| {
            let f = i as f32;
            RadarPoint {
                x: f,
                y: -f * 0.5,
                z: 0.25,
                rcs_dbsm: -8.0 + f * 0.3,
                v_r_mps: -3.5 + f * 0.1,
                v_r_comp_mps: -3.5 + f * 0.1,
                time_s: 0.0,
            }
        })
        .collect()
}

#[test]
fn pcd_headers_are_exact_and_points_round_trip() {
    let pts = lidar_points();
    let bytes = to_pcd(&pts);
    let header = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity ring time\nSIZE 4 4 4 4 2 4\nTYPE F F F F U F\nCOUNT 1 1 1 1 1 1\nWIDTH 257\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 257\nDATA binary\n";
    assert!(bytes.starts_with(header.as_bytes()));
    assert_eq!(bytes.len(), header.len() + 257 * 22);
    assert_eq!(from_pcd::<LidarPoint>(&bytes, Path::new("a.pcd")).unwrap(), pts);
    let r = radar_points();
    let rb = to_pcd(&r);
    assert!(String::from_utf8_lossy(&rb).contains("FIELDS x y z rcs v_r v_r_compensated time\n"));
    assert_eq!(from_pcd::<RadarPoint>(&rb, Path::new("r.pcd")).unwrap(), r);
    // Empty clouds too.
    assert!(from_pcd::<LidarPoint>(&to_pcd::<LidarPoint>(&[]), Path::new("e.pcd")).unwrap().is_empty());
}

#[test]
fn ply_headers_are_exact_and_points_round_trip() {
    let pts = lidar_points();
    let bytes = to_ply(&pts);
    let header = "ply\nformat binary_little_endian 1.0\ncomment written by hilo\nelement vertex 257\nproperty float x\nproperty float y\nproperty float z\nproperty float intensity\nproperty ushort ring\nproperty float time\nend_header\n";
    assert!(bytes.starts_with(header.as_bytes()));
    assert_eq!(from_ply::<LidarPoint>(&bytes, Path::new("a.ply")).unwrap(), pts);
    let r = radar_points();
    assert_eq!(from_ply::<RadarPoint>(&to_ply(&r), Path::new("r.ply")).unwrap(), r);
}

#[test]
fn truncated_or_foreign_files_are_errors_naming_the_file() {
    let bytes = to_pcd(&lidar_points());
    let e = from_pcd::<LidarPoint>(&bytes[..bytes.len() - 5], Path::new("cut.pcd")).unwrap_err().to_string();
    assert!(e.contains("cut.pcd") && e.contains("truncated"), "{e}");
    let e = from_pcd::<RadarPoint>(&bytes, Path::new("wrong.pcd")).unwrap_err().to_string();
    assert!(e.contains("wrong.pcd") && e.contains("FIELDS"), "{e}");
    let e = from_ply::<LidarPoint>(b"ply\nformat ascii 1.0\nend_header\n", Path::new("t.ply")).unwrap_err().to_string();
    assert!(e.contains("binary_little_endian"), "{e}");
    let e = from_pcd::<LidarPoint>(b"VERSION 0.7\nFIELDS x", Path::new("h.pcd")).unwrap_err().to_string();
    assert!(e.contains("h.pcd"), "{e}");
}
