"""A repair that does not happen: its steps against the baseline's, and a run without its log.

    python benchmarks/bench_no_repair.py RUN OUT [--iterations 100] [--protocol before|after] [--seed 0]

On the stage-I run RUN (its outlook "nothing to repair" or "train longer"; copied, never written):

1. bench_bootstrap's comparison: the default bootstrap for ``--iterations`` steps, then the
   baseline (stage I continued on the photos) for the bootstrap's time; prints both step counts
   and the bootstrap's held-out PSNR minus the baseline's (d_scarce, d_covered).
   ``--protocol after`` is bench_bootstrap's (an untimed warm-up first, the baseline run until the
   bootstrap's last step ended, at the bootstrap's evaluation cadence); ``before`` times the
   baseline against the bootstrap's whole wall time, the first run in the process paying its
   one-off costs, and evaluates at the baseline's own cadence.
2. the same bootstrap of a copy of RUN without metrics.jsonl: its measured outlook, its scores
   against the bootstrap with the log, and whether the two models are the same bytes.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_bootstrap as bench  # noqa: E402


def steps_against_baseline(run: Path, out: Path, iterations: int, protocol: str, seed: int = 0) -> dict:
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.runner import baseline_run, resolve_targets, run_bootstrap
    from inceptiongs.bootstrap.stage1 import load_stage1

    stage1 = load_stage1(run)
    targets = resolve_targets(stage1.scene, stage1.split, None, None, 1)
    if protocol == "after":
        bench.warm_up(stage1, out / "warm_up", seed)
    config = BootstrapConfig(seed=seed, iterations=iterations, log_every=1, eval_every=max(iterations // 4, 1))
    boot = run_bootstrap(stage1, out / "bootstrap", targets, config, progress=False, overwrite=True,
                         log=lambda line: None)
    total_s = boot.wall_s if protocol == "before" else bench.last_step_wall(out / "bootstrap")
    cap = max(1, int(total_s / max(bench.real_step_seconds(out / "bootstrap"), 1e-3)))
    eval_every = max(cap // 4, 1) if protocol == "before" else config.eval_every
    base = baseline_run(stage1, out / "baseline", total_s / 60.0, cap, seed=seed, progress=False, eval_every=eval_every,
                        overwrite=True, log=lambda line: None)
    verdict = json.loads((out / "bootstrap" / "bootstrap" / "summary.json").read_text())["outlook"]["verdict"]
    boot_scores, base_scores = bench.scores(out / "bootstrap"), bench.scores(out / "baseline")
    return {"protocol": protocol, "outlook": verdict, "bootstrap_steps": boot.iteration - boot.start_iteration,
            "bootstrap_s": round(boot.wall_s, 1), "baseline_steps": base.iteration - base.start_iteration,
            "baseline_s": round(base.wall_s, 1),
            **{f"d_{group}": round(boot_scores[f"{group}_psnr"] - base_scores[f"{group}_psnr"], 3)
               for group in ("scarce", "covered")}}


def without_log(run: Path, out: Path, iterations: int, seed: int = 0) -> dict:
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.runner import resolve_targets, run_bootstrap
    from inceptiongs.bootstrap.stage1 import load_stage1

    copy = out / "run_without_log"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(run, copy)
    (copy / "metrics.jsonl").unlink(missing_ok=True)
    rows = {}
    for name, source in (("with_log", run), ("without_log", copy)):
        stage1 = load_stage1(source)
        targets = resolve_targets(stage1.scene, stage1.split, None, None, 1)
        result = run_bootstrap(stage1, out / name, targets, BootstrapConfig(seed=seed, iterations=iterations, log_every=1),
                               progress=False, overwrite=True, log=lambda line: None)
        summary = json.loads((result.out_dir / "bootstrap" / "summary.json").read_text())
        rows[name] = {"outlook": summary["outlook"]["verdict"], "probe_steps": probe_steps(summary, result.start_iteration),
                      "virtual_steps": result.virtual_steps, "scarce": round(result.last_eval["scarce_psnr"], 3),
                      "covered": round(result.last_eval["covered_psnr"], 3)}
    rows["same_model_bytes"] = (out / "with_log" / "model.ply").read_bytes() == \
        (out / "without_log" / "model.ply").read_bytes()
    return rows


def probe_steps(summary: dict, start_iteration: int) -> int | None:
    """The probe's photo steps from a bootstrap's summary (None: the outlook came from the log)."""
    until = (summary.get("probe") or {}).get("until_step")
    return None if until is None else until - start_iteration


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("out")
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--protocol", choices=("before", "after"), default="after")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    from inceptiongs.threads import use_torch_threads

    use_torch_threads()
    out = Path(args.out)
    print(json.dumps(steps_against_baseline(Path(args.run), out / "steps", args.iterations, args.protocol,
                                                   args.seed)), flush=True)
    print(json.dumps(without_log(Path(args.run), out / "log", args.iterations, args.seed)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
