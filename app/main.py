"""``inceptiongs-viewer SCENE_DIR | MODEL.ply | RUN_DIR [--screenshot PATH [--camera cam.json] [--size WxH]]``"""

from __future__ import annotations

import argparse
import sys

from inceptiongs.errors import InputError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="inceptiongs-viewer",
        description="View, inspect, flag, train and edit a Gaussian-splat scene.")
    parser.add_argument("source", help="a scene folder, a model .ply or a training run folder")
    parser.add_argument("--screenshot", metavar="PATH", help="render one frame without UI to PATH (PNG) and exit")
    parser.add_argument("--camera", metavar="JSON", help="camera for --screenshot (default: first training camera)")
    parser.add_argument("--size", metavar="WxH", help="image size for --screenshot / window size")
    parser.add_argument("--debug", action="store_true", help="show tracebacks for errors")
    return parser


def default_job_factory(source):
    """The job the "start training" button runs: stage-I training for a scene, stage II
    (bootstrap) for a run when views are flagged (app/jobs.py). None when the source has
    neither a scene nor a run (a bare PLY)."""
    from inceptiongs.io.flags import flags_path  # noqa: PLC0415
    from .jobs import default_job, run_dir_of  # noqa: PLC0415

    if source.scene is None and run_dir_of(source) is None:
        return None
    return lambda src: default_job(src, flags_path(src.work_dir))  # noqa: E731


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        from .screenshot import parse_size, take_screenshot  # noqa: PLC0415
        from .sources import open_source  # noqa: PLC0415

        size = parse_size(args.size) if args.size else None
        if size is not None:
            from inceptiongs.io.limits import check_image_size  # noqa: PLC0415
            check_image_size(*size, f"--size {args.size}")
        if args.camera and not args.screenshot:
            raise InputError(f"{args.camera}: --camera is only used with --screenshot")
        source = open_source(args.source)
        if args.screenshot:
            path = take_screenshot(source, args.screenshot, args.camera, size)
            print(f"wrote {path}", file=sys.stderr)
            return 0
        from .viewer import Viewer  # noqa: PLC0415
        from .window import WindowError  # noqa: PLC0415

        width, height = size or (1280, 720)
        try:
            viewer = Viewer(source, width, height, job_factory=default_job_factory(source))
        except WindowError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        viewer.run()
        return 0
    except InputError as exc:
        if args.debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
