"""Sparse points triangulated from photos with known poses (inceptiongs.train.triangulate)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from inceptiongs.scene.demo import Textures, trace
from inceptiongs.scene.loader import load_scene
from inceptiongs.train.triangulate import (TriangulationConfig, connected_labels, epipolar_distance,
                                           fundamental_matrix, training_points, triangulate_points,
                                           triangulate_tracks)
from demo_cases import copy_of_demo_scene
from scene_cases import known_cameras, known_points, project


def _normalised_rays(camera, pixels: np.ndarray) -> np.ndarray:
    homogeneous = np.concatenate([pixels, np.ones((len(pixels), 1))], 1)
    return (homogeneous @ np.linalg.inv(camera.intrinsics).T)[:, :2]


def test_two_view_triangulation_is_exact():
    cameras = known_cameras(2)
    points = known_points()
    rays = np.stack([_normalised_rays(c, project(c, points)) for c in cameras], 1)      # [P, 2, 2]
    poses = np.broadcast_to(np.stack([c.world_to_camera[:3] for c in cameras]), (len(points), 2, 3, 4))
    estimate = triangulate_tracks(poses, rays)
    # Far from the origin (1000 units) on purpose: the DLT must still be exact to rounding.
    np.testing.assert_allclose(estimate, points, atol=1e-6)


def test_many_view_triangulation_averages_noise():
    cameras = known_cameras(4)
    points = known_points()
    rng = np.random.default_rng(0)
    pixels = [project(c, points) + rng.normal(0, 0.3, (len(points), 2)) for c in cameras]
    rays = np.stack([_normalised_rays(c, p) for c, p in zip(cameras, pixels)], 1)
    poses = np.broadcast_to(np.stack([c.world_to_camera[:3] for c in cameras]), (len(points), 4, 3, 4))
    two = np.linalg.norm(triangulate_tracks(poses[:, :2], rays[:, :2]) - points, axis=1).mean()
    four = np.linalg.norm(triangulate_tracks(poses, rays) - points, axis=1).mean()
    assert four < two


def test_fundamental_matrix_from_known_poses():
    cam_a, cam_b = known_cameras(2)
    points = known_points()
    x_a, x_b = project(cam_a, points), project(cam_b, points)
    f = fundamental_matrix(cam_a, cam_b)
    assert epipolar_distance(f, x_a, x_b).max() < 1e-6
    # A wrong correspondence (the next point) is far from its epipolar line.
    assert np.median(epipolar_distance(f, x_a, np.roll(x_b, 1, axis=0))) > 1.0


def test_connected_labels():
    edges = np.array([[0, 1], [1, 2], [4, 5], [6, 5]])
    labels = connected_labels(7, edges)
    assert labels.tolist() == [0, 0, 0, 3, 4, 4, 4]
    assert connected_labels(3, np.zeros((0, 2), np.int64)).tolist() == [0, 1, 2]


@pytest.fixture(scope="module")
def demo_scene_without_points(tmp_path_factory):
    root = copy_of_demo_scene(tmp_path_factory.mktemp("tri") / "scene")
    scene = load_scene(root)
    return dataclasses.replace(scene, points=np.zeros((0, 3)), point_colors=None)


def test_scene_without_points_gets_triangulated_points(demo_scene_without_points):
    scene = demo_scene_without_points
    views = list(range(0, len(scene.cameras), 2))
    images = {i: scene.load_image(i) for i in views}
    messages = []
    config = TriangulationConfig(min_points=50)
    points, colours, triangulated = training_points(scene, views, images, True, messages.append, config)
    assert triangulated
    assert len(points) >= 50 and colours.shape == (len(points), 3) and colours.dtype == np.uint8
    assert "triangulated" in messages[-1]
    # Every point lies on the ray-traced surface: the distance along the ray from a camera
    # that sees it matches the analytic hit within 2% for nearly all points.
    original = scene.normalization.to_original(points)
    camera = scene.normalization.camera_to_original(scene.cameras[views[0]])
    directions = original - camera.center
    distance = np.linalg.norm(directions, axis=1)
    _, hit = trace(np.broadcast_to(camera.center, original.shape), directions / distance[:, None], Textures(np.zeros((64, 64))))
    in_front = (original - camera.center) @ camera.rotation[2] > 0
    visible = in_front & np.isfinite(hit) & (hit > distance * 0.98)   # not occluded from this camera
    relative = np.abs(hit[visible] - distance[visible]) / distance[visible]
    assert visible.sum() >= 0.3 * len(points)
    # Sub-pixel keypoints on 192 px photos: about 1% depth noise, unbiased.
    assert np.median(relative) < 0.01
    assert np.mean(relative < 0.05) > 0.85
    # The second call is served from the scene's work folder.
    again, _, _ = training_points(scene, views, images, True, messages.append, config)
    assert "(cached)" in messages[-1]
    np.testing.assert_array_equal(again, points)


def test_scene_with_points_or_disabled_is_left_alone(demo_scene_without_points):
    scene = demo_scene_without_points
    messages = []
    points, colours, triangulated = training_points(scene, [0, 1], {}, False, messages.append)
    assert len(points) == 0 and colours is None and not triangulated and not messages
    own = dataclasses.replace(scene, points=np.ones((5, 3)))
    points, _, _ = training_points(own, [0, 1], {}, True, messages.append)
    assert points.shape == (5, 3) and not messages


def test_sparse_depth_samples_lie_on_the_sparse_surface():
    from inceptiongs.camera import Camera
    from inceptiongs.train.init_gaussians import gaussians_from_sparse_depth, sparse_depth_samples

    camera = Camera("c", 40, 30, 35.0, 35.0, 20.0, 15.0, np.eye(4))
    # Two fronto-parallel layers: left half of the view at depth 2, right half at depth 6.
    grid = np.stack(np.meshgrid(np.linspace(-1.2, 1.2, 25), np.linspace(-1, 1, 20)), -1).reshape(-1, 2)
    left, right = grid[grid[:, 0] < -0.1], grid[grid[:, 0] > 0.1]
    points = np.concatenate([np.c_[left * 2, np.full(len(left), 2.0)], np.c_[right * 6, np.full(len(right), 6.0)]])
    image = np.random.default_rng(0).random((30, 40, 3))
    samples, colours, scales = sparse_depth_samples(camera, image, points, 300, np.random.default_rng(1))
    z = samples[:, 2]
    u = samples[:, 0] / z * camera.fx + camera.cx
    assert np.all(np.isclose(z, 2.0) | np.isclose(z, 6.0))
    assert np.all(z[u < 15] == pytest.approx(2.0)) and np.all(z[u > 25] == pytest.approx(6.0))
    rows = (samples[:, 1] / z * camera.fy + camera.cy).astype(int)
    np.testing.assert_array_equal(colours, np.clip(image[rows, u.astype(int)] * 255 + 0.5, 0, 255).astype(np.uint8))
    np.testing.assert_allclose(scales, 2.0 * z / camera.fx)
    # Nothing in view: no samples; the model builder then falls back to the points.
    behind = points * np.array([1, 1, -1])
    assert len(sparse_depth_samples(camera, image, behind, 10, np.random.default_rng(0))[0]) == 0
    gaussians, message = gaussians_from_sparse_depth([camera], [image], points, 0, seed=0, count=50)
    assert len(gaussians) == 50 and "photo-coloured" in message


def test_triangulation_holds_one_photo_at_a_time_beside_the_store(demo_scene_without_points, monkeypatch):
    # Stage I hands its photo store to training_points. With the store's budget at 2 photos, a
    # pass over 28 views must never have more than those 2 plus the one being read alive
    # (a list of every view's photo would hold 28 at the end of its first pass).
    from inceptiongs.scene import photo_store
    from inceptiongs.scene.photo_store import PhotoStore, photo_bytes
    from photo_counting import AliveCount

    scene = demo_scene_without_points
    views = list(range(len(scene.cameras)))
    assert len(views) >= 20
    count = AliveCount()
    monkeypatch.setattr(photo_store, "photo_tensor", count.counting(photo_store.photo_tensor))
    store = PhotoStore(scene, views, budget=2 * photo_bytes(scene, 0))
    config = TriangulationConfig(max_features=400, min_points=1)
    points, colours, triangulated = training_points(scene, views, store, True, lambda line: None, config)
    store.close()
    assert triangulated and len(points) > 0
    assert count.peak <= 3, count.peak
    assert count.reads >= 2 * len(views)        # the key pass and the feature pass each read every view
    # The same points and colours as from photos held in a dict.
    again, again_colours = triangulate_points([scene.cameras[i] for i in views],
                                              [scene.load_image(i) for i in views], config)
    np.testing.assert_array_equal(again, points)
    np.testing.assert_array_equal(again_colours, colours)
