"""Error against run time: test PSNR/SSIM over wall-clock seconds and iterations, read from
the runs' metrics logs (RUN/metrics.jsonl, one JSON object per line, written by the trainer).

Which fields are evaluation scores: a (possibly nested, e.g. {"eval": {"scarce": {"psnr": ..}}})
key whose parts (split at "/", "_", ".", "-") contain a metric name ("psnr" or "ssim") and a
group ("scarce", "covered", "all"; "test" or "eval" alone mean the whole test set, "test").
Keys with "train" or "loss" parts are never read as test scores (the SSIM loss term is not a
test SSIM). Every record needs "wall_s"; "iteration" is used for the second plot.
"""

from __future__ import annotations

import io
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

from ..io.atomic import atomic_write_bytes
from ..errors import InputError
from ..io.paths import read_small_text

REPORT_MINUTES = (1, 2, 5, 10, 20)
GROUP_ORDER = ("scarce", "covered", "all", "test")
_METRICS = ("psnr", "ssim")
_IGNORED_PARTS = {"train", "loss"}


@dataclass
class RunLog:
    """One run's evaluations per group and how long it ran (the last wall_s it logged)."""

    series: dict[str, list["EvalPoint"]]
    duration_s: float


@dataclass(frozen=True)
class EvalPoint:
    wall_s: float
    iteration: int | None
    psnr: float | None
    ssim: float | None


def read_metrics(path: str | Path) -> list[dict]:
    """RUN/metrics.jsonl -> records. A torn last line (a run killed mid-write) is dropped;
    a malformed line elsewhere is an error naming the file and line."""
    path = Path(path)
    try:
        lines = read_small_text(path, "metrics log").splitlines()
    except FileNotFoundError:
        raise InputError(f"{path}: metrics log does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: unreadable metrics log ({exc})") from None
    records = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines):
                break
            raise InputError(f"{path}: line {number} is not JSON") from None
        if not isinstance(record, dict):
            raise InputError(f"{path}: line {number} is not a JSON object")
        records.append(record)
    return records


def _flatten(record: dict, prefix: tuple[str, ...] = ()) -> Iterable[tuple[tuple[str, ...], object]]:
    for key, value in record.items():
        path = prefix + (str(key),)
        if isinstance(value, dict):
            yield from _flatten(value, path)
        else:
            yield path, value


def _number(value) -> float | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    if value in ("inf", "Infinity"):
        return math.inf
    return None


def scores_of(record: dict) -> dict[str, dict[str, float]]:
    """The evaluation scores one log record holds: {group: {"psnr": x, "ssim": y}}."""
    out: dict[str, dict[str, float]] = {}
    for path, value in _flatten(record):
        parts = {part for key in path for part in re.split(r"[/_.\-\s]+", key.lower()) if part}
        number = _number(value)
        if number is None or parts & _IGNORED_PARTS:
            continue
        metrics = [m for m in _METRICS if m in parts]
        if len(metrics) != 1:
            continue
        group = next((g for g in ("scarce", "covered", "all") if g in parts), None)
        if group is None and parts & {"test", "eval"}:
            group = "test"
        if group is not None:
            out.setdefault(group, {})[metrics[0]] = number
    return out


def eval_series(records: list[dict], source: str = "<metrics>") -> dict[str, list[EvalPoint]]:
    """{group: [EvalPoint sorted by wall_s]} from a run's log records."""
    series: dict[str, list[EvalPoint]] = {}
    for record in records:
        scores = scores_of(record)
        if not scores:
            continue
        wall = _number(record.get("wall_s"))
        if wall is None:
            raise InputError(f"{source}: an evaluation record has no wall_s")
        iteration = record.get("iteration")
        if iteration is not None and (isinstance(iteration, bool) or not isinstance(iteration, int)):
            raise InputError(f"{source}: an evaluation record's iteration is not an integer ({iteration!r})")
        if not (math.isfinite(wall) and wall >= 0):
            raise InputError(f"{source}: an evaluation record's wall_s is not a finite time ({wall!r})")
        for group, values in scores.items():
            series.setdefault(group, []).append(EvalPoint(wall, None if iteration is None else int(iteration),
                                                          values.get("psnr"), values.get("ssim")))
    for group, points in series.items():
        points.sort(key=lambda p: p.wall_s)
        # A model state evaluated twice (e.g. at the last step and again at the end of the
        # run) is one point: keep its first evaluation.
        seen: set[int] = set()
        series[group] = [p for p in points if p.iteration is None
                         or not (p.iteration in seen or seen.add(p.iteration))]
    return {g: series[g] for g in sorted(series, key=lambda g: GROUP_ORDER.index(g))}


