"""sonoslice register: the CLI contract, outputs and bad input.

Gradients and recovery are checked in C++ (tests/register/test_register.cpp); these run the
command as users do: frames written by `sonoslice slice`, poses perturbed here.
"""
import json
import os
import subprocess

import numpy as np
import pytest

from conftest import assert_each_flag_required

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
W1 = os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json")
REPORT_KEYS = {"index", "metric", "evaluations", "iterations", "translation_change_mm", "rotation_change_deg",
               "starts", "agreeing_starts", "confidence", "converged", "uncertainty_mm", "uncertainty_deg"}


def run(cli, *args):
    return subprocess.run([cli, *args], capture_output=True, encoding="utf-8", errors="replace", timeout=600)


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def perturbed(poses, mm, deg, seed):
    """Each pose turned by `deg` about a random axis through its origin and moved by `mm`."""
    rng = np.random.default_rng(seed)
    out = poses.copy()
    for p in out:
        d = rng.normal(size=3)
        p[:3, :3] = rotation(rng.normal(size=3), np.deg2rad(deg)) @ p[:3, :3]
        p[:3, 3] += mm * d / np.linalg.norm(d)
    return out


def one_line_error(r, needle):
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert r.stderr.startswith("sonoslice: error: ") and r.stderr.count("\n") == 1, r.stderr
    assert needle in r.stderr, r.stderr


@pytest.fixture(scope="module")
def case(cli, tmp_path_factory):
    """The small phantom's CT, 4 W1 fans at --downsampling 4 of true poses, initial poses 3 mm
    and 3 degrees off."""
    d = tmp_path_factory.mktemp("reg")
    r = run(cli, "phantom", str(d / "ph"), "--poses", "4", "-q")
    assert r.returncode == 0, r.stderr
    truth = np.load(d / "ph" / "poses.npy")
    np.save(d / "truth.npy", truth)
    r = run(cli, "slice", "--volume", str(d / "ph" / "ct.nii.gz"), "--probe", W1, "--downsampling", "4",
            "--poses", str(d / "truth.npy"), "--out", str(d / "frames.npy"), "-q")
    assert r.returncode == 0, r.stderr
    np.save(d / "init.npy", perturbed(truth, 3, 3, 1))
    return d


def base_args(d, out="refined.npy"):
    return ["register", "--volume", str(d / "ph" / "ct.nii.gz"), "--probe", W1, "--downsampling", "4",
            "--frames", str(d / "frames.npy"), "--poses", str(d / "init.npy"), "--out", str(d / out)]


