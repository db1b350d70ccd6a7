"""Freehand reconstruction from Python (docs/conventions.md §7): known answers, axis conventions, incremental vs
batch, the slicer round trip, beam-space frames against a NumPy oracle, PLUS files and the real
NWire sweep against PLUS's own reconstruction, and bad input."""
import gc
import math
import os
import subprocess
import threading

import numpy as np
import pytest

import sonoslice
from conftest import DATA

PLUS = os.path.join(DATA, "plus")
NWIRE_MHA = os.path.join(PLUS, "NwirePhantomFreehand.igs.mha")
NWIRE_NRRD = os.path.join(PLUS, "NwirePhantomFreehand.igs.nrrd")
NWIRE_XML = os.path.join(PLUS, "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml")
NWIRE_REFERENCE = os.path.join(PLUS, "NwirePhantomFreehandReconstructed.mha")


@pytest.fixture(scope="module")
def plus_data():
    assert os.path.isfile(NWIRE_MHA), f"{NWIRE_MHA} is missing (see data/README.md)"
    return PLUS


@pytest.fixture(scope="module")
def nwire(plus_data):
    return sonoslice.read_plus_sequence(NWIRE_MHA)


@pytest.fixture(scope="module")
def nwire_config(plus_data):
    try:
        return sonoslice.read_plus_config(NWIRE_XML)
    except RuntimeError as e:  # a build without pugixml
        pytest.skip(str(e))


def translation(x, y, z, sx=1.0, sy=1.0):
    """Pixel (i, j) at (x + sx·i, y + sy·j, z)."""
    m = np.eye(4)
    m[0, 0], m[1, 1] = sx, sy
    m[:3, 3] = (x, y, z)
    return m


def rotation(axis, degrees):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(degrees)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * k @ k


# ---- known answers ----------------------------------------------------------------------------------
def test_nearest_frame_on_voxel_centres_is_copied_into_its_slice():
    # Anisotropic spacing and an offset origin: array axes are (z, y, x), spacing/origin (x, y, z).
    c = sonoslice.Compounder(shape=(4, 6, 8), spacing=(0.5, 0.25, 2.0), origin=(10, 20, 30), interpolation="nearest")
    frame = (3 * np.arange(6 * 8) + 1).astype(np.uint8).reshape(6, 8)  # (H, W)
    c.add(frame, translation(10, 20, 34, sx=0.5, sy=0.25))  # pixel (i, j) on voxel (i, j, 2)
    v, w = c.volume(), c.weights()
    assert v.shape == (4, 6, 8) and v.dtype == np.float32 and w.dtype == np.float32
    assert v.spacing == (0.5, 0.25, 2.0) and v.origin == (10.0, 20.0, 30.0)
    expected = np.zeros((4, 6, 8), np.float32)
    expected[2] = frame
    assert np.array_equal(v.array, expected)
    expected_weights = np.zeros((4, 6, 8), np.float32)
    expected_weights[2] = 1
    assert np.array_equal(w.array, expected_weights)
    assert c.frames_added == 1
    assert c.grid == sonoslice.Grid((4, 6, 8), (0.5, 0.25, 2.0), (10.0, 20.0, 30.0))
    # The frames' type as output: exact.
    assert np.array_equal(c.volume(dtype=np.uint8).array[2], frame)


@pytest.mark.parametrize("interpolation", ["nearest", "linear"])
@pytest.mark.parametrize("compounding,expected", [("mean", 17.5), ("max", 25.0), ("latest", 10.0)])
def test_mean_max_latest_of_two_frames(interpolation, compounding, expected):
    c = sonoslice.Compounder(shape=(3, 4, 4), spacing=1.0, interpolation=interpolation, compounding=compounding)
    c.add(np.full((4, 4), 25, np.uint8), translation(0, 0, 1))
    c.add(np.full((4, 4), 10, np.uint8), translation(0, 0, 1))
    v = c.volume().array
    assert np.all(v[1] == expected)
    assert np.all(v[0] == 0) and np.all(v[2] == 0)
    assert c.compounding == compounding and c.interpolation == interpolation


def test_linear_splat_of_one_sample_has_trilinear_weights_summing_to_one():
    c = sonoslice.Compounder(shape=(6, 6, 6), spacing=1.0)
    c.add(np.array([[80.0]], np.float32), translation(2.25, 3.5, 1.75))
    w, v = c.weights().array, c.volume().array
    f = (0.25, 0.5, 0.75)
    for k in range(8):
        dx, dy, dz = k & 1, (k >> 1) & 1, k >> 2
        expected = (f[0] if dx else 1 - f[0]) * (f[1] if dy else 1 - f[1]) * (f[2] if dz else 1 - f[2])
        assert w[1 + dz, 3 + dy, 2 + dx] == pytest.approx(expected, abs=1e-6)
        assert v[1 + dz, 3 + dy, 2 + dx] == pytest.approx(80.0)
    assert w.sum() == pytest.approx(1.0, abs=1e-6)
    assert np.count_nonzero(w) == 8 and np.count_nonzero(v) == 8


def test_rejection_threshold_and_hole_filling():
    frame = np.full((8, 8), 50, np.uint8)
    frame[:, :2] = 3
    c = sonoslice.Compounder(shape=(3, 8, 8), spacing=1.0, interpolation="nearest", rejection_threshold=5)
    c.add(frame, translation(0, 0, 1))
    w = c.weights().array
    assert np.all(w[1, :, :2] == 0) and np.all(w[1, :, 2:] == 1)
    assert c.rejection_threshold == 5.0
    # One missing voxel in a constant slab is filled by the Gaussian element, and only with filling on.
    slab = np.full((3, 8, 8), 40, np.uint8)
    slab[1, 4, 4] = 0  # rejected: a hole
    mats = np.stack([translation(0, 0, z) for z in range(3)])
    settings = dict(shape=(3, 8, 8), spacing=1.0, interpolation="nearest", rejection_threshold=1)
    holes = sonoslice.Compounder(**settings, hole_filling=[dict(type="gaussian", size=3, stdev=0.667, min_ratio=0.2),
                                                           dict(type="stick", length_limit=9, sticks=1)])
    assert holes.fill_holes and [h["type"] for h in holes.hole_filling] == ["gaussian", "stick"]
    assert holes.hole_filling[0] == dict(type="gaussian", size=3, stdev=0.667, min_ratio=0.2)
    plain = sonoslice.Compounder(**settings)
    assert not plain.fill_holes
    for c in (holes, plain):
        c.add(slab, mats)
        assert c.weights().array[1, 4, 4] == 0
    assert holes.volume().array[1, 4, 4] == 40.0
    assert plain.volume().array[1, 4, 4] == 0.0


