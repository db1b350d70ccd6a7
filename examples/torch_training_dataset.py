#!/usr/bin/env python3
"""Feed a PyTorch training loop with freshly sliced ultrasound-shaped images.

An ``IterableDataset`` draws random probe poses around a target, slices them on the GPU (or the
CPU where there is none) and yields (image batch, target) pairs; the images never leave the GPU.
The toy task: regress the probe's position from its image. A few hundred steps show the loss
falling; swap in your own network, targets and volume.

    python examples/torch_training_dataset.py [--steps 200] [--device cuda:0]
"""
import argparse
import time

import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset

import sonoslice


def random_rotations(rng, n):
    """Uniform random rotations (Shoemake), as (n, 3, 3)."""
    u1, u2, u3 = rng.random(n), rng.random(n) * 2 * np.pi, rng.random(n) * 2 * np.pi
    a, b = np.sqrt(1 - u1), np.sqrt(u1)
    w, x, y, z = a * np.sin(u2), a * np.cos(u2), b * np.sin(u3), b * np.cos(u3)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


class SlicedImages(IterableDataset):
    """Endless batches of (images (B, 1, H, W), probe positions (B, 3) in cm)."""

    def __init__(self, slicer, centre_mm, radius_mm, batch_size, seed=0):
        self.slicer, self.centre, self.radius, self.batch, self.seed = slicer, centre_mm, radius_mm, batch_size, seed

    def __iter__(self):
        rng = np.random.default_rng(self.seed)
        device = self.slicer.device if self.slicer.device.startswith("cuda") else "cpu"
        while True:
            poses = np.tile(np.eye(4), (self.batch, 1, 1))
            poses[:, :3, :3] = random_rotations(rng, self.batch)
            offset = rng.uniform(-self.radius, self.radius, (self.batch, 3))
            poses[:, :3, 3] = self.centre + offset
            images = self.slicer.slice(torch.from_numpy(poses))  # (B, H, W), on the slicer's device
            images = images.to(device).unsqueeze(1) / 1000.0      # HU → ~unit range
            yield images, torch.from_numpy(offset / 10).float().to(device)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--device", default="cuda:0" if sonoslice.cuda_available() else "cpu")
    args = ap.parse_args()

    ct, _ = sonoslice.phantom("small")
    probe = sonoslice.Probe.curvilinear(radius_mm=20, depth_mm=90, sector_deg=70, width=96, height=96,
                                        spacing_mm=1.0)
    slicer = sonoslice.Slicer(ct, probe, device=args.device)
    data = SlicedImages(slicer, centre_mm=np.array([-40.0, 0.0, 60.0]), radius_mm=30.0, batch_size=args.batch)
    loader = DataLoader(data, batch_size=None)  # the dataset batches already

    device = args.device if args.device.startswith("cuda") else "cpu"
    net = torch.nn.Sequential(
        torch.nn.Conv2d(1, 16, 5, stride=2), torch.nn.ReLU(),
        torch.nn.Conv2d(16, 32, 5, stride=2), torch.nn.ReLU(),
        torch.nn.Conv2d(32, 32, 3, stride=2), torch.nn.ReLU(),
        torch.nn.AdaptiveAvgPool2d(4), torch.nn.Flatten(), torch.nn.Linear(512, 3)).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    t0, first = time.perf_counter(), None
    for step, (images, target) in enumerate(loader):
        loss = torch.nn.functional.mse_loss(net(images), target)
        opt.zero_grad()
        loss.backward()
        opt.step()
        first = first if first is not None else loss.item()
        if step % 50 == 0 or step == args.steps - 1:
            print(f"step {step:4d}  loss {loss.item():.4f}")
        if step == args.steps - 1:
            break
    dt = time.perf_counter() - t0
    print(f"{args.steps * args.batch} images sliced and trained on in {dt:.1f} s on {args.device}; "
          f"loss {first:.3f} -> {loss.item():.3f}")


if __name__ == "__main__":
    main()
