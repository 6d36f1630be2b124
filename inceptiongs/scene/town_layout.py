"""The procedural town's layout: a grid of blocks and streets, buildings as boxes, and the grid
over the ground plane that the ray-caster walks.

World frame: z up, ground at z = 0, metres, the town centred on the origin. ``blocks`` x
``blocks`` blocks of ``BLOCK`` m separated by streets ``STREET`` m wide; a street also runs along
each edge, lined on its outer side by a ring of perimeter buildings, so every street ends in
facades rather than an empty horizon. Blocks are of three kinds:

- ordinary: cut into 2-3 x 2-3 lots, each a building of its own height and facade style (an
  inner lot of a 3 x 3 block is a back yard);
- square: an open paved plaza with a monument (a plinth and a column);
- courtyard: a ring of buildings around an enclosed yard, entered through one gateway 4 m wide.
  Seen from the streets only through the gateway (no closer than about 20 m), or from the air: the
  town's thin regions. Their facades carry the finest detail (shutters, railings).

Everything here is plain numpy; ``town_trace`` renders it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

BLOCK = 36.0            # block side (m)
STREET = 12.0           # street width, kerb to kerb of the facades (m)
PITCH = BLOCK + STREET
PERIMETER_DEPTH = 10.0  # depth of the ring of buildings around the town
RING_DEPTH = 9.0        # depth of a courtyard block's buildings: the yard is 18 m square
GATE_WIDTH = 4.0
SIDEWALK = 2.5          # sidewalk width on each side of a street
CELL = 6.0              # side of the ground grid's cells the ray-caster walks
NOISE_SIZE = 64

# Block kinds.
ORDINARY, SQUARE, COURTYARD = 0, 1, 2

# Columns of the per-box parameter table (float64 [K, N_PARAMS]).
P_MATERIAL = 0          # MAT_*
P_LIGHT = 1             # 3: main wall colour
P_DARK = 4              # 3: second wall colour (bricks' dark tone, stone joints)
P_FRAME = 7             # 3: window frames
P_BAY = 10              # preferred window bay width (m); the facade is divided evenly
P_STOREY = 11           # storey height (m)
P_GROUND = 12           # GROUND_* : what the ground floor shows
P_WINDOW = 13           # window width as a share of the bay
P_HAS_WINDOWS = 14      # 0 for monuments
P_NOISE = 15            # offset into the noise grid, so buildings do not repeat each other
P_FINE = 16             # 1: shutters and balcony railings (the courtyards' facades)
P_ACCENT = 17           # 3: shutters, awnings, doors
N_PARAMS = 20

MAT_BRICK, MAT_PLASTER, MAT_STONE, MAT_MONUMENT = 0, 1, 2, 3
GROUND_DOORS, GROUND_SHOPS = 0, 1

_PALETTES = {   # material -> list of (light, dark)
    MAT_BRICK: [((0.74, 0.36, 0.25), (0.52, 0.21, 0.14)), ((0.80, 0.55, 0.38), (0.58, 0.36, 0.24)),
                ((0.62, 0.30, 0.24), (0.40, 0.18, 0.15))],
    MAT_PLASTER: [((0.90, 0.84, 0.70), (0.75, 0.68, 0.55)), ((0.86, 0.70, 0.62), (0.70, 0.55, 0.48)),
                  ((0.72, 0.80, 0.78), (0.56, 0.64, 0.62)), ((0.93, 0.90, 0.84), (0.78, 0.76, 0.70))],
    MAT_STONE: [((0.80, 0.77, 0.68), (0.42, 0.40, 0.36)), ((0.68, 0.66, 0.62), (0.36, 0.35, 0.33))],
}
_FRAMES = [(0.95, 0.95, 0.92), (0.20, 0.22, 0.24), (0.45, 0.28, 0.16), (0.85, 0.82, 0.72)]
_ACCENTS = [(0.12, 0.38, 0.20), (0.62, 0.12, 0.10), (0.15, 0.25, 0.55), (0.75, 0.55, 0.15)]


@dataclass(frozen=True)
class Courtyard:
    """One thin region: the yard inside a courtyard block.

    yard: (x0, y0, x1, y1), the open yard; back: unit (x, y) normal of the facade that faces the
    gateway (pointing from that facade into the yard); gate: (x, y) centre of the gateway's
    street end."""

    yard: tuple[float, float, float, float]
    back: tuple[float, float]
    gate: tuple[float, float]

    def contains(self, points: np.ndarray, margin: float = 1e-6) -> np.ndarray:
        """points: [P, 3] -> [P] bool: on or over the yard (its floor and the facades around it)."""
        x0, y0, x1, y1 = self.yard
        x, y = points[:, 0], points[:, 1]
        return (x >= x0 - margin) & (x <= x1 + margin) & (y >= y0 - margin) & (y <= y1 + margin)


@dataclass(frozen=True)
class Town:
    """The layout and what the ray-caster needs.

    boxes: [K, 6] float64 (x0, y0, z0, x1, y1, z1); params: [K, N_PARAMS] float64 (P_*);
    kinds: [blocks, blocks] int64 block kind, row = x index; noise: [64, 64] in [0, 1];
    the ground grid: cells of CELL m from (grid_x0, grid_y0), grid_n a side, each cell's boxes
    cell_items[cell_start[c]:cell_start[c + 1]] and the top of its tallest box cell_top[c]."""

    blocks: int
    boxes: np.ndarray
    params: np.ndarray
    kinds: np.ndarray
    courtyards: tuple[Courtyard, ...]
    noise: np.ndarray
    grid_x0: float
    grid_y0: float
    grid_n: int
    cell_start: np.ndarray
    cell_items: np.ndarray
    cell_top: np.ndarray

    @property
    def half(self) -> float:
        """Half the side of the street grid: streets span [-half, half]^2."""
        return town_half(self.blocks)

    @property
    def top(self) -> float:
        """The tallest box's top (m)."""
        return float(self.boxes[:, 5].max())

    def street_centres(self) -> np.ndarray:
        """[blocks + 1] coordinate of each street's centre line (the same along x and y)."""
        return -self.half + STREET / 2 + PITCH * np.arange(self.blocks + 1)

    def block_bounds(self, i: int) -> tuple[float, float]:
        """Block index i's extent along one axis."""
        start = -self.half + STREET + PITCH * i
        return start, start + BLOCK


