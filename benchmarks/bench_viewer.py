"""Viewer frame-rate benchmark: donut.ply at 1280x720 in the real app (Xvfb or a desktop).

Logs per-frame totals and the renderer's sort/draw times for these situations:
  idle      the camera is still; each frame re-renders the splats at full resolution
            (the app itself would skip the re-render when nothing changed, and run() even
            waits for events: that frame rate is printed too as "idle, cached")
  moving    the camera turns every frame; the app renders at the scale that holds
            MOVING_BUDGET_MS, chosen from the last render's split of its time (next_moving_scale)
  training  a job thread publishes new Gaussians ~5 times a second with CPU work in between
            (competing for the 2 cores); the app does what it does live: a new snapshot at
            most every TRAINING_REFRESH_SECONDS costs a re-render at the moving size (the model
            is "moving"), frames in between reuse the image ("renders/s" says how often
            the splats were redrawn)
Targets: idle >= 10 FPS, moving >= 20 FPS, training >= 5 FPS.

With --jobs, the CPU rows (the app's own loop, ``run()``'s wait included):
  job it/s alone        a real stage-I job (the demo scene) on its thread, no viewer: what the
                        command line gets
  job it/s, viewer idle the same job with the viewer running its loop on that model, nobody
                        touching it (target >= 85 % of the alone rate)
  idle CPU %            process CPU time / wall time of the viewer loop with nothing happening,
                        with the job paused, and in the reference mode once its image is in
                        (target < 5 %)

With --idle, the idle rows (target < 5 % CPU, no memory growth): the app's own loop on the demo
scene at --size for --idle-seconds (default 60) each, with nothing happening, with a real stage-I
job paused, and after it was stopped; each with the pointer inside the window (over the scene)
and outside it. Process CPU time (every thread, the job's included) / wall time, the frames
drawn, and the growth of the resident memory.

With --model PLY, a large model's figures only (docs/large_scenes.md; --json OUT also writes
them): load_s (the PLY read, the window, the LOD tree loaded from the cache or built with
--fresh-tree, the first settled frame), first_frame_ms, load_longest_turn_ms (the longest loop
turn after it until the settled frame: how long input waits), moving_ms (median frame along an orbit of --frames frames, 3.4 degrees
each), settle_s (last movement to the settled frame), full_ms ("full detail always": every
Gaussian), peak_rss_mb (before full detail; peak_rss_full_mb after), moving_psnr (a moving frame,
upsampled as the window shows it, against the full-detail frame of that camera), settled_psnr.

    DISPLAY=:99 python3 benchmarks/bench_viewer.py [--ply PATH] [--frames 30] [--jobs [--seconds 20]]
                                                   [--idle [--idle-seconds 60] [--settle-seconds 2]]
                                                   [--model PLY [--json OUT] [--fresh-tree]]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np


def _default_ply() -> Path:
    root = Path(os.environ.get("INCEPTIONGS_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    return root / "splats" / "donut.ply"


class _PublishingJob:
    """Stands in for the trainer: jitters the model and publishes it ~5 times a second, with
    numpy work in between so the job thread really competes for the CPU."""

    def __init__(self, arrays: dict):
        self.arrays = arrays

    def run(self, box, control):
        rng = np.random.default_rng(0)
        step = 0
        while not control.stop.is_set():
            step += 1
            arrays = dict(self.arrays)
            arrays["means"] = self.arrays["means"] + rng.normal(0, 1e-3, self.arrays["means"].shape).astype(np.float32)
            box.publish(step, arrays, {"loss": 1.0 / step})
            deadline = time.perf_counter() + 0.2
            while time.perf_counter() < deadline and not control.stop.is_set():
                np.linalg.svd(rng.normal(size=(120, 120)))  # busy work like an optimiser step


def _measure(viewer, frames: int, before_frame) -> dict:
    totals, sorts, draws, scales = [], [], [], []
    renders_before = viewer.stats.splat_renders
    began = time.perf_counter()
    for i in range(frames):
        before_frame(i)
        start = time.perf_counter()
        viewer.step()
        totals.append(time.perf_counter() - start)
        sorts.append(viewer.stats.sort_ms)
        draws.append(viewer.stats.draw_ms)
        scales.append(viewer.stats.rendered_scale)
    elapsed = time.perf_counter() - began
    mean = statistics.mean(totals)
    return {"fps": 1.0 / mean, "frame_ms": 1e3 * mean, "p90_ms": 1e3 * sorted(totals)[int(0.9 * len(totals))],
            "sort_ms": statistics.mean(sorts), "draw_ms": statistics.mean(draws),
            "renders_per_s": (viewer.stats.splat_renders - renders_before) / elapsed,
            "scale": statistics.median(scales)}


def _loop_for(viewer, seconds: float) -> tuple[float, int]:
    """Run the app's own loop (wait, then step) for ``seconds`` -> (CPU % of one core, frames)."""
    from inceptiongs.app.pacing import wait_for_next_frame

    frames = viewer.stats.frames
    cpu, wall = time.process_time(), time.perf_counter()
    while time.perf_counter() - wall < seconds:
        if wait_for_next_frame(viewer):
            viewer.step()
    return 100.0 * (time.process_time() - cpu) / (time.perf_counter() - wall), viewer.stats.frames - frames


