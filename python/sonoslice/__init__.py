"""sonoslice: fast ultrasound-shaped images from 3D medical volumes, on CPU threads or CUDA.

Conventions (docs/conventions.md):

* World frame: the physical space of the volume as ITK defines it (LPS: x towards the patient's
  left, y posterior, z superior), millimetres. ``world="RAS"`` accepts poses from 3D Slicer or
  nibabel.
* A pose is a 4×4 matrix mapping probe millimetres to world millimetres: column 0 the lateral
  axis (image columns), column 1 the axial/depth axis (image rows), column 3 the probe origin.
* Pixel ``(u, v)`` (column, row) of an image sits at probe ``(x0 + u·sx, y0 + v·sy, 0)``.
* Arrays are C-order: a volume is ``(nz, ny, nx)``, a batch of images ``(N, H, W)``.
* Freehand 3D reconstruction (docs/conventions.md §7: ``Compounder``, ``reconstruct_plus``) and PLUS toolkit
  files (``read_plus_sequence``, ``read_plus_config``, ...) are in ``sonoslice.compound``,
  re-exported here.

Importing this package never touches a GPU; a slicer on ``"cuda"`` starts it.
"""
from __future__ import annotations

import math
import os
import warnings
from typing import Callable, Optional, Sequence, Tuple, Union

import numpy as np

from . import _sonoslice as _ext

__all__ = [
    "Volume", "Probe", "Slicer", "devices", "cuda_available", "set_threads", "threads",
    "read_poses", "write_poses", "validate_poses", "write_stack", "phantom", "phantom_poses",
    "surface_poses", "PHANTOM_LABELS", "Mesh", "voxelize", "SurfaceSlicer", "colorize", "cut_polygons",
    "fanslicer_models", "__version__",
    # freehand reconstruction and PLUS files (sonoslice.compound)
    "Grid", "Compounder", "BeamGeometry", "HoleFillingElement", "FrameClip", "grid_around", "grid_around_beams",
    "clip_mask", "PlusSequence", "PlusConfig", "TransformRepository", "read_plus_sequence", "write_plus_sequence",
    "read_plus_config", "plus_image_to_reference", "reconstruct_plus",
    # ultrasound simulation (docs/simulation.md)
    "Simulator", "default_tissues", "phantom_tissues", "simulation_presets",
    # registration (docs/registration.md)
    "register",
    # pose samplers and datasets (docs/datasets.md)
    "PoseSampler", "sample_seeds",
]
__version__ = "0.1.0"


def _is_torch(x) -> bool:
    return type(x).__module__.startswith("torch")


def _numpy(x):
    """A torch tensor as a NumPy array in host memory; anything else as it is."""
    return x.detach().cpu().numpy() if _is_torch(x) else x


def _path(path, what: str = "path") -> str:
    """A file path (str, bytes or os.PathLike) as str; TypeError naming ``what`` for anything else
    (``str(None)`` would look for a file called 'None')."""
    if isinstance(path, (str, bytes, os.PathLike)):
        return os.fsdecode(os.fspath(path))
    raise TypeError(f"{what}: expected a file path (str or os.PathLike), got {type(path).__name__}")


def _no_complex(a: np.ndarray, what: str) -> np.ndarray:
    """``a``, or ValueError naming ``what`` when it is complex (a cast would drop the imaginary part)."""
    if a.dtype.kind == "c":
        raise ValueError(f"{what}: dtype {a.dtype.name} is complex; sonoslice takes real numbers and does "
                         "not drop imaginary parts silently (pass .real if that is what you mean)")
    return a


def _native(a, what: str, *, in_place: bool = False):
    """A NumPy array ``a`` (an input named ``what``) in this machine's byte order: a big-endian one
    (from some files and instruments) is converted, a copy, or refused naming the dtype where
    sonoslice works on the array itself (``in_place``: a Volume's voxels, ``out=``). Anything else
    (torch tensors, lists) unchanged; the library names unsupported dtypes (complex among them)."""
    if not isinstance(a, np.ndarray):
        return a
    if not a.dtype.isnative:
        if in_place:
            raise ValueError(f"{what}: dtype {a.dtype.str} is big-endian (not this machine's byte order) and "
                             "sonoslice uses the array itself, not a copy; convert it first: "
                             "a.astype(a.dtype.newbyteorder('='))")
        a = a.astype(a.dtype.newbyteorder("="))
    return a


