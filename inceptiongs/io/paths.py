"""Paths read from a scene or run file, kept inside the folder they belong to.

A scene or run folder from someone else names files by strings it chose: an image name in
images.txt, a transforms.json ``file_path``, a ``ply_file_path``. Such a name may be absolute,
climb out with ``..`` or reach a symlink that leads elsewhere; followed blindly, a shared
scene would read (and a run later copy into its outputs) any file the user can read.
:func:`contained_path` resolves the name and refuses it, in one line, unless it stays inside
its folder. The folder itself is taken as the user gave it (a folder that is a symlink is
theirs and is followed).
"""

from __future__ import annotations

import errno
import stat
import os
from pathlib import Path

from ..errors import InputError


def resolved(path: str | Path, source: str) -> Path:
    """``path`` with every symlink resolved (missing tails kept as written); InputError naming
    ``source`` for a symlink loop."""
    try:
        return Path(os.path.realpath(path, strict=False))
    except (OSError, RuntimeError):
        raise InputError(f"{source}: symlink loop at {path}") from None


def is_inside(path: Path, folder: Path) -> bool:
    """Whether the resolved ``path`` is ``folder`` or below it (both already resolved)."""
    return path == folder or folder in path.parents


def contained_path(folder: str | Path, name: str, source: str) -> Path:
    """``folder / name`` when ``name`` is relative and, with symlinks resolved, stays inside
    ``folder``; InputError '<source>: ...' otherwise. Returns the path as written (unresolved),
    so messages and names stay the ones the user knows."""
    folder = Path(folder)
    if not isinstance(name, str) or not name or "\x00" in name:
        raise InputError(f"{source}: file name {name!r} is empty or not a valid path")
    if os.path.isabs(name) or Path(name).drive:
        raise InputError(f"{source}: file name {name!r} is an absolute path; a scene or run may only name "
                         f"files inside {folder}")
    path = folder / name
    if not is_inside(resolved(path, source), resolved(folder, source)):
        raise InputError(f"{source}: file {name!r} leads outside {folder} (through '..' or a symlink); refused")
    return path


def link_problem(path: str | Path) -> str | None:
    """'symlink loop' / 'dangling symlink' when ``path`` is a symlink that leads nowhere, else None."""
    if not os.path.islink(path):
        return None
    try:
        os.stat(path)
    except OSError as exc:
        return "symlink loop" if exc.errno == errno.ELOOP else "dangling symlink (its target does not exist)"
    return None


def files_below(folder: str | Path, suffix: str) -> list[Path]:
    """Regular files named ``*suffix`` below ``folder`` (recursive), found without following
    symlinked folders; a file that is a symlink counts only when it resolves to a regular file
    inside ``folder`` (a dangling, looping or escaping link is skipped)."""
    folder = Path(folder)
    inside = resolved(folder, str(folder))
    found = []
    for parent, _, names in os.walk(folder, followlinks=False):
        for name in names:
            path = Path(parent) / name
            if not name.endswith(suffix) or link_problem(path) is not None:
                continue
            try:
                target = Path(os.path.realpath(path))
                if target.is_file() and is_inside(target, inside):
                    found.append(path)
            except (OSError, RuntimeError):
                continue
    return found


# The largest text or JSON file a scene or run holds that is read whole (a metrics log of a long
# run is a few MB): a larger one, such as a sparse file of a huge declared size, is refused.
MAX_TEXT_FILE_BYTES = 256 * 2**20


def read_small_text(path: str | Path, what: str, max_bytes: int = MAX_TEXT_FILE_BYTES) -> str:
    """The UTF-8 text of the regular file ``path``; InputError '<path>: <problem>' (``what`` names
    the kind of file) when it is missing, a symlink loop, not a regular file, larger than
    ``max_bytes`` or not text. FileNotFoundError passes through for callers with their own word."""
    path = Path(path)
    problem = link_problem(path)
    if problem is not None:
        raise InputError(f"{path}: {problem}")
    check_read_inside_named_folder(path)
    try:
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):
            raise InputError(f"{path}: not a regular file (a {what} must be one)")
        if info.st_size > max_bytes:
            raise InputError(f"{path}: {info.st_size} bytes is too large for a {what} "
                             f"(at most {max_bytes // 2**20} MiB)")
        return path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable {what} ({exc})") from None


def stays_inside(path: str | Path, folder: str | Path) -> bool:
    """Whether ``path`` (written below ``folder``) is still inside ``folder`` once every symlink
    on the way is resolved; a loop counts as outside."""
    try:
        return is_inside(Path(os.path.realpath(path, strict=False)), Path(os.path.realpath(folder, strict=False)))
    except (OSError, RuntimeError):
        return False


def check_inside(path: str | Path, folder: str | Path) -> None:
    """The read guard for a file of a run or scene: InputError '<path>: ...' when ``path``, below
    ``folder``, leads outside it through a symlink (a shared run or scene could otherwise make a
    command read, and copy into its results, any file on the disk)."""
    if not stays_inside(path, folder):
        raise InputError(f"{path}: a symlink that leads outside {folder}; files of a run or scene folder are "
                         f"read only from inside it")


def check_read_inside_named_folder(path: str | Path) -> None:
    """InputError when ``path`` lies below a folder the user named (a run, an output folder:
    :func:`inceptiongs.io.atomic.writing_under`) but resolves outside it, through a symlink
    planted there. Files the user names directly, and files outside those folders, pass."""
    from .atomic import named_roots

    target = os.path.abspath(path)
    for root in named_roots():
        if target == root or not target.startswith(root.rstrip(os.sep) + os.sep):
            continue
        if not is_inside(resolved(target, str(path)), resolved(root, root)):
            raise InputError(f"{path}: a symlink that leads outside {root}; files of a run or scene folder "
                             f"are read only from inside it")


def check_readable_file(path: Path, what: str) -> None:
    """InputError '<path>: ...' unless ``path`` is a regular file (through a working symlink)
    that may be read: no dangling symlink or loop, no escape from a named folder."""
    problem = link_problem(path)
    if problem is not None:
        raise InputError(f"{path}: {problem}")
    if not path.is_file():
        raise InputError(f"{path}: {what} file does not exist" if not path.exists() else f"{path}: not a file")
    check_read_inside_named_folder(path)


def check_outside_scene(out: str | Path, scene: str | Path | None, flag: str = "--out") -> None:
    """InputError when ``out`` (a file or folder a command is about to write) lies in the scene
    folder ``scene`` (None: no scene, nothing to check): a scene folder is the user's input and is
    never written, whichever command is asked to."""
    if scene is None or not Path(scene).is_dir():
        return
    root = resolved(scene, flag)
    target = resolved(Path(out).absolute(), flag)
    if target == root or is_inside(target, root):
        raise InputError(f"{out}: {flag} is inside the scene folder {scene}, which is input and never written; "
                         f"give {flag} outside it")
