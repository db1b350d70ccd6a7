"""Surfaces (C++: surface/): triangle meshes, voxelising them into label volumes, exact label images
of their cross-sections, colouring labels, and fan-slicer's surface configurations."""
from __future__ import annotations

from typing import List, Optional, Sequence

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .slicing import Probe, _ImageSlicer, _out_array, _progress_and_chunk
from .volume import Volume

__all__ = ["Mesh", "voxelize", "SurfaceSlicer", "colorize", "cut_polygons", "fanslicer_models"]


class Mesh:
    """A triangle mesh in world millimetres (same frame as volumes). ``Mesh.from_file`` reads
    .vtk (legacy ASCII/binary POLYDATA), .vtp, .stl, .obj and .ply through VTK (polygons
    triangulated, coincident points merged); ``Mesh(vertices (V, 3), triangles (T, 3))`` builds one."""

    def __init__(self, vertices, triangles, name: str = "mesh"):
        vertices = np.ascontiguousarray(_arrays.real_array(_arrays.numpy_of(vertices), "vertices"))
        triangles = np.ascontiguousarray(_arrays.no_complex(np.asarray(_arrays.numpy_of(triangles)), "triangles"), dtype=np.int32)
        if vertices.ndim != 2 or vertices.shape[1:] != (3,):
            raise ValueError(f"vertices: expected (V, 3) points, got shape {vertices.shape}")
        self._cpp = _ext.Mesh.from_arrays(vertices, triangles, _arrays.text(name, "name"))

    @classmethod
    def _wrap(cls, cpp) -> "Mesh":
        m = cls.__new__(cls)
        m._cpp = cpp
        return m

    @classmethod
    def from_file(cls, path, world: str = "LPS") -> "Mesh":
        return cls._wrap(_ext.Mesh.from_file(_arrays.path(path), world))

    def save(self, path) -> None:
        self._cpp.save(_arrays.path(path))

    name = property(lambda self: self._cpp.name)
    vertices = property(lambda self: self._cpp.vertices(), doc="(V, 3) float64 mm (a copy)")
    triangles = property(lambda self: self._cpp.triangles(), doc="(T, 3) int32 vertex indices (a copy)")

    @property
    def bounds(self) -> np.ndarray:
        """[[xmin, ymin, zmin], [xmax, ymax, zmax]] (mm)."""
        return np.array(self._cpp.bounds())

    @property
    def closed(self) -> bool:
        """Every edge shared by exactly two triangles."""
        return self._cpp.closed()

    def __repr__(self) -> str:
        return f"Mesh({self.name!r}, {len(self.triangles)} triangles, {self._cpp.topology()})"


def voxelize(meshes, spacing: Optional[float] = None, margin: Optional[float] = None,
             reference: Optional[Volume] = None, labels: Optional[Sequence[int]] = None) -> Volume:
    """Meshes → one label volume: label k+1 (or ``labels[k]``) for the k-th mesh, later meshes
    winning where they overlap; uint8, or uint16 past 255. The grid is ``reference``'s, or an
    isotropic ``spacing`` (mm) around the meshes plus ``margin`` (default one voxel). Voxel centres
    are inside when the mesh contains them (docs/conventions.md §1); open meshes warn and are voted best-effort."""
    meshes = _mesh_list(meshes, "meshes")
    if reference is None and spacing is None:
        raise ValueError("voxelize: give spacing (mm) or a reference volume")
    if reference is not None and (spacing is not None or margin is not None):
        raise ValueError("voxelize: the reference volume sets the grid; spacing and margin do not apply")
    spacing = 0.0 if spacing is None else _arrays.number(spacing, "spacing")
    margin = spacing if margin is None else _arrays.number(margin, "margin")
    return Volume._wrap(_ext.voxelize([m._cpp for m in meshes], spacing, margin,
                                      None if reference is None else reference._cpp,
                                      [] if labels is None else _arrays.wholes(labels, "labels")))


