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
