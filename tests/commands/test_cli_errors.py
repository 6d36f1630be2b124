"""Bad input: every case raises one InputError line naming the file, and the
CLI prints that line and exits 2 without a traceback (unless --debug)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.scene.colmap import write_colmap_binary
from inceptiongs.io.ply import read_ply
from inceptiongs.scene.loader import load_scene
from scene_cases import known_cameras, known_points, write_images


def _colmap_scene(root, model="PINHOLE", extra=(), pose_nan=False):
    cameras = known_cameras(count=3)
    write_images(root / "images", cameras, [None] * 3)
    (root / "sparse" / "0").mkdir(parents=True)
    if pose_nan:
        pose = cameras[1].world_to_camera.copy()
        pose[0, 3] = np.nan
        cameras[1] = cameras[1].with_pose(pose)
    write_colmap_binary(root / "sparse" / "0",
                        [(c, model, [c.fx, c.fy, c.cx, c.cy, *extra]) for c in cameras], known_points())
    return cameras


def _missing_path(tmp_path):
    return tmp_path / "does" / "not" / "exist", "path does not exist"


def _no_scene(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.txt").write_text("hello")
    return tmp_path / "photos", "no recognisable scene"


def _missing_image(tmp_path):
    cameras = _colmap_scene(tmp_path)
    (tmp_path / "images" / cameras[1].name).unlink()
    return tmp_path, "image file does not exist"


def _corrupt_image(tmp_path):
    cameras = _colmap_scene(tmp_path)
    (tmp_path / "images" / cameras[0].name).write_bytes(b"\x89PNG broken")
    return tmp_path, "cannot read image header"


def _wrong_image_size(tmp_path):
    cameras = _colmap_scene(tmp_path)
    import cv2
    cv2.imwrite(str(tmp_path / "images" / cameras[2].name), np.zeros((10, 20, 3), np.uint8))
    return tmp_path, "image is 20x10 but its camera expects 120x90"


def _truncated_images_bin(tmp_path):
    _colmap_scene(tmp_path)
    path = tmp_path / "sparse" / "0" / "images.bin"
    path.write_bytes(path.read_bytes()[:-7])
    return tmp_path, "images.bin: truncated"


def _truncated_points_bin(tmp_path):
    _colmap_scene(tmp_path)
    path = tmp_path / "sparse" / "0" / "points3D.bin"
    path.write_bytes(path.read_bytes()[:50])
    return tmp_path, "points3D.bin: truncated"


def _corrupt_cameras_bin(tmp_path):
    _colmap_scene(tmp_path)
    path = tmp_path / "sparse" / "0" / "cameras.bin"
    data = bytearray(path.read_bytes())
    data[12:16] = (977).to_bytes(4, "little")  # model id of the first camera
    path.write_bytes(bytes(data))
    return tmp_path, "cameras.bin: unknown COLMAP camera model id 977"


def _trailing_garbage(tmp_path):
    _colmap_scene(tmp_path)
    path = tmp_path / "sparse" / "0" / "cameras.bin"
    path.write_bytes(path.read_bytes() + b"\0" * 5)
    return tmp_path, "cameras.bin: corrupt COLMAP binary file"


def _unsupported_model(tmp_path):
    _colmap_scene(tmp_path, model="FOV", extra=(0.1,))
    return tmp_path, "FOV model, which is not supported"


def _nan_colmap_pose(tmp_path):
    _colmap_scene(tmp_path, pose_nan=True)
    return tmp_path, "NaN"


def _llff_rows_mismatch(tmp_path):
    cameras = known_cameras(count=3)
    write_images(tmp_path / "images", cameras, [None] * 3)
    np.save(tmp_path / "poses_bounds.npy", np.tile(np.concatenate([np.eye(3, 5).ravel(), [1, 2]]), (4, 1)))
    return tmp_path, "4 poses but 3 images"


def _nan_transforms_pose(tmp_path):
    cameras = known_cameras(count=2)
    write_images(tmp_path / "images", cameras, [None] * 2)
    matrix = np.eye(4).tolist()
    matrix[2][2] = float("inf")
    frames = [{"file_path": f"images/{c.name}", "transform_matrix": matrix} for c in cameras]
    (tmp_path / "transforms.json").write_text(json.dumps({"fl_x": 50, "w": 120, "h": 90, "frames": frames}))
    return tmp_path, "NaN or Inf"


def _bad_transforms_json(tmp_path):
    (tmp_path / "transforms.json").write_text('{"frames": [')
    return tmp_path, "not a readable JSON file"


def _nan_ply(tmp_path):
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
    values = np.ones((3, len(names)), np.float32)
    values[1, names.index("opacity")] = np.nan
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
              + "".join(f"property float {n}\n" for n in names) + "end_header\n")
    path = tmp_path / "model.ply"
    path.write_bytes(header.encode() + values.astype("<f4").tobytes())
    return path, "field opacity has 1 NaN/Inf"


def _truncated_ply(tmp_path):
    path, _ = _nan_ply(tmp_path)
    path.write_bytes(path.read_bytes()[:-20])
    return path, "truncated PLY"


SCENE_CASES = [_missing_path, _no_scene, _missing_image, _corrupt_image, _wrong_image_size,
               _truncated_images_bin, _truncated_points_bin, _corrupt_cameras_bin, _trailing_garbage,
               _unsupported_model, _nan_colmap_pose, _llff_rows_mismatch, _nan_transforms_pose,
               _bad_transforms_json]
PLY_CASES = [_nan_ply, _truncated_ply]


def _check_line(message: str, path, fragment: str) -> None:
    assert "\n" not in message.strip()
    assert fragment in message
    # Names the file: the scene path itself or a file inside it.
    assert str(path) in message or str(path.parent) in message


@pytest.mark.parametrize("case", SCENE_CASES, ids=lambda c: c.__name__.strip("_"))
def test_bad_scene_raises_and_cli_exits_2(tmp_path, case, capsys):
    path, fragment = case(tmp_path)
    with pytest.raises(InputError) as info:
        load_scene(path)
    _check_line(str(info.value), path, fragment)
    assert main(["info", str(path), "--strict"]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("error: ") and captured.err.count("\n") == 1
    _check_line(captured.err, path, fragment)
    assert "Traceback" not in captured.err and captured.out == ""


@pytest.mark.parametrize("case", PLY_CASES, ids=lambda c: c.__name__.strip("_"))
def test_bad_ply_raises_and_cli_exits_2(tmp_path, case, capsys):
    path, fragment = case(tmp_path)
    with pytest.raises(InputError) as info:
        read_ply(path)
    _check_line(str(info.value), path, fragment)
    assert main(["info", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("error: ") and captured.err.count("\n") == 1
    _check_line(captured.err, path, fragment)


@pytest.mark.parametrize("case", [_missing_image, _wrong_image_size], ids=lambda c: c.__name__.strip("_"))
def test_info_without_strict_lists_image_problems_as_warnings(tmp_path, case, capsys):
    path, fragment = case(tmp_path)
    assert main(["info", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["cameras"] == 3 and any(fragment in w for w in summary["warnings"])


def test_demo_scene_into_foreign_folder_exits_2(tmp_path, capsys):
    (tmp_path / "keep.txt").write_text("x")
    assert main(["demo-scene", str(tmp_path)]) == 2
    assert "not an empty folder or a previous demo scene" in capsys.readouterr().err


def test_console_entry_prints_one_line_and_debug_shows_traceback(tmp_path):
    missing = tmp_path / "nowhere"
    result = subprocess.run([sys.executable, "-m", "inceptiongs", "info", str(missing)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr == f"error: {missing}: path does not exist\n"
    debug = subprocess.run([sys.executable, "-m", "inceptiongs", "--debug", "info", str(missing)],
                           capture_output=True, text=True, timeout=120)
    assert debug.returncode != 0 and "Traceback" in debug.stderr


def test_train_refuses_a_negative_shell_scale_floor_in_one_line(tmp_path, capsys):
    settings = tmp_path / "settings.json"
    settings.write_text('{"free_space": {"sky_min_scale": -1}}')
    assert main(["train", str(tmp_path), "--config", str(settings), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {settings}: ") and err.count("\n") == 1 and "free_space.sky_min_scale" in err
    assert not (tmp_path / "run").exists()
