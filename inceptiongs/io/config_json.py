"""Run configurations (dataclasses of plain values) as JSON files: written atomically, read
back strictly (unknown keys are an error, not silently dropped)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import TypeVar

from .atomic import atomic_write_text
from ..errors import InputError

Config = TypeVar("Config")


def read_json_object(path: str | Path, what: str) -> dict:
    """The JSON object in ``path``; an InputError naming the file when it cannot be read, is
    not JSON or is not an object (``what`` says what it should have been, e.g. "camera")."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable {what} JSON ({exc})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: {what} JSON must be an object")
    return data


def save_config(config, path: str | Path) -> None:
    """config: a dataclass instance of JSON-able fields."""
    atomic_write_text(path, json.dumps(dataclasses.asdict(config), indent=2, sort_keys=True) + "\n")


def load_config(cls: type[Config], path: str | Path, what: str = "config") -> Config:
    """An instance of the dataclass ``cls`` from ``path``, validated (``cls.validate(source)``).
    Errors name the file and the problem; ``what`` says which kind of config it should be."""
    path = Path(path)
    data = read_json_object(path, what)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InputError(f"{path}: unknown {what} keys {', '.join(unknown)}")
    try:
        config = cls(**data)
    except TypeError as exc:
        raise InputError(f"{path}: {what} JSON does not fit ({exc})") from None
    return config.validate(str(path))


def json_safe(value):
    """JSON has no inf: an exact reconstruction's PSNR is written as the string "inf"."""
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    return value
