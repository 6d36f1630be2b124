"""One image from the GL renderer in an offscreen (EGL) context: the ``gl`` backend of
``inceptiongs render``, plugged into the library's command through the
``inceptiongs.render_backends`` entry point (the library never imports GL)."""

from __future__ import annotations

import numpy as np

from inceptiongs.camera import Camera

from .context import create_offscreen_context
from .splats import SplatRenderer


def render_offscreen(gaussians, camera: Camera, mode: str, background) -> np.ndarray:
    """gaussians: a :class:`inceptiongs.gaussians.Gaussians`; mode: rgb | depth | normal | alpha
    -> [H, W, 3] or [H, W, 1] float32."""
    ctx = create_offscreen_context()
    renderer = SplatRenderer(ctx)
    try:
        renderer.set_gaussians(gaussians.numpy())
        return renderer.render(camera, mode=mode, background=background)
    finally:
        renderer.release()
        ctx.release()
