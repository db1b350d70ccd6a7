#!/usr/bin/env python3
"""Splatting speed on a long real-frame sweep: 500 frames of 820x616 pixels,
splatting time only, as `sonoslice compound --verbose` reports it, in frame pixels per second.

The workload: the 21 real frames of PLUS's BoneUltrasound_L14 sweep (data/plus) cycled to 500,
with its calibration and 0.5 mm output spacing, along a 60 mm freehand sweep that follows the
recorded sweep's direction, every pose jittered by up to ±1 mm and ±2° (seeded), written as an
uncompressed .igs.mha so that reading costs little. PLUS's figures (310 M px/s nearest, 35 M px/s
linear, 2 threads, 820x616 frames, paste time) are the ones the compounding issue measured on
this machine kind; PLUS is not built here, so they are quoted, not re-measured.

  build/venv/bin/python bench/splat_speed.py [--frames 500] [--threads 2] [--repeat 5]
      [--baseline OTHER/sonoslice]   # alternate runs with another build, report both
      [--roofline]                   # where the time goes (bench/README.md)

This machine is shared: other tenants' memory traffic moves single runs by ±30 %, so runs of the
two builds alternate and the median and the minimum of each are reported.
"""
import argparse
import os
import re
import statistics
import subprocess
import tempfile
import time

import numpy as np

from sonoslice.plus import read_plus_sequence, write_plus_sequence

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

PLUS_PX_PER_S = {"nearest": 310e6, "linear": 35e6}
SPLAT = re.compile(r"splatting ([0-9.]+) s")


def rotation(axis, angle):
    """Rodrigues' rotation matrix about a unit axis."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def write_workload(path, frames, jitter_mm=1.0, jitter_deg=2.0, length_mm=60.0, seed=12):
    seq = read_plus_sequence(os.path.join(ROOT, "data", "plus", "BoneUltrasound_L14.igs.mha"))
    first, last = seq.transform(0, "ProbeToTracker"), seq.transform(len(seq) - 1, "ProbeToTracker")
    reference = seq.transform(0, "ReferenceToTracker")
    direction = last[:3, 3] - first[:3, 3]
    direction /= np.linalg.norm(direction)
    rng = np.random.default_rng(seed)
    images = np.empty((frames,) + seq.frames.shape[1:], seq.frames.dtype)
    fields = []
    for k in range(frames):
        images[k] = seq.frames[k % len(seq)]
        pose = first.copy()
        axis = rng.normal(size=3)
        pose[:3, :3] = rotation(axis / np.linalg.norm(axis), np.radians(rng.uniform(-jitter_deg, jitter_deg))) @ first[:3, :3]
        pose[:3, 3] = first[:3, 3] + direction * (length_mm * k / frames) + rng.uniform(-jitter_mm, jitter_mm, 3)
        fields.append({"ProbeToTrackerTransform": pose, "ProbeToTrackerTransformStatus": "OK",
                       "ReferenceToTrackerTransform": reference, "ReferenceToTrackerTransformStatus": "OK",
                       "Timestamp": 0.05 * k, "ImageStatus": "OK"})
    write_plus_sequence(path, images, fields, compress=False)
    return images.shape


def splat_seconds(cli, sequence, out, interp, threads, spacing=None):
    cmd = [cli, "compound", "--sequence", sequence,
           "--config", os.path.join(ROOT, "data", "plus", "BoneUltrasound_L14_config.xml"),
           "--interp", interp, "--out", out, "--threads", str(threads), "--verbose"]
    if spacing:
        cmd += ["--spacing", str(spacing)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"splat_speed: {' '.join(cmd)} failed ({r.returncode}): {r.stderr.strip()}")
    m = SPLAT.search(r.stderr)
    if not m:
        raise SystemExit("splat_speed: no splatting time in sonoslice compound --verbose")
    return float(m.group(1))


def roofline(cli, sequence, workdir, pixels, repeat):
    """The parts of a splat's cost, one thread, best of `repeat`: reading the frames; the
    per-pixel arithmetic alone (4 mm voxels: the accumulators fit in L2 and runs are ~50 pixels,
    so there are almost no writes); and the accumulator writes (0.5 mm minus 4 mm)."""
    frames = read_plus_sequence(sequence).frames
    words = frames.reshape(-1)[: frames.size // 8 * 8].view(np.uint64)
    best = min(timed(lambda: int(words.sum())) for _ in range(repeat))
    print(f"reading the frames: {best:.3f} s ({frames.nbytes / best / 1e9:.1f} GB/s, {best / pixels * 1e9:.2f} ns/px)")
    out = os.path.join(workdir, "roofline.mha")
    for interp in ("nearest", "linear"):
        t = {sp: min(splat_seconds(cli, sequence, out, interp, 1, sp) for _ in range(repeat)) for sp in (4, 0.5)}
        print(f"{interp:8s} arithmetic (4 mm voxels) {t[4]:.3f} s ({t[4] / pixels * 1e9:.2f} ns/px); "
              f"+ accumulator writes (0.5 mm) {t[0.5] - t[4]:+.3f} s; total {t[0.5]:.3f} s, 1 thread")


def timed(f):
    t0 = time.perf_counter()
    f()
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sonoslice", default=os.path.join(ROOT, "build", "bin", "sonoslice"))
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5, help="runs per interpolation and build")
    ap.add_argument("--baseline", help="another sonoslice binary to time in the same run (e.g. the previous commit)")
    ap.add_argument("--jitter-mm", type=float, default=1.0)
    ap.add_argument("--jitter-deg", type=float, default=2.0)
    ap.add_argument("--roofline", action="store_true", help="also time the parts of a splat (one thread)")
    args = ap.parse_args()
    builds = [("sonoslice", args.sonoslice)] + ([("baseline", args.baseline)] if args.baseline else [])
    with tempfile.TemporaryDirectory(prefix="sonoslice-splat-") as workdir:
        sequence = os.path.join(workdir, "sweep.igs.mha")
        n, h, w = write_workload(sequence, args.frames, args.jitter_mm, args.jitter_deg)
        pixels = n * h * w
        print(f"{n} frames of {w}x{h} ({pixels / 1e6:.1f} M px), jitter ±{args.jitter_mm} mm ±{args.jitter_deg}°, "
              f"{args.threads} threads, {args.repeat} runs each (median, min)")
        for interp in ("nearest", "linear"):
            out = os.path.join(workdir, f"{interp}.mha")
            times = {name: [] for name, _ in builds}
            for name, cli in builds:
                splat_seconds(cli, sequence, out, interp, args.threads)  # warm-up
            for _ in range(args.repeat):
                for name, cli in builds:
                    times[name].append(splat_seconds(cli, sequence, out, interp, args.threads))
            for name, _ in builds:
                t = statistics.median(times[name])
                rate = pixels / t
                print(f"{interp:8s} {name:9s} splatting {t:.3f} s (min {min(times[name]):.3f})  "
                      f"{rate / 1e6:7.1f} M px/s  {rate / PLUS_PX_PER_S[interp]:.2f}x PLUS "
                      f"({PLUS_PX_PER_S[interp] / 1e6:.0f} M px/s)")
            if args.baseline:
                print(f"{interp:8s} sonoslice / baseline: {statistics.median(times['baseline']) / statistics.median(times['sonoslice']):.2f}x")
        if args.roofline:
            roofline(args.sonoslice, sequence, workdir, pixels, args.repeat)

if __name__ == "__main__":
    main()
