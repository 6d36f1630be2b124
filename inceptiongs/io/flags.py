"""The viewer's flagged bad views, ``flags.json``: the target views stage II repairs.

Format (docs/viewer.md): {"version": 1, "flags": [{"name": str, "camera": <camera JSON>,
"created": ISO-8601 UTC}]}. Camera JSON is the project's ({"width", "height", "fx", "fy",
"cx", "cy", "world_to_camera"}, plus "name"). The app writes it, stage II reads it; this is
the one place the format lives.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ..camera import Camera, camera_from_json_dict
from ..errors import InputError
from .paths import read_small_text
from .atomic import atomic_write_text

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
        data = json.loads(read_small_text(path, "flags JSON"))
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


def read_flag_cameras(flags_file: str | Path) -> list[Camera]:
    """The cameras of an existing flags.json (stage II's targets); a missing file is an error."""
    flags_file = Path(flags_file)
    if not flags_file.is_file():
        raise InputError(f"{flags_file}: flags file does not exist")
    return [flag.camera for flag in load_flags(flags_file)]
