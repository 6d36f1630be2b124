"""The town as a large capture: how long it takes to write, its size on disk, and the memory
its photos take when every one is decoded to float32 at once. Prints figures; asserts nothing.

    python benchmarks/bench_town.py [--views 3000] [--size 640x480] [--seed 0] [--out DIR]

Without --out the town goes to a temporary folder that is removed afterwards.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from inceptiongs.scene.loader import load_scene
from inceptiongs.scene.town import parse_town_size, town_cameras, town_points, write_town_scene
from inceptiongs.scene.town_layout import blocks_for_views, make_town
from inceptiongs.scene.town_trace import scene_tuple


def _folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=3000)
    parser.add_argument("--size", default="640x480", help="WIDTHxHEIGHT or a town size name")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="write here and keep it (default: a temporary folder)")
    args = parser.parse_args()
    width, height = parse_town_size(args.size)
    print(f"machine: {os.cpu_count()} x {_cpu_name()}, load average {os.getloadavg()[0]:.1f} at start")

    tmp = None if args.out else tempfile.mkdtemp(prefix="bench_town.")
    out = Path(args.out) if args.out else Path(tmp) / "town"
    try:
        start = time.perf_counter()
        write_town_scene(out, views=args.views, width=width, height=height, seed=args.seed)
        write_s = time.perf_counter() - start
        load_average = os.getloadavg()[0]

        # The sparse points alone (the writer samples them before rendering), timed again.
        town = make_town(blocks_for_views(args.views), args.seed)
        cameras, dense, _, _ = town_cameras(town, args.views, width, height, args.seed)
        dense_set = set(dense)
        start = time.perf_counter()
        points, _ = town_points(scene_tuple(town), [c for c in cameras if c.name in dense_set],
                                np.random.default_rng([args.seed, 0x9E7]))
        points_s = time.perf_counter() - start

        start = time.perf_counter()
        scene = load_scene(out)
        load_s = time.perf_counter() - start

        images = _folder_bytes(out / "images")
        total = _folder_bytes(out)
        pixels = args.views * width * height
        float32 = pixels * 3 * 4
        print(f"town: {args.views} views of {width}x{height}, {town.blocks} x {town.blocks} blocks, "
              f"{len(town.boxes)} buildings, {len(town.courtyards)} courtyards, {len(points):,} sparse points")
        print(f"written in {write_s:.0f} s ({1000 * write_s / args.views:.0f} ms a view; sparse points "
              f"{points_s:.1f} s of it), load average {load_average:.1f} at the end")
        print(f"on disk: {total / 1e6:.0f} MB ({images / 1e6:.0f} MB of JPEG photos, "
              f"{images / pixels:.3f} bytes a pixel)")
        print(f"load_scene (cameras, points, image headers): {load_s:.1f} s, {len(scene.cameras)} cameras")
        print(f"every photo decoded as float32 [H, W, 3]: {float32 / 1e9:.1f} GB; with stage I's grey copy "
              f"and edge weights (float32 [H, W] each): {pixels * 20 / 1e9:.1f} GB; as uint8: {pixels * 3 / 1e9:.1f} GB")
        print(f"peak RSS of this script: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
