"""Slicing (C++: slice/): probes and their image grids, and the Slicer that cuts a volume into images
at probe poses on the CPU or a GPU; with the helpers the other image makers share (progress and
chunks, ``out=`` arrays, CUDA streams)."""
from __future__ import annotations

import math
import warnings
from typing import Callable, Optional, Sequence, Tuple, Union

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .volume import Volume

__all__ = ["Probe", "Slicer"]


def _origin(origin_mm) -> Optional[Tuple[float, float]]:
    """A probe's ``origin_mm``: None (the default) or probe (x, y) of pixel (0, 0)."""
    return None if origin_mm is None else _arrays.floats(origin_mm, "origin_mm", 2)


class Probe:
    """A probe shape and its image grid (docs/conventions.md §3). Build one with :meth:`curvilinear`,
    :meth:`linear`, :meth:`from_json` or :meth:`from_fanslicer`."""

    def __init__(self, cpp):
        self._cpp = cpp

    @classmethod
    def curvilinear(cls, radius_mm: float, depth_mm: float, sector_deg: float, width: int, height: int,
                    spacing_mm: Union[float, Sequence[float]], face_y_mm: float = 0.0,
                    origin_mm: Optional[Sequence[float]] = None) -> "Probe":
        """A convex fan: apex at ``(0, face_y_mm - radius_mm)``; a pixel is inside when its
        distance r from the apex is in [R, R + depth] and its angle within ±sector/2.
        ``origin_mm`` = probe coordinates of pixel (0, 0) (default: centred laterally, y = 0)."""
        a = _arrays
        return cls(_ext.Probe.curvilinear(a.number(radius_mm, "radius_mm"), a.number(depth_mm, "depth_mm"),
                                          a.number(sector_deg, "sector_deg"), a.whole(width, "width"),
                                          a.whole(height, "height"), a.spacing(spacing_mm, "spacing_mm", 2),
                                          face_y_mm=a.number(face_y_mm, "face_y_mm"),
                                          origin_mm=_origin(origin_mm)))

    @classmethod
    def linear(cls, width: int, height: int, spacing_mm: Union[float, Sequence[float]],
               width_mm: Optional[float] = None, depth_mm: Optional[float] = None, face_y_mm: float = 0.0,
               origin_mm: Optional[Sequence[float]] = None) -> "Probe":
        """A linear array: inside where ``|x| <= width_mm/2`` and ``0 <= y - face_y_mm <= depth_mm``
        (either limit optional; without them the whole image is inside)."""
        a = _arrays
        return cls(_ext.Probe.linear(a.whole(width, "width"), a.whole(height, "height"),
                                     a.spacing(spacing_mm, "spacing_mm", 2),
                                     width_mm=None if width_mm is None else a.number(width_mm, "width_mm"),
                                     depth_mm=None if depth_mm is None else a.number(depth_mm, "depth_mm"),
                                     face_y_mm=a.number(face_y_mm, "face_y_mm"), origin_mm=_origin(origin_mm)))

    @classmethod
    def from_json(cls, path, downsampling: int = 1) -> "Probe":
        """A native probe JSON or a fan-slicer configuration (recognised by its "simulation" key)."""
        return cls(_ext.Probe.from_file(_arrays.path(path), _arrays.whole(downsampling, "downsampling")))

    @classmethod
    def from_fanslicer(cls, path, downsampling: int = 1) -> "Probe":
        """A fan-slicer configuration file, unchanged (docs/conventions.md §4): image size divided by
        ``downsampling`` (floor), pixel size multiplied by it."""
        import json
        path = _arrays.path(path)
        with open(path) as f:
            if "simulation" not in json.load(f):
                raise ValueError(f"fan-slicer config '{path}': no \"simulation\" block")
        return cls(_ext.Probe.from_file(path, _arrays.whole(downsampling, "downsampling")))

    @classmethod
    def workload(cls, name: str) -> "Probe":
        """The benchmark probes: "W1" (fan-slicer's LUS fan at downsampling 2, 334×272) or
        "W2" (fan-slicer's linear probe, 400×500)."""
        return cls(_ext.Probe.workload(_arrays.text(name, "workload")))

    def to_json(self) -> str:
        return self._cpp.to_json()

    @property
    def mask(self) -> np.ndarray:
        """(H, W) uint8: 1 where the pixel centre is inside the probe shape."""
        return self._cpp.mask()

    type = property(lambda self: self._cpp.type, doc='"curvilinear" or "linear"')
    width = property(lambda self: self._cpp.width, doc="image columns W")
    height = property(lambda self: self._cpp.height, doc="image rows H")
    spacing_mm = property(lambda self: tuple(self._cpp.spacing_mm), doc="(sx, sy) mm")
    origin_mm = property(lambda self: tuple(self._cpp.origin_mm), doc="probe (x, y) of pixel (0, 0), mm")
    radius_mm = property(lambda self: self._cpp.radius_mm)
    depth_mm = property(lambda self: self._cpp.depth_mm)
    sector_deg = property(lambda self: self._cpp.sector_deg)
    face_y_mm = property(lambda self: self._cpp.face_y_mm)

    def __repr__(self) -> str:
        return f"Probe({self._cpp.describe()})"


