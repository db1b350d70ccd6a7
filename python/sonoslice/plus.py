"""PLUS toolkit files (C++: io/Plus*): tracked-frame sequences (.igs.mha, .igs.nrrd), configuration
XMLs and transform repositories; and the reconstruction recipe for a PLUS sequence, the same C++
recipe as ``sonoslice compound --sequence S --config X`` (docs/compounding.md)."""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .compounding import (Clip, Grid, PathLike, _clip_dict, _dtype_name, _frame_clip, _frames, _hole_dicts,
                          _hole_elements, _memory_bytes, _spacing3)
from .volume import Volume

__all__ = [
    "PlusSequence", "PlusConfig", "TransformRepository", "read_plus_sequence", "write_plus_sequence",
    "read_plus_config", "plus_image_to_reference", "reconstruct_plus",
]


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
        m = _arrays.matrices(matrix, f"transform {name}", 1, single=True)[0]
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
        k = _arrays.whole(frame, "frame")
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
    return PlusSequence(_ext.read_plus_sequence(_arrays.path(path, "sequence")))


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
    _ext.write_plus_sequence(_arrays.path(path), a, out, str(orientation), bool(compress))


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
    return PlusConfig(_ext.read_plus_config(_arrays.path(path, "config")))


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
        out["image_to_probe"] = _arrays.matrices(image_to_probe, "image_to_probe", 1, single=True)[0]
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
        seq._cpp, None if cfg is None else cfg._cpp, None if skip is None else _arrays.whole(skip, "skip"),
        None if name is None else str(name), extra.get("image_to_probe"))
    return np.array(frames, dtype=np.int64), matrices


def reconstruct_plus(sequence, config=None, *, spacing=None, interpolation: Optional[str] = None,
                     compounding: Optional[str] = None, fill_holes: Optional[bool] = None,
                     hole_filling: Optional[Sequence[Dict[str, Any]]] = None,
                     rejection_threshold: Optional[float] = None, clip: Clip = None, skip: Optional[int] = None,
                     transform: Optional[str] = None, image_to_probe=None, dtype=None, device: str = "cpu",
                     max_memory: Union[None, int, str] = None, return_weights: bool = False,
                     return_report: bool = False, plus_exact: bool = False,
                     plus_optimization: Optional[str] = None, plus_grid: Optional[str] = None,
                     origin=None, extent=None):
    """Reconstructs a PLUS sequence with the same C++ recipe as ``sonoslice compound --sequence S
    --config X`` (same inputs, same bytes) and returns the :class:`Volume` (with
    ``return_weights=True``: ``(volume, weights)``; with ``return_report=True`` a dict of what was
    used is appended: input, frames_in_input/considered/used, skipped counts and reason,
    transform, grid_from_config, splat/finish seconds).

    Settings come from the configuration XML (``config``: path or :class:`PlusConfig`), then the
    keywords override them. The grid is ``origin`` (centre of voxel (0, 0, 0), mm) with ``extent``
    (voxels along x, y, z) when given, else the XML's when it gives OutputOrigin and OutputExtent (and
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
        skip=None if skip is None else _arrays.whole(skip, "skip"), transform=None if transform is None else str(transform),
        device=str(device), max_memory=_memory_bytes(max_memory), plus_exact=bool(plus_exact),
        plus_optimization=None if plus_optimization is None else str(plus_optimization),
        plus_grid=None if plus_grid is None else str(plus_grid),
        origin=None if origin is None else _arrays.floats(origin, "origin", 3),
        extent=None if extent is None else tuple(_arrays.whole(v, "extent") for v in extent),
        **_plus_options(seq, clip, image_to_probe, spacing, dtype))
    volume, weights = r.run(bool(return_weights))
    out: Tuple[Any, ...] = (Volume._wrap(volume),)
    if return_weights:
        out += (Volume._wrap(weights),)
    if return_report:
        out += (r.report,)
    return out[0] if len(out) == 1 else out
