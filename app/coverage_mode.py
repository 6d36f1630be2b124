"""The viewer's "coverage" render mode: every Gaussian coloured by how many of the source's
cameras see it (occlusion from the depth the GL renderer draws for each camera), a colour bar
for the panel, and the k scarcest camera viewpoints as flag suggestions.

The geometry is the library's (``inceptiongs.evaluation.coverage``); this module only feeds it
the viewer's arrays and depth maps and turns counts into splat colours.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from inceptiongs.camera import Camera
from inceptiongs.constants import SH_C0
from inceptiongs.evaluation import coverage as cov

DEPTH_WIDTH = 128            # depth maps for the occlusion test, pixels wide
VMAX_PERCENTILE = 95         # the colour bar tops out here (a few over-seen splats would flatten it)
SCARCITY_POINTS = 2000       # Gaussians sampled for the scarcity scores
SUGGESTED_FLAGS = 3
# A frame's share of the counting in the window: it stays responsive while thousands of views are counted.
COUNTING_SLICE_S = 0.1


def coloured_arrays(arrays: dict, colours: np.ndarray) -> dict:
    """Gaussian arrays (as Gaussians.numpy()) with every splat's colour replaced by ``colours``
    [N, 3] in [0, 1]: the DC coefficient that renders that colour, no view dependence."""
    sh = np.zeros_like(arrays["sh"])
    sh[:, 0, :] = (colours - 0.5) / SH_C0
    return {**arrays, "sh": sh.astype(arrays["sh"].dtype)}


@dataclass
class Counting:
    """A model version's counts in progress: the cameras before ``done`` are counted."""
    version: object
    means: np.ndarray        # [N, 3] float64
    cameras: list
    counts: np.ndarray       # [N] int64
    done: int = 0


class CoverageMode:
    """Counts per Gaussian for one model version, computed on first use, a slice of the cameras
    per frame when the frame asks (a 300-view town's counts froze the window for about 100 s)."""

    def __init__(self) -> None:
        self.version = None
        self.counts: np.ndarray | None = None
        self.vmax = 0.0
        self.arrays: dict | None = None
        self.pending: Counting | None = None

    @property
    def counting(self) -> tuple[int, int] | None:
        """(cameras counted, cameras) while a model version's counts are in progress, else None."""
        return None if self.pending is None else (self.pending.done, len(self.pending.cameras))

    def update(self, arrays: dict, cameras: list[Camera], depth_of: Callable[[Camera], np.ndarray],
               version, slice_s: float | None = None) -> dict | None:
        """Coloured arrays for ``arrays`` (recomputed when ``version`` changes). depth_of(camera)
        -> [h, w] camera depth (0 = no surface) of the current model. ``slice_s``: count for
        about this long (at least one camera), then return None while cameras are left (the
        next call goes on where this one stopped); None: all of them now."""
        if version == self.version and self.arrays is not None:
            return self.arrays
        if self.pending is None or self.pending.version != version:   # a new model starts over
            means = np.asarray(arrays["means"], np.float64)
            self.pending = Counting(version, means, list(cameras), np.zeros(len(means), np.int64))
        pending, start = self.pending, time.perf_counter()
        while pending.done < len(pending.cameras):
            camera = pending.cameras[pending.done]
            depth = depth_of(camera.scaled(min(1.0, DEPTH_WIDTH / camera.width)))
            pending.counts += cov.visibility_matrix(pending.means, [camera], [depth])[:, 0]
            pending.done += 1
            if (slice_s is not None and pending.done < len(pending.cameras)
                    and time.perf_counter() - start >= slice_s):
                return None
        counts = pending.counts
        self.counts, self.pending = counts, None
        self.vmax = float(max(np.percentile(counts, VMAX_PERCENTILE), 1.0)) if len(counts) else 1.0
        self.arrays = coloured_arrays(arrays, cov.ramp_colours(counts, self.vmax))
        self.version = version
        return self.arrays

    def suggest(self, arrays: dict, cameras: list[Camera], depth_of: Callable[[Camera], np.ndarray],
                k: int = SUGGESTED_FLAGS, seed: int = 0) -> list[int]:
        """Indices of the k cameras whose content the other cameras see least (scarcity with
        direction and resolution, on a sample of the Gaussians)."""
        means = np.asarray(arrays["means"], np.float64)
        if not len(cameras) or not len(means):
            return []
        if len(means) > SCARCITY_POINTS:
            means = means[np.random.default_rng(seed).choice(len(means), SCARCITY_POINTS, replace=False)]
        depths = [depth_of(c.scaled(min(1.0, DEPTH_WIDTH / c.width))) for c in cameras]
        visible = cov.visibility_matrix(means, cameras, depths)
        directions = cov.view_directions(means, np.array([c.center for c in cameras]))
        scores = cov.view_scarcity(directions, visible, resolution=cov.view_resolution(means, cameras))
        return cov.scarcest_views(scores, k)
