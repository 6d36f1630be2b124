"""RUN2/bootstrap/summary.json, what a bootstrap says about itself: written by
:mod:`.loop`, read by the stopped-run check (:mod:`.runner`), the repair outlook that
``eval`` shows (:mod:`.outlook`) and the verdicts (``inceptiongs.evaluation.verdict``: the viewer's,
``eval``'s, ``report``'s), which compare a bootstrap only with its same-time baseline
(:func:`same_time_mismatch` decides). Light: no torch, so readers stay cheap."""

from __future__ import annotations

import json
from pathlib import Path

BOOTSTRAP_DIR = "bootstrap"
SUMMARY_FILE = f"{BOOTSTRAP_DIR}/summary.json"


def read_summary(out_dir: str | Path) -> dict | None:
    """OUT/bootstrap/summary.json as a dict; None when it is absent, unreadable (a run being
    written), not a JSON object, or leads out of ``out_dir`` (a planted symlink: never followed)."""
    from ..errors import InputError
    from ..io.paths import contained_path, read_small_text

    try:
        data = json.loads(read_small_text(contained_path(out_dir, SUMMARY_FILE, str(out_dir)), "bootstrap summary"))
    except (OSError, InputError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def virtual_step_count(step_counts: dict) -> int:
    """Steps that carried a virtual loss: every virtual branch's count ("additive" photo steps
    are counted by their branch too; "real", "idle" and "photo_first" are photo steps)."""
    return sum(count for kind, count in step_counts.items() if kind not in ("real", "idle", "photo_first", "additive"))


# A baseline is the same-time baseline of a bootstrap when it continued the same stage-I run from
# the same iteration for the same wall time (pauses not counted: both clocks are StepLoop.wall_s)
# within SAME_TIME_TOLERANCE of the bootstrap's time, and never closer than SAME_TIME_MIN_S: a
# baseline given the bootstrap's measured time stops at its first step past it, so the two clocks
# differ by a step and the last evaluation (the demo's: 68.1 s and 68.8 s, 1 %).
SAME_TIME_TOLERANCE = 0.05
SAME_TIME_MIN_S = 2.0


def run_seconds(summary: dict) -> float | None:
    """The wall time a bootstrap or baseline ran (its summary's ``wall_s``, pauses not counted);
    None when it is not recorded or not a finite number >= 0."""
    value = summary.get("wall_s")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0.0 or value == float("inf"):
        return None
    return float(value)


def same_time_tolerance_s(seconds: float) -> float:
    """How far a baseline's wall time may be from a bootstrap's ``seconds`` and still be its
    same-time baseline."""
    return max(SAME_TIME_TOLERANCE * seconds, SAME_TIME_MIN_S)


def same_time_mismatch(bootstrap: dict, baseline: dict) -> str | None:
    """None when the run whose summary is ``baseline`` is the same-time baseline of the bootstrap
    whose summary is ``bootstrap`` (both RUN2/bootstrap/summary.json as dicts): a baseline
    ("baseline": true) of the same stage-I run ("run", compared as resolved paths), started at the
    same iteration ("start_iteration"), that ran the bootstrap's wall time ("wall_s") within
    same_time_tolerance_s. Else one phrase saying why not ("it ran 66 s, the bootstrap 5 s")."""
    if baseline.get("baseline") is not True:
        return "it is not a baseline (it made virtual views)"
    runs = [summary.get("run") for summary in (bootstrap, baseline)]
    if not all(isinstance(run, str) for run in runs) or Path(runs[0]).resolve() != Path(runs[1]).resolve():
        return f"it continued another stage-I run ({runs[1]})"
    starts = [summary.get("start_iteration") for summary in (bootstrap, baseline)]
    if starts[0] != starts[1]:
        return f"it started at iteration {starts[1]}, the bootstrap at {starts[0]}"
    mine, theirs = run_seconds(bootstrap), run_seconds(baseline)
    if mine is None or theirs is None:
        return "its time or the bootstrap's is not recorded"
    if abs(theirs - mine) > same_time_tolerance_s(mine):
        digits = 0 if f"{theirs:.0f}" != f"{mine:.0f}" else 1
        return f"it ran {theirs:.{digits}f} s, the bootstrap {mine:.{digits}f} s"
    return None
