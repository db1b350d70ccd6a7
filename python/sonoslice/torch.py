"""Differentiable slicing for PyTorch (docs/registration.md §7).

``sonoslice.torch.slice(volume, poses, probe)`` returns the linear slices (N, H, W) of ``poses``
as a tensor that autograd can differentiate with respect to the poses ((N, 4, 4) probe→world,
mm) and, when ``volume`` is a tensor that requires grad, the volume. The backward pass computes
dL/d(pose) from the trilinear interpolant's exact derivatives in the kernel, pixel by pixel,
without storing a sampling grid: memory is O(N) beyond the images. CPU, float64 throughout (the
result is cast to a floating volume tensor's dtype, else to the poses' floating dtype, so that
an integer volume still gives pose gradients).

To optimise an increment ξ ∈ se(3) instead of the 4×4 entries, compose it with
``pose_increment(T, xi)`` (T·exp(ξ), differentiable in torch) and slice the result.
"""
from typing import Optional, Sequence

import numpy as np
import torch as _torch

from . import _arrays
from . import _sonoslice as _ext
from .slicing import Probe
from .volume import Volume

__all__ = ["slice", "pose_increment"]


def _geometry_volume(volume, spacing, origin, direction):
    """(sonoslice.Volume for the kernel, tensor or None)."""
    if isinstance(volume, Volume):
        return volume, None
    if not isinstance(volume, _torch.Tensor):
        raise TypeError("volume: expected a sonoslice.Volume or a (Z, Y, X) torch tensor")
    if volume.ndim != 3:
        raise ValueError(f"volume: expected (Z, Y, X), got shape {tuple(volume.shape)}")
    if volume.is_complex():
        raise ValueError(f"volume: complex values ({volume.dtype}) have no meaning as intensities; "
                         "pass the real part or the magnitude")
    array = np.ascontiguousarray(volume.detach().cpu().numpy().astype(np.float64, copy=False))
    kwargs = {"spacing": spacing}
    if origin is not None:
        kwargs["origin"] = origin
    if direction is not None:
        kwargs["direction"] = direction
    return Volume(array, **kwargs), volume


class _Slice(_torch.autograd.Function):
    @staticmethod
    def forward(ctx, poses, volume_tensor, volume, probe, fill):
        # poses: (N, 3, 4), the rows that move a pixel; the last row is always (0, 0, 0, 1).
        top = poses.detach().cpu().numpy().astype(np.float64)
        p = np.zeros((top.shape[0], 4, 4))
        p[:, :3] = top
        p[:, 3, 3] = 1
        images = _ext.slice_linear_f64(volume._cpp, probe._cpp, p, float(fill))
        ctx.volume, ctx.probe, ctx.poses = volume, probe, p
        ctx.volume_grad = volume_tensor is not None and volume_tensor.requires_grad
        # The kernel reads the tensor's memory (no copy for a contiguous float64 tensor): saving it
        # lets autograd's version counter refuse a backward after an in-place change to it.
        ctx.save_for_backward(volume_tensor)
        floating = volume_tensor is not None and volume_tensor.is_floating_point()
        dtype = volume_tensor.dtype if floating else poses.dtype
        return _torch.from_numpy(np.array(images)).to(dtype=dtype, device=poses.device)

    @staticmethod
    def backward(ctx, grad):
        ctx.saved_tensors  # raises if the volume tensor was modified in place since forward
        g = np.ascontiguousarray(grad.detach().cpu().numpy(), dtype=np.float64)
        grad_poses, grad_volume = _ext.slice_linear_backward(ctx.volume._cpp, ctx.probe._cpp, ctx.poses, g,
                                                             bool(ctx.volume_grad))
        gp = _torch.from_numpy(np.array(grad_poses)[:, :3]).to(dtype=grad.dtype, device=grad.device)
        gv = None
        if ctx.volume_grad:
            gv = _torch.from_numpy(np.array(grad_volume)).to(dtype=grad.dtype, device=grad.device)
        return gp, gv, None, None, None


