import os

import numpy as np
import pytest

import sonoslice

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DATA = os.path.join(ROOT, "data")


@pytest.fixture(scope="session")
def phantom():
    return sonoslice.phantom("small")


@pytest.fixture(scope="session")
def poses():
    return sonoslice.phantom_poses(12, seed=3)


@pytest.fixture(scope="session")
def shared():
    path = os.path.join(DATA, "fanslicer")
    # The real data ships with the repository: a missing folder is a broken checkout, not a skip.
    assert os.path.isdir(path), f"{path} is missing (see data/README.md)"
    return path


@pytest.fixture(scope="session")
def cli():
    path = os.environ.get("SONOSLICE_CLI", os.path.join(ROOT, "build", "bin", "sonoslice"))
    if not os.access(path, os.X_OK):
        pytest.skip(f"the sonoslice CLI is not built at {path} (set SONOSLICE_CLI)")
    return path


# What a build without ITK or VTK (the GPU machine's: scripts/gpu-check.sh) says when a test needs
# a format only they read: such a test is reported as skipped there, naming the library, instead
# of failing. Builds that have the library (CI's) never produce these messages.
_MISSING_LIBRARY = {
    "ITK": ("built without ITK",),
    "VTK": ("built without VTK",),
}


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if not report.failed or call.excinfo is None:
        return
    text = str(report.longrepr)
    have = {"ITK": sonoslice._ext.built_with_itk(), "VTK": sonoslice._ext.built_with_vtk()}
    for library, phrases in _MISSING_LIBRARY.items():
        if not have[library] and any(p in text for p in phrases):
            report.outcome = "skipped"
            report.longrepr = (str(item.fspath), item.location[1] or 0,
                               f"Skipped: needs {library}, and this sonoslice was built without it")
            return


def cuda_required() -> bool:
    """SONOSLICE_REQUIRE_CUDA=1 (scripts/gpu-check.sh): a CUDA test that would skip fails instead,
    so a broken GPU setup can never look green."""
    return os.environ.get("SONOSLICE_REQUIRE_CUDA", "") not in ("", "0")


@pytest.fixture
def cuda():
    if not sonoslice.cuda_available():
        # devices() ends with the CUDA line, e.g. "cuda: not available (no NVIDIA driver found ...)".
        why = sonoslice.devices().strip().splitlines()[-1]
        if cuda_required():
            pytest.fail(f"SONOSLICE_REQUIRE_CUDA=1, but the test would skip: {why}")
        pytest.skip(why)
    return "cuda:0"


def small_probe():
    return sonoslice.Probe.curvilinear(radius_mm=20, depth_mm=60, sector_deg=60, width=96, height=80,
                                       spacing_mm=0.8)


def assert_each_flag_required(cli, args, flags):
    """``args`` (a command and its flags) run once without each of ``flags`` (and its value): a usage
    error each time (exit 2, one line naming the flag and pointing at the command's --help)."""
    import subprocess
    for flag in flags:
        i = args.index(flag)
        r = subprocess.run([cli, *args[:i], *args[i + 2:]], capture_output=True, encoding="utf-8",
                           errors="replace", timeout=300)
        assert r.returncode == 2, (flag, r.returncode, r.stderr)
        assert r.stderr.count("\n") == 1 and flag + " is required" in r.stderr, r.stderr
        assert r.stderr.rstrip().endswith(f"see 'sonoslice {args[0]} --help'"), r.stderr
