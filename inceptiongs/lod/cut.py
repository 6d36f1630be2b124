"""Which nodes of a :class:`~.hierarchy.LodHierarchy` to draw for one camera.

A node's projected size is ``radius * focal / depth`` pixels (focal = max(fx, fy), depth its
centre's camera z floored at the near plane). The cut at a granularity g walks down from the
root, level by level (vectorised over the frontier): a node is expanded while its size >= g
and drawn once it is smaller (leaves are drawn whatever their size). Nodes whose sphere lies
behind the near plane or outside the frustum (widened as the rasterizer widens it, by
FRUSTUM_CLAMP_MARGIN) are dropped with their subtrees; a node whose sphere holds the camera
centre has no meaningful size and is always expanded.

g = 0 draws every visible leaf (the exact model); g = inf draws the root. The budget cut is
the finest of these cuts with at most ``budget`` nodes.
"""

from __future__ import annotations

import math

import numpy as np

from ..camera import Camera
from ..constants import NEAR_PLANE
from ..gaussians import Gaussians
from ..rasterizer.projection import view_ratio_bounds
from .hierarchy import LodHierarchy


def camera_space(means: np.ndarray, world_to_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """[S, 3] world points -> their camera-space x, y, z, each [S] float64 (a node far from the
    origin keeps its offset to a camera beside it). Column by column: numpy's [S, 3] @ [3, 3]
    is several times slower than nine multiply-adds."""
    columns = [means[:, axis].astype(np.float64) for axis in range(3)]
    rotation, translation = world_to_camera[:3, :3], world_to_camera[:3, 3]
    return tuple(columns[0] * rotation[row, 0] + columns[1] * rotation[row, 1] + columns[2] * rotation[row, 2]
                 + translation[row] for row in range(3))


def node_sizes(hierarchy: LodHierarchy, camera: Camera, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """nodes [S] int -> (projected size in pixels [S] float64, inf where the sphere holds the
    camera; culled [S] bool: the sphere is entirely behind the near plane or outside the frustum)."""
    x, y, z = camera_space(hierarchy.means[nodes], camera.world_to_camera)
    radii = hierarchy.radii[nodes].astype(np.float64)
    holds_camera = x * x + y * y + z * z <= radii * radii
    culled = z + radii < NEAR_PLANE
    lo_x, hi_x, lo_y, hi_y = view_ratio_bounds(camera)
    # Signed distance of the centre outside each side plane u = bound * z (unit normals).
    for along, bound, sign in ((x, lo_x, -1.0), (x, hi_x, 1.0), (y, lo_y, -1.0), (y, hi_y, 1.0)):
        culled |= sign * (along - bound * z) / math.sqrt(1.0 + bound * bound) > radii
    culled &= ~holds_camera
    focal = max(camera.fx, camera.fy)
    sizes = radii * focal / np.maximum(z, NEAR_PLANE)   # floored depth: the division is bounded
    return np.where(holds_camera, np.inf, sizes), culled


def children_of(hierarchy: LodHierarchy, nodes: np.ndarray) -> np.ndarray:
    """[S] node indices -> [C] all their children (concatenated child ranges), int64."""
    counts = hierarchy.child_count[nodes].astype(np.int64)
    starts = hierarchy.child_start[nodes].astype(np.int64)
    first = np.cumsum(counts) - counts   # where each node's children begin in the output
    return np.repeat(starts - first, counts) + np.arange(int(counts.sum()), dtype=np.int64)


def cut_nodes(hierarchy: LodHierarchy, camera: Camera, granularity_px: float) -> np.ndarray:
    """The nodes to draw at ``granularity_px`` (see the module doc): [S] int64, ascending. The
    numba pass of :mod:`.cut_numba`; :func:`walk_cut_nodes` is the same cut in numpy."""
    from .cut_numba import DRAWN, cut_states  # noqa: PLC0415  (numba compiles on first use)

    if not granularity_px >= 0.0:
        raise ValueError(f"granularity must be >= 0 pixels, got {granularity_px}")
    return np.flatnonzero(cut_states(hierarchy, camera, granularity_px, view_ratio_bounds(camera)) == DRAWN)


def walk_cut_nodes(hierarchy: LodHierarchy, camera: Camera, granularity_px: float) -> np.ndarray:
    """:func:`cut_nodes` by walking down from the root level by level, vectorised over the
    frontier (the reference the numba pass is tested against)."""
    if not granularity_px >= 0.0:
        raise ValueError(f"granularity must be >= 0 pixels, got {granularity_px}")
    frontier = hierarchy.roots.astype(np.int64)
    drawn = []
    while frontier.size:
        sizes, culled = node_sizes(hierarchy, camera, frontier)
        frontier, sizes = frontier[~culled], sizes[~culled]
        expand = (sizes >= granularity_px) & (hierarchy.child_count[frontier] > 0)
        drawn.append(frontier[~expand])
        frontier = children_of(hierarchy, frontier[expand])
    return np.sort(np.concatenate(drawn)) if drawn else np.zeros(0, np.int64)


def cut_intervals(hierarchy: LodHierarchy, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every node's granularity interval: node n is in the cut at g iff ``kept[n]`` and
    ``lower[n] < g <= upper[n]``. All three [M]; O(M) work, one pass per level, root down.

    lower = the smallest size on the path root..n (n is expanded iff every node on it has
    size >= g), -1 for leaves (never expanded); upper = the parent's lower (inf at the root);
    kept: neither n nor an ancestor is culled.
    """
    everything = np.arange(len(hierarchy), dtype=np.int64)
    sizes, culled = node_sizes(hierarchy, camera, everything)
    lower, kept = sizes, ~culled
    offsets = hierarchy.level_offsets
    for level in range(hierarchy.levels - 2, -1, -1):   # below the root, top down
        span = slice(int(offsets[level]), int(offsets[level + 1]))
        parents = hierarchy.parent[span]
        lower[span] = np.minimum(lower[span], lower[parents])
        kept[span] &= kept[parents]
    upper = np.where(hierarchy.parent >= 0, lower[hierarchy.parent], np.inf)
    lower[hierarchy.child_count == 0] = -1.0
    return lower, upper, kept


def _largest_first(hierarchy: LodHierarchy, camera: Camera, nodes: np.ndarray, budget: int) -> np.ndarray:
    """The ``budget`` nodes of ``nodes`` with the largest projected sizes, ascending by index."""
    sizes, _ = node_sizes(hierarchy, camera, nodes)
    return np.sort(nodes[np.argsort(-sizes, kind="stable")[:budget]])


def budget_cut_nodes(hierarchy: LodHierarchy, camera: Camera, budget: int) -> tuple[np.ndarray, float]:
    """The finest cut with at most ``budget`` nodes -> (nodes [S] int64 ascending, its granularity).

    The cut only changes where g crosses a node's interval end, so the candidates are those
    ends (and 0); the count at each is #(lower < g) - #(upper < g) by binary search. When even
    the coarsest cut is over the budget (a root holding the camera), the ``budget`` largest
    nodes of it are kept: the budget is a hard limit.
    """
    if budget < 0:
        raise ValueError(f"budget must be >= 0 splats, got {budget}")
    lower, upper, kept = cut_intervals(hierarchy, camera)
    lower, upper = lower[kept], upper[kept]
    candidates = np.unique(np.concatenate([[0.0, np.inf], lower[lower >= 0.0], upper]))
    counts = (np.searchsorted(np.sort(lower), candidates, side="left")
              - np.searchsorted(np.sort(upper), candidates, side="left"))
    fits = np.flatnonzero(counts <= budget)
    granularity = float(candidates[fits[0]]) if fits.size else math.inf
    nodes = np.flatnonzero(kept)[(lower < granularity) & (granularity <= upper)]
    return (_largest_first(hierarchy, camera, nodes, budget) if nodes.size > budget else nodes), granularity


def lod_gaussians(hierarchy: LodHierarchy, camera: Camera, granularity_px: float | None = None,
                  budget: int | None = None, device=None) -> Gaussians:
    """The Gaussians to render for ``camera``: the cut at ``granularity_px``, or the finest cut
    within ``budget`` splats (exactly one of the two)."""
    if (granularity_px is None) == (budget is None):
        raise ValueError("give exactly one of granularity_px and budget")
    if budget is not None:
        nodes, _ = budget_cut_nodes(hierarchy, camera, budget)
    else:
        nodes = cut_nodes(hierarchy, camera, granularity_px)
    return hierarchy.gaussians(nodes, device=device)


def _expansion_gains(hierarchy: LodHierarchy, camera: Camera, parents: np.ndarray):
    """-> (kept children [C], their sizes [C], each parent's change of the count [P]: its kept
    children minus itself)."""
    children = children_of(hierarchy, parents)
    sizes, culled = node_sizes(hierarchy, camera, children)
    owner = np.repeat(np.arange(len(parents)), hierarchy.child_count[parents])
    kept_per_parent = np.bincount(owner[~culled], minlength=len(parents))
    return children[~culled], sizes[~culled], owner[~culled], kept_per_parent - 1


def greedy_budget_cut_nodes(hierarchy: LodHierarchy, camera: Camera, budget: int) -> np.ndarray:
    """A cut of at most ``budget`` nodes grown from the root by expanding the largest projected
    nodes first, in batches -> [S] int64 ascending. Its work grows with the budget, not with
    the tree (:func:`budget_cut_nodes` visits every node): the per-frame choice for large models.

    Each round takes the frontier's expandable nodes by decreasing size, evaluates the children
    of as many as could fit, and expands the longest prefix whose added count fits; it stops
    when the largest remaining node does not fit. Within a round, a child larger than the next
    frontier node waits for the next round, so the order is by size only batch by batch.
    """
    if budget < 0:
        raise ValueError(f"budget must be >= 0 splats, got {budget}")
    roots = hierarchy.roots.astype(np.int64)
    sizes, culled = node_sizes(hierarchy, camera, roots)
    frontier, sizes = roots[~culled], sizes[~culled]
    if len(frontier) > budget:
        return _largest_first(hierarchy, camera, frontier, budget)
    step = max(hierarchy.branching - 1, 1)
    while True:
        openable = np.flatnonzero(hierarchy.child_count[frontier] > 0)
        room = budget - len(frontier)
        if openable.size == 0:
            break
        openable = openable[np.argsort(-sizes[openable], kind="stable")][:room // step + 1]
        children, child_sizes, owner, gains = _expansion_gains(hierarchy, camera, frontier[openable])
        # The longest prefix whose running count never passes the budget (gains may be -1).
        fits = np.maximum.accumulate(np.cumsum(gains)) <= room
        taken = int(np.argmin(fits)) if not fits.all() else len(fits)
        if taken == 0:
            break
        keep = np.ones(len(frontier), bool)
        keep[openable[:taken]] = False
        joined = owner < taken
        frontier = np.concatenate([frontier[keep], children[joined]])
        sizes = np.concatenate([sizes[keep], child_sizes[joined]])
    return np.sort(frontier)
