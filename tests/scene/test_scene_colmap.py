"""COLMAP scenes: the real statuette model, synthetic pinhole and distorted models, text
models, downscaling and normalisation."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pycolmap
import pytest
import torch

from conftest import require_data
from inceptiongs.gaussians import Gaussians
from inceptiongs.scene.colmap import write_colmap_binary
from inceptiongs.scene.loader import load_scene
from inceptiongs.scene.undistort import distort_normalized, undistort_normalized
from scene_cases import HEIGHT, WIDTH, blob_centroids, known_cameras, known_points, project, write_images


def _project_pinhole(camera, points):
    """Continuous pixel coordinates [P, 2] and depths [P] of points in a loaded scene's frame."""
    p = points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
    return np.stack([camera.fx * p[:, 0] / p[:, 2] + camera.cx, camera.fy * p[:, 1] / p[:, 2] + camera.cy], 1), p[:, 2]


def test_statuette_cameras_and_points_match_pycolmap():
    root = require_data("statuette")
    scene = load_scene(root)
    recon = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    assert scene.format == "colmap-binary"
    assert len(scene.cameras) == 23 and scene.camera_models == ["PINHOLE"] * 23
    assert scene.warnings == []
    by_name = {im.name: im for im in recon.images.values()}
    assert {c.width for c in scene.cameras} == {1000}
    # The data README says 1000x657; the model's cameras are 656..662 rows high (each
    # matching its image file), so the heights are checked against COLMAP itself.
    assert 657 in {c.height for c in scene.cameras}
    for camera in scene.cameras:
        assert camera.height == by_name[camera.name].camera.height

    points = [p for _, p in sorted(recon.points3D.items())]
    original = np.array([p.xyz for p in points])
    assert scene.points.shape == (1443, 3) and scene.point_colors.shape == (1443, 3)
    assert np.allclose(scene.normalization.to_original(scene.points), original, rtol=0, atol=1e-9)
    assert np.array_equal(scene.point_colors, np.array([p.color for p in points]))

    checked = 0
    for index, camera in enumerate(scene.cameras):
        image = by_name[camera.name]
        ours, depth = _project_pinhole(camera, scene.points)
        for k, xyz in enumerate(original):
            theirs = image.project_point(xyz)
            if theirs is None:
                assert depth[k] <= 0
                continue
            assert np.abs(ours[k] - np.asarray(theirs).ravel()).max() < 1e-6
            checked += 1
    assert checked > 20000  # most points are in front of most cameras


def test_statuette_normalisation_centres_cameras_at_unit_extent():
    scene = load_scene(require_data("statuette"))
    centers = np.array([c.center for c in scene.cameras])
    assert np.allclose(centers.mean(axis=0), 0, atol=1e-12)
    assert np.max(np.linalg.norm(centers, axis=1)) == pytest.approx(1.0, abs=1e-12)
    image = scene.load_image(0)
    assert image.shape == (scene.cameras[0].height, 1000, 3) and image.dtype == np.float32
    assert 0 <= image.min() and image.max() <= 1


def _write_colmap_scene(root, model, params_for, dists, layout="sparse/0", cameras=None):
    cameras = known_cameras() if cameras is None else cameras
    write_images(root / "images", cameras, dists)
    (root / layout).mkdir(parents=True, exist_ok=True)
    points = known_points()
    colours = np.tile(np.array([[10, 200, 30]], np.uint8), (len(points), 1))
    write_colmap_binary(root / layout, [(c, model, params_for(c)) for c in cameras], points, colours)
    return cameras


