"""Cameras and pose math, in one place.

Conventions (DESIGN.md): OpenCV camera axes (x right, y down, z forward); poses are
float64 world-to-camera 4x4 matrices; intrinsics fx, fy, cx, cy in pixels, with pixel
(i, j) sampling the continuous point (i + 0.5, j + 0.5); quaternions are (w, x, y, z).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .io.atomic import atomic_write_text
from .io.config_json import read_json_object
from .io.limits import check_image_size
from .io.values import COORDINATE_MAX, rule
from .constants import NEAR_PLANE
from .errors import InputError

# Below this |sin(angle)| slerp falls back to normalised lerp: the slerp weights
# sin((1-t)a)/sin(a) lose all precision as a -> 0.
_SLERP_SMALL_ANGLE = 1e-6
# Smallest quaternion norm that is normalised; anything smaller is not a rotation.
_QUAT_NORM_MIN = 1e-12


@dataclass(frozen=True)
class Camera:
    """A pinhole camera. ``world_to_camera`` is a float64 [4, 4] OpenCV-convention pose."""

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_camera: np.ndarray

    def __post_init__(self) -> None:
        pose = np.asarray(self.world_to_camera, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"camera {self.name!r}: world_to_camera must be 4x4, got {pose.shape}")
        object.__setattr__(self, "world_to_camera", pose)

    @property
    def intrinsics(self) -> np.ndarray:
        """K: [3, 3] float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def camera_to_world(self) -> np.ndarray:
        """[4, 4] float64, the rigid inverse (no general matrix inverse needed)."""
        return rigid_inverse(self.world_to_camera)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates: [3]."""
        rotation = self.world_to_camera[:3, :3]
        return -rotation.T @ self.world_to_camera[:3, 3]

    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation: [3, 3]."""
        return self.world_to_camera[:3, :3]

    def scaled(self, factor: float) -> "Camera":
        """The same camera at an image ``factor`` times smaller (factor 2 halves width)."""
        width = max(1, int(round(self.width / factor)))
        height = max(1, int(round(self.height / factor)))
        sx, sy = width / self.width, height / self.height
        return replace(self, width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                       cx=self.cx * sx, cy=self.cy * sy)

    def cropped(self, x0: int, y0: int, width: int, height: int) -> "Camera":
        """A window of this camera's image (shifted principal point), e.g. a training patch."""
        return replace(self, width=int(width), height=int(height), cx=self.cx - x0, cy=self.cy - y0)

    def with_pose(self, world_to_camera: np.ndarray, name: str | None = None) -> "Camera":
        return replace(self, world_to_camera=np.asarray(world_to_camera, np.float64),
                       name=self.name if name is None else name)

    def to_json_dict(self) -> dict:
        return {
            "name": self.name,
            "width": int(self.width),
            "height": int(self.height),
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "world_to_camera": self.world_to_camera.tolist(),
        }


def project_points(points: np.ndarray, camera: "Camera") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points [P, 3] -> (pixels [P, 2] as (u, v), camera depth z [P], inside [P] bool: in
    front of the near plane and within the image). Pixels are only meaningful where inside."""
    local = np.asarray(points, np.float64).reshape(-1, 3) @ camera.rotation.T + camera.world_to_camera[:3, 3]
    z = local[:, 2]
    front = z > NEAR_PLANE
    safe_z = np.where(front, z, 1.0)        # divided by only where front (z > NEAR_PLANE > 0)
    u = camera.fx * local[:, 0] / safe_z + camera.cx
    v = camera.fy * local[:, 1] / safe_z + camera.cy
    inside = front & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    return np.stack([u, v], 1), z, inside


def rigid_inverse(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid [4, 4] transform: [R t]^-1 = [R^T, -R^T t]."""
    out = np.eye(4)
    rotation = pose[:3, :3]
    out[:3, :3] = rotation.T
    out[:3, 3] = -rotation.T @ pose[:3, 3]
    return out


# --- quaternions (w, x, y, z) -------------------------------------------------------------

def quat_normalize(q: np.ndarray) -> np.ndarray:
    """q: [..., 4] -> unit quaternions; raises ValueError for (near-)zero quaternions."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < _QUAT_NORM_MIN) or not np.all(np.isfinite(norm)):
        raise ValueError("cannot normalise a zero or non-finite quaternion")
    return q / norm


def unit_quat_to_rotation(w, x, y, z, stack):
    """Rotation matrices [..., 3, 3] of unit quaternions given as components w, x, y, z (numpy
    or torch arrays of one shape [...]); ``stack`` is ``np.stack`` or ``torch.stack``. The one
    home of the formula: callers normalise first, each with its own rule for degenerate input."""
    return stack([
        stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """q: [..., 4] (w, x, y, z), any non-zero norm -> rotation matrices [..., 3, 3]."""
    w, x, y, z = np.moveaxis(quat_normalize(q), -1, 0)
    return unit_quat_to_rotation(w, x, y, z, np.stack)


def rotation_to_quat(rotation: np.ndarray) -> np.ndarray:
    """rotation: [3, 3] -> unit quaternion [4] with w >= 0 (Shepperd's method: the largest
    diagonal term is always the pivot, so no branch divides by a small number)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    candidates = np.array([trace, m[0, 0], m[1, 1], m[2, 2]])
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * math.sqrt(max(1.0 + trace, 1e-300))
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2.0 * math.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 1e-300))
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2.0 * math.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 1e-300))
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 1e-300))
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = quat_normalize(np.array(q))
    return -q if q[0] < 0 else q


