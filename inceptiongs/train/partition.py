"""A large capture split into blocks: cells on the ground plane, and the photos that see each.

The ground plane is the one the cameras stand on: its normal is the mean of the cameras' up
directions (OpenCV: -y of each camera), its axes the principal directions of the camera centres
projected onto it, so cells follow the streets of a capture walked along them. The cells are a
k-d split of the plane, balanced by cameras and sparse points together (each half of the weight
theirs), always cutting the heaviest cell at its weighted median along its longer side; the
outer cells reach to infinity, so every point of the plane lies in exactly one cell.

A block's photos are those that see its cell, judged by the visibility of the cell's sparse
points (a coarse depth buffer of all points per photo keeps only the nearest surface), not only
by where the camera stands: a street view looking down a street sees the blocks ahead of it.
A cell widened by a margin selects the photos, so content near a border is trained from both
sides; the merge keeps each block's Gaussians inside its own cell only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..camera import Camera
from ..errors import InputError

# `train --blocks auto`: one block per this many training photos (a capture of fewer trains as one run).
PHOTOS_PER_BLOCK = 400
# Outer cells reach to infinity; stored as this many scene units (JSON has no infinity).
UNBOUNDED = 1e9
# A photo sees a cell when at least this share of its visible sparse points lies in the cell
# (widened by the margin), or when it stands in that widened cell.
SEE_SHARE = 0.05
# The depth buffer a photo's visible points are judged with: this many cells across its width
# (rows in proportion); a point is visible when it is within this factor of the nearest depth in its cell.
DEPTH_GRID = 48
DEPTH_TOLERANCE = 1.05
# At most this many sparse points enter the visibility test (a random subset, seeded).
VISIBILITY_POINTS_MAX = 200_000
# The margin, as a fraction of the cell's smaller side (finite sides only).
DEFAULT_MARGIN_FRACTION = 0.15


@dataclass(frozen=True)
class GroundPlane:
    """origin [3], u and v [3] (orthonormal, in the plane), up [3] (its normal): plane coordinates
    of a point p are ((p - origin) . u, (p - origin) . v)."""

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    up: np.ndarray

    def coordinates(self, points: np.ndarray) -> np.ndarray:
        """points: [N, 3] -> [N, 2] plane coordinates (float64)."""
        offset = np.asarray(points, np.float64).reshape(-1, 3) - self.origin
        return np.stack([offset @ self.u, offset @ self.v], axis=1)

    def to_json(self) -> dict:
        return {name: [float(x) for x in getattr(self, name)] for name in ("origin", "u", "v", "up")}

    @staticmethod
    def from_json(data: dict) -> "GroundPlane":
        return GroundPlane(*(np.asarray(data[name], np.float64) for name in ("origin", "u", "v", "up")))


@dataclass(frozen=True)
class Cell:
    """[u0, u1) x [v0, v1) in plane coordinates; +-UNBOUNDED marks an outer side."""

    u0: float
    u1: float
    v0: float
    v1: float

    def contains(self, coords: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """coords: [N, 2] -> [N] bool. Half-open without a margin, so the cells of a partition
        hold every point exactly once."""
        u, v = coords[:, 0], coords[:, 1]
        if margin == 0.0:
            return (u >= self.u0) & (u < self.u1) & (v >= self.v0) & (v < self.v1)
        return ((u >= self.u0 - margin) & (u <= self.u1 + margin)
                & (v >= self.v0 - margin) & (v <= self.v1 + margin))

    def finite_sides(self) -> tuple[float, float]:
        """The cell's extent along u and v, an unbounded one as inf."""
        width = self.u1 - self.u0 if max(abs(self.u0), abs(self.u1)) < UNBOUNDED else math.inf
        height = self.v1 - self.v0 if max(abs(self.v0), abs(self.v1)) < UNBOUNDED else math.inf
        return width, height

    def to_json(self) -> list[float]:
        return [self.u0, self.u1, self.v0, self.v1]


