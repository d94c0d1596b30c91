//! The embedded default scene is the file in `fixtures/`, and the whole chain from that file to
//! ray queries works across crates.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo::raycast::{HitTarget, QueryRegion, Ray, Scene, World};
use std::path::Path;

#[test]
fn embedded_default_equals_the_fixture_file() {
    let embedded = Scene::default_fixture().unwrap();
    let file = Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/intersection.toml")).unwrap();
    assert_eq!(embedded.config, file.config);
    assert_eq!(embedded.mesh, file.mesh);
}

#[test]
fn default_scene_really_occludes_parts_of_the_roi() {
    // From each pole top, some ROI ground points are hidden by trees, buildings or poles.
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    for m in &scene.mounts {
        let eye = m.base.extend(7.8);
        let (mut seen, mut hidden) = (0, 0);
        for roi in &scene.rois {
            for poly in &roi.polygons {
                let lo = poly.iter().fold(poly[0], |a, b| a.min(*b));
                let hi = poly.iter().fold(poly[0], |a, b| a.max(*b));
                let mut x = lo.x;
                while x < hi.x {
                    let mut y = lo.y;
                    while y < hi.y {
                        let p = hilo::core::glam::Vec2::new(x, y);
                        if roi.contains(p) {
                            let target = p.extend(0.0);
                            let d = target - eye;
                            let ray = Ray::new(eye, d, d.length() + 0.5);
                            match world.closest_hit(&ray, None).map(|h| h.target) {
                                Some(HitTarget::Ground) => seen += 1,
                                _ => hidden += 1,
                            }
                        }
                        y += 2.0;
                    }
                    x += 2.0;
                }
            }
        }
        let frac = hidden as f64 / (seen + hidden) as f64;
        assert!(frac > 0.01 && frac < 0.5, "{}: {:.1}% of ROI points hidden", m.name, 100.0 * frac);
    }
}
