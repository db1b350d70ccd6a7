#!/usr/bin/env python3
"""Loading a 512x512x400 int16 CT from .nii.gz, and saving it again: sonoslice vs nibabel,
same file, same run.

Loading: nibabel's figure is nib.load(path) plus np.asanyarray(img.dataobj): the voxels in their
stored dtype, which is what sonoslice keeps in memory too. sonoslice's figure is the "load" time
that `sonoslice slice --verbose` reports (one pose, so slicing and writing are negligible).
Saving: nib.save of the loaded image to .nii.gz (nibabel's default gzip level, 1) against
sonoslice's Volume.save to .nii.gz (build/venv's package, which also reads the file back in full
before it replaces anything), both from memory to a finished file; the file sizes are printed.

  /usr/bin/python3 bench/load_speed.py [--repeat 3] [--python build/venv/bin/python]
"""
import argparse
import os
import re
import subprocess
import tempfile
import time

import nibabel as nib
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sonoslice", default=os.path.join(ROOT, "build", "bin", "sonoslice"))
    ap.add_argument("--workdir")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--python", default=os.path.join(ROOT, "build", "venv", "bin", "python"),
                    help="a Python with the sonoslice package, for the saving figure")
    args = ap.parse_args()
    work = args.workdir or tempfile.mkdtemp(prefix="sonoslice-load-")
    ct = os.path.join(work, "ct.nii.gz")
    if not os.path.exists(ct):
        subprocess.run([args.sonoslice, "phantom", work, "--size", "full", "-q"], check=True)
    probe, pose = os.path.join(work, "probe.json"), os.path.join(work, "pose.txt")
    with open(probe, "w") as f:
        f.write('{"type": "linear", "image": {"width": 4, "height": 4, "spacing_mm": [1, 1]}}')
    with open(pose, "w") as f:
        f.write("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n")
    nibabel_s, ours_s = [], []
    for _ in range(args.repeat):
        t = time.perf_counter()
        a = np.asanyarray(nib.load(ct).dataobj)
        nibabel_s.append(time.perf_counter() - t)
        del a
        r = subprocess.run([args.sonoslice, "slice", "--volume", ct, "--probe", probe, "--poses",
                            pose, "--out", os.path.join(work, "o.npy"), "--verbose",
                            "-q"], check=True, capture_output=True, text=True)
        ours_s.append(float(re.search(r"load ([\d.]+) s", r.stderr).group(1)))
    print(f"{os.path.getsize(ct) / 2**20:.0f} MiB .nii.gz -> 200 MiB int16, best of {args.repeat}:")
    print(f"  nibabel   {min(nibabel_s):.3f} s")
    print(f"  sonoslice {min(ours_s):.3f} s  ({min(nibabel_s) / min(ours_s):.2f}x nibabel's speed)")

    img = nib.load(ct)
    img = nib.Nifti1Image(np.asanyarray(img.dataobj), img.affine, img.header)
    theirs, ours = os.path.join(work, "nibabel.nii.gz"), os.path.join(work, "sonoslice.nii.gz")
    save = ("import sys, time, sonoslice\n"
            "v = sonoslice.Volume.from_file(sys.argv[1])\n"
            "t = time.perf_counter(); v.save(sys.argv[2]); print(time.perf_counter() - t)")
    nibabel_s, ours_s = [], []
    for _ in range(args.repeat):
        t = time.perf_counter()
        nib.save(img, theirs)
        nibabel_s.append(time.perf_counter() - t)
        r = subprocess.run([args.python, "-c", save, ct, ours], check=True, capture_output=True, text=True)
        ours_s.append(float(r.stdout))
    print(f"200 MiB int16 -> .nii.gz, best of {args.repeat}:")
    print(f"  nibabel   {min(nibabel_s):.3f} s, {os.path.getsize(theirs) / 2**20:.1f} MiB")
    print(f"  sonoslice {min(ours_s):.3f} s, {os.path.getsize(ours) / 2**20:.1f} MiB "
          f"({min(nibabel_s) / min(ours_s):.2f}x nibabel's speed)")


if __name__ == "__main__":
    main()
