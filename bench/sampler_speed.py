#!/usr/bin/env python3
"""Pose sampler throughput: candidate poses per second before rejection (target
>= 1 million/s on 2 cores), accepted poses per second with the rejection rules on, and the
one-off setup (the skin surface of the CT), for each sampler type on the phantom CT.

  build/venv/bin/python bench/sampler_speed.py [--phantom DIR] [--count 2000000] [--threads 2]

DIR holds ct.nii(.gz) and labels.nii(.gz) (`sonoslice phantom DIR --size full`); without it the
small phantom is generated in memory. No peer: fan-slicer leaves pose generation to the user.
"""
import argparse
import os
import time


import sonoslice

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
W1 = os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json")


def load(directory, name):
    for ext in (".nii", ".nii.gz"):
        path = os.path.join(directory, name + ext)
        if os.path.exists(path):
            return sonoslice.Volume.from_file(path)
    raise SystemExit(f"{directory}: no {name}.nii or {name}.nii.gz (sonoslice phantom DIR --size full)")


def best_rate(fn, n, repeat=3):
    """Items per second of the fastest of `repeat` runs."""
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return n / best


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phantom", help="folder with ct.nii(.gz) and labels.nii(.gz)")
    ap.add_argument("--count", type=int, default=2_000_000)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    sonoslice.set_threads(args.threads)
    if args.phantom:
        ct, labels = load(args.phantom, "ct"), load(args.phantom, "labels")
    else:
        ct, labels = sonoslice.phantom("small")
    probe = sonoslice.Probe.from_fanslicer(W1, downsampling=2)
    seeds = sonoslice.sample_seeds(1, 0, 0, args.count)
    liver = sonoslice.PHANTOM_LABELS.index("liver")
    configs = {
        "skin (tilt, heel-toe, rotation, depth)": {"type": "skin", "tilt_deg": [-20, 20], "heel_toe_deg": [-10, 10],
                                                   "rotation_deg": [0, 360], "depth_mm": [0, 5]},
        "region (liver label, uniform rotations)": {"type": "region", "label": liver},
        "region (intensity, 30 deg cone)": {"type": "region", "intensity": [0, 100], "cone_deg": 30},
    }
    rules = {"min_inside": 0.9, "min_body": 0.9, "no_gas": True}
    print(f"{args.count} seeds, {sonoslice.threads()} threads, CT {ct.shape}")
    print("| sampler | setup s | candidates/s (no rejection) | accepted/s (min_inside 0.9, min_body 0.9, no_gas) |")
    print("|---|---|---|---|")
    for name, config in configs.items():
        t = time.perf_counter()
        sampler = sonoslice.PoseSampler(config, probe, ct, labels)
        setup = time.perf_counter() - t
        candidates = best_rate(lambda: sampler.candidates(seeds), len(seeds))
        strict = sonoslice.PoseSampler(dict(config, reject=rules), probe, ct, labels)
        n = min(len(seeds), 20000)
        accepted = best_rate(lambda: strict.sample(seeds[:n]), n, repeat=1)
        print(f"| {name} | {setup:.2f} | {candidates:,.0f} | {accepted:,.0f} |")


if __name__ == "__main__":
    main()
