"""Datasets at scale: many images from one SPEC, written as WebDataset shards (docs/datasets.md).

A SPEC (YAML or JSON) names volumes, probes, pose samplers with their counts and the image kinds
of each sample. Samples are numbered globally (sampler 0's ``count`` first, then sampler 1's,
...) and shard k holds samples [k·S, (k+1)·S) for S = ``shard_samples``. A sample's pose is a
pure function of its seed, and its seed of (SPEC seed, sampler index, index within the sampler)
(:func:`sonoslice.sample_seeds`), so every shard is a pure function of (SPEC, shard index):
whoever writes it, in whatever order, writes the same bytes. That is what lets a run resume by
skipping the shards already written, and lets Dask write one shard per task with a result
byte-identical to one process.

    spec = load_spec("dataset.yaml")
    plan("dataset.yaml")                                   # counts, estimated bytes and time
    write_dataset("dataset.yaml", "out/")                  # shards + out/manifest.json
    write_dataset("dataset.yaml", "out/", scheduler="local:4")   # the same bytes, on Dask

Nothing is ever left half-written under a final name: a shard is written to a temporary name,
its checksum recorded in ``out/.checksums/``, then renamed; ``manifest.json`` comes last.
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import os
import queue
import tarfile
import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Dict, Iterator, List, Optional, Tuple

import numpy as np

from .. import _sonoslice as _ext
from .._version import __version__
from ..devices import set_threads
from ..sampling import PoseSampler, sample_seeds
from ..simulation import Simulator
from ..slicing import Probe, Slicer
from ..surfaces import Mesh, colorize
from ..volume import Volume

KINDS = ("intensity", "labels", "colours", "ultrasound")
INTENSITY_DTYPES = ("float32", "int16", "uint16", "uint8")
IMAGE_FORMATS = ("npy", "png")
MANIFEST = "manifest.json"
CHECKSUMS = ".checksums"
DEFAULT_SHARD_SAMPLES = 1000
RETRIES = 2

#: The colours image kind: label k is painted PALETTE[k] (0 black, then the 12 colours of
#: ``sonoslice slice --colors``, repeating), pixels outside the probe's fan grey 210.
PALETTE = np.array([(0, 0, 0)] + [tuple(_ext.default_label_color(k)) for k in range(1, 256)], dtype=np.uint8)

_TOP_KEYS = {"seed", "shard_samples", "image_format", "volumes", "probes", "images", "samplers"}
_VOLUME_KEYS = {"id", "ct", "labels"}
_PROBE_KEYS = {"id", "file", "downsampling"}
_IMAGE_KEYS = {"kind", "dtype", "window"}
# A sampler entry's own keys; everything else is the sampler's parameters (sonoslice.PoseSampler).
_SAMPLER_DATASET_KEYS = {"volume", "probe", "count", "images", "mesh"}
# A sampler's count and local:N's workers beyond these are typos: a billion W1 images is about
# 200 TB, and no machine runs a thousand worker processes.
_MAX_SAMPLES = 1_000_000_000
_MAX_LOCAL_WORKERS = 1024
# Images rendered at a time within a shard: bounds memory (64 W1 float32 images are 23 MB).
_CHUNK = 64


class SpecError(ValueError):
    """A SPEC that cannot be run; the message names the SPEC file and the entry."""


# ---- the SPEC ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImageKind:
    kind: str
    dtype: str  # the image's dtype: intensity's choice; uint8 for the other kinds
    window: Optional[Tuple[float, float]] = None  # intensity as uint8: (level, width), as slice --window

    def extension(self, image_format: str) -> str:
        return f"{self.kind}.{image_format}"


@dataclass(frozen=True)
class VolumeEntry:
    id: str
    ct: str
    labels: Optional[str]  # absolute paths


@dataclass(frozen=True)
class ProbeEntry:
    id: str
    file: str
    downsampling: int


@dataclass(frozen=True)
class SamplerEntry:
    index: int
    type: str
    volume: str
    probe: str
    count: int
    first: int  # global index of this sampler's sample 0
    images: Tuple[ImageKind, ...]
    mesh: Optional[str]
    config: dict = field(hash=False)  # what sonoslice.PoseSampler gets, "type" included


@dataclass(frozen=True)
class Spec:
    """A checked SPEC: paths absolute, defaults filled in. ``data`` is the SPEC as written (it goes
    into the manifest); ``inputs`` maps each input file (as the SPEC names it, relative to its
    folder) to the sha256 of its content; ``fingerprint`` identifies (SPEC, inputs, sonoslice
    version), what a shard's bytes depend on."""
    name: str  # the SPEC path as the user gave it, for messages
    path: str
    data: dict = field(hash=False)
    seed: int
    shard_samples: int
    image_format: str
    volumes: Dict[str, VolumeEntry] = field(hash=False)
    probes: Dict[str, ProbeEntry] = field(hash=False)
    samplers: Tuple[SamplerEntry, ...]
    inputs: Dict[str, str] = field(hash=False)
    fingerprint: str

    @property
    def samples(self) -> int:
        return sum(s.count for s in self.samplers)

    @property
    def shards(self) -> int:
        return math.ceil(self.samples / self.shard_samples)

    def where(self, entry: str = "") -> str:
        """The prefix of every message about this SPEC: ``SPEC 'x.yaml': samplers[0]: ``."""
        return f"SPEC '{self.name}': " + (f"{entry}: " if entry else "")


