"""Camera paths: the interpolation passes through its keyframes (centres by a cubic, rotations by
slerp), the JSON round trip keeps every number, the strict reader gives one line naming the file
for each kind of bad input, and the orbit circles what the cameras look at."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at, rotation_angle_between
from inceptiongs.camera_path import (CameraPath, Keyframe, free_name, orbit_path, path_cameras, pose_at,
                                     read_path_json, write_path_json)
from inceptiongs.errors import InputError


def _path() -> CameraPath:
    target = np.zeros(3)
    eyes = [np.array([0.0, 0.0, -4.0]), np.array([3.0, -1.0, -3.0]), np.array([4.0, 0.0, 0.5]),
            np.array([1.0, 1.0, 3.0])]
    keys = tuple(Keyframe(t, look_at(eye, target), fov) for t, eye, fov in
                 zip([0.0, 1.0, 2.5, 4.0], eyes, [50.0, 60.0, 40.0, 55.0]))
    return CameraPath(keys, 320, 240, 24.0)


def test_the_path_passes_through_its_keyframes_and_moves_smoothly_between():
    path = _path()
    for key in path.keyframes:
        pose, fov = pose_at(path, key.time_s)
        np.testing.assert_allclose(pose, key.world_to_camera, atol=1e-9)
        assert fov == pytest.approx(key.fov_y_deg)
    cameras = path_cameras(path)
    assert len(cameras) == int(4.0 * 24) + 1
    centers = np.stack([c.center for c in cameras])
    steps = np.linalg.norm(np.diff(centers, axis=0), axis=1)
    # C1: no step jumps at a keyframe (a polyline's velocity changes direction there; the
    # cubic's steps change slowly), and the turn per frame stays small.
    assert np.max(np.abs(np.diff(steps))) < 0.2 * np.max(steps)
    turns = [rotation_angle_between(a.rotation, b.rotation) for a, b in zip(cameras, cameras[1:])]
    assert max(turns) < math.radians(5)


def test_rotations_are_slerped_at_constant_angular_speed():
    keys = (Keyframe(0.0, look_at(np.zeros(3), [0, 0, 1.0]), 50.0),
            Keyframe(2.0, look_at(np.zeros(3), [1.0, 0, 0]), 50.0))
    path = CameraPath(keys, 64, 48, 10.0)
    middle, _ = pose_at(path, 1.0)
    # Half way between looking along +z and along +x: along their bisector, 45 degrees from each.
    np.testing.assert_allclose(middle[2, :3], np.array([1.0, 0.0, 1.0]) / math.sqrt(2), atol=1e-9)
    quarter, _ = pose_at(path, 0.5)
    assert rotation_angle_between(quarter[:3, :3], keys[0].world_to_camera[:3, :3]) == pytest.approx(math.pi / 8)


def test_json_round_trip_keeps_every_number(tmp_path):
    path = _path()
    out = write_path_json(path, tmp_path / "path.json")
    back = read_path_json(out)
    assert (back.width, back.height, back.fps) == (path.width, path.height, path.fps)
    for a, b in zip(path.keyframes, back.keyframes):
        assert a.time_s == b.time_s and a.fov_y_deg == b.fov_y_deg
        np.testing.assert_array_equal(a.world_to_camera, b.world_to_camera)  # repr round-trips floats


def _bad(tmp_path, change) -> str:
    data = json.loads(write_path_json(_path(), tmp_path / "good.json").read_text())
    change(data)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data).replace("Infinity", "NaN") if "nan" in str(change) else json.dumps(data))
    with pytest.raises(InputError) as error:
        read_path_json(bad)
    message = str(error.value)
    assert "\n" not in message and str(bad) in message
    return message


@pytest.mark.parametrize("change, says", [
    (lambda d: d.pop("keyframes"), "missing keyframes"),
    (lambda d: d.pop("width"), "missing width"),
    (lambda d: d.update(keyframes=[]), "at least 2 keyframes"),
    (lambda d: d.update(keyframes=d["keyframes"][:1]), "at least 2 keyframes"),
    (lambda d: d.update(colour=1), "unknown key(s) colour"),
    (lambda d: d["keyframes"][1].pop("fov_y_deg"), "keyframe 1 is missing fov_y_deg"),
    (lambda d: d["keyframes"][1].update(fov_y_deg=0), "fov_y_deg 0 is outside"),
    (lambda d: d["keyframes"][1].update(fov_y_deg=180), "fov_y_deg 180 is outside"),
    (lambda d: d["keyframes"][1].update(fov_y_deg="wide"), "must be a number"),
    (lambda d: d["keyframes"][2].update(time=0.5), "times must increase"),
    (lambda d: d["keyframes"][0]["world_to_camera"][0].__setitem__(0, 2.0), "not a rigid pose"),
    (lambda d: d["keyframes"][0].update(world_to_camera=[[1, 0, 0]]), "4x4"),
    (lambda d: d.update(fps=0), "fps must be in"),
    (lambda d: d.update(width=-5), "must be positive"),
    (lambda d: d.update(width=10.5), "whole number"),
    (lambda d: d.update(version=7), "version 7"),
])
def test_bad_path_files_are_one_line_naming_the_file_and_problem(tmp_path, change, says):
    assert says in _bad(tmp_path, change)


def test_nan_and_non_json_are_refused(tmp_path):
    text = write_path_json(_path(), tmp_path / "good.json").read_text()
    nan = tmp_path / "nan.json"
    nan.write_text(text.replace('"time": 1.0', '"time": NaN'))
    with pytest.raises(InputError, match="keyframe 1 time is not finite"):
        read_path_json(nan)
    broken = tmp_path / "broken.json"
    broken.write_text(text[:40])
    with pytest.raises(InputError, match="not a readable camera path JSON"):
        read_path_json(broken)
    with pytest.raises(InputError, match="does not exist"):
        read_path_json(tmp_path / "none.json")


def test_orbit_circles_what_the_cameras_look_at():
    target = np.array([1.0, 2.0, 3.0])
    up = np.array([0.0, -1.0, 0.0])
    cameras = [Camera(f"c{i}", 64, 48, 50, 50, 32, 24, look_at(target + [3 * math.cos(a), -0.5, 3 * math.sin(a)],
                                                                target, up))
               for i, a in enumerate(np.linspace(0.2, 1.4, 6))]
    # The model's middle is far away: the cameras' common point wins.
    path = orbit_path(cameras, np.array([50.0, 0.0, 0.0]), 1.0, 160, 120, seconds=4.0, fps=10.0)
    frames = path_cameras(path)
    assert len(frames) == 41
    for camera in frames:
        pixel = camera.intrinsics @ (camera.rotation @ target + camera.world_to_camera[:3, 3])
        # The target in the middle: exactly at the orbit's keyframes, within half a pixel between.
        np.testing.assert_allclose(pixel[:2] / pixel[2], [80, 60], atol=0.5)
        offset = camera.center - target
        # At the cameras' distance and height above the target (their ring's plane gives the up:
        # their image up tilts towards the target as they look down at it).
        assert np.linalg.norm(offset - (offset @ up) * up) == pytest.approx(3.0, rel=0.01)
        assert offset @ up == pytest.approx(0.5, abs=1e-6)
        assert camera.rotation[1] @ up < -0.9  # upright: the image's down is the world's down
    np.testing.assert_allclose(frames[0].center, frames[-1].center, atol=1e-9)  # one whole turn
    headings = [math.atan2(*(c.center - target)[[2, 0]]) for c in frames]
    assert np.ptp(np.unwrap(headings)) == pytest.approx(2 * math.pi, rel=1e-6)


def test_free_name_never_reuses_a_name(tmp_path):
    first = free_name(tmp_path, "path", ".json")
    first.write_text("{}")
    second = free_name(tmp_path, "path", ".json")
    assert first.name == "path_1.json" and second.name == "path_2.json"
