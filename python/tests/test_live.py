"""sonoslice live against pyigtl, an independent OpenIGTLink implementation: frames streamed to
`sonoslice live compound` give the volume `sonoslice compound` makes from the recorded sequence,
byte for byte; PlusServer's commands (STRING CMD_ and header-v2 COMMAND) are answered as PlusServer
answers them; malformed messages are counted and leave the server serving; the virtual probe
answers poses with the images `slice` makes; the Python LiveCompounder and server."""
import json
import os
import socket
import struct
import subprocess
import time
import warnings

import numpy as np
import pytest

import sonoslice
from sonoslice.live import LiveCompounder, LiveCompoundServer, plus_frames, serve

pyigtl = pytest.importorskip("pyigtl")
pytestmark = pytest.mark.filterwarnings("ignore:.*BoneUltrasound_L14_config.xml")
from pyigtl.messages import CRC64, MessageBase  # noqa: E402  (pyigtl's own codec)

from conftest import DATA  # noqa: E402

SEQUENCE = os.path.join(DATA, "plus", "BoneUltrasound_L14.igs.mha")
CONFIG = os.path.join(DATA, "plus", "BoneUltrasound_L14_config.xml")


@pytest.fixture(scope="module")
def frames():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the configuration's deprecated attribute
        return list(plus_frames(SEQUENCE, CONFIG))


class Peer:
    """An OpenIGTLink peer: pyigtl packs and unpacks, a plain socket carries the bytes."""

    def __init__(self, port):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=30)

    def send(self, message):
        self.sock.sendall(message if isinstance(message, bytes) else message.pack())

    def _read(self, n):
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("closed")
            data += chunk
        return data

    def receive(self):
        """(header fields, body bytes, the pyigtl message or None for types pyigtl lacks)."""
        header = MessageBase.parse_header(self._read(58))
        body = self._read(header["body_size"])
        message = MessageBase.create_message(header["message_type"])
        if message is not None:
            message.unpack(header, body)
        return header, body, message

    def close(self):
        self.sock.close()


def image_message(pixels, matrix, timestamp=0.0, device="Image_Reference", version=1):
    m = pyigtl.ImageMessage(pixels[np.newaxis], ijk_to_world_matrix=matrix, timestamp=timestamp,
                            device_name=device)
    m.header_version = version
    return m


def command(uid, xml, version=1):
    m = pyigtl.StringMessage(xml, device_name=f"CMD_{uid}")
    m.header_version = version
    return m


def raw_message(kind, device, content, version=2, message_id=0, metadata=()):
    """A message pyigtl has no class for (COMMAND, GET_STATUS), with pyigtl's CRC."""
    body = content
    if version == 2:
        keys = b"".join(struct.pack(">HHI", len(k), 3, len(v)) for k, v in metadata)
        values = b"".join(k + v for k, v in metadata)
        meta = struct.pack(">H", len(metadata)) + keys
        body = struct.pack(">HHII", 12, len(meta), len(values), message_id) + content + meta + values
    return struct.pack(">H12s20sQQQ", version, kind.encode(), device.encode(), 0, len(body),
                       CRC64(body)) + body


def start(cli, *args):
    return serve("compound", "--config", CONFIG, *args, cli=cli, stderr=subprocess.PIPE)


def grid_flags(frames, spacing=0.5):
    g = sonoslice.grid_around(np.stack([m for _, m, _ in frames]), frames[0][0].shape, spacing)
    return ["--origin", ",".join(f"{v:.17g}" for v in g.origin),
            "--extent", ",".join(str(v) for v in g.dims)]


