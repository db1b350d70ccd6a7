#!/usr/bin/env python3
"""Slice a NIfTI CT with a curvilinear probe on the skin and plot a grid of fans.

    python examples/slice_nifti_and_plot.py [CT.nii.gz] [--out fans.png]

Without a CT it writes sonoslice's phantom to a temporary folder and uses that. Poses come from
the phantom's skin (``surface_poses``); for your own CT give a pose file with --poses (LPS mm,
or add --world RAS). Needs matplotlib.
"""
import argparse
import os
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import sonoslice  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("ct", nargs="?", help="a CT in .nii/.nii.gz (default: the phantom)")
    ap.add_argument("--poses", help="pose file (.npy/.txt/.json); default: 12 probes on the phantom's skin")
    ap.add_argument("--world", default="LPS")
    ap.add_argument("--device", default="cuda:0" if sonoslice.cuda_available() else "cpu")
    ap.add_argument("--out", default="fans.png")
    args = ap.parse_args()

    path = args.ct
    if path is None:
        ct, _ = sonoslice.phantom("full")
        path = os.path.join(tempfile.mkdtemp(), "ct.nii.gz")
        ct.save(path)
    volume = sonoslice.Volume.from_file(path)
    print(volume)

    # The fan of fan-slicer's laparoscopic probe at half resolution (334 x 272 px of 0.247 mm).
    probe = sonoslice.Probe.workload("W1")
    poses = (sonoslice.read_poses(args.poses, args.world) if args.poses
             else sonoslice.surface_poses(12, face_y_mm=probe.face_y_mm))
    slicer = sonoslice.Slicer(volume, probe, device=args.device, fill=np.nan)
    images = slicer.slice(poses)
    if not isinstance(images, np.ndarray):  # a torch tensor on the GPU
        images = images.cpu().numpy()

    cols = 4
    rows = (len(images) + cols - 1) // cols
    extent = [probe.origin_mm[0], probe.origin_mm[0] + probe.width * probe.spacing_mm[0],
              probe.height * probe.spacing_mm[1], 0]
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.8 * rows), squeeze=False)
    for ax, (n, img) in zip(axes.ravel(), enumerate(images)):
        ax.imshow(img, cmap="gray", vmin=-160, vmax=240, extent=extent)  # abdominal window
        ax.set_title(f"pose {n}", fontsize=9)
        ax.set_xlabel("lateral (mm)", fontsize=8)
        ax.set_ylabel("depth (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(images):]:
        ax.axis("off")
    fig.suptitle(f"{os.path.basename(path)}: {len(images)} fans on {slicer.device}")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
