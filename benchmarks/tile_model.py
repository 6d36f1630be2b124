"""Write a large model for the viewer and level-of-detail benchmarks: a PLY tiled on a grid.

    python benchmarks/tile_model.py OUT.ply [--ply donut.ply] [--copies 110] [--spacing 0.25]

donut.ply (45,624 Gaussians) tiled 110 times is 5.02M Gaussians (281 MB at SH degree 0), 22 times
1.0M. The copies lie on a square-ish grid in the model's ground plane (x, y), ``spacing`` apart,
so a camera that frames the grid sees every copy at once (the worst case for drawing).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch


def default_ply() -> Path:
    root = Path(os.environ.get("INCEPTIONGS_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    return root / "splats" / "donut.ply"


def grid_offsets(copies: int, spacing: float) -> np.ndarray:
    """[copies, 3] offsets on a grid of ceil(sqrt(copies)) columns in the x-y plane, centred."""
    columns = math.ceil(math.sqrt(copies))
    index = np.arange(copies)
    offsets = np.zeros((copies, 3))
    offsets[:, 0] = (index % columns - (columns - 1) / 2) * spacing
    offsets[:, 1] = (index // columns - (math.ceil(copies / columns) - 1) / 2) * spacing
    return offsets


def tiled_arrays(model: dict, copies: int, spacing: float = 0.25) -> dict:
    """``model`` (arrays as Gaussians.numpy()) repeated ``copies`` times on grid_offsets."""
    offsets = grid_offsets(copies, spacing).astype(np.float32)
    tiled = {name: np.concatenate([values] * copies) for name, values in model.items() if name != "means"}
    tiled["means"] = (model["means"][None] + offsets[:, None]).reshape(-1, 3)
    return tiled


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--ply", type=Path, default=default_ply())
    parser.add_argument("--copies", type=int, default=110)
    parser.add_argument("--spacing", type=float, default=0.25)
    args = parser.parse_args()
    from inceptiongs.gaussians import Gaussians
    from inceptiongs.io.ply import read_ply, write_ply

    start = time.perf_counter()
    model = read_ply(args.ply).numpy()
    tiled = tiled_arrays(model, args.copies, args.spacing)
    write_ply(Gaussians(**{name: torch.from_numpy(np.ascontiguousarray(v)) for name, v in tiled.items()}), args.out)
    print(f"{args.out}: {len(tiled['means']):,} Gaussians ({args.copies} copies of {args.ply.name}), "
          f"{args.out.stat().st_size / 1e6:.0f} MB, {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
