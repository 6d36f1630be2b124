"""SplatRenderer: Gaussians drawn as opacity-aware quads, or composited on the CPU cores.

A frame is three passes:
1. preprocess (transform feedback, one vertex per Gaussian: preprocess_gl.py): EWA projection,
   footprint box, colour/depth/normal -> four vec4 per Gaussian;
2. depth sort (compute-shader bitonic sort on GL >= 4.3, numpy otherwise);
3. compositing, one of (``SplatRenderer.compositing``):
   - "cpu" (the default on software GL such as llvmpipe, whose "GPU" is the CPU cores):
     passes 1 and 2 run on the CPU cores too (renderer/preprocess_numba.py, the shader's rules
     on the packed Gaussians kept here; renderer/sort_numba.py), and the splats are composited
     front to back with the stop rule by renderer/cpu_composite.py, exactly like the torch
     rasterizer; draw() uploads the result and shows it with one full-viewport pass (present.py);
   - "fetch" (hardware GL with GL_EXT_shader_framebuffer_fetch): one quad per Gaussian (the
     oriented box of the ellipse where alpha >= ALPHA_MIN), composited front to back in the
     fragment shader, stop rule included; draw() blends back to front;
   - "blend": premultiplied "over" blending back to front, which cannot stop early (the
     difference is bounded: docs/rendering.md).

Uploads: set_gaussians with an unchanged version uploads nothing; a camera change only
sets uniforms and re-runs passes 1-3. Buffers and textures are reused and only grow
(data_textures.py).
"""

from __future__ import annotations

import math
import time

import moderngl
import numpy as np

from inceptiongs.camera import Camera
from inceptiongs.constants import ALPHA_EPS, sh_degree_from_count

from .context import RendererError, check_context
from .data_textures import grown_texture, texture_height, write_rows
from .gl_camera import pixel_to_ndc_scale, shader_camera
from .layout import BASE_TEXELS, MODES, SPLAT_TEXELS, TEXTURE_WIDTH, sh_texels, texels_per_gaussian
from .preprocess_gl import PreprocessPass
from .present import CompositedPresenter
from .shaders import build_source, set_optional_uniform
from .sorting import GpuDepthSort, visible_depth_order, visible_quad_elements

COMPOSITING = ("cpu", "fetch", "blend")
FRAMEBUFFER_FETCH = "GL_EXT_shader_framebuffer_fetch"
# Oriented quads whose semi-axis exceeds this many pixels are drawn as clamped axis-aligned
# boxes instead (float32 corners far outside the image lose the sub-pixel precision).
QUAD_AXIS_MAX = 4096.0