@pytest.mark.parametrize("threads,grid", [(1, "growing"), (2, "growing"), (2, "fixed")])
def test_live_volume_is_the_offline_compound_of_the_recording(cli, tmp_path, frames, threads, grid):
    out, record, stats = tmp_path / "live.mha", tmp_path / "rec.igs.mha", tmp_path / "stats.json"
    fixed = grid_flags(frames) if grid == "fixed" else []
    server = start(cli, "--out", str(out), "--record", str(record), "--stats", str(stats),
                   "--max-frames", str(len(frames)), "--threads", str(threads), *fixed)
    peer = Peer(server.port)
    for pixels, matrix, t in frames:
        peer.send(image_message(pixels, matrix, t))
    assert server.wait(60) == 0, server.process.stderr.read()
    peer.close()
    s = json.loads(stats.read_text())
    assert s["frames_received"] == s["frames_compounded"] == len(frames)
    assert s["frames_dropped"] == s["frames_rejected"] == 0
    assert s["stopped_by"] == "--max-frames"
    assert 0 < s["latency_ms"]["p50"] <= s["latency_ms"]["p95"] <= s["latency_ms"]["max"]
    # The recording is a PLUS sequence of the frames as received; compounding it offline on the
    # live grid gives the same file, byte for byte.
    rec = sonoslice.read_plus_sequence(record)
    assert len(rec) == len(frames)
    np.testing.assert_array_equal(rec.frames, np.stack([p for p, _, _ in frames]))
    # The grown grid is fitted as `compound` fits it: the plain offline command gives the bytes.
    offline = tmp_path / "offline.mha"
    subprocess.run([cli, "compound", "--sequence", str(record), "--config", CONFIG, "-q",
                    "--threads", str(3 - threads), "--out", str(offline), *fixed],
                   check=True, stderr=subprocess.DEVNULL)
    assert out.read_bytes() == offline.read_bytes()


def test_a_start_without_grid_attributes_keeps_the_grid(cli, tmp_path, frames):
    # PlusServer's StartVolumeReconstruction sets only the grid attributes it carries (SlicerIGT's
    # PlusRemote sends none without an ROI): the configured grid stays.
    out = tmp_path / "live.mha"
    fixed = grid_flags(frames)
    server = start(cli, "--out", str(out), "--max-seconds", "60", *fixed)
    peer = Peer(server.port)
    peer.send(command(1, '<Command Name="StartVolumeReconstruction" />'))
    assert 'Status="SUCCESS"' in peer.receive()[2].string
    # A grid attribute that does not parse fails the command, named as the configuration's reader names it.
    peer.send(command(2, '<Command Name="StartVolumeReconstruction" OutputSpacing="0.5 0.5" />'))
    header, _, reply = peer.receive()
    assert 'Status="FAIL"' in reply.string and "OutputSpacing: expected 3 numbers" in reply.string, reply.string
    peer.send(command(3, '<Command Name="StartVolumeReconstruction" OutputSpacing="0.5 0.5 0.5" '
                         'OutputOrigin="0 0 0" OutputExtent="0 9 0 9 5 1" />'))
    assert 'Status="FAIL"' in peer.receive()[2].string
    # A grid beyond any scanner is named by the command's attributes, not by flags this client never gave.
    peer.send(command(5, '<Command Name="StartVolumeReconstruction" OutputSpacing="1 1 1" '
                         'OutputOrigin="1e300 0 0" OutputExtent="0 10 0 10 0 10" />'))
    reply = peer.receive()[2].string
    assert 'Status="FAIL"' in reply and "OutputOrigin/OutputExtent: origin along axis 0" in reply, reply
    assert "--origin" not in reply, reply
    for pixels, matrix, t in frames[:5]:
        peer.send(image_message(pixels, matrix, t))
    peer.send(command(4, '<Command Name="StopVolumeReconstruction" />'))
    assert 'Status="SUCCESS"' in peer.receive()[2].string
    assert server.wait(60) == 0
    peer.close()
    g = sonoslice.Volume.from_file(out)
    assert g.shape[::-1] == tuple(int(v) for v in fixed[3].split(","))
    np.testing.assert_allclose(g.origin, [float(v) for v in fixed[1].split(",")], atol=1e-6)


