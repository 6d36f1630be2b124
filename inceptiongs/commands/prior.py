"""`inceptiongs prior RUN [--minutes M | --steps N]`: train the tiny diffusion prior on a finished run.

Patches come from the run's training views only (RUN/split.json; every view when the run has
no split), so held-out views stay unseen. Checkpoints go to RUN/prior/prior.pt; an existing
checkpoint is resumed unless --restart is given.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from ..errors import InputError

HELP = "train the scene-adaptive diffusion prior on a run's training photos (tiny backend)"
DEFAULT_MINUTES = 15.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="a stage-I run folder")
    parser.add_argument("--minutes", type=float, default=None,
                        help=f"training time budget (default {DEFAULT_MINUTES:g} unless --steps is given)")
    parser.add_argument("--steps", type=int, default=None, help="stop after this many steps (whichever first)")
    parser.add_argument("--patch-size", type=int, default=None, help="patch edge s (default 64)")
    parser.add_argument("--batch-size", type=int, default=None, help="patches per step (default 4)")
    parser.add_argument("--seed", type=int, default=None, help="initial weights and patch sampling (default 0)")
    parser.add_argument("--restart", action="store_true", help="ignore an existing RUN/prior checkpoint")
    parser.add_argument("--device", default=None, help="torch device (default: cuda when available)")
    parser.add_argument("--checkpoint-every", type=int, default=200, help="steps between checkpoints")


def training_views(run_dir: Path, scene) -> list[int]:
    from ..protocols import Split

    split_path = run_dir / "split.json"
    if not split_path.is_file():
        return list(range(len(scene.cameras)))
    return list(Split.load(split_path, scene.cameras).train)


def run(args) -> int:
    import torch

    from ..prior.model import Prior, PriorConfig
    from ..prior.trainer import CHECKPOINT_NAME, PriorTrainer, prior_dir, resume_trainer
    from ..train.run_folder import load_run

    run_dir = Path(args.run)
    for name in ("minutes", "steps", "patch_size", "batch_size", "checkpoint_every"):
        value = getattr(args, name)
        if value is not None and value <= 0:
            raise InputError(f"--{name.replace('_', '-')}: must be positive, got {value}")
    minutes = DEFAULT_MINUTES if args.minutes is None and args.steps is None else args.minutes
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))

    gaussians, scene, _ = load_run(run_dir)
    gaussians = gaussians.to(device)
    views = training_views(run_dir, scene)
    cameras = [scene.cameras[i] for i in views]
    load_image = lambda k: scene.load_image(views[k])  # noqa: E731

    checkpoint = prior_dir(run_dir) / CHECKPOINT_NAME
    if checkpoint.is_file() and not args.restart:
        trainer = resume_trainer(run_dir, gaussians, cameras, load_image, device=device)
        print(f"resuming {checkpoint} at step {trainer.step_count}")
    else:
        config = PriorConfig()
        overrides = {"patch_size": args.patch_size, "batch_size": args.batch_size, "seed": args.seed}
        config = replace(config, **{k: v for k, v in overrides.items() if v is not None})
        try:
            prior = Prior.for_gaussians(config, gaussians).to(device)
        except ValueError as exc:
            raise InputError(f"{run_dir}: {exc}") from None
        trainer = PriorTrainer(prior, gaussians, cameras, load_image)
    first = trainer.step_count
    losses = trainer.train(steps=args.steps, minutes=minutes, run_dir=run_dir,
                           checkpoint_every=args.checkpoint_every)
    if losses:
        window = max(1, min(50, len(losses) // 4))
        print(f"prior: steps {first}..{trainer.step_count} on {len(cameras)} training views, "
              f"patch {trainer.patch_size}; mean loss first {window}: {sum(losses[:window]) / window:.4f}, "
              f"last {window}: {sum(losses[-window:]) / window:.4f}")
    print(f"wrote {checkpoint}")
    return 0
