"""Training the prior on random s x s patches of the training photos.

Each step draws ``batch_size`` (view, patch) pairs, renders the matching G-buffer patches from
the *current* Gaussians on the fly (only the patch: Camera.cropped), and takes one Adam step
on the epsilon-prediction loss; the hash grid is trained through that loss (its own, larger
learning rate, as hash tables need). Checkpoints go atomically to RUN/prior/prior.pt; with a
run_dir, RUN/prior/metrics.jsonl logs the loss against prior training seconds (and, when an
evaluation function is given, generated-image quality at intervals) for `inceptiongs report`.

Backends: the trainer only uses the prior interface of model.Prior (the tiny backend) and
sd_backend.SDPrior (Stable Diffusion + ControlNet): parameter_groups(), patch_multiple,
diffusion_loss(), checkpoint_state().
"""

from __future__ import annotations

import collections
import io
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from ..io.atomic import atomic_write_bytes
from ..io.paths import check_inside
from ..io.photo_memory import default_budget, photo_memory
from ..io.pickles import file_names_code
from ..camera import Camera
from ..errors import InputError, one_line
from ..gaussians import Gaussians
from .gbuffer import crop_candidates, gaussian_features, render_gbuffer, render_geometry, surface_features
from .footprint import check_training_fits
from .model import Prior, PriorConfig, denoiser_cond_channels

CHECKPOINT_NAME = "prior.pt"
METRICS_NAME = "metrics.jsonl"
BACKENDS = ("tiny", "sd")
# Adam's epsilon for the hash tables: most slots see no gradient in a step, and a large epsilon
# would damp the rare updates of the finest levels (Instant-NGP uses 1e-15).
HASH_ADAM_EPS = 1e-15
# With hash_at="surface" and unchanged Gaussians, each training view's geometry (normal, alpha,
# depth: 5 floats a pixel) is rendered once and cropped for every later patch. Views beyond
# this many bytes are rendered per patch instead, so a big capture cannot fill the memory.
GEOMETRY_CACHE_BYTES = 512 * 2 ** 20


def adam_for(groups: list[dict]) -> torch.optim.Adam:
    """Adam over a prior's parameter groups; a group marked "hash" gets HASH_ADAM_EPS."""
    return torch.optim.Adam([{**group, "eps": HASH_ADAM_EPS} if group.get("hash") else group for group in groups])


def prior_dir(run_dir: str | Path) -> Path:
    return Path(run_dir) / "prior"


def patch_size_for(prior, cameras: list[Camera]) -> int:
    """The patch edge: prior.config.patch_size, shrunk to fit the smallest image (a multiple of
    prior.patch_multiple: the UNet's, and for sd the VAE's, downsample factor)."""
    factor = prior.patch_multiple
    smallest = min(min(c.width, c.height) for c in cameras)
    size = min(prior.config.patch_size, smallest) // factor * factor
    if size < factor:
        raise InputError(f"{cameras[0].name}: images of {smallest} px are too small for prior patches")
    return size


