"""Flagged bad views: the target views stage II repairs, kept in ``<work dir>/flags.json``.

Format (docs/viewer.md): {"version": 1, "flags": [{"name": str, "camera": <camera JSON>,
"created": ISO-8601 UTC}]}. Camera JSON is the project's ({"width", "height", "fx", "fy",
"cx", "cy", "world_to_camera"}, plus "name").
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from inceptiongs.atomic import atomic_write_text
from inceptiongs.camera import Camera, camera_from_json_dict, look_at

from inceptiongs.errors import InputError

FLAGS_FILE_NAME = "flags.json"
FLAGS_FORMAT_VERSION = 1


@dataclass(frozen=True)
class Flag:
    name: str
    camera: Camera
    created: str  # ISO-8601, UTC


def now_iso() -> str:
    return datetime.now(timezone.utc).replace(microsecond=0).isoformat()


def flags_path(work_dir: str | Path) -> Path:
    return Path(work_dir) / FLAGS_FILE_NAME


def load_flags(path: str | Path) -> list[Flag]:
    """The flags in ``path``; an absent file means no flags yet. Malformed -> InputError."""
    path = Path(path)
    if not path.exists():
        return []
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable flags file ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("flags"), list):
        raise InputError(f"{path}: flags file must be an object with a 'flags' list")
    if data.get("version") != FLAGS_FORMAT_VERSION:
        raise InputError(f"{path}: unsupported flags file version {data.get('version')!r} "
                         f"(expected {FLAGS_FORMAT_VERSION})")
    flags = []
    for index, entry in enumerate(data["flags"]):
        if not isinstance(entry, dict) or not isinstance(entry.get("camera"), dict):
            raise InputError(f"{path}: flag {index} must be an object with a 'camera' object")
        name = str(entry.get("name", f"flag {index + 1}"))
        camera = camera_from_json_dict({**entry["camera"], "name": name}, f"{path} (flag {index})")
        flags.append(Flag(name, camera, str(entry.get("created", ""))))
    return flags


def save_flags(path: str | Path, flags: list[Flag]) -> None:
    """Write all flags atomically (a crash never leaves a half-written file for stage II)."""
    data = {
        "version": FLAGS_FORMAT_VERSION,
        "flags": [{"name": f.name, "camera": {**f.camera.to_json_dict(), "name": f.name},
                   "created": f.created} for f in flags],
    }
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")


def unique_flag_name(flags: list[Flag], prefix: str = "flag") -> str:
    """The first "prefix N" (N = 1, 2, ...) not used by any flag."""
    used = {f.name for f in flags}
    n = 1
    while f"{prefix} {n}" in used:
        n += 1
    return f"{prefix} {n}"


def flag_camera(camera: Camera, name: str) -> Flag:
    """A flag for the current view as it is."""
    return Flag(name, replace(camera, name=name), now_iso())


def unproject_pixel(camera: Camera, x: float, y: float, depth: float) -> np.ndarray:
    """World point [3] at camera-space z ``depth`` on the ray through pixel (x, y), where
    (x, y) are pixel indices (the ray goes through the pixel centre, x + 0.5, y + 0.5)."""
    ray = np.array([(x + 0.5 - camera.cx) / camera.fx, (y + 0.5 - camera.cy) / camera.fy, 1.0])
    point_camera = ray * depth
    return camera.rotation.T @ (point_camera - camera.world_to_camera[:3, 3])


def flag_aimed_at(camera: Camera, target: np.ndarray, name: str) -> Flag:
    """A flag at ``camera``'s position and intrinsics, turned to look straight at ``target``
    [3] (keeping the camera's own up direction so the horizon does not jump)."""
    up = -camera.rotation[1]
    pose = look_at(camera.center, target, up)
    return Flag(name, camera.with_pose(pose, name=name), now_iso())