def test_plus_server_commands_over_string_messages(cli, tmp_path, frames):
    out, stats = tmp_path / "live.mha", tmp_path / "stats.json"
    server = start(cli, "--out", str(out), "--stats", str(stats), "--max-seconds", "60")
    peer = Peer(server.port)
    origin, extent = [-60, -30, 40], [180, 150, 100]
    peer.send(command(1, '<Command Name="StartVolumeReconstruction" OutputSpacing="0.5 0.5 0.5" '
                         f'OutputOrigin="{origin[0]} {origin[1]} {origin[2]}" '
                         f'OutputExtent="0 {extent[0] - 1} 0 {extent[1] - 1} 0 {extent[2] - 1}" />'))
    header, _, reply = peer.receive()
    assert header["device_name"] == "ACK_1" and 'Status="SUCCESS"' in reply.string
    for pixels, matrix, t in frames[:10]:
        peer.send(image_message(pixels, matrix, t))
    peer.send(command(2, '<Command Name="SuspendVolumeReconstruction" />'))
    assert 'Status="SUCCESS"' in peer.receive()[2].string
    for pixels, matrix, t in frames[10:15]:  # counted, not compounded
        peer.send(image_message(pixels, matrix, t))
    peer.send(command(3, '<Command Name="SuspendVolumeReconstruction" />'))  # PlusServer: FAIL
    header, _, reply = peer.receive()
    assert header["device_name"] == "ACK_3" and 'Status="FAIL"' in reply.string
    peer.send(command(4, '<Command Name="ResumeVolumeReconstruction" />'))
    assert 'Status="SUCCESS"' in peer.receive()[2].string
    peer.send(command(5, '<Command Name="GetVolumeReconstructionSnapshot" OutputVolDeviceName="Snap" />'))
    header, _, snapshot = peer.receive()  # the volume first, then the reply, as PlusServer
    assert header["device_name"] == "Snap"
    assert snapshot.image.shape == (extent[2], extent[1], extent[0])
    np.testing.assert_allclose(snapshot.ijk_to_world_matrix[:3, 3], origin, atol=1e-4)
    np.testing.assert_allclose(np.diag(snapshot.ijk_to_world_matrix)[:3], 0.5)
    assert snapshot.image.max() > 0
    assert 'Status="SUCCESS"' in peer.receive()[2].string
    peer.send(raw_message("GET_STATUS", "", b"", version=1))
    header, body, _ = peer.receive()
    assert header["message_type"] == "STATUS"
    status = json.loads(body[30:].rstrip(b"\0"))
    assert status["frames_compounded"] == 10 and status["frames_suspended"] == 5
    peer.send(command(6, '<Command Name="NoSuchCommand" />'))
    assert 'Status="FAIL"' in peer.receive()[2].string
    peer.send(command(7, '<Command Name="StopVolumeReconstruction" OutputVolDeviceName="Final" />'))
    header, _, final = peer.receive()
    assert header["device_name"] == "Final"
    assert 'Status="SUCCESS"' in peer.receive()[2].string
    assert server.wait(60) == 0
    peer.close()
    s = json.loads(stats.read_text())
    assert s["stopped_by"] == "StopVolumeReconstruction"
    assert s["frames_received"] == 15 and s["frames_compounded"] == 10
    # The volume written is the one sent with the Stop command.
    written = sonoslice.Volume.from_file(out)
    np.testing.assert_array_equal(written.array, final.image)


