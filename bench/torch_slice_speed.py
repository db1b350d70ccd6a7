#!/usr/bin/env python3
"""Differentiable slicing: `sonoslice.torch.slice` forward and backward (to the
poses) against the same loss through torch.nn.functional.grid_sample with autograd, on W1 poses
of the full phantom CT, CPU, in one run; each in its own process so that its peak memory (max
RSS above the process after loading the CT) is its own.

  build/venv/bin/python bench/torch_slice_speed.py [--phantom DIR] [--batch 32] [--threads 2]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

from benchcommon import CLI, W1, full_phantom_ct

RUN = r'''
import json, resource, sys, time
import numpy as np, torch, sonoslice, sonoslice.torch as st
kind, ct_path, poses_path, batch, threads = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5])
torch.set_num_threads(threads); sonoslice.set_threads(threads)
ct = sonoslice.Volume.from_file(ct_path)
probe = sonoslice.Probe.from_fanslicer(sys.argv[6], downsampling=2)
poses = np.load(poses_path)[:batch]
mask = torch.from_numpy(probe.mask.astype(bool))
geometry = json.loads(probe.to_json())["image"]
if kind == "grid_sample":
    vol = torch.from_numpy(np.ascontiguousarray(ct.array, np.float32))[None, None]
    direction = np.asarray(ct.direction).reshape(3, 3)
    M = torch.tensor(np.linalg.inv(direction @ np.diag(ct.spacing)))
    o = -M @ torch.tensor(np.asarray(ct.origin, float))
    H, W = geometry["height"], geometry["width"]
    x = geometry["origin_mm"][0] + torch.arange(W, dtype=torch.float64) * geometry["spacing_mm"][0]
    y = geometry["origin_mm"][1] + torch.arange(H, dtype=torch.float64) * geometry["spacing_mm"][1]
    P = torch.stack(torch.meshgrid(x, y, indexing="xy") + (torch.zeros(H, W, dtype=torch.float64),), -1)
    size = torch.tensor(vol.shape[2:][::-1], dtype=torch.float64)
    def forward(p):
        w = torch.einsum("nij,hwj->nhwi", p[:, :3, :3], P) + p[:, None, None, :3, 3]
        g = (2 * (w @ M.T + o) / (size - 1) - 1).float()
        img = torch.nn.functional.grid_sample(vol.expand(p.shape[0], -1, -1, -1, -1), g[:, None], mode="bilinear",
                                              align_corners=True)[:, 0, 0]
        return img * mask
else:
    forward = lambda p: st.slice(ct, p, probe)
float(np.asarray(ct.array).sum())  # every page of the CT read in before the baseline
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
fw, bw = [], []
for _ in range(5):
    p = torch.tensor(poses, requires_grad=True)
    t0 = time.perf_counter(); img = forward(p); t1 = time.perf_counter()
    img.float().square().mean().backward(); t2 = time.perf_counter()
    fw.append(t1 - t0); bw.append(t2 - t1)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"forward": float(np.median(fw)), "backward": float(np.median(bw)), "peak_mib": (peak - base) / 1024}))
'''


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phantom", help="a folder from `sonoslice phantom DIR --size full` (default: written)")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ct = full_phantom_ct(args.phantom, tmp)
        subprocess.run([CLI, "phantom", os.path.join(tmp, "p"), "--poses", str(args.batch), "-q"], check=True)
        poses = os.path.join(tmp, "p", "poses.npy")
        script = os.path.join(tmp, "run.py")
        with open(script, "w") as f:
            f.write(RUN)
        results = {}
        for kind in ("sonoslice", "grid_sample"):
            r = subprocess.run([sys.executable, script, kind, ct, poses, str(args.batch), str(args.threads), W1],
                               capture_output=True, text=True)
            if r.returncode != 0:
                sys.exit(r.stderr)
            results[kind] = json.loads(r.stdout.strip().splitlines()[-1])
    print(f"\nW1 (334x272), {args.batch} poses of the full phantom CT, loss mean(image^2), gradient to the "
          f"poses, {args.threads} threads, medians of 5\n")
    print("| | forward | backward | backward / forward | peak memory above the loaded CT |")
    print("|---|---|---|---|---|")
    names = {"sonoslice": "sonoslice.torch.slice", "grid_sample": "torch grid_sample + autograd"}
    for kind, r in results.items():
        print(f"| {names[kind]} | {r['forward']:.3f} s | {r['backward']:.3f} s | {r['backward'] / r['forward']:.2f} | "
              f"{r['peak_mib']:.0f} MiB |")


if __name__ == "__main__":
    main()
