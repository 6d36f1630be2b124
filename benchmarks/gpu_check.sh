#!/usr/bin/env bash
# The GPU backend checked and timed on a CUDA machine in one pass (about 13 minutes at the step rate
# of 2026-11-27; each step has its own time limit): gsplat's
# first build, its contract tests against the torch reference, a short stage I and bootstrap on
# the tiny demo courtyard with --device cuda (every hot-loop path on the device), forward+backward
# through the rasterizer interface up to 1M Gaussians at 1920x1080, bonsai at full resolution
# (800x533, unstructured seed 0, 7000 steps, the default strategy with the PGSR terms), stage II's
# step rate on that run on the GPU and on this machine's CPU, and the README demo on CUDA; a
# profile of 20 steps at ~1.7M Gaussians (benchmarks/profile_step.py) says where a step's time goes.
# Figures: docs/devices.md.
#
#     bash benchmarks/gpu_check.sh [OUT]      (default OUT: runs/gpu_check)
#
# Needs pycolmap and gsplat (pip install 'inceptiongs[cuda]'), nvcc for gsplat's build, and the
# real data (../shared/data or $INCEPTIONGS_DATA; $GPU_CHECK_BONSAI names another copy of bonsai).
# Each step has its own time limit and a failed step does not stop the next. OUT gets
# gpu_check.log (every step's whole output) and the figures as JSON.
set -u
out=${1:-runs/gpu_check}
mkdir -p "$out"
out=$(cd "$out" && pwd)
data=${INCEPTIONGS_DATA:-../shared/data}
bonsai=${GPU_CHECK_BONSAI:-$data/bonsai}
export PYTHONUNBUFFERED=1 PYTHONPATH="$(pwd)${PYTHONPATH:+:$PYTHONPATH}"  # the checkout, installed or not
export MAX_JOBS=${MAX_JOBS:-$(nproc)}
work=$(mktemp -d)
export INCEPTIONGS_CACHE_DIR=$work/cache
. "$(dirname "$0")/check_step.sh"   # step SECONDS NAME COMMAND...
inc="python3 -m inceptiongs"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import torch, numpy; print('torch', torch.__version__, 'cuda', torch.version.cuda, 'numpy', \
numpy.__version__, 'cpus', __import__('os').cpu_count())"
step 240 gsplat_build python3 -c \
    "from gsplat.cuda._backend import _C; assert _C is not None, 'gsplat did not build its CUDA kernels'"
[ -n "${GPU_CHECK_SKIP_CONTRACT:-}" ] || step 120 contract python3 -m pytest -q -p no:cacheprovider -x tests/rasterizer/test_rasterizer_contract.py
step 20 smoke_scene $inc demo-scene "$work/tiny" --size tiny
step 60 smoke_train $inc --debug train "$work/tiny" --out "$work/tiny_run" --iterations 120 --protocol unstructured \
    --device cuda
step 60 smoke_mcmc $inc --debug train "$work/tiny" --out "$work/tiny_mcmc" --iterations 80 --protocol unstructured \
    --device cuda --strategy mcmc
step 60 smoke_boot $inc --debug bootstrap "$work/tiny_run" --out "$work/tiny_boot" --iterations 40
step 60 smoke_resume $inc --debug train "$work/tiny" --out "$work/tiny_run" --iterations 160 --resume --device cpu
step 60 raster python3 benchmarks/bench_rasterizers.py --sizes 10000 100000 1000000 --size 1920x1080 \
    --json "$out/raster.json"
# Where a step's time goes at ~1.7M Gaussians with the PGSR terms on (they start at 1633 of 7000).
step 150 profile python3 benchmarks/profile_step.py "$bonsai" --device cuda --iterations 7000 --warm 1700 \
    --steps 20 --top 30
step 230 bonsai $inc train "$bonsai" --out "$work/bonsai" --downscale 1 --iterations 7000 --protocol unstructured \
    --seed 0 --device cuda
cp "$work/bonsai/metrics.jsonl" "$out/bonsai_metrics.jsonl" 2>/dev/null
cp "$work/bonsai/config.json" "$out/bonsai_config.json" 2>/dev/null
step 100 stage2_gpu python3 benchmarks/bench_stage2_rate.py "$work/bonsai" --which device --steps 300 \
    --json "$out/stage2_gpu.json"
step 160 demo $inc demo "$work/demo" --device cuda
cp "$work/demo/report.md" "$out/demo_report.md" 2>/dev/null
# Last: the CPU's rate on the same bonsai model (its held-out evaluation alone takes minutes there).
step "${GPU_CHECK_CPU_SECONDS:-150}" stage2_cpu python3 benchmarks/bench_stage2_rate.py "$work/bonsai" --which cpu \
    --cpu-steps 10 --json "$out/stage2_cpu.json"
rm -rf "$work"
