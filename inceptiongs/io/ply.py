"""3DGS PLY read/write: the standard layout of the reference implementation.

Vertex properties, in this order on write: x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1)
opacity scale_0..2 rot_0..3, all float32, binary little-endian. f_rest is channel-major:
f_rest[c * (K - 1) + k] is coefficient k + 1 of colour channel c. On read the SH degree comes
from the number of f_rest fields, other properties (normals, extras) are ignored, and the
float32 values are kept as they are so a read/write round trip is bit-exact.

Read also: ASCII PLY with the same properties (the body parsed by numpy's text reader), and SuperSplat's
compressed PLY, recognised by its header (a ``chunk`` element and ``packed_*`` vertex
properties; :mod:`.ply_compressed`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from .atomic import atomic_open
from ..constants import SH_MAX_DEGREE, sh_coeff_count
from ..errors import InputError
from .limits import check_allocation
from .paths import check_readable_file
from ..gaussians import Gaussians

# PLY scalar type names (both spellings of the spec) -> numpy type codes without byte order.
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_BYTE_ORDER = {"binary_little_endian": "<", "binary_big_endian": ">"}
# The "byte order" _parse_header reports for a text (ASCII) PLY.
ASCII = "ascii"
# Which PLY a file was (format names as `inceptiongs convert` reports them).
PLY_BINARY, PLY_ASCII, PLY_COMPRESSED = "ply", "ply-ascii", "compressed-ply"
# A header longer than this is not a 3DGS PLY (the largest standard one is ~1.5 KB).
_MAX_HEADER_BYTES = 1 << 20


def _parse_header(raw: bytes, path: Path) -> tuple[int, str, list[tuple[str, int, list[tuple[str, str]]]]]:
    """-> (header length in bytes, byte order ('<', '>' or ASCII), elements [(name, count, [(prop, type)])])."""
    if not raw.startswith(b"ply\n") and not raw.startswith(b"ply\r\n"):
        raise InputError(f"{path}: not a PLY file (missing 'ply' magic)")
    end = raw.find(b"end_header")
    if end < 0:
        raise InputError(f"{path}: PLY header has no end_header (truncated or corrupt)")
    newline = raw.find(b"\n", end)
    if newline < 0:
        raise InputError(f"{path}: PLY header is truncated after end_header")
    header_len = newline + 1
    try:
        lines = raw[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise InputError(f"{path}: PLY header is not ASCII text") from None
    byte_order = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) < 2:
                raise InputError(f"{path}: PLY format line is malformed: {line!r}")
            if words[1] != ASCII and words[1] not in _BYTE_ORDER:
                raise InputError(f"{path}: unknown PLY format {words[1]!r}")
            byte_order = ASCII if words[1] == ASCII else _BYTE_ORDER[words[1]]
        elif words[0] == "element":
            if len(words) != 3 or not re.fullmatch(r"\d+", words[2]):
                raise InputError(f"{path}: PLY element line is malformed: {line!r}")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise InputError(f"{path}: PLY property before any element: {line!r}")
            if len(words) >= 2 and words[1] == "list":
                raise InputError(f"{path}: PLY element {elements[-1][0]!r} has a list property, "
                                 "which a 3DGS PLY does not have")
            if len(words) != 3 or words[1] not in _PLY_TYPES:
                raise InputError(f"{path}: PLY property line is malformed: {line!r}")
            if any(name == words[2] for name, _ in elements[-1][2]):
                raise InputError(f"{path}: PLY property {words[2]!r} appears twice in element {elements[-1][0]!r}")
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise InputError(f"{path}: unexpected PLY header line {line!r}")
    if byte_order is None:
        raise InputError(f"{path}: PLY header has no format line")
    return header_len, byte_order, elements


def _sh_rest_count(names: set[str], path: Path) -> int:
    """Number of f_rest_* fields, checked to be 3 * ((d+1)^2 - 1) and contiguous from 0."""
    count = sum(1 for name in names if name.startswith("f_rest_"))
    allowed = [3 * (sh_coeff_count(d) - 1) for d in range(SH_MAX_DEGREE + 1)]
    if count not in allowed:
        raise InputError(f"{path}: {count} f_rest fields is not an SH degree 0-3 "
                         f"(expected one of {allowed})")
    missing = [f"f_rest_{i}" for i in range(count) if f"f_rest_{i}" not in names]
    if missing:
        raise InputError(f"{path}: f_rest fields are not numbered 0..{count - 1} (missing {missing[0]})")
    return count


def _read_header(path: Path, what: str):
    """The header of the PLY at ``path`` (no link out of the named folders, no loop) ->
    _parse_header's (header length, byte order, elements); InputError naming the file."""
    check_readable_file(path, what)
    try:
        with open(path, "rb") as handle:
            head = handle.read(_MAX_HEADER_BYTES)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    return _parse_header(head, path)


