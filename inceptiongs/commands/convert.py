"""``inceptiongs convert IN OUT [--check]``: a model file to another format, by OUT's name.

Formats (:mod:`inceptiongs.io.models`): ``.ply`` (3DGS PLY; read binary or ASCII, and
SuperSplat's compressed PLY recognised by its header; written binary), ``.compressed.ply``
(SuperSplat's compressed PLY), ``.splat`` (the web viewers' 32-byte records: no SH rest) and
``.spz`` (Niantic's SPZ). What a format cannot hold is dropped or clamped with a note on
stderr. ``--check`` reads OUT back and prints how far it is from IN (positions relative to
the scene extent, colour in 8-bit levels, opacity, log scales, rotations, SH rest).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "convert a model between .ply, .compressed.ply, .splat and .spz (format by OUT's name)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="IN", help="model file: .ply (binary, ASCII or compressed), .splat or .spz")
    parser.add_argument("out", metavar="OUT", help="output file: .ply, .compressed.ply, .splat or .spz")
    parser.add_argument("--check", action="store_true",
                        help="read OUT back and print its error against IN (max and mean per quantity)")


def run(args: argparse.Namespace) -> int:
    import torch

    from ..io.model_error import format_error_lines, model_error
    from ..io.models import open_model, write_format, write_model

    out = Path(args.out)
    write_format(out)  # a wrong OUT name is refused before IN is read
    source = open_model(args.model)
    for note in source.notes:
        print(f"note: {note}", file=sys.stderr)
    written = write_model(out, source.gaussians)
    for note in written.notes:
        print(f"note: {note}", file=sys.stderr)
    g = source.gaussians
    print(f"{args.model} ({source.format}, {len(g)} splats, SH degree {g.sh_degree}) -> "
          f"{out} ({written.format}, {out.stat().st_size} bytes)")
    if args.check:
        back = open_model(out).gaussians
        reference = g if written.order is None else g.subset(torch.as_tensor(written.order))
        print(f"round trip of {out} against {args.model}:")
        print("\n".join(format_error_lines(model_error(reference, back))))
    return 0
