//! A scene's lane graph (`[[connections]]`): vehicles drive the movements it lists and no
//! others, each from its inbound lane to its outbound lane; the imported real junctions list
//! their OpenDRIVE file's connections, and every connecting lane of the file is followed by one
//! of the scene's routes (and every route follows one), measured against the parser's own
//! samples; where a file's lane graph is what hilo's own rules would draw, the routes are the
//! rules' routes, in their order.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec2;
use hilo_dataset::traffic::routes::{Movement, Route, build_routes, spawned_movement};
use hilo_raycast::Scene;
use hilo_raycast::scene::config::SceneConfig;
use hilo_raycast::scene::layout::LaneKind;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The imported sites: scene file, map and junction.
const IMPORTED: [(&str, &str, &str); 3] = [
    ("fixtures/sites/fabriksgatan.toml", "fixtures/opendrive/fabriksgatan_traffic_lights.xodr", "4"),
    ("fixtures/sites/three_arm_grid.toml", "fixtures/opendrive/multi_intersections.xodr", "150"),
    ("fixtures/sites/braunschweig.toml", "fixtures/opendrive/braunschweig.xodr", "1"),
];

fn same_routes(a: &[Route], b: &[Route]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            (x.approach, x.exit, x.movement) == (y.approach, y.exit, y.movement) && x.path.points == y.path.points
        })
}

#[test]
fn a_lane_graph_equal_to_the_rules_drives_the_rules_routes() {
    for (site, _, _) in IMPORTED {
        let scene = Scene::load(&root().join(site)).unwrap();
        assert!(!scene.layout.connections.is_empty(), "{site}: no lane graph");
        let with = build_routes(&scene.layout);
        assert_eq!(with.len(), scene.layout.connections.len(), "{site}: one route per connection");
        // The file's curves through the junction set aside, hilo draws the same routes.
        let mut undrawn = scene.layout.clone();
        undrawn.connections.iter_mut().for_each(|c| c.path.clear());
        let mut rules = scene.layout.clone();
        rules.connections.clear();
        let without = build_routes(&rules);
        assert!(same_routes(&build_routes(&undrawn), &without), "{site}: the file's lane graph is the rules' here");
        let movements = |rs: &[Route]| rs.iter().map(|r| (r.approach, r.exit, r.movement)).collect::<Vec<_>>();
        assert_eq!(movements(&with), movements(&without), "{site}: the same movements in the same order");
    }
}

/// The index of `lane` among the lanes of its kind on `arm`.
fn lane_index(scene: &Scene, arm: usize, kind: LaneKind, at: Vec2, end: bool) -> usize {
    let lanes = scene.layout.arms[arm].lanes.iter().filter(|l| l.kind == kind);
    lanes.clone().position(|l| (if end { l.end } else { l.start }).distance(at) < 1e-3).unwrap()
}

/// A connection that draws its way through the junction is driven along it. The rules' routes
/// of the default intersection, their curves through the junction given back as the
/// connections' paths, come back as the same routes: the same start, stop line and end, every
/// sample within 0.3 m of the drawn route and back (the curve is resampled every 0.5 m), and the
/// arc length where the route leaves the exit crosswalk within two samples. A path that begins
/// on the inbound lane behind the stop line is driven from the stop line all the same.
#[test]
fn a_connection_drawn_through_the_junction_is_driven_along_its_curve() {
    use hilo_dataset::traffic::routes::DS;
    use hilo_raycast::scene::layout::Connection;
    let scene = Scene::load(&root().join("fixtures/intersection.toml")).unwrap();
    let rules = build_routes(&scene.layout);
    let drawn_as = |lead_m: f32| {
        let mut layout = scene.layout.clone();
        layout.connections = rules
            .iter()
            .map(|r| {
                let (first, last) = (r.path.points[0], *r.path.points.last().unwrap());
                // A left turn from a bay starts on the innermost inbound lane.
                let from_lane = lane_index(&scene, r.approach, LaneKind::Inbound, first, false);
                let to_lane = lane_index(&scene, r.exit, LaneKind::Outbound, last, true);
                let (k0, k1) = ((r.stop_s / DS).ceil() as usize, (r.clear_s / DS).floor() as usize);
                let (stop, h) = r.path.at(r.stop_s);
                let mut path: Vec<Vec2> =
                    (1..=(lead_m / DS) as usize).rev().map(|k| stop - h * (k as f32 * DS)).collect();
                path.extend_from_slice(&r.path.points[k0..=k1]);
                Connection { from: r.approach, from_lane, to: r.exit, to_lane, path }
            })
            .collect();
        build_routes(&layout)
    };
    let along = drawn_as(0.0);
    assert_eq!(along.len(), rules.len());
    for (a, r) in along.iter().zip(&rules) {
        assert_eq!((a.approach, a.exit, a.movement), (r.approach, r.exit, r.movement));
        assert_eq!(a.stop_s, r.stop_s, "the stop line stays where the lane puts it");
        assert!(a.path.points[0].distance(r.path.points[0]) < 1e-4);
        assert!(a.path.points.last().unwrap().distance(*r.path.points.last().unwrap()) < 1e-4);
        let (there, back) = (farthest(&a.path.points, &r.path.points), farthest(&r.path.points, &a.path.points));
        assert!(there < 0.3 && back < 0.3, "{:?} {} -> {}: {there} / {back}", r.movement, r.approach, r.exit);
        assert!((a.clear_s - r.clear_s).abs() <= 2.0 * DS, "{:?}: {} vs {}", r.movement, a.clear_s, r.clear_s);
        assert_eq!(a.crosswalks.len(), r.crosswalks.len());
    }
    let behind = drawn_as(6.0);
    assert!(same_routes(&behind, &along), "a path's points behind the stop line are not driven");
}

