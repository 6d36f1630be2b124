"""`inceptiongs demo OUT [--minutes M]`: the main job on the built-in demo scene.

OUT/scene   the procedural demo scene (COLMAP binary + photos, ground-truth cameras)
OUT/run     stage I trained with the unstructured protocol (the run folder contract)
OUT/run/eval/  render | photo | error images of the held-out views + eval.json
OUT/before_target.png  the target view j* rendered from the initial Gaussians (before training)
OUT/report.png  test PSNR against run time and iterations
OUT/summary.md  the metrics table and where the images are
"""

from __future__ import annotations

import json
from pathlib import Path

HELP = "main job on the built-in demo scene: write it, train stage I, evaluate, report"

DEFAULT_MINUTES = 2.5
# Evaluations every this many iterations: a 2-3 minute CPU run makes a few hundred steps,
# so this gives the report several points without evaluation dominating the run.
DEMO_EVAL_EVERY = 50


def add_arguments(parser) -> None:
    parser.add_argument("out", help="output folder (scene, run, report, summary)")
    parser.add_argument("--minutes", type=float, default=DEFAULT_MINUTES,
                        help=f"stage-I training time budget (default {DEFAULT_MINUTES})")
    parser.add_argument("--iterations", type=int, default=None,
                        help="stop after this many iterations instead (whichever comes first)")
    parser.add_argument("--size", choices=("small", "medium"), default="small", help="demo scene size")
    parser.add_argument("--seed", type=int, default=0, help="scene, split and training seed")


def _write_before_image(scene, split, out_path: Path, seed: int) -> None:
    """Target view j* from the trainer's initial Gaussians: render | photo | error."""
    import torch

    from ..evaluate import side_by_side, write_png
    from ..rasterize import render
    from ..train.init_gaussians import initial_gaussians

    gaussians, _ = initial_gaussians([scene.cameras[i] for i in split.train], scene.points,
                                     scene.point_colors, 0, seed)
    with torch.no_grad():
        rgb = render(gaussians, scene.cameras[split.target_view])["rgb"].clamp(0, 1).numpy()
    write_png(out_path, side_by_side(rgb, scene.load_image(split.target_view)))


def _metrics_rows(summary: dict) -> list[str]:
    def cell(value, digits):
        if value is None:
            return "-"
        if isinstance(value, str):
            return value
        return f"{value:.{digits}f}"

    rows = ["| held-out views | count | PSNR (dB) | SSIM |", "| --- | ---: | ---: | ---: |"]
    for group in ("scarce", "covered", "all"):
        entry = summary["groups"][group]
        rows.append(f"| {group} | {entry['views']} | {cell(entry['psnr'], 2)} | {cell(entry['ssim'], 4)} |")
    return rows


def summary_markdown(scene, split, summary: dict, result, table: str) -> str:
    """OUT/summary.md text; paths relative to OUT."""
    target = split.target_view
    target_name = scene.cameras[target].name
    target_image = next(v["image"] for v in summary["views"] if v["index"] == target)
    meta_path = Path(scene.root) / "demo_scene.json"
    designed = json.loads(meta_path.read_text()).get("scarce_cameras", []) if meta_path.is_file() else []
    lines = [
        "# InceptionGS demo",
        "",
        f"- scene: `scene/` ({len(scene.cameras)} views, {scene.cameras[0].width}x{scene.cameras[0].height}; "
        f"cameras the scene generator made scarce: {', '.join(designed) or 'none'})",
        f"- stage I run: `run/` ({result.iteration} iterations, {result.num_gaussians} Gaussians, "
        f"unstructured protocol, seed {split.seed}: {len(split.train)} training views, "
        f"{len(split.scarce_test)} scarce + {len(split.covered_test)} covered held out)",
        f"- scarce cluster: views {', '.join(str(i) for i in split.scarce_cluster)}; "
        f"target view j* = {target} (`{target_name}`)",
        "",
        "## Stage I on the held-out views",
        "",
        *_metrics_rows(summary),
        "",
        f"LPIPS: {summary['lpips']}. FID: {summary['fid']}.",
        "",
        "## Images (render | photo | error)",
        "",
        "- before (initial Gaussians from the sparse points), target view: `before_target.png`",
        f"- after stage I, target view: `run/{target_image}`",
        "- every held-out view: `run/eval/`",
        "",
        "## Error against run time",
        "",
        "`report.png`",
        "",
        "```",
        table,
        "```",
        "",
    ]
    return "\n".join(lines)


def run(args) -> int:
    from ..atomic import atomic_write_text
    from ..demo_scene import write_demo_scene
    from ..errors import InputError
    from ..evaluate import evaluate_run, format_table
    from ..protocols import Split
    from ..report import make_report
    from ..scene import load_scene
    from ..train import TrainConfig, train

    if args.minutes <= 0:
        raise InputError(f"--minutes: must be positive, got {args.minutes}")
    if args.iterations is not None and args.iterations < 1:
        raise InputError(f"--iterations: must be >= 1, got {args.iterations}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    scene_dir = write_demo_scene(out / "scene", size=args.size, seed=args.seed)
    run_dir = out / "run"
    config = TrainConfig(scene=str(scene_dir.resolve()), protocol="unstructured", seed=args.seed,
                         minutes=args.minutes, eval_every=DEMO_EVAL_EVERY)
    if args.iterations is not None:
        config.iterations = args.iterations
    result = train(config, run_dir)

    summary = evaluate_run(run_dir)
    print(format_table(summary))
    scene = load_scene(config.scene)
    split = Split.load(run_dir / "split.json", scene.cameras)
    _write_before_image(scene, split, out / "before_target.png", args.seed)
    table = make_report([run_dir], out / "report.png")
    print(table)
    atomic_write_text(out / "summary.md", summary_markdown(scene, split, summary, result, table))
    print(f"summary: {out / 'summary.md'}")
    return 0
