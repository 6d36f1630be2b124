"""Training-step time at a real model size: resume a copy of a run's checkpoint and time steps.

    python benchmarks/bench_step.py RUN [--checkpoint step_0001500.pt] [--steps 30] [--warmup 5]

RUN is a stage-I run folder (config.json, checkpoints/). The checkpoint (default: the newest) and
the config are copied to a temporary folder, which is resumed for warmup + steps further steps
with the run's own settings (time budget, evaluation and checkpoints off); RUN is only read.
Prints the mean seconds per step over the timed steps and the model size. The step sequence
is the run's own (the resumed state holds the view order), so two code versions timed on the
same checkpoint time the same views: compare them on the same idle machine, one at a time.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import inceptiongs  # noqa: F401  (sets OMP_WAIT_POLICY before torch loads)
import inceptiongs.train.trainer as trainer_module
from inceptiongs.errors import InputError
from inceptiongs.runs.checkpoint import list_checkpoints
from inceptiongs.io.config_json import with_values
from inceptiongs.runs.config import TrainConfig


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--checkpoint", default=None, help="file name in RUN/checkpoints (default: the newest)")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=5)
    args = parser.parse_args(argv)
    try:
        config = TrainConfig.load(args.run / "config.json")
        found = [(step, path) for step, path in list_checkpoints(args.run)
                 if args.checkpoint is None or path.name == args.checkpoint]
        if not found:
            raise InputError(f"{args.run / 'checkpoints'}: no checkpoint "
                             f"{args.checkpoint or 'to resume'}")
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    start, source = found[-1]
    total = args.warmup + args.steps
    config = with_values(config, {"iterations": start + total, "minutes": None, "size_to_minutes": False,
                                  "output.eval_every": 10 ** 9, "output.checkpoint_every": 10 ** 9})

    timed: dict[str, float] = {}
    counts: list[int] = []
    # Wrapping the step function times the step alone; train()'s after_step hook would add
    # building a detached copy of the model to every timed step.
    original_step = trainer_module.train_step

    def timed_step(*step_args, **step_kwargs):
        done = len(counts)
        if done == args.warmup:
            timed["start"] = time.perf_counter()
        record = original_step(*step_args, **step_kwargs)
        counts.append(int(record.get("num_gaussians", 0)))
        if len(counts) == total:
            timed["end"] = time.perf_counter()
        return record

    with tempfile.TemporaryDirectory(prefix="bench_step_") as scratch:
        run = Path(scratch) / "run"
        (run / "checkpoints").mkdir(parents=True)
        shutil.copy2(source, run / "checkpoints" / source.name)
        if (args.run / "split.json").is_file():
            shutil.copy2(args.run / "split.json", run / "split.json")
        config.save(run / "config.json")
        trainer_module.train_step = timed_step
        try:
            trainer_module.train(config, run, resume=True, progress=False)
        finally:
            trainer_module.train_step = original_step
    if "end" not in timed:
        print(f"error: the run stopped after {len(counts)} of {total} steps", file=sys.stderr)
        return 1
    per_step = (timed["end"] - timed["start"]) / args.steps
    print(f"{args.run} from {source.name}: {per_step:.3f} s/step over {args.steps} steps "
          f"(after {args.warmup} warm-up), {counts[-1]} Gaussians")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
