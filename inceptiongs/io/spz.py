"""Niantic's SPZ (``.spz``): read (versions 1-4) and write (version 3), through the gsply
library's codec, with the coordinate frame and the checks done here.

A version 1-3 file is one gzip stream; a version 4 file has an uncompressed 32-byte header, a
table of streams and one zstd stream per array. Both start with the same header fields::

    uint32 magic 0x5053474e ("NGSP")   uint32 version        uint32 number of splats N
    uint8  SH degree (0-3)             uint8  fractional bits uint8  flags  (uint8 reserved)

then arrays of N: positions as 24-bit signed fixed point (value * 2^fractional bits),
alpha = round(255 * sigmoid(logit)), colour byte = round(f_dc * 0.15 * 255 + 127.5) (f_dc in
[-3.33, 3.33]), scale byte = round((log scale + 10) * 16) (log scales in [-10, 5.94]),
rotation (versions 3-4: the unit quaternion's largest component's index in 2 bits and the
other three as 9-bit magnitude + sign over [0, 1/sqrt2]; versions 1-2: x, y, z bytes), and the
SH rest as bytes, coefficient = (byte - 128) / 128 (so [-1, 1) in steps of 1/128; this writer
uses all 8 bits, Niantic's own uses 5 for degree 1 and 4 above).

Frame: SPZ stores right-up-back axes (RUB, OpenGL and three.js), the 3DGS PLY and this project
right-down-front (RDF, OpenCV). As Niantic's library does when told a PLY's data is RDF, both
directions flip y and z: means (x, -y, -z), quaternions (w, x, -y, -z), and each SH rest
coefficient by the sign its basis function takes under (x, y, z) -> (x, -y, -z)
(:data:`SH_REST_SIGNS`). Flag 0x1 (trained with antialiasing: a 2D filter this renderer does
not apply) is reported as a note; other flag bits (extensions) are ignored with a note.

The writer picks the fractional bits from the model's largest coordinate so positions keep
about 23 significant bits (Niantic's writer always uses 12: 1/4096 units).
"""

from __future__ import annotations

import math
import struct
import tempfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..gaussians import Gaussians
from .limits import check_allocation
from .quantise import LOGIT_LIMIT, clamped_note, unit_quaternions

MAGIC = 0x5053474E
HEADER = struct.Struct("<IIIBBBB")
WRITE_VERSION = 3
FLAG_ANTIALIASED = 0x1
# Positions are 24-bit signed integers: magnitudes below 2^23 units of 2^-fractional bits.
POSITION_LIMIT = (1 << 23) - 1
FRACTIONAL_BITS_RANGE = (1, 24)
# Ranges the byte encodings cover (values beyond are clamped by the writer).
SH0_RANGE = (-127.5 / (0.15 * 255), 127.5 / (0.15 * 255))
LOG_SCALE_RANGE = (-10.0, 255 / 16 - 10.0)
SH_REST_RANGE = (-1.0, 127 / 128)
# Sign of each SH rest basis function (3DGS order, degrees 1-3) under (x, y, z) -> (x, -y, -z):
# degree 1 ~ (y, z, x); degree 2 ~ (xy, yz, 3z^2-1, xz, x^2-y^2);
# degree 3 ~ (y(3x^2-y^2), xyz, y(5z^2-1), z(5z^2-3), x(5z^2-1), z(x^2-y^2), x(x^2-3y^2)).
SH_REST_SIGNS = np.array([-1, -1, 1,
                          -1, 1, 1, -1, 1,
                          -1, 1, -1, -1, 1, -1, 1], np.float32)


@dataclass(frozen=True)
class SpzHeader:
    version: int
    count: int
    sh_degree: int
    fractional_bits: int
    flags: int


