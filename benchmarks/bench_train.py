"""Stage-I training benchmark: test PSNR against wall-clock time, per strategy.

    python benchmarks/bench_train.py [--scene ../shared/data/fern | demo] [--protocol llff]
        [--minutes 10] [--iterations 700] [--eval-every 100] [--out /tmp/bench_train]
        [--strategies default,mcmc,dropgaussian] [--no-free-space] [--plot F.png]
        [--profile-steps N]

Trains each strategy with the CLI's defaults on the same scene and seed, one after the other,
at equal wall time (--minutes; without --iterations the schedule is sized to it from the
measured step rate, as `inceptiongs train --minutes` does) and prints one line per evaluation:
training seconds, iteration, Gaussians, PSNR / SSIM of every group the protocol scores
(all; scarce and covered for the unstructured one), then a summary at the end of the budget
and, with --plot, PSNR against time per strategy. ``--scene demo`` writes the built-in demo
scene (its stage I runs at --downscale 2, as `inceptiongs demo`). Targets (2-core CPU):
fern >= 23 dB within 10 min, 25.17 dB within 30 min. --profile-steps N instead profiles N steps
with cProfile and prints where the time goes.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TARGETS = {"fern": [(10, 23.0), (30, 25.17)]}


def main() -> int:
    parser = _parser()
    args = parser.parse_args()

    from inceptiongs.commands.train import photos_to_exclude
    from inceptiongs.runs.config import BUDGET_STEPS_PER_MINUTE_GUESS, STRATEGY_NAMES

    strategies = [name.strip() for name in args.strategies.split(",") if name.strip()]
    unknown = [name for name in strategies if name not in STRATEGY_NAMES]
    if unknown or not strategies:
        parser.error(f"--strategies: choose from {', '.join(STRATEGY_NAMES)} (got {args.strategies!r})")
    out = Path(args.out)
    scene = Path(args.scene)
    if args.scene == "demo":
        from inceptiongs.scene.demo import write_demo_scene
        scene = write_demo_scene(out / "demo_scene", progress=False)
    excluded = photos_to_exclude(args.exclude_photos)
    sized = args.iterations is None
    iterations = args.iterations if not sized else max(1, round(BUDGET_STEPS_PER_MINUTE_GUESS * args.minutes))

    def config_for(strategy: str):
        return _config_for(args, scene, iterations, sized, excluded, strategy)

    if args.profile_steps:
        _profile(config_for(strategies[0]), args.profile_steps, out)
        return 0

    curves: dict[str, list[dict]] = {}
    for strategy in strategies:
        curves[strategy] = _bench_strategy(strategy, config_for(strategy), out / strategy, scene.name,
                                           args.minutes)
    groups = _print_summary(curves, args, scene.name)
    if args.plot:
        plot_curves(curves, groups, Path(args.plot), f"{scene.name}: stage I per strategy")
        print(f"plot: {args.plot}")
    return 0


def _parser() -> argparse.ArgumentParser:
    """The benchmark's command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(REPO.parent / "shared" / "data" / "fern"))
    parser.add_argument("--protocol", default="llff")
    parser.add_argument("--downscale", type=int, default=1)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--iterations", type=int, default=None,
                        help="schedule length (default: sized to --minutes from the measured step rate)")
    parser.add_argument("--eval-every", type=int, default=100)
    parser.add_argument("--no-pgsr", action="store_true")
    parser.add_argument("--free-space", action=argparse.BooleanOptionalAction, default=True,
                        help="the free-space rules (on by default, as the train command)")
    parser.add_argument("--sky-shell", action=argparse.BooleanOptionalAction, default=True,
                        help="the sky shell (on by default, as the train command)")
    parser.add_argument("--sky-min-scale", type=float, default=None,
                        help="the shell's axes kept above this fraction of their initial size (default: TrainConfig's)")
    parser.add_argument("--random-background", action="store_true",
                        help="render each training step over a random colour (TrainConfig.losses.random_background)")
    parser.add_argument("--sh-spread", type=float, default=None,
                        help="degrees of view spread per SH degree (default: TrainConfig's; 0 = no per-Gaussian limit)")
    parser.add_argument("--prune-large-from", type=int, default=None,
                        help="step from which oversized Gaussians are pruned (default: the schedule's; "
                             "with --iterations only: a sized run re-derives it)")
    parser.add_argument("--prune-screen-radius", type=float, default=None,
                        help="footprint radius (pixels) above which the screen-size rule prunes (default: TrainConfig's)")
    parser.add_argument("--strategies", default="default",
                        help="comma-separated: default, mcmc, dropgaussian (each gets --minutes)")
    parser.add_argument("--exclude-photos", default=None, metavar="NAMES|FILE|RUN",
                        help="as `inceptiongs train --exclude-photos`: photos left out of training and evaluation")
    parser.add_argument("--plot", help="write PSNR against time per strategy to this PNG")
    parser.add_argument("--out", default="/tmp/bench_train")
    parser.add_argument("--profile-steps", type=int, default=0)
    return parser


