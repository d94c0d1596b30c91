//! Point clouds to and from binary PCD (v0.7) and PLY (binary little-endian), as PCL, Open3D and
//! CloudCompare read them. LiDAR fields: x y z intensity ring time; radar fields: x y z rcs v_r
//! v_r_compensated time (all float32 except ring, uint16).
//!
//! A dataset's radar files use nuScenes' own radar PCD layout instead
//! ([`to_nuscenes_radar_pcd`]), which the nuScenes devkit's `RadarPointCloud.from_file` reads.

use crate::error::SensorError;
use hilo_core::{LidarPoint, RadarPoint};
use std::path::Path;

/// Scalar types the formats carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ty {
    F32,
    U16,
}

impl Ty {
    fn size(self) -> usize {
        match self {
            Ty::F32 => 4,
            Ty::U16 => 2,
        }
    }
}

/// A point type with a fixed field list.
pub trait PointRecord: Sized {
    const FIELDS: &'static [(&'static str, Ty)];
    fn values(&self) -> Vec<f64>;
    fn from_values(v: &[f64]) -> Self;
}

impl PointRecord for LidarPoint {
    const FIELDS: &'static [(&'static str, Ty)] =
        &[("x", Ty::F32), ("y", Ty::F32), ("z", Ty::F32), ("intensity", Ty::F32), ("ring", Ty::U16), ("time", Ty::F32)];
    fn values(&self) -> Vec<f64> {
        vec![self.x as f64, self.y as f64, self.z as f64, self.intensity as f64, self.ring as f64, self.time_s as f64]
    }
    fn from_values(v: &[f64]) -> Self {
        LidarPoint {
            x: v[0] as f32,
            y: v[1] as f32,
            z: v[2] as f32,
            intensity: v[3] as f32,
            ring: v[4] as u16,
            time_s: v[5] as f32,
        }
    }
}

impl PointRecord for RadarPoint {
    const FIELDS: &'static [(&'static str, Ty)] = &[
        ("x", Ty::F32),
        ("y", Ty::F32),
        ("z", Ty::F32),
        ("rcs", Ty::F32),
        ("v_r", Ty::F32),
        ("v_r_compensated", Ty::F32),
        ("time", Ty::F32),
    ];
    fn values(&self) -> Vec<f64> {
        vec![
            self.x as f64,
            self.y as f64,
            self.z as f64,
            self.rcs_dbsm as f64,
            self.v_r_mps as f64,
            self.v_r_comp_mps as f64,
            self.time_s as f64,
        ]
    }
    fn from_values(v: &[f64]) -> Self {
        RadarPoint {
            x: v[0] as f32,
            y: v[1] as f32,
            z: v[2] as f32,
            rcs_dbsm: v[3] as f32,
            v_r_mps: v[4] as f32,
            v_r_comp_mps: v[5] as f32,
            time_s: v[6] as f32,
        }
    }
}

fn push_body<T: PointRecord>(out: &mut Vec<u8>, points: &[T]) {
    for p in points {
        for (v, (_, ty)) in p.values().into_iter().zip(T::FIELDS) {
            match ty {
                Ty::F32 => out.extend_from_slice(&(v as f32).to_le_bytes()),
                Ty::U16 => out.extend_from_slice(&(v as u16).to_le_bytes()),
            }
        }
    }
}

fn read_body<T: PointRecord>(body: &[u8], n: usize, path: &Path) -> Result<Vec<T>, SensorError> {
    let stride: usize = T::FIELDS.iter().map(|(_, t)| t.size()).sum();
    if body.len() < n * stride {
        return Err(SensorError::PointFile {
            path: path.to_path_buf(),
            message: format!(
                "truncated: {} points of {stride} bytes need {} bytes of data, found {}",
                n,
                n * stride,
                body.len()
            ),
        });
    }
    Ok(body[..n * stride]
        .chunks_exact(stride)
        .map(|rec| {
            let mut off = 0;
            let vals: Vec<f64> = T::FIELDS
                .iter()
                .map(|(_, ty)| {
                    let v = match ty {
                        Ty::F32 => f32::from_le_bytes([rec[off], rec[off + 1], rec[off + 2], rec[off + 3]]) as f64,
                        Ty::U16 => u16::from_le_bytes([rec[off], rec[off + 1]]) as f64,
                    };
                    off += ty.size();
                    v
                })
                .collect();
            T::from_values(&vals)
        })
        .collect())
}

