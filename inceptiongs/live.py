"""The one hand-off between a training job and the viewer: a lock and a version number.

The job publishes immutable snapshots (numpy copies made on the job's thread); the viewer
asks for the newest one it has not seen. Nothing else is shared, so there is no tearing and
the viewer re-uploads Gaussians only when the version moved.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Protocol


@dataclass
class JobControl:
    """The viewer's side of a running job: set ``pause`` to pause (clear to continue); set
    ``stop`` to have the job checkpoint and return. The job sets ``listening`` when its loop
    first checks for a stop (train.loop.StepLoop.wait_or_stop): from then on a stop is honoured
    within a step; before it, the job is in its set-up and has nothing of its own to save."""

    pause: threading.Event = field(default_factory=threading.Event)
    stop: threading.Event = field(default_factory=threading.Event)
    listening: threading.Event = field(default_factory=threading.Event)


def wait_while_paused(control: JobControl | None, poll_s: float = 0.05) -> tuple[bool, float]:
    """Block while ``control`` is paused. -> (stop requested, seconds spent paused). Paused time
    is nobody's time: a job moves its clocks (time budget, elapsed) forward by it."""
    if control is None:
        return False, 0.0
    paused_s = 0.0
    while control.pause.is_set() and not control.stop.is_set():
        began = time.perf_counter()
        time.sleep(poll_s)
        paused_s += time.perf_counter() - began
    return control.stop.is_set(), paused_s


@dataclass(frozen=True)
class Snapshot:
    """What a job shows the world at one moment. ``gaussians`` holds the newest model as numpy
    arrays keyed as :meth:`inceptiongs.gaussians.Gaussians.numpy` returns them (None before the
    first); it is new to a reader whose last seen ``gaussians_version`` is smaller."""

    version: int
    iteration: int
    gaussians: dict | None
    metrics: dict = field(default_factory=dict)
    message: str = ""
    # The version at which ``gaussians`` was published (0: none yet). A log line published
    # after a model keeps that model here, so a reader that only sees the newest snapshot (the
    # box has one slot) never loses Gaussians to a message that overwrote them.
    gaussians_version: int = 0


class SnapshotBox:
    """Single-slot, versioned mailbox: publish() from the job thread, latest() from the UI."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._snapshot: Snapshot | None = None
        self._version = 0

    @property
    def version(self) -> int:
        with self._lock:
            return self._version

    def publish(self, iteration: int, gaussians: dict | None, metrics: dict | None = None,
                message: str = "") -> int:
        with self._lock:
            self._version += 1
            if gaussians is not None:
                gaussians_version = self._version
            elif self._snapshot is not None:  # a log line: the newest model stays in the slot
                gaussians, gaussians_version = self._snapshot.gaussians, self._snapshot.gaussians_version
            else:
                gaussians_version = 0
            self._snapshot = Snapshot(self._version, iteration, gaussians, dict(metrics or {}), message,
                                      gaussians_version)
            return self._version

    def latest(self, seen_version: int = 0) -> Snapshot | None:
        """The newest snapshot if its version is greater than ``seen_version``, else None."""
        with self._lock:
            if self._snapshot is None or self._snapshot.version <= seen_version:
                return None
            return self._snapshot


@dataclass
class JobPublisher:
    """A job's side of the hand-off: Gaussians snapshots and log lines, both through ``box``
    (a log line carries the iteration of the newest snapshot)."""

    box: SnapshotBox
    iteration: int = 0

    def snapshot(self, iteration: int, gaussians, metrics: dict) -> None:
        """gaussians: an :class:`inceptiongs.gaussians.Gaussians`; numpy() copies it on the
        job's thread, so the viewer never sees tensors that are being updated."""
        self.iteration = iteration
        self.box.publish(iteration, gaussians.numpy(), metrics)

    def log(self, message: str) -> None:
        self.box.publish(self.iteration, None, {}, message)

    def finish(self, what: str, iteration: int, finished: bool, metrics: dict, detail: str = "") -> None:
        """The job's last word: "<what> finished|stopped (checkpoint written) at iteration N[: detail]"
        with its final scores."""
        state = "finished" if finished else "stopped (checkpoint written)"
        self.box.publish(iteration, None, dict(metrics),
                         f"{what} {state} at iteration {iteration}" + (f": {detail}" if detail else ""))


class Job(Protocol):
    """What the viewer runs on a thread (stage-I training, stage-II bootstrap): publish through
    ``box`` and honour ``control`` (pause, stop) until done."""

    def run(self, box: SnapshotBox, control: JobControl) -> None: ...
