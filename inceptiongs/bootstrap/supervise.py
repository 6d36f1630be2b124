"""I* for one virtual view from the run's settings."""

from __future__ import annotations

from .generation import blend_target
from .source_depth import depth_from_training_views


def supervise_view(config, generated, camera, sources, cameras, train, photos, renders, report):
    target_depth = None
    if config.virtual_depth != "render" and sources:
        target_depth = depth_from_training_views(camera, cameras, train, config.splat_views, renders.depth)
    return blend_target(generated, camera, sources, cameras, photos, renders.depth,
                        config.blending, config.delta, config.supervision, config.fill,
                        renders.rgb, config.virtual_pixels, config.residual_floor,
                        target_depth, report,
                        config.virtual_depth if config.virtual_depth in ("both", "auto") else "none",
                        config.align_px)