def load_spec(path) -> Spec:
    """Reads and checks a SPEC (docs/datasets.md §1); :class:`SpecError` naming the file, the entry
    and the key for anything wrong. Relative paths in it are relative to the SPEC file. Input files
    must exist (they are read later, where the work runs)."""
    name = os.fsdecode(os.fspath(path))
    data = _read_spec_file(name)
    where = f"SPEC '{name}': "
    base = os.path.dirname(os.path.abspath(name))
    _check_keys(where, data, _TOP_KEYS, {"volumes", "probes", "samplers"})
    seed = _integer(where, "seed", data.get("seed", 0), 0, 2 ** 64 - 1)
    shard_samples = _integer(where, "shard_samples", data.get("shard_samples", DEFAULT_SHARD_SAMPLES), 1)
    image_format = data.get("image_format", "npy")
    if image_format not in IMAGE_FORMATS:
        raise SpecError(f"{where}image_format {image_format!r}: expected npy or png")
    volumes = _entries(where, data, "volumes", lambda w, e: _volume_entry(w, e, base))
    probes = _entries(where, data, "probes", lambda w, e: _probe_entry(w, e, base))
    images = _image_kinds(where + "images: ", data["images"], image_format) if "images" in data else None
    samplers, first = [], 0
    for i, entry in enumerate(_list(where, data, "samplers")):
        s = _sampler_entry(f"{where}samplers[{i}]: ", entry, i, first, base, volumes, probes, images, image_format)
        samplers.append(s)
        first += s.count
    files = [v.ct for v in volumes.values()] + [v.labels for v in volumes.values() if v.labels]
    files += [p.file for p in probes.values()] + [s.mesh for s in samplers if s.mesh]
    # Keyed as the SPEC names them: relative to its folder, or absolute where they lie elsewhere.
    named = {f: os.path.relpath(f, base) for f in set(files)}
    inputs = {(n if not n.startswith("..") else f): _content_sha256(where, f) for f, n in sorted(named.items())}
    try:
        canonical = json.dumps({"spec": data, "inputs": inputs, "sonoslice": __version__}, sort_keys=True)
    except (TypeError, ValueError) as e:
        raise SpecError(f"{where}a value JSON cannot hold ({e}); quote it") from None
    return Spec(name, os.path.abspath(name), data, seed, shard_samples, image_format, volumes, probes,
                tuple(samplers), inputs, hashlib.sha256(canonical.encode()).hexdigest())


def _content_sha256(where: str, path: str) -> str:
    """The sha256 of a file's bytes, or of a folder's (a DICOM series): its files' names relative
    to it and their bytes, in name order. A shard depends on its inputs' content, so a rerun
    after an input changed must not keep the shards of the old one (about 1 GB/s)."""
    sha = hashlib.sha256()
    if os.path.isdir(path):
        names = sorted(os.path.relpath(os.path.join(d, f), path) for d, _, fs in os.walk(path) for f in fs)
    else:
        names = [""]
    try:
        for rel in names:
            sha.update(rel.encode("utf-8", "surrogateescape") + b"\0")
            with open(os.path.join(path, rel) if rel else path, "rb") as f:
                while chunk := f.read(1 << 22):
                    sha.update(chunk)
    except OSError as e:
        raise SpecError(f"{where}cannot read '{path}' ({e.strerror or e})") from None
    return sha.hexdigest()


