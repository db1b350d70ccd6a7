#!/usr/bin/env python3
"""Reconstruction time on PLUS's own sweeps and configurations, against PLUS.

For each PLUS configuration (the NWire and BoneUltrasound sweeps of data/plus with their XML, and
variants of interpolation, compounding mode and hole-filling element), `sonoslice compound
--verbose` is run --repeat times and its reconstruction time taken: splatting + finishing (hole
filling included), no file reading or writing, as PLUS's reconstruction time (extent + paste +
hole filling) is measured. Medians, with the split.

PLUS is not built here (it is not in Debian). The PLUS column is the time PLUS took on this
machine kind (2 threads) for the same configuration on a 21-frame 820x616 sweep of the same
probe and depth as BoneUltrasound (PLUS's regression data, not in this repository), so it stands
beside the BoneUltrasound rows; elsewhere it is blank.

  build/venv/bin/python bench/plus_configs.py [--sonoslice build/bin/sonoslice] [--threads 2]
      [--repeat 5]
"""
import argparse
import os
import re
import statistics
import tempfile
import xml.etree.ElementTree as ET

from benchcommon import CLI, ROOT, run_timed

PLUS_DIR = os.path.join(ROOT, "data", "plus")
SWEEPS = {
    "Bone": ("BoneUltrasound_L14.igs.mha", "BoneUltrasound_L14_config.xml"),
    "NWire": ("NwirePhantomFreehand.igs.mha",
              "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"),
}
ELEMENTS = {
    "off": None,
    "STICK": {"Type": "STICK", "StickLengthLimit": "9", "NumberOfSticksToUse": "1"},
    "GAUSSIAN": {"Type": "GAUSSIAN", "Size": "5", "Stdev": "1", "MinimumKnownVoxelsRatio": "0.1"},
    "GAUSSIAN_ACCUMULATION": {"Type": "GAUSSIAN_ACCUMULATION", "Size": "5", "Stdev": "1",
                              "MinimumKnownVoxelsRatio": "0.1"},
    "DISTANCE_WEIGHT_INVERSE": {"Type": "DISTANCE_WEIGHT_INVERSE", "Size": "5",
                                "MinimumKnownVoxelsRatio": "0.1"},
    "NEAREST_NEIGHBOR": {"Type": "NEAREST_NEIGHBOR", "Size": "5", "MinimumKnownVoxelsRatio": "0.1"},
}
# PLUS, 2 threads, this machine kind, a 21-frame 820x616 sweep (see above): milliseconds.
PLUS_MS = {("Bone", "LINEAR", "MEAN", "STICK"): 402, ("Bone", "NEAREST_NEIGHBOR", "MEAN", "STICK"): 176,
           ("Bone", "LINEAR", "MAXIMUM", "off"): 246}
CASES = [(sweep, interp, mode, fill)
         for sweep in ("Bone", "NWire")
         for interp, mode, fill in [
             ("LINEAR", "MEAN", "STICK"), ("NEAREST_NEIGHBOR", "MEAN", "STICK"), ("LINEAR", "MAXIMUM", "off"),
             ("LINEAR", "MEAN", "off"), ("NEAREST_NEIGHBOR", "MEAN", "off"), ("LINEAR", "LATEST", "off"),
             ("NEAREST_NEIGHBOR", "MAXIMUM", "off"), ("LINEAR", "MEAN", "GAUSSIAN"),
             ("LINEAR", "MEAN", "GAUSSIAN_ACCUMULATION"), ("LINEAR", "MEAN", "DISTANCE_WEIGHT_INVERSE"),
             ("LINEAR", "MEAN", "NEAREST_NEIGHBOR"), ("LINEAR", "MAXIMUM", "STICK")]]
TIMES = re.compile(r"splatting ([0-9.]+) s.*finishing ([0-9.]+) s")


def write_config(sweep, interp, mode, fill, path):
    """The sweep's own XML with PLUS's attributes for this configuration."""
    tree = ET.parse(os.path.join(PLUS_DIR, SWEEPS[sweep][1]))
    rec = tree.getroot().find("VolumeReconstruction")
    rec.set("Interpolation", interp)
    rec.set("CompoundingMode", mode)
    rec.set("FillHoles", "OFF" if fill == "off" else "ON")
    for old in rec.findall("HoleFilling"):
        rec.remove(old)
    if fill != "off":
        ET.SubElement(ET.SubElement(rec, "HoleFilling"), "HoleFillingElement", ELEMENTS[fill])
    tree.write(path)


def reconstruction_ms(cli, sweep, config, out, threads):
    _, log = run_timed([cli, "compound", "--sequence", os.path.join(PLUS_DIR, SWEEPS[sweep][0]),
                        "--config", config, "--out", out, "--threads", str(threads), "--verbose"])
    m = TIMES.search(log)
    if not m:
        raise SystemExit("plus_configs: no splatting/finishing times in sonoslice compound --verbose")
    return 1e3 * float(m.group(1)), 1e3 * float(m.group(2))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sonoslice", default=CLI, help="the sonoslice binary (default: build/bin's)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(f"{args.threads} threads, median of {args.repeat} runs; milliseconds")
    print("| sweep | interpolation | compounding | hole filling | sonoslice (splatting + finishing) "
          "| PLUS | PLUS / sonoslice |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="sonoslice-plus-configs-") as work:
        config, out = os.path.join(work, "config.xml"), os.path.join(work, "volume.mha")
        for case in CASES:
            write_config(*case, config)
            reconstruction_ms(args.sonoslice, case[0], config, out, args.threads)  # warm-up
            runs = [reconstruction_ms(args.sonoslice, case[0], config, out, args.threads)
                    for _ in range(args.repeat)]
            splat = statistics.median(r[0] for r in runs)
            finish = statistics.median(r[1] for r in runs)
            total = statistics.median(r[0] + r[1] for r in runs)
            plus = PLUS_MS.get(case)
            ratio = f"**{plus / total:.1f}x**" if plus else ""
            print(f"| {' | '.join(case)} | {total:.0f} ({splat:.0f} + {finish:.0f}) | "
                  f"{plus or ''} | {ratio} |", flush=True)


if __name__ == "__main__":
    main()
