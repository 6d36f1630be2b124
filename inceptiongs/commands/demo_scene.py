"""``inceptiongs demo-scene OUT``: write a built-in procedural scene (the demo's courtyard, the
small objects scene the tests use, or the town: a large capture of thousands of views)."""

from __future__ import annotations

import argparse

from ..errors import InputError
from ..scene.courtyard import COURTYARD_SIZES, write_courtyard_scene
from ..scene.demo import SIZES, write_demo_scene
from ..scene.town import DEFAULT_TOWN_SIZE, TOWN_SIZES, VIEWS_MAX, VIEWS_MIN, check_views, parse_town_size, \
    write_town_scene
from ..io.values import flag

HELP = "write a built-in procedural scene (COLMAP model + images, ground-truth cameras)"
DEFAULT_TOWN_VIEWS = 3000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", help="output folder (created; a previous demo scene there is replaced)")
    parser.add_argument("--scene", choices=("courtyard", "objects", "town"), default="courtyard",
                        help="courtyard: the demo's, one facade seen only from far or grazing views (default); "
                             "objects: a ground, a wall, boxes and spheres; town: streets, squares and "
                             "courtyards seen by --views street-level and aerial views (JPEG photos)")
    parser.add_argument("--size", default=None,
                        help="courtyard: tiny 21 views of 64x48, small 47 of 192x144 (default), medium 65 of "
                             "320x240; objects: small 28 of 192x144, medium 46 of 320x240; town: WIDTHxHEIGHT "
                             f"or {', '.join(f'{k} {w}x{h}' for k, (w, h) in TOWN_SIZES.items())} "
                             f"(default {DEFAULT_TOWN_SIZE})")
    parser.add_argument("--views", type=flag("count"), default=None,
                        help=f"town only: number of views, {VIEWS_MIN} to {VIEWS_MAX} (default {DEFAULT_TOWN_VIEWS}); "
                             "the town grows with it, about 60 views a block")
    parser.add_argument("--seed", type=flag("seed"), default=0, help="random seed (the scene is deterministic for a seed)")


def run(args: argparse.Namespace) -> int:
    if args.scene == "town":
        views = DEFAULT_TOWN_VIEWS if args.views is None else args.views
        check_views(views)
        width, height = parse_town_size(args.size or DEFAULT_TOWN_SIZE)
        out = write_town_scene(args.out, views=views, width=width, height=height, seed=args.seed)
        print(f"wrote the town ({views} views of {width}x{height}) to {out} (COLMAP model in sparse/0, "
              "camera groups in demo_scene.json)")
        return 0
    if args.views is not None:
        raise InputError(f"--views {args.views}: only the town takes a number of views (--scene town)")
    size = args.size or "small"
    sizes = SIZES if args.scene == "objects" else COURTYARD_SIZES
    if size not in sizes:
        raise InputError(f"--size {size}: the {args.scene} scene comes in {', '.join(sizes)}")
    writer = write_courtyard_scene if args.scene == "courtyard" else write_demo_scene
    out = writer(args.out, size=size, seed=args.seed)
    print(f"wrote the {args.scene} scene to {out} (COLMAP model in sparse/0, camera groups in demo_scene.json)")
    return 0
