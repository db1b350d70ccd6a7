#!/usr/bin/env python3
"""Capture range of `sonoslice register` (a worked example): CT fans of the phantom at
known poses, with Gaussian noise, registered back from initial poses perturbed by a growing
error; the success rate (within 1 mm and 1 degree at the fan's centre) against the initial error.

  build/venv/bin/python examples/register_capture_range.py [--phantom DIR] [--poses 40]
      [--noise 20] [--errors 2 4 6 8 10] [--starts auto 1 8] [--metric ncc] [--plot capture.svg]
      [--simulated [--simulate-from ct|labels] | --independent | --frames FRAMES.npy]
      [--pose-source body|skin|liver]

Each perturbation moves the fan's centre by E mm in a random direction and turns the probe by
E degrees about a random axis through that centre (seeded). The registration runs through the
CLI exactly as a user would call it (W1: fan-slicer's LUS config at --downsampling 2). The table
goes to stdout (markdown); --plot writes the curves as an SVG. `--starts auto` leaves the
choice to the command (its default: starts until three agree). The table also says how many frames
the report calls converged, and how many of the frames that missed were called converged anyway
(the silent failures the convergence check is there to prevent). Instead of CT fans: --simulated
registers `sonoslice simulate --preset lus` B-mode frames; --independent B-mode frames of another
simulator (MUST's pymust, examples/independent_bmode.py; `pip install "pymust<0.1.9"` with numpy 1.x), so that the figure
is not our simulator agreeing with itself. The true poses are at random inside the body (the
benchmarks' poses, default), or with --pose-source where a probe lies: on the skin looking in, or
on the liver's surface looking into it (laparoscopic).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

import sonoslice

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.environ.get("SONOSLICE_CLI", os.path.join(ROOT, "build", "bin", "sonoslice"))
W1 = os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json")


def phantom_folder(phantom, tmp):
    """The full phantom's folder: `phantom`, or one written under `tmp`."""
    if not phantom:
        phantom = os.path.join(tmp, "phantom")
        subprocess.run([CLI, "phantom", phantom, "--size", "full", "--format", "nii", "-q"], check=True)
    return phantom


def phantom_file(folder, prefix):
    """The volume of `folder` whose name starts with `prefix` ("ct.", "labels."); an .npy volume's
    .json sidecar is not one."""
    return next(os.path.join(folder, f) for f in sorted(os.listdir(folder))
                if f.startswith(prefix) and not f.endswith(".json"))


def body_poses(tmp, n):
    """n probe poses inside the phantom's body (`sonoslice phantom --size small --poses n`: the
    same every time)."""
    subprocess.run([CLI, "phantom", os.path.join(tmp, "p"), "--size", "small", "--poses", str(n), "-q"], check=True)
    return np.load(os.path.join(tmp, "p", "poses.npy"))[:n]


def sampled_poses(source, ct, labels, probe, n):
    """n poses of a pose sampler (docs/datasets.md §2), seeds 0..n-1 of base seed 7: "skin", the probe on
    the body surface looking in (transabdominal; the dataset example's tilts and rejection rules), or
    "liver", the probe's face on the liver's surface looking into it (laparoscopic: the skin sampler on a
    volume that is -1000 outside the liver's label and 100 inside)."""
    config = {"type": "skin", "rotation_deg": [0, 360], "tilt_deg": [-15, 15], "heel_toe_deg": [-10, 10],
              "reject": {"min_inside": 0.9, "min_body": 0.6}}
    volume = ct
    if source == "liver":
        liver = sonoslice.PHANTOM_LABELS.index("liver")
        mask = np.where(labels.array == liver, 100, -1000).astype(np.int16)
        volume = sonoslice.Volume(mask, spacing=ct.spacing, origin=ct.origin, direction=ct.direction)
    else:
        config["reject"]["no_gas"] = True
    return sonoslice.PoseSampler(config, probe, volume).sample(sonoslice.sample_seeds(7, 0, 0, n))