def test_header_v2_commands_frames_and_metadata(cli, tmp_path, frames):
    out = tmp_path / "live.mha"
    server = start(cli, "--out", str(out), "--max-seconds", "60")
    peer = Peer(server.port)
    for pixels, matrix, t in frames[:3]:  # header v2 frames, with metadata, from pyigtl
        m = image_message(pixels, matrix, t, version=2)
        m.metadata = {"ProbeName": "L14", "Depth": "60"}
        peer.send(m)
    # A header-v2 STRING command: the reply keeps the header version (pyigtl reads it).
    peer.send(command(8, '<Command Name="GetVolumeReconstructionSnapshot" />', version=2))
    header, _, reply = peer.receive()
    assert header["header_version"] == 2 and header["device_name"] == "ACK_8"
    # COMMAND (OpenIGTLink 3): id, a 128-byte name, encoding, length, the XML; the reply is an
    # RTS_COMMAND with the same id and name and PlusServer's reply XML, with its metadata.
    xml = b'<Command Name="StopVolumeReconstruction" />'
    content = struct.pack(">I128sHI", 42, b"StopVolumeReconstruction", 3, len(xml)) + xml
    peer.send(raw_message("COMMAND", "command", content, message_id=9))
    header, body, _ = peer.receive()
    assert header["message_type"] == "RTS_COMMAND" and header["header_version"] == 2
    ext, meta_header, meta_size, message_id = struct.unpack(">HHII", body[:12])
    assert message_id == 9
    command_id, name, _, length = struct.unpack(">I128sHI", body[12:150])
    assert command_id == 42 and name.rstrip(b"\0") == b"StopVolumeReconstruction"
    text = body[150:150 + length].decode()
    assert 'Name="StopVolumeReconstruction" Status="SUCCESS"' in text
    assert b"Status" in body[len(body) - meta_size - meta_header:]
    assert server.wait(60) == 0
    peer.close()


def test_malformed_messages_are_counted_and_the_server_goes_on(cli, tmp_path, frames):
    out, stats = tmp_path / "live.mha", tmp_path / "stats.json"
    server = start(cli, "--out", str(out), "--stats", str(stats), "--max-seconds", "60",
                   *grid_flags(frames))
    idle = Peer(server.port)  # connects and sends nothing
    peer = Peer(server.port)
    pixels, matrix, t = frames[0]
    good = image_message(pixels, matrix, t).pack()
    peer.send(good[:-1] + bytes([good[-1] ^ 1]))  # bad CRC
    peer.send(image_message(pixels.astype(np.float64), matrix).pack())  # float64 frame
    nan = matrix.copy()
    nan[0, 3] = np.nan
    peer.send(image_message(pixels, nan).pack())  # NaN matrix
    singular = matrix.copy()
    singular[:3, 1] = singular[:3, 0]
    peer.send(image_message(pixels, singular).pack())
    peer.send(pyigtl.ImageMessage(np.zeros((2, 3, 4), np.uint8), ijk_to_world_matrix=np.eye(4)).pack())
    peer.send(pyigtl.ImageMessage(np.zeros((1, 3, 4, 2), np.uint8), ijk_to_world_matrix=np.eye(4)).pack())
    peer.send(pyigtl.PointMessage(positions=[[1, 2, 3]], device_name="Points").pack())  # ignored
    peer.send(command(1, "<Command Name=broken"))  # XML that does not parse
    header, _, reply = peer.receive()
    assert header["device_name"] == "ACK_1" and 'Status="FAIL"' in reply.string
    for k, (pixels, matrix, t) in enumerate(frames[:5]):
        if k == 2:  # as a video grabber sends it: grey in RGB, compounded by its first component
            pixels = np.repeat(pixels[..., np.newaxis], 3, axis=-1)
        peer.send(image_message(pixels, matrix, t))
    peer.send(good[:1000])  # a client that leaves mid-message
    peer.close()
    for k in range(5):  # five reconnects, a frame each
        p = Peer(server.port)
        p.send(image_message(*frames[5 + k]))
        time.sleep(0.05)
        p.close()
    flood = Peer(server.port)  # an absurd body size closes that connection only
    flood.send(struct.pack(">H12s20sQQQ", 1, b"IMAGE", b"x", 0, 1 << 40, 0))
    time.sleep(0.2)
    p = Peer(server.port)
    peer_frames = frames[10:12]
    for pixels, matrix, t in peer_frames:
        p.send(image_message(pixels, matrix, t))
    time.sleep(0.3)
    assert server.stop() == 0, server.process.stderr.read()
    for c in (idle, p, flood):
        c.close()
    s = json.loads(stats.read_text())
    assert s["frames_compounded"] == 12
    reasons = s["rejected_by_reason"]
    assert any("float64" in r for r in reasons) and any("singular" in r for r in reasons)
    network = s["network"]
    assert network["rejected: an IMAGE matrix with a non-finite value"] == 1
    assert network["rejected: a CRC that does not match its body"] == 1
    assert network["rejected: a 3-D image (frames are 2-D)"] == 1
    assert network["rejected: an image of 2 components (frames have 1, or 3 or 4: RGB, RGBA)"] == 1
    assert network["ignored: POINT message"] == 1
    assert network["rejected: command XML that does not parse"] == 1
    assert sum(v for k, v in network.items() if "limit is" in k) == 1
    assert network["connections"] >= 9
    # The volume is the one of the 12 good frames, whatever came between them.
    offline = sonoslice.LiveCompounder(CONFIG, **grid_kwargs(frames))
    for pixels, matrix, t in frames[:12]:
        offline.push(pixels, wire_matrix(matrix, pixels.shape), t)
    np.testing.assert_array_equal(sonoslice.Volume.from_file(out).array, offline.finish().array)


