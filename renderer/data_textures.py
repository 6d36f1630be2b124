"""The packed data textures (layout.py): float32 RGBA, TEXTURE_WIDTH texels a row, as many rows
as the data needs. The Gaussians' texture and the splat texture are kept and grown, never
shrunk below the rows in use."""

from __future__ import annotations

import moderngl
import numpy as np

from .layout import TEXTURE_WIDTH


def texture_height(texel_count: int) -> int:
    """Rows of TEXTURE_WIDTH texels that hold ``texel_count`` texels (at least one)."""
    return max(1, -(-texel_count // TEXTURE_WIDTH))


def grown_texture(ctx: moderngl.Context, texture: moderngl.Texture | None, height: int) -> moderngl.Texture:
    """``texture`` when it has ``height`` rows, else a new one of that height (the old one
    released): nearest filtering, as the shaders fetch texels, never interpolate them."""
    if texture is not None and texture.height == height:
        return texture
    if texture is not None:
        texture.release()
    texture = ctx.texture((TEXTURE_WIDTH, height), 4, dtype="f4")
    texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return texture


def write_rows(texture: moderngl.Texture, flat: np.ndarray) -> None:
    """flat [T, 4] float32 into ``texture``, row by row of TEXTURE_WIDTH: the full rows straight
    from ``flat`` (no padded copy of a model of millions), the last one padded."""
    full_rows, rest = divmod(len(flat), TEXTURE_WIDTH)
    if full_rows:
        texture.write(memoryview(flat[: full_rows * TEXTURE_WIDTH]), viewport=(0, 0, TEXTURE_WIDTH, full_rows))
    if rest:
        last = np.zeros((TEXTURE_WIDTH, 4), np.float32)
        last[:rest] = flat[full_rows * TEXTURE_WIDTH:]
        texture.write(last.tobytes(), viewport=(0, full_rows, TEXTURE_WIDTH, 1))
