"""I* at the virtual views: the prior's image, cached on disk, blended with warped real photos.

Generation is the costly part of a bootstrap round on a CPU, so every generated image is kept in
RUN2/bootstrap/cache/<key>.npy, where the key hashes everything the image depends on: the seed,
the view's pose and intrinsics, the prior's weights, the Gaussians the G-buffer is rendered from,
and the sampler settings. A rerun with the same inputs reads the file instead of sampling.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from ..io.atomic import atomic_write_bytes
from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians

CACHE_FORMAT_VERSION = 1
# Poses are rounded to this many decimals before hashing, so a pose that went through JSON
# (or float64 -> text -> float64) still hits its cache entry.
POSE_DECIMALS = 9


def tensor_digest(tensors: Sequence[torch.Tensor]) -> str:
    """A short hex digest of tensors' exact bytes (shapes included)."""
    sha = hashlib.sha1()
    for tensor in tensors:
        array = tensor.detach().cpu().contiguous().numpy()
        sha.update(str((array.dtype.str, array.shape)).encode())
        sha.update(array.tobytes())
    return sha.hexdigest()[:16]


def prior_version(prior) -> str:
    """Digest of a prior's weights and config (the "model version" of the cache key): the config
    holds how it samples (e.g. sample_start), so the same weights can give another image."""
    # checkpoint_state(): what the prior's checkpoint holds (all weights of the tiny backend,
    # the trained parts of a large pretrained one), so hashing stays cheap for both.
    state = prior.checkpoint_state() if hasattr(prior, "checkpoint_state") else prior.state_dict()
    weights = tensor_digest([state[name] for name in sorted(state) if torch.is_tensor(state[name])])
    config = prior.config.to_dict() if hasattr(prior, "config") else {}
    return hashlib.sha1((weights + json.dumps(config, sort_keys=True, default=str)).encode()).hexdigest()[:24]


def gaussians_version(gaussians: Gaussians) -> str:
    return tensor_digest([gaussians.means, gaussians.log_scales, gaussians.quats,
                          gaussians.opacity_logits, gaussians.sh])


def cache_key(camera: Camera, seed: int, prior_hash: str, gaussians_hash: str, steps: int) -> str:
    """Hex key of one generated image."""
    description = {
        "format": CACHE_FORMAT_VERSION, "seed": int(seed), "steps": int(steps),
        "prior": prior_hash, "gaussians": gaussians_hash,
        "size": [int(camera.width), int(camera.height)],
        "intrinsics": np.round([camera.fx, camera.fy, camera.cx, camera.cy], POSE_DECIMALS).tolist(),
        "pose": np.round(camera.world_to_camera, POSE_DECIMALS).tolist(),
    }
    return hashlib.sha1(json.dumps(description, sort_keys=True).encode()).hexdigest()[:24]


def view_seed(seed: int, key: str) -> int:
    """A per-view sampling seed: different views get different noise, reruns the same."""
    return (int(seed) * 1_000_003 + int(key[:8], 16)) % (2**31 - 1)


@dataclass
class GenerationCache:
    """RUN2/bootstrap/cache: one .npy ([H, W, 3] float32 in [0, 1]) per key."""

    folder: Path
    hits: int = 0
    misses: int = 0

    def path(self, key: str) -> Path:
        return Path(self.folder) / f"{key}.npy"

    def get(self, key: str, shape: tuple[int, int]) -> np.ndarray | None:
        """The cached image, or None (absent, unreadable or the wrong shape: regenerate)."""
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            image = np.load(path, allow_pickle=False)
        except (OSError, ValueError):
            return None  # a foreign or truncated file: the key's image is generated again
        if image.shape != (*shape, 3) or not np.isfinite(image).all():
            return None
        return image.astype(np.float32)

    def put(self, key: str, image: np.ndarray) -> None:
        buffer = io.BytesIO()
        np.save(buffer, np.asarray(image, np.float32), allow_pickle=False)
        atomic_write_bytes(self.path(key), buffer.getvalue())


def generate_cached(prior, gaussians: Gaussians, camera: Camera, seed: int, steps: int,
                    cache: GenerationCache, prior_hash: str, gaussians_hash: str) -> tuple[np.ndarray, bool]:
    """(generated rgb [H, W, 3] float32 in [0, 1], True when read from the cache)."""
    key = cache_key(camera, seed, prior_hash, gaussians_hash, steps)
    cached = cache.get(key, (camera.height, camera.width))
    if cached is not None:
        cache.hits += 1
        return cached, True
    rgb, _ = prior.generate(gaussians, camera, steps=steps, seed=view_seed(seed, key))
    image = rgb.detach().cpu().numpy().astype(np.float32)
    cache.put(key, image)
    cache.misses += 1
    return image, False


