"""Model formats on real models: each format's round-trip error (max and mean), file size and
read/write time. Prints a Markdown table (the one in docs/scene_io.md); asserts nothing.

    python benchmarks/bench_formats.py MODEL [MODEL ...]

MODEL: any model file (.ply, .compressed.ply, .splat, .spz), e.g. ../shared/data/splats/donut.ply
or a trained run's model.ply. Errors as inceptiongs.io.model_error defines them: positions
relative to the scene extent, colour in 8-bit levels of the displayable [0, 1], opacity in
[0, 1], log scales, rotation angle in degrees, SH rest coefficients.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
import torch

from inceptiongs.io.model_error import model_error
from inceptiongs.io.models import read_model, write_model

SUFFIXES = ("ply", "compressed.ply", "splat", "spz")


def _timed(fn):
    start = time.perf_counter()
    value = fn()
    return value, time.perf_counter() - start


def _figure(pair: tuple[float, float], digits: str = ".2g") -> str:
    return f"{pair[0]:{digits}} / {pair[1]:{digits}}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="model files")
    args = parser.parse_args()
    print(f"machine: {platform.machine()}, {platform.processor() or 'cpu'}, torch threads {torch.get_num_threads()}")
    print("| model | format | size | write / read ms | positions max / mean (of extent) | colour max / mean "
          "(levels) | opacity max / mean | log scale max / mean | rotation max / mean (deg) | SH rest max / mean |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as folder:
        for model_path in map(Path, args.models):
            source = read_model(model_path)
            label = f"{model_path.name} ({len(source):,}, SH {source.sh_degree})"
            for suffix in SUFFIXES:
                path = Path(folder) / f"model.{suffix}"
                # The first write and read compile gsply's kernels (numba, cached on disk): not timed.
                write_model(path, source)
                read_model(path)
                written, write_s = _timed(lambda: write_model(path, source))
                back, read_s = _timed(lambda: read_model(path))
                reference = source if written.order is None else source.subset(torch.as_tensor(written.order))
                error = model_error(reference, back)
                print(f"| {label} | {suffix} | {path.stat().st_size / 1e6:.2f} MB | {write_s * 1e3:.0f} / {read_s * 1e3:.0f} | "
                      f"{_figure(error['position'])} | {_figure(error['colour'], '.2f')} | "
                      f"{_figure(error['opacity'])} | {_figure(error['log_scale'])} | "
                      f"{_figure(error['rotation'])} | {_figure(error['sh_rest'])} |")


if __name__ == "__main__":
    main()