def test_clip_dict_and_the_equivalent_mask_give_the_same_bytes():
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 255, (4, 40, 50), dtype=np.uint8)
    mats = np.stack([translation(-5, -3, 2 + 0.7 * k, sx=0.3, sy=0.3) for k in range(4)])
    clip = dict(rect=(5, 2, 40, 30), fan=dict(angles_deg=(-30, 30), origin_px=(25, -10), radius_px=(15, 45)))
    mask = sonoslice.clip_mask(clip, (40, 50))
    assert mask.shape == (40, 50) and mask.dtype == np.uint8
    # An independent mask: the rectangle (W x H pixels from (x, y)) and PLUS's fan test.
    y, x = np.mgrid[0:40, 0:50].astype(np.float64)
    dx, dy = x - 25, y + 10
    r = np.hypot(dx, dy)
    angle = np.degrees(np.arctan2(dx, dy))
    expected = (x >= 5) & (x < 45) & (y >= 2) & (y < 32) & (r >= 15) & (r <= 45) & (np.abs(angle) <= 30)
    assert np.array_equal(mask.astype(bool), expected)
    grid = sonoslice.Grid((12, 20, 20), (0.8, 0.8, 0.8), (-6, -4, 1))
    a = sonoslice.Compounder(grid).add(frames, mats, clip=clip)
    b = sonoslice.Compounder(grid).add(frames, mats, clip=mask.astype(bool))
    c = sonoslice.Compounder(grid, clip=clip).add(frames, mats)
    none = sonoslice.Compounder(grid).add(frames, mats)
    assert a.volume().array.tobytes() == b.volume().array.tobytes() == c.volume().array.tobytes()
    assert a.weights().array.sum() < none.weights().array.sum()


def test_incremental_and_batch_give_identical_bytes():
    rng = np.random.default_rng(7)
    frames = rng.integers(0, 4000, (11, 30, 40)).astype(np.uint16)
    mats = []
    for k in range(11):
        m = np.eye(4)
        m[:3, :3] = rotation((1, 0.3, 0.2), 4 * k) * 0.4
        m[:3, 3] = (-6 + 0.2 * k, -5, -4 + 0.5 * k)
        mats.append(m)
    mats = np.array(mats)
    for compounding in ("mean", "max", "latest"):
        def make():
            return sonoslice.Compounder(shape=(20, 24, 28), spacing=0.6, origin=(-8, -7, -6), compounding=compounding,
                                        dtype="uint16")
        batch = make().add(frames, mats)
        one_by_one = make()
        for f, m in zip(frames, mats):
            one_by_one.add(f, m)
        chunks = make()
        for k in range(0, 11, 4):
            chunks.add(frames[k:k + 4], mats[k:k + 4])
        for c in (batch, one_by_one, chunks):
            assert c.frames_added == 11
        ref = batch.volume(np.float32).array
        assert np.count_nonzero(ref) > 1000
        for c in (one_by_one, chunks):
            assert c.volume(np.float32).array.tobytes() == ref.tobytes(), compounding
            assert c.weights().array.tobytes() == batch.weights().array.tobytes()
        assert batch.volume().dtype == np.uint16


def test_every_supported_frame_dtype_is_accepted_and_non_contiguous_frames_are_copied():
    base = np.arange(5 * 6, dtype=np.float64).reshape(5, 6)
    results = []
    for dtype in ("uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"):
        c = sonoslice.Compounder(shape=(3, 5, 6), spacing=1.0, interpolation="nearest")
        c.add(base.astype(dtype), translation(0, 0, 1))
        results.append(c.volume().array[1])
    for r in results:
        assert np.array_equal(r, base.astype(np.float32))
    wide = np.zeros((5, 12), np.float32)
    wide[:, ::2] = base
    c = sonoslice.Compounder(shape=(3, 5, 6), spacing=1.0, interpolation="nearest")
    c.add(wide[:, ::2], translation(0, 0, 1))  # a strided view
    assert np.array_equal(c.volume().array[1], base.astype(np.float32))
    read_only = base.astype(np.uint16)
    read_only.setflags(write=False)
    matrix = translation(0, 0, 1)
    matrix.setflags(write=False)
    c = sonoslice.Compounder(shape=(3, 5, 6), spacing=1.0, interpolation="nearest")
    c.add(read_only, matrix)
    assert np.array_equal(c.volume().array[1], base.astype(np.float32))


def test_torch_frames_and_matrices():
    torch = pytest.importorskip("torch")
    frames = np.random.default_rng(3).random((3, 8, 9)).astype(np.float32)
    mats = np.stack([translation(0, 0, 1 + 0.5 * k) for k in range(3)])
    a = sonoslice.Compounder(shape=(4, 8, 9), spacing=1.0).add(frames, mats)
    b = sonoslice.Compounder(shape=(4, 8, 9), spacing=1.0).add(torch.from_numpy(frames), torch.from_numpy(mats))
    assert a.volume().array.tobytes() == b.volume().array.tobytes()


def test_volume_and_grid_constructors():
    v = sonoslice.Volume(np.zeros((5, 6, 7), np.int16), spacing=(0.5, 0.6, 0.7), origin=(1, 2, 3))
    c = sonoslice.Compounder(v)
    assert c.grid.shape == (5, 6, 7) and c.grid.spacing == (0.5, 0.6, 0.7) and c.grid.origin == (1.0, 2.0, 3.0)
    assert c.grid.dims == (7, 6, 5)
    c2 = sonoslice.Compounder(c.grid, dtype="int16")
    assert c2.volume().shape == (5, 6, 7) and c2.volume().dtype == np.int16
    assert "7x6x5" in repr(c2)
    assert np.allclose(c.grid.index_to_world((1, 1, 1)), (1.5, 2.6, 3.7))
    assert np.allclose(c.grid.world_to_index((1.5, 2.6, 3.7)), (1, 1, 1))


def test_grid_around_follows_plus_rule():
    a = translation(5, 6, 7, sx=0.1, sy=0.1)
    b = translation(5, 6, 9.6, sx=0.1, sy=0.1)
    g = sonoslice.grid_around(np.stack([a, b]), (51, 101), 0.5)  # frames (H, W) = (51, 101)
    assert np.allclose(g.origin, (5, 6, 7))
    assert g.shape == (6, 11, 21)  # (nz, ny, nx): round(2.6/0.5)+1, round(5/0.5)+1, round(10/0.5)+1
    g = sonoslice.grid_around(a, (51, 101), 0.5, clip=dict(rect=(10, 20, 51, 11)))
    assert np.allclose(g.origin[:2], (6, 8)) and g.shape[1:] == (3, 11)
    c = sonoslice.Compounder.around(np.stack([a, b]), (51, 101), 0.5, interpolation="nearest")
    c.add(np.ones((51, 101), np.uint8), a).add(np.ones((51, 101), np.uint8), b)
    assert c.weights().array[0].min() > 0 and c.weights().array[-1].max() > 0


