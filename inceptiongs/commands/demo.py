"""`inceptiongs demo OUT`: the whole pipeline on the built-in courtyard, judged honestly.

OUT/scene            the procedural courtyard (COLMAP binary + photos, ground-truth cameras); its
                     north facade is seen only from far away or at grazing angles
OUT/run              stage I (unstructured protocol; the views in front of the north facade are the
                     scarce cluster, 90 % of them held out; j* its centre view)
OUT/coverage.png     where the capture is thin (cameras from above, the viewing density over the
                     scene's hemisphere, the views whose content is seen least)
OUT/run_bootstrap    stage II on j* (a prior is trained here only when the supervision generates images)
OUT/run_baseline     stage I continued on the photos alone for the bootstrap's total time
OUT/*/eval/          render | photo | error images of the held-out views + eval.json
OUT/target.png       j*: stage I | baseline | bootstrap | photo (held out, shown only)
OUT/report.png       held-out PSNR against time: the three runs on one axis (the bootstrap and the
                     baseline start where stage I ended)
OUT/report.md        what ran, the three-way table (scarce vs covered), whether the bootstrap beat
                     the baseline, the images
"""

from __future__ import annotations

import io
import json
import math
import time
from pathlib import Path
from .device import add_device_argument, command_device
from ..io.values import flag

HELP = ("the whole pipeline on the built-in courtyard: scene, stage I, coverage, bootstrap, the same-time "
        "baseline, evaluation, report")

# Budgets sized for about 5.5 minutes on two idle CPU cores (the README's first command, install
# included, must stay under 8): stage I, then the bootstrap (which includes the prior's
# training, at most half of it, and generating K * L = 2 * 3 virtual views), then the baseline
# for the bootstrap's measured time.
DEFAULT_SIZE = "small"
DEFAULT_MINUTES = 1.75
DEFAULT_ITERATIONS = 600
DEFAULT_DOWNSCALE = 1
DEFAULT_BOOTSTRAP_MINUTES = 1.5
DEFAULT_BOOTSTRAP_ITERATIONS = 300
DEFAULT_PRIOR_MINUTES = 0.5
# Fewer DDIM steps than the bootstrap's default: generating the virtual views at 192x144 must
# leave most of the short budget to refinement (measured under load: 8 steps, a 0.6-minute
# prior and 1.25 minutes in all left no refinement step at all).
DEMO_DDIM_STEPS = 4
DEMO_K, DEMO_L = 2, 3
# Generated pixels count 0.2 against pixels trusted from warped photos: a prior trained for a
# minute on a CPU paints mostly noise, and at weight 1 it cost the scarce views ~0.4 dB in
# 180 demo steps (docs/bootstrap.md).
DEMO_GENERATED_WEIGHT = 0.2
# Evaluations every this many iterations: a few-minute CPU run makes a few hundred steps, so
# this gives the time plot several points without evaluation dominating the run.
DEMO_EVAL_EVERY = 50
# The baseline's step cap: it runs for the bootstrap's time, not for a number of steps.
BASELINE_ITERATION_CAP = 100_000
# Rough seconds for the stages that have no budget of their own (ETA only): scene, coverage,
# evaluating three runs, the report.
_FIXED_ESTIMATES_S = {"scene": 15.0, "coverage": 15.0, "evaluation": 15.0, "report": 5.0}
RUN_LABELS = ("stage I", "baseline", "bootstrap")
# The demo's coverage map: fewer points and smaller depth maps than the command's defaults
# (39 s under load at 3,000 points and 96 px), enough for a map of 47 views.
DEMO_COVERAGE_POINTS = 2000
DEMO_DEPTH_WIDTH = 64


