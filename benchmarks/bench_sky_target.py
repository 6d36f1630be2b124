"""What a background term at virtual views could be worth:
the sky that the training photos show, warped to each held-out view and put behind the foreground.

    python benchmarks/bench_sky_target.py RUN [--margin 2] [--clear 0.05] [--at-shell]

RUN must have the sky shell (the default in stage I): its checkpoint's sphere splits the Gaussians
into foreground and shell (``inceptiongs.train.sky.in_background``). At each held-out view, each
pixel's ray is followed to the sky: by default as a direction (a sky at infinity: the demo's sky is
a function of direction alone), with ``--at-shell`` to its point on the shell's sphere (what the
shell Gaussians model). A training view *shows that sky* where it frames the direction and its own
foreground alpha, grown by ``--margin`` px, is below ``--clear``: its photo there is sky and nothing
else. The target is the per-pixel median of those photos (bilinear, border-clamped); where no
training view shows it, OpenCV's Telea inpainting of the target (the fill ``--fill inpaint``
already uses) continues it. Both replace the shell only where the shell is drawn (its own alpha
> 0.5), the region a background term could train.

Per held-out group, the mean over views of the PSNR (as ``inceptiongs eval`` reports it) of:
the render; the render with the target behind the foreground where photos show the sky; the same
plus the inpainted rest; and an oracle with the held-out photo itself behind the foreground
(everything the shell could give, and more: behind a translucent surface the photo holds the
surface too). A self-check first: on open sky (foreground alpha < OPEN_SKY_ALPHA) where a training
photo shows it, the target's PSNR against the held-out photo, which must be high for the warp to
be right. Timings are not measured (about 10 s per run on the 96 x 72 demo, two cores).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import numpy as np
import torch
import torch.nn.functional as F

from bench_geometry_term import psnr_of
from bench_silhouette import dilate_alpha, pixel_rays, ray_depths
from inceptiongs.bootstrap.experimental.inpaint import inpaint
from inceptiongs.train.sky import FOREGROUND_ALPHA

# Foreground alpha below which a held-out pixel is open sky (the self-check's pixels).
OPEN_SKY_ALPHA = 0.02
# The shell is "drawn" at a pixel where its own alpha exceeds this.
SHELL_DRAWN = 0.5
# Camera-z below which a direction is behind a training camera.
FRONT = 1e-6


def sky_points(camera, sphere: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
    """(origin [3], points [h*w, 3]) for ``camera``'s pixel rays: the points where the rays leave
    ``sphere`` [4] (centre, radius; the camera is inside it), or, for None, origin + direction
    (a sky at infinity: only directions are projected then)."""
    center, directions = pixel_rays(camera)
    if sphere is None:
        return center, center + directions
    far = ray_depths(center, directions, sphere, 2)[:, -1:]                # the last depth: the exit
    return center, center + directions * far


def sky_target(camera, training: list, sphere: torch.Tensor | None, clear: float
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """(target [h, w, 3], known [h, w] bool) at ``camera``: the median of the training photos that
    show the sky along each pixel's ray (see the module doc). training: (camera, foreground alpha
    [H, W] already grown by the margin, photo [H, W, 3]) per training view."""
    origin, points = sky_points(camera, sphere)
    colours, shows = [], []
    for view, alpha, photo in training:
        pose = torch.as_tensor(view.world_to_camera, dtype=torch.float64)
        local = (points - origin) @ pose[:3, :3].T if sphere is None else points @ pose[:3, :3].T + pose[:3, 3]
        z = local[:, 2]
        front = z > FRONT
        safe_z = torch.where(front, z, torch.ones_like(z))                   # divided by only in front
        u = view.fx * local[:, 0] / safe_z + view.cx
        v = view.fy * local[:, 1] / safe_z + view.cy
        inside = front & (u >= 0) & (u < view.width) & (v >= 0) & (v < view.height)
        column = u.clamp(0, view.width - 1).long()
        row = v.clamp(0, view.height - 1).long()
        shows.append(inside & (alpha[row, column] < clear))
        # Border padding: a ray that lands in the outer half pixel reads the edge, not black.
        grid = torch.stack([u / view.width * 2 - 1, v / view.height * 2 - 1], -1).float()[None, None]
        colours.append(F.grid_sample(photo.permute(2, 0, 1)[None], grid, align_corners=False,
                                     padding_mode="border")[0, :, 0].T)
    stacked, valid = torch.stack(colours), torch.stack(shows)               # [V, R, 3], [V, R]
    masked = torch.where(valid[..., None], stacked, torch.full_like(stacked, float("nan")))
    target = torch.nan_to_num(masked.nanmedian(0).values, nan=0.0)          # all-NaN rows: unknown, 0
    return target.reshape(camera.height, camera.width, 3), valid.any(0).reshape(camera.height, camera.width)


def measure(run: str, margin: int, clear: float, at_shell: bool) -> None:
    """Print the figures of the module docstring for ``run``."""
    from inceptiongs.bootstrap.stage1 import load_stage1
    from inceptiongs.rasterizer.interface import cpu_rasterizer
    from inceptiongs.train.sky import in_background

    stage1 = load_stage1(Path(run))
    render = cpu_rasterizer()   # the CPU's best, through the registry
    scene, split, payload, gaussians = stage1.scene, stage1.split, stage1.payload, stage1.gaussians
    sphere = None if payload is None else payload.get("sky")
    if sphere is None:
        raise SystemExit(f"{run}: no sky shell in the checkpoint (train with the shell on)")
    sphere = sphere.to(torch.float64)
    background = in_background(gaussians.means, sphere)
    foreground, shell = gaussians.subset(~background), gaussians.subset(background)
    cameras = scene.cameras
    training = []
    with torch.no_grad():
        for i in split.train:
            alpha = render(foreground, cameras[i], outputs=("alpha",))["alpha"][..., 0]
            photo = torch.as_tensor(np.asarray(scene.load_image(i)), dtype=torch.float32)
            training.append((cameras[i], dilate_alpha(alpha, margin), photo))
    print(f"{run}: {len(foreground)} foreground / {len(shell)} shell Gaussians; sky "
          f"{'on the shell sphere' if at_shell else 'at infinity'}; a photo shows it where its foreground alpha "
          f"within {margin} px is < {clear}")
    for group in ("scarce_test", "covered_test"):
        scores = {name: [] for name in ("render", "photos' sky", "photos' sky + inpainted", "oracle")}
        shares = {"sky shows (fg alpha < 0.5)": [], "shell drawn": [], "shell drawn, a photo shows it": []}
        check_error, check_pixels = 0.0, 0
        for view in getattr(split, group):
            camera = cameras[view]
            with torch.no_grad():
                out = render(gaussians, camera)["rgb"]
                alpha = render(foreground, camera, outputs=("alpha",))["alpha"][..., 0:1]
                drawn_shell = render(shell, camera, outputs=("rgb", "alpha"))
            behind, drawn = drawn_shell["rgb"], drawn_shell["alpha"][..., 0] > SHELL_DRAWN
            photo = torch.as_tensor(np.asarray(scene.load_image(view)), dtype=torch.float32)
            target, known = sky_target(camera, training, None if not at_shell else sphere, clear)
            open_sky = known & (alpha[..., 0] < OPEN_SKY_ALPHA)
            check_error += float(((target - photo) ** 2).mean(-1)[open_sky].sum())
            check_pixels += int(open_sky.sum())
            skies = {
                "render": behind,
                "photos' sky": torch.where((known & drawn)[..., None], target, behind),
                "photos' sky + inpainted": torch.where(drawn[..., None], inpaint(target, known), behind),
                "oracle": torch.where(drawn[..., None], photo, behind),
            }
            for name, sky in skies.items():
                # The shell lies behind every foreground Gaussian, so the render is the foreground
                # over the shell: swapping what is behind swaps (1 - alpha) * shell.
                composite = (out + (1.0 - alpha) * (sky - behind)).clamp(0.0, 1.0)
                scores[name].append(psnr_of(((composite - photo) ** 2).mean()))
            shares["sky shows (fg alpha < 0.5)"].append(float((alpha[..., 0] < FOREGROUND_ALPHA).float().mean()))
            shares["shell drawn"].append(float(drawn.float().mean()))
            shares["shell drawn, a photo shows it"].append(float((drawn & known).float().mean()))
        check = psnr_of(torch.tensor(check_error / check_pixels)) if check_pixels else float("nan")
        print(f"\n{group.split('_')[0]} ({len(getattr(split, group))} views); self-check: the target on open sky "
              f"({check_pixels} px) scores {check:.2f} dB")
        print("  pixels: " + "; ".join(f"{name} {100 * np.mean(v):.1f} %" for name, v in shares.items()))
        for name, values in scores.items():
            print(f"  {name:<26}{np.mean(values):>8.2f}{np.mean(values) - np.mean(scores['render']):>+8.2f}")
        sys.stdout.flush()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--margin", type=int, default=2, help="px a training view's foreground alpha grows by")
    parser.add_argument("--clear", type=float, default=0.05,
                        help="a training view shows the sky where its grown foreground alpha is below this")
    parser.add_argument("--at-shell", action="store_true",
                        help="follow the rays to the shell's sphere instead of to infinity")
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    measure(args.run, max(0, args.margin), args.clear, args.at_shell)
    return 0


if __name__ == "__main__":
    sys.exit(main())
