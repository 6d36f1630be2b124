#!/usr/bin/env bash
# The bootstrap against the same-time baseline on bonsai at full resolution (800x533) on a CUDA
# machine: stage I (3DGS-MCMC, no planar terms, unstructured split, seed 0) with --device cuda for
# STAGE1_MIN minutes; then from it, each for BOOT_MIN minutes of wall clock, the default bootstrap
# of j* (which follows the outlook), the bootstrap that does not (follow_outlook false), and stage I
# continued on the photos alone. Figures: docs/results.md ("At full resolution on a GPU").
#
#     bash benchmarks/gpu_bootstrap.sh [OUT] [all|stage1|compare|prior]   (default: runs/gpu_bootstrap all)
#
# "stage1" trains (and first builds gsplat's kernels), "compare" runs the three continuations of
# the stage I already in OUT/s1; "all" does both. "prior" measures the scene-adaptive prior as the
# fill at a GPU's size: `inceptiongs prior` on OUT/s1 for PRIOR_MIN minutes (denoiser UNET_WIDTH
# channels wide, PRIOR_BATCH patches of PRIOR_PATCH px a step; its generated images scored on
# held-out views before and after), a bootstrap for BOOT_MIN with that prior as the fill and the
# agreement gate off (on, the gate judges the photos alone and left every view out here) and
# virtual views from the start whatever the outlook says, and stage I continued on the photos for
# PRIOR_MIN + BOOT_MIN, the bootstrap's whole time.
# Needs gsplat (pip install 'inceptiongs[cuda]'),
# nvcc for its build and bonsai (../shared/data or $INCEPTIONGS_DATA; $GPU_CHECK_BONSAI names
# another copy). DEVICE=cpu DOWNSCALE=8 runs the same steps on a CPU (a dry run of this script).
# OUT gets the runs, gpu_check.log (every step's output) and figures.json (figures_prior.json).
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
if [ "$phase" = all ] || [ "$phase" = stage1 ]; then
    [ "$device" = cpu ] || nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
    [ "$device" = cpu ] || step 240 gsplat_build python3 -c \
        "from gsplat.cuda._backend import _C; assert _C is not None, 'gsplat did not build its CUDA kernels'"
    echo '{"pgsr": false, "free_space": {"sky_min_scale": 0}}' >"$out/stage1_settings.json"
    step 240 stage1 $inc train "$bonsai" --out "$out/s1" --downscale "$downscale" --strategy mcmc \
        --config "$out/stage1_settings.json" --protocol unstructured --minutes "$stage1_min" --seed 0 --device "$device"
fi
[ "$phase" = stage1 ] && exit 0
[ -f "$out/s1/model.ply" ] || { echo "$out/s1: no stage I here (run the stage1 phase first)"; exit 2; }
if [ "$phase" = prior ]; then
    prior_min=${PRIOR_MIN:-1}
    echo '{"fill": "prior", "agreement_min_db": null, "follow_outlook": false}' >"$out/prior_fill.json"
    step 400 prior $inc prior "$out/s1" --minutes "$prior_min" --unet-width "${UNET_WIDTH:-64}" \
        --batch-size "${PRIOR_BATCH:-16}" --patch-size "${PRIOR_PATCH:-128}" --device "$device" --restart \
        --eval-every-minutes "$prior_min" --eval-views 6
    step 300 prior_fill $inc bootstrap "$out/s1" --out "$out/boot_prior" --minutes "$boot_min" \
        --iterations 100000 --seed 0 --config "$out/prior_fill.json" --overwrite
    total=$(python3 -c "print($prior_min + $boot_min)")
    step 400 prior_baseline python3 -c "import sys; from inceptiongs.bootstrap.runner import baseline_run; \
baseline_run(sys.argv[1], sys.argv[2], float(sys.argv[3]), 100000, seed=0, progress=False, overwrite=True)" \
        "$out/s1" "$out/base_prior" "$total"
    names="s1 boot_prior base_prior"
    pairs="boot_prior:base_prior"
else
    names="s1 boot boot_nf base"
    pairs="boot:base boot_nf:base"
    echo '{"follow_outlook": false}' >"$out/not_following.json"
    step 200 bootstrap $inc bootstrap "$out/s1" --out "$out/boot" --minutes "$boot_min" --iterations 100000 \
        --seed 0 --overwrite
    step 200 not_following $inc bootstrap "$out/s1" --out "$out/boot_nf" --minutes "$boot_min" --iterations 100000 \
        --seed 0 --config "$out/not_following.json" --overwrite
    step 200 baseline python3 -c "import sys; from inceptiongs.bootstrap.runner import baseline_run; \
baseline_run(sys.argv[1], sys.argv[2], float(sys.argv[3]), 100000, seed=0, progress=False, overwrite=True)" \
        "$out/s1" "$out/base" "$boot_min"
fi
python3 - "$out" "$names" "$pairs" "$phase" <<'EOF'
import json, sys
from pathlib import Path

out, names, pairs, phase = Path(sys.argv[1]), sys.argv[2].split(), sys.argv[3].split(), sys.argv[4]
rows = {}
for name in names:
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
prior_metrics = out / "s1" / "prior" / "metrics.jsonl"
if phase == "prior" and prior_metrics.is_file():
    # The prior's own scores: its generated images against the held-out photos, first and last.
    scored = [json.loads(line) for line in prior_metrics.read_text().splitlines() if '"generated"' in line]
    if scored:
        rows["prior"] = {"steps": scored[-1].get("step"), "train_s": scored[-1].get("train_s"),
                         "first": scored[0], "last": scored[-1]}
for name, row in rows.items():
    print(name, json.dumps(row))
for pair in pairs:
    name, base = pair.split(":")
    if name in rows and base in rows:
        print(f"{name} - {base}: {rows[name]['scarce'] - rows[base]['scarce']:+.2f} scarce / "
              f"{rows[name]['covered'] - rows[base]['covered']:+.2f} covered")
(out / ("figures_prior.json" if phase == "prior" else "figures.json")).write_text(json.dumps(rows, indent=1))
EOF
