"""sonoslice: fast ultrasound-shaped images from 3D medical volumes, on CPU threads or CUDA.

Conventions (docs/conventions.md):

* World frame: the physical space of the volume as ITK defines it (LPS: x towards the patient's
  left, y posterior, z superior), millimetres. ``world="RAS"`` accepts poses from 3D Slicer or
  nibabel.
* A pose is a 4×4 matrix mapping probe millimetres to world millimetres: column 0 the lateral
  axis (image columns), column 1 the axial/depth axis (image rows), column 3 the probe origin.
* Pixel ``(u, v)`` (column, row) of an image sits at probe ``(x0 + u·sx, y0 + v·sy, 0)``.
* Arrays are C-order: a volume is ``(nz, ny, nx)``, a batch of images ``(N, H, W)``.

Importing this package never touches a GPU; a slicer on ``"cuda"`` starts it.

This file only gathers the public names. Each capability has its module, as the C++ library has
its folder (src/<area>/):

* :mod:`sonoslice.volume` (Volume), :mod:`sonoslice.slicing` (Probe, Slicer),
  :mod:`sonoslice.files` (pose files, image stacks), :mod:`sonoslice.devices` (devices, threads);
* :mod:`sonoslice.surfaces` (meshes, voxelize, exact label images), :mod:`sonoslice.phantom`;
* :mod:`sonoslice.compounding` (freehand 3D reconstruction, docs/conventions.md §7) and
  :mod:`sonoslice.plus` (PLUS toolkit files, ``reconstruct_plus``);
* :mod:`sonoslice.live` (live compounding and the OpenIGTLink servers, docs/live.md);
* :mod:`sonoslice.simulation` (ultrasound simulation, docs/simulation.md),
  :mod:`sonoslice.registration` (docs/registration.md), :mod:`sonoslice.sampling` (pose samplers);
* :mod:`sonoslice.datasets` (``writer``: SPEC → shards; ``reader``: shards → PyTorch;
  docs/datasets.md), :mod:`sonoslice.torch` (differentiable slicing),
  :mod:`sonoslice.fanslicer` (fan-slicer's classes);
* :mod:`sonoslice._arrays`: the checks of arrays and 4×4 pose stacks every module uses.

``sonoslice.compound``, ``sonoslice.data`` and ``sonoslice.dataset`` are the earlier names of
compounding + plus, datasets.reader and datasets.writer, still importable.
"""
from __future__ import annotations

from . import _sonoslice as _ext  # the extension, as sonoslice._ext (tests, benchmarks)
from ._version import __version__
from .compounding import (BeamGeometry, Compounder, FrameClip, Grid, HoleFillingElement, clip_mask, grid_around,
                          grid_around_beams)
from .devices import cuda_available, devices, set_threads, threads
from .files import read_poses, read_stack, validate_poses, write_poses, write_stack
from .live import LiveCompounder, LiveCompoundServer
from .phantom import PHANTOM_LABELS, phantom, phantom_poses, surface_poses
from .plus import (PlusConfig, PlusSequence, TransformRepository, plus_image_to_reference, read_plus_config,
                   read_plus_sequence, reconstruct_plus, write_plus_sequence)
from .registration import (RegistrationMetric, RegistrationMode, RegistrationOptimizer, RegistrationSettings,
                           register, register_sequence, registration_cost)
from .sampling import PoseSampler, SamplerSettings, sample_seeds
from .simulation import (SimulationOutput, SimulationSettings, SimulationSource, Simulator, Tissue, default_tissues,
                         phantom_tissues, simulation_presets)
from .slicing import Probe, Slicer, _current_stream  # _current_stream: tested through the package
from .surfaces import Mesh, SurfaceSlicer, colorize, cut_polygons, fanslicer_models, voxelize
from .volume import Volume

__all__ = [
    "Volume", "Probe", "Slicer", "devices", "cuda_available", "set_threads", "threads",
    "read_poses", "write_poses", "validate_poses", "read_stack", "write_stack", "phantom", "phantom_poses",
    "surface_poses", "PHANTOM_LABELS", "Mesh", "voxelize", "SurfaceSlicer", "colorize", "cut_polygons",
    "fanslicer_models", "__version__",
    # freehand reconstruction (sonoslice.compounding) and PLUS files (sonoslice.plus)
    "Grid", "Compounder", "BeamGeometry", "HoleFillingElement", "FrameClip", "grid_around", "grid_around_beams",
    "clip_mask", "PlusSequence", "PlusConfig", "TransformRepository", "read_plus_sequence", "write_plus_sequence",
    "read_plus_config", "plus_image_to_reference", "reconstruct_plus",
    # ultrasound simulation (docs/simulation.md)
    "Simulator", "SimulationSettings", "SimulationSource", "SimulationOutput", "Tissue", "default_tissues",
    "phantom_tissues", "simulation_presets",
    # registration (docs/registration.md)
    "register", "register_sequence", "registration_cost", "RegistrationSettings", "RegistrationMetric", "RegistrationOptimizer",
    "RegistrationMode",
    # pose samplers and datasets (docs/datasets.md)
    "PoseSampler", "SamplerSettings", "sample_seeds",
    # live compounding (docs/live.md; sonoslice.live also has plus_frames and serve)
    "LiveCompounder", "LiveCompoundServer",
]