def _read_spec_file(name: str) -> dict:
    """The SPEC's content: JSON for ``.json`` files, YAML otherwise (YAML reads JSON too)."""
    where = f"SPEC '{name}'"
    try:
        with open(name, encoding="utf-8") as f:
            text = f.read()
    except FileNotFoundError:
        raise SpecError(f"{where}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SpecError(f"{where}: cannot read it ({e})") from None
    if name.lower().endswith(".json"):
        try:
            data = json.loads(text)
        except ValueError as e:
            raise SpecError(f"{where}: not valid JSON ({e})") from None
        except RecursionError:
            raise SpecError(f"{where}: not valid JSON (nested too deep to read)") from None
    else:
        try:
            import yaml
        except ImportError:
            raise SpecError(f"{where}: YAML SPECs need PyYAML (pip install pyyaml); or write it as .json") from None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise SpecError(f"{where}: not valid YAML ({' '.join(str(e).split())})") from None
        except RecursionError:
            raise SpecError(f"{where}: not valid YAML (nested too deep to read)") from None
    if not isinstance(data, dict):
        raise SpecError(f"{where}: expected a mapping of keys (seed, volumes, probes, samplers, ...) at the top")
    return data


def _check_keys(where: str, entry, allowed, required=()) -> None:
    if not isinstance(entry, dict):
        raise SpecError(f"{where.rstrip(': ')}: expected a mapping of keys, got {type(entry).__name__}")
    for key in entry:
        if key not in allowed:
            raise SpecError(f"{where}unknown key '{key}' (known: {', '.join(sorted(allowed))})")
    for key in sorted(required):
        if key not in entry:
            raise SpecError(f"{where}missing key '{key}'")


def _integer(where: str, key: str, value, minimum: int, maximum: Optional[int] = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum or (maximum and value > maximum):
        bound = f"an integer >= {minimum}" + (f" and <= {maximum}" if maximum else "")
        raise SpecError(f"{where}{key} {value!r}: expected {bound}")
    return value


def _list(where: str, data: dict, key: str) -> list:
    value = data.get(key)
    if not isinstance(value, list) or not value:
        raise SpecError(f"{where}{key}: expected a non-empty list")
    return value


def _entries(where: str, data: dict, key: str, make) -> dict:
    """``data[key]``'s entries by id (unique, non-empty strings)."""
    out = {}
    for i, entry in enumerate(_list(where, data, key)):
        e = make(f"{where}{key}[{i}]: ", entry)
        if e.id in out:
            raise SpecError(f"{where}{key}[{i}]: id {e.id!r} is used twice")
        out[e.id] = e
    return out


def _id(where: str, entry: dict) -> str:
    value = entry["id"]
    if not isinstance(value, str) or not value:
        raise SpecError(f"{where}id {value!r}: expected a non-empty string")
    return value


def _input_file(where: str, entry: dict, key: str, base: str) -> str:
    """``entry[key]`` as an absolute path (relative to the SPEC's folder); it must exist."""
    value = entry[key]
    if not isinstance(value, str) or not value:
        raise SpecError(f"{where}{key} {value!r}: expected a path")
    path = os.path.normpath(os.path.join(base, os.path.expanduser(value)))
    if not os.path.exists(path):
        raise SpecError(f"{where}{key}: no such file '{value}' ({path})")
    return path


def _volume_entry(where: str, entry, base: str) -> VolumeEntry:
    _check_keys(where, entry, _VOLUME_KEYS, {"id", "ct"})
    labels = _input_file(where, entry, "labels", base) if entry.get("labels") is not None else None
    return VolumeEntry(_id(where, entry), _input_file(where, entry, "ct", base), labels)


def _probe_entry(where: str, entry, base: str) -> ProbeEntry:
    _check_keys(where, entry, _PROBE_KEYS, {"id", "file"})
    downsampling = _integer(where, "downsampling", entry.get("downsampling", 1), 1)
    return ProbeEntry(_id(where, entry), _input_file(where, entry, "file", base), downsampling)


def _image_kinds(where: str, value, image_format: str) -> Tuple[ImageKind, ...]:
    """The image kinds of a sample: a list of kind names or {kind, dtype} mappings, each kind once."""
    if not isinstance(value, list) or not value:
        raise SpecError(f"{where.rstrip(': ')}: expected a non-empty list of image kinds ({', '.join(KINDS)})")
    kinds = []
    for i, entry in enumerate(value):
        w = f"{where.rstrip(': ')}[{i}]: "
        entry = {"kind": entry} if isinstance(entry, str) else entry
        _check_keys(w, entry, _IMAGE_KEYS, {"kind"})
        kind = entry["kind"]
        if kind not in KINDS:
            raise SpecError(f"{w}kind {kind!r}: expected one of {', '.join(KINDS)}")
        if any(k.kind == kind for k in kinds):
            raise SpecError(f"{w}kind {kind!r} is listed twice")
        if "dtype" in entry and kind != "intensity":
            raise SpecError(f"{w}dtype: only intensity images have a choice of dtype ({kind}: uint8)")
        dtype = entry.get("dtype", "float32" if image_format == "npy" else None) if kind == "intensity" else "uint8"
        if image_format == "png" and dtype not in ("uint8", "uint16"):
            raise SpecError(f"{w}intensity as png needs dtype uint8 or uint16 (PNG holds no "
                            f"{dtype or 'float32'}); or use image_format npy")
        if dtype not in INTENSITY_DTYPES:
            raise SpecError(f"{w}dtype {dtype!r}: expected one of {', '.join(INTENSITY_DTYPES)}")
        window = _window(w, entry["window"], kind, dtype) if "window" in entry else None
        kinds.append(ImageKind(kind, dtype, window))
    return tuple(kinds)


def _window(where: str, value, kind: str, dtype: str) -> Tuple[float, float]:
    """An intensity image's window [level, width]: its values from level - width/2 to level +
    width/2 spread over 0..255 (what ``slice --window`` does to PNGs), for uint8 images."""
    if kind != "intensity" or dtype != "uint8":
        raise SpecError(f"{where}window: only intensity images of dtype uint8 have a window ({kind}: {dtype})")
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
            or not value[1] > 0):
        raise SpecError(f"{where}window {value!r}: expected [level, width], finite numbers, width > 0 "
                        "(e.g. [40, 400] for soft tissue)")
    return float(value[0]), float(value[1])


def _sampler_entry(where: str, entry, index: int, first: int, base: str, volumes: dict, probes: dict,
                   images: Optional[Tuple[ImageKind, ...]], image_format: str) -> SamplerEntry:
    """A sampler entry: its dataset keys checked here; its own parameters go to PoseSampler
    as they are (it names the ones it does not know)."""
    if not isinstance(entry, dict):
        raise SpecError(f"{where.rstrip(': ')}: expected a mapping of keys, got {type(entry).__name__}")
    for key in ("type", "volume", "probe", "count"):
        if key not in entry:
            raise SpecError(f"{where}missing key '{key}'")
    if not isinstance(entry["type"], str):
        raise SpecError(f"{where}type {entry['type']!r}: expected a sampler type (skin, mesh, region, sweep)")
    for key, known in (("volume", volumes), ("probe", probes)):
        if entry[key] not in known:
            raise SpecError(f"{where}{key} {entry[key]!r}: no such id in {key}s (ids: {', '.join(known)})")
    count = _integer(where, "count", entry["count"], 1, _MAX_SAMPLES)
    if "images" in entry:
        kinds = _image_kinds(where + "images: ", entry["images"], image_format)
    elif images is not None:
        kinds = images
    elif image_format == "png":
        raise SpecError(f"{where}images: the default, intensity as float32, cannot be a PNG; give images, "
                        "e.g. [{kind: intensity, dtype: uint8}]")
    else:
        kinds = (ImageKind("intensity", "float32"),)
    volume = volumes[entry["volume"]]
    for k in kinds:
        if k.kind in ("labels", "colours") and volume.labels is None:
            raise SpecError(f"{where}image kind '{k.kind}' needs labels, and volume '{volume.id}' has none")
    mesh = _input_file(where, entry, "mesh", base) if "mesh" in entry else None
    config = {k: v for k, v in entry.items() if k not in _SAMPLER_DATASET_KEYS}
    return SamplerEntry(index, entry["type"], volume.id, entry["probe"], count, first, kinds, mesh, config)


# ---- inputs, loaded once per process ---------------------------------------------------------------
# A Dask worker runs many shard tasks: it loads each volume, probe, mesh and sampler once, keyed by
# what defines it, and keeps it for the process's life.
_CACHE: dict = {}
_CACHE_LOCK = threading.RLock()  # re-entrant: a sampler loads its volume through the cache


def _cached(key, make):
    with _CACHE_LOCK:
        if key not in _CACHE:
            _CACHE[key] = make()
        return _CACHE[key]


def _load(what: str, path: str, read):
    """``read(path)``, its errors as :class:`SpecError` naming ``what`` (the SPEC entry)."""
    try:
        return read(path)
    except (OSError, ValueError, RuntimeError) as e:
        raise SpecError(f"{what} '{path}': {e}") from None


def volume(spec: Spec, volume_id: str) -> Volume:
    entry = spec.volumes[volume_id]
    where = f"{spec.where()}volume '{volume_id}' ct"
    return _cached(("volume", volume_id, entry.ct), lambda: _load(where, entry.ct, Volume.from_file))


def labels(spec: Spec, volume_id: str) -> Optional[Volume]:
    entry = spec.volumes[volume_id]
    if entry.labels is None:
        return None
    return _cached(("labels", volume_id, entry.labels), lambda: _label_volume(spec, entry))


def _label_volume(spec: Spec, entry: VolumeEntry) -> Volume:
    """The label volume, refused when its labels do not fit the uint8 label images."""
    v = _load(f"{spec.where()}volume '{entry.id}' labels", entry.labels, Volume.from_file)
    if v.dtype != np.uint8:
        lo, hi = v.value_range()
        if np.dtype(v.dtype).kind not in "iu" or lo < 0 or hi > 255:
            raise SpecError(f"{spec.where()}volume '{entry.id}' labels '{entry.labels}': {v.dtype} values in "
                            f"[{lo:g}, {hi:g}]; label images hold the integers 0..255")
    return v


def probe(spec: Spec, probe_id: str) -> Probe:
    entry = spec.probes[probe_id]
    return _cached(("probe", entry.file, entry.downsampling),
                   lambda: _load(f"{spec.where()}probe '{probe_id}' file", entry.file,
                                 lambda p: Probe.from_json(p, entry.downsampling)))


def pose_sampler(spec: Spec, s: SamplerEntry):
    """The ``sonoslice.PoseSampler`` of sampler entry ``s``; its ValueError for a bad parameter
    becomes a SpecError naming the SPEC and ``samplers[i]``."""
    key = ("sampler", json.dumps(s.config, sort_keys=True), spec.volumes[s.volume], spec.probes[s.probe], s.mesh)

    def make():
        mesh = None if s.mesh is None else _load(f"{spec.where(f'samplers[{s.index}]')}mesh", s.mesh, Mesh.from_file)
        inputs = dict(volume=volume(spec, s.volume), labels=labels(spec, s.volume), mesh=mesh)  # name their own entries
        the_probe = probe(spec, s.probe)
        try:
            return PoseSampler(dict(s.config), the_probe, **inputs)
        except (ValueError, TypeError, RuntimeError) as e:
            raise SpecError(f"{spec.where(f'samplers[{s.index}]')}{_unprefixed(e)}") from None
    return _cached(key, make)


def _unprefixed(error: Exception) -> str:
    """PoseSampler's message without its own "sampler: " or "sampler." prefix (the SPEC's
    ``samplers[i]`` says which sampler)."""
    text = str(error)
    for prefix in ("sampler: ", "sampler."):
        if text.startswith(prefix):
            return text[len(prefix):]
    return text


def _renderer(spec: Spec, s: SamplerEntry, kind: ImageKind):
    """The Slicer or Simulator that makes ``kind`` images for sampler ``s``'s volume and probe
    (colours: the labels' Slicer)."""
    p, inputs = probe(spec, s.probe), (spec.volumes[s.volume], spec.probes[s.probe])
    if kind.kind == "intensity":
        dtype = "float32" if kind.window else kind.dtype  # windowed from the CT's values, not rounded ones
        return _cached(("intensity", dtype) + inputs,
                       lambda: Slicer(volume(spec, s.volume), p, interpolation="linear", dtype=dtype))
    if kind.kind in ("labels", "colours"):
        return _cached(("labels",) + inputs,
                       lambda: Slicer(labels(spec, s.volume), p, interpolation="nearest", dtype="uint8"))
    return _cached(("ultrasound", spec.seed) + inputs,
                   lambda: Simulator(volume(spec, s.volume), p, seed=spec.seed, kind="ct"))


# ---- samples ---------------------------------------------------------------------------------------
def sample_poses(spec: Spec, s: SamplerEntry, first: int, count: int):
    """Poses of sampler ``s``'s samples [first, first + count) (indices within the sampler):
    ``(poses (n, 4, 4), seeds (n,), frames (n,) or None)``. A sweep's samples are its frames:
    sample i is frame i % F of sweep i // F, and records the sweep's seed."""
    sampler = pose_sampler(spec, s)
    frames_per_seed = int(sampler.poses_per_seed)
    local = np.arange(first, first + count)
    sweep0, sweep1 = first // frames_per_seed, (first + count - 1) // frames_per_seed  # the seeds' range
    seeds = np.asarray(sample_seeds(spec.seed, s.index, sweep0, sweep1 - sweep0 + 1), dtype=np.uint64)
    try:
        poses = np.asarray(sampler.sample(seeds))
    except (ValueError, RuntimeError) as e:
        which = f"sample {first}" if count == 1 else f"samples {first}..{first + count - 1}"
        raise SpecError(f"{spec.where(f'samplers[{s.index}]')}{which}: {_unprefixed(e)}") from None
    start = first - sweep0 * frames_per_seed
    frames = local % frames_per_seed if frames_per_seed > 1 else None
    return poses[start:start + count], seeds[local // frames_per_seed - sweep0], frames


def render(spec: Spec, s: SamplerEntry, poses: np.ndarray) -> Dict[str, np.ndarray]:
    """The images of each of ``s``'s kinds at ``poses``: (N, H, W), colours (N, H, W, 3)."""
    images: Dict[str, np.ndarray] = {}
    for kind in s.images:
        if kind.kind == "colours":
            slicer = _renderer(spec, s, kind)
            label_images = images["labels"] if "labels" in images else slicer.slice(poses)
            images["colours"] = colorize(label_images, slicer.mask, PALETTE[1:])
        elif kind.kind == "ultrasound":
            images["ultrasound"] = _renderer(spec, s, kind).simulate(poses)
        elif kind.window:
            images[kind.kind] = _ext.apply_window(_renderer(spec, s, kind).slice(poses), *kind.window)
        else:
            images[kind.kind] = _renderer(spec, s, kind).slice(poses)
    return images


def sample_json(s: SamplerEntry, index: int, pose: np.ndarray, seed: int, frame: Optional[int]) -> dict:
    """A sample's metadata: everything needed to make it again (its pose is a pure function of
    ``seed`` and the sampler's SPEC entry)."""
    meta = {"index": index, "volume": s.volume, "probe": s.probe, "sampler": {"index": s.index, "type": s.type},
            "seed": int(seed), "pose": pose.tolist(), "images": [k.kind for k in s.images]}
    if frame is not None:
        meta["frame"] = int(frame)
    return meta


def encode_png(image: np.ndarray, spacing_mm=(1.0, 1.0)) -> bytes:
    """PNG bytes of an (H, W) uint8/uint16 or (H, W, 3) uint8 image, encoded by libpng (the same
    pixels give the same bytes); ``spacing_mm`` goes into the sCAL chunk, as ITK writes it.
    :func:`sonoslice.datasets.reader.decode_png` reads them back."""
    return _ext.encode_png(np.ascontiguousarray(image), [float(x) for x in spacing_mm])


def encode_image(image: np.ndarray, image_format: str, spacing_mm=(1.0, 1.0)) -> bytes:
    """An image's file in the shard: ``numpy.save``'s bytes, or :func:`encode_png`'s (with the
    probe's pixel spacing)."""
    return b"".join(_image_parts(image, image_format, spacing_mm))


_NPY_HEADERS: Dict[tuple, bytes] = {}


def _image_parts(image: np.ndarray, image_format: str, spacing_mm=(1.0, 1.0)) -> tuple:
    """encode_image's bytes as pieces that are not copied: for .npy, ``numpy.save``'s header (the
    same for every image of a shape and dtype, made once) and the image's own memory."""
    if image_format == "png":
        return (encode_png(image, spacing_mm),)
    if not image.flags.c_contiguous:  # numpy.save's own bytes (Fortran order, strides)
        f = io.BytesIO()
        np.save(f, image)
        return (f.getvalue(),)
    key = (image.shape, image.dtype.str)
    header = _NPY_HEADERS.get(key)
    if header is None:
        f = io.BytesIO()
        np.lib.format.write_array_header_1_0(f, np.lib.format.header_data_from_array_1_0(image))
        header = _NPY_HEADERS[key] = f.getvalue()
    return header, memoryview(image).cast("B")


def shard_name(index: int) -> str:
    return f"shard-{index:06d}.tar"


def shard_segments(spec: Spec, index: int) -> List[Tuple[SamplerEntry, int, int]]:
    """Shard ``index``'s samples as (sampler, first index within it, count), in global order."""
    lo = index * spec.shard_samples
    hi = min(lo + spec.shard_samples, spec.samples)
    return [(s, max(lo, s.first) - s.first, min(hi, s.first + s.count) - max(lo, s.first))
            for s in spec.samplers if max(lo, s.first) < min(hi, s.first + s.count)]


def sample_members(spec: Spec, s: SamplerEntry, first: int, count: int) -> Iterator[Tuple[str, tuple]]:
    """The tar members of sampler ``s``'s samples [first, first + count), in order: for each sample
    ``KEY.json`` then ``KEY.<kind>.<format>`` per image kind; KEY = the global index, 8 digits.
    Each member's bytes come as pieces (an image's memory is not copied: it is hashed and written
    as it is). The next chunk of images is rendered (C++ threads, without the GIL) while this one
    is encoded, hashed and written."""
    poses, seeds, frames = sample_poses(spec, s, first, count)
    spacing = probe(spec, s.probe).spacing_mm
    with ThreadPoolExecutor(1) as pool:
        pending = pool.submit(render, spec, s, poses[:_CHUNK])
        for c in range(0, count, _CHUNK):
            images = pending.result()
            if c + _CHUNK < count:
                pending = pool.submit(render, spec, s, poses[c + _CHUNK:c + 2 * _CHUNK])
            for i in range(c, min(c + _CHUNK, count)):
                key = f"{s.first + first + i:08d}"
                meta = sample_json(s, s.first + first + i, poses[i], seeds[i], None if frames is None else frames[i])
                yield f"{key}.json", (json.dumps(meta, sort_keys=True).encode(),)
                for kind in s.images:
                    yield (f"{key}.{kind.extension(spec.image_format)}",
                           _image_parts(images[kind.kind][i - c], spec.image_format, spacing))


def shard_members(spec: Spec, index: int) -> Iterator[Tuple[str, bytes]]:
    """Shard ``index``'s tar members as (name, bytes), in order: a pure function of (SPEC, index)."""
    for name, parts in _shard_parts(spec, index):
        yield name, b"".join(parts)


def _shard_parts(spec: Spec, index: int) -> Iterator[Tuple[str, tuple]]:
    for s, first, count in shard_segments(spec, index):
        yield from sample_members(spec, s, first, count)


# ---- shards ----------------------------------------------------------------------------------------
class _ShardWriter:
    """A shard's bytes on their way to its file: hashed by one thread and written by another, so
    that hashing (about 1.3 GB/s), the disk's write-back stalls, rendering and encoding overlap
    (hashing and writing release the GIL). The pieces are queued as they are (never modified
    afterwards); at most 64 wait at each stage."""

    def __init__(self, f):
        self.f, self.sha, self.size, self.error = f, hashlib.sha256(), 0, None
        self.to_hash: queue.Queue = queue.Queue(maxsize=64)
        self.to_write: queue.Queue = queue.Queue(maxsize=64)
        self.threads = [threading.Thread(target=self._hash, daemon=True),
                        threading.Thread(target=self._write, daemon=True)]
        for t in self.threads:
            t.start()

    def _hash(self) -> None:
        for pieces in iter(self.to_hash.get, None):
            for piece in pieces:
                self.sha.update(piece)
            self.to_write.put(pieces)
        self.to_write.put(None)

    def _write(self) -> None:
        for pieces in iter(self.to_write.get, None):
            if self.error is None:
                try:
                    for piece in pieces:
                        self.f.write(piece)
                # Disk full, ... (raised in the writing thread, next write or close), or the file
                # closed under it because the run was interrupted (ValueError).
                except (OSError, ValueError) as e:
                    self.error = e

    def write(self, pieces: list) -> None:
        """Queues bytes-like pieces, written one after the other."""
        if self.error is not None:
            raise self.error
        self.size += sum(len(p) for p in pieces)
        self.to_hash.put(pieces)

    def close(self) -> None:
        self.to_hash.put(None)
        for t in self.threads:
            t.join()
        if self.error is not None:
            raise self.error


# Every member's ustar header is this one with its name, size and checksum written in.
_HEADER = tarfile.TarInfo("x")
_HEADER.mtime, _HEADER.mode, _HEADER.uid, _HEADER.gid, _HEADER.uname, _HEADER.gname = 0, 0o644, 0, 0, "", ""
_HEADER_TEMPLATE = _HEADER.tobuf(tarfile.USTAR_FORMAT, tarfile.ENCODING, "surrogateescape")


def _tar_header(name: str, size: int) -> bytes:
    """tarfile's ustar header (TarInfo.tobuf) of a member with write_tar's fields, without
    tarfile's per-field machinery (it cost a third of the writer's Python time)."""
    raw = name.encode(tarfile.ENCODING, "surrogateescape")
    if len(raw) > 100 or size >= 8 ** 11:  # a long name goes into the prefix field: tarfile's rules
        info = tarfile.TarInfo(name)
        info.size, info.mtime, info.mode, info.uid, info.gid, info.uname, info.gname = size, 0, 0o644, 0, 0, "", ""
        return info.tobuf(tarfile.USTAR_FORMAT, tarfile.ENCODING, "surrogateescape")
    h = bytearray(_HEADER_TEMPLATE)
    h[0:100] = raw.ljust(100, tarfile.NUL)
    h[124:136] = b"%011o\0" % size
    h[148:156] = b" " * 8
    h[148:155] = b"%06o\0" % sum(h)  # the checksum counts its own field as spaces
    return bytes(h)


def write_tar(f, members) -> Tuple[str, int]:
    """Writes ``members`` ((name, data) pairs; data: bytes, or a tuple of bytes-like pieces) as a
    tar to the binary file ``f``, deterministically: the bytes Python's tarfile writes in ustar
    format with mtime 0, uid/gid 0, no user or group names, mode 0644, in the given order (each
    member a 512-byte header, its data padded to 512 bytes; two zero blocks, then zeros to a
    multiple of 10240). Written here rather than through tarfile, which copies every member
    twice more. Returns (sha256 hex, byte count)."""
    out = _ShardWriter(f)
    try:
        for name, data in members:
            parts = data if isinstance(data, tuple) else (data,)
            size = sum(len(p) for p in parts)
            pieces = [_tar_header(name, size), *parts]
            if size % tarfile.BLOCKSIZE:
                pieces.append(tarfile.NUL * (tarfile.BLOCKSIZE - size % tarfile.BLOCKSIZE))
            out.write(pieces)
        end = 2 * tarfile.BLOCKSIZE
        end += -(out.size + end) % tarfile.RECORDSIZE
        out.write([tarfile.NUL * end])
    except Exception:
        out.close()
        raise
    except BaseException:
        # SIGTERM or Ctrl-C, raised by a signal handler wherever the main thread was, possibly
        # inside a Queue's lock: a close() would wait on that lock for ever. The threads are
        # daemons and the process is on its way out.
        raise
    out.close()
    return out.sha.hexdigest(), out.size


def write_shard(spec: Spec, index: int, out_dir) -> dict:
    """Writes shard ``index`` of ``spec`` to ``out_dir`` and returns its manifest entry (name,
    first, samples, sha256, bytes); a shard already there whose size and sha256 match its checksum
    record is kept as it is. Written to a temporary name, its record next, then renamed: an
    interrupted write leaves no shard under the final name, and a shard never exists without the
    record that vouches for it."""
    out_dir = os.fspath(out_dir)
    name = shard_name(index)
    path = os.path.join(out_dir, name)
    record = _read_record(spec, out_dir, name)
    if record is not None and _intact(path, record):
        return record
    segments = shard_segments(spec, index)
    tmp = f"{path}.{uuid.uuid4().hex}.tmp"  # unique: a retried task may race its first attempt
    try:
        with open(tmp, "wb") as f:
            sha, size = write_tar(f, _shard_parts(spec, index))
        entry = {"name": name, "first": index * spec.shard_samples, "samples": sum(n for _, _, n in segments),
                 "sha256": sha, "bytes": size}
        _write_json(os.path.join(out_dir, CHECKSUMS, name + ".json"), {"fingerprint": spec.fingerprint, **entry})
        os.replace(tmp, path)
    except OSError as e:  # a full disk, a quota, a folder gone: say which file
        _remove(tmp)
        if e.filename:
            raise
        raise OSError(e.errno, f"--out '{out_dir}': writing {name}: {e.strerror or e}") from None
    except BaseException:
        _remove(tmp)
        raise
    return entry


def _read_record(spec: Spec, out_dir: str, name: str) -> Optional[dict]:
    """Shard ``name``'s checksum record (its manifest entry), or None; a record of another SPEC is
    refused, so that a complete shard of another dataset is never replaced."""
    try:
        with open(os.path.join(out_dir, CHECKSUMS, name + ".json")) as f:
            record = json.load(f)
    except FileNotFoundError:
        return None
    except (OSError, ValueError):  # a damaged record vouches for nothing: the shard is written again
        return None
    if record.get("fingerprint") != spec.fingerprint:
        raise SpecError(f"--out '{out_dir}': {name} belongs to another SPEC, other input files or another "
                        f"sonoslice version (its record "
                        f"{CHECKSUMS}/{name}.json differs); write to another folder or empty this one")
    return {k: v for k, v in record.items() if k != "fingerprint"}


def _intact(path: str, entry: dict) -> bool:
    """Whether the file at ``path`` has the recorded size and sha256."""
    try:
        if os.path.getsize(path) != entry["bytes"]:
            return False
        sha = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 22), b""):
                sha.update(block)
    except OSError:
        return False
    return sha.hexdigest() == entry["sha256"]


