"""Per-frame back-to-front depth sort of the Gaussians.

Front to back: camera z ascending, ties by index ascending (the torch rasterizer's stable
order); back to front: its exact reverse. Either way both renderers composite in the same order.
GL >= 4.3: a bitonic sort in compute shaders over (key, index) pairs, keys from the camera z
the preprocess pass wrote. Otherwise: numpy on camera z computed in float64.
"""

from __future__ import annotations

import moderngl
import numpy as np

from .shaders import build_source

# Elements sorted in one workgroup's shared memory (2 * local size). 1024 pairs = 8 KiB.
BLOCK = 1024
# Corner order of the two triangles of a quad (corner = (x bit, y bit)).
QUAD_CORNERS = np.array([0, 1, 2, 2, 1, 3], np.uint32)


def quad_elements(order: np.ndarray) -> np.ndarray:
    """order: [M] uint32 Gaussians in draw order -> [6 M] uint32 element indices
    4 * gaussian + corner (see splat_draw.vert)."""
    return np.ascontiguousarray((4 * order.astype(np.uint32)[:, None] + QUAD_CORNERS).ravel())


def depth_order(relative_means: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
                front_to_back: bool) -> np.ndarray:
    """relative_means: [N, 3] (mean - anchor); rotation [3, 3], translation [3] as in
    ShaderCamera. Returns [N] uint32 draw order (camera z in float64)."""
    z = relative_means.astype(np.float64) @ rotation[2] + translation[2]
    order = np.argsort(z, kind="stable")
    # Reversing the stable ascending order gives descending z with ties by descending index.
    return np.ascontiguousarray((order if front_to_back else order[::-1]).astype(np.uint32))


def visible_quad_elements(splats: np.ndarray, relative_means: np.ndarray, rotation: np.ndarray,
                          translation: np.ndarray, front_to_back: bool) -> np.ndarray:
    """The quad paths' CPU order: splats [N, 4, 4] the preprocess output (opacity in [:, 1, 3],
    0 for a culled Gaussian), relative_means [N, 3], rotation [3, 3] and translation [3] as in
    depth_order -> [6 M] uint32 element indices of the M visible Gaussians in draw order.
    Culled Gaussians are left out of the draw rather than drawn as empty quads."""
    visible = splats[:, 1, 3] > 0.0
    order = depth_order(relative_means, rotation, translation, front_to_back)
    return quad_elements(order[visible[order]])


def padded_size(count: int) -> int:
    """The power of two >= count that bitonic sorting needs, at least one block."""
    size = BLOCK
    while size < count:
        size *= 2
    return size


class GpuDepthSort:
    """Bitonic sort of (key, index) uint pairs in an SSBO; needs GL 4.3."""

    def __init__(self, ctx: moderngl.Context, splat_texels: int, front_to_back: bool):
        """splat_texels: vec4 per Gaussian in the preprocess output (key = z in texel 2's w)."""
        self.ctx = ctx
        order = {"FRONT_TO_BACK": 1} if front_to_back else {}
        self.keys = ctx.compute_shader(build_source(
            430, ["sort_keys.comp"], {"SPLAT_TEXELS": f"{int(splat_texels)}u", **order}))
        self.bitonic = ctx.compute_shader(build_source(
            430, ["sort_bitonic.comp"], {"BLOCK_HALF": BLOCK // 2, **order}))
        self.elements_shader = ctx.compute_shader(build_source(430, ["sort_indices.comp"]))
        self.pairs: moderngl.Buffer | None = None
        self.elements: moderngl.Buffer | None = None
        self.generation = 0  # bumped whenever the element buffer is reallocated

    def ensure_capacity(self, count: int) -> moderngl.Buffer:
        """The pair buffer (8 bytes per padded element); reallocated only when it grows."""
        needed = padded_size(count) * 8
        if self.pairs is None or self.pairs.size < needed:
            if self.pairs is not None:
                self.pairs.release()
            self.pairs = self.ctx.buffer(reserve=needed)
        return self.pairs

    def sort(self, splats: moderngl.Buffer, count: int) -> moderngl.Buffer:
        """splats: the preprocess output. Returns the element buffer of the sorted quads
        (6 uint32 per Gaussian, see quad_elements)."""
        size = padded_size(count)
        pairs = self.ensure_capacity(count)
        splats.bind_to_storage_buffer(0)
        pairs.bind_to_storage_buffer(1)
        self.keys["splat_count"] = count
        self.keys["padded_count"] = size
        self.keys.run(group_x=(size + 255) // 256)
        self.ctx.memory_barrier()
        groups = size // BLOCK
        self._run(0, 0, 0, groups)
        k = 2 * BLOCK
        while k <= size:
            j = k // 2
            while j >= BLOCK:
                self._run(1, k, j, size // 2 // (BLOCK // 2))
                j //= 2
            self._run(2, k, 0, groups)
            k *= 2
        if self.elements is None or self.elements.size < 24 * count:
            if self.elements is not None:
                self.elements.release()
            self.elements = self.ctx.buffer(reserve=24 * count)
            self.generation += 1
        self.elements.bind_to_storage_buffer(2)
        self.elements_shader["splat_count"] = count
        self.elements_shader.run(group_x=(count + 255) // 256)
        self.ctx.memory_barrier()
        return self.elements

    def _run(self, mode: int, stage: int, distance: int, groups: int) -> None:
        self.bitonic["sort_mode"] = mode
        if mode != 0:
            self.bitonic["stage"] = stage
        if mode == 1:
            self.bitonic["distance"] = distance
        self.bitonic.run(group_x=groups)
        self.ctx.memory_barrier()

    def release(self) -> None:
        for obj in (self.pairs, self.elements, self.keys, self.bitonic, self.elements_shader):
            if obj is not None:
                obj.release()
        self.pairs = self.elements = None


def visible_depth_order(relative_means: np.ndarray, visible: np.ndarray, rotation: np.ndarray,
                        translation: np.ndarray) -> np.ndarray:
    """Front-to-back order [M] int64 of the visible Gaussians only (visible: [N] bool).

    The torch rasterizer's order: camera z computed in float64, rounded to float32, ascending,
    ties by index. Visible Gaussians have z >= NEAR_PLANE > 0, where the float32 bit pattern
    read as uint32 is monotonic in z: :mod:`.sort_numba` sorts those bits (stable, so ties keep
    index order). A mask that lets through a depth not finite and positive (a caller's own)
    gets a stable argsort of the floats instead."""
    from .sort_numba import sorted_visible  # noqa: PLC0415 (numba compiles on first use)

    candidates = np.flatnonzero(visible)
    order = sorted_visible(relative_means, candidates, rotation[2], translation[2])
    if order is not None:
        return order
    z = (relative_means[candidates].astype(np.float64) @ rotation[2] + translation[2]).astype(np.float32)
    return candidates[np.argsort(z, kind="stable")]