def ground_plane(cameras: Sequence[Camera]) -> GroundPlane:
    """The plane the cameras stand on (module doc). Needs at least one camera."""
    centres = np.stack([camera.camera_to_world[:3, 3] for camera in cameras])
    ups = np.stack([-camera.camera_to_world[:3, 1] for camera in cameras])
    up = ups.mean(axis=0)
    norm = np.linalg.norm(up)
    # Cameras looking every way (a turntable from all sides) average to no up: fall back on the
    # camera centres' direction of least spread.
    if not norm > 1e-3:
        centred = centres - centres.mean(axis=0)
        up = np.linalg.svd(centred, full_matrices=True)[2][-1]
        norm = np.linalg.norm(up)
    up = up / norm
    flat = centres - np.outer(centres @ up, up)
    centred = flat - flat.mean(axis=0)
    # The principal in-plane direction of the camera centres; any in-plane axis when they coincide.
    helper = np.eye(3)[int(np.argmin(np.abs(up)))]
    u = helper - (helper @ up) * up
    if len(cameras) >= 2 and np.linalg.norm(centred) > 0:
        for direction in np.linalg.svd(centred, full_matrices=False)[2]:
            candidate = direction - (direction @ up) * up
            if np.linalg.norm(candidate) > 1e-6:
                u = candidate
                break
    u = u / np.linalg.norm(u)
    v = np.cross(up, u)
    return GroundPlane(flat.mean(axis=0), u, v / np.linalg.norm(v), up)


def balanced_cells(camera_coords: np.ndarray, point_coords: np.ndarray, count: int) -> list[Cell]:
    """``count`` cells of the plane (module doc): camera_coords [C, 2], point_coords [P, 2] (may be
    empty). Each split cuts the heaviest cell at its weighted median along its longer side (by the
    spread of its cameras)."""
    weights = [np.full(len(camera_coords), 0.5 / max(len(camera_coords), 1))]
    coords = [camera_coords]
    if len(point_coords):
        weights.append(np.full(len(point_coords), 0.5 / len(point_coords)))
        coords.append(point_coords)
    all_coords, all_weights = np.concatenate(coords), np.concatenate(weights)
    cells = [Cell(-UNBOUNDED, UNBOUNDED, -UNBOUNDED, UNBOUNDED)]
    while len(cells) < count:
        loads = [float(all_weights[cell.contains(all_coords)].sum()) for cell in cells]
        heaviest = int(np.argmax(loads))
        halves = split_cell(cells[heaviest], all_coords, all_weights, camera_coords)
        if halves is None:
            raise InputError(f"cannot split the capture into {count} blocks: a cell holds too few distinct camera "
                             f"positions (got {len(cells)} blocks); give fewer blocks")
        cells[heaviest:heaviest + 1] = halves
    return cells


