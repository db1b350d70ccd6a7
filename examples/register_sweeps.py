#!/usr/bin/env python3
"""Rigid-sweep registration at the defaults (a worked example): straight tracked sweeps of the
phantom CT whose frames all carry one shared error, as when a tracker-to-CT registration is off,
registered back with `mode="rigid-sweep"` and nothing else set. Counts the sweeps whose every
frame ends within 0.5 mm and 0.5 degrees of the truth, and whether the report calls the others
not converged (the silent failures the convergence check is there to prevent).

  build/venv/bin/python examples/register_sweeps.py [--phantom DIR] [--sweeps 10] [--frames 30]
      [--spacing 1] [--max-error 10] [--noise 20] [--simulated | --independent] [--metric lc2]
      [--probes W1 W2] [--directions along across] [--pose-source body|skin|liver]
      [--simulate-from ct|labels] [--threads 2]

For each probe (W1, fan-slicer's curvilinear LUS fan at downsampling 2, and W2, its linear probe
at half resolution: 200 x 250 pixels of 0.247 mm) and each direction (along: the probe moves
through its image plane, the usual freehand sweep; across: it slides along its own lateral
axis), --sweeps sweeps of --frames CT fans 1 mm apart with Gaussian noise (HU), centred on
random poses inside the body (--pose-source skin: probes on the skin looking in; liver: on the
liver's surface looking into it, as a laparoscopic probe lies) (--simulated: B-mode frames of `sonoslice.Simulator` at the same
poses, W1 at the lus preset's 6.5 MHz, W2 at the simulator's default, from the CT or with
--simulate-from labels from the labels and tissues.json, registered with --metric,
for example lc2 or mi; --independent: B-mode frames of another simulator, MUST's pymust through
examples/independent_bmode.py, W1 only). The shared error turns the sweep by up to --max-error degrees
about a random axis through the sweep's centre and moves it by up to --max-error mm in a random
direction (both uniform in magnitude, seeded).
"""
import argparse
import json
import os
import sys
import tempfile
import time
import warnings

import numpy as np

import sonoslice

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from register_capture_range import (body_poses, errors, independent_frames, phantom_file,  # noqa: E402
                                    phantom_folder, rotation, sampled_poses)


