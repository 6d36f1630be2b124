"""inceptiongs train: stage-I planar 3DGS reconstruction into a run folder."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from ..errors import InputError
from ..io.atomic import OutputError
from ..io.config_json import check_seed, config_value, setting_paths, with_values
from ..io.photo_memory import PHOTO_MEMORY_HELP
from ..io.paths import check_outside_scene, contained_path, read_small_text
from ..train.distributed import ranks_from_environment
from .device import add_device_argument, command_device

from ..runs.config import PROTOCOLS, TrainConfig
from ..train.partition import PHOTOS_PER_BLOCK
from ..train.strategies import STRATEGIES
from ..io.values import flag

HELP = "train stage I (PGSR-style planar 3DGS) on a scene into a run folder"
# Trainer steps per prior step of `train --prior` without a number.
DEFAULT_PRIOR_EVERY = 10


def add_arguments(parser) -> None:
    parser.add_argument("scene", help="scene folder (COLMAP, transforms.json or LLFF)")
    parser.add_argument("--out", help="run folder (default: ./runs/SCENE_NAME in the current folder; "
                                      "never inside the scene folder)")
    parser.add_argument("--config", metavar="FILE.json",
                        help="settings of the new run: a JSON object of any of the keys in docs/train_options.md "
                             "(plain 3DGS, the free-space rules, the sky shell and its scale floor, learning "
                             "rates, densification, the strategies' options, ...), sections nested, e.g. "
                             "'{\"pgsr\": false, \"free_space\": {\"sky_min_scale\": 0}}'; the flags given "
                             "override it (RUN/config.json records the result)")
    budget = parser.add_mutually_exclusive_group()
    budget.add_argument("--minutes", type=flag("minutes"), help="train for this much time: the schedule (learning-rate "
                        "decay, densification, pruning) is sized to it from the measured step rate")
    budget.add_argument("--iterations", type=flag("steps"), help="number of steps (default 30000)")
    parser.add_argument("--downscale", type=flag("factor"), help="image downscale factor (default 1)")
    parser.add_argument("--protocol", choices=PROTOCOLS,
                        help="which views are held out for evaluation (default llff: every 8th view, "
                             "so `eval` works on the run; none: train on all)")
    parser.add_argument("--seed", type=flag("seed"), help="seed of the split, the initial points and every random draw "
                                                 "(default 0)")
    add_device_argument(parser, reads_run=True, default_help="auto; with --resume the run's device")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its newest checkpoint (with its RUN/config.json)")
    parser.add_argument("--strategy", choices=list(STRATEGIES),
                        help="default (the default): 3DGS densification; mcmc: 3DGS-MCMC (relocation, fixed "
                             "budget); dropgaussian: random drops with opacity compensation")
    parser.add_argument("--exclude-photos", default=None, metavar="NAMES|FILE|RUN",
                        help="leave these photos out (neither trained on nor held out): comma-separated image "
                             "names, a text file of names (one per line), or a finished run folder whose "
                             "view_fit.json names the photos it fitted poorly (moved objects, wrong poses)")
    parser.add_argument("--blocks", metavar="auto|N",
                        help="train in N blocks on the ground plane (auto: one per "
                             f"{PHOTOS_PER_BLOCK} training photos; fewer train as one ordinary run): a global stage on every photo "
                             "(block.global_share of --iterations), then each block, an ordinary run in "
                             "RUN/blocks/, fine-tuned from it with its share of the rest, merged into RUN; the "
                             "same command again trains only what is unfinished. Under torchrun the ranks share "
                             "the blocks (docs/large_scenes.md)")
    parser.add_argument("--photo-memory", metavar="SIZE", default=None, help=PHOTO_MEMORY_HELP)
    from .prior import add_backend_arguments
    prior = parser.add_argument_group("joint diffusion-prior training")
    prior.add_argument("--prior", nargs="?", type=flag("steps"), const=DEFAULT_PRIOR_EVERY, default=None, metavar="EVERY",
                       help=f"also train the diffusion prior: one prior step every EVERY trainer steps (default "
                            f"{DEFAULT_PRIOR_EVERY}), checkpointed with the run in RUN/prior/")
    add_backend_arguments(prior, prefix="prior-")


def check_arguments(args) -> None:
    """One line (InputError) for values no run can use, before anything is read or written."""
    if args.seed is not None:
        check_seed(args.seed, "--seed")
    if args.minutes is not None and not 0.0 < args.minutes < math.inf:
        raise InputError(f"--minutes: must be a finite number of minutes > 0, got {args.minutes}")
    if args.iterations is not None and args.iterations < 1:
        raise InputError(f"--iterations: must be >= 1, got {args.iterations}")
    if args.downscale is not None and args.downscale < 1:
        raise InputError(f"--downscale: must be >= 1, got {args.downscale}")


# What a run gets when neither a flag nor --config gives it, where that differs from TrainConfig's
# default: held-out views, so that `eval` works on the run.
COMMAND_LINE_DEFAULTS = {"protocol": "llff"}
# The settings a flag of `train` sets (each flag's argparse name is the setting's).
FLAG_SETTINGS = {"iterations": "--iterations", "minutes": "--minutes", "downscale": "--downscale",
                 "exclude_photos": "--exclude-photos", "protocol": "--protocol", "seed": "--seed",
                 "device": "--device", "strategy": "--strategy"}


def build_config(args) -> "TrainConfig":
    """The config of a new run: TrainConfig's defaults, then the --config file's settings, then
    the flags given. The schedule is sized to the time budget when minutes is given without
    iterations; the milestones (SCHEDULE_FIELDS) the file does not give are the default schedule
    scaled to the run's length (short_run_schedule), those it gives are kept as they are."""
    from ..runs.config import SCHEDULE_FIELDS, read_settings, schedule_length, short_run_schedule

    check_arguments(args)
    given = read_settings(args.config) if args.config else {}
    flags = {path: getattr(args, path) for path in FLAG_SETTINGS if getattr(args, path) is not None}
    if "exclude_photos" in flags:
        flags["exclude_photos"] = photos_to_exclude(flags["exclude_photos"])
    values = {**COMMAND_LINE_DEFAULTS, **given, **flags}
    iterations, sized = schedule_length(values.get("iterations"), values.get("minutes"))
    milestones = {path: values.pop(path) for path in SCHEDULE_FIELDS if path in values}
    if sized and milestones:
        raise InputError(f"{args.config}: {next(iter(milestones))} is a step of the schedule, which minutes "
                         f"without iterations sizes to the time budget; give iterations too (a fixed schedule) "
                         f"or leave the milestones out")
    values.update(scene=str(Path(args.scene).resolve()), iterations=iterations, size_to_minutes=sized)
    source = f"{args.config} with the command line" if args.config else "command line"
    config = short_run_schedule(with_values(TrainConfig(), values).validate(source))
    return with_values(config, milestones).validate(source)


