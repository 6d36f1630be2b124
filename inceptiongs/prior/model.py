"""The prior as one object: hash grid + conditional denoiser + noise schedule, and its config.

Images are in [-1, 1] inside the diffusion model (photos in [0, 1] are mapped by 2x - 1).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np
import torch
from torch import nn

from ..camera import Camera
from ..gaussians import Gaussians
from ..io.config_json import dataclass_from_dict
from ..io.limits import check_allocation
from .appearance import HINT_CHANNELS, AppearanceHead
from .controlnet import ConditionalDenoiser
from .ddim import start_timestep
from .footprint import check_sampling_fits, denoiser_size
from .gbuffer import FEATURES_START, HASH_AT, gbuffer_channels, render_gbuffer
from .hashgrid import HashGrid, HashGridConfig, scene_grid
from .multidiffusion import multidiffusion_sample
from .schedule import make_schedule, q_sample
from .unet import UNetConfig

# The hash grid box is fitted to this quantile of the Gaussians' |coordinates|, so a few far
# floaters do not stretch the box (and waste resolution); points beyond it are clamped onto it.
BOUND_QUANTILE = 0.99
# Margin on the fitted box, and a floor for degenerate (single-point) scenes.
BOUND_MARGIN = 1.05
BOUND_MIN = 1e-3
# The contraction's core (hashgrid.contract) holds this quantile of the Gaussians' |coordinates|
# (the object the cameras surround; captures carry a far background), widened by the margin so
# the core's edge is not on the object.
CONTRACT_QUANTILE = 0.5
CONTRACT_MARGIN = 1.5
SAMPLE_INITS = ("render", "hint")
PREDICTIONS = ("epsilon", "v")


@dataclass(frozen=True)
class PriorConfig:
    patch_size: int = 64
    batch_size: int = 4
    learning_rate: float = 2e-4
    hash_learning_rate: float = 1e-2
    schedule: str = "cosine"
    num_timesteps: int = 1000
    seed: int = 0
    hash_at: str = "surface"     # where the hash grid is evaluated: "surface" | "centres" (gbuffer.py)
    prediction: str = "epsilon"  # what the UNet outputs: "epsilon" | "v" (see Prior.eps)
    # This share of every batch draws t from [high_noise_t T, T) instead of [0, T): there the
    # noisy image holds (almost) nothing, so only the G-buffer can lower the loss, which keeps
    # the condition branch in use (docs/prior.md: uniform t alone let the samples ignore it).
    high_noise_share: float = 0.0
    high_noise_t: float = 0.8
    # Weight of the appearance hint's L1 loss against the photo (appearance.py); 0 = no hint
    # (the denoiser then sees the bare G-buffer, as priors made before the option did).
    appearance_weight: float = 1.0
    # The hint's MLP is a neural-texture decoder beside a hash grid: it needs Instant-NGP-like
    # rates, not the denoiser's (at 2e-4 the hint was still a blur after 5 minutes on statuette).
    appearance_learning_rate: float = 5e-3
    # Where generation starts, as a fraction of T: 1 = pure noise; below 1 the appearance
    # hint noised to that level (SDEdit), so the sample keeps the hint's layout (needs the hint).
    # Statuette, 5-minute priors: 0.3 beat 0.5 on PSNR and SSIM for both view groups, and pure
    # noise gave noise (docs/prior.md).
    sample_start: float = 0.3
    # What a start below 1 noises: "render" (the Gaussians' own render of the view: the prior
    # repairs what the scene shows, the generative-bootstrapping step) or "hint" (the appearance
    # hint: an image from the G-buffer alone). Statuette, 15-minute prior, held-out views: from
    # the render the scarce views' SSIM rises above the render's (0.49 vs 0.47), from the hint it
    # falls to 0.36 (docs/prior.md).
    sample_init: str = "render"
    unet: UNetConfig = field(default_factory=UNetConfig)
    grid: HashGridConfig = field(default_factory=scene_grid)

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(data: dict, source: str = "prior checkpoint") -> "PriorConfig":
        """Strict (unknown keys are an error); fields added after a checkpoint was written take
        the value that checkpoint was trained with (LEGACY_DEFAULTS), not today's default."""
        data = {**PRIOR_LEGACY_DEFAULTS, **data}
        unet = dict(data.pop("unet"))
        unet["channel_mults"] = tuple(unet["channel_mults"])
        return dataclass_from_dict(PriorConfig, {
            **data, "unet": dataclass_from_dict(UNetConfig, unet, source, "prior unet config"),
            "grid": dataclass_from_dict(HashGridConfig, data.pop("grid"), source, "prior hash grid config"),
        }, source, "prior config")


