"""How stage II's settings are declared and read back.

A setting is a dataclass field declared with :func:`option`: its meaning, unit and role live in
the field's metadata, so docs/bootstrap_options.md is generated from the code
(scripts/gen_bootstrap_options.py). ``BootstrapConfig`` (config.py) and every variant's own
options (variants.py) are declared this way, and a JSON object of them is read by the same strict
rules (:func:`read_options`): an unknown key is one line with the nearest name, a value of the
wrong type or a non-finite number one line naming the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
from dataclasses import field
from pathlib import Path
from typing import Iterable

from ..errors import InputError

# A setting's role (docs/bootstrap_options.md explains them).
DEFAULT_PATH = "default path"           # its value shapes a run with every default
PRIOR_FILL = "prior fill"               # read only when a prior makes the fill (fill "prior", or blending off)
ABLATION = "ablation"                   # one of the paper's ablations; off by default
BOOKKEEPING = "bookkeeping"             # logs, evaluations, checkpoints, saved images: never the model
VARIANT = "variant"                     # a variant's own option: read only when that variant is chosen
ROLES = (DEFAULT_PATH, PRIOR_FILL, ABLATION, BOOKKEEPING, VARIANT)


def option(default, meaning: str, unit: str = "-", role: str = DEFAULT_PATH):
    """A documented setting: its default, what it means, its unit ("-": none) and its role (one
    of ROLES)."""
    assert role in ROLES, role
    return field(default=default, metadata={"meaning": meaning, "unit": unit, "role": role})


def closest(key: str, names: Iterable[str]) -> str:
    """' (did you mean NAME?)' for the name nearest ``key``, or '' when none is close."""
    close = difflib.get_close_matches(key, list(names), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def read_options(cls: type, data: dict, path: str | Path, prefix: str = "", also_known: Iterable[str] = ()) -> dict:
    """The values of the JSON object ``data`` for the dataclass ``cls``'s fields, each checked
    against its annotation (:func:`checked_value`) -> {field name: value}. ``prefix`` names
    where the object sits in the file ("variants.align."); ``also_known``: other names a key may
    be near (the hint suggests them too). Errors are one line naming ``path`` and the key."""
    by_name = {f.name: f for f in dataclasses.fields(cls)}
    values = {}
    for key, value in data.items():
        if key not in by_name:
            hint = closest(key, [*by_name, *also_known])
            raise InputError(f"{path}: unknown key {(prefix + key)!r}{hint}; docs/bootstrap_options.md lists the keys")
        values[key] = checked_value(path, prefix + key, by_name[key].type, value)
    return values


def checked_value(path: str | Path, key: str, annotation: str, value):
    """``value`` from a JSON file when it fits the field's annotation (a string such as
    "int", "float | None"), an int widened to float for a float field; else an InputError
    naming ``path`` and ``key``."""
    kinds = {kind.strip() for kind in str(annotation).split("|")}
    nullable = "None" in kinds
    (kind,) = kinds - {"None"}
    wanted = {"int": "an integer", "float": "a finite number", "str": "a string", "bool": "true or false"}[kind]
    if value is None and nullable:
        return None
    if kind == "bool" and isinstance(value, bool):
        return value
    if kind == "int" and isinstance(value, int) and not isinstance(value, bool):
        return value
    if kind == "str" and isinstance(value, str):
        return value
    if (kind == "float" and isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value)):
        return float(value)
    shown = json.dumps(value, allow_nan=True)
    raise InputError(f"{path}: {key} must be {wanted}{' or null' if nullable else ''}, got {shown}")


def check_finite(options, source: str) -> None:
    """A NaN passes every range comparison and an inf most of them: InputError for the first
    float field of the dataclass instance ``options`` that is not finite."""
    for f in dataclasses.fields(options):
        value = getattr(options, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{source}: {f.name} must be a finite number, got {value}")
