"""Does the leave-one-out estimate (inceptiongs/bootstrap/experimental/validation.py) predict where the blend
beats the render? Scored at a stage-I run's held-out views, treated as virtual views.

    python benchmarks/bench_evidence.py RUN [--k 3] [--photos 6] [--covered 6]

The estimate is measured as the loop measures it (the training photos nearest j*, each blended
from the others); the held-out photos are read only here, to score the prediction, never to make
it. Per held-out view: the share of its pixels the blend trusts and the share on positive
evidence, the estimate's mean margin over its trusted pixels (predicted), and the blend's actual
gain over the render against the held-out photo: on all trusted pixels, on those with positive
evidence, and on the rest (what masking the rest out of the loss gives up). The agreement margin
(agreement.py) of the same blend is printed beside it.
"""

from __future__ import annotations

import argparse
import json

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch

from inceptiongs.bootstrap.config import BootstrapConfig
from inceptiongs.bootstrap.source_depth import depth_from_training_views
from inceptiongs.bootstrap.stage1 import load_stage1
from inceptiongs.bootstrap.supervise import supervise_view
from inceptiongs.bootstrap.view_supervision import ViewContext
from inceptiongs.bootstrap.experimental.validation import (margin_db, measure_evidence, squared_error,
                                                           validation_photos, view_margins)
from inceptiongs.bootstrap.view_targets import ModelRenders
from inceptiongs.bootstrap.virtual_views import nearest_training_views
from inceptiongs.rasterizer.interface import resolve_device
from inceptiongs.threads import use_torch_threads
from inceptiongs.train.step import prepare_data

MIN_PIXELS = 50     # a gain over fewer pixels is not printed


def gain(render_se: torch.Tensor, blend_se: torch.Tensor, selected: torch.Tensor) -> float | None:
    count = int(selected.sum())
    return None if count < MIN_PIXELS else round(margin_db(render_se[selected].sum(), blend_se[selected].sum(),
                                                           count), 2)


def score_view(index: int, grid, cameras, train, images, renders, config) -> dict:
    """The prediction and the actual gain at held-out view ``index`` (module doc)."""
    camera = cameras[index]
    sources = nearest_training_views(camera, cameras, train, config.k)
    supervision = supervise_view(ViewContext(
        config, camera, renders.rgb(camera), sources, cameras, images, renders.depth, renders.rgb,
        source_depth=lambda: depth_from_training_views(camera, cameras, train, config.splat_views, renders.depth)))
    photo = images[index].float()
    blend_se, render_se = squared_error(supervision.image, photo), squared_error(renders.rgb(camera), photo)
    trusted = supervision.mask[..., 0] > 0
    margins = view_margins(grid, camera, renders.depth(camera))
    positive = trusted & (margins > 0)
    known = trusted & ~torch.isnan(margins)
    return {"view": camera.name, "trusted": round(float(trusted.float().mean()), 2),
            "positive": round(float(positive.float().mean()), 2),
            "predicted_db": round(float(margins[known].mean()), 2) if bool(known.any()) else None,
            "gain_trusted_db": gain(render_se, blend_se, trusted),
            "gain_positive_db": gain(render_se, blend_se, positive),
            "gain_rest_db": gain(render_se, blend_se, trusted & ~positive),
            "agreement_db": supervision.report.get("agreement_db")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--k", type=int, default=3, help="photos blended per view")
    parser.add_argument("--photos", type=int, default=6, help="training photos the estimate is measured at")
    parser.add_argument("--covered", type=int, default=6, help="covered held-out views scored as well")
    args = parser.parse_args()
    use_torch_threads()
    run = load_stage1(args.run)
    scene, split = run.scene, run.split
    if split.target_view is None:
        raise SystemExit(f"{args.run}: the split has no target view j* (protocol unstructured needed)")
    images = prepare_data(scene, split, run.config, lambda message: None).images
    renders = ModelRenders(run.gaussians, resolve_device(run.config.device).rasterizer, (run.payload or {}).get("sky"))
    config, cameras, train = BootstrapConfig(k=args.k), list(scene.cameras), list(split.train)
    target = cameras[split.target_view]
    photos = nearest_training_views(target, cameras, validation_photos(target, cameras, train, args.k), args.photos)
    grid = measure_evidence(photos, cameras, train, images, config, renders.depth, renders.rgb)
    print(json.dumps({"estimate": None if grid is None else grid.summary()}, indent=1))
    if grid is not None:
        # One figure a forecast could quote: the photos' margins weighted by their validated pixels.
        weighted = [(p["margin_db"], p["pixels"]) for p in grid.photos if p["margin_db"] is not None]
        total = sum(n for _, n in weighted)
        print("pooled margin over the validation photos:",
              "none" if not total else f"{sum(m * n for m, n in weighted) / total:+.2f} dB over {total} pixels")
    for group, views in (("scarce", split.scarce_test), ("covered", split.covered_test[:args.covered])):
        for index in views:
            print(group, json.dumps(score_view(index, grid, cameras, train, images, renders, config)))


if __name__ == "__main__":
    main()
