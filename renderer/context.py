"""OpenGL contexts for the splat renderer: headless EGL for tests, the CLI and benchmarks.

The app makes its own GLFW window and passes ``moderngl.create_context()`` to
:class:`~inceptiongs.renderer.splats.SplatRenderer`; :func:`check_context` tells either kind
of context what the renderer can do with it.
"""

from __future__ import annotations

import ctypes
import os
import sys

import moderngl

# Instanced quads, transform feedback, texelFetch and integer attributes: GL 3.3 core.
GL_VERSION_MIN = 330
# Compute shaders and shader storage buffers (the GPU depth sort): GL 4.3.
GL_VERSION_COMPUTE = 430


class RendererError(RuntimeError):
    """The GL context cannot do what the renderer needs (message says what was found)."""


def check_context(ctx: moderngl.Context) -> bool:
    """Raise RendererError below GL 3.3; return True when compute shaders (GL 4.3) exist."""
    version = int(ctx.version_code)
    if version < GL_VERSION_MIN:
        renderer = ctx.info.get("GL_RENDERER", "unknown renderer")
        raise RendererError(f"OpenGL {version // 100}.{version % 100 // 10} found ({renderer}); "
                            f"the splat renderer needs OpenGL 3.3 or newer")
    return version >= GL_VERSION_COMPUTE


def create_offscreen_context() -> moderngl.Context:
    """A headless EGL context (Mesa llvmpipe on machines without a GPU).

    A standalone context is OpenGL 3.3 unless a version is required (NVIDIA's driver gives
    exactly 3.3), which turns the compute-shader depth sort off; so 4.3 is asked for first, and
    a driver that refuses it gets today's plain request.
    """
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl", require=GL_VERSION_COMPUTE)
    except Exception:  # moderngl raises plain Exception when the driver cannot give 4.3
        try:
            ctx = moderngl.create_context(standalone=True, backend="egl")
        except Exception as exc:  # a missing EGL/driver
            raise RendererError(f"could not create an EGL OpenGL context ({exc})") from None
    check_context(ctx)
    return ctx


def unbind_current_egl() -> bool:
    """Unbind whatever EGL context is current on this thread; True when one was.

    moderngl's ``release()`` of an EGL context leaves it current, and Mesa then refuses a GLX
    context on the same thread (``BadAccess`` in ``X_GLXMakeCurrent``, which Xlib answers with
    ``exit(1)``). A process that rendered headless before opening a GLFW window (the tests, a
    script) calls this first. libEGL is only consulted when it is already loaded.
    """
    if sys.platform != "linux":
        return False
    try:
        # RTLD_NOLOAD: look at a library the process already has; never load one just to ask.
        egl = ctypes.CDLL("libEGL.so.1", mode=os.RTLD_NOLOAD)
    except OSError:
        return False
    egl.eglGetCurrentContext.restype = ctypes.c_void_p
    egl.eglGetCurrentDisplay.restype = ctypes.c_void_p
    egl.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
    if not egl.eglGetCurrentContext():
        return False
    egl.eglMakeCurrent(egl.eglGetCurrentDisplay(), None, None, None)
    egl.eglReleaseThread()
    return True
