"""Where a stage-I step's time goes: torch's profiler over a window of training steps.

Trains SCENE with the default strategy and the PGSR terms (as `inceptiongs train`), lets
``--warm`` steps pass (caches, densification's first rounds), then profiles the next ``--steps``
steps and prints the operators with the most self time (on CUDA, GPU time; on the CPU, CPU
time), the number of host synchronisations, and the wall time per step. With ``--trace FILE``
it also writes a Chrome trace (chrome://tracing, Perfetto).

    python benchmarks/profile_step.py SCENE [--device cuda] [--downscale 1] [--iterations 7000]
                                            [--warm 2100] [--steps 20] [--top 25] [--trace OUT.json]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import inceptiongs  # noqa: F401  (before torch: OMP_WAIT_POLICY, docs/training.md "Speed")
import torch
from torch.profiler import ProfilerActivity, profile

from inceptiongs.rasterizer.interface import resolve_device
from inceptiongs.io.config_json import with_values
from inceptiongs.runs.config import TrainConfig, short_run_schedule
from inceptiongs.train.trainer import train


class StepWindow:
    """Starts the profiler after step ``warm`` and stops the run after ``warm + steps``."""

    def __init__(self, warm: int, steps: int, cuda: bool) -> None:
        self.warm, self.steps, self.cuda = warm, steps, cuda
        activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
        self.profiler = profile(activities=activities, record_shapes=False)
        self.started_at = self.stopped_at = None
        self.control = type("Control", (), {})()
        import threading
        self.control.stop, self.control.pause = threading.Event(), threading.Event()

    def __call__(self, step: int, gaussians, checkpointed: bool) -> None:
        if step == self.warm:
            self.sync()
            self.profiler.__enter__()
            self.started_at = time.perf_counter()
            self.count = len(gaussians)
        elif step == self.warm + self.steps:
            self.sync()
            self.stopped_at = time.perf_counter()
            self.profiler.__exit__(None, None, None)
            self.control.stop.set()

    def sync(self) -> None:
        if self.cuda:
            torch.cuda.synchronize()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                        help="the commands' one device rule (inceptiongs.rasterizer.interface.resolve_device)")
    parser.add_argument("--downscale", type=int, default=1)
    parser.add_argument("--iterations", type=int, default=7000, help="the schedule the window sits in")
    parser.add_argument("--warm", type=int, default=2100, help="steps before the window (PGSR terms on, model grown)")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--trace", type=Path, default=None)
    args = parser.parse_args()
    cuda = resolve_device(args.device).torch_device.type == "cuda"   # one that cannot run: one line now
    config = short_run_schedule(with_values(
        TrainConfig(scene=str(args.scene.resolve()), downscale=args.downscale, protocol="unstructured",
                    iterations=args.iterations, device=args.device),
        {"output.eval_every": 10 ** 9, "output.checkpoint_every": 10 ** 9}))
    window = StepWindow(args.warm, args.steps, cuda)
    with tempfile.TemporaryDirectory() as run_dir:
        train(config, run_dir, progress=False, control=window.control, after_step=window, log=lambda _: None)
    if window.stopped_at is None:
        print(f"the run ended before step {args.warm + args.steps}", file=sys.stderr)
        return 1
    per_step_ms = 1000.0 * (window.stopped_at - window.started_at) / args.steps
    events = window.profiler.key_averages()
    sort = "self_cuda_time_total" if cuda else "self_cpu_time_total"
    print(f"{args.steps} steps after step {args.warm} at {window.count} Gaussians on {args.device}: "
          f"{per_step_ms:.1f} ms per step (profiler on)")
    syncs = sum(e.count for e in events if e.key in ("cudaStreamSynchronize", "cudaDeviceSynchronize",
                                                      "aten::item", "aten::_local_scalar_dense"))
    print(f"host synchronisations (item / stream syncs): {syncs / args.steps:.1f} per step")
    print(events.table(sort_by=sort, row_limit=args.top))
    if args.trace is not None:
        window.profiler.export_chrome_trace(str(args.trace))
    return 0


if __name__ == "__main__":
    sys.exit(main())
