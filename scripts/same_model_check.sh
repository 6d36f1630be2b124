#!/usr/bin/env bash
# Same models from the same inputs: stage I (150 iterations), the default bootstrap (40
# iterations; on this tiny stage I it follows the outlook, "nothing to repair", and takes photo
# steps only) and the bootstrap that makes virtual views anyway ("follow_outlook": false) on the
# tiny demo courtyard at seed 0; prints the sha256 of the three model.ply.
# A change meant to keep behaviour (a refactor) must print the same two lines before and after,
# on the same machine (numba's float reductions may differ across CPUs).
#   bash scripts/same_model_check.sh OUT_DIR
set -euo pipefail
out=${1:?usage: same_model_check.sh OUT_DIR}
rm -rf "$out" && mkdir -p "$out" && cd "$out"
inceptiongs demo-scene scene --size tiny > demo_scene.log 2>&1
inceptiongs train scene --out run --iterations 150 --protocol unstructured --seed 0 > train.log 2>&1
inceptiongs bootstrap run --out boot --iterations 40 --seed 0 > bootstrap.log 2>&1
echo '{"follow_outlook": false}' > not_following.json
inceptiongs bootstrap run --out boot_virtual --iterations 40 --seed 0 --config not_following.json > virtual.log 2>&1
sha256sum run/model.ply boot/model.ply boot_virtual/model.ply
