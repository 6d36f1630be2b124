"""Stage II's refinement rate on one stage-I run: steps per second on the run's device and on the CPU.

Runs the default bootstrap of the run's j* twice into a temporary folder, once with the
rasterizer the run's device selects (gsplat on a CUDA machine) and once with the CPU's, each for
a fixed number of refinement steps, and reads the rate from each result's metrics (training
seconds between its first and last logged step: target making, the prior and evaluation are
not refinement time).

    python benchmarks/bench_stage2_rate.py RUN [--steps 200] [--cpu-steps 20] [--which both|device|cpu]
                                               [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import inceptiongs  # noqa: F401  (before torch: OMP_WAIT_POLICY, docs/training.md "Speed")
import torch

from inceptiongs.bootstrap.config import BootstrapConfig
from inceptiongs.bootstrap.runner import run_bootstrap, run_rasterizer
from inceptiongs.bootstrap.stage1 import load_stage1
from inceptiongs.bootstrap.targets import split_targets
from inceptiongs.rasterizer.interface import cpu_rasterizer
from inceptiongs.evaluation.report import read_metrics


def refinement_rate(out_dir: Path) -> tuple[float, int]:
    """(steps per training second, steps) between the first and last logged refinement steps."""
    lines = [r for r in read_metrics(out_dir / "metrics.jsonl") if "iteration" in r and "train_s" in r and r.get("phase") is None]
    if len(lines) < 2:
        return float("nan"), 0
    steps = lines[-1]["iteration"] - lines[0]["iteration"]
    seconds = lines[-1]["train_s"] - lines[0]["train_s"]
    return (steps / seconds if seconds > 0 else float("nan")), steps


def one(run, rasterizer, steps: int, folder: Path) -> dict:
    config = BootstrapConfig(iterations=steps, log_every=max(1, steps // 10))
    targets = split_targets(run.split, run.scene, config.rounds)
    result = run_bootstrap(run, folder, targets, config, rasterizer=rasterizer, progress=False, log=lambda _: None)
    rate, measured = refinement_rate(folder)
    return {"rasterizer": rasterizer.name, "device": rasterizer.device, "steps_per_s": round(rate, 2),
            "steps_measured": measured, "num_gaussians": result.num_gaussians}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--cpu-steps", type=int, default=20)
    parser.add_argument("--which", choices=("both", "device", "cpu"), default="both")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    run = load_stage1(args.run)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        device_rasterizer = run_rasterizer(run, print)
        for rasterizer, steps, name in ((device_rasterizer, args.steps, "device"),
                                        (cpu_rasterizer(), args.cpu_steps, "cpu")):
            if args.which not in ("both", name):
                continue
            row = one(run, rasterizer, steps, Path(tmp) / name)
            rows.append(row)
            print(f"{row['rasterizer']:>7} on {row['device']}: {row['steps_per_s']:.2f} refinement steps/s "
                  f"({row['steps_measured']} steps, {row['num_gaussians']} Gaussians, "
                  f"{torch.get_num_threads()} CPU threads)", flush=True)
    if len(rows) == 2 and rows[1]["steps_per_s"] > 0:
        print(f"device / cpu: {rows[0]['steps_per_s'] / rows[1]['steps_per_s']:.1f}x")
    if args.json is not None:
        args.json.write_text(json.dumps({"gpu": torch.cuda.get_device_name() if torch.cuda.is_available() else None,
                                         "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
