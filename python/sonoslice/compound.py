"""The earlier home of freehand reconstruction and PLUS files, kept importable: they are in
:mod:`sonoslice.compounding` and :mod:`sonoslice.plus`."""
from .compounding import (BeamGeometry, Compounder, FrameClip, Grid, HoleFillingElement, clip_mask, grid_around,
                          grid_around_beams)
from .plus import (PlusConfig, PlusSequence, TransformRepository, plus_image_to_reference, read_plus_config,
                   read_plus_sequence, reconstruct_plus, write_plus_sequence)

__all__ = [
    "Grid", "Compounder", "BeamGeometry", "HoleFillingElement", "FrameClip", "grid_around", "grid_around_beams",
    "clip_mask", "PlusSequence", "PlusConfig", "TransformRepository", "read_plus_sequence", "write_plus_sequence",
    "read_plus_config", "plus_image_to_reference", "reconstruct_plus",
]
