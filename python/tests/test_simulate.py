"""sonoslice simulate: the CLI contract, outputs and bad input.

The model's own checks (speckle statistics, attenuation, shadows, ...) are the C++ tests
tests/simulate/test_simulate.cpp; these run the command as users do.
"""
import json
import os
import subprocess

import numpy as np
import pytest


def run(cli, *args, cwd=None):
    return subprocess.run([cli, *args], capture_output=True, encoding="utf-8", errors="replace",
                          timeout=600, cwd=cwd)


@pytest.fixture(scope="module")
def ph(cli, tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    r = run(cli, "phantom", str(d / "ph"), "--poses", "6", "-q")
    assert r.returncode == 0, r.stderr
    poses = np.load(d / "ph" / "poses.npy")[:3]
    np.save(d / "p3.npy", poses)
    return d


def one_line_error(r, needle, status=1):
    assert r.returncode == status, (r.returncode, r.stderr)
    assert r.stderr.startswith("sonoslice: error: ") and r.stderr.count("\n") == 1, r.stderr
    assert needle in r.stderr, r.stderr


def test_presets_and_default_tissue_table(cli, tmp_path):
    r = run(cli, "simulate", "--list-presets")
    assert r.returncode == 0, r.stderr
    names = [line.split()[0] for line in r.stdout.splitlines()]
    assert names == ["abdominal", "laparoscopic", "lus"]
    r = run(cli, "simulate", "--print-tissues")
    assert r.returncode == 0, r.stderr
    table = json.loads(r.stdout)["tissues"]
    assert [t["name"] for t in table] == ["water", "blood", "fat", "liver", "kidney", "muscle",
                                          "soft tissue", "vessel wall", "bone", "gas"]
    for t in table:
        assert set(t) == {"name", "label", "impedance_mrayl", "attenuation_db_cm_mhz",
                          "scatter_mean", "scatter_density"}
    assert table[6]["impedance_mrayl"] == 1.63 and table[6]["attenuation_db_cm_mhz"] == 0.54
    assert os.listdir(tmp_path) == []


def test_simulate_ct_labels_and_meshless_outputs(cli, ph):
    base = ["--preset", "lus", "--poses", str(ph / "p3.npy"), "-q"]
    r = run(cli, "simulate", "--volume", str(ph / "ph" / "ct.nii.gz"), "--out", str(ph / "ct.npy"),
            "--mask", str(ph / "mask.npy"), *base)
    assert r.returncode == 0, r.stderr
    ct = np.load(ph / "ct.npy")
    assert ct.shape == (3, 272, 334) and ct.dtype == np.uint8
    # The fan mask is slice's: the same file slice --mask writes for the same probe.
    r = run(cli, "slice", "--volume", str(ph / "ph" / "ct.nii.gz"), "--probe",
            os.path.join(os.path.dirname(__file__), "..", "..", "data", "fanslicer",
                         "models_intensity_LUS_config.json"),
            "--downsampling", "2", "--poses", str(ph / "p3.npy"), "--out", str(ph / "slice.npy"),
            "--mask", str(ph / "slice_mask.npy"), "-q")
    assert r.returncode == 0, r.stderr
    mask = np.load(ph / "mask.npy")
    assert np.array_equal(mask, np.load(ph / "slice_mask.npy"))
    assert (ct[:, mask == 0] == 0).all()
    assert ct[:, mask == 1].std() > 5  # speckle, not a flat fill

    r = run(cli, "simulate", "--labels", str(ph / "ph" / "labels.nii.gz"), "--tissues",
            str(ph / "ph" / "tissues.json"), "--out", str(ph / "env.npy"), "--output", "envelope",
            "--tgc", "off", *base)
    assert r.returncode == 0, r.stderr
    env = np.load(ph / "env.npy")
    assert env.dtype == np.float32 and env.shape == (3, 272, 334)
    assert (env >= 0).all() and env[:, mask == 1].max() > 0


def test_same_seed_same_bytes_any_threads(cli, ph):
    outs = []
    for threads, seed in (("1", "5"), ("2", "5"), ("2", "6")):
        out = ph / f"s{threads}_{seed}.npy"
        r = run(cli, "simulate", "--volume", str(ph / "ph" / "ct.nii.gz"), "--preset", "lus",
                "--poses", str(ph / "p3.npy"), "--out", str(out), "--threads", threads, "--seed",
                seed, "-q")
        assert r.returncode == 0, r.stderr
        outs.append(np.load(out))
    assert np.array_equal(outs[0], outs[1])
    assert not np.array_equal(outs[0], outs[2])


def test_simulate_cli_on_the_gpu(cli, tmp_path, cuda):
    """--device cuda: the CPU's images within docs/simulation.md §4's tolerance. (.npy files: the
    GPU machine's build has no ITK.)"""
    r = run(cli, "phantom", str(tmp_path / "ph"), "--format", "npy", "--poses", "3", "-q")
    assert r.returncode == 0, r.stderr
    outs = []
    for device in ("cpu", cuda):
        out = tmp_path / f"{device.replace(':', '')}.npy"
        r = run(cli, "simulate", "--volume", str(tmp_path / "ph" / "ct.npy"), "--preset", "lus",
                "--poses", str(tmp_path / "ph" / "poses.npy"), "--out", str(out), "--device", device,
                "--mask", str(tmp_path / "mask.npy"), "-q")
        assert r.returncode == 0, r.stderr
        outs.append(np.load(out))
    mask = np.load(tmp_path / "mask.npy") == 1
    diff = np.abs(outs[0].astype(int) - outs[1].astype(int))[:, mask]
    assert (diff > 1).mean() <= 0.005 and diff.mean() < 0.05, ((diff > 1).mean(), diff.mean())


def test_bad_input_one_line_nothing_written(cli, ph, tmp_path):
    ct = str(ph / "ph" / "ct.nii.gz")
    labels = str(ph / "ph" / "labels.nii.gz")
    poses = str(ph / "p3.npy")
    good = tmp_path / "good.npy"
    np.save(good, np.zeros(3))
    before = good.read_bytes()
    bad_table = tmp_path / "bad.json"
    bad_table.write_text(json.dumps({"tissues": [{"name": "x", "label": 1, "impedance_mrayl": 1.5,
                                                   "attenuation_db_cm_mhz": 0.5}]}))
    partial = tmp_path / "partial.json"
    partial.write_text(json.dumps({"tissues": [{"name": "fat", "label": 1, "impedance_mrayl": 1.38,
                                                 "attenuation_db_cm_mhz": 0.48, "scatter_mean": 0.01,
                                                 "colour": "yellow"}]}))
    nan = np.load(poses)
    nan[1, 0, 0] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    common = ["--out", str(good), "-q"]
    cases = [
        (["--volume", ct, "--poses", poses, "--preset", "nope"], "--preset nope: unknown (presets: abdominal"),
    ] + [(["--preset", "lus", *args], needle) for args, needle in [
        (["--volume", ct, "--poses", poses, "--tgc", "on"], "--tgc on: expected auto or off"),
        (["--volume", ct, "--poses", poses, "--output", "rf"], "--output rf: expected bmode or envelope"),
        (["--volume", ct, "--poses", poses, "--device", "tpu"], "device 'tpu': expected cpu, cuda or cuda:K"),
        (["--volume", ct, "--poses", poses, "--frequency", "0"], "frequency 0"),
        (["--volume", ct, "--poses", poses, "--dynamic-range", "-3"], "dynamic range -3"),
        (["--volume", ct, "--tissues", str(partial), "--poses", poses], "--tissues is for --labels"),
        (["--labels", labels, "--tissues", str(tmp_path / "none.json"), "--poses", poses], "none.json"),
        (["--labels", labels, "--tissues", str(bad_table), "--poses", poses], 'missing "scatter_mean"'),
        (["--labels", labels, "--tissues", str(partial), "--poses", poses],
         f"--labels '{labels}' holds label 0, which --tissues '{partial}' does not list"),
        (["--labels", labels, "--poses", poses], "which the default tissue table (--print-tissues; give --tissues)"),
        (["--labels", ct, "--poses", poses], "uint8 or uint16, this one is int16"),
        (["--meshes", str(tmp_path / "a.stl"), "--poses", poses], "--meshes: give --tissues"),
        (["--volume", ct, "--poses", str(tmp_path / "nan.npy")], "pose 1"),
        (["--volume", str(tmp_path / "missing.nii.gz"), "--poses", poses], "missing.nii.gz"),
    ]]
    for args, needle in cases:
        r = run(cli, "simulate", *common, *args)
        one_line_error(r, needle)
        assert good.read_bytes() == before, args
    # What is missing is a usage error (2), with a pointer to the command's help.
    r = run(cli, "simulate", "--volume", ct, "--poses", poses, "--out", str(tmp_path / "x.npy"))
    one_line_error(r, "give --probe or --preset", status=2)
    r = run(cli, "simulate", *common, "--preset", "lus", "--volume", ct, "--labels", labels, "--poses", poses)
    one_line_error(r, "exactly one of --volume, --labels, --meshes; see 'sonoslice simulate --help'", status=2)
    for args, needle in [(["--volume", ct, "--out", str(good)], "--poses is required"),
                         (["--volume", ct, "--poses", poses], "--out is required")]:
        one_line_error(run(cli, "simulate", "--preset", "lus", *args), needle, status=2)
    assert sorted(os.listdir(tmp_path)) == ["bad.json", "good.npy", "nan.npy", "partial.json"]


# ---- Python: sonoslice.Simulator ---------------------------------------------------------------
def test_python_simulator_ct_labels_and_out(phantom, poses):
    import sonoslice
    ct, labels = phantom
    sim = sonoslice.Simulator(ct, "lus", seed=4)
    assert sim.kind == "ct" and sim.frequency == 6.5
    images = sim.simulate(poses[:3])
    assert images.shape == (3, sim.height, sim.width) == (3, 272, 334) and images.dtype == np.uint8
    assert np.array_equal(sim.mask, sonoslice.Slicer(ct, sonoslice.Probe.workload("W1")).mask)
    # In place, zero-copy, and the same bytes again.
    out = np.zeros_like(images)
    assert sim.simulate(poses[:3], out=out) is out
    assert np.array_equal(out, images)
    env = sim.simulate(poses[:3], output="envelope")
    assert env.dtype == np.float32 and (env >= 0).all()
    # Labels with the phantom's table: the kind follows from the table.
    lab = sonoslice.Simulator(labels, sonoslice.Probe.workload("W1"), tissues=sonoslice.phantom_tissues(),
                              frequency=6.5, seed=4)
    assert lab.kind == "labels"
    li = lab.simulate(poses[:3])
    assert li.shape == images.shape and li[:, lab.mask == 1].std() > 5


def test_python_simulator_on_the_gpu(phantom, poses, cuda):
    import sonoslice
    ct, _ = phantom
    cpu = sonoslice.Simulator(ct, "lus", seed=4).simulate(poses[:4])
    sim = sonoslice.Simulator(ct, "lus", seed=4, device=cuda)
    assert sim.settings.device == "cuda:0"
    gpu = sim.simulate(poses[:4])
    assert gpu.shape == cpu.shape and gpu.dtype == np.uint8
    diff = np.abs(cpu.astype(int) - gpu.astype(int))[:, sim.mask == 1]
    assert (diff > 1).mean() <= 0.005 and diff.mean() < 0.05, ((diff > 1).mean(), diff.mean())
    assert np.array_equal(sim.simulate(poses[:4]), gpu)  # the same bytes every run


def test_python_simulator_bad_input(phantom, poses, tmp_path):
    import sonoslice
    ct, labels = phantom
    with pytest.raises(ValueError, match="tpu"):
        sonoslice.Simulator(ct, "lus", device="tpu")
    with pytest.raises(ValueError, match="^preset nope: unknown"):  # the setting, not the CLI's --preset
        sonoslice.Simulator(ct, "nope")
    with pytest.raises(ValueError, match="holds label 0, which the tissue table does not list"):
        sonoslice.Simulator(labels, "lus", tissues=sonoslice.default_tissues())
    bad = [dict(t) for t in sonoslice.phantom_tissues()]
    bad[2]["impedance_mrayl"] = -1
    with pytest.raises(ValueError, match="impedance_mrayl -1 must be > 0 and <= 1000$"):
        sonoslice.Simulator(labels, "lus", tissues=bad)
    sim = sonoslice.Simulator(ct, "lus")
    p = np.array(poses[:2])
    p[1, 0, 0] = np.nan
    out = np.full((2, sim.height, sim.width), 7, np.uint8)
    with pytest.raises(ValueError, match="pose 1"):
        sim.simulate(p, out=out)
    assert (out == 7).all()
    with pytest.raises(ValueError, match="output 'rf'"):
        sim.simulate(poses[:1], output="rf")
    with pytest.raises(ValueError, match="out: expected shape"):
        sim.simulate(poses[:2], out=np.zeros((1, sim.height, sim.width), np.uint8))
    table = tmp_path / "t.json"
    table.write_text("{not json")
    with pytest.raises(OSError, match="invalid JSON"):
        sonoslice.Simulator(labels, "lus", tissues=table)


def test_simulate_meshes(cli, shared, tmp_path):
    """fan-slicer's liver and arteries as meshes: label 0 outside, 1 liver, 2 arteries (blood)."""
    import sonoslice
    table = tmp_path / "t.json"
    table.write_text(json.dumps({"tissues": [
        {"name": "soft tissue", "label": 0, "impedance_mrayl": 1.63, "attenuation_db_cm_mhz": 0.54, "scatter_mean": 0.02},
        {"name": "liver", "label": 1, "impedance_mrayl": 1.65, "attenuation_db_cm_mhz": 0.5, "scatter_mean": 0.03},
        {"name": "arteries", "label": 2, "impedance_mrayl": 1.61, "attenuation_db_cm_mhz": 0.18, "scatter_mean": 0.0},
    ]}))
    liver = os.path.join(shared, "liver.vtk")
    lo, hi = np.array(sonoslice.Mesh.from_file(liver).bounds)
    pose = np.eye(4)
    pose[:3, 3] = (lo + hi) / 2 + [0, -60, 0]
    np.save(tmp_path / "p.npy", pose[None])
    r = run(cli, "simulate", "--meshes", liver, os.path.join(shared, "arteries.vtk"), "--tissues", str(table),
            "--preset", "lus", "--poses", str(tmp_path / "p.npy"), "--out", str(tmp_path / "m.npy"), "-q")
    assert r.returncode == 0, r.stderr
    img = np.load(tmp_path / "m.npy")
    assert img.shape == (1, 272, 334) and img.std() > 5
    # A mesh the table has no tissue for is named by its file.
    short = tmp_path / "short.json"
    short.write_text(json.dumps({"tissues": json.loads(table.read_text())["tissues"][:2]}))
    r = run(cli, "simulate", "--meshes", liver, os.path.join(shared, "arteries.vtk"), "--tissues", str(short),
            "--preset", "lus", "--poses", str(tmp_path / "p.npy"), "--out", str(tmp_path / "m2.npy"), "-q")
    one_line_error(r, f"--meshes '{os.path.join(shared, 'arteries.vtk')}' is label 2, which --tissues '{short}'")
    assert not (tmp_path / "m2.npy").exists()


def test_python_simulator_takes_settings_or_keywords(phantom, poses):
    """settings= (a SimulationSettings) is the same simulation as its keywords, its output is the
    default output, and giving both is refused (as register() does)."""
    import sonoslice
    ct, _ = phantom
    p = poses[:2]
    settings = sonoslice.SimulationSettings(seed=3, dynamic_range_db=50)
    a = sonoslice.Simulator(ct, "lus", settings=settings).simulate(p)
    b = sonoslice.Simulator(ct, "lus", seed=3, dynamic_range=50).simulate(p)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, sonoslice.Simulator(ct, "lus", seed=4, dynamic_range=50).simulate(p))
    envelope = sonoslice.SimulationSettings(output=sonoslice.SimulationOutput.envelope)
    assert sonoslice.Simulator(ct, "lus", settings=envelope).simulate(p).dtype == np.float32
    with pytest.raises(TypeError, match="not both"):
        sonoslice.Simulator(ct, "lus", seed=1, settings=settings)
    with pytest.raises(TypeError, match="SimulationSettings"):
        sonoslice.Simulator(ct, "lus", settings={"seed": 1})