/// Binary PCD bytes.
pub fn to_pcd<T: PointRecord>(points: &[T]) -> Vec<u8> {
    let names: Vec<&str> = T::FIELDS.iter().map(|f| f.0).collect();
    let sizes: Vec<String> = T::FIELDS.iter().map(|f| f.1.size().to_string()).collect();
    let types: Vec<&str> = T::FIELDS.iter().map(|f| if f.1 == Ty::F32 { "F" } else { "U" }).collect();
    let counts = vec!["1"; T::FIELDS.len()];
    let n = points.len();
    let header = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {}\nSIZE {}\nTYPE {}\nCOUNT {}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n",
        names.join(" "),
        sizes.join(" "),
        types.join(" "),
        counts.join(" ")
    );
    let mut out = header.into_bytes();
    push_body(&mut out, points);
    out
}

/// Splits header lines (ASCII, up to and including the line starting with `last`) from the body.
fn split_header<'a>(bytes: &'a [u8], last: &str, path: &Path) -> Result<(Vec<String>, &'a [u8]), SensorError> {
    let mut lines = Vec::new();
    let mut pos = 0;
    while pos < bytes.len() {
        let end = bytes[pos..].iter().position(|&b| b == b'\n').map(|e| pos + e).ok_or_else(|| {
            SensorError::PointFile { path: path.to_path_buf(), message: "header ends before its last line".into() }
        })?;
        let line = String::from_utf8_lossy(&bytes[pos..end]).trim_end_matches('\r').to_owned();
        pos = end + 1;
        let done = line.starts_with(last);
        lines.push(line);
        if done {
            return Ok((lines, &bytes[pos..]));
        }
        if lines.len() > 200 {
            break;
        }
    }
    Err(SensorError::PointFile { path: path.to_path_buf(), message: format!("no `{last}` line in the header") })
}

/// Parses binary PCD written for the same point type (fields are checked).
pub fn from_pcd<T: PointRecord>(bytes: &[u8], path: &Path) -> Result<Vec<T>, SensorError> {
    let (lines, body) = split_header(bytes, "DATA", path)?;
    let bad = |m: String| SensorError::PointFile { path: path.to_path_buf(), message: m };
    let field = |key: &str| lines.iter().find_map(|l| l.strip_prefix(key).map(|r| r.trim().to_owned()));
    let expected: Vec<&str> = T::FIELDS.iter().map(|f| f.0).collect();
    let fields = field("FIELDS ").ok_or_else(|| bad("no FIELDS line".into()))?;
    if fields.split_whitespace().collect::<Vec<_>>() != expected {
        return Err(bad(format!("FIELDS {fields:?}, expected {:?}", expected.join(" "))));
    }
    let data = field("DATA ").unwrap_or_default();
    if data != "binary" {
        return Err(bad(format!("DATA {data}: only binary is read")));
    }
    let n: usize = field("POINTS ").and_then(|v| v.parse().ok()).ok_or_else(|| bad("missing or bad POINTS".into()))?;
    read_body(body, n, path)
}

/// Binary little-endian PLY bytes (one `vertex` element).
pub fn to_ply<T: PointRecord>(points: &[T]) -> Vec<u8> {
    let mut header =
        format!("ply\nformat binary_little_endian 1.0\ncomment written by hilo\nelement vertex {}\n", points.len());
    for (name, ty) in T::FIELDS {
        header.push_str(&format!("property {} {name}\n", if *ty == Ty::F32 { "float" } else { "ushort" }));
    }
    header.push_str("end_header\n");
    let mut out = header.into_bytes();
    push_body(&mut out, points);
    out
}

/// Parses binary little-endian PLY written for the same point type.
pub fn from_ply<T: PointRecord>(bytes: &[u8], path: &Path) -> Result<Vec<T>, SensorError> {
    let (lines, body) = split_header(bytes, "end_header", path)?;
    let bad = |m: String| SensorError::PointFile { path: path.to_path_buf(), message: m };
    if lines.first().map(String::as_str) != Some("ply") {
        return Err(bad("not a PLY file".into()));
    }
    if !lines.iter().any(|l| l == "format binary_little_endian 1.0") {
        return Err(bad("only binary_little_endian 1.0 is read".into()));
    }
    let n: usize = lines
        .iter()
        .find_map(|l| l.strip_prefix("element vertex ").and_then(|v| v.trim().parse().ok()))
        .ok_or_else(|| bad("missing or bad `element vertex`".into()))?;
    let props: Vec<&str> =
        lines.iter().filter_map(|l| l.strip_prefix("property ")).filter_map(|l| l.split_whitespace().last()).collect();
    let expected: Vec<&str> = T::FIELDS.iter().map(|f| f.0).collect();
    if props != expected {
        return Err(bad(format!("properties {props:?}, expected {expected:?}")));
    }
    read_body(body, n, path)
}

