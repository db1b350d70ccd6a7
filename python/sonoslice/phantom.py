"""The built-in phantom (C++: phantom/): a deterministic CT-like abdomen with its labels, and the
poses the benchmarks use."""
from __future__ import annotations

from typing import Tuple

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .volume import Volume

__all__ = ["PHANTOM_LABELS", "phantom", "phantom_poses", "surface_poses"]

PHANTOM_LABELS = tuple(_ext.phantom_label_names())


def phantom(size: str = "small") -> Tuple[Volume, Volume]:
    """The deterministic CT-like abdominal phantom: (CT in HU as int16, labels as uint8; see
    PHANTOM_LABELS). "small": 128×128×100 at 3.2×3.2×4 mm; "full": 512×512×400 at 0.8×0.8×1 mm."""
    ct, labels = _ext.make_phantom(_arrays.text(size, "size"))
    return Volume._wrap(ct), Volume._wrap(labels)


def phantom_poses(count: int, seed: int = 2024) -> np.ndarray:
    """(count, 4, 4) random poses inside the phantom's body (the benchmarks' poses)."""
    return _ext.phantom_random_poses(_arrays.count(count, "count"), _arrays.seed(seed))


def surface_poses(count: int, face_y_mm: float = 0.0) -> np.ndarray:
    """(count, 4, 4) poses with the probe face on the phantom's skin, aimed at the liver."""
    return _ext.phantom_surface_poses(_arrays.count(count, "count"), _arrays.number(face_y_mm, "face_y_mm"))
