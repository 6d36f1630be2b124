"""Loading GLSL sources from the ``inceptiongs.shaders`` package with the constants injected."""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

from inceptiongs.constants import glsl_defines


@lru_cache(maxsize=None)
def shader_source(name: str) -> str:
    """Raw text of one file in inceptiongs.shaders (e.g. ``"splat_draw.frag"``)."""
    return resources.files("inceptiongs.shaders").joinpath(name).read_text(encoding="utf-8")


def build_source(version: int, names: list[str], defines: dict[str, int | float | str] | None = None) -> str:
    """``#version`` line, the rasterization constants, extra defines (ints stay GLSL ints,
    floats become float literals), then the files."""
    lines = [f"#version {version} core", glsl_defines()]
    lines += [f"#define {key} {value if isinstance(value, str) else repr(value)}" for key, value in (defines or {}).items()]
    lines += [shader_source(name) for name in names]
    return "\n".join(lines)
