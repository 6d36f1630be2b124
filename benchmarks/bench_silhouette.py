"""Where a sky-shell run's held-out error lies, and whether the training views' visual hull
disagrees with the render there.

    python benchmarks/bench_silhouette.py RUN [--samples 384 | --samples 0] [--dilate 1] [--truth-masks]

RUN must be trained with the sky shell (on by default, ``free_space.sky_shell``): its checkpoint's
sphere splits the Gaussians into foreground (inside BACKGROUND_FRACTION of the shell's radius) and
background, so every render has a foreground alpha. Per held-out group (scarce, covered), pooled over its views:

* the share of the squared error (and of the pixels, and the PSNR) within EDGE_BAND px of the
  render's foreground/background edge, inside the foreground, in the background; and, inside the
  foreground, within EDGE_BAND px of a depth edge (bench_geometry_term's band: object contours);
* the visual hull: the training views' rendered foreground masks (alpha > 0.5, dilated by
  --dilate px so that a one-pixel misregistration carves nothing) carved into the held-out view.
  Along each pixel's ray, --samples depths (uniform in disparity, from NEAR to where the ray leaves
  the foreground sphere) are projected into every training view; a point inside some view's image
  is carved when a view sees it as background, occupied when every view that sees it says
  foreground. A pixel is hull-foreground if its ray meets an occupied point, hull-background if
  every point is carved, else unknown. Reported: how often hull and render disagree (pixels where
  the hull is known), the error's share there, and, on the procedural demo scene (where the
  ground truth can be ray-traced), which side the truth takes and how well the training masks
  match the photos' true sky;
* the shell behind the silhouettes: its Gaussians seen as sky by some training view (at the
  centre's pixel the view's foreground alpha is < 0.5), hidden (framed, but always behind the
  foreground) or outside every image; on the demo, their colour error against the true sky, the
  held-out error where the hidden ones show, and the group's PSNR with the true sky behind the
  foreground (an oracle: what the shell costs);
* a fill that uses the training views only: each hidden shell Gaussian takes the mean colour and
  opacity of its FILL_NEIGHBOURS nearest seen ones; the group's PSNR (pooled, and the mean over
  views as `inceptiongs eval` reports it) before and after.

Timings are not measured; the hull takes ~1 min on the 96 x 72 demo (two cores).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import numpy as np
import torch
import torch.nn.functional as F

from bench_geometry_term import EDGE_BAND, edge_band, psnr_of
from inceptiongs.train.sky import FILL_NEIGHBOURS, FOREGROUND_ALPHA

# Rays start this far in front of the camera (normalised scene units; the demo's objects sit
# 0.3-1 units away).
NEAR = 0.02
HULL_FG, HULL_BG, HULL_UNKNOWN = 1, 0, -1
# A foreground pixel off the silhouette rendered with less alpha than this lets the sky shell
# show through a surface.
OPAQUE = 0.95
# A truly-sky pixel with more foreground alpha than this is part of a halo round the silhouette.
HALO_ALPHA = 0.05
# The opacity of the "every shell Gaussian opaque" variant (below the rasterizer's 0.99 cap).
SHELL_OPAQUE = 0.99
# Rays per pixel side for the demo's ray-traced coverage (the photos use 2 x 2).
TRUTH_SAMPLES = 4
# A silhouette pixel whose rendered foreground alpha is off the true coverage by more than this
# is "misplaced" (about a quarter pixel of edge position for a straight edge).
ALPHA_OFF = 0.25


def band_of(mask: torch.Tensor, width: int = EDGE_BAND) -> torch.Tensor:
    """mask [h, w] bool -> [h, w] bool: pixels within ``width`` px of a change of ``mask``."""
    m = mask[None, None].float()
    size = 2 * width + 1
    grown = F.max_pool2d(m, size, stride=1, padding=width)
    shrunk = -F.max_pool2d(-m, size, stride=1, padding=width)
    return (grown != shrunk)[0, 0]


def dilate(mask: torch.Tensor, width: int) -> torch.Tensor:
    """mask [h, w] bool grown by ``width`` px (square), unchanged for width 0."""
    if width <= 0:
        return mask
    return F.max_pool2d(mask[None, None].float(), 2 * width + 1, stride=1, padding=width)[0, 0] > 0


def pixel_rays(camera) -> tuple[torch.Tensor, torch.Tensor]:
    """(centre [3], directions [h*w, 3] with camera-z component 1) through pixel centres, world frame."""
    j, i = torch.meshgrid(torch.arange(camera.height, dtype=torch.float64),
                          torch.arange(camera.width, dtype=torch.float64), indexing="ij")
    local = torch.stack([(i + 0.5 - camera.cx) / camera.fx, (j + 0.5 - camera.cy) / camera.fy,
                         torch.ones_like(i)], -1).reshape(-1, 3)
    rotation = torch.as_tensor(camera.world_to_camera[:3, :3], dtype=torch.float64)
    return torch.as_tensor(camera.center, dtype=torch.float64), local @ rotation   # R^T d, row form


def ray_depths(center: torch.Tensor, directions: torch.Tensor, sphere: torch.Tensor, samples: int) -> torch.Tensor:
    """Camera-z depths [R, samples] from NEAR to the exit of ``sphere`` [4] (centre, radius),
    uniform in disparity (even steps in the other views' pixels). The camera is inside the sphere,
    so the quadratic has a positive root; a ray leaving before NEAR gets NEAR alone."""
    oc = center - sphere[:3]
    a = (directions ** 2).sum(1)                                      # >= 1: z component is 1
    b = 2.0 * (directions @ oc)
    c = float(oc @ oc - sphere[3] ** 2)                               # < 0 inside the sphere
    far = (-b + torch.sqrt((b * b - 4.0 * a * c).clamp_min(0.0))) / (2.0 * a)
    far = far.clamp_min(NEAR)
    s = torch.linspace(0.0, 1.0, samples, dtype=torch.float64)
    return 1.0 / ((1.0 - s) / NEAR + s / far[:, None])                # disparities > 0


def visual_hull(camera, masks: list[tuple[object, torch.Tensor]], sphere: torch.Tensor, samples: int) -> torch.Tensor:
    """[h, w] int8 labels HULL_FG / HULL_BG / HULL_UNKNOWN of ``camera``'s pixels from the
    foreground masks [H_k, W_k] bool of the views in ``masks`` (a list of (camera, mask))."""
    center, directions = pixel_rays(camera)
    depths = ray_depths(center, directions, sphere, samples)           # [R, S]
    points = center + directions[:, None, :] * depths[..., None]      # [R, S, 3]
    seen = torch.zeros(depths.shape, dtype=torch.bool)
    carved = torch.zeros(depths.shape, dtype=torch.bool)
    for view, mask in masks:
        pose = torch.as_tensor(view.world_to_camera, dtype=torch.float64)
        local = points @ pose[:3, :3].T + pose[:3, 3]
        z = local[..., 2]
        front = z > 1e-6                                               # divide only in front
        zs = torch.where(front, z, torch.ones_like(z))
        u = torch.floor(view.fx * local[..., 0] / zs + view.cx)
        v = torch.floor(view.fy * local[..., 1] / zs + view.cy)
        inside = front & (u >= 0) & (u < view.width) & (v >= 0) & (v < view.height)
        flat = (v.clamp(0, view.height - 1) * view.width + u.clamp(0, view.width - 1)).long()
        foreground = mask.reshape(-1)[flat]
        seen |= inside
        carved |= inside & ~foreground
    occupied = seen & ~carved
    labels = torch.full((depths.shape[0],), HULL_UNKNOWN, dtype=torch.int8)
    labels[carved.all(1)] = HULL_BG
    labels[occupied.any(1)] = HULL_FG
    return labels.reshape(camera.height, camera.width)


def true_coverage(scene, camera) -> torch.Tensor | None:
    """[h, w] float in [0, 1]: the share of 4 x 4 rays per pixel that hit the procedural demo
    scene's geometry (not its sky); None when the scene is not the objects demo."""
    import json

    from inceptiongs.scene.demo import Textures, camera_rays, trace

    description = Path(scene.root) / "demo_scene.json"
    if not description.is_file() or json.loads(description.read_text()).get("scene") != "objects":
        return None
    original = scene.normalization.camera_to_original(camera)
    grid = (np.arange(TRUTH_SAMPLES) + 0.5) / TRUTH_SAMPLES
    offsets = np.array([(a, b) for b in grid for a in grid])
    origins, dirs = camera_rays(original, offsets)
    _, distance = trace(np.ascontiguousarray(origins), dirs, Textures(noise=np.zeros((64, 64))))
    hit = np.isfinite(distance).reshape(len(offsets), camera.height, camera.width).mean(0)
    return torch.as_tensor(hit, dtype=torch.float32)


def true_sky_colours(scene, means: torch.Tensor, sphere: torch.Tensor) -> np.ndarray | None:
    """[S, 3]: the demo's sky colour in the direction of each shell point (means [S, 3], normalised
    frame) from the shell's centre; None when the scene is not the objects demo."""
    import json

    from inceptiongs.scene.demo import Textures, trace

    description = Path(scene.root) / "demo_scene.json"
    if not description.is_file() or json.loads(description.read_text()).get("scene") != "objects":
        return None
    points = means.detach().double().numpy()
    outward = points - sphere[:3].numpy()
    outward /= np.linalg.norm(outward, axis=1, keepdims=True)   # shell points lie at the radius > 0
    # Cast from the shell point outwards: nothing of the scene lies beyond it, so every ray is sky.
    colours, distance = trace(scene.normalization.to_original(points), outward, Textures(noise=np.zeros((64, 64))))
    assert not np.isfinite(distance).any(), "a ray cast outward from the shell hit the scene"
    return colours


def filled_shell(gaussians, background: torch.Tensor, exposure: torch.Tensor):
    """``gaussians`` with each hidden shell Gaussian (background [N] bool; exposure [S] of the
    background ones in order, 0 = hidden: see ``inceptiongs.train.sky.shell_exposure``) filled
    from its nearest shell Gaussians seen as sky (``inceptiongs.train.sky.fill_hidden_shell``)."""
    from inceptiongs.gaussians import gaussians_from_params
    from inceptiongs.train.optim import params_from_gaussians
    from inceptiongs.train.sky import fill_hidden_shell

    params = {name: t.detach() for name, t in params_from_gaussians(gaussians).items()}
    hidden = torch.zeros_like(background)
    donors = torch.zeros_like(background)
    hidden[background] = exposure == 0
    donors[background] = exposure == 1
    fill_hidden_shell(params, hidden, donors)
    return gaussians_from_params(params)


def opaque_shell(gaussians, background: torch.Tensor):
    """``gaussians`` with every shell Gaussian (background [N] bool) at opacity SHELL_OPAQUE."""
    from dataclasses import replace

    logits = gaussians.opacity_logits.detach().clone()
    logits[background] = float(np.log(SHELL_OPAQUE / (1.0 - SHELL_OPAQUE)))   # 0 < SHELL_OPAQUE < 1
    return replace(gaussians, opacity_logits=logits)


def dilate_alpha(alpha: torch.Tensor, width: int) -> torch.Tensor:
    """[h, w] -> [h, w]: the maximum of ``alpha`` within ``width`` px (square)."""
    return F.max_pool2d(alpha[None, None], 2 * width + 1, stride=1, padding=width)[0, 0]


class Pool:
    """Sums of squared error and pixel counts over named pixel sets, pooled over views."""

    def __init__(self) -> None:
        self.error: dict[str, float] = {}
        self.pixels: dict[str, int] = {}
        self.total_error = 0.0
        self.total_pixels = 0

    def add(self, error: torch.Tensor, sets: dict[str, torch.Tensor]) -> None:
        self.total_error += float(error.sum())
        self.total_pixels += error.numel()
        for name, where in sets.items():
            self.error[name] = self.error.get(name, 0.0) + float(error[where].sum())
            self.pixels[name] = self.pixels.get(name, 0) + int(where.sum())

    def row(self, name: str) -> str:
        e, n = self.error.get(name, 0.0), self.pixels.get(name, 0)
        psnr = psnr_of(torch.tensor(e / n)) if n else float("nan")
        return (f"{name:<34}{100 * e / max(self.total_error, 1e-12):>8.1f} %{100 * n / max(self.total_pixels, 1):>8.1f} %"
                f"{psnr:>9.2f}")


@dataclass
class ShellRun:
    """A sky-shell stage-I run split for measuring: the scene, its split, all Gaussians, the
    foreground ones (inside the shell), the shell ones, the shell's sphere [4] (centre, radius)
    and the foreground sphere [4] (BACKGROUND_FRACTION of its radius), both float64."""

    scene: object
    split: object
    gaussians: object
    foreground: object
    shell: object
    sphere: torch.Tensor
    foreground_sphere: torch.Tensor


@dataclass
class GroupTotals:
    """What one held-out group pools over its views: the error per pixel set, each variant's
    summed error, per-view PSNRs, the shell's figures on truly-sky edge pixels and the hull's
    votes where it disagrees with the render."""

    pool: Pool
    variant_error: dict[str, float]
    view_psnr: dict[str, list[float]]
    shell_pool: dict[str, float] = field(default_factory=lambda: {
        "error": 0.0, "pixels": 0, "alpha": 0.0, "true sky error": 0.0, "true sky band error": 0.0})
    votes: dict[str, int] = field(default_factory=lambda: {
        f"hull {side}: truth with {who}": 0 for side in ("fg", "bg") for who in ("hull", "render")})


def measure(run: str, samples: int, dilation: int, truth_masks: bool, fill_margin: int) -> None:
    """Print the figures of the module docstring for ``run``; samples 0 skips the hull."""
    from inceptiongs.train.sky import in_background

    setup = load_shell_run(run)
    masks, train_alphas, mask_wrong, mask_pixels = training_masks(setup, run, dilation, truth_masks)
    print(f"{run}: {len(setup.foreground)} foreground / {len(setup.gaussians) - len(setup.foreground)} "
          f"background Gaussians; "
          f"{len(masks)} {'ray-traced' if truth_masks else 'rendered'} training masks (dilated {dilation} px), "
          f"{samples} samples per ray")
    if mask_pixels:
        print(f"training masks vs the ray-traced truth: {100 * mask_wrong / mask_pixels:.2f} % of pixels differ")
    exposure, fill_exposure, hidden = report_shell_exposure(setup, train_alphas, fill_margin)
    background = in_background(setup.gaussians.means, setup.sphere)
    variants = {"filled": filled_shell(setup.gaussians, background, fill_exposure),
                "opaque": opaque_shell(setup.gaussians, background)}
    for group in ("scarce_test", "covered_test"):
        totals = GroupTotals(Pool(), {name: 0.0 for name in variants},
                             {name: [] for name in ("render", *variants)})
        for view in getattr(setup.split, group):
            measure_view(setup, view, variants, masks, samples, hidden, totals)
        print_group(group, len(getattr(setup.split, group)), totals, fill_margin)
        sys.stdout.flush()


def load_shell_run(run: str) -> ShellRun:
    """Load ``run``'s stage I and split its Gaussians at the sky shell; exit when it has none."""
    from inceptiongs.bootstrap.stage1 import load_stage1
    from inceptiongs.train.sky import BACKGROUND_FRACTION, in_background

    stage1 = load_stage1(Path(run))
    scene, split, payload, gaussians = stage1.scene, stage1.split, stage1.payload, stage1.gaussians
    sphere = None if payload is None else payload.get("sky")
    if sphere is None:
        raise SystemExit(f"{run}: no sky shell in the checkpoint (train with the sky shell on: free_space.sky_shell)")
    sphere = sphere.to(torch.float64)
    foreground_sphere = torch.cat([sphere[:3], sphere[3:] * BACKGROUND_FRACTION])
    foreground = gaussians.subset(~in_background(gaussians.means, sphere))
    shell = gaussians.subset(in_background(gaussians.means, sphere))
    return ShellRun(scene, split, gaussians, foreground, shell, sphere, foreground_sphere)


def render_alpha(gaussians, camera) -> torch.Tensor:
    """[h, w]: the alpha of ``gaussians`` seen from ``camera``, without gradients."""
    from inceptiongs.rasterizer.interface import cpu_rasterizer

    with torch.no_grad():
        return cpu_rasterizer()(gaussians, camera, outputs=("alpha",))["alpha"][..., 0]


def render_colour(gaussians, camera) -> torch.Tensor:
    """[h, w, 3]: the colour render of ``gaussians`` from ``camera`` on black, without gradients."""
    from inceptiongs.rasterizer.interface import cpu_rasterizer

    with torch.no_grad():
        return cpu_rasterizer()(gaussians, camera)["rgb"]


def training_masks(setup: ShellRun, run: str, dilation: int, truth_masks: bool) -> tuple[list, list, int, int]:
    """((camera, foreground mask [h, w] bool dilated by ``dilation``) per training view, the
    foreground alphas [h, w] of those views, the rendered masks' pixels that differ from the
    ray-traced truth, the pixels compared (both 0 unless the scene is the objects demo))."""
    from inceptiongs.train.sky import FOREGROUND_ALPHA

    cameras = setup.scene.cameras
    masks, mask_wrong, mask_pixels, train_alphas = [], 0, 0, []
    for i in setup.split.train:
        train_alphas.append(render_alpha(setup.foreground, cameras[i]))
        rendered = train_alphas[-1] > FOREGROUND_ALPHA
        coverage = true_coverage(setup.scene, cameras[i])
        if coverage is not None:
            truth = coverage > 0.5
            mask_wrong += int((rendered != truth).sum())
            mask_pixels += rendered.numel()
        if truth_masks and coverage is None:
            raise SystemExit(f"{run}: --truth-masks needs the procedural objects demo scene")
        masks.append((cameras[i], dilate(truth if truth_masks else rendered, dilation)))
    return masks, train_alphas, mask_wrong, mask_pixels


def report_shell_exposure(setup: ShellRun, train_alphas: list[torch.Tensor],
                          fill_margin: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(exposure [S], the fill's exposure [S], hidden [S, 1] float) of the shell Gaussians; prints
    how many are seen as sky, hidden or outside every image, their opacity and, on the demo, their
    colour error against the true sky."""
    from inceptiongs.rasterizer.sh import sh_to_color
    from inceptiongs.train.sky import shell_exposure

    shell, sphere = setup.shell, setup.sphere
    train_cameras = [setup.scene.cameras[i] for i in setup.split.train]
    exposure = shell_exposure(shell.means, train_cameras, train_alphas)
    # For the fill only: "seen" may demand sky on every pixel within fill_margin px of the centre's.
    fill_exposure = exposure if fill_margin == 0 else shell_exposure(
        shell.means, train_cameras, [dilate_alpha(a, fill_margin) for a in train_alphas])
    hidden = (exposure == 0).to(shell.dtype)[:, None]                       # feature [S, 1]
    sky_colours = true_sky_colours(setup.scene, shell.means, sphere)
    outward = shell.means.detach() - sphere[:3].to(shell.dtype)
    outward = outward / outward.norm(dim=1, keepdim=True)                   # shell points at radius > 0
    shell_colours = sh_to_color(shell.sh.detach(), outward, shell.sh_degree).clamp(0.0, 1.0).double().numpy()
    for code, name in ((1, "seen as sky by a training view"), (0, "framed, always behind the foreground"),
                       (-1, "outside every training image")):
        where = (exposure == code).numpy()
        line = f"shell Gaussians {name}: {int(where.sum())}"
        if where.any():
            opacity = torch.sigmoid(shell.opacity_logits.detach()[torch.as_tensor(where)])
            line += (f", median opacity {float(opacity.median()):.3f}, "
                     f"{100 * float((opacity < 0.5).float().mean()):.0f} % below 0.5")
        if sky_colours is not None and where.any():
            rms = float(np.sqrt(((shell_colours[where] - sky_colours[where]) ** 2).mean()))
            line += f", RMS colour error against the true sky {rms:.3f}"
        print(line)
    return exposure, fill_exposure, hidden


def measure_view(setup: ShellRun, view: int, variants: dict, masks: list, samples: int,
                 hidden: torch.Tensor, totals: GroupTotals) -> None:
    """Add one held-out view's squared error [h, w], per pixel set and per variant, to ``totals``."""
    from inceptiongs.rasterizer.interface import cpu_rasterizer
    from inceptiongs.train.sky import FOREGROUND_ALPHA

    camera = setup.scene.cameras[view]
    with torch.no_grad():
        out = cpu_rasterizer()(setup.gaussians, camera, outputs=("rgb", "depth"))
    photo = torch.as_tensor(np.asarray(setup.scene.load_image(view)), dtype=torch.float32)
    error = ((out["rgb"].clamp(0.0, 1.0) - photo) ** 2).mean(-1)                # [h, w]
    totals.view_psnr["render"].append(psnr_of(error.mean()))
    for name, variant in variants.items():
        variant_squared = ((render_colour(variant, camera).clamp(0.0, 1.0) - photo) ** 2).mean(-1)
        totals.variant_error[name] += float(variant_squared.sum())
        totals.view_psnr[name].append(psnr_of(variant_squared.mean()))
    alpha = render_alpha(setup.foreground, camera)
    rendered = alpha > FOREGROUND_ALPHA
    silhouette = band_of(rendered)
    hull = (visual_hull(camera, masks, setup.foreground_sphere, samples) if samples
            else torch.full(rendered.shape, HULL_UNKNOWN, dtype=torch.int8))
    sets = render_sets(rendered, silhouette, edge_band(out["depth"]) & rendered & ~silhouette,
                       alpha, hull, samples)
    coverage = true_coverage(setup.scene, camera)
    if coverage is not None:
        sets.update(truth_sets(setup, camera, out["rgb"], photo, alpha, coverage, silhouette, hull,
                               samples, hidden, totals))
        add_votes(totals.votes, rendered, coverage > 0.5, hull)
    totals.pool.add(error, sets)


def render_sets(rendered: torch.Tensor, silhouette: torch.Tensor, depth_edges: torch.Tensor,
                alpha: torch.Tensor, hull: torch.Tensor, samples: int) -> dict[str, torch.Tensor]:
    """The pixel sets [h, w] bool that need no ground truth: edge bands, foreground, background
    and, with a hull (samples > 0), where hull and render disagree."""
    known = hull != HULL_UNKNOWN
    disagree = known & ((hull == HULL_FG) != rendered)
    sets = {
        f"fg/bg edge (<= {EDGE_BAND} px)": silhouette,
        "foreground, off the edge": rendered & ~silhouette,
        f"  of which depth edges (<= {EDGE_BAND} px)": depth_edges,
        "  of which the rest": rendered & ~silhouette & ~depth_edges,
        f"  of which alpha < {OPAQUE} (see-through)": rendered & ~silhouette & (alpha < OPAQUE),
        "background, off the edge": ~rendered & ~silhouette,
    }
    if samples:
        sets.update({
            "hull unknown": ~known,
            "hull fg, render bg": disagree & (hull == HULL_FG),
            "hull bg, render fg": disagree & (hull == HULL_BG),
            "hull and render disagree": disagree,
            "  of which off the fg/bg edge": disagree & ~silhouette,
        })
    return sets


def truth_sets(setup: ShellRun, camera, rgb: torch.Tensor, photo: torch.Tensor, alpha: torch.Tensor,
               coverage: torch.Tensor, silhouette: torch.Tensor, hull: torch.Tensor, samples: int,
               hidden: torch.Tensor, totals: GroupTotals) -> dict[str, torch.Tensor]:
    """The pixel sets [h, w] bool that the demo's ray-traced coverage [h, w] allows (in display
    order); adds the shell's figures on truly-sky edge pixels to ``totals.shell_pool``."""
    from inceptiongs.rasterizer.interface import cpu_rasterizer
    from inceptiongs.train.sky import FOREGROUND_ALPHA

    rendered = alpha > FOREGROUND_ALPHA
    truth = coverage > 0.5
    sky = coverage <= 0.0
    misplaced = (alpha - coverage).abs() > ALPHA_OFF
    sets = {
        f"fg/bg edge, |alpha - truth| > {ALPHA_OFF}": silhouette & misplaced,
        f"fg/bg edge, |alpha - truth| <= {ALPHA_OFF}": silhouette & ~misplaced,
        "fg/bg edge, truly all foreground": silhouette & (coverage >= 1.0),
        "fg/bg edge, truly mixed": silhouette & (coverage > 0.0) & (coverage < 1.0),
        "fg/bg edge, truly all sky": silhouette & sky,
        "  of which fg alpha > 0.05 (halo)": silhouette & sky & (alpha > HALO_ALPHA),
    }
    if samples:
        sets["  of which the hull says sky"] = silhouette & sky & (hull == HULL_BG)
    with torch.no_grad():
        shown = cpu_rasterizer()(setup.shell, camera, outputs=("alpha", "features"), features=hidden)
    # The shell's own alpha is > 0 wherever it is framed; the floor keeps 0/0 out.
    hidden_share = shown["features"][..., 0] / shown["alpha"][..., 0].clamp_min(1e-6)
    sets["  of which the shell there was hidden"] = silhouette & sky & (hidden_share > 0.5)
    add_shell_figures(totals.shell_pool, render_colour(setup.shell, camera), rgb, photo, alpha, sky,
                      silhouette & sky)
    wrong = rendered != truth
    sets["render fg != truth"] = wrong
    if samples:
        sets["  of which the hull is right"] = wrong & (hull != HULL_UNKNOWN) & ((hull == HULL_FG) == truth)
    return sets


def add_shell_figures(shell_pool: dict[str, float], behind: torch.Tensor, rgb: torch.Tensor,
                      photo: torch.Tensor, alpha: torch.Tensor, sky: torch.Tensor,
                      sky_band: torch.Tensor) -> None:
    """Add to ``shell_pool`` the shell's own error and the foreground alpha on truly-sky edge
    pixels (sky_band [h, w]), and the error of the render with the true sky behind the foreground
    on every truly-sky pixel (sky [h, w]) and on the band. behind: the shell's render [h, w, 3]."""
    shell_error = ((behind.clamp(0.0, 1.0) - photo) ** 2).mean(-1)
    # The render with the true sky (the photo, where all of a pixel's rays miss the
    # scene) behind the foreground instead of the shell: what the shell costs.
    true_sky = rgb - (1.0 - alpha[..., None]) * behind + (1.0 - alpha[..., None]) * photo
    for name, where in (("true sky error", sky), ("true sky band error", sky_band)):
        oracle = torch.where(where[..., None], true_sky, rgb).clamp(0.0, 1.0)
        shell_pool[name] += float(((oracle - photo) ** 2).mean(-1).sum())
    shell_pool["error"] += float(shell_error[sky_band].sum())
    shell_pool["pixels"] += int(sky_band.sum())
    shell_pool["alpha"] += float(alpha[sky_band].sum())


def add_votes(votes: dict[str, int], rendered: torch.Tensor, truth: torch.Tensor, hull: torch.Tensor) -> None:
    """Where hull and render disagree, count per hull side the pixels whose truth sides with each."""
    disagree = (hull != HULL_UNKNOWN) & ((hull == HULL_FG) != rendered)
    for kind in (HULL_FG, HULL_BG):
        here = disagree & (hull == kind)
        side = 'fg' if kind == HULL_FG else 'bg'
        votes[f"hull {side}: truth with hull"] += int((here & ((hull == HULL_FG) == truth)).sum())
        votes[f"hull {side}: truth with render"] += int((here & (rendered == truth)).sum())


def print_group(group: str, views: int, totals: GroupTotals, fill_margin: int) -> None:
    """Print one held-out group's table, shell figures, variants and hull votes."""
    pool, shell_pool = totals.pool, totals.shell_pool
    print(f"\n{group.split('_')[0]} ({views} views, PSNR {psnr_of(torch.tensor(pool.total_error / pool.total_pixels)):.2f})"
          f"\n{'pixel set':<34}{'error':>10}{'pixels':>10}{'PSNR':>9}")
    for name in pool.error:
        print(pool.row(name))
    if shell_pool["pixels"]:
        print(f"truly-sky pixels at the fg/bg edge: mean foreground alpha {shell_pool['alpha'] / shell_pool['pixels']:.3f}; "
              f"the shell alone scores {psnr_of(torch.tensor(shell_pool['error'] / shell_pool['pixels'])):.2f} dB there; "
              f"with the true sky behind the foreground the group scores "
              f"{psnr_of(torch.tensor(shell_pool['true sky band error'] / pool.total_pixels)):.2f} dB "
              f"(there only), {psnr_of(torch.tensor(shell_pool['true sky error'] / pool.total_pixels)):.2f} dB "
              f"(on every truly-sky pixel)")
    render_psnr = psnr_of(torch.tensor(pool.total_error / pool.total_pixels))
    for name, label in (("filled", f"the hidden shell filled (colour and opacity) from its {FILL_NEIGHBOURS} nearest "
                                   f"seen neighbours (seen: sky on every pixel within {fill_margin} px)"),
                        ("opaque", "every shell Gaussian made opaque")):
        print(f"{label}: PSNR {psnr_of(torch.tensor(totals.variant_error[name] / pool.total_pixels)):.2f} pooled "
              f"(render {render_psnr:.2f}); mean over views {np.mean(totals.view_psnr[name]):.2f} "
              f"(render {np.mean(totals.view_psnr['render']):.2f})")
    if any(totals.votes.values()):
        print("where hull and render disagree, pixels on each side of the ray-traced truth: "
              + "; ".join(f"{name} {count}" for name, count in totals.votes.items()))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--samples", type=int, default=384, help="depths per ray for the hull (0: no hull)")
    parser.add_argument("--dilate", type=int, default=1, help="px the training masks grow before carving")
    parser.add_argument("--truth-masks", action="store_true",
                        help="carve with the ray-traced true masks instead of the rendered ones (objects demo only): "
                             "the hull's own limit, without the render's mask errors")
    parser.add_argument("--fill-margin", type=int, default=0,
                        help="the fill counts a shell Gaussian as seen only where a training view shows sky on every "
                             "pixel within this many px of its centre's pixel")
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    measure(args.run, 0 if args.samples <= 0 else max(2, args.samples), max(0, args.dilate), args.truth_masks,
            max(0, args.fill_margin))
    return 0


if __name__ == "__main__":
    sys.exit(main())
