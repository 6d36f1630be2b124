"""--device auto|cpu|cuda: one flag, one meaning, in every command that renders or runs torch
models (train, render --backend torch, eval, prior, generate, coverage, demo; bootstrap, with its
few flags, runs where its stage-I run ran). Its value goes through the one device rule,
:func:`inceptiongs.rasterizer.interface.resolve_device`, which gives the rasterizer and the torch
device together: ``--device cpu`` puts nothing on a GPU."""

from __future__ import annotations

import json
from pathlib import Path

from ..constants import DEVICES

DEVICE_HELP = ("where the command runs, rasterizer and torch alike: cpu (numba), cuda (gsplat on the GPU: "
               "pip install 'inceptiongs[cuda]' and a CUDA compiler) or auto (cuda when all of that is there, "
               "else cpu)")
# How a run whose recorded device cannot run here is run anyway.
OVERRIDE = "--device cpu or --device auto runs it here"


def add_device_argument(parser, reads_run: bool = False, default_help: str | None = None) -> None:
    """Add --device. ``reads_run``: the default (None) is the run's recorded device
    (:func:`command_device`), else "auto". ``default_help``: how the help names the default."""
    default = "the run's device (RUN/config.json; auto when it records none)" if reads_run else "auto"
    parser.add_argument("--device", choices=DEVICES, default=None if reads_run else "auto",
                        help=f"{DEVICE_HELP}; default: {default_help or default}")


def recorded_device(run_dir) -> tuple[str, str]:
    """(the device RUN/config.json records, the words naming where it came from). A path that is
    no run folder (a PLY, a scene) or a config without the key records none: "auto". Read
    leniently, like ``render``'s scene lookup: only the key is needed, and resolve_device checks it."""
    from ..errors import InputError
    from ..io.paths import read_small_text

    path = Path(run_dir) / "config.json"
    if not path.is_file():
        return "auto", "--device"
    try:
        data = json.loads(read_small_text(path, "run config"))
    except (OSError, json.JSONDecodeError):
        raise InputError(f"{path}: not a readable run config") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: not a readable run config (not a JSON object)")
    return data.get("device", "auto"), f"{path}: device"


def command_device(value: str | None, run_dir=None):
    """The :class:`~inceptiongs.rasterizer.interface.Device` for a command's --device ``value``;
    None: the device ``run_dir`` records (``recorded_device``), "auto" without a run. InputError
    (exit 2, one line) when it cannot run here, naming the flag or the run's config.json."""
    from ..rasterizer.interface import resolve_device

    if value is not None or run_dir is None:
        return resolve_device(value or "auto")
    asked, source = recorded_device(run_dir)
    return resolve_device(asked, source, instead=OVERRIDE if source != "--device" else None)
