"""Camera math in inceptiongs/camera.py: quaternions, slerp, pose distance, look-at, JSON."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from inceptiongs.camera import (Camera, camera_from_json_dict, interpolate_pose, look_at, pose_distance,
                                quat_normalize, quat_slerp, quat_to_rotation, read_camera_json,
                                rigid_inverse, rotation_angle_between, rotation_to_quat, write_camera_json)
from inceptiongs.errors import InputError


def _axis_angle_rotation(axis, angle) -> np.ndarray:
    """Rodrigues' formula: an independent way to build rotations."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _random_quats(n, seed=0):
    q = np.random.default_rng(seed).standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_quat_to_rotation_matches_axis_angle():
    for axis, angle in [((1, 0, 0), 0.3), ((0, 1, 0), -1.2), ((1, 2, 3), 2.9), ((0, 0, 1), math.pi)]:
        unit = np.asarray(axis, float) / np.linalg.norm(axis)
        q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * unit])
        assert np.allclose(quat_to_rotation(q), _axis_angle_rotation(axis, angle), atol=1e-12)


def test_quaternion_round_trips_including_pivot_branches():
    quats = list(_random_quats(200))
    # Rotations by ~pi about each axis exercise every Shepperd pivot.
    quats += [np.array([1e-9, 1, 0, 0]), np.array([0, 0, 1, 1e-9]), np.array([1e-7, 0, 0, 1])]
    for q in quats:
        q = quat_normalize(q)
        back = rotation_to_quat(quat_to_rotation(q))
        assert back[0] >= 0 and abs(np.linalg.norm(back) - 1) < 1e-12
        assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9
        rotation = quat_to_rotation(q)
        assert np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert abs(np.linalg.det(rotation) - 1) < 1e-12


def test_unnormalised_quaternion_gives_same_rotation_and_zero_is_rejected():
    q = _random_quats(1)[0]
    assert np.allclose(quat_to_rotation(3.7 * q), quat_to_rotation(q), atol=1e-14)
    with pytest.raises(ValueError):
        quat_normalize(np.zeros(4))
    with pytest.raises(ValueError):
        quat_normalize(np.array([np.nan, 0, 0, 1]))


def test_slerp_end_points_midpoint_and_unit_norm():
    q0, q1 = _random_quats(2, seed=3)
    assert np.allclose(quat_slerp(q0, q1, 0.0), q0, atol=1e-12)
    r1 = quat_slerp(q0, q1, 1.0)
    assert min(np.abs(r1 - q1).max(), np.abs(r1 + q1).max()) < 1e-12
    total = rotation_angle_between(quat_to_rotation(q0), quat_to_rotation(q1))
    for t in np.linspace(0, 1, 11):
        q = quat_slerp(q0, q1, t)
        assert abs(np.linalg.norm(q) - 1) < 1e-12
        # Constant angular speed along the geodesic.
        a = rotation_angle_between(quat_to_rotation(q0), quat_to_rotation(q))
        assert abs(a - t * total) < 1e-9


def test_slerp_takes_the_shorter_arc_when_quaternions_are_in_opposite_hemispheres():
    q0 = np.array([1.0, 0, 0, 0])
    angle = 0.4
    q1 = -np.array([math.cos(angle / 2), 0, math.sin(angle / 2), 0])  # same rotation as +q1
    half = quat_slerp(q0, q1, 0.5)
    a = rotation_angle_between(quat_to_rotation(q0), quat_to_rotation(half))
    assert abs(a - angle / 2) < 1e-12  # not (2 pi - angle) / 2


def test_slerp_small_angle_is_finite_and_between():
    q0 = np.array([1.0, 0, 0, 0])
    q1 = quat_normalize(np.array([1.0, 1e-10, 0, 0]))
    for t in (0.0, 0.3, 1.0):
        q = quat_slerp(q0, q1, t)
        assert np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1) < 1e-12
    assert np.allclose(quat_slerp(q0, q0, 0.5), q0)


def _pose(rotation, center):
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = -rotation @ np.asarray(center, float)
    return pose


def test_pose_distance_equal_opposite_and_mixed():
    a = _pose(_axis_angle_rotation((0, 1, 0), 0.2), (1, 2, 3))
    assert pose_distance(a, a) == pytest.approx(0.0, abs=1e-7)
    flipped = _pose(_axis_angle_rotation((0, 1, 0), 0.2 + math.pi), (1, 2, 3))
    assert math.isfinite(pose_distance(a, flipped))
    assert pose_distance(a, flipped) == pytest.approx(math.pi, abs=1e-6)
    b = _pose(_axis_angle_rotation((0, 1, 0), 0.5), (4, 6, 3))
    assert pose_distance(a, b, rotation_weight=2.0) == pytest.approx(5.0 + 2.0 * 0.3, abs=1e-9)
    assert pose_distance(a, b) == pytest.approx(pose_distance(b, a), abs=1e-12)


def test_interpolate_pose_end_points_and_midpoint_centre():
    a = _pose(_axis_angle_rotation((1, 0, 0), 0.1), (0, 0, 0))
    b = _pose(_axis_angle_rotation((1, 0, 0), 0.9), (2, 0, 4))
    assert np.allclose(interpolate_pose(a, b, 0.0), a, atol=1e-12)
    assert np.allclose(interpolate_pose(a, b, 1.0), b, atol=1e-12)
    mid = interpolate_pose(a, b, 0.5)
    assert np.allclose(rigid_inverse(mid)[:3, 3], [1, 0, 2], atol=1e-12)
    assert np.allclose(mid[:3, :3], _axis_angle_rotation((1, 0, 0), 0.5), atol=1e-12)


