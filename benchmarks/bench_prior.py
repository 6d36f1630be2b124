"""Prior timings: one 250x165 image by MultiDiffusion + DDIM (target: < 20 s with 20 steps on
2 CPU cores) and one training step on 64x64 patches, with the default tiny-backend config.

Timings do not depend on the weights, so an untrained prior is used; the Gaussians are a
synthetic blob (--gaussians N) or a finished run's model (--run RUN).

    python benchmarks/bench_prior.py [--steps 20] [--gaussians 20000] [--run RUN] [--device cpu]

--device auto|cpu|cuda follows the commands' one device rule (cuda: gsplat and torch on the GPU).

Quality targets (--quality RUN, a stage-I run of statuette at downscale 4, unstructured
protocol): trains the prior for --minutes (default 15) with an evaluation every
--eval-every minutes, scores generated images on the held-out views with 20 and 5 DDIM
steps (`inceptiongs eval --generated`), writes RUN_prior-report figure, and checks: scarce
mean SSIM generated >= render; covered PSNR generated >= render - 2 dB; 20 DDIM steps per
image < 20 s.

    python benchmarks/bench_prior.py --quality RUN [--minutes 15] [--eval-every 5] [--prediction v]

The appearance hint alone (--hint RUN): the hash grid + hint head trained on their L1 loss for
--minutes (default 2) with the grid's finest resolution and level count from --grid-max-res /
--grid-levels (0 levels: the uncontracted box around 99 % of the Gaussians, 4 levels to
128), scored on the held-out views next to the render (the docs' table of grid sizes).

    python benchmarks/bench_prior.py --hint RUN [--minutes 2] [--grid-max-res 256 --grid-levels 6]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.prior.model import Prior, PriorConfig
from inceptiongs.prior.trainer import PriorTrainer
from inceptiongs.rasterizer.interface import resolve_device


def synthetic_scene(n: int, width: int = 250, height: int = 165):
    g = torch.Generator().manual_seed(0)
    gaussians = Gaussians((torch.rand(n, 3, generator=g) * 2 - 1) * 0.7,
                          torch.full((n, 3), -3.5) + torch.rand(n, 3, generator=g),
                          torch.randn(n, 4, generator=g), torch.full((n,), 1.0),
                          torch.rand(n, 1, 3, generator=g))
    cameras = [Camera(f"c{i}", width, height, 220.0, 220.0, width / 2, height / 2,
                      look_at(np.array([3 * np.sin(a), 0.2, -3 * np.cos(a)]), np.zeros(3)))
               for i, a in enumerate(np.linspace(0, 1.5, 4))]
    photos = [np.full((height, width, 3), 0.5, np.float32) for _ in cameras]
    return gaussians, cameras, photos


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--gaussians", type=int, default=20000)
    parser.add_argument("--run", default=None, help="use this run's Gaussians and cameras")
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                        help="the one device rule of the commands (inceptiongs.rasterizer.interface.resolve_device)")
    parser.add_argument("--train-steps", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    parser.add_argument("--quality", metavar="RUN", default=None, help="run the quality-target benchmark on RUN")
    parser.add_argument("--minutes", type=float, default=None,
                        help="training time: of the prior for --quality (default 15), of the hint for --hint (default 2)")
    parser.add_argument("--prediction", choices=("epsilon", "v"), default="epsilon",
                        help="what the tiny UNet predicts, for --quality")
    parser.add_argument("--eval-every", type=float, default=5.0, help="minutes between evaluations for --quality")
    parser.add_argument("--hint", metavar="RUN", default=None, help="train and score the appearance hint alone on RUN")
    parser.add_argument("--grid-max-res", type=int, default=256, help="finest hash grid level for --hint")
    parser.add_argument("--grid-levels", type=int, default=6, help="hash grid levels for --hint (0: uncontracted box)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.hint:
        hint_only(args.hint, 2.0 if args.minutes is None else args.minutes, args.grid_levels, args.grid_max_res)
        return
    if args.quality:
        quality(args.quality, 15.0 if args.minutes is None else args.minutes, args.eval_every, args.prediction)
        return

    if args.run:
        from inceptiongs.runs.load import load_run
        gaussians, scene, _ = load_run(args.run)
        cameras, photos = scene.cameras, None
        load_image = scene.load_image
    else:
        gaussians, cameras, photos = synthetic_scene(args.gaussians)
        load_image = photos.__getitem__
    device = resolve_device(args.device).torch_device
    gaussians = gaussians.to(device)
    prior = Prior.for_gaussians(PriorConfig(), gaussians).to(device)
    camera = cameras[0]
    print(f"device {device}, torch threads {torch.get_num_threads()}, {len(gaussians)} Gaussians, "
          f"image {camera.width}x{camera.height}, window {prior.config.patch_size}")

    # Wall time and this process's CPU time: on a shared machine the wall time includes waiting
    # for other jobs; with --threads 1 the CPU time is what an idle core would take.
    wall, cpu = time.perf_counter(), time.process_time()
    prior.gbuffer(gaussians, camera)
    print(f"G-buffer (full image): wall {time.perf_counter() - wall:.2f} s, cpu {time.process_time() - cpu:.2f} s")
    prior.generate(gaussians, camera, steps=1, seed=0)  # warm-up (JIT, allocator)
    wall, cpu = time.perf_counter(), time.process_time()
    prior.generate(gaussians, camera, steps=args.steps, seed=0)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    print(f"generate {camera.width}x{camera.height}, {args.steps} DDIM steps: wall {wall:.2f} s, cpu {cpu:.2f} s "
          f"(target < 20 s)")

    trainer = PriorTrainer(prior, gaussians, cameras, load_image)
    trainer.step()  # warm-up
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(args.train_steps):
        trainer.step()
    wall = (time.perf_counter() - wall) / args.train_steps
    cpu = (time.process_time() - cpu) / args.train_steps
    print(f"training step (batch {prior.config.batch_size} x {trainer.patch_size}^2 patches, G-buffers "
          f"rendered on the fly): wall {wall:.2f} s, cpu {cpu:.2f} s -> {60 / wall:.0f} steps/min (wall)")


def quality(run: str, minutes: float, eval_every: float, prediction: str = "epsilon") -> None:
    """The prior's quality targets (module docstring) through the same commands a user runs."""
    import json
    from pathlib import Path

    from inceptiongs.cli import main as cli

    assert cli(["prior", run, "--minutes", f"{minutes:g}", "--restart", "--eval-every-minutes", f"{eval_every:g}",
                "--eval-views", "1", "--eval-steps", "10", "--prediction", prediction]) == 0
    assert cli(["eval", run, "--generated", "--ddim-steps", "20,5"]) == 0
    assert cli(["report", run, "--prior", "--out", str(Path(run).with_name(Path(run).name + "_prior-report.png"))]) == 0
    summary = json.loads((Path(run) / "eval" / "generated.json").read_text())
    at20 = next(e for e in summary["by_steps"] if e["ddim_steps"] == 20)
    scarce, covered = at20["groups"]["scarce"], at20["groups"]["covered"]
    checks = {
        "scarce SSIM generated >= render": (scarce["generated"]["ssim"], scarce["render"]["ssim"],
                                            scarce["generated"]["ssim"] >= scarce["render"]["ssim"]),
        "covered PSNR generated >= render - 2 dB": (covered["generated"]["psnr"], covered["render"]["psnr"],
                                                    covered["generated"]["psnr"] >= covered["render"]["psnr"] - 2.0),
    }
    for name, (generated, render, ok) in checks.items():
        print(f"{name}: generated {generated:.4f}, render {render:.4f} -> {'met' if ok else 'NOT met'}")
    seconds = at20["seconds_per_image"]
    print(f"20 DDIM steps: {seconds:.1f} s per image (wall, this machine's load) -> "
          f"{'met' if seconds < 20 else 'NOT met'} (target < 20 s)")


