#!/usr/bin/env bash
# The bootstrap against the same-time baseline on bonsai at full resolution (800x533) on a CUDA
# machine: stage I (3DGS-MCMC, no planar terms, unstructured split, seed 0) with --device cuda for
# STAGE1_MIN minutes; then from it, each for BOOT_MIN minutes of wall clock, the default bootstrap
# of j* (which follows the outlook), the bootstrap that does not (follow_outlook false), and stage I
# continued on the photos alone. Figures: docs/results.md ("At full resolution on a GPU").
#
#     bash benchmarks/gpu_bootstrap.sh [OUT] [all|stage1|compare]   (default: runs/gpu_bootstrap all)
#
# "stage1" trains (and first builds gsplat's kernels), "compare" runs the three continuations of
# the stage I already in OUT/s1; "all" does both. Needs gsplat (pip install 'inceptiongs[cuda]'),
# nvcc for its build and bonsai (../shared/data or $INCEPTIONGS_DATA; $GPU_CHECK_BONSAI names
# another copy). DEVICE=cpu DOWNSCALE=8 runs the same steps on a CPU (a dry run of this script).
# OUT gets the runs, gpu_check.log (every step's output) and figures.json.
set -u
out=${1:-runs/gpu_bootstrap}
phase=${2:-all}
mkdir -p "$out"
out=$(cd "$out" && pwd)
data=${INCEPTIONGS_DATA:-../shared/data}
bonsai=${GPU_CHECK_BONSAI:-$data/bonsai}
stage1_min=${STAGE1_MIN:-1.5}
boot_min=${BOOT_MIN:-1.25}
device=${DEVICE:-cuda}
downscale=${DOWNSCALE:-1}
export PYTHONUNBUFFERED=1
export MAX_JOBS=${MAX_JOBS:-$(nproc)}
work=$out
export INCEPTIONGS_CACHE_DIR=$out/cache
. "$(dirname "$0")/check_step.sh"   # step SECONDS NAME COMMAND...
inc="python3 -m inceptiongs"
if [ "$phase" != compare ]; then
    [ "$device" = cpu ] || nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
    [ "$device" = cpu ] || step 240 gsplat_build python3 -c \
        "from gsplat.cuda._backend import _C; assert _C is not None, 'gsplat did not build its CUDA kernels'"
    step 240 stage1 $inc train "$bonsai" --out "$out/s1" --downscale "$downscale" --strategy mcmc --no-pgsr \
        --sky-min-scale 0 --protocol unstructured --minutes "$stage1_min" --seed 0 --device "$device"
fi
[ "$phase" = stage1 ] && exit 0
echo '{"follow_outlook": false}' >"$out/not_following.json"
step 200 bootstrap $inc bootstrap "$out/s1" --out "$out/boot" --minutes "$boot_min" --iterations 100000 --seed 0 \
    --overwrite
step 200 not_following $inc bootstrap "$out/s1" --out "$out/boot_nf" --minutes "$boot_min" --iterations 100000 \
    --seed 0 --config "$out/not_following.json" --overwrite
step 200 baseline python3 -c "import sys; from inceptiongs.bootstrap.runner import baseline_run; \
baseline_run(sys.argv[1], sys.argv[2], float(sys.argv[3]), 100000, seed=0, progress=False, overwrite=True)" \
    "$out/s1" "$out/base" "$boot_min"
python3 - "$out" <<'EOF'
import json, sys
from pathlib import Path

out = Path(sys.argv[1])
rows = {}
for name in ("s1", "boot", "boot_nf", "base"):
    path = out / name / "metrics.jsonl"
    if not path.is_file():
        continue
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    scored = [r for r in records if "scarce_psnr" in r]
    if scored:
        last = scored[-1]
        rows[name] = {"scarce": last["scarce_psnr"], "covered": last["covered_psnr"],
                      "iteration": max(r.get("iteration", 0) for r in records), "wall_s": last.get("wall_s"),
                      "gaussians": last.get("num_gaussians")}
    summary = out / name / "bootstrap" / "summary.json"
    if summary.is_file() and name in rows:
        data = json.loads(summary.read_text())
        rows[name].update(steps=data.get("steps"), outlook=(data.get("outlook") or {}).get("line"),
                          generation_s=[r.get("generation_s") for r in data.get("rounds", [])],
                          regenerations=[round(r["seconds"], 1) for r in data.get("regenerations", [])])
for name, row in rows.items():
    print(name, json.dumps(row))
for name in ("boot", "boot_nf"):
    if name in rows and "base" in rows:
        print(f"{name} - baseline: {rows[name]['scarce'] - rows['base']['scarce']:+.2f} scarce / "
              f"{rows[name]['covered'] - rows['base']['covered']:+.2f} covered")
(out / "figures.json").write_text(json.dumps(rows, indent=1))
EOF
