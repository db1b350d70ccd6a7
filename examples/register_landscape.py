#!/usr/bin/env python3
"""The shape of a registration metric around the true pose (a worked example): simulated W1
B-mode frames of the phantom at known poses, each moved along one axis at a time (x, y, z in mm,
rotations about x, y, z in degrees, about the fan's centre, in the probe frame), the cost
`sonoslice register` minimises at each step. Counts the frame-axis profiles whose minimum lies
within 1 mm (1 degree) of the truth, and how far on both sides of it the cost keeps rising (the
basin a local optimiser can come back from).

  build/venv/bin/python examples/register_landscape.py --phantom DIR [--poses 12] [--metric lc2]
      [--levels 1 2] [--frames FRAMES.npy]

DIR is a folder from `sonoslice phantom DIR --size full`; the poses are the first --poses of
`sonoslice phantom P --size small --poses N` (those of examples/register_capture_range.py), the
frames `sonoslice simulate --preset lus` at them unless --frames gives others.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

import sonoslice

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from register_capture_range import CLI, W1, body_poses, phantom_file  # noqa: E402


def moved(pose, centre, axis, d):
    """`pose` moved by d mm along probe axis 0..2, or turned by d degrees about probe axis
    (axis - 3) through `centre` (probe mm)."""
    m = np.eye(4)
    if axis < 3:
        m[axis, 3] = d
    else:
        a = np.deg2rad(d)
        e = np.eye(3)[axis - 3]
        k = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])  # e x .
        r = np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * (k @ k)
        m[:3, :3] = r
        m[:3, 3] = centre - r @ centre
    return pose @ m


def basin(cost, steps):
    """How far (in steps' units) the cost rises on both sides of its minimum; -1 when the
    minimum is more than 1 away from 0."""
    i = int(np.argmin(cost))
    if abs(steps[i]) > 1:
        return -1
    width = 0
    for k in range(1, len(steps)):
        lo, hi = i - k, i + k
        if lo < 0 and hi >= len(steps):
            break
        if (lo >= 0 and cost[lo] < cost[lo + 1]) or (hi < len(steps) and cost[hi] < cost[hi - 1]):
            break
        width = k
    return width * (steps[1] - steps[0])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phantom", required=True, help="a folder from `sonoslice phantom DIR --size full`")
    ap.add_argument("--poses", type=int, default=12)
    ap.add_argument("--metric", default="lc2")
    ap.add_argument("--levels", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--frames", help="frames at the true poses (.npy, (N, H, W) on W1's grid)")
    args = ap.parse_args()
    steps = np.arange(-10, 10.1, 1.0)
    with tempfile.TemporaryDirectory() as tmp:
        ct_path = phantom_file(args.phantom, "ct.")
        truth = body_poses(tmp, args.poses)
        if args.frames:
            frames = np.load(args.frames)[: args.poses].astype(np.float32)
        else:
            np.save(os.path.join(tmp, "truth.npy"), truth)
            subprocess.run([CLI, "simulate", "--volume", ct_path, "--preset", "lus", "--poses",
                            os.path.join(tmp, "truth.npy"), "--out", os.path.join(tmp, "f.npy"), "-q"], check=True)
            frames = np.load(os.path.join(tmp, "f.npy")).astype(np.float32)
    ct = sonoslice.Volume.from_file(ct_path).astype(np.float32)  # converted once, not per call
    probe = sonoslice.Probe.from_fanslicer(W1, downsampling=2)
    image = json.loads(probe.to_json())["image"]
    v, u = np.nonzero(probe.mask)
    centre = np.array([image["origin_mm"][0] + u.mean() * image["spacing_mm"][0],
                       image["origin_mm"][1] + v.mean() * image["spacing_mm"][1], 0.0])
    print(f"{args.poses} frames x 6 axes, {args.metric}, steps of 1 mm / 1 deg to +-10\n")
    print("| level | minimum within 1 of the truth | basin >= 3 | >= 5 | >= 8 |")
    print("|---|---|---|---|---|")
    for level in args.levels:
        widths = []
        for k in range(args.poses):
            for axis in range(6):
                path = np.stack([moved(truth[k], centre, axis, d) for d in steps])
                cost = sonoslice.registration_cost(ct, probe, np.repeat(frames[k:k + 1], len(steps), 0), path,
                                                   metric=args.metric, level=level)
                widths.append(basin(cost, steps))
        w = np.array(widths)
        n = len(w)
        print(f"| {level} | {(w >= 0).sum()} of {n} | {(w >= 3).sum()} | {(w >= 5).sum()} | {(w >= 8).sum()} |",
              flush=True)


if __name__ == "__main__":
    main()
