"""What the Training panel says about a running job: its plan (iterations from..to, time budget,
where it logs), elapsed time without pauses, ETA, the held-out PSNR series read from the job's
metrics log, and the closing line that replaces the running status. Pure: no GL, no imgui."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

from inceptiongs.bootstrap.job import BaselineJob, BootstrapJob
from inceptiongs.bootstrap.summary_file import read_summary, run_seconds
from inceptiongs.errors import InputError
from inceptiongs.evaluation.report import eval_series, read_metrics
from inceptiongs.runs.checkpoint import list_checkpoints
from inceptiongs.runs.config import TrainConfig
from inceptiongs.train.job import TrainJob

# Held-out groups the panel plots, in this order (evaluation.report names them).
PLOTTED_GROUPS = ("scarce", "covered", "all")


@dataclass(frozen=True)
class JobPlan:
    """start/end: the iterations the job runs from and to; budget_s: its time budget (None:
    the whole schedule); metrics: the metrics.jsonl it appends to (None: unknown); config: the
    run's config.json, whose ``iterations`` is the end when the trainer re-sizes the schedule
    to the budget (None: the end is fixed); resumed: the job continues from a checkpoint at
    ``start_iteration`` (a stopped run or bootstrap)."""

    start_iteration: int = 0
    end_iteration: int | None = None
    budget_s: float | None = None
    metrics: Path | None = None
    kind: str = "job"
    config: Path | None = None
    resumed: bool = False

    @property
    def steps(self) -> int | None:
        return None if self.end_iteration is None else self.end_iteration - self.start_iteration


def stage1_iteration(run_dir: Path) -> int:
    """The iteration a run stands at: its newest checkpoint's, else its schedule's end."""
    found = list_checkpoints(Path(run_dir))
    if found:
        return found[-1][0]
    return TrainConfig.load(Path(run_dir) / "config.json").iterations


def plan_of(job) -> JobPlan:
    """The plan of the viewer's job kinds; an unknown job (a test's stand-in) gets an empty plan."""
    if isinstance(job, TrainJob):
        config = job.config
        start, trained_s = 0, 0.0
        if job.resume:
            found = list_checkpoints(Path(job.run_dir))
            start = found[-1][0] if found else 0
            trained_s = trained_seconds(Path(job.run_dir) / "metrics.jsonl", start)
        # A resumed run's budget counts the training it had: what is left of it is this job's.
        budget_s = None if config.minutes is None else max(60.0 * config.minutes - trained_s, 0.0)
        return JobPlan(start, config.iterations, budget_s, Path(job.run_dir) / "metrics.jsonl", "training",
                       Path(job.run_dir) / "config.json" if config.size_to_minutes else None, resumed=start > 0)
    if isinstance(job, BootstrapJob):
        return bootstrap_plan(job)
    if isinstance(job, BaselineJob):   # runs for its time: the end is not known in steps
        return JobPlan(stage1_iteration(job.run_dir), None, job.seconds, Path(job.out_dir) / "metrics.jsonl",
                       "baseline")
    return JobPlan()


def bootstrap_plan(job: BootstrapJob) -> JobPlan:
    """A bootstrap's plan: from its stage-I run's end for its rounds' steps; a resumed one starts at
    its newest checkpoint, its budget less the time its summary says it ran."""
    config = job.config
    start = stage1_iteration(job.run_dir)
    end = start + config.rounds * config.iterations
    budget_s = None if config.minutes is None else 60.0 * config.minutes
    out = None if job.out_dir is None else Path(job.out_dir)
    found = list_checkpoints(out) if job.resume and out is not None else []
    if found:
        start = found[-1][0]
        spent_s = run_seconds(read_summary(out) or {}) or 0.0
        budget_s = None if budget_s is None else max(budget_s - spent_s, 0.0)
    return JobPlan(start, end, budget_s, None if out is None else out / "metrics.jsonl", "bootstrap",
                   resumed=bool(found))


def trained_seconds(metrics: Path, iteration: int) -> float:
    """The training time a run's log records at ``iteration`` (its last line at or before it;
    0 when the log is absent, unreadable or has none): what a resume's budget has spent."""
    try:
        records = read_metrics(metrics) if Path(metrics).is_file() else []
    except InputError:
        return 0.0
    times = [r["train_s"] for r in records if isinstance(r.get("iteration"), int) and r["iteration"] <= iteration
             and isinstance(r.get("train_s"), (int, float))]
    return float(times[-1]) if times else 0.0


