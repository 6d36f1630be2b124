"""``inceptiongs demo-scene OUT``: write the built-in procedural demo scene."""

from __future__ import annotations

import argparse

from ..scene.demo import SIZES, write_demo_scene

HELP = "write the built-in procedural demo scene (COLMAP model + images, ground-truth cameras)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", help="output folder (created; a previous demo scene there is replaced)")
    parser.add_argument("--size", choices=sorted(SIZES), default="small",
                        help="small: 28 views of 192x144 (default); medium: 46 views of 320x240")
    parser.add_argument("--seed", type=int, default=0, help="random seed (the scene is deterministic for a seed)")


def run(args: argparse.Namespace) -> int:
    out = write_demo_scene(args.out, size=args.size, seed=args.seed)
    print(f"wrote demo scene to {out} (COLMAP model in sparse/0, cameras listed in demo_scene.json)")
    return 0
