"""Ctrl+C and SIGTERM during a long job: stop means save.

The first signal asks the job to stop after its current step; the job then saves what it has
(checkpoint and model.ply, as its final save does) and returns. A second signal stops at once
(KeyboardInterrupt), for a user who would rather lose the step than wait for it. A signal
before the job's loop has begun (its set-up: reading and decoding photos, triangulating, the
near bounds; minutes on a large capture) stops at once too: there is nothing of the job's to
save yet, and every file the set-up writes is written whole or not at all (io/atomic.py). Python
handlers replace whatever a native library installed (pycolmap's prints a stack dump on
SIGTERM), so a stop prints one line.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from dataclasses import dataclass
from typing import Callable, Iterator

from .live import JobControl

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StoppedDuringSetup(KeyboardInterrupt):
    """A stop signal arrived before the job's loop began; ``exit_status`` is the shell's for it."""

    def __init__(self, exit_status: int) -> None:
        super().__init__(exit_status)
        self.exit_status = exit_status


@dataclass
class StopRequest:
    """Which signal asked the job to stop (None: none did)."""

    signum: int | None = None

    @property
    def exit_status(self) -> int:
        """The shell's convention for a process ended by a signal: 128 + its number (130, 143)."""
        return 128 + self.signum if self.signum is not None else 0


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


@contextlib.contextmanager
def stop_on_signals(control: JobControl, say: Callable[[str], None] = _say) -> Iterator[StopRequest]:
    """While inside: SIGINT/SIGTERM set ``control.stop`` (the job saves and returns); the
    same signal again raises KeyboardInterrupt, and so does the first one before the job
    listens (``control.listening``: its set-up; StoppedDuringSetup, with the exit status). Handlers can only be set from the main
    thread; elsewhere (a viewer job) this does nothing and the caller's own stop applies."""
    request = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request
        return

    def handle(signum, _frame) -> None:
        if request.signum is not None:
            raise KeyboardInterrupt
        request.signum = signum
        control.stop.set()
        if not control.listening.is_set():
            say(f"{signal.Signals(signum).name}: stopping during the set-up (nothing to save yet)")
            raise StoppedDuringSetup(request.exit_status)
        say(f"{signal.Signals(signum).name}: stopping after this step and saving the model and a checkpoint "
            f"(again to quit without saving)")

    # pycolmap installs native failure handlers (a stack dump on SIGTERM) when first imported,
    # which would replace ours if the job imported it later: import it before installing.
    with contextlib.suppress(ImportError):
        import pycolmap  # noqa: F401
    previous = {signum: signal.getsignal(signum) for signum in STOP_SIGNALS}
    for signum in STOP_SIGNALS:
        signal.signal(signum, handle)
    try:
        yield request
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