def _real_array(x, what: str) -> np.ndarray:
    """Numbers (array-like, not torch) as float64; complex refused naming ``what``."""
    return np.asarray(_no_complex(np.asarray(x), what), dtype=np.float64)


def _floats(x, what: str, count: int) -> Tuple[float, ...]:
    """Exactly ``count`` real numbers as floats; ValueError naming ``what`` otherwise."""
    a = _real_array(x, what).ravel()
    if a.size != count:
        raise ValueError(f"{what}: expected {count} numbers, got {a.size}")
    return tuple(float(v) for v in a)


def _matrix_stack(m, what: str = "matrices") -> np.ndarray:
    """``m`` (array-like, not torch) as float64, a (4, 4) matrix as a stack of one; shape unchecked.
    Complex values are refused, naming ``what`` (a cast would drop the imaginary part)."""
    a = _real_array(m, what)
    return a[None] if a.shape == (4, 4) else a


def _as_pose_array(poses, world: str = "LPS") -> np.ndarray:
    """(N, 4, 4) float64 C-contiguous probe→world matrices in LPS, from NumPy or torch."""
    a = _matrix_stack(_numpy(poses), "poses")
    if a.ndim != 3 or a.shape[1:] != (4, 4):
        raise ValueError(f"poses: expected shape (N, 4, 4) or (4, 4), got {a.shape}")
    world = world.upper()
    if world == "RAS":
        a = a * np.array([-1.0, -1.0, 1.0, 1.0])[None, :, None]  # diag(-1, -1, 1, 1) · T
    elif world != "LPS":
        raise ValueError(f"world frame {world!r}: expected 'LPS' or 'RAS'")
    return np.ascontiguousarray(a)


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
        d = np.eye(3) if direction is None else np.array(_floats(direction, "direction", 9)).reshape(3, 3)
        self._cpp = _ext.ArrayVolume.from_array(_native(array, "volume array", in_place=True),
                                                _floats(spacing, "spacing", 3), _floats(origin, "origin", 3),
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
        d = None if direction is None else np.array(_floats(direction, "direction", 9)).reshape(3, 3).tolist()
        return cls._wrap(_ext.Volume.from_file(
            _path(path), None if spacing is None else _floats(spacing, "spacing", 3),
            None if origin is None else _floats(origin, "origin", 3), d, series or "",
            "" if npy_config is None else _path(npy_config, "npy_config")))

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
        self._cpp.save(_path(path))

    def world_to_index(self, point_mm: Sequence[float]) -> np.ndarray:
        """Continuous voxel index (i, j, k) of a world point (mm, LPS)."""
        return np.array(self._cpp.world_to_index(tuple(map(float, point_mm))))

    def index_to_world(self, index: Sequence[float]) -> np.ndarray:
        """World position (mm, LPS) of a continuous voxel index (i, j, k)."""
        return np.array(self._cpp.index_to_world(tuple(map(float, index))))

    def __repr__(self) -> str:
        nz, ny, nx = self.shape
        return (f"Volume({nx}x{ny}x{nz} {self._cpp.dtype}, spacing={self.spacing} mm, "
                f"origin={self.origin} mm)")


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
        s = (float(spacing_mm),) * 2 if np.isscalar(spacing_mm) else tuple(map(float, spacing_mm))
        return cls(_ext.Probe.curvilinear(float(radius_mm), float(depth_mm), float(sector_deg), int(width),
                                          int(height), s, float(face_y_mm),
                                          None if origin_mm is None else tuple(map(float, origin_mm))))

    @classmethod
    def linear(cls, width: int, height: int, spacing_mm: Union[float, Sequence[float]],
               width_mm: Optional[float] = None, depth_mm: Optional[float] = None, face_y_mm: float = 0.0,
               origin_mm: Optional[Sequence[float]] = None) -> "Probe":
        """A linear array: inside where ``|x| <= width_mm/2`` and ``0 <= y - face_y_mm <= depth_mm``
        (either limit optional; without them the whole image is inside)."""
        s = (float(spacing_mm),) * 2 if np.isscalar(spacing_mm) else tuple(map(float, spacing_mm))
        return cls(_ext.Probe.linear(int(width), int(height), s, width_mm, depth_mm, float(face_y_mm),
                                     None if origin_mm is None else tuple(map(float, origin_mm))))

    @classmethod
    def from_json(cls, path, downsampling: int = 1) -> "Probe":
        """A native probe JSON or a fan-slicer configuration (recognised by its "simulation" key)."""
        return cls(_ext.Probe.from_file(_path(path), int(downsampling)))

    @classmethod
    def from_fanslicer(cls, path, downsampling: int = 1) -> "Probe":
        """A fan-slicer configuration file, unchanged (docs/conventions.md §4): image size divided by
        ``downsampling`` (floor), pixel size multiplied by it."""
        import json
        path = _path(path)
        with open(path) as f:
            if "simulation" not in json.load(f):
                raise ValueError(f"fan-slicer config '{path}': no \"simulation\" block")
        return cls(_ext.Probe.from_file(path, int(downsampling)))

    @classmethod
    def workload(cls, name: str) -> "Probe":
        """The benchmark probes: "W1" (fan-slicer's LUS fan at downsampling 2, 334×272) or
        "W2" (fan-slicer's linear probe, 400×500)."""
        return cls(_ext.Probe.workload(name))

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
    callable ``(done, total)``, else none) and chunk size (default: about 1% of the images, at least
    64, when reporting progress; else 0, all at once)."""
    callback = _tqdm_callback(n) if progress is True else (progress if callable(progress) else None)
    if chunk is None:
        chunk = max(64, math.ceil(n / 100)) if callback else 0
    return callback, int(chunk)


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
    if isinstance(out, np.ndarray) and not out.flags.writeable:
        raise ValueError("out: the array is read-only; slicing fills it in place: pass a writable array")
    return _native(out, "out", in_place=True)


def _current_stream(out) -> int:
    """The raw cudaStream_t that ``out``'s library queues its work on now: torch's or CuPy's current
    stream for their CUDA arrays, else 0 (the legacy default stream, which orders with every
    blocking stream)."""
    if _is_torch(out) and out.is_cuda:
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
        self._cpp = _ext.Slicer(volume._cpp, probe._cpp, str(device), str(interpolation), float(fill), str(dtype))

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
        allocator never hands out ``out`` memory still being written. ``out`` must sit on the
        slicer's GPU (checked: host or another GPU's memory is refused).
        ``progress``: True for a tqdm bar, or a callable ``(done, total)``.
        """
        p = _as_pose_array(poses, world)
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
            elif _is_torch(poses):
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
        if _is_torch(out):
            import torch
            m = torch.from_numpy(m).to(out.device)
        return out, m

    def __call__(self, poses, **kwargs):
        return self.slice(poses, **kwargs)

    def __repr__(self) -> str:
        return f"Slicer({self.probe!r} on {self.device}, {self.interpolation}, {self.dtype})"