def probes():
    w2 = json.loads(sonoslice.Probe.workload("W2").to_json())["image"]
    return {"W1 curvilinear": sonoslice.Probe.workload("W1"),
            "W2 linear": sonoslice.Probe.linear(w2["width"] // 2, w2["height"] // 2, 2 * w2["spacing_mm"][0])}


def fan_centre(probe):
    """The centroid of the probe's fan (probe mm)."""
    image = json.loads(probe.to_json())["image"]
    v, u = np.nonzero(probe.mask)
    return np.array([image["origin_mm"][0] + u.mean() * image["spacing_mm"][0],
                     image["origin_mm"][1] + v.mean() * image["spacing_mm"][1], 0.0])


def apart(values):
    """The largest of these distances (mm), "-" where none was measured (the sides of a sweep
    through its image plane are not compared)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return f"{values.max():.2f} mm" if values.size else "-"


def sweep_cost(report):
    """The sweep's own cost in a report (+inf where it has none)."""
    return np.inf if report.get("sweep_metric") is None else report["sweep_metric"]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phantom", help="a folder from `sonoslice phantom DIR --size full` (default: written)")
    ap.add_argument("--sweeps", type=int, default=10, help="sweeps per probe and direction (10)")
    ap.add_argument("--frames", type=int, default=30, help="frames a sweep (30)")
    ap.add_argument("--spacing", type=float, default=1, help="distance between frames, mm (1)")
    ap.add_argument("--max-error", type=float, default=10, help="largest shared error, mm and degrees (10)")
    ap.add_argument("--noise", type=float, default=20, help="Gaussian noise on the fans, HU (20)")
    kind = ap.add_mutually_exclusive_group()
    kind.add_argument("--simulated", action="store_true", help="simulated B-mode frames instead of CT fans")
    kind.add_argument("--independent", action="store_true",
                      help="B-mode frames of pymust (examples/independent_bmode.py; W1 only)")
    ap.add_argument("--probes", nargs="+", default=["W1", "W2"], choices=["W1", "W2"])
    ap.add_argument("--directions", nargs="+", default=["along", "across"], choices=["along", "across"])
    ap.add_argument("--metric", help="register's metric (default: the library's, ncc)")
    ap.add_argument("--pose-source", choices=["body", "skin", "liver"], default="body",
                    help="where the sweeps' centres are: at random inside the body (default), on the skin looking "
                         "in, or on the liver's surface looking into it (pose samplers, seeded)")
    ap.add_argument("--simulate-from", choices=["ct", "labels"], default="ct",
                    help="--simulated: from the CT (default; the phantom's contrast-filled vessels scatter like "
                         "liver there) or from the labels and tissues.json (vessels anechoic)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    sonoslice.set_threads(args.threads)
    tmp_dir = tempfile.TemporaryDirectory()
    tmp = tmp_dir.name
    phantom = phantom_folder(args.phantom, tmp)
    ct = sonoslice.Volume.from_file(phantom_file(phantom, "ct."))
    needs_labels = args.pose_source == "liver" or (args.simulated and args.simulate_from == "labels")
    labels = sonoslice.Volume.from_file(phantom_file(phantom, "labels.")) if needs_labels else None
    bases = body_poses(tmp, args.sweeps) if args.pose_source == "body" else None
    rng = np.random.default_rng(7)
    rows = []
    print("| probe | sweep | within 0.5 mm and 0.5 deg | within 1 mm and 1 deg | median worst frame "
          "| called converged | missed but called converged | halves; sides apart, recovered (largest) | seconds a sweep |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, probe in probes().items():
        if name.split()[0] not in args.probes or (args.independent and not name.startswith("W1")):
            continue
        centre = fan_centre(probe)
        slicer = sonoslice.Slicer(ct, probe)
        simulator = None
        if args.simulated:
            frequency = 6.5 if name.startswith("W1") else None
            simulator = (sonoslice.Simulator(ct, probe, frequency=frequency) if args.simulate_from == "ct" else
                         sonoslice.Simulator(labels, probe, tissues=os.path.join(phantom, "tissues.json"),
                                             frequency=frequency))
        if args.pose_source != "body":
            bases = sampled_poses(args.pose_source, ct, labels, probe, args.sweeps)
        for direction, axis in (("along", 2), ("across", 0)):
            if direction not in args.directions:
                continue
            ok, near, worst_mm, worst_deg, conv, halves, sides, seconds = [], [], [], [], [], [], [], []
            for k, base in enumerate(bases):
                steps = (np.arange(args.frames) - (args.frames - 1) / 2) * args.spacing
                truth = np.repeat(base[None], args.frames, 0)
                truth[:, :3, 3] += steps[:, None] * base[:3, axis]  # along the probe's axis
                if args.independent:
                    independent_frames(phantom, truth, tmp, os.path.join(tmp, "frames.npy"), args.threads)
                    frames = np.load(os.path.join(tmp, "frames.npy")).astype(np.float32)
                elif args.simulated:
                    frames = simulator.simulate(truth).astype(np.float32)
                else:
                    frames = slicer.slice(truth).astype(np.float32)
                    frames += rng.normal(0, args.noise, frames.shape).astype(np.float32)
                # One shared world-frame error X about the sweep's centre: init_i = X . truth_i.
                c = base[:3, :3] @ centre + base[:3, 3]
                d = rng.normal(size=3)
                R = rotation(rng.normal(size=3), np.deg2rad(rng.uniform(0, args.max_error)))
                X = np.eye(4)
                X[:3, :3] = R
                X[:3, 3] = c - R @ c + rng.uniform(0, args.max_error) * d / np.linalg.norm(d)
                init = X @ truth
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # the report's converged flag is what is counted
                    t0 = time.perf_counter()
                    refined, report = sonoslice.register(ct, probe, frames, init, mode="rigid-sweep",
                                                         metric=args.metric)
                    seconds.append(time.perf_counter() - t0)
                mm, deg = errors(refined, truth, centre)
                worst_mm.append(mm.max())
                worst_deg.append(deg.max())
                ok.append(mm.max() < 0.5 and deg.max() < 0.5)
                near.append(mm.max() < 1 and deg.max() < 1)
                conv.append(report["frames"][0]["converged"])
                halves.append(report.get("halves_mm", np.nan))
                sides.append(report.get("sides_mm", np.nan))
                if ok[-1] and not conv[-1]:
                    f = report["frames"][0]
                    print(f"  {name} {direction} sweep {k}: recovered ({mm.max():.2f} mm {deg.max():.2f} deg) but "
                          f"not called converged: {f['agreeing_starts']} of {f['starts']} starts agree, halves "
                          f"{apart(halves[-1:])} and sides {apart(sides[-1:])} apart", file=sys.stderr)
                if not ok[-1]:
                    # Which failed, the search or the metric: the sweep's cost at the optimum next
                    # to the truth (one start from it) against its cost at the result.
                    f = report["frames"][0]
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        _, at_truth = sonoslice.register(ct, probe, frames, truth, mode="rigid-sweep", starts=1,
                                                        metric=args.metric)
                    start_mm, start_deg = errors(init, truth, centre)
                    print(f"  {name} {direction} sweep {k}: from {start_mm.max():.1f} mm {start_deg.max():.1f} deg "
                          f"to {mm.max():.2f} mm {deg.max():.2f} deg, {f['agreeing_starts']} of {f['starts']} starts "
                          f"agree, halves {apart(halves[-1:])} and sides {apart(sides[-1:])} apart, {'called converged' if f['converged'] else 'not converged'}; sweep cost "
                          f"{sweep_cost(report):.5f}, at the optimum next to the truth {sweep_cost(at_truth):.5f}",
                          file=sys.stderr)
            ok, conv = np.array(ok), np.array(conv)
            rows.append((ok.sum(), len(ok), (conv & ~ok).sum()))
            print(f"| {name} | {direction} | {ok.sum()} of {len(ok)} | {sum(near)} of {len(ok)} "
                  f"| {np.median(worst_mm):.3f} mm, "
                  f"{np.median(worst_deg):.3f} deg | {conv.sum()} of {len(ok)} | {(conv & ~ok).sum()} of "
                  f"{(~ok).sum()} | {apart(np.array(halves)[ok])}; {apart(np.array(sides)[ok])} | {np.mean(seconds):.1f} |", flush=True)
    good, total, silent = (sum(r[i] for r in rows) for i in range(3))
    print(f"\nAll: {good} of {total} sweeps ({100 * good / total:.0f} %) within 0.5 mm and 0.5 deg; "
          f"{silent} missed sweeps called converged.")


if __name__ == "__main__":
    main()