def _torch_dtype(name: str):
    import torch
    t = {"float32": torch.float32, "int16": torch.int16, "uint8": torch.uint8,
         "uint16": getattr(torch, "uint16", None)}[name]
    if t is None:
        raise ValueError(f"dtype {name}: this torch has no such tensor type; use int16 or float32")
    return t


def _tqdm_callback(total: int):
    try:
        from tqdm.auto import tqdm
    except ImportError as e:
        raise RuntimeError("progress=True needs tqdm (pip install tqdm); or pass a callable") from e
    bar = tqdm(total=total, unit="img", desc="slicing")

    def update(done, _total):
        bar.update(done - bar.n)
        if done >= _total:
            bar.close()
    return update


def _progress_and_chunk(progress, n: int, chunk: Optional[int]):
    """The C++ side's progress callback for ``n`` images (``progress``: True for a tqdm bar, a
    callable ``(done, total)``, else none) and chunk size (images between progress reports; default:
    about 1% of the images, at least 64, when reporting progress; 0 for all at once)."""
    callback = _tqdm_callback(n) if progress is True else (progress if callable(progress) else None)
    if chunk is None:
        return callback, max(64, math.ceil(n / 100)) if callback else 0
    return callback, _arrays.count(chunk, "chunk")


class _ImageSlicer:
    """What Slicer and SurfaceSlicer share: their images' size and dtype and the probe mask."""

    width = property(lambda self: self._cpp.width)
    height = property(lambda self: self._cpp.height)
    dtype = property(lambda self: self._cpp.dtype)

    @property
    def mask(self) -> np.ndarray:
        """(H, W) uint8 probe mask."""
        return self._cpp.mask()


def _out_array(out):
    """``out=``: filled in place, so a NumPy array must be writable and in this machine's byte
    order (ValueError naming ``out`` otherwise)."""
    if out is not None and not (isinstance(out, np.ndarray) or _arrays.is_torch(out) or hasattr(out, "__dlpack__")):
        raise TypeError(f"out: expected a NumPy array, a torch tensor or a DLPack array, got {type(out).__name__}")
    if isinstance(out, np.ndarray) and not out.flags.writeable:
        raise ValueError("out: the array is read-only; slicing fills it in place: pass a writable array")
    return _arrays.native(out, "out", in_place=True)


def _current_stream(out) -> int:
    """The raw cudaStream_t that ``out``'s library queues its work on now: torch's or CuPy's current
    stream for their CUDA arrays, else 0 (the legacy default stream, which orders with every
    blocking stream)."""
    if _arrays.is_torch(out) and out.is_cuda:
        import torch
        return int(torch.cuda.current_stream(out.device).cuda_stream)
    if type(out).__module__.split(".")[0] == "cupy":
        import cupy
        with cupy.cuda.Device(out.device.id):
            return int(cupy.cuda.get_current_stream().ptr)
    return 0


def _renamed_keyword(value, old_value, name: str, old_name: str, default, where: str):
    """``value`` of the keyword ``name``, or of ``old_name`` (its deprecated spelling: a
    DeprecationWarning pointing at the caller's caller) when that was given instead."""
    if old_value is None:
        return value
    if value != default:
        raise TypeError(f"{where}: give {name}= ({old_name}= is its deprecated spelling), not both")
    warnings.warn(f"{where}: {old_name}= is deprecated; use {name}=", DeprecationWarning, stacklevel=3)
    return old_value