def _job_rate(live, seconds: float, during=None) -> float:
    """it/s of a started LiveTraining over ``seconds`` after its first snapshot; ``during(seconds)``
    runs meanwhile (the viewer's loop), else this thread sleeps."""
    while live.poll() is None or live.progress.iteration == 0:
        time.sleep(0.05)
    start_iteration, start = live.progress.iteration, time.perf_counter()
    if during is None:
        time.sleep(seconds)
    else:
        during(seconds)
    live.poll()
    return (live.progress.iteration - start_iteration) / (time.perf_counter() - start)


def job_rows(seconds: float) -> list[str]:
    """The CPU rows: a real training job alone vs with the viewer idle on it; idle CPU."""
    import tempfile

    from inceptiongs.app.job_requests import train_job_for
    from inceptiongs.app.job_settings import JobSettings
    from inceptiongs.app.live_training import LiveTraining
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.scene.demo import write_demo_scene

    rows = []
    with tempfile.TemporaryDirectory() as folder:
        scene = write_demo_scene(Path(folder) / "scene", progress=False)
        source = open_source(scene)
        settings = JobSettings(minutes=None, iterations=100_000, downscale=1, protocol="none")
        alone = LiveTraining(train_job_for(source, settings))
        alone.start()
        try:
            rate_alone = _job_rate(alone, seconds)
        finally:
            alone.stop(timeout=120)
        viewer = Viewer(source, 1280, 720)
        try:
            viewer.jobs.settings = settings
            viewer.jobs.start_training()
            rate_viewer = _job_rate(viewer.jobs.training, seconds, lambda s: _loop_for(viewer, s))
            viewer.jobs.training.pause()
            time.sleep(1.0)
            paused_cpu, paused_frames = _loop_for(viewer, seconds / 2)
            viewer.jobs.training.stop(timeout=120)
            _loop_for(viewer, 2.0)  # the last snapshot's refine
            idle_cpu, idle_frames = _loop_for(viewer, seconds / 2)
            viewer.view.settings.mode = "reference"
            deadline = time.perf_counter() + 120
            while not viewer.drawing.reference_settled() and time.perf_counter() < deadline:
                viewer.step()
            reference_cpu, reference_frames = _loop_for(viewer, seconds / 2)
        finally:
            viewer.close()
    share = 100.0 * rate_viewer / rate_alone if rate_alone > 0 else float("nan")
    rows.append(f"  job it/s alone (as the CLI)     {rate_alone:6.2f}")
    rows.append(f"  job it/s, viewer idle on it     {rate_viewer:6.2f}  ({share:.0f} % of alone; target >= 85 %)")
    for name, cpu, frames in (("idle viewer", idle_cpu, idle_frames), ("paused job", paused_cpu, paused_frames),
                              ("reference mode, settled", reference_cpu, reference_frames)):
        verdict = "ok" if cpu < 5.0 else "ABOVE target 5 %"
        rows.append(f"  CPU {name:24s} {cpu:5.1f} %  ({frames} frames in {seconds / 2:.0f} s) {verdict}")
    return rows


def _resident_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _idle_row(viewer, name: str, seconds: float, settle_s: float) -> list[str]:
    """Two rows for ``name``: the app's loop idling ``seconds`` with the pointer inside the
    window (over the scene, right of the panel), then outside it, each after ``settle_s`` of the
    pointer move's frames."""
    import glfw

    width, height = glfw.get_window_size(viewer.window)
    rows = []
    for where, (x, y) in (("inside", (0.7 * width, 0.5 * height)), ("outside", (-200.0, -200.0))):
        glfw.set_cursor_pos(viewer.window, x, y)  # a pointer warp: GLFW sees the move and the enter/leave
        _loop_for(viewer, settle_s)  # the move's frames and the refine after it
        memory = _resident_mb()
        cpu, frames = _loop_for(viewer, seconds)
        growth = _resident_mb() - memory
        verdict = "ok" if cpu < 5.0 and growth < 5.0 else "ABOVE target (5 % CPU, no growth)"
        rows.append(f"  {name:22s} mouse {where:7s} CPU {cpu:5.1f} %  {frames:4d} frames in {seconds:g} s  "
                    f"memory {growth:+6.1f} MB  {verdict}")
    return rows


