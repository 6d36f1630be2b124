"""User-facing errors.

An :class:`InputError` is a problem with what the user gave us (a path, a file, a value).
Its message is one line that names the file and the problem; the CLI prints it and exits
with status 2, without a traceback unless ``--debug`` is given.
"""


class InputError(Exception):
    """Bad input: message is '<path>: <problem>' on one line."""


class DeviceMemoryError(InputError):
    """The GPU ran out of memory during a run: one line saying where, what was kept and what to
    change (a larger downscale, a Gaussian budget); exit status 2 like any error the user can act on."""


def one_line(exc: BaseException, limit: int = 200) -> str:
    """'<type>: <first line of the message>' of a library's exception, terminal colour codes
    removed and cut to ``limit`` characters: what an InputError may quote of it."""
    import re  # noqa: PLC0415 (only an error being reported needs it)

    text = re.sub(r"\x1b\[[0-9;]*[A-Za-z]", "", str(exc))
    first = next((line.strip() for line in text.splitlines() if line.strip()), "")
    return f"{type(exc).__name__}: {first[:limit]}" if first else type(exc).__name__
