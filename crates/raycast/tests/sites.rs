//! The site library (`fixtures/sites/`): structurally different junctions, each a scene hilo
//! builds and the field would accept (poles, lights and trees off the carriageway, buildings
//! off the roads and out of the junction box), and the imported real junctions equal to a fresh
//! import of their OpenDRIVE file, so the committed scene is what the importer makes today.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_raycast::Scene;
use hilo_raycast::scene::config::SceneConfig;
use hilo_raycast::scene::opendrive::{JunctionPick, import_file, scene_toml};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn sites() -> Vec<PathBuf> {
    hilo_core::fs::files_with_extension(&root().join("fixtures/sites"), "toml").unwrap()
}

#[test]
fn every_site_builds_with_mounts_arms_and_regions_of_interest() {
    let all = sites();
    assert!(all.len() >= 6, "{all:?}");
    let mut names = Vec::new();
    let mut arm_counts = Vec::new();
    for p in &all {
        let scene = Scene::load(p).unwrap_or_else(|e| panic!("{e}"));
        let n_arms = scene.layout.arms.len();
        assert!((3..=6).contains(&n_arms), "{}: {n_arms} arms", p.display());
        assert!(scene.mounts.len() >= 2, "{}: {} mounting structures", p.display(), scene.mounts.len());
        assert!(!scene.rois.is_empty(), "{}: no regions of interest", p.display());
        names.push(scene.config.name.clone());
        arm_counts.push(n_arms);
    }
    names.sort();
    names.dedup();
    assert_eq!(names.len(), all.len(), "two sites share a name");
    // Structurally different: three, four and five arms are all there.
    for n in [3, 4, 5] {
        assert!(arm_counts.contains(&n), "no site with {n} arms: {arm_counts:?}");
    }
}

/// The imported sites are what `hilo scene import` writes today from the committed maps.
#[test]
fn imported_sites_equal_a_fresh_import() {
    for (site, map, junction) in [
        ("fabriksgatan.toml", "fixtures/opendrive/fabriksgatan_traffic_lights.xodr", "4"),
        ("three_arm_grid.toml", "fixtures/opendrive/multi_intersections.xodr", "150"),
        ("braunschweig.toml", "fixtures/opendrive/braunschweig.xodr", "1"),
    ] {
        let imported = import_file(&root().join(map), &JunctionPick::id(junction)).unwrap();
        let fresh = scene_toml(&imported, Path::new(map)).unwrap();
        let committed = std::fs::read_to_string(root().join("fixtures/sites").join(site)).unwrap();
        assert_eq!(committed, fresh, "{site}: import it again with `hilo scene import {map} --junction {junction}`");
    }
}

fn default_config() -> SceneConfig {
    SceneConfig::load(&root().join("fixtures/intersection.toml")).unwrap()
}

fn refused(cfg: SceneConfig, needle: &str) {
    let path = Path::new("edited.toml");
    let e = Scene::from_config(cfg, Path::new("."), path).err().map(|e| e.to_string()).unwrap_or_default();
    assert!(e.contains(needle), "{needle}: {e}");
}

/// A building laid across an arm with no corner on the road (its edges cross the road's) is
/// refused, as is one in the lanes; a tree on the lanes is refused; median trees (the default
/// fixture's) are not.
#[test]
fn buildings_and_trees_on_the_carriageway_are_refused() {
    let mut cfg = default_config();
    // The east arm runs along y = 0 from the box to x = 130: a thin slab from y = -40 to 40.
    cfg.buildings[0].footprint = vec![[80.0, -40.0], [82.0, -40.0], [82.0, 40.0], [80.0, 40.0]];
    refused(cfg, "buildings[0].footprint");
    let mut cfg = default_config();
    cfg.buildings[0].footprint = vec![[60.0, 3.0], [66.0, 3.0], [66.0, 8.0], [60.0, 8.0]];
    refused(cfg, "reaches onto the carriageway of arm \"east\"");
    let mut cfg = default_config();
    cfg.trees[0].position = [60.0, 5.0];
    refused(cfg, "trees[0].position");
    let cfg = default_config();
    assert!(cfg.trees.iter().any(|t| t.position[1] == 0.0), "the default has median trees");
    Scene::from_config(cfg, Path::new("."), Path::new("intersection.toml")).unwrap();
}

