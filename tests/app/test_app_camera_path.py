"""A camera path made in the real window (under Xvfb, with mouse events as GLFW delivers them):
keyframes added from the current view, reordered and deleted in the panel's "Camera path"
section, saved as a new JSON each time, rendered to a video from the panel; the video's decoded
frames match `inceptiongs render --camera` at the path's cameras."""

from __future__ import annotations

import time

import numpy as np
import pytest

from viewer_cases import click_widget, open_grid_viewer, opened, scroll_panel_to, write_grid_model

from inceptiongs.camera import Camera, look_at
from inceptiongs.camera_path import path_cameras, read_path_json
from inceptiongs.io.video import read_video_frames

pytestmark = pytest.mark.gl

VIDEO_MEAN_LEVELS = 3.0   # as tests/commands/test_render_path.py (the codec's error, measured there)
VIDEO_P99_LEVELS = 32.0


def _view(eye) -> Camera:
    pose = look_at(np.asarray(eye, float), np.zeros(3), np.array([0.0, -1.0, 0.0]))
    return Camera("view", 640, 480, 500.0, 500.0, 320.0, 240.0, pose)


def _section(viewer, label: str) -> None:
    """Scroll the panel until ``label`` shows, then click it."""
    scroll_panel_to(viewer, label)
    click_widget(viewer, label)


def test_a_path_made_in_the_window_renders_to_the_frames_of_the_command_line(xvfb, tmp_path):
    from inceptiongs.app.camera_path import KEYFRAME_SPACING_S
    from inceptiongs.cli import main
    from inceptiongs.renderer.context import unbind_current_egl
    from PIL import Image

    model = write_grid_model(tmp_path / "grid.ply")
    eyes = [(0.3, -0.2, -3.0), (2.0, -0.5, -2.2), (2.6, 0.2, -0.8), (0.0, -2.5, -1.0)]
    with opened(open_grid_viewer, model, 1000, 800) as viewer:
        _section(viewer, "Camera path")
        for eye in eyes:   # the user flies to a view, then adds it
            viewer.view.look_from(_view(eye))
            _section(viewer, "add keyframe (current view)")
        paths = viewer.paths
        assert [k.time_s for k in paths.keyframes] == [i * KEYFRAME_SPACING_S for i in range(4)]
        _section(viewer, "keyframe 4")        # select the last ...
        _section(viewer, "delete keyframe")   # ... and delete it
        _section(viewer, "keyframe 2")
        _section(viewer, "later")             # keyframes 2 and 3 trade places (times stay)
        order = [eyes[0], eyes[2], eyes[1]]
        np.testing.assert_allclose([k.center for k in paths.keyframes], order, atol=1e-9)
        assert [k.time_s for k in paths.keyframes] == [0.0, 2.0, 4.0]
        paths.size, paths.fps = [160, 120], 3.0   # imgui's size and fps fields, as typed
        _section(viewer, "save path")
        _section(viewer, "save path")          # a second save is a new file
        saved = sorted((p.name for p in paths.saved.parent.glob("path_*.json")))
        assert saved == ["path_1.json", "path_2.json"]
        _section(viewer, "render video")
        deadline = time.time() + 300
        while paths.render.running() and time.time() < deadline:
            viewer.step()
            time.sleep(0.05)
        viewer.step()
        assert paths.video is not None and paths.video.is_file(), viewer.status
        assert viewer.status == f"video saved to {paths.video}"
        video, path_file = paths.video, paths.saved
    assert path_file.name == "path_3.json" and video.name == "video_1.mp4"
    frames, fps, codec = read_video_frames(video)
    cameras = path_cameras(read_path_json(path_file))
    assert (len(frames), fps, codec) == (13, 3.0, "h264")
    np.testing.assert_allclose(cameras[0].center, eyes[0], atol=1e-9)  # a PLY: the window's frame is the file's
    try:
        for index in (0, 6, 9, 12):
            from inceptiongs.camera import write_camera_json

            write_camera_json(cameras[index], tmp_path / "cam.json")
            out = tmp_path / f"single_{index}.png"
            assert main(["render", str(model), "--camera", str(tmp_path / "cam.json"), "--out", str(out)]) == 0
            image = np.asarray(Image.open(out).convert("RGB")).astype(np.float64)
            difference = np.abs(frames[index].astype(np.float64) - image)
            assert difference.mean() < VIDEO_MEAN_LEVELS and np.percentile(difference, 99) < VIDEO_P99_LEVELS
        # The camera moved: the first and last frames differ far beyond the codec's error.
        assert np.abs(frames[0].astype(int) - frames[12].astype(int)).mean() > 3 * VIDEO_MEAN_LEVELS
    finally:
        unbind_current_egl()  # the next window's GLX context needs the thread free of EGL