def _write_json(path: str, data) -> None:
    """Writes ``data`` as JSON atomically (temporary name, then rename)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.{uuid.uuid4().hex}.tmp"
    try:
        with open(tmp, "w") as f:
            f.write(json.dumps(data, sort_keys=True, indent=1) + "\n")
        os.replace(tmp, path)
    except BaseException:
        _remove(tmp)
        raise


def _remove(path: str) -> None:
    try:
        os.remove(path)
    except FileNotFoundError:
        pass


# ---- the plan --------------------------------------------------------------------------------------
@dataclass
class Plan:
    """What :func:`write_dataset` would do: counts, and (``measure=True``) size and time estimated
    from a small batch of real samples per sampler, made on this machine in this process."""
    spec: Spec
    shards: int
    samples: int
    images: int
    estimated_bytes: Optional[int] = None
    estimated_seconds: Optional[float] = None
    setup_seconds: Optional[float] = None  # loading inputs, building samplers, slicers, simulators
    batch: Dict[int, int] = field(default_factory=dict)  # samples timed per sampler


def plan(spec_path, measure: bool = True) -> Plan:
    """The plan of ``spec_path`` (a path or a :class:`Spec`). ``measure``: also make the first
    min(16, count) samples of each sampler in memory, twice (the first pass loads the inputs and
    builds the samplers and slicers: setup; the second is timed), and extrapolate the shards'
    bytes and the run's time in one process from them. Writes nothing."""
    spec = spec_path if isinstance(spec_path, Spec) else load_spec(spec_path)
    images = sum(s.count * len(s.images) for s in spec.samplers)
    result = Plan(spec, spec.shards, spec.samples, images)
    if not measure:
        return result
    start, total_bytes, total_seconds = time.perf_counter(), 0.0, 0.0
    for s in spec.samplers:
        result.batch[s.index] = n = min(16, s.count)
        _batch_bytes(spec, s, n)  # setup: inputs, sampler, slicers
    result.setup_seconds = time.perf_counter() - start
    for s in spec.samplers:
        t0 = time.perf_counter()
        nbytes = _batch_bytes(spec, s, result.batch[s.index])
        total_seconds += (time.perf_counter() - t0) * s.count / result.batch[s.index]
        total_bytes += nbytes * s.count / result.batch[s.index]
    result.estimated_bytes = int(total_bytes + spec.shards * tarfile.RECORDSIZE)
    result.estimated_seconds = result.setup_seconds + total_seconds
    return result


