"""What a user of `sonoslice view` waits for, in Debian's headless Chromium (software WebGL), on
the full 512x512x400 phantom with W1 (fan-slicer's LUS fan at downsampling 2, 334x272):

* first image: from asking for the page to the planes and the first pose's image on screen;
* pose change: from changing the pose to its new image drawn (the page's own clock), p50/p95;
* plane scrolling: planes drawn per second when one plane is scrolled step by step.

    build/venv/bin/python bench/view_speed.py [--poses 100] [--threads 2]

The targets (docs/view.md): first image < 1 s, pose change p95 < 50 ms, scrolling >= 30 planes/s.
"""
import argparse
import os
import sys
import tempfile
import time

import numpy as np

import sonoslice

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "python", "tests"))
from test_view import Viewer, call, chromium  # noqa: E402,F401  (the browser tests' own driver)

PROBE = os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--poses", type=int, default=100)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--cli", default=os.environ.get("SONOSLICE_CLI", os.path.join(ROOT, "build", "bin", "sonoslice")))
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        ct = os.path.join(tmp, "ct.nii")
        sonoslice.phantom("full")[0].save(ct)
        poses = os.path.join(tmp, "poses.npy")
        np.save(poses, sonoslice.phantom_poses(a.poses, seed=7))
        viewer = Viewer([a.cli, "view", "--no-browser", "--volume", ct, "--probe", PROBE, "--downsampling", "2",
                         "--poses", poses, "--threads", str(a.threads)])
        driver = chromium(network_log=False)
        try:
            first = []  # a browser that has not shown the page yet, then reloads
            for _ in range(3):
                driver.get("about:blank")
                t0 = time.time()
                driver.get(viewer.url)
                while not driver.execute_script("return !!(window.sonosliceView && window.sonosliceView.ready)"):
                    time.sleep(0.005)
                first.append(time.time() - t0)
            driver.execute_script("window.sonosliceView.stats.imageMs.length = 0")
            for k in range(1, a.poses):
                call(driver, f"window.sonosliceView.setPose({k})")
            ms = np.array(driver.execute_script("return window.sonosliceView.stats.imageMs"))
            axis, n = 2, 60
            start = driver.execute_script(f"return window.sonosliceView.state.positions[{axis}]")
            step = driver.execute_script(f"return window.sonosliceView.scene.planes[{axis}].step")
            # Scrolled inside the page (as wheel events do), timed by the page's clock.
            ms_total = driver.execute_async_script(f"""
                const done = arguments[arguments.length - 1], v = window.sonosliceView;
                const t0 = performance.now();
                let p = Promise.resolve();
                for (let i = 0; i < {n}; i++) p = p.then(() => v.setPlane({axis}, {start} + (i % 30 - 15) * {step}));
                p.then(() => done(performance.now() - t0));""")
            fps = n / (ms_total / 1e3)
        finally:
            driver.quit()
            viewer.stop()
    print(f"sonoslice view, full phantom (512x512x400), W1, {a.threads} threads, headless Chromium:")
    print(f"  first image on screen   {first[0] * 1e3:7.0f} ms new browser, "
          f"{min(first[1:]) * 1e3:.0f}-{max(first[1:]) * 1e3:.0f} ms reloads   (target < 1000 ms)")
    print(f"  pose change -> image    p50 {np.percentile(ms, 50):5.1f} ms  p95 {np.percentile(ms, 95):5.1f} ms"
          f"   ({len(ms)} changes; target p95 < 50 ms)")
    print(f"  plane scrolling         {fps:7.1f} planes/s (target >= 30)")


if __name__ == "__main__":
    main()
