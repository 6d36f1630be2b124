"""Parent/child blending of a cut, so that a cut changing with the camera does not pop.

When a node's projected size passes the granularity g, the cut draws its children instead of
it. Drawn as they are, they change the picture at once; blended, a child starts as its parent's
share and becomes itself while its parent grows from g to BLEND_RATIO x g on screen
(the hierarchical 3DGS paper's interpolation towards the parent). For a drawn node with weight t:

- mean, log scales and SH: parent + t (child - parent);
- rotation: the normalised lerp of the two unit quaternions, signs aligned (their dot >= 0, so
  the lerp's norm is >= 1/sqrt(2) and the normalisation safe);
- opacity: from the parent's share to the child's own, where the share is what each of the k
  children of the parent that the cut draws needs for k overlapping copies to cover what the
  parent covered at its centre: 1 - (1 - o_parent)^(1/k).

At t = 0 the children are k copies of the parent's shape, so the picture is the parent's where
it was opaque; at t = 1 each is itself. Roots and nodes whose parent is far above g get t = 1.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..constants import OPACITY_LOGIT_ABS_MAX, QUAT_NORM_MIN
from .cut import node_sizes
from .hierarchy import LodHierarchy
from .moments import opacities_of

# A child is drawn as itself once its parent covers this many times the granularity.
BLEND_RATIO = 2.0
# The share of a budget cut's expanded parents allowed below its effective granularity. With
# it, blending the greedy 200k cut of a 1M overview cost 1.9 dB against every Gaussian (42.8 ->
# 40.9); the 90th percentile of its drawn merged nodes' sizes (near the exact budget cut's g)
# left three in four nodes as their parents' shares and cost 3.6 dB.
EFFECTIVE_QUANTILE = 0.1
# Opacities are clipped to the model's logit range before the logit is taken (finite, and
# nothing the rasterizer's own clamp would change).
_OPACITY_LOW = 1.0 / (1.0 + np.exp(OPACITY_LOGIT_ABS_MAX))
_OPACITY_HIGH = 1.0 / (1.0 + np.exp(-OPACITY_LOGIT_ABS_MAX))


def blend_weights(hierarchy: LodHierarchy, camera: Camera, nodes: np.ndarray,
                  granularity_px: float | None = None) -> np.ndarray:
    """nodes [S] of a cut at ``granularity_px`` (None: a budget cut, at its
    :func:`effective_granularity`) -> t [S] float32 in [0, 1] (module doc):
    clip((parent size / g - 1) / (BLEND_RATIO - 1), 0, 1); 1 for roots, for g <= 0 (the exact
    model) and for a parent holding the camera (infinite size)."""
    nodes = np.asarray(nodes, np.int64)
    weights = np.ones(len(nodes), np.float32)
    if granularity_px is not None and not (granularity_px > 0.0 and np.isfinite(granularity_px)):
        return weights   # the exact model or the root: nothing to blend, no sizes needed
    has_parent, inverse, sizes, culled = _parents_on_screen(hierarchy, camera, nodes)
    g = _granularity_of(sizes, culled) if granularity_px is None else granularity_px
    if not (g > 0.0 and np.isfinite(g)):
        return weights
    ratio = sizes[inverse] / g   # g > 0 and finite: bounded, inf stays inf
    weights[has_parent] = np.clip((ratio - 1.0) / (BLEND_RATIO - 1.0), 0.0, 1.0)
    return weights


def effective_granularity(hierarchy: LodHierarchy, camera: Camera, nodes: np.ndarray) -> float:
    """The granularity a cut not chosen by one (a budget cut) stands for: the projected size
    that all but EFFECTIVE_QUANTILE of the parents it expanded exceed (a cut at g expands only
    nodes of size >= g; the greedy budget cut's batches expand a few smaller ones too); 0 when
    it draws only roots (nothing was expanded: nothing to blend)."""
    _, _, sizes, culled = _parents_on_screen(hierarchy, camera, np.asarray(nodes, np.int64))
    return _granularity_of(sizes, culled)


def _parents_on_screen(hierarchy: LodHierarchy, camera: Camera, nodes: np.ndarray):
    """-> (has_parent [S] bool, inverse: each such node's index into the distinct parents,
    the distinct parents' projected sizes and culled flags, as cut.node_sizes gives them)."""
    parents = hierarchy.parent[nodes].astype(np.int64)
    has_parent = parents >= 0
    unique, inverse = np.unique(parents[has_parent], return_inverse=True)
    sizes, culled = node_sizes(hierarchy, camera, unique)
    return has_parent, inverse, sizes, culled


def _granularity_of(sizes: np.ndarray, culled: np.ndarray) -> float:
    """EFFECTIVE_QUANTILE of the finite sizes of the parents in view; 0 without any."""
    sizes = sizes[~culled & np.isfinite(sizes)]
    return float(np.quantile(sizes, EFFECTIVE_QUANTILE)) if len(sizes) else 0.0


def _unit_quats(quats: np.ndarray) -> np.ndarray:
    """[n, 4] any norm -> unit float64; near-zero ones become the identity (the rasterizer's rule)."""
    q = quats.astype(np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    unit = q / np.maximum(norm, QUAT_NORM_MIN)
    return np.where(norm >= QUAT_NORM_MIN, unit, np.array([1.0, 0.0, 0.0, 0.0]))


def blended_arrays(hierarchy: LodHierarchy, nodes: np.ndarray, weights: np.ndarray,
                   siblings: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``hierarchy.node_arrays(nodes)`` with each node blended towards its parent by
    ``weights`` [S] (module doc). siblings [S]: how many children of each node's parent the cut
    draws (default: counted within ``nodes``; a caller packing a cut in chunks passes the
    whole cut's counts)."""
    nodes = np.asarray(nodes, np.int64)
    arrays = hierarchy.node_arrays(nodes)
    blend = np.flatnonzero(weights < 1.0)
    if len(blend) == 0:
        return arrays
    if siblings is None:
        siblings = sibling_counts(hierarchy, nodes)
    t = weights[blend].astype(np.float64)[:, None]
    parents = hierarchy.parent[nodes[blend]].astype(np.int64)
    for name in ("means", "log_scales"):
        parent = getattr(hierarchy, name)[parents].astype(np.float64)
        arrays[name][blend] = parent + t * (arrays[name][blend] - parent)
    parent_sh = hierarchy.sh[parents].astype(np.float64)
    arrays["sh"][blend] = parent_sh + t[:, :, None] * (arrays["sh"][blend] - parent_sh)
    child_q, parent_q = _unit_quats(arrays["quats"][blend]), _unit_quats(hierarchy.quats[parents])
    parent_q *= np.where((child_q * parent_q).sum(axis=1, keepdims=True) < 0.0, -1.0, 1.0)
    mixed = parent_q + t * (child_q - parent_q)
    arrays["quats"][blend] = mixed / np.linalg.norm(mixed, axis=1, keepdims=True)
    share = 1.0 - (1.0 - opacities_of(hierarchy.opacity_logits[parents])) ** (1.0 / siblings[blend])
    own = opacities_of(arrays["opacity_logits"][blend])
    opacity = np.clip(share + t[:, 0] * (own - share), _OPACITY_LOW, _OPACITY_HIGH)
    arrays["opacity_logits"][blend] = np.log(opacity) - np.log1p(-opacity)
    return arrays


def sibling_counts(hierarchy: LodHierarchy, nodes: np.ndarray) -> np.ndarray:
    """[S] nodes -> [S] how many of ``nodes`` share each one's parent (>= 1; 1 for roots)."""
    parents = hierarchy.parent[np.asarray(nodes, np.int64)].astype(np.int64)
    _, inverse, counts = np.unique(parents, return_inverse=True, return_counts=True)
    return np.where(parents >= 0, counts[inverse], 1)