def resumed_config(run_dir: Path, minutes: float | None = None, iterations: int | None = None,
                   say=lambda line: print(line, file=sys.stderr)) -> "TrainConfig":
    """The config a resume of ``run_dir`` trains with: the stored one, the run's contract (its
    schedule and its own time budget); only ``minutes`` (a new budget) may change it. A different
    ``iterations`` is ignored, with a note through ``say``."""
    stored = Path(run_dir) / "config.json"
    resumed = TrainConfig.load(stored)
    if minutes is not None:
        resumed = dataclasses.replace(resumed, minutes=minutes)
    if iterations is not None and iterations != resumed.iterations:
        say(f"note: {stored} keeps its schedule of {resumed.iterations} iterations on --resume; "
            f"--iterations {iterations} is ignored (start a new run with --out to train longer)")
    return resumed


def photos_to_exclude(value: str | None) -> list[str]:
    """--exclude-photos: a finished run folder (the photos its view_fit.json reports as poorly
    fit), a text file of image names (one per line or comma-separated), or comma-separated names."""
    from ..train.view_fit import VIEW_FIT_FILE, read_poorly_fit

    if not value:
        return []
    try:
        path = Path(value)
        is_dir, is_file = path.is_dir(), path.is_file()
    except OSError:  # a long list of names is no path (ENAMETOOLONG)
        is_dir = is_file = False
    if is_dir:
        if not (path / VIEW_FIT_FILE).is_file():
            raise InputError(f"{value}: no {VIEW_FIT_FILE} (a finished stage-I run writes one) to take the "
                             f"photos to exclude from")
        # The run's view_fit.json must be its own (not a symlink planted to lead out of it) and of
        # a report's size, before it is read whole.
        read_small_text(contained_path(path, VIEW_FIT_FILE, f"--exclude-photos {value}"), "view-fit report")
        names = list(read_poorly_fit(path))
        print(f"excluding {len(names)} photo(s) that {value} fitted poorly", file=sys.stderr)
        return names
    if is_file:
        try:     # of a list's size (a huge or sparse file is refused before it is read)
            value = read_small_text(path, "list of photos to exclude").replace("\n", ",")
        except FileNotFoundError as exc:
            raise InputError(f"{path}: cannot read the list of photos to exclude ({exc.strerror})") from None
    return [name.strip() for name in value.split(",") if name.strip()]


