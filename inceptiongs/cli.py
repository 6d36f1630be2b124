"""The ``inceptiongs`` command line: one subcommand per module in ``inceptiongs.commands``.

Each command module defines ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int | None``. Bad input raises :class:`InputError`, which is printed as one
line and exits with status 2 (the traceback only with ``--debug``).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .errors import InputError
from .io.atomic import writing_under
from .io.cache import set_cache_dir
from .io.photo_memory import parse_memory, set_photo_memory
from .io.values import bind_flags

# The arguments that name a run, output or input folder of a command.
WRITE_ROOT_ARGUMENTS = ("run", "runs", "out", "path", "model", "scene")


def named_folders(args: argparse.Namespace) -> list[str]:
    """The paths the command line names in WRITE_ROOT_ARGUMENTS (a list argument, one by one)."""
    found = []
    for name in WRITE_ROOT_ARGUMENTS:
        value = getattr(args, name, None)
        found.extend(value if isinstance(value, list) else [value])
    return [str(value) for value in found if value]

# name -> module in inceptiongs.commands; order is the order in --help.
COMMANDS = {
    "info": "info",
    "coverage": "coverage",
    "demo-scene": "demo_scene",
    "render": "render_video",  # images (render.py) and videos
    "convert": "convert",
    "train": "train",
    "prior": "prior",
    "generate": "generate",
    "bootstrap": "bootstrap",
    "eval": "evaluate",
    "report": "report",
    "demo": "demo",
}


def available_commands() -> dict[str, object]:
    modules = {}
    for name, module_name in COMMANDS.items():
        try:
            modules[name] = importlib.import_module(f"inceptiongs.commands.{module_name}")
        except ModuleNotFoundError as exc:
            # Only hide a command whose own module is absent, never a broken import inside it.
            if exc.name != f"inceptiongs.commands.{module_name}":
                raise
    return modules


class OneLineParser(argparse.ArgumentParser):
    """argparse's refusals (a missing argument, a choice it does not know, too few values) as
    the one line every bad input gets (InputError, exit status 2), not a usage block."""

    def error(self, message: str):
        raise InputError(f"{self.prog}: {message} (see {self.prog} --help)")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="inceptiongs", description=__doc__.splitlines()[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks for errors")
    parser.add_argument("--cache-dir", metavar="DIR", default=None,
                        help="cache folder (default $INCEPTIONGS_CACHE_DIR, else $XDG_CACHE_HOME/inceptiongs)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    sub.required = True
    for name, module in available_commands().items():
        command_parser = sub.add_parser(name, help=module.HELP, description=module.HELP)
        command_parser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                                    help="show tracebacks for errors")
        command_parser.add_argument("--cache-dir", metavar="DIR", default=argparse.SUPPRESS,
                                    help="cache folder (default $INCEPTIONGS_CACHE_DIR, else "
                                         "$XDG_CACHE_HOME/inceptiongs)")
        module.add_arguments(command_parser)
        bind_flags(command_parser)      # every numeric flag checked by its rule (io/values.py)
        command_parser.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    try:
        args = build_parser().parse_args(argv)
        set_cache_dir(getattr(args, "cache_dir", None))
        memory = getattr(args, "photo_memory", None)
        set_photo_memory(None if memory is None else parse_memory(memory))
        # Writes below the folders a command is given never follow a symlink planted there.
        with writing_under(*named_folders(args)):
            return int(args._run(args) or 0)
    except InputError as exc:
        if debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        status = getattr(exc, "exit_status", None)     # stop_signals.StoppedDuringSetup: already said
        if status is None:
            print("interrupted", file=sys.stderr)
        return status or 130
    finally:
        set_cache_dir(None)
        set_photo_memory(None)


if __name__ == "__main__":
    sys.exit(main())
