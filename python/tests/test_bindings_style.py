"""One binding style (docs/architecture: bindings forward): no bound function or method takes more
than 6 positional parameters (more are a positional bag: settings go in typed, keyword-built
classes or keyword-only arguments), and choices are enums whose str() is the library's spelling."""
import enum

import pytest

import sonoslice
from sonoslice import _sonoslice as ext

MAX_POSITIONAL = 6


def _split_top_level(text):
    """``text`` split at the commas outside brackets, quotes included."""
    parts, depth, quote, start = [], 0, None, 0
    for i, c in enumerate(text):
        if quote:
            if c == quote and text[i - 1] != "\\":
                quote = None
        elif c in "'\"":
            quote = c
        elif c in "([{":
            depth += 1
        elif c in ")]}":
            depth -= 1
        elif c == "," and depth == 0:
            parts.append(text[start:i].strip())
            start = i + 1
    if text[start:].strip():
        parts.append(text[start:].strip())
    return parts


def positional_parameters(signature):
    """The names of the parameters of a nanobind signature ("def f(self, a: int, *, b: float = 1)
    -> None") that a caller can pass by position, ``self`` left out."""
    head = signature[signature.index("(") + 1:]
    depth = 1
    for i, c in enumerate(head):
        depth += c == "("
        depth -= c == ")"
        if depth == 0:
            head = head[:i]
            break
    names = []
    for p in _split_top_level(head):
        name = p.split(":")[0].split("=")[0].strip()
        if name in ("*", "**kwargs") or name.startswith("**"):
            break
        if name.startswith("*"):  # *args: any number
            names.append(name)
            names.extend(["..."] * MAX_POSITIONAL)
            break
        if name not in ("self", "/"):
            names.append(name)
    return names


def bound_callables():
    """(qualified name, nanobind signature) of every function and method of the extension."""
    seen = []
    for name, obj in vars(ext).items():
        if hasattr(obj, "__nb_signature__"):
            seen += [(name, s[0]) for s in obj.__nb_signature__]
        elif isinstance(obj, type):
            for attr in vars(obj):
                member = getattr(obj, attr, None)
                if hasattr(member, "__nb_signature__"):
                    seen += [(f"{name}.{attr}", s[0]) for s in member.__nb_signature__]
    return seen


def test_the_signature_parser():
    assert positional_parameters("def f(self, a: int, b: tuple[float, float] = (1, 2), *, c: int = 3) -> None") \
        == ["a", "b"]
    assert positional_parameters("def f(a: Annotated[NDArray, dict(shape=(None, 4, 4), order='C')], b: str = ',')") \
        == ["a", "b"]
    assert positional_parameters("def __init__(self, **kwargs) -> None") == []
    assert len(positional_parameters("def f(*args) -> None")) > MAX_POSITIONAL


def test_no_bound_callable_takes_more_than_six_positional_parameters():
    callables = bound_callables()
    names = {name for name, _ in callables}
    # The walk reaches functions, static methods, constructors and methods.
    assert {"register_frames", "Probe.curvilinear", "Simulator.__init__", "Slicer.slice_into"} <= names
    bags = [f"{name}: {signature}" for name, signature in callables
            if len(positional_parameters(signature)) > MAX_POSITIONAL]
    assert not bags, "\n".join(bags)


@pytest.mark.parametrize("kind, spellings", [
    (sonoslice.RegistrationMetric, ["ssd", "ncc", "lncc", "mi", "lc2"]),
    (sonoslice.RegistrationOptimizer, ["gn", "lm", "bobyqa", "nelder-mead"]),
    (sonoslice.RegistrationMode, ["per-frame", "rigid-sweep", "smooth-sweep", "calibration"]),
    (sonoslice.SimulationSource, ["ct", "labels"]),
    (sonoslice.SimulationOutput, ["bmode", "envelope"]),
])
def test_choices_are_enums_spelled_as_the_library_spells_them(kind, spellings):
    assert issubclass(kind, enum.Enum)
    assert [str(m) for m in kind] == spellings