def _config_for(args: argparse.Namespace, scene: Path, iterations: int, sized: bool, excluded,
                strategy: str):
    """The TrainConfig one strategy trains with: the CLI's short-run schedule plus the overrides
    given on the command line."""
    from inceptiongs.io.config_json import with_values
    from inceptiongs.runs.config import TrainConfig, short_run_schedule

    config = short_run_schedule(with_values(TrainConfig(
        scene=str(scene.resolve()), protocol=args.protocol, downscale=args.downscale,
        iterations=iterations, minutes=args.minutes, pgsr=not args.no_pgsr, strategy=strategy,
        size_to_minutes=sized, exclude_photos=excluded), {
            "free_space.enabled": args.free_space, "free_space.sky_shell": args.sky_shell,
            "losses.random_background": args.random_background}))
    overrides = {"sh.spread_deg_per_degree": args.sh_spread,
                 "densification.prune_screen_radius": args.prune_screen_radius,
                 "free_space.sky_min_scale": args.sky_min_scale,
                 "densification.prune_large_from": args.prune_large_from}
    config = with_values(config, {path: value for path, value in overrides.items() if value is not None})
    return with_values(config, {"output.eval_every": args.eval_every, "output.log_every": 10,
                                "output.checkpoint_every": max(args.eval_every, 500)})


def _profile(config, steps: int, out: Path) -> None:
    """Train ``steps`` steps under cProfile and print the 30 most expensive calls (cumulative)."""
    from inceptiongs.train.trainer import train
    from inceptiongs.io.config_json import with_values

    config = with_values(config, {"iterations": steps, "minutes": None, "size_to_minutes": False,
                                  "output.eval_every": 10 ** 9, "output.checkpoint_every": 10 ** 9})
    shutil.rmtree(out / "profile", ignore_errors=True)
    profiler = cProfile.Profile()
    profiler.enable()
    train(config, out / "profile", progress=False)
    profiler.disable()
    pstats.Stats(profiler, stream=sys.stdout).sort_stats("cumulative").print_stats(30)


def _bench_strategy(strategy: str, config, run: Path, scene_name: str, minutes_budget: float) -> list[dict]:
    """Train one strategy into ``run`` (emptied first), print its evaluation table, floaters and
    targets, and return its evaluation records (metrics.jsonl lines that carry scores)."""
    from inceptiongs.train.trainer import train

    shutil.rmtree(run, ignore_errors=True)
    # The machine is shared: the load average says how much of it this run had.
    load_before = os.getloadavg()
    result = train(config, run)
    load_after = os.getloadavg()
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    records = [r for r in records if "all_psnr" in r]
    groups = _groups(records)
    print(f"\n== {strategy}: {result.iteration} iterations (schedule "
          f"{json.loads((run / 'config.json').read_text())['iterations']}), {result.num_gaussians} Gaussians; "
          f"load average (1/5/15 min) {'/'.join(f'{v:.1f}' for v in load_before)} before, "
          f"{'/'.join(f'{v:.1f}' for v in load_after)} after, on {os.cpu_count()} cores "
          f"(figures are noisy when others run)")
    print(f"{'train_s':>8} {'iter':>6} {'gaussians':>9} "
          + " ".join(f"{g + '_psnr':>12} {g + '_ssim':>12}" for g in groups))
    for record in records:
        print(f"{record['train_s']:8.1f} {record['iteration']:6d} {record['num_gaussians']:9d} "
              + " ".join(f"{record[g + '_psnr']:12.2f} {record[g + '_ssim']:12.4f}" for g in groups))
    worst, over = floaters_in_training_views(run)
    if worst is not None:
        print(f"floaters (training-view pixels rendered closer than the camera's near bound): worst view "
              f"{100 * worst:.2f} %, {over} view(s) above 1 %")
    _print_targets(records, scene_name, minutes_budget)
    return records