def obtain_prior(run_dir: Path, out_dir: Path, gaussians: Gaussians, cameras: list[Camera],
                 load_image: Callable[[int], np.ndarray], mode: str, seed: int,
                 minutes: float | None, steps: int | None, log: Callable[[str], None],
                 should_stop: Callable[[], bool] | None = None):
    """The prior used for generation -> (Prior, one-line description).

    mode "untrained": a randomly initialised prior (the ablation). "trained": RUN/prior/prior.pt
    when the stage-I run has one, else RUN2/prior/prior.pt from an earlier bootstrap into the
    same folder, else a short training (``minutes`` / ``steps``) on the training photos,
    saved to RUN2/prior/prior.pt. should_stop() ends that training early (before any step):
    the bootstrap's wall-clock share of its budget, or the user's stop.
    """
    from ..prior.model import Prior, PriorConfig
    from ..prior.trainer import CHECKPOINT_NAME, PriorTrainer, load_prior, prior_dir

    if mode == "untrained":
        prior = Prior.for_gaussians(PriorConfig(seed=seed), gaussians)
        return prior, "untrained prior (random initial weights: ablation)"
    for folder, what in ((run_dir, "the stage-I run's"), (out_dir, "this bootstrap's earlier")):
        if (prior_dir(folder) / CHECKPOINT_NAME).is_file():
            return load_prior(folder), f"{what} trained prior ({prior_dir(folder) / CHECKPOINT_NAME})"
    if not cameras:
        raise InputError(f"{run_dir}: no training views to train a prior on")
    log(f"{run_dir}: no trained prior; training one for "
        + (f"{minutes:g} min" if minutes is not None else "") + (" / " if minutes and steps else "")
        + (f"{steps} steps" if steps is not None else ""))
    trainer = PriorTrainer(Prior.for_gaussians(PriorConfig(seed=seed), gaussians), gaussians,
                           cameras, load_image)
    trainer.train(steps=steps, minutes=minutes, run_dir=out_dir, progress=False, should_stop=should_stop)
    return trainer.prior, (f"prior trained here for {trainer.step_count} steps "
                           f"({prior_dir(out_dir) / CHECKPOINT_NAME})")


@dataclass
class VirtualTarget:
    """One virtual view's supervision: camera, I* [H, W, 3], trusted-pixel mask [H, W, 1], and the
    source photos of the geometry term (refine.virtual_loss)."""

    name: str
    camera: Camera
    target: torch.Tensor
    mask: torch.Tensor
    generated: torch.Tensor
    cache_hit: bool
    round: int
    # The source photos of the geometry term (multiview.GeometrySource; empty when it is off).
    geometry: list = field(default_factory=list)
    # The warped photos' agreement margin (agreement.py; None: not measured) and whether the
    # view takes part in the refinement (False: the render agrees with the photos better than
    # they agree with each other).
    agreement_db: float | None = None
    supervised: bool = True
    # Which depth placed the photos: "render", "sources" or "both" (--virtual-depth; "auto"
    # records the one it chose).
    depth: str = "render"


