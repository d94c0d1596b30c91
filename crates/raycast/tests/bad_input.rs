//! Bad scene input: every case is an error naming the file and the field, never a panic.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_raycast::{RaycastError, Scene};
use std::path::Path;

fn load_text(dir: &Path, text: &str) -> Result<Scene, RaycastError> {
    let p = dir.join("scene.toml");
    std::fs::write(&p, text).unwrap();
    Scene::load(&p)
}

fn expect_err(dir: &Path, text: &str, needles: &[&str]) {
    let err = load_text(dir, text).expect_err("should fail").to_string();
    assert!(
        err.contains("scene.toml") || needles.iter().any(|n| n.ends_with(".obj") || n.ends_with(".gltf")),
        "no file name in: {err}"
    );
    for n in needles {
        assert!(err.contains(n), "{err:?} does not mention {n:?}");
    }
}

#[test]
fn malformed_and_unknown_fields() {
    let d = tempfile::tempdir().unwrap();
    expect_err(d.path(), "name = \"x\"\n[[arms]\nname = 1", &["scene.toml"]);
    expect_err(d.path(), "name = \"x\"\ncolour = \"red\"", &["colour"]);
    expect_err(d.path(), "name = \"x\"\n[[trees]]\nposition = [1.0, 2.0]\nleaves = 3", &["leaves"]);
    expect_err(d.path(), "[ground]\nz_m = 0.0", &["name"]);
}

#[test]
fn nan_negative_and_degenerate_values_name_the_field() {
    let d = tempfile::tempdir().unwrap();
    expect_err(
        d.path(),
        "name = \"x\"\n[[buildings]]\nfootprint = [[0.0,0.0],[1.0,0.0],[1.0,1.0]]\nheight_m = nan",
        &["buildings[0].height_m", "NaN"],
    );
    expect_err(
        d.path(),
        "name = \"x\"\n[[buildings]]\nfootprint = [[0.0,0.0],[1.0,0.0],[1.0,1.0]]\nheight_m = -3.0",
        &["buildings[0].height_m", "-3"],
    );
    expect_err(
        d.path(),
        "name = \"x\"\n[[buildings]]\nfootprint = [[0.0,0.0],[1.0,0.0],[2.0,0.0]]\nheight_m = 3.0",
        &["buildings[0].footprint", "zero area"],
    );
    expect_err(
        d.path(),
        "name = \"x\"\n[[trees]]\nposition = [1.0, 2.0]\ncrown_radius_m = -1.0",
        &["trees[0].crown_radius_m"],
    );
    expect_err(
        d.path(),
        "name = \"x\"\n[[arms]]\nname = \"a\"\nheading_deg = 0.0\nlane_width_m = 0.0",
        &["arms[0].lane_width_m"],
    );
    expect_err(
        d.path(),
        "name = \"x\"\n[[arms]]\nname = \"a\"\nheading_deg = 0.0\noffset_m = 25.0",
        &["arms[0].offset_m", "25", "within 20 m"],
    );
    expect_err(
        d.path(),
        "name = \"x\"\n[[arms]]\nname = \"a\"\nheading_deg = 0.0\noffset_m = nan",
        &["arms[0].offset_m"],
    );
    expect_err(d.path(), "name = \"x\"\n[ground]\nhalf_size_m = inf", &["ground.half_size_m"]);
    expect_err(
        d.path(),
        "name = \"x\"\n[[signal_poles]]\nname = \"p\"\nposition = [0.0, 0.0]\narm_heading_deg = 0.0\narm_length_m = 5.0\nhead_offsets_m = [6.0]",
        &["signal_poles[0].head_offsets_m[0]"],
    );
    expect_err(d.path(), "name = \"x\"\n[[roi]]\nname = \"r\"\nkind = \"polygon\"", &["roi[0].polygon"]);
    expect_err(d.path(), "name = \"x\"\n[[roi]]\nname = \"r\"\nkind = \"central\"", &["roi[0].kind"]);
    expect_err(d.path(), "name = \"x\"\n[[meshes]]\npath = \"m.obj\"\nscale = 0.0", &["meshes[0].scale"]);
}

