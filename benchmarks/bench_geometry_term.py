"""How photo-consistent a run's geometry is at its held-out views: the geometry term of stage II
(inceptiongs.bootstrap.experimental.multiview) evaluated with each held-out view as the virtual view.

    python benchmarks/bench_geometry_term.py RUN [RUN ...] [--k 3]

Per run and group (scarce, covered): the mean NCC of the K nearest training photos' patches
mapped through the rendered depth and planar normal (1 = the photos agree everywhere), and
1 - NCC with the rendered depth scaled by 0.98 ... 1.02 (is the render at the photos' optimum?).
The held-out photos are read only for the last columns: how much of the render's squared error
lies within EDGE_BAND px of a depth edge (silhouettes), and the PSNR there and elsewhere.
Used in docs/bootstrap.md to check whether the geometry term
made the geometry more photo-consistent where it was applied, independently of PSNR.
"""

from __future__ import annotations

import argparse
import sys

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import numpy as np
import torch

SCALES = (0.98, 0.99, 1.0, 1.01, 1.02)
# Depth edges: neighbouring rendered depths differing by more than this (relative), or a
# surface next to background; the band around them is EDGE_BAND pixels wide on each side.
EDGE_JUMP = 0.05
EDGE_BAND = 2


def edge_band(depth: torch.Tensor) -> torch.Tensor:
    """depth [h, w, 1] -> [h, w] bool: within EDGE_BAND px of a depth edge (see EDGE_JUMP)."""
    import torch.nn.functional as F

    d = depth[..., 0]

    def jump(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        near = torch.maximum(a, b)  # > 0 where either pixel has depth; both 0: no edge
        return (near > 0) & ((a - b).abs() > EDGE_JUMP * near)

    edge = torch.zeros_like(d, dtype=torch.bool)
    horizontal, vertical = jump(d[:, :-1], d[:, 1:]), jump(d[:-1], d[1:])
    edge[:, :-1] |= horizontal
    edge[:, 1:] |= horizontal
    edge[:-1] |= vertical
    edge[1:] |= vertical
    size = 2 * EDGE_BAND + 1
    return F.max_pool2d(edge[None, None].float(), size, stride=1, padding=EDGE_BAND)[0, 0] > 0


def psnr_of(squared_error: torch.Tensor) -> float:
    """PSNR (dB) of a mean squared error of [0, 1] images; the floor keeps log finite for a perfect match."""
    return float(-10.0 * torch.log10(squared_error.clamp_min(1e-10)))


def group_figures(run: str, k: int) -> dict:
    from inceptiongs.bootstrap.experimental.multiview import GeometrySource, multiview_consistency
    from inceptiongs.bootstrap.stage1 import load_stage1
    from inceptiongs.bootstrap.virtual_views import nearest_training_views
    from inceptiongs.rasterizer.interface import cpu_rasterizer

    stage1 = load_stage1(run)
    render = cpu_rasterizer()   # the CPU's best, through the registry
    scene, split, gaussians = stage1.scene, stage1.split, stage1.gaussians
    cameras = scene.cameras
    greys = {i: torch.as_tensor(np.asarray(scene.load_image(i)), dtype=torch.float32).mean(-1, keepdim=True)
             for i in split.train}
    figures = {}
    for group in ("scarce_test", "covered_test"):
        ncc, curves, edges = [], [], []
        for view in getattr(split, group):
            camera = cameras[view]
            with torch.no_grad():
                out = render(gaussians, camera, outputs=("depth", "normal"))
                sources = [GeometrySource(greys[i], cameras[i], render(gaussians, cameras[i], outputs=("depth",))["depth"])
                           for i in nearest_training_views(camera, cameras, list(split.train), k)]
                term = multiview_consistency(out["depth"], out["normal"], camera, sources, samples=None)
                rgb = render(gaussians, camera)["rgb"].clamp(0.0, 1.0)
                photo = torch.as_tensor(np.asarray(scene.load_image(view)), dtype=torch.float32)
                error = ((rgb - photo) ** 2).mean(-1)                                      # [h, w]
                band = edge_band(out["depth"])
                edges.append((float(error[band].sum() / error.sum().clamp_min(1e-12)), float(band.float().mean()),
                              psnr_of(error[band].mean()) if bool(band.any()) else float("nan"),
                              psnr_of(error[~band].mean()) if bool((~band).any()) else float("nan")))
                curve = [multiview_consistency(out["depth"] * s, out["normal"], camera, sources, samples=None).loss
                         for s in SCALES]
            if term.loss is not None:
                ncc.append(term.ncc)
                curves.append([float("nan") if c is None else float(c) for c in curve])
        figures[group] = {"ncc": float(np.mean(ncc)) if ncc else float("nan"),
                          "curve": np.nanmean(np.array(curves), 0).tolist() if curves else [],
                          # share of the squared error within the edge band, the band's share of
                          # the pixels, PSNR in the band and off it (means over the group's views)
                          "edges": np.nanmean(np.array(edges), 0).tolist() if edges else []}
    return figures


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--k", type=int, default=3, help="source photos per held-out view (stage II's K)")
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    print(f"{'run':<50}{'group':>8}{'mean NCC':>10}   1 - NCC at depth x " + " ".join(f"{s:.2f}" for s in SCALES)
          + f"   | error share / pixel share / PSNR within {EDGE_BAND} px of a depth edge / PSNR elsewhere")
    for run in args.runs:
        for group, row in group_figures(run, args.k).items():
            curve = " ".join(f"{v:.4f}" for v in row["curve"])
            edges = " / ".join(f"{v:.2f}" for v in row["edges"])
            print(f"{run[-50:]:<50}{group.split('_')[0]:>8}{row['ncc']:>10.4f}   {curve}   | {edges}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
