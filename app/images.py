"""The visualisation of non-colour render modes as displayable RGB."""

from __future__ import annotations

import numpy as np



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


# The photo shown "beside" the render is an inset this fraction of the image's width.
PHOTO_INSET_FRACTION = 0.35


def compose_photo(render: np.ndarray, photo: np.ndarray, how: str, alpha: float) -> np.ndarray:
    """render: [H, W, 3]; photo: [h, w, 3] (any size; float in [0, 1]) -> [H, W, 3]:
    "blended": the photo resized to the render, mixed in with weight ``alpha``; "beside": the
    photo as an inset in the bottom-right corner (PHOTO_INSET_FRACTION of the width, its aspect
    kept, a 2-px white frame); anything else: the render unchanged."""
    import cv2  # noqa: PLC0415

    height, width = render.shape[:2]
    out = np.array(render, np.float32, copy=True)
    if how == "blended":
        resized = cv2.resize(np.asarray(photo, np.float32), (width, height), interpolation=cv2.INTER_AREA)
        a = float(np.clip(alpha, 0.0, 1.0))
        return (1.0 - a) * out + a * resized
    if how == "beside":
        inset_w = max(int(width * PHOTO_INSET_FRACTION), 1)
        inset_h = max(min(int(round(inset_w * photo.shape[0] / max(photo.shape[1], 1))), height), 1)
        inset = cv2.resize(np.asarray(photo, np.float32), (inset_w, inset_h), interpolation=cv2.INTER_AREA)
        top, left = height - inset_h, width - inset_w
        out[max(top - 2, 0):, max(left - 2, 0):] = 1.0
        out[top:, left:] = inset
    return out
