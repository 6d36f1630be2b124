"""``inceptiongs-viewer SCENE_DIR | MODEL (.ply, .splat, .spz) | RUN_DIR [--runs DIR] [--screenshot PATH [--camera cam.json] [--size WxH]]``"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from inceptiongs.errors import InputError
from inceptiongs.io.atomic import writing_under


def build_parser() -> argparse.ArgumentParser:
    from .settings import bindings_text  # noqa: PLC0415 (plain data: keeps --help fast)

    parser = argparse.ArgumentParser(
        prog="inceptiongs-viewer",
        description="View, inspect, flag, train and edit a Gaussian-splat scene.",
        epilog="keys and mouse in the window (also H / F1 there):\n" + bindings_text(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("source", help="a scene folder, a model file (.ply, .compressed.ply, .splat, .spz) or a "
                                       "training run folder")
    parser.add_argument("--screenshot", metavar="PATH", help="render one frame without UI to PATH (format from its extension: .png, .jpg, ...) and exit")
    parser.add_argument("--camera", metavar="JSON", help="camera for --screenshot (default: first training camera)")
    parser.add_argument("--size", metavar="WxH", help="image size for --screenshot / window size")
    parser.add_argument("--runs", metavar="DIR",
                        help="runs folder: new runs go to DIR/NAME (default ./runs/NAME in the current folder, as "
                             "`inceptiongs train`), and the scene's runs in DIR are listed with the others")
    parser.add_argument("--debug", action="store_true", help="show tracebacks for errors")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        from .screenshot import parse_size  # noqa: PLC0415

        size = parse_size(args.size) if args.size else None
        if size is not None:
            from inceptiongs.io.limits import check_image_size  # noqa: PLC0415
            check_image_size(*size, f"--size {args.size}")
        if args.camera and not args.screenshot:
            raise InputError(f"{args.camera}: --camera is only used with --screenshot")
        # Writes below the opened folder (a run's flags, a job's checkpoints) never follow a
        # symlink planted in it, as the command line's do.
        opened = Path(args.source)
        with writing_under(opened if opened.is_dir() else opened.parent):
            return _open(args, size)
    except InputError as exc:
        if args.debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def _open(args, size) -> int:
    """The window on ``args.source`` (or one screenshot of it) -> exit status."""
    from .screenshot import take_screenshot  # noqa: PLC0415
    from .sources import open_source  # noqa: PLC0415
    from .warmup import start_warmup  # noqa: PLC0415

    start_warmup()   # the first frame's kernels and imports, while the model is read
    runs_dir = None
    if args.runs:
        runs_dir = Path(args.runs)
        if runs_dir.exists() and not runs_dir.is_dir():
            raise InputError(f"{runs_dir}: --runs must be a folder (it is created when a run starts)")
    if args.screenshot:
        path = take_screenshot(open_source(args.source, runs_dir), args.screenshot, args.camera, size)
        print(f"wrote {path}", file=sys.stderr)
        return 0
    from .loading import open_with_progress  # noqa: PLC0415
    from .sources import check_openable  # noqa: PLC0415
    from .window import WindowError  # noqa: PLC0415

    check_openable(args.source)   # bad input is one line, before a window opens

    width, height = size or (1280, 720)
    try:
        # The window shows from its first frame what is being read (loading.py).
        viewer = open_with_progress(args.source, runs_dir, width, height)
    except WindowError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0 if viewer is None else viewer.run()


if __name__ == "__main__":
    sys.exit(main())