/// A connection as listed: from arm, its lane, to arm, its lane.
type Listed = (String, u32, String, u32);

/// The default intersection with a lane graph of its own (every lane straight on, the
/// outermost also right, the innermost also left by its bay) in which the arms `no_left` may
/// not turn left.
fn with_lane_graph(no_left: &[&str]) -> (Scene, Vec<Listed>, tempfile::TempDir) {
    let text = std::fs::read_to_string(root().join("fixtures/intersection.toml")).unwrap();
    let arms = ["east", "north", "west", "south"];
    let mut extra = String::new();
    let mut listed = Vec::new();
    for (i, from) in arms.iter().enumerate() {
        // Driving in from the east (westward), the left turn leads south.
        let right = arms[(i + 1) % 4];
        let ahead = arms[(i + 2) % 4];
        let left = arms[(i + 3) % 4];
        let mut add = |to: &str, from_lane: u32, to_lane: u32| {
            extra.push_str(&format!(
                "\n[[connections]]\nfrom = \"{from}\"\nfrom_lane = {from_lane}\nto = \"{to}\"\nto_lane = {to_lane}\n"
            ));
            listed.push((from.to_string(), from_lane, to.to_string(), to_lane));
        };
        for k in 0..3 {
            add(ahead, k, k);
        }
        add(right, 2, 2);
        if !no_left.contains(from) {
            add(left, 0, 0);
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("scene.toml");
    std::fs::write(&file, format!("{text}{extra}")).unwrap();
    (Scene::load(&file).unwrap(), listed, dir)
}

/// North's traffic may not turn left; every other arm keeps its left turn from its innermost
/// lane (by its bay) and every arm its right turn from its outermost.
#[test]
fn a_junction_drives_only_the_movements_its_lane_graph_allows() {
    let (scene, listed, _dir) = with_lane_graph(&["north"]);
    let layout = &scene.layout;
    let routes = build_routes(layout);
    assert_eq!(routes.len(), listed.len());
    let index = |n: &str| layout.arms.iter().position(|a| a.name == n).unwrap();
    let north = index("north");
    assert!(routes.iter().all(|r| !(r.approach == north && r.movement == Movement::Left)));
    assert_eq!(spawned_movement(&routes, north, Movement::Left), Some(Movement::Through), "no left: straight on");
    assert_eq!(spawned_movement(&routes, index("east"), Movement::Left), Some(Movement::Left));
    // Each route starts on its inbound lane (a left turn in its bay) and ends on its outbound lane.
    for (from, from_lane, to, to_lane) in &listed {
        let (i, j) = (index(from), index(to));
        let ins: Vec<_> = layout.arms[i].lanes.iter().filter(|l| l.kind == LaneKind::Inbound).collect();
        let outs: Vec<_> = layout.arms[j].lanes.iter().filter(|l| l.kind == LaneKind::Outbound).collect();
        let start = ins[*from_lane as usize].start;
        let end = outs[*to_lane as usize].end;
        let found = routes
            .iter()
            .filter(|r| r.approach == i && r.exit == j)
            .any(|r| r.path.points[0].distance(start) < 1e-3 && r.path.points.last().unwrap().distance(end) < 1e-3);
        assert!(found, "{from} lane {from_lane} -> {to} lane {to_lane}: no route");
    }
    // A dataset's fingerprint reads the scene's Debug text: a lane graph is in it, and a scene
    // without one reads as before scenes could list one.
    assert!(format!("{:?}", scene.config).contains("connections"));
    let plain = Scene::load(&root().join("fixtures/intersection.toml")).unwrap();
    assert!(!format!("{:?}", plain.config).contains("connections"));
    // The rules would have given north a left turn: the lane graph took it away.
    let mut rules = layout.clone();
    rules.connections.clear();
    assert!(build_routes(&rules).iter().any(|r| r.approach == north && r.movement == Movement::Left));
}

/// The signal runs a protected left only for arms the lane graph turns left from: with no left
/// turn from north or south (opposing arms, one phase), their phase has no left arrow while east
/// and west keep theirs; with the left turns of the rules, every phase has one.
#[test]
fn a_left_arrow_runs_only_where_the_lane_graph_turns_left() {
    use hilo_dataset::traffic::TrafficConfig;
    use hilo_dataset::traffic::signal::plan_for;
    let cfg = TrafficConfig::default().signal;
    let (scene, _, _dir) = with_lane_graph(&["north", "south"]);
    let plan = plan_for(&scene.layout, &cfg);
    let index = |n: &str| scene.layout.arms.iter().position(|a| a.name == n).unwrap();
    for (arm, arrow) in [("north", false), ("south", false), ("east", true), ("west", true)] {
        assert_eq!(plan.phase(index(arm)).left_s > 0.0, arrow, "{arm}");
    }
    let (all, _, _dir) = with_lane_graph(&[]);
    let plan = plan_for(&all.layout, &cfg);
    let rules = plan_for(&Scene::load(&root().join("fixtures/intersection.toml")).unwrap().layout, &cfg);
    for a in 0..4 {
        assert!(plan.phase(a).left_s > 0.0);
        assert_eq!(plan.phase(a), rules.phase(a));
    }
}

#[test]
fn a_lane_graph_that_names_what_the_scene_lacks_is_refused_by_field() {
    let text = std::fs::read_to_string(root().join("fixtures/intersection.toml")).unwrap();
    let err = |c: &str| {
        let t = format!("{text}\n[[connections]]\n{c}\n");
        SceneConfig::from_toml_str(&t, Path::new("scene.toml")).unwrap_err().to_string()
    };
    let e = err("from = \"east\"\nfrom_lane = 0\nto = \"nowhere\"\nto_lane = 0");
    assert!(e.contains("connections[0].to") && e.contains("nowhere") && e.contains("east, north"), "{e}");
    let e = err("from = \"east\"\nfrom_lane = 3\nto = \"west\"\nto_lane = 0");
    assert!(e.contains("connections[0].from_lane") && e.contains("3 inbound lane"), "{e}");
    let e = err("from = \"east\"\nfrom_lane = 0\nto = \"west\"\nto_lane = 7");
    assert!(e.contains("connections[0].to_lane"), "{e}");
    let e = err("from = \"east\"\nfrom_lane = 0\nto = \"east\"\nto_lane = 0");
    assert!(e.contains("U-turn"), "{e}");
    let way = "from = \"east\"\nfrom_lane = 0\nto = \"west\"\nto_lane = 0\npath = ";
    let e = err(&format!("{way}[[1.0, 2.0]]"));
    assert!(e.contains("connections[0].path") && e.contains("2 to"), "{e}");
    let e = err(&format!("{way}[[1.0, 2.0], [nan, 0.0]]"));
    assert!(e.contains("connections[0].path[1]") && e.contains("finite"), "{e}");
    let e = err(&format!("{way}[[1.0, 2.0], [900.0, 2.0]]"));
    assert!(e.contains("connections[0].path") && e.contains("off the ground"), "{e}");
    let twice = "from = \"east\"\nfrom_lane = 0\nto = \"west\"\nto_lane = 0\n";
    let e = err(&format!("{twice}\n[[connections]]\n{twice}"));
    assert!(e.contains("connections[1]") && e.contains("listed twice"), "{e}");
    let ring = std::fs::read_to_string(root().join("fixtures/sites/roundabout.toml")).unwrap();
    let t = format!("{ring}\n[[connections]]\nfrom = \"a\"\nfrom_lane = 0\nto = \"b\"\nto_lane = 0\n");
    let e = SceneConfig::from_toml_str(&t, Path::new("ring.toml")).unwrap_err().to_string();
    assert!(e.contains("connections") && e.contains("ring"), "{e}");
}

/// The largest distance from any of `pts` to the polyline `path` (to its nearest segment).
fn farthest(pts: &[Vec2], path: &[Vec2]) -> f32 {
    let to_segment = |p: Vec2, a: Vec2, b: Vec2| {
        let ab = b - a;
        let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
        p.distance(a + ab * t)
    };
    let to_path = |p: &Vec2| match path {
        [q] => p.distance(*q),
        _ => path.windows(2).map(|w| to_segment(*p, w[0], w[1])).fold(f32::INFINITY, f32::min),
    };
    pts.iter().map(to_path).fold(0.0, f32::max)
}

/// Every connecting lane of each imported junction (a lane of the junction whose predecessor
/// is a driving lane into it and whose successor a driving lane out of it) runs near the route
/// that leaves its predecessor's arm for its successor's, over its whole centre line as the
/// parser samples it; and that route, over the lane's span, near it: within 0.3 m (the route's
/// samples nearest the lane's ends may lie a quarter metre past them). The scene keeps the
/// file's curve for every movement of the library's imported sites, right turns included, since
/// the import rounds each corner as the file's right turn goes round it. The figures print.
#[test]
fn each_connecting_lane_of_the_file_is_driven_by_a_route() {
    for (site, map, junction) in IMPORTED {
        let scene = Scene::load(&root().join(site)).unwrap();
        let cfg = &scene.config;
        let origin = Vec2::new(cfg.origin.x_m as f32, cfg.origin.y_m as f32);
        let routes = build_routes(&scene.layout);
        let net = xodr::load_str(&std::fs::read_to_string(root().join(map)).unwrap()).unwrap();
        let in_junction = |id: xodr::LaneId| {
            net.road_lane(id).and_then(|rl| net.road(rl.road)).and_then(|r| r.junction().map(str::to_owned))
        };
        let driving_outside = |id: &xodr::LaneId| {
            net.lane(*id).is_some_and(|l| l.kind == xodr::LaneType::Driving) && in_junction(*id).is_none()
        };
        // The arm a lane outside the junction lies along: its point farthest from the centre.
        let arm_of = |id: &xodr::LaneId| {
            let l = net.lane(*id).unwrap();
            let far = l
                .center
                .points()
                .iter()
                .map(|p| Vec2::new(p.x, p.y) - origin)
                .fold(Vec2::ZERO, |a, b| if b.length() > a.length() { b } else { a });
            let u = far.normalize_or_zero();
            (0..scene.layout.arms.len())
                .min_by(|&a, &b| {
                    (u - scene.layout.arms[a].dir).length().total_cmp(&(u - scene.layout.arms[b].dir).length())
                })
                .unwrap()
        };
        // The arm pairs whose every connection follows the file's curve.
        let own: HashSet<(usize, usize)> = scene
            .layout
            .connections
            .iter()
            .map(|c| (c.from, c.to))
            .filter(|&(i, j)| scene.layout.connections.iter().all(|c| (c.from, c.to) != (i, j) || !c.path.is_empty()))
            .collect();
        let (mut worst_file, mut worst_route) = (0.0f32, 0.0f32);
        let mut pairs = HashSet::new();
        let mut n = 0;
        for l in net.lanes().iter().filter(|l| l.kind == xodr::LaneType::Driving) {
            if in_junction(l.id).as_deref() != Some(junction) {
                continue;
            }
            let (Some(from), Some(to)) =
                (l.predecessors.iter().find(|p| driving_outside(p)), l.successors.iter().find(|s| driving_outside(s)))
            else {
                continue;
            };
            let (i, j) = (arm_of(from), arm_of(to));
            if i == j {
                continue;
            }
            let pts: Vec<Vec2> = l.center.points().iter().map(|p| Vec2::new(p.x, p.y) - origin).collect();
            let best = routes
                .iter()
                .filter(|r| r.approach == i && r.exit == j)
                .map(|r| {
                    // The route over the lane's span: from its sample nearest the lane's first
                    // point to the one nearest its last.
                    let nearest = |q: Vec2| {
                        (0..r.path.points.len())
                            .min_by(|&a, &b| r.path.points[a].distance(q).total_cmp(&r.path.points[b].distance(q)))
                            .unwrap()
                    };
                    let (a, b) = (nearest(pts[0]), nearest(pts[pts.len() - 1]));
                    let inside = &r.path.points[a.min(b)..=a.max(b)];
                    (farthest(&pts, &r.path.points), farthest(inside, &pts))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let Some((to_route, to_file)) = best else {
                panic!("{site}: the file connects {} to {}; no route does", i, j)
            };
            worst_file = worst_file.max(to_route);
            worst_route = worst_route.max(to_file);
            pairs.insert((i, j));
            n += 1;
        }
        let driven: HashSet<(usize, usize)> = routes.iter().map(|r| (r.approach, r.exit)).collect();
        println!(
            "{site}: {n} connecting lanes, {} of {} arm pairs along the file's curves: file to route at most \
             {worst_file:.2} m, route to file at most {worst_route:.2} m",
            own.len(),
            pairs.len()
        );
        assert!(n >= 4, "{site}: {n} connecting lanes");
        assert_eq!(pairs, driven, "{site}: the arms the file connects are the arms the routes connect");
        // Every movement, right turns round the rounded corners included, keeps the file's curve.
        assert_eq!(own, pairs, "{site}: an arm pair whose turn hilo draws");
        assert!(worst_file <= 0.3 && worst_route <= 0.3, "{site}: {worst_file} / {worst_route}");
    }
}