def town_half(blocks: int) -> float:
    return (blocks * BLOCK + (blocks + 1) * STREET) / 2


def blocks_for_views(views: int) -> int:
    """Blocks a side for a capture of ``views`` views: about 60 views a block, 2 to 24 a side."""
    return int(min(24, max(2, round(math.sqrt(views / 60.0)))))


def _style(rng: np.random.Generator, fine: bool = False) -> np.ndarray:
    """One building's facade parameters: [N_PARAMS]."""
    p = np.zeros(N_PARAMS)
    material = int(rng.choice([MAT_BRICK, MAT_PLASTER, MAT_STONE], p=[0.45, 0.4, 0.15]))
    palette = _PALETTES[material]
    light, dark = palette[int(rng.integers(len(palette)))]
    tint = rng.uniform(0.92, 1.06, 3)
    p[P_MATERIAL] = material
    p[P_LIGHT:P_LIGHT + 3] = np.clip(np.array(light) * tint, 0, 1)
    p[P_DARK:P_DARK + 3] = np.clip(np.array(dark) * tint, 0, 1)
    p[P_FRAME:P_FRAME + 3] = _FRAMES[int(rng.integers(len(_FRAMES)))]
    p[P_BAY] = rng.uniform(2.2, 3.4)
    p[P_STOREY] = rng.uniform(3.0, 3.6)
    p[P_GROUND] = GROUND_SHOPS if rng.random() < 0.45 else GROUND_DOORS
    p[P_WINDOW] = rng.uniform(0.38, 0.55)
    p[P_HAS_WINDOWS] = 1.0
    p[P_NOISE] = rng.uniform(0, NOISE_SIZE)
    p[P_FINE] = 1.0 if fine else 0.0
    p[P_ACCENT:P_ACCENT + 3] = _ACCENTS[int(rng.integers(len(_ACCENTS)))]
    return p


def _height(rng: np.random.Generator, storey: float, low: int = 2, high: int = 7) -> float:
    """Storeys x storey height plus a parapet; one building in 12 is a tower."""
    storeys = int(rng.integers(10, 15)) if rng.random() < 1 / 12 else int(rng.integers(low, high + 1))
    return storeys * storey + 0.8