def errors(a, b):
    mm = np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)
    rel = np.einsum("nij,nkj->nik", a[:, :3, :3], b[:, :3, :3])
    deg = np.rad2deg(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return mm, deg


def test_per_frame_refines_poses_and_reports(cli, case):
    r = run(cli, *base_args(case), "--report", str(case / "report.json"), "--starts", "4",
            "--search-rot-deg", "3", "--search-trans-mm", "3")
    assert r.returncode == 0, r.stderr
    refined = np.load(case / "refined.npy")
    assert refined.shape == (4, 4, 4) and refined.dtype == np.float64
    truth, init = np.load(case / "truth.npy"), np.load(case / "init.npy")
    mm0, deg0 = errors(init, truth)
    mm, deg = errors(refined, truth)
    assert np.all(mm0 > 2) and np.all(deg0 > 2.9)
    assert np.all(mm < 1) and np.all(deg < 1), (mm, deg)
    report = json.load(open(case / "report.json"))
    assert len(report["frames"]) == 4 and REPORT_KEYS <= set(report["frames"][0])
    assert [f["index"] for f in report["frames"]] == [0, 1, 2, 3]
    assert report["evaluations"] == sum(f["evaluations"] for f in report["frames"]) > 0
    assert report["seconds"] > 0
    for f, a, b in zip(report["frames"], mm0, deg0):
        assert f["translation_change_mm"] > 0 and f["rotation_change_deg"] > 0
    # Four starts each, the best pose reached from at least three: converged, and nothing to warn.
    assert all(f["starts"] == 4 and f["converged"] and f["agreeing_starts"] >= 3 for f in report["frames"])
    assert report["converged_frames"] == 4 and "warning" not in r.stderr


def test_a_single_start_is_never_called_converged(cli, case):
    """One optimisation cannot tell its optimum from a local minimum: the report says so and the
    command warns in one line (exit status 0: the poses are written)."""
    r = run(cli, *base_args(case, "one.npy"), "--report", str(case / "one.json"), "--starts", "1")
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith("sonoslice: warning: registration: 4 of 4 frames not converged"), r.stderr
    report = json.load(open(case / "one.json"))
    assert report["starts"] == 1 and report["converged_frames"] == 0
    assert all(not f["converged"] and f["starts"] == 1 and f["confidence"] == 0 for f in report["frames"])


def test_rigid_sweep_applies_one_correction(cli, case):
    r = run(cli, *base_args(case, "sweep.npy"), "--mode", "rigid-sweep", "--metric", "ssd", "--optimizer", "gn")
    assert r.returncode == 0, r.stderr
    init, refined = np.load(case / "init.npy"), np.load(case / "sweep.npy")
    # X = refined_i · init_i⁻¹ is the same for every frame.
    X = [refined[k] @ np.linalg.inv(init[k]) for k in range(4)]
    for k in range(1, 4):
        np.testing.assert_allclose(X[k], X[0], atol=1e-9)


@pytest.mark.parametrize("axis, sides", [(0, True), (2, False)])
def test_a_sweep_within_its_plane_is_also_split_by_sides(cli, case, tmp_path, axis, sides):
    # Six fans 2 mm apart along the probe's lateral axis (within the image plane: its frames'
    # halves see the same tissue, so the left and right halves of its frames are compared too)
    # or its normal (through the plane: the frames' halves alone).
    base = np.load(case / "truth.npy")[0]
    truth = np.repeat(base[None], 6, 0)
    truth[:, :3, 3] += (np.arange(6) - 2.5)[:, None] * 2 * base[:3, axis]
    np.save(tmp_path / "truth.npy", truth)
    r = run(cli, "slice", "--volume", str(case / "ph" / "ct.nii.gz"), "--probe", W1, "--downsampling", "4",
            "--poses", str(tmp_path / "truth.npy"), "--out", str(tmp_path / "frames.npy"), "-q")
    assert r.returncode == 0, r.stderr
    init = truth.copy()
    init[:, :3, 3] += 1
    np.save(tmp_path / "init.npy", init)
    r = run(cli, "register", "--volume", str(case / "ph" / "ct.nii.gz"), "--probe", W1, "--downsampling", "4",
            "--frames", str(tmp_path / "frames.npy"), "--poses", str(tmp_path / "init.npy"), "--mode", "rigid-sweep",
            "--out", str(tmp_path / "refined.npy"), "--report", str(tmp_path / "r.json"))
    assert r.returncode == 0, r.stderr
    report = json.load(open(tmp_path / "r.json"))
    assert 0 <= report["halves_mm"] < 0.1
    assert ("sides_mm" in report) == sides
    if sides:
        assert 0 <= report["sides_mm"] < 0.1
    assert report["converged_frames"] == 6 and "warning" not in r.stderr
    mm, deg = errors(np.load(tmp_path / "refined.npy"), truth)
    assert np.all(mm < 0.1) and np.all(deg < 0.1), (mm, deg)


@pytest.mark.parametrize("metric", ["ssd", "mi"])
def test_a_sweep_reports_its_own_cost(cli, case, tmp_path, metric):
    # The sweep's cost at the shared correction: MI's is the mean of the frames' own costs; SSD's
    # pools every frame's pixels, the frames' own costs weighted by their pixel counts, so it lies
    # between their least and greatest.
    r = run(cli, *base_args(case, "sweep_cost.npy"), "--mode", "rigid-sweep", "--metric", metric, "--starts", "2",
            "--report", str(tmp_path / "r.json"))
    assert r.returncode == 0, r.stderr
    report = json.load(open(tmp_path / "r.json"))
    own = [f["metric"] for f in report["frames"]]
    if metric == "mi":
        assert report["sweep_metric"] == pytest.approx(np.mean(own), rel=1e-12, abs=1e-12)
    else:
        assert min(own) <= report["sweep_metric"] <= max(own) and min(own) < max(own)
    assert report["halves_mm"] >= 0  # the halves check ran (4 frames: two halves of two)
    r = run(cli, *base_args(case, "frame_cost.npy"), "--starts", "1", "--report", str(tmp_path / "f.json"))
    per_frame = json.load(open(tmp_path / "f.json"))
    assert "sweep_metric" not in per_frame and "halves_mm" not in per_frame


def test_smooth_sweep_reports_and_its_weight_spans_per_frame_to_rigid(cli, case):
    truth, init = np.load(case / "truth.npy"), np.load(case / "init.npy")
    # Weight 0: every frame free (from the rigid-sweep correction), so each finds its own pose.
    r = run(cli, *base_args(case, "smooth0.npy"), "--mode", "smooth-sweep", "--smoothness", "0",
            "--report", str(case / "smooth0.json"))
    assert r.returncode == 0, r.stderr
    mm, deg = errors(np.load(case / "smooth0.npy"), truth)
    assert np.all(mm < 1) and np.all(deg < 1), (mm, deg)
    report = json.load(open(case / "smooth0.json"))
    assert report["mode"] == "smooth-sweep" and report["smoothness"] == 0
    assert len(report["frames"]) == 4 and REPORT_KEYS <= set(report["frames"][0])
    # A huge weight: the corrections X_i = refined_i · init_i⁻¹ stay (nearly) one.
    r = run(cli, *base_args(case, "stiff.npy"), "--mode", "smooth-sweep", "--smoothness", "1e6")
    assert r.returncode == 0, r.stderr
    refined = np.load(case / "stiff.npy")
    X = [refined[k] @ np.linalg.inv(init[k]) for k in range(4)]
    for k in range(1, 4):
        np.testing.assert_allclose(X[k][:3, :3], X[0][:3, :3], atol=2e-3)


@pytest.mark.parametrize("metric", ["lc2", "lncc", "mi"])
def test_metrics_without_derivatives_default_to_bobyqa(cli, case, metric):
    r = run(cli, *base_args(case, f"{metric}.npy"), "--metric", metric, "--report", str(case / f"{metric}.json"))
    if "built without NLopt" in r.stderr:
        pytest.skip("this sonoslice was built without NLopt")
    assert r.returncode == 0, r.stderr
    report = json.load(open(case / f"{metric}.json"))
    assert report["metric"] == metric and report["optimizer"] == "bobyqa"
    costs = [f["metric"] for f in report["frames"]]
    assert all(c <= 0 for c in costs) if metric == "mi" else all(0 <= c <= 2 for c in costs), costs


@pytest.mark.parametrize("optimizer", ["bobyqa", "nelder-mead"])
def test_derivative_free_optimisers(cli, case, optimizer):
    r = run(cli, *base_args(case, f"{optimizer}.npy"), "--optimizer", optimizer, "--report",
            str(case / f"{optimizer}.json"))
    if "built without NLopt" in r.stderr:
        pytest.skip("this sonoslice was built without NLopt")
    assert r.returncode == 0, r.stderr
    report = json.load(open(case / f"{optimizer}.json"))
    assert report["optimizer"] == optimizer and report["evaluations"] > 0
    assert np.load(case / f"{optimizer}.npy").shape == (4, 4, 4)


def test_png_frames_and_a_user_mask(cli, case, tmp_path):
    r = run(cli, "slice", "--volume", str(case / "ph" / "ct.nii.gz"), "--probe", W1, "--downsampling", "4",
            "--poses", str(case / "truth.npy"), "--out", str(tmp_path / "png") + "/", "--dtype", "uint16",
            "--window", "0,4000", "-q")
    assert r.returncode == 0, r.stderr
    frames = np.load(case / "frames.npy")
    mask = np.zeros(frames.shape[1:], np.uint8)
    mask[: mask.shape[0] // 2] = 1  # the upper half only
    np.save(tmp_path / "mask.npy", mask[None])
    args = base_args(case, "png_refined.npy")
    args[args.index("--frames") + 1] = str(tmp_path / "png")
    r = run(cli, *args, "--mask", str(tmp_path / "mask.npy"))
    assert r.returncode == 0, r.stderr
    assert np.load(case / "png_refined.npy").shape == (4, 4, 4)
    # The 2-D (H, W) mask `slice --mask` writes is taken as it is, and gives the same poses.
    np.save(tmp_path / "mask2d.npy", mask)
    r = run(cli, *args[:-1], str(case / "png_refined_2d.npy"), "--mask", str(tmp_path / "mask2d.npy"))
    assert r.returncode == 0, r.stderr
    assert np.array_equal(np.load(case / "png_refined_2d.npy"), np.load(case / "png_refined.npy"))
    r = run(cli, "slice", "--volume", str(case / "ph" / "ct.nii.gz"), "--probe", W1, "--downsampling", "4",
            "--poses", str(case / "truth.npy"), "--out", str(tmp_path / "s.npy"), "--mask",
            str(tmp_path / "fan.npy"), "-q")
    assert r.returncode == 0 and np.load(tmp_path / "fan.npy").ndim == 2, r.stderr
    r = run(cli, *base_args(case, "fan_refined.npy"), "--mask", str(tmp_path / "fan.npy"))
    assert r.returncode == 0, r.stderr


def write_png(path, pixels):
    """An 8-bit PNG of (H, W) grey or (H, W, 3|4) RGB/RGBA pixels, written by zlib alone."""
    import struct
    import zlib

    h, w = pixels.shape[:2]
    kind = {1: 0, 2: 4, 3: 2, 4: 6}[1 if pixels.ndim == 2 else pixels.shape[2]]  # PNG colour types

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    rows = b"".join(b"\0" + row.tobytes() for row in pixels.astype(np.uint8).reshape(h, -1))
    header = struct.pack(">IIBBBBB", w, h, 8, kind, 0, 0, 0)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows)) +
                chunk(b"IEND", b""))


