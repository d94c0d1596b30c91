//! OpenDRIVE import: real junctions (esmini's public maps, `fixtures/opendrive/`) become scenes
//! hilo builds, and what the file gives reaches the scene: each approach's heading against the
//! file's own reference-line headings, its lanes by direction, widths and sidewalks.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_raycast::Scene;
use hilo_raycast::scene::config::SceneConfig;
use hilo_raycast::scene::opendrive::{JunctionPick, import_file, import_str, scene_toml};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/opendrive").join(name)
}

fn build(cfg: &SceneConfig, path: &Path) -> Scene {
    Scene::from_config(cfg.clone(), path.parent().unwrap(), path).unwrap_or_else(|e| panic!("{e}"))
}

/// Signed difference of two headings in degrees, in (-180, 180].
fn turn(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(360.0);
    if d > 180.0 { d - 360.0 } else { d }
}

#[test]
fn a_four_way_junction_keeps_the_files_headings_lanes_and_sidewalks() {
    let path = fixture("fabriksgatan.xodr");
    let imp = import_file(&path, &JunctionPick::id("4")).unwrap();
    let arms = &imp.config.arms;
    assert_eq!(arms.len(), 4);
    // Outward headings from the file's <geometry hdg>: roads 0 and 1 start at the junction
    // (their heading at s = 0), roads 2 and 3 end there (their end heading, reversed); road 2
    // ends on a paramPoly3 whose end heading the first 25 m average only approximately.
    let expected = [("road 0", -77.86, 1.5), ("road 1", 11.06, 0.5), ("road 2", 100.6, 2.0), ("road 3", -171.65, 0.5)];
    for (name, heading, tol) in expected {
        let a = arms.iter().find(|a| a.name == name).unwrap_or_else(|| panic!("no arm {name}: {arms:?}"));
        assert!(turn(a.heading_deg, heading).abs() <= tol, "{name}: {} against {heading}", a.heading_deg);
        assert_eq!((a.lanes_in, a.lanes_out), (1, 1), "{name}");
        assert_eq!(a.lane_width_m, 3.5, "{name}");
        assert_eq!(a.sidewalk_width_m, 2.0, "{name}");
        assert_eq!(a.median_width_m, 0.0, "{name}");
    }
    // No traffic light in this version of the map: a pole at each of the four corners.
    assert_eq!(imp.config.signal_poles.len(), 4);
    assert!(imp.notes.iter().any(|n| n.contains("no traffic light")), "{:?}", imp.notes);
    let scene = build(&imp.config, &path);
    assert_eq!(scene.mounts.len(), 4);
}

#[test]
fn traffic_lights_put_poles_only_at_their_corners() {
    let path = fixture("fabriksgatan_traffic_lights.xodr");
    let imp = import_file(&path, &JunctionPick::id("4")).unwrap();
    let poles = &imp.config.signal_poles;
    assert!(!poles.is_empty() && poles.len() < 4, "{poles:?}");
    assert!(imp.notes.iter().any(|n| n.contains("3 traffic lights")), "{:?}", imp.notes);
    build(&imp.config, &path);
}