def hint_only(run: str, minutes: float, levels: int, max_resolution: int) -> None:
    """Train the hash grid + appearance head alone (L1 against photo patches) and score the hint."""
    from dataclasses import replace
    from pathlib import Path

    from inceptiongs.evaluation.scoring import group_of
    from inceptiongs.rasterizer.interface import render_rgb
    from inceptiongs.evaluation.generated import held_out, photo_of, score
    from inceptiongs.prior.hashgrid import HashGridConfig
    from inceptiongs.prior.joint import training_views
    from inceptiongs.prior.trainer import adam_for
    from inceptiongs.runs.load import load_run

    gaussians, scene, _ = load_run(run)
    views = training_views(run, scene)
    grid = HashGridConfig() if levels == 0 else replace(PriorConfig().grid, levels=levels, max_resolution=max_resolution)
    config = replace(PriorConfig(), grid=grid)
    prior = Prior.for_gaussians(config, gaussians)
    trainer = PriorTrainer(prior, gaussians, [scene.cameras[i] for i in views], lambda k: scene.load_image(views[k]))
    # The prior's own groups for the hint head and the hash grid (the denoiser is not trained here).
    denoiser = {id(parameter) for parameter in prior.denoiser.parameters()}
    optimizer = adam_for([g for g in prior.parameter_groups() if id(g["params"][0]) not in denoiser])
    for _ in range(4 * len(views)):  # render every view's geometry before the clock starts
        trainer.sample_batch()
    start, steps = time.perf_counter(), 0
    while time.perf_counter() - start < 60.0 * minutes:
        photos, conds = trainer.sample_batch()
        loss = (prior.hint(conds) - photos).abs().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        steps += 1
    print(f"grid {prior.config.grid}: {steps} steps in {minutes:g} min, last L1 {float(loss.detach()):.4f}")
    split, indices = held_out(Path(run), scene)
    scores = {}
    for index in indices:
        camera, photo, group = scene.cameras[index], photo_of(scene, index), group_of(index, split)
        with torch.no_grad():
            hint = (prior.hint(prior.gbuffer(gaussians, camera)[None])[0].permute(1, 2, 0) + 1.0) * 0.5
        scores.setdefault((group, "render"), []).append(score(render_rgb(gaussians, camera).cpu(), photo))
        scores.setdefault((group, "hint"), []).append(score(hint.clamp(0.0, 1.0).cpu(), photo))
    for (group, source), values in sorted(scores.items()):
        print(f"{group:8s} {source:7s} PSNR {np.mean([v['psnr'] for v in values]):6.2f} "
              f"SSIM {np.mean([v['ssim'] for v in values]):.4f} ({len(values)} views)")


if __name__ == "__main__":
    main()
