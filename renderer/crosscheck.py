"""Agreement figures between two renderings (GL vs the torch reference).

Used by the cross-check tests and the benchmark, so both report the same numbers.
"""

from __future__ import annotations

import numpy as np

from inceptiongs.evaluation.metrics import psnr

# Acceptance thresholds of the GL-vs-torch cross-check.
RGB_PSNR_MIN_DB = 45.0
ALPHA_TOLERANCE = 2e-3
ALPHA_FRACTION_MIN = 0.999


def fraction_within(image: np.ndarray, reference: np.ndarray, tolerance: float) -> float:
    """Share of elements with |image - reference| <= tolerance (NaN counts as outside)."""
    difference = np.abs(np.asarray(image, np.float64) - np.asarray(reference, np.float64))
    return float(np.mean(difference <= tolerance))


def agreement(rgb: np.ndarray, alpha: np.ndarray, rgb_ref: np.ndarray, alpha_ref: np.ndarray) -> dict:
    """{"psnr": dB, "alpha_within": share of pixels within ALPHA_TOLERANCE, "alpha_max": max
    abs alpha difference, "ok": both thresholds met}."""
    value = float(psnr(np.asarray(rgb, np.float64), np.asarray(rgb_ref, np.float64)))
    within = fraction_within(alpha, alpha_ref, ALPHA_TOLERANCE)
    alpha_max = float(np.max(np.abs(alpha - alpha_ref))) if alpha.size else 0.0
    return {"psnr": value, "alpha_within": within, "alpha_max": alpha_max,
            "ok": value >= RGB_PSNR_MIN_DB and within >= ALPHA_FRACTION_MIN}
