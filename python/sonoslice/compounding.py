"""Freehand 3D reconstruction ("compounding", C++: compound/; docs/conventions.md §7). PLUS toolkit
files and the reconstruction recipe for PLUS sequences are in :mod:`sonoslice.plus`.

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
from typing import Any, Dict, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .volume import Volume

__all__ = [
    "Grid", "Compounder", "BeamGeometry", "HoleFillingElement", "FrameClip", "grid_around", "grid_around_beams",
    "clip_mask",
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
    return tuple(tuple(row) for row in _arrays.real_array(direction, "direction").reshape(3, 3).tolist())


def _spacing3(spacing, what: str) -> Tuple[float, float, float]:
    """One number or three (x, y, z mm) as three; the library checks the values."""
    if spacing is None:
        raise ValueError(f"{what}: give spacing (mm)")
    name = what if what == "spacing" else f"{what}: spacing"
    if np.ndim(spacing) == 1 and len(spacing) != 3:
        raise ValueError(f"{name} must be one number or three (x, y, z mm), got {spacing!r}")
    return _arrays.spacing(spacing, name, 3)


def _dtype_name(dtype, what: str) -> str:
    try:
        name = _arrays.dtype_name(dtype, what)
    except ValueError:
        raise ValueError(f"{what} {dtype!r}: expected one of {', '.join(_DTYPES)}") from None
    if name not in _DTYPES:
        raise ValueError(f"{what} {name}: expected one of {', '.join(_DTYPES)}")
    return name


def _frames(frames, what: str = "frames") -> np.ndarray:
    """Frames as an array in host memory (torch tensors through NumPy, lists as arrays, big-endian
    ones converted); the library checks their dtype and shape (naming ``what``), and nanobind
    makes strided arrays C-contiguous."""
    a = np.asarray(_arrays.numpy_of(frames))
    if a.dtype.kind in "OSUVMm":  # None, text, objects: nanobind would only say "incompatible"
        raise TypeError(f"{what}: expected an array of numbers, got {type(frames).__name__} of dtype {a.dtype}")
    return _arrays.native(a, what)


# ---- frame clips ----------------------------------------------------------------------------------
FrameClip = _ext.FrameClip
_FAN_KEYS = {"angles_deg": "fan_angles_deg", "origin_px": "fan_origin_px", "radius_px": "fan_radius_px"}


def _whole_pixels(v, rect, what: str) -> int:
    try:
        return _arrays.whole(v, f"{what}: clip rect")
    except ValueError:
        raise ValueError(f"{what}: clip rect {rect} must be whole pixels") from None


def _shape_of(shape, what: str, names: str) -> Tuple[int, ...]:
    """A shape given as a sequence of whole numbers (``names``: what each is, for the error)."""
    n = names.count(",") + 1
    if np.ndim(shape) != 1 or len(shape) != n:
        raise ValueError(f"{what} {shape!r} must be ({names})")
    return tuple(_arrays.whole(v, what) for v in shape)


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
                if np.ndim(value) != 1 or len(value) != 2:
                    raise ValueError(f"{what}: clip fan {key} must be two numbers, got {value!r}")
                kw[_FAN_KEYS[key]] = _arrays.floats(value, f"{what}: clip fan {key}", 2)
        return FrameClip(**kw)
    m = np.asarray(_arrays.numpy_of(clip))
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
    h, w = _shape_of(frame_shape, "clip_mask: frame_shape", "H, W")
    return _frame_clip(clip, "clip_mask", (h, w)).mask(w, h)


def grid_around(image_to_reference, frame_shape: Tuple[int, int], spacing, clip: Clip = None) -> Grid:
    """PLUS's output grid for 2D frames of ``frame_shape`` = (H, W): axes parallel to the reference
    frame, origin at the per-axis minimum of the clip rectangle's corner pixel centres over all
    frames, ``round((max - min) / spacing) + 1`` voxels. ``image_to_reference``: (N, 4, 4)."""
    h, w = _shape_of(frame_shape, "grid_around: frame_shape", "H, W")
    m = _arrays.matrices(image_to_reference, "grid_around: image_to_reference")
    return Grid._from_ext(_ext.compound_grid_around(m, w, h, _frame_clip(clip, "grid_around", (h, w)),
                                                    _spacing3(spacing, "grid_around")))


def grid_around_beams(probe_to_reference, geometry, beam_shape: Tuple[int, int, int], spacing) -> Grid:
    """The grid (axes parallel to the reference frame) around every beam's first and last sample of
    beam-space frames of ``beam_shape`` = (n_elevation, n_azimuth, n_samples)."""
    m = _arrays.matrices(probe_to_reference, "grid_around_beams: probe_to_reference")
    g = BeamGeometry.of(geometry)
    shape = _shape_of(beam_shape, "grid_around_beams: beam_shape", "n_elevation, n_azimuth, n_samples")
    spacing = _spacing3(spacing, "grid_around_beams")
    return Grid._from_ext(_ext.compound_grid_around_beams(m, g, shape, spacing))


# ---- beam-space frames ------------------------------------------------------------------------------
HoleFillingElement = _ext.HoleFillingElement


def _fields(cls) -> List[str]:
    """The fields of a bound class (its read-write properties), in declaration order."""
    return [k for k, v in vars(cls).items() if isinstance(v, property) and v.fset is not None]


class BeamGeometry(_ext.BeamGeometry):
    __doc__ = _ext.BeamGeometry.__doc__

    def __init__(self, *fields, **named):
        """Keywords as the bound class takes them (each checked); or, as when BeamGeometry was a
        dataclass, positionally in the fields' order (r0_mm, dr_mm, azimuth0_deg, ...)."""
        names = _fields(_ext.BeamGeometry)
        if len(fields) > len(names):
            raise TypeError(f"BeamGeometry: {len(fields)} values for {len(names)} fields ({', '.join(names)})")
        for name, value in zip(names, fields):
            if name in named:
                raise TypeError(f"BeamGeometry: {name} given twice")
            named[name] = value
        super().__init__(**named)

    @classmethod
    def from_file(cls, path) -> "BeamGeometry":
        """Reads the geometry JSON ({"r0_mm": ..., "dr_mm": ..., ...})."""
        g = _ext.BeamGeometry.from_file(path)
        return cls(**{name: getattr(g, name) for name in _fields(_ext.BeamGeometry)})