/// No sidewalk reaches onto another arm's carriageway: every sidewalk's corners, pulled 1 cm
/// towards its centre, lie outside every other arm's road. At an acute corner (the skewed
/// junction's 65°, Braunschweig's 77°) a strip that started at the corner reached up to
/// `width · cos θ` into the neighbour's outermost lane; it now starts where its outer edge meets
/// the neighbour's curb, and the corner between the curbs is a triangle.
#[test]
fn no_sidewalk_reaches_onto_another_arm_s_carriageway() {
    use hilo_raycast::scene::layout::point_in_polygon;
    let mut all = sites();
    all.push(root().join("fixtures/intersection.toml"));
    for p in &all {
        let scene = Scene::load(p).unwrap();
        let l = &scene.layout;
        let mut pieces: Vec<(String, Option<usize>, &Vec<glam::Vec2>)> = Vec::new();
        for (i, arm) in l.arms.iter().enumerate() {
            for w in &arm.sidewalks {
                pieces.push((format!("{} sidewalk", arm.name), Some(i), w));
            }
        }
        for (k, w) in l.corner_sidewalks.iter().enumerate() {
            pieces.push((format!("corner {k}"), None, w));
        }
        for (name, own, poly) in pieces {
            let c = poly.iter().copied().sum::<glam::Vec2>() / poly.len() as f32;
            for v in poly {
                let q = *v + (c - *v).normalize_or_zero() * 0.01;
                for (j, arm) in l.arms.iter().enumerate() {
                    if Some(j) == own {
                        continue;
                    }
                    assert!(
                        !point_in_polygon(q, &arm.road),
                        "{}: {name} reaches onto {}'s carriageway at {q}",
                        p.display(),
                        arm.name
                    );
                }
            }
        }
    }
}

/// Every drawn site's corners rounded at 2, 6 and 10 m (where the scene can hold the radius):
/// the ground between each arc and its sharp corner becomes carriageway, just behind the arc
/// is raised, the corner's pole stands on its sidewalk, and no sidewalk piece reaches onto
/// another arm's road or into the junction box.
#[test]
fn rounded_corners_at_every_site_keep_the_sidewalks_off_the_carriageway() {
    use hilo_raycast::scene::layout::{corner_curb, point_in_polygon};
    let mut all = sites();
    all.push(root().join("fixtures/intersection.toml"));
    let mut rounded = 0;
    for p in &all {
        let base = SceneConfig::load(p).unwrap();
        if base.roundabout.is_some() {
            continue;
        }
        let sharp = Scene::load(p).unwrap().layout;
        for r in [2.0f32, 6.0, 10.0] {
            // What stands at the sharp corners (poles, lights, trees, buildings) would stand
            // in the wider junction box: only the road's geometry is checked here.
            let mut cfg = SceneConfig {
                signal_poles: Vec::new(),
                street_lights: Vec::new(),
                trees: Vec::new(),
                buildings: Vec::new(),
                ..base.clone()
            };
            for a in &mut cfg.arms {
                a.corner_radius_m = r;
            }
            // Straight sides (a T-junction's) take none.
            let scene = loop {
                match Scene::from_config(cfg.clone(), p.parent().unwrap(), p) {
                    Ok(s) => break Some(s),
                    Err(e) => {
                        let e = e.to_string();
                        let Some(k) = (0..cfg.arms.len()).find(|k| e.contains(&format!("arms[{k}].corner_radius_m")))
                        else {
                            panic!("{}: r {r}: {e}", p.display());
                        };
                        if e.contains("beyond half its length") {
                            break None;
                        }
                        cfg.arms[k].corner_radius_m = 0.0;
                    }
                }
            };
            let Some(scene) = scene else { continue };
            let l = &scene.layout;
            let n = l.arms.len();
            for i in 0..n {
                let (a, b) = (&l.arms[i], &l.arms[(i + 1) % n]);
                let radius = cfg.arms.iter().find(|c| c.name == a.name).unwrap().corner_radius_m;
                let (Some(curb), Some(corner)) = (corner_curb(a, b, radius, 1.0), corner_curb(a, b, 0.0, 1.0)) else {
                    continue;
                };
                // A corner the sharp layout has: a vertex of its junction box.
                let (mid, sharp_corner) = (curb[curb.len() / 2], corner[1]);
                if radius == 0.0 || !sharp.central.iter().any(|v| v.distance(sharp_corner) < 1e-3) {
                    continue;
                }
                rounded += 1;
                let q = 0.5 * (mid + sharp_corner);
                let at = format!("{} r {r}, corner of {:?} at {q}", p.display(), a.name);
                assert!(l.on_carriageway(q) && !sharp.on_carriageway(q), "{at}");
                let behind = mid + (mid - sharp_corner).normalize() * 0.05;
                assert!(!l.on_carriageway(behind), "{at}: behind the arc at {behind}");
            }
            for w in &l.corner_sidewalks {
                let c = w.iter().copied().sum::<glam::Vec2>() / w.len() as f32;
                for v in w {
                    let q = *v + (c - *v).normalize_or_zero() * 0.01;
                    assert!(
                        !point_in_polygon(q, &l.central),
                        "{} r {r}: corner sidewalk in the box at {q}",
                        p.display()
                    );
                    for arm in &l.arms {
                        assert!(
                            !point_in_polygon(q, &arm.road),
                            "{} r {r}: on {}'s road at {q}",
                            p.display(),
                            arm.name
                        );
                    }
                }
            }
            for post in &l.corner_posts {
                assert!(!l.on_carriageway(*post), "{} r {r}: pole on the carriageway at {post}", p.display());
            }
        }
    }
    assert!(rounded >= 40, "only {rounded} rounded corners checked");
}
