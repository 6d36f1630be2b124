"""Shared model-format cases: the stated round-trip error per format (docs/scene_io.md) and
random models whose values lie inside every format's ranges."""

from __future__ import annotations

import numpy as np

from inceptiongs.gaussians import Gaussians

# The stated round-trip error per format (docs/scene_io.md, "Model formats"): max of
# positions (fraction of the scene extent), colour (8-bit levels), opacity, log scale,
# rotation (degrees), SH rest, on models whose values lie inside the formats' ranges.
# Compressed PLY's position, colour and scale bounds are half a step of a chunk's range; here
# bounded by the whole model's (the worst chunk), which is what the figures below assume:
# colours span at most [0, 1] (0.5 levels) and log scales [-5, -1] (4 / 2046).
STATED = {
    "ply": {"position": 0.0, "colour": 0.0, "opacity": 0.0, "log_scale": 0.0, "rotation": 1e-4, "sh_rest": 0.0},
    "compressed.ply": {"position": 1 / 2046, "colour": 0.5, "opacity": 1 / 510, "log_scale": 4 / 2046,
                       "rotation": 0.3, "sh_rest": 1 / 64},
    "splat": {"position": 0.0, "colour": 0.5, "opacity": 1 / 510, "log_scale": 1e-6, "rotation": 1.0,
              "sh_rest": 0.0},
    "spz": {"position": 2e-7, "colour": 0.95, "opacity": 1 / 510, "log_scale": 1 / 32, "rotation": 0.3,
            "sh_rest": 1 / 256},
}
# Floating-point slack on top of a quantisation bound (float32 decode arithmetic).
SLACK = 1e-5


def random_model(count: int, degree: int, seed: int = 0) -> Gaussians:
    """Values inside every format's ranges: colours 0.5 + SH_C0 * f_dc within [0.08, 0.92]."""
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2
    sh = np.concatenate([rng.uniform(-1.5, 1.5, (count, 1, 3)), rng.uniform(-0.9, 0.9, (count, k - 1, 3))], axis=1)
    return Gaussians.from_numpy({
        "means": rng.uniform(-3.0, 3.0, (count, 3)) + np.array([10.0, -2.0, 0.5]),
        "log_scales": rng.uniform(-5.0, -1.0, (count, 3)),
        "quats": rng.normal(size=(count, 4)) * rng.uniform(0.5, 2.0, (count, 1)),  # not unit: formats normalise
        "opacity_logits": rng.uniform(-5.0, 5.0, count),
        "sh": sh,
    })