# ---- the slicer round trip ------------------------------------------------------------------------
def test_slicing_a_smooth_volume_and_compounding_it_back_recovers_it():
    nz, ny, nx, s = 40, 50, 60, 0.8
    origin = np.array([-24.0, -5.0, -16.0])
    z, y, x = np.meshgrid(*(origin[a] + s * np.arange(n) for a, n in ((2, nz), (1, ny), (0, nx))), indexing="ij")
    truth = (100 + 40 * np.sin(x / 7.0) * np.cos(y / 9.0) + 0.8 * z).astype(np.float32)
    volume = sonoslice.Volume(truth, spacing=(s, s, s), origin=origin)
    probe = sonoslice.Probe.linear(width=120, height=90, spacing_mm=0.3)
    poses = []
    for k in range(100):
        p = np.eye(4)
        p[:3, :3] = rotation((1, 0, 0), 5.0 * math.sin(k * 0.05))
        p[:3, 3] = (0.0, 2.0, -13.0 + 0.26 * k)
        poses.append(p)
    poses = np.array(poses)
    images = sonoslice.Slicer(volume, probe).slice(poses)  # (N, H, W) float32
    pixel_to_probe = translation(probe.origin_mm[0], probe.origin_mm[1], 0, *probe.spacing_mm)
    c = sonoslice.Compounder(volume, interpolation="linear")
    c.add(images, poses @ pixel_to_probe)
    v, w = c.volume().array, c.weights().array
    assert v.shape == truth.shape
    ok = w >= 1
    interior = np.ones_like(ok[1:-1, 1:-1, 1:-1])
    for dz in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                interior &= ok[1 + dz:nz - 1 + dz, 1 + dy:ny - 1 + dy, 1 + dx:nx - 1 + dx]
    err = np.abs(v[1:-1, 1:-1, 1:-1] - truth[1:-1, 1:-1, 1:-1])[interior]
    assert err.size > 20000
    assert err.mean() < 0.25 and err.max() < 2.0


# ---- 3-D beam-space frames ------------------------------------------------------------------------
def test_beam_frames_land_where_spec7_puts_their_samples(tmp_path):
    geometry = sonoslice.BeamGeometry(r0_mm=3, dr_mm=0.4, azimuth0_deg=-20, dazimuth_deg=5, elevation0_deg=-8,
                                      delevation_deg=4, apex_offset_mm=2)
    geometry.save(tmp_path / "beams.json")
    assert sonoslice.BeamGeometry.from_file(tmp_path / "beams.json") == geometry
    ne, na, ns = 5, 9, 40
    pose = np.eye(4)
    pose[:3, :3] = rotation((1, 0.2, 0.1), 25)
    pose[:3, 3] = (1, 2, 3)
    samples = np.random.default_rng(3).uniform(0, 100, (ne, na, ns)).astype(np.float32)
    c = sonoslice.Compounder.around_beams(pose, geometry, (ne, na, ns), 0.7, interpolation="nearest")
    c.add_beams(samples, pose)  # the geometry given to around_beams
    g = c.grid
    v, w = c.volume().array.astype(np.float64), c.weights().array

    # The NumPy oracle: docs/conventions.md §7 positions, voxel floor(c + 0.5).
    a = np.radians(geometry.azimuth0_deg + np.arange(na) * geometry.dazimuth_deg)[None, :, None]
    e = np.radians(geometry.elevation0_deg + np.arange(ne) * geometry.delevation_deg)[:, None, None]
    r = (geometry.r0_mm + np.arange(ns) * geometry.dr_mm)[None, None, :]
    probe = np.stack(np.broadcast_arrays(r * np.sin(a), -geometry.apex_offset_mm + r * np.cos(a) * np.cos(e),
                                         r * np.cos(a) * np.sin(e)), axis=-1).reshape(-1, 3)
    world = probe @ pose[:3, :3].T + pose[:3, 3]
    t = (world - np.array(g.origin)) / np.array(g.spacing) + 0.5  # (x, y, z)
    dims = np.array(g.dims)
    assert np.all(t >= -1e-6) and np.all(t <= dims + 1e-6)  # the grid encloses every sample
    idx = np.floor(t).astype(int)
    inside = np.all((idx >= 0) & (idx < dims), axis=1)
    total = np.zeros(g.shape)
    count = np.zeros(g.shape)
    xi, yi, zi = idx[inside].T
    np.add.at(total, (zi, yi, xi), samples.reshape(-1)[inside])
    np.add.at(count, (zi, yi, xi), 1)
    # Voxels a float32 rounding could change: a sample within 1e-3 voxel of a boundary.
    uncertain = np.zeros(g.shape, bool)
    near = np.any(np.abs(t - np.round(t)) < 1e-3, axis=1)
    for p in t[near]:
        lo, hi = np.floor(p - 1e-3).astype(int), np.floor(p + 1e-3).astype(int)
        uncertain[max(lo[2], 0):hi[2] + 1, max(lo[1], 0):hi[1] + 1, max(lo[0], 0):hi[0] + 1] = True
    sure = ~uncertain
    assert np.array_equal(w[sure], count[sure])
    reached = sure & (count > 0)
    assert reached.sum() > 500
    assert np.allclose(v[reached], total[reached] / count[reached], atol=1e-3)
    # Batched beam frames: the same as one by one.
    two = sonoslice.Compounder(g, interpolation="nearest").add_beams(np.stack([samples, samples[::-1].copy()]),
                                                                     np.stack([pose, pose]), geometry)
    one = sonoslice.Compounder(g, interpolation="nearest")
    one.add_beams(samples, pose, geometry).add_beams(samples[::-1], pose, dict(
        r0_mm=3, dr_mm=0.4, azimuth0_deg=-20, dazimuth_deg=5, elevation0_deg=-8, delevation_deg=4, apex_offset_mm=2))
    assert two.volume().array.tobytes() == one.volume().array.tobytes() and two.frames_added == 2


