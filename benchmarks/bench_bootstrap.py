"""Stage II against stage I continued for the same total time, and the paper's ablations.

    python benchmarks/bench_bootstrap.py [--scenes demo statuette] [--out runs/bench_bootstrap]
        [--stage1-iterations 300] [--stage1-minutes 10] [--stage1-run RUN] [--bootstrap-iterations 200]
        [--prior-minutes 2] [--variants default no-blending uniform-sampling paper-loop-untrained-prior ...]

Per scene (demo: the procedural demo scene at downscale 2; statuette: ../shared/data/statuette
or $INCEPTIONGS_DATA, downscale 4), unstructured protocol, seed fixed:

1. stage I (short-run schedule) into OUT/<scene>/run (reused when it already has model.ply;
   ``--stage1-run RUN`` copies an existing run there whole, its log included, e.g. one trained to its budget);
2. the prior, trained once into OUT/<scene>/run/prior (shared by every variant but the
   untrained-prior ablation; its time is counted in every variant's total);
3. each variant: `run_bootstrap` on j* into OUT/<scene>/<variant> (held-out PSNR/SSIM logged
   over time: quality against bootstrap time);
4. the baseline: the same continuation of stage I on the photos alone (`baseline_run`) for the
   longest variant's total time (prior + generation + refinement); each variant is compared with
   the baseline's final scores (d) and with its curve at the variant's own time (d@time).

Prints the table and writes OUT/bench.json. Targets (for the default): scarce PSNR >= +1.0 dB
over the baseline, scarce SSIM up, covered PSNR >= -0.2 dB.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch

from inceptiongs.threads import use_torch_threads

REPO = Path(__file__).resolve().parents[1]
# The paper's loop: the render's depth, every view used, alternating steps at weight 0.5.
PAPER_LOOP = {"virtual_depth": "render", "agreement_min_db": None, "virtual_every": 2, "lambda_virtual": 0.5}
# The informative pixels (with the photo supervision), added to photo steps, views drawn uniformly.
INFORMATIVE_ADDITIVE = {"variants": {"photo_supervision": {}, "informative": {}, "additive": {}}, "sampling": "uniform"}


def geometry_only(weight: float) -> dict:
    """Only the geometry term at virtual views (no colour target), added to photo steps, drawn uniformly."""
    return {"variants": {"geometry": {"weight": weight, "colour": False}, "additive": {}}, "sampling": "uniform"}


# Each variant: the BootstrapConfig fields it changes from the default (the experimental ones are
# chosen in "variants", each with its options: docs/bootstrap_options.md), named after them.
VARIANTS = {
    # The default: the blend over the render, warped with the depth splatted from the training
    # views (or the render's, whichever places more photos), views the render outvotes left out,
    # every 4th step at weight 1; the conscience.
    "default": {},
    # The paper's I*: the warps (render depth, binary mask, uniform mean) over the prior's image,
    # every view used, every 2nd step at 0.5.
    "paper-loop": {"fill": "prior", **PAPER_LOOP},
    # The paper's ablations.
    "no-blending": {"blending": False},
    "uniform-sampling": {"sampling": "uniform"},
    "paper-loop-untrained-prior": {"prior": "untrained", "fill": "prior", **PAPER_LOOP},
    # Photo supervision (photo-consistent depth, exposure matching, lumigraph weights, soft mask)
    # over the render, in the paper's loop.
    "photo-supervision": {"variants": {"photo_supervision": {}}, **PAPER_LOOP},
    # One ingredient of the default changed at a time.
    "fill-prior": {"fill": "prior"},
    "fill-inpaint": {"variants": {"inpaint": {}}},
    "no-conscience": {"conscience_tolerance": None},
    "render-depth": {"virtual_depth": "render"},
    "no-agreement-gate": {"agreement_min_db": None},
    # I* generated once per round from stage I's render, never regenerated from the refined Gaussians.
    "no-regeneration": {"regenerate_every": 0},
    # Virtual steps learn only from pixels the photos are trusted on (the fill gives no gradient).
    "generated-weight-0": {"generated_weight": 0.0},
    # Generated pixels weighted 0.2 against photo-trusted ones in the paper's loop (a weak
    # CPU-trained prior paints noise where no photo is trusted).
    "paper-loop-generated-weight-0.2": {"fill": "prior", "generated_weight": 0.2, **PAPER_LOOP},
    # Each warp moved onto the render by optical flow before the blend (experimental/align.py).
    "flow-alignment-3px": {"variants": {"align": {"max_shift_px": 3.0}}},
    # Virtual steps learn only where the photos contradict the render (photo_supervision
    # .informative_mask), and only views with such pixels are sampled; no informative view: a photo step.
    "informative-pixels": {"variants": {"photo_supervision": {}, "informative": {}}},
    # ... with uniform sampling (no pose gradient per virtual step: cheaper).
    "informative-pixels-uniform": {"variants": {"photo_supervision": {}, "informative": {}}, "sampling": "uniform"},
    # ... added to a photo step's gradient instead of replacing the photo step ...
    "informative-pixels-additive": INFORMATIVE_ADDITIVE,
    # ... at virtual weight 1 (an informative pixel pulls as hard as a photo's) ...
    "informative-pixels-additive-weight-1": {**INFORMATIVE_ADDITIVE, "lambda_virtual": 1.0},
    # ... and a residual floor of 0.1 (only where the render is grossly wrong).
    "informative-pixels-additive-floor-0.1": {
        **INFORMATIVE_ADDITIVE, "lambda_virtual": 1.0,
        "variants": {**INFORMATIVE_ADDITIVE["variants"], "informative": {"residual_floor": 0.1}}},
    # The geometry term (experimental/multiview.py): 1 - NCC of the source photos mapped through
    # the rendered depth and normal at each virtual view, on top of the default, at weight 0.15
    # (stage I's lambda_ncc) and 0.6 ...
    "geometry-term-0.15": {"variants": {"geometry": {"weight": 0.15}}},
    "geometry-term-0.6": {"variants": {"geometry": {"weight": 0.6}}},
    # ... and alone (no colour target at virtual views) at 0.15, 0.6 and 2.4.
    "geometry-only-0.15": geometry_only(0.15),
    "geometry-only-0.6": geometry_only(0.6),
    "geometry-only-2.4": geometry_only(2.4),
}
# The variants' names in the runs docs/bootstrap.md records, still accepted by --variants.
RECORDED_NAMES = {
    "full": "default", "paper": "paper-loop", "untrained-prior": "paper-loop-untrained-prior",
    "photo": "photo-supervision", "masked": "generated-weight-0",
    "generated-weight-0.2": "paper-loop-generated-weight-0.2", "align": "flow-alignment-3px",
    "informative": "informative-pixels", "informative-uniform": "informative-pixels-uniform",
    "informative-additive": "informative-pixels-additive",
    "informative-additive-x2": "informative-pixels-additive-weight-1",
    "informative-strict": "informative-pixels-additive-floor-0.1",
    "geometry": "geometry-term-0.15", "geometry-x4": "geometry-term-0.6", "geometry-only": "geometry-only-0.15",
    "geometry-only-x4": "geometry-only-0.6", "geometry-only-x16": "geometry-only-2.4",
}


def variant_name(name: str) -> str:
    """A --variants name (a recorded one included) -> its key in VARIANTS."""
    name = RECORDED_NAMES.get(name, name)
    if name not in VARIANTS:
        raise argparse.ArgumentTypeError(f"unknown variant {name!r}; one of: {', '.join(VARIANTS)}")
    return name


def data_root() -> Path | None:
    env = os.environ.get("INCEPTIONGS_DATA")
    for candidate in ([Path(env)] if env else []) + [REPO.parent / "shared" / "data"]:
        if candidate.is_dir():
            return candidate
    return None


def copy_stage1(source: Path, run_dir: Path) -> None:
    """An existing stage-I run copied whole to ``run_dir`` (read-only input stays untouched: a
    prior trained for the benchmark is written beside the copy): config.json, split.json,
    model.ply, its checkpoints (their Adam moments are what the continuation resumes) and its
    metrics.jsonl (the curve the bootstrap's outlook is read from)."""
    import shutil

    from inceptiongs.errors import InputError

    for name in ("config.json", "split.json", "model.ply"):
        if not (source / name).is_file():
            raise InputError(f"{source / name}: --stage1-run needs a finished run (config.json, split.json, model.ply)")
    tmp = run_dir.with_name(run_dir.name + ".copying")
    if tmp.exists():
        shutil.rmtree(tmp)
    shutil.copytree(source, tmp, symlinks=True)
    tmp.rename(run_dir)  # whole or absent: a half copy is never reused


def stage1_run(name: str, out: Path, iterations: int, minutes: float, seed: int, source: Path | None = None) -> Path:
    from inceptiongs.scene.demo import write_demo_scene
    from inceptiongs.runs.config import TrainConfig
    from inceptiongs.train.trainer import train
    from inceptiongs.runs.config import short_run_schedule
    from inceptiongs.io.config_json import with_values

    run_dir = out / name / "run"
    if (run_dir / "model.ply").is_file():
        print(f"[{name}] reusing stage I {run_dir}", flush=True)
        return run_dir
    if source is not None:
        run_dir.parent.mkdir(parents=True, exist_ok=True)
        copy_stage1(source, run_dir)
        print(f"[{name}] stage I copied from {source}", flush=True)
        return run_dir
    if name == "demo":
        scene, downscale = write_demo_scene(out / name / "scene", progress=False), 2
    else:
        root = data_root()
        if root is None or not (root / name).is_dir():
            raise SystemExit(f"{name}: real data not found (set INCEPTIONGS_DATA or ../shared/data)")
        scene, downscale = root / name, 4
    config = short_run_schedule(with_values(
        TrainConfig(scene=str(Path(scene).resolve()), downscale=downscale, protocol="unstructured", seed=seed,
                    iterations=iterations, minutes=minutes), {"output.eval_every": max(iterations // 4, 1)}))
    print(f"[{name}] stage I: {iterations} iterations / {minutes:g} min", flush=True)
    train(config, run_dir, progress=False)
    return run_dir


def train_prior(run_dir: Path, minutes: float, seed: int) -> float:
    """The trained prior shared by the variants: RUN/prior/prior.pt -> seconds spent (0 if reused)."""
    from inceptiongs.prior.model import Prior, PriorConfig
    from inceptiongs.prior.trainer import CHECKPOINT_NAME, PriorTrainer, prior_dir
    from inceptiongs.evaluation.protocols import Split
    from inceptiongs.runs.load import load_run

    seconds_file = prior_dir(run_dir) / "bench_seconds.json"
    if (prior_dir(run_dir) / CHECKPOINT_NAME).is_file() and seconds_file.is_file():
        return float(json.loads(seconds_file.read_text())["seconds"])
    gaussians, scene, _ = load_run(run_dir)
    split = Split.load(run_dir / "split.json", scene.cameras)
    began = time.perf_counter()
    trainer = PriorTrainer(Prior.for_gaussians(PriorConfig(seed=seed), gaussians), gaussians,
                           [scene.cameras[i] for i in split.train], lambda k: scene.load_image(split.train[k]))
    trainer.train(minutes=minutes, run_dir=run_dir, progress=False)
    seconds = time.perf_counter() - began
    seconds_file.write_text(json.dumps({"seconds": seconds, "steps": trainer.step_count}))
    return seconds


def real_step_seconds(run_dir: Path) -> float:
    """Median duration of a real-photo step in a bootstrap log (log_every = 1)."""
    records = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    steps = [r for r in records if "kind" in r]
    gaps = [b["wall_s"] - a["wall_s"] for a, b in zip(steps, steps[1:]) if b["kind"] == "real"]
    gaps.sort()
    return gaps[len(gaps) // 2] if gaps else 1.0


def last_step_wall(run_dir: Path) -> float:
    """The wall second at which the last step of a run (log_every = 1) ended, on its own clock."""
    records = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    steps = [r["wall_s"] for r in records if "kind" in r]
    return steps[-1] if steps else 0.0


def extra_of(config, prior_s: float) -> float:
    """The prior's seconds a variant is charged beside its own run (see bench_scene)."""
    return prior_s if config.needs_prior() and config.prior != "untrained" else 0.0


def eval_curve(run_dir: Path) -> list[dict]:
    records = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [{"wall_s": r["wall_s"], "iteration": r["iteration"],
             **{k: r[k] for k in ("scarce_psnr", "scarce_ssim", "covered_psnr", "covered_ssim") if k in r}}
            for r in records if "scarce_psnr" in r]


def scores(run_dir: Path) -> dict:
    from inceptiongs.evaluation.run import evaluate_run
    from inceptiongs.evaluation.scoring import flat_scores

    return flat_scores(evaluate_run(run_dir, progress=False)["groups"])


def base_config(args):
    from inceptiongs.bootstrap.config import BootstrapConfig

    return BootstrapConfig(seed=args.seed, iterations=args.bootstrap_iterations, ddim_steps=args.ddim_steps,
                           k=args.k, l=args.l, log_every=1, eval_every=max(args.bootstrap_iterations // 4, 1))


def bench_scene(name: str, args) -> dict:
    from inceptiongs.bootstrap.runner import baseline_run, resolve_targets, run_bootstrap
    from inceptiongs.bootstrap.stage1 import load_stage1

    out = Path(args.out)
    source = None
    if args.stage1_run:
        if len(args.scenes) != 1:
            raise SystemExit("--stage1-run names one run: give exactly one --scenes")
        source = Path(args.stage1_run)
    run_dir = stage1_run(name, out, args.stage1_iterations, args.stage1_minutes, args.seed, source)
    configs = {variant: dataclasses.replace(base_config(args), **VARIANTS[variant]) for variant in args.variants}
    prior_s = 0.0
    if any(c.needs_prior() and c.prior != "untrained" for c in configs.values()):
        prior_s = train_prior(run_dir, args.prior_minutes, args.seed)
        print(f"[{name}] prior: {prior_s:.0f} s", flush=True)
    stage1 = load_stage1(run_dir)
    targets = resolve_targets(stage1.scene, stage1.split, None, None, 1)
    warm_up(stage1, out / name / "warm_up", args.seed)
    rows = {"stage I": {"seconds": 0.0, **scores(run_dir)}}
    curves = {}
    for variant, config in configs.items():
        print(f"[{name}] {variant} ...", flush=True)
        result = run_bootstrap(stage1, out / name / variant, targets, config, progress=False, overwrite=True)
        # A prior trained for the run counts towards the time of every variant that uses it.
        extra = extra_of(config, prior_s)
        rows[variant] = {"seconds": result.wall_s + extra, **scores(out / name / variant)}
        curves[variant] = eval_curve(out / name / variant)
    if configs:
        # The baseline runs as long as the longest variant; each variant is also compared with
        # the baseline's curve at its own time (at_same_time).
        longest = max(configs, key=lambda v: rows[v]["seconds"])
        # Until the longest variant's last step: the baseline's time is checked before each step
        # and its own finish (final evaluation, saves) comes after, so the variant's finish is
        # not given to the baseline as step time.
        total_s = extra_of(configs[longest], prior_s) + last_step_wall(out / name / longest)
        step_s = real_step_seconds(out / name / longest)
        iterations = max(1, int(total_s / max(step_s, 1e-3)))
        baseline_dir = out / name / "baseline"
        if args.reuse_baseline and (baseline_dir / "model.ply").is_file():
            seconds = eval_curve(baseline_dir)[-1]["wall_s"]
            print(f"[{name}] baseline reused ({seconds:.0f} s; this run's longest variant: {total_s:.0f} s)", flush=True)
        else:
            print(f"[{name}] baseline: stage I continued {total_s:.0f} s (<= {iterations} steps)", flush=True)
            # The variants' evaluation cadence (every eval_every steps, each in the time): the same
            # bookkeeping per step on both sides.
            seconds = baseline_run(stage1, baseline_dir, total_s / 60.0, iterations, seed=args.seed, progress=False,
                                   eval_every=base_config(args).eval_every, overwrite=True).wall_s
        rows["baseline (same time)"] = {"seconds": seconds, **scores(baseline_dir)}
        curves["baseline (same time)"] = eval_curve(out / name / "baseline")
    return {"rows": rows, "curves": curves, "prior_s": prior_s}


def warm_up(stage1, out_dir: Path, seed: int) -> None:
    """A few untimed baseline steps and an evaluation in this process before anything is timed:
    the first run in a process pays one-off costs (kernels compiled, caches filled; ~15 s on
    the tiny demo scene) that would otherwise be charged to whichever run comes first, here
    always a variant and never the baseline it is compared with."""
    import shutil

    from inceptiongs.bootstrap.runner import baseline_run

    baseline_run(stage1, out_dir, None, 2, seed=seed, progress=False, eval_every=1, overwrite=True,
                 log=lambda line: None)
    shutil.rmtree(out_dir, ignore_errors=True)


def at_same_time(curve: list[dict], seconds: float, key: str) -> float | None:
    """The baseline's ``key`` at ``seconds``, linear between its logged evaluations (held at
    the last one beyond them); None without evaluations."""
    points = [(p["wall_s"], p[key]) for p in curve if key in p]
    if not points:
        return None
    for (t0, v0), (t1, v1) in zip(points, points[1:]):
        if t0 <= seconds <= t1:
            return v0 if t1 <= t0 else v0 + (v1 - v0) * (seconds - t0) / (t1 - t0)
    return points[0][1] if seconds < points[0][0] else points[-1][1]


def table(name: str, result: dict) -> str:
    rows = result["rows"]
    baseline = rows.get("baseline (same time)")
    lines = [f"{name}: held-out PSNR (dB) / SSIM; deltas against the same-time baseline",
             f"{'variant':<38}{'total s':>9}{'scarce':>9}{'ssim':>8}{'covered':>9}{'ssim':>8}"
             f"{'d scarce':>10}{'d covered':>11}{'d@time sc/cov':>15}"]
    curve = result["curves"].get("baseline (same time)", [])
    for variant, row in rows.items():
        delta = lambda key: "" if baseline is None else f"{row[key] - baseline[key]:+.2f}"  # noqa: E731
        same = [at_same_time(curve, row["seconds"], key) for key in ("scarce_psnr", "covered_psnr")]
        at_time = "" if None in same else f"{row['scarce_psnr'] - same[0]:+.2f}/{row['covered_psnr'] - same[1]:+.2f}"
        lines.append(f"{variant:<38}{row['seconds']:>9.0f}{row['scarce_psnr']:>9.2f}{row['scarce_ssim']:>8.4f}"
                     f"{row['covered_psnr']:>9.2f}{row['covered_ssim']:>8.4f}{delta('scarce_psnr'):>10}"
                     f"{delta('covered_psnr'):>11}{at_time:>15}")
    if baseline is not None and "default" in rows:
        full = rows["default"]  # the targets are checked for the default; other variants: the d columns
        checks = [("scarce PSNR >= baseline + 1.0 dB", full["scarce_psnr"] - baseline["scarce_psnr"] >= 1.0),
                  ("scarce SSIM rises", full["scarce_ssim"] > baseline["scarce_ssim"]),
                  ("covered PSNR >= baseline - 0.2 dB", full["covered_psnr"] - baseline["covered_psnr"] >= -0.2)]
        lines += [f"  target {text}: {'met' if ok else 'NOT met'}" for text, ok in checks]
    for variant, curve in result["curves"].items():
        points = ", ".join(f"{p['wall_s']:.0f}s {p['scarce_psnr']:.2f}/{p['covered_psnr']:.2f}" for p in curve)
        lines.append(f"  {variant} scarce/covered PSNR over time: {points}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["demo", "statuette"])
    parser.add_argument("--out", default="runs/bench_bootstrap")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--stage1-iterations", type=int, default=300)
    parser.add_argument("--stage1-minutes", type=float, default=10.0)
    parser.add_argument("--stage1-run", default=None, metavar="RUN",
                        help="start from this existing stage-I run (copied to OUT/<scene>/run; one scene) "
                             "instead of training one")
    parser.add_argument("--bootstrap-iterations", type=int, default=200)
    parser.add_argument("--prior-minutes", type=float, default=2.0)
    parser.add_argument("--ddim-steps", type=int, default=10)
    parser.add_argument("--k", type=int, default=None, help="nearest training views per target (default A's K)")
    parser.add_argument("--l", type=int, default=None, help="poses per training view (default A's L)")
    parser.add_argument("--reuse-baseline", action="store_true",
                        help="reuse OUT/<scene>/baseline from an earlier invocation (same stage I) instead of "
                             "running it again; compare by the d@time column when its time differs")
    parser.add_argument("--variants", nargs="+", type=variant_name, default=list(VARIANTS), metavar="VARIANT",
                        help=f"which variants to run (default: all): {', '.join(VARIANTS)}")
    args = parser.parse_args(argv)
    use_torch_threads()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"machine: {os.cpu_count()} CPUs, load average {load:.1f} at start", flush=True)
    results = {}
    for name in args.scenes:
        results[name] = bench_scene(name, args)
        print(table(name, results[name]), flush=True)
    results["machine"] = {"cpus": os.cpu_count(), "load_start": load,
                          "load_end": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
                          "args": vars(args)}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps(results, indent=1))
    print(f"wrote {out / 'bench.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
