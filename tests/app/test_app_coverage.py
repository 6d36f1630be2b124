"""The viewer's coverage mode: splats coloured by the cameras that see them, a golden
screenshot, and the scarcest-view flag suggestion."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at
from inceptiongs.constants import SH_C0
from inceptiongs.evaluation.coverage import ramp_colours
from viewer_cases import opened

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "viewer_coverage_160x120.png"
REGENERATE = os.environ.get("INCEPTIONGS_REGEN_GOLDEN") == "1"


def _grid(n: int = 12) -> dict:
    """n x n opaque grey blobs on the plane z = 0, x, y in [-1, 1] (arrays as Gaussians.numpy())."""
    xs, ys = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    means = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1).astype(np.float32)
    count = len(means)
    return {"means": means, "log_scales": np.tile(np.log([0.09, 0.09, 0.01]), (count, 1)).astype(np.float32),
            "quats": np.tile([1.0, 0, 0, 0], (count, 1)).astype(np.float32),
            "opacity_logits": np.full(count, 3.0, np.float32), "sh": np.zeros((count, 4, 3), np.float32)}


def _camera(eye, target, name, size=(64, 48)) -> Camera:
    w, h = size
    return Camera(name, w, h, 0.8 * w, 0.8 * w, w / 2, h / 2,
                  look_at(np.asarray(eye, float), np.asarray(target, float), up=(0.0, -1.0, 0.0)))


def _cameras() -> list[Camera]:
    # Three cameras close to the left half of the grid, one far camera seeing all of it.
    left = [_camera((-0.5 + dx, 0.0, -1.2), (-0.5 + dx, 0.0, 0.0), f"left{k}") for k, dx in enumerate((-0.1, 0, 0.1))]
    return left + [_camera((0.0, 0.0, -4.0), (0.0, 0.0, 0.0), "far")]


def _no_occlusion(camera: Camera) -> np.ndarray:
    return np.zeros((camera.height, camera.width))


def test_coloured_arrays_render_the_given_colours():
    from inceptiongs.app.coverage_mode import coloured_arrays

    arrays = _grid(3)
    arrays["sh"][:] = 7.0                               # view-dependent colour that must go
    colours = ramp_colours(np.arange(9.0), 8.0)
    out = coloured_arrays(arrays, colours)
    assert np.allclose(SH_C0 * out["sh"][:, 0, :] + 0.5, colours, atol=1e-6)
    assert not out["sh"][:, 1:, :].any() and out["means"] is arrays["means"]


def test_coverage_mode_counts_the_cameras_and_suggests_the_lone_view():
    from inceptiongs.app.coverage_mode import CoverageMode

    arrays, cameras = _grid(), _cameras()
    mode = CoverageMode()
    coloured = mode.update(arrays, cameras, _no_occlusion, version=1)
    x, y = arrays["means"][:, 0], arrays["means"][:, 1]
    # The far camera sees the whole grid; the close ones (0.75 x 0.56 half-extents at 1.2)
    # add 3 around x = -0.5 only.
    assert mode.counts[x > 0.4].max() == 1 and mode.counts[(np.abs(x + 0.5) < 0.15) & (np.abs(y) < 0.4)].min() == 4
    assert mode.vmax == 4.0
    assert np.allclose(SH_C0 * coloured["sh"][:, 0, :] + 0.5, ramp_colours(mode.counts, 4.0), atol=1e-6)
    assert mode.update(arrays, cameras, None, version=1) is coloured      # cached per version
    # What the far view shows (the right half at its resolution) no other camera shows.
    assert mode.suggest(arrays, cameras, _no_occlusion, k=1) == [3]


def test_coverage_counts_a_slice_of_the_cameras_a_frame_and_end_where_all_at_once_do():
    """The window counts a slice of the cameras a frame (a 300-view town's counts froze it for
    about 100 s); the counts end the same as all at once, and a new model starts over."""
    from inceptiongs.app.coverage_mode import CoverageMode

    arrays, cameras = _grid(), _cameras()
    whole = CoverageMode()
    expected = whole.update(arrays, cameras, _no_occlusion, version=1)
    sliced = CoverageMode()
    seen = []
    while (coloured := sliced.update(arrays, cameras, _no_occlusion, version=1, slice_s=0.0)) is None:
        seen.append(sliced.counting)
    assert seen == [(k, len(cameras)) for k in range(1, len(cameras))]   # one camera a call
    assert sliced.counting is None and np.array_equal(sliced.counts, whole.counts)
    assert np.array_equal(coloured["sh"], expected["sh"])
    assert sliced.update(arrays, cameras, _no_occlusion, version=2, slice_s=0.0) is None   # another model
    assert sliced.counting == (1, len(cameras))
    assert sliced.update(arrays, cameras, _no_occlusion, version=3) is not None and sliced.counting is None


@pytest.mark.gl
def test_coverage_mode_golden_screenshot_and_flag_suggestion(xvfb, tmp_path):
    from inceptiongs.app.sources import ViewerSource
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.io.flags import load_flags
    from inceptiongs.io.images import read_png, write_png

    source = ViewerSource("ply", tmp_path / "model.ply", _grid(), _cameras(), tmp_path)
    with opened(Viewer, source, 320, 240, visible=False, with_ui=False) as viewer:
        viewer.view.settings.mode = "coverage"
        camera = _camera((0.0, 0.0, -3.0), (0.0, 0.0, 0.0), "shot", size=(160, 120))
        image = viewer.render_image(camera)
        assert image.shape == (120, 160, 3)
        # Left half (4 views) bright yellow-green, right half (1 view) dark purple-blue.
        assert image[60, 40].mean() > image[60, 120].mean() + 0.2
        shot = np.round(image * 255).astype(np.uint8)
        if REGENERATE:
            write_png(GOLDEN, shot)
        if not GOLDEN.exists():
            pytest.fail(f"{GOLDEN} missing: regenerate with INCEPTIONGS_REGEN_GOLDEN=1")
        difference = np.abs(shot.astype(float) - read_png(GOLDEN).astype(float)) / 255.0
        assert difference.mean() <= 1.5 / 255 and np.percentile(difference, 99) <= 24 / 255
        names = viewer.flags.suggest(viewer.drawing, k=1)
        assert names == ["scarce 1"] and viewer.view.settings.mode == "coverage"
        flags = load_flags(viewer.flags.file)
        assert [f.camera.world_to_camera.tolist() for f in flags] == [source.cameras[3].world_to_camera.tolist()]