# ---- ultrasound simulation (docs/simulation.md) -----------------------------------------------
def default_tissues() -> list:
    """The default tissue table: a list of dicts (name, label, impedance_mrayl,
    attenuation_db_cm_mhz, scatter_mean, scatter_density), as ``sonoslice simulate
    --print-tissues`` prints it."""
    import json
    return json.loads(_ext.default_tissues_json())["tissues"]


def phantom_tissues() -> list:
    """The tissue table of the built-in phantom's labels (:data:`PHANTOM_LABELS`)."""
    import json
    return json.loads(_ext.phantom_tissues_json())["tissues"]


def simulation_presets() -> dict:
    """{name: description} of the presets (a probe and a centre frequency)."""
    return dict(_ext.simulation_presets())


def _tissues_json(tissues) -> str:
    """A tissue table given as a path, a list of dicts or {"tissues": [...]}, as JSON text."""
    import json
    if tissues is None:
        return ""
    if isinstance(tissues, (str, bytes, os.PathLike)):
        return _ext.read_tissue_table_json(_path(tissues, "tissues"))
    if isinstance(tissues, dict):
        return json.dumps(tissues)
    if isinstance(tissues, (list, tuple)):
        return json.dumps({"tissues": list(tissues)})
    raise TypeError(f"tissues: expected a path, a list of dicts or a dict, got {type(tissues).__name__}")


