"""Time the numba compositing fast path (inceptiongs.rasterizer.composite_numba) at 512x512.

Random projected Gaussians spread over the image (footprint radius 2-20 px, anisotropy up to
3:1, opacities 0.05-0.95, 3 value channels), as the composite stage sees them after
projection. Prints, per N: forward ms and forward+backward ms (median of --repeats runs after
one warm-up), the (tile, Gaussian) pair count and the peak resident memory of a fresh process
for that N. Each N runs in its own subprocess so the peaks do not mix.

    python3 benchmarks/bench_composite_numba.py [--sizes 10000 100000] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time


def make_scene(n: int, width: int, height: int, seed: int = 0):
    import torch

    from inceptiongs.constants import ALPHA_MIN

    gen = torch.Generator().manual_seed(seed)

    def uniform(shape, lo, hi):
        return lo + (hi - lo) * torch.rand(shape, generator=gen)

    opacity = uniform(n, 0.05, 0.95)
    level = torch.log(opacity / ALPHA_MIN).clamp(min=0.0)  # footprint = sqrt(2 level) sigma
    radius = uniform(n, 2.0, 20.0)  # footprint radius along the long axis, pixels
    sigma_long = radius / torch.sqrt(2.0 * level)
    sigma_short = sigma_long / uniform(n, 1.0, 3.0)
    angle = uniform(n, 0.0, math.pi)
    cos, sin = torch.cos(angle), torch.sin(angle)
    rot = torch.stack([cos, -sin, sin, cos], 1).view(n, 2, 2)
    sigmas = torch.stack([sigma_long, sigma_short], 1)
    cov = rot @ torch.diag_embed(sigmas**2) @ rot.transpose(1, 2)
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2  # > 0: both sigmas > 0
    conics = torch.stack([cov[:, 1, 1] / det, -cov[:, 0, 1] / det, cov[:, 0, 0] / det], 1)
    extents = torch.sqrt(2.0 * level[:, None] * torch.stack([cov[:, 0, 0], cov[:, 1, 1]], 1))
    means = torch.stack([uniform(n, 0.0, width), uniform(n, 0.0, height)], 1)
    return {
        "means2d": means,
        "conics": conics,
        "opacities": opacity,
        "values": uniform((n, 3), 0.0, 1.0),
        "depths": uniform(n, 1.0, 10.0),
        "extents": extents,
    }


def measure(n: int, width: int, height: int, threads: int, repeats: int) -> dict:
    import numba
    import torch

    from inceptiongs.rasterizer.composite_numba import composite_numba

    numba.set_num_threads(threads)
    torch.set_num_threads(threads)
    scene = make_scene(n, width, height)
    differentiable = ("means2d", "conics", "opacities", "values")

    def forward():
        with torch.no_grad():
            return composite_numba(**scene, width=width, height=height)

    def forward_backward():
        leaves = {k: v.clone().requires_grad_(k in differentiable) for k, v in scene.items()}
        image, alpha = composite_numba(**leaves, width=width, height=height)
        (image.sum() + alpha.sum()).backward()
        return image

    def timed(fn):
        """Median wall ms and median CPU ms (all threads of the process) over the repeats."""
        fn()  # warm-up (JIT cache load, page faults)
        wall, cpu = [], []
        for _ in range(repeats):
            start, start_cpu = time.perf_counter(), time.process_time()
            fn()
            wall.append((time.perf_counter() - start) * 1e3)
            cpu.append((time.process_time() - start_cpu) * 1e3)
        return statistics.median(wall), statistics.median(cpu)

    forward_ms, forward_cpu_ms = timed(forward)
    both_ms, both_cpu_ms = timed(forward_backward)
    image, alpha = forward()
    pairs = _count_pairs(scene, width, height)
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB
    return {"n": n, "forward_ms": forward_ms, "forward_backward_ms": both_ms, "pairs": pairs,
            "forward_cpu_ms": forward_cpu_ms, "forward_backward_cpu_ms": both_cpu_ms,
            "mean_alpha": float(alpha.mean()), "peak_rss_mib": peak_mib}


def _count_pairs(scene, width, height) -> int:
    import numpy as np

    from inceptiongs.rasterizer.composite_numba import bin_tiles, pack_params
    from inceptiongs.constants import TILE_SIZE

    params = pack_params(scene["means2d"].double().numpy(), scene["conics"].double().numpy(),
                          scene["opacities"].double().numpy())
    extents = np.ascontiguousarray(scene["extents"].double().numpy())
    _, _, entries = bin_tiles(params, extents, width, height, -(-width // TILE_SIZE), -(-height // TILE_SIZE))
    return int(entries.shape[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--width", type=int, default=512)
    parser.add_argument("--height", type=int, default=512)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()

    if args.child is not None:
        print(json.dumps(measure(args.child, args.width, args.height, args.threads, args.repeats)))
        return

    print(f"composite_numba at {args.width}x{args.height}, {args.threads} threads, median of {args.repeats}")
    # CPU ms is summed over the process's threads: on a machine shared with other jobs the
    # wall time inflates, and CPU ms / threads is what the same run takes on idle cores.
    print(f"{'N':>9} {'pairs':>10} {'fwd ms':>9} {'fwd+bwd ms':>11} {'fwd cpu ms':>11} "
          f"{'fwd+bwd cpu ms':>15} {'mean alpha':>11} {'peak RSS MiB':>13}")
    for n in args.sizes:
        command = [sys.executable, __file__, "--child", str(n), "--width", str(args.width),
                   "--height", str(args.height), "--threads", str(args.threads), "--repeats", str(args.repeats)]
        result = json.loads(subprocess.run(command, check=True, capture_output=True, text=True).stdout)
        print(f"{result['n']:>9} {result['pairs']:>10} {result['forward_ms']:>9.1f} "
              f"{result['forward_backward_ms']:>11.1f} {result['forward_cpu_ms']:>11.1f} "
              f"{result['forward_backward_cpu_ms']:>15.1f} {result['mean_alpha']:>11.3f} "
              f"{result['peak_rss_mib']:>13.0f}", flush=True)
    print(f"load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())} "
          f"(on {os.cpu_count()} cores; above the core count the wall times are inflated)")


if __name__ == "__main__":
    main()
