#!/usr/bin/env python3
"""Reads hilo's PCD and PLY files with independent readers (pypcd4, plyfile) and checks them
against hilo's own reading, printed as JSON by the caller. Optional for users:
    pip install pypcd4 plyfile
    hilo scan --sensor lidar-16 --pose 13,16.6,7.8,-127,10 --out scan.pcd
    hilo scan --sensor lidar-16 --pose 13,16.6,7.8,-127,10 --out scan.ply
    python3 scripts/check_point_files.py scan.pcd scan.ply
The two files hold the same scan (same seed), so the script also checks they agree.
"""
import sys

import numpy as np
from plyfile import PlyData
from pypcd4 import PointCloud


def main(pcd_path, ply_path):
    pc = PointCloud.from_path(pcd_path)
    fields = list(pc.fields)
    assert fields == ["x", "y", "z", "intensity", "ring", "time"], fields
    pcd = pc.numpy(fields)
    ply = PlyData.read(ply_path)["vertex"].data
    names = list(ply.dtype.names)
    assert names == fields, names
    assert len(pcd) == len(ply) > 0, (len(pcd), len(ply))
    for i, name in enumerate(fields):
        a = pcd[:, i].astype(np.float64)
        b = np.asarray(ply[name], dtype=np.float64)
        assert np.array_equal(a, b), name
    assert ply["ring"].dtype == np.uint16
    print(f"ok: {len(pcd)} points, fields {fields}, PCD and PLY identical")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