def blend_target(generated: np.ndarray, camera: Camera, sources: Sequence[int], cameras: Sequence[Camera],
                 photos: dict[int, torch.Tensor], render_depth: Callable[[Camera], torch.Tensor],
                 blending: bool, delta: float | None, supervision: str = "blend", fill: str = "prior",
                 render_rgb: Callable[[Camera], torch.Tensor] | None = None,
                 pixels: str = "all", residual_floor: float | None = None,
                 target_depth: torch.Tensor | None = None,
                 report: dict | None = None, combine: str = "none",
                 align_px: float | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """I* = M * warped + (1 - M) * fill for one virtual view -> (I* [H, W, 3], M [H, W, 1]).

    sources: training view indices whose photos are warped in, with the stage-I depth of both
    views. ``supervision="blend"``: the uniform mean of the binary-masked warps over the
    generated image (the paper's blending with ``fill="prior"``; the caller passes the render as
    ``generated`` for ``fill="render"``; ``fill="inpaint"`` carries the blend into the pixels no
    photo reaches); ``"photo"``: photo-consistent depth, exposure
    matching, lumigraph weights and a soft mask over ``fill`` (supervision.py; needs
    ``render_rgb`` for the render fill and the inpainting's surroundings). ``blending=False``
    (ablation) keeps the generated image and an all-zero mask. ``pixels="informative"`` (photo
    supervision only) returns the informative mask instead of the trust mask (the pixels where
    the photos contradict the render: supervision.informative_mask, whose floor ``residual_floor``
    overrides) and the blended photos there. ``target_depth`` [H, W, 1]: the virtual view's
    depth to warp with (default ``render_depth(camera)``; source_depth.splatted_depth).
    ``combine`` (blend only, with ``target_depth``): "both" warps with both depths, and a pixel
    the warps placed with ``render_depth(camera)`` trust takes their blend, else the blend placed
    with ``target_depth`` (``--virtual-depth both``); "auto" keeps whichever depth's blend
    trusts more pixels (``--virtual-depth auto``; report["depth"] says which: "render" or
    "sources"). ``report``: a dict that receives "agreement_db", the warps' agreement margin against the
    render (agreement.agreement_margin_db; None when not measurable). ``align_px`` (blend only):
    each warp is first moved onto the render by optical flow, pixels moved further than this
    left untrusted (align.align_warp; the render is ``render_rgb(camera)``, else ``generated``).
    """
    if combine not in ("none", "both", "auto"):
        raise ValueError(f"combine must be 'none', 'both' or 'auto', got {combine!r}")
    generated_t = torch.as_tensor(generated, dtype=torch.float32)
    if not blending or not sources:
        return generated_t, torch.zeros((*generated_t.shape[:2], 1))
    from .agreement import agreement_margin_db
    from .warp import DEFAULT_DELTA, WarpResult, blend_views, warp_to_view

    delta = DEFAULT_DELTA if delta is None else delta
    dst_depth = render_depth(camera) if target_depth is None else target_depth

    def the_render() -> torch.Tensor:
        # Asked for only where needed: a caller without ``render_rgb`` passes the render as ``generated``.
        return render_rgb(camera) if render_rgb is not None else generated_t

    if supervision == "photo":
        from .supervision import RESIDUAL_FLOOR, Source, supervise

        render = the_render()
        out = supervise(camera, render, dst_depth,
                        [Source(photos[i], cameras[i], render_depth(cameras[i])) for i in sources],
                        generated=generated_t, fill=fill, delta=delta,
                        residual_floor=RESIDUAL_FLOOR if residual_floor is None else residual_floor)
        if report is not None:
            report["agreement_db"] = agreement_margin_db(render, out.warps)
        if pixels == "informative":
            # The blend itself on the informative pixels (not I*, whose soft mask may give the
            # photos almost no weight where the best witness is far off in angle), the fill elsewhere.
            target = out.informative * out.blended + (1.0 - out.informative) * out.fill
            return target.detach().float().clamp(0.0, 1.0), out.informative.detach().float()
        return out.target.detach().float().clamp(0.0, 1.0), out.mask.detach().float()
    def warps_with(depth: torch.Tensor) -> list:
        warps = [warp_to_view(photos[index], render_depth(cameras[index]), cameras[index], depth, camera, delta=delta)
                 for index in sources]
        if align_px is None:
            return warps
        from .align import align_warp
        reference = the_render()
        return [align_warp(reference, warp, align_px) for warp in warps]

    warps = warps_with(dst_depth)
    image, mask = blend_views(generated_t, warps)
    if report is not None and target_depth is not None:
        report["depth"] = "sources"
    if combine != "none" and target_depth is not None:
        own_depth = render_depth(camera)
        first = warps_with(own_depth)
        first_image, first_mask = blend_views(generated_t, first)
        if combine == "both":
            # Per source, the warp placed with the view's own depth where it is trusted (the
            # agreement is judged on the photos as they enter the blend).
            warps = [WarpResult(torch.where(a.mask > 0, a.image, b.image), torch.maximum(a.mask, b.mask))
                     for a, b in zip(first, warps)]
            image = torch.where(first_mask > 0, first_image, image)
            mask = torch.maximum(first_mask, mask)
            dst_depth = torch.where(own_depth > 0, own_depth, dst_depth)
            if report is not None:
                report["depth"] = "both"
        elif float(first_mask.sum()) > float(mask.sum()):
            warps, image, mask, dst_depth = first, first_image, first_mask, own_depth
            if report is not None:
                report["depth"] = "render"
    if report is not None:
        report["agreement_db"] = agreement_margin_db(the_render(), warps)
    if fill == "inpaint":
        from .supervision import inpaint

        # The photos' blend carried into the pixels no photo reaches (where the view has depth).
        image = inpaint(image, (mask[..., 0] > 0) | (dst_depth[..., 0] <= 0))
    return image.detach().float().clamp(0.0, 1.0), mask.detach().float()
