"""What the value fuzz tests draw from, read off the code itself so a new flag or config key is
covered without a new test: every numeric flag of every command (from the parsers), every
setting of the run and bootstrap configurations and every camera JSON key (from the
dataclasses), and the bad values the README promises one line for."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import math

from inceptiongs.cli import build_parser, main
from inceptiongs.io.values import numeric_flags

# Values a user or a shared file can give in place of a number: negative, zero, NaN, infinity,
# huge, text, null, a number written as a string, a fraction where an integer belongs.
FLAG_VALUES = ("-1", "0", "nan", "inf", "-inf", "1e12", "1000000000000", "text", "null", "1e6", "0.5")
JSON_VALUES = (-1, 0, math.nan, math.inf, 1e12, "text", None, "64", 64.5, 10**30)


class Reached(Exception):
    """Raised by a stub of a command's long work: everything before it, the checking of every
    value, has passed. A case that reaches it counts as a success."""


def subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def flag_cases() -> list[tuple[str, str]]:
    """(command, flag) for every numeric flag of every command."""
    return [(command, flag) for command, parser in subparsers().items() for flag in numeric_flags(parser)]


def flag_arity(parser: argparse.ArgumentParser, flag: str) -> int:
    action = next(a for a in parser._actions if flag in a.option_strings)
    return action.nargs if isinstance(action.nargs, int) else 1


def flag_arguments(parser: argparse.ArgumentParser, flag: str, value: str) -> list[str]:
    """The command-line words giving ``value`` to ``flag``: '--flag=value' for a one-value flag
    (how a value starting with '-' is given), else the value repeated for each of its values."""
    arity = flag_arity(parser, flag)
    return [f"{flag}={value}"] if arity == 1 else [flag, *[value] * arity]


def run_cli(argv: list[str]) -> tuple[int, str]:
    """cli.main in-process -> (status, stderr); a stub's Reached counts as status 0. Any other
    exception escaping main fails the caller's test (a user would have seen a traceback)."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            status = main(argv)
        except Reached:
            status = 0
    return status, err.getvalue()


def assert_one_line_or_success(status: int, stderr: str, names: str, case) -> None:
    """Success, or exit 2 with exactly one 'error:' line naming ``names`` (a flag, a file)."""
    assert "Traceback" not in stderr, (case, stderr)
    if status == 0:
        return
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert status == 2 and len(errors) == 1, (case, status, stderr)
    assert names in errors[0], (case, errors[0])


def train_setting_cases() -> list[str]:
    from inceptiongs.io.config_json import setting_paths
    from inceptiongs.runs.config import TrainConfig

    return setting_paths(TrainConfig)


def train_setting_edges() -> list[tuple[str, object]]:
    """(dotted path, value) of every numeric train setting at the edges it allows: its range's
    closed ends, 0, 1 and 1e12 where the range holds them (each a value the reader accepts, so
    the case reaches the training loop)."""
    import typing

    from inceptiongs.io.config_json import is_section, section_hints
    from inceptiongs.runs.config import TrainConfig

    def walk(cls, prefix=""):
        hints = section_hints(cls)
        for f in dataclasses.fields(cls):
            kind = hints[f.name]
            if is_section(kind):
                yield from walk(kind, f"{prefix}{f.name}.")
                continue
            numeric = {int, float} & ({kind} | set(typing.get_args(kind)))
            limits = f.metadata.get("range")
            if not numeric or limits is None:
                continue
            integer = numeric == {int}
            for value in (limits.low, limits.high, 0, 1, 1e12):
                if value is not None and value in limits and math.isfinite(value):
                    yield prefix + f.name, int(value) if integer else float(value)

    return sorted(set(walk(TrainConfig)))


def bootstrap_setting_cases() -> list[str]:
    from inceptiongs.bootstrap.config import BootstrapConfig

    return [f.name for f in dataclasses.fields(BootstrapConfig) if f.name != "variants"]


def camera_key_cases() -> list[str]:
    from inceptiongs.camera import Camera

    return [f.name for f in dataclasses.fields(Camera) if f.name != "name"]


def nested(path: str, value) -> dict:
    """{"a": {"b": value}} for the dotted path "a.b"."""
    head, _, rest = path.partition(".")
    return {head: nested(rest, value) if rest else value}
