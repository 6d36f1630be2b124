"""Coverage (directional viewing density) on synthetic camera rigs with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at
from inceptiongs.evaluation import coverage as cov


def _camera(eye, target=(0.0, 0.0, 0.0), name="c", size=(64, 48)) -> Camera:
    w, h = size
    return Camera(name, w, h, 50.0, 50.0, w / 2, h / 2, look_at(np.asarray(eye, float), np.asarray(target, float),
                                                               up=(0.0, 0.0, 1.0)))


def _ring(n: int, radius: float = 4.0, height: float = 1.0, start_deg: float = 0.0) -> list[Camera]:
    return [_camera((radius * math.cos(a), radius * math.sin(a), height), name=f"{k:02d}")
            for k, a in enumerate(np.radians(start_deg + np.arange(n) * 360.0 / n))]


@pytest.mark.parametrize("n", [1, 3, 7])
def test_a_point_seen_by_n_cameras_reports_n(n):
    # n cameras look at the origin; as many again look away from it.
    looking = _ring(n)
    away = [_camera(c.center, target=2 * c.center) for c in _ring(n, start_deg=10.0)]
    visible = cov.visibility_matrix(np.zeros((1, 3)), looking + away)
    assert cov.view_counts(visible).tolist() == [n]
    assert visible[0, :n].all() and not visible[0, n:].any()


def test_a_nearer_surface_in_the_depth_map_hides_the_point():
    cameras = _ring(4)
    points = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    far = [np.full((12, 16), 10.0)] * 4
    blocked = [np.full((12, 16), 10.0)] * 3 + [np.full((12, 16), 1.0)]  # a wall 1 unit in front of camera 3
    assert cov.view_counts(cov.visibility_matrix(points, cameras, far)).tolist() == [4, 4]
    assert cov.view_counts(cov.visibility_matrix(points, cameras, blocked)).tolist() == [3, 3]
    # No surface (depth 0) hides nothing.
    empty = [np.zeros((12, 16))] * 4
    assert cov.view_counts(cov.visibility_matrix(points, cameras, empty)).tolist() == [4, 4]


def test_angular_radius_grows_with_the_spread_of_views():
    point = np.zeros((1, 3))
    one_side = [_camera((4 * math.cos(a), 4 * math.sin(a), 0.0)) for a in np.radians([0, 5, 10])]
    around = _ring(6, height=0.0)
    narrow = cov.angular_radius_deg(cov.view_directions(point, np.array([c.center for c in one_side])),
                                    np.ones((1, 3), bool))
    wide = cov.angular_radius_deg(cov.view_directions(point, np.array([c.center for c in around])),
                                  np.ones((1, 6), bool))
    assert narrow[0] < 10.0 and wide[0] == pytest.approx(90.0, abs=1e-6)
    opposite = cov.view_directions(point, np.array([[1.0, 0, 0], [-1.0, 0, 0]]))
    assert cov.angular_radius_deg(opposite, np.ones((1, 2), bool))[0] == pytest.approx(90.0)
    assert cov.angular_radius_deg(opposite, np.array([[True, False]]))[0] == pytest.approx(0.0)


def test_a_uniformly_sampled_hemisphere_is_flat():
    n = 2000
    samples = cov.fibonacci_hemisphere(n)
    _, elevation, grid = cov.hemisphere_grid(36, 9)
    density = cov.directional_density(samples, np.ones(n), grid)
    expected = n / (2 * math.pi)
    # Flat to 3 % everywhere, the rim (lowest elevation band) included.
    assert np.abs(density / expected - 1).max() < 0.03
    # Halving the weights halves the density (it is linear in the views).
    assert np.allclose(cov.directional_density(samples, np.full(n, 0.5), grid), density / 2)
    # Directions below the horizon count nothing.
    below = samples * np.array([1, 1, -1])
    assert cov.directional_density(below[below[:, 2] < -1e-9], np.ones(int((below[:, 2] < -1e-9).sum())),
                                   grid).max() == 0.0


def test_a_removed_cluster_shows_as_a_hole_in_the_right_place():
    samples = cov.fibonacci_hemisphere(3000)
    hole = np.array([math.cos(math.radians(30)) * math.cos(math.radians(200)),
                     math.cos(math.radians(30)) * math.sin(math.radians(200)), math.sin(math.radians(30))])
    kept = samples[samples @ hole < math.cos(math.radians(35))]  # a 35-degree cap removed
    azimuth, elevation, grid = cov.hemisphere_grid(72, 18)
    density = cov.directional_density(kept, np.ones(len(kept)), grid)
    row, col = np.unravel_index(np.argmin(density), density.shape)
    assert math.degrees(azimuth[col]) == pytest.approx(200.0, abs=10.0)
    assert math.degrees(elevation[row]) == pytest.approx(30.0, abs=10.0)
    # The kernel (15 degrees) reaches 35 degrees into the hole only with exp(-(35/15)^2 / 2) ~ 7 %.
    assert density[row, col] < 0.15 * np.median(density)
    # Away from the hole the map stays flat.
    far = (grid @ hole) < math.cos(math.radians(75))
    assert np.abs(density[far] / (len(samples) / (2 * math.pi)) - 1).max() < 0.05


def test_region_directions_put_views_where_they_are_in_the_hemisphere_frame():
    frame = cov.hemisphere_frame(np.array([0.0, 0.0, 1.0]))
    assert np.allclose(frame, np.eye(3))
    cameras = [_camera((4.0, 0.0, 4.0)), _camera((-4.0, 0.0, 0.5))]
    points = np.zeros((1, 3))
    directions = cov.view_directions(points, np.array([c.center for c in cameras]))
    samples, weights = cov.region_directions(directions, np.ones((1, 2), bool), np.array([True]), frame)
    assert np.allclose(samples[0], np.array([1, 0, 1]) / math.sqrt(2)) and weights.tolist() == [1.0, 1.0]
    azimuth, elevation, grid = cov.hemisphere_grid(36, 9)
    density = cov.directional_density(samples[:1], weights[:1], grid)
    row, col = np.unravel_index(np.argmax(density), density.shape)
    assert math.degrees(elevation[row]) == pytest.approx(45.0, abs=5.0) and math.degrees(azimuth[col]) < 10.0
    # The rig's up is +z whatever the cameras look at: a full ring, half a ring looking down
    # steeply (the mean image-down axis alone would tilt towards the missing half), and a
    # forward-facing rig whose image right axes are all parallel.
    assert np.allclose(cov.up_vector(_ring(5)), [0, 0, 1], atol=1e-6)
    half = [_camera((4 * math.cos(a), 4 * math.sin(a), 3.0)) for a in np.radians(np.linspace(0, 180, 7))]
    assert np.allclose(cov.up_vector(half), [0, 0, 1], atol=1e-6)
    facing = [_camera((x, -4.0, 1.0 + 0.1 * x), target=(x, 0.0, 0.5)) for x in np.linspace(-1, 1, 5)]
    assert np.allclose(cov.up_vector(facing), [0, 0, 1], atol=0.15)


def test_view_scarcity_ranks_the_lone_view_first():
    # Seven cameras watch a patch of points from the south; one watches it from the north.
    points = np.random.default_rng(0).uniform(-0.5, 0.5, (50, 3)) * np.array([1, 1, 0])
    south = [_camera((x, -4.0, 1.0), name=f"s{k}") for k, x in enumerate(np.linspace(-1, 1, 7))]
    north = [_camera((0.0, 4.0, 1.0), name="n")]
    cameras = south + north
    visible = cov.visibility_matrix(points, cameras)
    assert visible.all()
    directions = cov.view_directions(points, np.array([c.center for c in cameras]))
    scores = cov.view_scarcity(directions, visible)
    assert cov.scarcest_views(scores, 1) == [7]
    assert scores[7] == pytest.approx(1.0)      # no other view near its direction
    assert scores[:7].max() < 0.35              # each south view has >= 2 neighbours within 30 degrees
    # Counting only the north view as a source, every south view becomes scarce.
    sources = np.zeros(8, bool)
    sources[7] = True
    assert np.allclose(cov.view_scarcity(directions, visible, sources)[:7], 1.0)
    assert cov.scarcest_views(scores, 2, candidates=[0, 3, 6]) == sorted([0, 3, 6], key=lambda i: -scores[i])[:2]


def test_the_hemisphere_map_covers_only_the_region_of_interest():
    from inceptiongs.evaluation.coverage_map import compute

    # Two patches of points: the west one is watched by cameras to its west, the east one by
    # cameras to its east; each camera's depth map shows a surface at 4.5 units, so the far
    # patch behind its own is hidden.
    rng = np.random.default_rng(0)
    west = rng.uniform(-0.3, 0.3, (40, 3)) * np.array([1, 1, 0]) + np.array([-5.0, 0, 0])
    east = rng.uniform(-0.3, 0.3, (40, 3)) * np.array([1, 1, 0]) + np.array([5.0, 0, 0])
    cameras = ([_camera((-8.0, y, 2.0), target=(-5.0, 0.0, 0.0)) for y in (-1.0, 0.0, 1.0)]
               + [_camera((8.0, y, 2.0), target=(5.0, 0.0, 0.0)) for y in (-1.0, 0.0, 1.0)])
    points = np.concatenate([west, east])
    roi = (np.array([-6.0, -1.0, -1.0]), np.array([-4.0, 1.0, 1.0]))
    result = compute(points, cameras, np.ones(6, bool), depths=[np.full((48, 64), 4.5)] * 6, roi=roi)
    assert result.in_region.sum() == 40 and result.counts.tolist() == [3] * 80
    row, col = np.unravel_index(np.argmax(result.density), result.density.shape)
    assert math.degrees(result.azimuth[col]) == pytest.approx(180.0, abs=10.0)   # seen from the west
    east_cells = (np.degrees(result.azimuth) < 45) | (np.degrees(result.azimuth) > 315)
    assert result.density[:, east_cells].max() < 0.01 * result.density.max()


def test_a_scene_without_points_is_triangulated_one_photo_at_a_time(tmp_path, monkeypatch):
    # `inceptiongs coverage SCENE` on a scene without sparse points triangulates from every
    # view: its 28 photos must pass through one at a time, not all held for the triangulation.
    import dataclasses

    from inceptiongs.evaluation.coverage_map import scene_coverage
    from inceptiongs.scene import photo_store
    from inceptiongs.scene.loader import load_scene
    from demo_cases import copy_of_demo_scene
    from photo_counting import AliveCount

    scene = load_scene(copy_of_demo_scene(tmp_path / "scene"))
    scene = dataclasses.replace(scene, points=np.zeros((0, 3)), point_colors=None)
    assert len(scene.cameras) >= 20
    count = AliveCount()
    monkeypatch.setattr(photo_store, "photo_tensor", count.counting(photo_store.photo_tensor))
    coverage = scene_coverage(scene)
    assert coverage.point_source == "points triangulated from the photos"
    assert count.peak == 1, count.peak
    assert count.reads >= 2 * len(scene.cameras)


def test_a_runs_coverage_measures_the_scene_not_its_sky_shell(tmp_path):
    """The sky shell (4 x the scene's extent away, opaque from its start) is no surface: a briefly
    trained town's map took most of its points from it and measured the sky around the town."""
    import torch

    from inceptiongs.cli import main
    from inceptiongs.evaluation.coverage_map import run_coverage
    from inceptiongs.evaluation.protocols import Split
    from inceptiongs.runs.load import load_run
    from inceptiongs.train.sky import in_background, shell_geometry

    scene_dir, run = tmp_path / "town", tmp_path / "run"
    assert main(["demo-scene", str(scene_dir), "--scene", "town", "--views", "32", "--size", "tiny"]) == 0
    assert main(["train", str(scene_dir), "--out", str(run), "--iterations", "20"]) == 0
    gaussians, scene, _ = load_run(run)
    split = Split.load(run / "split.json", scene.cameras)
    centre, radius = shell_geometry([scene.cameras[i] for i in split.train], scene.points)
    sphere = torch.tensor([*centre, radius], dtype=gaussians.means.dtype)
    opacity = torch.sigmoid(gaussians.opacity_logits.reshape(-1))
    shell = in_background(gaussians.means, sphere)
    # The shell is there and opaque enough to pass the coverage's opacity cut.
    assert shell.sum() > 100 and (opacity[shell] >= 0.2).float().mean() > 0.5
    coverage = run_coverage(run)
    distance = np.linalg.norm(coverage.points - centre, axis=1)
    assert len(coverage.points) > 10 and distance.max() <= 0.5 * radius
