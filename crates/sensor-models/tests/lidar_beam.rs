//! A LiDAR beam of finite width against its sources: the footprint's share of a Gaussian spot
//! intercepted by thin poles and edges, against a dense quadrature of the spot; a pole seen
//! where the lidar equation says for the share it intercepts; a mixed pixel between two close
//! surfaces and two returns from two far apart, as Velodyne's return modes report them; the
//! catalog refusing a beam it cannot model.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use glam::Vec3;
use hilo_raycast::World;
use hilo_sensor_models::lidar::beam::Footprint;
use hilo_sensor_models::{Beam, Catalog, DetectionRange, LidarSpec, ReturnMode, SensorPose, simulate_lidar};
use std::path::Path;

const DATASHEET: &str = include_str!("../../../fixtures/sensors-datasheet.toml");

fn beam(rings: u32, returns: ReturnMode) -> Beam {
    Beam { horizontal_mrad: 3.0, vertical_mrad: 1.5, returns, separation_m: 1.0, rings }
}

/// One level beam, no noise, no drop-off, no attenuation, a detection range that sees anything
/// within 200 m unless a test says otherwise; column 0 looks along +x.
fn one_beam(b: Beam) -> LidarSpec {
    LidarSpec {
        beams: 1,
        elevations_deg: Some(vec![0.0]),
        azimuth_resolution_deg: 0.5,
        max_range_m: 200.0,
        atmosphere_attenuation_per_m: 0.0,
        detection_range: Some(DetectionRange { range_m: 1_000.0, reflectivity: 0.01 }),
        beam: Some(b),
        ..common::ideal_lidar("lidar-16")
    }
}

/// A vertical quad facing the sensor at x = `x`, over y ∈ [y0, y1], z ∈ [−5, 5].
fn quad(x: f32, y0: f32, y1: f32) -> [[Vec3; 3]; 2] {
    let (a, b, c, d) = (Vec3::new(x, y0, -5.0), Vec3::new(x, y1, -5.0), Vec3::new(x, y1, 5.0), Vec3::new(x, y0, 5.0));
    [[a, b, c], [a, c, d]]
}

fn world(quads: &[[[Vec3; 3]; 2]]) -> World {
    let tris: Vec<[Vec3; 3]> = quads.iter().flatten().copied().collect();
    World::from_triangles(&tris, None).unwrap()
}

/// The returns of the beam along +x (column 0): (range, intensity), nearest first.
fn along_x(spec: &LidarSpec, world: &World) -> Vec<(f32, f32)> {
    let scan = simulate_lidar(spec, &SensorPose::new(Vec3::ZERO, 0.0, 0.0, 0.0), world, None, 1).unwrap();
    let mut out: Vec<(f32, f32)> =
        scan.points.iter().filter(|p| p.x > 0.0 && p.y.abs() < 1e-4 * p.x).map(|p| (p.x, p.intensity)).collect();
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out
}

/// The share of a Gaussian spot (irradiance e^{−2ρ²}, ρ = 1 on the 1/e² contour, the spot cut
/// there) inside the strip |x − centre| ≤ half of the normalised across-scan coordinate:
/// midpoint quadrature on a 1,200 × 1,200 grid.
fn quadrature_share(centre: f32, half: f32) -> f64 {
    let n = 1_200;
    let (mut inside, mut all) = (0.0f64, 0.0f64);
    for i in 0..n {
        let x = -1.0 + (i as f64 + 0.5) * 2.0 / n as f64;
        for j in 0..n {
            let y = -1.0 + (j as f64 + 0.5) * 2.0 / n as f64;
            let r2 = x * x + y * y;
            if r2 > 1.0 {
                continue;
            }
            let w = (-2.0 * r2).exp();
            all += w;
            if (x - centre as f64).abs() <= half as f64 {
                inside += w;
            }
        }
    }
    inside / all
}

