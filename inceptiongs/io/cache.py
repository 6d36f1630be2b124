"""Where caches and work files live: never in the user's scene folder.

The cache root is, first found: the ``--cache-dir`` flag (:func:`set_cache_dir`), the
``INCEPTIONGS_CACHE_DIR`` environment variable, ``$XDG_CACHE_HOME/inceptiongs``, then
``~/.cache/inceptiongs``. A scene's cache folder below it is keyed by the scene's resolved
path and by the content of its description files (COLMAP model, transforms.json,
poses_bounds.npy), so a moved or re-calibrated scene never reuses stale caches.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

CACHE_ENV = "INCEPTIONGS_CACHE_DIR"
# Description files up to this size are hashed byte for byte; larger ones (a huge points3D.bin)
# by size and modification time, so keying a scene never reads hundreds of megabytes.
_HASH_BYTES_MAX = 16 * 2**20

_override: Path | None = None


def set_cache_dir(path: str | Path | None) -> None:
    """Use ``path`` as the cache root for this process (None: back to the environment)."""
    global _override
    _override = None if path is None else Path(path).expanduser()


def cache_root() -> Path:
    """The cache root (not created here)."""
    if _override is not None:
        return _override
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "inceptiongs"


def content_digest(files: list[Path]) -> str:
    """A short hash of ``files``' names and contents (big files: size and mtime). Files that
    cannot be read contribute their name only (the reader reports them)."""
    digest = hashlib.sha1()
    for path in sorted(files):
        digest.update(path.name.encode())
        try:
            stat = path.stat()
            if stat.st_size <= _HASH_BYTES_MAX:
                digest.update(path.read_bytes())
            else:
                digest.update(f"{stat.st_size}:{stat.st_mtime_ns}".encode())
        except OSError:
            continue
    return digest.hexdigest()[:10]


def scene_cache_dir(root: str | Path, description_files: list[Path]) -> Path:
    """cache_root()/scenes/NAME-PATHHASH-CONTENTHASH for the scene at ``root`` (not created)."""
    root = Path(root).resolve()
    path_key = hashlib.sha1(str(root).encode()).hexdigest()[:10]
    return cache_root() / "scenes" / f"{root.name}-{path_key}-{content_digest(description_files)}"
