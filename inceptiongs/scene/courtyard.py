"""The demo's courtyard: a procedural scene like the paper's, with one region seen badly.

A square courtyard (tiled floor, z = 0, z up) closed by four textured facades with recurring
structure: brick courses, rows of framed windows with mullions, doors, and on the north
facade balconies with railings over stone blocks. A fountain block stands in the middle.
Everything is ray-cast analytically in numpy (``inceptiongs.scene.demo``'s primitives and
Lambert shading), supersampled, so held-out photos are exact ground truth.

The camera path is the unstructured-capture problem: most views ("dense") walk the southern
half and look south, east, west and down at the floor; they see the north facade only from
far away or at grazing angles. A few views ("scarce") stand close in front of the north facade
and look straight at it. The demo holds most of those out (the scarce group): stage I never saw
the north facade's railings and stone joints at the scale those views show them, so it renders
them blurred or broken there, while the rest of the courtyard is well covered.
``demo_scene.json`` names both groups.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..camera import Camera, look_at
from ..errors import InputError
from .demo import Textures, checker, check_out_dir, hit_box, hit_plane, mix, nearest_hits, sample_points, \
    supersampled_photo, write_scene_folder

# size -> (width, height, dense cameras, scarce cameras). "tiny" keeps tests fast.
COURTYARD_SIZES = {"tiny": (64, 48, 16, 5), "small": (192, 144, 40, 7), "medium": (320, 240, 56, 9)}
_HORIZONTAL_FOV_DEG = 70.0
_SUPERSAMPLE = 2             # 2 x 2 rays per pixel, box-filtered
_HALF = 6.0                  # the courtyard spans [-6, 6] x [-6, 6]
# Tall enough that views at eye height see little sky (an infinitely far sky is something
# Gaussians cannot fit in a few hundred steps, and it would swamp the covered views' error).
_WALL_HEIGHT = 8.0
_POINTS_PER_CAMERA = 300
_FOUNTAIN = ((0.0, -0.5, 0.45), (0.9, 0.9, 0.45))
_LIGHT = np.array([0.35, -0.55, 0.76]) / np.linalg.norm([0.35, -0.55, 0.76])
_AMBIENT = 0.4
_EYE_HEIGHT = 1.6

# Surface ids, in the order ``trace`` stacks them.
_FLOOR, _NORTH, _SOUTH, _EAST, _WEST, _FOUNTAIN_ID = range(6)


def _frac(x: np.ndarray) -> np.ndarray:
    return x - np.floor(x)


def _bricks(u: np.ndarray, v: np.ndarray, tex: Textures, light, dark) -> np.ndarray:
    """Running-bond bricks (0.4 x 0.2 m courses) with mortar joints: [R] -> [R, 3]."""
    row = np.floor(v / 0.2)
    shifted = u + 0.2 * (row % 2)
    tint = tex.sample(np.floor(shifted / 0.4) * 3.7 + 11.0, row * 2.3)   # one tint per brick
    base = mix(dark, light, tint)
    mortar = (_frac(v / 0.2) < 0.12) | (_frac(shifted / 0.4) < 0.06)
    base[mortar] = (0.82, 0.80, 0.74)
    return base * (0.85 + 0.25 * tex.fractal(6.0 * u, 6.0 * v + 3.0))[:, None]


def _windows(u: np.ndarray, v: np.ndarray, colour: np.ndarray, period: float, frame) -> np.ndarray:
    """Paint framed windows with a cross mullion over ``colour`` [R, 3] in place; one per
    ``period`` metres and storey (1.6 m) above the ground floor."""
    cell_u = _frac(u / period) * period - 0.5 * period        # -period/2 .. period/2 across a bay
    storey = np.floor(v / 1.6)
    cell_v = v - 1.6 * storey                                  # 0 .. 1.6 within a storey
    in_window = (np.abs(cell_u) < 0.4) & (cell_v > 0.45) & (cell_v < 1.35) & (storey >= 1)
    glass = mix((0.12, 0.18, 0.28), (0.45, 0.55, 0.65), np.clip((cell_v - 0.45) / 0.9, 0, 1))
    colour[in_window] = glass[in_window]
    inner = (np.abs(cell_u) < 0.34) & (cell_v > 0.51) & (cell_v < 1.29)
    mullion = (np.abs(cell_u) < 0.025) | (np.abs(cell_v - 0.95) < 0.025)
    framed = in_window & (~inner | mullion)
    colour[framed] = frame
    return colour


def _door(u: np.ndarray, v: np.ndarray, colour: np.ndarray, at: float) -> np.ndarray:
    """A planked wooden door 1.2 m wide, 2.2 m high, centred at u = at."""
    door = (np.abs(u - at) < 0.6) & (v < 2.2)
    planks = mix((0.40, 0.24, 0.12), (0.55, 0.34, 0.18), (np.floor((u - at) / 0.15) % 2).astype(float))
    colour[door] = planks[door]
    return colour


def _north(u: np.ndarray, v: np.ndarray, tex: Textures) -> np.ndarray:
    """The thinly seen facade: small stone blocks, balconies with railings on each storey,
    tall shuttered windows. Fine, recurring detail that far or grazing views cannot resolve."""
    course = np.floor(v / 0.3)
    shifted = u + 0.25 * (course % 3)
    tint = tex.sample(np.floor(shifted / 0.5) * 5.1 + 2.0, course * 1.7 + 40.0)
    colour = mix((0.62, 0.60, 0.55), (0.86, 0.83, 0.74), tint)
    joint = (_frac(v / 0.3) < 0.08) | (_frac(shifted / 0.5) < 0.05)
    colour[joint] = (0.35, 0.33, 0.30)
    colour = _windows(u, v, colour, 1.5, (0.90, 0.88, 0.80))
    # Shutters beside every window: green with horizontal slats.
    cell_u = _frac(u / 1.5) * 1.5 - 0.75
    storey = np.floor(v / 1.6)
    cell_v = v - 1.6 * storey
    shutter = (np.abs(cell_u) >= 0.42) & (np.abs(cell_u) < 0.62) & (cell_v > 0.45) & (cell_v < 1.35) & (storey >= 1)
    slats = mix((0.10, 0.35, 0.18), (0.20, 0.55, 0.30), (_frac(cell_v / 0.08) < 0.5).astype(float))
    colour[shutter] = slats[shutter]
    # Balcony railings across every upper storey: a dark top rail and thin vertical bars.
    rail_v = cell_v
    balcony = (storey >= 1) & (rail_v < 0.55)
    bars = balcony & (_frac(u / 0.12) < 0.3)
    top = (storey >= 1) & (np.abs(rail_v - 0.55) < 0.04)
    colour[bars] = (0.08, 0.08, 0.10)
    colour[top] = (0.10, 0.10, 0.12)
    colour = _door(u, v, colour, 0.0)
    return colour * (0.9 + 0.15 * tex.fractal(4.0 * u + 9.0, 4.0 * v))[:, None]


def _facade(kind: int, u: np.ndarray, v: np.ndarray, tex: Textures) -> np.ndarray:
    """Albedo [R, 3] of a facade at horizontal coordinate u and height v (metres)."""
    if kind == _NORTH:
        return _north(u, v, tex)
    palettes = {_SOUTH: ((0.78, 0.38, 0.26), (0.55, 0.22, 0.15), (0.95, 0.95, 0.92), 1.8),
                _EAST: ((0.85, 0.72, 0.50), (0.65, 0.50, 0.32), (0.30, 0.22, 0.15), 1.5),
                _WEST: ((0.72, 0.52, 0.45), (0.50, 0.34, 0.30), (0.92, 0.90, 0.85), 2.0)}
    light, dark, frame, period = palettes[kind]
    colour = _bricks(u, v, tex, light, dark)
    colour = _windows(u, v, colour, period, frame)
    # A plinth of darker stone along the foot of the wall.
    plinth = v < 0.4
    colour[plinth] = (0.40, 0.40, 0.42) * (0.8 + 0.3 * tex.sample(8.0 * u[plinth], 8.0 * v[plinth]))[:, None]
    return _door(u, v, colour, {_SOUTH: 1.5, _EAST: -2.0, _WEST: 2.5}[kind])


def _floor(x: np.ndarray, y: np.ndarray, tex: Textures) -> np.ndarray:
    """Square 0.5 m tiles in two close tones with grout, a diagonal-checker border near the
    walls. Low contrast on purpose: a floor seen at grazing angles aliases into noise that no
    method could fit, and the covered views' score would measure that instead of coverage."""
    tone = checker(x, y, 0.5)
    colour = mix((0.78, 0.74, 0.66), (0.62, 0.58, 0.52), tone)
    border = np.maximum(np.abs(x), np.abs(y)) > _HALF - 0.8
    diagonal = checker(x + y, x - y, 0.35)
    colour[border] = mix((0.42, 0.44, 0.50), (0.70, 0.66, 0.55), diagonal)[border]
    grout = (_frac(x / 0.5) < 0.05) | (_frac(y / 0.5) < 0.05)
    colour[grout & ~border] = (0.35, 0.33, 0.30)
    return colour * (0.8 + 0.3 * tex.fractal(3.0 * x + 50.0, 3.0 * y))[:, None]


