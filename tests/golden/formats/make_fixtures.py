"""Regenerates the model-format fixtures beside this file (see README.md here).

    python3 tests/golden/formats/make_fixtures.py [PATH_TO_SPLAT_TRANSFORM]

source.ply is a small random model written by InceptionGS; the tool's files are made from it,
and the tool reads back the .splat, .spz and compressed PLY that InceptionGS writes from it.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from inceptiongs.gaussians import Gaussians
from inceptiongs.io.models import write_model

HERE = Path(__file__).resolve().parent
DEFAULT_TOOL = "/tmp/splat-transform/node_modules/.bin/splat-transform"
# Two chunks of a compressed PLY, the second partial; few enough to keep the files small.
COUNT = 300


def source_model(count: int = COUNT, seed: int = 55) -> Gaussians:
    """SH degree 3, every value inside all formats' ranges (nothing is clamped)."""
    rng = np.random.default_rng(seed)
    sh = np.concatenate([rng.uniform(-1.5, 1.5, (count, 1, 3)), rng.uniform(-0.6, 0.6, (count, 15, 3))], axis=1)
    return Gaussians.from_numpy({
        "means": rng.uniform(-2.0, 2.0, (count, 3)),
        "log_scales": rng.uniform(-5.0, -1.0, (count, 3)),
        "quats": rng.normal(size=(count, 4)),
        "opacity_logits": rng.uniform(-4.0, 4.0, count),
        "sh": sh,
    })


def main() -> None:
    tool = sys.argv[1] if len(sys.argv) > 1 else DEFAULT_TOOL
    write_model(HERE / "source.ply", source_model())
    for name in ("ours.splat", "ours.spz", "ours.compressed.ply"):
        write_model(HERE / name, source_model())

    def run(*args: str) -> None:
        subprocess.run([tool, "-q", "-w", *args], check=True)

    run(str(HERE / "source.ply"), str(HERE / "tool.compressed.ply"))
    run(str(HERE / "source.ply"), "--spz-version", "3", str(HERE / "tool_v3.spz"))
    run(str(HERE / "source.ply"), "--spz-version", "4", str(HERE / "tool_v4.spz"))
    for name in ("ours.splat", "ours.spz", "ours.compressed.ply"):
        run(str(HERE / name), str(HERE / f"tool_read_{name.replace('.', '_')}.ply"))


if __name__ == "__main__":
    main()
