"""Bootstrap variants against stage I continued for the same minutes, per seed, on one stage-I run.

    python benchmarks/bench_same_time.py RUN OUT [--minutes 8] [--variants fixer,baseline] [--seeds 0,1]

RUN: a stage-I run folder (read, never written). Each variant is a time-budgeted bootstrap of RUN
(``--minutes``, no step cap) into OUT/<variant><seed>: "default" (the defaults), "fixer" (the
experimental scene-adaptive fixer as the fill, docs/bootstrap_options.md), "fixer_whole" and
"fixer_long" (the fixed render as all of I*, 300 and 1 200 fixer steps), "fixer_guided" (a fixer
that also sees the nearest photos' blend), "fixer_far" (the same with far photos' guides), and
"baseline" (stage I continued on the photos, `baseline_run`) for the same minutes; the fixer
variants leave no view out by the warps' agreement (their held-out check is the gate). An untimed two-step warm-up runs first, so
no run pays the process's one-off costs. Each finished run is scored by `evaluate_run` on every
held-out view; one JSON line per run (steps, virtual steps, wall seconds, scarce / covered PSNR)
and OUT/rows.json. Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_bootstrap as bench  # noqa: E402

VARIANTS = {"default": {}, "fixer": {"variants": {"fixer": {}}},
            "fixer_whole": {"variants": {"fixer": {"target": "whole"}}, "agreement_min_db": None},
            "fixer_long": {"variants": {"fixer": {"target": "whole", "steps": 1200}}, "agreement_min_db": None},
            "fixer_guided": {"variants": {"fixer": {"target": "guided", "steps": 600}}, "agreement_min_db": None},
            "fixer_far": {"variants": {"fixer": {"target": "guided", "steps": 600, "guide_sources": "far"}},
                          "agreement_min_db": None, "regenerate_every": 200},
            "baseline": None}


def run_one(stage1, targets, out_dir: Path, variant: str, seed: int, minutes: float) -> dict:
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.runner import baseline_run, run_bootstrap

    def log(line: str) -> None:
        print(f"  [{out_dir.name}] {line}", flush=True)

    if VARIANTS[variant] is None:
        result = baseline_run(stage1, out_dir, minutes, 10**6, seed=seed, progress=False, overwrite=True, log=log)
    else:
        config = BootstrapConfig(seed=seed, iterations=10**6, minutes=minutes, **VARIANTS[variant])
        result = run_bootstrap(stage1, out_dir, targets, config, progress=False, overwrite=True, log=log)
    scores = bench.scores(out_dir)
    return {"run": out_dir.name, "steps": result.iteration - result.start_iteration,
            "virtual": result.virtual_steps or 0, "wall_s": round(result.wall_s, 1),
            "scarce": round(scores["scarce_psnr"], 3), "covered": round(scores["covered_psnr"], 3),
            "load": round(os.getloadavg()[0], 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("out")
    parser.add_argument("--minutes", type=float, default=8.0)
    parser.add_argument("--variants", default="fixer,baseline",
                        help=f"comma-separated, run in this order per seed: {', '.join(VARIANTS)}")
    parser.add_argument("--seeds", default="0,1")
    args = parser.parse_args(argv)
    variants = args.variants.split(",")
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"unknown variant(s) {', '.join(unknown)}; choose from {', '.join(VARIANTS)}")
    from inceptiongs.bootstrap.runner import resolve_targets
    from inceptiongs.bootstrap.stage1 import load_stage1
    from inceptiongs.threads import use_torch_threads

    use_torch_threads()
    out = Path(args.out)
    stage1 = load_stage1(Path(args.run))
    targets = resolve_targets(stage1.scene, stage1.split, None, None, 1)
    bench.warm_up(stage1, out / "warm_up", int(args.seeds.split(",")[0]))
    rows = []
    for seed in (int(s) for s in args.seeds.split(",")):
        for variant in variants:
            rows.append(run_one(stage1, targets, out / f"{variant}{seed}", variant, seed, args.minutes))
            print(json.dumps(rows[-1]), flush=True)
    (out / "rows.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
