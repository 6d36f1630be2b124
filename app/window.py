"""The GLFW window with its GL 4.3 core context, and the imgui-bundle backend attached to it."""

from __future__ import annotations

import warnings
from contextlib import contextmanager
from dataclasses import dataclass

import glfw
import moderngl

from inceptiongs.renderer.context import unbind_current_egl

GL_REQUIRED = (4, 3)


class WindowError(RuntimeError):
    """No window / no GL 4.3 context; the message says what was found."""


@dataclass(frozen=True)
class WindowPixels:
    """A GLFW window's two pixel grids: the window's (the mouse's, imgui's) and its framebuffer's
    (the renderer's and the camera's), larger on a HiDPI screen."""

    window: object

    @property
    def framebuffer_size(self) -> tuple[int, int]:
        """(width, height) in framebuffer pixels; at least 1 each (a minimised window has 0)."""
        width, height = glfw.get_framebuffer_size(self.window)
        return max(width, 1), max(height, 1)

    def to_framebuffer(self, x: float, y: float) -> tuple[float, float]:
        """Window position or distance (x, y) -> framebuffer pixels."""
        window_w, window_h = glfw.get_window_size(self.window)
        fb_w, fb_h = self.framebuffer_size
        return x * fb_w / max(window_w, 1), y * fb_h / max(window_h, 1)


def create_window(width: int, height: int, title: str, visible: bool = True):
    """A GLFW window with a GL 4.3 core context made current. Raises WindowError naming the GL
    version that could be had when 4.3 core cannot."""
    unbind_current_egl()  # an EGL context left current blocks GLX on this thread
    with glfw_warnings() as reported:
        initialised = glfw.init()
    if not initialised:
        # pyGLFW would print its own warning line first; its reason joins the one error line.
        reason = f" ({reported[-1]})" if reported else ""
        raise WindowError(f"could not initialise GLFW{reason}: no display? set DISPLAY or run under Xvfb")
    glfw.window_hint(glfw.VISIBLE, glfw.TRUE if visible else glfw.FALSE)
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, GL_REQUIRED[0])
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, GL_REQUIRED[1])
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, glfw.TRUE)
    window = glfw.create_window(width, height, title, None, None)
    if window:
        glfw.make_context_current(window)
        return window
    raise WindowError(f"no OpenGL {GL_REQUIRED[0]}.{GL_REQUIRED[1]} core context could be created; "
                      f"found: {probe_gl_version()}")


@contextmanager
def glfw_warnings():
    """Collect GLFW's error reports as text (yielded list) instead of letting pyGLFW print them
    as Python warnings before the one-line error that explains them."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", glfw.GLFWError)
        reported: list[str] = []
        yield reported
        reported.extend(_glfw_reason(w.message) for w in caught if issubclass(w.category, glfw.GLFWError))


def _glfw_reason(error) -> str:
    """pyGLFW's "(65550) b'X11: The DISPLAY environment variable is missing'" -> the text."""
    text = str(error)
    start, end = text.find("b'"), text.rfind("'")
    return text[start + 2:end] if 0 <= start < end else text


def probe_gl_version() -> str:
    """What GL a default (unversioned) context gives, for the error message."""
    glfw.default_window_hints()
    glfw.window_hint(glfw.VISIBLE, glfw.FALSE)
    window = glfw.create_window(16, 16, "probe", None, None)
    if not window:
        return "no OpenGL context at all"
    glfw.make_context_current(window)
    try:
        ctx = moderngl.create_context()
        info = f"OpenGL {ctx.info.get('GL_VERSION', '?')} ({ctx.info.get('GL_RENDERER', '?')})"
        ctx.release()
    except Exception as exc:  # noqa: BLE001 - only feeding an error message
        info = f"an unusable context ({exc})"
    glfw.destroy_window(window)
    return info


# The progress bars' fill (imgui's plot_histogram colour), under their white label ("iteration
# 1285 / 1305"). imgui's dark default, amber (0.90, 0.70, 0.00), gave the label a contrast of
# 1.9:1 where the bar had reached; this darker amber gives 5.0:1 (WCAG's text minimum is 4.5).
PROGRESS_FILL = (0.55, 0.42, 0.0)


def create_imgui(window):
    """imgui + implot contexts and the GLFW backend for ``window``; the viewer forwards GLFW's
    events to it itself (attach_callbacks=False), so tests can inject them."""
    from imgui_bundle import imgui, implot  # noqa: PLC0415 (no imgui unless there is a UI)
    from imgui_bundle.python_backends.glfw_backend import GlfwRenderer  # noqa: PLC0415

    # create_context makes a context current only when none is: a second window in the same
    # process (the tests open many) would share the first one's context, its mouse and active
    # widget included. Each window gets its own, destroyed by destroy_imgui.
    context = imgui.create_context()
    imgui.set_current_context(context)
    plot_context = implot.create_context()
    implot.set_current_context(plot_context)
    imgui.get_io().set_ini_filename("")  # no imgui.ini littering the working folder
    imgui.get_style().set_color_(imgui.Col_.plot_histogram, imgui.ImVec4(*PROGRESS_FILL, 1.0))
    renderer = GlfwRenderer(window, attach_callbacks=False)
    renderer.contexts = (context, plot_context)
    return renderer


def destroy_imgui(renderer) -> None:
    """Shut the backend down and destroy the contexts create_imgui made for it."""
    from imgui_bundle import imgui, implot  # noqa: PLC0415

    renderer.shutdown()
    context, plot_context = renderer.contexts
    implot.destroy_context(plot_context)
    imgui.destroy_context(context)


def ui_wants_mouse(imgui_impl) -> bool:
    """Whether imgui uses the mouse this frame (a panel is under it); False with no UI."""
    if imgui_impl is None:
        return False
    from imgui_bundle import imgui  # noqa: PLC0415
    return imgui.get_io().want_capture_mouse


def ui_wants_keyboard(imgui_impl) -> bool:
    """Whether imgui takes the keys (a text field has focus); False with no UI."""
    if imgui_impl is None:
        return False
    from imgui_bundle import imgui  # noqa: PLC0415
    return imgui.get_io().want_capture_keyboard


def ui_under_cursor(imgui_impl, x: float, y: float) -> bool:
    """Whether a window imgui drew last frame (the panel, the help, an open list) covers window
    position (x, y). A move and a press that arrive in one poll (a quick click, xdotool's
    "mousemove click") come before imgui's next frame, so its want_capture_mouse still
    describes where the cursor was: the press would reach the scene under the panel too."""
    if imgui_impl is None:
        return False
    from imgui_bundle import imgui  # noqa: PLC0415

    for window in imgui.get_current_context().windows:
        if not window.active or window.hidden or window.flags & imgui.WindowFlags_.no_inputs:
            continue
        if window.pos.x <= x < window.pos.x + window.size.x and window.pos.y <= y < window.pos.y + window.size.y:
            return True
    return False