def test_commands_that_deliver_nothing_fail_and_idle_clients_make_room(cli, tmp_path, frames):
    out, stats = tmp_path / "live.mha", tmp_path / "stats.json"
    server = start(cli, "--out", str(out), "--stats", str(stats), "--max-seconds", "60", *grid_flags(frames))
    peer = Peer(server.port)
    # A snapshot before any frame: FAIL, not a SUCCESS that delivers nothing.
    peer.send(command(1, f'<Command Name="GetVolumeReconstructionSnapshot" OutputVolFilename="{tmp_path}/s.mha"/>'))
    _, _, reply = peer.receive()
    assert 'Status="FAIL"' in reply.string and "no frame compounded yet" in reply.string, reply.string
    peer.send(command(2, '<Command Name="FormatDisk"/>'))
    _, _, reply = peer.receive()
    assert 'Status="FAIL" Message="unknown command FormatDisk"' in reply.string
    pixels, matrix, t = frames[0]
    point = matrix.copy()
    point[:3, :3] = np.eye(3) * 1e-30  # a frame shrunk to a point
    peer.send(image_message(pixels, point, t))
    # 15 more clients that connect and do nothing fill the 16 places; once they have been silent
    # for 2 s a sender still gets in (the silent one longest out).
    idle = [Peer(server.port) for _ in range(15)]
    time.sleep(2.5)
    sender = Peer(server.port)
    for k, (pixels, matrix, t) in enumerate(frames[:3]):
        values = pixels.astype(np.float32)
        values[0, 0] = np.nan if k == 0 else values[0, 0]  # compounded as it is, and counted
        sender.send(image_message(values, matrix, t))
    time.sleep(0.5)
    assert server.stop() == 0, server.process.stderr.read()
    for c in (peer, sender, *idle):
        c.close()
    s = json.loads(stats.read_text())
    assert s["frames_compounded"] == 3 and not (tmp_path / "s.mha").exists()
    network = s["network"]
    assert network["rejected: unknown command FormatDisk"] == 1
    assert [k for k in network if "spacing" in k] == ["rejected: an IMAGE pixel spacing of 1e-30 mm along axis 0 (expected 1e-6 to 1e9 mm)"], network
    assert network["dropped: an idle client at the client limit"] == 1
    assert network["frames with NaN or infinite pixels"] == 1


def grid_kwargs(frames):
    g = sonoslice.grid_around(np.stack([m for _, m, _ in frames]), frames[0][0].shape, 0.5)
    return {"origin": g.origin, "extent": g.dims}


def wire_matrix(matrix, shape):
    """The matrix after OpenIGTLink: float32 columns and centre (pyigtl's packing)."""
    m = image_message(np.zeros(shape, np.uint8), matrix)
    header = MessageBase.parse_header(m.pack()[:58])
    back = pyigtl.ImageMessage()
    back.unpack(header, m.pack()[58:])
    return back.ijk_to_world_matrix


