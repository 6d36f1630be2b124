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
