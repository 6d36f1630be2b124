"""inceptiongs train: stage-I planar 3DGS reconstruction into a run folder."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..errors import InputError

HELP = "train stage I (PGSR-style planar 3DGS) on a scene into a run folder"


def add_arguments(parser) -> None:
    parser.add_argument("scene", help="scene folder (COLMAP, transforms.json or LLFF)")
    parser.add_argument("--out", help="run folder (default: SCENE/.inceptiongs/runs/train)")
    budget = parser.add_mutually_exclusive_group()
    budget.add_argument("--minutes", type=float, help="stop after this much training time")
    budget.add_argument("--iterations", type=int, help="number of steps (default 30000; with "
                        "--minutes the schedule length, default 5000)")
    parser.add_argument("--downscale", type=int, default=1, help="image downscale factor")
    parser.add_argument("--protocol", choices=("llff", "unstructured", "none"), default="none",
                        help="which views are held out for evaluation")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its newest checkpoint")
    parser.add_argument("--no-pgsr", action="store_true", help="plain 3DGS: no planar terms")


def build_config(args) -> "TrainConfig":
    from ..train.config import TrainConfig, short_run_schedule

    iterations = args.iterations if args.iterations is not None else (5_000 if args.minutes else 30_000)
    config = TrainConfig(scene=str(Path(args.scene).resolve()), downscale=args.downscale,
                         protocol=args.protocol, seed=args.seed, iterations=iterations,
                         minutes=args.minutes, pgsr=not args.no_pgsr)
    return short_run_schedule(config.validate("command line"))


def run(args) -> int:
    from ..train.config import TrainConfig
    from ..train.trainer import train

    scene = Path(args.scene)
    if not scene.exists():
        raise InputError(f"{scene}: scene folder does not exist")
    out = Path(args.out) if args.out else scene / ".inceptiongs" / "runs" / "train"
    config = build_config(args)
    stored = out / "config.json"
    if args.resume and stored.is_file():
        # The stored config is the run's contract: resume with it, only the time budget may change.
        resumed = TrainConfig.load(stored)
        if args.minutes is not None:
            resumed = dataclasses.replace(resumed, minutes=args.minutes)
        config = resumed
    elif stored.is_file() and not args.resume:
        raise InputError(f"{out}: run folder already holds a run (use --resume or another --out)")
    result = train(config, out, resume=args.resume)
    summary = ", ".join(f"{k} {v:.3f}" for k, v in result.last_eval.items())
    print(f"{out}: {result.iteration} iterations, {result.num_gaussians} Gaussians"
          + (f"; {summary}" if summary else ""))
    return 0
