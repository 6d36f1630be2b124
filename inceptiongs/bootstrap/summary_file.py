"""RUN2/bootstrap/summary.json, what a bootstrap says about itself: written by
:mod:`.loop`, read by the stopped-run check (:mod:`.runner`), the repair outlook that
``eval`` shows (:mod:`.outlook`) and the viewer's verdict. Light: no torch, so readers stay cheap."""

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