def _batch_bytes(spec: Spec, s: SamplerEntry, n: int) -> int:
    """Bytes in a shard of sampler ``s``'s first ``n`` samples, made and encoded in memory."""
    _, size = write_tar(io.BytesIO(), sample_members(spec, s, 0, n))
    return size - tarfile.RECORDSIZE  # the end-of-archive blocks come once per shard


def check_inputs(spec: Spec) -> None:
    """Loads every input and makes each sampler's first sample, so that a bad volume, probe, mesh,
    sampler parameter or an impossible rejection rule is refused before any shard is written."""
    for s in spec.samplers:
        sample_poses(spec, s, 0, 1)
        for kind in s.images:
            _renderer(spec, s, kind)


# ---- the run ---------------------------------------------------------------------------------------
def write_dataset(spec_path, out_dir, scheduler: Optional[str] = None, dry_run: bool = False,
                  progress: bool = True, threads: Optional[int] = None):
    """Writes the dataset of ``spec_path`` to ``out_dir``: shards ``shard-000000.tar`` ... and, last,
    ``manifest.json``; returns the manifest (a dict). Shards already complete there (size and sha256
    as recorded) are kept, so rerunning an interrupted run finishes it.

    ``scheduler``: None for this process; ``"local:N"`` for a Dask LocalCluster of N worker
    processes; a Dask scheduler address (``"tcp://host:8786"``) for a running cluster whose workers
    see ``out_dir`` and the SPEC's inputs at the same paths. One task per shard, retried twice on
    failure; the bytes are the same as in one process. ``threads``: CPU threads per process
    (default: all cores; with ``local:N``, the cores divided among the N workers).
    ``progress``: a tqdm bar on stderr, advancing as shards complete.
    ``dry_run``: returns :func:`plan` (measured) and writes nothing."""
    spec = load_spec(spec_path)
    if dry_run:
        return plan(spec)
    workers = _parse_scheduler(scheduler)
    out_dir = os.path.abspath(os.fspath(out_dir))
    _check_out_dir(spec, out_dir)
    if scheduler is None:
        entries = _write_here(spec, out_dir, threads, progress)
    else:
        entries = _write_on_dask(spec, out_dir, scheduler, workers, threads, progress)
    manifest = _manifest(spec, sorted(entries, key=lambda e: e["first"]))
    _write_json(os.path.join(out_dir, MANIFEST), manifest)
    return manifest