/// The footprint's share in the same strip: the summed weights of the sub-rays inside it.
fn lattice_share(f: &Footprint, b: &Beam, centre: f32, half: f32) -> f32 {
    let h = 0.5e-3 * b.horizontal_mrad;
    f.samples.iter().filter(|s| (s.across_rad / h - centre).abs() <= half).map(|s| s.weight).sum()
}

#[test]
fn the_footprint_is_a_symmetric_lattice_carrying_the_whole_pulse() {
    for (rings, n) in [(1, 7), (2, 19), (3, 37)] {
        let b = beam(rings, ReturnMode::Strongest);
        let f = Footprint::new(&b);
        assert_eq!(f.samples.len(), n, "rings {rings}");
        let total: f32 = f.samples.iter().map(|s| s.weight).sum();
        assert!((total - 1.0).abs() < 1e-6, "{total}");
        let centroid: (f32, f32) =
            f.samples.iter().fold((0.0, 0.0), |(x, y), s| (x + s.weight * s.across_rad, y + s.weight * s.along_rad));
        assert!(centroid.0.abs() < 1e-9 && centroid.1.abs() < 1e-9, "{centroid:?}");
        assert_eq!((f.samples[0].across_rad, f.samples[0].along_rad), (0.0, 0.0), "the axis first");
        assert!((f.spread_rad() - 1.5e-3).abs() < 1e-7, "the 1/e² half-angle across: {}", f.spread_rad());
    }
}

/// Poles of a tenth to the whole of the spot's width, centred on the axis and off it: the
/// lattice's share against the quadrature, its worst error falling as the rings grow.
#[test]
fn a_pole_intercepts_the_share_a_quadrature_of_the_spot_gives() {
    let mut worst = Vec::new();
    for rings in 1..=3 {
        let b = beam(rings, ReturnMode::Strongest);
        let f = Footprint::new(&b);
        let (mut max_err, mut sum_err, mut n) = (0.0f64, 0.0f64, 0);
        for half in [0.1f32, 0.2, 0.35, 0.5, 0.75, 1.0] {
            for centre in [0.0f32, 0.13, 0.31, 0.5, 0.77] {
                let e = (lattice_share(&f, &b, centre, half) as f64 - quadrature_share(centre, half)).abs();
                max_err = max_err.max(e);
                sum_err += e;
                n += 1;
            }
        }
        worst.push((max_err, sum_err / n as f64));
    }
    eprintln!("lattice share against the quadrature (worst, mean), rings 1..=3: {worst:?}");
    assert!(worst[2].1 < worst[1].1 && worst[1].1 < worst[0].1, "{worst:?}");
    assert!(worst[1].1 < 0.06 && worst[2].1 < 0.04, "{worst:?}");
    assert!(worst[1].0 < 0.20 && worst[2].0 < 0.12, "{worst:?}");
}

/// End to end, a pole 20 m ahead returns the intensity ρ·share (no attenuation, normal
/// incidence): the scan uses the footprint as the footprint says.
#[test]
fn a_poles_return_carries_the_share_it_intercepts() {
    let b = beam(2, ReturnMode::Strongest);
    let spec = one_beam(b);
    let f = Footprint::new(&b);
    let half_rad = 0.5e-3 * b.horizontal_mrad;
    let r = 20.0;
    let mut shares = Vec::new();
    for (width, offset) in [(0.01f32, 0.0f32), (0.02, 0.0), (0.02, 0.012), (0.04, -0.01), (1.0, 0.0)] {
        let w = world(&[quad(r, offset - 0.5 * width, offset + 0.5 * width)]);
        let got = along_x(&spec, &w);
        let (c, h) = ((offset / r).atan() / half_rad, (0.5 * width / r).atan() / half_rad);
        let want = lattice_share(&f, &b, c, h);
        match got.as_slice() {
            [(range, i)] => {
                assert!((range - r).abs() < 1e-3, "{range}");
                assert!((i / 0.4 - want).abs() < 1e-3, "width {width}, offset {offset}: {} vs {want}", i / 0.4);
                shares.push(i / 0.4);
            }
            [] => assert_eq!(want, 0.0, "width {width}, offset {offset}"),
            more => panic!("one return expected: {more:?}"),
        }
    }
    // The wide wall fills the beam; a 1 cm pole takes less than half of a 3 mrad spot at 20 m.
    assert!((shares.last().unwrap() - 1.0).abs() < 1e-3 && shares[0] < 0.5, "{shares:?}");
}

