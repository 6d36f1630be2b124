"""RUN/metrics.jsonl: one JSON record per logged step, appended; read back through the read guard."""

from __future__ import annotations

import json
from pathlib import Path

from ..io.atomic import append_line, atomic_write_text
from ..io.paths import contained_path, read_small_text
from ..io.values import rule


def append_metrics(run_dir: Path, record: dict) -> None:
    """One JSON line per call (appended and flushed; a torn last line is dropped on resume)."""
    append_line(Path(run_dir) / "metrics.jsonl", json.dumps(record))


def truncate_metrics(run_dir: Path, last_iteration: int) -> None:
    """Keep only records up to ``last_iteration`` (the resumed checkpoint): the steps after
    it will be run again and logged again."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.exists():
        return
    kept = []
    # Through the read guard: a run may come from someone else (no symlink out, a log's size).
    text = read_small_text(contained_path(run_dir, "metrics.jsonl", str(run_dir)), "metrics log")
    for number, line in enumerate(text.splitlines(), 1):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # the line a kill cut in half
        if not isinstance(record, dict):
            continue
        # An iteration is a step number (io/values.py's "count or 0"): a string or NaN is refused
        # in one line, not compared.
        iteration = rule("count or 0").check(record.get("iteration", 0), f"{path}: line {number}: iteration")
        if iteration <= last_iteration:
            kept.append(line)
    atomic_write_text(path, "".join(line + "\n" for line in kept))


def logged_iterations(run_dir: Path) -> set[int]:
    """The iterations metrics.jsonl already holds a record for (torn lines skipped)."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.is_file():
        return set()
    found = set()
    for line in read_small_text(contained_path(run_dir, "metrics.jsonl", str(run_dir)), "metrics log").splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(record, dict) and isinstance(record.get("iteration"), int):
            found.add(record["iteration"])
    return found
