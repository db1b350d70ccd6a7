"""Compute devices and CPU threads (C++: backend/): what this machine offers, and how many threads
slicing, compounding, simulation and registration use."""
from __future__ import annotations

import warnings
from typing import Optional

import numpy as np

from . import _arrays
from . import _sonoslice as _ext

__all__ = ["devices", "cuda_available", "set_threads", "threads"]


def devices() -> str:
    """One line per compute device (CPU threads and kernels; CUDA GPUs or why there are none)."""
    return _ext.describe_devices()


def cuda_available(device: str = "cuda:0") -> bool:
    """True when this build has CUDA and ``device`` is a usable GPU (starts the CUDA runtime)."""
    try:
        _ext.require_device(_arrays.device(device))
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
    _ext.set_cpu_threads(_arrays.whole(n, "set_threads: n"))


def threads() -> int:
    return _ext.cpu_threads()