def quat_slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Spherical interpolation between unit quaternions [4] along the shorter arc.

    q and -q are the same rotation, so q1 is flipped into q0's hemisphere first; for nearly
    equal rotations the slerp weights are ill-conditioned and normalised lerp is used.
    The result is always a unit quaternion.
    """
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    dot = min(dot, 1.0)
    angle = math.acos(dot)
    sin_angle = math.sin(angle)
    if sin_angle < _SLERP_SMALL_ANGLE:
        return quat_normalize((1.0 - t) * q0 + t * q1)
    w0 = math.sin((1.0 - t) * angle) / sin_angle
    w1 = math.sin(t * angle) / sin_angle
    return quat_normalize(w0 * q0 + w1 * q1)


def rotation_angle_between(rotation_a: np.ndarray, rotation_b: np.ndarray) -> float:
    """Geodesic angle (radians, in [0, pi]) between two rotation matrices."""
    relative = rotation_a @ rotation_b.T
    # Rounding can put the trace a hair outside [-1, 3]; clip before acos.
    cos_angle = np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)
    return float(math.acos(cos_angle))


def pose_distance(world_to_camera_a: np.ndarray, world_to_camera_b: np.ndarray,
                  rotation_weight: float = 1.0) -> float:
    """Distance mixing camera-centre distance and viewing-angle difference.

    d = |c_a - c_b| + rotation_weight * angle(R_a, R_b), angle in radians. Finite for equal
    poses (0) and for opposite orientations (pi * weight); the caller picks the weight in
    scene units per radian (scene normalisation makes ~1 a sensible default).
    """
    center_a = -world_to_camera_a[:3, :3].T @ world_to_camera_a[:3, 3]
    center_b = -world_to_camera_b[:3, :3].T @ world_to_camera_b[:3, 3]
    angle = rotation_angle_between(world_to_camera_a[:3, :3], world_to_camera_b[:3, :3])
    return float(np.linalg.norm(center_a - center_b) + rotation_weight * angle)


def interpolate_pose(world_to_camera_a: np.ndarray, world_to_camera_b: np.ndarray,
                     t: float) -> np.ndarray:
    """Pose at fraction t from a to b: centre lerp, orientation slerp. Returns [4, 4]."""
    center_a = -world_to_camera_a[:3, :3].T @ world_to_camera_a[:3, 3]
    center_b = -world_to_camera_b[:3, :3].T @ world_to_camera_b[:3, 3]
    q = quat_slerp(rotation_to_quat(world_to_camera_a[:3, :3]),
                   rotation_to_quat(world_to_camera_b[:3, :3]), t)
    rotation = quat_to_rotation(q)
    center = (1.0 - t) * center_a + t * center_b
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = -rotation @ center
    return out


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, -1.0, 0.0)) -> np.ndarray:
    """World-to-camera [4, 4] for a camera at ``eye`` looking at ``target`` (OpenCV axes).

    ``up`` is the world direction that should appear up in the image; since OpenCV's y axis
    points down, the default (0, -1, 0) means world -y is up. When ``up`` is parallel to the
    viewing direction another axis is used instead of producing a NaN basis.
    """
    eye = np.asarray(eye, np.float64)
    forward = np.asarray(target, np.float64) - eye
    norm = np.linalg.norm(forward)
    if norm < 1e-12:
        raise ValueError("look_at: eye and target coincide")
    forward /= norm
    up = np.asarray(up, np.float64)
    # OpenCV axes: x = y cross z, i.e. right = down x forward = forward x up.
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        fallback = np.array([1.0, 0.0, 0.0]) if abs(forward[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        right = np.cross(forward, fallback)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])  # rows: camera axes in world coordinates
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = -rotation @ eye
    return out


# --- camera JSON (DESIGN.md) ----------------------------------------------------------------

def camera_from_json_dict(data: dict, source: str = "<camera json>") -> Camera:
    """Parse {"width","height","fx","fy","cx","cy","world_to_camera"} (+ optional "name")."""
    required = ("width", "height", "fx", "fy", "cx", "cy", "world_to_camera")
    missing = [key for key in required if key not in data]
    if missing:
        raise InputError(f"{source}: camera JSON is missing {', '.join(missing)}")
    width, height = (rule("image side").check(data[key], f"{source}: {key}") for key in ("width", "height"))
    values = [rule("focal length" if key in ("fx", "fy") else "principal point").check(data[key], f"{source}: {key}")
              for key in ("fx", "fy", "cx", "cy")]
    try:
        pose = np.asarray(data["world_to_camera"], dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{source}: world_to_camera has a malformed value ({exc})") from None
    if pose.shape != (4, 4):
        raise InputError(f"{source}: world_to_camera must be a 4x4 matrix, got shape {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise InputError(f"{source}: world_to_camera contains NaN or Inf")
    if np.abs(pose).max() > COORDINATE_MAX:
        raise InputError(f"{source}: world_to_camera holds {np.abs(pose).max():g}, beyond the {COORDINATE_MAX:g} "
                         "a scene coordinate may reach")
    check_image_size(width, height, source)
    rotation = pose[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4) or np.linalg.det(rotation) < 0:
        raise InputError(f"{source}: world_to_camera rotation is not a proper rotation")
    return Camera(str(data.get("name", Path(source).stem)), width, height, *values, pose)


def read_camera_json(path: str | Path) -> Camera:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: camera file does not exist")
    return camera_from_json_dict(read_json_object(path, "camera"), str(path))


def write_camera_json(camera: Camera, path: str | Path) -> None:
    atomic_write_text(path, json.dumps(camera.to_json_dict(), indent=2) + "\n")
