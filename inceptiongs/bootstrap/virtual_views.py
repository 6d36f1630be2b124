"""Virtual views: poses between a target view j* and its nearest training views.

Stage II repairs a badly observed target view by generating images at poses that walk from
j* towards the training views that see the same region best. This module picks those
training views (:func:`nearest_training_views`) and interpolates the poses
(:func:`virtual_views`): camera centre linear, orientation quaternion slerp, intrinsics of
the target (the generated images are then all at the resolution the user judges).

Spacing: for each of the K sources, t_l = l / L for l = 1 .. L, so t = 0 (the target itself,
whose render is what is wrong) is excluded, t = 1 is exactly the training pose, and
|V| = K * L (with K clipped to the number of candidates).

Degenerate cases (decided here, tested in tests/test_bootstrap_geometry.py):

- a training view equal to the target: it is still selected (distance 0 sorts first) and its
  L poses all coincide with the target. They are *kept*, so |V| = K * L holds without
  exceptions and each virtual view still names its source; snapping ties go to the lowest
  index, so the duplicates cost nothing but their generation.
- antipodal orientations (180 degrees apart): quaternion slerp is well conditioned there
  (the quaternions are 90 degrees apart on the 4-sphere); the path is the one camera.quat_slerp
  picks deterministically, and every pose is a proper rotation.
- K larger than the number of candidates: K is clipped; no candidates -> no virtual views.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Sequence


from ..camera import Camera, interpolate_pose, pose_distance

# K = 3 nearest training views: the paper's ablation shows a handful suffices; more sources
# add views far from j* whose generated images say little about the target region, and every
# virtual view costs one prior generation (the dominant cost on CPU).
DEFAULT_K = 3
# L = 4 poses per source: spacing of a quarter of the way between j* and the source keeps
# neighbouring virtual views overlapping heavily (warps and Langevin snapping need that)
# while |V| = 12 generations stay affordable.
DEFAULT_L = 4
# Radians weigh like scene units in the pose distance; scenes are normalised so the camera
# rig's radius is 1 (inceptiongs.scene.loader.compute_normalization), which makes 1 sensible.
DEFAULT_ROTATION_WEIGHT = 1.0


@dataclass(frozen=True)
class VirtualView:
    """One virtual view: ``camera`` (target intrinsics, interpolated pose), ``source`` (index
    of the training camera it walks towards), ``t`` in (0, 1] (0 = target, 1 = source pose)
    and a file-name-safe unique ``name``."""

    camera: Camera
    source: int
    t: float
    name: str


def _checked_candidates(cameras: Sequence[Camera], candidates: Sequence[int]) -> list[int]:
    """Unique candidate indices in the order given; ValueError for indices outside cameras."""
    out: list[int] = []
    for index in candidates:
        index = int(index)
        if not 0 <= index < len(cameras):
            raise ValueError(f"candidate index {index} is outside the {len(cameras)} cameras")
        if index not in out:
            out.append(index)
    return out


def nearest_training_views(target: Camera, cameras: Sequence[Camera], candidates: Sequence[int],
                           k: int, rotation_weight: float = DEFAULT_ROTATION_WEIGHT) -> list[int]:
    """The k candidates nearest to ``target`` by camera.pose_distance: indices into cameras.

    Sorted by distance, ties broken by the lower index; k is clipped to the number of
    (unique) candidates; a candidate equal to the target is kept (distance 0).
    """
    if k < 0:
        raise ValueError(f"k must be >= 0, got {k}")
    indices = _checked_candidates(cameras, candidates)
    keyed = [(pose_distance(target.world_to_camera, cameras[i].world_to_camera, rotation_weight), i)
             for i in indices]
    keyed.sort()
    return [i for _, i in keyed[:k]]


def pool_view_name(round_number: int, target_index: int, view_name: str) -> str:
    """e.g. 'r1_t3_virtual_s0007_t03of04': a pool view of round 1 made for flag 3 (target index)."""
    return f"r{round_number}_t{target_index}_{view_name}"


_POOL_VIEW_NAME = re.compile(r"r\d+_(t\d+)_")


def flag_of(name: str) -> str:
    """The flag a pool view was made for ('t3' for 'r1_t3_...', whichever round made it); a
    name not made by :func:`pool_view_name` is its own flag."""
    match = _POOL_VIEW_NAME.match(name)
    return match.group(1) if match else name


def virtual_view_name(source: int, step: int, steps: int) -> str:
    """e.g. 'virtual_s0007_t03of04': unique per (source, step), safe as a file name."""
    return f"virtual_s{source:04d}_t{step:02d}of{steps:02d}"


def virtual_views(target: Camera, cameras: Sequence[Camera], candidates: Sequence[int],
                  k: int = DEFAULT_K, l: int = DEFAULT_L,
                  rotation_weight: float = DEFAULT_ROTATION_WEIGHT) -> list[VirtualView]:
    """K * L virtual views: for each of the k nearest candidates (nearest first) the poses at
    t = 1/L, 2/L, ..., 1 from the target towards it (centre lerp, orientation slerp).

    Intrinsics and image size are the target's.
    """
    if l < 1:
        raise ValueError(f"l (poses per training view) must be >= 1, got {l}")
    sources = nearest_training_views(target, cameras, candidates, k, rotation_weight)
    views = []
    for source in sources:
        for step in range(1, l + 1):
            t = step / l
            pose = interpolate_pose(target.world_to_camera, cameras[source].world_to_camera, t)
            name = virtual_view_name(source, step, l)
            views.append(VirtualView(target.with_pose(pose, name=name), source, t, name))
    return views