def _split(rng: np.random.Generator, length: float, parts: int, smallest: float) -> np.ndarray:
    """Cut points [parts + 1] from 0 to length, no piece shorter than ``smallest``."""
    cuts = np.sort(rng.uniform(0, 1, parts - 1)) * (length - parts * smallest)
    return np.concatenate([[0.0], cuts + smallest * np.arange(1, parts), [length]])


def _ordinary_block(rng, x0, y0) -> list[tuple[tuple, np.ndarray]]:
    xs = x0 + _split(rng, BLOCK, int(rng.integers(2, 4)), 9.0)
    ys = y0 + _split(rng, BLOCK, int(rng.integers(2, 4)), 9.0)
    out = []
    for i in range(len(xs) - 1):
        for j in range(len(ys) - 1):
            inner = 0 < i < len(xs) - 2 and 0 < j < len(ys) - 2
            if inner and rng.random() < 0.7:
                continue   # a back yard
            style = _style(rng)
            out.append(((xs[i], ys[j], 0.0, xs[i + 1], ys[j + 1], _height(rng, style[P_STOREY])), style))
    return out


def _square_block(rng, x0, y0) -> list[tuple[tuple, np.ndarray]]:
    cx, cy = x0 + BLOCK / 2, y0 + BLOCK / 2
    stone = np.zeros(N_PARAMS)
    stone[P_MATERIAL] = MAT_MONUMENT
    stone[P_LIGHT:P_LIGHT + 3] = (0.82, 0.80, 0.74)
    stone[P_DARK:P_DARK + 3] = (0.55, 0.53, 0.48)
    stone[P_NOISE] = rng.uniform(0, NOISE_SIZE)
    column = stone.copy()
    column[P_LIGHT:P_LIGHT + 3] = (0.70, 0.64, 0.55)
    height = rng.uniform(7.0, 11.0)
    return [((cx - 3.0, cy - 3.0, 0.0, cx + 3.0, cy + 3.0, 1.2), stone),
            ((cx - 0.8, cy - 0.8, 1.2, cx + 0.8, cy + 0.8, 1.2 + height), column)]


def _courtyard_block(rng, x0, y0) -> tuple[list[tuple[tuple, np.ndarray]], Courtyard]:
    """Four wings around an 18 m yard; the gateway cuts one wing, on a random side."""
    d, x1, y1 = RING_DEPTH, x0 + BLOCK, y0 + BLOCK
    mid = BLOCK / 2
    g = GATE_WIDTH / 2
    side = int(rng.integers(4))   # the gateway's side: 0 south (-y), 1 east, 2 north, 3 west
    wings = {0: [(x0, y0, x0 + mid - g, y0 + d), (x0 + mid + g, y0, x1, y0 + d)],
             2: [(x0, y1 - d, x0 + mid - g, y1), (x0 + mid + g, y1 - d, x1, y1)],
             1: [(x1 - d, y0 + d, x1, y0 + mid - g), (x1 - d, y0 + mid + g, x1, y1 - d)],
             3: [(x0, y0 + d, x0 + d, y0 + mid - g), (x0, y0 + mid + g, x0 + d, y1 - d)]}
    whole = {0: [(x0, y0, x1, y0 + d)], 2: [(x0, y1 - d, x1, y1)],
             1: [(x1 - d, y0 + d, x1, y1 - d)], 3: [(x0, y0 + d, x0 + d, y1 - d)]}
    out = []
    for s in range(4):
        style = _style(rng, fine=True)
        height = _height(rng, style[P_STOREY], 4, 6)
        for rect in (wings[s] if s == side else whole[s]):
            out.append(((rect[0], rect[1], 0.0, rect[2], rect[3], height), style))
    normal = {0: (0.0, -1.0), 1: (1.0, 0.0), 2: (0.0, 1.0), 3: (-1.0, 0.0)}[side]   # yard -> gateway
    centre = np.array([x0 + mid, y0 + mid])
    gate = centre + np.array(normal) * mid
    yard = Courtyard(yard=(x0 + d, y0 + d, x1 - d, y1 - d), back=normal, gate=(float(gate[0]), float(gate[1])))
    return out, yard