def _mesh_list(meshes, what: str) -> List["Mesh"]:
    """A Mesh or a sequence of them, as a list; TypeError naming ``what`` otherwise."""
    if isinstance(meshes, Mesh):
        return [meshes]
    try:
        out = list(meshes)
    except TypeError:
        raise TypeError(f"{what}: expected a Mesh or a list of Mesh, got {type(meshes).__name__}") from None
    for m in out:
        if not isinstance(m, Mesh):
            raise TypeError(f"{what}: expected a Mesh or a list of Mesh, got a list holding {type(m).__name__}")
    return out


class SurfaceSlicer(_ImageSlicer):
    """Exact label images: each image plane cuts the meshes' triangles and the cross-sections are
    filled (even-odd), with no voxelisation: exact at any pixel size. Mesh k paints label k+1 (or
    ``labels[k]``), later meshes over earlier ones; outside the probe shape 0. CPU threads."""

    def __init__(self, meshes, probe: Probe, labels: Optional[Sequence[int]] = None, dtype: str = "uint8"):
        meshes = _mesh_list(meshes, "meshes")
        self.meshes, self.probe = meshes, probe
        self._cpp = _ext.SurfaceSlicer([m._cpp for m in meshes], probe._cpp,
                                       [] if labels is None else _arrays.wholes(labels, "labels"),
                                       _arrays.dtype_name(dtype, "dtype"))

    def slice(self, poses, out=None, *, progress=None, world: str = "LPS", chunk: Optional[int] = None):
        """(N, H, W) label images for (N, 4, 4) poses (NumPy or torch); ``out`` as in Slicer.slice
        (host memory)."""
        p = _arrays.pose_array(poses, world)
        n = p.shape[0]
        out = _out_array(out)
        if out is None:
            out = np.empty((n, self.height, self.width), dtype=self.dtype)
        callback, chunk = _progress_and_chunk(progress, n, chunk)
        self._cpp.slice_into(p, out, callback, chunk)
        return out

    __call__ = slice


def colorize(labels, mask, colors: Optional[Sequence[Sequence[int]]] = None) -> np.ndarray:
    """(N, H, W) labels → (N, H, W, 3) uint8 RGB, fan-slicer style: label k in ``colors[k-1]``
    (default palette otherwise), 0 black, outside the (H, W) probe mask grey 210."""
    labels = np.ascontiguousarray(_arrays.native(np.asarray(_arrays.numpy_of(labels)), "labels"))
    if colors is None:
        top = int(labels.max()) if labels.size else 0
        colors = [_ext.default_label_color(k) for k in range(1, max(top, 1) + 1)]
    if isinstance(colors, (str, bytes)) or np.ndim(colors) != 2 or np.shape(colors)[1] != 3:
        raise ValueError(f"colors: expected (r, g, b) triples, got {colors!r:.60}")
    if mask is None:
        raise TypeError("colorize: mask: expected the (H, W) probe mask (Probe.mask), got None")
    return _ext.colorize(labels, _arrays.mask_array(mask, "mask"), [tuple(_arrays.wholes(c, "colors")) for c in colors])


def cut_polygons(mesh: Mesh, pose) -> list:
    """The cut of ``mesh`` by the image plane of ``pose``: a list of (K, 2) arrays of probe (x, y)
    mm, one per closed loop (open meshes may give open chains)."""
    return [np.array(points) for points, _closed in _ext.cut_polygons(mesh._cpp, _arrays.pose_array(pose))]


def fanslicer_models(config, mesh_dir) -> list:
    """The enabled models of a fan-slicer surface config: dicts of name, path (mesh_dir/<name>.vtk),
    label (k-th enabled = k) and color."""
    models = _ext.fanslicer_models(_arrays.path(config, "config"), _arrays.path(mesh_dir, "mesh_dir"))
    return [dict(name=n, path=p, label=l, color=tuple(c)) for n, p, l, c in models]
