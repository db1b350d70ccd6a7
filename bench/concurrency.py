#!/usr/bin/env python3
"""How sonoslice shares a machine: K copies of one job at once, each one's time against the same
job alone (live reconstruction beside a tracker, a viewer or another job is the normal
case). On a machine of C cores, K jobs of T threads each should each take about K·T/C times as
long as alone (the fair share); much more means the jobs get in each other's way (threads
spinning at barriers, a slab per thread waiting for the slowest).

Workloads (the first is the default):
  compound  sonoslice compound of PLUS's NWire sweep (linear, mean): the splatting time that
            --verbose reports
  slice     sonoslice slice of the generated phantom, 2000 fan images (W1): wall time

  python3 bench/concurrency.py [--workload compound|slice] [--copies 2 4] [--repeat 3]
Run it on an otherwise idle machine: anything else running counts as a copy.
"""
import argparse
import concurrent.futures
import json
import os
import re
import statistics
import subprocess
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SPLAT = re.compile(r"splatting ([0-9.]+) s")


def job_command(cli, workload, workdir, k, threads):
    out = os.path.join(workdir, f"out{k}")
    if workload == "compound":
        plus = os.path.join(ROOT, "data", "plus")
        return [cli, "compound", "--sequence", os.path.join(plus, "NwirePhantomFreehand.igs.mha"),
                "--config", os.path.join(plus, "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"),
                "--out", out + ".mha", "--verbose", "--threads", str(threads)]
    return [cli, "slice", "--volume", os.path.join(workdir, "ph", "ct.nii.gz"),
            "--probe", os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json"),
            "--poses", os.path.join(workdir, "ph", "poses.npy"), "--out", out + ".npy",
            "--threads", str(threads), "-q"]


def run_one(cmd, workload):
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"concurrency: {' '.join(cmd)} failed ({r.returncode}): {r.stderr.strip()}")
    if workload == "compound":
        m = SPLAT.search(r.stderr)
        if not m:
            raise SystemExit("concurrency: no splatting time in sonoslice compound --verbose")
        return float(m.group(1))
    return wall


def at_once(cli, workload, workdir, copies, threads):
    """The times of `copies` jobs started together (each with its own output)."""
    cmds = [job_command(cli, workload, workdir, k, threads) for k in range(copies)]
    with concurrent.futures.ThreadPoolExecutor(copies) as pool:
        return list(pool.map(lambda c: run_one(c, workload), cmds))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sonoslice", default=os.path.join(ROOT, "build", "bin", "sonoslice"))
    ap.add_argument("--workload", choices=["compound", "slice"], default="compound")
    ap.add_argument("--copies", type=int, nargs="+", default=[2, 4])
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="threads per job (default: all cores)")
    ap.add_argument("--repeat", type=int, default=3, help="rounds per setting; the median is reported")
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="sonoslice-concurrency-") as workdir:
        if args.workload == "slice":
            subprocess.run([args.sonoslice, "phantom", os.path.join(workdir, "ph"), "--poses", "2000", "-q"],
                           check=True)
        run_one(job_command(args.sonoslice, args.workload, workdir, 0, args.threads), args.workload)  # warm-up
        alone = statistics.median(at_once(args.sonoslice, args.workload, workdir, 1, args.threads)[0]
                                  for _ in range(args.repeat))
        cores = os.cpu_count()
        print(f"{args.workload}: {args.threads} threads per job on {cores} cores; alone {alone:.3f} s "
              f"(median of {args.repeat})")
        print(f"{'copies':>6} {'each (median)':>14} {'slowdown':>9} {'fair share':>10} {'worst':>8}")
        results = {"workload": args.workload, "threads": args.threads, "cores": cores, "alone_s": alone,
                   "copies": []}
        for k in args.copies:
            rounds = [at_once(args.sonoslice, args.workload, workdir, k, args.threads) for _ in range(args.repeat)]
            times = [t for r in rounds for t in r]
            each = statistics.median(times)
            fair = max(1.0, k * args.threads / cores)
            print(f"{k:>6} {each:>13.3f}s {each / alone:>8.2f}x {fair:>9.2f}x {max(times) / alone:>7.2f}x")
            results["copies"].append({"copies": k, "each_s": each, "slowdown": each / alone, "fair": fair,
                                      "worst_slowdown": max(times) / alone, "times_s": times})
        if args.json:
            with open(args.json, "w") as f:
                json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
