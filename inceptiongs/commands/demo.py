"""`inceptiongs demo OUT`: the whole pipeline on the built-in demo scene.

OUT/scene            the procedural demo scene (COLMAP binary + photos, ground-truth cameras)
OUT/run              stage I (unstructured protocol: a scarce cluster held out, j* its centre view)
OUT/run_bootstrap    stage II on j* (prior trained here when the run has none)
OUT/*/eval/          render | photo | error images of the held-out views + eval.json
OUT/target.png       j*: initial Gaussians | stage I | bootstrap | photo (held out, shown only)
OUT/report.png       test PSNR against run time (stage I and bootstrap)
OUT/report.md        what ran, the metrics table (scarce vs covered, stage I vs bootstrap), images
"""

from __future__ import annotations

import json
import time
from pathlib import Path

HELP = "the whole pipeline on the built-in demo scene: scene, stage I, prior, bootstrap, evaluation, report"

# Defaults sized for about 10 minutes on two CPU cores: stage I, then the bootstrap's budget
# (which includes the prior's training, DEFAULT_PRIOR_MINUTES, and generating the virtual views:
# K * L = 2 * 3 of them at 96x72, a few seconds each).
DEFAULT_MINUTES = 3.0
DEFAULT_ITERATIONS = 600
DEFAULT_DOWNSCALE = 2
DEFAULT_BOOTSTRAP_MINUTES = 4.0
DEFAULT_BOOTSTRAP_ITERATIONS = 300
DEFAULT_PRIOR_MINUTES = 1.5
DEMO_K, DEMO_L = 2, 3
# Generated pixels count 0.2 against pixels trusted from warped photos: a prior trained for a
# minute or two on a CPU paints mostly noise, and at weight 1 it cost the scarce views ~0.4 dB
# in 180 demo steps (docs/bootstrap.md).
DEMO_GENERATED_WEIGHT = 0.2
# Evaluations every this many iterations: a few-minute CPU run makes a few hundred steps, so
# this gives the report several points without evaluation dominating the run.
DEMO_EVAL_EVERY = 50


def add_arguments(parser) -> None:
    parser.add_argument("out", help="output folder (scene, runs, report)")
    parser.add_argument("--minutes", type=float, default=DEFAULT_MINUTES,
                        help=f"stage-I training time budget (default {DEFAULT_MINUTES:g})")
    parser.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS,
                        help=f"stage-I schedule length, stops early at --minutes (default {DEFAULT_ITERATIONS})")
    parser.add_argument("--size", choices=("small", "medium"), default="small", help="demo scene size")
    parser.add_argument("--downscale", type=int, default=DEFAULT_DOWNSCALE,
                        help=f"train on images this many times smaller (default {DEFAULT_DOWNSCALE})")
    parser.add_argument("--seed", type=int, default=0, help="scene, split, training and generation seed")
    parser.add_argument("--bootstrap-minutes", type=float, default=DEFAULT_BOOTSTRAP_MINUTES,
                        help=f"stage-II wall budget (default {DEFAULT_BOOTSTRAP_MINUTES:g})")
    parser.add_argument("--bootstrap-iterations", type=int, default=DEFAULT_BOOTSTRAP_ITERATIONS,
                        help=f"stage-II refinement steps (default {DEFAULT_BOOTSTRAP_ITERATIONS})")
    parser.add_argument("--prior-minutes", type=float, default=DEFAULT_PRIOR_MINUTES,
                        help=f"prior training budget (default {DEFAULT_PRIOR_MINUTES:g})")
    parser.add_argument("--prior-steps", type=int, default=None, help="or stop the prior after this many steps")
    parser.add_argument("--ddim-steps", type=int, default=8, help="DDIM steps per generated image")


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


