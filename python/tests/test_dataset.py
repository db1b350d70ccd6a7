"""sonoslice dataset: SPEC → WebDataset shards + manifest, and sonoslice.data.

The contract checked here: every shard is a pure function of (SPEC, shard index), so runs, worker
counts (one process or Dask local:2) and write orders give the same bytes; an interrupted run
resumes to the same manifest; bad SPECs stop with one line naming the input and leave nothing;
--dry-run writes nothing. The samplers' own behaviour is tested on the C++ side.
"""
import hashlib
import json
import os
import signal
import subprocess
import sys
import tarfile
import time

import numpy as np
import pytest

import sonoslice
from sonoslice import dataset as ds

from conftest import DATA

LUS = os.path.join(DATA, "fanslicer", "models_intensity_LUS_config.json")


def run(*args, cwd=None, timeout=600):
    """``python -m sonoslice dataset ARGS`` (what ``sonoslice dataset`` runs)."""
    return subprocess.run([sys.executable, "-m", "sonoslice", "dataset", *map(str, args)], capture_output=True,
                          encoding="utf-8", errors="replace", timeout=timeout, cwd=cwd)


def one_line_error(r, *needles):
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert r.stderr.startswith("sonoslice: error: ") and r.stderr.count("\n") == 1, r.stderr
    for needle in needles:
        assert needle in r.stderr, r.stderr


@pytest.fixture(scope="module")
def volumes(tmp_path_factory):
    """The small phantom's CT and labels as files (the SPECs name files)."""
    d = tmp_path_factory.mktemp("dataset_inputs")
    ct, labels = sonoslice.phantom("small")
    ct.save(str(d / "ct.nii.gz"))
    labels.save(str(d / "labels.nii.gz"))
    return d


def spec_text(inputs, samplers, **top):
    """A SPEC (JSON text) on the small phantom (files in ``inputs``) with fan-slicer's LUS probe at
    downsampling 4; ``top``: top-level keys to add or replace."""
    spec = {"seed": 11, "shard_samples": 7,
            "volumes": [{"id": "ph", "ct": str(inputs / "ct.nii.gz"), "labels": str(inputs / "labels.nii.gz")}],
            "probes": [{"id": "lus", "file": LUS, "downsampling": 4}],
            "samplers": samplers}
    spec.update(top)
    return json.dumps(spec, indent=1)


def write_spec(path, text):
    path.write_text(text)
    return path


SKIN = {"type": "skin", "volume": "ph", "probe": "lus", "tilt_deg": [-15, 15], "reject": {"min_inside": 0.5}}
MIXED = [
    dict(SKIN, count=10, images=["intensity", "labels", "colours", "ultrasound"]),
    {"type": "sweep", "volume": "ph", "probe": "lus", "count": 11, "frames": 4, "step": 2, "from": {"type": "skin"}},
    {"type": "region", "volume": "ph", "probe": "lus", "count": 5, "label": 3,
     "images": [{"kind": "intensity", "dtype": "int16"}]},
]


@pytest.fixture(scope="module")
def mixed(volumes, tmp_path_factory):
    """A SPEC with three samplers (skin with every image kind, a sweep, a region) and its dataset
    written once in this process: the reference the other tests compare with."""
    d = tmp_path_factory.mktemp("dataset_mixed")
    spec = write_spec(d / "mixed.json", spec_text(volumes, MIXED))
    manifest = ds.write_dataset(spec, d / "ref", progress=False)
    return spec, d / "ref", manifest


def shard_bytes(folder):
    return {n: (folder / n).read_bytes() for n in sorted(os.listdir(folder)) if n.endswith(".tar")}


def members(path):
    with tarfile.open(path) as tar:
        return [(m, tar.extractfile(m).read()) for m in tar.getmembers()]