def _beam_geometry_of(geometry) -> BeamGeometry:
    """A BeamGeometry from itself, a dict of its fields, or a path to its JSON file."""
    if isinstance(geometry, _ext.BeamGeometry):
        return geometry
    if isinstance(geometry, dict):
        names = _fields(_ext.BeamGeometry)
        unknown = sorted(set(geometry) - set(names))
        if unknown:
            raise ValueError(f"beam geometry: unknown key(s) {unknown}; expected {', '.join(sorted(names))}")
        return BeamGeometry(**{k: _arrays.number(v, f"beam geometry: {k}") for k, v in geometry.items()})
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
        given = {key: v for key, v in e.items() if v is not None}
        if "type" not in given:
            raise ValueError(f"hole_filling[{k}]: needs a type (gaussian, gaussian_accumulation, "
                             "distance_weight_inverse, nearest_neighbor or stick)")
        # Set field by field: the Compounder checks the list, naming the element's position
        # ("hole filling element 2: size 4 must be odd ...").
        element = HoleFillingElement(_arrays.text(given.pop("type"), f"hole_filling[{k}]: type"))
        for key, value in given.items():
            name, field = f"hole_filling[{k}]: {key}", _HOLE_KEYS[key]
            setattr(element, field, _arrays.number(value, name) if field in ("stdev", "minimum_known_ratio")
                    else _arrays.whole(value, name))
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
        value, scale = _arrays.number(max_memory, "max_memory"), 1
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
            if np.ndim(shape) != 1 or len(shape) != 3:
                raise ValueError(f"Compounder: shape {shape!r} must be (nz, ny, nx)")
            shape = tuple(_arrays.whole(n, "Compounder: shape") for n in shape)
            if np.ndim(origin) != 1 or len(origin) != 3:
                raise ValueError(f"Compounder: origin {origin!r} must be (x, y, z) mm")
            o = _arrays.floats(origin, "Compounder: origin", 3)
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
            rejection_threshold=None if rejection_threshold is None else _arrays.number(rejection_threshold, "rejection_threshold"))
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
        m = _arrays.matrices(image_to_reference, "add: image_to_reference")
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
        m = _arrays.matrices(probe_to_reference, "add_beams: probe_to_reference")
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
