"""Virtual-view geometry: nearest-view selection and the interpolated poses (stage II)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from inceptiongs.bootstrap.virtual_views import (DEFAULT_K, DEFAULT_L, nearest_training_views,
                                                 virtual_views)
from inceptiongs.camera import Camera, look_at, pose_distance, rotation_angle_between


def _camera(eye, target=(0.0, 0.0, 0.0), name="c", up=(0.0, -1.0, 0.0), width=40, height=30, focal=35.0):
    return Camera(name, width, height, focal, focal, width / 2, height / 2,
                  look_at(np.array(eye, float), np.array(target, float), up=up))


def _ring(count=8, radius=3.0):
    return [_camera((radius * math.sin(a), 0.3 * math.cos(3 * a), -radius * math.cos(a)), name=f"r{i}")
            for i, a in enumerate(np.linspace(0, 2 * math.pi, count, endpoint=False))]


def test_nearest_views_sorted_by_pose_distance_ties_by_index():
    cameras = _ring(10)
    target = _camera((0.4, 0.1, -2.9), name="target")
    candidates = [9, 0, 3, 1, 2, 7, 5]
    chosen = nearest_training_views(target, cameras, candidates, k=4)
    brute = sorted(candidates, key=lambda i: (pose_distance(target.world_to_camera,
                                                            cameras[i].world_to_camera), i))
    assert chosen == brute[:4]
    distances = [pose_distance(target.world_to_camera, cameras[i].world_to_camera) for i in chosen]
    assert distances == sorted(distances)
    # Only candidates are considered: camera 4, 6, 8 never appear.
    assert set(chosen) <= set(candidates)


def test_nearest_views_tie_goes_to_lower_index_and_k_is_clipped():
    base = _camera((0.0, 0.0, -3.0))
    cameras = [base.with_pose(base.world_to_camera, name=f"dup{i}") for i in range(4)]
    assert nearest_training_views(base, cameras, [3, 1, 2], k=2) == [1, 2]
    assert nearest_training_views(base, cameras, [3, 1, 2], k=10) == [1, 2, 3]
    assert nearest_training_views(base, cameras, [], k=3) == []
    with pytest.raises(ValueError, match="outside"):
        nearest_training_views(base, cameras, [4], k=1)


def test_virtual_view_count_spacing_and_names():
    cameras = _ring(8)
    target = _camera((0.5, 0.0, -2.9), name="target")
    views = virtual_views(target, cameras, range(8), k=3, l=5)
    assert len(views) == 3 * 5
    assert len({v.name for v in views}) == len(views)
    sources = nearest_training_views(target, cameras, range(8), k=3)
    assert [v.source for v in views] == [s for s in sources for _ in range(5)]
    for index, view in enumerate(views):
        assert view.t == pytest.approx((index % 5 + 1) / 5)
        assert 0.0 < view.t <= 1.0
        # Intrinsics are the target's.
        cam = view.camera
        assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (
            target.width, target.height, target.fx, target.fy, target.cx, target.cy)
    default = virtual_views(target, cameras, range(8))
    assert len(default) == DEFAULT_K * DEFAULT_L


def test_slerp_end_points_and_lerp_centres():
    cameras = _ring(6)
    target = _camera((0.8, -0.4, -2.5), target=(0.2, 0.1, 0.3), name="target")
    views = virtual_views(target, cameras, range(6), k=2, l=6)
    for view in views:
        source = cameras[view.source]
        expected_centre = (1 - view.t) * target.center + view.t * source.center
        np.testing.assert_allclose(view.camera.center, expected_centre, atol=1e-12)
        total = rotation_angle_between(target.rotation, source.rotation)
        # On the geodesic: angle to target = t * total and to source = (1 - t) * total.
        assert rotation_angle_between(target.rotation, view.camera.rotation) == pytest.approx(
            view.t * total, abs=1e-7)
        assert rotation_angle_between(source.rotation, view.camera.rotation) == pytest.approx(
            (1 - view.t) * total, abs=1e-7)
        if view.t == 1.0:
            np.testing.assert_allclose(view.camera.world_to_camera, source.world_to_camera, atol=1e-12)
    # t -> 0 approaches the target pose (t = 0 itself is excluded).
    fine = virtual_views(target, cameras, range(6), k=1, l=1000)[0]
    assert fine.t == pytest.approx(1e-3)
    assert pose_distance(fine.camera.world_to_camera, target.world_to_camera) < 2e-3 * pose_distance(
        cameras[fine.source].world_to_camera, target.world_to_camera) + 1e-12


def test_target_equal_to_a_training_view_collapses_but_is_kept():
    cameras = _ring(5)
    target = cameras[2].with_pose(cameras[2].world_to_camera, name="target")
    views = virtual_views(target, cameras, range(5), k=2, l=3)
    assert len(views) == 6
    assert views[0].source == 2  # distance 0 sorts first
    for view in views[:3]:
        np.testing.assert_allclose(view.camera.world_to_camera, target.world_to_camera, atol=1e-12)
        assert np.all(np.isfinite(view.camera.world_to_camera))


def test_antipodal_orientations_stay_proper_rotations_on_the_geodesic():
    target = _camera((0.0, 0.0, -3.0), target=(0.0, 0.0, 0.0), name="target")
    # Same centre, looking the opposite way: a 180 degree turn about the vertical axis.
    opposite = _camera((0.0, 0.0, -3.0), target=(0.0, 0.0, -6.0), name="back")
    assert rotation_angle_between(target.rotation, opposite.rotation) == pytest.approx(math.pi)
    views = virtual_views(target, [opposite], [0], k=1, l=4)
    for view in views:
        rotation = view.camera.rotation
        assert np.all(np.isfinite(rotation))
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        assert rotation_angle_between(target.rotation, rotation) == pytest.approx(view.t * math.pi, abs=1e-7)
    np.testing.assert_allclose(views[-1].camera.world_to_camera, opposite.world_to_camera, atol=1e-12)


def test_bad_arguments_are_rejected():
    cameras = _ring(3)
    with pytest.raises(ValueError):
        virtual_views(cameras[0], cameras, [1, 2], k=2, l=0)
    with pytest.raises(ValueError):
        nearest_training_views(cameras[0], cameras, [1, 2], k=-1)
