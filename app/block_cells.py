"""The cells of a run trained in blocks (RUN/blocks.json, inceptiongs.train.blocks), drawn in the
coverage mode as outlines on the ground: which block owns which part of the scene."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from inceptiongs.errors import InputError

CELL_COLOR = (0.2, 0.9, 1.0)
# The model's plane coordinates that bound an outer (unbounded) side: its central 98 %.
OUTER_PERCENTILES = (1.0, 99.0)
# The ground: this percentile of the model's heights below the cameras' plane.
GROUND_PERCENTILE = 5.0


def read_block_plan(run_dir: Path | None) -> tuple[object | None, str | None]:
    """(the run's BlockPlan, None); (None, None) without blocks.json; (None, the one-line problem)
    when it cannot be read (the run still opens)."""
    from inceptiongs.train.blocks import read_plan  # noqa: PLC0415

    if run_dir is None:
        return None, None
    try:
        return read_plan(Path(run_dir)), None
    except InputError as exc:
        return None, f"block cells not shown: {exc}"


def cell_outline_segments(plan, means: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Each cell's four sides [4 * C, 2, 3] on the ground under the model: the plane of
    ``plan.plane`` moved along its normal to the model's GROUND_PERCENTILE height (``up`` [3], the
    view's world up, says which way is down); unbounded sides at the model's OUTER_PERCENTILES
    extent. means: [N, 3] in the run's (normalised) frame, as the plan."""
    plane = plan.plane
    origin, u, v, normal = (np.asarray(x, np.float64) for x in (plane.origin, plane.u, plane.v, plane.up))
    means = np.asarray(means, np.float64)
    if len(means):
        coords = plane.coordinates(means)
        lo, hi = np.percentile(coords, OUTER_PERCENTILES, axis=0)
        heights = (means - origin) @ normal
        below = GROUND_PERCENTILE if normal @ np.asarray(up, np.float64) >= 0 else 100.0 - GROUND_PERCENTILE
        height = float(np.percentile(heights, below))
    else:   # no model: the cells' own finite sides, on the cameras' plane
        lo, hi, height = np.array([-1.0, -1.0]), np.array([1.0, 1.0]), 0.0
    segments = []
    for cell in plan.cells:
        u0, u1 = _bounded(cell.u0, lo[0], hi[0]), _bounded(cell.u1, lo[0], hi[0])
        v0, v1 = _bounded(cell.v0, lo[1], hi[1]), _bounded(cell.v1, lo[1], hi[1])
        corners = [origin + a * u + b * v + height * normal for a, b in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))]
        segments += [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    return np.array(segments, np.float64).reshape(-1, 2, 3)


def _bounded(side: float, low: float, high: float) -> float:
    """A cell's side in plane coordinates; an outer one (+-UNBOUNDED) at the model's extent."""
    from inceptiongs.train.partition import UNBOUNDED  # noqa: PLC0415

    if abs(side) < UNBOUNDED:
        return float(side)
    return float(low if side < 0 else high)


@dataclass
class BlockCellOutlines:
    """The open run's cell outlines, read once per source and model (the coverage mode draws
    them every frame): ``key`` (id of the source, model version) they were made for."""

    key: tuple | None = None
    segments: np.ndarray | None = None

    def of_model(self, source, model_version: int, means: np.ndarray, up: np.ndarray, status) -> np.ndarray | None:
        """The cells of ``source``'s run as ground outlines [4 * C, 2, 3] over the model shown
        (``means`` [N, 3], world ``up`` [3]), None when it was not trained in blocks; a plan that
        cannot be read is said in ``status``."""
        key = (id(source), model_version)
        if self.key != key:
            plan, problem = read_block_plan(getattr(source, "run_dir", None))
            if problem:
                status.text = problem
            self.segments = None if plan is None else cell_outline_segments(plan, means, up)
            self.key = key
        return self.segments