def run(args) -> int:
    from ..runs.folder import default_run_dir

    scene = Path(args.scene)
    if not scene.exists():
        raise InputError(f"{scene}: scene folder does not exist")
    out = Path(args.out) if args.out else default_run_dir(scene)
    if args.blocks is not None:
        return run_blocks(args, out)
    return run_one(args, out)


def run_one(args, out: Path) -> int:
    """`train` without --blocks (or --blocks auto on a capture of one block): one run into ``out``."""
    from ..live import JobControl
    from ..stop_signals import stop_on_signals
    from ..train.trainer import train

    ranks = ranks_from_environment()
    if ranks.distributed:
        raise InputError(f"torchrun ({ranks.world} ranks): only `train --blocks` spreads over ranks")
    stored = out / "config.json"
    resuming = args.resume and stored.is_file()
    if resuming and args.config:
        raise InputError(f"--config: a resume keeps the settings in {stored} (train a new run with another "
                         f"--out to change them)")
    config = build_config(args)
    if resuming:
        config = resumed_config(out, args.minutes, args.iterations)
        if args.device is not None:   # checkpoints hold CPU tensors: a run resumes on any device
            config = dataclasses.replace(config, device=args.device)
    elif stored.is_file() and not args.resume:
        raise InputError(f"{out}: run folder already holds a run (use --resume or another --out)")
    # A device that cannot run here: one line before anything starts. The trainer resolves
    # config.device by the same rule (and prints what auto chose once its start has succeeded).
    device = command_device(args.device, out if resuming else None)
    # After the settings and the device have had their say (each their own one line), before any write.
    check_outside_scene(out, args.scene)
    joint = joint_prior(args, out, config, device.torch_device) if args.prior is not None else None
    control = JobControl()
    with stop_on_signals(control) as stopping:
        try:
            result = train(config, out, resume=args.resume, after_step=joint, control=control)
        except OutputError as exc:
            if stopping.signum is None:
                raise
            from .stopped import stopped_with_failed_save
            return stopped_with_failed_save(exc, out, stopping.exit_status,
                                            f"inceptiongs train {args.scene} --out {out} --resume")
    if joint is not None:
        saved = joint.finish()
        if saved is not None:
            print(f"{saved}: prior at step {joint.trainer.step_count} ({joint.trainer.train_s:.0f} s of prior training)")
    if stopping.signum is not None:
        print(f"{out}: stopped at iteration {result.iteration}; saved model.ply and a checkpoint "
              f"(continue with: inceptiongs train {args.scene} --out {out} --resume)", file=sys.stderr)
        return stopping.exit_status
    summary = ", ".join(f"{k} {v:.3f}" for k, v in result.last_eval.items())
    print(f"{out}: {result.iteration} iterations, {result.num_gaussians} Gaussians"
          + (f"; {summary}" if summary else ""))
    return 0


def changed_settings(stored: TrainConfig, asked: TrainConfig, shown: int = 1) -> list[str]:
    """The settings (dotted paths, at most ``shown`` of them, then a count) in which ``asked``
    differs from ``stored``, as "PATH V (asked W)"; the first is the one a user most likely gave
    (top-level settings come first; a milestone sized from --iterations follows it). The device
    is left out: a run continues on any device (checkpoints hold CPU tensors)."""
    changed = [f"{path} {config_value(stored, path)!r} (asked {config_value(asked, path)!r})"
               for path in setting_paths(type(stored)) if path != "device"
               and config_value(stored, path) != config_value(asked, path)]
    return changed[:shown] + ([f"{len(changed) - shown} more setting(s)"] if len(changed) > shown else [])


