#!/usr/bin/env python3
"""Simulation speed against slicing on the same poses: W1 (fan-slicer's LUS
fan at --downsampling 2, the `lus` preset's probe, 334x272) on the full phantom CT, through the
CLI, written to .npy. Each figure is the compute time that `--verbose` reports ("simulate X s",
"slice X s": no loading or writing) and the command's wall time, for the same poses, in runs that
alternate so that both see the same machine.

  build/venv/bin/python bench/simulate_speed.py [--poses 400] [--threads 2] [--repeat 5]
      [--phantom DIR]                # a phantom written by `sonoslice phantom DIR --size full`
      [--baseline OTHER/sonoslice]   # also time another build's simulate, alternating
      [--dataset N]                  # also: `sonoslice dataset` of N ultrasound images against
                                     # `simulate` of the same N poses (wall clock, both)

This machine is shared: single runs move by ±30 %, so the median and the best of each are
reported, and the ratio simulate : slice is taken from the medians of the same run.
"""
import argparse
import json
import os
import re
import statistics
import subprocess
import tempfile

import numpy as np

from benchcommon import CLI, W1, full_phantom_ct, run_timed
from dataset_speed import poses_of, write_spec
COMPUTE = re.compile(r"(?:simulate|slice) ([0-9.]+) s \(")


def timed(cmd):
    """(compute seconds from --verbose, wall seconds) of one run."""
    wall, stderr = run_timed(cmd)
    match = COMPUTE.search(stderr)
    if not match:
        raise SystemExit(f"no timing in the output of {' '.join(cmd)}:\n{stderr}")
    return float(match.group(1)), wall


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, default=400)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--phantom", help="a directory with ct.* from `sonoslice phantom --size full`")
    ap.add_argument("--baseline", help="another build's sonoslice executable, timed alternately")
    ap.add_argument("--dataset", type=int, default=0, help="also time a dataset of this many ultrasound images")
    args = ap.parse_args()
    dataset_line = None

    with tempfile.TemporaryDirectory() as tmp:
        ct = full_phantom_ct(args.phantom, tmp)
        # Random poses inside the body: the phantom command's benchmark poses, cycled to --poses.
        subprocess.run([CLI, "phantom", os.path.join(tmp, "poses"), "--size", "full", "--format", "nii",
                        "--poses", "64", "-q"], check=True)
        base = np.load(os.path.join(tmp, "poses", "poses.npy"))
        poses = os.path.join(tmp, "poses.npy")
        np.save(poses, np.concatenate([base] * (args.poses // len(base) + 1))[: args.poses])
        out = os.path.join(tmp, "out.npy")
        threads = ["--threads", str(args.threads), "-v"]
        runs = {
            "slice": [CLI, "slice", "--volume", ct, "--probe", W1, "--downsampling", "2", "--poses", poses,
                      "--out", out] + threads,
            "simulate": [CLI, "simulate", "--volume", ct, "--preset", "lus", "--poses", poses, "--out", out]
            + threads,
        }
        if args.baseline:
            runs["simulate (baseline)"] = [args.baseline] + runs["simulate"][1:]
        times = {name: [] for name in runs}
        for _ in range(args.repeat):
            for name, cmd in runs.items():
                times[name].append(timed(cmd))
        if args.dataset:
            dataset_line = dataset_against_simulate(ct, args.dataset, args.threads, tmp)

    n = args.poses
    print(f"\nW1 (334x272, lus preset, 6.5 MHz) on the full phantom CT, {n} poses, {args.threads} threads, "
          f"{args.repeat} alternating runs\n")
    print("| command | images/s, compute (median; best) | images/s, wall incl. load and write (median) |")
    print("|---|---|---|")
    medians = {}
    for name, t in times.items():
        compute = [c for c, _ in t]
        wall = [w for _, w in t]
        medians[name] = statistics.median(compute)
        print(f"| {name} | {n / medians[name]:.1f}; {n / min(compute):.1f} | {n / statistics.median(wall):.1f} |")
    print(f"\nsimulate costs {medians['simulate'] / medians['slice']:.1f}x slice (medians of the same run); "
          f"targets: >= 500 images/s and <= 10x slice")
    if args.baseline:
        print(f"this build against the baseline: {medians['simulate (baseline)'] / medians['simulate']:.2f}x")
    if dataset_line:
        print(dataset_line)


def dataset_against_simulate(ct, count, threads, tmp):
    """`sonoslice dataset` of `count` ultrasound images (docs/dataset_example.yaml's skin sampler
    and probe, images: [ultrasound]) against `simulate` of the same poses, both wall clock with
    loading and writing; the target is a ratio of at least 0.8."""
    folder = os.path.dirname(ct)
    labels = [os.path.join(folder, f) for f in sorted(os.listdir(folder)) if f.startswith("labels.")]
    spec = os.path.join(tmp, "spec.json")
    write_spec(spec, ct, labels[0] if labels else None, count)
    with open(spec) as f:
        s = json.load(f)
    s["images"] = [{"kind": "ultrasound"}]
    if not labels:
        s["volumes"][0].pop("labels", None)
    with open(spec, "w") as f:
        json.dump(s, f)
    out = os.path.join(tmp, "dataset")
    dataset_wall, _ = run_timed([CLI, "dataset", spec, "--out", out, "--threads", str(threads), "-q"])
    poses = os.path.join(tmp, "dataset_poses.npy")
    np.save(poses, poses_of(out))
    simulate_wall, _ = run_timed([CLI, "simulate", "--volume", ct, "--probe", W1, "--downsampling", "2",
                                  "--poses", poses, "--out", os.path.join(tmp, "us.npy"), "--seed",
                                  str(s.get("seed", 0)), "--threads", str(threads)])
    return (f"dataset of {count} ultrasound images: {count / dataset_wall:.1f} images/s against simulate of the same "
            f"poses {count / simulate_wall:.1f} images/s (wall clock, both): ratio {simulate_wall / dataset_wall:.2f} "
            f"(target >= 0.8)")


if __name__ == "__main__":
    main()
