"""The demo's courtyard: a loadable scene whose designed thin region (the north facade's close
views) is what coverage ranks as seen least."""

from __future__ import annotations

import json

import numpy as np
import pytest

from inceptiongs.evaluation import coverage as cov
from inceptiongs.scene import courtyard
from inceptiongs.scene.demo import Textures, sample_points
from inceptiongs.scene.loader import load_scene


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return courtyard.write_courtyard_scene(tmp_path_factory.mktemp("courtyard") / "scene", size="tiny",
                                           progress=False)


def test_courtyard_loads_with_its_camera_groups(root):
    scene = load_scene(root)
    width, height, n_dense, n_scarce = courtyard.COURTYARD_SIZES["tiny"]
    meta = json.loads((root / "demo_scene.json").read_text())
    assert scene.format == "colmap-binary" and scene.warnings == [] and meta["scene"] == "courtyard"
    assert len(meta["dense_cameras"]) == n_dense and len(meta["scarce_cameras"]) == n_scarce
    assert {(c.width, c.height) for c in scene.cameras} == {(width, height)}
    assert len(scene.points) > 500
    photo = scene.load_image(0)
    assert photo.shape == (height, width, 3) and float(np.std(photo)) > 0.05   # textured, not flat


def test_coverage_ranks_the_north_facade_views_scarcest():
    cameras, dense, scarce = courtyard.courtyard_cameras("small")
    tex = Textures(noise=np.random.default_rng(0).random((64, 64)))
    # Surface points that any view shows, so the close views' content is in the sample too.
    points, _ = sample_points(cameras, lambda o, d: courtyard.trace_courtyard(o, d, tex),
                              np.random.default_rng(1), per_camera=60)
    visible = cov.visibility_matrix(points, cameras)
    directions = cov.view_directions(points, np.array([c.center for c in cameras]))
    sources = np.array([c.name in set(dense) for c in cameras])
    scores = cov.view_scarcity(directions, visible, sources, resolution=cov.view_resolution(points, cameras))
    # Every close view of the north facade is ranked among the scarcest (a dense view that
    # stands alone close to another facade may rank with them: it is a unique viewpoint too).
    ranked = [cameras[i].name for i in cov.scarcest_views(scores, len(scarce) + 2)]
    assert set(scarce) <= set(ranked)
    assert scores[~sources].min() > 0.9 and np.median(scores[sources]) < 0.3
    # The dense views see the north facade (y = 6) at well under half the resolution (pixels per
    # metre) at which they see the south facade (y = -6): only from far away.
    resolution = cov.view_resolution(points, cameras)
    best = {}
    for y in (6.0, -6.0):
        on = np.abs(points[:, 1] - y) < 1e-6
        best[y] = np.median(np.max(np.where(visible[on][:, sources], resolution[on][:, sources], 0.0), axis=1))
    assert best[6.0] < 0.5 * best[-6.0]