def test_colour_png_frames_register_as_their_first_component(cli, case, tmp_path):
    """A scanner's screen capture is RGB: its first (red) component is registered, as PLUS
    reconstructs colour frames, with one warning when the colours differ."""
    frames = np.load(case / "frames.npy")
    grey = np.clip(frames / 4000 * 255, 0, 255).astype(np.uint8)
    results = {}
    for name, make in [("grey", lambda g: g), ("rgb", lambda g: np.stack([g, g, g], -1)),
                       ("coloured", lambda g: np.stack([g, g // 2, 255 - g, np.full_like(g, 255)], -1))]:
        (tmp_path / name).mkdir()
        for k, g in enumerate(grey):
            write_png(tmp_path / name / f"f{k:02d}.png", make(g))
        args = base_args(case, f"{name}.npy")
        args[args.index("--frames") + 1] = str(tmp_path / name)
        r = run(cli, *args, "-q")
        assert r.returncode == 0, r.stderr
        warned = [line for line in r.stderr.splitlines() if "first (red) component" in line]
        assert len(warned) == (1 if name == "coloured" else 0), r.stderr
        results[name] = np.load(case / f"{name}.npy")
    assert np.array_equal(results["rgb"], results["grey"])
    assert np.array_equal(results["coloured"], results["grey"])
    # The same frames as an (N, H, W, 3) .npy, as `slice --colors` writes colour stacks.
    np.save(tmp_path / "rgb.npy", np.stack([grey, grey // 2, grey], -1))
    args = base_args(case, "rgb_npy.npy")
    args[args.index("--frames") + 1] = str(tmp_path / "rgb.npy")
    r = run(cli, *args, "-q")
    assert r.returncode == 0 and "--frames '" + str(tmp_path / "rgb.npy") + "': colour images" in r.stderr, r.stderr
    assert np.array_equal(np.load(case / "rgb_npy.npy"), results["grey"])
    # A grey-and-alpha PNG has no colour to take the first of: refused, named.
    (tmp_path / "ga").mkdir()
    write_png(tmp_path / "ga" / "f.png", np.stack([grey[0], grey[0]], -1))
    args = base_args(case, "ga.npy")
    args[args.index("--frames") + 1] = str(tmp_path / "ga")
    one_line_error(run(cli, *args), "f.png': 2 components (frames have 1, or 3 or 4: RGB, RGBA)")


def test_a_mask_of_nan_is_refused_not_taken_as_non_zero(cli, case, tmp_path):
    frames = np.load(case / "frames.npy")
    np.save(tmp_path / "nan.npy", np.full(frames.shape[1:], np.nan, np.float32))
    one_line_error(run(cli, *base_args(case, "nan_mask.npy"), "--mask", str(tmp_path / "nan.npy")),
                   f"--mask '{tmp_path / 'nan.npy'}': {frames[0].size} pixels are NaN or infinite")
    assert not (case / "nan_mask.npy").exists()
    import sonoslice
    ct = sonoslice.Volume.from_file(str(case / "ph" / "ct.nii.gz"))
    probe = sonoslice.Probe.from_fanslicer(W1, downsampling=4)
    with pytest.raises(ValueError, match=f"mask: {frames[0].size} NaN pixels"):
        sonoslice.register(ct, probe, frames, np.load(case / "init.npy"), mask=np.full(frames.shape[1:], np.nan))


def test_missing_required_flags_are_usage_errors(cli, case):
    full = base_args(case, "never.npy")
    assert_each_flag_required(cli, full, ("--volume", "--probe", "--frames", "--poses", "--out"))
    assert not (case / "never.npy").exists()


@pytest.mark.parametrize("extra, needle", [
    (["--metric", "mutual"], "--metric mutual"),
    (["--metric", "mi", "--optimizer", "gn"], "no analytic derivatives"),
    (["--metric", "lc2", "--optimizer", "lm"], "no analytic derivatives"),
    (["--optimizer", "adam"], "--optimizer adam"),
    (["--mode", "sweep"], "--mode sweep"),
    (["--mode", "smooth-sweep", "--metric", "mi"], "smooth-sweep"),
    (["--mode", "smooth-sweep", "--smoothness", "-1"], "--smoothness"),
    (["--mode", "rigid-sweep", "--smoothness", "0.5"], "--smoothness: applies to --mode smooth-sweep"),
    (["--starts", "0"], "--starts 0"),
    (["--search-trans-mm", "nan"], "--search-trans-mm"),
    (["--search-trans-mm", "1e300"], "--search-trans-mm 1e+300: must be a distance from 0 to 1e9 mm"),
    (["--pyramid", "4,0"], "--pyramid 4,0"),
    (["--pyramid", "2,2"], "--pyramid 2,2: the block sizes must decrease"),
    (["--downsampling", "2"], "--frames"),
])
def test_bad_settings_are_one_line(cli, case, extra, needle):
    args = base_args(case, "bad.npy")
    if extra[0] in args:  # a flag the base arguments already give: replace its value
        args[args.index(extra[0]) + 1] = extra[1]
        extra = []
    one_line_error(run(cli, *args, *extra), needle)
    assert not os.path.exists(case / "bad.npy")


def test_bad_inputs_leave_a_good_output_alone(cli, case, tmp_path):
    good = tmp_path / "good.npy"
    np.save(good, np.eye(4)[None])
    before = good.read_bytes()

    def args(**replace):
        a = base_args(case)
        a[a.index("--out") + 1] = str(good)
        for flag, value in replace.items():
            a[a.index("--" + flag) + 1] = value
        return a

    poses = np.load(case / "init.npy")
    np.save(tmp_path / "three.npy", poses[:3])
    one_line_error(run(cli, *args(poses=str(tmp_path / "three.npy"))), "3 poses for 4 frames")
    bad = poses.copy()
    bad[2, 0, 3] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    one_line_error(run(cli, *args(poses=str(tmp_path / "nan.npy"))), "pose 2")
    one_line_error(run(cli, *args(frames=str(tmp_path / "missing.npy"))), "missing.npy")
    (tmp_path / "corrupt.npy").write_bytes(b"\x93NUMPY garbage")
    one_line_error(run(cli, *args(frames=str(tmp_path / "corrupt.npy"))), "corrupt.npy")
    one_line_error(run(cli, *args(volume=str(tmp_path / "none.nii.gz"))), "none.nii.gz")
    one_line_error(run(cli, *base_args(case, "refined.txt")), "--out")
    assert good.read_bytes() == before


def test_python_register_matches_the_command(cli, case):
    import sonoslice

    ct = sonoslice.Volume.from_file(str(case / "ph" / "ct.nii.gz"))
    probe = sonoslice.Probe.from_fanslicer(W1, downsampling=4)
    frames = np.load(case / "frames.npy")
    init, truth = np.load(case / "init.npy"), np.load(case / "truth.npy")
    refined, report = sonoslice.register(ct, probe, frames, init, starts=3, search_rot_deg=3, search_trans_mm=3)
    assert refined.shape == (4, 4, 4) and refined.dtype == np.float64
    assert [set(f) for f in report["frames"]] == [REPORT_KEYS] * 4
    mm, deg = errors(refined, truth)
    assert np.all(mm < 1) and np.all(deg < 1), (mm, deg)
    # The command with the same settings gives the same poses.
    r = run(cli, *base_args(case, "same.npy"), "--starts", "3", "--search-rot-deg", "3", "--search-trans-mm", "3")
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(np.load(case / "same.npy"), refined, atol=1e-12)
    with pytest.raises(ValueError, match="frames"):
        sonoslice.register(ct, probe, frames[:, :-1], init)
    with pytest.raises(ValueError, match="metric"):
        sonoslice.register(ct, probe, frames, init, metric="mutual")


# ---- PLUS sequences: frames and tracked poses as they come ------------------------------------
PLUS = os.path.join(ROOT, "data", "plus")
NWIRE = os.path.join(PLUS, "NwirePhantomFreehand.igs.mha")
NWIRE_XML = os.path.join(PLUS, "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml")
NWIRE_VOLUME = os.path.join(PLUS, "NwirePhantomFreehandReconstructed.mha")  # PLUS's own reconstruction


def nwire_config(path, image_to_probe=None, skip=4):
    """The NWire configuration with every `skip`-th frame and, if given, another ImageToProbe."""
    import re
    text = open(NWIRE_XML).read()
    text = text.replace('Optimization="NONE"', f'Optimization="NONE" SkipInterval="{skip}"')
    if image_to_probe is not None:
        matrix = " ".join(f"{v:.9g}" for v in np.asarray(image_to_probe).ravel())
        text = re.sub(r'(<Transform From="Image" To="Probe"\s+Matrix=")[^"]*"', rf'\g<1>{matrix}"', text)
    open(path, "w").write(text)
    return str(path)


def nwire_image_to_probe():
    import re
    m = re.search(r'<Transform From="Image" To="Probe"\s+Matrix="([^"]*)"', open(NWIRE_XML).read())
    return np.array(m.group(1).split(), float).reshape(4, 4)


def clip_corners_mm(image_to_probe):
    """The NWire clip rectangle's corners and centre (pixels) in probe mm."""
    (x0, y0), (w, h) = (167, 62), (495, 488)
    pixels = np.array([[x0, y0, 0, 1], [x0 + w, y0, 0, 1], [x0, y0 + h, 0, 1], [x0 + w, y0 + h, 0, 1],
                       [x0 + w / 2, y0 + h / 2, 0, 1]]).T
    return (np.asarray(image_to_probe) @ pixels)[:3].T


def test_calibration_of_a_plus_sweep_recovers_a_perturbed_image_to_probe(cli, tmp_path):
    """The real NWire sweep against PLUS's own reconstruction of it: `register --sequence
    --config --mode calibration` from the configuration's calibration, and from that calibration
    moved by 2 mm and 2 degrees, finds the same corrected ImageToProbe."""
    truth = nwire_image_to_probe()
    error = np.eye(4)
    error[:3, :3] = rotation([1, -2, 0.5], np.deg2rad(2))
    error[:3, 3] = [1.2, -1.0, 1.2]  # 2 mm
    found = {}
    for name, image_to_probe in (("as-given", None), ("perturbed", error @ truth)):
        config = nwire_config(tmp_path / f"{name}.xml", image_to_probe)
        out, report_path = tmp_path / f"{name}.npy", tmp_path / f"{name}.json"
        r = run(cli, "register", "--sequence", NWIRE, "--config", config, "--volume", NWIRE_VOLUME,
                "--mode", "calibration", "--pyramid", "8,4,2", "--out", str(out), "--report", str(report_path))
        assert r.returncode == 0, r.stderr
        # The calibration's pixel axes are 0.9 degrees from perpendicular: said once, not refused.
        assert "degrees from perpendicular" in r.stderr and r.stderr.count("\n") == 1, r.stderr
        report = json.load(open(report_path))
        assert report["mode"] == "calibration" and report["sequence_frames"] == list(range(0, 97, 4))
        assert report["converged_frames"] == 25 and np.load(out).shape == (25, 4, 4)
        found[name] = np.array(report["image_to_probe"])
    start = np.linalg.norm(clip_corners_mm(error @ truth) - clip_corners_mm(truth), axis=1).max()
    apart = np.linalg.norm(clip_corners_mm(found["perturbed"]) - clip_corners_mm(found["as-given"]), axis=1)
    moved = np.linalg.norm(clip_corners_mm(found["as-given"]) - clip_corners_mm(truth), axis=1)
    print(f"clip corners: perturbed by up to {start:.2f} mm; the two results {apart.max():.3f} mm apart; "
          f"the configuration's calibration moved by up to {moved.max():.3f} mm")
    assert start > 2 and apart.max() < 0.3


def test_python_registers_a_plus_sequence_as_the_command_does(cli, tmp_path):
    """sonoslice.register_sequence (paths or objects) and `register --sequence --config` are one
    library call: the same refined ImageToReference matrices, frames and corrected ImageToProbe."""
    import sonoslice
    out, report_path = tmp_path / "cli.npy", tmp_path / "cli.json"
    xml = nwire_config(tmp_path / "c.xml", None)  # every 4th frame
    r = run(cli, "register", "--sequence", NWIRE, "--config", xml, "--volume", NWIRE_VOLUME,
            "--mode", "calibration", "--pyramid", "8,4", "--out", str(out), "--report", str(report_path))
    assert r.returncode == 0, r.stderr
    want = json.load(open(report_path))
    volume = sonoslice.Volume.from_file(NWIRE_VOLUME)
    for sequence, config in ((NWIRE, xml), (sonoslice.read_plus_sequence(NWIRE), sonoslice.read_plus_config(xml))):
        with pytest.warns(UserWarning, match="degrees from perpendicular"):
            matrices, report = sonoslice.register_sequence(volume, sequence, config, mode="calibration",
                                                           pyramid=[8, 4])
        np.testing.assert_array_equal(matrices, np.load(out))
        assert report["sequence_frames"] == want["sequence_frames"] == list(range(0, 97, 4))
        np.testing.assert_array_equal(report["image_to_probe"], want["image_to_probe"])
        assert report["mode"] == "calibration" and report["converged_frames"] == want["converged_frames"]
        assert [f["metric"] for f in report["frames"]] == [f["metric"] for f in want["frames"]]
    with pytest.raises(TypeError, match="volume"):
        sonoslice.register_sequence(NWIRE_VOLUME, NWIRE)


def test_a_corrected_sequence_compounds_where_registration_put_the_frames(cli, tmp_path):
    """`register --sequence --out X.igs.mha` writes the real NWire sweep with its ProbeToTracker
    transforms corrected: read back with the same configuration, each used frame's ImageToReference
    is the refined matrix `--out X.npy` writes, the other frames and every image are as they were,
    `compound` takes it, and Python's register_sequence(corrected=True) writes the same."""
    import sonoslice
    xml = nwire_config(tmp_path / "c.xml", None)  # every 4th frame
    common = ["register", "--sequence", NWIRE, "--config", xml, "--volume", NWIRE_VOLUME, "--pyramid", "8,4",
              "--starts", "1"]
    r = run(cli, *common, "--out", str(tmp_path / "refined.npy"))
    assert r.returncode == 0, r.stderr
    corrected_path = tmp_path / "corrected.igs.mha"
    r = run(cli, *common, "--out", str(corrected_path))
    assert r.returncode == 0, r.stderr
    refined = np.load(tmp_path / "refined.npy")
    frames, matrices = sonoslice.plus_image_to_reference(str(corrected_path), xml)
    assert list(frames) == list(range(0, 97, 4))
    np.testing.assert_allclose(matrices, refined, rtol=0, atol=1e-9)
    _, before = sonoslice.plus_image_to_reference(NWIRE, xml)
    moved = np.abs(matrices[:, :3, 3] - before[:, :3, 3]).max()
    assert moved > 0.01, moved  # registration moved the frames, and the file says so
    original, corrected = sonoslice.read_plus_sequence(NWIRE), sonoslice.read_plus_sequence(corrected_path)
    np.testing.assert_array_equal(corrected.frames, original.frames)
    for frame in range(len(original)):
        changed = {k for k in original.frame_fields[frame]
                   if original.frame_fields[frame][k] != corrected.frame_fields[frame].get(k)}
        assert changed == ({"ProbeToTrackerTransform"} if frame % 4 == 0 else set()), (frame, changed)
    volume = tmp_path / "v.mha"
    r = run(cli, "compound", "--sequence", str(corrected_path), "--config", xml, "--out", str(volume), "-q")
    assert r.returncode == 0 and volume.exists(), r.stderr
    with pytest.warns(UserWarning, match="degrees from perpendicular"):
        same, _, fixed = sonoslice.register_sequence(sonoslice.Volume.from_file(NWIRE_VOLUME), NWIRE, xml,
                                                     pyramid=[8, 4], starts=1, corrected=True)
    np.testing.assert_array_equal(same, refined)
    assert fixed.frame_fields == corrected.frame_fields
    # A refined-poses file is .npy; with --sequence a sequence as well, nothing else.
    r = run(cli, *common, "--out", str(tmp_path / "x.txt"))
    assert r.returncode == 1 and "a corrected sequence as .mha or .nrrd" in r.stderr, r.stderr


def test_sequence_input_bad_input_is_one_line(cli, tmp_path):
    skewed = nwire_image_to_probe()
    skewed[:3, 1] = skewed[:3, 1] + 0.3 * np.linalg.norm(skewed[:3, 1]) * skewed[:3, 0] / np.linalg.norm(skewed[:3, 0])
    cases = [
        (["--sequence", NWIRE, "--config", nwire_config(tmp_path / "skew.xml", skewed)],
         "frame 0's ImageToReference shears the image"),
        (["--sequence", NWIRE, "--config", NWIRE_XML, "--probe", W1], "--probe is for frames given as files"),
        (["--sequence", str(tmp_path / "missing.igs.mha")], "missing.igs.mha"),
        (["--frames", NWIRE, "--config", NWIRE_XML], "--config goes with --sequence"),
    ]
    for args, needle in cases:
        r = run(cli, "register", "--volume", NWIRE_VOLUME, "--out", str(tmp_path / "x.npy"), *args)
        assert r.returncode == 1, (args, r.stderr)
        assert r.stderr.startswith("sonoslice: error: ") and r.stderr.count("\n") == 1, r.stderr
        assert needle in r.stderr, r.stderr
        assert not (tmp_path / "x.npy").exists()


def test_one_warning_for_poses_a_little_off_orthonormal(cli, case, tmp_path):
    skewed = np.load(case / "init.npy")
    skewed[:, 0, 0] *= 1.01
    np.save(tmp_path / "skewed.npy", skewed)
    args = base_args(case, "skewed_refined.npy")
    args[args.index("--poses") + 1] = str(tmp_path / "skewed.npy")
    r = run(cli, *args, "--starts", "2")
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("not orthonormal") == 1, r.stderr


def test_constant_frames_keep_their_pose_and_say_why(cli, case, tmp_path):
    frames = np.load(case / "frames.npy")
    frames[1] = 7.0  # no contrast at all
    np.save(tmp_path / "frames.npy", frames)
    args = base_args(case, "const_refined.npy")
    args[args.index("--frames") + 1] = str(tmp_path / "frames.npy")
    r = run(cli, *args, "--report", str(tmp_path / "r.json"))
    assert r.returncode == 0, r.stderr
    assert "registration: frame 1 (1 of 4) constant over the compared pixels: nothing to register against; " \
           "poses left as given" in r.stderr, r.stderr
    report = json.load(open(tmp_path / "r.json"))
    flat = report["frames"][1]
    assert (flat["starts"], flat["evaluations"], flat["converged"], flat["metric"]) == (0, 0, False, None)
    refined = np.load(case / "const_refined.npy")
    np.testing.assert_array_equal(refined[1], np.load(case / "init.npy")[1])
    assert report["frames"][0]["starts"] >= 1


@pytest.mark.parametrize("mode,metric", [("rigid-sweep", "mi"), ("rigid-sweep", "ncc"), ("calibration", "lc2")])
def test_a_sweep_without_contrast_keeps_its_poses(cli, case, tmp_path, mode, metric):
    # Nothing steers a sweep whose every frame is constant: its cost is flat, and a search would
    # wander on round-off (it moved such a sweep by 9.6 mm before).
    frames = np.full_like(np.load(case / "frames.npy"), 7.0)
    np.save(tmp_path / "frames.npy", frames)
    args = base_args(case, "flat_refined.npy")
    args[args.index("--frames") + 1] = str(tmp_path / "frames.npy")
    r = run(cli, *args, "--mode", mode, "--metric", metric, "--report", str(tmp_path / "r.json"))
    assert r.returncode == 0, r.stderr
    assert "constant over the compared pixels: nothing to register against; poses left as given" in r.stderr
    assert "not converged" not in r.stderr, r.stderr
    np.testing.assert_array_equal(np.load(case / "flat_refined.npy"), np.load(case / "init.npy"))
    report = json.load(open(tmp_path / "r.json"))
    assert all((f["starts"], f["converged"], f["metric"]) == (0, False, None) for f in report["frames"])
