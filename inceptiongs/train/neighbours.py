"""Neighbour views for the multi-view terms, computed once before the loop."""

from __future__ import annotations

import math

import numpy as np

from ..camera import Camera, rotation_angle_between

# What the all-pairs prefilter may differ from the exact pair check by (radians, scene units).
_ROUNDING = 1e-7


def neighbour_views(cameras: list[Camera], candidates: list[int], max_count: int = 8,
                    max_angle_deg: float = 30.0) -> dict[int, list[int]]:
    """For every index in ``candidates``: up to ``max_count`` other candidate indices whose
    viewing directions differ by at most ``max_angle_deg``, nearest camera centres first.

    A view needs a baseline for depth to be observable, so coincident centres are skipped.
    Returns {camera index: [neighbour indices]} (lists may be empty).
    """
    max_angle = math.radians(max_angle_deg)
    result: dict[int, list[int]] = {}
    if not candidates:
        return result
    centers = np.stack([cameras[i].center for i in candidates]).astype(np.float64)               # [C, 3]
    rotations = np.stack([cameras[i].rotation for i in candidates]).astype(np.float64).reshape(-1, 9)
    for a, i in enumerate(candidates):
        # All pairs at once, to rounding (trace(R_i R_j^T) = the sum of R_i * R_j): 3,000 views
        # are 9 million pairs. The views they admit, nearest first, are then checked exactly as
        # one pair at a time, until max_count pass and no nearer one can follow.
        approx_distance = np.linalg.norm(centers - centers[a], axis=1)
        approx_angle = np.arccos(np.clip((rotations @ rotations[a] - 1.0) / 2.0, -1.0, 1.0))
        admitted = np.flatnonzero((approx_angle <= max_angle + _ROUNDING) & (approx_distance >= 1e-9 - _ROUNDING))
        admitted = admitted[admitted != a]
        scored = []
        for b in admitted[np.argsort(approx_distance[admitted], kind="stable")]:
            if len(scored) >= max_count and approx_distance[b] > sorted(scored)[max_count - 1][0] + _ROUNDING:
                break
            j = candidates[b]
            distance = float(np.linalg.norm(cameras[i].center - cameras[j].center))
            if distance < 1e-9:
                continue
            if rotation_angle_between(cameras[i].rotation, cameras[j].rotation) <= max_angle:
                scored.append((distance, j))
        scored.sort()
        result[i] = [j for _, j in scored[:max_count]]
    return result
