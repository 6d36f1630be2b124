"""The passes before a large capture's first step, made fast, against their one-at-a-time
definitions: neighbour views (all pairs prefiltered, then checked exactly) and the compiled
projection of a large cloud into a view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at, project_points, rotation_angle_between
from inceptiongs.train.neighbours import neighbour_views
from inceptiongs.train.point_projection import COMPILED_FROM, project_cloud


def pairwise_reference(cameras, candidates, max_count, max_angle_deg):
    """The definition, one pair at a time."""
    out = {}
    for i in candidates:
        scored = []
        for j in candidates:
            if j == i:
                continue
            distance = float(np.linalg.norm(cameras[i].center - cameras[j].center))
            if distance < 1e-9:
                continue
            if rotation_angle_between(cameras[i].rotation, cameras[j].rotation) <= math.radians(max_angle_deg):
                scored.append((distance, j))
        scored.sort()
        out[i] = [j for _, j in scored[:max_count]]
    return out


def rig(rng: np.random.Generator, count: int) -> list[Camera]:
    """Street-like cameras: positions on a grid (exact ties in distance), four headings, some
    coincident centres, plus random ones."""
    cameras = []
    for k in range(count):
        if k % 5 == 4:
            eye = rng.uniform(-10, 10, 3)
            target = eye + rng.normal(size=3)
        else:
            eye = np.array([float(k % 7), 0.0, float((k // 7) % 4)])
            heading = (k % 4) * math.pi / 2
            target = eye + np.array([math.cos(heading), 0.1 * (k % 3), math.sin(heading)])
        cameras.append(Camera(f"c{k}", 64, 48, 50.0, 50.0, 32.0, 24.0, look_at(eye, target)))
    return cameras


@pytest.mark.parametrize("max_count,max_angle", [(8, 30.0), (3, 90.0), (50, 10.0)])
def test_neighbour_views_are_the_pairwise_definition(max_count, max_angle):
    cameras = rig(np.random.default_rng(0), 90)
    candidates = list(range(0, 90, 1))[3:]
    assert neighbour_views(cameras, candidates, max_count, max_angle) == \
        pairwise_reference(cameras, candidates, max_count, max_angle)


def test_a_large_cloud_projects_as_project_points_does():
    rng = np.random.default_rng(1)
    points = np.concatenate([rng.uniform(-5, 5, (COMPILED_FROM, 3)), np.zeros((10, 3)),
                             rng.uniform(-1e-3, 1e-3, (10, 3)) + np.array([0, 0, 3.0])])
    camera = Camera("c", 64, 48, 50.0, 55.0, 31.5, 24.5, look_at(np.array([0.3, 0.2, -3.0]), np.zeros(3)))
    pixels, z, inside = project_cloud(points, camera)
    ref_pixels, ref_z, ref_inside = project_points(points, camera)
    np.testing.assert_allclose(z, ref_z, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(pixels[ref_inside], ref_pixels[ref_inside], rtol=1e-9, atol=1e-9)
    # Inside may differ only for a point within rounding of the image's border or the near plane.
    differ = inside != ref_inside
    assert differ.sum() <= 1 and inside.sum() > 1000
