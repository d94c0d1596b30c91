//! Which presets and rigs each of the paper's claims compares in `--profile paper`, with the
//! plugins hilo ships that this crate's tests can reach (raw and early): fusion against the
//! LiDAR-only preset that shares its head, the ablation that exists, the rigs by role.

#![allow(clippy::unwrap_used)]

use hilo_study::stats::Scores;
use hilo_study::verdict::{Design, DetectorScores, PresetRoles};
use hilo_study::{Study, profile};
use std::collections::BTreeMap;

#[test]
fn the_paper_profile_maps_each_claim_to_the_presets_it_names() {
    let mut registry = hilo_detector::Registry::with_builtin();
    hilo_fusion_raw::register(&mut registry).unwrap();
    hilo_fusion_early::register(&mut registry).unwrap();
    registry.set_primary("lirafusion-like").unwrap();
    let text = include_str!("../../../fixtures/study.toml");
    let study = Study::parse_embedded(text, "<embedded>/fixtures/study.toml").unwrap();
    let prof = profile(hilo_study::ProfileName::Paper, &study, &registry).unwrap();
    assert_eq!(&prof.presets[..2], &["centerpoint".to_string(), "lirafusion-like".to_string()]);
    assert!(prof.ablations.contains(&"lirafusion-like-no-early".to_string()));
    let roles = PresetRoles::of(&prof, &registry);
    assert_eq!(roles.counterpart["lirafusion-like"], "centerpoint");
    assert_eq!(roles.counterpart["l4dr-like"], "centerpoint");
    assert_eq!(roles.counterpart["pointpillars-lr"], "pointpillars");
    // Every preset on every rig (ablations too), three seeds, scores that differ by preset.
    let rigs: Vec<(String, f64, usize)> = study
        .file
        .configurations
        .iter()
        .map(|c| {
            let cost = c.sensors.iter().map(|(t, n)| study.catalog.get(t).unwrap().price_usd() * *n as f64).sum();
            (c.name.clone(), cost, c.sensors.get("radar-4d").copied().unwrap_or(0) as usize)
        })
        .collect();
    let mut scores = Vec::new();
    for (ci, (rig, _, _)) in rigs.iter().enumerate() {
        for (pi, p) in prof.presets.iter().chain(&prof.ablations).enumerate() {
            for seed in 0..3u64 {
                let v = 0.5 + 0.01 * pi as f64 + 0.02 * ci as f64 + 0.001 * seed as f64;
                let s = Scores { full: v, replicates: vec![v; 30] };
                scores.push(DetectorScores {
                    configuration: rig.clone(),
                    preset: p.clone(),
                    seed,
                    draw: 0,
                    scores: BTreeMap::from([("mAP".to_string(), s.clone()), ("pedestrian AP".to_string(), s)]),
                });
            }
        }
    }
    let no_conditions = BTreeMap::new();
    let design = Design {
        scores: &scores,
        configurations: &rigs,
        conditions: &no_conditions,
        given: &no_conditions,
        presets: &prof.presets,
        ablations: &prof.ablations,
        ablation_of: &roles.ablation_of,
        uses_radar: &roles.uses_radar,
        counterpart: &roles.counterpart,
        pointpillars_head: &roles.pointpillars_head,
        scenes: 20,
        level: 0.95,
    };
    let claims = design.claims();
    let sides = |id: &str| {
        let c = claims.iter().find(|c| c.id == id).unwrap();
        assert!(c.not_tested.is_none(), "{id}: {:?}", c.not_tested);
        let r = &c.rows[0];
        (r.a.clone(), r.b.clone(), r.paper)
    };
    let g = |c: &str, p: &str| (c.to_string(), p.to_string());
    let cheap = "2x lidar-16 + radar";
    assert_eq!(
        sides("fusion_vs_lidar_only"),
        (vec![g(cheap, "centerpoint")], vec![g(cheap, "lirafusion-like")], Some(0.031))
    );
    assert_eq!(
        sides("fused_pedestrian_over_centerpoint"),
        (vec![g(cheap, "centerpoint")], vec![g(cheap, "lirafusion-like")], Some(0.068))
    );
    assert_eq!(
        sides("fusion_over_pointpillars"),
        (vec![g(cheap, "pointpillars")], vec![g(cheap, "pointpillars-lr")], Some(0.077))
    );
    assert_eq!(
        sides("early_fusion_ablation"),
        (vec![g(cheap, "lirafusion-like-no-early")], vec![g(cheap, "lirafusion-like")], Some(0.009))
    );
    assert_eq!(
        sides("vs_lidar_alone"),
        (vec![g("1x lidar-64", "centerpoint")], vec![g(cheap, "lirafusion-like")], Some(0.015))
    );
    let (a, b, paper) = sides("vs_mid_lidar_radar");
    assert!(a.iter().all(|x| x.0 == "1x lidar-32 + radar") && b.iter().all(|x| x.0 == cheap), "{a:?} {b:?}");
    assert_eq!((a.len(), paper), (prof.presets.len(), Some(0.032)));
    let (a, _, _) = sides("vs_lidar_radar");
    assert!(a.iter().all(|x| x.0 == "1x lidar-64 + radar"));
    // The confounds: the cheap rig without its radar, and two viewpoints against one.
    assert_eq!(sides("radar_adds"), (vec![g("2x lidar-16", "centerpoint")], vec![g(cheap, "lirafusion-like")], None));
    assert_eq!(
        sides("second_viewpoint"),
        (vec![g("1x lidar-64", "centerpoint")], vec![g("2x lidar-16", "centerpoint")], None)
    );
    // With the cheap radar rig and the 64-beam LiDAR alone (the quick profile's first two), the
    // only LiDAR-only rig costs more than the radar rig: the radar's claims are not tested
    // rather than comparing the two rigs again under the radar's name.
    let two = Design { configurations: &rigs[..2], ..design };
    assert_eq!((rigs[0].0.as_str(), rigs[1].0.as_str()), (cheap, "1x lidar-64"));
    let claims = two.claims();
    for id in ["radar_adds", "radar_adds_velocity"] {
        let c = claims.iter().find(|c| c.id == id).unwrap();
        assert!(c.rows.is_empty() && c.not_tested.as_deref().is_some_and(|w| w.contains("costs less")), "{id}: {c:?}");
    }
    let c = claims.iter().find(|c| c.id == "vs_lidar_alone").unwrap();
    assert!(c.not_tested.is_none() && !c.rows.is_empty());
}
