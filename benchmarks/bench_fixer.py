"""The scene-adaptive fixer's held-out check per way of degrading (bootstrap/fixer.py).

    python3 benchmarks/bench_fixer.py OUT [--scene bonsai] [--downscale 8] [--iterations 800]
        [--early 200] [--keep 0.5] [--steps 300] [--held-out 3] [--stage1 RUN]
        [--ways fewer,underfit,left-out] [--left-out-clusters 2] [--left-out-each]
        [--left-out-keep 0]

Stage I on the scene (unstructured protocol, seed 0, short schedule, a checkpoint every
``--early`` steps kept; or ``--stage1 RUN``, an existing run, read only), then per way of
degrading -- "underfit" (the stage-I checkpoint at ``--early``), "fewer" (the final model keeping
``--keep`` of its Gaussians, the most visible), "left-out" (stage I's schedule trained again
without the training photos of ``--left-out-clusters`` of the split's clusters, those whose
sizes are nearest the scarce cluster's: at those poses it renders what it never saw, as the
final model does at the scarce views) -- a fixer trained on the way's views but the
``--held-out`` most isolated ones (the training views; for "left-out" its check is the last
left-out cluster's views, never near a pose it trained on, or with one cluster its
``--held-out`` most isolated views; with ``--left-out-each`` one model per left-out cluster,
each trained without that cluster only, so the fixer learns unseen poses all around the scene;
``--left-out-keep S`` trains on every 1/S-th photo of a left-out cluster still, as the scarce
cluster keeps a few of its photos), and:

* how much the way's errors at the training views resemble the final model's errors at the
  scarce held-out views (RMS distance of the mean log error spectra, decades; the covered
  views' for reference);
* the held-out check: PSNR of the degraded render and of the fixed one at the isolated poses;
* what the loop would get: PSNR of the final render and of the fixed render at the scarce and
  covered test views (measured only; nothing is chosen with them).

Prints the table and writes OUT/bench_fixer.json.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path
from unittest import mock

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import numpy as np
import torch

from inceptiongs.bootstrap.fixer import FixerSettings, build_pairs, error_spectrum, fewer_gaussians, \
    held_out_check, held_out_views, spectrum_distance, train_fixer
from inceptiongs.bootstrap.stage1 import load_stage1
from inceptiongs.gaussians import gaussians_from_params
from inceptiongs.rasterizer.interface import rasterizer_for
from inceptiongs.evaluation.protocols import make_split
from inceptiongs.runs.checkpoint import list_checkpoints, load_checkpoint
from inceptiongs.io.config_json import with_values
from inceptiongs.runs.config import TrainConfig, short_run_schedule
from inceptiongs.threads import use_torch_threads
from inceptiongs.train.trainer import train

DATA = Path(os.environ.get("INCEPTIONGS_DATA") or Path(__file__).resolve().parents[1] / ".." / "shared" / "data")


def stage1(out: Path, scene: Path, downscale: int, iterations: int, early: int) -> Path:
    run_dir = out / "stage1"
    if (run_dir / "model.ply").is_file():
        return run_dir
    config = short_run_schedule(with_values(
        TrainConfig(scene=str(scene.resolve()), downscale=downscale, protocol="unstructured", seed=0,
                    iterations=iterations),
        {"output.checkpoint_every": early, "output.keep_checkpoints": iterations // early + 1,
         "output.eval_every": iterations}))
    train(config, run_dir, progress=False)
    return run_dir


def left_out_clusters(split, count: int) -> list[list[int]]:
    """The training views of the ``count`` clusters (not the scarce one) whose sizes are nearest
    the scarce cluster's held-out count."""
    scarce, train = set(split.scarce_test), set(split.train)
    clusters = [[v for v in cluster if v in train] for cluster in split.clusters if not scarce & set(cluster)]
    if len(clusters) < count:
        raise SystemExit(f"the left-out way needs {count} clusters besides the scarce one (unstructured protocol)")
    return sorted(clusters, key=lambda cluster: abs(len(cluster) - len(scarce)))[:count]


def left_out_model(out: Path, config, views: list[int]) -> Path:
    """Stage I's config trained again into OUT/left_out_FIRST_N (its first view, how many) with
    ``views`` left out of its training views (its held-out views as stage I's: the split is stage
    I's, less ``views``)."""
    run_dir = out / f"left_out_{min(views)}_{len(views)}"
    if (run_dir / "model.ply").is_file():
        return run_dir
    gone = set(views)

    def without(*args, **kwargs):
        split = make_split(*args, **kwargs)
        clusters = [[v for v in cluster if v not in gone] for cluster in split.clusters]
        return replace(split, train=[v for v in split.train if v not in gone],
                       clusters=[cluster for cluster in clusters if cluster],
                       excluded=sorted(set(split.excluded) | gone))

    with mock.patch("inceptiongs.train.trainer.make_split", without):
        train(config, run_dir, progress=False)
    return run_dir


