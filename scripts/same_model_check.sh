#!/usr/bin/env bash
# Same models from the same inputs: stage I (150 iterations) and the default bootstrap
# (40 iterations) on the tiny demo courtyard at seed 0; prints the sha256 of both model.ply.
# A change meant to keep behaviour (a refactor) must print the same two lines before and after,
# on the same machine (numba's float reductions may differ across CPUs).
#   bash scripts/same_model_check.sh OUT_DIR
set -euo pipefail
out=${1:?usage: same_model_check.sh OUT_DIR}
rm -rf "$out" && mkdir -p "$out" && cd "$out"
inceptiongs demo-scene scene --size tiny > demo_scene.log 2>&1
inceptiongs train scene --out run --iterations 150 --protocol unstructured --seed 0 > train.log 2>&1
inceptiongs bootstrap run --out boot --iterations 40 --seed 0 > bootstrap.log 2>&1
sha256sum run/model.ply boot/model.ply