/// Braunschweig's signalised junction of two dual carriageways (OpenStreetMap through SUMO's
/// `netconvert`, `fixtures/opendrive/braunschweig/`): each arm's two one-way roads become one
/// divided arm, its heading the mean of the source's two carriageway directions at the junction.
#[test]
fn a_junction_of_dual_carriageways_has_one_divided_arm_per_road() {
    let path = fixture("braunschweig.xodr");
    let imp = import_file(&path, &JunctionPick::id("1")).unwrap();
    let arms = &imp.config.arms;
    assert_eq!(arms.len(), 4, "{arms:?}");
    // The source's (plain edge file's) first segment of each carriageway from the junction:
    // (outbound from, to) and (inbound to, from), in the file's metres.
    let outward = |a: [f32; 2], b: [f32; 2]| (b[1] - a[1]).atan2(b[0] - a[0]).to_degrees();
    let sources = [
        (outward([667.56, 630.86], [688.47, 573.89]), outward([680.27, 633.86], [697.40, 583.69])),
        (outward([680.27, 633.86], [795.92, 677.81]), outward([674.26, 647.56], [713.92, 661.39])),
        (outward([661.98, 644.53], [632.34, 639.49]), outward([667.56, 630.86], [628.17, 626.33])),
        (outward([674.26, 647.56], [662.72, 675.46]), outward([661.98, 644.53], [652.81, 670.46])),
    ];
    for (out_deg, in_deg) in sources {
        let mean = out_deg + 0.5 * turn(in_deg, out_deg);
        let a = arms
            .iter()
            .find(|a| turn(a.heading_deg, mean).abs() <= 2.0)
            .unwrap_or_else(|| panic!("no arm within 2 degrees of {mean}: {arms:?}"));
        assert_eq!((a.lanes_in, a.lanes_out), (2, 2), "{}", a.name);
        assert!((a.lane_width_m - 3.2).abs() < 1e-3, "{}: {}", a.name, a.lane_width_m);
        // The carriageways' centre lines lie 9-14 m apart in the source: medians of 2-8.5 m.
        assert!((2.0..=8.5).contains(&a.median_width_m), "{}: median {}", a.name, a.median_width_m);
        assert!(a.name.contains(" / "), "{}", a.name);
        let note = imp
            .notes
            .iter()
            .find(|n| n.contains("one divided arm") && a.name.starts_with(n.split(" (in)").next().unwrap()));
        assert!(note.is_some_and(|n| n.contains(&format!("{:.2} m", a.median_width_m))), "{note:?}");
    }
    // Every one of the 16 lights is read (netconvert's rounded stop-line `s` stays on its road),
    // and they stand at every approach: a pole at each corner.
    assert!(imp.notes.iter().any(|n| n.contains("16 traffic lights")), "{:?}", imp.notes);
    assert!(!imp.notes.iter().any(|n| n.contains("skipped")), "{:?}", imp.notes);
    assert_eq!(imp.config.signal_poles.len(), 4);
    assert_eq!(
        imp.config.origin.crs.as_deref(),
        Some("+proj=utm +zone=32 +ellps=WGS84 +datum=WGS84 +units=m +no_defs")
    );
    build(&imp.config, &path);
}

/// A signal past its road's end (as a file rounded to fewer digits writes the stop line) is
/// skipped by the reader; the import says so instead of silently placing fewer poles.
#[test]
fn skipped_signals_are_counted_in_the_notes() {
    let path = fixture("braunschweig.xodr");
    let text = std::fs::read_to_string(&path).unwrap();
    let road = text.find("<road name=\"\" length=\"182.7860").expect("road 92's length");
    let at = road + text[road..].find("s=\"182.7860\"").unwrap();
    // The four lights of road 92, moved 1 cm past its end.
    let moved = format!("{}{}", &text[..at], text[at..].replacen("s=\"182.7860\"", "s=\"182.7960\"", 4));
    let imp = import_str(&moved, &path, &JunctionPick::id("1")).unwrap();
    assert!(imp.notes.iter().any(|n| n.contains("4 of the file's 16 signals were skipped")), "{:?}", imp.notes);
}

#[test]
fn every_junction_of_a_town_is_a_site() {
    let path = fixture("multi_intersections.xodr");
    for (id, arms) in [("146", 4), ("148", 3), ("150", 4), ("152", 3), ("154", 3)] {
        let imp = import_file(&path, &JunctionPick::id(id)).unwrap();
        assert_eq!(imp.junction, id);
        assert_eq!(imp.config.arms.len(), arms, "junction {id}");
        let scene = build(&imp.config, &path);
        assert!(!scene.mounts.is_empty(), "junction {id}");
        // The origin is the junction, so the arms meet at the scene's centre.
        assert!(imp.config.origin.x_m.is_finite() && imp.config.origin.y_m.is_finite());
    }
    // Picked by a point: the junction whose centre is nearest, within the radius.
    let at = import_file(&path, &JunctionPick::id("150")).unwrap().config.origin;
    let near = JunctionPick { id: None, near: Some([at.x_m + 3.0, at.y_m - 2.0]), radius_m: Some(30.0) };
    assert_eq!(import_file(&path, &near).unwrap().junction, "150");
    let far = JunctionPick { id: None, near: Some([at.x_m + 5_000.0, at.y_m]), radius_m: Some(30.0) };
    let e = import_file(&path, &far).unwrap_err().to_string();
    assert!(e.contains("no junction centre within 30 m") && e.contains("146"), "{e}");
}

