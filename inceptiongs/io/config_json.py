"""Run configurations (dataclasses of plain values) as JSON files: written atomically, read
back strictly (unknown keys are an error, not silently dropped)."""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import types
import typing
from pathlib import Path
from dataclasses import dataclass
from typing import ClassVar, TypeVar


from .atomic import atomic_write_text
from .paths import read_small_text
from .values import (SEED_MAX, Range, Rule, above, at_least, is_finite_number, is_integer,  # noqa: F401
                     rule as named_rule, shown, within)
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
        return is_integer(value)
    if kind is float:
        return is_finite_number(value)
    if kind is str:
        return isinstance(value, str)
    return True


def check_seed(value, source: str) -> None:
    """InputError unless ``value`` is an int seed in 0..SEED_MAX (the "seed" rule)."""
    named_rule("seed").check(value, f"{source}: seed" if not source.startswith("--") else source)


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


# --- documented, nested configs -------------------------------------------------------------------
# A config made of sections (nested dataclasses) whose every setting carries its meaning, unit,
# range and choices in its field metadata: the strict reader below checks a JSON object against
# them, and an options page is generated from the same metadata (scripts/gen_train_options.py).


def setting(default, meaning: str, unit: str = "-", range: Range | None = None,
            choices: tuple | None = None, rule: Rule | None = None):
    """A config field with its documentation and limits: what it means, its unit ("-": none),
    the range a number must lie in and the values a string may take (None: any). ``rule`` (a
    rule of io/values.py, the one the matching flag follows) gives the range and unit instead.
    A list default is copied for every instance."""
    if rule is not None:
        range, unit = rule.range, (unit if rule.unit == "-" else rule.unit)
    metadata = {"meaning": meaning, "unit": unit, "range": range, "choices": choices}
    if isinstance(default, list):
        return dataclasses.field(default_factory=lambda: list(default), metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def section(cls: type, meaning: str):
    """A config field holding a section: the dataclass ``cls`` of settings, its defaults by default."""
    return dataclasses.field(default_factory=cls, metadata={"meaning": meaning})


def is_section(kind) -> bool:
    """Whether the (resolved) annotation ``kind`` is a section: a dataclass type."""
    return isinstance(kind, type) and dataclasses.is_dataclass(kind)


def section_hints(cls: type) -> dict:
    """Field name -> resolved annotation of the dataclass ``cls``."""
    return typing.get_type_hints(cls)


def setting_paths(cls: type, prefix: str = "") -> list[str]:
    """Every setting of the config class ``cls`` as a dotted path ("losses.lambda_dssim"), in
    declaration order, sections' settings in place of the section."""
    hints, paths = section_hints(cls), []
    for f in dataclasses.fields(cls):
        if is_section(hints[f.name]):
            paths += setting_paths(hints[f.name], f"{prefix}{f.name}.")
        else:
            paths.append(prefix + f.name)
    return paths


def config_value(config, path: str):
    """The value at dotted ``path`` of a config instance."""
    for part in path.split("."):
        config = getattr(config, part)
    return config


def with_values(config, values: dict):
    """A copy of the config instance ``config`` with ``values`` ({dotted path: value}) set,
    sections copied (dataclasses.replace) along each path; the others are shared."""
    by_section: dict[str, dict] = {}
    direct = {}
    for path, value in values.items():
        head, _, rest = path.partition(".")
        if rest:
            by_section.setdefault(head, {})[rest] = value
        else:
            direct[head] = value
    for head, inner in by_section.items():
        direct[head] = with_values(getattr(config, head), inner)
    return dataclasses.replace(config, **direct)


def flat_values(data: dict, prefix: str = "") -> dict:
    """A nested JSON object -> {dotted path: value} of its leaves (non-object values)."""
    out = {}
    for key, value in data.items():
        if isinstance(value, dict):
            out.update(flat_values(value, f"{prefix}{key}."))
        else:
            out[prefix + key] = value
    return out


def key_hint(key: str, paths: list[str], aliases: dict[str, str] | None = None) -> str:
    """' (did you mean ...?)' for an unknown dotted ``key`` among ``paths``: the path an alias
    (an older spelling) stands for, the setting of the same name in another section, else the
    closest path; '' when nothing is close."""
    leaf = key.rsplit(".", 1)[-1]
    leaves = {path: path.rsplit(".", 1)[-1] for path in paths}
    close_leaves = difflib.get_close_matches(leaf, list(set(leaves.values())), n=1)
    close = ([aliases[key]] if aliases and key in aliases else []) \
        or [path for path, name in leaves.items() if name == leaf] \
        or difflib.get_close_matches(key, paths, n=1) \
        or [path for path, name in leaves.items() if name in close_leaves]
    return f" (did you mean {close[0]!r}?)" if close else ""


def _wanted(kind) -> str:
    """The JSON type an annotation asks for, in words."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_wanted(option) for option in typing.get_args(kind))
    if origin in (list, tuple):
        (item, *_) = typing.get_args(kind) or (None,)
        return "a list" + (f" of {_wanted(item).removeprefix('a ').removeprefix('an ')}s" if item else "")
    return {int: "an integer", float: "a finite number", str: "a string", bool: "true or false",
            type(None): "null"}.get(kind, _type_name(kind))


def _shown(value) -> str:
    """A value as its JSON text (NaN and Infinity too), cut to 60 characters."""
    return shown(value)


def checked_setting(source: str, path: str, kind, value, field: dataclasses.Field):
    """``value`` for the setting at ``path`` when it fits its annotation ``kind`` (an int widened
    to float for a float setting), its range and its choices (the field's metadata); else an
    InputError naming ``source`` and ``path``."""
    if not value_fits(value, kind):
        raise InputError(f"{source}: {path} must be {_wanted(kind)}, got {_shown(value)}")
    if value is None:
        return None
    wants_float = kind is float or (typing.get_origin(kind) in (typing.Union, types.UnionType)
                                    and float in typing.get_args(kind) and int not in typing.get_args(kind))
    if wants_float and not isinstance(value, bool):
        value = float(value)
    limits, choices = field.metadata.get("range"), field.metadata.get("choices")
    if limits is not None:
        value = Rule(float if wants_float else int, limits, field.metadata.get("unit", "-")).check(
            value, f"{source}: {path}")
    if choices is not None and value not in choices:
        raise InputError(f"{source}: {path} must be one of {', '.join(map(str, choices))}, got {value!r}")
    return value


def config_from_dict(cls: type[Config], data: dict, source: str, docs: str = "",
                     aliases: dict[str, str] | None = None, prefix: str = "",
                     paths: list[str] | None = None) -> Config:
    """An instance of the config class ``cls`` (settings and sections) from the JSON object
    ``data``: any subset of its keys (the others keep their defaults), a section as an object of
    its own keys. Strict: an unknown key (with the nearest known one, or the path an alias in
    ``aliases`` stands for), a value of the wrong type, a non-finite number, a number out of its
    range or a string not among its choices is an InputError, one line naming ``source`` and the
    key (``docs``: the page listing the keys). Rules between settings are the caller's (the
    config's ``validate``)."""
    paths = setting_paths(cls) if paths is None else paths
    hints = section_hints(cls)
    by_name = {f.name: f for f in dataclasses.fields(cls)}
    values = {}
    for key, value in data.items():
        path = prefix + str(key)
        if key not in by_name:
            listed = f"; {docs} lists the keys" if docs else ""
            raise InputError(f"{source}: unknown key {path!r}{key_hint(path, paths, aliases)}{listed}")
        kind = hints[key]
        if is_section(kind):
            if not isinstance(value, dict):
                raise InputError(f"{source}: {path} must be an object (the {path} section's keys), "
                                 f"got {_shown(value)}")
            values[key] = config_from_dict(kind, value, source, docs, aliases, f"{path}.", paths)
        else:
            values[key] = checked_setting(source, path, kind, value, by_name[key])
    return cls(**values)


def check_settings(config, source: str, prefix: str = "") -> None:
    """The checks of :func:`config_from_dict` on a config instance (one built in code or from
    the command line): InputError '<source>: <path> must be ...' for the first setting that does
    not fit its type, range or choices."""
    hints = section_hints(type(config))
    for f in dataclasses.fields(config):
        value, kind, path = getattr(config, f.name), hints[f.name], prefix + f.name
        if is_section(kind):
            if not isinstance(value, kind):
                raise InputError(f"{source}: {path} must hold the {path} section's settings, got {_shown(value)}")
            check_settings(value, source, f"{path}.")
        else:
            checked_setting(source, path, kind, value, f)