def flip_frame(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """RDF <-> RUB (its own inverse): arrays keyed like Gaussians.numpy() -> new arrays with
    y and z negated for means, quaternion (w, x, y, z) -> (w, x, -y, -z), SH rest signed."""
    flipped = dict(arrays)
    flipped["means"] = arrays["means"] * np.array([1, -1, -1], np.float32)
    flipped["quats"] = arrays["quats"] * np.array([1, 1, -1, -1], np.float32)
    k = arrays["sh"].shape[1]
    signs = np.concatenate([[1.0], SH_REST_SIGNS[:k - 1]]).astype(np.float32)
    flipped["sh"] = arrays["sh"] * signs[None, :, None]
    return flipped


def read_header(raw: bytes, path: Path) -> SpzHeader:
    """The header of an SPZ file's bytes (gzip'd or version 4), checked; InputError otherwise."""
    if raw[:2] == b"\x1f\x8b":
        try:
            head = zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(raw, HEADER.size)
        except zlib.error as exc:
            raise InputError(f"{path}: SPZ gzip stream is corrupt ({exc})") from None
    else:
        head = raw[:HEADER.size]
    if len(head) < HEADER.size:
        raise InputError(f"{path}: truncated SPZ: {len(head)} header bytes of {HEADER.size}")
    magic, version, count, sh_degree, fractional_bits, flags, _ = HEADER.unpack(head)
    if magic != MAGIC:
        raise InputError(f"{path}: not an SPZ file (no NGSP magic)")
    if not 1 <= version <= 4:
        raise InputError(f"{path}: SPZ version {version} is not supported (1-4)")
    if version == 4 and raw[:2] == b"\x1f\x8b":
        raise InputError(f"{path}: SPZ version 4 inside gzip is not a valid layout")
    if sh_degree > 3:
        raise InputError(f"{path}: SPZ SH degree {sh_degree} is not 0-3")
    low, high = FRACTIONAL_BITS_RANGE
    if not low <= fractional_bits <= high:
        raise InputError(f"{path}: SPZ fractional bits {fractional_bits} not in {low}-{high}")
    return SpzHeader(version, count, sh_degree, fractional_bits, flags)


def header_notes(header: SpzHeader, path: Path) -> list[str]:
    notes = []
    if header.flags & FLAG_ANTIALIASED:
        notes.append(f"{path}: trained with antialiasing (SPZ flag); InceptionGS renders it without that 2D filter")
    if header.flags & ~FLAG_ANTIALIASED:
        notes.append(f"{path}: SPZ flags 0x{header.flags:02x}: extensions are ignored")
    return notes


def _reason(exc: BaseException, path: Path) -> str:
    """gsply's message without the file name it appends (ours leads the line)."""
    text = (str(exc).splitlines() or [type(exc).__name__])[0]
    return text.replace(f": {path}", "").strip() or type(exc).__name__


def _decoder_errors() -> tuple[type[BaseException], ...]:
    errors: tuple[type[BaseException], ...] = (ValueError, EOFError, zlib.error, struct.error, IndexError)
    try:
        import zstandard
        errors += (zstandard.ZstdError,)
    except ImportError:
        pass
    return errors


def read_spz(path: str | Path) -> tuple[Gaussians, list[str]]:
    """An SPZ file -> (float32 CPU Gaussians in the PLY's RDF frame, notes)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    header = read_header(raw, path)
    rest = 3 * ((header.sh_degree + 1) ** 2 - 1)
    # Decoded bytes (at most 20 + rest per splat) and the float32 arrays, a few copies each.
    check_allocation(len(raw) + header.count * ((20 + rest) + 3 * 4 * (14 + rest)), str(path),
                     f"{header.count} declared splats")
    import gsply

    try:
        data = gsply.read_spz(path)
    except _decoder_errors() as exc:
        raise InputError(f"{path}: truncated or corrupt SPZ ({_reason(exc, path)})") from None
    count = header.count
    k_rest = rest // 3
    sh = np.empty((count, 1 + k_rest, 3), np.float32)
    sh[:, 0] = data.sh0
    if k_rest:
        sh[:, 1:] = np.asarray(data.shN, np.float32).reshape(count, k_rest, 3)
    arrays = {"means": np.asarray(data.means, np.float32), "log_scales": np.asarray(data.scales, np.float32),
              "quats": np.asarray(data.quats, np.float32),
              "opacity_logits": np.asarray(data.opacities, np.float32).reshape(count), "sh": sh}
    return Gaussians.from_numpy(flip_frame(arrays)), header_notes(header, path)


def fractional_bits_for(means: np.ndarray, target: str | Path = "SPZ") -> int:
    """The most fractional bits that keep every coordinate of ``means`` ([N, 3]) inside the
    24-bit range; InputError naming ``target`` when even one bit does not."""
    largest = float(np.max(np.abs(means))) if means.size else 0.0
    low, high = FRACTIONAL_BITS_RANGE
    if largest == 0.0:
        return high
    bits = min(high, math.floor(math.log2(POSITION_LIMIT / largest)))
    if bits < low:
        raise InputError(f"{target}: a coordinate of {largest:g} is beyond SPZ's 24-bit positions "
                         f"(at most {POSITION_LIMIT / 2 ** low:g})")
    return bits


def encode_spz(gaussians: Gaussians, target: str | Path = "SPZ") -> tuple[bytes, list[str]]:
    """-> (the bytes of a version-3 SPZ file of ``gaussians``, notes on clamped values);
    ``target`` names the file in errors."""
    import gsply

    arrays = flip_frame(gaussians.numpy())
    notes = [note for note in (
        clamped_note(arrays["sh"][:, 0], *SH0_RANGE, "SH0 (f_dc) values"),
        clamped_note(arrays["log_scales"], *LOG_SCALE_RANGE, "log scales"),
        clamped_note(arrays["sh"][:, 1:], *SH_REST_RANGE, "SH rest values"),
    ) if note]
    k = arrays["sh"].shape[1]
    data = gsply.GSData.from_arrays(
        means=arrays["means"], scales=arrays["log_scales"],
        quats=unit_quaternions(arrays["quats"]).astype(np.float32),
        # gsply's sigmoid would overflow exp() past this; the byte is 0 or 255 either way.
        opacities=np.clip(arrays["opacity_logits"], -LOGIT_LIMIT, LOGIT_LIMIT),
        sh0=np.ascontiguousarray(arrays["sh"][:, 0]),
        shN=np.ascontiguousarray(arrays["sh"][:, 1:]) if k > 1 else None, format="ply")
    # gsply writes SPZ only to a path: a private temporary folder, read back, so the file the
    # user named is written by the one atomic write path.
    with tempfile.TemporaryDirectory(prefix="inceptiongs-spz-") as folder:
        temporary = Path(folder) / "model.spz"
        gsply.write_spz(temporary, data, version=WRITE_VERSION,
                        fractional_bits=fractional_bits_for(arrays["means"], target))
        return temporary.read_bytes(), notes
