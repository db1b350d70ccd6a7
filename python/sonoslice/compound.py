"""Freehand 3D reconstruction ("compounding", docs/conventions.md §7) and PLUS toolkit files.

Tracked 2D frames (or 3D beam-space frames of a 3D/4D probe) are inserted into one voxel grid
whose axes are parallel to the reference (world) frame, as PLUS toolkit's volume reconstructor
does. The conventions are those of :class:`sonoslice.Volume`:

* a grid's ``shape`` is ``(nz, ny, nx)`` (the C-order of ``Volume.array``); its ``spacing`` and
  ``origin`` are along x, y, z (mm; ``origin`` = centre of voxel (0, 0, 0));
* a 2D frame is an ``(H, W)`` array in MF orientation (row 0 nearest the transducer, column 0 on
  the marked side) and ``image_to_reference`` (4×4) maps pixel ``(i, j)`` = ``frame[j, i]``
  (column i, row j) at ``(i, j, 0)`` to reference millimetres: for a sonoslice probe it is
  ``pose @ [[sx, 0, 0, x0], [0, sy, 0, y0], [0, 0, 1, 0], [0, 0, 0, 1]]``;
* a beam-space frame is an ``(n_elevation, n_azimuth, n_samples)`` array (samples along each beam
  fastest) with a :class:`BeamGeometry`; ``probe_to_reference`` maps probe mm to reference mm.

Frames cross into C++ without a copy when they are C-contiguous arrays of uint8, int8, uint16,
int16, uint32, int32, float32 or float64 (uint8/uint16/int16/float32 go to the kernels as they
are; the others are converted to float32 batch by batch). The GIL is released while frames are
inserted and while the volume is finished. Bad input raises ``ValueError`` naming the argument,
unreadable files ``OSError``, a grid too large for memory ``RuntimeError`` (with a spacing that
fits).
"""
from __future__ import annotations

import math
import os
import warnings
from typing import Any, Dict, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from . import _sonoslice as _ext
from . import Volume, _matrix_stack, _native, _no_complex, _numpy, _real_array

__all__ = [
    "Grid", "Compounder", "BeamGeometry", "HoleFillingElement", "FrameClip", "grid_around", "grid_around_beams",
    "clip_mask", "PlusSequence", "PlusConfig", "TransformRepository", "read_plus_sequence", "write_plus_sequence",
    "read_plus_config", "plus_image_to_reference", "reconstruct_plus",
]

_DTYPES = ("uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64")
_IDENTITY3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
Clip = Union[None, Dict[str, Any], np.ndarray, "FrameClip"]
PathLike = Union[str, "os.PathLike[str]"]


# ---- grids ----------------------------------------------------------------------------------------
class Grid(NamedTuple):
    """A voxel grid in :class:`Volume`'s conventions: ``shape`` = (nz, ny, nx); ``spacing`` (mm)
    and ``origin`` (mm, centre of voxel (0, 0, 0)) along x, y, z; ``direction``: the 3×3 matrix
    (as rows) whose columns are the index axes in world coordinates."""
    shape: Tuple[int, int, int]
    spacing: Tuple[float, float, float]
    origin: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    direction: Tuple[Tuple[float, float, float], ...] = _IDENTITY3

    @property
    def dims(self) -> Tuple[int, int, int]:
        """Voxels along x, y, z: (nx, ny, nz)."""
        return tuple(reversed(self.shape))

    @property
    def size(self) -> int:
        """Number of voxels."""
        return int(np.prod(self.shape, dtype=np.int64))

    def index_to_world(self, index: Sequence[float]) -> np.ndarray:
        """World position (mm) of a continuous voxel index (i, j, k) (i along x)."""
        d = np.array(self.direction, dtype=np.float64)
        return np.array(self.origin) + d @ (np.array(self.spacing) * np.asarray(index, dtype=np.float64))

    def world_to_index(self, point_mm: Sequence[float]) -> np.ndarray:
        """Continuous voxel index (i, j, k) of a world point (mm)."""
        d = np.array(self.direction, dtype=np.float64)
        offset = np.asarray(point_mm, dtype=np.float64) - np.array(self.origin)
        return np.linalg.solve(d, offset) / np.array(self.spacing)

    def memory_bytes(self, compounding: str = "mean", dtype="float32") -> int:
        """Bytes a :class:`Compounder` on this grid holds (accumulators plus a ``dtype`` result)."""
        return int(_ext.compounding_memory_bytes(self.dims, str(compounding), _dtype_name(dtype, "dtype")))

    @classmethod
    def _from_ext(cls, g: "_ext.VolumeGrid") -> "Grid":
        return cls(tuple(reversed(g.dims)), g.spacing, g.origin, g.direction)

    def _to_ext(self) -> "_ext.VolumeGrid":
        """The C++ grid (dims along x, y, z), checked by the library (ValueError naming the field)."""
        return _ext.VolumeGrid(dims=self.dims, spacing=self.spacing, origin=self.origin, direction=self.direction)

    @classmethod
    def of(cls, volume_like) -> "Grid":
        """The grid of a :class:`Volume` (or of anything with ``shape``/``spacing``/``origin``
        and optionally ``direction`` in these conventions, or of a ``_sonoslice.VolumeGrid``)."""
        if isinstance(volume_like, Grid):
            return volume_like
        if isinstance(volume_like, _ext.VolumeGrid):
            return cls._from_ext(volume_like)
        try:
            shape, spacing, origin = volume_like.shape, volume_like.spacing, volume_like.origin
        except AttributeError:
            raise TypeError("grid: expected a sonoslice.Grid or Volume (something with shape, spacing and "
                            f"origin), got {type(volume_like).__name__}") from None
        direction = getattr(volume_like, "direction", None)
        d = _IDENTITY3 if direction is None else _direction_rows(direction)
        return cls(tuple(int(n) for n in shape), tuple(map(float, spacing)), tuple(map(float, origin)), d)

    def __repr__(self) -> str:
        nz, ny, nx = self.shape
        extra = "" if self.direction == _IDENTITY3 else f", direction={self.direction}"
        return f"Grid({nx}x{ny}x{nz} voxels (x, y, z), spacing={self.spacing} mm, origin={self.origin} mm{extra})"


