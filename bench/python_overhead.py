#!/usr/bin/env python3
"""The Python package's overhead against the CLI's slicing time, same run, same inputs:
W1 (334x272 fan) on the full phantom (int16), 1000 random poses, best of --repeat.

The CLI figure is `sonoslice bench`'s (the slicing call alone, inside the C++ program); the
Python figure is `Slicer.slice(poses, out=preallocated)`, which also converts the poses,
checks the output array and releases/reacquires the GIL.

    build/venv/bin/python bench/python_overhead.py [--repeat 7]
"""
import argparse
import json
import os
import subprocess
import tempfile
import time

import numpy as np

import sonoslice

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sonoslice", default=os.path.join(ROOT, "build", "bin", "sonoslice"))
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--count", type=int, default=1000)
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix="sonoslice-pyoverhead-")
    ct, _ = sonoslice.phantom("full")
    ct.save(os.path.join(work, "ct.npy"))
    probe = sonoslice.Probe.workload("W1")
    with open(os.path.join(work, "w1.json"), "w") as f:
        f.write(probe.to_json())
    poses = sonoslice.phantom_poses(args.count)
    np.save(os.path.join(work, "poses.npy"), poses)

    volume = sonoslice.Volume.from_file(os.path.join(work, "ct.npy"))
    slicer = sonoslice.Slicer(volume, probe)
    out = np.empty((args.count, probe.height, probe.width), np.float32)
    slicer.slice(poses[:32], out=out[:32])
    cli_best, py_best = [], []
    for _ in range(args.repeat):  # interleaved, so both see the same machine load
        r = subprocess.run([args.sonoslice, "bench", "--volume", os.path.join(work, "ct.npy"), "--probe",
                            os.path.join(work, "w1.json"), "--poses", os.path.join(work, "poses.npy"),
                            "--repeat", "3", "--json"], check=True, capture_output=True, text=True)
        cli_best.append(json.loads(r.stdout)[0]["best_seconds"])
        for _ in range(3):
            t = time.perf_counter()
            slicer.slice(poses, out=out)
            py_best.append(time.perf_counter() - t)
    cli, py = min(cli_best), min(py_best)
    print(f"W1, {args.count} poses, int16 full phantom, best of {3 * args.repeat}:")
    print(f"  CLI slicing  {cli * 1000:8.1f} ms")
    print(f"  Python       {py * 1000:8.1f} ms   overhead {100 * (py / cli - 1):+.1f} %")


if __name__ == "__main__":
    main()
