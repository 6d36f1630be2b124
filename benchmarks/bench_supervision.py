"""How good is the supervision stage II can give? An oracle check on the held-out views.

Stage II refines the Gaussians towards I* at virtual views. A held-out view has a photo, so
treating it *as* a virtual view measures how close each candidate I* comes to the truth there,
before any refinement: if I* is no better than the render, refining on it cannot lift the
held-out scores. Per held-out view of RUN (scarce cluster / covered views), against its photo,
each ingredient on its own:

- ``render``: the stage-I render (what the view shows now);
- ``blend``: the paper's blending (K nearest photos warped with the stage-I depth, binary
  trusted-pixel mask, uniform mean) over the render;
- ``blend+flow``: the blend with each warp first moved onto the render by optical flow
  (align.py; shifts beyond ``--align-px`` untrusted); ``splat+flow``: the same for ``splat``;
- ``splat``: the same blend, the view's depth splatted from its nearest training views' depths
  (source_depth.py, ``--virtual-depth sources``); ``splat+inp``: and the blend inpainted into
  the pixels no photo reaches (the variant ``inpaint``);
- ``+depth``: the same warps placed with the photo-consistent depth (photo_depth.py), uniform
  mean, soft mask, over the render;
- ``+lumi``: lumigraph weights instead of the uniform mean;
- ``+expo``: and exposure matching (the full photo supervision), over the render;
- ``inpaint``: the full photo supervision with the inpainting fill;
- ``+inform``: the blend only on the informative pixels (trusted, depth confirmed, the photos
  disagreeing with the render by more than among themselves), the render elsewhere: what a
  virtual step with the variant ``informative`` pulls towards;
- ``repair``: the prior's repair of the render (needs a prior: RUN/prior/prior.pt or --prior-run);
- ``I*blend``: the bootstrap's default I*: the paper's blending over the repair;
- ``I*photo``: the photo supervision over the repair (the variant ``photo_supervision``, fill ``prior``).

Trusted-pixel columns compare the photos with the render *on the pixels the supervision
trusts* (binary mask > 0 for blend, soft mask >= 0.5 for photo): the warps must beat the render
there, or blending cannot help (``inform``: the informative pixels; ``inform-flat``: those
more than 2 px from a depth edge of the render).

Depths are the scene's own surface (the sky shell left out; ``--blended-depth``: the render's
blended depth, sky shell included).

    python benchmarks/bench_supervision.py RUN [--prior-run RUN2] [--ddim-steps 10] [--k 3]
        [--search 0.1] [--steps 21] [--residual-floor F] [--views N]

Prints a table per group (mean over views) and writes nothing. No photo of a held-out view is
used for anything but its score.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import inceptiongs  # noqa: E402,F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch  # noqa: E402

WITHOUT_PRIOR = ("render", "blend", "blend+flow", "splat", "splat+flow", "splat+inp", "+depth", "+lumi", "+expo", "inpaint", "+inform")
WITH_PRIOR = ("repair", "I*blend", "I*photo")
TRUSTED = ("blend", "blend+flow", "splat", "splat+flow", "photo", "inform", "inform-flat")


# A relative depth jump above this between neighbouring pixels is an occlusion edge ...
EDGE_JUMP = 0.05
# ... and pixels within this many pixels of one are "near" it (the 5 x 5 NCC window's radius).
EDGE_RADIUS = 2


def near_depth_edges(depth: torch.Tensor) -> torch.Tensor:
    """depth [h, w] camera z -> [h, w] bool: within EDGE_RADIUS pixels of a relative depth jump
    above EDGE_JUMP (or of a pixel without depth). A diagnostic: where do the warps fail?"""
    valid = depth > 0
    safe = torch.where(valid, depth, torch.ones_like(depth))  # no division by 0 below
    jump = torch.zeros_like(depth, dtype=torch.bool)
    jump[:, 1:] |= (safe[:, 1:] - safe[:, :-1]).abs() > EDGE_JUMP * torch.minimum(safe[:, 1:], safe[:, :-1])
    jump[1:] |= (safe[1:] - safe[:-1]).abs() > EDGE_JUMP * torch.minimum(safe[1:], safe[:-1])
    jump |= ~valid
    size = 2 * EDGE_RADIUS + 1
    return torch.nn.functional.max_pool2d(jump.float()[None, None], size, 1, EDGE_RADIUS)[0, 0] > 0


def scores_at(view: int, scene, split, gaussians, prior, args, depths: dict, sky=None) -> dict:
    """One held-out view's scores; depths: {camera name: rendered depth}, shared across views
    (a training view is a warp source of several held-out views)."""
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.source_depth import depth_from_training_views
    from inceptiongs.bootstrap.supervise import ViewContext, supervise_view
    from inceptiongs.bootstrap.experimental.photo_supervision import Source, supervise
    from inceptiongs.bootstrap.virtual_views import nearest_training_views
    from inceptiongs.evaluation.generated import photo_of, score
    from inceptiongs.evaluation.metrics import psnr
    from inceptiongs.rasterizer.interface import cpu_rasterizer, render_rgb
    from inceptiongs.train.free_space import render_surface_depth

    render = cpu_rasterizer()   # the CPU's best, through the registry
    camera = scene.cameras[view]
    photo = photo_of(scene, view)
    rendered = render_rgb(gaussians, camera, render)
    sources = nearest_training_views(camera, scene.cameras, list(split.train), args.k)
    photos = {i: photo_of(scene, i) for i in sources}

    def render_depth(cam):
        if cam.name not in depths:
            with torch.no_grad():
                depths[cam.name] = (render(gaussians, cam, outputs=("depth",))["depth"] if args.blended_depth
                                    else render_surface_depth(gaussians, cam, sky))
        return depths[cam.name]

    def blend(base, virtual_depth: str = "render", **fields):
        config = BootstrapConfig(virtual_depth=virtual_depth, delta=args.delta, **fields)
        out = supervise_view(ViewContext(config, camera, base.numpy(), sources, scene.cameras, photos, render_depth,
                                         source_depth=lambda: splatted))
        return out.image, out.mask

    splatted = depth_from_training_views(camera, scene.cameras, split.train, args.splat_views, render_depth)
    photo_sources = [Source(photos[i], scene.cameras[i], render_depth(scene.cameras[i])) for i in sources]
    dst_depth = render_depth(camera)
    photo_run = lambda **kw: supervise(camera, rendered, dst_depth, photo_sources, delta=args.delta,  # noqa: E731
                                       search=args.search, steps=args.steps,
                                       residual_floor=args.residual_floor, **kw)

    began = time.perf_counter()
    images = {"render": rendered}
    images["blend"], blend_mask = blend(rendered)
    flow = {"align": {"max_shift_px": args.align_px}}       # the variant "align"
    images["blend+flow"], blend_flow_mask = blend(rendered, variants=flow)
    images["splat"], splat_mask = blend(rendered, "sources")
    images["splat+flow"], splat_flow_mask = blend(rendered, "sources", variants=flow)
    images["splat+inp"], _ = blend(rendered, "sources", variants={"inpaint": {}})
    images["+depth"] = photo_run(fill="render", lumigraph=False, exposure=False).target
    images["+lumi"] = photo_run(fill="render", exposure=False).target
    full = photo_run(fill="render")
    images["+expo"] = full.target
    images["inpaint"] = photo_run(fill="inpaint").target
    images["+inform"] = (full.informative * full.blended + (1.0 - full.informative) * rendered).clamp(0, 1)
    row = {"photo_s": time.perf_counter() - began}
    if prior is not None:
        with torch.no_grad():
            repaired, _ = prior.generate(gaussians, camera, steps=args.ddim_steps, seed=args.seed)
        images["repair"] = repaired.detach().float().clamp(0, 1)
        images["I*blend"], _ = blend(images["repair"])
        images["I*photo"] = photo_run(fill="prior", generated=images["repair"]).target
    row.update({name: score(image, photo) for name, image in images.items()})
    edges = near_depth_edges(dst_depth[..., 0])
    # The blend columns are judged by their own image on their own mask, the rest by the photo
    # supervision's blend.
    blend_masks = {"blend": blend_mask, "blend+flow": blend_flow_mask, "splat": splat_mask, "splat+flow": splat_flow_mask}
    trusted = {**{name: m[..., 0] > 0 for name, m in blend_masks.items()},
               "photo": full.mask[..., 0] >= 0.5, "inform": full.informative[..., 0] > 0,
               "inform-flat": (full.informative[..., 0] > 0) & ~edges}
    for name, mask in trusted.items():
        row[f"{name}_trusted_fraction"] = float(mask.float().mean())
        if mask.any():
            warped = images[name] if name in blend_masks else full.blended
            row[f"{name}_trusted_warp"] = float(psnr(warped, photo, mask))
            row[f"{name}_trusted_render"] = float(psnr(rendered, photo, mask))
    return row


def main(argv=None) -> int:
    from inceptiongs.bootstrap.experimental.align import DEFAULT_MAX_SHIFT_PX
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.stage1 import load_stage1
    from inceptiongs.bootstrap.virtual_views import DEFAULT_K
    from inceptiongs.bootstrap.experimental.photo_depth import DEFAULT_SEARCH, DEFAULT_STEPS
    from inceptiongs.bootstrap.experimental.photo_supervision import RESIDUAL_FLOOR
    from inceptiongs.bootstrap.warp import DEFAULT_DELTA
    from inceptiongs.evaluation.scoring import GROUPS, group_of
    from inceptiongs.prior.trainer import load_prior

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", help="a stage-I run with a split")
    parser.add_argument("--prior-run", default=None,
                        help="folder whose prior/prior.pt to use (default RUN; e.g. the bootstrap's output, "
                             "which trains one when the run has none). Without a prior the prior rows are left out")
    parser.add_argument("--ddim-steps", type=int, default=10, help="the bootstrap's default")
    parser.add_argument("--k", type=int, default=DEFAULT_K, help="training photos warped into each view")
    parser.add_argument("--delta", type=float, default=DEFAULT_DELTA, help="the warp's depth tolerance")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--search", type=float, default=DEFAULT_SEARCH,
                        help="depth sweep: relative half-width around the stage-I depth")
    parser.add_argument("--steps", type=int, default=DEFAULT_STEPS, help="depth sweep: hypotheses")
    parser.add_argument("--residual-floor", type=float, default=RESIDUAL_FLOOR,
                        help="informative pixels: the residual floor (supervision.RESIDUAL_FLOOR)")
    parser.add_argument("--splat-views", type=int, default=BootstrapConfig().splat_views,
                        help="training views whose depths are splatted into the view (the splat columns)")
    parser.add_argument("--blended-depth", action="store_true",
                        help="warp with the render's depth, sky shell blended in, "
                             "instead of the scene's own surface depth")
    parser.add_argument("--align-px", type=float, default=DEFAULT_MAX_SHIFT_PX,
                        help="the +flow columns: each warp moved onto the render by optical flow, shifts "
                             "beyond this many pixels left untrusted (align.py)")
    parser.add_argument("--views", type=int, default=None, help="score only the first N held-out views")
    args = parser.parse_args(argv)
    torch.set_num_threads(2)

    stage1 = load_stage1(Path(args.run))
    scene, split, payload, gaussians = stage1.scene, stage1.split, stage1.payload, stage1.gaussians
    sky = payload.get("sky") if payload is not None else None
    prior_run = Path(args.prior_run or args.run)
    prior = load_prior(prior_run) if (prior_run / "prior" / "prior.pt").is_file() else None
    sources = WITHOUT_PRIOR + (WITH_PRIOR if prior is not None else ())
    if prior is None:
        print(f"{prior_run}: no prior/prior.pt: the prior rows (repair, I*) are left out")
    rows, depths = {}, {}
    for view in split.test[:args.views]:
        rows[view] = scores_at(view, scene, split, gaussians, prior, args, depths, sky)
        print(f"  {scene.cameras[view].name} ({group_of(view, split)}): "
              + "  ".join(f"{s} {rows[view][s]['psnr']:.2f}" for s in sources)
              + f"  (photo supervision {rows[view]['photo_s']:.1f} s)", flush=True)
    print(f"\n{args.run}: held-out views as virtual views; PSNR (dB) / SSIM against their photos")
    print(f"{'group':<9}{'views':>6}" + "".join(f"{s:>14}" for s in sources))
    for group in GROUPS:
        members = [rows[v] for v in rows if group_of(v, split) == group]
        if not members:
            continue
        mean = lambda key, metric: sum(m[key][metric] for m in members) / len(members)  # noqa: E731
        print(f"{group:<9}{len(members):>6}" + "".join(f"{mean(s, 'psnr'):>7.2f}/{mean(s, 'ssim'):.3f}"
                                                     for s in sources))
    print("\ntrusted pixels: PSNR of the blended photos / of the render on the pixels the supervision trusts "
          "(fraction of the image)")
    for group in GROUPS:
        members = [rows[v] for v in rows if group_of(v, split) == group]
        cells = []
        for name in TRUSTED:
            have = [m for m in members if f"{name}_trusted_warp" in m]
            if not have:
                cells.append(f"{name}: -")
                continue
            avg = lambda key: sum(m[key] for m in have) / len(have)  # noqa: E731
            cells.append(f"{name}: {avg(f'{name}_trusted_warp'):.2f} / {avg(f'{name}_trusted_render'):.2f} "
                         f"({sum(m[f'{name}_trusted_fraction'] for m in members) / len(members):.2f})")
        if members:
            print(f"{group:<9}" + "   ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