def _scheduler_address(scheduler: str) -> tuple:
    """(host, port) of a tcp:// or tls:// Dask scheduler address; ValueError naming it otherwise."""
    scheme, _, rest = scheduler.partition("://")
    host, _, port = rest.rpartition(":")
    if scheme not in ("tcp", "tls") or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--scheduler '{scheduler}': expected a Dask scheduler address tcp://HOST:PORT "
                         "(PORT 1-65535), or local:N")
    return host.strip("[]"), int(port)


def _check_listening(scheduler: str) -> None:
    """A quick TCP connection to the scheduler, so that a wrong host or a closed port is said at once
    (Dask's own connect waits out its 30 s timeout)."""
    import socket
    host, port = _scheduler_address(scheduler)
    try:
        socket.create_connection((host, port), timeout=5).close()
    except OSError as e:
        why = "nothing listens there" if isinstance(e, ConnectionRefusedError) else (e.strerror or str(e))
        raise OSError(f"--scheduler '{scheduler}': cannot connect ({why})") from None


def _parse_scheduler(scheduler: Optional[str]) -> Optional[int]:
    """The worker count of ``local:N``; None for no scheduler or an address; ValueError otherwise."""
    if scheduler is None:
        return None
    if "://" in scheduler:
        _scheduler_address(scheduler)
        return None
    n = scheduler[len("local:"):] if scheduler.startswith("local:") else ""
    if not n.isdigit() or not 1 <= int(n) <= _MAX_LOCAL_WORKERS:
        raise ValueError(f"--scheduler '{scheduler}': expected local:N (1 <= N <= {_MAX_LOCAL_WORKERS} worker "
                         "processes) or a Dask scheduler address such as tcp://HOST:8786")
    return int(n)


