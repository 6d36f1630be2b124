"""One writer per run folder: an advisory lock held for the whole job.

Two jobs writing one run (two `train --resume`, a viewer job and a command line) would
interleave their metrics and checkpoints. The lock is ``flock`` on the folder itself, so it
goes with the process: a crash or kill -9 frees it and leaves nothing stale to clean up. The
holder's pid is written to ``RUN/.lock`` for the message the second writer gets.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
from pathlib import Path
from typing import Iterator

from ..errors import InputError
from ..io.atomic import ensure_dir, output_error

LOCK_INFO_FILE = ".lock"
# What a non-blocking flock raises when another process holds the lock.
HELD_ERRNOS = (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)


def _holder(run_dir: Path) -> str:
    try:
        text = (run_dir / LOCK_INFO_FILE).read_text(errors="replace").strip()
    except OSError:
        return "another process"
    return f"pid {text}" if text.isdigit() else "another process"


def writer_of(run_dir: str | Path) -> str | None:
    """Who writes ``run_dir`` now ("pid N", "another process"), or None when no job holds its lock
    (or it is no folder). Takes and drops a shared lock: it never waits and never blocks a writer
    that comes later."""
    run_dir = Path(run_dir)
    try:
        fd = os.open(run_dir, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError as exc:
        return _holder(run_dir) if exc.errno in HELD_ERRNOS else None
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


@contextlib.contextmanager
def run_folder_lock(run_dir: str | Path) -> Iterator[Path]:
    """Hold ``run_dir``'s lock (the folder is created when missing; a folder this call made is
    removed again on the way out when the job left it empty). InputError naming the holder
    when another process writes the folder."""
    run_dir = Path(run_dir)
    created = not run_dir.exists()
    ensure_dir(run_dir)   # OutputError (one line) for a folder that cannot be made
    try:
        fd = os.open(run_dir, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as exc:
        raise output_error(run_dir, exc) from None
    info = run_dir / LOCK_INFO_FILE
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in HELD_ERRNOS:
                raise InputError(f"{run_dir}: in use by {_holder(run_dir)} (a job writing this run); wait for it "
                                 f"to end or choose another output folder") from None
            raise
        with contextlib.suppress(OSError):
            if not info.is_symlink():
                info.write_text(f"{os.getpid()}\n")
        try:
            yield run_dir
        finally:
            with contextlib.suppress(OSError):
                if not info.is_symlink():
                    info.unlink()
    finally:
        os.close(fd)
        if created:
            with contextlib.suppress(OSError):
                run_dir.rmdir()  # only succeeds when the job wrote nothing