def test_sigint_mid_stream_writes_the_frames_so_far(cli, tmp_path, frames):
    out, stats = tmp_path / "live.nii.gz", tmp_path / "stats.json"
    server = start(cli, "--out", str(out), "--stats", str(stats))
    peer = Peer(server.port)
    for pixels, matrix, t in frames[:8]:
        peer.send(image_message(pixels, matrix, t))
    time.sleep(0.5)
    assert server.stop() == 0
    peer.close()
    s = json.loads(stats.read_text())
    assert s["stopped_by"] == "a signal" and s["frames_compounded"] == 8
    assert sonoslice.Volume.from_file(out).array.max() > 0


def test_no_frame_no_volume_and_a_named_reason(cli, tmp_path):
    out = tmp_path / "live.mha"
    r = subprocess.run([cli, "live", "compound", "--listen", "127.0.0.1:0", "--config", CONFIG,
                        "--out", str(out), "--max-seconds", "0.3"], capture_output=True, text=True)
    assert r.returncode == 1 and not out.exists()
    assert r.stderr.splitlines()[-1] == (f"sonoslice: error: live compound: stopped by --max-seconds with no frame "
                                         f"compounded, nothing written to '{out}' (0 frames received)"), r.stderr
    assert "stopped by --max-seconds:" not in r.stderr  # the error alone carries the counts
    for args, what in [(["--listen", "0", "--connect", "x:1"], "one of --listen or --connect"),
                       (["--listen", "99999"], "--listen 99999"),
                       (["--listen", "0", "--queue", "some"], "--queue"),
                       (["--listen", "0", "--queue-size", "0"], "--queue-size"),
                       (["--listen", "0", "--origin", "1,2,3"], "--origin"),
                       (["--listen", "0", "--view", "70000"], "--view 70000: expected [HOST:]PORT"),
                       (["--listen", "0", "--max-seconds", "nan"], "--max-seconds nan: must be a finite number"),
                       (["--listen", "0", "--max-seconds", "inf"], "--max-seconds inf: must be a finite number"),
                       (["--listen", "0", "--max-frames", "-2"], "--max-frames -2: must be >= 0")]:
        r = subprocess.run([cli, "live", "compound", *args, "--spacing", "1", "--out", str(out)],
                           capture_output=True, text=True, timeout=30)
        assert r.returncode != 0 and what in r.stderr, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1
        assert r.stdout == "", (args, r.stdout)  # refused before listening


def test_queue_newest_counts_every_frame_it_drops(cli, tmp_path, frames):
    out, stats = tmp_path / "live.mha", tmp_path / "stats.json"
    server = start(cli, "--out", str(out), "--stats", str(stats), "--queue", "newest",
                   "--max-frames", "200", *grid_flags(frames))
    peer = Peer(server.port)
    packed = [image_message(p, m, t).pack() for p, m, t in frames]
    for k in range(200):  # as fast as the socket takes them
        peer.send(packed[k % len(packed)])
    assert server.wait(60) == 0
    peer.close()
    s = json.loads(stats.read_text())
    assert s["frames_received"] == 200
    assert s["frames_compounded"] + s["frames_dropped"] == 200