# ---- layout ----------------------------------------------------------------------------------------
def test_manifest_and_shards(mixed):
    spec, out, manifest = mixed
    assert manifest["samples"] == 26 and manifest["images"] == 10 * 4 + 11 + 5
    assert manifest["sonoslice"] == sonoslice.__version__
    assert manifest["spec"] == json.loads(spec.read_text())
    names = [s["name"] for s in manifest["shards"]]
    assert names == [f"shard-{k:06d}.tar" for k in range(4)]
    assert [s["samples"] for s in manifest["shards"]] == [7, 7, 7, 5]
    assert json.loads((out / "manifest.json").read_text()) == manifest
    for s in manifest["shards"]:
        data = (out / s["name"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == s["sha256"] and len(data) == s["bytes"]
    assert sorted(n for n in os.listdir(out) if not n.startswith(".")) == ["manifest.json"] + names


def test_sample_members_are_deterministic_tar_entries(mixed):
    _, out, _ = mixed
    entries = members(out / "shard-000000.tar")
    assert [m.name for m, _ in entries[:6]] == ["00000000.json", "00000000.intensity.npy", "00000000.labels.npy",
                                                "00000000.colours.npy", "00000000.ultrasound.npy", "00000001.json"]
    for m, _ in entries:
        assert (m.mtime, m.uid, m.gid, m.uname, m.gname, m.mode) == (0, 0, 0, "", "", 0o644)
    # shard 1 holds samples 7..13: the skin sampler's last three, then the sweep's first four frames
    keys = sorted({m.name.split(".")[0] for m, _ in members(out / "shard-000001.tar")})
    assert keys == [f"{i:08d}" for i in range(7, 14)]


def test_sample_json_reproduces_the_sample(mixed, volumes):
    """Each sample's JSON holds what makes it again: the pose is PoseSampler's for the recorded
    seed, the images are the Slicer's and Simulator's at that pose."""
    spec_path, out, _ = mixed
    spec = ds.load_spec(spec_path)
    ct, labels = sonoslice.Volume.from_file(str(volumes / "ct.nii.gz")), sonoslice.Volume.from_file(
        str(volumes / "labels.nii.gz"))
    probe = sonoslice.Probe.from_json(LUS, 4)
    files = dict((m.name, data) for m, data in members(out / "shard-000001.tar"))
    meta = json.loads(files["00000008.json"])
    assert meta["index"] == 8 and meta["volume"] == "ph" and meta["probe"] == "lus"
    assert meta["sampler"] == {"index": 0, "type": "skin"} and "frame" not in meta
    assert meta["images"] == ["intensity", "labels", "colours", "ultrasound"]
    assert meta["seed"] == int(sonoslice.sample_seeds(11, 0, 8, 1)[0])
    pose = np.array(meta["pose"])
    sampler = sonoslice.PoseSampler(spec.samplers[0].config, probe, volume=ct, labels=labels)
    np.testing.assert_array_equal(pose, sampler.sample([meta["seed"]])[0])
    load = lambda name: np.load(__import__("io").BytesIO(files[name]))  # noqa: E731
    np.testing.assert_array_equal(load("00000008.intensity.npy"), sonoslice.Slicer(ct, probe).slice(pose)[0])
    lab = sonoslice.Slicer(labels, probe, interpolation="nearest", dtype="uint8").slice(pose)
    np.testing.assert_array_equal(load("00000008.labels.npy"), lab[0])
    np.testing.assert_array_equal(load("00000008.colours.npy"), sonoslice.colorize(lab, probe.mask)[0])
    np.testing.assert_array_equal(load("00000008.ultrasound.npy"),
                                  sonoslice.Simulator(ct, probe, seed=11).simulate(pose)[0])
    assert load("00000008.colours.npy").shape == lab.shape[1:] + (3,)


def test_sweep_samples_are_frames_of_seeded_sweeps(mixed, volumes):
    """Sweep sampler (4 frames a seed, 11 samples): sample i is frame i % 4 of sweep i // 4, and
    records the sweep's seed; the last sweep is cut short by the count."""
    spec_path, out, _ = mixed
    spec = ds.load_spec(spec_path)
    metas = {}
    for k in range(4):
        for m, data in members(out / f"shard-{k:06d}.tar"):
            if m.name.endswith(".json"):
                metas[int(m.name[:8])] = json.loads(data)
    sweep = [metas[i] for i in range(10, 21)]
    assert [m["frame"] for m in sweep] == [0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2]
    assert [m["sampler"] for m in sweep] == [{"index": 1, "type": "sweep"}] * 11
    seeds = sonoslice.sample_seeds(11, 1, 0, 3)
    assert [m["seed"] for m in sweep] == [int(seeds[i // 4]) for i in range(11)]
    ct = sonoslice.Volume.from_file(str(volumes / "ct.nii.gz"))
    sampler = sonoslice.PoseSampler(spec.samplers[1].config, sonoslice.Probe.from_json(LUS, 4), volume=ct)
    np.testing.assert_array_equal(np.array([m["pose"] for m in sweep]), sampler.sample(seeds)[:11])
    assert [metas[i]["sampler"]["type"] for i in range(21, 26)] == ["region"] * 5


def test_png_images(volumes, tmp_path):
    """image_format png: intensity as uint16, labels and colours as PNGs that decode to the pixels."""
    samplers = [dict(SKIN, count=3, images=[{"kind": "intensity", "dtype": "uint16"}, "labels", "colours"])]
    spec = write_spec(tmp_path / "png.json", spec_text(volumes, samplers, image_format="png"))
    ds.write_dataset(spec, tmp_path / "out", progress=False)
    files = dict((m.name, data) for m, data in members(tmp_path / "out" / "shard-000000.tar"))
    assert sorted(files) == sorted(f"{i:08d}.{x}" for i in range(3) for x in
                                   ("json", "intensity.png", "labels.png", "colours.png"))
    from sonoslice.data import decode_png
    pose = np.array(json.loads(files["00000002.json"])["pose"])
    ct = sonoslice.Volume.from_file(str(volumes / "ct.nii.gz"))
    probe = sonoslice.Probe.from_json(LUS, 4)
    intensity = decode_png(files["00000002.intensity.png"])
    assert intensity.dtype == np.uint16 and files["00000002.intensity.png"][24] == 16  # bit depth 16
    np.testing.assert_array_equal(intensity, sonoslice.Slicer(ct, probe, dtype="uint16").slice(pose)[0])
    assert decode_png(files["00000002.colours.png"]).shape == (probe.height, probe.width, 3)


def test_png_intensity_through_a_window(volumes, tmp_path):
    """window [level, width] on uint8 intensity: the CT's values (sliced as float32) from level -
    width/2 to level + width/2 spread over 0..255, rounded half up and saturated, as `slice
    --window` writes PNGs; HU below 0 are no longer all 0."""
    window = [40, 400]
    samplers = [dict(SKIN, count=3, images=[{"kind": "intensity", "dtype": "uint8", "window": window}])]
    spec = write_spec(tmp_path / "png.json", spec_text(volumes, samplers, image_format="png"))
    ds.write_dataset(spec, tmp_path / "out", progress=False)
    files = dict((m.name, data) for m, data in members(tmp_path / "out" / "shard-000000.tar"))
    from sonoslice.data import decode_png
    ct = sonoslice.Volume.from_file(str(volumes / "ct.nii.gz"))
    probe = sonoslice.Probe.from_json(LUS, 4)
    for i in range(3):
        pose = np.array(json.loads(files[f"{i:08d}.json"])["pose"])
        values = sonoslice.Slicer(ct, probe, dtype="float32").slice(pose)[0].astype(np.float64)
        want = np.floor(np.clip((values - (window[0] - window[1] / 2)) * (255 / window[1]), 0, 255) + 0.5)
        got = decode_png(files[f"{i:08d}.intensity.png"])
        assert got.dtype == np.uint8
        np.testing.assert_array_equal(got, want.astype(np.uint8))
        fan = probe.mask.astype(bool)
        assert len(np.unique(got[fan])) > 20  # a spread of greys inside the fan, not 0 and 255


def test_png_codec_round_trip():
    rng = np.random.default_rng(0)
    from sonoslice.data import decode_png
    for image in (rng.integers(0, 256, (5, 7), dtype=np.uint8), rng.integers(0, 65536, (4, 3), dtype=np.uint16),
                  rng.integers(0, 256, (6, 2, 3), dtype=np.uint8)):
        back = decode_png(ds.encode_png(image))
        assert back.dtype == image.dtype
        np.testing.assert_array_equal(back, image)
        assert ds.encode_png(image) == ds.encode_png(image.copy())  # bytes are the pixels'
    good = ds.encode_png(np.zeros((4, 4), np.uint8))
    for bad, needle in ((good[:40], "truncated"), (b"GIF89a", "not a PNG")):
        with pytest.raises(ValueError, match=needle):
            decode_png(bad)
    with pytest.raises(ValueError, match="uint8 or uint16"):
        ds.encode_png(np.zeros((3, 3), np.float32))


# ---- determinism -----------------------------------------------------------------------------------
def test_same_bytes_across_runs_workers_and_order(mixed, tmp_path):
    """A second run, a Dask local:2 run (the CLI) and shards written in reverse order by
    write_shard all give the reference's bytes, shard by shard, and the same manifest."""
    spec_path, ref, manifest = mixed
    reference = shard_bytes(ref)
    ds.write_dataset(spec_path, tmp_path / "again", progress=False)
    assert shard_bytes(tmp_path / "again") == reference
    r = run(spec_path, "--out", tmp_path / "dask", "--scheduler", "local:2", "-q")
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert shard_bytes(tmp_path / "dask") == reference
    assert json.loads((tmp_path / "dask" / "manifest.json").read_text()) == manifest
    spec = ds.load_spec(spec_path)
    (tmp_path / "reverse").mkdir()
    entries = [ds.write_shard(spec, k, tmp_path / "reverse") for k in reversed(range(spec.shards))]
    assert shard_bytes(tmp_path / "reverse") == reference
    assert entries[::-1] == manifest["shards"]


def test_threads_do_not_change_bytes(mixed, tmp_path):
    spec_path, ref, _ = mixed
    r = run(spec_path, "--out", tmp_path / "one", "--threads", "1", "-q")
    assert r.returncode == 0, r.stderr
    assert shard_bytes(tmp_path / "one") == shard_bytes(ref)


# ---- resuming --------------------------------------------------------------------------------------
def test_resume_rewrites_only_damaged_shards(mixed, tmp_path):
    """Truncated, deleted and leftover-temporary shards are made again; intact ones are kept
    untouched; the manifest comes out identical."""
    spec_path, ref, manifest = mixed
    out = tmp_path / "out"
    ds.write_dataset(spec_path, out, progress=False)
    kept = os.stat(out / "shard-000000.tar")
    with open(out / "shard-000001.tar", "r+b") as f:
        f.truncate(1000)
    os.remove(out / "shard-000002.tar")
    (out / "shard-000003.tar.0123.tmp").write_bytes(b"partial")
    os.remove(out / "manifest.json")
    r = run(spec_path, "--out", out, "-q")
    assert r.returncode == 0, r.stderr
    assert shard_bytes(out) == shard_bytes(ref)
    assert json.loads((out / "manifest.json").read_text()) == manifest
    assert not [n for n in os.listdir(out) + os.listdir(out / ".checksums") if n.endswith(".tmp")]
    after = os.stat(out / "shard-000000.tar")
    assert (after.st_ino, after.st_mtime_ns) == (kept.st_ino, kept.st_mtime_ns)


def slow_spec(volumes, tmp_path):
    """A SPEC of 60 small shards with simulated ultrasound: a run of a few seconds to interrupt."""
    samplers = [dict(SKIN, count=600, images=["intensity", "ultrasound"])]
    return write_spec(tmp_path / "slow.json", spec_text(volumes, samplers, shard_samples=10))


def start_and_interrupt(spec, out, signum):
    """Starts a run, and sends ``signum`` once two shards are complete; its exit status and
    stderr."""
    proc = subprocess.Popen([sys.executable, "-m", "sonoslice", "dataset", str(spec), "--out", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / "shard-000001.tar").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=60)
    return proc.returncode, stderr


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGTERM])
def test_resume_after_an_interrupted_run(volumes, tmp_path, signum):
    spec = slow_spec(volumes, tmp_path)
    out = tmp_path / "out"
    status, stderr = start_and_interrupt(spec, out, signum)
    assert status == -signum
    assert not (out / "manifest.json").exists(), "the run ended before it was interrupted"
    if signum == signal.SIGTERM:  # the temporaries are removed on the way out, and one line said so
        assert not [n for n in os.listdir(out) if n.endswith(".tmp")]
        assert stderr == "sonoslice: terminated; run the same command again to resume\n"
    done = {n: os.stat(out / n).st_mtime_ns for n in os.listdir(out) if n.endswith(".tar")}
    assert done, "no shard was complete when the run was interrupted"
    r = run(spec, "--out", out, "-q")
    assert r.returncode == 0, r.stderr
    ds.write_dataset(spec, tmp_path / "ref", progress=False)
    assert shard_bytes(out) == shard_bytes(tmp_path / "ref")
    assert (out / "manifest.json").read_bytes() == (tmp_path / "ref" / "manifest.json").read_bytes()
    assert all(os.stat(out / n).st_mtime_ns == t for n, t in done.items())


def test_refuses_a_folder_of_another_dataset(mixed, volumes, tmp_path):
    spec_path, ref, _ = mixed
    out = tmp_path / "out"
    ds.write_dataset(spec_path, out, progress=False)
    before = shard_bytes(out)
    other = write_spec(tmp_path / "other.json", spec_text(volumes, MIXED, seed=12))
    one_line_error(run(other, "--out", out), "another SPEC", str(out))
    os.remove(out / "manifest.json")  # an interrupted run of the other SPEC: its shards' records say so
    one_line_error(run(other, "--out", out), "shard-000000.tar belongs to another SPEC")
    assert shard_bytes(out) == before


def test_a_changed_input_file_is_not_mixed_with_shards_of_the_old_one(volumes, tmp_path):
    import shutil
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    for name in ("ct.nii.gz", "labels.nii.gz"):
        shutil.copy(volumes / name, inputs / name)
    spec = write_spec(inputs / "s.json", spec_text(inputs, [dict(SKIN, count=8)]).replace(str(inputs) + "/", ""))
    out = tmp_path / "out"
    r = run(spec, "--out", out, "-q")
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(manifest["inputs"]) == {"ct.nii.gz", "labels.nii.gz", LUS}
    assert all(len(sha) == 64 for sha in manifest["inputs"].values())
    before = shard_bytes(out)
    ct = sonoslice.Volume.from_file(str(inputs / "ct.nii.gz"))
    sonoslice.Volume(ct.array + 1, ct.spacing, ct.origin, ct.direction).save(str(inputs / "ct.nii.gz"))
    one_line_error(run(spec, "--out", out), "holds this SPEC's dataset made from another 'ct.nii.gz'")
    os.remove(out / "manifest.json")  # an interrupted run of the old inputs: its records say so
    one_line_error(run(spec, "--out", out), "shard-000000.tar belongs to another SPEC, other input files")
    assert shard_bytes(out) == before


# ---- bad SPECs ---------------------------------------------------------------------------------------
def bad(volumes, tmp_path, text, name="bad.json"):
    spec = write_spec(tmp_path / name, text)
    out = tmp_path / "out"
    start = time.monotonic()
    r = run(spec, "--out", out)
    assert time.monotonic() - start < 60
    assert not out.exists(), os.listdir(out)
    return r, spec


def test_missing_files(volumes, tmp_path):
    text = spec_text(volumes, [dict(SKIN, count=3)]).replace(str(volumes / "ct.nii.gz"), "nowhere/ct.nii.gz")
    r, spec = bad(volumes, tmp_path, text)
    one_line_error(r, f"SPEC '{spec}'", "volumes[0]: ct: no such file 'nowhere/ct.nii.gz'")
    r = run(tmp_path / "absent.yaml", "--out", tmp_path / "out")
    one_line_error(r, "absent.yaml", "no such file")


def test_unknown_keys_are_named_with_their_place(volumes, tmp_path):
    cases = [
        ({"sed": 3}, "unknown key 'sed'"),
        ({"volumes": [{"id": "ph", "ct": str(volumes / "ct.nii.gz"), "label": "x"}]},
         "volumes[0]: unknown key 'label'"),
        ({"probes": [{"id": "lus", "file": LUS, "downsample": 2}]}, "probes[0]: unknown key 'downsample'"),
        ({"images": [{"kind": "intensity", "type": "float32"}]}, "images[0]: unknown key 'type'"),
    ]
    for top, needle in cases:
        r, spec = bad(volumes, tmp_path, spec_text(volumes, [dict(SKIN, count=3)], **top))
        one_line_error(r, f"SPEC '{spec}': ", needle)
    # the sampler's own parameters are PoseSampler's to check
    r, spec = bad(volumes, tmp_path, spec_text(volumes, [dict(SKIN, count=3, tilt=[0, 5])]))
    one_line_error(r, f"SPEC '{spec}': samplers[0]: unknown key 'tilt'")


def test_bad_values(volumes, tmp_path):
    cases = [
        ([dict(SKIN, count=0)], {}, "samplers[0]: count 0"),
        ([dict(SKIN, count=3, volume="liver")], {}, "samplers[0]: volume 'liver': no such id"),
        ([dict(SKIN, count=3)], {"shard_samples": "many"}, "shard_samples 'many'"),
        ([dict(SKIN, count=3)], {"image_format": "jpg"}, "image_format 'jpg'"),
        ([dict(SKIN, count=3)], {"images": ["x-ray"]}, "images[0]: kind 'x-ray'"),
        ([dict(SKIN, count=3)], {"image_format": "png", "images": ["intensity"]}, "intensity as png needs"),
        ([dict(SKIN, count=3)], {"images": [{"kind": "intensity", "dtype": "uint16", "window": [40, 400]}]},
         "images[0]: window: only intensity images of dtype uint8"),
        ([dict(SKIN, count=3)], {"images": [{"kind": "intensity", "dtype": "uint8", "window": [40, 0]}]},
         "images[0]: window [40, 0]: expected [level, width]"),
        ([dict(SKIN, count=3)], {"images": [{"kind": "labels", "window": [40, 400]}]},
         "images[0]: window: only intensity images"),
        ([dict(SKIN, count=3, images=["labels"])],
         {"volumes": [{"id": "ph", "ct": str(volumes / "ct.nii.gz")}]}, "'labels' needs labels"),
    ]
    for samplers, top, needle in cases:
        r, _ = bad(volumes, tmp_path, spec_text(volumes, samplers, **top))
        one_line_error(r, needle)
    r, spec = bad(volumes, tmp_path, "volumes: [\n", name="broken.yaml")
    one_line_error(r, f"SPEC '{spec}': not valid YAML")
    # Nested deeper than Python's parsers recurse: named, not a bare RecursionError.
    r, spec = bad(volumes, tmp_path, "samplers: " + "[" * 100000 + "]" * 100000, name="deep.yaml")
    one_line_error(r, f"SPEC '{spec}': not valid YAML (nested too deep to read)")
    r, spec = bad(volumes, tmp_path, '{"samplers": ' + "[" * 100000 + "]" * 100000 + "}", name="deep.json")
    one_line_error(r, f"SPEC '{spec}': not valid JSON (nested too deep to read)")


def test_impossible_rejection_rule_stops_after_bounded_tries(volumes, tmp_path):
    """No point of a CT is 5000 HU: the gas rule can never pass; the run stops after max_tries
    candidates with one line, and writes nothing."""
    sampler = dict(SKIN, count=50, reject={"no_gas": True, "gas_hu": 5000}, max_tries=300)
    r, spec = bad(volumes, tmp_path, spec_text(volumes, [sampler]))
    one_line_error(r, f"SPEC '{spec}': samplers[0]", "300 tries")


def test_scheduler_errors(mixed, tmp_path, monkeypatch):
    spec_path, _, _ = mixed
    one_line_error(run(spec_path, "--out", tmp_path / "o", "--scheduler", "local:0"), "--scheduler 'local:0'")
    one_line_error(run(spec_path, "--out", tmp_path / "o", "--scheduler", "cluster"), "--scheduler 'cluster'")
    one_line_error(run(spec_path, "--out", tmp_path / "o", "--scheduler", "tcp://127.0.0.1:notaport"),
                   "--scheduler 'tcp://127.0.0.1:notaport': expected a Dask scheduler address tcp://HOST:PORT")
    import socket
    with socket.socket() as s:  # a port that was free a moment ago: nothing listens there now
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    pytest.importorskip("distributed")
    start = time.monotonic()
    with pytest.raises(OSError, match=f"^--scheduler 'tcp://127.0.0.1:{port}': cannot connect \\(nothing listens there\\)"):
        ds.write_dataset(spec_path, tmp_path / "o", scheduler=f"tcp://127.0.0.1:{port}", progress=False)
    assert time.monotonic() - start < 10
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if Dask were not installed
    with pytest.raises(RuntimeError, match="needs Dask's distributed package"):
        ds.write_dataset(spec_path, tmp_path / "o", scheduler="local:2", progress=False)
    assert not (tmp_path / "o" / "manifest.json").exists()


def test_usage_errors(mixed):
    spec_path, _, _ = mixed
    r = run(spec_path)  # no --out
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--out" in r.stderr and "--help" in r.stderr, r.stderr
    r = run(spec_path, "--out", "x", "--bogus")
    assert r.returncode == 2 and "--bogus" in r.stderr, r.stderr


# ---- dry run, CLI -------------------------------------------------------------------------------------
def test_dry_run_prints_the_plan_and_writes_nothing(mixed, tmp_path):
    spec_path, ref, manifest = mixed
    out = tmp_path / "out"
    r = run(spec_path, "--out", out, "--dry-run")
    assert r.returncode == 0, r.stderr
    assert not out.exists()
    text = r.stdout
    assert "26 samples in 4 shards of up to 7" in text
    assert "images: 56 (npy)" in text
    assert "samplers[1] sweep: 11 samples (global 10..20)" in text
    assert "estimated size: " in text and "estimated time: " in text
    p = ds.plan(spec_path)
    real = sum(s["bytes"] for s in manifest["shards"])
    assert 0.8 * real < p.estimated_bytes < 1.25 * real
    assert p.estimated_seconds > 0 and p.batch == {0: 10, 1: 11, 2: 5}


def test_the_cli_command_runs_the_package(cli, mixed, tmp_path):
    """`sonoslice dataset` (the C++ CLI) hands its arguments to `python -m sonoslice dataset`."""
    spec_path, ref, _ = mixed
    env = dict(os.environ, SONOSLICE_PYTHON=sys.executable)
    r = subprocess.run([cli, "dataset", str(spec_path), "--out", str(tmp_path / "out")], capture_output=True,
                       text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr
    assert shard_bytes(tmp_path / "out") == shard_bytes(ref)
    assert r.stderr.rstrip().splitlines()[-1].startswith("sonoslice: 26 samples (56 images) in 4 shards")


def test_example_spec_is_complete(tmp_path):
    """docs/dataset_example.yaml: every key it uses is known, it uses the skin sampler, and its
    paths resolve once the phantom it names is written (the PoseSampler checks are run)."""
    example = os.path.join(os.path.dirname(DATA), "docs", "dataset_example.yaml")
    import yaml
    with open(example) as f:
        data = yaml.safe_load(f)
    assert data["samplers"][0]["type"] == "skin"
    ct, labels = sonoslice.phantom("small")
    (tmp_path / "phantom").mkdir()
    ct.save(str(tmp_path / "phantom" / "ct.nii.gz"))
    labels.save(str(tmp_path / "phantom" / "labels.nii.gz"))
    data["probes"][0]["file"] = os.path.join(os.path.dirname(example), data["probes"][0]["file"])
    copy = write_spec(tmp_path / "example.json", json.dumps(data))
    spec = ds.load_spec(copy)
    ds.check_inputs(spec)
    assert spec.samplers[0].count == 20000 and spec.shards == 20


# ---- training side -----------------------------------------------------------------------------------
def test_shard_dataset_splits_shards_over_workers(mixed):
    torch = pytest.importorskip("torch")
    from torch.utils.data import DataLoader
    from sonoslice.data import ShardDataset
    _, out, _ = mixed
    seen = []
    for images, poses, meta in DataLoader(ShardDataset(out, kinds="intensity"), batch_size=4, num_workers=2):
        assert images.dtype in (torch.float32, torch.int16) and poses.shape[1:] == (4, 4)
        assert poses.dtype == torch.float64
        seen += meta["index"].tolist()
    assert sorted(seen) == list(range(26))  # every sample once
    first = next(iter(ShardDataset(out)))
    images, pose, meta = first
    assert set(images) == {"intensity", "labels", "colours", "ultrasound"}
    assert images["colours"].shape[-1] == 3 and meta["frame"] == -1
    assert meta["seed"] == str(sonoslice.sample_seeds(11, 0, 0, 1)[0])
    shuffled = [m["index"] for _, _, m in ShardDataset(out, kinds=["intensity"], shuffle=True, buffer=5, seed=1)]
    assert sorted(shuffled) == list(range(26)) and shuffled != list(range(26))


def test_webdataset_pipeline_of_the_docs_reads_the_same(mixed):
    """The plain webdataset pipeline of docs/datasets.md §6 gives ShardDataset's samples."""
    wds = pytest.importorskip("webdataset")
    from sonoslice.data import ShardDataset
    _, out, manifest = mixed
    urls = [str(out / s["name"]) for s in manifest["shards"]]
    pipeline = wds.WebDataset(urls, shardshuffle=False).decode().to_tuple("intensity.npy", "json")
    ours = list(ShardDataset(out, kinds="intensity"))
    theirs = list(pipeline)
    assert len(theirs) == len(ours) == 26
    for (image, meta), (tensor, pose, _) in zip(theirs, ours):
        np.testing.assert_array_equal(image, tensor.numpy())
        np.testing.assert_array_equal(np.array(meta["pose"]), pose.numpy())


def test_shard_dataset_names_a_damaged_shard(mixed, tmp_path):
    """A shard cut at a sample boundary (fewer samples than the manifest says), cut mid-member, or
    replaced by garbage: ValueError naming the shard, not a silent short epoch or a bare tarfile error."""
    pytest.importorskip("torch")
    import shutil
    from sonoslice.datasets.reader import ShardDataset, read_shard
    _, ref, manifest = mixed
    copy = tmp_path / "copy"
    shutil.copytree(ref, copy)
    first = copy / manifest["shards"][0]["name"]
    with tarfile.open(ref / manifest["shards"][0]["name"]) as tar:
        kept = [m for m in tar.getmembers() if int(m.name.split(".")[0]) < int(tar.getmembers()[-1].name.split(".")[0])]
        with tarfile.open(first, "w", format=tarfile.USTAR_FORMAT) as out:
            for m in kept:
                out.addfile(m, tar.extractfile(m))
    with pytest.raises(ValueError, match=f"^shard '{first}': 6 samples, its manifest says 7"):
        list(ShardDataset(copy))
    data = (ref / manifest["shards"][0]["name"]).read_bytes()
    for damaged in (data[: len(data) // 2], b"not a tar at all" * 100):
        first.write_bytes(damaged)
        with pytest.raises(ValueError, match=f"^shard '{first}': not a complete tar archive"):
            list(ShardDataset(copy))
        with pytest.raises(ValueError, match="not a complete tar archive"):
            list(read_shard(first))


def test_a_full_disk_names_the_output(mixed, tmp_path, monkeypatch):
    import errno
    from sonoslice.datasets import writer

    def full(f, members):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(writer, "write_tar", full)
    spec_path, _, _ = mixed
    out = tmp_path / "o"
    with pytest.raises(OSError, match=f"^\\[Errno 28\\] --out '{out}': writing shard-000000.tar: No space left on device"):
        ds.write_dataset(spec_path, out, progress=False)
    assert not [n for n in os.listdir(out) if n.endswith(".tmp") or n.endswith(".tar")]


def test_write_tar_gives_tarfiles_bytes():
    """The shards' tar writer (its own headers, members written from their pieces) writes what
    Python's tarfile writes for the same members, long names included."""
    import io
    import random

    from sonoslice.datasets.writer import write_tar
    rng = random.Random(3)
    for trial in range(30):
        members = [(("d" * 60 + "/" + "x" * rng.randrange(40, 60)) if i == 3 else f"{i:08d}.{rng.choice(['json', 'labels.npy'])}",
                    bytes(rng.randrange(256) for _ in range(rng.choice([0, 1, 511, 512, 513, 5000]))))
                   for i in range(rng.randrange(0, 12))]
        want = io.BytesIO()
        with tarfile.open(fileobj=want, mode="w", format=tarfile.USTAR_FORMAT) as tar:
            for name, data in members:
                info = tarfile.TarInfo(name)
                info.size, info.mtime, info.mode, info.uid, info.gid, info.uname, info.gname = \
                    len(data), 0, 0o644, 0, 0, "", ""
                tar.addfile(info, io.BytesIO(data))
        got = io.BytesIO()
        sha, size = write_tar(got, [(name, (data[:7], data[7:])) for name, data in members])
        assert got.getvalue() == want.getvalue(), trial
        assert (sha, size) == (hashlib.sha256(want.getvalue()).hexdigest(), len(want.getvalue()))
