#!/usr/bin/env python3
"""Dataset speed: W1 images (fan-slicer's LUS probe at --downsampling 2,
334x272, float32) of the full phantom CT from the skin sampler, written by `sonoslice dataset` as
.npy shards, against `sonoslice slice` on the same poses (read back from the shards), in the same
run; then the same dataset on Dask `--scheduler local:2`, checked byte for byte.

  build/venv/bin/python bench/dataset_speed.py [--count 20000] [--threads 2]
      [--phantom DIR]       # a phantom written by `sonoslice phantom DIR --size full`
      [--work DIR]          # where the outputs go (default: a temporary folder; needs ~15 GB free)

Figures are images per second of each command's wall time: both read the CT and write every image
to disk; the dataset run also builds the skin sampler, draws the poses and hashes the shards.
`slice`'s compute-only rate (its --verbose "slice X s") is printed beside it. The target: the
dataset at >= 70 % of `slice`'s rate.
"""
import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import tarfile
import tempfile

import numpy as np

from benchcommon import CLI, W1, full_phantom_ct, run_timed
COMPUTE = re.compile(r"slice ([0-9.]+) s \(")


def write_spec(path, ct, count):
    spec = {"seed": 2024, "shard_samples": 1000,
            "volumes": [{"id": "phantom", "ct": ct}],
            "probes": [{"id": "lus", "file": W1, "downsampling": 2}],
            "images": [{"kind": "intensity", "dtype": "float32"}],
            "samplers": [{"type": "skin", "volume": "phantom", "probe": "lus", "count": count,
                          "tilt_deg": [-15, 15], "rotation_deg": [0, 360], "reject": {"min_inside": 0.9}}]}
    with open(path, "w") as f:
        json.dump(spec, f, indent=1)


def poses_of(folder):
    """The poses recorded in a dataset's shards, in sample order."""
    with open(os.path.join(folder, "manifest.json")) as f:
        shards = json.load(f)["shards"]
    poses = []
    for s in shards:
        with tarfile.open(os.path.join(folder, s["name"])) as tar:
            poses += [json.load(tar.extractfile(m))["pose"] for m in tar.getmembers() if m.name.endswith(".json")]
    return np.array(poses)


def file_hashes(folder):
    out = {}
    for name in sorted(os.listdir(folder)):
        if name.endswith(".tar") or name == "manifest.json":
            sha = hashlib.sha256()
            with open(os.path.join(folder, name), "rb") as f:
                for block in iter(lambda: f.read(1 << 22), b""):
                    sha.update(block)
            out[name] = sha.hexdigest()
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=20000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--phantom", help="a directory with ct.nii.gz from `sonoslice phantom --size full`")
    ap.add_argument("--work", help="folder for the outputs (default: a temporary one, removed)")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(dir=args.work) as tmp:
        ct = full_phantom_ct(args.phantom, tmp)
        spec = os.path.join(tmp, "spec.json")
        write_spec(spec, ct, args.count)
        dataset = [sys.executable, "-m", "sonoslice", "dataset", spec, "-q", "--threads", str(args.threads)]

        one, _ = run_timed(dataset + ["--out", os.path.join(tmp, "one")])
        poses = os.path.join(tmp, "poses.npy")
        np.save(poses, poses_of(os.path.join(tmp, "one")))
        out = os.path.join(tmp, "slice.npy")
        wall, log = run_timed([CLI, "slice", "--volume", ct, "--probe", W1, "--downsampling", "2", "--poses", poses,
                           "--out", out, "--threads", str(args.threads), "-q", "-v"])
        compute = float(COMPUTE.search(log).group(1))
        os.remove(out)
        reference = file_hashes(os.path.join(tmp, "one"))
        subprocess.run(["rm", "-rf", os.path.join(tmp, "one")], check=True)
        dask, _ = run_timed(dataset + ["--out", os.path.join(tmp, "dask"), "--scheduler", "local:2"])
        same = file_hashes(os.path.join(tmp, "dask")) == reference

    n = args.count
    print(f"{n} W1 images (334x272 float32, {n * 334 * 272 * 4 / 1e9:.1f} GB), skin sampler, full phantom, "
          f"{args.threads} threads, {os.cpu_count()} cores")
    print(f"  sonoslice slice (same poses)    {wall:7.1f} s  {n / wall:7.0f} images/s "
          f"(compute alone {compute:.1f} s, {n / compute:.0f} images/s)")
    print(f"  sonoslice dataset               {one:7.1f} s  {n / one:7.0f} images/s")
    print(f"  sonoslice dataset local:2       {dask:7.1f} s  {n / dask:7.0f} images/s "
          f"({(dask / one - 1) * 100:+.0f} % time vs one process; shards byte-identical: {same})")
    print(f"dataset : slice = {wall / one:.2f} (target >= 0.70); against slice's compute alone {compute / one:.2f}")


if __name__ == "__main__":
    main()
