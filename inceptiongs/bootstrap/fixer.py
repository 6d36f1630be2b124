"""A scene-adaptive fixer: a small image-to-image network trained per scene, from scratch, on
pairs the scene itself provides -- a degraded render at a training pose and the photo there --
so that at a virtual view it can turn the render into (part of) I*.

The pieces, each a small function:

* ways to make the degraded side: renders of an earlier, underfit stage-I
  checkpoint (``"underfit"``), renders of the model with its least visible Gaussians dropped
  (``"fewer"``, :func:`fewer_gaussians`), or any render function a caller supplies (a model
  trained with a photo and its neighbours left out is one);
* :func:`build_pairs`: (degraded, photo) at the given views; :class:`KeptPairs` the same made
  when asked, as many kept as a byte budget holds (the fixer's training set on a large capture);
* :func:`held_out_views`: the training views held out of the fixer's training, the most isolated
  camera centres first -- poses like the scarce ones, whose nearest photo stands far away;
* :func:`train_fixer`: the network (prior.unet.UNet, timestep fixed at 0, predicting a residual
  added to the render; its last layer starts at zero, so an untrained fixer returns the render);
* :func:`held_out_check`: PSNR of the fixed render and of the render itself against photos the
  fixer never trained on; the loop may use the fixer only where it beats the render by
  ``margin_db``;
* :func:`error_spectrum`, :func:`spectrum_distance`: the radially binned power spectrum of a
  render's error, to measure which way of degrading resembles the scarce views' errors.
"""

from __future__ import annotations

import collections
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import torch
from torch.nn import functional as F

from ..gaussians import Gaussians
from ..prior.unet import UNet, UNetConfig

# Squared error below this is treated as this: PSNR of a perfect image is then 100 dB, never inf.
MSE_FLOOR = 1e-10
# The held-out check's default margin: the fixer must beat the render by this much (dB) on
# average over the held-out photos (below it the difference is within a run's noise).
CHECK_MARGIN_DB = 0.1


@dataclass(frozen=True)
class FixerPair:
    """degraded: [H, W, 3 + G] float32 in [0, 1], the degraded render and G guide channels (none,
    or the nearest photos' blend and its mask: a guided fixer); photo: [H, W, 3]; at training
    view ``view``."""

    view: int
    degraded: torch.Tensor
    photo: torch.Tensor


@dataclass(frozen=True)
class FixerSettings:
    """steps: optimiser steps; crop: square training crop side (pixels, a multiple of 4);
    batch: crops per step; lr: Adam's rate; width: the UNet's base width; seed; time_s: a time
    budget (None: none) -- the fixer's training is charged to the bootstrap's clock."""

    steps: int = 400
    crop: int = 48
    batch: int = 4
    lr: float = 2e-3
    width: int = 16
    seed: int = 0
    time_s: float | None = None


@dataclass
class FixerCheck:
    """Per held-out view: the render's and the fixed render's PSNR against the photo (dB); the
    fixer passes when its mean gain is at least ``margin_db``."""

    views: list[int]
    render_db: list[float]
    fixed_db: list[float]
    margin_db: float

    @property
    def gain_db(self) -> float:
        return float(np.mean(self.fixed_db) - np.mean(self.render_db)) if self.views else 0.0

    @property
    def passes(self) -> bool:
        return bool(self.views) and self.gain_db >= self.margin_db

    def words(self) -> str:
        if not self.views:
            return "fixer: no held-out photo to check it on -- not used"
        verdict = "used" if self.passes else "not used"
        return (f"fixer held-out check on {len(self.views)} photos: render {np.mean(self.render_db):.2f} dB, "
                f"fixed {np.mean(self.fixed_db):.2f} dB ({self.gain_db:+.2f}, margin {self.margin_db:+.2f}) -- {verdict}")


@dataclass
class TrainedFixer:
    """The network and its training record (loss per step, seconds, steps done)."""

    net: UNet
    losses: list[float] = field(default_factory=list)
    seconds: float = 0.0


def fewer_gaussians(gaussians: Gaussians, keep_fraction: float) -> Gaussians:
    """The ``keep_fraction`` of Gaussians with the largest opacity x footprint (the product of
    the two largest scales), the least visible dropped. keep_fraction in (0, 1]."""
    if not 0.0 < keep_fraction <= 1.0:
        raise ValueError(f"keep_fraction must be in (0, 1], got {keep_fraction}")
    n = len(gaussians)
    keep = max(1, int(round(n * keep_fraction)))
    scales = torch.sort(gaussians.log_scales, dim=1, descending=True).values
    # Ranked in log space: log sigmoid(o) + the two largest log scales (no exp to overflow).
    score = F.logsigmoid(gaussians.opacity_logits) + scales[:, 0] + scales[:, 1]
    index = torch.sort(torch.topk(score, keep).indices).values
    return gaussians.subset(index)