def _print_targets(records: list[dict], scene_name: str, minutes_budget: float) -> None:
    """Whether the best PSNR within each of the scene's time targets (TARGETS) met it."""
    curve = [(r["train_s"], r["all_psnr"]) for r in records]
    for minutes, target in TARGETS.get(scene_name, []):
        if minutes > minutes_budget:
            print(f"target {target:.2f} dB within {minutes} min: not measured (ran {minutes_budget:g} min)")
            continue
        reached = [p for t, p in curve if t <= minutes * 60]
        best = max(reached) if reached else float("nan")
        print(f"target {target:.2f} dB within {minutes} min: best {best:.2f} dB -> "
              f"{'met' if best >= target else 'NOT met'}")


def _print_summary(curves: dict[str, list[dict]], args: argparse.Namespace, scene_name: str) -> list[str]:
    """Print each strategy's last evaluation side by side; return the scored groups."""
    print(f"\n== at the end of {args.minutes:g} min ({scene_name}, seed 0, {args.protocol} protocol)")
    groups = _groups(next(iter(curves.values())))
    print(f"{'strategy':>14} {'iter':>6} {'gaussians':>9} "
          + " ".join(f"{g + '_psnr':>12} {g + '_ssim':>12}" for g in groups))
    for strategy, records in curves.items():
        last = records[-1]
        print(f"{strategy:>14} {last['iteration']:6d} {last['num_gaussians']:9d} "
              + " ".join(f"{last[g + '_psnr']:12.2f} {last[g + '_ssim']:12.4f}" for g in groups))
    return groups


def floaters_in_training_views(run: Path) -> tuple[float | None, int]:
    """(largest fraction of a training view's pixels drawn before its near bound, views above 1 %),
    from the run's last checkpoint (its near bounds come from the sparse points); (None, 0)
    when the checkpoint has no near bounds."""
    import torch

    from inceptiongs.evaluation.protocols import Split
    from inceptiongs.rasterizer.interface import cpu_rasterizer
    from inceptiongs.runs.checkpoint import latest_checkpoint, load_checkpoint
    from inceptiongs.runs.config import TrainConfig
    from inceptiongs.train.free_space import floater_fraction
    from inceptiongs.gaussians import gaussians_from_params
    from inceptiongs.scene.loader import load_scene

    payload = load_checkpoint(latest_checkpoint(run))
    if payload.get("near") is None:
        return None, 0
    config = TrainConfig.load(run / "config.json")
    scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
    split = Split.load(run / "split.json", scene.cameras)
    gaussians = gaussians_from_params(payload["params"]).detach()
    fractions = []
    with torch.no_grad():
        for near, index in zip(payload["near"].tolist(), split.train):
            depth = cpu_rasterizer()(gaussians, scene.cameras[index], outputs=("depth",))["depth"]
            fractions.append(floater_fraction(depth, near))
    return max(fractions), sum(f > 0.01 for f in fractions)


def _groups(records: list[dict]) -> list[str]:
    """The scored groups, in display order (the unstructured protocol adds scarce and covered)."""
    return [g for g in ("all", "scarce", "covered") if records and f"{g}_psnr" in records[0]]


def plot_curves(curves: dict[str, list[dict]], groups: list[str], path: Path, title: str) -> None:
    """One panel per group: PSNR against training minutes, one line per strategy."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from inceptiongs.io.atomic import atomic_write_bytes

    figure, axes = plt.subplots(1, len(groups), figsize=(4.2 * len(groups), 3.4), squeeze=False)
    for axis, group in zip(axes[0], groups):
        for strategy, records in curves.items():
            axis.plot([r["train_s"] / 60 for r in records], [r[f"{group}_psnr"] for r in records],
                      marker="o", markersize=3, label=strategy)
        axis.set_title(f"{group} views")
        axis.set_xlabel("training minutes")
        axis.set_ylabel("PSNR (dB)")
        axis.grid(alpha=0.3)
    axes[0][0].legend()
    figure.suptitle(title)
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    plt.close(figure)
    atomic_write_bytes(path, buffer.getvalue())


if __name__ == "__main__":
    sys.exit(main())