def test_virtual_probe_answers_each_pose_with_the_slice_image(cli, tmp_path):
    ct_path = tmp_path / "ct.nii.gz"
    ct, _ = sonoslice.phantom("small")
    ct.save(ct_path)
    probe = sonoslice.Probe.curvilinear(20, 60, 60, 64, 48, 1.0)
    probe_path = tmp_path / "probe.json"
    probe_path.write_text(probe.to_json())
    grid = json.loads(probe.to_json())["image"]
    pixel_to_probe = np.eye(4)
    pixel_to_probe[0, 0], pixel_to_probe[1, 1] = grid["spacing_mm"]
    pixel_to_probe[:2, 3] = grid["origin_mm"]
    # TRANSFORM carries float32: poses that are float32 already arrive unchanged.
    poses = sonoslice.phantom_poses(6, seed=4).astype(np.float32).astype(np.float64)
    stats = tmp_path / "stats.json"
    server = serve("slice", "--volume", str(ct_path), "--probe", str(probe_path), "--stats", str(stats),
                   "--max-frames", str(len(poses)), cli=cli)
    peer = Peer(server.port)
    expected = sonoslice.Slicer(sonoslice.Volume.from_file(ct_path), probe).slice(poses)
    mirror = poses[0].copy()
    mirror[:3, 2] *= -1  # a left-handed frame: counted and answered with nothing
    peer.send(pyigtl.TransformMessage(mirror, device_name="ProbeToReference"))
    for k, pose in enumerate(poses):
        peer.send(pyigtl.TransformMessage(pose, timestamp=100 + k, device_name="ProbeToReference"))
        header, _, image = peer.receive()
        assert header["device_name"] == "Image" and abs(header["timestamp"] - (100 + k)) < 1e-6
        np.testing.assert_array_equal(image.image[0], expected[k])
        # The IMAGE matrix places pixel (i, j) where the pose puts it: pose · pixel → probe.
        placed = pose @ pixel_to_probe
        np.testing.assert_allclose(image.ijk_to_world_matrix[:3, :2], placed[:3, :2], atol=1e-5)
        np.testing.assert_allclose(image.ijk_to_world_matrix[:3, 3], placed[:3, 3], atol=1e-3)
    assert server.wait(30) == 0
    peer.close()
    s = json.loads(stats.read_text())
    assert s["poses_received"] == len(poses) + 1 and s["images_sent"] == len(poses), s
    assert [k for k in s["network"] if k.startswith("rejected")] == [
        "rejected: TRANSFORM ProbeToReference: not a rigid frame (a mirror image, deviation 2 from "
        "orthonormal and right-handed)"], s
    # --world RAS (3D Slicer's frame): RAS poses in, the same images, matrices in RAS.
    ras = np.diag([-1.0, -1.0, 1.0, 1.0])
    server = serve("slice", "--volume", str(ct_path), "--probe", str(probe_path), "--world", "RAS",
                   "--max-frames", "2", cli=cli)
    peer = Peer(server.port)
    for k in range(2):
        peer.send(pyigtl.TransformMessage(ras @ poses[k], device_name="ProbeToReference"))
        _, _, image = peer.receive()
        np.testing.assert_array_equal(image.image[0], expected[k])
        assert image.world_coordinate_system == "ras"
        np.testing.assert_allclose(image.ijk_to_world_matrix[:3, :2], (ras @ poses[k] @ pixel_to_probe)[:3, :2],
                                   atol=1e-5)
    assert server.wait(30) == 0
    peer.close()