def _try_creating_in(folder: str, out_dir: str) -> None:
    """Permission bits do not tell (root passes os.access on /sys and /proc, where nothing can be
    created): a hidden file is created in ``folder`` and removed at once."""
    import tempfile
    try:
        fd, probe = tempfile.mkstemp(prefix=".sonoslice-probe-", dir=folder)
    except OSError as e:
        raise OSError(f"--out '{out_dir}': cannot create files in '{folder}' ({e.strerror or e})") from None
    os.close(fd)
    os.remove(probe)


def _check_out_dir(spec: Spec, out_dir: str) -> None:
    """Refuses, before anything is loaded or written, an ``out_dir`` that cannot be created or that
    holds another dataset (a manifest or a shard that is not this SPEC's)."""
    if not os.path.isdir(out_dir):
        parent = out_dir
        while not os.path.exists(parent):
            parent = os.path.dirname(parent) or "."
        if not os.path.isdir(parent) or not os.access(parent, os.W_OK | os.X_OK):
            raise OSError(f"--out '{out_dir}': cannot create it ('{parent}' is not a writable folder)")
        _try_creating_in(parent, out_dir)
        return
    _try_creating_in(out_dir, out_dir)
    manifest = os.path.join(out_dir, MANIFEST)
    if os.path.exists(manifest):
        try:
            with open(manifest) as f:
                written = json.load(f)
            fingerprint, inputs = written.get("fingerprint"), written.get("inputs")
        except (OSError, ValueError, AttributeError):
            fingerprint, inputs = None, None
        if fingerprint != spec.fingerprint:
            changed = [f for f, sha in spec.inputs.items() if isinstance(inputs, dict) and
                       f in inputs and inputs[f] != sha and written.get("spec") == spec.data]
            if changed:
                raise SpecError(f"--out '{out_dir}': holds this SPEC's dataset made from another '{changed[0]}' "
                                f"(its content changed since); write to another folder or empty this one")
            raise SpecError(f"--out '{out_dir}': holds the dataset of another SPEC, other input files or "
                            f"another sonoslice version ({MANIFEST} differs); write to another folder or empty "
                            "this one")
    for k in range(spec.shards):
        name = shard_name(k)
        if os.path.exists(os.path.join(out_dir, name)) and _read_record(spec, out_dir, name) is None:
            raise SpecError(f"--out '{out_dir}': {name} is there without its checksum record ({CHECKSUMS}/"
                            f"{name}.json), so it is not this SPEC's; move it away or write to another folder")


