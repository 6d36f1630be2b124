"""transforms.json scenes (NeRF / instant-ngp / nerfstudio) written by the tests with known
cameras: shared or per-frame intrinsics, camera_angle_x, OpenGL axes, k1 k2 p1 p2."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from inceptiongs.camera import rigid_inverse
from inceptiongs.errors import InputError
from inceptiongs.scene.loader import load_scene
from inceptiongs.scene.undistort import Fisheye
from scene_cases import HEIGHT, WIDTH, blob_centroids, known_cameras, known_points, project, write_images


def _opengl_camera_to_world(camera) -> list:
    """OpenCV world-to-camera -> camera-to-world with OpenGL camera axes (y up, z backward)."""
    c2w = rigid_inverse(camera.world_to_camera)
    c2w[:, 1] *= -1
    c2w[:, 2] *= -1
    return c2w.tolist()


def _found_error(scene) -> float:
    """Largest distance between where the loaded cameras project the known points and where
    the blobs are in the loaded images (pixels)."""
    worst = 0.0
    points = scene.normalization.to_normalized(known_points())
    for index, camera in enumerate(scene.cameras):
        p = points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
        assert np.all(p[:, 2] > 0)
        expected = np.stack([camera.fx * p[:, 0] / p[:, 2] + camera.cx, camera.fy * p[:, 1] / p[:, 2] + camera.cy], 1)
        error = np.abs(blob_centroids(scene.load_image(index), expected) - expected).max(axis=1)
        assert np.isfinite(error).sum() >= 0.8 * len(error)
        worst = max(worst, float(np.nanmax(error)))
    return worst


def test_shared_intrinsics_and_opengl_axes(tmp_path):
    cameras = known_cameras()
    write_images(tmp_path / "images", cameras, [None] * len(cameras))
    c = cameras[0]
    data = {"fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": WIDTH, "h": HEIGHT,
            "frames": [{"file_path": f"images/{cam.name}", "transform_matrix": _opengl_camera_to_world(cam)}
                       for cam in cameras]}
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    scene = load_scene(tmp_path)
    assert scene.format == "transforms" and len(scene.cameras) == len(cameras)
    for ours, truth in zip(scene.cameras, cameras):
        assert np.allclose(scene.normalization.camera_to_original(ours).world_to_camera,
                           truth.world_to_camera, atol=1e-9)
        assert (ours.fx, ours.fy, ours.cx, ours.cy) == (truth.fx, truth.fy, truth.cx, truth.cy)
    assert _found_error(scene) < 0.05
    # The file itself may be given instead of its folder.
    assert len(load_scene(tmp_path / "transforms.json").cameras) == len(cameras)


def test_per_frame_intrinsics_camera_angle_and_names_without_extension(tmp_path):
    cameras = [known_cameras(fx=55.0 + 5 * k, fy=55.0 + 5 * k, cx=60.0, cy=45.0)[k] for k in range(3)]
    write_images(tmp_path / "images", cameras, [None] * 3)
    frames = [{"file_path": "./images/view_00", "fl_x": cameras[0].fx, "fl_y": cameras[0].fy,
               "transform_matrix": _opengl_camera_to_world(cameras[0])}]
    frames += [{"file_path": f"./images/{cam.name}", "fl_x": cam.fx, "transform_matrix": _opengl_camera_to_world(cam)}
               for cam in cameras[1:2]]
    # camera_angle_x alone: fx = fy = (w / 2) / tan(angle / 2), principal point at the centre.
    angle = 2 * math.atan(0.5 * WIDTH / cameras[2].fx)
    frames.append({"file_path": f"./images/{cameras[2].name}", "camera_angle_x": angle,
                   "transform_matrix": _opengl_camera_to_world(cameras[2])[:3]})  # 3x4 accepted
    (tmp_path / "transforms.json").write_text(json.dumps({"frames": frames}))
    scene = load_scene(tmp_path)
    for ours, truth in zip(scene.cameras, cameras):
        assert (ours.width, ours.height) == (WIDTH, HEIGHT)  # read from the image files
        assert np.allclose([ours.fx, ours.fy, ours.cx, ours.cy], [truth.fx, truth.fy, 60.0, 45.0], atol=1e-9)
    assert scene.cameras[0].name == "images/view_00"
    assert _found_error(scene) < 0.05


def test_distortion_coefficients_are_undistorted(tmp_path):
    cameras = known_cameras()
    dist = np.array([-0.15, 0.03, 0.002, -0.002])
    write_images(tmp_path / "images", cameras, [dist] * len(cameras))
    c = cameras[0]
    data = {"fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": WIDTH, "h": HEIGHT,
            "k1": dist[0], "k2": dist[1], "p1": dist[2], "p2": dist[3],
            "frames": [{"file_path": f"images/{cam.name}", "transform_matrix": _opengl_camera_to_world(cam)}
                       for cam in cameras]}
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    scene = load_scene(tmp_path)
    assert scene.camera_models == ["OPENCV"] * len(cameras)
    assert scene.cameras[0].fx != c.fx  # a new pinhole camera that covers only valid pixels
    assert _found_error(scene) < 0.2


FISHEYE_K = [0.08, -0.03, 0.01, -0.002]


@pytest.mark.parametrize("per_frame", [False, True])
def test_opencv_fisheye_camera_model_is_undistorted_with_the_fisheye_model(tmp_path, per_frame):
    cameras = known_cameras()
    lens = Fisheye(np.array(FISHEYE_K))
    # Blobs placed by cv2.fisheye.projectPoints: an implementation independent of ours.
    write_images(tmp_path / "images", cameras, [lens] * len(cameras))
    c = cameras[0]
    model = {"camera_model": "OPENCV_FISHEYE", **dict(zip(("k1", "k2", "k3", "k4"), FISHEYE_K))}
    data = {"fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": WIDTH, "h": HEIGHT,
            **({} if per_frame else model),
            "frames": [{"file_path": f"images/{cam.name}", "transform_matrix": _opengl_camera_to_world(cam),
                        **(model if per_frame else {})} for cam in cameras]}
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    scene = load_scene(tmp_path)
    assert scene.camera_models == ["OPENCV_FISHEYE"] * len(cameras)
    assert _found_error(scene) < 0.5  # reprojection error of the undistorted images, pixels
    # Read as the standard model (what happened before camera_model was read) the blobs are off.
    naive = max(np.abs(project(cam, known_points(), lens) - project(cam, known_points())).max() for cam in cameras)
    assert naive > 1.0


@pytest.mark.parametrize("model", ["EQUIRECTANGULAR", "FISHEYE624", 7])
def test_unsupported_camera_models_are_refused_in_one_line(tmp_path, model):
    cameras = known_cameras(count=2)
    write_images(tmp_path / "images", cameras, [None] * 2)
    frames = [{"file_path": f"images/{cam.name}", "transform_matrix": _opengl_camera_to_world(cam)}
              for cam in cameras]
    frames[1]["camera_model"] = model
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps({"fl_x": 60.0, "w": WIDTH, "h": HEIGHT, "frames": frames}))
    with pytest.raises(InputError, match="camera_model .* is not supported") as info:
        load_scene(tmp_path)
    assert str(info.value).startswith(f"{path} frame 1") and "\n" not in str(info.value)


@pytest.mark.parametrize("change, match", [
    (lambda d: d["frames"][1]["transform_matrix"][0].__setitem__(3, float("nan")), "NaN or Inf"),
    (lambda d: [d.pop(k) for k in ("fl_x", "fl_y")], "no focal length"),
    (lambda d: d.__setitem__("frames", []), "no 'frames'"),
    (lambda d: d["frames"][0].pop("transform_matrix"), "needs 'file_path' and 'transform_matrix'"),
    (lambda d: d.__setitem__("fl_x", "long"), "fl_x is not a number"),
])
def test_bad_transforms(tmp_path, change, match):
    cameras = known_cameras(count=2)
    write_images(tmp_path / "images", cameras, [None] * 2)
    data = {"fl_x": 60.0, "fl_y": 60.0, "w": WIDTH, "h": HEIGHT,
            "frames": [{"file_path": f"images/{cam.name}", "transform_matrix": _opengl_camera_to_world(cam)}
                       for cam in cameras]}
    change(data)
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=match) as info:
        load_scene(tmp_path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_nerfstudio_point_cloud_is_loaded(tmp_path):
    cameras = known_cameras(count=2)
    write_images(tmp_path / "images", cameras, [None] * 2)
    points = known_points()
    record = np.zeros(len(points), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                    ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for axis, name in enumerate("xyz"):
        record[name] = points[:, axis]
    record["red"] = np.arange(len(points))
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\n"
              + "".join(f"property {t} {n}\n" for t, n in [("float", "x"), ("float", "y"), ("float", "z"),
                                                            ("uchar", "red"), ("uchar", "green"), ("uchar", "blue")])
              + "end_header\n")
    (tmp_path / "sparse_pc.ply").write_bytes(header.encode() + record.tobytes())
    data = {"fl_x": 60.0, "w": WIDTH, "h": HEIGHT, "ply_file_path": "sparse_pc.ply",
            "frames": [{"file_path": f"images/{c.name}", "transform_matrix": _opengl_camera_to_world(c)}
                       for c in cameras]}
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    scene = load_scene(tmp_path)
    assert scene.points.shape == points.shape
    # float32 in the file: the original frame is recovered to float32 precision.
    assert np.allclose(scene.normalization.to_original(scene.points), points, atol=1e-3)
    assert np.array_equal(scene.point_colors[:, 0], np.arange(len(points)))
