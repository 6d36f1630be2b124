"""Scoring Gaussians on held-out views: PSNR and SSIM (LPIPS and FID when the caller gives
networks), separately for the scarce cluster and the covered views, and render | photo | error
images. Pure: it renders and compares, it knows no run folder and no training code (run-folder
evaluation is :mod:`inceptiongs.evaluation.run`).

Scores per group are means of per-view scores (the NeRF/3DGS convention: each held-out view
weighs the same whatever its content).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import torch

from ..errors import InputError
from ..io.images import write_png
from ..scene.photo_store import photo_tensor
from .metrics import frechet_distance, psnr, ssim
from .protocols import Split

GROUPS = ("scarce", "covered")
# The error panel maps |render - photo| (mean over channels) linearly onto the colour map,
# saturating at this error: typical reconstruction errors are well below 0.25, so the full
# [0, 1] range would show nearly everything black.
ERROR_IMAGE_MAX = 0.25


@dataclass
class ViewScore:
    index: int
    name: str
    group: str        # "scarce" | "covered"
    psnr: float
    ssim: float
    lpips: float | None = None
    image: str | None = None  # side-by-side PNG, relative to the run folder


def group_of(index: int, split: Split) -> str:
    return "scarce" if index in split.scarce_test else "covered"


def mean_or_none(values: list[float]) -> float | None:
    """Mean of per-view scores; None for an empty group (nothing to report, not zero)."""
    return float(np.mean(values)) if values else None


def summarise(views: list[ViewScore]) -> dict[str, dict]:
    """Per group ("scarce", "covered", "all"): {"views": n, "psnr": mean | None, "ssim": ...}."""
    out = {}
    for group in (*GROUPS, "all"):
        members = [v for v in views if group == "all" or v.group == group]
        entry = {"views": len(members), "psnr": mean_or_none([v.psnr for v in members]),
                 "ssim": mean_or_none([v.ssim for v in members])}
        if members and all(v.lpips is not None for v in members):
            entry["lpips"] = mean_or_none([v.lpips for v in members])
        out[group] = entry
    return out


def flat_scores(groups: Mapping[str, Mapping]) -> dict[str, float]:
    """{"scarce_psnr": .., "scarce_ssim": .., "covered_psnr": .., ...} for a metrics log line;
    groups with no views are left out."""
    flat = {}
    for group, entry in groups.items():
        for metric in ("psnr", "ssim", "lpips"):
            value = entry.get(metric)
            if isinstance(value, float):
                flat[f"{group}_{metric}"] = value
    return flat


def error_image(render: np.ndarray, photo: np.ndarray) -> np.ndarray:
    """|render - photo| averaged over channels, colour-mapped: [H, W, 3] float in [0, 1]."""
    from matplotlib import colormaps

    error = np.abs(render - photo).mean(axis=-1) / ERROR_IMAGE_MAX
    return colormaps["inferno"](np.clip(error, 0.0, 1.0))[..., :3].astype(np.float32)


def side_by_side(render: np.ndarray, photo: np.ndarray) -> np.ndarray:
    """render | photo | error panels: [H, W, 3] x2 in [0, 1] -> [H, 3W, 3] uint8 (RGB)."""
    panels = np.concatenate([np.clip(render, 0, 1), np.clip(photo, 0, 1), error_image(render, photo)], axis=1)
    return (panels * 255.0 + 0.5).astype(np.uint8)


def safe_name(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in Path(name).stem) or "view"


def evaluate_views(gaussians, scene, split: Split, photos: Mapping[int, torch.Tensor] | None = None,
                   background=None, save_dir: str | Path | None = None,
                   lpips_model: Callable | None = None, fid_model: Callable | None = None,
                   progress: bool = False, rasterizer=None) -> dict:
    """Render every held-out view of ``split`` with ``rasterizer`` (default: the CPU's) and
    score it against its photo.

    gaussians: Gaussians in the scene's normalised frame; scene: a Scene (cameras, load_image);
    photos: optional {view index: [H, W, 3] float tensor in [0, 1]} already in memory (the
    trainer's preloaded images), otherwise scene.load_image(index) is read; background: [3]
    (default black, as the rasterizer). save_dir: write render | photo | error PNGs there.
    lpips_model: a callable (pred, target) [1, 3, H, W] in [-1, 1] -> distance;
    fid_model: a callable [1, 3, H, W] in [0, 1] -> features [1, D].
    Returns {"groups": summarise(...), "views": [ViewScore as dict, ...]}; with lpips_model
    per-view and group "lpips", with fid_model group "fid" (groups of at least 2 views: a
    covariance needs two samples).
    """
    from ..rasterizer.interface import cpu_rasterizer  # heavy; evaluation of a run needs it, readers don't

    rasterizer = cpu_rasterizer() if rasterizer is None else rasterizer

    views: list[ViewScore] = []
    features: list[tuple[str, torch.Tensor, torch.Tensor]] = []  # (group, render, photo) for FID
    indices = list(split.test)
    iterator = indices
    if progress:
        from tqdm import tqdm
        iterator = tqdm(indices, desc="eval", unit="view", leave=False)
    save_dir = Path(save_dir) if save_dir is not None else None
    background_t = None if background is None else torch.as_tensor(background, dtype=gaussians.dtype,
                                                                    device=gaussians.device)
    for index in iterator:
        camera = scene.cameras[index]
        if photos is not None and index in photos:
            photo = photos[index]
        else:
            photo = photo_tensor(scene, index)   # decoded once into the photo cache
        photo = photo.to(device=gaussians.device, dtype=torch.float32)
        if tuple(photo.shape) != (camera.height, camera.width, 3):
            raise InputError(f"{camera.name}: photo is {tuple(photo.shape)}, camera expects "
                             f"{(camera.height, camera.width, 3)}")
        with torch.no_grad():
            rgb = rasterizer(gaussians, camera, outputs=("rgb",), background=background_t)["rgb"]
            rgb = rgb.to(torch.float32).clamp(0.0, 1.0)
            score = ViewScore(index, camera.name, group_of(index, split),
                              float(psnr(rgb, photo)), float(ssim(rgb, photo)))
            if lpips_model is not None:
                to_model = lambda x: x.permute(2, 0, 1)[None] * 2.0 - 1.0  # noqa: E731
                score.lpips = float(torch.as_tensor(lpips_model(to_model(rgb), to_model(photo))).reshape(-1)[0])
            if fid_model is not None:
                chw = lambda x: x.permute(2, 0, 1)[None]  # noqa: E731
                features.append((score.group, torch.as_tensor(fid_model(chw(rgb))).reshape(-1).double(),
                                 torch.as_tensor(fid_model(chw(photo))).reshape(-1).double()))
        if save_dir is not None:
            file_name = f"{score.group}_{index:04d}_{safe_name(camera.name)}.png"
            write_png(save_dir / file_name, side_by_side(rgb.cpu().numpy(), photo.cpu().numpy()))
            score.image = file_name
        views.append(score)
    groups = summarise(views)
    if fid_model is not None:
        for group in (*GROUPS, "all"):
            members = [(r, p) for g, r, p in features if group == "all" or g == group]
            if len(members) >= 2:
                groups[group]["fid"] = frechet_distance(torch.stack([r for r, _ in members]),
                                                        torch.stack([p for _, p in members]))
    return {"groups": groups, "views": [vars(v) for v in views]}


def format_table(summary: dict) -> str:
    """A plain-text table of the group scores of :func:`evaluate_run`'s result."""
    def cell(value, digits):
        if value is None:
            return "-"
        if isinstance(value, str):
            return value
        return f"{value:.{digits}f}"

    groups = summary["groups"]
    lines = [f"{'views':<10}{'n':>4}{'PSNR':>9}{'SSIM':>8}{'LPIPS':>8}{'FID':>9}"]
    for group in (*GROUPS, "all"):
        entry = groups[group]
        lines.append(f"{group:<10}{entry['views']:>4}{cell(entry['psnr'], 2):>9}{cell(entry['ssim'], 4):>8}"
                     f"{cell(entry.get('lpips'), 4):>8}{cell(entry.get('fid'), 2):>9}")
    lines.append(f"LPIPS: {summary['lpips']}")
    lines.append(f"FID: {summary['fid']}")
    if summary.get("target_view") is not None:
        lines.append(f"target view j*: {summary['target_view']}")
    return "\n".join(lines)
