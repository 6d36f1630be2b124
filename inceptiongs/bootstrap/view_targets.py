"""I* at a virtual view from the Gaussians as they are now: the fill (the prior's image, or the
render), the photos warped in over it (the supervision kind: ``supervise.py``), the agreement
gate, and the PNG of the view."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from ..camera import Camera
from ..gaussians import Gaussians
from ..io.images import write_png
from ..train.free_space import render_surface_depth
from .config import BootstrapConfig
from .source_depth import depth_from_training_views
from .supervise import ViewContext, supervise_view
from .generation import GenerationCache, ImagePrior, VirtualTarget, gaussians_version, generate_cached
from .virtual_views import DEFAULT_K, nearest_training_views


def view_png(generated: torch.Tensor, mask: torch.Tensor, target: torch.Tensor, render: torch.Tensor) -> np.ndarray:
    """generated | mask | I* | stage-I render, side by side: [H, 4W, 3] uint8."""
    panels = [generated, mask.expand(-1, -1, 3), target, render]
    image = torch.cat([p.detach().float().clamp(0, 1).cpu() for p in panels], dim=1).numpy()
    return np.round(image * 255.0).astype(np.uint8)


def blend_sources(camera: Camera, cameras: Sequence[Camera], train: Sequence[int],
                  config: BootstrapConfig) -> list[int]:
    """The K training photos nearest the virtual view (warped into it for blending)."""
    if not config.blending:
        return []
    return nearest_training_views(camera, cameras, list(train), config.k or DEFAULT_K)


class ModelRenders:
    """One render per (camera, output) of one model: the warps' depths, the fill, the PNGs.
    ``depths``: a dict the surface depths are kept in instead of this object's own, so that
    several makers share them (the pool's for one regeneration interval: pool.ViewPool.depths)."""

    def __init__(self, gaussians: Gaussians, rasterizer, sky, depths: dict | None = None) -> None:
        self.gaussians, self.rasterizer, self.sky = gaussians, rasterizer, sky
        self._cache: dict[tuple[str, str], torch.Tensor] = {}
        self._depths = self._cache if depths is None else depths

    def _cached(self, camera: Camera, output: str, compute: Callable[[], torch.Tensor],
                cache: dict | None = None) -> torch.Tensor:
        cache = self._cache if cache is None else cache
        key = (camera.name + str(camera.world_to_camera.tobytes()), output)
        if key not in cache:
            with torch.no_grad():
                cache[key] = compute()
        return cache[key]

    def forget(self) -> None:
        """Drop every kept render (a caller that visits many views once keeps none of them)."""
        self._cache.clear()
        self._depths.clear()

    def depth(self, camera: Camera) -> torch.Tensor:
        """[H, W, 1] the scene's own surface depth: the sky shell blended in pulls a faint
        surface's depth far behind it, and the warps then place the photos wrongly and reject them."""
        return self._cached(camera, "surface_depth",
                            lambda: render_surface_depth(self.gaussians, camera, self.sky, self.rasterizer),
                            self._depths)

    def rgb(self, camera: Camera) -> torch.Tensor:
        """[H, W, 3] float32 in [0, 1]."""
        render = self._cached(camera, "rgb", lambda: self.rasterizer(self.gaussians, camera, outputs=("rgb",))["rgb"])
        return render.float().clamp(0.0, 1.0)


@dataclass(frozen=True)
class TargetSetting:
    """What every virtual view's I* in a run is made with (fixed for the run): the scene's
    cameras, the training views, their photos (on the device I* is made on), the generation
    cache, the folder of the views' PNGs, the rasterizer and the prior (None: no fill is generated)."""

    cameras: Sequence[Camera]
    train: Sequence[int]
    photos: dict
    cache: GenerationCache
    views_dir: Path
    rasterizer: Callable
    prior: ImagePrior | None = None
    prior_hash: str = ""


class TargetMaker:
    """I* at virtual views from ``current`` (its G-buffer, its render for the prior's start and
    as the fill, its depth for warping)."""

    def __init__(self, setting: TargetSetting, current: Gaussians, sky, depths: dict | None = None) -> None:
        self.setting = setting
        self.current = current
        self.renders = ModelRenders(current, setting.rasterizer, sky, depths)

    # Only a prior's fill needs these, once per maker: without a prior nothing copies or hashes
    # the model (on a GPU that would move every Gaussian to the host each regeneration).
    @functools.cached_property
    def current_for_prior(self) -> Gaussians:
        """The model on the prior's device (the same tensors when the run's device is the prior's)."""
        return self.current.to(self.setting.prior.device)

    @functools.cached_property
    def gaussians_hash(self) -> str:
        """The model's version in the generation cache's keys."""
        return gaussians_version(self.current)

    def fill(self, camera: Camera, config: BootstrapConfig) -> tuple[torch.Tensor, bool]:
        """(what fills the pixels no photo covers [H, W, 3] float32 on the model's device, read
        from the cache): the prior's image (``config.seed``, ``config.ddim_steps``), else the render."""
        s = self.setting
        if s.prior is not None:
            image, hit = generate_cached(s.prior, self.current_for_prior, camera, config.seed, config.ddim_steps,
                                         s.cache, s.prior_hash, self.gaussians_hash)
            # The cache holds host arrays; the warps it is blended with are on the model's device.
            return torch.as_tensor(image).to(self.current.means.device), hit
        # The fill is the render itself (or inpainted around it): nothing to generate.
        return self.renders.rgb(camera), False

    def make(self, camera: Camera, round_number: int, save: bool, config: BootstrapConfig
             ) -> tuple[VirtualTarget, list[int]]:
        """-> (the view's VirtualTarget, the training views warped into it)."""
        s = self.setting
        generated, hit = self.fill(camera, config)
        sources = blend_sources(camera, s.cameras, s.train, config)
        report: dict = {}
        colour = config.colour_target()
        if colour:
            supervision = supervise_view(ViewContext(
                config, camera, generated, sources, s.cameras, s.photos, self.renders.depth, self.renders.rgb,
                source_depth=lambda: depth_from_training_views(camera, s.cameras, s.train, config.splat_views,
                                                               self.renders.depth)))
            image, mask, report = supervision.image, supervision.mask, supervision.report
        else:
            # No colour target: I* (depth sweep, warps; ~2.3 s per courtyard view) would be
            # built for nothing. The render stands in for the PNGs, with an empty mask.
            image = torch.as_tensor(generated, dtype=torch.float32)
            mask = torch.zeros(camera.height, camera.width, 1, device=image.device)
        geometry = [source for variant in config.variants.values()
                    for source in variant.view_geometry(sources, s.photos, s.cameras, self.renders.depth)]
        agreement = report.get("agreement_db")
        # Only the photos' colour is gated: a view without a colour target has no warped colour to judge.
        supervised = (config.agreement_min_db is None or agreement is None or not colour
                      or agreement >= config.agreement_min_db)
        entry = VirtualTarget(camera.name, camera, image, mask, torch.as_tensor(generated), hit, round_number,
                              geometry, agreement, supervised, report.get("depth", "render"))
        if save:
            write_png(s.views_dir / f"{camera.name}.png", view_png(entry.generated, mask, image,
                                                                    self.renders.rgb(camera)))
        return entry, sources
