"""The Python API over the C++ objects: round trips, dtypes, layouts, zero copies, errors."""
import os
import threading
import time

import numpy as np
import pytest

import sonoslice
from conftest import small_probe

DTYPES = ["uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"]


@pytest.mark.parametrize("dtype", DTYPES)
def test_volume_from_array_is_a_zero_copy_view(dtype):
    a = (np.arange(4 * 5 * 6) % 100).astype(dtype).reshape(4, 5, 6)
    v = sonoslice.Volume(a, spacing=(0.5, 0.6, 0.7), origin=(1, 2, 3))
    assert v.shape == (4, 5, 6) and v.dtype == np.dtype(dtype)
    assert np.shares_memory(v.array, a)
    a[1, 2, 3] = 42
    assert v.array[1, 2, 3] == 42  # the volume sees the caller's array
    assert v.spacing == (0.5, 0.6, 0.7) and v.origin == (1.0, 2.0, 3.0)
    assert np.array_equal(v.direction, np.eye(3))


def test_volume_layout_and_dtype_errors():
    a = np.zeros((4, 5, 6), np.float32)
    with pytest.raises(ValueError, match="not C-contiguous"):
        sonoslice.Volume(a[:, :, ::2])
    with pytest.raises(ValueError, match="not C-contiguous"):
        sonoslice.Volume(np.asfortranarray(a))
    with pytest.raises(ValueError, match="3 dimensions"):
        sonoslice.Volume(a[0])
    with pytest.raises(ValueError, match="unsupported dtype"):
        sonoslice.Volume(a.astype(np.complex64))
    with pytest.raises(ValueError, match="spacing"):
        sonoslice.Volume(a, spacing=(1, 0, 1))
    # An explicit copy is the documented way round.
    v = sonoslice.Volume(np.ascontiguousarray(a[:, :, ::2]))
    assert v.shape == (4, 5, 3)


def test_volume_file_round_trip_keeps_geometry(tmp_path, phantom):
    ct, _ = phantom
    d = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], float)
    v = sonoslice.Volume(np.ascontiguousarray(ct.array[:20]), spacing=(0.9, 1.1, 2.5), origin=(-5, 6, 7), direction=d)
    for name in ("v.nii.gz", "v.mha", "v.npy"):
        v.save(tmp_path / name)
        back = sonoslice.Volume.from_file(tmp_path / name)
        assert back.dtype == np.int16 and back.shape == v.shape
        assert np.allclose(back.spacing, v.spacing) and np.allclose(back.origin, v.origin, atol=1e-4)
        assert np.allclose(back.direction, d, atol=1e-6)
        assert np.array_equal(back.array, v.array)
    assert np.allclose(v.index_to_world(v.world_to_index([1, 2, 3])), [1, 2, 3])


def test_errors_map_to_python_exceptions(tmp_path, phantom, poses):
    ct, _ = phantom
    with pytest.raises(OSError, match="no such file"):
        sonoslice.Volume.from_file(tmp_path / "missing.nii.gz")
    (tmp_path / "bad.json").write_text('{"type": "linear", "image": {"width": 5, "height": 5, "spacing": [1, 1]}}')
    with pytest.raises(ValueError, match="unknown key 'spacing'"):
        sonoslice.Probe.from_json(tmp_path / "bad.json")
    bad = poses.copy()
    bad[3, 0, 0] = np.nan
    with pytest.raises(ValueError, match="pose 3"):
        sonoslice.Slicer(ct, small_probe()).slice(bad)
    with pytest.raises(ValueError, match="interpolation 'cubic'"):
        sonoslice.Slicer(ct, small_probe(), interpolation="cubic")
    with pytest.raises(ValueError, match="expected shape"):
        sonoslice.Slicer(ct, small_probe()).slice(np.zeros((3, 3)))
    if not sonoslice.cuda_available():
        with pytest.raises(RuntimeError, match="cuda:0: (not available|this sonoslice was built without CUDA)"):
            sonoslice.Slicer(ct, small_probe(), device="cuda")


def test_probes(shared, tmp_path):
    w1 = sonoslice.Probe.from_fanslicer(os.path.join(shared, "models_intensity_LUS_config.json"), downsampling=2)
    assert (w1.width, w1.height, w1.type) == (334, 272, "curvilinear")
    assert w1.spacing_mm == pytest.approx((0.247, 0.247))
    assert np.array_equal(w1.mask, sonoslice.Probe.workload("W1").mask)
    lin = sonoslice.Probe.from_json(os.path.join(shared, "linear_config.json"))
    assert lin.type == "linear" and lin.mask.all()
    fan = sonoslice.Probe.curvilinear(46.93, 64.96, 36, 334, 272, 0.247, face_y_mm=2.1, origin_mm=(-41.25, 0))
    assert fan.origin_mm == (-41.25, 0.0)
    # Native JSON round trip: the same probe back.
    path = tmp_path / "fan.json"
    path.write_text(fan.to_json())
    back = sonoslice.Probe.from_json(path)
    for attr in ("type", "width", "height", "radius_mm", "depth_mm", "sector_deg", "face_y_mm"):
        assert getattr(back, attr) == pytest.approx(getattr(fan, attr)), attr
    assert back.spacing_mm == pytest.approx(fan.spacing_mm) and back.origin_mm == pytest.approx(fan.origin_mm)
    assert np.array_equal(back.mask, fan.mask)
    with pytest.raises(ValueError, match="no \"simulation\" block"):
        sonoslice.Probe.from_fanslicer(path)


