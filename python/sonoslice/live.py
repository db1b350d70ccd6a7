"""Live ultrasound (docs/live.md): tracked frames compounded as they arrive.

:class:`LiveCompounder` takes frames (NumPy (H, W) + a 4×4 image → reference matrix) one at a time
from your own acquisition code, with the queue policies of ``sonoslice live compound``, and gives
snapshots and statistics; the final volume is byte-identical to ``sonoslice compound`` of the same
frames on the same grid. :class:`LiveCompoundServer` runs ``sonoslice live compound``'s server on
a thread of this process (OpenIGTLink IMAGE messages in, PlusServer's commands); :func:`serve`
starts any ``sonoslice live`` command (``slice`` too) as a process and tells its port.
"""
import json
import os
import shutil
import signal
import subprocess
from typing import Any, Dict, Iterator, Optional, Tuple

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .compounding import _dtype_name, _frame_clip, _hole_elements, _memory_bytes, _spacing3
from .plus import PlusSequence, TransformRepository, _as_config, _as_sequence
from .volume import Volume


class LiveCompounder:
    """Frames in, a growing volume out. Settings as :func:`reconstruct_plus` takes them
    (``config`` a PLUS configuration XML or :class:`PlusConfig`, then the keywords override it).
    The grid: ``origin`` (centre of voxel (0, 0, 0), mm) with ``extent`` (voxels along x, y, z),
    else the configuration's OutputOrigin/OutputExtent, else it grows around the frames on the
    lattice of ``spacing`` (keeping the frames; :meth:`finish` fits it tightly).

    ``queue="all"``: every frame is compounded, :meth:`push` waits while ``queue_size`` frames
    wait; ``"newest"``: only the newest waiting frame is kept, the others are counted as dropped.
    ``keep_frames=True`` keeps the compounded frames for :meth:`recorded`."""

    def __init__(self, config=None, *, spacing=None, origin=None, extent=None,
                 interpolation: Optional[str] = None, compounding: Optional[str] = None,
                 fill_holes: Optional[bool] = None, hole_filling=None,
                 rejection_threshold: Optional[float] = None, clip=None, dtype=None,
                 device: str = "cpu", max_memory=None, queue: str = "all", queue_size: int = 16,
                 keep_frames: bool = False):
        cfg = _as_config(config)
        self._shape: Optional[Tuple[int, int]] = None
        self._clip = clip
        self._cpp = _ext.LiveCompounder(
            None if cfg is None else cfg._cpp,
            spacing=None if spacing is None else _spacing3(spacing, "spacing"),
            origin=None if origin is None else _arrays.floats(origin, "origin", 3),
            extent=None if extent is None else tuple(_arrays.whole(v, "extent") for v in extent),
            interpolation=None if interpolation is None else str(interpolation),
            compounding=None if compounding is None else str(compounding),
            fill_holes=None if fill_holes is None else bool(fill_holes),
            hole_filling=_hole_elements(hole_filling),
            rejection_threshold=None if rejection_threshold is None else _arrays.number(rejection_threshold, "rejection_threshold"),
            clip=None if clip is None else _frame_clip(clip, "clip"),
            dtype=None if dtype is None else _dtype_name(dtype, "dtype"), device=str(device),
            max_memory=_memory_bytes(max_memory), queue=str(queue),
            queue_size=_arrays.whole(queue_size, "queue_size"), keep_frames=bool(keep_frames))

    def push(self, frame, image_to_reference, timestamp: float = 0.0) -> Optional[str]:
        """Queues an (H, W) frame (uint8, int8, uint16, int16 or float32; copied) placed by
        ``image_to_reference`` (pixel (i, j, 0) → mm). Returns None when queued, else why it was
        refused (also counted in :meth:`stats`)."""
        if frame is None:
            raise TypeError("push: frame: expected an (H, W) array, got None")
        frame = np.ascontiguousarray(_arrays.numpy_of(frame))
        matrix = _arrays.matrices(image_to_reference, "image_to_reference", 1, single=True)[0]
        why = self._cpp.push(frame, np.ascontiguousarray(matrix, dtype=np.float64), _arrays.number(timestamp, "timestamp"))
        return why or None

    @property
    def full(self) -> bool:
        """queue="all": ``queue_size`` frames wait (a push would wait)."""
        return self._cpp.full

    def drain(self) -> None:
        """Waits until every queued frame is in the volume."""
        self._cpp.drain()

    def suspend(self) -> None:
        """Frames pushed from now on are counted, not compounded (PlusServer's Suspend)."""
        self._cpp.suspend()

    def resume(self) -> None:
        self._cpp.resume()

    @property
    def suspended(self) -> bool:
        return self._cpp.suspended

    def reset(self) -> None:
        """An empty volume (and record) from here on; counts go on (PlusServer's Start)."""
        self._cpp.reset()

    def snapshot(self) -> Optional[Volume]:
        """The volume of the frames compounded so far (None before the first)."""
        v = self._cpp.snapshot()
        return Volume._wrap(v) if v.shape[0] else None

    def finish(self) -> Optional[Volume]:
        """Waits for the queue, then the final volume (None when no frame went in)."""
        v = self._cpp.finish()
        return Volume._wrap(v) if v.shape[0] else None

    def stats(self) -> Dict[str, Any]:
        """frames_received, frames_compounded, frames_dropped, frames_suspended, frames_rejected
        (and rejected_by_reason), frames_waiting, bytes, latency_ms {p50, p95, p99, max} from a
        frame's push to its being in the volume, seconds, and the grid."""
        return json.loads(self._cpp.stats_json())

    def recorded(self) -> PlusSequence:
        """The compounded frames as a PLUS sequence (needs keep_frames=True): ``save()`` it and
        ``sonoslice compound`` reproduces the volume."""
        return PlusSequence(self._cpp.recorded())


