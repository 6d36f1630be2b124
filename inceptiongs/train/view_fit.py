"""Training photos the model cannot fit: a user's warning that a capture disagrees with itself,
or that part of it is seen by too few photos to be reproduced yet.

A static, evenly covered scene fits its training photos within a few dB of each other. A photo
whose content moved (a table carried across the room, a parked car gone), whose pose is wrong or
whose exposure jumped keeps a much larger error than the rest however long training runs, and
it drags the model towards a compromise the other photos then show. On bonsai the first 108 of
252 photos render at 15-21 dB where the others render at 22-29 dB: in them the table and the
bonsai stand where no other photo has them.

The per-view error comes free from training: each step already renders one training view, so
the trainer keeps that render's MSE per view (:attr:`TrainState.view_mse
<inceptiongs.train.step.TrainState>`). At the end of a run the views more than
``POOR_FIT_MARGIN_DB`` below the median training-view PSNR are named in the log, and every
view's figure goes to ``view_fit.json`` in the run folder. The report cannot tell why a photo
fits poorly: the README demo's short stage I (about 410 steps) names 5 of its 36 training
photos, the ones beside its thinly observed region (nothing in that procedural scene moves), at
17-21 dB against a median of 26.
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path

from ..errors import InputError
from ..evaluation.metrics import psnr_from_mse
from ..io.paths import contained_path, read_small_text

# The run folder's per-view figures (written at the end of a finished run).
VIEW_FIT_FILE = "view_fit.json"
# A view this far below the median training-view PSNR is reported. Views of a consistent scene
# spread by a few dB (bonsai's later 144 photos: 21-29 dB around 25.6); a moved object or a wrong
# pose costs far more where it shows (bonsai's first photos: 15-18 dB).
POOR_FIT_MARGIN_DB = 5.0
# PSNR reported for an MSE of exactly 0 (a photo matched to the last bit): finite for JSON.
PSNR_CAP_DB = 100.0
# Views named in the log line; the JSON file lists them all.
LOGGED_NAMES = 5


def view_psnr(view_mse: dict[int, float]) -> dict[int, float]:
    """view -> PSNR (dB, peak 1) of its last training render; an MSE of 0 gives PSNR_CAP_DB."""
    return {view: min(psnr_from_mse(mse), PSNR_CAP_DB) for view, mse in view_mse.items()}


def poorly_fit(psnr: dict[int, float], margin_db: float = POOR_FIT_MARGIN_DB) -> list[int]:
    """Views whose PSNR is more than ``margin_db`` below the median of all views, worst first.
    Fewer than three views have no meaningful median: none are reported then."""
    if len(psnr) < 3:
        return []
    median = statistics.median(psnr.values())
    return sorted((view for view, value in psnr.items() if value < median - margin_db), key=psnr.get)


def view_fit_report(view_mse: dict[int, float], names: dict[int, str],
                    margin_db: float = POOR_FIT_MARGIN_DB) -> dict:
    """The content of ``view_fit.json``: the median training-view PSNR, the margin, and per view
    (in view order) its index, image name, PSNR of its last training render and whether it is
    reported as poorly fit."""
    psnr = view_psnr(view_mse)
    flagged = set(poorly_fit(psnr, margin_db))
    return {
        "median_psnr": statistics.median(psnr.values()) if psnr else None,
        "margin_db": margin_db,
        "views": [{"index": view, "name": names[view], "psnr": round(psnr[view], 3), "poorly_fit": view in flagged}
                  for view in sorted(psnr)],
    }


def summary_line(report: dict, run_file: str) -> str | None:
    """One log line naming the poorly fit views (None when there are none)."""
    bad = sorted((v for v in report["views"] if v["poorly_fit"]), key=lambda v: v["psnr"])
    if not bad:
        return None
    names = ", ".join(f"{v['name']} {v['psnr']:.1f} dB" for v in bad[:LOGGED_NAMES])
    more = f" and {len(bad) - LOGGED_NAMES} more" if len(bad) > LOGGED_NAMES else ""
    return (f"poorly fit photos: {len(bad)} of {len(report['views'])} training views render more than "
            f"{report['margin_db']:g} dB below the median {report['median_psnr']:.1f} dB ({names}{more}): "
            f"the model does not reproduce them: they disagree with the other photos (moved objects, wrong "
            f"poses, exposure changes) or show what no other photo sees. All views: {run_file}")


def read_poorly_fit(run_dir: str | Path) -> dict[str, float]:
    """RUN/view_fit.json -> {image name: PSNR} of the views it reports as poorly fit, worst first;
    {} when the run has no report (not finished, or written before reports existed). InputError
    naming the file when it is not a report."""
    path = Path(run_dir) / VIEW_FIT_FILE
    if not path.is_file():
        return {}
    try:
        views = json.loads(read_small_text(contained_path(run_dir, VIEW_FIT_FILE, str(run_dir)),
                                           "view-fit report"))["views"]
        bad = {str(v["name"]): float(v["psnr"]) for v in views if v["poorly_fit"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a view-fit report ({type(exc).__name__}: {exc})") from exc
    return dict(sorted(bad.items(), key=lambda item: item[1]))