def run_duration(records: list[dict]) -> float:
    """The last wall-clock time a run logged (0 for an empty log)."""
    times = [_number(r.get("wall_s")) for r in records]
    return max((t for t in times if t is not None), default=0.0)


def score_at(points: list[EvalPoint], seconds: float, duration_s: float = math.inf) -> EvalPoint | None:
    """The last evaluation at or before ``seconds`` of wall-clock time; None if there is
    none or the run stopped before ``seconds`` (it never got there)."""
    if duration_s < seconds:
        return None
    before = [p for p in points if p.wall_s <= seconds]
    return before[-1] if before else None


def load_runs(run_dirs: list[str | Path]) -> dict[str, RunLog]:
    """{label: RunLog}; labels are the folder names (the full path on a clash)."""
    names = [Path(r).resolve().name for r in run_dirs]
    runs = {}
    for run_dir, name in zip(run_dirs, names):
        label = name if names.count(name) == 1 else str(Path(run_dir).resolve())
        path = Path(run_dir) / "metrics.jsonl"
        records = read_metrics(path)
        runs[label] = RunLog(eval_series(records, str(path)), run_duration(records))
    return runs


def _format_point(point: EvalPoint | None) -> str:
    if point is None:
        return "-"
    psnr = "-" if point.psnr is None else f"{point.psnr:.2f}"
    ssim = "-" if point.ssim is None else f"{point.ssim:.3f}"
    return f"{psnr}/{ssim}"


def report_table(runs: dict[str, RunLog], minutes=REPORT_MINUTES) -> str:
    """Rows: run x group; columns: PSNR/SSIM of the last evaluation at or before each time
    ("-" where the run had no evaluation yet or never ran that long)."""
    header = ["run", "views"] + [f"{m:g} min" for m in minutes] + ["last (at s)"]
    rows = []
    for label, log in runs.items():
        if not log.series:
            rows.append([label, "(no evaluations)"] + ["-"] * (len(minutes) + 1))
        for group, points in log.series.items():
            last = f"{_format_point(points[-1])} ({points[-1].wall_s:.0f})"
            rows.append([label, group] + [_format_point(score_at(points, 60.0 * m, log.duration_s))
                                          for m in minutes] + [last])
    widths = [max(len(str(row[i])) for row in [header] + rows) for i in range(len(header))]
    lines = ["  ".join(str(cell).ljust(width) for cell, width in zip(row, widths)).rstrip()
             for row in [header] + rows]
    lines.append("cells: PSNR (dB) / SSIM of the last evaluation at or before that time ('-': no evaluation "
                 "yet or the run never got there); last: the final evaluation and its wall-clock second")
    return "\n".join(lines)


def plot_report(runs: dict[str, RunLog], out_path: str | Path) -> None:
    """Two panels (test PSNR against wall-clock seconds, against iterations), one line per
    run and group; written atomically as PNG (matplotlib Agg, no display needed)."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 4.5), dpi=100)
    by_time, by_iteration = figure.subplots(1, 2)
    styles = {"scarce": "--", "covered": "-", "all": ":", "test": "-"}
    for run_number, (label, log) in enumerate(runs.items()):
        colour = f"C{run_number % 10}"  # one colour per run, one line style per group
        for group, points in log.series.items():
            finite = [p for p in points if p.psnr is not None and math.isfinite(p.psnr)]
            if not finite:
                continue
            by_time.plot([p.wall_s for p in finite], [p.psnr for p in finite], styles[group],
                         color=colour, marker="o", markersize=3, label=f"{label} {group}")
            with_iteration = [p for p in finite if p.iteration is not None]
            by_iteration.plot([p.iteration for p in with_iteration], [p.psnr for p in with_iteration],
                              styles[group], marker="o", markersize=3, color=colour,
                              label=f"{label} {group}")
    by_time.set_xlabel("wall-clock time (s)")
    by_iteration.set_xlabel("iteration")
    for axis in (by_time, by_iteration):
        axis.set_ylabel("test PSNR (dB)")
        axis.grid(True, alpha=0.3)
        if axis.get_legend_handles_labels()[0]:
            axis.legend(fontsize=8)
    by_time.set_title("test PSNR against run time")
    by_iteration.set_title("test PSNR against iterations")
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    atomic_write_bytes(out_path, buffer.getvalue())


def make_report(run_dirs: list[str | Path], out_path: str | Path | None) -> str:
    """Read the runs, write the figure (when ``out_path`` is given), return the table."""
    for run_dir in run_dirs:
        if not Path(run_dir).is_dir():
            raise InputError(f"{run_dir}: run folder does not exist")
    runs = load_runs(run_dirs)
    if out_path is not None:
        if Path(out_path).suffix.lower() != ".png":
            raise InputError(f"{out_path}: the report figure must be a .png file")
        plot_report(runs, out_path)
    return report_table(runs)
