"""The window opens at once and says what it is reading until the viewer can show the model.

Reading a scene (cameras, sparse points, its runs, a trained model) took 7-14 s on bonsai and
12 s on donut's first open, a black window all that time. Here the window and its imgui come
first, the source is read on a thread (sources.open_source, which names each thing it reads),
and a frame a few times a second shows the words and the seconds passed; the viewer then takes
the window over (Viewer(window=..., imgui_impl=...))."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import glfw
import moderngl

# The opening frames are drawn this often while the source is read (events are taken too).
FRAME_SECONDS = 0.1
BACKGROUND = (0.08, 0.08, 0.1)


class Reading:
    """What the reading thread says (the newest line) and what it made: ``source`` or ``error``."""

    def __init__(self, text: str) -> None:
        self.text, self.source, self.error = text, None, None
        self.began = time.perf_counter()

    def say(self, text: str) -> None:
        self.text = text


def open_with_progress(path: str, runs_dir: Path | None, width: int, height: int, on_frame=None):
    """The viewer on ``path`` (sources.open_source) in a window shown from the first frame, which
    says what is being read meanwhile. ``on_frame(image [H, W, 3], text)``: called with each
    opening frame as drawn (tests). -> the Viewer, or None when the window was closed before the
    source was read. An InputError of the source (or the memory check) closes the window and is
    raised."""
    from .detail import check_window_memory  # noqa: PLC0415
    from .sources import open_source  # noqa: PLC0415
    from .viewer import Viewer, read_framebuffer  # noqa: PLC0415
    from .window import create_imgui, create_window, destroy_imgui  # noqa: PLC0415

    name = Path(path).name
    window = create_window(width, height, f"InceptionGS — opening {name}")
    ctx = moderngl.create_context()
    imgui_impl = create_imgui(window)
    reading = Reading(f"opening {name}: reading {path}")

    def read() -> None:
        try:
            reading.source = open_source(path, runs_dir, reading.say)
        except BaseException as exc:  # noqa: BLE001 - raised again on the main thread
            reading.error = exc

    thread = threading.Thread(target=read, name="inceptiongs-open", daemon=True)
    thread.start()
    try:
        while thread.is_alive() and not glfw.window_should_close(window):
            _frame(window, ctx, imgui_impl, name, reading, on_frame, read_framebuffer)
            thread.join(FRAME_SECONDS)
        if glfw.window_should_close(window):
            raise _Closed
        if reading.error is not None:
            raise reading.error
        source = reading.source
        model = source.gaussians
        check_window_memory(source.model_path or source.path, len(model["means"]), model["sh"].shape[1])
        reading.say(f"opening {name}: {len(model['means']):,} {'points' if source.sparse_points else 'Gaussians'} "
                    "read; drawing the first frame")
        _frame(window, ctx, imgui_impl, name, reading, on_frame, read_framebuffer)
    except _Closed:
        destroy_imgui(imgui_impl)
        glfw.destroy_window(window)
        return None
    except BaseException:
        destroy_imgui(imgui_impl)
        glfw.destroy_window(window)
        raise
    return Viewer(source, width, height, window=window, imgui_impl=imgui_impl)


def wrapped(text: str, width: float, measure) -> list[str]:
    """``text`` in lines at most ``width`` wide (``measure``: text -> its width), broken at spaces
    (a word longer than the width stands alone on its line)."""
    lines, line = [], ""
    for word in text.split(" "):
        candidate = f"{line} {word}" if line else word
        if line and measure(candidate) > width:
            lines.append(line)
            candidate = word
        line = candidate
    return lines + ([line] if line else [])


class _Closed(Exception):
    """The user closed the window before the source was read."""


def _frame(window, ctx, imgui_impl, name: str, reading: Reading, on_frame, read_framebuffer) -> None:
    """One opening frame: the words in the window's middle over a dark background."""
    from imgui_bundle import imgui  # noqa: PLC0415

    glfw.poll_events()
    width, height = glfw.get_framebuffer_size(window)
    screen = ctx.detect_framebuffer(0)
    screen.use()
    ctx.viewport = (0, 0, max(width, 1), max(height, 1))
    screen.clear(*BACKGROUND, 1.0)
    imgui_impl.process_inputs()
    imgui.new_frame()
    # Drawn straight onto the foreground: an imgui window would be hidden on its first frame
    # (auto-sized), and the first frame is the one that must say something.
    size = imgui.get_io().display_size
    seconds = time.perf_counter() - reading.began
    lines = [f"InceptionGS: opening {name}", *wrapped(reading.text, max(size.x - 80.0, 100.0),
                                                       lambda text: imgui.calc_text_size(text).x),
             f"{seconds:.0f} s" + " ." * (int(seconds * 2) % 4)]
    line_height = imgui.get_text_line_height_with_spacing()
    top = 0.5 * size.y - 0.5 * line_height * len(lines)
    draw = imgui.get_foreground_draw_list()
    for number, line in enumerate(lines):
        grey = 0.6 if number == len(lines) - 1 else 0.95
        colour = imgui.get_color_u32(imgui.ImVec4(grey, grey, grey, 1.0))
        left = 0.5 * (size.x - imgui.calc_text_size(line).x)
        draw.add_text(imgui.ImVec2(max(left, 10.0), top + number * line_height), colour, line)
    imgui.render()
    imgui_impl.render(imgui.get_draw_data())
    if on_frame is not None:
        on_frame(read_framebuffer(screen, max(width, 1), max(height, 1)), reading.text)
        _ = ctx.error   # the read-back's read-buffer error (Viewer.step says why): dropped
    glfw.swap_buffers(window)