class Simulator:
    """Ultrasound-looking images of a CT in Hounsfield units or a label volume at probe poses
    (docs/simulation.md): reflections at impedance changes, shadows, attenuation, speckle fixed
    in the volume, log compression. Deterministic: the same seed and pose give the same bytes.

    ``volume_or_labels``: a :class:`Volume`. ``kind``: "ct" or "labels"; by default "labels"
    when ``tissues`` is given or the volume is uint8, else "ct". ``tissues``: for labels, a
    path to a JSON table, a list of dicts as :func:`default_tissues` returns, or None for the
    default table. ``probe``: a :class:`Probe` or a preset name ("abdominal", "laparoscopic",
    "lus"; its frequency is used unless ``frequency`` is given). ``tgc``: "auto" or "off".
    CPU only so far (``device="cpu"``).
    """

    def __init__(self, volume_or_labels: Volume, probe, tissues=None, frequency: Optional[float] = None,
                 seed: int = 0, device: str = "cpu", *, kind: Optional[str] = None,
                 dynamic_range: float = 60.0, tgc: str = "auto"):
        if not isinstance(volume_or_labels, Volume):
            raise TypeError("volume_or_labels: expected a sonoslice.Volume")
        if str(device) != "cpu":
            raise ValueError(f"device {device!r}: simulation runs on the CPU only so far")
        if isinstance(probe, str):
            if frequency is None:
                frequency = _ext.simulation_preset_frequency(probe)
            probe = Probe(_ext.simulation_preset_probe(probe))
        if not isinstance(probe, Probe):
            raise TypeError("probe: expected a sonoslice.Probe or a preset name")
        if kind is None:
            kind = "labels" if tissues is not None or volume_or_labels.dtype == np.uint8 else "ct"
        if tgc not in ("auto", "off"):
            raise ValueError(f'tgc {tgc!r}: expected "auto" or "off"')
        self.volume, self.probe, self.kind = volume_or_labels, probe, kind
        self._args = (volume_or_labels._cpp, probe._cpp, kind, _tissues_json(tissues),
                      float(5.0 if frequency is None else frequency), int(seed), float(dynamic_range),
                      tgc == "auto")
        self._cpp = {"bmode": _ext.Simulator(*self._args, "bmode")}

    def _engine(self, output: str):
        if output not in ("bmode", "envelope"):
            raise ValueError(f'output {output!r}: expected "bmode" or "envelope"')
        if output not in self._cpp:
            self._cpp[output] = _ext.Simulator(*self._args, output)
        return self._cpp[output]

    width = property(lambda self: self._cpp["bmode"].width)
    height = property(lambda self: self._cpp["bmode"].height)
    frequency = property(lambda self: self._args[4], doc="centre frequency, MHz")
    seed = property(lambda self: self._args[5])

    @property
    def mask(self) -> np.ndarray:
        """(H, W) uint8 probe mask (the same as :class:`Slicer`'s)."""
        return self._cpp["bmode"].mask()

    def simulate(self, poses, output: str = "bmode", out=None, *,
                 progress: Union[None, bool, Callable[[int, int], None]] = None, world: str = "LPS",
                 chunk: Optional[int] = None) -> np.ndarray:
        """Images at ``poses`` ((N, 4, 4) or (4, 4) probe→world, mm): (N, H, W) uint8 B-mode, or
        float32 linear envelope for ``output="envelope"`` (before TGC and log compression).
        ``out``: a C-contiguous array of that shape and dtype, filled in place without a copy."""
        engine = self._engine(output)
        p = _as_pose_array(poses, world)
        dtype = np.uint8 if output == "bmode" else np.float32
        out = _out_array(out)
        if out is None:
            out = np.empty((p.shape[0], self.height, self.width), dtype=dtype)
        callback, chunk = _progress_and_chunk(progress, p.shape[0], chunk)
        engine.simulate_into(p, out, callback, chunk)
        return out

    def __call__(self, poses, **kwargs):
        return self.simulate(poses, **kwargs)

    def __repr__(self) -> str:
        return f"Simulator({self.probe!r}, {self.kind}, {self.frequency} MHz, seed {self.seed})"


# ---- devices, threads ------------------------------------------------------------------------
def devices() -> str:
    """One line per compute device (CPU threads and kernels; CUDA GPUs or why there are none)."""
    return _ext.describe_devices()


