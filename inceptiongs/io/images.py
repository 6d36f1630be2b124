"""Image files the project writes and reads: PNG (and JPEG by extension) through OpenCV,
written atomically."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from .atomic import atomic_write_bytes


def to_uint8(image: np.ndarray) -> np.ndarray:
    """[H, W, C] float in [0, 1] -> uint8 with rounding; C = 1 is repeated to grey RGB."""
    if image.ndim == 3 and image.shape[2] == 1:
        image = np.repeat(image, 3, axis=2)
    return np.clip(image.astype(np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)


def write_png(path: str | Path, image: np.ndarray) -> None:
    """image: [H, W, 3] float RGB in [0, 1] (or uint8), row 0 = top -> PNG at ``path``, atomically."""
    _write_encoded(path, image, ".png")


def _write_encoded(path: str | Path, image: np.ndarray, encoding: str) -> None:
    rgb = image if image.dtype == np.uint8 else to_uint8(image)
    ok, encoded = cv2.imencode(encoding, np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise InputError(f"{path}: {encoding[1:].upper()} encoding failed")
    atomic_write_bytes(path, encoded.tobytes())


# The formats write_image writes, by file extension.
IMAGE_ENCODINGS = {".png": ".png", ".jpg": ".jpg", ".jpeg": ".jpg", ".bmp": ".bmp", ".tif": ".tif", ".tiff": ".tif"}


def image_encoding(path: str | Path) -> str:
    """The encoder for ``path``'s extension (.png, .jpg/.jpeg, .bmp, .tif/.tiff); another
    extension is an InputError naming the file."""
    encoding = IMAGE_ENCODINGS.get(Path(path).suffix.lower())
    if encoding is None:
        raise InputError(f"{path}: unknown image format (use one of {', '.join(sorted(IMAGE_ENCODINGS))})")
    return encoding


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Like write_png, in the format the extension names (image_encoding)."""
    _write_encoded(path, image, image_encoding(path))


def read_png(path: str | Path) -> np.ndarray:
    """[H, W, 3] uint8 RGB."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    return image[..., ::-1].copy()
