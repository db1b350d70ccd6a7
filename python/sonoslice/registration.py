"""Registration (C++: register/; docs/registration.md): refining the poses of ultrasound frames
against a volume. The settings, their defaults and their rules (the optimiser: lm for ssd and
ncc, bobyqa for the others) are the library's (:class:`RegistrationSettings`); :func:`register`
passes on what its caller gave. Differentiable slicing for PyTorch is :mod:`sonoslice.torch`."""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from . import _arrays
from . import _sonoslice as _ext
from .plus import PlusSequence, _as_config, _as_sequence
from .slicing import Probe
from .volume import Volume

__all__ = ["register", "register_sequence", "RegistrationSettings", "RegistrationMetric", "RegistrationOptimizer", "RegistrationMode"]

RegistrationSettings = _ext.RegistrationSettings
RegistrationMetric = _ext.RegistrationMetric
RegistrationOptimizer = _ext.RegistrationOptimizer
RegistrationMode = _ext.RegistrationMode


def _settings(settings: Optional[RegistrationSettings], given: dict) -> RegistrationSettings:
    """``settings``, or the settings of the keywords given (None: the library's default)."""
    given = {k: v for k, v in given.items() if v is not None}
    if settings is not None:
        if given:
            raise TypeError(f"register: give settings= or the keywords {sorted(given)}, not both")
        if not isinstance(settings, RegistrationSettings):
            raise TypeError("settings: expected a sonoslice.RegistrationSettings")
        return settings
    for key, kind in (("metric", RegistrationMetric), ("optimizer", RegistrationOptimizer),
                      ("mode", RegistrationMode)):
        if key in given:
            given[key] = _arrays.choice(kind, given[key], key)
    # Checked here so that a wrong type gets an error naming the setting, not nanobind's generic one.
    for key in ("starts", "seed"):
        if key in given:
            given[key] = _arrays.whole(given[key], key)
    for key in ("search_rot_deg", "search_trans_mm", "smoothness"):
        if key in given:
            given[key] = _arrays.floats(given[key], key, 1)[0]
    if "pyramid" in given:
        given["pyramid"] = [_arrays.whole(level, "pyramid") for level in given["pyramid"]]
    return RegistrationSettings(**given)


def _report(report) -> dict:
    """The typed report as the dict ``sonoslice register --report`` writes."""
    s = report.settings
    out = {"metric": str(s.metric), "optimizer": str(s.optimizer), "mode": str(s.mode),
           "starts": "auto" if s.starts is None else s.starts}
    if s.mode == RegistrationMode.smooth_sweep:
        out["smoothness"] = s.smoothness
    keys = ("index", "metric", "evaluations", "iterations", "translation_change_mm", "rotation_change_deg",
            "starts", "agreeing_starts", "confidence", "converged", "uncertainty_mm", "uncertainty_deg")
    out["frames"] = [{k: getattr(f, k) for k in keys} for f in report.frames]
    out["converged_frames"] = sum(f.converged for f in report.frames)
    if report.correction is not None:  # rigid-sweep and smooth-sweep: world side; calibration: probe side
        out["correction"] = report.correction[0].tolist()
    if report.sweep_metric is not None:
        out["sweep_metric"] = report.sweep_metric
    if report.halves_mm is not None:
        out["halves_mm"] = report.halves_mm
    if report.sides_mm is not None:
        out["sides_mm"] = report.sides_mm
    out.update(evaluations=int(report.evaluations), seconds=float(report.seconds))
    return out


def _frames_and_poses(volume, probe, frames, poses, world: str):
    """The checked inputs of register and registration_cost: (N, H, W) float32 frames (one (H, W)
    frame as N = 1) and (N, 4, 4) LPS poses."""
    if not isinstance(volume, Volume):
        raise TypeError("volume: expected a sonoslice.Volume")
    if not isinstance(probe, Probe):
        raise TypeError("probe: expected a sonoslice.Probe")
    f = np.ascontiguousarray(_arrays.real_array(frames, "frames"), dtype=np.float32)
    if f.ndim == 2:
        f = f[None]
    if f.ndim != 3:
        raise ValueError(f"frames: expected (N, H, W), got shape {f.shape}")
    return f, _arrays.pose_array(poses, world)