def _until_parked(viewer, quiet_s: float = 3.0) -> None:
    """Run the loop until the paused job has finished the step it was in (its iteration and
    its model unchanged for ``quiet_s``): the pause is honoured between steps."""
    run, deadline = viewer.jobs.training, time.perf_counter() + 300
    last, since = None, time.perf_counter()
    while time.perf_counter() < deadline:
        _loop_for(viewer, 0.5)
        now = (run.progress.iteration, viewer.view.model_version)
        if now != last:
            last, since = now, time.perf_counter()
        elif time.perf_counter() - since >= quiet_s:
            return


def idle_rows(seconds: float, size: tuple[int, int], settle_s: float = 2.0) -> list[str]:
    """The idle rows: nothing happening, a paused job, a stopped job (docstring above); each
    measurement starts ``settle_s`` after the pointer moved (the paused job's parking waits as long)."""
    import tempfile

    from inceptiongs.app.job_settings import JobSettings
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.scene.demo import write_demo_scene

    with tempfile.TemporaryDirectory() as folder:
        scene = write_demo_scene(Path(folder) / "scene", progress=False)
        viewer = Viewer(open_source(scene), *size)
        try:
            rows = _idle_row(viewer, "idle, no job", seconds, settle_s)
            viewer.jobs.settings = JobSettings(minutes=None, iterations=100_000, downscale=2, protocol="none")
            viewer.jobs.start_training()
            deadline = time.perf_counter() + 300
            while viewer.jobs.training.progress.iteration < 5 and time.perf_counter() < deadline:
                _loop_for(viewer, 0.5)
            viewer.jobs.training.pause()
            _until_parked(viewer, quiet_s=1.5 * settle_s)
            rows += _idle_row(viewer, "job paused", seconds, settle_s)
            viewer.jobs.training.stop(timeout=120)
            rows += _idle_row(viewer, "job stopped", seconds, settle_s)
        finally:
            viewer.close()
    return rows


def _settle(viewer, timeout: float = 120.0, steps: list | None = None) -> float:
    """Run the app's loop until the settled frame of a still camera is drawn -> seconds it took
    (from now, taken as the last movement); ``steps`` collects each loop turn's seconds (how long
    input would wait)."""
    from inceptiongs.app.pacing import wait_for_next_frame

    began = time.perf_counter()
    while time.perf_counter() - began < timeout:
        turn = time.perf_counter()
        if wait_for_next_frame(viewer):
            viewer.step()
        if steps is not None:
            steps.append(time.perf_counter() - turn)
        drawing = viewer.drawing
        settled = "settled" in drawing.drawn[2] or drawing.drawn[2] == "full detail"
        if settled and drawing.last_render_key is not None and drawing.last_render_key[2] == 1.0:
            return time.perf_counter() - began
    return float("nan")


def _upsampled(image: np.ndarray, width: int, height: int) -> np.ndarray:
    import cv2

    return cv2.resize(image, (width, height), interpolation=cv2.INTER_LINEAR)