def read_ply(path: str | Path) -> Gaussians:
    """Read a 3DGS PLY (binary, ASCII or SuperSplat's compressed) into float32 CPU Gaussians.
    Raises InputError for anything malformed."""
    return read_ply_with_format(path)[0]


def read_ply_with_format(path: str | Path) -> tuple[Gaussians, str]:
    """-> (:func:`read_ply`'s Gaussians, which PLY it was: PLY_BINARY, PLY_ASCII or PLY_COMPRESSED)."""
    path = Path(path)
    header_len, byte_order, elements = _read_header(path, "PLY")
    from .ply_compressed import is_compressed_layout, read_compressed_ply

    if is_compressed_layout(elements):
        return read_compressed_ply(path, header_len, byte_order, elements), PLY_COMPRESSED
    return _read_standard_ply(path, header_len, byte_order, elements), \
        PLY_ASCII if byte_order == ASCII else PLY_BINARY


def _read_standard_ply(path: Path, header_len: int, byte_order: str, elements) -> Gaussians:
    """The standard 3DGS vertex layout, binary (either byte order) or ASCII."""
    offset = header_len
    rows_before = 0  # in an ASCII PLY every element row is one line
    vertex = None
    for name, count, props in elements:
        dtype = np.dtype([(prop, ("<" if byte_order == ASCII else byte_order) + code) for prop, code in props])
        if name == "vertex":
            vertex = (count, dtype, offset)
            break
        offset += count * dtype.itemsize  # fixed-size elements before the vertices are skipped
        rows_before += count
    if vertex is None:
        raise InputError(f"{path}: PLY has no 'vertex' element")
    count, dtype, offset = vertex
    names = set(dtype.names or ())
    required = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    missing = [name for name in required if name not in names]
    if missing:
        raise InputError(f"{path}: PLY vertex element lacks 3DGS field(s) {', '.join(missing)}")
    rest_count = _sh_rest_count(names, path)
    used = required + [f"f_rest_{i}" for i in range(rest_count)]

    file_size = path.stat().st_size
    needed = offset + count * dtype.itemsize
    if byte_order != ASCII and file_size < needed:
        raise InputError(f"{path}: truncated PLY: header declares {count} vertices "
                         f"({needed} bytes) but the file has {file_size} bytes")
    # The model holds [count, 14 + rest] float32 values, copied about three times on the way.
    check_allocation(3 * count * (14 + rest_count) * 4, str(path), f"{count} declared vertices")
    k_rest = rest_count // 3
    if byte_order == ASCII:
        matrix = _ascii_vertex_matrix(path, header_len, rows_before, count, [dtype.names.index(n) for n in used])
        column_of = {name: i for i, name in enumerate(used)}
    elif all(dtype.fields[name][0] == np.dtype("<f4") for name in dtype.names):
        # The usual case, every property a little-endian float32: the vertices are one
        # [N, F] float32 matrix, and each model array is a (mostly contiguous) column slice,
        # so the file is read once instead of once per field.
        # Mapped rather than read: the column slices below are the only copies made.
        matrix = (np.memmap(path, dtype="<f4", mode="r", offset=offset, shape=(count, len(dtype.names)))
                  if count else np.zeros((0, len(dtype.names)), np.float32))
        column_of = {name: i for i, name in enumerate(dtype.names)}
    else:
        data = np.fromfile(path, dtype=dtype, count=count, offset=offset)
        matrix = np.stack([data[name].astype(np.float32) for name in used], axis=1) if count else \
            np.zeros((0, len(used)), np.float32)
        column_of = {name: i for i, name in enumerate(used)}

    def take(field_names: list[str]) -> np.ndarray:
        """[N, len(field_names)] float32 columns, checked to be finite."""
        index = [column_of[name] for name in field_names]
        contiguous = index == list(range(index[0], index[0] + len(index))) if index else True
        block = matrix[:, index[0]:index[0] + len(index)] if contiguous and index else matrix[:, index]
        finite = np.isfinite(block)
        if not finite.all():
            rows, cols = np.nonzero(~finite)
            bad = int(cols[0])
            raise InputError(f"{path}: field {field_names[bad]} has {int((~finite[:, bad]).sum())} "
                             f"NaN/Inf value(s) (first at vertex {int(rows[0])})")
        return block

    sh = np.empty((count, 1 + k_rest, 3), np.float32)
    sh[:, 0, :] = take(["f_dc_0", "f_dc_1", "f_dc_2"])
    if k_rest:
        # f_rest is channel-major: [N, 3, k_rest] in the file -> [N, k_rest, 3] in the model.
        rest = take([f"f_rest_{i}" for i in range(rest_count)])
        sh[:, 1:, :] = rest.reshape(count, 3, k_rest).transpose(0, 2, 1)
    arrays = {
        "means": take(["x", "y", "z"]),
        "log_scales": take(["scale_0", "scale_1", "scale_2"]),
        "quats": take(["rot_0", "rot_1", "rot_2", "rot_3"]),
        "opacity_logits": take(["opacity"])[:, 0],
        "sh": sh,
    }
    # Copies make the arrays writable, contiguous and detached from the memory map; ``sh``
    # was assembled into fresh memory already.
    return Gaussians(**{name: torch.from_numpy(a if name == "sh" else np.array(a, np.float32, order="C"))
                        for name, a in arrays.items()})


