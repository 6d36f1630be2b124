"""The `sd` backend: Stable Diffusion 1.5 + a ControlNet (through diffusers) as the prior.

The frozen base (UNet2DConditionModel and AutoencoderKL) comes from a local diffusers folder
the user gives; nothing is downloaded. What is trained, per scene, is the same thing the tiny
backend trains around its denoiser: a ControlNet on the same G-buffer (normal, alpha, hash
features), the hash grid, and a null prompt embedding. Diffusion runs on the VAE's latents
(x scaling_factor); sampling is the shared DDIM + MultiDiffusion code with windows in latent
space (the G-buffer windows are the same windows at pixel scale) and x0 not clipped (latents
have no fixed range).

Folder layout read (the diffusers layout of an SD 1.5 checkout):
    DIR/unet/        config.json + weights      (required)
    DIR/vae/         config.json + weights      (required)
    DIR/controlnet/  a ControlNetModel          (optional; else initialised from the UNet's
                                                 encoder, as ControlNet does)
    DIR/scheduler/scheduler_config.json         (optional; else SD's scaled_linear 0.00085-0.012)
    DIR/null_prompt_embedding.pt                (optional; [1, L, D] tensor, e.g. CLIP's output for
                                                 the empty prompt; else zeros, then learned)
No text encoder is loaded: the prior is conditioned on geometry, not words, so one learned
prompt embedding stands in for the text (the tokenizer/text encoder, and transformers, are
not needed).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch
from torch import nn

from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians
from ..io.config_json import dataclass_from_dict
from .gbuffer import gbuffer_channels, render_gbuffer
from .hashgrid import HashGrid, HashGridConfig, scene_grid
from .model import fit_grid
from .multidiffusion import multidiffusion_sample
from .schedule import make_schedule, q_sample

# SD 1.5's defaults where the folder has no scheduler config (the frozen UNet only denoises
# correctly under the schedule it was trained with).
SD_SCHEDULE = {"beta_schedule": "scaled_linear", "beta_start": 0.00085, "beta_end": 0.012,
               "num_train_timesteps": 1000}
# ControlNet's hint-encoder widths for SD (3 stride-2 stages: the VAE's factor 8); shorter VAEs
# use a prefix, longer ones repeat the last width.
HINT_WIDTHS = (16, 32, 96, 256)
NULL_PROMPT_FILE = "null_prompt_embedding.pt"
# CLIP's context length in SD 1.5: the frozen cross-attention was trained on 77 tokens.
PROMPT_TOKENS = 77
FROZEN_PREFIXES = ("unet.", "vae.")


@dataclass(frozen=True)
class SDPriorConfig:
    sd_path: str = ""
    patch_size: int = 256
    batch_size: int = 1
    learning_rate: float = 1e-5       # ControlNet's usual rate
    hash_learning_rate: float = 1e-2
    prompt_learning_rate: float = 1e-3
    seed: int = 0
    hash_at: str = "surface"          # where the hash grid is evaluated (gbuffer.py)
    grid: HashGridConfig = field(default_factory=scene_grid)

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(data: dict, source: str = "prior checkpoint") -> "SDPriorConfig":
        """Strict, as PriorConfig.from_dict; checkpoints from before ``hash_at`` splatted centres."""
        data = {"hash_at": "centres", **data}
        grid = dataclass_from_dict(HashGridConfig, data.pop("grid"), source, "prior hash grid config")
        return dataclass_from_dict(SDPriorConfig, {**data, "grid": grid}, source, "sd prior config")


def _diffusers():
    try:
        import diffusers
    except ImportError:
        raise InputError("the sd prior backend needs diffusers: pip install 'inceptiongs[diffusers]'") from None
    return diffusers


def _load_model(cls, folder: Path):
    if not (folder / "config.json").is_file():
        raise InputError(f"{folder}: missing (the sd backend reads a diffusers folder with unet/ and vae/)")
    try:
        # low_cpu_mem_usage=False: the lazy loader needs accelerate, which the extra does not carry.
        return cls.from_pretrained(str(folder), local_files_only=True, low_cpu_mem_usage=False)
    except (OSError, ValueError, TypeError, KeyError, RuntimeError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise InputError(f"{folder}: not a readable diffusers {cls.__name__} ({first})") from None


def read_schedule(root: Path):
    """The noise schedule of the base model (DIR/scheduler/scheduler_config.json or SD's)."""
    import json

    path = root / "scheduler" / "scheduler_config.json"
    settings = dict(SD_SCHEDULE)
    if path.is_file():
        try:
            settings.update(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: unreadable scheduler config ({exc})") from None
    if settings.get("prediction_type", "epsilon") != "epsilon":
        raise InputError(f"{path}: prediction_type {settings['prediction_type']!r} is not supported "
                         "(the prior predicts epsilon, as SD 1.5 does)")
    kind = {"squaredcos_cap_v2": "cosine"}.get(settings["beta_schedule"], settings["beta_schedule"])
    try:
        return make_schedule(kind, int(settings["num_train_timesteps"]), float(settings["beta_start"]),
                             float(settings["beta_end"]))
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None


def downsample_factor(block_count: int) -> int:
    """Spatial factor of a diffusers encoder with ``block_count`` blocks (one fewer downsamples)."""
    return 2 ** (block_count - 1)


class SDPrior(nn.Module):
    """Frozen SD UNet + VAE, trainable ControlNet + hash grid + null prompt (see module doc).

    Same interface as model.Prior: eps(x_t, t, cond) is the denoiser on latents
    [B, 4, h, w] with the G-buffer cond [B, 4 + Z, h * f, w * f] (f: the VAE's factor)."""

    backend = "sd"

    def __init__(self, config: SDPriorConfig, device=None):
        super().__init__()
        diffusers = _diffusers()
        root = Path(config.sd_path)
        if not root.is_dir():
            raise InputError(f"{root}: Stable Diffusion folder does not exist (--sd-path)")
        self.config = config
        self.unet = _load_model(diffusers.UNet2DConditionModel, root / "unet")
        self.vae = _load_model(diffusers.AutoencoderKL, root / "vae")
        if self.unet.config.in_channels != self.vae.config.latent_channels:
            raise InputError(f"{root}: UNet takes {self.unet.config.in_channels} channels but the VAE's latents "
                             f"have {self.vae.config.latent_channels}")
        for frozen in (self.unet, self.vae):
            frozen.requires_grad_(False)
            frozen.eval()
        self.vae_factor = downsample_factor(len(self.vae.config.block_out_channels))
        self.unet_factor = downsample_factor(len(self.unet.config.down_block_types))
        self.scaling_factor = float(self.vae.config.scaling_factor)
        self.schedule = read_schedule(root)
        self.hash_grid = HashGrid(config.grid, seed=config.seed)
        cond_channels = gbuffer_channels(self.hash_grid)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            self.controlnet = self._controlnet(diffusers, root, cond_channels)
            self.null_prompt = nn.Parameter(self._null_prompt(root))
        self.to(device)

    def _controlnet(self, diffusers, root: Path, cond_channels: int) -> nn.Module:
        """DIR/controlnet when present (its first hint conv re-made for the G-buffer's channels),
        else ControlNet's initialisation: a copy of the UNet's encoder, zero convs at the joins."""
        levels = round(math.log2(self.vae_factor)) + 1
        widths = tuple(HINT_WIDTHS[:levels]) + (HINT_WIDTHS[-1],) * max(0, levels - len(HINT_WIDTHS))
        if not (root / "controlnet").is_dir():
            return diffusers.ControlNetModel.from_unet(self.unet, conditioning_embedding_out_channels=widths,
                                                       conditioning_channels=cond_channels)
        controlnet = _load_model(diffusers.ControlNetModel, root / "controlnet")
        hint = controlnet.controlnet_cond_embedding
        strides = sum(1 for conv in hint.blocks if conv.stride[0] == 2)
        if 2 ** strides != self.vae_factor:
            raise InputError(f"{root / 'controlnet'}: its hint encoder downsamples by {2 ** strides}, "
                             f"the VAE by {self.vae_factor}")
        if hint.conv_in.in_channels != cond_channels:
            hint.conv_in = nn.Conv2d(cond_channels, hint.conv_in.out_channels, 3, padding=1)
        return controlnet

    def _null_prompt(self, root: Path) -> torch.Tensor:
        """[1, L, D]: DIR/null_prompt_embedding.pt, else zeros (learned from there)."""
        dim = self.unet.config.cross_attention_dim
        path = root / NULL_PROMPT_FILE
        if not path.is_file():
            return torch.zeros(1, PROMPT_TOKENS, dim)
        try:
            embedding = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # a foreign or truncated file: the user's input
            raise InputError(f"{path}: not a readable tensor file ({type(exc).__name__})") from None
        if not isinstance(embedding, torch.Tensor) or embedding.ndim != 3 or embedding.shape[0] != 1 \
                or embedding.shape[2] != dim:
            raise InputError(f"{path}: expected a [1, L, {dim}] tensor")
        return embedding.float()

    @staticmethod
    def for_gaussians(config: SDPriorConfig, gaussians: Gaussians, device=None) -> "SDPrior":
        """A new prior whose hash grid (contraction core, box) is fitted to ``gaussians``."""
        return SDPrior(replace(config, grid=fit_grid(config.grid, gaussians.means)), device)

    @property
    def device(self) -> torch.device:
        return self.null_prompt.device

    @property
    def patch_multiple(self) -> int:
        """Pixels: the VAE's factor times the UNet's (a patch's latent must pass every UNet level)."""
        return self.vae_factor * self.unet_factor

    def parameter_groups(self) -> list[dict]:
        return [{"params": list(self.controlnet.parameters()), "lr": self.config.learning_rate},
                {"params": [self.null_prompt], "lr": self.config.prompt_learning_rate},
                {"params": list(self.hash_grid.parameters()), "lr": self.config.hash_learning_rate,
                 "hash": True}]

    def checkpoint_state(self) -> dict:
        """The trained weights only: the frozen base stays in the user's folder."""
        return {k: v for k, v in self.state_dict().items() if not k.startswith(FROZEN_PREFIXES)}

    def load_checkpoint_state(self, state: dict) -> None:
        result = self.load_state_dict(state, strict=False)
        missing = [k for k in result.missing_keys if not k.startswith(FROZEN_PREFIXES)]
        if missing or result.unexpected_keys:
            raise InputError(f"prior checkpoint does not match the sd model in {self.config.sd_path} "
                             f"(missing {missing[:3]}, unexpected {result.unexpected_keys[:3]})")

    def gbuffer(self, gaussians: Gaussians, camera: Camera, crop=None,
                features: torch.Tensor | None = None) -> torch.Tensor:
        """[4 + Z, H, W] (see gbuffer.render_gbuffer)."""
        return render_gbuffer(gaussians.to(self.device), camera, self.hash_grid, crop=crop, features=features,
                              hash_at=self.config.hash_at)

    def encode(self, images: torch.Tensor) -> torch.Tensor:
        """images [B, 3, H, W] in [-1, 1] -> scaled latents [B, C, H/f, W/f]. The posterior mean
        (not a sample), so a step's loss depends only on the trainer's generator."""
        with torch.no_grad():
            return self.vae.encode(images).latent_dist.mean * self.scaling_factor

    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        """scaled latents [B, C, h, w] -> images [B, 3, h f, w f] in [-1, 1]."""
        with torch.no_grad():
            return self.vae.decode(latents / self.scaling_factor).sample.clamp(-1.0, 1.0)

    def eps(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor | None = None) -> torch.Tensor:
        """Noise prediction on latents x [B, C, h, w]; cond [B, 4 + Z, h f, w f] or None (base only)."""
        prompt = self.null_prompt.expand(x.shape[0], -1, -1).to(x.dtype)
        if cond is None:
            return self.unet(x, t, encoder_hidden_states=prompt, return_dict=False)[0]
        down, middle = self.controlnet(x, t, encoder_hidden_states=prompt, controlnet_cond=cond.to(x.dtype),
                                       return_dict=False)
        return self.unet(x, t, encoder_hidden_states=prompt, down_block_additional_residuals=down,
                         mid_block_additional_residual=middle, return_dict=False)[0]

    def diffusion_loss(self, images: torch.Tensor, cond: torch.Tensor,
                       generator: torch.Generator | None = None) -> torch.Tensor:
        """Epsilon MSE on the latents of images [B, 3, s, s] in [-1, 1]; cond [B, 4 + Z, s, s]."""
        latents = self.encode(images)
        batch = latents.shape[0]
        t = torch.randint(0, self.schedule.num_timesteps, (batch,), generator=generator)
        noise = torch.randn(latents.shape, generator=generator).to(latents)
        t = t.to(latents.device)
        noisy = q_sample(self.schedule, latents, t, noise)
        return (self.eps(noisy, t, cond) - noise).pow(2).mean()

    @torch.no_grad()
    def generate(self, gaussians: Gaussians, camera: Camera, steps: int = 20, seed: int = 0,
                 window: int | None = None, stride: int | None = None,
                 progress: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """(rgb [H, W, 3] in [0, 1], the G-buffer [4 + Z, H, W]). window/stride in pixels
        (window a multiple of patch_multiple; default the training patch size, stride 3/4 of it);
        MultiDiffusion runs on the latent grid, the image is decoded once at the end."""
        f = self.vae_factor
        window = self.config.patch_size if window is None else window
        if window < self.patch_multiple or window % self.patch_multiple:
            raise ValueError(f"window {window} must be a positive multiple of {self.patch_multiple}")
        stride = max(1, window * 3 // 4) if stride is None else stride
        cond = self.gbuffer(gaussians, camera)
        height, width = camera.height, camera.width
        # The latent grid covers the image rounded up to whole latent pixels; the extra border
        # has an empty G-buffer (no surface) and is cropped after decoding.
        latent_h, latent_w = -(-height // f), -(-width // f)
        padded = nn.functional.pad(cond, (0, latent_w * f - width, 0, latent_h * f - height))
        latents = multidiffusion_sample(self.eps, self.schedule, latent_h, latent_w, cond=padded[None],
                                        channels=self.unet.config.in_channels, window=window // f,
                                        stride=max(1, stride // f), steps=steps, seed=seed,
                                        batch_windows=4, device=self.device, progress=progress,
                                        cond_scale=f, clip_sample=False)
        image = self.decode(latents)[0, :, :height, :width]
        return ((image.permute(1, 2, 0) + 1.0) * 0.5).clamp(0.0, 1.0), cond
