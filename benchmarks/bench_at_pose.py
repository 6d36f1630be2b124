"""Does training on I* lift the views it is made at? Virtual views at flagged held-out poses.

    python benchmarks/bench_at_pose.py RUN OUT [--iterations 600 | --minutes M] [--seed 0]
        [--variants '{"NAME": {BOOTSTRAP SETTINGS}, ...}']

On the stage-I run RUN (read, never written; `--protocol unstructured`), every other held-out
scarce view (sorted by name) is flagged: their poses go to a flags file (no photo of a held-out
view is read to make I*; the bootstrap reads poses only, as from the viewer's flags). Each
variant is a bootstrap of ``--iterations`` steps with those flags (``"_jstar": true``: the split's
j* instead, as the default benchmark targets), ``follow_outlook`` false and, with flags, one pose
between each flag and its nearest training view (``k`` 1, ``l`` 1; the flag's own pose is a
virtual view: ``include_target``). The baseline is stage I continued on the photos for the same
number of steps. Prints, per run, the mean PSNR of the flagged views, of the other scarce views
and of the covered group, and each against the baseline.

By default steps, not time: the comparison asks what the supervision can teach at its own
poses, before the virtual steps' cost is charged. With ``--minutes M`` every run, the baseline
included, has M minutes instead (and no step limit): the same-time comparison.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
from inceptiongs.bootstrap.runner import baseline_run
from inceptiongs.bootstrap.summary_file import read_summary
from inceptiongs.io.flags import Flag, save_flags
from inceptiongs.runs.config import TrainConfig
from inceptiongs.scene.loader import load_scene

DEFAULT_VARIANTS = {"at flags": {}, "at flags, L1 branch only": {"tau": 0.0}, "j*": {"_jstar": True},
                    "j*, L1 branch only": {"_jstar": True, "tau": 0.0}}


def flagged_views(run: Path) -> tuple[list[str], list[str], dict]:
    """(flagged scarce view names, the other scarce names, camera by name) of ``run``'s split."""
    config = TrainConfig.load(run / "config.json")
    split = json.loads((run / "split.json").read_text())
    if not split.get("scarce_test"):
        raise SystemExit(f"{run}: its split holds no scarce held-out views (train with --protocol unstructured)")
    scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
    scarce = sorted(split["view_names"][i] for i in split["scarce_test"])
    return scarce[0::2], scarce[1::2], {camera.name: camera for camera in scene.cameras}


def scores(run: Path, flagged: list[str], others: list[str]) -> tuple[float, float, float]:
    """(flagged mean PSNR, other scarce mean PSNR, covered PSNR) of ``run`` by `inceptiongs eval`."""
    out = subprocess.run([sys.executable, "-m", "inceptiongs", "eval", str(run), "--json"], capture_output=True,
                         text=True, check=True).stdout
    data = json.loads(out)
    psnr = {view["name"]: view["psnr"] for view in data["views"]}
    return (float(np.mean([psnr[n] for n in flagged])), float(np.mean([psnr[n] for n in others])),
            float(data["groups"]["covered"]["psnr"]))


def steps_made(folder: Path) -> int:
    """Steps the bootstrap or baseline in ``folder`` made (its summary's first and last iteration;
    a stage-I config's ``iterations`` is its schedule's length, not its last step)."""
    summary = read_summary(folder) or {}
    return int(summary["iteration"]) - int(summary["start_iteration"])


def bootstrap(run: Path, out: Path, name: str, settings: dict, flags: Path, iterations: int, seed: int,
              minutes: float | None) -> Path:
    settings = dict(settings)
    jstar = settings.pop("_jstar", False)
    settings = {"follow_outlook": False, **({} if jstar else {"k": 1, "l": 1}), **settings}
    folder = out / name.replace(" ", "_").replace(",", "").replace("*", "star")
    config = folder.with_suffix(".json")
    config.write_text(json.dumps(settings))
    command = [sys.executable, "-m", "inceptiongs", "bootstrap", str(run), *([] if jstar else ["--targets", str(flags)]),
               "--iterations", str(iterations), "--seed", str(seed), "--config", str(config), "--out", str(folder),
               "--overwrite", *([] if minutes is None else ["--minutes", str(minutes)])]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stderr[-2000:]}")
    return folder


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run")
    parser.add_argument("out")
    parser.add_argument("--iterations", type=int, default=600)
    parser.add_argument("--minutes", type=float, default=None,
                        help="every run (the baseline too) has this many minutes and no step limit")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variants", type=json.loads, default=DEFAULT_VARIANTS,
                        help="a JSON object: variant name -> bootstrap settings (module doc)")
    args = parser.parse_args()
    run, out = Path(args.run), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    flagged, others, cameras = flagged_views(run)
    flags = out / "flags.json"
    save_flags(flags, [Flag(name, cameras[name], "") for name in flagged])
    iterations = args.iterations if args.minutes is None else 10**6
    print(f"{run}: {len(flagged)} flagged scarce poses, {len(others)} other scarce views; "
          + (f"{args.iterations} steps" if args.minutes is None else f"{args.minutes:g} minutes each"), flush=True)
    rows = {"stage I": scores(run, flagged, others)}
    steps = {}
    baseline_run(run, out / "baseline", args.minutes, iterations, seed=args.seed, progress=False, overwrite=True)
    rows["baseline"] = scores(out / "baseline", flagged, others)
    steps["baseline"] = steps_made(out / "baseline")
    for name, settings in args.variants.items():
        folder = bootstrap(run, out, name, settings, flags, iterations, args.seed, args.minutes)
        rows[name], steps[name] = scores(folder, flagged, others), steps_made(folder)
        print(f"{name}: done", flush=True)
    base = rows["baseline"]
    print(f"{'run':28s} {'steps':>6s} {'flagged':>8s} {'others':>8s} {'covered':>8s}   against the baseline")
    for name, row in rows.items():
        print(f"{name:28s} {steps.get(name, ''):>6} " + " ".join(f"{value:8.2f}" for value in row) + "   "
              + " / ".join(f"{value - ref:+.2f}" for value, ref in zip(row, base)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