def split_cell(cell: Cell, coords: np.ndarray, weights: np.ndarray, camera_coords: np.ndarray
               ) -> list[Cell] | None:
    """The two halves of ``cell`` at its weighted median (None: nothing to split)."""
    inside = cell.contains(coords)
    cams = camera_coords[cell.contains(camera_coords)]
    if len(cams) < 2:
        return None
    spread = cams.max(axis=0) - cams.min(axis=0)
    for axis in np.argsort(-spread):
        values, w = coords[inside, axis], weights[inside]
        order = np.argsort(values, kind="stable")
        cumulative = np.cumsum(w[order])
        cut = float(values[order][int(np.searchsorted(cumulative, cumulative[-1] / 2.0))])
        # Both halves must keep a camera: a cut at the smallest camera coordinate would empty one.
        low_cams, high_cams = cams[:, axis] < cut, cams[:, axis] >= cut
        if not low_cams.any() or not high_cams.any():
            sorted_cams = np.unique(cams[:, axis])
            if len(sorted_cams) < 2:
                continue
            cut = float(sorted_cams[len(sorted_cams) // 2])
        if axis == 0:
            return [Cell(cell.u0, cut, cell.v0, cell.v1), Cell(cut, cell.u1, cell.v0, cell.v1)]
        return [Cell(cell.u0, cell.u1, cell.v0, cut), Cell(cell.u0, cell.u1, cut, cell.v1)]
    return None


def visible_points(camera: Camera, points: np.ndarray) -> np.ndarray:
    """points [N, 3] -> [N] bool: in front of ``camera``, inside its image and not behind a
    nearer point of the same coarse depth-buffer cell (DEPTH_GRID, DEPTH_TOLERANCE)."""
    w2c = camera.world_to_camera
    local = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = local[:, 2]
    front = z > 1e-6
    safe_z = np.where(front, z, 1.0)           # the division only counts where z > 0
    x = camera.fx * local[:, 0] / safe_z + camera.cx
    y = camera.fy * local[:, 1] / safe_z + camera.cy
    inside = front & (x >= 0) & (x < camera.width) & (y >= 0) & (y < camera.height)
    if not inside.any():
        return inside
    columns = DEPTH_GRID
    rows = max(1, round(DEPTH_GRID * camera.height / camera.width))
    cell = (np.clip((y[inside] * rows / camera.height).astype(np.int64), 0, rows - 1) * columns
            + np.clip((x[inside] * columns / camera.width).astype(np.int64), 0, columns - 1))
    nearest = np.full(rows * columns, np.inf)
    np.minimum.at(nearest, cell, z[inside])
    visible = inside.copy()
    visible[inside] = z[inside] <= nearest[cell] * DEPTH_TOLERANCE
    return visible


def cell_margin(cell: Cell, fraction: float = DEFAULT_MARGIN_FRACTION) -> float:
    """The margin of ``cell`` in scene units: ``fraction`` of its smaller finite side (0 when
    both sides are unbounded: a single block)."""
    sides = [side for side in cell.finite_sides() if math.isfinite(side)]
    return fraction * min(sides) if sides else 0.0


def photos_seeing(cells: Sequence[Cell], margins: Sequence[float], plane: GroundPlane, cameras: Sequence[Camera],
                  views: Sequence[int], points: np.ndarray, seed: int = 0) -> list[list[int]]:
    """For each cell, the views (indices into ``cameras``, from ``views``) that see it widened by
    its margin (module doc), sorted."""
    if len(points) > VISIBILITY_POINTS_MAX:
        points = points[np.random.default_rng(seed).choice(len(points), VISIBILITY_POINTS_MAX, replace=False)]
    point_coords = plane.coordinates(points) if len(points) else np.zeros((0, 2))
    in_cell = [cell.contains(point_coords, margin) for cell, margin in zip(cells, margins)]
    seen: list[list[int]] = [[] for _ in cells]
    for view in views:
        camera = cameras[view]
        centre = plane.coordinates(camera.camera_to_world[:3, 3][None])
        visible = visible_points(camera, points) if len(points) else np.zeros(0, bool)
        total = int(visible.sum())
        for index, (cell, margin) in enumerate(zip(cells, margins)):
            stands_in = bool(cell.contains(centre, margin)[0])
            share = int((visible & in_cell[index]).sum()) / total if total else 0.0
            if stands_in or share >= SEE_SHARE:
                seen[index].append(int(view))
    return seen


def block_plane(block) -> GroundPlane:
    """The ground plane a block config (runs.config.Block) names."""
    u, v = np.asarray(block.u, np.float64), np.asarray(block.v, np.float64)
    return GroundPlane(np.asarray(block.origin, np.float64), u, v, np.cross(u, v))


def as_block(scene, split, block):
    """(scene, split) as the block ``block`` (runs.config.Block, count > 0) sees them: the split
    among its photos (Split.restricted) and the sparse points its training photos see or its cell
    widened by its margin holds (the points the block's Gaussians start from and its near bounds
    are measured with). A photo
    the block names that the scene lacks is an InputError."""
    import dataclasses

    index = {camera.name: i for i, camera in enumerate(scene.cameras)}
    missing = [name for name in block.photos if name not in index]
    if missing:
        raise InputError(f"{scene.root}: block {block.index} names a photo the scene lacks: {missing[0]!r}")
    restricted = split.restricted(index[name] for name in block.photos)
    if not restricted.train:
        raise InputError(f"{scene.root}: block {block.index} of {block.count} has no training photo "
                         f"(its photos are all held out)")
    points = np.asarray(scene.points, np.float64).reshape(-1, 3)
    if len(points):
        keep = Cell(*block.cell).contains(block_plane(block).coordinates(points), block.margin)
        # Everything the block's photos see starts as Gaussians too: with the cell's points alone,
        # the photos' other content is fitted by Gaussians densified inside the cell, which the
        # merge keeps, and which float in front of every view that is not the block's.
        for view in restricted.train:
            keep |= visible_points(scene.cameras[view], points)
        colours = None if scene.point_colors is None else np.asarray(scene.point_colors)[keep]
        scene = dataclasses.replace(scene, points=points[keep].astype(scene.points.dtype, copy=False),
                                    point_colors=colours)
    return scene, restricted
