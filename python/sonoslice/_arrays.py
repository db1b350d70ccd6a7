"""The checks and conversions every capability's arguments go through: arrays (NumPy, torch,
lists), 4×4 matrix stacks (poses, image→reference transforms), paths, numbers, whole numbers,
seeds, strings and choices.
One place, so that a pose is checked the same way by the slicer, the compounder, registration,
the samplers and ``sonoslice.torch``.
"""
from __future__ import annotations

import numbers
import os
from typing import Optional, Tuple

import numpy as np


def is_torch(x) -> bool:
    return type(x).__module__.startswith("torch")


def numpy_of(x):
    """A torch tensor as a NumPy array in host memory; anything else as it is."""
    return x.detach().cpu().numpy() if is_torch(x) else x


def path(value, what: str = "path") -> str:
    """A file path (str, bytes or os.PathLike) as str; TypeError naming ``what`` for anything else
    (``str(None)`` would look for a file called 'None')."""
    if isinstance(value, (str, bytes, os.PathLike)):
        return os.fsdecode(os.fspath(value))
    raise TypeError(f"{what}: expected a file path (str or os.PathLike), got {type(value).__name__}")


def no_complex(a: np.ndarray, what: str) -> np.ndarray:
    """``a``, or ValueError naming ``what`` when it is complex (a cast would drop the imaginary part)."""
    if a.dtype.kind == "c":
        raise ValueError(f"{what}: dtype {a.dtype.name} is complex; sonoslice takes real numbers and does "
                         "not drop imaginary parts silently (pass .real if that is what you mean)")
    return a


def native(a, what: str, *, in_place: bool = False):
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


def real_array(x, what: str) -> np.ndarray:
    """Numbers (array-like, not torch) as float64; complex and what is not numbers (text, None)
    refused naming ``what``."""
    try:
        a = np.asarray(x)
    except ValueError:  # NumPy's "inhomogeneous shape"
        raise ValueError(f"{what}: expected numbers in a regular (rectangular) shape, got {x!r:.60}") from None
    numbers = a.dtype.kind in "biufc"
    if a.dtype.kind == "O" and not any(v is None for v in a.flat):
        try:  # numbers held as Python objects (a pandas column) convert; None and text do not
            a, numbers = a.astype(np.float64), True
        except (TypeError, ValueError):
            pass
    if not numbers:
        raise TypeError(f"{what}: expected numbers, got {type(x).__name__} {x!r:.60}")
    return np.asarray(no_complex(a, what), dtype=np.float64)


def floats(x, what: str, count: int) -> Tuple[float, ...]:
    """Exactly ``count`` real numbers as floats; ValueError naming ``what`` otherwise."""
    a = real_array(x, what).ravel()
    if a.size != count:
        raise ValueError(f"{what}: expected {count} numbers, got {a.size}")
    return tuple(float(v) for v in a)


def _scalar(value):
    """A 0-d NumPy array or torch tensor as its Python number; anything else unchanged."""
    if (isinstance(value, np.ndarray) or is_torch(value)) and getattr(value, "ndim", None) == 0:
        return value.item()
    return value


def whole(value, what: str, limit: int = 2**31 - 1) -> int:
    """An integer argument; ValueError naming ``what`` for 2.5 (int() would make it 2) or beyond
    ±``limit`` (the C++ parameter's range: nanobind would refuse it with a generic message),
    TypeError for what is not a number. The library checks the meaningful range."""
    value = _scalar(value)
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{what}: expected an integer, got {value!r}")
    if isinstance(value, (float, np.floating)) and not float(value).is_integer():
        raise ValueError(f"{what} {value!r}: expected a whole number")
    if not isinstance(value, (int, np.integer, float, np.floating)):
        raise TypeError(f"{what}: expected an integer, got {type(value).__name__}")
    n = int(value)  # a float here is whole (and finite: inf and NaN are not is_integer())
    if not -limit - 1 <= n <= limit:
        raise ValueError(f"{what} {n}: out of range")
    return n


def count(value, what: str) -> int:
    """A whole number ≥ 0 (a count, an index); errors name ``what`` (a negative one would meet
    nanobind's generic "incompatible function arguments")."""
    n = whole(value, what, limit=2**63 - 1)
    if n < 0:
        raise ValueError(f"{what} {n}: must be at least 0")
    return n


def seed(value, what: str = "seed") -> int:
    """A seed: a whole number from 0 to 2⁶⁴ − 1 (the library's seeds are unsigned 64-bit)."""
    n = whole(value, what, limit=2**64)
    if not 0 <= n < 2**64:
        raise ValueError(f"{what} {n}: expected a whole number from 0 to {2**64 - 1}")
    return n


def wholes(values, what: str) -> list:
    """A sequence of whole numbers (labels, colours) as a list of ints; errors name ``what``."""
    if isinstance(values, (str, bytes)) or np.ndim(values) != 1:
        raise TypeError(f"{what}: expected a sequence of integers, got {type(values).__name__} {values!r:.60}")
    return [whole(v, what) for v in values]


def number(value, what: str) -> float:
    """One real number as float (NaN passes: the library says what it must be); TypeError naming
    ``what`` for text, None, a sequence or a bool."""
    value = _scalar(value)
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{what}: expected a number, got {value!r}")
    if isinstance(value, numbers.Real):  # int, float, NumPy's, Fraction
        return float(value)
    raise TypeError(f"{what}: expected a number, got {type(value).__name__} {value!r:.60}")


