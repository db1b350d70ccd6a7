"""What the Python benchmarks share: the repository's paths and a timed CLI run."""
import os
import subprocess
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.environ.get("SONOSLICE_CLI", os.path.join(ROOT, "build", "bin", "sonoslice"))
W1 = os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json")


def run_timed(cmd):
    """(wall seconds, stderr) of one command; stops the benchmark if it fails."""
    start = time.perf_counter()
    run = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if run.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{run.stderr}")
    return wall, run.stderr