/// nuScenes' radar PCD fields (the Continental ARS 408 cluster list), in order, with their size
/// in bytes and PCD type.
pub const NUSCENES_RADAR_FIELDS: [(&str, usize, char); 18] = [
    ("x", 4, 'F'),
    ("y", 4, 'F'),
    ("z", 4, 'F'),
    ("dyn_prop", 1, 'I'),
    ("id", 2, 'I'),
    ("rcs", 4, 'F'),
    ("vx", 4, 'F'),
    ("vy", 4, 'F'),
    ("vx_comp", 4, 'F'),
    ("vy_comp", 4, 'F'),
    ("is_quality_valid", 1, 'I'),
    ("ambig_state", 1, 'I'),
    ("x_rms", 1, 'I'),
    ("y_rms", 1, 'I'),
    ("invalid_state", 1, 'I'),
    ("pdh0", 1, 'I'),
    ("vx_rms", 1, 'I'),
    ("vy_rms", 1, 'I'),
];

/// Bytes of one point in nuScenes' radar layout.
pub const NUSCENES_RADAR_STRIDE: usize = 43;

/// Below this radial speed (m/s) a detection is flagged stationary (`dyn_prop` 1), above it
/// moving (0).
pub const STATIONARY_MPS: f32 = 0.2;

/// Radar points as nuScenes radar PCD bytes: its 18 fields, in its header order, so the devkit's
/// `RadarPointCloud.from_file` (and the loaders built on it) read them.
///
/// - `vx, vy` are the sensor-frame x and y components of the radial velocity vector
///   (`v_r · (x, y) / r`, r the 3D range), as nuScenes gives them; `vx_comp, vy_comp` the same
///   for the compensated velocity (equal for a roadside radar, which does not move). Its z
///   component is not a nuScenes field; [`from_nuscenes_radar_pcd`] recovers `v_r` from the
///   geometry.
/// - Flags are those of a valid, unambiguous cluster (`invalid_state` 0, `ambig_state` 3,
///   `is_quality_valid` 1, `pdh0` 1: false-alarm probability below 25%), which the devkit's
///   default filters keep; `dyn_prop` is 1 (stationary) below [`STATIONARY_MPS`], else 0
///   (moving); `id` the point's index (wrapping at 32,768); the `*_rms` codes 0.
/// - hilo's per-point `time` is not stored (the simulated radar stamps every detection of a
///   frame at its start, so it is 0).
/// - An empty cloud is one point of NaN, the devkit's convention (its reader refuses a width of
///   0); a trailing newline follows the data, as its reader needs one byte past the last point.
pub fn to_nuscenes_radar_pcd(points: &[RadarPoint]) -> Vec<u8> {
    let n = points.len().max(1);
    let line =
        |f: &dyn Fn(&(&str, usize, char)) -> String| NUSCENES_RADAR_FIELDS.iter().map(f).collect::<Vec<_>>().join(" ");
    let header = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {}\nSIZE {}\nTYPE {}\nCOUNT {}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n",
        line(&|f| f.0.to_owned()),
        line(&|f| f.1.to_string()),
        line(&|f| f.2.to_string()),
        line(&|_| "1".to_owned()),
    );
    let mut out = header.into_bytes();
    out.reserve(n * NUSCENES_RADAR_STRIDE + 1);
    let nan = RadarPoint {
        x: f32::NAN,
        y: f32::NAN,
        z: f32::NAN,
        rcs_dbsm: f32::NAN,
        v_r_mps: f32::NAN,
        v_r_comp_mps: f32::NAN,
        time_s: 0.0,
    };
    let empty = [nan];
    let points = if points.is_empty() { &empty[..] } else { points };
    for (i, p) in points.iter().enumerate() {
        let r = ((p.x as f64).powi(2) + (p.y as f64).powi(2) + (p.z as f64).powi(2)).sqrt();
        let along = |v: f32, c: f32| if r > 0.0 { (v as f64 * c as f64 / r) as f32 } else { 0.0 };
        let f32s = |out: &mut Vec<u8>, vs: &[f32]| vs.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
        f32s(&mut out, &[p.x, p.y, p.z]);
        out.push(if p.v_r_mps.abs() < STATIONARY_MPS { 1 } else { 0 });
        out.extend_from_slice(&((i % 32_768) as i16).to_le_bytes());
        f32s(
            &mut out,
            &[
                p.rcs_dbsm,
                along(p.v_r_mps, p.x),
                along(p.v_r_mps, p.y),
                along(p.v_r_comp_mps, p.x),
                along(p.v_r_comp_mps, p.y),
            ],
        );
        // is_quality_valid, ambig_state, x_rms, y_rms, invalid_state, pdh0, vx_rms, vy_rms.
        out.extend_from_slice(&[1, 3, 0, 0, 0, 1, 0, 0]);
    }
    out.push(b'\n');
    out
}

