"""Compiles the CPU kernels once, at install time: numba caches each compiled kernel beside its
module (``__pycache__/*.nbi``), so training, the viewer and the tests start without waiting
about a minute for the compiler.

    python3 scripts/compile_kernels.py

Runs the kernels on small inputs of the types the library uses: a tiny town written and trained
three steps (town tracing, the rasterizer, free space), then the rasterizer at SH degree 3 in
float32 and float64 with gradients, nearest points, point projection and a level-of-detail cut.
Writes nothing outside a temporary folder (its caches included). Prints the seconds it took.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
import time
from pathlib import Path

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import numpy as np
import torch


def random_gaussians(n: int, dtype: torch.dtype, degree: int = 3):
    from inceptiongs.gaussians import Gaussians

    gen = torch.Generator().manual_seed(0)
    return Gaussians(means=(torch.rand(n, 3, generator=gen) - 0.5) * 2,
                     log_scales=-2.0 + 0.5 * torch.randn(n, 3, generator=gen),
                     quats=torch.randn(n, 4, generator=gen), opacity_logits=torch.randn(n, generator=gen),
                     sh=0.3 * torch.randn(n, (degree + 1) ** 2, 3, generator=gen)).to(dtype=dtype)


def compile_rasterizer(camera) -> None:
    from inceptiongs.rasterizer.interface import rasterizer_for

    rasterizer = rasterizer_for("cpu")
    for dtype in (torch.float32, torch.float64):
        gaussians = random_gaussians(64, dtype)
        leaves = [tensor.requires_grad_() for tensor in (gaussians.means, gaussians.log_scales, gaussians.quats,
                                                         gaussians.opacity_logits, gaussians.sh)]
        out = rasterizer(gaussians, camera, outputs=("rgb", "alpha", "depth"))
        (out["rgb"].sum() + out["alpha"].sum() + out["depth"].sum()).backward()
        assert all(leaf.grad is not None for leaf in leaves)


def compile_geometry(camera) -> None:
    from inceptiongs.lod.cache import load_or_build
    from inceptiongs.lod.cut import cut_nodes
    from inceptiongs.train.nearest_points import mean_nearest_distance
    from inceptiongs.train.point_projection import COMPILED_FROM, project_cloud

    points = np.random.default_rng(0).normal(size=(max(COMPILED_FROM, 64), 3))
    mean_nearest_distance(torch.from_numpy(points).float(), 3)
    project_cloud(points, camera)
    hierarchy, _ = load_or_build(random_gaussians(256, torch.float32, degree=1))
    cut_nodes(hierarchy, camera, 1.0)


def main() -> int:
    from inceptiongs.cli import main as cli
    from inceptiongs.scene.loader import load_scene

    began = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="inceptiongs-compile-") as folder:
        folder = Path(folder)
        os.environ["INCEPTIONGS_CACHE_DIR"] = str(folder / "cache")   # the user's cache stays untouched
        town = folder / "town"
        for command in (["demo-scene", str(town), "--scene", "town", "--views", "24", "--size", "tiny"],
                        ["train", str(town), "--iterations", "3", "--out", str(folder / "run")]):
            said = io.StringIO()     # the commands' own lines are shown only when one fails
            with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
                status = cli(command)
            if status != 0:
                print(said.getvalue()[-2000:] + f"compile_kernels: `inceptiongs {' '.join(command)}` failed "
                      f"(status {status})", file=sys.stderr)
                return 1
        camera = load_scene(town).cameras[0]
        compile_rasterizer(camera)
        compile_geometry(camera)
    print(f"compiled the CPU kernels in {time.perf_counter() - began:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