def spacing(value, what: str, n: int) -> Tuple[float, ...]:
    """A spacing given as one number for every axis or as ``n`` numbers."""
    if np.ndim(value) == 0 and not isinstance(value, str):
        return (number(value, what),) * n
    return floats(value, what, n)


def text(value, what: str) -> str:
    """A string argument (a name, a choice); TypeError naming ``what`` otherwise (``str(None)``
    would become the choice 'None')."""
    if isinstance(value, str):
        return value
    raise TypeError(f"{what}: expected a string, got {type(value).__name__} {value!r:.60}")


def device(value, what: str = "device") -> str:
    """A device name ("cpu", "cuda", "cuda:K"), also as a torch.device; TypeError naming ``what``
    for anything else. The library checks the name."""
    return str(value) if is_torch(value) else text(value, what)


def dtype_name(value, what: str) -> str:
    """NumPy's name of a dtype given as a name ("float32"), a NumPy type or a dtype; errors name
    ``what`` (``np.dtype(None)`` would be float64)."""
    if value is None or isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{what}: expected a dtype (a name such as 'float32'), got {value!r}")
    try:
        return np.dtype(value).name
    except TypeError:
        raise ValueError(f"{what} {value!r:.60}: not a dtype") from None


def choice(kind, value, what: str):
    """A member of the bound enum ``kind``, given as itself or as the library spells it (its str:
    "ncc", "nelder-mead"; or its member name, nelder_mead); ValueError naming ``what`` and the
    choices otherwise."""
    if isinstance(value, kind):
        return value
    for member in kind:
        if isinstance(value, str) and value in (str(member), member.name):
            return member
    names = [repr(str(m)) for m in kind]
    raise ValueError(f"{what} {value!r}: expected {', '.join(names[:-1])} or {names[-1]}")


# ---- 4×4 matrices: poses (probe → world) and transforms ------------------------------------------
def matrix_stack(m, what: str = "poses", count: Optional[int] = None, single: bool = False):
    """``m`` (a NumPy array or a torch tensor, not converted, so autograd keeps a tensor) as a stack
    of 4×4 matrices: (N, 4, 4) as it is, (4, 4) as a stack of one. ValueError naming ``what`` for
    another shape, or for another N than ``count`` (``single``: the count is one frame's)."""
    shape = tuple(m.shape)
    if shape == (4, 4):
        m = m[None]
    elif len(shape) != 3 or shape[1:] != (4, 4):
        raise ValueError(f"{what} has shape {shape}; expected (4, 4) or (N, 4, 4) (the expected shape of one "
                         "4x4 matrix or of a stack)")
    if count is not None and m.shape[0] != count:
        frames = "1 frame" if single else f"{count} frames"
        raise ValueError(f"{what} has shape {shape} for {frames}; expected "
                         f"{'(4, 4)' if count == 1 else f'({count}, 4, 4)'}")
    return m


def matrices(m, what: str = "poses", count: Optional[int] = None, single: bool = False) -> np.ndarray:
    """4×4 matrices (NumPy, torch or nested lists of real numbers) as an (N, 4, 4) float64
    C-contiguous array (checked by :func:`matrix_stack`); complex or non-numbers refused naming
    ``what``."""
    m = numpy_of(m)
    if np.iscomplexobj(m):  # said as such, not as "expected 4x4 matrices of numbers" below
        no_complex(np.asarray(m), what)
    try:
        a = real_array(m, what)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected 4x4 matrices of numbers") from None
    return np.ascontiguousarray(matrix_stack(a, what, count, single))


def pose_array(poses, world: str = "LPS") -> np.ndarray:
    """Probe→world poses ((N, 4, 4) or (4, 4), NumPy or torch) as (N, 4, 4) float64 C-contiguous
    matrices in LPS; ``world="RAS"`` converts poses from 3D Slicer or nibabel."""
    a = matrices(poses, "poses")
    return np.ascontiguousarray(pose_to_lps(a, world))


def pose_to_lps(poses: np.ndarray, world: str) -> np.ndarray:
    """(N, 4, 4) poses in ``world`` ("LPS" or "RAS") → LPS; the flip is its own inverse, so this
    also takes LPS poses back to ``world``."""
    world = str(world).upper()
    if world == "RAS":
        return poses * np.array([-1.0, -1.0, 1.0, 1.0])[None, :, None]  # diag(-1, -1, 1, 1) · T
    if world != "LPS":
        raise ValueError(f"world frame {world!r}: expected 'LPS' or 'RAS'")
    return poses


def mask_array(mask, what: str) -> Optional[np.ndarray]:
    """An (H, W) mask as C-contiguous uint8, 1 where ``mask`` is non-zero (None stays None); complex
    refused, and NaN, which is neither zero nor a choice."""
    if mask is None:
        return None
    m = no_complex(np.asarray(numpy_of(mask)), what)
    if m.dtype.kind == "f" and np.isnan(m).any():
        raise ValueError(f"{what}: {int(np.isnan(m).sum())} NaN pixels (a mask is zero where pixels are "
                         "left out, non-zero where they are used)")
    return np.ascontiguousarray(m != 0, dtype=np.uint8)