/// Reads nuScenes radar PCD bytes ([`to_nuscenes_radar_pcd`]'s layout, and nuScenes' own files):
/// the header must list nuScenes' 18 fields with their sizes and types. The radial velocity is
/// recovered from `vx, vy` and the point's position (`v_r = (vx·x + vy·y)·r / (x² + y²)`); a
/// point straight above or below the sensor (x = y = 0) has none and reads 0. A file of one NaN
/// point is an empty cloud.
pub fn from_nuscenes_radar_pcd(bytes: &[u8], path: &Path) -> Result<Vec<RadarPoint>, SensorError> {
    let (lines, body) = split_header(bytes, "DATA", path)?;
    let bad = |m: String| SensorError::PointFile { path: path.to_path_buf(), message: m };
    let field = |key: &str| lines.iter().find_map(|l| l.strip_prefix(key).map(|r| r.trim().to_owned()));
    let words = |key: &str| field(key).map(|v| v.split_whitespace().map(str::to_owned).collect::<Vec<_>>());
    let expect = |key: &str, want: Vec<String>| match words(key) {
        Some(w) if w == want => Ok(()),
        got => Err(bad(format!("{key}{got:?}: not nuScenes' radar layout (expected {})", want.join(" ")))),
    };
    expect("FIELDS ", NUSCENES_RADAR_FIELDS.iter().map(|f| f.0.to_owned()).collect())?;
    expect("SIZE ", NUSCENES_RADAR_FIELDS.iter().map(|f| f.1.to_string()).collect())?;
    expect("TYPE ", NUSCENES_RADAR_FIELDS.iter().map(|f| f.2.to_string()).collect())?;
    if field("DATA ").as_deref() != Some("binary") {
        return Err(bad("DATA: only binary is read".into()));
    }
    let n: usize = field("POINTS ").and_then(|v| v.parse().ok()).ok_or_else(|| bad("missing or bad POINTS".into()))?;
    let need = n.checked_mul(NUSCENES_RADAR_STRIDE).ok_or_else(|| bad(format!("POINTS {n} is too large")))?;
    if body.len() < need {
        return Err(bad(format!(
            "truncated: {n} points of {NUSCENES_RADAR_STRIDE} bytes need {need} bytes of data, found {}",
            body.len()
        )));
    }
    let mut out = Vec::with_capacity(n);
    for rec in body[..need].chunks_exact(NUSCENES_RADAR_STRIDE) {
        let f = |o: usize| f32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
        let (x, y, z, rcs, vx, vy, vxc, vyc) = (f(0), f(4), f(8), f(15), f(19), f(23), f(27), f(31));
        if out.is_empty() && n == 1 && x.is_nan() {
            return Ok(Vec::new());
        }
        let (xd, yd, zd) = (x as f64, y as f64, z as f64);
        let rho2 = xd * xd + yd * yd;
        let r = (rho2 + zd * zd).sqrt();
        let radial =
            |vx: f32, vy: f32| if rho2 > 0.0 { ((vx as f64 * xd + vy as f64 * yd) * r / rho2) as f32 } else { 0.0 };
        out.push(RadarPoint {
            x,
            y,
            z,
            rcs_dbsm: rcs,
            v_r_mps: radial(vx, vy),
            v_r_comp_mps: radial(vxc, vyc),
            time_s: 0.0,
        });
    }
    Ok(out)
}
