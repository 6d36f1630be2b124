"""How far a model read back from a file is from the model that was written: the figures
`inceptiongs convert --check`, benchmarks/bench_formats.py and the format tests report.

Every figure compares splat i with splat i (reorder one side first when the format reorders):

- positions: |difference| per coordinate, relative to the scene extent (the largest side of
  the source means' bounding box);
- colour: the SH0 colour 0.5 + SH_C0 * f_dc of each channel, both clamped to the displayable
  [0, 1], difference in 8-bit levels (x 255);
- opacity: |sigmoid(logit) difference|, in [0, 1];
- log scale: |difference| (0.01 is a 1 % scale error);
- rotation: the angle between the two unit quaternions, degrees (q and -q are one rotation);
- SH rest: |difference| of the coefficients both models have (none when either is degree 0).
"""

from __future__ import annotations

import numpy as np

from ..constants import SH_C0
from ..gaussians import Gaussians
from .quantise import sigmoid, unit_quaternions

# The figures, in the order printed: (key, what, unit).
FIGURES = (
    ("position", "positions", "of the scene extent"),
    ("colour", "colour", "8-bit levels"),
    ("opacity", "opacity", "(0..1)"),
    ("log_scale", "log scales", ""),
    ("rotation", "rotations", "degrees"),
    ("sh_rest", "SH rest", ""),
)


def scene_extent(means: np.ndarray) -> float:
    """The largest side of the bounding box of ``means`` [N, 3]; 1.0 for an empty or single-point
    model (no extent to be relative to)."""
    if len(means) == 0:
        return 1.0
    extent = float(np.max(np.max(means, axis=0) - np.min(means, axis=0)))
    return extent if extent > 0 else 1.0


def _max_mean(values: np.ndarray) -> tuple[float, float]:
    values = np.asarray(values, np.float64)
    return (float(values.max()), float(values.mean())) if values.size else (0.0, 0.0)


def model_error(source: Gaussians, decoded: Gaussians) -> dict[str, tuple[float, float]]:
    """{figure key: (max, mean)} of ``decoded`` against ``source`` (same splat count and order)."""
    if len(source) != len(decoded):
        raise ValueError(f"model_error: {len(source)} splats against {len(decoded)}")
    a, b = source.numpy(), decoded.numpy()
    extent = scene_extent(a["means"])
    colour_a = np.clip(0.5 + SH_C0 * a["sh"][:, 0].astype(np.float64), 0.0, 1.0)
    colour_b = np.clip(0.5 + SH_C0 * b["sh"][:, 0].astype(np.float64), 0.0, 1.0)
    # The angle between rotations as 2 atan2(|qa - qb|, |qa + qb|) with qb's sign matched to qa:
    # exact near 0, where arccos(<qa, qb>) loses half its digits.
    qa, qb = unit_quaternions(a["quats"]), unit_quaternions(b["quats"])
    qb = qb * np.where(np.sum(qa * qb, axis=1, keepdims=True) < 0, -1.0, 1.0)
    angle = 2.0 * np.arctan2(np.linalg.norm(qa - qb, axis=1), np.linalg.norm(qa + qb, axis=1))
    k = min(a["sh"].shape[1], b["sh"].shape[1])
    return {
        "position": _max_mean(np.abs(a["means"].astype(np.float64) - b["means"]) / extent),
        "colour": _max_mean(np.abs(colour_a - colour_b) * 255.0),
        "opacity": _max_mean(np.abs(sigmoid(a["opacity_logits"]) - sigmoid(b["opacity_logits"]))),
        "log_scale": _max_mean(np.abs(a["log_scales"].astype(np.float64) - b["log_scales"])),
        "rotation": _max_mean(np.degrees(angle)),
        "sh_rest": _max_mean(np.abs(a["sh"][:, 1:k].astype(np.float64) - b["sh"][:, 1:k])),
    }


def format_error_lines(error: dict[str, tuple[float, float]]) -> list[str]:
    """One line per figure: '  positions   max 1.2e-04  mean 3.4e-05 of the scene extent'."""
    lines = []
    for key, what, unit in FIGURES:
        worst, mean = error[key]
        lines.append(f"  {what:<10}  max {worst:.3g}  mean {mean:.3g} {unit}".rstrip())
    return lines
