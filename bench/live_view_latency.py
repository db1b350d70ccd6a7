"""What a page watching a live volume costs the frames: `sonoslice live compound --view` on a large
fixed grid (513 x 385 x 301 voxels of 0.25 mm: 59 M voxels), 640 x 480 uint8 frames 0.5 mm apart
sent by pyigtl at --rate, once with no page and once with a client polling the page's /api/live
every 20 ms (as the page does every 25 ms; every poll lets the viewer take its next snapshot).
Prints the frame latency --stats reports (arrival to in the volume) and how many snapshots the
page was shown.

    build/venv/bin/python bench/live_view_latency.py [--fill-holes] [--frames 150] [--rate 30]

The first frame allocates the grid; the others follow it 3 s later, so the latencies are the
steady state's.
"""
import argparse
import json
import signal
import socket
import subprocess
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pyigtl

ROOT = Path(__file__).resolve().parent.parent


def run(cli, frames, rate, fill, poll, tmp):
    stats = Path(tmp) / "stats.json"
    args = [cli, "live", "compound", "--listen", "127.0.0.1:0", "--spacing", "0.25", "--origin", "0,0,0",
            "--extent", "513,385,301", "--max-frames", str(len(frames)), "--out", str(Path(tmp) / "live.nii"),
            "--stats", str(stats), "--view", "0", "--threads", "2", "--fill-holes", "on" if fill else "off"]
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = url = None
    while port is None or url is None:
        line = p.stdout.readline()
        if not line:
            raise SystemExit(p.stderr.read())
        if "http://" in line:
            url = line.split(": ", 1)[1].strip()
        elif line.startswith("sonoslice live compound: "):
            port = int(line.rsplit(":", 1)[1])
    stop, versions = False, set()

    def poller():
        while not stop:
            state = json.loads(urllib.request.urlopen(url + "api/live", timeout=10).read())
            versions.add(state["volume_version"])
            time.sleep(0.02)

    thread = threading.Thread(target=poller)
    if poll:
        thread.start()
    sock = socket.create_connection(("127.0.0.1", port))
    for i, pixels in enumerate(frames):
        if i == 1:
            time.sleep(3)
        if i <= 1:
            t0 = time.time() - i / rate
        m = np.eye(4)
        m[0, 0] = m[1, 1] = 0.2
        m[2, 3] = i * 0.5
        sock.sendall(pyigtl.ImageMessage(pixels[np.newaxis], ijk_to_world_matrix=m, timestamp=i / rate,
                                         device_name="Image_Reference").pack())
        time.sleep(max(0.0, t0 + (i + 1) / rate - time.time()))
    line = p.stderr.readline()
    while line and "the run ended" not in line:
        line = p.stderr.readline()
    stop = True
    if poll:
        thread.join()
    p.send_signal(signal.SIGINT)  # --view stays up after the run until Ctrl-C
    p.wait(60)
    s = json.load(open(stats))["latency_ms"]
    print(f"| {'on' if fill else 'off'} | {'polling' if poll else 'none'} | {s['p50']:.1f} | {s['p95']:.1f} "
          f"| {s['max']:.1f} | {max(len(versions) - 1, 0) if poll else '-'} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cli", default=str(ROOT / "build/bin/sonoslice"))
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--rate", type=float, default=30)
    ap.add_argument("--fill-holes", action="store_true")
    args = ap.parse_args()
    frames = np.random.default_rng(1).integers(1, 255, (args.frames, 480, 640), dtype=np.uint8)
    print("| hole filling | page | latency p50 (ms) | p95 | max | snapshots shown |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for poll in (False, True):
            run(args.cli, frames, args.rate, args.fill_holes, poll, tmp)


if __name__ == "__main__":
    main()
