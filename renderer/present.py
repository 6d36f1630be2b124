"""The "cpu" compositing's last step: a frame composited on the CPU cores (cpu_composite.py) shown
upright in a framebuffer by one full-viewport pass (splat_present.vert/.frag), blended over what
is there as the quad paths blend."""

from __future__ import annotations

import moderngl
import numpy as np

from .shaders import build_source, set_optional_uniform


class CompositedPresenter:
    """The texture a composited frame is uploaded to (reused while its size stays), the present
    program and its vertex array (made on the first frame); owns these GL objects (see release())."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self._texture: moderngl.Texture | None = None
        self._program: moderngl.Program | None = None
        self._vao: moderngl.VertexArray | None = None

    def present(self, raw: np.ndarray, framebuffer: moderngl.Framebuffer) -> None:
        """Blend a CPU-composited frame [H, W, 4] (row 0 = top; rgb = sum of T alpha value,
        a = T) upright over ``framebuffer``."""
        ctx = self.ctx
        height, width = raw.shape[:2]
        texture = self._texture
        if texture is None or texture.size != (width, height):
            if texture is not None:
                texture.release()
            texture = self._texture = ctx.texture((width, height), 4, dtype="f4")
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        texture.write(raw)
        if self._program is None:
            self._program = ctx.program(vertex_shader=build_source(330, ["splat_present.vert"]),
                                        fragment_shader=build_source(330, ["splat_present.frag"]))
            self._vao = ctx.vertex_array(self._program, [])
        set_optional_uniform(self._program, "composited", 0)
        self._program["image_height"].value = height
        texture.use(0)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA
        ctx.blend_equation = moderngl.FUNC_ADD
        self._vao.render(mode=moderngl.TRIANGLES, vertices=3)
        ctx.disable(moderngl.BLEND)

    def release(self) -> None:
        """Free the texture, program and vertex array (the context stays the caller's)."""
        for obj in (self._vao, self._program, self._texture):
            if obj is not None:
                obj.release()
        self._vao = self._program = self._texture = None