def _fountain(points: np.ndarray, tex: Textures) -> np.ndarray:
    """Stone block with a blue-and-white band of tiles."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    colour = mix((0.70, 0.70, 0.66), (0.85, 0.84, 0.80), tex.fractal(5.0 * x + 7.0, 5.0 * (y + z)))
    band = (z > 0.55) & (z < 0.82)
    tiles = mix((0.15, 0.30, 0.70), (0.92, 0.92, 0.95), checker(x + y, z, 0.12))
    colour[band] = tiles[band]
    return colour


def trace_courtyard(origins: np.ndarray, dirs: np.ndarray, tex: Textures) -> tuple[np.ndarray, np.ndarray]:
    """Cast unit rays. origins, dirs: [R, 3] -> (colour [R, 3] in [0, 1], distance [R], inf = sky)."""
    lo, hi = np.array([-_HALF, 0.0]), np.array([_HALF, _WALL_HEIGHT])
    hits = [
        hit_plane(origins, dirs, 2, 0.0, np.array([-_HALF, -_HALF]), np.array([_HALF, _HALF]), 1.0),
        hit_plane(origins, dirs, 1, _HALF, lo, hi, -1.0),    # north facade (y = +6), facing south
        hit_plane(origins, dirs, 1, -_HALF, lo, hi, 1.0),    # south facade
        hit_plane(origins, dirs, 0, _HALF, lo, hi, -1.0),    # east facade
        hit_plane(origins, dirs, 0, -_HALF, lo, hi, 1.0),    # west facade
        hit_box(origins, dirs, *_FOUNTAIN),
    ]
    kind, t = nearest_hits(hits)
    colour = mix((0.50, 0.66, 0.92), (0.85, 0.90, 0.98), 1.0 - np.clip(dirs[:, 2], 0, 1))
    for k, (_, normals) in enumerate(hits):
        mask = (kind == k) & np.isfinite(t)
        if not mask.any():
            continue
        p = origins[mask] + dirs[mask] * t[mask, None]
        if k == _FLOOR:
            albedo = _floor(p[:, 0], p[:, 1], tex)
        elif k == _FOUNTAIN_ID:
            albedo = _fountain(p, tex)
        else:
            # u runs left to right for a viewer facing the facade from inside the courtyard.
            u = {_NORTH: p[:, 0], _SOUTH: -p[:, 0], _EAST: p[:, 1], _WEST: -p[:, 1]}[k]
            albedo = _facade(k, u, p[:, 2], tex)
        light = _AMBIENT + (1 - _AMBIENT) * np.clip(normals[mask] @ _LIGHT, 0, 1)
        colour[mask] = albedo * light[:, None]
    return np.clip(colour, 0, 1), t


def render_courtyard_photo(camera: Camera, tex: Textures) -> np.ndarray:
    """Supersampled photo: [H, W, 3] float in [0, 1]."""
    return supersampled_photo(camera, lambda origins, dirs: trace_courtyard(origins, dirs, tex), _SUPERSAMPLE)


def courtyard_cameras(size: str = "small", seed: int = 0) -> tuple[list[Camera], list[str], list[str]]:
    """-> (cameras, dense names, scarce names).

    Dense: a walk over the southern half (y in [-4.5, 0.5]) at eye height, each view turned
    towards the south, east or west facade or a southern corner, plus a few far views up the
    courtyard along the side walls (the north facade at 8-11 m, obliquely). Scarce: views 2.5 m
    in front of the north facade, looking at it head on.
    """
    width, height, n_dense, n_scarce = COURTYARD_SIZES[size]
    rng = np.random.default_rng(seed)
    fx = 0.5 * width / math.tan(math.radians(_HORIZONTAL_FOV_DEG) / 2)
    cameras, dense, scarce = [], [], []

    def add(eye, target, group: list[str]) -> None:
        name = f"{len(cameras):03d}.png"
        cameras.append(Camera(name, width, height, fx, fx, width / 2, height / 2,
                              look_at(np.asarray(eye, float), np.asarray(target, float), up=(0.0, 0.0, 1.0))))
        group.append(name)

    n_far = max(2, n_dense // 8)
    n_walk = n_dense - n_far
    # The walk: a lawn-mower path over the southern half; headings cycle south, east, west and
    # the two southern diagonals, so neighbouring views overlap.
    headings = [(0.0, -1.0), (1.0, 0.0), (-1.0, 0.0), (0.7, -0.7), (-0.7, -0.7)]
    for k in range(n_walk):
        s = k / max(n_walk - 1, 1)
        x = -4.0 + 8.0 * _frac(np.array(3.0 * s)).item()
        y = -4.5 + 5.0 * s
        eye = np.array([x, y, _EYE_HEIGHT]) + rng.normal(0, 0.15, 3) * (1, 1, 0.3)
        hx, hy = headings[k % len(headings)]
        pitch = -0.35 if k % len(headings) < 3 else -0.6
        target = eye + np.array([hx * 4.0, hy * 4.0, pitch * 2.0]) + rng.normal(0, 0.3, 3)
        add(eye, target, dense)
    # Far views from the south-west and south-east corners looking up the courtyard at the
    # north facade's ends: far away and oblique.
    for k in range(n_far):
        side = -1.0 if k % 2 == 0 else 1.0
        eye = np.array([side * 4.8, -4.8 + 0.5 * (k // 2), _EYE_HEIGHT + rng.uniform(0, 0.5)])
        target = np.array([-side * 1.5, _HALF, 2.2]) + rng.normal(0, 0.3, 3)
        add(eye, target, dense)
    # Scarce: close in front of the north facade, spread along it, looking north.
    for x in np.linspace(-3.6, 3.6, n_scarce):
        eye = np.array([x, _HALF - 2.5, _EYE_HEIGHT + rng.uniform(0, 0.6)])
        target = np.array([x + rng.normal(0, 0.3), _HALF, 2.2 + rng.normal(0, 0.2)])
        add(eye, target, scarce)
    return cameras, dense, scarce


def write_courtyard_scene(out_dir: str | Path, size: str = "small", seed: int = 0, progress: bool = True) -> Path:
    """Write the courtyard (images/, sparse/0/*.bin, demo_scene.json) to out_dir, atomically
    (see ``write_scene_folder``). Returns out_dir."""
    if size not in COURTYARD_SIZES:
        raise InputError(f"{out_dir}: unknown courtyard size {size!r} (choose {', '.join(COURTYARD_SIZES)})")
    out_dir = Path(out_dir)
    check_out_dir(out_dir)
    rng = np.random.default_rng(seed)
    tex = Textures(noise=rng.random((64, 64)))
    cameras, dense, scarce = courtyard_cameras(size, seed)
    # Sparse points from the dense views only: a real capture's SfM has points where it has
    # views, and few on a facade only far views saw.
    dense_cameras = [c for c in cameras if c.name in set(dense)]
    points, colours = sample_points(dense_cameras, lambda o, d: trace_courtyard(o, d, tex), rng,
                                    _POINTS_PER_CAMERA)
    meta = {
        "description": "InceptionGS courtyard demo scene (z up, floor at z = 0, courtyard [-6, 6]^2)",
        "scene": "courtyard", "size": size, "seed": seed, "width": cameras[0].width, "height": cameras[0].height,
        "dense_cameras": dense, "scarce_cameras": scarce,
        "note": "scarce cameras stand close in front of the north facade (y = 6); the dense walk sees it "
                "only from 8 m or more away or at grazing angles",
    }
    return write_scene_folder(out_dir, cameras, lambda camera: render_courtyard_photo(camera, tex), points,
                              colours, meta, progress=progress, desc="courtyard")
