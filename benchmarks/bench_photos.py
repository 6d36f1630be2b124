"""Photos out of core: stage I's start and peak memory on the town with a photo budget, and
bonsai's step rate with the budget below its photos' size against all of them in memory.
Prints figures; asserts nothing.

    python benchmarks/bench_photos.py [--town /tmp/town3000] [--town-steps 50] [--town-budget 1G]
        [--bonsai ../shared/data/bonsai] [--bonsai-steps 300] [--downscale 4] [--out /tmp/bench_photos]
        [--skip-town] [--skip-bonsai]

Each run is its own `inceptiongs train` process (peak RSS: its ru_maxrss) with a cache folder of
its own in OUT, so the town's start includes decoding its photos into the photo cache once.
Targets: the town at 3,000 views of 640x480 starts within a minute with a peak RSS <= 3 GB at a
1 GB budget; bonsai's step rate with the budget below its size within 10 % of the in-memory rate.
A missing town is written first (`inceptiongs demo-scene TOWN --scene town --views 3000`).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# One `inceptiongs` command in a process that reports its own peak RSS on its last line.
_WRAPPER = ("import resource, sys\nfrom inceptiongs.cli import main\nrc = main(sys.argv[1:])\n"
            "print('PEAK_RSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
            "sys.exit(rc)\n")
# Training steps logged every 10 steps, no held-out evaluation during the short runs.
_QUIET = {"output": {"log_every": 10, "eval_every": 1000000, "checkpoint_every": 1000000}}


def run_train(scene: Path, out: Path, steps: int, budget: str, extra: list[str]) -> dict:
    """One short stage I -> {start_s, steps_per_s, peak_rss_gb, wall_s}. start_s: the process's
    wall time less its training time (process start, scene load, photo preparation, initial
    Gaussians, and the final model write: an upper bound of the time to the first step)."""
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    config = out / "quiet.json"
    config.write_text(json.dumps(_QUIET))
    argv = ["--cache-dir", str(out / "cache"), "train", str(scene), "--out", str(out / "run"),
            "--iterations", str(steps), "--photo-memory", budget, "--config", str(config), *extra]
    started = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _WRAPPER, *argv], capture_output=True, text=True)
    wall = time.perf_counter() - started
    if proc.returncode != 0:
        raise SystemExit(f"train failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    peak_kb = int(next(line.split()[1] for line in proc.stderr.splitlines() if line.startswith("PEAK_RSS_KB")))
    records = [json.loads(line) for line in (out / "run" / "metrics.jsonl").read_text().splitlines()]
    steps_logged = [r for r in records if "l1" in r]
    first, last = steps_logged[0], steps_logged[-1]
    # Rate over the logged steps after the first log (the first epoch's loading included).
    rate = (last["iteration"] - first["iteration"]) / max(last["train_s"] - first["train_s"], 1e-9)
    return {"start_s": wall - last["train_s"], "steps_per_s": rate,
            "peak_rss_gb": peak_kb / 2**20, "wall_s": wall}


def _data_dir() -> Path:
    """$INCEPTIONGS_DATA, else the first shared/data beside the repository or above it."""
    if os.environ.get("INCEPTIONGS_DATA"):
        return Path(os.environ["INCEPTIONGS_DATA"])
    for parent in REPO.parents:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return REPO.parent / "shared" / "data"


def photo_gb(scene: Path, downscale: int) -> tuple[int, float]:
    """(photos, GB of all of them as float32 at the training resolution)."""
    from inceptiongs.scene.loader import load_scene
    loaded = load_scene(str(scene), downscale=downscale)
    return len(loaded.cameras), sum(c.width * c.height * 12 for c in loaded.cameras) / 2**30


def machine() -> str:
    cpu = platform.processor() or "CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores {cpu}, load average {os.getloadavg()[0]:.1f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--town", default="/tmp/town3000")
    parser.add_argument("--town-steps", type=int, default=50)
    parser.add_argument("--town-budget", default="1G")
    parser.add_argument("--bonsai", default=str(_data_dir() / "bonsai"))
    parser.add_argument("--bonsai-steps", type=int, default=300)
    parser.add_argument("--downscale", type=int, default=4)
    parser.add_argument("--out", default="/tmp/bench_photos")
    parser.add_argument("--skip-town", action="store_true")
    parser.add_argument("--skip-bonsai", action="store_true")
    args = parser.parse_args()
    out = Path(args.out)
    print(f"machine: {machine()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    if not args.skip_town:
        town = Path(args.town)
        if not town.is_dir():
            subprocess.run([sys.executable, "-m", "inceptiongs", "demo-scene", str(town), "--scene", "town",
                            "--views", "3000"], check=True)
        count, size = photo_gb(town, 1)
        result = run_train(town, out / "town", args.town_steps, args.town_budget, [])
        print(f"town: {count} photos, {size:.1f} GB as float32; {args.town_steps} steps at --photo-memory "
              f"{args.town_budget}: start {result['start_s']:.1f} s (cold photo cache), peak RSS "
              f"{result['peak_rss_gb']:.2f} GB, {result['steps_per_s']:.2f} steps/s, whole run {result['wall_s']:.0f} s")
    if not args.skip_bonsai:
        bonsai = Path(args.bonsai)
        count, size = photo_gb(bonsai, args.downscale)
        below = f"{int(size * 2**30 / 4)}"       # a quarter of the photos
        above = f"{int(size * 2**30 * 2)}"       # all of them, with room
        flags = ["--downscale", str(args.downscale)]
        for name, budget in (("in memory", above), ("budget 1/4", below)):
            result = run_train(bonsai, out / f"bonsai_{name.replace(' ', '_').replace('/', '_')}",
                               args.bonsai_steps, budget, flags)
            print(f"bonsai {name}: {count} photos, {size:.2f} GB as float32, --photo-memory {budget}: "
                  f"{result['steps_per_s']:.3f} steps/s, peak RSS {result['peak_rss_gb']:.2f} GB, "
                  f"start {result['start_s']:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
