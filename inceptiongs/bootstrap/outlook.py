"""Before a bootstrap runs: is there anything to repair, and is stage I done with the photos?

Two readings of the stage-I run's own held-out curve (RUN/metrics.jsonl), both cheap and both
about the scene rather than about the method:

- **thinness**: how far the scarce held-out views render below the covered ones. A region the
  photos see well renders as well as the rest (statuette: -0.1 dB); a thin one renders far
  below (the courtyard 7.6 dB, bonsai 5.9 dB, a phone capture 5.9 dB).
- **convergence**: how fast the scarce views still gain from photo steps (dB per minute of
  training, over the last part of the curve). While photo steps still lift the scarce views,
  the same minutes spent on the photos are worth more than on virtual views (a phone capture
  after a 2-minute stage I still rising fast: the bootstrap ended 0.41 dB below the same-time
  baseline).

The outlook says one line ("nothing to repair here: ...", "train longer first: ...", or why a
repair may help); the bootstrap still runs when asked to. Without a held-out split (protocol
"none") or with too short a curve it says what it could not tell.

The loop follows it (``BootstrapConfig.follow_outlook``, on by default). With nothing to repair
it makes no virtual views and every step is a photo step (the same-time baseline's run). While
stage I's curve says photo steps gain more than the break-even rate, it takes photo steps first
(``photo_first_minutes``: the rate's decay read from the curve's last two thirds, extrapolated
exponentially). The break-even is ``STILL_RISING_DB_PER_MIN``: on the
README courtyard the default loop gains ~0.5 dB a minute over the baseline (+0.75 dB in 92 s),
so a photo step that lifts the scarce views faster than that is the better use of the time.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

# The scarce views render within this of the covered ones: the region is not thin (statuette's
# gap is -0.1 dB and every bootstrap there ends level or below its baseline).
NOTHING_TO_REPAIR_DB = 1.0
# Photo steps still lift the scarce views by at least this much a minute of stage-I training:
# spend the time on the photos first.
STILL_RISING_DB_PER_MIN = 0.5
# The slope is read over this last fraction of the training time (at least two evaluations).
CURVE_TAIL_FRACTION = 1.0 / 3.0


@dataclass(frozen=True)
class Outlook:
    verdict: str                        # "repair", "nothing to repair", "train longer", "unknown"
    line: str
    gap_db: float | None = None         # covered - scarce held-out PSNR at the end of stage I
    scarce_db_per_min: float | None = None
    covered_db_per_min: float | None = None
    # Minutes of the bootstrap that go to photo steps before its first virtual view ("train longer":
    # until stage I's curve predicts the photos gain less than STILL_RISING_DB_PER_MIN); None: all.
    photo_first_min: float | None = 0.0

    def to_json(self) -> dict:
        return asdict(self)


def last_group_scores(lines: list[dict]) -> tuple[float, float] | None:
    """(scarce, covered) PSNR of the newest line that has both, or None."""
    for record in reversed(lines):
        scarce, covered = record.get("scarce_psnr"), record.get("covered_psnr")
        if isinstance(scarce, (int, float)) and isinstance(covered, (int, float)):
            return float(scarce), float(covered)
    return None


def gain_per_minute(lines: list[dict], key: str, tail_fraction: float = CURVE_TAIL_FRACTION) -> float | None:
    """dB per minute of training time of ``key`` (a PSNR) over the last ``tail_fraction`` of the
    curve: the least-squares slope through its evaluations there (at least two, at distinct
    times), else None."""
    points = curve_points(lines, key)
    if len(points) < 2:
        return None
    end = points[-1][0]
    tail = [p for p in points if p[0] >= (1.0 - tail_fraction) * end]
    if len(tail) < 2:
        tail = points[-2:]
    return _slope_per_minute(tail)      # None: every evaluation at one time, no slope to read


def curve_points(lines: list[dict], key: str) -> list[tuple[float, float]]:
    """[(training seconds, value of ``key``)] of the metrics lines that have both."""
    return [(float(r["train_s"]), float(r[key])) for r in lines
            if isinstance(r.get(key), (int, float)) and isinstance(r.get("train_s"), (int, float))]


def _slope_per_minute(points: list[tuple[float, float]]) -> float | None:
    """Least-squares dB per minute through ``points`` (None: fewer than two distinct times)."""
    if len(points) < 2:
        return None
    mean_t = sum(t for t, _ in points) / len(points)
    mean_v = sum(v for _, v in points) / len(points)
    spread = sum((t - mean_t) ** 2 for t, _ in points)
    if spread <= 0.0:
        return None
    return 60.0 * sum((t - mean_t) * (v - mean_v) for t, v in points) / spread


def gain_decay_minutes(lines: list[dict], key: str = "scarce_psnr") -> float | None:
    """Minutes of training over which the photo steps' gain rate on ``key`` falls by a factor e:
    from the slopes over the curve's middle and last thirds (rate_mid > rate_last > 0), as if the
    rate decayed exponentially. None when the curve does not show a falling, positive rate (too
    short, flat, or speeding up): the caller then cannot predict when photo steps stop paying."""
    points = curve_points(lines, key)
    if len(points) < 4:
        return None
    end = points[-1][0]
    middle = [p for p in points if end / 3.0 <= p[0] < 2.0 * end / 3.0]
    last = [p for p in points if p[0] >= 2.0 * end / 3.0]
    rate_mid, rate_last = _slope_per_minute(middle), _slope_per_minute(last)
    if rate_mid is None or rate_last is None or not rate_mid > rate_last > 0.0:
        return None
    centre = lambda group: sum(t for t, _ in group) / len(group) / 60.0   # noqa: E731
    # ln(rate_mid / rate_last) > 0 here: both positive and rate_mid strictly larger.
    return (centre(last) - centre(middle)) / math.log(rate_mid / rate_last)


def photo_first_minutes(rate: float | None, decay_minutes: float | None,
                        break_even: float = STILL_RISING_DB_PER_MIN) -> float:
    """Minutes of photo steps before a virtual step is worth more: 0 when the photo steps' rate
    (dB a minute) is already below ``break_even`` (or unknown), the time the exponential decay
    takes to bring it there, or math.inf when it is not seen to decay."""
    if rate is None or not rate >= break_even:
        return 0.0
    if decay_minutes is None or not decay_minutes > 0.0:
        return math.inf
    return decay_minutes * math.log(rate / break_even)     # rate >= break_even > 0: log >= 0


def outlook_from_curve(lines: list[dict]) -> Outlook:
    """The outlook of a stage-I run from its metrics lines (see the module doc)."""
    scores = last_group_scores(lines)
    if scores is None:
        return Outlook("unknown", "repair outlook: unknown (the run holds out no scarce and covered views: "
                                  "train with --protocol unstructured to measure how thin the region is)")
    scarce, covered = scores
    gap = covered - scarce
    scarce_rate, covered_rate = gain_per_minute(lines, "scarce_psnr"), gain_per_minute(lines, "covered_psnr")
    figures = dict(gap_db=round(gap, 2),
                   scarce_db_per_min=None if scarce_rate is None else round(scarce_rate, 3),
                   covered_db_per_min=None if covered_rate is None else round(covered_rate, 3))
    where = f"scarce {scarce:.2f} / covered {covered:.2f} dB"
    if gap < NOTHING_TO_REPAIR_DB:
        return Outlook("nothing to repair", f"nothing to repair here: the scarce views render within "
                                            f"{NOTHING_TO_REPAIR_DB:g} dB of the covered ones ({where}); by "
                                            f"default a bootstrap spends every step on the photos", **figures)
    if scarce_rate is not None and scarce_rate >= STILL_RISING_DB_PER_MIN:
        wait = photo_first_minutes(scarce_rate, gain_decay_minutes(lines))
        plan = ("by default a bootstrap now spends every step on the photos (stage I's curve shows no slowing)"
                if math.isinf(wait) else f"by default a bootstrap now spends its first {wait:.1f} min on photo steps, "
                                         f"until the curve predicts they gain less than {STILL_RISING_DB_PER_MIN:g} "
                                         f"dB a minute")
        return Outlook("train longer", f"train longer first: stage I still gains {scarce_rate:.2f} dB a minute on "
                                       f"the scarce views ({where}); {plan}",
                       photo_first_min=None if math.isinf(wait) else round(wait, 2), **figures)
    rising = "" if scarce_rate is None else f", gaining {scarce_rate:.2f} dB a minute from photo steps"
    return Outlook("repair", f"worth a repair: the scarce views render {gap:.1f} dB below the covered ones "
                             f"({where}{rising}); the expected gain is not estimated", **figures)


def run_outlook(run_dir: str | Path) -> Outlook:
    """The outlook of the stage-I run in ``run_dir`` (its metrics.jsonl); "unknown" without one."""
    from ..errors import InputError
    from ..evaluation.report import read_metrics

    try:
        lines = read_metrics(Path(run_dir) / "metrics.jsonl")
    except InputError as exc:
        return Outlook("unknown", f"repair outlook: unknown ({exc})")
    outlook = outlook_from_curve(lines)
    if outlook.verdict == "unknown" and holds_out_both_groups(Path(run_dir) / "split.json"):
        # A run in blocks (its blocks' curves are theirs) or a log from elsewhere: the views are
        # held out, the curve has no scores of them.
        return Outlook("unknown", "repair outlook: unknown (stage I's log holds no scores of its held-out views; "
                                  "a bootstrap measures the outlook with a short probe of photo steps first)")
    return outlook


def holds_out_both_groups(split_file: Path) -> bool:
    """Whether the split in ``split_file`` holds out scarce and covered views (False: unreadable)."""
    import json

    try:
        split = json.loads(split_file.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(split, dict) and all(isinstance(split.get(group), list) and split[group]
                                           for group in ("scarce_test", "covered_test"))


def recorded_outlook(run_dir: str | Path) -> tuple[str, Outlook] | None:
    """What ``inceptiongs eval`` shows beside a run's scores: for a bootstrap result the outlook it
    printed before it started ("before the bootstrap"), for a stage-I run the outlook of a
    bootstrap of it ("for a bootstrap"); None for a baseline or a folder without either."""
    from .summary_file import SUMMARY_FILE, read_summary

    run_dir = Path(run_dir)
    if (run_dir / SUMMARY_FILE).exists():
        recorded = (read_summary(run_dir) or {}).get("outlook")
        if not isinstance(recorded, dict) or not isinstance(recorded.get("line"), str):
            return None
        fields = {name: recorded.get(name) for name in Outlook.__dataclass_fields__}
        if not isinstance(fields["verdict"], str):
            return None
        return "before the bootstrap", Outlook(**fields)
    if (run_dir / "metrics.jsonl").exists():
        return "for a bootstrap", run_outlook(run_dir)
    return None
