"""LOD hierarchy speed: build seconds per million Gaussians, one cut, the exact and the greedy
budget cuts, cache save/load, on a random model. Prints figures, writes them as JSON; asserts
nothing.

    python benchmarks/bench_lod.py [--count 1000000] [--sh-degree 0] [--json lod.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.io.atomic import atomic_write_text
from inceptiongs.lod.cache import load_hierarchy, save_hierarchy
from inceptiongs.lod.cut import budget_cut_nodes, cut_nodes, greedy_budget_cut_nodes
from inceptiongs.lod.hierarchy import build_hierarchy


def random_model(n: int, degree: int) -> Gaussians:
    """n Gaussians spread over a 20-unit cube, scales around 0.02 units."""
    rng = np.random.default_rng(0)
    f = lambda *shape: rng.standard_normal(shape, dtype=np.float32)  # noqa: E731
    return Gaussians.from_numpy({"means": rng.uniform(-10, 10, (n, 3)).astype(np.float32),
                                 "log_scales": f(n, 3) * 0.5 - 4.0, "quats": f(n, 4),
                                 "opacity_logits": f(n), "sh": f(n, (degree + 1) ** 2, 3)})


def timed(fn):
    start = time.perf_counter()
    value = fn()
    return value, time.perf_counter() - start


def measure(args) -> dict:
    model = random_model(args.count, args.sh_degree)
    tree, build_s = timed(lambda: build_hierarchy(model))
    pose = look_at(np.array([0.0, -8.0, -25.0]), np.zeros(3))   # the whole cube in view
    camera = Camera("bench", 1280, 720, 1000.0, 1000.0, 640.0, 360.0, pose)
    cut, cut_s = timed(lambda: cut_nodes(tree, camera, args.granularity))
    (budget_nodes, budget_g), budget_s = timed(lambda: budget_cut_nodes(tree, camera, args.budget))
    greedy_nodes, greedy_s = timed(lambda: greedy_budget_cut_nodes(tree, camera, args.budget))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "tree.npz"
        _, save_s = timed(lambda: save_hierarchy(tree, path))
        _, load_s = timed(lambda: load_hierarchy(path))
        cache_mb = path.stat().st_size / 1e6
    return {
        "date": datetime.date.today().isoformat(), "command": " ".join(["python"] + sys.argv),
        "machine": args.machine, "python": platform.python_version(), "torch_threads": torch.get_num_threads(),
        "count": args.count, "sh_degree": args.sh_degree, "nodes": len(tree), "levels": tree.levels,
        "build_s": build_s, "build_s_per_million": build_s / (args.count / 1e6),
        "cut_granularity_px": args.granularity, "cut_nodes": int(len(cut)), "cut_ms": cut_s * 1e3,
        "budget": args.budget, "budget_nodes": int(len(budget_nodes)), "budget_granularity_px": budget_g,
        "budget_cut_ms": budget_s * 1e3, "greedy_nodes": int(len(greedy_nodes)), "greedy_cut_ms": greedy_s * 1e3,
        "cache_mb": cache_mb, "save_s": save_s, "load_s": load_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=1_000_000)
    parser.add_argument("--sh-degree", type=int, default=0, choices=(0, 1, 2, 3))
    parser.add_argument("--granularity", type=float, default=2.0, help="cut granularity in pixels")
    parser.add_argument("--budget", type=int, default=250_000, help="splat budget of the budget cut")
    parser.add_argument("--machine", default="2 shared CPU cores", help="recorded in the JSON")
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    result = measure(args)
    print(f"{args.count:,} Gaussians SH{args.sh_degree}: build {result['build_s']:.2f} s "
          f"({result['build_s_per_million']:.2f} s per million, {result['nodes']:,} nodes, {result['levels']} levels)")
    print(f"cut at {args.granularity:g} px: {result['cut_nodes']:,} nodes in {result['cut_ms']:.0f} ms; "
          f"budget {args.budget:,}: {result['budget_nodes']:,} nodes (g = {result['budget_granularity_px']:.2f} px) "
          f"in {result['budget_cut_ms']:.0f} ms; greedy: {result['greedy_nodes']:,} nodes "
          f"in {result['greedy_cut_ms']:.0f} ms")
    print(f"cache {result['cache_mb']:.0f} MB: save {result['save_s']:.2f} s, load {result['load_s']:.2f} s")
    if args.json:
        atomic_write_text(args.json, json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
