"""The level of detail on an offscreen EGL context: what the window's cuts cost to draw on a GPU.

For each size (donut.ply tiled on a grid, as benchmarks/tile_model.py does; written as a PLY and
read back, so the read is the one a user's model gets), with a fresh cache folder:
  ply_read_s      the PLY read
  tree_s          the LOD tree built (first opening); tree_cached_s: loaded from the cache
  moving_ms       median render of a budgeted cut along an orbit (3.4 degrees a frame, the view
                  the window opens with), the budget adapted towards the window's 25 ms target
                  by app.detail.next_budget; the cut is chosen and uploaded for every frame
                  (cut_ms, upload_ms apart: the window does that on its worker, at most every 0.2 s),
                  blended towards the parents as the window's moving cuts are
  settled_*       the 1-pixel cut: cut, pack + upload seconds, its render ms and PSNR
  full_ms         every Gaussian's render; moving_psnr: the last moving frame against it
  passes_ms       the last moving, settled and full render split into preprocess, sort, draw
Renders are the renderer's own timings (preprocess + sort + draw, each pass finished), drawn
into a framebuffer the window's size with the compositing `auto` picks. It measures the
renderer and the cuts, not the window's loop (GLFW, the panel, the swap). On a data-centre GPU
its few graphics units make the draw times no guide to a desktop card's.

    python benchmarks/bench_lod_gl.py [--copies 110 440] [--size 1280x720] [--frames 20] [--json OUT]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch

from inceptiongs.app.detail import BUDGET_START, SETTLED_GRANULARITY_PX, next_budget, pack_nodes
from inceptiongs.app.navigation import default_view, model_up
from inceptiongs.evaluation.metrics import psnr
from inceptiongs.gaussians import Gaussians
from inceptiongs.io.atomic import atomic_write_text
from inceptiongs.io.ply import read_ply, write_ply
from inceptiongs.lod.blend import blend_weights
from inceptiongs.lod.cache import load_or_build
from inceptiongs.lod.cut import cut_nodes, greedy_budget_cut_nodes
from inceptiongs.renderer.context import create_offscreen_context
from inceptiongs.renderer.splats import SplatRenderer
from tile_model import default_ply, tiled_arrays


def timed(fn):
    start = time.perf_counter()
    value = fn()
    return value, time.perf_counter() - start


def draw_ms(renderer: SplatRenderer, camera, framebuffer, repeats: int = 1, passes: dict | None = None) -> float:
    """Median of ``repeats`` renders' own timings (each pass ends with a finish); ``passes`` gets
    the last render's preprocess, sort and draw ms."""
    times = []
    for _ in range(repeats):
        renderer.draw(camera, "rgb", framebuffer)
        times.append(sum(renderer.timings.values()))
    if passes is not None:
        passes.update(renderer.timings)
    return statistics.median(times)