# ---- PLUS files ----------------------------------------------------------------------------------
def test_nwire_mha_and_nrrd_read_identically(nwire):
    nrrd = sonoslice.read_plus_sequence(NWIRE_NRRD)
    for s in (nwire, nrrd):
        assert s.shape == (97, 616, 820) and len(s) == 97
        assert s.frames.shape == (97, 616, 820) and s.frames.dtype == np.uint8
        assert s.orientation == "MFA"
    assert np.array_equal(nwire.frames, nrrd.frames)
    assert np.count_nonzero(nwire.frames) > nwire.frames.size / 200
    assert nwire.frame_fields == nrrd.frame_fields
    assert np.array_equal(nwire.timestamps, nrrd.timestamps) and nwire.timestamps[0] == 345.627957
    probe0 = np.array([[0.956683, -0.263308, 0.124204, -190.886], [0.269031, 0.962616, -0.0315089, -98.0911],
                       [-0.111264, 0.0635588, 0.991756, -1949.07], [0, 0, 0, 1]])
    assert np.array_equal(nwire.transform(0, "ProbeToTracker"), probe0)
    assert np.array_equal(nrrd.transform(0, "ProbeToTrackerTransform"), probe0)
    assert nwire.transform(0, "StylusToTracker") is None  # INVALID in this recording
    assert nwire.transform(-1, "NoSuchToTracker") is None
    assert {"ProbeToTracker", "ReferenceToTracker", "StylusToTracker"} <= set(nwire.transform_names(0))
    assert all(nwire.image_ok(k) for k in range(97))
    assert nwire.frame_fields[0]["ImageStatus"] == "OK"


def test_plus_frames_are_a_view_that_keeps_the_sequence_alive(plus_data):
    s = sonoslice.read_plus_sequence(NWIRE_MHA)
    a, b = s.frames, s.frames
    assert np.shares_memory(a, b)
    total = int(a[3].sum(dtype=np.int64))
    del s, b
    gc.collect()
    assert int(a[3].sum(dtype=np.int64)) == total


def test_plus_config_and_image_to_reference(nwire, nwire_config):
    c = nwire_config
    assert c.spacing == (0.5, 0.5, 0.5) and c.origin is None and c.extent is None and c.grid is None
    assert (c.interpolation, c.compounding, c.fill_holes) == ("linear", "mean", False)
    assert c.clip == dict(rect=(167, 62, 496, 489))  # PLUS's size 495 488 covers 496 x 489 pixels
    assert c.skip_interval == 1 and c.transform == "ImageToReference" and c.rejection_threshold is None
    assert c.settings == dict(interpolation="linear", compounding="mean", fill_holes=False, hole_filling=None,
                              rejection_threshold=None)
    frames, mats = sonoslice.plus_image_to_reference(nwire, c)
    assert np.array_equal(frames, np.arange(97)) and mats.shape == (97, 4, 4)
    image_to_probe = c.coordinate_definitions.get("ImageToProbe")
    assert image_to_probe[0, 3] == -103.5322
    expected = (np.linalg.inv(nwire.transform(0, "ReferenceToTracker")) @ nwire.transform(0, "ProbeToTracker")
                @ image_to_probe)
    assert np.allclose(mats[0], expected, atol=1e-9)
    # The same through a repository by hand, and skipping.
    repo = c.coordinate_definitions
    repo.set_frame(nwire, 5)
    assert np.allclose(repo.get("ImageToReference"), mats[5], atol=1e-12)
    frames3, mats3 = sonoslice.plus_image_to_reference(NWIRE_MHA, NWIRE_XML, skip=3)
    assert np.array_equal(frames3, np.arange(0, 97, 3)) and np.array_equal(mats3, mats[::3])
    # Another calibration, given directly.
    frames2, mats2 = sonoslice.plus_image_to_reference(nwire, image_to_probe=np.eye(4))
    assert len(frames2) == 97 and np.allclose(mats2[0], expected @ np.linalg.inv(image_to_probe), atol=1e-9)


def test_reconstruct_plus_matches_plus_reference(nwire, nwire_config):
    volume, weights = sonoslice.reconstruct_plus(nwire, nwire_config, return_weights=True)
    # PLUS's rule at 0.5 mm: 101 x 105 x 74 voxels (x, y, z); PLUS 2.x's older rounding made its
    # reference one voxel shorter along y.
    assert volume.shape == (74, 105, 101) and volume.dtype == np.uint8
    assert np.allclose(volume.origin, (-22.2573, -137.793, -58.5829), atol=1e-3)
    assert volume.spacing == (0.5, 0.5, 0.5)
    reference = sonoslice.Volume.from_file(NWIRE_REFERENCE)
    assert reference.shape == (74, 104, 101)
    assert np.allclose(reference.origin, volume.origin, atol=1e-3)
    ours = volume.array[:, :104, :].astype(np.float64)
    filled = weights.array[:, :104, :] > 0
    assert filled.sum() > 350000
    theirs = reference.array.astype(np.float64)
    mad = np.abs(ours - theirs)[filled].mean()
    assert mad < 0.3  # measured 0.187; an empty volume would score about 1
    # The same structures where they are: a shifted or blurred volume correlates far less.
    assert np.corrcoef(ours[filled], theirs[filled])[0, 1] > 0.97
    # The paths give the same volume as the objects.
    again = sonoslice.reconstruct_plus(NWIRE_MHA, NWIRE_XML)
    assert again.array.tobytes() == volume.array.tobytes()


def test_reconstruct_plus_plus_exact_is_plus_reference_byte_for_byte(nwire, nwire_config):
    volume, weights = sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, return_weights=True)
    reference = sonoslice.Volume.from_file(NWIRE_REFERENCE)
    assert volume.dtype == np.uint8
    # PLUS 2.x's grid (origin at the frames' minimum, int() + 1 voxels): the reference's own.
    assert volume.shape == reference.shape
    assert np.allclose(volume.origin, reference.origin, atol=1e-4)
    assert volume.array.tobytes() == reference.array.tobytes()
    # The weights are PLUS's uint16 accumulation buffer / 256.
    buffer = weights.array * 256
    assert np.array_equal(buffer, np.round(buffer)) and buffer.max() <= 65535
    with pytest.raises(ValueError, match="dtype float32 with plus_exact"):
        sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, dtype="float32")


def test_reconstruct_plus_plus_optimization(nwire, nwire_config):
    # The XML says Optimization="NONE"; FULL (PLUS's default, fixed-point positions) moves a few
    # samples by one voxel; PARTIAL gives NONE's bytes here (IGSIO's code does the same).
    none = sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, skip=4)
    partial = sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, skip=4, plus_optimization="partial")
    full = sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, skip=4, plus_optimization="FULL")
    assert partial.array.tobytes() == none.array.tobytes()
    differ = np.count_nonzero(full.array != none.array)
    assert 0 < differ < 0.01 * none.array.size
    with pytest.raises(ValueError, match="plus_optimization .*GPU"):
        sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, plus_optimization="gpu")
    with pytest.raises(ValueError, match="not one of NONE, PARTIAL, FULL"):
        sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, plus_optimization="fast")
    with pytest.raises(ValueError, match="needs plus_exact"):
        sonoslice.reconstruct_plus(nwire, nwire_config, plus_optimization="full")


