"""Forward and forward+backward time through the project's rasterizer interface.

N random Gaussians in a unit cube in front of the camera (as bench_torch_rasterizer.py), rendered
by each named rasterizer (inceptiongs.rasterizer.interface.RASTERIZERS) with the outputs a stage-I
training step asks for (rgb, alpha, normal, plane_depth: the PGSR terms' inputs), the Gaussians
on the rasterizer's device. Medians over --repeats after one warm-up call; CUDA timings wait for
the kernels (torch.cuda.synchronize).

    python benchmarks/bench_rasterizers.py [--rasterizers gsplat] [--sizes 10000 100000 1000000]
                                           [--size 1920x1080] [--repeats 5] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import inceptiongs  # noqa: F401  (before torch: OMP_WAIT_POLICY, docs/training.md "Speed")
import numpy as np
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.rasterizer.interface import get_rasterizer
from timing import median_ms   # benchmarks/timing.py (this script's folder is on sys.path)

OUTPUTS = ("rgb", "alpha", "normal", "plane_depth")


def random_cube(n: int, device: str, sh_degree: int = 3) -> dict[str, torch.Tensor]:
    """Leaf parameters of ``n`` Gaussians filling a unit cube (size ~ spacing / 3)."""
    gen = torch.Generator().manual_seed(0)
    spacing = n ** (-1.0 / 3.0)
    params = dict(means=torch.rand(n, 3, generator=gen) - 0.5,
                  log_scales=np.log(spacing / 3.0) + 0.4 * torch.randn(n, 3, generator=gen),
                  quats=torch.randn(n, 4, generator=gen),
                  opacity_logits=torch.randn(n, generator=gen),
                  sh=0.3 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=gen))
    return {k: v.float().to(device).requires_grad_(True) for k, v in params.items()}


def time_one(name: str, n: int, width: int, height: int, repeats: int) -> dict:
    rasterizer = get_rasterizer(name)
    device = rasterizer.device
    params = random_cube(n, device)
    gaussians = Gaussians(**params)
    camera = Camera("bench", width, height, 1.1 * width, 1.1 * width, width / 2, height / 2,
                    look_at(np.array([0.3, -0.4, -2.5]), np.zeros(3)))
    cuda = device == "cuda"

    def sync() -> None:
        if cuda:
            torch.cuda.synchronize()

    def forward():
        return rasterizer(gaussians, camera, outputs=OUTPUTS)

    def forward_backward():
        out = forward()
        (out["rgb"].sum() + out["plane_depth"].mean() + out["normal"].sum() + out["alpha"].sum()).backward()
        for p in params.values():
            p.grad = None

    with torch.no_grad():
        forward_ms = median_ms(forward, repeats, sync)
    return {"rasterizer": name, "device": device, "n": n, "size": f"{width}x{height}",
            "forward_ms": round(forward_ms, 2),
            "forward_backward_ms": round(median_ms(forward_backward, repeats, sync), 2)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rasterizers", nargs="+", default=["gsplat"] if torch.cuda.is_available() else ["numba"])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--size", default="1920x1080", help="image WIDTHxHEIGHT")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    where = torch.cuda.get_device_name() if torch.cuda.is_available() else "CPU"
    print(f"outputs {', '.join(OUTPUTS)} at {width}x{height}; {where}")
    print(f"{'rasterizer':>10} {'N':>9} {'fwd ms':>9} {'fwd+bwd ms':>11}")
    rows = []
    for name in args.rasterizers:
        for n in args.sizes:
            row = time_one(name, n, width, height, args.repeats)
            rows.append(row)
            print(f"{name:>10} {n:>9} {row['forward_ms']:>9.2f} {row['forward_backward_ms']:>11.2f}", flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps({"device": where, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