def pack_gaussians(arrays: dict[str, np.ndarray], anchor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Gaussians.numpy() arrays -> (texels [N, 3 + S, 4] float32, anchor [3] float64, degree).

    Means are stored relative to their float64 centroid (the anchor; ``anchor`` when given, e.g.
    one model packed in parts) so shader arithmetic is as precise far from the origin as next
    to it. S = ceil(3 K / 4) texels hold the K = (degree + 1)^2 SH coefficients,
    channel-interleaved as in the arrays.
    """
    means = np.asarray(arrays["means"], np.float64).reshape(-1, 3)
    n = means.shape[0]
    sh = np.asarray(arrays["sh"], np.float32)
    sh = sh.reshape(n, sh.shape[1] if sh.ndim == 3 else -1, 3)
    degree = sh_degree_from_count(sh.shape[1])
    if anchor is None:
        anchor = means.mean(axis=0) if n else np.zeros(3)
    if not np.all(np.isfinite(anchor)):
        anchor = np.zeros(3)
    per_sh = sh_texels(sh.shape[1])
    texels = np.zeros((n, BASE_TEXELS + per_sh, 4), np.float32)
    texels[:, 0, :3] = means - anchor
    texels[:, 0, 3] = np.asarray(arrays["opacity_logits"], np.float32).reshape(n)
    texels[:, 1, :3] = np.asarray(arrays["log_scales"], np.float32).reshape(n, 3)
    texels[:, 2, :] = np.asarray(arrays["quats"], np.float32).reshape(n, 4)
    flat_sh = texels[:, BASE_TEXELS:, :].reshape(n, per_sh * 4)
    flat_sh[:, : 3 * sh.shape[1]] = sh.reshape(n, 3 * sh.shape[1])
    texels[:, BASE_TEXELS:, :] = flat_sh.reshape(n, per_sh, 4)
    return texels, anchor, degree


def is_software_renderer(ctx: moderngl.Context) -> bool:
    """True for Mesa's CPU rasterizers (llvmpipe, softpipe, swrast)."""
    name = str(ctx.info.get("GL_RENDERER", "")).lower()
    return any(word in name for word in ("llvmpipe", "softpipe", "swrast"))


def check_frame_arguments(mode: str, splat_scale: float) -> None:
    """ValueError naming the argument unless ``mode`` is a render mode (layout.MODES) and
    ``splat_scale`` a positive finite number."""
    if mode not in MODES:
        raise ValueError(f"unknown render mode {mode!r}; expected one of {', '.join(MODES)}")
    if not (math.isfinite(splat_scale) and splat_scale > 0):
        raise ValueError(f"splat_scale must be a positive finite number, got {splat_scale}")


def capped_degree(degree: int, sh_degree_cap: int | None) -> int:
    """The SH degree a frame evaluates: the model's ``degree``, at most ``sh_degree_cap`` (None: no cap)."""
    return degree if sh_degree_cap is None else max(0, min(degree, int(sh_degree_cap)))


class SplatRenderer:
    """Draws Gaussians with one moderngl context; owns its GL resources (see release())."""

    def __init__(self, ctx: moderngl.Context, sort: str = "auto", compositing: str = "auto"):
        """sort: "gpu" (compute shaders, GL >= 4.3), "cpu" (numpy) or "auto": the GPU sort
        where GL >= 4.3 on a hardware driver, numpy on software rasterizers (llvmpipe), where
        the "GPU" is the same two CPU cores and numpy's sort is several times faster.
        compositing: "cpu", "fetch", "blend" (module docstring) or "auto": "cpu" on software
        rasterizers, else "fetch" where the extension exists, else "blend". The "cpu" path
        always orders with numpy; ``sort`` applies to the quad paths. The attribute
        ``compositing`` may be changed between frames."""
        self.ctx = ctx
        self.has_compute = check_context(ctx)
        if sort not in ("auto", "gpu", "cpu"):
            raise ValueError(f"sort must be 'auto', 'gpu' or 'cpu', got {sort!r}")
        if sort == "gpu" and not self.has_compute:
            raise RendererError(f"the GPU sort needs OpenGL 4.3; this context is {ctx.version_code}")
        if sort == "auto":
            sort = "gpu" if self.has_compute and not is_software_renderer(ctx) else "cpu"
        self.sort = sort
        self.timings: dict[str, float] = {"preprocess_ms": 0.0, "sort_ms": 0.0, "draw_ms": 0.0}
        has_fetch = FRAMEBUFFER_FETCH in ctx.extensions
        if compositing == "auto":
            compositing = "cpu" if is_software_renderer(ctx) else ("fetch" if has_fetch else "blend")
        if compositing not in COMPOSITING:
            raise ValueError(f"compositing must be 'auto' or one of {', '.join(COMPOSITING)}, got {compositing!r}")
        if compositing == "fetch" and not has_fetch:
            raise RendererError(f"'fetch' compositing needs {FRAMEBUFFER_FETCH}, which this GL lacks")
        self.compositing = compositing
        self._gpu_sorts: dict[bool, GpuDepthSort] = {}
        vertex = build_source(330, ["splat_common.glsl", "splat_draw.vert"],
                              {"TEXTURE_WIDTH": TEXTURE_WIDTH, "SPLAT_TEXELS": SPLAT_TEXELS,
                               "QUAD_AXIS_MAX": QUAD_AXIS_MAX})
        self._draw_programs = {False: ctx.program(vertex_shader=vertex,
                                                  fragment_shader=build_source(330, ["splat_draw.frag"]))}
        if has_fetch:
            self._draw_programs[True] = ctx.program(
                vertex_shader=vertex,
                fragment_shader=build_source(330, ["splat_draw.frag"], {"FRONT_TO_BACK": 1}))
        self._preprocess = PreprocessPass(ctx)
        self._version: int | None = None
        self._count = 0
        self._degree = 0
        self._anchor = np.zeros(3)
        self._relative_means = np.zeros((0, 3), np.float32)
        self._texels: np.ndarray | None = None       # "cpu" compositing: the packed Gaussians
        self._cpu_splats: np.ndarray | None = None   # and their preprocess output, reused
        self._gaussian_texture: moderngl.Texture | None = None
        self._splat_buffer: moderngl.Buffer | None = None
        self._splat_texture: moderngl.Texture | None = None
        self._index_buffer: moderngl.Buffer | None = None
        self._draw_vaos: dict[tuple, moderngl.VertexArray] = {}
        self._element_generation = 0
        self._offscreen: moderngl.Framebuffer | None = None
        self._composited: np.ndarray | None = None  # the "cpu" path's frame, reused
        self._presenter = CompositedPresenter(ctx)  # shows the "cpu" path's frame

    # --- model upload ---------------------------------------------------------------------

    @property
    def count(self) -> int:
        return self._count

    def set_gaussians(self, arrays: dict[str, np.ndarray], version: int | None = None) -> None:
        """arrays: as Gaussians.numpy() (means [N,3], log_scales [N,3], quats [N,4],
        opacity_logits [N], sh [N,K,3]). The same non-None version as last time: no upload."""
        if version is not None and version == self._version:
            return
        self.set_packed(*pack_gaussians(arrays), version=version)

    def set_packed(self, texels: np.ndarray, anchor: np.ndarray, degree: int, version: int | None = None) -> None:
        """set_gaussians() for Gaussians packed already (pack_gaussians(), e.g. on a worker
        thread): texels [N, 3 + S, 4] float32, anchor [3], SH degree. With "cpu" compositing
        the texels stay here (the CPU cores preprocess them, renderer/preprocess_numba.py) and
        GL holds none of them; the quad paths upload them into the Gaussian texture."""
        if version is not None and version == self._version:
            return
        texels = np.ascontiguousarray(texels, np.float32)
        self._count, self._degree, self._anchor, self._version = texels.shape[0], degree, anchor, version
        if self.compositing == "cpu":
            self._texels, self._relative_means = texels, texels[:, 0, :3]
            return
        self._texels = None
        self._relative_means = np.ascontiguousarray(texels[:, 0, :3])
        self._upload(texels)

    def _upload(self, texels: np.ndarray) -> None:
        """texels [N, 3 + S, 4] float32 into the Gaussian texture; the preprocess output buffer sized."""
        n, per_gaussian = texels.shape[0], texels.shape[1]
        height = texture_height(n * per_gaussian)
        if height > self.ctx.info["GL_MAX_TEXTURE_SIZE"]:
            raise RendererError(f"{n} Gaussians with SH degree {self._degree} exceed this GL's "
                                f"texture size ({self.ctx.info['GL_MAX_TEXTURE_SIZE']})")
        if n == 0:
            return
        self._gaussian_texture = grown_texture(self.ctx, self._gaussian_texture, height)
        write_rows(self._gaussian_texture, texels.reshape(-1, 4))
        splat_bytes = TEXTURE_WIDTH * texture_height(n * SPLAT_TEXELS) * 16
        if self._splat_buffer is None or self._splat_buffer.size != splat_bytes:
            if self._splat_buffer is not None:
                self._splat_buffer.release()
            # Exactly the splat texture's size: the quad paths copy the buffer into it each frame.
            self._splat_buffer = self.ctx.buffer(reserve=splat_bytes)

    def _texels_in_gl(self) -> None:
        """The quad paths after "cpu" compositing held the texels: upload them now."""
        if self._texels is not None:
            texels, self._texels = self._texels, None
            self._relative_means = np.ascontiguousarray(texels[:, 0, :3])
            self._upload(texels)

    def _texels_on_cpu(self) -> np.ndarray:
        """The packed texels for the CPU preprocess; read back from GL when a quad path had
        uploaded them (the compositing changed between frames)."""
        if self._texels is None:
            per_gaussian = texels_per_gaussian((self._degree + 1) ** 2)
            flat = np.frombuffer(self._gaussian_texture.read(), np.float32)
            self._texels = flat[: self._count * per_gaussian * 4].reshape(self._count, per_gaussian, 4)
        return self._texels

    # --- frame ------------------------------------------------------------------------------

    def render(self, camera: Camera, mode: str = "rgb", background=(0.0, 0.0, 0.0),
               sh_degree_cap: int | None = None, splat_scale: float = 1.0) -> np.ndarray:
        """Offscreen frame as float32 numpy, row 0 = image top.

        rgb [H,W,3] = blended colour + (1 - alpha) * background; depth [H,W,1] = blended z /
        alpha (0 where alpha < ALPHA_EPS); normal [H,W,3] blended, not renormalised; alpha [H,W,1].
        """
        width, height = int(camera.width), int(camera.height)
        exact = self.compositing in ("cpu", "fetch")
        if self.compositing == "cpu":
            raw = self._cpu_frame(camera, mode, sh_degree_cap, splat_scale)
        else:
            fbo = self._offscreen_target(width, height)
            if exact:
                # rgb accumulates T * alpha * value, a holds T (negated once the pixel stopped).
                self._frame(camera, mode, fbo, (0.0, 0.0, 0.0, 1.0), sh_degree_cap, splat_scale,
                            flip_y=False, front_to_back=True)
            else:
                self._frame(camera, mode, fbo, (0.0, 0.0, 0.0, 0.0), sh_degree_cap, splat_scale,
                            flip_y=False, front_to_back=False)
            raw = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32)
            raw = raw.reshape(height, width, 4)
        if mode in ("rgb", "normal"):
            # Normals are blended vectors: nothing of the background belongs in them.
            background = np.zeros((1, 1, 3), np.float32) if mode == "normal" else \
                np.asarray(background, np.float32).reshape(1, 1, 3)
            if self.compositing == "cpu":
                from .cpu_composite import colour_over_background  # loaded by _cpu_frame already
                return colour_over_background(raw, background)
            if not background.any():  # the common case: one copy, no T
                return raw[..., :3].copy()
            transmittance = np.abs(raw[..., 3:4]) if exact else 1.0 - raw[..., 3:4]
            return (raw[..., :3] + transmittance * background).astype(np.float32, copy=False)
        alpha = 1.0 - np.abs(raw[..., 3:4]) if exact else raw[..., 3:4].copy()
        if mode == "alpha":
            return alpha
        safe = np.maximum(alpha, ALPHA_EPS)  # depth; only used where alpha >= ALPHA_EPS
        return np.where(alpha >= ALPHA_EPS, raw[..., 0:1] / safe, 0.0).astype(np.float32)

    def draw(self, camera: Camera, mode: str, framebuffer: moderngl.Framebuffer,
             background=(0.0, 0.0, 0.0), sh_degree_cap: int | None = None,
             splat_scale: float = 1.0, clear: bool = True) -> None:
        """Draw upright into ``framebuffer`` (e.g. the app's window). The camera's size should be
        the framebuffer's viewport. rgb and alpha are final; depth is the blended z before the
        division by alpha that render() does, and normal is the blended normal. With "cpu"
        compositing the frame is exactly render()'s; otherwise it is blended back to front."""
        # Cleared to (background, 0): "over" blending then leaves colour + T * background.
        clear_colour = (*(float(v) for v in background), 0.0) if clear else None
        if self.compositing == "cpu":
            raw = self._cpu_frame(camera, mode, sh_degree_cap, splat_scale)
            start = time.perf_counter()
            framebuffer.use()
            if clear_colour is not None:
                framebuffer.clear(*clear_colour)
            self._presenter.present(raw, framebuffer)
            self.timings["draw_ms"] += 1e3 * (time.perf_counter() - start)
            return
        self._frame(camera, mode, framebuffer, clear_colour, sh_degree_cap, splat_scale,
                    flip_y=True, front_to_back=False)

    def pick_depth(self, camera: Camera, x: int, y: int) -> float | None:
        """Expected camera z at pixel (x, y) (column, row from the top), None where nothing was
        drawn (alpha < ALPHA_EPS) or outside the image. Renders only a 1x1 window of the
        camera; the EWA Jacobian clamp depends on the image extent, so the value can differ
        from the full frame's depth by ~1e-4 relative where Gaussians lie outside the window."""
        if not (0 <= x < camera.width and 0 <= y < camera.height):
            return None
        depth = self.render(camera.cropped(int(x), int(y), 1, 1), mode="depth")
        value = float(depth[0, 0, 0])
        return value if value > 0.0 else None

    def _offscreen_target(self, width: int, height: int) -> moderngl.Framebuffer:
        fbo = self._offscreen
        if fbo is None or fbo.size != (width, height):
            if fbo is not None:
                for attachment in fbo.color_attachments:
                    attachment.release()
                fbo.release()
            colour = self.ctx.renderbuffer((width, height), 4, dtype="f4")
            fbo = self._offscreen = self.ctx.framebuffer(color_attachments=[colour])
        return fbo

    def _frame(self, camera: Camera, mode: str, fbo: moderngl.Framebuffer, clear_colour,
               sh_degree_cap: int | None, splat_scale: float, flip_y: bool,
               front_to_back: bool) -> None:
        check_frame_arguments(mode, splat_scale)
        ctx = self.ctx
        fbo.use()
        if clear_colour is not None:
            fbo.clear(*clear_colour)
        self.timings = {"preprocess_ms": 0.0, "sort_ms": 0.0, "draw_ms": 0.0}
        if self._count == 0:
            return
        self._texels_in_gl()
        start = time.perf_counter()
        cam = shader_camera(camera, self._anchor)
        self._preprocess.run(self._gaussian_texture, self._splat_buffer, self._count, self._degree, cam, mode,
                             capped_degree(self._degree, sh_degree_cap), splat_scale)
        preprocess_done = time.perf_counter()

        if self.sort == "gpu":
            sorter = self._gpu_sorts.get(front_to_back)
            if sorter is None:
                sorter = self._gpu_sorts[front_to_back] = GpuDepthSort(ctx, SPLAT_TEXELS, front_to_back)
            element_buffer = sorter.sort(self._splat_buffer, self._count)
            generation = ("gpu", front_to_back, sorter.generation)
            element_count = 6 * self._count
        else:
            splats = np.frombuffer(self._splat_buffer.read(size=self._count * SPLAT_TEXELS * 16),
                                   np.float32).reshape(self._count, SPLAT_TEXELS, 4)
            elements = visible_quad_elements(splats, self._relative_means, cam.rotation, cam.translation,
                                             front_to_back)
            element_count = elements.size
            if self._index_buffer is None or self._index_buffer.size < max(elements.nbytes, 4):
                if self._index_buffer is not None:
                    self._index_buffer.release()
                self._index_buffer = ctx.buffer(reserve=max(elements.nbytes, 4))
                self._element_generation += 1
            if elements.size:
                self._index_buffer.write(elements.tobytes())
            element_buffer = self._index_buffer
            generation = ("cpu", self._element_generation)
        # The splat texture exists for the quad paths only: CPU compositing reads the buffer
        # (a model of millions saves its 64 bytes per Gaussian).
        self._splat_texture = grown_texture(ctx, self._splat_texture, texture_height(self._count * SPLAT_TEXELS))
        self._splat_texture.write(self._splat_buffer)
        ctx.finish()
        sort_done = time.perf_counter()

        draw = self._draw_programs[front_to_back]
        # Keyed by allocation generation, not id(): a released buffer's id (and GL name) can
        # be reused by its replacement while an old array still holds the old storage.
        key = (front_to_back, generation)
        vao = self._draw_vaos.get(key)
        if vao is None:
            # A new element buffer (or program) invalidates the old arrays; they are cheap.
            for old_vao in self._draw_vaos.values():
                old_vao.release()
            self._draw_vaos.clear()
            vao = self._draw_vaos[key] = ctx.vertex_array(draw, [], index_buffer=element_buffer,
                                                          index_element_size=4)
        draw["splat_count"].value = self._count
        draw["pixel_to_ndc"].value = pixel_to_ndc_scale(cam.size[0], cam.size[1], flip_y)
        draw["image_size"].value = tuple(map(float, cam.size))
        draw["flip_height"].value = float(cam.size[1]) if flip_y else 0.0
        set_optional_uniform(draw, "splats", 0)
        self._splat_texture.use(0)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        if front_to_back:
            ctx.disable(moderngl.BLEND)  # the fragment shader composites
        else:
            ctx.enable(moderngl.BLEND)
            ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA
            ctx.blend_equation = moderngl.FUNC_ADD
        if element_count:
            vao.render(mode=moderngl.TRIANGLES, vertices=element_count)
        ctx.finish()
        ctx.disable(moderngl.BLEND)
        end = time.perf_counter()
        self.timings = {"preprocess_ms": 1e3 * (preprocess_done - start),
                        "sort_ms": 1e3 * (sort_done - preprocess_done),
                        "draw_ms": 1e3 * (end - sort_done)}

    def _cpu_frame(self, camera: Camera, mode: str, sh_degree_cap: int | None,
                   splat_scale: float) -> np.ndarray:
        """Preprocess, order and compositing on the CPU cores: [H, W, 4] float32 (rgb = sum of
        T alpha value, a = T, negated once the pixel stopped), row 0 = image top."""
        from .cpu_composite import composite_splats  # numba: compiled on first use only
        from .preprocess_numba import preprocess_splats

        check_frame_arguments(mode, splat_scale)
        width, height = int(camera.width), int(camera.height)
        self.timings = {"preprocess_ms": 0.0, "sort_ms": 0.0, "draw_ms": 0.0}
        if self._count == 0:
            empty = np.zeros((height, width, 4), np.float32)
            empty[..., 3] = 1.0
            return empty
        start = time.perf_counter()
        cam = shader_camera(camera, self._anchor)
        degree = capped_degree(self._degree, sh_degree_cap)
        splats = self._cpu_splats = preprocess_splats(self._texels_on_cpu(), degree, cam, MODES[mode], splat_scale,
                                                      out=self._cpu_splats)
        preprocess_done = time.perf_counter()
        order = visible_depth_order(self._relative_means, splats[:, 1, 3] > 0.0, cam.rotation, cam.translation)
        sort_done = time.perf_counter()
        self._composited = composite_splats(splats, order, width, height, self._composited)
        end = time.perf_counter()
        self.timings = {"preprocess_ms": 1e3 * (preprocess_done - start),
                        "sort_ms": 1e3 * (sort_done - preprocess_done),
                        "draw_ms": 1e3 * (end - sort_done)}
        return self._composited

    def release(self) -> None:
        """Free every GL object this renderer made (the context stays the caller's)."""
        objects = [self._gaussian_texture, self._splat_buffer, self._splat_texture, self._index_buffer,
                   *self._draw_vaos.values(), *self._draw_programs.values()]
        if self._offscreen is not None:
            objects += list(self._offscreen.color_attachments) + [self._offscreen]
        for obj in objects:
            if obj is not None:
                obj.release()
        self._preprocess.release()
        self._presenter.release()
        for sorter in self._gpu_sorts.values():
            sorter.release()
        self._gpu_sorts.clear()
        self._draw_vaos.clear()
        self._draw_programs.clear()
        self._gaussian_texture = self._splat_buffer = self._splat_texture = None
        self._index_buffer = self._offscreen = None
        self._composited = self._texels = self._cpu_splats = None
        self._count = 0
        self._version = None
