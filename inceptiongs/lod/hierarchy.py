"""The LOD hierarchy: every Gaussian of a model as a leaf, merged bottom-up into parents.

Layout (flat arrays, level by level, leaves first, the root last):

- nodes ``[level_offsets[l], level_offsets[l+1])`` form level l; level 0 holds the model's
  Gaussians (bit-exact copies) in Morton order, the last level is the one root;
- the children of a node are the contiguous range ``[child_start, child_start + child_count)``
  of the level below (``child_count`` 0 for leaves); ``parent`` is -1 for the root;
- ``radii``: a sphere around the node's mean holding the footprints of every leaf below it.

Building: one sort of the leaves by Morton code (3 x 21 bits of the position in the model's
bounding cube), so runs of consecutive leaves are spatially compact; then each level merges
runs of ``branching`` consecutive nodes (:func:`.moments.merge_groups`). O(N log N) for the
sort, O(N) numpy work per level, geometric in the levels.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Callable

import numpy as np
import torch

from ..gaussians import Gaussians
from .moments import bounding_radii, covariances_of, merge_groups, surface_weights

DEFAULT_BRANCHING = 4
MORTON_BITS = 21   # per axis: 3 x 21 bits fill a uint64
# The bounding cube's side is floored here before dividing, so a model whose Gaussians all
# sit at one point (side 0) still gets finite grid coordinates (all zero).
CUBE_SIDE_MIN = 1e-30
GAUSSIAN_FIELDS = ("means", "log_scales", "quats", "opacity_logits", "sh")
MERGE_CHUNK_PARENTS = 65_536


@dataclass
class LodHierarchy:
    """means [M, 3], log_scales [M, 3], quats [M, 4], opacity_logits [M], sh [M, K, 3]: the
    node Gaussians (float32); parent, child_start, child_count [M] int32; radii [M] float32;
    level_offsets [L + 1] int64; branching: the children per parent used to build it."""

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    parent: np.ndarray
    child_start: np.ndarray
    child_count: np.ndarray
    radii: np.ndarray
    level_offsets: np.ndarray
    branching: int

    def __len__(self) -> int:
        return len(self.means)

    @property
    def leaf_count(self) -> int:
        return int(self.level_offsets[1]) if len(self.level_offsets) > 1 else 0

    @property
    def levels(self) -> int:
        return len(self.level_offsets) - 1

    @property
    def roots(self) -> np.ndarray:
        """[R] int64 node indices without a parent (one root, none for an empty model)."""
        return np.flatnonzero(self.parent < 0)

    def arrays(self) -> dict[str, np.ndarray]:
        return {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}

    def node_arrays(self, nodes: np.ndarray) -> dict[str, np.ndarray]:
        """The float32 arrays of ``nodes`` ([S] int indices) by Gaussians field name, as
        ``Gaussians.numpy()`` gives them (e.g. for the GL renderer's upload, without torch)."""
        return {name: np.take(getattr(self, name), nodes, axis=0) for name in GAUSSIAN_FIELDS}

    def gaussians(self, nodes: np.ndarray | None = None, device=None) -> Gaussians:
        """The Gaussians of ``nodes`` ([S] int indices; None: every leaf), as torch float32."""
        if nodes is None:
            nodes = np.arange(self.leaf_count)
        return Gaussians(**{name: torch.from_numpy(array).to(device) for name, array in self.node_arrays(nodes).items()})


def morton_codes(means: np.ndarray) -> np.ndarray:
    """[n, 3] positions -> [n] uint64 Morton codes in the bounding cube (non-finite -> 0)."""
    points = np.nan_to_num(means.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    low = points.min(axis=0) if len(points) else np.zeros(3)
    side = max(float((points.max(axis=0) - low).max()) if len(points) else 0.0, CUBE_SIDE_MIN)
    cells = (1 << MORTON_BITS) - 1
    grid = np.clip((points - low) / side * cells, 0, cells).astype(np.uint64)
    code = np.zeros(len(points), np.uint64)
    for axis in range(3):
        code |= _spread_bits(grid[:, axis]) << np.uint64(axis)
    return code


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """21-bit integers -> the same bits two zeros apart (bit i moves to bit 3 i)."""
    v = v & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def _leaf_level(gaussians: Gaussians) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """-> (the leaves' stored arrays in Morton order, their working state for merging)."""
    arrays = gaussians.numpy()
    order = np.argsort(morton_codes(arrays["means"]), kind="stable")
    # np.take: ~3x faster than fancy indexing for a million rows.
    leaves = {name: np.take(arrays[name], order, axis=0) for name in GAUSSIAN_FIELDS}
    # A Gaussian with a non-finite parameter (the rasterizer culls it) stays a leaf as it is but
    # enters its parents with weight 0 at the origin: one NaN must not poison every ancestor.
    valid = np.ones(len(order), bool)
    for name in GAUSSIAN_FIELDS:
        valid &= np.isfinite(leaves[name]).all(axis=tuple(range(1, leaves[name].ndim)))
    finite = {name: np.where(valid.reshape((-1,) + (1,) * (leaves[name].ndim - 1)), leaves[name], 0.0)
              .astype(np.float32) for name in GAUSSIAN_FIELDS}
    leaves["radii"] = np.where(valid, bounding_radii(finite["log_scales"]), 0.0)
    state = {"means": finite["means"].astype(np.float64),
             "covs": covariances_of(finite["log_scales"], finite["quats"]),
             "weights": np.where(valid, surface_weights(finite["log_scales"], finite["opacity_logits"]), 0.0),
             "sh": finite["sh"], "radii": leaves["radii"]}
    return leaves, state


def build_hierarchy(gaussians: Gaussians, branching: int = DEFAULT_BRANCHING,
                    progress: Callable[[float], None] | None = None) -> LodHierarchy:
    """The hierarchy of ``gaussians`` (any SH degree); ``progress(fraction)`` after each level."""
    if branching < 2:
        raise ValueError(f"branching must be at least 2, got {branching}")
    leaves, state = _leaf_level(gaussians)
    stored, finite_leaves = [leaves], state
    sizes = [len(state["means"])]
    while sizes[-1] > 1:
        starts = np.arange(0, sizes[-1], branching)
        state = merge_level(state, starts)
        state["radii"] = np.minimum(state["radii"], _leaf_reach(finite_leaves, state, branching ** len(sizes)))
        stored.append({name: state[name] for name in GAUSSIAN_FIELDS + ("radii",)})
        sizes.append(len(starts))
        if progress is not None:
            progress(1.0 - (sizes[-1] - 1) / max(sizes[0] - 1, 1))
    return _assemble(stored, sizes, branching)


def merge_level(state: dict[str, np.ndarray], starts: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`.moments.merge_groups` of a whole level, MERGE_CHUNK_PARENTS parents at a time.
    Each parent depends on its own children only, so the result is the one-call result, bit for
    bit; numpy's reduceat holds the interpreter lock, and one call over a level of millions held a
    window drawing on another thread for ~200 ms."""
    count = len(state["means"])
    parts = []
    for first in range(0, len(starts), MERGE_CHUNK_PARENTS):
        group_starts = starts[first:first + MERGE_CHUNK_PARENTS]
        begin = int(group_starts[0])
        end = int(starts[first + MERGE_CHUNK_PARENTS]) if first + MERGE_CHUNK_PARENTS < len(starts) else count
        parts.append(merge_groups(*(state[name][begin:end] for name in ("means", "covs", "weights", "sh", "radii")),
                                  group_starts - begin))
    return parts[0] if len(parts) == 1 else {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}


def _leaf_reach(leaves: dict[str, np.ndarray], parents: dict[str, np.ndarray], span: int) -> np.ndarray:
    """``leaves``: the leaf level's finite working state (means, radii). [m] radius around each parent's mean holding the spheres of the leaves below it (the
    leaves ``[j span, (j + 1) span)``, as runs of consecutive nodes are merged at every level)
    and the parent's own footprint. Tighter than nesting the children's spheres, whose slack
    would add up level after level."""
    ancestor = np.arange(len(leaves["means"])) // span
    offsets = leaves["means"] - parents["means"][ancestor]
    reach = np.sqrt(np.einsum("ij,ij->i", offsets, offsets)) + leaves["radii"]
    starts = np.arange(0, len(ancestor), span)
    return np.maximum(np.maximum.reduceat(reach, starts), bounding_radii(parents["log_scales"]))


def _assemble(stored: list[dict[str, np.ndarray]], sizes: list[int], branching: int) -> LodHierarchy:
    """Concatenate the levels and link parents and children (runs of ``branching``)."""
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    total = int(offsets[-1])
    parent = np.full(total, -1, np.int32)
    child_start = np.zeros(total, np.int32)
    child_count = np.zeros(total, np.int32)
    for level in range(1, len(sizes)):
        below = np.arange(sizes[level - 1])
        parent[offsets[level - 1]:offsets[level]] = offsets[level] + below // branching
        starts = np.arange(0, sizes[level - 1], branching)
        child_start[offsets[level]:offsets[level + 1]] = offsets[level - 1] + starts
        child_count[offsets[level]:offsets[level + 1]] = np.diff(np.append(starts, sizes[level - 1]))
    columns = {name: np.concatenate([level[name] for level in stored]).astype(np.float32)
               for name in GAUSSIAN_FIELDS + ("radii",)}
    # Rounded up to float32, so a stored sphere never shrinks below the bound it was built as.
    columns["radii"] = np.nextafter(columns["radii"], np.float32(np.inf))
    if total == 0:   # an empty model: keep the SH width of the input
        columns["sh"] = stored[0]["sh"]
    return LodHierarchy(**columns, parent=parent, child_start=child_start, child_count=child_count,
                        level_offsets=offsets, branching=int(branching))
