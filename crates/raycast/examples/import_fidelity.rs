//! How far an imported junction's lanes stand from the OpenDRIVE file's own lane centre lines
//! ([`hilo_raycast::scene::opendrive::lane_deviations`]), and its road edges from the borders of
//! the file's driving lanes ([`hilo_raycast::scene::opendrive::edge_deviations`]), per imported
//! site of the library, lane and edge, over the samples from 10 m (the junction's box) out to 20, 40, 60 and 120 m from the
//! junction's centre:
//!
//!     cargo run --release -p hilo-raycast --example import_fidelity
//!
//! hilo's arms are straight and hold their lanes side by side; what the file draws otherwise (a
//! bend, lanes of different widths, a gap between the directions) shows here.

use glam::Vec2;
use hilo_raycast::Scene;
use hilo_raycast::scene::opendrive::{RoadEdge, edge_deviations, lane_deviations};
use std::path::{Path, PathBuf};

const REACHES_M: [f32; 4] = [20.0, 40.0, 60.0, 120.0];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("| site | road | way | measured | max deviation (m) from 10 m out to 20 / 40 / 60 / 120 m |");
    println!("|---|---|---|---|---|");
    for (site, map, junction) in [
        ("fabriksgatan.toml", "fabriksgatan_traffic_lights.xodr", "4"),
        ("three_arm_grid.toml", "multi_intersections.xodr", "150"),
        ("braunschweig.toml", "braunschweig.xodr", "1"),
    ] {
        let path = root().join("fixtures/opendrive").join(map);
        let xml = std::fs::read_to_string(&path)?;
        let scene = Scene::load(&root().join("fixtures/sites").join(site))?;
        let origin = Vec2::new(scene.config.origin.x_m as f32, scene.config.origin.y_m as f32);
        for d in lane_deviations(&xml, &path, junction, &scene.layout, origin, &REACHES_M)? {
            let cells: Vec<String> = d.worst_m.iter().map(|w| format!("{w:.2}")).collect();
            let way = if d.into { "in" } else { "out" };
            println!("| {site} | {} | {way} | lane centre | {} |", d.road, cells.join(" / "));
        }
        for d in edge_deviations(&xml, &path, junction, &scene.layout, origin, &REACHES_M)? {
            let cells: Vec<String> = d.worst_m.iter().map(|w| format!("{w:.2}")).collect();
            let way = if d.into { "in" } else { "out" };
            let edge = match d.edge {
                RoadEdge::Curb => "curb edge",
                RoadEdge::Median => "median edge",
            };
            println!("| {site} | {} | {way} | {edge} | {} |", d.road, cells.join(" / "));
        }
    }
    Ok(())
}
