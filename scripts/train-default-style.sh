#!/usr/bin/env bash
# Rebuild the two shipped styles from ../shared and install them into assets/styles:
#   zeggs-speech:                   the ZEGGS speaker (retargeted take + 9-joint takes), configs/zeggs.yaml
#   beat2-scott-demo (the default): zeggs-speech fine-tuned on BEAT speaker 2, configs/demo-beat2-scott.yaml
# prepare -> train -> figures on the held-out 20 % and unseen audio (scripts/style_report.py).
# Needs ../shared beside the repo and `make setup` done. On an idle 2-core CPU both
# train in well under an hour (the model cards give the measured wall times).
# ONLY=beat2|zeggs rebuilds one; RESUME=1 continues interrupted runs exactly.
set -euo pipefail
cd "$(dirname "$0")/.."
FC=.venv/bin/facecapges
PY=.venv/bin/python
WORK=${WORK:-build/default-style}
STYLES=src/facecapges/assets/styles
BEAT=../shared/data/beat
mkdir -p "$WORK" "$STYLES"
if [ -z "${RESUME:-}" ]; then
    $FC prepare "$BEAT" --out "$WORK/cache-beat" --speakers 2 --force --quiet
    $FC prepare "$BEAT" --out "$WORK/cache-zeggs" --speakers 2 --mocap ../shared/data/zeggs \
        --joints9 ../shared/data/zeggs9 --force --quiet
fi
train() {  # NAME CACHE SPEAKER CONFIG [train options]
    if [ -n "${RESUME:-}" ]; then
        $FC train --cache "$2" --speaker "$3" --out "$WORK/$1" --resume
    else
        $FC train --cache "$2" --speaker "$3" --split all --out "$WORK/$1" --config "$4" --force "${@:5}"
    fi
    cp "$WORK/$1/model.safetensors" "$STYLES/$1.safetensors"
    cp "$WORK/$1/log.csv" "$STYLES/$1.log.csv"
}
# zeggs-speech first: the default style is fine-tuned from it
if [ "${ONLY:-zeggs}" = zeggs ] || [ -z "${ONLY:-}" ]; then
    train zeggs-speech "$WORK/cache-zeggs" 100 configs/zeggs.yaml
    $PY scripts/style_report.py --checkpoint "$STYLES/zeggs-speech.safetensors" --cache "$WORK/cache-zeggs" \
        --speaker 100 --audio "$BEAT/2_scott_0_2_2.wav" --out "$WORK/zeggs-speech.report.json"
fi
if [ "${ONLY:-beat2}" = beat2 ] || [ -z "${ONLY:-}" ]; then
    train beat2-scott-demo "$WORK/cache-beat" 2 configs/demo-beat2-scott.yaml --init-from "$STYLES/zeggs-speech.safetensors"
    $PY scripts/style_report.py --checkpoint "$STYLES/beat2-scott-demo.safetensors" --cache "$WORK/cache-beat" \
        --speaker 2 --holdout-from 766 --audio "$BEAT/2_scott_0_2_2.wav" --audio "$BEAT/2_scott_0_4_4.wav" \
        --out "$WORK/beat2-scott-demo.report.json"
fi
echo "installed into $STYLES; figures in $WORK/*.report.json (copy them into the model cards)"
