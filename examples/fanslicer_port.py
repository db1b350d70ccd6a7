#!/usr/bin/env python3
"""fan-slicer's own demo (simulation_demo.py), ported by changing its imports.

The body below the marked line is fan-slicer's script as published, with only the two import
lines changed and its data paths pointed at data/fanslicer. fan-slicer's CT test
volume is not distributed, so the prelude builds a stand-in in the same place and format (an
[Y, X, Z] .npy plus its npy_config), from the same patient's surface meshes; and figures are saved
to fanslicer_port_<i>.png instead of opening windows.

    python examples/fanslicer_port.py        (needs matplotlib)
"""
import json
import os
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import sonoslice  # noqa: E402

SHARED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "data", "fanslicer")
WORK = tempfile.mkdtemp(prefix="fanslicer-port-")

# ---- prelude: a CT-like stand-in for fan-slicer's missing CT_test_volume.npy -----------------
meshes = [sonoslice.Mesh.from_file(os.path.join(SHARED, n + ".vtk"))
          for n in ("liver", "hepatic veins", "portal vein", "arteries")]
labels = sonoslice.voxelize(meshes, spacing=1.0, margin=30)
hu = np.array([-80, 60, 170, 180, 250], np.float32)[labels.array]  # fat, liver, veins, arteries
hu += np.random.default_rng(0).normal(0, 12, hu.shape).astype(np.float32)
np.save(os.path.join(WORK, "CT_test_volume.npy"), np.ascontiguousarray(hu.transpose(1, 2, 0)))  # [Y, X, Z]
lo = np.array(labels.origin)
hi = lo + (np.array(labels.shape[::-1]) - 1) * np.array(labels.spacing)
with open(os.path.join(WORK, "CT_npy_volume_config.json"), "w") as f:
    json.dump({"planar resolution": [1.0, 1.0], "voxel size": [1.0, 1.0, 1.0],
               "bounding box": [lo.tolist(), hi.tolist()]}, f)
figures = iter(range(100))
plt.show = lambda: plt.savefig(f"fanslicer_port_{next(figures)}.png", dpi=80) or plt.close("all")
config_path = SHARED + "/"
data_path = WORK + "/"
# ---- fan-slicer's simulation_demo.py from here; only the two imports changed -----------------

# coding=utf-8

"""
A demo script to illustrate simulation of segmented and intensity images with
ultrasound image shapes.
"""


import numpy as np
import matplotlib.pyplot as plt
import sonoslice.fanslicer as svol  # was: import fanslicer.pycuda_simulation.segmented_volume as svol
import sonoslice.fanslicer as ivol  # was: import fanslicer.pycuda_simulation.intensity_volume as ivol


# Load the segmented volume
liver_volume = svol.SegmentedVolume(config_dir=config_path + "models_binary_LUS_config.json",
                                    mesh_dir=config_path,
                                    voxel_size=0.5,
                                    downsampling=2,
                                    image_num=10)
# Load the intensity volume
ct_volume = ivol.IntensityVolume(config_dir=config_path + "models_intensity_LUS_config.json",
                                 vol_dir=data_path + "CT_test_volume.npy",
                                 file_type="npy",
                                 npy_config=data_path + "CT_npy_volume_config.json",
                                 downsampling=2,
                                 image_num=10)

# Define a set of 10 poses, and slice generated volumes
pose = np.array([[-0.46,	0.29, -0.84	, -41.77],
                 [0.28, 0.94, 0.18, -47.72],
                 [0.84, -0.15, -0.52, -253.44],
                 [0, 0, 0, 1]])

poses = np.tile(pose, (1, 10))
poses[2, 3:40:4] = poses[2, 3:40:4] - np.arange(0, 20, 2)

# Simulate binary maps, always matching image_num with the number of poses
points, binary_map, colored_map = \
    liver_volume.simulate_image(poses=poses, image_num=10)

points, ct_map = \
    ct_volume.simulate_image(poses=poses, image_num=10)


# Show results image by image
for i in range(10):
    fig = plt.figure()
    plt.clf()
    ax1 = fig.add_subplot(121)
    ax1.imshow(colored_map[:, :, :, i])
    ax2 = fig.add_subplot(122)
    ax2.imshow(ct_map[:, :, i], cmap='gray', vmin=-200)
    plt.tight_layout()
    plt.show()
