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


class OffscreenFrames:
    """Many frames from one offscreen context (``inceptiongs render --path/--orbit``): the
    ``gl`` entry of ``inceptiongs.frame_renderers``. A context manager; set_gaussians() then
    render() per frame (a frame of a level-of-detail cut sets its own Gaussians)."""

    def __init__(self) -> None:
        self.ctx = create_offscreen_context()
        self.renderer = SplatRenderer(self.ctx)

    def __enter__(self) -> "OffscreenFrames":
        return self

    def __exit__(self, *exc) -> None:
        self.renderer.release()
        self.ctx.release()

    def set_gaussians(self, gaussians) -> None:
        """gaussians: a Gaussians or its numpy arrays."""
        self.renderer.set_gaussians(gaussians if isinstance(gaussians, dict) else gaussians.numpy())

    def render(self, camera: Camera, mode: str, background) -> np.ndarray:
        return self.renderer.render(camera, mode=mode, background=background)
