#!/usr/bin/env python3
"""Writes the realism ablation: the default study on the paper's sensors with each modelled
effect switched on alone, none, and all together, as a directory of study files (a sweep):
    python3 scripts/realism-ablation.py OUT
    hilo study OUT --profile quick --presets centerpoint,lirafusion-like --out ablation

Every study extends fixtures/paper-sensors-study.toml (the default study on the paper's
sensors). The effects and where each comes from:
- ideal: the paper's sensors (fixtures/sensors.toml), a perfect rig.
- lidar_tables, lidar_range: one of the datasheet LiDARs' changes (beam tables; range by
  reflectivity from the lidar equation), taken from fixtures/sensors-datasheet.toml.
- lidar_range_beam: lidar_range and the beams' width and return mode (`beam`), which needs the
  lidar equation to decide which partial hits are seen: compare it with lidar_range. The quick
  and default profiles cast rays of no width unless told, so this study and `all` set
  `[dataset] lidar_beam_width = true`.
- radar_azimuth, radar_resolution, radar_multipath, radar_side_lobes, radar_false_alarms,
  radar_vegetation, radar_aspect: one of the datasheet radars' effects (their azimuth tables;
  `doppler_resolution_mps`; both multipath losses; `side_lobe_level_db`; the false alarms and
  their speed; `vegetation_doppler_mps`; `rcs_aspect_db`), on every radar.
- calibration: `[dataset] calibration_error` of 0.2 deg and 2 cm (a careful survey).
- time_sync: `[dataset] time_sync_error_s` of 5 ms (NTP-class clocks).
- rolling_shutter: `[dataset] rolling_shutter = true`.
- vehicle_paint: `[dataset] vehicle_paint = "fleet"` (each vehicle a colour's reflectivity).
- foliage: `[dataset] foliage`, crowns in wind: 30% of the rays that meet one pass through a
  gap, the others return from a leaf moved by 0.1 m (1 sigma) along the ray.
- all: the datasheet catalog and the five dataset settings together.
The one-effect catalogs go to OUT/catalogs/. OUT must not exist yet or be empty.
"""
import os
import sys
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
FIXTURES = os.path.abspath(os.path.join(HERE, "..", "fixtures"))

RIG = {
    "calibration": "calibration_error = { rotation_deg = 0.2, translation_m = 0.02 }",
    "time_sync": "time_sync_error_s = 0.005",
    "rolling_shutter": "rolling_shutter = true",
    "vehicle_paint": 'vehicle_paint = "fleet"',
    "foliage": "foliage = { gap_probability = 0.3, sway_m = 0.1 }",
}
RADAR_EFFECTS = {
    "radar_resolution": ["doppler_resolution_mps"],
    "radar_multipath": ["wall_multipath_loss_db", "ground_multipath_loss_db"],
    "radar_side_lobes": ["side_lobe_level_db"],
    "radar_false_alarms": ["false_alarms_per_frame", "false_alarm_speed_mps"],
    "radar_vegetation": ["vegetation_doppler_mps"],
    "radar_aspect": ["rcs_aspect_db"],
}


def value(v):
    """A TOML value as text (the numbers, lists and inline tables a catalog holds)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"%s"' % v.replace("\\", "\\\\").replace('"', '\\"')
    if isinstance(v, list):
        return "[" + ", ".join(value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join("%s = %s" % (k, value(x)) for k, x in v.items()) + " }"
    raise SystemExit(f"cannot write {v!r}")


def catalog(doc):
    """A catalog document as TOML text."""
    out = ["# Written by scripts/realism-ablation.py; do not edit.\n"]
    for kind in ("lidar", "radar"):
        for entry in doc.get(kind, []):
            out.append(f"[[{kind}]]")
            tables = {k: v for k, v in entry.items() if isinstance(v, dict) and k != "detection_range"}
            arrays = {k: v for k, v in entry.items() if isinstance(v, list) and v and isinstance(v[0], dict)}
            for k, v in entry.items():
                if k not in tables and k not in arrays:
                    out.append(f"{k} = {value(v)}")
            for k, v in tables.items():
                out.append(f"\n[{kind}.{k}]")
                out.extend(f"{a} = {value(b)}" for a, b in v.items())
            for k, rows in arrays.items():
                for row in rows:
                    out.append(f"\n[[{kind}.{k}]]")
                    out.extend(f"{a} = {value(b)}" for a, b in row.items())
            out.append("")
    return "\n".join(out) + "\n"


def by_name(doc, kind):
    return {e["name"]: e for e in doc.get(kind, [])}


def one_effect(paper, sheet, effect):
    """The paper's catalog with one effect of the datasheet catalog's sensors."""
    doc = {"lidar": [dict(e) for e in paper["lidar"]], "radar": [dict(e) for e in paper["radar"]]}
    lidars, radars = by_name(sheet, "lidar"), by_name(sheet, "radar")
    for e in doc["lidar"]:
        s = lidars.get(e["name"])
        if s is None:
            continue
        if effect == "lidar_tables" and "elevations_deg" in s:
            e["elevations_deg"] = s["elevations_deg"]
            e["vfov_deg"] = s["vfov_deg"]
        if effect in ("lidar_range", "lidar_range_beam"):
            e["max_range_m"] = s["max_range_m"]
            e["detection_range"] = s["detection_range"]
        if effect == "lidar_range_beam" and "beam" in s:
            e["beam"] = s["beam"]
    for e in doc["radar"]:
        s = radars.get(e["name"])
        if s is None:
            continue
        if effect == "radar_azimuth" and "azimuth_table" in s:
            e["azimuth_resolution_deg"] = s["azimuth_resolution_deg"]
            e["azimuth_table"] = s["azimuth_table"]
        if effect in RADAR_EFFECTS:
            e["effects"] = {k: s["effects"][k] for k in RADAR_EFFECTS[effect]}
    return doc


def study(base, catalog_path, rig_lines):
    lines = [f'extends = "{base}"', f'catalog = "{catalog_path}"']
    if rig_lines:
        lines.append("\n[dataset]")
        lines.extend(rig_lines)
    return "\n".join(lines) + "\n"


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = os.path.abspath(sys.argv[1])
    if os.path.exists(out) and os.listdir(out):
        sys.exit(f"{out} is not empty; give a new folder")
    os.makedirs(os.path.join(out, "catalogs"), exist_ok=True)
    paper_path = os.path.join(FIXTURES, "sensors.toml")
    sheet_path = os.path.join(FIXTURES, "sensors-datasheet.toml")
    with open(paper_path, "rb") as f:
        paper = tomllib.load(f)
    with open(sheet_path, "rb") as f:
        sheet = tomllib.load(f)
    base = os.path.join(FIXTURES, "paper-sensors-study.toml")
    width = "lidar_beam_width = true"
    studies = {"ideal": study(base, paper_path, []), "all": study(base, sheet_path, [*RIG.values(), width])}
    for effect in ["lidar_tables", "lidar_range", "lidar_range_beam", "radar_azimuth", *RADAR_EFFECTS]:
        path = os.path.join(out, "catalogs", effect + ".toml")
        with open(path, "w") as f:
            f.write(catalog(one_effect(paper, sheet, effect)))
        studies[effect] = study(base, path, [width] if effect == "lidar_range_beam" else [])
    for effect, line in RIG.items():
        studies[effect] = study(base, paper_path, [line])
    for name, text in studies.items():
        with open(os.path.join(out, name + ".toml"), "w") as f:
            f.write(text)
    print(f"{len(studies)} studies in {out}")


if __name__ == "__main__":
    main()
