"""Run configurations (dataclasses of plain values) as JSON files: written atomically, read
back strictly (unknown keys are an error, not silently dropped)."""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import types
import typing
from pathlib import Path
from typing import ClassVar, TypeVar

import numpy as np

from .atomic import atomic_write_text
from .paths import read_small_text
from ..errors import InputError

Config = TypeVar("Config")


def read_json_object(path: str | Path, what: str) -> dict:
    """The JSON object in ``path``; an InputError naming the file when it cannot be read, is
    not JSON or is not an object (``what`` says what it should have been, e.g. "camera")."""
    path = Path(path)
    try:
        data = json.loads(read_small_text(path, f"{what} JSON"))
    except (OSError, json.JSONDecodeError) as exc:
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

    def check_types(self, source: str) -> None:
        """Every field fits its annotation (:func:`check_field_types`); ``validate`` calls it
        first, so a config from the command line is held to what a file is."""
        check_field_types(self, source)

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
        config = cls(**data)
    except TypeError as exc:
        raise InputError(f"{source}: {what} does not fit ({exc})") from None
    check_field_types(config, source)
    return config


def _type_name(kind) -> str:
    return getattr(kind, "__name__", None) or str(kind).replace("typing.", "")


def value_fits(value, kind) -> bool:
    """Whether a JSON value fits the annotation ``kind``: bool, int (not bool), float (an int
    too; finite), str, None, ``X | None``, ``list[X]``/``tuple[X, ...]``, ``Literal[...]``;
    any other annotation is not checked here (its ``validate`` does)."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        return any(value_fits(value, option) for option in typing.get_args(kind))
    if origin is typing.Literal:
        return value in typing.get_args(kind)
    if origin in (list, tuple):
        args = [a for a in typing.get_args(kind) if a is not Ellipsis]
        return isinstance(value, (list, tuple)) and all(value_fits(item, args[0]) for item in value) \
            if args else isinstance(value, (list, tuple))
    if kind is type(None) or kind is None:
        return value is None
    if kind is bool:
        return isinstance(value, bool)
    # numbers.Integral/Real: numpy scalars computed by the schedule helpers count as well.
    if kind is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))
    if kind is float:
        return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)) and math.isfinite(value)
    if kind is str:
        return isinstance(value, str)
    return True


# Seeds numpy and torch both take: 0 .. 2**32 - 1.
SEED_MAX = 2**32 - 1


def check_seed(value, source: str) -> None:
    """InputError unless ``value`` is an int seed in 0..SEED_MAX."""
    if not value_fits(value, int) or not 0 <= value <= SEED_MAX:
        raise InputError(f"{source}: seed must be an integer in 0..{SEED_MAX}, got {value!r}")


def check_field_types(config, source: str) -> None:
    """InputError '<source>: <field> must be <type>, got <value>' for the first field of the
    dataclass instance ``config`` whose value does not fit its annotation (types read from the
    annotations; numbers must be finite unless the field's default is not)."""
    hints = typing.get_type_hints(type(config))
    for field in dataclasses.fields(config):
        value, kind = getattr(config, field.name), hints.get(field.name)
        if kind is None or value_fits(value, kind) or value == field.default:
            continue
        shown = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
        raise InputError(f"{source}: {field.name} must be {_type_name(kind)}"
                         f"{' (a finite number)' if 'float' in _type_name(kind) else ''}, got {shown}")
    if "seed" in {field.name for field in dataclasses.fields(config)}:
        check_seed(config.seed, source)


def json_safe(value):
    """JSON has no inf: an exact reconstruction's PSNR is written as the string "inf"."""
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    return value
