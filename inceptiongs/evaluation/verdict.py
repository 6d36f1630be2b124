"""Whether a bootstrap helped, told truthfully about time: the held-out scores of stage I (the
bootstrap's first evaluation) and of the result, compared with the same-time baseline (stage I
continued on the photos alone for the bootstrap's time, from the same stage-I run and iteration:
``inceptiongs.bootstrap.summary_file.same_time_mismatch`` decides) and never with a baseline of
another length; without one, the sentence says so and names the baselines it refused and why.
It also says when the bootstrap made no step, made no virtual step, or scored below stage I.

Read from RUN2/bootstrap/summary.json (the bootstrap's own evaluations, no rendering), so the
viewer's verdict, ``inceptiongs eval`` and ``inceptiongs report`` say the same sentence."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..bootstrap.summary_file import (SUMMARY_FILE, read_summary, run_seconds, same_time_mismatch,
                                      virtual_step_count)

GROUPS = ("scarce", "covered", "all")
# A difference within this many dB is reported as no change (held-out PSNR noise).
SAME_DB = 0.05


@dataclass
class BootstrapVerdict:
    """What is known about the bootstrap result in ``out_dir``: flat held-out scores
    ("scarce_psnr", ...) of stage I (before) and of the result (after); its same-time baseline's
    scores and folder (None: none found); the baselines of the same stage-I run refused as not
    for the same time ((folder, why), ...); the bootstrap's wall time in seconds (what its baseline
    must run); the outlook it recorded; its steps that carried a virtual loss (None: unknown) and
    the iterations it ran from and to (None: unknown)."""

    out_dir: Path
    stage1_run: Path | None
    before: dict
    after: dict
    baseline: dict | None = None
    baseline_dir: Path | None = None
    refused: tuple = ()
    seconds: float | None = None
    outlook: str | None = None
    virtual_steps: int | None = None
    iterations: tuple | None = None
    no_virtual_why: str | None = None   # why no virtual step ran, as the summary tells it (None: not told)


def no_virtual_reason(data: dict) -> str | None:
    """Why a bootstrap's summary ``data`` ran no virtual step, in words: its rounds held their
    views back (the outlook said nothing to repair, or a photo-first time the run ended within),
    or the agreement gate left out every view made; None when the summary does not tell."""
    rounds = [r for r in data.get("rounds", ()) if isinstance(r, dict)] if isinstance(data.get("rounds"), list) else []
    if not rounds:
        return None
    outlook = data.get("outlook")
    said = outlook.get("verdict") if isinstance(outlook, dict) and isinstance(outlook.get("verdict"), str) else None
    deferred = [r.get("deferred") for r in rounds if isinstance(r.get("deferred"), str)]
    if deferred and all(d == "every step on the photos" for d in deferred):
        return f'the outlook said "{said}", so every step went to the photos' if said \
            else "every step went to the photos"
    if deferred:
        return f"the virtual views were held back ({deferred[-1]}) and the run ended first"
    views = [v for r in rounds if isinstance(r.get("views"), list) for v in r["views"] if isinstance(v, dict)]
    if views and not any(v.get("supervised") for v in views):
        return (f"the agreement gate left out all {len(views)} virtual views: their warped photos agreed worse "
                f"with each other than with the render")
    return None


def scores_of(data: dict, key: str) -> dict:
    """The numeric entries of ``data[key]`` (a summary's "initial_eval" / "last_eval"), {} when absent."""
    value = data.get(key)
    return {k: v for k, v in value.items() if isinstance(v, (int, float)) and not isinstance(v, bool)} \
        if isinstance(value, dict) else {}


def baseline_places(out_dir: Path, stage1_run: Path | None) -> list[Path]:
    """Where a bootstrap's baselines are looked for: the folders beside it and beside its stage-I
    run (as `inceptiongs demo` lays them out: run, run_bootstrap, run_baseline)."""
    parents = {Path(out_dir).resolve().parent} | ({Path(stage1_run).resolve().parent} if stage1_run else set())
    found = set()
    for parent in parents:
        if parent.is_dir():
            found.update(p for p in parent.iterdir() if p.is_dir())
    return sorted(found)


def find_same_time_baseline(out_dir: Path, summary: dict, folders: list[Path]) -> tuple[tuple | None, tuple]:
    """Among ``folders``, the newest same-time baseline of the bootstrap in ``out_dir`` (whose
    summary is ``summary``) -> ((its folder, its last held-out scores) or None, the baselines of
    the same stage-I run refused: ((folder, why), ...)). Baselines of other stage-I runs are not
    this bootstrap's and are not named."""
    stage1 = summary.get("run")
    matches, refused = [], []
    for folder in folders:
        if Path(folder).resolve() == Path(out_dir).resolve():
            continue
        data = read_summary(folder)
        if (data is None or data.get("baseline") is not True or not isinstance(stage1, str)
                or not isinstance(data.get("run"), str) or Path(data["run"]).resolve() != Path(stage1).resolve()):
            continue
        scores = scores_of(data, "last_eval")
        why = same_time_mismatch(summary, data) if scores else "it has no held-out scores yet"
        if why is None:
            matches.append(((Path(folder) / SUMMARY_FILE).stat().st_mtime, Path(folder), scores))
        else:
            refused.append((Path(folder), why))
    if not matches:
        return None, tuple(refused)
    _, folder, scores = max(matches, key=lambda item: item[0])
    return (folder, scores), tuple(refused)


def read_bootstrap_verdict(out_dir: Path | None, folders: list[Path] | None = None) -> BootstrapVerdict | None:
    """The verdict of the bootstrap result in ``out_dir``, its baseline looked for in ``folders``
    (default: baseline_places); None for anything else (a stage-I run, a baseline, a bootstrap
    without both evaluations yet)."""
    if out_dir is None:
        return None
    data = read_summary(out_dir)
    if data is None or data.get("baseline") is True:
        return None
    before, after = scores_of(data, "initial_eval"), scores_of(data, "last_eval")
    if not before or not after:
        return None
    stage1 = Path(data["run"]) if isinstance(data.get("run"), str) else None
    outlook = data.get("outlook")
    steps = data.get("steps")
    counted = isinstance(steps, dict) and all(isinstance(v, int) for v in steps.values())
    start, end = data.get("start_iteration"), data.get("iteration")
    found, refused = find_same_time_baseline(Path(out_dir), data, baseline_places(Path(out_dir), stage1)
                                             if folders is None else folders)
    return BootstrapVerdict(
        Path(out_dir), stage1, before, after, baseline=None if found is None else found[1],
        baseline_dir=None if found is None else found[0], refused=refused, seconds=run_seconds(data),
        outlook=outlook.get("line") if isinstance(outlook, dict) and isinstance(outlook.get("line"), str) else None,
        virtual_steps=virtual_step_count(steps) if counted else None,
        iterations=(start, end) if isinstance(start, int) and isinstance(end, int) else None,
        no_virtual_why=no_virtual_reason(data))


def score_rows(verdict: BootstrapVerdict) -> list[tuple[str, float, float, float | None]]:
    """[(group, stage I dB, bootstrap dB, baseline dB or None)] for the groups the result scored."""
    rows = []
    for group in GROUPS:
        key = f"{group}_psnr"
        if key in verdict.before and key in verdict.after:
            baseline = None if verdict.baseline is None else verdict.baseline.get(key)
            rows.append((group, verdict.before[key], verdict.after[key], baseline))
    return rows


def change_phrase(difference: float, other: str) -> str:
    """How the result compares with ``other`` ("the same-time baseline", "stage I")."""
    if abs(difference) < SAME_DB:
        return f"about the same as {other} ({difference:+.2f} dB)"
    return f"{'better' if difference > 0 else 'worse'} by {abs(difference):.2f} dB than {other}"


def seconds_text(seconds: float | None) -> str:
    """'68 s', '2 min 05 s'; '' when unknown."""
    if seconds is None:
        return ""
    whole = int(round(seconds))
    return f"{whole} s" if whole < 60 else f"{whole // 60} min {whole % 60:02d} s"


def missing_baseline_phrase(verdict: BootstrapVerdict) -> str:
    """'no same-time baseline (stage I continued on the photos alone for 68 s) was run; run_baseline
    is not one: it ran 66 s, the bootstrap 5 s'."""
    time = seconds_text(verdict.seconds) or "the bootstrap's time"
    phrase = f"no same-time baseline (stage I continued on the photos alone for {time}) was run"
    if verdict.refused:
        phrase += "; " + "; ".join(f"{folder.name} is not one: {why}" for folder, why in verdict.refused)
    return phrase


def verdict_line(verdict: BootstrapVerdict) -> str:
    """One sentence: how the result compares on the held-out scarce views (else the first group
    scored; "held-out": a flagged view has no photo to score, and a user read "scarce views" as
    the views they had flagged)
    with its same-time baseline, or with stage I when there is none (saying so, and which
    baselines were refused); then whether it made no step or no virtual step, and whether it
    scored below stage I."""
    rows = score_rows(verdict)
    if not rows:
        return "no held-out scores to judge the bootstrap by"
    group, before, after, baseline = rows[0]
    parts = []
    if baseline is not None:
        parts.append(f"held-out {group} views: {change_phrase(after - baseline, 'the same-time baseline')}")
    else:
        parts.append(f"held-out {group} views: {change_phrase(after - before, 'stage I')}")
    # Said unless the first part already says "worse ... than stage I".
    if after < before and (baseline is not None or before - after < SAME_DB):
        parts.append(f"it scored below stage I ({before:.2f} -> {after:.2f} dB)")
    if baseline is None:
        parts.append(missing_baseline_phrase(verdict))
    if verdict.iterations is not None and verdict.iterations[1] <= verdict.iterations[0]:
        parts.append(f"the bootstrap made no step (iterations {verdict.iterations[0]}..{verdict.iterations[1]})")
    elif verdict.virtual_steps == 0:
        why = verdict.no_virtual_why or "the loop followed the outlook, or every view was left out"
        parts.append(f"no virtual step ran ({why}), so this is stage I trained longer")
    elif baseline is None:
        parts.append("part of the change may be the extra training alone")
    return "; ".join(parts)


def verdict_json(verdict: BootstrapVerdict) -> dict:
    """The verdict as `inceptiongs eval --json` prints it: the sentence, the same-time baseline's
    folder (None: none), the baselines refused and why, the bootstrap's seconds, the scores."""
    return {"line": verdict_line(verdict), "same_time_baseline": None if verdict.baseline_dir is None
            else str(verdict.baseline_dir), "refused": [{"folder": str(folder), "why": why}
                                                        for folder, why in verdict.refused],
            "seconds": verdict.seconds, "stage1": verdict.before, "bootstrap": verdict.after,
            "baseline": verdict.baseline}


def report_verdicts(run_dirs: list) -> list[str]:
    """For each bootstrap result among ``run_dirs``: "NAME: <verdict sentence>", its baseline
    looked for among the given runs and beside it (baseline_places); [] when none is one."""
    lines = []
    for run_dir in run_dirs:
        data = read_summary(run_dir)
        if data is None or data.get("baseline") is True:
            continue
        stage1 = Path(data["run"]) if isinstance(data.get("run"), str) else None
        folders = sorted({Path(r) for r in run_dirs} | set(baseline_places(Path(run_dir), stage1)))
        verdict = read_bootstrap_verdict(Path(run_dir), folders)
        if verdict is not None:
            lines.append(f"{Path(run_dir).name}: {verdict_line(verdict)}")
    return lines