/// The lidar equation for a surface filling a share s of the beam: seen while
/// s·ρ/r² ≥ ρ_ref/R_ref². A 2 cm pole falls out well before a wall of the same paint.
#[test]
fn a_thin_pole_is_seen_only_as_far_as_its_share_allows() {
    let mut b = beam(2, ReturnMode::Strongest);
    b.separation_m = 0.5;
    let spec = LidarSpec { detection_range: Some(DetectionRange { range_m: 60.0, reflectivity: 0.8 }), ..one_beam(b) };
    let f = Footprint::new(&b);
    let half_rad = 0.5e-3 * b.horizontal_mrad;
    // The wall (ρ 0.4) is seen to 60·√(0.4/0.8) = 42.4 m.
    let (mut pole_last, mut wall_last) = (0.0f32, 0.0f32);
    for k in 0..40 {
        let r = 5.0 + 1.0 * k as f32;
        let share = lattice_share(&f, &b, 0.0, (0.01 / r).atan() / half_rad);
        let pole = !along_x(&spec, &world(&[quad(r, -0.01, 0.01)])).is_empty();
        assert_eq!(pole, share * 0.4 / (r * r) >= 0.8 / 3_600.0, "pole at {r} m, share {share}");
        let wall = !along_x(&spec, &world(&[quad(r, -5.0, 5.0)])).is_empty();
        assert_eq!(wall, r <= 60.0 * 0.5f32.sqrt(), "wall at {r} m");
        if pole {
            pole_last = r;
        }
        if wall {
            wall_last = r;
        }
    }
    assert!(pole_last > 5.0 && pole_last + 10.0 < wall_last, "pole to {pole_last} m, wall to {wall_last} m");
}

/// Half the beam on a near wall's edge, the rest on a wall behind: within the separation one
/// echo at the power-weighted range between them (a mixed pixel); beyond it two echoes, which
/// the modes report as Velodyne's do.
#[test]
fn an_edge_gives_a_mixed_pixel_or_two_returns() {
    let near = 10.0f32;
    // The near wall covers y > 1 mm: the sub-rays across > 0, not the axis column.
    let f = Footprint::new(&beam(2, ReturnMode::Strongest));
    let s_near: f32 = f.samples.iter().filter(|s| s.across_rad > 1e-6).map(|s| s.weight).sum();
    assert!(s_near > 0.3 && s_near < 0.5, "{s_near}");
    let p_near = s_near * 0.4 / (near * near);
    // Mixed: the wall behind 0.6 m on.
    let far = near + 0.6;
    let p_far = (1.0 - s_near) * 0.4 / (far * far);
    let w = world(&[quad(near, 0.001, 5.0), quad(far, -5.0, 5.0)]);
    let got = along_x(&one_beam(beam(2, ReturnMode::Dual)), &w);
    let mixed = (p_near * near + p_far * far) / (p_near + p_far);
    assert_eq!(got.len(), 1, "{got:?}");
    assert!((got[0].0 - mixed).abs() < 1e-3 && got[0].0 > near + 0.1 && got[0].0 < far - 0.1, "{got:?} vs {mixed}");
    assert!((got[0].1 - 0.4).abs() < 1e-3, "the whole pulse returns: {got:?}");
    // Apart: the wall behind 5 m on.
    let far = near + 5.0;
    let p_far = (1.0 - s_near) * 0.4 / (far * far);
    let w = world(&[quad(near, 0.001, 5.0), quad(far, -5.0, 5.0)]);
    let strongest_near = p_near > p_far;
    assert!(strongest_near, "the nearer half-covered wall returns more here: {p_near} vs {p_far}");
    let range = |mode| -> Vec<f32> { along_x(&one_beam(beam(2, mode)), &w).iter().map(|p| p.0).collect() };
    let close = |got: Vec<f32>, want: &[f32]| {
        assert_eq!(got.len(), want.len(), "{got:?} vs {want:?}");
        assert!(got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-3), "{got:?} vs {want:?}");
    };
    close(range(ReturnMode::Strongest), &[near]);
    close(range(ReturnMode::Last), &[far]);
    close(range(ReturnMode::Dual), &[near, far]);
    // The dual pair's intensities are the two shares.
    let dual = along_x(&one_beam(beam(2, ReturnMode::Dual)), &w);
    assert!((dual[0].1 / 0.4 - s_near).abs() < 1e-3 && (dual[1].1 / 0.4 - (1.0 - s_near)).abs() < 1e-3, "{dual:?}");
}

