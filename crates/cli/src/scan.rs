//! `hilo scan`: one frame of one sensor, written as PCD or PLY, with an optional picture.

use crate::load_scene;
use anyhow::{Context, Result, bail};
use hilo_core::fs::write_atomic;
use hilo_raycast::{ActorSet, QueryRegion, World};
use hilo_sensor_models::export::{to_pcd, to_ply};
use hilo_sensor_models::{Catalog, SensorPose, SensorSpec, simulate_lidar, simulate_radar};
use hilo_study::demo::{actor_box, demo_actors};
use hilo_study::render::{ScanPoints, scan_png};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct ScanArgs {
    /// Sensor name from the catalog (e.g. lidar-16, lidar-32, lidar-64, radar-4d).
    #[arg(long)]
    sensor: String,
    /// Mount pose in the scene's local frame: x,y,z[,yaw_deg[,pitch_deg[,roll_deg]]]; positive
    /// pitch tilts the sensor down.
    #[arg(long, allow_hyphen_values = true)]
    pose: String,
    /// Output point cloud: .pcd or .ply (binary), in the sensor frame.
    #[arg(long)]
    out: PathBuf,
    /// Also draw the points over the scene, top-down.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Scene TOML; the embedded default when omitted.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Sensor catalog TOML; the embedded default (the paper's Table I) when omitted.
    #[arg(long)]
    catalog: Option<PathBuf>,
    /// Road users placed in the scene (vehicles on lanes, pedestrians on crosswalks).
    #[arg(long, default_value_t = 12)]
    actors: usize,
    /// Whether the road users move (radar Doppler needs motion).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    moving: bool,
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

pub fn run(args: &ScanArgs) -> Result<()> {
    let scene = load_scene(args.scene.as_deref(), &crate::JunctionArgs::default())?;
    let catalog = match &args.catalog {
        Some(p) => Catalog::load(p)?,
        None => Catalog::default_catalog()?,
    };
    let spec = catalog.get(&args.sensor)?;
    let pose = SensorPose::parse(&args.pose)?;
    if let Some(why) = hilo_study::rig::outside(&scene, &pose) {
        bail!("--pose {}: the position {why}", args.pose);
    }
    let ext = args.out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
    if ext != "pcd" && ext != "ply" {
        bail!("--out {}: the extension must be .pcd or .ply", args.out.display());
    }
    let actors = demo_actors(&scene, args.actors, args.moving, args.seed);
    if actors.len() < args.actors {
        eprintln!(
            "warning: --actors {} asked, {} placed: the scene's lanes and crosswalks hold no more \
             without overlapping road users",
            args.actors,
            actors.len()
        );
    }
    let boxes: Vec<_> = actors.iter().map(actor_box).collect();
    let set = ActorSet::new(actors)?;
    let range = match spec {
        SensorSpec::Lidar(l) => l.max_range_m,
        SensorSpec::Radar(r) => r.max_range_m,
    };
    let world = World::build(&scene, &QueryRegion::spheres([(pose.position, range)]))?;
    let (lidar, radar);
    let (bytes, points) = match spec {
        SensorSpec::Lidar(l) => {
            let s = simulate_lidar(l, &pose, &world, Some(&set), args.seed)?;
            lidar = s.points_local();
            (if ext == "pcd" { to_pcd(&s.points) } else { to_ply(&s.points) }, ScanPoints::Lidar(&lidar))
        }
        SensorSpec::Radar(r) => {
            let s = simulate_radar(r, &pose, &world, Some(&set), args.seed)?;
            radar = s.points_local();
            (if ext == "pcd" { to_pcd(&s.points) } else { to_ply(&s.points) }, ScanPoints::Radar(&radar))
        }
    };
    write_atomic(&args.out, &bytes)?;
    let count = match points {
        ScanPoints::Lidar(p) => p.len(),
        ScanPoints::Radar(p) => p.len(),
    };
    eprintln!("wrote {count} points to {}", args.out.display());
    if let Some(png) = &args.png {
        let picture = scan_png(&scene, points, pose.position.truncate(), &boxes).context("drawing the scan")?;
        write_atomic(png, &picture)?;
        eprintln!("wrote {}", png.display());
    }
    Ok(())
}
