"""PyTorch interop: DLPack round trips without copies, tensors in and out; CUDA where present."""
import numpy as np
import pytest

import sonoslice
from conftest import small_probe

torch = pytest.importorskip("torch")


def test_volume_from_a_cpu_tensor_is_zero_copy():
    t = torch.arange(4 * 5 * 6, dtype=torch.int16).reshape(4, 5, 6)
    v = sonoslice.Volume(t, spacing=(1, 1, 1))
    t[2, 3, 4] = -7
    assert v.array[2, 3, 4] == -7
    # And back: the volume's voxels as a tensor through DLPack, still the same memory.
    back = torch.utils.dlpack.from_dlpack(v.array.__dlpack__())
    assert back.data_ptr() == t.data_ptr()


def test_slicing_into_a_cpu_tensor(phantom, poses):
    ct, _ = phantom
    s = sonoslice.Slicer(ct, small_probe())
    out = torch.empty((12, 80, 96))
    address = out.data_ptr()
    r = s.slice(torch.from_numpy(poses), out=out)
    assert r is out and out.data_ptr() == address
    assert np.array_equal(out.numpy(), s.slice(poses))
    # Torch poses without out= give a torch tensor back; with mask=True the mask is one too.
    images, mask = s.slice(torch.from_numpy(poses), mask=True)
    assert isinstance(images, torch.Tensor) and isinstance(mask, torch.Tensor)
    assert np.array_equal(images.numpy(), s.slice(poses))
    assert np.array_equal(mask.numpy(), small_probe().mask)


def test_cuda_tensors_without_host_copies(phantom, poses, cuda):
    ct, _ = phantom
    cpu = sonoslice.Slicer(ct, small_probe()).slice(poses)
    s = sonoslice.Slicer(ct, small_probe(), device=cuda)
    images = s.slice(poses)  # a tensor on the GPU
    assert images.is_cuda and images.shape == (12, 80, 96)
    assert np.abs(images.cpu().numpy() - cpu).max() <= 0.05
    out = torch.empty((12, 80, 96), device=cuda)
    address = out.data_ptr()
    s.slice(poses, out=out)
    assert out.data_ptr() == address
    assert torch.equal(out, images)


def test_cuda_slicing_into_pinned_and_pageable_host_memory(phantom, poses, cuda):
    # Host output of a CUDA slicer: a pinned tensor is copied into directly (no staging), a
    # pageable one through the slicer's pinned buffers; both hold the same images. 400 images of
    # 400 × 500 (320 MB) take several chunks on both of the slicer's streams.
    ct, _ = phantom
    probe = sonoslice.Probe.linear(400, 500, (0.1, 0.1))
    many = np.tile(poses, (34, 1, 1))[:400]
    s = sonoslice.Slicer(ct, probe, device=cuda)
    pinned = torch.full((400, 500, 400), float("nan")).pin_memory()
    assert pinned.is_pinned()
    assert s.slice(many, out=pinned) is pinned
    pageable = s.slice(many, out=np.full((400, 500, 400), np.nan, dtype=np.float32))
    assert np.array_equal(pinned.numpy(), pageable)
    assert np.abs(pageable[:12] - sonoslice.Slicer(ct, probe).slice(poses)).max() <= 0.05
