"""Shared pieces of the viewer's tests: a small synthetic model and the real app opened on it."""

from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians


def synthetic_gaussians(shift: float = 0.0) -> dict:
    """A 12 x 9 grid of coloured, slightly flattened blobs on the plane z = 0 (x, y in [-1, 1]),
    plus a second smaller layer behind it so sorting matters. Arrays as Gaussians.numpy()."""
    xs, ys = np.meshgrid(np.linspace(-1, 1, 12), np.linspace(-0.75, 0.75, 9))
    front = np.stack([xs.ravel() + shift, ys.ravel(), np.zeros(xs.size)], 1)
    back = front[::3] * 1.2 + np.array([0.05, 0.05, 0.6])
    means = np.concatenate([front, back]).astype(np.float32)
    n = len(means)
    hue = np.linspace(0, 1, n, endpoint=False)
    rgb = np.stack([0.5 + 0.4 * np.cos(2 * np.pi * hue), 0.5 + 0.4 * np.cos(2 * np.pi * (hue - 1 / 3)),
                    0.5 + 0.4 * np.cos(2 * np.pi * (hue - 2 / 3))], 1)
    log_scales = np.tile(np.log([0.07, 0.05, 0.01]), (n, 1))
    angle = np.linspace(0, np.pi, n)
    quats = np.stack([np.cos(angle / 2), np.zeros(n), np.zeros(n), np.sin(angle / 2)], 1)
    return {"means": means, "log_scales": log_scales.astype(np.float32), "quats": quats.astype(np.float32),
            "opacity_logits": np.full(n, 2.0, np.float32),
            "sh": ((rgb - 0.5) / 0.28209479177387814)[:, None, :].astype(np.float32)}


def front_camera(width=160, height=120) -> Camera:
    pose = look_at(np.array([0.3, -0.2, -3.0]), np.zeros(3), np.array([0.0, -1.0, 0.0]))
    focal = 0.9 * width
    return Camera("front", width, height, focal, focal, width / 2, height / 2, pose)


def synthetic_table() -> dict:
    """A grey disc of radius 1 on the plane z = 0 (a table top, its normal +Z) with a red block
    standing on it at z in [0.1, 0.5]: the model's up is +Z, and an upright view shows the red
    above the grey. Arrays as Gaussians.numpy()."""
    rng = np.random.default_rng(3)
    angle, radius = rng.uniform(0, 2 * np.pi, 900), np.sqrt(rng.uniform(0, 1, 900))
    disc = np.stack([radius * np.cos(angle), radius * np.sin(angle), rng.normal(0, 0.005, 900)], 1)
    block = np.stack([rng.uniform(-0.15, 0.15, 200), rng.uniform(-0.15, 0.15, 200), rng.uniform(0.1, 0.5, 200)], 1)
    means = np.concatenate([disc, block]).astype(np.float32)
    rgb = np.concatenate([np.full((900, 3), 0.6), np.tile([0.9, 0.1, 0.1], (200, 1))])
    n = len(means)
    return {"means": means, "log_scales": np.full((n, 3), np.log(0.05), np.float32),
            "quats": np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
            "opacity_logits": np.full(n, 3.0, np.float32),
            "sh": ((rgb - 0.5) / 0.28209479177387814)[:, None, :].astype(np.float32)}


def write_table_model(path: Path) -> Path:
    """synthetic_table() as a PLY at ``path``."""
    from inceptiongs.io.ply import write_ply

    write_ply(Gaussians.from_numpy(synthetic_table()), path)
    return path


def write_grid_model(path: Path) -> Path:
    """synthetic_gaussians() as a PLY at ``path``."""
    from inceptiongs.io.ply import write_ply

    write_ply(Gaussians.from_numpy(synthetic_gaussians()), path)
    return path


def open_viewer(source_path: Path, width: int = 640, height: int = 480, **kwargs):
    """The real app (a GLFW window; needs the xvfb fixture) on ``source_path``."""
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer

    return Viewer(open_source(source_path), width, height, **kwargs)


def open_grid_viewer(source_path: Path, width: int = 640, height: int = 480, **kwargs):
    """open_viewer on the synthetic grid, seen from the front: the grid is a wall (its plane's
    normal, which the viewer would take as up, is horizontal), so -Y is chosen as up."""
    viewer = open_viewer(source_path, width, height, **kwargs)
    viewer.view.set_up((0.0, -1.0, 0.0))
    return viewer


@contextmanager
def opened(opener, *args, **kwargs):
    """The viewer ``opener(*args, **kwargs)`` returns (open_viewer, open_grid_viewer, Viewer),
    closed when the block ends, however it ends: a failing assert must still close the GL window
    (and stop a job it runs), or the next test's context breaks with it."""
    viewer = opener(*args, **kwargs)
    try:
        yield viewer
    finally:
        viewer.close()