def build_pairs(render: Callable[[int], torch.Tensor], photos: dict, views: Sequence[int]) -> list[FixerPair]:
    """(degraded, photo) at each of ``views``: render(view) -> [H, W, 3] the degraded side;
    photos: view -> [H, W, 3] in [0, 1]. A view without a photo, or whose render's shape differs
    from its photo's, is a ValueError naming the view."""
    return [pair_at(render, photos, view) for view in views]


def pair_at(render: Callable[[int], torch.Tensor], photos, view: int) -> FixerPair:
    """The (degraded, photo) pair at ``view``, as build_pairs makes it."""
    if view not in photos:
        raise ValueError(f"fixer pairs: training view {view} has no photo")
    photo = torch.as_tensor(photos[view], dtype=torch.float32)
    degraded = torch.as_tensor(render(view), dtype=torch.float32).detach().clamp(0.0, 1.0)
    if (photo.ndim != 3 or photo.shape[-1] != 3 or degraded.ndim != 3 or degraded.shape[:2] != photo.shape[:2]
            or degraded.shape[-1] < 3):
        raise ValueError(f"fixer pairs: view {view}: render {tuple(degraded.shape)} and photo "
                         f"{tuple(photo.shape)} must be [H, W, 3 + G] and [H, W, 3]")
    return FixerPair(view, degraded.cpu(), photo.clamp(0.0, 1.0).cpu())


class KeptPairs(Sequence):
    """build_pairs(render, photos, views) made when asked: at most ``budget`` bytes of pairs are
    kept (least recently used first out, at least one), and a pair asked for again after it
    went is made again, to the same values (render must be deterministic, as a no-grad render is)."""

    def __init__(self, render: Callable[[int], torch.Tensor], photos, views: Sequence[int], budget: int):
        self.render, self.photos, self.views, self.budget = render, photos, list(views), budget
        for view in self.views:
            if view not in photos:
                raise ValueError(f"fixer pairs: training view {view} has no photo")
        self._kept: collections.OrderedDict[int, FixerPair] = collections.OrderedDict()
        self._kept_bytes = 0

    def __len__(self) -> int:
        return len(self.views)

    def __getitem__(self, index: int) -> FixerPair:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        view = self.views[index]
        pair = self._kept.get(view)
        if pair is not None:
            self._kept.move_to_end(view)
            return pair
        pair = pair_at(self.render, self.photos, view)
        size = pair_bytes(pair)
        while self._kept and self._kept_bytes + size > self.budget:
            _, old = self._kept.popitem(last=False)
            self._kept_bytes -= pair_bytes(old)
        self._kept[view] = pair
        self._kept_bytes += size
        return pair


def pair_bytes(pair: FixerPair) -> int:
    return (pair.degraded.numel() + pair.photo.numel()) * pair.photo.element_size()


def held_out_views(centres: np.ndarray, views: Sequence[int], count: int) -> list[int]:
    """The ``count`` views of ``views`` whose camera centre (centres: [N, 3], indexed by view)
    lies farthest from every other view's: the isolated poses, like the scarce ones."""
    views = list(views)
    if count <= 0 or len(views) < 2:
        return []
    points = np.asarray(centres, dtype=np.float64)[views]
    distance = np.linalg.norm(points[:, None] - points[None], axis=-1)
    np.fill_diagonal(distance, np.inf)
    isolation = distance.min(axis=1)
    order = np.argsort(-isolation, kind="stable")[:min(count, len(views) - 1)]
    return sorted(views[i] for i in order)


def fixer_network(width: int, in_channels: int = 3) -> UNet:
    """The UNet (two levels) with its output layer zeroed: an untrained fixer adds nothing.
    in_channels: 3 (the render) plus its guide channels; the output is always 3 (the residual
    added to the render)."""
    net = UNet(UNetConfig(image_channels=3, base_width=width, channel_mults=(1, 2), time_dim=16))
    if in_channels != 3:
        net.encoder.conv_in = torch.nn.Conv2d(in_channels, width, 3, padding=1)
    torch.nn.init.zeros_(net.decoder.conv_out.weight)
    torch.nn.init.zeros_(net.decoder.conv_out.bias)
    return net


def apply_fixer(net: UNet, render: torch.Tensor) -> torch.Tensor:
    """render [H, W, 3 + G] in [0, 1] (the render and the net's guide channels) -> the fixed
    render [H, W, 3] in [0, 1]. The image is padded
    (replicate) to the UNet's multiple and the residual is added in [-1, 1] space."""
    factor = net.config.downsample_factor
    h, w = render.shape[:2]
    x = render.permute(2, 0, 1)[None].to(next(net.parameters()).device)
    x = F.pad(x, (0, (-w) % factor, 0, (-h) % factor), mode="replicate")
    out = fixed_batch(net, x)[..., :h, :w]
    return out[0].permute(1, 2, 0).to(render.device)


def fixed_batch(net: UNet, x: torch.Tensor) -> torch.Tensor:
    """x: [B, 3 + G, H, W] in [0, 1] (render first) -> [B, 3, H, W] in [0, 1]: render + residual,
    clamped."""
    t = torch.zeros(x.shape[0], dtype=torch.long, device=x.device)
    return (x[:, :3] + net(x * 2.0 - 1.0, t)).clamp(0.0, 1.0)


