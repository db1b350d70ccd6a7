#!/usr/bin/env python3
"""sonoslice on CUDA against torch.nn.functional.grid_sample on the same GPU, same run.

Same workloads and poses as peers.py (W1 fan, W2 linear, 1000 random poses inside the full
phantom). Two figures for each tool:
  on-GPU    images/s with the images left in GPU memory (what a training loop consumes);
            grid_sample's coordinates are built on the GPU too
  to host   images/s end to end into host memory, also as GB/s against this machine's
            device-to-host copy bandwidth (pinned memory, measured here with torch): into
            pageable memory (a NumPy array, `sonoslice bench`) and, through the Python API,
            into a pinned torch tensor (`pin_memory=True`), which the GPU's copies fill directly
Needs a CUDA build of sonoslice and a Python with torch on CUDA (the GPU machine's python3):
  python3 bench/peers_cuda.py [--count 1000] [--repeat 5]
"""
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from peers import (  # noqa: E402
    add_output_arguments, argument_parser, fanslicer_probe, grid_sample_setup, prepare_phantom,
    sonoslice_bench_record, workloads,
)


def grid_sample_cuda(vol, p, poses, origin, spacing, batch, repeat):
    import torch
    grid_for, sample = grid_sample_setup(vol, p, poses, origin, spacing, device="cuda")

    def run(to_host):
        outs = []
        for b0 in range(0, len(poses), batch):
            out = sample(grid_for(b0, min(len(poses), b0 + batch)))
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


def sonoslice_python_to_host(ct, cfg, ds, poses, repeat, device):
    """images/s of a float32 CUDA slicer (Python API) into a pageable NumPy array and into a pinned
    torch tensor of the whole batch, best of ``repeat``."""
    import torch

    import sonoslice
    volume = sonoslice.Volume.from_file(ct).astype("float32")
    slicer = sonoslice.Slicer(volume, sonoslice.Probe.from_fanslicer(cfg, ds), device=device)
    shape = (len(poses), slicer.height, slicer.width)
    rates = {}
    for name, out in (("pageable", np.empty(shape, np.float32)),
                      ("pinned", torch.empty(shape, dtype=torch.float32, pin_memory=True))):
        slicer.slice(poses, out=out)  # warm-up: touches every page once
        best = float("inf")
        for _ in range(repeat):
            t0 = time.perf_counter()
            slicer.slice(poses, out=out)
            best = min(best, time.perf_counter() - t0)
        rates[name] = len(poses) / best
    return rates


def pcie_bandwidth(device, gib=2, repeat=5):
    """Device -> host copy bandwidth (GB/s) into pinned memory: the ceiling of any to-host figure."""
    import torch
    n = gib << 30
    src = torch.empty(n, dtype=torch.uint8, device=device)
    dst = torch.empty(n, dtype=torch.uint8, pin_memory=True)
    dst.copy_(src)
    torch.cuda.synchronize()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        dst.copy_(src, non_blocking=True)
        torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t0)
    del src, dst
    return n / best / 1e9


def main():
    ap = argument_parser(__doc__)
    ap.add_argument("--count", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--batch", type=int, default=250, help="grid_sample images per call")
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--python-to-host", action="store_true",
                    help="only sonoslice's Python API into pageable and pinned host memory (its own run, "
                         "so that a failure there leaves the peer figures standing)")
    add_output_arguments(ap)
    args = ap.parse_args()

    _, ct, vol, origin, spacing, poses_file, poses = prepare_phantom(args.sonoslice, args.workdir, args.count,
                                                                     "sonoslice-peers-cuda-")
    results = []
    import torch
    print(f"GPU: {torch.cuda.get_device_name(args.device)}")
    pcie = pcie_bandwidth(args.device)
    print(f"device -> host copy into pinned memory: {pcie:.1f} GB/s")
    print(f"images/s on {args.device}, {len(poses)} poses, best of {args.repeat}")
    if not args.python_to_host:
        print(f"{'workload':8} {'tool':26} {'on-GPU':>10} {'to host':>10}")
    for name, cfg, ds in workloads(args.data):
        p = fanslicer_probe(cfg, ds)
        image_gb = p["W"] * p["H"] * 4 / 1e9  # float32 images
        if args.python_to_host:
            py = sonoslice_python_to_host(ct, cfg, ds, poses, args.repeat, args.device)
            for kind, rate in py.items():
                print(f"{name:8} sonoslice float32 (Python) into {kind} host memory: {rate:.0f} images/s = "
                      f"{rate * image_gb:.1f} GB/s = {100 * rate * image_gb / pcie:.0f} % of the device -> host "
                      "bandwidth")
            results.append({"workload": name, "python_to_host_images_per_s": py, "pcie_gb_per_s": pcie})
            continue
        ours = {}
        for t in ("float32", "int16"):
            r = sonoslice_bench_record(args.sonoslice, ct, cfg, ds, poses_file, t, args.repeat,
                                       ("--device", args.device))
            ours[t] = (r["device_images_per_second"], r["images_per_second"])
        gs_dev, gs_host, _ = grid_sample_cuda(vol, p, poses, origin, spacing, args.batch, args.repeat)
        for tool, (d, h) in [("sonoslice float32", ours["float32"]), ("sonoslice int16", ours["int16"]),
                             ("torch grid_sample float32", (gs_dev, gs_host))]:
            print(f"{name:8} {tool:26} {d:10.0f} {h:10.0f}")
        print(f"{name:8} ratio (sonoslice float32 / grid_sample): on-GPU {ours['float32'][0] / gs_dev:.2f}, "
              f"to host {ours['float32'][1] / gs_host:.2f}")
        # The bench slices into float32 images whatever the volume's type.
        to_host_gbs = ours["float32"][1] * image_gb
        print(f"{name:8} sonoslice to host: {to_host_gbs:.1f} GB/s = {100 * to_host_gbs / pcie:.0f} % of the "
              f"device -> host bandwidth")
        results.append({"workload": name, "sonoslice": ours, "grid_sample": {"device": gs_dev, "host": gs_host},
                        "to_host_gb_per_s": to_host_gbs, "pcie_gb_per_s": pcie})
    if args.json:
        json.dump(results, open(args.json, "w"), indent=2)


if __name__ == "__main__":
    main()
