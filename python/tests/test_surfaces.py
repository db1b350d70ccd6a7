"""Meshes, voxelisation, exact cuts, colours and the fan-slicer SegmentedVolume shim."""
import os
import subprocess

import numpy as np
import pytest

import sonoslice
from sonoslice import fanslicer


def icosphere(radius, centre=(0, 0, 0), subdivisions=3):
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        cache, faces = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = faces
    return sonoslice.Mesh(np.array(verts) * radius + np.array(centre), np.array(f), name="sphere")


def test_mesh_arrays_files_and_topology(tmp_path):
    s = icosphere(10)
    assert s.closed and s.triangles.shape == (1280, 3)
    assert np.allclose(s.bounds, [[-10, -10, -10], [10, 10, 10]], atol=1e-6)
    for ext in (".stl", ".vtk", ".ply"):
        s.save(tmp_path / ("s" + ext))
        back = sonoslice.Mesh.from_file(tmp_path / ("s" + ext))
        assert back.closed and len(back.triangles) == 1280
    ras = sonoslice.Mesh.from_file(tmp_path / "s.vtk", world="RAS")
    assert np.allclose(ras.vertices[:, :2], -back.vertices[:, :2])
    with pytest.raises(OSError, match="no such file"):
        sonoslice.Mesh.from_file(tmp_path / "missing.vtk")
    with pytest.raises(ValueError, match="uses vertex"):
        sonoslice.Mesh([[0, 0, 0]], [[0, 1, 2]])


def test_voxelize_and_exact_cut_agree_on_a_sphere():
    s = icosphere(15, subdivisions=4)
    labels = sonoslice.voxelize(s, spacing=0.25)
    assert labels.dtype == np.uint8
    volume = (labels.array == 1).sum() * 0.25 ** 3
    assert volume == pytest.approx(4 / 3 * np.pi * 15 ** 3, rel=0.02)
    probe = sonoslice.Probe.linear(160, 160, 0.25, origin_mm=(-19.875, -19.875))
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 2, 3] = [0.0, 5.0, 10.0]  # planes z = 0, 5, 10
    exact = sonoslice.SurfaceSlicer(s, probe).slice(poses)
    voxel = sonoslice.Slicer(labels, probe, interpolation="nearest", dtype="uint8").slice(poses)
    both = ((exact == 1) & (voxel == 1)).sum()
    assert 2 * both / ((exact == 1).sum() + (voxel == 1).sum()) > 0.98
    for n, z in enumerate([0.0, 5.0, 10.0]):
        disc = np.pi * (15 ** 2 - z ** 2)
        assert (exact[n] == 1).sum() * 0.0625 == pytest.approx(disc, rel=0.03)
        loops = sonoslice.cut_polygons(s, poses[n])
        assert len(loops) == 1
        x, y = loops[0][:, 0], loops[0][:, 1]
        area = 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
        assert area == pytest.approx(disc, rel=0.03)


def test_overlaps_labels_and_colours():
    a, b = icosphere(10), icosphere(5, centre=(8, 0, 0))
    v = sonoslice.voxelize([a, b], spacing=0.5, labels=[3, 7])
    assert set(np.unique(v.array)) == {0, 3, 7}
    probe = sonoslice.Probe.curvilinear(10, 30, 60, 100, 100, 0.4)
    pose = np.eye(4)
    pose[1, 3] = -20  # the fan reaches from y = -20 through both spheres
    lab = sonoslice.SurfaceSlicer([a, b], probe, labels=[3, 7]).slice(pose)
    rgb = sonoslice.colorize(lab, probe.mask, colors=[(0, 0, 0), (0, 0, 0), (10, 20, 30), (0, 0, 0), (0, 0, 0),
                                                      (0, 0, 0), (200, 100, 50)])
    assert rgb.shape == (1, 100, 100, 3) and rgb.dtype == np.uint8
    assert (rgb[0][probe.mask == 0] == 210).all()
    assert (rgb[0][lab[0] == 7] == (200, 100, 50)).all()
    assert (rgb[0][lab[0] == 3] == (10, 20, 30)).all()
    assert (lab[0] == 7).any() and (lab[0] == 3).any()


def test_segmented_volume_shim_shapes_modes_and_cli(shared, cli, tmp_path):
    cfg = os.path.join(shared, "models_binary_LUS_config.json")
    pose = np.array([[-0.46, 0.29, -0.84, -41.77], [0.28, 0.94, 0.18, -47.72], [0.84, -0.15, -0.52, -253.44],
                     [0, 0, 0, 1]])
    q, _ = np.linalg.qr(pose[:3, :3])  # an orthonormal version of fan-slicer's demo pose
    pose[:3, :3] = q * np.sign(np.diag(q))
    poses = np.tile(pose, (1, 4))
    poses[2, 3:16:4] -= np.arange(0, 8, 2)
    voxel = fanslicer.SegmentedVolume(shared, cfg, image_num=4, downsampling=2, voxel_size=0.5, device="cpu")
    exact = fanslicer.SegmentedVolume(shared, cfg, image_num=4, downsampling=2, mode="exact")
    pts, lab, vis = voxel.simulate_image(poses, 4)
    _, lab_exact, _ = exact.simulate_image(poses, 4)
    assert lab.shape == (272, 334, 4) and lab.dtype == np.float64
    assert vis.shape == (272, 334, 3, 4) and vis.dtype == np.float64 and vis.max() <= 1.0
    assert set(np.unique(lab)) <= {0.0, 1.0, 2.0, 3.0} and (lab == 1).any()
    mask = voxel.slicer.mask.astype(bool)
    assert np.allclose(vis[~mask], 210 / 255)           # fan-slicer's grey outline
    assert np.allclose(vis.transpose(0, 1, 3, 2)[lab == 1], np.array([0, 200, 0]) / 255)  # hepatic veins
    agree = ((lab == 1) & (lab_exact == 1)).sum() / max((lab == 1).sum(), 1)
    assert agree > 0.85
    # Same inputs through the CLI (voxel mode, 0.5 mm): identical labels.
    strip = np.concatenate([poses[:, 4 * i:4 * i + 4][None] for i in range(4)])
    np.save(tmp_path / "poses.npy", strip)
    subprocess.run([cli, "slice", "--mesh-dir", shared, "--probe", cfg, "--downsampling", "2", "--poses",
                    str(tmp_path / "poses.npy"), "--voxel-size", "0.5", "--out", str(tmp_path / "cli.npy"), "-q"],
                   check=True)
    assert np.array_equal(np.load(tmp_path / "cli.npy").transpose(1, 2, 0), lab.astype(np.uint8))
