"""``inceptiongs coverage SCENE_OR_RUN --out coverage.png``: where a capture is thin."""

from __future__ import annotations

import argparse
import math
import json
from pathlib import Path

from ..errors import InputError
from .device import add_device_argument, command_device
from ..io.values import flag

HELP = ("where a capture is thin: cameras from above, viewing density over a region's hemisphere, "
        "the views whose content is seen least")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="scene folder (its sparse points) or run folder (its Gaussians, "
                                     "occlusion from rendered depth, training views as sources)")
    parser.add_argument("--out", default="coverage.png", help="figure to write (.png, default coverage.png)")
    parser.add_argument("--roi", type=flag("number"), nargs=6, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                        help="region of interest, an axis-aligned box in the scene's original frame "
                             "(default: the points' 2-98 %% bounds)")
    parser.add_argument("--suggest", type=flag("count or 0"), default=5, metavar="K",
                        help="list the K scarcest views (candidates to flag; default 5)")
    parser.add_argument("--downscale", type=flag("factor"), default=4,
                        help="scene folders without sparse points: triangulate from images this many times "
                             "smaller (default 4)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    add_device_argument(parser, reads_run=True, default_help="the run's device; a scene folder renders nothing")


def run(args: argparse.Namespace) -> int:
    from ..evaluation import coverage_map

    path = Path(args.path)
    if not path.exists():
        raise InputError(f"{path}: path does not exist")
    if args.suggest < 0:
        raise InputError(f"--suggest: must be >= 0, got {args.suggest}")
    if args.downscale < 1:
        raise InputError(f"--downscale: must be >= 1, got {args.downscale}")
    if args.roi is not None and not all(math.isfinite(value) for value in args.roi):
        raise InputError(f"--roi: the box corners must be finite numbers, got {' '.join(map(str, args.roi))}")
    if Path(args.out).suffix.lower() != ".png":
        raise InputError(f"{args.out}: the coverage figure must be a .png file")
    from ..io.paths import check_outside_scene
    from .render import run_scene_path

    # The figure never goes into the scene folder (input): the one given, or the run's.
    check_outside_scene(args.out, run_scene_path(path) if (path / "config.json").is_file() else path)
    log = (lambda message: None) if args.json else (lambda message: print(message, flush=True))
    if (path / "config.json").is_file():
        device = command_device(args.device, path)   # what renders the views' depth
        if device.note:
            log(device.note)
        result = coverage_map.run_coverage(path, roi=args.roi, log=log, rasterizer=device.rasterizer,
                                              progress=True)
    else:
        from ..scene.loader import load_scene

        result = coverage_map.scene_coverage(load_scene(path, downscale=args.downscale), roi=args.roi, log=log)
    coverage_map.plot(result, args.out, title=str(path))
    figures = coverage_map.summary(result, listed=args.suggest)
    if args.json:
        print(json.dumps(figures, indent=2))
        return 0
    per_point = figures["views_per_point"]
    hemi = figures["hemisphere"]
    print(f"{path}: {figures['points']} {figures['point_source']}, {figures['source_views']} of "
          f"{figures['views']} views as sources{', occlusion from rendered depth' if figures['occlusion_tested'] else ''}")
    print(f"  views per point: median {per_point['median']:g} (10th-90th percentile {per_point['p10']:g}-"
          f"{per_point['p90']:g}); {figures['thinly_seen_fraction']:.0%} seen by fewer than "
          f"{figures['thin_threshold_views']}")
    print(f"  hemisphere: peak {hemi['peak_views_per_sr']:.2f} views/sr, mean {hemi['mean_views_per_sr']:.2f}; "
          f"{hemi['sparse_fraction']:.0%} of it under 10 % of the peak")
    if figures["scarcest_views"]:
        print("  scarcest views (flag candidates): " + ", ".join(
            f"{v['name']} ({v['scarcity']:.2f})" for v in figures["scarcest_views"]))
    print(f"wrote {args.out}")
    return 0
