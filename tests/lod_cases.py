"""Random Gaussian models for the level-of-detail tests (tests/lod)."""

from __future__ import annotations

import numpy as np

from inceptiongs.gaussians import Gaussians


def random_gaussians(n: int, seed: int = 0, logit: float | None = None, degree: int = 1) -> Gaussians:
    """n Gaussians around the origin (unit normal means, scales ~ e^-3), unnormalised quaternions,
    opacity logits normal (or all ``logit``), SH of ``degree`` normal."""
    rng = np.random.default_rng(seed)
    logits = rng.normal(size=n) if logit is None else np.full(n, logit)
    return Gaussians.from_numpy({
        "means": rng.normal(size=(n, 3)), "log_scales": rng.normal(-3.0, 0.5, size=(n, 3)),
        "quats": rng.normal(size=(n, 4)), "opacity_logits": logits,
        "sh": rng.normal(size=(n, (degree + 1) ** 2, 3))})
