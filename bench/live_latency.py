"""Live compounding end to end over loopback: `sonoslice live compound` receives a real PLUS
sweep (820x616 uint8 frames, data/plus) from a pyigtl sender paced at a frame rate, and reports
what its --stats say: frames received / compounded / dropped and the latency from a frame's
arrival to its being in the volume (p50, p95, p99, max).

    build/venv/bin/python bench/live_latency.py                  # 300 frames at 30/s, both grids
    build/venv/bin/python bench/live_latency.py --rate 300 --queue newest

The sender is pyigtl (an independent OpenIGTLink implementation) in another process; the sweep
is repeated until --frames frames are sent. Two grids: one fixed by --origin/--extent (as a PLUS
configuration with OutputOrigin/OutputExtent or Slicer's ROI gives it) and one grown around the
frames as they arrive (no grid given; growing re-inserts the frames kept so far).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyigtl

import sonoslice
from sonoslice.live import plus_frames, serve
from benchcommon import CLI

ROOT = Path(__file__).resolve().parent.parent
SEQUENCE = ROOT / "data/plus/BoneUltrasound_L14.igs.mha"
CONFIG = ROOT / "data/plus/BoneUltrasound_L14_config.xml"


def send(port, frames, count, rate):
    """Sends `count` frames (cycling) at `rate` per second from this process; seconds taken."""
    import socket
    messages = [pyigtl.ImageMessage(p[np.newaxis], ijk_to_world_matrix=m, timestamp=t,
                                    device_name="Image_Reference").pack() for p, m, t in frames]
    sock = socket.create_connection(("127.0.0.1", port), timeout=60)
    start = time.perf_counter()
    for n in range(count):
        delay = start + n / rate - time.perf_counter() if rate > 0 else 0
        if delay > 0:
            time.sleep(delay)
        sock.sendall(messages[n % len(messages)])
    seconds = time.perf_counter() - start
    sock.close()
    return seconds


def run(label, frames, args, extra):
    with tempfile.TemporaryDirectory() as tmp:
        out, stats = os.path.join(tmp, "volume.mha"), os.path.join(tmp, "stats.json")
        server = serve("compound", "--config", str(CONFIG), "--out", out, "--stats", stats,
                       "--max-frames", str(args.frames), "--queue", args.queue, "-q",
                       "--threads", str(args.threads), *extra, cli=CLI, stderr=subprocess.DEVNULL)
        seconds = send(server.port, frames, args.frames, args.rate)
        if server.wait(timeout=120) != 0:
            sys.exit(f"{label}: sonoslice live compound failed")
        s = json.load(open(stats))
    lat = s["latency_ms"]
    print(f"{label:<14} sent {args.frames} at {args.frames / seconds:6.1f}/s: received "
          f"{s['frames_received']}, compounded {s['frames_compounded']}, dropped "
          f"{s['frames_dropped']}, rejected {s['frames_rejected']}; latency ms p50 "
          f"{lat['p50']:.2f} p95 {lat['p95']:.2f} p99 {lat['p99']:.2f} max {lat['max']:.2f}; "
          f"peak memory {s['peak_memory_mb']} MB")
    return s


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--rate", type=float, default=30.0, help="frames/s (0: as fast as the socket takes them)")
    p.add_argument("--queue", default="all")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--grid", choices=["fixed", "growing", "both"], default="both")
    a = p.parse_args(argv)
    frames = list(plus_frames(SEQUENCE, CONFIG))
    # The fixed grid: the box PLUS would fit around the sweep (as a configuration would give it).
    g = sonoslice.grid_around(np.stack([m for _, m, _ in frames]), frames[0][0].shape, 0.5)
    fixed = ["--origin", ",".join(f"{v:.17g}" for v in g.origin),
             "--extent", ",".join(str(v) for v in g.dims)]
    print(f"sonoslice live compound, {len(frames)}-frame sweep of "
          f"{frames[0][0].shape[1]}x{frames[0][0].shape[0]} uint8 repeated, {a.threads} threads, "
          f"--queue {a.queue}")
    if a.grid in ("fixed", "both"):
        run("fixed grid", frames, a, fixed)
    if a.grid in ("growing", "both"):
        run("growing grid", frames, a, [])


if __name__ == "__main__":
    sys.exit(main())
