"""The sky shell: Gaussians on a far sphere where the photos see past every sparse point.

Without a background to put the sky on, the optimiser paints it wherever it costs least:
on flat, sky-coloured disks hanging just beside the training cameras (the objects demo at 2400
steps: a held-out view on the rig looks through them at 10 dB). A shell of Gaussians far
beyond the scene, coloured from the photos where they show open sky, gives the sky a place
that every camera sees at the right direction: a shell at a few scene radii moves by a
fraction of a degree between cameras of the rig.

Only the directions that some training camera sees with no sparse point in that part of its
image get a Gaussian (an indoor capture gets few or none: "leave out what a scene does not
need"). They are background: the size rules, made for the scene's own Gaussians, leave them
alone (:func:`in_background`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable

import cv2
import numpy as np
import torch
from tqdm import tqdm

from ..camera import Camera, project_points
from .point_projection import project_cloud
from ..gaussians import gaussians_from_params

# The shell's radius, in units of the sparse points' far extent (their 99th-percentile
# distance from the cameras' centroid): far enough that the rig's parallax on it is small.
SKY_RADIUS_FACTOR = 4.0
# Directions on the whole sphere: at most this many (about 0.032 rad apart), and no closer
# than SKY_PIXELS pixels of the median camera (finer than that no photo resolves).
SKY_MAX_DIRECTIONS = 12_000
SKY_PIXELS = 6.0
# An image cell (of a SKY_GRID x SKY_GRID grid) with no sparse point in it shows open sky.
SKY_GRID = 16
# An open cell counts as sky only where the photo's mean gradient magnitude there (intensity in
# [0, 1] per pixel, measured at SKY_TEXTURE_PIXELS pixels per cell so that it does not depend on
# the photo's resolution) is below this. Measured on the open cells of five scenes (median /
# 90th percentile): the objects demo's sky 0.000 / 0.015, the statuette's blurred backdrop 0.006 /
# 0.033, the courtyard's brick walls and tiles 0.037 / 0.112 (docs/training_reference.md, "The sky shell").
# Why a limit: structure from motion finds points wherever a photo has texture, so a textured cell
# without points is a gap in the reconstruction (a wall), and a far shell painted with a wall's
# texture lacks the wall's parallax. Off (inf): at 0.02 the courtyard's scarce views gain 0.49 dB
# but the objects demo's lose 0.39 (its horizon cells hold an edge and drop the sky above it).
SKY_MAX_TEXTURE = float("inf")
SKY_TEXTURE_PIXELS = 8
# A direction gets a shell Gaussian where at least this fraction of the training cameras that
# frame it see an open cell there (0: any one camera suffices).
SKY_OPEN_FRACTION = 0.0
# Opaque enough from the start that the sky's pixels need nothing else.
SKY_OPACITY = 0.5
# Gaussians farther than this fraction of the shell's radius from its centre are background.
BACKGROUND_FRACTION = 0.5


def fibonacci_directions(count: int) -> np.ndarray:
    """``count`` >= 1 near-uniform unit vectors on the sphere: [count, 3]."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count                          # in (-1, 1)
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))        # clip: rounding may leave 1 - z^2 < 0
    phi = i * math.pi * (3.0 - math.sqrt(5.0))         # the golden angle
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _cells(pixels: np.ndarray, camera: Camera) -> np.ndarray:
    """Grid cell index (row * SKY_GRID + column) of in-image pixels [P, 2]: [P]."""
    col = np.clip((pixels[:, 0] * SKY_GRID / camera.width).astype(np.int64), 0, SKY_GRID - 1)
    row = np.clip((pixels[:, 1] * SKY_GRID / camera.height).astype(np.int64), 0, SKY_GRID - 1)
    return row * SKY_GRID + col


def open_cells(camera: Camera, points: np.ndarray) -> np.ndarray:
    """[SKY_GRID * SKY_GRID] bool: the image cells no sparse point (in front) falls in."""
    pixels, _, inside = project_cloud(points, camera)
    occupied = np.zeros(SKY_GRID * SKY_GRID, dtype=bool)
    occupied[_cells(pixels[inside], camera)] = True
    return ~occupied