def _target_image(scene, split, stage1_dir: Path, boot_dir: Path, out_path: Path, seed: int) -> None:
    """j*: initial Gaussians | stage I | bootstrap | photo, side by side."""
    import numpy as np
    import torch

    from ..io.images import write_png
    from ..rasterizer.rasterize import render
    from ..train.init_gaussians import initial_gaussians
    from ..train.run_folder import load_run

    camera = scene.cameras[split.target_view]
    initial, _ = initial_gaussians([scene.cameras[i] for i in split.train], scene.points,
                                   scene.point_colors, 0, seed)
    panels = []
    with torch.no_grad():
        for gaussians in (initial, load_run(stage1_dir)[0], load_run(boot_dir)[0]):
            panels.append(render(gaussians, camera)["rgb"].clamp(0, 1).numpy())
    panels.append(np.asarray(scene.load_image(split.target_view), np.float32))
    write_png(out_path, np.round(np.concatenate(panels, axis=1) * 255.0).astype(np.uint8))


def _cell(value, digits: int) -> str:
    return "-" if value is None else value if isinstance(value, str) else f"{value:.{digits}f}"


def metrics_table(stage1: dict, boot: dict) -> list[str]:
    """Markdown rows: group | views | stage-I PSNR/SSIM | bootstrap PSNR/SSIM | change."""
    rows = ["| held-out views | count | stage I PSNR | stage I SSIM | bootstrap PSNR | bootstrap SSIM | PSNR change |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for group in ("scarce", "covered", "all"):
        a, b = stage1["groups"][group], boot["groups"][group]
        change = (b["psnr"] - a["psnr"]) if isinstance(a["psnr"], float) and isinstance(b["psnr"], float) else None
        rows.append(f"| {group} | {a['views']} | {_cell(a['psnr'], 2)} | {_cell(a['ssim'], 4)} | "
                    f"{_cell(b['psnr'], 2)} | {_cell(b['ssim'], 4)} | "
                    f"{'-' if change is None else f'{change:+.2f}'} |")
    return rows


def report_markdown(scene, split, stage1: dict, boot: dict, stage1_result, boot_result, boot_summary: dict,
                    table: str, timings: dict) -> str:
    """OUT/report.md text; paths relative to OUT."""
    target = split.target_view
    meta_path = Path(scene.root) / "demo_scene.json"
    designed = json.loads(meta_path.read_text()).get("scarce_cameras", []) if meta_path.is_file() else []
    views = [v for r in boot_summary.get("rounds", []) for v in r.get("views", [])]
    view_images = sorted(p.name for p in (Path(boot_result.out_dir) / "bootstrap" / "views").glob("*.png"))
    lines = [
        "# InceptionGS demo",
        "",
        f"- scene: `scene/` ({len(scene.cameras)} views at {scene.cameras[0].width}x{scene.cameras[0].height}; "
        f"cameras the scene generator made scarce: {', '.join(designed) or 'none'})",
        f"- stage I: `run/` ({stage1_result.iteration} iterations, {stage1_result.num_gaussians} Gaussians, "
        f"unstructured protocol, seed {split.seed}: {len(split.train)} training views, "
        f"{len(split.scarce_test)} scarce + {len(split.covered_test)} covered held out)",
        f"- target view j* = {target} (`{scene.cameras[target].name}`), the centre of the scarce cluster "
        f"(views {', '.join(str(i) for i in split.scarce_cluster)})",
        f"- prior: {boot_result.prior}",
        f"- bootstrap: `run_bootstrap/` ({boot_result.virtual_views} virtual views, "
        f"{sum(v['mask_fraction'] for v in views) / max(len(views), 1):.0%} of their pixels from warped photos; "
        f"iterations {boot_result.start_iteration}..{boot_result.iteration}; "
        f"perceptual loss: {boot_summary.get('perceptual', '-')})",
        "- times: " + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()),
        "",
        "## Held-out views: stage I vs bootstrap",
        "",
        *metrics_table(stage1, boot),
        "",
        f"LPIPS: {stage1['lpips']}. FID: {stage1['fid']}.",
        "The bootstrap continues stage I; the comparison with stage I continued for the same total time "
        "(without virtual views) is `benchmarks/bench_bootstrap.py` (docs/bootstrap.md).",
        "",
        "## Images",
        "",
        "- `target.png`: j* rendered from the initial Gaussians | after stage I | after the bootstrap | "
        "its photo (held out: never trained on)",
        "- `run/eval/`, `run_bootstrap/eval/`: every held-out view, render | photo | error",
        "- `run_bootstrap/bootstrap/views/`: generated | trusted-pixel mask | I* | stage-I render, per virtual view"
        + (f" ({', '.join(view_images[:3])}{', ...' if len(view_images) > 3 else ''})" if view_images else ""),
        "- `report.png`: held-out PSNR against run time",
        "",
        "```",
        table,
        "```",
        "",
    ]
    return "\n".join(lines)


