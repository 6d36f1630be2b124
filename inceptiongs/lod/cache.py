"""Built hierarchies kept in the cache directory, keyed by the model's content.

The key is a sha256 of the model (its PLY's bytes, or its tensors' bytes and shapes) together
with the build parameters and :data:`FORMAT_VERSION`, so a changed model, another branching
or a new layout never reuses a stale file. Files go to ``cache_root()/lod/KEY.npz``, written
atomically, never beside the user's input. A cache file that cannot be read back as a
well-formed hierarchy is ignored and rebuilt.
"""

from __future__ import annotations

import hashlib
import zipfile
from dataclasses import fields
from pathlib import Path
from typing import Callable

import numpy as np

from ..gaussians import Gaussians
from ..io.atomic import OutputError, atomic_open
from ..io.cache import cache_root
from .hierarchy import DEFAULT_BRANCHING, GAUSSIAN_FIELDS, LodHierarchy, build_hierarchy

# Bumped whenever the stored layout or the merge rule changes: old files then miss.
FORMAT_VERSION = 1
_READ_CHUNK = 1 << 22


def _finish_key(digest, branching: int) -> str:
    digest.update(f"|lod-v{FORMAT_VERSION}|branching={int(branching)}".encode())
    return digest.hexdigest()


def model_key(gaussians: Gaussians, branching: int = DEFAULT_BRANCHING) -> str:
    """sha256 of the model's tensors (float32 bytes and shapes) and the build parameters."""
    digest = hashlib.sha256()
    for name, array in gaussians.numpy().items():
        digest.update(f"{name}{array.shape}".encode())
        digest.update(np.ascontiguousarray(array).tobytes())
    return _finish_key(digest, branching)


def ply_key(path: str | Path, branching: int = DEFAULT_BRANCHING) -> str:
    """sha256 of a PLY file's bytes (read in chunks) and the build parameters."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(_READ_CHUNK), b""):
            digest.update(chunk)
    return _finish_key(digest, branching)


def hierarchy_cache_path(key: str) -> Path:
    return cache_root() / "lod" / f"{key}.npz"


def save_hierarchy(hierarchy: LodHierarchy, path: str | Path) -> None:
    """Write atomically: a crash leaves the previous file or none, never half of one."""
    with atomic_open(path, "wb") as handle:
        np.savez(handle, **hierarchy.arrays())


def _well_formed(h: LodHierarchy) -> bool:
    """Shapes agree, levels tile the nodes and every link points inside the arrays."""
    m = len(h.means)
    same_length = all(len(getattr(h, name)) == m for name in
                      GAUSSIAN_FIELDS + ("parent", "child_start", "child_count", "radii"))
    offsets = h.level_offsets
    tiled = (offsets.ndim == 1 and len(offsets) >= 1 and offsets[0] == 0 and offsets[-1] == m
             and bool(np.all(np.diff(offsets) >= 0)))
    linked = m == 0 or (h.parent.max() < m and h.parent.min() >= -1 and h.child_start.min() >= 0
                        and int((h.child_start.astype(np.int64) + h.child_count).max()) <= m)
    return same_length and tiled and linked and h.branching >= 2


def load_hierarchy(path: str | Path) -> LodHierarchy | None:
    """The hierarchy stored at ``path``, or None when it is missing or not a well-formed one."""
    try:
        with np.load(path, allow_pickle=False) as data:
            values = {f.name: data[f.name] for f in fields(LodHierarchy)}
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None
    values["branching"] = int(values["branching"])
    hierarchy = LodHierarchy(**values)
    return hierarchy if _well_formed(hierarchy) else None


def load_or_build(gaussians: Gaussians, key: str | None = None, branching: int = DEFAULT_BRANCHING,
                  progress: Callable[[float], None] | None = None) -> tuple[LodHierarchy, bool]:
    """-> (the hierarchy of ``gaussians``, whether it came from the cache). ``key``: the
    content key of exactly these tensors when the caller has one (:func:`ply_key` of the file
    they were read from, unchanged: not after moving them into another frame), else the
    tensors' hash. A cache that cannot be written costs the next load a rebuild, nothing more."""
    key = model_key(gaussians, branching) if key is None else key
    path = hierarchy_cache_path(key)
    cached = load_hierarchy(path) if path.is_file() else None
    if cached is not None and cached.leaf_count == len(gaussians):
        return cached, True
    hierarchy = build_hierarchy(gaussians, branching, progress)
    try:
        save_hierarchy(hierarchy, path)
    except OutputError:
        pass   # the hierarchy in hand is complete; only the next load is slower
    return hierarchy, False