def add_arguments(parser) -> None:
    parser.add_argument("out", help="output folder (scene, runs, report)")
    parser.add_argument("--minutes", type=flag("minutes"), default=DEFAULT_MINUTES,
                        help=f"stage-I training time budget (default {DEFAULT_MINUTES:g})")
    parser.add_argument("--iterations", type=flag("steps"), default=DEFAULT_ITERATIONS,
                        help=f"stage-I schedule length, stops early at --minutes (default {DEFAULT_ITERATIONS})")
    parser.add_argument("--size", choices=("tiny", "small", "medium"), default=DEFAULT_SIZE,
                        help="courtyard size: tiny 64x48 (tests), small 192x144 (default), medium 320x240")
    parser.add_argument("--downscale", type=flag("factor"), default=DEFAULT_DOWNSCALE,
                        help=f"train on images this many times smaller (default {DEFAULT_DOWNSCALE})")
    parser.add_argument("--seed", type=flag("seed"), default=0, help="scene, split, training and generation seed")
    add_device_argument(parser)
    parser.add_argument("--bootstrap-minutes", type=flag("minutes"), default=DEFAULT_BOOTSTRAP_MINUTES,
                        help=f"stage-II wall budget, prior included; the baseline gets the same time "
                             f"(default {DEFAULT_BOOTSTRAP_MINUTES:g})")
    parser.add_argument("--bootstrap-iterations", type=flag("steps"), default=DEFAULT_BOOTSTRAP_ITERATIONS,
                        help=f"stage-II refinement steps (default {DEFAULT_BOOTSTRAP_ITERATIONS})")
    parser.add_argument("--prior-minutes", type=flag("minutes"), default=DEFAULT_PRIOR_MINUTES,
                        help=f"prior training budget (default {DEFAULT_PRIOR_MINUTES:g})")
    parser.add_argument("--prior-steps", type=flag("steps"), default=None, help="or stop the prior after this many steps")
    parser.add_argument("--ddim-steps", type=flag("steps"), default=DEMO_DDIM_STEPS,
                        help=f"DDIM steps per generated image (default {DEMO_DDIM_STEPS})")