class Slicer(_ImageSlicer):
    """Slices a volume with a probe on one device ("cpu", "cuda", "cuda:K").

    On CUDA the volume is uploaded once, in its own pixel type, and stays on the GPU for the
    slicer's life. ``interpolation``: "linear" (trilinear) or "nearest" (labels), as for
    :class:`Compounder` (``interp=`` is its deprecated spelling); ``fill``: value outside the probe
    shape or the volume; ``dtype``: "float32", "int16", "uint8" or "uint16" (integers round and
    saturate). The GIL is released while slicing.
    """

    def __init__(self, volume: Volume, probe: Probe, device: str = "cpu", interpolation: str = "linear",
                 fill: float = 0.0, dtype: str = "float32", *, interp: Optional[str] = None):
        interpolation = _renamed_keyword(interpolation, interp, "interpolation", "interp", "linear", "Slicer")
        if not isinstance(volume, Volume):
            raise TypeError("volume: expected a sonoslice.Volume")
        if not isinstance(probe, Probe):
            raise TypeError("probe: expected a sonoslice.Probe")
        self.volume, self.probe = volume, probe
        self._cpp = _ext.Slicer(volume._cpp, probe._cpp, _arrays.device(device),
                                _arrays.text(interpolation, "interpolation"), _arrays.number(fill, "fill"),
                                _arrays.dtype_name(dtype, "dtype"))

    device = property(lambda self: self._cpp.device, doc='"cpu" or "cuda:K"')
    interpolation = property(lambda self: self._cpp.interpolation, doc='"linear" or "nearest"')

    def slice(self, poses, out=None, *, mask: bool = False,
              progress: Union[None, bool, Callable[[int, int], None]] = None, world: str = "LPS",
              stream: Optional[int] = None, chunk: Optional[int] = None):
        """Images of the probe at ``poses``: (N, 4, 4) or (4, 4) probe→world matrices (mm), NumPy or
        torch. Returns an (N, H, W) array of the slicer's dtype (and the (H, W) mask when
        ``mask=True``):

        * ``out`` given (NumPy array, torch tensor, or any CUDA array with DLPack): filled in place,
          no copy, and returned. CUDA arrays must sit on the slicer's GPU.
        * otherwise on the CPU: a new NumPy array (a torch tensor if ``poses`` is one);
          on CUDA: a new torch tensor on the slicer's GPU (torch required).

        CUDA work is queued on ``stream`` (a raw cudaStream_t; 0 is the legacy default stream), by
        default the current stream of the array's library (torch, CuPy; else 0), so that the
        library's later operations see the images without a synchronisation and its caching
        allocator never hands out ``out`` memory still being written. A CUDA ``out`` must sit on
        the slicer's GPU (another GPU's memory is refused). A host ``out`` is filled before
        ``slice`` returns; page-locked memory (a tensor made with ``pin_memory=True``) receives
        the images straight from the GPU, at the full speed of the bus, pageable memory through
        the slicer's own pinned buffers.
        ``progress``: True for a tqdm bar, or a callable ``(done, total)``.
        """
        p = _arrays.pose_array(poses, world)
        n = p.shape[0]
        on_gpu = self.device.startswith("cuda")
        out = _out_array(out)
        if out is None:
            if on_gpu:
                try:
                    import torch
                except ImportError as e:
                    raise RuntimeError("CUDA output needs PyTorch; or pass out= a CUDA array (DLPack)") from e
                out = torch.empty((n, self.height, self.width), dtype=_torch_dtype(self.dtype), device=self.device)
            elif _arrays.is_torch(poses):
                import torch
                out = torch.empty((n, self.height, self.width), dtype=_torch_dtype(self.dtype))
            else:
                out = np.empty((n, self.height, self.width), dtype=self.dtype)
        if stream is None:
            stream = _current_stream(out)
        callback, chunk = _progress_and_chunk(progress, n, chunk)
        self._cpp.slice_into(p, out, stream, callback, chunk)
        if not mask:
            return out
        m = self.mask
        if _arrays.is_torch(out):
            import torch
            m = torch.from_numpy(m).to(out.device)
        return out, m

    def __call__(self, poses, **kwargs):
        return self.slice(poses, **kwargs)

    def __repr__(self) -> str:
        return f"Slicer({self.probe!r} on {self.device}, {self.interpolation}, {self.dtype})"
