"""Generated images against photos: is the prior a better guess than the stage-I render?

For every held-out view of a run (RUN/split.json), the prior (RUN/prior/prior.pt) generates
an image from the G-buffer of the run's Gaussians; it is scored against the photo (PSNR,
SSIM) next to the stage-I render's scores, per group (scarce cluster / covered views), for
one or several DDIM step counts. Images: RUN/eval/generated/<group>_<index>_<name>.png as
render | generated | photo; scores: RUN/eval/generated.json (read by `inceptiongs report`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..io.atomic import atomic_write_text
from ..errors import InputError
from ..io.images import write_png
from ..scene.photo_store import photo_tensor
from ..io.config_json import json_safe
from ..rasterizer.interface import render_rgb
from .scoring import GROUPS, group_of, mean_or_none, safe_name
from .metrics import psnr, ssim
from .protocols import Split

GENERATED_JSON = "generated.json"
SOURCES = ("render", "generated")


def score(image: torch.Tensor, photo: torch.Tensor) -> dict[str, float]:
    """{"psnr", "ssim"} of image against photo, both [H, W, 3] in [0, 1]."""
    return {"psnr": float(psnr(image, photo)), "ssim": float(ssim(image, photo))}


def photo_of(scene, index: int) -> torch.Tensor:
    camera = scene.cameras[index]
    photo = photo_tensor(scene, index)   # decoded once into the photo cache
    if tuple(photo.shape) != (camera.height, camera.width, 3):
        raise InputError(f"{camera.name}: photo is {tuple(photo.shape)}, camera expects "
                         f"{(camera.height, camera.width, 3)}")
    return photo


def group_means(views: list[dict], source: str) -> dict[str, dict]:
    """{group: {"views": n, "psnr": mean | None, "ssim": mean | None}} of views[i][source]."""
    out = {}
    for group in (*GROUPS, "all"):
        members = [v[source] for v in views if group == "all" or v["group"] == group]
        out[group] = {"views": len(members), "psnr": mean_or_none([m["psnr"] for m in members]),
                      "ssim": mean_or_none([m["ssim"] for m in members])}
    return out


def score_views(prior, gaussians, scene, indices: list[int], split: Split, steps: int, seed: int = 0,
                save_dir: Path | None = None, renders: dict | None = None,
                progress: bool = False, sampling: dict | None = None) -> list[dict]:
    """Per held-out view: {"index", "name", "group", "render": scores, "generated": scores,
    "seconds" (generation wall time), "cpu_seconds" (this process's CPU time: on a shared machine
    the wall time includes waiting for other jobs)[, "image"]}. renders: {index: render} cache."""
    from tqdm import tqdm

    renders = {} if renders is None else renders
    device = prior.device
    views = []
    for index in tqdm(indices, desc=f"generate ({steps} steps)", unit="view", disable=not progress, leave=False):
        camera = scene.cameras[index]
        photo = photo_of(scene, index)
        if index not in renders:
            renders[index] = render_rgb(gaussians, camera).cpu()
        start, cpu_start = time.perf_counter(), time.process_time()
        generated, _ = prior.generate(gaussians.to(device), camera, steps=steps, seed=seed, **(sampling or {}))
        seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
        generated = generated.detach().to(torch.float32).cpu()
        view = {"index": index, "name": camera.name, "group": group_of(index, split),
                "render": score(renders[index], photo), "generated": score(generated, photo),
                "seconds": seconds, "cpu_seconds": cpu_seconds}
        if save_dir is not None:
            name = f"{view['group']}_{index:04d}_{safe_name(camera.name)}.png"
            panels = torch.cat([renders[index], generated, photo], dim=1).numpy()
            write_png(save_dir / name, (np.clip(panels, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
            view["image"] = name
        views.append(view)
    return views


def held_out(run_dir: Path, scene) -> tuple[Split, list[int]]:
    split = Split.load(Path(run_dir) / "split.json", scene.cameras)
    if not split.test:
        raise InputError(f"{Path(run_dir) / 'split.json'}: the split holds out no views (protocol "
                         f"{split.protocol!r}); nothing to evaluate")
    return split, list(split.test)


def generated_scores_fn(run_dir: str | Path, gaussians, scene, steps: int = 20, seed: int = 0,
                        max_views: int | None = None) -> Callable[[object], dict]:
    """For PriorTrainer.train(evaluate=...): prior -> {"generated": {group: {"psnr", "ssim"}},
    "render": {...}, "eval_s": seconds} over the held-out views (the first ``max_views`` of
    each group when given, to bound the cost of frequent evaluations)."""
    split, indices = held_out(Path(run_dir), scene)
    if max_views is not None:
        indices = [i for g in GROUPS for i in [j for j in indices if group_of(j, split) == g][:max_views]]
    renders: dict = {}

    def evaluate(prior) -> dict:
        start = time.perf_counter()
        views = score_views(prior, gaussians, scene, indices, split, steps, seed, renders=renders)
        strip = lambda groups: {g: {"psnr": e["psnr"], "ssim": e["ssim"]}  # noqa: E731
                                for g, e in groups.items() if e["views"]}
        return {"generated": strip(group_means(views, "generated")), "render": strip(group_means(views, "render")),
                "ddim_steps": steps, "eval_s": time.perf_counter() - start}

    return evaluate


def evaluate_generated_run(run_dir: str | Path, ddim_steps: tuple[int, ...] = (20,), seed: int = 0,
                           device=None, progress: bool = True, start: float | None = None,
                           init: str | None = None) -> dict:
    """Score the run's prior on its held-out views for every DDIM step count in ``ddim_steps``.

    Writes RUN/eval/generated/*.png (render | generated | photo, for the first step count) and
    RUN/eval/generated.json; returns the same dict: {"run", "prior": {"backend", "step",
    "train_s"}, "seed", "sampling" (the tiny prior's start and init, given or its config's), "by_steps": [{"ddim_steps", "seconds_per_image", "cpu_seconds_per_image", "groups": {group:
    {"views", "render": {"psnr", "ssim"}, "generated": {...}}}}], "views": [...first count...]}.
    """
    from ..prior.trainer import load_prior, read_prior_checkpoint, sampling_options
    from ..runs.load import load_run

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: run folder does not exist")
    if not ddim_steps or any(s < 1 for s in ddim_steps):
        raise InputError(f"DDIM steps must be >= 1, got {list(ddim_steps)}")
    payload = read_prior_checkpoint(run_dir, device)
    prior = load_prior(run_dir, device)
    sampling = sampling_options(prior, start, init, run_dir)
    gaussians, scene, _ = load_run(run_dir)
    gaussians = gaussians.to(prior.device)
    split, indices = held_out(run_dir, scene)
    save_dir = run_dir / "eval" / "generated"
    renders: dict = {}
    by_steps, first_views = [], None
    for steps in ddim_steps:
        views = score_views(prior, gaussians, scene, indices, split, steps, seed,
                            save_dir=save_dir if first_views is None else None, renders=renders,
                            progress=progress, sampling=sampling)
        render_groups, generated_groups = group_means(views, "render"), group_means(views, "generated")
        by_steps.append({
            "ddim_steps": steps,
            "seconds_per_image": float(np.mean([v["seconds"] for v in views])),
            "cpu_seconds_per_image": float(np.mean([v["cpu_seconds"] for v in views])),
            "groups": {g: {"views": render_groups[g]["views"],
                           "render": {k: render_groups[g][k] for k in ("psnr", "ssim")},
                           "generated": {k: generated_groups[g][k] for k in ("psnr", "ssim")}}
                       for g in (*GROUPS, "all")},
        })
        if first_views is None:
            first_views = views
    for view in first_views:
        if "image" in view:
            view["image"] = f"eval/generated/{view['image']}"
    summary = {"run": str(run_dir.resolve()), "protocol": split.protocol, "seed": seed,
               "prior": {"backend": payload["backend"], "step": int(payload["step"]),
                         "train_s": float(payload.get("train_s", 0.0))},
               "sampling": {"start": sampling.get("start", getattr(prior.config, "sample_start", None)),
                            "init": sampling.get("init", getattr(prior.config, "sample_init", None))},
               "by_steps": by_steps, "views": first_views}
    atomic_write_text(run_dir / "eval" / GENERATED_JSON, json.dumps(json_safe(summary), indent=1) + "\n")
    return summary


def format_generated_table(summary: dict) -> str:
    """Rows: DDIM steps x group; render and generated PSNR/SSIM side by side."""
    def cell(value, digits):
        return "-" if value is None else f"{value:.{digits}f}"

    prior = summary["prior"]
    lines = [f"prior: {prior['backend']} backend, {prior['step']} steps, {prior['train_s']:.0f} s of training",
             f"{'steps':>5}  {'views':<8}{'n':>3}{'render PSNR':>13}{'gen PSNR':>10}{'render SSIM':>13}"
             f"{'gen SSIM':>10}{'s/image':>9}{'cpu s':>7}"]
    for entry in summary["by_steps"]:
        for group in (*GROUPS, "all"):
            g = entry["groups"][group]
            lines.append(f"{entry['ddim_steps']:>5}  {group:<8}{g['views']:>3}{cell(g['render']['psnr'], 2):>13}"
                         f"{cell(g['generated']['psnr'], 2):>10}{cell(g['render']['ssim'], 4):>13}"
                         f"{cell(g['generated']['ssim'], 4):>10}{entry['seconds_per_image']:>9.1f}"
                         f"{entry.get('cpu_seconds_per_image', float('nan')):>7.1f}")
    return "\n".join(lines)