def test_pinhole_scene_round_trips_poses_far_from_origin(tmp_path):
    cameras = _write_colmap_scene(tmp_path, "PINHOLE", lambda c: [c.fx, c.fy, c.cx, c.cy], [None] * 4)
    scene = load_scene(tmp_path)
    assert scene.format == "colmap-binary" and [c.name for c in scene.cameras] == [c.name for c in cameras]
    for ours, truth in zip(scene.cameras, cameras):
        back = scene.normalization.camera_to_original(ours)
        assert np.allclose(back.world_to_camera, truth.world_to_camera, atol=1e-9)
        # Normalised frame: the blobs are where the normalised camera projects the points.
        expected, _ = _project_pinhole(ours, scene.points)
        assert np.allclose(expected, project(truth, known_points()), atol=1e-6)
    assert np.abs(scene.points).max() < 10  # far-from-origin capture is recentred
    assert np.array_equal(scene.point_colors[0], [10, 200, 30])


def test_sparse_without_zero_and_text_models_load_the_same(tmp_path):
    binary_root, text_root = tmp_path / "bin", tmp_path / "txt"
    _write_colmap_scene(binary_root, "SIMPLE_PINHOLE", lambda c: [c.fx, c.cx, c.cy], [None] * 4, layout="sparse")
    (text_root / "sparse" / "0").mkdir(parents=True)
    shutil.copytree(binary_root / "images", text_root / "images")
    pycolmap.Reconstruction(str(binary_root / "sparse")).write_text(str(text_root / "sparse" / "0"))
    a, b = load_scene(binary_root), load_scene(text_root)
    assert (a.format, b.format) == ("colmap-binary", "colmap-text")
    assert a.camera_models == b.camera_models == ["SIMPLE_PINHOLE"] * 4
    for ca, cb in zip(a.cameras, b.cameras):
        assert ca.fx == ca.fy  # SIMPLE_PINHOLE: one focal length
        assert np.allclose(ca.world_to_camera, cb.world_to_camera, atol=1e-9)
        assert np.allclose([ca.fx, ca.cx, ca.cy], [cb.fx, cb.cx, cb.cy], atol=1e-9)
    assert np.allclose(a.points, b.points, atol=1e-9)


_DISTORTED = {
    # model: (params from a camera, OpenCV coefficients)
    "SIMPLE_RADIAL": (lambda c: [c.fx, c.cx, c.cy, -0.12], [-0.12, 0, 0, 0]),
    "RADIAL": (lambda c: [c.fx, c.cx, c.cy, -0.2, 0.05], [-0.2, 0.05, 0, 0]),
    "OPENCV": (lambda c: [c.fx, c.fy, c.cx, c.cy, -0.18, 0.04, 0.002, -0.003], [-0.18, 0.04, 0.002, -0.003]),
    "FULL_OPENCV": (lambda c: [c.fx, c.fy, c.cx, c.cy, -0.18, 0.04, 0.002, -0.003, 0.01, 0.02, 0.0, 0.01],
                    [-0.18, 0.04, 0.002, -0.003, 0.01, 0.02, 0.0, 0.01]),
}


@pytest.mark.parametrize("model", sorted(_DISTORTED))
def test_distortion_model_matches_pycolmap(model):
    params_for, coefficients = _DISTORTED[model]
    camera = known_cameras()[0]
    if model in ("SIMPLE_RADIAL", "RADIAL"):
        camera = known_cameras(fy=60.0)[0]
    colmap_camera = pycolmap.Camera.create_from_model_name(1, model, 1.0, camera.width, camera.height)
    colmap_camera.params = params_for(camera)
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.9, 0.9, (50, 2))
    theirs = colmap_camera.img_from_cam(np.concatenate([xy, np.ones((50, 1))], 1))
    ours = distort_normalized(xy, np.array(coefficients)) * [camera.fx, camera.fy] + [camera.cx, camera.cy]
    assert np.abs(ours - theirs).max() < 1e-9
    assert np.abs(undistort_normalized(distort_normalized(xy, np.array(coefficients)),
                                       np.array(coefficients)) - xy).max() < 1e-9


