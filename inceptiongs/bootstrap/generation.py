"""The prior's image at the virtual views, cached on disk (I* itself: supervise.py).

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
from typing import Callable, Protocol, Sequence

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


class ImagePrior(Protocol):
    """What generation asks of a prior (prior.model.Prior, prior.sd_backend.SDPrior): its device,
    and ``generate(gaussians, camera, steps, seed)`` -> (rgb [H, W, 3] in [0, 1], extras)."""

    device: torch.device

    def generate(self, gaussians: Gaussians, camera: Camera, steps: int, seed: int) -> tuple: ...

    def eval(self): ...


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
                 should_stop: Callable[[], bool] | None = None, device="cpu"):
    """The prior used for generation -> (Prior, one-line description).

    mode "untrained": a randomly initialised prior (the ablation). "trained": RUN/prior/prior.pt
    when the stage-I run has one, else RUN2/prior/prior.pt from an earlier bootstrap into the
    same folder, else a short training (``minutes`` / ``steps``) on the training photos,
    saved to RUN2/prior/prior.pt. should_stop() ends that training early (before any step):
    the bootstrap's wall-clock share of its budget, or the user's stop. The prior is trained and
    generates on ``device``, the run's (load_image still returns the photos on the host).
    """
    from ..prior.model import Prior, PriorConfig
    from ..prior.trainer import CHECKPOINT_NAME, PriorTrainer, load_prior, prior_dir

    if mode == "untrained":
        prior = Prior.for_gaussians(PriorConfig(seed=seed), gaussians).to(device)
        return prior, "untrained prior (random initial weights: ablation)"
    for folder, what in ((run_dir, "the stage-I run's"), (out_dir, "this bootstrap's earlier")):
        if (prior_dir(folder) / CHECKPOINT_NAME).is_file():
            return load_prior(folder, device), f"{what} trained prior ({prior_dir(folder) / CHECKPOINT_NAME})"
    if not cameras:
        raise InputError(f"{run_dir}: no training views to train a prior on")
    log(f"{run_dir}: no trained prior; training one for "
        + (f"{minutes:g} min" if minutes is not None else "") + (" / " if minutes and steps else "")
        + (f"{steps} steps" if steps is not None else ""))
    trainer = PriorTrainer(Prior.for_gaussians(PriorConfig(seed=seed), gaussians).to(device), gaussians,
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
    # What a variant keeps for its loss term at the view (the variant "geometry": its source
    # photos, experimental.multiview.GeometrySource; empty on the default path).
    geometry: list = field(default_factory=list)
    # The warped photos' agreement margin (agreement.py; None: not measured) and whether the
    # view takes part in the refinement (False: the render agrees with the photos better than
    # they agree with each other).
    agreement_db: float | None = None
    supervised: bool = True
    # Which depth placed the photos: "render", "sources" or "both" (--virtual-depth; "auto"
    # records the one it chose).
    depth: str = "render"
    # [H, W, 1] loss weight per pixel set by a placement (the variant "evidence": 1 where the
    # leave-one-out estimate says the blend beats the render, else 0); None: every pixel counts.
    evidence: torch.Tensor | None = None