def cuda_available(device: str = "cuda:0") -> bool:
    """True when this build has CUDA and ``device`` is a usable GPU (starts the CUDA runtime)."""
    try:
        _ext.require_device(device)
        return True
    except (RuntimeError, ValueError):
        return False


def set_threads(n: Optional[int]) -> None:
    """CPU threads for slicing and compounding: ``n`` >= 1, or None for all hardware threads (the
    default). Negative counts raise ValueError; 0, which earlier versions documented as "all
    threads", still means that, with a DeprecationWarning (use None)."""
    if n is None:
        _ext.reset_cpu_threads()
        return
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
        raise TypeError(f"set_threads: expected an int >= 1 or None, got {n!r}")
    if int(n) == 0:
        warnings.warn("set_threads(0) is deprecated: use set_threads(None) for all hardware threads",
                      DeprecationWarning, stacklevel=2)
        _ext.reset_cpu_threads()
        return
    _ext.set_cpu_threads(int(n))


def threads() -> int:
    return _ext.cpu_threads()


# ---- poses, files ----------------------------------------------------------------------------
def read_poses(path, world: str = "LPS") -> np.ndarray:
    """(N, 4, 4) float64 poses from .npy ((N,4,4) or fan-slicer's (4,4N)), .txt/.csv (16 or 12
    numbers a line) or .json; validated, converted to LPS."""
    return _ext.read_poses(_path(path), world)


def write_poses(path, poses) -> None:
    """Writes (N, 4, 4) poses as .npy or text (16 numbers a line), atomically."""
    _ext.write_poses(_path(path), _as_pose_array(poses))


def validate_poses(poses, source: str = "poses") -> None:
    """Raises ValueError naming the first bad pose (docs/conventions.md §2); warns once for non-orthonormal ones."""
    _ext.validate_poses(_as_pose_array(poses), source)


def write_stack(path, images, spacing_mm: Sequence[float], window: Optional[Sequence[float]] = None,
                poses=None, mask=None) -> None:
    """Writes an (N, H, W) batch (docs/conventions.md §6): .nii[.gz]/.mha/.nrrd (W×H×N, spacing (sx, sy, 1)),
    .npy, or a directory of PNGs (``window`` = (level, width), default robust auto) + poses.txt."""
    images = np.ascontiguousarray(_native(np.asarray(_numpy(images)), "images"))
    _ext.write_stack(_path(path), images, _floats(spacing_mm, "spacing_mm", 2),
                     None if window is None else _floats(window, "window", 2),
                     None if poses is None else _as_pose_array(poses), _mask_array(mask, "mask"))


def _mask_array(mask, what: str) -> Optional[np.ndarray]:
    """An (H, W) mask as C-contiguous uint8 (None stays None); complex refused."""
    if mask is None:
        return None
    return np.ascontiguousarray(_no_complex(np.asarray(_numpy(mask)), what), dtype=np.uint8)


# ---- surfaces -----------------------------------------------------------------------------------
class Mesh:
    """A triangle mesh in world millimetres (same frame as volumes). ``Mesh.from_file`` reads
    .vtk (legacy ASCII/binary POLYDATA), .vtp, .stl, .obj and .ply through VTK (polygons
    triangulated, coincident points merged); ``Mesh(vertices (V, 3), triangles (T, 3))`` builds one."""

    def __init__(self, vertices, triangles, name: str = "mesh"):
        vertices = np.ascontiguousarray(_real_array(_numpy(vertices), "vertices"))
        triangles = np.ascontiguousarray(_no_complex(np.asarray(_numpy(triangles)), "triangles"), dtype=np.int32)
        self._cpp = _ext.Mesh.from_arrays(vertices, triangles, name)

    @classmethod
    def _wrap(cls, cpp) -> "Mesh":
        m = cls.__new__(cls)
        m._cpp = cpp
        return m

    @classmethod
    def from_file(cls, path, world: str = "LPS") -> "Mesh":
        return cls._wrap(_ext.Mesh.from_file(_path(path), world))

    def save(self, path) -> None:
        self._cpp.save(_path(path))

    name = property(lambda self: self._cpp.name)
    vertices = property(lambda self: self._cpp.vertices(), doc="(V, 3) float64 mm (a copy)")
    triangles = property(lambda self: self._cpp.triangles(), doc="(T, 3) int32 vertex indices (a copy)")

    @property
    def bounds(self) -> np.ndarray:
        """[[xmin, ymin, zmin], [xmax, ymax, zmax]] (mm)."""
        return np.array(self._cpp.bounds())

    @property
    def closed(self) -> bool:
        """Every edge shared by exactly two triangles."""
        return self._cpp.closed()

    def __repr__(self) -> str:
        return f"Mesh({self.name!r}, {len(self.triangles)} triangles, {self._cpp.topology()})"


