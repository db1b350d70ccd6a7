"""sonoslice.torch: differentiable slicing checked by torch.autograd.gradcheck
(float64, small cases), against the CPU slicer, and the se(3) increment helper."""
import numpy as np
import pytest

import sonoslice

torch = pytest.importorskip("torch")
import sonoslice.torch as st  # noqa: E402


def small_case(seed=0):
    rng = np.random.default_rng(seed)
    volume = rng.normal(size=(7, 8, 9))  # (Z, Y, X)
    probe = sonoslice.Probe.linear(width=5, height=4, spacing_mm=0.7)
    # A pose well inside the volume, turned off the axes (so that samples fall mid-cell).
    a, b = 0.3, 0.2
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) @ \
        np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = [3.1, 2.3, 2.7]
    return volume, probe, T


def test_gradcheck_poses_and_volume():
    volume, probe, T = small_case()
    poses = torch.tensor(np.stack([T, T @ np.diag([1, 1, 1, 1.0])]), dtype=torch.float64, requires_grad=True)
    with torch.no_grad():
        poses[1, :3, 3] += torch.tensor([0.31, -0.17, 0.23], dtype=torch.float64)
    vol = torch.tensor(volume, dtype=torch.float64, requires_grad=True)
    f = lambda p, v: st.slice(v, p, probe, spacing=(0.9, 1.1, 1.0))
    assert torch.autograd.gradcheck(f, (poses, vol), eps=1e-6, atol=1e-6, rtol=1e-4)


def test_gradcheck_through_the_se3_increment():
    volume, probe, T = small_case(1)
    Tt = torch.tensor(T, dtype=torch.float64)
    xi = torch.tensor([0.1, -0.2, 0.05, 0.02, -0.03, 0.01], dtype=torch.float64, requires_grad=True)
    vol = sonoslice.Volume(volume, spacing=(1.0, 1.0, 1.0))
    f = lambda x: st.slice(vol, st.pose_increment(Tt, x), probe)
    assert torch.autograd.gradcheck(f, (xi,), eps=1e-6, atol=1e-6, rtol=1e-4)
    # exp(0) is the identity, and the increment is a rotation.
    E = st.pose_increment(torch.eye(4, dtype=torch.float64), xi.detach())
    R = E[:3, :3].numpy()
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(st.pose_increment(Tt, torch.zeros(6, dtype=torch.float64)).numpy(), T)


def test_matches_the_slicer_and_keeps_no_grid(phantom, poses):
    probe = sonoslice.Probe.workload("W1")
    p = torch.tensor(poses[:4], requires_grad=True)
    ct = phantom[0]
    images = st.slice(ct, p, probe)
    ref = sonoslice.Slicer(ct, probe).slice(poses[:4])
    assert images.shape == ref.shape
    assert np.abs(images.detach().numpy() - ref).max() <= 1e-5 * np.abs(ref).max()
    # The graph holds the poses and the volume's handle, not a (N, H, W, 3) sampling grid.
    node = images.grad_fn
    saved = [getattr(node, name) for name in dir(node) if name.startswith("_saved")]
    saved += list(getattr(node, "__dict__", {}).values())  # what the Function kept on ctx
    sizes = [s.numel() if isinstance(s, torch.Tensor) else s.size if isinstance(s, np.ndarray) else 0
             for s in saved]
    assert sizes and max(sizes) < images.numel(), sizes
    loss = (images ** 2).mean()
    loss.backward()
    assert p.grad.shape == (4, 4, 4) and torch.all(p.grad[:, 3] == 0) and torch.any(p.grad != 0)


def test_bad_input():
    volume, probe, T = small_case()
    with pytest.raises(ValueError, match="poses"):
        st.slice(torch.tensor(volume), torch.zeros(3, 3, dtype=torch.float64), probe)
    with pytest.raises(ValueError, match="volume"):
        st.slice(torch.zeros(4, 4, dtype=torch.float64), torch.tensor(T), probe)
    bad = torch.tensor(T)
    bad[0, 3] = float("nan")
    with pytest.raises(ValueError, match="pose 0"):
        st.slice(torch.tensor(volume), bad, probe)
    with pytest.raises(ValueError, match="^volume: complex values"):
        st.slice(torch.tensor(volume, dtype=torch.complex128), torch.tensor(T), probe)
    with pytest.raises(ValueError, match="^poses: complex values"):
        st.slice(torch.tensor(volume), torch.tensor(T, dtype=torch.complex128), probe)
    with pytest.raises(ValueError, match=r"^xi: expected \(6,\) or \(N, 6\)"):
        st.pose_increment(torch.tensor(T), torch.zeros(5, dtype=torch.float64))


def test_integer_volume_gives_float_images_and_pose_gradients():
    volume, probe, T = small_case()
    ints = torch.tensor(np.round(volume * 100), dtype=torch.int16)
    poses = torch.tensor(T, requires_grad=True)
    images = st.slice(ints, poses, probe)
    assert images.dtype == torch.float64
    images.sum().backward()
    assert poses.grad is not None and torch.isfinite(poses.grad).all() and poses.grad.abs().sum() > 0
    same = st.slice(torch.tensor(np.round(volume * 100)), torch.tensor(T), probe)
    assert torch.equal(images.detach(), same)


def test_a_volume_changed_in_place_before_backward_is_refused():
    volume, probe, T = small_case()
    v = torch.tensor(volume, requires_grad=True)
    loss = st.slice(v, torch.tensor(T, requires_grad=True), probe).sum()
    with torch.no_grad():
        v.add_(1.0)
    with pytest.raises(RuntimeError, match="modified by an inplace operation"):
        loss.backward()