@dataclass
class PriorTrainer:
    """prior: Prior or SDPrior; gaussians: the current model (re-assign it when the geometry
    changes); cameras: training cameras; load_image(i) -> [H, W, 3] float in [0, 1] of camera i.
    train_s: seconds spent in step() over the prior's whole life (kept across resumes).
    photo_budget: bytes of converted photos kept between steps (None: --photo-memory, else as
    the photo store's default); at least one photo, least recently used first out."""

    prior: Prior
    gaussians: Gaussians
    cameras: list[Camera]
    load_image: Callable[[int], np.ndarray]
    step_count: int = 0
    losses: list[float] = field(default_factory=list)
    train_s: float = 0.0
    photo_budget: int | None = None

    def __post_init__(self) -> None:
        if not self.cameras:
            raise InputError("prior training: no training cameras")
        self.patch_size = patch_size_for(self.prior, self.cameras)
        if self.prior.backend == "tiny":     # the batch a file or a flag set must fit before the first step
            check_training_fits(self.prior.config.unet, denoiser_cond_channels(self.prior.config), self.patch_size,
                                self.prior.config.batch_size, "prior settings", self.prior.device)
        self.generator = torch.Generator().manual_seed(self.prior.config.seed)
        self.optimizer = adam_for(self.prior.parameter_groups())
        sizes = [3 * 4 * c.width * c.height for c in self.cameras]   # float32 [3, H, W]
        budget = self.photo_budget if self.photo_budget is not None else photo_memory()
        self._image_budget = max(default_budget(sum(sizes)) if budget is None else budget, max(sizes))
        self._images: collections.OrderedDict[int, torch.Tensor] = collections.OrderedDict()
        self._image_bytes = 0
        self._geometry: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        self._geometry_bytes = 0
        self._geometry_of: Gaussians | None = None  # the Gaussians object the cache was rendered from
        self._on_device: tuple[Gaussians, Gaussians] | None = None   # (self.gaussians, its copy)

    def _gaussians_on_device(self) -> Gaussians:
        """self.gaussians on the prior's device, detached: moved once per model, not per step (a
        host model trained against a GPU prior would otherwise cross the bus every step)."""
        if self._on_device is None or self._on_device[0] is not self.gaussians:
            self._on_device = (self.gaussians, self.gaussians.to(self.prior.device).detach())
        return self._on_device[1]

    def _image(self, index: int) -> torch.Tensor:
        """Photo i as [3, H, W] in [-1, 1], kept within the photo budget (patches are drawn
        from it many times; one read again is converted again, to the same values)."""
        image = self._images.get(index)
        if image is not None:
            self._images.move_to_end(index)
            return image
        camera = self.cameras[index]
        photo = np.asarray(self.load_image(index), dtype=np.float32)
        if photo.shape != (camera.height, camera.width, 3):
            raise InputError(f"{camera.name}: image is {photo.shape}, camera expects "
                             f"{(camera.height, camera.width, 3)}")
        image = torch.from_numpy(photo).permute(2, 0, 1).mul(2.0).sub(1.0)
        size = image.numel() * image.element_size()
        while self._images and self._image_bytes + size > self._image_budget:
            _, old = self._images.popitem(last=False)
            self._image_bytes -= old.numel() * old.element_size()
        self._images[index] = image
        self._image_bytes += size
        return image

    def sample_batch(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(photo patches [B, 3, s, s] in [-1, 1], G-buffer patches [B, 4 + Z, s, s])."""
        s = self.patch_size
        gaussians = self._gaussians_on_device()
        photos, patches = [], []
        for _ in range(self.prior.config.batch_size):
            index = int(torch.randint(len(self.cameras), (1,), generator=self.generator))
            camera = self.cameras[index]
            x0 = int(torch.randint(camera.width - s + 1, (1,), generator=self.generator))
            y0 = int(torch.randint(camera.height - s + 1, (1,), generator=self.generator))
            photos.append(self._image(index)[:, y0:y0 + s, x0:x0 + s])
            patches.append((index, x0, y0))
        photos = torch.stack(photos).to(self.prior.device)
        if getattr(self.prior.config, "hash_at", "centres") == "surface":
            return photos, self._surface_conds(gaussians, patches)
        patch_cameras = [self.cameras[index].cropped(x0, y0, s, s) for index, x0, y0 in patches]
        # The hash lookup is the costly part for big scenes: do it once per step, only for the
        # Gaussians some patch can see, and share it between the patches.
        candidates = [crop_candidates(gaussians, patch) for patch in patch_cameras]
        union = torch.unique(torch.cat(candidates))  # sorted
        features = gaussian_features(gaussians.subset(union), self.prior.hash_grid)
        conds = [render_gbuffer(gaussians.subset(keep), patch, self.prior.hash_grid,
                                features=features[torch.searchsorted(union, keep)], hash_at="centres")
                 for keep, patch in zip(candidates, patch_cameras)]
        return photos, torch.stack(conds)

    def _surface_conds(self, gaussians: Gaussians, patches: list[tuple[int, int, int]]) -> torch.Tensor:
        """G-buffer patches [B, 4 + Z, s, s] for (view, x0, y0) with hash_at="surface".

        When self.gaussians is the object of the previous step (a finished run's fixed model),
        each view's geometry comes from a cache of full-view renders; when it was re-assigned
        (joint training: new geometry every prior step) the cache is dropped and only the
        patches are rendered."""
        s = self.patch_size
        if self._geometry_of is not self.gaussians:
            self._geometry.clear()
            self._geometry_bytes = 0
            stable = False
        else:
            stable = True
        self._geometry_of = self.gaussians
        conds = []
        for index, x0, y0 in patches:
            camera = self.cameras[index]
            patch = camera.cropped(x0, y0, s, s)
            cached = self._geometry.get(index)
            view_bytes = 5 * 4 * camera.width * camera.height
            if cached is None and stable and self._geometry_bytes + view_bytes <= GEOMETRY_CACHE_BYTES:
                cached = self._geometry[index] = render_geometry(gaussians, camera)
                self._geometry_bytes += view_bytes
            if cached is None:
                geometry, depth = render_geometry(gaussians, patch)
            else:
                geometry, depth = cached[0][:, y0:y0 + s, x0:x0 + s], cached[1][y0:y0 + s, x0:x0 + s]
            conds.append(torch.cat([geometry, surface_features(self.prior.hash_grid, geometry, depth, patch)]))
        return torch.stack(conds)

    def step(self) -> float:
        """One Adam step; returns the batch's diffusion loss."""
        start = time.perf_counter()
        photos, conds = self.sample_batch()
        loss = self.prior.diffusion_loss(photos, conds, generator=self.generator)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.step_count += 1
        value = float(loss.detach())
        self.losses.append(value)
        self.train_s += time.perf_counter() - start
        return value

    def log(self, run_dir: str | Path, record: dict | None = None, last: int = 1) -> None:
        """Append {"step", "train_s" (prior training seconds), "loss" (mean of the ``last``
        losses), **record} to RUN/prior/metrics.jsonl."""
        window = self.losses[-max(1, last):]
        entry = {"step": self.step_count, "train_s": self.train_s,
                 **({"loss": sum(window) / len(window)} if window else {}), **(record or {})}
        append_prior_metrics(run_dir, entry)

    def train(self, steps: int | None = None, minutes: float | None = None,
              run_dir: str | Path | None = None, checkpoint_every: int = 200,
              progress: bool = True, log_every: int = 20,
              evaluate: Callable[["Prior"], dict] | None = None,
              evaluate_every_s: float | None = None,
              should_stop: Callable[[], bool] | None = None) -> list[float]:
        """Train for ``steps`` steps and/or ``minutes`` minutes of training time (whichever ends
        first), checkpointing into RUN/prior/ every ``checkpoint_every`` steps and at the end when
        run_dir is given, logging to RUN/prior/metrics.jsonl every ``log_every`` steps.
        evaluate(prior) -> scores ({"generated": {"scarce": {"psnr": .., "ssim": ..}, ..}}) runs
        at the start, every ``evaluate_every_s`` training seconds and at the end; its time is
        not training time (it does not count against ``minutes``). should_stop() is asked before
        each step: True ends the training there (a caller's wall-clock budget, a user's stop)."""
        if steps is None and minutes is None:
            raise ValueError("give steps or minutes")
        budget_s = None if minutes is None else 60.0 * minutes
        start_s = self.train_s
        next_eval = self.train_s

        def maybe_evaluate(force: bool = False) -> None:
            nonlocal next_eval
            if evaluate is None or run_dir is None or not (force or self.train_s >= next_eval):
                return
            self.log(run_dir, evaluate(self.prior), last=log_every)
            next_eval = self.train_s + (evaluate_every_s or float("inf"))

        bar = tqdm(total=steps, desc="prior", disable=not progress, unit="step")
        done = 0
        try:
            maybe_evaluate()
            while (steps is None or done < steps) and (budget_s is None or self.train_s - start_s < budget_s):
                if should_stop is not None and should_stop():
                    break
                loss = self.step()
                done += 1
                bar.update(1)
                bar.set_postfix(loss=f"{loss:.4f}")
                if run_dir is not None and log_every and self.step_count % log_every == 0:
                    self.log(run_dir, last=log_every)
                if run_dir is not None and checkpoint_every and self.step_count % checkpoint_every == 0:
                    save_prior(run_dir, self)
                maybe_evaluate()
        finally:
            bar.close()
        if run_dir is not None:
            if done and evaluate is not None:
                maybe_evaluate(force=True)
            elif done and (not log_every or self.step_count % log_every):
                self.log(run_dir, last=min(done, log_every or done))  # the last steps' record
            save_prior(run_dir, self)
        return self.losses[-done:] if done else []


def append_prior_metrics(run_dir: str | Path, record: dict) -> None:
    """One JSON line in RUN/prior/metrics.jsonl (appended and flushed; a torn last line, from a
    kill mid-write, is dropped by the reader)."""
    from ..io.atomic import append_line

    append_line(prior_dir(run_dir) / METRICS_NAME, json.dumps(record))


def build_prior(backend: str, config, device=None, source: str = "prior config"):
    """A new prior of ``backend`` from its config object (PriorConfig or SDPriorConfig);
    ``source`` (where the config came from) names it in a refusal."""
    if backend == "tiny":
        return Prior(config, source).to(device)
    if backend == "sd":
        from .sd_backend import SDPrior
        return SDPrior(config, device=device)
    raise InputError(f"unknown prior backend {backend!r} ({' | '.join(BACKENDS)})")


def config_from_dict(backend: str, data: dict, source: str = "prior checkpoint"):
    if backend == "sd":
        from .sd_backend import SDPriorConfig
        return SDPriorConfig.from_dict(data, source)
    return PriorConfig.from_dict(data, source)


def save_prior(run_dir: str | Path, trainer: PriorTrainer) -> Path:
    """Write RUN/prior/prior.pt atomically: config, weights, optimiser state, step, losses, and
    the device it trained on."""
    payload = {
        "backend": trainer.prior.backend,
        "config": trainer.prior.config.to_dict(),
        # The sd backend stores only what it trains (ControlNet, hash grid, null prompt): the
        # frozen base stays in the user's Stable Diffusion folder.
        "model": trainer.prior.checkpoint_state(),
        "optimizer": trainer.optimizer.state_dict(),
        "step": trainer.step_count,
        "losses": list(trainer.losses),
        "train_s": trainer.train_s,
        "generator": trainer.generator.get_state(),
        "device": trainer.prior.device.type,   # where it trained ("cpu", "cuda"): the command's --device
    }
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    path = prior_dir(run_dir) / CHECKPOINT_NAME
    atomic_write_bytes(path, buffer.getvalue())
    return path


def read_prior_checkpoint(run_dir: str | Path, device=None) -> dict:
    path = prior_dir(run_dir) / CHECKPOINT_NAME
    if not path.is_file():
        raise InputError(f"{path}: no prior checkpoint (train one with `inceptiongs prior RUN`)")
    check_inside(path, run_dir)
    try:
        payload = torch.load(path, map_location=device, weights_only=True)
        backend = payload.get("backend", "tiny")  # checkpoints from before the sd backend
        return {**payload, "backend": backend, "config": config_from_dict(backend, payload["config"], str(path))}
    except Exception as exc:  # a truncated or foreign file: report it as the user's input problem
        text = str(exc)
        if "Weights only load failed" in text:   # torch's advice to load it unsafely is not repeated
            if file_names_code(path, text):
                raise InputError(f"{path}: refused: it holds Python objects other than tensors and plain data "
                                 "(loading it could run code; a prior checkpoint never does)") from None
            after = text.split("WeightsUnpickler error:", 1)[-1] if "WeightsUnpickler error:" in text else ""
            detail = next((line.strip() for line in after.splitlines() if line.strip()), "not a torch checkpoint")
            raise InputError(f"{path}: not a readable prior checkpoint ({detail[:200]})") from None
        raise InputError(f"{path}: not a readable prior checkpoint ({one_line(exc)})") from None


def load_prior(run_dir: str | Path, device=None) -> Prior:
    """The trained prior of a run (for generation): a Prior, or an SDPrior for the sd backend."""
    payload = read_prior_checkpoint(run_dir, device)
    prior = build_prior(payload["backend"], payload["config"], device, str(prior_dir(run_dir) / CHECKPOINT_NAME))
    prior.load_checkpoint_state(payload["model"])
    return prior


def resume_trainer(run_dir: str | Path, gaussians: Gaussians, cameras: list[Camera],
                   load_image: Callable[[int], np.ndarray], device=None) -> PriorTrainer:
    """A trainer continuing exactly where RUN/prior/prior.pt left off."""
    payload = read_prior_checkpoint(run_dir, device)
    prior = build_prior(payload["backend"], payload["config"], device, str(prior_dir(run_dir) / CHECKPOINT_NAME))
    prior.load_checkpoint_state(payload["model"])
    trainer = PriorTrainer(prior, gaussians, cameras, load_image, step_count=int(payload["step"]),
                           losses=list(payload["losses"]), train_s=float(payload.get("train_s", 0.0)))
    trainer.optimizer.load_state_dict(payload["optimizer"])
    trainer.generator.set_state(payload["generator"])
    return trainer


def sampling_options(prior, start: float | None, init: str | None, where) -> dict:
    """--start / --init checked against the prior -> keyword arguments for prior.generate."""
    options = {}
    if (start is not None or init is not None) and prior.backend != "tiny":
        raise InputError(f"{where}: --start and --init are for the tiny backend")
    if init is not None:
        options["init"] = init
    if start is not None:
        if not 0.0 < start <= 1.0:
            raise InputError(f"--start: must be in (0, 1], got {start}")
        options["start"] = start
    init = options.get("init", getattr(prior.config, "sample_init", "hint"))
    start = options.get("start", getattr(prior.config, "sample_start", 1.0))
    if start < 1.0 and init == "hint" and getattr(prior, "appearance", None) is None:
        raise InputError(f"{where}: starting from the hint needs a prior with an appearance hint "
                         "(trained with --appearance-weight > 0); use --init render")
    return options
