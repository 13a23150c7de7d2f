#!/usr/bin/env bash
# Reproduce the shipped default style from the shared BEAT clip:
#   prepare -> train (configs/demo-beat2-scott.yaml) -> install into assets/styles.
# Needs ../shared beside the repo and `make setup` done. Takes ~30 min on 2 CPU cores.
set -euo pipefail
cd "$(dirname "$0")/.."
FC=.venv/bin/facecapges
WORK=${WORK:-build/default-style}
mkdir -p "$WORK"
[ -n "${RESUME:-}" ] || $FC prepare ../shared/data/beat --out "$WORK/cache" --speakers 2 --force
if [ -n "${RESUME:-}" ]; then  # RESUME=1: continue an interrupted run exactly
    $FC train --cache "$WORK/cache" --speaker 2 --out "$WORK/run" --resume
else
    $FC train --cache "$WORK/cache" --speaker 2 --split all --out "$WORK/run" \
        --config configs/demo-beat2-scott.yaml --force
fi
mkdir -p src/facecapges/assets/styles
cp "$WORK/run/model.safetensors" src/facecapges/assets/styles/beat2-scott-demo.safetensors
cp "$WORK/run/log.csv" src/facecapges/assets/styles/beat2-scott-demo.log.csv
# its FGD autoencoder (thesis 5.5.1), saved beside it as beat2-scott-demo.fgd/
$FC fgd-train --cache "$WORK/cache" --speaker 2 --split all --holdout-from 766 \
    --checkpoint src/facecapges/assets/styles/beat2-scott-demo.safetensors --force
echo "installed src/facecapges/assets/styles/beat2-scott-demo.safetensors (+ .fgd/)"
