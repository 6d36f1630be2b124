"""Run configurations (dataclasses of plain values) as JSON files: written atomically, read
back strictly (unknown keys are an error, not silently dropped)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import ClassVar, TypeVar

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


class SavedConfig:
    """What every run configuration (a dataclass with ``validate(source)``) does with its file:
    ``to_json_dict``, ``save`` (atomic) and ``load`` (strict, validated). ``CONFIG_KIND`` names
    it in errors."""

    CONFIG_KIND = "config"
    # Fields added after files were already written, and the value that reproduces how such a
    # file's run behaved: a file without the key loads with it (a new config gets the default).
    LEGACY_VALUES: ClassVar[dict] = {}

    def to_json_dict(self) -> dict:
        return dataclasses.asdict(self)

    def save(self, path: str | Path) -> None:
        save_config(self, path)

    @classmethod
    def load(cls, path: str | Path):
        return load_config(cls, path, cls.CONFIG_KIND)


def save_config(config, path: str | Path) -> None:
    """config: a dataclass instance of JSON-able fields."""
    atomic_write_text(path, json.dumps(dataclasses.asdict(config), indent=2, sort_keys=True) + "\n")


def load_config(cls: type[Config], path: str | Path, what: str = "config") -> Config:
    """An instance of the dataclass ``cls`` from ``path``, validated (``cls.validate(source)``),
    with ``cls.LEGACY_VALUES`` (if any) for the keys the file lacks. Errors name the file and the
    problem; ``what`` says which kind of config it should be."""
    path = Path(path)
    data = {**getattr(cls, "LEGACY_VALUES", {}), **read_json_object(path, what)}
    config = dataclass_from_dict(cls, data, str(path), what)
    return config.validate(str(path))


def dataclass_from_dict(cls: type[Config], data: dict, source: str, what: str = "config") -> Config:
    """An instance of the dataclass ``cls`` from ``data``, strictly: an unknown key or a missing
    required one is an InputError naming ``source``, never silently dropped or guessed."""
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InputError(f"{source}: unknown {what} keys {', '.join(unknown)}")
    try:
        return cls(**data)
    except TypeError as exc:
        raise InputError(f"{source}: {what} does not fit ({exc})") from None


def json_safe(value):
    """JSON has no inf: an exact reconstruction's PSNR is written as the string "inf"."""
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    return value
