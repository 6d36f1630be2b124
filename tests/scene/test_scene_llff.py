"""LLFF poses_bounds.npy scenes: the real fern capture and synthetic scenes with known cameras."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import require_data
from inceptiongs.camera import rigid_inverse
from inceptiongs.errors import InputError
from inceptiongs.scene.loader import load_scene
from scene_cases import HEIGHT, WIDTH, blob_centroids, known_cameras, known_points, write_images


def test_fern_loads_twenty_cameras_in_llff_axes():
    root = require_data("fern")
    scene = load_scene(root)
    table = np.load(root / "poses_bounds.npy")
    assert scene.format == "llff" and len(scene.cameras) == 20
    assert {(c.width, c.height) for c in scene.cameras} == {(504, 378)}
    assert scene.points.shape == (0, 3) and scene.camera_models == ["PINHOLE"] * 20
    names = sorted(p.name for p in (root / "images_8").iterdir())
    assert [c.name for c in scene.cameras] == names
    for camera, row in zip(scene.cameras, table):
        matrix = row[:15].reshape(3, 5)
        h, w, focal = matrix[:, 4]
        assert camera.fx == pytest.approx(focal * 504 / w) and camera.fy == pytest.approx(focal * 378 / h)
        original = scene.normalization.camera_to_original(camera)
        rotation = original.world_to_camera[:3, :3]
        # Rows of world-to-camera are the camera axes in world coordinates:
        # right = LLFF column 1, down = LLFF column 0, forward = -LLFF "back" column 2.
        assert np.allclose(rotation[0], matrix[:, 1], atol=1e-6)
        assert np.allclose(rotation[1], matrix[:, 0], atol=1e-6)
        assert np.allclose(rotation[2], -matrix[:, 2], atol=1e-6)
        assert np.allclose(original.center, matrix[:, 3], atol=1e-6)
    image = scene.load_image(3)
    assert image.shape == (378, 504, 3) and image.dtype == np.float32


def _write_llff(root, cameras, folder="images_2", full_scale=2, rows=None):
    """Known OpenCV cameras -> poses_bounds.npy (LLFF axes, full-resolution h, w, focal)."""
    write_images(root / folder, cameras, [None] * len(cameras))
    table = []
    for camera in cameras:
        c2w = rigid_inverse(camera.world_to_camera)
        columns = [c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3],
                   [camera.height * full_scale, camera.width * full_scale, camera.fx * full_scale]]
        table.append(np.concatenate([np.stack(columns, 1).ravel(), [0.5, 10.0]]))
    table = np.array(table if rows is None else table[:rows])
    np.save(root / "poses_bounds.npy", table)
    return table


def _blob_error(scene) -> float:
    points = scene.normalization.to_normalized(known_points())
    worst = 0.0
    for index, camera in enumerate(scene.cameras):
        p = points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
        expected = np.stack([camera.fx * p[:, 0] / p[:, 2] + camera.cx, camera.fy * p[:, 1] / p[:, 2] + camera.cy], 1)
        found = blob_centroids(scene.load_image(index), expected, radius=2 if camera.width < WIDTH else 4)
        worst = max(worst, float(np.nanmax(np.abs(found - expected))))
    return worst


def test_synthetic_llff_folder_choice_and_downscale(tmp_path):
    cameras = known_cameras(fx=60.0, fy=60.0, cx=WIDTH / 2, cy=HEIGHT / 2)
    _write_llff(tmp_path, cameras)
    exact = load_scene(tmp_path, downscale=2)  # images_2 is made for this downscale
    assert exact.warnings == []
    for ours, truth in zip(exact.cameras, cameras):
        assert (ours.width, ours.height, ours.fx, ours.cx, ours.cy) == (WIDTH, HEIGHT, 60.0, 60.0, 45.0)
        assert np.allclose(exact.normalization.camera_to_original(ours).world_to_camera,
                           truth.world_to_camera, atol=1e-9)
    assert _blob_error(exact) < 0.05

    full = load_scene(tmp_path)  # no images/: the sharpest folder there is, with a warning
    assert [c.width for c in full.cameras] == [WIDTH] * len(cameras)
    assert any("images_2" in w for w in full.warnings)

    quarter = load_scene(tmp_path, downscale=4)  # further halved from images_2
    assert {(c.width, c.height) for c in quarter.cameras} == {(WIDTH // 2, HEIGHT // 2)}
    assert quarter.cameras[0].fx == pytest.approx(30.0)
    assert quarter.load_image(0).shape == (HEIGHT // 2, WIDTH // 2, 3)
    assert _blob_error(quarter) < 0.3  # blobs of ~0.6 px sigma after INTER_AREA


@pytest.mark.parametrize("problem, match", [
    ("rows", "4 poses but 3 images"),
    ("nan", "NaN or Inf"),
    ("shape", "N x 17"),
    ("no_images", "no images/ or images_N/"),
    ("not_npy", "cannot read as a .npy"),
])
def test_bad_llff(tmp_path, problem, match):
    cameras = known_cameras(fx=60.0, fy=60.0, cx=WIDTH / 2, cy=HEIGHT / 2)
    table = _write_llff(tmp_path, cameras)
    path = tmp_path / "poses_bounds.npy"
    if problem == "rows":
        (tmp_path / "images_2" / cameras[-1].name).unlink()
    elif problem == "nan":
        table[2, 3] = np.nan
        np.save(path, table)
    elif problem == "shape":
        np.save(path, table[:, :15])
    elif problem == "no_images":
        for image in (tmp_path / "images_2").iterdir():
            image.unlink()
        (tmp_path / "images_2").rmdir()
    elif problem == "not_npy":
        path.write_bytes(b"not numpy at all")
    with pytest.raises(InputError, match=match) as info:
        load_scene(tmp_path)
    message = str(info.value)
    assert message.startswith(str(tmp_path)) and "\n" not in message