def _perimeter(rng, half: float) -> list[tuple[tuple, np.ndarray]]:
    """A ring of buildings along the outer side of the edge streets, in lots of 10-24 m."""
    out = []
    lo, hi = -half - PERIMETER_DEPTH, half + PERIMETER_DEPTH
    for side in range(4):
        position = lo
        while position < hi - 1e-9:
            end = min(hi, position + rng.uniform(10.0, 24.0))
            if hi - end < 8.0:
                end = hi
            style = _style(rng)
            height = _height(rng, style[P_STOREY], 3, 8)
            if side == 0:
                rect = (position, lo, end, -half)
            elif side == 1:
                rect = (position, half, end, hi)
            elif side == 2:
                rect = (lo, position, -half, end)
            else:
                rect = (half, position, hi, end)
            if side >= 2:   # the x-sides' corners are already built by the y-sides
                rect = (rect[0], max(rect[1], -half), rect[2], min(rect[3], half))
                if rect[3] - rect[1] < 1e-9:
                    position = end
                    continue
            out.append(((rect[0], rect[1], 0.0, rect[2], rect[3], height), style))
            position = end
    return out


def _block_kinds(rng: np.random.Generator, blocks: int) -> np.ndarray:
    """[blocks, blocks]: one courtyard per 12 blocks (at least one) and one square per 10."""
    n = blocks * blocks
    n_courtyards = max(1, n // 12)
    n_squares = max(1, n // 10)
    order = rng.permutation(n)
    kinds = np.full(n, ORDINARY, np.int64)
    kinds[order[:n_courtyards]] = COURTYARD
    kinds[order[n_courtyards:n_courtyards + n_squares]] = SQUARE
    return kinds.reshape(blocks, blocks)


def build_grid(boxes: np.ndarray, x0: float, y0: float, n: int, cell: float = CELL):
    """Bin boxes [K, 6] into an n x n grid of ``cell`` m from (x0, y0) (cell index iy * n + ix).
    -> (cell_start [n*n + 1] int64, cell_items [M] int64, cell_top [n*n] float64, 0 when empty)."""
    lists: list[list[int]] = [[] for _ in range(n * n)]
    top = np.zeros(n * n)
    eps = 1e-9
    for k, (bx0, by0, _, bx1, by1, bz1) in enumerate(boxes):
        i0 = max(0, int(math.floor((bx0 - x0) / cell + eps)))
        i1 = min(n - 1, int(math.floor((bx1 - x0) / cell - eps)))
        j0 = max(0, int(math.floor((by0 - y0) / cell + eps)))
        j1 = min(n - 1, int(math.floor((by1 - y0) / cell - eps)))
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                lists[j * n + i].append(k)
                top[j * n + i] = max(top[j * n + i], bz1)
    counts = np.array([len(items) for items in lists], np.int64)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    items = np.array([k for items in lists for k in items], np.int64)
    return start, items, top


def make_town(blocks: int, seed: int = 0) -> Town:
    """The town of ``blocks`` x ``blocks`` blocks for a seed (deterministic)."""
    rng = np.random.default_rng([seed, 0x70C4])
    noise = rng.random((NOISE_SIZE, NOISE_SIZE))
    half = town_half(blocks)
    kinds = _block_kinds(rng, blocks)
    parts: list[tuple[tuple, np.ndarray]] = []
    courtyards = []
    for i in range(blocks):
        for j in range(blocks):
            x0 = -half + STREET + PITCH * i
            y0 = -half + STREET + PITCH * j
            if kinds[i, j] == SQUARE:
                parts += _square_block(rng, x0, y0)
            elif kinds[i, j] == COURTYARD:
                wings, yard = _courtyard_block(rng, x0, y0)
                parts += wings
                courtyards.append(yard)
            else:
                parts += _ordinary_block(rng, x0, y0)
    parts += _perimeter(rng, half)
    boxes = np.array([p[0] for p in parts], np.float64)
    params = np.stack([p[1] for p in parts])
    grid_x0 = -half - PERIMETER_DEPTH
    n = int(math.ceil(2 * (half + PERIMETER_DEPTH) / CELL))
    start, items, top = build_grid(boxes, grid_x0, grid_x0, n)
    return Town(blocks, boxes, params, kinds, tuple(courtyards), noise, grid_x0, grid_x0, n, start, items, top)
