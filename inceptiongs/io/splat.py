"""The ``.splat`` format of the first web viewers (antimatter15/splat and those that followed):
read and write.

No header: the file is N records of 32 bytes, little-endian::

    float32 position[3]   the mean, as in the PLY
    float32 scale[3]      linear scales: exp(log scale)
    uint8   rgba[4]       r, g, b = round(255 * clamp(0.5 + SH_C0 * f_dc, 0, 1)),
                          a = round(255 * sigmoid(opacity logit))
    uint8   rotation[4]   the unit quaternion (w, x, y, z): byte = clamp(round(128 * q + 128), 0, 255)

It has no SH rest (view-dependent colour is dropped: degree 0 only), and colours outside
[0, 1] are clamped. Positions and scales are float32 as in the PLY (scales go through exp and
log: a relative error of a few float32 ulps); colours and opacity are within half an 8-bit
step; each quaternion component within 1/256 before renormalisation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..constants import SH_C0
from ..errors import InputError
from ..gaussians import Gaussians
from .limits import check_allocation
from .quantise import logits_from_bytes, sigmoid, unit_quaternions

RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])
# Log scales are clamped here before exp: exp(+-80) is a finite float32 (exp(89) is not), and
# no splat is 1e34 times its scene.
LOG_SCALE_LIMIT = 80.0


def encode_splat(gaussians: Gaussians) -> bytes:
    """The .splat bytes of ``gaussians`` (SH rest, if any, is not written)."""
    arrays = gaussians.numpy()
    records = np.zeros(len(gaussians), RECORD)
    records["position"] = arrays["means"]
    records["scale"] = np.exp(np.clip(arrays["log_scales"].astype(np.float64), -LOG_SCALE_LIMIT, LOG_SCALE_LIMIT))
    colour = np.clip(0.5 + SH_C0 * arrays["sh"][:, 0].astype(np.float64), 0.0, 1.0)
    records["rgba"][:, :3] = np.round(colour * 255.0)
    records["rgba"][:, 3] = np.round(sigmoid(arrays["opacity_logits"]) * 255.0)
    records["rotation"] = np.clip(np.round(unit_quaternions(arrays["quats"]) * 128.0 + 128.0), 0, 255)
    return records.tobytes()


def read_splat(path: str | Path) -> Gaussians:
    """A .splat file -> float32 CPU Gaussians of SH degree 0; InputError naming the file when
    its size is not whole records or its values cannot be a .splat's."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    if size % RECORD.itemsize:
        raise InputError(f"{path}: truncated or not a .splat file: {size} bytes is not a whole number "
                         f"of {RECORD.itemsize}-byte splats")
    count = size // RECORD.itemsize
    check_allocation(3 * count * 14 * 4 + size, str(path), f"{count} splats")
    try:
        records = np.fromfile(path, RECORD)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    bad = ~np.all(np.isfinite(records["position"]), axis=1) | ~np.all(np.isfinite(records["scale"]), axis=1)
    # exp() never gives a negative scale: a file that has one is not a .splat (garbage bytes
    # make half of all floats negative).
    bad |= np.any(records["scale"] < 0, axis=1)
    if bad.any():
        raise InputError(f"{path}: not a .splat file: {int(bad.sum())} of {count} splats have NaN/Inf "
                         f"positions or negative/NaN scales (first: splat {int(np.argmax(bad))})")
    scale = records["scale"].astype(np.float64)
    # A scale of 0 (exp underflow of a very small log scale) is read as the smallest normal
    # float32 so its log is finite.
    log_scales = np.log(np.maximum(scale, np.finfo(np.float32).tiny))
    arrays = {
        "means": records["position"],
        "log_scales": log_scales,
        "quats": (records["rotation"].astype(np.float64) - 128.0) / 128.0,
        "opacity_logits": logits_from_bytes(records["rgba"][:, 3]),
        "sh": ((records["rgba"][:, :3] / 255.0 - 0.5) / SH_C0)[:, None, :],
    }
    return Gaussians.from_numpy({name: np.ascontiguousarray(values, np.float32) for name, values in arrays.items()})
