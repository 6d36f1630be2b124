"""Prior quality against prior training time and against DDIM steps.

Reads RUN/prior/metrics.jsonl (PriorTrainer's log: "train_s", "step", and on evaluation
records "generated"/"render": {group: {"psnr", "ssim"}}, written by `inceptiongs prior
--eval-every-minutes`) and RUN/eval/generated.json (`inceptiongs eval --generated
--ddim-steps ...`). Stage-I render scores are drawn as dashed reference lines.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

from ..io.atomic import atomic_write_bytes
from ..io.paths import check_inside
from ..errors import InputError
from .report import read_metrics

GROUPS = ("scarce", "covered")
METRICS = ("psnr", "ssim")


def prior_evaluations(run_dir: str | Path) -> list[dict]:
    """Evaluation records of RUN/prior/metrics.jsonl sorted by training seconds ([] when absent)."""
    path = Path(run_dir) / "prior" / "metrics.jsonl"
    if not path.is_file():
        return []
    check_inside(path, run_dir)
    records = [r for r in read_metrics(path) if isinstance(r.get("generated"), dict)]
    for record in records:
        if not isinstance(record.get("train_s"), (int, float)):
            raise InputError(f"{path}: an evaluation record has no train_s")
    return sorted(records, key=lambda r: r["train_s"])


def generated_by_steps(run_dir: str | Path) -> list[dict]:
    """RUN/eval/generated.json's "by_steps" sorted by DDIM steps ([] when absent)."""
    path = Path(run_dir) / "eval" / "generated.json"
    if not path.is_file():
        return []
    check_inside(path, run_dir)
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))["by_steps"]
        return sorted(entries, key=lambda e: int(e["ddim_steps"]))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a generated-image evaluation ({type(exc).__name__}: {exc})") from None


def has_prior_report(run_dir: str | Path) -> bool:
    return bool(prior_evaluations(run_dir) or generated_by_steps(run_dir))


def _value(entry: dict | None, metric: str) -> float | None:
    value = None if entry is None else entry.get(metric)
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def _cell(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def prior_table(run_dir: str | Path) -> str:
    """Text: generated (and render) PSNR/SSIM per group against training seconds, then against DDIM steps."""
    label = Path(run_dir).resolve().name
    lines = []
    evaluations = prior_evaluations(run_dir)
    if evaluations:
        lines.append(f"{label}: generated images (render in brackets) against prior training time")
        lines.append(f"{'train s':>8}{'step':>7}  " + "  ".join(f"{g + ' PSNR/SSIM':<28}" for g in GROUPS))
        for record in evaluations:
            cells = []
            for group in GROUPS:
                gen, ren = record["generated"].get(group), record.get("render", {}).get(group)
                cells.append(f"{_cell(_value(gen, 'psnr'), 2)}/{_cell(_value(gen, 'ssim'), 3)} "
                             f"({_cell(_value(ren, 'psnr'), 2)}/{_cell(_value(ren, 'ssim'), 3)})")
            lines.append(f"{record['train_s']:>8.0f}{record.get('step', 0):>7}  " + "  ".join(f"{c:<28}" for c in cells))
    steps = generated_by_steps(run_dir)
    if steps:
        lines.append(f"{label}: generated images (render in brackets) against DDIM steps")
        lines.append(f"{'steps':>8}{'s/img':>7}  " + "  ".join(f"{g + ' PSNR/SSIM':<28}" for g in GROUPS))
        for entry in steps:
            cells = []
            for group in GROUPS:
                g = entry["groups"].get(group, {})
                cells.append(f"{_cell(_value(g.get('generated'), 'psnr'), 2)}/{_cell(_value(g.get('generated'), 'ssim'), 3)} "
                             f"({_cell(_value(g.get('render'), 'psnr'), 2)}/{_cell(_value(g.get('render'), 'ssim'), 3)})")
            lines.append(f"{entry['ddim_steps']:>8}{entry.get('seconds_per_image', float('nan')):>7.1f}  "
                         + "  ".join(f"{c:<28}" for c in cells))
    if not lines:
        lines.append(f"{label}: no prior evaluations (run `inceptiongs prior RUN --eval-every-minutes M` "
                     "or `inceptiongs eval RUN --generated --ddim-steps 5,10,20`)")
    return "\n".join(lines)


def plot_prior_report(run_dirs: list[str | Path], out_path: str | Path) -> None:
    """2 x 2 panels (PSNR, SSIM) x (against prior training seconds, against DDIM steps): solid
    lines for the generated images, dashed for the stage-I render, one colour per run and
    group. Written atomically as PNG."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 8), dpi=100)
    axes = figure.subplots(2, 2)
    colour = 0
    for run_dir in run_dirs:
        label = Path(run_dir).resolve().name
        evaluations, steps = prior_evaluations(run_dir), generated_by_steps(run_dir)
        for group in GROUPS:
            c = f"C{colour % 10}"
            colour += 1
            for row, metric in enumerate(METRICS):
                series = [(r["train_s"], _value(r["generated"].get(group), metric)) for r in evaluations]
                series = [(x, y) for x, y in series if y is not None]
                if series:
                    axes[row, 0].plot(*zip(*series), "-o", color=c, markersize=3, label=f"{label} {group} generated")
                    render = [_value(r.get("render", {}).get(group), metric) for r in evaluations]
                    render = [v for v in render if v is not None]
                    if render:
                        axes[row, 0].axhline(render[-1], color=c, linestyle="--", linewidth=1,
                                             label=f"{label} {group} stage-I render")
                by = [(e["ddim_steps"], _value(e["groups"].get(group, {}).get("generated"), metric)) for e in steps]
                by = [(x, y) for x, y in by if y is not None]
                if by:
                    axes[row, 1].plot(*zip(*by), "-o", color=c, markersize=3, label=f"{label} {group} generated")
                    render = _value(steps[0]["groups"].get(group, {}).get("render"), metric)
                    if render is not None:
                        axes[row, 1].axhline(render, color=c, linestyle="--", linewidth=1,
                                             label=f"{label} {group} stage-I render")
    for row, metric in enumerate(METRICS):
        axes[row, 0].set_xlabel("prior training time (s)")
        axes[row, 1].set_xlabel("DDIM steps")
        for axis in axes[row]:
            axis.set_ylabel(f"held-out {metric.upper()}")
            axis.grid(True, alpha=0.3)
            if axis.get_legend_handles_labels()[0]:
                axis.legend(fontsize=7)
    axes[0, 0].set_title("generated quality against prior training time")
    axes[0, 1].set_title("generated quality against DDIM steps")
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    atomic_write_bytes(out_path, buffer.getvalue())


def prior_figure_path(out_path: str | Path) -> Path:
    """FIGURE.png -> FIGURE_prior.png (beside the stage-I figure)."""
    out_path = Path(out_path)
    return out_path.with_name(out_path.stem + "_prior" + out_path.suffix)
