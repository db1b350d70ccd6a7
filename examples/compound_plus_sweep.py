#!/usr/bin/env python3
"""Reconstruct a real tracked ultrasound sweep (PLUS toolkit files) into a volume.

    python examples/compound_plus_sweep.py [--data data/plus] [--out nwire_slices.png]
                                           [--save nwire.nii.gz] [--spacing MM]

Reads PLUS's NWire phantom sweep (NwirePhantomFreehand.igs.mha, 97 frames of 820x616) and its
configuration XML (calibration ImageToProbe, clip rectangle, 0.5 mm voxels, linear splats, mean
compounding), chains each frame's ImageToReference = (ReferenceToTracker)^-1 · ProbeToTracker ·
ImageToProbe (docs/conventions.md §7), fits PLUS's output grid around the clipped frames, compounds them, prints
the timings and the difference from PLUS's own reconstruction, and saves three orthogonal slices
as a PNG (top: sonoslice; bottom: PLUS's reconstruction of the same sweep, when it is there;
with matplotlib, else Pillow, else no picture).
"""
import argparse
import os
import time

import numpy as np

import sonoslice

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_DATA = os.path.normpath(os.path.join(HERE, "..", "data", "plus"))
SEQUENCE = "NwirePhantomFreehand.igs.mha"
CONFIG = "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"
REFERENCE = "NwirePhantomFreehandReconstructed.mha"


def three_slices(volume: np.ndarray, weights: np.ndarray):
    """Slices normal to z, y and x (array axes 0, 1, 2), each the one with the most bright voxels
    (the phantom's wires are thin: a slice through the middle may miss most of them)."""
    values = volume[weights > 0]
    bright = volume > np.percentile(values, 99) if values.size else np.zeros(volume.shape, bool)
    z = int(np.argmax(bright.sum(axis=(1, 2))))
    y = int(np.argmax(bright.sum(axis=(0, 2))))
    x = int(np.argmax(bright.sum(axis=(0, 1))))
    return [("z", z, volume[z]), ("y", y, volume[:, y]), ("x", x, volume[:, :, x])]


