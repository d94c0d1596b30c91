//! A scene's signal groups (`signal_groups`): the phases run the arms the scene groups, in its
//! order; an imported junction's groups come from its OpenDRIVE controllers, and where they are
//! the pairs hilo would form, the plan is hilo's to the second; groups that could not run (an
//! unknown arm, an arm twice or in none, crossing arms on one green, at a roundabout) are
//! refused by field; an exit arm, with no inbound lane, has no phase.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_dataset::traffic::TrafficConfig;
use hilo_dataset::traffic::routes::Movement;
use hilo_dataset::traffic::signal::{Light, SignalPlan, plan_for};
use hilo_raycast::Scene;
use hilo_raycast::scene::config::SceneConfig;
use hilo_raycast::scene::layout::Layout;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

const MOVES: [Movement; 3] = [Movement::Left, Movement::Through, Movement::Right];

/// Whether two plans show every movement of every arm, and every crosswalk, the same light
/// every quarter second over two cycles.
fn same_plan(a: &SignalPlan, b: &SignalPlan, arms: usize) -> bool {
    a.cycle_s() == b.cycle_s()
        && (0..(8.0 * a.cycle_s()) as usize).all(|k| {
            let t = 0.25 * k as f64;
            (0..arms)
                .all(|i| MOVES.iter().all(|&m| a.light(i, m, t) == b.light(i, m, t)) && a.walk(i, t) == b.walk(i, t))
        })
}

fn arm(layout: &Layout, name: &str) -> usize {
    layout.arms.iter().position(|a| a.name == name).unwrap()
}

/// The default intersection with `groups` put first in its file.
fn with_groups(groups: &str) -> Result<SceneConfig, String> {
    let text = std::fs::read_to_string(root().join("fixtures/intersection.toml")).unwrap();
    SceneConfig::from_toml_str(&format!("signal_groups = {groups}\n{text}"), Path::new("scene.toml"))
        .map_err(|e| e.to_string())
}

fn scene(cfg: SceneConfig) -> Scene {
    Scene::from_config(cfg, &root().join("fixtures"), Path::new("scene.toml")).unwrap()
}

#[test]
fn the_esmini_grids_controllers_give_the_pairs_hilo_would_form() {
    let cfg = TrafficConfig::default().signal;
    let grid = Scene::load(&root().join("fixtures/sites/three_arm_grid.toml")).unwrap();
    let l = &grid.layout;
    assert_eq!(
        l.signal_groups,
        vec![vec![arm(l, "road 242"), arm(l, "road 235")], vec![arm(l, "road 229"), arm(l, "road 230")]]
    );
    let mut pairs = l.clone();
    pairs.signal_groups.clear();
    assert!(same_plan(&plan_for(l, &cfg), &plan_for(&pairs, &cfg), l.arms.len()));
    // Neither of the other imported junctions lists a controller: hilo's pairs run them.
    for site in ["fabriksgatan.toml", "braunschweig.toml"] {
        assert!(Scene::load(&root().join("fixtures/sites").join(site)).unwrap().layout.signal_groups.is_empty());
    }
}