def cell_texture(image: np.ndarray) -> np.ndarray:
    """[SKY_GRID * SKY_GRID] mean gradient magnitude of ``image`` [H, W, 3] in [0, 1] per grid cell,
    the image first resampled to SKY_TEXTURE_PIXELS pixels per cell (area averaging)."""
    side = SKY_GRID * SKY_TEXTURE_PIXELS
    grey = np.asarray(image, dtype=np.float32)[..., :3] @ np.array([0.299, 0.587, 0.114], np.float32)
    grey = cv2.resize(grey, (side, side), interpolation=cv2.INTER_AREA)
    # Central differences, one-sided at the border (np.gradient): |d/dx| and |d/dy| per pixel.
    gy, gx = np.gradient(grey)
    magnitude = np.sqrt(gx * gx + gy * gy)
    return magnitude.reshape(SKY_GRID, SKY_TEXTURE_PIXELS, SKY_GRID, SKY_TEXTURE_PIXELS).mean((1, 3)).reshape(-1)


def shell_spacing(cameras: list[Camera]) -> float:
    """Angle in radians between neighbouring shell directions: SKY_PIXELS pixels of the median
    camera's focal length (at least 1 px, so the division is safe), but no finer than
    SKY_MAX_DIRECTIONS directions on the sphere allow."""
    focal = float(np.median([max(c.fx, c.fy) for c in cameras]))
    return max(math.sqrt(4.0 * math.pi / SKY_MAX_DIRECTIONS), SKY_PIXELS / max(focal, 1.0))


def shell_log_scale_floor(sphere: torch.Tensor, cameras: list[Camera], fraction: float) -> float:
    """log of ``fraction`` (> 0) of a shell Gaussian's initial scale (half the directions' spacing
    at the radius; sphere [4]): what :func:`hold_shell_scales` keeps the shell's axes above."""
    return math.log(fraction * 0.5 * shell_spacing(cameras) * float(sphere[3]))


def hold_shell_scales(log_scales: torch.Tensor, background: torch.Tensor, floor: float) -> None:
    """In place: the shell's (background [N] bool) log-scales [N, 3] raised to ``floor``. One
    masked select on the device and no count read back: it runs every step, and a read would
    make the host wait for the GPU.

    Why: a shell Gaussian that the photos fit as a speck leaves the sky around it empty, and a
    held-out view that looks there sees black (the README courtyard, 330 steps: the shell's
    median axis ended at 14 % of its initial size, 1 % for the shortest, and 44 % of the scarce
    views' pixels had alpha below 0.5)."""
    with torch.no_grad():
        log_scales.copy_(torch.where(background[:, None], log_scales.clamp_min(floor), log_scales))


def shell_geometry(cameras: list[Camera], points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre [3], radius) of the shell: the cameras' centroid, SKY_RADIUS_FACTOR x the far extent
    of the sparse points and cameras around it (at least 1 scene unit)."""
    centers = np.stack([c.center for c in cameras])
    centre = centers.mean(0)
    spread = np.linalg.norm(np.concatenate([np.asarray(points, np.float64).reshape(-1, 3), centers]) - centre, axis=1)
    return centre, SKY_RADIUS_FACTOR * max(float(np.percentile(spread, 99)), 1.0)


def sky_shell(cameras: list[Camera], images: Iterable[np.ndarray], points: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The shell's Gaussians. images[k]: [H, W, 3] in [0, 1] of cameras[k]; points: [P, 3].

    Returns (means [S, 3], colours [S, 3] uint8: the mean of the photos' pixels there, scales [S]:
    half the directions' spacing at the radius, sphere [4]: centre and radius); S may be 0.
    """
    centre, radius = shell_geometry(cameras, points)
    spacing = shell_spacing(cameras)
    directions = fibonacci_directions(max(1, int(4.0 * math.pi / spacing ** 2)))
    shell = centre + radius * directions
    colour_sum = np.zeros((len(shell), 3))
    seen = np.zeros(len(shell))
    framed = np.zeros(len(shell))
    for camera, image in zip(cameras, images):
        pixels, _, inside = project_points(shell, camera)
        rows = np.nonzero(inside)[0]
        framed[rows] += 1
        sky_cells = open_cells(camera, points)
        if math.isfinite(SKY_MAX_TEXTURE):
            sky_cells &= cell_texture(image) < SKY_MAX_TEXTURE
        open_here = sky_cells[_cells(pixels[rows], camera)]
        rows = rows[open_here]
        u = np.minimum(pixels[rows, 0].astype(np.int64), camera.width - 1)
        v = np.minimum(pixels[rows, 1].astype(np.int64), camera.height - 1)
        colour_sum[rows] += np.asarray(image)[v, u, :3]
        seen[rows] += 1
    keep = (seen > 0) & (seen >= SKY_OPEN_FRACTION * framed)
    colours = colour_sum[keep] / seen[keep, None]            # seen > 0 where kept
    colours = np.clip(colours * 255.0 + 0.5, 0, 255).astype(np.uint8)
    scales = np.full(int(keep.sum()), 0.5 * spacing * radius)
    return shell[keep], colours, scales, np.array([*centre, radius])


