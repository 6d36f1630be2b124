"""`inceptiongs report RUN [RUN ...] --out FILE.png`: test PSNR against run time."""

from __future__ import annotations

HELP = "error against run time: PSNR vs seconds and iterations, table at 1/2/5/10/20 min"


def add_arguments(parser) -> None:
    parser.add_argument("runs", nargs="+", metavar="RUN", help="run folders (each with metrics.jsonl)")
    parser.add_argument("--out", metavar="FILE.png", help="write the figure here")


def run(args) -> int:
    from ..report import make_report

    print(make_report(args.runs, args.out))
    if args.out:
        print(f"figure: {args.out}")
    return 0