def test_reconstruct_plus_plus_grid(nwire, nwire_config):
    legacy = sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, skip=4)
    lattice = sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, skip=4, plus_grid="lattice")
    # Current PLUS: the origin on a multiple of the spacing, at or below the legacy origin, and
    # the grid still reaching the legacy grid's last voxel.
    for a in range(3):
        k = lattice.origin[a] / 0.5
        assert abs(k - round(k)) < 1e-9
        assert legacy.origin[a] - 0.5 < lattice.origin[a] <= legacy.origin[a]
    n_legacy, n_lattice = legacy.shape[::-1], lattice.shape[::-1]  # (x, y, z)
    for a in range(3):
        assert lattice.origin[a] + 0.5 * (n_lattice[a] - 1) >= legacy.origin[a] + 0.5 * (n_legacy[a] - 1)
    with pytest.raises(ValueError, match="not legacy or lattice"):
        sonoslice.reconstruct_plus(nwire, nwire_config, plus_exact=True, plus_grid="round")
    with pytest.raises(ValueError, match="plus_grid needs plus_exact"):
        sonoslice.reconstruct_plus(nwire, nwire_config, plus_grid="lattice")


def test_reconstruct_plus_overrides(nwire, nwire_config):
    v = sonoslice.reconstruct_plus(nwire, nwire_config, spacing=1.0, interpolation="nearest", compounding="max",
                                   skip=4, dtype="float32")
    assert v.dtype == np.float32 and v.spacing == (1.0, 1.0, 1.0)
    _, mats = sonoslice.plus_image_to_reference(nwire, nwire_config, skip=4)
    expected = sonoslice.grid_around(mats, nwire.shape[1:], 1.0, nwire_config.clip)
    assert v.shape == expected.shape and v.origin == expected.origin
    # The same as the Compounder with the XML's settings, changed as asked.
    c = sonoslice.Compounder.around(mats, nwire.shape[1:], 1.0, nwire_config.clip,
                                    **dict(nwire_config.settings, interpolation="nearest", compounding="max"))
    c.add(nwire.frames[::4], mats)
    assert c.volume().array.tobytes() == v.array.tobytes()
    with pytest.raises(ValueError, match="spacing"):
        sonoslice.reconstruct_plus(nwire)


def test_reconstruct_plus_reports_what_it_used(nwire, nwire_config):
    v, report = sonoslice.reconstruct_plus(nwire, nwire_config, skip=2, return_report=True)
    assert report["frames_in_input"] == 97 and report["frames_considered"] == 49
    assert report["frames_used"] == 49 and report["skipped_reason"] == ""
    assert report["transform"] == "ImageToReference" and report["skip"] == 2
    assert not report["grid_from_config"] and not report["grid_given"]  # the NWire XML gives a spacing only
    assert report["splat_seconds"] > 0 and "49" not in report["input"] and "97 frames" in report["input"]
    with pytest.raises(ValueError, match="skip 0: must be >= 1"):
        sonoslice.reconstruct_plus(nwire, nwire_config, skip=0)
    with pytest.raises(ValueError, match="spacing -1"):
        sonoslice.reconstruct_plus(nwire, nwire_config, spacing=-1)


@pytest.mark.parametrize("case", ["nwire", "nwire overrides", "nwire float64", "bone"])
def test_reconstruct_plus_gives_the_cli_bytes(cli, tmp_path, plus_data, case):
    sequence, config, flags, kwargs = NWIRE_MHA, NWIRE_XML, [], {}
    if case == "nwire overrides":
        flags = ["--spacing", "0.8", "--interp", "nearest", "--compounding", "max", "--skip", "3",
                 "--dtype", "float32", "--clip-rect", "200,100,300,300", "--fill-holes", "on"]
        kwargs = dict(spacing=0.8, interpolation="nearest", compounding="max", skip=3, dtype="float32",
                      clip=dict(rect=(200, 100, 300, 300)), fill_holes=True)
    elif case == "nwire float64":  # before the shared recipe, the CLI wrote float32 here
        flags = ["--dtype", "float64", "--skip", "2", "--compounding", "max"]
        kwargs = dict(dtype="float64", skip=2, compounding="max")
    elif case == "bone":
        sequence = os.path.join(PLUS, "BoneUltrasound_L14.igs.mha")
        config = os.path.join(PLUS, "BoneUltrasound_L14_config.xml")
    out, weights = tmp_path / "cli.mha", tmp_path / "cli_weights.mha"
    run = subprocess.run([cli, "compound", "--sequence", sequence, "--config", config, "--out", str(out),
                          "--weights", str(weights), "--quiet"] + flags, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    if case == "bone":  # its XML uses PLUS's deprecated Compounding attribute: warned, as by the CLI
        with pytest.warns(UserWarning, match="deprecated"):
            volume, w = sonoslice.reconstruct_plus(sequence, config, return_weights=True, **kwargs)
    else:
        volume, w = sonoslice.reconstruct_plus(sequence, config, return_weights=True, **kwargs)
    expected = sonoslice.Volume.from_file(out)
    assert volume.shape == expected.shape and volume.dtype == expected.dtype
    assert np.allclose(volume.origin, expected.origin, atol=1e-4) and np.allclose(volume.spacing, expected.spacing)
    assert volume.array.tobytes() == expected.array.tobytes()
    assert w.array.tobytes() == sonoslice.Volume.from_file(weights).array.tobytes()
    assert np.count_nonzero(volume.array) > 1000


def test_write_plus_sequence_round_trips(tmp_path):
    rng = np.random.default_rng(5)
    frames = rng.integers(0, 65535, (4, 9, 13)).astype(np.uint16)
    m = np.eye(4)
    m[:3, 3] = (1.25, -2.5, 1e-7)
    fields = [dict(ProbeToTrackerTransform=m * (k + 1) + np.diag([0, 0, 0, -k]), ProbeToTrackerTransformStatus=True,
                   Timestamp=0.1 * k, ImageStatus="OK" if k != 2 else "INVALID") for k in range(4)]
    for name, compress in (("s.igs.mha", True), ("s.mha", False), ("s.igs.nrrd", True), ("s.nrrd", False)):
        for orientation in ("MF", "UN"):
            path = tmp_path / name
            sonoslice.write_plus_sequence(path, frames, fields, orientation=orientation, compress=compress)
            s = sonoslice.read_plus_sequence(path)
            assert s.orientation == orientation and s.dtype == np.uint16
            assert np.array_equal(s.frames, frames)  # MF again, whatever the file's orientation
            assert [s.image_ok(k) for k in range(4)] == [True, True, False, True]
            assert np.array_equal(s.transform(3, "ProbeToTracker"), fields[3]["ProbeToTrackerTransform"])
            assert np.allclose(s.timestamps, [0.0, 0.1, 0.2, 0.3], rtol=0, atol=1e-15)
            # And back out through the object.
            s.save(tmp_path / ("copy_" + name))
            t = sonoslice.read_plus_sequence(tmp_path / ("copy_" + name))
            assert np.array_equal(t.frames, frames) and t.frame_fields == s.frame_fields


def test_reconstruct_plus_skips_bad_frames_with_a_warning(tmp_path):
    frames = np.random.default_rng(9).integers(1, 255, (4, 9, 13), dtype=np.uint8)
    fields = [dict(ProbeToTrackerTransform=translation(0, 0, k), ProbeToTrackerTransformStatus=k != 3,
                   ImageStatus="OK" if k != 2 else "INVALID") for k in range(4)]
    path = tmp_path / "sweep.igs.nrrd"
    sonoslice.write_plus_sequence(path, frames, fields)
    with pytest.warns(UserWarning, match="skipped 2 of 4 frames: 1 with an invalid ImageToTracker transform, 1 with "
                                         "an image status not OK"):
        v = sonoslice.reconstruct_plus(path, transform="ImageToTracker", image_to_probe=np.eye(4), spacing=1.0)
    assert v.shape == (2, 9, 13) and v.dtype == np.uint8  # frames 0 and 1, on voxel centres
    assert np.array_equal(v.array, frames[:2])
    frames_used, mats = sonoslice.plus_image_to_reference(path, name="ImageToTracker", image_to_probe=np.eye(4))
    assert list(frames_used) == [0, 1] and np.array_equal(mats[1], translation(0, 0, 1))
    with pytest.raises(ValueError, match="give the calibration with config or image_to_probe"):
        sonoslice.reconstruct_plus(path, spacing=1.0)
    sonoslice.write_plus_sequence(path, frames[:1], [dict(ImageStatus="INVALID")])
    with pytest.raises(ValueError, match="no frame"), pytest.warns(UserWarning, match="skipped 1 of 1"):
        sonoslice.reconstruct_plus(path, transform="ImageToTracker", image_to_probe=np.eye(4), spacing=1.0)


# ---- threads, devices --------------------------------------------------------------------------------
def test_threads_can_share_a_compounder():
    c = sonoslice.Compounder(shape=(20, 30, 40), spacing=1.0)
    frames = np.full((5, 30, 40), 7, np.uint8)
    errors = []

    def work(k):
        try:
            for i in range(5):
                c.add(frames, np.stack([translation(0, 0, (k * 5 + i) % 20 + 0.3 * j) for j in range(5)]))
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)
    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and c.frames_added == 100
    v = c.volume().array
    assert np.allclose(v[c.weights().array > 0], 7.0)