def random_crops(pairs: Sequence[FixerPair], crop: int, batch: int, rng: np.random.Generator,
                 device) -> tuple[torch.Tensor, torch.Tensor]:
    """``batch`` random crops ([B, 3 + G, crop, crop] of degraded, [B, 3, crop, crop] of photo)
    from random pairs (an image smaller than ``crop`` is padded by replication first)."""
    degraded, photos = [], []
    for _ in range(batch):
        pair = pairs[int(rng.integers(len(pairs)))]
        both = torch.cat([pair.degraded, pair.photo], dim=-1).permute(2, 0, 1)[None]
        h, w = both.shape[-2:]
        both = F.pad(both, (0, max(0, crop - w), 0, max(0, crop - h)), mode="replicate")[0]
        y = int(rng.integers(both.shape[1] - crop + 1))
        x = int(rng.integers(both.shape[2] - crop + 1))
        window = both[:, y:y + crop, x:x + crop]
        degraded.append(window[:-3])
        photos.append(window[-3:])
    return torch.stack(degraded).to(device), torch.stack(photos).to(device)


def train_fixer(pairs: Sequence[FixerPair], settings: FixerSettings = FixerSettings(), device="cpu",
                log: Callable[[str], None] = lambda line: None) -> TrainedFixer:
    """The fixer trained on ``pairs`` with an L1 loss on random crops, for ``settings.steps`` steps
    or until ``settings.time_s`` has passed."""
    if not pairs:
        raise ValueError("fixer: no pairs to train on")
    if settings.crop % 2 or settings.crop < 8:
        raise ValueError(f"fixer: crop must be an even number of pixels >= 8, got {settings.crop}")
    torch.manual_seed(settings.seed)
    net = fixer_network(settings.width, pairs[0].degraded.shape[-1]).to(device)
    optimiser = torch.optim.Adam(net.parameters(), lr=settings.lr)
    rng = np.random.default_rng(settings.seed)
    trained, start = TrainedFixer(net), time.perf_counter()
    for step in range(settings.steps):
        if settings.time_s is not None and time.perf_counter() - start >= settings.time_s:
            break
        degraded, photo = random_crops(pairs, settings.crop, settings.batch, rng, device)
        loss = (fixed_batch(net, degraded) - photo).abs().mean()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        trained.losses.append(float(loss.detach()))
        if step % 100 == 0:
            log(f"fixer step {step}: L1 {trained.losses[-1]:.4f}")
    trained.seconds = time.perf_counter() - start
    net.eval()
    return trained


def psnr_db(image: torch.Tensor, reference: torch.Tensor) -> float:
    """PSNR (dB, peak 1) with the squared error floored at MSE_FLOOR: finite for equal images."""
    mse = float(((image.float() - reference.float()) ** 2).mean())
    return 10.0 * math.log10(1.0 / max(mse, MSE_FLOOR))


def held_out_check(net: UNet, pairs: Sequence[FixerPair], margin_db: float = CHECK_MARGIN_DB) -> FixerCheck:
    """The fixer against the render on held-out pairs (photos it never trained on)."""
    render_db, fixed_db = [], []
    with torch.no_grad():
        for pair in pairs:
            render_db.append(psnr_db(pair.degraded[..., :3], pair.photo))
            fixed_db.append(psnr_db(apply_fixer(net, pair.degraded).cpu(), pair.photo))
    return FixerCheck([p.view for p in pairs], render_db, fixed_db, margin_db)


def error_spectrum(render: torch.Tensor, photo: torch.Tensor, bins: int = 8) -> np.ndarray:
    """The render's error's power per radial frequency band: [bins] log10 of the mean power in
    each band of the grey error's 2-D FFT (each floored at MSE_FLOOR, so log10 is finite)."""
    error = (render.float() - photo.float()).mean(dim=-1).cpu().numpy()
    error = error - error.mean()
    power = np.abs(np.fft.fft2(error)) ** 2 / max(error.size, 1)
    fy = np.fft.fftfreq(error.shape[0])[:, None]
    fx = np.fft.fftfreq(error.shape[1])[None, :]
    radius = np.sqrt(fy ** 2 + fx ** 2) / (math.sqrt(0.5))        # 0 .. 1 (the corner frequency)
    band = np.minimum((radius * bins).astype(int), bins - 1)
    sums = np.bincount(band.ravel(), weights=power.ravel(), minlength=bins)
    counts = np.maximum(np.bincount(band.ravel(), minlength=bins), 1)
    return np.log10(np.maximum(sums / counts, MSE_FLOOR))


def spectrum_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Root mean square difference of two log-power spectra (decades): 0 when the errors have the
    same spectrum."""
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def fix_where_check_says(net: UNet | None, check: FixerCheck | None, render: torch.Tensor) -> torch.Tensor | None:
    """The fixed render where the held-out check passed, else None (the loop keeps its fill)."""
    if net is None or check is None or not check.passes:
        return None
    with torch.no_grad():
        return apply_fixer(net, render)
