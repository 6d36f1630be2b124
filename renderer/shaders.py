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


def set_optional_uniform(program, name: str, value) -> None:
    """Set uniform ``name`` of a moderngl program to ``value`` if the program has it."""
    # The GLSL compiler drops uniforms a specialisation does not use (e.g. camera_center
    # for SH degree 0 is still used, sh_degree is not): setting them must not fail.
    if name in program:
        program[name].value = value
