"""The viewer opens a model file of every format (.ply binary/ASCII/compressed, .splat, .spz)
and refuses other files with one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from inceptiongs.errors import InputError
from inceptiongs.io.models import read_model, write_model
from model_cases import random_model


@pytest.mark.parametrize("suffix", ["ply", "compressed.ply", "splat", "spz"])
def test_viewer_opens_every_model_format(tmp_path, suffix):
    from inceptiongs.app.sources import open_source

    path = tmp_path / f"model.{suffix}"
    write_model(path, random_model(40, 1))
    source = open_source(path)
    assert source.kind == "ply" and source.model_path == path
    expected = read_model(path).numpy()
    assert set(source.gaussians) == set(expected)
    for name, values in expected.items():
        assert np.array_equal(source.gaussians[name], values), name


def test_viewer_refuses_a_file_that_is_not_a_model(tmp_path):
    from inceptiongs.app.sources import open_source

    path = tmp_path / "notes.txt"
    path.write_text("hello")
    with pytest.raises(InputError, match=r"notes.txt: not a scene folder, a model file \(.ply, .splat, .spz\)"):
        open_source(path)
    broken = tmp_path / "broken.spz"
    broken.write_bytes(b"\x1f\x8b" + b"\0" * 30)
    with pytest.raises(InputError) as info:
        open_source(broken)
    assert str(info.value).startswith(str(broken)) and "\n" not in str(info.value)


def test_points_for_a_scene_without_any_read_its_photos_one_at_a_time(tmp_path, monkeypatch):
    # The viewer opening a scene with no model and no sparse points triangulates points to
    # show: its 28 photos pass through one at a time, never all held at once.
    from inceptiongs.app.sources import triangulated_splats
    from inceptiongs.scene import photo_store
    from demo_cases import copy_of_demo_scene
    from photo_counting import AliveCount

    root = copy_of_demo_scene(tmp_path / "scene")
    (root / "sparse" / "0" / "points3D.bin").write_bytes(np.uint64(0).tobytes())   # no sparse points
    count = AliveCount()
    monkeypatch.setattr(photo_store, "photo_tensor", count.counting(photo_store.photo_tensor))
    splats, line = triangulated_splats(root)
    assert splats is not None and "triangulated" in line, line
    assert count.reads >= 2 * 20
    assert count.peak == 1, count.peak


def test_each_saved_format_has_a_view_file_of_its_own():
    """web.splat and web.spz saved side by side shared web.view.json: the second save's camera
    was the one both reopened at."""
    from inceptiongs.app.sources import saved_view_file

    names = [saved_view_file(Path("/out") / name).name for name in
             ("web.ply", "web.compressed.ply", "web.splat", "web.spz", "WEB.PLY")]
    assert names == ["web.view.json", "web.compressed.view.json", "web.splat.view.json", "web.spz.view.json",
                     "WEB.view.json"]
    assert len(set(names)) == len(names)