def test_cuda_and_cpu_agree_for_nearest_max(cuda):
    rng = np.random.default_rng(2)
    frames = rng.integers(0, 255, (6, 20, 30), dtype=np.uint8)
    mats = np.stack([translation(0.3, 0.2, 1 + 0.6 * k, sx=0.7, sy=0.7) for k in range(6)])
    out = []
    for device in ("cpu", cuda):
        c = sonoslice.Compounder(shape=(6, 16, 24), spacing=1.0, interpolation="nearest", compounding="max",
                                 device=device)
        out.append(c.add(frames, mats).volume().array)
    assert np.array_equal(out[0], out[1])


# ---- bad input -----------------------------------------------------------------------------------
def test_bad_input_raises_and_names_the_argument(tmp_path):
    c = sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0)
    frame = np.ones((2, 2), np.uint8)
    with pytest.raises(ValueError, match=r"add: frames has dtype complex64"):
        c.add(frame.astype(np.complex64), np.eye(4))
    with pytest.raises(ValueError, match=r"add: frames has shape \(2,\)"):
        c.add(np.ones(2, np.uint8), np.eye(4))
    expected = r"add: image_to_reference has shape \(3, 4\); expected \(4, 4\) or \(N, 4, 4\)"
    with pytest.raises(ValueError, match=expected):
        c.add(frame, np.eye(4)[:3])
    with pytest.raises(ValueError, match=r"add: image_to_reference has shape \(2, 4, 4\) for 3 frames"):
        c.add(np.ones((3, 2, 2), np.uint8), np.stack([np.eye(4)] * 2))
    nan = np.eye(4)
    nan[1, 2] = np.nan
    with pytest.raises(ValueError, match="image-to-reference of frame 0: the matrix has a non-finite element"):
        c.add(frame, nan)
    projective = np.eye(4)
    projective[3, 0] = 1
    with pytest.raises(ValueError, match="last row"):
        c.add(frame, projective)
    for singular in (np.diag([1.0, 0, 1, 1]), np.array([[1, 2, 0, 0], [1, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])):
        with pytest.raises(ValueError, match="image-to-reference of frame 0: the matrix is singular"):
            c.add(frame, singular)
    flat_z = np.diag([1.0, 1, 0, 1])  # an image's z column is never used: fine for add, not for beams
    c2 = sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0)
    c2.add(frame, flat_z)
    with pytest.raises(ValueError, match="probe-to-reference of frame 1: the matrix is singular"):
        c2.add_beams(np.ones((2, 2, 2), np.uint8), flat_z, sonoslice.BeamGeometry())
    with pytest.raises(ValueError, match="unknown clip key"):
        c.add(frame, np.eye(4), clip=dict(rectangle=(0, 0, 1, 1)))
    with pytest.raises(ValueError, match=r"clip mask has shape \(3, 3\) but frames are \(2, 2\)"):
        c.add(frame, np.eye(4), clip=np.ones((3, 3), bool))
    with pytest.raises(ValueError, match="fan angles"):
        c.add(frame, np.eye(4), clip=dict(fan=dict(angles_deg=(-95, 30))))
    with pytest.raises(ValueError, match="add_beams: give the frames' geometry"):
        c.add_beams(np.ones((2, 2, 2), np.uint8), np.eye(4))
    with pytest.raises(ValueError, match=r"add_beams: frames has shape \(2, 2\)"):
        c.add_beams(np.ones((2, 2), np.uint8), np.eye(4), sonoslice.BeamGeometry())
    with pytest.raises(ValueError, match="beam geometry: unknown key"):
        c.add_beams(np.ones((2, 2, 2), np.uint8), np.eye(4), dict(r0=1))
    with pytest.raises(ValueError, match="beam angles"):
        c.add_beams(np.ones((2, 200, 2), np.uint8), np.eye(4), sonoslice.BeamGeometry(azimuth0_deg=-80))
    assert c.frames_added == 0  # nothing went in
    with pytest.raises(ValueError, match="volume: dtype complex64"):
        c.volume(np.complex64)

    with pytest.raises(ValueError, match="interpolation 'cubic'"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, interpolation="cubic")
    with pytest.raises(ValueError, match="compounding mode 'median'"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, compounding="median")
    with pytest.raises(ValueError, match="hole filling type 'bogus'"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, hole_filling=[dict(type="bogus")])
    with pytest.raises(ValueError, match=r"hole_filling\[0\]: unknown key"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, hole_filling=[dict(type="gaussian", sigma=1)])
    with pytest.raises(ValueError, match="hole filling element 1: size 4"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, hole_filling=[dict(type="gaussian", size=4)])
    with pytest.raises(ValueError, match="spacing"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=0)
    with pytest.raises(ValueError, match="give a grid"):
        sonoslice.Compounder(shape=(4, 4, 4))
    with pytest.raises(ValueError, match="dtype complex64"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, dtype=np.complex64)
    with pytest.raises(ValueError, match="max_memory"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, max_memory="lots")
    with pytest.raises(ValueError, match="device"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, device="tpu")
    with pytest.raises(RuntimeError, match="2000x2000x1000 voxels.*a spacing of"):
        sonoslice.Compounder(shape=(1000, 2000, 2000), spacing=0.1, max_memory="1G")
    if not sonoslice.cuda_available():
        with pytest.raises(RuntimeError, match="cuda:0: (not available|this sonoslice was built without CUDA)"):
            sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, device="cuda")

    with pytest.raises(OSError, match="not found"):
        sonoslice.read_plus_sequence(tmp_path / "missing.igs.mha")
    (tmp_path / "junk.mha").write_bytes(b"\x00\x01 not a header")
    with pytest.raises(OSError):
        sonoslice.read_plus_sequence(tmp_path / "junk.mha")
    with pytest.raises(OSError):
        sonoslice.BeamGeometry.from_file(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="write_plus_sequence: frames has dtype complex128"):
        sonoslice.write_plus_sequence(tmp_path / "x.mha", np.zeros((1, 2, 2), complex))
    with pytest.raises(ValueError, match="expected .mha or .nrrd"):
        sonoslice.write_plus_sequence(tmp_path / "x.png", np.zeros((1, 2, 2), np.uint8))
    assert not (tmp_path / "x.png").exists()
    with pytest.raises(ValueError, match="orientation 'FM'"):
        sonoslice.write_plus_sequence(tmp_path / "x.mha", np.zeros((1, 2, 2), np.uint8), orientation="FM")
    with pytest.raises(ValueError, match="transform name"):
        sonoslice.TransformRepository().get("ImageReference")
    with pytest.raises(ValueError, match="no chain of transforms from 'Image' to 'Reference'"):
        sonoslice.TransformRepository().get("ImageToReference")


