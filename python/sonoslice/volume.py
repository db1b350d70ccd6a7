"""Volumes (C++: volume/): a 3D array in its stored pixel type with its world geometry, made from
an array without a copy or read from NIfTI, MetaImage, NRRD, DICOM or NumPy files."""
from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np

from . import _arrays
from . import _sonoslice as _ext

__all__ = ["Volume"]


class Volume:
    """A 3D volume in its stored pixel type with its world geometry.

    ``Volume(array, spacing, origin, direction)`` wraps a C-contiguous ``(nz, ny, nx)`` array of
    uint8, int8, uint16, int16, uint32, int32, float32 or float64 **without copying it** (NumPy
    arrays, read-only ones such as a memmap included, or CPU torch tensors through DLPack): the
    volume keeps the array alive and sees changes made to its values. A non-contiguous or
    big-endian array raises ``ValueError``; pass ``numpy.ascontiguousarray(a)`` (or
    ``a.astype(a.dtype.newbyteorder('='))``) to copy it on purpose. A bare DLPack capsule is copied.

    If the array itself changes after that (torch's ``resize_``, NumPy's
    ``resize(refcheck=False)``, assigning ``.shape`` or ``.dtype``), its memory may have been
    freed: the volume's next use (slicing, ``array``, ``save``, ...) raises ``RuntimeError``
    instead of reading it. Make a new Volume from the array as it is then. (Do not resize it while
    another thread slices it.)

    Geometry (docs/conventions.md §1): voxel ``(i, j, k)`` = ``array[k, j, i]`` has its centre at
    ``origin + direction @ (spacing * (i, j, k))`` (mm, LPS); ``direction`` holds the index axes
    as columns.
    """

    def __init__(self, array, spacing: Sequence[float] = (1.0, 1.0, 1.0),
                 origin: Sequence[float] = (0.0, 0.0, 0.0), direction=None):
        d = np.eye(3) if direction is None else np.array(_arrays.floats(direction, "direction", 9)).reshape(3, 3)
        self._cpp = _ext.ArrayVolume.from_array(_arrays.native(array, "volume array", in_place=True),
                                                _arrays.floats(spacing, "spacing", 3), _arrays.floats(origin, "origin", 3),
                                                d.tolist())

    @classmethod
    def _wrap(cls, cpp) -> "Volume":
        v = cls.__new__(cls)
        v._cpp = cpp
        return v

    @classmethod
    def from_file(cls, path, *, spacing=None, origin=None, direction=None, series: Optional[str] = None,
                  npy_config=None) -> "Volume":
        """Reads NIfTI (.nii, .nii.gz), MetaImage (.mha, .mhd), NRRD (.nrrd, .nhdr), a DICOM
        series (a directory; ``series`` picks one by SeriesInstanceUID, default the largest) or
        NumPy .npy (geometry from ``spacing``/``origin``/``direction``, else a sidecar
        ``<name>.json``; ``npy_config``: fan-slicer's volume config). Voxels keep their stored
        type. Missing or corrupt files raise ``OSError``; bad values ``ValueError``."""
        d = None if direction is None else np.array(_arrays.floats(direction, "direction", 9)).reshape(3, 3).tolist()
        return cls._wrap(_ext.Volume.from_file(
            _arrays.path(path), None if spacing is None else _arrays.floats(spacing, "spacing", 3),
            None if origin is None else _arrays.floats(origin, "origin", 3), d, series or "",
            "" if npy_config is None else _arrays.path(npy_config, "npy_config")))

    @property
    def array(self) -> np.ndarray:
        """The voxels as a ``(nz, ny, nx)`` NumPy view (no copy; read-only when the volume views
        a read-only array)."""
        return self._cpp.array()

    @property
    def spacing(self) -> Tuple[float, float, float]:
        """Voxel size along i, j, k (mm)."""
        return tuple(self._cpp.spacing)

    @property
    def origin(self) -> Tuple[float, float, float]:
        """World position of voxel (0, 0, 0)'s centre (mm, LPS)."""
        return tuple(self._cpp.origin)

    @property
    def direction(self) -> np.ndarray:
        """3×3 matrix whose columns are the index axes in world coordinates."""
        return np.array(self._cpp.direction, dtype=np.float64).reshape(3, 3)

    @property
    def shape(self) -> Tuple[int, int, int]:
        """(nz, ny, nx)."""
        return tuple(self._cpp.shape)

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self._cpp.dtype)

    @property
    def nbytes(self) -> int:
        return self._cpp.nbytes

    def value_range(self) -> Tuple[float, float]:
        """(min, max) of the voxels, NaN ignored."""
        return tuple(self._cpp.value_range())

    def astype(self, dtype) -> "Volume":
        """A converted copy (integers round and saturate)."""
        return Volume._wrap(self._cpp.converted(np.dtype(dtype).name))

    def save(self, path) -> None:
        """Writes .nii[.gz], .mha, .nrrd... through ITK, or .npy with a sidecar .json; atomically."""
        self._cpp.save(_arrays.path(path))

    def world_to_index(self, point_mm: Sequence[float]) -> np.ndarray:
        """Continuous voxel index (i, j, k) of a world point (mm, LPS)."""
        return np.array(self._cpp.world_to_index(_arrays.floats(point_mm, "point_mm", 3)))

    def index_to_world(self, index: Sequence[float]) -> np.ndarray:
        """World position (mm, LPS) of a continuous voxel index (i, j, k)."""
        return np.array(self._cpp.index_to_world(_arrays.floats(index, "index", 3)))

    def __repr__(self) -> str:
        nz, ny, nx = self.shape
        return (f"Volume({nx}x{ny}x{nz} {self._cpp.dtype}, spacing={self.spacing} mm, "
                f"origin={self.origin} mm)")
