#!/usr/bin/env python3
"""Regenerates the viewer's golden images in tests/golden/ (the tests only compare, never write).

Run after an intended change of what the viewer draws, then LOOK at the new images before
committing them:

    DISPLAY=:99 python3 scripts/regen_viewer_golden.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from viewer_cases import GOLDEN, golden_photo_images, golden_window_images, write_grid_model  # noqa: E402

from inceptiongs.camera import write_camera_json  # noqa: E402
from inceptiongs.io.images import write_png  # noqa: E402
from viewer_cases import front_camera  # noqa: E402


def main() -> int:
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        os.environ["INCEPTIONGS_CACHE_DIR"] = str(folder / "cache")  # the scene's work folder: thrown away
        model = write_grid_model(folder / "model.ply")
        camera = folder / "cam.json"
        write_camera_json(front_camera(), camera)
        shot = GOLDEN / "viewer_grid_160x120.png"
        subprocess.run([sys.executable, "-m", "inceptiongs.app.main", str(model), "--screenshot", str(shot),
                        "--camera", str(camera), "--size", "160x120"], check=True)
        print(f"wrote {shot}")
        from inceptiongs.scene.demo import write_demo_scene

        scene = write_demo_scene(folder / "demo", progress=False)
        for name, image in {**golden_window_images(model), **golden_photo_images(scene)}.items():
            write_png(GOLDEN / name, image)
            print(f"wrote {GOLDEN / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
