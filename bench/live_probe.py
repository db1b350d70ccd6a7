"""The virtual probe end to end over loopback: `sonoslice live slice` (or `live simulate`) on the
full phantom with W1 (fan-slicer's LUS fan at downsampling 2, 334x272), a pyigtl client sending
TRANSFORM messages and reading the IMAGE answers. Poses per second as the client sees them:

* lockstep: send a pose, wait for its image (what a navigation loop does);
* pipelined: keep up to --window poses in flight (what a data generator does).

    build/venv/bin/python bench/live_probe.py                 # live slice, 2000 poses
    build/venv/bin/python bench/live_probe.py --simulate --poses 200

The answers are checked against `sonoslice.Slicer` at the same poses (the first few) so the
figure is of correct images.
"""
import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time

import numpy as np
import pyigtl
from pyigtl.messages import MessageBase

import sonoslice
from sonoslice.live import serve
from benchcommon import CLI

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PROBE = os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json")


def read_exact(sock, n):
    data = bytearray()
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError("the server closed the connection")
        data += chunk
    return bytes(data)


def receive_image(sock):
    header = MessageBase.parse_header(read_exact(sock, 58))
    body = read_exact(sock, header["body_size"])
    m = pyigtl.ImageMessage()
    m.unpack(header, body)
    return m


def run(sock, messages, window):
    """Seconds to get an image for every message with at most `window` in flight."""
    start = time.perf_counter()
    sent = received = 0
    while received < len(messages):
        while sent < len(messages) and sent - received < window:
            sock.sendall(messages[sent])
            sent += 1
        receive_image(sock)
        received += 1
    return time.perf_counter() - start


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--poses", type=int, default=2000)
    p.add_argument("--window", type=int, default=16)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--simulate", action="store_true", help="live simulate (preset lus) instead")
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        ct_path = os.path.join(tmp, "ct.nii")
        sonoslice.phantom("full")[0].save(ct_path)
        ct = sonoslice.Volume.from_file(ct_path)  # as the server reads it (NIfTI's float32 header)
        poses = sonoslice.phantom_poses(a.poses, seed=7).astype(np.float32).astype(np.float64)
        stats_path = os.path.join(tmp, "stats.json")
        common = ["--threads", str(a.threads), "--stats", stats_path]
        if a.simulate:
            server = serve("simulate", "--volume", ct_path, "--preset", "lus", *common,
                           cli=CLI, stderr=subprocess.DEVNULL)
        else:
            server = serve("slice", "--volume", ct_path, "--probe", PROBE, "--downsampling", "2", *common,
                           cli=CLI, stderr=subprocess.DEVNULL)
        with server:
            sock = socket.create_connection(("127.0.0.1", server.port))
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            messages = [pyigtl.TransformMessage(pose, device_name="ProbeToReference").pack() for pose in poses]
            # Correct images first: the first answers against the library's slicer.
            if not a.simulate:
                probe = sonoslice.Probe.from_fanslicer(PROBE, downsampling=2)
                expected = sonoslice.Slicer(ct, probe).slice(poses[:5])
                for k in range(5):
                    sock.sendall(messages[k])
                    np.testing.assert_array_equal(receive_image(sock).image[0], expected[k])
            lockstep = run(sock, messages[: max(1, len(messages) // 4)], 1)
            pipelined = run(sock, messages, a.window)
            sock.close()
        with open(stats_path) as f:
            server_latency = json.load(f)["latency_ms"]
    n_lock = max(1, len(messages) // 4)
    kind = "live simulate (lus preset)" if a.simulate else "live slice W1 (334x272 float32)"
    print(f"{kind}, full phantom, {a.threads} threads, loopback, pyigtl client:")
    print(f"  lockstep   {n_lock:5d} poses: {n_lock / lockstep:7.1f} poses/s "
          f"({lockstep / n_lock * 1e3:.2f} ms per pose, round trip)")
    print(f"  pipelined  {len(messages):5d} poses: {len(messages) / pipelined:7.1f} poses/s "
          f"(window {a.window})")
    print(f"  server side, TRANSFORM read -> IMAGE queued: p50 {server_latency['p50']:.2f} ms, "
          f"p99 {server_latency['p99']:.2f} ms")


if __name__ == "__main__":
    sys.exit(main())
