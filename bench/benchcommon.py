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


def full_phantom_ct(phantom, tmp):
    """The CT of the full phantom: the ct.* file of folder `phantom` (from `sonoslice phantom DIR
    --size full`), else one written into `tmp` first."""
    if not phantom:
        phantom = os.path.join(tmp, "phantom")
        print("writing the full phantom (512x512x400) ...", flush=True)
        subprocess.run([CLI, "phantom", phantom, "--size", "full", "--format", "nii", "-q"], check=True)
    phantom = os.path.abspath(phantom)  # the benchmarks' SPECs and servers run in other folders
    cts = [f for f in sorted(os.listdir(phantom)) if f.startswith("ct.") and not f.endswith(".json")]  # not a sidecar
    if not cts:
        raise SystemExit(f"{phantom}: no ct.* file (write one with `sonoslice phantom DIR --size full`)")
    return os.path.join(phantom, cts[0])