#[test]
fn empty_and_broken_meshes() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("empty.obj"), "# nothing\n").unwrap();
    expect_err(d.path(), "name = \"x\"\n[[meshes]]\npath = \"empty.obj\"", &["empty.obj", "no triangles"]);
    std::fs::write(d.path().join("bad.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n").unwrap();
    let err = load_text(d.path(), "name = \"x\"\n[[meshes]]\npath = \"bad.obj\"").unwrap_err().to_string();
    assert!(err.contains("bad.obj"), "{err}");
    std::fs::write(d.path().join("junk.obj"), "v 0 0 zero\nf 1 2 3\n").unwrap();
    let err = load_text(d.path(), "name = \"x\"\n[[meshes]]\npath = \"junk.obj\"").unwrap_err().to_string();
    assert!(err.contains("junk.obj"), "{err}");
    std::fs::write(d.path().join("broken.gltf"), "{\"asset\": {\"version\": \"2.0\"}, \"meshes\": [").unwrap();
    expect_err(d.path(), "name = \"x\"\n[[meshes]]\npath = \"broken.gltf\"", &["broken.gltf", "malformed glTF"]);
    expect_err(d.path(), "name = \"x\"\n[[meshes]]\npath = \"missing.obj\"", &["missing.obj"]);
    std::fs::write(d.path().join("model.stl"), "solid x").unwrap();
    expect_err(d.path(), "name = \"x\"\n[[meshes]]\npath = \"model.stl\"", &["unsupported mesh format"]);
}

/// Well-formed but impossible scenes: a footprint that crosses itself (symmetric or not), arms
/// whose roadways overlap, absurd lane counts, an ROI or a building off the ground.
#[test]
fn impossible_geometry_is_refused_naming_the_field() {
    let d = tempfile::tempdir().unwrap();
    for bowtie in ["[[0.0,0.0],[10.0,10.0],[10.0,0.0],[0.0,10.0]]", "[[0.0,0.0],[12.0,9.0],[10.0,0.0],[1.0,11.0]]"] {
        expect_err(
            d.path(),
            &format!("name = \"x\"\n[[buildings]]\nfootprint = {bowtie}\nheight_m = 5.0"),
            &["buildings[0].footprint", "crosses itself"],
        );
    }
    let arm = |name: &str, heading: f32, extra: &str| {
        format!("[[arms]]\nname = \"{name}\"\nheading_deg = {heading}\nlength_m = 80.0\n{extra}\n")
    };
    expect_err(
        d.path(),
        &format!("name = \"x\"\n{}{}", arm("a", 0.0, ""), arm("b", 5.0, "")),
        &["arms[1].heading_deg", "overlap"],
    );
    expect_err(d.path(), &format!("name = \"x\"\n{}", arm("a", 0.0, "lanes_in = 1000")), &["arms[0].lanes_in", "1000"]);
    expect_err(
        d.path(),
        "name = \"x\"\n[[roi]]\nname = \"far\"\nkind = \"polygon\"\nweight = 1.0\npolygon = [[900.0,900.0],[950.0,900.0],[950.0,950.0]]",
        &["roi[0].polygon", "off the ground"],
    );
    // A real four-arm junction, and a skewed three-arm one, pass.
    let ok = format!(
        "name = \"x\"\n{}{}{}{}",
        arm("n", 90.0, ""),
        arm("e", 0.0, ""),
        arm("s", 270.0, ""),
        arm("w", 180.0, "")
    );
    load_text(d.path(), &ok).unwrap();
    let skew = format!("name = \"x\"\n{}{}{}", arm("a", 0.0, ""), arm("b", 60.0, ""), arm("c", 180.0, ""));
    load_text(d.path(), &skew).unwrap();
    // A curb radius: out of range, on a T-junction's straight side (no corner), so large the
    // crosswalk leaves the arm's inner half, at a roundabout; a fitting one passes.
    let four = |extra: &str| {
        format!(
            "name = \"x\"\n{}{}{}{}",
            arm("e", 0.0, extra),
            arm("n", 90.0, ""),
            arm("w", 180.0, ""),
            arm("s", 270.0, "")
        )
    };
    expect_err(d.path(), &four("corner_radius_m = -1.0"), &["arms[0].corner_radius_m", "0 (sharp) to 30 m"]);
    expect_err(d.path(), &four("corner_radius_m = nan"), &["arms[0].corner_radius_m"]);
    expect_err(d.path(), &four("corner_radius_m = 30.0"), &["arms[0].corner_radius_m", "beyond half its length"]);
    load_text(d.path(), &four("corner_radius_m = 12.0")).unwrap();
    let tee = format!(
        "name = \"x\"\n{}{}{}",
        arm("e", 0.0, ""),
        arm("n", 90.0, ""),
        arm("w", 180.0, "corner_radius_m = 5.0")
    );
    expect_err(d.path(), &tee, &["arms[2].corner_radius_m", "meets no corner"]);
    let ring =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/sites/roundabout.toml"))
            .unwrap()
            .replacen("[[arms]]\n", "[[arms]]\ncorner_radius_m = 5.0\n", 1);
    expect_err(d.path(), &ring, &["arms[0].corner_radius_m", "flare onto its ring"]);
}

