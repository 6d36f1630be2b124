"""The Training panel's list of the open scene's runs: a line per run (when it was last written,
its last held-out scores, its folder) and the runs folder the user picks for the next ones."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

from .progress import run_scores
from .runs import runs_folder
from .sources import oldest_first, scene_runs


@dataclass
class RunLabels:
    """The list's lines, kept per (run, its metrics log's mtime): a run's scores are re-read only
    when its log changes, not on every frame the list is drawn."""

    lines: dict = dataclasses.field(default_factory=dict)

    def label(self, run: Path) -> str:
        """A run in the list: when it was last written, its last held-out scores and its folder
        in full."""
        metrics = Path(run) / "metrics.jsonl"
        try:
            stamp = metrics.stat().st_mtime_ns if metrics.is_file() else Path(run).stat().st_mtime_ns
        except OSError:
            return f"{run} (gone)"
        key = (Path(run), stamp)
        if key not in self.lines:
            when = time.strftime("%Y-%m-%d %H:%M", time.localtime(stamp / 1e9))
            # Time and scores first: the list's closed preview shows the start of a line.
            self.lines[key] = f"{when}  {run_scores(run)}  {run}"
        return self.lines[key]


def choose_runs_folder(source, folder: Path) -> str:
    """Where the next runs of ``source`` (sources.ViewerSource) go (the Training panel's field,
    as --runs): its runs of the scene join the list. -> the status line saying so."""
    source.runs_dir = runs_folder(folder)
    if source.scene is not None and source.kind == "scene":
        source.runs = oldest_first([*source.runs, *scene_runs(source.scene, source.runs_dir)])
    return f"new runs go to {source.runs_dir}"
