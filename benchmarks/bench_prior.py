"""Prior timings: one 250x165 image by MultiDiffusion + DDIM (target: < 20 s with 20 steps on
2 CPU cores) and one training step on 64x64 patches, with the default tiny-backend config.

Timings do not depend on the weights, so an untrained prior is used; the Gaussians are a
synthetic blob (--gaussians N) or a finished run's model (--run RUN).

    python benchmarks/bench_prior.py [--steps 20] [--gaussians 20000] [--run RUN] [--device cpu]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.prior.model import Prior, PriorConfig
from inceptiongs.prior.trainer import PriorTrainer


def synthetic_scene(n: int, width: int = 250, height: int = 165):
    g = torch.Generator().manual_seed(0)
    gaussians = Gaussians((torch.rand(n, 3, generator=g) * 2 - 1) * 0.7,
                          torch.full((n, 3), -3.5) + torch.rand(n, 3, generator=g),
                          torch.randn(n, 4, generator=g), torch.full((n,), 1.0),
                          torch.rand(n, 1, 3, generator=g))
    cameras = [Camera(f"c{i}", width, height, 220.0, 220.0, width / 2, height / 2,
                      look_at(np.array([3 * np.sin(a), 0.2, -3 * np.cos(a)]), np.zeros(3)))
               for i, a in enumerate(np.linspace(0, 1.5, 4))]
    photos = [np.full((height, width, 3), 0.5, np.float32) for _ in cameras]
    return gaussians, cameras, photos


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--gaussians", type=int, default=20000)
    parser.add_argument("--run", default=None, help="use this run's Gaussians and cameras")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--train-steps", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    if args.run:
        from inceptiongs.train.run_folder import load_run
        gaussians, scene, _ = load_run(args.run)
        cameras, photos = scene.cameras, None
        load_image = scene.load_image
    else:
        gaussians, cameras, photos = synthetic_scene(args.gaussians)
        load_image = photos.__getitem__
    device = torch.device(args.device)
    gaussians = gaussians.to(device)
    prior = Prior.for_gaussians(PriorConfig(), gaussians).to(device)
    camera = cameras[0]
    print(f"device {device}, torch threads {torch.get_num_threads()}, {len(gaussians)} Gaussians, "
          f"image {camera.width}x{camera.height}, window {prior.config.patch_size}")

    # Wall time and this process's CPU time: on a shared machine the wall time includes waiting
    # for other jobs; with --threads 1 the CPU time is what an idle core would take.
    wall, cpu = time.perf_counter(), time.process_time()
    prior.gbuffer(gaussians, camera)
    print(f"G-buffer (full image): wall {time.perf_counter() - wall:.2f} s, cpu {time.process_time() - cpu:.2f} s")
    prior.generate(gaussians, camera, steps=1, seed=0)  # warm-up (JIT, allocator)
    wall, cpu = time.perf_counter(), time.process_time()
    prior.generate(gaussians, camera, steps=args.steps, seed=0)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    print(f"generate {camera.width}x{camera.height}, {args.steps} DDIM steps: wall {wall:.2f} s, cpu {cpu:.2f} s "
          f"(target < 20 s)")

    trainer = PriorTrainer(prior, gaussians, cameras, load_image)
    trainer.step()  # warm-up
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(args.train_steps):
        trainer.step()
    wall = (time.perf_counter() - wall) / args.train_steps
    cpu = (time.process_time() - cpu) / args.train_steps
    print(f"training step (batch {prior.config.batch_size} x {trainer.patch_size}^2 patches, G-buffers "
          f"rendered on the fly): wall {wall:.2f} s, cpu {cpu:.2f} s -> {60 / wall:.0f} steps/min (wall)")


if __name__ == "__main__":
    main()
