"""Moving a selection: pure numpy transforms of Gaussians (translate, rotate, uniform scale about
a pivot) and the gizmo's geometry (three axis handles at the selection's centre), no GL.

A rotation turns the means about the pivot and the orientations with them (the rotation's
quaternion multiplies each Gaussian's on the left). Spherical harmonics above degree 0 are left
unrotated, so view-dependent colour keeps its world direction (docs/viewer.md says so).
A uniform scale multiplies the offsets from the pivot and adds log(factor) to every log scale.
"""

from __future__ import annotations

import numpy as np

GIZMO_MODES = ("translate", "rotate", "scale")
# Handle length as a share of the pivot's camera depth: the gizmo keeps its size on screen.
GIZMO_SCREEN_SHARE = 0.15
# A scale drag of one handle length multiplies sizes by e; factors outside this range are clamped
# so a wild drag cannot collapse a selection to a point or blow it up past the log-scale limits.
SCALE_FACTOR_RANGE = (1e-3, 1e3)


def axis_angle_quaternion(axis: np.ndarray, angle: float) -> np.ndarray:
    """axis: [3] (any length > 0), angle: radians -> unit quaternion [4] (w, x, y, z)."""
    axis = np.asarray(axis, np.float64)
    norm = float(np.linalg.norm(axis))
    if norm < 1e-12:  # no direction: the identity (avoids dividing by zero)
        return np.array([1.0, 0.0, 0.0, 0.0])
    half = 0.5 * float(angle)
    return np.concatenate([[np.cos(half)], np.sin(half) * axis / norm])


def quaternion_matrix(quat: np.ndarray) -> np.ndarray:
    """quat: [4] (w, x, y, z), normalised here -> rotation matrix [3, 3]."""
    w, x, y, z = np.asarray(quat, np.float64) / max(float(np.linalg.norm(quat)), 1e-12)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quaternion_multiply(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """left: [4] or [N, 4], right: [N, 4] (w, x, y, z) -> [N, 4], the rotation ``right`` then ``left``."""
    lw, lx, ly, lz = np.moveaxis(np.broadcast_to(left, np.shape(right)), -1, 0)
    rw, rx, ry, rz = np.moveaxis(np.asarray(right), -1, 0)
    return np.stack([lw * rw - lx * rx - ly * ry - lz * rz,
                     lw * rx + lx * rw + ly * rz - lz * ry,
                     lw * ry - lx * rz + ly * rw + lz * rx,
                     lw * rz + lx * ry - ly * rx + lz * rw], axis=-1)


def translate(means: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """means: [N, 3], offset: [3] -> [N, 3] (same dtype)."""
    return (np.asarray(means, np.float64) + np.asarray(offset, np.float64)).astype(means.dtype)


def rotate(means: np.ndarray, quats: np.ndarray, pivot: np.ndarray, rotation: np.ndarray):
    """means: [N, 3], quats: [N, 4] (w, x, y, z), pivot: [3], rotation: unit quaternion [4]
    -> (means [N, 3], quats [N, 4]) turned about ``pivot``; dtypes kept. The stored quaternions'
    lengths are kept (the renderer normalises them), so a rotation changes nothing else."""
    matrix = quaternion_matrix(rotation)
    pivot = np.asarray(pivot, np.float64)
    moved = (np.asarray(means, np.float64) - pivot) @ matrix.T + pivot
    turned = quaternion_multiply(np.asarray(rotation, np.float64), np.asarray(quats, np.float64))
    return moved.astype(means.dtype), turned.astype(quats.dtype)


def scale(means: np.ndarray, log_scales: np.ndarray, pivot: np.ndarray, factor: float):
    """means: [N, 3], log_scales: [N, 3], pivot: [3], factor > 0 -> (means, log_scales), each
    offset from the pivot times ``factor`` and each axis's size too (log scale + log factor)."""
    factor = float(np.clip(factor, *SCALE_FACTOR_RANGE))  # > 0, so the log is safe
    pivot = np.asarray(pivot, np.float64)
    moved = (np.asarray(means, np.float64) - pivot) * factor + pivot
    return moved.astype(means.dtype), (np.asarray(log_scales, np.float64) + np.log(factor)).astype(log_scales.dtype)


def gizmo_handles(pivot: np.ndarray, length: float) -> np.ndarray:
    """pivot: [3], length: scene units -> handle tips [3, 3] (pivot + length * x, y, z axis)."""
    return np.asarray(pivot, np.float64) + float(length) * np.eye(3)


def gizmo_segments(pivot: np.ndarray, length: float) -> np.ndarray:
    """-> [3, 2, 3]: the three axis lines from the pivot to its handles (drawn red, green, blue)."""
    tips = gizmo_handles(pivot, length)
    return np.stack([np.broadcast_to(np.asarray(pivot, np.float64), (3, 3)), tips], axis=1)


def drag_amount(screen_axis: np.ndarray, motion: np.ndarray) -> float:
    """screen_axis: [2] pixels per scene unit along a handle's axis; motion: [2] mouse pixels ->
    scene units along the axis (0 when the axis points at the eye and has no screen direction)."""
    length2 = float(np.dot(screen_axis, screen_axis))
    if not np.isfinite(length2) or length2 < 1e-9:
        return 0.0
    return float(np.dot(motion, screen_axis)) / length2


def transform_rows(arrays: dict, rows: np.ndarray, mode: str, axis: int, amount: float,
                   pivot: np.ndarray, length: float) -> dict:
    """The new values of ``rows`` (int [K]) of ``arrays`` (Gaussians.numpy() keys) after a gizmo
    drag of ``amount`` scene units along handle ``axis`` (0, 1, 2) in ``mode`` (GIZMO_MODES):
    translate moves by ``amount`` along the axis; rotate turns about the axis by
    amount / length radians; scale multiplies by exp(amount / length). Returns only the
    changed keys, each [K, ...]; length > 0."""
    means = arrays["means"][rows]
    direction = np.eye(3)[axis]
    if mode == "translate":
        return {"means": translate(means, direction * amount)}
    turns = amount / max(float(length), 1e-12)
    if mode == "rotate":
        new_means, new_quats = rotate(means, arrays["quats"][rows], pivot, axis_angle_quaternion(direction, turns))
        return {"means": new_means, "quats": new_quats}
    if mode == "scale":
        new_means, new_logs = scale(means, arrays["log_scales"][rows], pivot, float(np.exp(np.clip(turns, -7, 7))))
        return {"means": new_means, "log_scales": new_logs}
    raise ValueError(f"unknown gizmo mode {mode!r}; expected one of {', '.join(GIZMO_MODES)}")
