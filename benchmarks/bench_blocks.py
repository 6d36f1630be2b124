"""Blocks against one run: the same scene, the same total number of steps, scored on the same
held-out views.

    python benchmarks/bench_blocks.py [--scene ../shared/data/bonsai] [--blocks 4] [--iterations 4000]
        [--downscale 4] [--protocol unstructured] [--seed 0] [--out /tmp/bench_blocks]

Trains the scene once as one run of --iterations steps and once in --blocks blocks of
--iterations / blocks steps each (`inceptiongs train --blocks`), evaluates both on the whole
scene's held-out views and prints: wall time, Gaussians, scarce / covered / all PSNR of each,
and per held-out view the blocks' PSNR minus the single run's (the worst view names a seam).
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
        command += ["--blocks", str(blocks)]
    began = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stderr[-3000:]}")
    return time.perf_counter() - began


def evaluate(run: Path) -> dict:
    result = subprocess.run([sys.executable, "-m", "inceptiongs", "eval", str(run), "--json"],
                            capture_output=True, text=True, check=True)
    return json.loads(result.stdout)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(Path(os.environ.get("INCEPTIONGS_DATA", REPO.parent / "shared" / "data")) / "bonsai"))
    parser.add_argument("--blocks", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=4000, help="total steps (each block: this / blocks)")
    parser.add_argument("--downscale", type=int, default=4)
    parser.add_argument("--protocol", default="unstructured")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="/tmp/bench_blocks")
    args = parser.parse_args()
    scene, out = Path(args.scene), Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    single_s = train(scene, out / "single", args.iterations, args, None)
    blocks_s = train(scene, out / "blocks", args.iterations // args.blocks, args, args.blocks)
    single, blocks = evaluate(out / "single"), evaluate(out / "blocks")
    plan = json.loads((out / "blocks" / "blocks.json").read_text())
    print(f"scene {scene.name}, {args.iterations} steps in all, downscale {args.downscale}, protocol {args.protocol}")
    print(f"blocks: {args.blocks}, training photos per block {[b['train_photos'] for b in plan['blocks']]}, "
          f"Gaussians kept per block {plan['kept_gaussians']}")
    print(f"{'run':8s} {'wall s':>8s} {'scarce':>8s} {'covered':>8s} {'all':>8s}")
    for name, scores, seconds in (("single", single, single_s), ("blocks", blocks, blocks_s)):
        groups = scores["groups"]
        print(f"{name:8s} {seconds:8.0f} " + " ".join(f"{groups.get(g, {}).get('psnr', float('nan')):8.2f}"
                                                       for g in ("scarce", "covered", "all")))
    by_view = {view["name"]: view["psnr"] for view in single["views"]}
    gaps = sorted((view["psnr"] - by_view[view["name"]], view["name"]) for view in blocks["views"])
    print("blocks - single per held-out view (dB): worst "
          + ", ".join(f"{name} {gap:+.2f}" for gap, name in gaps[:5]) + f"; best {gaps[-1][1]} {gaps[-1][0]:+.2f}")
    for group in ("scarce", "covered"):
        if group in single["groups"]:
            print(f"{group}: blocks - single = {blocks['groups'][group]['psnr'] - single['groups'][group]['psnr']:+.2f} dB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
