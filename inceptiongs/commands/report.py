"""`inceptiongs report RUN [RUN ...] --out FILE.png [--prior]`: test PSNR against run time, and the
prior's generated-image quality against prior training time and DDIM steps."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

HELP = "error against run time: PSNR vs seconds and iterations, table at 1/2/5/10/20 min; prior quality"


def add_arguments(parser) -> None:
    parser.add_argument("runs", nargs="+", metavar="RUN", help="run folders (each with metrics.jsonl)")
    parser.add_argument("--out", metavar="FILE.png",
                        help="write the figure here (and the prior's to FILE_prior.png)")
    parser.add_argument("--prior", action="store_true",
                        help="only the prior report: generated quality against prior training time "
                             "(RUN/prior/metrics.jsonl) and DDIM steps (RUN/eval/generated.json); "
                             "without it, added automatically where a run has them")


def run(args) -> int:
    from ..evaluation.report import make_report
    from ..evaluation.report_prior import has_prior_report, plot_prior_report, prior_figure_path, prior_table

    for run_dir in args.runs:
        if not Path(run_dir).is_dir():
            raise InputError(f"{run_dir}: run folder does not exist")
    if args.out and Path(args.out).suffix.lower() != ".png":
        raise InputError(f"{args.out}: the report figure must be a .png file")
    if not args.prior:
        from ..evaluation.verdict import report_verdicts

        print(make_report(args.runs, args.out))
        if args.out:
            print(f"figure: {args.out}")
        # A bootstrap is compared only with its same-time baseline (or the line says there is none).
        verdicts = report_verdicts(args.runs)
        if verdicts:
            print("repair verdicts (each bootstrap's own evaluations against its same-time baseline):")
            print("\n".join(f"  {line}" for line in verdicts))
    with_prior = [r for r in args.runs if has_prior_report(r)]
    if args.prior and not with_prior:
        raise InputError(f"{', '.join(args.runs)}: no prior evaluations (RUN/prior/metrics.jsonl evaluation "
                         "records or RUN/eval/generated.json)")
    for run_dir in with_prior:
        print(prior_table(run_dir))
    if with_prior and args.out:
        figure = Path(args.out) if args.prior else prior_figure_path(args.out)
        plot_prior_report(with_prior, figure)
        print(f"prior figure: {figure}")
    return 0
