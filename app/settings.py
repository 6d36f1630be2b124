"""What the user chose to see (render mode, SH cap, overlays, edit tool, crop box) and the
frame statistics the panel shows. Plain data: every other part of the viewer reads these."""

from __future__ import annotations

from dataclasses import dataclass, field

RENDER_MODES = ("rgb", "depth", "normal", "opacity", "reference")
# The viewer's mode names -> the GL renderer's.
GL_MODE_NAMES = {"rgb": "rgb", "depth": "depth", "normal": "normal", "opacity": "alpha"}
# training_utilisation is capped here: 1 would leave the viewer no frames at all (and divide by 0).
MAX_TRAINING_UTILISATION = 0.98


EDIT_TOOLS = ("none", "rectangle", "brush", "lasso")


@dataclass
class ViewSettings:
    mode: str = "rgb"
    reference_view: str = "heat-map"  # or "side by side"
    sh_degree_cap: int = 3
    splat_scale: float = 1.0
    background: tuple = (0.0, 0.0, 0.0)
    show_training_cameras: bool = True
    show_flags: bool = True
    orbit: bool = False
    edit_tool: str = "none"  # one of EDIT_TOOLS
    brush_radius: float = 30.0
    selection_mode: str = "replace"
    crop_enabled: bool = False
    crop_min: list = field(default_factory=lambda: [-1.0, -1.0, -1.0])
    crop_max: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    max_opacity: float = 0.05
    min_size: float = 0.5
    # While a job trains, the share of the time the viewer leaves to it: after a frame that
    # took t seconds the viewer waits t * u / (1 - u) for input before drawing the next (as
    # nerfview's "train util"). 0.9: the viewer draws about a tenth of the time.
    training_utilisation: float = 0.9


@dataclass
class FrameStats:
    frame_ms: float = 0.0
    fps: float = 0.0
    sort_ms: float = 0.0
    draw_ms: float = 0.0
    rendered_scale: float = 1.0
    frames: int = 0
    splat_renders: int = 0
