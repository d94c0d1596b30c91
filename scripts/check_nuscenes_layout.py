#!/usr/bin/env python3
"""Loads a hilo dataset with the official nuscenes-devkit (optional for users):
    pip install nuscenes-devkit==1.2.0
    python3 scripts/check_nuscenes_layout.py DATAROOT VERSION
Lists the scenes, and for every sample of every scene asks get_sample_data for each key-frame
channel, checking that the boxes it returns are the sample's annotations. Then reads every point
file of the dataset (key frames and sweeps) with the devkit's own readers,
LidarPointCloud.from_file and RadarPointCloud.from_file (with its default filters), and checks
that each returns every point the file holds.
"""
import os
import sys

from nuscenes.nuscenes import NuScenes
from nuscenes.utils.data_classes import LidarPointCloud, RadarPointCloud


def header_points(path):
    """POINTS of a PCD header."""
    with open(path, "rb") as f:
        for line in f:
            line = line.strip().decode("ascii")
            if line.startswith("POINTS"):
                return int(line.split()[1])
    raise AssertionError(f"{path}: no POINTS line")


def main(dataroot, version):
    nusc = NuScenes(version=version, dataroot=dataroot, verbose=False)
    nusc.list_scenes()
    checked = 0
    for scene in nusc.scene:
        token = scene["first_sample_token"]
        while token:
            sample = nusc.get("sample", token)
            for channel, sd_token in sample["data"].items():
                path, boxes, _ = nusc.get_sample_data(sd_token)
                assert len(boxes) == len(sample["anns"]), (channel, len(boxes), len(sample["anns"]))
                assert {b.token for b in boxes} == set(sample["anns"])
                checked += 1
            token = sample["next"]
    files = {"lidar": 0, "radar": 0}
    points = {"lidar": 0, "radar": 0}
    for sd in nusc.sample_data:
        path = os.path.join(dataroot, sd["filename"])
        modality = nusc.get("sensor", nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])["sensor_token"])["modality"]
        if modality == "lidar":
            pc = LidarPointCloud.from_file(path)
            want = os.path.getsize(path) // 20
            assert os.path.getsize(path) % 20 == 0, path
        else:
            pc = RadarPointCloud.from_file(path)
            assert pc.points.shape[0] == 18, (path, pc.points.shape)
            n = header_points(path)
            # An empty cloud is one NaN point, which the devkit reads as no point.
            want = 0 if n == 1 and pc.points.shape[1] == 0 else n
        assert pc.points.shape[1] == want, (path, pc.points.shape, want)
        files[modality] += 1
        points[modality] += want
    assert files["lidar"] > 0, "no LiDAR file read"
    print(
        f"ok: {len(nusc.scene)} scenes, {len(nusc.sample)} samples, {checked} get_sample_data calls; "
        f"read {files['lidar']} LiDAR files ({points['lidar']} points) and {files['radar']} radar files "
        f"({points['radar']} points) with the devkit's readers"
    )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