def mean_spectrum(render, photos: dict, views) -> np.ndarray:
    return np.mean([error_spectrum(render(v), photos[v]) for v in views], axis=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--scene", default="bonsai")
    parser.add_argument("--downscale", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=800)
    parser.add_argument("--early", type=int, default=200)
    parser.add_argument("--keep", type=float, default=0.5)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--held-out", type=int, default=3)
    parser.add_argument("--stage1", type=Path, help="an existing stage-I run to use (read only)")
    parser.add_argument("--ways", default="fewer,underfit,left-out")
    parser.add_argument("--left-out-clusters", type=int, default=2)
    parser.add_argument("--left-out-keep", type=float, default=0.0,
                        help="share of each left-out cluster's photos still trained on (evenly spaced)")
    parser.add_argument("--left-out-each", action="store_true",
                        help="one left-out model per cluster (each without that cluster only)")
    args = parser.parse_args()
    use_torch_threads()
    wanted = args.ways.split(",")
    began = time.perf_counter()
    run_dir = args.stage1 or stage1(args.out, DATA / args.scene, args.downscale, args.iterations, args.early)
    stage1_s = time.perf_counter() - began
    run = load_stage1(run_dir)
    cameras, split = run.scene.cameras, run.split
    rasterizer = rasterizer_for("cpu")
    views = list(split.train) + list(split.test)
    photos = {v: torch.as_tensor(run.scene.load_image(v)) for v in views}
    early = [path for it, path in list_checkpoints(run_dir) if it == args.early]
    held = held_out_views(np.array([c.center for c in cameras]), split.train, args.held_out)
    fit = [v for v in split.train if v not in held]
    ways = {}       # way -> (degraded model, its fixer's training views, its check's views)
    if "fewer" in wanted:
        ways["fewer"] = (fewer_gaussians(run.gaussians, args.keep), fit, held)
    if "underfit" in wanted and early:
        ways["underfit"] = (gaussians_from_params(load_checkpoint(early[0])["params"]), fit, held)
    left_s = 0.0
    if "left-out" in wanted:
        clusters = left_out_clusters(split, args.left_out_clusters)
        if args.left_out_keep > 0.0:    # each cluster keeps evenly spaced photos, as the scarce one keeps a few
            clusters = [[v for v in cluster if v not in cluster[::max(1, round(1 / args.left_out_keep))]]
                        for cluster in clusters]
        left_began = time.perf_counter()
        if args.left_out_each:     # each cluster's poses rendered by the model trained without it
            models = [load_stage1(left_out_model(args.out, run.config, cluster)).gaussians for cluster in clusters]
            owner = {v: i for i, cluster in enumerate(clusters) for v in cluster}
            left = lambda v: models[owner[v]]     # noqa: E731
        else:
            left = load_stage1(left_out_model(args.out, run.config, sum(clusters, []))).gaussians
        left_s = time.perf_counter() - left_began
        if len(clusters) > 1:
            left_held = clusters[-1]
        else:
            left_held = held_out_views(np.array([c.center for c in cameras]), clusters[0], args.held_out)
        ways["left-out"] = (left, [v for v in sum(clusters, []) if v not in left_held], left_held)

    def renderer(gaussians):
        """gaussians: a model, or view -> the model that renders it."""
        cache = {}

        def render(v):
            if v not in cache:
                model = gaussians(v) if callable(gaussians) else gaussians
                with torch.no_grad():
                    cache[v] = rasterizer(model, cameras[v], outputs=("rgb",))["rgb"].float().clamp(0, 1)
            return cache[v]
        return render

    final = renderer(run.gaussians)
    scarce_spectrum = mean_spectrum(final, photos, split.scarce_test)
    covered_spectrum = mean_spectrum(final, photos, split.covered_test)
    rows = []
    for way, (gaussians, fit, held) in ways.items():
        degraded = renderer(gaussians)
        spectrum = mean_spectrum(degraded, photos, fit)
        trained = train_fixer(build_pairs(degraded, photos, fit), FixerSettings(steps=args.steps))
        check = held_out_check(trained.net, build_pairs(degraded, photos, held))
        scarce = held_out_check(trained.net, build_pairs(final, photos, split.scarce_test))
        covered = held_out_check(trained.net, build_pairs(final, photos, split.covered_test))
        rows.append({"way": way, "fit_views": len(fit), "held_out": held, "spectrum_to_scarce": spectrum_distance(spectrum, scarce_spectrum),
                     "spectrum_to_covered": spectrum_distance(spectrum, covered_spectrum),
                     "loss_first": float(np.mean(trained.losses[:10])), "loss_last": float(np.mean(trained.losses[-10:])),
                     "train_s": trained.seconds,
                     "check_render_db": float(np.mean(check.render_db)), "check_fixed_db": float(np.mean(check.fixed_db)),
                     "check_passes": check.passes,
                     "scarce_render_db": float(np.mean(scarce.render_db)), "scarce_fixed_db": float(np.mean(scarce.fixed_db)),
                     "covered_render_db": float(np.mean(covered.render_db)),
                     "covered_fixed_db": float(np.mean(covered.fixed_db))})
    print(f"{args.scene} at downscale {args.downscale}, stage I {args.iterations} steps ({stage1_s:.0f} s), "
          f"scarce {list(split.scarce_test)}, fixer {args.steps} steps"
          + (f", left-out model {left_s:.0f} s" if left_s else ""))
    print(f"{'way':<10}{'fit':>5}{'spec->sc':>9}{'spec->cov':>10}{'L1 0->end':>14}{'check r/f':>16}{'pass':>6}"
          f"{'scarce r/f':>16}{'covered r/f':>16}{'train s':>9}")
    for r in rows:
        print(f"{r['way']:<10}{r['fit_views']:>5}{r['spectrum_to_scarce']:>9.3f}{r['spectrum_to_covered']:>10.3f}"
              f"{r['loss_first']:>7.4f}{r['loss_last']:>7.4f}{r['check_render_db']:>8.2f}{r['check_fixed_db']:>8.2f}"
              f"{str(r['check_passes']):>6}{r['scarce_render_db']:>8.2f}{r['scarce_fixed_db']:>8.2f}"
              f"{r['covered_render_db']:>8.2f}{r['covered_fixed_db']:>8.2f}{r['train_s']:>9.0f}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_fixer.json").write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()},
                                                           "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
