"""Camera paths: keyframed fly-throughs and orbits, their JSON file and the cameras of their frames.

A path is a list of keyframes, each a pose (world-to-camera, OpenCV axes) with a vertical field
of view at a time in seconds, plus the video's size and frame rate. A frame at time t takes
its camera centre from a cubic through the keyframes' centres (Catmull-Rom with the keyframe
times as knots: it passes through every keyframe, and its velocity is continuous), its
orientation from the quaternion slerp between the two keyframes around t, and its field of
view linearly between them (a cubic could overshoot to a negative or huge angle).

The JSON file (``write_path_json`` / ``read_path_json``) is user input: unknown keys, missing
keys, non-finite numbers, fewer than two keyframes, times not increasing, a field of view
outside (FOV_MIN_DEG, FOV_MAX_DEG), a frame rate outside (0, FPS_MAX] and an improper rotation
are each one InputError line naming the file. Poses are in the frame of the model file they
were made for (as ``inceptiongs render --camera``)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .camera import Camera, look_at, quat_slerp, quat_to_rotation, rotation_to_quat
from .errors import InputError
from .io.atomic import atomic_write_text
from .io.config_json import read_json_object
from .io.limits import check_image_size

PATH_FORMAT = "inceptiongs camera path"
PATH_VERSION = 1
FOV_MIN_DEG = 1.0
FOV_MAX_DEG = 170.0
FPS_MAX = 240.0
# Frames of one video at most: 10 minutes at 60 fps.
MAX_FRAMES = 36_000
DEFAULT_FPS = 30.0
TOP_KEYS = {"format", "version", "width", "height", "fps", "keyframes"}
KEYFRAME_KEYS = {"time", "world_to_camera", "fov_y_deg"}


@dataclass(frozen=True)
class Keyframe:
    """time_s: seconds from the start; world_to_camera: [4, 4] float64; fov_y_deg: vertical."""

    time_s: float
    world_to_camera: np.ndarray
    fov_y_deg: float

    @property
    def center(self) -> np.ndarray:
        """[3] camera centre in world coordinates."""
        return -self.world_to_camera[:3, :3].T @ self.world_to_camera[:3, 3]


@dataclass(frozen=True)
class CameraPath:
    """keyframes: at least two, times strictly increasing; width x height: the video's size;
    fps: frames per second."""

    keyframes: tuple
    width: int
    height: int
    fps: float = DEFAULT_FPS

    @property
    def duration_s(self) -> float:
        return float(self.keyframes[-1].time_s - self.keyframes[0].time_s)

    def frame_count(self, fps: float | None = None) -> int:
        """Frames at ``fps`` (default the path's) from the first keyframe to the last, both ends shown."""
        fps = self.fps if fps is None else fps
        # A hair under a whole frame counts as one: 2 s at 30 fps is 61 frames, not 60.
        return int(math.floor(self.duration_s * fps + 1e-6)) + 1


# --- interpolation ---------------------------------------------------------------------------

def hermite_tangents(times: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Catmull-Rom tangents of ``points`` [K, D] at ``times`` [K] (strictly increasing): the
    central difference over the neighbours' times, one-sided at the ends. -> [K, D]."""
    tangents = np.empty_like(points)
    # times strictly increase (checked by the reader and the editor), so every span is > 0.
    tangents[1:-1] = (points[2:] - points[:-2]) / (times[2:] - times[:-2])[:, None]
    tangents[0] = (points[1] - points[0]) / (times[1] - times[0])
    tangents[-1] = (points[-1] - points[-2]) / (times[-1] - times[-2])
    return tangents


def hermite(times: np.ndarray, points: np.ndarray, tangents: np.ndarray, t: float) -> np.ndarray:
    """The cubic Hermite spline through ``points`` [K, D] at ``times`` [K] with ``tangents``
    [K, D], at time ``t`` (clamped to the keyframes' range). -> [D]."""
    t = float(np.clip(t, times[0], times[-1]))
    i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
    span = times[i + 1] - times[i]
    s = (t - times[i]) / span
    h00, h10 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s
    h01, h11 = -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
    return h00 * points[i] + h10 * span * tangents[i] + h01 * points[i + 1] + h11 * span * tangents[i + 1]


def pose_at(path: CameraPath, t: float) -> tuple[np.ndarray, float]:
    """(world_to_camera [4, 4], fov_y_deg) of ``path`` at ``t`` seconds after its first keyframe."""
    keys = path.keyframes
    times = np.array([k.time_s for k in keys], np.float64)
    centers = np.stack([k.center for k in keys])
    t = float(np.clip(times[0] + t, times[0], times[-1]))
    center = hermite(times, centers, hermite_tangents(times, centers), t)
    i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
    s = (t - times[i]) / (times[i + 1] - times[i])
    q = quat_slerp(rotation_to_quat(keys[i].world_to_camera[:3, :3]),
                   rotation_to_quat(keys[i + 1].world_to_camera[:3, :3]), s)
    rotation = quat_to_rotation(q)
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = -rotation @ center
    fov = (1.0 - s) * keys[i].fov_y_deg + s * keys[i + 1].fov_y_deg
    return pose, float(fov)


def even_size(width: int, height: int) -> tuple[int, int]:
    """The video's frame size: H.264 in yuv420p needs even sides, so an odd side loses a pixel."""
    return max(2, int(width) - int(width) % 2), max(2, int(height) - int(height) % 2)


def camera_for(pose: np.ndarray, fov_y_deg: float, width: int, height: int, name: str) -> Camera:
    """A centred pinhole camera of square pixels at ``pose`` [4, 4] seeing ``fov_y_deg`` vertically."""
    # fov_y_deg lies in [FOV_MIN_DEG, FOV_MAX_DEG], so the tangent is finite and positive.
    focal = 0.5 * height / math.tan(math.radians(fov_y_deg) * 0.5)
    return Camera(name, int(width), int(height), focal, focal, 0.5 * width, 0.5 * height, pose)


def path_cameras(path: CameraPath, fps: float | None = None) -> list[Camera]:
    """The camera of every frame of ``path`` at ``fps`` (default the path's), at its even size."""
    fps = path.fps if fps is None else fps
    width, height = even_size(path.width, path.height)
    cameras = []
    for index in range(path.frame_count(fps)):
        pose, fov = pose_at(path, index / fps)
        cameras.append(camera_for(pose, fov, width, height, f"frame_{index:05d}"))
    return cameras


# --- the orbit ---------------------------------------------------------------------------------

def looked_at_point(cameras: list[Camera], fallback: np.ndarray) -> np.ndarray:
    """The point nearest (least squares) to every camera's optical axis: what the cameras look
    at. ``fallback`` [3] when the axes are (nearly) parallel, as in a forward-facing capture,
    where that point is ill-determined."""
    system = np.zeros((3, 3))
    rhs = np.zeros(3)
    for camera in cameras:
        forward = camera.rotation[2]
        projector = np.eye(3) - np.outer(forward, forward)  # distance to the axis, squared
        system += projector
        rhs += projector @ camera.center
    eigenvalues = np.linalg.eigvalsh(system)
    # Parallel axes leave one eigenvalue ~0: no single point; 5 % of the largest is a clear fix.
    if len(cameras) < 2 or eigenvalues[0] < 0.05 * eigenvalues[-1]:
        return np.asarray(fallback, np.float64)
    return np.linalg.solve(system, rhs)


def orbit_up(cameras: list[Camera]) -> np.ndarray:
    """[3] unit world up for an orbit: the cameras' mean image up; but when their centres lie
    near a plane that is clearly a plane (a ring around the object: its thinnest spread under
    1/10 of the next), that plane's normal on the same side, since cameras looking down at
    the object tilt their image up towards it and a tilted orbit would rise and fall."""
    up = -np.mean([c.rotation[1] for c in cameras], axis=0)
    up = up / max(np.linalg.norm(up), 1e-12)
    centers = np.stack([c.center for c in cameras])
    if len(centers) >= 3:
        values, vectors = np.linalg.eigh(np.cov((centers - centers.mean(0)).T))
        if values[1] > 0 and values[0] < 0.1 * values[1]:
            normal = vectors[:, 0]
            return normal if normal @ up >= 0 else -normal
    return up


def orbit_path(cameras: list[Camera], model_center: np.ndarray, model_radius: float, width: int = 1280,
               height: int = 720, seconds: float = 8.0, fps: float = DEFAULT_FPS,
               fov_y_deg: float = 50.0, keyframes: int = 24) -> CameraPath:
    """One turn around what the training ``cameras`` look at (looked_at_point; ``model_center``
    [3] when they look along parallel axes or there are none), at their median distance and
    mean height above it, looking at it, the image's up the cameras' mean up. Without cameras:
    around ``model_center`` at 2.5 ``model_radius``, up -y (the 3DGS convention)."""
    if cameras:
        target = looked_at_point(cameras, model_center)
        up = orbit_up(cameras)
        offsets = np.stack([c.center for c in cameras]) - target
        height_above = float(np.mean(offsets @ up))
        flat = offsets - np.outer(offsets @ up, up)
        radius = float(np.median(np.linalg.norm(flat, axis=1)))
        if radius < 1e-6 * max(float(np.linalg.norm(offsets, axis=1).max()), 1e-12):
            radius = max(abs(height_above), 1e-3)  # cameras straight above: circle at their height
    else:
        target = np.asarray(model_center, np.float64)
        up = np.array([0.0, -1.0, 0.0])
        radius, height_above = 2.5 * max(float(model_radius), 1e-3), 0.5 * max(float(model_radius), 1e-3)
    # Two directions across up; the first points at the first camera (the orbit starts there).
    start = (cameras[0].center - target) if cameras else np.array([0.0, 0.0, -1.0])
    across = start - (start @ up) * up
    if np.linalg.norm(across) < 1e-9:
        across = np.cross(up, [1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.cross(up, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    side = np.cross(up, across)
    keys = []
    for index in range(keyframes + 1):  # the last closes the circle where it began
        angle = 2.0 * math.pi * index / keyframes
        eye = target + radius * (math.cos(angle) * across + math.sin(angle) * side) + height_above * up
        keys.append(Keyframe(seconds * index / keyframes, look_at(eye, target, up), fov_y_deg))
    return CameraPath(tuple(keys), int(width), int(height), float(fps))


# --- the JSON file -----------------------------------------------------------------------------

def path_to_json_dict(path: CameraPath) -> dict:
    return {"format": PATH_FORMAT, "version": PATH_VERSION, "width": int(path.width), "height": int(path.height),
            "fps": float(path.fps),
            "keyframes": [{"time": float(k.time_s), "world_to_camera": np.asarray(k.world_to_camera).tolist(),
                           "fov_y_deg": float(k.fov_y_deg)} for k in path.keyframes]}


def write_path_json(path: CameraPath, out: str | Path) -> Path:
    """The path as JSON at ``out`` (atomic: a reader never sees half a file)."""
    check_path(path, str(out))
    data = path_to_json_dict(path)
    keys = data.pop("keyframes")
    head = json.dumps(data, indent=1)[:-2]  # the object without its closing brace
    # One keyframe a line: a person reads and edits the file by keyframe.
    lines = ",\n  ".join(json.dumps(key) for key in keys)
    atomic_write_text(out, f'{head},\n "keyframes": [\n  {lines}\n ]\n}}\n')
    return Path(out)


def _number(value, where: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{source}: {where} must be a number, got {json.dumps(value)[:40]}")
    if not math.isfinite(value):
        raise InputError(f"{source}: {where} is not finite ({value})")
    return float(value)


def _keyframe(data, index: int, source: str) -> Keyframe:
    where = f"keyframe {index}"
    if not isinstance(data, dict):
        raise InputError(f"{source}: {where} must be an object with {', '.join(sorted(KEYFRAME_KEYS))}")
    unknown, missing = set(data) - KEYFRAME_KEYS, KEYFRAME_KEYS - set(data)
    if unknown:
        raise InputError(f"{source}: {where} has unknown key(s) {', '.join(sorted(unknown))}")
    if missing:
        raise InputError(f"{source}: {where} is missing {', '.join(sorted(missing))}")
    time_s = _number(data["time"], f"{where} time", source)
    fov = _number(data["fov_y_deg"], f"{where} fov_y_deg", source)
    rows = data["world_to_camera"]
    if (not isinstance(rows, list) or len(rows) != 4
            or not all(isinstance(row, list) and len(row) == 4 for row in rows)):
        raise InputError(f"{source}: {where} world_to_camera must be a 4x4 list of numbers")
    pose = np.array([[_number(v, f"{where} world_to_camera", source) for v in row] for row in rows])
    return Keyframe(time_s, pose, fov)


def check_path(path: CameraPath, source: str) -> None:
    """InputError (one line naming ``source``) unless ``path`` can be rendered."""
    keys = path.keyframes
    if len(keys) < 2:
        raise InputError(f"{source}: a camera path needs at least 2 keyframes, it has {len(keys)}")
    for index, key in enumerate(keys):
        if not (key.time_s >= 0.0 and math.isfinite(key.time_s)):
            raise InputError(f"{source}: keyframe {index} time must be >= 0 seconds, got {key.time_s}")
        if index and not key.time_s > keys[index - 1].time_s:
            raise InputError(f"{source}: keyframe {index} time {key.time_s:g} s is not after keyframe "
                             f"{index - 1}'s {keys[index - 1].time_s:g} s (times must increase)")
        if not FOV_MIN_DEG <= key.fov_y_deg <= FOV_MAX_DEG:
            raise InputError(f"{source}: keyframe {index} fov_y_deg {key.fov_y_deg:g} is outside "
                             f"[{FOV_MIN_DEG:g}, {FOV_MAX_DEG:g}] degrees")
        pose = np.asarray(key.world_to_camera, np.float64)
        rotation = pose[:3, :3]
        if (not np.all(np.isfinite(pose)) or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4)
                or np.linalg.det(rotation) < 0 or not np.allclose(pose[3], [0, 0, 0, 1])):
            raise InputError(f"{source}: keyframe {index} world_to_camera is not a rigid pose (proper rotation, "
                             "last row 0 0 0 1)")
    if not 0.0 < path.fps <= FPS_MAX:
        raise InputError(f"{source}: fps must be in (0, {FPS_MAX:g}], got {path.fps:g}")
    if path.width <= 0 or path.height <= 0:
        raise InputError(f"{source}: width and height must be positive, got {path.width}x{path.height}")
    check_image_size(path.width, path.height, source)
    if path.frame_count() > MAX_FRAMES:
        raise InputError(f"{source}: {path.frame_count()} frames ({path.duration_s:g} s at {path.fps:g} fps); "
                         f"at most {MAX_FRAMES} are rendered")


def path_from_json_dict(data: dict, source: str) -> CameraPath:
    """The strict reader: see the module's docstring for what is refused."""
    unknown, missing = set(data) - TOP_KEYS, {"width", "height", "keyframes"} - set(data)
    if unknown:
        raise InputError(f"{source}: unknown key(s) {', '.join(sorted(unknown))} (a camera path has "
                         f"{', '.join(sorted(TOP_KEYS))})")
    if missing:
        raise InputError(f"{source}: camera path is missing {', '.join(sorted(missing))}")
    if data.get("format", PATH_FORMAT) != PATH_FORMAT:
        raise InputError(f"{source}: format must be {PATH_FORMAT!r}, got {data['format']!r}")
    if data.get("version", PATH_VERSION) != PATH_VERSION:
        raise InputError(f"{source}: version {data['version']!r} is not supported (this reader: {PATH_VERSION})")
    keyframes = data["keyframes"]
    if not isinstance(keyframes, list):
        raise InputError(f"{source}: keyframes must be a list")
    sizes = []
    for key in ("width", "height"):
        value = _number(data[key], key, source)
        if value != int(value):
            raise InputError(f"{source}: {key} must be a whole number of pixels, got {value:g}")
        sizes.append(int(value))
    fps = _number(data.get("fps", DEFAULT_FPS), "fps", source)
    path = CameraPath(tuple(_keyframe(k, i, source) for i, k in enumerate(keyframes)), *sizes, fps)
    check_path(path, source)
    return path


def read_path_json(path_file: str | Path) -> CameraPath:
    path_file = Path(path_file)
    if not path_file.is_file():
        raise InputError(f"{path_file}: camera path file does not exist")
    return path_from_json_dict(read_json_object(path_file, "camera path"), str(path_file))


def free_name(folder: str | Path, stem: str, suffix: str) -> Path:
    """``folder/stem_N.suffix`` for the smallest N >= 1 not yet taken: each save a new file."""
    folder = Path(folder)
    number = 1
    while (folder / f"{stem}_{number}{suffix}").exists():
        number += 1
    return folder / f"{stem}_{number}{suffix}"
