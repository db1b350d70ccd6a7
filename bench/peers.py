#!/usr/bin/env python3
"""sonoslice against the tools people slice volumes with today, on the same workloads, in one run.

Workloads:
  W1  fan-slicer's LUS fan (models_intensity_LUS_config.json, --downsampling 2): 334x272 px at
      0.247 mm, 36 deg sector, on the full phantom (512x512x400, 0.8x0.8x1 mm).
  W2  fan-slicer's linear probe (linear_config.json): 400x500 px at 0.1235 mm.
Poses: 1000 random poses inside the body (the phantom command writes them).

Peers, each with the same thread count where it has threads:
  torch.nn.functional.grid_sample  (trilinear, coordinates built in torch)
  vtkImageReslice                  (linear interpolation, one image per Update)
  scipy.ndimage.map_coordinates    (order=1; single-threaded by design)

"sampling only" times the interpolation call with coordinates prepared beforehand; "end to end"
includes building the coordinates from the poses (and, for fans, blanking outside the fan).
sonoslice computes coordinates inside its kernel, so its two figures are the same call.

Runs with Debian's Python, which has torch, vtk, scipy and numpy:
  /usr/bin/python3 bench/peers.py [--threads 2] [--count 1000]
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def log(*a):
    print(*a, file=sys.stderr, flush=True)


# ---- geometry (docs/conventions.md §2-§4) ----------------------------------------------------------------------
def fanslicer_probe(path, ds):
    """docs/conventions.md §4: a fan-slicer config → image grid and fan parameters (mm)."""
    sim = json.load(open(path))["simulation"]
    W, H = (int(d) // ds for d in sim["image_dimensions"])
    sx, sy = (ds * p for p in sim["pixel_size"])
    probe = {"W": W, "H": H, "sx": sx, "sy": sy}
    if sim.get("transducer", "curvilinear") == "curvilinear":
        _, da, theta, A, C, B = sim["fan_geometry"]
        probe.update(type="curvilinear", x0=-W * sx / 2, R=C * da, D=A * da, theta=theta, face=B * da)
    else:
        probe.update(type="linear", x0=-(W // 2) * sx)
    return probe


def probe_mask(p):
    x = p["x0"] + np.arange(p["W"]) * p["sx"]
    y = np.arange(p["H"]) * p["sy"]
    X, Y = np.meshgrid(x, y)
    if p["type"] == "linear":
        return np.ones((p["H"], p["W"]), bool)
    dy = Y - (p["face"] - p["R"])
    r, phi = np.hypot(X, dy), np.arctan2(X, dy)
    return (r >= p["R"]) & (r <= p["R"] + p["D"]) & (np.abs(phi) <= np.deg2rad(p["theta"]) / 2)


def index_coordinates(p, poses, origin, spacing):
    """(N, H, W, 3) continuous indices (x, y, z) of every pixel; identity direction."""
    x = p["x0"] + np.arange(p["W"]) * p["sx"]
    y = np.arange(p["H"]) * p["sy"]
    R, t = poses[:, :3, :3], poses[:, :3, 3]
    world = (R[:, None, None, :, 0] * x[None, None, :, None] + R[:, None, None, :, 1] * y[None, :, None, None]
             + t[:, None, None, :])
    return (world - origin) / spacing


# ---- peers ---------------------------------------------------------------------------------------
def grid_sample_setup(vol, p, poses, origin, spacing, device="cpu"):
    """torch.nn.functional.grid_sample slicing ``vol`` with probe ``p`` at ``poses``, its tensors on
    ``device``: returns ``grid_for(b0, b1)``, the sampling grid of poses[b0:b1] (built in torch, as a
    training pipeline would), and ``sample(grid)``, the (b1 - b0, H, W) images (trilinear, zero
    outside the volume and the fan)."""
    import torch
    import torch.nn.functional as F
    dev = torch.device(device)
    v = torch.from_numpy(vol.astype(np.float32)).to(dev)[None, None]
    n = np.array(vol.shape[::-1], np.float64)  # (nx, ny, nz)
    mask = torch.from_numpy(probe_mask(p)).to(dev)
    x = torch.tensor(p["x0"] + np.arange(p["W"]) * p["sx"], dtype=torch.float32, device=dev)
    y = torch.tensor(np.arange(p["H"]) * p["sy"], dtype=torch.float32, device=dev)
    scale = torch.tensor(2 / ((n - 1) * spacing), dtype=torch.float32, device=dev)
    offset = torch.tensor(-2 * origin / ((n - 1) * spacing) - 1, dtype=torch.float32, device=dev)
    T = torch.tensor(poses, dtype=torch.float32, device=dev)

    def grid_for(b0, b1):
        Rx, Ry, t = T[b0:b1, :3, 0], T[b0:b1, :3, 1], T[b0:b1, :3, 3]
        world = (Rx[:, None, None, :] * x[None, None, :, None] + Ry[:, None, None, :] * y[None, :, None, None]
                 + t[:, None, None, :])
        return (world * scale + offset)[None]  # normalised, align_corners=True

    def sample(grid):
        out = F.grid_sample(v, grid, mode="bilinear", padding_mode="zeros", align_corners=True)[0, 0]
        return torch.where(mask, out, torch.zeros((), dtype=out.dtype, device=dev))

    return grid_for, sample


def bench_grid_sample(vol, p, poses, origin, spacing, threads, batch=50):
    import torch
    torch.set_num_threads(threads)
    grid_for, sample = grid_sample_setup(vol, p, poses, origin, spacing)
    sampling = end_to_end = 0.0
    first = None
    for b0 in range(0, len(poses), batch):
        b1 = min(len(poses), b0 + batch)
        t0 = time.perf_counter()
        g = grid_for(b0, b1)
        t1 = time.perf_counter()
        out = sample(g)
        t2 = time.perf_counter()
        sampling += t2 - t1
        end_to_end += t2 - t0
        if first is None:
            first = out[:5].numpy().copy()
    return len(poses) / sampling, len(poses) / end_to_end, first


def bench_vtk(vol, p, poses, origin, spacing, threads, count):
    import vtk
    from vtk.util import numpy_support as ns
    img = vtk.vtkImageData()
    img.SetDimensions(*vol.shape[::-1])
    img.SetSpacing(*spacing)
    img.SetOrigin(*origin)
    arr = ns.numpy_to_vtk(vol.ravel(), deep=False)
    img.GetPointData().SetScalars(arr)
    r = vtk.vtkImageReslice()
    r.SetInputData(img)
    r.SetInterpolationModeToLinear()
    r.SetOutputExtent(0, p["W"] - 1, 0, p["H"] - 1, 0, 0)
    r.SetOutputSpacing(p["sx"], p["sy"], 1)
    r.SetOutputOrigin(p["x0"], 0, 0)
    r.SetBackgroundLevel(0)
    r.SetNumberOfThreads(threads)
    m = vtk.vtkMatrix4x4()
    count = min(count, len(poses))
    t0 = time.perf_counter()
    for i in range(count):
        for a in range(4):
            for b in range(4):
                m.SetElement(a, b, poses[i, a, b])
        r.SetResliceAxes(m)
        r.Update()
        out = ns.vtk_to_numpy(r.GetOutput().GetPointData().GetScalars())
    dt = time.perf_counter() - t0
    del out
    return count / dt


def bench_map_coordinates(vol, p, poses, origin, spacing, count):
    from scipy import ndimage
    v = vol.astype(np.float32)
    count = min(count, len(poses))
    t0 = time.perf_counter()
    c = index_coordinates(p, poses[:count], origin, spacing)
    coords = np.stack([c[..., 2].ravel(), c[..., 1].ravel(), c[..., 0].ravel()])  # (z, y, x)
    t1 = time.perf_counter()
    ndimage.map_coordinates(v, coords, order=1, mode="constant", cval=0.0, prefilter=False)
    t2 = time.perf_counter()
    return count / (t2 - t1), count / (t2 - t0)


# ---- sonoslice -----------------------------------------------------------------------------------
def sonoslice_bench_record(exe, volume, probe_file, ds, poses_file, as_type, repeat, options=()):
    """What ``sonoslice bench --json`` reports for one volume, probe and output type; ``options``:
    more of its options (("--threads", "8"), ("--device", "cuda:0"))."""
    out = subprocess.run([exe, "bench", "--volume", volume, "--probe", probe_file, "--downsampling", str(ds),
                          "--poses", poses_file, "--as", as_type, *options, "--repeat", str(repeat), "--json"],
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out)[0]


def sonoslice_bench(exe, volume, probe_file, ds, poses_file, as_type, threads, repeat):
    return sonoslice_bench_record(exe, volume, probe_file, ds, poses_file, as_type, repeat,
                                  ("--threads", str(threads)))["images_per_second"]


def sonoslice_slice(exe, volume, probe_file, ds, poses_file, threads, out):
    r = subprocess.run([exe, "slice", "--volume", volume, "--probe", probe_file, "--downsampling", str(ds),
                        "--poses", poses_file, "--out", out, "--threads", str(threads), "--verbose", "-q"],
                       check=True, capture_output=True, text=True)
    m = re.search(r"load ([\d.]+) s, slice ([\d.]+) s .* write ([\d.]+) s, total ([\d.]+) s", r.stderr)
    return {k: float(v) for k, v in zip(("load", "slice", "write", "total"), m.groups())}


# ---- the run ------------------------------------------------------------------------------------
def argument_parser(doc):
    """The options every peer benchmark takes first: the sonoslice binary and fan-slicer's configs."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sonoslice", default=os.path.join(ROOT, "build", "bin", "sonoslice"))
    ap.add_argument("--data", default=os.path.join(ROOT, "data", "fanslicer"),
                    help="folder of the fan-slicer configs (default: the repository's data/fanslicer)")
    return ap