def voxelize(meshes, spacing: Optional[float] = None, margin: Optional[float] = None,
             reference: Optional[Volume] = None, labels: Optional[Sequence[int]] = None) -> Volume:
    """Meshes → one label volume: label k+1 (or ``labels[k]``) for the k-th mesh, later meshes
    winning where they overlap; uint8, or uint16 past 255. The grid is ``reference``'s, or an
    isotropic ``spacing`` (mm) around the meshes plus ``margin`` (default one voxel). Voxel centres
    are inside when the mesh contains them (docs/conventions.md §1); open meshes warn and are voted best-effort."""
    meshes = [meshes] if isinstance(meshes, Mesh) else list(meshes)
    if reference is None and spacing is None:
        raise ValueError("voxelize: give spacing (mm) or a reference volume")
    if reference is not None and (spacing is not None or margin is not None):
        raise ValueError("voxelize: the reference volume sets the grid; spacing and margin do not apply")
    spacing = 0.0 if spacing is None else float(spacing)
    margin = spacing if margin is None else float(margin)
    return Volume._wrap(_ext.voxelize([m._cpp for m in meshes], spacing, margin,
                                      None if reference is None else reference._cpp,
                                      [] if labels is None else [int(x) for x in labels]))


class SurfaceSlicer(_ImageSlicer):
    """Exact label images: each image plane cuts the meshes' triangles and the cross-sections are
    filled (even-odd), with no voxelisation: exact at any pixel size. Mesh k paints label k+1 (or
    ``labels[k]``), later meshes over earlier ones; outside the probe shape 0. CPU threads."""

    def __init__(self, meshes, probe: Probe, labels: Optional[Sequence[int]] = None, dtype: str = "uint8"):
        meshes = [meshes] if isinstance(meshes, Mesh) else list(meshes)
        self.meshes, self.probe = meshes, probe
        self._cpp = _ext.SurfaceSlicer([m._cpp for m in meshes], probe._cpp,
                                       [] if labels is None else [int(x) for x in labels], dtype)

    def slice(self, poses, out=None, *, progress=None, world: str = "LPS", chunk: Optional[int] = None):
        """(N, H, W) label images for (N, 4, 4) poses (NumPy or torch); ``out`` as in Slicer.slice
        (host memory)."""
        p = _as_pose_array(poses, world)
        n = p.shape[0]
        out = _out_array(out)
        if out is None:
            out = np.empty((n, self.height, self.width), dtype=self.dtype)
        callback, chunk = _progress_and_chunk(progress, n, chunk)
        self._cpp.slice_into(p, out, callback, chunk)
        return out

    __call__ = slice


def colorize(labels, mask, colors: Optional[Sequence[Sequence[int]]] = None) -> np.ndarray:
    """(N, H, W) labels → (N, H, W, 3) uint8 RGB, fan-slicer style: label k in ``colors[k-1]``
    (default palette otherwise), 0 black, outside the (H, W) probe mask grey 210."""
    labels = np.ascontiguousarray(_native(np.asarray(_numpy(labels)), "labels"))
    if colors is None:
        top = int(labels.max()) if labels.size else 0
        colors = [_ext.default_label_color(k) for k in range(1, max(top, 1) + 1)]
    return _ext.colorize(labels, _mask_array(mask, "mask"), [tuple(int(v) for v in c) for c in colors])


def cut_polygons(mesh: Mesh, pose) -> list:
    """The cut of ``mesh`` by the image plane of ``pose``: a list of (K, 2) arrays of probe (x, y)
    mm, one per closed loop (open meshes may give open chains)."""
    return [np.array(points) for points, _closed in _ext.cut_polygons(mesh._cpp, _as_pose_array(pose))]


