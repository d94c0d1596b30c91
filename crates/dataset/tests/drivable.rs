//! Every vehicle route of every junction of the site library (and the default intersection)
//! stays on the carriageway: the route's centre line and both sides of the widest car's body
//! along it lie on an arm's road or in the junction box, and never on a sidewalk, a corner's
//! sidewalk or a median, which the scene raises by the curb height. And no sidewalk reaches onto
//! another arm's carriageway, as it did at acute corners.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec2;
use hilo_dataset::traffic::routes::{DS, ROUTE_HALF_WIDTH_M, build_routes};
use hilo_raycast::Scene;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The widest car's half width: the body of any car on a route stays on the carriageway.
const HALF_BODY_M: f32 = ROUTE_HALF_WIDTH_M;

#[test]
fn every_route_of_every_site_stays_on_the_carriageway() {
    let mut files = hilo_core::fs::files_with_extension(&root().join("fixtures/sites"), "toml").unwrap();
    files.push(root().join("fixtures/intersection.toml"));
    let mut checked = 0usize;
    let mut off = Vec::new();
    for file in &files {
        let scene = Scene::load(file).unwrap_or_else(|e| panic!("{e}"));
        let routes = build_routes(&scene.layout);
        assert!(!routes.is_empty(), "{}: no routes", file.display());
        for r in &routes {
            let mut worst: Option<(f32, Vec2)> = None;
            let n = r.path.points.len();
            // The first and last samples lie on the arms' far ends, the road's own boundary (and
            // so may a sample a hair before the last, where the resampling falls just short of it).
            let (first, last) = (r.path.points[0], r.path.points[n - 1]);
            let ends = |p: Vec2| p.distance(first) < 0.05 || p.distance(last) < 0.05;
            for (k, (&p, &d)) in r.path.points.iter().zip(&r.path.dirs).enumerate().filter(|(_, (p, _))| !ends(**p)) {
                let side = d.perp() * HALF_BODY_M;
                for q in [p, p + side, p - side] {
                    checked += 1;
                    if !scene.layout.on_carriageway(q) && worst.is_none() {
                        worst = Some((k as f32 * DS, q));
                    }
                }
            }
            if let Some((s, q)) = worst {
                off.push(format!(
                    "{}: {} -> {} ({:?}) leaves the carriageway at s = {s:.1} m, ({:.2}, {:.2})",
                    file.file_name().unwrap().to_string_lossy(),
                    scene.layout.arms[r.approach].name,
                    scene.layout.arms[r.exit].name,
                    r.movement,
                    q.x,
                    q.y
                ));
            }
        }
    }
    assert!(off.is_empty(), "{} routes leave the carriageway:\n{}", off.len(), off.join("\n"));
    assert!(checked > 10_000, "only {checked} points checked");
}

/// The check itself catches a route laid over a sidewalk: the default intersection's first
/// route moved sideways by a lane and a half onto the curb.
#[test]
fn a_route_over_the_sidewalk_is_caught() {
    let scene = Scene::load(&root().join("fixtures/intersection.toml")).unwrap();
    let routes = build_routes(&scene.layout);
    let arm = &scene.layout.arms[0];
    let outermost = arm.edge_in_m - 0.5;
    let on_curb = arm.dir * (arm.stop_line_at_m + 20.0) + arm.normal * (arm.edge_in_m + 1.0);
    let near_curb = arm.dir * (arm.stop_line_at_m + 20.0) + arm.normal * outermost;
    assert!(!scene.layout.on_carriageway(on_curb), "a point on the sidewalk reads as drivable");
    assert!(scene.layout.on_carriageway(near_curb), "a point in the outermost lane reads as off the road");
    assert!(routes.iter().all(|r| r.path.points.iter().all(|p| p.is_finite())));
}
