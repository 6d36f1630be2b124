#!/usr/bin/env bash
# The torch reference and the diffusion prior on CUDA, checked and timed on a GPU machine in one
# pass (each step has its own time limit): the torch rasterizer against the CPU
# (tests/rasterizer/test_cuda.py) and its speed next to the CPU's on the same machine, the prior's
# generation and training step, and the prior's path as a user runs it on the demo courtyard
# (stage I on the CPU, `inceptiongs prior`, `generate`, `eval --generated` on the GPU). Figures:
# docs/rendering.md and docs/prior.md, "On a GPU". The gsplat training path has its own check:
# benchmarks/gpu_check.sh.
#
#     bash benchmarks/gpu_check_prior.sh [OUT]      (default OUT: runs/gpu_check_prior; needs pycolmap)
#
# The prior's steps run with --device cuda, which (the one device rule, docs/devices.md) is gsplat
# and torch on the GPU: they need gsplat (pip install 'inceptiongs[cuda]') and nvcc as well.
#
# Each step has its own time limit and a failed step does not stop the next. OUT gets
# gpu_check.log (every step's whole output), generated.png and generated.json.
set -u
out=${1:-runs/gpu_check_prior}
mkdir -p "$out"
export PYTHONUNBUFFERED=1 PYTHONPATH="$(pwd)${PYTHONPATH:+:$PYTHONPATH}"  # the checkout, installed or not
work=$(mktemp -d)
. "$(dirname "$0")/check_step.sh"   # step SECONDS NAME COMMAND...
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import torch, numpy, numba; print('torch', torch.__version__, 'cuda', torch.version.cuda, \
'numpy', numpy.__version__, 'numba', numba.__version__, 'cpus', __import__('os').cpu_count())"
step 180 tests python3 -m pytest -q -p no:cacheprovider tests/rasterizer/test_cuda.py tests/rasterizer/test_rasterize.py
step 150 raster_cuda python3 benchmarks/bench_torch_rasterizer.py --device cuda --sizes 10000 100000 1000000
step 90 raster_cpu python3 benchmarks/bench_torch_rasterizer.py --sizes 100000
step 60 prior_cuda python3 benchmarks/bench_prior.py --device cuda
step 30 scene python3 -m inceptiongs demo-scene "$work/scene"
step 120 stage1 python3 -m inceptiongs train "$work/scene" --out "$work/run" --protocol unstructured --minutes 1 \
    --device cpu
step 100 prior python3 -m inceptiongs prior "$work/run" --minutes 1 --device cuda
target=$(python3 -c "import json, sys; s = json.load(open(sys.argv[1])); print(s['view_names'][s['target_view']])" \
    "$work/run/split.json")
step 60 generate python3 -m inceptiongs generate "$work/run" --view "$target" --out "$out/generated.png" \
    --device cuda
step 120 eval_generated python3 -m inceptiongs eval "$work/run" --generated --ddim-steps 20,5 --device cuda
cp "$work/run/eval/generated.json" "$out/" 2>/dev/null
rm -rf "$work"
