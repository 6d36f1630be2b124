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

import numpy as np
import torch

from ..camera import Camera, project_points

# The shell's radius, in units of the sparse points' far extent (their 99th-percentile
# distance from the cameras' centroid): far enough that the rig's parallax on it is small.
SKY_RADIUS_FACTOR = 4.0
# Directions on the whole sphere: at most this many (about 0.032 rad apart), and no closer
# than SKY_PIXELS pixels of the median camera (finer than that no photo resolves).
SKY_MAX_DIRECTIONS = 12_000
SKY_PIXELS = 6.0
# An image cell (of a SKY_GRID x SKY_GRID grid) with no sparse point in it shows open sky.
SKY_GRID = 16
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
    pixels, _, inside = project_points(points, camera)
    occupied = np.zeros(SKY_GRID * SKY_GRID, dtype=bool)
    occupied[_cells(pixels[inside], camera)] = True
    return ~occupied


def shell_geometry(cameras: list[Camera], points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre [3], radius) of the shell: the cameras' centroid, SKY_RADIUS_FACTOR x the far extent
    of the sparse points and cameras around it (at least 1 scene unit)."""
    centers = np.stack([c.center for c in cameras])
    centre = centers.mean(0)
    spread = np.linalg.norm(np.concatenate([np.asarray(points, np.float64).reshape(-1, 3), centers]) - centre, axis=1)
    return centre, SKY_RADIUS_FACTOR * max(float(np.percentile(spread, 99)), 1.0)


def sky_shell(cameras: list[Camera], images: list[np.ndarray], points: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The shell's Gaussians. images[k]: [H, W, 3] in [0, 1] of cameras[k]; points: [P, 3].

    Returns (means [S, 3], colours [S, 3] uint8: the mean of the photos' pixels there, scales [S]:
    half the directions' spacing at the radius, sphere [4]: centre and radius); S may be 0.
    """
    centre, radius = shell_geometry(cameras, points)
    focal = float(np.median([max(c.fx, c.fy) for c in cameras]))
    spacing = max(math.sqrt(4.0 * math.pi / SKY_MAX_DIRECTIONS), SKY_PIXELS / max(focal, 1.0))
    directions = fibonacci_directions(max(1, int(4.0 * math.pi / spacing ** 2)))
    shell = centre + radius * directions
    colour_sum = np.zeros((len(shell), 3))
    seen = np.zeros(len(shell))
    for camera, image in zip(cameras, images):
        pixels, _, inside = project_points(shell, camera)
        rows = np.nonzero(inside)[0]
        open_here = open_cells(camera, points)[_cells(pixels[rows], camera)]
        rows = rows[open_here]
        u = np.minimum(pixels[rows, 0].astype(np.int64), camera.width - 1)
        v = np.minimum(pixels[rows, 1].astype(np.int64), camera.height - 1)
        colour_sum[rows] += np.asarray(image)[v, u, :3]
        seen[rows] += 1
    keep = seen > 0
    colours = colour_sum[keep] / seen[keep, None]            # seen > 0 where kept
    colours = np.clip(colours * 255.0 + 0.5, 0, 255).astype(np.uint8)
    scales = np.full(int(keep.sum()), 0.5 * spacing * radius)
    return shell[keep], colours, scales, np.array([*centre, radius])


def in_background(means: torch.Tensor, sphere: torch.Tensor | None) -> torch.Tensor:
    """[N] bool: Gaussians farther from the shell's centre than BACKGROUND_FRACTION of its radius
    (all False without a shell). means: [N, 3]; sphere: [4] (centre, radius) or None."""
    if sphere is None:
        return torch.zeros(means.shape[0], dtype=torch.bool)
    sphere = sphere.to(means.dtype)
    return (means - sphere[:3]).norm(dim=1) > BACKGROUND_FRACTION * sphere[3]
