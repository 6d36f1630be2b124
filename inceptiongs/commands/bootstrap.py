"""`inceptiongs bootstrap RUN`: stage II, repair the flagged (or j*) views of a stage-I run.

Writes RUN2 (default RUN_bootstrap), a run folder that eval/report/render/the viewer read;
see docs/bootstrap.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError

HELP = "stage II: repair flagged views of a run by generative bootstrapping (writes RUN_bootstrap)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..bootstrap.config import VIRTUAL_DEPTHS, BootstrapConfig

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
    parser.add_argument("--rounds", type=int, default=d.rounds, help=f"bootstrap rounds (default {d.rounds})")
    parser.add_argument("--minutes", type=float, default=None,
                        help="wall budget for the whole bootstrap (prior, generation, refinement)")
    parser.add_argument("--iterations", type=int, default=d.iterations,
                        help=f"refinement steps per round (default {d.iterations})")
    parser.add_argument("--seed", type=int, default=d.seed, help="generation and sampling seed")
    parser.add_argument("--k", type=int, default=None, help="nearest training views per target")
    parser.add_argument("--l", type=int, default=None, help="interpolated poses per training view")
    parser.add_argument("--ddim-steps", type=int, default=d.ddim_steps, help="DDIM steps per generated image")
    parser.add_argument("--prior-minutes", type=float, default=d.prior_minutes,
                        help="budget of the short prior training when the run has no prior")
    parser.add_argument("--generated-weight", type=float, default=d.generated_weight,
                        help="loss weight of generated (not photo-trusted) pixels of a virtual view "
                             f"(default {d.generated_weight:g}: the paper's loss on I*)")
    parser.add_argument("--regenerate-every", type=int, default=d.regenerate_every, metavar="N",
                        help="generate every virtual view's I* again from the refined Gaussians every N "
                             f"refinement steps (default {d.regenerate_every}; 0: once per round)")
    parser.add_argument("--include-target", action=argparse.BooleanOptionalAction, default=d.include_target,
                        help="also supervise the target pose itself with the prior's repair of its render "
                             f"(default {'on' if d.include_target else 'off'})")
    parser.add_argument("--densify", action="store_true", help="densify during the refinement")
    parser.add_argument("--no-blending", action="store_true", help="ablation: I* = generated image only")
    parser.add_argument("--uniform-sampling", action="store_true",
                        help="ablation: uniform virtual-view sampling instead of Langevin")
    parser.add_argument("--untrained-prior", action="store_true", help="ablation: randomly initialised prior")
    parser.add_argument("--lpips-weights", metavar="FILE", default=None,
                        help="TorchScript LPIPS for the perceptual loss (default: a weight-free distance)")
    parser.add_argument("--supervision", choices=("blend", "photo"), default=d.supervision,
                        help="what I* is made of: 'blend' (binary-masked mean of the warped photos over the "
                             "fill) or 'photo' (photo-consistent depth, exposure "
                             f"matching, lumigraph weights, soft mask; default {d.supervision})")
    parser.add_argument("--fill", choices=("prior", "inpaint", "render"), default=d.fill,
                        help=f"what fills pixels no photo covers: the prior's image (the paper's, with --supervision "
                             f"blend), the photos inpainted, or the render (default {d.fill})")
    parser.add_argument("--virtual-depth", choices=VIRTUAL_DEPTHS, default=d.virtual_depth,
                        help="the depth photos are warped into a virtual view with: 'render' (the model's "
                             "surface depth there), 'sources' (the nearest training views' depths splatted "
                             "into it), 'both' (the render's where its warps are trusted, else the splatted) or "
                             "'auto' (per view, whichever places more photos; "
                             f"default {d.virtual_depth})")
    parser.add_argument("--align-px", type=float, default=d.align_px, metavar="PX",
                        help="with --supervision blend: move each warped photo onto the render by optical flow "
                             "first, shifts beyond PX pixels untrusted (default: off)")
    parser.add_argument("--virtual-pixels", choices=("all", "informative"), default=d.virtual_pixels,
                        help="which pixels of a virtual view carry loss: 'all' (I*; generated ones weighted by "
                             "--generated-weight) or 'informative' (with --supervision photo: only where the "
                             f"photos contradict the render; default {d.virtual_pixels})")
    parser.add_argument("--virtual-mode", choices=("alternate", "additive"), default=d.virtual_mode,
                        help="'alternate': a virtual step replaces a photo step; 'additive': the virtual loss "
                             f"is added to a photo step's gradient (default {d.virtual_mode})")
    parser.add_argument("--geometry-weight", type=float, default=d.geometry_weight, metavar="W",
                        help="weight of the geometry term at virtual views: 1 - NCC of the nearest photos' "
                             "patches mapped through the rendered depth and normal, back-propagated into the "
                             f"Gaussians (default {d.geometry_weight}: off)")
    parser.add_argument("--no-virtual-colour", action="store_true",
                        help="no colour target at virtual views: they carry only the geometry term "
                             "(needs --geometry-weight > 0)")
    parser.add_argument("--conscience-tolerance", type=float, default=d.conscience_tolerance, metavar="T",
                        help="lower the virtual views' weight when the nearest photos' L1 rises above its start "
                             f"by more than T (relative; default {d.conscience_tolerance}; a negative T: off)")


def config_from_args(args):
    from ..bootstrap.config import BootstrapConfig

    if args.lpips_weights is not None and not Path(args.lpips_weights).is_file():
        raise InputError(f"{args.lpips_weights}: LPIPS weights file does not exist")
    return BootstrapConfig(
        seed=args.seed, rounds=args.rounds, iterations=args.iterations, minutes=args.minutes,
        k=args.k, l=args.l, ddim_steps=args.ddim_steps, prior_minutes=args.prior_minutes,
        blending=not args.no_blending, sampling="uniform" if args.uniform_sampling else "langevin",
        prior="untrained" if args.untrained_prior else "trained", lpips_weights=args.lpips_weights,
        generated_weight=args.generated_weight, densify=args.densify,
        regenerate_every=args.regenerate_every, include_target=args.include_target,
        supervision=args.supervision, fill=args.fill, virtual_pixels=args.virtual_pixels,
        virtual_depth=args.virtual_depth,
        align_px=args.align_px,
        virtual_mode=args.virtual_mode, geometry_weight=args.geometry_weight,
        virtual_colour=not args.no_virtual_colour,
        conscience_tolerance=None if args.conscience_tolerance < 0 else args.conscience_tolerance,
    ).validate("arguments")


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
