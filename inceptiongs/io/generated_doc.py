"""The command line of a script that generates a docs page from the code (scripts/gen_*.py):
write the page, or with --check only say whether it is stale."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .atomic import atomic_write_text


def write_or_check(doc: Path, text: str, script: str, description: str, argv: list[str] | None = None) -> int:
    """Write ``text`` to ``doc`` (atomically) -> 0; with ``--check`` in ``argv`` only compare:
    1 and one line on stderr naming ``script`` when ``doc`` differs (or is missing), else 0."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 when the file is stale")
    args = parser.parse_args(argv)
    if args.check:
        if not doc.is_file() or doc.read_text(encoding="utf-8") != text:
            print(f"{doc} is stale: run python3 {script}", file=sys.stderr)
            return 1
        return 0
    atomic_write_text(doc, text)
    print(f"wrote {doc}")
    return 0