def run(args) -> int:
    from ..io.atomic import atomic_write_text
    from ..bootstrap.config import BootstrapConfig
    from ..bootstrap.runner import run_bootstrap
    from ..bootstrap.targets import split_targets
    from ..scene.demo import write_demo_scene
    from ..evaluation.run import evaluate_run
    from ..evaluation.scoring import format_table
    from ..evaluation.protocols import Split
    from ..evaluation.report import make_report
    from ..scene.loader import load_scene
    from ..train.config import TrainConfig
    from ..train.trainer import train
    from ..train.config import short_run_schedule

    _check(args)
    out = Path(args.out)
    timings: dict[str, float] = {}
    began = time.perf_counter()
    print("[1/5] writing the demo scene", flush=True)
    scene_dir = write_demo_scene(out / "scene", size=args.size, seed=args.seed)
    timings["scene"] = time.perf_counter() - began

    print(f"[2/5] stage I: {args.iterations} iterations or {args.minutes:g} min", flush=True)
    began = time.perf_counter()
    run_dir = out / "run"
    config = short_run_schedule(TrainConfig(scene=str(scene_dir.resolve()), protocol="unstructured",
                                            seed=args.seed, downscale=args.downscale, iterations=args.iterations,
                                            minutes=args.minutes, eval_every=DEMO_EVAL_EVERY))
    stage1_result = train(config, run_dir)
    timings["stage I"] = time.perf_counter() - began

    scene = load_scene(config.scene, downscale=config.downscale)
    split = Split.load(run_dir / "split.json", scene.cameras)
    print(f"[3/5] bootstrap of j* = {scene.cameras[split.target_view].name} (prior, virtual views, "
          f"refinement; at most {args.bootstrap_minutes:g} min)", flush=True)
    began = time.perf_counter()
    boot_dir = out / "run_bootstrap"
    boot_config = BootstrapConfig(seed=args.seed, iterations=args.bootstrap_iterations,
                                  minutes=args.bootstrap_minutes, prior_minutes=args.prior_minutes,
                                  prior_steps=args.prior_steps, ddim_steps=args.ddim_steps, k=DEMO_K, l=DEMO_L,
                                  generated_weight=DEMO_GENERATED_WEIGHT)
    # The demo's own output folder: a rerun of the demo replaces its previous demo result.
    boot_result = run_bootstrap(run_dir, boot_dir, split_targets(split, scene, 1), boot_config, overwrite=True,
                                log=lambda message: print(f"      {message}", flush=True))
    timings["bootstrap"] = time.perf_counter() - began

    print("[4/5] evaluating stage I and the bootstrap on the held-out views", flush=True)
    stage1_eval = evaluate_run(run_dir, progress=False)
    boot_eval = evaluate_run(boot_dir, progress=False)
    print("stage I\n" + format_table(stage1_eval))
    print("bootstrap\n" + format_table(boot_eval))

    print("[5/5] report", flush=True)
    _target_image(scene, split, run_dir, boot_dir, out / "target.png", args.seed)
    table = make_report([run_dir, boot_dir], out / "report.png")
    boot_summary = json.loads((boot_dir / "bootstrap" / "summary.json").read_text())
    atomic_write_text(out / "report.md", report_markdown(scene, split, stage1_eval, boot_eval, stage1_result,
                                                         boot_result, boot_summary, table, timings))
    print(f"report: {out / 'report.md'}")
    return 0