def _check(args) -> None:
    from ..errors import InputError

    for name in ("minutes", "bootstrap_minutes", "prior_minutes"):
        if getattr(args, name) <= 0:
            raise InputError(f"--{name.replace('_', '-')}: must be positive, got {getattr(args, name)}")
    for name in ("iterations", "bootstrap_iterations", "prior_steps", "ddim_steps", "downscale"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise InputError(f"--{name.replace('_', '-')}: must be >= 1, got {value}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")


class Progress:
    """Numbered stage lines with the elapsed time and an estimate of what is left (the
    remaining stages' budgets: an upper bound for the training stages)."""

    def __init__(self, estimates: list[tuple[str, float]]):
        self.estimates = estimates
        self.began = time.perf_counter()
        self.done = 0

    @staticmethod
    def clock(seconds: float) -> str:
        seconds = max(0, int(round(seconds)))
        return f"{seconds // 60}:{seconds % 60:02d}"

    def stage(self, text: str) -> None:
        left = sum(seconds for _, seconds in self.estimates[self.done:])
        self.done += 1
        print(f"[{self.done}/{len(self.estimates)}] {text}  (elapsed {self.clock(time.perf_counter() - self.began)}, "
              f"about {self.clock(left)} left)", flush=True)

    def replan(self, name: str, seconds: float) -> None:
        """A later stage's estimate became known (the baseline's time is the bootstrap's)."""
        self.estimates = [(n, seconds if n == name else s) for n, s in self.estimates]


def _cell(value, digits: int) -> str:
    return "-" if value is None else value if isinstance(value, str) else f"{value:.{digits}f}"


def _difference(a, b) -> float | None:
    """b - a for two finite scores, else None."""
    if isinstance(a, float) and isinstance(b, float) and math.isfinite(a) and math.isfinite(b):
        return b - a
    return None


def metrics_table(stage1: dict, baseline: dict, boot: dict) -> list[str]:
    """Markdown rows: group | views | PSNR/SSIM of stage I, the baseline, the bootstrap |
    bootstrap - baseline PSNR (the honest gain) | bootstrap - stage I PSNR."""
    rows = ["| held-out views | count | stage I PSNR / SSIM | baseline PSNR / SSIM | bootstrap PSNR / SSIM "
            "| bootstrap - baseline | bootstrap - stage I |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for group in ("scarce", "covered", "all"):
        runs = [stage1["groups"][group], baseline["groups"][group], boot["groups"][group]]
        cells = [f"{_cell(r['psnr'], 2)} / {_cell(r['ssim'], 4)}" for r in runs]
        gains = [_difference(runs[1]["psnr"], runs[2]["psnr"]), _difference(runs[0]["psnr"], runs[2]["psnr"])]
        rows.append(f"| {group} | {runs[0]['views']} | " + " | ".join(cells) + " | "
                    + " | ".join("-" if g is None else f"{g:+.2f}" for g in gains) + " |")
    return rows


def flagged_view_rows(index: int, stage1: dict, baseline: dict, boot: dict) -> list[str]:
    """Markdown rows: the flagged view's own PSNR / SSIM after stage I, the baseline and the
    bootstrap (its photo is held out, so it scores the repair where the user asked for it)."""
    def score(result: dict):
        return next((v for v in result.get("views", []) if v.get("index") == index), None)

    found = [score(r) for r in (stage1, baseline, boot)]
    if any(f is None for f in found):
        return [f"(view {index} is not a held-out view: no photo to score it against)"]
    cells = [f"{_cell(f['psnr'], 2)} / {_cell(f['ssim'], 4)}" for f in found]
    gains = [_difference(found[1]["psnr"], found[2]["psnr"]), _difference(found[0]["psnr"], found[2]["psnr"])]
    return ["| flagged view | stage I PSNR / SSIM | baseline PSNR / SSIM | bootstrap PSNR / SSIM "
            "| bootstrap - baseline | bootstrap - stage I |",
            "| --- | ---: | ---: | ---: | ---: | ---: |",
            f"| `{found[0]['name']}` | " + " | ".join(cells) + " | "
            + " | ".join("-" if g is None else f"{g:+.2f}" for g in gains) + " |"]


def verdict(stage1: dict, baseline: dict, boot: dict, not_same_time: str | None = None) -> str:
    """One plain sentence: did the bootstrap beat the same-time baseline on the scarce views?
    ``not_same_time``: why the baseline run is not the bootstrap's same-time baseline
    (summary_file.same_time_mismatch); then the bootstrap is not judged against it."""
    if not_same_time is not None:
        return (f"run_baseline is not the bootstrap's same-time baseline ({not_same_time}), so the bootstrap is "
                "not judged against it.")
    scarce = _difference(baseline["groups"]["scarce"]["psnr"], boot["groups"]["scarce"]["psnr"])
    covered = _difference(baseline["groups"]["covered"]["psnr"], boot["groups"]["covered"]["psnr"])
    if scarce is None:
        return "The scarce views could not be scored, so the bootstrap cannot be compared with the baseline."
    covered_text = "" if covered is None else f"; covered views {covered:+.2f} dB"
    if scarce > 0:
        return (f"The bootstrap beat the same-time baseline on the scarce views by {scarce:+.2f} dB PSNR"
                f"{covered_text}.")
    return (f"The bootstrap did NOT beat the same-time baseline: on the scarce views it is {scarce:+.2f} dB "
            f"PSNR against stage I continued on the photos for the same time{covered_text}.")


def gap_sentence(stage1: dict) -> str:
    """How much worse stage I renders the scarce views than the covered ones."""
    gap = _difference(stage1["groups"]["scarce"]["psnr"], stage1["groups"]["covered"]["psnr"])
    if gap is None:
        return "Stage I's scarce and covered views could not both be scored."
    return (f"Stage I renders the scarce views {gap:.2f} dB PSNR below the covered ones "
            f"({'visibly broken' if gap >= 3.0 else 'less than the 3 dB the demo is built for'}).")


def time_curves(stage1_records: list[dict], later: dict[str, list[dict]]) -> dict[str, dict[str, list]]:
    """{run label: {group: [(seconds, psnr)]}} on one time axis: the runs in ``later`` (metrics
    records whose wall_s starts at 0 when they start from stage I's result) are shifted by
    stage I's duration, so their curves start where stage I ended."""
    from ..evaluation.report import eval_series, run_duration

    shift = run_duration(stage1_records)
    curves = {}
    for label, records, offset in [("stage I", stage1_records, 0.0)] + [(k, v, shift) for k, v in later.items()]:
        series = eval_series(records, label)
        curves[label] = {group: [(p.wall_s + offset, p.psnr) for p in points
                                 if p.psnr is not None and math.isfinite(p.psnr)]
                         for group, points in series.items() if group in ("scarce", "covered")}
    return curves


def plot_time(curves: dict[str, dict[str, list]], out_path: Path) -> None:
    """PSNR against seconds, one colour per run, dashed = scarce, solid = covered."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from ..io.atomic import atomic_write_bytes

    figure = Figure(figsize=(9, 4.8), dpi=100)
    axis = figure.add_subplot(1, 1, 1)
    colours = {"stage I": "black", "baseline": "tab:blue", "bootstrap": "tab:red"}
    for label, groups in curves.items():
        for group, points in groups.items():
            if points:
                axis.plot([p[0] for p in points], [p[1] for p in points], "--" if group == "scarce" else "-",
                          marker="o", markersize=3, color=colours.get(label, "gray"), label=f"{label}: {group}")
    axis.set_xlabel("wall-clock seconds since stage I started")
    axis.set_ylabel("held-out PSNR (dB)")
    axis.set_title("stage I, then the bootstrap and the same-time baseline from where it ended")
    axis.grid(True, alpha=0.3)
    if axis.get_legend_handles_labels()[0]:
        axis.legend(fontsize=8)
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    atomic_write_bytes(out_path, buffer.getvalue())


def _target_image(scene, split, run_dirs: list[Path], out_path: Path, rasterizer) -> None:
    """j*: one render per run (stage I | baseline | bootstrap) by ``rasterizer``, then its held-out photo."""
    import numpy as np
    import torch

    from ..io.images import write_png
    from ..runs.load import load_run

    camera = scene.cameras[split.target_view]
    panels = []
    with torch.no_grad():
        for run_dir in run_dirs:
            panels.append(rasterizer(load_run(run_dir)[0], camera)["rgb"].clamp(0, 1).cpu().numpy())
    panels.append(np.asarray(scene.load_image(split.target_view), np.float32))
    write_png(out_path, np.round(np.concatenate(panels, axis=1) * 255.0).astype(np.uint8))


def outlook_text(boot_summary: dict) -> str:
    """The repair outlook the bootstrap printed before it started (bootstrap/outlook.py)."""
    outlook = boot_summary.get("outlook")
    return f"*{outlook['line']}*." if isinstance(outlook, dict) and "line" in outlook else "*no outlook recorded*."


def report_markdown(scene, split, evals: dict, stage1_result, boot_result, base_result, boot_summary: dict,
                    coverage: dict, timings: dict, not_same_time: str | None = None) -> str:
    """OUT/report.md text; paths relative to OUT. evals: {run label: evaluate_run result}."""
    target = split.target_view
    meta_path = Path(scene.root) / "demo_scene.json"
    designed = json.loads(meta_path.read_text()).get("scarce_cameras", []) if meta_path.is_file() else []
    views = [v for r in boot_summary.get("rounds", []) for v in r.get("views", [])]
    view_images = sorted(p.name for p in (Path(boot_result.out_dir) / "bootstrap" / "views").glob("*.png"))
    stage1, baseline, boot = (evals[label] for label in RUN_LABELS)
    scarcest = ", ".join(f"`{v['name']}` ({v['scarcity']:.2f})" for v in coverage.get("scarcest_views", [])[:5])
    lines = [
        "# InceptionGS demo",
        "",
        f"**{verdict(stage1, baseline, boot, not_same_time)}** {gap_sentence(stage1)}",
        "",
        f"Before the bootstrap ran, stage I's curve said: {outlook_text(boot_summary)}",
        "",
        f"- scene: `scene/`, a procedural courtyard ({len(scene.cameras)} views at "
        f"{scene.cameras[0].width}x{scene.cameras[0].height}); the views in front of its north facade, which "
        f"every other view sees only from far away or at a grazing angle: {', '.join(designed) or 'none'}",
        f"- stage I: `run/` ({stage1_result.iteration} iterations, {stage1_result.num_gaussians} Gaussians, "
        f"unstructured protocol with those views as the scarce cluster, seed {split.seed}: {len(split.train)} "
        f"training views, {len(split.scarce_test)} scarce + {len(split.covered_test)} covered held out)",
        f"- target view j* = {target} (`{scene.cameras[target].name}`), the centre of the scarce cluster",
        f"- prior: {boot_result.prior}",
        f"- bootstrap: `run_bootstrap/` ({boot_result.virtual_views} virtual views, "
        f"mean trust of their pixels in the warped photos {sum(v['mask_fraction'] for v in views) / max(len(views), 1):.0%}; "
        f"iterations {boot_result.start_iteration}..{boot_result.iteration} in {boot_result.wall_s:.0f} s, all of "
        f"stage II included; perceptual loss: {boot_summary.get('perceptual', '-')})",
        f"- baseline: `run_baseline/`, stage I continued on the photos alone for the bootstrap's time "
        f"(iterations {base_result.start_iteration}..{base_result.iteration} in {base_result.wall_s:.0f} s)",
        "- times: " + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()),
        "",
        "## Held-out views: stage I, the same-time baseline, the bootstrap",
        "",
        *metrics_table(stage1, baseline, boot),
        "",
        "The flagged view j* itself (`target.png` shows it after each run, beside its photo):",
        "",
        *flagged_view_rows(target, stage1, baseline, boot),
        "",
        f"LPIPS: {stage1['lpips']}. FID: {stage1['fid']}.",
        "",
        "## Coverage (`coverage.png`)",
        "",
        f"Stage I's opaque Gaussians seen by a median of {coverage['views_per_point']['median']:g} training views; "
        f"{coverage['thinly_seen_fraction']:.0%} by fewer than {coverage['thin_threshold_views']}. "
        f"Views whose content the training views see least: {scarcest or '-'}.",
        "",
        "## Images",
        "",
        "- `target.png`: j* after stage I | after the baseline | after the bootstrap | its photo (held out: "
        "never trained on)",
        "- `report.png`: held-out PSNR against time, the three runs on one axis",
        "- `coverage.png`: cameras from above, viewing density over the hemisphere, the scarcest views",
        "- `run/eval/`, `run_baseline/eval/`, `run_bootstrap/eval/`: every held-out view, render | photo | error",
        "- `run_bootstrap/bootstrap/views/`: generated | trusted-pixel mask | I* | stage-I render, per virtual view"
        + (f" ({', '.join(view_images[:3])}{', ...' if len(view_images) > 3 else ''})" if view_images else ""),
        "",
    ]
    return "\n".join(lines)


def _stage1(args, out: Path, progress: Progress, timings: dict):
    """OUT/scene and OUT/run: the courtyard and stage I on it -> (TrainResult, Stage1)."""
    from ..bootstrap.stage1 import load_stage1
    from ..scene.courtyard import write_courtyard_scene
    from ..io.config_json import with_values
    from ..runs.config import TrainConfig, short_run_schedule
    from ..train.trainer import train

    progress.stage("writing the courtyard scene")
    began = time.perf_counter()
    scene_dir = write_courtyard_scene(out / "scene", size=args.size, seed=args.seed)
    meta = json.loads((scene_dir / "demo_scene.json").read_text())
    timings["scene"] = time.perf_counter() - began

    progress.stage(f"stage I: {args.iterations} iterations or {args.minutes:g} min")
    began = time.perf_counter()
    run_dir = out / "run"
    config = short_run_schedule(with_values(TrainConfig(
        scene=str(scene_dir.resolve()), protocol="unstructured", scarce_views=list(meta["scarce_cameras"]),
        seed=args.seed, downscale=args.downscale, iterations=args.iterations, minutes=args.minutes,
        device=args.device), {"output.eval_every": DEMO_EVAL_EVERY}))
    result = train(config, run_dir)
    timings["stage I"] = time.perf_counter() - began
    return result, load_stage1(run_dir)


def _coverage(run_dir: Path, out: Path, progress: Progress, timings: dict, rasterizer) -> dict:
    """OUT/coverage.png -> its summary figures."""
    from ..evaluation import coverage_map

    progress.stage("coverage of stage I's Gaussians by the training views")
    began = time.perf_counter()
    coverage = coverage_map.run_coverage(run_dir, max_points=DEMO_COVERAGE_POINTS, depth_width=DEMO_DEPTH_WIDTH,
                                         rasterizer=rasterizer)
    coverage_map.plot(coverage, out / "coverage.png", title="demo courtyard: coverage by stage I's training views")
    timings["coverage"] = time.perf_counter() - began
    return coverage_map.summary(coverage)


def _bootstrap_and_baseline(args, stage1, out: Path, progress: Progress, timings: dict, rasterizer):
    """OUT/run_bootstrap on j*, then OUT/run_baseline for the bootstrap's time -> (boot, baseline) results."""
    from ..bootstrap.config import BootstrapConfig
    from ..bootstrap.runner import baseline_run, run_bootstrap
    from ..bootstrap.summary_file import read_summary, run_seconds
    from ..bootstrap.targets import split_targets
    from ..evaluation.report import read_metrics, run_duration

    scene, split = stage1.scene, stage1.split
    boot_config = BootstrapConfig(seed=args.seed, iterations=args.bootstrap_iterations,
                                  minutes=args.bootstrap_minutes, prior_minutes=args.prior_minutes,
                                  prior_steps=args.prior_steps, ddim_steps=args.ddim_steps, k=DEMO_K, l=DEMO_L,
                                  generated_weight=DEMO_GENERATED_WEIGHT, eval_every=DEMO_EVAL_EVERY)
    made_of = "prior, virtual views" if boot_config.needs_prior() else "virtual views from the photos"
    progress.stage(f"bootstrap of j* = {scene.cameras[split.target_view].name} ({made_of}, "
                   f"refinement; at most {args.bootstrap_minutes:g} min)")
    began = time.perf_counter()
    boot_dir = out / "run_bootstrap"
    # Stage I said which device it chose; the bootstrap and the baseline use the same one quietly.
    # The demo's own output folder: a rerun of the demo replaces its previous demo result.
    boot_result = run_bootstrap(stage1, boot_dir, split_targets(split, scene, 1), boot_config, overwrite=True,
                                log=lambda message: print(f"      {message}", flush=True), rasterizer=rasterizer)
    timings["bootstrap"] = time.perf_counter() - began

    # The baseline gets what the bootstrap took by its own clock (prior, generation, refinement):
    # the wall time its summary records, which the same-time rule compares (summary_file).
    recorded = run_seconds(read_summary(boot_dir) or {})
    base_s = max(recorded if recorded is not None else run_duration(read_metrics(boot_dir / "metrics.jsonl")), 1.0)
    progress.replan("baseline", base_s)
    progress.stage(f"baseline: stage I continued on the photos alone for the bootstrap's {base_s:.0f} s")
    began = time.perf_counter()
    base_result = baseline_run(stage1, out / "run_baseline", base_s / 60.0, BASELINE_ITERATION_CAP, seed=args.seed,
                               eval_every=DEMO_EVAL_EVERY, rasterizer=rasterizer)
    timings["baseline"] = time.perf_counter() - began
    return boot_result, base_result


def _evaluate(dirs: dict[str, Path], progress: Progress, timings: dict, device) -> dict:
    """Held-out scores of the three runs, printed as tables -> {label: eval}."""
    from ..evaluation.run import evaluate_run
    from ..evaluation.scoring import format_table

    progress.stage("evaluating stage I, the baseline and the bootstrap on the held-out views")
    began = time.perf_counter()
    evals = {label: evaluate_run(path, progress=False, device=device) for label, path in dirs.items()}
    for label in RUN_LABELS:
        print(f"{label}\n{format_table(evals[label])}")
    timings["evaluation"] = time.perf_counter() - began
    return evals


def run(args) -> int:
    from ..bootstrap.summary_file import read_summary, same_time_mismatch
    from ..evaluation.report import read_metrics
    from ..io.atomic import atomic_write_text

    _check(args)
    # The one device for every stage (stage I records it and prints what auto chose); one that
    # cannot run here is one line before the scene is written.
    device = command_device(args.device)
    out = Path(args.out)
    boot_s = 60.0 * args.bootstrap_minutes
    progress = Progress([("scene", _FIXED_ESTIMATES_S["scene"]), ("stage I", 60.0 * args.minutes),
                         ("coverage", _FIXED_ESTIMATES_S["coverage"]), ("bootstrap", boot_s),
                         ("baseline", boot_s), ("evaluation", _FIXED_ESTIMATES_S["evaluation"]),
                         ("report", _FIXED_ESTIMATES_S["report"])])
    timings: dict[str, float] = {}
    stage1_result, stage1 = _stage1(args, out, progress, timings)
    run_dir, scene, split = stage1.run_dir, stage1.scene, stage1.split
    coverage_figures = _coverage(run_dir, out, progress, timings, device.rasterizer)
    boot_result, base_result = _bootstrap_and_baseline(args, stage1, out, progress, timings, device.rasterizer)
    dirs = dict(zip(RUN_LABELS, (run_dir, out / "run_baseline", out / "run_bootstrap")))
    evals = _evaluate(dirs, progress, timings, device)

    progress.stage("report")
    _target_image(scene, split, list(dirs.values()), out / "target.png", device.rasterizer)
    curves = time_curves(read_metrics(run_dir / "metrics.jsonl"),
                         {label: read_metrics(dirs[label] / "metrics.jsonl") for label in ("baseline", "bootstrap")})
    plot_time(curves, out / "report.png")
    boot_summary = json.loads((dirs["bootstrap"] / "bootstrap" / "summary.json").read_text())
    # The verdict holds only if run_baseline is the same-time baseline (the one rule: summary_file).
    not_same_time = same_time_mismatch(boot_summary, read_summary(dirs["baseline"]) or {})
    atomic_write_text(out / "report.md", report_markdown(scene, split, evals, stage1_result, boot_result, base_result,
                                                         boot_summary, coverage_figures, timings, not_same_time))
    print(f"total {Progress.clock(time.perf_counter() - progress.began)}")
    print(gap_sentence(evals["stage I"]))
    print(verdict(*(evals[label] for label in RUN_LABELS), not_same_time))
    print(f"report: {out / 'report.md'}")
    print(f"open the result in the viewer:\n  inceptiongs-viewer {dirs['bootstrap']}")
    return 0
