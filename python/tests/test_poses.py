"""sonoslice poses and sonoslice.PoseSampler: the command and the binding give the same
poses, seeds make poses reproducible, bad settings are one line. Geometry (surface distance,
normals, tilt ranges, uniform rotations) is checked in C++ (tests/sampling/)."""
import json
import os
import subprocess
import time

import numpy as np
import pytest

import sonoslice
from conftest import assert_each_flag_required

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
W1 = os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json")


def run(cli, *args):
    return subprocess.run([cli, *args], capture_output=True, encoding="utf-8", errors="replace", timeout=600)


@pytest.fixture(scope="module")
def ph(cli, tmp_path_factory):
    d = tmp_path_factory.mktemp("poses")
    r = run(cli, "phantom", str(d / "ph"), "-q")
    assert r.returncode == 0, r.stderr
    return d


def test_command_and_binding_agree(cli, ph):
    out = ph / "skin.npy"
    r = run(cli, "poses", "--sampler", "skin", "--volume", str(ph / "ph" / "ct.nii.gz"), "--probe", W1,
            "--downsampling", "2", "--count", "500", "--seed", "9", "--tilt-deg", "-10,10", "--min-body", "0.5",
            "--out", str(out), "-v", "-q")
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""  # -q wins over -v, as in every command
    poses = np.load(out)
    assert poses.shape == (500, 4, 4) and poses.dtype == np.float64
    ct = sonoslice.Volume.from_file(str(ph / "ph" / "ct.nii.gz"))
    probe = sonoslice.Probe.from_fanslicer(W1, downsampling=2)
    sampler = sonoslice.PoseSampler({"type": "skin", "tilt_deg": [-10, 10], "reject": {"min_body": 0.5}}, probe, ct)
    same = sampler.sample(sonoslice.sample_seeds(9, 0, 0, 500))
    np.testing.assert_array_equal(same, poses)
    # Each pose is its seed's: asking for a part gives that part.
    np.testing.assert_array_equal(sampler.sample(sonoslice.sample_seeds(9, 0, 100, 5)), poses[100:105])
    assert all(sampler.accepts(p) for p in poses[:50])
    # A pose that is not one is bad input, not a rejection.
    nan = poses[0].copy()
    nan[0, 3] = np.nan
    with pytest.raises(ValueError, match="^pose: pose 0: "):
        sampler.accepts(nan)
    with pytest.raises(ValueError, match="pose has shape \\(3, 3\\)"):
        sampler.accepts(np.eye(3))
    # Rigid, and the face centre on the body's surface (the skin's sampled points).
    np.testing.assert_allclose(np.einsum("nji,njk->nik", poses[:, :3, :3], poses[:, :3, :3]),
                               np.broadcast_to(np.eye(3), (500, 3, 3)), atol=1e-9)
    surface = sampler.surface()
    assert surface.shape[1:] == (2, 3) and len(surface) > 1000


def test_sweeps_give_their_frames_and_json_settings(cli, ph, tmp_path):
    spec = tmp_path / "sweep.json"
    spec.write_text(json.dumps({"type": "sweep", "motion": "linear", "step": 1.5, "frames": 8,
                                "from": {"type": "skin"}, "jitter_mm": 0.2}))
    r = run(cli, "poses", "--sampler", str(spec), "--volume", str(ph / "ph" / "ct.nii.gz"), "--probe", W1,
            "--count", "3", "--out", str(tmp_path / "sweep.txt"))
    assert r.returncode == 0, r.stderr
    rows = np.loadtxt(tmp_path / "sweep.txt")
    assert rows.shape == (24, 16)


@pytest.mark.parametrize("extra, needle", [
    (["--sampler", "ring"], "--sampler 'ring'"),
    (["--sampler", '{"type": "skin", "tilt": [0, 1]}'], "unknown key 'tilt'"),
    (["--sampler", '{"type": "skin", "cone_deg": 3}'], "does not apply to a skin sampler"),
    (["--sampler", "region"], "give its \"label\" or \"intensity\" range"),
    (["--tilt-deg", "10,-10"], "--tilt-deg 10,-10: expected lo,hi with lo <= hi"),
    (["--count", "0"], "--count 0"),
    (["--min-body", "1.0", "--max-tries", "20", "--depth-mm", "-200,-200"], "20 tries"),
    (["--out", "poses.png"], "--out"),
    (["--sampler", '{"type": "skin", "notes": ' + "[" * 1000 + "]" * 1000 + "}"],
     "--sampler: invalid JSON (nested deeper than 64 levels)"),
])
def test_bad_settings_are_one_line(cli, ph, tmp_path, extra, needle):
    args = ["poses", "--sampler", "skin", "--volume", str(ph / "ph" / "ct.nii.gz"), "--probe", W1,
            "--count", "10", "--out", str(tmp_path / "bad.npy")]
    for i in range(0, len(extra), 2):
        if extra[i] in args:
            args[args.index(extra[i]) + 1] = extra[i + 1]
        else:
            args += extra[i:i + 2]
    r = run(cli, *args)
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert r.stderr.startswith("sonoslice: error: ") and r.stderr.count("\n") == 1, r.stderr
    assert needle in r.stderr, r.stderr
    assert not os.path.exists(tmp_path / "bad.npy")