# What a checkpoint written before a field existed was trained with.
PRIOR_LEGACY_DEFAULTS = {
    "hash_at": "centres",            # before the option, hash features were splatted at centres
    "prediction": "epsilon",
    "high_noise_share": 0.0,
    "high_noise_t": 0.8,
    "appearance_weight": 0.0,        # no hint head before the option
    "sample_start": 1.0,
    "sample_init": "hint",           # priors from before the option started from the hint
    "appearance_learning_rate": 5e-3,
}


def fit_bound(means: torch.Tensor, quantile: float = BOUND_QUANTILE, margin: float = BOUND_MARGIN) -> float:
    """Half-size of a box holding ``quantile`` of the Gaussians ``means`` [N, 3] (normalised
    frame), times ``margin``."""
    if means.shape[0] == 0:
        return 1.0
    extent = means.detach().abs().amax(dim=1).float().cpu().numpy()
    return max(float(np.quantile(extent, quantile)) * margin, BOUND_MIN)


def fit_grid(grid: HashGridConfig, means: torch.Tensor) -> HashGridConfig:
    """``grid`` fitted to the Gaussians: a contraction core around half of them and the box
    [-2R, 2R]^3 when grid.contract_radius > 0 (the default), else a box around 99 % of them."""
    if grid.contract_radius > 0:
        radius = fit_bound(means, CONTRACT_QUANTILE, CONTRACT_MARGIN)
        return replace(grid, contract_radius=radius, bound=2.0 * radius)
    return replace(grid, bound=fit_bound(means))


def denoiser_cond_channels(config: PriorConfig) -> int:
    """The channels the denoiser's condition branch sees: the G-buffer (normal, alpha, hash
    features) and the appearance hint when the prior has one."""
    hint = HINT_CHANNELS if config.appearance_weight > 0 else 0
    return FEATURES_START + config.grid.num_features + hint


