"""NeRF / instant-ngp / nerfstudio ``transforms.json``.

Intrinsics are shared (top level) or per frame: ``fl_x``/``fl_y`` or ``camera_angle_x``/
``camera_angle_y``, ``cx``, ``cy``, ``w``, ``h`` and optional ``k1 k2 p1 p2`` (plus ``k3``).
``camera_model`` (top level or per frame, nerfstudio): PINHOLE, SIMPLE_PINHOLE, OPENCV or
PERSPECTIVE (k1 k2 p1 p2 k3, OpenCV's standard model) or OPENCV_FISHEYE (k1 k2 k3 k4, OpenCV's
fisheye model, undistorted like COLMAP's OPENCV_FISHEYE); absent means OPENCV. Any other model
(EQUIRECTANGULAR, ...) is refused with one line naming the file.
``ply_file_path`` (nerfstudio) names a point cloud PLY of sparse points.
``transform_matrix`` is camera-to-world with OpenGL camera axes (x right, y up, z backward);
flipping the camera's y and z axes gives OpenCV's (x right, y down, z forward).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..camera import Camera, rigid_inverse
from ..errors import InputError
from ..io.paths import contained_path
from ..io.paths import read_small_text
from .undistort import Fisheye
from .raw import RawScene, check_finite_pose, check_intrinsics

_NAMES = ("transforms.json", "transforms_train.json")
_STANDARD_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "PERSPECTIVE")
_FISHEYE_MODEL = "OPENCV_FISHEYE"
# Column flip from OpenGL camera axes to OpenCV camera axes (camera-to-world columns).
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def find_transforms(root: Path) -> Path | None:
    for name in _NAMES:
        if (root / name).is_file():
            return root / name
    return None


def _number(frame: dict, shared: dict, key: str, source: str) -> float | None:
    value = frame.get(key, shared.get(key))
    if value is None:
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InputError(f"{source}: {key} is not a number ({value!r})") from None


def _resolve_image(base: Path, file_path: str, source: str) -> Path:
    """file_path as written, or with a common image extension when the file has none
    (the NeRF synthetic scenes write names without '.png'); it must stay inside ``base``."""
    path = contained_path(base, file_path, source)
    if path.suffix == "" and not path.is_file():
        for ext in (".png", ".jpg", ".jpeg", ".JPG", ".PNG"):
            if path.with_suffix(ext).is_file():
                return contained_path(base, file_path + ext, source)
    return path


def _frame_size(path: Path, width: float | None, height: float | None, source: str) -> tuple[int, int]:
    if width is not None and height is not None:
        if not (math.isfinite(width) and math.isfinite(height)):
            raise InputError(f"{source}: w/h must be finite numbers, got {width} x {height}")
        return int(round(width)), int(round(height))
    from PIL import Image

    try:
        with Image.open(path) as image:
            return image.size
    except Exception:
        raise InputError(f"{source}: no w/h given and the image cannot be read to find its size") from None


def load_transforms(root: Path) -> RawScene:
    json_path = root if root.is_file() else find_transforms(root)
    if json_path is None:
        raise InputError(f"{root}: no transforms.json found")
    base = json_path.parent
    try:
        data = json.loads(read_small_text(json_path, "transforms JSON"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{json_path}: not a readable JSON file ({exc})") from None
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list) or not frames:
        raise InputError(f"{json_path}: has no 'frames' list")

    cameras, paths, models, distortion, warnings = [], [], [], [], []
    for index, frame in enumerate(frames):
        source = f"{json_path} frame {index}"
        if not isinstance(frame, dict) or "file_path" not in frame or "transform_matrix" not in frame:
            raise InputError(f"{source}: needs 'file_path' and 'transform_matrix'")
        try:
            c2w_gl = np.asarray(frame["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{source}: transform_matrix is not a numeric matrix") from None
        if c2w_gl.shape == (3, 4):
            c2w_gl = np.vstack([c2w_gl, [0.0, 0.0, 0.0, 1.0]])
        if c2w_gl.shape != (4, 4):
            raise InputError(f"{source}: transform_matrix must be 4x4, got shape {c2w_gl.shape}")
        check_finite_pose(c2w_gl, source)
        world_to_camera = rigid_inverse(c2w_gl @ _GL_TO_CV)

        path = _resolve_image(base, str(frame["file_path"]), source)
        width, height = _frame_size(path, _number(frame, data, "w", source),
                                    _number(frame, data, "h", source), source)
        fx, fy = _number(frame, data, "fl_x", source), _number(frame, data, "fl_y", source)
        angle_x = _number(frame, data, "camera_angle_x", source)
        angle_y = _number(frame, data, "camera_angle_y", source)
        if fx is None and angle_x is not None:
            # tan(angle / 2) > 0 for a field of view in (0, pi), checked below via fx > 0.
            fx = 0.5 * width / math.tan(0.5 * angle_x) if 0 < angle_x < math.pi else -1.0
        if fy is None and angle_y is not None:
            fy = 0.5 * height / math.tan(0.5 * angle_y) if 0 < angle_y < math.pi else -1.0
        if fx is None and fy is None:
            raise InputError(f"{source}: no focal length (fl_x, fl_y or camera_angle_x)")
        fx = fy if fx is None else fx
        fy = fx if fy is None else fy
        cx = _number(frame, data, "cx", source)
        cy = _number(frame, data, "cy", source)
        cx = width / 2.0 if cx is None else cx
        cy = height / 2.0 if cy is None else cy
        check_intrinsics(width, height, [fx, fy, cx, cy], source)

        model = frame.get("camera_model", data.get("camera_model", "OPENCV"))
        if model not in (*_STANDARD_MODELS, _FISHEYE_MODEL):
            raise InputError(f"{source}: camera_model {model!r} is not supported (supported: "
                             f"{', '.join((*_STANDARD_MODELS, _FISHEYE_MODEL))})")
        keys = ("k1", "k2", "k3", "k4") if model == _FISHEYE_MODEL else ("k1", "k2", "p1", "p2", "k3")
        coefficients = [_number(frame, data, key, source) or 0.0 for key in keys]
        if not all(math.isfinite(c) for c in coefficients):
            raise InputError(f"{source}: distortion coefficients contain NaN or Inf")
        if model == _FISHEYE_MODEL:
            # A fisheye lens is never a pinhole one, even with all k = 0 (theta_d = theta).
            dist = Fisheye(np.array(coefficients))
        else:
            dist = np.array(coefficients) if any(coefficients) else None
        name = str(Path(str(frame["file_path"])).as_posix()).removeprefix("./")
        cameras.append(Camera(name, width, height, fx, fy, cx, cy, world_to_camera))
        paths.append(path)
        models.append(_FISHEYE_MODEL if model == _FISHEYE_MODEL else ("PINHOLE" if dist is None else "OPENCV"))
        distortion.append(dist)
    points, colors = np.zeros((0, 3)), None
    if data.get("ply_file_path"):
        # nerfstudio: sparse points in the same world frame as the transform matrices.
        from ..io.ply import read_point_cloud_ply
        points, colors = read_point_cloud_ply(contained_path(base, str(data["ply_file_path"]),
                                                             f"{json_path} ply_file_path"))
    return RawScene(root if root.is_dir() else base, "transforms", cameras, paths, models, distortion,
                    points, colors, warnings=warnings)
