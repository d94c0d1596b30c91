//! `hilo dataset stats`: what a dataset holds, and a bird's-eye picture of one frame.

use anyhow::Result;
use hilo_core::fs::write_atomic;
use hilo_dataset::Dataset;
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

pub fn stats(args: &StatsArgs) -> Result<()> {
    let ds = Dataset::open(&args.root, &args.version)?;
    let t = &ds.tables;
    let per_class = ds.class_stats();
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
    for (c, k) in &per_class {
        let per_box = |pts: u64| pts as f64 / k.boxes as f64;
        println!("{:<12} {:>9} {:>16.1} {:>16.2}", c, k.boxes, per_box(k.lidar_points), per_box(k.radar_points));
    }
    if let Some(png) = &args.png {
        let pic = hilo_study::render::dataset_frame(&ds, args.frame)?;
        write_atomic(png, &pic.canvas.png()?)?;
        println!("wrote {} (frame {}: {} points, {} boxes)", png.display(), args.frame, pic.points, pic.boxes);
    }
    Ok(())
}
