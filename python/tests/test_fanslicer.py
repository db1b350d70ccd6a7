"""The fan-slicer shim against the CLI on the same inputs (docs/conventions.md §4)."""
import json
import os
import subprocess

import numpy as np
import pytest

import sonoslice
from sonoslice import fanslicer


@pytest.fixture(scope="module")
def fanslicer_volume(tmp_path_factory, phantom):
    """The phantom stored the fan-slicer way: an [Y, X, Z] .npy and its npy_config."""
    ct, _ = phantom
    d = tmp_path_factory.mktemp("fs")
    arr = ct.array.transpose(1, 2, 0)  # (z, y, x) → [Y, X, Z]
    np.save(d / "ct.npy", np.ascontiguousarray(arr))
    lo = np.array(ct.origin)
    hi = lo + (np.array(ct.shape[::-1]) - 1) * np.array(ct.spacing)
    (d / "ct_config.json").write_text(json.dumps({"voxel size": list(ct.spacing),
                                                  "bounding box": [lo.tolist(), hi.tolist()]}))
    return d


def strip(poses):
    return np.concatenate(list(poses), axis=1)  # (N, 4, 4) → fan-slicer's (4, 4N)


def test_shim_matches_cli_on_the_same_inputs(fanslicer_volume, shared, cli, tmp_path):
    cfg = os.path.join(shared, "models_intensity_LUS_config.json")
    poses = sonoslice.phantom_poses(6, seed=9)
    np.save(tmp_path / "strip.npy", strip(poses))
    vol = fanslicer.IntensityVolume(config_dir=cfg, vol_dir=str(fanslicer_volume / "ct.npy"), file_type="npy",
                                    npy_config=str(fanslicer_volume / "ct_config.json"), downsampling=2,
                                    image_num=6, device="cpu")
    points, images = vol.simulate_image(poses=strip(poses), image_num=6)
    assert images.shape == (272, 334, 6) and images.dtype == np.float32
    assert points.shape == (0, 3)
    subprocess.run([cli, "slice", "--volume", str(fanslicer_volume / "ct.npy"), "--npy-config",
                    str(fanslicer_volume / "ct_config.json"), "--probe", cfg, "--downsampling", "2",
                    "--poses", str(tmp_path / "strip.npy"), "--out", str(tmp_path / "cli.npy"), "-q"], check=True)
    from_cli = np.load(tmp_path / "cli.npy").transpose(1, 2, 0)
    inside = vol.slicer.mask.astype(bool)
    assert np.array_equal(images[inside], from_cli[inside])
    # Outside the fan: each image's minimum, as fan-slicer does.
    for n in range(6):
        assert (images[~inside, n] == images[inside, n].min()).all()


def test_shim_argument_checks_and_points(fanslicer_volume, shared):
    cfg = os.path.join(shared, "linear_config.json")
    vol = fanslicer.IntensityVolume(cfg, str(fanslicer_volume / "ct.npy"), image_num=2,
                                    npy_config=str(fanslicer_volume / "ct_config.json"))
    poses = strip(sonoslice.phantom_poses(2))
    with pytest.raises(ValueError, match="do not match image number"):
        vol.simulate_image(poses=poses, image_num=3)
    points, images = vol.simulate_image(poses=poses, image_num=2, out_points=True)
    assert images.shape == (500, 400, 2)
    assert points.shape == (2 * 500 * 400, 3) and points.dtype == np.float32
    # The first pixel of the first image sits at pose · (x0, 0, 0).
    p0 = sonoslice.phantom_poses(2)[0] @ np.array([-200 * 0.1235, 0, 0, 1])
    assert np.allclose(points[0], p0[:3], atol=1e-3)
    with pytest.raises(ValueError, match="No valid config for npy file"):
        fanslicer.IntensityVolume(cfg, str(fanslicer_volume / "ct.npy"))
    with pytest.raises(ValueError, match="No valid config file"):
        fanslicer.IntensityVolume("nope.json", str(fanslicer_volume / "ct.npy"))
