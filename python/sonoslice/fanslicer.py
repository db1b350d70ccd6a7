"""Drop-in replacements for fan-slicer's classes: an existing fan-slicer script runs by changing

    import fanslicer.pycuda_simulation.intensity_volume as ivol
    import fanslicer.pycuda_simulation.segmented_volume as svol

to

    import sonoslice.fanslicer as ivol
    import sonoslice.fanslicer as svol

Same constructors, same ``simulate_image`` calls, same shapes and dtypes: poses as fan-slicer's
``(4, 4N)`` strip, images as ``(H, W, N)`` float32. Unlike fan-slicer this runs without a GPU (on
the CPU threads) and uses one when CUDA is available.

Known, documented differences (docs/conventions.md §4):

* Each pixel is sampled directly at its centre (fan-slicer samples a polar grid and splats it
  back onto the pixels), so edges are sharper and no pixel is left empty.
* Trilinear interpolation runs on the volume's true voxel lattice (fan-slicer anchors its lattice
  at world 0, which can shift images by up to one voxel).
* Outside the fan, images hold the image's minimum, as in fan-slicer; sonoslice's own API fills
  with a chosen value instead.
* ``out_points=True`` returns the world positions of the image's pixel centres (N·H·W, 3);
  fan-slicer returns its polar sampling points. Without it, ``points`` is an empty (0, 3) array
  (fan-slicer returns uninitialised memory).
* NIfTI and DICOM volumes are read with their full geometry in ITK's LPS frame (fan-slicer's
  loaders flip axes and drop direction cosines), so poses for them are LPS millimetres.
"""
from __future__ import annotations

import json
import os
from typing import Optional, Tuple

import numpy as np

from ._arrays import numpy_of as _numpy
from ._arrays import real_array as _real_array
from .devices import cuda_available
from .slicing import Probe, Slicer
from .surfaces import Mesh, SurfaceSlicer, colorize, fanslicer_models, voxelize
from .volume import Volume

__all__ = ["IntensityVolume", "SegmentedVolume"]


def _default_device(device: Optional[str]) -> str:
    if device is not None:
        return device
    return "cuda:0" if cuda_available() else "cpu"


def _strip_to_poses(poses: np.ndarray, image_num: int) -> np.ndarray:
    """fan-slicer's (4, 4N) strip → (N, 4, 4)."""
    poses = _real_array(_numpy(poses), "poses")
    if poses.ndim != 2 or poses.shape[0] != 4 or poses.shape[1] / 4 != image_num:
        raise ValueError("Input poses do not match image number!")
    return np.ascontiguousarray(poses.reshape(4, image_num, 4).transpose(1, 0, 2))


def _check_counts(image_num, downsampling) -> None:
    """fan-slicer's checks of ``image_num`` and ``downsampling``, with its messages."""
    if not isinstance(image_num, int) or image_num <= 0:
        raise ValueError("image_num must be positive integer")
    if downsampling < 1:
        raise ValueError("Downsampling must be greater than 1")


def _simulate(sim, poses, image_num: int) -> Tuple[np.ndarray, np.ndarray]:
    """The start of both classes' ``simulate_image`` (``sim``: the object), as fan-slicer's: check
    the (4, 4·image_num) strip, note a changed ``image_num``, slice. Returns the (N, 4, 4) poses
    and the (N, H, W) images as NumPy."""
    if np.asarray(poses).shape[1] / 4 != image_num:
        raise ValueError("Input poses do not match image number!")
    if image_num != sim.image_num:
        print("Number of images was changed from " + str(sim.image_num) + " to " + str(image_num))
        sim.image_num = image_num
    p = _strip_to_poses(poses, image_num)
    return p, _numpy(sim.slicer.slice(p))  # a CUDA slicer gives a torch tensor


def _pixel_points(probe: Probe, poses: np.ndarray) -> np.ndarray:
    """World positions (N·H·W, 3) float32 of every pixel centre."""
    sx, sy = probe.spacing_mm
    x0, y0 = probe.origin_mm
    x = x0 + np.arange(probe.width) * sx
    y = y0 + np.arange(probe.height) * sy
    X, Y = np.meshgrid(x, y)
    pts = (poses[:, None, None, :3, 0] * X[None, ..., None] + poses[:, None, None, :3, 1] * Y[None, ..., None]
           + poses[:, None, None, :3, 3])
    return pts.reshape(-1, 3).astype(np.float32)


