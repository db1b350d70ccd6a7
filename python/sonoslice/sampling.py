"""Pose samplers (C++: sampling/; docs/datasets.md §2): probe poses as a pure function of a seed,
on the skin, on a mesh, inside a region, or sweeps, with rejection on the fan's content. The
settings are the library's :class:`SamplerSettings`, read from keywords or a dict by the same
parser as a dataset SPEC's sampler entries."""
from __future__ import annotations

from typing import Optional

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .slicing import Probe
from .surfaces import Mesh
from .volume import Volume

__all__ = ["PoseSampler", "SamplerSettings", "sample_seeds"]

SamplerSettings = _ext.SamplerSettings


def sample_seeds(base_seed: int, stream: int, first: int, count: int) -> np.ndarray:
    """The seeds of samples ``first .. first + count - 1`` of ``stream`` (a dataset's sampler
    index) under ``base_seed``: (count,) uint64, each computed on its own (counter-based), so a
    shard knows its samples' seeds without drawing the others."""
    for name, v in (("base_seed", base_seed), ("stream", stream), ("first", first), ("count", count)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or not 0 <= v < 2**64:
            raise ValueError(f"{name}: expected an integer from 0 to 2**64 - 1, got {v!r}")
    return _ext.sample_seeds(int(base_seed), int(stream), int(first), int(count))


class PoseSampler:
    """Probe poses as a pure function of a seed (docs/datasets.md §2): on the skin of a CT
    (``{"type": "skin"}``), on a mesh (``"mesh"``), inside a label or intensity range
    (``"region"``), or sweeps (``"sweep"``), with rejection on the fan's content (``"reject"``).
    ``config``: the sampler's settings, a :class:`SamplerSettings` or a dict of its keys (the
    SPEC's sampler entry without its dataset keys); unknown keys, keys of another sampler type and
    bad values raise ValueError naming them. ``volume``: the CT (HU); ``labels``: a label volume;
    ``mesh``: a :class:`Mesh`."""

    def __init__(self, config, probe: Probe, volume: Optional[Volume] = None,
                 labels: Optional[Volume] = None, mesh=None):
        if isinstance(config, dict):
            settings, self.config = SamplerSettings.from_dict(config), dict(config)
        elif isinstance(config, SamplerSettings):
            settings, self.config = config, None
        else:
            raise TypeError("config: expected a dict of sampler settings or a sonoslice.SamplerSettings")
        if not isinstance(probe, Probe):
            raise TypeError("probe: expected a sonoslice.Probe")
        for name, v in (("volume", volume), ("labels", labels)):
            if v is not None and not isinstance(v, Volume):
                raise TypeError(f"{name}: expected a sonoslice.Volume or None")
        if mesh is not None and not isinstance(mesh, Mesh):
            raise TypeError("mesh: expected a sonoslice.Mesh or None")
        self.settings, self.probe = settings, probe
        self._cpp = _ext.PoseSampler(settings, probe._cpp, volume=None if volume is None else volume._cpp,
                                     labels=None if labels is None else labels._cpp,
                                     mesh=None if mesh is None else mesh._cpp)

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
        if a.size and np.issubdtype(a.dtype, np.signedinteger) and a.min() < 0:
            # astype would wrap -1 to 2**64 - 1: another seed than the one given.
            raise ValueError(f"seeds: {a.min()} is negative; seeds are whole numbers from 0 to {2**64 - 1}")
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
        return self._cpp.accepts(_arrays.matrices(pose, "pose", count=1, single=True))

    def surface(self) -> np.ndarray:
        """Skin sampler: (P, 2, 3) points (mm) and outward unit normals of the body surface."""
        return self._cpp.surface()

    def __repr__(self) -> str:
        return f"PoseSampler({self.settings.type!r}, {self.poses_per_seed} pose(s) per seed)"
