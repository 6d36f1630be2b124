"""GL splat renderer figures on EGL: preprocess / sort / draw / frame ms, CPU ms, peak memory,
and GL-vs-torch PSNR (at a smaller size, where the torch reference is affordable).

    python benchmarks/bench_gl.py [--sizes 10000,100000,1000000] [--frames 5] [--no-torch]
        [--paths cpu,fetch,fetch-gpu]

Paths: "cpu" = compositing on the CPU cores (the default on software GL), "fetch" = one quad
per Gaussian composited front to back in the fragment shader (framebuffer fetch) with the
numpy sort, "fetch-gpu" = the same with the compute-shader bitonic sort, "blend" = back-to-
front blending (what draw() does on the quad paths).

Scenes: N random Gaussians in a unit cube in front of the camera (scales shrinking with
N^(-1/3) so density stays scene-like; SH degree 3) and ../shared/data/splats/donut.ply with
the camera fitted so the donut spans ~80% of the image height. Wall-clock figures depend on
the machine's load; "cpu ms" (this process, all threads: llvmpipe renders on its own
threads) is the steadier measure of work on a shared machine.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.renderer.context import create_offscreen_context
from inceptiongs.renderer.crosscheck import agreement
from inceptiongs.renderer.splats import SplatRenderer

WIDTH, HEIGHT = 1280, 720
CHECK_WIDTH, CHECK_HEIGHT = 320, 180
REPO = Path(__file__).resolve().parents[1]


def random_cube(n: int, seed: int = 0) -> Gaussians:
    """n Gaussians in [-0.5, 0.5]^3 centred 2 units in front of an identity camera."""
    gen = torch.Generator().manual_seed(seed)
    typical = 0.5 * n ** (-1.0 / 3.0)  # about half the mean spacing
    return Gaussians(
        means=torch.rand(n, 3, generator=gen) - 0.5 + torch.tensor([0.0, 0.0, 2.0]),
        log_scales=torch.log(torch.tensor(typical)) + torch.randn(n, 3, generator=gen) * 0.5,
        quats=torch.randn(n, 4, generator=gen),
        opacity_logits=torch.randn(n, generator=gen),
        sh=torch.randn(n, 16, 3, generator=gen) * 0.3,
    )


def cube_camera(width: int, height: int) -> Camera:
    focal = 0.9 * width
    return Camera("cube", width, height, focal, focal, width / 2, height / 2, np.eye(4))


def donut_camera(means: np.ndarray, width: int, height: int) -> Camera:
    lo, hi = means.min(0), means.max(0)
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    focal = 0.8 * width
    distance = focal * radius / (0.4 * height)
    a, e = np.radians(30.0), np.radians(50.0)
    eye = centre + distance * np.array([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.sin(e)])
    return Camera("donut", width, height, focal, focal, width / 2, height / 2,
                  look_at(eye, centre, up=(0.0, 0.0, 1.0)))


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


PATHS = {"cpu": ("cpu", "cpu"), "fetch": ("cpu", "fetch"), "fetch-gpu": ("gpu", "fetch"),
         "blend": ("cpu", "blend")}


def time_frames(renderer: SplatRenderer, cam: Camera, frames: int) -> dict:
    renderer.render(cam)  # warm-up: shader compilation (numba: first call), buffer growth
    rows = []
    for _ in range(frames):
        wall, cpu = time.perf_counter(), time.process_time()
        renderer.render(cam)
        rows.append({**renderer.timings, "frame_ms": 1e3 * (time.perf_counter() - wall),
                     "cpu_ms": 1e3 * (time.process_time() - cpu)})
    return {key: statistics.median(r[key] for r in rows) for key in rows[0]}


def torch_psnr(renderer: SplatRenderer, model: Gaussians, cam: Camera) -> dict:
    from inceptiongs.rasterizer.interface import cpu_rasterizer
    with torch.no_grad():
        ref = cpu_rasterizer()(model, cam, outputs=("rgb", "alpha"))
    return agreement(renderer.render(cam, "rgb"), renderer.render(cam, "alpha"),
                     ref["rgb"].numpy(), ref["alpha"].numpy())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10000,100000,1000000")
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--no-torch", action="store_true", help="skip the GL-vs-torch PSNR column")
    parser.add_argument("--paths", default="cpu", help=f"comma-separated, of {', '.join(PATHS)}")
    parser.add_argument("--donut", default=str(REPO.parent / "shared" / "data" / "splats" / "donut.ply"))
    args = parser.parse_args(argv)
    torch.set_num_threads(2)

    ctx = create_offscreen_context()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}; GL: {ctx.info['GL_RENDERER']} {ctx.version_code}")
    scenes = [(f"random {int(n):,}", random_cube(int(n)), cube_camera) for n in args.sizes.split(",")]
    if Path(args.donut).is_file():
        from inceptiongs.io.ply import read_ply
        donut = read_ply(args.donut)
        means = donut.means.numpy()
        scenes.append(("donut.ply (45,624)", donut, lambda w, h, m=means: donut_camera(m, w, h)))
    else:
        print(f"donut.ply not found at {args.donut}: skipped", file=sys.stderr)

    header = (f"{'scene':<20} {'path':<9} {'prep ms':>8} {'sort ms':>8} {'draw ms':>8} {'frame ms':>9} "
              f"{'cpu ms':>8} {'peak MB':>8} {'PSNR dB':>8} {'alpha ok':>9}")
    print(f"{WIDTH}x{HEIGHT}, median of {args.frames} frames; PSNR/alpha vs torch at {CHECK_WIDTH}x{CHECK_HEIGHT}")
    print(header)
    for name, model, make_camera in scenes:
        for path in args.paths.split(","):
            sort, compositing = PATHS[path]
            if sort == "gpu" and ctx.version_code < 430:
                continue
            if compositing == "fetch" and "GL_EXT_shader_framebuffer_fetch" not in ctx.extensions:
                continue
            renderer = SplatRenderer(ctx, sort=sort, compositing=compositing)
            renderer.set_gaussians(model.numpy())
            t = time_frames(renderer, make_camera(WIDTH, HEIGHT), args.frames)
            check = "" if args.no_torch or sort == "gpu" else torch_psnr(
                renderer, model, make_camera(CHECK_WIDTH, CHECK_HEIGHT))
            psnr_text = f"{check['psnr']:8.1f} {check['alpha_within']:9.4f}" if check else f"{'':>8} {'':>9}"
            print(f"{name:<20} {path:<9} {t['preprocess_ms']:8.1f} {t['sort_ms']:8.1f} {t['draw_ms']:8.1f} "
                  f"{t['frame_ms']:9.1f} {t['cpu_ms']:8.1f} {peak_rss_mb():8.0f} {psnr_text}", flush=True)
            renderer.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