@pytest.mark.parametrize("model", sorted(_DISTORTED))
def test_distorted_scene_is_undistorted_to_a_pinhole_camera(tmp_path, model):
    params_for, coefficients = _DISTORTED[model]
    cameras = known_cameras(fy=60.0)  # one focal length, so the radial models fit too
    dist = np.array(coefficients)
    # Blobs are drawn where cv2.projectPoints puts the points through the distortion.
    _write_colmap_scene(tmp_path, model, params_for, [dist] * len(cameras), cameras=cameras)
    scene = load_scene(tmp_path)
    assert scene.camera_models == [model] * len(cameras)
    worst, found_count, naive_worst = 0.0, 0, 0.0
    for index, (camera, truth) in enumerate(zip(scene.cameras, cameras)):
        assert (camera.width, camera.height) == (truth.width, truth.height)
        expected, _ = _project_pinhole(camera, scene.points)
        error = np.abs(blob_centroids(scene.load_image(index), expected) - expected).max(axis=1)
        worst = max(worst, np.nanmax(error))
        found_count += int(np.isfinite(error).sum())
        # Without undistortion the blobs would sit pixels away: the test can fail.
        shift = project(truth, known_points(), dist) - project(truth, known_points())
        naive_worst = max(naive_worst, np.abs(shift).max())
    assert found_count >= 0.9 * len(cameras) * len(known_points())
    assert worst < 0.2  # bilinear resampling of ~1 px blobs, measured ~0.1
    assert naive_worst > 1.5
    # Undistorted once: cached in the work folder and reused.
    cached = sorted((scene.work_dir / "images").rglob("*.png"))
    assert len(cached) == len(cameras)
    assert np.array_equal(scene.load_image(0), scene.load_image(0))


def test_colmap_opencv_fisheye_is_undistorted_with_the_fisheye_model(tmp_path):
    from inceptiongs.scene.undistort import Fisheye

    k = [0.08, -0.03, 0.01, -0.002]
    cameras = known_cameras()
    lens = Fisheye(np.array(k))
    _write_colmap_scene(tmp_path, "OPENCV_FISHEYE", lambda c: [c.fx, c.fy, c.cx, c.cy, *k], [lens] * len(cameras),
                        cameras=cameras)
    scene = load_scene(tmp_path)
    assert scene.camera_models == ["OPENCV_FISHEYE"] * len(cameras)
    # Our fisheye model agrees with COLMAP's own.
    colmap_camera = pycolmap.Camera.create_from_model_name(1, "OPENCV_FISHEYE", 1.0, WIDTH, HEIGHT)
    c = cameras[0]
    colmap_camera.params = [c.fx, c.fy, c.cx, c.cy, *k]
    xy = np.random.default_rng(0).uniform(-0.9, 0.9, (50, 2))
    theirs = colmap_camera.img_from_cam(np.concatenate([xy, np.ones((50, 1))], 1))
    ours = distort_normalized(xy, lens) * [c.fx, c.fy] + [c.cx, c.cy]
    assert np.abs(ours - theirs).max() < 1e-9
    worst, found = 0.0, 0
    for index, camera in enumerate(scene.cameras):
        expected, _ = _project_pinhole(camera, scene.points)
        error = np.abs(blob_centroids(scene.load_image(index), expected) - expected).max(axis=1)
        worst = max(worst, np.nanmax(error))
        found += int(np.isfinite(error).sum())
    assert found >= 0.9 * len(cameras) * len(known_points())
    assert worst < 0.5  # reprojection error, pixels