def add_output_arguments(ap):
    """The options every peer benchmark takes last: where its phantom and results go."""
    ap.add_argument("--workdir", help="keep the phantom and outputs here (default: a temp dir)")
    ap.add_argument("--json", help="also write the results here")


def workloads(data):
    """(name, fan-slicer config, downsampling) of W1 and W2."""
    return [("W1", os.path.join(data, "models_intensity_LUS_config.json"), 2),
            ("W2", os.path.join(data, "linear_config.json"), 1)]


def prepare_phantom(exe, workdir, count, prefix):
    """The full phantom and ``count`` random poses in ``workdir`` (default: a new temp dir named
    ``prefix``...), made by ``sonoslice phantom`` unless already there. Returns (work dir, ct.npy's
    path, the CT as a C-contiguous array, origin, spacing, poses.npy's path, the poses)."""
    work = workdir or tempfile.mkdtemp(prefix=prefix)
    os.makedirs(work, exist_ok=True)
    ct = os.path.join(work, "ct.npy")
    if not os.path.exists(ct):
        log("generating the full phantom ...")
        subprocess.run([exe, "phantom", work, "--size", "full", "--format", "npy", "--poses", str(count), "-q"],
                       check=True)
    vol = np.load(ct, mmap_mode="r")
    geo = json.load(open(os.path.join(work, "ct.json")))
    assert np.allclose(np.array(geo["direction"]).reshape(3, 3), np.eye(3)), "phantom direction is identity"
    origin, spacing = np.array(geo["origin"]), np.array(geo["spacing"])
    poses_file = os.path.join(work, "poses.npy")
    poses = np.load(poses_file)[:count]
    return work, ct, np.ascontiguousarray(vol), origin, spacing, poses_file, poses