#[test]
fn the_written_scene_file_reads_back_and_says_what_was_assumed() {
    let path = fixture("multi_intersections.xodr");
    let imp = import_file(&path, &JunctionPick::id("146")).unwrap();
    let text = scene_toml(&imp, &path).unwrap();
    assert!(text.starts_with("# Imported by `hilo scene import`"), "{text}");
    for n in &imp.notes {
        assert!(text.contains(n.as_str()), "{n}");
    }
    let back = SceneConfig::from_toml_str(&text, Path::new("scene.toml")).unwrap();
    assert!(imp.config.connections.iter().any(|c| !c.path.is_empty()), "the file's curves are kept");
    assert_eq!(back, imp.config);
    // A source path with line breaks and other control characters stays inside its comment.
    let odd = scene_toml(&imp, Path::new("a\nname = \"x\"\r\u{7}.xodr")).unwrap();
    assert_eq!(SceneConfig::from_toml_str(&odd, Path::new("scene.toml")).unwrap(), imp.config);
}

#[test]
fn a_junction_not_in_the_file_or_a_broken_file_is_named() {
    let path = fixture("multi_intersections.xodr");
    let e = import_file(&path, &JunctionPick::id("999")).unwrap_err().to_string();
    assert!(
        e.contains("multi_intersections.xodr") && e.contains("999") && e.contains("146, 148, 150, 152, 154"),
        "{e}"
    );
    let both = JunctionPick { id: Some("146".into()), near: Some([0.0, 0.0]), radius_m: None };
    let e = import_file(&path, &both).unwrap_err().to_string();
    assert!(e.contains("either id or near"), "{e}");
    let e = import_str("<OpenDRIVE><road", Path::new("bad.xodr"), &JunctionPick::id("1")).unwrap_err().to_string();
    assert!(e.contains("bad.xodr") && e.contains("OpenDRIVE"), "{e}");
    // A file that is not a regular file is refused before it is read.
    let e = import_file(Path::new("/dev/zero"), &JunctionPick::id("1")).unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
}

/// Truncated and mutated files give a clear error or a scene, never a panic; a file without a
/// junction is refused by name.
#[test]
fn broken_files_are_errors_not_panics() {
    let path = fixture("fabriksgatan_traffic_lights.xodr");
    let text = std::fs::read_to_string(&path).unwrap();
    let pick = JunctionPick::id("4");
    let cuts = (1..40).map(|k| text.len() * k / 40);
    for cut in cuts.filter(|&c| text.is_char_boundary(c)) {
        let _ = import_str(&text[..cut], &path, &pick);
    }
    // Numbers and ids changed one at a time (a seeded walk over the file's digits).
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let digits: Vec<usize> = text.char_indices().filter(|(_, c)| c.is_ascii_digit()).map(|(i, _)| i).collect();
    for _ in 0..60 {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        let at = digits[(seed % digits.len() as u64) as usize];
        let mut bytes = text.clone().into_bytes();
        bytes[at] = [b'-', b'9', b'e', b'0', b'.'][(seed >> 32) as usize % 5];
        let mutated = String::from_utf8(bytes).unwrap();
        if let Ok(imp) = import_str(&mutated, &path, &pick) {
            // What imports either builds or is refused with the file named.
            if let Err(e) = Scene::from_config(imp.config, path.parent().unwrap(), &path) {
                assert!(e.to_string().contains("fabriksgatan"), "{e}");
            }
        }
    }
    let one_road = r#"<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6"/>
<road id="1" junction="-1" length="50"><planView><geometry s="0" x="0" y="0" hdg="0" length="50"><line/></geometry></planView>
<lanes><laneSection s="0"><center><lane id="0" type="none"/></center>
<right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right></laneSection></lanes></road></OpenDRIVE>"#;
    let e = import_str(one_road, Path::new("road.xodr"), &pick).unwrap_err().to_string();
    assert!(e.contains("road.xodr") && e.contains("junction"), "{e}");
}