class MovingGridJob:
    """A fake training job (the hand-off is what is tested): publishes the grid shifted a little
    further each step, then keeps its 'checkpoint' when told to stop."""

    def __init__(self):
        self.checkpoint_written = False
        self.steps = 0

    def run(self, box, control):
        while not control.stop.is_set():
            if control.pause.is_set():
                time.sleep(0.01)
                continue
            self.steps += 1
            box.publish(self.steps, synthetic_gaussians(shift=0.1 * self.steps), {"loss": 1.0 / self.steps})
            time.sleep(0.05)
        self.checkpoint_written = True


GOLDEN = Path(__file__).resolve().parent / "golden"
# The real window's pictures that have golden images: file name -> the view settings shown.
GOLDEN_WINDOW_SIZE = (320, 240)


def golden_window_images(model: Path) -> dict:
    """{golden file name: [H, W, 3] window capture} of the app on ``model`` (no panels), seen
    from front_camera(): what scripts/regen_viewer_golden.py writes and the tests compare."""
    from inceptiongs.app.navigation import NavigationState

    with opened(open_viewer, model, *GOLDEN_WINDOW_SIZE, with_ui=False) as viewer:
        viewer.view.nav = NavigationState.from_camera(front_camera(*GOLDEN_WINDOW_SIZE))
        viewer.view.settings.show_training_cameras = False
        images = {}
        viewer.view.settings.mode = "opacity"
        images["viewer_window_opacity_320x240.png"] = viewer.capture_window()
    # Orientation: a model without cameras opens upright (its up from its dominant plane).
    table = write_table_model(Path(model).with_name("table.ply"))
    with opened(open_viewer, table, *GOLDEN_WINDOW_SIZE, with_ui=False) as viewer:
        images["viewer_window_table_up_320x240.png"] = viewer.capture_window()
        # The crop box, fitted to the model, drawn in 3-D with its face handles.
        viewer.view.settings.orbit = True
        viewer.view.nav.orbit(60.0, 40.0)  # from above at an angle: all three axes show
        viewer.editor.enable_crop()
        viewer.view.frame_model()
        images["viewer_window_table_crop_320x240.png"] = viewer.capture_window()
    images.update(golden_tool_images(model))
    return images


def golden_tool_images(model: Path) -> dict:
    """{golden file name: window capture} of the edit tools' outlines while they are used on the
    grid: the app with its imgui layer (which draws them) and the panel hidden by Tab, the
    mouse moved and pressed with events as GLFW delivers them."""
    import glfw

    from inceptiongs.app.navigation import NavigationState

    images = {}
    with opened(open_viewer, model, *GOLDEN_WINDOW_SIZE) as viewer:
        viewer.view.nav = NavigationState.from_camera(front_camera(*GOLDEN_WINDOW_SIZE))
        viewer.view.settings.show_training_cameras = False
        press_key(viewer, glfw.KEY_TAB)  # hide the panel
        viewer.step()
        viewer.view.settings.edit_tool = "rectangle"
        viewer.input.on_cursor(viewer.window, 70, 50)
        viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.PRESS, 0)
        viewer.input.on_cursor(viewer.window, 230, 170)
        images["viewer_window_rectangle_320x240.png"] = viewer.capture_window()
        viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.RELEASE, 0)
        viewer.view.edit.select(np.zeros(viewer.view.edit.count, bool))  # the rectangle's selection off again
        viewer.view.settings.edit_tool = "brush"
        viewer.view.settings.brush_radius = 35.0
        viewer.input.on_cursor(viewer.window, 200, 110)
        images["viewer_window_brush_320x240.png"] = viewer.capture_window()
        viewer.view.settings.edit_tool = "lasso"
        path = [(60, 60), (150, 40), (260, 80), (240, 190), (120, 200), (80, 150)]
        viewer.input.on_cursor(viewer.window, *path[0])
        viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.PRESS, 0)
        for point in path[1:]:
            viewer.input.on_cursor(viewer.window, *point)
        images["viewer_window_lasso_320x240.png"] = viewer.capture_window()
        viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.RELEASE, 0)
    return images


def golden_photo_images(scene: Path) -> dict:
    """{golden file name: window capture} of the nearest training photo shown with the render
    (blended at weight 0.5, and as the inset beside it) at the demo scene's camera 3."""
    images = {}
    with opened(open_viewer, scene, *GOLDEN_WINDOW_SIZE, with_ui=False) as viewer:
        viewer.view.settings.show_training_cameras = False
        viewer.view.snap_to_camera(3)
        time.sleep(0.2)  # still: full-resolution frames
        viewer.view.settings.photo, viewer.view.settings.photo_alpha = "blended", 0.5
        images["viewer_window_photo_blended_320x240.png"] = viewer.capture_window()
        viewer.view.settings.photo = "beside"
        images["viewer_window_photo_beside_320x240.png"] = viewer.capture_window()
    return images


# --- a user's mouse and keyboard on the panel, as GLFW delivers them ------------------------------

def click_at(viewer, x: float, y: float) -> None:
    """Move the cursor to window position (x, y) and click the left button, a frame between each
    event (imgui reacts to an event on the frame after it)."""
    import glfw

    viewer.input.on_cursor(viewer.window, x, y)
    viewer.step()
    viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.PRESS, 0)
    viewer.step()
    viewer.input.on_mouse_button(viewer.window, glfw.MOUSE_BUTTON_LEFT, glfw.RELEASE, 0)
    viewer.step()
    viewer.step()  # imgui lets the widget go (no longer active: keys reach the viewer again)