def _camera(pose, w=64, h=48, f=50.0):
    return Camera("c", w, h, f, f, w / 2, h / 2, pose)


def _project(camera, point):
    p = camera.world_to_camera[:3, :3] @ point + camera.world_to_camera[:3, 3]
    return np.array([camera.fx * p[0] / p[2] + camera.cx, camera.fy * p[1] / p[2] + camera.cy]), p[2]


def test_look_at_centres_the_target_and_keeps_up_up():
    for eye, target, up in [((5, 0, 2), (0, 0, 0), (0, 0, 1)), ((0, -3, -4), (1, 1, 1), (0, -1, 0)),
                            ((2, 3, 4), (-1, 0, 0.5), (0.2, 0.1, 1))]:
        pose = look_at(np.array(eye, float), np.array(target, float), up)
        rotation = pose[:3, :3]
        assert np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        camera = _camera(pose)
        assert np.allclose(camera.center, eye, atol=1e-12)
        pixel, depth = _project(camera, np.array(target, float))
        assert depth > 0 and np.allclose(pixel, [camera.cx, camera.cy], atol=1e-9)
        # A point above the target (along world up) appears higher in the image (smaller v).
        above, _ = _project(camera, np.array(target, float) + 0.1 * np.asarray(up, float))
        assert above[1] < camera.cy
        # Image x grows to the right of the viewing direction: forward x up (right-handed).
        forward = np.array(target, float) - np.array(eye, float)
        right = np.cross(forward, up)
        to_right, _ = _project(camera, np.array(target, float) + 0.1 * right / np.linalg.norm(right))
        assert to_right[0] > camera.cx


def test_look_at_with_up_parallel_to_view_is_finite():
    pose = look_at(np.array([0.0, 0.0, 5.0]), np.zeros(3), up=(0.0, 0.0, 1.0))
    assert np.all(np.isfinite(pose))
    assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)
    with pytest.raises(ValueError):
        look_at(np.ones(3), np.ones(3))


def test_camera_scaled_keeps_the_projection_of_a_point():
    camera = _camera(look_at(np.array([0.0, 0, -3]), np.zeros(3)), w=640, h=480, f=500)
    small = camera.scaled(4)
    assert (small.width, small.height) == (160, 120)
    point = np.array([0.3, -0.2, 0.5])
    big_px, _ = _project(camera, point)
    small_px, _ = _project(small, point)
    assert np.allclose(small_px, big_px / 4, atol=1e-12)  # continuous coords scale exactly


def test_camera_json_round_trip(tmp_path):
    pose = look_at(np.array([1.0, 2.0, 3.0]), np.zeros(3))
    camera = Camera("view", 320, 240, 300.5, 301.25, 160.1, 119.9, pose)
    path = tmp_path / "cam.json"
    write_camera_json(camera, path)
    data = json.loads(path.read_text())
    assert set(data) >= {"width", "height", "fx", "fy", "cx", "cy", "world_to_camera"}
    back = read_camera_json(path)
    assert back.name == "view" and (back.width, back.height) == (320, 240)
    assert (back.fx, back.fy, back.cx, back.cy) == (300.5, 301.25, 160.1, 119.9)
    assert np.array_equal(back.world_to_camera, pose)


@pytest.mark.parametrize("content, match", [
    ("{not json", "not a readable camera JSON"),
    ("[1, 2]", "must be an object"),
    ('{"width": 4, "height": 4, "fx": 1, "fy": 1, "cx": 2}', "missing cy, world_to_camera"),
    ('{"width": 4, "height": 4, "fx": 1, "fy": 1, "cx": 2, "cy": 2, "world_to_camera": [[1, 0], [0, 1]]}',
     "4x4"),
    ('{"width": 4, "height": 4, "fx": NaN, "fy": 1, "cx": 2, "cy": 2, '
     '"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', "fx must be a finite number"),
    ('{"width": 0, "height": 4, "fx": 1, "fy": 1, "cx": 2, "cy": 2, '
     '"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', r"width must be in \[1, 16384\]"),
    ('{"width": 4, "height": 4, "fx": 1, "fy": 1, "cx": 2, "cy": 2, '
     '"world_to_camera": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', "not a proper rotation"),
    ('{"width": "wide", "height": 4, "fx": 1, "fy": 1, "cx": 2, "cy": 2, '
     '"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', "width must be an integer"),
    # A width given as text or with a fraction is no pixel count (it was read as int("64") / int(64.5)).
    ('{"width": "64", "height": 4, "fx": 1, "fy": 1, "cx": 2, "cy": 2, '
     '"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', 'width must be an integer .*got "64"'),
    ('{"width": 64.5, "height": 4, "fx": 1, "fy": 1, "cx": 2, "cy": 2, '
     '"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', "width must be an integer .*got 64.5"),
    ('{"width": 64, "height": 48, "fx": 1e308, "fy": 1, "cx": 2, "cy": 2, '
     '"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', r"fx must be in \(0, 10000000\]"),
])
def test_bad_camera_json(tmp_path, content, match):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(InputError, match=match) as info:
        read_camera_json(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_missing_camera_json(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        read_camera_json(tmp_path / "absent.json")


def test_camera_from_json_dict_accepts_camera_to_json_dict():
    camera = _camera(look_at(np.array([0.0, 1, -2]), np.zeros(3)))
    assert np.array_equal(camera_from_json_dict(camera.to_json_dict()).world_to_camera, camera.world_to_camera)