def test_slicing_matches_the_cli_library_path_and_dtypes(phantom, poses):
    ct, labels = phantom
    probe = sonoslice.Probe.workload("W1")
    images, mask = sonoslice.Slicer(ct, probe).slice(poses, mask=True)
    assert images.shape == (12, 272, 334) and images.dtype == np.float32
    assert mask.shape == (272, 334) and mask.dtype == np.uint8
    assert (images[:, mask == 0] == 0).all()  # fill outside the fan
    inside = images[:, mask == 1]
    assert inside.min() < -500 and inside.max() > 0  # real CT values: air and tissue
    # Integer outputs: the float32 images rounded (ties up) and saturated, fill included.
    as_float = sonoslice.Slicer(ct, probe, fill=-1).slice(poses).astype(np.float64)
    for dtype in ("int16", "uint8", "uint16"):
        out = sonoslice.Slicer(ct, probe, dtype=dtype, fill=-1).slice(poses)
        info = np.iinfo(dtype)
        assert out.dtype == np.dtype(dtype)
        assert np.array_equal(out, np.clip(np.floor(as_float + 0.5), info.min, info.max).astype(dtype))
    lab = sonoslice.Slicer(labels, probe, interpolation="nearest", dtype="uint8").slice(poses)
    assert set(np.unique(lab)) <= set(range(len(sonoslice.PHANTOM_LABELS)))
    # One pose as a 4x4, RAS poses, torch poses.
    one = sonoslice.Slicer(ct, probe).slice(poses[0])
    assert np.array_equal(one[0], images[0])
    ras = poses.copy()
    ras[:, :2, :] *= -1
    assert np.array_equal(sonoslice.Slicer(ct, probe).slice(ras, world="RAS"), images)


def test_out_arrays_are_filled_without_copies(phantom, poses):
    ct, _ = phantom
    s = sonoslice.Slicer(ct, small_probe())
    out = np.full((12, 80, 96), 7.0, np.float32)
    address = out.__array_interface__["data"][0]
    r = s.slice(poses, out=out)
    assert r is out and out.__array_interface__["data"][0] == address
    assert np.array_equal(out, s.slice(poses))
    with pytest.raises(ValueError, match="expected shape"):
        s.slice(poses, out=np.empty((11, 80, 96), np.float32))
    with pytest.raises(ValueError, match="dtype must be float32"):
        s.slice(poses, out=np.empty((12, 80, 96), np.float64))
    with pytest.raises(ValueError, match="C-contiguous"):
        s.slice(poses, out=np.empty((12, 80, 192), np.float32)[:, :, ::2])


def test_progress_callback_and_chunks(phantom):
    ct, _ = phantom
    s = sonoslice.Slicer(ct, small_probe())
    seen = []
    poses = sonoslice.phantom_poses(300)
    images = s.slice(poses, progress=lambda done, total: seen.append((done, total)), chunk=64)
    assert seen == [(64, 300), (128, 300), (192, 300), (256, 300), (300, 300)]
    assert np.array_equal(images, s.slice(poses))


def test_progress_bar_with_tqdm(phantom, capsys):
    pytest.importorskip("tqdm")
    ct, _ = phantom
    sonoslice.Slicer(ct, small_probe()).slice(sonoslice.phantom_poses(200), progress=True)
    assert "200/200" in capsys.readouterr().err


def test_gil_is_released_while_slicing():
    ct, _ = sonoslice.phantom("full")
    s = sonoslice.Slicer(ct, sonoslice.Probe.workload("W2"))
    poses = sonoslice.phantom_poses(600)
    ticks, span = [], []

    def work():
        t0 = time.perf_counter()
        s.slice(poses)
        span.append(time.perf_counter() - t0)

    worker = threading.Thread(target=work)
    worker.start()
    while worker.is_alive():
        ticks.append(time.perf_counter())
        time.sleep(0.005)
    worker.join()
    # The main thread kept running Python code during the C++ call: with the GIL held it would tick
    # once or twice; released, about once per 5 ms of the call (a fast machine slices in ~50 ms).
    assert len(ticks) >= max(3, 0.25 * span[0] / 0.005), (len(ticks), span)


