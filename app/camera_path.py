"""The camera path being made in the window: keyframes taken from the current view, their order
and times, a preview that flies the path in the window, the path saved as JSON (a new file each
time, beside the runs), and its video rendered by `inceptiongs render --path` in a child process
(the same frames as the command line, the window answering meanwhile, its progress in the panel).

Keyframes are kept in the window's frame (a run's or a scene's normalised frame); the saved JSON
holds them in the frame of the model file the video renders (inceptiongs.camera_path), so the
file works with `inceptiongs render MODEL --path` as it is."""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from inceptiongs.camera_path import (DEFAULT_FPS, FOV_MAX_DEG, FOV_MIN_DEG, CameraPath, Keyframe, free_name,
                                     pose_at, write_path_json)
from inceptiongs.errors import InputError

from .navigation import NavigationState
from .runs import saved_dir

# A new keyframe comes this many seconds after the last.
KEYFRAME_SPACING_S = 2.0
DEFAULT_VIDEO_SIZE = (1280, 720)
PROGRESS = re.compile(r"(\d+)/(\d+)")


@dataclass
class VideoRender:
    """`inceptiongs render --path` running in a child process: frames done of ``total``."""

    process: subprocess.Popen
    out: Path
    done: int = 0
    total: int = 0
    tail: list = field(default_factory=list)  # its last lines of stderr (an error to show)

    def running(self) -> bool:
        return self.process.poll() is None

    def read_progress(self) -> None:
        """On a thread: tqdm's bar ("12/61") and lines from the child's stderr."""
        buffer = ""
        for chunk in iter(lambda: self.process.stderr.read(64), ""):
            buffer += chunk
            *lines, buffer = re.split(r"[\r\n]", buffer)
            for line in lines:
                found = PROGRESS.findall(line)
                if found:
                    self.done, self.total = (int(v) for v in found[-1])
                elif line.strip():
                    self.tail = (self.tail + [line.strip()])[-3:]