def test_bad_plus_input(tmp_path, nwire, nwire_config):
    with pytest.raises(OSError):
        sonoslice.read_plus_config(tmp_path / "missing.xml")
    (tmp_path / "bad.xml").write_text('<PlusConfiguration><VolumeReconstruction Interpolation="CUBIC"/>'
                                      '</PlusConfiguration>')
    with pytest.raises(ValueError, match="Interpolation"):
        sonoslice.read_plus_config(tmp_path / "bad.xml")
    with pytest.raises(OSError):
        sonoslice.reconstruct_plus(tmp_path / "missing.igs.mha", NWIRE_XML)
    # Without the calibration there is no chain from Image to Reference: say how to give it.
    with pytest.raises(ValueError, match="give the calibration with config or image_to_probe"):
        sonoslice.plus_image_to_reference(nwire)
    with pytest.raises(IndexError):
        nwire.transform(97, "ProbeToTracker")
    with pytest.raises(ValueError, match="skip"):
        sonoslice.plus_image_to_reference(nwire, nwire_config, skip=0)
    # A clip that leaves nothing of the frames names where it came from and the frames' size.
    small = tmp_path / "small.igs.mha"
    sonoslice.write_plus_sequence(small, np.ascontiguousarray(nwire.frames[:3, :80, :100]), nwire.frame_fields[:3],
                                  orientation=nwire.orientation)
    with pytest.raises(ValueError, match=r"the configuration's clip rectangle \(origin 167,62, size 496 x 489\) "
                                         r"leaves no pixel of the 100x80 frames of '.*small.igs.mha'"):
        sonoslice.reconstruct_plus(small, NWIRE_XML)
    with pytest.raises(ValueError, match=r"clip \(origin 900,0, size 10 x 10\) leaves no pixel of the "
                                         r"820x616 frames"):
        sonoslice.reconstruct_plus(NWIRE_MHA, NWIRE_XML, clip=dict(rect=(900, 0, 10, 10)))
    # A header field given twice is refused, not the last one taken.
    text = small.read_bytes()
    (tmp_path / "twice.igs.mha").write_bytes(text.replace(b"DimSize = 100 80 3\n",
                                                           b"DimSize = 100 80 3\nDimSize = 10 10 3\n", 1))
    with pytest.raises(OSError, match=r"twice.igs.mha: header field 'DimSize' given twice"):
        sonoslice.read_plus_sequence(tmp_path / "twice.igs.mha")
    # A header line of megabytes is named by its number (the first: not a text header at all).
    first_end = text.index(b"\n") + 1
    (tmp_path / "long.igs.mha").write_bytes(text[:first_end] + b"Comment = " + b"x" * (2 << 20) + b"\n" +
                                            text[first_end:])
    with pytest.raises(OSError, match=r"long.igs.mha: header line 2 is longer than 1 MiB"):
        sonoslice.read_plus_sequence(tmp_path / "long.igs.mha")
    (tmp_path / "blob.igs.mha").write_bytes(b"x" * (2 << 20))
    with pytest.raises(OSError, match=r"blob.igs.mha: not a PLUS sequence file \(no text header\)"):
        sonoslice.read_plus_sequence(tmp_path / "blob.igs.mha")


