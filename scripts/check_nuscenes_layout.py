#!/usr/bin/env python3
"""Loads a hilo dataset with the official nuscenes-devkit (optional for users):
    pip install nuscenes-devkit==1.2.0
    python3 scripts/check_nuscenes_layout.py DATAROOT VERSION
Lists the scenes, and for every sample of every scene asks get_sample_data for each key-frame
channel, checking that the boxes it returns are the sample's annotations.
"""
import sys

from nuscenes.nuscenes import NuScenes


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
    print(f"ok: {len(nusc.scene)} scenes, {len(nusc.sample)} samples, {checked} get_sample_data calls")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