def model_rows(path: Path, size: tuple[int, int], frames: int) -> dict:
    """The large-model figures (module docstring of the issue's benchmark): load_s, moving_ms,
    settle_s, full_ms, peak_rss_mb, moving_psnr, and how the level of detail drew them."""
    import resource

    from inceptiongs.app import viewer as viewer_module
    from inceptiongs.app.drawing import STILL_SECONDS
    from inceptiongs.app.sources import open_source
    from inceptiongs.evaluation.metrics import psnr

    from inceptiongs.app.warmup import start_warmup

    began = time.perf_counter()
    start_warmup()   # as inceptiongs-viewer does before reading the model
    viewer = viewer_module.Viewer(open_source(path), *size)
    out = {"model": str(path), "size": f"{size[0]}x{size[1]}", "gaussians": viewer.view.edit.count}
    try:
        out["window_s"] = time.perf_counter() - began  # the PLY read and the window open
        turns: list[float] = []
        _settle(viewer, timeout=600.0, steps=turns)
        out["load_s"] = time.perf_counter() - began
        # The longest loop turn while the tree loaded or built, between the first frame (numba's
        # start, the preview) and the settled frame's own render: how long a click could wait.
        out["first_frame_ms"] = 1e3 * turns[0] if turns else None
        out["load_longest_turn_ms"] = 1e3 * max(turns[1:-1], default=0.0)
        detail = viewer.drawing.detail
        out["tree_from_cache"] = None if detail is None else detail.from_cache
        out["tree_s"] = None if detail is None else detail.build_seconds
        times, drawn = [], []
        for _ in range(frames):
            viewer.view.nav.orbit(12.0, 0.0)   # 3.4 degrees a frame around the pivot
            viewer.view.moved()
            start = time.perf_counter()
            viewer.step()
            times.append(time.perf_counter() - start)
            drawn.append(viewer.drawing.drawn[0])
        out["moving_ms"] = 1e3 * statistics.median(times)
        out["moving_p90_ms"] = 1e3 * sorted(times)[int(0.9 * len(times))]
        out["moving_drawn"] = int(statistics.median(drawn))
        out["budget"] = viewer.drawing.detail_budget
        scale = viewer.drawing.last_render_key[2]
        moving = viewer.renderer.render(viewer.view.current_camera(scale), "rgb")
        time.sleep(STILL_SECONDS)
        out["settle_s"] = _settle(viewer) + STILL_SECONDS
        out["settled_drawn"] = viewer.drawing.drawn[0]
        settled = viewer.renderer.render(viewer.view.current_camera(), "rgb")
        out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
        viewer.view.settings.full_detail = True
        viewer.view.moved()
        time.sleep(STILL_SECONDS)
        start = time.perf_counter()
        _settle(viewer)
        out["full_ms"] = 1e3 * (time.perf_counter() - start)
        full = viewer.renderer.render(viewer.view.current_camera(), "rgb").astype(np.float64)
        width, height = full.shape[1], full.shape[0]
        out["moving_scale"] = scale
        out["moving_psnr"] = float(psnr(_upsampled(moving, width, height).astype(np.float64), full))
        out["settled_psnr"] = float(psnr(settled.astype(np.float64), full))
        out["peak_rss_full_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
    finally:
        viewer.close()
    out["load_average"] = os.getloadavg()[0]
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ply", type=Path, default=_default_ply())
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--jobs", action="store_true", help="also the job-throughput and idle-CPU rows")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each --jobs measurement")
    parser.add_argument("--idle", action="store_true", help="also the idle CPU and memory rows")
    parser.add_argument("--idle-seconds", type=float, default=60.0, help="length of each --idle measurement")
    parser.add_argument("--settle-seconds", type=float, default=2.0,
                        help="--idle: the loop runs this long after each pointer move before measuring")
    parser.add_argument("--model", type=Path, help="a large model: the level-of-detail figures only")
    parser.add_argument("--json", type=Path, help="with --model: also write the figures here")
    parser.add_argument("--fresh-tree", action="store_true",
                        help="with --model: build the LOD tree as the first opening does (a new cache folder)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    if args.model is not None:
        if args.fresh_tree:
            import tempfile

            os.environ["INCEPTIONGS_CACHE_DIR"] = tempfile.mkdtemp(prefix="bench-viewer-cache-")
        figures = model_rows(args.model, (width, height), args.frames)
        print(json.dumps(figures, indent=1))
        if args.json is not None:
            args.json.write_text(json.dumps(figures, indent=1) + "\n")
        return 0
    if args.idle:
        print(f"idle rows at {width}x{height}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
        print("\n".join(idle_rows(args.idle_seconds, (width, height), args.settle_seconds)), flush=True)
    if args.jobs:
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores "
              "(figures are noisy on a shared machine)")
        print("\n".join(job_rows(args.seconds)))
    if not args.ply.is_file():
        print(f"benchmark skipped: {args.ply} not found", file=sys.stderr)
        return 0
    from inceptiongs.app import viewer as viewer_module
    from inceptiongs.app.drawing import STILL_SECONDS
    from inceptiongs.app.sources import open_source

    source = open_source(args.ply)
    job = _PublishingJob(source.gaussians)
    viewer = viewer_module.Viewer(source, width, height, job_factory=lambda s: job)
    results = {}
    try:
        viewer.step()

        def force_full_render(_):
            viewer.drawing.last_render_key = None  # re-render although nothing changed
        results["idle"] = _measure(viewer, args.frames, force_full_render)
        results["idle, cached"] = _measure(viewer, args.frames, lambda _: None)

        def turn(_):
            viewer.view.nav.look(4.0, 0.0)
            viewer.view.moved()
        results["moving"] = _measure(viewer, args.frames, turn)
        time.sleep(STILL_SECONDS)
        viewer.jobs.start_training()
        time.sleep(0.3)
        results["training"] = _measure(viewer, args.frames, lambda _: None)
    finally:
        viewer.close()
    targets = {"idle": 10.0, "moving": 20.0, "training": 5.0}
    print(f"{args.ply.name} at {width}x{height}, {viewer.view.edit.count} Gaussians, {args.frames} frames each; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (figures are noisy on a shared machine)")
    for name, r in results.items():
        target = targets.get(name)
        verdict = "" if target is None else (" ok" if r["fps"] >= target else f" BELOW target {target:g}")
        print(f"  {name:13s} {r['fps']:6.1f} FPS  frame {r['frame_ms']:7.1f} ms (p90 {r['p90_ms']:7.1f})  "
              f"sort {r['sort_ms']:6.1f} ms  draw {r['draw_ms']:6.1f} ms  renders/s {r['renders_per_s']:5.1f}  "
              f"scale {r['scale']:.3f}{verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