def test_python_live_compounder_matches_reconstruct_plus(tmp_path, frames):
    kw = grid_kwargs(frames)
    live = LiveCompounder(CONFIG, keep_frames=True, **kw)
    for pixels, matrix, t in frames:
        assert live.push(pixels, matrix, t) is None
    snapshot = live.snapshot()
    volume = live.finish()
    assert snapshot is not None and volume.shape == tuple(reversed(kw["extent"]))
    s = live.stats()
    assert s["frames_compounded"] == len(frames) and s["latency_ms"]["p99"] > 0
    path = tmp_path / "rec.igs.mha"
    live.recorded().save(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        offline = sonoslice.reconstruct_plus(path, CONFIG, **kw)
    np.testing.assert_array_equal(volume.array, offline.array)
    # Bad input: a reason, or a ValueError naming the argument.
    nan = frames[0][1].copy()
    nan[2, 2] = np.nan
    assert "non-finite" in live.push(frames[0][0], nan)
    with pytest.raises(ValueError, match="push: a frame is"):
        live.push(np.zeros((2, 3, 4), np.uint8), frames[0][1])
    with pytest.raises(ValueError, match="queue"):
        LiveCompounder(CONFIG, queue="sometimes")
    with pytest.raises(ValueError, match="origin and extent together"):
        LiveCompounder(CONFIG, origin=(0, 0, 0))


def test_a_stray_first_pose_does_not_turn_the_sweep_away(tmp_path, frames):
    # A tracker's pose before it locks on, a metre from the sweep: the growing grid cannot take
    # both. Three frames of the sweep later the sweep wins; the stray counts as rejected, and the
    # volume is the one the sweep alone makes.
    stray = frames[0][1].copy()
    stray[:3, 3] += 1000.0
    live = LiveCompounder(CONFIG, keep_frames=True)
    live.push(frames[0][0], stray, 0.0)
    for pixels, matrix, t in frames[:8]:
        live.push(pixels, matrix, t)
    volume = live.finish()
    s = live.stats()
    assert s["frames_compounded"] == 8 and s["frames_rejected"] == 1, s
    assert s["rejected_by_reason"] == {
        "a stray pose: far from the frames that followed it, which went on without it": 1}, s
    alone = LiveCompounder(CONFIG)
    for pixels, matrix, t in frames[:8]:
        alone.push(pixels, matrix, t)
    expected = alone.finish()
    assert volume.shape == expected.shape and volume.origin == expected.origin
    np.testing.assert_array_equal(volume.array, expected.array)
    path = tmp_path / "rec.igs.mha"
    live.recorded().save(path)
    assert len(sonoslice.read_plus_sequence(path)) == 8


def test_python_server_in_process(frames):
    live = LiveCompounder(CONFIG, **grid_kwargs(frames))
    with LiveCompoundServer(live, max_frames=6) as server:
        peer = Peer(server.port)
        for pixels, matrix, t in frames[:6]:
            peer.send(image_message(pixels, matrix, t))
        volume, stats = server.wait()
        peer.close()
    assert stats["stopped_by"] == "max_frames"
    with pytest.raises(ValueError, match="10.1.2.3:5000: cannot listen"):
        LiveCompoundServer(live, listen="10.1.2.3:5000")
    assert stats["frames_compounded"] == 6 and volume.array.max() > 0


def test_virtual_probe_simulates_what_simulate_makes(cli, tmp_path):
    ct_path = tmp_path / "ct.nii.gz"
    ct, _ = sonoslice.phantom("small")
    ct.save(ct_path)
    poses = sonoslice.phantom_poses(3, seed=5).astype(np.float32).astype(np.float64)
    np.save(tmp_path / "poses.npy", poses)
    batch = tmp_path / "batch.npy"
    subprocess.run([cli, "simulate", "--volume", str(ct_path), "--preset", "abdominal", "--downsampling",
                    "1", "--poses", str(tmp_path / "poses.npy"), "--out", str(batch), "-q"], check=True)
    expected = np.load(batch)
    stats = tmp_path / "stats.json"
    server = serve("simulate", "--volume", str(ct_path), "--preset", "abdominal",
                   "--image-device", "Simulated", "--stats", str(stats), cli=cli)
    peer = Peer(server.port)
    for k, pose in enumerate(poses):
        peer.send(pyigtl.TransformMessage(pose, device_name="ProbeToReference"))
        header, _, image = peer.receive()
        assert header["device_name"] == "Simulated" and image.image.dtype == np.uint8
        np.testing.assert_array_equal(image.image[0], expected[k])
    # A NaN pose is counted and answered with nothing; the server goes on.
    bad = poses[0].copy()
    bad[0, 0] = np.nan
    peer.send(pyigtl.TransformMessage(bad, device_name="ProbeToReference"))
    peer.send(pyigtl.TransformMessage(poses[1], device_name="ProbeToReference"))
    np.testing.assert_array_equal(peer.receive()[2].image[0], expected[1])
    assert server.stop() == 0
    peer.close()
    s = json.loads(stats.read_text())
    assert s["poses_received"] == 5 and s["images_sent"] == 4 and s["rejected"] == 1
