"""`inceptiongs prior RUN [--minutes M | --steps N] [--backend tiny|sd --sd-path DIR]`: train the
diffusion prior on a finished run.

Patches come from the run's training views only (RUN/split.json; every view when the run has
no split), so held-out views stay unseen. Checkpoints go to RUN/prior/prior.pt; an existing
checkpoint is resumed unless --restart is given. --eval-every-minutes M also scores generated
images on the held-out views every M minutes of training (RUN/prior/metrics.jsonl, for
`inceptiongs report`).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from ..errors import InputError
from .device import add_device_argument, command_device
from ..io.values import flag

HELP = "train the scene-adaptive diffusion prior on a run's training photos (tiny or sd backend)"
DEFAULT_MINUTES = 15.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="a stage-I run folder")
    parser.add_argument("--minutes", type=flag("minutes"), default=None,
                        help=f"training time budget (default {DEFAULT_MINUTES:g} unless --steps is given)")
    parser.add_argument("--steps", type=flag("steps"), default=None, help="stop after this many steps (whichever first)")
    parser.add_argument("--patch-size", type=flag("pixels"), default=None, help="patch edge s (default 64)")
    parser.add_argument("--batch-size", type=flag("count"), default=None, help="patches per step (default 4)")
    parser.add_argument("--seed", type=flag("seed"), default=None, help="initial weights and patch sampling (default 0)")
    parser.add_argument("--unet-width", type=flag("count"), default=None,
                        help="tiny backend: channels of the denoiser's first level (default 32, the two-core "
                             "machine's size; a GPU affords 64 or more); a new prior only")
    parser.add_argument("--prediction", choices=("epsilon", "v"), default=None,
                        help="tiny backend: what the UNet is trained to predict (default epsilon; see "
                             "docs/prior.md for when v samples better); a new prior only")
    parser.add_argument("--high-noise-share", type=flag("fraction"), default=None,
                        help="tiny backend: share of each batch trained at t >= 0.8 T, where only the "
                             "G-buffer can help (default 0); a new prior only")
    parser.add_argument("--appearance-weight", type=flag("weight"), default=None,
                        help="tiny backend: weight of the appearance hint's L1 loss (default 1; 0 = no "
                             "hint: the denoiser sees the bare G-buffer); a new prior only")
    parser.add_argument("--sample-start", type=flag("start"), default=None,
                        help="tiny backend: generation starts at this fraction of T from an image "
                             "noised to it (SDEdit; 1 = pure noise); a new prior only")
    parser.add_argument("--sample-init", choices=("render", "hint"), default=None,
                        help="tiny backend: the image a start below 1 noises: the Gaussians' render "
                             "(default: the prior repairs it) or the appearance hint; a new prior only")
    parser.add_argument("--restart", action="store_true", help="ignore an existing RUN/prior checkpoint")
    add_device_argument(parser, reads_run=True)
    parser.add_argument("--checkpoint-every", type=flag("steps"), default=200, help="steps between checkpoints")
    add_backend_arguments(parser)
    parser.add_argument("--eval-every-minutes", type=flag("minutes"), default=None,
                        help="score generated images on the held-out views every M training minutes")
    parser.add_argument("--eval-steps", type=flag("steps"), default=20, help="DDIM steps of those evaluations")
    parser.add_argument("--eval-views", type=flag("count"), default=None,
                        help="score at most this many held-out views per group in those evaluations")


def add_backend_arguments(parser: argparse.ArgumentParser, prefix: str = "") -> None:
    """--[prefix]backend and --sd-path (shared with `inceptiongs train --prior`)."""
    parser.add_argument(f"--{prefix}backend", choices=("tiny", "sd"), default=None,
                        help="tiny: trained from scratch (default); sd: Stable Diffusion 1.5 + ControlNet "
                             "from --sd-path (needs the diffusers extra)")
    parser.add_argument("--sd-path", default=None,
                        help="local diffusers folder with unet/ and vae/ (see docs/prior.md)")


def new_prior(backend: str, sd_path: str | None, gaussians, device, where: Path, patch_limit: int | None = None,
              **overrides):
    """A fresh prior of ``backend`` fitted to ``gaussians``; overrides: config fields (None = default).
    ``patch_limit``: the smallest training image side (patches shrink to it when training)."""
    overrides = {k: v for k, v in overrides.items() if v is not None}
    try:
        if (backend or "tiny") == "sd":
            from ..prior.sd_backend import SDPrior, SDPriorConfig
            if not sd_path:
                raise InputError("--backend sd needs --sd-path DIR (a local Stable Diffusion diffusers folder)")
            if overrides.pop("prediction", "epsilon") != "epsilon":
                raise InputError("--prediction v is for the tiny backend (SD 1.5 predicts epsilon)")
            for name in ("high_noise_share", "appearance_weight", "sample_start", "sample_init", "unet_width"):
                if overrides.pop(name, None) is not None:
                    raise InputError(f"--{name.replace('_', '-')} is for the tiny backend")
            config = replace(SDPriorConfig(sd_path=str(Path(sd_path).resolve())), **overrides)
            return SDPrior.for_gaussians(config, gaussians, device)
        from ..prior.footprint import check_training_fits
        from ..prior.model import Prior, PriorConfig, denoiser_cond_channels
        from ..prior.unet import UNetConfig
        if "unet_width" in overrides:
            overrides["unet"] = UNetConfig(base_width=overrides.pop("unet_width"))
        config = replace(PriorConfig(), **overrides)
        # Refused before the denoiser is built: the sizes the flags set must fit the device.
        sizes = f"--unet-width {config.unet.base_width} --batch-size {config.batch_size} --patch-size {config.patch_size}"
        patch = min(config.patch_size, patch_limit or config.patch_size)
        check_training_fits(config.unet, denoiser_cond_channels(config), patch, config.batch_size, sizes, device)
        return Prior.for_gaussians(config, gaussians, sizes).to(device)
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from None


def run(args) -> int:
    from ..runs.lock import run_folder_lock

    if not Path(args.run).is_dir():
        return train_prior(args)   # its one line names what is wrong with the path
    # One writer per run: two priors at once interleaved prior/metrics.jsonl and lost one's work,
    # and a `train --resume` would change the model under the prior.
    with run_folder_lock(args.run):
        return train_prior(args)


def train_prior(args) -> int:
    from ..prior.joint import training_views
    from ..prior.trainer import CHECKPOINT_NAME, METRICS_NAME, PriorTrainer, prior_dir, resume_trainer
    from ..runs.load import load_run

    run_dir = Path(args.run)
    for name in ("minutes", "steps", "patch_size", "batch_size", "unet_width", "checkpoint_every",
                 "eval_every_minutes", "eval_steps", "eval_views"):
        value = getattr(args, name)
        if value is not None and value <= 0:
            raise InputError(f"--{name.replace('_', '-')}: must be positive, got {value}")
    minutes = DEFAULT_MINUTES if args.minutes is None and args.steps is None else args.minutes
    chosen = command_device(args.device, run_dir)   # the prior, its G-buffer and the model on one device
    device = chosen.torch_device
    if chosen.note:
        print(chosen.note, file=sys.stderr)

    gaussians, scene, _ = load_run(run_dir)
    from ..io.atomic import check_writable_dir
    from ..io.paths import check_inside
    check_inside(prior_dir(run_dir), run_dir)   # RUN/prior a symlink out of the run: neither read nor written
    check_writable_dir(prior_dir(run_dir))  # one line now, not after the prior's training
    gaussians = gaussians.to(device)
    views = training_views(run_dir, scene)
    cameras = [scene.cameras[i] for i in views]
    from ..scene.photo_store import photo_tensor
    load_image = lambda k: photo_tensor(scene, views[k]).numpy()  # noqa: E731  (the photo cache)

    checkpoint = prior_dir(run_dir) / CHECKPOINT_NAME
    if checkpoint.is_file() and not args.restart:
        trainer = resume_trainer(run_dir, gaussians, cameras, load_image, device=device)
        if args.prediction and args.prediction != getattr(trainer.prior.config, "prediction", "epsilon"):
            raise InputError(f"{checkpoint}: its prior predicts {trainer.prior.config.prediction}, not "
                             f"{args.prediction} (use --restart to replace it)")
        width = getattr(getattr(trainer.prior.config, "unet", None), "base_width", None)
        if args.unet_width and width is None:
            raise InputError(f"{checkpoint}: holds a {trainer.prior.backend} prior; --unet-width is for the tiny backend")
        if args.unet_width and args.unet_width != width:
            raise InputError(f"{checkpoint}: its prior's denoiser is {width} channels wide, not {args.unet_width} "
                             "(use --restart to replace it)")
        if args.backend and args.backend != trainer.prior.backend:
            raise InputError(f"{checkpoint}: holds a {trainer.prior.backend} prior, not {args.backend} "
                             "(use --restart to replace it)")
        print(f"resuming {checkpoint} at step {trainer.step_count}")
    else:
        sample_start = args.sample_start
        if sample_start is None and args.appearance_weight == 0 and args.sample_init == "hint":
            sample_start = 1.0  # no hint to start from: sample from pure noise
        prior = new_prior(args.backend, args.sd_path, gaussians, device, run_dir,
                          patch_limit=min(min(c.width, c.height) for c in cameras), patch_size=args.patch_size,
                          batch_size=args.batch_size, seed=args.seed, prediction=args.prediction,
                          high_noise_share=args.high_noise_share, appearance_weight=args.appearance_weight,
                          sample_start=sample_start, sample_init=args.sample_init, unet_width=args.unet_width)
        (prior_dir(run_dir) / METRICS_NAME).unlink(missing_ok=True)  # a new prior starts a new log
        trainer = PriorTrainer(prior, gaussians, cameras, load_image)
    evaluate = None
    if args.eval_every_minutes is not None:
        from ..evaluation.generated import generated_scores_fn
        evaluate = generated_scores_fn(run_dir, gaussians, scene, steps=args.eval_steps, max_views=args.eval_views)
    first = trainer.step_count
    losses = trainer.train(steps=args.steps, minutes=minutes, run_dir=run_dir,
                           checkpoint_every=args.checkpoint_every, evaluate=evaluate,
                           evaluate_every_s=None if args.eval_every_minutes is None else 60.0 * args.eval_every_minutes)
    if losses:
        window = max(1, min(50, len(losses) // 4))
        print(f"prior: steps {first}..{trainer.step_count} on {len(cameras)} training views, "
              f"patch {trainer.patch_size}; mean loss first {window}: {sum(losses[:window]) / window:.4f}, "
              f"last {window}: {sum(losses[-window:]) / window:.4f}")
    print(f"wrote {checkpoint}")
    return 0
