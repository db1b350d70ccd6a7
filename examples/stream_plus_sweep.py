"""Streams a PLUS sweep to an OpenIGTLink receiver (`sonoslice live compound`, PlusServer's
peers, 3D Slicer) as PlusServer broadcasts it: one IMAGE message per frame, device
`Image_Reference`, whose matrix is the frame's ImageToReference transform (pixel -> mm).

    python examples/stream_plus_sweep.py data/plus/BoneUltrasound_L14.igs.mha \
        --config data/plus/BoneUltrasound_L14_config.xml --port 18944 --rate 30

The transforms come from the sequence and the configuration's CoordinateDefinitions (the
calibration), as PLUS chains them (sonoslice.live.plus_frames). Frames whose chain is invalid are
skipped. Uses pyigtl
(pip install pyigtl), an OpenIGTLink implementation independent of sonoslice's.
"""
import argparse
import socket
import sys
import time

import numpy as np
import pyigtl

from sonoslice.live import plus_frames


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence")
    p.add_argument("--config", help="PLUS configuration XML (the calibration)")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=18944)
    p.add_argument("--rate", type=float, default=30.0, help="frames per second (0: as fast as "
                   "the receiver takes them)")
    p.add_argument("--device-name", default="Image_Reference")
    p.add_argument("--repeat", type=int, default=1, help="send the sweep this many times")
    p.add_argument("--stop", action="store_true",
                   help="then send PlusServer's StopVolumeReconstruction command")
    a = p.parse_args(argv)

    frames = list(plus_frames(a.sequence, a.config))
    if not frames:
        sys.exit(f"{a.sequence}: no frame with a valid ImageToReference transform")
    sock = socket.create_connection((a.host, a.port), timeout=30)
    start = time.perf_counter()
    sent = 0
    for _ in range(a.repeat):
        for pixels, matrix, timestamp in frames:
            message = pyigtl.ImageMessage(pixels[np.newaxis], ijk_to_world_matrix=matrix,
                                          timestamp=timestamp, device_name=a.device_name)
            if a.rate > 0:  # paced like a scanner: frame n leaves at start + n / rate
                delay = start + sent / a.rate - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            sock.sendall(message.pack())
            sent += 1
    if a.stop:
        command = pyigtl.StringMessage('<Command Name="StopVolumeReconstruction" />',
                                       device_name="CMD_1")
        sock.sendall(command.pack())
        sock.settimeout(60)
        sock.recv(1 << 16)  # the ACK_1 reply: the volume is complete
    sock.close()
    seconds = time.perf_counter() - start
    print(f"sent {sent} frames of {frames[0][0].shape[1]}x{frames[0][0].shape[0]} in "
          f"{seconds:.2f} s ({sent / seconds:.1f} frames/s)")


if __name__ == "__main__":
    main()