/// An imported site of the library with its map: the map's path and text, the site's scene and
/// the scene's origin in the map's frame.
fn imported_site(site: &str, map: &str) -> (PathBuf, String, Scene, glam::Vec2) {
    let path = fixture(map);
    let xml = std::fs::read_to_string(&path).unwrap();
    let scene = Scene::load(&fixture("../sites").join(site)).unwrap();
    let origin = glam::Vec2::new(scene.config.origin.x_m as f32, scene.config.origin.y_m as f32);
    (path, xml, scene, origin)
}

/// Import fidelity: the lanes of each imported site stand, within 20 m of the junction's centre
/// (out of its box), within 0.05 m of the file's own lane centre lines at the esmini maps and
/// within 0.15 m at Braunschweig, whose roads bend there (the arms are straight along each road's
/// first 25 m). Before the arms kept the file's lateral positions, Fabriksgatan's lanes stood
/// 0.18 m off and Braunschweig's 1.39 m.
#[test]
fn imported_lanes_stand_where_the_file_draws_them() {
    use hilo_raycast::scene::opendrive::lane_deviations;
    for (site, map, junction, tolerance_m) in [
        ("fabriksgatan.toml", "fabriksgatan_traffic_lights.xodr", "4", 0.05),
        ("three_arm_grid.toml", "multi_intersections.xodr", "150", 0.05),
        ("braunschweig.toml", "braunschweig.xodr", "1", 0.15),
    ] {
        let (path, xml, scene, origin) = imported_site(site, map);
        let all = lane_deviations(&xml, &path, junction, &scene.layout, origin, &[20.0]).unwrap();
        let lanes_in_scene: usize =
            scene.config.arms.iter().map(|a| (a.lanes_in + a.lanes_out + a.left_turn_lanes) as usize).sum();
        assert_eq!(all.len(), lanes_in_scene, "{site}: every lane of the file's approaches is measured");
        for d in &all {
            assert!(d.worst_m[0] <= tolerance_m, "{site}: road {} stands {} m off", d.road, d.worst_m[0]);
        }
    }
}

/// Import fidelity of the road edges: the border of each approach's driving lanes on the curb
/// side (and on the median side of a divided arm) stands, within 20 m of the junction's centre
/// (out of its box), within 0.05 m of the scene's road edge at the esmini maps and within
/// 0.15 m at Braunschweig, as the lanes do; every road's curbs are measured, both ways.
#[test]
fn imported_road_edges_stand_where_the_file_draws_them() {
    use hilo_raycast::scene::opendrive::{RoadEdge, edge_deviations};
    for (site, map, junction, tolerance_m, medians) in [
        ("fabriksgatan.toml", "fabriksgatan_traffic_lights.xodr", "4", 0.05, 0),
        ("three_arm_grid.toml", "multi_intersections.xodr", "150", 0.05, 0),
        ("braunschweig.toml", "braunschweig.xodr", "1", 0.15, 8),
    ] {
        let (path, xml, scene, origin) = imported_site(site, map);
        let all = edge_deviations(&xml, &path, junction, &scene.layout, origin, &[20.0]).unwrap();
        let ways: usize =
            scene.config.arms.iter().map(|a| usize::from(a.lanes_in > 0) + usize::from(a.lanes_out > 0)).sum();
        let curbs = all.iter().filter(|d| d.edge == RoadEdge::Curb).count();
        assert_eq!(curbs, ways, "{site}: one curb per road and way");
        assert_eq!(all.len() - curbs, medians, "{site}: median edges");
        for d in &all {
            assert!(
                d.worst_m[0] <= tolerance_m,
                "{site}: road {} ({:?}, in {}) stands {} m off",
                d.road,
                d.edge,
                d.into,
                d.worst_m[0]
            );
        }
    }
}

