"""How good is the supervision stage II can give? An oracle check on the held-out views.

Stage II refines the Gaussians towards I* at virtual views. A held-out view has a photo, so
treating it *as* a virtual view measures how close each candidate I* comes to the truth there,
before any refinement: if I* is no better than the render, refining on it cannot lift the
held-out scores far. Per held-out view of RUN (scarce cluster / covered views), against its
photo:

- ``render``: the stage-I render (what the view shows now);
- ``blend(render)``: the K nearest training photos warped in (the bootstrap's warp and
  trusted-pixel mask), the render elsewhere: what blending alone gives;
- ``repair``: the prior's repair of the render (RUN/prior/prior.pt, its default sampling);
- ``I*``: the repair with the warped photos blended in: exactly what the bootstrap trains on;
- ``trusted``: PSNR on the trusted pixels only, warped photos vs the render there, and the
  trusted fraction M.

    python benchmarks/bench_supervision.py RUN [--ddim-steps 10] [--k 3] [--delta 0.03]

Prints a table per group (mean over views) and writes nothing. No photo of a held-out view is
used for anything but its score.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

SOURCES = ("render", "blend(render)", "repair", "I*")


def scores_at(view: int, scene, split, gaussians, prior, args, depths: dict) -> dict:
    """One held-out view's scores; depths: {camera name: rendered depth}, shared across views
    (a training view is a warp source of several held-out views)."""
    from inceptiongs.bootstrap.generation import blend_target
    from inceptiongs.bootstrap.virtual_views import nearest_training_views
    from inceptiongs.rasterizer.rasterize import render_rgb
    from inceptiongs.evaluation.generated import photo_of, score
    from inceptiongs.evaluation.metrics import psnr
    from inceptiongs.rasterizer.rasterize import render

    camera = scene.cameras[view]
    photo = photo_of(scene, view)
    rendered = render_rgb(gaussians, camera)
    sources = nearest_training_views(camera, scene.cameras, list(split.train), args.k)
    photos = {i: photo_of(scene, i) for i in sources}

    def render_depth(cam):
        if cam.name not in depths:
            with torch.no_grad():
                depths[cam.name] = render(gaussians, cam, outputs=("depth",))["depth"]
        return depths[cam.name]

    blend = lambda base: blend_target(base.numpy(), camera, sources, scene.cameras, photos,  # noqa: E731
                                      render_depth, True, args.delta)
    blended, mask = blend(rendered)
    with torch.no_grad():
        repaired, _ = prior.generate(gaussians, camera, steps=args.ddim_steps, seed=args.seed)
    repaired = repaired.detach().float().clamp(0, 1)
    target, _ = blend(repaired)
    row = {name: score(image, photo) for name, image in
           zip(SOURCES, (rendered, blended, repaired, target))}
    trusted = mask[..., 0] > 0
    row["mask"] = float(mask.mean())
    if trusted.any():
        row["trusted_warp"] = float(psnr(blended, photo, mask))
        row["trusted_render"] = float(psnr(rendered, photo, mask))
    return row


def main(argv=None) -> int:
    from inceptiongs.bootstrap.runner import load_stage1
    from inceptiongs.bootstrap.virtual_views import DEFAULT_K
    from inceptiongs.bootstrap.warp import DEFAULT_DELTA
    from inceptiongs.evaluation.scoring import GROUPS, group_of
    from inceptiongs.prior.trainer import load_prior

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", help="a stage-I run with a split and a trained prior (RUN/prior/prior.pt)")
    parser.add_argument("--ddim-steps", type=int, default=10, help="the bootstrap's default")
    parser.add_argument("--k", type=int, default=DEFAULT_K, help="training photos warped into each view")
    parser.add_argument("--delta", type=float, default=DEFAULT_DELTA, help="the warp's depth tolerance")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    _, scene, split, _, gaussians = load_stage1(Path(args.run))
    prior = load_prior(Path(args.run))
    rows, depths = {}, {}
    for view in split.test:
        rows[view] = scores_at(view, scene, split, gaussians, prior, args, depths)
        print(f"  {scene.cameras[view].name} ({group_of(view, split)}): "
              + "  ".join(f"{s} {rows[view][s]['psnr']:.2f}/{rows[view][s]['ssim']:.3f}" for s in SOURCES),
              flush=True)
    print(f"\n{args.run}: held-out views as virtual views; PSNR (dB) / SSIM against their photos")
    print(f"{'group':<9}{'views':>6}" + "".join(f"{s:>17}" for s in SOURCES) + f"{'M':>6}{'trusted warp/render':>22}")
    for group in GROUPS:
        members = [rows[v] for v in rows if group_of(v, split) == group]
        if not members:
            continue
        mean = lambda key, metric: sum(m[key][metric] for m in members) / len(members)  # noqa: E731
        trusted = [m for m in members if "trusted_warp" in m]
        cells = "".join(f"{mean(s, 'psnr'):>10.2f}/{mean(s, 'ssim'):.3f}" for s in SOURCES)
        warp = (f"{sum(m['trusted_warp'] for m in trusted) / len(trusted):>13.2f}/"
                f"{sum(m['trusted_render'] for m in trusted) / len(trusted):.2f}") if trusted else f"{'-':>22}"
        print(f"{group:<9}{len(members):>6}{cells}{sum(m['mask'] for m in members) / len(members):>6.2f}{warp}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
