"""Where a capture is thin: the directional viewing density of the cameras (the paper's Figure 1).

For surface points (sparse points or Gaussian centres) and cameras:

- ``visibility_matrix``: which camera sees which point (in front, inside the image, and, when
  a rendered depth map is given, not behind the surface it shows);
- ``view_counts`` / ``angular_radius_deg``: how many views see a point, and from how wide a
  range of directions (the angle between the mean viewing direction and the unit directions'
  mean length: 0 when every view looks from one direction);
- ``directional_density``: views per steradian over the hemisphere above a region of
  interest, a smoothed (von Mises-Fisher kernel) density of the directions from which its
  points are seen, normalised over the hemisphere so that a uniformly sampled hemisphere of
  N views reads N / (2 pi) everywhere, the rim included;
- ``view_scarcity``: per view, how little of what it shows is seen by the *other* (training)
  views from a similar viewpoint: the mean over its visible points of 1 / (1 + n), n = other
  views within ``window_deg`` of its own direction at that point and (optionally) at least
  half its resolution there. 1 = nothing it shows was seen from near its viewpoint; the
  highest-ranked views are the ones to flag.

All functions here are pure (numpy in, numpy out). ``inceptiongs.evaluation.coverage_run``
loads scenes and runs, renders depth and draws the figure.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..camera import Camera
from ..constants import NEAR_PLANE

# A point is visible in a depth map when its camera depth is at most this much (relative)
# behind the surface the pixel shows: Gaussian centres sit on the surface, half a Gaussian
# behind it at most, and the rendered depth is an alpha-weighted mean.
DEPTH_TOLERANCE = 0.05
# Directions count as "similar" within this angle (scarcity, directional counts): about the
# angle over which a surface's appearance and its photos' resolution stay comparable.
DIRECTION_WINDOW_DEG = 30.0
# A source view supports a view's content only if it images it at no less than 1 / this of the
# view's resolution (one octave: beyond it the detail the view shows was never photographed).
SCALE_RATIO = 2.0
# Kernel width of the hemisphere density (standard deviation of the angular kernel).
DENSITY_SIGMA_DEG = 15.0
# Hemisphere points used to normalise the kernel (the Fibonacci lattice's error is ~1/n).
_NORMALISER_SAMPLES = 8192
_NORM_MIN = 1e-12


def project(points: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """points [P, 3] world -> (pixel x [P], pixel y [P], camera depth z [P]); pixel (i, j)'s
    centre is at (i + 0.5, j + 0.5). x, y are meaningless where z <= NEAR_PLANE."""
    cam = points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
    z = cam[:, 2]
    safe = np.where(z > NEAR_PLANE, z, 1.0)  # behind the camera: any finite value, masked later
    return camera.fx * cam[:, 0] / safe + camera.cx, camera.fy * cam[:, 1] / safe + camera.cy, z


def visibility_matrix(points: np.ndarray, cameras: Sequence[Camera],
                      depths: Sequence[np.ndarray | None] | None = None,
                      tolerance: float = DEPTH_TOLERANCE) -> np.ndarray:
    """points [P, 3], N cameras, optional depth maps ([h, w] camera z, 0 = no surface, any
    resolution: looked up at the point's pixel scaled to the map) -> [P, N] bool."""
    visible = np.zeros((len(points), len(cameras)), dtype=bool)
    for k, camera in enumerate(cameras):
        x, y, z = project(points, camera)
        inside = (z > NEAR_PLANE) & (x >= 0) & (x < camera.width) & (y >= 0) & (y < camera.height)
        depth = None if depths is None else depths[k]
        if depth is not None and inside.any():
            h, w = depth.shape[:2]
            col = np.clip((x[inside] * w / camera.width).astype(np.int64), 0, w - 1)
            row = np.clip((y[inside] * h / camera.height).astype(np.int64), 0, h - 1)
            surface = depth.reshape(h, w)[row, col]
            # No surface at the pixel (depth 0) occludes nothing.
            unoccluded = (surface <= 0) | (z[inside] <= surface * (1.0 + tolerance))
            inside[np.flatnonzero(inside)[~unoccluded]] = False
        visible[:, k] = inside
    return visible


def view_directions(points: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """Unit directions from each point to each camera centre: points [P, 3], centers [N, 3]
    -> [P, N, 3]. A centre on a point gives the zero vector (no direction)."""
    d = centers[None, :, :] - points[:, None, :]
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    return d / np.maximum(norm, _NORM_MIN)


def view_counts(visible: np.ndarray) -> np.ndarray:
    """[P, N] bool -> [P] int: how many views see each point."""
    return visible.sum(axis=1)


def angular_radius_deg(directions: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """How widely spread the directions a point is seen from are: arccos of the length of the
    mean unit direction, in degrees. directions [P, N, 3], visible [P, N] -> [P]; 0 for points
    seen once or never, 90 for two opposite views."""
    counts = visible.sum(axis=1)
    mean = (directions * visible[..., None]).sum(axis=1) / np.maximum(counts, 1)[:, None]
    length = np.clip(np.linalg.norm(mean, axis=1), 0.0, 1.0)
    return np.where(counts > 0, np.degrees(np.arccos(length)), 0.0)


def directional_counts(directions: np.ndarray, visible: np.ndarray, query: np.ndarray,
                       window_deg: float = DIRECTION_WINDOW_DEG) -> np.ndarray:
    """How many views see each point from within ``window_deg`` of a query direction.
    directions [P, N, 3], visible [P, N], query [P, 3] (unit) -> [P] int."""
    cosines = np.einsum("pnc,pc->pn", directions, query)
    return (visible & (cosines >= math.cos(math.radians(window_deg)))).sum(axis=1)


def view_resolution(points: np.ndarray, cameras: Sequence[Camera]) -> np.ndarray:
    """Pixels per scene unit at which each camera images each point (focal length over
    distance; a surface's detail survives in a photo only at enough of these): [P, N]."""
    centers = np.array([c.center for c in cameras])
    focal = np.array([0.5 * (c.fx + c.fy) for c in cameras])
    distance = np.linalg.norm(points[:, None, :] - centers[None, :, :], axis=-1)
    return focal[None, :] / np.maximum(distance, _NORM_MIN)


def view_scarcity(directions: np.ndarray, visible: np.ndarray, sources: np.ndarray | None = None,
                  window_deg: float = DIRECTION_WINDOW_DEG, resolution: np.ndarray | None = None,
                  scale_ratio: float = SCALE_RATIO) -> np.ndarray:
    """Per view, the mean over the points it sees of 1 / (1 + n), n = the other source views
    that see the point from within ``window_deg`` of this view's direction (and, when
    ``resolution`` [P, N] is given, at no less than 1 / ``scale_ratio`` of this view's
    pixels per unit: a view from four times as far cannot supply the detail a close view shows).

    directions [P, N, 3], visible [P, N], sources [N] bool (views that count as seen-from, e.g.
    the training views; default all) -> [N] in (0, 1]; 1 also for a view that sees no point
    (nothing it shows is known)."""
    n = visible.shape[1]
    sources = np.ones(n, dtype=bool) if sources is None else np.asarray(sources, dtype=bool)
    cos_window = math.cos(math.radians(window_deg))
    scores = np.ones(n)
    for v in range(n):
        seen = np.flatnonzero(visible[:, v])
        if not len(seen):
            continue
        others = sources.copy()
        others[v] = False
        cosines = np.einsum("pnc,pc->pn", directions[seen][:, others], directions[seen, v])
        similar = visible[seen][:, others] & (cosines >= cos_window)
        if resolution is not None:
            similar &= resolution[seen][:, others] * scale_ratio >= resolution[seen, v][:, None]
        scores[v] = float(np.mean(1.0 / (1.0 + similar.sum(axis=1))))
    return scores


def scarcest_views(scores: np.ndarray, k: int, candidates: Sequence[int] | None = None) -> list[int]:
    """Indices of the k highest scarcity scores (ties -> lower index), among ``candidates``."""
    pool = np.arange(len(scores)) if candidates is None else np.asarray(list(candidates), dtype=np.int64)
    order = sorted(pool.tolist(), key=lambda i: (-scores[i], i))
    return order[:max(0, k)]


# --- the hemisphere -------------------------------------------------------------------------

def up_vector(cameras: Sequence[Camera], level_ratio: float = 0.25) -> np.ndarray:
    """The world's "up" as the cameras hold it, unit [3].

    People hold cameras level: every image's right axis (OpenCV x) is horizontal, so up is the
    direction most perpendicular to all of them (the smallest eigenvector of sum x x^T), signed
    like minus the mean image-down axis. That holds for a ring with a gap, where the mean down
    axis alone tilts towards the gap. When the right axes do not span a plane (a forward-facing
    capture: all nearly parallel; smallest eigenvalue above ``level_ratio`` times the middle
    one), up is the mean down axis negated, made perpendicular to the common right axis.
    Falls back to +z for a rig with no consistent up."""
    if not len(cameras):
        return np.array([0.0, 0.0, 1.0])
    rights = np.array([c.world_to_camera[0, :3] for c in cameras])
    down = np.mean([c.world_to_camera[1, :3] for c in cameras], axis=0)
    values, vectors = np.linalg.eigh(rights.T @ rights)           # ascending eigenvalues
    if values[0] < level_ratio * values[1]:
        up = vectors[:, 0] * (-1.0 if float(vectors[:, 0] @ down) > 0 else 1.0)
    else:
        common = vectors[:, 2]
        up = -(down - common * float(down @ common))
    norm = float(np.linalg.norm(up))
    return up / norm if norm > 1e-6 else np.array([0.0, 0.0, 1.0])


def hemisphere_frame(up: np.ndarray) -> np.ndarray:
    """Rows (east, north, up): a right-handed orthonormal basis [3, 3] with the given up; east
    is world x projected onto the horizontal plane (world y when up is along x)."""
    up = np.asarray(up, np.float64) / max(float(np.linalg.norm(up)), _NORM_MIN)
    seed = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    east = seed - up * float(seed @ up)
    east /= np.linalg.norm(east)  # |seed x up| >= sqrt(1 - 0.81): never ~0
    north = np.cross(up, east)
    return np.stack([east, north, up])


def hemisphere_grid(n_azimuth: int = 72, n_elevation: int = 18) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell centres of an azimuth x elevation grid over the upper hemisphere, local frame
    (east, north, up): -> (azimuth [A] rad in [0, 2pi), elevation [E] rad in (0, pi/2),
    directions [E, A, 3] unit)."""
    azimuth = (np.arange(n_azimuth) + 0.5) * 2 * math.pi / n_azimuth
    elevation = (np.arange(n_elevation) + 0.5) * 0.5 * math.pi / n_elevation
    ce, se = np.cos(elevation)[:, None], np.sin(elevation)[:, None]
    dirs = np.stack([ce * np.cos(azimuth)[None], ce * np.sin(azimuth)[None], np.broadcast_to(se, (n_elevation, n_azimuth))], -1)
    return azimuth, elevation, dirs


def fibonacci_hemisphere(n: int) -> np.ndarray:
    """n near-uniform unit directions [n, 3] over the upper hemisphere (z >= 0), local frame."""
    k = np.arange(n) + 0.5
    z = 1.0 - k / n                             # uniform in z on [0, 1] = uniform in area
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))  # golden angle
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def _kernel(cosines: np.ndarray, sigma_deg: float) -> np.ndarray:
    """von Mises-Fisher-shaped kernel exp(kappa (cos - 1)), kappa = 1 / sigma^2: 1 at 0 degrees."""
    kappa = 1.0 / math.radians(sigma_deg) ** 2
    return np.exp(kappa * (np.clip(cosines, -1.0, 1.0) - 1.0))   # exponent <= 0: no overflow


def directional_density(samples: np.ndarray, weights: np.ndarray, grid: np.ndarray,
                        sigma_deg: float = DENSITY_SIGMA_DEG) -> np.ndarray:
    """Views per steradian at each grid direction, from viewing directions in the local frame.

    samples [M, 3] unit (those below the horizon, z < 0, count nothing), weights [M] (e.g.
    1 / number of points, to average over a region's points), grid [..., 3] unit (upper
    hemisphere) -> [...]. Each direction's kernel is normalised by its mass over the upper
    hemisphere, so N uniform samples of weight 1 read N / (2 pi) at every grid direction."""
    shape = grid.shape[:-1]
    g = grid.reshape(-1, 3)
    above = samples[:, 2] >= 0
    s, w = samples[above], np.asarray(weights, np.float64)[above]
    total = np.zeros(len(g))
    for start in range(0, len(s), 4096):  # [G, chunk] at a time: bounded memory
        total += _kernel(g @ s[start:start + 4096].T, sigma_deg) @ w[start:start + 4096]
    lattice = fibonacci_hemisphere(_NORMALISER_SAMPLES)
    # Mass of each grid direction's kernel over the hemisphere; >= half the mass of a kernel
    # on the sphere (the kernel is centred on the hemisphere), so the division is safe.
    mass = _kernel(g @ lattice.T, sigma_deg).sum(axis=1) * (2.0 * math.pi / _NORMALISER_SAMPLES)
    return (total / mass).reshape(shape)


def region_directions(directions: np.ndarray, visible: np.ndarray, in_region: np.ndarray,
                      frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The viewing directions of a region's points in the hemisphere frame, weighted so the
    density is per point of the region: directions [P, N, 3], visible [P, N], in_region [P]
    bool, frame [3, 3] (rows east, north, up) -> (samples [M, 3], weights [M])."""
    rows, cols = np.nonzero(visible & in_region[:, None])
    count = int(in_region.sum())
    samples = directions[rows, cols] @ frame.T
    return samples, np.full(len(samples), 1.0 / max(count, 1))


def robust_bounds(points: np.ndarray, percentile: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box holding the points between the given low and high percentiles per
    axis (stray points do not stretch it): points [P, 3] -> (lo [3], hi [3])."""
    return np.percentile(points, percentile, axis=0), np.percentile(points, 100.0 - percentile, axis=0)


# --- colours (the viewer's coverage mode, figures) ------------------------------------------

# A perceptually ordered ramp (dark purple -> blue -> green -> yellow, as viridis): few views
# read dark, many bright. Stops at 0, 0.25, 0.5, 0.75, 1.
_RAMP = np.array([[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551],
                  [0.370, 0.789, 0.383], [0.993, 0.906, 0.144]])


def ramp_colours(values: np.ndarray, vmax: float) -> np.ndarray:
    """values [N] >= 0 -> colours [N, 3] in [0, 1], 0 at the dark end, >= vmax at the bright
    end (vmax <= 0 maps everything to the dark end)."""
    t = np.clip(np.asarray(values, np.float64) / vmax, 0.0, 1.0) if vmax > 0 else np.zeros(len(values))
    position = t * (len(_RAMP) - 1)
    low = np.minimum(np.floor(position).astype(np.int64), len(_RAMP) - 2)
    frac = (position - low)[:, None]
    return _RAMP[low] * (1.0 - frac) + _RAMP[low + 1] * frac


def colour_bar(vmax: float, height: int = 128, width: int = 16) -> np.ndarray:
    """The ramp as an image [height, width, 3] in [0, 1], vmax at the top row, 0 at the bottom."""
    values = np.linspace(vmax, 0.0, height)
    return np.repeat(ramp_colours(values, vmax)[:, None, :], width, axis=1)
