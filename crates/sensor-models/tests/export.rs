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

#[test]
fn nuscenes_radar_pcd_has_the_devkit_header_and_round_trips_the_radial_velocity() {
    use hilo_sensor_models::export::{NUSCENES_RADAR_STRIDE, from_nuscenes_radar_pcd, to_nuscenes_radar_pcd};
    // A pole-mounted radar sees points well below it: the radial velocity has a z component.
    let pts: Vec<RadarPoint> = (0..40)
        .map(|i| {
            let f = i as f32;
            let v = -9.0 + 0.45 * f;
            RadarPoint {
                x: 3.0 + f,
                y: -12.0 + 0.7 * f,
                z: -6.5,
                rcs_dbsm: -5.0 + 0.5 * f,
                v_r_mps: v,
                v_r_comp_mps: v,
                time_s: 0.0,
            }
        })
        .collect();
    let bytes = to_nuscenes_radar_pcd(&pts);
    let text = String::from_utf8_lossy(&bytes);
    let header: Vec<&str> = text.lines().take(11).collect();
    // The devkit reads the header by line number: FIELDS at 2, SIZE 3, TYPE 4, COUNT 5, WIDTH 6, HEIGHT 7, DATA 10.
    assert!(header[0].starts_with('#') && header[1].starts_with("VERSION"));
    assert_eq!(
        header[2],
        "FIELDS x y z dyn_prop id rcs vx vy vx_comp vy_comp is_quality_valid ambig_state x_rms y_rms invalid_state pdh0 vx_rms vy_rms"
    );
    assert_eq!(header[3], "SIZE 4 4 4 1 2 4 4 4 4 4 1 1 1 1 1 1 1 1");
    assert_eq!(header[4], "TYPE F F F I I F F F F F I I I I I I I I");
    assert_eq!((header[6], header[7], header[10]), ("WIDTH 40", "HEIGHT 1", "DATA binary"));
    let body = bytes.len() - (header.iter().map(|l| l.len() + 1).sum::<usize>());
    assert_eq!(body, 40 * NUSCENES_RADAR_STRIDE + 1, "a trailing byte after the data, as the devkit's reader needs");
    let back = from_nuscenes_radar_pcd(&bytes, Path::new("r.pcd")).unwrap();
    for (a, b) in back.iter().zip(&pts) {
        assert_eq!([a.x, a.y, a.z, a.rcs_dbsm], [b.x, b.y, b.z, b.rcs_dbsm]);
        assert!((a.v_r_mps - b.v_r_mps).abs() < 1e-5, "{} {}", a.v_r_mps, b.v_r_mps);
        // vx, vy are the sensor-frame components of the radial velocity vector v_r · (x, y, z) / r.
    }
    // An empty cloud is one NaN point (the devkit refuses width 0) and reads back empty.
    let e = to_nuscenes_radar_pcd(&[]);
    assert!(String::from_utf8_lossy(&e).contains("\nWIDTH 1\n"));
    assert!(from_nuscenes_radar_pcd(&e, Path::new("e.pcd")).unwrap().is_empty());
    // The generic radar layout is refused by name.
    let err = from_nuscenes_radar_pcd(&to_pcd(&pts), Path::new("g.pcd")).unwrap_err().to_string();
    assert!(err.contains("g.pcd") && err.contains("nuScenes' radar layout"), "{err}");
    let err = from_nuscenes_radar_pcd(&bytes[..bytes.len() - 10], Path::new("cut.pcd")).unwrap_err().to_string();
    assert!(err.contains("truncated"), "{err}");
}
