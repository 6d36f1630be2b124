"""`inceptiongs eval RUN [--json]`: PSNR/SSIM on the run's held-out views, scarce vs covered."""

from __future__ import annotations

import json

HELP = "PSNR/SSIM on held-out views, scarce vs covered (LPIPS/FID only with local weights)"


def add_arguments(parser) -> None:
    parser.add_argument("run", help="run folder written by `inceptiongs train`")
    parser.add_argument("--json", action="store_true", help="print eval.json instead of a table")
    parser.add_argument("--lpips-weights", metavar="PATH",
                        help="TorchScript LPIPS network (pred, target in [-1, 1], [B,3,H,W] -> distance)")
    parser.add_argument("--fid-weights", metavar="PATH",
                        help="TorchScript feature extractor for FID ([B,3,H,W] in [0, 1] -> [B, D])")


def run(args) -> int:
    from ..evaluate import json_safe, evaluate_run, format_table

    summary = evaluate_run(args.run, lpips_weights=args.lpips_weights, fid_weights=args.fid_weights)
    if args.json:
        print(json.dumps(json_safe(summary), indent=1))
    else:
        print(format_table(summary))
        print(f"images and eval.json in {args.run.rstrip('/')}/eval/")
    return 0
