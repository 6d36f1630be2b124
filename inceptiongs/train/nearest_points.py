"""The mean distance of every point of a large cloud to its k nearest other points, exactly, on
a uniform grid searched in growing rings of cells (numba).

A dense [P, P] distance matrix costs P^2: a town's 172,000 sparse points are 30 billion
distances, minutes before the first step. On the grid a point reads the cells around its own
until no unread point can be nearer than its k-th nearest so far (every point of a cell
r rings away lies at least r cells' widths away), so a cloud of even density costs O(P k).
An isolated point whose search would read many rings is compared with every point instead.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch

# Cells per point: the grid's cell count is about this multiple of the number of points (a
# point's own ring then holds a few points wherever the cloud is even); at most _MAX_CELLS.
_CELLS_PER_POINT = 2.0
_MAX_CELLS = 1 << 22
# A point whose k nearest lie further than this many rings reads every point instead.
_MAX_RINGS = 6


def grid_cell_size(points: np.ndarray) -> float:
    """points: [P, 3] (P >= 2) -> the cells' edge: the bounding box cut into about
    _CELLS_PER_POINT x P cubes (at most _MAX_CELLS); > 0 even for a flat or collapsed cloud."""
    extent = points.max(0) - points.min(0)
    largest = float(extent.max())
    if largest <= 0.0:                   # every point in one place: one cell holds them all
        return 1.0
    # Flat axes (a facade, a ground plane) count with the width of one cell, not zero.
    size = largest / 2.0
    for _ in range(64):
        cells = np.prod(np.floor(extent / size) + 1.0)
        if cells >= min(_CELLS_PER_POINT * len(points), _MAX_CELLS):
            break
        size /= 1.25
    while np.prod(np.floor(extent / size) + 1.0) > _MAX_CELLS:
        size *= 1.25
    return size


@numba.njit(cache=True)
def _offer(best, points, i, j):                          # pragma: no cover - compiled
    """Point j as a neighbour of point i: its squared distance enters ``best`` (ascending, [k])
    when it is below the largest kept; i itself never does."""
    if j == i:
        return
    d2 = ((points[j, 0] - points[i, 0]) ** 2 + (points[j, 1] - points[i, 1]) ** 2
          + (points[j, 2] - points[i, 2]) ** 2)
    k = best.shape[0]
    if d2 < best[k - 1]:
        slot = k - 1
        while slot > 0 and best[slot - 1] > d2:
            best[slot] = best[slot - 1]
            slot -= 1
        best[slot] = d2


@numba.njit(cache=True, parallel=True)
def _mean_nearest(points, cell_of, starts, order, dims, size, k):      # pragma: no cover - compiled
    p = points.shape[0]
    nx, ny, nz = dims[0], dims[1], dims[2]
    out = np.empty(p, dtype=np.float64)
    for i in numba.prange(p):
        best = np.full(k, np.inf)                 # squared distances, ascending
        cx = cell_of[i, 0]
        cy = cell_of[i, 1]
        cz = cell_of[i, 2]
        ring = 0
        done = False
        while not done:
            if ring > _MAX_RINGS:                 # isolated: every point
                best[:] = np.inf
                for j in range(p):
                    _offer(best, points, i, j)
                break
            for x in range(max(cx - ring, 0), min(cx + ring, nx - 1) + 1):
                for y in range(max(cy - ring, 0), min(cy + ring, ny - 1) + 1):
                    for z in range(max(cz - ring, 0), min(cz + ring, nz - 1) + 1):
                        if max(abs(x - cx), abs(y - cy), abs(z - cz)) != ring:
                            continue              # read in an earlier ring
                        cell = x + nx * (y + ny * z)
                        for slot_j in range(starts[cell], starts[cell + 1]):
                            _offer(best, points, i, order[slot_j])
            # An unread point lies at least `ring` cells' widths away on some axis.
            reach = ring * size
            outside = cx - ring <= 0 and cy - ring <= 0 and cz - ring <= 0 and \
                cx + ring >= nx - 1 and cy + ring >= ny - 1 and cz + ring >= nz - 1
            done = best[k - 1] <= reach * reach or outside
            ring += 1
        total = 0.0
        for slot in range(k):
            total += math.sqrt(best[slot])
        out[i] = total / k
    return out


def mean_nearest_distance(points: torch.Tensor, k: int) -> torch.Tensor:
    """points: [P, 3] (P > k >= 1) -> [P]: the mean distance of each point to its k nearest
    other points (a duplicate of a point counts, at distance 0), in float64 on the CPU, returned
    in points' dtype."""
    cloud = points.detach().to("cpu", torch.float64).numpy()
    size = grid_cell_size(cloud)
    low = cloud.min(0)
    cell_of = np.floor((cloud - low) / size).astype(np.int64)
    dims = cell_of.max(0) + 1
    linear = cell_of[:, 0] + dims[0] * (cell_of[:, 1] + dims[1] * cell_of[:, 2])
    order = np.argsort(linear, kind="stable")
    starts = np.zeros(int(np.prod(dims)) + 1, dtype=np.int64)
    np.cumsum(np.bincount(linear, minlength=int(np.prod(dims))), out=starts[1:])
    distances = _mean_nearest(cloud, cell_of, starts, order.astype(np.int64), dims.astype(np.int64), size, int(k))
    return torch.from_numpy(distances).to(points.dtype)
