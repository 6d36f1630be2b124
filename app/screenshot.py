"""``--screenshot``: load, render one frame without UI, save a PNG, exit.

Uses a hidden GLFW window (GL 4.3 core) when a display is available, else a headless EGL
context, so it runs under Xvfb, on a desktop and on a machine with no display at all."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import moderngl

from inceptiongs.camera import Camera, read_camera_json
from inceptiongs.errors import InputError

from inceptiongs.io.images import image_encoding, write_image

from .images import visualize
from .navigation import default_view, estimate_up
from .points import point_colours, render_points
from .sources import ViewerSource

DEFAULT_SIZE = (1280, 720)


def parse_size(text: str) -> tuple[int, int]:
    """"WxH" -> (W, H), both positive."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text}: expected WIDTHxHEIGHT, e.g. 1280x720") from None
    if width <= 0 or height <= 0:
        raise InputError(f"--size {text}: width and height must be positive")
    return width, height


def resized(camera: Camera, width: int, height: int) -> Camera:
    """The same view at another image size: intrinsics scale with each axis."""
    sx, sy = width / camera.width, height / camera.height
    return replace(camera, width=width, height=height, fx=camera.fx * sx, fy=camera.fy * sy,
                   cx=camera.cx * sx, cy=camera.cy * sy)


def screenshot_camera(source: ViewerSource, camera_path: str | None, size: tuple[int, int] | None) -> Camera:
    """--camera if given (at its own size unless --size), else the first training camera at the
    window's default size (its aspect kept: a run's training size may be 96x72), else a saved
    edit's camera (the same way), else a view of the whole model."""
    if camera_path is not None:
        camera = read_camera_json(camera_path)
    elif source.cameras or getattr(source, "saved_camera", None) is not None:
        # A saved edit's own view (sources.read_saved_view) where it has no training camera.
        camera = source.cameras[0] if source.cameras else source.saved_camera
        if size is None:
            fit = min(DEFAULT_SIZE[0] / camera.width, DEFAULT_SIZE[1] / camera.height)
            size = (max(int(round(camera.width * fit)), 1), max(int(round(camera.height * fit)), 1))
    else:
        width, height = size or DEFAULT_SIZE
        return default_view(source.gaussians["means"], width, height,
                            up=estimate_up(source.cameras)).camera(width, height, "default")
    return resized(camera, *size) if size is not None else camera


def _context():
    """(moderngl context, cleanup callable)."""
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        import glfw  # noqa: PLC0415

        from .window import create_window  # noqa: PLC0415

        window = create_window(64, 64, "inceptiongs screenshot", visible=False)
        ctx = moderngl.create_context()

        def cleanup():
            glfw.destroy_window(window)
            glfw.terminate()
        return ctx, cleanup
    from inceptiongs.renderer.context import create_offscreen_context  # noqa: PLC0415

    ctx = create_offscreen_context()
    return ctx, ctx.release


def shown_model(source: ViewerSource) -> dict:
    """What the screenshot shows: the source's model; for a scene without a model or sparse
    points (an LLFF capture), the points the window triangulates on a thread, made here first
    (a picture taken before them is black). InputError when none come out."""
    if not source.points_pending:
        return source.gaussians
    from .sources import triangulated_splats  # noqa: PLC0415

    splats, message = triangulated_splats(source.scene.root)
    if splats is None:
        raise InputError(f"{source.path}: nothing to take a screenshot of: {message}")
    return splats


def take_screenshot(source: ViewerSource, out_path: str | Path, camera_path: str | None = None,
                    size: tuple[int, int] | None = None, mode: str = "rgb") -> Path:
    from inceptiongs.renderer.splats import SplatRenderer  # noqa: PLC0415

    image_encoding(out_path)  # a bad extension fails before any rendering
    gaussians = shown_model(source)
    camera = screenshot_camera(source, camera_path, size)
    if source.sparse_points or source.points_pending:   # points, as the window draws them
        raw = render_points(gaussians["means"], point_colours(gaussians), camera, mode)
        write_image(out_path, visualize(raw, mode))
        return Path(out_path)
    ctx, cleanup = _context()
    try:
        renderer = SplatRenderer(ctx)
        renderer.set_gaussians(gaussians)
        image = renderer.render(camera, mode=mode)
        renderer.release()
    finally:
        cleanup()
    write_image(out_path, visualize(image, mode))
    return Path(out_path)
