"""How photo-consistent a run's geometry is at its held-out views: the geometry term of stage II
(inceptiongs.bootstrap.multiview) evaluated with each held-out view as the virtual view.

    python benchmarks/bench_geometry_term.py RUN [RUN ...] [--k 3]

Per run and group (scarce, covered): the mean NCC of the K nearest training photos' patches
mapped through the rendered depth and planar normal (1 = the photos agree everywhere), and
1 - NCC with the rendered depth scaled by 0.98 ... 1.02 (is the render at the photos' optimum?).
The held-out photos are not read. Used in docs/bootstrap.md to check whether the geometry term
made the geometry more photo-consistent where it was applied, independently of PSNR.
"""

from __future__ import annotations

import argparse
import sys

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import numpy as np
import torch

SCALES = (0.98, 0.99, 1.0, 1.01, 1.02)


def group_figures(run: str, k: int) -> dict:
    from inceptiongs.bootstrap.multiview import GeometrySource, multiview_consistency
    from inceptiongs.bootstrap.runner import load_stage1
    from inceptiongs.bootstrap.virtual_views import nearest_training_views
    from inceptiongs.rasterizer.rasterize import render

    _, scene, split, _, gaussians = load_stage1(run)
    cameras = scene.cameras
    greys = {i: torch.as_tensor(np.asarray(scene.load_image(i)), dtype=torch.float32).mean(-1, keepdim=True)
             for i in split.train}
    figures = {}
    for group in ("scarce_test", "covered_test"):
        ncc, curves = [], []
        for view in getattr(split, group):
            camera = cameras[view]
            with torch.no_grad():
                out = render(gaussians, camera, outputs=("depth", "normal"))
                sources = [GeometrySource(greys[i], cameras[i], render(gaussians, cameras[i], outputs=("depth",))["depth"])
                           for i in nearest_training_views(camera, cameras, list(split.train), k)]
                term = multiview_consistency(out["depth"], out["normal"], camera, sources, samples=None)
                curve = [multiview_consistency(out["depth"] * s, out["normal"], camera, sources, samples=None).loss
                         for s in SCALES]
            if term.loss is not None:
                ncc.append(term.ncc)
                curves.append([float("nan") if c is None else float(c) for c in curve])
        figures[group] = {"ncc": float(np.mean(ncc)) if ncc else float("nan"),
                          "curve": np.nanmean(np.array(curves), 0).tolist() if curves else []}
    return figures


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--k", type=int, default=3, help="source photos per held-out view (stage II's K)")
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    print(f"{'run':<50}{'group':>8}{'mean NCC':>10}   1 - NCC at depth x " + " ".join(f"{s:.2f}" for s in SCALES))
    for run in args.runs:
        for group, row in group_figures(run, args.k).items():
            curve = " ".join(f"{v:.4f}" for v in row["curve"])
            print(f"{run[-50:]:<50}{group.split('_')[0]:>8}{row['ncc']:>10.4f}   {curve}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
