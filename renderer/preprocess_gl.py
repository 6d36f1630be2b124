"""Pass 1 on the GPU: the preprocess vertex shader (splat_preprocess.vert) run by transform
feedback, one vertex per Gaussian, from the Gaussians' texture into the splat buffer (SPLAT_TEXELS
vec4 per Gaussian). Its CPU twin is preprocess_numba.py."""

from __future__ import annotations

import moderngl
import numpy as np

from .gl_camera import ShaderCamera
from .layout import MODES, TEXTURE_WIDTH, sh_texels, texels_per_gaussian
from .shaders import build_source, set_optional_uniform


class PreprocessPass:
    """The preprocess programs (one per model SH degree, compiled when first needed) and the
    vertex array that runs them; owns these GL objects (see release())."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self._programs: dict[int, moderngl.Program] = {}
        self._vao: moderngl.VertexArray | None = None

    def program(self, degree: int) -> moderngl.Program:
        """The program for models of SH ``degree`` (its texel layout is compiled in)."""
        program = self._programs.get(degree)
        if program is None:
            defines = {"TEXTURE_WIDTH": TEXTURE_WIDTH, "SH_DEGREE": degree,
                       "SH_TEXELS": sh_texels((degree + 1) ** 2),
                       "GAUSSIAN_TEXELS": texels_per_gaussian((degree + 1) ** 2)}
            program = self.ctx.program(
                vertex_shader=build_source(330, ["splat_common.glsl", "splat_preprocess.vert"], defines),
                varyings=["out_screen", "out_conic", "out_value", "out_minor"])
            self._programs[degree] = program
        return program

    def run(self, gaussians: moderngl.Texture, splats: moderngl.Buffer, count: int, model_degree: int,
            cam: ShaderCamera, mode: str, degree: int, splat_scale: float) -> None:
        """``count`` Gaussians of SH ``model_degree`` packed in ``gaussians`` -> ``splats``, seen by
        ``cam`` (anchor-relative), evaluating SH up to ``degree`` (<= model_degree)."""
        program = self.program(model_degree)
        program["rotation"].write(cam.rotation.T.astype(np.float32).tobytes())  # column-major
        program["translation"].value = tuple(map(float, cam.translation))
        set_optional_uniform(program, "camera_center", tuple(map(float, cam.center)))
        program["intrinsics"].value = tuple(map(float, cam.intrinsics))
        program["image_size"].value = tuple(map(float, cam.size))
        program["mode"].value = MODES[mode]
        set_optional_uniform(program, "sh_degree", degree)
        program["splat_scale"].value = float(splat_scale)
        set_optional_uniform(program, "gaussians", 0)
        gaussians.use(0)
        if self._vao is None or self._vao.program is not program:
            if self._vao is not None:
                self._vao.release()
            self._vao = self.ctx.vertex_array(program, [])
        self._vao.transform(splats, mode=moderngl.POINTS, vertices=count)
        self.ctx.finish()

    def release(self) -> None:
        """Free the programs and the vertex array (the context stays the caller's)."""
        for obj in [self._vao, *self._programs.values()]:
            if obj is not None:
                obj.release()
        self._programs.clear()
        self._vao = None