def save_montage(path: str, rows, spacing, title: str) -> bool:
    """rows: [(label, slices)], one row of three slices each (sonoslice; PLUS's when present)."""
    sx, sy, sz = spacing
    # Window: 0 to the 99.5th percentile of the non-zero voxels shown.
    shown = np.concatenate([image[image > 0].ravel() for _, slices in rows for _, _, image in slices] +
                           [np.ones(1)])
    top = max(float(np.percentile(shown, 99.5)), 1.0)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        plt = None
    if plt is not None:
        fig, axes = plt.subplots(len(rows), 3, figsize=(13, 4.6 * len(rows)), squeeze=False)
        labels = {"z": ("x (mm)", "y (mm)", sx, sy), "y": ("x (mm)", "z (mm)", sx, sz),
                  "x": ("y (mm)", "z (mm)", sy, sz)}
        for row_axes, (label, slices) in zip(axes, rows):
            for ax, (axis, index, image) in zip(row_axes, slices):
                xl, yl, dx, dy = labels[axis]
                ax.imshow(image, cmap="gray", vmin=0, vmax=top, origin="lower",
                          extent=[0, image.shape[1] * dx, 0, image.shape[0] * dy])
                ax.set_title(f"{label}: {axis} = voxel {index}")
                ax.set_xlabel(xl)
                ax.set_ylabel(yl)
        fig.suptitle(title)
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        return True
    try:
        from PIL import Image
    except ImportError:
        print("matplotlib (and Pillow) not available: no picture written (pip install matplotlib)")
        return False
    # A plain montage: each row's three slices side by side (bottom row of each at the bottom, as
    # with origin="lower"), windowed, three times enlarged; rows one above the other.
    strips = []
    for _, slices in rows:
        height = max(image.shape[0] for _, _, image in slices)
        tiles = [np.pad(np.flipud(image.astype(np.float64)), ((height - image.shape[0], 8), (0, 8)))
                 for _, _, image in slices]
        strips.append(np.hstack(tiles))
    width = max(s.shape[1] for s in strips)
    strips = [np.pad(s, ((0, 0), (0, width - s.shape[1]))) for s in strips]
    montage = np.clip(np.vstack(strips) * (255.0 / top), 0, 255).astype(np.uint8)
    Image.fromarray(np.kron(montage, np.ones((3, 3), np.uint8))).save(path)
    print("matplotlib not available: wrote a plain montage with Pillow")
    return True


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=DEFAULT_DATA, help="folder with the PLUS files (default: %(default)s)")
    ap.add_argument("--spacing", type=float, help="voxel size in mm (default: the XML's OutputSpacing)")
    ap.add_argument("--out", default="nwire_slices.png", help="PNG of three orthogonal slices")
    ap.add_argument("--save", help="also write the volume (.nii.gz, .mha, .nrrd, .npy)")
    args = ap.parse_args()

    t0 = time.perf_counter()
    sequence = sonoslice.read_plus_sequence(os.path.join(args.data, SEQUENCE))
    config = sonoslice.read_plus_config(os.path.join(args.data, CONFIG))
    t1 = time.perf_counter()
    print(sequence)
    print(config)

    # Per frame ImageToReference through the configuration's calibration and the frame's tracking.
    frames, image_to_reference = sonoslice.plus_image_to_reference(sequence, config)
    spacing = args.spacing or config.spacing
    compounder = sonoslice.Compounder.around(image_to_reference, sequence.shape[1:], spacing, config.clip,
                                             dtype=sequence.dtype, **config.settings)
    print(compounder.grid)
    t2 = time.perf_counter()
    # Every frame is usable here: the whole (N, H, W) view goes in without a copy.
    pixels = sequence.frames if len(frames) == len(sequence) else sequence.frames[frames]
    compounder.add(pixels, image_to_reference)
    t3 = time.perf_counter()
    volume, weights = compounder.volume(), compounder.weights()
    t4 = time.perf_counter()
    print(f"read {t1 - t0:.3f} s; grid {t2 - t1:.3f} s; {len(frames)} frames compounded in {t3 - t2:.3f} s "
          f"({len(frames) / (t3 - t2):.0f} frames/s); volume finished in {t4 - t3:.3f} s")
    print(volume)
    reached = weights.array > 0
    print(f"voxels reached: {reached.sum()} of {reached.size} ({100 * reached.mean():.1f} %)")

    # The same in one call, as `sonoslice compound --sequence S --config X` does it.
    t5 = time.perf_counter()
    again = sonoslice.reconstruct_plus(sequence, config, spacing=args.spacing)
    print(f"reconstruct_plus: {time.perf_counter() - t5:.3f} s, identical: "
          f"{again.array.tobytes() == volume.array.tobytes()}")

    slices = three_slices(volume.array, weights.array)
    rows = [("sonoslice", slices)]
    reference_path = os.path.join(args.data, REFERENCE)
    if args.spacing is None and os.path.exists(reference_path):
        reference = sonoslice.Volume.from_file(reference_path)
        nz, ny, nx = (min(a, b) for a, b in zip(volume.shape, reference.shape))
        ours = volume.array[:nz, :ny, :nx].astype(np.float64)
        theirs = reference.array[:nz, :ny, :nx].astype(np.float64)
        common = reached[:nz, :ny, :nx]
        diff = np.abs(ours - theirs)[common]
        print(f"vs PLUS's reconstruction ({reference.shape[::-1]} voxels x, y, z): mean |difference| "
              f"{diff.mean():.3f} over {common.sum()} voxels, identical {100 * np.mean(diff == 0):.1f} %")
        # The same slices of PLUS's volume (one voxel shorter along y), for the picture.
        ref = np.zeros(volume.shape, reference.array.dtype)
        ref[:nz, :ny, :nx] = reference.array[:nz, :ny, :nx]
        rows.append(("PLUS", [(axis, index, ref[index] if axis == "z" else
                               (ref[:, index] if axis == "y" else ref[:, :, index]))
                              for axis, index, _ in slices]))

    if args.save:
        volume.save(args.save)
        print(f"wrote {args.save}")
    title = f"{SEQUENCE}: {len(frames)} frames, {volume.shape[::-1]} voxels of {volume.spacing[0]} mm"
    if save_montage(args.out, rows, volume.spacing, title):
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
