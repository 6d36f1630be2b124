"""The one write path: atomic file writes, appends and output folders, with OS errors as one line.

Atomic writes go to a temporary file beside the target (``.NAME.XXXX.tmp``), are fsynced,
then renamed over it: a crash or an exception mid-write leaves the previous file untouched
and no partial file under the target's name. Every OS error on the way (read-only file
system, a path under a regular file, no space left, no permission) becomes an
:class:`OutputError` — an :class:`InputError`, so the CLI prints one line naming the path and
the problem and exits with status 2 — and what was saved before stays intact.

Writes never go through a symlink planted inside a folder the user named as a run or output
folder (:func:`writing_under`; the CLI names the folders of every command): a shared run whose
``eval`` is a symlink to another folder is refused with one line instead of written through.

Files are created with the permissions an ordinary ``open()`` would give (0666 minus the
umask, so 0644 under umask 022), not ``mkstemp``'s private 0600.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
import time
from pathlib import Path
from typing import IO, Iterator

from ..errors import InputError

TEMP_SUFFIX = ".tmp"
# Temporary files older than this are left by a killed writer, not being written by a live one
# (a checkpoint write takes well under a second; a minute leaves a wide margin).
STALE_TEMP_AGE_S = 60.0

_PROBLEMS = {
    errno.EROFS: "read-only file system",
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.ENOTDIR: "a parent of this path is a file, not a folder",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EISDIR: "is a folder, not a file",
    errno.ENAMETOOLONG: "file name too long",
    errno.ELOOP: "a symlink, not followed for writing",
}


class OutputError(InputError):
    """A file or folder could not be written: '<path>: cannot write (<problem>)'."""


# Below this many free bytes a write that failed without an error number (numpy's tofile says
# only "N requested and 0 written") failed for want of space.
FULL_DISK_BYTES = 2**20


def describe_os_error(exc: OSError, path: str | Path | None = None) -> str:
    """A short phrase for an OS error ("no space left on device", ...). An error without an
    errno (a short write reported by a library) is told by the free space of ``path``'s file
    system when that is (almost) none, else by its own message."""
    if exc.errno is None and path is not None:
        with contextlib.suppress(OSError):
            folder = Path(path).parent
            info = os.statvfs(folder if folder.is_dir() else ".")
            if info.f_bavail * info.f_frsize < FULL_DISK_BYTES:
                return _PROBLEMS[errno.ENOSPC]
    return _PROBLEMS.get(exc.errno, exc.strerror or (str(exc).splitlines() or [""])[0] or type(exc).__name__)


def output_error(path: str | Path, exc: OSError) -> OutputError:
    return OutputError(f"{path}: cannot write ({describe_os_error(exc, path)})")


def _umask() -> int:
    """The process umask. Linux reports it in /proc/self/status; elsewhere it can only be read
    by setting it, which is set straight back (a brief race with other threads' file creation)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# Folders (absolute, as the user named them) inside which no path component may be a symlink
# when writing. A plain list, not a context variable: writer threads started by a command see it.
_write_roots: list[str] = []


@contextlib.contextmanager
def writing_under(*roots: str | Path | None) -> Iterator[None]:
    """While inside, every write below one of ``roots`` refuses symlinks between the root and the
    written file (a symlink the user passes as the root itself is followed: it is theirs)."""
    added = [os.path.abspath(root) for root in roots if root]
    _write_roots.extend(added)
    try:
        yield
    finally:
        for root in added:
            _write_roots.remove(root)


def named_roots() -> list[str]:
    """The folders given to :func:`writing_under` now (absolute, as named)."""
    return list(_write_roots)


def check_no_symlink_below_root(path: str | Path) -> None:
    """OutputError when a component of ``path`` below a :func:`writing_under` root is a symlink."""
    target = os.path.abspath(path)
    for root in list(_write_roots):
        if target != root and not target.startswith(root.rstrip(os.sep) + os.sep):
            continue
        current = root
        for part in os.path.relpath(target, root).split(os.sep):
            if part in ("", "."):
                continue
            current = os.path.join(current, part)
            if os.path.islink(current):
                raise OutputError(f"{current}: cannot write (a symlink inside {root}; InceptionGS never writes "
                                  f"through a symlink in a run or output folder)")


def ensure_dir(path: str | Path) -> Path:
    """mkdir -p ``path`` or OutputError naming the folder and the problem."""
    path = Path(path)
    check_no_symlink_below_root(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(f"{path}: cannot create folder (a file of that name exists)") from None
    except OSError as exc:
        raise output_error(path, exc) from None
    return path


def check_writable_dir(path: str | Path) -> Path:
    """Create ``path`` if needed and prove it writable by writing and removing a probe file,
    before hours of work start. OutputError (one line) otherwise."""
    path = ensure_dir(path)
    try:
        fd, probe = tempfile.mkstemp(prefix=".write-probe.", suffix=TEMP_SUFFIX, dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise output_error(path, exc) from None
    return path


def remove_stale_temp_files(folder: str | Path, max_age_s: float = STALE_TEMP_AGE_S) -> list[Path]:
    """Delete ``.*.tmp`` files (left by writers killed mid-write) in ``folder`` and its
    sub-folders that are older than ``max_age_s``; returns the removed paths."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    now = time.time()
    for path in folder.rglob(f".*{TEMP_SUFFIX}"):
        with contextlib.suppress(OSError):  # a file that vanished or cannot go is left alone
            if path.is_file() and now - path.stat().st_mtime >= max_age_s:
                path.unlink()
                removed.append(path)
    return removed


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file for writing that replaces ``path`` only on clean exit."""
    if mode not in ("w", "wb"):
        raise ValueError("atomic_open only supports 'w' and 'wb'")
    path = Path(path)
    ensure_dir(path.parent)
    check_no_symlink_below_root(path)
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    except OSError as exc:
        raise output_error(path, exc) from None
    try:
        try:
            with os.fdopen(fd, mode) as handle:
                os.fchmod(handle.fileno(), 0o666 & ~_umask())
                yield handle
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp_name, path)
        except OSError as exc:
            raise output_error(path, exc) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_open(path, "wb") as handle:
        handle.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def append_line(path: str | Path, line: str) -> None:
    """Append one line (flushed) to a log file; OutputError on failure. A kill mid-append
    leaves at most one torn last line, which the readers drop."""
    path = Path(path)
    ensure_dir(path.parent)
    check_no_symlink_below_root(path)
    try:
        # O_NOFOLLOW: a log that is a symlink is refused (ELOOP), never appended through.
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o666)
        with os.fdopen(fd, "a", encoding="utf-8") as handle:
            handle.write(line.rstrip("\n") + "\n")
            handle.flush()
    except OSError as exc:
        raise output_error(path, exc) from None
