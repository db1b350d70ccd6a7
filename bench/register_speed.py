#!/usr/bin/env python3
"""Registration speed: pose evaluations per second at full W1 resolution (334x272 fan, NCC, the
cost, its 6 derivatives and, for sonoslice, the 6x6 Gauss-Newton matrix), sonoslice against the
loop users build by hand today: torch.nn.functional.grid_sample on the same CT with autograd to
a 6-vector pose increment (forward and backward), on the CPU with the same thread count.

  build/venv/bin/python bench/register_speed.py [--phantom DIR] [--frames 20] [--threads 2]

sonoslice's figure is `sonoslice register --pyramid 1 -v` on frames 2 mm and 2 degrees off
(evaluations / registration seconds: every evaluation of the optimiser, with or without
derivatives, plus the optimiser's own arithmetic). The peer runs in Debian's Python
(/usr/bin/python3, torch 1.13) on the volume and masked pixel coordinates this script exports.

Then what an ultrasound user waits for: `--ultrasound N` simulated W1 B-mode frames (`sonoslice
simulate --preset lus` at the true poses) registered from 2 mm and 2 degrees off at the defaults
(LC2, automatic starts): one frame alone, and the N frames together (seconds a frame). No
published tool registers B-mode to CT with LC2 to compare with; `--baseline OTHER/sonoslice`
runs another build on the same frames in the same run (and says whether the poses agree).
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

import numpy as np

import sonoslice

from benchcommon import CLI, W1, full_phantom_ct

PEER = r'''
import sys, time, numpy as np, torch
d = np.load(sys.argv[1]); threads = int(sys.argv[2]); batch = int(sys.argv[3])
torch.set_num_threads(threads)
vol = torch.from_numpy(d["volume"]).float()[None, None]          # (1, 1, Z, Y, X)
L = torch.from_numpy(d["world_to_index"]).double(); o = torch.from_numpy(d["offset"]).double()
pts = torch.from_numpy(d["probe_points"]).double()                # (P, 3) masked pixels, probe mm
poses = torch.from_numpy(d["poses"]).double()                     # (N, 4, 4)
frames = torch.from_numpy(d["frames"]).float()                    # (N, P)
size = torch.tensor(vol.shape[2:][::-1], dtype=torch.float64)     # (X, Y, Z)
def ncc(a, b):
    a = a - a.mean(-1, keepdim=True); b = b - b.mean(-1, keepdim=True)
    return (a * b).sum(-1) / torch.sqrt((a * a).sum(-1) * (b * b).sum(-1))
def evaluate(k0):
    P = poses[k0:k0 + batch]; B = P.shape[0]
    xi = torch.zeros(B, 6, dtype=torch.float64, requires_grad=True)
    w = pts @ P[:, :3, :3].transpose(1, 2) + P[:, None, :3, 3]     # (B, P, 3)
    c = w.mean(1, keepdim=True)
    w = w + xi[:, None, :3] + torch.cross(xi[:, None, 3:].expand_as(w), w - c, dim=-1)
    idx = w @ L.T + o
    g = (2 * idx / (size - 1) - 1).float()
    I = torch.nn.functional.grid_sample(vol.expand(B, -1, -1, -1, -1), g[:, None, None], mode="bilinear",
                                        align_corners=True).reshape(B, -1)
    loss = (1 - ncc(I, frames[k0:k0 + B])).sum()
    loss.backward()
    return xi.grad
n = poses.shape[0]
evaluate(0)
t = time.perf_counter(); count = 0
while time.perf_counter() - t < 5:
    for k in range(0, n, batch):
        evaluate(k); count += min(batch, n - k)
print(count / (time.perf_counter() - t))
'''


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phantom", help="a folder from `sonoslice phantom DIR --size full` (default: written)")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--peer-python", default="/usr/bin/python3")
    ap.add_argument("--ultrasound", type=int, default=4,
                    help="simulated B-mode frames registered at the defaults (LC2); 0: skip")
    ap.add_argument("--baseline", help="another sonoslice CLI for the ultrasound frames")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ct_path = full_phantom_ct(args.phantom, tmp)
        subprocess.run([CLI, "phantom", os.path.join(tmp, "p"), "--poses", str(args.frames), "-q"], check=True)
        truth = np.load(os.path.join(tmp, "p", "poses.npy"))[: args.frames]
        ct = sonoslice.Volume.from_file(ct_path)
        probe = sonoslice.Probe.from_fanslicer(W1, downsampling=2)
        frames = sonoslice.Slicer(ct, probe).slice(truth).astype(np.float32)
        frames += np.random.default_rng(1).normal(0, 20, frames.shape).astype(np.float32)
        np.save(os.path.join(tmp, "frames.npy"), frames)
        # 2 mm and 2 degrees off: a translation along a random direction and a turn about z.
        rng = np.random.default_rng(2)
        init = truth.copy()
        for p in init:
            d = rng.normal(size=3)
            p[:3, 3] += 2 * d / np.linalg.norm(d)
            a = np.deg2rad(2)
            p[:3, :3] = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) @ p[:3, :3]
        np.save(os.path.join(tmp, "init.npy"), init)
        run = subprocess.run([CLI, "register", "--volume", ct_path, "--probe", W1, "--downsampling", "2",
                              "--frames", os.path.join(tmp, "frames.npy"), "--poses", os.path.join(tmp, "init.npy"),
                              "--out", os.path.join(tmp, "out.npy"), "--pyramid", "1", "--threads",
                              str(args.threads), "-v"], capture_output=True, text=True)
        if run.returncode != 0:
            sys.exit(run.stderr)
        ours = float(re.search(r"([0-9.]+) per second", run.stderr).group(1))

        # The peer's inputs: the volume (z, y, x), its world → index map, the masked pixels.
        geometry = json.loads(probe.to_json())["image"]
        v, u = np.nonzero(probe.mask)
        pts = np.stack([geometry["origin_mm"][0] + u * geometry["spacing_mm"][0],
                        geometry["origin_mm"][1] + v * geometry["spacing_mm"][1], np.zeros(len(u))], 1)
        direction = np.asarray(ct.direction).reshape(3, 3)
        M = np.linalg.inv(direction @ np.diag(ct.spacing))
        np.savez(os.path.join(tmp, "peer.npz"), volume=np.ascontiguousarray(ct.array, np.float32),
                 world_to_index=M, offset=-M @ np.asarray(ct.origin), probe_points=pts, poses=init,
                 frames=frames[:, v, u])
        with open(os.path.join(tmp, "peer.py"), "w") as f:
            f.write(PEER)
        rates = {}
        for batch in (1, 8):
            peer = subprocess.run([args.peer_python, os.path.join(tmp, "peer.py"), os.path.join(tmp, "peer.npz"),
                                   str(args.threads), str(batch)], capture_output=True, text=True)
            if peer.returncode != 0:
                sys.exit(peer.stderr)
            rates[batch] = float(peer.stdout.strip().splitlines()[-1])
        ultrasound = ultrasound_frames(args, tmp, ct_path, truth, init) if args.ultrasound else []
    print(f"\nW1 (334x272 fan, {len(pts)} pixels), NCC, full resolution, {args.threads} threads\n")
    print("| | pose evaluations/s | sonoslice ratio |")
    print("|---|---|---|")
    print(f"| sonoslice register --pyramid 1 (value, gradient, 6x6 matrix) | {ours:.0f} | |")
    for batch, rate in rates.items():
        print(f"| torch grid_sample + autograd, batch {batch} (value, gradient) | {rate:.0f} | {ours / rate:.1f}x |")
    print("\ntarget: >= 2,000 pose evaluations/s (an earlier one: 10,000)")
    if ultrasound:
        n = min(args.ultrasound, len(truth))
        print(f"\nSimulated W1 B-mode frames, 2 mm and 2 deg off, defaults (LC2, automatic starts), "
              f"{args.threads} threads\n")
        print(f"| build | one frame alone (s) | {n} frames (s a frame) | same poses as the first |")
        print("|---|---|---|---|")
        for name, one, each, same in ultrasound:
            print(f"| {name} | {one:.2f} | {each:.2f} | {same} |")
        print("\ntarget: <= 0.5 s a frame")


def ultrasound_frames(args, tmp, ct_path, truth, init):
    """(build, seconds for one frame, seconds a frame for N, same poses) for this CLI, then the
    baseline."""
    n = min(args.ultrasound, len(truth))
    np.save(os.path.join(tmp, "us_truth.npy"), truth[:n])
    subprocess.run([CLI, "simulate", "--volume", ct_path, "--preset", "lus", "--poses",
                    os.path.join(tmp, "us_truth.npy"), "--out", os.path.join(tmp, "us.npy"),
                    "--output", "bmode", "-q"], check=True)
    frames = np.load(os.path.join(tmp, "us.npy")).astype(np.float32)
    for count in (1, n):
        np.save(os.path.join(tmp, f"us_{count}.npy"), frames[:count])
        np.save(os.path.join(tmp, f"us_init_{count}.npy"), init[:count])
    clis = [("this build", CLI)] + ([("baseline", args.baseline)] if args.baseline else [])
    rows = []
    first = None  # this build's poses for the N frames
    for name, cli in clis:
        seconds = []
        for count in (1, n):
            out = os.path.join(tmp, f"us_out_{count}.npy")
            run = subprocess.run([cli, "register", "--volume", ct_path, "--probe", W1, "--downsampling", "2",
                                  "--frames", os.path.join(tmp, f"us_{count}.npy"), "--poses",
                                  os.path.join(tmp, f"us_init_{count}.npy"), "--metric", "lc2", "--out", out,
                                  "--threads", str(args.threads), "-v"], capture_output=True, text=True)
            if run.returncode != 0:
                sys.exit(run.stderr)
            seconds.append(float(re.search(r"register ([0-9.]+) s", run.stderr).group(1)) / count)
        poses = np.load(out)
        first = poses if first is None else first
        same = bool(np.array_equal(first, poses))
        rows.append((name, seconds[0], seconds[1], "yes" if same else "no"))
    return rows


if __name__ == "__main__":
    main()