def main():
    ap = argument_parser(__doc__)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--count", type=int, default=1000, help="poses per workload")
    ap.add_argument("--slow-count", type=int, default=100,
                    help="images for the slow peers (vtkImageReslice, map_coordinates)")
    ap.add_argument("--repeat", type=int, default=3)
    add_output_arguments(ap)
    args = ap.parse_args()

    work, ct, vol, origin, spacing, poses_file, poses = prepare_phantom(args.sonoslice, args.workdir, args.count,
                                                                        "sonoslice-peers-")
    results = []
    table = []
    for name, cfg, ds in workloads(args.data):
        p = fanslicer_probe(cfg, ds)
        log(f"{name}: {p['W']}x{p['H']} {p['type']}, {len(poses)} poses, {args.threads} threads")
        ours = {t: sonoslice_bench(args.sonoslice, ct, cfg, ds, poses_file, t, args.threads, args.repeat)
                for t in ("float32", "int16")}
        cli = sonoslice_slice(args.sonoslice, ct, cfg, ds, poses_file, args.threads, os.path.join(work, name + ".npy"))
        gs_sampling, gs_e2e, gs_first = bench_grid_sample(vol, p, poses, origin, spacing, args.threads)
        vtk_f32 = bench_vtk(vol.astype(np.float32), p, poses, origin, spacing, args.threads, args.slow_count)
        vtk_i16 = bench_vtk(vol, p, poses, origin, spacing, args.threads, args.slow_count)
        mc_sampling, mc_e2e = bench_map_coordinates(vol, p, poses, origin, spacing, min(args.slow_count, 50))

        # Same computation? Compare sonoslice's first images with grid_sample's inside the fan,
        # away from the volume border (where zero padding and docs/conventions.md §5's clamping differ).
        mine = np.load(os.path.join(work, name + ".npy"), mmap_mode="r")[:5]
        c = index_coordinates(p, poses[:5], origin, spacing)
        n = np.array(vol.shape[::-1])
        interior = np.all((c >= 0) & (c <= n - 1), axis=-1) & probe_mask(p)[None]
        diff = float(np.abs(mine[interior] - gs_first[interior]).max()) if interior.any() else float("nan")

        best = max(ours.values())
        rows = [("sonoslice float32", ours["float32"], ours["float32"]),
                ("sonoslice int16", ours["int16"], ours["int16"]),
                ("torch grid_sample", gs_sampling, gs_e2e),
                ("vtkImageReslice float32", vtk_f32, vtk_f32),
                ("vtkImageReslice int16", vtk_i16, vtk_i16),
                ("scipy map_coordinates (1 thread)", mc_sampling, mc_e2e)]
        for peer, sampling, e2e in rows:
            mine = peer.startswith("sonoslice")
            table.append((name, peer, sampling, e2e, None if mine else ours["float32"] / sampling,
                          None if mine else ours["float32"] / e2e, None if mine else ours["int16"] / e2e))
        results.append({"workload": name, "width": p["W"], "height": p["H"], "threads": args.threads,
                        "poses": len(poses), "sonoslice": ours, "sonoslice_cli_seconds": cli,
                        "grid_sample": {"sampling": gs_sampling, "end_to_end": gs_e2e},
                        "vtkImageReslice": {"float32": vtk_f32, "int16": vtk_i16},
                        "map_coordinates": {"sampling": mc_sampling, "end_to_end": mc_e2e},
                        "max_abs_difference_vs_grid_sample_HU": diff,
                        "ratios_float32": {"grid_sample_sampling": ours["float32"] / gs_sampling,
                                           "grid_sample_end_to_end": ours["float32"] / gs_e2e,
                                           "vtkImageReslice": ours["float32"] / max(vtk_f32, vtk_i16),
                                           "map_coordinates": ours["float32"] / mc_sampling},
                        "best_sonoslice": best})
        log(f"{name}: sonoslice vs grid_sample on 5 images, max |difference| inside the fan: {diff:.3g} HU; "
            f"CLI end to end {cli['total']:.2f} s (load {cli['load']:.2f}, slice {cli['slice']:.2f}, "
            f"write {cli['write']:.2f})")

    print(f"\nimages/s, {args.threads} threads, same run; ratios = sonoslice's images/s / the peer's")
    print(f"{'workload':8} {'tool':34} {'sampling only':>14} {'end to end':>11} {'f32/peer':>9} "
          f"{'f32/peer e2e':>13} {'i16/peer e2e':>13}")
    fmt = lambda r: f"{r:.2f}" if r is not None else "-"  # noqa: E731
    for name, peer, s, e, rs, re_, ri in table:
        print(f"{name:8} {peer:34} {s:14.0f} {e:11.0f} {fmt(rs):>9} {fmt(re_):>13} {fmt(ri):>13}")
    if args.json:
        json.dump(results, open(args.json, "w"), indent=2)


if __name__ == "__main__":
    main()
