#!/usr/bin/env python3
"""Dataset speed: the documented example SPEC (docs/dataset_example.yaml: W1 intensity and label
images, 334x272, of the full phantom from the skin sampler with its rejection rules) written by
`sonoslice dataset` as .npy shards, against `sonoslice slice` on the same poses (read back from the
shards), in the same run; then the same dataset on Dask `--scheduler local:2`, checked byte for
byte.

  build/venv/bin/python bench/dataset_speed.py [--count 20000] [--threads 2]
      [--phantom DIR]       # a phantom written by `sonoslice phantom DIR --size full`
      [--work DIR]          # where the outputs go (default: a temporary folder; needs ~20 GB free)

Figures are images per second of each command's wall time: both read the CT and write every image
to disk; the dataset run also builds the skin sampler, draws the poses, slices the labels and
hashes the shards. The target: the dataset at >= 70 % of `slice`'s rate (intensity images, one
command). `slice` making the same images as the dataset (a second run with --labels) and its
compute-only rate (--verbose "slice X s") are printed beside it.
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
import yaml

from benchcommon import CLI, ROOT, W1, full_phantom_ct, run_timed
COMPUTE = re.compile(r"slice ([0-9.]+) s \(")


def write_spec(path, ct, labels, count):
    """docs/dataset_example.yaml with this phantom's files and `count` samples."""
    with open(os.path.join(ROOT, "docs", "dataset_example.yaml")) as f:
        spec = yaml.safe_load(f)
    spec["volumes"][0].update(ct=ct, labels=labels)
    spec["probes"][0]["file"] = W1
    spec["samplers"][0]["count"] = count
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
        labels = [os.path.join(os.path.dirname(ct), f) for f in sorted(os.listdir(os.path.dirname(ct)))
                  if f.startswith("labels.")][0]
        spec = os.path.join(tmp, "spec.json")
        write_spec(spec, ct, labels, args.count)
        dataset = [sys.executable, "-m", "sonoslice", "dataset", spec, "-q", "--threads", str(args.threads)]

        one, _ = run_timed(dataset + ["--out", os.path.join(tmp, "one")])
        poses = os.path.join(tmp, "poses.npy")
        np.save(poses, poses_of(os.path.join(tmp, "one")))
        out = os.path.join(tmp, "slice.npy")
        wall, log = run_timed([CLI, "slice", "--volume", ct, "--probe", W1, "--downsampling", "2", "--poses", poses,
                           "--out", out, "--threads", str(args.threads), "-q", "-v"])
        compute = float(COMPUTE.search(log).group(1))
        os.remove(out)
        labels_wall, _ = run_timed([CLI, "slice", "--labels", labels, "--probe", W1,
                                    "--downsampling", "2", "--poses", poses, "--out", out,
                                    "--threads", str(args.threads), "-q"])
        os.remove(out)
        reference = file_hashes(os.path.join(tmp, "one"))
        subprocess.run(["rm", "-rf", os.path.join(tmp, "one")], check=True)
        dask, _ = run_timed(dataset + ["--out", os.path.join(tmp, "dask"), "--scheduler", "local:2"])
        same = file_hashes(os.path.join(tmp, "dask")) == reference

    n = args.count
    print(f"{n} samples of the documented example (W1 intensity 334x272 float32 + labels uint8, "
          f"{n * 334 * 272 * 5 / 1e9:.1f} GB), skin sampler with its rules, full phantom, "
          f"{args.threads} threads, {os.cpu_count()} cores")
    print(f"  sonoslice slice (same poses)    {wall:7.1f} s  {n / wall:7.0f} images/s "
          f"(compute alone {compute:.1f} s, {n / compute:.0f} images/s)")
    print(f"  sonoslice slice --labels        {labels_wall:7.1f} s  (both slice runs: {wall + labels_wall:.1f} s)")
    print(f"  sonoslice dataset               {one:7.1f} s  {n / one:7.0f} samples/s")
    print(f"  sonoslice dataset local:2       {dask:7.1f} s  {n / dask:7.0f} samples/s "
          f"({(dask / one - 1) * 100:+.0f} % time vs one process; shards byte-identical: {same})")
    print(f"dataset : slice = {wall / one:.2f} (target >= 0.70); against both slice runs (the same images) "
          f"{(wall + labels_wall) / one:.2f}; against slice's compute alone {compute / one:.2f}")

if __name__ == "__main__":
    main()