def independent_frames(phantom, truth, tmp, out, threads=None):
    """B-mode frames of another simulator (MUST's pymust, examples/independent_bmode.py) at the poses
    `truth`, from the phantom's labels and tissues.json, written to `out` (.npy)."""
    poses = os.path.join(tmp, "truth.npy")
    np.save(poses, truth)
    cmd = [sys.executable, os.path.join(ROOT, "examples", "independent_bmode.py"), "--labels",
           phantom_file(phantom, "labels."), "--tissues", os.path.join(phantom, "tissues.json"), "--poses", poses,
           "--out", out]
    subprocess.run(cmd + (["--threads", str(threads)] if threads else []), check=True)


def rotation(axis, angle):
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def perturb(pose, centre_probe, mm, deg, rng):
    """The pose moved by `mm` and turned by `deg` about its fan centre (world frame)."""
    c = pose[:3, :3] @ centre_probe + pose[:3, 3]
    d = rng.normal(size=3)
    R = rotation(rng.normal(size=3), np.deg2rad(deg))
    out = pose.copy()
    out[:3, :3] = R @ pose[:3, :3]
    out[:3, 3] = c + mm * d / np.linalg.norm(d) + R @ (pose[:3, 3] - c)
    return out


def errors(a, b, centre_probe):
    ca = a[:, :3, :3] @ centre_probe + a[:, :3, 3]
    cb = b[:, :3, :3] @ centre_probe + b[:, :3, 3]
    mm = np.linalg.norm(ca - cb, axis=1)
    rel = np.einsum("nij,nkj->nik", a[:, :3, :3], b[:, :3, :3])
    deg = np.rad2deg(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return mm, deg


def svg_plot(path, errors_list, curves, title):
    """Success rate (%) against initial error, one polyline per curve: a dependency-free SVG."""
    W, H, L, B, T, R = 560, 340, 60, 50, 40, 150
    x_max = max(errors_list)
    sx = lambda e: L + (W - L - R) * e / x_max
    sy = lambda p: T + (H - T - B) * (1 - p / 100)
    colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"]
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" '
           f'font-size="12"><rect width="100%" height="100%" fill="white"/>',
           f'<text x="{W / 2}" y="20" text-anchor="middle" font-size="14">{title}</text>']
    for p in range(0, 101, 20):
        out.append(f'<line x1="{L}" y1="{sy(p)}" x2="{W - R}" y2="{sy(p)}" stroke="#ddd"/>')
        out.append(f'<text x="{L - 6}" y="{sy(p) + 4}" text-anchor="end">{p}</text>')
    for e in errors_list:
        out.append(f'<text x="{sx(e)}" y="{H - B + 16}" text-anchor="middle">{e:g}</text>')
    out.append(f'<line x1="{L}" y1="{sy(0)}" x2="{W - R}" y2="{sy(0)}" stroke="black"/>')
    out.append(f'<line x1="{L}" y1="{sy(0)}" x2="{L}" y2="{sy(100)}" stroke="black"/>')
    out.append(f'<text x="{(L + W - R) / 2}" y="{H - 12}" text-anchor="middle">initial error: '
               f'E mm and E degrees</text>')
    out.append(f'<text x="16" y="{(T + H - B) / 2}" text-anchor="middle" '
               f'transform="rotate(-90 16 {(T + H - B) / 2})">within 1 mm and 1 deg (%)</text>')
    for i, (name, rates) in enumerate(curves.items()):
        c = colours[i % len(colours)]
        pts = " ".join(f"{sx(e):.1f},{sy(r):.1f}" for e, r in zip(errors_list, rates))
        out.append(f'<polyline points="{pts}" fill="none" stroke="{c}" stroke-width="2"/>')
        for e, r in zip(errors_list, rates):
            out.append(f'<circle cx="{sx(e):.1f}" cy="{sy(r):.1f}" r="3" fill="{c}"/>')
        out.append(f'<text x="{W - R + 10}" y="{T + 16 + 18 * i}" fill="{c}">{name}</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phantom", help="a folder from `sonoslice phantom DIR --size full` (default: written)")
    ap.add_argument("--poses", type=int, default=40)
    ap.add_argument("--noise", type=float, default=20, help="Gaussian noise on the fans, HU (20)")
    ap.add_argument("--errors", type=float, nargs="+", default=[2, 4, 6, 8, 10])
    ap.add_argument("--starts", nargs="+", default=["auto", "1", "8"],
                    help="starts per frame: numbers, or auto (the command's default)")
    ap.add_argument("--metric", default="ncc")
    ap.add_argument("--pyramid", help="the command's --pyramid (default: the metric's default)")
    ap.add_argument("--simulated", action="store_true",
                    help="frames from `sonoslice simulate --preset lus` (B-mode) instead of CT fans with noise")
    ap.add_argument("--simulate-from", choices=["ct", "labels"], default="ct",
                    help="--simulated: from the CT (default; the phantom's contrast-filled vessels scatter like "
                         "liver there) or from the labels and tissues.json (vessels anechoic, as ultrasound shows them)")
    ap.add_argument("--independent", action="store_true",
                    help="frames from an independent simulator (MUST's pymust: examples/independent_bmode.py, "
                         "from the phantom's labels and tissues) instead of CT fans with noise")
    ap.add_argument("--frames", help="frames at the true poses made elsewhere (.npy, (N, H, W) on W1's grid, at the "
                                     "first --poses poses of `sonoslice phantom DIR --size small --poses N`)")
    ap.add_argument("--pose-source", choices=["body", "skin", "liver"], default="body",
                    help="where the true poses are: at random inside the body (default), on the skin looking in, "
                         "or on the liver's surface looking into it (pose samplers, seeded)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--plot", help="write the capture-range curves here (.svg)")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        phantom = phantom_folder(args.phantom, tmp)
        ct_path = phantom_file(phantom, "ct.")
        ct = sonoslice.Volume.from_file(ct_path)
        probe = sonoslice.Probe.from_fanslicer(W1, downsampling=2)
        if args.pose_source == "body":
            truth = body_poses(tmp, args.poses)
        else:
            labels = sonoslice.Volume.from_file(phantom_file(phantom, "labels.")) if args.pose_source == "liver" else None
            truth = sampled_poses(args.pose_source, ct, labels, probe, args.poses)
        geometry = json.loads(probe.to_json())
        mask = probe.mask
        v, u = np.nonzero(mask)
        image = geometry.get("image", geometry)
        origin, spacing = image["origin_mm"], image["spacing_mm"]
        centre = np.array([origin[0] + u.mean() * spacing[0], origin[1] + v.mean() * spacing[1], 0.0])
        frames_path = os.path.join(tmp, "frames.npy")
        if args.frames:
            np.save(frames_path, np.load(args.frames)[: args.poses].astype(np.float32))
        elif args.independent:
            independent_frames(phantom, truth, tmp, frames_path)
        elif args.simulated:  # the lus preset's probe is W1
            np.save(os.path.join(tmp, "truth.npy"), truth)
            source = (["--volume", ct_path] if args.simulate_from == "ct" else
                      ["--labels", phantom_file(phantom, "labels."), "--tissues", os.path.join(phantom, "tissues.json")])
            subprocess.run([CLI, "simulate", *source, "--preset", "lus", "--poses",
                            os.path.join(tmp, "truth.npy"), "--out", frames_path, "-q"], check=True)
        else:
            frames = sonoslice.Slicer(ct, probe).slice(truth).astype(np.float32)
            rng = np.random.default_rng(1)
            frames += rng.normal(0, args.noise, frames.shape).astype(np.float32)
            np.save(frames_path, frames)
        curves = {}
        rows = []
        for starts in args.starts:
            rates = []
            for e in args.errors:
                prng = np.random.default_rng(int(e * 1000))
                init = np.stack([perturb(p, centre, e, e, prng) for p in truth])
                init_path, out_path, report_path = (os.path.join(tmp, n) for n in ("init.npy", "out.npy", "r.json"))
                np.save(init_path, init)
                cmd = [CLI, "register", "--volume", ct_path, "--probe", W1, "--downsampling", "2", "--frames",
                       frames_path, "--poses", init_path, "--out", out_path, "--metric", args.metric,
                       "--search-rot-deg", str(e), "--search-trans-mm", str(e),
                       "--threads", str(args.threads), "--report", report_path]
                if starts != "auto":
                    cmd += ["--starts", starts]
                if args.pyramid:
                    cmd += ["--pyramid", args.pyramid]
                run = subprocess.run(cmd, capture_output=True, text=True)
                if run.returncode != 0:
                    sys.exit(run.stderr)
                mm, deg = errors(np.load(out_path), truth, centre)
                report = json.load(open(report_path))
                ok = (mm < 1) & (deg < 1)
                converged = np.array([f["converged"] for f in report["frames"]])
                rates.append(100 * ok.mean())
                rows.append((starts, e, 100 * ok.mean(), np.median(mm), np.median(deg), 100 * converged.mean(),
                             int((converged & ~ok).sum()), int((~ok).sum()), report["evaluations"],
                             report["seconds"]))
                print(f"starts {starts}, error {e:g}: {100 * ok.mean():.0f} % within 1 mm and 1 deg", file=sys.stderr)
                u_mm = np.array([np.nan if f["uncertainty_mm"] is None else f["uncertainty_mm"]
                                 for f in report["frames"]], float)
                u_deg = np.array([np.nan if f["uncertainty_deg"] is None else f["uncertainty_deg"]
                                  for f in report["frames"]], float)
                if np.isfinite(u_mm[ok]).any():  # the metrics with derivatives (ssd, ncc) give it
                    print(f"  uncertainty of the frames within 1 mm and 1 deg: up to {np.nanmax(u_mm[ok]):.3g} mm, "
                          f"{np.nanmax(u_deg[ok]):.3g} deg", file=sys.stderr)
                for k in np.nonzero(converged & ~ok)[0]:
                    f = report["frames"][k]
                    print(f"  frame {k}: {mm[k]:.2f} mm {deg[k]:.2f} deg off, called converged "
                          f"({f['agreeing_starts']} of {f['starts']} starts agree, cost {f['metric']:.4f}, "
                          f"uncertainty {u_mm[k]:.3g} mm {u_deg[k]:.3g} deg)",
                          file=sys.stderr)
            curves[f"{args.metric}, {starts} start{'' if starts == '1' else 's'}"] = rates
    kind = ("frames of " + args.frames if args.frames else
            "independent B-mode frames (pymust)" if args.independent else
            f"simulated B-mode frames (lus preset, from the {args.simulate_from})" if args.simulated else f"CT fans with {args.noise:g} HU noise")
    print(f"\n{args.poses} W1 {kind} of the full phantom at poses {args.pose_source}, metric {args.metric}, default optimizer, "
          f"pyramid {args.pyramid or 'default'}, {args.threads} threads\n")
    print("| starts | initial error (mm and deg) | within 1 mm and 1 deg | median error after | called converged "
          "| missed but called converged | pose evaluations | seconds |")
    print("|---|---|---|---|---|---|---|---|")
    for s, e, rate, mm, deg, conv, silent, missed, ev, sec in rows:
        print(f"| {s} | {e:g} | {rate:.0f} % | {mm:.3f} mm, {deg:.3f} deg | {conv:.0f} % | {silent} of {missed} "
              f"| {ev} | {sec:.1f} |")
    if args.plot:
        svg_plot(args.plot, args.errors, curves, f"sonoslice register: capture range ({args.metric}, W1 CT fans)")


if __name__ == "__main__":
    main()