def test_absurd_spacing_and_a_broken_transform_are_named(cli, tmp_path):
    sequence = os.path.join(PLUS, "NwirePhantomFreehand.igs.mha")
    config = os.path.join(PLUS, "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml")
    run = lambda *args: subprocess.run([cli, "compound", "--config", config, "--out", str(tmp_path / "v.nii"), *args],
                                       capture_output=True, text=True, timeout=300)  # noqa: E731
    r = run("--sequence", sequence, "--spacing", "1e-300")
    assert r.returncode == 1, r.stderr
    assert r.stderr == "sonoslice: error: --spacing 1e-300 mm: expected a spacing from 1e-06 to 1e+09 mm\n", r.stderr
    # Frame 5's ProbeToTracker translation set to 1e30.
    data = open(sequence, "rb").read()
    head, rest = data.split(b"ElementDataFile", 1)
    lines = head.split(b"\n")
    for n, line in enumerate(lines):
        if line.startswith(b"Seq_Frame0005_ProbeToTrackerTransform ="):
            numbers = line.split(b"=")[1].split()
            numbers[3] = b"1e30"
            lines[n] = b"Seq_Frame0005_ProbeToTrackerTransform = " + b" ".join(numbers)
    broken = tmp_path / "broken.igs.mha"
    broken.write_bytes(b"\n".join(lines) + b"ElementDataFile" + rest)
    r = run("--sequence", str(broken))
    assert r.returncode == 1 and r.stderr.count("\n") == 1, r.stderr
    assert "frame 5 at 2.64e+29 mm): a frame's transform is broken" in r.stderr, r.stderr
    assert os.listdir(tmp_path) == ["broken.igs.mha"]


def test_a_probe_that_does_not_fit_the_frames_names_both_files(cli, tmp_path):
    w1 = os.path.join(DATA, "fanslicer", "models_intensity_LUS_config.json")
    r = subprocess.run([cli, "phantom", str(tmp_path / "ph"), "--poses", "2", "-q"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    frames, poses = tmp_path / "frames.npy", tmp_path / "ph" / "poses.npy"
    r = subprocess.run([cli, "slice", "--volume", str(tmp_path / "ph" / "ct.nii.gz"), "--probe", w1, "--downsampling",
                        "4", "--poses", str(poses), "--out", str(frames), "-q"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([cli, "compound", "--frames", str(frames), "--poses", str(poses), "--probe", w1, "--spacing", "1",
                        "--out", str(tmp_path / "v.nii")], capture_output=True, text=True)
    assert r.returncode == 1, r.stderr
    last = r.stderr.splitlines()[-1]
    assert last == f"sonoslice: error: --probe '{w1}': its mask is 668x544, the frames of '{frames}' are 167x136 " \
                   "(the probe the frames were sliced with, and the --downsampling they were sliced at)", r.stderr
    assert not (tmp_path / "v.nii").exists()


def test_a_png_folder_as_slice_writes_it_compounds_as_its_pixels(cli, tmp_path):
    """`slice --out pngs/` writes PNGs and their poses.txt; `compound --frames pngs/` reads them
    back as a stack, the same bytes as the same pixels given as a .npy."""
    w1 = os.path.join(DATA, "fanslicer", "models_intensity_LUS_config.json")
    r = subprocess.run([cli, "phantom", str(tmp_path / "ph"), "--poses", "6", "-q"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    common = ["--volume", str(tmp_path / "ph" / "ct.nii.gz"), "--probe", w1, "--downsampling", "4",
              "--poses", str(tmp_path / "ph" / "poses.npy"), "-q"]
    for out in (["--out", str(tmp_path / "f.npy")], ["--out", str(tmp_path / "png") + "/", "--window", "40,400"]):
        r = subprocess.run([cli, "slice", *common, *out], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    g = (np.load(tmp_path / "f.npy").astype(np.float64) - (40 - 200)) * (255.0 / 400)  # the PNG window
    np.save(tmp_path / "png.npy", np.floor(np.clip(np.nan_to_num(g), 0, 255) + 0.5).astype(np.uint8))
    volumes = []
    for frames, poses in ((tmp_path / "png", tmp_path / "png" / "poses.txt"),
                          (tmp_path / "png.npy", tmp_path / "ph" / "poses.npy")):
        out = tmp_path / f"{frames.stem}_v.nii"
        r = subprocess.run([cli, "compound", "--frames", str(frames), "--poses", str(poses), "--probe", w1,
                            "--downsampling", "4", "--spacing", "1", "--out", str(out), "-q"],
                           capture_output=True, text=True)
        assert r.returncode == 0 and r.stderr == "", r.stderr
        volumes.append(sonoslice.Volume.from_file(str(out)).array)
    assert volumes[0].any()
    np.testing.assert_array_equal(volumes[0], volumes[1])


def test_a_given_grid_that_no_frame_reaches_is_said(cli, tmp_path, plus_data):
    """--origin/--extent (or the XML's OutputOrigin/Extent) that miss every frame give an empty
    volume: one warning names the axis and both spans; a grid that frames reach gets none."""
    base = [cli, "compound", "--sequence", NWIRE_MHA, "--config", NWIRE_XML, "-q"]
    r = subprocess.run(base + ["--origin", "1e8,0,0", "--extent", "10,10,10", "--out", str(tmp_path / "far.nii")],
                       capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr.count("\n") == 1, r.stderr
    assert ("no frame reaches the output grid (along x the grid spans 99999999.75 to 100000004.75 mm, "
            "the frames -22.26 to 27.74 mm)") in r.stderr, r.stderr
    assert not sonoslice.Volume.from_file(str(tmp_path / "far.nii")).array.any()
    # A far grid too large for memory: the memory error alone, one line, nothing written.
    r = subprocess.run(base + ["--origin", "1e8,0,0", "--extent", "100000,100000,100000", "--out",
                               str(tmp_path / "huge.nii")], capture_output=True, text=True)
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "needs" in r.stderr and "GiB" in r.stderr, r.stderr
    assert not (tmp_path / "huge.nii").exists()
    r = subprocess.run(base + ["--origin", "-22,-137,-58", "--extent", "100,100,70", "--out", str(tmp_path / "near.nii")],
                       capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert sonoslice.Volume.from_file(str(tmp_path / "near.nii")).array.any()
    r = subprocess.run(base[:-1] + ["--origin", "-22,-137,-58", "--extent", "100,100,70", "--verbose",
                                    "--out", str(tmp_path / "near2.nii")], capture_output=True, text=True)
    assert r.returncode == 0 and "grid 100x100x70 at 0.5,0.5,0.5 mm, origin -22,-137,-58 (given)" in r.stderr, r.stderr
    _, report = sonoslice.reconstruct_plus(NWIRE_MHA, NWIRE_XML, origin=(-22, -137, -58), extent=(100, 100, 70),
                                           return_report=True)
    assert report["grid_given"] and not report["grid_from_config"]
