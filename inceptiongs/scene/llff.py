"""LLFF ``poses_bounds.npy`` (N x 17) with ``images/`` or ``images_N/`` folders.

Each row is a 3x5 matrix (row-major) followed by near/far bounds. Its columns 0-2 are the
camera-to-world rotation with LLFF's camera axes [down, right, back], column 3 the camera
centre, column 4 (height, width, focal) of the full-resolution images. The sorted
image names of the chosen folder match the rows.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..camera import Camera, rigid_inverse
from ..errors import InputError
from ..io.paths import contained_path
from .raw import RawScene, check_finite_pose, check_intrinsics

_IMAGE_EXTENSIONS = {".png", ".jpg", ".jpeg"}


def _image_folders(root: Path) -> dict[int, Path]:
    """{downscale N: folder} for images/ (N = 1) and images_N/."""
    folders = {}
    for child in root.iterdir():
        match = re.fullmatch(r"images(?:_(\d+))?", child.name)
        if child.is_dir() and match:
            folders[int(match.group(1) or 1)] = child
    return folders


def load_llff(root: Path, downscale: float = 1) -> RawScene:
    path = root / "poses_bounds.npy"
    try:
        table = np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001  (a corrupt header raises ValueError, SyntaxError, TokenError, ...)
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{path}: cannot read as a .npy array ({message})") from None
    if table.dtype.kind not in "fiu":
        raise InputError(f"{path}: expected a real-valued array, got dtype {table.dtype}")
    if table.ndim != 2 or table.shape[1] != 17:
        raise InputError(f"{path}: expected an N x 17 array, got shape {table.shape}")
    if not np.all(np.isfinite(table)):
        raise InputError(f"{path}: contains NaN or Inf")

    folders = _image_folders(root)
    if not folders:
        raise InputError(f"{root}: LLFF scene has no images/ or images_N/ folder")
    warnings = []
    # The folder made for exactly this downscale if there is one, otherwise the sharpest
    # folder that is not smaller than the requested size, otherwise the sharpest there is.
    if downscale in folders:
        chosen = int(downscale)
    else:
        usable = [n for n in folders if n <= downscale]
        chosen = max(usable) if usable else min(folders)
        if chosen > downscale:
            warnings.append(f"no image folder at downscale {downscale:g}; using {folders[chosen].name}/")
    folder = folders[chosen]
    images = sorted(contained_path(folder, p.name, f"{folder}") for p in folder.iterdir()
                    if p.suffix.lower() in _IMAGE_EXTENSIONS)
    if len(images) != len(table):
        raise InputError(f"{path}: {len(table)} poses but {len(images)} images in {folder.name}/")

    from PIL import Image

    try:
        with Image.open(images[0]) as first:
            width, height = first.size
    except Exception:
        raise InputError(f"{images[0]}: cannot read image header") from None

    cameras, models = [], []
    for row, image in zip(table, images):
        matrix = row[:15].reshape(3, 5)
        full_h, full_w, focal = matrix[:, 4]
        source = f"{path} row for {image.name}"
        check_intrinsics(full_w, full_h, [focal, focal], source)
        # [down, right, back] -> OpenCV [right, down, forward].
        rotation = np.stack([matrix[:, 1], matrix[:, 0], -matrix[:, 2]], axis=1)
        camera_to_world = np.eye(4)
        camera_to_world[:3, :3] = rotation
        camera_to_world[:3, 3] = matrix[:, 3]
        check_finite_pose(camera_to_world, source)
        # Intrinsics scale with the files' actual size (images_N are rounded sizes).
        sx, sy = width / full_w, height / full_h
        cameras.append(Camera(image.name, width, height, focal * sx, focal * sy,
                              0.5 * full_w * sx, 0.5 * full_h * sy, rigid_inverse(camera_to_world)))
        models.append("PINHOLE")
    source_downscale = float(table[0, 9] / width) if width else 1.0  # full width / file width
    return RawScene(root, "llff", cameras, images, models, [None] * len(cameras),
                    warnings=warnings, source_downscale=source_downscale)