class Prior(nn.Module):
    """denoiser: ConditionalDenoiser; hash_grid: HashGrid; schedule: NoiseSchedule.

    The interface the trainer, the checkpoints and generation use (shared with the sd backend,
    sd_backend.SDPrior): backend, config, patch_multiple, parameter_groups(), checkpoint_state(),
    load_checkpoint_state(), gbuffer(), diffusion_loss(), generate()."""

    backend = "tiny"

    def __init__(self, config: PriorConfig, source: str = "prior config"):
        """``source`` names where the config came from in the one-line refusal of a denoiser
        too large for the memory (a checkpoint's path, the command's flags)."""
        super().__init__()
        factor = config.unet.downsample_factor
        if config.prediction not in PREDICTIONS:
            raise ValueError(f"prediction must be one of {PREDICTIONS}, got {config.prediction!r}")
        if not 0.0 <= config.high_noise_share <= 1.0 or not 0.0 <= config.high_noise_t < 1.0:
            raise ValueError(f"high_noise_share must be in [0, 1] and high_noise_t in [0, 1), got "
                             f"{config.high_noise_share}, {config.high_noise_t}")
        if config.appearance_weight < 0.0 or not 0.0 < config.sample_start <= 1.0:
            raise ValueError(f"appearance_weight must be >= 0 and sample_start in (0, 1], got "
                             f"{config.appearance_weight}, {config.sample_start}")
        if config.sample_init not in SAMPLE_INITS:
            raise ValueError(f"sample_init must be one of {SAMPLE_INITS}, got {config.sample_init!r}")
        if config.sample_start < 1.0 and config.sample_init == "hint" and config.appearance_weight == 0.0:
            raise ValueError("sample_start < 1 with sample_init 'hint' starts from the appearance hint: "
                             "it needs appearance_weight > 0")
        if config.hash_at not in HASH_AT:
            raise ValueError(f"hash_at must be one of {HASH_AT}, got {config.hash_at!r}")
        if config.patch_size < factor or config.patch_size % factor:
            raise ValueError(f"patch_size {config.patch_size} must be a positive multiple of {factor}")
        weights = denoiser_size(config.unet, denoiser_cond_channels(config)).parameters * 4
        check_allocation(weights, source, f"the prior's denoiser (width {config.unet.base_width})")
        self.config = config
        self.hash_grid = HashGrid(config.grid, seed=config.seed)
        # The initial weights follow the seed, without disturbing the caller's global RNG.
        cond_channels = gbuffer_channels(self.hash_grid)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            self.appearance = AppearanceHead(cond_channels) if config.appearance_weight > 0 else None
            hint = HINT_CHANNELS if self.appearance is not None else 0
            self.denoiser = ConditionalDenoiser(config.unet, cond_channels + hint)
        self.schedule = make_schedule(config.schedule, config.num_timesteps)

    @staticmethod
    def for_gaussians(config: PriorConfig, gaussians: Gaussians, source: str = "prior config") -> "Prior":
        """A new prior whose hash grid (contraction core, box) is fitted to ``gaussians``."""
        return Prior(replace(config, grid=fit_grid(config.grid, gaussians.means)), source)

    @property
    def device(self) -> torch.device:
        return self.hash_grid.tables[0].device

    @property
    def patch_multiple(self) -> int:
        """Training patches and generation windows must be multiples of this (pixels)."""
        return self.config.unet.downsample_factor

    def parameter_groups(self) -> list[dict]:
        """Adam groups: the denoiser, the appearance hint's MLP (when there is one) and the hash
        tables (marked "hash": their own lr and eps)."""
        groups = [{"params": list(self.denoiser.parameters()), "lr": self.config.learning_rate}]
        if self.appearance is not None:
            groups.append({"params": list(self.appearance.parameters()),
                           "lr": self.config.appearance_learning_rate})
        return groups + [{"params": list(self.hash_grid.parameters()), "lr": self.config.hash_learning_rate,
                          "hash": True}]

    def checkpoint_state(self) -> dict:
        """What a checkpoint stores: every weight (the tiny backend trains all of them)."""
        return self.state_dict()

    def load_checkpoint_state(self, state: dict) -> None:
        self.load_state_dict(state)

    def gbuffer(self, gaussians: Gaussians, camera: Camera, crop=None,
                features: torch.Tensor | None = None) -> torch.Tensor:
        """[4 + Z, H, W] (see gbuffer.render_gbuffer; features from gaussian_features may be shared)."""
        return render_gbuffer(gaussians.to(self.device), camera, self.hash_grid, crop=crop, features=features,
                              hash_at=self.config.hash_at)

    def hint(self, cond: torch.Tensor) -> torch.Tensor:
        """The appearance hint [B, 3, H, W] in (-1, 1) for G-buffers cond [B, 4 + Z, H, W]."""
        if self.appearance is None:
            raise ValueError("this prior has no appearance hint (appearance_weight = 0)")
        return self.appearance(cond)

    def denoiser_condition(self, cond: torch.Tensor | None, hint: torch.Tensor | None = None) -> torch.Tensor | None:
        """What the denoiser's branch sees: the G-buffer, plus the (detached) hint when there is
        one (``hint``: already computed for cond). Detached: the hint stays the L1 colour guess;
        the diffusion loss shapes the branch."""
        if cond is None or self.appearance is None:
            return cond
        hint = self.appearance(cond) if hint is None else hint
        return torch.cat([cond, hint.detach()], dim=1)

    def _signal_noise_scales(self, t: torch.Tensor, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(sqrt(alpha_bar_t), sqrt(1 - alpha_bar_t)) as [B, 1, 1, 1] in ``like``'s dtype."""
        alpha_bar = self.schedule.alphas_cumprod.to(like.device)[t].to(like.dtype).view(-1, 1, 1, 1)
        return alpha_bar.sqrt(), (1.0 - alpha_bar).sqrt()  # alpha_bar in (0, 1): both real and > 0

    def eps(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor | None) -> torch.Tensor:
        """The noise estimate DDIM consumes, [B, 3, h, w], whatever the UNet is trained to output.

        "epsilon": the UNet's output. "v": the UNet predicts v = sqrt(ab) eps - sqrt(1 - ab) x0
        (Salimans & Ho 2022) and eps = sqrt(1 - ab) x_t + sqrt(ab) v. With epsilon, DDIM's x0
        estimate (x_t - sqrt(1 - ab) eps) / sqrt(ab) multiplies the network's error by up to
        1 / sqrt(ab) (2e4 at t = T - 1 of the cosine schedule); with v it is
        x0 = sqrt(ab) x_t - sqrt(1 - ab) v, whose error is never larger than v's."""
        out = self.denoiser(x, t, self.denoiser_condition(cond))
        if self.config.prediction == "epsilon":
            return out
        signal, noise = self._signal_noise_scales(t, x)
        return noise * x + signal * out

    def diffusion_loss(self, images: torch.Tensor, cond: torch.Tensor,
                       generator: torch.Generator | None = None) -> torch.Tensor:
        """MSE of the UNet's prediction (epsilon or v, config.prediction) at timesteps uniform
        in [0, T) (in [0, round(sample_start (T - 1))] when sampling starts there; the first
        round(high_noise_share B) of the batch in the top (1 - high_noise_t) of that range),
        plus appearance_weight x the hint's mean L1 error against the images (when there is a
        hint and a condition).
        images: [B, 3, s, s] in [-1, 1]; cond: [B, 4 + Z, s, s]. generator (CPU) makes t and
        the noise reproducible."""
        batch = images.shape[0]
        # Sampling that starts at sample_start x T never asks for a later timestep, so training
        # spends no capacity there (the whole range when sampling starts from noise).
        total = start_timestep(self.schedule, self.config.sample_start) + 1
        t = torch.randint(0, total, (batch,), generator=generator)
        high = round(self.config.high_noise_share * batch)
        if high:
            low = min(int(self.config.high_noise_t * total), total - 1)
            t[:high] = torch.randint(low, total, (high,), generator=generator)
        noise = torch.randn(images.shape, generator=generator).to(images)
        t = t.to(images.device)
        noisy = q_sample(self.schedule, images, t, noise)
        if self.config.prediction == "epsilon":
            target = noise
        else:
            signal, noise_scale = self._signal_noise_scales(t, images)
            target = signal * noise - noise_scale * images
        hint = self.appearance(cond) if cond is not None and self.appearance is not None else None
        loss = (self.denoiser(noisy, t, self.denoiser_condition(cond, hint)) - target).pow(2).mean()
        if hint is not None:
            loss = loss + self.config.appearance_weight * (hint - images).abs().mean()
        return loss

    @torch.no_grad()
    def generate(self, gaussians: Gaussians, camera: Camera, steps: int = 20, seed: int = 0,
                 window: int | None = None, stride: int | None = None,
                 progress: bool = False, start: float | None = None,
                 init: str | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """A generated image for any viewpoint: (rgb [H, W, 3] in [0, 1], the G-buffer [4 + Z, H, W]).
        Windows default to the training patch size, stride to 3/4 of it (1/4 overlap).
        start (default config.sample_start): below 1, sampling starts from an image noised to
        start x T (SDEdit): init (default config.sample_init) "render", the Gaussians' render of
        the view, or "hint", the appearance hint (both per pixel, computed for the whole image)."""
        window = self.config.patch_size if window is None else window
        stride = max(1, window * 3 // 4) if stride is None else stride
        start = self.config.sample_start if start is None else float(start)
        init = self.config.sample_init if init is None else init
        if init not in SAMPLE_INITS:
            raise ValueError(f"init must be one of {SAMPLE_INITS}, got {init!r}")
        check_sampling_fits(self.config.unet, denoiser_cond_channels(self.config), camera.height, camera.width,
                            window, f"generation window {window}", self.device)
        cond = self.gbuffer(gaussians, camera)
        image0 = None
        if start < 1.0:
            image0 = self.hint(cond[None]) if init == "hint" else render_init(gaussians, camera).to(cond)
        image = multidiffusion_sample(self.eps, self.schedule, camera.height, camera.width,
                                      cond=cond[None], window=window, stride=stride, steps=steps,
                                      seed=seed, device=self.device, progress=progress, init=image0,
                                      start=start)
        return ((image[0].permute(1, 2, 0) + 1.0) * 0.5).clamp(0.0, 1.0), cond


def render_init(gaussians: Gaussians, camera: Camera) -> torch.Tensor:
    """The Gaussians' render of camera as a sampler start [1, 3, H, W] in [-1, 1] (black
    background, like the evaluation's renders)."""
    from ..rasterizer.interface import render_rgb

    return (render_rgb(gaussians, camera) * 2.0 - 1.0).permute(2, 0, 1)[None]
