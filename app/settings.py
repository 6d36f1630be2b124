"""What the user chose to see (render mode, SH cap, overlays, edit tool, crop box), the frame
statistics and the status line the panel shows, and what the panels remember between frames.
Plain data: every other part of the viewer reads these."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

RENDER_MODES = ("rgb", "depth", "normal", "opacity", "reference", "coverage")
# The viewer's mode names -> the GL renderer's. "coverage" draws splats recoloured by their view
# counts (app/coverage_mode.py) as rgb.
GL_MODE_NAMES = {"rgb": "rgb", "depth": "depth", "normal": "normal", "opacity": "alpha", "coverage": "rgb"}
# training_utilisation is capped here: 1 would leave the viewer no frames at all (and divide by 0).
MAX_TRAINING_UTILISATION = 0.98


EDIT_TOOLS = ("none", "rectangle", "visible rectangle", "brush", "lasso", "gizmo")
# How the photo of the nearest training camera is shown with the rgb render (as SIBR does).
PHOTO_VIEWS = ("off", "blended", "beside")
# What the keys and buttons do (input.py), shown by the help overlay (H / F1) and --help.
KEY_BINDINGS = (
    ("W A S D, Q / E", "fly forward / left / back / right, up / down (Shift: x4)"),
    ("left drag", "look around (fly) or orbit the pivot (orbit mode); with an edit tool: select"),
    ("middle drag", "pan"),
    ("scroll", "fly speed (fly) / zoom to the pivot (orbit)"),
    ("double-click", "orbit around the surface point under the cursor"),
    ("O", "orbit mode on / off"),
    ("Home", "frame the model"),
    ("R", "reset the view"),
    ("N / P (PageDown / PageUp)", "next / previous training camera"),
    ("T", "training-camera frustums on / off"),
    ("1 2 3 4 5 6", "mode: rgb, depth, normal, opacity, reference, coverage"),
    ("F", "flag the current view"),
    ("right-click", "flag a view aimed at the clicked surface"),
    ("left drag a crop handle", "move that face of the crop box"),
    ("Delete", "delete the selection"),
    ("Ctrl+Z / Ctrl+Y", "undo / redo (selections, deletions, crops)"),
    ("F12", "screenshot of the scene at window size"),
    ("Tab", "hide / show the panel"),
    ("H / F1", "this help (Esc closes it)"),
    ("Ctrl+Q", "quit (as the window's close button)"),
)


def bindings_text(indent: str = "  ") -> str:
    """KEY_BINDINGS as aligned lines of text."""
    width = max(len(keys) for keys, _ in KEY_BINDINGS)
    return "\n".join(f"{indent}{keys:<{width}}  {action}" for keys, action in KEY_BINDINGS)


@dataclass
class ViewSettings:
    mode: str = "rgb"
    reference_view: str = "heat-map"  # or "side by side"
    sh_degree_cap: int = 3
    splat_scale: float = 1.0
    background: tuple = (0.0, 0.0, 0.0)
    photo: str = "off"  # one of PHOTO_VIEWS
    photo_alpha: float = 0.5  # the photo's weight when blended
    show_training_cameras: bool = True
    show_flags: bool = True
    show_panel: bool = True  # Tab: the scene alone, the edit tools' outlines still drawn
    orbit: bool = False
    edit_tool: str = "none"  # one of EDIT_TOOLS
    gizmo_mode: str = "translate"  # one of gizmo.GIZMO_MODES: what dragging a gizmo handle does
    brush_radius: float = 30.0
    selection_mode: str = "replace"
    crop_enabled: bool = False
    crop_min: list | None = None  # None: fitted to the model when the box is first shown
    crop_max: list | None = None
    max_opacity: float = 0.05
    min_size: float = 0.5
    full_detail: bool = False  # draw every Gaussian of a large model, never a LOD cut (detail.py)


# FrameStats.frame_ms and fps average over this many frames.
FRAME_TIME_WINDOW = 30


@dataclass
class FrameStats:
    frame_ms: float = 0.0
    fps: float = 0.0
    sort_ms: float = 0.0
    draw_ms: float = 0.0
    rendered_scale: float = 1.0
    drawn_by: str = "splats"  # what made the image shown: "splats" (sorted, drawn) or "points" (points.py)
    frames: int = 0
    splat_renders: int = 0
    frame_times: list = field(default_factory=list)  # seconds of the last FRAME_TIME_WINDOW frames

    def add_frame(self, seconds: float) -> None:
        """Count one drawn frame that took ``seconds``; frame_ms and fps follow the recent mean."""
        self.frames += 1
        self.frame_times.append(seconds)
        if len(self.frame_times) > FRAME_TIME_WINDOW:
            self.frame_times.pop(0)
        mean = sum(self.frame_times) / len(self.frame_times)
        self.frame_ms = 1000.0 * mean
        self.fps = 1.0 / mean if mean > 0 else 0.0


class StatusLine:
    """The message that answers the last action, shown in the notification area
    (notifications.py) that stays in view; every part that acts on the user's behalf (view,
    flags, editor, jobs) replaces it when the state it names changes. ``serial`` counts the
    replacements and ``changed_at`` (perf_counter) dates the last, so the area can mark a new one.

    A message set with :meth:`say` may name the state it is about: ``holds`` (a callable, asked
    once a frame by :meth:`check`) says whether that state is still there, and the message goes
    when it is not ("looking from flag 1" once the camera moves); ``topic`` lets the action that
    ends it take it back (:meth:`drop`: a mode key after "coverage mode is off")."""

    def __init__(self, text: str = "") -> None:
        self._text = ""
        self.serial = 0
        self.changed_at = time.perf_counter()
        self.holds = None
        self.topic: str | None = None
        self.text = text

    @property
    def text(self) -> str:
        return self._text

    @text.setter
    def text(self, value: str) -> None:
        self._text = str(value)
        self.serial += 1
        self.changed_at = time.perf_counter()
        self.holds, self.topic = None, None

    def say(self, text: str, holds=None, topic: str | None = None) -> None:
        """Show ``text`` while ``holds()`` is true (None: until replaced), under ``topic``."""
        self.text = text
        self.holds, self.topic = holds, topic

    def drop(self, topic: str) -> None:
        """Clear the message when it is one about ``topic``."""
        if self.topic == topic:
            self.text = ""

    def check(self) -> None:
        """Clear the message when the state it named has gone (once a frame)."""
        if self.holds is not None and not self.holds():
            self.text = ""


@dataclass
class PanelState:
    """What the panels remember between frames: the help overlay's visibility (H / F1), and where
    each widget was last drawn, in window pixels, so a test can click it as a user does: rects
    maps a widget's label to (x0, y0, x1, y1); layout is the panel's rectangle and reach."""

    show_help: bool = False
    rects: dict = field(default_factory=dict)
    texts: dict = field(default_factory=dict)  # the lines of figures drawn, by key (panels._flow)
    tooltip: str | None = None  # the last tooltip a shortened path showed (its whole text)
    layout: dict = field(default_factory=dict)