def _direction_rows(direction) -> Tuple[Tuple[float, float, float], ...]:
    return tuple(tuple(row) for row in _real_array(direction, "direction").reshape(3, 3).tolist())


def _spacing3(spacing, what: str) -> Tuple[float, float, float]:
    """One number or three (x, y, z mm) as three; the library checks the values."""
    if spacing is None:
        raise ValueError(f"{what}: give spacing (mm)")
    s = (float(spacing),) * 3 if np.isscalar(spacing) else tuple(float(v) for v in spacing)
    if len(s) != 3:
        raise ValueError(f"{what}: spacing must be one number or three (x, y, z mm), got {spacing!r}")
    return s


def _dtype_name(dtype, what: str) -> str:
    try:
        name = np.dtype(dtype).name
    except TypeError:
        raise ValueError(f"{what} {dtype!r}: expected one of {', '.join(_DTYPES)}") from None
    if name not in _DTYPES:
        raise ValueError(f"{what} {name}: expected one of {', '.join(_DTYPES)}")
    return name


def _matrices(m, what: str, count: Optional[int] = None, single: bool = False) -> np.ndarray:
    """(N, 4, 4) float64 C-contiguous; (4, 4) accepted as one matrix."""
    m = _numpy(m)
    if np.iscomplexobj(m):  # said as such, not as "expected 4x4 matrices of numbers" below
        _no_complex(np.asarray(m), what)
    try:
        a = _matrix_stack(m, what)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected 4x4 matrices of numbers") from None
    if a.ndim != 3 or a.shape[1:] != (4, 4):
        raise ValueError(f"{what} has shape {a.shape}; expected (4, 4) or (N, 4, 4)")
    if count is not None and a.shape[0] != count:
        frames = "1 frame" if single else f"{count} frames"
        raise ValueError(f"{what} has shape {a.shape} for {frames}; expected "
                         f"{'(4, 4)' if count == 1 else f'({count}, 4, 4)'}")
    return np.ascontiguousarray(a)


