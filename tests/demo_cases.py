"""The demo scene for tests that need a real-looking capture but do not test how it is written.

Writing the demo scene renders its 47 photos (about 2 s alone, 5 s on a loaded two-core
machine); some 20 modules need one. Each distinct (size, seed) is written once per pytest
process into a private folder and copied to where a test wants it, so every test still gets a
folder of its own (a scene is input: no test may change another's). tests/scene/test_scene_demo.py
tests write_demo_scene itself and calls it directly.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

from inceptiongs.scene.demo import write_demo_scene

_written: dict[tuple[str, int], Path] = {}
_root: Path | None = None


def copy_of_demo_scene(out_dir: str | Path, size: str = "small", seed: int = 0) -> Path:
    """A copy of ``write_demo_scene(out_dir, size=size, seed=seed)``'s folder at ``out_dir``
    (which must not exist yet); returns ``out_dir``."""
    global _root
    key = (size, seed)
    if key not in _written:
        if _root is None:
            _root = Path(tempfile.mkdtemp(prefix="inceptiongs-test-demo-"))
            atexit.register(shutil.rmtree, _root, True)
        _written[key] = write_demo_scene(_root / f"{size}_{seed}", size=size, seed=seed, progress=False)
    out_dir = Path(out_dir)
    shutil.copytree(_written[key], out_dir)
    return out_dir
