"""Scene I/O speed: 3DGS PLY read/write at 1M Gaussians (SH degree 3 and 0), demo scene
writing, and loading the real captures when present. Prints figures; asserts nothing.

    python benchmarks/bench_scene_io.py [--count 1000000]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch

from inceptiongs.scene.demo import write_demo_scene
from inceptiongs.gaussians import Gaussians
from inceptiongs.io.ply import read_ply, write_ply
from inceptiongs.scene.loader import load_scene


def _best_of(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def _random_gaussians(n: int, degree: int) -> Gaussians:
    rng = np.random.default_rng(0)
    k = (degree + 1) ** 2
    f = lambda *shape: torch.from_numpy(rng.standard_normal(shape, dtype=np.float32))  # noqa: E731
    return Gaussians(f(n, 3), f(n, 3), f(n, 4), f(n), f(n, k, 3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=1_000_000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for degree in (3, 0):
            g = _random_gaussians(args.count, degree)
            path = tmp / f"sh{degree}.ply"
            write_s = _best_of(lambda: write_ply(g, path))
            read_s = _best_of(lambda: read_ply(path))
            size_mb = path.stat().st_size / 1e6
            print(f"PLY {args.count:,} Gaussians SH{degree} ({size_mb:.0f} MB): "
                  f"read {read_s * 1e3:.0f} ms, write {write_s * 1e3:.0f} ms")
        start = time.perf_counter()
        write_demo_scene(tmp / "demo", progress=False)
        print(f"demo scene (small) written in {time.perf_counter() - start:.1f} s")
        load_s = _best_of(lambda: load_scene(tmp / "demo"))
        print(f"demo scene loaded in {load_s * 1e3:.0f} ms")

    data = Path(__file__).resolve().parents[2] / "shared" / "data"
    for name in ("statuette", "fern"):
        if (data / name).is_dir():
            load_s = _best_of(lambda: load_scene(data / name))
            print(f"{name}: load_scene {load_s * 1e3:.0f} ms")
        else:
            print(f"{name}: not found at {data / name}, skipped", file=sys.stderr)


if __name__ == "__main__":
    main()
