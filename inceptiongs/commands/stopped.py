"""What `train` and `bootstrap` say when a stop (Ctrl+C, SIGTERM) meets a save that fails (a full
disk): the failure as its one line, then the "stopped at" line pointing at the checkpoint
`--resume` continues from, and the stop's exit status (130, 143), not 2: the user stopped the
job, and what the last good checkpoint holds is kept."""

from __future__ import annotations

import sys
from pathlib import Path

from ..io.atomic import OutputError


def stopped_with_failed_save(exc: OutputError, out: Path, exit_status: int, resume_command: str) -> int:
    """Print '<exc>' and '<out>: stopped at iteration N ...' on stderr; return ``exit_status``."""
    from ..runs.checkpoint import list_checkpoints

    print(f"error: {exc}", file=sys.stderr)
    kept = list_checkpoints(out)
    where = (f"checkpoint at iteration {kept[-1][0]}" if kept else "no checkpoint yet (a plain rerun starts over)")
    print(f"{out}: stopped at a save that could not be written (above); --resume continues from its {where} "
          f"(continue with: {resume_command})", file=sys.stderr)
    return exit_status
