"""A small procedural, textured scene with ground-truth cameras, written as a COLMAP model.

Real geometry, ray-cast analytically in numpy: a ground plane, a wall, two boxes and two
spheres, each with its own detailed texture (checkers, stripes, value noise) and Lambert
shading, so PSNR against these photos means something. World frame: z up, ground at z = 0.

The cameras follow an uneven path: most of them ("dense") orbit the east side (+x) of the
scene, a few ("scarce") look from the north-west, the unstructured-sampling problem in
miniature. ``demo_scene.json`` next to the model names both groups.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from ..io.atomic import atomic_write_bytes, atomic_write_text, check_writable_dir, ensure_dir, output_error
from ..camera import Camera, look_at
from ..errors import InputError
from .colmap import write_colmap_binary

# size -> (width, height, dense cameras, scarce cameras)
SIZES = {"small": (192, 144, 24, 4), "medium": (320, 240, 40, 6)}
_HORIZONTAL_FOV_DEG = 60.0
_SUPERSAMPLE = 2             # 2 x 2 rays per pixel, box-filtered: photos without jaggies
_POINTS_PER_CAMERA = 150     # sparse points sampled from each camera's view
_GROUND_HALF_SIZE = 6.0
_LIGHT = np.array([0.45, -0.35, 0.82]) / np.linalg.norm([0.45, -0.35, 0.82])
_AMBIENT = 0.35
_NO_HIT = np.inf


@dataclass(frozen=True)
class Textures:
    """Value-noise grids for the textures (deterministic for a seed)."""

    noise: np.ndarray  # [64, 64] in [0, 1]

    def sample(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bilinear, tiling value noise at continuous grid coordinates u, v: [R] -> [R]."""
        size = self.noise.shape[0]
        u0, v0 = np.floor(u), np.floor(v)
        fu, fv = u - u0, v - v0
        i0, j0 = u0.astype(np.int64) % size, v0.astype(np.int64) % size
        i1, j1 = (i0 + 1) % size, (j0 + 1) % size
        n = self.noise
        return ((n[j0, i0] * (1 - fu) + n[j0, i1] * fu) * (1 - fv)
                + (n[j1, i0] * (1 - fu) + n[j1, i1] * fu) * fv)

    def fractal(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Two octaves of value noise in [0, 1]: coarse blotches plus fine grain."""
        return 0.65 * self.sample(u, v) + 0.35 * self.sample(4.1 * u + 17.0, 4.1 * v + 5.0)


def checker(u: np.ndarray, v: np.ndarray, period: float) -> np.ndarray:
    return ((np.floor(u / period) + np.floor(v / period)) % 2).astype(np.float64)


def mix(a, b, t: np.ndarray) -> np.ndarray:
    """Blend colours a, b [3] by t [R] -> [R, 3]."""
    return np.asarray(a)[None] * (1 - t[:, None]) + np.asarray(b)[None] * t[:, None]


# --- geometry: each returns ray parameter t [R] (inf = miss) and normals [R, 3] -----------

def hit_plane(origins, dirs, axis: int, offset: float, lo: np.ndarray, hi: np.ndarray, normal_sign: float):
    """Axis-aligned rectangle {x[axis] = offset, lo <= other coords <= hi}, one-sided."""
    d = dirs[:, axis]
    # Rays parallel to the plane (|d| ~ 0) never hit it; the guard keeps the division finite.
    safe = np.where(np.abs(d) > 1e-12, d, 1.0)
    t = np.where(np.abs(d) > 1e-12, (offset - origins[:, axis]) / safe, _NO_HIT)
    t = np.where(t > 1e-6, t, _NO_HIT)
    point = origins + dirs * np.where(np.isfinite(t), t, 0.0)[:, None]
    others = [k for k in range(3) if k != axis]
    inside = np.all((point[:, others] >= lo) & (point[:, others] <= hi), axis=1)
    t = np.where(inside, t, _NO_HIT)
    normal = np.zeros_like(dirs)
    normal[:, axis] = normal_sign
    return t, normal


def hit_box(origins, dirs, center, half):
    """Slab test against an axis-aligned box; normal from the face that was entered."""
    center, half = np.asarray(center, float), np.asarray(half, float)
    # Zero direction components are replaced by a tiny value: the slab bounds become +-huge,
    # which is exactly the parallel-ray limit.
    safe = np.where(np.abs(dirs) > 1e-12, dirs, 1e-12)
    t0 = (center - half - origins) / safe
    t1 = (center + half - origins) / safe
    t_near = np.minimum(t0, t1)
    t_far = np.maximum(t0, t1)
    enter = t_near.max(axis=1)
    leave = t_far.min(axis=1)
    hit = (enter <= leave) & (enter > 1e-6)
    t = np.where(hit, enter, _NO_HIT)
    face = np.argmax(t_near, axis=1)
    normal = np.zeros_like(dirs)
    normal[np.arange(len(dirs)), face] = -np.sign(safe[np.arange(len(dirs)), face])
    return t, normal


def hit_sphere(origins, dirs, center, radius):
    """Nearest positive root of |o + t d - c|^2 = r^2 (dirs are unit vectors)."""
    oc = origins - np.asarray(center, float)
    b = np.sum(oc * dirs, axis=1)
    c = np.sum(oc * oc, axis=1) - radius * radius
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))  # only used where disc >= 0
    t = np.where(disc >= 0, -b - root, _NO_HIT)
    t = np.where(t > 1e-6, t, _NO_HIT)
    point = origins + dirs * np.where(np.isfinite(t), t, 0.0)[:, None]
    normal = (point - np.asarray(center, float)) / radius
    return t, normal


# --- the scene ------------------------------------------------------------------------------

_BOX_A = ((0.9, -0.9, 0.5), (0.5, 0.5, 0.5))
_BOX_B = ((-1.0, 1.8, 0.6), (0.4, 0.6, 0.6))
_SPHERE_A = ((-0.3, -0.2, 0.6), 0.6)
_SPHERE_B = ((1.3, 1.5, 0.45), 0.45)
_WALL_X = -3.0
_WALL_Y = (-3.5, 0.5)
_WALL_TOP = 2.5
_OBJECT_CENTER = np.array([-0.2, 0.2, 0.5])


def _shade(kind: int, points: np.ndarray, normals: np.ndarray, tex: Textures) -> np.ndarray:
    """Albedo [R, 3] of surface ``kind`` at points [R, 3]."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    if kind == 0:  # ground: large checker, tinted by noise, with fine grain
        base = mix((0.78, 0.74, 0.62), (0.32, 0.40, 0.30), checker(x, y, 0.75))
        return base * (0.6 + 0.5 * tex.fractal(2.0 * x + 31.0, 2.0 * y + 7.0))[:, None]
    if kind == 1:  # wall: brick-like stripes with offset rows and noise
        row = np.floor(z / 0.25)
        brick = ((np.floor((y + 0.25 * (row % 2)) / 0.5) + row) % 2).astype(float)
        base = mix((0.72, 0.30, 0.22), (0.85, 0.62, 0.45), brick)
        mortar = (np.abs(z / 0.25 - np.round(z / 0.25)) < 0.08)
        base[mortar] = (0.9, 0.9, 0.88)
        return base * (0.75 + 0.35 * tex.fractal(5.0 * y, 5.0 * z + 11.0))[:, None]
    if kind == 2:  # box A: small red/white checker on every face
        uv = points - np.asarray(_BOX_A[0])
        pattern = ((np.floor(uv[:, 0] / 0.2) + np.floor(uv[:, 1] / 0.2) + np.floor(uv[:, 2] / 0.2)) % 2)
        return mix((0.90, 0.88, 0.85), (0.80, 0.12, 0.10), pattern.astype(float))
    if kind == 3:  # box B: diagonal blue/yellow stripes
        stripes = (np.floor((x + y + z) / 0.15) % 2).astype(float)
        return mix((0.15, 0.25, 0.75), (0.95, 0.80, 0.20), stripes)
    if kind == 4:  # sphere A: latitude/longitude checker, green
        d = normals
        lon = np.arctan2(d[:, 1], d[:, 0])
        lat = np.arcsin(np.clip(d[:, 2], -1, 1))
        return mix((0.10, 0.55, 0.20), (0.85, 0.95, 0.80), checker(lon, lat, math.pi / 8))
    # sphere B: orange marbled noise
    t = tex.fractal(6.0 * x + 3.0, 6.0 * (y + z))
    return mix((0.95, 0.55, 0.10), (0.35, 0.12, 0.05), t)


def trace(origins: np.ndarray, dirs: np.ndarray, tex: Textures) -> tuple[np.ndarray, np.ndarray]:
    """Cast unit rays. origins, dirs: [R, 3] -> (colour [R, 3] in [0, 1], hit distance [R]
    with inf for rays that leave the scene)."""
    hits = [
        hit_plane(origins, dirs, 2, 0.0, np.array([-_GROUND_HALF_SIZE] * 2), np.array([_GROUND_HALF_SIZE] * 2), 1.0),
        hit_plane(origins, dirs, 0, _WALL_X, np.array([_WALL_Y[0], 0.0]), np.array([_WALL_Y[1], _WALL_TOP]), 1.0),
        hit_box(origins, dirs, *_BOX_A),
        hit_box(origins, dirs, *_BOX_B),
        hit_sphere(origins, dirs, *_SPHERE_A),
        hit_sphere(origins, dirs, *_SPHERE_B),
    ]
    kind, t = nearest_hits(hits)
    # Sky: brighter towards the horizon.
    colour = mix((0.55, 0.70, 0.95), (0.85, 0.90, 0.98), 1.0 - np.clip(dirs[:, 2], 0, 1))
    for k, (_, normals) in enumerate(hits):
        mask = (kind == k) & np.isfinite(t)
        if not mask.any():
            continue
        points = origins[mask] + dirs[mask] * t[mask, None]
        normal = normals[mask]
        # The wall is two-sided: light its back with the flipped normal.
        normal = np.where(np.sum(normal * dirs[mask], axis=1, keepdims=True) > 0, -normal, normal)
        albedo = _shade(k, points, normals[mask], tex)
        light = _AMBIENT + (1 - _AMBIENT) * np.clip(normal @ _LIGHT, 0, 1)
        colour[mask] = albedo * light[:, None]
    return np.clip(colour, 0, 1), t


def camera_rays(camera: Camera, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rays through pixel points (i + ox, j + oy) for each offset [S, 2]:
    -> origins [S*H*W, 3], unit directions [S*H*W, 3], ordered (sample, row, column)."""
    j, i = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    dirs = []
    for ox, oy in offsets:
        x = (i + ox - camera.cx) / camera.fx
        y = (j + oy - camera.cy) / camera.fy
        dirs.append(np.stack([x, y, np.ones_like(x)], -1).reshape(-1, 3))
    d = np.concatenate(dirs) @ camera.rotation  # camera -> world: R^T d, row-vector form
    d /= np.linalg.norm(d, axis=1, keepdims=True)  # norm >= 1: z component is 1 before rotating
    return np.broadcast_to(camera.center, d.shape), d


def nearest_hits(hits: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """hits: per surface (distance [R] with inf = miss, normals [R, 3]) -> (index of the nearest
    surface [R], its distance [R]; inf where every surface was missed)."""
    ts = np.stack([h[0] for h in hits])              # [S, R]
    kind = np.argmin(ts, axis=0)
    return kind, ts[kind, np.arange(ts.shape[1])]


def supersampled_photo(camera: Camera, trace_fn, samples: int = _SUPERSAMPLE) -> np.ndarray:
    """[H, W, 3] float in [0, 1]: the mean of samples x samples rays per pixel through
    trace_fn(origins [R, 3], dirs [R, 3]) -> (colour [R, 3], distance [R])."""
    offsets = np.array([((a + 0.5) / samples, (b + 0.5) / samples) for b in range(samples) for a in range(samples)])
    origins, dirs = camera_rays(camera, offsets)
    colour, _ = trace_fn(origins, dirs)
    return colour.reshape(len(offsets), camera.height, camera.width, 3).mean(axis=0)


def render_photo(camera: Camera, tex: Textures) -> np.ndarray:
    """Supersampled photo of the objects scene: [H, W, 3] float in [0, 1]."""
    return supersampled_photo(camera, lambda origins, dirs: trace(origins, dirs, tex))


def demo_cameras(size: str = "small", seed: int = 0) -> tuple[list[Camera], list[str], list[str]]:
    """-> (cameras, dense names, scarce names). Dense: an arc over the east side; scarce: a
    few views from the north-west."""
    width, height, n_dense, n_scarce = SIZES[size]
    rng = np.random.default_rng(seed)
    fx = 0.5 * width / math.tan(math.radians(_HORIZONTAL_FOV_DEG) / 2)
    cameras, dense, scarce = [], [], []

    def add(azimuth_deg: float, radius: float, height_: float, group: list[str]) -> None:
        a = math.radians(azimuth_deg)
        eye = np.array([radius * math.cos(a), radius * math.sin(a), height_])
        target = _OBJECT_CENTER + rng.normal(0, 0.15, 3)
        name = f"{len(cameras):03d}.png"
        cameras.append(Camera(name, width, height, fx, fx, width / 2, height / 2,
                              look_at(eye, target, up=(0.0, 0.0, 1.0))))
        group.append(name)

    for azimuth in np.linspace(-65, 65, n_dense):
        add(azimuth + rng.normal(0, 2), 5.0 + rng.normal(0, 0.3), 2.0 + rng.uniform(0, 1.0), dense)
    for azimuth in np.linspace(105, 140, n_scarce):
        add(azimuth + rng.normal(0, 2), 5.0 + rng.normal(0, 0.3), 2.2 + rng.uniform(0, 0.6), scarce)
    return cameras, dense, scarce


def sample_points(cameras: list[Camera], trace_fn, rng: np.random.Generator,
                  per_camera: int = _POINTS_PER_CAMERA):
    """Surface points seen by the cameras, with their colours: ([P, 3], [P, 3] uint8).
    trace_fn(origins [R, 3], dirs [R, 3]) -> (colour [R, 3], distance [R], inf = miss)."""
    points, colours = [], []
    for camera in cameras:
        offsets = rng.uniform(0, 1, (1, 2))
        origins, dirs = camera_rays(camera, offsets)
        pick = rng.choice(len(dirs), size=min(per_camera, len(dirs)), replace=False)
        colour, t = trace_fn(origins[pick], dirs[pick])
        hit = np.isfinite(t)
        points.append(origins[pick][hit] + dirs[pick][hit] * t[hit, None])
        colours.append(np.round(colour[hit] * 255).astype(np.uint8))
    return np.concatenate(points), np.concatenate(colours)


def check_out_dir(out_dir: Path) -> None:
    """Refuse anything but a missing folder, an empty one or a previous demo scene, and a parent
    folder that cannot be written: one line before any rendering."""
    if out_dir.exists() and (not out_dir.is_dir() or (any(out_dir.iterdir())
                                                       and not (out_dir / "demo_scene.json").is_file())):
        raise InputError(f"{out_dir}: exists and is not an empty folder or a previous demo scene")
    check_writable_dir(out_dir.parent)


def write_scene_folder(out_dir: Path, cameras: list[Camera], photo_fn, points: np.ndarray,
                       colours: np.ndarray, meta: dict, progress: bool = True, desc: str = "demo scene",
                       jpeg_quality: int = 92) -> Path:
    """images/, sparse/0/*.bin and demo_scene.json, built beside out_dir and renamed into place
    (an interrupted run leaves nothing half-written; a previous demo scene is replaced).
    photo_fn(camera) -> [H, W, 3] float in [0, 1] or uint8, encoded as the camera's file name
    says (.png, .jpg at ``jpeg_quality``)."""
    check_out_dir(out_dir)
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    except OSError as exc:
        raise output_error(out_dir, exc) from None
    try:
        for camera in tqdm(cameras, desc=desc, unit="view", disable=not progress):
            photo = photo_fn(camera)
            pixels = photo if photo.dtype == np.uint8 else np.round(photo * 255).astype(np.uint8)
            suffix = Path(camera.name).suffix.lower()
            params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if suffix in (".jpg", ".jpeg") else []
            ok, encoded = cv2.imencode(suffix, np.ascontiguousarray(pixels[:, :, ::-1]), params)
            if not ok:
                raise RuntimeError(f"{suffix} encoding failed")
            atomic_write_bytes(staging / "images" / camera.name, encoded.tobytes())
        model = [(c, "PINHOLE", [c.fx, c.fy, c.cx, c.cy]) for c in cameras]
        ensure_dir(staging / "sparse" / "0")
        write_colmap_binary(staging / "sparse" / "0", model, points, colours)
        atomic_write_text(staging / "demo_scene.json", json.dumps(meta, indent=2) + "\n")
        try:
            if out_dir.exists():
                old = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}")
                os.replace(out_dir, old)
                os.replace(staging, out_dir)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(staging, out_dir)
        except OSError as exc:
            raise output_error(out_dir, exc) from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out_dir


def write_demo_scene(out_dir: str | Path, size: str = "small", seed: int = 0, progress: bool = True) -> Path:
    """Write images/, sparse/0/{cameras,images,points3D}.bin and demo_scene.json to out_dir.

    The folder is built beside out_dir and renamed into place, so an interrupted run leaves
    nothing half-written. An existing demo scene at out_dir is replaced; any other non-empty
    folder is refused. Returns out_dir.
    """
    if size not in SIZES:
        raise InputError(f"{out_dir}: unknown demo scene size {size!r} (choose {', '.join(SIZES)})")
    out_dir = Path(out_dir)
    check_out_dir(out_dir)
    rng = np.random.default_rng(seed)
    tex = Textures(noise=rng.random((64, 64)))
    cameras, dense, scarce = demo_cameras(size, seed)
    # Photos first, then the points: the random stream stays the one the scene always used.
    photos = {camera.name: render_photo(camera, tex)
              for camera in tqdm(cameras, desc="demo scene", unit="view", disable=not progress)}
    points, colours = sample_points(cameras, lambda o, d: trace(o, d, tex), rng)
    meta = {
        "description": "InceptionGS procedural demo scene (z up, ground at z = 0)",
        "scene": "objects", "size": size, "seed": seed, "width": cameras[0].width, "height": cameras[0].height,
        "dense_cameras": dense, "scarce_cameras": scarce,
        "note": "scarce cameras view the north-west side, which the dense arc sees at most obliquely",
    }
    return write_scene_folder(out_dir, cameras, lambda camera: photos[camera.name], points, colours, meta,
                              progress=False)