def _prepare_out_dir(out_dir: str) -> None:
    """Creates ``out_dir`` and removes the temporaries an interrupted run left (one run writes to a
    folder at a time)."""
    os.makedirs(os.path.join(out_dir, CHECKSUMS), exist_ok=True)
    for folder in (out_dir, os.path.join(out_dir, CHECKSUMS)):
        for name in os.listdir(folder):
            if name.startswith(("shard-", MANIFEST)) and name.endswith(".tmp"):
                _remove(os.path.join(folder, name))


class _NoBar:
    def update(self, n: int) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _progress_bar(spec: Spec, progress: bool):
    if not progress:
        return _NoBar()
    try:
        from tqdm import tqdm
    except ImportError:
        raise RuntimeError("progress=True needs tqdm (pip install tqdm); or pass progress=False (-q)") from None
    return tqdm(total=spec.samples, unit="sample", desc=f"{spec.shards} shards", smoothing=0.1)


def _write_here(spec: Spec, out_dir: str, threads: Optional[int], progress: bool) -> List[dict]:
    """The shards, one after the other, in this process."""
    if threads is not None:
        set_threads(threads)
    check_inputs(spec)
    _prepare_out_dir(out_dir)
    entries = []
    with _progress_bar(spec, progress) as bar:
        for k in range(spec.shards):
            entries.append(write_shard(spec, k, out_dir))
            bar.update(entries[-1]["samples"])
    return entries


def _shard_task(index: int, spec: Spec, out_dir: str, threads: Optional[int]) -> dict:
    """One Dask task: a shard, with this worker's share of the CPU threads."""
    if threads is not None:
        set_threads(threads)
    return write_shard(spec, index, out_dir)


def _check_task(spec: Spec, threads: Optional[int]) -> None:
    """The Dask task that checks the inputs before any shard task runs, alone on the cluster: with
    all cores unless told otherwise (building a skin sampler is parallel). Its worker keeps the
    inputs loaded."""
    set_threads(threads)
    check_inputs(spec)


def _write_on_dask(spec: Spec, out_dir: str, scheduler: str, workers: Optional[int], threads: Optional[int],
                   progress: bool) -> List[dict]:
    """The shards as Dask tasks on ``scheduler``; each worker writes its shards to ``out_dir``
    itself. The inputs are checked by one task first (this process never loads them: on a cluster
    it may be a login node); then the first shard task to fail (after its retries) stops the run
    with its error."""
    try:
        import distributed
    except ImportError:
        raise RuntimeError(f"--scheduler '{scheduler}' needs Dask's distributed package "
                           "(pip install distributed); leave --scheduler out to run in this process") from None
    import logging
    cluster, check_threads = None, threads
    if workers is not None:
        if threads is None:
            threads = max(1, len(os.sched_getaffinity(0)) // workers)
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=logging.CRITICAL)
    try:
        if cluster is None:
            _check_listening(scheduler)
        try:
            client = distributed.Client(cluster if cluster is not None else scheduler, timeout="30s")
        except (OSError, TimeoutError) as e:
            raise OSError(f"--scheduler '{scheduler}': cannot connect ({e})") from None
        with client:
            client.submit(_check_task, spec, check_threads, pure=False).result()
            _prepare_out_dir(out_dir)
            futures = client.map(_shard_task, range(spec.shards), spec=spec, out_dir=out_dir, threads=threads,
                                 retries=RETRIES, pure=False)
            return _gather(distributed, client, futures, spec, scheduler, progress)
    finally:
        if cluster is not None:
            cluster.close()


def _gather(distributed, client, futures, spec: Spec, scheduler: str, progress: bool) -> List[dict]:
    """The shard tasks' entries as they complete; on the first failure the others are cancelled."""
    entries = []
    try:
        with _progress_bar(spec, progress) as bar:
            for future in distributed.as_completed(futures):
                entries.append(future.result())
                bar.update(entries[-1]["samples"])
    except (distributed.KilledWorker, distributed.client.CancelledError) as e:
        client.cancel(futures)
        raise RuntimeError(f"--scheduler '{scheduler}': a shard task was lost ({type(e).__name__}: {e}); "
                           "run again to resume") from None
    except BaseException:
        client.cancel(futures)
        raise
    return entries


def _manifest(spec: Spec, entries: List[dict]) -> dict:
    return {
        "sonoslice": __version__,
        "spec": spec.data,
        "spec_file": os.path.basename(spec.path),
        "fingerprint": spec.fingerprint,
        "inputs": spec.inputs,
        "seed": spec.seed,
        "image_format": spec.image_format,
        "shard_samples": spec.shard_samples,
        "samples": spec.samples,
        "images": sum(s.count * len(s.images) for s in spec.samplers),
        "samplers": [{"index": s.index, "type": s.type, "volume": s.volume, "probe": s.probe, "count": s.count,
                      "first": s.first, "images": [k.kind for k in s.images]} for s in spec.samplers],
        "shards": entries,
    }