def in_background(means: torch.Tensor, sphere: torch.Tensor | None) -> torch.Tensor:
    """[N] bool: Gaussians farther from the shell's centre than BACKGROUND_FRACTION of its radius
    (all False without a shell). means: [N, 3]; sphere: [4] (centre, radius) or None."""
    if sphere is None:
        return torch.zeros(means.shape[0], dtype=torch.bool, device=means.device)
    sphere = sphere.to(means.device, means.dtype)
    return (means - sphere[:3]).norm(dim=1) > BACKGROUND_FRACTION * sphere[3]


# A shell Gaussian hidden behind the scene in every training view that frames it keeps the
# colour and opacity it started with, and a held-out view that sees past a silhouette shows
# them: on the objects demo (2400 steps) the sky beside the silhouettes scored 17 dB against
# 32 dB in open sky. Each takes the mean of this many nearest shell Gaussians seen as sky
# (benchmarks/bench_silhouette.py: +0.39 dB on the scarce views there).
FILL_NEIGHBOURS = 8
# Where the scene's own Gaussians cover a pixel less than this, the shell behind shows as sky.
FOREGROUND_ALPHA = 0.5
# The end-of-run fill recolours a shell Gaussian only where the scene covers it at least this much
# in every training view that frames it: behind a translucent foreground (alpha 0.5-0.99) its
# trained colour still shows in the training photos, and overwriting it with distant donors'
# cost fern 0.27 dB (24.92 -> 24.65 at step 2000: 9 694 of 20 564 shell Gaussians refilled).
HIDDEN_ALPHA = 0.99
# The training views' foreground alpha is rendered at most this many pixels wide: the test asks
# only whether a shell centre lies behind the scene (a 4x smaller render costs 1/16), but the
# silhouettes must stay sharp (the demo's 96-pixel views rendered 4x smaller filled 17k shell
# Gaussians instead of 4k and cost its covered views 0.18 dB).
FILL_RENDER_WIDTH = 320
FILL_BAR_VIEWS = 200    # fewer take a few seconds: no bar
# Rows of hidden Gaussians per distance block: [rows, seen] float32 stays under ~50 MB.
FILL_BLOCK_ROWS = 1024


def shell_exposure(means: torch.Tensor, cameras: list[Camera], alphas: list[torch.Tensor],
                   hidden_alpha: float = FOREGROUND_ALPHA) -> torch.Tensor:
    """[S] int8 for shell centres means [S, 3]: 1 where some camera frames the centre on a pixel
    whose foreground alpha (alphas[k]: [h, w] of cameras[k]) is below FOREGROUND_ALPHA (it shows
    as sky there), 0 where every camera that frames it sees the scene in front with alpha at least
    ``hidden_alpha`` (hidden), 2 where it is framed, never sky, but not hidden (behind a
    translucent foreground; none with the default ``hidden_alpha``), -1 where no camera frames it."""
    points = means.detach().double().cpu().numpy()
    framed = np.zeros(len(points), dtype=bool)
    sky = np.zeros(len(points), dtype=bool)
    shows = np.zeros(len(points), dtype=bool)   # behind less than hidden_alpha in some view
    for camera, alpha in zip(cameras, alphas):
        pixels, _, inside = project_cloud(points, camera)
        rows = np.nonzero(inside)[0]
        u = np.minimum(pixels[rows, 0].astype(np.int64), camera.width - 1)
        v = np.minimum(pixels[rows, 1].astype(np.int64), camera.height - 1)
        framed[rows] = True
        cover = alpha.detach().cpu().numpy()[v, u]
        sky[rows[cover < FOREGROUND_ALPHA]] = True
        shows[rows[cover < hidden_alpha]] = True
    code = np.where(sky, 1, np.where(shows, 2, np.where(framed, 0, -1)))
    return torch.as_tensor(code, dtype=torch.int8, device=means.device)


