"""``inceptiongs demo-scene OUT``: write a built-in procedural scene (the demo's courtyard, or
the small objects scene the tests use)."""

from __future__ import annotations

import argparse

from ..errors import InputError
from ..scene.courtyard import COURTYARD_SIZES, write_courtyard_scene
from ..scene.demo import SIZES, write_demo_scene

HELP = "write a built-in procedural scene (COLMAP model + images, ground-truth cameras)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", help="output folder (created; a previous demo scene there is replaced)")
    parser.add_argument("--scene", choices=("courtyard", "objects"), default="courtyard",
                        help="courtyard: the demo's, one facade seen only from far or grazing views (default); "
                             "objects: a ground, a wall, boxes and spheres")
    parser.add_argument("--size", choices=sorted(set(SIZES) | set(COURTYARD_SIZES)), default="small",
                        help="courtyard: tiny 21 views of 64x48, small 47 of 192x144 (default), medium 65 of "
                             "320x240; objects: small 28 of 192x144, medium 46 of 320x240")
    parser.add_argument("--seed", type=int, default=0, help="random seed (the scene is deterministic for a seed)")


def run(args: argparse.Namespace) -> int:
    if args.scene == "objects" and args.size not in SIZES:
        raise InputError(f"--size {args.size}: the objects scene comes in {', '.join(SIZES)}")
    writer = write_courtyard_scene if args.scene == "courtyard" else write_demo_scene
    out = writer(args.out, size=args.size, seed=args.seed)
    print(f"wrote the {args.scene} scene to {out} (COLMAP model in sparse/0, camera groups in demo_scene.json)")
    return 0