class IntensityVolume:
    """fan-slicer's ``IntensityVolume``: a CT/MRI volume sliced into (H, W, N) float32 images.

    :param config_dir: fan-slicer configuration JSON (its "simulation" block sets the probe)
    :param vol_dir: the volume: a .npy (with ``npy_config``), a NIfTI file, or a DICOM directory
    :param image_num: images per ``simulate_image`` call (as in fan-slicer, changing it is allowed)
    :param downsampling: divides the configured image size (floor) and multiplies the pixel size
    :param file_type: "npy", "nii" or "dicom"
    :param npy_config: fan-slicer's volume config ("voxel size", "bounding box") for .npy volumes
    :param device: "cpu", "cuda" or "cuda:K"; default: the first GPU if there is one, else the CPU
    """

    def __init__(self, config_dir, vol_dir, image_num: int = 1, downsampling: int = 1,
                 file_type: str = "npy", npy_config=None, device: Optional[str] = None):
        if not os.path.isfile(config_dir):
            raise ValueError("No valid config file!")
        with open(config_dir) as f:
            self.config = json.load(f)
        _check_counts(image_num, downsampling)
        if file_type == "npy":
            if npy_config is None or not os.path.isfile(npy_config):
                raise ValueError("No valid config for npy file!")
            self.volume = Volume.from_file(vol_dir, npy_config=npy_config)
        elif file_type == "nii":
            self.volume = Volume.from_file(vol_dir)
        elif file_type == "dicom":
            if not os.path.isdir(vol_dir):
                raise ValueError("No valid file directory for dicom!")
            self.volume = Volume.from_file(vol_dir)
        else:
            raise ValueError(f"file_type {file_type!r}: expected 'npy', 'nii' or 'dicom'")
        self.image_num = image_num
        self.downsampling = downsampling
        self.probe = Probe.from_fanslicer(config_dir, downsampling)
        self.slicer = Slicer(self.volume, self.probe, device=_default_device(device))
        # fan-slicer's attributes, for scripts that read them.
        self.voxel_size = np.array(self.volume.spacing)
        lo = np.array(self.volume.origin)
        self.bound_box = np.stack([lo, lo + (np.array(self.volume.shape[::-1]) - 1) * self.voxel_size])
        self.xdim, self.ydim, self.zdim = self.volume.shape[::-1]

    @property
    def ct_volume(self) -> np.ndarray:
        """The voxels, as a (nz, ny, nx) NumPy view."""
        return self.volume.array

    def simulate_image(self, poses=np.eye(4), image_num: int = 1,
                       out_points: bool = False) -> Tuple[np.ndarray, np.ndarray]:
        """Slices ``image_num`` poses given as fan-slicer's (4, 4·image_num) strip of probe→world
        matrices (mm). Returns ``(points, images)`` with images (H, W, image_num) float32, the
        outside of the fan set to each image's minimum."""
        p, images = _simulate(self, poses, image_num)
        inside = self.slicer.mask.astype(bool)
        if not inside.all():
            for img in images:
                img[~inside] = img[inside].min() if inside.any() else 0.0
        points = _pixel_points(self.probe, p) if out_points else np.empty((0, 3), np.float32)
        return points, np.ascontiguousarray(images.transpose(1, 2, 0))


class SegmentedVolume:
    """fan-slicer's ``SegmentedVolume``: surface meshes sliced into label and colour images.

    :param mesh_dir: folder of the meshes the config names (``<name>.vtk``, spaces allowed)
    :param config_dir: fan-slicer surface configuration ("models", "simulation_models", "colors")
    :param image_num: images per ``simulate_image`` call
    :param downsampling: divides the configured image size (floor)
    :param voxel_size: isotropic voxel size (mm) of the label volume the meshes are voxelised into
    :param mode: "voxel" (as fan-slicer: voxelise, then slice) or "exact" (plane cuts, no voxels)
    :param device: as for :class:`IntensityVolume` ("exact" runs on the CPU)

    Differences from fan-slicer: where models overlap the later one's label wins (fan-slicer adds
    the labels up); meshes are voxelised in memory in milliseconds instead of cached as
    ``binary_*.npy`` files; ``out_points`` as for :class:`IntensityVolume`.
    """

    def __init__(self, mesh_dir, config_dir, image_num: int = 1, downsampling: int = 1,
                 voxel_size: float = 1.0, mode: str = "voxel", device: Optional[str] = None):
        if voxel_size <= 0:
            raise ValueError("Voxel size must be positive!")
        if not os.path.isfile(config_dir):
            raise ValueError("No valid config file!")
        if not os.path.isdir(mesh_dir):
            raise ValueError("No valid mesh directory")
        _check_counts(image_num, downsampling)
        with open(config_dir) as f:
            self.config = json.load(f)
        self.models = fanslicer_models(config_dir, mesh_dir)
        self.meshes = {m["name"].replace(" ", "_"): Mesh.from_file(m["path"]) for m in self.models}
        self.colors = [m["color"] for m in self.models]
        self.voxel_size = voxel_size
        self.image_num = image_num
        self.downsampling = downsampling
        self.probe = Probe.from_fanslicer(config_dir, downsampling)
        meshes = list(self.meshes.values())
        labels = [m["label"] for m in self.models]
        if mode == "exact":
            self.slicer = SurfaceSlicer(meshes, self.probe, labels=labels)
        elif mode == "voxel":
            self.label_volume = voxelize(meshes, spacing=voxel_size, labels=labels)
            self.slicer = Slicer(self.label_volume, self.probe, device=_default_device(device),
                                 interpolation="nearest", dtype="uint8" if max(labels) < 256 else "uint16")
        else:
            raise ValueError(f"mode {mode!r}: expected 'voxel' or 'exact'")

    def simulate_image(self, poses=np.eye(4), image_num: int = 1, out_points: bool = False):
        """Returns ``(points, simulation_images, visual_images)`` like fan-slicer: labels (H, W, N)
        float64 (the k-th enabled model is k), colour images (H, W, 3, N) float64 in [0, 1]
        (outside a fan: grey 210/255)."""
        p, labels = _simulate(self, poses, image_num)
        mask = self.slicer.mask
        rgb = colorize(labels, mask, self.colors).astype(np.float64) / 255.0
        if self.probe.type == "linear":  # fan-slicer draws the grey outline for fans only
            rgb[:, ~mask.astype(bool)] = 0.0
        points = _pixel_points(self.probe, p) if out_points else np.empty((0, 3), np.float32)
        return (points, np.ascontiguousarray(labels.transpose(1, 2, 0)).astype(np.float64),
                np.ascontiguousarray(rgb.transpose(1, 2, 3, 0)))
