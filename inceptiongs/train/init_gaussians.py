"""Initial Gaussians: one per sparse point, or random points inside the cameras' view volume."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import torch

from ..camera import Camera, project_points
from ..constants import SH_C0, SH_OFFSET, sh_coeff_count
from ..gaussians import Gaussians
from .nearest_points import mean_nearest_distance

INITIAL_OPACITY = 0.1
# Floor on the nearest-neighbour distance used as the initial scale: duplicate points
# (distance 0) would give log(0).
_MIN_NEIGHBOUR_DISTANCE = 1e-7
_CHUNK = 2048
# Above this many points the dense [P, P] distances (P^2) give way to the grid search; below
# it they cost under a second and need no compiled code.
_GRID_FROM = 20_000


def scene_extent(cameras: list[Camera]) -> float:
    """Radius of the camera centres around their centroid, x1.1 (the 3DGS convention).

    Used to scale the position learning rate and the densification size limits. A single
    camera (or coincident ones) has no spread, so fall back to 1 scene unit.
    """
    centers = np.stack([c.center for c in cameras])
    radius = float(np.linalg.norm(centers - centers.mean(0), axis=1).max()) * 1.1
    return radius if radius > 1e-6 else 1.0


def mean_neighbour_distance(points: torch.Tensor, k: int = 3) -> torch.Tensor:
    """points: [P, 3] -> mean distance to the k nearest other points: [P] (chunked cdist; on a
    grid above _GRID_FROM points, nearest_points.py)."""
    p = points.shape[0]
    k_eff = min(k, p - 1)
    if k_eff < 1:
        return torch.ones(p, dtype=points.dtype)
    if p > _GRID_FROM:
        return mean_nearest_distance(points, k_eff).clamp_min(_MIN_NEIGHBOUR_DISTANCE)
    out = torch.empty(p, dtype=points.dtype)
    for start in range(0, p, _CHUNK):
        block = torch.cdist(points[start:start + _CHUNK], points)
        # k_eff + 1 smallest include the point itself (distance 0).
        nearest = block.topk(k_eff + 1, dim=1, largest=False).values[:, 1:]
        out[start:start + _CHUNK] = nearest.mean(1)
    return out.clamp_min(_MIN_NEIGHBOUR_DISTANCE)


def random_points_in_view(cameras: list[Camera], count: int, near: float, far: float,
                          generator: np.random.Generator, pixel_sigma: float = 2.0
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Random points on random cameras' pixels, depth log-uniform in [near, far] (0 < near < far).

    Returns (points [count, 3], scales [count]): each scale spans ``pixel_sigma`` pixels at
    its depth in the camera it was drawn from, so the cloud covers the images without
    Gaussians the size of the screen (which would also make every step slow).
    """
    out = np.empty((count, 3))
    scales = np.empty(count)
    which = generator.integers(0, len(cameras), size=count)
    for index, cam in enumerate(cameras):
        rows = np.nonzero(which == index)[0]
        if rows.size == 0:
            continue
        u = generator.uniform(0, cam.width, rows.size)
        v = generator.uniform(0, cam.height, rows.size)
        # Log-uniform: the unknown scene depth is equally likely at every order of magnitude.
        z = np.exp(generator.uniform(math.log(near), math.log(far), rows.size))
        camera_points = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], 1)
        c2w = cam.camera_to_world
        out[rows] = camera_points @ c2w[:3, :3].T + c2w[:3, 3]
        scales[rows] = pixel_sigma * z / max(cam.fx, cam.fy)
    return out, scales


def gaussians_from_points(points: np.ndarray, colors: np.ndarray | None, sh_degree: int,
                          dtype=torch.float32, scales: np.ndarray | None = None) -> Gaussians:
    """points: [P, 3]; colors: [P, 3] uint8 or None (grey); scales: [P] or None -> isotropic
    Gaussians.

    Scale = ``scales`` or the mean distance to the 3 nearest points (so the cloud starts
    hole-free), opacity
    0.1, identity rotation, SH with all ``sh_degree`` bands allocated and the higher bands 0.
    """
    means = torch.as_tensor(np.asarray(points, np.float64), dtype=dtype)
    p = means.shape[0]
    rgb = (torch.full((p, 3), 0.5, dtype=dtype) if colors is None
           else torch.as_tensor(np.asarray(colors), dtype=dtype) / 255.0)
    sh = torch.zeros(p, sh_coeff_count(sh_degree), 3, dtype=dtype)
    sh[:, 0] = (rgb - SH_OFFSET) / SH_C0
    distance = (mean_neighbour_distance(means) if scales is None
                else torch.as_tensor(scales, dtype=means.dtype).clamp_min(_MIN_NEIGHBOUR_DISTANCE))
    log_scales = torch.log(distance).unsqueeze(1).repeat(1, 3)
    quats = torch.zeros(p, 4, dtype=dtype)
    quats[:, 0] = 1.0
    opacity_logits = torch.full((p,), math.log(INITIAL_OPACITY / (1 - INITIAL_OPACITY)), dtype=dtype)
    return Gaussians(means, log_scales.to(dtype), quats, opacity_logits, sh)


