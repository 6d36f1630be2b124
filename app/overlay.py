"""The viewer's own small GL drawing: coloured lines/points in world space (frustums, flags,
crop box, selection) and a full-window blit of the scene texture."""

from __future__ import annotations

from importlib import resources

import moderngl
import numpy as np

from inceptiongs.camera import Camera
from inceptiongs.renderer.gl_camera import gl_view_projection

# GLSL version of the app's shaders: 3.3 core is all they use.
_GLSL_VERSION = "#version 330 core\n"
# Overlay clip planes in scene units (normalised scenes are ~unit size): lines closer than
# this would be clipped anyway, and the far plane only has to exceed any frustum we draw.
OVERLAY_NEAR = 0.01
OVERLAY_FAR = 1.0e4


def _source(name: str) -> str:
    return _GLSL_VERSION + resources.files("inceptiongs.shaders").joinpath(name).read_text(encoding="utf-8")


def _program(ctx: moderngl.Context, stem: str) -> moderngl.Program:
    return ctx.program(vertex_shader=_source(f"{stem}.vert"), fragment_shader=_source(f"{stem}.frag"))


class OverlayRenderer:
    """Draws segments [S, 2, 3] and points [P, 3] with per-item RGB colours."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.program = _program(ctx, "app_lines")
        self.buffer = ctx.buffer(reserve=1024)
        self.vao = ctx.vertex_array(self.program, [(self.buffer, "3f 3f", "in_position", "in_color")])

    def _upload(self, vertices: np.ndarray) -> None:
        data = np.ascontiguousarray(vertices, np.float32).tobytes()
        if len(data) > self.buffer.size:
            self.buffer.orphan(len(data))
        self.buffer.write(data)

    def _set_camera(self, camera: Camera, point_size: float) -> None:
        view, projection = gl_view_projection(camera, OVERLAY_NEAR, OVERLAY_FAR)
        # moderngl uniforms take column-major bytes: the transpose of numpy's row-major matrix.
        self.program["u_view"].write(np.ascontiguousarray(view.T).tobytes())
        self.program["u_projection"].write(np.ascontiguousarray(projection.T).tobytes())
        self.program["u_point_size"].value = float(point_size)

    def draw_segments(self, camera: Camera, segments: np.ndarray, colors: np.ndarray) -> None:
        """segments: [S, 2, 3] world; colors: [S, 3] in [0, 1]."""
        if len(segments) == 0:
            return
        colors = np.repeat(np.asarray(colors, np.float32)[:, None, :], 2, axis=1)
        self._upload(np.concatenate([np.asarray(segments, np.float32), colors], axis=2).reshape(-1, 6))
        self._set_camera(camera, 1.0)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND | moderngl.CULL_FACE)
        self.vao.render(moderngl.LINES, vertices=2 * len(segments))

    def draw_points(self, camera: Camera, points: np.ndarray, color, size: float = 3.0) -> None:
        """points: [P, 3] world; color: one RGB [3] or one per point [P, 3]; size: pixels."""
        if len(points) == 0:
            return
        colors = np.broadcast_to(np.asarray(color, np.float32), (len(points), 3))
        self._upload(np.concatenate([np.asarray(points, np.float32), colors], axis=1))
        self._set_camera(camera, size)
        self.ctx.enable_only(moderngl.PROGRAM_POINT_SIZE)
        self.vao.render(moderngl.POINTS, vertices=len(points))

    def release(self) -> None:
        for resource in (self.vao, self.buffer, self.program):
            resource.release()


class SceneTexture:
    """An RGBA8 colour target the splats are drawn into (at reduced size while moving) or an
    image is uploaded to, then stretched over the window."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.program = _program(ctx, "app_blit")
        self.vao = ctx.vertex_array(self.program, [])
        self.texture: moderngl.Texture | None = None
        self.framebuffer: moderngl.Framebuffer | None = None
        self.flip_y = False

    def ensure(self, width: int, height: int) -> moderngl.Framebuffer:
        if self.texture is None or self.texture.size != (width, height):
            self._release_target()
            self.texture = self.ctx.texture((width, height), 4)
            self.texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self.framebuffer = self.ctx.framebuffer(color_attachments=[self.texture])
        return self.framebuffer

    def upload(self, image: np.ndarray) -> None:
        """image: [H, W, 3] float in [0, 1], row 0 = top."""
        height, width = image.shape[:2]
        self.ensure(width, height)
        rgba = np.empty((height, width, 4), np.uint8)
        rgba[..., :3] = np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8)
        rgba[..., 3] = 255
        self.texture.write(rgba.tobytes())
        self.flip_y = True  # texture row 0 holds the image top

    def blit(self, target: moderngl.Framebuffer) -> None:
        if self.texture is None:
            return
        target.use()
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND | moderngl.CULL_FACE)
        self.texture.use(0)
        self.program["u_image"].value = 0
        self.program["u_flip_y"].value = int(self.flip_y)
        self.vao.render(moderngl.TRIANGLES, vertices=3)

    def _release_target(self) -> None:
        if self.framebuffer is not None:
            self.framebuffer.release()
        if self.texture is not None:
            self.texture.release()
        self.texture = self.framebuffer = None

    def release(self) -> None:
        self._release_target()
        self.vao.release()
        self.program.release()
