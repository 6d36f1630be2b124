"""The offscreen GL context: OpenGL 4.3 or newer when the driver gives it (compute-shader depth
sort on), the plain request when it refuses."""

from __future__ import annotations

import pytest

moderngl = pytest.importorskip("moderngl")
from inceptiongs.renderer import context as context_module  # noqa: E402
from inceptiongs.renderer.context import GL_VERSION_COMPUTE, create_offscreen_context  # noqa: E402
from inceptiongs.renderer.splats import SplatRenderer  # noqa: E402


def test_offscreen_context_is_gl_4_3_or_newer_and_sorts_with_compute_shaders(gl_context):
    # Mesa llvmpipe offers 4.5; a context left at moderngl's default would report 3.3.
    assert gl_context.version_code >= GL_VERSION_COMPUTE
    renderer = SplatRenderer(gl_context, sort="gpu")
    try:
        assert renderer.has_compute and renderer.sort == "gpu"
    finally:
        renderer.release()


def test_a_driver_refusing_4_3_gets_the_plain_request(monkeypatch, gl_context):
    asked = []

    def create_context(**kwargs):
        asked.append(kwargs.get("require"))
        if kwargs.get("require"):
            raise Exception("requested OpenGL version not supported")
        return gl_context

    monkeypatch.setattr(context_module.moderngl, "create_context", create_context)
    assert create_offscreen_context() is gl_context
    assert asked == [GL_VERSION_COMPUTE, None]
