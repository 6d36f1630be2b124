"""Model files of every format, by their names: the one place commands and the viewer open a
Gaussian model from and save one to.

| name ends with    | format                                   | read | write | SH rest kept |
| ----------------- | ---------------------------------------- | ---- | ----- | ------------ |
| ``.ply``          | 3DGS PLY, binary or ASCII; SuperSplat's   | yes  | binary| degree 0-3   |
|                   | compressed PLY recognised by its header  |      |       |              |
| ``.compressed.ply``| SuperSplat's compressed PLY              | yes  | yes   | degree 0-3   |
| ``.splat``        | the web viewers' 32-byte records         | yes  | yes   | none         |
| ``.spz``          | Niantic's SPZ                            | yes  | yes   | degree 0-3   |

What each keeps and loses is in the modules' docstrings (:mod:`.ply`, :mod:`.ply_compressed`,
:mod:`.splat`, :mod:`.spz`) and, measured, in docs/scene_io.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..gaussians import Gaussians
from .atomic import atomic_write_bytes

MODEL_SUFFIXES = (".ply", ".splat", ".spz")
COMPRESSED_PLY_SUFFIX = ".compressed.ply"
# Format names (what `inceptiongs convert` and the notes say); "ply-ascii" is read only.
PLY, COMPRESSED_PLY, SPLAT, SPZ = "ply", "compressed-ply", "splat", "spz"


@dataclass
class ModelRead:
    """A model read from a file: the Gaussians (float32, CPU) and one-line notes about it."""

    gaussians: Gaussians
    format: str
    notes: list[str] = field(default_factory=list)


@dataclass
class ModelWritten:
    """What writing a model did: its format, notes (what the format dropped or clamped) and
    ``order`` (file splat i is model splat order[i]) when the format reorders, else None."""

    format: str
    notes: list[str] = field(default_factory=list)
    order: np.ndarray | None = None


def is_model_file(path: str | Path) -> bool:
    """Whether ``path``'s name is that of a model file (by extension)."""
    return Path(path).suffix.lower() in MODEL_SUFFIXES


def write_format(path: str | Path) -> str:
    """The format a model written to ``path`` gets, from its name; InputError for another name."""
    name = Path(path).name.lower()
    if name.endswith(COMPRESSED_PLY_SUFFIX):
        return COMPRESSED_PLY
    suffix = Path(name).suffix
    formats = {".ply": PLY, ".splat": SPLAT, ".spz": SPZ}
    if suffix not in formats:
        raise InputError(f"{path}: not a model file name (use .ply, .compressed.ply, .splat or .spz)")
    return formats[suffix]


def open_model(path: str | Path) -> ModelRead:
    """Read the model at ``path`` (format from its extension; a .ply's variant from its header)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        from .ply import read_ply_with_format

        gaussians, format_name = read_ply_with_format(path)
        return ModelRead(gaussians, format_name)
    from .paths import check_readable_file

    check_readable_file(path, "model")
    if suffix == ".splat":
        from .splat import read_splat

        return ModelRead(read_splat(path), SPLAT)
    if suffix == ".spz":
        from .spz import read_spz

        gaussians, notes = read_spz(path)
        return ModelRead(gaussians, SPZ, notes)
    raise InputError(f"{path}: not a model file (expected .ply, .splat or .spz)")


def read_model(path: str | Path) -> Gaussians:
    """The Gaussians (float32, CPU) of the model file at ``path``, whatever its format."""
    return open_model(path).gaussians


def write_model(path: str | Path, gaussians: Gaussians) -> ModelWritten:
    """Write ``gaussians`` atomically in the format ``path``'s name says (:func:`write_format`).
    SH degrees the format cannot hold are dropped with a note, never silently."""
    format_name = write_format(path)
    notes: list[str] = []
    order = None
    if format_name == PLY:
        from .ply import write_ply

        write_ply(gaussians, path)
        return ModelWritten(PLY)
    if format_name == COMPRESSED_PLY:
        from .ply_compressed import LOG_SCALE_RANGE, SH_REST_RANGE, encode_compressed_ply
        from .quantise import clamped_note

        data, order = encode_compressed_ply(gaussians)
        arrays = gaussians.numpy()
        notes = [note for note in [clamped_note(arrays["sh"][:, 1:], *SH_REST_RANGE, "SH rest values"),
                                   clamped_note(arrays["log_scales"], *LOG_SCALE_RANGE, "log scales")] if note]
    elif format_name == SPLAT:
        from .splat import encode_splat

        data = encode_splat(gaussians)
        if gaussians.sh_degree > 0:
            notes.append(f"{path}: .splat holds no view-dependent colour: SH degree {gaussians.sh_degree} "
                         "written as degree 0")
    else:
        from .spz import encode_spz

        data, clamped = encode_spz(gaussians, path)
        notes = clamped
    atomic_write_bytes(path, data)
    return ModelWritten(format_name, [note if note.startswith(str(path)) else f"{path}: {note}" for note in notes],
                        order)