/// The road-edge measure is not blind: a scene whose inbound curbs stand 0.3 m out, or whose
/// medians are 0.4 m wider, is measured that far off.
#[test]
fn a_moved_road_edge_is_measured() {
    use hilo_raycast::scene::opendrive::{RoadEdge, edge_deviations};
    let (path, xml, scene, origin) = imported_site("braunschweig.toml", "braunschweig.xodr");
    let base = edge_deviations(&xml, &path, "1", &scene.layout, origin, &[20.0]).unwrap();
    let mut moved = scene.layout.clone();
    for arm in &mut moved.arms {
        arm.edge_in_m += 0.3;
        arm.median_half_width_m += 0.2;
    }
    let off = edge_deviations(&xml, &path, "1", &moved, origin, &[20.0]).unwrap();
    assert_eq!(base.len(), off.len());
    for (b, o) in base.iter().zip(&off) {
        let grew = o.worst_m[0] - b.worst_m[0];
        let (lo, hi) = match (b.edge, b.into) {
            (RoadEdge::Curb, true) => (0.3 - 2.0 * b.worst_m[0], 0.3 + 1e-3),
            (RoadEdge::Curb, false) => (-1e-3, 1e-3),
            (RoadEdge::Median, _) => (0.2 - 2.0 * b.worst_m[0], 0.2 + 1e-3),
        };
        assert!(
            (lo..=hi).contains(&grew),
            "road {} {:?} in {}: {} -> {}",
            b.road,
            b.edge,
            b.into,
            b.worst_m[0],
            o.worst_m[0]
        );
    }
}

/// A junction's `<controller>`s become its signal groups where they form phases hilo can run:
/// esmini's five junctions each list theirs (every one a phase of one arm or two facing arms);
/// a `sequence` reorders them; a controller made to switch a crossing arm as well, or lights
/// of three arms at once, is read as no phasing, and the notes say why.
#[test]
fn a_junctions_controllers_are_its_signal_groups_where_they_can_run() {
    let path = fixture("multi_intersections.xodr");
    let xml = std::fs::read_to_string(&path).unwrap();
    let groups = |xml: &str| {
        let imp = import_str(xml, &path, &JunctionPick::id("150")).unwrap();
        let note = imp.notes.iter().find(|n| n.contains("phases") || n.contains("signal groups")).cloned();
        (imp.config.signal_groups, note.unwrap_or_default())
    };
    let pair = |a: &str, b: &str| vec![a.to_owned(), b.to_owned()];
    let (g, note) = groups(&xml);
    assert_eq!(g, vec![pair("road 242", "road 235"), pair("road 229", "road 230")], "{note}");
    assert!(note.contains("4 controller(s)"), "{note}");
    for id in ["146", "148", "152", "154"] {
        let imp = import_file(&path, &JunctionPick::id(id)).unwrap();
        let scene = build(&imp.config, &path);
        assert!(!scene.layout.signal_groups.is_empty(), "junction {id}: {:?}", imp.notes);
    }
    // Controller 13 (roads 229 and 230) first by its sequence.
    let seq = xml
        .replacen(r#"<controller id="12" type="0"/>"#, r#"<controller id="12" type="0" sequence="2"/>"#, 1)
        .replacen(r#"<controller id="13" type="0"/>"#, r#"<controller id="13" type="0" sequence="1"/>"#, 1);
    assert_eq!(groups(&seq).0, vec![pair("road 229", "road 230"), pair("road 242", "road 235")]);
    // Controller 12 also switching one of road 229's lights: three arms on one green.
    let three = xml.replacen(r#"<control signalId="18474" type="0" />"#, r#"<control signalId="15440" type="0" />"#, 1);
    assert_ne!(three, xml);
    let (g, note) = groups(&three);
    assert!(g.is_empty() && note.contains("3 arms at once") && note.contains("pairs opposing arms"), "{note}");
}