def slice(volume, poses, probe: Probe, *, spacing: Sequence[float] = (1.0, 1.0, 1.0),
          origin: Optional[Sequence[float]] = None, direction=None, fill: float = 0.0):
    """Linear slices of ``volume`` at ``poses`` ((N, 4, 4) or (4, 4) tensor, probe→world mm, LPS)
    with ``probe``'s grid: an (N, H, W) tensor, differentiable with respect to ``poses`` and,
    when ``volume`` is a (Z, Y, X) tensor that requires grad (its geometry given by ``spacing``,
    ``origin``, ``direction`` as for :class:`sonoslice.Volume`), the volume. Pixels outside the
    fan or the volume are ``fill`` (gradient 0)."""
    if not isinstance(probe, Probe):
        raise TypeError("probe: expected a sonoslice.Probe")
    if not isinstance(poses, _torch.Tensor):
        poses = _torch.as_tensor(_arrays.matrices(poses, "poses"))
    if poses.is_complex():
        raise ValueError(f"poses: complex values ({poses.dtype}) are not a pose")
    if not poses.is_floating_point():
        poses = poses.to(_torch.float64)
    squeeze = poses.ndim == 2
    poses = _arrays.matrix_stack(poses, "poses")  # the tensor itself: autograd follows it
    geometry, tensor = _geometry_volume(volume, spacing, origin, direction)
    # Only the top three rows reach the kernel: the last row does not move a pixel (its gradient
    # is 0) and is not checked, so autograd and gradcheck may perturb it freely.
    out = _Slice.apply(poses[:, :3, :], tensor, geometry, probe, fill)
    return out[0] if squeeze else out


def pose_increment(T, xi):
    """T·exp(ξ) for ξ = (v, ω) (N, 6) or (6,): translation v (mm) and rotation ω (rad, axis times
    angle, Rodrigues) in the probe frame, composed on the right; differentiable in torch, also
    at ξ = 0."""
    if not isinstance(T, _torch.Tensor) or T.shape[-2:] != (4, 4):
        raise ValueError("T: expected a (4, 4) or (N, 4, 4) torch tensor")
    xi = _torch.as_tensor(xi, dtype=T.dtype, device=T.device)
    if xi.ndim not in (1, 2) or xi.shape[-1] != 6:
        raise ValueError(f"xi: expected (6,) or (N, 6): translation (3) and rotation (3), got shape "
                         f"{tuple(xi.shape)}")
    single = xi.ndim == 1
    if single:
        xi = xi[None]
    v, w = xi[:, :3], xi[:, 3:]
    theta2 = (w * w).sum(-1, keepdim=True)
    theta = _torch.sqrt(theta2 + 1e-30)
    small = theta2 < 1e-12
    # sin θ / θ and (1 − cos θ) / θ², by their series near 0 (finite gradients there).
    a = _torch.where(small, 1 - theta2 / 6, _torch.sin(theta) / theta)
    b = _torch.where(small, 0.5 - theta2 / 24, (1 - _torch.cos(theta)) / (theta2 + 1e-30))
    zero = _torch.zeros_like(w[:, 0])
    K = _torch.stack([_torch.stack([zero, -w[:, 2], w[:, 1]], -1),
                      _torch.stack([w[:, 2], zero, -w[:, 0]], -1),
                      _torch.stack([-w[:, 1], w[:, 0], zero], -1)], -2)
    eye = _torch.eye(3, dtype=T.dtype, device=T.device).expand_as(K)
    R = eye + a[..., None] * K + b[..., None] * (K @ K)
    E = _torch.zeros(xi.shape[0], 4, 4, dtype=T.dtype, device=T.device)
    E[:, :3, :3] = R
    E[:, :3, 3] = v
    E[:, 3, 3] = 1
    out = T @ E
    return out[0] if single and out.shape[0] == 1 and T.ndim == 2 else out
