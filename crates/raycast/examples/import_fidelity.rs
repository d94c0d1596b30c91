//! How far an imported junction's lanes stand from the OpenDRIVE file's own lane centre lines.
//!
//! For each imported site of the library and each of the file's driving lanes that leads into
//! or out of the junction, the largest distance from a sample of the file's centre line (the
//! `xodr` parser's polyline) to the nearest lane centre line of hilo's scene running the same
//! way, over the samples within 20, 40, 60 and 120 m of the junction's centre:
//!
//!     cargo run --release -p hilo-raycast --example import_fidelity
//!
//! hilo's arms are straight, pass through the junction's centre and hold their lanes side by side
//! from the median out; what the file draws otherwise (a road offset from the centre, a gap or an
//! unmodelled lane between the directions, a bend) shows here.

use glam::Vec2;
use hilo_raycast::Scene;
use hilo_raycast::scene::layout::LaneKind;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

const REACHES_M: [f32; 4] = [20.0, 40.0, 60.0, 120.0];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("| site | file lane | way | max deviation (m) within 20 / 40 / 60 / 120 m |");
    println!("|---|---|---|---|");
    for (site, map, junction) in [
        ("fabriksgatan.toml", "fabriksgatan_traffic_lights.xodr", "4"),
        ("three_arm_grid.toml", "multi_intersections.xodr", "150"),
        ("braunschweig.toml", "braunschweig.xodr", "1"),
    ] {
        let xml = std::fs::read_to_string(root().join("fixtures/opendrive").join(map))?;
        let (net, _) = xodr::load_str_with(&xml, |n| Err(format!("{n}: includes are not followed")))?;
        let scene = Scene::load(&root().join("fixtures/sites").join(site))?;
        let origin = Vec2::new(scene.config.origin.x_m as f32, scene.config.origin.y_m as f32);
        let road_of = |l: &xodr::Lane| net.road_lane(l.id).and_then(|rl| net.road(rl.road));
        let inside: HashSet<xodr::LaneId> = net
            .lanes()
            .iter()
            .filter(|l| road_of(l).and_then(|r| r.junction()).is_some_and(|j| j == junction))
            .map(|l| l.id)
            .collect();
        for l in net.lanes().iter().filter(|l| l.kind == xodr::LaneType::Driving) {
            let into = l.successors.iter().any(|s| inside.contains(s));
            let out_of = l.predecessors.iter().any(|p| inside.contains(p));
            if road_of(l).and_then(|r| r.junction()).is_some() || !(into || out_of) {
                continue;
            }
            let mut worst = [0.0f32; REACHES_M.len()];
            for p in l.center.points() {
                let q = Vec2::new(p.x, p.y) - origin;
                let d = scene
                    .layout
                    .arms
                    .iter()
                    .flat_map(|a| a.lanes.iter())
                    .filter(|ln| (ln.kind == LaneKind::Outbound) == out_of)
                    .map(|ln| {
                        let (a, b) = (ln.start, ln.end);
                        let t = ((q - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
                        (a + (b - a) * t).distance(q)
                    })
                    .fold(f32::INFINITY, f32::min);
                for (w, reach) in worst.iter_mut().zip(REACHES_M) {
                    if q.length() <= reach {
                        *w = w.max(d);
                    }
                }
            }
            let cells: Vec<String> = worst.iter().map(|w| format!("{w:.2}")).collect();
            let way = if out_of { "out" } else { "in" };
            println!("| {site} | {:?} | {way} | {} |", l.id, cells.join(" / "));
        }
    }
    Ok(())
}