class PathEditor:
    """Keyframes ([Keyframe] in the window's frame), the selected one, the video's fps and size,
    the preview and the render. ``view``: the window's View; ``status``: its status line."""

    def __init__(self, view, status) -> None:
        self.view, self.status = view, status
        self.keyframes: list[Keyframe] = []
        self.selected = -1
        self.fps = DEFAULT_FPS
        self.size = list(DEFAULT_VIDEO_SIZE)
        self.preview_started: float | None = None
        self.saved: Path | None = None
        self.render: VideoRender | None = None
        self.video: Path | None = None

    # --- keyframes --------------------------------------------------------------------------------
    def add_keyframe(self) -> None:
        """The current view becomes a keyframe, KEYFRAME_SPACING_S after the last."""
        nav = self.view.nav
        time_s = self.keyframes[-1].time_s + KEYFRAME_SPACING_S if self.keyframes else 0.0
        fov = float(np.clip(nav.fov_y_deg, FOV_MIN_DEG, FOV_MAX_DEG))
        self.keyframes.append(Keyframe(time_s, nav.world_to_camera.copy(), fov))
        self.selected = len(self.keyframes) - 1
        self.status.text = f"keyframe {len(self.keyframes)} added at {time_s:g} s"

    def delete(self, index: int) -> None:
        if 0 <= index < len(self.keyframes):
            del self.keyframes[index]
            self.selected = min(index, len(self.keyframes) - 1)
            self.status.text = f"keyframe {index + 1} deleted ({len(self.keyframes)} left)"

    def move(self, index: int, step: int) -> None:
        """Swap keyframe ``index`` with its neighbour ``step`` (-1: earlier, +1: later); the
        times stay where they were, so the poses trade places in time."""
        other = index + step
        if not (0 <= index < len(self.keyframes) and 0 <= other < len(self.keyframes)):
            return
        a, b = self.keyframes[index], self.keyframes[other]
        self.keyframes[index] = Keyframe(a.time_s, b.world_to_camera, b.fov_y_deg)
        self.keyframes[other] = Keyframe(b.time_s, a.world_to_camera, a.fov_y_deg)
        self.selected = other

    def set_time(self, index: int, time_s: float) -> None:
        """Keyframe ``index`` at ``time_s``, kept between its neighbours (times increase)."""
        if not 0 <= index < len(self.keyframes):
            return
        low = self.keyframes[index - 1].time_s + 0.05 if index > 0 else 0.0
        high = self.keyframes[index + 1].time_s - 0.05 if index + 1 < len(self.keyframes) else float("inf")
        key = self.keyframes[index]
        clamped = float(min(max(time_s, low), high)) if np.isfinite(time_s) else key.time_s
        self.keyframes[index] = Keyframe(clamped, key.world_to_camera, key.fov_y_deg)

    def go_to(self, index: int) -> None:
        """Stand at keyframe ``index``."""
        if 0 <= index < len(self.keyframes):
            self.selected = index
            self._stand_at(self.keyframes[index].world_to_camera, self.keyframes[index].fov_y_deg)

    def _stand_at(self, pose: np.ndarray, fov: float) -> None:
        view = self.view
        rotation = pose[:3, :3]
        view.nav = NavigationState(-rotation.T @ pose[:3, 3], rotation.copy(), view.nav.up.copy(),
                                   view.nav.pivot.copy(), fov, view.nav.speed)
        view.moved()

    # --- the path -----------------------------------------------------------------------------------
    def window_path(self) -> CameraPath:
        return CameraPath(tuple(self.keyframes), int(self.size[0]), int(self.size[1]), float(self.fps))

    def file_path(self) -> CameraPath:
        """The path in the model file's frame (a scene's or run's normalised frame undone)."""
        scene = self.view.source.scene
        keys = self.keyframes
        if scene is not None:
            from inceptiongs.camera import Camera  # noqa: PLC0415

            def original(pose):
                camera = Camera("key", 2, 2, 1.0, 1.0, 1.0, 1.0, pose)
                return scene.normalization.camera_to_original(camera).world_to_camera
            keys = [Keyframe(k.time_s, original(k.world_to_camera), k.fov_y_deg) for k in keys]
        return CameraPath(tuple(keys), int(self.size[0]), int(self.size[1]), float(self.fps))

    def save(self) -> Path | None:
        """The path as a new JSON file beside the runs (path_N.json); None with the reason shown."""
        source = self.view.source
        out = free_name(saved_dir(source, source.runs_dir), "path", ".json")
        try:
            write_path_json(self.file_path(), out)
        except InputError as error:
            self.status.text = f"path not saved: {str(error).split(': ', 1)[-1]}"
            return None
        self.saved = out
        self.status.text = f"camera path saved to {out}"
        return out

    # --- preview ------------------------------------------------------------------------------------
    def toggle_preview(self) -> None:
        if self.preview_started is not None or len(self.keyframes) < 2:
            self.preview_started = None
            return
        self.preview_started = time.perf_counter()

    def update(self) -> None:
        """One frame of the preview: the view at the path's pose for the time since it started."""
        if self.preview_started is None:
            return
        path = self.window_path()
        elapsed = time.perf_counter() - self.preview_started
        pose, fov = pose_at(path, elapsed)
        self._stand_at(pose, fov)
        if elapsed >= path.duration_s:
            self.preview_started = None

    def busy(self) -> bool:
        """Frames are owed: a preview flying, or a render whose progress shows."""
        return self.preview_started is not None or (self.render is not None and (
            self.render.running() or self.video != self.render.out))

    def close(self) -> None:
        """The window closes: a render still running is stopped (its file never appears)."""
        if self.render is not None and self.render.running():
            self.render.process.terminate()
            self.render.process.wait(10)


# --- the video (PathEditor.render) -------------------------------------------------------------------

def render_unavailable(editor: PathEditor) -> str | None:
    """Why "render video" cannot start now, or None."""
    if len(editor.keyframes) < 2:
        return "add at least 2 keyframes"
    model = editor.view.source.model_path
    if model is None or not Path(model).is_file():
        return "no model file to render (train a model or save a PLY first)"
    if editor.render is not None and editor.render.running():
        return "a video is rendering"
    return None


def start_render(editor: PathEditor) -> Path | None:
    """Save the path, then `inceptiongs render MODEL --path it --out video_N.mp4` in a child
    process (the model file as saved: edits not saved are not in the video)."""
    reason = render_unavailable(editor)
    if reason is not None:
        editor.status.text = f"no video: {reason}"
        return None
    saved = editor.save()
    if saved is None:
        return None
    out = free_name(saved.parent, "video", ".mp4")
    command = [sys.executable, "-m", "inceptiongs", "render", str(editor.view.source.model_path),
               "--path", str(saved), "--out", str(out)]
    process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True)
    editor.render = VideoRender(process, out)
    threading.Thread(target=editor.render.read_progress, name="inceptiongs-video", daemon=True).start()
    editor.status.text = f"rendering {out.name} ..."
    return out


def poll_render(editor: PathEditor) -> None:
    """Say once that the render ended: where the video is, or why it failed."""
    render = editor.render
    if render is None or render.running() or editor.video == render.out:
        return
    editor.video = render.out  # reported
    if render.process.returncode == 0 and render.out.is_file():
        editor.status.text = f"video saved to {render.out}"
    else:
        editor.status.text = f"video failed: {render.tail[-1] if render.tail else 'see the terminal'}"
