"""`inceptiongs bootstrap RUN [--config FILE.json]`: stage II, repair the flagged (or j*) views of a
stage-I run. A few flags of their own; every other setting comes from --config
(docs/bootstrap_options.md).

Writes RUN2 (default RUN_bootstrap), a run folder that eval/report/render/the viewer read;
see docs/bootstrap.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError
from ..io.atomic import OutputError
from .device import recorded_device
from ..io.values import flag

HELP = "stage II: repair flagged views of a run by generative bootstrapping (writes RUN_bootstrap)"


# The config fields with a flag of their own; the rest are set with --config FILE.json
# (docs/bootstrap_options.md). A flag given overrides the file.
CONFIG_FLAGS = ("rounds", "minutes", "iterations", "seed")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..bootstrap.config import BootstrapConfig

    d = BootstrapConfig()
    parser.add_argument("run", help="a stage-I run folder (inceptiongs train)")
    target = parser.add_mutually_exclusive_group()
    target.add_argument("--targets", metavar="FLAGS.json", default=None,
                        help="the viewer's flags file (default: the scene's flags.json when it exists, "
                             "else the split's target view j*)")
    target.add_argument("--target-view", metavar="NAME", default=None, help="repair this scene view's pose")
    parser.add_argument("--out", default=None, help="output run folder (default RUN_bootstrap, or RUN_bootstrap_2, "
                                                    "... when that already holds a result)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--overwrite", action="store_true",
                      help="replace the result already in --out (refused without this flag)")
    mode.add_argument("--resume", action="store_true",
                      help="continue the stopped bootstrap in --out from its newest checkpoint, with its saved "
                           "targets and settings (--minutes may give it a new budget)")
    parser.add_argument("--config", metavar="FILE.json", default=None,
                        help="a JSON object of bootstrap settings (docs/bootstrap_options.md lists every key; "
                             "RUN2/bootstrap/config.json of an earlier result is one); flags given here override it")
    # default None: a flag not given leaves the --config file's value (else the default) in place
    parser.add_argument("--rounds", type=flag("count"), default=None, help=f"bootstrap rounds (default {d.rounds})")
    parser.add_argument("--minutes", type=flag("minutes"), default=None,
                        help="wall budget for the whole bootstrap (prior, generation, refinement)")
    parser.add_argument("--iterations", type=flag("steps"), default=None,
                        help=f"refinement steps per round (default {d.iterations})")
    parser.add_argument("--seed", type=flag("seed"), default=None, help=f"generation and sampling seed (default {d.seed})")


def config_from_args(args: argparse.Namespace, resumed: Path | None = None):
    """The BootstrapConfig of a command line: the --config file's (else the defaults), with the
    flags given (CONFIG_FLAGS) in its place; validated, errors naming the file or "arguments".
    ``resumed``: the folder of a bootstrap being resumed, whose saved settings replace the defaults."""
    import dataclasses

    from ..bootstrap.config import BootstrapConfig

    saved = None if resumed is None else resumed / "bootstrap" / "config.json"
    if args.config is not None:
        base = BootstrapConfig.load(args.config)
    elif saved is not None and saved.is_file():
        base = BootstrapConfig.load(saved)   # a resumed bootstrap keeps the settings it started with
    else:
        base = BootstrapConfig()
    given = {name: getattr(args, name) for name in CONFIG_FLAGS if getattr(args, name) is not None}
    config = dataclasses.replace(base, **given).validate("arguments")
    if config.lpips_weights is not None:
        if not Path(config.lpips_weights).is_file():
            raise InputError(f"{args.config}: lpips_weights {config.lpips_weights}: LPIPS weights file does not exist")
        from ..evaluation.lpips_net import load_lpips
        load_lpips(config.lpips_weights)   # refused here, before any work: TorchScript, objects, wrong keys
    return config


def run(args) -> int:
    from ..bootstrap.runner import (check_default_out_dir, check_output_folder, default_out_dir, load_stage1,
                                    resolve_targets, resumable, run_bootstrap)
    from ..live import JobControl
    from ..rasterizer.interface import resolve_device
    from ..stop_signals import stop_on_signals
    from ..runs.folder import next_free_folder

    run_dir = Path(args.run)
    if args.out:
        out_dir = Path(args.out)
    elif args.overwrite or args.resume:
        out_dir = check_default_out_dir(default_out_dir(run_dir))
    else:  # the default name never lands on an earlier result: the next free one is chosen
        out_dir = check_default_out_dir(next_free_folder(check_default_out_dir(default_out_dir(run_dir))))
    if out_dir.resolve() == run_dir.resolve():     # said first: no other word about the folder applies
        raise InputError(f"{out_dir}: --out must differ from the input run (the bootstrap writes a new run folder)")
    from ..io.paths import check_outside_scene
    from .render import run_scene_path

    check_outside_scene(out_dir, run_scene_path(run_dir) if run_dir.is_dir() else None)
    config = config_from_args(args, out_dir if args.resume else None)
    if run_in_blocks(run_dir):
        return run_blocks(args, run_dir, out_dir, config)
    targets = None
    if args.resume:
        targets = resumable(out_dir)[1]   # one line now when there is nothing to resume
    else:
        check_output_folder(out_dir, args.overwrite)  # before loading anything
    # The stage-I run's device (the one device rule); one that cannot run here: one line before any work.
    device = resolve_device(*recorded_device(run_dir))
    stage1 = load_stage1(run_dir)
    if not args.resume:
        targets = resolve_targets(stage1.scene, stage1.split, args.targets, args.target_view, config.rounds,
                                  run_dir=run_dir)
    names = ", ".join(f"{t.name} ({t.origin})" for t in targets or [])
    print(f"bootstrap {run_dir} -> {out_dir}: {'resumed, ' if args.resume else ''}targets {names or 'none'}")
    if device.note:
        print(device.note, file=sys.stderr)
    control = JobControl()
    with stop_on_signals(control) as stopping:
        try:
            result = run_bootstrap(stage1, out_dir, targets, config, control=control, overwrite=args.overwrite,
                                   resume=args.resume, rasterizer=device.rasterizer)
        except OutputError as exc:
            if stopping.signum is None:
                raise
            from .stopped import stopped_with_failed_save
            return stopped_with_failed_save(exc, out_dir, stopping.exit_status,
                                            f"inceptiongs bootstrap {run_dir} --out {out_dir} --resume")
    if stopping.signum is not None:
        from ..runs.checkpoint import latest_checkpoint
        if latest_checkpoint(out_dir) is not None:
            print(f"{out_dir}: stopped at iteration {result.iteration}; saved model.ply and a checkpoint (continue "
                  f"with: inceptiongs bootstrap {run_dir} --out {out_dir} --resume)", file=sys.stderr)
        else:   # said as it is: a line promising a checkpoint that is not there sends the user to --resume in vain
            print(f"{out_dir}: stopped at iteration {result.iteration}; saved model.ply, no checkpoint (start again "
                  f"with: inceptiongs bootstrap {run_dir} --out {out_dir} --overwrite)", file=sys.stderr)
        return stopping.exit_status
    print(f"prior: {result.prior}")
    if result.supervised_views is not None and result.supervised_views < result.virtual_views:
        steps = "" if result.virtual_steps is None else f"; {result.virtual_steps} virtual steps ran"
        print(f"{result.virtual_views - result.supervised_views} of {result.virtual_views} virtual views were left out "
              f"by the end: their warped photos agree with the render better than with each other{steps}"
              + (" (so this run is stage I trained longer)" if result.virtual_steps == 0 else ""))
    print(f"{result.virtual_views} virtual views ({result.cache_hits} from the cache), "
          f"iterations {result.start_iteration}..{result.iteration}, {result.wall_s:.1f} s, "
          f"{result.num_gaussians} Gaussians")
    print_scores(result.initial_eval, result.last_eval)
    print(f"wrote {out_dir}")
    return 0


def print_scores(initial_eval: dict, last_eval: dict) -> None:
    """One line per held-out group scored before and after: PSNR and SSIM, input -> result."""
    for group in ("scarce", "covered", "all"):
        before, after = initial_eval.get(f"{group}_psnr"), last_eval.get(f"{group}_psnr")
        if before is not None and after is not None:
            print(f"{group:>8} PSNR {before:6.2f} -> {after:6.2f} dB   SSIM "
                  f"{initial_eval[f'{group}_ssim']:.4f} -> {last_eval[f'{group}_ssim']:.4f}")


def run_in_blocks(run_dir: Path) -> bool:
    """Whether RUN was trained in blocks (`train --blocks`; its config.json says how many)."""
    from ..runs.config import TrainConfig

    stored = run_dir / "config.json"
    return stored.is_file() and TrainConfig.load(stored).blocks > 0


def run_blocks(args, run_dir: Path, out_dir: Path, config) -> int:
    """Stage II on a run in blocks: only the blocks the flagged views see are refined
    (inceptiongs.bootstrap.blocks); the others stay as they are."""
    from ..bootstrap.blocks import bootstrap_blocks
    from ..bootstrap.runner import BLOCKS_NOT_RESUMED, check_output_folder, load_stage1, resolve_targets, run_bootstrap
    from ..live import JobControl
    from ..rasterizer.interface import resolve_device
    from ..stop_signals import stop_on_signals

    if args.resume:
        raise InputError(f"{out_dir}: {BLOCKS_NOT_RESUMED}; run it again (--overwrite replaces the stopped one)")
    check_output_folder(out_dir, args.overwrite)
    device = resolve_device(*recorded_device(run_dir))
    stage1 = load_stage1(run_dir)
    targets = resolve_targets(stage1.scene, stage1.split, args.targets, args.target_view, config.rounds,
                              run_dir=run_dir)
    print(f"bootstrap {run_dir} -> {out_dir}: targets {', '.join(f'{t.name} ({t.origin})' for t in targets)}")
    control = JobControl()
    say = lambda line: print(line, file=sys.stderr)  # noqa: E731
    with stop_on_signals(control) as stopping:
        result = bootstrap_blocks(stage1, out_dir, targets, config,
                                  lambda run, out, block_targets, block_config: run_bootstrap(
                                      run, out, block_targets, block_config, control=control,
                                      overwrite=args.overwrite, rasterizer=device.rasterizer, log=say), say,
                                  rasterizer=device.rasterizer)
    if stopping.signum is not None:
        print(f"{out_dir}: stopped; the refined blocks so far are merged into model.ply", file=sys.stderr)
        return stopping.exit_status
    for index, block in zip(result.refined, result.results):
        print(f"block {index + 1}: iterations {block.start_iteration}..{block.iteration}, {block.virtual_views} "
              f"virtual views, {block.wall_s:.1f} s")
    print_scores(result.initial_eval, result.last_eval)   # the merged model, on the whole run's held-out views
    print(f"wrote {out_dir}: {result.num_gaussians} Gaussians, blocks {', '.join(str(i + 1) for i in result.refined)} "
          f"refined (inceptiongs eval {out_dir})")
    return 0
