"""Value conversions shared by the quantised model formats (.splat, .spz, compressed PLY)."""

from __future__ import annotations

import numpy as np

# Logits are clamped before the sigmoid so exp(-x) cannot overflow float64 (60 is far past
# any opacity an 8-bit alpha can tell apart from 1).
LOGIT_LIMIT = 60.0
# An 8-bit alpha of 0 or 255 is read as half a step inside (0, 1), so its logit is finite.
ALPHA_EDGE = 0.5 / 255.0


def sigmoid(logits: np.ndarray) -> np.ndarray:
    """Opacity from logits, in float64, overflow-free."""
    return 1.0 / (1.0 + np.exp(-np.clip(np.asarray(logits, np.float64), -LOGIT_LIMIT, LOGIT_LIMIT)))


def logits_from_bytes(alpha: np.ndarray) -> np.ndarray:
    """8-bit opacities (alpha = round(255 * sigmoid(logit))) -> float64 logits, the end steps
    read half a step inside (0, 1) so none is infinite."""
    opacity = np.clip(np.asarray(alpha, np.float64) / 255.0, ALPHA_EDGE, 1.0 - ALPHA_EDGE)
    return np.log(opacity / (1.0 - opacity))


def unit_quaternions(quats: np.ndarray) -> np.ndarray:
    """quats: [N, 4] -> [N, 4] float64 of unit length; a zero quaternion becomes the identity
    (the renderers' rule for one)."""
    quats = np.asarray(quats, np.float64)
    norms = np.linalg.norm(quats, axis=1, keepdims=True)
    identity = np.zeros_like(quats)
    identity[:, 0] = 1.0
    return np.where(norms > 0, quats / np.where(norms > 0, norms, 1.0), identity)


def clamped_note(values: np.ndarray, low: float, high: float, what: str) -> str | None:
    """A one-line note when some of ``values`` lie outside [low, high] (and so are clamped by a
    format), else None."""
    values = np.asarray(values)
    outside = int(np.count_nonzero((values < low) | (values > high)))
    if not outside:
        return None
    return f"{outside} of {values.size} {what} lie outside [{low:g}, {high:g}] and are clamped"
