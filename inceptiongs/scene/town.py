"""The town: a large procedural capture (thousands of street-level views and a few aerial ones)
with ground-truth cameras, written as a COLMAP model with JPEG photos.

The layout (``town_layout``) is a grid of blocks and streets that grows with the number of
views (about 60 views a block); the renderer (``town_trace``) is a numba ray-caster walking a
grid over the ground plane. The views:

- **street** (dense): walks along both sidewalks of every street at eye height, looking along
  the street, across it at the facades opposite, obliquely and back;
- **aerial** (dense): 2 % of the views, over a grid across the town, looking down at 40-65
  degrees;
- **scarce**: in each courtyard, 4-5.5 m in front of the facade opposite its gateway, looking
  at it. No street view stands in a yard: the streets see a yard only through its gateway,
  no closer than about 20 m, and the aerial views from above 60 m. ``demo_scene.json`` names the
  groups (``dense_cameras`` = street + aerial, ``scarce_cameras``) and the yards.

Sparse points are surface points hit by random rays of the dense views that at least two
other dense views also see (a real SfM cloud has few points where only far views looked).
"""

from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path

import numpy as np

from ..camera import Camera, look_at
from ..errors import InputError
from .demo import check_out_dir, write_scene_folder
from .town_layout import STREET, Town, blocks_for_views, make_town
from .town_trace import SKY, render_kernel, scene_tuple, trace_kernel, witness_kernel

TOWN_SIZES = {"tiny": (96, 72), "small": (320, 240), "medium": (640, 480), "large": (1280, 960)}
DEFAULT_TOWN_SIZE = "medium"
VIEWS_MIN = 24            # a street walk, two aerial views and the scarce views need this many
VIEWS_MAX = 200_000
SIDE_MIN = 32
SIDE_MAX = 4096
SUPERSAMPLE = 2           # 2 x 2 more rays in a pixel on an edge
EDGE_THRESHOLD = 0.08     # a colour step (any channel, in [0, 1]) that makes a pixel an edge
JPEG_QUALITY = 92
# The disk-space check's estimate of JPEG bytes a pixel: 0.24 measured on the town at 640x480
# (quality 92), small photos take more (headers), so with a margin.
_JPEG_BYTES_PER_PIXEL = 0.45
_HORIZONTAL_FOV_DEG = 70.0
_EYE_HEIGHT = 1.65
_WALK_OFFSET = STREET / 2 - 1.6     # sidewalk walk, 1.6 m from the facades
_AERIAL_SHARE = 0.02
_SCARCE_PER_COURTYARD = 5
_POINTS_PER_VIEW = 64
_POINT_RAYS_MAX = 400_000   # fewer rays a view beyond ~6,000 views: points for initialisation, not millions
_WITNESSES = 2
# Witnesses are sought among the cameras this near in index (a walk's neighbours, the other
# sidewalk, the aerial views among themselves); it bounds the search for a point none sees.
_WITNESS_WINDOW = 5000
# Street views' headings (degrees from the walking direction, positive towards the street's
# far side) and pitch ranges: along, oblique, across at the facades opposite, towards the
# near facades, back.
_HEADINGS = ((0.0, (0.0, 8.0)), (35.0, (4.0, 12.0)), (90.0, (8.0, 18.0)), (-20.0, (2.0, 10.0)),
             (180.0, (0.0, 8.0)), (60.0, (6.0, 14.0)))


def parse_town_size(text: str, flag: str = "--size") -> tuple[int, int]:
    """A size name (tiny, small, medium, large) or WIDTHxHEIGHT -> (width, height); InputError
    naming the flag for anything else or a side outside [SIDE_MIN, SIDE_MAX]."""
    if text in TOWN_SIZES:
        return TOWN_SIZES[text]
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise InputError(f"{flag} {text}: expected WIDTHxHEIGHT (e.g. 640x480) or one of {', '.join(TOWN_SIZES)}")
    width, height = int(parts[0]), int(parts[1])
    if not (SIDE_MIN <= width <= SIDE_MAX and SIDE_MIN <= height <= SIDE_MAX):
        raise InputError(f"{flag} {text}: each side must be {SIDE_MIN} to {SIDE_MAX} pixels")
    return width, height


def check_views(views: int, flag: str = "--views") -> None:
    if not VIEWS_MIN <= views <= VIEWS_MAX:
        raise InputError(f"{flag} {views}: the town needs {VIEWS_MIN} to {VIEWS_MAX} views")


