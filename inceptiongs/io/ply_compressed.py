"""SuperSplat's compressed PLY (the PlayCanvas layout, ``*.compressed.ply``): read and write.

The quantisation itself is the gsply library's (``decompress_from_bytes`` /
``compress_to_bytes``); this module checks the file before handing it over, orders the splats
for writing and says what the layout keeps. The layout, a binary little-endian PLY:

- ``element chunk C``, C = ceil(N / 256): 18 float32 per chunk of 256 consecutive splats:
  min/max of x y z, min/max of the log scales (clamped to [-20, 20]) and min/max of the
  colour r g b, colour = 0.5 + SH_C0 * f_dc (the SH0 colour, not clamped to [0, 1]).
- ``element vertex N``, four uint32 per splat, each field a fraction of its chunk's range:
  ``packed_position`` x, y, z in 11, 10, 11 bits; ``packed_scale`` the log scales likewise;
  ``packed_color`` r, g, b and opacity = sigmoid(logit) in 8 bits each; ``packed_rotation``
  the unit quaternion (w, x, y, z) made to have its largest-magnitude component positive:
  that component's index in 2 bits, the other three (in w, x, y, z order) mapped from
  [-1/sqrt2, 1/sqrt2] to 10 bits each.
- ``element sh N`` (only for SH degree >= 1): uchar ``f_rest_0..``, channel-major like the
  standard PLY, coefficient = (byte - 127.5) / 32, i.e. [-4, 4] in steps of 1/32.

So a round trip is exact in nothing: positions are off by at most half a step of their
chunk's extent (1/4094 of it in x and z, 1/2046 in y), colours and opacity by half of an
8-bit step of their chunk's range, SH rest by 1/64. The writer sorts the splats along a
Morton (Z-order) curve first, as SuperSplat does, so each chunk holds neighbours and its
ranges are small: splat order in the file is not the model's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..gaussians import Gaussians
from .limits import check_allocation

CHUNK_SIZE = 256
CHUNK_PROPERTIES = [f"{bound}_{name}" for bound in ("min", "max") for name in ("x", "y", "z")] + \
    [f"{bound}_scale_{axis}" for bound in ("min", "max") for axis in ("x", "y", "z")] + \
    [f"{bound}_{channel}" for bound in ("min", "max") for channel in ("r", "g", "b")]
VERTEX_PROPERTIES = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]
# What the layout's 8-bit SH rest covers: (byte - 127.5) / 32 for bytes 0..255.
SH_REST_RANGE = (-127.5 / 32, 127.5 / 32)
# The chunk bounds of log scales are clamped to this range (SuperSplat's and gsply's rule).
LOG_SCALE_RANGE = (-20.0, 20.0)
# Bits of the Morton code per axis: 3 x 10 bits fit an int64 with room, and 1024 cells a side
# put ~1 splat per cell for a million splats: finer would not change which 256 share a chunk.
MORTON_BITS = 10


def is_compressed_layout(elements) -> bool:
    """Whether a parsed PLY header (``ply._parse_header``'s elements) is the compressed layout."""
    return any(name == "vertex" and any(prop == "packed_position" for prop, _ in props)
               for name, _, props in elements)


def _check_layout(path: Path, byte_order: str, elements) -> tuple[int, int]:
    """-> (splat count, SH rest values per splat), or InputError naming what differs."""
    if byte_order != "<":
        raise InputError(f"{path}: compressed PLY must be binary_little_endian")
    names = [name for name, _, _ in elements]
    if names[:2] != ["chunk", "vertex"] or names[2:] not in ([], ["sh"]):
        raise InputError(f"{path}: compressed PLY elements are {names}, expected chunk, vertex[, sh]")
    (_, chunks, chunk_props), (_, count, vertex_props) = elements[:2]
    chunk_names = [prop for prop, _ in chunk_props]
    if chunk_names == CHUNK_PROPERTIES[:12]:
        raise InputError(f"{path}: compressed PLY without colour ranges per chunk (an older SuperSplat "
                         "layout) is not supported; re-save it with a current SuperSplat")
    if chunk_names != CHUNK_PROPERTIES or any(code != "f4" for _, code in chunk_props):
        raise InputError(f"{path}: compressed PLY chunk properties are not the 18 float bounds "
                         f"{CHUNK_PROPERTIES[0]}..{CHUNK_PROPERTIES[-1]}")
    if [prop for prop, _ in vertex_props] != VERTEX_PROPERTIES or any(code != "u4" for _, code in vertex_props):
        raise InputError(f"{path}: compressed PLY vertex properties are not uint {', '.join(VERTEX_PROPERTIES)}")
    if chunks != -(-count // CHUNK_SIZE):
        raise InputError(f"{path}: compressed PLY declares {chunks} chunks for {count} splats "
                         f"(expected {-(-count // CHUNK_SIZE)})")
    rest = 0
    if len(elements) == 3:
        _, sh_count, sh_props = elements[2]
        rest = len(sh_props)
        expected = [f"f_rest_{i}" for i in range(rest)]
        if sh_count != count or [p for p, _ in sh_props] != expected or any(c != "u1" for _, c in sh_props):
            raise InputError(f"{path}: compressed PLY 'sh' element is not {count} rows of uchar f_rest_0..")
        if rest not in (9, 24, 45):
            raise InputError(f"{path}: compressed PLY has {rest} SH rest values, not an SH degree 1-3 (9, 24, 45)")
    return count, rest


def read_compressed_ply(path: Path, header_len: int, byte_order: str, elements) -> Gaussians:
    """A compressed PLY whose header ``ply.read_ply`` parsed -> float32 CPU Gaussians in file order."""
    count, rest = _check_layout(path, byte_order, elements)
    needed = header_len + -(-count // CHUNK_SIZE) * 18 * 4 + count * (16 + rest)
    size = path.stat().st_size
    if size < needed:
        raise InputError(f"{path}: truncated compressed PLY: header declares {count} splats "
                         f"({needed} bytes) but the file has {size} bytes")
    check_allocation(size + 4 * count * (14 + rest) * 3, str(path), f"{count} declared splats")
    import gsply

    try:
        data = gsply.decompress_from_bytes(path.read_bytes()[:needed])
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: compressed PLY cannot be decoded ({exc})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    k_rest = rest // 3
    sh = np.empty((count, 1 + k_rest, 3), np.float32)
    sh[:, 0] = data.sh0
    if k_rest:
        sh[:, 1:] = np.asarray(data.shN, np.float32).reshape(count, k_rest, 3)
    arrays = {"means": data.means, "log_scales": data.scales, "quats": data.quats,
              "opacity_logits": np.asarray(data.opacities).reshape(count), "sh": sh}
    for name, values in arrays.items():
        if not np.all(np.isfinite(values)):
            raise InputError(f"{path}: compressed PLY decodes to NaN/Inf {name} (corrupt chunk bounds)")
    return Gaussians.from_numpy({name: np.ascontiguousarray(values, np.float32) for name, values in arrays.items()})


def morton_order(means: np.ndarray) -> np.ndarray:
    """means: [N, 3] -> [N] int64 permutation along a Z-order curve over the means' bounding
    box (MORTON_BITS per axis), stable for ties."""
    means = np.asarray(means, np.float64)
    if len(means) == 0:
        return np.zeros(0, np.int64)
    low, high = means.min(axis=0), means.max(axis=0)
    # A flat axis (all splats at one coordinate) has no extent to divide by: its cells are all 0.
    span = np.where(high > low, high - low, 1.0)
    cells = np.clip(((means - low) / span * (1 << MORTON_BITS)).astype(np.int64), 0, (1 << MORTON_BITS) - 1)
    code = np.zeros(len(means), np.int64)
    for bit in range(MORTON_BITS):
        for axis in range(3):
            code |= ((cells[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(code, kind="stable")


def encode_compressed_ply(gaussians: Gaussians) -> tuple[bytes, np.ndarray]:
    """-> (the file's bytes, the [N] order the splats were written in: file row i is model
    splat order[i]). SH degree 1-3 go to the 'sh' element; values beyond the layout's ranges
    are clamped there (log scales to [-20, 20], SH rest to SH_REST_RANGE)."""
    import gsply

    arrays = gaussians.numpy()
    order = morton_order(arrays["means"])
    arrays = {name: np.ascontiguousarray(values[order]) for name, values in arrays.items()}
    sh = arrays["sh"]
    rest = sh[:, 1:] if sh.shape[1] > 1 else None
    data = gsply.compress_to_bytes(arrays["means"], arrays["log_scales"], arrays["quats"],
                                   arrays["opacity_logits"], np.ascontiguousarray(sh[:, 0]),
                                   None if rest is None else np.ascontiguousarray(rest))
    return data, order