def _whole(value, what: str) -> int:
    """An integer argument; ValueError naming ``what`` for 2.5 (int() would make it 2), TypeError for
    what is not a number. The library checks the range."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{what}: expected an integer, got {value!r}")
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)) and float(value).is_integer():
        return int(value)
    if isinstance(value, (float, np.floating)):
        raise ValueError(f"{what} {value!r}: expected a whole number")
    raise TypeError(f"{what}: expected an integer, got {type(value).__name__}")


def _frames(frames, what: str = "frames") -> np.ndarray:
    """Frames as an array in host memory (torch tensors through NumPy, lists as arrays, big-endian
    ones converted); the library checks their dtype and shape (naming ``what``), and nanobind
    makes strided arrays C-contiguous."""
    return _native(np.asarray(_numpy(frames)), what)


# ---- frame clips ----------------------------------------------------------------------------------
FrameClip = _ext.FrameClip
_FAN_KEYS = {"angles_deg": "fan_angles_deg", "origin_px": "fan_origin_px", "radius_px": "fan_radius_px"}


def _whole_pixels(v, rect, what: str) -> int:
    if not float(v).is_integer():
        raise ValueError(f"{what}: clip rect {rect} must be whole pixels")
    return int(v)


def _frame_clip(clip, what: str, frame_shape: Optional[Tuple[int, int]] = None) -> FrameClip:
    """A clip as a :class:`FrameClip`: None (every pixel), a FrameClip, ``dict(rect=(x, y, w, h),
    fan=dict(angles_deg=..., origin_px=..., radius_px=...))`` (w or h None: to the frame's edge) or
    an (H, W) mask (compared with ``frame_shape`` here, where the mask's shape is still known).
    FrameClip checks the values."""
    if clip is None:
        return FrameClip()
    if isinstance(clip, FrameClip):
        return clip
    if isinstance(clip, dict):
        unknown = sorted(set(clip) - {"rect", "fan"})
        if unknown:
            raise ValueError(f"{what}: unknown clip key(s) {unknown}; expected 'rect' and/or 'fan' "
                             "(or an (H, W) mask array)")
        kw: Dict[str, Any] = {}
        if clip.get("rect") is not None:
            r = tuple(clip["rect"])
            if len(r) != 4:
                raise ValueError(f"{what}: clip rect {r} must be (x, y, width, height) pixels")
            x, y, w, h = (None if v is None else _whole_pixels(v, r, what) for v in r)
            kw.update(x=x or 0, y=y or 0, width=-1 if w is None else w, height=-1 if h is None else h)
        if clip.get("fan") is not None:
            f = clip["fan"]
            if not isinstance(f, dict):
                raise ValueError(f"{what}: clip fan must be a dict(angles_deg=(a0, a1), origin_px=(x, y), "
                                 "radius_px=(r0, r1))")
            unknown = sorted(set(f) - set(_FAN_KEYS))
            if unknown:
                raise ValueError(f"{what}: unknown clip fan key(s) {unknown}; expected angles_deg, origin_px, "
                                 "radius_px")
            if "angles_deg" not in f:
                raise ValueError(f"{what}: clip fan needs angles_deg=(a0, a1) (degrees from +y, towards +x)")
            for key, value in f.items():
                v = tuple(float(t) for t in value)
                if len(v) != 2:
                    raise ValueError(f"{what}: clip fan {key} must be two numbers, got {value!r}")
                kw[_FAN_KEYS[key]] = v
        return FrameClip(**kw)
    m = np.asarray(_numpy(clip))
    if m.ndim != 2:
        raise ValueError(f"{what}: a clip mask must be (H, W) like the frames, got shape {m.shape} "
                         "(or give dict(rect=..., fan=...))")
    if m.dtype != np.bool_ and not np.issubdtype(m.dtype, np.integer):
        raise ValueError(f"{what}: a clip mask must be boolean or integer (non-zero: inserted), got {m.dtype}")
    if frame_shape is not None and tuple(m.shape) != tuple(frame_shape):
        raise ValueError(f"{what}: the clip mask has shape {m.shape} but frames are {tuple(frame_shape)}")
    return FrameClip(mask=m != 0)


def _clip_dict(c: FrameClip) -> Optional[Dict[str, Any]]:
    """A FrameClip (rect/fan only) as the dict Compounder takes; None when it clips nothing."""
    out: Dict[str, Any] = {}
    if (c.x, c.y, c.width, c.height) != (0, 0, -1, -1):
        out["rect"] = (c.x, c.y, None if c.width < 0 else c.width, None if c.height < 0 else c.height)
    if c.fan:
        out["fan"] = dict(angles_deg=c.fan_angles_deg, origin_px=c.fan_origin_px, radius_px=c.fan_radius_px)
    return out or None


def clip_mask(clip: Clip, frame_shape: Tuple[int, int]) -> np.ndarray:
    """The (H, W) uint8 mask (1: inserted) of the pixels a clip lets through for frames of
    ``frame_shape`` = (H, W). ``clip``: ``dict(rect=(x, y, w, h), fan=dict(angles_deg=(a0, a1),
    origin_px=(ox, oy), radius_px=(r0, r1)))`` (PLUS's conventions: the w × h pixels from (x, y);
    fan angles from the +y (depth) axis towards +x, inclusive), or a mask."""
    h, w = (int(v) for v in frame_shape)
    return _frame_clip(clip, "clip_mask", (h, w)).mask(w, h)


def grid_around(image_to_reference, frame_shape: Tuple[int, int], spacing, clip: Clip = None) -> Grid:
    """PLUS's output grid for 2D frames of ``frame_shape`` = (H, W): axes parallel to the reference
    frame, origin at the per-axis minimum of the clip rectangle's corner pixel centres over all
    frames, ``round((max - min) / spacing) + 1`` voxels. ``image_to_reference``: (N, 4, 4)."""
    h, w = (int(v) for v in frame_shape)
    m = _matrices(image_to_reference, "grid_around: image_to_reference")
    return Grid._from_ext(_ext.compound_grid_around(m, w, h, _frame_clip(clip, "grid_around", (h, w)),
                                                    _spacing3(spacing, "grid_around")))


def grid_around_beams(probe_to_reference, geometry, beam_shape: Tuple[int, int, int], spacing) -> Grid:
    """The grid (axes parallel to the reference frame) around every beam's first and last sample of
    beam-space frames of ``beam_shape`` = (n_elevation, n_azimuth, n_samples)."""
    m = _matrices(probe_to_reference, "grid_around_beams: probe_to_reference")
    g = BeamGeometry.of(geometry)
    shape = tuple(int(v) for v in beam_shape)
    if len(shape) != 3:
        raise ValueError(f"grid_around_beams: beam_shape {beam_shape} must be (n_elevation, n_azimuth, n_samples)")
    spacing = _spacing3(spacing, "grid_around_beams")
    return Grid._from_ext(_ext.compound_grid_around_beams(m, g, shape, spacing))


# ---- beam-space frames ------------------------------------------------------------------------------
BeamGeometry = _ext.BeamGeometry
HoleFillingElement = _ext.HoleFillingElement


def _fields(cls) -> List[str]:
    """The fields of a bound class (its read-write properties), in declaration order."""
    return [k for k, v in vars(cls).items() if isinstance(v, property) and v.fset is not None]


def _beam_geometry_of(geometry) -> BeamGeometry:
    """A BeamGeometry from itself, a dict of its fields, or a path to its JSON file."""
    if isinstance(geometry, BeamGeometry):
        return geometry
    if isinstance(geometry, dict):
        names = _fields(BeamGeometry)
        unknown = sorted(set(geometry) - set(names))
        if unknown:
            raise ValueError(f"beam geometry: unknown key(s) {unknown}; expected {', '.join(sorted(names))}")
        return BeamGeometry(**{k: float(v) for k, v in geometry.items()})
    if isinstance(geometry, (str, os.PathLike)):
        return BeamGeometry.from_file(geometry)
    raise TypeError("geometry: expected a sonoslice.BeamGeometry, a dict or a path to its JSON file, got "
                    f"{type(geometry).__name__}")


# BeamGeometry was a dataclass with this classmethod; the bound class keeps it (a conversion from
# dicts and paths, which is Python's to make).
BeamGeometry.of = staticmethod(_beam_geometry_of)


# ---- the compounder -------------------------------------------------------------------------------
# Hole-filling dicts' keys: the element's fields and the short names of the dicts users pass.
_HOLE_KEYS = {"type": "type", "size": "size", "stdev": "stdev", "min_ratio": "minimum_known_ratio",
              "minimum_known_ratio": "minimum_known_ratio", "length_limit": "stick_length_limit",
              "stick_length_limit": "stick_length_limit", "sticks": "sticks_to_use",
              "sticks_to_use": "sticks_to_use"}


def _hole_elements(hole_filling) -> Optional[List[HoleFillingElement]]:
    """Hole-filling elements from HoleFillingElement objects or dicts such as dict(type="gaussian",
    size=3, stdev=0.667, min_ratio=0.5) (a None value: the default)."""
    if hole_filling is None:
        return None
    if isinstance(hole_filling, (dict, HoleFillingElement)):
        hole_filling = [hole_filling]
    out = []
    for k, e in enumerate(hole_filling):
        if isinstance(e, HoleFillingElement):
            out.append(e)
            continue
        if not isinstance(e, dict):
            raise ValueError(f"hole_filling[{k}]: expected a dict such as dict(type='gaussian', size=3, "
                             f"stdev=0.667, min_ratio=0.5) or a sonoslice.HoleFillingElement, got {e!r}")
        unknown = sorted(set(e) - set(_HOLE_KEYS))
        if unknown:
            raise ValueError(f"hole_filling[{k}]: unknown key(s) {unknown}; expected type, size, stdev, "
                             "min_ratio, length_limit, sticks")
        d = {_HOLE_KEYS[key]: v for key, v in e.items() if v is not None}
        if "type" not in d:
            raise ValueError(f"hole_filling[{k}]: needs a type (gaussian, gaussian_accumulation, "
                             "distance_weight_inverse, nearest_neighbor or stick)")
        # Set field by field: the Compounder checks the list, naming the element's position
        # ("hole filling element 2: size 4 must be odd ...").
        element = HoleFillingElement(str(d.pop("type")))
        for key, value in d.items():
            setattr(element, key, float(value) if key in ("stdev", "minimum_known_ratio") else int(value))
        out.append(element)
    return out


def _hole_dicts(elements) -> List[Dict[str, Any]]:
    """Hole-filling elements as the dicts Compounder and PlusConfig report (the fields each type uses)."""
    out = []
    for e in elements:
        if e.type == "stick":
            out.append(dict(type=e.type, length_limit=e.stick_length_limit, sticks=e.sticks_to_use))
        else:
            d = dict(type=e.type, size=e.size)
            if e.type in ("gaussian", "gaussian_accumulation"):
                d["stdev"] = e.stdev
            d["min_ratio"] = e.minimum_known_ratio
            out.append(d)
    return out


def _memory_bytes(max_memory) -> int:
    """None → 0 (what the machine has); an int of bytes; or "8G", "512M", "1.5GiB"."""
    if max_memory is None:
        return 0
    if isinstance(max_memory, str):
        text = max_memory.strip().upper()
        units = {"": 1, "B": 1, "K": 1 << 10, "KB": 1 << 10, "KIB": 1 << 10, "M": 1 << 20, "MB": 1 << 20,
                 "MIB": 1 << 20, "G": 1 << 30, "GB": 1 << 30, "GIB": 1 << 30, "T": 1 << 40, "TB": 1 << 40,
                 "TIB": 1 << 40}
        number = text.rstrip("KMGTIB")
        try:
            value, scale = float(number), units[text[len(number):]]
        except (ValueError, KeyError):
            raise ValueError(f"max_memory {max_memory!r}: expected bytes or a size such as '8G' or '512M'") from None
    else:
        value, scale = float(max_memory), 1
    if not (value > 0 and math.isfinite(value)):
        raise ValueError(f"max_memory {max_memory!r}: must be a positive size")
    return int(value * scale)


class Compounder:
    """Inserts tracked frames into a voxel grid (freehand 3D reconstruction, docs/conventions.md §7) and returns
    the volume at any point. Incremental and batch insertion give the same bytes, for any number
    of threads.

    The grid: ``Compounder(grid)`` with a :class:`Grid` or a :class:`Volume` (its geometry), or
    ``Compounder(shape=(nz, ny, nx), spacing=s or (sx, sy, sz), origin=(x, y, z))``;
    :meth:`around` / :meth:`around_beams` fit it around the frames (PLUS's rule).

    Settings:

    * ``interpolation``: "linear" (each sample splatted into the 8 voxels around it with trilinear
      weights) or "nearest" (into the voxel ``floor(c + 0.5)``);
    * ``compounding``: "mean" (weighted mean of the samples), "max" (their maximum, counting
      samples with a splat weight >= 1/8) or "latest" (the newest frame that reached the voxel);
    * ``fill_holes`` (default: True when ``hole_filling`` is given) and ``hole_filling``: PLUS's
      hole-filling elements, tried in order, e.g. ``[dict(type="gaussian", size=3, stdev=0.667,
      min_ratio=0.5), dict(type="stick", length_limit=9, sticks=1)]`` (types: gaussian,
      gaussian_accumulation, distance_weight_inverse, nearest_neighbor, stick; default one
      Gaussian 3³, σ 0.6667 voxel, min_ratio 0.5);
    * ``rejection_threshold``: samples below it are not inserted (None: all are);
    * ``clip``: the default frame clip of :meth:`add` (see :func:`clip_mask`);
    * ``device``: "cpu", "cuda" or "cuda:K"; ``max_memory``: bytes or "8G" (default: what the
      machine has; a grid that does not fit raises RuntimeError naming a spacing that does);
    * ``dtype``: the default type of :meth:`volume` (integers round and saturate).
    """

    def __init__(self, grid=None, *, shape: Optional[Sequence[int]] = None, spacing=None,
                 origin: Sequence[float] = (0.0, 0.0, 0.0), direction=None, interpolation: str = "linear",
                 compounding: str = "mean", fill_holes: Optional[bool] = None,
                 hole_filling: Optional[Sequence[Union[Dict[str, Any], HoleFillingElement]]] = None,
                 rejection_threshold: Optional[float] = None, clip: Clip = None, device: str = "cpu",
                 max_memory: Union[None, int, str] = None, dtype="float32"):
        if grid is not None:
            if shape is not None or spacing is not None:
                raise ValueError("Compounder: give a grid (or volume), or shape and spacing, not both")
            g = Grid.of(grid)
        else:
            if shape is None or spacing is None:
                raise ValueError("Compounder: give a grid (a sonoslice.Grid or Volume), or shape=(nz, ny, nx) "
                                 "and spacing (mm)")
            shape = tuple(int(n) for n in shape)
            if len(shape) != 3:
                raise ValueError(f"Compounder: shape {shape} must be (nz, ny, nx)")
            o = tuple(float(v) for v in origin)
            if len(o) != 3:
                raise ValueError(f"Compounder: origin {origin} must be (x, y, z) mm")
            d = _IDENTITY3 if direction is None else _direction_rows(direction)
            g = Grid(shape, _spacing3(spacing, "Compounder"), o, d)
        if fill_holes is None:
            fill_holes = bool(hole_filling)
        if clip is not None:
            _frame_clip(clip, "Compounder")  # checked now; a mask's shape when frames arrive
        self._clip = clip
        self._beam_geometry: Optional[BeamGeometry] = None
        settings = _ext.CompoundSettings(
            interpolation=str(interpolation), compounding=str(compounding), fill_holes=bool(fill_holes),
            hole_filling=_hole_elements(hole_filling),
            rejection_threshold=None if rejection_threshold is None else float(rejection_threshold))
        self._cpp = _ext.Compounder(g._to_ext(), settings, str(device), _memory_bytes(max_memory),
                                    _dtype_name(dtype, "dtype"))
        self._device = str(device)

    @classmethod
    def around(cls, image_to_reference, frame_shape: Tuple[int, int], spacing, clip: Clip = None,
               **settings) -> "Compounder":
        """A compounder on PLUS's grid around 2D frames (:func:`grid_around`): ``frame_shape`` =
        (H, W), ``image_to_reference`` (N, 4, 4), ``spacing`` in mm (one number or x, y, z). The
        ``clip`` also becomes the default clip of :meth:`add`; other keywords as the constructor."""
        return cls(grid_around(image_to_reference, frame_shape, spacing, clip), clip=clip, **settings)

    @classmethod
    def around_beams(cls, probe_to_reference, geometry, beam_shape: Tuple[int, int, int], spacing,
                     **settings) -> "Compounder":
        """A compounder on the grid around beam-space frames (:func:`grid_around_beams`); ``geometry``
        becomes the default of :meth:`add_beams`."""
        c = cls(grid_around_beams(probe_to_reference, geometry, beam_shape, spacing), **settings)
        c._beam_geometry = BeamGeometry.of(geometry)
        return c

    # -- inserting
    def add(self, frames, image_to_reference, clip: Clip = None) -> "Compounder":
        """Inserts one 2D frame (H, W) with its (4, 4) ``image_to_reference``, or a stack (N, H, W)
        with (N, 4, 4) matrices (one pass over the grid per batch: faster than one call a frame, same
        result). Pixel (i, j) = ``frames[..., j, i]`` sits at ``image_to_reference @ (i, j, 0, 1)``
        (reference mm). ``clip``: which pixels go in (default: the compounder's); a dict
        ``dict(rect=(x, y, w, h), fan=dict(angles_deg=..., origin_px=..., radius_px=...))`` or an
        (H, W) boolean/uint8 mask. Frames entirely outside the grid change nothing. Returns self."""
        a = _frames(frames, "add: frames")
        m = _matrices(image_to_reference, "add: image_to_reference")
        if clip is None:
            clip = self._clip
        self._cpp.add_images(a, m, _frame_clip(clip, "add", a.shape[-2:]))
        return self

    def add_beams(self, frames, probe_to_reference, geometry=None) -> "Compounder":
        """Inserts 3D beam-space frames: (n_elevation, n_azimuth, n_samples) with a (4, 4)
        ``probe_to_reference``, or (N, n_elevation, n_azimuth, n_samples) with (N, 4, 4). ``geometry``:
        a :class:`BeamGeometry`, a dict of its fields or a path to its JSON (default: the one given to
        :meth:`around_beams`). Returns self."""
        a = _frames(frames, "add_beams: frames")
        m = _matrices(probe_to_reference, "add_beams: probe_to_reference")
        if geometry is None:
            if self._beam_geometry is None:
                raise ValueError("add_beams: give the frames' geometry (a sonoslice.BeamGeometry)")
            geometry = self._beam_geometry
        self._cpp.add_beams(a, m, BeamGeometry.of(geometry))
        return self

    # -- results
    def volume(self, dtype=None) -> Volume:
        """The reconstruction so far as a :class:`Volume` on the grid (``array`` is (nz, ny, nx)):
        samples combined by the compounding mode, voxels no sample reached 0, holes filled when
        asked. ``dtype``: default the compounder's; integers round and saturate."""
        return Volume._wrap(self._cpp.volume(None if dtype is None else _dtype_name(dtype, "volume: dtype")))

    def weights(self) -> Volume:
        """The summed splat weight per voxel (float32 :class:`Volume`; 0 where no sample arrived).
        Nearest splats: the number of samples; linear: the sum of their trilinear weights."""
        return Volume._wrap(self._cpp.weights())

    # -- properties
    @property
    def grid(self) -> Grid:
        """The output grid: shape (nz, ny, nx), spacing and origin along x, y, z (mm)."""
        return Grid._from_ext(self._cpp.grid)

    @property
    def frames_added(self) -> int:
        """Frames inserted so far (2D and beam-space)."""
        return self._cpp.frames_added

    dtype = property(lambda self: np.dtype(self._cpp.dtype), doc="default dtype of volume()")
    device = property(lambda self: self._device, doc='"cpu" or "cuda[:K]"')
    interpolation = property(lambda self: self._cpp.settings.interpolation, doc='"linear" or "nearest"')
    compounding = property(lambda self: self._cpp.settings.compounding, doc='"mean", "max" or "latest"')
    fill_holes = property(lambda self: self._cpp.settings.fill_holes)
    hole_filling = property(lambda self: _hole_dicts(self._cpp.settings.hole_filling),
                            doc="hole-filling elements (dicts)")
    rejection_threshold = property(lambda self: self._cpp.settings.rejection_threshold)

    def __repr__(self) -> str:
        holes = f", hole filling {[h['type'] for h in self.hole_filling]}" if self.fill_holes else ""
        return (f"Compounder({self.grid!r}, {self.interpolation} splats, {self.compounding}{holes}, "
                f"{self.frames_added} frames, {self.device})")


# ---- PLUS toolkit files -----------------------------------------------------------------------------
def _transform_name(name: str) -> str:
    return name[:-len("Transform")] if name.endswith("Transform") and len(name) > len("Transform") else name


class TransformRepository:
    """Named transforms (PLUS's transform repository; ``AToB`` maps coordinates in A to B): set some,
    ask for any chain of them and their inverses. A transform marked invalid makes every chain
    through it None."""

    def __init__(self, _cpp=None):
        self._cpp = _ext.TransformRepository() if _cpp is None else _cpp

    def set(self, name: str, matrix, valid: bool = True) -> None:
        """Adds or replaces ``name`` (e.g. "ImageToProbe"), a 4×4 matrix."""
        a, b = _ext.TransformRepository.split_name(name)
        m = _matrices(matrix, f"transform {name}", 1, single=True)[0]
        self._cpp.set(a, b, np.ascontiguousarray(m), bool(valid))

    def set_frame(self, sequence: "PlusSequence", frame: int) -> None:
        """Adds every transform of a sequence frame (those whose status is not OK as invalid)."""
        self._cpp.set_frame(sequence._cpp, sequence._index(frame))

    def get(self, name: str) -> Optional[np.ndarray]:
        """The 4×4 ``name`` (e.g. "ImageToReference") through the shortest chain; None when the chain
        passes through an invalid transform; ValueError when there is no chain at all."""
        a, b = _ext.TransformRepository.split_name(name)
        return self._cpp.get(a, b)

    def copy(self) -> "TransformRepository":
        return TransformRepository(self._cpp.copy())


class PlusSequence:
    """A PLUS tracked-frame sequence (.igs.mha / .seq.mha / .mha, .igs.nrrd / .seq.nrrd / .nrrd),
    read by :func:`read_plus_sequence`. ``frames`` is an (N, H, W) NumPy view (no copy) in MF
    orientation (flipped from the file's ``orientation`` on reading)."""

    def __init__(self, _cpp):
        self._cpp = _cpp
        self._fields = None

    @property
    def frames(self) -> np.ndarray:
        """(N, H, W) frames, MF orientation; a view of the sequence's memory, which it keeps alive."""
        return self._cpp.frames()

    path = property(lambda self: self._cpp.path)
    orientation = property(lambda self: self._cpp.orientation, doc='as written in the file (e.g. "MF", "UN")')
    dtype = property(lambda self: np.dtype(self._cpp.dtype))
    shape = property(lambda self: (self._cpp.frame_count, self._cpp.height, self._cpp.width), doc="(N, H, W)")

    def __len__(self) -> int:
        return self._cpp.frame_count

    @property
    def frame_fields(self) -> List[Dict[str, str]]:
        """Per frame, every ``Seq_FrameNNNN_<Field> = value`` of the header as strings, keyed by
        <Field> ("ProbeToTrackerTransform", "ImageStatus", "Timestamp", ...). NRRD's ``Status`` is
        "ImageStatus" here. A list of dicts (copies)."""
        if self._fields is None:
            self._fields = self._cpp.frame_fields
        return [dict(f) for f in self._fields]

    def _index(self, frame: int) -> int:
        n = len(self)
        k = int(frame)
        if k < 0:
            k += n
        if not 0 <= k < n:
            raise IndexError(f"{self.path}: frame {frame} out of range ({n} frames)")
        return k

    def image_ok(self, frame: int) -> bool:
        """False when the frame's image status exists and is not OK."""
        return self._cpp.image_ok(self._index(frame))

    def transform_names(self, frame: int) -> List[str]:
        """The transforms frame ``frame`` carries ("ProbeToTracker", ...)."""
        return self._cpp.transform_names(self._index(frame))

    def transform(self, frame: int, name: str) -> Optional[np.ndarray]:
        """Frame ``frame``'s ``<name>Transform`` as a 4×4 array ("ProbeToTracker" or
        "ProbeToTrackerTransform"); None when missing or its status is not OK."""
        return self._cpp.transform(self._index(frame), _transform_name(name))

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) seconds (NaN where a frame has no Timestamp)."""
        return np.array(self._cpp.timestamps(), dtype=np.float64)

    def save(self, path: PathLike, compress: bool = True) -> None:
        """Writes the sequence (frames, fields, orientation) with :func:`write_plus_sequence`."""
        write_plus_sequence(path, self.frames, self.frame_fields, self.orientation, compress)

    def __repr__(self) -> str:
        n, h, w = self.shape
        return f"PlusSequence({self.path!r}: {n} frames of {w}x{h} {self.dtype}, orientation {self.orientation})"


def read_plus_sequence(path: PathLike) -> PlusSequence:
    """Reads a PLUS sequence (MetaImage or NRRD, zlib/gzip-compressed or raw). OSError when missing,
    truncated or corrupt; ValueError for what sonoslice does not support (RF orientations, 3D
    frames, several channels, a transform that is not 16 numbers)."""
    return PlusSequence(_ext.read_plus_sequence(os.fspath(path)))


def _field_value(value) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return "OK" if value else "INVALID"
    a = np.asarray(value)
    if a.dtype.kind in "iuf":
        return " ".join(repr(float(v)) if a.dtype.kind == "f" else str(int(v)) for v in a.ravel())
    return str(value)


def write_plus_sequence(path: PathLike, frames, fields: Optional[Sequence[Dict[str, Any]]] = None,
                        orientation: str = "MF", compress: bool = True) -> None:
    """Writes a PLUS sequence atomically: .mha (MetaImage, zlib when ``compress``) or .nrrd (gzip).
    ``frames``: (N, H, W) in MF orientation (written flipped to ``orientation``, e.g. "UN");
    ``fields``: per frame (at most N) a dict of ``Seq_FrameNNNN_<key> = value`` fields, e.g.
    ``{"ProbeToTrackerTransform": m4x4, "ProbeToTrackerTransformStatus": "OK", "Timestamp": 0.1,
    "ImageStatus": "OK"}``: arrays become their numbers (row-major, exact), True/False "OK"/"INVALID"."""
    a = _frames(frames, "write_plus_sequence: frames")
    out = []
    for k, f in enumerate(fields or []):
        if not isinstance(f, dict):
            raise ValueError(f"write_plus_sequence: fields[{k}] must be a dict, got {type(f).__name__}")
        out.append({str(key): _field_value(v) for key, v in f.items()})
    _ext.write_plus_sequence(os.fspath(path), a, out, str(orientation), bool(compress))


class PlusConfig:
    """What sonoslice uses from a PLUS configuration XML (:func:`read_plus_config`): the
    calibration (``coordinate_definitions``, e.g. ImageToProbe) and the VolumeReconstruction
    settings with PLUS's defaults where absent.

    ``spacing``/``origin`` (x, y, z mm) and ``extent`` (i0, i1, j0, j1, k0, k1, inclusive) or None;
    ``interpolation``, ``compounding``, ``fill_holes``, ``hole_filling``, ``rejection_threshold``
    as :class:`Compounder` takes them (``settings`` gathers them); ``clip`` as ``dict(rect=...,
    fan=...)`` or None (PLUS's ClipRectangleSize w is w + 1 pixels: converted); ``skip_interval``;
    ``image_frame`` / ``reference_frame`` (default "Image" / "Reference")."""

    def __init__(self, _cpp):
        self._cpp = _cpp
        self.path: str = _cpp.path
        self.image_frame: str = _cpp.image_frame
        self.reference_frame: str = _cpp.reference_frame
        self.spacing = None if _cpp.spacing is None else tuple(_cpp.spacing)
        self.origin = None if _cpp.origin is None else tuple(_cpp.origin)
        self.extent = None if _cpp.extent is None else tuple(_cpp.extent)
        self.interpolation: str = _cpp.settings.interpolation
        self.compounding: str = _cpp.settings.compounding
        self.fill_holes: bool = _cpp.settings.fill_holes
        self.hole_filling = _hole_dicts(_cpp.settings.hole_filling)
        self.rejection_threshold: Optional[float] = _cpp.settings.rejection_threshold
        self.clip = _clip_dict(_cpp.clip)
        self.skip_interval: int = _cpp.skip_interval
        self.ignored_attributes: List[str] = list(_cpp.ignored_attributes)
        self.unknown_attributes: List[str] = list(_cpp.unknown_attributes)

    @property
    def coordinate_definitions(self) -> TransformRepository:
        """The configuration's CoordinateDefinitions (a copy)."""
        return TransformRepository(self._cpp.coordinate_definitions)

    @property
    def transform(self) -> str:
        """The transform frames are reconstructed with, e.g. "ImageToReference"."""
        return f"{self.image_frame}To{self.reference_frame}"

    @property
    def settings(self) -> Dict[str, Any]:
        """The reconstruction settings as :class:`Compounder` keywords."""
        return dict(interpolation=self.interpolation, compounding=self.compounding, fill_holes=self.fill_holes,
                    hole_filling=self.hole_filling if self.fill_holes else None,
                    rejection_threshold=self.rejection_threshold)

    @property
    def grid(self) -> Optional[Grid]:
        """The output grid the XML gives (OutputSpacing, OutputOrigin and OutputExtent), else None."""
        g = self._cpp.output_grid
        return None if g is None else Grid._from_ext(g)

    def __repr__(self) -> str:
        return (f"PlusConfig({self.path!r}: {self.transform}, spacing={self.spacing}, {self.interpolation}, "
                f"{self.compounding}, fill_holes={self.fill_holes}, clip={self.clip})")


def read_plus_config(path: PathLike) -> PlusConfig:
    """Reads a PLUS configuration XML. OSError for a missing or malformed file; ValueError naming
    the element and attribute for a bad value; warnings for deprecated/unknown attributes."""
    return PlusConfig(_ext.read_plus_config(os.fspath(path)))


def _as_sequence(sequence) -> PlusSequence:
    return sequence if isinstance(sequence, PlusSequence) else read_plus_sequence(sequence)


def _as_config(config) -> Optional[PlusConfig]:
    return None if config is None else config if isinstance(config, PlusConfig) else read_plus_config(config)


def _plus_options(seq: PlusSequence, clip, image_to_probe, spacing, dtype) -> Dict[str, Any]:
    """Conversions nanobind cannot do alone (dicts, masks, "float64" names, one spacing number);
    the recipe checks every value."""
    out: Dict[str, Any] = {}
    if clip is not None:
        out["clip"] = _frame_clip(clip, "clip", seq.shape[1:])
    if image_to_probe is not None:
        out["image_to_probe"] = _matrices(image_to_probe, "image_to_probe", 1, single=True)[0]
    if spacing is not None:
        out["spacing"] = _spacing3(spacing, "spacing")
    if dtype is not None:
        out["dtype"] = _dtype_name(dtype, "dtype")
    return out


def plus_image_to_reference(sequence, config=None, name: Optional[str] = None, image_to_probe=None,
                            skip: Optional[int] = None) -> Tuple[np.ndarray, np.ndarray]:
    """The frames of a PLUS sequence that can be used and their image→reference matrices:
    ``(frame_indices (M,), matrices (M, 4, 4))``, exactly as :func:`reconstruct_plus` and
    ``sonoslice compound`` pick them (one C++ recipe). For each frame the transform ``name``
    (default the config's ``ImageToReference``) is the chain, through the config's
    CoordinateDefinitions (calibration) and the frame's own transforms, e.g.
    ``(ReferenceToTracker)⁻¹ · ProbeToTracker · ImageToProbe`` (docs/conventions.md §7). Frames
    whose image status or transform is not OK are left out, as are all but every ``skip``-th
    (default: the config's SkipInterval). ``sequence``/``config``: objects or paths;
    ``image_to_probe``: a 4×4 calibration replacing the config's."""
    seq = _as_sequence(sequence)
    cfg = _as_config(config)
    extra = _plus_options(seq, None, image_to_probe, None, None)
    frames, matrices, _ = _ext.select_plus_frames(
        seq._cpp, None if cfg is None else cfg._cpp, None if skip is None else _whole(skip, "skip"),
        None if name is None else str(name), extra.get("image_to_probe"))
    return np.array(frames, dtype=np.int64), matrices


def reconstruct_plus(sequence, config=None, *, spacing=None, interpolation: Optional[str] = None,
                     compounding: Optional[str] = None, fill_holes: Optional[bool] = None,
                     hole_filling: Optional[Sequence[Dict[str, Any]]] = None,
                     rejection_threshold: Optional[float] = None, clip: Clip = None, skip: Optional[int] = None,
                     transform: Optional[str] = None, image_to_probe=None, dtype=None, device: str = "cpu",
                     max_memory: Union[None, int, str] = None, return_weights: bool = False,
                     return_report: bool = False, plus_exact: bool = False,
                     plus_optimization: Optional[str] = None, plus_grid: Optional[str] = None):
    """Reconstructs a PLUS sequence with the same C++ recipe as ``sonoslice compound --sequence S
    --config X`` (same inputs, same bytes) and returns the :class:`Volume` (with
    ``return_weights=True``: ``(volume, weights)``; with ``return_report=True`` a dict of what was
    used is appended: input, frames_in_input/considered/used, skipped counts and reason,
    transform, grid_from_config, splat/finish seconds).

    Settings come from the configuration XML (``config``: path or :class:`PlusConfig`), then the
    keywords override them. The grid is the XML's when it gives OutputOrigin and OutputExtent (and
    ``spacing`` is not given), else PLUS's grid around the clipped frames at ``spacing`` (mm;
    default the XML's OutputSpacing). ``fill_holes`` defaults to the XML's, or True when
    ``hole_filling`` is given. ``clip`` replaces the XML's clip (a dict, a mask or a
    :class:`FrameClip`). ``transform``: e.g. "ImageToTracker" (default the XML's
    ImageToReference); ``image_to_probe``: a 4×4 calibration (needed without a config, unless the
    frames carry the transform). Output ``dtype``: any given type is honoured; default the frames'
    (float64 and int8 frames give float32). Frames skipped (image or transform not OK) are
    reported as one warning; ValueError when none can be used.

    ``plus_exact=True`` reproduces PLUS's arithmetic bit for bit (``--plus-exact``,
    docs/compounding.md §4b): the volume in the frames' type rounded after every update, PLUS's
    uint16 accumulation buffer (the weights are it / 256), its clip extent; CPU only.
    ``plus_optimization`` picks PLUS's insertion path, "none", "partial" or "full" (default: the
    XML's Optimization attribute, else "full", PLUS's default). ``plus_grid`` picks how PLUS fits
    the grid around the frames when the XML does not fix it: "legacy" (default; PLUS 2.x, as in
    its NWire reference: origin at the frames' minimum, int((max − min)/spacing) + 1 voxels) or
    "lattice" (current PLUS/IGSIO: origin on a multiple of the spacing)."""
    if plus_optimization is not None and not plus_exact:
        raise ValueError("plus_optimization needs plus_exact=True")
    if plus_grid is not None and not plus_exact:
        raise ValueError("plus_grid needs plus_exact=True")
    seq = _as_sequence(sequence)
    cfg = _as_config(config)
    r = _ext.Reconstruction(
        seq._cpp, None if cfg is None else cfg._cpp,
        interpolation=None if interpolation is None else str(interpolation),
        compounding=None if compounding is None else str(compounding),
        fill_holes=None if fill_holes is None else bool(fill_holes),
        hole_filling=_hole_elements(hole_filling),
        rejection_threshold=None if rejection_threshold is None else float(rejection_threshold),
        skip=None if skip is None else _whole(skip, "skip"), transform=None if transform is None else str(transform),
        device=str(device), max_memory=_memory_bytes(max_memory), plus_exact=bool(plus_exact),
        plus_optimization=None if plus_optimization is None else str(plus_optimization),
        plus_grid=None if plus_grid is None else str(plus_grid),
        **_plus_options(seq, clip, image_to_probe, spacing, dtype))
    volume, weights = r.run(bool(return_weights))
    out: Tuple[Any, ...] = (Volume._wrap(volume),)
    if return_weights:
        out += (Volume._wrap(weights),)
    if return_report:
        out += (r.report,)
    return out[0] if len(out) == 1 else out