def _ascii_vertex_matrix(path: Path, header_len: int, rows_before: int, count: int,
                         columns: list[int]) -> np.ndarray:
    """The vertex rows of an ASCII PLY -> [count, len(columns)] float32 matrix of the given
    property columns, parsed by numpy's text reader. The header is parsed already and list
    properties are refused there, so every element row is one line: the ``rows_before`` lines
    of earlier elements are skipped. A malformed or truncated body is an InputError naming the file."""
    if count == 0:
        return np.zeros((0, len(columns)), np.float32)
    try:
        with open(path, "rb") as handle:
            handle.seek(header_len)
            matrix = np.loadtxt(handle, dtype=np.float32, comments=None, skiprows=rows_before, max_rows=count,
                                usecols=columns, ndmin=2, encoding="ascii")
    except (ValueError, UnicodeDecodeError) as exc:
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise InputError(f"{path}: ASCII PLY body is malformed ({reason})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    if len(matrix) != count:
        raise InputError(f"{path}: truncated ASCII PLY: header declares {count} vertices, the file has {len(matrix)}")
    return matrix


def ply_field_names(sh_degree: int) -> list[str]:
    """The standard property names, in file order, for an SH degree 0..3."""
    rest = 3 * (sh_coeff_count(sh_degree) - 1)
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(rest)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def write_ply(gaussians: Gaussians, path: str | Path) -> None:
    """Write the standard 3DGS PLY (float32, binary little-endian) atomically.

    Normals are written as zeros (the model has none); values are converted to float32.
    """
    arrays = gaussians.numpy()
    n = len(gaussians)
    k = arrays["sh"].shape[1]
    names = ply_field_names(gaussians.sh_degree)
    rest = arrays["sh"][:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major
    # One [N, F] float32 matrix in file order, written in a single call.
    matrix = np.concatenate([arrays["means"], np.zeros((n, 3), np.float32), arrays["sh"][:, 0, :], rest,
                             arrays["opacity_logits"][:, None], arrays["log_scales"], arrays["quats"]],
                            axis=1).astype("<f4", copy=False)
    assert matrix.shape[1] == len(names)
    header = "".join(["ply\n", "format binary_little_endian 1.0\n", f"element vertex {n}\n",
                      *[f"property float {name}\n" for name in names], "end_header\n"])
    with atomic_open(path, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(np.ascontiguousarray(matrix).data)


def read_point_cloud_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """A coloured point cloud PLY (x y z [red green blue], binary): ([P, 3] float64,
    [P, 3] uint8 or None). Used for the sparse points of nerfstudio scenes."""
    path = Path(path)
    header_len, byte_order, elements = _read_header(path, "point cloud")
    if byte_order == ASCII:
        raise InputError(f"{path}: ASCII point cloud PLY is not supported; save it as binary_little_endian")
    offset = header_len
    for name, count, props in elements:
        dtype = np.dtype([(prop, byte_order + code) for prop, code in props])
        if name == "vertex":
            break
        offset += count * dtype.itemsize
    else:
        raise InputError(f"{path}: PLY has no 'vertex' element")
    if not {"x", "y", "z"} <= set(dtype.names or ()):
        raise InputError(f"{path}: point cloud PLY lacks x, y, z")
    if path.stat().st_size < offset + count * dtype.itemsize:
        raise InputError(f"{path}: truncated PLY: header declares {count} vertices")
    check_allocation(3 * count * (dtype.itemsize + 32), str(path), f"{count} declared points")
    data = np.fromfile(path, dtype=dtype, count=count, offset=offset)
    points = np.stack([data[axis].astype(np.float64) for axis in "xyz"], axis=1)
    if not np.all(np.isfinite(points)):
        raise InputError(f"{path}: point coordinates contain NaN or Inf")
    colors = None
    if {"red", "green", "blue"} <= set(dtype.names):
        colors = np.stack([data[c] for c in ("red", "green", "blue")], axis=1)
        if colors.dtype != np.uint8:  # float colours in [0, 1]
            colors = np.round(np.clip(colors.astype(np.float64), 0, 1) * 255)
        colors = colors.astype(np.uint8)
    return points, colors
