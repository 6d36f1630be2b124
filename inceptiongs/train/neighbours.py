"""Neighbour views for the multi-view terms, computed once before the loop."""

from __future__ import annotations

import math

import numpy as np

from ..camera import Camera, rotation_angle_between


def neighbour_views(cameras: list[Camera], candidates: list[int], max_count: int = 8,
                    max_angle_deg: float = 30.0) -> dict[int, list[int]]:
    """For every index in ``candidates``: up to ``max_count`` other candidate indices whose
    viewing directions differ by at most ``max_angle_deg``, nearest camera centres first.

    A view needs a baseline for depth to be observable, so coincident centres are skipped.
    Returns {camera index: [neighbour indices]} (lists may be empty).
    """
    max_angle = math.radians(max_angle_deg)
    centers = {i: cameras[i].center for i in candidates}
    result: dict[int, list[int]] = {}
    for i in candidates:
        scored = []
        for j in candidates:
            if j == i:
                continue
            distance = float(np.linalg.norm(centers[i] - centers[j]))
            if distance < 1e-9:
                continue
            angle = rotation_angle_between(cameras[i].rotation, cameras[j].rotation)
            if angle <= max_angle:
                scored.append((distance, j))
        scored.sort()
        result[i] = [j for _, j in scored[:max_count]]
    return result
