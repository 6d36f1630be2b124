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
    rgb = image if image.dtype == np.uint8 else to_uint8(image)
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise InputError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, encoded.tobytes())


def read_png(path: str | Path) -> np.ndarray:
    """[H, W, 3] uint8 RGB."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    return image[..., ::-1].copy()
