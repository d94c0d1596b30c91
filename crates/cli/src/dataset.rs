//! `hilo dataset stats`: what a dataset holds, and a bird's-eye picture of one frame.

use anyhow::{Context, Result};
use glam::{Vec2, Vec3};
use hilo_core::Box3;
use hilo_core::fs::write_atomic;
use hilo_dataset::Dataset;
use hilo_dataset::writer::class_of_category;
use hilo_study::render::blank_canvas;
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct StatsArgs {
    /// Dataset root (holds <version>/ and samples/).
    pub root: PathBuf,
    #[arg(long, default_value = "v1.0-trainval")]
    pub version: String,
    /// Also draw one frame: points coloured by sensor, boxes by class.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Which frame to draw (index in sample order).
    #[arg(long, default_value_t = 0)]
    pub frame: usize,
}

/// Box colours, one per class in [`hilo_core::Class::ALL`] order.
const PALETTE: [(u8, u8, u8); 6] =
    [(80, 170, 255), (255, 170, 60), (120, 230, 120), (255, 90, 200), (250, 250, 120), (160, 120, 255)];
/// Point colours, one per sensor of the frame (greys and pastels, apart from the box colours).
const SENSOR_COLOURS: [(u8, u8, u8); 6] =
    [(210, 210, 210), (130, 220, 230), (240, 180, 180), (150, 150, 150), (200, 230, 160), (230, 200, 240)];

pub fn stats(args: &StatsArgs) -> Result<()> {
    let ds = Dataset::open(&args.root, &args.version)?;
    let t = &ds.tables;
    let class_of: BTreeMap<&str, String> =
        t.instance
            .iter()
            .filter_map(|i| {
                t.category.iter().find(|c| c.token == i.category_token).map(|c| {
                    (i.token.as_str(), class_of_category(&c.name).map_or(c.name.clone(), |k| k.name().to_owned()))
                })
            })
            .collect();
    let mut per_class: BTreeMap<String, (usize, u64, u64)> = BTreeMap::new();
    for a in &t.sample_annotation {
        let c = class_of.get(a.instance_token.as_str()).cloned().unwrap_or_else(|| "?".into());
        let e = per_class.entry(c).or_default();
        e.0 += 1;
        e.1 += a.num_lidar_pts as u64;
        e.2 += a.num_radar_pts as u64;
    }
    println!(
        "{}: {} scenes, {} frames, {} sensors, {} boxes, {} instances",
        args.root.display(),
        t.scene.len(),
        t.sample.len(),
        t.sensor.len(),
        t.sample_annotation.len(),
        t.instance.len()
    );
    println!("{:<12} {:>9} {:>16} {:>16}", "class", "boxes", "LiDAR pts/box", "radar pts/box");
    for (c, (n, l, r)) in &per_class {
        println!("{:<12} {:>9} {:>16.1} {:>16.2}", c, n, *l as f64 / *n as f64, *r as f64 / *n as f64);
    }
    if let Some(png) = &args.png {
        let sample = t
            .sample
            .get(args.frame)
            .with_context(|| format!("--frame {}: the dataset has {} frames", args.frame, t.sample.len()))?;
        let mut dots = Vec::new();
        let mut keys: Vec<((u8, u8, u8), String)> = Vec::new();
        for (k, sd) in t.sample_data.iter().filter(|s| s.sample_token == sample.token).enumerate() {
            let cs = t
                .calibrated_sensor
                .iter()
                .find(|c| c.token == sd.calibrated_sensor_token)
                .context("calibrated sensor")?;
            let q = glam::Quat::from_xyzw(
                cs.rotation[1] as f32,
                cs.rotation[2] as f32,
                cs.rotation[3] as f32,
                cs.rotation[0] as f32,
            );
            let position = Vec3::new(cs.translation[0] as f32, cs.translation[1] as f32, cs.translation[2] as f32);
            let col = SENSOR_COLOURS[k % SENSOR_COLOURS.len()];
            let channel = t.sensor.iter().find(|x| x.token == cs.sensor_token).map_or("sensor", |x| x.channel.as_str());
            keys.push((col, format!("{channel} point")));
            let pts: Vec<Vec3> = if sd.filename.ends_with(".pcd.bin") {
                ds.lidar_points(sd)?.iter().map(|p| Vec3::new(p.x, p.y, p.z)).collect()
            } else {
                ds.radar_points(sd)?.iter().map(|p| Vec3::new(p.x, p.y, p.z)).collect()
            };
            dots.extend(pts.into_iter().map(|p| ((position + q * p).truncate(), col)));
        }
        let boxes: Vec<(Box3, (u8, u8, u8))> = t
            .sample_annotation
            .iter()
            .filter(|a| a.sample_token == sample.token)
            .map(|a| {
                let yaw = 2.0 * a.rotation[3].atan2(a.rotation[0]);
                let b = Box3::new(
                    Vec3::new(a.translation[0] as f32, a.translation[1] as f32, a.translation[2] as f32),
                    a.size[1] as f32,
                    a.size[0] as f32,
                    a.size[2] as f32,
                    yaw as f32,
                );
                let c = class_of
                    .get(a.instance_token.as_str())
                    .and_then(|c| c.parse::<hilo_core::Class>().ok())
                    .map_or(0, |c| c.index());
                (b, PALETTE[c])
            })
            .collect();
        let all: Vec<Vec2> = dots.iter().map(|d| d.0).chain(boxes.iter().map(|b| b.0.center.truncate())).collect();
        let lo = all.iter().fold(Vec2::splat(-20.0), |a, b| a.min(*b)) - Vec2::splat(5.0);
        let hi = all.iter().fold(Vec2::splat(20.0), |a, b| a.max(*b)) + Vec2::splat(5.0);
        let scale = (1600.0 / (hi - lo).max_element()).clamp(1.0, 10.0);
        let mut canvas = blank_canvas(lo, hi, scale)?;
        canvas.dots(&dots, 1.0);
        for (b, col) in &boxes {
            canvas.boxes(std::slice::from_ref(b), *col);
        }
        keys.extend(
            hilo_core::Class::ALL.iter().map(|c| (PALETTE[c.index()], format!("{} box (tick: heading)", c.name()))),
        );
        let key_refs: Vec<((u8, u8, u8), &str)> = keys.iter().map(|(c, t)| (*c, t.as_str())).collect();
        canvas.legend(&key_refs);
        canvas.scale_bar(20.0);
        canvas.north_arrow();
        write_atomic(png, &canvas.png()?)?;
        println!("wrote {} (frame {}: {} points, {} boxes)", png.display(), args.frame, dots.len(), boxes.len());
    }
    Ok(())
}
