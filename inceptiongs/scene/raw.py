"""What every scene reader hands to :func:`inceptiongs.scene.loader.load_scene`, before
normalisation, undistortion and downscaling are applied (those live in scene.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import InputError


@dataclass
class RawScene:
    """A scene as read from disk, in the file's own (original) world frame.

    cameras: at the resolution of the image files in ``image_paths`` (what the reader found);
    distortion: per camera, OpenCV coefficients (k1, k2, p1, p2[, k3, k4, k5, k6]) or None;
    points: [P, 3] float64; point_colors: [P, 3] uint8 or None;
    source_downscale: how much smaller the image files are than the poses' full resolution
    (LLFF's images_N folders), so the remaining downscale is ``downscale / source_downscale``.
    """

    root: Path
    format: str
    cameras: list[Camera]
    image_paths: list[Path]
    camera_models: list[str]
    distortion: list[np.ndarray | None]
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    point_colors: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)
    source_downscale: float = 1.0


# Coordinates (scene units) beyond this are corrupt, not a capture: squaring them (distances,
# the scene's extent) would overflow float64's ~1e308, and float32 positions lose all
# precision long before. A capture in millimetres of a whole country stays far below it.
COORDINATE_ABS_MAX = 1e12
# Image sides beyond this are corrupt camera records (no sensor has a million pixels a side).
CAMERA_SIDE_MAX = 1_000_000


def check_finite_pose(pose: np.ndarray, source: str) -> None:
    """InputError unless pose [4, 4] is finite with a proper rotation and a translation
    within COORDINATE_ABS_MAX."""
    if not np.all(np.isfinite(pose)):
        raise InputError(f"{source}: pose contains NaN or Inf")
    if np.abs(pose[:3, 3]).max() > COORDINATE_ABS_MAX:
        raise InputError(f"{source}: pose translation is beyond {COORDINATE_ABS_MAX:g} units (corrupt?)")
    rotation = pose[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-3) or np.linalg.det(rotation) <= 0:
        raise InputError(f"{source}: pose rotation is not a proper rotation matrix")


def check_intrinsics(width: float, height: float, values: list[float], source: str) -> None:
    """InputError unless the size is positive and the intrinsics finite with positive focal."""
    try:
        width, height, *values = [float(v) for v in [width, height, *values]]
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{source}: camera intrinsics are not real numbers") from None
    if not all(np.isfinite(v) for v in [width, height, *values]):
        raise InputError(f"{source}: camera intrinsics contain NaN or Inf")
    if width <= 0 or height <= 0 or values[0] <= 0 or values[1] <= 0:
        raise InputError(f"{source}: camera size and focal lengths must be positive")
    if width > CAMERA_SIDE_MAX or height > CAMERA_SIDE_MAX:
        raise InputError(f"{source}: camera size {width:g}x{height:g} is beyond {CAMERA_SIDE_MAX} pixels a side")
    if max(abs(v) for v in values) > COORDINATE_ABS_MAX:
        raise InputError(f"{source}: camera intrinsics beyond {COORDINATE_ABS_MAX:g} (corrupt?)")


def finite_points(points: np.ndarray, colors, warnings: list[str]):
    """Drop sparse points [P, 3] that are NaN/Inf or beyond COORDINATE_ABS_MAX (with a
    warning); colors [P, 3] or None follow. -> (points, colors)."""
    keep = np.all(np.isfinite(points), axis=1) & np.all(np.abs(np.nan_to_num(points)) <= COORDINATE_ABS_MAX, axis=1)
    if keep.all():
        return points, colors
    warnings.append(f"{int((~keep).sum())} sparse point(s) with NaN/Inf or out-of-range coordinates dropped")
    return points[keep], (None if colors is None else colors[keep])
