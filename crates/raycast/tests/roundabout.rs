//! A roundabout's layout (`[roundabout]`, `fixtures/sites/roundabout.toml`): the ring is road
//! and its island is not, the curbs flare from each arm onto the ring and the sidewalks follow
//! them, the crosswalks stand behind the ring, the central ROI leaves the island out, and
//! numbers the model cannot drive are refused by name.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec2;
use hilo_raycast::Scene;
use hilo_raycast::scene::config::SceneConfig;
use hilo_raycast::scene::layout::point_in_polygon;
use std::path::{Path, PathBuf};

fn file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/sites/roundabout.toml")
}

fn text() -> String {
    std::fs::read_to_string(file()).unwrap()
}

fn build(text: &str) -> Result<Scene, String> {
    let cfg = SceneConfig::from_toml_str(text, &file()).map_err(|e| e.to_string())?;
    Scene::from_config(cfg, Path::new("."), &file()).map_err(|e| e.to_string())
}

#[test]
fn the_ring_is_road_the_island_is_not_and_the_curbs_flare_onto_it() {
    let scene = build(&text()).unwrap();
    let l = &scene.layout;
    let ring = l.ring.as_ref().expect("a ring");
    let (ri, ro) = (ring.island_radius_m, ring.outer_radius_m);
    let central = scene.rois.iter().find(|r| r.name == "ring and crosswalks").unwrap();
    for k in 0..144 {
        let u = Vec2::from_angle(k as f32 * std::f32::consts::TAU / 144.0);
        // Across the circulatory roadway, curb to curb.
        for r in [ri + 0.1, ring.lane_radius_m(), ro - 0.1] {
            assert!(l.on_carriageway(u * r), "ring at {:?} not road", u * r);
            assert!(central.contains(u * r), "ring at {:?} outside the central ROI", u * r);
        }
        assert!(!l.on_carriageway(u * (ri - 0.1)) && l.on_island(u * (ri - 0.1)));
        assert!(!central.contains(u * (ri - 0.1)), "the island counts as road user ground");
        // No sidewalk reaches over the ring.
        assert!(l.corner_sidewalks.iter().all(|w| !point_in_polygon(u * (ro - 0.1), w)));
    }
    for arm in &l.arms {
        // The crosswalk stands behind the ring by the setback, the yield line just off it.
        assert!(arm.crosswalk.iter().all(|c| c.length() > ro + 5.9), "{}: {:?}", arm.name, arm.crosswalk);
        assert!((arm.stop_line_at_m - (ro + 0.5)).abs() < 1e-4);
        // Where the arm meets the ring its curbs have flared out: a point just outside the arm's
        // straight edge, between ring and crosswalk, is road, and so is the crosswalk's middle.
        let a = 0.5 * (ro + arm.crosswalk[0].dot(arm.dir));
        let beside = arm.dir * (ro + 0.6) + arm.normal * (arm.edge_in_m + 0.3);
        assert!(l.on_carriageway(beside), "{}: no flare at {beside:?}", arm.name);
        let mid = arm.crosswalk.iter().fold(Vec2::ZERO, |s, c| s + *c) / 4.0;
        assert!(l.on_carriageway(mid) && l.on_carriageway(arm.dir * a));
    }
    // A pole's place on every corner's sidewalk, off the road.
    assert_eq!(l.corner_posts.len(), l.arms.len());
    for p in &l.corner_posts {
        assert!(l.corner_sidewalks.iter().any(|w| point_in_polygon(*p, w)) && !l.on_carriageway(*p), "{p:?}");
    }
    // The island is a raised block as high as the file says.
    let island = scene.objects.iter().position(|o| o.name == "roundabout/island").unwrap() as u32;
    let top = (0..scene.mesh.triangles.len())
        .filter(|&k| scene.mesh.object[k] == island)
        .flat_map(|k| scene.mesh.triangles[k].iter().map(|v| v.z))
        .fold(f32::MIN, f32::max);
    assert!((top - ring.island_height_m).abs() < 1e-5, "{top}");
}

#[test]
fn a_pole_may_stand_on_the_island_but_not_on_the_ring() {
    let light = |x: f32| format!("\n[[street_lights]]\nposition = [{x}, 0.0]\n");
    assert!(build(&(text() + &light(0.0))).is_ok());
    let e = build(&(text() + &light(17.0))).unwrap_err();
    assert!(e.contains("street_lights[4].position") && e.contains("junction box"), "{e}");
}

#[test]
fn what_the_ring_model_cannot_drive_is_refused_by_name() {
    for (from, to, field, why) in [
        (
            "island_radius_m = 13.5\nring_width_m = 6.5",
            "island_radius_m = 2.0\nring_width_m = 4.0",
            "roundabout.island_radius_m",
            "wider than the ring",
        ),
        ("island_height_m = 1.0", "island_height_m = 0.05", "roundabout.island_height_m", "curb"),
        ("crosswalk_setback_m = 6.0", "crosswalk_setback_m = 1.0", "roundabout.crosswalk_setback_m", "[2, 30]"),
        ("ring_width_m = 6.5", "ring_width_m = 12.0", "roundabout.ring_width_m", "[4, 8]"),
    ] {
        let t = text().replacen(from, to, 1);
        assert_ne!(t, text(), "{from}");
        let e = build(&t).unwrap_err();
        assert!(e.contains(field) && e.contains(why), "{from}: {e}");
    }
    // Two lanes each way, or a left-turn bay: one circulating lane serves every turn.
    let t = text().replacen("lanes_in = 1", "lanes_in = 2", 1);
    let e = build(&t).unwrap_err();
    assert!(e.contains("arms[0].lanes_in") && e.contains("one circulating lane"), "{e}");
    let t = text().replacen("lanes_out = 1\n", "lanes_out = 1\nleft_turn_lanes = 1\n", 1);
    let e = build(&t).unwrap_err();
    assert!(e.contains("arms[0].left_turn_lanes"), "{e}");
    // A ring needs three arms.
    let two: String = text().split("[[arms]]").take(3).collect::<Vec<_>>().join("[[arms]]");
    let rest = &text()[text().find("# Lighting poles").unwrap()..];
    let e = build(&format!("{two}{rest}")).unwrap_err();
    assert!(e.contains("at least three arms"), "{e}");
}