/// One surface filling the beam: every mode reports its one echo, at the range a ray of no
/// width reports (a wall, straight ahead).
#[test]
fn a_wall_filling_the_beam_returns_as_a_ray_of_no_width_does() {
    let w = world(&[quad(30.0, -5.0, 5.0)]);
    let thin = along_x(&LidarSpec { beam: None, ..one_beam(beam(2, ReturnMode::Dual)) }, &w);
    for mode in [ReturnMode::Strongest, ReturnMode::Last, ReturnMode::Dual] {
        let wide = along_x(&one_beam(beam(2, mode)), &w);
        assert_eq!(wide.len(), 1, "{mode:?}");
        assert!((wide[0].0 - thin[0].0).abs() < 1e-3 && (wide[0].1 - thin[0].1).abs() < 1e-4, "{wide:?} {thin:?}");
    }
}

/// The datasheet catalog's beam line (every LiDAR there has one).
const SHEET_BEAM: &str =
    "beam = { horizontal_mrad = 3.0, vertical_mrad = 1.5, returns = \"strongest\", separation_m = 1.0 }";

#[test]
fn the_catalog_refuses_a_beam_it_cannot_model() {
    assert_eq!(DATASHEET.matches(SHEET_BEAM).count(), 3);
    let cases = [
        ("horizontal_mrad = 0.0", "beam.horizontal_mrad"),
        ("vertical_mrad = 80.0", "beam.vertical_mrad"),
        ("separation_m = -1.0", "beam.separation_m"),
        ("rings = 4", "beam.rings"),
        ("returns = \"first\"", "returns"),
    ];
    let good =
        ["horizontal_mrad = 3.0", "vertical_mrad = 1.5", "returns = \"dual\"", "separation_m = 1.0", "rings = 2"];
    for (bad, field) in cases {
        let key = bad.split(" = ").next().unwrap();
        let entry: Vec<&str> = good.iter().map(|kv| if kv.starts_with(key) { bad } else { kv }).collect();
        let text = DATASHEET.replacen(SHEET_BEAM, &format!("beam = {{ {} }}", entry.join(", ")), 1);
        let err = Catalog::from_toml_str(&text, Path::new("beam.toml")).unwrap_err().to_string();
        assert!(err.contains(field) && err.contains("beam.toml"), "{bad}: {err}");
    }
    // A beam without the lidar equation's threshold: which partial hits are seen is undefined.
    let paper = include_str!("../../../fixtures/sensors.toml").replacen(
        "name = \"lidar-16\"",
        &format!("name = \"lidar-16\"\n{SHEET_BEAM}"),
        1,
    );
    let err = Catalog::from_toml_str(&paper, Path::new("paper.toml")).unwrap_err().to_string();
    assert!(err.contains("beam") && err.contains("detection_range"), "{err}");
}