def test_write_stack_and_poses(tmp_path, phantom, poses):
    ct, _ = phantom
    s = sonoslice.Slicer(ct, small_probe())
    images = s.slice(poses)
    sonoslice.write_stack(tmp_path / "s.nii.gz", images, (0.8, 0.8))
    back = sonoslice.Volume.from_file(tmp_path / "s.nii.gz")
    assert back.shape == (12, 80, 96) and np.array_equal(back.array, images)
    sonoslice.write_stack(tmp_path / "pngs", images, (0.8, 0.8), window=(40, 400), poses=poses)
    assert (tmp_path / "pngs" / "img_00011.png").exists()
    # read_stack reads back what write_stack writes, as the commands' frame readers do.
    assert np.array_equal(sonoslice.read_stack(tmp_path / "s.nii.gz"), images)
    pngs = sonoslice.read_stack(tmp_path / "pngs")
    assert pngs.shape == images.shape and pngs.dtype == np.uint8
    with pytest.raises(OSError, match="stack '.*missing.dcm': no such file"):
        sonoslice.read_stack(tmp_path / "missing.dcm")
    sonoslice.write_poses(tmp_path / "p.txt", poses)
    assert np.allclose(sonoslice.read_poses(tmp_path / "p.txt"), poses)
    with pytest.warns(UserWarning, match="not orthonormal"):
        stretched = poses.copy()
        stretched[:, :3, 0] *= 1.01
        sonoslice.validate_poses(stretched)


def test_devices_report():
    text = sonoslice.devices()
    assert text.startswith("cpu: ") and "cuda" in text
    sonoslice.set_threads(1)
    assert sonoslice.threads() == 1
    sonoslice.set_threads(None)


def test_require_cuda_turns_cuda_skips_into_failures(tmp_path):
    """SONOSLICE_REQUIRE_CUDA=1 (scripts/gpu-check.sh): a CUDA test without a GPU fails, never skips."""
    import subprocess
    import sys
    if sonoslice.cuda_available():
        pytest.skip("a GPU is present: the CUDA tests run")
    test = tmp_path / "test_needs_gpu.py"
    test.write_text("def test_gpu(cuda):\n    assert cuda == 'cuda:0'\n")
    conftest = os.path.join(os.path.dirname(__file__), "conftest.py")
    (tmp_path / "conftest.py").write_text(open(conftest).read())
    run = lambda env: subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(test)],
                                     cwd=tmp_path, env=env, capture_output=True, text=True)
    plain = {k: v for k, v in os.environ.items() if k != "SONOSLICE_REQUIRE_CUDA"}
    skipped = run(plain)
    assert skipped.returncode == 0 and "1 skipped" in skipped.stdout, skipped.stdout
    failed = run(dict(plain, SONOSLICE_REQUIRE_CUDA="1"))
    assert failed.returncode == 1 and "SONOSLICE_REQUIRE_CUDA=1, but the test would skip" in failed.stdout, failed.stdout


def test_cuda_work_goes_on_the_current_stream_of_the_arrays_library(monkeypatch):
    """slice(out=...) on CUDA queues on torch's or CuPy's current stream (0: the legacy default
    stream, which orders with every blocking stream), so that the library's next operation sees
    the images and its allocator never reuses out= memory still being written."""
    import sys
    import types
    from sonoslice import _current_stream
    assert _current_stream(np.zeros((1, 2, 3), np.float32)) == 0

    # torch: its current stream on the tensor's device, whatever stream that is.
    torch = pytest.importorskip("torch")
    assert _current_stream(torch.zeros(2)) == 0  # host memory: no stream
    asked = []

    class FakeStream:
        cuda_stream = 0x7F00

    monkeypatch.setattr(torch.cuda, "current_stream", lambda device=None: asked.append(device) or FakeStream())
    FakeCudaTensor = type("Tensor", (), {"__module__": "torch", "is_cuda": True, "device": "cuda:1"})
    assert _current_stream(FakeCudaTensor()) == 0x7F00 and asked == ["cuda:1"]

    # CuPy: its current stream, asked on the array's device.
    entered = []

    class Device:
        def __init__(self, index):
            self.index = index

        def __enter__(self):
            entered.append(self.index)

        def __exit__(self, *exc):
            return False

    cupy = types.ModuleType("cupy")
    cupy.cuda = types.SimpleNamespace(Device=Device, get_current_stream=lambda: types.SimpleNamespace(ptr=0x5A00))
    monkeypatch.setitem(sys.modules, "cupy", cupy)
    FakeCupyArray = type("ndarray", (), {"__module__": "cupy._core.core", "device": types.SimpleNamespace(id=2)})
    assert _current_stream(FakeCupyArray()) == 0x5A00 and entered == [2]