def register(volume: Volume, probe: Probe, frames, poses, *, metric: Optional[str] = None,
             optimizer: Optional[str] = None, mode: Optional[str] = None, starts: Optional[int] = None,
             search_rot_deg: Optional[float] = None, search_trans_mm: Optional[float] = None,
             seed: Optional[int] = None, pyramid: Optional[Sequence[int]] = None, mask=None, world: str = "LPS",
             smoothness: Optional[float] = None, settings: Optional[RegistrationSettings] = None):
    """Refines the poses of ``frames`` ((N, H, W) on ``probe``'s grid, any real dtype) against
    ``volume`` from ``poses`` ((N, 4, 4) probe→world, mm), as ``sonoslice register`` does
    (docs/registration.md). ``mask``: an (H, W) array, non-zero where pixels are compared (with
    the fan). Returns ``(refined, report)``: (N, 4, 4) float64 poses in ``world`` and a dict with
    the settings used ("metric", "optimizer", "mode", "starts", and "smoothness" for smooth-sweep),
    "frames" (one dict per frame: index, metric, evaluations, iterations,
    translation_change_mm, rotation_change_deg, starts, agreeing_starts, confidence, converged,
    uncertainty_mm, uncertainty_deg),
    "converged_frames", "correction" (the sweep modes' and calibration's shared 4×4 correction),
    "sweep_metric" (their cost over the whole sweep at that correction), "halves_mm" (how far
    apart the sweep's first and second halves end, each refined alone from that correction),
    "sides_mm" (the same for the left and right halves of its frames' pixels),
    "evaluations" and "seconds". A frame is converged when its best pose was
    reached from at least three starts (and, in rigid-sweep and calibration mode, both splits end
    at most 0.5 mm apart); a registration with frames that are not warns
    (``UserWarning``, one message). ``starts``: None (default) runs starts until three agree,
    at most 48 for ssd and ncc, 12 for the others (a sweep's shared correction: at most 16).

    The settings are :class:`RegistrationSettings`' (give one as ``settings``, or its keywords;
    unset ones take the library's defaults, ``RegistrationSettings()``). ``optimizer``: by default
    "lm" for "ssd" and "ncc",
    "bobyqa" for "lncc", "mi" and "lc2". ``mode``: "per-frame", "rigid-sweep" or "smooth-sweep"
    (``smoothness``: the prior's relative weight)."""
    s = _settings(settings, dict(metric=metric, optimizer=optimizer, mode=mode, starts=starts,
                                 search_rot_deg=search_rot_deg, search_trans_mm=search_trans_mm, seed=seed,
                                 pyramid=pyramid, smoothness=smoothness))
    f, p = _frames_and_poses(volume, probe, frames, poses, world)
    m = None if mask is None else _arrays.mask_array(_arrays.real_array(mask, "mask"), "mask")
    refined, report = _ext.register_frames(volume._cpp, probe._cpp, f, p, mask=m, settings=s)
    return np.ascontiguousarray(_arrays.pose_to_lps(refined, world)), _report(report)


def register_sequence(volume: Volume, sequence, config=None, *, metric: Optional[str] = None,
                      optimizer: Optional[str] = None, mode: Optional[str] = None, starts: Optional[int] = None,
                      search_rot_deg: Optional[float] = None, search_trans_mm: Optional[float] = None,
                      seed: Optional[int] = None, pyramid: Optional[Sequence[int]] = None,
                      smoothness: Optional[float] = None, settings: Optional[RegistrationSettings] = None,
                      corrected: bool = False):
    """Registers a PLUS sequence's tracked frames to ``volume``, as ``sonoslice register --sequence
    S --config C`` does (one C++ function; docs/registration.md §4): the frames and their
    ImageToReference chains that ``compound`` would use, the configuration's clip as the mask.
    ``sequence``/``config``: objects (:func:`read_plus_sequence`, :func:`read_plus_config`) or
    paths; ``config`` None: no calibration, every frame, no clip. The settings are
    :func:`register`'s.

    Returns ``(image_to_reference, report)``: the refined ImageToReference of each frame used,
    (M, 4, 4) float64 in the sequence's reference frame (its own matrix moved by the correction
    found, so a calibration's scale stays), and :func:`register`'s report with
    "sequence_frames" (the sequence's frames used), "skipped" (why frames were left out, when
    some were) and, in calibration mode with an Image → Probe calibration in the configuration,
    "image_to_probe" (that calibration corrected, 4 × 4).

    ``corrected=True`` returns ``(image_to_reference, report, corrected_sequence)``: the sequence
    with the tracked transform of each frame used corrected (the first of the frame's own
    transforms on its ImageToReference chain, typically ProbeToTracker), so that
    :func:`reconstruct_plus` or ``sonoslice compound`` with the same configuration puts the frames
    where registration did; ``corrected_sequence.save(path)`` writes it (docs/registration.md §4)."""
    if not isinstance(volume, Volume):
        raise TypeError("volume: expected a sonoslice.Volume")
    s = _settings(settings, dict(metric=metric, optimizer=optimizer, mode=mode, starts=starts,
                                 search_rot_deg=search_rot_deg, search_trans_mm=search_trans_mm, seed=seed,
                                 pyramid=pyramid, smoothness=smoothness))
    seq, cfg = _as_sequence(sequence), _as_config(config)
    if not isinstance(corrected, bool):
        raise TypeError("corrected: expected True or False")
    frames, matrices, image_to_probe, skipped, report, fixed = _ext.register_plus_sequence(
        volume._cpp, seq._cpp, None if cfg is None else cfg._cpp, settings=s, corrected=corrected)
    out = _report(report)
    out["sequence"] = seq.path
    out["sequence_frames"] = list(frames)
    if skipped:
        out["skipped"] = skipped
    if image_to_probe is not None:
        out["image_to_probe"] = np.asarray(image_to_probe).tolist()
    if corrected:
        return np.ascontiguousarray(matrices), out, PlusSequence(fixed)
    return np.ascontiguousarray(matrices), out


def registration_cost(volume: Volume, probe: Probe, frames, poses, *, metric: str = "ncc", level: int = 1,
                      world: str = "LPS") -> np.ndarray:
    """The cost ``register`` minimises for each frame at its pose: frame i of ``frames`` ((N, H, W)
    on ``probe``'s grid) at pose i of ``poses`` ((N, 4, 4) probe→world, mm), with ``metric`` at
    pyramid ``level`` (a block size: 1 is full resolution). SSD, 1 − NCC, 1 − LNCC, −MI or
    1 − LC2 (docs/registration.md §2); +inf where too few pixels overlap the volume. For looking
    at a metric's landscape: give one frame repeated along a path of poses."""
    f, p = _frames_and_poses(volume, probe, frames, poses, world)
    s = _settings(None, dict(metric=metric))
    return np.asarray(_ext.registration_costs(volume._cpp, probe._cpp, f, p, s.metric, _arrays.whole(level, "level")))
