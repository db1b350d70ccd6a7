"""Training on a dataset that ``sonoslice dataset`` wrote: its WebDataset shards streamed into
PyTorch (docs/datasets.md §6).

    from torch.utils.data import DataLoader
    from sonoslice.datasets.reader import ShardDataset

    data = ShardDataset("out/", shuffle=True, buffer=2000)   # the folder with manifest.json
    for images, poses, meta in DataLoader(data, batch_size=32, num_workers=4):
        ...   # images (32, H, W); poses (32, 4, 4) float64 probe→world (LPS mm); meta: index, seed, ...

Each DataLoader worker (and each process of a distributed run) reads its own shards, whole: shard
k of the list goes to reader k mod (processes × workers), so give at least that many shards. The
same stream is read by plain ``webdataset`` (docs/datasets.md §6 shows the pipeline).
"""
from __future__ import annotations

import io
import json
import os
import random
import tarfile
from typing import Callable, Dict, Iterator, List, Optional, Sequence, Union

import numpy as np

from .. import _sonoslice as _ext

try:
    import torch
    from torch.utils.data import IterableDataset, get_worker_info
except ImportError as e:  # pragma: no cover - the message is the point
    raise ImportError("sonoslice.datasets.reader needs PyTorch (pip install torch)") from e


def decode_png(data: bytes) -> np.ndarray:
    """The pixels of a grey or RGB, 8- or 16-bit PNG (what sonoslice writes), decoded by libpng:
    (H, W) uint8/uint16 or (H, W, 3). ValueError for anything else."""
    return _ext.decode_png(bytes(data))


def decode(name: str, data: bytes):
    """A member's content by its extension: ``.json`` → dict, ``.npy`` → array, ``.png`` → array."""
    if name.endswith(".json"):
        return json.loads(data)
    if name.endswith(".npy"):
        return np.load(io.BytesIO(data), allow_pickle=False)
    if name.endswith(".png"):
        return decode_png(data)
    raise ValueError(f"member '{name}': no decoder for its extension")


def read_shard(path, samples: Optional[int] = None) -> Iterator[Dict[str, object]]:
    """The samples of one shard, in order, as dicts: ``"__key__"``, ``"json"`` (the metadata) and one
    array per image kind (``"intensity"``, ``"labels"``, ``"colours"``, ``"ultrasound"``). Streams
    the tar: one sample in memory at a time. ``samples``: how many the shard must hold (its
    manifest entry's); a shard that is not a tar, is cut short or holds another count raises
    ValueError naming it, after the samples read so far."""
    name = os.fspath(path)
    sample: Dict[str, object] = {}
    count = 0
    try:
        with tarfile.open(name, mode="r|") as tar:
            for member in tar:
                if not member.isfile():
                    continue
                key, _, rest = member.name.partition(".")
                if sample and key != sample["__key__"]:
                    count += 1
                    yield sample
                    sample = {}
                field = "json" if rest == "json" else rest.rsplit(".", 1)[0]
                sample["__key__"] = key
                sample[field] = decode(member.name, tar.extractfile(member).read())
    except (tarfile.TarError, EOFError) as e:
        raise ValueError(f"shard '{name}': not a complete tar archive ({e}): the file is damaged or was "
                         "cut short") from None
    if sample:
        count += 1
        yield sample
    if samples is not None and count != samples:
        raise ValueError(f"shard '{name}': {count} samples, its manifest says {samples}: the shard was cut "
                         "short or replaced")


def shard_paths(source) -> List[str]:
    """Shard paths from a dataset folder (its manifest.json's shards, in order), one shard path, or
    a list of paths."""
    return [path for path, _ in _shards(source)]


def _shards(source) -> List[tuple]:
    """(path, samples the manifest promises or None) of each shard of ``source``."""
    if isinstance(source, (str, os.PathLike)) and os.path.isdir(source):
        with open(os.path.join(source, "manifest.json")) as f:
            return [(os.path.join(os.fspath(source), s["name"]), s.get("samples"))
                    for s in json.load(f)["shards"]]
    if isinstance(source, (str, os.PathLike)):
        return [(os.fspath(source), None)]
    return [(os.fspath(p), None) for p in source]