def fanslicer_models(config, mesh_dir) -> list:
    """The enabled models of a fan-slicer surface config: dicts of name, path (mesh_dir/<name>.vtk),
    label (k-th enabled = k) and color."""
    models = _ext.fanslicer_models(_path(config, "config"), _path(mesh_dir, "mesh_dir"))
    return [dict(name=n, path=p, label=l, color=tuple(c)) for n, p, l, c in models]


# ---- the built-in phantom ----------------------------------------------------------------------
PHANTOM_LABELS = tuple(_ext.phantom_label_names())


def phantom(size: str = "small") -> Tuple[Volume, Volume]:
    """The deterministic CT-like abdominal phantom: (CT in HU as int16, labels as uint8; see
    PHANTOM_LABELS). "small": 128×128×100 at 3.2×3.2×4 mm; "full": 512×512×400 at 0.8×0.8×1 mm."""
    ct, labels = _ext.make_phantom(size)
    return Volume._wrap(ct), Volume._wrap(labels)


def phantom_poses(count: int, seed: int = 2024) -> np.ndarray:
    """(count, 4, 4) random poses inside the phantom's body (the benchmarks' poses)."""
    return _ext.phantom_random_poses(int(count), int(seed))


def surface_poses(count: int, face_y_mm: float = 0.0) -> np.ndarray:
    """(count, 4, 4) poses with the probe face on the phantom's skin, aimed at the liver."""
    return _ext.phantom_surface_poses(int(count), float(face_y_mm))


# ---- freehand reconstruction (compounding) and PLUS files: sonoslice/compound.py --------------------
from .compound import (  # noqa: E402  (it uses Volume, defined above)
    BeamGeometry, Compounder, FrameClip, Grid, HoleFillingElement, PlusConfig, PlusSequence, TransformRepository,
    clip_mask, grid_around, grid_around_beams, plus_image_to_reference, read_plus_config, read_plus_sequence,
    reconstruct_plus, write_plus_sequence,
)


def register(volume: Volume, probe: Probe, frames, poses, *, metric: str = "ncc", optimizer: Optional[str] = None,
             mode: str = "per-frame", starts: int = 1, search_rot_deg: float = 10.0, search_trans_mm: float = 10.0,
             seed: int = 0, pyramid: Sequence[int] = (8, 4, 2, 1), mask=None, world: str = "LPS",
             smoothness: float = 0.3):
    """Refines the poses of ``frames`` ((N, H, W) on ``probe``'s grid, any real dtype) against
    ``volume`` from ``poses`` ((N, 4, 4) probe→world, mm), as ``sonoslice register`` does
    (docs/registration.md). ``mask``: an (H, W) array, non-zero where pixels are compared (with
    the fan). Returns ``(refined, report)``: (N, 4, 4) float64 poses in ``world`` and a dict with
    "frames" (one dict per frame: index, metric, evaluations, iterations,
    translation_change_mm, rotation_change_deg), "evaluations" and "seconds". ``optimizer``: by
    default "lm" for "ssd" and "ncc", "bobyqa" for "lncc", "mi" and "lc2". ``mode``: "per-frame",
    "rigid-sweep" or "smooth-sweep" (``smoothness``: the prior's relative weight)."""
    if optimizer is None:
        optimizer = "lm" if str(metric) in ("ssd", "ncc") else "bobyqa"
    if not isinstance(volume, Volume):
        raise TypeError("volume: expected a sonoslice.Volume")
    if not isinstance(probe, Probe):
        raise TypeError("probe: expected a sonoslice.Probe")
    f = np.ascontiguousarray(_real_array(frames, "frames"), dtype=np.float32)
    if f.ndim == 2:
        f = f[None]
    if f.ndim != 3:
        raise ValueError(f"frames: expected (N, H, W), got shape {f.shape}")
    p = _as_pose_array(poses, world)
    m = None if mask is None else np.ascontiguousarray(_real_array(mask, "mask") != 0, dtype=np.uint8)
    refined, rows, evaluations, seconds = _ext.register_frames(
        volume._cpp, probe._cpp, f, p, m, str(metric), str(optimizer), str(mode), int(starts),
        float(search_rot_deg), float(search_trans_mm), int(seed), [int(x) for x in pyramid], float(smoothness))
    if str(world).upper() == "RAS":  # back to the caller's frame (the flip is its own inverse)
        refined = refined.copy()
        refined[:, :2, :] *= -1
    keys = ("index", "metric", "evaluations", "iterations", "translation_change_mm", "rotation_change_deg")
    report = {"frames": [dict(zip(keys, r)) for r in rows], "evaluations": int(evaluations), "seconds": float(seconds)}
    return refined, report


