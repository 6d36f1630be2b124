"""Blocks against one run: the same scene, the same total number of steps, scored on the same
held-out views.

    python benchmarks/bench_blocks.py [--scene ../shared/data/bonsai] [--blocks 4] [--iterations 4000]
        [--global-share 0.333] [--start-keep seen|cell] [--downscale 4] [--protocol unstructured]
        [--seed 0] [--out /tmp/bench_blocks] [--reuse-single RUN] [--reuse-global FOLDER]

Trains the scene once as one run of --iterations steps and once in --blocks blocks with the same
--iterations in all (`inceptiongs train --blocks`: --global-share of them train the global stage
on every photo, the blocks fine-tune from it with the rest), evaluates both (and the global
stage alone) on the whole scene's held-out views and prints: wall time, Gaussians, scarce /
covered / all PSNR of each, and per held-out view the blocks' PSNR minus the single run's (the
worst view names a seam). --reuse-single RUN takes the single run from RUN when it is a finished
run of the same scene, steps, downscale, protocol and seed (trained there first when RUN is empty).
--out is emptied first; --reuse-global FOLDER copies a finished global stage (RUN/blocks/global of
an earlier blocks run of the same scene, downscale, protocol, seed and global steps) into the new
blocks run, which then skips it ("global stage: finished earlier").
Targets (issue "Captures of thousands of photos"): scarce and covered within 0.3 dB of the single
run; no held-out view below it by more than 1 dB.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def train(scene: Path, out: Path, iterations: int, args, blocks: int | None) -> float:
    command = [sys.executable, "-m", "inceptiongs", "train", str(scene), "--out", str(out), "--iterations",
               str(iterations), "--downscale", str(args.downscale), "--protocol", args.protocol, "--seed",
               str(args.seed)]
    if blocks:
        settings = out.parent / "blocks_settings.json"
        settings.write_text(json.dumps({"block": {"global_share": args.global_share,
                                                  "start_keep": args.start_keep, "schedule": args.schedule}}))
        command += ["--blocks", str(blocks), "--config", str(settings)]
    began = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stderr[-3000:]}")
    return time.perf_counter() - began


def reusable(run: Path, scene: Path, args) -> bool:
    """Whether ``run`` is a finished single run of this comparison (its config and last metrics line)."""
    try:
        config = json.loads((run / "config.json").read_text())
        last = json.loads((run / "metrics.jsonl").read_text().splitlines()[-1])
    except (OSError, ValueError, IndexError):
        return False
    return ((run / "model.ply").is_file() and not config.get("blocks") and config.get("scene") == str(scene.resolve())
            and config.get("iterations") == args.iterations and config.get("downscale") == args.downscale
            and config.get("protocol") == args.protocol and config.get("seed") == args.seed
            and last.get("iteration") == args.iterations)


def copy_global(source: Path, target: Path, scene: Path, args) -> None:
    """``source`` (a finished global stage) copied to ``target`` when it was trained for this
    comparison (scene, downscale, protocol, seed, the global share's steps); else SystemExit."""
    try:
        config = json.loads((source / "config.json").read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"--reuse-global {source}: no readable config.json ({exc})")
    steps = max(1, round(args.global_share * args.iterations)) if args.global_share > 0 else 0
    wanted = {"scene": str(scene.resolve()), "downscale": args.downscale, "protocol": args.protocol,
              "seed": args.seed, "iterations": steps}
    wrong = {key: config.get(key) for key, value in wanted.items() if config.get(key) != value}
    if wrong or not (source / "block_done.json").is_file():
        raise SystemExit(f"--reuse-global {source}: not a finished global stage of this comparison "
                         f"(block_done.json {'present' if (source / 'block_done.json').is_file() else 'missing'}; "
                         f"differs in {wrong or 'nothing'}; wanted {wanted})")
    shutil.copytree(source, target)
    print(f"global stage reused from {source}")


def evaluate(run: Path) -> dict:
    result = subprocess.run([sys.executable, "-m", "inceptiongs", "eval", str(run), "--json"],
                            capture_output=True, text=True, check=True)
    return json.loads(result.stdout)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(Path(os.environ.get("INCEPTIONGS_DATA", REPO.parent / "shared" / "data")) / "bonsai"))
    parser.add_argument("--blocks", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=4000, help="total steps of either run")
    parser.add_argument("--global-share", type=float, default=1.0 / 3.0,
                        help="share of the steps the global stage trains (block.global_share)")
    parser.add_argument("--start-keep", default="seen", choices=("seen", "cell"), help="block.start_keep")
    parser.add_argument("--schedule", default="restart", choices=("restart", "continue"), help="block.schedule")
    parser.add_argument("--reuse-single", metavar="RUN", help="the single run's folder, kept across invocations")
    parser.add_argument("--reuse-global", metavar="FOLDER", help="a finished global stage to copy in (module doc)")
    parser.add_argument("--downscale", type=int, default=4)
    parser.add_argument("--protocol", default="unstructured")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="/tmp/bench_blocks")
    args = parser.parse_args()
    scene, out = Path(args.scene), Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    single_dir = Path(args.reuse_single) if args.reuse_single else out / "single"
    if args.reuse_single and reusable(single_dir, scene, args):
        single_s = float("nan")
        print(f"single run reused from {single_dir}")
    else:
        if args.reuse_single:
            shutil.rmtree(single_dir, ignore_errors=True)
        single_s = train(scene, single_dir, args.iterations, args, None)
    if args.reuse_global:
        copy_global(Path(args.reuse_global), out / "blocks" / "blocks" / "global", scene, args)
    blocks_s = train(scene, out / "blocks", args.iterations, args, args.blocks)
    single, blocks = evaluate(single_dir), evaluate(out / "blocks")
    plan = json.loads((out / "blocks" / "blocks.json").read_text())
    stages = [("single", single, single_s), ("blocks", blocks, blocks_s)]
    global_dir = out / "blocks" / "blocks" / "global"
    global_steps = 0
    if (global_dir / "model.ply").is_file():
        global_steps = json.loads((global_dir / "config.json").read_text())["iterations"]
        stages.append(("global", evaluate(global_dir), float("nan")))
    block_steps = [json.loads((out / "blocks" / "blocks" / f"block_{i:02d}" / "config.json").read_text())["iterations"]
                   for i in range(args.blocks)]
    print(f"scene {scene.name}, {args.iterations} steps in all, downscale {args.downscale}, protocol {args.protocol}")
    print(f"global stage: share {args.global_share:.3f}, {global_steps} steps; blocks: {args.blocks} of "
          f"{block_steps} steps (sum with the global stage {global_steps + sum(block_steps)}), start_keep "
          f"{args.start_keep}, schedule {args.schedule}")
    print(f"training photos per block {[b['train_photos'] for b in plan['blocks']]}, "
          f"Gaussians kept per block {plan['kept_gaussians']}")
    print(f"{'run':8s} {'wall s':>8s} {'scarce':>8s} {'covered':>8s} {'all':>8s}")
    for name, scores, seconds in stages:
        groups = scores["groups"]
        # A protocol without a scarce group (llff) scores it as null: printed as nan.
        print(f"{name:8s} {seconds:8.0f} " + " ".join(f"{(groups.get(g) or {}).get('psnr') or float('nan'):8.2f}"
                                                       for g in ("scarce", "covered", "all")))
    by_view = {view["name"]: view["psnr"] for view in single["views"]}
    for name, scores, _ in stages[1:]:
        gaps = sorted((view["psnr"] - by_view[view["name"]], view["name"]) for view in scores["views"])
        print(f"{name} - single per held-out view (dB): worst "
              + ", ".join(f"{view} {gap:+.2f}" for gap, view in gaps[:5]) + f"; best {gaps[-1][1]} {gaps[-1][0]:+.2f}")
    for group in ("scarce", "covered"):
        if (single["groups"].get(group) or {}).get("psnr") is not None:
            print(f"{group}: blocks - single = {blocks['groups'][group]['psnr'] - single['groups'][group]['psnr']:+.2f} dB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