def test_downscale_and_max_width(tmp_path):
    cameras = _write_colmap_scene(tmp_path, "PINHOLE", lambda c: [c.fx, c.fy, c.cx, c.cy], [None] * 4)
    full = load_scene(tmp_path)
    half = load_scene(tmp_path, downscale=2)
    for a, b in zip(full.cameras, half.cameras):
        assert (b.width, b.height) == (60, 45)
        assert np.allclose([b.fx, b.fy, b.cx, b.cy], np.array([a.fx, a.fy, a.cx, a.cy]) / 2)
        assert np.array_equal(a.world_to_camera, b.world_to_camera)
    original = cv2.imread(str(tmp_path / "images" / cameras[1].name))[:, :, ::-1]
    expected = cv2.resize(original, (60, 45), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    image = half.load_image(1)
    assert image.shape == (45, 60, 3) and np.abs(image - expected).max() < 1e-6
    assert not (tmp_path / ".inceptiongs").exists()  # the scene folder is never written
    assert np.array_equal(half.load_image(1), image)  # second read comes from the cache

    capped = load_scene(tmp_path, max_width=50)
    assert {(c.width, c.height) for c in capped.cameras} == {(50, 38)}
    assert capped.load_image(0).shape == (38, 50, 3)


def test_gaussian_frame_conversions_round_trip(tmp_path):
    _write_colmap_scene(tmp_path, "PINHOLE", lambda c: [c.fx, c.fy, c.cx, c.cy], [None] * 4)
    scene = load_scene(tmp_path)
    norm = scene.normalization
    rng = np.random.default_rng(1)
    n = 6
    g = Gaussians(torch.tensor(rng.normal(size=(n, 3))), torch.tensor(rng.normal(size=(n, 3))),
                  torch.tensor(rng.normal(size=(n, 4))), torch.tensor(rng.normal(size=n)),
                  torch.tensor(rng.normal(size=(n, 4, 3))))
    original = norm.gaussians_to_original(g)
    assert np.allclose(original.means.numpy(), norm.to_original(g.means.numpy()), atol=1e-9)
    # A Gaussian's size scales with the frame: exp(log_scale) / scale.
    assert np.allclose(np.exp(original.log_scales.numpy()), np.exp(g.log_scales.numpy()) / norm.scale)
    assert torch.equal(original.quats, g.quats) and torch.equal(original.sh, g.sh)
    back = norm.gaussians_to_normalized(original)
    assert torch.allclose(back.means, g.means, atol=1e-9) and torch.allclose(back.log_scales, g.log_scales)
    # The same projection in both frames: normalising rescales camera space uniformly.
    camera = scene.cameras[0]
    in_original = norm.camera_to_original(camera)
    a, _ = _project_pinhole(camera, g.means.numpy())
    b, _ = _project_pinhole(in_original, original.means.numpy())
    assert np.allclose(a, b, atol=1e-6)


def test_camera_by_name(tmp_path):
    _write_colmap_scene(tmp_path, "PINHOLE", lambda c: [c.fx, c.fy, c.cx, c.cy], [None] * 4)
    scene = load_scene(tmp_path)
    assert scene.camera_by_name("view_02.png") is scene.cameras[2]
    assert scene.camera_by_name("view_03") is scene.cameras[3]
    from inceptiongs.errors import InputError
    with pytest.raises(InputError, match="no camera named"):
        scene.camera_by_name("elsewhere")


def test_recalibrated_lens_does_not_reuse_cached_undistortion(tmp_path):
    params_for, coefficients = _DISTORTED["OPENCV"]
    cameras = known_cameras()
    _write_colmap_scene(tmp_path, "OPENCV", params_for, [np.array(coefficients)] * len(cameras), cameras=cameras)
    before = load_scene(tmp_path).load_image(0)
    weaker = lambda c: [c.fx, c.fy, c.cx, c.cy, -0.05, 0.0, 0.0, 0.0]  # noqa: E731
    write_colmap_binary(tmp_path / "sparse" / "0", [(c, "OPENCV", weaker(c)) for c in cameras], known_points())
    after = load_scene(tmp_path).load_image(0)
    assert np.abs(after - before).max() > 0.1


def test_scene_arguments_for_commands(tmp_path):
    import argparse

    from inceptiongs.scene.loader import add_scene_arguments, load_scene_from_args

    _write_colmap_scene(tmp_path, "PINHOLE", lambda c: [c.fx, c.fy, c.cx, c.cy], [None] * 4)
    parser = argparse.ArgumentParser()
    add_scene_arguments(parser)
    scene = load_scene_from_args(tmp_path, parser.parse_args(["--downscale", "2", "--max-width", "40"]))
    assert {c.width for c in scene.cameras} == {40}
    with pytest.raises(SystemExit):
        parser.parse_args(["--downscale", "3"])