def resume_line(run_dir: Path, plan: JobPlan, minutes: float | None) -> str:
    """The status of a resume: where it continues and the run's own saved plan, so a plan the
    trainer later re-sizes is seen to change ("resuming RUN at iteration 305 of 1499 with its
    saved plan: a 1 min 00 s budget, 40 s of it left, the schedule sized to it")."""
    line = f"resuming {run_dir} at iteration {plan.start_iteration} of {plan.end_iteration} with its saved plan"
    if minutes is None:
        return line + ": no time budget, the whole schedule"
    line += f": a {format_duration(60.0 * minutes)} budget, {format_duration(plan.budget_s)} of it left"
    return line + (", the schedule sized to it" if plan.config is not None else "")


def replan_line(plan: JobPlan, before: int | None) -> str:
    """The status when the trainer re-sized the schedule to the budget (the plan's end moved)."""
    return (f"the schedule was re-sized to the time budget: iteration {plan.end_iteration} is the end "
            f"(was {before})")


def run_scores(run_dir: Path) -> str:
    """A run's last held-out scores from its metrics log ("all 22.30 dB, covered 23.10 dB"), or
    "no scores yet" (the run's list in the Training panel)."""
    return final_scores(psnr_series(Path(run_dir) / "metrics.jsonl")) or "no scores yet"


def planned_iterations(config_file: Path) -> int | None:
    """The schedule length stored in a run's config.json (the trainer re-saves it when it
    re-sizes the schedule to the budget); None while it is missing, half-written or odd."""
    try:
        value = json.loads(Path(config_file).read_text(encoding="utf-8")).get("iterations")
    except (OSError, ValueError, AttributeError):  # absent, not JSON yet, not an object
        return None
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 1 else None


def followed_plan(plan: JobPlan, iterations: int | None) -> JobPlan:
    """``plan`` ending at the stored schedule's end; unchanged when that is unknown (None) or
    before the start (a stale file from before a resume)."""
    if iterations is None or iterations < plan.start_iteration or iterations == plan.end_iteration:
        return plan
    return dataclasses.replace(plan, end_iteration=iterations)


def eta_seconds(iteration: int, plan: JobPlan, rate: float, elapsed_s: float) -> float | None:
    """Seconds left: the schedule's rest at ``rate`` it/s, or the budget's rest when that is
    sooner; None when neither is known (no rate yet and no budget)."""
    candidates = []
    if plan.end_iteration is not None and rate > 0:  # rate > 0: the division is safe
        candidates.append(max(plan.end_iteration - iteration, 0) / rate)
    if plan.budget_s is not None:
        candidates.append(max(plan.budget_s - elapsed_s, 0.0))
    return min(candidates) if candidates else None


def format_duration(seconds: float | None) -> str:
    """12 -> "12 s", 75 -> "1 min 15 s", 3725 -> "1 h 02 min"; None -> "?"."""
    if seconds is None or not math.isfinite(seconds):
        return "?"
    seconds = int(round(max(seconds, 0.0)))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {(seconds % 3600) // 60:02d} min"


def psnr_series(metrics: Path | None) -> dict[str, tuple[list[float], list[float]]]:
    """{group: ([iterations], [PSNR dB])} of the held-out evaluations logged so far; {} when
    the log is absent or unreadable yet (the job may be writing its first line)."""
    if metrics is None or not Path(metrics).is_file():
        return {}
    try:
        series = eval_series(read_metrics(metrics), str(metrics))
    except InputError:
        return {}
    out = {}
    for group in PLOTTED_GROUPS:
        points = [p for p in series.get(group, []) if p.iteration is not None and p.psnr is not None
                  and math.isfinite(p.psnr)]
        if points:
            out[group] = ([float(p.iteration) for p in points], [float(p.psnr) for p in points])
    return out


def final_scores(series: dict[str, tuple[list[float], list[float]]]) -> str:
    """"scarce 24.10 dB, covered 27.33 dB" from the last point of each group; "" when none."""
    return ", ".join(f"{group} {values[-1]:.2f} dB" for group, (_, values) in series.items() if values)


def closing_line(kind: str, state: str, elapsed_s: float, iteration: int, scores: str,
                 out_dir: Path | None) -> str:
    """The status that replaces "training..." once the job has ended."""
    verb = {"finished": "finished", "stopped": "stopped", "failed": "failed"}.get(state, state)
    line = f"{kind} {verb} in {format_duration(elapsed_s)} at iteration {iteration}"
    if scores:
        line += f"; held-out PSNR {scores}"
    if out_dir is not None and state != "failed":
        line += f"; saved in {out_dir}"
    return line