def _tensor(a: np.ndarray) -> "torch.Tensor":
    """A torch tensor of ``a``; uint16 widened to int32 (torch has no uint16 tensors)."""
    return torch.from_numpy(a.astype(np.int32) if a.dtype == np.uint16 else a)


class ShardDataset(IterableDataset):
    """The samples of a sonoslice dataset as ``(images, pose, meta)``.

    ``source``: the dataset folder (shards from its manifest), a shard path, or a list of paths.
    ``images``: a tensor when ``kinds`` is one kind name, a dict {kind: tensor} when it is a list;
    by default (None) a tensor when the sample has one image kind and a dict otherwise. Images are
    (H, W) (colours (H, W, 3)) in their stored dtype (uint16 as int32). ``pose``: (4, 4) float64
    probe→world (LPS mm). ``meta``: the rest of the sample's JSON (index, seed, volume, probe,
    sampler, frame), made to collate into batches: ``"frame"`` -1 where the sample is not a sweep
    frame, ``"seed"`` a decimal string (a uint64; torch has none).

    Shards are split over distributed processes (torch.distributed's rank) and then over DataLoader
    workers: shard k goes to reader k mod readers. ``shuffle``: the shard order is shuffled each
    epoch (``seed`` + the epoch of :meth:`set_epoch`) and samples pass a shuffle ``buffer`` of that
    many samples. ``transform``: applied to each (images, pose, meta).
    """

    def __init__(self, source, kinds: Union[None, str, Sequence[str]] = None, shuffle: bool = False,
                 buffer: int = 1000, seed: int = 0, transform: Optional[Callable] = None):
        shards = _shards(source)
        self.shards = [path for path, _ in shards]
        self._samples = dict(shards)
        self.kinds, self.shuffle, self.buffer, self.seed, self.transform = kinds, shuffle, buffer, seed, transform
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        """Reshuffles for ``epoch`` (call it before each epoch's iteration, as with DistributedSampler)."""
        self.epoch = epoch

    def _my_shards(self) -> List[str]:
        """This reader's shards: the epoch's order, then every readers-th from this reader's index."""
        shards = list(self.shards)
        if self.shuffle:
            random.Random(self.seed * 1_000_003 + self.epoch).shuffle(shards)
        rank, world = 0, 1
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            rank, world = torch.distributed.get_rank(), torch.distributed.get_world_size()
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        return shards[rank * workers + worker::world * workers]

    def _item(self, sample: dict):
        meta = dict(sample["json"])
        pose, stored = meta.pop("pose"), meta.pop("images")
        meta.setdefault("frame", -1)
        meta["seed"] = str(meta["seed"])  # a uint64: torch's collation takes int64 at most
        kinds = self.kinds if self.kinds is not None else (stored[0] if len(stored) == 1 else stored)
        images = _tensor(sample[kinds]) if isinstance(kinds, str) else {k: _tensor(sample[k]) for k in kinds}
        item = (images, torch.tensor(pose, dtype=torch.float64), meta)
        return self.transform(*item) if self.transform is not None else item

    def __iter__(self):
        samples = (s for path in self._my_shards() for s in read_shard(path, self._samples.get(path)))
        if self.shuffle and self.buffer > 1:
            samples = _shuffled(samples, self.buffer, random.Random(self.seed * 1_000_003 + self.epoch + 1))
        for sample in samples:
            yield self._item(sample)


def _shuffled(items: Iterator, size: int, rng: random.Random) -> Iterator:
    """``items`` through a shuffle buffer of ``size``: each output is a random one of the buffer."""
    buffer = []
    for item in items:
        if len(buffer) < size:
            buffer.append(item)
            continue
        k = rng.randrange(size)
        buffer[k], item = item, buffer[k]
        yield item
    rng.shuffle(buffer)
    yield from buffer