def initial_gaussians(cameras: list[Camera], points: np.ndarray, colors: np.ndarray | None,
                      sh_degree: int, seed: int, random_count: int = 20_000) -> tuple[Gaussians, str]:
    """Gaussians from the sparse points, or random in the view volume if there are none.

    Returns the Gaussians and one line saying which initialisation was used.
    """
    if len(points) > 0:
        return (gaussians_from_points(points, colors, sh_degree),
                f"initialised {len(points)} Gaussians from the sparse points")
    extent = scene_extent(cameras)
    rng = np.random.default_rng(seed)
    # Without points the depth range is unknown: forward-facing captures (LLFF) sit many
    # camera-spreads away, object captures about one; cover both orders of magnitude.
    random_points, scales = random_points_in_view(cameras, random_count, 0.3 * extent, 30.0 * extent, rng)
    return (gaussians_from_points(random_points, None, sh_degree, scales=scales),
            f"scene has no sparse points: initialised {random_count} random Gaussians in the view volume")


def sparse_depth_samples(camera: Camera, image: np.ndarray, points: np.ndarray, count: int,
                         generator: np.random.Generator, neighbours: int = 3, pixel_sigma: float = 2.0
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Photo-coloured points on random pixels of one view, at the depth of the sparse points
    that project nearest to each pixel.

    A few thousand triangulated points are too sparse to start from on their own (their
    nearest-neighbour scales span tens of pixels, so every step composites a 30x overdraw),
    but their depths interpolate well between them: each random pixel takes the median
    camera depth of the ``neighbours`` nearest projected points (the median ignores a
    single wrong one at a depth edge). image: [H, W, 3] in [0, 1]; points: [P, 3] world.
    Returns (points [M, 3], colours [M, 3] uint8, scales [M]) with M = count, or empty
    arrays when no point projects into the view.
    """
    pixels_of_points, z, inside = project_points(points, camera)
    if inside.sum() < neighbours:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0)
    projected = pixels_of_points[inside]
    depths = z[inside]
    pixels = np.stack([generator.uniform(0, camera.width, count), generator.uniform(0, camera.height, count)], 1)
    squared = ((pixels[:, None, :] - projected[None, :, :]) ** 2).sum(-1)          # [M, P]
    nearest = np.argpartition(squared, neighbours - 1, axis=1)[:, :neighbours]
    depth = np.median(depths[nearest], axis=1)                                      # > NEAR_PLANE
    local = np.stack([(pixels[:, 0] - camera.cx) / camera.fx * depth,
                      (pixels[:, 1] - camera.cy) / camera.fy * depth, depth], 1)
    c2w = camera.camera_to_world
    world = local @ c2w[:3, :3].T + c2w[:3, 3]
    rows = np.minimum(pixels[:, 1].astype(np.int64), camera.height - 1)
    cols = np.minimum(pixels[:, 0].astype(np.int64), camera.width - 1)
    colours = np.clip(np.asarray(image)[rows, cols] * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return world, colours, pixel_sigma * depth / max(camera.fx, camera.fy)


def gaussians_from_sparse_depth(cameras: list[Camera], images: Iterable[np.ndarray], points: np.ndarray,
                                sh_degree: int, seed: int, count: int = 30_000) -> tuple[Gaussians, str]:
    """``count`` pixel-sized, photo-coloured Gaussians spread evenly over the training views
    at depths interpolated from the sparse ``points`` [P, 3] (see sparse_depth_samples).
    images[k] belongs to cameras[k]. Falls back to the points themselves when none project."""
    rng = np.random.default_rng(seed)
    per_view = max(1, count // max(len(cameras), 1))
    parts = [sparse_depth_samples(cam, image, points, per_view, rng) for cam, image in zip(cameras, images)]
    parts = [p for p in parts if len(p[0])]
    if not parts:
        return gaussians_from_points(points, None, sh_degree), f"initialised {len(points)} Gaussians from the sparse points"
    means, colours, scales = (np.concatenate(column) for column in zip(*parts))
    return (gaussians_from_points(means, colours, sh_degree, scales=scales),
            f"initialised {len(means)} photo-coloured Gaussians at depths interpolated from "
            f"{len(points)} sparse points")
