"""Random Gaussian models for the level-of-detail tests (tests/lod)."""

from __future__ import annotations

import math

import numpy as np

from inceptiongs.camera import Camera, look_at
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


def psnr(image, reference) -> float:
    mse = float(((image - reference) ** 2).mean())
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def orbit_camera(means: np.ndarray, width=128, height=96) -> Camera:
    """A camera looking at the model's median from 2.5 times its 95th-percentile radius."""
    centre = np.median(means, axis=0)
    radius = np.percentile(np.linalg.norm(means - centre, axis=1), 95)
    direction = np.array([0.3, -1.0, -2.0]) / np.linalg.norm([0.3, -1.0, -2.0])
    return Camera("orbit", width, height, 0.9 * width, 0.9 * width, width / 2, height / 2,
                  look_at(centre + 2.5 * radius * direction, centre))
