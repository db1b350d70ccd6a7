#!/usr/bin/env python3
"""Feed a PyTorch training loop with freshly sliced ultrasound-shaped images.

An ``IterableDataset`` draws probe poses on the phantom's skin with a seeded pose sampler
(``sonoslice.PoseSampler``, docs/datasets.md §2: the probe's face on the body surface, tilted and
turned at random, kept when 80 % of its fan is inside the body), slices them on the GPU (or the
CPU where there is none) and yields (image batch, target) pairs; the images never leave the GPU.
Batch k's poses come from the seeds ``sample_seeds(seed, 0, k * batch, batch)``, so any batch can
be made again. The toy task: regress the probe's position from its image. A few hundred steps
show the loss falling; swap in your own network, targets and volume. To train on a dataset
written to disk by ``sonoslice dataset`` instead, see ``sonoslice.datasets.reader.ShardDataset``
(docs/datasets.md §6).

    python examples/torch_training_dataset.py [--steps 200] [--device cuda:0]
"""
import argparse
import time

import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset

import sonoslice

SKIN = {"type": "skin", "tilt_deg": [-20, 20], "heel_toe_deg": [-10, 10], "rotation_deg": [0, 360],
        "reject": {"min_body": 0.8}}


class SlicedImages(IterableDataset):
    """Endless batches of (images (B, 1, H, W), probe positions (B, 3) in dm from the volume's centre)."""

    def __init__(self, slicer, sampler, centre_mm, batch_size, seed=0):
        self.slicer, self.sampler, self.centre, self.batch, self.seed = slicer, sampler, centre_mm, batch_size, seed

    def __iter__(self):
        device = self.slicer.device if self.slicer.device.startswith("cuda") else "cpu"
        for k in range(2 ** 62):
            poses = self.sampler.sample(sonoslice.sample_seeds(self.seed, 0, k * self.batch, self.batch))
            images = self.slicer.slice(torch.from_numpy(poses))  # (B, H, W), on the slicer's device
            images = images.to(device).unsqueeze(1) / 1000.0      # HU → ~unit range
            yield images, torch.from_numpy((poses[:, :3, 3] - self.centre) / 100).float().to(device)


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
    sampler = sonoslice.PoseSampler(SKIN, probe, volume=ct)
    centre = ct.index_to_world((np.array(ct.shape[::-1]) - 1) / 2)
    data = SlicedImages(slicer, sampler, centre_mm=centre, batch_size=args.batch)
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
