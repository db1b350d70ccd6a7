"""Pose files and image stacks (C++: io/PoseFile.h, io/StackWriter.h): reading and writing (N, 4, 4)
probe→world poses, checking them (docs/conventions.md §2), and writing batches of images."""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from . import _arrays
from . import _sonoslice as _ext

__all__ = ["read_poses", "write_poses", "validate_poses", "read_stack", "write_stack"]


def read_poses(path, world: str = "LPS") -> np.ndarray:
    """(N, 4, 4) float64 poses from .npy ((N,4,4) or fan-slicer's (4,4N)), .txt/.csv (16 or 12
    numbers a line) or .json; validated, converted to LPS."""
    return _ext.read_poses(_arrays.path(path), _arrays.text(world, "world"))


def write_poses(path, poses) -> None:
    """Writes (N, 4, 4) poses as .npy or text (16 numbers a line), atomically."""
    _ext.write_poses(_arrays.path(path), _arrays.pose_array(poses))


def validate_poses(poses, source: str = "poses") -> None:
    """Raises ValueError naming the first bad pose (docs/conventions.md §2); warns once for non-orthonormal ones."""
    _ext.validate_poses(_arrays.pose_array(poses), source)


def read_stack(path) -> np.ndarray:
    """An (N, H, W) stack of 2-D frames, as ``compound --frames``, ``register --frames`` and
    ``view --images`` read them: any stack :func:`write_stack` writes (.nii[.gz]/.mha/.nrrd W×H×N,
    .npy, a folder of PNGs read in name order), a scanner's multi-frame DICOM clip (.dcm) or a
    folder of single-frame DICOM images (name order), one 2-D .npy image as a stack of one; colour frames as their first component (one warning when the
    colours differ). The pixels keep their stored dtype."""
    return _ext.read_stack(_arrays.path(path, "path"))


def write_stack(path, images, spacing_mm: Sequence[float], window: Optional[Sequence[float]] = None,
                poses=None, mask=None) -> None:
    """Writes an (N, H, W) batch (docs/conventions.md §6): .nii[.gz]/.mha/.nrrd (W×H×N, spacing (sx, sy, 1)),
    .npy, or a directory of PNGs (``window`` = (level, width), default robust auto) + poses.txt."""
    images = np.ascontiguousarray(_arrays.native(np.asarray(_arrays.numpy_of(images)), "images"))
    _ext.write_stack(_arrays.path(path), images, _arrays.floats(spacing_mm, "spacing_mm", 2),
                     None if window is None else _arrays.floats(window, "window", 2),
                     None if poses is None else _arrays.pose_array(poses), _arrays.mask_array(mask, "mask"))