def test_a_sampler_file_is_named_in_its_errors(cli, ph, tmp_path):
    (tmp_path / "cut.json").write_text('{"type": "skin"')
    (tmp_path / "huge.json").write_text('{"type": "skin", "max_tries": 1e400}')
    (tmp_path / "folder.json").mkdir()
    for name, needle in (("cut.json", "--sampler '{}': invalid JSON ("),
                         ("huge.json", "--sampler '{}': invalid JSON ("),
                         ("folder.json", "cannot open --sampler '{}': it is a directory")):
        path = str(tmp_path / name)
        r = run(cli, "poses", "--sampler", path, "--volume", str(ph / "ph" / "ct.nii.gz"), "--probe", W1,
                "--count", "2", "--out", str(tmp_path / "p.npy"))
        assert r.returncode == 1 and r.stderr.count("\n") == 1, r.stderr
        assert needle.format(path) in r.stderr, r.stderr
    assert not os.path.exists(tmp_path / "p.npy")


def test_flags_are_laid_over_a_sampler_file(cli, ph, tmp_path):
    spec = tmp_path / "skin.json"
    spec.write_text(json.dumps({"type": "skin", "tilt_deg": [-5, 5], "depth_mm": [0, 2],
                                "reject": {"min_body": 0.5}}))
    r = run(cli, "poses", "--sampler", str(spec), "--volume", str(ph / "ph" / "ct.nii.gz"), "--probe", W1,
            "--count", "50", "--seed", "4", "--tilt-deg", "-10,10", "--min-inside", "0.9",
            "--out", str(tmp_path / "p.npy"))
    assert r.returncode == 0, r.stderr
    ct = sonoslice.Volume.from_file(str(ph / "ph" / "ct.nii.gz"))
    merged = {"type": "skin", "tilt_deg": [-10, 10], "depth_mm": [0, 2],
              "reject": {"min_body": 0.5, "min_inside": 0.9}}
    sampler = sonoslice.PoseSampler(merged, sonoslice.Probe.from_fanslicer(W1), ct)
    np.testing.assert_array_equal(np.load(tmp_path / "p.npy"), sampler.sample(sonoslice.sample_seeds(4, 0, 0, 50)))


def test_python_errors_name_the_setting():
    probe = sonoslice.Probe.workload("W1")
    itself = []
    itself.append(itself)  # a list that holds itself: refused, not recursed into without end
    with pytest.raises(ValueError, match="nested deeper than 64 levels"):
        sonoslice.PoseSampler({"type": "skin", "tilt_deg": itself}, probe)
    with pytest.raises(ValueError, match="unknown key 'tilt'"):
        sonoslice.PoseSampler({"type": "skin", "tilt": 3}, probe)
    with pytest.raises(ValueError, match="needs the CT"):
        sonoslice.PoseSampler({"type": "skin"}, probe)
    with pytest.raises(TypeError):
        sonoslice.PoseSampler("skin", probe)
    with pytest.raises(ValueError, match="seeds"):
        sonoslice.PoseSampler({"type": "sweep", "start": np.eye(4).tolist()}, probe).sample([0.5])


def test_missing_required_flags_are_usage_errors(cli, ph, tmp_path):
    full = ["poses", "--sampler", "skin", "--volume", str(ph / "ph" / "ct.nii.gz"), "--probe", W1,
            "--count", "3", "--out", str(tmp_path / "never.npy")]
    assert_each_flag_required(cli, full, ("--sampler", "--probe", "--out"))
    assert not (tmp_path / "never.npy").exists()


def test_seeds_outside_64_bits_are_refused(cli, ph, tmp_path):
    base = ["--volume", str(ph / "ph" / "ct.nii.gz"), "--out", str(tmp_path / "never.npy")]
    commands = [["poses", "--sampler", "skin", "--probe", W1, "--count", "2", *base],
                ["simulate", "--preset", "lus", "--poses", str(ph / "ph" / "poses.npy"), *base]]
    for command in commands:
        for bad in ("-1", "18446744073709551616", "1.5", "0x10"):
            r = run(cli, *command, "--seed", bad)
            assert r.returncode == 1, (command[0], bad, r.stderr)
            assert r.stderr == f"sonoslice: error: --seed {bad}: expected a whole number from 0 to " \
                               "18446744073709551615\n", r.stderr
    assert not (tmp_path / "never.npy").exists()
    r = run(cli, *commands[0], "--seed", "18446744073709551615")
    assert r.returncode == 0, r.stderr


def test_impossible_rules_fail_early_and_name_the_first_seed(cli, ph, tmp_path):
    # Every seed would fail: the command stops at the first failing seeds instead of trying all
    # 100,000 seeds' 1000 candidates, and names the same (first) seed as a short run does.
    args = ["poses", "--sampler", "skin", "--volume", str(ph / "ph" / "ct.nii.gz"), "--probe", W1,
            "--min-inside", "1.0", "--depth-mm", "500,500", "--out", str(tmp_path / "never.npy")]
    start = time.monotonic()
    big = run(cli, *args, "--count", "100000")
    assert time.monotonic() - start < 30
    small = run(cli, *args, "--count", "100")
    assert big.returncode == small.returncode == 1, big.stderr
    assert big.stderr == small.stderr and "passed the rejection rules in 1000 tries" in big.stderr, big.stderr
    assert not (tmp_path / "never.npy").exists()