#[test]
fn a_scenes_own_groups_run_in_its_order() {
    let cfg = TrafficConfig::default().signal;
    let plain = Scene::load(&root().join("fixtures/intersection.toml")).unwrap();
    // Its own pairs, listed: the same plan.
    let listed = scene(with_groups(r#"[["east", "west"], ["north", "south"]]"#).unwrap());
    let n = plain.layout.arms.len();
    assert!(same_plan(&plan_for(&plain.layout, &cfg), &plan_for(&listed.layout, &cfg), n));
    // The pairs the other way round: north and south first.
    let swapped = scene(with_groups(r#"[["north", "south"], ["east", "west"]]"#).unwrap());
    let (l, p) = (&swapped.layout, plan_for(&swapped.layout, &cfg));
    let t = p.phase(arm(l, "north")).left_s + 1.0;
    assert_eq!(p.light(arm(l, "north"), Movement::Through, t), Light::Green { protected: true });
    assert_eq!(p.light(arm(l, "east"), Movement::Through, t), Light::Red);
    assert!(!same_plan(&p, &plan_for(&plain.layout, &cfg), n));
    // Split phasing: each arm alone, so its left turns go unopposed all green long, and the
    // cycle holds four phases.
    let split = scene(with_groups(r#"[["north"], ["east"], ["south"], ["west"]]"#).unwrap());
    let (l, p) = (&split.layout, plan_for(&split.layout, &cfg));
    let north = p.phase(arm(l, "north"));
    assert!(!north.opposed);
    let t = north.left_s + 0.5 * north.green_s;
    assert_eq!(p.light(arm(l, "north"), Movement::Left, t), Light::Green { protected: true });
    for other in ["east", "south", "west"] {
        assert_eq!(p.light(arm(l, other), Movement::Through, t), Light::Red, "{other}");
    }
    let whole: f64 = ["north", "east", "south", "west"]
        .iter()
        .map(|a| {
            let f = p.phase(arm(l, a));
            f.left_s + f.green_s + f.yellow_s + f.all_red_s
        })
        .sum();
    assert!((p.cycle_s() - whole).abs() < 1e-9, "{} against {whole}", p.cycle_s());
}

#[test]
fn groups_that_cannot_run_are_refused_by_field() {
    let e = with_groups(r#"[["east", "west"], ["north", "nowhere"]]"#).unwrap_err();
    assert!(e.contains("signal_groups[1]") && e.contains("nowhere") && e.contains("east, north"), "{e}");
    let e = with_groups(r#"[["east", "west"], ["north", "south"], ["east"]]"#).unwrap_err();
    assert!(e.contains("signal_groups[2]") && e.contains("another group"), "{e}");
    let e = with_groups(r#"[["east", "north"], ["west", "south"]]"#).unwrap_err();
    assert!(e.contains("signal_groups[0]") && e.contains("cross"), "{e}");
    let e = with_groups(r#"[["east", "west", "north"], ["south"]]"#).unwrap_err();
    assert!(e.contains("signal_groups[0]") && e.contains("one arm or two"), "{e}");
    let e = with_groups(r#"[[], ["east", "west"], ["north", "south"]]"#).unwrap_err();
    assert!(e.contains("signal_groups[0]"), "{e}");
    let e = with_groups(r#"[["east", "west"], ["north"]]"#).unwrap_err();
    assert!(e.contains("south") && e.contains("in no group"), "{e}");
    let text = std::fs::read_to_string(root().join("fixtures/sites/roundabout.toml")).unwrap();
    let e = SceneConfig::from_toml_str(&format!("signal_groups = [[\"north\"]]\n{text}"), Path::new("r.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("signal_groups") && e.contains("roundabout"), "{e}");
}

/// An arm that only leads out of the junction has no phase: its opposite runs alone (its left
/// turns unopposed), pedestrians cross it whenever another arm has green, and listing it in a
/// group is refused.
#[test]
fn an_exit_arm_has_no_phase() {
    let cfg = TrafficConfig::default().signal;
    let mut c = SceneConfig::from_toml_str(
        &std::fs::read_to_string(root().join("fixtures/intersection.toml")).unwrap(),
        Path::new("scene.toml"),
    )
    .unwrap();
    let west = c.arms.iter_mut().find(|a| a.name == "west").unwrap();
    west.lanes_in = 0;
    west.left_turn_lanes = 0;
    west.left_turn_bay_length_m = 0.0;
    let s = scene(c.clone());
    let (l, p) = (&s.layout, plan_for(&s.layout, &cfg));
    assert!(!p.phase(arm(l, "east")).opposed);
    assert!(p.phase(arm(l, "north")).opposed);
    let walks = (0..(4.0 * p.cycle_s()) as usize).filter(|&k| p.walk(arm(l, "west"), 0.25 * k as f64).is_some());
    let greens = (0..(4.0 * p.cycle_s()) as usize).filter(|&k| {
        let t = 0.25 * k as f64;
        ["east", "north", "south"]
            .iter()
            .any(|a| p.light(arm(l, a), Movement::Through, t) == Light::Green { protected: true })
    });
    assert_eq!(walks.count(), greens.count());
    c.signal_groups = vec![vec!["east".into(), "west".into()], vec!["north".into(), "south".into()]];
    let e = c.validate(Path::new("scene.toml")).unwrap_err().to_string();
    assert!(e.contains("west") && e.contains("no inbound lane"), "{e}");
}