def run_blocks(args, out: Path) -> int:
    """`train --blocks`: plan, train this process's blocks, merge (inceptiongs.train.blocks); under
    torchrun each rank trains its share and rank 0 merges."""
    from ..evaluation.protocols import make_split
    from ..live import JobControl
    from ..scene.loader import load_scene
    from ..scene.photo_store import photo_budget
    from ..stop_signals import stop_on_signals
    from ..train.blocks import block_count, train_blocks
    from ..train.distributed import end_group, start_group
    from ..train.trainer import train

    if args.prior is not None:
        raise InputError("--blocks: the joint prior (--prior) trains on one run; train it on the merged run with "
                         "`inceptiongs prior RUN`")
    if args.resume:
        raise InputError("--blocks: the same command without --resume continues the unfinished blocks")
    ranks = ranks_from_environment()
    config = build_config(args)
    stored = out / "config.json"
    if stored.is_file():
        previous = TrainConfig.load(stored)
        if not previous.blocks and args.blocks == "auto" and not ranks.distributed:
            return as_one_run(args, out, "continues the one run it trained this capture as", resume=True)
        if not previous.blocks:
            raise InputError(f"{out}: run folder already holds a run that is not in blocks (give another --out)")
        count = previous.blocks
        if args.blocks != "auto" and str(args.blocks) != str(count):
            raise InputError(f"{out}: holds a run in {count} blocks, not {args.blocks} (give --blocks {count} to "
                             f"continue it, or another --out)")
        changed = changed_settings(previous, dataclasses.replace(config, blocks=count))
        if changed:
            raise InputError(f"{out}: holds a run in blocks trained with other settings ({'; '.join(changed)}); "
                             f"the command that started it continues it, or give another --out")
        config = dataclasses.replace(previous, device=config.device)
    else:
        scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
        split = make_split(scene, config.protocol, config.seed, config.scarce_views, config.exclude_photos)
        photo_budget(scene, split.train)   # a budget below one photo: one line before the plan is written
        count = block_count(args.blocks, len(split.train))
        if count == 1 and args.blocks == "auto" and not ranks.distributed:
            return as_one_run(args, out, f"{len(split.train)} training photos, at most {PHOTOS_PER_BLOCK} a "
                                         f"block: trains them as one run", resume=False)
        config = dataclasses.replace(config, blocks=count)
    if ranks.world > count:   # before joining the group: the ranks it would wait for never come
        raise InputError(f"torchrun: {ranks.world} ranks for {count} blocks; start at most {count} (a rank "
                         f"without a block would only wait)")
    device = command_device(args.device, None)
    check_outside_scene(out, args.scene)   # before the plan is written
    control = JobControl()
    say = lambda line: print(line if not ranks.distributed else f"[rank {ranks.rank}] {line}",  # noqa: E731
                             file=sys.stderr, flush=True)
    if config.minutes is not None and ranks.rank == 0:   # said before the hours it may mean
        stages = count + (config.block.global_share > 0)
        say(f"--minutes {config.minutes:g} is each stage's own budget: the {stages} stages (global stage and "
            f"blocks) take up to {stages * config.minutes:g} min in all, shared by {ranks.world} process(es)")
    start_group(ranks, cuda=device.torch_device.type == "cuda")
    try:
        with stop_on_signals(control) as stopping:
            result = train_blocks(config, out, count, ranks,
                                  lambda block, folder, resume: train(block, folder, resume=resume, control=control,
                                                                      progress=not ranks.distributed, log=say), say,
                                  stop_requested=control.stop.is_set)
    finally:
        end_group(ranks)
    if result.stopped:   # a stop that came after the last block's last step leaves a finished, merged run
        print(f"{out}: stopped; finished blocks are kept (continue with the same command)", file=sys.stderr)
        return stopping.exit_status if stopping.signum is not None else 130
    if result.merged:
        print(f"{out}: {count} blocks merged, {result.num_gaussians} Gaussians (inceptiongs eval {out})")
    return 0


def as_one_run(args, out: Path, what: str, resume: bool) -> int:
    """`--blocks auto` on a capture whose training photos fill one block: an ordinary run (a global
    stage and one block would be two schedules of the same photos), continued by the same command."""
    print(f"--blocks auto: {what} ({out})", file=sys.stderr)
    return run_one(argparse.Namespace(**{**vars(args), "blocks": None, "resume": resume}), out)


def joint_prior(args, out: Path, config, device):
    """The stage-I trainer's after_step hook that trains the prior alongside (--prior), on
    ``device`` (torch.device), the run's."""
    from ..prior.joint import JointPrior
    from ..scene.loader import load_scene
    from .prior import new_prior

    if args.prior < 1:
        raise InputError(f"--prior: must be >= 1 trainer steps per prior step, got {args.prior}")
    if (args.prior_backend or "tiny") == "sd" and not args.sd_path:
        raise InputError("--prior-backend sd needs --sd-path DIR (a local Stable Diffusion diffusers folder)")
    scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
    return JointPrior(out, scene, lambda gaussians: new_prior(args.prior_backend, args.sd_path, gaussians.to(device),
                                                              device, out, seed=config.seed),
                      every=args.prior, restart=not args.resume, device=device)