# ---- pose samplers (docs/datasets.md) -----------------------------------------------------------
def sample_seeds(base_seed: int, stream: int, first: int, count: int) -> np.ndarray:
    """The seeds of samples ``first .. first + count - 1`` of ``stream`` (a dataset's sampler
    index) under ``base_seed``: (count,) uint64, each computed on its own (counter-based), so a
    shard knows its samples' seeds without drawing the others."""
    for name, v in (("base_seed", base_seed), ("stream", stream), ("first", first), ("count", count)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 0:
            raise ValueError(f"{name}: expected an integer >= 0, got {v!r}")
    return _ext.sample_seeds(int(base_seed) % 2**64, int(stream) % 2**64, int(first), int(count))


class PoseSampler:
    """Probe poses as a pure function of a seed (docs/datasets.md §2): on the skin of a CT
    (``{"type": "skin"}``), on a mesh (``"mesh"``), inside a label or intensity range
    (``"region"``), or sweeps (``"sweep"``), with rejection on the fan's content (``"reject"``).
    ``config``: the sampler's settings as a dict (the SPEC's sampler entry without its dataset
    keys); unknown keys, keys of another sampler type and bad values raise ValueError naming them.
    ``volume``: the CT (HU); ``labels``: a label volume; ``mesh``: a :class:`Mesh`."""

    def __init__(self, config: dict, probe: Probe, volume: Optional[Volume] = None,
                 labels: Optional[Volume] = None, mesh=None):
        import json
        if not isinstance(config, dict):
            raise TypeError("config: expected a dict of sampler settings")
        if not isinstance(probe, Probe):
            raise TypeError("probe: expected a sonoslice.Probe")
        for name, v in (("volume", volume), ("labels", labels)):
            if v is not None and not isinstance(v, Volume):
                raise TypeError(f"{name}: expected a sonoslice.Volume or None")
        if mesh is not None and not isinstance(mesh, Mesh):
            raise TypeError("mesh: expected a sonoslice.Mesh or None")
        try:
            text = json.dumps(config, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise ValueError(f"config: not expressible as JSON ({e})") from None
        self.config, self.probe = dict(config), probe
        self._cpp = _ext.PoseSampler(text, probe._cpp, None if volume is None else volume._cpp,
                                     None if labels is None else labels._cpp,
                                     None if mesh is None else mesh._cpp)

    @property
    def poses_per_seed(self) -> int:
        """1, or a sweep's frame count."""
        return self._cpp.poses_per_seed

    def _seeds(self, seeds) -> np.ndarray:
        a = np.asarray(seeds)
        if a.ndim == 0:
            a = a[None]
        if a.ndim != 1 or not (np.issubdtype(a.dtype, np.integer) or a.size == 0):
            raise ValueError(f"seeds: expected a 1-D array of integers, got {a.dtype} {a.shape}")
        return np.ascontiguousarray(a.astype(np.uint64, copy=False))

    def sample(self, seeds) -> np.ndarray:
        """(len(seeds) * poses_per_seed, 4, 4) float64 probe→world poses (LPS mm), each seed's
        first candidate that passes the rejection rules (ValueError after ``max_tries``)."""
        return self._cpp.sample(self._seeds(seeds))

    def candidates(self, seeds) -> np.ndarray:
        """Each seed's first candidate, without rejection."""
        return self._cpp.candidates(self._seeds(seeds))

    def accepts(self, pose) -> bool:
        """Whether a (4, 4) pose passes the rejection rules."""
        return self._cpp.accepts(np.ascontiguousarray(np.asarray(pose, float).reshape(1, 4, 4)))

    def surface(self) -> np.ndarray:
        """Skin sampler: (P, 2, 3) points (mm) and outward unit normals of the body surface."""
        return self._cpp.surface()

    def __repr__(self) -> str:
        return f"PoseSampler({self.config.get('type')!r}, {self.poses_per_seed} pose(s) per seed)"
