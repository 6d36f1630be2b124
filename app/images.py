"""PNG writing for screenshots (atomic) and the visualisation of non-colour render modes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from inceptiongs.atomic import atomic_write_bytes
from inceptiongs.errors import InputError


def to_uint8(image: np.ndarray) -> np.ndarray:
    """[H, W, C] float in [0, 1] -> uint8 with rounding; C = 1 is repeated to grey RGB."""
    if image.ndim == 3 and image.shape[2] == 1:
        image = np.repeat(image, 3, axis=2)
    return np.clip(image.astype(np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)


def write_png(path: str | Path, image: np.ndarray) -> None:
    """image: [H, W, 3] float RGB in [0, 1] (or uint8), row 0 = top."""
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


def visualize(image: np.ndarray, mode: str) -> np.ndarray:
    """A render-mode output as displayable RGB [H, W, 3] in [0, 1]:
    depth -> near bright / far dark over the robust range of covered pixels; normal -> 0.5 + 0.5 n;
    opacity/alpha -> grey; rgb unchanged."""
    if mode == "depth":
        depth = image[..., 0]
        covered = depth > 0
        out = np.zeros_like(depth)
        if covered.any():
            lo, hi = np.percentile(depth[covered], [2, 98])
            span = max(hi - lo, 1e-6)  # a flat depth range still maps to one grey level
            out[covered] = 1.0 - np.clip((depth[covered] - lo) / span, 0, 1) * 0.9
        return np.repeat(out[..., None], 3, axis=2)
    if mode == "normal":
        return np.clip(0.5 + 0.5 * image, 0, 1)
    if mode in ("alpha", "opacity"):
        return np.repeat(np.clip(image[..., :1], 0, 1), 3, axis=2)
    return np.clip(image, 0, 1)
