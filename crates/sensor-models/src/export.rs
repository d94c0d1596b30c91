//! Point clouds to and from binary PCD (v0.7) and PLY (binary little-endian), as PCL, Open3D and
//! CloudCompare read them. LiDAR fields: x y z intensity ring time; radar fields: x y z rcs v_r
//! v_r_compensated time (all float32 except ring, uint16).

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
