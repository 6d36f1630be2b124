"""Evaluation of a run on its held-out views: PSNR and SSIM, separately for the scarce
cluster and the covered views, plus render | photo | error images and RUN/eval/eval.json.

Scores per group are means of per-view scores (the NeRF/3DGS convention: each held-out view
weighs the same whatever its content). LPIPS and FID are computed only from weights the user
gives as local TorchScript files (docs/evaluation.md says what they must compute); without
them the result says "unavailable" - never a stand-in under that name.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import torch

from .atomic import atomic_write_bytes, atomic_write_text
from .errors import InputError
from .metrics import frechet_distance, psnr, ssim
from .protocols import Split

GROUPS = ("scarce", "covered")
# The error panel maps |render - photo| (mean over channels) linearly onto the colour map,
# saturating at this error: typical reconstruction errors are well below 0.25, so the full
# [0, 1] range would show nearly everything black.
ERROR_IMAGE_MAX = 0.25
UNAVAILABLE_LPIPS = "unavailable (no --lpips-weights given)"
UNAVAILABLE_FID = "unavailable (no --fid-weights given)"


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


def _mean(values: list[float]) -> float | None:
    """Mean of per-view scores; None for an empty group (nothing to report, not zero)."""
    return float(np.mean(values)) if values else None


def summarise(views: list[ViewScore]) -> dict[str, dict]:
    """Per group ("scarce", "covered", "all"): {"views": n, "psnr": mean | None, "ssim": ...}."""
    out = {}
    for group in (*GROUPS, "all"):
        members = [v for v in views if group == "all" or v.group == group]
        entry = {"views": len(members), "psnr": _mean([v.psnr for v in members]),
                 "ssim": _mean([v.ssim for v in members])}
        if members and all(v.lpips is not None for v in members):
            entry["lpips"] = _mean([v.lpips for v in members])
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


def write_png(path: Path, rgb: np.ndarray) -> None:
    """rgb: [H, W, 3] uint8 -> PNG, atomically."""
    import cv2

    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, encoded.tobytes())


def _safe_name(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in Path(name).stem) or "view"


def evaluate_views(gaussians, scene, split: Split, photos: Mapping[int, torch.Tensor] | None = None,
                   background=None, save_dir: str | Path | None = None,
                   lpips_model: Callable | None = None, fid_model: Callable | None = None,
                   progress: bool = False) -> dict:
    """Render every held-out view of ``split`` and score it against its photo.

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
    from .rasterize import render  # the rasterizer is heavy; evaluation of a run needs it, readers don't

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
            photo = torch.as_tensor(scene.load_image(index))
        photo = photo.to(device=gaussians.device, dtype=torch.float32)
        if tuple(photo.shape) != (camera.height, camera.width, 3):
            raise InputError(f"{camera.name}: photo is {tuple(photo.shape)}, camera expects "
                             f"{(camera.height, camera.width, 3)}")
        with torch.no_grad():
            rgb = render(gaussians, camera, outputs=("rgb",), background=background_t)["rgb"]
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
            file_name = f"{score.group}_{index:04d}_{_safe_name(camera.name)}.png"
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


def load_torchscript(path: str | Path, what: str) -> Callable:
    """A user-given TorchScript network (LPIPS or FID feature extractor), in eval mode."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} weights file does not exist")
    try:
        module = torch.jit.load(str(path), map_location="cpu")
    except (RuntimeError, ValueError, OSError) as exc:
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: not a TorchScript {what} network ({first_line})") from None
    return module.eval()


def json_safe(value):
    """JSON has no inf: an exact reconstruction's PSNR is written as the string "inf"."""
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    return value


def evaluate_run(run_dir: str | Path, lpips_weights: str | Path | None = None,
                 fid_weights: str | Path | None = None, progress: bool = True) -> dict:
    """Evaluate RUN/model (via inceptiongs.train.load_run) on RUN/split.json's held-out views.

    Writes RUN/eval/<group>_<index>_<name>.png (render | photo | error) and RUN/eval/eval.json,
    and returns the same dict as eval.json: {"run", "protocol", "seed", "target_view",
    "groups": {"scarce"|"covered"|"all": {"views", "psnr", "ssim"[, "lpips"][, "fid"]}},
    "views": [...], "lpips": "computed ..." | "unavailable ...", "fid": ...}.
    """
    from .train import load_run

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: run folder does not exist")
    gaussians, scene, _config = load_run(run_dir)
    split = Split.load(run_dir / "split.json", scene.cameras)
    if not split.test:
        raise InputError(f"{run_dir / 'split.json'}: the split holds out no views (protocol "
                         f"{split.protocol!r}); nothing to evaluate")
    lpips_model = load_torchscript(lpips_weights, "LPIPS") if lpips_weights else None
    fid_model = load_torchscript(fid_weights, "FID") if fid_weights else None
    eval_dir = run_dir / "eval"
    # The trainer scores its test views on black (the rasterizer's default); so do we.
    result = evaluate_views(gaussians, scene, split, save_dir=eval_dir, lpips_model=lpips_model,
                            fid_model=fid_model, progress=progress)
    for view in result["views"]:
        view["image"] = f"eval/{view['image']}"
    groups = result["groups"]
    summary = {
        "run": str(run_dir.resolve()),
        "protocol": split.protocol,
        "seed": split.seed,
        "target_view": split.target_view,
        "groups": groups,
        "views": result["views"],
        "lpips": f"computed with {lpips_weights}" if lpips_weights else UNAVAILABLE_LPIPS,
        "fid": f"computed with {fid_weights}" if fid_weights else UNAVAILABLE_FID,
    }
    atomic_write_text(eval_dir / "eval.json", json.dumps(json_safe(summary), indent=1) + "\n")
    return summary


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