def _host_port(text: str, what: str) -> Tuple[str, int]:
    host, _, port = _arrays.text(text, what).rpartition(":")
    try:
        value = int(port)
    except ValueError:
        raise ValueError(f"{what} {text!r}: expected [HOST:]PORT") from None
    return host or "127.0.0.1", value


class LiveCompoundServer:
    """``sonoslice live compound``'s server on a thread of this process: IMAGE messages are frames
    for ``compounder``, PlusServer's volume reconstruction commands are answered (docs/live.md).
    ``listen="[HOST:]PORT"`` (default 127.0.0.1 and a free port: see :attr:`port`) or
    ``connect="HOST:PORT"``. Stops at ``max_frames``, ``max_seconds``, a StopVolumeReconstruction
    command or :meth:`stop`; :meth:`wait` returns (volume, stats). A context manager: leaving it
    stops and waits."""

    def __init__(self, compounder: LiveCompounder, *, listen: Optional[str] = "127.0.0.1:0",
                 connect: Optional[str] = None, image_device: Optional[str] = None,
                 max_frames: int = 0, max_seconds: float = 0.0):
        if connect is not None:
            host, port = _host_port(connect, "connect")
        else:
            host, port = _host_port(listen, "listen")
        self._compounder = compounder
        self._result = None
        self._cpp = _ext.LiveCompoundServer(compounder._cpp, listen=connect is None, host=host, port=port,
                                            image_device=image_device or "",
                                            max_frames=_arrays.whole(max_frames, "max_frames"),
                                            max_seconds=_arrays.number(max_seconds, "max_seconds"))

    @property
    def port(self) -> int:
        return self._cpp.port

    def stop(self) -> None:
        self._cpp.stop()

    def wait(self) -> Tuple[Optional[Volume], Dict[str, Any]]:
        """Joins the server: (final volume or None, statistics with "network" counts and
        "stopped_by")."""
        if self._result is None:
            volume, text = self._cpp.wait()
            stats = json.loads(text)
            # "--max-frames" (the CLI's words) as this class's keyword
            stopped_by = stats["stopped_by"]
            stats["stopped_by"] = stopped_by[2:].replace("-", "_") if stopped_by.startswith("--") else stopped_by
            self._result = (Volume._wrap(volume) if volume.shape[0] else None, stats)
        return self._result

    def __enter__(self) -> "LiveCompoundServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        self.wait()


def plus_frames(sequence, config=None, transform: str = "ImageToReference"
                ) -> Iterator[Tuple[np.ndarray, np.ndarray, float]]:
    """(pixels (H, W), 4×4 image → reference, timestamp) for each frame of a PLUS sequence whose
    image is OK and whose ``transform`` chain (the frame's transforms and the configuration's
    CoordinateDefinitions) is valid, as PlusServer would broadcast them."""
    seq = _as_sequence(sequence)
    cfg = _as_config(config)
    repository = cfg.coordinate_definitions.copy() if cfg is not None else TransformRepository()
    frames, timestamps = seq.frames, seq.timestamps
    for k in range(len(seq)):
        repository.set_frame(seq, k)
        matrix = repository.get(transform)
        if matrix is None or not seq.image_ok(k):
            continue
        yield frames[k], matrix, float(timestamps[k]) if np.isfinite(timestamps[k]) else 0.0


class CliServer:
    """A ``sonoslice live`` command running as a process (see :func:`serve`)."""

    def __init__(self, process: subprocess.Popen, port: int):
        self.process, self.port = process, port

    def stop(self, timeout: float = 60) -> int:
        """SIGINT (the command writes its outputs and exits 0), then waits; the exit status."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        return self.wait(timeout)

    def wait(self, timeout: Optional[float] = None) -> int:
        """Waits for the command to end by itself; its exit status."""
        return self.process.wait(timeout)

    def __enter__(self) -> "CliServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def serve(command: str, *args: str, cli: Optional[str] = None, **popen) -> CliServer:
    """Starts ``sonoslice live COMMAND --listen 127.0.0.1:0 ARGS...`` (``command``: "compound" or
    "slice") and returns once it listens, with its port. ``cli``: the sonoslice executable
    (default: $SONOSLICE_CLI, else ``sonoslice`` on PATH)."""
    exe = cli or os.environ.get("SONOSLICE_CLI") or shutil.which("sonoslice")
    if not exe:
        raise FileNotFoundError("serve: no sonoslice executable (give cli= or set SONOSLICE_CLI)")
    listen = [] if any(a in ("--listen", "--connect") for a in args) else ["--listen", "127.0.0.1:0"]
    process = subprocess.Popen([exe, "live", command, *listen, *args], stdout=subprocess.PIPE,
                               text=True, **popen)
    line = process.stdout.readline()
    if "listening on" not in line and "connecting to" not in line:
        process.wait(30)
        raise RuntimeError(f"sonoslice live {command} did not start (exit status "
                           f"{process.returncode}): {line.strip()}")
    return CliServer(process, int(line.rsplit(":", 1)[1]))