def measure_size(donut: dict, copies: int, size: tuple[int, int], frames: int, ctx, folder: Path) -> dict:
    ply = folder / f"tiled_{copies}.ply"
    arrays = tiled_arrays(donut, copies)
    write_ply(Gaussians(**{name: torch.from_numpy(np.ascontiguousarray(v)) for name, v in arrays.items()}), ply)
    del arrays
    model, read_s = timed(lambda: read_ply(ply))
    os.environ["INCEPTIONGS_CACHE_DIR"] = str(folder / f"cache_{copies}")
    (tree, _), tree_s = timed(lambda: load_or_build(model))
    (tree, cached), cached_s = timed(lambda: load_or_build(model))
    assert cached, "the second load_or_build did not read the cache"
    means = model.means.numpy()
    nav = default_view(means, *size, up=model_up(means))
    out = {"copies": copies, "gaussians": len(model), "ply_mb": ply.stat().st_size / 1e6, "ply_read_s": read_s,
           "tree_s": tree_s, "tree_cached_s": cached_s, "nodes": len(tree)}
    renderer = SplatRenderer(ctx)
    out.update(sort=renderer.sort, compositing=renderer.compositing)
    framebuffer = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 4)])
    try:
        budget, moving, cuts, uploads, drawn = BUDGET_START, [], [], [], []
        passes = {"moving": {}, "settled": {}, "full": {}}
        # One frame first: the shaders' compiles (and numba's, on a CPU) are not a frame's cost.
        renderer.set_packed(*pack_nodes(tree, greedy_budget_cut_nodes(tree, nav.camera(*size), budget)))
        draw_ms(renderer, nav.camera(*size), framebuffer)
        for _ in range(frames):
            nav.orbit(12.0, 0.0)
            camera = nav.camera(*size)
            nodes, cut_s = timed(lambda: greedy_budget_cut_nodes(tree, camera, budget))
            # Blended towards their parents, as the window's moving cuts are.
            weights = blend_weights(tree, camera, nodes)
            _, upload_s = timed(lambda: renderer.set_packed(*pack_nodes(tree, nodes, weights=weights)))
            render_ms = draw_ms(renderer, camera, framebuffer, passes=passes["moving"])
            moving.append(render_ms), cuts.append(1e3 * cut_s), uploads.append(1e3 * upload_s)
            drawn.append(len(nodes))
            budget = next_budget(len(nodes), render_ms)
        moving_image = renderer.render(camera, "rgb")
        out.update(moving_ms=statistics.median(moving), moving_p90_ms=sorted(moving)[int(0.9 * len(moving))],
                   moving_drawn=int(statistics.median(drawn)), moving_cut_ms=statistics.median(cuts),
                   moving_upload_ms=statistics.median(uploads), budget_end=budget)
        nodes, cut_s = timed(lambda: cut_nodes(tree, camera, SETTLED_GRANULARITY_PX))
        _, upload_s = timed(lambda: renderer.set_packed(*pack_nodes(tree, nodes)))
        out.update(settled_drawn=len(nodes), settled_cut_s=cut_s, settled_upload_s=upload_s,
                   settled_ms=draw_ms(renderer, camera, framebuffer, 3, passes["settled"]))
        settled_image = renderer.render(camera, "rgb")
        _, full_upload_s = timed(lambda: renderer.set_gaussians(model.numpy()))
        out.update(full_upload_s=full_upload_s, full_ms=draw_ms(renderer, camera, framebuffer, 3, passes["full"]))
        full = renderer.render(camera, "rgb").astype(np.float64)
        out.update(moving_psnr=float(psnr(moving_image.astype(np.float64), full)),
                   settled_psnr=float(psnr(settled_image.astype(np.float64), full)), passes_ms=passes)
    finally:
        framebuffer.release()
        renderer.release()
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ply", type=Path, default=default_ply(), help="the model tiled (default donut.ply)")
    parser.add_argument("--copies", type=int, nargs="+", default=[110, 440], help="5.0M and 20.1M Gaussians")
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if not args.ply.is_file():
        print(f"benchmark skipped: {args.ply} not found", file=sys.stderr)
        return 0
    size = tuple(int(v) for v in args.size.split("x"))
    ctx = create_offscreen_context()
    result = {"date": datetime.date.today().isoformat(), "command": " ".join(["python"] + sys.argv),
              "gl_renderer": ctx.info["GL_RENDERER"], "gl_version": ctx.version_code,
              "python": platform.python_version(), "cpus": os.cpu_count(), "size": args.size, "rows": []}
    print(f"{result['gl_renderer']} (GL {ctx.version_code}), {os.cpu_count()} CPUs, {args.size}", flush=True)
    donut = read_ply(args.ply).numpy()
    with tempfile.TemporaryDirectory(prefix="bench-lod-gl-") as folder:
        for copies in args.copies:
            row = measure_size(donut, copies, size, args.frames, ctx, Path(folder))
            result["rows"].append(row)
            print(json.dumps(row), flush=True)
            for path in Path(folder).iterdir():   # the next size's disk
                if path.is_file():
                    path.unlink()
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