def _camera(name: str, width: int, height: int, eye, target) -> Camera:
    fx = 0.5 * width / math.tan(math.radians(_HORIZONTAL_FOV_DEG) / 2)
    return Camera(name, width, height, fx, fx, width / 2, height / 2,
                  look_at(np.asarray(eye, float), np.asarray(target, float), up=(0.0, 0.0, 1.0)))


def _street_poses(town: Town, count: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """(eye, target) for ``count`` views spread evenly along both sidewalks of every street."""
    half = town.half
    ends = (-half + 2.0, half - 2.0)
    length = ends[1] - ends[0]
    walks = []   # (axis along which the street runs, street centre, side)
    for axis in (0, 1):
        for centre in town.street_centres():
            for side in (1.0, -1.0):
                walks.append((axis, centre, side))
    spacing = len(walks) * length / count
    poses = []
    for m in range(count):
        s = (m + 0.5) * spacing
        axis, centre, side = walks[min(len(walks) - 1, int(s // length))]
        along = s - length * (s // length)
        # One sidewalk is walked forwards, the other backwards.
        position = ends[0] + along if side > 0 else ends[1] - along
        forward = np.zeros(2)
        forward[axis] = side
        across = np.zeros(2)
        across[1 - axis] = -side          # from this sidewalk towards the far one
        eye2 = np.zeros(2)
        eye2[axis] = position + rng.uniform(-0.3, 0.3)
        eye2[1 - axis] = centre + side * _WALK_OFFSET + rng.uniform(-0.2, 0.2)
        heading, (pitch_lo, pitch_hi) = _HEADINGS[m % len(_HEADINGS)]
        a = math.radians(heading + rng.uniform(-6.0, 6.0))
        pitch = math.radians(rng.uniform(pitch_lo, pitch_hi))
        look2 = math.cos(a) * forward + math.sin(a) * across
        eye = np.array([eye2[0], eye2[1], _EYE_HEIGHT + rng.uniform(-0.1, 0.1)])
        direction = np.array([look2[0] * math.cos(pitch), look2[1] * math.cos(pitch), math.sin(pitch)])
        poses.append((eye, eye + 10.0 * direction))
    return poses


def _aerial_poses(town: Town, count: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """(eye, target) on a jittered grid over the town, looking down at 40-65 degrees."""
    half = town.half
    side = int(math.ceil(math.sqrt(count)))
    altitude = 60.0 + 0.3 * half
    poses = []
    for m in range(count):
        gx, gy = m % side, m // side
        x = -0.7 * half + 1.4 * half * (gx + 0.5) / side + rng.uniform(-0.05, 0.05) * half
        y = -0.7 * half + 1.4 * half * (gy + 0.5) / side + rng.uniform(-0.05, 0.05) * half
        heading = math.radians(45.0 + 90.0 * m + rng.uniform(-15, 15))
        pitch = math.radians(rng.uniform(40.0, 65.0))
        eye = np.array([x, y, altitude + rng.uniform(-5.0, 5.0)])
        direction = np.array([math.cos(heading) * math.cos(pitch), math.sin(heading) * math.cos(pitch),
                              -math.sin(pitch)])
        poses.append((eye, eye + 10.0 * direction))
    return poses


def _scarce_poses(town: Town, per_courtyard: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """(eye, target): in each yard, 4-5.5 m from the facade opposite the gateway, looking at it."""
    poses = []
    for yard in town.courtyards:
        x0, y0, x1, y1 = yard.yard
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        normal = np.array(yard.back)                  # from the back facade into the yard
        tangent = np.array([-normal[1], normal[0]])
        back = centre - normal * (x1 - x0) / 2        # a point of the back facade
        for offset in np.linspace(-6.0, 6.0, per_courtyard):
            distance = rng.uniform(4.0, 5.5)
            eye2 = back + normal * distance + tangent * offset
            target2 = back + tangent * (offset + rng.normal(0, 0.5))
            eye = np.array([eye2[0], eye2[1], _EYE_HEIGHT + rng.uniform(0.0, 0.5)])
            poses.append((eye, np.array([target2[0], target2[1], rng.uniform(3.0, 5.0)])))
    return poses


def town_cameras(town: Town, views: int, width: int, height: int, seed: int = 0):
    """-> (cameras, dense names, scarce names, aerial names); cameras in the order street,
    aerial, scarce, named 00000.jpg, 00001.jpg, ..."""
    rng = np.random.default_rng([seed, 0xCA3])
    per_yard = min(_SCARCE_PER_COURTYARD, max(3, views // (8 * len(town.courtyards))))
    n_scarce = per_yard * len(town.courtyards)
    n_aerial = max(2, int(round(_AERIAL_SHARE * views)))
    n_street = views - n_scarce - n_aerial
    groups = [("street", _street_poses(town, n_street, rng)), ("aerial", _aerial_poses(town, n_aerial, rng)),
              ("scarce", _scarce_poses(town, per_yard, rng))]
    cameras, names = [], {"street": [], "aerial": [], "scarce": []}
    for group, poses in groups:
        for eye, target in poses:
            name = f"{len(cameras):05d}.jpg"
            cameras.append(_camera(name, width, height, eye, target))
            names[group].append(name)
    return cameras, names["street"] + names["aerial"], names["scarce"], names["aerial"]


def camera_rays(camera: Camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays through image points pixels [R, 2] (continuous, pixel (i, j) covers [i, i + 1)):
    -> origins [R, 3], unit directions [R, 3]."""
    x = (pixels[:, 0] - camera.cx) / camera.fx
    y = (pixels[:, 1] - camera.cy) / camera.fy
    dirs = np.stack([x, y, np.ones_like(x)], axis=1) @ camera.rotation   # R^T d, row-vector form
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)                    # norm >= 1
    return np.broadcast_to(camera.center, dirs.shape).copy(), dirs


def trace_rays(town_scene: tuple, origins: np.ndarray, dirs: np.ndarray, footprint_per_m=None):
    """origins, dirs [R, 3] (unit) -> (t [R] with inf for the sky, hit [R] (box index, GROUND or
    SKY), face [R], colour [R, 3] in [0, 1]). footprint_per_m: [R] pixel size per metre of
    distance (0: unfiltered textures)."""
    count = len(origins)
    footprint = np.zeros(count) if footprint_per_m is None else np.broadcast_to(footprint_per_m, (count,))
    t = np.empty(count)
    hit = np.empty(count, np.int64)
    face = np.empty(count, np.int64)
    colour = np.empty((count, 3))
    trace_kernel(np.ascontiguousarray(origins, np.float64), np.ascontiguousarray(dirs, np.float64),
                 np.ascontiguousarray(footprint, np.float64), town_scene, t, hit, face, colour)
    return t, hit, face, colour


def render_town_photo(town_scene: tuple, camera: Camera, samples: int = SUPERSAMPLE,
                      threshold: float = EDGE_THRESHOLD) -> np.ndarray:
    """[H, W, 3] uint8 RGB: one ray a pixel, plus samples x samples more where the pixel sits
    on an edge (another surface, or a colour step over ``threshold``, beside it); threshold 0
    supersamples every pixel whose neighbours differ at all."""
    offsets = np.array([((a + 0.5) / samples, (b + 0.5) / samples) for b in range(samples) for a in range(samples)])
    out = np.empty((camera.height, camera.width, 3), np.uint8)
    colour = np.empty((camera.height, camera.width, 3))
    surface = np.empty((camera.height, camera.width), np.int64)
    render_kernel(np.ascontiguousarray(camera.rotation), np.ascontiguousarray(camera.center), camera.fx, camera.fy,
                  camera.cx, camera.cy, offsets, float(threshold), town_scene, colour, surface, out)
    return out


def _camera_arrays(cameras: list[Camera]):
    rotations = np.ascontiguousarray(np.stack([c.rotation for c in cameras]))
    centres = np.ascontiguousarray(np.stack([c.center for c in cameras]))
    intrinsics = np.array([[c.fx, c.fy, c.cx, c.cy] for c in cameras])
    sizes = np.array([[c.width, c.height] for c in cameras], np.float64)
    return rotations, centres, intrinsics, sizes


def visibility_counts(town_scene: tuple, points: np.ndarray, source: np.ndarray, cameras: list[Camera],
                      wanted: int, window: int = _WITNESS_WINDOW) -> np.ndarray:
    """points [P, 3], source [P] index into cameras -> [P]: how many of the other cameras (at most
    ``window`` away in index) see each point unoccluded (counting stops at ``wanted``)."""
    out = np.zeros(len(points), np.int64)
    witness_kernel(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(source, np.int64),
                   *_camera_arrays(cameras), int(wanted), int(window), town_scene, out)
    return out


def town_points(town_scene: tuple, cameras: list[Camera], rng: np.random.Generator,
                per_view: int = _POINTS_PER_VIEW, witnesses: int = _WITNESSES):
    """Sparse points: hits of ``per_view`` random rays of each camera (fewer when that would pass
    _POINT_RAYS_MAX rays) that at least ``witnesses`` other cameras see.
    -> (points [P, 3], colours [P, 3] uint8)."""
    per_view = max(2, min(per_view, _POINT_RAYS_MAX // len(cameras)))
    origins, dirs, source, footprint = [], [], [], []
    for index, camera in enumerate(cameras):
        pixels = rng.uniform(0, 1, (per_view, 2)) * (camera.width, camera.height)
        o, d = camera_rays(camera, pixels)
        origins.append(o)
        dirs.append(d)
        source.append(np.full(per_view, index))
        footprint.append(np.full(per_view, 1.0 / max(camera.fx, camera.fy)))
    origins, dirs = np.concatenate(origins), np.concatenate(dirs)
    source, footprint = np.concatenate(source), np.concatenate(footprint)
    t, hit, _, colour = trace_rays(town_scene, origins, dirs, footprint)
    solid = hit != SKY
    points = origins[solid] + dirs[solid] * t[solid, None]
    counts = visibility_counts(town_scene, points, source[solid], cameras, witnesses)
    keep = counts >= witnesses
    return points[keep], np.round(colour[solid][keep] * 255).astype(np.uint8)


def check_disk_space(out_dir: Path, views: int, width: int, height: int) -> None:
    """InputError before any rendering when the photos would not fit on OUT's disk."""
    need = views * width * height * _JPEG_BYTES_PER_PIXEL
    free = shutil.disk_usage(out_dir.parent if not out_dir.exists() else out_dir).free
    if need > free:
        raise InputError(f"{out_dir}: the town's photos need about {need / 1e9:.1f} GB of disk, "
                         f"only {free / 1e9:.1f} GB are free")


def write_town_scene(out_dir: str | Path, views: int = 3000, width: int = 640, height: int = 480, seed: int = 0,
                     progress: bool = True) -> Path:
    """Write the town (images/*.jpg, sparse/0/*.bin, demo_scene.json) to out_dir, atomically
    (see ``write_scene_folder``). Returns out_dir."""
    check_views(views)
    if not (SIDE_MIN <= width <= SIDE_MAX and SIDE_MIN <= height <= SIDE_MAX):
        raise InputError(f"{out_dir}: town photos must be {SIDE_MIN} to {SIDE_MAX} pixels a side, "
                         f"got {width}x{height}")
    out_dir = Path(out_dir)
    check_out_dir(out_dir)
    check_disk_space(out_dir, views, width, height)
    town = make_town(blocks_for_views(views), seed)
    scene = scene_tuple(town)
    cameras, dense, scarce, aerial = town_cameras(town, views, width, height, seed)
    if progress:
        print(f"town: {town.blocks} x {town.blocks} blocks, {len(town.boxes)} buildings, "
              f"{len(town.courtyards)} courtyard(s); {len(dense) - len(aerial)} street, {len(aerial)} aerial, "
              f"{len(scarce)} scarce views; sampling sparse points", file=sys.stderr, flush=True)
    dense_set = set(dense)
    dense_cameras = [c for c in cameras if c.name in dense_set]
    points, colours = town_points(scene, dense_cameras, np.random.default_rng([seed, 0x9E7]))
    meta = {
        "description": "InceptionGS procedural town (z up, ground at z = 0, metres, streets span "
                       f"[-{town.half:g}, {town.half:g}]^2)",
        "scene": "town", "views": views, "seed": seed, "width": width, "height": height, "blocks": town.blocks,
        "dense_cameras": dense, "scarce_cameras": scarce, "aerial_cameras": aerial,
        "courtyards": [{"yard": list(c.yard), "back_normal": list(c.back), "gate": list(c.gate)}
                       for c in town.courtyards],
        "note": "scarce cameras stand in the courtyards 4-5.5 m from the facade opposite the gateway; the "
                "dense views see a yard only through its gateway, no closer than about 20 m, or from the air",
    }
    return write_scene_folder(out_dir, cameras, lambda camera: render_town_photo(scene, camera), points, colours,
                              meta, progress=progress, desc="town", jpeg_quality=JPEG_QUALITY)