def scroll_panel_to(viewer, label: str) -> None:
    """Turn the mouse wheel over the panel until its widget ``label`` is inside the window, as a
    user scrolls a panel longer than the window."""
    import glfw

    viewer.input.on_cursor(viewer.window, 200, 200)
    for _ in range(3):
        viewer.step()
    height = glfw.get_window_size(viewer.window)[1]
    for _ in range(20):
        if viewer.ui.rects[label][3] <= height - 5:
            return
        viewer.input.on_scroll(viewer.window, 0.0, -1.0)
        viewer.step()
        viewer.step()
    raise AssertionError(f"{label!r} stays below the window: {viewer.ui.rects[label]}")


def click_widget(viewer, label: str) -> None:
    """Click the middle of a panel widget the panels recorded in viewer.ui.rects."""
    viewer.step()  # the panel as it is now (a click may have changed which widgets show)
    x0, y0, x1, y1 = viewer.ui.rects[label]
    click_at(viewer, 0.5 * (x0 + x1), 0.5 * (y0 + y1))


def open_edit_section(viewer) -> None:
    """Fold the panel's other sections and open "Edit", so its widgets fit the window."""
    for header in ("View", "Inspect", "Flags", "Training"):
        click_widget(viewer, header)
    click_widget(viewer, "Edit")


def choose(viewer, combo: str, choice: str) -> None:
    """Open the panel's combo ``combo`` and click its ``choice``, as a user picks from a list."""
    click_widget(viewer, combo)
    click_widget(viewer, f"{combo}/{choice}")


def _key_of(char: str) -> int:
    """The GLFW key a US keyboard types ``char`` with (imgui takes the text from the char event;
    the key event is what GLFW sends with it)."""
    import glfw

    if char.isdigit():
        return glfw.KEY_0 + int(char)
    if char.isascii() and char.isalpha():
        return glfw.KEY_A + ord(char.lower()) - ord("a")
    return {".": glfw.KEY_PERIOD, "-": glfw.KEY_MINUS, "_": glfw.KEY_MINUS, "/": glfw.KEY_SLASH,
            " ": glfw.KEY_SPACE}[char]


def press_key(viewer, key: int, mods: int = 0) -> None:
    import glfw

    viewer.input.on_key(viewer.window, key, 0, glfw.PRESS, mods)
    viewer.input.on_key(viewer.window, key, 0, glfw.RELEASE, mods)


def type_into(viewer, label: str, text: str) -> None:
    """Click into the panel's text field ``label`` (at its left end: a field with +/- buttons has
    them on its right), select what it holds (Ctrl+A), type ``text`` key by key (a key event
    then its char event, as GLFW sends them) and press Enter."""
    import glfw

    viewer.step()
    x0, y0, x1, y1 = viewer.ui.rects[label]
    click_at(viewer, x0 + 6, 0.5 * (y0 + y1))
    viewer.input.on_key(viewer.window, glfw.KEY_LEFT_CONTROL, 0, glfw.PRESS, glfw.MOD_CONTROL)
    viewer.step()
    press_key(viewer, glfw.KEY_A, glfw.MOD_CONTROL)
    viewer.step()
    viewer.input.on_key(viewer.window, glfw.KEY_LEFT_CONTROL, 0, glfw.RELEASE, 0)
    viewer.step()
    for char in text:
        viewer.input.on_key(viewer.window, _key_of(char), 0, glfw.PRESS, 0)
        viewer.input.on_char(viewer.window, ord(char))
        viewer.input.on_key(viewer.window, _key_of(char), 0, glfw.RELEASE, 0)
        viewer.step()
    press_key(viewer, glfw.KEY_ENTER)
    viewer.step()
    viewer.step()


def flag_a_view(viewer) -> None:
    """Flag the current view as a user does (F with the cursor over the scene, right of the panel)
    and scroll the Training panel to "Bootstrap flagged views"."""
    import glfw

    for _ in range(3):
        viewer.step()
    viewer.input.on_cursor(viewer.window, 700, 500)
    for _ in range(3):
        viewer.step()
    press_key(viewer, glfw.KEY_F)
    scroll_panel_to(viewer, "Bootstrap flagged views")


def wait_for_job_end(viewer, seconds: float = 60.0) -> None:
    """Step the viewer until its job has ended and its closing line is reported (at most ``seconds``)."""
    deadline = time.time() + seconds
    while (viewer.jobs.training.alive or not viewer.jobs.reported) and time.time() < deadline:
        viewer.step()


def start_job(viewer, button: str) -> None:
    """Press a job button of the Training panel ("train (new run)", "resume", "Bootstrap flagged
    views", ...) and answer its question with "start the job", as a user starts a job (a button
    that could not build its job asks nothing: the status line says why)."""
    click_widget(viewer, button)
    if getattr(viewer.jobs, "pending", None) is not None:
        click_widget(viewer, "start the job")