/// The default intersection with `edit` applied to its text.
fn default_with(edit: impl Fn(String) -> String) -> String {
    edit(
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/intersection.toml"))
            .unwrap(),
    )
}

/// Values that are each a number but make no junction: a pole on the carriageway, in the
/// junction box or inside a building, a building in the junction box, a heading of 1e30°, two
/// arms pointing the same way.
#[test]
fn implausible_scenes_are_refused_by_field() {
    let d = tempfile::tempdir().unwrap();
    let pole = "[[signal_poles]]\nname = \"X\"\nheight_m = 7.5\nradius_m = 0.18\narm_heading_deg = 0.0\narm_length_m = 5.0\n\
                arm_height_m = 6.0\nhead_offsets_m = [3.0]\nposition = ";
    // 40 m out along the east arm, in its outbound lanes (south of the median).
    let text = default_with(|t| format!("{t}\n{pole}[40.0, -6.0]\n"));
    expect_err(d.path(), &text, &["signal_poles[4].position", "carriageway of arm \"east\""]);
    let text = default_with(|t| format!("{t}\n{pole}[0.0, 0.0]\n"));
    expect_err(d.path(), &text, &["signal_poles[4].position", "junction box"]);
    // On the east arm's median, 60 m out: where median poles stand.
    load_text(d.path(), &default_with(|t| format!("{t}\n{pole}[60.0, 0.0]\n"))).unwrap();
    let building = "[[buildings]]\nheight_m = 8.0\nfootprint = ";
    let text = default_with(|t| {
        format!("{t}\n{building}[[50.0, 50.0], [60.0, 50.0], [60.0, 60.0], [50.0, 60.0]]\n{pole}[55.0, 55.0]\n")
    });
    expect_err(d.path(), &text, &["signal_poles[4].position", "inside buildings["]);
    let text = default_with(|t| format!("{t}\n{building}[[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]]\n"));
    expect_err(d.path(), &text, &["footprint", "junction box"]);
    // A box larger than the junction box, around it: no corner of it inside, every corner of the box inside it.
    let text =
        default_with(|t| format!("{t}\n{building}[[-60.0, -60.0], [60.0, -60.0], [60.0, 60.0], [-60.0, 60.0]]\n"));
    expect_err(d.path(), &text, &["footprint", "junction box"]);
    let text = default_with(|t| t.replacen("heading_deg = 90.0", "heading_deg = 1e30", 1));
    expect_err(d.path(), &text, &["arms[1].heading_deg", "[-360, 360]"]);
    let text = default_with(|t| t.replacen("heading_deg = 90.0", "heading_deg = 0.0", 1));
    expect_err(d.path(), &text, &["heading_deg", "point the same way"]);
}

/// glTF documents that gltf's own reader panics on (found by fuzzing): a POSITION accessor
/// index past the accessors, and accessors of another shape than the reader assumes (indices
/// stored as floats, an empty accessor). Each is an error naming the file and the primitive.
#[test]
fn gltf_accessors_the_reader_would_panic_on_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let doc = |position: &str, accessor: &str| {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":{position}}},"indices":1}}]}}],
"buffers":[{{"byteLength":42,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAABAAIA"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":6}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0.0,0.0,0.0],"max":[1.0,1.0,0.0]}},
{accessor}]}}"#
        )
    };
    let indices = r#"{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}"#;
    let scene = "name = \"x\"\n[[meshes]]\npath = \"t.gltf\"";
    std::fs::write(d.path().join("t.gltf"), doc("0", indices)).unwrap();
    load_text(d.path(), scene).unwrap();
    for (position, accessor, needle) in [
        ("7", indices, "POSITION is accessor 7, but the file has 2 accessors"),
        ("0", &indices.replace("5123", "5126"), "the indices accessor"),
        ("0", &indices.replace("\"count\":3", "\"count\":0"), "the indices accessor"),
        ("1", indices, "POSITION"),
    ] {
        std::fs::write(d.path().join("t.gltf"), doc(position, accessor)).unwrap();
        expect_err(d.path(), scene, &["t.gltf", needle]);
    }
}
