#!/usr/bin/env python3
"""sonoslice on CUDA against torch.nn.functional.grid_sample on the same GPU, same run.

Same workloads and poses as peers.py (W1 fan, W2 linear, 1000 random poses inside the full
phantom). Two figures for each tool:
  on-GPU    images/s with the images left in GPU memory (what a training loop consumes);
            grid_sample's coordinates are built on the GPU too
  to host   images/s end to end into host memory
Needs a CUDA build of sonoslice and a Python with torch on CUDA (the GPU machine's python3):
  python3 bench/peers_cuda.py [--count 1000] [--repeat 5]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from peers import ROOT, fanslicer_probe, log, probe_mask  # noqa: E402


def grid_sample_cuda(vol, p, poses, origin, spacing, batch, repeat):
    import torch
    import torch.nn.functional as F
    dev = torch.device("cuda")
    v = torch.from_numpy(vol.astype(np.float32)).to(dev)[None, None]
    n = np.array(vol.shape[::-1], np.float64)
    mask = torch.from_numpy(probe_mask(p)).to(dev)
    x = torch.tensor(p["x0"] + np.arange(p["W"]) * p["sx"], dtype=torch.float32, device=dev)
    y = torch.tensor(np.arange(p["H"]) * p["sy"], dtype=torch.float32, device=dev)
    scale = torch.tensor(2 / ((n - 1) * spacing), dtype=torch.float32, device=dev)
    offset = torch.tensor(-2 * origin / ((n - 1) * spacing) - 1, dtype=torch.float32, device=dev)
    T = torch.tensor(poses, dtype=torch.float32, device=dev)

    def run(to_host):
        outs = []
        for b0 in range(0, len(poses), batch):
            b1 = min(len(poses), b0 + batch)
            Rx, Ry, t = T[b0:b1, :3, 0], T[b0:b1, :3, 1], T[b0:b1, :3, 3]
            world = (Rx[:, None, None, :] * x[None, None, :, None] + Ry[:, None, None, :] * y[None, :, None, None]
                     + t[:, None, None, :])
            out = F.grid_sample(v, (world * scale + offset)[None], mode="bilinear", padding_mode="zeros",
                                align_corners=True)[0, 0]
            out = torch.where(mask, out, torch.zeros((), dtype=out.dtype, device=dev))
            outs.append(out.cpu() if to_host else out)
        torch.cuda.synchronize()
        return outs

    run(False)  # warm-up
    best = {}
    for to_host in (False, True):
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            run(to_host)
            times.append(time.perf_counter() - t0)
        best[to_host] = len(poses) / min(times)
    first = run(False)[0][:5].cpu().numpy()
    return best[False], best[True], first


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sonoslice", default=os.path.join(ROOT, "build", "bin", "sonoslice"))
    ap.add_argument("--shared", default=os.path.join(ROOT, "..", "shared", "data", "fanslicer"))
    ap.add_argument("--count", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--batch", type=int, default=250, help="grid_sample images per call")
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--workdir")
    ap.add_argument("--json")
    args = ap.parse_args()

    work = args.workdir or tempfile.mkdtemp(prefix="sonoslice-peers-cuda-")
    os.makedirs(work, exist_ok=True)
    ct = os.path.join(work, "ct.npy")
    if not os.path.exists(ct):
        log("generating the full phantom ...")
        subprocess.run([args.sonoslice, "phantom", work, "--size", "full", "--format", "npy", "--poses",
                        str(args.count), "-q"], check=True)
    vol = np.ascontiguousarray(np.load(ct))
    geo = json.load(open(os.path.join(work, "ct.json")))
    origin, spacing = np.array(geo["origin"]), np.array(geo["spacing"])
    poses_file = os.path.join(work, "poses.npy")
    poses = np.load(poses_file)[: args.count]

    results = []
    print(f"images/s on {args.device}, {len(poses)} poses, best of {args.repeat}")
    print(f"{'workload':8} {'tool':26} {'on-GPU':>10} {'to host':>10}")
    for name, cfg, ds in [("W1", os.path.join(args.shared, "models_intensity_LUS_config.json"), 2),
                          ("W2", os.path.join(args.shared, "linear_config.json"), 1)]:
        p = fanslicer_probe(cfg, ds)
        ours = {}
        for t in ("float32", "int16"):
            out = subprocess.run([args.sonoslice, "bench", "--device", args.device, "--volume", ct, "--probe", cfg,
                                  "--downsampling", str(ds), "--poses", poses_file, "--as", t, "--repeat",
                                  str(args.repeat), "--json"], check=True, capture_output=True, text=True).stdout
            r = json.loads(out)[0]
            ours[t] = (r["device_images_per_second"], r["images_per_second"])
        gs_dev, gs_host, _ = grid_sample_cuda(vol, p, poses, origin, spacing, args.batch, args.repeat)
        for tool, (d, h) in [("sonoslice float32", ours["float32"]), ("sonoslice int16", ours["int16"]),
                             ("torch grid_sample float32", (gs_dev, gs_host))]:
            print(f"{name:8} {tool:26} {d:10.0f} {h:10.0f}")
        print(f"{name:8} ratio (sonoslice float32 / grid_sample): on-GPU {ours['float32'][0] / gs_dev:.2f}, "
              f"to host {ours['float32'][1] / gs_host:.2f}")
        results.append({"workload": name, "sonoslice": ours, "grid_sample": {"device": gs_dev, "host": gs_host}})
    if args.json:
        json.dump(results, open(args.json, "w"), indent=2)


if __name__ == "__main__":
    main()
