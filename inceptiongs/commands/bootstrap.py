"""`inceptiongs bootstrap RUN [--config FILE.json]`: stage II, repair the flagged (or j*) views of a
stage-I run. A few flags of their own; every other setting comes from --config
(docs/bootstrap_options.md).

Writes RUN2 (default RUN_bootstrap), a run folder that eval/report/render/the viewer read;
see docs/bootstrap.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError

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
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the result already in --out (refused without this flag)")
    parser.add_argument("--config", metavar="FILE.json", default=None,
                        help="a JSON object of bootstrap settings (docs/bootstrap_options.md lists every key; "
                             "RUN2/bootstrap/config.json of an earlier result is one); flags given here override it")
    # default None: a flag not given leaves the --config file's value (else the default) in place
    parser.add_argument("--rounds", type=int, default=None, help=f"bootstrap rounds (default {d.rounds})")
    parser.add_argument("--minutes", type=float, default=None,
                        help="wall budget for the whole bootstrap (prior, generation, refinement)")
    parser.add_argument("--iterations", type=int, default=None,
                        help=f"refinement steps per round (default {d.iterations})")
    parser.add_argument("--seed", type=int, default=None, help=f"generation and sampling seed (default {d.seed})")


def config_from_args(args: argparse.Namespace):
    """The BootstrapConfig of a command line: the --config file's (else the defaults), with the
    flags given (CONFIG_FLAGS) in its place; validated, errors naming the file or "arguments"."""
    import dataclasses

    from ..bootstrap.config import BootstrapConfig

    base = BootstrapConfig.load(args.config) if args.config is not None else BootstrapConfig()
    given = {name: getattr(args, name) for name in CONFIG_FLAGS if getattr(args, name) is not None}
    config = dataclasses.replace(base, **given).validate("arguments")
    if config.lpips_weights is not None and not Path(config.lpips_weights).is_file():
        raise InputError(f"{args.config}: lpips_weights {config.lpips_weights}: LPIPS weights file does not exist")
    return config


def run(args) -> int:
    from ..bootstrap.runner import (check_output_folder, default_out_dir, load_stage1, resolve_targets,
                                    run_bootstrap)
    from ..train.run_folder import next_free_folder

    config = config_from_args(args)
    run_dir = Path(args.run)
    if args.out:
        out_dir = Path(args.out)
    else:  # the default name never lands on an earlier result: the next free one is chosen
        out_dir = default_out_dir(run_dir) if args.overwrite else next_free_folder(default_out_dir(run_dir))
    check_output_folder(out_dir, args.overwrite)  # before loading anything
    stage1 = load_stage1(run_dir)
    targets = resolve_targets(stage1.scene, stage1.split, args.targets, args.target_view, config.rounds, run_dir=run_dir)
    print(f"bootstrap {run_dir} -> {out_dir}: targets {', '.join(f'{t.name} ({t.origin})' for t in targets)}")
    result = run_bootstrap(stage1, out_dir, targets, config, overwrite=args.overwrite)
    print(f"prior: {result.prior}")
    if result.supervised_views is not None and result.supervised_views < result.virtual_views:
        print(f"{result.virtual_views - result.supervised_views} of {result.virtual_views} virtual views took no step: "
              f"their warped photos agree with the render better than with each other"
              + (" (so this run is stage I trained longer)" if result.supervised_views == 0 else ""))
    print(f"{result.virtual_views} virtual views ({result.cache_hits} from the cache), "
          f"iterations {result.start_iteration}..{result.iteration}, {result.wall_s:.1f} s, "
          f"{result.num_gaussians} Gaussians")
    for group in ("scarce", "covered", "all"):
        before, after = result.initial_eval.get(f"{group}_psnr"), result.last_eval.get(f"{group}_psnr")
        if before is not None and after is not None:
            print(f"{group:>8} PSNR {before:6.2f} -> {after:6.2f} dB   SSIM "
                  f"{result.initial_eval[f'{group}_ssim']:.4f} -> {result.last_eval[f'{group}_ssim']:.4f}")
    print(f"wrote {out_dir}")
    return 0