def fill_hidden_shell(params: dict[str, torch.Tensor], hidden: torch.Tensor, donors: torch.Tensor,
                      neighbours: int = FILL_NEIGHBOURS) -> int:
    """In place on ``params`` ("means" [N, 3], "sh_dc" [N, 1, 3], optional "sh_rest" [N, K, 3],
    "opacity_logits" [N]): every hidden Gaussian (hidden [N] bool) takes the mean base colour and
    mean opacity logit of its ``neighbours`` nearest donors (donors [N] bool: shell Gaussians
    seen as sky), and no view-dependent colour (nothing observed it). Returns how many were
    filled: 0 when none is hidden or there is no donor."""
    with torch.no_grad():
        hidden_rows = torch.nonzero(hidden & ~donors).squeeze(-1)
        donor_rows = torch.nonzero(donors).squeeze(-1)
        if len(hidden_rows) == 0 or len(donor_rows) == 0:
            return 0
        k = min(int(neighbours), len(donor_rows))
        donor_means = params["means"][donor_rows].float()
        for start in range(0, len(hidden_rows), FILL_BLOCK_ROWS):
            rows = hidden_rows[start:start + FILL_BLOCK_ROWS]
            distances = torch.cdist(params["means"][rows].float(), donor_means)               # [B, D]
            nearest = donor_rows[distances.topk(k, dim=1, largest=False).indices]             # [B, k]
            params["sh_dc"][rows] = params["sh_dc"][nearest].mean(1)
            params["opacity_logits"][rows] = params["opacity_logits"][nearest].mean(1)
            if "sh_rest" in params:
                params["sh_rest"][rows] = 0.0
        return len(hidden_rows)


def fill_shell_behind_scene(params: dict[str, torch.Tensor], sphere: torch.Tensor, cameras: list[Camera],
                            rasterizer, hidden_alpha: float = HIDDEN_ALPHA, progress: bool = False) -> int:
    """The end-of-training fill: the shell (beyond BACKGROUND_FRACTION of ``sphere`` [4]) hidden
    behind the scene (foreground alpha >= ``hidden_alpha``) in every training camera (``cameras``)
    takes its sky-seen neighbours' colour. rasterizer: the run's
    rasterizer (inceptiongs.rasterizer.interface.Rasterizer), which draws the scene's own
    Gaussians' alpha at most FILL_RENDER_WIDTH pixels wide (tens of ms a view on two CPU cores:
    ``progress`` shows a bar when there are more than FILL_BAR_VIEWS). Returns how many were filled."""
    background = in_background(params["means"].detach(), sphere)
    if not bool(background.any()) or bool(background.all()):
        return 0
    small = [camera.scaled(max(1.0, camera.width / FILL_RENDER_WIDTH)) for camera in cameras]
    with torch.no_grad():
        scene_part = gaussians_from_params(params).detach().subset(~background)     # built once for every view
        shown = tqdm(small, desc="sky shell: views it hides behind", unit="view", file=sys.stderr, leave=False,
                     disable=not progress or len(small) <= FILL_BAR_VIEWS)
        alphas = [rasterizer(scene_part, camera, outputs=("alpha",))["alpha"][..., 0] for camera in shown]
    exposure = shell_exposure(params["means"][background], small, alphas, hidden_alpha)
    hidden = torch.zeros_like(background)
    donors = torch.zeros_like(background)
    hidden[background] = exposure == 0
    donors[background] = exposure == 1
    return fill_hidden_shell(params, hidden, donors)
