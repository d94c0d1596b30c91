#!/usr/bin/env python3
"""Writes the two one-effect catalogs between the paper's sensors and the datasheet LiDARs,
and a sweep study over all four, so each datasheet change is measured alone:
    python3 scripts/realism-catalogs.py OUT
    hilo place OUT/<variant>.toml --out OUT/place-<variant> --json     (one per variant)
    hilo study OUT/realism-sweep.toml --profile quick --out realism    (all four, trained)

- OUT/sensors-tables.toml: fixtures/sensors.toml with the datasheet file's beam tables
  (`elevations_deg`) for the LiDARs that have one there; ranges as the paper's.
- OUT/sensors-range.toml: fixtures/sensors.toml with the datasheet file's `max_range_m` and
  `detection_range` (the lidar equation); beams spread as the paper's.
The study files extend fixtures/paper-sensors-study.toml; the sweep lists the paper's catalog,
the two above and the datasheet catalog. OUT must not exist yet or be empty.
"""
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
FIXTURES = os.path.join(HERE, "..", "fixtures")
LIDARS = ["lidar-64", "lidar-32", "lidar-16"]


def block(text, name):
    """(start, end) of the [[lidar]] entry named `name`: from its name line to the next table."""
    start = text.index('name = "%s"' % name)
    end = text.index("[[", start)
    return start, end


def field(text, name, key):
    """The line (or bracketed multi-line value) of `key` in entry `name`, or None."""
    start, end = block(text, name)
    m = re.search(r"^%s = (\[[^\]]*\]|\{[^}]*\}|[^\n]*)\n" % re.escape(key), text[start:end], re.M)
    return m.group(0) if m else None


def replace_in(text, name, edit):
    start, end = block(text, name)
    return text[:start] + edit(text[start:end]) + text[end:]


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = sys.argv[1]
    if os.path.exists(out) and os.listdir(out):
        sys.exit(f"{out} is not empty; give a new folder")
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(FIXTURES, "sensors.toml")) as f:
        paper = f.read()
    with open(os.path.join(FIXTURES, "sensors-datasheet.toml")) as f:
        sheet = f.read()
    tables, ranges = paper, paper
    for name in LIDARS:
        table = field(sheet, name, "elevations_deg")
        if table and not field(paper, name, "elevations_deg"):
            tables = replace_in(tables, name, lambda b: b.replace("azimuth_resolution_deg", table + "azimuth_resolution_deg", 1))
        gate, reach = field(sheet, name, "max_range_m"), field(sheet, name, "detection_range")
        if gate is None or reach is None:
            sys.exit(f"sensors-datasheet.toml: {name} has no max_range_m or detection_range")
        ranges = replace_in(
            ranges, name, lambda b: re.sub(r"^max_range_m = .*\n", gate, b, flags=re.M).rstrip("\n") + "\n" + reach + "\n"
        )
    catalogs = {
        "paper": os.path.abspath(os.path.join(FIXTURES, "sensors.toml")),
        "tables": os.path.abspath(os.path.join(out, "sensors-tables.toml")),
        "range": os.path.abspath(os.path.join(out, "sensors-range.toml")),
        "datasheet": os.path.abspath(os.path.join(FIXTURES, "sensors-datasheet.toml")),
    }
    for path, text in [(catalogs["tables"], tables), (catalogs["range"], ranges)]:
        with open(path, "w") as f:
            f.write(text)
    base = os.path.abspath(os.path.join(FIXTURES, "paper-sensors-study.toml"))
    for variant, catalog in catalogs.items():
        with open(os.path.join(out, variant + ".toml"), "w") as f:
            f.write(f"extends = {base!r}\ncatalog = {catalog!r}\n".replace("'", '"'))
    with open(os.path.join(out, "realism-sweep.toml"), "w") as f:
        listed = ", ".join('"%s"' % c for c in catalogs.values())
        f.write(f'extends = "{base}"\ncatalogs = [{listed}]\n')


if __name__ == "__main__":
    main()
