"""Ultrasound simulation (C++: simulate/; docs/simulation.md): B-mode-like images of a CT in
Hounsfield units or of a label volume with a tissue table, at probe poses. The settings, their
defaults (the frequency: the preset's, else 5 MHz) and their checks are the library's
(:class:`SimulationSettings`); :class:`Simulator` passes on what its caller gave."""
from __future__ import annotations

import os
from typing import Callable, Optional, Union

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .slicing import Probe, _out_array, _progress_and_chunk
from .volume import Volume

__all__ = ["Simulator", "SimulationSettings", "SimulationSource", "SimulationOutput", "Tissue", "default_tissues",
           "phantom_tissues", "simulation_presets"]

SimulationSettings = _ext.SimulationSettings
SimulationSource = _ext.SimulationSource
SimulationOutput = _ext.SimulationOutput
Tissue = _ext.Tissue


def default_tissues() -> list:
    """The default tissue table: a list of :class:`Tissue` (name, label, impedance_mrayl,
    attenuation_db_cm_mhz, scatter_mean, scatter_density; each reads as a dict too), as
    ``sonoslice simulate --print-tissues`` prints it."""
    return list(_ext.default_tissues())


def phantom_tissues() -> list:
    """The tissue table of the built-in phantom's labels (:data:`sonoslice.PHANTOM_LABELS`)."""
    return list(_ext.phantom_tissues())


def simulation_presets() -> dict:
    """{name: description} of the presets (a probe and a centre frequency)."""
    return dict(_ext.simulation_presets())


def _tissue_table(tissues) -> list:
    """A tissue table given as a path to its JSON, a list of :class:`Tissue` or dicts, or
    {"tissues": [...]}: read by the library's table parser (keys and values checked)."""
    if isinstance(tissues, (str, bytes, os.PathLike)):
        return _ext.read_tissue_table(_arrays.path(tissues, "tissues"))
    if isinstance(tissues, (list, tuple, dict)):
        return _ext.tissue_table(tissues)
    raise TypeError(f"tissues: expected a path, a list of Tissue or dicts, or a dict, got {type(tissues).__name__}")


class Simulator:
    """Ultrasound-looking images of a CT in Hounsfield units or a label volume at probe poses
    (docs/simulation.md): reflections at impedance changes, shadows, attenuation, speckle fixed
    in the volume, log compression. Deterministic: the same seed and pose give the same bytes.

    ``volume_or_labels``: a :class:`Volume`. ``kind``: "ct" or "labels"; by default "labels"
    when ``tissues`` is given or the volume is uint8, else "ct". ``tissues``: for labels, a
    path to a JSON table, a list of :class:`Tissue` (or dicts) as :func:`default_tissues`
    returns, or None for the default table. ``probe``: a :class:`Probe` or a preset name
    ("abdominal", "laparoscopic", "lus"; its frequency is used unless ``frequency`` is given).
    ``tgc``: "auto" or "off". Unset settings take :class:`SimulationSettings`' defaults; or give
    them all as ``settings=`` (a :class:`SimulationSettings`; not with the keywords). ``device``:
    "cpu" (default) or "cuda[:K]" (the volume and tables are uploaded once; images come back as
    NumPy arrays).
    """

    def __init__(self, volume_or_labels: Volume, probe, tissues=None, frequency: Optional[float] = None,
                 seed: Optional[int] = None, device: Optional[str] = None, *, kind: Optional[str] = None,
                 dynamic_range: Optional[float] = None, tgc: Optional[str] = None,
                 settings: Optional[SimulationSettings] = None):
        if not isinstance(volume_or_labels, Volume):
            raise TypeError("volume_or_labels: expected a sonoslice.Volume")
        a = _arrays  # checked here so that a wrong type gets an error naming it, not nanobind's generic one
        given = dict(frequency_mhz=None if frequency is None else a.number(frequency, "frequency"),
                     seed=None if seed is None else a.seed(seed),
                     dynamic_range_db=None if dynamic_range is None else a.number(dynamic_range, "dynamic_range"),
                     device=None if device is None else a.device(device))
        if tgc is not None:
            if tgc not in ("auto", "off"):
                raise ValueError(f'tgc {tgc!r}: expected "auto" or "off"')
            given["tgc_auto"] = tgc == "auto"
        given = {k: v for k, v in given.items() if v is not None}  # the library has the defaults
        self._default_output = SimulationSettings().output
        if settings is not None:  # the same rule as register(): settings= or keywords
            if given:
                raise TypeError(f"Simulator: give settings= or the keywords {sorted(given)}, not both")
            if not isinstance(settings, SimulationSettings):
                raise TypeError("settings: expected a sonoslice.SimulationSettings")
            given = {k: getattr(settings, k) for k in ("frequency_mhz", "seed", "dynamic_range_db", "tgc_auto",
                                                       "axial_fwhm_mm", "lateral_fwhm_mm", "elevation_fwhm_mm",
                                                       "device", "preset")}
            given = {k: v for k, v in given.items() if v is not None}
            self._default_output = settings.output
        if isinstance(probe, str):
            given["preset"], probe = probe, None
        elif not isinstance(probe, Probe):
            raise TypeError("probe: expected a sonoslice.Probe or a preset name")
        self._given = given
        self._inputs = dict(source=None if kind is None else _arrays.choice(SimulationSource, kind, "kind"),
                            tissues=None if tissues is None else _tissue_table(tissues))
        self.volume, self._probe, self._cpp = volume_or_labels, probe, {}  # probe None: the preset's
        engine = self._engine()
        self.probe = probe if probe is not None else Probe(engine.probe)
        self.kind = str(engine.source)

    def _engine(self, output=None):
        """The C++ simulator making ``output`` images (default: the settings' output), one
        per output, made when first asked for."""
        output = self._default_output if output is None else _arrays.choice(SimulationOutput, output, "output")
        if output not in self._cpp:
            settings = SimulationSettings(**self._given, output=output)
            probe = None if self._probe is None else self._probe._cpp
            self._cpp[output] = _ext.Simulator(self.volume._cpp, probe, settings=settings, **self._inputs)
        return self._cpp[output]

    width = property(lambda self: self._engine().width)
    height = property(lambda self: self._engine().height)
    settings = property(lambda self: self._engine().settings,
                        doc="the SimulationSettings as the library resolved them")
    frequency = property(lambda self: self.settings.frequency_mhz, doc="centre frequency, MHz")
    seed = property(lambda self: self.settings.seed)

    @property
    def mask(self) -> np.ndarray:
        """(H, W) uint8 probe mask (the same as :class:`Slicer`'s)."""
        return self._engine().mask()

    def simulate(self, poses, output: Optional[str] = None, out=None, *,
                 progress: Union[None, bool, Callable[[int, int], None]] = None, world: str = "LPS",
                 chunk: Optional[int] = None) -> np.ndarray:
        """Images at ``poses`` ((N, 4, 4) or (4, 4) probe→world, mm): (N, H, W) uint8 B-mode (the
        default ``output``, "bmode"), or float32 linear envelope for ``output="envelope"`` (before
        TGC and log compression).
        ``out``: a C-contiguous array of that shape and dtype, filled in place without a copy."""
        engine = self._engine(output)
        p = _arrays.pose_array(poses, world)
        dtype = np.uint8 if engine.settings.output == SimulationOutput.bmode else np.float32
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
