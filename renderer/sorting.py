"""Per-frame back-to-front depth sort of the Gaussians.

Order: camera z descending, ties by index descending: the exact reverse of the torch
rasterizer's stable front-to-back order, so both renderers composite in the same order.
GL >= 4.3: a bitonic sort in compute shaders over (key, index) pairs, keys from the camera z
the preprocess pass wrote. Otherwise: numpy on camera z computed in float64.
"""

from __future__ import annotations

import moderngl
import numpy as np

from .shaders import build_source

# Elements sorted in one workgroup's shared memory (2 * local size). 1024 pairs = 8 KiB.
BLOCK = 1024


def back_to_front_order(relative_means: np.ndarray, rotation: np.ndarray,
                        translation: np.ndarray) -> np.ndarray:
    """relative_means: [N, 3] (mean - anchor); rotation [3, 3], translation [3] as in
    ShaderCamera. Returns [N] uint32 indices, far to near, ties by descending index."""
    z = relative_means.astype(np.float64) @ rotation[2] + translation[2]
    # Stable ascending sort, reversed: descending z and, among equal z, descending index.
    return np.ascontiguousarray(np.argsort(z, kind="stable")[::-1].astype(np.uint32))


def padded_size(count: int) -> int:
    """The power of two >= count that bitonic sorting needs, at least one block."""
    size = BLOCK
    while size < count:
        size *= 2
    return size


class GpuDepthSort:
    """Bitonic sort of (key, index) uint pairs in an SSBO; needs GL 4.3."""

    def __init__(self, ctx: moderngl.Context, splat_texels: int):
        """splat_texels: vec4 per Gaussian in the preprocess output (key = z in texel 2's w)."""
        self.ctx = ctx
        self.keys = ctx.compute_shader(build_source(430, ["sort_keys.comp"],
                                                    {"SPLAT_TEXELS": f"{int(splat_texels)}u"}))
        self.bitonic = ctx.compute_shader(build_source(430, ["sort_bitonic.comp"],
                                                       {"BLOCK_HALF": BLOCK // 2}))
        self.pairs: moderngl.Buffer | None = None

    def ensure_capacity(self, count: int) -> moderngl.Buffer:
        """The pair buffer (8 bytes per padded element); reallocated only when it grows."""
        needed = padded_size(count) * 8
        if self.pairs is None or self.pairs.size < needed:
            if self.pairs is not None:
                self.pairs.release()
            self.pairs = self.ctx.buffer(reserve=needed)
        return self.pairs

    def sort(self, splats: moderngl.Buffer, count: int) -> moderngl.Buffer:
        """splats: the preprocess output (3 vec4 per Gaussian). Returns the sorted pair buffer;
        entry i's second uint is the Gaussian drawn i-th (far to near)."""
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
        return pairs

    def _run(self, mode: int, stage: int, distance: int, groups: int) -> None:
        self.bitonic["sort_mode"] = mode
        if mode != 0:
            self.bitonic["stage"] = stage
        if mode == 1:
            self.bitonic["distance"] = distance
        self.bitonic.run(group_x=groups)
        self.ctx.memory_barrier()

    def release(self) -> None:
        for obj in (self.pairs, self.keys, self.bitonic):
            if obj is not None:
                obj.release()
        self.pairs = None
